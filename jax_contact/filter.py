"""The forward recursion (eq. 1-2) in log space, and its batched and scanned entry points.

One step for one foot::

    prior_t(x)  = sum_x' T_{t-1}(x | x') b_{t-1}(x')              (eq. 1, the sum)
    b_t(C)      ∝ L_dyn L_dkin L_kin (C) * prior_t(C)              (eq. 1, 3)
    b_t         = alpha_t / sum alpha_t                            (eq. 2)
    T_t         from this step's measurement (eq. 11-17)           (applied at t+1)

The belief is carried as a logit, so a million steps neither underflow nor round it to
exactly 0 or 1. ``step`` is pure and unbatched; ``step_robot`` runs it for every foot of
one robot from a per-robot measurement; ``step_batch`` vmaps either over the envs (and
legs) and ``run`` scans ``step_batch`` over time.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact._math import logit as logit_of
from jax_contact.measurement import (
    end_of_interval,
    leg_blocks,
    measurement_terms,
    robot_leg_blocks,
)
from jax_contact.params import TERMS, EstimatorParams, Switches, switches_of, validate_params
from jax_contact.terrain import validate_terrain
from jax_contact.transition import log_prior_transition, log_transition_matrix
from jax_contact.types import (
    Diagnostics,
    LegBelief,
    LegBlocks,
    LegMeasurement,
    RobotMeasurement,
    blocks_are_finite,
    validate_measurement,
    validate_robot_measurement,
)


def init_belief(params: EstimatorParams) -> LegBelief:
    """The belief of one foot before its first measurement.

    ``P(C) = params.initial_contact``, the gait prior as the first transition, no foothold.

    Raises:
      ValueError: ``params`` that are not valid :class:`EstimatorParams` (checked when
        concrete): a prior of 0 or 1 made the belief's logit infinite, a NaN one NaN.
    """
    _check_params("init_belief", params)
    p = params.initial_contact
    return LegBelief(
        logit=jnp.log(p) - jnp.log1p(-p),
        log_transition=log_prior_transition(params),
        # The parameters' float type, so a float64 filter keeps a float64 scan carry.
        foothold=jnp.zeros(3, jnp.result_type(params.dt)),
        foothold_valid=jnp.array(False),
    )


def init_belief_batch(params: EstimatorParams, n_envs: int, n_legs: int) -> LegBelief:
    """:func:`init_belief` broadcast to leading axes (n_envs, n_legs).

    Raises:
      ValueError: ``n_envs`` or ``n_legs`` is not a positive int.
    """
    for name, n in (("n_envs", n_envs), ("n_legs", n_legs)):
        if isinstance(n, bool | np.bool_) or not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"{name} must be a positive int, got {n!r}")
    one = init_belief(params)
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (n_envs, n_legs) + x.shape), one)


@jax.named_call
def _sanitize(leg: LegBlocks, valid: jax.Array) -> LegBlocks:
    """Replaces an invalid measurement by a benign one so no NaN enters any computation.

    ``jnp.where`` alone would still propagate NaN into gradients, so the inputs themselves
    are swapped: zeros everywhere and an identity mass matrix (its leg block; the
    coupling block of an identity is zero). The noise model's fields are kept.
    """
    measured = {
        name: jnp.where(valid, x, jnp.zeros_like(x))
        for name, x in vars(leg).items()
        if name not in LegBlocks.NOISE_FIELDS
    }
    measured["M_l"] = jnp.where(valid, leg.M_l, jnp.eye(leg.M_l.shape[0], dtype=leg.M_l.dtype))
    return leg.replace(**measured)


def step(
    params: EstimatorParams,
    terrain,
    belief: LegBelief,
    meas: LegMeasurement,
    *,
    key: jax.Array,
) -> tuple[LegBelief, Diagnostics]:
    """One update of one foot's contact belief.

    Args:
      params: estimator parameters (shared by every foot).
      terrain: a terrain model from ``jax_contact.terrain`` (e.g. ``flat()``).
      belief: this foot's belief after the previous step.
      meas: this foot's measurement at this step.
      key: PRNG key for the Monte-Carlo touch-down transition (unused by quadrature).

    Returns:
      (new belief, this step's diagnostics). If a reading this foot's terms read holds a
      NaN or inf (:func:`jax_contact.types.blocks_are_finite`: not ``q``, nor another
      leg's joints), the belief is the transition-only prediction, the next transition
      is the gait prior, the foothold is kept, and ``diagnostics.valid`` is False. A
      belief that is already NaN (set by hand) stays NaN, and every step of it reports
      ``valid`` False.

    Raises:
      ValueError: naming the argument: ``params`` out of range (checked when they are
        concrete, not traced), a measurement or belief of the wrong shape or type, a
        ``key`` that is not a PRNG key.
    """
    if isinstance(meas, RobotMeasurement):
        raise ValueError(
            "step: meas is a RobotMeasurement (every foot of a robot); step takes one foot's"
            " LegMeasurement: use step_robot (one robot) or step_batch (a batch)"
        )
    _check_shapes("step", params, belief, meas, ())
    _check_call("step", params, terrain, key)
    return _step(params, terrain, belief, _as_jax(meas), key)


def _check_params(fn: str, params) -> None:
    """``params`` are EstimatorParams in range (:func:`jax_contact.params.validate_params`,
    when concrete: parameters traced by ``jit``, ``vmap`` or ``grad`` are not read)."""
    if not isinstance(params, EstimatorParams):
        raise ValueError(
            f"{fn}: params must be EstimatorParams (jax_contact.params_for, load_params), got"
            f" {type(params).__name__}"
        )
    if not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(params)):
        try:
            validate_params(params)
        except ValueError as err:
            raise ValueError(f"{fn}: params: {err}") from None


def _check_call(fn: str, params, terrain, key) -> None:
    """Trace-time checks of the arguments besides the measurement: ``params`` in range
    (:func:`jax_contact.params.validate_params`, when they are concrete: parameters
    traced by ``jit``, ``vmap`` or ``grad`` are not read), a terrain model and a PRNG
    key. Raises ValueError naming the argument."""
    _check_params(fn, params)
    if not callable(getattr(terrain, "query", None)):
        raise ValueError(
            f"{fn}: terrain must be a terrain model of jax_contact.terrain (e.g. flat()), got"
            f" {type(terrain).__name__}"
        )
    try:
        validate_terrain(terrain)
    except ValueError as err:
        raise ValueError(f"{fn}: terrain: {err}") from None
    dtype = getattr(key, "dtype", None)
    if dtype is None or not (
        jnp.issubdtype(dtype, jax.dtypes.prng_key) or (dtype == jnp.uint32 and np.ndim(key) >= 1)
    ):
        raise ValueError(
            f"{fn}: key must be a PRNG key, e.g. jax.random.key(0) (every step takes one; the"
            f" quadrature touch-down of params_for draws nothing from it), got {type(key).__name__}"
            + ("" if dtype is None else f" of dtype {dtype}")
        )
    typed = jnp.issubdtype(dtype, jax.dtypes.prng_key)
    if np.ndim(key) != (0 if typed else 1):
        raise ValueError(
            f"{fn}: key must be one PRNG key (shape {'()' if typed else '(2,), raw'}), got an"
            f" array of keys of shape {np.shape(key)}: pass one key, which {fn} splits over"
            " the steps, envs and feet it runs (or jax.vmap an unbatched step)"
        )


def _check_shapes(
    fn: str,
    params,
    belief,
    meas,
    batch: tuple[int, ...],
    time: tuple[int, ...] = (),
    arg: str = "meas",
) -> None:
    """Trace-time check (static shapes only, no cost in the compiled program) that
    ``meas`` and ``belief`` fit ``params`` and each other: ``batch`` is the leading shape
    ``meas``'s per-robot (or per-foot) fields must have after the sequence's ``time``
    axis, if any. Raises ValueError naming the argument, the field and both shapes."""
    robot = isinstance(meas, RobotMeasurement)
    if not robot and not isinstance(meas, LegMeasurement):
        raise ValueError(
            f"{fn}: {arg} must be a LegMeasurement or RobotMeasurement, got {type(meas).__name__}"
        )
    if not isinstance(params, EstimatorParams):  # before params.nv is read
        _check_params(fn, params)
    if not isinstance(belief, LegBelief):
        raise ValueError(
            f"{fn}: belief must be a LegBelief (init_belief, init_belief_batch), got"
            f" {type(belief).__name__}"
        )
    want = time + batch + (params.nv,)
    if tuple(np.shape(meas.qdd)) != want:
        if time:
            what = f"the time axis T = {time[0]}, then the belief's batch {batch}"
        else:
            what = "the leading axes of the batch" if batch else "unbatched"
        raise ValueError(
            f"{fn}: {arg}.qdd has shape {tuple(np.shape(meas.qdd))}; expected {want} ({what},"
            f" then params' nv = {params.nv}): parameters of another robot, or a measurement"
            " batched differently" + (" (time first: (T, n_envs, ...))" if time else "")
        )
    legs = (meas.n_legs,) if robot else ()
    if tuple(np.shape(belief.logit)) != batch + legs:
        raise ValueError(
            f"{fn}: belief has shape {tuple(np.shape(belief.logit))} (its logit); the"
            f" measurement needs {batch + legs}"
        )
    for field, tail in (("log_transition", (2, 2)), ("foothold", (3,)), ("foothold_valid", ())):
        got = tuple(np.shape(getattr(belief, field)))
        if got != batch + legs + tail:
            raise ValueError(
                f"{fn}: belief.{field} has shape {got}; expected {batch + legs + tail} (the"
                f" logit's {batch + legs}, then {tail}): a belief of init_belief"
            )
    # Every other field (M, J, qd, ... and the legs' indices where they are known), named.
    try:
        if robot:
            validate_robot_measurement(meas, params.nv)
        else:
            validate_measurement(meas, params.nv)
    except ValueError as err:
        raise ValueError(f"{fn}: {err}") from None


def _as_jax(meas):
    """The measurement's arrays as JAX arrays (NumPy float64 readings outside ``jit`` gave
    a JAX dtype warning from inside the update; inside ``jit`` they already are)."""
    return jax.tree.map(jnp.asarray, meas)


def _batch_of(fn: str, belief: LegBelief) -> tuple[int, int]:
    """(n_envs, n_legs) of a batch of beliefs, or a ValueError naming ``fn``."""
    if np.ndim(belief.logit) != 2:
        raise ValueError(
            f"{fn}: belief has shape {tuple(np.shape(belief.logit))} (its logit); expected"
            " (n_envs, n_legs): init_belief_batch"
        )
    return tuple(np.shape(belief.logit))


def _check_sequence(fn: str, params, belief, meas_seq, n_steps: int | None = None) -> None:
    """:func:`_check_shapes` of a time series (leading axis T, ``n_steps`` if given) for a
    batch of beliefs (n_envs, n_legs), before ``lax.scan`` reads it."""
    n_envs, n_legs = _batch_of(fn, belief)
    robot = isinstance(meas_seq, RobotMeasurement)
    shape = np.shape(getattr(meas_seq, "qd", ()))
    if isinstance(meas_seq, LegMeasurement | RobotMeasurement) and len(shape) < 2:
        raise ValueError(
            f"{fn}: meas_seq.qd has shape {shape}; expected (T, n_envs, ..., nv): a time axis"
            " first, then the batch"
        )
    time = (shape[0] if n_steps is None else n_steps,) if shape else ()
    # _check_shapes names a meas_seq of another type, and every field's shape.
    batch = (n_envs,) if robot else (n_envs, n_legs)
    _check_shapes(fn, params, belief, meas_seq, batch, time, arg="meas_seq")


def _step(params, terrain, belief, meas, key, switches=None):
    """:func:`step`, with the switches of :func:`_update`."""
    leg = leg_blocks(params, meas)
    return _update(params, terrain, belief, leg, blocks_are_finite(leg), key, switches)


def _update(
    params: EstimatorParams,
    terrain,
    belief: LegBelief,
    leg: LegBlocks,
    valid: jax.Array,
    key: jax.Array,
    switches: Switches | None = None,
) -> tuple[LegBelief, Diagnostics]:
    """:func:`step` from the foot's split measurement and whether all of it was finite.

    ``switches`` (None: :func:`jax_contact.params.switches_of` ``params``, constants) turn
    the terms, the measured transitions, the one-sided kinematics term and the still
    foothold on or off.
    """
    sw = switches_of(params) if switches is None else switches
    leg = _sanitize(leg, valid)
    # The kinematic terms, the transitions and the foothold read the newest state.
    kin = end_of_interval(params, leg)
    tq = terrain.query(kin.p_f, belief.foothold, belief.foothold_valid)

    # eq. 1, the sum over the previous state, in log space.
    log_b_prev = jnp.stack([jax.nn.log_sigmoid(belief.logit), jax.nn.log_sigmoid(-belief.logit)])
    log_prior = jax.nn.logsumexp(belief.log_transition + log_b_prev[:, None], axis=0)
    prior_logit = log_prior[0] - log_prior[1]

    # eq. 3: the product of the terms is the sum of their log-likelihood ratios; eq. 2's
    # normalisation over the two states is the logit itself (below).
    terms = measurement_terms(params, leg, tq, kin, sw.kinematics_neutral_below)
    llr = sum(jnp.where(sw.terms[i], getattr(terms, name), 0.0) for i, name in enumerate(TERMS))
    # A term that is not finite on finite inputs (a numerical failure, e.g. a singular
    # leg) is no evidence: the belief keeps its prior and the step is reported invalid,
    # instead of a NaN that every later step of this foot would inherit.
    # A NaN belief (set by hand) cannot be updated: reported, not hidden.
    valid = valid & jnp.isfinite(llr) & ~jnp.isnan(belief.logit)
    logit = jnp.where(valid, prior_logit + llr, prior_logit)

    # Without the transition model (an ablation) the gait prior alone.
    log_t_meas = log_transition_matrix(params, kin, tq, key=key)
    use_meas = sw.transition_model & valid & jnp.all(~jnp.isnan(log_t_meas))
    log_t = jnp.where(use_meas, log_t_meas, log_prior_transition(params))

    # The foothold memory stores only confident, still stance: a false contact in the air
    # would otherwise write the swing height as terrain.
    on_ground = valid & (logit > logit_of(params.foothold_confidence))
    on_ground = on_ground & (~sw.foothold_still | (terms.diff_kinematics > 0.0))
    sole = kin.p_f - kin.foot_radius * tq.normal
    new_belief = LegBelief(
        logit=logit,
        log_transition=log_t,
        foothold=jnp.where(
            on_ground,
            terrain.remember(belief.foothold, belief.foothold_valid, sole),
            belief.foothold,
        ),
        foothold_valid=belief.foothold_valid | on_ground,
    )
    nan = jnp.float32(jnp.nan)
    diag = Diagnostics(
        p_contact=jax.nn.sigmoid(logit),
        p_dynamics=jnp.where(valid, jax.nn.sigmoid(terms.dynamics), nan),
        p_diff_kinematics=jnp.where(valid, jax.nn.sigmoid(terms.diff_kinematics), nan),
        p_kinematics=jnp.where(valid, jax.nn.sigmoid(terms.kinematics), nan),
        p_takeoff=jnp.exp(log_t[0, 1]),
        p_touchdown=jnp.exp(log_t[1, 0]),
        force=jnp.where(valid, terms.force, jnp.full(3, nan)),
        valid=valid,
    )
    # Every entry point returns the belief in the type it was given: float32 parameters
    # fed float64 readings under ``jax_enable_x64`` compute in float64, and a loop that
    # fed the result back would trace a second program (a scan's carry must not change).
    return _like(new_belief, belief), diag


def _like(new: LegBelief, old: LegBelief) -> LegBelief:
    """``new`` in ``old``'s dtypes."""
    return jax.tree.map(lambda n, o: n.astype(o.dtype), new, old)


def _step_legs(params, terrain, belief, meas: RobotMeasurement, keys, switches=None):
    """:func:`step` of each foot of one robot: the legs' blocks sliced with constant
    indices, then one program vmapped over the legs."""

    def one(b, leg, valid, k):
        return _update(params, terrain, b, leg, valid, k, switches)

    legs = robot_leg_blocks(params, meas)
    return jax.vmap(one)(belief, legs, jax.vmap(blocks_are_finite)(legs), keys)


def step_robot(
    params: EstimatorParams,
    terrain,
    belief: LegBelief,
    meas: RobotMeasurement,
    *,
    key: jax.Array,
) -> tuple[LegBelief, Diagnostics]:
    """:func:`step` for every foot of one robot, from its per-robot measurement.

    Args:
      belief: the robot's feet's beliefs, leaves with leading axis (n_legs,).
      meas: the robot's measurement (unbatched).
      key: PRNG key, split into one per foot.

    Returns:
      (new beliefs, diagnostics), leaves with leading axis (n_legs,); the same as
      :func:`step` of each foot on ``meas.leg(i)`` with the i-th of
      ``jax.random.split(key, n_legs)``.
    """
    if not isinstance(meas, RobotMeasurement):
        raise ValueError(
            f"step_robot: meas must be a RobotMeasurement, got {type(meas).__name__} (one"
            " foot's LegMeasurement goes to step)"
        )
    _check_shapes("step_robot", params, belief, meas, ())
    _check_call("step_robot", params, terrain, key)
    keys = jax.random.split(key, meas.n_legs)
    return _step_legs(params, terrain, belief, _as_jax(meas), keys)


def step_batch(
    params: EstimatorParams,
    terrain,
    belief: LegBelief,
    meas: LegMeasurement | RobotMeasurement,
    *,
    key: jax.Array,
    switches: Switches | None = None,
) -> tuple[LegBelief, Diagnostics]:
    """:func:`step` over a batch of (n_envs, n_legs) feet sharing params and terrain.

    Every leaf of ``belief`` has leading axes (n_envs, n_legs); so do the outputs. ``meas``
    is either per foot (a :class:`LegMeasurement`, leaves with leading axes (n_envs,
    n_legs)) or per robot (a :class:`RobotMeasurement`, leaves with leading axis
    (n_envs,)); both give the same result, the second reads less. Each foot gets its own
    key, split from ``key``. ``switches`` (a :class:`jax_contact.params.Switches`, for
    ``params`` of :func:`jax_contact.params.without_switches`) gives the four static
    switches as data, so variants differing only in them ``vmap`` as one program; None
    reads them from ``params``.
    """
    n_envs, n_legs = _batch_of("step_batch", belief)
    batch = (n_envs,) if isinstance(meas, RobotMeasurement) else (n_envs, n_legs)
    _check_shapes("step_batch", params, belief, meas, batch)
    _check_call("step_batch", params, terrain, key)
    keys = jax.random.split(key, n_envs * n_legs)
    keys = keys.reshape((n_envs, n_legs) + keys.shape[1:])
    meas = _as_jax(meas)

    if isinstance(meas, RobotMeasurement):
        return jax.vmap(lambda b, m, k: _step_legs(params, terrain, b, m, k, switches))(
            belief, meas, keys
        )

    def one(b, m, k):
        return _step(params, terrain, b, m, k, switches)

    return jax.vmap(jax.vmap(one))(belief, meas, keys)


def run(
    params: EstimatorParams,
    terrain,
    belief: LegBelief,
    meas_seq: LegMeasurement | RobotMeasurement,
    *,
    key: jax.Array,
) -> tuple[LegBelief, Diagnostics]:
    """Runs :func:`step_batch` over a time series with ``lax.scan``.

    Args:
      belief: initial belief, leaves with leading axes (n_envs, n_legs).
      meas_seq: measurements, leaves with leading axes (T, n_envs, n_legs), or a
        :class:`RobotMeasurement` with leading axes (T, n_envs).
      key: PRNG key, split once per step.

    Returns:
      (final belief, diagnostics with leading axes (T, n_envs, n_legs)).

    Raises:
      ValueError: as :func:`step`, naming ``meas_seq``'s field whose leading axes are not
        (T, n_envs[, n_legs]) with ``belief``'s (n_envs, n_legs).
    """
    _check_sequence("run", params, belief, meas_seq)
    _check_call("run", params, terrain, key)

    def body(carry, meas):
        b, k = carry
        k, sub = jax.random.split(k)
        new, diag = step_batch(params, terrain, b, meas, key=sub)
        return (new, k), diag

    (belief, _), diags = jax.lax.scan(body, (belief, key), meas_seq)
    return belief, diags


def sequence_bce(
    params: EstimatorParams,
    terrain,
    meas_seq: LegMeasurement | RobotMeasurement,
    truth: jax.Array,
    *,
    key: jax.Array,
) -> jax.Array:
    """Mean binary cross-entropy of the filtered belief against ground-truth contact.

    Differentiable with respect to ``params`` (the noise model included), for tuning.

    Args:
      meas_seq: leaves with leading axes (T, n_envs, n_legs), or a
        :class:`RobotMeasurement` with leading axes (T, n_envs).
      truth: (T, n_envs, n_legs) bool or {0, 1} ground-truth contact.

    Returns:
      () mean over time, envs and legs, in nats.

    Raises:
      ValueError: as :func:`run`; ``truth`` not of shape (T, n_envs, n_legs) with
        ``meas_seq``'s T, or (when concrete) holding values other than 0 and 1.
    """
    shape = tuple(np.shape(truth))
    if len(shape) != 3 or min(shape, default=0) < 1:
        raise ValueError(
            f"sequence_bce: truth has shape {shape}; expected (T, n_envs, n_legs), T >= 1"
        )
    if not isinstance(truth, jax.core.Tracer):
        values = np.asarray(truth)
        if not np.all((values == 0) | (values == 1)):
            bad = values[~((values == 0) | (values == 1))].ravel()[:3]
            raise ValueError(
                f"sequence_bce: truth must hold 0 and 1 (or bool) only, found {bad.tolist()}"
            )
    n_envs, n_legs = shape[1:]
    belief = init_belief_batch(params, n_envs, n_legs)
    _check_sequence("sequence_bce", params, belief, meas_seq, n_steps=shape[0])
    _check_call("sequence_bce", params, terrain, key)

    def body(carry, inputs):
        b, k = carry
        meas, y = inputs
        k, sub = jax.random.split(k)
        b = step_batch(params, terrain, b, meas, key=sub)[0]
        y = y.astype(b.logit.dtype)
        nll = -(y * jax.nn.log_sigmoid(b.logit) + (1.0 - y) * jax.nn.log_sigmoid(-b.logit))
        return (b, k), nll

    _, nll = jax.lax.scan(body, (belief, key), (meas_seq, truth))
    return jnp.mean(nll)
