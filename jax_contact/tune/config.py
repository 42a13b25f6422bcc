"""The settings of one tuning run."""

from __future__ import annotations

import dataclasses

import numpy as np

SELECT_RULES = ("loss", "bce", "cells", "spread")


def check_noise_ratio(r, name: str = "noise_ratio") -> float:
    """``r`` as a float if it is 0 (no plausibility box) or a finite number > 1; else
    ValueError naming ``name`` (``TuneConfig.noise_ratio``, :func:`theta_bounds`)."""
    v = float(r)
    if not (v == 0.0 or (np.isfinite(v) and v > 1.0)):
        raise ValueError(f"{name} must be 0 (no box) or a finite number > 1, got {r!r}")
    return v


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Settings of one tuning run (frozen: override with ``dataclasses.replace``).

    Attributes:
      learning_rate: Adam's step size, in units of theta (log or logit) per update.
      clip_norm: the gradient's global norm is clipped to this before Adam.
      max_epochs: passes over the tuning logs at most.
      patience: epochs without a validation improvement before stopping.
      min_delta: the improvement of validation BCE that counts, nats per foot-step.
      chunk: steps per truncated-BPTT window (one optimizer update each).
      prior_noise: ``lambda_sigma``, weight of the prior on the noise log multipliers.
      prior_other: ``lambda_other``, weight of the prior on caps, ``T_s``, ``a_F``.
      seed: the run's key, ``jax.random.key(seed)``, drawn only by a Monte-Carlo
        touch-down (``touchdown="monte_carlo"``): with the quadrature of
        :func:`jax_contact.params_for` the fit does not depend on it.
      air_penalty: ``mu``, weight of the per-step false-contact hinge (0: off, the
        default; a diagnostic of the previous session, superseded by ``event_weight``).
      air_margin: ``m``, the logit below which a true air step costs nothing in the hinge.
      event_weight: ``w_e``, weight of the air-phase event term (0: plain BCE).
      event_temperature: ``tau``, the log-sum-exp's temperature (logit units); smaller is
        closer to the hard maximum.
      event_early_s: the early window of ``jax_contact.metrics`` (rule 2), s: a flagged
        run that starts this close before a true touch-down and lasts into it is the
        touch-down's detection, not a false contact, and is not scored.
      select: which validation number picks the epoch returned: ``"loss"`` (BCE plus the
        event term, the default), ``"bce"``, ``"cells"`` (the lowest loss among the
        epochs no worse than epoch 0 in any validation cell, :func:`no_worse`), or
        ``"spread"`` (the lowest loss among the epochs with no validation cell worse than
        epoch 0's beyond the rollouts' spread, :func:`worse_beyond_spread`: a paired env
        bootstrap instead of the fixed tolerances of ``"cells"``).
      cell_tolerance: with ``select="cells"``, how much worse than epoch 0 a validation
        cell may be, in units of :data:`CELL_TOLERANCE` (0: not at all).
      constraint_weight: ``lambda_c``, weight of the cells in the objective (0: off): the
        penalty :func:`constraint_penalty` of each window's :func:`cell_surrogates` against
        the untuned parameters' on the same window.
      feasible: reject an epoch whose *tuning* logs' cells (:func:`score_logs`, the hard
        metrics) are worse than epoch 0's beyond ``cell_tolerance``: the parameters and the
        optimiser go back to the last accepted epoch and the learning rate is halved (a
        rejected epoch counts against ``patience``). Costs one filter pass over the tuning
        logs per epoch.
      noise_ratio: ``r``, the plausibility box: every tuned noise std stays within a
        factor ``r`` of its derived value (:func:`theta_bounds`, projected like the floors;
        0: no box). :data:`PLAUSIBLE_NOISE_RATIO` (8) is the standing check of the shipped
        presets made a bound of the fit.
    """

    learning_rate: float = 0.05
    clip_norm: float = 1.0
    max_epochs: int = 12
    patience: int = 3
    min_delta: float = 1e-4
    chunk: int = 400
    prior_noise: float = 1e-3
    prior_other: float = 1e-3
    seed: int = 0
    air_penalty: float = 0.0
    air_margin: float = 2.0
    event_weight: float = 0.3
    event_temperature: float = 0.25
    event_early_s: float = 0.05
    select: str = "loss"
    cell_tolerance: float = 0.0
    constraint_weight: float = 0.0
    feasible: bool = False
    noise_ratio: float = 0.0

    def __post_init__(self):
        for name in ("learning_rate", "clip_norm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"TuneConfig.{name} must be a finite number > 0, got {v!r}")
        for name in (
            "prior_noise", "prior_other", "min_delta", "air_penalty", "air_margin",
            "event_weight", "event_early_s", "cell_tolerance", "constraint_weight",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"TuneConfig.{name} must be a finite number >= 0, got {v!r}")
        if not (np.isfinite(self.event_temperature) and self.event_temperature > 0):
            raise ValueError(
                f"TuneConfig.event_temperature must be a finite number > 0,"
                f" got {self.event_temperature!r}"
            )
        check_noise_ratio(self.noise_ratio, "TuneConfig.noise_ratio")
        if self.select not in SELECT_RULES:
            raise ValueError(
                f"TuneConfig.select must be one of {SELECT_RULES}, got {self.select!r}"
            )
        for name, low in (("max_epochs", 0), ("patience", 1), ("chunk", 1)):
            v = getattr(self, name)
            if not isinstance(v, int) or v < low:
                raise ValueError(f"TuneConfig.{name} must be an int >= {low}, got {v!r}")
