"""Every Playground locomotion env offline, wrapped at the physics rate, jitted: a table.

For each name of :func:`jax_contact.envs.playground_offline.offline_names`: load, wrap with the
defaults (physics rate, anymal_like sensors, the env's own foot sensors as truth), jit
reset and step (compile times apart), run ``--steps`` steps of zero actions (the default
pose) on one env, check the observation size and that nothing is NaN, and report the
feet, the truth source and the fraction of foot-updates where the estimate matched the
truth after the first 0.5 s (the reset drop) and up to the step whose ``done`` ends the
episode (a humanoid holding its default pose falls; the steps after it, which no training
loop would see without a reset, are not scored), with the number of scored foot-updates
and that step. Prints the table and writes JSON.

    python -m jax_contact.benchmarks.playground_envs --json out/playground_envs.json [--names A B]
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    json_of_what_finished,
    machine,
    print_table,
    run_main,
)
from jax_contact.train.cli_args import positive_int


def score_until_done(records, skip: int) -> tuple[int, int, int | None]:
    """Agreement of the estimate with the truth over an episode's env steps.

    Args:
      records: per env step, ``(p_contact, truth, done)``: the step's substeps' P(contact)
        and truth, (n_substeps, n_legs), and its ``done``.
      skip: env steps left out at the start (the reset drop).

    Returns:
      ``(hits, n, done_step)``: the foot-updates whose ``P > 0.5`` equals the truth and
      their number, over the steps from ``skip`` up to and including the first whose
      ``done`` is set (none after it: a training loop would have reset the env), and that
      step, counted from 1 (None if the episode did not end).
    """
    hits, n = 0, 0
    for i, (p, truth, done) in enumerate(records):
        p = np.asarray(p)
        if i >= skip:
            hits += int(np.sum((p > 0.5) == np.asarray(truth, bool)))
            n += p.size
        if bool(np.asarray(done)):
            return hits, n, i + 1
    return hits, n, None


def run_one(name: str, n_steps: int) -> dict:
    from jax_contact.envs import playground_offline
    from jax_contact.envs import wrapper as W

    t0 = time.perf_counter()
    env = playground_offline.load(name)
    wrapped = W.wrap_contact(env, W.ContactObsConfig(record_substeps=True))
    report = wrapped.contact_report()
    row = {
        "env": name,
        "feet": ",".join(f["name"] for f in report["feet"]),
        "kind": report["feet"][0]["kind"],
        "truth": report["truth"],
        "dt_ms": report["dt"] * 1e3,
        "load_s": time.perf_counter() - t0,
    }
    key = jax.random.PRNGKey(0)
    t = time.perf_counter()
    reset = jax.jit(wrapped.reset).lower(key).compile()
    row["reset_compile_s"] = time.perf_counter() - t
    state = jax.block_until_ready(reset(key))  # not running while the step compiles
    action = jnp.zeros(env.action_size)
    t = time.perf_counter()
    step = jax.jit(wrapped.step).lower(state, action).compile()
    row["step_compile_s"] = time.perf_counter() - t
    finite, records, step_s = True, [], 0.0
    for _ in range(n_steps):
        t = time.perf_counter()
        state = jax.block_until_ready(step(state, action))
        step_s += time.perf_counter() - t  # the step alone, not the host-side checks below
        finite &= all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree.leaves(state.obs))
        sub = state.info["contact_est_substeps"]
        records.append((sub["p_contact"], sub["truth"], state.done))
    row["run_s_per_step"] = step_s / n_steps
    hits, n, done_step = score_until_done(records, skip=int(round(0.5 / float(env.dt))))
    size = wrapped.observation_size
    shapes = jax.tree.map(lambda x: x.shape, state.obs)
    if isinstance(size, dict):
        row["obs_ok"] = all(tuple(shapes[k]) == tuple(v) for k, v in size.items())
    else:
        row["obs_ok"] = tuple(shapes) == (size,)
    row["finite"] = finite
    row["accuracy_standing"] = hits / n if n else None
    row["scored_updates"] = n
    row["done_step"] = done_step
    return row


def main(argv=None) -> int:
    from jax_contact.envs import playground_offline

    parser = bench_parser(__doc__)
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--names", nargs="*", default=None, help="registry names (none given: all)")
    parser.add_argument("--steps", type=positive_int, default=50, help="env steps per env")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names or () if n not in playground_offline.ENV_NAMES]
    if unknown:  # refused before anything loads (it was an error row and exit 0)
        parser.error(
            f"argument --names: unknown env(s) {unknown}; valid:"
            f" {', '.join(playground_offline.ENV_NAMES)}"
        )
    check_json_arg(parser, args.json)
    names = args.names or list(playground_offline.offline_names())
    result = {"machine": machine(), "steps": args.steps, "rows": []}
    with json_of_what_finished(args.json, result):
        for name in names:
            try:
                row = run_one(name, args.steps)
            except Exception as err:  # noqa: BLE001 - one env's failure is one row
                row = {"env": name, "error": f"{type(err).__name__}: {err}"[:300]}
            result["rows"].append(row)
            print(row, flush=True)
    cols = [
        ("env", "env", "{}"),
        ("kind", "foot kind", "{}"),
        ("truth", "truth", "{}"),
        ("dt_ms", "dt ms", "{:.0f}"),
        ("reset_compile_s", "reset comp s", "{:.1f}"),
        ("step_compile_s", "step comp s", "{:.1f}"),
        ("run_s_per_step", "s/step", "{:.4f}"),
        ("obs_ok", "obs size", "{}"),
        ("finite", "no NaN", "{}"),
        ("accuracy_standing", "acc (stand)", "{:.3f}"),
        ("scored_updates", "scored", "{}"),
        ("done_step", "done at step", "{}"),
    ]
    print_table(result["rows"], cols)
    failed = [r["env"] for r in result["rows"] if "error" in r]
    if failed:
        print(f"{len(failed)} env(s) failed (their error is in the JSON and above): {failed}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, "playground_envs"))
