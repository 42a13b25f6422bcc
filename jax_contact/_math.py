"""Gradient-safe Gaussian helpers in log space, shared by the measurement and transition terms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.special import log_ndtr, ndtri

LOG_2PI = 1.8378770664093453

# Below this standardised truncation point the inverse CDF of the truncated normal is taken
# from its exponential tail: Phi(-8) ~ 6e-16, and ndtri of its products with a uniform draw
# would lose all precision in float32.
_TAIL_SWITCH = -8.0


def mvn_logpdf(x: jax.Array, mean: jax.Array, cov: jax.Array) -> jax.Array:
    """Log density of a multivariate normal through its Cholesky factor.

    Args:
      x: (n,) point.
      mean: (n,) mean.
      cov: (n, n) symmetric positive definite covariance.

    Returns:
      () log N(x; mean, cov).
    """
    n = x.shape[-1]
    chol = jnp.linalg.cholesky(cov)
    z = jax.scipy.linalg.solve_triangular(chol, x - mean, lower=True)
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol)))
    return -0.5 * (jnp.dot(z, z) + log_det + n * LOG_2PI)


def normal_logpdf(x: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    """() log N(x; mean, std^2) of a scalar."""
    z = (x - mean) / std
    return -0.5 * (z * z + LOG_2PI) - jnp.log(std)


def log_diff_ndtr(a: jax.Array, b: jax.Array) -> jax.Array:
    """log(Phi(a) - Phi(b)) for a >= b, accurate in both tails.

    When both arguments are large and positive, Phi(a) - Phi(b) = Phi(-b) - Phi(-a) is
    evaluated on the side where the CDF is small, so no cancellation occurs.
    """
    flip = b > 0.0
    hi = jnp.where(flip, -b, a)
    lo = jnp.where(flip, -a, b)
    log_hi = log_ndtr(hi)
    log_lo = log_ndtr(lo)
    # log(e^x - e^y) = x + log1p(-e^(y-x)); the minimum keeps the argument below 0 exactly.
    return log_hi + jnp.log1p(-jnp.exp(jnp.minimum(log_lo - log_hi, -1e-7)))


def logit(p: jax.Array) -> jax.Array:
    """log(p / (1 - p))."""
    return jnp.log(p) - jnp.log1p(-p)


def cap_llr(llr: jax.Array, cap: jax.Array) -> jax.Array:
    """Clips a log-likelihood ratio to +-logit(cap): the term's confidence cap (MODEL.md).

    A cap of exactly 1 leaves the ratio unbounded.
    """
    bound = jnp.where(cap >= 1.0, jnp.inf, logit(jnp.minimum(cap, 1.0 - 1e-7)))
    return jnp.clip(llr, -bound, bound)


def log_mean_exp(x: jax.Array, axis=None) -> jax.Array:
    """log(mean(exp(x))) along ``axis``."""
    n = x.size if axis is None else x.shape[axis]
    return jax.nn.logsumexp(x, axis=axis) - jnp.log(n)


def upper_truncated_normal_icdf(v: jax.Array, upper: jax.Array) -> jax.Array:
    """Inverse CDF of a standard normal truncated to (-inf, upper].

    Returns x <= upper with P(X <= x | X <= upper) = v. For ``upper`` deep in the lower
    tail, Phi(upper) underflows; there X - upper is asymptotically exponential with rate
    |upper| (Mills' ratio), which is used instead of ndtri.

    Args:
      v: uniform draw or quadrature node in (0, 1); any shape.
      upper: standardised truncation point; broadcastable to ``v``.

    Returns:
      Standardised values of the shape of ``v``.
    """
    in_bulk = upper > _TAIL_SWITCH
    safe_upper = jnp.where(in_bulk, upper, 0.0)
    bulk = ndtri(jnp.exp(jnp.log(v) + log_ndtr(safe_upper)))
    tail_upper = jnp.where(in_bulk, _TAIL_SWITCH, upper)
    tail = tail_upper + jnp.log(v) / jnp.abs(tail_upper)
    return jnp.minimum(jnp.where(in_bulk, bulk, tail), upper)
