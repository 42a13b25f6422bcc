"""A wrapped env's physics steps as its estimator saw them, for tuning (``jax-contact tune-env``).

A scene (:func:`load_scene`: a Playground locomotion env with a scripted policy, or a
scene of ``jax-contact rates``) is loaded once; :func:`recorder` wraps it at the physics
rate and jits its rollout once, and each call records one seed: every physics step's
sensor readings and ground truth (:class:`Recording`). :func:`tuning_data` rebuilds every
step's estimator inputs from those readings with the code the live wrapper runs
(:meth:`jax_contact.envs.contact_core.Core.measure`), so what is fitted is what the
wrapper will see. The command and the fit are :mod:`jax_contact.train.tune_env`.
"""

from __future__ import annotations

import dataclasses
import functools

STEPS, ROLLOUTS = 150, 8  # the defaults of benchmarks/wrapper_accuracy.py
PLAYGROUND_SKIP_S, RATES_SKIP_S = 0.5, 0.2


@dataclasses.dataclass(frozen=True)
class Scene:
    """A scene's rollouts: the unwrapped env, the closed-loop part of the policy and its
    stop rule (or None), the time left out at the start (s), a one-line description, and
    ``actions_of(seed) -> (T, E, nu)`` the open-loop actions of one seed."""

    env: object
    feedback: object
    stop: object
    skip_s: float
    description: str
    actions_of: object


def load_scene(scene: str, n_steps: int, n_envs: int) -> Scene:
    """The :class:`Scene` of ``scene`` (the module docstring): the env is loaded once, and
    each seed's actions are drawn by ``actions_of``.

    Raises:
      ValueError: an unknown scene or policy (the message lists the valid ones).
    """
    from jax_contact.train import rates

    if scene in rates.SCENES:
        env, acts = rates.scene(scene, n_steps=n_steps, n_rollouts=n_envs)
        desc = f"jax-contact rates scene {scene!r}"
        return Scene(env, None, None, RATES_SKIP_S, desc, lambda seed: acts)
    from jax_contact.benchmarks import wrapper_accuracy as wa
    from jax_contact.envs import playground_offline

    name, _, policy = scene.partition(":")
    env = playground_offline.load(name)
    feedback, stop = wa.closed_loop_for(name, env, policy or None)
    # The description does not depend on the seed; drawn once here to check the policy.
    desc = wa.actions_for(name, env, 1, 1, 0, policy or None)[1]

    def actions_of(seed: int):
        return wa.actions_for(name, env, n_steps, n_envs, seed, policy or None)[0]

    return Scene(env, feedback, stop, PLAYGROUND_SKIP_S, f"{name}: {desc}", actions_of)


@dataclasses.dataclass(frozen=True)
class Recording:
    """Every physics step of E rollouts as the wrapper's estimator saw it.

    Attributes:
      core: the wrapper's :class:`~jax_contact.envs.contact_core.Core` (model, feet,
        default parameters, terrain, sensor model).
      mj_model: the env's ``mujoco.MjModel`` (the nominal one the wrapper reads).
      first: the readings at reset, leaves (E, ...): the first update's ``prev``.
      readings: each physics step's readings, leaves (N, E, ...), ``N = T x n_substeps``.
      truth: (N, E, L) bool, the wrapper's ground truth.
      valid: (N, E) bool: after the skipped start, before the rollout's first ``done`` (or
        ``stop``) and while every reading is finite. Readings after it hold the last
        valid one (a rollout that ended may have NaN physics).
      dt: the physics step, s.
      p_contact: (N, E, L) the live wrapper's P(contact) (its defaults, its map if any).
    """

    core: object
    mj_model: object
    first: object
    readings: object
    truth: object
    valid: object
    dt: float
    p_contact: object = None


def recorder(
    env,
    *,
    feedback=None,
    stop=None,
    skip_s: float = 0.0,
    config=None,
    policy=None,
):
    """``record(actions, key) -> Recording``: ``env`` wrapped at the physics rate once and its
    rollout jitted once, for every seed of a scene. ``record.core`` and ``record.dt`` are
    its recordings' estimator core and period, before any rollout.

    ``record`` rolls out ``actions`` (T, E, nu) and records every physics step's readings
    and truth (rollout ``e`` resets with ``split(key, E)[e]``; ``feedback(data) -> (nu,)``
    is added to each action, ``stop(data) -> bool`` ends a rollout's valid steps, as in
    :func:`jax_contact.train.rates.compare_rates`). Calls with actions of one shape reuse
    one compilation.

    Args:
      config: the wrapper's :class:`~jax_contact.envs.contact_config.ContactObsConfig`
        (feet, sensors, parameters, observation placement), as in training; its rate is
        set to ``"substep"`` and ``record_substeps`` on. None: the defaults
        (``anymal_like`` sensors).
      policy: a closed-loop policy ``(obs, key) -> (action, extras)`` (a Brax inference
        function, e.g. :func:`jax_contact.train.policy_eval.load_policy`'s) of the wrapped
        env's observation; its action is added to ``actions``. Its keys are drawn from
        ``fold_in(key, 1)``, apart from the resets' and the sensors'.

    Raises:
      ValueError: the env has no ground truth, or ``policy`` does not take the wrapped
        env's observation (or returns another action size); (from ``record``)
        ``actions`` is not (T, E, nu).
    """
    import jax
    import numpy as np

    from jax_contact.envs.contact_config import ContactObsConfig
    from jax_contact.envs.contact_core import model_of
    from jax_contact.envs.contact_wrappers import wrap_contact
    from jax_contact.train.rates import in_time_order, policy_step

    base = ContactObsConfig() if config is None else config
    cfg = dataclasses.replace(base, rate="substep", record_substeps=True)
    wrapped = wrap_contact(env, cfg)
    core = wrapped.contact_core
    if core.truth is None:
        raise ValueError("env's model has no ground-truth contact for every foot: nothing to fit")
    sub_key = cfg.info_key + "_substeps"
    mj_model = model_of(env)[1]
    dt = float(core.params.dt)
    if policy is not None:
        _check_policy(policy, wrapped)

    def step(carry, a):
        s, k = carry
        if policy is not None:
            k, k_act = jax.random.split(k)
            a = a + policy(s.obs, k_act)[0]
        s, ended = policy_step(wrapped, s, a, feedback, stop)
        sub = s.info[sub_key]
        return (s, k), (sub["reading"], sub["truth"], sub["p_contact"], ended)

    @jax.jit
    def rollout(keys, policy_keys, a_seq):
        s0 = jax.vmap(wrapped.reset)(keys)
        out = jax.lax.scan(jax.vmap(step), (s0, policy_keys), a_seq)[1]
        return s0.info[cfg.info_key].prev, out

    def record_one(actions, key) -> Recording:
        acts = np.asarray(actions)
        if acts.ndim != 3:
            raise ValueError(f"actions must have shape (T, E, nu), got {acts.shape}")
        n = acts.shape[1]
        keys = jax.random.split(key, n)
        policy_keys = jax.random.split(jax.random.fold_in(key, 1), n)
        first, (readings, truth, p_live, done) = rollout(keys, policy_keys, acts)
        first, readings = jax.tree.map(np.asarray, (first, readings))
        truth, p_live, done = np.asarray(truth), np.asarray(p_live), np.asarray(done)
        n_sub = truth.shape[2]
        readings = jax.tree.map(in_time_order, readings)
        truth, p_live = in_time_order(truth), in_time_order(p_live)
        valid, readings = valid_and_held(readings, done, n_sub, dt, skip_s)
        return Recording(core, mj_model, first, readings, truth, valid, dt, p_live)

    # What every Recording of it will hold, known before anything is rolled out (tune-env
    # checks its scenes' estimators against each other with it).
    record_one.core, record_one.dt = core, dt
    return record_one


def _check_policy(policy, wrapped) -> None:
    """ValueError naming the wrapped env's observation shapes unless ``policy(obs, key)``
    takes it and returns an action of ``wrapped.action_size`` (shapes only, nothing runs)."""
    import jax

    key = jax.random.PRNGKey(0)
    obs = jax.eval_shape(wrapped.reset, key).obs
    shapes = jax.tree.map(lambda x: tuple(x.shape), obs)
    try:
        action = jax.eval_shape(policy, obs, key)[0]
    except Exception as err:  # noqa: BLE001  any failure to trace is the same mistake
        raise ValueError(
            f"policy: it does not take the wrapped env's observation {shapes} ({err});"
            " pass the ContactObsConfig the policy was trained with as config"
        ) from None
    if tuple(action.shape) != (wrapped.action_size,):
        raise ValueError(
            f"policy: it returns an action of shape {tuple(action.shape)}; the env takes"
            f" ({wrapped.action_size},)"
        )


def valid_and_held(readings, done, n_sub: int, dt: float, skip_s: float):
    """(valid, readings) of a recording (NumPy).

    Args:
      readings: leaves (N, E, ...) of each physics step, ``N = T x n_sub``.
      done: (T, E) the env step's ``done`` (or ``stop``).
      n_sub: physics steps per env step; dt: the physics step, s.
      skip_s: steps before this time are not valid.

    Returns:
      ``valid`` (N, E): from ``skip_s`` on, before the env step of the first ``done`` (that
      step's physics steps left out) and before the first non-finite reading; and the
      readings with every step after an env's last valid one holding that one's (the
      tuning filter runs through masked steps too, so it must never meet a NaN).
    """
    import jax
    import numpy as np

    leaves = jax.tree.leaves(readings)
    shape = leaves[0].shape[:2]
    finite = np.ones(shape, bool)
    for leaf in leaves:
        finite &= np.isfinite(leaf).reshape(shape + (-1,)).all(axis=-1)
    alive = np.repeat(np.cumsum(done, axis=0) == 0, n_sub, axis=0)
    alive &= np.cumsum(~finite, axis=0) == 0
    last = np.maximum(np.cumsum(alive, axis=0) - 1, 0)  # an env's last alive step so far
    held = jax.tree.map(lambda x: np.take_along_axis(x, _expand(last, x), axis=0), readings)
    # Physics step k starts at k dt: it counts from skip_s on (compare_rates' rule).
    valid = alive & (np.arange(shape[0]) >= round(skip_s / dt))[:, None]
    return valid, held


def _expand(index, x):
    return index.reshape(index.shape + (1,) * (x.ndim - index.ndim))


def tuning_data(rec: Recording, chunk: int = 400):
    """A :class:`jax_contact.tune.TuningData` of a recording: each step's estimator inputs
    rebuilt from its readings by ``Core.measure`` (the wrapper's own code), in chunks of
    ``chunk`` steps (one compilation per wrapped env: recordings of one :func:`recorder`
    share it)."""
    import jax
    import numpy as np

    from jax_contact.train.tune_data import in_time_chunks
    from jax_contact.tune import TuningData

    measure = _jitted_measure(rec.core, rec.mj_model)
    prev = jax.tree.map(lambda f, r: np.concatenate([f[None], r[:-1]]), rec.first, rec.readings)
    meas = in_time_chunks(lambda xs: measure(*xs), (prev, rec.readings), chunk)
    mask = np.broadcast_to(rec.valid[..., None], rec.truth.shape)
    return TuningData(meas=meas, truth=rec.truth, mask=np.array(mask))


@functools.lru_cache(maxsize=8)
def _jitted_measure(core, mj_model):
    """``jit(vmap(vmap(core.measure)))`` over (time, env) of (prev, reading), one per wrapped
    env (``Core`` and ``MjModel`` hash by identity)."""
    import jax
    import mujoco
    from mujoco import mjx

    template = mjx.put_data(mj_model, mujoco.MjData(mj_model))

    @jax.jit
    def measure(p, r):
        one = lambda p1, r1: core.measure(template, p1, r1)  # noqa: E731
        return jax.vmap(jax.vmap(one))(p, r)

    return measure


def record_scene(scene: str, seed: int, n_steps: int = STEPS, n_envs: int = ROLLOUTS):
    """(Recording, Scene) of one seed of ``scene`` (key ``PRNGKey(seed)``, as the
    benchmarks' rollouts)."""
    import jax

    sc = load_scene(scene, n_steps, n_envs)
    rec = recorder(sc.env, feedback=sc.feedback, stop=sc.stop, skip_s=sc.skip_s)
    return rec(sc.actions_of(seed), jax.random.PRNGKey(seed)), sc
