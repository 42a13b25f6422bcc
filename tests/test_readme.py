"""The README runs as written (issue 18): its Python blocks, its commands, what it promises.

**Python blocks.** Every fenced ``python`` block of README.md runs. The blocks of one
section (a ``##`` heading) run cumulatively, in README order, in one fresh subprocess from
the repository root (a block may use what an earlier block of *its* section defined, never
another section's); then the section's checks in :data:`CHECKS` run in the same process on
the variables the blocks left. A section with a block and no checks fails.

**Commands.** Every line that starts with ``jax-contact `` inside a fenced block runs, in
README order, as the installed entry point, in one temporary folder (so ``out/...`` lands
there and a later command reads what an earlier one wrote: ``evaluate`` the log of
``simulate``, ``policy-eval`` the run of ``train``). Such a pair runs in order in one chain
(:data:`CHAIN`, which also puts commands that share compiled programs in one); the chains
run two at a time, which changes nothing but the wall time.
Sizes: for each command, the flags of :data:`TINY` replace the README's value of the same
flag (with all its values) or are appended. The long commands run at their smallest size
flags: ``demo`` with ``--size tiny`` (2 envs for 0.5 s; still every scenario, so mostly
compilation), ``train`` with ``--config tiny`` (160 steps of 8 envs), only the variant
that ``policy-eval`` reads (each variant compiles its own environment and PPO step:
minutes) and no final evaluation (``policy-eval`` is one), ``bench`` with 1 and 8 envs
and 100 latency calls, ``rates`` with one scene; all compiled at XLA's optimisation level
0 (:data:`_ENV`). ``reproduce --size tiny`` is ``demo --size tiny``'s job and is
checked to be (:data:`SAME_JOB`), not run again. Checked:
exit code 0, no traceback, no XLA C++ log line (``E1201 ... Very slow compile?``), and
every file the command is documented to write exists (:func:`expected_outputs`). The README
must list every command of ``jax-contact --help``. ``pytest -s`` prints each command's wall
time and the CPU time of them all.

These runs are most of this file's time (2026-12-01: 1191 of the cold suite's 2841
CPU-s). Measured 2026-12-02 on an idle 2-core host, each alone with an empty compilation
cache: ``demo --size tiny`` 200 s wall (246 CPU-s), ``train --config tiny`` 172 s (230),
``bench`` 150 s (190); in the whole cold suite (``make test``, 20 min 43 s) this file's
commands took 736 s on their worker. ``docs/performance.md`` has the warm numbers.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import io
import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from jax_contact.train import cli, progress

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
_ENTRY = Path(sys.executable).parent / "jax-contact"
CLI = [str(_ENTRY)] if _ENTRY.exists() else [sys.executable, "-m", "jax_contact.train.cli"]

# --------------------------------------------------------------------- README parsing

_FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def sections(text: str = README) -> dict[str, list[str]]:
    """``## heading`` -> its ``python`` blocks, in order (sections without one: absent)."""
    out: dict[str, list[str]] = {}
    parts = re.split(r"^## (.+)$", text, flags=re.M)
    for heading, body in zip(parts[1::2], parts[2::2], strict=True):
        blocks = [code for lang, code in _FENCE.findall(body) if lang == "python"]
        if blocks:
            out[heading.strip()] = blocks
    return out


def commands(text: str = README) -> list[list[str]]:
    """Every ``jax-contact ...`` line of a fenced block, as arguments, comments removed."""
    out = []
    for _, code in _FENCE.findall(text):
        for line in code.splitlines():
            if line.startswith("jax-contact "):
                out.append(shlex.split(line, comments=True)[1:])
    return out


# --------------------------------------------------------------------- Python blocks

# Section -> code run after its blocks, in the same process: what the section promises.
CHECKS = {
    "Using the estimator": """
import numpy as np
p = np.asarray(diag.p_contact)
assert p.shape == (n_envs, desc.n_legs) == (4, 4), p.shape
for name in ("p_dynamics", "p_takeoff", "p_touchdown"):
    assert np.shape(getattr(diag, name)) == p.shape, name
assert dt == mj_model.opt.timestep == 0.004  # the shipped Go1 model's own period
assert np.isfinite(p).all() and (p > 0.8).all(), p  # standing on all four feet
""",
    "In an RL environment": """
from jax_contact.envs.wrapper import PlaygroundContactWrapper
assert isinstance(env, PlaygroundContactWrapper), type(env)
inner = env.unwrapped.observation_size["state"][0]
assert env.observation_size["state"][0] == inner + 4, env.observation_size  # one per foot
""",
}


def test_every_python_section_has_checks():
    assert set(sections()) == set(CHECKS), "add the section's checks to CHECKS"


@pytest.mark.parametrize("heading", sorted(CHECKS))
def test_python_blocks_run_as_written(heading):
    blocks = sections()[heading]
    script = "\n\n".join([*blocks, "# --- tests/test_readme.py's checks", CHECKS[heading]])
    res = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert res.returncode == 0, f"{heading}:\n{res.stderr[-3000:]}"


# ---------------------------------------------------------------------------- commands

TINY: dict[str, dict[str, list[str]]] = {
    "demo": {"--size": ["tiny"]},
    "reproduce": {"--size": ["tiny"]},
    "simulate": {"--envs": ["2"], "--duration": ["0.5"]},
    "evaluate": {},
    "rates": {"--scenes": ["planar_leg"]},
    # One env: the throughput's Monte-Carlo program is then the latency's own (from the
    # compilation cache); 100 timed calls per latency row instead of 10,000.
    "bench": {"--envs": ["1"], "--versus-envs": ["8"], "--latency-calls": ["100"]},
    # One variant, the one policy-eval reads: each costs minutes of compilation. No final
    # evaluation: the README's policy-eval, run next on this run, is that evaluation.
    "train": {"--config": ["tiny"], "--variants": ["truth"], "--eval-envs": ["0"]},
    "policy-eval": {"--envs": ["2"]},
    "estimate": {},  # the shipped 2 s recording
}


def tiny(argv: list[str]) -> list[str]:
    """``argv`` with the flags of :data:`TINY` for its command: each replaces the same flag
    and all its values, or is appended."""
    sizes = TINY[argv[0]]
    out, i = [], 0
    while i < len(argv):
        if argv[i] in sizes:
            i += 1
            while i < len(argv) and not argv[i].startswith("--"):
                i += 1
            continue
        out.append(argv[i])
        i += 1
    for flag, values in sizes.items():
        out += [flag, *values]
    return out


def _options(argv: list[str]) -> dict[str, list[str]]:
    opts: dict[str, list[str]] = {}
    flag = None
    for a in argv[1:]:
        if a.startswith("--"):
            flag = a
            opts[flag] = []
        elif flag is not None:
            opts[flag].append(a)
    return opts


def expected_outputs(argv: list[str]) -> list[str]:
    """The files a command is documented to write (relative to its folder)."""
    cmd, opts = argv[0], _options(argv)
    files = list(opts.get("--json", []))
    if cmd in ("demo", "reproduce"):
        out = opts.get("--out", [f"out/{cmd}"])[0]
        files += [f"{out}/table3.json", f"{out}/ablation.json", f"{out}/section3_fig5.png"]
        files += [f"{out}/table3_trot_fig7.png", f"{out}/reliability_trot.png"]
    elif cmd == "simulate":
        files.append(argv[1])
    elif cmd == "estimate":
        out = opts.get("--out", ["out/estimate"])[0]
        files += [f"{out}/estimate.h5", f"{out}/estimate.csv"]
    elif cmd == "train":
        out = opts.get("--out", ["out/train"])[0]
        variants = opts.get("--variants", list(cli.VARIANTS))
        files += [f"{out}/summary.json", f"{out}/reward_curves.png"]
        names = ("run.json", "progress.csv", "training.csv")  # the module docstring's files
        files += [f"{out}/{v}/{name}" for v in variants for name in names]
    return files


README_COMMANDS = [tiny(argv) for argv in commands()]


# Commands the README names and links to their own page, where they are shown with the
# inputs they need (several logs, an exported artefact). tests/test_deploy.py runs export
# and deploy-check (export_to_file, deploy_check); tests/test_tune.py tests what tune runs
# but not the command end to end (minutes of compilation); tests/test_tune_env.py runs
# tune-env end to end on the planar leg. Each page must show the command.
DOCUMENTED_IN = {
    "tune": "docs/tuning.md",
    "tune-env": "docs/tuning.md",
    "export": "docs/deploy.md",
    "deploy-check": "docs/deploy.md",
    "transfer": "docs/training.md",  # needs trained runs of every variant and seed
}


def test_the_readme_lists_every_command():
    listed = {argv[0] for argv in README_COMMANDS}
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    missing = set(sub.choices) - listed - set(DOCUMENTED_IN)
    assert not missing, f"not in the README: {missing}"
    for cmd, page in DOCUMENTED_IN.items():
        assert f"`jax-contact {cmd}`" in README, cmd
        assert re.search(rf"^jax-contact {cmd} ", (ROOT / page).read_text(), re.M), page
        assert page in README, f"the README does not link {page}"
    assert set(TINY) >= listed, f"add tiny sizes to TINY for {listed - set(TINY)}"


def test_tiny_replaces_values_and_appends_flags():
    argv = ["train", "--variants", "truth", "estimate", "--config", "small", "--seed", "3"]
    assert tiny(argv) == ["train", "--seed", "3"] + [
        "--config",
        "tiny",
        "--variants",
        "truth",
        "--eval-envs",
        "0",
    ]
    assert tiny(["simulate", "a.h5", "--envs", "16"]) == [
        "simulate",
        "a.h5",
        "--envs",
        "2",
        "--duration",
        "0.5",
    ]


# A command that reads what an earlier one wrote runs after it, in the same chain; chains
# run side by side (two at a time), so that this file, which holds most of the suite's
# compilation, can use both cores once the other pytest-xdist worker is done. ``simulate``
# and ``evaluate`` run in ``demo``'s chain, after it in README order for Go1: the Go1
# simulation program of ``simulate --robot go1 --envs 2 --duration 0.5`` is the demo's own
# and then loads from the compilation cache (measured: 10 s instead of a cold compile),
# where a parallel chain would compile it at the same time.
CHAIN = {"policy-eval": "train", "evaluate": "demo", "simulate": "demo"}
PARALLEL = 2

# A command whose tiny run is another README command's job: ``reproduce --size tiny`` is
# ``demo --size tiny`` (the same ``reproduce.run`` on the same configuration; only the
# output folder differs), ~120 CPU-s of a cold suite to compute the same tables again.
# It is not run; test_same_job_as_a_command_that_runs checks, through the CLI's own parser
# and command function, that it calls what the other runs with the same configuration.
SAME_JOB = {"reproduce": "demo"}
RUN_COMMANDS = [argv for argv in README_COMMANDS if argv[0] not in SAME_JOB]


@dataclasses.dataclass
class Ran:
    argv: list[str]
    returncode: int
    stdout: str
    stderr: str
    wall_s: float


@pytest.fixture(scope="module")
def ran(tmp_path_factory) -> tuple[Path, dict[str, Ran]]:
    """Runs every README command (module docstring) in one folder; returns the folder and
    ' '.join(argv) -> its result."""
    folder = tmp_path_factory.mktemp("readme_commands")
    # The README's commands run from the repository root and read the files it ships
    # (envs/assets, tests/fixtures); outputs go to the temporary folder's out/.
    for shipped in ("envs", "tests"):
        (folder / shipped).symlink_to(ROOT / shipped, target_is_directory=True)
    chains: dict[str, list[list[str]]] = {}
    for argv in RUN_COMMANDS:
        chains.setdefault(CHAIN.get(argv[0], argv[0]), []).append(argv)

    def run_chain(argvs):
        out = {}
        for argv in argvs:
            t0 = time.perf_counter()
            res = subprocess.run(
                CLI + argv, cwd=folder, capture_output=True, text=True, timeout=1500, env=_ENV
            )
            wall = time.perf_counter() - t0
            out[" ".join(argv)] = Ran(argv, res.returncode, res.stdout, res.stderr, wall)
            print(f"jax-contact {' '.join(argv)}: {wall:.0f} s wall")  # pytest -s
            if res.returncode != 0:
                break  # the chain's later commands read this one's output
        return out

    t0, cpu0 = time.perf_counter(), _children_cpu_s()
    results: dict[str, Ran] = {}
    # Longest chains first (README order within a chain).
    order = sorted(chains.values(), key=lambda c: -max(_COST.get(a[0], 1) for a in c))
    with concurrent.futures.ThreadPoolExecutor(PARALLEL) as pool:
        for part in pool.map(run_chain, order):
            results.update(part)
    wall, cpu = time.perf_counter() - t0, _children_cpu_s() - cpu0
    print(f"README commands: {wall:.0f} s wall, {cpu:.0f} s CPU in all")  # pytest -s
    return folder, results


_COST = {"train": 5, "demo": 4, "bench": 3}  # rough CPU-minutes, cold cache

# The commands' programs are compiled at XLA:CPU's optimisation level 0: the same programs
# (same HLO, same results up to float rounding), unoptimised machine code, which compiles
# faster. Measured 2026-12-02 on `demo --size tiny` with an empty cache: 420 -> 350 CPU-s,
# every printed table identical. These runs check that the commands run and write what
# they promise; the numbers are tested in-process (the rest of the suite) at the default
# level, where two float32 tolerance tests do not hold at level 0 (docs/performance.md).
_ENV = {
    **os.environ,
    "XLA_FLAGS": " ".join(
        [os.environ.get("XLA_FLAGS", ""), "--xla_backend_optimization_level=0"]
    ).strip(),
}


@pytest.mark.parametrize("argv", RUN_COMMANDS, ids=[" ".join(a) for a in RUN_COMMANDS])
def test_readme_command_runs(argv, ran):
    workdir, results = ran
    key = " ".join(argv)
    assert key in results, f"not run: an earlier command of its chain failed ({key})"
    res = results[key]
    where = f"jax-contact {key} ({res.wall_s:.0f} s)\nstderr: {res.stderr[-3000:]}"
    assert res.returncode == 0, where
    assert "Traceback" not in res.stderr, where
    # XLA's C++ log lines (E1201 ... Very slow compile?) are not the user's concern.
    assert not re.search(r"^[EWI]\d{4} ", res.stderr, re.M), where
    assert "Very slow compile" not in res.stderr, where
    missing = [f for f in expected_outputs(argv) if not (workdir / f).is_file()]
    assert not missing, f"{where}\nmissing outputs: {missing}"
    for f in expected_outputs(argv):
        if f.endswith(".json"):
            json.loads((workdir / f).read_text())  # complete, valid JSON
    if argv[0] == "policy-eval":
        assert "estimator acc" in res.stdout, res.stdout
    if argv[0] == "bench":  # memory per row, and whether compile times are cache loads
        got = json.loads((workdir / argv[argv.index("--json") + 1]).read_text())
        assert all(r["bytes_per_env"] > 0 for r in got["throughput"])
        assert got["bytes_per_env_of"]["envs"] == got["throughput"][-1]["envs"]
        assert "compilation_cache_dir" in got["machine"]
    if argv[0] == "rates":  # the JSON holds every row and line the table prints
        (scene,) = json.loads((workdir / argv[argv.index("--json") + 1]).read_text()).values()
        # Always-contact scores the share of true-contact steps. Derived from the substep
        # row's own scores on the same steps (n, accuracy a, precision p, recall r):
        # FP + FN = (1 - a) n, FP = TP (1 - p) / p, FN = TP (1 - r) / r, so
        # TP = (1 - a) n / ((1 - p) / p + (1 - r) / r), and the true contacts are TP / r.
        row = scene["substep_every_physics_step"]
        n, a, p, r = (row[k] for k in ("n_steps", "accuracy", "precision", "recall"))
        if a < 1.0:
            share = (1 - a) * n / ((1 - p) / p + (1 - r) / r) / r / n
            assert scene["always_contact_accuracy"] == pytest.approx(share, rel=1e-6)
        assert 0.0 < scene["always_contact_accuracy"] < 1.0  # the hop has both phases
        assert scene["always_air_accuracy"] == pytest.approx(1 - scene["always_contact_accuracy"])
        assert scene["substep_every_physics_step_raw_truth"]["n_steps"] > 0
        assert scene["nonfinite_rollouts"] == 0 and "wall_s_with_compile" in scene


def _called_with(argv: list[str], monkeypatch) -> tuple:
    """The arguments the command function of ``argv`` passes to ``reproduce.run`` (recorded,
    not run), after the CLI's parser and argument checks."""
    from jax_contact.train import reproduce

    calls = []
    monkeypatch.setattr(reproduce, "run", lambda *a, **k: calls.append((a, k)))
    args = cli.build_parser().parse_args(argv)
    args.check(args)
    assert args.func(args) == 0
    assert len(calls) == 1, calls
    return calls[0]


@pytest.mark.parametrize("command", sorted(SAME_JOB))
def test_same_job_as_a_command_that_runs(command, monkeypatch):
    mine = [a for a in README_COMMANDS if a[0] == command]
    other = [a for a in RUN_COMMANDS if a[0] == SAME_JOB[command]]
    assert mine and other, (command, SAME_JOB[command])
    (cfg, out), kw = _called_with(mine[0], monkeypatch)
    (cfg_other, out_other), kw_other = _called_with(other[0], monkeypatch)
    assert cfg == cfg_other and kw == kw_other, (cfg, cfg_other)
    assert str(out) == f"out/{command}" and str(out_other) == f"out/{SAME_JOB[command]}"
    # Not vacuous: another size or robot gives another configuration.
    (cfg_spot, _), _ = _called_with([command, "--size", "demo", "--robot", "spot"], monkeypatch)
    assert cfg_spot != cfg


def _children_cpu_s() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def test_the_commands_filled_the_compilation_cache(ran):
    """After the README's commands ran (with this suite's cache settings, conftest.py), the
    cache folder holds compiled programs."""
    folder = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if not folder:
        pytest.fail("conftest.py did not turn the compilation cache on")
    assert any(Path(folder).iterdir())


# ----------------------------------------------------- feedback and cache (the README's)


def test_compiles_are_reported_while_they_run():
    import jax
    import jax.numpy as jnp

    stream = io.StringIO()
    # A program no cache holds (the cache keeps every program: the constant must differ from
    # every earlier run's, or the line reads 'loaded ... from the compilation cache').
    salt = float(time.time_ns() % 10**9)
    x = jnp.ones(3)  # made outside: its own (cached) programs are not the span's
    with progress.watch_compiles("jax-contact test", stream=stream, min_s=0.0):
        with progress.compiling("the test function"):
            jax.jit(lambda x: jnp.sin(x) * salt + 1.0)(x).block_until_ready()
    lines = stream.getvalue().splitlines()
    assert "jax-contact test: compiling the test function (first call)..." in lines, lines
    assert any(
        re.fullmatch(r"jax-contact test: compiled the test function in \d+\.\d s.*", line)
        for line in lines
    ), lines
    # The listeners are gone afterwards: another compilation writes nothing.
    jax.jit(lambda x: jnp.cos(x) * salt)(jnp.ones(3)).block_until_ready()
    assert stream.getvalue().splitlines() == lines


class FakeClock:
    """``progress``'s clock, moved by the test (its thread still sleeps in real time)."""

    def __init__(self):
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now

    sleep = staticmethod(time.sleep)


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(progress, "time", fake)
    return fake


def _wait_for_line(stream: io.StringIO, text: str) -> None:
    """Until the progress thread has written ``text`` (it shows a span once past min_s)."""
    for _ in range(500):
        if text in stream.getvalue().splitlines():
            return
        time.sleep(0.01)
    pytest.fail(f"{text!r} not shown within 5 s: {stream.getvalue()!r}")


def test_a_span_whose_programs_all_came_from_the_cache_says_loaded(clock):
    """A warm run said 'compiled in 6.2 s (1 of 1 from the compilation cache)' though
    nothing was compiled (a newcomer's trial); a span with a miss still says compiled.
    The span lasts 0.6 s of the test's clock."""
    for hits, misses, want in (
        (2, 0, "p: loaded the step from the compilation cache in 0.6 s"),
        (1, 1, "p: compiled the step in 0.6 s (1 of 2 from the compilation cache)"),
    ):
        stream = io.StringIO()
        timer = progress._Timer("p: ", stream, 0.0)
        timer.what = " the step"
        timer.begin()
        _wait_for_line(stream, "p: compiling the step (first call)...")
        clock.now += 0.6
        timer.cache_hits, timer.cache_misses = hits, misses
        timer.end()
        timer.close()
        lines = stream.getvalue().splitlines()
        assert lines == ["p: compiling the step (first call)...", want], lines


def test_a_block_outside_the_watcher_is_timed_by_compiling_itself(clock):
    stream = io.StringIO()
    with progress.compiling("the block", stream=stream, min_s=0.0):
        _wait_for_line(stream, "compiling the block (first call)...")
        clock.now += 0.7  # the block's duration on the test's clock
    lines = stream.getvalue().splitlines()
    assert lines == ["compiling the block (first call)...", "compiled the block in 0.7 s"]


def test_a_block_shorter_than_min_s_says_nothing(clock):
    stream = io.StringIO()
    with progress.compiling("the block", stream=stream, min_s=5.0):
        clock.now += 4.9  # under min_s on the clock the thread reads: no line, no summary
    assert stream.getvalue() == ""


def test_bar_yields_everything_and_reports_in_a_log(clock):
    stream = io.StringIO()
    items = list(progress.bar(range(3), desc="replay", unit="chunk", stream=stream))
    assert items == [0, 1, 2]
    assert stream.getvalue().splitlines() == ["replay: 3/3 chunks, 0 s"]
    assert list(progress.bar(iter("ab"), desc="x", stream=stream)) == ["a", "b"]


def test_bar_reports_elapsed_time_and_time_left(clock, monkeypatch):
    """A log's line every PLAIN_EVERY_S: k of n, seconds since the start, and the time
    left at the rate after the first (compiling) item."""
    monkeypatch.setattr(progress, "PLAIN_EVERY_S", 10.0)
    stream = io.StringIO()
    for k in progress.bar(range(4), desc="r", unit="chunk", stream=stream):
        clock.now += 30.0 if k == 0 else 6.0  # item 0 compiles: 30 s; the others 6 s each
    # Item 1 done at 30 s: 30 s since the start >= 10, a line (no rate from one item).
    # Item 2 at 36 s: 6 s since that line, none. Item 3 at 42 s: 12 s since, a line; rate
    # (42 - 30) / 2 = 6 s per item after the first, 1 item left: 6 s. Item 4 at 48 s: the
    # final line, no estimate.
    assert stream.getvalue().splitlines() == [
        "r: 1/4 chunks, 30 s",
        "r: 3/4 chunks, 42 s, about 6 s left",
        "r: 4/4 chunks, 48 s",
    ]


def test_bar_shows_the_loops_state_after_the_last_item(clock):
    # simulate's bar: the postfix is read after each chunk, so the line shows the last state
    stream, upright = io.StringIO(), [2]
    for k in progress.bar(
        range(2), desc="sim", unit="chunk", stream=stream, postfix=lambda: f"{upright[0]}/2 upright"
    ):
        upright[0] = 2 - k
    assert stream.getvalue().splitlines() == ["sim: 2/2 chunks, 0 s, 1/2 upright"]


def test_feedback_can_be_turned_off(monkeypatch):
    monkeypatch.setenv(progress.ENV_SWITCH, "0")
    stream = io.StringIO()
    with progress.compiling("x", stream=stream, min_s=0.0):
        time.sleep(0.2)
    assert list(progress.bar(range(2), stream=stream)) == [0, 1]
    assert stream.getvalue() == ""


def _cache_settings(env: dict) -> list[str]:
    code = (
        "import jax_contact.train.cli as c; c.enable_compilation_cache(); import jax;"
        " print(jax.config.jax_compilation_cache_dir);"
        " print(jax.config.jax_persistent_cache_min_compile_time_secs);"
        " print(jax.config.jax_persistent_cache_min_entry_size_bytes)"
    )
    base = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") or k == "JAX_PLATFORMS"}
    res = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**base, **env},
    )
    assert res.returncode == 0, res.stderr
    return res.stdout.split()


def test_the_cli_cache_folder_is_configurable(tmp_path):
    folder = tmp_path / "xla"
    assert _cache_settings({cli.CACHE_ENV: str(folder)}) == [str(folder), "0.0", "0"]
    assert folder.is_dir()
    assert _cache_settings({cli.CACHE_ENV: ""})[0] == "None"  # off
    home = tmp_path / "cachehome"
    expected = str(home / "jax-contact" / "xla" / cli.host_tag())
    assert _cache_settings({"XDG_CACHE_HOME": str(home)})[0] == expected


def test_the_default_cache_folder_is_per_cpu_feature_set():
    """Programs compiled for one CPU's instruction set are not loaded on another: the
    default folder's last part is the architecture and a hash of the sorted feature flags."""
    import hashlib
    import platform

    avx512 = "processor\t: 0\nflags\t\t: fpu sse2 avx2 avx512f\n"
    assert cli.host_tag(avx512) == cli.host_tag(avx512.replace("sse2 avx2", "avx2 sse2"))
    assert cli.host_tag(avx512) != cli.host_tag(avx512.replace(" avx512f", ""))
    digest = hashlib.sha256(b"avx2 avx512f fpu sse2").hexdigest()[:12]
    assert cli.host_tag(avx512) == f"{platform.machine() or 'cpu'}-{digest}"
    arm = "processor\t: 0\nFeatures\t: fp asimd sve\n"  # aarch64's name for the flags
    assert cli.host_tag(arm).endswith(hashlib.sha256(b"asimd fp sve").hexdigest()[:12])
