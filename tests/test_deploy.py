"""The exported estimator (jax_contact.export / deploy) against the live one.

One short simulated Go1 log, one export and one offline replay per module (about a minute
of compilation on 2 cores); the artefact is run in a fresh Python process where ``mujoco``
cannot be imported, one reading per call, and compared with ``jax_contact.train.evaluate.replay`` on
the same readings.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

import jax_contact as jc
from jax_contact.io import read_log, write_log

ROOT = Path(__file__).resolve().parents[1]
# Both sides run the same float32 program from different compilations (the export is one
# robot, the replay a vmapped scan): differences are rounding, ~1e-6 in P(contact); 1e-4
# leaves room for a logit that rounding moves across the foothold memory's threshold.
P_TOL = 1e-4
N_STEPS = 160  # 0.4 s at 400 Hz: a trot's touch-downs and lift-offs on every foot


@pytest.fixture(scope="module")
def deployed(tmp_path_factory):
    from jax_contact.train.deploy_cmd import export_to_file
    from jax_contact.train.logs import simulate_to_file

    tmp = tmp_path_factory.mktemp("deploy")
    log = simulate_to_file(
        tmp / "go1.h5", robot="go1", gait="trot", n_envs=1, duration=N_STEPS / 400.0, seed=3
    )
    artefact = tmp / "go1.contact"
    header = export_to_file(artefact, robot="go1", rate_hz=400.0)
    arrays, attrs = read_log(log)
    readings = {
        k: np.asarray(arrays[f"readings/{k}"], np.float32) for k in ("qpos", "qvel", "qacc", "tau")
    }
    return {"tmp": tmp, "log": log, "artefact": artefact, "header": header, "readings": readings}


def _replay_go1(readings) -> np.ndarray:
    """P(contact) (T, L) of the offline estimator with Go1's default parameters."""
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.evaluate import replay
    from jax_contact.train.log_estimator import default_estimator

    robot = load_robot("go1")
    params, terrain = default_estimator(robot.description, 1.0 / 400.0)
    out = replay(
        robot,
        readings,
        estimators={"export": params},
        terrain=terrain,
        dt=1.0 / 400.0,
        seed=0,
        progress=False,
    )
    return out["export"][:, 0]


@pytest.fixture(scope="module")
def live(deployed):
    """P(contact) (T, L) of the offline estimator on the log's readings."""
    return _replay_go1(dict(deployed["readings"]))


_CHILD = """
import json, sys
# What a robot's computer need not have: any import of them now raises ImportError.
BLOCKED = ("mujoco", "flax", "h5py", "brax", "optax")
for name in BLOCKED:
    sys.modules[name] = None
import numpy as np
from jax_contact import deploy

est = deploy.load(sys.argv[1])
log = np.load(sys.argv[2])
belief, ps, valid = est.init(), [], []
for k in range(log["qpos"].shape[0]):
    belief, p, diag = est.update(belief, {n: log[n][k, 0] for n in est.reading_names})
    ps.append(p)
    valid.append(diag["valid"])
errors = {}
bad = {n: log[n][0, 0] for n in est.reading_names}
bad["qvel"] = bad["qvel"][:-1]
try:
    est.update(belief, bad)
except ValueError as err:
    errors["short_qvel"] = str(err)
try:
    est.update(belief, {n: log[n][0, 0] for n in ("qpos", "qvel", "qacc")})
except ValueError as err:
    errors["missing_tau"] = str(err)
try:
    est.update(None, {n: log[n][0, 0] for n in est.reading_names})
except ValueError as err:
    errors["no_belief"] = str(err)
try:
    est.update(belief, {**{n: log[n][0, 0] for n in est.reading_names}, "qpos": "abc"})
except ValueError as err:
    errors["text_qpos"] = str(err)
one = {n: log[n][0, 0] for n in est.reading_names}
for case, value in (("bool_tau", one["tau"] > 0), ("none_tau", [None] * one["tau"].size)):
    try:
        est.update(belief, {**one, "tau": np.asarray(value)})
    except ValueError as err:
        errors[case] = str(err)
try:  # another file's belief (a state of another size)
    est.update(deploy.Belief(belief.state[:-1], belief.key), one)
except ValueError as err:
    errors["short_state"] = str(err)
# A belief rebuilt by hand from lists (a float64 state, an int64 key) is the same belief.
_, p_kept, _ = est.update(belief, one)
rebuilt = deploy.Belief(belief.state.tolist(), np.array(belief.key.tolist()))
_, p_rebuilt, _ = est.update(rebuilt, one)
errors["rebuilt_equal"] = bool(np.array_equal(p_kept, p_rebuilt))
# A NaN velocity is the invalid step of the call that reads it, and the next, clean call
# is valid (it pairs with its own state): once flagged on the call after.
bad = {n: log[n][5, 0].copy() for n in est.reading_names}
bad["qvel"][0] = np.nan
b2, p_nan, d_nan = est.update(belief, bad)
b2, p_next, d_next = est.update(b2, {n: log[n][6, 0] for n in est.reading_names})
nan_calls = [np.asarray(d_nan["valid"]).tolist(), np.asarray(d_next["valid"]).tolist(),
             bool(np.isfinite(p_nan).all() and np.isfinite(p_next).all())]
# A float64 reading beyond float32 (1e300) is an inf, a lost reading, without NumPy's
# "overflow encountered in cast" warning on every such call (a helper's trial).
import warnings
big = {n: log[n][5, 0].astype(np.float64) for n in est.reading_names}
big["qvel"][0] = 1e300
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    _, p_big, d_big = est.update(belief, big)
nan_calls.append([len(caught), np.asarray(d_big["valid"]).tolist()])
# A lost joint velocity (front-left knee, qvel 11) is that foot's invalid step only.
bad = {n: log[n][5, 0].copy() for n in est.reading_names}
bad["qvel"][11] = np.nan
b3, _, d_leg = est.update(belief, bad)
b3, _, d_leg_next = est.update(b3, {n: log[n][6, 0] for n in est.reading_names})
nan_calls += [np.asarray(d_leg["valid"]).tolist(), np.asarray(d_leg_next["valid"]).tolist()]
# The whole log again with the front-left knee's velocity lost on readings 30-35.
lost = {n: log[n][:, 0].copy() for n in est.reading_names}
lost["qvel"][30:36, 11] = np.nan
belief, ps_lost = est.init(), []
for k in range(lost["qpos"].shape[0]):
    belief, p, _ = est.update(belief, {n: lost[n][k] for n in est.reading_names})
    ps_lost.append(p)
# The base quaternion zeroed on readings 40-42 (a driver's zero fill: no orientation).
zeroed = {n: log[n][:, 0].copy() for n in est.reading_names}
zeroed["qpos"][40:43, 3:7] = 0.0
belief, ps_zero = est.init(), []
for k in range(zeroed["qpos"].shape[0]):
    belief, p, _ = est.update(belief, {n: zeroed[n][k] for n in est.reading_names})
    ps_zero.append(p)
loaded = sorted(m for m, v in sys.modules.items() if v is not None and m.split(".")[0] in BLOCKED)
np.savez(
    sys.argv[3],
    p=np.stack(ps),
    valid=np.stack(valid),
    p_lost=np.stack(ps_lost),
    p_zero=np.stack(ps_zero),
)
print(json.dumps({"errors": errors, "blocked_modules": loaded, "nan_calls": nan_calls}))
"""


@pytest.fixture(scope="module")
def child(deployed):
    """The artefact run in a fresh process without mujoco, flax, h5py, brax or optax."""
    tmp = deployed["tmp"]
    np.savez(tmp / "readings.npz", **deployed["readings"])
    env = dict(os.environ, PYTHONPATH=str(ROOT), TF_CPP_MIN_LOG_LEVEL="3")
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            textwrap.dedent(_CHILD),
            str(deployed["artefact"]),
            str(tmp / "readings.npz"),
            str(tmp / "child.npz"),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    out = np.load(tmp / "child.npz")
    return {k: out[k] for k in ("p", "valid", "p_lost", "p_zero")} | report


def test_artefact_without_mujoco_matches_replay(child, live):
    assert child["blocked_modules"] == []
    assert child["p"].shape == live.shape == (N_STEPS, 4)
    assert child["valid"].all()
    np.testing.assert_allclose(child["p"], live, rtol=0, atol=P_TOL)
    # Not a trivially constant estimate: the trot makes and breaks contact.
    assert ((child["p"].max(axis=0) > 0.9) & (child["p"].min(axis=0) < 0.1)).any()


@pytest.fixture(scope="module")
def lost_replay(deployed):
    """The offline P (T, L) with the front-left knee's velocity (Go1's dof 11, its leg
    (9, 10, 11)) lost on readings 30-35."""
    readings = {k: v.copy() for k, v in deployed["readings"].items()}
    readings["qvel"][30:36, 0, 11] = np.nan
    return _replay_go1(readings)


def test_replay_keeps_a_lost_knee_velocity_in_its_leg(lost_replay, live):
    """Offline, a stretch of NaN in the front-left knee's velocity (a dropped encoder
    packet) changes that foot's P only: the other feet's are the clean replay's to the bit
    (the same compiled program as ``live``)."""
    p = lost_replay
    np.testing.assert_array_equal(p[:, [0, 2, 3]], live[:, [0, 2, 3]])
    assert np.isfinite(p).all() and np.abs(p[:, 1] - live[:, 1]).max() > 1e-3


def test_the_exported_update_takes_lost_readings_as_replay_does(child, lost_replay):
    """One convention for lost readings (train/evaluate.py's docstring): the exported file,
    fed the same readings one call at a time, gives the offline replay's P on every foot,
    the lost knee's included (its steps 30-35 invalid in both, and step 36 valid in both:
    the lost entry of the previous state replaced by the reading's own)."""
    np.testing.assert_allclose(child["p_lost"], lost_replay, rtol=0, atol=P_TOL)


def test_a_zero_base_quaternion_is_a_lost_reading_as_replay_takes_nan(child, live, deployed):
    """A base quaternion of zeros (norm < MIN_QUATERNION_NORM: no orientation) on readings
    40-42 is read by the exported update as lost, NaN: its P is the offline replay's with
    NaN there (steps 41-42 predicted only, every foot), not a rotation of zeros."""
    from jax_contact.export import MIN_QUATERNION_NORM

    assert 0.0 < MIN_QUATERNION_NORM < 0.5  # no noisy unit quaternion falls below it
    readings = {k: v.copy() for k, v in deployed["readings"].items()}
    readings["qpos"][40:43, 0, 3:7] = np.nan
    offline = _replay_go1(readings)
    np.testing.assert_allclose(child["p_zero"], offline, rtol=0, atol=P_TOL)
    assert np.abs(offline - live).max() > 1e-3  # the lost steps changed the estimate


def test_a_log_with_a_zero_base_quaternion_reads_it_as_lost(deployed, child, capsys):
    """A helper's audit: the same zeros in an .h5 log were read by evaluate (and by
    deploy-check's offline reference) as an orientation, P up to 0.54 from the clean log's,
    while the exported file and ``estimate`` read them as lost. load_log now reads them as
    the exported update does, with a note."""
    from jax_contact.train.logs import load_log

    arrays, attrs = read_log(deployed["log"])
    arrays["readings/qpos"] = np.array(arrays["readings/qpos"])
    arrays["readings/qpos"][40:43, 0, 3:7] = 0.0
    path = write_log(deployed["tmp"] / "zeroed.h5", arrays, attrs)
    log = load_log(path)
    err = capsys.readouterr().err
    assert "qpos[3:7] on 3 step-env rows" in err
    # The file held zeros, not NaN: the second note calls them lost, not "not finite".
    assert "readings that are lost (not finite, or the quaternions above) on valid steps" in err
    assert "not finite on valid steps" not in err
    qpos = log.readings["qpos"]
    assert (
        np.isnan(qpos[40:43, 0, 3:7]).all() and np.isfinite(np.delete(qpos, [40, 41, 42], 0)).all()
    )
    readings = {k: np.asarray(v, np.float32) for k, v in log.readings.items()}
    np.testing.assert_allclose(child["p_zero"], _replay_go1(readings), rtol=0, atol=P_TOL)
    # replay itself, given the zeros (a Python user's readings, not a loaded log), reads
    # them as lost too (it read them as an orientation: P up to 0.75 from the export's).
    raw = {k: np.asarray(arrays[f"readings/{k}"], np.float32) for k in readings}
    assert (raw["qpos"][40:43, 0, 3:7] == 0).all()
    np.testing.assert_allclose(child["p_zero"], _replay_go1(raw), rtol=0, atol=P_TOL)


def test_a_non_finite_state_is_the_invalid_step_of_its_own_call(child):
    invalid, after, finite, overflow, leg, leg_after = child["nan_calls"]
    assert invalid == [False] * 4 and after == [True] * 4 and finite
    assert overflow == [0, [False] * 4]  # no warning; lost like the NaN of the same entry
    # A base velocity reaches every foot; a knee's only its own (Go1's feet FR, FL, RR, RL).
    assert leg == [True, False, True, True] and leg_after == [True] * 4


def test_wrong_reading_names_the_field(child):
    msg = child["errors"]["short_qvel"]
    assert "'qvel'" in msg and "(17,)" in msg and "(18,)" in msg
    assert "'tau'" in child["errors"]["missing_tau"]
    assert child["errors"]["no_belief"].startswith("belief must be the Belief that init()")
    assert child["errors"]["text_qpos"].startswith("readings['qpos'] must hold real numbers")
    assert (
        "readings['tau'] must hold real numbers (float or int), got dtype bool"
        == (child["errors"]["bool_tau"])
    )
    assert child["errors"]["none_tau"].endswith("got dtype object")
    short = child["errors"]["short_state"]
    assert short.startswith("belief.state has shape (") and "float32 (a belief of another" in short
    assert child["errors"]["rebuilt_equal"] is True


def test_header_describes_inputs_and_parameters(deployed):
    from jax_contact.envs.robots import load_robot

    h = deployed["header"]
    m = load_robot("go1").mj_model
    assert [r["name"] for r in h["readings"]] == ["qpos", "qvel", "qacc", "tau"]
    assert [r["shape"] for r in h["readings"]] == [[m.nq], [m.nv], [m.nv], [m.nv]]
    qvel = h["readings"][1]
    # Joint order as in the model: the free joint's six coordinates, then every hinge.
    hinges = [m.joint(j).name for j in range(1, m.njnt)]
    assert qvel["labels"][6:] == hinges and len(qvel["labels"]) == m.nv
    assert qvel["units"][:6] == ["m/s"] * 3 + ["rad/s"] * 3
    assert h["readings"][0]["units"][3:7] == ["1"] * 4  # the base quaternion w, x, y, z
    assert h["readings"][3]["units"][6] == "N m"
    assert h["rate_hz"] == 400.0 and h["dt"] == 0.0025
    assert h["params"]["provenance"]["source"] == "defaults"
    assert h["library_version"] and h["exported_with"]["jax"]
    assert h["pairing"]["delayed"] == ["qpos", "qvel"]
    # Go1's feet: spheres, each at its geom's centre (0.213 m down the calf), no sole.
    r = h["robot"]
    assert r["foot_points"] == [[0.0, 0.0, -0.213]] * 4 and r["foot_radii"] == [0.023] * 4
    assert r["foot_soles"] == [[]] * 4 and r["contact_point"] == "fixed"
    assert r["total_mass_kg"] == pytest.approx(12.743, abs=1e-3)  # test_estimate's hand sum
    # The stored parameters are the ones the offline estimator gets.
    from jax_contact.params_file import params_from_dict, params_to_dict
    from jax_contact.train.log_estimator import default_estimator

    params, _ = default_estimator(load_robot("go1").description, 0.0025)
    stored = params_from_dict(h["params"])
    assert params_to_dict(stored)["values"] == params_to_dict(params)["values"]


def test_header_of_a_sole_and_static_scenery():
    """A box sole's header says where its contact point rolls: the sole's centre (0.01, 0,
    -0.26) in the shank frame and its four corners, x 0.01 +- 0.08, y +- 0.03 (a box at
    (0.01, 0, -0.25) of half sizes .08 .03 .01). A 300 kg static body of the scene is not
    the robot's mass: the moving bodies' are (model_mass, 5 + 0.5 + 0.5 kg here)."""
    import mujoco

    from jax_contact.envs import feet
    from jax_contact.export import _robot_header
    from jax_contact.robot import model_mass

    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<body name="stairs" pos="1 0 0"><geom type="box" size=".1 .1 .1" mass="300"/></body>'
        '<body name="base" pos="0 0 .6"><joint type="slide" axis="0 0 1"/>'
        '<geom type="box" size=".1 .1 .05" contype="0" conaffinity="0" mass="5"/>'
        '<body name="thigh"><joint name="hip" axis="0 1 0"/><inertial pos="0 0 -.1" mass=".5"'
        ' diaginertia=".01 .01 .01"/><body name="shank" pos="0 0 -.25"><joint name="knee"'
        ' axis="0 1 0"/><inertial pos="0 0 -.1" mass=".5" diaginertia=".01 .01 .01"/>'
        '<geom name="sole" type="box" pos="0.01 0 -0.25" size=".08 .03 .01" mass="0"/>'
        "</body></body></body></worldbody><actuator><motor joint='hip'/><motor joint='knee'/>"
        "</actuator></mujoco>"
    )
    assert model_mass(m) == pytest.approx(6.0) and float(np.sum(m.body_mass)) == pytest.approx(306)
    desc, _ = feet.describe(m, ["sole"])
    r = _robot_header(m, desc, "box_leg.xml")
    np.testing.assert_allclose(r["foot_points"], [[0.01, 0.0, -0.26]], atol=1e-12)
    corners = sorted([0.01 + sx * 0.08, sy * 0.03, -0.26] for sx in (1, -1) for sy in (1, -1))
    np.testing.assert_allclose(sorted(r["foot_soles"][0]), corners, atol=1e-12)
    assert r["contact_point"] == "rolling" and r["foot_radii"] == [0.0]
    assert r["total_mass_kg"] == pytest.approx(6.0)


def test_a_shipped_preset_exports_by_name(deployed, tmp_path):
    """``--params go1`` exports the shipped preset: its values, a provenance naming the
    preset with the SHA-256 of the shipped file (recomputed here from the package data),
    and its calibration map, which the exported P goes through. Reference: the offline
    replay of the preset's parameters on the same readings, its P mapped in float64 NumPy
    (l' = l / T_c for l > 0, l / T_a else; the map's own code is not used)."""
    import hashlib
    from importlib import resources

    import jax_contact as jc
    from jax_contact import deploy
    from jax_contact.envs.robots import load_robot
    from jax_contact.params_file import params_from_dict, params_to_dict
    from jax_contact.train.deploy_cmd import export_to_file, offline_estimate, params_and_terrain
    from jax_contact.train.evaluate import replay

    h = export_to_file(tmp_path / "go1.contact", robot="go1", params_path="go1")
    prov = h["params"]["provenance"]
    shipped = (resources.files("jax_contact") / "presets" / "go1.json").read_bytes()
    assert prov["source"] == "preset" and prov["name"] == "go1"
    assert prov["sha256"] == hashlib.sha256(shipped).hexdigest()
    stored = params_to_dict(params_from_dict(h["params"]))["values"]
    assert stored == params_to_dict(jc.load_params("go1"))["values"]
    cal = json.loads(shipped)["provenance"]["calibration"]
    assert h["calibration"]["temperature_air"] == cal["temperature_air"]

    est = deploy.load(tmp_path / "go1.contact")
    belief, ps = est.init(), []
    readings = deployed["readings"]
    for k in range(N_STEPS):
        belief, p, _ = est.update(belief, {n: readings[n][k, 0] for n in est.reading_names})
        ps.append(p)
    got = np.stack(ps)
    raw = replay(
        load_robot("go1"),
        readings,
        estimators={"export": jc.load_params("go1")},
        terrain=params_and_terrain(h)[1],
        dt=1.0 / 400.0,
        seed=0,
        progress=False,
    )["export"][:, 0].astype(np.float64)
    logit = np.log(np.maximum(raw, 1e-38)) - np.log1p(-np.minimum(raw, 1 - 1e-7))
    scaled = np.where(logit > 0, logit / cal["temperature"], logit / cal["temperature_air"])
    want = 1.0 / (1.0 + np.exp(-scaled))
    np.testing.assert_allclose(got, want, atol=P_TOL)
    assert np.max(np.abs(got - raw)) > 0.01  # the map moved P ...
    np.testing.assert_array_equal(got > 0.5, raw > 0.5)  # ... and kept every decision
    # deploy-check's offline side reads P through the header's map too.
    offline = offline_estimate(h, {k: v[:, 0] for k, v in readings.items()}, dt=1.0 / 400.0)
    np.testing.assert_allclose(offline, got, atol=P_TOL)


def test_export_checks_a_params_file_as_evaluate_does(tmp_path):
    """``export --params`` reads the file as ``evaluate`` does: another robot's preset
    (Spot's, 50.3 kg, on Go1's 12.7 kg) warns, and a file of another period is moved to the
    export's rate with a warning (it was written unchecked, or refused)."""
    import warnings

    from jax_contact.params_file import params_from_dict
    from jax_contact.train.deploy_cmd import export_to_file

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        h = export_to_file(tmp_path / "x.contact", robot="go1", params_path="spot", rate_hz=250)
    said = " | ".join(str(w.message) for w in caught)
    assert "tuned on a robot of 50.3 kg ('spot'); this one weighs 12.7 kg" in said
    assert "has dt = 0.0025 s" in said and "0.004 s" in said
    assert float(params_from_dict(h["params"]).dt) == pytest.approx(0.004)
    assert h["params"]["provenance"]["name"] == "spot"
    # 0.01 % off the file's rate is the same rate (a clock's rounding): no period warning.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        export_to_file(tmp_path / "z.contact", robot="go1", params_path="go1", rate_hz=400.04)
    assert not [w for w in caught if "has dt =" in str(w.message)]
    with pytest.raises(ValueError, match=r"argument --params: .*nv = 3; the robot has nv = 18"):
        export_to_file(tmp_path / "y.contact", robot="go1", params_path=_planar_file(tmp_path))
    assert not (tmp_path / "y.contact").exists()
    # The command's argument is named (it said "foot_names name the same foot twice").
    with pytest.raises(ValueError, match=r"^argument --feet: name the same foot twice"):
        export_to_file(tmp_path / "f.contact", robot="go1", feet=["FR", "FR", "FL", "RL"])
    # A name the model has not (a helper's trial: the message lacked the argument).
    with pytest.raises(ValueError, match=r"^argument --feet: foot 'XX' is no geom, site or"):
        export_to_file(tmp_path / "f.contact", robot="go1", feet=["FR", "FL", "RR", "XX"])
    assert not (tmp_path / "f.contact").exists()


def _planar_file(tmp_path) -> str:
    import jax_contact as jc
    from jax_contact.train.reproduce import planar_estimator_params

    path = tmp_path / "planar.json"
    jc.save_params(path, planar_estimator_params(3, 0.0025))
    return str(path)


def test_corrupt_or_foreign_file_is_refused(deployed, tmp_path):
    from jax_contact.export import read_artefact

    data = bytearray(Path(deployed["artefact"]).read_bytes())
    data[-10] ^= 0xFF
    bad = tmp_path / "bad.contact"
    bad.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="checksum"):
        read_artefact(bad)
    other = tmp_path / "other.contact"
    other.write_text("hello")
    with pytest.raises(ValueError, match="not a jax-contact export"):
        read_artefact(other)
    with pytest.raises(ValueError, match=r"is a folder; expected a \.contact file"):
        read_artefact(tmp_path)  # it said "does not exist"
    # The header is checked too: its rate edited to 200 Hz (valid JSON, same length; the
    # program would still difference at 2.5 ms) was loaded as a 200 Hz estimator.
    data = Path(deployed["artefact"]).read_bytes()
    assert data.count(b'"rate_hz": 400.0') == 1
    edited = tmp_path / "edited.contact"
    edited.write_bytes(data.replace(b'"rate_hz": 400.0', b'"rate_hz": 200.0'))
    with pytest.raises(ValueError, match=r"edited\.contact': the header does not match its"):
        read_artefact(edited)
    # A header length beyond the file's end is named as such, not as bad JSON.
    magic = data[: data.index(b"{") - 8]
    huge = tmp_path / "huge.contact"
    huge.write_bytes(magic + (10**9).to_bytes(8, "little") + data[len(magic) + 8 :])
    with pytest.raises(ValueError, match=r"header length \(1000000000 bytes\) exceeds the file"):
        read_artefact(huge)
    listed = tmp_path / "list.contact"  # valid JSON, not an object: was an AttributeError
    listed.write_bytes(magic + (6).to_bytes(8, "little") + b"[1, 2]" + b"payload")
    with pytest.raises(ValueError, match=r"the header is not a JSON object"):
        read_artefact(listed)


def test_a_pre_checksum_header_is_checked_by_load(deployed, tmp_path):
    """A file written before headers had a checksum is read without that check, so
    ``deploy.load`` checks what it reads from the header (an audit: a missing ``state``
    was a KeyError, a payload that is no program a ``struct.error``, neither naming the
    file)."""
    from jax_contact import deploy
    from jax_contact.export import FORMAT, MAGIC, read_artefact, write_artefact

    header, payload = read_artefact(deployed["artefact"])
    old = {k: v for k, v in header.items() if k not in ("header_sha256", "payload_sha256")}
    old = {k: v for k, v in old.items() if k != "payload_bytes"}

    def rewritten(name, head, body=payload):
        path = write_artefact(tmp_path / name, head, body)
        # write_artefact adds a header checksum; an older file has none.
        data = path.read_bytes()
        start = len(MAGIC) + 8
        n = int.from_bytes(data[len(MAGIC) : start], "little")
        head_json = json.loads(data[start : start + n])
        del head_json["header_sha256"]
        text = json.dumps(head_json).encode()
        path.write_bytes(MAGIC + len(text).to_bytes(8, "little") + text + bytes(body))
        return path

    no_state = rewritten("no_state.contact", {k: v for k, v in old.items() if k != "state"})
    with pytest.raises(
        ValueError, match=r"no_state\.contact': its header lacks or garbles KeyError 'state'"
    ):
        deploy.load(no_state, compile=False)
    # The rate edited (a helper's trial): it loaded and said 250 Hz, the program 400.
    edited = rewritten("rate.contact", old | {"rate_hz": 250.0})
    with pytest.raises(ValueError, match=r"rate\.contact': its header's rate_hz \(250\) disagrees"):
        deploy.load(edited, compile=False)
    fewer = rewritten("fewer.contact", old | {"readings": old["readings"][:2]})
    with pytest.raises(
        ValueError, match=r"fewer\.contact': the header's state, key and readings do not"
    ):
        deploy.load(fewer, compile=False)
    not_a_program = rewritten("abc.contact", {"format": FORMAT, "format_version": 1}, b"abc")
    with pytest.raises(ValueError, match=r"abc\.contact': its header lacks"):
        deploy.load(not_a_program, compile=False)
    garbage = rewritten("garbage.contact", old, b"abc")
    with pytest.raises(
        ValueError, match=r"garbage\.contact': its payload is not an exported program"
    ):
        deploy.load(garbage, compile=False)
    word = rewritten("word.contact", old | {"format_version": "two"})
    with pytest.raises(ValueError, match=r"word\.contact': format_version 'two' is not an integer"):
        deploy.load(word, compile=False)
    # The file as written, without its header checksum, still loads and runs.
    assert (
        deploy.load(rewritten("plain.contact", old), compile=False).header["robot"]
        == header["robot"]
    )


def test_deploy_check_compares_the_physics_not_the_name(deployed):
    """A log is of the export's robot when their physics' fingerprints agree: an export of
    ``--model PATH`` (its source a path) of Go1 was warned about on Go1's own log."""
    from jax_contact.envs.robots import load_robot
    from jax_contact.robot import model_fingerprint
    from jax_contact.train.deploy_cmd import _other_robot

    robot = deployed["header"]["robot"]
    _, attrs = read_log(deployed["log"])
    go1 = model_fingerprint(load_robot("go1").mj_model)
    assert robot["model_sha256"] == attrs["model_sha256"] == go1
    as_path = {**robot, "source": "/robots/go1/scene.xml"}
    assert _other_robot("log", "x.contact", as_path, attrs) is None
    spot = {"robot": "spot", "model_sha256": "0" * 64}
    said = _other_robot("log", "x.contact", robot, spot)
    assert "is of robot 'spot', 'x.contact' of 'go1'" in said
    edited = {"robot": "go1", "model_sha256": "0" * 64}
    assert "of other physics" in _other_robot("log", "x.contact", robot, edited)
    old = {k: v for k, v in robot.items() if k != "model_sha256"}  # an export before them
    assert _other_robot("log", "x.contact", old, attrs) is None
    assert "robot 'spot'" in _other_robot("log", "x.contact", old, spot)


def test_deploy_check_of_an_export_whose_model_moved_says_so(deployed, tmp_path):
    """An export of ``--model PATH`` names that path; moved, deploy-check's log loader
    suggested --robot, which deploy-check has not (a helper's trial). The export's model is
    loaded first and its failure named as such."""
    from jax_contact.export import read_artefact, write_artefact
    from jax_contact.train.deploy_cmd import deploy_check

    header, payload = read_artefact(deployed["artefact"])
    head = {k: v for k, v in header.items() if k not in ("header_sha256", "payload_sha256")}
    head = {k: v for k, v in head.items() if k != "payload_bytes"}
    gone = tmp_path / "robots" / "hexa.xml"
    moved = write_artefact(
        tmp_path / "moved.contact", head | {"robot": head["robot"] | {"source": str(gone)}}, payload
    )
    with pytest.raises(
        ValueError,
        match=r"moved\.contact' was exported for the model '.*hexa\.xml', which cannot be"
        r" loaded \(.*\): deploy-check replays",
    ):
        deploy_check(moved, deployed["log"], pace=False, steps=3)


def test_deploy_check_says_recording_options_do_nothing_on_a_log(deployed, capsys):
    """--units deg on a simulate log ran as if not given, without a word (a helper's audit)."""
    from jax_contact.train import deploy_cmd

    deploy_cmd.deploy_check(
        deployed["artefact"], deployed["log"], steps=3, pace=False, units="deg", resample=True
    )
    out = capsys.readouterr().out
    assert "note: --units and --resample read a recording's columns;" in out
    assert "is a `jax-contact simulate` log" in out


def test_deploy_check_reports_latency_and_agreement(deployed, live, tmp_path, monkeypatch):
    from jax_contact.train import deploy_cmd

    replays = []

    def recorded(*args, **kwargs):
        replays.append(real(*args, **kwargs))
        return replays[-1]

    real = deploy_cmd.realtime_replay
    monkeypatch.setattr(deploy_cmd, "realtime_replay", recorded)
    out = tmp_path / "check.json"
    res = deploy_cmd.deploy_check(deployed["artefact"], deployed["log"], json_path=out)
    saved = json.loads(out.read_text())
    # The summary is of the replay's own per-call latencies, one per step.
    (rt,) = replays
    lat_us = 1e6 * rt["latency_s"]
    assert lat_us.shape == (N_STEPS,)
    assert saved["latency_us"] == pytest.approx(
        {"median": np.median(lat_us), "p99": np.percentile(lat_us, 99),
         "p999": np.percentile(lat_us, 99.9), "max": lat_us.max()}
    )  # fmt: skip
    assert saved["deadline_misses"] == rt["deadline_misses"]
    assert saved["max_abs_diff"] <= P_TOL
    assert res["steps"] == N_STEPS
    assert saved["cpus"] == sorted(os.sched_getaffinity(0))  # what --cpu pins is recorded


def test_deploy_check_fails_with_exit_1_when_the_programs_disagree(deployed, tmp_path, monkeypatch):
    """The check passes by default (round-off ~1e-6 against --max-diff 1e-2) and exits 1,
    naming the pass mark, when the offline estimate is moved by 0.05 on one output or set to
    NaN on another (the exported file's own output is left as it is)."""
    from jax_contact.train import cli, deploy_cmd

    argv = ["deploy-check", str(deployed["artefact"]), str(deployed["log"]), "--no-pace"]
    out = tmp_path / "check.json"
    assert cli.main([*argv, "--steps", "20", "--json", str(out)]) == 0
    saved = json.loads(out.read_text())
    assert saved["passed"] and saved["failed"] == [] and saved["nan_mismatches"] == 0
    assert saved["max_diff_allowed"] == deploy_cmd.MAX_DIFF == 1e-2
    assert saved["max_misses_allowed"] is None

    real = deploy_cmd.offline_estimate

    def moved(*args, **kwargs):
        p = np.array(real(*args, **kwargs))
        p[5, 1] += 0.05 if p[5, 1] < 0.5 else -0.05
        p[7, 2] = np.nan
        return p

    monkeypatch.setattr(deploy_cmd, "offline_estimate", moved)
    assert cli.main([*argv, "--steps", "20", "--json", str(out)]) == deploy_cmd.EXIT_CHECK_FAILED
    saved = json.loads(out.read_text())
    assert not saved["passed"]
    assert saved["max_abs_diff"] == pytest.approx(0.05, abs=P_TOL)
    assert saved["nan_mismatches"] == 1
    assert [f.split(" (")[0] for f in saved["failed"]] == [
        f"max |P(contact) - offline estimate| {saved['max_abs_diff']:.2e} > 0.01",
        "1 outputs are NaN in one program and a number in the other",
    ]
    # A wider pass mark takes the 0.05 (the NaN still fails).
    assert cli.main([*argv, "--steps", "20", "--max-diff", "0.1"]) == 1


def test_deploy_check_of_another_robots_log_fails(deployed, tmp_path, capsys):
    """A log of other physics (here Go1's log with another fingerprint) was warned about
    and then "passed", exit 0 (a helper's trial on a Barkour export and a Go1 log): the
    agreement holds, but nothing was checked on the export's robot."""
    from jax_contact.train import cli

    arrays, attrs = read_log(deployed["log"])
    other = write_log(tmp_path / "other.h5", arrays, {**attrs, "model_sha256": "0" * 64})
    out = tmp_path / "check.json"
    argv = ["deploy-check", str(deployed["artefact"]), str(other), "--no-pace", "--steps", "20"]
    assert cli.main([*argv, "--json", str(out)]) == 1
    saved = json.loads(out.read_text())
    assert saved["max_abs_diff"] <= P_TOL and not saved["passed"]
    assert saved["failed"][0].startswith("the log is not of the export's robot")
    assert "of other physics" in saved["warnings"][0]
    assert "FAILED: the log is not of the export's robot" in capsys.readouterr().out


def test_deploy_check_pass_marks_by_hand():
    """:func:`_check_failures` on hand-made results: deadline misses only when asked; NaN
    (nothing compared) fails."""
    from jax_contact.train.deploy_cmd import _check_failures

    base = {"max_abs_diff": 3e-4, "nan_mismatches": 0, "deadline_misses": 7, "rate_hz": 400.0}
    assert _check_failures(base, 1e-3, None) == []
    assert _check_failures(base, 1e-3, 7) == []
    (why,) = _check_failures(base, 1e-3, 6)
    assert why == "7 deadline misses > 6 (--max-misses) at 400 Hz"
    (why,) = _check_failures(base, 1e-4, None)
    assert why.startswith("max |P(contact) - offline estimate| 3.00e-04 > 0.0001 (--max-diff)")
    (why,) = _check_failures({**base, "max_abs_diff": float("nan")}, 1e-3, None)
    assert why == "no reading gave both programs a P(contact) to compare"


class _TimedEstimator:
    """An estimator whose k-th call after its latest ``init`` takes ``durations[k]`` s of a
    fake clock; calls before that ``init`` (the warm-up) take none. Its P(contact) is the
    reading."""

    reading_names = ("x",)
    feet = ("foot",)

    def __init__(self, clock, durations):
        self.clock, self.durations, self.inits, self.calls = clock, durations, 0, 0

    def init(self):
        self.inits, self.calls = self.inits + 1, 0
        return None

    def update(self, belief, reading):
        if self.inits % 2 == 0:  # realtime_replay inits twice: the warm-up, then the replay
            self.clock[0] += self.durations[self.calls]
        self.calls += 1
        diag = {"p_dynamics": [0.5], "p_diff_kinematics": [0.5], "valid": [True]}
        diag["force"] = [[0.0, 0.0, -10.0]]  # the exported update also gives the force
        return belief, np.array([reading["x"]], np.float32), diag


def test_realtime_replay_paces_calls_and_counts_missed_deadlines(monkeypatch):
    """Calls released every 10 ms of a fake clock (from t0); call k takes 4, 13, 2, 25, 1
    ms. Hand count, ms after t0: call 0 runs 0-4 (deadline 10), call 1 runs 10-23 (deadline
    20: missed), call 2 starts late, 23-25 (deadline 30), call 3 runs 30-55 (deadline 40:
    missed), call 4 starts at 55 (its release, 40, is past), 55-56 (deadline 50: missed).
    Three misses; each latency is the call's own time. Back to back (no pacing): none."""
    import time

    from jax_contact.train.deploy_cmd import realtime_replay

    clock = [0.0]

    def perf_counter():
        clock[0] += 1e-9  # a clock that moves, so the pacing's spin always ends
        return clock[0]

    def sleep(s):
        clock[0] += s

    monkeypatch.setattr(time, "perf_counter", perf_counter)
    monkeypatch.setattr(time, "sleep", sleep)
    durations = [0.004, 0.013, 0.002, 0.025, 0.001]
    est = _TimedEstimator(clock, durations)
    readings = {"x": np.arange(5, dtype=np.float32)}
    rt = realtime_replay(est, readings, period_s=0.010, spin_s=0.0)
    np.testing.assert_allclose(rt["latency_s"], durations, atol=1e-8)
    assert rt["deadline_misses"] == 3
    np.testing.assert_array_equal(rt["p_contact"][:, 0], readings["x"])
    rt = realtime_replay(est, readings, period_s=0.010, pace=False)
    np.testing.assert_allclose(rt["latency_s"], durations, atol=1e-8)
    assert rt["deadline_misses"] == 0


def test_deploy_check_reads_a_recording_and_warns_as_estimate(deployed, live, tmp_path, capsys):
    """The module's log written as a recording of named columns (a real robot's log) runs
    through the artefact like the log itself: the same P(contact), so the same share of
    steps in contact per foot as the offline replay of the log (``live``). Its columns are
    checked as ``jax-contact estimate`` checks them, and a recording without torques is
    refused (the exported dynamics term would read zeros)."""
    from jax_contact.train.deploy_cmd import deploy_check, is_recording
    from jax_contact.train.logs import load_log
    from jax_contact.train.recording import write_recording_csv
    from jax_contact.train.recording_convert import log_to_columns

    cols = log_to_columns(load_log(deployed["log"]), env=0)
    write_recording_csv(tmp_path / "rec.csv", cols)
    res = deploy_check(deployed["artefact"], tmp_path / "rec.csv", pace=False)
    assert res["steps"] == N_STEPS and res["max_abs_diff"] <= P_TOL and not res["warnings"]
    want = np.mean(live > 0.5, axis=0)
    got = np.array(list(res["contact_share"].values()))
    assert list(res["contact_share"]) == list(deployed["header"]["robot"]["feet"])
    np.testing.assert_allclose(got, want, atol=1.0 / N_STEPS)  # one step's flag, rounding
    assert "share of steps estimated in contact (P > 0.5): FR " in capsys.readouterr().out
    # An HDF5 recording is told from a simulate log (which also has a time dataset).
    with h5py.File(tmp_path / "rec.h5", "w") as f:
        for name, col in cols.items():
            f[name] = col  # "q/FR_hip_joint" is the dataset FR_hip_joint of group q
    assert is_recording(tmp_path / "rec.h5") and not is_recording(deployed["log"])
    # A knee in degrees: estimate's warning, printed before the replay.
    damaged = {**cols, "q/FR_calf_joint": np.rad2deg(cols["q/FR_calf_joint"])}
    write_recording_csv(tmp_path / "deg.csv", damaged)
    deploy_check(deployed["artefact"], tmp_path / "deg.csv", pace=False, steps=20)
    assert "warning: column 'q/FR_calf_joint': outside the range" in capsys.readouterr().out
    # One leg's torques negated: the torque check, from the exported update's own terms.
    fr = [k for k in cols if k.startswith("tau/FR_")]
    write_recording_csv(tmp_path / "fr.csv", {**cols, **{k: -cols[k] for k in fr}})
    res = deploy_check(deployed["artefact"], tmp_path / "fr.csv", pace=False)
    assert res["warnings"] and res["warnings"][0].startswith("the dynamics term reads air")
    assert "(FR 9" in res["warnings"][0] and f"[{', '.join(fr)}]" in res["warnings"][0]
    # ... and its push, from the exported update's force: the negated leg pulls.
    assert re.search(r"\(FR 9\d% air, median push -\d", res["warnings"][0])
    no_tau = {k: v for k, v in cols.items() if not k.startswith("tau/")}
    write_recording_csv(tmp_path / "no_tau.csv", no_tau)
    with pytest.raises(ValueError, match=r"no_tau.csv' has no tau/ column .* dynamics term"):
        deploy_check(deployed["artefact"], tmp_path / "no_tau.csv", pace=False)
    # One column missing: the message names that joint (it said "some actuated joint").
    one_gone = {k: v for k, v in cols.items() if k != "tau/RL_calf_joint"}
    write_recording_csv(tmp_path / "one_gone.csv", one_gone)
    with pytest.raises(ValueError, match=r"for the actuated joint\(s\) \['RL_calf_joint'\]"):
        deploy_check(deployed["artefact"], tmp_path / "one_gone.csv", pace=False)
    # Columns whose absence `estimate` meets by leaving a term out: the export runs every
    # term, so deploy-check refuses them, naming the term and the reason (it ran the
    # dynamics on positions differenced twice and "agreed" at 0.40 accuracy).
    for dropped, term, why in (
        (("qd/", "qdd/"), "dynamics", "second differences of positions"),
        (("base_pos/",), "kinematics", "no base position"),
    ):
        part = {k: v for k, v in cols.items() if not k.startswith(dropped)}
        write_recording_csv(tmp_path / "part.csv", part)
        with pytest.raises(
            ValueError,
            match=rf"part.csv' cannot feed the exported estimator's {term} term \(.*{why}",
        ):
            deploy_check(deployed["artefact"], tmp_path / "part.csv", pace=False)
    with pytest.raises(ValueError, match="argument --env: a recording holds one robot"):
        deploy_check(deployed["artefact"], tmp_path / "rec.csv", env=1)
    # Epoch timestamps: float64 rounds 1.7e9 + k 2.5 ms to 2.4e-7 s, so the median step
    # is a few 1e-5 off 400 Hz (a user trial's recording was refused at 399.991 Hz). It runs
    # at the export's rate, with a note, and agrees as well; 2 % off is refused.
    epoch = {**cols, "time": 1.7e9 + cols["time"]}
    write_recording_csv(tmp_path / "epoch.csv", epoch)
    capsys.readouterr()
    res = deploy_check(deployed["artefact"], tmp_path / "epoch.csv", pace=False)
    assert res["max_abs_diff"] <= P_TOL and res["rate_hz"] == 400.0
    assert "Hz (its median step)" in capsys.readouterr().out
    write_recording_csv(tmp_path / "slow.csv", {**cols, "time": cols["time"] * 1.02})
    with pytest.raises(ValueError, match=r"at 392\.157 Hz but .* 400 Hz \(more than 1 % apart"):
        deploy_check(deployed["artefact"], tmp_path / "slow.csv", pace=False)


def test_cli_arguments_are_checked_without_jax(tmp_path, capsys):
    import argparse

    from jax_contact.train import deploy_cmd

    parser = argparse.ArgumentParser()
    deploy_cmd.add_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["export", "--robot", "go1", "--out", str(tmp_path / "x.bin")])
    with pytest.raises(ValueError, match="--out.*.contact"):
        args.check(args)
    args = parser.parse_args(
        ["export", "--robot", "go1", "--params", str(tmp_path / "no.json"), "--out", "a.contact"]
    )
    with pytest.raises(ValueError, match="--params"):
        args.check(args)
    args = parser.parse_args(["export", "--robot", "go1", "--rate", "4", "--out", "a.contact"])
    with pytest.raises(ValueError, match=r"argument --rate: 4 Hz; .* at least 10 readings"):
        args.check(args)  # it failed later on "swing_time must exceed dt"
    args = parser.parse_args(["export", "--robot", "go1", "--rate", "1e9", "--out", "a.contact"])
    with pytest.raises(ValueError, match=r"argument --rate: 1e\+09 Hz; at most 100000"):
        args.check(args)  # it wrote a file whose period is 1 ns
    # The library function behind it, called as code: 1 / rate_hz came first (0 was a
    # ZeroDivisionError, a string a TypeError).
    from jax_contact.train.deploy_cmd import export_to_file

    for rate in (0, float("inf"), "400", None):
        with pytest.raises(ValueError, match=r"rate_hz must be a finite number > 0 \(Hz\)"):
            export_to_file(tmp_path / "x.contact", robot="planar_leg", rate_hz=rate)
    assert not (tmp_path / "x.contact").exists()
    # An existing --out is replaced only if it is an export (or empty): another program's
    # .contact file was replaced without a word.
    from jax_contact.export import MAGIC

    assert deploy_cmd.ARTEFACT_MAGIC == MAGIC
    (tmp_path / "other.contact").write_text("contact list of another tool\n")
    args = parser.parse_args(["export", "--robot", "go1", "--out", str(tmp_path / "other.contact")])
    with pytest.raises(ValueError, match=r"--out: '.*other.contact' exists and is no file of"):
        args.check(args)
    for held in (b"", MAGIC + b"\0" * 8):
        (tmp_path / "other.contact").write_bytes(held)
        args.check(args)
    args = parser.parse_args(["export", "--robot", "go1", "--out", ""])
    with pytest.raises(ValueError, match=r"argument --out: an empty name"):
        args.check(args)  # it said "'' is a folder"
    with pytest.raises(SystemExit) as stop:  # --robot and --model together
        parser.parse_args(["export", "--robot", "go1", "--model", "a.xml", "--out", "a.contact"])
    assert stop.value.code == 2
    assert "argument --model: not allowed with argument --robot" in capsys.readouterr().err
    # --model takes a robot name as estimate's and tune's do (it used to say "file 'go1'
    # does not exist"), else an existing MJCF .xml file.
    args = parser.parse_args(["export", "--model", "go1", "--out", str(tmp_path / "a.contact")])
    args.check(args)
    (tmp_path / "r.urdf").write_text("x")
    for model, match in [
        ("go7", r"argument --model: unknown robot 'go7'; valid names: go1"),
        (str(tmp_path / "no.xml"), r"argument --model: MJCF file '.*no.xml' does not exist"),
        (str(tmp_path / "r.urdf"), r"argument --model: '.*r.urdf' must be an MJCF .xml file"),
    ]:
        args = parser.parse_args(["export", "--model", model, "--out", "a.contact"])
        with pytest.raises(ValueError, match=match):
            args.check(args)
    (tmp_path / "a.contact").write_bytes(b"x")
    args = parser.parse_args(["deploy-check", str(tmp_path / "a.contact"), str(tmp_path / "l.h5")])
    with pytest.raises(ValueError, match="argument log"):
        args.check(args)
    (tmp_path / "l.txt").write_text("x")
    args = parser.parse_args(["deploy-check", str(tmp_path / "a.contact"), str(tmp_path / "l.txt")])
    with pytest.raises(ValueError, match=r"argument log: .*l.txt' must end in .csv, .npz, .h5"):
        args.check(args)
    log = tmp_path / "l.h5"
    log.write_bytes(b"x")
    art = str(tmp_path / "a.contact")
    args = parser.parse_args(["deploy-check", art, str(log), "--names", "a"])
    with pytest.raises(ValueError, match="argument --names: 'a' is not log_name=model_name"):
        args.check(args)
    args = parser.parse_args(
        ["deploy-check", str(tmp_path / "a.contact"), str(log), "--cpu", "999"]
    )
    with pytest.raises(ValueError, match="--cpu"):
        args.check(args)
    args = parser.parse_args(["deploy-check", art, str(log), "--no-pace", "--max-misses", "0"])
    with pytest.raises(ValueError, match="argument --max-misses: --no-pace calls back to back"):
        args.check(args)
    for flag, value in (("--max-diff", "0"), ("--max-diff", "nan"), ("--max-misses", "-1")):
        with pytest.raises(SystemExit):
            parser.parse_args(["deploy-check", art, str(log), flag, value])
        assert f"argument {flag}: must be" in capsys.readouterr().err
    code = "import jax_contact.train.deploy_cmd, sys; print('jax' in sys.modules)"
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    assert proc.stdout.strip() == "False", proc.stderr


def test_export_flat_round_trip_with_key():
    """export_flat (the benchmark's export) serialises pytrees and typed keys."""
    import jax
    import jax.numpy as jnp

    from jax_contact.export import export_flat, load_exported

    params = jc.make_params(
        jc.make_noise(3), force_rows=(0, 2), touchdown="monte_carlo", n_samples=16
    )

    def f(belief, key):
        return jax.random.normal(key, (2,)) + belief.logit, belief

    belief = jc.init_belief(params)
    exported, flat = export_flat(f, belief, jax.random.key(1))
    restored = load_exported(exported.serialize())
    got = restored.call(*flat)
    want = jax.tree.leaves(f(belief, jax.random.key(1)))
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(jnp.asarray(b)))
