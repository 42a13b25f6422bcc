"""The loss of one window: BCE, prior, event term, the cells' penalty."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact.filter import step_batch
from jax_contact.params import EstimatorParams
from jax_contact.tune.cells import cell_surrogates, constraint_penalty
from jax_contact.tune.config import TuneConfig
from jax_contact.tune.events import TuningData, air_event_terms
from jax_contact.tune.space import NOISE_FIELDS, ParamSpace, to_params


def prior_penalty(space: ParamSpace, theta: dict, theta0: dict, config: TuneConfig) -> jax.Array:
    """() the regulariser of ``jax_contact.tune``'s docstring."""
    total = jnp.float32(0.0)
    for f in space.fields:
        d = theta[f] - theta0[f]
        w = config.prior_noise if f in NOISE_FIELDS else config.prior_other
        total = total + 0.5 * w * jnp.sum(d * d)
    return total


def _window(data: TuningData, start: int, length: int) -> TuningData:
    """Steps [start, start + length) as device arrays, padded with masked copies of the
    last step so every window has one shape (one compilation). A window longer than the
    log is the log: padded to ``length``, ``tune --chunk 100000000`` on an 800-step log
    filled the host's 23 GB with masked copies (a helper's trial)."""
    length = min(length, data.n_steps)
    stop = min(start + length, data.n_steps)
    pad = length - (stop - start)

    def take(x):
        x = np.asarray(x[start:stop])
        if pad:
            x = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)], axis=0)
        return jnp.asarray(x)

    out = jax.tree.map(take, data)
    if pad:
        keep = jnp.asarray(np.arange(length) < stop - start)[:, None, None]
        out = out.replace(mask=out.mask & keep)
        if out.events is not None:  # the padding holds no phase start and no event
            out = out.replace(events=jax.tree.map(lambda x: x & keep, out.events))
    return out


def _bce(logit: jax.Array, y: jax.Array) -> jax.Array:
    y = y.astype(logit.dtype)
    return -(y * jax.nn.log_sigmoid(logit) + (1.0 - y) * jax.nn.log_sigmoid(-logit))


def filter_logits(
    params: EstimatorParams, terrain, belief, meas, *, key: jax.Array, remat: bool = False
):
    """Runs the filter over a window; returns (final belief, (T, E, L) logits).

    ``belief`` has leaves of leading axes (E, L); ``meas`` leading axes (T, E[, L]).
    With ``remat`` each step is recomputed in the backward pass (memory: beliefs only).
    """

    def body(carry, m):
        b, k = carry
        k, sub = jax.random.split(k)
        b, _ = step_batch(params, terrain, b, m, key=sub)
        return (b, k), b.logit

    if remat:
        body = jax.checkpoint(body)
    (belief, _), logits = jax.lax.scan(body, (belief, key), meas)
    return belief, logits


def air_hinge(logit: jax.Array, margin: float) -> jax.Array:
    """Smooth hinge ``softplus(2 (l + margin)) / 2``: ~0 below ``-margin``, ~``l + margin``
    above (the false-contact term of ``jax_contact.tune``'s docstring)."""
    return jax.nn.softplus(2.0 * (logit + margin)) / 2.0


def window_bce(
    params: EstimatorParams,
    terrain,
    belief,
    window: TuningData,
    *,
    key: jax.Array,
    air_margin: float = 2.0,
    event_temperature: float | None = None,
) -> tuple[jax.Array, tuple]:
    """Masked BCE of one window: (sum of BCE, (final belief, number of counted steps, sum
    of the air hinge over the true air steps, sum of the event term over the window's air
    phases, number of air phases, the (T, E, L) logits)); the event sums are 0 unless
    ``event_temperature``."""
    belief, logits = filter_logits(params, terrain, belief, window.meas, key=key, remat=True)
    nll = jnp.where(window.mask, _bce(logits, window.truth), 0.0)
    air = window.mask & ~window.truth.astype(bool)
    hinge = jnp.where(air, air_hinge(logits, air_margin), 0.0)
    if event_temperature is None:
        event, n_phases = jnp.zeros((), logits.dtype), jnp.zeros((), jnp.int32)
    else:
        if window.events is None:
            raise ValueError("the event term needs the window's AirPhases (with_air_phases)")
        event, n_phases = air_event_terms(logits, window, event_temperature)
    return jnp.sum(nll), (belief, jnp.sum(window.mask), jnp.sum(hinge), event, n_phases, logits)


def tuning_loss(
    theta: dict,
    space: ParamSpace,
    base: EstimatorParams,
    theta0: dict,
    terrain,
    belief,
    window: TuningData,
    config: TuneConfig,
    *,
    key: jax.Array,
    cells_reference: tuple[jax.Array, jax.Array] | None = None,
):
    """The loss of ``jax_contact.tune``'s docstring on one window.

    ``cells_reference``: with ``config.constraint_weight > 0``, the untuned parameters'
    :func:`cell_surrogates` on this window and :func:`constraint_units`, both (4,).

    Returns:
      (loss (), (final belief, mean BCE of the window (), counted steps ())).
    """
    params = to_params(space, base, theta)
    events = config.event_weight > 0 or config.constraint_weight > 0
    total, (belief, n, hinge, event, n_phases, logits) = window_bce(
        params, terrain, belief, window, key=key, air_margin=config.air_margin,
        event_temperature=config.event_temperature if events else None,
    )  # fmt: skip
    scale = 1.0 / jnp.maximum(n, 1).astype(total.dtype)
    data = total * scale
    loss = data + prior_penalty(space, theta, theta0, config)
    if config.air_penalty > 0:
        loss = loss + config.air_penalty * hinge * scale
    if config.event_weight > 0:
        loss = loss + config.event_weight * event / jnp.maximum(n_phases, 1).astype(total.dtype)
    if config.constraint_weight > 0:
        if cells_reference is None:
            raise ValueError("constraint_weight > 0 needs the window's cells_reference")
        reference, units = cells_reference
        cells = cell_surrogates(logits, window, config.event_temperature)
        penalty = constraint_penalty(
            cells, jnp.asarray(reference, cells.dtype), jnp.asarray(units, cells.dtype)
        )
        loss = loss + config.constraint_weight * penalty
    return loss, (belief, data, n)
