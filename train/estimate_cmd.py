"""``jax-contact estimate RECORDING --model ROBOT``: contact estimates for a recording that
this library did not make (a robot's log).

The recording's schema is in :mod:`jax_contact.train.recording`, its timing and the
resampling rule in :mod:`jax_contact.train.recording_convert`, and the work in
:func:`jax_contact.train.recording_estimate.estimate_recording`. This module only parses and checks
the arguments, and like ``train/cli.py`` imports no JAX, NumPy or MuJoCo at module level:
:func:`check` runs before JAX is imported. Register it in the CLI with
``estimate_cmd.add_parser(sub)`` (the parser's defaults carry ``func=run`` and
``check=check``, as ``train/cli.py``'s commands do); until then ``python -m
jax_contact.train.estimate_cmd RECORDING --model ROBOT ...`` runs it alone (:func:`main`)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

RECORDING_SUFFIXES = (".csv", ".npz", ".h5", ".hdf5")  # jax_contact.train.recording.SUFFIXES
UNITS = ("rad", "deg")  # jax_contact.train.recording.UNITS
TERRAIN_MODELS = ("flat", "memory")  # jax_contact.train.log_estimator.TERRAIN_MODELS
FORCE_THRESHOLD = 1.0  # N, jax_contact.train.recording.FORCE_THRESHOLD


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Adds the ``estimate`` command to an argparse subparsers object; returns its parser."""
    from jax_contact.train.cli_args import HelpFormatter

    p = subparsers.add_parser(
        "estimate",
        help="contact estimates for your own recording (CSV, NPZ, HDF5) and robot model",
        description="Runs the estimator on a recording with named columns (time, q/<joint>,"
        " optional qd/, qdd/, tau/<joint>, base_quat/w,x,y,z, base_angvel/x,y,z, optional"
        " base_pos/, base_linvel/, base_linacc/, base_angacc/, and contact/<foot> or"
        " force/<foot> as ground truth; the"
        " schema and timing are in train/recording.py, train/recording_convert.py and"
        " docs/own_robot.md) and writes"
        " P(contact) per foot, each term's probability and the transitions to"
        " OUT/estimate.h5 and OUT/estimate.csv, a figure per foot, and the metrics when the"
        " recording has ground truth. The estimator runs at the recording's rate. Several"
        " recordings of one robot (the same options for all): each into OUT/<its file name"
        " without the suffix>/ (two files of one name are refused), and the metrics of those"
        " with ground truth at one rate (the largest such set, at least two) pooled into"
        " OUT/pooled_metrics.json, which replaces an earlier run's.",
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "recording",
        nargs="+",
        help="the recording: .csv (header row), .npz or .h5; or several, of one robot",
    )
    p.add_argument(
        "--model",
        "--robot",
        dest="model",
        required=True,
        help="the robot: a robot name (e.g. go1, planar_leg) or an MJCF .xml file with a floor",
    )
    p.add_argument(
        "--feet",
        nargs="+",
        default=None,
        metavar="FOOT",
        help="foot geom or body names, in leg order (default: found in the model)",
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="FILE|PRESET",
        help="estimator parameters (jax_contact.save_params / jax-contact tune, or a shipped"
        " preset: go1, spot, barkour, go1_playground, spot_walk, ...; p_contact is read through"
        " the file's calibration map, if it has one); default: the robot's defaults (those of"
        " jax-contact evaluate)",
    )
    add_terrain_model_flag(p)
    add_recording_flags(p)
    add_force_threshold_flag(p)
    p.add_argument(
        "--out",
        default="out/estimate",
        help="output folder (several recordings: one subfolder each)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG per foot")
    p.set_defaults(func=run, check=check)
    return p


# ------------------------------------------- robot flags for simulate / evaluate / reproduce


def add_recording_flags(p: argparse.ArgumentParser) -> None:
    """``--names``, ``--units`` and ``--resample``: how a recording's columns are read
    (:func:`jax_contact.train.recording_convert.to_readings`), for ``estimate`` and
    ``deploy-check``; :func:`parse_names` reads the first."""
    p.add_argument(
        "--names",
        default=None,
        metavar="MAP",
        help="recording name -> model name for joints and feet whose names differ: a JSON"
        ' file {"log name": "model name"} or inline log=model,log2=model2; a name mapped to'
        " nothing (log=, or null in the file) drops its columns (a joint the model lacks)",
    )
    p.add_argument(
        "--units", choices=UNITS, default="rad", help="unit of joint angles and angular rates"
    )
    p.add_argument(
        "--resample",
        action="store_true",
        help="resample irregular time steps onto a uniform grid (linear) instead of refusing",
    )


def add_force_threshold_flag(p: argparse.ArgumentParser) -> None:
    """``--force-threshold N``: how a recording's ``force/<foot>`` truth column is read
    (``estimate``, ``tune`` on recordings); :func:`check_force_threshold` checks it."""
    p.add_argument(
        "--force-threshold",
        type=float,
        default=FORCE_THRESHOLD,
        metavar="N",
        help="a force/<foot> column above this is contact, N (1 N is the simulator's); raise"
        " it for a foot sensor with an offset",
    )


def check_force_threshold(value: float) -> None:
    """Raises ValueError naming ``--force-threshold`` unless it is a finite force >= 0 N."""
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(
            f"argument --force-threshold: must be a finite force >= 0 N, got"
            f" {value} (a force/ column above it is contact; a sensor that"
            " reads the load as negative: negate its column)"
        )


def add_feet_flag(p: argparse.ArgumentParser, default: str = "found in the model") -> None:
    """``--feet FOOT [FOOT ...]``: ``foot_names`` of ``jax_contact.envs.robots.load_robot`` /
    ``jax_contact.train.logs.simulate_to_file`` /
    ``jax_contact.train.log_evaluate.evaluate_file`` (None: the model's or the log's own, which
    ``default`` says in the help)."""
    p.add_argument(
        "--feet",
        nargs="+",
        default=None,
        metavar="FOOT",
        help=f"foot geom or body names, in leg order (default: {default})",
    )


def add_terrain_model_flag(p: argparse.ArgumentParser) -> None:
    """``--terrain-model {flat,memory}``: ``terrain_model`` of
    ``jax_contact.train.log_evaluate.evaluate_file`` and
    ``jax_contact.train.recording_estimate.estimate_recording``."""
    p.add_argument(
        "--terrain-model",
        choices=TERRAIN_MODELS,
        default=None,
        help="the estimator's ground: flat, a plane at z = 0 of the log's world frame (std"
        " 5 cm, 0.2 m for the planar leg: the reproduction's); memory, where each foot last"
        " stood, averaged over its stance: for a base position that drifts"
        " (docs/model_choices.md; the kinematic detector keeps no memory and always reads the"
        " flat plane, which a drifting base costs it). Default: the one the --params file was"
        " tuned with (its provenance), else flat",
    )


def add_gait_flags(p: argparse.ArgumentParser) -> None:
    """The ``jax_contact.envs.gaits.GaitSettings`` fields as flags; :func:`gait_overrides` reads
    them."""
    g = p.add_argument_group("gait settings (default: the robot's, else derived from the model)")
    g.add_argument("--home-key", default=None, metavar="KEY", help="keyframe of the standing pose")
    g.add_argument(
        "--home-qpos", nargs="+", type=float, default=None, metavar="Q", help="standing qpos (nq)"
    )
    g.add_argument("--base-height", type=float, default=None, metavar="M", help="base height, m")
    g.add_argument("--kp", type=float, default=None, help="joint PD stiffness, N m/rad")
    g.add_argument("--kd", type=float, default=None, help="joint PD damping, N m s/rad")
    g.add_argument(
        "--speed",
        nargs=2,
        type=float,
        default=None,
        metavar=("LOW", "HIGH"),
        help="range of the forward speed commands of the chosen gait, m/s",
    )


def gait_overrides(args: argparse.Namespace) -> dict:
    """The gait flags that were given, as ``GaitSettings`` field overrides (the mapping
    ``jax_contact.train.logs.simulate_to_file(gait_settings=...)`` takes)."""
    out = {}
    for flag, field in (
        ("home_key", "home_key"),
        ("home_qpos", "home_qpos"),
        ("base_height", "base_height"),
        ("kp", "kp"),
        ("kd", "kd"),
    ):
        value = getattr(args, flag, None)
        if value is not None:
            out[field] = tuple(value) if isinstance(value, list) else value
    speed = getattr(args, "speed", None)
    if speed is not None:
        gait = getattr(args, "gait", "trot")
        if gait not in ("trot", "walk"):
            raise ValueError(f"argument --speed: the {gait!r} gait has no speed command")
        out[f"{gait}_speed"] = tuple(speed)
    for name in ("base_height", "kp", "kd"):
        if name in out and not (math.isfinite(out[name]) and out[name] > 0):
            raise ValueError(
                f"argument --{name.replace('_', '-')}: must be a finite number > 0, got {out[name]}"
            )
    if "home_qpos" in out and not all(math.isfinite(q) for q in out["home_qpos"]):
        raise ValueError(f"argument --home-qpos: must be finite numbers, got {out['home_qpos']}")
    if "trot_speed" in out or "walk_speed" in out:
        low, high = out.get("trot_speed") or out["walk_speed"]
        if not (math.isfinite(low) and math.isfinite(high)):
            raise ValueError(f"argument --speed: must be finite speeds in m/s, got {low} {high}")
        if low > high:
            raise ValueError(f"argument --speed: LOW {low} > HIGH {high}")
    return out


def parse_names(text: str | None) -> dict[str, str]:
    """The ``--names`` map: a JSON file of ``{"log name": "model name"}`` or inline
    ``log=model,log2=model2``. Raises ValueError naming the argument."""
    if not text:
        return {}
    path = Path(text)
    try:
        is_file = path.is_file()
    except OSError:  # an inline map longer than a file name may be
        is_file = False
    if path.suffix == ".json" or is_file:
        try:
            payload = json.loads(path.read_text())
        except FileNotFoundError:
            raise ValueError(f"argument --names: file {text!r} does not exist") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise ValueError(f"argument --names: {text!r} is not JSON ({err})") from None
        ok = isinstance(payload, dict) and all(
            isinstance(k, str) and k and (v is None or isinstance(v, str))
            for k, v in payload.items()
        )
        if not ok:
            raise ValueError(
                f"argument --names: {text!r} must hold one object of name: name (or null)"
            )
        return {k: v or "" for k, v in payload.items()}
    out = {}
    for item in text.split(","):
        parts = [x.strip() for x in item.split("=")]
        if len(parts) != 2 or not parts[0]:
            raise ValueError(
                f"argument --names: {item!r} is not log_name=model_name (or log_name= to drop)"
            )
        out[parts[0]] = parts[1]
    return out


def check(args: argparse.Namespace) -> None:
    """Raises ValueError naming the argument; imports no JAX."""
    from jax_contact.train.cli_args import (
        ESTIMATE_OUTPUTS,
        check_input_file,
        check_not_an_input,
        check_output_folder,
        check_outputs_not_folders,
        check_params_source,
        check_robot,
    )
    from jax_contact.train.recording_batch import POOLED_FILE, recording_folders

    for recording in args.recording:
        check_input_file("recording", recording)
        if Path(recording).suffix.lower() not in RECORDING_SUFFIXES:
            raise ValueError(
                f"argument recording: {recording!r} must end in {', '.join(RECORDING_SUFFIXES)}"
            )
    check_robot("--model", args.model)
    if args.params is not None:
        check_params_source("--params", args.params)
    parse_names(args.names)
    check_force_threshold(args.force_threshold)
    check_output_folder("--out", args.out, staged=len(args.recording) == 1)
    # The inputs an output would replace: a recording, or the --names file, named like one.
    inputs = {f"recording {r!r}": r for r in args.recording} | {"--names file": args.names}
    if len(args.recording) == 1:
        check_outputs_not_folders("--out", args.out, ESTIMATE_OUTPUTS)
        for name in ESTIMATE_OUTPUTS:
            check_not_an_input("--out", Path(args.out) / name, **inputs)
        return
    check_outputs_not_folders("--out", args.out, (POOLED_FILE,))
    check_not_an_input("--out", Path(args.out) / POOLED_FILE, **inputs)
    for folder in recording_folders(args.recording):
        check_output_folder("--out", Path(args.out) / folder, staged=True)
        check_outputs_not_folders("--out", Path(args.out) / folder, ESTIMATE_OUTPUTS)
        for name in ESTIMATE_OUTPUTS:
            check_not_an_input("--out", Path(args.out) / folder / name, **inputs)


def run(args: argparse.Namespace) -> int:
    """Runs the estimate (imports the library); returns the exit code."""
    from jax_contact.train.recording_batch import estimate_recordings
    from jax_contact.train.recording_estimate import estimate_recording

    if len(args.recording) == 1:
        estimate, what = estimate_recording, args.recording[0]
    else:
        estimate, what = estimate_recordings, args.recording
    estimate(
        what,
        model=args.model,
        out_dir=args.out,
        feet=args.feet,
        names=parse_names(args.names),
        params_path=args.params,
        terrain_model=args.terrain_model,
        units=args.units,
        resample=args.resample,
        force_threshold=args.force_threshold,
        plots=not args.no_plots,
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m jax_contact.train.estimate_cmd ...``: the command alone; a bad argument or input
    is one line on stderr and exit code 2, as in ``jax-contact``."""
    parser = argparse.ArgumentParser(prog="jax-contact")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["estimate", *(sys.argv[1:] if argv is None else argv)])
    try:
        args.check(args)
        return run(args)
    except (ValueError, OSError) as err:
        print(f"jax-contact estimate: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
