"""A log's tuning data and its true events: air phases, touch-downs, lift-offs; the
air-phase event term of the loss."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jax_contact.types import LegMeasurement, RobotMeasurement

# ---------------------------------------------------------------------------- the data


@struct.dataclass
class AirPhases:
    """Where the true air phases and touch-downs of a log are (from its truth, mask and
    known truth alone, :func:`air_phases`; "known air": a step of known truth in the air).

    Attributes:
      start: (T, E, L) bool, the first valid step of each true air phase, a run of known
        air (``jax_contact.metrics`` rule 8; without known truth, a valid air step whose
        previous step is not one).
      td_step: (T, E, L) bool, each true touch-down (a valid contact step after a step of
        known air; rule 2's ``t0``).
      td_window: (T, E, L) bool, the known-air steps at most ``early`` steps before the
        touch-down that ends their phase (rule 2's early window).
      lo_step: (T, E, L) bool, each true lift-off (a valid air step after a step of known
        contact).
      after_td: (T, E, L) bool, the first ``early`` valid contact steps of each stance
        that begins with a touch-down (:func:`cell_surrogates`' touch-down lateness).
      after_lo: (T, E, L) bool, the first ``early`` valid air steps of each air phase that
        begins with a lift-off.
    """

    start: jax.Array
    td_step: jax.Array
    td_window: jax.Array
    lo_step: jax.Array | None = None
    after_td: jax.Array | None = None
    after_lo: jax.Array | None = None


@struct.dataclass
class TuningData:
    """One log's precomputed estimator inputs and ground truth (NumPy or JAX leaves).

    Attributes:
      meas: a :class:`RobotMeasurement` with leaves of leading axes (T, E) (or a
        :class:`LegMeasurement` with (T, E, L)): the inputs of each step, paired as the
        estimator would see them.
      truth: (T, E, L) bool ground-truth contact at each step.
      mask: (T, E, L) bool, the steps that count (env valid).
      events: the log's :class:`AirPhases` (:func:`with_air_phases`), needed by the event
        term; None until annotated.
      known: (T, E, L) bool, the steps whose truth is known (None: ``mask``), a superset
        of ``mask``: the validation cells' air phases and the loss's event term
        (:func:`air_phases`) follow ``jax_contact.metrics`` rules 7b and 8 with it (a
        recording's lost reading inside a swing does not split its phase, as in
        ``jax-contact estimate``).
    """

    meas: RobotMeasurement | LegMeasurement
    truth: jax.Array
    mask: jax.Array
    events: AirPhases | None = None
    known: jax.Array | None = None

    @property
    def n_steps(self) -> int:
        return int(self.truth.shape[0])


def _check_shapes(d: TuningData, where: str) -> None:
    """``truth``, ``mask`` (and ``known``) of one (T, E, L) shape, and ``meas`` of the same
    steps and envs (``qdd`` (T, E, nv) of a RobotMeasurement, (T, E, L, nv) of a
    LegMeasurement): a log's (T, E) valid mask, or inputs one step short of the truth
    (easy with the delayed pairing), failed deep inside NumPy or the windows."""
    if not isinstance(d, TuningData):
        raise ValueError(f"{where} must be a TuningData, got {type(d).__name__}")
    truth = np.shape(d.truth)
    if len(truth) != 3:
        raise ValueError(f"{where}: truth has shape {truth}; expected (T, E, L)")
    for field in ("mask", "known"):
        value = getattr(d, field)
        if value is not None and np.shape(value) != truth:
            raise ValueError(
                f"{where}: {field} has shape {np.shape(value)}; expected truth's {truth}"
            )
    qdd = np.shape(d.meas.qdd)
    want = truth[:2] if isinstance(d.meas, RobotMeasurement) else truth
    if qdd[: len(want)] != want:
        raise ValueError(
            f"{where}: meas.qdd has shape {qdd}; its leading axes must be truth's {want}"
            " (one input per step, env and foot)"
        )


def check_scored_steps(logs: Sequence[TuningData], what: str, names=None) -> None:
    """Refuses logs the loss cannot learn from, before anything is fitted.

    Every log needs steps that count (``mask`` true somewhere), and the logs together need
    both contact and air among them: on one class alone the BCE is minimised by calling
    everything that class, and F1, ECE and a calibration map are undefined.

    Args:
      logs: the tuning (or validation) logs.
      what: what they are, for the message (``"tuning log"``, ``"validation log"``).
      names: each log's name for the message (e.g. its path); None: its 1-based index.

    Raises:
      ValueError: naming the log whose arrays do not fit each other, the log without a
        counted step, or the class the logs lack.
    """
    names = [f"{i + 1} of {len(logs)}" for i in range(len(logs))] if names is None else names
    n_contact = n_air = 0
    for d, name in zip(logs, names, strict=True):
        _check_shapes(d, f"{what} {name}")
        mask, truth = np.asarray(d.mask, bool), np.asarray(d.truth, bool)  # one shape
        if not mask.any():
            raise ValueError(
                f"{what} {name} has no step that counts (valid and read: its valid mask, or"
                " the finiteness of the readings each foot reads, is false everywhere: a"
                " robot that fell at once, readings that are all NaN, or a log no longer"
                " than the skipped start)"
            )
        n_contact += int(np.sum(truth & mask))
        n_air += int(np.sum(~truth & mask))
    if logs and (n_contact == 0 or n_air == 0):
        lack = "contact" if n_contact == 0 else "air"
        raise ValueError(
            f"the {what}s have no {lack} step among their {n_contact + n_air} counted steps:"
            " tuning needs both classes"
        )


def _shifted(x: np.ndarray) -> np.ndarray:
    """``x`` one step later along time (False first)."""
    return np.concatenate([np.zeros_like(x[:1]), x[:-1]], axis=0)


def air_phases(truth, mask, early: int, known=None) -> AirPhases:
    """The :class:`AirPhases` of a (T, ...) truth and mask (NumPy, whole log at once).

    With ``known`` (the steps whose truth is known, a superset of ``mask``: a recording's
    lost readings), the phases are the runs of known air (``jax_contact.metrics`` rules 7b
    and 8, as the validation cells count them): a lost step inside a swing does not split
    its phase, a phase starts at its first valid step, and a touch-down or lift-off is
    found across a lost step before it. Without it (None: ``mask``) every invalid step
    ends a phase.

    Args:
      truth, mask: (T, ...) bool.
      early: the early window in steps (``round(early_window_s / dt)``).
      known: None, or (T, ...) bool.
    """
    truth = np.asarray(truth, bool)
    mask = np.asarray(mask, bool)
    known = mask if known is None else np.asarray(known, bool) | mask
    air, kair = mask & ~truth, known & ~truth
    contact, kcontact = mask & truth, known & truth
    # Each run of known air starts its phase at its first valid step.
    run_start = kair & ~_shifted(kair)
    start = np.zeros_like(air)
    seen = np.zeros(air.shape[1:], bool)
    for t in range(air.shape[0]):
        seen = np.where(run_start[t] | ~kair[t], False, seen)
        start[t] = air[t] & ~seen
        seen = seen | air[t]
    td_step = contact & _shifted(kair)
    # Steps from each air step to the touch-down that ends its phase (a large number where
    # the phase ends otherwise: a step of unknown truth or the end of the log).
    far = np.iinfo(np.int32).max // 2
    dist = np.full(air.shape, far, np.int64)
    cur = np.full(air.shape[1:], far, np.int64)
    for t in range(air.shape[0] - 1, -1, -1):
        cur = np.where(td_step[t], 0, np.where(kair[t], cur + 1, far))
        dist[t] = cur
    lo_step = air & _shifted(kcontact)

    def first_steps(inside, begins):
        # Steps since the event that began each run of ``inside`` (far where none did).
        since = np.full(inside.shape, far, np.int64)
        cur = np.full(inside.shape[1:], far, np.int64)
        for t in range(inside.shape[0]):
            cur = np.where(begins[t], 0, np.where(inside[t], cur + 1, far))
            since[t] = cur
        return inside & (since < early)

    return AirPhases(
        start=start,
        td_step=td_step,
        # Lost steps of the approach included, so the run into a touch-down continues
        # across them (scored_air_steps scores valid steps only).
        td_window=kair & (dist <= early),
        lo_step=lo_step,
        after_td=first_steps(kcontact, td_step) & mask,
        after_lo=first_steps(kair, lo_step) & mask,
    )


def with_air_phases(data: TuningData, early: int) -> TuningData:
    """``data`` with its :class:`AirPhases` (``early`` steps of early window; the phases of
    its known truth, :func:`air_phases`)."""
    return data.replace(events=air_phases(data.truth, data.mask, early, data.known))


def scored_air_steps(logits: jax.Array, window: TuningData) -> jax.Array:
    """(T, E, L) bool: the true air steps where a rise of the logit could be a failure.

    The steps of a true air phase between the end of the lift-off's fall and the start of
    the touch-down's rise (computed from the logits without gradient; a window's first
    step starts its phases afresh):

    - from the first step, after the flag ``logit > 0`` has been off in the phase, at which
      the logit does not fall (``l_t >= l_{t-1}``): the stance's flag carried into the air
      and the fall after it are the lift-off delay, not a false contact
      (``jax_contact.metrics`` rule 7 needs a rise of the flag in the air);
    - minus the run into the touch-down: going back from the true touch-down ``t0`` over
      the early window (``AirPhases.td_window``), a flagged step followed by a flagged
      step, or an unflagged one at or below the next logit (the rise toward the detection);
      the detection itself (rule 4) and the approach to it are not false contacts. A
      blip (on, then off) before the detection breaks the run and is scored.
    """
    lg = jax.lax.stop_gradient(logits)
    on = lg > 0
    truth = jnp.asarray(window.truth).astype(bool)
    air = jnp.asarray(window.mask) & ~truth
    # The phase's state carries across its lost steps (steps of known truth not scored).
    kair = air if window.known is None else (jnp.asarray(window.known) | air) & ~truth
    ev = jax.tree.map(jnp.asarray, window.events)
    prev = jnp.concatenate([lg[:1], lg[:-1]], axis=0)
    nxt = jnp.concatenate([lg[1:], lg[-1:]], axis=0)
    on_next = jnp.concatenate([on[1:], on[-1:]], axis=0)

    def fwd(carry, x):
        dropped, settled = carry
        a, st, o, rising = x
        dropped = a & ((~st & dropped) | ~o)
        settled = dropped & ((~st & settled) | rising)
        return (dropped, settled), settled

    zeros = jnp.zeros(on.shape[1:], bool)
    _, settled = jax.lax.scan(fwd, (zeros, zeros), (kair, ev.start, on, lg >= prev))

    def bwd(run, x):
        td, win, into = x
        run = td | (win & run & into)
        return run, run

    into = jnp.where(on, on_next, lg <= nxt)
    # The window's last step: a run there is taken to go on into the next window.
    _, run = jax.lax.scan(
        bwd, jnp.ones(on.shape[1:], bool), (ev.td_step, ev.td_window, into), reverse=True
    )
    return air & settled & ~run


def air_event_terms(logits: jax.Array, window: TuningData, temperature: float):
    """The event term's sum over the window's air phases and their number.

    For each true air phase ``a`` (:class:`AirPhases`; a phase cut by the window's start
    counts from there) with scored steps ``S_a`` (:func:`scored_air_steps`)::

        E_a = tau log sum_{t in S_a} exp(l_t / tau)      (smooth maximum of the logit)
        cost_a = softplus(E_a) = -log(1 - sigmoid(E_a))

    ``sigmoid(E_a)`` stands for the probability of at least one false contact in the phase
    (``E_a`` lies between the largest logit and ``tau log |S_a|`` above it), so ``cost_a``
    is the binary cross-entropy of the event "no false contact in this phase" (true for
    every true air phase). Phases without a scored step cost 0.

    Returns:
      (sum of ``cost_a`` (), number of air phases in the window ()).
    """
    e, has, n_phases = air_phase_maxima(logits, window, temperature)
    return jnp.sum(jnp.where(has, jax.nn.softplus(e), 0.0)), n_phases


def air_phase_maxima(logits: jax.Array, window: TuningData, temperature: float):
    """The smooth maximum ``E_a`` of the logit over each air phase's scored steps.

    Returns:
      (``E`` (S,) per segment, ``has`` (S,) bool: the segment is a phase with a scored
      step (``E`` is 0 elsewhere), the number of air phases in the window ()); segments
      are (column, phase) pairs, so ``S`` is fixed by the window's shape.
    """
    n_t = logits.shape[0]
    cols = int(np.prod(logits.shape[1:]))
    scored = scored_air_steps(logits, window)
    air = jnp.asarray(window.mask) & ~jnp.asarray(window.truth).astype(bool)
    # A phase cut by the window's start begins at its first step.
    first = (jnp.asarray(window.events.start) & air).at[0].set(air[0])
    pid = jnp.cumsum(first, axis=0)  # phase number along each column, >= 1 inside phases
    col = jnp.arange(cols).reshape(logits.shape[1:])
    n_seg = cols * (n_t + 1) + 1
    seg = jnp.where(scored, col * (n_t + 1) + pid, n_seg - 1).reshape(-1)
    x = (logits / temperature).reshape(-1)
    sc = scored.reshape(-1)
    mx = jax.ops.segment_max(jnp.where(sc, jax.lax.stop_gradient(x), -jnp.inf), seg, n_seg)
    has = jax.ops.segment_sum(sc.astype(jnp.int32), seg, n_seg) > 0
    mx = jnp.where(has, mx, 0.0)
    z = jnp.where(sc, x - mx[seg], -60.0)
    total = jax.ops.segment_sum(jnp.where(sc, jnp.exp(z), 0.0), seg, n_seg)
    e = temperature * (mx + jnp.log(jnp.where(has, total, 1.0)))
    return jnp.where(has, e, 0.0), has, jnp.sum(first)
