"""The closed-loop hop of Berkeley Humanoid (envs/biped_hop.py).

Its pieces against hand-written references (tilt and heading velocity from MuJoCo's own
quaternion-to-matrix, the feedback's formulas written out), and its behaviour in MuJoCo (C,
the env's own model): from the standing pose it hops for 4 s without falling, both feet
leaving the floor once per cycle. Its accuracy as a policy for the wrapped estimator is
measured by ``benchmarks/wrapper_accuracy.py`` (docs/training.md).
"""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jax_contact.envs import biped_hop as bh
from jax_contact.envs import playground_offline


def _quat(axis, angle):
    q = np.zeros(4)
    axis = np.asarray(axis, float)
    mujoco.mju_axisAngle2Quat(q, axis / np.linalg.norm(axis), angle)
    return q


def _state(quat, qvel_base=(0, 0, 0, 0, 0, 0)):
    qpos = np.zeros(19)
    qpos[2] = 0.5
    qpos[3:7] = quat
    qvel = np.zeros(18)
    qvel[:6] = qvel_base
    return qpos, qvel


def _reference(qpos, qvel):
    """Roll, pitch from the gravity direction in the base frame (MuJoCo's rotation
    matrix), yaw from the base's x axis, world velocity turned by -yaw."""
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, qpos[3:7])
    r = r.reshape(3, 3)
    g = r.T @ np.array([0.0, 0.0, -1.0])  # gravity in base coordinates
    roll, pitch = -np.arcsin(g[1]), np.arcsin(g[0])
    yaw = np.arctan2(r[1, 0], r[0, 0])
    vx = np.cos(yaw) * qvel[0] + np.sin(yaw) * qvel[1]
    vy = -np.sin(yaw) * qvel[0] + np.cos(yaw) * qvel[1]
    return roll, pitch, vx, vy


def test_tilt_and_velocity_analytic():
    # A rotation by 0.1 rad about the base's x (y) axis is a roll (pitch) of 0.1.
    st = bh.tilt_and_velocity(*_state(_quat((1, 0, 0), 0.1)))
    assert float(st["roll"]) == pytest.approx(0.1, abs=1e-6)
    assert float(st["pitch"]) == pytest.approx(0.0, abs=1e-6)
    st = bh.tilt_and_velocity(*_state(_quat((0, 1, 0), 0.1)))
    assert float(st["pitch"]) == pytest.approx(0.1, abs=1e-6)
    assert float(st["roll"]) == pytest.approx(0.0, abs=1e-6)
    # Yaw 90 deg, world velocity (1, 2): forward (heading x = world y) 2, lateral -1.
    st = bh.tilt_and_velocity(*_state(_quat((0, 0, 1), np.pi / 2), (1, 2, 0, 0.3, -0.4, 0)))
    assert float(st["vx"]) == pytest.approx(2.0, abs=1e-6)
    assert float(st["vy"]) == pytest.approx(-1.0, abs=1e-6)
    assert (float(st["roll_rate"]), float(st["pitch_rate"])) == pytest.approx((0.3, -0.4))


def test_tilt_and_velocity_against_mujoco_rotation(x64):
    rng = np.random.default_rng(0)
    for _ in range(10):
        # Tilts up to ~0.5 rad about a random horizontal axis, any yaw.
        tilt = _quat((*rng.normal(size=2), 0.0), rng.uniform(0, 0.5))
        q = np.zeros(4)
        mujoco.mju_mulQuat(q, _quat((0, 0, 1), rng.uniform(-np.pi, np.pi)), tilt)
        qpos, qvel = _state(q, rng.normal(size=6))
        st = bh.tilt_and_velocity(jnp.asarray(qpos, jnp.float64), jnp.asarray(qvel, jnp.float64))
        got = [float(st[k]) for k in ("roll", "pitch", "vx", "vy")]
        np.testing.assert_allclose(got, _reference(qpos, qvel), atol=1e-9)


def test_feedback_formulas(x64):
    g, legs = bh.BERKELEY_HOP, bh.BERKELEY_LEGS
    rng = np.random.default_rng(1)
    qpos, qvel = _state(_quat((1, 2, 0), 0.2), rng.normal(size=6))
    qpos, qvel = jnp.asarray(qpos, jnp.float64), jnp.asarray(qvel, jnp.float64)
    roll, pitch, vx, vy = _reference(np.asarray(qpos), np.asarray(qvel))
    wx, wy = float(qvel[3]), float(qvel[4])
    stance = np.asarray(bh.feedback(qpos, qvel, jnp.asarray(True)))
    flight = np.asarray(bh.feedback(qpos, qvel, jnp.asarray(False)))
    for side in (0, 1):
        hip, ank, abd = legs.hip_pitch[side], legs.ankle_pitch[side], legs.hip_abduction[side]
        assert stance[hip] == pytest.approx(g.k_t * pitch + g.k_td * wy)
        assert stance[ank] == pytest.approx(g.k_a * pitch + g.k_d * wy)
        assert stance[abd] == pytest.approx(g.k_r * roll + g.k_rd * wx)
        assert flight[hip] == pytest.approx(g.k_x * vx)
        assert flight[ank] == 0.0
        assert flight[abd] == pytest.approx(g.k_y * vy)
    untouched = sorted(set(range(12)) - set(legs.hip_pitch + legs.ankle_pitch + legs.hip_abduction))
    assert not stance[untouched].any() and not flight[untouched].any()


def test_feedforward_and_fallen():
    g, legs = bh.BERKELEY_HOP, bh.BERKELEY_LEGS
    t = np.array([[0.0], [0.05], [0.1]])
    ff = bh.feedforward(t, np.array([1.0, 1.1]), np.array([0.0, 0.25]))
    assert ff.shape == (3, 2, 12)
    s = np.sin(2 * np.pi * (g.freq * 1.1 * 0.05 + 0.25))
    for side in (0, 1):
        assert ff[1, 1, legs.hip_pitch[side]] == pytest.approx(g.amplitude * s)
        assert ff[1, 1, legs.knee[side]] == pytest.approx(-2 * g.amplitude * s)
        assert ff[1, 1, legs.ankle_pitch[side]] == pytest.approx(g.ankle * g.amplitude * s)
    assert not ff[0, 0].any()  # sin(0) = 0
    upright = _state(np.array([1.0, 0, 0, 0]))[0]
    assert not bool(bh.fallen(upright))
    assert bool(bh.fallen(np.where(np.arange(19) == 2, 0.2, upright)))  # base at 0.2 m
    assert not bool(bh.fallen(_state(_quat((1, 1, 0), 0.7))[0]))
    assert bool(bh.fallen(_state(_quat((1, 1, 0), 0.9))[0]))


@pytest.fixture(scope="module")
def berkeley():
    return playground_offline.load("BerkeleyHumanoidJoystickFlatTerrain")


def test_hop_keeps_berkeley_humanoid_up(berkeley):
    """MuJoCo (C) on the env's model, 20 ms control as the env's, from the standing pose
    at rest at 10 phases of the cycle: measured, 9 stay upright for 4 s (the one at phase
    0.5 falls at 1.3 s). Those hop: each foot in the air 30-70 % of the time, lifting off
    at least once a cycle (f T = 13.7 cycles; bounces add more)."""
    t_end = 4.0
    runs = [bh.run_mujoco(berkeley, t_end=t_end, phase0=ph) for ph in np.arange(10) / 10]
    up = [r for r in runs if r.upright_s == t_end]
    assert len(up) >= 8, [r.upright_s for r in runs]
    cycles = bh.BERKELEY_HOP.freq * t_end
    for r in up:
        assert np.all((r.air_share > 0.3) & (r.air_share < 0.7)), r.air_share
        assert np.all(r.liftoffs >= cycles - 2), r.liftoffs


def test_hop_recovers_from_env_resets(berkeley):
    """Resets drawn as the env draws them (seeds 2000-2009; the gains were fitted on
    100-109): measured, 8 of 10 upright for the whole 3 s, one fell at 0.4 s and one at
    2.96 s (32 of 40 other held-out resets stayed up 6 s, the module docstring)."""
    runs = [
        bh.run_mujoco(berkeley, t_end=3.0, phase0=i / 10, reset_rng=np.random.default_rng(2000 + i))
        for i in range(10)
    ]
    assert sum(r.upright_s == 3.0 for r in runs) >= 7, [r.upright_s for r in runs]
