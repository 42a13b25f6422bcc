"""The tasks ``jax-contact train`` can train, and their frozen PPO configurations.

- ``"go1"``: MuJoCo Playground's Go1 joystick (:mod:`jax_contact.train.ppo`; configurations
  :data:`jax_contact.train.ppo.SMALL`, :data:`jax_contact.train.ppo.FULL`).
- ``"hop"``: the planar leg hopping to a commanded apex height (:mod:`jax_contact.envs.hop_task`),
  where contact timing matters; configuration :data:`HOP_SMALL` (this 2-core CPU) and
  :data:`HOP_REDUCED` (the reduced run of docs/training_hop.md).
- ``"hop_blind"``: the same hop without the rail (base) velocity in the observation
  (:data:`jax_contact.envs.hop_task.HOP_BLIND`), so that stance cannot be read off the
  kinematics of one observation; the same configurations.
- any other MuJoCo Playground locomotion env that loads offline
  (:data:`PLAYGROUND_TASK_NAMES`: Spot, the humanoids, Go1's getup and handstand, ...),
  by its registry name, with the contact wrapper as for Go1. Its configurations come from
  Playground's published one for that env (:func:`playground_configs`): ``"full"`` is it,
  ``"small"`` is :data:`jax_contact.train.ppo.SMALL`'s size and networks with the env's
  own PPO hyper-parameters and episode length. ``"Go1JoystickFlatTerrain"`` is ``"go1"``.

A :class:`Task` says how :func:`jax_contact.train.ppo.train` builds the env of a variant and wraps
it for training; everything else (the PPO call, the run folder, checkpoints, curves) is the
same for both.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

from jax_contact.train.cli_args import HOP_TASKS, PLAYGROUND_TASKS
from jax_contact.train.ppo import PPOConfig

# Sized for the 2-core CPU: a 7-number observation (5 leg + command + 1 contact), small
# networks, 3 s episodes (300 steps of 10 ms). 1,228,800 steps = 6 epochs of 20 training
# steps of 10,240 env steps. The reward is the env's own (HopEnv); `reward` is unused.
HOP_SMALL = PPOConfig(
    num_timesteps=1_228_800,
    num_envs=128,
    batch_size=128,
    num_minibatches=4,
    unroll_length=20,
    num_updates_per_batch=4,
    num_evals=7,
    num_eval_envs=32,
    episode_length=300,
    learning_rate=1e-3,
    entropy_cost=1e-2,
    discounting=0.98,
    policy_hidden=(64, 64),
    value_hidden=(64, 64),
)

# The reduced run that fitted the session (docs/training_hop.md): a third of HOP_SMALL.
HOP_REDUCED = dataclasses.replace(HOP_SMALL, num_timesteps=409_600, num_evals=5)


@dataclasses.dataclass(frozen=True)
class Task:
    """How to train one task.

    Attributes:
      name: the task's name (``--task``).
      env_name: the env's name in ``run.json`` and plot titles.
      configs: configuration name -> :class:`jax_contact.train.ppo.PPOConfig`, as pairs.
      make_env: ``(observe, cfg) -> env``: the unbatched env with the contact wrapper.
      wrap_env_fn: the training wrappers (``ppo.train``'s ``wrap_env_fn``); None: Brax's.
    """

    name: str
    env_name: str
    configs: tuple[tuple[str, PPOConfig], ...]
    make_env: Callable
    wrap_env_fn: Callable | None

    def config(self, name: str) -> PPOConfig:
        d = dict(self.configs)
        if name not in d:
            raise ValueError(f"task {self.name!r} has configurations {tuple(d)}, not {name!r}")
        return d[name]


def _playground_env(env_name: str, observe: str, cfg: PPOConfig):
    from jax_contact.train import ppo

    return ppo.make_env(
        observe,
        sensor=cfg.sensor,
        reward=cfg.reward,
        params=cfg.estimator_params,
        env_name=env_name,
    )


def _go1_wrap(env, **kwargs):
    from mujoco_playground._src import wrapper as pg_wrapper

    return pg_wrapper.wrap_for_brax_training(env, **kwargs)


def _hop_env(task_name: str, observe: str, cfg: PPOConfig):
    from jax_contact.envs import hop_task

    if cfg.estimator_params is not None:
        raise ValueError(
            f"estimator_params: the {task_name} task runs the planar leg's own estimator"
            " (jax_contact.envs.hop_task); a parameter file is taken by the go1 task only"
        )
    task = dataclasses.replace(
        hop_task.task_config(task_name), episode_length=cfg.episode_length, sensor=cfg.sensor
    )
    return hop_task.make_hop_env(observe, task)


def _go1() -> Task:
    from jax_contact.train import ppo

    env = functools.partial(_playground_env, ppo.ENV_NAME)
    return Task("go1", ppo.ENV_NAME, tuple(ppo.CONFIGS.items()), env, _go1_wrap)


def _brax_ppo_default(name: str):
    """The default of ``brax.training.agents.ppo.train``'s argument ``name``: what
    Playground's training script gets where an env's configuration leaves it out."""
    import inspect

    from brax.training.agents.ppo import train as ppo_train

    return inspect.signature(ppo_train.train).parameters[name].default


def playground_configs(env_name: str) -> tuple[tuple[str, PPOConfig], ...]:
    """``("small", ...), ("full", ...)`` of a Playground locomotion env.

    ``"full"`` is Playground's published PPO configuration of the env
    (``mujoco_playground.config.locomotion_params.brax_ppo_config``; a field it leaves out
    takes Brax PPO's default, as in Playground's training script), for a GPU. ``"small"``
    is :data:`jax_contact.train.ppo.SMALL` (this 2-core CPU: its size, networks and
    unclipped reward) with the env's PPO hyper-parameters, episode length and observation
    keys. For Go1's joystick these are :data:`~jax_contact.train.ppo.SMALL` and
    :data:`~jax_contact.train.ppo.FULL` (tests/test_train_ppo.py).

    Raises:
      ValueError: a configuration with an ``action_repeat`` other than 1 (the wrapper's
        estimator runs on the env's own steps).
    """
    from mujoco_playground.config import locomotion_params

    from jax_contact.train import ppo

    ref = locomotion_params.brax_ppo_config(env_name)
    if ref.get("action_repeat", 1) != 1:
        raise ValueError(f"{env_name}'s PPO configuration has action_repeat {ref.action_repeat}")

    def get(name):
        return ref[name] if name in ref else _brax_ppo_default(name)

    net = ref.network_factory
    own = dict(
        episode_length=int(ref.episode_length),
        learning_rate=float(get("learning_rate")),
        entropy_cost=float(get("entropy_cost")),
        discounting=float(get("discounting")),
        reward_scaling=float(get("reward_scaling")),
        max_grad_norm=None if get("max_grad_norm") is None else float(get("max_grad_norm")),
        clipping_epsilon=float(get("clipping_epsilon")),
        normalize_observations=bool(get("normalize_observations")),
        policy_obs_key=str(net.get("policy_obs_key", "state")),
        value_obs_key=str(net.get("value_obs_key", "state")),
    )
    full = ppo.PPOConfig(
        num_timesteps=int(ref.num_timesteps),
        num_envs=int(ref.num_envs),
        batch_size=int(get("batch_size")),
        num_minibatches=int(get("num_minibatches")),
        unroll_length=int(get("unroll_length")),
        num_updates_per_batch=int(get("num_updates_per_batch")),
        num_evals=int(get("num_evals")),
        num_eval_envs=int(get("num_eval_envs")),
        num_resets_per_eval=int(get("num_resets_per_eval")),
        policy_hidden=tuple(net.policy_hidden_layer_sizes),
        value_hidden=tuple(net.value_hidden_layer_sizes),
        **own,
    )
    return (("small", dataclasses.replace(ppo.SMALL, **own)), ("full", full))


def _playground(env_name: str) -> Task:
    env = functools.partial(_playground_env, env_name)
    return Task(env_name, env_name, playground_configs(env_name), env, _go1_wrap)


HOP_TASK = Task(
    "hop",
    "PlanarLegHop",
    (("small", HOP_SMALL), ("reduced", HOP_REDUCED)),
    functools.partial(_hop_env, "hop"),
    None,
)
HOP_BLIND_TASK = dataclasses.replace(
    HOP_TASK,
    name="hop_blind",
    env_name="PlanarLegHopBlind",
    make_env=functools.partial(_hop_env, "hop_blind"),
)

HOP_TASK_NAMES = HOP_TASKS
# The Playground locomotion envs that load offline (jax_contact.envs.playground_offline;
# tests/test_cli.py checks the list against it), less the go1 task's.
PLAYGROUND_TASK_NAMES = PLAYGROUND_TASKS
TASK_NAMES = ("go1", *HOP_TASK_NAMES, *PLAYGROUND_TASK_NAMES)


def is_playground_task(name: str) -> bool:
    """Whether the task ``name`` (a ``run.json``'s ``task``; absent: ``"go1"``) trains a
    Playground env, whose runs :mod:`jax_contact.train.policy_eval` evaluates (the hop
    tasks have their own evaluation)."""
    return name not in HOP_TASK_NAMES


def get_task(name: str) -> Task:
    """The :class:`Task` called ``name`` (one of :data:`TASK_NAMES`;
    ``"Go1JoystickFlatTerrain"`` is ``"go1"``)."""
    if name in ("go1", "Go1JoystickFlatTerrain"):
        return _go1()
    if name == "hop":
        return HOP_TASK
    if name == "hop_blind":
        return HOP_BLIND_TASK
    if name in PLAYGROUND_TASK_NAMES:
        return _playground(name)
    raise ValueError(f"task must be one of {TASK_NAMES}, got {name!r}")
