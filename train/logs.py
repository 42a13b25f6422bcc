"""Simulated logs on disk: ``jax-contact simulate`` writes them, ``jax-contact evaluate`` reads.

The schema is documented in :mod:`jax_contact.io`. Evaluating a log recomputes the
estimator's inputs from the stored readings with the robot's nominal model, exactly as on
a recorded robot log.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from jax_contact.io import read_log, write_json_atomic, write_log


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
) -> Path:
    """Simulates and writes an HDF5 log (atomically). Returns the path."""
    from envs.gaits import make_gait
    from envs.simulate import build_world, simulate

    path = Path(path)
    if path.suffix not in (".h5", ".hdf5"):
        raise ValueError(f"output {str(path)!r} must end in .h5 or .hdf5")
    world = build_world(robot, terrain=terrain, roughness=roughness)
    roll = simulate(world, make_gait(gait), noise, n_envs, duration, seed, speed_range=(0.0, 0.4))
    attrs = {
        "robot": robot,
        "gait": gait,
        "noise": noise,
        "terrain": terrain,
        "roughness": world.roughness,
        "seed": seed,
        "dt": world.dt,
        "rate_hz": 1.0 / world.dt,
        "n_envs": n_envs,
        "foot_names": list(world.robot.description.foot_names),
        "reading_timing": READING_TIMING,
    }
    write_log(path, roll.to_arrays(), attrs)
    n_valid = int(roll.valid[-1].sum())
    print(
        f"wrote {path}: {roll.qpos.shape[0]} steps x {n_envs} envs ({n_valid} upright at the end)"
    )
    return path


READINGS = ("readings/qpos", "readings/qvel", "readings/qacc", "readings/tau")
# Reading k is taken at the end of physics step k (train.evaluate's module docstring). Logs
# without the attribute were written before this convention, with reading k taken at the
# start of step k (state q_k, torque tau_k, acceleration over step k - 1).
READING_TIMING = "end_of_step"
_OLD_TIMING = "start_of_step"
TRUTH_CONTACT = "truth/contact"


def evaluate_file(path: str | Path, *, json_path: str | Path | None = None) -> dict:
    """Runs the estimator, GM observer and kinematic detector on a log; prints the metrics.

    A log without ground truth (no ``truth/contact``, e.g. one recorded on a robot) has no
    metrics: the estimator's P(contact) per foot is then printed as a mean per foot and,
    with ``json_path``, written per step and env under ``"p_contact"``.

    Returns:
      ``log``, ``attrs``, ``scores`` (detector -> metrics; empty without ground truth),
      ``has_truth``, ``foot_names``, and ``p_contact`` (foot -> (T, E) nested lists) when
      the log has no ground truth.

    Raises:
      FileNotFoundError: no such file.
      ValueError: one line naming the file, the field and what was expected: unreadable
        file, a missing attribute or array, an array of the wrong shape, a robot whose
        model does not fit the readings.
    """
    import jax_contact as jc
    from envs.robots import load_robot
    from jax_contact.baselines import make_gm_params, make_kinematic_params
    from train.evaluate import replay, score
    from train.reproduce import TERRAIN_SIGMA, planar_estimator_params, quadruped_estimator_params

    arrays, attrs = read_log(path)
    name = f"log {str(path)!r}"
    robot_name, dt = _log_attrs(name, attrs)
    readings, truth, valid = _log_arrays(name, arrays)
    timing = attrs.get("reading_timing", _OLD_TIMING)
    if timing == _OLD_TIMING:
        print(
            f"{name} has readings taken at the start of each step (written before"
            f" 'reading_timing' existed): re-aligned to {READING_TIMING!r}, one step shorter",
            file=sys.stderr,
        )
        readings, truth, valid = to_end_of_step(readings, truth, valid)
    elif timing != READING_TIMING:
        raise ValueError(
            f"{name}: attribute 'reading_timing' is {timing!r}; expected {READING_TIMING!r}"
        )
    robot = load_robot(robot_name)
    desc = robot.description
    for key, size, what in (("qpos", desc.nq, "nq"), ("qvel", desc.nv, "nv")):
        if readings[key].shape[-1] != size:
            raise ValueError(
                f"{name}: array 'readings/{key}' has {readings[key].shape[-1]} columns but"
                f" robot {robot_name!r} has {what} = {size}"
            )
    if truth is not None and truth.shape[-1] != desc.n_legs:
        raise ValueError(
            f"{name}: array {TRUTH_CONTACT!r} has {truth.shape[-1]} feet but robot"
            f" {robot_name!r} has {desc.n_legs}"
        )
    if desc.n_leg_dofs == 2:
        params, terrain = planar_estimator_params(desc.nv, dt), jc.flat(0.0, 0.2)
    else:
        params, terrain = quadruped_estimator_params(desc, dt), jc.flat(0.0, TERRAIN_SIGMA)
    out = replay(
        robot,
        readings,
        estimators={"probabilistic": params},
        terrain=terrain,
        # Without ground truth only the estimator's P(contact) is reported.
        gms={"gm": make_gm_params()} if truth is not None else None,
        kinematic=make_kinematic_params() if truth is not None else None,
        dt=dt,
    )
    feet = [str(f) for f in attrs.get("foot_names") or desc.foot_names]
    result = {"log": str(path), "attrs": attrs, "has_truth": truth is not None, "foot_names": feet}
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
        result["scores"] = {}
        result["p_contact"] = {f: p[..., i] for i, f in enumerate(feet)}
    else:
        scores = score(out, truth, valid, dt=dt)
        print(format_scores(scores))
        result["scores"] = scores
    if json_path:
        write_json_atomic(json_path, json.loads(json.dumps(result, default=_plain)))
    return result


def format_scores(scores: dict[str, dict]) -> str:
    """The metrics table of :func:`evaluate_file`, with a header and a legend."""
    lines = [
        f"{'detector':14s} {'touch-down delay ms':>20s} {'failures':>8s} {'missed':>6s}"
        f" {'F1':>5s} {'Brier':>5s} {'ECE':>5s} {'touch-downs':>11s}"
    ]
    for det, s in scores.items():
        td = s["touchdown_delay_ms"]
        lines.append(
            f"{det:14s} {td[0]:11.1f} +- {td[1]:5.1f} {s['failures']:8d} {s['missed']:6d}"
            f" {s['f1']:5.3f} {s['brier']:5.3f} {s['ece']:5.3f} {s['n_touchdowns']:11d}"
        )
    lines += [
        "delay: true touch-down to detection, mean +- std; failures: false contacts in the"
        " air (the paper's 'fail');",
        "missed: touch-downs not detected before the lift-off; F1 of the flag P > 0.5;"
        " Brier, ECE: calibration of P(contact) (definitions: jax_contact.metrics)",
    ]
    return "\n".join(lines)


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
