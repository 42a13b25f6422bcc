"""An independent float64 NumPy/SciPy oracle of the contact estimator, for tests only.

Written from the project's model specification alone (docs/model.md restates it), with
explicit loops, and sharing no code with ``jax_contact`` (which it never imports). It
follows the modelling choices the library documents:

* dynamics (eq. 4-7): only the rows ``force_rows`` of ``J``; the contact force from the
  damped operational-space system ``(J M^-1 J^T + inv_damping I) F = ...``, solved here as
  the equivalent *compliant-contact KKT system* rather than by the formula of eq. 6;
  ``Sigma_d = diag(sigma_d_l^2) + M_lb diag(sigma_qdd_b^2) M_lb^T``; the stabilised
  contact constraint ``J qdd + Jdot qd = -contact_damping min(e . v_f, 0) e`` with its
  velocity noise added to ``Sigma_f``; with ``unilateral`` the
  contact log-likelihood gains ``log Phi((-(e.F) - min_push) / sqrt(sum_r e_r^2
  sigma_f,r^2))``;
* differential kinematics (eq. 8-9): all three rows of ``J``; with ``slip_prob`` rho the
  contact hypothesis is the mixture of the still foot and a foot sliding along the
  terrain's tangent plane; the kinematic terms read the state ``kinematics_lead`` of the
  way to the end of the measured interval;
* the outlier model: the dynamics and differential-kinematics densities of both hypotheses
  mixed with one shared broad uniform component of weight ``outlier_prob``;
* kinematics (eq. 10): the sole ``p_f - r e``, the terrain point ``p_i`` below the foot
  centre at the terrain's height, gap ``e . (p_sole - p_i)``,
  ``sigma_pf^2 = e^T J diag(sigma_q^2) J^T e``, ``phi ~ N(gap, sigma_pf^2 + sigma_pi^2)``;
* every term's log-likelihood ratio clipped to ``+-logit(cap)`` (no clipping for cap = 1);
* take-off (eq. 11-15) with the ``1 / u_max`` of the uniform density and Bayes'
  normalisation against the gait prior ``dt / T_s``;
* touch-down (eq. 16-17, Algorithm 1 with docs/model.md's sign), as a nested adaptive
  ``scipy.integrate.quad`` over the foot height and the *truncated terrain height* (the
  velocity is integrated analytically, as in Algorithm 1) -- a different route from the
  library's quadrature, which integrates the terrain height analytically -- or by a NumPy
  Monte-Carlo with ``scipy.stats.truncnorm`` draws;
* log transition entries floored at ``LOG_FLOOR``; with ``cap_transition`` < 1 each
  transition's leaving log-odds clipped from above to ``logit(cap_transition)``;
* the recursion (eq. 1-2) in probability space with explicit normalisation, the belief
  reported as a logit, the transition built from step ``t``'s measurement used at ``t+1``;
* a coordinate outside the leg that neither the leg's rows of ``M`` nor ``J`` involve
  (every such entry exactly zero: another leg's joint) has its velocity and acceleration
  read as 0;
* an invalid measurement (a NaN or inf in what the foot's terms read: the leg's rows of
  ``M``, its ``tau`` and ``h``, the accelerations, the other coordinates' velocities,
  ``J``, ``Jdot_qd``, ``p_f``, ``v_f``, the radius; not ``q``): transition-only
  prediction, next transition the gait prior, foothold kept, ``valid = False``;
* the foothold (sole point) remembered when the posterior exceeds
  ``foothold_confidence`` and (with ``foothold_still``) the differential-kinematics term
  says the foot is still.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
from scipy import integrate, special, stats

LOG_FLOOR = -30.0
# The library adds 1e-12 m^2 (or (m/s)^2) under the square roots of sigma_pf and sigma_v so
# that a foot whose Jacobian has no component along e keeps a finite std; it shifts those
# stds by up to 1e-7 relative for 1 mm stds, far below float32 resolution but visible in a
# float64 comparison, so the oracle mirrors this numerical guard (not a modelling choice).
VAR_GUARD = 1e-12
F64 = np.float64


@dataclasses.dataclass
class Params:
    """Float64 copy of the estimator's parameters (names as in ``EstimatorParams``)."""

    sigma_q: np.ndarray
    sigma_qd: np.ndarray
    sigma_qdd: np.ndarray
    sigma_d: np.ndarray
    sigma_f: np.ndarray
    sigma_J: np.ndarray
    sigma_qd_prior: np.ndarray
    dt: float
    stance_time: float
    swing_time: float
    takeoff_accel: float
    cap_dynamics: float
    cap_diff_kinematics: float
    cap_kinematics: float
    inv_damping: float
    initial_contact: float
    cap_diff_kinematics_still: float = 0.9
    cap_transition: float = 1.0
    outlier_prob: float = 0.0
    outlier_qdd: float = 8000.0
    outlier_v: float = 4.0
    foothold_confidence: float = 0.5
    force_rows: tuple[int, ...] = (0, 1, 2)
    unilateral: bool = True
    kinematics_neutral_below: bool = True
    foothold_still: bool = True
    contact_damping: float = 0.0
    kinematics_lead: float = 0.0
    min_push: float = 0.0
    slip_prob: float = 0.0
    slip_speed: float = 0.5


@dataclasses.dataclass
class Meas:
    """One foot's measurement (names and shapes as in ``LegMeasurement``)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    M: np.ndarray
    h: np.ndarray
    J: np.ndarray
    Jdot_qd: np.ndarray
    p_f: np.ndarray
    v_f: np.ndarray
    foot_radius: float
    leg_dofs: np.ndarray
    other_dofs: np.ndarray


@dataclasses.dataclass
class Query:
    """A terrain model's answer: mean height, its std, unit normal out of the ground."""

    height: float
    sigma: float
    normal: np.ndarray


@dataclasses.dataclass
class Flat:
    height: float
    sigma: float

    def query(self, p, foothold, foothold_valid) -> Query:
        return Query(self.height, self.sigma, np.array([0.0, 0.0, 1.0]))

    def remember(self, foothold, foothold_valid, sole):
        return np.array(sole, dtype=float)


@dataclasses.dataclass
class Foothold:
    """Foothold memory over a flat fallback: sigma^2 = s0^2 + (growth d_xy)^2; the height
    remembered as z <- (1 - smoothing) z + smoothing z_sole once a foothold is set."""

    fallback: Flat
    sigma_foothold: float
    growth: float
    smoothing: float = 1.0

    def remember(self, foothold, foothold_valid, sole):
        out = np.array(sole, dtype=float)
        if foothold_valid:
            out[2] = (1.0 - self.smoothing) * foothold[2] + self.smoothing * sole[2]
        return out

    def query(self, p, foothold, foothold_valid) -> Query:
        base = self.fallback.query(p, foothold, foothold_valid)
        dx = p[0] - foothold[0]
        dy = p[1] - foothold[1]
        sigma = math.sqrt(self.sigma_foothold**2 + self.growth**2 * (dx * dx + dy * dy))
        if foothold_valid and sigma < base.sigma:
            return Query(float(foothold[2]), sigma, base.normal)
        return base


@dataclasses.dataclass
class Belief:
    logit: float
    log_transition: np.ndarray  # (2, 2), rows state at t (C, A), columns state at t+1
    foothold: np.ndarray
    foothold_valid: bool


# --------------------------------------------------------------------------- helpers


def _logit(p: float) -> float:
    return math.log(p) - math.log1p(-p)


def cap(llr: float, c: float, c_contact: float | None = None) -> float:
    """Clip a log-likelihood ratio to [-logit(c), logit(c_contact or c)]; 1 is unbounded."""
    lo = math.inf if c >= 1.0 else _logit(c)
    c_up = c if c_contact is None else c_contact
    hi = math.inf if c_up >= 1.0 else _logit(c_up)
    return min(max(llr, -lo), hi)


def mixed(log_p: float, eps: float, log_u: float) -> float:
    """log[(1-eps) p + eps U]: a density with the broad outlier component."""
    if eps <= 0.0:
        return log_p
    return float(np.logaddexp(math.log1p(-eps) + log_p, math.log(eps) + log_u))


def robust(log_c: float, log_a: float, eps: float, log_u: float) -> float:
    """log[(1-eps) p_C + eps U] - log[(1-eps) p_A + eps U] (the shared outlier component)."""
    return mixed(log_c, eps, log_u) - mixed(log_a, eps, log_u)


def _sub(A, rows, cols):
    out = np.zeros((len(rows), len(cols)))
    for i, r in enumerate(rows):
        for j, c in enumerate(cols):
            out[i, j] = A[r, c]
    return out


def _log_phi_diff(a: float, b: float) -> float:
    """log(Phi(a) - Phi(b)), a >= b, from whichever tail is small."""
    if b > 0.0:
        hi, lo = special.log_ndtr(-b), special.log_ndtr(-a)
    else:
        hi, lo = special.log_ndtr(a), special.log_ndtr(b)
    return hi + math.log1p(-math.exp(lo - hi)) if lo < hi else -math.inf


# --------------------------------------------------------------------------- terms


def dynamics(p: Params, m: Meas, e: np.ndarray):
    """Dynamics term (eq. 4-7).

    Returns:
      (capped LLR, contact force (3,), dict of intermediates: raw LLR, qdd_air, qdd_contact).
    """
    legs = [int(i) for i in m.leg_dofs]
    base = [int(i) for i in m.other_dofs]
    rows = list(p.force_rows)
    nl, nb, nr = len(legs), len(base), len(rows)
    M_l = _sub(m.M, legs, legs)
    M_lb = _sub(m.M, legs, base)
    J_l = _sub(m.J, rows, legs)
    J_b = _sub(m.J, rows, base)
    qdd_l = np.array([m.qdd[i] for i in legs])
    qdd_b = np.array([m.qdd[i] for i in base])
    resid = np.zeros(nl)
    for i in range(nl):
        resid[i] = m.tau[legs[i]] - m.h[legs[i]]
        for j in range(nb):
            resid[i] -= M_lb[i, j] * qdd_b[j]
    M_inv = np.linalg.inv(M_l)
    qdd_air = M_inv @ resid

    # Contact: M_l qdd + J_l^T F = resid and the damped constraint
    # J_l qdd + J_b qdd_b + Jdot_qd - inv_damping F = 0 (a compliant contact), i.e. eq. 6
    # with the damped operational-space matrix, solved as one KKT system.
    # Stabilised contact (contact_damping b): the foot's acceleration along the kept rows is
    # -b min(u, 0) e_r, u = e . v_f, instead of 0, so it enters c with a plus sign.
    u = float(sum(e[i] * m.v_f[i] for i in range(3)))
    c = np.zeros(nr)
    for k, r in enumerate(rows):
        c[k] = m.Jdot_qd[r] + p.contact_damping * min(u, 0.0) * e[r]
        for j in range(nb):
            c[k] += J_b[k, j] * qdd_b[j]
    K = np.zeros((nl + nr, nl + nr))
    K[:nl, :nl] = M_l
    K[:nl, nl:] = J_l.T
    K[nl:, :nl] = J_l
    K[nl:, nl:] = -p.inv_damping * np.eye(nr)
    sol = np.linalg.solve(K, np.concatenate([resid, -c]))
    qdd_contact, f_rows = sol[:nl], sol[nl:]

    Sd = np.zeros((nl, nl))
    for i in range(nl):
        Sd[i, i] = p.sigma_d[legs[i]] ** 2
        for j in range(nl):
            for k in range(nb):
                Sd[i, j] += M_lb[i, k] * p.sigma_qdd[base[k]] ** 2 * M_lb[j, k]
    # Force covariance in the kept rows: Sigma_f, plus the normal velocity's noise carried by
    # the stabilising term, F = Lambda (... + b u e_r): b^2 var(u) (Lambda e_r)(Lambda e_r)^T
    # with Lambda = (J_l M^-1 J_l^T + inv_damping I)^-1.
    Sf_rows = np.diag([p.sigma_f[r] ** 2 for r in rows])
    if p.contact_damping > 0:
        Je = e @ m.J
        var_u = float(np.sum(Je**2 * np.asarray(p.sigma_qd) ** 2))
        var_u += float(np.sum(np.asarray(e) ** 2 * np.asarray(p.sigma_J) ** 2))
        Lam = np.linalg.inv(J_l @ M_inv @ J_l.T + p.inv_damping * np.eye(nr))
        g = Lam @ np.array([e[r] for r in rows])
        Sf_rows = Sf_rows + p.contact_damping**2 * var_u * np.outer(g, g)
    Sf = np.zeros((nl, nl))
    for i in range(nl):
        for j in range(nl):
            for k in range(nr):
                for k2 in range(nr):
                    Sf[i, j] += J_l[k, i] * Sf_rows[k, k2] * J_l[k2, j]
    Sqdd = np.diag([p.sigma_qdd[i] ** 2 for i in legs])
    cov_air = M_inv @ Sd @ M_inv.T + Sqdd
    cov_contact = M_inv @ (Sd + Sf) @ M_inv.T + Sqdd
    cov_air = 0.5 * (cov_air + cov_air.T)
    cov_contact = 0.5 * (cov_contact + cov_contact.T)
    llr = robust(
        stats.multivariate_normal.logpdf(qdd_l, qdd_contact, cov_contact),
        stats.multivariate_normal.logpdf(qdd_l, qdd_air, cov_air),
        p.outlier_prob,
        -nl * math.log(2.0 * p.outlier_qdd),
    )
    force = np.zeros(3)
    for k, r in enumerate(rows):
        force[r] = f_rows[k]
    if p.unilateral:
        push = sum(e[r] * force[r] for r in rows)
        var = sum(e[r] ** 2 * p.sigma_f[r] ** 2 for r in rows)
        # P(-push > min_push): the foot pushes into the ground with at least min_push. When
        # e has no component along the kept rows the force says nothing: Phi(0).
        if var > 0:
            llr += special.log_ndtr((-push - p.min_push) / math.sqrt(var))
        else:
            llr += math.log(0.5)
    info = {"llr_raw": llr, "qdd_air": qdd_air, "qdd_contact": qdd_contact}
    return cap(llr, p.cap_dynamics), force, info


def diff_kinematics(p: Params, m: Meas, normal=(0.0, 0.0, 1.0)) -> float:
    """Differential kinematics term (eq. 8-9), all three rows of J.

    With ``slip_prob`` rho > 0 the contact density is the mixture of the still foot and,
    with weight rho, a foot moving along the tangent plane of ``normal``:
    ``(1 - rho) N(0, S) + rho N(0, S + slip_speed^2 (I - n n^T))``.
    """
    nv = m.J.shape[1]
    legs = [int(i) for i in m.leg_dofs]
    base = [int(i) for i in m.other_dofs]
    S = np.zeros((3, 3))
    P = np.zeros((3, 3))
    for i in range(3):
        S[i, i] += p.sigma_J[i] ** 2
        for j in range(3):
            for k in range(nv):
                S[i, j] += m.J[i, k] * p.sigma_qd[k] ** 2 * m.J[j, k]
            for k in legs:
                P[i, j] += m.J[i, k] * p.sigma_qd_prior[k] ** 2 * m.J[j, k]
    mean_air = np.zeros(3)
    for i in range(3):
        for k in base:
            mean_air[i] += m.J[i, k] * m.qd[k]
    log_contact = stats.multivariate_normal.logpdf(m.v_f, np.zeros(3), S)
    if p.slip_prob > 0:
        n = np.asarray(normal, float)
        T = np.eye(3) - np.outer(n, n)
        log_slide = stats.multivariate_normal.logpdf(m.v_f, np.zeros(3), S + p.slip_speed**2 * T)
        log_contact = np.logaddexp(
            math.log1p(-p.slip_prob) + log_contact, math.log(p.slip_prob) + log_slide
        )
    llr = robust(
        log_contact,
        stats.multivariate_normal.logpdf(m.v_f, mean_air, S + P),
        p.outlier_prob,
        -3.0 * math.log(2.0 * p.outlier_v),
    )
    return cap(llr, p.cap_diff_kinematics, p.cap_diff_kinematics_still)


def _along(e, J, sigma):
    """sqrt(e^T J diag(sigma^2) J^T e + VAR_GUARD)."""
    acc = VAR_GUARD
    for k in range(J.shape[1]):
        je = e[0] * J[0, k] + e[1] * J[1, k] + e[2] * J[2, k]
        acc += je * je * sigma[k] ** 2
    return math.sqrt(acc)


def end_of_interval(p: Params, m: Meas) -> Meas:
    """The foot read ``kinematics_lead`` of the way to the end of the measured interval.

    Written out from the semi-implicit Euler step over ``h = lead dt``: every coordinate's
    velocity ``qd_i + h qdd_i``; the foot's velocity is the Jacobian times that, plus the
    velocity-product term over the step, ``v_f + h (sum_k J_ik qdd_k + Jdot_qd_i)``; its
    position ``p_f + h v_f'``. ``J``, ``M`` and the rest are kept.
    """
    h = p.kinematics_lead * p.dt
    nv = m.J.shape[1]
    qd = np.array([m.qd[k] + h * m.qdd[k] for k in range(nv)])
    v = np.zeros(3)
    pos = np.zeros(3)
    for i in range(3):
        acc = m.Jdot_qd[i]
        for k in range(nv):
            acc += m.J[i, k] * m.qdd[k]
        v[i] = m.v_f[i] + h * acc
        pos[i] = m.p_f[i] + h * v[i]
    return dataclasses.replace(m, qd=qd, v_f=v, p_f=pos)


def sole_gap(p: Params, m: Meas, tq: Query) -> tuple[float, float]:
    """(gap e . (p_sole - p_i), sigma_pf) in m, eq. 10.

    The sole is ``p_f - r e``; the terrain point ``p_i`` lies below the foot centre at the
    queried height, so the gap is the sole's distance from the terrain's tangent plane.
    """
    e = tq.normal
    p_i = np.array([m.p_f[0], m.p_f[1], tq.height])
    # e . (p_f - r e - p_i) with e . e = 1 (exactly, not as rounded to float32).
    gap = -m.foot_radius
    for k in range(3):
        gap += e[k] * (m.p_f[k] - p_i[k])
    return gap, _along(e, m.J, p.sigma_q)


def kinematics(p: Params, m: Meas, tq: Query) -> float:
    """Kinematics term (eq. 10): log P(phi <= 0) - log P(phi > 0)."""
    gap, s_pf = sole_gap(p, m, tq)
    s = math.sqrt(s_pf**2 + tq.sigma**2)
    llr = stats.norm.logcdf(0.0, loc=gap, scale=s) - stats.norm.logsf(0.0, loc=gap, scale=s)
    if p.kinematics_neutral_below:
        llr = min(llr, 0.0)  # neutral on and below the terrain (docs/model.md)
    return cap(llr, p.cap_kinematics)


# --------------------------------------------------------------------------- transitions


def normal_velocity(p: Params, m: Meas, e: np.ndarray) -> tuple[float, float]:
    """(u = e . v_f, sigma_v = sqrt(e^T J diag(sigma_qd^2) J^T e)), eq. 13."""
    return float(e @ m.v_f), _along(e, m.J, p.sigma_qd)


def takeoff_joint(p: Params, u: float, sigma_v: float) -> np.ndarray:
    """(2,) log [P(u, C|C), P(u, A|C)]: eq. 13 and eq. 15 (with 1/u_max) times the prior."""
    u_max = p.takeoff_accel * p.dt
    prior = p.dt / p.stance_time
    still = stats.norm.logpdf(u, 0.0, sigma_v)
    rising = _log_phi_diff(u / sigma_v, (u - u_max) / sigma_v) - math.log(u_max)
    # The shared outlier component, uniform on +-outlier_v.
    log_u = -math.log(2.0 * p.outlier_v)
    still, rising = mixed(still, p.outlier_prob, log_u), mixed(rising, p.outlier_prob, log_u)
    return np.array([still + math.log1p(-prior), rising + math.log(prior)])


def takeoff(p: Params, u: float, sigma_v: float) -> np.ndarray:
    """(2,) log [P(C|C), P(A|C)] (eq. 11-15): Bayes' rule, normalised; unfloored."""
    log_stay, log_leave = takeoff_joint(p, u, sigma_v)
    z = np.logaddexp(log_stay, log_leave)
    return np.array([log_stay - z, log_leave - z])


_GL_X, _GL_W = np.polynomial.legendre.leggauss(32)


def touchdown_integral(
    gap,
    sigma_pf,
    sigma_pi,
    u,
    sigma_u,
    dt,
    power=1,
    complement=False,
    epsrel=1e-10,
    inner_rule="panels",
):
    """E[g^power] over Algorithm 1's draws by nested adaptive quadrature (float64).

    ``g = Phi((-(p_f - p_i)/dt - u)/sigma_u)`` (or ``1 - g`` with ``complement``), with
    ``p_f ~ N(gap, sigma_pf^2)`` and ``p_i ~ N(0, sigma_pi^2)`` truncated to ``p_i <= p_f``.
    The inner integral runs over the standardised depth ``t = (p_f - p_i)/sigma_pi >= 0``,
    whose density is ``phi(z - t)/Phi(z)`` with ``z = p_f/sigma_pi``; the outer one over
    the standardised foot height, by adaptive ``quad`` with relative tolerance ``epsrel``.
    The inner one is either adaptive too (``inner_rule="adaptive"``, tolerance
    ``epsrel / 10``) or, 30 times faster, a vectorised composite 32-node Gauss-Legendre rule
    on panels cut at the same break points, each halved (``"panels"``); the tests check
    that both agree to ~1e-12.
    """
    sign = -1.0 if complement else 1.0
    k = sigma_pi / dt  # m/s per unit of t

    def g_arg(t):
        return sign * (-(t * k) - u) / sigma_u

    def inner(z):
        # The density in t falls off beyond max(z, 0) + a few widths (width 1/|z| when
        # z << 0, where the truncated normal is exponential).
        t_hi = max(z, 0.0) + 40.0 / max(1.0, -z)
        pts = []
        if not complement:
            # g is negligible (< Phi(-40)) beyond t = (40 sigma_u - u) / k.
            t_g = (40.0 * sigma_u - u) / k
            if t_g <= 0.0:
                return 0.0
            t_hi = min(t_hi, t_g)
        # Break points on the scales of both factors, so that quad's error estimate is
        # not fooled by a narrow feature in a long interval: the density (mode max(z, 0),
        # width 1 or 1/|z|) and the step of g (at t0, width sigma_u / k).
        w = 1.0 / max(1.0, -z)
        t0 = -u / k  # where g crosses 1/2
        cand = [max(z, 0.0) + w * s for s in (-8, -4, -2, -1, 0, 0.5, 1, 2, 4, 8, 16)]
        cand += [t0 + sigma_u / k * s for s in (-6, -3, -1, 0, 1, 3, 6)]
        for t in cand:
            if 0.0 < t < t_hi:
                pts.append(t)
        log_norm = float(special.log_ndtr(z)) + 0.5 * math.log(2.0 * math.pi)
        if inner_rule == "panels":
            edges = np.array([0.0] + sorted(pts) + [t_hi])
            edges = np.sort(np.concatenate([edges, 0.5 * (edges[1:] + edges[:-1])]))
            lo, hi = edges[:-1, None], edges[1:, None]
            t = 0.5 * (hi + lo) + 0.5 * (hi - lo) * _GL_X[None, :]
            vals = np.exp(-0.5 * (z - t) ** 2 - log_norm) * special.ndtr(g_arg(t)) ** power
            return float(np.sum(0.5 * (hi - lo) * _GL_W[None, :] * vals))

        def f(t):
            g = 0.5 * math.erfc(-g_arg(t) / math.sqrt(2.0))
            return math.exp(-0.5 * (z - t) ** 2 - log_norm) * g**power

        val, _ = integrate.quad(
            f, 0.0, t_hi, points=sorted(pts) or None, epsabs=0.0, epsrel=epsrel / 10, limit=400
        )
        return val

    def outer(x):
        z = (gap + sigma_pf * x) / sigma_pi
        return math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi) * inner(z)

    x0 = -gap / sigma_pf  # the foot at the terrain's mean height
    w = sigma_pi / sigma_pf  # the scale of the inner integral's dependence on x
    pts = [0.0] + [x0 + w * s for s in (-8, -4, -2, -1, 0, 1, 2, 4, 8)]
    pts = [x for x in pts if -12.0 < x < 12.0]
    with warnings.catch_warnings():
        # quad warns when round-off stops it short of epsrel = 1e-10; it is then still
        # accurate to ~1e-12 relative (checked against 1e6-sample Monte-Carlo and against
        # P(C|A) + P(A|A) = 1 by the tests).
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        val, _ = integrate.quad(
            outer, -12.0, 12.0, points=sorted(set(pts)), epsabs=0.0, epsrel=epsrel, limit=400
        )
    return val


def touchdown(gap, sigma_pf, sigma_pi, u, sigma_u, dt, **kw) -> np.ndarray:
    """(2,) [P(C|A), P(A|A)] by :func:`touchdown_integral` (each computed directly)."""
    args = (gap, sigma_pf, sigma_pi, u, sigma_u, dt)
    return np.array(
        [touchdown_integral(*args, **kw), touchdown_integral(*args, complement=True, **kw)]
    )


def touchdown_std(gap, sigma_pf, sigma_pi, u, sigma_u, dt) -> float:
    """Standard deviation of one Algorithm 1 draw g (so an n-sample mean has std / sqrt(n))."""
    m1 = touchdown_integral(gap, sigma_pf, sigma_pi, u, sigma_u, dt)
    m2 = touchdown_integral(gap, sigma_pf, sigma_pi, u, sigma_u, dt, power=2)
    return math.sqrt(max(m2 - m1 * m1, 0.0))


def touchdown_mc(gap, sigma_pf, sigma_pi, u, sigma_u, dt, n, seed=0):
    """Algorithm 1 in NumPy: (mean of g, sample std of g), SciPy truncated-normal draws."""
    rng = np.random.default_rng(seed)
    p_f = gap + sigma_pf * rng.standard_normal(n)
    p_i = stats.truncnorm.rvs(
        a=-np.inf, b=p_f / sigma_pi, loc=0.0, scale=sigma_pi, size=n, random_state=rng
    )
    g = special.ndtr((-(p_f - p_i) / dt - u) / sigma_u)
    return float(g.mean()), float(g.std(ddof=1))


def transition(p: Params, m: Meas, tq: Query, td_fn=touchdown) -> np.ndarray:
    """(2, 2) log transition matrix for the next step, floored at LOG_FLOOR."""
    u, s_v = normal_velocity(p, m, tq.normal)
    gap, s_pf = sole_gap(p, m, tq)
    rows = np.zeros((2, 2))
    rows[0] = takeoff(p, u, s_v)
    with np.errstate(divide="ignore"):
        rows[1] = np.log(td_fn(gap, s_pf, tq.sigma, u, s_v, p.dt))
    if p.cap_transition < 1.0:
        # Each row's log-odds of leaving its state clipped from above to logit(cap).
        bound = _logit(p.cap_transition)
        for i, leave in ((0, 1), (1, 0)):
            odds = min(rows[i, leave] - rows[i, 1 - leave], bound)
            rows[i, leave] = -np.logaddexp(0.0, -odds)
            rows[i, 1 - leave] = -np.logaddexp(0.0, odds)
    for i in range(2):
        for j in range(2):
            rows[i, j] = max(rows[i, j], LOG_FLOOR)
    return rows


def prior_transition(p: Params) -> np.ndarray:
    off = p.dt / p.stance_time
    on = p.dt / p.swing_time
    return np.log(np.array([[1.0 - off, off], [on, 1.0 - on]]))


# --------------------------------------------------------------------------- recursion


def init_belief(p: Params) -> Belief:
    return Belief(_logit(p.initial_contact), prior_transition(p), np.zeros(3), False)


def own_branch(m: Meas) -> Meas:
    """``m`` with the velocity and acceleration of every coordinate outside the leg that
    the leg's rows of ``M`` and the Jacobian do not involve (all exactly 0) set to 0."""
    legs = [int(i) for i in m.leg_dofs]
    qd, qdd = np.array(m.qd, F64), np.array(m.qdd, F64)
    for k in (int(i) for i in m.other_dofs):
        if all(m.M[i, k] == 0 for i in legs) and all(m.J[r, k] == 0 for r in range(3)):
            qd[k], qdd[k] = 0.0, 0.0
    return dataclasses.replace(m, qd=qd, qdd=qdd)


def _finite(m: Meas) -> bool:
    """Whether everything the foot's terms read is finite (``m`` after :func:`own_branch`)."""
    legs = [int(i) for i in m.leg_dofs]
    base = [int(i) for i in m.other_dofs]
    read = [m.M[legs, :], m.tau[legs], m.h[legs], m.qdd, m.qd[base], m.J, m.Jdot_qd, m.p_f]
    read += [m.v_f, m.foot_radius]
    return all(np.all(np.isfinite(np.asarray(x, F64))) for x in read)


def step(p: Params, terrain, b: Belief, m: Meas, td_fn=touchdown):
    """One update of one foot (eq. 1-3). Returns (new belief, diagnostics dict)."""
    # eq. 1 in probability space, each state's probability computed directly (no 1 - x).
    b_c = 1.0 / (1.0 + math.exp(-b.logit)) if b.logit > -700 else 0.0
    b_a = 1.0 / (1.0 + math.exp(b.logit)) if b.logit < 700 else 0.0
    T = np.exp(b.log_transition)
    prior_c = T[0, 0] * b_c + T[1, 0] * b_a
    prior_a = T[0, 1] * b_c + T[1, 1] * b_a
    prior_logit = math.log(prior_c) - math.log(prior_a)
    nan = float("nan")
    m = own_branch(m)
    if not _finite(m):
        new = Belief(prior_logit, prior_transition(p), b.foothold.copy(), b.foothold_valid)
        diag = dict(
            p_contact=1.0 / (1.0 + math.exp(-prior_logit)) if prior_logit > -700 else 0.0,
            logit=prior_logit,
            p_dynamics=nan,
            p_diff_kinematics=nan,
            p_kinematics=nan,
            p_takeoff=math.exp(new.log_transition[0, 1]),
            p_touchdown=math.exp(new.log_transition[1, 0]),
            force=np.full(3, nan),
            valid=False,
            takeoff_scale=1.0,
        )
        return new, diag
    # The dynamics term reads the interval's start, everything else the foot at its end.
    k = end_of_interval(p, m)
    tq = terrain.query(k.p_f, b.foothold, b.foothold_valid)
    l_dyn, force, _ = dynamics(p, m, tq.normal)
    l_dk = diff_kinematics(p, k, tq.normal)
    l_k = kinematics(p, k, tq)
    # eq. 2: alpha(C) / alpha(A) = prior(C) L(C) / (prior(A) L(A)).
    logit = prior_logit + l_dyn + l_dk + l_k
    log_t = transition(p, k, tq, td_fn)
    u, s_v = normal_velocity(p, k, tq.normal)
    takeoff_scale = float(np.abs(takeoff_joint(p, u, s_v)).max())
    still = (not p.foothold_still) or l_dk > 0.0
    if logit > _logit(p.foothold_confidence) and still:
        sole = k.p_f - k.foot_radius * tq.normal
        foothold, fvalid = terrain.remember(b.foothold, b.foothold_valid, sole), True
    else:
        foothold, fvalid = b.foothold.copy(), b.foothold_valid
    new = Belief(logit, log_t, foothold, fvalid)

    def sig(x):
        return 1.0 / (1.0 + math.exp(-x)) if x > -700 else math.exp(x)

    diag = dict(
        p_contact=sig(logit),
        logit=logit,
        p_dynamics=sig(l_dyn),
        p_diff_kinematics=sig(l_dk),
        p_kinematics=sig(l_k),
        p_takeoff=math.exp(log_t[0, 1]),
        p_touchdown=math.exp(log_t[1, 0]),
        force=force,
        valid=True,
        takeoff_scale=takeoff_scale,
    )
    return new, diag


# --------------------------------------------------------------------------- test inputs
# Float64 NumPy inputs for the tests; nothing above depends on them.

# The planar leg of the paper's Section III (Table I), with the link lengths and foot
# radius chosen in envs/assets/planar_leg.xml: q = (base height z, hip, knee), both hinges
# about the world y axis, the leg hanging straight down at zero angles.
LEG = dict(
    m_base=5.449, m_thigh=2.48, i_thigh=3.18e-2, c_thigh=0.043,
    m_shank=0.31, i_shank=1.383e-2, c_shank=0.039,
    l_thigh=0.25, l_shank=0.25, radius=0.02, g=9.81,
)  # fmt: skip


def planar_leg(q, qd):
    """Analytic rigid-body model of the planar leg (Kane's method), float64.

    A point at distance c along the thigh is ``(x, z) = (-c sin q1, z - c cos q1)``, along
    the shank ``(-l1 sin q1 - c sin q12, z - l1 cos q1 - c cos q12)`` with ``q12 = q1 + q2``.
    Its velocity is ``J qd`` and its acceleration ``J qdd + b`` with the centripetal bias
    ``b = (l1 sin q1 w1^2 + c sin q12 w12^2, l1 cos q1 w1^2 + c cos q12 w12^2)``. The
    equations of motion ``sum_i J_i^T m_i (J_i qdd + b_i - g) + Jw_i^T I_i Jw_i qdd = tau``
    give ``M = sum m J^T J + I Jw^T Jw`` and ``h = sum m J^T (b - g)`` (the planar links turn
    about a fixed principal axis, so they have no gyroscopic term).

    Returns:
      dict of M (3, 3), h (3,), J (3, 3) foot-centre translational Jacobian (rows x, y, z),
      Jdot_qd (3,), p_f (3,), v_f (3,).
    """
    P = LEG
    z, a1, a2 = q
    _, w1, w2 = qd
    w12 = w1 + w2
    s1, c1, s12, c12 = math.sin(a1), math.cos(a1), math.sin(a1 + a2), math.cos(a1 + a2)
    l1 = P["l_thigh"]

    def thigh_point(c):
        Jx = np.array([0.0, -c * c1, 0.0])
        Jz = np.array([1.0, c * s1, 0.0])
        pos = np.array([-c * s1, z - c * c1])
        bias = np.array([c * s1 * w1**2, c * c1 * w1**2])
        return pos, Jx, Jz, bias

    def shank_point(c):
        Jx = np.array([0.0, -l1 * c1 - c * c12, -c * c12])
        Jz = np.array([1.0, l1 * s1 + c * s12, c * s12])
        pos = np.array([-l1 * s1 - c * s12, z - l1 * c1 - c * c12])
        bias = np.array([l1 * s1 * w1**2 + c * s12 * w12**2, l1 * c1 * w1**2 + c * c12 * w12**2])
        return pos, Jx, Jz, bias

    bodies = [
        (P["m_base"], 0.0, np.zeros(3), (None, np.zeros(3), np.array([1.0, 0, 0]), np.zeros(2))),
        (P["m_thigh"], P["i_thigh"], np.array([0.0, 1, 0]), thigh_point(P["c_thigh"])),
        (P["m_shank"], P["i_shank"], np.array([0.0, 1, 1]), shank_point(P["c_shank"])),
    ]
    M = np.zeros((3, 3))
    h = np.zeros(3)
    for mass, inertia, Jw, (_, Jx, Jz, bias) in bodies:
        M += mass * (np.outer(Jx, Jx) + np.outer(Jz, Jz)) + inertia * np.outer(Jw, Jw)
        h += mass * (Jx * bias[0] + Jz * (bias[1] + P["g"]))
    pos, Jx, Jz, bias = shank_point(P["l_shank"])
    J = np.stack([Jx, np.zeros(3), Jz])
    qd = np.asarray(qd, dtype=float)
    return dict(
        M=M,
        h=h,
        J=J,
        Jdot_qd=np.array([bias[0], 0.0, bias[1]]),
        p_f=np.array([pos[0], 0.0, pos[1]]),
        v_f=J @ qd,
    )


def _logu(rng, lo, hi, size=None):
    return np.exp(rng.uniform(math.log(lo), math.log(hi), size))


def random_case(rng, nv: int, n_l: int, force_rows=(0, 1, 2), stance: bool | None = None, leg=None):
    """Seeded random but physically plausible inputs for one foot, all float64.

    A random SPD mass matrix (kg, kg m^2 scale), a random foot Jacobian (~0.25 m lever
    arms), a random leg/rest split, Table-II-like noise drawn log-uniformly around the
    paper's values, and either a stance-like foot (on the ground, nearly still, the leg's
    acceleration that of the pinned leg plus noise) or an air-like one (up to 0.3 m up,
    moving, the free leg's acceleration plus noise).

    Args:
      leg: the leg's dof indices, or None for a random split.

    Returns:
      dict with ``meas`` (fields of LegMeasurement), ``terrain`` (height, sigma, normal),
      ``noise`` (fields of NoiseParams) and ``scalars`` (float leaves of EstimatorParams).
    """
    if stance is None:
        stance = bool(rng.integers(2))
    A = rng.normal(scale=0.4, size=(nv, nv))
    M = A @ A.T + np.diag(rng.uniform(0.05, 1.0, nv))
    J = rng.normal(scale=0.25, size=(3, nv))
    perm = rng.permutation(nv)
    if leg is None:
        leg, other = np.sort(perm[:n_l]), perm[n_l:]
    else:
        leg, other = np.asarray(leg), np.setdiff1d(np.arange(nv), leg)
    noise = dict(
        sigma_q=_logu(rng, 1e-3, 4e-2, nv),
        sigma_qd=_logu(rng, 0.02, 0.4, nv),
        sigma_qdd=_logu(rng, 5.0, 200.0, nv),
        sigma_d=_logu(rng, 0.5, 5.0, nv),
        sigma_f=_logu(rng, 3.0, 30.0, 3),
        sigma_J=_logu(rng, 0.01, 0.1, 3),
        sigma_qd_prior=_logu(rng, 5.0, 30.0, nv),
    )
    capped = bool(rng.integers(2))
    scalars = dict(
        dt=float(rng.choice([0.001, 0.0025, 0.005])),
        stance_time=float(rng.uniform(0.2, 0.6)),
        swing_time=float(rng.uniform(0.2, 0.5)),
        takeoff_accel=float(rng.uniform(50.0, 400.0)),
        cap_dynamics=float(rng.uniform(0.6, 0.999)) if capped else 1.0,
        cap_diff_kinematics=float(rng.uniform(0.6, 0.99)) if capped else 1.0,
        cap_kinematics=float(rng.uniform(0.6, 0.999)) if capped else 1.0,
        inv_damping=float(_logu(rng, 1e-8, 1e-3)),
        initial_contact=float(rng.uniform(0.05, 0.95)),
    )
    tilt = rng.uniform(0.0, math.radians(25.0))
    az = rng.uniform(0.0, 2 * math.pi)
    normal = np.array(
        [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), math.cos(tilt)]
    )
    terrain = dict(
        height=rng.uniform(-0.03, 0.03), sigma=float(_logu(rng, 0.005, 0.3)), normal=normal
    )
    radius = rng.uniform(0.0, 0.03)

    qd = np.zeros(nv)
    qd[other] = rng.normal(scale=0.3, size=nv - n_l)
    if stance:
        # The leg's joints cancel the rest's foot velocity (least squares for n_l < 3).
        qd[leg] = np.linalg.lstsq(J[:, leg], -J[:, other] @ qd[other], rcond=None)[0]
        qd[leg] += rng.normal(scale=0.05, size=n_l)
        gap = rng.normal(scale=0.005)
    else:
        qd[leg] = rng.normal(scale=3.0, size=n_l)
        gap = rng.uniform(0.02, 0.3)
    # The sole `gap` above the terrain's tangent plane: e_z (z_f - height) - r = gap.
    z_f = terrain["height"] + (gap + radius) / normal[2]
    p_f = np.array([rng.normal(scale=0.3), rng.normal(scale=0.3), z_f])
    meas = dict(
        q=rng.normal(size=nv + 1),
        qd=qd,
        qdd=rng.normal(scale=2.0, size=nv),
        tau=rng.normal(scale=15.0, size=nv),
        M=M,
        h=rng.normal(scale=20.0, size=nv),
        J=J,
        Jdot_qd=rng.normal(scale=3.0, size=3),
        p_f=p_f,
        v_f=J @ qd,
        foot_radius=radius,
        leg_dofs=leg.astype(np.int32),
        other_dofs=other.astype(np.int32),
    )
    # Set the leg's acceleration to the pinned (stance) or free (air) prediction plus noise
    # of the size the noise model expects.
    probe = Params(**{k: np.asarray(v) for k, v in noise.items()}, **scalars,
                   force_rows=tuple(force_rows), unilateral=False)  # fmt: skip
    _, _, info = dynamics(probe, Meas(**meas), normal)
    pred = info["qdd_contact"] if stance else info["qdd_air"]
    meas["qdd"][leg] = pred + rng.normal(size=n_l) * noise["sigma_qdd"][leg] * 0.7
    # The robust model's parameters, from a generator seeded by this case's own values so
    # that ``rng`` (and every later case) draws as it did before they existed; half the
    # cases switch the outlier component off.
    sub = np.random.default_rng([int(abs(x) * 1e9) % 2**32 for x in p_f])
    robust_on = bool(sub.integers(2))
    scalars.update(
        cap_diff_kinematics_still=float(sub.uniform(0.55, 0.99)) if capped else 1.0,
        cap_transition=float(sub.uniform(0.6, 0.99)) if robust_on else 1.0,
        outlier_prob=float(_logu(sub, 1e-3, 0.1)) if robust_on else 0.0,
        outlier_qdd=float(_logu(sub, 500.0, 2e4)),
        outlier_v=float(_logu(sub, 0.5, 10.0)),
        foothold_confidence=float(sub.uniform(0.5, 0.999)),
    )
    # The stabilised contact, from its own generator (so every earlier draw is unchanged);
    # half the cases keep the paper's rigid constraint.
    sub2 = np.random.default_rng([int(abs(x) * 1e9 + 7) % 2**32 for x in p_f])
    scalars["contact_damping"] = float(_logu(sub2, 10.0, 400.0)) if sub2.integers(2) else 0.0
    # The kinematic terms' lead, likewise: the interval's start, its end, or between.
    sub3 = np.random.default_rng([int(abs(x) * 1e9 + 11) % 2**32 for x in p_f])
    scalars["kinematics_lead"] = float(sub3.choice([0.0, 1.0, sub3.uniform()]))
    # The loaded contact's least push: none (the sign rule) in half the cases.
    sub4 = np.random.default_rng([int(abs(x) * 1e9 + 13) % 2**32 for x in p_f])
    scalars["min_push"] = float(sub4.uniform(0.0, 40.0)) if sub4.integers(2) else 0.0
    # The sliding contact: the still foot alone (rho = 0) in half the cases.
    sub5 = np.random.default_rng([int(abs(x) * 1e9 + 17) % 2**32 for x in p_f])
    scalars["slip_prob"] = float(_logu(sub5, 0.01, 0.5)) if sub5.integers(2) else 0.0
    scalars["slip_speed"] = float(_logu(sub5, 0.05, 2.0))
    return dict(meas=meas, terrain=terrain, noise=noise, scalars=scalars)


def round32(tree):
    """Rounds every float array of a nested dict to float32, keeping float64 storage."""
    if isinstance(tree, dict):
        return {k: round32(v) for k, v in tree.items()}
    arr = np.asarray(tree)
    if np.issubdtype(arr.dtype, np.floating):
        return arr.astype(np.float32).astype(np.float64)
    return arr


# Table II's noise for the planar leg, (base z, hip, knee); Sigma_f, Sigma_J:
# docs/model_choices.md's choices; the velocity prior from Table I's 25 rad/s joint limit.
TABLE_II = dict(
    sigma_q=(0.04, 0.02, 0.02),
    sigma_qd=(0.2, 0.3, 0.3),
    sigma_qdd=(2.0, 100.0, 100.0),
    sigma_d=(1.0, 2.0, 2.0),
    sigma_f=10.0,
    sigma_J=0.05,
    sigma_qd_prior=25.0,
)
PLANAR_LEG_DOFS = np.array([1, 2], np.int32)
PLANAR_OTHER_DOFS = np.array([0], np.int32)


def planar_measurement(q, qd, qdd, tau):
    """A LegMeasurement's fields (float64 NumPy) for the planar leg at state (q, qd)."""
    q = np.asarray(q, float)
    qd = np.asarray(qd, float)
    model = planar_leg(q, qd)
    return dict(
        q=q,
        qd=qd,
        qdd=np.asarray(qdd, float),
        tau=np.asarray(tau, float),
        M=model["M"],
        h=model["h"],
        J=model["J"],
        Jdot_qd=model["Jdot_qd"],
        p_f=model["p_f"],
        v_f=model["v_f"],
        foot_radius=np.float64(LEG["radius"]),
        leg_dofs=PLANAR_LEG_DOFS,
        other_dofs=PLANAR_OTHER_DOFS,
    )


def base_height_for(hip, knee, sole_height=0.0):
    """Base height that puts the sole ``sole_height`` above the floor z = 0."""
    return (
        LEG["l_thigh"] * math.cos(hip)
        + LEG["l_shank"] * math.cos(hip + knee)
        + LEG["radius"]
        + sole_height
    )


def planar_stance(hip=0.6, knee=-1.2, base_vel=0.0, push_x=0.0):
    """A loaded, still foot on the floor: (q, qd, qdd, tau) of the pinned planar leg.

    With ``qd = 0`` (``base_vel = 0``) and ``qdd = 0`` the equation of motion gives
    ``tau = h + J^T F``; its unactuated base row ``0 = h_z + F_z`` fixes
    ``F_z = -(total mass) g``: the foot pushes down with the robot's weight. The leg's
    torques follow from the x-z rows of J; ``push_x`` adds a horizontal force (N).
    With ``base_vel != 0`` the leg's joint velocities keep the foot still (v_f = 0).
    """
    q = np.array([base_height_for(hip, knee), hip, knee])
    qd = np.zeros(3)
    qd[0] = base_vel
    model = planar_leg(q, qd)
    J = model["J"]
    if base_vel:
        rows = [0, 2]
        qd[1:] = np.linalg.solve(J[np.ix_(rows, [1, 2])], -J[rows, 0] * base_vel)
        model = planar_leg(q, qd)
    F = np.array([push_x, 0.0, -model["h"][0]])  # base row: h_z + F_z = tau_z = 0
    tau = model["h"] + model["J"].T @ F
    tau[0] = 0.0
    return q, qd, np.zeros(3), tau


def planar_swing(height=0.2, hip=0.3, knee=-1.0, qd_leg=(8.0, -4.0), tau_leg=(5.0, -3.0)):
    """A swinging leg in free flight, the sole ``height`` above the floor.

    ``qdd = M^-1 (tau - h)`` with ``tau = (0, tau_hip, tau_knee)``: the whole robot in the
    air, base included, accelerates as the free dynamics say.
    """
    q = np.array([base_height_for(hip, knee, height), hip, knee])
    qd = np.array([0.0, *qd_leg])
    model = planar_leg(q, qd)
    tau = np.array([0.0, *tau_leg])
    qdd = np.linalg.solve(model["M"], tau - model["h"])
    return q, qd, qdd, tau


def random_planar(rng, stance: bool | None = None):
    """A random planar-leg measurement (fields of LegMeasurement, float64 NumPy).

    Stance: a loaded, still foot on the floor with a random horizontal push. Air: the leg
    swinging freely 0.5 to 25 cm above the floor with random joint velocities and torques.
    The measured accelerations carry noise of a fifth of Table II's.
    """
    if stance is None:
        stance = bool(rng.integers(2))
    hip = rng.uniform(-0.6, 0.9)
    knee = rng.uniform(-2.0, -0.4)
    if stance:
        q, qd, qdd, tau = planar_stance(hip, knee, push_x=rng.normal(scale=20.0))
    else:
        q, qd, qdd, tau = planar_swing(
            rng.uniform(0.005, 0.25),
            hip,
            knee,
            qd_leg=rng.normal(scale=4.0, size=2),
            tau_leg=rng.normal(scale=10.0, size=2),
        )
    qdd = qdd + rng.normal(size=3) * np.array([0.4, 20.0, 20.0])
    return planar_measurement(q, qd, qdd, tau)
