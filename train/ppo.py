"""PPO on a quadruped with three contact observations: none, ground truth, estimated.

The task is MuJoCo Playground's Go1 joystick on flat terrain (track a random base velocity
command; Playground's own rewards, terminations and observation noise), built offline by
:mod:`jax_contact.envs.playground_offline` with MJX's JAX implementation. The contact wrapper
(:mod:`jax_contact.envs.wrapper`, at the physics rate, its default) appends one
number per foot to the policy's ``"state"`` observation:

- ``"none"``: nothing (the policy Playground trains);
- ``"truth"``: the simulator's contact flag (the privileged baseline no robot has);
- ``"estimate"``: the estimator's P(contact) from simulated, noisy proprioception
  (``anymal_like`` sensors), what the policy will also see on the robot.

The estimator runs in all three, so the training cost is the same and its accuracy is in the
metrics. The critic sees Playground's ``"privileged_state"`` in all three (it already holds
the true contact; the critic is not deployed). The sim-to-real check
(:func:`train_variants`) evaluates the policy trained on ``"truth"`` with ``"estimate"``
features in the same slots, next to the policy trained on ``"estimate"``.

Training is ``brax.training.agents.ppo.train`` with Playground's training wrappers; only the
configuration is ours: :data:`SMALL` (this 2-core CPU, under 20 minutes per variant) and
:data:`FULL` (Playground's published Go1 configuration, for a GPU). Every other Playground
locomotion env that loads offline trains the same way, by its name
(:mod:`jax_contact.train.tasks`, :func:`~jax_contact.train.tasks.playground_configs`).

A run folder ``<out>/<variant>/`` holds ``run.json`` (variant and configuration),
``progress.csv`` (one row per evaluation, rewritten atomically after each),
``training.csv`` (Brax's training-episode means, every two training steps: only its
header for a shorter run, e.g. ``--config tiny``), ``reward.png`` and
``checkpoints/<step>/`` (Brax's orbax checkpoints with their network configuration, loaded
by :func:`jax_contact.train.policy_eval.load_policy`; Brax 0.14.2's own loader cannot read
them, see there).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import io
import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import numpy as np
from mujoco_playground._src import wrapper as pg_wrapper

from jax_contact.train.cli_args import check_run_folder, unfinished_run  # noqa: F401  (re-exported)
from jax_contact.train.interrupt import set_kept
from jax_contact.train.run_folder import SUMMARY_FILES, EarlierRun

VARIANTS = ("none", "truth", "estimate")
REWARDS = ("playground", "unclipped")
ENV_NAME = "Go1JoystickFlatTerrain"
INFO_KEY = "contact_est"
CSV_FIELDS = (
    "step",
    "wall_s",
    "eval_reward",
    "eval_reward_std",
    "eval_episode_length",
    "eval_contact_accuracy",
)
# training.csv: Brax's running means over the last 100 finished training episodes
# (stochastic policy, exploration noise included): the objective PPO climbs.
TRAIN_FIELDS = ("step", "wall_s", "train_episode_return", "train_episode_length")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """A PPO run: ``brax.training.agents.ppo.train``'s arguments, the networks and the env.

    Attributes:
      num_timesteps: environment steps of training.
      num_envs: parallel training environments.
      batch_size, num_minibatches, unroll_length, num_updates_per_batch: Brax PPO's batch
        layout: one training step collects ``batch_size * num_minibatches * unroll_length``
        env steps.
      num_evals: evaluations (the first before any training), each a row of the CSV; each
        after training has begun also writes a checkpoint.
      num_eval_envs: environments per evaluation (one episode each).
      episode_length: env steps per episode (Go1: 20 ms each).
      learning_rate, entropy_cost, discounting, reward_scaling, max_grad_norm,
      clipping_epsilon, normalize_observations: PPO's.
      policy_hidden, value_hidden: MLP layer sizes.
      distribution: the policy's action distribution, ``"tanh_normal"`` (Brax's default:
        one MLP outputs mean and scale) or ``"normal"`` (a Gaussian with a learned,
        state-independent std, as rsl_rl's legged_gym policies; the next two fields
        apply to it only).
      init_noise_std: initial std of the ``"normal"`` policy.
      zero_init_mean: initialise the ``"normal"`` policy's mean layer to zero, so that the
        untrained deterministic policy holds the default pose instead of falling over.
      num_resets_per_eval: Brax's host-side resets per evaluation epoch.
      sensor: sensor preset of the estimator's inputs (:data:`jax_contact.envs.sensors.PRESETS`).
      reward: ``"playground"`` (the env's reward: the scaled terms summed, times ``dt``,
        clipped below at 0) or ``"unclipped"`` (the same sum without the clip,
        :class:`UnclippedReward`).
      estimator_params: the wrapper's estimator parameters, a parameter file or a shipped
        preset (``ContactObsConfig.params``, its calibration map applied; e.g.
        ``"go1_playground"``), or None for the wrapper's defaults. Playground tasks only
        (the hop runs the planar leg's own estimator).
      policy_obs_key, value_obs_key: the dict observation's entries the policy and the
        critic read (Playground's configuration of the env: Go1's critic reads
        ``"privileged_state"``, Spot's and H1's ``"state"``). The contact features are in
        ``"state"``.
    """

    num_timesteps: int
    num_envs: int
    batch_size: int
    num_minibatches: int
    unroll_length: int
    num_updates_per_batch: int
    num_evals: int
    num_eval_envs: int
    episode_length: int = 1000
    learning_rate: float = 3e-4
    entropy_cost: float = 1e-2
    discounting: float = 0.97
    reward_scaling: float = 1.0
    max_grad_norm: float | None = 1.0
    clipping_epsilon: float = 0.3
    normalize_observations: bool = True
    policy_hidden: tuple[int, ...] = (512, 256, 128)
    value_hidden: tuple[int, ...] = (512, 256, 128)
    distribution: str = "tanh_normal"
    init_noise_std: float = 1.0
    zero_init_mean: bool = False
    num_resets_per_eval: int = 0
    sensor: str = "anymal_like"
    reward: str = "playground"
    estimator_params: str | None = None
    policy_obs_key: str = "state"
    value_obs_key: str = "privileged_state"

    @property
    def steps_per_training_step(self) -> int:
        return self.batch_size * self.num_minibatches * self.unroll_length

    def validate(self) -> None:
        """Raises ValueError naming the field if Brax PPO would refuse or misbehave."""
        for f in (
            "num_timesteps",
            "num_envs",
            "batch_size",
            "num_minibatches",
            "unroll_length",
            "num_updates_per_batch",
            "num_evals",
            "num_eval_envs",
            "episode_length",
        ):
            v = getattr(self, f)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"PPOConfig.{f} must be an int >= 1, got {v!r}")
        if self.distribution not in ("tanh_normal", "normal"):
            raise ValueError(
                f"PPOConfig.distribution must be 'tanh_normal' or 'normal', got"
                f" {self.distribution!r}"
            )
        if self.reward not in REWARDS:
            raise ValueError(f"PPOConfig.reward must be one of {REWARDS}, got {self.reward!r}")
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(
                f"PPOConfig: batch_size * num_minibatches ({self.batch_size} *"
                f" {self.num_minibatches}) must be a multiple of num_envs ({self.num_envs})"
            )
        if self.num_timesteps < self.steps_per_training_step:
            raise ValueError(
                f"PPOConfig.num_timesteps ({self.num_timesteps}) is less than one training"
                f" step ({self.steps_per_training_step} env steps)"
            )


def brax_timesteps(cfg: PPOConfig) -> int:
    """The env steps ``brax.training.agents.ppo.train`` actually trains for ``cfg``.

    Brax (0.14) trains ``num_evals - 1`` epochs (at least 1), each of ``max(1,
    num_resets_per_eval)`` blocks of ``ceil(num_timesteps / (epochs * blocks *
    steps_per_training_step))`` training steps, so ``num_timesteps`` is rounded *up* to a
    multiple of ``epochs * blocks * steps_per_training_step``: 40,960 steps with SMALL's 6
    epochs of 40,960-step training steps train 245,760.
    """
    epochs = max(cfg.num_evals - 1, 1)
    blocks = max(cfg.num_resets_per_eval, 1)
    per_block = -(-cfg.num_timesteps // (epochs * blocks * cfg.steps_per_training_step))
    return epochs * blocks * per_block * cfg.steps_per_training_step


def fit_timesteps(cfg: PPOConfig, requested: int) -> tuple[PPOConfig, str | None]:
    """``cfg`` with ``num_timesteps`` set so that Brax trains ``requested`` steps exactly.

    Brax rounds up to whole epochs (:func:`brax_timesteps`); to train what was asked, this
    lowers ``num_evals`` to the most evaluations (at most ``cfg``'s) that split the
    training steps evenly. Only when ``requested`` is not a whole number of training
    steps (``steps_per_training_step``, times ``num_resets_per_eval`` if set) is it
    rounded up to the next one.

    Args:
      cfg: the configuration.
      requested: env steps to train, an int >= 1.

    Returns:
      (the configuration, for which ``brax_timesteps`` is the number trained; a one-line
      note of what differs from the request, or None when nothing does).

    Raises:
      ValueError: ``requested`` is not an int >= 1.
    """
    if isinstance(requested, bool) or not isinstance(requested, int) or requested < 1:
        raise ValueError(f"timesteps must be an int >= 1, got {requested!r}")
    step = cfg.steps_per_training_step
    blocks = max(cfg.num_resets_per_eval, 1)
    n_steps = -(-requested // step)  # training steps
    n_steps = -(-n_steps // blocks) * blocks  # each epoch holds `blocks` of them
    most = max(cfg.num_evals - 1, 1)
    epochs = max(e for e in range(1, most + 1) if n_steps % (e * blocks) == 0)
    trained = n_steps * step
    num_evals = cfg.num_evals if epochs == most else epochs + 1
    fitted = dataclasses.replace(cfg, num_timesteps=trained, num_evals=num_evals)
    if trained == requested and num_evals == cfg.num_evals:
        return fitted, None
    note = f"training {trained:,d} env steps"
    if trained != requested:
        note += (
            f" ({requested:,d} rounded up to a multiple of {step * blocks:,d}, Brax PPO's"
            " training step)"
        )
    if num_evals != cfg.num_evals:
        unfitted = brax_timesteps(dataclasses.replace(cfg, num_timesteps=requested))
        note += (
            f" with {num_evals} evaluations instead of {cfg.num_evals}: Brax PPO trains the"
            f" same whole number of training steps between evaluations, and"
            f" {_plural(n_steps, 'training step')} cannot be split into {most} ({cfg.num_evals}"
            f" evaluations would train {unfitted:,d})"
        )
    return fitted, note


def _plural(n: int, noun: str) -> str:
    return f"{n:,d} {noun}{'' if n == 1 else 's'}"


# Sized for the 2-core CPU (docs/training.md has the measured times): ~4k env steps/s in
# training at 256 envs with the machine otherwise idle, ~2 min of compilation. 2.46 M steps =
# 6 epochs of 10 training steps of 40,960 env steps. Smaller networks than Playground's; the
# PPO hyper-parameters are Playground's Go1 values. The reward is unclipped: Playground's
# clip at 0 hides every improvement while the robot still falls (measured: with it, the
# random initial policy fell within ~40 steps and the reward stayed 0 for the first 0.8 M
# steps; a policy started at the default pose stood at a return of ~18 and stayed there).
SMALL = PPOConfig(
    num_timesteps=2_457_600,
    num_envs=256,
    batch_size=256,
    num_minibatches=8,
    unroll_length=20,
    num_updates_per_batch=4,
    num_evals=7,
    num_eval_envs=64,
    policy_hidden=(128, 128, 128),
    value_hidden=(256, 256, 256),
    reward="unclipped",
)

# Playground's published configuration for Go1JoystickFlatTerrain
# (mujoco_playground.config.locomotion_params.brax_ppo_config; tests check it still is),
# for one GPU: 200 M steps over 8192 envs.
FULL = PPOConfig(
    num_timesteps=200_000_000,
    num_envs=8192,
    batch_size=256,
    num_minibatches=32,
    unroll_length=20,
    num_updates_per_batch=4,
    num_evals=10,
    num_eval_envs=128,
    policy_hidden=(512, 256, 128),
    value_hidden=(512, 256, 128),
    num_resets_per_eval=10,
)

CONFIGS = {"small": SMALL, "full": FULL}


# ---------------------------------------------------------------------------- pieces


class UnclippedReward(pg_wrapper.Wrapper):
    """Playground env wrapper: the reward is the sum of the env's scaled reward terms (its
    ``metrics["reward/<term>"]``) times ``dt``, without the env's clip at 0."""

    def step(self, state, action):
        state = self.env.step(state, action)
        terms = [v for k, v in state.metrics.items() if k.startswith("reward/")]
        if not terms:
            raise ValueError(
                f"{type(self.env.unwrapped).__name__} puts no reward/<term> metrics in its"
                " state: reward='unclipped' needs them"
            )
        return state.replace(reward=sum(terms) * self.env.dt)


def make_env(
    observe: str,
    *,
    sensor: str = "anymal_like",
    reward: str = "playground",
    env_name: str = ENV_NAME,
    extra_latency: int = 0,
    params: str | None = None,
):
    """The unbatched Playground env (Go1 joystick by default) with the contact wrapper,
    observing ``observe``.

    Args:
      observe: one of :data:`VARIANTS`.
      sensor: sensor preset of the estimator's inputs (or a
        :class:`jax_contact.envs.sensors.SensorParams` at the estimator's period).
      reward: one of :data:`REWARDS` (:class:`PPOConfig`).
      env_name: a name of :data:`jax_contact.envs.playground_offline.ENV_NAMES`.
      extra_latency: env steps of sensor delay added to ``sensor``'s, an int >= 0 (the
        transfer matrix's ``estimate_latK`` columns): at the wrapper's physics rate each is
        the env's substeps (Go1 joystick: 5 of 4 ms), by
        :func:`jax_contact.envs.contact_params.with_extra_latency`.
      params: ``ContactObsConfig.params`` (a parameter file or preset name), None: the
        wrapper's defaults.
    """
    from jax_contact.envs import playground_offline
    from jax_contact.envs import wrapper as W
    from jax_contact.envs.contact_params import with_extra_latency

    if observe not in VARIANTS:
        raise ValueError(f"observe must be one of {VARIANTS}, got {observe!r}")
    if reward not in REWARDS:
        raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
    env = playground_offline.load(env_name)
    if reward == "unclipped":
        env = UnclippedReward(env)
    cfg = W.ContactObsConfig(observe=observe, obs_keys=("state",), info_key=INFO_KEY, params=params)
    wrapped = W.wrap_contact(env, cfg, sensor=sensor)
    if extra_latency == 0:
        return wrapped
    # The preset as the wrapper resolved it (estimator period, latency in its steps), delayed.
    # The estimator as resolved too (a file moved to this period from the preset, its map
    # and terrain): the column differs from "estimate" in its readings' latency alone.
    core = wrapped.contact_core
    delayed = with_extra_latency(core.sensor, extra_latency, float(env.dt))
    same = cfg.replace(params=core.params, calibration=core.calibration, terrain=core.terrain)
    return W.wrap_contact(env, same, sensor=delayed)


def network_factory(cfg: PPOConfig):
    """Brax's PPO networks for the dict observation: the policy on ``cfg.policy_obs_key``,
    the critic on ``cfg.value_obs_key``."""
    from brax.training.agents.ppo import networks as ppo_networks

    extra = {}
    if cfg.zero_init_mean:
        extra = dict(
            mean_kernel_init_fn=jax.nn.initializers.constant,
            mean_kernel_init_kwargs={"value": 0.0},
        )
    return functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=tuple(cfg.policy_hidden),
        value_hidden_layer_sizes=tuple(cfg.value_hidden),
        policy_obs_key=cfg.policy_obs_key,
        value_obs_key=cfg.value_obs_key,
        distribution_type=cfg.distribution,
        init_noise_std=cfg.init_noise_std,
        **extra,
    )


def _csv_text(rows: Sequence[dict], fields: Sequence[str] = CSV_FIELDS) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r[k] for k in fields})
    return buf.getvalue()


def read_progress(run_dir: str | Path, name: str = "progress.csv") -> list[dict]:
    """The rows of a run's ``progress.csv`` (or ``training.csv``) as dicts of floats."""
    path = Path(run_dir) / name
    if not path.is_file():
        raise FileNotFoundError(f"no {name} in {run_dir}")
    with path.open() as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


# ----------------------------------------------------------------------------- train


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What :func:`train` measured.

    Attributes:
      run_dir: the run folder.
      rows: the progress rows (:data:`CSV_FIELDS`).
      train_rows: the training-episode rows (:data:`TRAIN_FIELDS`).
      wall_s: training wall time, compilation and evaluations included, s.
      first_eval_s: wall time to the first evaluation (mostly compilation), s.
    """

    run_dir: Path
    rows: list[dict]
    train_rows: list[dict]
    wall_s: float
    first_eval_s: float


def train(
    variant: str,
    cfg: PPOConfig,
    out_dir: str | Path,
    *,
    seed: int = 0,
    overwrite: bool = False,
    log: Callable[[str], None] = print,
    task: str = "go1",
) -> RunResult:
    """Trains one variant with Brax PPO; writes the run folder (module docstring).

    Args:
      variant: one of :data:`VARIANTS`.
      cfg: the configuration.
      out_dir: parent folder; the run goes to ``out_dir/variant``.
      seed: PPO's seed (networks, env keys).
      overwrite: replace an existing run folder (kept at ``<run>.earlier`` until this run's
        first checkpoint and put back if it stops before: :mod:`jax_contact.train.run_folder`);
        otherwise one is refused.
      log: where progress lines go.
      task: a name of :data:`jax_contact.train.tasks.TASK_NAMES` (the env and its training
      wrappers).

    Returns:
      The :class:`RunResult`.

    Raises:
      ValueError: an unknown variant, a bad configuration, or an existing run folder.
    """
    from jax_contact.train import _compat, tasks

    _compat.install()  # Brax's PPO on jax >= 0.10 (the GPU image's 0.11.2); no-op on the pin
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    spec = tasks.get_task(task)
    cfg.validate()
    run_dir = Path(out_dir) / variant
    # The run replaced is kept aside until this one's first checkpoint (train/run_folder.py).
    earlier = EarlierRun(run_dir, check_run_folder(run_dir, overwrite))
    try:
        return _train_into(run_dir, variant, cfg, spec, earlier, seed=seed, log=log)
    except BaseException:
        earlier.restore() or earlier.remove_unsaved()
        raise


def _train_into(run_dir: Path, variant, cfg, spec, earlier, *, seed: int, log) -> RunResult:
    """:func:`train`'s work, into ``run_dir`` (the earlier run, if any, set aside)."""
    from brax.training.agents.ppo import train as ppo_train

    from jax_contact.io import write_json_atomic, write_text_atomic
    from jax_contact.train import figures

    run_dir.mkdir(parents=True, exist_ok=True)
    run_info = {
        "variant": variant,
        "env": spec.env_name,
        "task": spec.name,
        "seed": seed,
        "config": dataclasses.asdict(cfg),
        "finished": False,  # set when the training returns
    }
    write_json_atomic(run_dir / "run.json", run_info)
    set_kept(earlier.note)

    env = spec.make_env(variant, cfg)
    eval_env = spec.make_env(variant, cfg)
    rows: list[dict] = []
    train_rows: list[dict] = []
    t0 = time.perf_counter()
    acc_key = f"eval/episode_{INFO_KEY}/accuracy"

    def progress(step: int, m: dict) -> None:
        wall = time.perf_counter() - t0
        if "eval/episode_reward" not in m:  # Brax's training-episode metrics
            train_rows.append(
                {
                    "step": int(step),
                    "wall_s": round(wall, 1),
                    "train_episode_return": float(m.get("episode/sum_reward", np.nan)),
                    "train_episode_length": float(m.get("episode/length", np.nan)),
                }
            )
            write_text_atomic(run_dir / "training.csv", _csv_text(train_rows, TRAIN_FIELDS))
            return
        row = eval_row(step, wall, m, acc_key)
        length = row["eval_episode_length"]
        rows.append(row)
        write_text_atomic(run_dir / "progress.csv", _csv_text(rows, CSV_FIELDS))
        earlier.settle()  # Brax saves a checkpoint before each evaluation's report
        log(
            f"[{variant}] step {row['step']:>10,d}/{brax_timesteps(cfg):,d}"
            f"  return {row['eval_reward']:8.2f} +- {row['eval_reward_std']:6.2f}"
            f"  episode {length:6.1f} steps  estimator acc {row['eval_contact_accuracy']:.3f}"
            f"  wall {wall:7.1f} s"
        )

    total = brax_timesteps(cfg)  # what Brax trains: num_timesteps rounded up to epochs
    rounded = f" (num_timesteps {cfg.num_timesteps:,d} rounded up to whole epochs)"
    log(
        f"[{variant}] training {spec.env_name}, {total:,d} steps"
        f"{rounded if total != cfg.num_timesteps else ''} over {cfg.num_envs}"
        f" envs ({cfg.steps_per_training_step:,d} per training step); compiling ..."
    )
    ppo_train.train(
        environment=env,
        eval_env=eval_env,
        wrap_env_fn=spec.wrap_env_fn,
        num_timesteps=cfg.num_timesteps,
        num_evals=cfg.num_evals,
        num_eval_envs=cfg.num_eval_envs,
        deterministic_eval=True,  # the curve of the policy as deployed (and policy-eval)
        log_training_metrics=True,
        training_metrics_steps=2 * cfg.steps_per_training_step,
        episode_length=cfg.episode_length,
        num_envs=cfg.num_envs,
        batch_size=cfg.batch_size,
        num_minibatches=cfg.num_minibatches,
        unroll_length=cfg.unroll_length,
        num_updates_per_batch=cfg.num_updates_per_batch,
        learning_rate=cfg.learning_rate,
        entropy_cost=cfg.entropy_cost,
        discounting=cfg.discounting,
        reward_scaling=cfg.reward_scaling,
        max_grad_norm=cfg.max_grad_norm,
        clipping_epsilon=cfg.clipping_epsilon,
        normalize_observations=cfg.normalize_observations,
        num_resets_per_eval=cfg.num_resets_per_eval,
        network_factory=network_factory(cfg),
        seed=seed,
        progress_fn=progress,
        save_checkpoint_path=str((run_dir / "checkpoints").resolve()),
    )
    wall = time.perf_counter() - t0
    if not train_rows:  # Brax reports them every two training steps: none in a shorter run
        write_text_atomic(run_dir / "training.csv", _csv_text(train_rows, TRAIN_FIELDS))
        every = 2 * cfg.steps_per_training_step
        log(
            f"[{variant}] training.csv holds its header only: Brax reports the training"
            f" episodes every {every:,d} env steps (two training steps)"
            + (f" and this run had {total:,d}" if total < every else ", and reported none")
        )
    figures.plot_reward_curves(
        {variant: rows},
        run_dir / "reward.png",
        title=f"{spec.env_name}, {variant}",
        training={variant: train_rows},
    )
    write_json_atomic(run_dir / "run.json", run_info | {"finished": True})
    earlier.drop()
    set_kept(None)
    log(f"[{variant}] done in {wall:.0f} s; {run_dir}")
    return RunResult(
        run_dir=run_dir,
        rows=rows,
        train_rows=train_rows,
        wall_s=wall,
        first_eval_s=rows[0]["wall_s"],
    )


def read_run(run_dir: str | Path) -> dict:
    """A run folder's ``run.json`` (written by :func:`train`), checked: a JSON object with
    a known ``variant`` and a ``config`` of :class:`PPOConfig` fields.

    Raises:
      FileNotFoundError: no ``run.json`` (:func:`jax_contact.train.cli_args.not_a_run_folder`).
      ValueError: naming ``run.json`` and what is wrong with it.
    """
    run_dir = Path(run_dir)
    path = run_dir / "run.json"
    if not path.is_file():
        from jax_contact.train.cli_args import not_a_run_folder

        raise FileNotFoundError(not_a_run_folder(run_dir))
    damaged = "the run folder is damaged; train it again with --overwrite"
    try:
        run = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path} is not JSON ({err}): {damaged}") from None
    if not isinstance(run, dict):
        raise ValueError(f"{path} holds no JSON object: {damaged}")
    if run.get("variant") not in VARIANTS:
        raise ValueError(
            f"{path}: variant {run.get('variant')!r} is not one of {VARIANTS}: {damaged}"
        )
    from jax_contact.train.cli_args import TASKS

    if run.get("task", "go1") not in TASKS:  # an unknown one read as "unknown env ..."
        raise ValueError(f"{path}: task {run.get('task')!r} is not one of {TASKS}: {damaged}")
    fields = {f.name for f in dataclasses.fields(PPOConfig)}
    config = run.get("config")
    if not isinstance(config, dict) or not set(config) <= fields:
        unknown = sorted(set(config) - fields) if isinstance(config, dict) else config
        raise ValueError(f"{path}: config is not a PPOConfig (unknown: {unknown!r}): {damaged}")
    return run


def config_of(run: Mapping) -> PPOConfig:
    """The :class:`PPOConfig` of a ``run.json``'s contents (JSON lists back to tuples)."""
    return PPOConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in run["config"].items()}
    )


def eval_row(step: int, wall_s: float, metrics: Mapping, acc_key: str) -> dict:
    """One row of ``progress.csv`` from the metrics Brax's PPO reports after an evaluation.

    Brax's ``EvalWrapper`` sums each per-step metric over an episode and averages the sums
    over the eval envs. The wrapper's ``accuracy`` metric is the per-step *increment* of the
    episode's running accuracy (``envs/wrapper.py``), so its sum, ``acc_key``, already is the
    episode's accuracy: it is not divided by the episode length again.
    """
    return {
        "step": int(step),
        "wall_s": round(wall_s, 1),
        "eval_reward": float(metrics["eval/episode_reward"]),
        "eval_reward_std": float(metrics["eval/episode_reward_std"]),
        "eval_episode_length": float(metrics["eval/avg_episode_length"]),
        "eval_contact_accuracy": float(metrics.get(acc_key, np.nan)),
    }


def train_variants(
    cfg: PPOConfig,
    out_dir: str | Path,
    *,
    variants: Sequence[str] = VARIANTS,
    seed: int = 0,
    overwrite: bool = False,
    eval_envs: int = 64,
    log: Callable[[str], None] = print,
    task: str = "go1",
) -> dict:
    """Trains each variant, evaluates each policy, and runs the sim-to-real check.

    Writes ``out_dir/summary.json`` (wall times, curves, evaluations),
    ``out_dir/reward_curves.csv`` and ``training_curves.csv`` (all runs, a ``variant``
    column) and ``out_dir/reward_curves.png``, after each run and again after the final
    evaluation (``summary["final_evaluation"]``: ``"pending"`` until it is done, then
    ``"done"``, or ``"skipped"``): a stop leaves the summary of the runs that finished,
    which a later call into ``out_dir`` keeps. An earlier call's summary is rewritten
    before the first run, without the runs this call replaces. ``task``: as
    :func:`train`. ``eval_envs``: episodes of each final evaluation; 0 skips them
    (``summary["evaluation"]`` then holds only the kept runs' evaluations).
    """
    from jax_contact.io import write_json_atomic, write_text_atomic
    from jax_contact.train import figures, tasks

    out_dir = Path(out_dir)
    env_name = ENV_NAME if task == "go1" else task
    # Before any training: every run folder is free (or may be replaced), and the runs of
    # an earlier call into the same folder are kept.
    for v in variants:
        check_run_folder(out_dir / v, overwrite)
    kept_runs, kept_evals = earlier_runs(out_dir, env_name, cfg, seed, variants, overwrite)
    if kept_runs:
        log(f"kept the earlier runs in {out_dir} in its summary: {', '.join(kept_runs)}")
    runs = dict(kept_runs)
    results = {}

    # Curves after every run, the summary after every run and after the final evaluation:
    # a stop later (Ctrl-C in the next run or the evaluation) leaves a summary of the runs
    # that finished, which the next call into this folder keeps (earlier_runs).
    def write_curves() -> None:
        curves = {v: r["curve"] for v, r in runs.items()}
        training = {v: r["training_curve"] for v, r in runs.items()}
        for name, data, fields in (
            ("reward_curves.csv", curves, CSV_FIELDS),
            ("training_curves.csv", training, TRAIN_FIELDS),
        ):
            lines = ["variant," + ",".join(fields)]
            for v, rows in data.items():
                lines += [v + "," + ",".join(str(r[k]) for k in fields) for r in rows]
            write_text_atomic(out_dir / name, "\n".join(lines) + "\n")
        figures.plot_reward_curves(
            curves,
            out_dir / "reward_curves.png",
            title=f"{tasks.get_task(task).env_name}, PPO",  # was "Go1 joystick" for every task
            training=training,
        )

    def write_summary(evaluation: list, final: str) -> dict:
        summary = {
            "env": env_name,
            "config": dataclasses.asdict(cfg),
            "seed": seed,
            "machine": {
                "backend": jax.default_backend(),
                "devices": [str(d) for d in jax.devices()],
            },
            "runs": runs,
            "evaluation": kept_evals + evaluation,
            "final_evaluation": final,
        }
        write_json_atomic(out_dir / "summary.json", summary)
        return summary

    if (out_dir / "summary.json").is_file():
        # Now, before any training: an earlier summary listing a run this call replaces
        # (--overwrite) went on describing it (finished, its wall time and returns, beside
        # the new run's unfinished folder) when the new run was stopped after its first
        # checkpoint (a helper's trial). It holds the kept runs until this call's finish.
        write_curves()
        write_summary([], "pending")
    for v in variants:
        r = results[v] = train(v, cfg, out_dir, seed=seed, overwrite=overwrite, log=log, task=task)
        runs[v] = {
            "wall_s": round(r.wall_s, 1),
            "first_eval_s": r.first_eval_s,
            "curve": r.rows,
            "training_curve": r.train_rows,
        }
        write_curves()
        write_summary([], "pending")

    evals = []
    if eval_envs:
        from jax_contact.train.policy_eval import evaluate_policy, format_evaluation

        evals = [evaluate_policy(results[v].run_dir, n_envs=eval_envs) for v in variants]
        if "truth" in results:  # the sim-to-real check
            evals.append(
                evaluate_policy(results["truth"].run_dir, observe="estimate", n_envs=eval_envs)
            )
        log(format_evaluation(evals))
    else:
        log("final evaluation skipped (eval_envs=0); `jax-contact policy-eval RUN` runs it")
    summary = write_summary(evals, "done" if eval_envs else "skipped")
    written = list(SUMMARY_FILES)
    log(f"wrote {', '.join(written)} and the run folders {', '.join(results)} in {out_dir}")
    return summary


def earlier_runs(
    out_dir: Path,
    env_name: str,
    cfg: PPOConfig,
    seed: int,
    variants: Sequence[str],
    overwrite: bool,
) -> tuple[dict, list]:
    """The runs and evaluations of an earlier :func:`train_variants` into ``out_dir`` that
    this call keeps in its summary: those of other variants whose run folder is still there,
    from a ``summary.json`` of the same env, configuration and seed. With ``overwrite`` a
    summary that does not fit is replaced; without it, refused.

    Raises:
      ValueError: naming ``summary.json`` and what differs (before any training).
    """
    path = out_dir / "summary.json"
    if not path.is_file():
        return {}, []
    try:
        earlier = json.loads(path.read_text())
        ok = isinstance(earlier, dict) and isinstance(earlier.get("runs"), dict)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        ok = False
    if not ok:
        if overwrite:
            return {}, []
        raise ValueError(
            f"{path} is not a summary of jax-contact train: pass another --out, or --overwrite"
            " to replace it"
        )
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))  # tuples as JSON lists
    ours = {"env": env_name, "config": config, "seed": seed}
    differs = [k for k, v in ours.items() if earlier.get(k) != v]
    others = [v for v in earlier["runs"] if v not in variants]
    if differs and others:
        if overwrite:
            return {}, []
        shown = [f"{k} {earlier.get(k)!r}, not {ours[k]!r}" for k in differs if k != "config"]
        if "config" in differs:  # which fields (tiny against small: num_timesteps, ...)
            theirs = earlier.get("config") if isinstance(earlier.get("config"), dict) else {}
            fields = sorted(k for k in set(theirs) | set(config) if theirs.get(k) != config.get(k))
            shown.append(
                "config: "
                + ", ".join(f"{k} {theirs.get(k)!r}, not {config.get(k)!r}" for k in fields[:3])
                + (", ..." if len(fields) > 3 else "")
            )
        raise ValueError(
            f"{path} holds the runs {others} of another {' and '.join(differs)}"
            f" ({'; '.join(shown)}): pass another --out, or --overwrite to replace that"
            " summary (their run folders stay)"
        )
    kept = {v: earlier["runs"][v] for v in others if (out_dir / v / "run.json").is_file()}
    evals = [e for e in earlier.get("evaluation", []) if e.get("trained_with") in kept]
    return kept, evals


def main_log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
