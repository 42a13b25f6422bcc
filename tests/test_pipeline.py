"""The simulated-log pipeline: simulate -> HDF5 log -> replay -> metrics, and the CLI.

One small planar-leg rollout is simulated once per session (two compilations: the rollout
chunk and the replay chunk) and shared by every test here.
"""

from __future__ import annotations

import json
import os

import h5py
import numpy as np
import pytest

import jax_contact as jc
from jax_contact.envs.simulate import Rollout, build_world, simulate
from jax_contact.io import read_log, write_json_atomic, write_log
from jax_contact.train import cli
from jax_contact.train.evaluate import delay_one_step, replay, score
from jax_contact.train.report import ABLATION_ROWS, PRINTED_ROWS, ROWS, format_table, table3_json
from jax_contact.train.reproduce import planar_estimator_params

N_ENVS, DURATION = 2, 1.0


@pytest.fixture(scope="module")
def planar():
    world = build_world("planar_leg")
    roll = simulate(world, "hop", "anymal_like", N_ENVS, DURATION, 0, chunk_s=0.5, progress=False)
    return world, roll


def test_a_rollout_shorter_than_two_steps_is_refused(planar):
    """Every consumer of a log differences a reading with the one before: a duration of
    one step (here 0.003 s at 2.5 ms) or none is refused before anything compiles."""
    world, _ = planar
    for duration in (0.001, 0.003):
        with pytest.raises(ValueError, match=r"duration .* a log needs at least 2"):
            simulate(world, "hop", "anymal_like", 1, duration, 0, progress=False)


def test_a_gait_the_robot_cannot_run_is_refused(planar, tmp_path):
    """The planar leg on its rail cannot trot or walk (it would only drop its base at each
    swing) and a quadruped cannot hop: refused, naming the gait and the robot's legs,
    before anything compiles."""
    world, _ = planar
    for kind in ("trot", "walk"):
        with pytest.raises(ValueError, match=rf"gait '{kind}' needs two or more legs.*'hop'"):
            simulate(world, kind, "anymal_like", 1, 0.1, 0, progress=False)
    go1 = build_world("go1")
    with pytest.raises(ValueError, match=r"gait 'hop' runs a one-legged robot.*4 legs"):
        simulate(go1, "hop", "anymal_like", 1, 0.1, 0, progress=False)
    # Two legs (hip and knee, sphere feet) under a free base: the scripted gaits cannot
    # balance it (Berkeley Humanoid fell in both envs within 1 s).
    leg = (
        "<body pos='0 {y} -.1'><joint name='hip{i}' axis='0 1 0'/><geom type='capsule'"
        " fromto='0 0 0 0 0 -.2' size='.02'/><body pos='0 0 -.2'><joint name='knee{i}'"
        " axis='0 1 0'/><geom type='capsule'"
        " fromto='0 0 0 0 0 -.2' size='.02'/><geom name='foot{i}' type='sphere' pos='0 0 -.2'"
        " size='.02'/></body></body>"
    )
    biped = tmp_path / "biped.xml"
    biped.write_text(
        "<mujoco><worldbody><geom name='floor' type='plane' size='5 5 .1'/><body pos='0 0 .5'>"
        "<freejoint/><geom type='box' size='.1 .1 .1'/>"
        + "".join(leg.format(y=y, i=i) for i, y in enumerate((0.1, -0.1)))
        + "</body></worldbody><actuator>"
        + "".join(f"<motor joint='{j}{i}'/>" for i in (0, 1) for j in ("hip", "knee"))
        + "</actuator></mujoco>"
    )
    with pytest.raises(ValueError, match=r"gait 'walk' is scripted without balance.*2 legs"):
        simulate(build_world(str(biped)), "walk", "anymal_like", 1, 0.1, 0, progress=False)


@pytest.fixture(scope="module")
def replayed(planar):
    world, roll = planar
    params = planar_estimator_params(3, world.dt)
    out = replay(
        world.robot,
        dict(qpos=roll.qpos, qvel=roll.qvel, qacc=roll.qacc, tau=roll.tau),
        estimators={"probabilistic": params},
        terrain=jc.flat(0.0, 0.2),
        gms={"gm": jc.baselines.make_gm_params()},
        # A grid as the reproduction tunes one: the defaults, and wider thresholds.
        kinematic={
            "kinematic": jc.baselines.make_kinematic_params(),
            "kin_wide": jc.baselines.make_kinematic_params(0.04, 1.0),
        },
        dt=world.dt,
        diagnostics_of="probabilistic",
        chunk=100,
        progress=False,
    )
    return out


def test_replay_runs_a_grid_of_kinematic_detectors(replayed, planar):
    """A mapping of kinematic settings gives one output each. The detector calls contact
    where the sole is at most ``height_threshold`` above the ground and moves at most
    ``velocity_threshold``, so wider thresholds flag contact wherever the defaults do, and
    on this hop more (the landing's last centimetres and the stance's faster moments)."""
    _, roll = planar
    narrow, wide = replayed["kinematic"], replayed["kin_wide"]
    assert narrow.shape == wide.shape == roll.contact.shape
    assert set(np.unique(narrow)) <= {0.0, 1.0} and set(np.unique(wide)) <= {0.0, 1.0}
    assert np.all(wide >= narrow)
    assert wide.sum() > narrow.sum()


def test_replay_refuses_two_detectors_of_one_name(planar):
    """Each detector's name is one output key: an estimator and a kinematic setting both
    named "kinematic" (the second output would replace the first) and a name holding '/'
    (the diagnostics' key separator) are refused before anything compiles."""
    world, roll = planar
    readings = dict(qpos=roll.qpos, qvel=roll.qvel, qacc=roll.qacc, tau=roll.tau)
    params = planar_estimator_params(3, world.dt)
    kw = dict(terrain=jc.flat(0.0, 0.2), dt=world.dt, progress=False)
    with pytest.raises(
        ValueError, match="kinematic and estimators both name a detector 'kinematic'"
    ):
        kin = jc.baselines.make_kinematic_params()
        replay(world.robot, readings, estimators={"kinematic": params}, kinematic=kin, **kw)
    with pytest.raises(ValueError, match=r"gms: detector name 'gm/a' must be"):
        replay(
            world.robot, readings, estimators={}, gms={"gm/a": jc.baselines.make_gm_params()}, **kw
        )


def test_replay_refuses_a_users_likely_mistakes(planar):
    """Refused before anything compiles, naming the argument: one params object where a
    mapping of them belongs, a diagnostics_of typo (its outputs were missing without a
    word), parameters of another period (they ran with the wrong gait prior and sigma_qdd
    without a word), a read_log dict's keys, and one env's (T, nq) readings (an opaque
    vmap error on 'inconsistent sizes' before)."""
    world, roll = planar
    readings = dict(qpos=roll.qpos, qvel=roll.qvel, qacc=roll.qacc, tau=roll.tau)
    params = planar_estimator_params(3, world.dt)
    kw = dict(terrain=jc.flat(0.0, 0.2), dt=world.dt, progress=False)
    with pytest.raises(ValueError, match=r"estimators must be a mapping .* got EstimatorParams"):
        replay(world.robot, readings, estimators=params, **kw)
    with pytest.raises(ValueError, match=r"diagnostics_of 'estmate' is not one of .*'estimate'"):
        replay(
            world.robot, readings, estimators={"estimate": params}, diagnostics_of="estmate", **kw
        )
    slow = planar_estimator_params(3, 2 * world.dt)
    with pytest.raises(ValueError, match=r"estimators\['slow'\] has dt=0\.005 s .* dt=0\.0025 s"):
        replay(world.robot, readings, estimators={"slow": slow}, **kw)
    logged = {f"readings/{k}": v for k, v in readings.items()}
    with pytest.raises(ValueError, match=r"readings lack \['qpos', 'qvel', 'qacc', 'tau'\]"):
        replay(world.robot, logged, estimators={"estimate": params}, **kw)
    one_env = {k: v[:, 0] for k, v in readings.items()}
    with pytest.raises(ValueError, match=r"readings\['qpos'\] has shape \(\d+, 3\); expected"):
        replay(world.robot, one_env, estimators={"estimate": params}, **kw)


def test_rollout_shapes_and_truth(planar):
    world, roll = planar
    t = int(round(DURATION / world.dt))
    assert roll.qpos.shape == (t, N_ENVS, 3) and roll.tau.shape == (t, N_ENVS, 3)
    assert roll.contact.shape == (t, N_ENVS, 1) and roll.valid.shape == (t, N_ENVS)
    assert roll.valid.all(), "the planar leg on its rail cannot fall"
    # The hop alternates stance and flight: both states occur, and in flight the sole is
    # above the floor while the contact force is below the 1 N threshold.
    assert 0.2 < roll.contact.mean() < 0.95
    air = ~roll.contact
    assert (roll.force[air] <= 1.0).all() and np.median(roll.distance[air]) > 0.0
    np.testing.assert_allclose(roll.time[1] - roll.time[0], world.dt, rtol=1e-6)


def test_replay_tracks_truth(planar, replayed):
    _, roll = planar
    scores = score(replayed, roll.contact, roll.valid, dt=0.0025)
    # The estimator tracks the hop: its F1 is well above that of always-contact guessing,
    # 2 s / (1 + s) at a contact share s (precision s, recall 1; 0.86 at the hop's duty
    # 0.75), and its accuracy is well above a constant flag's, max(s, 1 - s). The outputs
    # are probabilities in [0, 1] without NaN.
    p = replayed["probabilistic"]
    assert np.isfinite(p).all() and ((p >= 0) & (p <= 1)).all()
    share = float(roll.contact[roll.valid].mean())
    got = scores["probabilistic"]
    # Measured (2026-12-06): s = 0.78, F1 0.985 against 0.876, accuracy 0.978 against 0.78.
    assert got["f1"] > max(0.9, 2 * share / (1 + share) + 0.05), (share, got["f1"])
    assert got["accuracy"] > max(share, 1 - share) + 0.1, (share, got["accuracy"])
    assert scores["probabilistic"]["n_touchdowns"] >= 2 * N_ENVS
    for f in ("p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff", "p_touchdown"):
        assert replayed[f"probabilistic/{f}"].shape == p.shape


def test_delayed_pairing_shifts_state_not_acceleration():
    a = np.arange(5.0)[:, None]
    np.testing.assert_array_equal(delay_one_step(a)[:, 0], [0, 0, 1, 2, 3])


def test_delayed_pairing_takes_lost_readings_entry_by_entry():
    """Two coordinates over 4 readings (hand values). Coordinate 0's velocity is lost at
    reading 1: its acceleration there is NaN, and reading 2's state takes reading 2's own
    velocity (30) for it instead of the lost one. Coordinate 1's position is lost at reading
    2: reading 3's state takes reading 3's own position (13). Everything else is the plain
    one-step delay, the first reading with its own state."""
    from jax_contact.train.evaluate import pair_delayed

    nan = np.nan
    qpos = np.array([[0.0, 10.0], [1.0, 11.0], [2.0, nan], [3.0, 13.0]])
    qvel = np.array([[0.0, 20.0], [nan, 21.0], [30.0, 22.0], [40.0, 23.0]])
    qacc = np.array([[5.0, 6.0], [7.0, 8.0], [9.0, 1.0], [2.0, 3.0]])
    q, v, a = pair_delayed(qpos, qvel, qacc)
    np.testing.assert_array_equal(q, [[0, 10], [0, 10], [1, 11], [2, 13]])
    np.testing.assert_array_equal(v, [[0, 20], [0, 20], [30, 21], [30, 22]])
    np.testing.assert_array_equal(a, [[5, 6], [nan, 8], [9, 1], [2, 3]])
    first = {"qpos": qpos[:1] - 1.0, "qvel": qvel[:1] - 1.0}
    q, v, _ = pair_delayed(qpos, qvel, qacc, first)
    np.testing.assert_array_equal(q[0], [-1, 9])
    np.testing.assert_array_equal(v[0], [-1, 19])


def test_replay_refuses_unknown_pairing(planar):
    world, roll = planar
    with pytest.raises(ValueError, match="pairing"):
        replay(
            world.robot,
            dict(qpos=roll.qpos, qvel=roll.qvel, qacc=roll.qacc, tau=roll.tau),
            estimators={},
            terrain=jc.flat(),
            dt=world.dt,
            pairing="forward",
        )


def test_log_roundtrip_is_exact(planar, tmp_path):
    world, roll = planar
    path = write_log(tmp_path / "log.h5", roll.to_arrays(), {"robot": "planar_leg", "dt": world.dt})
    arrays, attrs = read_log(path)
    back = Rollout.from_arrays(arrays)
    for name in ("qpos", "qvel", "qacc", "tau", "contact", "force", "distance", "valid", "time"):
        np.testing.assert_array_equal(getattr(back, name), getattr(roll, name))
    assert attrs["robot"] == "planar_leg" and attrs["dt"] == world.dt
    assert [p.name for p in tmp_path.iterdir()] == ["log.h5"], "no temporary file left behind"


def test_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(ValueError, match="dtype object"):
        write_log(tmp_path / "x.h5", {"a": np.array([object()])}, {})
    with pytest.raises(ValueError, match="attribute 'bad'"):
        write_log(tmp_path / "y.h5", {"a": np.zeros(3)}, {"bad": object()})
    # A version of its own wrote a file read_log then refused (a helper's audit).
    with pytest.raises(ValueError, match=r"attrs: 'format_version' 99 is not this library's"):
        write_log(tmp_path / "z.h5", {"a": np.zeros(3)}, {"format_version": 99})
    # Names and dtypes h5py would refuse mid-file, with messages naming neither (an audit):
    # each is now refused before the file is opened, naming the array or attribute.
    bad = [
        ({"a": np.ones(2), "a/b": np.ones(2)}, {}, r"array 'a' is also a group"),
        ({"": np.ones(2)}, {}, r"array name '': expected a non-empty str"),
        ({"a": np.ones(2)}, {1: "x"}, r"attribute name 1: expected a non-empty str"),
        ({"s": np.array(["ab", "c"])}, {}, r"array 's' has dtype <U2 and cannot be written"),
        ({"c": np.ones(2, complex)}, {}, r"array 'c' has dtype complex128"),
    ]
    for arrays, attrs, message in bad:
        with pytest.raises(ValueError, match=message):
            write_log(tmp_path / "w.h5", arrays, attrs)
    with pytest.raises(ValueError, match=r"array 'r' is not rectangular"):
        write_log(tmp_path / "w.h5", {"r": [[1, 2], [3]]}, {})
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match=r"log file '.*' is a folder"):
        read_log(tmp_path)  # it said "does not exist"


def test_read_log_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.h5"):
        read_log(tmp_path / "missing.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = np.zeros(2)
    with pytest.raises(ValueError, match="not a jax-contact log"):
        read_log(tmp_path / "other.h5")
    # A version that is no integer named nothing ("invalid literal for int()").
    with h5py.File(tmp_path / "odd.h5", "w") as f:
        f["x"] = np.zeros(2)
        f.attrs["format_version"] = "one"
    with pytest.raises(ValueError, match=r"odd.h5': format_version 'one' is not an integer"):
        read_log(tmp_path / "odd.h5")
    with pytest.raises(ValueError, match="missing arrays"):
        Rollout.from_arrays({"readings/qpos": np.zeros((1, 1, 3))})


def test_json_is_strict_and_atomic(tmp_path):
    path = write_json_atomic(tmp_path / "r.json", {"a": float("nan"), "b": np.float32(2.5)})
    assert path.read_text().replace(" ", "").replace("\n", "") == '{"a":null,"b":2.5}'
    assert os.listdir(tmp_path) == ["r.json"]


def test_cli_evaluate_a_log(planar, tmp_path, capsys):
    world, roll = planar
    log = write_log(
        tmp_path / "log.h5",
        roll.to_arrays(),
        {"robot": "planar_leg", "dt": world.dt, "gait": "hop", "noise": "anymal_like"},
    )
    argv = ["evaluate", str(log), "--json", str(tmp_path / "m.json"), "--bootstrap", "20"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "probabilistic" in out and "gm" in out and "kinematic" in out
    # The bootstrap compares each baseline with the estimator; its point estimate is the
    # difference of the two rows' own scores in the same file.
    result = json.loads((tmp_path / "m.json").read_text())
    assert set(result["vs_probabilistic"]) == {"gm", "kinematic"}
    for row in ("gm", "kinematic"):
        delta, low, high, verdict = result["vs_probabilistic"][row]["f1"]
        want = result["scores"]["probabilistic"]["f1"] - result["scores"][row]["f1"]
        assert delta == pytest.approx(want) and low <= high
        assert verdict == "too few envs"  # 2 envs: no call (jax_contact.bootstrap.MIN_ENVS)
        # Printed without the interval (2 envs have 3 distinct resamples), saying why.
        (line,) = [ln for ln in out.splitlines() if ln.startswith(f"  vs {row} ")]
        assert line.endswith("(no interval: fewer than 5 envs to resample)"), line
        assert f"F1 {delta:+.4f};" in line and "[" not in line, line


def test_load_log_names_what_does_not_fit(planar, tmp_path, capsys):
    """A user trial's cases: NaN readings were replayed without a word; a torque array cut
    short was named as the adapter's 'tau must have shape (3,)', no file; a log loaded for
    another robot blamed that robot's foot names."""
    from jax_contact.train.logs import load_log

    world, roll = planar
    attrs = {"robot": "planar_leg", "dt": world.dt, "gait": "hop", "noise": "anymal_like"}
    arrays = roll.to_arrays()
    tau = np.array(arrays["readings/tau"])
    tau[5:8, 1, 0] = np.nan
    log = write_log(tmp_path / "nan.h5", {**arrays, "readings/tau": tau}, attrs)
    load_log(log)
    err = capsys.readouterr().err
    assert "readings that are not finite on valid steps (readings/tau 3, of" in err
    assert "readings/qvel" not in err
    load_log(write_log(tmp_path / "ok.h5", arrays, attrs))
    assert "not finite" not in capsys.readouterr().err
    short = write_log(tmp_path / "short.h5", {**arrays, "readings/tau": tau[..., :2]}, attrs)
    with pytest.raises(ValueError, match=r"short\.h5'.*'readings/tau' has 2 columns but robot"
                       r" 'planar_leg' has nv = 3"):  # fmt: skip
        load_log(short)
    feet = write_log(tmp_path / "feet.h5", arrays, {**attrs, "foot_names": ["foot"]})
    with pytest.raises(ValueError, match=r"robot 'go1': .*the log's feet \['foot'\] are those"
                       r" of the robot it names, 'planar_leg'"):  # fmt: skip
        load_log(feet, robot="go1")


def test_evaluate_leaves_lost_readings_out_of_every_row(planar, tmp_path, capsys):
    """A log with a lost torque inside a true air phase: the estimator predicts that foot
    from the transition alone there, so ``evaluate`` (like ``estimate`` on a recording)
    scores those foot-steps for no detector; their truth stays known, so the air phase
    is not split (metrics rules 7b, 8). Before, the predicted-only steps were scored."""
    from jax_contact.train.log_evaluate import evaluate_file

    world, roll = planar
    attrs = {"robot": "planar_leg", "dt": world.dt, "gait": "hop", "noise": "anymal_like"}
    arrays = roll.to_arrays()
    truth = np.asarray(arrays["truth/contact"], bool)[:, 1, 0]
    # A true air phase of env 1 at least 12 steps long, past the first 20 steps.
    starts = [t for t in range(20, len(truth) - 12) if truth[t - 1] and not truth[t : t + 12].any()]
    t0 = starts[0] + 4
    tau = np.array(arrays["readings/tau"])
    tau[t0 : t0 + 3, 1, 2] = np.nan  # the knee's torque, three readings
    clean = write_log(tmp_path / "clean.h5", arrays, attrs)
    lost = write_log(tmp_path / "lost.h5", {**arrays, "readings/tau": tau}, attrs)
    a = evaluate_file(clean, bootstrap=20)
    b = evaluate_file(lost, bootstrap=20)
    capsys.readouterr()
    read = np.asarray(b["outputs"]["probabilistic/valid"], bool)
    # A torque is not differenced: exactly the three readings lose the leg's update.
    assert int((~read).sum()) == 3 and read[:, 0].all()
    for row in ("probabilistic", "gm", "kinematic"):
        sa, sb = a["scores"][row], b["scores"][row]
        assert sb["n_steps"] == sa["n_steps"] - 3, row
        assert sb["n_air_phases"] == sa["n_air_phases"], row
    assert set(b["vs_probabilistic"]) == {"gm", "kinematic"}


def test_cli_errors_name_the_problem(tmp_path, capsys):
    assert cli.main(["evaluate", str(tmp_path / "nope.h5")]) == 2
    assert "nope.h5" in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "out.txt"), "--robot", "planar_leg"]) == 2
    assert "must end in .h5" in capsys.readouterr().err
    assert not (tmp_path / "out.txt").exists()
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0


def test_build_world_refuses_bad_input():
    with pytest.raises(ValueError, match="terrain must be one of"):
        build_world("planar_leg", terrain="ice")
    with pytest.raises(ValueError, match="'no_such_body'"):
        build_world("planar_leg", added_mass=[("no_such_body", 1.0)])


def test_table_shapes():
    cell = {
        "touchdown_delay_ms": (5.0, 1.0),
        "liftoff_delay_ms": (3.0, 2.0),
        "touchdown_delay_persist_ms": (7.5, 1.0),
        "liftoff_delay_persist_ms": (5.5, 2.0),
        "failures": 1,
        "air_phase_failure_rate": 0.25,
        "air_false_contact_rate": 0.01,
        "missed": 0,
        "missed_liftoffs": 2,
        "touchdown_already_on": 0,
        "false_liftoffs": 3,
        "accuracy": 0.95,
        "f1": 0.9,
        "brier": 0.05,
        "ece": 0.02,
        "n_touchdowns": 120,
        "n_liftoffs": 118,
        "n_air_phases": 4,
    }
    scores = {k: dict(cell) for k in (*ROWS, *ABLATION_ROWS)}
    payload = table3_json(
        {
            "tuned_gm": {"walk": "a", "trot": "b"},
            "results": {"trot": {"scores": scores, "upright": 1.0}},
        }
    )
    got = payload["scenarios"]["trot"]["gm_walk"]
    assert got["touchdown_delay_ms"] == [5.0, 1.0] and got["n_touchdowns"] == 120
    assert set(payload["scenarios"]["trot"]) == set(ROWS)
    got = payload["scenarios"]["trot"]["probabilistic"]
    assert got["air_phase_failure_rate"] == 0.25 and got["missed_liftoffs"] == 2
    assert got["accuracy"] == 0.95 and got["liftoff_delay_ms"] == [3.0, 2.0]
    text = format_table(payload)
    assert "5.0±1.0" in text and "25.0%" in text and "0.950" in text
    # A log without a true air phase (a robot standing throughout): both rates have no
    # denominator and read n/a (air-ph printed "nan%" where sw-ph said n/a).
    nan = float("nan")
    quiet = {**cell, "air_phase_failure_rate": nan, "swing_phase_failure_rate": nan}
    table = format_table({"scenarios": {"stand": {"probabilistic": quiet}}}, legend=False)
    assert table.splitlines()[1].split()[6:8] == ["n/a", "n/a"] and "nan" not in table
    # With a tuned row (the robot's preset): its cell, its comparisons and its source are
    # stored, and the printed table shows it right after the defaults.
    scores["tuned"] = {**cell, "f1": 0.97}
    info = {"source": "go1", "seeds": {}, "calibration": None, "held_out": True}
    vs = {"probabilistic": {"f1": [0.07, 0.05, 0.09, "better"]}}
    payload = table3_json(
        {
            "tuned_gm": {"walk": "a", "trot": "b"},
            "results": {"trot": {"scores": scores, "upright": 1.0, "tuned_vs": vs}},
            "tuned_params": info,
        }
    )
    assert payload["scenarios"]["trot"]["tuned"]["f1"] == 0.97
    assert payload["tuned_vs"] == {"trot": vs} and payload["tuned_params"] == info
    lines = format_table(payload, PRINTED_ROWS).splitlines()
    assert lines[1].split()[0] == "probabilistic" and lines[2].split()[:4] == [
        "tuned",
        "5.0±1.0",
        "3.0±2.0",
        "0.970",
    ]


def test_a_flags_ece_is_shown_as_flag_and_left_out_of_the_calibration_comparison():
    """A 0/1 flag's ECE and Brier are 1 - accuracy (here 2 of 8 steps wrong: 0.25), which
    the table printed beside the estimator's calibration error; it now reads `flag`, and
    evaluate's bootstrap compares no ECE with a flag."""
    from jax_contact.train.evaluate import is_flag, score
    from jax_contact.train.report import format_scores

    truth = np.array([1, 1, 1, 0, 0, 0, 1, 1], bool)[:, None, None]
    flag = np.array([1, 1, 0, 0, 1, 0, 1, 1], np.float32)[:, None, None]
    prob = np.array([0.9, 0.8, 0.6, 0.2, 0.3, 0.1, 0.7, 0.9], np.float32)[:, None, None]
    sc = score({"probabilistic": prob, "gm": flag}, truth, np.ones((8, 1), bool), dt=0.0025)
    assert sc["gm"]["is_flag"] and not sc["probabilistic"]["is_flag"]
    assert sc["gm"]["ece"] == pytest.approx(0.25) == 1 - sc["gm"]["accuracy"]
    assert is_flag(np.array([0.0, 1.0, np.nan])) and not is_flag(np.array([0.0, 0.5]))
    rows = format_scores(sc, legend=False).splitlines()
    assert rows[1].split()[0] == "probabilistic" and rows[1].split()[-1] != "flag"
    assert rows[2].split()[0] == "gm" and rows[2].split()[-1] == "flag"
    # The bootstrap against a flag row: every statistic but ECE.
    from jax_contact.train.log_evaluate import _vs_probabilistic

    rng = np.random.default_rng(0)
    truth = (np.arange(60)[:, None, None] // 6 % 2 == 0) & np.ones((60, 6, 1), bool)
    prob = np.clip(truth + rng.normal(0, 0.3, truth.shape), 0, 1).astype(np.float32)
    out = {"probabilistic": prob, "gm": (prob > 0.4).astype(np.float32)}
    valid = np.ones(truth.shape, bool)
    sc = score(out, truth, valid[..., 0], dt=0.0025)
    vs = _vs_probabilistic(out, sc, truth, valid, 0.0025, 50)
    assert "ece" not in vs["gm"] and "f1" in vs["gm"]


def test_table3_says_what_its_missed_liftoffs_count():
    """mLO of 222 beside F1 0.99 read as a defect to a newcomer: Table III is followed by
    the scenarios' one-step air phases, counted by hand here. Truth 1 1 0 1 1 0 0 0 0 0 0 1:
    two air phases between contacts, of 1 and 6 steps; at most 4 steps (10 ms at 400 Hz): 1."""
    from jax_contact.train.report import format_short_air_phases, short_air_phase_counts

    truth = np.array([1, 1, 0, 1, 1, 0, 0, 0, 0, 0, 0, 1], bool)[:, None, None]
    assert short_air_phase_counts(truth, np.ones((12, 1), bool), 0.0025) == [1, 2]
    line = format_short_air_phases({"short_air_phases": {"walk": [1, 2]}, "dt": 0.0025})
    assert line.startswith("short air phases: true air phases of at most 4 steps (10 ms)")
    # wrapped at 100; the count is of complete air phases, not air-ph's (a user read
    # "walk 16 of 16" as contradicting sw-ph's share of longer swings, cut by the end)
    assert " walk 1 of 2 complete air phases (contact before and after;" in " ".join(line.split())
    assert format_short_air_phases({"short_air_phases": {}, "dt": 0.0025}) is None
    # The legend follows a table unless asked not to (reproduce prints it once).
    text = format_table({"scenarios": {}}, legend=False)
    assert "TD / LO ms" not in text and "TD / LO ms" in format_table({"scenarios": {}})
