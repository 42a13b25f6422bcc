"""Fitting the calibration map on the fused logit after tuning (the map itself:
:mod:`jax_contact.calibration`)."""

from __future__ import annotations

import numpy as np

from jax_contact.calibration import (
    CALIBRATION_KINDS,
    Calibration,
    apply_calibration,
    calibrate_probability,
    calibration_of,
    sigmoid_np,
)
from jax_contact.metrics import as_bool

__all__ = [
    "CALIBRATION_KINDS",
    "Calibration",
    "apply_calibration",
    "calibrate_probability",
    "calibration_of",
    "fit_calibration",
    "sigmoid_np",
]

# The per-side temperatures of a "sign" map are kept in [1/20, 20]: a side whose steps are
# all of one class (never wrong) has no finite maximum-likelihood temperature.
_TEMPERATURE_BOUNDS = (0.05, 20.0)


def fit_calibration(
    logits, truth, mask, *, kind: str = "sign", iterations: int = 50
) -> Calibration:
    """Maximum-likelihood calibration map of ``kind`` (:class:`Calibration`).

    - ``"affine"``: logistic regression on the logit, ``sigmoid(a l + c)`` with
      ``a = 1 / T``. Newton's method in float64 on ``(a, c)`` with a backtracking line
      search (the BCE is convex in ``(a, c)``, but a full Newton step can overshoot when
      most logits sit at the caps' bounds), starting from the identity.
    - ``"sign"``: ``sigmoid(a_c l)`` on the steps with ``l > 0`` and ``sigmoid(a_a l)`` on
      the others, each side a one-parameter fit of the same kind (the two sides share no
      step, so the joint maximum is the two separate ones). A side without steps keeps 1;
      each temperature is kept in [0.05, 20] (a side that is never wrong has no finite
      maximum).

    Args:
      logits, truth, mask: arrays of one shape (e.g. (T, E, L)); only masked steps count.
      kind: ``"sign"`` (the default: keeps every decision) or ``"affine"``.
      iterations: Newton steps at most (per side).

    Raises:
      ValueError: an unknown kind, arrays of different shapes, a mask or a masked truth
        value other than bool or 0/1, no masked step, only one class, a non-finite masked
        logit, probabilities given as logits (every masked value in [0, 1]), iterations
        not an int >= 1, or no finite positive temperature.
    """
    if kind not in CALIBRATION_KINDS:
        raise ValueError(f"kind must be one of {CALIBRATION_KINDS}, got {kind!r}")
    shapes = {n: np.shape(a) for n, a in (("logits", logits), ("truth", truth), ("mask", mask))}
    if len(set(shapes.values())) != 1:
        raise ValueError(f"logits, truth and mask must have one shape, got {shapes}")
    if isinstance(iterations, bool) or not isinstance(iterations, int | np.integer):
        raise ValueError(f"iterations must be an int >= 1, got {iterations!r}")
    if iterations < 1:
        raise ValueError(f"iterations must be an int >= 1, got {iterations}")
    # A NaN, 2 or 0.3 read as True moved the map applied to every env (a helper's audit).
    m = as_bool("mask", mask, None)
    x = np.asarray(logits, np.float64)[m]
    y = as_bool("truth", truth, m, where="mask")[m].astype(np.float64)
    if x.size == 0 or y.min() == y.max():
        raise ValueError("fit_calibration needs masked steps of both classes")
    if not np.all(np.isfinite(x)):
        raise ValueError(
            f"logits: {int(np.sum(~np.isfinite(x)))} masked steps are not finite (leave them"
            " out of mask)"
        )
    if x.size >= 10 and np.all((x >= 0.0) & (x <= 1.0)):
        # P(contact) where its logit belongs: every step on the contact side, a map fitted
        # to the wrong quantity without a word.
        raise ValueError(
            "logits: every masked value lies in [0, 1]: these look like probabilities; pass"
            " logits (jax_contact.tune.predict_logits, or log(p) - log1p(-p))"
        )
    x = np.clip(x, -50.0, 50.0)
    if kind == "sign":
        temps = []
        for side in (x > 0, x <= 0):
            # _newton keeps a in [1/20, 20] without a bias: only a NaN can get through.
            a = _newton(x[side], y[side], iterations, bias=False)[0] if side.any() else 1.0
            if not np.isfinite(a):
                raise ValueError(f"the fitted inverse temperature is {a}; no calibration map")
            temps.append(1.0 / a)
        return Calibration(temperature=temps[0], temperature_air=temps[1])
    a, c = _newton(x, y, iterations, bias=True)
    if not (np.isfinite(a) and np.isfinite(c) and a > 0):
        raise ValueError(f"the fitted inverse temperature is {a}; no calibration map")
    return Calibration(temperature=float(1.0 / a), bias=float(c))


def sides_on_bounds(cal: Calibration) -> list[str]:
    """The sides (``"P > 0.5"``, ``"P < 0.5"``) of a ``"sign"`` map whose temperature
    ended on a bound of :func:`fit_calibration`'s [0.05, 20]: a side whose steps were
    (nearly) never wrong, or too few to fit, so its temperature says little. Empty for
    an affine map (not bounded)."""
    if cal.kind != "sign":
        return []
    return [
        side
        for side, t in (("P > 0.5", cal.temperature), ("P < 0.5", cal.temperature_air))
        if any(abs(t - b) <= 1e-6 * b for b in _TEMPERATURE_BOUNDS)
    ]


def _newton(x, y, iterations: int, *, bias: bool) -> tuple[float, float]:
    """Minimises the mean BCE of ``sigmoid(a x + c)`` (``c`` fixed at 0 without ``bias``)
    from ``(1, 0)``: damped Newton steps with a backtracking line search, float64. Without
    ``bias`` ``a`` stays within [1/20, 20] (:data:`_TEMPERATURE_BOUNDS`), so a side that is
    never wrong cannot run off to infinity."""
    lo, hi = (
        (1.0 / _TEMPERATURE_BOUNDS[1], 1.0 / _TEMPERATURE_BOUNDS[0]) if not bias else (0, np.inf)
    )

    def loss(a, c):
        z = a * x + c
        return float(np.mean(np.logaddexp(0.0, z) - y * z))

    a, c = 1.0, 0.0
    current = loss(a, c)
    for _ in range(iterations):
        p = sigmoid_np(a * x + c)
        r = p - y
        w = p * (1.0 - p)
        if bias:
            g = np.array([np.mean(r * x), np.mean(r)])
            h = np.array([[np.mean(w * x * x), np.mean(w * x)], [np.mean(w * x), np.mean(w)]])
            step = np.linalg.solve(h + 1e-9 * np.eye(2), g)
        else:
            step = np.array([np.mean(r * x) / (np.mean(w * x * x) + 1e-12), 0.0])
        t = 1.0
        while t > 1e-8:
            a_new = float(np.clip(a - t * step[0], lo, hi))
            trial = loss(a_new, c - t * step[1])
            if trial <= current:
                break
            t *= 0.5
        else:
            break  # no descent along the Newton direction: at the minimum (to round-off)
        moved = max(abs(a_new - a), abs(t * step[1]))
        a, c, current = a_new, c - t * step[1], trial
        if moved < 1e-10:
            break
    return a, c
