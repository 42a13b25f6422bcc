"""One source of parameters (jax_contact.params_for) and the versioned parameter file."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jax_contact as jc
import jax_contact.params_file  # noqa: F401  (the package imports its submodules lazily)
from jax_contact.envs.robots import load_robot
from jax_contact.envs.sensors import sensor_preset

DT = 0.0025


@pytest.fixture(scope="module")
def go1():
    return load_robot("go1").description


def test_params_for_derives_the_noise_from_the_sensors(go1):
    """Hand derivation for Go1 with the anymal_like sensors at 400 Hz (jax_contact.envs.sensors):
    joints q 0.02 rad white, no drift -> 0.02; base linear q 0.01 m white with a 0.01
    m/sqrt(s) drift over 10 s -> sqrt(0.01^2 + 0.01^2 * 10) = 0.0332 m; joint qd 0.3 ->
    qdd sqrt(2) 0.3 / 0.0025 = 169.7 rad/s^2; base linear qdd is the accelerometer's 0.5
    m/s^2, not a differenced velocity; sigma_d = sqrt(2^2 + 0.5^2) = 2.062 N m on the
    joints (torque noise 0.5 N m). Outliers 1e-3 per sample on 3-joint legs: eps =
    clip(2 * 3 * 1e-3, 0.01, 0.5) = 0.01; width 2 * 10 rad/s / dt = 8000 rad/s^2."""
    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    p = jc.params_for(go1, sp, DT)
    n = p.noise
    joint = 6
    np.testing.assert_allclose(n.sigma_q[joint], 0.02, rtol=1e-6)
    np.testing.assert_allclose(n.sigma_q[2], math.sqrt(0.01**2 + 0.01**2 * 10), rtol=1e-6)
    np.testing.assert_allclose(n.sigma_qdd[joint], math.sqrt(2) * 0.3 / DT, rtol=1e-6)
    np.testing.assert_allclose(n.sigma_qdd[0], 0.5, rtol=1e-6)
    np.testing.assert_allclose(n.sigma_d[joint], math.hypot(2.0, 0.5), rtol=1e-6)
    np.testing.assert_allclose(float(p.outlier_prob), 0.01, rtol=1e-6)
    np.testing.assert_allclose(float(p.outlier_qdd), 8000.0, rtol=1e-6)
    assert float(p.dt) == pytest.approx(DT) and p.touchdown == "quadrature"


def test_sensor_noise_floor_is_the_sensors_white_noise(go1):
    """Hand derivation (anymal_like, 400 Hz, as above): the floor is what one reading
    carries, without the bias drift: joint q 0.02 rad, base linear q 0.01 m (not 0.0332),
    base linear qd 0.05 m/s (params_for: 0.081 with the drift), joint qd 0.3 rad/s, joint
    qdd sqrt(2) 0.3 / 0.0025 = 169.7 rad/s^2, base linear qdd the accelerometer's 0.5,
    sigma_d the torque sensors' 0.5 N m (no 2 N m model error). params_for's stds are
    never below it."""
    from jax_contact.defaults import sensor_noise_floor

    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    floor = sensor_noise_floor(go1, sp, DT)
    assert set(floor) == {"sigma_q", "sigma_qd", "sigma_qdd", "sigma_d"}
    joint = 6
    np.testing.assert_allclose(floor["sigma_q"][[2, joint]], [0.01, 0.02], rtol=1e-6)
    np.testing.assert_allclose(floor["sigma_qd"][[0, joint]], [0.05, 0.3], rtol=1e-6)
    np.testing.assert_allclose(floor["sigma_qdd"][joint], math.sqrt(2) * 0.3 / DT, rtol=1e-6)
    np.testing.assert_allclose(floor["sigma_qdd"][0], 0.5, rtol=1e-6)
    np.testing.assert_allclose(floor["sigma_d"][joint], 0.5, rtol=1e-6)
    noise = jc.params_for(go1, sp, DT).noise
    for field, values in floor.items():
        assert np.all(np.asarray(getattr(noise, field)) >= values * (1 - 1e-6)), field
    with pytest.raises(ValueError, match="dt"):
        sensor_noise_floor(go1, sp, 0.0)


def test_wrapper_and_reproduction_use_the_same_parameters(go1):
    from jax_contact.envs.wrapper import default_estimator_params
    from jax_contact.train.reproduce import quadruped_estimator_params

    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    a = default_estimator_params(go1, DT, sp)
    b = quadruped_estimator_params(go1, DT)
    for x, y in zip(
        jc.params_file.params_to_dict(a)["noise"].values(),
        jc.params_file.params_to_dict(b)["noise"].values(),
        strict=True,
    ):
        np.testing.assert_array_equal(x, y)
    assert jc.params_file.params_to_dict(a)["values"] == jc.params_file.params_to_dict(b)["values"]


def test_params_for_names_bad_input(go1):
    sp = sensor_preset("anymal_like", 12, dt=DT, floating_base=False)
    with pytest.raises(ValueError, match=r"sensors.sigma_q has shape \(12,\), expected \(18,\)"):
        jc.params_for(go1, sp, DT)
    with pytest.raises(ValueError, match="sensors has no field 'sigma_q'"):
        jc.params_for(go1, object(), DT)
    with pytest.raises(ValueError, match="GaitPrior.stance_time"):
        jc.GaitPrior(stance_time=-1.0)
    planar = load_robot("planar_leg").description
    sp = sensor_preset("anymal_like", planar.nv, dt=DT, floating_base=False, base_dofs=(0,))
    with pytest.raises(ValueError, match="pass force_rows"):
        jc.params_for(planar, sp, DT)
    # A 2-joint leg spans two force axes; a third made the force estimate blow up.
    with pytest.raises(ValueError, match=r"force_rows \(0, 1, 2\): legs of 2 joints span at"):
        jc.params_for(planar, sp, DT, force_rows=(0, 1, 2))
    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    for bad in ("x", None):
        with pytest.raises(ValueError, match="dt must be a finite float > 0"):
            jc.params_for(go1, sp, bad)
    # NumPy scalars are numbers (they were refused as not int | float).
    p = jc.params_for(go1, sp, np.float32(DT), contact_timeconst=np.float32(0.02),
                      gait=jc.GaitPrior(stance_time=np.float32(0.3)))  # fmt: skip
    assert float(p.stance_time) == pytest.approx(0.3) and float(p.dt) == pytest.approx(DT)
    # So is a concrete 0-d JAX array (refused with 'must be a finite float > 0, got
    # Array(0.0025)'), giving the same parameters as the float.
    q = jc.params_for(go1, sp, jnp.float32(DT), contact_timeconst=np.float32(0.02),
                      gait=jc.GaitPrior(stance_time=np.float32(0.3)))  # fmt: skip
    for a, b in zip(jax.tree.leaves(p), jax.tree.leaves(q), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match=r"desc must be a RobotDescription .*MjModel without"):
        jc.params_for(load_robot("go1").mj_model, sp, DT)
    # The sensor model of another period: its velocities are differenced at 2.5 ms, so a
    # 20 ms sigma_qdd (8x smaller) was silently wrong.
    with pytest.raises(ValueError, match=r"sensors\.dt = 0\.0025 s but dt = 0\.02 s"):
        jc.params_for(go1, sp, 0.02)
    # Static flags and sequences are typed: bool("no") and tuple("dynamics") were accepted.
    noise = p.noise
    with pytest.raises(ValueError, match="unilateral must be True or False, got 'no'"):
        jc.make_params(noise, unilateral="no")
    with pytest.raises(ValueError, match="terms must be a sequence .* got 'dynamics'"):
        jc.make_params(noise, terms="dynamics")


def test_params_file_round_trip(go1, tmp_path):
    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    p = jc.params_for(
        go1, sp, DT, touchdown="monte_carlo", n_samples=64, min_push=12.5, slip_prob=0.1
    )
    path = jc.save_params(tmp_path / "go1.json", p, provenance={"by": "test"})
    q = jc.load_params(path)
    da, db = jc.params_file.params_to_dict(p), jc.params_file.params_to_dict(q)
    assert da["noise"] == db["noise"] and da["values"] == db["values"]
    assert da["options"] == db["options"] and q.n_samples == 64
    assert float(q.min_push) == 12.5 and float(q.slip_prob) == np.float32(0.1)
    assert json.loads(path.read_text())["provenance"] == {"by": "test"}
    # A file written before min_push (the sign rule) and the sliding contact loads with
    # the values that reproduce its model: 0 (that rule) and 0 (the still foot).
    old = json.loads(path.read_text())
    for field in ("min_push", "slip_prob", "slip_speed"):
        del old["values"][field]
    (tmp_path / "old.json").write_text(json.dumps(old))
    old_p = jc.load_params(tmp_path / "old.json")
    assert float(old_p.min_push) == 0.0 and float(old_p.slip_prob) == 0.0


def test_save_params_refuses_invalid_params_and_names_an_unwritable_path(go1, tmp_path):
    """A NaN would be written as null and the file would not load: refused before writing,
    naming the field and its value as a plain number; an unwritable destination is named
    (not the temporary file beside it)."""
    p = jc.params_for(go1, sensor_preset("anymal_like", go1.nv, dt=DT), DT)
    with pytest.raises(ValueError, match=r"^stance_time must be a finite scalar > 0, got nan$"):
        jc.save_params(tmp_path / "nan.json", p.replace(stance_time=np.float32(np.nan)))
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(OSError, match=r"cannot create '.*file/sub/p\.json'"):
        jc.save_params(tmp_path / "file" / "sub" / "p.json", p)
    # A provenance that is not JSON (a str, a Calibration object) or that load_params would
    # refuse: named, and nothing written (the last were written and could not be read back).
    cal = jc.Calibration(temperature=1.2, temperature_air=2.0)
    for bad, said in (
        ("tuned by hand", r"provenance must be a mapping .* got str"),
        ({"calibration": cal}, r"provenance\['calibration'\] is not a JSON value \(a Calib"),
        ({"robot_mass_kg": 0}, r"bad\.json: provenance field 'robot_mass_kg' must be a positive"),
        ({"robot_mass_kg": float("nan")}, r"provenance\['robot_mass_kg'\] must be a positive"),
        ({"calibration": {"kind": "sign"}}, r"bad\.json': provenance field 'calibration'"),
        ({"terrain_model": "stairs"}, r"bad\.json': provenance field 'terrain_model'"),
    ):
        with pytest.raises(ValueError, match=said):
            jc.save_params(tmp_path / "bad.json", p, bad)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["file"]
    jc.save_params(tmp_path / "ok.json", p, {"calibration": cal.as_dict(), "n": np.int64(3)})
    assert jc.load_params(tmp_path / "ok.json", with_provenance=True)[1]["n"] == 3


def test_bad_params_file_names_the_field(go1, tmp_path):
    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    payload = jc.params_file.params_to_dict(jc.params_for(go1, sp, DT))
    cases = {
        "missing": (lambda d: d["values"].pop("cap_transition"), "missing field.*cap_transition"),
        "extra": (lambda d: d["noise"].update(sigma_x=[1.0]), "unknown field.*sigma_x"),
        "bad value": (lambda d: d["values"].update(cap_transition=2.0), "cap_transition"),
        "bad shape": (lambda d: d["noise"].update(sigma_qd=[0.3] * 3), "sigma_qd"),
        # The offending entry, not the smallest (an Infinity among 10s read 'got min 10').
        "inf": (
            lambda d: d["noise"].update(sigma_f=[float("inf"), 10.0, 10.0]),
            "noise.sigma_f must be finite and > 0 everywhere, got non-finite inf",
        ),
        "bad nv": (lambda d: d.update(nv=5), "nv is 5 but every per-dof noise vector has 18"),
        "version": (lambda d: d.update(version=99), "version 99"),
        "top-level": (lambda d: d.update(notes="x"), r"unknown top-level key\(s\) \['notes'\]"),
        "provenance": (lambda d: d.update(provenance=[1]), "'provenance' must be a mapping"),
        # A value of the wrong type: named (it was "could not convert string to float").
        "string": (
            lambda d: d["values"].update(stance_time="fast"),
            "values.stance_time must be a number, got 'fast'",
        ),
        "string in list": (
            lambda d: d["noise"]["sigma_q"].__setitem__(2, "abc"),
            r"noise.sigma_q must be a number or a list of numbers, got \[.*'abc'",
        ),
        "bool": (lambda d: d["values"].update(dt=True), "values.dt must be a number, got True"),
        "section type": (
            lambda d: d.update(values=[1.0]),
            "section 'values' must be a JSON object of fields, got list",
        ),
        "mass": (
            lambda d: d["provenance"].update(robot_mass_kg="heavy"),
            "'robot_mass_kg' must be a positive number of kg.*'heavy'",
        ),
        # Refused on reading as save_params refuses to write them (the wrapper and the
        # commands refused them only after using the file: a dt warning came first).
        "calibration": (
            lambda d: d["provenance"].update(calibration={"kind": "sign"}),
            "provenance field 'calibration'",
        ),
        "terrain model": (
            lambda d: d["provenance"].update(terrain_model="stairs"),
            r"provenance field 'terrain_model' must be one of \(.*\), got 'stairs'",
        ),
    }
    for name, (mutate, pattern) in cases.items():
        d = json.loads(json.dumps(payload))
        mutate(d)
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(d))
        with pytest.raises(ValueError, match=pattern) as err:
            jc.load_params(path)
        assert str(path) in str(err.value), name
    # Checked against a robot at another period: refused before any warning about it.
    d = json.loads(json.dumps(payload))
    d["provenance"]["calibration"] = {"kind": "sign"}
    (tmp_path / "cal.json").write_text(json.dumps(d))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="cal.json'?: provenance field 'calibration'"):
            jc.params_file.load_params_for(tmp_path / "cal.json", nv=go1.nv, dt=2 * DT)
    (tmp_path / "not.json").write_text("{")
    with pytest.raises(ValueError, match="is not JSON"):
        jc.load_params(tmp_path / "not.json")
    with pytest.raises(ValueError, match=r"does not exist$"):
        jc.load_params(tmp_path / "absent.json")
    # The preset's name with a suffix (a helper's audit: no hint that "go1" is one).
    with pytest.raises(
        ValueError, match=r"'.*go1.json' does not exist \(the preset is named 'go1'\)"
    ):
        jc.load_params(tmp_path / "go1.json")


def test_contact_force_std_is_at_most_a_share_of_a_foots_load(go1):
    """sigma_f = min(10 N, 0.4 m g / n_legs): Go1 (12.74 kg, 0.4 x 31.2 N = 12.5 N) keeps
    10 N; a 5 kg quadruped gets 0.4 x 5 x 9.81 / 4 = 4.905 N; a description without a mass
    10 N, as before the rule."""
    import dataclasses

    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    assert go1.mass_kg == pytest.approx(12.74, abs=0.01)
    np.testing.assert_allclose(np.asarray(jc.params_for(go1, sp, DT).noise.sigma_f), 10.0)
    light = dataclasses.replace(go1, mass_kg=5.0)
    np.testing.assert_allclose(
        np.asarray(jc.params_for(light, sp, DT).noise.sigma_f), 4.905, rtol=1e-6
    )
    unknown = dataclasses.replace(go1, mass_kg=None)
    np.testing.assert_allclose(np.asarray(jc.params_for(unknown, sp, DT).noise.sigma_f), 10.0)
    with pytest.raises(ValueError, match="desc.mass_kg must be a finite number > 0"):
        jc.params_for(dataclasses.replace(go1, mass_kg=-1.0), sp, DT)
    # A string of axes was split into them ("02" -> (0, 2)), an int failed in tuple().
    for rows in ("02", 2):
        with pytest.raises(ValueError, match="force_rows must be a sequence of axes"):
            jc.params_for(go1, sp, DT, force_rows=rows)


def test_a_light_robots_contact_force_std_is_derived_from_its_mass():
    """tests/fixtures/hexapod.xml: base 2 kg + 6 legs x (0.05 + 0.1 + 0.08 + 0.01) kg =
    3.44 kg; sigma_f = 0.4 x 3.44 x 9.81 / 6 = 2.24976 N (10 N would exceed every foot's
    share of the weight, 5.62 N)."""
    robot = load_robot(str(Path(__file__).parent / "fixtures" / "hexapod.xml"))
    desc = robot.description
    assert desc.n_legs == 6 and desc.mass_kg == pytest.approx(3.44, abs=1e-9)
    sp = sensor_preset("anymal_like", desc.nv, dt=DT)
    np.testing.assert_allclose(
        np.asarray(jc.params_for(desc, sp, DT).noise.sigma_f), 2.24976, rtol=1e-6
    )


def test_contact_damping_from_the_contact_time_constant(go1):
    """Critical damping of a contact that settles in T: b = 2 / T (20 ms -> 100 1/s)."""
    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    assert float(jc.params_for(go1, sp, DT).contact_damping) == pytest.approx(100.0)
    p = jc.params_for(go1, sp, DT, contact_timeconst=0.05)
    assert float(p.contact_damping) == pytest.approx(40.0)
    assert float(jc.params_for(go1, sp, DT, contact_timeconst=math.inf).contact_damping) == 0.0
    with pytest.raises(ValueError, match="contact_timeconst"):
        jc.params_for(go1, sp, DT, contact_timeconst=0.0)


def payload_default(field: str) -> float:
    """The value ``params_for`` gives every robot: 2 / 20 ms, and the newest reading."""
    return {"contact_damping": 100.0, "kinematics_lead": 1.0}[field]


@pytest.mark.parametrize("later", ["contact_damping", "kinematics_lead"])
def test_a_file_written_before_a_later_field_loads_with_the_old_model(go1, tmp_path, later):
    """A version-1 file without ``contact_damping`` (written before the stabilised contact)
    loads with 0, the rigid contact it was written with; one without ``kinematics_lead``
    (before the kinematic terms read the newest reading) with 0, every term at the
    interval's start. Every other field is unchanged."""
    sp = sensor_preset("anymal_like", go1.nv, dt=DT)
    payload = jc.params_file.params_to_dict(jc.params_for(go1, sp, DT))
    assert payload["values"][later] > 0.0  # the default is not the old model
    old = json.loads(json.dumps(payload))
    del old["values"][later]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    q = jc.params_file.params_to_dict(jc.load_params(path))
    assert q["values"].pop(later) == 0.0
    payload["values"].pop(later)
    assert q["values"] == payload["values"] and q["noise"] == payload["noise"]
    for name in jc.preset_names():  # written with both fields: the model as it is
        params, prov = jc.load_params(name, with_provenance=True)
        if later in prov["fields"]:  # tuned (Spot's and Barkour's damping): not the old model
            assert float(getattr(params, later)) > 0.0
        else:
            assert float(getattr(params, later)) == payload_default(later)


def test_still_side_cap_is_a_rate_of_evidence(go1):
    """The still side of differential kinematics gives the same evidence per second at any
    period: logit(cap) = logit(0.65) dt / 2.5 ms, at most the air side's 0.9. By hand: at
    5 ms the odds square, (0.65 / 0.35)^2 = 3.449, cap 3.449 / 4.449 = 0.7752; at 1.25 ms
    the square root, sqrt(1.857) = 1.3628, cap 0.5768; at 10 ms the odds would be
    11.9 > 9, so 0.9."""
    from jax_contact.defaults import still_cap

    assert still_cap(0.0025) == pytest.approx(0.65, abs=1e-12)
    assert still_cap(0.005) == pytest.approx(0.7752, abs=1e-4)
    assert still_cap(0.00125) == pytest.approx(0.5768, abs=1e-4)
    assert still_cap(0.01) == pytest.approx(0.9, abs=1e-12)
    for dt, want in ((0.0025, 0.65), (0.02, 0.9)):
        sp = sensor_preset("anymal_like", go1.nv, dt=dt)
        got = float(jc.params_for(go1, sp, dt).cap_diff_kinematics_still)
        assert got == pytest.approx(want, abs=1e-6)


def test_the_still_side_cap_stays_at_most_the_air_sides_at_any_period(go1):
    """A helper's float64 oracle: an air cap set below the still side's was passed by it
    (params_for's override, the still cap clamped to the constant 0.9), and a tuned file
    moved to a slower rate got a still cap above its own air cap. By hand, Spot's preset
    (air 0.876, still 0.660 at 400 Hz) moved to 100 Hz, where the rules' still cap goes
    0.65 -> 0.9: logit 0.663 x 2.197 / 0.619 = 2.35, a cap of 0.913 > 0.876."""
    from jax_contact.defaults import change_period

    for dt, want in ((0.0025, 0.6), (0.01, 0.6)):  # 0.65 and 0.9 without the override
        sp = sensor_preset("anymal_like", go1.nv, dt=dt)
        p = jc.params_for(go1, sp, dt, cap_diff_kinematics=0.6)
        assert float(p.cap_diff_kinematics_still) == pytest.approx(want, abs=1e-6)
    spot = load_robot("spot").description
    tuned = jc.load_params("spot")
    air = float(tuned.cap_diff_kinematics)
    assert float(tuned.cap_diff_kinematics_still) < 0.7 < air < 0.9

    def derived(dt):
        return jc.params_for(spot, sensor_preset("anymal_like", spot.nv, dt=dt), dt)

    moved = change_period(tuned, derived(0.0025), derived(0.01))
    assert float(moved.cap_diff_kinematics) == pytest.approx(air, abs=1e-6)  # 0.9 both
    assert float(moved.cap_diff_kinematics_still) == pytest.approx(air, abs=1e-6)
    # At its own period, and a little slower, the file's value moves as the rules' do.
    same = change_period(tuned, derived(0.0025), derived(0.0025))
    assert float(same.cap_diff_kinematics_still) == float(tuned.cap_diff_kinematics_still)
    odds = float(tuned.cap_diff_kinematics_still) / (1 - float(tuned.cap_diff_kinematics_still))
    want = odds**2 / (1 + odds**2)  # 5 ms: the rules' log-odds double, so the file's do
    slower = change_period(tuned, derived(0.0025), derived(0.005))
    assert float(slower.cap_diff_kinematics_still) == pytest.approx(want, abs=1e-5)


def test_a_saved_file_with_its_robot_provenance_warns_on_another_robot(tmp_path):
    """A helper's audit: Go1's parameters saved with ``jc.save_params`` loaded on Berkeley
    Humanoid (both nv 18) without a word, since only tuned files recorded the robot.
    ``robot_provenance`` records what ``jax-contact tune`` records: Go1's 12.74 kg (its
    moving bodies) and its joints grouped as four legs of three."""
    from jax_contact.params_file import load_params_for, robot_provenance
    from jax_contact.robot import model_mass
    from jax_contact.tune.space import robot_space

    go1, spot = load_robot("go1"), load_robot("spot")
    prov = robot_provenance(go1.mj_model, go1.description, "go1")
    assert prov["robot"] == "go1" and prov["robot_mass_kg"] == pytest.approx(12.743, abs=1e-3)
    assert prov["groups"] == robot_space(go1.description).named_groups()
    assert "robot" not in robot_provenance(go1.mj_model, go1.description)
    p = jc.params_for(go1.description, sensor_preset("anymal_like", go1.description.nv, dt=DT), DT)
    path = jc.save_params(tmp_path / "go1.json", p, provenance=prov)
    with pytest.warns(
        UserWarning, match=r"tuned on a robot of 12\.7 kg \('go1'\); this one weighs 50"
    ):
        load_params_for(
            path, nv=spot.description.nv, dt=DT, mass_kg=model_mass(spot.mj_model), robot="spot"
        )


def test_load_params_of_a_folder_or_of_no_path_is_one_clear_error(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match=r"parameter file '.*' is a folder"):
        jc.load_params(tmp_path)
    (tmp_path / "files").mkdir()  # a one-part name without a suffix: "no preset name" before
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=r"parameter file 'files' is a folder"):
        jc.load_params("files")
    with pytest.raises(ValueError, match="a path or a preset name, got NoneType"):
        jc.load_params(None)
    with pytest.raises(ValueError, match="a path or a preset name, got an empty string"):
        jc.load_params("")


def test_save_params_into_a_folder_names_it_and_writes_nothing(go1, tmp_path):
    p = jc.params_for(go1, sensor_preset("anymal_like", go1.nv, dt=DT), DT)
    (tmp_path / "rt").mkdir()
    with pytest.raises(IsADirectoryError, match=r"cannot create '.*rt': it is a folder"):
        jc.save_params(tmp_path / "rt", p)
    assert [f.name for f in tmp_path.iterdir()] == ["rt"] and not any((tmp_path / "rt").iterdir())


def test_a_calibration_map_without_its_temperature_is_named(tmp_path):
    from jax_contact.calibration import load_calibration

    payload = dict(jc.params_file.read_params("go1").payload)
    payload["provenance"]["calibration"] = {"kind": "sign", "temperature_air": 2.0}
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(payload))
    with pytest.raises(ValueError, match=r"'calibration': calibration: expected a mapping with"
                       r" 'temperature'"):  # fmt: skip
        load_calibration(path)
