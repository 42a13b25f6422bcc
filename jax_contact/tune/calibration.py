"""The calibration map on the fused logit, fitted after tuning."""

from __future__ import annotations

import dataclasses

import numpy as np

# ------------------------------------------------------------------------- calibration


def sigmoid_np(logit) -> np.ndarray:
    """P = sigmoid(logit) in float64 NumPy (no overflow)."""
    x = np.asarray(logit, np.float64)
    return np.exp(-np.logaddexp(0.0, -x))


CALIBRATION_KINDS = ("sign", "affine")
# The per-side temperatures of a "sign" map are kept in [1/20, 20]: a side whose steps are
# all of one class (never wrong) has no finite maximum-likelihood temperature.
_TEMPERATURE_BOUNDS = (0.05, 20.0)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A monotone map on the fused logit, applied after the recursion.

    Two kinds (:func:`fit_calibration`):

    - affine, ``l' = l / temperature + bias`` (``temperature_air`` None);
    - per side ("sign"), ``l' = l / temperature`` for ``l > 0`` and
      ``l / temperature_air`` for ``l <= 0``, bias 0. It keeps the sign of every logit, so
      a flag taken at P > 0.5 (F1, accuracy, failures, delays) is the raw P's, and only the
      probabilities move.

    The identity: temperature 1, bias 0, no ``temperature_air``.
    """

    temperature: float = 1.0
    bias: float = 0.0
    temperature_air: float | None = None

    def __post_init__(self):
        for name in ("temperature", "temperature_air"):
            v = getattr(self, name)
            if name == "temperature_air" and v is None:
                continue
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not np.isfinite(self.bias):
            raise ValueError(f"bias must be finite, got {self.bias!r}")
        if self.temperature_air is not None and self.bias != 0:
            raise ValueError(
                f"a per-side map (temperature_air set) has no bias, got bias {self.bias!r}"
            )

    @property
    def kind(self) -> str:
        """``"sign"`` (keeps every decision at 0.5) or ``"affine"``."""
        return "affine" if self.temperature_air is None else "sign"

    @property
    def keeps_decisions(self) -> bool:
        """Whether the flag P > 0.5 is unchanged by the map (a per-side map, or bias 0)."""
        return self.temperature_air is not None or self.bias == 0

    def as_dict(self) -> dict:
        out = {"kind": self.kind, "temperature": float(self.temperature), "bias": float(self.bias)}
        if self.temperature_air is not None:
            out["temperature_air"] = float(self.temperature_air)
        return out

    @classmethod
    def from_dict(cls, d) -> Calibration:
        """From :meth:`as_dict` (files written before the per-side map have no
        ``temperature_air`` and are affine)."""
        air = d.get("temperature_air")
        cal = cls(
            temperature=float(d["temperature"]),
            bias=float(d.get("bias", 0.0)),
            temperature_air=None if air is None else float(air),
        )
        if d.get("kind", cal.kind) != cal.kind:
            raise ValueError(
                f"calibration: kind {d['kind']!r} does not match its fields (a 'sign' map has"
                f" temperature_air and no bias, an 'affine' one no temperature_air)"
            )
        return cal


def apply_calibration(logit, calibration: Calibration):
    """The calibrated logit (JAX or NumPy arrays, any shape): ``logit / T + bias``, or
    per side ``logit / T`` where ``logit > 0`` and ``logit / T_air`` elsewhere."""
    if calibration.temperature_air is None:
        return logit / calibration.temperature + calibration.bias
    scale = 1.0 / calibration.temperature
    scale_air = 1.0 / calibration.temperature_air
    if isinstance(logit, np.ndarray | np.generic | float | int):
        return np.where(np.asarray(logit) > 0, logit * scale, logit * scale_air)
    import jax.numpy as jnp

    return jnp.where(logit > 0, logit * scale, logit * scale_air)


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
      ValueError: an unknown kind, no masked step, only one class, or no finite positive
        temperature.
    """
    if kind not in CALIBRATION_KINDS:
        raise ValueError(f"kind must be one of {CALIBRATION_KINDS}, got {kind!r}")
    m = np.asarray(mask, bool)
    x = np.asarray(logits, np.float64)[m]
    y = np.asarray(truth, bool)[m].astype(np.float64)
    if x.size == 0 or y.min() == y.max():
        raise ValueError("fit_calibration needs masked steps of both classes")
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
