"""The estimator side by side with MJX physics, a per-robot NumPy implementation, and sharded.

Run::

    python -m jax_contact.benchmarks.versus --json out/bench/versus.json [--envs 1024 4096]

1. Ratio of one estimator update (with and without the adapter's extraction of its
   inputs from ``mjx.Data``) to one ``mjx.step`` of Go1 at the same batch size, with the
   per-robot measurement (the wrapper's) and with per-foot copies.
   Calls are interleaved (physics, estimator, adapter, ...) and medians taken, so load
   changes on the machine hit every contender alike.
2. Speed-up over a float64 NumPy implementation (the test oracle, ``tests/oracle.py``,
   with Algorithm 1 by 500 NumPy draws) that processes one robot at a time, as existing
   single-robot estimators do: a subset of robots is timed and the time scaled to the batch.
3. Sharding: the env batch (rounded up to a multiple of 8) split over 8 simulated CPU
   devices (``XLA_FLAGS=--xla_force_host_platform_device_count=8``, set in a subprocess)
   with ``jax.sharding``; the result is compared with the unsharded run.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jax_contact as jc
from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    json_of_what_finished,
    machine,
    print_table,
    run_main,
    synthetic_measurements,
)
from jax_contact.train.cli_args import positive_int

# The folder that holds the jax_contact package (the checkout, or site-packages once
# installed from a wheel): the sharding subprocess imports the library from there, and
# never runs inside the package folder, whose types.py / io.py would hide the standard
# library's. The NumPy oracle is the test suite's (tests/oracle.py), in a checkout only.
SITE = Path(jc.__file__).resolve().parents[1]
ORACLE_DIR = SITE / "tests"
MODES = ("quadrature", "monte_carlo")


def _timed(fn, *args) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t


def ratio_vs_mjx(n_envs: int, repeats: int = 15) -> dict:
    """Median times of mjx.step, the estimator (both modes, both measurement layouts) and
    the adapter, interleaved.

    ``quadrature`` and ``monte_carlo`` are the per-robot layout (``RobotMeasurement``, what
    the observation wrapper runs); ``..._per_foot`` the per-foot copies (``LegMeasurement``).
    """
    from mujoco import mjx

    from jax_contact.adapter import leg_measurements, prepare, robot_measurement
    from jax_contact.envs.robots import load_robot

    robot = load_robot("go1")
    robot.mj_model.opt.timestep = 0.0025
    m = mjx.put_model(robot.mj_model)
    desc = robot.description
    d0 = mjx.make_data(m).replace(qpos=jnp.asarray(robot.home_qpos, jnp.float32))
    data = jax.vmap(lambda _: d0)(jnp.arange(n_envs))

    physics = jax.jit(jax.vmap(lambda d: mjx.step(m, d)))
    extractors = {
        "": jax.jit(jax.vmap(lambda dd: robot_measurement(m, prepare(m, dd), desc))),
        "_per_foot": jax.jit(jax.vmap(lambda dd: leg_measurements(m, prepare(m, dd), desc))),
    }
    contenders = {"mjx_step": (physics, (data,))}
    compile_s = {}
    for layout, extract in extractors.items():
        # The adapter's first call (trace + compile + run) is here, where its output is
        # needed; timed, so its compile time is not the cached second call's (it read 0.00).
        t = time.perf_counter()
        meas = jax.block_until_ready(extract(data))
        compile_s[f"adapter{layout}"] = time.perf_counter() - t
        contenders[f"adapter{layout}"] = (extract, (data,))
        for mode in MODES:
            params = jc.make_params(jc.make_noise(desc.nv), touchdown=mode)
            belief = jc.init_belief_batch(params, n_envs, desc.n_legs)

            def update(b, mm, k, params=params):
                return jc.step_batch(params, jc.flat(), b, mm, key=k)

            def full(b, d, k, params=params, extract=extract):
                return jc.step_batch(params, jc.flat(), b, extract(d), key=k)

            contenders[f"{mode}{layout}"] = (jax.jit(update), (belief, meas, jax.random.key(0)))
            contenders[f"{mode}{layout}+adapter"] = (
                jax.jit(full),
                (belief, data, jax.random.key(0)),
            )

    for name, (fn, args) in contenders.items():
        if name not in compile_s:
            compile_s[name] = _timed(fn, *args)  # first call: trace + compile + run
    times = {name: [] for name in contenders}
    for _ in range(repeats):
        for name, (fn, args) in contenders.items():
            times[name].append(_timed(fn, *args))
    med = {name: statistics.median(v) for name, v in times.items()}
    runs = [f"{mode}{layout}" for layout in extractors for mode in MODES]
    return {
        "envs": n_envs,
        "median_ms": {k: 1e3 * v for k, v in med.items()},
        "first_call_s": compile_s,
        "ratio": {r: med[r] / med["mjx_step"] for r in runs},
        "ratio_with_adapter": {r: med[f"{r}+adapter"] / med["mjx_step"] for r in runs},
    }


def numpy_speedup(n_envs: int = 4096, n_robots_timed: int = 8) -> dict:
    """JAX batched (Monte-Carlo 500) vs the float64 NumPy oracle, one robot at a time."""
    if not (ORACLE_DIR / "oracle.py").is_file():
        raise FileNotFoundError(
            f"the NumPy comparison runs the test suite's float64 oracle, {ORACLE_DIR}/oracle.py,"
            " which a source checkout has and an installed wheel does not"
        )
    sys.path.insert(0, str(ORACLE_DIR))
    import oracle
    from scipy import special

    rng = np.random.default_rng(0)

    def td_numpy(gap, s_pf, s_pi, u, s_u, dt, n=500):
        # Algorithm 1 with NumPy draws: p_i truncated to p_i <= p_f by inverse CDF.
        p_f = gap + s_pf * rng.standard_normal(n)
        v = rng.uniform(1e-12, 1.0, n)
        p_i = s_pi * special.ndtri(v * special.ndtr(p_f / s_pi))
        arg = (-(p_f - p_i) / dt - u) / s_u
        return np.array([special.ndtr(arg).mean(), special.ndtr(-arg).mean()])

    meas = synthetic_measurements(n_robots_timed, 4, 18)
    params = jc.make_params(jc.make_noise(18), touchdown="monte_carlo")
    # The oracle's parameters, field by field from the JAX ones (names are shared).
    noise = {
        f: np.asarray(getattr(params.noise, f), np.float64)
        for f in jc.NoiseParams.__dataclass_fields__
    }
    scalars = {
        f: float(getattr(params, f))
        for f in oracle.Params.__dataclass_fields__
        if f not in noise and f not in ("force_rows", "unilateral")
    }
    p = oracle.Params(**noise, **scalars)
    terrain = oracle.Flat(0.0, 0.2)
    leaves = jax.tree.map(np.asarray, meas)
    beliefs = [oracle.init_belief(p) for _ in range(4)]
    t = time.perf_counter()
    for r in range(n_robots_timed):
        for leg in range(4):
            m = oracle.Meas(
                **{
                    f: np.asarray(getattr(leaves, f)[r, leg], np.float64)
                    for f in oracle.Meas.__dataclass_fields__
                }
            )
            oracle.step(p, terrain, beliefs[leg], m, td_fn=td_numpy)
    per_robot = (time.perf_counter() - t) / n_robots_timed

    big = synthetic_measurements(n_envs, 4, 18)
    belief = jc.init_belief_batch(params, n_envs, 4)
    update = jax.jit(lambda b, mm, k: jc.step_batch(params, jc.flat(0.0, 0.2), b, mm, key=k))
    _timed(update, belief, big, jax.random.key(0))
    jax_s = statistics.median(_timed(update, belief, big, jax.random.key(0)) for _ in range(7))
    numpy_s = per_robot * n_envs
    return {
        "envs": n_envs,
        "numpy_robots_timed": n_robots_timed,
        "numpy_s_per_robot": per_robot,
        "numpy_s_scaled": numpy_s,
        "jax_s": jax_s,
        "speedup": numpy_s / jax_s,
    }


SHARD_SCRIPT = r"""
import json, statistics, time, jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
import jax_contact as jc
from jax_contact.benchmarks.common import synthetic_measurements
n = int(__import__("sys").argv[1])
params = jc.make_params(jc.make_noise(18), touchdown="quadrature")
meas = synthetic_measurements(n, 4, 18)
belief = jc.init_belief_batch(params, n, 4)
upd = jax.jit(lambda b, m: jc.step_batch(params, jc.flat(), b, m, key=jax.random.key(0)))
ref_b, ref_d = upd(belief, meas)
mesh = Mesh(np.array(jax.devices()), ("envs",))
shard = NamedSharding(mesh, P("envs"))
sb, sm = jax.device_put((belief, meas), shard)
out_b, out_d = upd(sb, sm)
err = float(jnp.max(jnp.abs(out_d.p_contact - ref_d.p_contact)))
def t(f, *a):
    s = time.perf_counter(); jax.block_until_ready(f(*a)); return time.perf_counter() - s
tu = statistics.median(t(upd, belief, meas) for _ in range(7))
ts = statistics.median(t(upd, sb, sm) for _ in range(7))
print(json.dumps({"devices": len(jax.devices()), "envs": n, "max_abs_diff": err,
  "sharding_of_output": str(out_d.p_contact.sharding.spec),
  "unsharded_leg_updates_per_s": 4 * n / tu, "sharded_leg_updates_per_s": 4 * n / ts}))
"""


def shard_batch(n_envs: int, devices: int) -> int:
    """The batch of the sharding check: ``n_envs`` rounded up to a multiple of ``devices``,
    since ``jax.sharding`` splits the env axis into equal parts (4 envs cannot go on 8
    devices)."""
    if n_envs < 1 or devices < 1:
        raise ValueError(f"n_envs and devices must be >= 1, got {n_envs} and {devices}")
    return -(-n_envs // devices) * devices


def sharded(n_envs: int = 4096, devices: int = 8, *, script: str | None = None) -> dict:
    """Runs :data:`SHARD_SCRIPT` in a subprocess with ``devices`` simulated CPU devices.

    The batch is ``n_envs`` rounded up to a multiple of ``devices`` (:func:`shard_batch`);
    the result holds both under ``envs`` and ``envs_requested``.

    Raises:
      RuntimeError: the subprocess failed; the message holds the end of its stderr.
    """
    n = shard_batch(n_envs, devices)
    env = dict(os.environ)
    # The simulated devices are the CPU's, on a GPU host too (where jax.devices() would be
    # the one GPU, and the parent would hold 75 % of its memory); the user's own XLA
    # flags are kept.
    env["JAX_PLATFORMS"] = "cpu"
    flags = f"--xla_force_host_platform_device_count={devices}"
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {flags}".strip()
    env["PYTHONPATH"] = str(SITE) + os.pathsep + env.get("PYTHONPATH", "")
    res = subprocess.run(
        [sys.executable, "-c", script or SHARD_SCRIPT, str(n)],
        env=env,
        capture_output=True,
        text=True,
        cwd=SITE,
    )
    if res.returncode != 0:
        tail = "\n".join(res.stderr.strip().splitlines()[-15:])
        raise RuntimeError(
            f"the sharding check ({n} envs over {devices} CPU devices, in a subprocess) exited"
            f" with code {res.returncode}; the end of its stderr:\n{tail}"
        )
    return {**json.loads(res.stdout.strip().splitlines()[-1]), "envs_requested": n_envs}


def check_sizes(envs, numpy_robots: int = 1) -> None:
    """Raises ValueError naming the size if a batch size is not an int >= 1, before
    anything is compiled (a bad size used to fail only after minutes of benchmarks)."""
    for n in envs:
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"--envs: every batch size must be an int >= 1, got {n!r}")
    if not envs:
        raise ValueError("--envs: give at least one batch size")
    if isinstance(numpy_robots, bool) or not isinstance(numpy_robots, int) or numpy_robots < 1:
        raise ValueError(f"--numpy-robots must be an int >= 1, got {numpy_robots!r}")


def run(envs, numpy_robots: int = 8, *, into: dict | None = None) -> dict:
    """Runs the three benchmarks (module docstring) and prints their tables.

    Args:
      envs: batch sizes of the ratio to ``mjx.step``; the largest is also the size of the
        NumPy comparison and (rounded up to a multiple of 8) of the sharding check.
      numpy_robots: robots the NumPy implementation is timed on.
      into: a dict filled with each result as soon as it is measured, so that a caller
        still has what finished when a later part fails.

    Returns:
      ``into`` (or a new dict) with ``machine``, ``ratio_vs_mjx_step``,
      ``speedup_vs_numpy``, ``numpy`` and ``sharding``.
    """
    envs = list(envs)
    check_sizes(envs, numpy_robots)
    result = {} if into is None else into
    result["machine"] = machine()
    ratios = result.setdefault("ratio_vs_mjx_step", {})
    for n in envs:
        r = ratio_vs_mjx(n)
        ratios[str(n)] = {
            **r["ratio"],
            "with_adapter": r["ratio_with_adapter"],
            "median_ms": r["median_ms"],
            # First call: trace + compile (or a load from the persistent cache) + one run.
            "first_call_s": r["first_call_s"],
        }
        print(f"# {n} envs, median ms per call (interleaved) and the first call:", flush=True)
        print_table(
            [
                {"what": k, "ms": v, "first": r["first_call_s"][k]}
                for k, v in r["median_ms"].items()
            ],
            [
                ("what", "call", "{}"),
                ("ms", "median ms", "{:.2f}"),
                ("first", "first call s", "{:.2f}"),
            ],
        )
        print(f"# {n} envs, the update's time over one mjx.step's:")
        print_table(
            [
                {"what": k, "alone": v, "adapter": r["ratio_with_adapter"][k]}
                for k, v in r["ratio"].items()
            ],
            [
                ("what", "update", "{}"),
                ("alone", "x mjx.step", "{:.3f}"),
                ("adapter", "with adapter", "{:.3f}"),
            ],
        )
    try:
        sp = numpy_speedup(max(envs), numpy_robots)
    except FileNotFoundError as err:  # an installed wheel: no oracle to time
        result["numpy"] = {"skipped": str(err)}
        print(f"# NumPy comparison skipped: {err}")
    else:
        result["speedup_vs_numpy"] = sp["speedup"]
        result["numpy"] = sp
        print(
            f"# NumPy float64, one robot at a time ({sp['numpy_robots_timed']} robots timed,"
            f" scaled to {sp['envs']}): {sp['numpy_s_scaled']:.2f} s; JAX batched"
            f" {sp['jax_s'] * 1e3:.1f} ms; speed-up {sp['speedup']:.0f}x (both the estimator"
            " alone with the Monte-Carlo touch-down of 500 draws, the oracle's, on synthetic"
            " measurements: a program of its own, not a row above)"
        )
    sh = sharded(max(envs))
    result["sharding"] = sh
    print(
        f"# sharded over {sh['devices']} virtual CPU devices (XLA's forced host device count"
        f" on {os.cpu_count()} cores: a check that sharding keeps the beliefs, not a"
        f" speed-up; {sh['envs']} envs): max |diff|"
        f" {sh['max_abs_diff']:.2g}, {sh['sharded_leg_updates_per_s']:.3g} vs unsharded"
        f" {sh['unsharded_leg_updates_per_s']:.3g} leg-updates/s"
    )
    return result


def main(argv=None) -> dict:
    parser = bench_parser(__doc__)
    # The CLI's size type: "argument --envs: must be an int >= 1", as every script says it.
    parser.add_argument(
        "--envs", type=positive_int, nargs="+", default=[1024, 4096], help="batch sizes (envs)"
    )
    parser.add_argument(
        "--numpy-robots", type=positive_int, default=8, help="robots the float64 NumPy oracle runs"
    )
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args(argv)
    check_json_arg(parser, args.json)
    try:
        check_sizes(args.envs, args.numpy_robots)
    except ValueError as err:
        parser.error(str(err))

    result: dict = {}
    with json_of_what_finished(args.json, result):
        run(args.envs, args.numpy_robots, into=result)
    return result


if __name__ == "__main__":
    raise SystemExit(run_main(main, "versus"))
