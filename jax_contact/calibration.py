"""The calibration map on the fused logit, applied after the recursion.

The filter (eq. 1-3) runs on the raw log-odds ``l``; a :class:`Calibration` maps the
logit it reports, ``l' = map(l)``, and ``P(contact) = sigmoid(l')``. Maps are fitted by
:func:`jax_contact.tune.fit_calibration` on the tuning logs (``jax-contact tune
--calibrate``) and kept in a parameter file's provenance; :func:`load_calibration` reads
one back, and the wrapper (``ContactObsConfig.calibration``), ``jax-contact estimate``,
``jax-contact evaluate`` and the exported estimator apply the file's map to the P they
report (docs/tuning.md, rule 14).

NumPy only at import: the JAX branch of :func:`apply_calibration` imports JAX when given
JAX arrays.
"""

from __future__ import annotations

import dataclasses
import difflib
import os

import numpy as np


def sigmoid_np(logit) -> np.ndarray:
    """P = sigmoid(logit) in float64 NumPy (no overflow; NaN stays NaN, silently)."""
    x = np.asarray(logit, np.float64)
    with np.errstate(invalid="ignore"):  # logaddexp of a NaN warns; the NaN is the answer
        return np.exp(-np.logaddexp(0.0, -x))


CALIBRATION_KINDS = ("sign", "affine")
# The temperatures a map may hold: fits keep theirs in [0.05, 20]; outside this range
# 1 / T overflows or underflows float32 and the reported P is no probability.
TEMPERATURE_RANGE = (1e-3, 1e3)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A monotone map on the fused logit, applied after the recursion.

    Two kinds (:func:`jax_contact.tune.fit_calibration`):

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
        for name in ("temperature", "temperature_air", "bias"):
            v = getattr(self, name)
            if name == "temperature_air" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
                raise ValueError(f"{name} must be a number, got {v!r}")
            # Bounded: 1 / T overflowed float32 for T ~ 1e-40, and 0 * inf made P NaN.
            if name != "bias" and not (
                np.isfinite(v) and TEMPERATURE_RANGE[0] <= v <= TEMPERATURE_RANGE[1]
            ):
                raise ValueError(
                    f"{name} must be a finite number in [{TEMPERATURE_RANGE[0]:g},"
                    f" {TEMPERATURE_RANGE[1]:g}], got {v!r}"
                )
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

    def describe(self) -> str:
        """One line for people: the temperature(s), and the bias of an affine map."""
        if self.temperature_air is None:
            return f"T {self.temperature:.3f}, bias {self.bias:+.3f}"
        return f"T {self.temperature:.3f} for P > 0.5, {self.temperature_air:.3f} for P < 0.5"

    def as_dict(self) -> dict:
        out = {"kind": self.kind, "temperature": float(self.temperature), "bias": float(self.bias)}
        if self.temperature_air is not None:
            out["temperature_air"] = float(self.temperature_air)
        return out

    @classmethod
    def from_dict(cls, d) -> Calibration:
        """From :meth:`as_dict` (files written before the per-side map have no
        ``temperature_air`` and are affine)."""
        if not isinstance(d, dict) or "temperature" not in d:
            raise ValueError(
                f"calibration: expected a mapping with 'temperature' (and 'bias' or"
                f" 'temperature_air'), got {d!r}"
            )
        # A typo ("tempreature_air") silently made a per-side map affine. Other keys are
        # the map's notes (fitted_on, validation_after, ...), kept as they are.
        fields = ("kind", "temperature", "bias", "temperature_air")
        for key in set(d) - set(fields):
            if close := difflib.get_close_matches(str(key), fields, n=1, cutoff=0.8):
                raise ValueError(f"calibration: unknown field {key!r}; did you mean {close[0]!r}?")
        for name in ("temperature", "bias", "temperature_air"):
            v = d.get(name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)):
                raise ValueError(f"calibration.{name} must be a number, got {v!r}")
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

    The logit of ``p`` is mapped by :func:`apply_calibration` and turned back into a
    probability. ``p`` is clipped to [float32's smallest normal, 1 - 1e-7]: the filter's
    float32 P keeps its logit down to about -87, but above 1 - 6e-8 it rounds to 1, so
    there the logit is read as 16.1 (the map of a larger logit differs by at most 1e-7 in
    P: every shipped map has ``temperature`` near 1).
    """
    p = np.asarray(p)
    if not (np.issubdtype(p.dtype, np.floating) or np.issubdtype(p.dtype, np.integer)):
        raise ValueError(f"p must be probabilities (numbers in [0, 1]), got dtype {p.dtype}")
    p = p.astype(np.float64)
    if np.any((p < 0) | (p > 1)):  # a logit passed as P came back as a confident P
        bad = p[(p < 0) | (p > 1)]
        raise ValueError(
            f"p must lie in [0, 1] (probabilities, not logits: apply_calibration maps a"
            f" logit), got {bad.size} values outside, e.g. {bad.flat[0]:g}"
        )
    q = np.clip(p, np.finfo(np.float32).tiny, 1.0 - 1e-7)
    return sigmoid_np(apply_calibration(np.log(q) - np.log1p(-q), calibration))


def calibration_of(provenance) -> Calibration | None:
    """The calibration map a parameter file's provenance holds (``jax-contact tune
    --calibrate``), or None."""
    cal = (provenance or {}).get("calibration")
    return None if cal is None else Calibration.from_dict(cal)


def file_calibration(provenance, source) -> Calibration | None:
    """:func:`calibration_of` a provenance read from the file or preset ``source``, a
    malformed map raised as a ValueError that names ``source`` and the field."""
    return checked_calibration(provenance, repr(str(source)))


def checked_calibration(provenance, where: str) -> Calibration | None:
    """:func:`calibration_of`, a malformed map raised as a ValueError that starts with
    ``where`` (a file's description, e.g. ``"parameter file '...'"``) and names the field."""
    try:
        return calibration_of(provenance)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{where}: provenance field 'calibration': {err}") from None


def load_calibration(path: str | os.PathLike) -> Calibration | None:
    """The calibration map of a parameter file or shipped preset (``provenance
    ["calibration"]``, :func:`jax_contact.load_params`), or None when it has none.

    Raises:
      ValueError: as :func:`jax_contact.load_params`, or a malformed map (named).
    """
    from jax_contact.params_file import load_params

    _, provenance = load_params(path, with_provenance=True)
    return file_calibration(provenance, path)


def probability(logit, calibration: Calibration | None = None):
    """P(contact) of a fused logit (JAX arrays, any shape), through ``calibration`` if
    given: ``sigmoid(apply_calibration(logit, calibration))``, else ``sigmoid(logit)``."""
    import jax

    if calibration is not None:
        logit = apply_calibration(logit, calibration)
    return jax.nn.sigmoid(logit)
