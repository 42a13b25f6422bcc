"""Loading and evaluating a trained PPO policy: checkpoints, rollouts, the transfer columns.

A run folder of :func:`jax_contact.train.ppo.train` holds Brax's orbax checkpoints;
:func:`load_policy` reads them (Brax 0.14.2's own loader cannot), :func:`evaluate_policy`
runs the latest one for one episode per env in the contact the policy was trained with,
in another (``observe``: the sim-to-real check), or in a transfer-matrix column
(:mod:`jax_contact.train.transfer`), and reports the return, the falls and the
estimator's metrics over the steps alive. ``jax-contact policy-eval`` is its command.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from mujoco_playground._src import wrapper as pg_wrapper

from jax_contact.train.ppo import (
    ENV_NAME,
    INFO_KEY,
    VARIANTS,
    PPOConfig,
    config_of,
    make_env,
    read_run,
    unfinished_run,
)
from jax_contact.train.tasks import is_playground_task


def _closed_loop_quiet(previous):
    """``sys.unraisablehook`` that drops tensorstore's late reports to a closed event loop.

    When orbax's restore fails, the reads still in flight report to the asyncio loop it has
    already closed: each report raises ``RuntimeError("Event loop is closed")`` in a
    tensorstore thread, which Python prints through ``sys.unraisablehook``, 14-17 tracebacks
    around the one-line error of a damaged checkpoint. Only those are dropped; anything
    else goes to ``previous``."""

    def hook(unraisable):
        err = unraisable.exc_value
        if isinstance(err, RuntimeError) and str(err) == "Event loop is closed":
            return
        previous(unraisable)

    hook.drops_closed_loop = True
    return hook


@contextlib.contextmanager
def _absl_quiet():
    """Orbax's absl WARNING lines (``Failed to get item metadata ...`` on a damaged
    checkpoint) kept off stderr while it loads: the error that follows names the file in
    one line. Errors still print."""
    import logging

    logger = logging.getLogger("absl")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def load_policy(ckpt: str | Path, *, deterministic: bool = True, parts: bool = False):
    """A checkpoint's policy ``(obs, key) -> (action, extras)`` and its observation shapes.

    Brax 0.14.2's ``ppo.checkpoint.load_policy`` cannot read the configuration its own
    ``save`` writes when a kernel-initialiser argument is None (``KeyError: None``), which
    is the default for ``mean_kernel_init_fn``; this reads the same files (the network
    configuration JSON and the orbax parameters) and builds the same network.

    With ``parts``, ``(make_policy, params, sizes)`` instead: Brax's
    ``make_inference_fn(network)`` and the parameters apart, so that one compiled rollout
    can take the parameters of several checkpoints as arguments (:mod:`jax_contact.train.transfer`).

    Returns:
      (policy, {observation key: shape}).
    """
    from brax.training import networks as brax_networks
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo import checkpoint as ppo_checkpoint
    from brax.training.agents.ppo import networks as ppo_networks

    from jax_contact.train.run_folder import CHECKPOINT_CONFIG

    ckpt = Path(ckpt).resolve()  # orbax refuses relative paths
    path = ckpt / CHECKPOINT_CONFIG
    if not path.is_file():
        raise FileNotFoundError(f"no {CHECKPOINT_CONFIG} in {ckpt}: not a Brax PPO checkpoint")
    damaged = "the checkpoint is damaged or incomplete; train again with --overwrite"
    try:
        cfg = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path} is not JSON ({err}): {damaged}") from None
    needed = ("network_factory_kwargs", "observation_size", "action_size", "normalize_observations")
    missing = [k for k in needed if not isinstance(cfg, dict) or k not in cfg]
    if missing or not isinstance(cfg["network_factory_kwargs"], dict):
        raise ValueError(f"{path} is not a Brax PPO network config (missing {missing}): {damaged}")
    kwargs = {k: v for k, v in cfg["network_factory_kwargs"].items() if v is not None}
    if "activation" in kwargs:
        kwargs["activation"] = brax_networks.ACTIVATION[kwargs["activation"]]
    for k, v in kwargs.items():
        if k.endswith("kernel_init_fn"):
            kwargs[k] = brax_networks.KERNEL_INITIALIZER[v]
    raw = cfg["observation_size"]
    if isinstance(raw, dict) and "shape" in raw and "dtype" in raw:  # one array, as saved
        raw = raw["shape"]
    if isinstance(raw, dict):
        sizes = {k: tuple(v["shape"] if isinstance(v, dict) else v) for k, v in raw.items()}
        net_sizes = sizes
    else:  # an array observation (a Brax PipelineEnv's, e.g. the hop task): "state"
        sizes = {"state": tuple(raw) if isinstance(raw, list) else (int(raw),)}
        net_sizes = sizes["state"][0] if len(sizes["state"]) == 1 else sizes["state"]
    net = ppo_networks.make_ppo_networks(
        net_sizes,
        cfg["action_size"],
        preprocess_observations_fn=(
            running_statistics.normalize if cfg["normalize_observations"] else lambda x, _: x
        ),
        **kwargs,
    )
    previous = sys.unraisablehook
    if not getattr(previous, "drops_closed_loop", False):
        sys.unraisablehook = _closed_loop_quiet(previous)
    try:
        with warnings.catch_warnings(), _absl_quiet():
            # Orbax's note on every restore without shardings (it reads them from the
            # checkpoint): nothing a user can act on; the parameters land on the default device.
            warnings.filterwarnings("ignore", message="Sharding info not provided")
            params = ppo_checkpoint.load(ckpt)
        sys.unraisablehook = previous
    except Exception as err:  # orbax / tensorstore: a wall of JSON specs; one line instead
        # The hook stays: the failed restore's reads report after this (_closed_loop_quiet).
        first = " ".join(str(err).split())
        short = first if len(first) <= 240 else first[:240] + " ..."
        raise ValueError(
            f"the parameters in {ckpt} cannot be read ({type(err).__name__}: {short}): {damaged}"
        ) from None
    if parts:
        return ppo_networks.make_inference_fn(net), params, sizes
    return ppo_networks.make_inference_fn(net)(params, deterministic=deterministic), sizes


def latest_checkpoint(run_dir: str | Path) -> Path:
    """The checkpoint folder with the most steps in ``<run_dir>/checkpoints`` among those
    Brax finished saving (:func:`jax_contact.train.run_folder.complete_checkpoints`: a save
    stopped midway is passed over for the one before it)."""
    from jax_contact.train.run_folder import CHECKPOINT_CONFIG, complete_checkpoints, earlier_path

    folder = Path(run_dir) / "checkpoints"
    steps = complete_checkpoints(run_dir)
    if not steps:
        earlier = earlier_path(Path(run_dir))
        started = sorted(p.name for p in folder.glob("*") if p.is_dir() and p.name.isdigit())
        if earlier.exists():  # an --overwrite run killed before its first checkpoint
            why = (
                f"the run it replaced is in {earlier} (an --overwrite run was stopped before"
                f" its first checkpoint): move it back to {Path(run_dir)} to evaluate it, or"
                " delete it and train again"
            )
        elif started:
            why = (
                f"its only checkpoint folder{'s' if len(started) > 1 else ''}"
                f" ({', '.join(started)}) {'were' if len(started) > 1 else 'was'} not finished"
                f" (no readable {CHECKPOINT_CONFIG}: the save was stopped); train again"
                " with --overwrite"
            )
        elif unfinished_run(Path(run_dir)):
            why = (
                "its training stopped before the first checkpoint (run.json: finished false);"
                " train again with --overwrite"
            )
        elif (Path(run_dir) / "run.json").is_file():
            why = (
                "run.json says its training finished, but its checkpoints are gone; train"
                " again with --overwrite"
            )
        else:
            why = "train first (jax-contact train)"
        raise FileNotFoundError(f"no checkpoint in {folder}: {why}")
    return steps[-1]


# ------------------------------------------------------------------------ evaluate


def column_env(column: str, cfg: PPOConfig, env_name: str = ENV_NAME):
    """The unbatched Playground env of a transfer-matrix column for a run trained with
    ``cfg``.

    Args:
      column: a name of :data:`jax_contact.train.transfer.COLUMNS` or a variant
        (:data:`jax_contact.train.ppo.VARIANTS`);
        :func:`jax_contact.train.transfer.column_setting` maps it to (observe, sensor
        preset, extra env steps of latency).
      cfg: the run's configuration (its ``sensor`` is the training preset, its ``reward``
        the reward).
      env_name: the Playground env the run trained in (``run.json``'s ``env``).
    """
    from jax_contact.train import transfer

    observe, preset, extra = transfer.column_setting(column, cfg.sensor)
    return make_env(
        observe,
        sensor=preset,
        reward=cfg.reward,
        extra_latency=extra,
        params=cfg.estimator_params,
        env_name=env_name,
    )


def policy_rollout(env, make_policy, n_envs: int, episode_length: int) -> Callable:
    """A jitted rollout of a checkpoint's deterministic policy in ``env``, one episode per env.

    The parameters are an argument, so checkpoints of the same network share one
    compilation (:mod:`jax_contact.train.transfer`).

    Args:
      env: the unbatched env with the contact wrapper (:func:`jax_contact.train.ppo.make_env`).
      make_policy: ``(params, deterministic) -> policy``, as ``load_policy(parts=True)``.
      n_envs: episodes, run in parallel.
      episode_length: env steps per episode (Playground's training wrappers truncate there).

    Returns:
      ``rollout(params, key) -> (ret, p, truth, alive, fell)``: ``ret`` (n_envs,) the
      return over the steps alive; over (episode_length, n_envs[, n_feet]): the estimator's
      P(contact), the simulator's contact, alive before the step, and terminated (not
      truncated) at it.
    """
    benv = pg_wrapper.wrap_for_brax_training(env, episode_length=episode_length)

    @jax.jit
    def rollout(params, key):
        policy = make_policy(params, deterministic=True)
        k_reset, k_act = jax.random.split(key)
        state = benv.reset(jax.random.split(k_reset, n_envs))

        def body(carry, k):
            s, alive, ret = carry
            act, _ = policy(s.obs, k)
            s = benv.step(s, act)
            out = (s.info[INFO_KEY].diag.p_contact, s.info[INFO_KEY + "_truth"], alive)
            ret = ret + jnp.where(alive, s.reward, 0.0)
            terminated = (s.done > 0) & (s.info["truncation"] == 0)
            return (s, alive & ~(s.done > 0), ret), out + (alive & terminated,)

        carry = (state, jnp.ones(n_envs, bool), jnp.zeros(n_envs))
        (_, _, ret), outs = jax.lax.scan(body, carry, jax.random.split(k_act, episode_length))
        return (ret, *outs)

    return rollout


class ColumnEvaluator:
    """Checkpoints of a Playground env (Go1's joystick, ...) evaluated in transfer-matrix
    columns, sharing compiled rollouts.

    One env per column (:func:`column_env`) and one compiled :func:`policy_rollout` per
    (column, ``make_policy``): pass the same ``make_policy`` for checkpoints of the same
    network and each column compiles once for all of them.

    Args:
      cfg: the runs' configuration (sensor preset, reward, episode length).
      n_envs: episodes per evaluation.
      episode_length: env steps per episode; None: ``cfg.episode_length``.
      env_name: the env the runs trained in (``run.json``'s ``env``).
    """

    def __init__(
        self,
        cfg: PPOConfig,
        n_envs: int,
        episode_length: int | None = None,
        env_name: str = ENV_NAME,
    ):
        self.cfg, self.n_envs, self.env_name = cfg, int(n_envs), env_name
        self.episode_length = int(episode_length or cfg.episode_length)
        self._envs: dict = {}
        self._fns: dict = {}

    def env(self, column: str):
        if column not in self._envs:
            self._envs[column] = column_env(column, self.cfg, self.env_name)
        return self._envs[column]

    def evaluate(self, run_dir: str | Path, column: str, seed: int, loaded=None) -> dict:
        """The latest checkpoint of ``run_dir`` in ``column`` (:func:`evaluate_policy`'s dict).

        Args:
          run_dir: a run folder of this evaluator's env.
          column: as :func:`column_env`.
          seed: seeds the episodes.
          loaded: ``load_policy(ckpt, parts=True)`` of its latest checkpoint, if loaded.

        Raises:
          ValueError: the column's observation does not fit the checkpoint's network.
        """
        run_dir = Path(run_dir)
        run = read_run(run_dir)
        ckpt = latest_checkpoint(run_dir)
        make_policy, params, sizes = loaded or load_policy(ckpt, parts=True)
        env = self.env(column)
        have = policy_obs_shape(env)
        if tuple(sizes["state"]) != have:
            raise ValueError(
                f"observing {column!r} gives a policy observation of shape {have}; the"
                f" checkpoint {ckpt} (trained with {run['variant']!r}) takes"
                f" {tuple(sizes['state'])}"
            )
        key = (column, id(make_policy))
        if key not in self._fns:  # keeps make_policy alive, so its id is not reused
            self._fns[key] = (policy_rollout(env, make_policy, self.n_envs, self.episode_length),)
            self._fns[key] += (make_policy,)
        rollout = self._fns[key][0]
        t0 = time.perf_counter()
        ret, p, truth, alive, fell = jax.device_get(rollout(params, jax.random.PRNGKey(seed)))
        wall = time.perf_counter() - t0
        return {
            "run": str(run_dir.absolute()),
            "checkpoint": str(ckpt.absolute()),
            "trained_with": run["variant"],
            "run_finished": run.get("finished", True),
            "observed": column,
            "n_episodes": self.n_envs,
            **rollout_metrics(ret, p, truth, alive, fell, dt=float(env.dt)),
            "wall_s": round(wall, 1),
        }


def policy_obs_shape(env) -> tuple[int, ...]:
    """The shape of what the policy reads from ``env``'s observation: the dict's
    ``"state"`` (Go1, the humanoids), or the whole array (Spot's and H1's envs observe one
    array), as :func:`load_policy` names a checkpoint's ``"state"``."""
    size = env.observation_size
    if isinstance(size, dict):
        return tuple(size["state"])
    return tuple(size) if isinstance(size, tuple) else (int(size),)


def rollout_metrics(ret, p, truth, alive, fell, *, dt: float) -> dict:
    """:func:`evaluate_policy`'s numbers from a :func:`policy_rollout`'s arrays.

    Args:
      ret: (n,) returns; p, truth: (T, n, n_feet) P(contact) and contact; alive, fell:
        (T, n) bool, alive before each step and terminated at it.
      dt: the env step, s (the estimator's metrics' time unit).

    Returns:
      ``return_mean``, ``return_std``, ``episode_length_mean`` (steps alive), ``fell``
      (fraction of episodes terminated early) and ``contact`` (the estimator's metrics over
      the steps alive, :func:`jax_contact.metrics.evaluate`).
    """
    from jax_contact import metrics

    ret, p, alive = np.asarray(ret), np.asarray(p), np.asarray(alive, bool)
    valid = np.broadcast_to(alive[..., None], p.shape)
    m = metrics.evaluate(p, np.asarray(truth, bool), valid, dt=float(dt))
    return {
        "return_mean": float(np.mean(ret)),
        "return_std": float(np.std(ret)),
        "episode_length_mean": float(np.mean(alive.sum(axis=0))),
        "fell": float(np.mean(np.asarray(fell, bool).any(axis=0))),
        "contact": m.as_dict(),
    }


def evaluate_policy(
    run_dir: str | Path,
    *,
    observe: str | None = None,
    column: str | None = None,
    n_envs: int = 64,
    episode_length: int | None = None,
    seed: int = 12345,
) -> dict:
    """Runs a run's latest checkpoint (deterministic policy) for one episode per env.

    Args:
      run_dir: a run folder written by :func:`jax_contact.train.ppo.train`.
      observe: the contact the policy sees now (:data:`jax_contact.train.ppo.VARIANTS`,
        the training sensors); None: the one it was trained with. ``"estimate"`` for a
        ``"truth"`` run is the sim-to-real check.
      column: instead of ``observe``, a transfer-matrix column
        (:data:`jax_contact.train.transfer.COLUMNS`): ``estimate_harsh`` (the ``harsh``
        sensors), ``estimate_lat1``/``estimate_lat2`` (the training sensors 1 or 2 env
        steps late), ...
      n_envs: episodes, run in parallel.
      episode_length: env steps per episode; None: the training configuration's.
      seed: seeds the episodes (commands, noise, the estimator's sensors).

    Returns:
      ``return_mean``, ``return_std``, ``episode_length_mean`` (steps before termination or
      the end), ``fell`` (fraction of episodes that terminated early), and ``contact``: the
      estimator's metrics (:func:`jax_contact.metrics.evaluate`) against the simulator's
      contact over the steps alive, plus the checkpoint, what it was trained with and the
      column it ``observed``. A hop run (``run.json``'s ``task``) gets its own metrics
      (:func:`jax_contact.train.transfer.evaluate_run`).

    Raises:
      FileNotFoundError: no run.json or checkpoint.
      ValueError: both ``observe`` and ``column``, an unknown one, or an observation the
        checkpoint's network cannot take.
    """
    if observe is not None and column is not None:
        raise ValueError(
            f"pass observe or column, not both (got observe={observe!r}, column={column!r})"
        )
    if observe is not None and observe not in VARIANTS:
        raise ValueError(f"observe must be one of {VARIANTS}, got {observe!r}")
    run_dir = Path(run_dir)
    run = read_run(run_dir)
    ckpt = latest_checkpoint(run_dir)  # before building envs: FileNotFoundError without one
    if run.get("finished") is False:  # every task's run (a hop's was evaluated silently)
        warnings.warn(
            f"{run_dir}'s training did not finish (run.json: finished false; interrupted, or"
            f" still training): evaluating its latest checkpoint, {ckpt.name}",
            stacklevel=2,
        )
    if not is_playground_task(run.get("task", "go1")):  # a hop: its own evaluation
        from jax_contact.train import transfer

        return transfer.evaluate_run(
            run_dir,
            observe=observe,
            column=column,
            n_envs=n_envs,
            episode_length=episode_length,
            seed=seed,
        )
    ev = ColumnEvaluator(config_of(run), n_envs, episode_length, run.get("env", ENV_NAME))
    return ev.evaluate(run_dir, column or observe or run["variant"], seed)


def format_evaluation(results: Sequence[dict]) -> str:
    """A table of :func:`evaluate_policy` results."""
    lines = [
        f"{'trained with':>12s} {'observed':>14s} {'return':>16s} {'ep. length':>10s}"
        f" {'fell':>5s} {'estimator acc':>13s} {'estimator F1':>12s}"
    ]
    for r in results:
        c = r["contact"]
        lines.append(
            f"{r['trained_with']:>12s} {r['observed']:>14s}"
            f" {r['return_mean']:8.2f} +- {r['return_std']:5.2f} {r['episode_length_mean']:10.1f}"
            f" {r['fell']:5.2f} {c['accuracy']:13.3f} {c['f1']:12.3f}"
        )
    lines.append(
        "return: episode sum, mean +- std over episodes; fell: share of episodes that fell;"
        " estimator acc, F1: per foot-step against the simulator's contact"
    )
    return "\n".join(lines)
