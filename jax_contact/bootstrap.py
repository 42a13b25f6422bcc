"""Is one detector really better than another? A paired bootstrap over envs.

Two parameter sets replayed on the same log give two rows of Table III that differ in
every cell by a little. Whether a difference of 0.3 ms in touch-down delay or 0.003 in
ECE is a property of the parameters or of the particular rollouts the log happens to
hold is a question of how much the metric moves from one set of rollouts to another.
This module answers it by resampling the rollouts.

The unit of resampling is the env (axis 1 of a (T, E, ...) batch). Envs are independent
rollouts (their own random commands, pushes and sensor noise), while the steps, events
and legs of one env are not: a leg's contact phases follow its gait, and a drifting base
estimate touches every step of its env. Resampling steps or events would treat thousands
of correlated samples as independent and give intervals far too narrow; resampling envs
keeps each env's dependence whole (the cluster bootstrap).

The procedure (paired: both detectors always see the same resample):

1. For ``b = 1..B``, draw ``E`` envs with replacement (``numpy`` generator of ``seed``)
   and score both detectors on them: every metric pools its events over the resampled
   envs exactly as over the original ones, an env drawn twice counting twice. Each
   pooled metric is a ratio of sums over sequences, so the envs are scored once
   (:func:`jax_contact.metrics.env_sums`) and a resample is a weighted sum of their rows,
   equal to :func:`jax_contact.metrics.evaluate` on the resampled batch (a test checks
   this); 10 000 resamples cost milliseconds.
2. For each statistic, the difference ``candidate - reference`` on that resample.
3. The interval is ``delta -+ h sd``: ``delta`` the difference on the log itself, ``sd``
   the standard deviation of the ``B`` differences (NaN resamples left out), and
   ``h = t_{E-1}((1 + level) / 2) sqrt(E / (E - 1))`` (:func:`student_half_width`): the
   bootstrap's variance of a mean of ``E`` clusters is ``(E - 1) / E`` of the unbiased
   one, and a mean of ``E`` clusters has ``E - 1`` degrees of freedom. Until the
   fifty-fourth session the interval was the plain percentile one (the ``(1 -+ level) /
   2`` quantiles of the differences), which is too narrow for few clusters: in a helper's
   simulation (two equally good detectors, 1000 null batches each, F1) it called 7.6 % of
   them better or worse at 16 envs, 13 % at 8 and 16 % at 5, against the 5 % a 95 %
   interval promises; this interval calls 4.7 %, 5.6 % and 4.3 %, and still finds a true
   F1 difference of 0.019 in 97 % of the batches at 8 envs and in all at 16.

A statistic is *worse* when the whole interval lies on the worse side of 0, *better*
when it lies on the better side, and *within noise* otherwise. With ``level = 0.95`` about
one cell in twenty is called better or worse by chance when two detectors are the same, so
a table of 24 cells x 6 statistics will show a few such calls for identical detectors:
read a lone call with that in mind. With ``E = 16`` envs the interval is itself rough;
it says whether a difference is of the size that re-running the rollouts produces, not
more. Below :data:`MIN_ENVS` envs no call is made
(``too few envs``): 2 envs have 3 distinct resamples, 4 have 35, and so coarse a
distribution's spread says little about the rollouts' (with the percentile interval used
before, a 2-env log called differences "better" on intervals like [-0.20, -0.20]; the
Student interval's own null rate was measured from 5 envs up).

Evaluation code, NumPy in float64, like :mod:`jax_contact.metrics`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from jax_contact.metrics import env_sums


@dataclasses.dataclass(frozen=True)
class Statistic:
    """One pooled metric (a key of :meth:`jax_contact.metrics.EnvSums.pooled`).

    Attributes:
      key: the pooled metric.
      higher_is_better: the direction of "better".
      description: what the number is, with units.
      label: its name in printed lines (Table III's column where it has one).
      magnitude: compare ``|value|`` (a mean delay, whose bound is on its size).
    """

    key: str
    higher_is_better: bool
    description: str
    label: str
    magnitude: bool = False

    def of(self, pooled: Mapping[str, np.ndarray]) -> np.ndarray:
        """The statistic from ``EnvSums.pooled``'s dict."""
        value = pooled[self.key]
        return np.abs(value) if self.magnitude else value


# The fewest envs whose resamples make an interval worth a verdict (module docstring).
MIN_ENVS = 5

STATISTICS: Mapping[str, Statistic] = {
    "f1": Statistic("f1", True, "F1 of the per-step flag", "F1"),
    "accuracy": Statistic("accuracy", True, "per-step accuracy", "acc"),
    "air_phase_failure_rate": Statistic(
        "air_phase_failure_rate", False, "fraction of air phases with a false contact", "air-ph"
    ),
    "swing_phase_failure_rate": Statistic(
        "swing_phase_failure_rate",
        False,
        "fraction of air phases longer than a bounce with a false contact",
        "sw-ph",
    ),
    "swing_phase_flag_on_rate": Statistic(
        "swing_phase_flag_on_rate",
        False,
        "fraction of air phases longer than a bounce with the flag on throughout",
        "sw-on",
    ),
    "touchdown_delay_ms": Statistic(
        "touchdown_delay_ms", False, "|mean touch-down delay|, ms", "|TD| ms", magnitude=True
    ),
    "liftoff_delay_ms": Statistic(
        "liftoff_delay_ms", False, "|mean lift-off delay|, ms", "|LO| ms", magnitude=True
    ),
    "ece": Statistic("ece", False, "expected calibration error of P(contact)", "ECE"),
}
"""The statistics of issue 15's "every cell at least as good as the defaults" (Table III's
cells and ECE). Delays are compared by the magnitude of their mean (the issue's targets
bound ``|mean|``). Both failure rates are here: rule 9's counts the truth's bounces as air
phases without a failure, which flatters every detector (:mod:`jax_contact.metrics`, rule
9b), and rule 9b's leaves them out; and rule 9c's swings the flag stays on through, which
neither counts (since the fiftieth session)."""


@dataclasses.dataclass(frozen=True)
class Difference:
    """``candidate - reference`` for one statistic, with its bootstrap interval.

    Attributes:
      reference: the statistic of the reference on the log itself.
      candidate: the statistic of the candidate on the log itself.
      low: lower end of the interval of ``candidate - reference``.
      high: upper end.
      higher_is_better: the statistic's direction.
      n_nan: resamples on which the difference was NaN (left out of the interval).
      n_envs: the envs resampled (None: unknown); below :data:`MIN_ENVS` no verdict.
    """

    reference: float
    candidate: float
    low: float
    high: float
    higher_is_better: bool
    n_nan: int = 0
    n_envs: int | None = None

    @property
    def delta(self) -> float:
        """``candidate - reference`` on the log itself."""
        return self.candidate - self.reference

    @property
    def verdict(self) -> str:
        """``"better"``, ``"worse"``, ``"within noise"``, ``"n/a"`` (NaN interval) or
        ``"too few envs"`` (fewer than :data:`MIN_ENVS`)."""
        if not (np.isfinite(self.low) and np.isfinite(self.high)):
            return "n/a"
        if self.n_envs is not None and self.n_envs < MIN_ENVS:
            return "too few envs"
        if self.low > 0.0 or self.high < 0.0:
            up = self.low > 0.0
            return "better" if up == self.higher_is_better else "worse"
        return "within noise"

    def as_list(self) -> list:
        """``[delta, low, high, verdict]``, for JSON."""
        return [self.delta, self.low, self.high, self.verdict]


def _env_axis_inputs(reference, candidate, truth, valid):
    ref, cand, tru = (np.asarray(x) for x in (reference, candidate, truth))
    for name, x in (("reference", ref), ("candidate", cand)):
        if x.shape != tru.shape:
            raise ValueError(f"{name} has shape {x.shape}, but truth has shape {tru.shape}")
    if tru.ndim < 2 or tru.shape[1] < 2:
        raise ValueError(
            f"truth must have shape (T, E, ...) with at least 2 envs to resample, got {tru.shape}"
        )
    if valid is None:
        val = np.ones(tru.shape, bool)
    else:
        val = np.asarray(valid)
        if val.shape != tru.shape:
            if val.shape != tru.shape[: val.ndim]:
                raise ValueError(
                    f"valid has shape {val.shape}: expected {tru.shape} or a leading part of it"
                )
            val = np.broadcast_to(val.reshape(val.shape + (1,) * (tru.ndim - val.ndim)), tru.shape)
    return ref, cand, tru, val


def student_half_width(level: float, n_envs: int) -> float:
    """The interval's half-width in bootstrap standard deviations (module docstring, step
    3): ``t_{n-1}((1 + level) / 2) sqrt(n / (n - 1))``, e.g. 2.2013 for 0.95 at 16 envs
    (``t_15(0.975)`` = 2.1314 times ``sqrt(16 / 15)`` = 1.0328).

    Args:
      level: the nominal coverage, in (0, 1).
      n_envs: the number of envs resampled, >= 2.

    Raises:
      ValueError: ``n_envs`` below 2 (no spread to scale) or ``level`` outside (0, 1).
    """
    import math

    from scipy.stats import t as student_t

    if isinstance(n_envs, bool) or not isinstance(n_envs, int | np.integer) or n_envs < 2:
        raise ValueError(f"n_envs must be an integer >= 2, got {n_envs!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")

    t = float(student_t.ppf((1.0 + level) / 2.0, n_envs - 1))
    return t * math.sqrt(n_envs / (n_envs - 1.0))


def paired_bootstrap(
    reference,
    candidate,
    truth,
    valid=None,
    *,
    dt: float,
    statistics: Sequence[str] = tuple(STATISTICS),
    n_resamples: int = 1000,
    level: float = 0.95,
    seed: int = 0,
    **evaluate_kwargs,
) -> dict[str, Difference]:
    """``candidate - reference`` for each statistic, with its env-bootstrap interval.

    Args:
      reference: (T, E, ...) P(contact) or flags of the reference detector (e.g. the
        default parameters).
      candidate: (T, E, ...) the same of the candidate, on the same log.
      truth: (T, E, ...) bool ground-truth contact.
      valid: None, (T, E, ...) like truth, or (T, E) broadcast over the trailing axes.
      dt: time step, s.
      statistics: names in :data:`STATISTICS`.
      n_resamples: ``B``, the number of env resamples (>= 1).
      level: the interval's coverage, in (0, 1) (:func:`student_half_width`).
      seed: the resampling generator's seed (same seed, same intervals).
      **evaluate_kwargs: passed to :func:`jax_contact.metrics.env_sums` (threshold,
        early_window_s, min_on, n_bins), as to :func:`jax_contact.metrics.evaluate`.

    Returns:
      statistic name -> :class:`Difference`.

    Raises:
      ValueError: on a shape mismatch, fewer than 2 envs, an unknown statistic, or a bad
        ``n_resamples`` / ``level`` / ``seed``.
    """
    unknown = [s for s in statistics if s not in STATISTICS]
    if unknown:
        raise ValueError(f"statistics: unknown {unknown}; known: {sorted(STATISTICS)}")

    def whole(x) -> bool:  # an int, or a float of an int's value (inf: an OverflowError)
        return (
            not isinstance(x, bool)
            and isinstance(x, int | float | np.integer | np.floating)
            and np.isfinite(x)
            and int(x) == x
        )

    if not whole(n_resamples) or n_resamples < 1:
        raise ValueError(f"n_resamples must be an integer >= 1, got {n_resamples!r}")
    if isinstance(level, bool) or not isinstance(level, int | float | np.floating):
        raise ValueError(f"level must be a number in (0, 1), got {level!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    if not whole(seed) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    ref, cand, tru, val = _env_axis_inputs(reference, candidate, truth, valid)
    sums = {}
    for name, x in (("reference", ref), ("candidate", cand)):
        try:  # metrics name their input "estimate": say which of the two it was
            sums[name] = env_sums(x, tru, val, dt=dt, **evaluate_kwargs)
        except ValueError as err:
            msg = str(err)
            if msg.startswith("estimate"):
                raise ValueError(name + msg[len("estimate") :]) from None
            raise
    sums_ref, sums_cand = sums["reference"], sums["candidate"]
    n_envs = tru.shape[1]
    # Each resample as the number of times it draws each env: (B, E) counts.
    counts = np.random.default_rng(seed).multinomial(
        n_envs, np.full(n_envs, 1.0 / n_envs), size=int(n_resamples)
    )
    full_ref, full_cand = sums_ref.pooled(np.ones(n_envs)), sums_cand.pooled(np.ones(n_envs))
    boot_ref, boot_cand = sums_ref.pooled(counts), sums_cand.pooled(counts)
    half = student_half_width(level, n_envs)
    out = {}
    for s in statistics:
        st = STATISTICS[s]
        deltas = st.of(boot_cand) - st.of(boot_ref)
        d = deltas[np.isfinite(deltas)]
        ref_value, cand_value = float(st.of(full_ref)), float(st.of(full_cand))
        spread = half * float(np.std(d)) if d.size > 1 else np.nan
        low, high = cand_value - ref_value - spread, cand_value - ref_value + spread
        out[s] = Difference(
            reference=ref_value,
            candidate=cand_value,
            low=float(low),
            high=float(high),
            higher_is_better=st.higher_is_better,
            n_nan=int(n_resamples) - int(d.size),
            n_envs=n_envs,
        )
    return out


def row_differences(
    outputs: Mapping[str, np.ndarray],
    row: str,
    others: Mapping[str, Sequence[str]],
    truth,
    valid=None,
    *,
    dt: float,
    n_resamples: int = 1000,
    truth_known=None,
) -> dict[str, dict[str, list]]:
    """``row - other`` for each of ``others``, as the JSON outputs store it: the paired
    bootstrap (:func:`paired_bootstrap`, 95 %, seed 0) of ``outputs[row]`` against
    ``outputs[other]`` on the statistics ``others[other]``; ``truth_known`` as
    :func:`jax_contact.metrics.evaluate`'s (None: ``valid``).

    Returns:
      other -> statistic -> ``[delta, low, high, verdict]`` (:meth:`Difference.as_list`).
    """
    return {
        other: {
            k: d.as_list()
            for k, d in paired_bootstrap(
                outputs[other], outputs[row], truth, valid, dt=dt, statistics=tuple(stats),
                n_resamples=n_resamples, truth_known=truth_known,
            ).items()
        }
        for other, stats in others.items()
    }  # fmt: skip


def verdicts(differences: Mapping[str, Difference]) -> dict[str, list[str]]:
    """``{"better": [...], "worse": [...]}``: the statistics called each way (the rest are
    within noise or n/a)."""
    return {
        side: [s for s, d in differences.items() if d.verdict == side]
        for side in ("better", "worse")
    }


def format_intervals(intervals: Mapping[str, Sequence]) -> str:
    """One line, ``"F1 +0.0040 [+0.0010, +0.0070] better; ..."``, from statistic ->
    ``[delta, low, high, verdict]`` (:meth:`Difference.as_list`, as the JSON outputs store
    it), each statistic by its :attr:`Statistic.label`. A difference of too few envs is
    printed without its interval (the JSON keeps it): from 2-4 envs the interval is no
    measure of the rollouts' spread, and a rate's could reach past +-1 (a helper's trial on 2
    envs, ``sw-ph -0.06 [-0.85, +0.73]``)."""
    parts, few = [], False
    for k, (d, lo, hi, v) in intervals.items():
        label = STATISTICS[k].label if k in STATISTICS else k
        if v == "too few envs":
            parts.append(f"{label} {d:+.4f}")
            few = True
        else:
            parts.append(f"{label} {d:+.4f} [{lo:+.4f}, {hi:+.4f}] {v}")
    line = "; ".join(parts)
    if few:
        line += f" (no interval: fewer than {MIN_ENVS} envs to resample)"
    return line
