"""``jax-contact tune-env SCENE [SCENE ...] --seeds S [S ...] --validate-seed S --out FILE``: tuning
the wrapper's estimator on a wrapped env's own rollouts.

The shipped presets were tuned on this library's robots at 400 Hz. On another env (another
model of the robot, another physics step, other feet) they carry over only in part
(docs/training.md, "A shipped preset in the wrapper"). This command tunes on the env itself:

1. It wraps the env at the physics rate as :func:`jax_contact.envs.wrap_contact` does for
   training (the same feet, sensor model, pairing, ground truth; the wrapper's default
   parameters at the physics step are the starting point and the prior's centre).
2. For each seed it rolls out a scripted policy and keeps every physics step's sensor
   readings (``ContactObsConfig.record_substeps``) and ground truth (the wrapper's, with
   its ``truth_gap``).
3. It rebuilds every step's estimator inputs from those readings with the code the live
   wrapper runs (:meth:`jax_contact.envs.contact_core.Core.measure`), so what is fitted is
   what the wrapper will see.
4. It fits them as ``jax-contact tune`` fits logs: the same loss, options and file
   (:mod:`jax_contact.train.tune_cmd`), with the provenance naming the scene and seeds.

The file then goes back into the wrapper, ``ContactObsConfig(params="params.json")``, into
``jax-contact rates --params`` and into ``python -m jax_contact.benchmarks.wrapper_accuracy
--params``.

Scenes (``SCENE``):

- a Playground locomotion env (registry name, loaded offline by
  :func:`jax_contact.envs.playground_offline.load`), optionally ``NAME:POLICY`` with a
  scripted policy of :mod:`jax_contact.benchmarks.wrapper_accuracy` (``walk``, ``trot``,
  ``hop``, ``step``, ``random``; its default per env otherwise). A seed draws the
  rollouts' frequencies and phases (or random actions), the resets and the sensor noise.
  Scored from 0.5 s (the drop at reset) to each rollout's first ``done``.
- a scene of ``jax-contact rates`` (:data:`jax_contact.train.rates.SCENES`). Its actions
  are fixed by rollout index; a seed draws the resets and the sensor noise. Scored from
  0.2 s.

Tune on some seeds, validate on another, report on a third that neither saw (the
reports of docs/training.md use seed 1 for Playground scenes, seed 0 for the rates scenes;
pass other seeds here).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import time

from jax_contact.train import tune_cmd

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
    rollout jitted once, for every seed of a scene.

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


# ----------------------------------------------------------------------------- command


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Adds the ``tune-env`` command; its defaults carry ``func=run`` and ``check=check``."""
    from jax_contact.train.cli_args import positive_int

    p = subparsers.add_parser(
        "tune-env",
        help="tune the wrapper's estimator on a Playground env's (or rates scene's) own rollouts",
        description="Rolls out a scripted policy on a wrapped env at the physics rate for each"
        " seed, rebuilds the estimator's inputs from the wrapper's own sensor readings and"
        " tunes the estimator on them as `jax-contact tune` does (the same options). The"
        " file goes into ContactObsConfig(params=FILE), `jax-contact rates --params` and"
        " `wrapper_accuracy --params`. Your own env or a trained policy: tune_on_env in"
        " jax_contact.train.tune_env (docs/tuning.md).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument(
        "scenes",
        nargs="+",
        metavar="SCENE",
        help="a Playground locomotion env, optionally NAME:POLICY (walk, trot, hop, step,"
        " random), or a `jax-contact rates` scene (go1, go1_walk, go1_trot, planar_leg);"
        " several scenes of one robot are tuned on together",
    )
    p.add_argument("--seeds", required=True, nargs="+", type=int, metavar="S", help="tuning seeds")
    p.add_argument(
        "--validate-seed",
        required=True,
        nargs="+",
        type=int,
        metavar="S",
        help="validation seed(s): early stopping on their pooled loss",
    )
    p.add_argument("--rollouts", type=positive_int, default=ROLLOUTS, help="rollouts per seed")
    p.add_argument("--steps", type=positive_int, default=STEPS, help="env steps per rollout")
    tune_cmd.add_tuning_options(p)
    p.set_defaults(func=run, check=check)
    return p


def check(args: argparse.Namespace) -> None:
    """ValueError naming the argument, before JAX is imported (the scene's name is checked
    at the start of :func:`run`, before anything is simulated: Playground's registry
    imports JAX)."""
    seeds, vals = list(args.seeds), list(args.validate_seed)
    for arg, given in (("--seeds", seeds), ("--validate-seed", vals)):
        if len(set(given)) != len(given):
            raise ValueError(f"argument {arg}: repeated seed in {given}")
    both = sorted(set(seeds) & set(vals))
    if both:
        raise ValueError(f"argument --validate-seed: seed(s) {both} are also tuning seeds")
    if len(set(args.scenes)) != len(args.scenes):
        raise ValueError(f"argument SCENE: repeated scene in {list(args.scenes)}")
    tune_cmd.check_tuning_options(args)


def check_scene(scene: str) -> None:
    """ValueError naming ``scene`` unless it is a rates scene or a Playground locomotion env
    with a known policy (imports Playground's registry, hence JAX)."""
    from jax_contact.train.rates import SCENES

    if ":" not in scene and scene in SCENES:
        return
    from jax_contact.benchmarks.wrapper_accuracy import POLICIES
    from jax_contact.envs.playground_offline import ENV_NAMES

    name, _, policy = scene.partition(":")
    if name not in ENV_NAMES:
        raise ValueError(
            f"argument SCENE: unknown scene {name!r}; valid: a `jax-contact rates` scene"
            f" ({', '.join(SCENES)}) or a Playground locomotion env ({', '.join(ENV_NAMES)})"
        )
    if policy and policy not in POLICIES:
        raise ValueError(f"argument SCENE: unknown policy {policy!r}; valid: {', '.join(POLICIES)}")


def _same_estimator(first, other, scene: str) -> None:
    """ValueError unless two recordings' wrappers run one estimator (model size, feet, dt)."""
    a, b = first.core, other.core
    same_dt = abs(first.dt - other.dt) <= 1e-6 * abs(first.dt)
    if (a.desc.nv, tuple(a.desc.foot_names)) != (
        b.desc.nv,
        tuple(b.desc.foot_names),
    ) or not same_dt:
        raise ValueError(
            f"argument SCENE: {scene!r} runs another estimator (nv {b.desc.nv}, feet"
            f" {list(b.desc.foot_names)}, dt {other.dt:g} s) than the first scene's (nv"
            f" {a.desc.nv}, feet {list(a.desc.foot_names)}, dt {first.dt:g} s)"
        )


def run(args: argparse.Namespace) -> int:
    """Records every scene at every seed, tunes, writes ``args.out``; returns 0."""
    import jax

    for scene in args.scenes:
        check_scene(scene)

    def recordings():
        for scene in args.scenes:
            sc = load_scene(scene, args.steps, args.rollouts)
            record_seed = recorder(sc.env, feedback=sc.feedback, stop=sc.stop, skip_s=sc.skip_s)
            for seed in [*args.seeds, *args.validate_seed]:
                yield (
                    scene,
                    sc.description,
                    seed,
                    record_seed(sc.actions_of(seed), jax.random.PRNGKey(seed)),
                )

    return _fit(args, recordings(), "wrapped env " + " + ".join(args.scenes))


def tune_on_env(
    env,
    *,
    seeds,
    validate_seeds,
    out,
    actions_of=None,
    policy=None,
    config=None,
    name: str = "custom env",
    n_steps: int = STEPS,
    n_envs: int = ROLLOUTS,
    skip_s: float = PLAYGROUND_SKIP_S,
    feedback=None,
    stop=None,
    options=(),
) -> int:
    """``tune-env`` on any env the wrapper takes (a Brax ``PipelineEnv`` with the MJX
    backend or a Playground ``MjxEnv``, with ground truth for every foot), from Python.

    Each seed ``S`` is one recording of ``n_envs`` rollouts of ``n_steps`` env steps (keys
    ``PRNGKey(S)``, as the command's): ``actions_of(S) -> (n_steps, n_envs, nu)`` open-loop
    actions (None: zeros), plus ``policy(obs, key)``'s action if given (a trained policy's
    inference function, on the observation of the env wrapped with ``config``, the
    config it was trained with), plus ``feedback(data)``; ``stop(data)`` ends a rollout's
    valid steps. Steps before ``skip_s`` seconds are left out. The fit, its file and its
    provenance are the command's (``name`` stands for the scene).

    Args:
      options: more ``jax-contact tune-env`` options, as command-line strings (e.g.
        ``["--calibrate", "--epochs", "20"]``).

    Returns:
      0 once ``out`` is written.

    Raises:
      ValueError: a bad option or seed (named as the command names it), or neither
        ``actions_of`` nor ``policy`` given.
    """
    import jax
    import numpy as np

    if actions_of is None and policy is None:
        raise ValueError("tune_on_env needs actions_of, policy or both: nothing drives the env")
    if config is not None and config.terrain is not None:
        _terrain_model(config.terrain)  # refused before anything is simulated
    parser = argparse.ArgumentParser(prog="tune_on_env")
    add_parser(parser.add_subparsers(dest="command", required=True))
    argv = ["tune-env", name, "--seeds", *map(str, seeds), "--validate-seed"]
    argv += [*map(str, validate_seeds), "--out", str(out), "--steps", str(n_steps)]
    argv += ["--rollouts", str(n_envs), *options]
    try:
        args = parser.parse_args(argv)
    except SystemExit:  # argparse has printed the reason
        raise ValueError(f"tune_on_env: bad options {list(options)}") from None
    args.check(args)
    record_seed = recorder(
        env, feedback=feedback, stop=stop, skip_s=skip_s, config=config, policy=policy
    )
    zeros = np.zeros((n_steps, n_envs, env.action_size), np.float32)
    desc = "closed-loop policy" if actions_of is None else "open-loop actions"
    if actions_of is not None and policy is not None:
        desc = "open-loop actions + closed-loop policy"

    def recordings():
        for seed in [*args.seeds, *args.validate_seed]:
            acts = zeros if actions_of is None else actions_of(seed)
            yield name, f"{name}: {desc}", seed, record_seed(acts, jax.random.PRNGKey(seed))

    return _fit(args, recordings(), f"wrapped env {name}")


def _terrain_model(terrain) -> str:
    """The provenance's ``terrain_model`` of the wrapper's terrain (the defaults': the floor
    plane, ``"flat"``).

    Raises:
      ValueError: a terrain no parameter file can name (a height field).
    """
    from jax_contact.terrain import FlatTerrain, FootholdMemory

    if isinstance(terrain, FootholdMemory):
        return "memory"
    if isinstance(terrain, FlatTerrain):
        return "flat"
    raise ValueError(
        f"config.terrain: a {type(terrain).__name__} cannot be recorded in a parameter file;"
        " tune with a flat terrain or a foothold memory"
    )


def _fit(args: argparse.Namespace, recordings, robot: str) -> int:
    """Rebuilds the inputs of every ``(scene, description, seed, Recording)`` of
    ``recordings``, fits them with ``args``' options and writes ``args.out``; returns 0."""
    from jax_contact.robot import model_mass

    t0 = time.perf_counter()
    train, vals, infos, vinfos = [], [], [], []
    first = None
    t = time.perf_counter()
    for scene, description, seed, rec in recordings:
        if first is None:
            first = rec
        _same_estimator(first, rec, scene)
        data = tuning_data(rec, args.chunk)
        n_valid = int(rec.valid.sum())
        print(
            f"recorded {scene} seed {seed}: {rec.truth.shape} (physics steps, rollouts,"
            f" feet), {n_valid} valid steps, contact {rec.truth[rec.valid].mean():.3f}"
            f" ({time.perf_counter() - t:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
        info = {
            "path": f"{scene} seed {seed}",
            "scene": scene,
            "policy": description,
            "seed": seed,
            "n_envs": int(rec.truth.shape[1]),
            "dt": rec.dt,
            "noise": rec.core.cfg.sensor,
            "steps": int(data.n_steps),
            "valid_steps": n_valid,
        }
        (train if seed in args.seeds else vals).append(data)
        (infos if seed in args.seeds else vinfos).append(info)
        t = time.perf_counter()
    core = first.core
    floor = None
    if getattr(args, "noise_floor", "sensor") == "sensor":
        from jax_contact.defaults import sensor_noise_floor

        floor = sensor_noise_floor(core.desc, core.sensor, float(core.params.dt))
    inputs = tune_cmd.Inputs(
        train=train,
        vals=vals,
        infos=infos,
        vinfos=vinfos,
        base=core.params,
        terrain=core.terrain,
        floor=floor,
        desc=core.desc,
        robot=robot,
        terrain_model=_terrain_model(core.terrain),
        load_s=time.perf_counter() - t0,
        mass_kg=model_mass(first.mj_model),
    )
    return tune_cmd.fit_and_write(args, inputs)


def main(argv: list[str] | None = None) -> int:
    """``python -m jax_contact.train.tune_env SCENE [SCENE ...] --seeds ...``."""
    parser = argparse.ArgumentParser(prog="jax-contact")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["tune-env", *(argv if argv is not None else sys.argv[1:])])
    try:
        args.check(args)
    except ValueError as err:
        parser.error(str(err))
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
