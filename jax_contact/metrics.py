"""Evaluation of contact estimates against ground truth: event delays, failures, scores.

Evaluation code, not part of any jitted path: everything here is NumPy in float64, takes
JAX or NumPy arrays, and pools over every axis after the leading time axis, so a batch of
shape (T, E, L) (time, envs, legs) gives one row of a results table (Table III).

Inputs, throughout:
  estimate: (T, ...) contact probability in [0, 1] (float), or a contact flag (bool) for
    detectors that only give flags (then the probability is 0 or 1).
  truth: (T, ...) bool ground-truth contact (or 0/1 numbers).
  valid: optional (T, ...) bool; False steps are ignored (NaN estimates are allowed there).
    Each maximal run of valid steps of one sequence is evaluated on its own, as if it were
    a sequence of its own, except where ``truth_known`` (below) links two runs across a
    gap (rules 7b and 8).
  truth_known: optional (T, ...) bool, the steps whose ``truth`` is known (default:
    ``valid``); it must hold every valid step. A step that is not valid but whose truth is
    known (a detector that read a lost reading there, a recording's row of NaN readings
    with its truth column intact) still tells where the true phases run: rules 7b and 8.
  dt: time step between samples, s.

Event-matching rules (:func:`match_events`), written for touch-downs; lift-offs are the same
rules applied to the complements (``not truth``, ``not flag``):

1. The estimate's flag is ``estimate > threshold`` (default 0.5). A *run* is a maximal
   stretch of consecutive flagged steps. A run is *solid* if it lasts at least ``min_on``
   steps (debounce; default 1, i.e. the raw flag, as a controller would use it); a shorter
   run is a *blip*. A run cut by the end of a valid stretch counts as solid if it is
   already ``min_on`` long and as neither otherwise.
2. A true touch-down is a rising edge of ``truth`` at step ``t0`` (``truth[t0-1]`` off and
   valid). Let ``a0`` be the first step of the air phase before it and ``t1`` the next
   true lift-off (or the end of the valid stretch). Its window is ``[w0, t1)`` with
   ``w0 = max(t0 - early, a0)`` and ``early = round(early_window_s / dt)`` steps (default
   50 ms; Python's ``round``, half to even: 12.5 steps at 250 Hz give 12, 48 ms, and 2.5
   at 50 Hz give 2, 40 ms): detections may lead the truth by up to ``early`` steps, never
   into the previous contact phase, and may lag until the next true lift-off.
3. *Already on*: if the estimate is on at ``w0`` in a solid run that began before ``w0``
   (or at the start of the valid stretch) and lasts past ``t0``, the touch-down has no
   edge to time; it is counted as ``already_on``, neither matched nor missed. (The run
   that caused it is counted elsewhere: a failure if it began in the air, a missed
   lift-off if it never ended.)
4. Otherwise the touch-down is *matched* to the first solid run that starts in
   ``[w0, t1)`` and is still on at ``t0`` (it ends after ``t0``); its delay is
   ``(start - t0) * dt``, between ``-early * dt`` and the stance duration, timed from the
   run's first step whatever ``min_on`` is (a controller that waits for ``min_on`` steps
   before it acts learns of the contact ``(min_on - 1) * dt`` later than this delay). A
   run that starts and ends within the early window, before the true touch-down, is a
   false contact in the air, not the detection. The mean delay is signed: early
   detections (negative) and late ones cancel in it, the standard deviation shows both,
   and the mean of ``|delay|`` (``touchdown_abs_delay_ms``) is reported beside it.
5. Otherwise it is *missed*, if the true lift-off ``t1`` lies in the valid stretch; if the
   true contact lasts to the end of the valid stretch without a detection, it is not
   evaluated at all (the detection may come after the data ends).
6. A touch-down is evaluated only if its early window lies in valid steps: ``t0 - early``
   is in the valid stretch or the air phase began inside it. Matches are still made for
   the others, so that their detections are not counted as failures.
7. A *failure* (the paper's false contact in the air) is a solid run that starts with
   ``truth`` off and is not the match of a touch-down. *Chatter* is each blip that starts
   with ``truth`` off; with ``min_on = 1`` there are no blips and every false blip is a
   failure. A run that begins at the first step of a valid stretch has no edge (the step
   before is not valid; the flag may have risen before the data), so it is neither, and
   it is never a match either.
7b. *Across a gap*: a solid run that begins at the first step after invalid steps is a
   failure all the same if the truth is known and off from the last valid step before the
   gap through the run's first step and the flag was off at that last valid step: the flag
   rose in the gap, inside one true air phase (its time is not known, so it is never a
   match: a flag that rose in a gap within the early window of a touch-down is a failure,
   not that touch-down's detection). Such a run shorter than ``min_on`` is chatter.
   Likewise, for lift-offs, a false lift-off. With ``truth_known`` left at ``valid`` no
   step is both, and rule 7 stands alone.

Delays are reported in ms as mean and population standard deviation (ddof 0) over the
matched, evaluated events pooled over all sequences; NaN when there are none.

Phase and step rates (:func:`evaluate`), the false contacts seen per air phase and per
step rather than as a bare count:

8. An *air phase* is a maximal run of steps whose truth is known (``truth_known``) and
   off, in one sequence, that holds at least one valid step. Invalid steps whose truth is
   known do not split it (a gap of a few lost readings inside a swing is one air phase,
   counted once); a step whose truth is not known does, and with ``truth_known`` left at
   ``valid`` every invalid step does (an air phase is then a maximal off-run inside one
   valid stretch). Runs cut by the start or end of the data count too. ``n_air_phases``
   counts them over all sequences. (Before the thirty-eighth session an invalid step
   always split the phase, so a gap in a recording added an air phase without a failure:
   on a recording the rate of a detector with false contacts fell with every gap.)
9. Each failure (rule 7) is attributed to the air phase that holds its first step (truth
   is off there by rule 7, so there is exactly one). ``air_phases_with_failure`` counts the
   air phases to which at least one failure is attributed, and ``air_phase_failure_rate =
   air_phases_with_failure / n_air_phases`` (NaN for no air phase). A failure that stays
   on through the next stance into the following air phase counts for the phase it began
   in only, and a flag that is already on at the first step of a valid stretch is no
   failure (it has no edge, rule 7; unless rule 7b makes it one); both still show in the
   step rate below.
9b. *Swing phases* are the air phases of more than ``bounce_s`` (default 10 ms, rounded
   to steps; a phase's length counts its steps of known truth, valid or not): a force
   truth calls a resting foot's load dropping below its threshold for a step or a few an
   air phase, which no detector reads as one and which rule 9's rate
   counts as an air phase without a failure. ``swing_phase_failure_rate =
   swing_phases_with_failure / n_swing_phases`` is rule 9's rate without them (on Go1's
   demo walk on rough ground 0.046 where rule 9 gives 0.020).
9c. A flag that stays on through a whole swing phase has no failure in it (rule 7 needs a
   rising edge in the air), only a missed lift-off (rule 5) and a touch-down already on
   (rule 3), so rules 9 and 9b favour a detector that sticks on over one that flickers
   (a hand example: 50 % of the air steps wrong and no failure). ``swing_phases_flag_on``
   counts the swing phases (rule 9b) with the flag on at every valid step, and
   ``swing_phase_flag_on_rate = swing_phases_flag_on / n_swing_phases`` (NaN for none).
10. ``air_false_contact_rate`` = (valid steps with ``truth`` off and the flag on) / (valid
    steps with ``truth`` off), NaN for none: the per-step false-positive rate
    (1 - specificity), independent of ``min_on`` and of the event matching.
11. *Persistent* delays are the delays of the same rules with ``min_on = persist_steps``
    (default 3): the touch-down is timed by the first run of the flag that lasts
    ``persist_steps`` steps, the lift-off by the first such run of its complement, each
    from the run's first step (rule 4: a debounce that confirms the run acts
    ``(persist_steps - 1) * dt`` later, 5 ms at 400 Hz for 3 steps). They are pooled over
    the events matched and evaluated under that debounce, which may be a different set from
    the ``min_on`` one (a touch-down seen only by a 2-step run is matched with
    ``min_on = 1`` but not with ``persist_steps = 3``).

Per env (:func:`env_sums`): the step, phase, delay and ECE-bin sums behind F1, accuracy,
the air- and swing-phase failure rates, the swings the flag stays on through (rule 9c),
the mean delays and ECE, one row per env, so that these
metrics of any multiset of envs are weighted sums of rows (the env bootstrap of
:mod:`jax_contact.bootstrap`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

# ----------------------------------------------------------------------------- inputs


def as_bool(name: str, x, valid: np.ndarray | None, where: str = "valid") -> np.ndarray:
    """``x`` as a bool array: bool, or numbers that are 0 or 1 where ``valid`` (None: all);
    ValueError naming ``name`` and the mask ``where`` otherwise (a NaN or a 0.3 is no truth
    value)."""
    arr = np.asarray(x)
    if arr.dtype == bool:
        return arr
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be bool or 0/1 numbers, got dtype {arr.dtype}")
    checked = arr if valid is None else arr[valid]
    if not np.all((checked == 0) | (checked == 1)):
        raise ValueError(f"{name} must be bool or hold only 0 and 1 (where {where})")
    return arr == 1


def _inputs(estimate, truth, valid, threshold: float):
    """Validates and returns (prob float64, flag bool, truth bool, valid bool), all (T, ...)."""
    est = np.asarray(estimate)
    tru = np.asarray(truth)
    if est.ndim < 1 or est.shape[0] < 1:
        raise ValueError(f"estimate must have shape (T, ...) with T >= 1, got {est.shape}")
    if tru.shape != est.shape:
        raise ValueError(f"truth has shape {tru.shape}, but estimate has shape {est.shape}")
    if valid is None:
        val = np.ones(est.shape, bool)
    else:
        val = np.asarray(valid)
        if val.shape != est.shape:
            raise ValueError(f"valid has shape {val.shape}, but estimate has shape {est.shape}")
        val = as_bool("valid", val, None)
    tru = as_bool("truth", tru, val)
    try:
        th = float(threshold)
    except (TypeError, ValueError):
        raise ValueError(f"threshold must be a number in [0, 1), got {threshold!r}") from None
    if not 0.0 <= th < 1.0:
        raise ValueError(f"threshold must lie in [0, 1), got {threshold!r}")
    if est.dtype == bool:
        flag = est
        prob = est.astype(np.float64)
    else:
        if not np.issubdtype(est.dtype, np.number) or np.issubdtype(est.dtype, np.complexfloating):
            raise ValueError(f"estimate must be float probabilities or bool, got {est.dtype}")
        prob = est.astype(np.float64)
        seen = prob[val]
        if not np.all(np.isfinite(seen)):
            raise ValueError("estimate holds NaN or inf at valid steps")
        if np.any(seen < 0.0) or np.any(seen > 1.0):
            raise ValueError(
                f"estimate must lie in [0, 1], got values in [{seen.min()}, {seen.max()}]"
            )
        flag = prob > th
    return prob, flag, tru, val


def _known(truth_known, truth, val: np.ndarray) -> np.ndarray:
    """The (T, ...) bool steps of known truth (rule 8), ``val`` when ``truth_known`` is None.

    Raises:
      ValueError: naming ``truth_known`` for a wrong shape or dtype, or a valid step whose
        truth is not known; naming ``truth`` for a value other than 0 / 1 where it is known.
    """
    if truth_known is None:
        return val
    known = np.asarray(truth_known)
    if known.shape != val.shape:
        raise ValueError(f"truth_known has shape {known.shape}, but estimate has shape {val.shape}")
    known = as_bool("truth_known", known, None)
    if np.any(val & ~known):
        raise ValueError(
            "truth_known is False at valid steps: a step can be scored only where its truth is"
            " known (pass valid=valid & truth_known)"
        )
    as_bool("truth", truth, known, where="truth_known")
    return known


def _check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    bound = ">=" if allow_zero else ">"
    try:  # None, a string or an array named nothing (float()'s own errors)
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number {bound} 0, got {value!r}") from None
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be finite and {bound} 0, got {value!r}")
    return v


def _check_int(name: str, value, lowest: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lowest:
        raise ValueError(f"{name} must be an int >= {lowest}, got {value!r}")
    return int(value)


# The longest sample period taken for one, s: a contact estimate sampled slower than 1 Hz
# has no touch-down to time; a larger dt is a period in ms or a rate in Hz.
MAX_DT = 1.0
# The longest early window taken, s: a detection more than this before the event is no
# early detection of it (the default is 50 ms).
MAX_EARLY_S = 10.0


def _check_dt(dt) -> float:
    dt = _check_positive("dt", dt)
    if dt > MAX_DT:
        raise ValueError(
            f"dt is the period between samples in seconds (0.0025 at 400 Hz), got {dt:g}:"
            " a period in ms or a rate in Hz?"
        )
    return dt


def _event_settings(dt, early_window_s, min_on) -> tuple[float, int, int]:
    """Checked (dt, early window in steps, min_on) of the event matching (rules 1-2)."""
    dt = _check_dt(dt)
    early_s = _check_positive("early_window_s", early_window_s, allow_zero=True)
    if early_s > MAX_EARLY_S:  # 1e30 s overflowed int() with an OverflowError
        raise ValueError(f"early_window_s must be at most {MAX_EARLY_S:g} s, got {early_s:g}")
    return dt, int(round(early_s / dt)), _check_int("min_on", min_on, 1)


def _flat_codes(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(S * (T + 1),) int8: 1 / 0 at valid steps, -1 at invalid ones, time fastest.

    Every sequence (one per trailing index) is laid out in turn, followed by one invalid
    entry, so runs never cross from one sequence into the next and flat index differences
    within a valid stretch are step counts.
    """
    t = x.shape[0]
    codes = np.where(valid, x.astype(np.int8), np.int8(-1)).reshape(t, -1).T
    pad = np.full((codes.shape[0], 1), -1, np.int8)
    return np.concatenate([codes, pad], axis=1).reshape(-1)


def _flip(k: np.ndarray) -> np.ndarray:
    """Complements the valid entries of ``k``, so lift-offs become rising edges."""
    return np.where(k == -1, k, 1 - k).astype(np.int8)


def _runs(k: np.ndarray):
    """Maximal runs of equal value over the valid entries of ``k`` (from ``_flat_codes``).

    Returns:
      start, end (exclusive), value, start_is_edge (the entry before is valid), and
      end_is_edge (the entry after is valid), each (n_runs,).
    """
    n = k.shape[0]
    change = np.ones(n, bool)
    change[1:] = k[1:] != k[:-1]
    start = np.flatnonzero(change)
    end = np.append(start[1:], n)
    value = k[start]
    keep = value != -1
    start, end, value = start[keep], end[keep], value[keep]
    start_edge = (start > 0) & (k[np.maximum(start - 1, 0)] != -1)
    end_edge = (end < n) & (k[np.minimum(end, n - 1)] != -1)
    return start, end, value, start_edge, end_edge


def short_air_phases(truth, valid, max_steps: int) -> tuple[int, int]:
    """(air phases of at most ``max_steps`` steps, all air phases) of ``truth`` (T, ...)
    with ``valid`` of its shape: the maximal runs of valid air steps with a valid step on
    both sides (so contact there; phases cut by an invalid step or an end are not counted).
    A log's bounce-like air phases (a resting foot's load dropping for a step)."""
    tru = np.asarray(truth, bool)
    k = _flat_codes(tru, np.broadcast_to(np.asarray(valid, bool), tru.shape))
    start, end, value, start_edge, end_edge = _runs(k)
    between = (value == 0) & start_edge & end_edge
    return int(np.sum(between & (end - start <= max_steps))), int(np.sum(between))


def bounce_counts(truth, valid, dt: float) -> tuple[int, int]:
    """(bounces, all air phases) of :func:`short_air_phases` at rule 9b's bounce length
    (:func:`bounce_steps` of ``dt``): ``truth`` (T, E, L) with ``valid`` (T, E), as the
    reproduction and ``evaluate`` hold them."""
    truth = np.asarray(truth, bool)
    valid = np.broadcast_to(np.asarray(valid, bool)[..., None], truth.shape)
    return short_air_phases(truth, valid, bounce_steps(dt))


# ----------------------------------------------------------------------------- events


@dataclasses.dataclass(frozen=True, eq=False)
class EdgeEvents:
    """Matched edges of one kind (touch-downs, or lift-offs), pooled over sequences.

    Attributes:
      delays_ms: (n_matched,) detection delay of every matched, evaluated event, ms.
      n_events: evaluated true events (matched + missed + already).
      missed: evaluated true events with no detection before the next opposite true edge.
      already: evaluated true events the estimate had anticipated by more than the early
        window (rule 3: "already on" for touch-downs, "already off" for lift-offs).
      false_edges: solid estimated edges in the wrong true phase and matched to no event
        (touch-downs: failures, false contacts in the air; lift-offs: false lift-offs).
      chatter: blips (runs shorter than ``min_on``) starting in the wrong true phase.
    """

    delays_ms: np.ndarray
    n_events: int
    missed: int
    already: int
    false_edges: int
    chatter: int

    @property
    def delay_mean_std_ms(self) -> tuple[float, float]:
        """(mean, population std) of the delays, ms; NaN for no matched event."""
        if self.delays_ms.size == 0:
            return (float("nan"), float("nan"))
        return (float(np.mean(self.delays_ms)), float(np.std(self.delays_ms)))

    @property
    def delay_abs_mean_ms(self) -> float:
        """Mean of the delays' magnitudes, ms (early and late detections do not cancel);
        NaN for no matched event."""
        if self.delays_ms.size == 0:
            return float("nan")
        return float(np.mean(np.abs(self.delays_ms)))


@dataclasses.dataclass(frozen=True, eq=False)
class EventMatch:
    """Touch-down and lift-off events of :func:`match_events`."""

    touchdown: EdgeEvents
    liftoff: EdgeEvents


def _rose_in_gap(kf: np.ndarray, kt: np.ndarray, fs, fv, fse) -> np.ndarray:
    """Rule 7b: (n_runs,) bool, the flag runs of ``kf`` (starts ``fs``, values ``fv``, start
    edges ``fse``) that begin right after invalid steps inside one known-off run of ``kt``
    (the truth over its known steps) that also holds the last valid step before them, where
    the flag was off."""
    out = np.zeros(fs.shape, bool)
    idx = np.flatnonzero((fv == 1) & ~fse & (fs > 0))
    if idx.size == 0:
        return out
    last_valid = np.maximum.accumulate(np.where(kf != -1, np.arange(kf.size), -1))
    before = last_valid[fs[idx] - 1]
    ts = _runs(kt)[0]
    # The known-truth run that holds each start (its truth is known there: valid steps are).
    holder = np.searchsorted(ts, fs[idx], side="right") - 1
    out[idx] = (
        (before >= 0)
        & (kt[fs[idx]] == 0)
        & (ts[holder] <= before)
        & (kf[np.maximum(before, 0)] == 0)
    )
    return out


def _edge_events(
    kg: np.ndarray,
    kf: np.ndarray,
    early: int,
    min_on: int,
    dt: float,
    kt: np.ndarray | None = None,
) -> tuple[EdgeEvents, np.ndarray]:
    """Rules 2-7b of the module docstring for rising edges of ``kg`` (truth) vs ``kf``;
    ``kt`` the truth's codes over its known steps (None: ``kg``'s, no rule 7b).

    Returns:
      The :class:`EdgeEvents`, and the flat indices (into ``kg``) of the first steps of the
      false edges, so that callers can attribute them to true phases (rule 9).
    """
    gs, ge, gv, gse, gee = _runs(kg)
    fs, fe, fv, fse, fee = _runs(kf)

    events = np.flatnonzero((gv == 1) & gse)
    t0, t1, t1_real = gs[events], ge[events], gee[events]
    # The run before a rising edge is the (valid) off-phase that it ends.
    a0, a0_real = gs[events - 1], gse[events - 1]
    w0 = np.maximum(t0 - early, a0)
    evaluable = a0_real | (t0 - early >= a0)

    length = fe - fs
    solid = (fv == 1) & (length >= min_on)
    cand = np.flatnonzero(solid & fse)
    cand_start = fs[cand]
    # Runs are disjoint and ordered, so their ends are sorted too: j is the first candidate
    # still on at t0 (rule 4); if it started before w0 it is rule 3's run, not a match.
    j = np.searchsorted(fe[cand], t0, side="right")
    has = j < cand.size
    j = np.minimum(j, max(cand.size - 1, 0))
    if cand.size:
        matched = has & (cand_start[j] >= w0) & (cand_start[j] < t1)
    else:
        matched = np.zeros(events.shape, bool)

    # The estimate's run that holds step w0 (w0 is a valid step, so one always does).
    r = np.searchsorted(fs, w0, side="right") - 1
    if events.size:
        already = solid[r] & (fe[r] > t0) & ~((fs[r] == w0) & fse[r])
    else:
        already = np.zeros(0, bool)
    matched &= ~already
    missed = ~matched & ~already & t1_real

    delays = (cand_start[j[matched & evaluable]] - t0[matched & evaluable]) * dt * 1e3
    matched_runs = np.zeros(fs.shape, bool)
    matched_runs[cand[j[matched]]] = True

    wrong_phase = kg[fs] == 0
    # A run with a start edge, or one that rose in a gap of a known air phase (rule 7b).
    edge = fse if kt is None else fse | _rose_in_gap(kf, kt, fs, fv, fse)
    false_edges = solid & edge & wrong_phase & ~matched_runs
    chatter = (fv == 1) & (length < min_on) & edge & fee & wrong_phase
    events_out = EdgeEvents(
        delays_ms=delays.astype(np.float64),
        n_events=int(np.sum(evaluable & (matched | already | missed))),
        missed=int(np.sum(evaluable & missed)),
        already=int(np.sum(evaluable & already)),
        false_edges=int(np.sum(false_edges)),
        chatter=int(np.sum(chatter)),
    )
    return events_out, fs[false_edges]


def match_events(
    estimate,
    truth,
    valid=None,
    *,
    dt: float,
    threshold: float = 0.5,
    early_window_s: float = 0.05,
    min_on: int = 1,
    truth_known=None,
) -> EventMatch:
    """Matches estimated touch-downs and lift-offs to the true ones (module docstring rules).

    Args:
      estimate: (T, ...) contact probability in [0, 1], or bool flags.
      truth: (T, ...) bool true contact.
      valid: optional (T, ...) bool mask of the steps to evaluate.
      dt: time step, s.
      threshold: the flag is ``estimate > threshold``.
      early_window_s: how far a detection may lead the true edge, s (default 50 ms).
      min_on: debounce, steps a run must last to count as an edge (default 1: raw flag).
      truth_known: optional (T, ...) bool, the steps whose truth is known (default
        ``valid``; it must hold every valid step): rule 7b.

    Returns:
      :class:`EventMatch`, pooled over every sequence (every index after the time axis).

    Raises:
      ValueError: naming the argument, for mismatched shapes, probabilities outside [0, 1]
        or NaN at valid steps, or a bad ``dt``, ``threshold``, ``early_window_s``,
        ``min_on`` or ``truth_known``.
    """
    dt, early, min_on = _event_settings(dt, early_window_s, min_on)
    _, flag, tru, val = _inputs(estimate, truth, valid, threshold)
    known = _known(truth_known, truth, val)
    kt = None if known is val else _flat_codes(tru, known)
    return _match_codes(_flat_codes(tru, val), _flat_codes(flag, val), dt, early, min_on, kt)[0]


def _match_codes(
    kg: np.ndarray,
    kf: np.ndarray,
    dt: float,
    early: int,
    min_on: int,
    kt: np.ndarray | None = None,
) -> tuple[EventMatch, np.ndarray]:
    """Rules 2-7b on flat codes (``kt``: the truth over its known steps, None: ``kg``);
    also returns the failures' first steps (flat)."""
    touchdown, failure_starts = _edge_events(kg, kf, early, min_on, dt, kt)
    flipped = None if kt is None else _flip(kt)
    liftoff, _ = _edge_events(_flip(kg), _flip(kf), early, min_on, dt, flipped)
    return EventMatch(touchdown=touchdown, liftoff=liftoff), failure_starts


def _air_phase_failures(
    kg: np.ndarray,
    kf: np.ndarray,
    failure_starts: np.ndarray,
    bounce_steps: int = 0,
    kt: np.ndarray | None = None,
) -> tuple[int, int, int, int, int]:
    """(n_air_phases, air_phases_with_failure, n_swing_phases, swing_phases_with_failure,
    swing_phases_flag_on) of rules 8-9, 9b and 9c, from flat truth codes (``kg`` over the
    valid steps, ``kt`` over the steps of known truth, None: ``kg``) and flag codes ``kf``;
    swing phases are the air phases of more than ``bounce_steps`` steps, and rule 9c's
    those in which the flag is on at every valid step.

    The off-runs of ``kt`` that hold a valid step are the air phases of rule 8: an invalid
    step of known truth does not cut one, a step of unknown truth does.
    """
    kt = kg if kt is None else kt
    ts, te, tv, _, _ = _runs(kt)
    # Runs are disjoint and ordered by start, so the run that holds a failure's first step
    # is the last one starting at or before it; rule 7 puts that step at truth off (and
    # known: it is valid).
    holder = np.searchsorted(ts, failure_starts, side="right") - 1
    hit = np.zeros(ts.shape, bool)
    hit[holder] = True
    valid_before = np.concatenate([[0], np.cumsum(kg != -1)])
    on_before = np.concatenate([[0], np.cumsum(kf == 1)])
    n_valid = valid_before[te] - valid_before[ts]
    air = (tv == 0) & (n_valid > 0)
    swing = air & (te - ts > bounce_steps)
    stuck_on = swing & (on_before[te] - on_before[ts] == n_valid)
    counts = (air, hit & air, swing, hit & swing, stuck_on)
    return tuple(int(np.sum(c)) for c in counts)


# ----------------------------------------------------------------------------- per step


@dataclasses.dataclass(frozen=True)
class StepScores:
    """Per-step classification scores of the flag ``estimate > threshold``, contact positive.

    Attributes:
      accuracy, precision, recall, f1: in [0, 1]; NaN where the ratio is 0 / 0.
      n_steps: number of valid steps.
    """

    accuracy: float
    precision: float
    recall: float
    f1: float
    n_steps: int


def _ratio(num: int, den: int) -> float:
    return float(num) / float(den) if den else float("nan")


def step_scores(estimate, truth, valid=None, *, threshold: float = 0.5) -> StepScores:
    """Accuracy, precision, recall and F1 over the valid steps of all sequences.

    Args and raises: as :func:`match_events`.
    """
    _, flag, tru, val = _inputs(estimate, truth, valid, threshold)
    return _step_scores(flag, tru, val)


def _step_counts(flag, tru, val) -> tuple[int, int, int, int, int]:
    """(valid steps, correct flags, true positives, false positives, false negatives)."""
    f, g = flag[val], tru[val]
    return (
        int(f.size),
        int(np.sum(f == g)),
        int(np.sum(f & g)),
        int(np.sum(f & ~g)),
        int(np.sum(~f & g)),
    )


def _step_scores(flag, tru, val) -> StepScores:
    n, correct, tp, fp, fn = _step_counts(flag, tru, val)
    return StepScores(
        accuracy=_ratio(correct, n),
        precision=_ratio(tp, tp + fp),
        recall=_ratio(tp, tp + fn),
        f1=_ratio(2 * tp, 2 * tp + fp + fn),
        n_steps=n,
    )


def brier_score(estimate, truth, valid=None) -> float:
    """Mean squared error of the probability, ``mean (p - truth)^2`` over valid steps.

    Bool estimates count as probabilities 0 and 1. NaN for no valid step.
    """
    prob, _, tru, val = _inputs(estimate, truth, valid, 0.5)
    return _brier(prob, tru, val)


def _brier(prob, tru, val) -> float:
    if not np.any(val):
        return float("nan")
    return float(np.mean((prob[val] - tru[val]) ** 2))


def expected_calibration_error(estimate, truth, valid=None, *, n_bins: int = 10) -> float:
    """Expected calibration error with ``n_bins`` equal-width bins on [0, 1].

    Bin ``b`` holds ``b / n_bins <= p < (b + 1) / n_bins`` (the last bin also holds 1);
    ``ECE = sum_b (n_b / N) |mean(truth in b) - mean(p in b)|`` over the N valid steps.
    NaN for no valid step.
    """
    n_bins = _check_int("n_bins", n_bins, 1)
    prob, _, tru, val = _inputs(estimate, truth, valid, 0.5)
    return _ece(prob, tru, val, n_bins)


def ece_bins(prob, tru, val, n_bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bins of :func:`expected_calibration_error` (and of a reliability diagram).

    Args:
      prob: (T, ...) float64 P(contact) in [0, 1].
      tru: (T, ...) bool truth.
      val: (T, ...) bool mask of the steps counted.
      n_bins: equal-width bins on [0, 1] (the last also holds 1).

    Returns:
      (count, sum of truth, sum of P) per bin over the valid steps, each (n_bins,).
    """
    p, g = prob[val], tru[val].astype(np.float64)
    # Compared with the edges themselves: int(p * n_bins) rounds a p one ulp below an edge
    # (0.8999999999999999 * 10) into the bin above, and 15/22 * 22 into the bin below.
    idx = np.searchsorted(np.arange(1, n_bins) / n_bins, p, side="right")
    count = np.bincount(idx, minlength=n_bins).astype(np.float64)
    return count, np.bincount(idx, g, n_bins), np.bincount(idx, p, n_bins)


def _ece(prob, tru, val, n_bins: int) -> float:
    n = int(np.sum(val))
    if n == 0:
        return float("nan")
    _, sum_g, sum_p = ece_bins(prob, tru, val, n_bins)
    # sum_b n_b/N |mean_g - mean_p| = sum_b |sum_g - sum_p| / N (an empty bin adds 0).
    return float(np.sum(np.abs(sum_g - sum_p)) / n)


# ----------------------------------------------------------------------------- summary


@dataclasses.dataclass(frozen=True)
class ContactMetrics:
    """All metrics of one estimator on one batch, one row of a results table.

    Rule numbers refer to the module docstring.

    Attributes:
      touchdown_delay_ms, liftoff_delay_ms: (mean, std) over matched events, ms.
      touchdown_delay_persist_ms, liftoff_delay_persist_ms: (mean, std) in ms of the
        delays under the debounce ``min_on = persist_steps`` (rule 11): the first run that
        lasts ``persist_steps`` steps; over the events matched under that debounce.
      touchdown_abs_delay_ms, liftoff_abs_delay_ms: mean of ``|delay|`` over the matched
        events, ms: the signed mean lets early (negative) and late detections cancel
        (rule 4), this one does not.
      n_touchdowns: evaluated true touch-downs (matched + missed + already on).
      missed: missed touch-downs.
      touchdown_already_on: evaluated touch-downs the estimate was on for since before the
        early window (rule 3): no edge to time, neither matched nor missed.
      failures: false contacts in the air (solid runs, unmatched), the paper's "fail"
        (rules 7, 7b).
      chatter: blips in the air shorter than ``min_on`` steps.
      n_air_phases: maximal truth-off runs over the steps of known truth that hold a
        valid step, over all sequences (rule 8; invalid steps of known truth do not cut
        one).
      air_phases_with_failure: air phases in which at least one failure starts (rule 9).
      air_phase_failure_rate: ``air_phases_with_failure / n_air_phases``; NaN for none.
      n_swing_phases, swing_phases_with_failure, swing_phase_failure_rate: the same over
        the air phases longer than ``bounce_s`` (rule 9b): the truth's one-step bounces of a
        resting foot left out, which dilute the rate above.
      swing_phases_flag_on, swing_phase_flag_on_rate: the swing phases with the flag on
        at every valid step, and their share of the swing phases (rule 9c).
      air_false_contact_rate: fraction of the valid truth-off steps with the flag on
        (rule 10); NaN for none.
      n_liftoffs, liftoff_already_off: as above, for lift-offs.
      missed_liftoffs: evaluated true lift-offs, not already off, with no solid fall of
        the flag matched before the next true touch-down inside the valid stretch (rules
        3-5 for the complements).
      false_liftoffs: false air detections during contact; liftoff_chatter their blips.
      accuracy, precision, recall, f1: per-step scores of the flag.
      brier: Brier score; ece: expected calibration error.
      n_steps: valid steps evaluated.
    """

    touchdown_delay_ms: tuple[float, float]
    liftoff_delay_ms: tuple[float, float]
    touchdown_delay_persist_ms: tuple[float, float]
    liftoff_delay_persist_ms: tuple[float, float]
    touchdown_abs_delay_ms: float
    liftoff_abs_delay_ms: float
    n_touchdowns: int
    missed: int
    touchdown_already_on: int
    failures: int
    chatter: int
    n_air_phases: int
    air_phases_with_failure: int
    air_phase_failure_rate: float
    n_swing_phases: int
    swing_phases_with_failure: int
    swing_phase_failure_rate: float
    swing_phases_flag_on: int
    swing_phase_flag_on_rate: float
    air_false_contact_rate: float
    n_liftoffs: int
    missed_liftoffs: int
    liftoff_already_off: int
    false_liftoffs: int
    liftoff_chatter: int
    accuracy: float
    precision: float
    recall: float
    f1: float
    brier: float
    ece: float
    n_steps: int

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


# The longest true air phase that rule 9b takes for a bounce, s: a resting foot's load
# dropping below the threshold for a step or a few under MuJoCo's soft contact (4 steps
# at 400 Hz; on Go1's demo walk 278 of 685 air phases, docs/results.md).
BOUNCE_S = 0.01


def bounce_steps(dt: float, bounce_s: float = BOUNCE_S) -> int:
    """``bounce_s`` in steps of ``dt`` (rounded): rule 9b's longest bounce, the air phases
    :func:`short_air_phases` counts as bounces; a ValueError naming ``bounce_s``."""
    try:
        b = float(bounce_s)
    except (TypeError, ValueError):
        raise ValueError(f"bounce_s must be a number >= 0 (s), got {bounce_s!r}") from None
    if not (np.isfinite(b) and b >= 0):
        raise ValueError(f"bounce_s must be a number >= 0 (s), got {bounce_s!r}")
    return int(round(b / _check_dt(dt)))


def _scoring_inputs(
    estimate, truth, valid, dt, threshold, early_window_s, min_on, n_bins, bounce_s, truth_known
):
    """The checked settings and arrays that :func:`evaluate` and :func:`env_sums` score:
    ``(dt, early window in steps, min_on, n_bins, bounce steps, prob, flag, truth, valid,
    known)``."""
    dt, early, min_on = _event_settings(dt, early_window_s, min_on)
    n_bins = _check_int("n_bins", n_bins, 1)
    n_bounce = bounce_steps(dt, bounce_s)
    prob, flag, tru, val = _inputs(estimate, truth, valid, threshold)
    known = _known(truth_known, truth, val)
    return dt, early, min_on, n_bins, n_bounce, prob, flag, tru, val, known


def evaluate(
    estimate,
    truth,
    valid=None,
    *,
    dt: float,
    threshold: float = 0.5,
    early_window_s: float = 0.05,
    min_on: int = 1,
    n_bins: int = 10,
    persist_steps: int = 3,
    bounce_s: float = BOUNCE_S,
    truth_known=None,
) -> ContactMetrics:
    """Every metric of this module for a batch (T, E, L), events pooled over envs and legs.

    Args and raises: as :func:`match_events` (``truth_known``, rules 7b and 8, included);
    ``n_bins`` as
    :func:`expected_calibration_error`; ``persist_steps`` (an int >= 1, independent of
    ``min_on``) is the debounce of the persistent delays (rule 11); ``bounce_s`` (>= 0, s)
    the longest air phase rule 9b leaves out of the swing phases.
    """
    persist_steps = _check_int("persist_steps", persist_steps, 1)
    dt, early, min_on, n_bins, n_bounce, prob, flag, tru, val, known = _scoring_inputs(
        estimate, truth, valid, dt, threshold, early_window_s, min_on, n_bins, bounce_s,
        truth_known,
    )  # fmt: skip
    kg, kf = _flat_codes(tru, val), _flat_codes(flag, val)
    kt = None if known is val else _flat_codes(tru, known)
    ev, failure_starts = _match_codes(kg, kf, dt, early, min_on, kt)
    # The persistent matching is a second pass of the same rules, skipped when it is the same.
    persist = (
        ev if persist_steps == min_on else _match_codes(kg, kf, dt, early, persist_steps, kt)[0]
    )
    n_air, air_failed, n_swing, swing_failed, swing_on = _air_phase_failures(
        kg, kf, failure_starts, n_bounce, kt
    )
    air_steps = val & ~tru
    steps = _step_scores(flag, tru, val)
    td, lo = ev.touchdown, ev.liftoff
    return ContactMetrics(
        touchdown_delay_ms=td.delay_mean_std_ms,
        liftoff_delay_ms=lo.delay_mean_std_ms,
        touchdown_delay_persist_ms=persist.touchdown.delay_mean_std_ms,
        liftoff_delay_persist_ms=persist.liftoff.delay_mean_std_ms,
        touchdown_abs_delay_ms=td.delay_abs_mean_ms,
        liftoff_abs_delay_ms=lo.delay_abs_mean_ms,
        n_touchdowns=td.n_events,
        missed=td.missed,
        touchdown_already_on=td.already,
        failures=td.false_edges,
        chatter=td.chatter,
        n_air_phases=n_air,
        air_phases_with_failure=air_failed,
        air_phase_failure_rate=_ratio(air_failed, n_air),
        n_swing_phases=n_swing,
        swing_phases_with_failure=swing_failed,
        swing_phase_failure_rate=_ratio(swing_failed, n_swing),
        swing_phases_flag_on=swing_on,
        swing_phase_flag_on_rate=_ratio(swing_on, n_swing),
        air_false_contact_rate=_ratio(int(np.sum(flag & air_steps)), int(np.sum(air_steps))),
        n_liftoffs=lo.n_events,
        missed_liftoffs=lo.missed,
        liftoff_already_off=lo.already,
        false_liftoffs=lo.false_edges,
        liftoff_chatter=lo.chatter,
        accuracy=steps.accuracy,
        precision=steps.precision,
        recall=steps.recall,
        f1=steps.f1,
        brier=_brier(prob, tru, val),
        ece=_ece(prob, tru, val, n_bins),
        n_steps=steps.n_steps,
    )


# ----------------------------------------------------------------------------- per env


@dataclasses.dataclass(frozen=True)
class EnvSums:
    """The additive counts behind the pooled metrics, one row per env (axis 1 of the batch).

    Every metric below is pooled over sequences as a ratio of sums (F1 of step counts, the
    air-phase failure rate of phase counts, a mean delay of delay sums, ECE of per-bin
    sums), so its value over any multiset of envs (an env drawn twice counts twice, as in
    a bootstrap resample) is the same ratio of these rows' weighted sums
    (:meth:`pooled`), equal to :func:`evaluate` on the envs taken that way.

    Attributes (each (E,), or (E, n_bins) for the bins):
      n_steps, correct, tp, fp, fn: valid steps, correct flags, true / false positives,
        false negatives.
      n_air_phases, air_phases_with_failure: rules 8-9.
      n_swing_phases, swing_phases_with_failure: rule 9b.
      swing_phases_flag_on: rule 9c.
      touchdown_delay_sum_ms, n_touchdown_delays: sum and number of the matched, evaluated
        touch-down delays (rules 2-6); liftoff_*: the same for lift-offs.
      bin_truth, bin_prob: per ECE bin, the sums of truth and of P(contact).
    """

    n_steps: np.ndarray
    correct: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    n_air_phases: np.ndarray
    air_phases_with_failure: np.ndarray
    n_swing_phases: np.ndarray
    swing_phases_with_failure: np.ndarray
    swing_phases_flag_on: np.ndarray
    touchdown_delay_sum_ms: np.ndarray
    n_touchdown_delays: np.ndarray
    liftoff_delay_sum_ms: np.ndarray
    n_liftoff_delays: np.ndarray
    bin_truth: np.ndarray
    bin_prob: np.ndarray

    def pooled(self, weights) -> dict[str, np.ndarray]:
        """The pooled metrics of envs counted ``weights`` times.

        Args:
          weights: (..., E) counts (or any non-negative weights) per env.

        Returns:
          ``f1``, ``accuracy``, ``air_phase_failure_rate``, ``swing_phase_failure_rate``,
          ``swing_phase_flag_on_rate``, ``touchdown_delay_ms`` and
          ``liftoff_delay_ms`` (the mean delays), ``ece``: each (...) float64, NaN where
          :func:`evaluate` gives NaN (a ratio 0 / 0).

        Raises:
          ValueError: ``weights`` whose last axis is not the E envs, or a weight that is
            negative or not finite (it gave an F1 above 1 and negative failure rates).
        """
        w = np.asarray(weights, np.float64)
        n_envs = len(self.tp)
        if w.ndim < 1 or w.shape[-1] != n_envs:
            raise ValueError(
                f"weights must have shape (..., {n_envs}) (one per env), got {w.shape}"
            )
        if not np.all(np.isfinite(w) & (w >= 0)):
            raise ValueError("weights must be finite and >= 0 (counts of each env)")
        s = {f.name: w @ getattr(self, f.name) for f in dataclasses.fields(self)}
        gap = np.abs(s["bin_truth"] - s["bin_prob"]).sum(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            return {
                "f1": 2 * s["tp"] / (2 * s["tp"] + s["fp"] + s["fn"]),
                "accuracy": s["correct"] / s["n_steps"],
                "air_phase_failure_rate": s["air_phases_with_failure"] / s["n_air_phases"],
                "swing_phase_failure_rate": s["swing_phases_with_failure"] / s["n_swing_phases"],
                "swing_phase_flag_on_rate": s["swing_phases_flag_on"] / s["n_swing_phases"],
                "touchdown_delay_ms": s["touchdown_delay_sum_ms"] / s["n_touchdown_delays"],
                "liftoff_delay_ms": s["liftoff_delay_sum_ms"] / s["n_liftoff_delays"],
                "ece": gap / s["n_steps"],
            }


def env_sums(
    estimate,
    truth,
    valid=None,
    *,
    dt: float,
    threshold: float = 0.5,
    early_window_s: float = 0.05,
    min_on: int = 1,
    n_bins: int = 10,
    bounce_s: float = BOUNCE_S,
    truth_known=None,
) -> EnvSums:
    """:class:`EnvSums` of a (T, E, ...) batch: each env's sequences scored by the rules of
    :func:`evaluate` (same arguments), pooled over its trailing axes (legs).

    Raises:
      ValueError: as :func:`evaluate`, or for a batch without an env axis.
    """
    dt, early, min_on, n_bins, n_bounce, prob, flag, tru, val, known = _scoring_inputs(
        estimate, truth, valid, dt, threshold, early_window_s, min_on, n_bins, bounce_s,
        truth_known,
    )  # fmt: skip
    if prob.ndim < 2 or prob.shape[1] < 1:
        raise ValueError(f"estimate must have shape (T, E, ...) with E >= 1, got {prob.shape}")
    rows = []
    for e in range(prob.shape[1]):
        p, f, g, v, k = (x[:, e] for x in (prob, flag, tru, val, known))
        kg, kf = _flat_codes(g, v), _flat_codes(f, v)
        kt = None if known is val else _flat_codes(g, k)
        ev, failure_starts = _match_codes(kg, kf, dt, early, min_on, kt)
        phases = _air_phase_failures(kg, kf, failure_starts, n_bounce, kt)
        rows.append(
            (
                *_step_counts(f, g, v),
                *phases,
                np.sum(ev.touchdown.delays_ms), ev.touchdown.delays_ms.size,
                np.sum(ev.liftoff.delays_ms), ev.liftoff.delays_ms.size,
                *ece_bins(p, g, v, n_bins)[1:],
            )
        )  # fmt: skip
    cols = list(zip(*rows, strict=True))
    return EnvSums(*(np.asarray(c, np.float64) for c in cols))
