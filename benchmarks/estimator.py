"""Estimator throughput, single-robot latency and memory (issue: benchmarks).

Run::

    python -m jax_contact.benchmarks.estimator --json out/bench/estimator.json [--envs 1 64 1024]

One "update" is the whole step of every foot of every env: all three measurement terms,
both transitions (take-off and touch-down, Monte-Carlo at ``n_samples`` or quadrature) and
the recursion, i.e. ``jax_contact.step_batch`` on one ``RobotMeasurement`` per env (what
the observation wrapper runs; ``--layout per_foot``: on per-foot ``LegMeasurement``
copies). Compilation is timed apart from running.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

import jax_contact as jc
from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    compile_and_time,
    format_table,
    json_of_what_finished,
    kernel_count,
    machine,
    pin_to_cpu,
    print_table,
    run_main,
    synthetic,
)
from jax_contact.export import export_flat, load_exported
from jax_contact.train.cli_args import positive_int

DEFAULT_ENVS = (1, 64, 256, 1024, 4096, 16384)
MODES = ("quadrature", "monte_carlo")
N_LEGS = 4
NV = 18


def make_update(params: jc.EstimatorParams, terrain):
    """The function that is benchmarked: one batched step."""

    def update(belief, meas, key):
        return jc.step_batch(params, terrain, belief, meas, key=key)

    return update


def params_for(mode: str, n_samples: int = 500) -> jc.EstimatorParams:
    return jc.make_params(jc.make_noise(NV), touchdown=mode, n_samples=n_samples)


def throughput(
    envs, modes=MODES, n_samples: int = 500, layout: str = "robot", *, rows: list | None = None
) -> list[dict]:
    """Leg-updates per second of one full update at each batch size and mode; each row is
    appended to ``rows`` (a new list if None) as soon as it is measured."""
    rows = [] if rows is None else rows
    terrain = jc.flat()
    for n in envs:
        meas = synthetic(n, layout, N_LEGS, NV)
        for mode in modes:
            params = params_for(mode, n_samples)
            belief = jc.init_belief_batch(params, n, N_LEGS)
            t = compile_and_time(
                make_update(params, terrain), (belief, meas, jax.random.key(0)), repeats=10
            )
            rows.append(
                {
                    "envs": n,
                    "mode": mode,
                    "n_samples": n_samples if mode == "monte_carlo" else params.n_quad**2,
                    "compile_s": t["compile_s"],
                    "update_ms": 1e3 * t["median_s"],
                    "leg_updates_per_s": n * N_LEGS / t["median_s"],
                    "bytes_per_env": _bytes_per_env(t["compiled"], n),
                }
            )
            # Print as we go: the largest batches take a while on a small CPU.
            lines = format_table(rows[-1:], _THROUGHPUT_COLUMNS)
            print("\n".join(lines if len(rows) == 1 else lines[1:]), flush=True)
    return rows


def _bytes_per_env(compiled, n_envs: int) -> float | None:
    """Peak device memory of one call (arguments, outputs, temporaries) per env."""
    try:
        mem = compiled.memory_analysis()
    except Exception:  # noqa: BLE001 - some backends do not report it
        return None
    if mem is None:
        return None
    total = (
        mem.argument_size_in_bytes
        + mem.output_size_in_bytes
        + mem.temp_size_in_bytes
        - mem.alias_size_in_bytes
    )
    return total / n_envs


def _batch1(mode: str, layout: str):
    """A single robot's (4 legs) update in ``mode``: (update, args, jitted, compiled)."""
    params = params_for(mode)
    meas = synthetic(1, layout, N_LEGS, NV)
    args = (jc.init_belief_batch(params, 1, N_LEGS), meas, jax.random.key(0))
    update = make_update(params, jc.flat())
    jitted = jax.jit(update)
    jax.block_until_ready(jitted(*args))
    return update, args, jitted, jitted.lower(*args).compile()


def latency(n_calls: int = 10_000) -> dict:
    """Single-robot (4 legs) latency: Monte-Carlo jitted, AOT-compiled and jax.export'ed
    (by ``jax_contact.export.export_flat``, as the exported robot estimator is), and the
    quadrature jitted, on per-foot copies; with the number of kernels each executable
    launches. Also the Monte-Carlo jitted on the per-robot layout (the legs'
    blocks sliced, then one program vmapped over the legs: about as many kernels)."""
    _, q_args, q_jitted, q_compiled = _batch1("quadrature", "per_foot")
    _, r_args, r_jitted, r_compiled = _batch1("monte_carlo", "robot")
    update, args, jitted, compiled = _batch1("monte_carlo", "per_foot")
    out = {
        "jit": _time_calls(lambda: jitted(*args), n_calls),
        "aot": _time_calls(lambda: compiled(*args), n_calls),
    }
    out["jit"]["kernels"] = out["aot"]["kernels"] = kernel_count(compiled)

    # jax.export serialises plain arrays: the library's export flattens the pytrees and
    # passes the raw key data, as a deployment that loads the estimator without it would.
    exported, flat = export_flat(update, *args)
    call = jax.jit(load_exported(exported.serialize()).call)
    jax.block_until_ready(call(*flat))
    out["export"] = _time_calls(lambda: call(*flat), n_calls)
    out["quadrature_jit"] = _time_calls(lambda: q_jitted(*q_args), n_calls)
    out["quadrature_jit"]["kernels"] = kernel_count(q_compiled)
    out["robot_layout_jit"] = _time_calls(lambda: r_jitted(*r_args), n_calls)
    out["robot_layout_jit"]["kernels"] = kernel_count(r_compiled)
    return out


def _time_calls(fn, n: int) -> dict:
    times = np.empty(n)
    for i in range(n):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times[i] = time.perf_counter() - t
    return {
        "median_us": float(1e6 * np.median(times)),
        "p99_us": float(1e6 * np.percentile(times, 99)),
        "calls": n,
    }


def linearity(rows: list[dict]) -> dict:
    """Per-mode cost per env at the largest batch over that at 1024 envs (1 = linear)."""
    out = {}
    for mode in MODES:
        r = {row["envs"]: row["update_ms"] / row["envs"] for row in rows if row["mode"] == mode}
        if 1024 in r and max(r) > 1024:
            out[mode] = r[max(r)] / r[1024]
    return out


_THROUGHPUT_COLUMNS = [
    ("envs", "envs", "{:d}"),
    ("mode", "mode", "{}"),
    ("n_samples", "draws|nodes", "{:d}"),
    ("compile_s", "compile s", "{:.2f}"),
    ("update_ms", "update ms", "{:.3f}"),
    ("leg_updates_per_s", "leg-updates/s", "{:.3g}"),
    ("bytes_per_env", "bytes/env", "{:.0f}"),
]


def main(argv=None, *, into: dict | None = None) -> dict:
    """Runs the benchmark of the module docstring; ``into`` (a dict) is filled as results
    come, so a caller keeps what finished if a later part fails or is interrupted."""
    parser = bench_parser(__doc__)
    parser.add_argument(
        "--envs",
        type=positive_int,
        nargs="+",
        default=list(DEFAULT_ENVS),
        help="batch sizes of the throughput table (the default sweep takes minutes on a CPU)",
    )
    parser.add_argument(
        "--samples", type=positive_int, default=500, help="Monte-Carlo samples (throughput)"
    )
    parser.add_argument(
        "--latency-calls",
        type=positive_int,
        default=10_000,
        help="timed single-robot calls (the latency table always uses 500 Monte-Carlo samples)",
    )
    parser.add_argument("--latency-only", action="store_true", help="skip the throughput")
    parser.add_argument(
        "--cpu",
        type=int,
        default=None,
        help="run on this one CPU core only (Linux): XLA:CPU then sizes its thread pool to "
        "one core, as on a robot whose estimator process is pinned",
    )
    parser.add_argument(
        "--layout",
        choices=("robot", "per_foot"),
        default="robot",
        help="measurement layout: one RobotMeasurement per env (the wrapper's) or per-foot copies",
    )
    parser.add_argument("--json", default=None, help="write results as JSON here")
    args = parser.parse_args(argv)
    check_json_arg(parser, args.json)
    if args.cpu is not None:
        try:
            pin_to_cpu(args.cpu)
        except ValueError as err:
            parser.error(f"argument --cpu: {err}")
    jnp.zeros(())  # initialise the backend (after any pinning) before timing anything

    print(f"# estimator on {jax.default_backend()} ({jax.devices()[0]})")
    print(f"# measurement layout: {args.layout}")
    if jax.config.jax_compilation_cache_dir:
        print(
            f"# persistent compilation cache on ({jax.config.jax_compilation_cache_dir}): a"
            " program compiled in an earlier run is loaded, and 'compile s' is that load"
        )
    result = {} if into is None else into
    result.update(machine=machine(), args=vars(args), layout=args.layout)
    # Standalone, what finished is written if a later part fails (suite wraps its own).
    with json_of_what_finished(args.json, result):
        _measure(args, result)
    return result


def _measure(args, result: dict) -> None:
    """Throughput, latency and memory into ``result``, each part as it finishes."""
    rows = result.setdefault("throughput", [])  # the rows as they are measured
    if not args.latency_only:
        throughput(args.envs, n_samples=args.samples, layout=args.layout, rows=rows)
    lat = latency(args.latency_calls)
    print(
        f"\n# single-robot latency (4 legs; Monte-Carlo 500 and per-foot unless named;"
        f" {args.latency_calls} calls each"
        + (
            "; under 100 calls the p99 is about the slowest call, not a tail percentile"
            if args.latency_calls < 100
            else ""
        )
        + ")"
    )
    print_table(
        [{"how": k, **v} for k, v in lat.items()],
        [
            ("how", "call", "{}"),
            ("median_us", "median us", "{:.1f}"),
            ("p99_us", "p99 us", "{:.1f}"),
            ("kernels", "kernels", "{:d}"),
        ],
    )
    lin = linearity(rows)
    if lin:
        print("\n# cost per env at the largest batch / at 1024 envs:", lin)
    at = [r for r in rows if r["envs"] == 4096 and r["mode"] == "monte_carlo"] or rows[-1:]
    at = at or [{"bytes_per_env": None}]
    result.update(
        {
            "latency_batch1_us": {"median": lat["jit"]["median_us"], "p99": lat["jit"]["p99_us"]},
            "latency_batch1_detail": lat,
            # The headline memory figure: the 4096-env Monte-Carlo row, else the last row's.
            "bytes_per_env": at[0]["bytes_per_env"],
            "bytes_per_env_of": {k: at[0].get(k) for k in ("envs", "mode")},
            "linearity": lin,
        }
    )


if __name__ == "__main__":
    raise SystemExit(run_main(main, "estimator"))
