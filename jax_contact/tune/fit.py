"""The tuning loop: epochs of truncated BPTT, validation, selection, the rejection step."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jax_contact.bootstrap import MIN_ENVS
from jax_contact.filter import init_belief_batch
from jax_contact.params import EstimatorParams, validate_params
from jax_contact.tune.calibration import sigmoid_np
from jax_contact.tune.cells import (
    cell_surrogates,
    constraint_units,
    no_worse,
    worse_beyond_spread,
)
from jax_contact.tune.config import TuneConfig
from jax_contact.tune.events import (
    TuningData,
    air_event_terms,
    check_scored_steps,
    with_air_phases,
)
from jax_contact.tune.loss import _window, filter_logits, tuning_loss
from jax_contact.tune.space import (
    NOISE_FIELDS,
    ParamSpace,
    init_theta,
    theta_bounds,
    to_params,
)


def _optimizer(config: TuneConfig) -> optax.GradientTransformation:
    if config.feasible:  # the learning rate in the state, so that a rejection can halve it
        adam = optax.inject_hyperparams(optax.adam)(learning_rate=config.learning_rate)
    else:
        adam = optax.adam(config.learning_rate)
    return optax.chain(optax.clip_by_global_norm(config.clip_norm), adam)


def _halve_learning_rate(opt_state):
    """The state of :func:`_optimizer` (``feasible``) with half the learning rate."""
    clip, adam = opt_state
    lr = adam.hyperparams["learning_rate"]
    return (clip, adam._replace(hyperparams={**adam.hyperparams, "learning_rate": lr * 0.5}))


@functools.partial(jax.jit, static_argnames=("space", "config"))
def _train_window(
    theta, opt_state, space, base, theta0, bounds, terrain, belief, window, config, key,
    cells_reference=None,
):  # fmt: skip
    grad_fn = jax.value_and_grad(tuning_loss, has_aux=True)
    (loss, (belief, data, n)), grads = grad_fn(
        theta, space, base, theta0, terrain, belief, window, config, key=key,
        cells_reference=cells_reference,
    )  # fmt: skip
    updates, opt_state = _optimizer(config).update(grads, opt_state, theta)
    # Projected gradient step: back into the bounds (theta_bounds: the floors and the
    # plausibility box) after the update.
    lower, upper = bounds
    theta = jax.tree.map(jnp.clip, optax.apply_updates(theta, updates), lower, upper)
    return theta, opt_state, belief, loss, data, n, optax.global_norm(grads)


@jax.jit
def _forward_window(params, terrain, belief, meas, key):
    return filter_logits(params, terrain, belief, meas, key=key)


def predict_logits(
    params: EstimatorParams,
    terrain,
    data: TuningData,
    *,
    key: jax.Array,
    chunk: int = 400,
) -> np.ndarray:
    """(T, E, L) float32 filtered logits of a whole log, in windows of ``chunk`` steps."""
    out = _over_windows(
        params, data, chunk, key, lambda b, win, k: _forward_window(params, terrain, b, win.meas, k)
    )
    return np.concatenate(out, axis=0)[: data.n_steps]


def _over_windows(params, data: TuningData, chunk: int, key, run) -> list[np.ndarray]:
    """``run(belief, window, key) -> (belief, out)`` over a log's windows of ``chunk``
    steps (:func:`_window`), the belief carried from one to the next as in :func:`tune`'s
    epochs; the ``out`` of each window."""
    n_envs, n_legs = data.truth.shape[1:]
    belief = init_belief_batch(params, n_envs, n_legs)
    out = []
    for w, start in enumerate(range(0, data.n_steps, chunk)):
        belief, o = run(belief, _window(data, start, chunk), jax.random.fold_in(key, w))
        out.append(np.asarray(o))
    return out


@functools.partial(jax.jit, static_argnames=("temperature",))
def _window_cells(params, terrain, belief, window, key, temperature):
    belief, logits = filter_logits(params, terrain, belief, window.meas, key=key)
    return belief, cell_surrogates(logits, window, temperature)


def reference_cells(
    params: EstimatorParams,
    terrain,
    data: TuningData,
    *,
    key: jax.Array,
    chunk: int = 400,
    temperature: float = 0.25,
) -> np.ndarray:
    """(n_windows, 4) :func:`cell_surrogates` of ``params`` on each training window of a
    log (the windows and belief carry of :func:`tune`'s epochs)."""
    return np.stack(
        _over_windows(
            params, data, chunk, key,
            lambda b, win, k: _window_cells(params, terrain, b, win, k, temperature),
        )
    )  # fmt: skip


def pooled(datas: Sequence[TuningData]) -> TuningData:
    """Truth and mask of several logs flattened into one (for pooled scores)."""
    return TuningData(
        meas=None,
        truth=np.concatenate([np.asarray(d.truth).reshape(-1) for d in datas]),
        mask=np.concatenate([np.asarray(d.mask).reshape(-1) for d in datas]),
    )


def score_logits(logits, data: TuningData) -> dict[str, float]:
    """Mean BCE, F1 (flag P > 0.5) and ECE (10 bins) of logits over the masked steps."""
    from jax_contact.metrics import expected_calibration_error, step_scores

    mask = np.asarray(data.mask, bool)
    truth = np.asarray(data.truth, bool)
    x = np.asarray(logits, np.float64)
    bce = np.logaddexp(0.0, -x) * truth + np.logaddexp(0.0, x) * ~truth
    p = sigmoid_np(x)
    return {
        "bce": float(bce[mask].mean()) if mask.any() else float("nan"),
        "f1": step_scores(p, truth, mask).f1,
        "ece": expected_calibration_error(p, truth, mask),
    }


@functools.partial(jax.jit, static_argnames=("temperature",))
def _event_sum(logits, window, temperature):
    return air_event_terms(logits, window, temperature)


def score_logs(
    logits: Sequence, datas: Sequence[TuningData], *, dt: float, config: TuneConfig
) -> dict:
    """Pooled validation scores of whole logs (each (T, E, L) logits with its data).

    ``bce`` (mean over masked foot-steps), ``event`` (the event term's mean over air
    phases; NaN without :class:`AirPhases`), ``loss`` (``bce + event_weight * event``,
    no prior), ``f1``, ``ece`` and ``fail`` (``jax_contact.metrics``' swing-phase failure
    rate, rule 9b: air phases longer than a bounce with a false contact / such phases,
    events per log; Table III's target reads it, as air-phase failures diluted by the
    truth's bounces flatter the walks), and ``cells``: per log, the numbers
    :func:`no_worse` compares (:data:`CELL_KEYS`).
    """
    from jax_contact.metrics import evaluate

    out = score_logits(np.concatenate([np.asarray(x).reshape(-1) for x in logits]), pooled(datas))
    ev_sum = n_ph = failed = n_air = 0.0
    cells = []
    for x, d in zip(logits, datas, strict=True):
        if d.events is not None:
            e, n = _event_sum(jnp.asarray(x), d.replace(meas=None), config.event_temperature)
            ev_sum, n_ph = ev_sum + float(e), n_ph + float(n)
        known = None if d.known is None else np.asarray(d.known, bool)
        m = evaluate(
            sigmoid_np(x), np.asarray(d.truth, bool), np.asarray(d.mask, bool), dt=dt,
            truth_known=known,
        )  # fmt: skip
        failed, n_air = failed + m.swing_phases_with_failure, n_air + m.n_swing_phases
        cells.append(
            dict(
                f1=float(m.f1),
                accuracy=float(m.accuracy),
                ece=float(m.ece),
                fail=float(m.swing_phase_failure_rate),
                touchdown_ms=abs(float(m.touchdown_delay_ms[0])),
                liftoff_ms=abs(float(m.liftoff_delay_ms[0])),
            )
        )
    out["event"] = ev_sum / n_ph if n_ph else float("nan")
    out["loss"] = out["bce"] + (config.event_weight * out["event"] if n_ph else 0.0)
    out["fail"] = failed / n_air if n_air else float("nan")
    out["cells"] = cells
    return out


# ------------------------------------------------------------------------------ tuning


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` returns.

    Attributes:
      params: the parameters of the best validation epoch (validated).
      theta: their unconstrained values.
      history: one dict per epoch (epoch 0: before any update): ``epoch``, ``train_loss``
        (mean over the epoch's windows of the loss, NaN for epoch 0), ``train_bce``,
        ``val_bce``, ``val_event``, ``val_loss``, ``val_f1``, ``val_ece``, ``val_fail``
        (:func:`score_logs`), ``val_worse`` (the validation cells worse than epoch 0's
        beyond the rollouts' spread, :func:`worse_beyond_spread`; absent when a validation
        log has fewer than :data:`jax_contact.bootstrap.MIN_ENVS` envs, where the bootstrap
        makes no call), ``grad_norm``, ``wall_s``; with ``config.feasible`` also
        ``train_cells`` (the tuning logs' cells) and ``rejected``.
      best_epoch: the epoch whose parameters are returned (lowest ``val_loss``, or
        ``val_bce`` with ``config.select == "bce"``, or the lowest ``val_loss`` among the
        epochs :func:`no_worse` than epoch 0 with ``"cells"``, or among those with no
        ``val_worse`` with ``"spread"``).
      stopped_early: whether patience ran out before ``max_epochs``, or the fit diverged.
      wall_s: total wall time, s (compilation included).
      diverged: None, or what stopped a fit whose update left the parameters' valid range
        (a NaN or inf std, a cap at 0.5: too large a learning rate), naming the epoch and
        the field; that epoch has no row, and the best epoch before it is returned.
    """

    params: EstimatorParams
    theta: dict
    history: tuple[dict, ...]
    best_epoch: int
    stopped_early: bool
    wall_s: float
    diverged: str | None = None


def _out_of_range(space: ParamSpace, base: EstimatorParams, theta: dict) -> str | None:
    """None, or :func:`jax_contact.validate_params`' message for the parameters of
    ``theta`` (an update that left their range: the next window's ``init_belief`` raised
    it as if it were bad input, and every finished epoch was lost)."""
    try:
        validate_params(to_params(space, base, theta))
    except ValueError as err:
        return str(err)
    return None


def select_epoch(history: Sequence[dict], config: TuneConfig) -> int:
    """The epoch :func:`tune` returns from a history of its rows (``TuneResult.history``).

    Going through the epochs in order from epoch 0, an epoch replaces the one kept if it
    was not ``rejected`` (``config.feasible``), its criterion (``val_bce`` with
    ``config.select == "bce"``, else ``val_loss``) is below the kept one's by more than
    ``config.min_delta``, and it is admissible: with ``"cells"`` :func:`no_worse` than
    epoch 0 in every validation cell (within ``config.cell_tolerance``), with ``"spread"``
    no ``val_worse`` cell. ``tune`` calls it after every epoch (an epoch that is not kept
    counts against ``patience``).
    """
    crit = "val_bce" if config.select == "bce" else "val_loss"
    first = history[0]

    def admissible(row) -> bool:
        if config.select == "spread":
            return not row["val_worse"]
        return config.select != "cells" or no_worse(
            row["val_cells"], first["val_cells"], config.cell_tolerance
        )

    best, kept = first[crit], 0
    for row in history[1:]:
        if not row.get("rejected") and row[crit] < best - config.min_delta and admissible(row):
            best, kept = row[crit], row["epoch"]
    return kept


def tune(
    base: EstimatorParams,
    terrain,
    train: Sequence[TuningData],
    validation: TuningData | Sequence[TuningData],
    space: ParamSpace,
    config: TuneConfig = TuneConfig(),  # noqa: B008 (frozen)
    *,
    floor: dict | None = None,
    progress: Callable[[dict], None] | None = None,
) -> TuneResult:
    """Fits the fields of ``space`` to the tuning logs (``jax_contact.tune``'s docstring).

    Args:
      base: the untuned parameters; their noise is the prior's centre.
      terrain: the estimator's terrain model (e.g. ``jax_contact.flat(0.0, 0.05)``).
      train: the tuning logs, each a :class:`TuningData` (NumPy leaves are fine: windows
        are moved to the device one at a time).
      validation: the log(s) that decide early stopping (other seeds); with several, the
        BCE, F1 and ECE are pooled over all their steps.
      space: what is tuned.
      config: optimiser, windows, prior, seed.
      floor: the smallest std of each floored noise field (``{field: array}``, e.g.
        :func:`jax_contact.defaults.sensor_noise_floor`): every update is projected back
        onto it (:func:`theta_lower_bounds`); None: no floor. ``config.noise_ratio`` adds
        the plausibility box (:func:`theta_bounds`).
      progress: called with each epoch's history dict as it completes.

    Returns:
      :class:`TuneResult`.

    Raises:
      ValueError: no tuning log, a log without a step that counts, logs without both
        contact and air (:func:`check_scored_steps`), or parameters that fail validation.
    """
    train = [train] if isinstance(train, TuningData) else list(train)  # as validation
    if not train:
        raise ValueError("tune needs at least one tuning log")
    if len(space.dof_groups) != base.nv:
        raise ValueError(
            f"space has nv={len(space.dof_groups)} (its dof_groups) but base has nv={base.nv}:"
            " make the space for the same robot (make_space(base.nv) or robot_space(desc))"
        )
    t_start = time.perf_counter()
    key = jax.random.key(config.seed)
    theta = init_theta(space, base)
    theta0 = theta
    bounds = theta_bounds(space, base, floor, config.noise_ratio)
    opt_state = _optimizer(config).init(theta)
    val_key = jax.random.fold_in(key, 10**6)

    vals = [validation] if isinstance(validation, TuningData) else list(validation)
    if not vals:
        raise ValueError("tune needs a validation log")
    check_scored_steps(train, "tuning log")
    check_scored_steps(vals, "validation log")

    dt = float(base.dt)
    early = int(round(config.event_early_s / dt))
    train = [d if d.events is not None else with_air_phases(d, early) for d in train]
    vals = [v if v.events is not None else with_air_phases(v, early) for v in vals]

    def logits_of(th, logs, log_key) -> list:
        params = to_params(space, base, th)
        return [
            np.asarray(predict_logits(params, terrain, d, key=jax.random.fold_in(log_key, i),
                                      chunk=config.chunk))
            for i, d in enumerate(logs)
        ]  # fmt: skip

    def scores(th, logs, log_key) -> dict:
        # score_logs of the parameters th on whole logs (validation or tuning logs).
        return score_logs(logits_of(th, logs, log_key), logs, dt=dt, config=config)

    val_logits0 = None  # epoch 0's validation logits, the reference of val_worse
    # The validation logs too small for the bootstrap to make a call (below MIN_ENVS envs).
    few = [(i, v.truth.shape[1]) for i, v in enumerate(vals) if v.truth.shape[1] < MIN_ENVS]

    def validate(th) -> dict:
        # score_logs on the validation logs, and the cells worse than epoch 0's beyond the
        # rollouts' spread (a paired env bootstrap).
        nonlocal val_logits0
        logits = logits_of(th, vals, val_key)
        out = score_logs(logits, vals, dt=dt, config=config)
        if val_logits0 is None:
            val_logits0 = logits
        # Below MIN_ENVS envs the bootstrap makes no call: no count rather than a 0 that
        # reads as "no cell worse".
        if not few:
            out["worse"] = worse_beyond_spread(logits, val_logits0, vals, dt=dt)
        return out

    if config.select == "spread" and few:
        i, n = few[0]
        raise ValueError(
            f"select='spread' resamples the validation logs' envs and makes no call below"
            f" {MIN_ENVS} (jax_contact.bootstrap.MIN_ENVS); validation log {i + 1} of"
            f" {len(vals)} has {n}"
        )
    history = []
    first = dict(epoch=0, train_loss=float("nan"), train_bce=float("nan"), grad_norm=float("nan"))
    first.update({f"val_{k}": v for k, v in validate(theta).items()})
    first["wall_s"] = time.perf_counter() - t_start
    history.append(first)
    if progress:
        progress(first)
    best_theta, best_epoch, bad = theta, 0, 0

    # The compiled training step depends on the loss and optimiser only: one program
    # whatever the epochs, patience or selection rule.
    step_config = dataclasses.replace(
        config, select="loss", max_epochs=0, patience=1, min_delta=0.0, cell_tolerance=0.0,
        noise_ratio=0.0,  # the box enters as bounds, traced
    )  # fmt: skip

    def tuning_cells(th) -> list[dict]:
        return scores(th, train, jax.random.fold_in(key, 3 * 10**6))["cells"]

    # The feasible-direction variant: the tuning logs' own cells at the defaults, and the
    # last accepted point.
    train_cells0 = None
    if config.feasible:
        train_cells0 = first["train_cells"] = tuning_cells(theta)
    accepted = (theta, opt_state)

    # The cells in the objective: the untuned parameters' surrogates on every training
    # window (the same windows and belief carry as the epochs below).
    references = [None] * len(train)
    if config.constraint_weight > 0:
        units = jnp.asarray(constraint_units(dt), jnp.float32)
        params0 = to_params(space, base, theta0)
        references = [
            reference_cells(params0, terrain, d, key=jax.random.fold_in(key, 2 * 10**6 + i),
                            chunk=config.chunk, temperature=config.event_temperature)
            for i, d in enumerate(train)
        ]  # fmt: skip

    stopped, diverged = False, None
    for epoch in range(1, config.max_epochs + 1):
        losses, bces, norms, counts = [], [], [], []
        for i, data in enumerate(train):
            n_envs, n_legs = data.truth.shape[1:]
            belief = init_belief_batch(to_params(space, base, theta), n_envs, n_legs)
            for w, start in enumerate(range(0, data.n_steps, config.chunk)):
                win = _window(data, start, config.chunk)
                k = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(key, epoch), i), w)
                ref = None
                if references[i] is not None:
                    ref = (jnp.asarray(references[i][w], jnp.float32), units)
                theta, opt_state, belief, loss, bce, n, gn = _train_window(
                    theta, opt_state, space, base, theta0, bounds, terrain, belief, win,
                    step_config, k, ref,
                )  # fmt: skip
                losses.append(float(loss))
                bces.append(float(bce))
                counts.append(float(n))
                norms.append(float(gn))
                if why := _out_of_range(space, base, theta):
                    diverged = (
                        f"epoch {epoch}, tuning log {i + 1}, window {w + 1}: {why} (loss"
                        f" {float(loss):.4g}, gradient norm {float(gn):.4g})"
                    )
                    break
            if diverged:
                break
        if diverged:
            stopped = True
            break
        w = np.asarray(counts) / max(sum(counts), 1.0)
        row = dict(
            epoch=epoch,
            train_loss=float(np.mean(losses)),
            train_bce=float(np.dot(w, bces)),
            grad_norm=float(np.mean(norms)),
        )
        row.update({f"val_{k}": v for k, v in validate(theta).items()})
        rejected = False
        if config.feasible:
            row["train_cells"] = tuning_cells(theta)
            rejected = not no_worse(row["train_cells"], train_cells0, config.cell_tolerance)
            row["rejected"] = rejected
            if rejected:
                theta, opt_state = accepted[0], _halve_learning_rate(accepted[1])
            accepted = (theta, opt_state)
        row["wall_s"] = time.perf_counter() - t_start
        history.append(row)
        if progress:
            progress(row)
        if select_epoch(history, config) == epoch:
            best_theta, best_epoch, bad = theta, epoch, 0
        else:
            bad += 1
            if bad >= config.patience:
                stopped = epoch < config.max_epochs
                break
    params = jax.tree.map(np.asarray, to_params(space, base, best_theta))
    params = jax.tree.map(jnp.asarray, params)
    validate_params(params)
    return TuneResult(
        params=params,
        theta={k: np.asarray(v) for k, v in best_theta.items()},
        history=tuple(history),
        best_epoch=best_epoch,
        stopped_early=stopped,
        wall_s=time.perf_counter() - t_start,
        diverged=diverged,
    )


def describe(space: ParamSpace, base: EstimatorParams, tuned: EstimatorParams) -> list[dict]:
    """One row per tuned value: ``field``, ``group``, ``default``, ``tuned``, ``ratio``.

    For the noise fields the value shown is the group's first coordinate (every coordinate
    of a group is scaled by the same factor, ``ratio``).
    """
    rows = []
    for f in space.fields:
        if f in NOISE_FIELDS:
            idx, names = space.groups_of(f)
            a, b = np.asarray(getattr(base.noise, f)), np.asarray(getattr(tuned.noise, f))
            for g, name in enumerate(names):
                i = list(idx).index(g)
                rows.append(
                    dict(
                        field=f,
                        group=name,
                        default=float(a[i]),
                        tuned=float(b[i]),
                        ratio=float(b[i] / a[i]),
                    )
                )
        else:
            a, b = float(getattr(base, f)), float(getattr(tuned, f))
            rows.append(dict(field=f, group="", default=a, tuned=b, ratio=b / a))
    return rows
