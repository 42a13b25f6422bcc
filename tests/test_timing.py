"""One timing convention for readings: simulate, the wrapper and the offline replay agree.

Reading ``k`` is what the sensors give at the end of physics step ``k`` (state after the
step, acceleration over it, torque applied during it; train/evaluate.py's module
docstring). Two checks, on the planar leg (cheap to compile):

1. The wrapper's own readings, replayed offline by ``jax_contact.train.evaluate.replay``, give the
live
   wrapper's beliefs to float tolerance (issue 13, item 4). Quadrature touch-down rule, so
   the estimator is deterministic and the two runs' different PRNG keys do not matter.
2. A log written by ``jax_contact.envs.simulate`` (ideal sensors) has the same convention, checked
   against a float64 MuJoCo oracle: in the air, ``M(q) qdd + c(q, qd) = tau`` holds with
   the state of reading ``k - 1`` and the acceleration and torque of reading ``k``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jax_contact.envs import ground_truth
from jax_contact.envs import wrapper as W
from jax_contact.envs.robots import load_robot
from jax_contact.envs.simulate import build_world, simulate
from jax_contact.train.evaluate import replay

N_STEPS = 240  # 0.6 s at 400 Hz: two hops of the planar leg
HOP_HZ, HOP_AMP = 2.0, 0.7


def _hop_targets(n_steps: int, dt: float) -> np.ndarray:
    """(n_steps, 2) hip/knee targets: knee -1.2 + 0.7 sin(2 pi 2 t), hip = -knee / 2."""
    t = np.arange(1, n_steps + 1) * dt
    knee = -1.2 + HOP_AMP * np.sin(2 * np.pi * HOP_HZ * t)
    return np.stack([-0.5 * knee, knee], axis=-1).astype(np.float32)


@pytest.fixture(scope="module")
def live():
    """The wrapped planar leg, one physics step per env step, anymal_like sensors."""
    robot = ground_truth.with_contact_sensors(load_robot("planar_leg"))
    env = W.LeggedPipelineEnv(robot, n_frames=1, position_servo=(300.0, 8.0))
    wrapped = W.wrap_contact(env, W.ContactObsConfig(rate="substep"))
    core = wrapped.contact_core
    assert core.params.touchdown == "quadrature"  # deterministic, whatever the key
    dt = float(env.dt)
    acts = jnp.asarray(_hop_targets(N_STEPS, dt))

    @jax.jit
    def rollout(key):
        s0 = wrapped.reset(key)

        def body(s, a):
            s = wrapped.step(s, a)
            est = s.info["contact_est"]
            return s, (est.prev, est.diag.p_contact, s.info["contact_est_truth"])

        _, outs = jax.lax.scan(body, s0, acts)
        return s0.info["contact_est"].prev, outs

    first, (readings, p_live, truth) = rollout(jax.random.PRNGKey(7))
    return robot, core, dt, first, readings, np.asarray(p_live), np.asarray(truth)


def test_replaying_the_wrappers_readings_gives_its_beliefs(live):
    robot, core, dt, first, readings, p_live, truth = live
    assert truth.any() and not truth.all()  # the leg hops: both phases occur
    as_log = {k: np.asarray(getattr(readings, k))[:, None] for k in ("qpos", "qvel", "qacc", "tau")}
    out = replay(
        robot,
        as_log,
        estimators={"wrapper": core.params},
        terrain=core.terrain,
        dt=dt,
        previous={k: np.asarray(getattr(first, k))[None] for k in ("qpos", "qvel")},
        progress=False,
    )
    p_off = out["wrapper"][:, 0]
    assert p_off.shape == p_live.shape
    # float32 on both sides; the two compute the same graph but XLA may fuse differently.
    np.testing.assert_allclose(p_off, p_live, atol=2e-4)


@pytest.fixture(scope="module")
def ideal_log():
    world = build_world("planar_leg")
    roll = simulate(world, "hop", "ideal", 1, 0.6, 0, chunk_s=0.6, progress=False)
    return world, roll


def test_simulated_readings_are_end_of_step(ideal_log):
    """Float64 MuJoCo oracle of the convention: with the state of reading k - 1, the
    acceleration and torque of reading k satisfy the equation of motion, eq. (4), without
    contact force (foot in the air); the torque of reading k - 1 (the convention before)
    does not."""
    world, roll = ideal_log
    mj = world.robot.mj_model
    d = mujoco.MjData(mj)
    M = np.zeros((mj.nv, mj.nv))
    air = np.flatnonzero(~roll.contact[1:, 0, 0] & ~roll.contact[:-1, 0, 0]) + 1
    air = air[(air > 2) & roll.valid[air, 0]]
    assert air.size > 20
    right, stale = [], []
    for k in air:
        d.qpos[:] = roll.qpos[k - 1, 0]
        d.qvel[:] = roll.qvel[k - 1, 0]
        mujoco.mj_forward(mj, d)
        mujoco.mj_fullM(mj, d, M)
        lhs = M @ roll.qacc[k, 0].astype(np.float64) + d.qfrc_bias - d.qfrc_passive
        right.append(np.max(np.abs(lhs - roll.tau[k, 0])))
        stale.append(np.max(np.abs(lhs - roll.tau[k - 1, 0])))
    # Residual of float32 readings differenced at 400 Hz: below 0.05 N m; the other
    # pairing is off by the PD torque's change over one step on most air steps.
    assert np.median(right) < 0.05
    assert np.median(stale) > 10 * np.median(right)


def test_old_start_of_step_logs_are_realigned():
    """Hand derivation: start-of-step reading k = (q_k, qd_k, acc over k-1, tau_k); the
    end-of-step reading k = (q_{k+1}, qd_{k+1}, acc over k, tau_k), truth of step k kept."""
    from jax_contact.train.logs import to_end_of_step

    t = np.arange(4.0)[:, None, None]  # (T=4, E=1, 1): value = the step index
    old = {"qpos": t + 100, "qvel": t + 200, "qacc": t + 300, "tau": t + 400}
    truth = np.array([0, 1, 1, 0], bool)[:, None, None]
    valid = np.array([1, 1, 0, 1], bool)[:, None]
    new, tr, ok = to_end_of_step(old, truth, valid)
    np.testing.assert_array_equal(new["qpos"][:, 0, 0], [101, 102, 103])
    np.testing.assert_array_equal(new["qvel"][:, 0, 0], [201, 202, 203])
    np.testing.assert_array_equal(new["qacc"][:, 0, 0], [301, 302, 303])
    np.testing.assert_array_equal(new["tau"][:, 0, 0], [400, 401, 402])
    np.testing.assert_array_equal(tr[:, 0, 0], [0, 1, 1])
    np.testing.assert_array_equal(ok[:, 0], [1, 0, 0])  # a step needs both its readings


def test_which_logs_are_read_as_start_of_step():
    """Only an older ``jax-contact simulate`` log (gait, noise, seed; no reading_timing) is
    re-aligned; a log the user wrote is read in the documented convention."""
    from jax_contact.train.logs import reading_timing_of

    sim = {"robot": "go1", "dt": 0.0025, "gait": "trot", "noise": "anymal_like", "seed": 0}
    assert reading_timing_of("old", sim) == "start_of_step"
    assert reading_timing_of("new", {**sim, "reading_timing": "end_of_step"}) == "end_of_step"
    assert reading_timing_of("user", {"robot": "go1", "dt": 0.0025}) == "end_of_step"
    with pytest.raises(ValueError, match="'reading_timing' is 'middle'"):
        reading_timing_of("log 'x.h5'", {"reading_timing": "middle"})
