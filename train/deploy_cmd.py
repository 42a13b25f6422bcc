"""``jax-contact export`` and ``jax-contact deploy-check``: the estimator as a robot runs it.

- ``export`` writes one ``.contact`` file (:mod:`jax_contact.export`): the single-robot update
  with the robot's kinematics and dynamics traced in, and a JSON header (readings, state,
  outputs, parameters and their provenance, versions).
- ``deploy-check`` feeds a log (``jax-contact simulate``), or a recording of the robot in
  ``jax-contact estimate``'s format (its columns checked and warned about as there), at its
  rate through the loaded file
  (:mod:`jax_contact.deploy`), one reading per call as a control loop would, and reports
  the per-call latency (median, p99, p99.9, max), the deadline misses at the rate and the
  largest |P(contact)| difference from the offline estimator (``jax_contact.train.evaluate.replay``
  with the file's own parameters on the same readings); it exits 1 when that difference
  exceeds ``--max-diff`` (or the misses ``--max-misses``, where given).

Like :mod:`jax_contact.train.cli`, this module imports only the standard library: arguments are
checked before JAX is imported, and the library is imported inside the run functions.
Register the commands with :func:`add_parsers` (``jax_contact.train.cli.build_parser``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ARTEFACT_SUFFIX = ".contact"
ARTEFACT_MAGIC = b"JAX-CONTACT-EXP\n"  # jax_contact.export.MAGIC (that module imports JAX)
# deploy-check's default pass mark for |P(contact) - offline estimate|: the two programs
# are compiled apart and round float32 differently, 2e-6 (Go1, Spot, the planar leg) to
# 5.8e-4 (a six-legged MJCF) measured; another parameter file, terrain model or robot
# gives differences of 0.1-1.
MAX_DIFF = 1e-2
EXIT_CHECK_FAILED = 1


def add_parsers(subparsers) -> None:
    """Adds ``export`` and ``deploy-check`` to ``jax-contact``'s subparsers.

    Each parser gets ``func`` (run) and ``check`` (validate, no JAX) defaults, as
    :func:`jax_contact.train.cli.main` expects.
    """
    from jax_contact.train.cli_args import (
        ROBOT_NAMES,
        HelpFormatter,
        nonnegative_int,
        positive_float,
        positive_int,
        seed_int,
    )
    from jax_contact.train.estimate_cmd import add_recording_flags

    p = subparsers.add_parser(
        "export",
        help="write the estimator of one robot as a file its control loop runs (jax only)",
        description="Exports the single-robot estimator update, the robot's kinematics and"
        " dynamics included (the MJX adapter traced in, so the runtime needs jax but not"
        " mujoco), with a JSON header naming the readings (order, units, shapes), the"
        " parameters and their provenance. Load it with jax_contact.deploy.load. Without"
        " --params the robot's shipped defaults (jax_contact.params_for with the anymal_like"
        " sensor model) are used.",
        formatter_class=HelpFormatter,
    )
    p.set_defaults(func=run_export, check=check_export)
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument(
        "--robot", default=None, metavar="NAME", help=f"a robot name: {', '.join(ROBOT_NAMES)}"
    )
    which.add_argument(
        "--model",
        default=None,
        metavar="XML",
        help="an MJCF file (with its floor); a robot name is taken too, as by estimate and tune",
    )
    p.add_argument(
        "--feet",
        nargs="+",
        default=None,
        metavar="NAME",
        help="foot geom (or body) names, in the order of P(contact); default: found in the model",
    )
    p.add_argument(
        "--params",
        default=None,
        metavar="P.json|PRESET",
        help="parameter file (jax_contact.save_params) or a shipped preset (go1, spot, barkour,"
        " go1_playground, spot_walk, ...); the exported p_contact is read through the file's"
        " calibration map, if it has one",
    )
    p.add_argument("--rate", type=positive_float, default=400.0, help="reading rate, Hz")
    p.add_argument(
        "--seed", type=seed_int, default=0, help="PRNG seed (Monte-Carlo touch-down only)"
    )
    p.add_argument(
        "--out",
        required=True,
        help=f"the {ARTEFACT_SUFFIX} file to write; an existing file is replaced only if it is"
        " an earlier export",
    )

    p = subparsers.add_parser(
        "deploy-check",
        help="replay a log in real time through an exported estimator: latency, agreement",
        description="Feeds a log at its rate through the exported estimator, one reading per"
        " call as a control loop would, and reports the per-call latency (median, p99, p99.9,"
        " max in us), the deadline misses at the rate and the largest |P(contact)| difference"
        " from the offline estimator on the same readings. Exits 1 when that difference"
        " exceeds --max-diff (or the two disagree on which readings give no estimate), when"
        " the log is of another robot than the export, or when the deadline misses exceed"
        " --max-misses where given; the JSON says which.",
        formatter_class=HelpFormatter,
    )
    p.set_defaults(func=run_deploy_check, check=check_deploy_check)
    p.add_argument("artefact", help=f"a {ARTEFACT_SUFFIX} file written by `jax-contact export`")
    p.add_argument(
        "log",
        help="an .h5 log written by `jax-contact simulate`, or a recording of the robot (.csv,"
        " .npz or .h5 with a time column, as `jax-contact estimate` reads it; --names, --units"
        " and --resample as there)",
    )
    p.add_argument("--env", type=int, default=0, help="which env of the log to replay")
    add_recording_flags(p)
    p.add_argument(
        "--steps", type=positive_int, default=None, help="replay only the first N readings"
    )
    p.add_argument(
        "--cpu",
        type=int,
        default=None,
        help="run on this one CPU core (Linux), as a robot's pinned estimator process: XLA:CPU"
        " then runs every kernel on one thread (the fastest setting measured, docs/deploy.md)",
    )
    p.add_argument(
        "--no-pace",
        action="store_true",
        help="call back to back instead of once per period (latency only, no deadlines)",
    )
    p.add_argument(
        "--max-diff",
        type=positive_float,
        default=MAX_DIFF,
        help="the largest |P(contact) - offline estimate| that passes: float32 round-off"
        " measured 2e-6 to 6e-4 (docs/deploy.md); above it, exit 1",
    )
    p.add_argument(
        "--max-misses",
        type=nonnegative_int,
        default=None,
        help="the most missed deadlines that pass (paced replays only); default: reported,"
        " not checked (they depend on the host and its load)",
    )
    p.add_argument("--json", default=None, help="write the results here")


# ------------------------------------------------------------------------- argument checks


def check_export(args: argparse.Namespace) -> None:
    """Raises ValueError naming the argument that is wrong (no JAX import)."""
    from jax_contact.train.cli_args import (
        MAX_RATE_HZ,
        MIN_RATE_HZ,
        ROBOT_NAMES,
        check_output_file,
        check_params_source,
        check_robot,
    )

    if args.robot is not None:
        check_robot("--robot", args.robot)
    else:  # an MJCF file, or a robot name (as `estimate --model` and `tune --model` take)
        check_robot("--model", args.model)
        if args.model not in ROBOT_NAMES and not args.model.endswith(".xml"):
            raise ValueError(f"argument --model: {args.model!r} must be an MJCF .xml file")
    if args.rate < MIN_RATE_HZ:
        raise ValueError(
            f"argument --rate: {args.rate:g} Hz; the estimator needs at least {MIN_RATE_HZ:g}"
            " readings per second (a swing is over in a few tenths of a second)"
        )
    if args.rate > MAX_RATE_HZ:
        raise ValueError(
            f"argument --rate: {args.rate:g} Hz; at most {MAX_RATE_HZ:g} (the control loop's"
            " rate in Hz: 400 for a 2.5 ms loop)"
        )
    if args.params is not None:
        check_params_source("--params", args.params)
    check_output_file("--out", args.out, (ARTEFACT_SUFFIX,))
    check_replaces_an_export("--out", args.out)


def check_replaces_an_export(arg: str, path: str) -> None:
    """Raises ValueError when ``path`` exists and is neither empty nor an exported
    estimator (its first bytes are not :data:`ARTEFACT_MAGIC`): another program's
    ``.contact`` file would be replaced. An earlier export is replaced (``export`` says
    so when it writes)."""
    p = Path(path)
    if not p.is_file():
        return
    try:
        with p.open("rb") as f:
            head = f.read(len(ARTEFACT_MAGIC))
    except OSError:
        return  # unreadable: the write's own error names it
    if head and head != ARTEFACT_MAGIC:
        raise ValueError(
            f"argument {arg}: {path!r} exists and is no file of `jax-contact export`;"
            " writing it would replace it: pass a new name"
        )


def check_deploy_check(args: argparse.Namespace) -> None:
    """Raises ValueError naming the argument that is wrong (no JAX import)."""
    from jax_contact.train.cli_args import (
        check_input_file,
        check_not_an_input,
        check_output_file,
    )
    from jax_contact.train.estimate_cmd import RECORDING_SUFFIXES, parse_names

    check_input_file("artefact", args.artefact)
    check_input_file("log", args.log)
    if Path(args.log).suffix.lower() not in RECORDING_SUFFIXES:
        raise ValueError(f"argument log: {args.log!r} must end in {', '.join(RECORDING_SUFFIXES)}")
    if args.env < 0:
        raise ValueError(f"argument --env: must be >= 0, got {args.env}")
    parse_names(args.names)
    if args.cpu is not None:
        allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        if args.cpu not in allowed:
            raise ValueError(
                f"argument --cpu: {args.cpu} is not one of this process's CPUs {allowed}"
            )
    if args.max_misses is not None and args.no_pace:
        raise ValueError(
            "argument --max-misses: --no-pace calls back to back, so there are no deadlines"
            " to miss; pace the replay, or leave --max-misses out"
        )
    check_not_an_input("--json", args.json, artefact=args.artefact, log=args.log, names=args.names)
    check_output_file("--json", args.json)


# -------------------------------------------------------------------------------- export


DEFAULTS_PROVENANCE = {
    "source": "defaults",
    "function": "jax_contact.train.log_estimator.default_estimator",
    "rule": "jax_contact.params_for with the anymal_like sensor model"
    " (jax_contact.envs.sensors), the force axes the legs' Jacobians span and the sign test"
    " where the legs' torques can read a foot's load (both from the robot's model); the"
    " planar leg's Section III estimator for one two-joint leg on a rail",
}


def export_to_file(
    out: str | Path,
    *,
    robot: str,
    feet=None,
    params_path: str | None = None,
    rate_hz: float = 400.0,
    seed: int = 0,
) -> dict:
    """Exports ``robot`` (a name or an MJCF path) to ``out``; returns the header.

    The parameters are those of ``jax-contact evaluate`` (:func:`jax_contact.train.log_estimator.
    default_estimator`), or ``params_path``'s checked as ``evaluate`` checks them (its
    ``nv``; a file tuned on a robot of another mass warns; a file of another period is
    moved to ``1 / rate_hz`` with a warning), with its calibration map and terrain model.

    Raises:
      ValueError: naming ``--params`` for a file that does not fit the robot, as
        :func:`jax_contact.train.log_estimator.load_params_for`.
    """
    from jax_contact import export
    from jax_contact.envs.robots import load_robot
    from jax_contact.robot import model_mass
    from jax_contact.train.log_estimator import estimator_for

    # Before 1 / rate_hz below: 0 was a ZeroDivisionError, a string a TypeError.
    rate_hz = export.check_rate_hz(rate_hz)
    try:
        loaded = load_robot(robot, foot_names=feet)
    except ValueError as err:  # the library's argument is foot_names, the command's --feet
        if feet is None or not ("foot_names" in str(err) or str(err).startswith("foot ")):
            raise  # the robot's own error (unknown name, unreadable MJCF)
        said = str(err).replace("foot_names: ", "", 1).replace("foot_names ", "", 1)
        raise ValueError(f"argument --feet: {said}") from None
    desc = loaded.description
    dt = 1.0 / float(rate_hz)
    # A file that does not fit the robot is named as --params by estimator_for.
    params, _, terrain, calibration, params_record = estimator_for(
        desc,
        dt,
        params_path,
        None,
        model_mass(loaded.mj_model),
        mj_model=loaded.mj_model,
        period="the export's",
        robot=loaded.name,
    )
    provenance = params_record or {**DEFAULTS_PROVENANCE, "dt": dt}
    source = robot if robot in _robot_names() else str(Path(robot).resolve())
    header, payload = export.export_robot(
        loaded.mj_model,
        desc,
        params,
        terrain,
        rate_hz=rate_hz,
        robot_source=source,
        provenance=provenance,
        seed=seed,
        calibration=calibration,
    )
    export.write_artefact(out, header, payload)
    return export.read_artefact(out)[0]  # as written, checksum verified


def _robot_names() -> tuple[str, ...]:
    from jax_contact.train.cli_args import ROBOT_NAMES

    return ROBOT_NAMES


def run_export(args: argparse.Namespace) -> int:
    replaces = Path(args.out).is_file() and Path(args.out).stat().st_size > 0
    header = export_to_file(
        args.out,
        robot=args.robot or args.model,
        feet=args.feet,
        params_path=args.params,
        rate_hz=args.rate,
        seed=args.seed,
    )
    r = header["robot"]
    print(
        f"wrote {args.out}{' (replaced an earlier export)' if replaces else ''}:"
        f" {r['source']} (nq {r['nq']}, nv {r['nv']}, feet"
        f" {', '.join(r['feet'])}) at {header['rate_hz']:g} Hz, {header['payload_bytes']} bytes"
        f" of StableHLO; parameters: {header['params']['provenance'].get('source')}"
        + (f" {args.params!r}" if args.params is not None else "")
    )
    if (cal := header.get("calibration")) is not None:
        from jax_contact.calibration import Calibration

        described = Calibration.from_dict(cal).describe()
        print(f"p_contact through the file's calibration map ({described})")
    return 0


# -------------------------------------------------------------------------- deploy-check


def params_and_terrain(header: dict):
    """The estimator parameters and terrain model stored in an export's header."""
    import jax_contact as jc
    from jax_contact.params_file import params_from_dict

    params = params_from_dict(header["params"], source="export header")
    t = header["terrain"]

    def plane(t):
        if t.get("type") != "FlatTerrain":
            raise ValueError(
                f"deploy-check replays a plane or a foothold memory over one, got {t.get('type')!r}"
            )
        return jc.flat(float(t["height"]), float(t["sigma"]))

    if t.get("type") == "FootholdMemory":  # a file tuned with --terrain-model memory
        keys = ("sigma_foothold", "growth", "smoothing")
        return params, jc.foothold_memory(plane(t["fallback"]), **{k: float(t[k]) for k in keys})
    return params, plane(t)


def offline_estimate(header: dict, readings: dict, *, dt: float, robot=None):
    """(T, L) P(contact) of the offline estimator (``replay``) on one env's readings;
    ``robot``: the export's robot if already loaded (:func:`export_robot`), else loaded."""
    from jax_contact.train.evaluate import replay

    params, terrain = params_and_terrain(header)
    robot = robot or export_robot(header)
    out = replay(
        robot,
        {k: v[:, None] for k, v in readings.items()},
        estimators={"export": params},
        terrain=terrain,
        dt=dt,
        seed=int(header["key"]["seed"]),
        progress=False,
    )
    p = out["export"][:, 0]
    if (cal := header.get("calibration")) is not None:  # as the export reports P
        from jax_contact.calibration import Calibration, calibrate_probability

        p = calibrate_probability(p, Calibration.from_dict(cal))
    return p


def export_robot(header: dict):
    """The robot an export was made for (its header's source and feet), loaded."""
    from jax_contact.envs.robots import load_robot

    return load_robot(header["robot"]["source"], foot_names=header["robot"]["feet"])


def realtime_replay(
    est, readings: dict, *, period_s: float, pace: bool = True, spin_s: float = 3e-4
) -> dict:
    """Feeds ``readings`` ((T, n) arrays) through ``est`` one call per period.

    Each call is released at ``t0 + k * period_s`` (a sleep, then a spin for the last
    ``spin_s``; ``spin_s >= period_s`` spins the whole period); its latency is the
    duration of :meth:`Estimator.update`, and a deadline is missed when the call ends
    after the next release. Without ``pace`` the calls run back to back (no deadlines).

    Returns:
      ``latency_s`` (T,), ``p_contact`` (T, L), ``deadline_misses``, and each call's
      diagnostics that the torque check reads
      (:data:`jax_contact.train.recording_estimate.TORQUE_CHECK_INPUTS`), (T, L) each.
    """
    import time

    import numpy as np

    from jax_contact.train.recording_estimate import TORQUE_CHECK_INPUTS

    names = est.reading_names
    n_t = len(readings[names[0]])
    steps = [{k: readings[k][i] for k in names} for i in range(n_t)]
    warm = est.init()
    for _ in range(20):  # first calls allocate; a controller warms up before it starts
        warm, _, _ = est.update(warm, steps[0])
    belief = est.init()
    latency = np.empty(n_t)
    p = np.empty((n_t, len(est.feet)), np.float32)
    diags = []
    misses = 0
    clock = time.perf_counter
    t0 = clock() + 0.01
    for k in range(n_t):
        if pace:
            release = t0 + k * period_s
            wait = release - clock()
            if wait > spin_s:
                time.sleep(wait - spin_s)
            while clock() < release:
                pass
        start = clock()
        belief, p[k], diag = est.update(belief, steps[k])
        end = clock()
        latency[k] = end - start
        diags.append(diag)  # read after the loop
        if pace and end > t0 + (k + 1) * period_s:
            misses += 1
    terms = {k: np.stack([np.asarray(d[k]) for d in diags]) for k in TORQUE_CHECK_INPUTS}
    return {"latency_s": latency, "p_contact": p, "deadline_misses": misses, **terms}


def deploy_check(
    artefact: str | Path,
    log: str | Path,
    *,
    env: int = 0,
    steps: int | None = None,
    pace: bool = True,
    json_path: str | Path | None = None,
    names: dict[str, str] | None = None,
    units: str = "rad",
    resample: bool = False,
    max_diff: float = MAX_DIFF,
    max_misses: int | None = None,
) -> dict:
    """The ``deploy-check`` command as a function; returns its JSON payload.

    ``log`` is a ``jax-contact simulate`` log, or a recording of the robot
    (:func:`is_recording`), read with ``names``, ``units`` and ``resample`` as ``jax-contact
    estimate`` reads it, its convention checks printed as there.

    The payload's ``passed`` is False, and ``failed`` says why, when a simulate log is of
    another robot's physics than the export's, when the largest
    |P(contact) - offline estimate| exceeds ``max_diff``, when the exported file and the
    offline estimator disagree on which readings give no estimate (NaN in one, a number in
    the other), or when a paced replay missed more than ``max_misses`` deadlines (None:
    not checked).
    """
    import numpy as np

    from jax_contact import deploy
    from jax_contact.export import read_artefact
    from jax_contact.io import write_json_atomic
    from jax_contact.train.logs import load_log
    from jax_contact.train.recording_estimate import contact_summary, print_note, torque_note

    header, _ = read_artefact(artefact)
    terms = params_and_terrain(header)[0].terms
    try:
        robot = export_robot(header)
    except ValueError as err:
        # An export of --model PATH names that path; moved, the log's loader suggested
        # --robot, which deploy-check has not (a helper's trial).
        raise ValueError(
            f"{str(artefact)!r} was exported for the model {header['robot']['source']!r},"
            f" which cannot be loaded ({err}): deploy-check replays the readings offline with"
            " that model; put it back there, or export again from where it is now"
        ) from None
    if is_recording(log):
        if env != 0:
            raise ValueError(f"argument --env: a recording holds one robot (env 0), got {env}")
        name, conv = _recording_readings(robot, log, terms, names, units, resample)
        dt, readings, robot_name = conv.dt, conv.readings, header["robot"]["source"]
        other_robot = None  # a recording is read with the export's own robot model
    else:
        conv = None
        given = [
            f"--{opt}"
            for opt, on in (("names", names), ("units", units != "rad"), ("resample", resample))
            if on
        ]
        if given:  # a simulate log stores readings in the model's own names, units, rate
            print(
                f"note: {' and '.join(given)} read a recording's columns; {str(log)!r} is a"
                " `jax-contact simulate` log (its readings in the model's order, radians,"
                " one per step), so they do nothing here"
            )
        # Checked, and re-aligned to end-of-step readings if older (what the export pairs).
        loaded = load_log(log)
        name, dt, readings = loaded.name, loaded.dt, loaded.readings
        robot_name = loaded.attrs.get("robot")
        other_robot = _other_robot(name, artefact, header["robot"], loaded.attrs)
    dt = _replay_period(name, dt, artefact, header["rate_hz"])
    n_envs = readings["qpos"].shape[1]
    if env >= n_envs:
        raise ValueError(f"argument --env: {name} has {n_envs} envs, got --env {env}")
    for r in header["readings"]:
        if readings[r["name"]].shape[-1] != r["shape"][0]:
            raise ValueError(
                f"{name}: readings/{r['name']} has {readings[r['name']].shape[-1]} columns but"
                f" {str(artefact)!r} expects {r['shape'][0]} (robot {header['robot']['source']!r},"
                f" log robot {robot_name!r})"
            )
    if other_robot:
        print(f"warning: {other_robot}", file=sys.stderr)
    one = {k: np.ascontiguousarray(v[:steps, env], np.float32) for k, v in readings.items()}

    est = deploy.load(artefact)
    rt = realtime_replay(est, one, period_s=dt, pace=pace)
    offline = offline_estimate(header, one, dt=dt, robot=robot)
    diff = np.abs(rt["p_contact"] - offline)
    # Readings that give P in one program and NaN in the other: nanmax would skip them.
    nan_mismatch = int(np.sum(np.isnan(rt["p_contact"]) != np.isnan(offline)))
    lat_us = 1e6 * rt["latency_s"]
    result = {
        "artefact": str(artefact),
        "log": str(log),
        "env": env,
        "steps": int(len(lat_us)),
        "rate_hz": float(header["rate_hz"]),
        "paced": bool(pace),
        # The CPUs the replay ran on (--cpu pins one): latency depends on them.
        "cpus": sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "latency_us": {
            "median": float(np.median(lat_us)),
            "p99": float(np.percentile(lat_us, 99)),
            "p999": float(np.percentile(lat_us, 99.9)),
            "max": float(np.max(lat_us)),
        },
        "deadline_misses": int(rt["deadline_misses"]),
        "max_abs_diff": float(np.nanmax(diff)) if np.isfinite(diff).any() else float("nan"),
        "nan_mismatches": nan_mismatch,
        "contact_share": {
            foot: float(np.nanmean(rt["p_contact"][:, i] > 0.5))
            for i, foot in enumerate(header["robot"]["feet"])
        },
    }
    summary, all_air = contact_summary(
        np.array(list(result["contact_share"].values())),
        header["robot"]["feet"],
        floor_hint="export with a file tuned with --terrain-model memory",
        seconds=result["steps"] * dt,
    )
    notes = list(conv.notes) if conv is not None else []
    torque = (
        torque_note(rt, terms, robot.description, conv, notes, robot.mj_model)
        if conv is not None
        else None
    )
    # Every warning of the run, in the order printed: the recording's, the torque check's
    # and the summary's (every foot reads air).
    result["warnings"] = [
        *([other_robot] if other_robot else []),
        *(n.removeprefix("WARNING ") for n in notes if n.startswith("WARNING ")),
        *([torque.removeprefix("WARNING ")] if torque else []),
        *([all_air] if all_air else []),
    ]
    result["max_diff_allowed"] = float(max_diff)
    result["max_misses_allowed"] = None if max_misses is None else int(max_misses)
    result["failed"] = _check_failures(result, max_diff, max_misses, bool(other_robot))
    result["passed"] = not result["failed"]
    if json_path:  # before the printing, which a closed pipe (| head) can interrupt
        write_json_atomic(json_path, result)
    lat = result["latency_us"]
    print(
        f"{result['steps']} readings of env {env} at {result['rate_hz']:g} Hz through"
        f" {str(artefact)!r}:\n  latency per call: median {lat['median']:.1f} us, p99"
        f" {lat['p99']:.1f}, p99.9 {lat['p999']:.1f}, max {lat['max']:.1f} us\n  deadline"
        f" misses ({1e3 * dt:g} ms period): "
        + (f"{result['deadline_misses']}" if pace else "not paced (--no-pace)")
        + f"\n  max |P(contact) - offline estimate|: {result['max_abs_diff']:.2e}\n  "
        + summary
    )
    if all_air:
        print(f"warning: {all_air}")
    if torque:
        print_note(torque)
    if result["passed"]:
        print(
            f"passed: max |P(contact) - offline estimate| {result['max_abs_diff']:.2e} <="
            f" {max_diff:g} (--max-diff)"
            + (f", {result['deadline_misses']} <= {max_misses} deadline misses (--max-misses)"
               if max_misses is not None else "")
        )  # fmt: skip
    else:
        print("FAILED: " + "; ".join(result["failed"]))
    return result


def _check_failures(
    result: dict, max_diff: float, max_misses: int | None, other_robot: bool = False
) -> list[str]:
    """Why a deploy-check ``result`` fails its pass marks, one sentence each; [] passes.
    ``other_robot``: the log is of another robot's physics than the export's."""
    failed = []
    if other_robot:  # the agreement holds, but the export was checked on no log of its robot
        failed.append(
            "the log is not of the export's robot (the warning above): the check says nothing"
            " of the estimate on this robot's readings"
        )
    diff = result["max_abs_diff"]
    if diff != diff:  # NaN: no reading gave a number to compare
        failed.append("no reading gave both programs a P(contact) to compare")
    elif diff > max_diff:
        why = f"max |P(contact) - offline estimate| {diff:.2e} > {max_diff:g} (--max-diff)"
        if diff >= MAX_DIFF:
            why += (
                ": more than float32 round-off, the exported file and the library disagree"
                " (another parameter file, terrain model or robot than the log's, or"
                " library versions apart)"
            )
        failed.append(why)
    if result["nan_mismatches"]:
        failed.append(
            f"{result['nan_mismatches']} outputs are NaN in one program and a number in the"
            " other (the two take lost readings differently)"
        )
    if max_misses is not None and result["deadline_misses"] > max_misses:
        failed.append(
            f"{result['deadline_misses']} deadline misses > {max_misses} (--max-misses) at"
            f" {result['rate_hz']:g} Hz"
        )
    return failed


def _other_robot(name: str, artefact, robot: dict, attrs: dict) -> str | None:
    """The warning when a simulate log is not of the export's robot, else None: their
    physics' fingerprints (``model_sha256``) differ, or, where the export or the log
    predates them, their robot names do (an export of ``--model PATH`` names a path)."""
    ours, theirs = robot.get("model_sha256"), attrs.get("model_sha256")
    if ours and theirs and ours == theirs:
        return None
    if attrs.get("robot") != robot["source"]:
        what = f"robot {attrs.get('robot')!r}"
    elif ours and theirs:
        what = f"a {attrs.get('robot')!r} of other physics (model_sha256 differs)"
    else:
        return None
    return (
        f"{name} is of {what}, {str(artefact)!r} of {robot['source']!r}: their readings have"
        " the same sizes, so the check runs, but its P(contact) is not an estimate of this"
        " log's robot (the latency and the agreement with the library's own estimate still"
        " hold)"
    )


def _replay_period(name: str, dt: float, artefact, rate_hz: float) -> float:
    """The period a log is replayed at through an export of ``rate_hz``: the export's own.

    A log's period is the median step of its clock, which float32 or epoch timestamps
    leave a few 1e-5 away from the nominal rate (399.992 Hz for a 400 Hz loop); within
    :data:`~jax_contact.train.cli_args.RATE_TOLERANCE` (the recordings' own tolerance
    for their steps) the log is taken to be at the export's rate, as the control loop
    calls it, with a note.

    Raises:
      ValueError: the rates differ by more than that.
    """
    from jax_contact.train.cli_args import RATE_TOLERANCE

    off = abs(dt * rate_hz - 1.0)
    if off > RATE_TOLERANCE:
        raise ValueError(
            f"{name} is at {1.0 / dt:.6g} Hz but {str(artefact)!r} was exported for"
            f" {rate_hz:g} Hz (more than {100 * RATE_TOLERANCE:g} % apart): export at the"
            " log's rate"
        )
    if off > 1e-6:
        print(
            f"note: {name} is at {1.0 / dt:.6g} Hz (its median step), {str(artefact)!r} was"
            f" exported for {rate_hz:g} Hz: within {100 * RATE_TOLERANCE:g} %, so it is"
            f" replayed at {rate_hz:g} Hz, as the control loop calls the estimator"
        )
    return 1.0 / rate_hz


def is_recording(path: str | Path) -> bool:
    """Whether ``path`` is a recording (:mod:`jax_contact.train.recording`) rather than a
    ``jax-contact simulate`` log: a CSV or NPZ file, or an HDF5 file with a ``time``
    dataset at its root and no ``readings`` group."""
    path = Path(path)
    if path.suffix.lower() in (".csv", ".npz"):
        return True
    import h5py

    try:
        with h5py.File(path, "r") as f:  # a simulate log also has time, beside readings/
            return isinstance(f.get("time"), h5py.Dataset) and "readings" not in f
    except OSError:
        return False  # not HDF5: load_log names the file and the reason


def _recording_readings(robot, log, terms, names, units: str, resample: bool):
    """(name, :class:`~jax_contact.train.recording_convert.Converted`) of a recording of
    the artefact's robot (:func:`export_robot`), its notes and warnings printed as
    ``jax-contact estimate`` prints them; ``terms``: the exported estimator's measurement
    terms.

    Raises:
      ValueError: as :func:`jax_contact.train.recording_convert.to_readings`, or the
        recording cannot feed a term the exported estimator runs (the dynamics: joint
        torques, and joint velocities or accelerations; the kinematics: a base position;
        the differential kinematics: a base velocity or position): an export runs every
        term it was made with, on whatever the readings hold.
    """
    from jax_contact.train.recording import read_recording
    from jax_contact.train.recording_convert import to_readings
    from jax_contact.train.recording_estimate import print_note

    conv = to_readings(read_recording(log), robot, names=names, units=units, resample=resample)
    name = f"recording {str(log)!r}"
    if not conv.has_torque and "dynamics" in terms:
        raise ValueError(
            f"{name} has no tau/ column for the actuated joint(s)"
            f" {list(conv.missing_torques)}, but the exported estimator's dynamics term reads"
            " every joint torque (the readings would hold zeros): record"
            " the torques, or run `jax-contact estimate`, which leaves the term out"
        )
    if off := [t for t in terms if t not in conv.terms]:
        # to_readings leaves these out for `estimate` (it says so in a note); the export
        # would run them on zeros or on positions differenced twice (a helper's trial
        # without qd/ columns: every foot read air, 0.40 accuracy, the check "agreed").
        why = [n.removeprefix("WARNING ") for n in conv.notes if "term is off" in n]
        raise ValueError(
            f"{name} cannot feed the exported estimator's {' and '.join(off)} term"
            f"{'s' if len(off) > 1 else ''} ({'; '.join(why)}); an export runs every term it"
            " was made with: record the missing columns, or run `jax-contact estimate`,"
            " which leaves the term out"
        )
    for note in conv.notes:
        print_note(note)
    return name, conv


def run_deploy_check(args: argparse.Namespace) -> int:
    from jax_contact.train.estimate_cmd import parse_names

    if args.cpu is not None:
        # Before the first computation: XLA's CPU client sizes its thread pool from the
        # process's CPUs when it starts (at the first array, not at `import jax`, which the
        # command line does before every command; a warning said "--cpu after jax was
        # imported" on every run, a helper's trial).
        os.sched_setaffinity(0, {args.cpu})
    result = deploy_check(
        args.artefact,
        args.log,
        env=args.env,
        steps=args.steps,
        pace=not args.no_pace,
        json_path=args.json,
        names=parse_names(args.names),
        units=args.units,
        resample=args.resample,
        max_diff=args.max_diff,
        max_misses=args.max_misses,
    )
    return 0 if result["passed"] else EXIT_CHECK_FAILED


if __name__ == "__main__":  # python -m jax_contact.train.deploy_cmd {export,deploy-check} ...
    from jax_contact.train import cli

    parser = argparse.ArgumentParser(prog="jax-contact")
    add_parsers(parser.add_subparsers(dest="command", metavar="COMMAND"))
    ns = parser.parse_args()
    try:
        ns.check(ns)
    except ValueError as err:
        print(f"jax-contact {ns.command}: error: {err}", file=sys.stderr)
        sys.exit(cli.EXIT_USAGE)
    sys.exit(ns.func(ns))
