"""Simulated logs on disk: ``jax-contact simulate`` writes them, ``jax-contact evaluate`` reads.

The schema is documented in :mod:`jax_contact.io`. Evaluating a log recomputes the
estimator's inputs from the stored readings with the robot's nominal model, exactly as on
a recorded robot log.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jax_contact.io import read_log, write_json_atomic, write_log
from jax_contact.metrics import bounce_counts, bounce_steps
from jax_contact.robot import model_fingerprint, model_mass


def simulate_to_file(
    path: str | Path,
    *,
    robot: str = "go1",
    gait: str = "trot",
    noise: str = "anymal_like",
    terrain: str = "flat",
    n_envs: int = 16,
    duration: float = 10.0,
    seed: int = 0,
    roughness: float = 0.015,
    foot_names: Sequence[str] | None = None,
    gait_settings=None,
) -> Path:
    """Simulates and writes an HDF5 log (atomically). Returns the path.

    Args:
      robot: a robot name or an MJCF path (:func:`jax_contact.envs.robots.load_robot`).
      foot_names: the feet, geom or body names in leg order (None: found in the model);
        stored in the log (``foot_names``), which :func:`evaluate_file` replays with.
      gait_settings: an :class:`jax_contact.envs.gaits.GaitSettings`, or a mapping of fields that
        override the robot's (e.g. ``{"kp": 80.0, "home_key": "home"}``); None: the
        robot's own. Resolved, they are stored as the attribute ``gait_settings`` (JSON),
        and their speed range for ``gait`` is what the envs' speed commands are drawn from.
    """
    from jax_contact.envs.gaits import GaitSettings, make_gait
    from jax_contact.envs.gaits import gait_settings as settings_of
    from jax_contact.envs.robots import ROBOT_NAMES, load_robot
    from jax_contact.envs.simulate import build_world, simulate

    path = Path(path)
    if path.suffix not in (".h5", ".hdf5"):
        raise ValueError(f"output {str(path)!r} must end in .h5 or .hdf5")
    if gait_settings is None or isinstance(gait_settings, GaitSettings):
        settings = gait_settings
    else:
        settings = settings_of(robot, **dict(gait_settings))
    loaded = load_robot(robot, foot_names=foot_names, gait=settings)
    world = build_world(loaded, terrain=terrain, roughness=roughness)
    resolved = world.robot.gait_settings
    speeds = resolved.speed_range(gait)
    attrs = {
        # An MJCF path as an absolute path: the log is then read from any folder, and two
        # spellings of one file are one robot.
        "robot": robot if robot in ROBOT_NAMES else str(Path(robot).expanduser().resolve()),
        "gait": gait,
        "noise": noise,
        "terrain": terrain,
        "roughness": world.roughness,
        "seed": seed,
        "dt": world.dt,
        "rate_hz": 1.0 / world.dt,
        "n_envs": n_envs,
        # The nominal robot's names, which load_log resolves: the simulated world renames
        # unnamed foot geoms (Barkour's) gt_foot<i> when it adds its ground-truth geoms.
        "foot_names": list(loaded.description.foot_names),
        "gait_settings": dataclasses.asdict(resolved),
        "reading_timing": READING_TIMING,
        # The nominal model's physics (load_log warns when the robot loads differently).
        "model_sha256": model_fingerprint(loaded.mj_model),
    }
    if foot_names is None:
        print(note_found_feet(loaded))
    if abs(loaded.mj_model.opt.timestep - world.dt) > 1e-12:
        print(
            f"note: the model's timestep {loaded.mj_model.opt.timestep:g} s is replaced by"
            f" {world.dt:g} s: the physics runs at the estimator's rate, one reading per step"
        )
    roll = simulate(world, make_gait(gait), noise, n_envs, duration, seed, speed_range=speeds)
    write_log(path, roll.to_arrays(), attrs)
    n_valid = int(roll.valid[-1].sum())
    print(
        f"wrote {path}: {roll.qpos.shape[0]} steps x {n_envs} envs ({n_valid} upright at the end)"
    )
    if 2 * n_valid < n_envs:
        print(
            f"warning: {n_envs - n_valid} of {n_envs} robots fell (their steps from the fall"
            " on are invalid, not scored): check the gait settings (--kp, --kd, --base-height,"
            " --home-key) and that --feet names every foot"
        )
    return path


# Feet whose soles differ in height by more than this at the home pose, m: one of them is
# likely not a foot (a shin sphere the rule found where the foot geom is missing).
FOOT_HEIGHT_SPREAD_M = 0.03


def note_found_feet(robot) -> str:
    """The ``note:`` line naming the feet the model's rule found (``simulate`` without
    ``--feet``), with a warning when their soles' heights at the home pose (the model's
    ``home`` keyframe, else its first, else ``qpos0``) spread over more than
    :data:`FOOT_HEIGHT_SPREAD_M`: a user trial's Go2 with one foot geom deleted walked on
    that leg's shin sphere, and only a lower score said so."""
    from jax_contact.envs.feet import foot_points_np, home_data

    m, desc = robot.mj_model, robot.description
    z = foot_points_np(m, home_data(m), desc)[:, 2] - np.asarray(desc.foot_radii)
    soles = dict(zip(desc.foot_names, z.tolist(), strict=True))
    line = f"note: feet found in the model: {list(soles)} (name them with --feet)"
    low = min(soles.values())
    high = {n: z - low for n, z in soles.items() if z - low > FOOT_HEIGHT_SPREAD_M}
    if high:
        above = ", ".join(f"{n} {1e3 * dz:.0f} mm" for n, dz in high.items())
        line += (
            f"\nwarning: at the home pose some soles are above the lowest ({above}): is each"
            " a foot? (a leg without its foot geom walks on the lowest sphere left, e.g. a"
            " shin's); name the feet with --feet"
        )
    return line


READINGS = ("readings/qpos", "readings/qvel", "readings/qacc", "readings/tau")
# Reading k is taken at the end of physics step k (jax_contact.train.evaluate's module docstring).
# `jax-contact simulate` wrote its logs before this convention with reading k taken at the
# start of step k (state q_k, torque tau_k, acceleration over step k - 1) and without the
# `reading_timing` attribute; see reading_timing_of.
READING_TIMING = "end_of_step"
_OLD_TIMING = "start_of_step"
_SIMULATE_ATTRS = ("gait", "noise", "seed")  # what marks a log of `jax-contact simulate`


def reading_timing_of(name: str, attrs: dict) -> str:
    """The timing convention of a log's readings: its ``reading_timing`` attribute; without
    one, ``"start_of_step"`` for a log of an older ``jax-contact simulate`` (it has the
    ``gait``, ``noise`` and ``seed`` attributes), else the current convention (a log the
    user wrote, documented in :mod:`jax_contact.io`). ValueError for an unknown value."""
    timing = attrs.get("reading_timing")
    if timing is None:
        old = all(k in attrs for k in _SIMULATE_ATTRS)
        return _OLD_TIMING if old else READING_TIMING
    if timing not in (READING_TIMING, _OLD_TIMING):
        raise ValueError(
            f"{name}: attribute 'reading_timing' is {timing!r}; expected {READING_TIMING!r}"
            f" or {_OLD_TIMING!r}"
        )
    return str(timing)


TRUTH_CONTACT = "truth/contact"


@dataclasses.dataclass(frozen=True, eq=False)
class LoadedLog:
    """A log read and checked, with the robot it was made with.

    Attributes:
      name: ``log '<path>'``, for messages.
      robot: the robot of the log's ``robot`` attribute with the feet it stores.
      readings: ``qpos`` (T, E, nq), ``qvel``, ``qacc``, ``tau`` (T, E, nv), end-of-step.
      truth: (T, E, L) bool ground-truth contact, or None.
      valid: (T, E) bool.
      dt: the readings' period, s.
      attrs: the log's attributes.
      lost: a reading is not finite on a valid step (:func:`non_finite_note`, printed
        when the log is loaded).
    """

    name: str
    robot: object
    readings: dict
    truth: np.ndarray | None
    valid: np.ndarray
    dt: float
    attrs: dict
    lost: bool = False


def load_log(
    path: str | Path,
    *,
    foot_names: Sequence[str] | None = None,
    robot: str | None = None,
) -> LoadedLog:
    """Reads a log of :func:`simulate_to_file` and loads its robot with its feet.

    Args:
      foot_names: the feet to use; None takes the log's ``foot_names`` attribute (the feet
        it was simulated with), else the model's own.
      robot: the robot to load instead of the one the log names (a name or an MJCF path:
        the model moved, or the log came from another machine); its physics fingerprint is
        checked against the log's as for the named one.

    Raises:
      FileNotFoundError, ValueError: as :func:`evaluate_file`.
    """
    from jax_contact.envs.robots import ROBOT_NAMES, load_robot

    arrays, attrs = read_log(path)
    name = f"log {str(path)!r}"
    robot_name, dt = _log_attrs(name, attrs)
    robot_name = robot or robot_name
    readings, truth, valid = _log_arrays(name, arrays)
    if reading_timing_of(name, attrs) == _OLD_TIMING:
        print(
            f"{name} has readings taken at the start of each step (an older jax-contact"
            f" simulate): re-aligned to {READING_TIMING!r}, one step shorter",
            file=sys.stderr,
        )
        readings, truth, valid = to_end_of_step(readings, truth, valid)
    feet = foot_names if foot_names is not None else attrs.get("foot_names") or None
    try:
        loaded = load_robot(robot_name, foot_names=feet)
    except ValueError as err:
        hint = "; if its model moved, name it with --robot (evaluate)"
        if robot and foot_names is None and feet:
            hint = (
                f"; the log's feet {list(feet)} are those of the robot it names,"
                f" {attrs.get('robot')!r}: is the log another robot's? (--feet names"
                f" the feet of {robot_name!r})"
            )
        elif robot:
            hint = ""
        raise ValueError(f"{name}: robot {robot_name!r}: {err}{hint}") from None
    robot, desc = loaded, loaded.description
    stored = attrs.get("model_sha256")
    if stored and stored != model_fingerprint(robot.mj_model):
        logged = attrs.get("robot")
        if robot_name in ROBOT_NAMES and logged in ROBOT_NAMES and logged != robot_name:
            # Two shipped robots: not a moved model but another robot (a user trial read
            # Go1's log through Go2 and was shown F1 0.26 with a warning).
            raise ValueError(
                f"{name} was simulated with robot {logged!r}; robot {robot_name!r} is another"
                f" model (its physics' fingerprint differs): evaluate it with --robot {logged}"
                " or without --robot"
            )
        warnings.warn(
            f"{name}: robot {robot_name!r} loads today as a model that differs from the one"
            f" the log was simulated with ({logged!r}; its physics' fingerprint,"
            " model_sha256): the replay reads these readings through another model",
            stacklevel=2,
        )
    for key, size, what in (
        ("qpos", desc.nq, "nq"),
        ("qvel", desc.nv, "nv"),
        ("qacc", desc.nv, "nv"),
        ("tau", desc.nv, "nv"),
    ):
        if readings[key].shape[-1] != size:
            raise ValueError(
                f"{name}: array 'readings/{key}' has {readings[key].shape[-1]} columns but"
                f" robot {robot_name!r} has {what} = {size}"
            )
    if truth is not None and truth.shape[-1] != desc.n_legs:
        whose = (
            f"--feet names {desc.n_legs} ({', '.join(foot_names)}); the log's feet are"
            f" {list(attrs.get('foot_names') or [])}"
            if foot_names is not None
            else f"robot {robot_name!r} has {desc.n_legs}"
        )
        raise ValueError(f"{name}: array {TRUTH_CONTACT!r} has {truth.shape[-1]} feet but {whose}")
    if note := non_finite_note(name, readings, valid):
        print(note, file=sys.stderr)
    return LoadedLog(name, robot, readings, truth, valid, dt, attrs, lost=note is not None)


def non_finite_note(name: str, readings: dict, valid: np.ndarray) -> str | None:
    """A note naming the readings arrays that hold a NaN or inf on valid steps, with the
    number of (step, env) rows each: the estimator skips those steps on the feet whose
    terms read the lost entry (its prediction alone, ``valid`` False in its diagnostics),
    and the metrics leave those foot-steps out (:func:`scored_steps`)."""
    counts = {
        key: int((~np.isfinite(a).all(axis=-1) & valid).sum())
        for key, a in readings.items()
        if np.issubdtype(a.dtype, np.floating)
    }
    bad = {k: n for k, n in counts.items() if n}
    if not bad:
        return None
    total = int(valid.sum())
    listed = ", ".join(f"readings/{k} {n}" for k, n in bad.items())
    return (
        f"note: {name}: readings that are not finite on valid steps ({listed}, of {total}"
        " step-env rows): the feet whose terms read them get the estimator's prediction"
        " alone there, and those foot-steps are left out of the metrics"
    )


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


# The estimator's terrain model for logs (``--terrain-model``): ``flat``, a plane at z = 0 of
# the log's world frame; ``memory``, the height where each foot last stood (its stance
# average) over that plane (docs/model_choices.md, "Base drift and the kinematics term").
TERRAIN_MODELS = ("flat", "memory")
# sigma at the foothold (m), its growth per metre walked, the stance average's weight.
FOOTHOLD_MEMORY = dict(sigma_foothold=0.02, growth=0.3, smoothing=0.05)


def default_estimator(desc, dt: float, terrain_model: str = "flat", *, mj_model=None):
    """(EstimatorParams, terrain) that ``evaluate``, ``estimate`` and ``export`` use for a
    robot: the planar leg's Section III estimator for one 2-joint leg on a 1-dof rail, else Table
    III's (the one source: :func:`jax_contact.params_for` with ``anymal_like`` sensors,
    ``jax_contact.train.reproduce``). Legs of fewer than three joints on a floating base
    (a biped's, Brax's ant's) resist the force axes their Jacobian spans
    (:func:`jax_contact.envs.contact_params.choose_force_rows`, which needs ``mj_model``).
    ``terrain_model`` (:data:`TERRAIN_MODELS`): ``"flat"`` the plane of the reproduction,
    ``"memory"`` a :func:`jax_contact.foothold_memory` over it with :data:`FOOTHOLD_MEMORY`,
    for base positions that drift.

    Raises:
      ValueError: an unknown terrain model, or legs of fewer than three joints (not the
        planar leg's) without ``mj_model``.
    """
    import jax_contact as jc
    from jax_contact.train.reproduce import (
        TERRAIN_SIGMA,
        planar_estimator_params,
        quadruped_estimator_params,
    )

    check_terrain_model(terrain_model)
    if desc.n_leg_dofs == 2 and desc.n_legs == 1 and len(desc.base_dofs) == 1 and desc.nv == 3:
        params, plane = planar_estimator_params(desc.nv, dt), jc.flat(0.0, 0.2)
    elif desc.n_leg_dofs < 3:
        if mj_model is None:
            raise ValueError(
                f"legs of {desc.n_leg_dofs} joints: their force axes are chosen from the"
                " robot's model (pass mj_model)"
            )
        from jax_contact.envs.contact_params import choose_force_rows

        rows = choose_force_rows(mj_model, desc)
        params = quadruped_estimator_params(desc, dt, force_rows=rows)
        plane = jc.flat(0.0, TERRAIN_SIGMA)
    else:
        params, plane = quadruped_estimator_params(desc, dt), jc.flat(0.0, TERRAIN_SIGMA)
    return params, terrain_for(plane, terrain_model)


def check_terrain_model(terrain_model: str) -> None:
    """Raises ValueError unless ``terrain_model`` is one of :data:`TERRAIN_MODELS`."""
    if terrain_model not in TERRAIN_MODELS:
        raise ValueError(f"terrain_model must be one of {TERRAIN_MODELS}, got {terrain_model!r}")


def terrain_for(plane, terrain_model: str):
    """The estimator's terrain of ``terrain_model`` over ``plane``: the plane itself
    (``"flat"``), or a :func:`jax_contact.foothold_memory` over it with
    :data:`FOOTHOLD_MEMORY` (``"memory"``)."""
    import jax_contact as jc

    check_terrain_model(terrain_model)
    if terrain_model == "memory":
        return jc.foothold_memory(plane, **FOOTHOLD_MEMORY)
    return plane


def file_terrain_model(path) -> str | None:
    """The terrain model a parameter file (or preset name) was tuned with
    (``provenance["terrain_model"]`` of ``jax-contact tune``), or None when it does not say
    (files written before the option: tuned on the plane)."""
    from jax_contact.params_file import load_params

    _, prov = load_params(path, with_provenance=True)
    return _terrain_model_in(prov, path)


def _terrain_model_in(provenance: dict, path) -> str | None:
    """``provenance["terrain_model"]`` of the file ``path``, checked, or None."""
    model = provenance.get("terrain_model")
    if model is not None and model not in TERRAIN_MODELS:
        raise ValueError(
            f"parameter file {str(path)!r}: provenance field 'terrain_model' must be one of"
            f" {TERRAIN_MODELS}, got {model!r}"
        )
    return model


def resolve_terrain_model(
    terrain_model: str | None, params_path, provenance: dict | None = None
) -> str:
    """``--terrain-model`` as given, else the parameter file's own
    (:func:`file_terrain_model`), else ``"flat"``: parameters tuned with a foothold memory
    are run with it unless the user says otherwise. ``provenance``: the file's, when the
    caller has read it already (the file is then not read again)."""
    if terrain_model is not None:
        check_terrain_model(terrain_model)
        return terrain_model
    if params_path is not None:
        if provenance is not None:
            return _terrain_model_in(provenance, params_path) or "flat"
        return file_terrain_model(params_path) or "flat"
    return "flat"


def tune_gm(path: str | Path) -> tuple[str, object, dict]:
    """The GM observer setting of ``jax_contact.train.reproduce``'s grid with the best F1 on a log.

    Runs every grid point (:func:`jax_contact.train.reproduce.gm_grid`) on the log and picks one
    with
    :func:`jax_contact.train.reproduce.best_gm` (best per-step F1, ties: fewer failures), the rule
    the reproduction tunes by.

    Returns:
      (grid name, e.g. ``"gm_K50_F15"``, its GMParams, grid name -> scores).

    Raises:
      ValueError: the log has no ground truth, or as :func:`load_log`.
    """
    import jax_contact as jc
    from jax_contact.train.evaluate import replay, score
    from jax_contact.train.reproduce import TERRAIN_SIGMA, best_gm, gm_grid

    log = load_log(path)
    if log.truth is None:
        raise ValueError(f"{log.name} has no ground truth ({TRUTH_CONTACT!r}): cannot tune on it")
    grid = gm_grid()
    out = replay(
        log.robot,
        log.readings,
        estimators={},
        terrain=jc.flat(0.0, TERRAIN_SIGMA),
        gms=grid,
        dt=log.dt,
    )
    scores = score(out, log.truth, log.valid, dt=log.dt, names=list(grid))
    best = best_gm(scores)
    return best, grid[best], scores


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
) -> dict:
    """Runs the estimator, GM observer and kinematic detector on a log; prints the metrics.

    The log is replayed with the robot and feet it was made with (its ``foot_names``
    attribute) unless ``foot_names`` is given. Every detector's full metric set is printed
    as one table with a header and a legend (``jax_contact.train.report.format_table``):
    touch-down and lift-off delays, F1, accuracy, failures, per-air-phase failure rate, missed
    touch-downs and lift-offs, ECE. A parameter file that holds a calibration map
    (``jax-contact tune --calibrate``, the shipped presets) adds the row
    ``probabilistic+cal``: the estimator's P(contact) mapped by it
    (:func:`jax_contact.tune.calibrate_probability`), flagged at calibrated P > 0.5. With a
    parameter file the robot's default parameters run too, as the row ``defaults`` (same
    terrain model), so a tuned file is seen beside what it was tuned from.

    With ``bootstrap`` > 0 (and ground truth) every other row is compared with
    ``probabilistic`` by a paired bootstrap of that many env resamples
    (:func:`jax_contact.bootstrap.paired_bootstrap`, 95 %, seed 0): ``probabilistic - row``
    of F1, accuracy, air-phase failures, ``|mean|`` delays and ECE, each called better,
    worse or within noise (the log needs at least 2 envs).

    A log without ground truth (no ``truth/contact``, e.g. one recorded on a robot) has no
    metrics: the estimator's P(contact) per foot is then printed as a mean per foot and,
    with ``json_path``, written per step and env under ``"p_contact"``.

    Args:
      json_path: write the result as JSON here.
      gm_grid_log: tune the GM observer on this other log (:func:`tune_gm`) instead of
        using the default setting (``make_gm_params()``).
      params_path: estimator parameters (:func:`jax_contact.load_params`) instead of the
        robot's defaults (:func:`default_estimator`).
      foot_names: the feet, overriding the log's.
      robot: the robot, overriding the one the log names (:func:`load_log`).
      terrain_model: the estimator's terrain model, one of :data:`TERRAIN_MODELS`
        (:func:`default_estimator`); None: the one ``params_path`` was tuned with, else
        ``"flat"`` (:func:`resolve_terrain_model`).
      bootstrap: env resamples of the comparison with ``probabilistic``; 0: none.
      plots_dir: write the reliability diagram of every scored row
        (:func:`jax_contact.train.calibration.reliability_diagram`, ECE in the legend) to
        ``plots_dir/reliability_<log stem>.png``; without ground truth nothing is drawn
        (a line says so).

    Returns:
      ``log``, ``attrs``, ``scores`` (detector -> metrics; empty without ground truth),
      ``vs_probabilistic`` (row -> statistic -> ``[delta, low, high, verdict]``, with
      ``bootstrap``),
      ``has_truth``, ``foot_names``, ``gm`` (the GM setting used), ``outputs`` (the
      replay's (T, E, L) arrays, not written to the JSON) and ``p_contact`` (foot -> (T, E)
      nested lists) when the log has no ground truth.

    Raises:
      FileNotFoundError: no such file.
      ValueError: one line naming the file, the field and what was expected: unreadable
        file, a missing attribute or array, an array of the wrong shape, a robot whose
        model does not fit the readings.
    """
    from jax_contact.baselines import make_gm_params, make_kinematic_params
    from jax_contact.train.evaluate import replay, score

    log = load_log(path, foot_names=foot_names, robot=robot)
    name, truth, desc, dt = log.name, log.truth, log.robot.description, log.dt
    mass = model_mass(log.robot.mj_model)
    params, terrain_model, terrain, calibration = estimator_for(
        desc, dt, params_path, terrain_model, mass, mj_model=log.robot.mj_model,
        robot=log.robot.name,
    )  # fmt: skip
    if bootstrap and truth is not None and truth.shape[1] < 2:
        raise ValueError(
            f"{name} has {truth.shape[1]} env: the bootstrap resamples envs and needs at least 2"
        )
    estimators = {"probabilistic": params}
    if params_path is not None:
        estimators["defaults"] = default_estimator(
            desc, dt, terrain_model, mj_model=log.robot.mj_model
        )[0]
    gm_name, gm = "gm", make_gm_params()
    if gm_grid_log is not None and truth is not None:
        gm_name, gm, _ = tune_gm(gm_grid_log)
        print(f"GM observer tuned on {str(gm_grid_log)!r}: {gm_name} (best F1 of the grid)")
    out = replay(
        log.robot,
        log.readings,
        estimators=estimators,
        terrain=terrain,
        # Without ground truth only the estimator's P(contact) is reported.
        gms={gm_name: gm} if truth is not None else None,
        kinematic=make_kinematic_params() if truth is not None else None,
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
    result = {
        "log": str(path),
        "params": {"source": "defaults"}
        if params_path is None
        else params_file_provenance(params_path),
        "terrain_model": terrain_model,
        "attrs": log.attrs,
        "has_truth": truth is not None,
        "foot_names": feet,
        "gm": {"name": gm_name, "K_I": float(gm.K_I), "threshold": float(gm.threshold)},
    }
    if truth is None:
        p = np.asarray(out["probabilistic"])  # (T, E, L)
        means = "  ".join(f"{f} {np.nanmean(p[..., i]):.3f}" for i, f in enumerate(feet))
        print(
            f"{name} has no ground truth ({TRUTH_CONTACT!r}): no metrics can be computed."
            f"\nmean P(contact) per foot over {p.shape[0]} steps x {p.shape[1]} envs: {means}"
        )
        print(
            f"P(contact) per foot, step and env written to {json_path}"
            if json_path
            else "pass --json FILE to write P(contact) per foot, step and env"
        )
        if bootstrap:
            print("--bootstrap: no ground truth, so there is nothing to compare")
        if plots_dir is not None:
            print("--plots: no ground truth, so no reliability diagram")
        result["scores"] = {}
        result["p_contact"] = {f: p[..., i] for i, f in enumerate(feet)}
    else:
        scored, known = scored_steps(out, truth, log.valid)
        scores = score(out, truth, scored, dt=dt, truth_known=known)
        print(format_scores(scores, title=Path(path).name))
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
            print(f"wrote {png}")
            result["plots"] = [str(png)]
    if json_path:
        written = write_json_atomic(json_path, json.loads(json.dumps(result, default=_plain)))
        if truth is not None:  # without truth the line above says where P(contact) went
            print(f"wrote {written}")
    result["outputs"] = out  # not in the JSON: (T, E, L) arrays of every detector
    return result


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


def params_file_provenance(params_path: str | Path) -> dict:
    """Where a parameter file or shipped preset came from (its resolved path, or the
    preset's name), its SHA-256 and its own ``provenance``: what ``evaluate --json`` and
    ``export`` record of the ``--params`` they ran."""
    import hashlib

    from jax_contact._presets import preset_file

    if (ref := preset_file(str(params_path))) is not None:
        raw = ref.read_bytes()
        where = {"source": "preset", "name": str(params_path)}
    else:
        raw = Path(params_path).read_bytes()
        where = {"source": "file", "path": str(Path(params_path).resolve())}
    return {
        **where,
        "sha256": hashlib.sha256(raw).hexdigest(),
        "file_provenance": json.loads(raw).get("provenance", {}),
    }


def _vs_probabilistic(
    out, scores, truth, valid, dt: float, n_resamples: int, *, truth_known=None
) -> dict:
    """``probabilistic - row`` for every other scored row, with its env-bootstrap interval;
    printed, one line per row (``valid`` and ``truth_known`` as :func:`scored_steps`')."""
    from jax_contact.bootstrap import STATISTICS, format_intervals, row_differences

    print(
        f"probabilistic - row, 95 % interval of a paired bootstrap of {n_resamples} env resamples:"
    )
    others = {row: tuple(STATISTICS) for row in scores if row != "probabilistic"}
    vs = row_differences(
        out, "probabilistic", others, truth, valid, dt=dt, n_resamples=n_resamples,
        truth_known=truth_known,
    )  # fmt: skip
    for row, stats in vs.items():
        print(f"  vs {row:18s} {format_intervals(stats)}")
    return vs


def estimator_for(
    desc,
    dt: float,
    params_path,
    terrain_model: str | None,
    mass_kg=None,
    *,
    mj_model=None,
    period: str = "the log's",
    robot: str | None = None,
):
    """(params, terrain model, terrain, calibration map or None) of ``evaluate`` and
    ``estimate``: the defaults (:func:`default_estimator`) or ``params_path`` checked
    against the robot (``robot``: the name it was loaded by) and period, with the file's
    calibration map, on the terrain model
    given, else the file's own (:func:`resolve_terrain_model`), which is then printed.
    The file is read once; ``period`` names ``dt`` in the warning of a file of another
    period (e.g. ``"the export's"``)."""
    from jax_contact.calibration import file_calibration

    provenance, calibration = None, None
    if params_path is not None:
        file_params, provenance = load_params_for(
            params_path, desc, dt, mass_kg, with_provenance=True, mj_model=mj_model,
            period=period, robot=robot,
        )  # fmt: skip
        calibration = file_calibration(provenance, params_path)
    model = resolve_terrain_model(terrain_model, params_path, provenance)
    if terrain_model is None and model != "flat":
        print(f"terrain model {model!r}: the one {str(params_path)!r} was tuned with")
    params, terrain = default_estimator(desc, dt, model, mj_model=mj_model)
    if params_path is not None:
        params = file_params
    return params, model, terrain, calibration


def load_params_for(
    path,
    desc,
    dt,
    mass_kg=None,
    *,
    with_provenance=False,
    mj_model=None,
    period="the log's",
    robot=None,
):
    """A params file, checked against the robot (its ``nv`` and, given, its mass and the
    name it was loaded by, ``robot``) and the log's period
    (:func:`jax_contact.params_file.load_params_for`; ``with_provenance`` as there; ``mj_model`` as
    :func:`default_estimator`'s, whose values move the file's period)."""
    from jax_contact.params_file import load_params_for as load
    from jax_contact.tune.space import robot_space

    derive = lambda d: default_estimator(desc, d, mj_model=mj_model)[0]  # noqa: E731
    return load(
        path,
        nv=desc.nv,
        dt=dt,
        derive=derive,
        mass_kg=mass_kg,
        with_provenance=with_provenance,
        period=period,
        robot=robot,
        groups=robot_space(desc).named_groups(),
    )


def format_scores(scores: dict[str, dict], *, title: str = "log", legend: bool = True) -> str:
    """Every detector's full metric set as one table with a header and (``legend``) the
    legend (``jax_contact.train.report.format_table``'s columns: TD / LO delays, F1,
    accuracy, failures, per-air-phase failure rate, missed touch-downs and lift-offs, ECE)."""
    from jax_contact.train.report import cell, format_table

    rows = sorted(scores, key=lambda d: (not d.startswith("probabilistic"), d == "kinematic", d))
    payload = {"scenarios": {title: {det: cell(scores[det]) for det in rows}}}
    return format_table(payload, rows=rows, legend=legend)


def to_end_of_step(readings: dict, truth: np.ndarray | None, valid: np.ndarray):
    """Start-of-step readings (old logs) re-aligned to the end-of-step convention.

    A start-of-step reading ``k`` holds ``q_k, qd_k``, the acceleration over step ``k - 1``
    and the torque of step ``k``; the end-of-step reading ``k`` is ``q_{k+1}, qd_{k+1}``,
    the acceleration over step ``k`` (the old reading ``k + 1``'s) and ``tau_k``. The truth
    of step ``k`` is unchanged; the last step is dropped (its end state was never read).
    """
    out = {k: readings[k][1:] for k in ("qpos", "qvel", "qacc")}
    out["tau"] = readings["tau"][:-1]
    ok = valid[:-1] & valid[1:]
    return out, None if truth is None else truth[:-1], ok


def _log_attrs(name: str, attrs: dict) -> tuple[str, float]:
    """The robot name and the period of a log, or a ValueError naming the attribute."""
    robot = attrs.get("robot")
    if not isinstance(robot, str) or not robot:
        raise ValueError(
            f"{name} has no attribute 'robot' (expected the robot's name, e.g. 'go1', or an"
            " MJCF path)"
            if robot is None
            else f"{name}: attribute 'robot' is {robot!r}; expected a robot name such as 'go1'"
        )
    dt = attrs.get("dt")
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        dt = None
    if dt is None or not (np.isfinite(dt) and dt > 0):
        raise ValueError(
            f"{name}: attribute 'dt' is {attrs.get('dt')!r}; expected the readings' period,"
            " a float > 0 in s"
        )
    return robot, dt


def _log_arrays(name: str, arrays: dict) -> tuple[dict, np.ndarray | None, np.ndarray]:
    """(readings, truth contact or None, valid) of a log, each shape checked."""
    missing = [k for k in READINGS if k not in arrays]
    if missing:
        raise ValueError(f"{name} is missing arrays {missing}; every log needs {list(READINGS)}")
    readings = {k.split("/")[1]: np.asarray(arrays[k]) for k in READINGS}
    qpos = readings["qpos"]
    if qpos.ndim != 3:
        raise ValueError(
            f"{name}: array 'readings/qpos' has shape {qpos.shape}; expected (T, n_envs, nq)"
            " (time, env, coordinate: a single robot's log needs an env axis of length 1)"
        )
    n_t, n_envs = qpos.shape[:2]
    for key in ("qvel", "qacc", "tau"):
        a = readings[key]
        if a.ndim != 3 or a.shape[:2] != (n_t, n_envs):
            raise ValueError(
                f"{name}: array 'readings/{key}' has shape {a.shape}; expected ({n_t},"
                f" {n_envs}, nv) like readings/qpos's (T, n_envs)"
            )
    if n_t < 2:
        raise ValueError(f"{name}: the readings have {n_t} time step(s); expected at least 2")
    truth = arrays.get(TRUTH_CONTACT)
    if truth is not None:
        truth = np.asarray(truth)
        if truth.ndim != 3 or truth.shape[:2] != (n_t, n_envs):
            raise ValueError(
                f"{name}: array {TRUTH_CONTACT!r} has shape {truth.shape}; expected ({n_t},"
                f" {n_envs}, n_feet)"
            )
        truth = truth.astype(bool)
    valid = arrays.get("valid")
    if valid is None:  # e.g. a robot's log: every step counts
        valid = np.ones((n_t, n_envs), bool)
    else:
        valid = np.asarray(valid)
        if valid.shape != (n_t, n_envs):
            raise ValueError(
                f"{name}: array 'valid' has shape {valid.shape}; expected ({n_t}, {n_envs})"
            )
        valid = valid.astype(bool)
    return readings, truth, valid


def _plain(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x).__name__)
