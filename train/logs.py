"""Simulated logs on disk: ``jax-contact simulate`` writes them, ``jax-contact evaluate`` reads.

The schema is documented in :mod:`jax_contact.io`. Evaluating a log recomputes the
estimator's inputs from the stored readings with the robot's nominal model, exactly as on
a recorded robot log.
"""

from __future__ import annotations

import dataclasses
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jax_contact.io import read_log, read_log_attrs, write_log
from jax_contact.robot import model_fingerprint
from jax_contact.train.cli_args import check_log_size


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
    # The readings (float32 qpos, qvel, qacc, tau) and per-foot truth (a flag, the normal
    # force and the sole's height) alone, before the physics compiles.
    m, n_legs = loaded.mj_model, loaded.description.n_legs
    check_log_size(n_envs, duration, 4 * (m.nq + 3 * m.nv) + 9 * n_legs, robot=robot)
    # The rough floor of the log's own seed: tuning and evaluation seeds walk other ground.
    world = build_world(loaded, terrain=terrain, roughness=roughness, terrain_seed=seed)
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
    gait_params = make_gait(gait)
    roll = simulate(world, gait_params, noise, n_envs, duration, seed, speed_range=speeds)
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
    # Judged on a log of a full cycle after the ramp (a 0.3 s walk has no swing yet).
    full_cycle = duration >= float(gait_params.ramp_time) + float(gait_params.period)
    names = loaded.description.foot_names
    still = feet_that_never_lift(roll.distance, roll.valid, names) if full_cycle else {}
    if still:
        print(
            f"warning: feet that never lifted more than {LIFT_M * 1e3:g} mm in this {gait} log"
            f" (their highest sole, mm): {still}: the gait did not move them, so the log has"
            " no swing of theirs to score; check the model's joint ranges and angle unit"
            ' (<compiler angle="radian"/> for ranges in radians) and the gait settings'
        )
    return path


# A foot whose sole never rises this far above the floor in a gait log never swung, m.
LIFT_M = 0.005


def feet_that_never_lift(distance, valid, names) -> dict[str, float]:
    """Feet whose sole stays within :data:`LIFT_M` of the floor on every valid step of
    every env (a user's model whose knee range was in degrees read as radians: a "trot"
    whose largest gap was 0.4 mm, and no word), with their highest sole, mm.

    Args:
      distance: (T, n_envs, n_legs) the sole's height above the floor, m.
      valid: (T, n_envs) steps before a fall.
      names: the feet's names.
    """
    d = np.where(np.asarray(valid, bool)[..., None], np.asarray(distance, float), -np.inf)
    top = d.max(axis=(0, 1))
    return {
        n: round(float(h) * 1e3, 1)
        for n, h in zip(names, top, strict=True)
        if np.isfinite(h) and h < LIFT_M
    }


# Feet whose soles differ in height by more than this at the home pose, m: one of them is
# likely not a foot (a shin sphere the rule found where the foot geom is missing).
FOOT_HEIGHT_SPREAD_M = 0.03


def note_found_feet(robot) -> str:
    """The ``note:`` line naming the feet the model's rule found (``simulate`` and
    ``estimate`` without ``--feet``), with a warning when their soles' heights at the home
    pose (the model's ``home`` keyframe, else its first, else ``qpos0``) spread over more than
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
    # A foot found as one sphere whose body carries more (a heel sphere above a toe
    # sphere at the home pose) is one sole when named by its body, as the wrapper names it.
    from jax_contact.robot import floor_spheres

    spheres = floor_spheres(m)[1]
    several = {
        m.body(b).name: n
        for b, g, sole in zip(desc.foot_body_ids, desc.foot_geom_ids, desc.soles, strict=True)
        if g in spheres
        and not sole  # one sphere, not a sole of several
        and (n := sum(int(m.geom_bodyid[s]) == b for s in spheres)) > 1
        and m.body(b).name
    }
    if several:
        bodies = ", ".join(f"{b} ({n})" for b, n in several.items())
        line += (
            f"\nnote: the feet's bodies carry several floor-touching spheres ({bodies}): each"
            f" foot above is one of them; --feet {' '.join(several)} reads each body's"
            " spheres as one sole"
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
    if zeroed := degenerate_quaternions_lost(name, readings["qpos"], valid, robot.mj_model):
        print(zeroed, file=sys.stderr)
    if note := non_finite_note(name, readings, valid, zeroed_quaternions=zeroed is not None):
        print(note, file=sys.stderr)
    return LoadedLog(name, robot, readings, truth, valid, dt, attrs, lost=note is not None)


def degenerate_quaternions_lost(name: str, qpos: np.ndarray, valid: np.ndarray, mj_model):
    """Sets, in place, every joint quaternion of ``qpos`` ((T, E, nq)) whose norm is below
    :data:`jax_contact.export.MIN_QUATERNION_NORM` (no orientation: a driver's zero fill)
    to NaN, a lost reading, as the exported estimator and ``estimate`` read it; returns a
    note naming them on valid steps, else None. (A log's replay read the zeros as an
    orientation, and deploy-check's offline reference disagreed with the exported file by
    up to 0.99 in P.)"""
    from jax_contact.export import MIN_QUATERNION_NORM
    from jax_contact.train.recording_checks import lose_degenerate_quaternions

    counts = []
    for a, bad in lose_degenerate_quaternions(qpos, mj_model).items():
        if n := int((bad & valid).sum()):
            counts.append(f"qpos[{a}:{a + 4}] on {n}")
    if not counts:
        return None
    return (
        f"note: {name}: quaternions (the base's, a ball joint's) with a norm below"
        f" {MIN_QUATERNION_NORM:g} (no orientation), read as lost readings (NaN):"
        f" {', '.join(counts)} step-env rows"
    )


def non_finite_note(
    name: str, readings: dict, valid: np.ndarray, zeroed_quaternions: bool = False
) -> str | None:
    """A note naming the readings arrays that hold a NaN or inf on valid steps, with the
    number of (step, env) rows each: the estimator skips those steps on the feet whose
    terms read the lost entry (its prediction alone, ``valid`` False in its diagnostics),
    and the metrics leave those foot-steps out (:func:`scored_steps`).
    ``zeroed_quaternions``: :func:`degenerate_quaternions_lost` set some to NaN, so the
    note calls the entries lost, not "not finite" (the file held zeros there)."""
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
    what = "lost (not finite, or the quaternions above)" if zeroed_quaternions else "not finite"
    return (
        f"note: {name}: readings that are {what} on valid steps ({listed}, of {total}"
        " step-env rows): the feet whose terms read them get the estimator's prediction"
        " alone there, and those foot-steps are left out of the metrics"
    )


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


# The sensor model of a log that does not name one: the reproduction's.
DEFAULT_LOG_NOISE = "anymal_like"


def log_noise(attrs) -> str:
    """A log's sensor model: ``simulate``'s ``noise`` attribute, else
    :data:`DEFAULT_LOG_NOISE`. The estimator's defaults for the log are derived with it
    (``evaluate``, ``tune``), as the reproduction's are with its own."""
    return str(attrs.get("noise", DEFAULT_LOG_NOISE))


def log_setup(path: str | Path) -> tuple[str, float, str | None]:
    """(robot name, period s, physics fingerprint or None) of a log, from its attributes
    alone: logs checked against each other before any is loaded (a ValueError or
    FileNotFoundError as :func:`load_log`'s)."""
    attrs = read_log_attrs(path)
    robot, dt = _log_attrs(f"log {str(path)!r}", attrs)
    return robot, dt, attrs.get("model_sha256")


def _log_attrs(name: str, attrs: dict) -> tuple[str, float]:
    """The robot name and the period of a log, or a ValueError naming the attribute."""
    robot = attrs.get("robot")
    if robot is None and "recording" in attrs and "terms" in attrs:
        raise ValueError(
            f"{name} is an output of `jax-contact estimate` (estimates of the recording"
            f" {attrs['recording']!r}), not a log of `jax-contact simulate`"
        )
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
