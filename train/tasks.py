"""The tasks ``jax-contact train`` can train, and their frozen PPO configurations.

- ``"go1"``: MuJoCo Playground's Go1 joystick (:mod:`jax_contact.train.ppo`; configurations
  :data:`jax_contact.train.ppo.SMALL`, :data:`jax_contact.train.ppo.FULL`).
- ``"hop"``: the planar leg hopping to a commanded apex height (:mod:`jax_contact.envs.hop_task`),
  where contact timing matters; configuration :data:`HOP_SMALL` (this 2-core CPU) and
  :data:`HOP_REDUCED` (the reduced run of docs/training_hop.md).
- ``"hop_blind"``: the same hop without the rail (base) velocity in the observation
  (:data:`jax_contact.envs.hop_task.HOP_BLIND`), so that stance cannot be read off the
  kinematics of one observation; the same configurations.

A :class:`Task` says how :func:`jax_contact.train.ppo.train` builds the env of a variant and wraps
it for training; everything else (the PPO call, the run folder, checkpoints, curves) is the
same for both.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

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


def _go1_env(observe: str, cfg: PPOConfig):
    from jax_contact.train import ppo

    return ppo.make_env(observe, sensor=cfg.sensor, reward=cfg.reward, params=cfg.estimator_params)


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

    return Task("go1", ppo.ENV_NAME, tuple(ppo.CONFIGS.items()), _go1_env, _go1_wrap)


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

TASK_NAMES = ("go1", "hop", "hop_blind")


def get_task(name: str) -> Task:
    """The :class:`Task` called ``name`` (one of :data:`TASK_NAMES`)."""
    if name == "go1":
        return _go1()
    if name == "hop":
        return HOP_TASK
    if name == "hop_blind":
        return HOP_BLIND_TASK
    raise ValueError(f"task must be one of {TASK_NAMES}, got {name!r}")
