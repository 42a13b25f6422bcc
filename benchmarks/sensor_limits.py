"""What each imperfection of the sensors costs the estimator (docs/model_choices.md).

One scenario of the reproduction (``jax_contact.train.reproduce``: its world, scripted gait,
speed range and seed) is simulated once per sensor model below; the gait and the physics
do not depend on the sensors, so every row sees the same steps, touch-downs and lift-offs
(checked: the script stops if the ground truth differs). Every row is replayed through
the *same* estimator, the defaults for the ``anymal_like`` sensors
(:func:`jax_contact.train.reproduce.quadruped_estimator_params`), and scored on every
step (:mod:`jax_contact.metrics`):

- ``anymal_like``: Table III's sensors (docs/results.md);
- ``no_latency``: the same readings one step sooner (``latency`` 0 instead of 1 step);
- ``no_outliers``: without the joint-velocity spikes;
- ``no_base_drift``: without the base state's bias random walks;
- ``joint_qd_half``: half the joints' velocity noise (and so half the differenced
  acceleration's);
- ``noise_free``: the true state, one step late (``ideal`` with ``anymal_like``'s latency);
- ``ideal``: the true state, on time.

So the rows split the gap between ``anymal_like`` and the targets of issue 13 into what
the readings' latency, noise, outliers and drift cause, and what remains with perfect
readings (the estimator's own model). Prints a table per scenario and writes JSON.

    python -m jax_contact.benchmarks.sensor_limits --robot go1 --json out/sensor_limits.json

The default seed, 1000, is a tuning seed of the presets (docs/tuning.md); nothing here
is tuned.
"""

from __future__ import annotations

import dataclasses
import time

import jax.numpy as jnp
import numpy as np

from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    check_robot_arg,
    json_of_what_finished,
    machine,
    print_table,
    run_main,
)
from jax_contact.train.cli_args import positive_float, positive_int, seed_int

SCENARIOS = ("trot", "walk", "walk_added_mass", "rough")


def sensor_variants(nv: int, dt: float) -> dict:
    """Name -> :class:`jax_contact.envs.sensors.SensorParams`: ``anymal_like`` and the
    variants of the module docstring, each with one imperfection removed (or two for
    ``noise_free`` and ``ideal``)."""
    from jax_contact.envs.sensors import sensor_preset

    base = sensor_preset("anymal_like", nv, dt=dt)
    ideal = sensor_preset("ideal", nv, dt=dt)
    zeros = jnp.zeros(nv, jnp.float32)
    # Joints only: the floating base's 6 coordinates come first.
    joint_qd = base.sigma_qd.at[6:].multiply(0.5)
    return {
        "anymal_like": base,
        "no_latency": dataclasses.replace(base, latency=0),
        "no_outliers": dataclasses.replace(base, outlier_prob=jnp.float32(0.0)),
        "no_base_drift": dataclasses.replace(base, bias_rw_q=zeros, bias_rw_qd=zeros),
        "joint_qd_half": dataclasses.replace(base, sigma_qd=joint_qd),
        "noise_free": dataclasses.replace(ideal, latency=base.latency),
        "ideal": ideal,
    }


def run_scenario(robot: str, scenario: str, n_envs: int, duration: float, seed: int) -> list:
    """The rows of one scenario: per sensor model, the estimator's metrics as a dict."""
    import jax_contact as jc
    from jax_contact.envs.gaits import make_gait
    from jax_contact.envs.simulate import simulate
    from jax_contact.train import reproduce
    from jax_contact.train.evaluate import replay, score
    from jax_contact.train.tune_presets import scenario_world

    world, gait, speeds = scenario_world(robot, scenario, seed)
    params = reproduce.quadruped_estimator_params(world.robot.description, world.dt)
    rows, truth0 = [], None
    for name, sensors in sensor_variants(world.robot.description.nv, world.dt).items():
        t0 = time.perf_counter()
        roll = simulate(world, make_gait(gait), sensors, n_envs, duration, seed, speed_range=speeds)
        if truth0 is None:
            truth0 = roll.contact
        elif not np.array_equal(truth0, roll.contact):
            raise RuntimeError(f"{name}: the ground truth differs from anymal_like's")
        out = replay(
            world.robot,
            dict(qpos=roll.qpos, qvel=roll.qvel, qacc=roll.qacc, tau=roll.tau),
            estimators={name: params},
            terrain=jc.flat(0.0, reproduce.TERRAIN_SIGMA),
            dt=world.dt,
            seed=seed,
            progress=False,
        )
        m = score(out, roll.contact, roll.valid, dt=world.dt)[name]
        rows.append(
            {
                "robot": robot,
                "scenario": scenario,
                "sensors": name,
                "latency_ms": sensors.latency * world.dt * 1e3,
                "f1": m["f1"],
                "accuracy": m["accuracy"],
                "air_phase_failure_rate": m["air_phase_failure_rate"],
                "td_ms": m["touchdown_delay_ms"][0],
                "lo_ms": m["liftoff_delay_ms"][0],
                "ece": m["ece"],
                "wall_s": time.perf_counter() - t0,
                "metrics": m,
            }
        )
    return rows


COLUMNS = [
    ("scenario", "scenario", "{}"),
    ("sensors", "sensors", "{}"),
    ("latency_ms", "lag ms", "{:.1f}"),
    ("f1", "F1", "{:.3f}"),
    ("accuracy", "acc", "{:.3f}"),
    ("air_phase_failure_rate", "air-ph fail", "{:.3f}"),
    ("td_ms", "TD ms", "{:.1f}"),
    ("lo_ms", "LO ms", "{:.1f}"),
    ("ece", "ECE", "{:.3f}"),
]


def main(argv=None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--robot", default="go1", help="a robot `jax-contact reproduce` takes")
    parser.add_argument(
        "--scenarios",
        nargs="+",
        default=["trot", "walk"],
        choices=list(SCENARIOS),
        help="the reproduction's scenarios, each simulated once per sensor model",
    )
    parser.add_argument("--envs", type=positive_int, default=8, help="envs per scenario")
    parser.add_argument("--duration", type=positive_float, default=4.0, help="simulated seconds")
    parser.add_argument("--seed", type=seed_int, default=1000, help="simulation seed")
    parser.add_argument("--json", default=None, help="write the rows and the machine here")
    args = parser.parse_args(argv)
    check_robot_arg(parser, "--robot", args.robot)
    check_json_arg(parser, args.json)
    result = {"machine": machine(), "args": vars(args), "rows": []}
    with json_of_what_finished(args.json, result):
        for scenario in args.scenarios:
            rows = run_scenario(args.robot, scenario, args.envs, args.duration, args.seed)
            print_table(rows, COLUMNS)
            result["rows"].extend(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, "sensor_limits"))
