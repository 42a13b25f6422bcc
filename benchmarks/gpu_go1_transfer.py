"""The Go1 joystick transfer matrix in one device command (issue 19; prepared, unrun on a GPU).

Trains the three variants (``none``, ``truth``, ``estimate``; one seed each by default) at
Playground's Go1 configuration (:data:`jax_contact.train.ppo.FULL`: 8192 envs, its PPO
hyper-parameters and networks) for a *budget* of env steps, then evaluates the latest
checkpoints in every column of :data:`jax_contact.train.transfer.COLUMNS`
(:func:`jax_contact.train.transfer.transfer_matrix`), all within one command of the device
tool (at most 10 minutes). ``benchmarks/gpu_go1_transfer.sh`` installs the carried wheels
and runs this; docs/training.md ("Transfer matrix on Go1") has the commands.

Time. Compilation is most of a short run, so the processes run side by side on the
machine's 16 cores: one training process per (variant, seed), then one matrix process per
column (and one for the ``none`` row), each with an equal share of the GPU's memory.

- Training budget: ``--timesteps`` env steps per variant; by default ``--train-s`` seconds
  at ``--assumed-sps`` env steps/s per variant, rounded to whole epochs. The default
  assumption, 1e5 env steps/s per variant while the three train together (3e5 in all), is
  an *estimate*, not a measurement: Playground's Go1 joystick trains at roughly 1e5-1e6 env
  steps/s on one modern GPU, and the physics-rate estimator costs ~1.5x the bare env step
  (docs/training.md, "Throughput"). The JSON records the measured rate, to size the next run.
- Guards: a training process stops at its first evaluation after ``--train-deadline-s``
  (seconds since this script started; its latest checkpoint is kept and evaluated), and
  matrix processes still running at ``--matrix-deadline-s`` are killed (their cells are
  missing from the JSON; their finished lines are in the log).

Writes into ``--out`` (at most 8 files, as the device tool returns): ``transfer.json`` (the
matrix, the settings, each run's curve and measured rate, versions), ``train_<variant>_s
<seed>.log`` per run, ``matrix.log`` and ``runs.tar.gz`` (each run's run.json, CSVs and
latest checkpoint, to evaluate again elsewhere). The run folders themselves go to
``--runs`` (not ``--out``: a checkpoint is many files).

    python -m jax_contact.benchmarks.gpu_go1_transfer --out $OUT --runs /tmp/go1_runs
    python -m jax_contact.benchmarks.gpu_go1_transfer --config tiny --timesteps 320 \\
        --episode-length 20 --eval-envs 4 --out /tmp/o --runs /tmp/r   # the CPU check
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import subprocess
import sys
import tarfile
import time
from collections.abc import Sequence
from pathlib import Path

# The CLI's argument types (the module imports only the standard library).
from jax_contact.train.cli_args import (
    HelpFormatter,
    check_no_repeats,
    check_output_folder,
    positive_float,
    positive_int,
    seed_int,
)

COLUMNS = ("truth", "estimate", "estimate_harsh", "estimate_lat1", "estimate_lat2")
VARIANTS = ("none", "truth", "estimate")
_MODULE = "jax_contact.benchmarks.gpu_go1_transfer"
_STEP_LINE = re.compile(r"\] step +([0-9,]+)/")  # ppo.train's line of an evaluation


class DeadlineReached(Exception):
    """Raised from a training process's log at an evaluation after its deadline."""


# ---------------------------------------------------------------------------- config


def config_for(name: str, num_evals: int):
    """The :class:`jax_contact.train.ppo.PPOConfig` called ``name`` (``full``, ``small`` or
    ``tiny``, the CLI's), with ``num_evals`` evaluations."""
    from jax_contact.train import cli, ppo

    if name == "tiny":
        cfg = dataclasses.replace(ppo.SMALL, **cli.TINY_PPO)
    elif name in ppo.CONFIGS:
        cfg = ppo.CONFIGS[name]
    else:
        raise ValueError(f"config must be 'tiny' or one of {tuple(ppo.CONFIGS)}, got {name!r}")
    return dataclasses.replace(cfg, num_evals=int(num_evals))


def budget_timesteps(cfg, requested: int) -> int:
    """``requested`` env steps rounded to whole epochs of ``cfg`` (at least one).

    An epoch (between two evaluations) is ``max(num_resets_per_eval, 1)`` training steps of
    ``steps_per_training_step`` env steps; Brax PPO trains ``num_evals - 1`` of them.
    """
    epochs = max(cfg.num_evals - 1, 1)
    unit = epochs * max(cfg.num_resets_per_eval, 1) * cfg.steps_per_training_step
    return unit * max(1, round(int(requested) / unit))


# ----------------------------------------------------------------------- subprocesses


def _child_env(n_share: int) -> dict:
    env = dict(os.environ)
    # Each of n_share processes gets an equal part of the GPU's memory (JAX takes 75 %
    # by default, which would leave nothing to the next process).
    env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{0.9 / max(n_share, 1):.3f}"
    env.setdefault("JAX_CONTACT_PROGRESS", "0")
    return env


def _spawn(argv: list[str], log_path: Path, n_share: int) -> subprocess.Popen:
    f = open(log_path, "w")  # noqa: SIM115 (closed with the process, in _wait)
    p = subprocess.Popen(
        [sys.executable, "-m", _MODULE, *argv],
        stdout=f,
        stderr=subprocess.STDOUT,
        env=_child_env(n_share),
    )
    p.log_file = f
    return p


def _wait(procs: list[subprocess.Popen], deadline: float | None) -> list[int | None]:
    """Waits for every process; kills those running at ``deadline`` (time.time()).
    Returns their exit codes (None: killed)."""
    codes: list[int | None] = []
    for p in procs:
        try:
            left = None if deadline is None else max(deadline - time.time(), 0.1)
            codes.append(p.wait(timeout=left))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
            codes.append(None)
        p.log_file.close()
    return codes


# -------------------------------------------------------------------------- children


def deadline_log(stop_at: float | None, out=print):
    """A ``log`` for :func:`jax_contact.train.ppo.train` that stops training at a deadline.

    ``ppo.train`` logs one ``[variant] step N/...`` line per evaluation, after Brax has
    saved that evaluation's checkpoint; the first such line with N > 0 after ``stop_at``
    (``time.time()``) raises :class:`DeadlineReached` through Brax's loop, leaving that
    checkpoint the latest. Step 0 (the evaluation before training) has no checkpoint, so
    it never stops there. None: never.
    """

    def log(msg: str) -> None:
        out(msg, flush=True)
        m = _STEP_LINE.search(msg)
        if stop_at is not None and m and int(m.group(1).replace(",", "")) > 0:
            if time.time() > stop_at:
                raise DeadlineReached(msg)

    return log


def _train_child(args: argparse.Namespace) -> int:
    """One (variant, seed) training run; stops at an evaluation after ``--stop-at``."""
    from jax_contact.train import cli, ppo

    cli.enable_compilation_cache()
    cfg = config_for(args.config, args.num_evals)
    cfg = dataclasses.replace(cfg, num_timesteps=args.timesteps)
    log = deadline_log(args.stop_at)
    t0 = time.perf_counter()
    try:
        ppo.train(args.variant, cfg, Path(args.runs) / f"seed{args.seed}", seed=args.seed, log=log)
        stopped = False
    except DeadlineReached:
        print(f"[{args.variant}] deadline reached: stopped, its latest checkpoint is kept")
        stopped = True
    print(json.dumps({"train_wall_s": round(time.perf_counter() - t0, 1), "stopped": stopped}))
    return 0


def _matrix_child(args: argparse.Namespace) -> int:
    """The matrix of ``--variants`` in ``--columns``, written to ``--part``."""
    from jax_contact.io import write_json_atomic
    from jax_contact.train import cli, transfer

    cli.enable_compilation_cache()
    runs = transfer.runs_under(args.runs, variants=args.variants)
    res = transfer.transfer_matrix(
        runs,
        columns=args.columns,
        n_envs=args.eval_envs,
        episode_length=args.episode_length,
        seed=args.eval_seed,
        log=lambda m: print(m, flush=True),
    )
    write_json_atomic(args.part, res)
    return 0


# --------------------------------------------------------------------------- parent


def _versions() -> dict:
    import importlib.metadata as md

    # The parent only reads the devices: without this JAX would reserve 75 % of the GPU's
    # memory for it, and the training children's shares (_child_env) would not fit.
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    import jax

    out = {"python": sys.version.split()[0], "backend": jax.default_backend()}
    out["devices"] = [str(d) for d in jax.devices()]
    for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "playground", "flax", "optax"):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = None
    from jax_contact.train import _compat

    out["device_put_replicated_shim"] = not hasattr(jax, "device_put_replicated")
    _compat.install()
    return out


def merge_parts(parts: Sequence[dict], columns: Sequence[str]) -> dict:
    """One matrix from per-column parts: the ``none`` row's one evaluation in every column.

    Args:
      parts: :func:`jax_contact.train.transfer.transfer_matrix` results, each over some
        columns and variants (``none`` in one part, any column).
      columns: the columns of the merged matrix, in order.

    Returns:
      The merged result (``cells`` of the variants and columns found; ``missing`` lists
      the ``variant/column`` cells no part had).
    """
    cells: dict = {}
    for part in parts:
        for variant, row in part["cells"].items():
            if variant == "none":
                one = next(iter(row.values()))
                row = {c: one for c in columns}
            cells.setdefault(variant, {}).update(row)
    order = [v for v in VARIANTS if v in cells] + [v for v in cells if v not in VARIANTS]
    cells = {v: {c: cells[v][c] for c in columns if c in cells[v]} for v in order}
    missing = [f"{v}/{c}" for v in VARIANTS for c in columns if c not in cells.get(v, {})]
    first = parts[0] if parts else {}
    return {
        "task": first.get("task"),
        "metrics": first.get("metrics", []),
        "cells": cells,
        "columns": list(columns),
        "n_envs": first.get("n_envs"),
        "seed": first.get("seed"),
        "missing": missing,
    }


def _curve(run_dir: Path) -> dict:
    from jax_contact.train import ppo

    out: dict = {"run": str(run_dir)}
    for name in ("progress.csv", "training.csv"):
        try:
            out[name[:-4]] = ppo.read_progress(run_dir, name)
        except FileNotFoundError:
            out[name[:-4]] = []
    rows = out["progress"]
    if len(rows) >= 2 and rows[-1]["wall_s"] > rows[1]["wall_s"]:
        # Env steps per second between the first trained evaluation and the last: the
        # training rate without the compilation (evaluations included).
        steps = rows[-1]["step"] - rows[1]["step"]
        out["measured_sps"] = round(steps / (rows[-1]["wall_s"] - rows[1]["wall_s"]))
    if rows:
        out["first_eval_s"] = rows[0]["wall_s"]
    return out


def _tar_runs(runs: Path, path: Path) -> None:
    """Each run's run.json, CSVs and latest checkpoint, as one file (written atomically: a
    run stopped at its deadline while taring leaves no truncated archive)."""
    from jax_contact.io import write_atomic

    write_atomic(path, lambda tmp: _tar_into(runs, tmp))


def _tar_into(runs: Path, path) -> None:
    from jax_contact.train import policy_eval

    with tarfile.open(path, "w:gz") as tar:
        for run_json in sorted(runs.glob("seed*/*/run.json")):
            run = run_json.parent
            for name in ("run.json", "progress.csv", "training.csv"):
                if (run / name).is_file():
                    tar.add(run / name, arcname=str((run / name).relative_to(runs)))
            try:
                ckpt = policy_eval.latest_checkpoint(run)
            except FileNotFoundError:
                continue
            tar.add(ckpt, arcname=str(ckpt.relative_to(runs)))


def run(args: argparse.Namespace) -> dict:
    """Trains, evaluates and writes everything (module docstring)."""
    from jax_contact.io import write_json_atomic, write_text_atomic
    from jax_contact.train import transfer

    t_start = args.started_at or time.time()
    out, runs = Path(args.out).resolve(), Path(args.runs).resolve()
    out.mkdir(parents=True, exist_ok=True)
    runs.mkdir(parents=True, exist_ok=True)
    cfg = config_for(args.config, args.num_evals)
    requested = args.timesteps or int(args.train_s * args.assumed_sps)
    timesteps = budget_timesteps(cfg, requested)
    result: dict = {
        "settings": {
            "config": args.config,
            "ppo_config": dataclasses.asdict(dataclasses.replace(cfg, num_timesteps=timesteps)),
            "timesteps_per_variant": timesteps,
            "requested_timesteps": requested,
            "assumed_sps_per_variant": None if args.timesteps else args.assumed_sps,
            "train_s": None if args.timesteps else args.train_s,
            "seeds": args.seeds,
            "variants": args.variants,
            "eval_envs": args.eval_envs,
            "episode_length": args.episode_length or cfg.episode_length,
            "train_deadline_s": args.train_deadline_s,
            "matrix_deadline_s": args.matrix_deadline_s,
        },
        "versions": _versions(),
    }
    print(f"[gpu_go1_transfer] {json.dumps(result)}", flush=True)
    write_json_atomic(out / "transfer.json", result)

    # 1. Training: every (variant, seed) at once.
    jobs = [(v, s) for s in args.seeds for v in args.variants]
    t0 = time.time()
    procs = [
        _spawn(
            [
                "train",
                v,
                "--seed",
                str(s),
                "--config",
                args.config,
                "--num-evals",
                str(args.num_evals),
                "--timesteps",
                str(timesteps),
                "--runs",
                str(runs),
                "--stop-at",
                str(t_start + args.train_deadline_s),
            ],
            out / f"train_{v}_s{s}.log",
            len(jobs),
        )
        for v, s in jobs
    ]
    codes = _wait(procs, t_start + args.matrix_deadline_s)
    result["training"] = {
        f"{v}/seed{s}": {"exit": c, **_curve(runs / f"seed{s}" / v)}
        for (v, s), c in zip(jobs, codes, strict=True)
    }
    result["training_wall_s"] = round(time.time() - t0, 1)
    print(f"[gpu_go1_transfer] training done in {result['training_wall_s']} s", flush=True)
    write_json_atomic(out / "transfer.json", result)

    # 2. The matrix: one process per column, one for the none row (it sees no contact).
    t0 = time.time()
    trained = [v for v in args.variants if v != "none"]
    groups = ([(["none"], [args.columns[0]])] if "none" in args.variants else []) + [
        (trained, [c]) for c in args.columns if trained
    ]
    part_paths = [runs / f"part{i}.json" for i in range(len(groups))]
    for p in part_paths:  # an earlier run's parts would be merged as this run's cells
        p.unlink(missing_ok=True)
    common = ["--runs", str(runs), "--eval-envs", str(args.eval_envs)]
    common += ["--eval-seed", str(args.eval_seed)]
    if args.episode_length:
        common += ["--episode-length", str(args.episode_length)]
    procs = []
    for i, (variants, cols) in enumerate(groups):
        argv = ["matrix", "--variants", *variants, "--columns", *cols, "--part"]
        procs.append(
            _spawn([*argv, str(part_paths[i]), *common], runs / f"matrix{i}.log", len(groups))
        )
    codes = _wait(procs, t_start + args.matrix_deadline_s)
    mlog = "".join(
        f"--- matrix process {i} {groups[i]}: exit {c}\n" + (runs / f"matrix{i}.log").read_text()
        for i, c in enumerate(codes)
    )
    write_text_atomic(out / "matrix.log", mlog)
    parts = [json.loads(p.read_text()) for p in part_paths if p.is_file()]
    matrix = merge_parts(parts, args.columns)
    matrix["wall_s"] = round(time.time() - t0, 1)
    result["matrix"] = matrix
    result["wall_s"] = round(time.time() - t_start, 1)
    write_json_atomic(out / "transfer.json", result)
    for metric in matrix["metrics"]:
        rows = {v: r for v, r in matrix["cells"].items() if all(c in r for c in args.columns)}
        if rows:
            table = transfer.format_matrix({"columns": args.columns, "cells": rows}, metric)
            print(f"\n{metric}\n{table}", flush=True)
    print(f"[gpu_go1_transfer] missing cells: {matrix['missing']}", flush=True)
    if args.keep_checkpoints:
        _tar_runs(runs, out / "runs.tar.gz")
    print(f"[gpu_go1_transfer] done in {result['wall_s']} s; {out}", flush=True)
    return result


# ---------------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="role")
    p = sub.add_parser(
        "run",
        help="train and evaluate (the default)",
        description="Trains every variant, then evaluates the latest checkpoints in every"
        " column (module docstring); writes at most 8 files into --out.",
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "--out",
        default=os.environ.get("OUT", "out/gpu_go1_transfer"),
        help="folder of transfer.json and the logs (the device tool's $OUT)",
    )
    p.add_argument("--runs", default="/tmp/go1_runs", help="run folders (not copied to --out)")
    p.add_argument(
        "--config",
        default="full",
        choices=("full", "small", "tiny"),
        help="PPO configuration: Playground's Go1 (full), a smaller one, or tiny (a CPU check)",
    )
    p.add_argument(
        "--variants",
        nargs="+",
        default=list(VARIANTS),
        choices=VARIANTS,
        help="what the policy observes in training (one run per variant and seed)",
    )
    p.add_argument(
        "--seeds", nargs="+", type=seed_int, default=[0], help="one run per variant each"
    )
    p.add_argument("--num-evals", type=positive_int, default=6, help="evaluations per run")
    p.add_argument(
        "--timesteps",
        type=positive_int,
        default=None,
        help="env steps per variant (rounded to whole epochs); default: train-s x assumed-sps",
    )
    p.add_argument(
        "--train-s", type=positive_float, default=160.0, help="training seconds per variant"
    )
    p.add_argument(
        "--assumed-sps",
        type=positive_float,
        default=1e5,
        help="env steps/s per variant while all train together: an estimate (module docstring)",
    )
    p.add_argument(
        "--train-deadline-s",
        type=positive_float,
        default=360.0,
        help="seconds after the start at which a training run stops at its next evaluation"
        " (its latest checkpoint is kept)",
    )
    p.add_argument(
        "--matrix-deadline-s",
        type=positive_float,
        default=555.0,
        help="seconds after the start at which matrix processes still running are killed"
        " (their cells missing)",
    )
    p.add_argument(
        "--columns",
        nargs="+",
        default=list(COLUMNS),
        choices=COLUMNS,
        help="the contact signals each policy is evaluated observing",
    )
    p.add_argument("--eval-envs", type=positive_int, default=128, help="episodes per cell")
    p.add_argument(
        "--episode-length",
        type=positive_int,
        default=None,
        help="env steps per evaluation episode; default: the configuration's",
    )
    p.add_argument("--eval-seed", type=seed_int, default=12345, help="seeds the episodes")
    p.add_argument(
        "--no-checkpoints",
        dest="keep_checkpoints",
        action="store_false",
        help="write no runs.tar.gz of the runs' latest checkpoints",
    )
    p.add_argument("--started-at", type=float, default=None, help="time.time() of the start")

    t = sub.add_parser("train", help="(internal) one training run")
    t.add_argument("variant", choices=VARIANTS)
    t.add_argument("--seed", type=int, required=True)
    t.add_argument("--config", required=True)
    t.add_argument("--num-evals", type=int, required=True)
    t.add_argument("--timesteps", type=int, required=True)
    t.add_argument("--runs", required=True)
    t.add_argument("--stop-at", type=float, default=None)

    m = sub.add_parser("matrix", help="(internal) part of the matrix")
    m.add_argument("--variants", nargs="+", required=True)
    m.add_argument("--columns", nargs="+", required=True)
    m.add_argument("--part", required=True)
    m.add_argument("--runs", required=True)
    m.add_argument("--eval-envs", type=int, required=True)
    m.add_argument("--eval-seed", type=int, required=True)
    m.add_argument("--episode-length", type=int, default=None)
    return parser


def check_run_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Exits 2 naming the argument before anything runs: output folders that cannot be
    written, repeats, deadlines out of order, and run folders of an earlier run in
    ``--runs`` (every training child would refuse them, and the matrix would evaluate the
    earlier run's checkpoints as this run's)."""
    try:
        check_output_folder("--out", args.out)
        check_output_folder("--runs", args.runs)
        check_no_repeats("--seeds", args.seeds, "seed")
        check_no_repeats("--variants", args.variants, "variant")
        check_no_repeats("--columns", args.columns, "column")
    except ValueError as err:
        parser.error(str(err))
    if args.train_deadline_s >= args.matrix_deadline_s:
        parser.error(
            f"argument --train-deadline-s: {args.train_deadline_s:g} s leaves the matrix no"
            f" time before --matrix-deadline-s {args.matrix_deadline_s:g} s"
        )
    earlier = [
        f"seed{s}/{v}" for s in args.seeds for v in args.variants
        if (Path(args.runs) / f"seed{s}" / v).exists()
    ]  # fmt: skip
    if earlier:
        parser.error(
            f"argument --runs: {args.runs} already holds run folders ({', '.join(earlier)}):"
            " pass an empty folder, or remove them"
        )


def main(argv: Sequence[str] | None = None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in ("run", "train", "matrix", "-h", "--help"):
        argv = ["run", *argv]
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.role == "run":
        check_run_args(parser, args)
    if args.role == "train":
        return _train_child(args)
    if args.role == "matrix":
        return _matrix_child(args)
    return run(args)


if __name__ == "__main__":
    res = main()
    sys.exit(res if isinstance(res, int) else 0)
