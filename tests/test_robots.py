"""Robots that load offline, their descriptions, and the height-field floor.

References are independent of the loader: inertias parsed from the shipped XML with
ElementTree, hand-derived masses, and the MuJoCo C library (ray casts, contacts).
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
from mujoco import mjx

from jax_contact.envs.model_files import PLANAR_LEG_XML, playground_xml
from jax_contact.envs.robots import RobotUnavailableError, load_robot, with_terrain
from jax_contact.robot import RobotDescription, derive_description

BUILTIN = ("go1", "spot", "barkour", "planar_leg")


@pytest.fixture(scope="module")
def loaded():
    return {name: load_robot(name) for name in BUILTIN}


def _xml_inertials(path: Path) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """body name -> (mass, COM in body frame, 3x3 inertia about the COM in body frame)."""
    out = {}
    for body in ET.parse(path).getroot().iter("body"):
        inertial = body.find("inertial")
        if inertial is None:
            continue
        quat = np.array([float(x) for x in inertial.get("quat", "1 0 0 0").split()])
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, quat / np.linalg.norm(quat))
        rot = rot.reshape(3, 3)
        diag = np.array([float(x) for x in inertial.get("diaginertia").split()])
        out[body.get("name")] = (
            float(inertial.get("mass")),
            np.array([float(x) for x in inertial.get("pos").split()]),
            rot @ np.diag(diag) @ rot.T,
        )
    return out


def _compiled_inertia(m: mujoco.MjModel, b: int) -> np.ndarray:
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[b])
    rot = rot.reshape(3, 3)
    return rot @ np.diag(m.body_inertia[b]) @ rot.T


# Hand sums of the shipped <inertial> masses: trunk + 4 x (hip + thigh + calf).
#   go1:  5.204 + 4 * (0.68 + 1.009 + 0.195862) = 12.743448 kg
#   spot: 32.86 + 4 * (1.68 + 2.34 + 0.35)      = 50.34 kg
TOTAL_MASS = {"go1": 12.743448, "spot": 50.34}


@pytest.mark.parametrize("name", ["go1", "spot"])
def test_playground_robot_dynamics_as_shipped(loaded, name):
    robot = loaded[name]
    m = robot.mj_model
    xml_dir = playground_xml(name).parent
    reference = _xml_inertials(xml_dir / f"{name}_mjx_feetonly.xml")
    assert len(reference) == m.nbody - 1  # every body but the world has an <inertial>
    for body_name, (mass, com, inertia) in reference.items():
        b = m.body(body_name).id
        np.testing.assert_allclose(m.body_mass[b], mass, rtol=1e-12, err_msg=body_name)
        np.testing.assert_allclose(m.body_ipos[b], com, atol=1e-12, err_msg=body_name)
        np.testing.assert_allclose(
            _compiled_inertia(m, b), inertia, rtol=1e-9, atol=1e-12, err_msg=body_name
        )
    np.testing.assert_allclose(m.body_mass.sum(), TOTAL_MASS[name], rtol=1e-12)

    # Collision geometry: every non-mesh geom of the shipped XML is still there, and no
    # mesh geom or mesh asset is.
    assert m.nmesh == 0
    assert not np.any(m.geom_type == mujoco.mjtGeom.mjGEOM_MESH)
    n_xml_geoms = sum(
        1
        for f in ("scene_mjx_feetonly_flat_terrain.xml", f"{name}_mjx_feetonly.xml")
        for world in ET.parse(xml_dir / f).getroot().iter("worldbody")
        for g in world.iter("geom")
        if g.get("mesh") is None
    )
    assert m.ngeom == n_xml_geoms


def test_playground_feet_as_shipped(loaded):
    # Foot spheres from the shipped default classes: go1 size 0.023 at (0, 0, -0.213),
    # spot size 0.036 at (0, 0, -0.3365).
    for name, radius, z in (("go1", 0.023, -0.213), ("spot", 0.036, -0.3365)):
        desc = loaded[name].description
        assert desc.foot_radii == (radius,) * 4
        assert desc.foot_offsets == ((0.0, 0.0, z),) * 4
    assert loaded["go1"].description.foot_names == ("FR", "FL", "RR", "RL")
    assert loaded["spot"].description.foot_names == ("FL", "FR", "HL", "HR")


@pytest.mark.parametrize("name", ["go1", "spot", "barkour"])
def test_quadruped_descriptions(loaded, name):
    m = loaded[name].mj_model
    desc = loaded[name].description
    assert desc.n_legs == 4 and desc.n_leg_dofs == 3
    assert desc.base_dofs == (0, 1, 2, 3, 4, 5)
    assert (desc.nq, desc.nv) == (m.nq, m.nv) == (19, 18)
    # The twelve leg dofs partition the joints after the free joint.
    assert sorted(d for leg in desc.leg_dofs for d in leg) == list(range(6, 18))
    for leg, other in zip(desc.leg_dofs, desc.other_dofs, strict=True):
        assert sorted(leg + other) == list(range(18))
    for g, b in zip(desc.foot_geom_ids, desc.foot_body_ids, strict=True):
        assert m.geom_bodyid[g] == b and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE
        # each leg's last dof is the joint of the foot's own body
        assert m.dof_bodyid[desc.leg_dofs[desc.foot_body_ids.index(b)][-1]] == b
    # Description is hashable, so it can be a static jit argument.
    assert hash(desc) == hash(derive_description(m))


@pytest.mark.parametrize("name", ["go1", "spot", "barkour", "planar_leg"])
def test_only_feet_touch_the_floor(loaded, name):
    m = loaded[name].mj_model
    desc = loaded[name].description
    floors = desc.floor_geom_ids
    touching = {
        g
        for g in range(m.ngeom)
        if m.geom_bodyid[g] != 0
        and any(
            (m.geom_contype[g] & m.geom_conaffinity[f])
            or (m.geom_contype[f] & m.geom_conaffinity[g])
            for f in floors
        )
    }
    assert touching == set(desc.foot_geom_ids)


def test_planar_leg_matches_table_one(loaded):
    m = loaded["planar_leg"].mj_model
    desc = loaded["planar_leg"].description
    # Table I: base 5.449 kg; thigh 2.48 kg, 3.18e-2 kg m^2, COM 0.043 m; shank 0.31 kg,
    # 1.383e-2 kg m^2, COM 0.039 m; pitch is the y axis.
    for body, mass, inertia_y, com in (
        ("thigh", 2.48, 3.18e-2, 0.043),
        ("shank", 0.31, 1.383e-2, 0.039),
    ):
        b = m.body(body).id
        np.testing.assert_allclose(m.body_mass[b], mass, rtol=1e-12)
        np.testing.assert_allclose(_compiled_inertia(m, b)[1, 1], inertia_y, rtol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(m.body_ipos[b]), com, rtol=1e-12)
    np.testing.assert_allclose(m.body_mass[m.body("base").id], 5.449, rtol=1e-12)
    assert m.opt.timestep == 0.0025
    np.testing.assert_array_equal(m.actuator_ctrlrange, [[-30.0, 30.0], [-30.0, 30.0]])
    np.testing.assert_array_equal(m.numeric("joint_velocity_limit").data, [25.0, 25.0])
    assert desc.n_legs == 1 and desc.leg_dofs == ((1, 2),) and desc.other_dofs == ((0,),)
    assert desc.base_dofs == (0,) and desc.foot_names == ("foot",)
    # Hinges about y, rail along z: the leg stays in the x-z plane.
    np.testing.assert_array_equal(m.jnt_axis, [[0, 0, 1], [0, 1, 0], [0, 1, 0]])


def test_planar_leg_stands_and_only_the_foot_touches():
    robot = load_robot("planar_leg")
    m = robot.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    mujoco.mj_forward(m, d)
    # Keyframe: 0.4327 - (0.25 cos 0.6 + 0.25 cos 0.6) = 0.0200 m, the foot radius.
    assert abs(d.geom_xpos[m.geom("foot").id][2] - 0.02) < 1e-4
    # Fall from 0.1 m higher with the knee folding under zero torque: every contact is
    # foot-floor.
    d.qpos[0] += 0.1
    pairs = set()
    for _ in range(400):
        mujoco.mj_step(m, d)
        pairs |= {tuple(sorted((c.geom1, c.geom2))) for c in d.contact[: d.ncon]}
    assert pairs == {(m.geom("floor").id, m.geom("foot").id)}


FIXED_LEG_XML = Path(__file__).parent / "fixtures" / "fixed_leg.xml"


def test_fixed_base_leg_has_no_base_coordinates():
    """A leg bolted to the world: its actuated hip is a leg joint, not the base's (the
    planar leg's passive rail stays its base, test above)."""
    from jax_contact.envs.feet import describe

    m = mujoco.MjModel.from_xml_path(str(FIXED_LEG_XML))
    for desc in (derive_description(m), describe(m)[0]):
        assert desc.leg_dofs == ((0, 1),) and desc.other_dofs == ((),)
        assert desc.base_dofs == () and desc.base_body_id == 0


def _hold_fixed_leg(m, d, target) -> np.ndarray:
    """Resets ``d`` to the fixed leg's joint ``target`` and holds it there for 2 s (PD,
    settled) in C MuJoCo; returns the floor's force on the foot, world frame, N
    (``mj_contactForce`` over the contacts)."""
    mujoco.mj_resetData(m, d)
    d.qpos[:] = target
    for _ in range(800):
        d.ctrl[:] = np.clip(20.0 * (np.asarray(target) - d.qpos) - d.qvel, -30, 30)
        mujoco.mj_step(m, d)
    f_on_foot = np.zeros(3)
    for i in range(d.ncon):
        c = np.zeros(6)
        mujoco.mj_contactForce(m, d, i, c)
        f_on_foot += d.contact[i].frame.reshape(3, 3).T @ c[:3]
    return f_on_foot


def test_fixed_base_leg_force_is_the_floors():
    """The dynamics term on a fixed-base leg (no other coordinates: empty base blocks)
    gives the contact force MuJoCo's C library resolves (``mj_contactForce``), and its
    default parameters treat both joints as joints (``anymal_like``: 0.3 rad/s each)."""
    import jax.numpy as jnp

    from jax_contact import adapter
    from jax_contact.measurement import dynamics_llr
    from jax_contact.train.log_estimator import default_estimator

    m = mujoco.MjModel.from_xml_path(str(FIXED_LEG_XML))
    d = mujoco.MjData(m)
    desc = derive_description(m)
    params, _ = default_estimator(desc, 0.0025, mj_model=m)
    np.testing.assert_allclose(np.asarray(params.noise.sigma_qd), [0.3, 0.3], rtol=1e-6)
    assert tuple(params.force_rows) == (0, 2)  # a leg in the x-z plane
    normal = jnp.array([0.0, 0.0, 1.0])
    mx = mjx.put_model(m)
    # Pressed: a PD hold whose pose would put the sole 9 mm below the floor
    # (0.40 - 0.2 cos 0.3 - 0.2 cos(-0.15) - 0.02 = -0.009 m before the leg yields);
    # lifted: the knee folded, the foot 0.1 m up.
    for target, pressed in (((0.3, -0.45), True), ((0.5, -1.6), False)):
        f_on_foot = _hold_fixed_leg(m, d, target)
        dx = adapter.prepare(mx, mjx.put_data(m, d))
        meas = adapter.robot_measurement(
            mx, dx, desc, qdd=jnp.asarray(d.qacc), tau=jnp.asarray(d.qfrc_actuator)
        )
        llr, force = dynamics_llr(params, meas.leg(0), normal)
        if pressed:
            assert f_on_foot[2] > 20.0  # the ground carries the leg's push
            # The force the foot exerts on the ground is minus the floor's on the foot.
            np.testing.assert_allclose(np.asarray(force)[[0, 2]], -f_on_foot[[0, 2]], atol=1.0)
            assert float(llr) > 0.5
        else:
            assert d.ncon == 0
            np.testing.assert_allclose(np.asarray(force)[[0, 2]], 0.0, atol=1.0)
            assert float(llr) < 0.0


WAIST_BIPED_XML = Path(__file__).parent / "fixtures" / "waist_biped.xml"


def _waist_forces(target, desc=None):
    """The waist biped held at joint ``target`` (waist, left hip, knee, right hip, knee)
    for 2 s by its position servos (settled); returns ``(feet, {foot: (eq. 6's force the
    foot exerts on the ground, N; the dynamics term's log-odds)})``, feet as MuJoCo's C
    library resolves the floor's force on them (``mj_contactForce``, world frame, N).
    ``desc``: a description of the model other than its own."""
    import jax.numpy as jnp

    from jax_contact import adapter
    from jax_contact.measurement import dynamics_llr
    from jax_contact.train.log_estimator import default_estimator

    m = mujoco.MjModel.from_xml_path(str(WAIST_BIPED_XML))
    d = mujoco.MjData(m)
    desc = desc or derive_description(m)
    d.qpos[:] = target
    d.ctrl[:] = target
    for _ in range(800):
        mujoco.mj_step(m, d)
    assert np.abs(d.qvel).max() < 1e-3  # settled
    feet = {}
    for i in range(d.ncon):
        c = np.zeros(6)
        mujoco.mj_contactForce(m, d, i, c)
        name = m.geom(d.contact[i].geom2).name
        feet[name] = feet.get(name, 0.0) + d.contact[i].frame.reshape(3, 3).T @ c[:3]
    params, _ = default_estimator(desc, 0.0025, mj_model=m)
    mx = mjx.put_model(m)
    dx = adapter.prepare(mx, mjx.put_data(m, d))
    meas = adapter.robot_measurement(
        mx, dx, desc, qdd=jnp.asarray(d.qacc), tau=jnp.asarray(d.qfrc_actuator)
    )
    normal = jnp.array([0.0, 0.0, 1.0])
    est = {}
    for leg, foot in enumerate(desc.foot_names):
        llr, force = dynamics_llr(params, meas.leg(leg), normal)
        est[foot] = (np.asarray(force), float(llr))
    return feet, est


def test_a_waist_above_both_legs_belongs_to_neither():
    """A joint on the chains of two feet (tests/fixtures/waist_biped.xml: a pitching waist
    above two 2-joint legs) carries both feet's forces, while eq. 6 explains a leg's
    torques by its own foot's alone: it counts with the base, in each foot's ``b``
    (jax_contact.robot.split_legs), for the log commands' and the wrapper's descriptions.
    Against MuJoCo's C library (mj_contactForce), settled, measured on this host:

    - both feet pressed (each 62.9 N): eq. 6's force is the floor's to 0.05 N; with the
      waist in both legs (the rule before), 5.7 N off: the waist's torque holds both
      feet's moment about it, and each leg's fit takes it for its own;
    - the left foot pressed, the right one lifted: the lifted foot's force is 0 and its
      dynamics term says air (log-odds -0.82); with the waist in its leg the waist's
      torque, the left foot's moment, reads as a push under the right foot (-0.13).
    """
    import dataclasses

    m = mujoco.MjModel.from_xml_path(str(WAIST_BIPED_XML))
    from jax_contact.envs.feet import describe

    for desc in (derive_description(m), describe(m)[0]):
        # dofs: waist 0, left hip 1, knee 2, right hip 3, knee 4
        assert desc.leg_dofs == ((1, 2), (3, 4)), desc.leg_dofs
        assert desc.other_dofs == ((0, 3, 4), (0, 1, 2))
    shared = dataclasses.replace(
        derive_description(m), leg_dofs=((0, 1, 2), (0, 3, 4)), other_dofs=((3, 4), (1, 2))
    )
    pressed, lifted = (0.3, -0.45), (0.5, -1.6)  # the fixed-leg test's two holds
    both = (0.0, *pressed, *pressed)
    feet, own = _waist_forces(both)
    _, old = _waist_forces(both, shared)
    for foot in ("l_foot", "r_foot"):
        assert feet[foot][2] > 30.0
        # The force the foot exerts on the ground is minus the floor's on the foot.
        np.testing.assert_allclose(own[foot][0][[0, 2]], -feet[foot][[0, 2]], atol=0.5)
        assert np.abs(old[foot][0][[0, 2]] + feet[foot][[0, 2]]).max() > 3.0
    one = (0.0, *pressed, *lifted)
    feet, own = _waist_forces(one)
    _, old = _waist_forces(one, shared)
    assert set(feet) == {"l_foot"} and feet["l_foot"][2] > 30.0
    np.testing.assert_allclose(own["l_foot"][0][[0, 2]], -feet["l_foot"][[0, 2]], atol=0.5)
    np.testing.assert_allclose(own["r_foot"][0], 0.0, atol=0.1)
    assert own["r_foot"][1] < -0.5  # the lifted foot reads as air
    assert old["r_foot"][1] > own["r_foot"][1] + 0.4  # the waist's load read as its push


def test_two_feet_on_one_leg_are_refused():
    """Two feet that share every joint (a toe and a heel sphere on one shin, named as two
    feet) have no joint of their own to resolve either force: refused, naming both."""
    toe = '<geom name="toe" type="sphere" pos="0.03 0 -0.2" size="0.02" mass="0.01"/>'
    foot = '<geom name="foot" type="sphere" pos="0 0 -0.2" size="0.02" mass="0.05"/>'
    text = FIXED_LEG_XML.read_text()
    m = mujoco.MjModel.from_xml_string(text.replace(foot, foot + toe))
    with pytest.raises(ValueError, match="foot 'foot' has no actuated joint of its own.*'toe'"):
        derive_description(m, foot_names=("foot", "toe"))


def test_robot_mass_leaves_static_scenery_out(tmp_path):
    """model_mass counts the bodies that move: the fixed leg's hip 0.8 kg, shin 0.3 kg and
    foot 0.05 kg = 1.15 kg (the fixture's masses). A 300 kg staircase body welded to the
    world (Go1's Playground stairs scene has one) and a mocap target are scenery, not
    robot; a free box is a body that moves, so it counts (5 kg)."""
    from jax_contact.robot import model_mass

    text = FIXED_LEG_XML.read_text()
    scenery = (
        '<body name="stairs" pos="1 0 0.1"><geom type="box" size=".2 .2 .1" mass="300"/></body>'
        '<body name="target" mocap="true"><geom type="sphere" size=".01" mass="2"'
        ' contype="0" conaffinity="0"/></body>'
    )
    floor = '<geom name="floor" type="plane" size="2 2 0.1"/>'
    assert text.count(floor) == 1
    m = mujoco.MjModel.from_xml_string(text.replace(floor, floor + scenery))
    assert model_mass(m) == pytest.approx(1.15, abs=1e-9)
    assert load_robot(
        _write(tmp_path / "leg.xml", text.replace(floor, floor + scenery))
    ).description.mass_kg == pytest.approx(1.15, abs=1e-9)
    free = (
        '<body name="box" pos="0.5 0 0.2"><freejoint/>'
        '<geom type="box" size=".05 .05 .05" mass="5"/></body>'
    )
    m = mujoco.MjModel.from_xml_string(text.replace(floor, floor + free))
    assert model_mass(m) == pytest.approx(6.15, abs=1e-9)


def _write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


def test_a_box_sole_through_load_robot_gives_the_floors_force(tmp_path):
    """The log commands take a flat foot (load_robot: the feet as the wrapper resolves
    them). The fixed leg with a 8 x 4 x 2 cm box for a foot, pressed by the PD hold of the
    test above: its shin pitches by hip + knee = -0.15 rad, so the sole stands on one
    edge, which the rolling contact point follows (adapter.contact_points). A 2-joint leg
    resolves a force at one point in its plane; at that edge it equals the force
    MuJoCo's C library resolves on the two corners touching (mj_contactForce). Read at
    the sole's centre instead, the same torques are explained by a force at the wrong
    point: the centre lies h = 4 cm cos 0.15 along the sole from the edge. Measured on
    this host: 0.03 / 0.05 N (x / z) off MuJoCo's 15.5 / 135.3 N at the edge, 16 / 31 N at
    the centre."""
    import jax.numpy as jnp

    from jax_contact import adapter
    from jax_contact.measurement import dynamics_llr
    from jax_contact.train.log_estimator import default_estimator

    sphere = '<geom name="foot" type="sphere" pos="0 0 -0.2" size="0.02" mass="0.05"/>'
    box = '<geom name="foot" type="box" pos="0 0 -0.21" size="0.04 0.02 0.01" mass="0.05"/>'
    text = FIXED_LEG_XML.read_text()
    assert text.count(sphere) == 1
    (tmp_path / "box_leg.xml").write_text(text.replace(sphere, box))
    robot = load_robot(str(tmp_path / "box_leg.xml"))
    desc, m = robot.description, robot.mj_model
    assert desc.foot_names == ("foot",) and len(desc.foot_soles[0]) == 4
    for bad in ("foot", ()):  # a str or nothing: named, not "no sphere geom" (user trial)
        with pytest.raises(ValueError, match="foot_names must be a non-empty sequence of names"):
            load_robot(str(tmp_path / "box_leg.xml"), foot_names=bad)
    params, _ = default_estimator(desc, 0.0025, mj_model=m)
    d = mujoco.MjData(m)
    f_on_foot = _hold_fixed_leg(m, d, (0.3, -0.45))  # pressed, as in the test above
    assert d.ncon == 2 and f_on_foot[2] > 20.0  # one edge: two corners carry the push
    mx = mjx.put_model(m)
    dx = adapter.prepare(mx, mjx.put_data(m, d))
    normal = jnp.array([0.0, 0.0, 1.0])
    errors = {}
    for sole in ("rolling", "centre"):
        meas = adapter.robot_measurement(
            mx, dx, desc, qdd=jnp.asarray(d.qacc), tau=jnp.asarray(d.qfrc_actuator), sole=sole
        )
        llr, force = dynamics_llr(params, meas.leg(0), normal)
        errors[sole] = np.abs(np.asarray(force)[[0, 2]] + f_on_foot[[0, 2]])
        if sole == "rolling":
            # The point is on the touching edge: its height is the corners' (MuJoCo's
            # contact positions, at the floor up to the penetration).
            z_edge = np.mean([d.contact[i].pos[2] for i in range(d.ncon)])
            assert abs(float(meas.p_f[0, 2]) - z_edge) < 2e-3
            assert float(llr) > 0.5
    np.testing.assert_array_less(errors["rolling"], 1.0)
    assert errors["centre"].max() > 5.0 * max(errors["rolling"].max(), 0.2), errors


def test_a_log_replayed_on_an_edited_model_warns(tmp_path):
    """Simulated logs store the model's physics fingerprint; two loads of a robot agree,
    a heavier calf does not, and load_log warns when the robot's name loads differently
    (it replayed through the edited model silently)."""
    import shutil
    import warnings

    import h5py

    from jax_contact.robot import model_fingerprint
    from jax_contact.train.logs import load_log

    go1 = load_robot("go1").mj_model
    assert model_fingerprint(go1) == model_fingerprint(load_robot("go1").mj_model)
    heavier = load_robot("go1").mj_model
    heavier.body_mass[heavier.body("FR_calf").id] += 0.05
    assert model_fingerprint(heavier) != model_fingerprint(go1)
    log = tmp_path / "log.h5"
    shutil.copy(Path(__file__).parent / "fixtures" / "planar_leg_hop.h5", log)
    planar = load_robot("planar_leg").mj_model
    with h5py.File(log, "a") as f:
        f.attrs["model_sha256"] = model_fingerprint(planar)
    with warnings.catch_warnings():  # the same model: silent
        warnings.simplefilter("error")
        load_log(log)
    with h5py.File(log, "a") as f:
        f.attrs["model_sha256"] = model_fingerprint(go1)
    with pytest.warns(UserWarning, match="differs from the one the log was simulated with"):
        load_log(log)
    # Read through another shipped robot (a user trial: Go1's log with --robot unitree_go2
    # printed F1 0.26 after a warning about a changed model): refused, both named.
    with h5py.File(log, "a") as f:
        f.attrs["model_sha256"] = model_fingerprint(planar)
        del f.attrs["foot_names"]  # the other robot's own feet, so the loading gets there
    with pytest.raises(ValueError, match=r"simulated with robot 'planar_leg'; robot 'go1' is"
                       r" another model .*--robot planar_leg or without --robot"):  # fmt: skip
        load_log(log, robot="go1")
    # The log names a model file that has moved (another machine): the error says how to
    # name it; named, the log loads, its fingerprint checked as before.
    moved = tmp_path / "models" / "leg.xml"
    moved.parent.mkdir()
    shutil.copy(PLANAR_LEG_XML, moved)
    with h5py.File(log, "a") as f:
        f.attrs["robot"] = str(tmp_path / "gone" / "leg.xml")
        f.attrs["model_sha256"] = model_fingerprint(planar)
    with pytest.raises(
        ValueError, match="does not exist; if its model moved, name it with --robot"
    ):
        load_log(log)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_log(log, robot=str(moved)).robot.description.n_legs == 1


def test_simulate_refuses_feet_that_leave_a_leg_limp():
    from jax_contact.envs.gaits import make_gait
    from jax_contact.envs.simulate import check_gait_fits

    robot = load_robot("go1", foot_names=["FR", "FL", "RR"])
    with pytest.raises(ValueError, match=r"actuated joints \['RL_calf_joint'.*name every foot"):
        check_gait_fits(make_gait("trot"), robot)
    check_gait_fits(make_gait("trot"), load_robot("go1"))  # all four: accepted


def test_a_rough_floor_mjx_cannot_collide_is_refused_naming_the_geoms(tmp_path):
    """A user trial's Menagerie Go2 (foot spheres with margin="0.001") crashed with MJX's
    traceback ("(mjGEOM_HFIELD, mjGEOM_SPHERE) margin/gap not implemented") on the rough
    scenario, minutes into `reproduce`. build_world now refuses it naming the geoms, and
    reproduce checks every scenario before Section III (check_scenarios)."""
    from jax_contact.envs.simulate import build_world
    from jax_contact.train.reproduce import ReproduceConfig, check_scenarios

    xml = PLANAR_LEG_XML.read_text().replace(
        '<geom name="foot" type="sphere"', '<geom name="foot" margin="0.001" type="sphere"'
    )
    path = tmp_path / "leg.xml"
    path.write_text(xml)
    build_world(str(path))  # a plane takes the margin
    foot = r"foot \(sphere, body shank\)"
    want = rf"rough floor: geoms .*{foot}.* margin or gap \({foot}: margin 0.001, gap 0\)"
    with pytest.raises(ValueError, match=want + r".*margin=\"0\""):
        build_world(str(path), terrain="rough")
    with pytest.raises(
        ValueError, match=r"^Table III scenario 'trot': gait 'trot' needs two or more legs"
    ):
        check_scenarios(ReproduceConfig(robot=str(path)))  # one leg: no trot, said first


def test_simulate_names_the_feet_it_found_and_a_foot_above_the_others():
    """simulate without --feet prints the feet the rule found; a sole well above the
    others at the home pose is named (a user trial's Go2 without one foot geom walked on
    that leg's shin sphere, silently)."""
    import mujoco

    from jax_contact.train.logs import note_found_feet

    robot = load_robot("go1")
    assert note_found_feet(robot) == (
        "note: feet found in the model: ['FR', 'FL', 'RR', 'RL'] (name them with --feet)"
    )
    # RL's knee bent 0.5 rad further in the home keyframe lifts its foot: by the C
    # library's kinematics (the reference), its sole is then h above the lowest.
    m = robot.mj_model
    key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    adr = m.jnt_qposadr[m.joint("RL_calf_joint").id]
    m.key_qpos[key, adr] -= 0.5
    d = mujoco.MjData(m)
    d.qpos[:] = m.key_qpos[key]
    mujoco.mj_kinematics(m, d)
    z = [d.geom_xpos[m.geom(n).id][2] for n in ("FR", "FL", "RR", "RL")]
    h = z[3] - min(z[:3])
    assert h > 0.03
    line = note_found_feet(robot)
    assert line.splitlines()[1].startswith(
        f"warning: at the home pose some soles are above the lowest (RL {1e3 * h:.0f} mm)"
    )


def test_a_foot_of_corner_spheres_is_one_sole_as_in_the_wrapper(tmp_path):
    """T1's feet are four corner spheres on one body. Found or named by the body, the log
    commands take the four as one sole, as the wrapper does (feet.describe): the rolling
    point of their centres, one radius. Naming one sphere keeps that sphere. With a corner
    sole of one low sphere and three 2 cm higher (beyond feet.SOLE_SPREAD, 1 cm), the
    rule finds the low sphere alone and simulate's note names the body that reads all
    four. Here a leg (rail, hip, knee)
    whose shank carries four spheres of radius 1 cm at x = +-4 cm, y = +-2 cm, 0.3 m
    down."""
    from jax_contact.envs import feet
    from jax_contact.train.logs import note_found_feet

    def leg(*z: float) -> str:
        corners = "".join(
            f'<geom name="c{i}" type="sphere" size=".01" pos="{x} {y} {zi}"/>'
            for i, (x, y, zi) in enumerate(
                zip((0.04, 0.04, -0.04, -0.04), (0.02, -0.02, 0.02, -0.02), z, strict=True)
            )
        )
        path = tmp_path / f"corners{z[1]}.xml"
        path.write_text(
            "<mujoco><worldbody><geom name='floor' type='plane' size='1 1 .1'/>"
            "<body name='base'><joint type='slide' axis='0 0 1'/><geom type='box'"
            " size='.1 .1 .1' mass='1'/><body name='b'><joint name='j' type='hinge'/>"
            "<inertial pos='0 0 -.1' mass='.5' diaginertia='.01 .01 .01'/><body name='shank'>"
            "<joint name='k' type='hinge'/><inertial pos='0 0 -.2' mass='.2'"
            f" diaginertia='.01 .01 .01'/>{corners}</body></body></body></worldbody><actuator>"
            "<motor joint='j'/><motor joint='k'/></actuator></mujoco>"
        )
        return str(path)

    level = leg(-0.3, -0.3, -0.3, -0.3)
    corners = sorted((x, y, -0.3) for x in (0.04, -0.04) for y in (0.02, -0.02))
    for names in (None, ["shank"]):
        sole = load_robot(level, foot_names=names)
        desc = sole.description
        assert desc.foot_names == ("shank",) and desc.foot_radii == (0.01,)
        np.testing.assert_allclose(desc.foot_offsets[0], (0.0, 0.0, -0.3), atol=1e-12)
        assert sorted(desc.foot_soles[0]) == corners
        assert desc == feet.describe(sole.mj_model, names)[0]
    assert "several floor-touching" not in note_found_feet(load_robot(level))
    one = load_robot(level, foot_names=["c3"]).description
    assert one.foot_names == ("c3",) and one.foot_offsets[0] == (-0.04, -0.02, -0.3)
    raised = load_robot(leg(-0.3, -0.28, -0.28, -0.28))
    assert raised.description.foot_names == ("c0",)
    assert note_found_feet(raised).splitlines()[-1] == (
        "note: the feet's bodies carry several floor-touching spheres (shank (4)): each foot"
        " above is one of them; --feet shank reads each body's spheres as one sole"
    )


def test_short_air_phases_by_hand():
    from jax_contact.metrics import short_air_phases

    # Air at step 0 (cut by the start: not counted), steps 5-6 (2 steps, short), 10-15
    # (6 steps), and 18-19 (cut by the end).
    truth = np.ones((20, 1, 1), bool)
    truth[0] = truth[5:7] = truth[10:16] = truth[18:] = False
    valid = np.ones((20, 1, 1), bool)
    assert short_air_phases(truth, valid, 4) == (1, 2)
    valid[12] = False  # splits 10-15: neither part lies between two valid contact steps
    assert short_air_phases(truth, valid, 4) == (1, 1)


def test_unknown_name_lists_valid_ones():
    with pytest.raises(ValueError, match="unknown robot 'go3'") as err:
        load_robot("go3")
    for name in ("go1", "spot", "barkour", "planar_leg", "anybotics_anymal_c"):
        assert name in str(err.value)


def test_menagerie_without_package_or_root(monkeypatch):
    monkeypatch.delenv("MENAGERIE_ROOT", raising=False)
    monkeypatch.setitem(sys.modules, "mujoco_menagerie", None)  # import raises ImportError
    with pytest.raises(RobotUnavailableError, match="MENAGERIE_ROOT") as err:
        load_robot("anybotics_anymal_c")
    assert isinstance(err.value, ValueError)
    assert "anybotics_anymal_c" in str(err.value)


def test_menagerie_root(monkeypatch, tmp_path):
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    with pytest.raises(RobotUnavailableError, match="no anybotics_anymal_c/scene.xml"):
        load_robot("anybotics_anymal_c")
    # A checkout with the model in it loads (the planar leg stands in for ANYmal here).
    (tmp_path / "anybotics_anymal_c").mkdir()
    (tmp_path / "anybotics_anymal_c" / "scene.xml").write_text(PLANAR_LEG_XML.read_text())
    robot = load_robot("anybotics_anymal_c")
    assert robot.mj_model.nv == 3 and robot.description.foot_names == ("foot",)


def test_load_from_path(tmp_path):
    robot = load_robot(str(PLANAR_LEG_XML))
    assert robot.description == load_robot("planar_leg").description
    missing = tmp_path / "nope.xml"
    with pytest.raises(ValueError, match="nope.xml"):
        load_robot(str(missing))
    with pytest.raises(ValueError, match="is a folder; name the .xml file in it"):
        load_robot(str(tmp_path) + "/")
    # A URDF, as .xml or .urdf: named as such (as .xml it was "mj_model has no floor").
    urdf = '<?xml version="1.0"?>\n<!-- r -->\n<robot name="r"><link name="base"/></robot>\n'
    for name in ("r.xml", "r.urdf"):
        (tmp_path / name).write_text(urdf)
        with pytest.raises(ValueError, match=f"'.*{name}' is a URDF \\(root element <robot>\\)"):
            load_robot(str(tmp_path / name))


def test_a_missing_mesh_file_says_why_it_was_needed(tmp_path):
    """A visual mesh on a body that takes its mass from its geoms cannot be dropped, so its
    file is read: the error names the folder it is read from and why (it was MuJoCo's
    "Error opening file" alone)."""
    xml = (
        "<mujoco><asset><mesh name='shell' file='meshes/shell.stl'/></asset><worldbody>"
        "<geom type='plane' size='1 1 .1'/><body name='base' pos='0 0 .3'><freejoint/>"
        "<geom type='box' size='.1 .1 .02'/><geom type='mesh' mesh='shell' contype='0'"
        " conaffinity='0'/></body></worldbody></mujoco>"
    )
    (tmp_path / "shell.xml").write_text(xml)
    why = r"shell.stl.*relative to '.*', or to the compiler's meshdir; the visual meshes could"
    with pytest.raises(ValueError, match=why + r" not be dropped: body 'base' takes"):
        load_robot(str(tmp_path / "shell.xml"))


def test_every_builtin_quadruped_stands_on_a_plane_at_zero(loaded):
    # The reproduction's flat scenarios need a flat floor. Barkour's scene (MJX's test data)
    # ships random blocks, a height field of 0-5 cm; load_robot swaps it for a plane.
    for name in ("go1", "spot", "barkour"):
        m, desc = loaded[name].mj_model, loaded[name].description
        assert m.nhfield == 0, name
        (floor,) = desc.floor_geom_ids
        assert int(m.geom_type[floor]) == int(mujoco.mjtGeom.mjGEOM_PLANE), name
        np.testing.assert_array_equal(m.geom_pos[floor], 0.0)
        np.testing.assert_array_equal(m.geom_quat[floor], [1.0, 0.0, 0.0, 0.0])
    # The swap keeps what the feet touch: the floor collides with them as the blocks did.
    m = loaded["barkour"].mj_model
    (floor,) = loaded["barkour"].description.floor_geom_ids
    for g in loaded["barkour"].description.foot_geom_ids:
        assert m.geom_contype[g] & m.geom_conaffinity[floor] or (
            m.geom_contype[floor] & m.geom_conaffinity[g]
        )


def test_barkour_foot_names_by_body(loaded):
    m = loaded["barkour"].mj_model
    names = ("lower_leg_1to1_hind_left", "lower_leg_1to1_front_right")
    desc = derive_description(m, names)
    assert desc.foot_names == names
    assert [m.body(b).name for b in desc.foot_body_ids] == list(names)


def _mjcf(
    body: str,
    floor: str = '<geom name="floor" type="plane" size="1 1 .1"/>',
    actuator: str = '<actuator><motor joint="j"/></actuator>',
    base: str = "<geom type='box' size='.1 .1 .1' mass='1'/>",
) -> mujoco.MjModel:
    """A base on a slide rail, one hinged leg body holding ``body``, a floor."""
    return mujoco.MjModel.from_xml_string(
        f"<mujoco><worldbody>{floor}<body name='base'><joint type='slide'/>"
        f"{base}<body name='b'><joint name='j' type='hinge'/>"
        "<inertial pos='0 0 -.1' mass='.5' diaginertia='.01 .01 .01'/>"
        f"{body}</body></body></worldbody>{actuator}</mujoco>"
    )


def test_description_refusals(loaded):
    foot = '<geom name="toe" type="sphere" size=".02" pos="0 0 -.3"/>'
    # A sphere on the base (no joint between it and the base) can touch the floor: no foot.
    with pytest.raises(ValueError, match="no floor contact through a leg"):
        derive_description(_mjcf("", base="<geom type='sphere' size='.1' mass='1'/>"))
    with pytest.raises(ValueError, match="no floor"):
        derive_description(_mjcf(foot, floor=""))
    with pytest.raises(ValueError, match="no floor contact: no sphere geom"):
        derive_description(_mjcf(foot.replace("/>", ' contype="0" conaffinity="0"/>')))
    with pytest.raises(ValueError, match=r"none of its leg's joints \['.*'\] is driven by a joint"
                       " actuator \\(the model has no joint actuator at all\\)"):  # fmt: skip
        derive_description(_mjcf(foot, actuator=""))
    assert derive_description(_mjcf(foot)).foot_names == ("toe",)
    with pytest.raises(ValueError, match=r"'heel'.*valid names: \['FL', 'FL_calf'"):
        derive_description(loaded["go1"].mj_model, ["FL", "heel"])
    with pytest.raises(ValueError, match="same foot twice"):
        derive_description(loaded["go1"].mj_model, ["FL", "FL_calf"])


def test_description_is_frozen(loaded):
    desc = loaded["go1"].description
    assert isinstance(desc, RobotDescription)
    with pytest.raises(AttributeError):
        desc.nv = 3


@pytest.fixture(scope="module")
def rough_go1(loaded):
    rng = np.random.default_rng(7)
    heights = rng.uniform(-0.03, 0.05, size=(21, 31))
    return heights, with_terrain(loaded["go1"], heights, (3.0, 2.0))


def test_terrain_heights_as_requested(rough_go1, loaded):
    heights, robot = rough_go1
    m = robot.mj_model
    span = heights.max() - heights.min()
    np.testing.assert_allclose(robot.terrain.heights, heights, atol=1e-6 * span)
    # Independent check: cast rays straight down with the C library at sample points.
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    geom_id = np.zeros(1, np.int32)
    ny, nx = heights.shape
    for r, c in ((0, 0), (10, 15), (20, 30), (3, 27)):
        x = -3.0 + 6.0 * c / (nx - 1)
        y = -2.0 + 4.0 * r / (ny - 1)
        floor_group = np.array([1, 0, 0, 0, 0, 0], np.uint8)  # the robot's geoms are group 3
        dist = mujoco.mj_ray(
            m, d, np.array([x, y, 1.0]), np.array([0, 0, -1.0]), floor_group, 1, -1, geom_id
        )
        assert geom_id[0] == m.geom("floor").id
        np.testing.assert_allclose(1.0 - dist, heights[r, c], atol=1e-6)
    # The floor sensors still name the floor, and the input robot is unchanged.
    assert m.nsensor == loaded["go1"].mj_model.nsensor
    assert m.geom_type[robot.description.floor_geom_ids[0]] == mujoco.mjtGeom.mjGEOM_HFIELD
    assert loaded["go1"].mj_model.geom_type[0] == mujoco.mjtGeom.mjGEOM_PLANE
    assert robot.description.foot_geom_ids == loaded["go1"].description.foot_geom_ids


def test_terrain_constant_and_refusals(loaded):
    robot = with_terrain(loaded["planar_leg"], np.full((3, 4), 0.1), (1.0, 1.0))
    np.testing.assert_allclose(robot.terrain.heights, 0.1, atol=1e-9)
    with pytest.raises(ValueError, match="heights must have shape"):
        with_terrain(loaded["planar_leg"], np.zeros(5), (1.0, 1.0))
    with pytest.raises(ValueError, match="size_xy"):
        with_terrain(loaded["planar_leg"], np.zeros((3, 3)), (0.0, 1.0))
    with pytest.raises(ValueError, match="finite"):
        with_terrain(loaded["planar_leg"], np.full((3, 3), np.nan), (1.0, 1.0))


def test_put_model_smoke(loaded, rough_go1):
    for robot in (*loaded.values(), rough_go1[1]):
        mm = mjx.put_model(robot.mj_model)
        assert (mm.nq, mm.nv) == (robot.mj_model.nq, robot.mj_model.nv)


def _all_sphere_quadruped() -> mujoco.MjModel:
    """Every collision geom a sphere (as in Menagerie's Go2 MJX model): hip, two on the
    thigh, two along the calf and the foot at its end, plus one on the base."""
    legs = ""
    for leg, (x, y) in {"FR": (0.2, -0.1), "FL": (0.2, 0.1), "RR": (-0.2, -0.1)}.items():
        legs += f"""
        <body name="{leg}_hip" pos="{x} {y} 0"><joint axis="1 0 0"/>
          <inertial pos="0 0 0" mass=".5" diaginertia=".001 .001 .001"/>
          <geom type="sphere" size=".04"/>
          <body name="{leg}_thigh"><joint axis="0 1 0"/>
            <inertial pos="0 0 -.1" mass=".8" diaginertia=".004 .004 .001"/>
            <geom type="sphere" size=".03" pos="0 0 -.05"/>
            <geom type="sphere" size=".03" pos="0 0 -.15"/>
            <body name="{leg}_calf" pos="0 0 -.2"><joint pos="0 0 0" axis="0 1 0"/>
              <inertial pos="0 0 -.1" mass=".2" diaginertia=".002 .002 .0005"/>
              <geom type="sphere" size=".015" pos="0 0 -.07"/>
              <geom name="{leg}" type="sphere" size=".02" pos="0 0 -.2"/>
              <geom type="sphere" size=".015" pos="0 0 -.13"/>
            </body></body></body>"""
    xml = f"""<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>
      <body name="base" pos="0 0 .5"><freejoint/>
        <inertial pos="0 0 0" mass="5" diaginertia=".02 .05 .06"/>
        <geom type="sphere" size=".08"/>{legs}
      </body></worldbody></mujoco>"""
    spec = mujoco.MjSpec.from_string(xml)
    for j in spec.joints:
        if j.type == mujoco.mjtJoint.mjJNT_HINGE:
            j.name = j.name or f"{j.parent.name}_joint"
            spec.add_actuator(target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    return spec.compile()


def test_feet_of_an_all_sphere_model_are_the_distal_spheres():
    m = _all_sphere_quadruped()
    desc = derive_description(m)
    # Nine spheres per leg chain can touch the floor; the foot is the calf's sphere
    # farthest from the knee (0.2 m below it, the others 0.07 and 0.13 m).
    assert desc.foot_names == ("FR", "FL", "RR")
    assert desc.n_leg_dofs == 3 and desc.foot_radii == (0.02,) * 3
    assert desc.foot_offsets == ((0.0, 0.0, -0.2),) * 3
    assert desc == derive_description(m, ["FR", "FL", "RR"])


def test_feet_that_never_lift_are_named():
    """Sole heights by hand (T 3, 2 envs, 3 feet): foot a swings 4 cm in env 1; foot b
    never rises above 0.4 mm (a user's "trot" whose knee range, in degrees read as
    radians, held every foot on the floor); foot c rises 6 cm only on a step after env
    0's fall, which is not scored, so it is named too, at its 3 mm. A log whose every
    step is invalid names nothing (no height at all)."""
    from jax_contact.train.logs import LIFT_M, feet_that_never_lift

    assert LIFT_M == 0.005
    dist = np.zeros((3, 2, 3))
    dist[1, 1, 0] = 0.04
    dist[:, :, 1] = 0.0004
    dist[2, 0, 2], dist[0, 1, 2] = 0.06, 0.003
    valid = np.array([[True, True], [True, True], [False, True]])
    assert feet_that_never_lift(dist, valid, ["a", "b", "c"]) == {"b": 0.4, "c": 3.0}
    assert feet_that_never_lift(dist, np.zeros((3, 2), bool), ["a", "b", "c"]) == {}
