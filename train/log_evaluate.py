"""``jax-contact evaluate`` on logs: every detector replayed on each log's readings and
scored against its ground truth (the metrics of :mod:`jax_contact.metrics`); given several
logs, their metrics pooled too (:func:`evaluate_files`).
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jax_contact.io import staged_folder, write_json_atomic
from jax_contact.metrics import bounce_counts, bounce_steps
from jax_contact.robot import model_mass
from jax_contact.train.log_estimator import default_estimator, estimator_for
from jax_contact.train.logs import TRUTH_CONTACT, LoadedLog, load_log, log_noise, log_setup
from jax_contact.train.report import format_scores


def scored_steps(out: dict, truth: np.ndarray, valid: np.ndarray):
    """(scored, truth known), both (T, E, L) bool: the foot-steps a log's metrics score.

    A log's truth is known on its valid steps. Where the estimator skipped a foot's
    update because a reading it reads is not finite (``out["probabilistic/valid"]``,
    present when :func:`jax_contact.train.evaluate.replay` ran with ``diagnostics_of=
    "probabilistic"``), that foot-step is not scored for any detector, as ``jax-contact
    estimate`` does on a recording; its truth stays known, so it does not cut a true air
    phase in two (``jax_contact.metrics`` rules 7b and 8).

    Args:
      out: the replay's outputs.
      truth: (T, E, L) bool.
      valid: (T, E) bool.
    """
    known = np.broadcast_to(np.asarray(valid, bool)[..., None], np.shape(truth))
    read = out.get("probabilistic/valid")
    scored = known if read is None else known & np.asarray(read, bool)
    return scored, known


UNTUNED_BASELINES = (
    "gm and kinematic: the baselines at their untuned defaults (K_I 50 1/s, or 1/dt on a"
    " log slower than 50 Hz, 20 N; 2 cm, 0.3 m/s), not tuned for this robot"
)
GM_GRID_HINT = "; --gm-grid LOG tunes them on another seed's log, as the reproduction does"


def _estimator_read(log: LoadedLog) -> np.ndarray:
    """The foot-steps a log's baselines are scored on when they are tuned: its valid steps
    less those where the default estimator skips a foot for a lost reading, the steps
    :func:`scored_steps` leaves out of every detector's score (the grid was scored on all
    valid steps, the rows it picked then on fewer)."""
    from jax_contact.train.logs import log_noise
    from jax_contact.train.tune_data import default_params, feet_read, measure_readings

    known = np.broadcast_to(np.asarray(log.valid, bool)[..., None], np.shape(log.truth))
    if not log.lost:  # load_log found every reading of a valid step finite
        return known
    params, _ = default_params(log.robot, log.dt, log_noise(log.attrs))
    read = feet_read(params, log.readings, measure_readings(log.robot, log.readings))
    return known & np.asarray(read, bool)


def tune_baselines(path: str | Path) -> dict:
    """The GM observer's and the kinematic detector's settings of
    ``jax_contact.train.reproduce``'s grids with the best F1 on a log, from one replay.

    Every point of :func:`jax_contact.train.reproduce.gm_grid` and
    :func:`jax_contact.train.reproduce.kinematic_grid` runs on the log; the picks follow
    rule the reproduction tunes by (:func:`jax_contact.train.reproduce.best_setting`: best
    per-step F1, ties: fewer failures). Each grid is also picked by the estimator defaults'
    rule, as the reproduction's rows ``*_fl`` (``FAILURE_LIMIT``: swing phases with a false
    contact or the flag on throughout at most 2 %, then F1), where a point meets it.

    Returns:
      ``{"gm": (name, GMParams), "kinematic": (name, KinematicParams), "scores": {"gm": GM
      grid name -> scores, "kinematic": kinematic grid name -> scores}, "grid_edges":
      {"gm": [...], "kinematic": [...]}, "failure_limited": {"gm_fl": ..., "kinematic_fl":
      ...}, "failure_limited_params": {row: params}}``
      (:func:`jax_contact.train.reproduce.grid_edges`); each ``failure_limited`` entry is a
      :func:`jax_contact.train.reproduce.failure_limited_record`, and
      ``failure_limited_params`` holds the settings of the rows that meet the limit.

    Raises:
      ValueError: the log has no ground truth, or as :func:`load_log`.
    """
    import jax_contact as jc
    from jax_contact.train.evaluate import replay, score
    from jax_contact.train.reproduce import (
        GM_FIELDS,
        KIN_FIELDS,
        TERRAIN_SIGMA,
        best_setting,
        failure_limited_record,
        foot_load,
        gm_grid,
        grid_edges,
        kinematic_grid,
    )

    log = load_log(path)
    if log.truth is None:
        raise ValueError(f"{log.name} has no ground truth ({TRUTH_CONTACT!r}): cannot tune on it")
    gms, kins = gm_grid(foot_load(log.robot), log.dt), kinematic_grid()
    out = replay(
        log.robot,
        log.readings,
        estimators={},
        terrain=jc.flat(0.0, TERRAIN_SIGMA),
        gms=gms,
        kinematic=kins,
        dt=log.dt,
    )
    scored = _estimator_read(log)
    scores = {
        grid: score(out, log.truth, scored, dt=log.dt, names=list(names))
        for grid, names in (("gm", gms), ("kinematic", kins))
    }
    grids = {"gm": (gms, GM_FIELDS), "kinematic": (kins, KIN_FIELDS)}
    gm, kin = (best_setting({log.name: scores[grid]}) for grid in grids)
    edges = {"gm": grid_edges(gms, gm, GM_FIELDS), "kinematic": grid_edges(kins, kin, KIN_FIELDS)}
    limited, limited_params = {}, {}
    for grid, (points, fields) in grids.items():
        record = failure_limited_record(points, {log.name: scores[grid]}, fields)
        limited[f"{grid}_fl"] = record
        if record["row"]:
            limited_params[f"{grid}_fl"] = points[record["pick"]]
    return {
        "gm": (gm, gms[gm]),
        "kinematic": (kin, kins[kin]),
        "scores": scores,
        "grid_edges": edges,
        "failure_limited": limited,
        "failure_limited_params": limited_params,
    }


def check_gm_grid_log(gm_grid_log: str | Path, paths: Sequence[str | Path]) -> None:
    """Refuses a ``--gm-grid`` log of another robot or rate than an evaluated log, from
    the logs' attributes, before any replay: the GM grid's thresholds are shares of the
    tuning robot's foot load (N) and its gains act per step, so its picks are no tuning of
    another robot or rate. One robot: the same name, or the same physics fingerprint (or
    one that cannot be told: a model not on this machine, which its loading names)."""
    from jax_contact.train.cli_args import RATE_TOLERANCE

    robot, dt, sha = log_setup(gm_grid_log)
    grid_print = []  # the tuning log's fingerprint, computed once and only if a name differs
    for path in paths:
        other, other_dt, other_sha = log_setup(path)
        if other != robot and not grid_print:
            grid_print.append(_fingerprint(robot, sha))
        prints = {grid_print[0], _fingerprint(other, other_sha)} if other != robot else set()
        same_robot = other == robot or None in prints or len(prints) == 1
        if same_robot and abs(other_dt - dt) <= RATE_TOLERANCE * max(dt, other_dt):
            continue
        raise ValueError(
            f"argument --gm-grid: log {str(gm_grid_log)!r} is {robot!r} at {1.0 / dt:.6g} Hz,"
            f" the evaluated log {str(path)!r} {other!r} at {1.0 / other_dt:.6g} Hz: tune the"
            " baselines on another seed's log of the same robot and rate"
        )


def _fingerprint(robot: str, stored: str | None, mj_model=None) -> str | None:
    """A log's physics fingerprint: ``stored`` (its ``model_sha256``), else its robot's
    model's (logs written before the attribute; ``mj_model`` if already loaded, else
    loaded by name), else None (a model not on this machine)."""
    if stored is not None:
        return stored
    from jax_contact.envs.robots import load_robot
    from jax_contact.robot import model_fingerprint

    try:
        return model_fingerprint(mj_model if mj_model is not None else load_robot(robot).mj_model)
    except Exception:  # noqa: BLE001  (any model that does not load: no fingerprint)
        return None


def tuned_line(gm_grid_log, tuned: dict, note: str = "") -> str:
    """What :func:`tune_baselines` chose on ``gm_grid_log``, with the picks on an edge of
    their grid named (the grid may hold them back there), then the rows ``*_fl``
    (:func:`jax_contact.train.reproduce.format_failure_limited`)."""
    from jax_contact.train.reproduce import format_failure_limited

    edges = [f"{k} {', '.join(v)}" for k, v in tuned["grid_edges"].items() if v]
    on_edge = f"; on the grid's edge: {'; '.join(edges)}" if edges else ""
    return (
        f"GM observer and kinematic detector tuned on {str(gm_grid_log)!r}: {tuned['gm'][0]},"
        f" {tuned['kinematic'][0]} (best F1 of each grid{on_edge}){note}\n"
        + format_failure_limited(tuned["failure_limited"])
    )


def tune_gm(path: str | Path) -> tuple[str, object, dict]:
    """The GM observer of :func:`tune_baselines`: (grid name, e.g. ``"gm_K50_F15"``, its
    GMParams, GM grid name -> scores)."""
    tuned = tune_baselines(path)
    name, gm = tuned["gm"]
    return name, gm, tuned["scores"]["gm"]


def evaluate_file(
    path: str | Path,
    *,
    json_path: str | Path | None = None,
    gm_grid_log: str | Path | None = None,
    params_path: str | Path | None = None,
    foot_names: Sequence[str] | None = None,
    robot: str | None = None,
    terrain_model: str | None = None,
    bootstrap: int = 0,
    plots_dir: str | Path | None = None,
    tuned_baselines: dict | None = None,
    legend: bool = True,
    loaded: LoadedLog | None = None,
    plots_to: str | Path | None = None,
    json_later: str | Path | None = None,
    title: str | None = None,
) -> dict:
    """Runs the estimator, GM observer and kinematic detector on a log; prints the metrics.

    The log is replayed with the robot and feet it was made with (its ``foot_names``
    attribute) unless ``foot_names`` is given. Every detector's full metric set is printed
    as one table with a header and a legend (``jax_contact.train.report.format_table``):
    touch-down and lift-off delays, F1, accuracy, failures, per-air-phase and per-swing-phase
    failure rates, missed touch-downs and lift-offs, ECE. A parameter file that holds a
    calibration map (``jax-contact tune --calibrate``, the shipped presets) adds the row
    ``probabilistic+cal``: the estimator's P(contact) mapped by it
    (:func:`jax_contact.tune.calibrate_probability`), flagged at calibrated P > 0.5. With a
    parameter file the robot's default parameters run too, as the row ``defaults`` (same
    terrain model), so a tuned file is seen beside what it was tuned from.

    With ``bootstrap`` > 0 (and ground truth) every other row is compared with
    ``probabilistic`` by a paired bootstrap of that many env resamples
    (:func:`jax_contact.bootstrap.paired_bootstrap`, 95 %, seed 0): ``probabilistic - row``
    of every statistic of :data:`jax_contact.bootstrap.STATISTICS` (F1, accuracy, air- and
    swing-phase failures, sw-on, ``|mean|`` delays, ECE), each called better, worse or within
    noise (the log needs at least 2 envs).

    A log without ground truth (no ``truth/contact``, e.g. one recorded on a robot) has no
    metrics: the estimator's P(contact) per foot is then printed as a mean per foot and,
    with ``json_path``, written per step and env under ``"p_contact"``.

    Args:
      json_path: write the result as JSON here.
      gm_grid_log: tune the GM observer and the kinematic detector on this other log
        (:func:`tune_baselines`) instead of using their default settings
        (``make_gm_params()``, ``make_kinematic_params()``).
      params_path: estimator parameters (:func:`jax_contact.load_params`) instead of the
        robot's defaults (:func:`default_estimator`).
      foot_names: the feet, overriding the log's.
      robot: the robot, overriding the one the log names (:func:`load_log`).
      loaded: ``path`` as :func:`load_log` already read it (with ``foot_names`` and
        ``robot``); None: it is read here.
      terrain_model: the estimator's terrain model, one of :data:`TERRAIN_MODELS`
        (:func:`default_estimator`); None: the one ``params_path`` was tuned with, else
        ``"flat"`` (:func:`resolve_terrain_model`).
      bootstrap: env resamples of the comparison with ``probabilistic``; 0: none.
      plots_dir: write the reliability diagram of every scored row
        (:func:`jax_contact.train.calibration.reliability_diagram`, ECE in the legend) to
        ``plots_dir/reliability_<log stem>.png``; without ground truth nothing is drawn
        (a line says so).
      tuned_baselines: :func:`tune_baselines` of ``gm_grid_log``, already computed (several
        logs tuned on one: :func:`evaluate_files`); None tunes here when ``gm_grid_log``
        is given.
      legend: print the table's legend under it (:func:`evaluate_files` prints it once).
      plots_to: where ``plots_dir``'s files end up when ``plots_dir`` stages them
        (:func:`evaluate_files`: all of a run's plots or none); the printed and returned
        paths are there. None: ``plots_dir`` itself.
      json_later: the file the caller writes this result into (:func:`evaluate_files`),
        named in what is printed; None: ``json_path``.
      title: the table's title; None: the log's file name.

    Returns:
      ``log``, ``attrs``, ``scores`` (detector -> metrics; empty without ground truth),
      ``vs_probabilistic`` (row -> statistic -> ``[delta, low, high, verdict]``, with
      ``bootstrap``),
      ``has_truth``, ``foot_names``, ``gm`` (the GM setting used), ``outputs`` (the
      replay's (T, E, L) arrays, not written to the JSON) and ``p_contact`` (foot -> (T, E)
      nested lists) when the log has no ground truth; beside ``outputs``, also not in the
      JSON: ``dt``, ``robot`` (the name it was loaded by) and, with ground truth, the
      (T, E, L) ``truth``, ``scored`` and ``truth_known`` the scores were computed on.

    Raises:
      FileNotFoundError: no such file.
      ValueError: one line naming the file, the field and what was expected: unreadable
        file, a missing attribute or array, an array of the wrong shape, a robot whose
        model does not fit the readings.
    """
    from jax_contact.baselines import make_gm_params, make_kinematic_params
    from jax_contact.train.evaluate import replay, score

    if gm_grid_log is not None and tuned_baselines is None:
        check_gm_grid_log(gm_grid_log, [path])
    log = loaded or load_log(path, foot_names=foot_names, robot=robot)
    name, truth, desc, dt = log.name, log.truth, log.robot.description, log.dt
    mass = model_mass(log.robot.mj_model)
    noise = log_noise(log.attrs)  # the defaults are the log's sensors', as tune's
    params, terrain_model, terrain, calibration, params_record = estimator_for(
        desc, dt, params_path, terrain_model, mass, mj_model=log.robot.mj_model,
        robot=log.robot.name, noise=noise,
    )  # fmt: skip
    if bootstrap and truth is not None and truth.shape[1] < 2:
        raise ValueError(
            f"{name} has {truth.shape[1]} env: the bootstrap resamples envs and needs at least 2"
        )
    estimators = {"probabilistic": params}
    if params_path is not None:
        estimators["defaults"] = default_estimator(
            desc, dt, terrain_model, mj_model=log.robot.mj_model, noise=noise
        )[0]
    gm_name, gm = "gm", make_gm_params()
    # A slow log: the default's pole would leave (0, 1]. (With --gm-grid the tuned GM runs
    # instead, and without truth no GM runs: no note then.)
    if float(gm.K_I) * dt > 1.0 and gm_grid_log is None and truth is not None:
        gm = make_gm_params(K_I=1.0 / dt)
        print(
            f"note: the GM observer's default K_I is lowered to 1 / dt = {1.0 / dt:g} 1/s at"
            f" this log's {1.0 / dt:g} Hz (K_I dt <= 1: above, the discrete observer overshoots)"
        )
    kinematic = make_kinematic_params()
    # The baselines picked by the estimator's rule (tune_baselines), rows gm_fl and
    # kinematic_fl, where a point of the grid meets it.
    gms_fl, kins_fl, limited = {}, {}, None
    if gm_grid_log is not None and truth is not None:
        tuned = tuned_baselines or tune_baselines(gm_grid_log)
        (gm_name, gm), (_, kinematic) = tuned["gm"], tuned["kinematic"]
        limited = tuned["failure_limited"]
        for row, params in tuned["failure_limited_params"].items():
            (gms_fl if row == "gm_fl" else kins_fl)[row] = params
        if tuned_baselines is None:
            print(tuned_line(gm_grid_log, tuned))
    out = replay(
        log.robot,
        log.readings,
        estimators=estimators,
        terrain=terrain,
        # Without ground truth only the estimator's P(contact) is reported.
        gms={gm_name: gm, **gms_fl} if truth is not None else None,
        kinematic={"kinematic": kinematic, **kins_fl} if truth is not None else None,
        dt=dt,
        # A reading that is not finite leaves its feet to the prediction alone: the
        # estimator's per-foot validity says which, and those steps are not scored.
        diagnostics_of="probabilistic" if truth is not None and log.lost else None,
    )
    if calibration is not None and truth is not None:
        # The map fitted on the tuning logs, applied after the recursion: a second row,
        # flagged at calibrated P > 0.5 (as in docs/tuning.md's comparisons).
        from jax_contact.tune import calibrate_probability

        out["probabilistic+cal"] = calibrate_probability(out["probabilistic"], calibration)
    feet = list(desc.foot_names)
    if params_path is not None:
        print(
            f"probabilistic: the estimator with --params {str(params_path)!r}; defaults: with the"
            " robot's derived defaults, on the same readings"
        )
    if gm_grid_log is None and truth is not None and legend:
        print(UNTUNED_BASELINES + GM_GRID_HINT)
    result = {
        "log": str(path),
        "params": params_record or {"source": "defaults"},
        "terrain_model": terrain_model,
        "attrs": log.attrs,
        "has_truth": truth is not None,
        "foot_names": feet,
        "gm": {"name": gm_name, "K_I": float(gm.K_I), "threshold": float(gm.threshold)},
        "kinematic": {
            "height_threshold": float(kinematic.height_threshold),
            "velocity_threshold": float(kinematic.velocity_threshold),
        },
    }
    if limited is not None:
        result["failure_limited"] = limited
    scored = known = None
    if truth is None:
        p = np.asarray(out["probabilistic"])  # (T, E, L)
        if calibration is not None:
            # What estimate, export and the wrapper report for this file: P through its map.
            from jax_contact.tune import calibrate_probability

            p = np.asarray(calibrate_probability(p, calibration))
            print(f"P(contact) read through the calibration map of {str(params_path)!r}")
        result["p_contact_calibrated"] = calibration is not None
        means = "  ".join(f"{f} {np.nanmean(p[..., i]):.3f}" for i, f in enumerate(feet))
        print(
            f"{name} has no ground truth ({TRUTH_CONTACT!r}): no metrics can be computed."
            f"\nmean P(contact) per foot over {p.shape[0]} steps x {p.shape[1]} envs: {means}"
        )
        if json_path:
            print(f"P(contact) per foot, step and env written to {json_path}")
        elif json_later:
            print(f"P(contact) per foot, step and env goes into {json_later} with the other logs'")
        else:
            print("pass --json FILE to write P(contact) per foot, step and env")
        if bootstrap:
            print("--bootstrap: no ground truth, so there is nothing to compare")
        if gm_grid_log is not None:
            print("--gm-grid: no ground truth, so no baseline is scored on this log")
        if plots_dir is not None:
            print("--plots: no ground truth, so no reliability diagram")
        result["scores"] = {}
        result["p_contact"] = {f: p[..., i] for i, f in enumerate(feet)}
    else:
        scored, known = scored_steps(out, truth, log.valid)
        scores = score(out, truth, scored, dt=dt, truth_known=known)
        print(format_scores(scores, title=title or Path(path).name, legend=legend))
        if note := weaker_than_kinematic(scores):
            print(note)
        if note := bounce_note(truth, log.valid, dt):
            print(note)
        result["scores"] = scores
        if bootstrap:
            result["vs_probabilistic"] = _vs_probabilistic(
                out, scores, truth, scored, dt, bootstrap, truth_known=known
            )
        if plots_dir is not None:
            from jax_contact.train.calibration import reliability_diagram

            png = reliability_diagram(
                out,
                truth,
                scored,
                Path(plots_dir) / f"reliability_{Path(path).stem}.png",
                names=list(scores),
                title=f"{Path(path).name}: reliability of P(contact)",
            )
            if plots_to is not None:
                png = Path(plots_to) / Path(png).name
            print(f"wrote {png}" if plots_to is None else f"drew {png}")
            result["plots"] = [str(png)]
    if json_path:
        written = write_json_atomic(json_path, json.loads(json.dumps(result, default=_plain)))
        if truth is not None:  # without truth the line above says where P(contact) went
            print(f"wrote {written}")
    # Not in the JSON: (T, E, L) arrays of every detector, and what pooling needs.
    result.update(outputs=out, dt=dt, robot=log.robot.name)
    if truth is not None:
        result.update(truth=truth, scored=scored, truth_known=known)
    return result


def evaluate_files(
    paths: Sequence[str | Path],
    *,
    json_path: str | Path | None = None,
    gm_grid_log: str | Path | None = None,
    bootstrap: int = 0,
    **options,
) -> dict:
    """:func:`evaluate_file` on each of ``paths``, and their metrics pooled.

    One log is :func:`evaluate_file` itself (its JSON as there). With several, each log's
    table is printed as it would be alone (``options``: ``params_path``, ``foot_names``,
    ``robot``, ``terrain_model``, ``plots_dir``, for all of them), the GM observer and
    kinematic detector are tuned once on ``gm_grid_log`` for all, and the logs with ground
    truth of one robot at one period (the largest such set,
    :func:`jax_contact.train.recording_batch.pool_groups`; at least two) are scored
    together: every env of every log one sequence of one (T, E, L) batch, padded with
    unscored steps to the longest log (:func:`jax_contact.train.recording_batch.
    pooled_arrays`), so the counts (steps, failures, air phases, events) are the sums of the
    logs' own and the per-step scores their step-weighted means. ``bootstrap`` resamples
    the pooled envs (several logs of few envs compare where one could not); the per-log
    tables then have no bootstrap.

    Returns:
      One log: :func:`evaluate_file`'s result. Several: ``logs`` (each one's result),
      ``pooled`` (detector -> metrics, or None when fewer than two logs pool),
      ``pooled_logs`` (their paths), ``not_pooled`` (path -> why), and with ``bootstrap``
      ``vs_probabilistic`` of the pooled envs. ``json_path`` gets all of it but the arrays,
      written once at the end.

    Raises:
      ValueError: as :func:`evaluate_file`, naming the log; a log given twice.
    """
    from jax_contact.train.cli_args import check_distinct_files
    from jax_contact.train.recording_batch import pool_groups, pooled_arrays

    paths = [str(p) for p in paths]
    if len(paths) == 1:
        return evaluate_file(
            paths[0], json_path=json_path, gm_grid_log=gm_grid_log, bootstrap=bootstrap, **options
        )
    check_distinct_files("log", paths)
    if gm_grid_log is not None:
        check_gm_grid_log(gm_grid_log, paths)
    # Every log read and checked before the first replay: a bad last log failed after the
    # others' replays (minutes each), and nothing was written.
    logs = [
        load_log(p, foot_names=options.get("foot_names"), robot=options.get("robot")) for p in paths
    ]
    tuned = None
    if gm_grid_log is None and any(log.truth is not None for log in logs):
        print(UNTUNED_BASELINES + GM_GRID_HINT)
    if gm_grid_log is not None:
        tuned = tune_baselines(gm_grid_log)
        print(tuned_line(gm_grid_log, tuned, ", for every log"))
    # A run's plots appear together or not at all: staged, and moved in when every log is
    # done (a stop after two of three logs left their two PNGs).
    plots_dir = options.pop("plots_dir", None)
    staging = staged_folder(plots_dir) if plots_dir is not None else contextlib.nullcontext()
    # Two logs of one file name (in two folders) get their paths as titles.
    names = [Path(p).name for p in paths]
    # One robot to the pooling as to --gm-grid: the same name or the same physics (a log
    # simulated from an MJCF path and one from the shipped model of the same robot were not
    # pooled, a helper's trial), named after the first log of that physics.
    same_physics: dict[str, str] = {}
    robot_of = [
        same_physics.setdefault(
            _fingerprint(log.robot.name, log.attrs.get("model_sha256"), log.robot.mj_model),
            log.robot.name,
        )
        for log in logs
    ]
    with staging as stage:
        results = []
        for i, p in enumerate(paths):
            results.append(
                evaluate_file(
                    p, gm_grid_log=gm_grid_log, tuned_baselines=tuned, legend=False, loaded=logs[i],
                    plots_dir=stage, plots_to=plots_dir, json_later=json_path,
                    title=p if names.count(names[i]) > 1 else None, **options,
                )
            )  # fmt: skip
            logs[i] = None  # its readings are not needed again
        keys = [str(i) for i in range(len(paths))]
        dts = {k: r["dt"] if r["has_truth"] else None for k, r in zip(keys, results, strict=True)}
        robots = {k: robot_of[int(k)] for k, r in zip(keys, results, strict=True) if r["has_truth"]}
        # The largest set of one robot and rate, whichever robot has the most logs (ties: the
        # set of the earliest log).
        pooled_keys, why = pool_groups(dts, robots)
        not_pooled = {
            r["log"]: why[k].replace("recording", "log")
            for k, r in zip(keys, results, strict=True)
            if k not in pooled_keys
        }
        for path, reason in not_pooled.items():
            print(f"note: {path!r} is not pooled: {reason}")
        summary = {"pooled": None, "pooled_logs": [], "not_pooled": not_pooled}
        if pooled_keys:
            group = {k: results[int(k)] for k in pooled_keys}
            outputs, truth, valid, known, dt = pooled_arrays(group)
            from jax_contact.train.evaluate import score

            pooled = score(outputs, truth, valid, dt=dt, names=list(outputs), truth_known=known)
            summary["pooled"] = pooled
            summary["pooled_logs"] = [g["log"] for g in group.values()]
            print(format_scores(pooled, title=f"{len(group)} logs pooled"))
            noises = sorted({log_noise(g["attrs"]) for g in group.values()})
            params_path = options.get("params_path")
            if len(noises) > 1 and params_path is None:
                print(
                    f"note: the pooled logs were simulated with the sensor presets {noises}:"
                    " each log's estimator ran with the defaults derived for its own, so the"
                    " pooled row 'probabilistic' mixes those estimators (pool one preset's"
                    " logs, or pass --params for one estimator on all)"
                )
            elif len(noises) > 1:
                print(
                    f"note: the pooled logs were simulated with the sensor presets {noises};"
                    f" one estimator ({str(params_path)!r}) ran on all of them"
                )
            if bootstrap:
                summary["vs_probabilistic"] = _vs_probabilistic(
                    outputs, pooled, truth, valid, dt, bootstrap, truth_known=known
                )
        else:
            print("no pooled metrics: fewer than two logs with ground truth of one robot and rate")
            if bootstrap:
                print("--bootstrap: nothing pooled, so nothing to compare")
        arrays = ("outputs", "truth", "scored", "truth_known", "dt", "robot")
        logs = [{k: v for k, v in r.items() if k not in arrays} for r in results]
        if json_path:
            payload = {"logs": logs, **summary}
            written = write_json_atomic(json_path, json.loads(json.dumps(payload, default=_plain)))
            print(f"wrote {written}")
    if plots_dir is not None:
        drawn = [png for r in results for png in r.get("plots", [])]
        print(f"wrote {len(drawn)} reliability diagram(s) into {plots_dir}")
    return {"logs": results, **summary}


def bounce_note(truth, valid, dt: float) -> str | None:
    """The note ``evaluate`` prints when more than a quarter of a log's true air phases are
    bounces (at most :func:`jax_contact.metrics.bounce_steps` steps, the 10 ms of rule 9b),
    else None.

    Args:
      truth: (T, E, L) bool ground truth.
      valid: (T, E) bool.
      dt: period, s.
    """
    short, n_air = bounce_counts(truth, valid, dt)
    n_bounce = bounce_steps(dt)
    if not n_air or short <= 0.25 * n_air:
        return None
    return (
        f"note: {short} of {n_air} true air phases last at most {n_bounce} steps"
        f" ({n_bounce * dt * 1e3:.3g} ms), most often a resting foot's load dropping"
        " for a step (the floor's soft contact): every detector's missed lift-offs"
        " (mLO) count them, sw-ph leaves them out; truth/distance in the log holds"
        " the sole's height"
    )


KINEMATIC_MARGIN = 0.02  # F1 by which the kinematic detector must win for the note below


# True touch-downs a log needs before the note below is drawn (a 2-step or 0.5 s log's F1
# says nothing about the parameters).
KINEMATIC_MIN_EVENTS = 20


def weaker_than_kinematic(scores: dict) -> str | None:
    """A note when the kinematic detector (foot height alone) beats the estimator's F1 by
    more than :data:`KINEMATIC_MARGIN` on a log of at least :data:`KINEMATIC_MIN_EVENTS`
    true touch-downs: its parameters do not fit this robot or
    its sensors (a light robot's loads sit near the torque noise), which tuning addresses."""
    est, kin = scores.get("probabilistic"), scores.get("kinematic")
    if not est or not kin or not kin["f1"] > est["f1"] + KINEMATIC_MARGIN:
        return None
    if est.get("n_touchdowns", 0) < KINEMATIC_MIN_EVENTS:
        return None
    return (
        f"note: the kinematic detector's F1 ({kin['f1']:.3f}) beats the estimator's"
        f" ({est['f1']:.3f}): its parameters do not fit this robot or sensor model; tune them"
        " on logs with ground truth (jax-contact tune; docs/own_robot.md, 'A light robot')"
    )


def _vs_probabilistic(
    out, scores, truth, valid, dt: float, n_resamples: int, *, truth_known=None
) -> dict:
    """``probabilistic - row`` for every other scored row, with its env-bootstrap interval;
    printed, one line per row (``valid`` and ``truth_known`` as :func:`scored_steps`')."""
    from jax_contact.bootstrap import STATISTICS, format_intervals, row_differences
    from jax_contact.train.evaluate import is_flag

    print(
        f"probabilistic - row, 95 % interval of a paired bootstrap of {n_resamples} env resamples:"
    )
    # A flag's ECE is 1 - accuracy: compared as calibration it would only restate accuracy.
    others = {
        row: tuple(s for s in STATISTICS if not (s == "ece" and is_flag(out[row])))
        for row in scores
        if row != "probabilistic"
    }
    vs = row_differences(
        out, "probabilistic", others, truth, valid, dt=dt, n_resamples=n_resamples,
        truth_known=truth_known,
    )  # fmt: skip
    for row, stats in vs.items():
        print(f"  vs {row:18s} {format_intervals(stats)}")
    return vs


def _plain(x):
    """``json.dumps``'s default for NumPy scalars and arrays."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x).__name__)
