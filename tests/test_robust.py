"""The robust likelihoods and transitions (docs/model_choices.md, "Robust likelihoods").

On the analytic planar leg of ``oracle`` (Section III's leg), with the estimator of the
reproduction (``jax_contact.train.reproduce.planar_estimator_params``: ``jax_contact.params_for`` on
the planar leg's ``anymal_like`` sensors). A velocity outlier is the sensors' 10 rad/s spike
on one joint for one sample: it moves the foot velocity ``v_f = J qd`` and, through the
backward difference of ``qd``, the measured acceleration by +-10 / dt = +-4000 rad/s^2 on
the step of the spike and the next one. Each case is also run with the paper's model
(``jax_contact.train.reproduce.paper_model``), which these outliers flip: the checks can fail.
"""

from __future__ import annotations

import jax
import numpy as np
import oracle
import pytest
from test_core_limits import _as_meas

import jax_contact as jc
from jax_contact.train.reproduce import paper_model, planar_estimator_params

DT = 0.0025
SPIKE = 10.0  # rad/s, the anymal_like outlier
ROBUST = planar_estimator_params(3, DT)
PAPER = paper_model(ROBUST)
TERRAIN = jc.flat(0.0, 0.2)


def _run(jit_step, params, fields_seq):
    """P(contact) after each step of a sequence of planar-leg measurement fields."""
    belief = jc.init_belief(params)
    out = []
    for i, fields in enumerate(fields_seq):
        belief, diag = jit_step(params, TERRAIN, belief, _as_meas(fields), key=jax.random.key(i))
        out.append(float(diag.p_contact))
    return np.array(out)


def _with_outlier(state, n_steps, at, joint, sign, *, velocity=True):
    """``n_steps`` copies of one (q, qd, qdd, tau) state with one outlier at step ``at``.

    ``velocity``: a velocity spike on ``joint`` at ``at`` (and its differenced +-4000
    rad/s^2 at ``at`` and ``at + 1``); else an acceleration spike of 4000 rad/s^2 at ``at``
    alone.
    """
    q, qd, qdd, tau = state
    seq = []
    for k in range(n_steps):
        qd_k, qdd_k = np.array(qd, float), np.array(qdd, float)
        if velocity and k == at:
            qd_k[joint] += sign * SPIKE
        if k == at:
            qdd_k[joint] += sign * SPIKE / DT
        if velocity and k == at + 1:
            qdd_k[joint] -= sign * SPIKE / DT
        seq.append(oracle.planar_measurement(q, qd_k, qdd_k, tau))
    return seq


STANCE = oracle.planar_stance()
SWING = oracle.planar_swing(height=0.2)
CASES = [
    # (state, true contact, joint, sign, velocity outlier?)
    pytest.param(STANCE, True, 1, +1.0, True, id="stance-hip-velocity"),
    pytest.param(STANCE, True, 2, -1.0, True, id="stance-knee-velocity"),
    pytest.param(STANCE, True, 2, +1.0, False, id="stance-knee-acceleration"),
    pytest.param(SWING, False, 1, -1.0, True, id="swing-hip-velocity"),
    pytest.param(SWING, False, 2, +1.0, True, id="swing-knee-velocity"),
    pytest.param(SWING, False, 1, +1.0, False, id="swing-hip-acceleration"),
]


@pytest.mark.parametrize("state, contact, joint, sign, velocity", CASES)
def test_single_outlier_never_flips_a_confident_belief(
    jit_step, state, contact, joint, sign, velocity
):
    n, at = 60, 40
    p = _run(jit_step, ROBUST, _with_outlier(state, n, at, joint, sign, velocity=velocity))
    clean = _run(jit_step, ROBUST, _with_outlier(state, n, n + 5, joint, sign))
    side = p if contact else 1.0 - p  # probability of the true state
    # Confident before the outlier (the clean belief has converged by step 40).
    assert side[at - 1] > 0.99 and abs(p[at - 1] - clean[at - 1]) < 1e-6
    # Never flipped, and below 0.9 on at most one step (the outlier is evidence for
    # neither state; only one step's transition is bounded by cap_transition).
    assert side[at:].min() > 0.5, side[at:].min()
    assert np.sum(side[at:] < 0.9) <= 1
    # Back to the clean belief within a few steps.
    np.testing.assert_allclose(p[at + 4 :], clean[at + 4 :], atol=1e-3)


def test_the_paper_model_is_flipped_by_an_outlier(jit_step):
    """A knee spike in stance under the paper's pure Gaussians and uncapped transitions:
    the spike moves the foot along the normal (J_z of the knee -0.14 m), one velocity
    sample makes take-off certain, and the belief drops to air (P(C) 5e-4 measured)."""
    n, at = 60, 40
    p = _run(jit_step, PAPER, _with_outlier(STANCE, n, at, 2, -1.0))
    assert p[at - 1] > 0.99
    assert p[at:].min() < 0.5


def _slow_low_swing():
    """The sole 1.5 cm above the floor moving at 0.2 m/s, leg in free flight."""
    q, qd, qdd, tau = oracle.planar_swing(height=0.015, qd_leg=(1.0, -0.5), tau_leg=(1.0, -1.0))
    model = oracle.planar_leg(q, qd)
    speed = np.linalg.norm(model["v_f"])
    qd = qd * (0.2 / speed)  # scale the joint velocities to a 0.2 m/s foot
    qdd = np.linalg.solve(oracle.planar_leg(q, qd)["M"], tau - oracle.planar_leg(q, qd)["h"])
    return q, qd, qdd, tau


def test_slow_low_swing_foot_no_longer_held_in_contact(jit_step):
    """After 40 steps of stance the foot lifts 1.5 cm and moves at 0.2 m/s in free flight
    with light torques. Measured per-step evidence (log-likelihood ratios), robust model:
    dynamics -1.24 (the light torques barely tell a free leg from a pinned one; the rail's
    acceleration read by an accelerometer, 2 m/s^2), kinematics -0.12, differential
    kinematics +0.62 (its still-side cap, 0.65 at 400 Hz): -0.73 per step, so the belief
    falls below 0.5 on the 8th swing step (20 ms) and reaches the transitions' floor. The
    paper's symmetric 0.9 cap gives the still foot +2.20 per step (-1.08 dynamics): +1.0
    per step for contact, and it holds the foot on the ground."""
    swing = _slow_low_swing()
    np.testing.assert_allclose(np.linalg.norm(oracle.planar_leg(*swing[:2])["v_f"]), 0.2)
    meas = _as_meas(oracle.planar_measurement(*swing))
    tq = TERRAIN.query(meas.p_f, meas.p_f, False)

    def evidence(params):
        t = jc.measurement_terms(params, meas, tq)
        return float(t.dynamics + t.diff_kinematics + t.kinematics)

    assert evidence(ROBUST) < 0.0 < 0.5 < evidence(PAPER)
    seq = [oracle.planar_measurement(*STANCE)] * 40 + [oracle.planar_measurement(*swing)] * 40
    p = _run(jit_step, ROBUST, seq)
    paper = _run(jit_step, PAPER, seq)
    assert p[39] > 0.99 and paper[39] > 0.99
    # Falls monotonically (float32 ties once at the floor), below 0.5 within 10 steps.
    assert np.all(np.diff(p[40:]) <= 0) and p[-1] < 0.01
    assert 40 < np.argmax(p < 0.5) <= 50
    assert paper[-1] > 0.99


def test_sliding_stance_foot_is_contact_evidence_a_rising_one_is_not():
    """The sliding contact (docs/model_choices.md, "A sliding contact"): the planar leg in
    its stance pose, base still, joints moving the foot at 1 m/s.

    Along the floor (x): eq. 9's still foot (``slip_prob`` 0) calls it air at the cap,
    -logit(0.9); the defaults' sliding component (weight 0.3, tangential std 1 m/s) keeps
    the normal velocity at its noise and lets the foot move along the floor, so the same
    reading is weak evidence for contact (measured +0.42, below the still-side cap
    logit(0.65) = 0.62). Along the normal (z, a rising foot): 1 m/s is ~10 std of the
    normal velocity's noise (sigma_qd 0.3 rad/s through J), so both models call it air at
    the cap: sliding does not excuse a foot leaving the ground.
    """
    q, qd, qdd, tau = oracle.planar_stance()
    J = oracle.planar_leg(q, qd)["J"][[0, 2]][:, 1:]  # x and z rows, the leg's two joints
    still = ROBUST.replace(slip_prob=ROBUST.slip_prob * 0)
    air_cap = -np.log(0.9 / 0.1)

    def llr(params, v_xz):
        qd_leg = np.linalg.solve(J, np.asarray(v_xz, float))
        meas = _as_meas(oracle.planar_measurement(q, np.array([0.0, *qd_leg]), qdd, tau))
        return float(jc.diff_kinematics_llr(params, meas))

    assert float(ROBUST.slip_prob) == np.float32(0.3)
    slide = llr(ROBUST, (1.0, 0.0))
    assert 0.2 < slide < np.log(0.65 / 0.35) - 0.1, slide
    np.testing.assert_allclose(llr(still, (1.0, 0.0)), air_cap, rtol=1e-6)
    np.testing.assert_allclose(llr(ROBUST, (0.0, 1.0)), air_cap, rtol=1e-6)
    np.testing.assert_allclose(llr(still, (0.0, 1.0)), air_cap, rtol=1e-6)
