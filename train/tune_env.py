"""``jax-contact tune-env SCENE [SCENE ...] --seeds S [S ...] --validate-seed S --out FILE``: tuning
the wrapper's estimator on a wrapped env's own rollouts.

The shipped presets were tuned on this library's robots at 400 Hz. On another env (another
model of the robot, another physics step, other feet) they carry over only in part
(docs/training.md, "A shipped preset in the wrapper"). This command tunes on the env itself:

1. It wraps the env at the physics rate as :func:`jax_contact.envs.wrapper.wrap_contact` does for
   training (the same feet, sensor model, pairing, ground truth; the wrapper's default
   parameters at the physics step are the starting point and the prior's centre).
2. For each seed it rolls out a scripted policy and keeps every physics step's sensor
   readings (``ContactObsConfig.record_substeps``) and ground truth (the wrapper's, with
   its ``truth_gap``).
3. It rebuilds every step's estimator inputs from those readings with the code the live
   wrapper runs (:meth:`jax_contact.envs.contact_core.Core.measure`), so what is fitted is
   what the wrapper will see.
   Steps 1-3 are :mod:`jax_contact.train.env_rollouts`.
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
  are fixed by rollout index and it starts from its home pose, so every seed plays the same
  motion; a seed draws only the sensor noise (the command says so when it validates on
  one: held-out motion needs a Playground scene). Scored from 0.2 s.

Tune on some seeds, validate on another, report on a third that neither saw (the
reports of docs/training.md use seed 1 for Playground scenes, seed 0 for the rates scenes;
pass other seeds here).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from jax_contact.train import tune_cmd, tune_inputs
from jax_contact.train.env_rollouts import (
    PLAYGROUND_SKIP_S,
    RATES_SKIP_S,
    ROLLOUTS,
    STEPS,
    load_scene,
    recorder,
    tuning_data,
)

# ----------------------------------------------------------------------------- command


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Adds the ``tune-env`` command; its defaults carry ``func=run`` and ``check=check``."""
    from jax_contact.train.cli_args import HelpFormatter, positive_int, seed_int

    p = subparsers.add_parser(
        "tune-env",
        help="tune the wrapper's estimator on a Playground env's (or rates scene's) own rollouts",
        description="Rolls out a scripted policy on a wrapped env at the physics rate for each"
        " seed, rebuilds the estimator's inputs from the wrapper's own sensor readings and"
        " tunes the estimator on them as `jax-contact tune` does (the same options). The"
        " file goes into ContactObsConfig(params=FILE), `jax-contact rates --params` and"
        " `wrapper_accuracy --params`. Your own env or a trained policy: tune_on_env in"
        " jax_contact.train.tune_env (docs/tuning.md).",
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "scenes",
        nargs="+",
        metavar="SCENE",
        help="a Playground locomotion env, optionally NAME:POLICY (walk, trot, hop, step,"
        " random), or a `jax-contact rates` scene (go1, go1_walk, go1_trot, planar_leg);"
        " several scenes of one robot are tuned on together",
    )
    p.add_argument(
        "--seeds", required=True, nargs="+", type=seed_int, metavar="S", help="tuning seeds"
    )
    p.add_argument(
        "--validate-seed",
        required=True,
        nargs="+",
        type=seed_int,
        metavar="S",
        help="validation seed(s): early stopping on their pooled loss",
    )
    p.add_argument("--rollouts", type=positive_int, default=ROLLOUTS, help="rollouts per seed")
    p.add_argument(
        "--steps",
        type=positive_int,
        default=STEPS,
        help=f"env steps per rollout; the first {PLAYGROUND_SKIP_S} s"
        f" ({RATES_SKIP_S} s on a rates scene) after the reset are not scored",
    )
    tune_cmd.add_tuning_options(p)
    p.set_defaults(func=run, check=check)
    return p


def check(args: argparse.Namespace) -> None:
    """ValueError naming the argument, before JAX is imported (the scene's name is checked
    at the start of :func:`run`, before anything is simulated: Playground's registry
    imports JAX)."""
    from jax_contact.train.cli_args import check_no_repeats

    seeds, vals = list(args.seeds), list(args.validate_seed)
    for arg, given in (("--seeds", seeds), ("--validate-seed", vals)):
        check_no_repeats(arg, given, "seed")
    both = sorted(set(seeds) & set(vals))
    if both:
        raise ValueError(f"argument --validate-seed: seed(s) {both} are also tuning seeds")
    check_no_repeats("SCENE", args.scenes, "scene")
    tune_cmd.check_tuning_options(args)


def check_steps_count(scene: str, n_steps: int, dt: float, skip_s: float) -> None:
    """ValueError naming ``--steps`` when rollouts of ``n_steps`` env steps of ``dt`` s end
    before ``skip_s`` (the start left out): no step would count, which the recordings
    otherwise report only after compiling."""
    if n_steps * dt <= skip_s + 1e-9:
        need = math.floor(skip_s / dt + 1e-9) + 1
        raise ValueError(
            f"argument --steps: {n_steps} env steps of {scene} ({dt * 1e3:g} ms each) end"
            f" within the first {skip_s:g} s of each rollout, which is left out: no step would"
            f" count; at least {need}"
        )


def check_scene(scene: str) -> None:
    """ValueError naming ``scene`` unless it is a rates scene or a Playground locomotion env
    with a known policy (imports Playground's registry, hence JAX)."""
    from jax_contact.train.rates import SCENES

    if ":" not in scene and scene in SCENES:
        return
    from jax_contact.benchmarks.wrapper_accuracy import check_policy
    from jax_contact.envs.playground_offline import ENV_NAMES

    name, _, policy = scene.partition(":")
    if name in SCENES:
        raise ValueError(
            f"argument SCENE: {scene!r}: the `jax-contact rates` scene {name!r} plays its own"
            f" scripted actions and takes no :POLICY; pass {name!r} alone"
        )
    if name not in ENV_NAMES:
        raise ValueError(
            f"argument SCENE: unknown scene {name!r}; valid: a `jax-contact rates` scene"
            f" ({', '.join(SCENES)}) or a Playground locomotion env ({', '.join(ENV_NAMES)})"
        )
    try:
        check_policy(name, policy or None)
        if policy == "stand":  # the benchmark's standing check: no air phase to learn from
            raise ValueError(
                "policy 'stand' holds every foot on the floor: nothing to tune on; use a"
                " gait or random"
            )
    except ValueError as err:
        raise ValueError(f"argument SCENE: {scene!r}: {err}") from None


def _same_estimator(first, other, scene: str) -> None:
    """ValueError unless two recordings' (or recorders') wrappers run one estimator (model
    size, feet, dt)."""
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

    # Every scene is loaded and wrapped (nothing compiled) before the first rollout, so a
    # scene of another robot is refused at once, not after the first scene's recordings.
    scenes = [load_scene(scene, args.steps, args.rollouts) for scene in args.scenes]
    for scene, sc in zip(args.scenes, scenes, strict=True):
        check_steps_count(scene, args.steps, float(sc.env.dt), sc.skip_s)
    recorders = [
        recorder(sc.env, feedback=sc.feedback, stop=sc.stop, skip_s=sc.skip_s) for sc in scenes
    ]
    for scene, record_seed in zip(args.scenes, recorders, strict=True):
        _same_estimator(recorders[0], record_seed, scene)
    from jax_contact.train.rates import SCENES

    fixed = [scene for scene in args.scenes if scene in SCENES]
    if fixed and args.validate_seed:
        print(
            f"note: {', '.join(fixed)}: a `jax-contact rates` scene plays the same motion at"
            " every seed (fixed actions, home start); its validation seed draws only other"
            " sensor noise, so early stopping sees no held-out motion (a Playground scene's"
            " seed draws the gait too)",
            file=sys.stderr,
        )

    def recordings():
        for scene, sc, record_seed in zip(args.scenes, scenes, recorders, strict=True):
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
        n_valid = int(rec.valid.sum())
        if n_valid == 0:
            raise ValueError(
                f"{scene} seed {seed}: no step counts in {rec.truth.shape[0]} physics steps"
                f" per rollout ({args.steps} env steps): the start of each rollout is left out"
                f" ({PLAYGROUND_SKIP_S} s on Playground envs, {RATES_SKIP_S} s on the rates"
                " scenes) and a rollout ends at its first done: raise --steps"
            )
        data = tuning_data(rec, args.chunk)
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
            # The feet the wrapper estimated, and its sole point: what the file fits.
            "feet": list(rec.core.desc.foot_names),
            "sole": rec.core.cfg.sole,
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
    inputs = tune_inputs.Inputs(
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
