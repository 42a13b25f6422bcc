"""Accuracy of the wrapped estimator at the physics rate on Playground envs (docs/training.md).

Scenes (``--envs``, Playground registry names loaded offline), each E rollouts of T env
steps (20 ms), ``anymal_like`` sensors, the env's own ``*_floor_found`` foot sensors as
truth, scored at every physics step after the first ``--skip`` s (the drop at reset)
and up to each rollout's first ``done``:

- ``Go1JoystickFlatTerrain``, ``SpotFlatTerrainJoystick``: a scripted trot in place,
  diagonal pairs lifting in turn (hip pitch +0.5 rad, knee -0.8 rad at the peak of a
  half-sine, 2.5 Hz x (1 + 0.02 e) for rollout e), actions in the env's units
  (rad / action_scale, added to the default pose by the env);
- ``BerkeleyHumanoidJoystickFlatTerrain``: scripted stepping in place, the legs in turn
  (hip pitch -0.4 rad, knee +0.8 rad, ankle pitch -0.4 rad at the peak, 1.5 Hz);
- ``Go1Getup``, ``Go1Handstand``: uniform random actions in [-1, 1] (the issue's case).

Both rates run on the same rollouts (:func:`jax_contact.train.rates.compare_rates`: control-rate
wrapper inside, physics-rate outside). Reported: accuracy, F1, precision, recall at every
physics step, the control rate's accuracy at env steps, and the trivial scores
(always-contact, always-air). Prints a table and writes JSON.

    python -m jax_contact.benchmarks.wrapper_accuracy --json out/wrapper_accuracy.json
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from jax_contact.benchmarks.common import json_of_what_finished, machine, print_table

ENVS = (
    "Go1JoystickFlatTerrain",
    "SpotFlatTerrainJoystick",
    "BerkeleyHumanoidJoystickFlatTerrain",
    "Go1Getup",
    "Go1Handstand",
)
SCALE = {"Go1": 0.5, "Spot": 0.3, "BerkeleyHumanoid": 0.5}  # their configs' action_scale


def actions_for(name: str, env, n_steps: int, n_envs: int, seed: int) -> tuple[np.ndarray, str]:
    """(T, E, nu) actions and a one-line description of the policy."""
    nu = env.action_size
    if name in ("Go1Getup", "Go1Handstand"):
        rng = np.random.default_rng(seed)
        return rng.uniform(-1, 1, (n_steps, n_envs, nu)).astype(np.float32), "random U(-1,1)"
    t = np.arange(1, n_steps + 1)[:, None] * float(env.dt)
    freq = 1.0 + 0.02 * np.arange(n_envs)
    acts = np.zeros((n_steps, n_envs, nu), np.float32)
    robot = next(k for k in SCALE if name.startswith(k))
    scale = SCALE[robot]
    if robot in ("Go1", "Spot"):
        for leg, phase in enumerate([0.0, np.pi, np.pi, 0.0]):  # two diagonal pairs
            s = np.maximum(0.0, np.sin(2 * np.pi * 2.5 * freq * t + phase))
            acts[:, :, 3 * leg + 1] += 0.5 * s / scale
            acts[:, :, 3 * leg + 2] -= 0.8 * s / scale
        return acts, "scripted trot in place (2.5 Hz)"
    for leg, phase in enumerate([0.0, np.pi]):  # left, right: 6 actuators each
        s = np.maximum(0.0, np.sin(2 * np.pi * 1.5 * freq * t + phase))
        acts[:, :, 6 * leg + 2] -= 0.4 * s / scale
        acts[:, :, 6 * leg + 3] += 0.8 * s / scale
        acts[:, :, 6 * leg + 4] -= 0.4 * s / scale
    return acts, "scripted stepping in place (1.5 Hz)"


def run_one(name: str, n_steps: int, n_envs: int, skip_s: float, seed: int) -> dict:
    from jax_contact.envs import playground_offline
    from jax_contact.train.rates import compare_rates

    env = playground_offline.load(name)
    acts, policy = actions_for(name, env, n_steps, n_envs, seed)
    t0 = time.perf_counter()
    res = compare_rates(env, acts, key=jax.random.PRNGKey(seed), skip_s=skip_s)
    wall = time.perf_counter() - t0
    print(f"{name}: {policy}, {n_envs} x {n_steps} steps ({wall:.0f} s)\n{res.table()}", flush=True)
    m = res.substep_all
    return {
        "env": name,
        "policy": policy,
        "dt_physics_ms": res.dt_substep * 1e3,
        "accuracy": m.accuracy,
        "f1": m.f1,
        "precision": m.precision,
        "recall": m.recall,
        "always_contact": res.contact_fraction,
        "always_air": 1 - res.contact_fraction,
        "control_accuracy": res.control.accuracy,
        "substep_accuracy_at_env_steps": res.substep.accuracy,
        "foot_updates": m.n_steps,
        "wall_s": wall,
        "substep": m.as_dict(),
        "control": res.control.as_dict(),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None)
    parser.add_argument("--envs", nargs="*", default=list(ENVS))
    parser.add_argument("--steps", type=int, default=150, help="env steps per rollout")
    parser.add_argument("--rollouts", type=int, default=8)
    parser.add_argument("--skip", type=float, default=0.5, help="seconds left out at the start")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    result = {"machine": machine(), "args": vars(args), "rows": []}
    with json_of_what_finished(args.json, result):
        for name in args.envs:
            result["rows"].append(run_one(name, args.steps, args.rollouts, args.skip, args.seed))
    cols = [
        ("env", "env", "{}"),
        ("policy", "policy", "{}"),
        ("accuracy", "acc", "{:.3f}"),
        ("f1", "F1", "{:.3f}"),
        ("precision", "prec", "{:.3f}"),
        ("recall", "rec", "{:.3f}"),
        ("always_contact", "all-contact", "{:.3f}"),
        ("always_air", "all-air", "{:.3f}"),
        ("control_accuracy", "ctrl acc", "{:.3f}"),
        ("foot_updates", "n", "{}"),
    ]
    print_table(result["rows"], cols)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
