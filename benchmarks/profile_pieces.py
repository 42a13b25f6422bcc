"""Where one estimator update spends its time: each piece jitted alone, XLA's cost analysis.

Run::

    python -m benchmarks.profile_pieces [--envs 1024] [--modes quadrature monte_carlo]

``step_batch`` runs on :func:`benchmarks.common.synthetic_robot_measurements` (the
per-robot layout); every other piece is ``vmap``-ed over (envs, 4 legs) of those robots'
:class:`jax_contact.LegBlocks` (split beforehand, except in the "split" piece) and compiled
ahead of time; it prints the median (and min) ms per call over ``--repeats``
calls and, per leg, the flops, transcendental calls and bytes that
``compiled.cost_analysis()`` reports. Pieces fused into one update cost less than alone.
Last, the cost of launching one (nearly empty) kernel, which bounds a small batch's latency.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp

import jax_contact as jc
from benchmarks.common import kernel_count, synthetic_robot_measurements
from jax_contact import filter as filter_
from jax_contact import measurement, transition
from jax_contact.types import feet_are_finite

N_LEGS, NV = 4, 18


def _time(name: str, fn, args, n_legs: int, repeats: int) -> dict:
    compiled = jax.jit(fn).lower(*args).compile()
    cost = compiled.cost_analysis()
    cost = (cost[0] if isinstance(cost, list) else cost) or {}
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t)
    row = {
        "piece": name,
        "median_ms": 1e3 * statistics.median(times),
        "min_ms": 1e3 * min(times),
        "flops_per_leg": cost.get("flops", 0.0) / n_legs,
        "transcendentals_per_leg": cost.get("transcendentals", 0.0) / n_legs,
        "bytes_per_leg": cost.get("bytes accessed", 0.0) / n_legs,
    }
    print(
        f"{name:24s} {row['median_ms']:8.2f} ms (min {row['min_ms']:7.2f})"
        f"  flops/leg {row['flops_per_leg']:8.0f}  transc/leg {row['transcendentals_per_leg']:6.0f}"
        f"  bytes/leg {row['bytes_per_leg']:7.0f}",
        flush=True,
    )
    return row


def _read_once(m) -> jax.Array:
    """() the sum of every floating-point input of a batch: one pass over its bytes."""
    leaves = [x for x in jax.tree.leaves(m) if jnp.issubdtype(x.dtype, jnp.floating)]
    return sum(jnp.sum(x) for x in leaves)


def _kernel_chain(x: jax.Array, n: int = 100) -> jax.Array:
    """``n`` dependent kernels on 4 floats: each reduction ends one (XLA fuses none of them)."""
    for _ in range(n):
        x = x + jnp.sum(jnp.sin(x))
    return x


def launch_cost(repeats: int) -> dict:
    """What XLA:CPU spends per kernel when there is next to no work in it: the floor of a
    small batch's latency, which is (kernels launched) x (this) + the call's dispatch."""
    x = jnp.ones(4, jnp.float32)
    compiled = jax.jit(_kernel_chain).lower(x).compile()
    kernels = kernel_count(compiled)
    jax.block_until_ready(compiled(x))
    times = []
    for _ in range(max(repeats, 200)):
        t = time.perf_counter()
        jax.block_until_ready(compiled(x))
        times.append(time.perf_counter() - t)
    row = {
        "piece": "kernel launch",
        "kernels": kernels,
        "median_ms": 1e3 * statistics.median(times),
        "us_per_kernel": 1e6 * statistics.median(times) / kernels,
    }
    print(
        f"{'kernel launch':24s} {row['us_per_kernel']:8.2f} us per kernel"
        f" ({kernels} dependent 4-float kernels, {row['median_ms']:.3f} ms per call)",
        flush=True,
    )
    return row


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=1024)
    parser.add_argument("--modes", nargs="+", default=["quadrature", "monte_carlo"])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    n, legs = args.envs, args.envs * N_LEGS
    meas = synthetic_robot_measurements(n, N_LEGS, NV)
    terrain = jc.flat()
    params = jc.make_params(jc.make_noise(NV), touchdown="quadrature")
    blocks = jax.jit(jax.vmap(lambda m: jc.robot_leg_blocks(params, m)))(meas)
    valid = jax.jit(jax.vmap(feet_are_finite))(meas)

    def per_leg(f):
        return jax.vmap(jax.vmap(f))

    def query(m):
        return terrain.query(m.p_f, jnp.zeros(3), jnp.array(False))

    rows = []
    keys = jax.random.split(jax.random.key(0), legs).reshape(n, N_LEGS)
    for mode in args.modes:
        params = jc.make_params(jc.make_noise(NV), touchdown=mode)
        belief = jc.init_belief_batch(params, n, N_LEGS)

        def update(b, m, k, params=params):
            return jc.step_batch(params, terrain, b, m, key=k)

        def touchdown(m, k, params=params):
            return transition.log_touchdown(params, m, query(m), key=k)

        rows.append(
            _time(
                f"step_batch {mode}", update, (belief, meas, jax.random.key(0)), legs, args.repeats
            )
        )
        rows.append(
            _time(f"touch-down {mode}", per_leg(touchdown), (blocks, keys), legs, args.repeats)
        )
    rows.append(
        _time(
            "split (robot_leg_blocks)",
            jax.vmap(lambda m: jc.robot_leg_blocks(params, m)),
            (meas,),
            legs,
            args.repeats,
        )
    )
    rows.append(_time("finiteness check", jax.vmap(feet_are_finite), (meas,), legs, args.repeats))
    rows.append(_time("sanitize", per_leg(filter_._sanitize), (blocks, valid), legs, args.repeats))
    pieces = {
        "dynamics": lambda m: measurement.dynamics_llr(params, m, query(m).normal),
        "diff. kinematics": lambda m: measurement.diff_kinematics_llr(params, m),
        "kinematics": lambda m: measurement.kinematics_llr(params, m, query(m)),
        "take-off": lambda m: transition.log_takeoff(
            params, *transition.normal_velocity(params, m, query(m).normal)
        ),
    }
    for name, f in pieces.items():
        rows.append(_time(name, per_leg(f), (blocks,), legs, args.repeats))
    # The floor for any update that reads this layout: one pass over every input byte of the
    # whole batch, no arithmetic to speak of.
    rows.append(_time("read inputs once", _read_once, (meas,), legs, args.repeats))
    rows.append(launch_cost(args.repeats))
    return rows


if __name__ == "__main__":
    main()
