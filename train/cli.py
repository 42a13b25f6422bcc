"""The ``jax-contact`` command line: a thin layer that parses arguments and calls library code.

What here is about the command line itself, not the library:

- **Arguments are checked before JAX is imported.** Importing JAX, MuJoCo MJX and Brax
  takes seconds (up to a minute on a loaded machine), so this module imports only the
  standard library; every number, choice, input file and output folder is checked by
  :func:`main` first (:mod:`jax_contact.train.cli_args`: the argument types, the checks and
  the copies of the library's lists of names), and the library is imported inside each
  command function. A test checks that ``import jax_contact.train.cli`` does not import JAX.
- **XLA's C++ log lines are silenced.** XLA logs to stderr from C++, e.g. ``E1201 ...
  slow_operation_alarm.cc ... Very slow compile? If you want to file a bug...`` whenever a
  compilation takes long, which on a 2-core CPU is every large one. These look like errors
  but are not the user's concern; a failure that matters raises a Python exception as
  well. :func:`main` sets ``TF_CPP_MIN_LOG_LEVEL=3`` (which XLA reads when JAX loads it,
  and which drops C++ INFO, WARNING and ERROR lines) unless the variable is already set:
  run with ``TF_CPP_MIN_LOG_LEVEL=0`` to see everything.
- **Ctrl-C stops a command at once** (:mod:`jax_contact.train.interrupt`): it exits with
  code 130, prints ``jax-contact <command>: interrupted`` (and, if the command had written
  files, a line naming them as complete), and leaves no partial output file, even in the
  middle of an XLA compilation.
- **Compiled programs are kept between runs** (:mod:`jax_contact.train.compile_cache`):
  JAX's persistent compilation cache, in ``~/.cache/jax-contact/xla/<host>``
  (``$JAX_CONTACT_CACHE_DIR`` moves it, empty turns it off).
- **Nothing is silent for long** (:mod:`jax_contact.train.progress`): while JAX loads and
  whenever it compiles for over a second, stderr says so with the seconds counting
  (``jax-contact simulate: compiling (first call)... 12 s``); ``JAX_CONTACT_PROGRESS=0``
  turns these lines off.

Adding a command: a ``_cmd_<name>`` function (imports the library inside, returns the exit
code), a ``_check_<name>`` that raises ValueError for a bad argument without importing JAX,
and a ``command(...)`` block with its arguments in :func:`build_parser`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import warnings
from pathlib import Path

import jax_contact
from jax_contact.train import (  # stdlib-only at import
    deploy_cmd,
    estimate_cmd,
    progress,
    tune_cmd,
    tune_env,
)
from jax_contact.train.cli_args import (  # noqa: F401  (COLUMNS ... SCENES: re-exported)
    BENCH_ENVS,
    BENCH_HELP,
    COLUMNS,
    FAILURE_LIMIT,
    GAITS,
    HOP_TASKS,
    LOG_SUFFIXES,
    MENAGERIE_NAMES,
    NOISES,
    ONE_LEGGED,
    PLAYGROUND_TASKS,
    REPRODUCE_OUTPUTS,
    ROBOT_NAMES,
    SCENES,
    TASKS,
    TERRAINS,
    VARIANTS,
    HelpFormatter,
    Parser,
    add_transfer_arguments,
    bootstrap_int,
    check_distinct_files,
    check_env_memory,
    check_gait_for_robot,
    check_input_file,
    check_log_size,
    check_no_repeats,
    check_not_a_run_file,
    check_not_an_input,
    check_output_file,
    check_output_folder,
    check_outputs_not_folders,
    check_params_source,
    check_robot,
    check_run_folder,
    check_run_record,
    check_transfer,
    int_between,
    nonnegative_int,
    not_a_run_folder,
    positive_float,
    positive_int,
    seed_int,
)
from jax_contact.train.compile_cache import (  # noqa: F401  (re-exported)
    CACHE_ENV,
    compilation_cache_dir,
    enable_compilation_cache,
    host_tag,
)
from jax_contact.train.interrupt import EXIT_INTERRUPTED, StopOnInterrupt

EXIT_USAGE = 2


# ----------------------------------------------------------------------------- commands


# `--size tiny` / `--config tiny`: the smallest runs that go through every step of a
# command (a check of the install and of the README's commands, tests/test_readme.py); their
# numbers mean nothing. Mostly compilation.
REPRODUCE_SIZES = ("tiny", "demo", "full")
TINY_REPRODUCE = dict(
    n_envs=2,
    duration=0.5,
    tune_envs=2,
    tune_duration=0.5,
    planar_envs=1,
    planar_duration=0.5,
)
# Each task's own configurations (jax_contact.train.tasks: Task.configs), plus "tiny" for all.
TASK_CONFIGS = {
    "go1": ("small", "full"),
    **{n: ("small", "reduced") for n in HOP_TASKS},
    **{n: ("small", "full") for n in PLAYGROUND_TASKS},  # the other Playground envs
}
PPO_CONFIGS = ("tiny", *dict.fromkeys(c for cs in TASK_CONFIGS.values() for c in cs))
TINY_PPO = dict(
    num_timesteps=160,
    num_envs=8,
    batch_size=8,
    num_minibatches=2,
    unroll_length=10,
    num_updates_per_batch=1,
    num_evals=2,
    num_eval_envs=4,
    episode_length=50,
    policy_hidden=(16, 16),
    value_hidden=(16,),
)


def _reproduce_config(size: str, **overrides):
    import dataclasses

    from jax_contact.train import reproduce

    cfg = reproduce.FULL if size == "full" else reproduce.DEMO
    if size == "tiny":
        cfg = dataclasses.replace(cfg, **TINY_REPRODUCE)
    return dataclasses.replace(cfg, **{k: v for k, v in overrides.items() if v is not None})


def _cmd_demo(args: argparse.Namespace) -> int:
    from jax_contact.train import reproduce

    reproduce.run(_reproduce_config(args.size, seed=args.seed), args.out)
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    import dataclasses

    from jax_contact.train import reproduce

    feet = tuple(args.feet) if args.feet else None
    tuned = None if args.params == "none" else args.params  # auto, per-gait, a file, a preset
    cfg = _reproduce_config(
        args.size, robot=args.robot, seed=args.seed, foot_names=feet, bootstrap=args.bootstrap
    )
    cfg = dataclasses.replace(cfg, tuned_params=tuned)
    reproduce.run(cfg, args.out)
    return 0


# The library's errors that are about one option of `simulate`, by how they start: named
# as that option, as the checks before JAX name the shipped robots' (the gait's of an
# MJCF robot and --home-qpos came without it, a helper's trial).
_SIMULATE_OPTION_ERRORS = {"gait ": "--gait", "home_qpos ": "--home-qpos"}


def _cmd_simulate(args: argparse.Namespace) -> int:
    from jax_contact.train import logs

    try:
        logs.simulate_to_file(
            args.output,
            robot=args.robot,
            gait=args.gait,
            noise=args.noise,
            terrain=args.terrain,
            n_envs=args.envs,
            duration=args.duration,
            seed=args.seed,
            foot_names=args.feet,
            gait_settings=estimate_cmd.gait_overrides(args) or None,
        )
    except ValueError as err:
        option = next(
            (o for s, o in _SIMULATE_OPTION_ERRORS.items() if str(err).startswith(s)), None
        )
        if option is None:
            raise
        raise ValueError(f"argument {option}: {err}") from None
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from jax_contact.train import log_evaluate

    log_evaluate.evaluate_files(
        args.log,
        json_path=args.json,
        gm_grid_log=args.gm_grid,
        params_path=args.params,
        foot_names=args.feet,
        robot=args.robot,
        terrain_model=args.terrain_model,
        bootstrap=args.bootstrap,
        plots_dir=args.plots,
    )
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from jax_contact.benchmarks import suite

    argv = ["--json", args.json] if args.json else []
    if args.envs:
        argv += ["--envs", *map(str, args.envs)]
    if args.versus_envs:
        argv += ["--versus-envs", *map(str, args.versus_envs)]
    if args.latency_calls:
        argv += ["--latency-calls", str(args.latency_calls)]
    suite.main(argv)
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    import dataclasses

    from jax_contact.train import ppo, tasks

    task = tasks.get_task(args.task)
    if args.config == "tiny":
        cfg = dataclasses.replace(task.config("small"), **TINY_PPO)
    else:
        cfg = task.config(args.config)
    if args.params is not None:
        from jax_contact._presets import preset_file

        # A file by its absolute path: run.json is read later from anywhere (policy-eval).
        params = args.params if preset_file(args.params) else str(Path(args.params).resolve())
        cfg = dataclasses.replace(cfg, estimator_params=params)
    if args.timesteps:
        # Brax PPO rounds num_timesteps up to whole epochs (6x the request at 40,960 steps);
        # fit_timesteps makes it train exactly what was asked, or says what it trains.
        cfg, note = ppo.fit_timesteps(cfg, args.timesteps)
        if note:
            print(f"jax-contact train: --timesteps {args.timesteps}: {note}", file=sys.stderr)
    ppo.train_variants(
        cfg,
        args.out,
        variants=args.variants,
        seed=args.seed,
        overwrite=args.overwrite,
        eval_envs=args.eval_envs,
        log=ppo.main_log,
        task=args.task,
    )
    return 0


def _cmd_policy_eval(args: argparse.Namespace) -> int:
    from jax_contact.io import write_json_atomic
    from jax_contact.train import policy_eval

    res = policy_eval.evaluate_policy(
        args.run, observe=args.observe, column=args.column, n_envs=args.envs, seed=args.seed
    )
    print(policy_eval.format_evaluation([res]))
    c = res["contact"]
    print(
        f"contact estimator: touch-down delay {c['touchdown_delay_ms'][0]:.1f} +- "
        f"{c['touchdown_delay_ms'][1]:.1f} ms, failures {c['failures']}, sw-ph"
        f" {100 * c['swing_phase_failure_rate']:.1f} %, sw-on"
        f" {100 * c['swing_phase_flag_on_rate']:.1f} %, Brier {c['brier']:.3f}"
    )
    print(
        "estimator acc, F1, delay, failures, Brier: the contact estimator run beside the policy"
        " (whatever the policy observes), per step against the simulator's contact, over the"
        " steps alive; failures: false contacts in the air (runs of the flag that start in an"
        " air phase); sw-ph: share of swing phases with one; sw-on: share of swing phases"
        " with the flag on throughout (no failure, a missed lift-off; Table III's columns,"
        " jax_contact/metrics.py)"
    )
    if args.json:
        print(f"wrote {write_json_atomic(args.json, res)}")
    return 0


def _cmd_transfer(args: argparse.Namespace) -> int:
    from jax_contact.train import transfer

    def error(message):
        raise ValueError(message)

    transfer.run_transfer(args, error)
    return 0


def _cmd_rates(args: argparse.Namespace) -> int:
    from jax_contact.io import write_json_atomic
    from jax_contact.train import rates

    rates.check_params(args.scenes, args.params)  # before the first scene's minute
    out = {}
    for scene in progress.bar(args.scenes, desc="rates", unit="scene"):
        out.update(rates.run([scene], seed=args.seed, pairing=args.pairing, params=args.params))
    if args.json:
        print(f"wrote {write_json_atomic(args.json, out)}")  # as bench and policy-eval say
    return 0


def _check_demo(args: argparse.Namespace) -> None:
    check_output_folder("--out", args.out, staged=True)
    check_outputs_not_folders("--out", args.out, REPRODUCE_OUTPUTS)


def _check_reproduce(args: argparse.Namespace) -> None:
    # The names a quadruped's Table III takes: not the one-legged ones (refused below).
    check_robot("--robot", args.robot, [n for n in ROBOT_NAMES if n not in ONE_LEGGED])
    if args.robot in ONE_LEGGED:
        raise ValueError(
            f"argument --robot: Table III needs a quadruped; {args.robot!r} has one leg (its"
            " hop is Section III, which every reproduce runs)"
        )
    check_output_folder("--out", args.out, staged=True)
    check_outputs_not_folders("--out", args.out, REPRODUCE_OUTPUTS)
    modes = ("auto", "per-gait", "none")
    if args.params not in modes:
        try:
            check_params_source("--params", args.params)
        except ValueError as err:
            raise ValueError(f"{err}; or one of {', '.join(modes)}") from None


def _check_simulate(args: argparse.Namespace) -> None:
    if args.output is not None and args.out_option is not None:
        raise ValueError(
            f"argument output: given twice ({args.output!r} and --out {args.out_option!r});"
            " give one"
        )
    if not args.output and not args.out_option:
        raise ValueError(
            "argument output: missing: the .h5 file to write, e.g. jax-contact simulate"
            " out/go1.h5 (or --out out/go1.h5)"
        )
    args.output = args.output or args.out_option
    check_output_file("output", args.output, LOG_SUFFIXES)
    check_robot("--robot", args.robot)
    check_gait_for_robot(args.robot, args.gait)
    check_log_size(args.envs, args.duration)
    estimate_cmd.gait_overrides(args)  # ValueError naming the flag


def _check_evaluate(args: argparse.Namespace) -> None:
    for log in args.log:
        check_input_file("log", log)
    check_distinct_files("log", args.log)
    check_robot("--robot", args.robot)
    logs = {f"log {log!r}": log for log in args.log}
    # An input named as the output: said as such, before the file's own checks.
    check_not_an_input("--json", args.json, **logs, gm_grid_log=args.gm_grid, params=args.params)
    check_output_file("--json", args.json)
    if args.plots is not None:
        check_output_folder("--plots", args.plots)
        stems: dict[str, str] = {}
        for log in args.log:
            if (stem := Path(log).stem) in stems:
                raise ValueError(
                    f"argument --plots: {stems[stem]!r} and {log!r} would both draw"
                    f" reliability_{stem}.png; rename one"
                )
            stems[stem] = log
        pngs = [Path(args.plots) / f"reliability_{stem}.png" for stem in stems]
        check_outputs_not_folders("--plots", args.plots, [png.name for png in pngs])
        if args.json is not None and any(Path(args.json).resolve() == p.resolve() for p in pngs):
            raise ValueError(f"argument --json: {args.json!r} is a file --plots draws")
    if args.gm_grid:
        check_input_file("--gm-grid", args.gm_grid)
        for log in args.log:
            if Path(log).exists() and os.path.samefile(log, args.gm_grid):
                raise ValueError(
                    f"argument --gm-grid: {args.gm_grid!r} is an evaluated log; the baselines"
                    " would be scored on the log they were tuned on: pass another seed's log"
                )
    if args.params:
        check_params_source("--params", args.params)


def _check_train(args: argparse.Namespace) -> None:
    check_output_folder("--out", args.out)
    # A repeat trained twice, or failed after the first had trained.
    check_no_repeats("--variants", args.variants, "variant")
    for variant in args.variants:  # each variant's run folder, before JAX loads
        try:
            check_run_folder(Path(args.out) / variant, args.overwrite)
        except ValueError as err:
            raise ValueError(f"argument --out: {err}") from None
    have = ("tiny", *TASK_CONFIGS[args.task])
    if args.config not in have:
        raise ValueError(
            f"argument --config: the {args.task} task has no {args.config!r} configuration"
            f" ({', '.join(have)})"
        )
    if args.params is not None:
        if args.task in HOP_TASKS:
            raise ValueError(
                f"argument --params: the {args.task} task runs the planar leg's own estimator;"
                " --params is for the Playground tasks (go1, ...)"
            )
        check_params_source("--params", args.params)
    check_env_memory("--eval-envs", args.eval_envs)


def _check_policy_eval(args: argparse.Namespace) -> None:
    run = Path(args.run)
    if not run.exists():
        raise ValueError(f"argument run: folder {args.run!r} does not exist")
    if not (run / "run.json").is_file():
        raise ValueError(f"argument run: {not_a_run_folder(run)}")
    check_run_record("run", run, args.column or args.observe)
    check_env_memory("--envs", args.envs)
    check_output_file("--json", args.json)
    check_not_a_run_file("--json", args.json, [run])


def _check_bench(args: argparse.Namespace) -> None:
    check_output_file("--json", args.json, (".json",))  # the suite's own rule, before JAX loads
    for arg in ("--envs", "--versus-envs"):
        sizes = getattr(args, arg[2:].replace("-", "_")) or ()
        check_no_repeats(arg, sizes, "batch size")  # a repeat was measured twice
        if sizes:
            check_env_memory(arg, max(sizes))


def _check_rates(args: argparse.Namespace) -> None:
    # A repeat ran again, its first result dropped.
    check_no_repeats("--scenes", args.scenes, "scene")
    check_not_an_input("--json", args.json, params=args.params)
    check_output_file("--json", args.json)
    if args.params is not None:
        check_params_source("--params", args.params)


# -------------------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    """The ``jax-contact`` parser; each command has ``func`` (run) and ``check`` (validate)."""
    parser = Parser(
        prog="jax-contact",
        description="Probabilistic foot contact estimation (Hwangbo et al., IROS 2016) in JAX.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--version", action="version", version=f"jax-contact {jax_contact.__version__}"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def command(name, help, func, check, description=None):
        p = sub.add_parser(
            name, help=help, description=description or help, formatter_class=HelpFormatter
        )
        p.set_defaults(func=func, check=check)
        return p

    menagerie = (
        f" ({', '.join(MENAGERIE_NAMES)}: needs $MENAGERIE_ROOT or the mujoco_menagerie package)"
    )
    builtin = [r for r in ROBOT_NAMES if r not in MENAGERIE_NAMES]
    robots = (
        f"one of {', '.join(builtin)}, or of MuJoCo Menagerie{menagerie}, or a path to an"
        " MJCF .xml file"
    )
    p = command(
        "demo",
        "the reproduction at its default size (what `make demo` runs)",
        _cmd_demo,
        _check_demo,
    )
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--seed", type=seed_int, default=0, help="evaluation seed")
    p.add_argument(
        "--size",
        choices=REPRODUCE_SIZES,
        default="demo",
        help="run size, as `reproduce --size` (tiny: 2 envs for 0.5 s, checks the install)",
    )

    p = command(
        "reproduce",
        "Section III, Table III and the ablation in simulation",
        _cmd_reproduce,
        _check_reproduce,
        description="Reproduces the paper in simulation: Section III's planar leg, Table III's"
        " comparison of the estimator with the generalized-momentum observer and a kinematic"
        " detector on a quadruped, and an ablation of the estimator's terms. Prints the tables"
        " and writes figures and table3.json into --out. `--size demo` is what `jax-contact"
        " demo` runs; `--size full` is larger (more envs, longer, Monte-Carlo touch-down too);"
        " `--size tiny` (2 envs for 0.5 s) only checks that every step runs.",
    )
    p.add_argument("--size", choices=REPRODUCE_SIZES, default="demo", help="run size")
    p.add_argument(
        "--robot",
        default=None,
        metavar="ROBOT",
        help="quadruped of Table III (default: go1): one of"
        f" {', '.join(r for r in builtin if r not in ONE_LEGGED)}, or of MuJoCo"
        f" Menagerie{menagerie}, or a path to an MJCF .xml file",
    )
    p.add_argument("--seed", type=seed_int, default=None, help="evaluation seed (default: 0)")
    p.add_argument(
        "--out",
        default="out/reproduce",
        help="output folder; an earlier run's outputs there are replaced as a set: its JSON"
        " files and every section3_*, table3_* and reliability_*.png, those this run does"
        " not write removed (other files are kept)",
    )
    p.add_argument(
        "--bootstrap",
        type=bootstrap_int,
        default=None,
        metavar="N",
        help="env resamples of the paired bootstrap that compares the estimator with each GM"
        " tuning (F1, accuracy, air- and swing-phase failures, sw-on) and the tuned row with the"
        " defaults (every statistic); default 1000, 0: off",
    )
    p.add_argument(
        "--params",
        default="auto",
        metavar="FILE|PRESET",
        help="parameters of the row 'tuned' beside the defaults: a jc.save_params file or a"
        " shipped preset; auto (default): the robot's preset if it has one; per-gait: each"
        " scenario its gait's preset (e.g. spot_walk on the walks) if shipped, else the"
        " robot's; none: no row",
    )
    estimate_cmd.add_feet_flag(p)

    p = command(
        "simulate",
        "simulate scripted robots and save the logs as HDF5",
        _cmd_simulate,
        _check_simulate,
    )
    p.add_argument(
        "output", nargs="?", default=None, help="the .h5 file to write (atomically); or --out"
    )
    p.add_argument(
        "--out", dest="out_option", default=None, metavar="OUTPUT", help="the same as OUTPUT"
    )
    p.add_argument("--robot", default="go1", metavar="ROBOT", help=robots)
    p.add_argument("--gait", default="trot", choices=GAITS, help="scripted gait")
    p.add_argument("--noise", default="anymal_like", choices=NOISES, help="sensor noise preset")
    p.add_argument("--terrain", default="flat", choices=TERRAINS, help="floor")
    p.add_argument("--envs", type=positive_int, default=16, help="robots simulated at once")
    p.add_argument("--duration", type=positive_float, default=10.0, help="simulated seconds")
    p.add_argument("--seed", type=seed_int, default=0, help="seeds states, commands and noise")
    estimate_cmd.add_feet_flag(p)
    estimate_cmd.add_gait_flags(p)

    p = command(
        "evaluate",
        "run the estimator and baselines on saved logs",
        _cmd_evaluate,
        _check_evaluate,
        description="Runs the estimator, the generalized-momentum observer and a kinematic"
        " detector on a log and prints their metrics against the log's ground truth. A log"
        " without ground truth (no truth/contact) has no metrics: then the estimator's mean"
        " P(contact) per foot is printed, and --json gets it per step and env. Given several"
        " logs, each is evaluated as it would be alone, and the metrics of those with ground"
        " truth of one robot and rate are pooled (every env of every log one sequence). The"
        " estimator's defaults are derived for the log's sensor preset (simulate --noise),"
        " as tune's start is.",
    )
    p.add_argument(
        "log",
        nargs="+",
        metavar="LOG",
        help="an .h5 log written by `jax-contact simulate`; several: each evaluated, then"
        " those with ground truth of one robot and rate pooled, the largest such set (ties:"
        " the set of the earliest log; each env of each log one sequence)",
    )
    p.add_argument("--json", default=None, help="write the metrics (or P(contact)) here")
    p.add_argument(
        "--plots",
        default=None,
        metavar="DIR",
        help="write the reliability diagram of every detector (ECE in the legend) to"
        " DIR/reliability_<log name>.png (needs ground truth)",
    )
    estimate_cmd.add_feet_flag(p, default="the feet the log stores")
    p.add_argument(
        "--robot",
        default=None,
        help="the log's robot, if its model moved since (a name or an MJCF .xml path);"
        " default: the one the log names (its physics fingerprint is still checked)",
    )
    p.add_argument(
        "--gm-grid",
        default=None,
        metavar="LOG",
        help="tune the GM observer and the kinematic detector on this other log (another"
        " seed's, of the same robot and rate)"
        " (jax_contact.train.reproduce's grids, best F1), and add each picked by the"
        " estimator's rule as the rows gm_fl, kinematic_fl (sw-ph + sw-on"
        f" <= {100 * FAILURE_LIMIT:g} %%, then F1)"
        " where a point of its grid meets it",
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE|PRESET",
        help="estimator parameters: a jc.save_params file or a shipped preset (go1, spot,"
        " barkour, go1_playground, spot_walk, ...); the robot's defaults then run too, as the row"
        " 'defaults'",
    )
    p.add_argument(
        "--bootstrap",
        type=bootstrap_int,
        default=0,
        metavar="N",
        help="compare every other row with the estimator by a paired bootstrap of N env"
        " resamples: each difference called better, worse or within noise (1000 is typical);"
        " with several logs, of the pooled envs",
    )
    estimate_cmd.add_terrain_model_flag(p)
    estimate_cmd.add_parser(sub)
    tune_cmd.add_parser(sub)
    tune_env.add_parser(sub)
    deploy_cmd.add_parsers(sub)

    p = command(
        "train",
        "PPO (Go1 joystick, the hop or any Playground locomotion env, --task) with no / true /"
        " estimated contact observed",
        _cmd_train,
        _check_train,
    )
    p.add_argument(
        "--variants",
        nargs="+",
        default=list(VARIANTS),
        choices=VARIANTS,
        help="contact observations to train with",
    )
    p.add_argument(
        "--config",
        choices=PPO_CONFIGS,
        default="small",
        help="small: this 2-core CPU, <= 20 min per variant (Go1); full (Playground tasks):"
        " Playground's published configuration of the env, for a GPU; reduced (hop): a third of"
        " small, docs/training_hop.md's run; tiny: 160 steps of 8 envs, checks that every step"
        " runs (learns nothing)",
    )
    p.add_argument(
        "--task",
        choices=TASKS,
        default="go1",
        metavar="TASK",
        help="go1: Playground's Go1 joystick; hop, hop_blind: the planar leg hopping to a"
        " commanded apex height, where contact timing matters (docs/training_hop.md); or any"
        f" other Playground locomotion env by its name ({', '.join(PLAYGROUND_TASKS)}), with"
        " Playground's PPO settings for it",
    )
    p.add_argument(
        "--timesteps",
        type=int_between(1, 2**63 - 1),  # Brax's step counters are int64: 1e20 started training
        default=None,
        help="env steps to train (default: the configuration's); trained exactly, with fewer"
        " evaluations if needed, or rounded up to a whole training step (a message says so)",
    )
    p.add_argument("--seed", type=seed_int, default=0, help="PPO seed")
    p.add_argument(
        "--eval-envs",
        type=nonnegative_int,
        default=64,
        help="episodes of the final evaluation; 0 skips it (`policy-eval` evaluates a run later)",
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE|PRESET",
        help="the wrapper's estimator parameters for the estimate variant (and the estimator"
        " every variant is scored with): a parameter file or a shipped preset, e.g."
        " go1_playground (Playground tasks; recorded in run.json); default: the wrapper's"
        " defaults",
    )
    p.add_argument("--out", default="out/train", help="output folder (a run folder per variant)")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help=(
            "replace existing run folders (each earlier run is kept at <run>.earlier until"
            " the new run's first checkpoint, and put back if it stops before)"
        ),
    )

    p = command(
        "policy-eval",
        "evaluate a trained policy (returns, contact metrics)",
        _cmd_policy_eval,
        _check_policy_eval,
    )
    p.add_argument("run", help="a run folder of `jax-contact train`, e.g. out/train/estimate")
    sees = p.add_mutually_exclusive_group()
    sees.add_argument(
        "--observe",
        choices=VARIANTS,
        default=None,
        help="contact the policy sees now, training sensors (default: what it was trained with)",
    )
    sees.add_argument(
        "--column",
        choices=COLUMNS,
        default=None,
        help="a column of the transfer matrix instead: estimate_harsh (harsh sensors),"
        " estimate_lat1/2 (the training sensors 1/2 env steps late), truth, estimate; a run"
        " trained with contact observed takes any column or --observe truth/estimate, one"
        " trained with none only --observe none (its policy's input has no contact slots)",
    )
    p.add_argument("--envs", type=positive_int, default=64, help="episodes, run in parallel")
    p.add_argument("--seed", type=seed_int, default=12345, help="seeds the episodes")
    p.add_argument("--json", default=None, help="write the evaluation here")

    p = command(
        "transfer",
        "the transfer matrix of trained policies: each run's policy observing each contact"
        " signal (truth, estimate, harsher or later sensors)",
        _cmd_transfer,
        check_transfer,
        description="Evaluates every ROOT/seed*/{none,truth,estimate} run folder of `jax-contact"
        " train --seed S --out ROOT/seedS` (a Playground env or the hop, by each run.json) in every"
        " column of the transfer matrix (jax_contact.train.transfer: truth, estimate,"
        " estimate_harsh, estimate_lat1, estimate_lat2) and prints the mean, std and per-seed"
        " values of each metric; --json writes them.",
    )
    add_transfer_arguments(p)

    p = command(
        "rates",
        "estimator at every physics step vs once per control step, same rollouts",
        _cmd_rates,
        _check_rates,
    )
    p.add_argument(
        "--scenes",
        nargs="+",
        default=list(SCENES),
        choices=SCENES,
        help="planar_leg: the paper's leg hopping; go1: Go1 stepping on the spot with a"
        " half-sine (feet slammed and sliding: a stress test); go1_walk, go1_trot: Go1"
        " gaits in place (jax_contact.train.rates)",
    )
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the rollouts")
    p.add_argument(
        "--pairing",
        default="delayed",
        choices=("delayed", "raw"),
        help="state the differenced acceleration is paired with (ContactObsConfig.pairing)",
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE|PRESET",
        help="the physics-rate estimator's parameter file or preset, for every scene, so"
        " with --scenes of one robot (e.g. --scenes go1 go1_trot go1_walk --params"
        " go1_playground; moved to the scene's 4 ms, its calibration map applied); default:"
        " the defaults",
    )
    p.add_argument("--json", default=None, help="write the results here")

    p = command(
        "bench",
        "estimator throughput, latency and memory; ratio to mjx.step, NumPy, sharding",
        _cmd_bench,
        _check_bench,
    )
    p.add_argument("--json", default=None, help="write every result as one JSON here")
    p.add_argument(
        "--envs",
        type=positive_int,
        nargs="+",
        default=None,
        help=f"{BENCH_HELP['--envs']} (default: {' '.join(map(str, BENCH_ENVS))})",
    )
    p.add_argument(
        "--versus-envs",
        type=positive_int,
        nargs="+",
        default=None,
        help=f"{BENCH_HELP['--versus-envs']} (default: 1024 4096)",
    )
    p.add_argument(
        "--latency-calls",
        type=positive_int,
        default=None,
        help=f"{BENCH_HELP['--latency-calls']} (default: 10000)",
    )
    for p in sub.choices.values():  # main() reports an unknown option with its command's usage
        p.set_defaults(command_parser=p)
    return parser


# ---------------------------------------------------------------------------------- main


def _quiet_xla_logs() -> None:
    """Silences XLA's C++ log lines (module docstring) unless the user chose a level."""
    if "jax" not in sys.modules:  # read when JAX loads XLA; later changes do nothing
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")


# Other libraries' notices about themselves, not about the user's input, which the
# one-line form would present as this command's warnings.
_FOREIGN_NOTICES = (
    # brax.io.mjcf on every model load (the legged PipelineEnv of rates' scenes).
    "Brax System, piplines and environments are not actively being maintained",
)


@contextlib.contextmanager
def _warnings_as_lines(prog: str):
    """While a command runs, a library warning (``UserWarning``) prints as one line,
    ``<prog>: warning: <message>``, not with the file, line and source of its raise;
    :data:`_FOREIGN_NOTICES` are not shown."""
    with warnings.catch_warnings():
        for notice in _FOREIGN_NOTICES:
            warnings.filterwarnings("ignore", message=notice)
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, UserWarning):
                print(f"{prog}: warning: {message}", file=file or sys.stderr)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def main(argv: list[str] | None = None) -> int:
    """Runs ``jax-contact`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code:
    0, 2 for a bad argument or input (one line on stderr), 130 when interrupted."""
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    # Not an argument: commands that record their arguments (tune's provenance) never see it.
    command_parser = vars(args).pop("command_parser", None)
    if unknown:  # argparse's own message, with the command's usage rather than the top one
        (command_parser or parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    prog = f"jax-contact {args.command}"
    try:
        args.check(args)  # before any import of JAX: a bad argument is reported at once
    except ValueError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    _quiet_xla_logs()
    enable_compilation_cache()
    try:
        with StopOnInterrupt(prog), _warnings_as_lines(prog):
            with progress.status(prog, "loading JAX and MuJoCo", "loaded JAX and MuJoCo"):
                import jax  # noqa: F401  (what every command imports first, and the slow part)
                from mujoco import mjx  # noqa: F401
            with progress.watch_compiles(prog):
                return int(args.func(args) or 0)
    except KeyboardInterrupt:  # raised before the watcher ran, or outside the main thread
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, OSError) as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return EXIT_USAGE


def console_main() -> int:
    """The ``jax-contact`` program: :func:`main`, then Ctrl-C ignored while the process
    exits. The command's outputs are written by then; a SIGINT in JAX's and Python's
    clean-up (its atexit handlers) printed a KeyboardInterrupt traceback."""
    import signal

    code = main()
    with contextlib.suppress(ValueError):  # not the main thread: nothing to set
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(console_main())
