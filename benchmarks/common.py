"""Shared pieces of the benchmark scripts: synthetic batches, timing, machine description,
and their command line (:func:`bench_parser`, the argument checks, :func:`run_main`)."""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import statistics
import subprocess
import time
from collections.abc import Callable
from contextlib import contextmanager

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact.types import LegMeasurement, RobotMeasurement


def synthetic_measurements(
    n_envs: int, n_legs: int = 4, nv: int = 18, n_l: int = 3, seed: int = 0
) -> LegMeasurement:
    """A (n_envs, n_legs) batch of plausible quadruped-sized measurements (float32).

    The estimator's cost does not depend on the values, only on the shapes; the values
    still look like a robot's (SPD mass matrix, ~0.3 m lever arms, feet near the ground),
    so no branch of the arithmetic runs on denormals or infinities.
    """
    rng = np.random.default_rng(seed)
    shape = (n_envs, n_legs)
    a = rng.normal(size=shape + (nv, nv)) * 0.3
    M = a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(nv)
    legs = np.arange(6, 6 + n_legs * n_l).reshape(n_legs, n_l)
    leg_dofs = np.broadcast_to(legs, shape + (n_l,))
    others = np.stack([np.setdiff1d(np.arange(nv), legs[i]) for i in range(n_legs)])
    other_dofs = np.broadcast_to(others, shape + (nv - n_l,))
    qd = rng.normal(size=shape + (nv,))
    J = rng.normal(size=shape + (3, nv)) * 0.3
    p_f = np.concatenate(
        [rng.normal(size=shape + (2,)), rng.uniform(0.0, 0.1, size=shape + (1,))], axis=-1
    )
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return LegMeasurement(
        q=f32(rng.normal(size=shape + (nv + 1,))),
        qd=f32(qd),
        qdd=f32(rng.normal(size=shape + (nv,)) * 10.0),
        tau=f32(rng.normal(size=shape + (nv,)) * 5.0),
        M=f32(M),
        h=f32(rng.normal(size=shape + (nv,)) * 5.0),
        J=f32(J),
        Jdot_qd=f32(rng.normal(size=shape + (3,))),
        p_f=f32(p_f),
        v_f=f32(np.einsum("...ij,...j->...i", J, qd)),
        foot_radius=f32(np.full(shape, 0.02)),
        leg_dofs=jnp.asarray(leg_dofs, jnp.int32),
        other_dofs=jnp.asarray(other_dofs, jnp.int32),
    )


def synthetic_robot_measurements(
    n_envs: int, n_legs: int = 4, nv: int = 18, n_l: int = 3, seed: int = 0
) -> RobotMeasurement:
    """:func:`synthetic_measurements` in the per-robot layout (leaves with axis (n_envs,)).

    The robot-level fields are the first leg's; the per-foot ones every leg's.
    """
    lm = synthetic_measurements(n_envs, n_legs, nv, n_l, seed)
    return RobotMeasurement(
        **{f: getattr(lm, f)[:, 0] for f in ("q", "qd", "qdd", "tau", "M", "h")},
        **{f: getattr(lm, f) for f in ("J", "Jdot_qd", "p_f", "v_f", "foot_radius")},
        leg_dofs=tuple(tuple(int(i) for i in row) for row in np.asarray(lm.leg_dofs[0])),
    )


def synthetic(n_envs: int, layout: str, n_legs: int = 4, nv: int = 18):
    """A synthetic batch in ``layout``: "robot" (RobotMeasurement) or "per_foot"."""
    if layout == "robot":
        return synthetic_robot_measurements(n_envs, n_legs, nv)
    if layout == "per_foot":
        return synthetic_measurements(n_envs, n_legs, nv)
    raise ValueError(f"layout must be 'robot' or 'per_foot', got {layout!r}")


def compile_and_time(
    fn: Callable, args: tuple, *, repeats: int = 20, min_time_s: float = 0.5
) -> dict:
    """Compiles ``jax.jit(fn)`` ahead of time, then times calls of the compiled function.

    Returns:
      dict with ``compile_s`` (lowering and compilation), ``median_s`` and ``p99_s`` per call
      over at least ``repeats`` calls and ``min_time_s`` seconds, ``calls``, and the
      compiled executable under ``compiled``.
    """
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))  # warm-up: first call allocates
    times = []
    start = time.perf_counter()
    while len(times) < repeats or time.perf_counter() - start < min_time_s:
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t)
        if len(times) > 100_000:
            break
    return {
        "compile_s": compile_s,
        "median_s": statistics.median(times),
        "p99_s": float(np.percentile(times, 99)),
        "calls": len(times),
        "compiled": compiled,
    }


def kernel_count(compiled) -> int:
    """Kernels one call of a compiled XLA:CPU executable launches (its entry's fusions,
    dots, copies and library calls; parameters, constants and bitcasts launch nothing)."""
    text = compiled.as_text()
    entry = text[text.index("\nENTRY") :]
    entry = entry[: entry.index("\n}")]
    free = ("parameter", "constant", "bitcast", "get-tuple-element", "tuple")
    ops = re.findall(r"^\s*(?:ROOT )?%?\S+ = \S+ ([\w-]+)\(", entry, re.M)
    return sum(op not in free for op in ops)


def pin_to_cpu(cpu: int) -> None:
    """Restricts this process to one CPU core; call before JAX creates its CPU client.

    Raises:
      ValueError: naming ``cpu`` when it is not one this process may run on, or when the
        platform cannot set the affinity (not Linux).
    """
    if not hasattr(os, "sched_setaffinity"):
        raise ValueError(f"cpu={cpu}: setting the CPU affinity needs Linux")
    allowed = sorted(os.sched_getaffinity(0))
    if cpu not in allowed:
        raise ValueError(f"cpu={cpu} is not one of this process's CPUs {allowed}")
    os.sched_setaffinity(0, {cpu})


def bench_parser(doc: str) -> argparse.ArgumentParser:
    """A benchmark script's parser: its docstring's first line as the description, every
    default in ``--help`` but None and False (the CLI's formatter)."""
    from jax_contact.train.cli_args import HelpFormatter

    return argparse.ArgumentParser(description=doc.splitlines()[0], formatter_class=HelpFormatter)


def check_json_arg(parser, path: str | None, arg: str = "--json") -> None:
    """``parser.error`` (exit 2) unless the JSON file ``path`` (None: none) can be
    written, checked before minutes of measuring rather than after them
    (:func:`jax_contact.train.cli_args.check_output_file`, the CLI's rule)."""
    from jax_contact.train.cli_args import check_output_file

    try:
        check_output_file(arg, None if path is None else str(path), (".json",))
    except ValueError as err:
        parser.error(str(err))


def check_folder_arg(parser, arg: str, folder) -> None:
    """``parser.error`` (exit 2) unless files can be created in ``folder`` (None: none)."""
    from jax_contact.train.cli_args import check_output_folder

    if folder is None:
        return
    try:
        check_output_folder(arg, folder)
    except ValueError as err:
        parser.error(str(err))


def check_env_arg(parser, arg: str, name: str) -> None:
    """``parser.error`` (exit 2) unless ``name`` is a Playground locomotion env
    (:func:`jax_contact.envs.playground_offline.check_name`), before anything loads."""
    from jax_contact.envs.playground_offline import check_name

    try:
        check_name(name)
    except ValueError as err:
        parser.error(f"argument {arg}: {err}")


def check_robot_arg(parser, arg: str, name: str, *, legged: bool = True) -> None:
    """``parser.error`` (exit 2) unless ``name`` is a robot the reproduction simulates (a
    shipped or Menagerie name or an MJCF path; ``legged``: more than one leg), before JAX
    builds anything."""
    from jax_contact.train.cli_args import ONE_LEGGED, check_robot

    try:
        check_robot(arg, name)
    except ValueError as err:
        parser.error(str(err))
    if legged and name in ONE_LEGGED:
        parser.error(f"argument {arg}: {name!r} has one leg; this benchmark runs quadruped gaits")


def run_main(main: Callable, prog: str) -> int:
    """Runs a script's ``main()`` as ``jax-contact``'s commands run: Ctrl-C (or SIGTERM)
    stops it at once with one line, ``<prog>: interrupted``, exit code 130 (143), and no
    JSON file (:mod:`jax_contact.train.interrupt`); returns ``main``'s exit code (0 for a
    non-int result)."""
    from jax_contact.train.interrupt import StopOnInterrupt

    with StopOnInterrupt(prog):
        out = main()
    return out if isinstance(out, int) else 0


def _git(*args: str) -> str | None:
    """``git <args>``'s output in the checkout this package runs from (None outside one)."""
    try:
        done = subprocess.run(
            ["git", *args],
            cwd=os.path.dirname(os.path.abspath(__file__)),
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def machine() -> dict:
    """What the numbers were measured on, when, and with which code."""
    from importlib.metadata import PackageNotFoundError, version

    def version_of(package: str) -> str | None:
        try:
            return version(package)
        except PackageNotFoundError:
            return None

    affinity = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {
        "time_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "jax_contact": version_of("jax-contact"),
        "git_commit": _git("rev-parse", "HEAD") or None,
        # Changes not committed (a benchmark of work in progress): None outside a checkout.
        "git_dirty": None if (status := _git("status", "--porcelain")) is None else bool(status),
        "jaxlib": version_of("jaxlib"),
        "mujoco": version_of("mujoco"),
        "mujoco_mjx": version_of("mujoco-mjx"),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "cpu_affinity": affinity,
        # With the persistent cache on (jax-contact's CLI turns it on), a program compiled
        # in an earlier run is loaded from it: "compile s" is then the load, not a compile.
        "compilation_cache_dir": jax.config.jax_compilation_cache_dir or None,
    }


# The per-step scores of a detector, as the accuracy benchmarks print them
# (jax_contact.metrics.ContactMetrics' names): columns of format_table.
SCORE_COLUMNS = [
    ("accuracy", "acc", "{:.3f}"),
    ("f1", "F1", "{:.3f}"),
    ("precision", "prec", "{:.3f}"),
    ("recall", "rec", "{:.3f}"),
    ("ece", "ECE", "{:.3f}"),
]


def format_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> list[str]:
    """Formats rows as fixed-width lines (header first); columns are (key, header, format)."""
    headers = [h for _, h, _ in columns]
    cells = [
        [fmt.format(r[k]) if r.get(k) is not None else "-" for k, _, fmt in columns] for r in rows
    ]
    widths = [max(len(h), 11, *(len(c[i]) for c in cells)) for i, h in enumerate(headers)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(headers, widths, strict=True))]
    lines += ["  ".join(x.rjust(w) for x, w in zip(c, widths, strict=True)) for c in cells]
    return lines


def print_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> None:
    """Prints rows as a fixed-width table."""
    print("\n".join(format_table(rows, columns)), flush=True)


@contextmanager
def json_of_what_finished(path: str | None, result: dict):
    """Writes ``result`` as JSON to ``path`` (if given) when the block ends, unless it is
    interrupted.

    What finished is still worth its JSON: if the block raises, ``result["error"]`` says
    why the rest is missing and ``result["complete"]`` is False (True otherwise), the file
    is written, and the exception goes on. A ``KeyboardInterrupt`` (Ctrl-C where
    :func:`run_main`'s handler is not installed) writes nothing, as Ctrl-C does everywhere
    else.
    """
    from jax_contact.io import write_json_atomic

    try:
        yield result
    except KeyboardInterrupt:
        path = None
        raise
    except BaseException as err:
        result["error"] = f"{type(err).__name__}: {err}"
        raise
    finally:
        if path:
            result["complete"] = "error" not in result
            write_json_atomic(path, result)
            print(f"\nwrote {path}{'' if result['complete'] else ' (incomplete)'}")
