"""Tests of envs/gaits.py, gait_settings.py and gait_robot.py: kinematics against MuJoCo,
actuator inversion, phases, and closed-loop walking.

The closed-loop tests step C MuJoCo with the jitted JAX controller: the controller is what
is under test, and a jitted MJX rollout per gait would cost a minute of compilation each on
this CPU. ``benchmarks/gait_survival.py`` runs the same controller inside MJX at scale.
"""

from __future__ import annotations

import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jax_contact.envs.gait_robot import leg_phase_offsets
from jax_contact.envs.gaits import (
    GAIT_SETTINGS,
    GaitSettings,
    gait_control,
    gait_settings,
    leg_fk,
    leg_ik,
    leg_phases,
    make_gait,
    make_gait_robot,
    torque_to_ctrl,
)
from jax_contact.envs.ground_truth import make_truth_layout, with_contact_sensors
from jax_contact.envs.robots import Robot, load_robot
from jax_contact.robot import derive_description

ROBOTS = ("go1", "spot", "barkour", "planar_leg")


@pytest.fixture(scope="module")
def robots():
    out = {}
    for name in ROBOTS:
        robot = with_contact_sensors(load_robot(name))
        out[name] = (robot, make_gait_robot(robot))
    return out


def _feet_in_base(robot, qpos):
    """Foot sphere centres in the base frame from C MuJoCo's kinematics (the reference)."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    b = robot.description.base_body_id
    rot = d.xmat[b].reshape(3, 3)
    return np.stack([rot.T @ (d.geom_xpos[g] - d.xpos[b]) for g in robot.description.foot_geom_ids])


@pytest.mark.parametrize("name", ROBOTS)
def test_leg_fk_matches_mujoco_and_ik_inverts_it(robots, name):
    robot, gr = robots[name]
    rng = np.random.default_rng(0)
    fk = jax.jit(leg_fk, static_argnums=1)
    ik = jax.jit(leg_ik, static_argnums=1)
    leg_qpos = np.asarray(gr.leg_qpos)
    for _ in range(3):
        qpos = np.array(robot.home_qpos)
        # Random base pose and joint angles within +-0.3 rad of the standing pose.
        qpos[0:3] += rng.normal(0, 0.1, 3)
        if gr.floating_base:
            quat = rng.normal(size=4)
            qpos[3:7] = quat / np.linalg.norm(quat)
        qpos[leg_qpos.ravel()] += rng.uniform(-0.3, 0.3, leg_qpos.size)
        expected = _feet_in_base(robot, qpos)
        for leg in range(gr.n_legs):
            q = jnp.asarray(qpos[leg_qpos[leg]], jnp.float32)
            np.testing.assert_allclose(fk(gr, leg, q), expected[leg], atol=2e-6)
            # IK from the standing pose recovers a reachable foot position.
            q_ik = ik(gr, leg, jnp.asarray(expected[leg], jnp.float32))
            np.testing.assert_allclose(fk(gr, leg, q_ik), expected[leg], atol=1e-4)


@pytest.mark.parametrize("name", ROBOTS)
def test_torque_to_ctrl_inverts_the_actuators(robots, name):
    robot, gr = robots[name]
    m = robot.mj_model
    rng = np.random.default_rng(1)
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home_qpos
    d.qvel[:] = rng.normal(0, 0.5, m.nv)
    tau = np.zeros(m.nv)
    dofs = np.asarray(gr.leg_dof).ravel()
    tau[dofs] = rng.uniform(-2.0, 2.0, dofs.size)  # small: inside every control range
    ctrl = torque_to_ctrl(
        gr,
        jnp.asarray(tau, jnp.float32),
        jnp.asarray(d.qpos, jnp.float32),
        jnp.asarray(d.qvel, jnp.float32),
    )
    d.ctrl[:] = np.asarray(ctrl)
    mujoco.mj_forward(m, d)
    # MuJoCo's own actuator model maps the controls back to the requested joint torques.
    np.testing.assert_allclose(d.qfrc_actuator[dofs], tau[dofs], atol=2e-4)


def test_phases_trot_pairs_and_walk_sequence(robots):
    robot, gr = robots["go1"]  # feet FR, FL, RR, RL
    names = robot.description.foot_names
    assert names == ("FR", "FL", "RR", "RL")
    trot = make_gait("trot", period=0.5)
    ph = np.asarray(leg_phases(trot, gr, jnp.float32(0.1)))
    idx = {n: i for i, n in enumerate(names)}
    # Diagonal pairs in phase, the two pairs half a cycle apart.
    assert ph[idx["FL"]] == pytest.approx(ph[idx["RR"]])
    assert ph[idx["FR"]] == pytest.approx(ph[idx["RL"]])
    assert (ph[idx["FR"]] - ph[idx["FL"]]) % 1.0 == pytest.approx(0.5)

    walk = make_gait("walk", period=1.0, duty=0.85)
    ts = np.arange(0.0, 2.0, 0.001, dtype=np.float32)
    phases = np.stack([np.asarray(leg_phases(walk, gr, jnp.float32(t))) for t in ts[::10]])
    swing = phases >= 0.85
    # A static walk: never more than one foot in the air.
    assert swing.sum(axis=1).max() == 1
    # Lift-off order within a cycle: left-hind, left-front, right-hind, right-front,
    # a quarter cycle apart.
    lift = {n: float(ts[::10][np.argmax(swing[:, idx[n]])]) for n in names}
    order = sorted(names, key=lambda n: lift[n])
    start = order.index("RL")
    assert order[start:] + order[:start] == ["RL", "FL", "RR", "FR"]  # cyclically
    np.testing.assert_allclose(np.diff([lift[n] for n in order]), 0.25, atol=0.011)


_CONTROLLERS: dict = {}


def _controller(name, gr):
    """The jitted controller of one robot, the gait an argument: Go1's trot and walk run
    one compiled program (the gait's kind is data, not a static field)."""
    if name not in _CONTROLLERS:
        _CONTROLLERS[name] = jax.jit(
            lambda g, t, q, v: gait_control(g, gr, t, types.SimpleNamespace(qpos=q, qvel=v))
        )
    return _CONTROLLERS[name]


def _rollout(robot, gr, gait, seconds):
    """C MuJoCo physics, jitted JAX controller; returns per-step time, base z, up-z, x,
    foot normal forces (N) and foot heights above the floor (m)."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home_qpos
    layout = make_truth_layout(robot)
    ctrl_fn = _controller(robot.name, gr)
    n = int(round(seconds / m.opt.timestep))
    log = np.zeros((n, 4 + 2 * gr.n_legs))
    feet = list(robot.description.foot_geom_ids)
    for k in range(n):
        t = k * m.opt.timestep
        d.ctrl[:] = np.asarray(
            ctrl_fn(
                gait,
                jnp.float32(t),
                jnp.asarray(d.qpos, jnp.float32),
                jnp.asarray(d.qvel, jnp.float32),
            )
        )
        mujoco.mj_step(m, d)
        # Normal force: first entry of every contact slot of the foot's sensor.
        fn = [
            sum(
                d.sensordata[a + 9 * s]
                for a, n_s in zip(row, row_slots, strict=True)
                for s in range(n_s)
            )
            for row, row_slots in zip(layout.sensor_adr, layout.sensor_slots, strict=True)
        ]
        height = [d.geom_xpos[g][2] - r for g, r in zip(feet, layout.foot_radii, strict=True)]
        if gr.floating_base:
            up = 1.0 - 2.0 * (d.qpos[4] ** 2 + d.qpos[5] ** 2)
            z, x = d.qpos[2], d.qpos[0]
        else:
            up, z, x = 1.0, d.qpos[0], 0.0
        log[k] = [t + m.opt.timestep, z, up, x, *fn, *height]
    return log


def _touchdowns(force, min_air_steps):
    """Indices where a foot makes contact (> 1 N) after min_air_steps off the ground."""
    contact = force > 1.0
    out = []
    air = 0
    for k, c in enumerate(contact):
        if c and air >= min_air_steps:
            out.append(k)
        air = 0 if c else air + 1
    return np.array(out)


@pytest.mark.parametrize(
    ("name", "kind", "speed"), [("go1", "trot", 0.4), ("go1", "walk", 0.1), ("spot", "trot", 0.4)]
)
def test_quadruped_gait_stays_upright_and_steps(robots, name, kind, speed):
    robot, gr = robots[name]
    gait = make_gait(kind, speed=speed)
    seconds = 6.0
    log = _rollout(robot, gr, gait, seconds)
    t, z, up, x = log[:, 0], log[:, 1], log[:, 2], log[:, 3]
    n_legs = gr.n_legs
    forces = log[:, 4 : 4 + n_legs]
    assert np.all(up > 0.9) and np.all(z > 0.7 * float(gr.base_height))
    period = float(gait.period)
    late = t > float(gait.ramp_time) + period
    dt = t[1] - t[0]
    for leg in range(n_legs):
        tds = _touchdowns(forces[:, leg], int(0.02 / dt))
        tds = tds[late[tds]]
        # One touch-down per cycle: the gaps between them are one period (+-20 %).
        gaps = np.diff(t[tds])
        assert len(tds) >= int((seconds - float(gait.ramp_time) - period) / period) - 1
        np.testing.assert_allclose(np.median(gaps), period, rtol=0.2)
        assert gaps.max() < 1.5 * period
    # It moves forward at about the commanded speed (stance feet slip a little).
    mean_speed = (x[-1] - x[np.argmax(late)]) / (t[-1] - t[np.argmax(late)])
    np.testing.assert_allclose(mean_speed, speed, rtol=0.3)


def test_planar_leg_hops(robots):
    robot, gr = robots["planar_leg"]
    gait = make_gait("hop")
    log = _rollout(robot, gr, gait, 4.0)
    t, z = log[:, 0], log[:, 1]
    force, height = log[:, 4], log[:, 5]
    late = t > 1.5
    dt = t[1] - t[0]
    tds = _touchdowns(force, int(0.02 / dt))
    tds = tds[late[tds]]
    # One touch-down per hop period (0.6 s), the foot lifted several cm in between and the
    # stance taking about `duty` of the cycle.
    np.testing.assert_allclose(np.diff(t[tds]), float(gait.period), atol=0.03)
    assert height[late].max() > 0.04
    np.testing.assert_allclose(np.mean(force[late] > 1.0), float(gait.duty), atol=0.1)
    # The stance carries the robot: mean normal force over whole cycles = total weight.
    whole = late & (t <= t[tds[-1]]) & (t > t[tds[0]])
    weight = float(np.sum(robot.mj_model.body_mass)) * 9.81
    np.testing.assert_allclose(np.mean(force[whole]), weight, rtol=0.1)
    assert z[late].min() > 0.25  # never collapses onto the floor


def test_gait_control_vmap_matches_loop(robots):
    robot, gr = robots["go1"]
    gait = make_gait("trot", speed=0.3)
    rng = np.random.default_rng(2)
    qpos = np.stack([robot.home_qpos] * 2).astype(np.float32)
    qpos[:, 7:] += rng.uniform(-0.1, 0.1, (2, 12))
    qvel = rng.normal(0, 0.2, (2, 18)).astype(np.float32)
    data = types.SimpleNamespace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel))
    t = jnp.float32(1.3)
    batched = jax.jit(
        jax.vmap(lambda q, v: gait_control(gait, gr, t, types.SimpleNamespace(qpos=q, qvel=v)))
    )(data.qpos, data.qvel)
    # One env at a time, jitted (op by op, the Gauss-Newton IK dispatched every primitive
    # on its own: ~30 s of a cold suite).
    single = jax.jit(lambda q, v: gait_control(gait, gr, t, types.SimpleNamespace(qpos=q, qvel=v)))
    for i in range(2):
        np.testing.assert_allclose(
            batched[i], single(data.qpos[i], data.qvel[i]), rtol=1e-4, atol=1e-4
        )


def test_trot_and_walk_are_one_program_and_keep_their_own_targets(robots):
    """The trot and the walk differ in data only (``pattern`` picks the phase-offset row
    and switches the sway), so ``jit`` lowers both to the same program; the walk still
    sways and the trot still does not (reference: the walk's targets minus the sway shift
    of ``_walk_sway``, which the trot's targets equal)."""
    from jax_contact.envs.gaits import _walk_sway, foot_targets

    robot, gr = robots["go1"]
    trot, walk = make_gait("trot", speed=0.2), make_gait("walk", speed=0.1)
    assert (trot.kind, walk.kind, make_gait("hop").kind) == ("trot", "walk", "hop")
    assert jax.tree.structure(trot) == jax.tree.structure(walk)
    t, vel = jnp.float32(2.3), jnp.zeros(3)
    fn = jax.jit(lambda g, t: foot_targets(g, gr, t, vel))
    assert fn.lower(trot, t).as_text() == fn.lower(walk, t).as_text()

    # The walk's targets are shifted by the sway (ramp done at t = 2.3 s > ramp_time 1 s)...
    shift = np.asarray(_walk_sway(walk, gr, t))
    assert np.abs(shift).max() > 1e-3  # a real shift, m
    unswayed = walk.replace(sway=jnp.float32(0.0))
    np.testing.assert_allclose(
        np.asarray(fn(walk, t)[0]),
        np.asarray(fn(unswayed, t)[0]) - np.concatenate([shift, [0.0]])[None, :],
        atol=1e-6,
    )
    # ... and a trot ignores ``sway`` (documented: walk only).
    np.testing.assert_array_equal(
        np.asarray(fn(trot.replace(sway=jnp.float32(0.5)), t)[0]), np.asarray(fn(trot, t)[0])
    )
    # Phases: the row of the gait's own kind.
    for g in (trot, walk):
        np.testing.assert_allclose(
            np.asarray(jax.jit(lambda g: leg_phases(g, gr, t))(g)),
            np.mod(float(t) / float(g.period) + np.asarray(gr.phase_offset)[int(g.pattern)], 1.0),
            atol=1e-6,
        )
    # A batch reports its kind; a batch of both reports "mixed".
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), trot, walk)
    assert jax.vmap(lambda s: walk.replace(speed=s))(jnp.zeros(3)).kind == "walk"
    assert both.kind == "mixed"


def test_phase_offsets_of_any_leg_count():
    """Legs ranked by their standing feet (front +x, left +y). Hand-derived: Go1's order
    FR, FL, RR, RL keeps its diagonal pairs (FL & RR at 0, FR & RL at 0.5) and its lateral
    walk (delays RL 0, FL 1/4, RR 1/2, FR 3/4; offset = 1 - delay). A hexapod L1-L3, R1-R3
    (front to hind) trots in tripods, {L1, L3, R2} against {L2, R1, R3} half a cycle
    later (before, any leg count but four trotted every leg in phase: a pronk), and walks
    one leg after another in the feet's order, one sixth apart, as before. The fixture's
    radial hexapod (legs L0-L5 every 60 degrees from the front, L0 and L3 on the axis)
    alternates around the circle: {L0, L2, L4} against {L1, L3, L5}."""
    quad = np.array([[0.19, -0.13, 0], [0.19, 0.13, 0], [-0.19, -0.13, 0], [-0.19, 0.13, 0]])
    trot, walk = leg_phase_offsets(quad)
    np.testing.assert_allclose(trot, [0.5, 0.0, 0.0, 0.5])
    np.testing.assert_allclose(walk, [0.25, 0.75, 0.5, 0.0])
    hexa = np.array([[x, y, 0.0] for y in (0.2, -0.2) for x in (0.13, 0.0, -0.13)])
    trot, walk = leg_phase_offsets(hexa)
    np.testing.assert_allclose(trot, [0.0, 0.5, 0.0, 0.5, 0.0, 0.5])
    np.testing.assert_allclose(walk, np.arange(6) / 6)
    angles = np.radians(60.0 * np.arange(6))
    radial = np.stack([0.2 * np.cos(angles), 0.2 * np.sin(angles), np.zeros(6)], axis=1)
    np.testing.assert_allclose(leg_phase_offsets(radial)[0], [0.5, 0, 0.5, 0, 0.5, 0], atol=0)
    # A biped alternates; one leg has nothing to alternate with.
    np.testing.assert_allclose(
        leg_phase_offsets(np.array([[0, 0.1, 0], [0, -0.1, 0]]))[0], [0, 0.5]
    )
    assert [o.tolist() for o in leg_phase_offsets(np.zeros((1, 3)))] == [[0.0], [0.0]]


def test_the_gaits_place_a_capsule_shin_by_its_lower_end(tmp_path):
    """A quadruped whose shanks are floor-touching capsules from the knee down 0.2 m, with a
    site at each tip and no foot geom (a helper's model): the feet found are the shank
    capsules, whose point is the capsule's centre, 0.1 m above the tip. The gaits placed
    that centre and both robots fell on the trot; they now place the lowest of the
    capsule's ends at the standing pose (knees bent 1 rad, hips 0.5 rad: the lower end,
    (0, 0, -0.2) in the shank frame, is lower than the knee end by 0.2 cos(0.5) m). The
    sites named as feet are placed where they are, at the same point."""
    from jax_contact.envs.gait_settings import feet_in_base, gait_foot_points

    leg = (
        '<body name="{s}_thigh" pos="{x} {y} 0"><joint name="{s}_hip" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -.2" size=".02" mass=".6"/>'
        '<body name="{s}_shank" pos="0 0 -.2"><joint name="{s}_knee" axis="0 1 0"/>'
        '<geom contype="1" conaffinity="1" type="capsule" fromto="0 0 0 0 0 -.2" size=".015"'
        ' mass=".2"/><site name="{s}_tip" pos="0 0 -.2"/></body></body>'
    )
    sides = [("FL", 0.2, 0.12), ("FR", 0.2, -0.12), ("HL", -0.2, 0.12), ("HR", -0.2, -0.12)]
    xml = (
        '<mujoco><default><geom contype="0" conaffinity="0"/></default><worldbody>'
        '<geom name="floor" type="plane" size="5 5 .1" contype="1" conaffinity="1"/>'
        '<body name="trunk" pos="0 0 .36"><freejoint/><geom type="box" size=".25 .1 .05"'
        ' mass="8"/>'
        + "".join(leg.format(s=s, x=x, y=y) for s, x, y in sides)
        + "</body></worldbody><actuator>"
        + "".join(f'<motor joint="{s}_{j}"/>' for s, *_ in sides for j in ("hip", "knee"))
        + "</actuator></mujoco>"
    )
    path = tmp_path / "shins.xml"
    path.write_text(xml)
    home = np.array([0, 0, 0.366, 1, 0, 0, 0] + [0.5, -1.0] * 4)
    found = load_robot(str(path)).description
    assert found.foot_names == ("FL_shank", "FR_shank", "HL_shank", "HR_shank")
    np.testing.assert_allclose(found.foot_offsets, [(0, 0, -0.1)] * 4, atol=1e-12)
    m = load_robot(str(path)).mj_model
    np.testing.assert_allclose(gait_foot_points(m, found, home), [(0, 0, -0.2)] * 4, atol=1e-12)
    sites = load_robot(str(path), foot_names=[f"{s}_tip" for s, *_ in sides]).description
    np.testing.assert_allclose(gait_foot_points(m, sites, home), [(0, 0, -0.2)] * 4, atol=1e-12)

    # In the base frame: hip at (x, y, 0); a hinge about y by a turns (0, 0, -L) into
    # (-L sin a, 0, -L cos a); thigh at 0.5 rad, shank at 0.5 - 1 = -0.5 rad: the x
    # shifts cancel, z = -0.4 cos 0.5.
    expected = [(x, y, -0.4 * np.cos(0.5)) for _, x, y in sides]
    np.testing.assert_allclose(feet_in_base(m, found, home), expected, atol=1e-9)
    np.testing.assert_allclose(feet_in_base(m, sites, home), expected, atol=1e-9)


def test_a_box_foot_is_measured_from_its_lowest_corner(tmp_path):
    """The settle measured each foot as its centre less its radius, 0 for a box: a user's
    quadruped with box feet stood on their corners 27 mm "above the floor" and was refused
    ("did not settle standing"). Hand derivation: a box foot of half-sizes (a, b, c) =
    (0.03, 0.02, 0.01) 0.2 m below a hinge about y, 0.1 m below the base at height 0.5;
    turned by t its centre is at z = 0.5 - 0.1 - 0.2 cos t and its bottom face's lowest
    corner c cos t + a |sin t| lower. A sphere foot (radius 0.02) is its centre less 0.02,
    whatever the angle."""
    import mujoco

    from jax_contact.envs.gait_settings import foot_bottoms

    xml = (
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<body name="base" pos="0 0 .5"><freejoint/><geom type="box" size=".1 .1 .05"/>'
        '<body name="leg" pos="0 0 -.1"><joint name="hinge" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -.15" size=".01" contype="0" conaffinity="0"/>'
        '<geom name="foot" type="box" pos="0 0 -.2" size=".03 .02 .01"/></body>'
        '<body name="leg2" pos="0 .2 -.1"><joint name="hinge2" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -.15" size=".01" contype="0" conaffinity="0"/>'
        '<geom name="ball" type="sphere" pos="0 0 -.2" size=".02"/></body>'
        '</body></worldbody><actuator><motor joint="hinge"/><motor joint="hinge2"/></actuator>'
        "</mujoco>"
    )
    path = tmp_path / "box_foot.xml"
    path.write_text(xml)
    robot = load_robot(str(path), foot_names=["foot", "ball"])
    m, desc = robot.mj_model, robot.description
    d = mujoco.MjData(m)
    for t in (0.0, 0.3, -0.5):
        d.qpos[:] = [0, 0, 0.5, 1, 0, 0, 0, t, t]
        mujoco.mj_kinematics(m, d)
        centre = 0.5 - 0.1 - 0.2 * np.cos(t)
        expected = [centre - 0.01 * np.cos(t) - 0.03 * abs(np.sin(t)), centre - 0.02]
        np.testing.assert_allclose(foot_bottoms(desc, d), expected, atol=1e-12)
    # The minimal RL env starts where the user's gait settings stand the robot (it
    # rebuilt the robot from its model and stood it at the keyframe or a settle instead;
    # its reset starts from _home, read here rather than compiling a reset).
    from jax_contact.envs.gaits import GaitSettings
    from jax_contact.envs.legged_env import LeggedPipelineEnv

    home = (0.0, 0.0, 0.43, 1.0, 0.0, 0.0, 0.0, 0.2, -0.2)
    posed = load_robot(str(path), foot_names=["foot", "ball"], gait=GaitSettings(home_qpos=home))
    np.testing.assert_allclose(np.asarray(LeggedPipelineEnv(posed)._home), home, atol=1e-6)


def test_make_gait_rejects_bad_arguments():
    with pytest.raises(ValueError, match="kind must be one of"):
        make_gait("gallop")
    with pytest.raises(ValueError, match="duty"):
        make_gait("walk", duty=0.6)
    with pytest.raises(ValueError, match="period"):
        make_gait("trot", period=0.0)
    with pytest.raises(ValueError, match="sway"):
        make_gait("walk", sway=2.0)


# ------------------------------------------------------------------ gait settings


def _without_keyframes(name: str) -> Robot:
    spec = load_robot(name).spec.copy()
    for key in list(spec.keys):
        spec.delete(key)
    m = spec.compile()
    return Robot(f"{name}_no_keyframe", m, derive_description(m), spec)


def test_tuned_settings_are_public_and_overridable(robots):
    # The tuned gains that the private dict held, now GAIT_SETTINGS.
    tuned = {"go1": (60.0, 1.5), "spot": (400.0, 20.0), "barkour": (35.0, 0.65)}
    for name, (kp, kd) in tuned.items():
        assert (GAIT_SETTINGS[name].kp, GAIT_SETTINGS[name].kd) == (kp, kd)
        gr = robots[name][1]
        np.testing.assert_allclose([float(gr.kp), float(gr.kd)], [kp, kd], rtol=1e-6)
    with pytest.raises(TypeError):
        GAIT_SETTINGS["go1"] = GaitSettings()  # read-only
    home = np.array(load_robot("go1").home_qpos)
    home[7:] += 0.1
    settings = gait_settings("go1", kp=80.0, base_height=0.3, home_qpos=tuple(home))
    robot = load_robot("go1", gait=settings)
    gr = make_gait_robot(robot)
    assert (float(gr.kp), float(gr.kd)) == (80.0, 1.5)  # kd stays the tuned one
    np.testing.assert_allclose(float(gr.base_height), 0.3, rtol=1e-6)
    np.testing.assert_allclose(robot.home_qpos, home)
    np.testing.assert_allclose(
        np.asarray(gr.q_home).ravel(), home[np.asarray(gr.leg_qpos).ravel()], rtol=1e-6
    )
    with pytest.raises(ValueError, match=r"'crouch' is not a keyframe.*\['home', 'home_higher'"):
        _ = load_robot("go1", gait=GaitSettings(home_key="crouch")).home_qpos
    with pytest.raises(ValueError, match="nq = 19"):
        _ = load_robot("go1", gait=GaitSettings(home_qpos=(0.0,) * 7)).home_qpos
    with pytest.raises(ValueError, match="kp must be"):
        GaitSettings(kp=-1.0)
    with pytest.raises(ValueError, match="trot_speed"):
        GaitSettings(trot_speed=(0.5, 0.1))
    assert GaitSettings(walk_speed=(0.0, 0.2)).speed_range("walk") == (0.0, 0.2)


def test_a_robot_without_keyframe_settles_standing():
    robot = _without_keyframes("go1")
    m, desc = robot.mj_model, robot.description
    s = robot.gait_settings
    home = np.array(s.home_qpos)
    assert s.base_height == pytest.approx(home[2])
    # Not a tuned name: the servos' own stiffness (Go1: kp 35) and, as they have no
    # damping (kv 0), kd = 0.025 s * 35.
    assert (s.kp, s.kd) == (35.0, 0.025 * 35.0)
    # Independent check in C MuJoCo: held at the settled joint angles by a stiff PD of
    # this test's own (200 N m/rad, 5 N m s/rad, through Go1's servo law force = 35
    # (ctrl - q)), the robot stays where it is, level, on all four feet.
    d = mujoco.MjData(m)
    d.qpos[:] = home
    for _ in range(int(0.5 / m.opt.timestep)):
        tau = 200.0 * (home[7:] - d.qpos[7:]) - 5.0 * d.qvel[6:]
        d.ctrl[:] = d.qpos[7:] + tau / 35.0
        mujoco.mj_step(m, d)
    assert abs(d.qpos[2] - home[2]) < 0.01
    assert 1.0 - 2.0 * (d.qpos[4] ** 2 + d.qpos[5] ** 2) > 0.99
    touching = {c.geom1 for c in d.contact[: d.ncon]} | {c.geom2 for c in d.contact[: d.ncon]}
    assert set(desc.foot_geom_ids) <= touching
    # Knees bent (Go1's calf range is [-2.818, -0.888] rad; qpos0 has them at 0, straight).
    calves = [m.joint(f"{leg}_calf_joint").qposadr[0] for leg in ("FR", "FL", "RR", "RL")]
    assert np.all(home[calves] < -1.0)


def test_torque_motor_gains_are_derived_from_the_weight():
    robot = load_robot("planar_leg", gait=GaitSettings())  # not the tuned 300 / 8
    s = robot.gait_settings
    m = robot.mj_model
    # kp = 7 M g h / n_legs with h the home pose's hip height (the rail's qpos[0]) above
    # the foot's sole; kd = 0.025 s * kp.
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home_qpos
    mujoco.mj_kinematics(m, d)
    b, g = robot.description.base_body_id, robot.description.foot_geom_ids[0]
    h = d.xpos[b, 2] - d.geom_xpos[g, 2] + robot.description.foot_radii[0]
    kp = 7.0 * float(m.body_mass.sum()) * 9.81 * h
    np.testing.assert_allclose([s.kp, s.kd], [kp, 0.025 * kp], rtol=1e-9)


def test_a_waist_above_both_legs_is_a_fixed_link_held_at_its_standing_angle():
    """A joint above several feet is in no leg (jax_contact.robot.split_legs), so the
    scripted gaits do not solve for it: its link is fixed at the standing angle in the
    legs' kinematics, and the controller holds it there. On tests/fixtures/waist_biped.xml
    standing with the waist pitched 0.2 rad: leg_fk at the standing joint angles is where
    MuJoCo puts each foot (base frame, float32 round-off), and with the waist 0.1 rad past
    its standing angle, at rest, the waist's servo applies its own stiffness, 500 N m/rad
    (the fixture's), times -0.1 rad (the actuator force C MuJoCo computes from the
    controller's ctrl): a waist carries both legs' loads, which the legs' gains would not
    hold."""
    from pathlib import Path

    path = Path(__file__).parent / "fixtures" / "waist_biped.xml"
    home = (0.2, 0.3, -0.45, 0.5, -1.6)
    kp, kd = 20.0, 1.0
    robot = load_robot(str(path), gait=GaitSettings(home_qpos=home, base_height=0.45, kp=kp, kd=kd))
    gr = make_gait_robot(robot)
    m = robot.mj_model
    assert np.asarray(gr.held_dof).tolist() == [0] and float(gr.held_home[0]) == pytest.approx(0.2)
    assert float(gr.held_kp[0]) == pytest.approx(500.0)
    d = mujoco.MjData(m)
    d.qpos[:] = home
    mujoco.mj_kinematics(m, d)
    base = robot.description.base_body_id
    rot, pos = d.xmat[base].reshape(3, 3), d.xpos[base]
    for leg, foot in enumerate(robot.description.foot_names):
        want = rot.T @ (d.geom_xpos[m.geom(foot).id] - pos)
        q_leg = np.asarray(home)[list(np.asarray(gr.leg_qpos[leg]))]
        np.testing.assert_allclose(leg_fk(gr, leg, jnp.asarray(q_leg)), want, atol=2e-6)
    d.qpos[:] = (0.3, *home[1:])
    d.qvel[:] = 0.0
    gait = make_gait("trot")
    d.ctrl[:] = np.asarray(
        gait_control(
            gait,
            gr,
            jnp.float32(0.0),
            types.SimpleNamespace(qpos=jnp.asarray(d.qpos), qvel=jnp.asarray(d.qvel)),
        )
    )
    mujoco.mj_forward(m, d)
    assert d.actuator_force[0] == pytest.approx(500.0 * -0.1, rel=1e-4)


def test_a_spine_above_the_front_legs_is_held_and_the_legs_keep_their_joints(tmp_path):
    """Playground's Go1 with a pitching spine between its trunk and its front hips (a
    position servo, kp 300), as a user would build one: before the forty-sixth session
    its front legs had 4 joints and its hind legs 3, and the model was refused ("every
    leg must have the same number of dofs"). Now each leg keeps its 3 joints, the spine
    counts with the base, the scripted gaits hold it with its servo's stiffness, and
    simulate takes the trot. (Simulated with Go1's gains, 8 envs x 4 s, seed 0: every
    robot upright on the trot and the walk; docs/own_robot.md has the scores.)"""
    import re
    import shutil

    from jax_contact.envs.model_files import playground_xml
    from jax_contact.envs.simulate import check_gait_fits

    src = playground_xml("go1").parent
    shutil.copytree(src, tmp_path / "xmls")
    robot_xml = tmp_path / "xmls" / "go1_mjx_feetonly.xml"
    text = robot_xml.read_text()
    a, b = text.index('      <body name="FR_hip"'), text.index('      <body name="RR_hip"')
    spine = (
        '      <body name="front">\n'
        '        <joint name="spine" axis="0 1 0" range="-0.3 0.3" damping="2" frictionloss="0"/>\n'
        '        <inertial pos="0.1 0 0" mass="0.5" diaginertia="0.001 0.001 0.001"/>\n'
    )
    text = text[:a] + spine + text[a:b] + "      </body>\n" + text[b:]
    last = '    <position class="knee" name="RL_calf" joint="RL_calf_joint"/>\n'
    assert text.count(last) == 1
    servo = '    <position name="spine" joint="spine" kp="300" forcerange="-60 60"/>\n'
    robot_xml.write_text(text.replace(last, last + servo))
    scene = tmp_path / "xmls" / "scene_mjx_feetonly_flat_terrain.xml"

    def with_spine(attr, at):  # a 0 for the spine in every keyframe's qpos / ctrl
        def insert(match):
            values = match.group(2).split()
            values.insert(len(values) if at is None else at, "0")
            return f"{attr}={match.group(1)}{' '.join(values)}{match.group(1)}"

        return lambda t: re.sub(rf"{attr}=([\"'])(.*?)\1", insert, t, flags=re.S)

    text = scene.read_text()
    text = with_spine("ctrl", None)(with_spine("qpos", 7)(text))  # after the free joint
    scene.write_text(text)

    robot = load_robot(str(scene), gait=GaitSettings(kp=60.0, kd=1.5))
    desc, m = robot.description, robot.mj_model
    spine_dof = int(m.jnt_dofadr[m.joint("spine").id])
    assert spine_dof == 6 and [len(leg) for leg in desc.leg_dofs] == [3, 3, 3, 3]
    assert all(spine_dof in other for other in desc.other_dofs)
    check_gait_fits(make_gait("trot"), robot)  # the spine is driven, not left limp
    gr = make_gait_robot(robot)
    assert np.asarray(gr.held_dof).tolist() == [spine_dof]
    assert float(gr.held_kp[0]) == pytest.approx(300.0)
