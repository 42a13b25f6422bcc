"""Hand-derived limiting cases on a physically consistent planar leg.

The leg is the paper's Section III example (Table I masses and inertias; link lengths and
foot radius as chosen in ``envs/assets/planar_leg.xml``): q = (base height on a vertical
rail, hip, knee), modelled analytically in ``oracle.planar_leg`` (checked here against
MuJoCo when the MJCF file is present). The force rows are x and z (``force_rows=(0, 2)``),
the terrain a flat floor at z = 0 with the normal e = (0, 0, 1), dt = 2.5 ms,
T_s = T_sw = 0.3 s, a_F = 200 m/s^2, caps 0.99 / 0.9 / 0.99, Table II's noise unless a
case says otherwise. Each expected value carries its derivation.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from scipy.stats import norm

from jax_contact import LegMeasurement, flat, init_belief, make_noise, make_params

PARAMS = make_params(make_noise(3, **oracle.TABLE_II), force_rows=(0, 2), touchdown="quadrature")
DT, T_S = 0.0025, 0.3
P_OFF = DT / T_S  # gait prior P(A | C), eq. 12
LOGIT = lambda p: math.log(p / (1 - p))  # noqa: E731
CAP_DYN, CAP_DK, CAP_KIN = 0.99, 0.9, 0.99
XML = Path(__file__).resolve().parents[1] / "envs" / "assets" / "planar_leg.xml"


def _float64_fields(params) -> dict:
    """The float64 oracle's ``Params`` fields read from an ``EstimatorParams`` (and its
    noise model)."""
    out = {}
    for field in dataclasses.fields(oracle.Params):
        src = params if hasattr(params, field.name) else params.noise
        v = getattr(src, field.name)
        if field.name == "force_rows":
            out[field.name] = tuple(int(i) for i in v)
        elif isinstance(v, bool):
            out[field.name] = v
        else:
            out[field.name] = np.asarray(v, np.float64) if np.ndim(v) else float(v)
    return out


def _as_meas(fields) -> LegMeasurement:
    def conv(x):
        x = np.asarray(x)
        return jnp.asarray(x, jnp.int32 if np.issubdtype(x.dtype, np.integer) else jnp.float32)

    return LegMeasurement(**{k: conv(v) for k, v in fields.items()})


def _steps(jit_step, params, terrain, meas, n):
    """n steps from P(C) = 0.5 with the same measurement; the diagnostics of each."""
    belief = init_belief(params)
    out = []
    for i in range(n):
        belief, diag = jit_step(params, terrain, belief, meas, key=jax.random.key(i))
        out.append((belief, diag))
    return out


def test_analytic_planar_leg_matches_mujoco():
    """The hand-written model (Kane's method) against MuJoCo's M, h, J, Jdot qd and p_f."""
    import mujoco  # a dependency of the package: missing, the test fails, never skips

    model = mujoco.MjModel.from_xml_path(str(XML))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    site = model.site("foot").id
    for _ in range(5):
        q = np.array([rng.uniform(0.3, 0.5), rng.uniform(-1.5, 1.5), rng.uniform(-2.6, -0.1)])
        qd = rng.normal(scale=3.0, size=3)
        data.qpos[:], data.qvel[:] = q, qd
        mujoco.mj_forward(model, data)
        M = np.zeros((3, 3))
        mujoco.mj_fullM(model, data, M)  # mujoco 3.17's signature (m, d, dst)
        jacp, jacr = np.zeros((3, 3)), np.zeros((3, 3))
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        jdot, jrdot = np.zeros((3, 3)), np.zeros((3, 3))
        mujoco.mj_jacDot(model, data, jdot, jrdot, data.site_xpos[site], model.site_bodyid[site])
        ours = oracle.planar_leg(q, qd)
        np.testing.assert_allclose(ours["M"], M, atol=1e-12)
        np.testing.assert_allclose(ours["h"], data.qfrc_bias, atol=1e-10)
        np.testing.assert_allclose(ours["J"], jacp, atol=1e-12)
        np.testing.assert_allclose(ours["Jdot_qd"], jdot @ qd, atol=1e-10)
        np.testing.assert_allclose(ours["p_f"], data.site_xpos[site], atol=1e-12)


def test_loaded_still_foot_on_the_ground(jit_step):
    """A standing leg (hip 0.6, knee -1.2 rad), qd = 0, qdd = 0, sole on the floor.

    Equation of motion with qdd = 0: tau = h + J^T F; its unactuated rail row
    0 = h_z + F_z gives F_z = -(5.449 + 2.48 + 0.31) kg * 9.81 = -80.82 N: the foot
    pushes down with the robot's weight (e . F < 0) and the leg torques are
    tau_l = h_l + J_l^T F.

    * Dynamics: eq. 6 with qdd_b = 0, Jdot qd = 0 and tau_l - h_l = J_l^T F gives
      F_hat = (Lambda^-1 + eps I)^-1 Lambda^-1 F = F (1 + O(eps Lambda)), so the contact
      prediction qdd_C = M_l^-1 J_l^T (F - F_hat) = 0 is what is measured, while the free
      leg would accelerate at qdd_A = M_l^-1 J_l^T F = (-221, 1035) rad/s^2. The raw LLR
      is +11.7 (Table II noise), above logit(0.99) = 4.595: capped, P_dyn = 0.99 exactly.
      The unilateral factor is log Phi(80.8 / 10) ~ -3e-16.
    * Differential kinematics: v_f = 0, so LLR = 0.5 log det(S + J_l P J_l^T) / det(S)
      = +7.1 with the 25 rad/s prior, capped: P_dk = 0.9.
    * Kinematics: the sole is on the mean terrain, gap = 0, so P(phi <= 0) = 1/2: neutral.
    * Step 1 from b_0 = 1/2 with the gait prior (T_s = T_sw, so the prior is symmetric):
      prior logit 0, posterior logit = logit(0.99) + logit(0.9) + 0 = 6.792, P = 0.99888.
      Later steps add the same 6.792 to a prior that stays above 1/2, so P > 0.99 holds.
    """
    meas = _as_meas(oracle.planar_measurement(*oracle.planar_stance()))
    out = _steps(jit_step, PARAMS, flat(0.0, 0.05), meas, 4)
    _, d1 = out[0]
    np.testing.assert_allclose(float(d1.p_dynamics), CAP_DYN, rtol=1e-6)
    np.testing.assert_allclose(float(d1.p_diff_kinematics), CAP_DK, rtol=1e-6)
    np.testing.assert_allclose(float(d1.p_kinematics), 0.5, atol=1e-6)
    total = LOGIT(CAP_DYN) + LOGIT(CAP_DK)
    np.testing.assert_allclose(float(out[0][0].logit), total, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(d1.force), [0.0, 0.0, -80.8245], atol=2e-3)
    for belief, diag in out[1:]:
        assert float(diag.p_contact) > 0.99
        # Foothold memory: the sole point on the floor was remembered.
        np.testing.assert_allclose(np.asarray(belief.foothold), [0.0, 0.0, 0.0], atol=1e-6)


def test_foothold_memory_averages_the_stance_height(jit_step):
    """The standing leg above (sole at z = 0, confident and still from the first step) under
    a foothold memory with smoothing 1/2, its belief starting from a remembered foothold
    2 cm up at another x (a base estimate that drifted since): each stance step halves the
    remembered height's offset, z_k = z_{k-1} / 2 + 0 / 2 = 0.02 / 2^k, and takes the sole's
    x, y. With smoothing 1 the sole is kept as it is (z = 0 after one step).
    FootholdMemory.remember by hand: not set yet -> the sole itself."""
    from jax_contact import foothold_memory

    sole = jnp.array([0.3, -0.1, 0.05])
    memo = foothold_memory(flat(0.0, 0.05), 0.02, 0.3, smoothing=0.25)
    np.testing.assert_allclose(memo.remember(jnp.zeros(3), jnp.array(False), sole), sole)
    got = memo.remember(jnp.array([9.0, 9.0, 0.09]), jnp.array(True), sole)
    np.testing.assert_allclose(got, [0.3, -0.1, 0.75 * 0.09 + 0.25 * 0.05], rtol=1e-6)

    meas = _as_meas(oracle.planar_measurement(*oracle.planar_stance()))
    for smoothing, want in ((0.5, [0.01, 0.005, 0.0025, 0.00125]), (1.0, [0.0] * 4)):
        terrain = foothold_memory(flat(0.0, 0.05), 0.02, 0.3, smoothing=smoothing)
        belief = init_belief(PARAMS).replace(
            foothold=jnp.array([0.1, 0.0, 0.02]), foothold_valid=jnp.array(True)
        )
        for i, z in enumerate(want):
            belief, diag = jit_step(PARAMS, terrain, belief, meas, key=jax.random.key(i))
            assert float(diag.p_contact) > 0.99
            np.testing.assert_allclose(np.asarray(belief.foothold), [0.0, 0.0, z], atol=1e-7)


def test_height_field_normal_of_a_plane_is_exact_on_its_border():
    """Heights [[0, .1], [.2, .3]] on a 1 m grid are the plane z = 0.1 x + 0.2 y, whose
    normal is (-0.1, -0.2, 1) / |.| everywhere on the grid, its corners and edges included
    (the clip's derivative of 1/2 at a bound halved the slope there); outside the grid the
    surface is continued flat (normal z)."""
    from jax_contact import height_field

    hf = height_field([[0.0, 0.1], [0.2, 0.3]], origin=(0.0, 0.0), spacing=(1.0, 1.0))
    want = np.array([-0.1, -0.2, 1.0]) / math.sqrt(1.05)
    none = (jnp.zeros(3), jnp.array(False))
    for x, y in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5), (0.0, 0.3)):
        q = hf.query(jnp.array([x, y, 0.5]), *none)
        np.testing.assert_allclose(np.asarray(q.normal), want, atol=1e-6, err_msg=str((x, y)))
        assert float(q.height) == pytest.approx(0.1 * x + 0.2 * y, abs=1e-6)
    q = hf.query(jnp.array([2.0, 3.0, 0.5]), *none)
    np.testing.assert_allclose(np.asarray(q.normal), [0.0, 0.0, 1.0], atol=1e-7)
    assert float(q.height) == pytest.approx(0.3, abs=1e-6)


def test_fast_swing_foot_high_above_the_ground(jit_step):
    """The free leg swinging with its foot 0.2 m up at ~2 m/s (qd = (0, 6, -3) rad/s),
    qdd = M^-1 (tau - h) the free dynamics (rail included) under tau = (0, 5, -3) N m.

    * Dynamics: the measured qdd_l equals the air prediction, and
      LLR = -0.5 d^T Sigma_C^-1 d - 0.5 log(det Sigma_C / det Sigma_A) with d = qdd_A - qdd_C
      != 0 and Sigma_C >= Sigma_A, so LLR < 0 (-12.2 here), and the unilateral factor only
      lowers it: P_dyn < 1/2 (capped: 0.01).
    * Differential kinematics: |v_f| = 2 m/s against a still-foot std of ~0.15 m/s, LLR
      ~ -86, capped: P_dk = 0.1.
    * Kinematics: gap 0.2 m, sigma_pf = sqrt(0.04^2 + (0.161 * 0.02)^2 + ...) = 0.0402 m,
      sigma_pi = 0.05 m, so P(phi <= 0) = Phi(-0.2 / 0.0641) = Phi(-3.12) = 9e-4,
      LLR = -7.0, capped: P_kin = 0.01.
    * Step 1: logit = 0 - 4.595 - 2.197 - 4.595 = -11.39, P = 1.1e-5.
    * Touch-down: the foot moves sideways (u = -0.04 m/s), 5 sigma_pf above the floor's
      mean, so P(C|A) is small: 1.30e-5 by the float64 oracle's integral (its step, run
      beside the estimator's). Every later step adds
      -11.39 to a prior logit of at most log(P(C|A) / P(A|A)) + log 2 = -10.6, so P stays
      below 1e-4 < 0.01.
    """
    meas64 = oracle.planar_measurement(*oracle.planar_swing(0.2, 0.3, -1.0, (6.0, -3.0)))
    meas = _as_meas(meas64)
    v = np.asarray(meas.v_f)
    assert 1.9 < np.linalg.norm(v) < 2.1
    out = _steps(jit_step, PARAMS, flat(0.0, 0.05), meas, 4)
    _, d1 = out[0]
    np.testing.assert_allclose(float(d1.p_dynamics), 1 - CAP_DYN, rtol=1e-4)
    np.testing.assert_allclose(float(d1.p_diff_kinematics), 1 - CAP_DK, rtol=1e-4)
    np.testing.assert_allclose(float(d1.p_kinematics), 1 - CAP_KIN, rtol=1e-4)
    np.testing.assert_allclose(
        float(out[0][0].logit), -(2 * LOGIT(CAP_DYN) + LOGIT(CAP_DK)), rtol=1e-5
    )
    ref = oracle.Params(**_float64_fields(PARAMS))
    b_ref = oracle.init_belief(ref)
    for belief, diag in out:
        b_ref, d_ref = oracle.step(ref, oracle.Flat(0.0, 0.05), b_ref, oracle.Meas(**meas64))
        assert float(diag.p_contact) < 1e-4
        np.testing.assert_allclose(float(diag.p_touchdown), d_ref["p_touchdown"], rtol=0.02)
        assert not bool(belief.foothold_valid)


def _lifting_foot(u):
    """Standing leg (hip 0.6, knee -1.2) whose joints lift the foot straight up at u m/s."""
    q, _, qdd, tau = oracle.planar_stance()
    J = oracle.planar_leg(q, np.zeros(3))["J"]
    qd = np.zeros(3)
    qd[1:] = np.linalg.solve(J[np.ix_([0, 2], [1, 2])], [0.0, u])
    fields = oracle.planar_measurement(q, qd, qdd, tau)
    np.testing.assert_allclose(fields["v_f"], [0.0, 0.0, u], atol=1e-12)
    return _as_meas(fields), J


def _expected_takeoff(u, sigma_v, a_f=200.0):
    """eq. 11-15 by hand: P(A|C) = p U / (p U + (1 - p) N), p = dt / T_s,
    N = phi(u / s) / s (eq. 13), U = [Phi(u / s) - Phi((u - u_max) / s)] / u_max (eq. 15)."""
    u_max = a_f * DT
    n = norm.pdf(u / sigma_v) / sigma_v
    uni = (norm.cdf(u / sigma_v) - norm.cdf((u - u_max) / sigma_v)) / u_max
    return P_OFF * uni / (P_OFF * uni + (1 - P_OFF) * n)


def test_stance_foot_accelerating_upward(jit_step):
    """A foot on the floor lifting at u = a_F dt / 2 = 0.25 m/s (the middle of eq. 15's
    uniform take-off velocities on [0, u_max = 0.5 m/s]).

    sigma_v^2 = e^T J diag(sigma_qd^2) J^T e with e^T J = (1, 0, -0.1412) at this pose.

    * A filtered velocity estimate, sigma_qd = 0.02 everywhere: sigma_v = 0.0202 m/s,
      u / sigma_v = 12.4, N = phi(12.4) / 0.0202 ~ 1e-32 against p U = (1/120) (1/0.5)
      = 0.0167, so P(A|C) = 1 - 6e-31 (P(C|C) floored at e^-30): take-off is certain.
    * Table II's velocity noise (0.2 m/s on the base): sigma_v = 0.2045 m/s,
      u / sigma_v = 1.222, N = 0.923, U = (Phi(1.222) - Phi(-1.222)) / 0.5 = 1.557, so
      P(A|C) = 0.01297 / (0.01297 + 0.9155) = 0.0140: barely above the 1/120 = 0.0083
      prior -- a 0.25 m/s lift is within the velocity noise.
    * A still foot (u = 0), Table II: P(A|C) = p (1/2 - Phi(-2.445)) / 0.5 / (p (...) +
      (1 - p) / (sqrt(2 pi) 0.2045)) = 0.008213 / (0.008213 + 1.9345) = 0.00423: below the
      prior.
    """
    u = 200.0 * DT / 2
    meas, J = _lifting_foot(u)
    je = J[2]  # e^T J with e = z
    for sigma_qd, expected, rtol in [
        (0.02, 1.0, 1e-6),
        (oracle.TABLE_II["sigma_qd"], 0.013982, 2e-3),
    ]:
        params = PARAMS.replace(noise=make_noise(3, **dict(oracle.TABLE_II, sigma_qd=sigma_qd)))
        sigma_v = math.sqrt(float(np.sum(je**2 * np.broadcast_to(sigma_qd, 3) ** 2)))
        hand = _expected_takeoff(u, sigma_v)
        np.testing.assert_allclose(hand, expected, rtol=rtol)
        (_, diag), *_ = _steps(jit_step, params, flat(0.0, 0.05), meas, 1)
        np.testing.assert_allclose(float(diag.p_takeoff), hand, rtol=1e-4)
    assert float(diag.p_takeoff) > P_OFF  # evidence for take-off, however weak
    still, _ = _lifting_foot(0.0)
    (_, diag), *_ = _steps(jit_step, PARAMS, flat(0.0, 0.05), still, 1)
    sigma_v = math.sqrt(float(np.sum(je**2 * np.asarray(oracle.TABLE_II["sigma_qd"]) ** 2)))
    np.testing.assert_allclose(float(diag.p_takeoff), _expected_takeoff(0.0, sigma_v), rtol=1e-4)
    np.testing.assert_allclose(float(diag.p_takeoff), 0.004227, rtol=2e-3)


def _foot_above(gap, u):
    """The leg at hip 0.3, knee -1.0 with its sole ``gap`` above the floor and the knee
    turning so that the foot's vertical velocity is u (m/s)."""
    q = np.array([oracle.base_height_for(0.3, -1.0, gap), 0.3, -1.0])
    J = oracle.planar_leg(q, np.zeros(3))["J"]
    qd = np.array([0.0, 0.0, u / J[2, 2]])
    fields = oracle.planar_measurement(q, qd, np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(fields["v_f"][2], u, rtol=1e-12)
    np.testing.assert_allclose(fields["p_f"][2] - oracle.LEG["radius"], gap, atol=1e-12)
    return _as_meas(fields)


# Near-exact position and velocity estimates (sigma_pf ~ 1e-5 m, sigma_u ~ 1e-4 m/s), so
# that Algorithm 1's integral reduces to the truncated terrain height alone.
SHARP = dict(oracle.TABLE_II, sigma_q=1e-5, sigma_qd=1e-4)


@pytest.mark.parametrize(
    "sigma_pi, expected",
    # (Phi(z_f) - Phi(z_f - |u| dt / sigma_pi)) / Phi(z_f), z_f = gap / sigma_pi:
    [(0.01, (0.6179114 - 0.4207403) / 0.6179114), (0.001, (0.9986501 - 0.0227501) / 0.9986501)],
    ids=["sigma_pi_1cm", "sigma_pi_1mm"],
)
def test_foot_falling_fast_just_above_the_ground(sigma_pi, expected, jit_step):
    """Sole 3 mm above the floor, falling at u = -2 m/s: in one step it travels
    |u| dt = 5 mm, so it lands unless the true floor is more than 2 mm below its mean.

    With p_f and u known exactly, Algorithm 1 averages over the terrain height
    p_i ~ N(0, sigma_pi^2) truncated to p_i <= p_f = 3 mm the indicator p_i > p_f - 5 mm:
    P(C|A) = (Phi(z_f) - Phi(z_f - 5 mm / sigma_pi)) / Phi(z_f), z_f = 3 mm / sigma_pi.

    * sigma_pi = 1 cm: (Phi(0.3) - Phi(-0.2)) / Phi(0.3) = 0.3191. A 1 cm terrain may lie
      a centimetre lower, so one step of 5 mm lands with probability ~1/3 only; it is
      still 30 times docs/model.md's ~1e-2 for a foot falling at 2 m/s over a vague terrain.
    * sigma_pi = 1 mm (e.g. the foothold memory at the same spot):
      (Phi(3) - Phi(-2)) / Phi(3) = 0.9772: touch-down is near certain.
    """
    params = PARAMS.replace(noise=make_noise(3, **SHARP))
    meas = _foot_above(0.003, -2.0)
    (_, diag), *_ = _steps(jit_step, params, flat(0.0, sigma_pi), meas, 1)
    # The derivation neglects sigma_pf / sigma_pi <= 1e-2 and the quadrature's ~1e-3.
    np.testing.assert_allclose(float(diag.p_touchdown), expected, rtol=5e-3)
    assert float(diag.p_touchdown) > 0.3


def test_foot_moving_away_never_touches_down(jit_step):
    """Sole 3 mm above a sharp floor (sigma_pi = 1 cm) moving away at u = +1 m/s.

    A touch-down needs the next-step gap p_f + dt u' - p_i < 0 with p_i <= p_f, so it needs
    u' < 0: P(C|A) <= P(u' < 0) = Phi(-u / sigma_u). With Table II's sigma_u = 0.2 m/s that
    bound is Phi(-4.9) = 5e-7 (and the true value far smaller, since u' just below zero
    closes at most a few microns); with sigma_u = 1e-4 m/s it is 0, floored at e^-30.
    """
    meas = _foot_above(0.003, 1.0)
    for noise, bound in [(oracle.TABLE_II, 5e-7), (SHARP, math.exp(-30) * 1.001)]:
        params = PARAMS.replace(noise=make_noise(3, **noise))
        (_, diag), *_ = _steps(jit_step, params, flat(0.0, 0.01), meas, 1)
        p = float(diag.p_touchdown)
        assert math.exp(-30) * 0.999 <= p <= bound, p
