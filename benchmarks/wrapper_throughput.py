"""Step throughput and compile time of the wrapped env against the bare env, both rates.

Playground's ``Go1JoystickFlatTerrain`` (offline, ``impl="jax"``, 4 ms physics x 5
substeps), batched with ``jax.vmap``: ``bare`` (the env's own step), ``substep`` (the
wrapper at the physics rate, the default) and ``control`` (one update per env step), at
each ``--sizes`` batch size. Compile time (``jit(...).lower().compile()``) and the median
of timed calls of the compiled step (zero actions, the state carried over) are measured
apart; the ratio wrapped/bare is the wrapper's cost. The variants are timed in turn at
each size, so that a load from other processes on the machine falls on all three alike.

    python -m jax_contact.benchmarks.wrapper_throughput --sizes 1 256 1024 \
        --json out/throughput.json
"""

from __future__ import annotations

import statistics
import time

import jax
import jax.numpy as jnp

from jax_contact.benchmarks.common import (
    bench_parser,
    check_env_arg,
    check_json_arg,
    json_of_what_finished,
    machine,
    print_table,
    run_main,
)
from jax_contact.train.cli_args import positive_int


def _variants(name: str):
    from jax_contact.envs import playground_offline
    from jax_contact.envs import wrapper as W

    env = playground_offline.load(name)
    return env, {
        "bare": env,
        "substep": W.wrap_contact(env),
        "control": W.wrap_contact(env, W.ContactObsConfig(rate="control")),
    }


def measure(name: str, sizes, calls: int, rows: list) -> list[dict]:
    """Appends one row per (size, variant) to ``rows`` as it finishes; returns it."""
    env, variants = _variants(name)
    for n in sizes:
        keys = jax.random.split(jax.random.PRNGKey(0), n)
        action = jnp.zeros((n, env.action_size))
        compiled, states = {}, {}
        for label, e in variants.items():
            # The reset runs asynchronously: finished before the compile clock starts.
            states[label] = jax.block_until_ready(jax.jit(jax.vmap(e.reset))(keys))
            t = time.perf_counter()
            compiled[label] = jax.jit(jax.vmap(e.step)).lower(states[label], action).compile()
            compile_s = time.perf_counter() - t
            states[label] = jax.block_until_ready(compiled[label](states[label], action))
            rows.append({"n_envs": n, "variant": label, "compile_s": compile_s, "times": []})
        for _ in range(calls):  # in turn, so that a passing load hits all three
            for row in rows[-len(variants) :]:
                label = row["variant"]
                t = time.perf_counter()
                states[label] = jax.block_until_ready(compiled[label](states[label], action))
                row["times"].append(time.perf_counter() - t)
        group = rows[-len(variants) :]
        bare = statistics.median(group[0]["times"])
        for row in group:
            med = statistics.median(row.pop("times"))
            row["step_ms"] = med * 1e3
            row["env_steps_per_s"] = n / med
            row["ratio_to_bare"] = med / bare
            print(row, flush=True)
    return rows


def main(argv=None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--json", default=None, help="write the rows and the machine here")
    parser.add_argument(
        "--env", default="Go1JoystickFlatTerrain", help="a Playground locomotion registry name"
    )
    parser.add_argument(
        "--sizes", type=positive_int, nargs="+", default=[1, 256, 1024], help="batch sizes (envs)"
    )
    parser.add_argument(
        "--calls", type=positive_int, default=5, help="timed calls per variant and size"
    )
    args = parser.parse_args(argv)
    check_env_arg(parser, "--env", args.env)
    check_json_arg(parser, args.json)
    result = {"machine": machine(), "args": vars(args), "rows": []}
    with json_of_what_finished(args.json, result):
        measure(args.env, args.sizes, args.calls, result["rows"])
    cols = [
        ("n_envs", "envs", "{}"),
        ("variant", "variant", "{}"),
        ("compile_s", "compile s", "{:.1f}"),
        ("step_ms", "step ms", "{:.2f}"),
        ("env_steps_per_s", "env steps/s", "{:.0f}"),
        ("ratio_to_bare", "x bare", "{:.2f}"),
    ]
    print_table(result["rows"], cols)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, "wrapper_throughput"))
