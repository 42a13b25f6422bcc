"""``jax-contact tune LOG [LOG ...] --validate LOG --out params.json``: gradient tuning.

Fits the estimator's continuous parameters to logs with ground truth
(:mod:`jax_contact.tune` states the loss, what is tuned and how), prints one progress line
per epoch (loss, validation BCE, F1 and ECE) and writes the tuned parameters as the
versioned parameter JSON of :func:`jax_contact.save_params`, with their provenance: the
logs (path, robot, gait, terrain, noise, seed), the tuning settings and seed, the loss and
validation metrics of every epoch, the epoch kept, the tuned values next to the defaults,
the wall time, the library and JAX versions and, with ``--calibrate``, the calibration map
fitted on the tuning logs (``provenance["calibration"]``, see
:class:`jax_contact.tune.Calibration`).

Like ``train/cli.py``, this module imports no JAX at module level: :func:`check`
validates the arguments first, and :func:`run` imports the library. Register it in the
CLI with ``tune_cmd.add_parser(sub)``; ``python -m jax_contact.train.tune_cmd ...`` runs it alone.

The default parameters that tuning starts from (and that the prior is centred on) are
the ones ``jax-contact evaluate`` uses for the log's robot
(:func:`jax_contact.train.log_estimator.default_estimator`): ``params_for`` with the log's
sensor preset (``anymal_like`` unless the log says otherwise), the default gait prior and
the force axes and sign test read from the robot's model; Section III's estimator for the
planar leg.

With ``--model ROBOT`` the inputs are recordings of your own robot with ground truth
(``contact/<foot>`` or ``force/<foot>`` columns; the schema of ``jax-contact estimate``,
read with its ``--feet``, ``--names``, ``--units``, ``--resample`` and
``--force-threshold``), and the fit starts from the parameters ``estimate`` uses for that
robot (:func:`jax_contact.train.tune_data.load_tuning_recording`). What is loaded, and
which sets of logs are refused: :mod:`jax_contact.train.tune_inputs`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# What used to live here, re-exported: the shipped presets' provenance names
# ``jax_contact.train.tune_cmd.regenerate_preset`` as their command.
from jax_contact.train.tune_data import (  # noqa: F401
    default_params,
    load_tuning_log,
    measure_readings,
    read_truth_log,
    sensor_floor,
)
from jax_contact.train.tune_inputs import Inputs, load_logs
from jax_contact.train.tune_presets import (  # noqa: F401
    PRESET_EVENT_WEIGHTS,
    PRESET_ROBOTS,
    PRESET_TUNE,
    PRESET_TUNE_ALSO,
    PRESET_VALIDATE,
    SCENARIOS,
    compare,
    format_comparison,
    regenerate_preset,
    scenario_world,
    simulate_log,
)

LOG_SUFFIXES = (".h5", ".hdf5")
# Copy of jax_contact.train.recording.SUFFIXES (estimate_cmd.RECORDING_SUFFIXES).
RECORDING_SUFFIXES = (".csv", ".npz", ".h5", ".hdf5")
# The flags that say how a recording is read; only with --model.
RECORDING_FLAGS = {"feet": None, "names": None, "units": "rad", "resample": False}
# Copies of jax_contact.tune.DEFAULT_FIELDS and OPTIONAL_FIELDS (importing it imports JAX);
# tests/test_tune.py checks that they agree.
DEFAULT_FIELDS = (
    "sigma_q",
    "sigma_qd",
    "sigma_qdd",
    "sigma_d",
    "sigma_f",
    "sigma_J",
    "sigma_qd_prior",
    "cap_dynamics",
    "cap_diff_kinematics",
    "cap_diff_kinematics_still",
    "cap_kinematics",
    "cap_transition",
    "stance_time",
    "takeoff_accel",
)
OPTIONAL_FIELDS = ("contact_damping",)


# -------------------------------------------------------------------------- arguments


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Adds the ``tune`` command to an argparse subparsers object; returns its parser.

    The parser's defaults carry ``func=run`` and ``check=check``, as ``train/cli.py``'s
    commands do.
    """
    from jax_contact.train.cli_args import HelpFormatter

    p = subparsers.add_parser(
        "tune",
        help="tune the estimator's parameters by gradient on logs with ground truth",
        description="Fits the estimator's noise standard deviations (log space, with a prior"
        " at their physically derived values), confidence caps (logit space), T_s and a_F to"
        " the binary cross-entropy of P(contact) (plus a per-air-phase event term and a"
        " prior; jax_contact.tune) against the ground truth of simulated logs"
        " (or, with --model, of your robot's recordings), with Adam, gradient clipping and"
        " early stopping on --validate (logs of other seeds, recordings of other runs). Writes"
        " a versioned parameter JSON with its provenance, which `jax_contact.load_params`"
        " reads.",
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "logs",
        nargs="+",
        metavar="LOG",
        help="tuning logs (.h5 of jax-contact simulate, with truth/contact); with --model,"
        " recordings of your robot with ground truth (.csv, .npz, .h5)",
    )
    p.add_argument(
        "--validate",
        required=True,
        nargs="+",
        metavar="LOG",
        help="validation log(s) of other seeds, or recordings of other runs (with --model):"
        " early stopping on their pooled loss (or what --select names)",
    )
    p.add_argument(
        "--model",
        "--robot",
        dest="model",
        default=None,
        help="tune on recordings of this robot (a robot name or an MJCF .xml file with a"
        " floor), read as `jax-contact estimate` reads them (docs/own_robot.md); the fit"
        " starts from estimate's defaults for it",
    )
    from jax_contact.train.estimate_cmd import (
        add_feet_flag,
        add_force_threshold_flag,
        add_recording_flags,
    )

    add_feet_flag(p, default="found in the model; with --model")
    add_recording_flags(p)
    add_force_threshold_flag(p)
    p.add_argument(
        "--terrain-model",
        choices=("flat", "memory"),  # jax_contact.train.log_estimator.TERRAIN_MODELS
        default="flat",
        help="the estimator's ground while tuning, stored in the file's provenance (evaluate"
        " and estimate then use it): flat, the plane at z = 0 (std 5 cm, 0.2 m for the planar"
        " leg); memory, where each foot last stood, for a base position that drifts"
        " (docs/model_choices.md)",
    )
    add_tuning_options(p)
    p.set_defaults(func=run, check=check)
    return p


def add_tuning_options(p: argparse.ArgumentParser) -> None:
    """The options of ``jax-contact tune`` that are not about its inputs (``--out`` and the
    fit's settings), shared with ``jax-contact tune-env``."""
    # The CLI's argument types (one rule); imported here, once jax_contact.train.cli is loaded.
    from jax_contact.train.cli_args import nonnegative_float, positive_float, positive_int, seed_int

    p.add_argument(
        "--out",
        required=True,
        help="parameter file to write (.json); an existing file is replaced only if it is one",
    )
    p.add_argument("--epochs", type=positive_int, default=12, help="passes over the logs at most")
    p.add_argument("--patience", type=positive_int, default=3, help="epochs without improvement")
    p.add_argument("--lr", type=positive_float, default=0.05, help="Adam step size")
    p.add_argument("--clip", type=positive_float, default=1.0, help="gradient norm clip")
    p.add_argument("--chunk", type=positive_int, default=400, help="steps per BPTT window")
    p.add_argument(
        "--prior", type=nonnegative_float, default=1e-3, help="weight of the prior on the stds"
    )
    p.add_argument(
        "--prior-other",
        type=nonnegative_float,
        default=1e-3,
        help="weight of the prior on caps, T_s, a_F",
    )
    p.add_argument(
        "--seed",
        type=seed_int,
        default=0,
        help="the run's key (recorded in the file), drawn only by a Monte-Carlo touch-down:"
        " the parameters tuned here use the quadrature, so the fit does not depend on it;"
        " rerun on other logs, not other seeds, to see how robust it is",
    )
    p.add_argument(
        "--air-penalty",
        type=nonnegative_float,
        default=0.0,
        help="weight of the false-contact hinge on true air steps (jax_contact.tune)",
    )
    p.add_argument(
        "--event-weight",
        type=nonnegative_float,
        default=0.3,
        help="weight of the air-phase event term (jax_contact.tune; 0: plain BCE)",
    )
    p.add_argument(
        "--event-temperature",
        type=positive_float,
        default=0.25,
        help="temperature of the event term's log-sum-exp, logit units",
    )
    p.add_argument(
        "--stance-time-bounds",
        type=positive_float,
        nargs=2,
        default=[0.15, 1.2],
        metavar=("LO", "HI"),
        help="interval T_s is tuned in, s",
    )
    p.add_argument(
        "--select",
        choices=("loss", "bce", "cells", "spread"),  # jax_contact.tune.SELECT_RULES
        default="loss",
        help="validation number that picks the epoch kept (loss: BCE + event term; cells:"
        " the lowest loss among the epochs no worse than the defaults in any validation"
        " log's F1, accuracy, ECE, swing-phase failures and mean delays; spread: the same,"
        " a cell counting as worse only beyond a 95 %% paired env-bootstrap interval)",
    )
    p.add_argument(
        "--cell-tolerance",
        type=nonnegative_float,
        default=0.0,
        help="with --select cells, how much worse than the defaults a validation cell may"
        " be, in units of jax_contact.tune.CELL_TOLERANCE (F1/accuracy/ECE 0.0005, 0.25"
        " point of swing-phase failures, 0.25 ms of delay)",
    )
    p.add_argument(
        "--constrain",
        type=nonnegative_float,
        default=0.0,
        metavar="WEIGHT",
        help="weight of the cells in the objective: each tuning window's expected errors,"
        " event term and touch-down / lift-off lateness are penalised where worse than the"
        " defaults' on that window (jax_contact.tune.constraint_penalty; 0: off)",
    )
    p.add_argument(
        "--feasible",
        action="store_true",
        help="reject an epoch whose tuning logs' cells are worse than the defaults' beyond"
        " --cell-tolerance: back to the last accepted epoch with half the learning rate"
        " (one more filter pass over the tuning logs per epoch)",
    )
    p.add_argument(
        "--noise-floor",
        choices=("sensor", "none"),
        default="sensor",
        help="sensor: no tuned std below what the log's sensor model alone gives"
        " (jax_contact.defaults.sensor_noise_floor); none: unbounded",
    )
    p.add_argument(
        "--noise-ratio",
        type=nonnegative_float,
        default=0.0,
        metavar="R",
        help="plausibility box: every tuned std within a factor R (> 1) of its derived value"
        " (8: the standing check of the shipped presets, jax_contact.tune.theta_bounds);"
        " 0: no box",
    )
    p.add_argument(
        "--calibrate",
        nargs="?",
        const="sign",
        default=None,
        choices=("sign", "affine"),  # jax_contact.tune.CALIBRATION_KINDS
        help="also fit a calibration map on the fused logit, stored in the provenance: sign"
        " (the default) one temperature per side of 0, which keeps every decision at P = 0.5;"
        " affine a temperature and a bias, which moves it",
    )
    p.add_argument(
        "--freeze",
        nargs="+",
        default=[],
        metavar="FIELD",
        help="fields kept at their defaults (e.g. stance_time takeoff_accel); the rest of"
        " jax_contact.tune.DEFAULT_FIELDS is tuned",
    )
    p.add_argument(
        "--tune-also",
        nargs="+",
        default=[],
        choices=OPTIONAL_FIELDS,
        metavar="FIELD",
        help="also tune these fields, which are kept at their derived values by default:"
        f" {', '.join(OPTIONAL_FIELDS)} (jax_contact.tune.OPTIONAL_FIELDS)",
    )
    p.add_argument("--note", default=None, help="free text stored in the provenance")


def check(args: argparse.Namespace) -> None:
    """Raises ValueError naming the argument unless the inputs exist and --out can be
    written (no JAX imported)."""
    from jax_contact.train.cli_args import check_distinct_files

    validate = [args.validate] if isinstance(args.validate, str) else list(args.validate)
    model = getattr(args, "model", None)
    # The same file twice (a path, a link or a copy), refused before JAX loads; the same
    # run under other bytes is tune_inputs' check, after the logs are read.
    check_distinct_files("LOG", args.logs)
    for arg, path in [("LOG", p) for p in args.logs] + [("--validate", v) for v in validate]:
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"argument {arg}: file {path!r} does not exist")
        if (
            model is None
            and p.suffix.lower() in RECORDING_SUFFIXES
            and p.suffix.lower() not in LOG_SUFFIXES
        ):
            raise ValueError(
                f"argument {arg}: {path!r} is a recording: tune on recordings of your robot"
                " with --model ROBOT (read as `jax-contact estimate` reads them)"
            )
        suffixes = LOG_SUFFIXES if model is None else RECORDING_SUFFIXES
        if p.suffix.lower() not in suffixes:
            raise ValueError(f"argument {arg}: {path!r} must end in {' or '.join(suffixes)}")
    if model is None:
        for flag, default in {**RECORDING_FLAGS, "force_threshold": 1.0}.items():
            if getattr(args, flag, default) != default:
                raise ValueError(
                    f"argument --{flag.replace('_', '-')}: says how a recording is read; it"
                    " needs --model ROBOT (a simulated log stores its own feet and units)"
                )
    else:
        from jax_contact.train.cli_args import check_robot
        from jax_contact.train.estimate_cmd import check_force_threshold, parse_names

        check_robot("--model", model)
        parse_names(args.names)
        check_force_threshold(args.force_threshold)
        if getattr(args, "select", "loss") == "spread":
            raise ValueError(
                "argument --select: spread resamples the validation logs' envs, and a"
                " recording is one run (one env); use loss, bce or cells"
            )
    tuning = {str(Path(p).resolve()) for p in args.logs}
    if any(str(Path(v).resolve()) in tuning for v in validate):
        raise ValueError("argument --validate: a validation log is also a tuning log")
    check_tuning_options(args)


def check_tuning_options(args: argparse.Namespace) -> None:
    """The checks of :func:`add_tuning_options`' arguments (ValueError naming one)."""
    unknown = [f for f in getattr(args, "freeze", []) or [] if f not in DEFAULT_FIELDS]
    if unknown:
        raise ValueError(
            f"argument --freeze: unknown field(s) {unknown}; tunable: {', '.join(DEFAULT_FIELDS)}"
        )
    if len(set(getattr(args, "freeze", []) or [])) >= len(DEFAULT_FIELDS):
        raise ValueError("argument --freeze: nothing left to tune")
    ratio = getattr(args, "noise_ratio", 0.0)
    if ratio and ratio <= 1:
        raise ValueError(f"argument --noise-ratio: must be 0 (no box) or > 1, got {ratio:g}")
    bounds = getattr(args, "stance_time_bounds", None)
    if bounds is not None and not bounds[0] < bounds[1]:
        raise ValueError(f"argument --stance-time-bounds: LO must be < HI, got {bounds}")
    # The suffix, not a folder, and a folder files can be created in (probed, as the
    # atomic write will): checked before minutes of tuning, not after.
    from jax_contact.train.cli_args import check_not_an_input, check_output_file

    check_not_an_input("--out", args.out, names=getattr(args, "names", None))
    check_output_file("--out", args.out, (".json",))
    check_replaces_a_parameter_file("--out", args.out)


def check_replaces_a_parameter_file(arg: str, path: str) -> None:
    """Raises ValueError when ``path`` exists and holds JSON that is no parameter file (an
    ``evaluate --json`` report was replaced by a tuned file without a word); an empty file
    or a parameter file is replaced (one that holds no JSON: check_output_file's)."""
    from jax_contact.params_file import PARAMS_FORMAT
    from jax_contact.train.cli_args import NO_JSON, is_parameter_file, json_in_file

    held = json_in_file(path)
    if held is not NO_JSON and not is_parameter_file(held):
        raise ValueError(
            f"argument {arg}: {path!r} exists and holds JSON that is no parameter file (no"
            f" 'format': {PARAMS_FORMAT!r}); writing it would replace it: pass a new name"
        )


# ---------------------------------------------------------------------------------- run


def code_version() -> dict:
    """The git commit of the library's checkout and the files of its code folders that
    differ from it, modified or untracked (a new module or preset the checkout's code may
    load; ignored files, e.g. ``__pycache__``, are not listed), None outside a git
    checkout: the parameters' provenance names the model they were tuned for."""
    import subprocess

    root = Path(__file__).resolve().parents[1]

    def git(*cmd):
        try:
            out = subprocess.run(
                ["git", *cmd], cwd=root, capture_output=True, text=True, timeout=10, check=True
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.rstrip()  # not strip(): porcelain lines start with a space

    commit = git("rev-parse", "HEAD")
    if not commit:
        return {"commit": None, "dirty": None}
    status = git(
        "status", "--porcelain", "--untracked-files=all", "--", "jax_contact", "envs", "train"
    )
    return {"commit": commit, "dirty": sorted(line[3:] for line in (status or "").splitlines())}


def _bar(done: int, total: int, width: int = 20) -> str:
    n = int(round(width * done / max(total, 1)))
    return "[" + "#" * n + "-" * (width - n) + "]"


def run(args: argparse.Namespace) -> int:
    """Runs ``jax-contact tune`` (arguments already checked); returns 0."""
    return fit_and_write(args, load_logs(args))


FAR_FACTOR = 4.0  # a tuned value this far from its derived one is reported
# Below this validation F1 of the untuned estimator, tune warns that the inputs look wrong
# (the reproduction's robots and gaits score above 0.9 untuned, the light hexapod of
# docs/own_robot.md 0.67-0.84 on seed 0, 0.62 on its tuning seed; a recording in degrees
# read as radians scored 0.000).
UNTUNED_F1_FLOOR = 0.5


def far_from_derived(table, factor: float = FAR_FACTOR) -> list[str]:
    """``"<field> <group> x<ratio>"`` for each row of :func:`jax_contact.tune.describe`'s
    table whose tuned value is over ``factor`` times, or under ``1 / factor`` of, its
    derived default."""
    return [
        " ".join(x for x in (r["field"], r["group"], f"x{r['ratio']:.3g}") if x)
        for r in table
        if not (1.0 / factor <= r["ratio"] <= factor)
    ]


def fit_and_write(args: argparse.Namespace, inputs: Inputs) -> int:
    """Tunes on ``inputs`` with ``args``' tuning options, prints the progress and the
    tuned values, writes ``args.out`` with its provenance; returns 0."""
    import jax
    import numpy as np

    import jax_contact as jc
    from jax_contact import tune as jt
    from jax_contact.train.interrupt import set_kept

    set_kept(f"nothing was written: {args.out} is written once the fit ends")
    t0 = time.perf_counter() - inputs.load_s
    train, vals, infos, vinfos = inputs.train, inputs.vals, inputs.infos, inputs.vinfos
    base, terrain, floor = inputs.base, inputs.terrain, inputs.floor
    robot_name, terrain_model, t_load = inputs.robot, inputs.terrain_model, inputs.load_s
    frozen = list(getattr(args, "freeze", []) or [])
    also = list(dict.fromkeys(getattr(args, "tune_also", []) or []))
    fields = [f for f in jt.DEFAULT_FIELDS if f not in frozen] + also
    bounds = tuple(getattr(args, "stance_time_bounds", None) or jt.STANCE_TIME_BOUNDS)
    space = jt.robot_space(inputs.desc, fields, stance_time_bounds=bounds)
    t_s = float(base.stance_time)
    if "stance_time" in fields and not bounds[0] < t_s < bounds[1]:
        raise ValueError(
            f"argument --stance-time-bounds: {bounds[0]:g} {bounds[1]:g} s must contain the"
            f" starting T_s, {t_s:g} s (the defaults' or --params' stance_time); widen them,"
            " or --freeze stance_time"
        )
    config = jt.TuneConfig(
        learning_rate=args.lr,
        clip_norm=args.clip,
        max_epochs=args.epochs,
        patience=args.patience,
        chunk=args.chunk,
        prior_noise=args.prior,
        prior_other=args.prior_other,
        seed=args.seed,
        air_penalty=getattr(args, "air_penalty", 0.0),
        event_weight=getattr(args, "event_weight", 0.3),
        event_temperature=getattr(args, "event_temperature", 0.25),
        select=getattr(args, "select", "loss"),
        cell_tolerance=getattr(args, "cell_tolerance", 0.0),
        constraint_weight=getattr(args, "constrain", 0.0),
        noise_ratio=getattr(args, "noise_ratio", 0.0),
        feasible=getattr(args, "feasible", False),
    )

    from jax_contact.bootstrap import MIN_ENVS

    fewest = min(v.truth.shape[1] for v in vals)
    if config.select == "spread" and fewest < MIN_ENVS:
        raise ValueError(
            f"argument --select: spread resamples the validation logs' envs and makes no call"
            f" below {MIN_ENVS}; a validation log has {fewest} (simulate it with --envs"
            f" {MIN_ENVS} or more), or use loss, bce or cells"
        )

    def progress(row: dict) -> None:
        e = row["epoch"]
        loss = "  (untuned)" if e == 0 else f"  loss {row['train_loss']:.4f}"
        print(
            f"tune {_bar(e, config.max_epochs)} epoch {e:2d}/{config.max_epochs}{loss}"
            f"  val loss {row['val_loss']:.4f} BCE {row['val_bce']:.4f}  F1 {row['val_f1']:.4f}"
            f"  ECE {row['val_ece']:.4f}  sw-ph {100 * row['val_fail']:.1f} %"
            + (f"  worse beyond spread: {len(row['val_worse'])}" if "val_worse" in row else "")
            + f"  {row['wall_s']:6.1f} s"
            + ("  rejected" if row.get("rejected") else ""),
            file=sys.stderr,
            flush=True,
        )

    result = jt.tune(base, terrain, train, vals, space, config, floor=floor, progress=progress)
    best = result.history[result.best_epoch]
    print(
        f"best epoch {result.best_epoch} (val loss {best['val_loss']:.4f},"
        f" BCE {best['val_bce']:.4f});"
        f" tuning {result.wall_s:.1f} s, total {time.perf_counter() - t0:.1f} s",
        file=sys.stderr,
    )
    if result.diverged:
        print(
            f"warning: the fit diverged, {result.diverged}: lower --lr (now"
            f" {config.learning_rate:g}); the file holds epoch {result.best_epoch}'s parameters,"
            " the best before it",
            file=sys.stderr,
        )
    if result.best_epoch == 0:
        tried = result.history[1:]
        if result.diverged and not tried:
            why = "the fit diverged in its first epoch"
        elif config.feasible and tried and all(row["rejected"] for row in tried):
            why = "every epoch made a tuning log's cell worse than the defaults' (--feasible)"
        elif config.select == "cells":
            why = "no epoch was no worse than the defaults in every validation cell"
        elif config.select == "spread":
            why = "every epoch had a validation cell worse than the defaults' beyond the spread"
        else:
            why = "no epoch improved the validation loss"
        print(
            f"{why}: the file holds the untuned defaults"
            + (" (and the calibration map)" if args.calibrate else ""),
            file=sys.stderr,
        )
    first_f1 = result.history[0].get("val_f1", float("nan"))
    if not first_f1 >= UNTUNED_F1_FLOOR:
        print(
            f"warning: the untuned estimator's validation F1 is {first_f1:.3f}: the readings"
            " likely do not fit the model (unit, quaternion order, floor height, feet); check"
            " them with `jax-contact estimate` (or `evaluate`) before trusting this file",
            file=sys.stderr,
        )
    table = jt.describe(space, base, result.params)
    for r in table:
        print(
            f"  {r['field']:26s} {r['group']:16s} {r['default']:10.4g} -> {r['tuned']:10.4g}"
            f"  (x{r['ratio']:.3g})",
            file=sys.stderr,
        )
    far = far_from_derived(table)
    if far:
        print(
            f"warning: tuned values beyond a factor {FAR_FACTOR:g} of their physically derived"
            f" ones: {', '.join(far)}; a noise far from the sensor's or a gait constant far"
            " from the gait's is a warning sign (docs/tuning.md, plausibility; --noise-ratio"
            " bounds the stds)",
            file=sys.stderr,
        )
    lib = jc.__version__
    provenance = {
        "tool": f"jax-contact {getattr(args, 'command', None) or 'tune'}",  # or tune-env
        "arguments": {k: v for k, v in vars(args).items() if k not in ("func", "check")},
        "note": args.note,
        "library_version": lib,
        "jax_version": jax.__version__,
        "robot": robot_name,
        "robot_mass_kg": inputs.mass_kg,
        "terrain_model": terrain_model,
        "logs": infos,
        "validation": vinfos,
        "seeds": {
            "tuning_logs": [i.get("seed") for i in infos],
            "validation_logs": [i.get("seed") for i in vinfos],
            "tune": args.seed,
        },
        "config": {k: getattr(config, k) for k in jt.TuneConfig.__dataclass_fields__},
        "fields": list(space.fields),
        "groups": space.named_groups(),
        "loss": "mean BCE of P(contact) vs truth over valid foot-steps"
        + (
            f" + {config.event_weight:g} x mean over true air phases of softplus(log-sum-exp"
            f" of the logit over the phase's scored steps, temperature"
            f" {config.event_temperature:g})"
            if config.event_weight > 0
            else ""
        )
        + (
            f" + {config.constraint_weight:g} x sum over the cells of softplus((surrogate -"
            " untuned surrogate) / tolerance) per window (jax_contact.tune.constraint_penalty)"
            if config.constraint_weight > 0
            else ""
        )
        + " + Gaussian prior on the unconstrained values (jax_contact.tune)",
        "stance_time_bounds": list(space.stance_time_bounds),
        "noise_floor": (
            {f: np.asarray(v).tolist() for f, v in floor.items()} if floor is not None else None
        ),
        "code": code_version(),
        "epochs": len(result.history) - 1,
        "best_epoch": result.best_epoch,
        "stopped_early": result.stopped_early,
        "diverged": result.diverged,
        "history": list(result.history),
        "final": dict(result.history[result.best_epoch]),
        "tuned_vs_default": table,
        "wall_s": {"load": t_load, "tune": result.wall_s},
    }
    if args.calibrate:
        provenance["calibration"] = calibration_entry(
            result.params, terrain, train, vals, [i["path"] for i in infos],
            kind=args.calibrate, seed=args.seed,
            ece_before=result.history[result.best_epoch]["val_ece"],
        )  # fmt: skip
    jc.save_params(args.out, result.params, provenance)
    set_kept(None)
    print(f"wrote {args.out}")
    return 0


def calibration_entry(
    params, terrain, train, vals, paths, *, kind: str, seed: int, ece_before: float | None = None
) -> dict:
    """The provenance's ``"calibration"``: the map of ``kind`` fitted on the tuning logs'
    logits (:func:`jax_contact.tune.fit_calibration`), where it was fitted and its pooled
    validation scores; prints one line. Used by ``jax-contact tune --calibrate`` and by
    :func:`jax_contact.train.tune_presets.recalibrate_preset`.

    Args:
      params: the tuned parameters; terrain: the estimator's terrain model.
      train, vals: the tuning and validation logs (``jax_contact.tune.TuningData``).
      paths: the tuning logs' paths (recorded as ``fitted_on``).
      kind: ``"sign"`` or ``"affine"``; seed: the key of the Monte-Carlo touch-down.
      ece_before: the validation ECE without the map, for the printed line.
    """
    import jax
    import numpy as np

    from jax_contact import tune as jt
    from jax_contact.tune.calibration import sides_on_bounds as calibration_sides_on_bounds

    key = jax.random.key(seed)
    logits = [jt.predict_logits(params, terrain, d, key=key) for d in train]
    cal = jt.fit_calibration(
        np.concatenate([lg.reshape(-1) for lg in logits]),
        np.concatenate([np.asarray(d.truth).reshape(-1) for d in train]),
        np.concatenate([np.asarray(d.mask).reshape(-1) for d in train]),
        kind=kind,
    )
    vl = np.concatenate([jt.predict_logits(params, terrain, v, key=key).reshape(-1) for v in vals])
    after = jt.score_logits(jt.apply_calibration(vl, cal), jt.pooled(vals))
    before = "" if ece_before is None else f"{ece_before:.4f} -> "
    print(
        f"calibration ({cal.kind}): {cal.describe()}; validation ECE {before}{after['ece']:.4f}",
        file=sys.stderr,
    )
    if bound := calibration_sides_on_bounds(cal):
        n = int(sum(np.asarray(d.mask).sum() for d in train))
        print(
            f"warning: calibration: the temperature for {' and '.join(bound)} ended on its"
            f" bound (fit on {n} counted foot-steps): that side's steps were nearly never"
            " wrong, or too few to fit, so its temperature says little; tune on longer"
            " logs, or leave --calibrate out",
            file=sys.stderr,
        )
    return {**cal.as_dict(), "fitted_on": list(paths), "validation_after": after}


def main(argv: list[str] | None = None) -> int:
    """``python -m jax_contact.train.tune_cmd ...``: the command without the rest of the CLI."""
    parser = argparse.ArgumentParser(prog="jax-contact")
    add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["tune", *(sys.argv[1:] if argv is None else argv)])
    try:
        args.check(args)
    except ValueError as err:
        print(f"jax-contact tune: error: {err}", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except (ValueError, OSError) as err:
        print(f"jax-contact tune: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
