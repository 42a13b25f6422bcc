"""The transition model (eq. 11-17, Algorithm 1): take-off and touch-down probabilities.

Both transitions use the measurements of the step *before* the transition, so the filter
builds the matrix at the end of step ``t`` and applies it at ``t+1``. Rows are the state
at ``t`` (0 = contact C, 1 = air A), columns the state at ``t+1``; entries are logs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import log_ndtr

from jax_contact._math import (
    cap_bound,
    log_diff_ndtr,
    mixed_logpdf,
    ndtr_ratio_pair,
    ndtr_small_side,
    ndtri,
    normal_logpdf,
    stack,
    upper_truncated_normal_icdf,
)
from jax_contact.measurement import sole_gap
from jax_contact.params import EstimatorParams
from jax_contact.types import LegBlocks, LegMeasurement, TerrainQuery

# Transition probabilities are floored here (in log space) so that no state becomes
# unreachable: a belief can always recover, even after a million steps
# (docs/model_choices.md, "transition floors").
LOG_FLOOR = -30.0


def normal_velocity(params: EstimatorParams, meas: LegMeasurement | LegBlocks, normal: jax.Array):
    """Foot velocity along the impact axis and its std (eq. 13).

    Args:
      params: estimator parameters (``noise.sigma_qd``, (nv,) m/s and rad/s).
      meas: one foot's measurement, or its ``LegBlocks`` (``J`` (3, nv), ``v_f`` (3,) m/s).
      normal: (3,) unit impact axis ``e``, world frame.

    Returns:
      (u = e . v_f in m/s (), sigma_v = sqrt(e^T J Sigma_qd J^T e) in m/s ()); u > 0 is
      moving away from the ground.
    """
    Je = normal @ meas.J
    sigma_v = jnp.sqrt(jnp.dot(Je * Je, jnp.square(params.noise.sigma_qd)) + 1e-12)
    return jnp.dot(normal, meas.v_f), sigma_v


@jax.named_call
def log_takeoff(params: EstimatorParams, u: jax.Array, sigma_v: jax.Array) -> jax.Array:
    """(2,) log [P(C | C), P(A | C)] given the normal foot velocity ``u`` (eq. 11-15).

    Gait prior ``P(A | C) = dt / T_s`` (eq. 12). Staying on the ground, the foot is still:
    ``u ~ N(0, sigma_v^2)`` (eq. 13). Taking off, its velocity is uniform on ``[0, u_max]``,
    ``u_max = a_F dt``, blurred by the velocity noise (eq. 14, ``v_f + w_v``; eq. 15 with
    the ``1 / u_max`` of the uniform density that the printed equation omits). Bayes'
    rule, normalised over the next state (eq. 11).

    Args:
      params: estimator parameters (``dt`` s, ``stance_time`` s, ``takeoff_accel`` m/s^2,
        the outlier model).
      u: () measured foot velocity along the impact axis, m/s (> 0: away from the ground).
      sigma_v: () its std, m/s (:func:`normal_velocity`).

    Returns:
      (2,) log probabilities of the next state from contact, normalised.
    """
    u_max = params.takeoff_accel * params.dt
    p_off = params.dt / params.stance_time
    log_still = normal_logpdf(u, 0.0, sigma_v)
    log_rising = log_diff_ndtr(u / sigma_v, (u - u_max) / sigma_v) - jnp.log(u_max)
    # The broad outlier component the measurement terms use (uniform over +-outlier_v),
    # shared by both hypotheses: one velocity outlier leaves the gait prior in charge
    # instead of deciding the transition alone.
    eps, log_outlier = params.outlier_prob, -jnp.log(2.0 * params.outlier_v)
    log_stay = mixed_logpdf(log_still, eps, log_outlier) + jnp.log1p(-p_off)
    log_leave = mixed_logpdf(log_rising, eps, log_outlier) + jnp.log(p_off)
    both = stack([log_stay, log_leave])
    return both - jax.nn.logsumexp(both)


def cap_leaving(log_row: jax.Array, leave: int, cap: jax.Array) -> jax.Array:
    """A transition row ``log [P(to C), P(to A)]`` with its leaving log-odds capped.

    The log-odds of leaving the current state, ``log P(leave) - log P(stay)``, are clipped
    from above to ``logit(cap)`` (``params.cap_transition``), like each measurement term's
    cap: no single step's velocity makes a transition more certain than ``cap``. Staying
    is not bounded (the floor ``LOG_FLOOR`` bounds it). A cap of 1 leaves the row as is.

    Args:
      log_row: (2,) normalised log transition probabilities.
      leave: static index of the leaving entry (1 from contact, 0 from air).
      cap: () cap in (0.5, 1].
    """
    odds = log_row[leave] - log_row[1 - leave]
    odds = jnp.minimum(odds, cap_bound(cap))
    log_leave, log_stay = jax.nn.log_sigmoid(odds), jax.nn.log_sigmoid(-odds)
    capped = stack([log_stay, log_leave] if leave == 1 else [log_leave, log_stay])
    return jnp.where(cap >= 1.0, log_row, capped)


def _lattice(n: int) -> np.ndarray:
    """(2, n) base points of a rank-1 lattice on the unit square (a Fibonacci-like rule).

    Point ``i`` is ``(i / n, frac(i g / n))`` with ``g`` the integer nearest ``n / phi``
    (golden ratio) that is coprime to ``n``: every row and every column of an n x n grid
    holds one point, spread as evenly as a 2-D lattice allows.
    """
    golden = (1.0 + 5.0**0.5) / 2.0
    g = max(1, round(n / golden))
    while np.gcd(g, n) != 1:
        g += 1
    i = np.arange(n, dtype=np.int64)
    return np.stack([i / n, (i * g % n) / n])


def log_touchdown_monte_carlo(
    gap: jax.Array,
    sigma_pf: jax.Array,
    sigma_pi: jax.Array,
    u: jax.Array,
    sigma_u: jax.Array,
    dt: jax.Array,
    n_samples: int,
    *,
    key: jax.Array,
) -> jax.Array:
    """(2,) log [P(C | A), P(A | A)] by Algorithm 1 (eq. 16-17).

    Draws, ``n_samples`` times, the foot ``p_f ~ N(gap, sigma_pf^2)`` (heights measured from
    the terrain's mean, so ``mu_pi = 0``) and the terrain ``p_i ~ N(0, sigma_pi^2)``
    truncated to ``p_i <= p_f`` by inverse CDF, and averages
    ``Phi((-(p_f - p_i) / dt - u) / sigma_u) = P(u' < -(p_f - p_i) / dt)``: the probability
    that the gap closes within one step. ``P(A | A)`` averages the complementary CDF, so
    both entries stay accurate near 0 and 1.

    The ``n_samples`` pairs of uniforms behind the draws are a rank-1 lattice shifted by
    one uniform random vector from ``key`` (randomised quasi-Monte-Carlo): every draw has
    exactly Algorithm 1's distribution (below a truncation point 8 ``sigma_pi`` under the
    terrain's mean, to ``_math.upper_truncated_normal_icdf``'s tail rule, 5e-4 in a draw)
    and the estimate is unbiased, but the points fill
    the square evenly, so its error is far below that of independent draws at the same
    ``n_samples``, and two random numbers per foot replace ``2 n_samples``.

    Args:
      gap, sigma_pf: mean and std of the sole's height above the terrain mean, m.
      sigma_pi: std of the terrain height, m.
      u, sigma_u: normal foot velocity (positive away from the ground) and its std, m/s.
      dt: time step, s.
      n_samples: static number of draws.
      key: PRNG key; the random shift has shape (2,), the draws (n_samples,) each.
    """
    dtype = jnp.result_type(gap)
    shift = jax.random.uniform(key, (2, 1), dtype=dtype)
    points = jnp.asarray(_lattice(n_samples), dtype) + shift
    points = points - jnp.floor(points)  # the shifted lattice, wrapped onto [0, 1)^2
    # The uniforms' clipping to [1e-7, 1 - 1e-7] biases the estimate by less than 1e-7.
    x_f = jnp.clip(points[0], 1e-7, 1.0 - 1e-7)
    v = jnp.maximum(points[1], 1e-7)
    p_f = gap + sigma_pf * ndtri(x_f)
    # Eq. 17: the terrain point drawn from N(0, sigma_pi^2) truncated to p_i <= p_f.
    p_i = sigma_pi * upper_truncated_normal_icdf(v, p_f / sigma_pi)
    # Eq. 16: the gap phi(t + 1) = p_f + dt u' - p_i closes (< 0) iff u' < -(p_f - p_i) / dt.
    arg = (-(p_f - p_i) / dt - u) / sigma_u
    # Phi(arg) and Phi(-arg) from one erfc each draw, averaged in linear space (a sum of
    # positive terms keeps their relative precision); the floor keeps the log finite, far
    # below the transition floor LOG_FLOOR.
    small = ndtr_small_side(arg)
    p_hit = jnp.where(arg < 0.0, small, 1.0 - small)
    p_miss = jnp.where(arg < 0.0, 1.0 - small, small)
    # Two plain means: XLA's reduction keeps float32 sums of 1e5 terms accurate to ~1e-7,
    # where a matrix-vector product (faster alone, no faster inside step_batch) lost 1e-4.
    floor = jnp.finfo(dtype).tiny
    return stack(
        [
            jnp.log(jnp.maximum(jnp.mean(p_hit), floor)),
            jnp.log(jnp.maximum(jnp.mean(p_miss), floor)),
        ]
    )


def _gauss_hermite(n: int, dtype) -> tuple[jax.Array, jax.Array]:
    """Nodes and weights of the probabilists' Gauss-Hermite rule, E[f(Z)] ~ sum w f(x), in
    ``dtype`` (float32 nodes in a float64 run left the rows' sum 4.5e-8 from 1)."""
    x, w = np.polynomial.hermite_e.hermegauss(n)
    return jnp.asarray(x, dtype), jnp.asarray(w / np.sqrt(2.0 * np.pi), dtype)


def _gauss_legendre01(n: int, dtype) -> tuple[jax.Array, jax.Array]:
    """Nodes and weights of the Gauss-Legendre rule on (0, 1), in ``dtype``."""
    x, w = np.polynomial.legendre.leggauss(n)
    return jnp.asarray(0.5 * (x + 1.0), dtype), jnp.asarray(0.5 * w, dtype)


def log_touchdown_quadrature(
    gap: jax.Array,
    sigma_pf: jax.Array,
    sigma_pi: jax.Array,
    u: jax.Array,
    sigma_u: jax.Array,
    dt: jax.Array,
    n_quad: int,
) -> jax.Array:
    """(2,) log [P(C | A), P(A | A)]: the integral of Algorithm 1 by a deterministic rule.

    Integrating the truncated terrain height out analytically leaves
    ``P(C | A) = E_{p_f, u'}[1 - Phi(z_f + k u') / Phi(z_f)]^+`` (the division by
    ``Phi(z_f)`` is eq. 17's truncation of the terrain to ``p_i <= p_f``) over independent
    Gaussians ``p_f ~ N(gap, sigma_pf^2)`` and ``u' ~ N(u, sigma_u^2)``, with
    ``z_f = p_f / sigma_pi`` and ``k = dt / sigma_pi``. Only ``u' < 0`` contributes, so the
    velocity integral runs over the lower half-line only (Gauss-Legendre in the CDF of the
    upper-truncated normal, smooth there); the foot position integral is Gauss-Hermite.
    ``n_quad`` nodes per dimension, ``n_quad^2`` evaluations.

    Args:
      gap, sigma_pf: () mean and std of the sole's height above the terrain mean, m.
      sigma_pi: () std of the terrain height, m.
      u, sigma_u: () mean and std of the foot velocity along the impact axis, m/s.
      dt: () step, s.
      n_quad: nodes per dimension (static).

    Returns:
      (2,) log [P(C | A), P(A | A)], in the inputs' dtype.
    """
    dtype = jnp.result_type(gap, sigma_pf, sigma_pi, u, sigma_u, dt)
    xh, wh = _gauss_hermite(n_quad, dtype)
    xl, wl = _gauss_legendre01(n_quad, dtype)
    z_f = (gap + sigma_pf * xh) / sigma_pi  # (n,)
    # Mass of u' < 0 and the nodes of u' given u' < 0, standardised then mapped back.
    z0 = -u / sigma_u
    log_mass = log_ndtr(z0)
    u_nodes = u + sigma_u * upper_truncated_normal_icdf(xl, z0)  # (n,) all <= 0
    k = dt / sigma_pi
    # ratio = Phi(z_f + k u') / Phi(z_f) and hit = 1 - ratio, both in linear space with one
    # erfc per node (ndtr_ratio_pair); the weighted sums are of positive terms, so they
    # keep the terms' relative precision. hit is floored at 1e-30 (as the log-space rule
    # floored its log) so that the log below stays finite.
    ratio, hit = ndtr_ratio_pair(z_f[:, None], jnp.minimum(k * u_nodes, 0.0)[None, :])
    w = wh[:, None] * wl[None, :]
    mean_hit = jnp.sum(w * jnp.maximum(hit, 1e-30))
    mean_ratio = jnp.sum(w * ratio)
    log_td = log_mass + jnp.log(mean_hit)
    # P(A|A) = P(u' >= 0) + P(u' < 0) E[ratio | u' < 0], each part kept in log space.
    log_stay = jnp.logaddexp(log_ndtr(-z0), log_mass + jnp.log(mean_ratio + 1e-30))
    return stack([log_td, log_stay])


@jax.named_call
def log_touchdown(
    params: EstimatorParams,
    meas: LegMeasurement | LegBlocks,
    terrain: TerrainQuery,
    *,
    key: jax.Array,
) -> jax.Array:
    """(2,) log [P(C | A), P(A | A)] from one foot's measurement (eq. 16-17).

    Uses Monte-Carlo (Algorithm 1, ``params.n_samples`` draws from ``key``) or the
    quadrature (``params.n_quad``), as ``params.touchdown`` selects.

    Args:
      params: estimator parameters.
      meas: one foot's measurement, or its ``LegBlocks``.
      terrain: the terrain at the foot (height and std in m, normal).
      key: PRNG key of the draws (unused by the quadrature).

    Returns:
      (2,) log probabilities of the next state from air.
    """
    gap, sigma_pf = sole_gap(params, meas, terrain)
    u, sigma_v = normal_velocity(params, meas, terrain.normal)
    if params.touchdown == "monte_carlo":
        return log_touchdown_monte_carlo(
            gap, sigma_pf, terrain.sigma, u, sigma_v, params.dt, params.n_samples, key=key
        )
    return log_touchdown_quadrature(
        gap, sigma_pf, terrain.sigma, u, sigma_v, params.dt, params.n_quad
    )


def log_transition_matrix(
    params: EstimatorParams,
    meas: LegMeasurement | LegBlocks,
    terrain: TerrainQuery,
    *,
    key: jax.Array,
) -> jax.Array:
    """(2, 2) log transition matrix of eq. 1 for the next step, rows from (C, A).

    Row C from eq. 11-15 (:func:`log_takeoff`), row A from eq. 16-17 / Algorithm 1
    (:func:`log_touchdown`), each leaving probability capped at ``params.cap_transition``
    (:func:`cap_leaving`) and every entry floored at :data:`LOG_FLOOR`.

    Args:
      params: estimator parameters.
      meas: one foot's measurement, or its ``LegBlocks``.
      terrain: the terrain at the foot (height, its std, normal).
      key: PRNG key of the Monte-Carlo touch-down draws (unused by the quadrature).

    Returns:
      (2, 2) log probabilities, ``[[log P(C|C), log P(A|C)], [log P(C|A), log P(A|A)]]``.
    """
    u, sigma_v = normal_velocity(params, meas, terrain.normal)
    from_contact = cap_leaving(log_takeoff(params, u, sigma_v), 1, params.cap_transition)
    from_air = cap_leaving(log_touchdown(params, meas, terrain, key=key), 0, params.cap_transition)
    return jnp.maximum(stack([from_contact, from_air]), LOG_FLOOR)


def log_prior_transition(params: EstimatorParams) -> jax.Array:
    """(2, 2) log transition matrix of the gait prior alone: eq. 12's ``P(A|C) = dt / T_s``
    and its swing analogue ``P(C|A) = dt / swing_time``, which the paper does not have
    (docs/model_choices.md, "gait prior on the air side"); the first transition, the
    transition of an invalid step, and every transition with ``transition_model=False``."""
    p_off = params.dt / params.stance_time
    p_on = params.dt / params.swing_time
    return jnp.log(jnp.array([[1.0 - p_off, p_off], [p_on, 1.0 - p_on]]))
