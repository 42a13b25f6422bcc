"""Simulated logs on disk: ``jax-contact simulate`` writes them, ``jax-contact evaluate`` reads.

The schema is documented in :mod:`jax_contact.io`. Evaluating a log recomputes the
estimator's inputs from the stored readings with the robot's nominal model, exactly as on
a recorded robot log.
"""

from __future__ import annotations

import json
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
    }
    write_log(path, roll.to_arrays(), attrs)
    n_valid = int(roll.valid[-1].sum())
    print(
        f"wrote {path}: {roll.qpos.shape[0]} steps x {n_envs} envs ({n_valid} upright at the end)"
    )
    return path


def evaluate_file(path: str | Path, *, json_path: str | Path | None = None) -> dict:
    """Runs the estimator, GM observer and kinematic detector on a log; prints the metrics."""
    import jax_contact as jc
    from envs.robots import load_robot
    from envs.simulate import Rollout
    from jax_contact.baselines import make_gm_params, make_kinematic_params
    from train.evaluate import replay, score
    from train.reproduce import TERRAIN_SIGMA, planar_estimator_params, quadruped_estimator_params

    arrays, attrs = read_log(path)
    roll = Rollout.from_arrays(arrays)
    robot = load_robot(attrs["robot"])
    desc = robot.description
    if roll.qvel.shape[-1] != desc.nv:
        raise ValueError(
            f"log {str(path)!r} has nv = {roll.qvel.shape[-1]} but robot {attrs['robot']!r} has"
            f" nv = {desc.nv}"
        )
    dt = float(attrs["dt"])
    if desc.n_leg_dofs == 2:
        params, terrain = planar_estimator_params(desc.nv, dt), jc.flat(0.0, 0.2)
    else:
        params, terrain = quadruped_estimator_params(desc, dt), jc.flat(0.0, TERRAIN_SIGMA)
    out = replay(
        robot,
        dict(qpos=roll.qpos, qvel=roll.qvel, qacc=roll.qacc, tau=roll.tau),
        estimators={"probabilistic": params},
        terrain=terrain,
        gms={"gm": make_gm_params()},
        kinematic=make_kinematic_params(),
        dt=dt,
    )
    scores = score(out, roll.contact, roll.valid, dt=dt)
    for name, s in scores.items():
        td = s["touchdown_delay_ms"]
        print(
            f"{name:14s} touch-down {td[0]:6.1f}±{td[1]:5.1f} ms  failures {s['failures']:4d}"
            f"  missed {s['missed']:4d}  F1 {s['f1']:.3f}  Brier {s['brier']:.3f}"
            f"  ECE {s['ece']:.3f}  ({s['n_touchdowns']} touch-downs)"
        )
    result = {"log": str(path), "attrs": attrs, "scores": scores}
    if json_path:
        write_json_atomic(json_path, json.loads(json.dumps(result, default=_plain)))
    return result


def _plain(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(type(x).__name__)
