"""The Brax and Playground adapters of the contact observation wrapper, and wrap_contact.

Both wrappers share :class:`_ContactMixin` (reset, step, observation size, metrics) and
differ only in the ``State`` field that holds the MJX data and in how the physics-rate
loop is reached (:mod:`jax_contact.envs.substeps`). See :mod:`jax_contact.envs.wrapper` for what
they do.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

import jax
import jax.numpy as jnp
from brax.envs import base as brax_base
from brax.envs.wrappers import training as brax_training
from mujoco_playground._src import mjx_env as pg_env
from mujoco_playground._src import wrapper as pg_wrapper

import jax_contact as jc
from jax_contact.envs import contact_core, sensors, substeps
from jax_contact.envs.contact_config import ContactObsConfig
from jax_contact.envs.contact_core import ContactEstState, Core

# Tag folded into the reset key, so the wrapper's stream is its own and the wrapped env
# gets the caller's key untouched (wrapped and unwrapped envs simulate the same episode).
_KEY_TAG = 0x6A78_636E


def _merge(config, foot_names, sensor, params, terrain) -> ContactObsConfig:
    """The config with the older keyword arguments folded in (they fill what it leaves at
    its default; one that says otherwise than the config is refused: ``foot_names``
    silently replaced ``config.feet``, reordering the features, a helper's trial)."""
    cfg = ContactObsConfig() if config is None else config
    if not isinstance(cfg, ContactObsConfig):
        raise ValueError(f"config must be a ContactObsConfig, got {type(cfg).__name__}")
    over = {}
    if foot_names is not None:
        over["feet"] = tuple(foot_names) if not isinstance(foot_names, str) else foot_names
    if sensor is not None:
        over["sensor"] = sensor
    if params is not None:
        over["params"] = params
    if terrain is not None:
        over["terrain"] = terrain
    default = ContactObsConfig()
    for field, value in over.items():
        given = getattr(cfg, field)
        same = given is value or (isinstance(given, str | tuple) and given == value)
        if not same and given is not getattr(default, field) and given != getattr(default, field):
            arg = "foot_names" if field == "feet" else field
            raise ValueError(
                f"{arg}={value!r} and config.{field}={given!r} disagree: give it once, in the"
                " config (the keyword arguments are kept for older callers)"
            )
    return dataclasses.replace(cfg, **over) if over else cfg


def _check_nesting(env, core: Core) -> None:
    """Refuses, when wrapping, what the wrapped step would refuse when traced: a second
    physics-rate wrapper over one env, or two wrappers with one ``info_key``. Walks the
    ``env`` attributes of the wrappers below."""
    inner = env
    while inner is not None:
        other = getattr(inner, "_core", None)
        if isinstance(other, Core):
            if core.rate == "substep" and other.rate == "substep":
                raise ValueError(
                    "the env is already wrapped by a physics-rate contact wrapper: only one"
                    " can run at the physics rate (give the others config.rate='control')"
                )
            if other.cfg.info_key == core.cfg.info_key:
                raise ValueError(
                    f"the env is already wrapped by a contact wrapper with info_key"
                    f" {core.cfg.info_key!r}: give this wrapper another config.info_key"
                )
        inner = getattr(inner, "env", None)


class _ContactMixin:
    """reset / step shared by the Brax and the Playground wrapper."""

    _DATA: str  # the State field holding the MJX data

    def _init_contact(self, config, foot_names, sensor, params, terrain) -> None:
        cfg = _merge(config, foot_names, sensor, params, terrain)
        self._core = contact_core.make_core(self.env, cfg)
        _check_nesting(self.env, self._core)
        key = cfg.info_key
        self._truth_key = key + "_truth"
        self._substeps_key = key + "_substeps"
        self._score_key = key + "_score"
        self._metric_key = key + "/accuracy"
        mj_model = contact_core.model_of(self.env)[1]
        self._n_sub = int(round(float(self.env.dt) / float(mj_model.opt.timestep)))

    def sim_data(self, state):
        """The MJX data of one of this env's states (Brax's ``pipeline_state``,
        Playground's ``data``)."""
        return getattr(state, self._DATA)

    @property
    def contact_core(self) -> Core:
        """The description, feet, parameters, sensor model and terrain the wrapper uses."""
        return self._core

    @property
    def contact_rate(self) -> str:
        """``"substep"`` (an update per physics step) or ``"control"`` (per env step)."""
        return self._core.rate

    def contact_report(self) -> dict:
        """The wrapper's choices: rate, feet and their contact points, force axes, sign test,
        truth."""
        return contact_core.report(self._core)

    @property
    def observation_size(self):
        return self._core.add_size(self.env.observation_size)

    def _finish(self, state, est: ContactEstState, score, rec=None):
        core = self._core
        data = getattr(state, self._DATA)
        info = dict(state.info)
        info[core.cfg.info_key] = est
        metrics = dict(state.metrics)
        if core.truth is not None:
            info[self._truth_key] = core.truth(data)
            n, hits = score["n"], score["hits"]
            mean = jnp.where(n > 0, hits / jnp.where(n > 0, n, 1.0), 0.0)
            info[self._score_key] = {**score, "mean": mean}
            # Brax's EpisodeWrapper and EvalWrapper sum every metric over the episode, once
            # per training-wrapper step (of action_repeat env steps): the increment of the
            # running accuracy since that step began (score["base"], _outer_base) sums to
            # the episode's accuracy.
            metrics[self._metric_key] = mean - score["base"]
        if core.cfg.record_substeps:
            info[self._substeps_key] = rec
        obs = core.add_features(state.obs, core.features(est, data))
        return state.replace(obs=obs, info=info, metrics=metrics)

    def reset(self, rng: jax.Array):
        if jnp.issubdtype(jnp.asarray(rng).dtype, jax.dtypes.prng_key):
            batched = jnp.ndim(rng) != 0
        else:
            batched = jnp.ndim(rng) != 1
        if batched:
            raise ValueError(
                f"reset got a batch of keys (shape {jnp.shape(rng)}): wrap the unbatched env"
                " and apply VmapWrapper (or the training wrappers) outside this wrapper"
            )
        state = self.env.reset(rng)
        if self._core.cfg.info_key in state.info:
            raise ValueError(
                f"state.info already has {self._core.cfg.info_key!r}: give this wrapper another"
                " config.info_key"
            )
        data = getattr(state, self._DATA)
        est = self._core.init(data, jax.random.fold_in(rng, _KEY_TAG))
        zero = jnp.zeros((), jnp.float32)
        score = {"n": zero, "hits": zero, "mean": zero, "base": zero, "tag": zero - 1.0}
        rec = None
        if self._core.cfg.record_substeps:
            n = self._n_substeps()
            rec = jax.tree.map(
                lambda x: jnp.broadcast_to(x, (n,) + x.shape), self._core.record(est, data)
            )
            rec.pop("hit", None)
            rec.pop("scored", None)
        return self._finish(state, est, score, rec)

    def _n_substeps(self) -> int:
        return self._n_sub

    def step(self, state, action: jax.Array):
        core = self._core
        data = getattr(state, self._DATA)
        if core.cfg.info_key not in state.info:  # a bare KeyError, raised while tracing
            raise ValueError(
                f"state.info has no {core.cfg.info_key!r}: step takes the state of this"
                " wrapper's reset (or of its last step), not the wrapped env's own"
            )
        est = state.info[core.cfg.info_key]
        moved = core.moved(est, data)
        est = core.restart(est, data, moved)
        if core.truth is not None:
            old = state.info[self._score_key]
            score = _outer_base({k: jnp.where(moved, 0.0, v) for k, v in old.items()}, state)
        else:
            score = None
        if core.rate == "control":
            nstate = self.env.step(state, action)
            est = core.update(est, getattr(nstate, self._DATA))
            rec = jax.tree.map(lambda x: x[None], core.record(est, getattr(nstate, self._DATA)))
        else:
            chain = substeps.Chain(est, core.update, core.record)
            nstate = self._step_hooked(state, action, chain)
            if not chain.records:
                raise ValueError(
                    f"{type(self.env.unwrapped).__name__}.step did not run its physics through"
                    f" {self._LOOP}, so the substep rate cannot reach its physics steps: use"
                    " config.rate='control'"
                )
            est = chain.est
            rec = jax.tree.map(lambda *x: jnp.concatenate(x), *chain.records)
        if score is not None:
            # Each update counts the share of its feet that were scored (all of them, but
            # where a reading was lost): n is the number of updates when nothing was lost.
            scored = rec.pop("scored").astype(jnp.float32)
            hits = jnp.sum(jnp.mean(rec.pop("hit").astype(jnp.float32) * scored, axis=-1))
            n_new = jnp.sum(jnp.mean(scored, axis=-1))
            score = {**score, "n": score["n"] + n_new, "hits": score["hits"] + hits}
        if core.cfg.record_substeps:
            rec = jax.tree.map(lambda x: x[-self._n_substeps() :], rec)
        return self._finish(nstate, est, score, rec)


def _outer_base(score: dict, state) -> dict:
    """``score`` with ``base``, the running accuracy when the current training-wrapper step
    began. Brax's ``EpisodeWrapper`` runs ``action_repeat`` env steps in a scan and adds
    only the last one's metrics; its counter ``info["steps"]`` is the same for all of them
    and changes between its steps (``tag`` keeps the value ``base`` was taken at). Without
    that counter every env step is its own (the increment of one step)."""
    steps = state.info.get("steps")
    if steps is None:
        return {**score, "base": score["mean"]}
    steps = jnp.asarray(steps, jnp.float32)
    fresh = steps != score["tag"]
    return {**score, "base": jnp.where(fresh, score["mean"], score["base"]), "tag": steps}


# The wrappers that batch and auto-reset an env for training: wrap_contact goes inside them.
_TRAINING_WRAPPERS = (
    brax_training.VmapWrapper,
    brax_training.EpisodeWrapper,
    brax_training.AutoResetWrapper,
    brax_training.EvalWrapper,
    brax_training.DomainRandomizationVmapWrapper,
    pg_wrapper.BraxAutoResetWrapper,
    pg_wrapper.BraxDomainRandomizationVmapWrapper,
)


def _check_env(env, kind, name: str) -> None:
    """Raises ValueError unless ``env`` is an unbatched env of ``kind`` (its ``unwrapped``)."""
    layer = env
    while layer is not None:
        if isinstance(layer, _TRAINING_WRAPPERS):
            raise ValueError(
                f"env is already wrapped for training ({type(layer).__name__}): wrap the"
                " unbatched env with wrap_contact first, then the training wrappers"
                " (wrapper.wrap_for_brax_training, brax.envs.training.wrap) around it"
            )
        layer = getattr(layer, "env", None)
    inner = getattr(env, "unwrapped", env)
    if not isinstance(inner, kind):
        raise ValueError(
            f"{name} wraps a {kind.__module__}.{kind.__name__}, got {type(inner).__name__}:"
            " wrap_contact picks the wrapper for the env"
        )


class BraxContactWrapper(_ContactMixin, brax_base.Wrapper):
    """Contact observation wrapper for Brax envs (``State.pipeline_state``). See the module."""

    _DATA = "pipeline_state"
    _LOOP = "self.pipeline_step"

    def __init__(
        self, env, config=None, *, foot_names=None, sensor=None, params=None, terrain=None
    ):
        _check_env(env, brax_base.Env, "BraxContactWrapper")
        super().__init__(env)
        self._init_contact(config, foot_names, sensor, params, terrain)

    def _step_hooked(self, state, action, chain):
        return substeps.brax_step(self.env, self.env.unwrapped, state, action, chain, self._n_sub)


class PlaygroundContactWrapper(_ContactMixin, pg_wrapper.Wrapper):
    """Contact observation wrapper for Playground envs (``State.data``). See the module."""

    _DATA = "data"
    _LOOP = "mjx_env.step"

    def __init__(
        self, env, config=None, *, foot_names=None, sensor=None, params=None, terrain=None
    ):
        _check_env(env, pg_env.MjxEnv, "PlaygroundContactWrapper")
        super().__init__(env)
        self._init_contact(config, foot_names, sensor, params, terrain)

    def _step_hooked(self, state, action, chain):
        return substeps.playground_step(self.env, state, action, chain)


def wrap_contact(
    env,
    config: ContactObsConfig | None = None,
    *,
    foot_names: Sequence | None = None,
    sensor: str | sensors.SensorParams | None = None,
    params: jc.EstimatorParams | str | os.PathLike | None = None,
    terrain=None,
):
    """Wraps an (unbatched) env so that its observation holds the estimated foot contact.

    Apply it before the training wrappers (``brax.envs.wrappers.training.wrap``,
    Playground's ``wrapper.wrap_for_brax_training``), which batch and auto-reset it; with
    domain randomisation, before :mod:`jax_contact.envs.randomization`'s (the frameworks'
    own randomisation steps ``env.unwrapped``, skipping this wrapper).

    Args:
      env: a Brax ``PipelineEnv`` with ``backend="mjx"`` or a Playground ``MjxEnv``
        (``impl="jax"``), possibly already wrapped by unbatched wrappers.
      config: a :class:`ContactObsConfig`, which holds every option; None: the defaults.
      foot_names, sensor, params, terrain: set ``config.feet``, ``config.sensor``,
        ``config.params``, ``config.terrain`` where the config leaves them at their
        defaults (kept for older callers; a value the config sets otherwise is
        refused). ``params`` may be a parameter file or preset name (``"go1"``): its
        calibration map is then applied (``ContactObsConfig.calibration``).

    Returns:
      A :class:`BraxContactWrapper` or :class:`PlaygroundContactWrapper`.

    Raises:
      ValueError: with the reason, for an env without an MJX model (or another Brax
        backend, or a Playground model not on ``impl="jax"``), a model without floor or
        floor contact, unknown feet (the message lists valid names), or parameters that
        do not fit.
    """
    inner = getattr(env, "unwrapped", env)
    kwargs = dict(foot_names=foot_names, sensor=sensor, params=params, terrain=terrain)
    if isinstance(inner, pg_env.MjxEnv):
        return PlaygroundContactWrapper(env, config, **kwargs)
    if isinstance(inner, brax_base.Env):
        return BraxContactWrapper(env, config, **kwargs)
    raise ValueError(
        f"env must be a Brax Env (PipelineEnv, backend='mjx') or a Playground MjxEnv, got"
        f" {type(env).__name__}"
    )
