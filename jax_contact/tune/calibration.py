"""The calibration map on the fused logit, fitted after tuning."""

from __future__ import annotations

import dataclasses

import numpy as np

# ------------------------------------------------------------------------- calibration


def sigmoid_np(logit) -> np.ndarray:
    """P = sigmoid(logit) in float64 NumPy (no overflow)."""
    x = np.asarray(logit, np.float64)
    return np.exp(-np.logaddexp(0.0, -x))


@dataclasses.dataclass(frozen=True)
class Calibration:
    """The map ``l' = l / temperature + bias`` on the fused logit, applied after the
    recursion (the identity: temperature 1, bias 0)."""

    temperature: float = 1.0
    bias: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.temperature) and self.temperature > 0):
            raise ValueError(f"temperature must be a finite number > 0, got {self.temperature!r}")
        if not np.isfinite(self.bias):
            raise ValueError(f"bias must be finite, got {self.bias!r}")

    def as_dict(self) -> dict:
        return {"temperature": float(self.temperature), "bias": float(self.bias)}

    @classmethod
    def from_dict(cls, d) -> Calibration:
        return cls(temperature=float(d["temperature"]), bias=float(d["bias"]))


def apply_calibration(logit, calibration: Calibration):
    """The calibrated logit ``logit / T + bias`` (JAX or NumPy arrays, any shape)."""
    return logit / calibration.temperature + calibration.bias


def calibrate_probability(p, calibration: Calibration) -> np.ndarray:
    """P(contact) mapped by ``calibration`` (float64 NumPy, any shape; NaN stays NaN).

    The logit of ``p`` (clipped to [1e-7, 1 - 1e-7], where the filter's float32 output
    saturates) is mapped by :func:`apply_calibration` and turned back into a probability.
    """
    q = np.clip(np.asarray(p, np.float64), 1e-7, 1.0 - 1e-7)
    return sigmoid_np(apply_calibration(np.log(q) - np.log1p(-q), calibration))


def calibration_of(provenance) -> Calibration | None:
    """The calibration map a parameter file's provenance holds (``jax-contact tune
    --calibrate``), or None."""
    cal = (provenance or {}).get("calibration")
    return None if cal is None else Calibration.from_dict(cal)


def fit_calibration(logits, truth, mask, *, iterations: int = 50) -> Calibration:
    """Maximum-likelihood temperature and bias (logistic regression on the logit).

    Newton's method in float64 on ``a = 1 / T`` and ``c`` with a backtracking line search
    (the BCE of ``sigmoid(a l + c)`` is convex in ``(a, c)``, but a full Newton step can
    overshoot when most logits sit at the caps' bounds), starting from the identity.

    Args:
      logits, truth, mask: (T, E, L) arrays; only masked steps count.

    Raises:
      ValueError: no masked step, only one class, or no finite positive temperature.
    """
    m = np.asarray(mask, bool)
    x = np.asarray(logits, np.float64)[m]
    y = np.asarray(truth, bool)[m].astype(np.float64)
    if x.size == 0 or y.min() == y.max():
        raise ValueError("fit_calibration needs masked steps of both classes")
    x = np.clip(x, -50.0, 50.0)

    def loss(a, c):
        z = a * x + c
        return float(np.mean(np.logaddexp(0.0, z) - y * z))

    a, c = 1.0, 0.0
    current = loss(a, c)
    for _ in range(iterations):
        p = sigmoid_np(a * x + c)
        r = p - y
        g = np.array([np.mean(r * x), np.mean(r)])
        w = p * (1.0 - p)
        h = np.array([[np.mean(w * x * x), np.mean(w * x)], [np.mean(w * x), np.mean(w)]])
        step = np.linalg.solve(h + 1e-9 * np.eye(2), g)
        t = 1.0
        while t > 1e-8:
            trial = loss(a - t * step[0], c - t * step[1])
            if trial <= current:
                break
            t *= 0.5
        else:
            break  # no descent along the Newton direction: at the minimum (to round-off)
        a, c, current = a - t * step[0], c - t * step[1], trial
        if np.max(np.abs(t * step)) < 1e-10:
            break
    if not (np.isfinite(a) and np.isfinite(c) and a > 0):
        raise ValueError(f"the fitted inverse temperature is {a}; no calibration map")
    return Calibration(temperature=float(1.0 / a), bias=float(c))
