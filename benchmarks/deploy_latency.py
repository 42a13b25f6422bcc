"""Latency of one robot's exported update (issue 17): XLA options, a fused variant, the floor.

Run::

    python -m jax_contact.benchmarks.deploy_latency --artefact go1.contact --log go1.h5 \
        --json out.json

Every option runs in its own process (``XLA_FLAGS`` and JAX's config are read when the CPU
backend starts): it loads the artefact with :func:`jax_contact.deploy.load` and feeds the
log's readings through :func:`jax_contact.train.deploy_cmd.realtime_replay`, one reading per call,
back to back (``--repeats`` passes; the median of the passes' medians is reported) and
once paced at the log's rate (median, p99, deadline misses). Also measured:

- ``raw_call``: the compiled executable called directly (no input checks, no NumPy
  conversion): what :meth:`Estimator.update` adds;
- ``dots_as_reductions``: an export whose every ``dot_general`` is rewritten as a
  broadcast multiply and a sum before XLA sees it (tiny batched dots are one XLA:CPU
  kernel each; as reductions they can fuse with their neighbours);
- the floor: the cost of one XLA:CPU kernel launch and of an empty call, from chains of
  ``n`` dependent kernels (``n`` = 1 ... 400), and the kernels of the adapter and of the
  estimator apart.

The machine is shared (the load average is printed with each result): compare within one
run, and repeat.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OPTIONS = {
    "default": {},
    "thunk_runtime_off": {"XLA_FLAGS": "--xla_cpu_use_thunk_runtime=false"},
    "eigen_single_thread": {"XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false"},
    "no_fusion_emitters": {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=false"},
    "no_xnnpack": {"XLA_FLAGS": "--xla_cpu_use_xnnpack=false"},
    "fast_math": {"XLA_FLAGS": "--xla_cpu_enable_fast_math=true"},
    "scheduler_concurrency": {
        "XLA_FLAGS": "--xla_cpu_scheduler_type=CPU_SCHEDULER_TYPE_CONCURRENCY_OPTIMIZED"
    },
    "scheduler_memory": {
        "XLA_FLAGS": "--xla_cpu_scheduler_type=CPU_SCHEDULER_TYPE_MEMORY_OPTIMIZED"
    },
    "xnn_graph_greedy": {
        "XLA_FLAGS": "--xla_cpu_experimental_xnn_graph_fusion_mode=XNN_GRAPH_FUSION_MODE_GREEDY"
    },
    "no_async_dispatch": {"JAX_CPU_ENABLE_ASYNC_DISPATCH": "false"},
    "one_core": {"_PIN": "0"},
}


# ------------------------------------------------------------------ the fused formulation


def dots_as_reductions(fn):
    """``fn`` with every ``dot_general`` (inlined through ``jit`` and custom-derivative
    calls) computed as a broadcast multiply and a sum; same values up to rounding."""
    import jax
    import jax.numpy as jnp
    from jax.extend import core

    def dot(lhs, rhs, *, dimension_numbers, preferred_element_type=None, **_):
        (lc, rc), (lb, rb) = (list(map(list, p)) for p in dimension_numbers)
        lf = [i for i in range(lhs.ndim) if i not in lc + lb]
        rf = [i for i in range(rhs.ndim) if i not in rc + rb]
        left, right = jnp.transpose(lhs, lb + lf + lc), jnp.transpose(rhs, rb + rf + rc)
        nb, nl, nr, nc = len(lb), len(lf), len(rf), len(lc)
        left = left.reshape(left.shape[: nb + nl] + (1,) * nr + left.shape[nb + nl :])
        right = right.reshape(right.shape[:nb] + (1,) * nl + right.shape[nb:])
        out = jnp.sum(left * right, axis=tuple(range(nb + nl + nr, nb + nl + nr + nc)))
        return out.astype(preferred_element_type or out.dtype)

    def run(jaxpr, consts, *args):
        env = dict(zip(jaxpr.constvars, consts, strict=True))
        env.update(zip(jaxpr.invars, args, strict=True))

        def read(v):
            return v.val if isinstance(v, core.Literal) else env[v]

        for eqn in jaxpr.eqns:
            ins = [read(v) for v in eqn.invars]
            name = eqn.primitive.name
            if name == "dot_general":
                outs = [dot(*ins, **eqn.params)]
            elif name in ("jit", "pjit"):
                sub = eqn.params["jaxpr"]
                outs = run(sub.jaxpr, sub.consts, *ins)
            elif name in ("custom_jvp_call", "custom_vjp_call"):
                sub = eqn.params["call_jaxpr"]
                outs = run(sub.jaxpr, sub.consts, *ins)
            else:
                outs = eqn.primitive.bind(*ins, **eqn.params)
                outs = outs if eqn.primitive.multiple_results else [outs]
            env.update(zip(eqn.outvars, outs, strict=True))
        return [read(v) for v in jaxpr.outvars]

    def rewritten(*args):
        closed = jax.make_jaxpr(fn)(*args)
        out = run(closed.jaxpr, closed.consts, *jax.tree.leaves(args))
        return jax.tree.unflatten(jax.tree.structure(jax.eval_shape(fn, *args)), out)

    return rewritten


def export_variant(artefact: Path, out: Path) -> None:
    """Re-exports ``artefact``'s robot and parameters with :func:`dots_as_reductions`."""
    import jax.numpy as jnp

    from jax_contact import export
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.deploy_cmd import params_and_terrain

    header, _ = export.read_artefact(artefact)
    params, terrain = params_and_terrain(header)
    robot = load_robot(header["robot"]["source"], foot_names=header["robot"]["feet"])
    update, init = export.robot_update_fn(robot.mj_model, robot.description, params, terrain)
    state, key = init(int(header["key"]["seed"]))
    zeros = [jnp.zeros(r["shape"], jnp.float32) for r in header["readings"]]
    exported, _ = export.export_flat(dots_as_reductions(update), state, key, *zeros)
    variant = dict(header, created=header["created"] + " (dots_as_reductions)")
    export.write_artefact(out, variant, bytes(exported.serialize()))


# -------------------------------------------------------------------------- child process


def _readings(log: str, steps: int):
    import numpy as np

    from jax_contact.io import read_log

    arrays, _ = read_log(log)
    return {
        k: np.ascontiguousarray(arrays[f"readings/{k}"][:steps, 0], np.float32)
        for k in ("qpos", "qvel", "qacc", "tau")
    }


def child(artefact: str, log: str, steps: int, repeats: int) -> dict:
    import numpy as np

    from jax_contact import deploy
    from jax_contact.benchmarks.common import kernel_count
    from jax_contact.train.deploy_cmd import realtime_replay

    t0 = time.perf_counter()
    est = deploy.load(artefact)
    compile_s = time.perf_counter() - t0
    readings = _readings(log, steps)
    period = 1.0 / est.rate_hz
    passes = []
    for _ in range(repeats):
        one = realtime_replay(est, readings, period_s=period, pace=False)
        passes.append(float(1e6 * np.median(one["latency_s"])))
    paced = realtime_replay(est, readings, period_s=period, pace=True)
    lat = 1e6 * paced["latency_s"]
    # The executable alone, on device-resident arguments.
    belief = est.init()
    args = [belief.state, belief.key] + [readings[n][0] for n in est.reading_names]
    raw = []
    for _ in range(repeats):
        ts = np.empty(len(readings["qpos"]))
        for i in range(len(ts)):
            t = time.perf_counter()
            out = est._call(*args)
            out[2].block_until_ready()
            ts[i] = time.perf_counter() - t
        raw.append(float(1e6 * np.median(ts)))
    return {
        "kernels": kernel_count(est._call),
        "compile_s": compile_s,
        "median_us": float(np.median(passes)),
        "passes_us": passes,
        "raw_call_us": float(np.median(raw)),
        "paced": {
            "median_us": float(np.median(lat)),
            "p99_us": float(np.percentile(lat, 99)),
            "max_us": float(lat.max()),
            "deadline_misses": int(paced["deadline_misses"]),
        },
        "load_avg_1min": os.getloadavg()[0],
    }


def floor(repeats: int) -> dict:
    """Per-kernel launch cost and empty-call cost of XLA:CPU, and the adapter/estimator split."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jax_contact.benchmarks.common import kernel_count

    def chain(n):
        def f(x):
            for _ in range(n):  # a dot each: XLA:CPU never fuses them, one kernel per dot
                x = jnp.tanh(x @ x)
            return x

        return f

    x = jnp.eye(4, dtype=jnp.float32) * 0.5
    rows = []
    for n in (1, 50, 100, 200, 400):
        c = jax.jit(chain(n)).lower(x).compile()
        meds = []
        for _ in range(repeats):
            ts = np.empty(1000)
            for i in range(len(ts)):
                t = time.perf_counter()
                c(x).block_until_ready()
                ts[i] = time.perf_counter() - t
            meds.append(1e6 * np.median(ts))
        rows.append({"n": n, "kernels": kernel_count(c), "median_us": float(np.median(meds))})
    k = np.array([r["kernels"] for r in rows], float)
    t = np.array([r["median_us"] for r in rows])
    slope, intercept = np.polyfit(k, t, 1)
    return {"chain": rows, "us_per_kernel": float(slope), "empty_call_us": float(intercept)}


def split(artefact: str, repeats: int) -> dict:
    """Kernels and latency of the adapter alone and of the estimator alone (jitted)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    from mujoco import mjx

    import jax_contact as jc
    from jax_contact.adapter import prepare, robot_measurement
    from jax_contact.benchmarks.common import kernel_count
    from jax_contact.envs.robots import load_robot
    from jax_contact.export import read_artefact
    from jax_contact.train.deploy_cmd import params_and_terrain

    header, _ = read_artefact(artefact)
    params, terrain = params_and_terrain(header)
    robot = load_robot(header["robot"]["source"], foot_names=header["robot"]["feet"])
    desc = robot.description
    m = mjx.put_model(robot.mj_model)
    template = mjx.make_data(m)

    def adapter(q, v, a, t):
        d = prepare(m, template.replace(qpos=q, qvel=v))
        return robot_measurement(m, d, desc, qdd=a, tau=t, include_passive=True)

    q = jnp.asarray(robot.home_qpos, jnp.float32)
    v = jnp.zeros(desc.nv, jnp.float32)
    ca = jax.jit(adapter).lower(q, v, v, v).compile()
    meas = ca(q, v, v, v)
    belief = jax.tree.map(lambda x: x[0], jc.init_belief_batch(params, 1, desc.n_legs))
    key = jax.random.key(0)
    ce = jax.jit(lambda b, me, k: jc.step_robot(params, terrain, b, me, key=k))
    ce = ce.lower(belief, meas, key).compile()

    def timed(fn):
        meds = []
        for _ in range(repeats):
            ts = np.empty(1000)
            for i in range(len(ts)):
                t = time.perf_counter()
                jax.block_until_ready(fn())
                ts[i] = time.perf_counter() - t
            meds.append(1e6 * np.median(ts))
        return float(np.median(meds))

    return {
        "adapter": {"kernels": kernel_count(ca), "median_us": timed(lambda: ca(q, v, v, v))},
        "estimator": {
            "kernels": kernel_count(ce),
            "median_us": timed(lambda: ce(belief, meas, key)),
        },
    }


def profile(artefact: str, calls: int = 50) -> dict:
    """Kernel times of the (jitted, not exported) robot update under ``jax.profiler``.

    Returns, per named scope (``adapter``, ``estimator``, the rest), the kernels and their
    summed time per call, the median kernel duration, the ten longest kernels and the
    wall time of a call outside the profiler: the gap between the kernels' sum and the
    wall time is launch overhead.
    """
    import collections
    import glob
    import gzip
    import re
    import statistics
    import tempfile

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jax_contact import export
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.deploy_cmd import params_and_terrain

    header, _ = export.read_artefact(artefact)
    params, terrain = params_and_terrain(header)
    robot = load_robot(header["robot"]["source"], foot_names=header["robot"]["feet"])
    update, init = export.robot_update_fn(robot.mj_model, robot.description, params, terrain)
    state, key = init(0)
    q = jnp.asarray(robot.home_qpos, jnp.float32)
    v = jnp.zeros(robot.description.nv, jnp.float32)
    args = (state, jax.random.key_data(key), q, v, v, v)

    def raw(s, k, *r):
        out = update(s, jax.random.wrap_key_data(k), *r)
        return out[0], jax.random.key_data(out[1]), out[2]

    compiled = jax.jit(raw).lower(*args).compile()
    text = compiled.as_text()
    module = re.match(r"HloModule (\S+?),", text).group(1)
    entry = text[text.index("\nENTRY") :]
    names = dict(
        re.findall(r'^\s*(?:ROOT )?%?([\w.\-]+) = [^\n]*?metadata=\{op_name="([^"]*)"', entry, re.M)
    )
    wall = []
    for _ in range(2000):
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        wall.append(time.perf_counter() - t)
    with tempfile.TemporaryDirectory(prefix="deploy_profile.") as out_dir:
        with jax.profiler.trace(out_dir):
            for _ in range(calls):
                jax.block_until_ready(compiled(*args))
        (path,) = glob.glob(os.path.join(out_dir, "**", "*.trace.json.gz"), recursive=True)
        with gzip.open(path) as f:
            events = json.load(f)["traceEvents"]
    per_scope = collections.defaultdict(list)
    per_op = collections.defaultdict(float)
    for e in events:
        a = e.get("args", {})
        if e.get("ph") == "X" and a.get("hlo_module") == module and "hlo_op" in a:
            name = names.get(a["hlo_op"], "")
            scope = next((s for s in ("adapter", "estimator") if s in name.split("/")), "other")
            per_scope[scope].append((a["hlo_op"], e["dur"]))
            per_op[(scope, a["hlo_op"], name[-60:])] += e["dur"] / calls
    scopes = {
        s: {
            "kernels": len({op for op, _ in ks}),
            "kernel_us_per_call": sum(d for _, d in ks) / calls,
            "median_kernel_us": float(np.median([d for _, d in ks])),
        }
        for s, ks in per_scope.items()
    }
    top = sorted(per_op.items(), key=lambda kv: -kv[1])[:10]
    return {
        "wall_us": 1e6 * statistics.median(wall),
        "kernel_us_per_call": sum(s["kernel_us_per_call"] for s in scopes.values()),
        "scopes": scopes,
        "top_kernels": [{"scope": k[0], "op": k[1], "name": k[2], "us": us} for k, us in top],
    }


# ---------------------------------------------------------------------------------- main


def _spawn(what: str, env_extra: dict, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    env.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    env.setdefault("JAX_PLATFORMS", "cpu")  # every option is an XLA:CPU one, on a GPU host too
    pin = env_extra.pop("_PIN", None)
    env.update(env_extra)
    cmd = [sys.executable, "-m", "jax_contact.benchmarks.deploy_latency", "--child", what]
    cmd += ["--artefact", str(args.artefact), "--log", str(args.log)]
    cmd += ["--steps", str(args.steps), "--repeats", str(args.repeats)]
    if pin is not None:
        cmd = ["taskset", "-c", pin] + cmd
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1:] or ["failed"]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    # Imported here: a child process reads its XLA_FLAGS before anything imports JAX.
    from jax_contact.benchmarks.common import bench_parser, check_json_arg
    from jax_contact.train.cli_args import check_input_file, positive_int

    parser = bench_parser(__doc__)
    parser.add_argument("--artefact", required=True, help="a .contact file (jax-contact export)")
    parser.add_argument("--log", required=True, help="an .h5 log of the same robot and rate")
    parser.add_argument("--steps", type=positive_int, default=1600, help="readings per pass")
    parser.add_argument("--repeats", type=positive_int, default=5, help="passes per option")
    parser.add_argument(
        "--options",
        nargs="+",
        default=list(OPTIONS) + ["dots_as_reductions"],
        choices=list(OPTIONS) + ["dots_as_reductions"],
        help="XLA options to time the exported program under",
    )
    parser.add_argument(
        "--no-floor", action="store_true", help="skip the floor, split and profile runs"
    )
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.child is None:  # the parent checks once, before any child compiles
        for arg, path in (("--artefact", args.artefact), ("--log", args.log)):
            try:
                check_input_file(arg, path)
            except ValueError as err:
                parser.error(str(err))
        check_json_arg(parser, args.json)
    if args.child == "floor":
        print(json.dumps(floor(args.repeats)))
        return {}
    if args.child == "split":
        print(json.dumps(split(args.artefact, args.repeats)))
        return {}
    if args.child == "profile":
        print(json.dumps(profile(args.artefact)))
        return {}
    if args.child is not None:
        print(json.dumps(child(args.artefact, args.log, args.steps, args.repeats)))
        return {}

    from jax_contact.benchmarks.common import json_of_what_finished, machine, print_table

    results = {"machine": machine()}
    # What finished is written if an option fails late (a missing taskset, a child's
    # error); the re-exported variant goes to a temporary folder, not beside the input.
    with json_of_what_finished(args.json, results), tempfile.TemporaryDirectory() as tmp:
        for name in args.options:
            if name == "dots_as_reductions":
                variant = Path(tmp) / "variant.dots.contact"
                export_variant(Path(args.artefact), variant)
                res = _spawn(name, {}, argparse.Namespace(**{**vars(args), "artefact": variant}))
            else:
                res = _spawn(name, dict(OPTIONS[name]), args)
            results[name] = {"env": OPTIONS.get(name, {}), **res}
            print(f"{name:24s} {'error: ' + str(res['error']) if 'error' in res else 'done'}")
        if not args.no_floor:
            for what in ("floor", "split", "profile"):
                results[what] = _spawn(what, {}, args)
                print(f"{what:24s} {json.dumps(results[what])}", flush=True)
        rows = [
            {
                "option": name,
                **results[name],
                "p99_us": results[name]["paced"]["p99_us"],
                "deadline_misses": results[name]["paced"]["deadline_misses"],
            }
            for name in args.options
            if "error" not in results[name]
        ]
        print_table(
            rows,
            [
                ("option", "option", "{}"),
                ("kernels", "kernels", "{}"),
                ("compile_s", "compile s", "{:.1f}"),
                ("median_us", "update us", "{:.1f}"),
                ("raw_call_us", "raw us", "{:.1f}"),
                ("p99_us", "paced p99 us", "{:.1f}"),
                ("deadline_misses", "misses", "{}"),
            ],
        )
        failed = [name for name in args.options if "error" in results[name]]
        if failed:
            raise RuntimeError(f"options {failed} failed in their processes (their 'error')")
    return results


if __name__ == "__main__":
    from jax_contact.benchmarks.common import run_main

    raise SystemExit(run_main(main, "deploy_latency"))
