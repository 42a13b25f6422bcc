"""The open-loop gaits in place (envs/scripted.py), against hand-computed values."""

import numpy as np
import pytest

from jax_contact.envs import scripted


def test_swing_profile_by_hand():
    # freq 1 Hz, swing 0.2 of the cycle, phase 0: the swing spans t in [0, 0.2) s, its
    # apex at 0.1 s (sin^2(pi/2) = 1), a quarter of it at 0.05 s (sin^2(pi/4) = 1/2); the
    # rest of the cycle is stance (0). Phase 0.25 moves the swing to t in [0.75, 0.95).
    t = np.array([[0.0], [0.05], [0.1], [0.15], [0.2], [0.5], [0.8], [1.1]])
    got = scripted.swing_profile(t, 1.0, np.array([0.0, 0.25]), 0.2)
    want = np.array(
        [
            [0.0, 0.0],
            [0.5, 0.0],
            [1.0, 0.0],
            [0.5, 0.0],
            [0.0, 0.0],
            [0.0, 0.0],
            [0.0, 0.5],
            [1.0, 0.0],
        ]
    )
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_walk_has_one_leg_in_the_air_and_trot_moves_diagonal_pairs_together():
    t = np.arange(1, 401)[:, None] * 0.005  # 2 s
    rate, phase0 = np.array([1.0, 1.1]), np.array([0.0, 0.3])
    walk = scripted.in_place_offsets("walk", "Go1", t, rate, phase0)
    assert walk.shape == (400, 2, 12)
    hip = walk[..., 1::3]  # (T, E, 4) hip pitch offsets
    # Walk: swings 0.2 of a cycle, legs 0.25 apart -> never two legs in the air.
    assert ((hip > 0).sum(axis=-1) <= 1).all()
    assert (hip > 0).any(axis=(0, 1)).all()  # every leg swings
    np.testing.assert_allclose(hip.max(), 0.3, atol=1e-3)  # apex: hip 0.3 rad
    np.testing.assert_allclose(walk[..., 2::3], -2.0 * hip, atol=1e-12)  # knee -0.6 at apex
    assert (walk[..., 0::3] == 0).all()  # hip abduction untouched
    trot = scripted.in_place_offsets("trot", "Go1", t, rate, phase0)
    # Go1's order FR FL RR RL: FR with RL, FL with RR; the pairs never overlap.
    np.testing.assert_array_equal(trot[..., 1], trot[..., 10])
    np.testing.assert_array_equal(trot[..., 4], trot[..., 7])
    assert not ((trot[..., 1] > 0) & (trot[..., 4] > 0)).any()


def test_bad_policy_or_robot_named():
    t = np.zeros((3, 1))
    with pytest.raises(ValueError, match="policy must be one of"):
        scripted.in_place_offsets("gallop", "Go1", t, np.ones(1), np.zeros(1))
    with pytest.raises(ValueError, match="'Anymal'"):
        scripted.in_place_offsets("walk", "Anymal", t, np.ones(1), np.zeros(1))


def test_rates_scenes_drive_go1_with_the_gaits_in_place():
    from jax_contact.train import rates

    env, acts = rates.scene("go1_walk", n_steps=60, n_rollouts=3)
    assert acts.shape == (60, 3, 12)
    home = env.sys.mj_model.key_ctrl[0]
    # Rollout e runs at 1 + 0.02 e times the gait's frequency, phase 0 (module docstring).
    t = np.arange(1, 61)[:, None] * 0.02
    want = home + scripted.in_place_offsets("walk", "Go1", t, 1 + 0.02 * np.arange(3), np.zeros(3))
    np.testing.assert_allclose(acts, want, atol=1e-6)
    with pytest.raises(ValueError, match="scene must be one of"):
        rates.scene("go1_gallop")
