"""Gradient-safe Gaussian helpers in log space, shared by the measurement and transition terms."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax.scipy.special import log_ndtr

LOG_2PI = 1.8378770664093453

# Below this standardised truncation point the inverse CDF of the truncated normal is taken
# from the Mills-ratio tail rule of upper_truncated_normal_icdf: Phi(-8) ~ 6e-16, and
# ndtri of its products with a uniform draw would lose all precision in float32.
_TAIL_SWITCH = -8.0
_SQRT_HALF = 0.7071067811865476


def stack(xs, axis: int = 0) -> jax.Array:
    """``jnp.stack(xs, axis)`` written as a chain of selects, for values computed per leg.

    Under ``vmap`` every per-leg scalar becomes an array over the batch. XLA:CPU fuses the
    whole computation of each stacked value into a ``concatenate``, which it emits element
    by element without SIMD (and recomputes what the entries share): on the estimator's
    small per-leg graphs that was 5-10x slower than the same arithmetic vectorised over the
    batch. A select reads each operand at every output element, so XLA does not fuse an
    expensive producer into it: the entries are computed once, vectorised, and only the
    selects are fused. Same values, NaN and inf included.

    Args:
      xs: sequence of arrays of one shape.
      axis: position of the new axis.

    Returns:
      The stacked array, ``len(xs)`` along ``axis``.
    """
    xs = [jnp.asarray(x) for x in xs]
    dtype = jnp.result_type(*xs)
    k = len(xs)
    shape = xs[0].shape
    axis = axis % (len(shape) + 1)
    out_shape = shape[:axis] + (k,) + shape[axis:]
    index = jax.lax.broadcasted_iota(jnp.int32, out_shape, axis)
    out = jnp.broadcast_to(jnp.expand_dims(xs[-1].astype(dtype), axis), out_shape)
    for i in range(k - 2, -1, -1):
        out = jnp.where(index == i, jnp.expand_dims(xs[i].astype(dtype), axis), out)
    return out


def cholesky_small(a: jax.Array) -> jax.Array:
    """Lower Cholesky factor of a small SPD matrix, unrolled at trace time.

    The leg blocks are 2x2 to 6x6: a batched LAPACK call per foot costs far more than these
    few dozen fused elementwise operations, which XLA vectorises over any vmapped batch.

    Args:
      a: (n, n) symmetric positive definite, n static and small.

    Returns:
      (n, n) lower-triangular L with L L^T = a.
    """
    n = a.shape[-1]
    cols: list[list[jax.Array]] = [[None] * n for _ in range(n)]
    for j in range(n):
        s = a[j, j] - sum(cols[j][k] * cols[j][k] for k in range(j))
        d = jnp.sqrt(s)
        cols[j][j] = d
        for i in range(j + 1, n):
            s = a[i, j] - sum(cols[i][k] * cols[j][k] for k in range(j))
            cols[i][j] = s / d
    zero = jnp.zeros_like(a[0, 0])
    return jnp.stack(
        [jnp.stack([cols[i][j] if j <= i else zero for j in range(n)]) for i in range(n)]
    )


def _forward_sub(chol: jax.Array, b: jax.Array) -> jax.Array:
    """Solves L y = b for lower-triangular L (n, n) and b (n,) or (n, m), unrolled."""
    n = chol.shape[-1]
    ys = []
    for i in range(n):
        s = b[i] - sum(chol[i, k] * ys[k] for k in range(i))
        ys.append(s / chol[i, i])
    return jnp.stack(ys)


def _back_sub(chol: jax.Array, y: jax.Array) -> jax.Array:
    """Solves L^T x = y for lower-triangular L (n, n), unrolled."""
    n = chol.shape[-1]
    xs = [None] * n
    for i in reversed(range(n)):
        s = y[i] - sum(chol[k, i] * xs[k] for k in range(i + 1, n))
        xs[i] = s / chol[i, i]
    return jnp.stack(xs)


def spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solves a x = b for a small SPD matrix a (n, n) and b (n,) or (n, m)."""
    chol = cholesky_small(a)
    return _back_sub(chol, _forward_sub(chol, b))


def mvn_logpdf(x: jax.Array, mean: jax.Array, cov: jax.Array) -> jax.Array:
    """Log density of a multivariate normal through its (unrolled) Cholesky factor.

    Args:
      x: (n,) point.
      mean: (n,) mean.
      cov: (n, n) symmetric positive definite covariance, n small.

    Returns:
      () log N(x; mean, cov).
    """
    n = x.shape[-1]
    chol = cholesky_small(cov)
    z = _forward_sub(chol, x - mean)
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol)))
    return -0.5 * (jnp.dot(z, z) + log_det + n * LOG_2PI)


def mvn_logpdf_rank1(x: jax.Array, mean: jax.Array, cov: jax.Array, v: jax.Array) -> jax.Array:
    """``log N(x; mean, cov + v v^T)`` without forming ``cov + v v^T``.

    The matrix determinant lemma and the Sherman-Morrison identity on the Cholesky factor
    ``L`` of ``cov``: with ``z = L^-1 (x - mean)``, ``w = L^-1 v`` and ``s = 1 + w.w``,
    ``log det = log det cov + log s`` and the quadratic form is ``z.z - (z.w)^2 / s``. A
    huge ``v`` (a stretched leg's operational-space inverse) only removes the direction of
    ``v`` from the density, where the Cholesky factor of the summed matrix would lose
    positive-definiteness in float32 and return NaN.

    Args:
      x: (n,) point.
      mean: (n,) mean.
      cov: (n, n) symmetric positive definite covariance, n small.
      v: (n,) the rank-one part's vector.

    Returns:
      () the log density.
    """
    n = x.shape[-1]
    chol = cholesky_small(cov)
    z = _forward_sub(chol, x - mean)
    w = _forward_sub(chol, v)
    s = 1.0 + jnp.dot(w, w)
    quad = jnp.maximum(jnp.dot(z, z) - jnp.square(jnp.dot(z, w)) / s, 0.0)
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol))) + jnp.log(s)
    return -0.5 * (quad + log_det + n * LOG_2PI)


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


def cap_bound(cap: jax.Array) -> jax.Array:
    """``logit(cap)``, or inf for a cap of 1 (no bound)."""
    return jnp.where(cap >= 1.0, jnp.inf, logit(jnp.minimum(cap, 1.0 - 1e-7)))


def cap_llr(llr: jax.Array, cap: jax.Array, cap_contact: jax.Array | None = None) -> jax.Array:
    """Clips a log-likelihood ratio to +-logit(cap): the term's confidence cap (docs/model.md).

    With ``cap_contact`` the contact side (positive ratios) is clipped to
    ``logit(cap_contact)`` instead. A cap of exactly 1 leaves that side unbounded.

    Args:
      llr: log-likelihood ratio ``log L(C) - log L(A)``, nats, any shape.
      cap: () cap in (0.5, 1] of the air side (and of both without ``cap_contact``).
      cap_contact: () cap of the contact side, or None.

    Returns:
      The clipped ratio, the shape of ``llr``.
    """
    upper = cap_bound(cap if cap_contact is None else cap_contact)
    return jnp.clip(llr, -cap_bound(cap), upper)


def log_outlier_weight(eps: jax.Array, log_density: jax.Array) -> jax.Array:
    """``log(eps * U)``, the log weight of a shared outlier component, ``-inf`` for eps = 0.

    Args:
      eps: () mixture weight of the outlier component in [0, 1).
      log_density: () log of the outlier component's density at the measurement.
    """
    on = eps > 0.0
    safe = jnp.where(on, eps, 1.0)  # no log(0) in the gradient of the disabled branch
    return jnp.where(on, jnp.log(safe) + log_density, -jnp.inf)


def mixed_logpdf(log_p: jax.Array, eps: jax.Array, log_outlier: jax.Array) -> jax.Array:
    """``log[(1 - eps) p(x) + eps U(x)]``: a density with a broad outlier component.

    Args:
      log_p: () log density of the measurement under the inlier model.
      eps: () outlier probability in [0, 1); 0 gives ``log_p`` exactly.
      log_outlier: () ``log U(x)``, the outlier density at the measurement.
    """
    return jnp.logaddexp(jnp.log1p(-eps) + log_p, log_outlier_weight(eps, log_outlier))


def robust_llr(
    log_c: jax.Array, log_a: jax.Array, eps: jax.Array, log_outlier: jax.Array
) -> jax.Array:
    """Log-likelihood ratio of two hypotheses that share an outlier component.

    Each hypothesis' density is ``(1 - eps) p_h(x) + eps U(x)`` with the same ``U``, so the
    ratio tends to 0 (no evidence) when ``x`` is far from both ``p_C`` and ``p_A``, and to
    ``log p_C - log p_A`` where either explains ``x`` far better than an outlier would.

    Args:
      log_c, log_a: () log densities of the measurement under contact and air.
      eps: () outlier probability in [0, 1); 0 gives ``log_c - log_a`` exactly.
      log_outlier: () ``log U(x)``, the outlier density at the measurement.
    """
    return mixed_logpdf(log_c, eps, log_outlier) - mixed_logpdf(log_a, eps, log_outlier)


def log_mean_exp(x: jax.Array, axis=None) -> jax.Array:
    """log(mean(exp(x))) along ``axis``."""
    n = x.size if axis is None else x.shape[axis]
    return jax.nn.logsumexp(x, axis=axis) - jnp.log(n)


# The float32 inverse normal CDF below writes ndtri(p) = (2p - 1) g(w), w = -log(4 p (1 - p)):
# g is smooth and the same for p and 1 - p, and 4 p (1 - p) keeps both tails' precision (the
# product 4 p (1 - p) has no cancellation where 2p - 1 would round to -1). g is fitted in three
# pieces, w in [0, 5) as a polynomial in w and [5, 17), [17, 52] in sqrt(w), each by Chebyshev
# least squares with relative weights against scipy's float64 ndtri at 4000 Chebyshev nodes
# (degrees 9, 9, 7; fit errors 6.5e-9, 1.3e-8, 4.9e-9 relative), then written as monomials
# in the piece's variable mapped onto [-1, 1]; stored highest degree first, for _horner.
_NDTRI_PIECES = (0.0, 5.0, 17.0, 52.0)  # the pieces' bounds in w
# Python floats, not NumPy ones: a NumPy float64 constant is not weakly typed, and with
# float64 enabled it turned every float32 quantile into float64 (then ndtr_ratio_pair took
# float64's deep-tail switch for float32 erfc values, which underflowed).
_NDTRI_COEFFS = tuple(
    tuple(float(v) for v in c[::-1])
    for c in (
        (
            2.1233134789945147,
            0.872005067137522,
            -0.03692324646913269,
            -0.027681578216145673,
            0.012062020092291285,
            -0.0006868147040824664,
            -0.0011956916959809227,
            0.00040419281270987156,
            5.0203545919277984e-05,
            -4.8237110281808946e-05,
        ),
        (
            4.261209420570249,
            1.34026583449672,
            0.00786333924547902,
            -0.005398538786063959,
            0.0035202808744581545,
            -0.0022461381193109747,
            0.001194050991566146,
            -0.0003393274347462789,
            -0.00011257128996674991,
            9.324783648134315e-05,
        ),
        (
            7.811789288140979,
            2.205165382266394,
            -0.0013929321861146419,
            -0.00040968882002627113,
            0.000257993736125116,
            -9.821144542845775e-05,
            3.978671890983849e-05,
            -1.2848170416420182e-05,
        ),
    )
)


def _horner(coeffs, x: jax.Array) -> jax.Array:
    """The polynomial with ``coeffs`` (highest degree first) at ``x``, unrolled at trace time.

    ``jnp.polyval`` evaluates it in a ``lax.scan``, which XLA:CPU keeps out of the
    surrounding fusion: inside the Monte-Carlo draws that was 1.6x slower overall.
    """
    acc = jnp.full_like(x, coeffs[0])
    for c in coeffs[1:]:
        acc = acc * x + c
    return acc


def ndtri(p: jax.Array) -> jax.Array:
    """Inverse of the standard normal CDF, ``Phi^-1(p)``, for ``p`` in (0, 1).

    float64 (and any type but float32) uses ``jax.scipy.special.ndtri``. float32 uses the
    fitted rule above: one ``log``, one ``sqrt`` and three polynomials, no division, about
    half the time of ``jax.scipy.special.ndtri`` (a Cephes rule built for float64: three
    rational functions, two logs) and as accurate (max relative error 2.0e-7 against
    3.8e-7, both against scipy's float64, for p from 1e-22 to 1 - 6e-8). The rule covers
    ``p >= 6.5e-24`` (``w <= 52``); smaller ``p`` give ``Phi^-1(6.5e-24) = -10.0`` instead of
    less, and ``p = 0`` or ``1`` give -10.0 or 10.0 rather than infinities (the estimator
    never passes them: draws are clipped to [1e-7, 1 - 1e-7] and scaled by at least
    ``Phi(-8)``).

    Args:
      p: probabilities, any shape.

    Returns:
      Standard normal quantiles, the shape and type of ``p``.
    """
    p = jnp.asarray(p)
    if p.dtype != jnp.float32:
        return jax.scipy.special.ndtri(p)
    w0, w1, w2, w3 = _NDTRI_PIECES
    w = jnp.minimum(-jnp.log(4.0 * p * (1.0 - p)), w3)
    # sqrt is only read where w >= w1; the floor keeps its gradient finite at w = 0.
    r = jnp.sqrt(jnp.maximum(w, w1))

    def scaled(x, lo, hi):  # [lo, hi] -> [-1, 1]
        return (x - lo) * (2.0 / (hi - lo)) - 1.0

    central, tail, deep = (
        _horner(c, x)
        for c, x in zip(
            _NDTRI_COEFFS,
            (
                scaled(w, w0, w1),
                scaled(r, math.sqrt(w1), math.sqrt(w2)),
                scaled(r, math.sqrt(w2), math.sqrt(w3)),
            ),
            strict=True,
        )
    )
    g = jnp.where(w < w1, central, jnp.where(w < w2, tail, deep))
    return (2.0 * p - 1.0) * g


def upper_truncated_normal_icdf(v: jax.Array, upper: jax.Array) -> jax.Array:
    """Inverse CDF of a standard normal truncated to (-inf, upper].

    Returns x <= upper with P(X <= x | X <= upper) = v. Below ``upper = -8``, where
    ``v Phi(upper)`` loses float32's precision, the tail ``t = upper - x`` solves
    ``Phi(upper - t) / Phi(upper) = v`` with Mills' ratio ``Phi(x) ~ phi(x) / |x|``:
    ``exp(-c t - t^2 / 2) c / (c + t) = v``, ``c = |upper|``, by its quadratic part's root
    and one Newton step for the ``c / (c + t)`` factor (max error 5e-4 in x at -8, less
    below; the exponential ``t = -log(v) / c`` used before put the mean of ``t`` 3 % too
    far at -8, and the Monte-Carlo touch-down probability about 1 % low there).

    Args:
      v: uniform draw or quadrature node in (0, 1); any shape.
      upper: standardised truncation point; broadcastable to ``v``.

    Returns:
      Standardised values of the shape of ``v``.
    """
    in_bulk = upper > _TAIL_SWITCH
    safe_upper = jnp.where(in_bulk, upper, 0.0)
    # v Phi(upper) in linear space: Phi(upper) >= Phi(-8) ~ 6e-16 here, and one erfc
    # replaces log_ndtr, log and exp at every draw.
    s = ndtr_small_side(safe_upper)
    bulk = ndtri(v * jnp.where(safe_upper < 0.0, s, 1.0 - s))
    tail_upper = jnp.where(in_bulk, _TAIL_SWITCH, upper)
    c, e = jnp.abs(tail_upper), -jnp.log(v)
    t = 2.0 * e / (c + jnp.sqrt(c * c + 2.0 * e))  # c t + t^2 / 2 = e, without cancellation
    t = t - jnp.log1p(t / c) / (c + t + 1.0 / (c + t))  # Newton for the c / (c + t) factor
    tail = tail_upper - t
    return jnp.minimum(jnp.where(in_bulk, bulk, tail), upper)


def ndtr_small_side(x: jax.Array) -> jax.Array:
    """``min(Phi(x), Phi(-x)) = Phi(-|x|)`` with one ``erfc``, accurate to underflow.

    Both ``Phi(x)`` and ``Phi(-x)`` follow from it without cancellation on the small side
    (``Phi(x) = s`` for ``x < 0``, else ``1 - s``), so one transcendental gives both tails;
    ``log_ndtr`` costs several (both of its branches and a log are evaluated under ``vmap``).
    """
    return 0.5 * jax.lax.erfc(jnp.abs(x) * _SQRT_HALF)


def _deep_tail_switch(dtype) -> float:
    """Below this standardised point the CDF ratio is taken from the Mills series.

    ``erfc`` keeps its relative accuracy down to ``Phi(-12.7)`` in float32 and
    ``Phi(-37)`` in float64; the switch leaves room below it.
    """
    return -20.0 if jnp.finfo(dtype).bits == 64 else -9.0


def _mills_series(x: jax.Array) -> jax.Array:
    """``Phi(x) |x| / phi(x)`` for ``x`` far below 0: its asymptotic series to ``x^-8``.

    The first omitted term, ``945 / x^10``, is below 3e-7 for ``|x| >= 9``.
    """
    return _mills_poly(1.0 / (x * x))


def _mills_poly(y: jax.Array) -> jax.Array:
    """:func:`_mills_series` as the polynomial in ``y = 1 / x^2`` that it is."""
    return 1.0 + y * (-1.0 + y * (3.0 + y * (-15.0 + y * 105.0)))


def ndtr_ratio_pair(b: jax.Array, d: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(r, 1 - r)`` for ``r = Phi(b + d) / Phi(b)``, ``d <= 0``, both to relative precision.

    ``1 - r = (Phi(b) - Phi(a)) / Phi(b)`` with ``a = b + d`` and the difference of the CDFs
    taken on the side where both are small, so no cancellation occurs unless ``d`` is tiny
    (where the absolute error stays at round-off). Far in the lower tail, where ``Phi(b)``
    underflows, ``r = exp(-d (a + b) / 2) (b / a) S(a) / S(b)`` with ``S`` the Mills series.
    Costs one ``erfc`` per distinct ``a`` and ``b`` and one ``exp``, against two
    ``log_ndtr`` (each several transcendentals) for the same ratio in log space.

    Args:
      b: upper point, any shape; ``erfc`` of ``b`` runs at ``b``'s own shape.
      d: non-positive shift, broadcastable against ``b``.

    Returns:
      (r, 1 - r), each of the broadcast shape, in [0, 1].
    """
    switch = _deep_tail_switch(jnp.result_type(b, d))
    # Direct branch, at points clamped into its range where the deep branch is taken (so
    # no inf or NaN arises in either branch or its gradient).
    # Everything of b alone (its CDF, the reciprocals) is formed at b's shape, so a division
    # happens once per b, not once per (b, d) pair: in the quadrature, 8 per leg, not 64.
    bs = jnp.maximum(b, switch)
    a = bs + d
    s_a, s_b = ndtr_small_side(a), ndtr_small_side(bs)
    cdf_b = jnp.where(bs < 0.0, s_b, 1.0 - s_b)
    inv_cdf_b = 1.0 / cdf_b
    cdf_a = jnp.where(a < 0.0, s_a, 1.0 - s_a)
    # Phi(b) - Phi(a): as upper tails Q(a) - Q(b) when a >= 0, else Phi(b) - Phi(a).
    diff = jnp.where(a >= 0.0, s_a - s_b, cdf_b - s_a)
    ratio = cdf_a * inv_cdf_b
    hit = diff * inv_cdf_b
    # Deep branch: both points below the switch.
    bd = jnp.minimum(b, switch)
    ad = bd + d
    inv_ad = 1.0 / ad
    bd_over_s_bd = bd / _mills_series(bd)
    ratio_deep = (
        jnp.exp(-0.5 * d * (ad + bd)) * (bd_over_s_bd * inv_ad) * _mills_poly(inv_ad * inv_ad)
    )
    deep = b < switch
    ratio = jnp.where(deep, ratio_deep, ratio)
    hit = jnp.where(deep, 1.0 - ratio_deep, hit)
    return jnp.clip(ratio, 0.0, 1.0), jnp.clip(hit, 0.0, 1.0)
