"""Where one estimator update spends its time: each piece jitted alone, XLA's cost analysis.

Run::

    python -m jax_contact.benchmarks.profile_pieces [--envs 1024] [--modes quadrature monte_carlo]

``step_batch`` runs on :func:`jax_contact.benchmarks.common.synthetic_robot_measurements` (the
per-robot layout); every other piece is ``vmap``-ed over (envs, 4 legs) of those robots'
:class:`jax_contact.LegBlocks` (split beforehand, except in the "split" piece) and compiled
ahead of time; it prints the median (and min) ms per call over ``--repeats``
calls and, per leg, the flops, transcendental calls and bytes that
``compiled.cost_analysis()`` reports. Pieces fused into one update cost less than alone.
Last, the cost of launching one (nearly empty) kernel, which bounds a small batch's latency.

``--trace DIR`` also runs the whole ``step_batch`` under ``jax.profiler.trace`` (the trace is
left in DIR for TensorBoard or Perfetto) and sums its kernels' times by the library function
they come from (the functions are ``jax.named_call``-scoped), so the split is measured
inside the fused update rather than piece by piece.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import re
import statistics
import time

import jax
import jax.numpy as jnp

import jax_contact as jc
from jax_contact import filter as filter_
from jax_contact import measurement, transition
from jax_contact.benchmarks.common import (
    bench_parser,
    check_folder_arg,
    check_json_arg,
    json_of_what_finished,
    kernel_count,
    machine,
    run_main,
    synthetic_robot_measurements,
)
from jax_contact.params import TOUCHDOWN_MODES
from jax_contact.train.cli_args import positive_int
from jax_contact.types import blocks_are_finite

N_LEGS, NV = 4, 18


def _call_times(compiled, args, calls: int) -> list[float]:
    """Seconds per call of ``compiled(*args)``, ``calls`` times after one warm-up call."""
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t)
    return times


def _time(name: str, fn, args, n_legs: int, repeats: int) -> dict:
    t = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t
    cost = compiled.cost_analysis()
    cost = (cost[0] if isinstance(cost, list) else cost) or {}
    times = _call_times(compiled, args, repeats)
    row = {
        "piece": name,
        "compile_s": compile_s,
        "median_ms": 1e3 * statistics.median(times),
        "min_ms": 1e3 * min(times),
        "flops_per_leg": cost.get("flops", 0.0) / n_legs,
        "transcendentals_per_leg": cost.get("transcendentals", 0.0) / n_legs,
        "bytes_per_leg": cost.get("bytes accessed", 0.0) / n_legs,
    }
    print(
        f"{name:24s} {row['median_ms']:8.2f} ms (min {row['min_ms']:7.2f})"
        f"  compile {compile_s:6.2f} s"
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
    times = _call_times(compiled, (x,), max(repeats, 200))
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


# The library's jax.named_call scopes a kernel can belong to (the innermost one counts).
SCOPES = (
    "robot_leg_blocks",
    "leg_blocks",
    "blocks_are_finite",
    "_sanitize",
    "dynamics_llr",
    "diff_kinematics_llr",
    "kinematics_llr",
    "log_takeoff",
    "log_touchdown",
)
_OTHER = "other (recursion, terrain, keys, stacking)"


def _scope(op_name: str) -> str:
    found = [m.group(1) for m in re.finditer(r"\b(" + "|".join(SCOPES) + r")\b", op_name)]
    return found[-1] if found else _OTHER


def trace_step(fn, args, out_dir: str, calls: int = 10) -> list[dict]:
    """Runs ``fn`` (jitted) ``calls`` times under ``jax.profiler.trace(out_dir)`` and sums
    the time of each kernel it launched by :data:`SCOPES`.

    Returns:
      rows of ``scope``, ``kernels``, ``ms_per_call`` and ``share`` of the kernel time; a
      last row ``all kernels`` with ``wall_ms_per_call``, the calls' median outside the
      trace (the kernels' times are summed over the threads that ran them concurrently,
      and taken under the profiler, so their sum can exceed it).
    """
    compiled = jax.jit(fn).lower(*args).compile()
    text = compiled.as_text()
    module = re.match(r"HloModule (\S+?),", text).group(1)
    entry = text[text.index("\nENTRY") :]
    op_names = dict(
        re.findall(r'^\s*(?:ROOT )?%?([\w.\-]+) = [^\n]*?metadata=\{op_name="([^"]*)"', entry, re.M)
    )
    wall = _call_times(compiled, args, calls)
    pattern = os.path.join(out_dir, "**", "*.trace.json.gz")
    before = set(glob.glob(pattern, recursive=True))
    with jax.profiler.trace(out_dir):
        for _ in range(calls):
            jax.block_until_ready(compiled(*args))
    (path,) = set(glob.glob(pattern, recursive=True)) - before
    with gzip.open(path) as f:
        events = json.load(f)["traceEvents"]
    us = collections.Counter()
    kernels = collections.defaultdict(set)
    for e in events:
        a = e.get("args", {})
        if e.get("ph") == "X" and a.get("hlo_module") == module and "hlo_op" in a:
            scope = _scope(op_names.get(a["hlo_op"], ""))
            us[scope] += e["dur"]
            kernels[scope].add(a["hlo_op"])
    total = sum(us.values())
    rows = [
        {
            "scope": scope,
            "kernels": len(kernels[scope]),
            "ms_per_call": t / 1e3 / calls,
            "share": t / total,
        }
        for scope, t in us.most_common()
    ]
    rows.append(
        {
            "scope": "all kernels",
            "kernels": sum(len(k) for k in kernels.values()),
            "ms_per_call": total / 1e3 / calls,
            "share": 1.0,
            "wall_ms_per_call": 1e3 * statistics.median(wall),
        }
    )
    for r in rows:
        extra = f"  (call: {r['wall_ms_per_call']:.3f} ms)" if "wall_ms_per_call" in r else ""
        print(
            f"  {r['scope']:44s} {r['kernels']:4d} kernels {r['ms_per_call']:8.3f} ms"
            f" {100 * r['share']:5.1f} %{extra}",
            flush=True,
        )
    return rows


def main(argv=None) -> list[dict]:
    parser = bench_parser(__doc__)
    parser.add_argument("--envs", type=positive_int, default=1024, help="batch size (envs)")
    parser.add_argument(
        "--modes",
        nargs="+",
        default=["quadrature", "monte_carlo"],
        choices=TOUCHDOWN_MODES,
        help="touch-down modes to profile",
    )
    parser.add_argument("--repeats", type=positive_int, default=20, help="timed calls per piece")
    parser.add_argument("--trace", metavar="DIR", help="also profile step_batch into DIR")
    parser.add_argument("--json", help="write the rows and the machine as JSON (atomically)")
    args = parser.parse_args(argv)
    check_folder_arg(parser, "--trace", args.trace)
    check_json_arg(parser, args.json)
    result = {"machine": machine(), "envs": args.envs, "repeats": args.repeats, "rows": []}
    with json_of_what_finished(args.json, result):  # what finished, if a piece fails
        _profile(args, result["rows"])
    return result["rows"]


def _profile(args, rows: list[dict]) -> None:
    """Appends each piece's row to ``rows`` as it is measured."""
    n, legs = args.envs, args.envs * N_LEGS
    meas = synthetic_robot_measurements(n, N_LEGS, NV)
    terrain = jc.flat()
    params = jc.make_params(jc.make_noise(NV), touchdown="quadrature")
    blocks = jax.jit(jax.vmap(lambda m: jc.robot_leg_blocks(params, m)))(meas)

    def per_leg(f):
        return jax.vmap(jax.vmap(f))

    valid = jax.jit(per_leg(blocks_are_finite))(blocks)

    def query(m):
        return terrain.query(m.p_f, jnp.zeros(3), jnp.array(False))

    keys = jax.random.split(jax.random.key(0), legs).reshape(n, N_LEGS)
    print(
        f"# {n} envs x {N_LEGS} legs; per piece: median (min) of {args.repeats} timed calls,"
        " its compile time apart, and XLA's cost analysis per leg"
        + (" (under 5 calls: their median is noise)" if args.repeats < 5 else ""),
        flush=True,
    )
    for mode in args.modes:
        mode_params = jc.make_params(jc.make_noise(NV), touchdown=mode)
        belief = jc.init_belief_batch(mode_params, n, N_LEGS)

        def update(b, m, k, p=mode_params):
            return jc.step_batch(p, terrain, b, m, key=k)

        def touchdown(m, k, p=mode_params):
            return transition.log_touchdown(p, m, query(m), key=k)

        update_args = (belief, meas, jax.random.key(0))
        rows.append(_time(f"step_batch {mode}", update, update_args, legs, args.repeats))
        if args.trace:
            print(f"# step_batch {mode}: kernel time by library function (jax.profiler)")
            traced = trace_step(update, update_args, args.trace)
            rows.extend({"piece": f"trace {mode}", **r} for r in traced)
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
    rows.append(
        _time("finiteness check", per_leg(blocks_are_finite), (blocks,), legs, args.repeats)
    )
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


if __name__ == "__main__":
    raise SystemExit(run_main(main, "profile_pieces"))
