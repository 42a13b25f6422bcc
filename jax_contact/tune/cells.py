"""The validation cells: their smooth stand-ins (the cells in the objective), their
tolerances, and the "no worse" rule."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact.tune.events import TuningData, air_phase_maxima

# The cells in the objective (``constraint_weight > 0``): one smooth stand-in per kind of
# validation cell, and how far each may move before it counts as worse.
CONSTRAINT_CELLS = ("errors", "events", "touchdown", "liftoff")


def constraint_units(dt: float) -> np.ndarray:
    """(4,) the tolerance of each of :data:`CONSTRAINT_CELLS`, in its surrogate's units:
    :data:`CELL_TOLERANCE`'s accuracy (errors per step), failure rate (failed phases per
    phase) and delays (ms -> steps of ``dt``)."""
    tol = CELL_TOLERANCE
    steps = 1e-3 / dt
    return np.array(
        [tol["accuracy"], tol["fail"], tol["touchdown_ms"] * steps, tol["liftoff_ms"] * steps]
    )


# The surrogates' logistic smoothing of the flag ``l > 0``, logit units: a step at ``l =
# -2`` counts 0.02 of a flag, at ``l = -1`` 0.12 (docs/tuning.md: with the probability
# itself, p = sigmoid(l), steps and phases far from the threshold dominate the sums).
CELL_SHARPNESS = 0.5


def cell_surrogates(
    logits: jax.Array,
    window: TuningData,
    temperature: float,
    sharpness: float = CELL_SHARPNESS,
) -> jax.Array:
    """(4,) smooth stand-ins for the validation cells (:data:`CONSTRAINT_CELLS`) of a window.

    Each is the metric's count with the flag ``l > 0`` replaced by ``f = sigmoid(l / k)``
    (``k = sharpness``; ``k`` = 1 would be P itself), over the window's :class:`AirPhases`:

    - ``errors``: the fraction of wrong flags, ``sum m (y (1 - f) + (1 - y) f) / sum m``
      (accuracy's and F1's stand-in);
    - ``events``: the air-phase failure rate, ``sum_a sigmoid(E_a / k) / #air phases``
      with ``E_a`` the smooth maximum of the logit over the phase's scored steps
      (:func:`air_phase_maxima`, the event term's). It counts the truth's bounces (air
      phases of at most ``metrics.BOUNCE_S``) that the cell it stands in for, the
      swing-phase failure rate, leaves out: a bounce almost never starts a false contact
      (the flag is on already), so they share the numerator and differ by a factor per
      log in the denominator;
    - ``touchdown``: ``sum_{after_td} (1 - f) / #touch-downs``, the steps a touch-down is
      missed in the first ``early`` steps of its stance (for a flag that switches on ``d``
      steps after ``t0`` it is ``d``: the delay in steps);
    - ``liftoff``: ``sum_{after_lo} f / #lift-offs``, the same for lift-offs.

    Every count is floored at 1, so a window without an event gives 0.
    """
    ev = jax.tree.map(jnp.asarray, window.events)
    if ev.after_td is None:
        raise ValueError("the cells' surrogates need AirPhases from air_phases()")
    f = jax.nn.sigmoid(logits / sharpness)
    mask = jnp.asarray(window.mask)
    y = jnp.asarray(window.truth).astype(f.dtype)

    def mean(total, count):
        return total / jnp.maximum(jnp.sum(count), 1).astype(f.dtype)

    wrong = jnp.where(mask, y * (1.0 - f) + (1.0 - y) * f, 0.0)
    e, has, n_phases = air_phase_maxima(logits, window, temperature)
    failed = jnp.sum(jnp.where(has, jax.nn.sigmoid(e / sharpness), 0.0))
    return jnp.stack(
        [
            mean(jnp.sum(wrong), mask),
            mean(failed, n_phases),
            mean(jnp.sum(jnp.where(ev.after_td, 1.0 - f, 0.0)), ev.td_step),
            mean(jnp.sum(jnp.where(ev.after_lo, f, 0.0)), ev.lo_step),
        ]
    )


def constraint_penalty(cells: jax.Array, reference: jax.Array, units: jax.Array) -> jax.Array:
    """() ``sum_c softplus((s_c - r_c) / u_c)``: the cells' surrogates ``s`` against the
    untuned parameters' ``r`` on the same window, in tolerance units ``u``
    (:func:`constraint_units`). ~0 where a cell is better by a few tolerances, ~the excess
    in tolerances where it is worse."""
    return jnp.sum(jax.nn.softplus((cells - reference) / units))


# What "no worse" allows with ``TuneConfig.cell_tolerance = 1`` (docs/tuning.md, rule 6: the
# measurement's resolution at 16 envs x 8 s): F1 and accuracy 0.0005 lower, ECE 0.0005
# higher, 0.25 point more swing phases with a false contact, 0.25 ms more |mean delay|.
CELL_TOLERANCE = dict(
    f1=0.0005, accuracy=0.0005, ece=0.0005, fail=0.0025, touchdown_ms=0.25, liftoff_ms=0.25
)
# The validation cells of select="cells": per log, (key, +1 higher is better / -1 lower is).
CELL_KEYS = (
    ("f1", 1),
    ("accuracy", 1),
    ("ece", -1),
    ("fail", -1),
    ("touchdown_ms", -1),
    ("liftoff_ms", -1),
)


def no_worse(cells: Sequence[dict], reference: Sequence[dict], tolerance: float = 0.0) -> bool:
    """Whether every validation cell of ``cells`` is at least as good as ``reference``'s.

    Both are :func:`score_logs`' ``cells`` (one dict per validation log). A cell is a log
    and one of :data:`CELL_KEYS`; ties count as no worse, and a number that is NaN in
    both (e.g. no air phase, no event to time) is not compared; NaN in one only is worse.
    With ``tolerance`` > 0 a cell may be worse by ``tolerance`` x its
    :data:`CELL_TOLERANCE`.
    """
    if len(cells) != len(reference):
        raise ValueError(f"{len(cells)} validation logs' cells against {len(reference)}")
    for got, ref in zip(cells, reference, strict=True):
        for key, sign in CELL_KEYS:
            a, b = float(got[key]), float(ref[key])
            if np.isnan(a) and np.isnan(b):
                continue
            if np.isnan(a) or np.isnan(b) or sign * (a - b) < -tolerance * CELL_TOLERANCE[key]:
                return False
    return True


# The cells of CELL_KEYS as jax_contact.bootstrap's statistics.
SPREAD_STATISTICS = {
    "f1": "f1",
    "accuracy": "accuracy",
    "ece": "ece",
    "fail": "swing_phase_failure_rate",
    "touchdown_ms": "touchdown_delay_ms",
    "liftoff_ms": "liftoff_delay_ms",
}


def worse_beyond_spread(
    logits: Sequence,
    reference_logits: Sequence,
    datas: Sequence,
    *,
    dt: float,
    n_resamples: int = 1000,
    level: float = 0.95,
) -> list[str]:
    """The validation cells of ``logits`` worse than ``reference_logits``' beyond the
    rollouts' spread: the whole 95 % interval of a paired env bootstrap
    (:func:`jax_contact.bootstrap.paired_bootstrap`, seed 0) on the worse side of 0.

    Args:
      logits, reference_logits: per validation log, (T, E, L) fused logits.
      datas: the logs' :class:`TuningData` (``truth``, ``mask`` and ``known``, as in
        :func:`jax_contact.tune.fit.score_logs`' cells); below
        :data:`jax_contact.bootstrap.MIN_ENVS` envs no cell is called worse.
      dt: period, s.

    Returns:
      ``"log<i>:<cell>"`` for each such cell (:data:`CELL_KEYS` names), empty if none.
    """
    from jax_contact.bootstrap import paired_bootstrap
    from jax_contact.tune.calibration import sigmoid_np

    worse = []
    for i, (x, x0, d) in enumerate(zip(logits, reference_logits, datas, strict=True)):
        names = {v: k for k, v in SPREAD_STATISTICS.items()}
        diffs = paired_bootstrap(
            sigmoid_np(x0), sigmoid_np(x), np.asarray(d.truth, bool), np.asarray(d.mask, bool),
            dt=dt, statistics=tuple(names), n_resamples=n_resamples, level=level,
            truth_known=None if d.known is None else np.asarray(d.known, bool),
        )  # fmt: skip
        worse += [f"log{i}:{names[k]}" for k, diff in diffs.items() if diff.verdict == "worse"]
    return worse
