"""The ``jax-contact`` command line: a thin layer that parses arguments and calls library code.

Three things here are about the command line itself, not the library:

- **Arguments are checked before JAX is imported.** Importing JAX, MuJoCo MJX and Brax
  takes seconds (up to a minute on a loaded machine), so this module imports only the
  standard library; every number, choice, input file and output folder is checked by
  :func:`main` first, and the library is imported inside each command function. A test
  checks that ``import jax_contact.train.cli`` does not import JAX. The names the checks need from
  modules that import JAX (:data:`ROBOT_NAMES`, the gaits, noise presets, ...) are copied
  here; tests check that each copy equals the library's list.
- **XLA's C++ log lines are silenced.** XLA logs to stderr from C++, e.g. ``E1201 ...
  slow_operation_alarm.cc ... Very slow compile? If you want to file a bug...`` whenever a
  compilation takes long, which on a 2-core CPU is every large one. These look like errors
  but are not the user's concern; a failure that matters raises a Python exception as
  well. :func:`main` sets ``TF_CPP_MIN_LOG_LEVEL=3`` (which XLA reads when JAX loads it,
  and which drops C++ INFO, WARNING and ERROR lines) unless the variable is already set:
  run with ``TF_CPP_MIN_LOG_LEVEL=0`` to see everything.
- **Ctrl-C stops a command at once** (:class:`_StopOnInterrupt`): it exits with code 130,
  prints one line, ``jax-contact <command>: interrupted``, and leaves no partial output
  file. Python's own ``KeyboardInterrupt`` does not do this in a JAX program: the
  exception is raised only when the main thread next runs Python code, which during an
  XLA compilation can be minutes later, and when that code is the garbage collector's
  callback into XLA the exception is printed as ``Exception ignored in: <function
  _xla_gc_callback ...>`` and lost, so the run carries on. Instead, the signal's arrival
  is read from :func:`signal.set_wakeup_fd` by a watcher thread, which Python's C-level
  handler wakes immediately whatever the main thread is doing; the watcher removes the
  temporary files of writes in progress (:func:`jax_contact.io.abort_writes`, every
  output goes through ``jax_contact.io``'s atomic writes) and ends the process with
  ``os._exit(130)``. Output written completely before the signal (e.g. the run folders of
  earlier ``train`` variants) stays.
- **Compiled programs are kept between runs** (:func:`enable_compilation_cache`): JAX's
  persistent compilation cache, in ``~/.cache/jax-contact/xla`` (``$XDG_CACHE_HOME`` is
  honoured), or in ``$JAX_CONTACT_CACHE_DIR`` (empty: off); a ``JAX_COMPILATION_CACHE_DIR``
  of the user's own wins. On 2 cores most of a short run is compilation, which a second
  run then loads in about a second per program. Every program is kept (minimum compile
  time and entry size 0); deleting the folder at any time is safe.
- **Nothing is silent for long** (:mod:`jax_contact.train.progress`): while JAX loads and whenever
it
  compiles for over a second, stderr says so with the seconds counting
  (``jax-contact simulate: compiling (first call)... 12 s``); ``JAX_CONTACT_PROGRESS=0``
  turns these lines off.

Adding a command: a ``_cmd_<name>`` function (imports the library inside, returns the exit
code), a ``_check_<name>`` that raises ValueError for a bad argument without importing JAX,
and a ``command(...)`` block with its arguments in :func:`build_parser`.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import tempfile
import threading
from pathlib import Path

from jax_contact.train import deploy_cmd, estimate_cmd, progress, tune_cmd  # stdlib-only at import

# Copies of the library's lists (importing those modules imports JAX); tests/test_cli.py
# checks that each equals its original.
ROBOT_NAMES = (  # jax_contact.envs.robots.ROBOT_NAMES
    "go1",
    "spot",
    "barkour",
    "planar_leg",
    "anybotics_anymal_b",
    "anybotics_anymal_c",
    "boston_dynamics_spot",
    "google_barkour_v0",
    "google_barkour_vb",
    "unitree_a1",
    "unitree_go1",
    "unitree_go2",
)
GAITS = ("trot", "walk", "hop")  # jax_contact.envs.gaits.KINDS
NOISES = ("ideal", "anymal_like", "harsh")  # jax_contact.envs.sensors.PRESETS
TERRAINS = ("flat", "rough")  # jax_contact.envs.simulate.TERRAINS
VARIANTS = ("none", "truth", "estimate")  # jax_contact.train.ppo.VARIANTS
COLUMNS = (  # jax_contact.train.transfer.COLUMNS
    "truth",
    "estimate",
    "estimate_harsh",
    "estimate_lat1",
    "estimate_lat2",
)
TASKS = ("go1", "hop", "hop_blind")  # jax_contact.train.tasks.TASK_NAMES
SCENES = ("planar_leg", "go1", "go1_walk", "go1_trot")  # jax_contact.train.rates.SCENES
LOG_SUFFIXES = (".h5", ".hdf5")

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for a command stopped by Ctrl-C


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
# Each task's own configurations (jax_contact.train.tasks: Task.configs), plus "tiny" for both.
TASK_CONFIGS = {
    "go1": ("small", "full"),
    "hop": ("small", "reduced"),
    "hop_blind": ("small", "reduced"),
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
    from jax_contact.train import reproduce

    feet = tuple(args.feet) if args.feet else None
    cfg = _reproduce_config(args.size, robot=args.robot, seed=args.seed, foot_names=feet)
    reproduce.run(cfg, args.out)
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from jax_contact.train import logs

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
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from jax_contact.train import logs

    logs.evaluate_file(
        args.log,
        json_path=args.json,
        gm_grid_log=args.gm_grid,
        params_path=args.params,
        foot_names=args.feet,
        terrain_model=args.terrain_model,
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
    from jax_contact.train import ppo, tasks

    task = tasks.get_task(args.task)
    if args.config == "tiny":
        import dataclasses

        cfg = dataclasses.replace(task.config("small"), **TINY_PPO)
    else:
        cfg = task.config(args.config)
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
        f"{c['touchdown_delay_ms'][1]:.1f} ms, failures {c['failures']}, Brier {c['brier']:.3f}"
    )
    print(
        "estimator acc, F1, delay, failures, Brier: the contact estimator run beside the policy"
        " (whatever the policy observes), per step against the simulator's contact, over the"
        " steps alive; failures: false contacts in the air"
    )
    if args.json:
        write_json_atomic(args.json, res)
    return 0


def _cmd_rates(args: argparse.Namespace) -> int:
    from jax_contact.io import write_json_atomic
    from jax_contact.train import rates

    out = {}
    for scene in progress.bar(args.scenes, desc="rates", unit="scene"):
        out.update(rates.run([scene], seed=args.seed, pairing=args.pairing))
    if args.json:
        write_json_atomic(args.json, out)
    return 0


# ------------------------------------------------------------------------ argument checks
# Types raise argparse.ArgumentTypeError (argparse names the argument); the per-command
# checks raise ValueError with the argument's name, printed by main().


def _int_at_least(minimum: int):
    """An argparse type: an int >= ``minimum``, else an error naming the value."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an int >= {minimum}, got {text!r}")
        return value

    return parse


_positive_int = _int_at_least(1)
_nonnegative_int = _int_at_least(0)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def check_robot(arg: str, name: str | None) -> None:
    """Raises ValueError unless ``name`` is a known robot or an existing MJCF file."""
    if name is None or name in ROBOT_NAMES:
        return
    if name.endswith(".xml") or os.sep in name or "/" in name:  # jax_contact.envs.robots' rule
        if not Path(name).expanduser().is_file():
            raise ValueError(f"argument {arg}: MJCF file {name!r} does not exist")
        return
    raise ValueError(
        f"argument {arg}: unknown robot {name!r}; valid names: {', '.join(ROBOT_NAMES)}, or a"
        " path to an MJCF .xml file"
    )


def check_input_file(arg: str, path: str) -> None:
    """Raises ValueError unless ``path`` is an existing file."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"argument {arg}: file {path!r} does not exist")
    if not p.is_file():
        raise ValueError(f"argument {arg}: {path!r} is not a file")


def check_params_source(arg: str, source: str) -> None:
    """Raises ValueError unless ``source`` is an existing parameter file or the name of a
    shipped preset (``jax_contact.preset_names()``), the two things
    :func:`jax_contact.load_params` takes."""
    from jax_contact._presets import preset_file, preset_names

    if preset_file(source) is not None:
        return
    if not Path(source).exists():
        raise ValueError(
            f"argument {arg}: {source!r} is neither a file nor a shipped preset"
            f" ({', '.join(preset_names())})"
        )
    check_input_file(arg, source)


def check_output_folder(arg: str, folder: str | os.PathLike) -> None:
    """Raises ValueError unless files can be created in ``folder`` (once created).

    The nearest existing ancestor is probed by creating and removing a file in it, as the
    atomic writes do: permission bits alone are no answer for root, nor for folders such
    as ``/proc``.
    """
    p = Path(folder).expanduser().absolute()
    if p.exists() and not p.is_dir():
        raise ValueError(f"argument {arg}: {str(p)!r} exists and is not a folder")
    existing = p
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(
            f"argument {arg}: cannot create folder {str(p)!r}: {str(existing)!r} is a file"
        )
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".jax-contact-check.", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise ValueError(
            f"argument {arg}: cannot create files in folder {str(existing)!r}"
            f" ({err.strerror or err})"
        ) from None


def check_output_file(arg: str, path: str | None, suffixes: tuple[str, ...] = ()) -> None:
    """Raises ValueError unless ``path`` (None: none) can be written: the suffix, not a
    folder, a writable folder."""
    if path is None:
        return
    p = Path(path)
    if suffixes and p.suffix not in suffixes:
        raise ValueError(f"argument {arg}: {path!r} must end in {' or '.join(suffixes)}")
    if p.is_dir():
        raise ValueError(f"argument {arg}: {path!r} is a folder; expected a file name")
    check_output_folder(arg, p.parent)


def _check_demo(args: argparse.Namespace) -> None:
    check_output_folder("--out", args.out)


def _check_reproduce(args: argparse.Namespace) -> None:
    check_robot("--robot", args.robot)
    check_output_folder("--out", args.out)


def _check_simulate(args: argparse.Namespace) -> None:
    if args.output is not None and args.out_option is not None:
        raise ValueError(
            f"argument output: given twice ({args.output!r} and --out {args.out_option!r});"
            " give one"
        )
    if args.output is None and args.out_option is None:
        raise ValueError(
            "argument output: missing: the .h5 file to write, e.g. jax-contact simulate"
            " out/go1.h5 (or --out out/go1.h5)"
        )
    args.output = args.output or args.out_option
    check_output_file("output", args.output, LOG_SUFFIXES)
    check_robot("--robot", args.robot)
    estimate_cmd.gait_overrides(args)  # ValueError naming the flag


def _check_evaluate(args: argparse.Namespace) -> None:
    check_input_file("log", args.log)
    check_output_file("--json", args.json)
    if args.gm_grid:
        check_input_file("--gm-grid", args.gm_grid)
    if args.params:
        check_params_source("--params", args.params)


def _check_train(args: argparse.Namespace) -> None:
    check_output_folder("--out", args.out)
    have = ("tiny", *TASK_CONFIGS[args.task])
    if args.config not in have:
        raise ValueError(
            f"argument --config: the {args.task} task has no {args.config!r} configuration"
            f" ({', '.join(have)})"
        )


def _check_policy_eval(args: argparse.Namespace) -> None:
    run = Path(args.run)
    if not run.is_dir():
        raise ValueError(f"argument run: folder {args.run!r} does not exist")
    if not (run / "run.json").is_file():
        raise ValueError(
            f"argument run: {args.run!r} is not a run folder of `jax-contact train` (no run.json)"
        )
    check_output_file("--json", args.json)


def _check_json(args: argparse.Namespace) -> None:
    check_output_file("--json", args.json)


# -------------------------------------------------------------------------------- parser


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default, except the uninformative None and False."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """The ``jax-contact`` parser; each command has ``func`` (run) and ``check`` (validate)."""
    parser = argparse.ArgumentParser(
        prog="jax-contact",
        description="Probabilistic foot contact estimation (Hwangbo et al., IROS 2016) in JAX.",
        formatter_class=_HelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def command(name, help, func, check, description=None):
        p = sub.add_parser(
            name, help=help, description=description or help, formatter_class=_HelpFormatter
        )
        p.set_defaults(func=func, check=check)
        return p

    robots = f"one of {', '.join(ROBOT_NAMES)}, or a path to an MJCF .xml file"
    p = command(
        "demo",
        "the reproduction at its default size (what `make demo` runs)",
        _cmd_demo,
        _check_demo,
    )
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--seed", type=int, default=0, help="evaluation seed")
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
        help=f"quadruped of Table III (default: go1): {robots}",
    )
    p.add_argument("--seed", type=int, default=None, help="evaluation seed (default: 0)")
    p.add_argument("--out", default="out/reproduce", help="output folder")
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
    p.add_argument("--envs", type=_positive_int, default=16, help="robots simulated at once")
    p.add_argument("--duration", type=_positive_float, default=10.0, help="simulated seconds")
    p.add_argument("--seed", type=int, default=0, help="seeds states, commands and noise")
    estimate_cmd.add_feet_flag(p)
    estimate_cmd.add_gait_flags(p)

    p = command(
        "evaluate",
        "run the estimator and baselines on a saved log",
        _cmd_evaluate,
        _check_evaluate,
        description="Runs the estimator, the generalized-momentum observer and a kinematic"
        " detector on a log and prints their metrics against the log's ground truth. A log"
        " without ground truth (no truth/contact) has no metrics: then the estimator's mean"
        " P(contact) per foot is printed, and --json gets it per step and env.",
    )
    p.add_argument("log", help="an .h5 log written by `jax-contact simulate`")
    p.add_argument("--json", default=None, help="write the metrics (or P(contact)) here")
    estimate_cmd.add_feet_flag(p)
    p.add_argument(
        "--gm-grid",
        default=None,
        metavar="LOG",
        help="tune the GM observer on this other log (jax_contact.train.reproduce's grid, best F1)",
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE|PRESET",
        help="estimator parameters: a jc.save_params file or a shipped preset (go1, spot, barkour)",
    )
    estimate_cmd.add_terrain_model_flag(p)
    estimate_cmd.add_parser(sub)
    tune_cmd.add_parser(sub)
    deploy_cmd.add_parsers(sub)

    p = command(
        "train",
        "PPO (Go1 joystick or the hop, --task) with no / true / estimated contact observed",
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
        help="small: this 2-core CPU, <= 20 min per variant; full (go1): a GPU; reduced (hop):"
        " a third of small, docs/training_hop.md's run; tiny: 160 steps of 8 envs, checks that"
        " every step runs (learns nothing)",
    )
    p.add_argument(
        "--task",
        choices=TASKS,
        default="go1",
        help="go1: Playground's Go1 joystick; hop: the planar leg hopping to a commanded apex"
        " height, where contact timing matters (docs/training_hop.md)",
    )
    p.add_argument(
        "--timesteps",
        type=_positive_int,
        default=None,
        help="env steps to train (default: the configuration's); trained exactly, with fewer"
        " evaluations if needed, or rounded up to a whole training step (a message says so)",
    )
    p.add_argument("--seed", type=int, default=0, help="PPO seed")
    p.add_argument(
        "--eval-envs",
        type=_nonnegative_int,
        default=64,
        help="episodes of the final evaluation; 0 skips it (`policy-eval` evaluates a run later)",
    )
    p.add_argument("--out", default="out/train", help="output folder (a run folder per variant)")
    p.add_argument("--overwrite", action="store_true", help="replace existing run folders")

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
        " estimate_lat1/2 (the training sensors 1/2 env steps late), truth, estimate",
    )
    p.add_argument("--envs", type=_positive_int, default=64, help="episodes, run in parallel")
    p.add_argument("--seed", type=int, default=12345, help="seeds the episodes")
    p.add_argument("--json", default=None, help="write the evaluation here")

    p = command(
        "rates",
        "estimator at every physics step vs once per control step, same rollouts",
        _cmd_rates,
        _check_json,
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
    p.add_argument("--seed", type=int, default=0, help="seed of the rollouts")
    p.add_argument(
        "--pairing",
        default="delayed",
        choices=("delayed", "raw"),
        help="state the differenced acceleration is paired with (ContactObsConfig.pairing)",
    )
    p.add_argument("--json", default=None, help="write the results here")

    p = command(
        "bench",
        "estimator throughput, latency and memory; ratio to mjx.step, NumPy, sharding",
        _cmd_bench,
        _check_json,
    )
    p.add_argument("--json", default=None, help="write every result as one JSON here")
    p.add_argument(
        "--envs",
        type=_positive_int,
        nargs="+",
        default=None,
        help="throughput batch sizes (default: jax_contact.benchmarks.estimator's)",
    )
    p.add_argument(
        "--versus-envs",
        type=_positive_int,
        nargs="+",
        default=None,
        help="batch sizes vs mjx.step; the largest, rounded up to a multiple of 8, is also"
        " the sharding check's (default: 1024 4096)",
    )
    p.add_argument(
        "--latency-calls",
        type=_positive_int,
        default=None,
        help="timed calls per single-robot latency row (default: 10000)",
    )
    return parser


# ------------------------------------------------------------------------------- Ctrl-C


class _StopOnInterrupt:
    """Context manager: while active, SIGINT ends the process at once (module docstring).

    Outside the main thread (where Python cannot install signal handlers) it does nothing
    and Python's ``KeyboardInterrupt`` applies.
    """

    def __init__(self, prog: str):
        self.prog = prog
        self._active = False

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)  # set_wakeup_fd requires it
        self._watcher = threading.Thread(target=self._watch, name="jax-contact-sigint", daemon=True)
        self._watcher.start()
        # Wake-up fd first: a SIGINT between the two calls then still reaches the watcher.
        self._old_fd = signal.set_wakeup_fd(self._write, warn_on_full_buffer=False)
        self._old_handler = signal.signal(signal.SIGINT, self._note)
        self._active = True
        return self

    @staticmethod
    def _note(signum, frame) -> None:
        # Runs in the main thread whenever it next runs Python code (possibly inside a GC
        # callback, where an exception would be swallowed): nothing to do here, the
        # watcher has already been woken by the C-level handler through the wake-up fd.
        del signum, frame

    def _watch(self) -> None:
        while True:
            try:
                data = os.read(self._read, 64)
            except OSError:
                return
            if not data:  # the write end was closed: the command finished
                return
            if signal.SIGINT in data:
                self._stop()

    def _stop(self) -> None:
        io = sys.modules.get("jax_contact.io")  # not imported: nothing was being written
        if io is not None:
            io.abort_writes()  # holds io's lock from here on: no rename can follow
        # Flush what was printed, but never wait on a main thread stuck mid-write.
        flusher = threading.Thread(target=_flush_std, daemon=True)
        flusher.start()
        flusher.join(0.5)
        try:
            os.write(2, f"{self.prog}: interrupted\n".encode())
        finally:
            os._exit(EXIT_INTERRUPTED)

    def __exit__(self, *exc) -> None:
        if not self._active:
            return
        signal.signal(signal.SIGINT, self._old_handler)
        signal.set_wakeup_fd(self._old_fd)
        os.close(self._write)
        self._watcher.join(1.0)
        os.close(self._read)
        self._active = False


def _flush_std() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # a closed or broken stream: nothing more to save
            pass


# ---------------------------------------------------------------------------------- main


def _quiet_xla_logs() -> None:
    """Silences XLA's C++ log lines (module docstring) unless the user chose a level."""
    if "jax" not in sys.modules:  # read when JAX loads XLA; later changes do nothing
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")


CACHE_ENV = "JAX_CONTACT_CACHE_DIR"


def host_tag(cpuinfo: str | None = None) -> str:
    """A folder name for this host's CPU: its architecture and a hash of its instruction-set
    features (the ``flags`` of ``/proc/cpuinfo``, else the processor's name).

    XLA:CPU compiles for the features of the host it runs on and loads a cached program
    built for other features with only a warning ("could lead to execution errors such as
    SIGILL"): a home folder shared by hosts of different CPUs must not share programs.

    Args:
      cpuinfo: the text of ``/proc/cpuinfo`` (read when None and present).
    """
    import hashlib
    import platform

    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
                cpuinfo = f.read()
        except OSError:
            cpuinfo = ""
    flags = next(
        (
            line.split(":", 1)[1]
            for line in cpuinfo.splitlines()
            if line.split(":")[0].strip() in ("flags", "Features")
        ),
        platform.processor(),
    )
    digest = hashlib.sha256(" ".join(sorted(flags.split())).encode()).hexdigest()[:12]
    return f"{platform.machine() or 'cpu'}-{digest}"


def compilation_cache_dir() -> str | None:
    """jax-contact's persistent compilation cache folder, or None when turned off:
    ``$JAX_CONTACT_CACHE_DIR`` if set (empty: off), else
    ``$XDG_CACHE_HOME/jax-contact/xla/<host_tag()>`` (``~/.cache/jax-contact/xla/...``), one
    folder per CPU feature set."""
    if CACHE_ENV in os.environ:
        return os.environ[CACHE_ENV].strip() or None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "jax-contact", "xla", host_tag())


def enable_compilation_cache() -> str | None:
    """Turns on JAX's persistent compilation cache (module docstring); returns its folder,
    or None when it is off or its folder cannot be created.

    Set through JAX's environment variables, before JAX is imported, so that subprocesses
    (``bench``'s sharding check) share it; when JAX is already imported (a test calling
    :func:`main`), through ``jax.config``, unless a cache folder is configured already.
    """
    folder = os.environ.get("JAX_COMPILATION_CACHE_DIR") or compilation_cache_dir()
    if not folder:
        return None
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:  # e.g. a read-only home: run without the cache
        return None
    settings = {
        "jax_compilation_cache_dir": folder,
        # Keep every program: the measured default thresholds skip most of this code's.
        "jax_persistent_cache_min_compile_time_secs": "0",
        "jax_persistent_cache_min_entry_size_bytes": "0",
    }
    for name, value in settings.items():  # read by JAX when it is imported, here or in a child
        os.environ.setdefault(name.upper(), value)
    jax = sys.modules.get("jax")
    if jax is not None:
        if jax.config.jax_compilation_cache_dir is None:
            jax.config.update("jax_compilation_cache_dir", folder)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def main(argv: list[str] | None = None) -> int:
    """Runs ``jax-contact`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code:
    0, 2 for a bad argument or input (one line on stderr), 130 when interrupted."""
    parser = build_parser()
    args = parser.parse_args(argv)
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
        with _StopOnInterrupt(prog):
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


if __name__ == "__main__":
    sys.exit(main())
