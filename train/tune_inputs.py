"""What ``jax-contact tune`` fits on: its logs or recordings, loaded and checked.

:func:`load_logs` reads the tuning and validation logs (or, with ``--model``, recordings
of your own robot, converted as ``jax-contact estimate`` converts them) into
:class:`Inputs`. The logs must be of one robot, period and sensor model (the fit starts
from the first log's defaults and floors its noise there); a run given twice, or as both a
tuning and a validation log, is refused. :mod:`jax_contact.train.tune_env` builds the same
:class:`Inputs` from a wrapped env's rollouts.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from jax_contact.train.cli_args import RATE_TOLERANCE
from jax_contact.train.tune_data import load_tuning_log, sensor_floor


def _setup(d) -> dict:
    """What the fit starts from, of a log's attributes or its :func:`_log_info` (a
    recording's also the measurement terms its columns support)."""
    from jax_contact.train.logs import log_noise  # imports JAX: not at the CLI's import

    out = {"robot": str(d["robot"]), "period dt": float(d["dt"]), "sensor noise": log_noise(d)}
    if "terms" in d:
        out["measurement terms"] = list(d["terms"])
    return out


# Two periods within this fraction of each other are one rate: the median steps of two
# recordings at one rate differ in their last digits, and by up to a few tenths of a per
# cent after --resample (each onto its own median); a recording's own steps may vary by 1 %.
PERIOD_TOLERANCE = RATE_TOLERANCE


def _differ(a, b) -> bool:
    """Two setup values differ (periods by more than :data:`PERIOD_TOLERANCE`)."""
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) > PERIOD_TOLERANCE * max(abs(a), abs(b))
    return a != b


def _shown(value) -> str:
    """A setup value as the refusal prints it (a period in ms and Hz)."""
    if isinstance(value, float):
        return f"{value * 1e3:.6g} ms ({1.0 / value:.6g} Hz)"
    return repr(value)


def _same_setup(arg: str, path, attrs, first: dict) -> None:
    """Refuses a log of another robot, period or sensor model than the first tuning log's
    (``first``, its :func:`_log_info`): the fit starts from one robot's defaults for one
    sensor model and floors its noise there, so a mixed set would be tuned from whichever
    log came first."""
    got, want = _setup(attrs), _setup(first)
    what = "recording" if attrs.get("kind") == "recording" else "log"
    for shown in got:
        if _differ(got[shown], want.get(shown)):
            raise ValueError(
                f"argument {arg}: {what} {str(path)!r} has {shown} {_shown(got[shown])}; the"
                f" first tuning {what} {first['path']!r} has {_shown(want[shown])}: tune on"
                f" {what}s of one robot, period and sensor model"
                + (", with the same columns" if what == "recording" else "")
            )


def _same_setups_first(logs, validate) -> None:
    """:func:`_same_setup` of every log against the first, from their attributes alone,
    before any is loaded (a mixed set was refused after the first log's compilation). A
    log whose attributes do not read is left to its loading, which names what is wrong."""
    from jax_contact.io import read_log_attrs

    first = None
    for arg, path in [("LOG", p) for p in logs] + [("--validate", p) for p in validate]:
        try:
            attrs = read_log_attrs(path)
            _setup(attrs)
        except (OSError, ValueError, KeyError, TypeError):
            return
        if first is None:
            first = {"path": str(path), **attrs}
        else:
            _same_setup(arg, path, attrs, first)


def _run_key(info: dict) -> tuple:
    """What makes two logs the same run: robot, gait, scenario, terrain, roughness, seed,
    envs, steps (a copy of a tuning log given as a validation log is caught by it; logs without a
    seed are never the same run); a recording's, its bytes (``sha256``: a copy under another
    name is the same run)."""
    if info.get("sha256"):
        return ("sha256", info["sha256"])
    if info.get("seed") is None:
        return ("path", info["path"])
    keys = ("robot", "gait", "scenario", "terrain", "roughness", "seed", "n_envs", "steps")
    return tuple(str(info.get(k)) for k in keys)


def _same_run(info: dict, earlier: list[dict]) -> str | None:
    """The path of the first of ``earlier`` (:func:`_log_info` dicts) that is the same run
    as ``info`` (:func:`_run_key`), or None."""
    return next((i["path"] for i in earlier if _run_key(i) == _run_key(info)), None)


def _log_info(path, attrs, data) -> dict:
    keys = ("robot", "gait", "scenario", "terrain", "noise", "seed", "n_envs", "dt", "roughness")
    keys += ("kind", "terms", "sha256")  # a recording's (load_tuning_recording)
    info = {"path": str(path), "resolved": str(Path(path).resolve())}
    info.update({k: attrs[k] for k in keys if k in attrs})
    info["steps"] = int(data.n_steps)
    return info


@dataclasses.dataclass
class Inputs:
    """What a tuning run fits on, however it was obtained (logs here,
    :mod:`jax_contact.train.tune_env` records a wrapped env's rollouts).

    Attributes:
      train, vals: the tuning and validation data (``jax_contact.tune.TuningData``).
      infos, vinfos: one provenance dict per tuning / validation log.
      base: the untuned parameters (the prior's centre); terrain: the estimator's terrain.
      floor: the noise floor (``--noise-floor sensor``) or None.
      desc: the robot's ``RobotDescription`` (the tuned groups).
      robot: the robot's (or scene's) name, for the provenance.
      terrain_model: the provenance's ``terrain_model``.
      load_s: seconds spent getting the data.
      mass_kg: the robot model's total mass (``provenance["robot_mass_kg"]``: loading the
        file for a robot of another mass warns, :func:`jax_contact.params_file.load_params_for`).
    """

    train: list
    vals: list
    infos: list
    vinfos: list
    base: object
    terrain: object
    floor: dict | None
    desc: object
    robot: str
    terrain_model: str
    load_s: float
    mass_kg: float | None = None


def load_logs(args: argparse.Namespace) -> Inputs:
    """The :class:`Inputs` of ``jax-contact tune``'s logs (one robot for all), or of its
    recordings with ``args.model``."""
    from jax_contact.robot import model_mass
    from jax_contact.train.logs import log_noise
    from jax_contact.tune import check_scored_steps

    t0 = time.perf_counter()
    train, infos = [], []
    base = terrain = floor = None
    terrain_model = getattr(args, "terrain_model", "flat")
    if getattr(args, "model", None):
        read = _RecordingLoader(args, terrain_model)
    else:

        def read(path):
            return load_tuning_log(path, terrain_model)

    def load_one(arg: str, path):
        try:  # the logs' and recordings' own checks (no truth, shapes, ...), named
            return read(path)
        except ValueError as err:
            raise ValueError(f"argument {arg}: {err}") from None

    validate = [args.validate] if isinstance(args.validate, str) else list(args.validate)
    if not getattr(args, "model", None):
        _same_setups_first(args.logs, validate)
    for path in args.logs:
        data, robot, attrs, params, terr = load_one("LOG", path)
        if not infos:
            first_robot = robot
            # The starting parameters, terrain and noise floor are the first log's; the
            # others must share its robot, period and sensors (_same_setup).
            base, terrain = params, terr
            if getattr(args, "noise_floor", "sensor") == "sensor":
                floor = sensor_floor(robot, float(attrs["dt"]), log_noise(attrs))
        else:
            _same_setup("LOG", path, attrs, infos[0])
        info = _log_info(path, attrs, data)
        if twice := _same_run(info, infos):
            raise ValueError(
                f"argument LOG: {str(path)!r} is the same run as tuning log {twice!r}"
                " (given twice, it would count twice)"
            )
        train.append(data)
        infos.append(info)
        print(f"loaded {path}: {data.truth.shape} (T, envs, feet)", file=sys.stderr)
    check_scored_steps(train, "tuning log", names=[repr(str(p)) for p in args.logs])
    if getattr(args, "model", None) and getattr(args, "noise_floor", "sensor") == "sensor":
        print(
            "note: the fit starts from `estimate`'s defaults, which assume `anymal_like`"
            " sensors, and no noise is tuned below what those sensors alone put on it"
            " (--noise-floor sensor); for a robot with better sensors, pass --noise-floor none",
            file=sys.stderr,
        )
    robot_name = infos[0]["robot"]
    vals, vinfos = [], []
    for path in validate:
        val, _, vattrs, _, _ = load_one("--validate", path)
        _same_setup("--validate", path, vattrs, infos[0])
        info = _log_info(path, vattrs, val)
        if twice := _same_run(info, vinfos):
            raise ValueError(
                f"argument --validate: {str(path)!r} is the same run as validation log"
                f" {twice!r} (given twice, it would count twice)"
            )
        if (tuned := _same_run(info, infos)) and info.get("sha256"):
            raise ValueError(
                f"argument --validate: recording {str(path)!r} has the same content as tuning"
                f" recording {tuned!r}: validation needs another run"
            )
        if tuned:
            raise ValueError(
                f"argument --validate: log {str(path)!r} is the same run (robot, gait, terrain,"
                f" seed {info.get('seed')}) as tuning log {tuned!r}: validation needs other"
                " seeds"
            )
        vals.append(val)
        vinfos.append(info)
        print(f"loaded {path} (validation): {val.truth.shape} (T, envs, feet)", file=sys.stderr)
    check_scored_steps(vals, "validation log", names=[repr(str(p)) for p in validate])
    if warned := getattr(read, "warned", None):
        print(
            f"warning: {len(warned)} of {len(args.logs) + len(validate)} recordings read with"
            f" warnings ({', '.join(warned)}): a file tuned on readings the model does not fit"
            " (another unit, frame or floor) learns their errors; check them with `jax-contact"
            " estimate` first",
            file=sys.stderr,
        )
    t_load = time.perf_counter() - t0
    print(f"measurements precomputed in {t_load:.1f} s", file=sys.stderr)
    return Inputs(
        train, vals, infos, vinfos, base, terrain, floor,
        first_robot.description, robot_name, terrain_model, t_load,
        model_mass(first_robot.mj_model),
    )  # fmt: skip


class _RecordingLoader:
    """``read(path)`` of :func:`load_logs` for recordings of ``args.model``: the robot
    loaded once, each recording converted as ``jax-contact estimate`` converts it (its
    notes printed as estimate prints them); ``warned`` lists the recordings read with a
    warning."""

    def __init__(self, args: argparse.Namespace, terrain_model: str):
        from jax_contact.envs.robots import load_robot
        from jax_contact.train.estimate_cmd import parse_names

        self.model = args.model
        self.robot = load_robot(args.model, foot_names=args.feet)
        self.options = dict(
            names=parse_names(args.names), units=args.units, resample=args.resample,
            force_threshold=args.force_threshold, terrain_model=terrain_model,
        )  # fmt: skip
        self.warned: list[str] = []

    def __call__(self, path):
        from jax_contact.train.recording import SimulateLogGiven
        from jax_contact.train.recording_estimate import print_note
        from jax_contact.train.tune_data import load_tuning_recording

        try:
            data, attrs, params, terrain = load_tuning_recording(
                path, self.robot, self.model, **self.options
            )
        except SimulateLogGiven:
            raise ValueError(
                f"{str(path)!r} is a log of `jax-contact simulate`: tune on simulated logs"
                " without --model (--model reads recordings of named columns)"
            ) from None
        notes = attrs.pop("notes")
        for line in notes:
            print_note(line, source=str(path), file=sys.stderr)
        if any(line.startswith("WARNING ") for line in notes):
            self.warned.append(str(path))
        return data, self.robot, attrs, params, terrain
