"""The MJX adapter against the MuJoCo C library in float64.

For each robot, a handful of random states near the standing pose (random base pose,
joint angles, velocities and controls) are set in C ``MjData`` and run through
``mj_forward``; the same state goes through ``prepare`` + ``leg_measurements`` in MJX
(float32 unless stated). References: ``mj_fullM``, ``qfrc_bias``, ``mj_jac``,
``geom_xpos``, and for ``Jdot_qd`` a central finite difference of the C library's ``mj_jac``
along ``qvel`` (positions moved with ``mj_integratePos``), cross-checked with ``mj_jacDot``.
Run with ``-s`` to see the maximum errors.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from jax_contact.adapter import leg_measurements, prepare
from jax_contact.envs.robots import load_robot
from jax_contact.types import LegMeasurement

N_STATES = 4
# float32 tolerances, relative to the size of the reference quantity (errors seen: ~1e-7).
RTOL32 = 2e-5
FD_EPS = 1e-6  # central difference step, s; truncation ~1e-12, round-off ~1e-10


def _random_states(robot, n: int, seed: int) -> list[mujoco.MjData]:
    m = robot.mj_model
    rng = np.random.default_rng(seed)
    desc = robot.description
    states = []
    for _ in range(n):
        d = mujoco.MjData(m)
        q = robot.home_qpos.copy()
        if len(desc.base_dofs) == 6:  # free joint: position, then quaternion
            q[:3] += rng.normal(0.0, 0.05, 3)
            quat = q[3:7] + rng.normal(0.0, 0.2, 4)
            q[3:7] = quat / np.linalg.norm(quat)
            joints = slice(7, m.nq)
        else:
            q[0] += rng.normal(0.0, 0.05)
            joints = slice(1, m.nq)
        q[joints] += rng.normal(0.0, 0.3, m.nq - joints.start)
        d.qpos[:] = q
        d.qvel[:] = rng.normal(0.0, 1.5, m.nv)
        lo, hi = m.actuator_ctrlrange.T
        d.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_forward(m, d)
        states.append(d)
    return states


def _jac(m, d, point, body) -> np.ndarray:
    jacp = np.zeros((3, m.nv))
    mujoco.mj_jac(m, d, jacp, None, point, body)
    return jacp


def _c_reference(robot, d: mujoco.MjData) -> dict[str, np.ndarray]:
    """Per-leg float64 references from the C library at the state of ``d``."""
    m, desc = robot.mj_model, robot.description
    full_m = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full_m)
    ref = {"M": full_m, "h": d.qfrc_bias.copy(), "passive": d.qfrc_passive.copy()}
    J, p_f, jdot_fd, jdot_c = [], [], [], []
    for body, geom in zip(desc.foot_body_ids, desc.foot_geom_ids, strict=True):
        J.append(_jac(m, d, d.geom_xpos[geom], body))
        p_f.append(d.geom_xpos[geom].copy())

        def jac_at(t, body=body, geom=geom):
            d2 = mujoco.MjData(m)
            q = d.qpos.copy()
            mujoco.mj_integratePos(m, q, d.qvel, t)
            d2.qpos[:] = q
            mujoco.mj_kinematics(m, d2)
            mujoco.mj_comPos(m, d2)
            return _jac(m, d2, d2.geom_xpos[geom], body)

        jdot_fd.append((jac_at(FD_EPS) - jac_at(-FD_EPS)) @ d.qvel / (2 * FD_EPS))
        jacdot = np.zeros((3, m.nv))
        mujoco.mj_jacDot(m, d, jacdot, None, d.geom_xpos[geom], body)
        jdot_c.append(jacdot @ d.qvel)
    ref.update(J=np.stack(J), p_f=np.stack(p_f), Jdot_fd=np.stack(jdot_fd))
    ref["Jdot_c"] = np.stack(jdot_c)
    ref["v_f"] = ref["J"] @ d.qvel
    return ref


def _measure_fn(robot):
    """Jitted ``(data, qdd, tau) -> (defaults, explicit)``: the measurements with every
    default, and with ``qdd``, ``tau`` given and ``include_passive``. One compilation."""
    mm = mjx.put_model(robot.mj_model)
    desc = robot.description

    def fn(d, qdd, tau):
        d = prepare(mm, d)
        explicit = leg_measurements(mm, d, desc, qdd=qdd, tau=tau, include_passive=True)
        return leg_measurements(mm, d, desc), explicit

    return mm, jax.jit(fn)


def _check_against_c(robot, states, fn, rtol: float) -> dict[str, float]:
    """Asserts every quantity within ``rtol * max|reference|``; returns max abs errors."""
    m, desc = robot.mj_model, robot.description
    errors: dict[str, float] = {}

    def check(name, got, want):
        got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
        assert got.shape == want.shape, name
        err = float(np.max(np.abs(got - want)))
        errors[name] = max(errors.get(name, 0.0), err)
        assert err <= rtol * max(1.0, float(np.max(np.abs(want)))), (name, err)

    n_legs = desc.n_legs
    rng = np.random.default_rng(0)
    for d in states:
        qdd, tau = rng.normal(0.0, 5.0, (2, m.nv))
        meas, explicit = fn(mjx.put_data(m, d), jnp.asarray(qdd), jnp.asarray(tau))
        ref = _c_reference(robot, d)
        # Reference sanity: MuJoCo's own Jdot agrees with the finite difference.
        np.testing.assert_allclose(ref["Jdot_c"], ref["Jdot_fd"], atol=1e-7)
        check("M", meas.M, np.broadcast_to(ref["M"], (n_legs, m.nv, m.nv)))
        check("h", meas.h, np.broadcast_to(ref["h"], (n_legs, m.nv)))
        check("J", meas.J, ref["J"])
        check("p_f", meas.p_f, ref["p_f"])
        check("v_f", meas.v_f, ref["v_f"])
        check("Jdot_qd", meas.Jdot_qd, ref["Jdot_fd"])
        check("q", meas.q, np.broadcast_to(d.qpos, (n_legs, m.nq)))
        check("qd", meas.qd, np.broadcast_to(d.qvel, (n_legs, m.nv)))
        check("qdd", meas.qdd, np.broadcast_to(d.qacc, (n_legs, m.nv)))
        check("tau", meas.tau, np.broadcast_to(d.qfrc_actuator, (n_legs, m.nv)))
        np.testing.assert_allclose(meas.foot_radius, desc.foot_radii, rtol=1e-6)
        np.testing.assert_array_equal(meas.leg_dofs, desc.leg_dofs)
        np.testing.assert_array_equal(meas.other_dofs, desc.other_dofs)
        assert meas.leg_dofs.dtype == jnp.int32 and meas.other_dofs.dtype == jnp.int32
        # Given qdd and tau pass through; include_passive moves joint springs and dampers
        # (qfrc_passive) into h.
        check("qdd given", explicit.qdd, np.broadcast_to(qdd, (n_legs, m.nv)))
        check("tau given", explicit.tau, np.broadcast_to(tau, (n_legs, m.nv)))
        check("h - passive", explicit.h, np.broadcast_to(ref["h"] - ref["passive"], (n_legs, m.nv)))
        np.testing.assert_array_equal(explicit.J, meas.J)
    return errors


@pytest.fixture(scope="module")
def robots():
    return {name: load_robot(name) for name in ("go1", "planar_leg", "barkour")}


@pytest.fixture(scope="module")
def compiled(robots):
    return {name: _measure_fn(robot) for name, robot in robots.items()}


@pytest.mark.parametrize("name,seed", [("go1", 1), ("planar_leg", 2), ("barkour", 3)])
def test_matches_c_library(robots, compiled, name, seed):
    robot = robots[name]
    states = _random_states(robot, N_STATES, seed)
    # The states really move: actuators push and the base turns.
    assert all(np.abs(d.qfrc_actuator).max() > 1.0 for d in states)
    errors = _check_against_c(robot, states, compiled[name][1], RTOL32)
    print(f"\n{name} (float32, {N_STATES} states) max abs error vs C float64:")
    print("  " + ", ".join(f"{k} {v:.1e}" for k, v in errors.items()))


def test_matches_c_library_float64(robots, x64):
    """In float64 the adapter agrees with C to round-off: the formulas, not just float32."""
    robot = robots["go1"]
    states = _random_states(robot, 2, seed=4)
    _, fn = _measure_fn(robot)
    zeros = jnp.zeros(robot.mj_model.nv)
    assert fn(mjx.put_data(robot.mj_model, states[0]), zeros, zeros)[0].M.dtype == jnp.float64
    errors = _check_against_c(robot, states, fn, rtol=1e-9)
    print("\ngo1 (float64, 2 states) max abs error vs C float64:")
    print("  " + ", ".join(f"{k} {v:.1e}" for k, v in errors.items()))


def test_passive_is_exercised(robots):
    # go1 and barkour have joint damping (0.5, 0.5239 N m s/rad), so "h - passive" above
    # differs from h; the planar leg has none.
    for name in ("go1", "barkour"):
        d = _random_states(robots[name], 1, seed=5)[0]
        assert np.abs(d.qfrc_passive).max() > 0.1


def test_vmap_equals_loop(robots, compiled):
    robot = robots["planar_leg"]
    m = robot.mj_model
    mm, fn = compiled["planar_leg"]
    desc = robot.description
    batch = [mjx.put_data(m, d) for d in _random_states(robot, 3, seed=6)]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *batch)
    batched = jax.jit(jax.vmap(lambda d: leg_measurements(mm, prepare(mm, d), desc)))(stacked)
    assert isinstance(batched, LegMeasurement)
    assert batched.J.shape == (3, 1, 3, m.nv)
    zeros = jnp.zeros(m.nv)
    for i, d in enumerate(batch):
        single, _ = fn(d, zeros, zeros)
        for a, b in zip(jax.tree.leaves(batched), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(a[i], b, rtol=1e-5, atol=1e-6)


def test_refusals(robots, compiled):
    mm_go1, _ = compiled["go1"]
    d = mjx.make_data(mm_go1)
    with pytest.raises(ValueError, match="desc has nv=3"):
        leg_measurements(mm_go1, d, robots["planar_leg"].description)
    with pytest.raises(ValueError, match=r"qdd must have shape \(18,\)"):
        leg_measurements(mm_go1, d, robots["go1"].description, qdd=jnp.zeros(3))
    # Unprepared data read as a massless robot (M = 0, every step invalid, no hint).
    with pytest.raises(ValueError, match=r"no mass matrix \(it is all zeros\): run prepare"):
        leg_measurements(mm_go1, d, robots["go1"].description)
    # MuJoCo's C structures where MJX's belong (an opt_einsum error before).
    m_c = robots["go1"].mj_model
    with pytest.raises(ValueError, match=r"mjx_data must be an mjx\.Data \(mjx\.put_data"):
        leg_measurements(mm_go1, mujoco.MjData(m_c), robots["go1"].description)
    with pytest.raises(ValueError, match=r"mjx_model must be an mjx\.Model \(mjx\.put_model"):
        leg_measurements(m_c, d, robots["go1"].description)
    # prepare is called first (the README's order): the same refusals there (it raised an
    # AttributeError on MjData, and MJX's broadcasting errors on a batch).
    with pytest.raises(ValueError, match=r"mjx_data must be an mjx\.Data \(mjx\.put_data"):
        prepare(mm_go1, mujoco.MjData(m_c))
    batch = jax.vmap(lambda _: mjx.make_data(mm_go1))(jnp.arange(4))
    with pytest.raises(ValueError, match=r"qpos has shape \(4, 19\); expected \(19,\).*vmap"):
        prepare(mm_go1, batch)
    other = d.replace(qvel=jnp.zeros(3))  # another robot's readings
    with pytest.raises(ValueError, match=r"mjx_data\.qvel has shape \(3,\); expected \(18,\)"):
        prepare(mm_go1, other)
    # The robot where its description belongs (robot.description).
    with pytest.raises(ValueError, match=r"desc must be .*RobotDescription \(robot\.description\)"):
        leg_measurements(mm_go1, d, robots["go1"])
    # Booleans are no readings (read as torques of 0 and 1 N m, P ~0.5, without a word;
    # the exported estimator refuses them).
    with pytest.raises(ValueError, match=r"^mjx_data\.qvel has dtype bool; expected real"):
        prepare(mm_go1, d.replace(qvel=np.zeros(18, bool)))
    with pytest.raises(ValueError, match=r"^tau has dtype bool; expected real"):
        leg_measurements(mm_go1, d, robots["go1"].description, tau=np.ones(18, bool))


def test_prepare_takes_numpy_state_outside_jit(robots):
    """A control loop's NumPy readings put in the data as they are, outside ``jit``: MJX's
    scan over the bodies failed on a NumPy qvel ("numpy arg elements do not match"). Now
    the same data as with JAX arrays (both eager, no compilation)."""
    robot = robots["go1"]
    mm = mjx.put_model(robot.mj_model, impl="jax")
    state = _random_states(robot, 1, seed=3)[0]
    base = mjx.make_data(mm)
    as_np = prepare(mm, base.replace(qpos=state.qpos.copy(), qvel=state.qvel.copy()))
    as_jax = prepare(mm, base.replace(qpos=jnp.asarray(state.qpos), qvel=jnp.asarray(state.qvel)))
    assert isinstance(as_np.qvel, jax.Array)
    for field in ("qfrc_bias", "cdof_dot", "xpos", "cvel"):
        np.testing.assert_array_equal(getattr(as_np, field), getattr(as_jax, field))


# One reading of each kind lost on Go1's front-left leg (leg 1: dofs 9-11, qpos 10-12),
# as a dropped encoder or torque packet gives it.
LOST = {"qpos": 11, "qvel": 10, "qdd": 10, "tau": 11}


@pytest.mark.parametrize("field", sorted(LOST))
def test_a_lost_reading_stays_in_its_leg(robots, compiled, field, jit_step_batch):
    """A NaN in one leg's joint reading marks that foot invalid and leaves the other feet's
    step as it is without the NaN: their terms read no coordinate of another leg
    (measurement._split), their v_f and Jdot_qd sum their own chain, and prepare computes a
    NaN joint position at qpos0 (MuJoCo's subtree-COM frame would spread it to every body)."""
    import jax_contact as jc
    from jax_contact.envs.sensors import sensor_preset

    robot = robots["go1"]
    m, desc = robot.mj_model, robot.description
    assert desc.leg_dofs[1] == (9, 10, 11)
    mm, fn = compiled["go1"]
    state = _random_states(robot, 1, seed=8)[0]
    qdd, tau = np.random.default_rng(1).normal(0.0, 5.0, (2, m.nv))
    clean = fn(mjx.put_data(m, state), jnp.asarray(qdd), jnp.asarray(tau))[1]
    bad_state = mujoco.MjData(m)
    bad_state.qpos[:], bad_state.qvel[:] = state.qpos, state.qvel
    bad_qdd, bad_tau = qdd.copy(), tau.copy()
    target = {"qpos": bad_state.qpos, "qvel": bad_state.qvel, "qdd": bad_qdd, "tau": bad_tau}
    target[field][LOST[field]] = np.nan
    d = mjx.put_data(m, state).replace(
        qpos=jnp.asarray(bad_state.qpos, jnp.float32), qvel=jnp.asarray(bad_state.qvel, jnp.float32)
    )
    bad = fn(d, jnp.asarray(bad_qdd), jnp.asarray(bad_tau))[1]
    if field == "qpos":  # prepare keeps the qpos it was given; only that foot is lost
        assert np.isnan(np.asarray(bad.q[0, 11]))
        np.testing.assert_array_equal(np.isnan(np.asarray(bad.p_f)).any(-1), [0, 1, 0, 0])
        # A base quaternion entry (the free joint, in every foot's chain): every foot.
        base = d.replace(qpos=d.qpos.at[4].set(jnp.nan).at[11].set(state.qpos[11]))
        lost_base = fn(base, jnp.asarray(qdd), jnp.asarray(tau))[1]
        assert np.isnan(np.asarray(lost_base.p_f)).any(-1).all()

    params = jc.params_for(desc, sensor_preset("anymal_like", m.nv, dt=0.0025), 0.0025)
    belief = jc.init_belief_batch(params, 1, desc.n_legs)
    belief = belief.replace(logit=jnp.asarray([[4.0, 4.0, -4.0, 4.0]]))
    add_env = functools.partial(jax.tree.map, lambda x: x[None])
    key = jax.random.key(3)
    want_b, want_d = jit_step_batch(params, jc.flat(), belief, add_env(clean), key=key)
    got_b, got_d = jit_step_batch(params, jc.flat(), belief, add_env(bad), key=key)
    np.testing.assert_array_equal(np.asarray(got_d.valid[0]), [True, False, True, True])
    assert bool(np.all(want_d.valid))
    # The other feet: the clean step (bitwise where no position was lost; a position computed
    # at qpos0 moves the subtree COM, the frame of MuJoCo's sums, by float32 round-off).
    for leg in (0, 2, 3):
        for x, y in zip(
            jax.tree.leaves((got_b, got_d)), jax.tree.leaves((want_b, want_d)), strict=True
        ):
            x, y = np.asarray(x[0, leg], np.float64), np.asarray(y[0, leg], np.float64)
            if field == "qpos":
                np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)
            else:
                np.testing.assert_array_equal(x, y)
    # The lost foot: the transition-only prediction from its prior (eq. 1 without L).
    T = np.exp(np.asarray(belief.log_transition[0, 1], np.float64))
    b = 1.0 / (1.0 + np.exp(-4.0))
    prior = np.array([b, 1.0 - b]) @ T
    np.testing.assert_allclose(float(got_b.logit[0, 1]), np.log(prior[0] / prior[1]), rtol=1e-5)
