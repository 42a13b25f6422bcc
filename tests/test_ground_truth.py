"""Tests of envs/ground_truth.py against C MuJoCo and hand-derived references."""

from __future__ import annotations

import dataclasses
import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from jax_contact.envs.ground_truth import foot_truth, make_truth_layout, with_contact_sensors
from jax_contact.envs.robots import load_robot, with_terrain
from jax_contact.envs.simulate import rough_heights
from jax_contact.robot import derive_description

G = 9.81


def _c_view(m: mujoco.MjModel, d: mujoco.MjData):
    """The fields foot_truth reads, from C MuJoCo data (no MJX, no compile)."""
    return types.SimpleNamespace(
        sensordata=jnp.asarray(d.sensordata),
        geom_xpos=jnp.asarray(d.geom_xpos),
        geom_xmat=jnp.asarray(d.geom_xmat).reshape(m.ngeom, 3, 3),
    )


def _forces_on_geoms(m: mujoco.MjModel, d: mujoco.MjData):
    """Independent reference, C MuJoCo's mj_contactForce: for every contact and each of its
    two geoms, ``(geom, world force on it (3,), normal force)``. The force in the contact
    frame (rows: normal, tangents) acts on geom2; geom1 gets minus it."""
    for i in range(d.ncon):
        c = d.contact[i]
        f6 = np.zeros(6)
        mujoco.mj_contactForce(m, d, i, f6)
        world = c.frame.reshape(3, 3).T @ f6[:3]
        yield int(c.geom1), -world, f6[0]
        yield int(c.geom2), world, f6[0]


@pytest.fixture(scope="module")
def go1():
    robot = with_contact_sensors(load_robot("go1"))
    return robot, make_truth_layout(robot)


@pytest.fixture(scope="module")
def drop_run(go1):
    """Go1 dropped from 0.25 m above its standing height, servos holding the home pose.

    One jitted MJX rollout of 2 s (500 steps of 4 ms), compiled once and shared by the
    tests below.
    """
    robot, layout = go1
    m = robot.mj_model
    mx = mjx.put_model(m)
    home = np.asarray(robot.home_qpos)
    qpos0 = home.copy()
    qpos0[2] += 0.25
    d0 = mjx.make_data(m).replace(
        qpos=jnp.asarray(qpos0, jnp.float32), ctrl=jnp.asarray(home[7:], jnp.float32)
    )

    @jax.jit
    def rollout(d):
        def body(d, _):
            d = mjx.step(mx, d)
            t = foot_truth(layout, d)
            return d, (t.normal_force, t.contact, t.distance, t.force, d.geom_xpos, d.qpos[2])

        return jax.lax.scan(body, mjx.forward(mx, d), None, length=500)

    final, out = rollout(d0)
    out = jax.tree.map(np.asarray, out)
    runs = dict(zip(("fn", "contact", "dist", "force", "geom_xpos", "z"), out, strict=True))
    runs["final"] = final
    return runs


def test_feet_in_the_air_have_no_force(go1, drop_run):
    robot, _ = go1
    r = drop_run
    radius = np.asarray(robot.description.foot_radii)
    # Free fall from 0.25 m above standing: the feet are ~0.25 m up and need
    # sqrt(2 * 0.25 / 9.81) = 0.23 s to land; the first 40 steps (0.16 s) are in the air.
    air = slice(0, 40)
    np.testing.assert_array_equal(r["fn"][air], 0.0)
    np.testing.assert_array_equal(r["force"][air], 0.0)
    assert not r["contact"][air].any()
    # The floor is the plane z = 0: the gap is the sphere centre's height minus its radius.
    feet = list(robot.description.foot_geom_ids)
    expected = r["geom_xpos"][air][:, feet, 2] - radius
    np.testing.assert_allclose(r["dist"][air], expected, atol=1e-6)
    assert (r["dist"][air] > 0.05).all()


def test_dropped_robot_lands_and_force_rises_from_zero(drop_run):
    r = drop_run
    for foot in range(4):
        first = int(np.argmax(r["contact"][:, foot]))
        assert 40 <= first < 100, first  # lands after ~0.23 s (step ~57)
        assert r["fn"][first - 1, foot] <= 1.0
        assert r["fn"][first, foot] > 1.0
        # Contact forms only once the foot reaches the floor.
        assert r["dist"][first, foot] < 1e-3


def test_standing_feet_carry_the_weight(go1, drop_run):
    robot, _ = go1
    r = drop_run
    # After settling (last 0.4 s), the base is still: the floor carries the total weight,
    # sum_feet F_n = M g with M = sum of body masses = 12.743 kg (Go1 XML):
    # 12.743448 * 9.81 = 125.01 N. Averaged over 100 steps to smooth solver ripple.
    mass = float(np.sum(robot.mj_model.body_mass))
    np.testing.assert_allclose(mass * G, 125.0132, rtol=1e-5)
    late = slice(400, 500)
    assert np.ptp(r["z"][late]) < 2e-3
    np.testing.assert_allclose(np.mean(r["fn"][late].sum(axis=1)), mass * G, rtol=0.03)
    # On a horizontal floor the normal is world z: the vertical force is the normal force.
    np.testing.assert_allclose(r["force"][late][..., 2], r["fn"][late], rtol=1e-4, atol=1e-3)
    assert r["contact"][late].all()
    assert (r["dist"][late] < 0).all() and (r["dist"][late] > -5e-3).all()


def _barkour_on_a_height_field():
    """Barkour on the reproduction's rough floor (1.5 cm std; its own floor is a plane)."""
    size = (10.0, 10.0)
    return with_terrain(load_robot("barkour"), rough_heights(0.015, size_xy=size), size)


def _settled(robot, steps: int = 300):
    """C MuJoCo's (model, data) of ``robot`` after ``steps`` steps from its home pose, its
    position servos holding the keyframe's targets."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home_qpos
    d.ctrl[:] = m.key_ctrl[0]
    for _ in range(steps):
        mujoco.mj_step(m, d)
    return m, d


def test_force_matches_mj_contact_force():
    """The sensor route against C MuJoCo's mj_contactForce, on a plane and a height field."""
    for robot in (load_robot("go1"), _barkour_on_a_height_field()):
        robot = with_contact_sensors(robot)
        layout = make_truth_layout(robot)
        m, d = _settled(robot)
        expected = np.zeros((4, 3))
        feet = list(robot.description.foot_geom_ids)
        for g, force, _ in _forces_on_geoms(m, d):
            if g in feet:
                expected[feet.index(g)] += force
        truth = foot_truth(layout, _c_view(m, d))
        np.testing.assert_allclose(truth.force, expected, rtol=1e-4, atol=1e-3)
        assert (np.linalg.norm(expected, axis=1) > 5.0).all()  # every foot is loaded


def test_height_field_gap_matches_mj_ray():
    """Gap to a height-field floor against a C MuJoCo ray cast straight down."""
    robot = with_contact_sensors(_barkour_on_a_height_field())
    layout = make_truth_layout(robot)
    m = robot.mj_model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    floor = robot.description.floor_geom_ids[0]
    radius = robot.description.foot_radii[0]
    feet = list(robot.description.foot_geom_ids)
    geomid = np.zeros(1, np.int32)
    for _ in range(10):
        d.qpos[:] = robot.home_qpos
        d.qpos[0:2] = rng.uniform(-5.0, 5.0, 2)
        d.qpos[2] = 0.25 + rng.uniform(0.0, 0.1)
        mujoco.mj_kinematics(m, d)
        truth = foot_truth(layout, _c_view(m, d))
        for k, g in enumerate(feet):
            # Start just below the sole so the ray cannot hit the robot itself.
            start = d.geom_xpos[g] - np.array([0.0, 0.0, radius + 1e-6])
            hit = mujoco.mj_ray(m, d, start, np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid)
            assert geomid[0] == floor
            np.testing.assert_allclose(truth.distance[k], hit + 1e-6, atol=2e-5)
            assert hit > 0.01


def test_vmap_matches_loop_and_jit(go1, drop_run):
    robot, layout = go1
    final = drop_run["final"]  # standing after the drop
    # A batch of two: the standing state, and the same with the foot geoms 0.1 m higher.
    feet = jnp.asarray(robot.description.foot_geom_ids)
    lifted = final.replace(geom_xpos=final.geom_xpos.at[feet, 2].add(0.1))
    final = jax.tree.map(lambda a, b: jnp.stack([a, b]), final, lifted)
    batched = jax.jit(jax.vmap(lambda x: foot_truth(layout, x)))(final)
    for i in range(2):
        single = foot_truth(layout, jax.tree.map(lambda x, i=i: x[i], final))
        for a, b in zip(jax.tree.leaves(batched), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(a[i], b, rtol=1e-5, atol=1e-5)
    assert batched.contact.all()
    np.testing.assert_allclose(batched.distance[1] - batched.distance[0], 0.1, atol=1e-6)


def test_missing_sensors_and_bad_threshold_raise():
    robot = load_robot("go1")
    with pytest.raises(ValueError, match="with_contact_sensors"):
        make_truth_layout(robot)
    with pytest.raises(ValueError, match="threshold"):
        make_truth_layout(with_contact_sensors(robot), threshold=-1.0)
    instrumented = with_contact_sensors(robot)
    assert with_contact_sensors(instrumented) is instrumented
    # Sensors are appended: ids and the description are unchanged.
    assert instrumented.description == robot.description


def test_force_counts_the_foot_bodys_other_geoms():
    """A foot that stands on another geom of its body (Menagerie's A1: a soft foot sphere,
    ``solimp="0.015 1 0.031"``, sinks until the calf capsule ending at its centre lands):
    the truth is the floor's force on the whole foot body, against mj_contactForce."""
    base = load_robot("go1")
    spec = base.spec.copy()
    feet = list(base.description.foot_geom_ids)
    for foot in [spec.geoms[g] for g in feet]:  # before the capsules shift the ids
        foot.solimp = [0.015, 1.0, 0.031, 0.5, 2.0]
        foot.priority = 1
        centre = np.asarray(foot.pos, float)
        foot.parent.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            fromto=np.concatenate([centre, centre + [0.0, 0.0, 0.07]]),
            size=[0.75 * foot.size[0], 0.0, 0.0],
            contype=foot.contype,
            conaffinity=foot.conaffinity,
        )
    m0 = spec.compile()
    # The capsules shift the geom ids: the description is derived again.
    desc = derive_description(m0, base.description.foot_names)
    robot = with_contact_sensors(
        dataclasses.replace(base, mj_model=m0, spec=spec, description=desc)
    )
    feet = list(robot.description.foot_geom_ids)
    layout = make_truth_layout(robot)
    assert all(len(extra) == 1 for extra in layout.body_sensors)
    m, d = _settled(robot)
    bodies = [int(m.geom_bodyid[g]) for g in feet]
    expected = np.zeros((4, 3))
    on_sphere = np.zeros(4)
    for g, force, normal in _forces_on_geoms(m, d):
        if int(m.geom_bodyid[g]) in bodies:
            leg = bodies.index(int(m.geom_bodyid[g]))
            expected[leg] += force
            if g in feet:
                on_sphere[leg] += normal
    truth = foot_truth(layout, _c_view(m, d))
    np.testing.assert_allclose(truth.force, expected, rtol=1e-4, atol=1e-3)
    # The scenario: the capsules carry most of the weight, the spheres a few newtons.
    assert (np.asarray(truth.normal_force) > 3.0 * on_sphere).all()
    np.testing.assert_allclose(truth.normal_force.sum(), m.body_subtreemass[1] * G, rtol=0.05)


def test_box_and_capsule_soles_carry_their_whole_force(tmp_path, go1):
    """A box sole touches a plane at 4 points and a capsule lying across the leg at 2; read
    through one slot (the sphere's count) the truth kept one contact: 9 N of a box foot's
    36 N, the four feet summing to a third of the weight (a helper's audit). A quadruped
    with two box and two capsule soles, legs straight under position servos, settled in C
    MuJoCo: the truth against mj_contactForce per foot, and the four normals against the
    weight. Go1's sphere feet keep one slot."""
    leg = (
        '<body name="{s}_thigh" pos="{x} {y} 0"><joint name="{s}_hip" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -.2" size=".02" mass=".5"/>'
        '<body name="{s}_shank" pos="0 0 -.2"><joint name="{s}_knee" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -.2" size=".015" mass=".2"/>{foot}</body></body>'
    )
    box = '<geom name="{s}" class="sole" type="box" pos="0 0 -.21" size=".03 .02 .01"/>'
    cap = (
        '<geom name="{s}" class="sole" type="capsule" fromto="0 -.02 -.21 0 .02 -.21" size=".01"/>'
    )
    legs = [("FL", 0.2, 0.12, box), ("FR", 0.2, -0.12, cap)]
    legs += [("HL", -0.2, 0.12, cap), ("HR", -0.2, -0.12, box)]
    xml = (
        '<mujoco><option timestep="0.002"/><default><geom contype="0" conaffinity="0"/>'
        '<default class="sole"><geom contype="1" conaffinity="1" mass=".05"/></default>'
        '</default><worldbody><geom name="floor" type="plane" size="5 5 .1" contype="1"'
        ' conaffinity="1"/><body name="trunk" pos="0 0 .43"><freejoint/>'
        '<geom type="box" size=".25 .1 .05" mass="8"/>'
        + "".join(leg.format(s=s, x=x, y=y, foot=f.format(s=s)) for s, x, y, f in legs)
        + "</body></worldbody><actuator>"
        + "".join(
            f'<position joint="{s}_{j}" kp="200"/>' for s, *_ in legs for j in ("hip", "knee")
        )
        + "</actuator></mujoco>"
    )
    path = tmp_path / "soles.xml"
    path.write_text(xml)
    robot = with_contact_sensors(load_robot(str(path), foot_names=["FL", "FR", "HL", "HR"]))
    layout = make_truth_layout(robot)
    assert layout.sensor_slots == ((4,),) * 4
    assert go1[1].sensor_slots == ((1,),) * 4
    m = robot.mj_model
    d = mujoco.MjData(m)
    for _ in range(500):
        mujoco.mj_step(m, d)
    feet = list(robot.description.foot_geom_ids)
    expected, contacts = np.zeros((4, 3)), np.zeros(4, int)
    for g, force, _ in _forces_on_geoms(m, d):
        if g in feet:
            expected[feet.index(g)] += force
            contacts[feet.index(g)] += 1
    assert contacts.tolist() == [4, 2, 2, 4]  # the scenario: every sole flat on the floor
    truth = foot_truth(layout, _c_view(m, d))
    np.testing.assert_allclose(truth.force, expected, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(truth.normal_force.sum(), m.body_subtreemass[1] * G, rtol=0.02)
