"""The ``jax-contact`` command line as a user meets it (issue 18).

Fast answers to bad arguments (before JAX is imported), ``--help``, Ctrl-C, ``--timesteps``,
``bench``'s sizes and partial JSON, one-line errors for bad logs, logs without ground
truth, and the mode of written files. Subprocess tests run the installed entry point or
``python -c``; nothing here trains, benchmarks or simulates beyond a few compiled steps.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from jax_contact import io
from jax_contact.train import cli, cli_args

ROOT = Path(__file__).resolve().parents[1]
# The installed entry point, as a user runs it (``python -m jax_contact.train.cli`` where it is
# missing).
_ENTRY = Path(sys.executable).parent / "jax-contact"
CLI = [str(_ENTRY)] if _ENTRY.exists() else [sys.executable, "-m", "jax_contact.train.cli"]


def _run(args, *, timeout=60, **kwargs):
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, cwd=ROOT, **kwargs)


# --------------------------------------------------------------- arguments, before JAX


def test_importing_the_cli_does_not_import_jax():
    code = (
        "import sys, jax_contact.train.cli; heavy = [m for m in ('jax', 'jaxlib', 'mujoco', 'h5py',"
        " 'numpy', 'brax') if m in sys.modules]; print(heavy)"
    )
    res = _run([sys.executable, "-c", code])
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def test_version_is_the_installed_distributions_without_importing_jax():
    """``jax-contact --version`` and ``jax_contact.__version__`` read the package metadata
    (the one version a bug report, a params file and an exported estimator name)."""
    from importlib.metadata import version

    code = (
        "import sys, jax_contact as jc, jax_contact.train.cli as c; print(jc.__version__);"
        " print([m for m in ('jax', 'numpy') if m in sys.modules])"
    )
    res = _run([sys.executable, "-c", code])
    assert res.returncode == 0, res.stderr
    assert res.stdout.split("\n")[:2] == [version("jax-contact"), "[]"]
    res = _run([*CLI, "--version"])
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"jax-contact {version('jax-contact')}"


# Runs ``jax-contact ARGS`` (``cli.main``) and prints the heavy modules it imported.
_MAIN_THEN_HEAVY = (
    "import sys\n"
    "from jax_contact.train import cli\n"
    "try:\n"
    "    code = cli.main(sys.argv[1:])\n"
    "except SystemExit as stop:\n"
    "    code = stop.code\n"
    "heavy = [m for m in ('jax', 'jaxlib', 'mujoco', 'brax') if m in sys.modules]\n"
    "print(f'heavy: {heavy}')\n"
    "sys.exit(code)\n"
)


@pytest.mark.parametrize(
    "argv, names",
    [
        (["simulate", "/proc/x.h5"], ["argument output", "'/proc'"]),
        (["simulate", "out.h5", "--envs", "0"], ["argument --envs", "'0'"]),
        (["simulate", "out.h5", "--duration", "-1"], ["argument --duration"]),
        (["simulate", "out.h5", "--duration", "nan"], ["argument --duration"]),
        (["transfer", "README.md"], ["argument root: 'README.md' is a file"]),
        (["transfer", "docs", "--json", "/proc/t.json"], ["argument --json", "'/proc'"]),
        (
            ["simulate", "out.h5", "--duration", "0.001"],
            ["argument --duration: 0.001 s is under 2"],
        ),
        (["simulate", "out.txt"], ["argument output", "must end in .h5"]),
        (["simulate"], ["argument output", "missing", "--out"]),
        (["simulate", "out.h5", "--out", "b.h5"], ["argument output", "twice", "'b.h5'"]),
        (["simulate", "--out", "out.txt"], ["argument output", "must end in .h5"]),
        (["simulate", "out.h5", "--robot", "dog"], ["argument --robot", "'dog'", "go1"]),
        (["simulate", "out.h5", "--robot", "no/such.xml"], ["argument --robot", "no/such.xml"]),
        (["simulate", "out.h5", "--robot", "docs/"], ["argument --robot", "'docs/' is a folder"]),
        (["evaluate", "no_such_log.h5"], ["argument log", "no_such_log.h5"]),
        (["evaluate", "README.md", "--robot", "no/such.xml"], ["argument --robot", "such.xml"]),
        (["evaluate", "README.md", "--json", "/proc/m.json"], ["argument --json", "'/proc'"]),
        (["train", "--timesteps", "0"], ["argument --timesteps"]),
        (["train", "--eval-envs", "-1"], ["argument --eval-envs", "'-1'", ">= 0"]),
        (["train", "--out", "README.md"], ["argument --out", "README.md"]),
        (["train", "--task", "hop", "--config", "full"], ["argument --config", "hop"]),
        (["train", "--config", "reduced"], ["argument --config", "go1", "'reduced'"]),
        (["train", "--task", "cat"], ["argument --task", "'cat'"]),
        (["policy-eval", "docs"], ["argument run", "run.json"]),
        (["policy-eval", "docs", "--envs", "-3"], ["argument --envs"]),
        (["bench", "--versus-envs", "0"], ["argument --versus-envs"]),
        (
            ["demo", "--out", "/proc/demo"],
            ["argument --out: cannot create folder '/proc/demo': '/proc' takes"],
        ),
        (["reproduce", "--robot", "cat"], ["argument --robot", "'cat'"]),
        # Refused after the simulation with a Python API hint (force_rows) before.
        (["reproduce", "--robot", "planar_leg"], ["argument --robot", "quadruped"]),
        (["simulate", "out.h5", "--robot", "spot", "--gait", "hop"], ["--gait", "'spot'"]),
        (["simulate", "out.h5", "--robot", "planar_leg"], ["--gait", "'trot'", "'hop'"]),
        # Killed by the kernel (exit 137) with no word before.
        (["simulate", "out.h5", "--envs", "100000000", "--duration", "1000"], ["--envs", "GiB"]),
        (["reproduce", "--params", "per_gait"], ["argument --params", "'per_gait'"]),
        (["rates", "--params", "dog"], ["argument --params", "'dog'", "go1"]),
        (
            ["simulate", "out.h5", "--seed", "99999999999999999999"],
            ["argument --seed", "2147483647"],
        ),
        (["simulate", "out.h5", "--seed", "-1"], ["argument --seed", "'-1'"]),
        # Accepted, then a TypeError traceback after JAX loaded.
        (["simulate", ""], ["argument output", "missing"]),
        # Accepted, then refused after JAX loaded naming GaitSettings' field, not the flag.
        (["simulate", "out.h5", "--speed", "0.2", "nan"], ["argument --speed", "finite"]),
        (["simulate", "out.h5", "--kp", "inf"], ["argument --kp", "finite"]),
        (["simulate", "out.h5", "--home-qpos", "nan"], ["argument --home-qpos", "finite"]),
        # The baselines tuned on the log they are scored on (a helper's fairness audit).
        (
            [
                "evaluate",
                "tests/fixtures/planar_leg_hop.h5",
                "--gm-grid",
                "tests/fixtures/planar_leg_hop.h5",
            ],
            ["argument --gm-grid", "is an evaluated log"],
        ),
        # A repeat trained twice (or failed after the first had trained); ran a scene again.
        (["train", "--variants", "truth", "truth"], ["argument --variants", "repeated variant"]),
        (["rates", "--scenes", "go1", "go1"], ["argument --scenes", "repeated scene"]),
        # bench: a repeat was measured twice; 10^9 envs died on a 9.4 TiB allocation after
        # the other sections had run.
        (["bench", "--envs", "8", "8"], ["argument --envs", "repeated batch size"]),
        (["bench", "--versus-envs", "1000000000"], ["argument --versus-envs", "GiB"]),
        # The final evaluation's episodes: 10^11 trained first, then died (policy-eval's
        # --envs and transfer's take the same check).
        (
            ["train", "--config", "tiny", "--eval-envs", "100000000000", "--out", "out_never"],
            ["argument --eval-envs: 100000000000 envs need at least", "GiB"],
        ),
        (["evaluate", "README.md", "--bootstrap", "99999999999"], ["argument --bootstrap"]),
        (["tune", "README.md", "--validate", "x.h5", "--out", "t.json"], ["argument LOG"]),
        # The same tuning log twice: refused after JAX loaded and the first log was measured.
        (
            [
                "tune",
                "tests/fixtures/planar_leg_hop.h5",
                "tests/fixtures/planar_leg_hop.h5",
                "--validate",
                "x.h5",
                "--out",
                "t.json",
            ],
            ["argument LOG", "is given twice"],
        ),
        (["evaluate", "README.md", "--params", "pyproject.toml"], ["argument --params", "JSON"]),
        # An unknown option: the command's usage and prog (it used to be the top level's).
        (["train", "--contact", "estimate"], ["unrecognized arguments: --contact estimate"]),
        # More steps than an int64 holds: training started (a helper's trial).
        (
            ["train", "--timesteps", "100000000000000000000", "--out", "out_never"],
            ["argument --timesteps: must be an int from 1 to 9223372036854775807"],
        ),
        # A value argparse's type refuses (its message came after the command's usage).
        (
            ["tune", "x.h5", "--validate", "y.h5", "--out", "t.json", "--epochs", "0"],
            ["argument --epochs: must be an int >= 1, got '0'"],
        ),
        (["policy-eval", "README.md"], ["argument run", "'README.md' is a file"]),
        # An output that is the command's input: the log was overwritten with JSON.
        (
            [
                "evaluate",
                "tests/fixtures/planar_leg_hop.h5",
                "--json",
                "tests/fixtures/planar_leg_hop.h5",
            ],
            ["argument --json", "this command's log"],
        ),
    ],
)
def test_bad_arguments_are_reported_at_once(argv, names):
    """Each bad argument: exit code 2, one error line naming the argument, before JAX,
    MuJoCo or Brax is imported (they used to come first: 45-65 s on a loaded machine).
    ``main`` runs in a fresh interpreter that prints, after it returns, which of them it
    imported."""
    res = _run([sys.executable, "-c", _MAIN_THEN_HEAVY, *argv], timeout=60)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert res.stdout.splitlines()[-1] == "heavy: []", (argv, res.stdout)
    errors = [line for line in res.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and errors[0].startswith(f"jax-contact {argv[0]}: error:"), res.stderr
    for name in names:
        assert name in errors[0], (name, errors[0])
    assert "Traceback" not in res.stderr
    # One line and a pointer to --help, not argparse's whole usage first (18 lines for
    # tune, burying the message: a helper's audit).
    assert "usage:" not in res.stderr, res.stderr
    assert res.stderr.splitlines()[-1] == f"(jax-contact {argv[0]} --help lists the options)" or (
        len(res.stderr.splitlines()) == 1
    ), res.stderr
    assert not (ROOT / "out.h5").exists() and not (ROOT / "out.txt").exists()


def test_a_log_too_large_for_its_robot_is_refused_once_the_robot_is_known(tmp_path):
    """Before JAX, ``simulate``'s size check can only assume the smallest robot's log (52
    bytes per step and env: the planar leg's readings): a Go1 log of several times this
    machine's memory passed it and compiled. Once the robot is loaded its own size is
    checked, before the physics compiles: Go1's readings (float32 qpos 19, qvel, qacc, tau
    18 each) and per-foot truth (a flag, a float32 force and height; 4 feet) are
    4 (19 + 3 x 18) + 9 x 4 = 328 bytes; 100 bytes x envs x steps = the memory lies between
    the two bounds."""
    from jax_contact.train.logs import simulate_to_file

    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    envs = int(total / (100 * 400)) + 1  # x 400 steps (1 s): 100 bytes each fill the memory
    cli_args.check_log_size(envs, 1.0)  # the planar leg's bound passes
    with pytest.raises(ValueError, match=r"arguments --envs and --duration: .* a log of 'go1'"):
        simulate_to_file(tmp_path / "big.h5", robot="go1", n_envs=envs, duration=1.0)
    assert not (tmp_path / "big.h5").exists()


@pytest.mark.parametrize("command", ["tune", "tune-env"])
def test_tuning_refuses_an_unwritable_out_before_it_tunes(tmp_path, command):
    """--out is probed before minutes of tuning (it used to fail after them, naming the
    temporary file)."""
    for name in ("a.h5", "b.h5"):
        (tmp_path / name).write_bytes(b"")
    inputs = {
        "tune": [str(tmp_path / "a.h5"), "--validate", str(tmp_path / "b.h5")],
        "tune-env": ["planar_leg", "--seeds", "0", "--validate-seed", "1"],
    }[command]
    argv = [command, *inputs, "--out", "/proc/t.json"]
    res = _run([sys.executable, "-c", _MAIN_THEN_HEAVY, *argv], timeout=60)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "argument --out" in res.stderr and "'/proc'" in res.stderr, res.stderr
    assert res.stdout.splitlines()[-1] == "heavy: []", res.stdout  # before any tuning


def test_output_folder_check_creates_nothing(tmp_path):
    cli.check_output_folder("--out", tmp_path / "a" / "b")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        cli.check_output_folder("--out", tmp_path / "file" / "sub")
    with pytest.raises(ValueError, match="not a folder"):
        cli.check_output_folder("--out", tmp_path / "file")


def test_static_lists_equal_the_librarys():
    """cli.py copies lists whose modules import JAX; the copies must not drift."""
    from jax_contact.envs import gaits, model_files, robots, sensors, simulate
    from jax_contact.train import ppo, rates

    assert cli.ROBOT_NAMES == robots.ROBOT_NAMES
    assert cli.MENAGERIE_NAMES == model_files.MENAGERIE_NAMES
    assert cli.GAITS == gaits.KINDS
    assert cli.NOISES == sensors.PRESETS
    assert cli.TERRAINS == simulate.TERRAINS
    assert cli.VARIANTS == ppo.VARIANTS
    from jax_contact.train import tasks

    assert cli.TASKS == tasks.TASK_NAMES
    for name in cli.TASKS:
        assert cli.TASK_CONFIGS[name] == tuple(dict(tasks.get_task(name).configs)), name
    assert set(cli.PPO_CONFIGS) == {"tiny"}.union(*cli.TASK_CONFIGS.values())
    assert cli.SCENES == rates.SCENES
    from jax_contact.benchmarks import estimator

    assert cli.BENCH_ENVS == estimator.DEFAULT_ENVS
    from jax_contact.train import reproduce

    figures = ("section3_fig5.png", "table3_trot_fig7.png")
    reliability = tuple(f"reliability_{n}.png" for n in reproduce.SCENARIOS)
    assert cli.REPRODUCE_OUTPUTS == reproduce.OUTPUT_FILES + figures + reliability
    # --out's help names the figures an earlier run's outputs are replaced by.
    sub = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    out_help = next(a.help for a in sub.choices["reproduce"]._actions if a.dest == "out")
    assert all(f"{prefix}*" in out_help for prefix in reproduce.FIGURE_PREFIXES), out_help
    import inspect

    from jax_contact.train import report

    assert cli_args.FAILURE_LIMIT == report.FAILURE_LIMIT

    assert cli_args._SIMULATE_DT == inspect.signature(simulate.build_world).parameters["dt"].default
    assert cli.ONE_LEGGED == tuple(
        n for n in model_files.BUILTIN_NAMES if robots.load_robot(n).description.n_legs == 1
    )


def test_help_shows_defaults_robot_names_and_every_command(capsys):
    parser = cli.build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: 16)" in text and "(default: go1)" in text and "(default: 10.0)" in text
    for name in cli.ROBOT_NAMES:
        assert name in text
    assert "(default: None)" not in text
    with pytest.raises(SystemExit):
        parser.parse_args(["--help"])
    top = capsys.readouterr().out
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, choice in sub.choices.items():
        assert choice.description, name
        assert name in top
    assert "Table III" in sub.choices["reproduce"].format_help()


def test_xla_log_lines_are_silenced_unless_the_user_set_a_level():
    code = (
        "import os, jax_contact.train.cli as c; c._quiet_xla_logs();"
        " print(os.environ['TF_CPP_MIN_LOG_LEVEL'])"
    )
    env = {k: v for k, v in os.environ.items() if k != "TF_CPP_MIN_LOG_LEVEL"}
    res = _run([sys.executable, "-c", code], env=env)
    assert res.stdout.strip() == "3", res.stderr
    res = _run([sys.executable, "-c", code], env={**env, "TF_CPP_MIN_LOG_LEVEL": "0"})
    assert res.stdout.strip() == "0", res.stderr


# ------------------------------------------------------------------------------ Ctrl-C


def _interrupt(args, *, wait_s, cwd):
    proc = subprocess.Popen(
        args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    time.sleep(wait_s)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"still running 30 s after SIGINT; stderr: {err[-2000:]}")
    return proc.returncode, out, err


def test_ctrl_c_stops_simulate_at_once_and_leaves_nothing(tmp_path):
    """SIGINT during imports or compilation (a 30 s rollout takes minutes here): exit 130
    (``_interrupt`` fails the test if the process still runs 30 s after the signal), one
    line on stderr, no output file and no temporary file."""
    code, out, err = _interrupt(
        [*CLI, "simulate", "out.h5", "--envs", "2", "--duration", "30"],
        wait_s=8.0,
        cwd=tmp_path,
    )
    env_note = f"stdout {out!r}, stderr {err!r}"
    assert code == 130, env_note
    assert err.strip().splitlines()[-1] == "jax-contact simulate: interrupted", env_note
    assert "Traceback" not in err and "Exception ignored" not in err, env_note
    assert len(err.strip().splitlines()) <= 3, env_note
    assert list(tmp_path.iterdir()) == [], "no output, no temporary file"


def test_ctrl_c_during_a_write_removes_the_temporary_file(tmp_path):
    """The watcher removes the temporary file of a write in progress (and no rename can
    follow), even when the writer is stuck in C code."""
    script = (
        "import os, signal, sys, time\n"
        "from jax_contact.train import cli\n"
        "from jax_contact.io import write_atomic\n"
        "def write(tmp):\n"
        "    open(tmp, 'w').write('partial')\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(20)\n"
        "with cli.StopOnInterrupt('jax-contact test'):\n"
        "    write_atomic(sys.argv[1], write)\n"
        "print('not reached')\n"
    )
    res = _run([sys.executable, "-c", script, str(tmp_path / "out.json")])
    assert res.returncode == 130, res.stderr
    assert res.stderr == "jax-contact test: interrupted\n"
    assert "not reached" not in res.stdout
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_after_a_write_names_the_file_as_complete(tmp_path):
    """A stop just after a command's "wrote ..." (export, a trial) printed only
    "interrupted", as if the file might be partial; the files written completely are named
    (the last five, the rest counted)."""
    script = (
        "import os, signal, sys, time\n"
        "from jax_contact.train import cli\n"
        "from jax_contact.io import write_text_atomic\n"
        "stop = cli.StopOnInterrupt('jax-contact test').__enter__()\n"
        "for i in (*range(7), 5):\n"
        "    write_text_atomic(os.path.join(sys.argv[1], f'{i}.txt'), 'x')\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"
        "time.sleep(20)\n"
    )
    res = _run([sys.executable, "-c", script, str(tmp_path)])
    assert res.returncode == 130
    # 5.txt, written again last, is named once, as the latest (it was named twice).
    names = ", ".join(str(tmp_path / f"{i}.txt") for i in (2, 3, 4, 6, 5))
    assert res.stderr == (
        "jax-contact test: interrupted\n"
        f"jax-contact test: written completely before the stop: {names} and 2 more\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{i}.txt" for i in range(7)]


def test_ctrl_c_names_what_the_command_keeps_on_purpose():
    """``train`` keeps an interrupted run folder (its checkpoints); the stop says so, and
    says nothing once the note is cleared (a finished run)."""
    script = (
        "import os, signal, sys, time\n"
        "from jax_contact.train import cli, interrupt\n"
        "interrupt.set_kept('kept a')\n"
        "interrupt.set_kept(None)\n"
        "interrupt.set_kept(lambda: sys.argv[1])  # asked at the stop\n"
        "with cli.StopOnInterrupt('jax-contact test'):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(20)\n"
    )
    res = _run([sys.executable, "-c", script, "kept out/estimate"])
    assert res.returncode == 130
    assert res.stderr == "jax-contact test: interrupted\njax-contact test: kept out/estimate\n"


def test_ctrl_c_while_the_io_module_is_still_importing(tmp_path):
    """A signal during start-up, while ``jax_contact.io`` is half imported (no
    ``abort_writes`` yet), still stops the command with 130: the watcher thread used to die
    on the AttributeError, and every later Ctrl-C was ignored (a helper's run carried on and
    replaced the earlier outputs)."""
    script = (
        "import os, signal, sys, time, types\n"
        "from jax_contact.train import cli\n"
        "sys.modules['jax_contact.io'] = types.ModuleType('jax_contact.io')  # mid-import\n"
        "with cli.StopOnInterrupt('jax-contact test'):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(20)\n"
        "print('not reached')\n"
    )
    res = _run([sys.executable, "-c", script])
    assert res.returncode == 130, res.stderr
    assert res.stderr == "jax-contact test: interrupted\n"
    assert "not reached" not in res.stdout


@pytest.mark.parametrize("sig, code, word", [("SIGINT", 130, "interrupted"),
                                             ("SIGTERM", 143, "terminated")])  # fmt: skip
def test_a_signal_during_a_staged_folder_leaves_the_earlier_run(tmp_path, sig, code, word):
    """``estimate`` writes its set of files through ``io.staged_folder``: a signal while
    they are written leaves the folder as the earlier run left it (no file of the new run,
    no temporary folder beside it); SIGTERM is handled like Ctrl-C, with its own code."""
    out = tmp_path / "est"
    out.mkdir()
    (out / "estimate.csv").write_text("earlier")
    (out / "metrics.json").write_text("{}")
    script = (
        "import os, signal, sys, time\n"
        "from jax_contact.train import cli\n"
        "from jax_contact.io import staged_folder, write_text_atomic\n"
        f"with cli.StopOnInterrupt('jax-contact test'):\n"
        "    with staged_folder(sys.argv[1]) as stage:\n"
        "        write_text_atomic(stage / 'estimate.csv', 'new')\n"
        f"        os.kill(os.getpid(), signal.{sig})\n"
        "        time.sleep(20)\n"
        "print('not reached')\n"
    )
    res = _run([sys.executable, "-c", script, str(out)])
    assert res.returncode == code, res.stderr
    assert res.stderr == f"jax-contact test: {word}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est"]
    assert (out / "estimate.csv").read_text() == "earlier"
    assert sorted(p.name for p in out.iterdir()) == ["estimate.csv", "metrics.json"]
    # Into folders that did not exist (several recordings' OUT/<name>): the folders made
    # for it are gone too (an empty OUT was left after a Ctrl-C in the first recording).
    res = _run([sys.executable, "-c", script, str(tmp_path / "new" / "out" / "rec")])
    assert res.returncode == code, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est"]


def test_a_single_file_that_fails_or_is_stopped_leaves_no_folder_it_made(tmp_path):
    """``write_atomic`` made the missing folders of its path and left them, empty, when the
    write failed or a signal stopped it (``simulate new/dir/log.h5`` then Ctrl-C), where
    a staged folder removed its own; a folder that existed, or got another file meanwhile,
    stays; a write that succeeds keeps its folders."""
    from jax_contact import io

    def fails(tmp):
        Path(tmp).write_text("half")
        raise RuntimeError("the writer's error")

    with pytest.raises(RuntimeError, match="the writer's error"):
        io.write_atomic(tmp_path / "a" / "b" / "x.json", fails)
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "kept.txt").write_text("x")
    with pytest.raises(RuntimeError):
        io.write_atomic(tmp_path / "a" / "b" / "x.json", fails)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["kept.txt"]
    io.write_atomic(tmp_path / "c" / "d" / "x.json", lambda t: Path(t).write_text("{}"))
    assert (tmp_path / "c" / "d" / "x.json").read_text() == "{}"
    script = (
        "import os, signal, sys, time\n"
        "from jax_contact.train import cli\n"
        "from jax_contact.io import write_atomic\n"
        "def slow(tmp):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(20)\n"
        "with cli.StopOnInterrupt('jax-contact test'):\n"
        "    write_atomic(sys.argv[1], slow)\n"
        "print('not reached')\n"
    )
    res = _run([sys.executable, "-c", script, str(tmp_path / "new" / "dir" / "log.h5")])
    assert res.returncode == 130, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "c"]


def test_a_staged_folder_replaces_the_earlier_run_and_keeps_other_files(tmp_path):
    """On success the new files replace their namesakes, the earlier run's files that this
    run did not write are removed (``stale``), anything else in the folder stays; on an
    exception the folder is untouched and the temporary folder gone."""
    from jax_contact.io import staged_folder, write_text_atomic

    out = tmp_path / "est"
    out.mkdir()
    for name, text in [("estimate.csv", "earlier"), ("metrics.json", "{}"), ("notes.txt", "x")]:
        (out / name).write_text(text)
    stale = lambda folder: ["estimate.csv", "metrics.json", "foot.png"]  # noqa: E731
    with pytest.raises(RuntimeError):
        with staged_folder(out, stale=stale) as stage:
            write_text_atomic(stage / "estimate.csv", "new")
            raise RuntimeError
    assert (out / "estimate.csv").read_text() == "earlier"
    with staged_folder(out, stale=stale) as stage:
        write_text_atomic(stage / "estimate.csv", "new")
    assert (out / "estimate.csv").read_text() == "new"
    assert sorted(p.name for p in out.iterdir()) == ["estimate.csv", "notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est"]
    # Without ``stale`` nothing is removed; a new folder is created.
    with staged_folder(tmp_path / "new") as stage:
        write_text_atomic(stage / "a.txt", "a")
    assert [p.name for p in (tmp_path / "new").iterdir()] == ["a.txt"]
    assert sorted(p.name for p in out.iterdir()) == ["estimate.csv", "notes.txt"]
    # A folder where one output goes: refused before anything moves (the moves had
    # stopped half done, this run's csv beside the folder, an errno naming the stage).
    (out / "metrics.json").mkdir()
    with pytest.raises(ValueError, match=r"cannot write '.*metrics\.json': it is a folder"):
        with staged_folder(out, stale=stale) as stage:
            write_text_atomic(stage / "estimate.csv", "newer")
            write_text_atomic(stage / "metrics.json", "{}")
    assert (out / "estimate.csv").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est", "new"]


@pytest.mark.parametrize("fails", ["aside b.json", "in c.json", "aside old.png"])
def test_a_staged_folder_that_cannot_replace_one_file_leaves_the_earlier_run(
    tmp_path, monkeypatch, fails
):
    """reproduce's outputs moved in one by one: a file that could not be replaced (one
    locked in a shared folder) stopped the moves after the earlier ones, and a user's
    folder held seed 2's ablation.json and figures beside seed 0's table3.json. Now the
    files replaced are moved aside first and every move is undone on a failure: the folder
    holds the earlier run's files only, named in the error, and nothing is left beside it."""
    import os

    from jax_contact import io
    from jax_contact.io import staged_folder, write_text_atomic

    out = tmp_path / "out"
    out.mkdir()
    earlier = {"a.json": "0", "b.json": "0", "c.json": "0", "old.png": "0", "notes.txt": "x"}
    for name, text in earlier.items():
        (out / name).write_text(text)
    where, name = fails.split()
    real = os.replace

    def replace(src, dst):
        src, dst = Path(src), Path(dst)
        moving_aside = src.parent == out and dst.parent != out
        moving_in = src.parent.name.endswith(".tmp") and dst.parent == out  # from the stage
        if src.name == name and (moving_aside if where == "aside" else moving_in):
            raise PermissionError(1, "Operation not permitted", str(src))
        real(src, dst)

    monkeypatch.setattr(io.os, "replace", replace)
    stale = lambda folder: ["a.json", "b.json", "c.json", "old.png"]  # noqa: E731
    with pytest.raises(OSError, match=rf"cannot replace the files of .*{name}.*as it was"):
        with staged_folder(out, stale=stale) as stage:
            for new in ("a.json", "b.json", "c.json"):
                write_text_atomic(stage / new, "2")
    assert {p.name: p.read_text() for p in out.iterdir()} == earlier
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_a_library_warning_prints_as_one_line_while_a_command_runs(capsys):
    """UserWarnings print as '<prog>: warning: <message>' (they printed the raising file,
    line and source line); other categories and the handler after the command are as
    Python has them."""
    import warnings

    from jax_contact.train import cli

    before = warnings.showwarning
    with cli._warnings_as_lines("jax-contact x"):
        warnings.warn("a file tuned at 200 Hz", UserWarning, stacklevel=1)
        # Brax's notice about its own maintenance, on every MJCF load, is not shown as ours.
        warnings.warn(
            "Brax System, piplines and environments are not actively being maintained. Please"
            " see MJX",
            UserWarning,
            stacklevel=1,
        )
    assert capsys.readouterr().err == "jax-contact x: warning: a file tuned at 200 Hz\n"
    assert warnings.showwarning is before


def test_the_interrupt_handler_is_removed_afterwards():
    """In-process callers of cli.main (tests) get their SIGINT handler and wake-up fd back."""
    before = signal.getsignal(signal.SIGINT)
    fd_before = signal.set_wakeup_fd(-1)  # reading it means setting it; put it back at once
    signal.set_wakeup_fd(fd_before)
    term_before = signal.getsignal(signal.SIGTERM)
    with cli.StopOnInterrupt("x"):
        assert signal.getsignal(signal.SIGINT) is not before
        assert signal.getsignal(signal.SIGTERM) is not term_before
    assert signal.getsignal(signal.SIGINT) is before
    assert signal.getsignal(signal.SIGTERM) is term_before
    assert signal.set_wakeup_fd(fd_before) == fd_before


# ------------------------------------------------------------------------- --timesteps


def test_timesteps_are_trained_as_asked():
    """Brax PPO rounds num_timesteps up to whole epochs: SMALL with 40,960 steps trained
    245,760 (6 epochs of one 40,960-step training step). fit_timesteps trains 40,960."""
    from jax_contact.train import ppo

    small = ppo.SMALL
    step = small.steps_per_training_step
    assert step == 40_960
    assert ppo.brax_timesteps(dataclasses.replace(small, num_timesteps=step)) == 245_760
    cfg, note = ppo.fit_timesteps(small, 40_960)
    assert ppo.brax_timesteps(cfg) == cfg.num_timesteps == 40_960
    assert cfg.num_evals == 2 and "40,960" in note and "2 evaluations instead of 7" in note
    assert ppo.fit_timesteps(small, small.num_timesteps) == (small, None)
    cfg, note = ppo.fit_timesteps(small, 50_000)
    assert ppo.brax_timesteps(cfg) == 81_920 and "81,920" in note and "rounded up" in note
    with pytest.raises(ValueError, match="timesteps"):
        ppo.fit_timesteps(small, 0)


@pytest.mark.parametrize("name", ["small", "full"])
def test_fitted_timesteps_are_exact_or_the_next_training_step(name):
    from jax_contact.train import ppo

    base = ppo.CONFIGS[name]
    unit = base.steps_per_training_step * max(base.num_resets_per_eval, 1)
    for requested in [1, unit - 1, unit, unit + 1, 7 * unit, 12 * unit, 13 * unit + 5, 10**7]:
        cfg, note = ppo.fit_timesteps(base, requested)
        trained = ppo.brax_timesteps(cfg)
        assert trained == cfg.num_timesteps
        assert requested <= trained < requested + unit
        assert 2 <= cfg.num_evals <= base.num_evals
        cfg.validate()
        if note is None:
            assert trained == requested and cfg.num_evals == base.num_evals
        else:
            assert f"{trained:,d}" in note


def test_brax_timesteps_mirrors_brax():
    """The formula is Brax's; this fails loudly if Brax's source changes it."""
    import inspect

    from brax.training.agents.ppo import train as ppo_train

    src = inspect.getsource(ppo_train.train)
    assert "num_evals_after_init = max(num_evals - 1, 1)" in src
    assert "max(num_resets_per_eval, 1)" in src and "np.ceil(" in src


# ------------------------------------------------------------------------------- bench


def test_sharding_batch_is_rounded_to_the_devices():
    from jax_contact.benchmarks import versus

    assert versus.shard_batch(4, 8) == 8
    assert versus.shard_batch(4096, 8) == 4096
    assert versus.shard_batch(4097, 8) == 4104
    with pytest.raises(ValueError):
        versus.shard_batch(0, 8)
    with pytest.raises(ValueError, match="--envs"):
        versus.check_sizes([4, 0])


def test_a_failed_sharding_subprocess_shows_its_stderr():
    from jax_contact.benchmarks import versus

    script = "import sys; sys.stderr.write('the real cause\\n'); sys.exit(3)"
    with pytest.raises(RuntimeError, match="(?s)exited with code 3.*the real cause"):
        versus.sharded(4, 8, script=script)


INT_ERR = "must be an int >= 1"


@pytest.mark.parametrize(
    "module, argv, expect",
    [
        ("estimator", ["--envs", "0"], INT_ERR),
        ("estimator", ["--latency-calls", "0"], INT_ERR),
        ("estimator", ["--samples", "-1"], INT_ERR),
        ("estimator", ["--json", "/proc/x.json"], "'/proc'"),
        ("estimator", ["--json", "/proc"], "argument --json: '/proc' is a folder"),
        ("estimator", ["--cpu", "100000"], "argument --cpu: cpu=100000 is not one of"),
        ("suite", ["--json", "/proc/x.json"], "'/proc'"),
        ("versus", ["--json", "/proc/x.json"], "'/proc'"),
        ("playground_envs", ["--names", "Bogus"], "unknown env(s) ['Bogus']"),  # was exit 0
        ("playground_envs", ["--steps", "0"], INT_ERR),
        ("profile_pieces", ["--repeats", "0"], INT_ERR),  # StatisticsError after compiling
        ("profile_pieces", ["--trace", "/proc/version"], "argument --trace: '/proc/version'"),
        ("profile_pieces", ["--json", "/proc"], "argument --json: '/proc' is a folder"),
        ("gait_survival", ["--n-envs", "0"], INT_ERR),  # a table of NaN and exit 0
        ("gait_survival", ["--robots", "go2"], "argument --robots: unknown robot 'go2'"),
        ("gait_survival", ["--json", "/proc"], "argument --json: '/proc' is a folder"),
        ("gait_survival", ["--min-air", "-0.1"], "argument --min-air"),
        # No step ran (the chunk is 2 s): a ZeroDivisionError after the compile.
        ("gait_survival", ["--duration", "0.0005"], "argument --duration: 0.0005 s is shorter"),
        # Not past the 1 s speed ramp: a traceback after loading the robot, and a JSON file.
        (
            "gait_survival",
            ["--duration", "0.5", "--chunk", "0.5"],
            "argument --duration: 0.5 s simulated (whole --chunk scans) is not past the gaits'"
            " 1 s speed ramp",
        ),
        ("wrapper_throughput", ["--calls", "0"], INT_ERR),
        ("wrapper_throughput", ["--env", "Go1Bogus"], "argument --env: unknown env 'Go1Bogus'"),
        ("wrapper_throughput", ["--json", "/proc"], "argument --json: '/proc' is a folder"),
        ("wrapper_accuracy", ["--envs", "Bogus"], "argument --envs: unknown env 'Bogus'"),
        ("wrapper_accuracy", ["--envs", "Go1Getup:skate"], "policy must be one of walk"),
        ("wrapper_accuracy", ["--rollouts", "0"], INT_ERR),
        ("wrapper_accuracy", ["--envs"], "argument --envs: expected at least one argument"),
        (
            "wrapper_accuracy",
            ["--params", "nosuch"],  # a traceback after loading the env
            "argument --params: parameter file 'nosuch' does not exist and is no preset name",
        ),
        ("brax_ant", ["--rollouts", "0"], INT_ERR),
        ("brax_ant", ["--policy", "hop"], "argument --policy: invalid choice: 'hop'"),
        ("brax_ant", ["--env", "hopper", "--policy", "trot"], "trot drives the ant only"),
        ("brax_ant", ["--env", "humanoid"], "argument --env: invalid choice: 'humanoid'"),
        ("brax_ant", ["--json", "/proc"], "argument --json: '/proc' is a folder"),
        ("sensor_limits", ["--robot", "go2"], "argument --robot: unknown robot 'go2'"),
        ("sensor_limits", ["--robot", "planar_leg"], "'planar_leg' has one leg"),
        ("sensor_limits", ["--envs", "0"], INT_ERR),
        ("biped_hop_fit", ["--fit", "-1"], "must be an int >= 0"),  # ran and exited 0
        ("biped_hop_fit", ["--start", "{kp: 1"], "argument --start: Expecting"),  # a traceback
        ("biped_hop_fit", ["--start", '{"kq": 1}'], "argument --start: "),  # a TypeError
        (
            "deploy_latency",
            ["--artefact", "/no/a.contact", "--log", "/no/l.h5"],
            "argument --artefact: file '/no/a.contact' does not exist",
        ),
    ],
)
def test_benchmark_scripts_check_their_arguments_before_measuring(module, argv, expect, capsys):
    """Run directly, the scripts refused a bad size, name or output path only after
    minutes of compiling and measuring (IndexError, StatisticsError, a lost result), or
    with a traceback; each is argparse's one line and exit 2 now, before any JAX work."""
    import importlib

    main = importlib.import_module(f"jax_contact.benchmarks.{module}").main
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert expect in capsys.readouterr().err


def test_deploy_latency_keeps_what_finished_and_writes_nothing_beside_its_input(
    tmp_path, monkeypatch, capsys
):
    """The parent of the latency benchmark (children faked: they compile for minutes):
    one table row per option that finished, the machine in the JSON, the re-exported
    variant in a temporary folder (it was written beside the user's artefact), and an
    option that failed in its process makes the run fail with the JSON of what finished
    (every result was lost when the last option raised)."""
    from jax_contact.benchmarks import deploy_latency as D

    art, log = tmp_path / "go1.contact", tmp_path / "go1.h5"
    art.write_bytes(b"x")
    log.write_bytes(b"x")
    made = []
    monkeypatch.setattr(D, "export_variant", lambda src, out: made.append(out) or out.touch())

    def spawn(what, env, args):
        if what == "no_xnnpack":
            return {"error": ["taskset: not found"]}
        paced = {"median_us": 300.0, "p99_us": 410.0, "max_us": 500.0, "deadline_misses": 2}
        return {"kernels": 420, "compile_s": 1.5, "median_us": 190.0, "raw_call_us": 185.0,
                "paced": paced}  # fmt: skip

    monkeypatch.setattr(D, "_spawn", spawn)
    out = tmp_path / "lat.json"
    base = ["--artefact", str(art), "--log", str(log), "--no-floor", "--json", str(out)]
    D.main([*base, "--options", "default", "dots_as_reductions"])
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(lines) if "update us" in line)
    assert "190.0" in lines[header + 1] and "410.0" in lines[header + 1]  # update vs paced p99
    assert lines[header + 2].split()[0] == "dots_as_reductions"
    got = json.loads(out.read_text())
    assert got["complete"] is True and got["machine"]["jaxlib"]
    assert got["default"]["paced"]["deadline_misses"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["go1.contact", "go1.h5", "lat.json"]
    assert made and not made[0].parent.exists()  # the temporary folder is gone
    with pytest.raises(RuntimeError, match=r"options \['no_xnnpack'\] failed"):
        D.main([*base, "--options", "default", "no_xnnpack"])
    got = json.loads(out.read_text())
    assert got["complete"] is False and got["default"]["median_us"] == 190.0
    assert got["no_xnnpack"]["error"] == ["taskset: not found"]


def test_benchmark_json_says_when_where_and_whether_complete(tmp_path):
    """A benchmark's JSON names the time, the code and the versions it ran with, and
    whether it is complete; Ctrl-C (a KeyboardInterrupt where the CLI's handler is not
    installed) writes none, as everywhere else."""
    from jax_contact.benchmarks.common import json_of_what_finished, machine

    m = machine()
    assert m["time_utc"].endswith("+00:00") and m["jaxlib"] and m["mujoco"]
    assert m["git_commit"] is None or len(m["git_commit"]) == 40
    assert m["git_dirty"] in (None, True, False)
    done = tmp_path / "done.json"
    with json_of_what_finished(str(done), {"rows": [1]}):
        pass
    assert json.loads(done.read_text()) == {"rows": [1], "complete": True}
    failed = tmp_path / "failed.json"
    with pytest.raises(RuntimeError):
        with json_of_what_finished(str(failed), {"rows": [1]}):
            raise RuntimeError("broke")
    got = json.loads(failed.read_text())
    assert got["complete"] is False and got["error"] == "RuntimeError: broke"
    stopped = tmp_path / "stopped.json"
    with pytest.raises(KeyboardInterrupt):
        with json_of_what_finished(str(stopped), {"rows": [1]}):
            raise KeyboardInterrupt
    assert not stopped.exists()


def test_bench_keeps_the_estimator_rows_measured_before_a_failure(tmp_path, monkeypatch):
    """The estimator part fills the suite's result as it measures: a failure (or Ctrl-C)
    in its latency part keeps the throughput rows already measured (the JSON held only
    the error)."""
    from jax_contact.benchmarks import estimator

    row = {"envs": 4, "mode": "quadrature", "update_ms": 1.0, "bytes_per_env": 10.0}
    monkeypatch.setattr(estimator, "throughput", lambda *a, rows, **k: rows.append(row))
    got = _suite_json_when(monkeypatch, tmp_path, estimator, "latency", "latency broke")
    assert got["throughput"] == [row] and "latency broke" in got["error"]


def _suite_json_when(monkeypatch, tmp_path, module, name: str, message: str) -> dict:
    """The suite's JSON when ``module.name`` raises ``RuntimeError(message)``."""
    from jax_contact.benchmarks import suite

    def fail(*a, **k):
        raise RuntimeError(message)

    monkeypatch.setattr(module, name, fail)
    path = tmp_path / "bench.json"
    with pytest.raises(RuntimeError, match=message):
        suite.main(["--json", str(path), "--envs", "4", "--versus-envs", "4"])
    return json.loads(path.read_text())


def test_bench_writes_what_finished_when_a_part_fails(tmp_path, monkeypatch):
    from jax_contact.benchmarks import estimator, versus

    monkeypatch.setattr(
        estimator, "main", lambda argv, into: into.update(machine="m", throughput=[1])
    )
    monkeypatch.setattr(
        versus,
        "ratio_vs_mjx",
        lambda n: {
            "ratio": {"q": 1.0},
            "ratio_with_adapter": {"q": 2.0},
            "median_ms": {"q": 3.0},
            "first_call_s": {"q": 4.0},
        },
    )
    monkeypatch.setattr(versus, "print_table", lambda *a: None)
    monkeypatch.setattr(versus, "machine", lambda: "m")
    got = _suite_json_when(monkeypatch, tmp_path, versus, "numpy_speedup", "numpy part broke")
    assert got["throughput"] == [1] and got["ratio_vs_mjx_step"]["4"]["q"] == 1.0
    assert got["ratio_vs_mjx_step"]["4"]["first_call_s"] == {"q": 4.0}  # compile apart
    assert "numpy part broke" in got["error"] and "sharding" not in got
    # The suite's own arguments (the estimator's part had "json": null, no --versus-envs).
    assert got["args"]["json"] == str(tmp_path / "bench.json") and got["args"]["versus_envs"] == [4]


# ------------------------------------------------------------------------- file modes


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield 0o027
    os.umask(old)


def test_written_files_get_the_umask(tmp_path, umask_027):
    want = 0o666 & ~umask_027
    paths = [
        io.write_json_atomic(tmp_path / "a.json", {"a": 1}),
        io.write_text_atomic(tmp_path / "b.txt", "b"),
        io.write_log(tmp_path / "c.h5", {"x": np.zeros(3)}, {"robot": "go1"}),
    ]
    (tmp_path / "d.txt").write_text("old")
    os.chmod(tmp_path / "d.txt", 0o600)
    paths.append(io.write_text_atomic(tmp_path / "d.txt", "new"))
    for p in paths:
        assert os.stat(p).st_mode & 0o777 == want, (p, oct(os.stat(p).st_mode))
    assert io._umask() == umask_027
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.txt", "c.h5", "d.txt"]


# ---------------------------------------------------------------------------- bad logs


def _planar_log(path, n_t=12, n_envs=1, *, truth=True, attrs=None, **override):
    rng = np.random.default_rng(0)
    arrays = {
        "readings/qpos": np.zeros((n_t, n_envs, 3), np.float32),
        "readings/qvel": rng.normal(size=(n_t, n_envs, 3)).astype(np.float32) * 0.01,
        "readings/qacc": np.zeros((n_t, n_envs, 3), np.float32),
        "readings/tau": np.zeros((n_t, n_envs, 3), np.float32),
        "valid": np.ones((n_t, n_envs), bool),
        "time": np.arange(n_t, dtype=np.float32) * 0.0025,
    }
    if truth:
        arrays["truth/contact"] = np.ones((n_t, n_envs, 1), bool)
    arrays.update(override)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    meta = {"robot": "planar_leg", "dt": 0.0025} if attrs is None else attrs
    return io.write_log(path, arrays, meta)


def _evaluate_error(capsys, path) -> str:
    assert cli.main(["evaluate", str(path)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jax-contact evaluate: error:"), err
    assert str(path) in lines[0]
    return lines[0]


def test_a_bad_log_among_several_is_named_before_any_is_replayed(tmp_path, capsys, monkeypatch):
    """evaluate read each log when its turn came: a bad last log failed after the earlier
    logs' replays (a compile and minutes each), and nothing was written. Every log is read
    and checked first now."""
    from jax_contact.train import evaluate

    def replay(*args, **kwargs):
        raise AssertionError("a log was replayed before every log was checked")

    monkeypatch.setattr(evaluate, "replay", replay)
    bad = tmp_path / "b.h5"
    bad.write_text("not HDF5")
    good = ROOT / "tests/fixtures/planar_leg_hop.h5"
    assert cli.main(["evaluate", str(good), str(bad), "--json", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jax-contact evaluate: error:") and str(bad) in err, err
    assert not (tmp_path / "m.json").exists()


def test_a_non_hdf5_log_is_one_line(tmp_path, capsys):
    path = tmp_path / "text.h5"
    path.write_text("not an HDF5 file\n")
    with pytest.raises(ValueError, match="cannot be read as HDF5"):
        io.read_log(path)
    assert "expected an .h5 file" in _evaluate_error(capsys, path)


def test_a_truncated_log_is_one_line(tmp_path, capsys):
    path = _planar_log(tmp_path / "log.h5", n_t=2000)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=str(path)):
        io.read_log(path)
    line = _evaluate_error(capsys, path)
    assert "truncated" in line or "HDF5" in line


def test_a_log_without_robot_attribute_is_one_line(tmp_path, capsys):
    path = _planar_log(tmp_path / "log.h5", attrs={"dt": 0.0025})
    assert "no attribute 'robot'" in _evaluate_error(capsys, path)
    path = _planar_log(tmp_path / "log2.h5", attrs={"robot": "planar_leg"})
    assert "attribute 'dt'" in _evaluate_error(capsys, path)


def test_arrays_without_the_env_axis_are_one_line(tmp_path, capsys):
    path = _planar_log(
        tmp_path / "log.h5",
        **{k: np.zeros((12, 3), np.float32) for k in ("readings/qpos", "readings/qvel")},
    )
    line = _evaluate_error(capsys, path)
    assert "'readings/qpos'" in line and "(12, 3)" in line and "(T, n_envs, nq)" in line
    path = _planar_log(tmp_path / "log2.h5", **{"readings/tau": np.zeros((12, 3), np.float32)})
    line = _evaluate_error(capsys, path)
    assert "'readings/tau'" in line and "(12, 1, nv)" in line
    path = _planar_log(tmp_path / "log3.h5", **{"readings/tau": None})
    assert "missing arrays ['readings/tau']" in _evaluate_error(capsys, path)
    path = _planar_log(tmp_path / "log4.h5", **{"readings/qvel": np.zeros((12, 1, 5), "f4")})
    line = _evaluate_error(capsys, path)
    assert "'readings/qvel'" in line and "nv = 3" in line


def test_a_log_without_ground_truth_gives_p_contact(tmp_path, capsys):
    """No truth/contact: no metrics, the estimator's P(contact) per foot (issue 18)."""
    path = _planar_log(tmp_path / "log.h5", truth=False)
    out_json = tmp_path / "p.json"
    plots = tmp_path / "plots"
    argv = [
        "evaluate",
        str(path),
        "--json",
        str(out_json),
        "--bootstrap",
        "9",
        "--plots",
        str(plots),
        "--gm-grid",
        str(_planar_log(tmp_path / "grid.h5", n_t=40, n_envs=2)),
    ]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "no ground truth" in out and "no metrics" in out and "P(contact)" in out
    assert "--bootstrap: no ground truth, so there is nothing to compare" in out
    assert "--gm-grid: no ground truth, so no baseline is scored on this log" in out
    assert "--plots: no ground truth, so no reliability diagram" in out and not plots.exists()
    got = json.loads(out_json.read_text())
    assert got["has_truth"] is False and got["scores"] == {}
    assert got["params"] == {"source": "defaults"}
    (foot,) = got["foot_names"]
    p = np.array(got["p_contact"][foot], dtype=float)
    assert p.shape == (12, 1)
    # Truth never feeds the estimator: the same readings with a truth column give the same
    # P(contact), step for step (a step the estimator cannot score is NaN in both).
    from jax_contact.train.log_evaluate import evaluate_file

    same = _planar_log(tmp_path / "with_truth.h5", truth=True)
    want = np.asarray(evaluate_file(same)["outputs"]["probabilistic"], float)[..., 0]
    capsys.readouterr()
    assert np.isfinite(p).sum() >= 10, p  # at most the first steps before a pair of readings
    np.testing.assert_allclose(p, want, rtol=1e-6, atol=1e-7, equal_nan=True)


def test_a_log_without_ground_truth_reports_p_through_the_files_map(tmp_path, capsys):
    """With a --params file that holds a calibration map, a truth-less log's P(contact) is
    the file's raw P read through that map, as estimate, export and the wrapper report it
    (it was the raw P). The reference: the same readings with truth, whose raw row is the
    estimator's own output, mapped here by hand: l' = l / T_c above 0, l / T_a below."""
    import jax_contact as jc
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.log_estimator import default_estimator
    from jax_contact.train.log_evaluate import evaluate_file

    desc = load_robot("planar_leg").description
    params, _ = default_estimator(desc, 0.0025)
    cal = {"kind": "sign", "temperature": 0.8, "bias": 0.0, "temperature_air": 2.0}
    file = jc.save_params(tmp_path / "mapped.json", params, {"calibration": cal})
    path = _planar_log(tmp_path / "log.h5", truth=False)
    out_json = tmp_path / "p.json"
    assert cli.main(["evaluate", str(path), "--params", str(file), "--json", str(out_json)]) == 0
    assert "read through the calibration map" in capsys.readouterr().out
    got = json.loads(out_json.read_text())
    assert got["p_contact_calibrated"] is True
    p = np.array(got["p_contact"]["foot"], dtype=float)[..., 0]
    same = _planar_log(tmp_path / "with_truth.h5", truth=True)
    raw = np.asarray(evaluate_file(same, params_path=file)["outputs"]["probabilistic"], float)
    raw = raw[:, 0, 0]  # (T, E, L): env 0's only foot
    logit = np.log(raw) - np.log1p(-raw)
    mapped = 1 / (1 + np.exp(-np.where(logit > 0, logit / 0.8, logit / 2.0)))
    capsys.readouterr()
    assert np.isfinite(p).sum() >= 10
    np.testing.assert_allclose(p, mapped, rtol=1e-5, atol=1e-6, equal_nan=True)
    assert not np.allclose(p[np.isfinite(p)], raw[np.isfinite(p)], atol=1e-3)


def test_evaluate_pools_several_logs(tmp_path, capsys):
    """``evaluate A B C``: each log's own table, then the logs with ground truth of one
    robot and rate pooled. Every env of every log is its own sequence, so (hand
    derivation) the pooled counts are the sums of the logs' own and the per-step scores
    their step-weighted means; a log without truth is named as not pooled; the bootstrap
    resamples the pooled envs."""
    rng = np.random.default_rng(3)
    a = _planar_log(
        tmp_path / "a.h5", n_t=40, n_envs=2, **{"truth/contact": rng.random((40, 2, 1)) < 0.5}
    )
    b = _planar_log(
        tmp_path / "b.h5", n_t=30, n_envs=1, **{"truth/contact": rng.random((30, 1, 1)) < 0.5}
    )
    c = _planar_log(tmp_path / "c.h5", n_t=20, truth=False)
    out_json = tmp_path / "pooled.json"
    argv = ["evaluate", str(a), str(b), str(c), "--json", str(out_json), "--bootstrap", "9"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "a.h5" in out and "b.h5" in out and "2 logs pooled" in out
    assert f"note: {str(c)!r} is not pooled: no ground truth" in out
    got = json.loads(out_json.read_text())
    assert [r["log"] for r in got["logs"]] == [str(a), str(b), str(c)]
    assert got["pooled_logs"] == [str(a), str(b)] and got["not_pooled"] == {
        str(c): "no ground truth"
    }
    assert got["logs"][2]["scores"] == {}
    each = [r["scores"] for r in got["logs"][:2]]
    assert set(got["pooled"]) == set(each[0]) == {"probabilistic", "gm", "kinematic"}
    for row, pooled in got["pooled"].items():
        n = [e[row]["n_steps"] for e in each]
        assert pooled["n_steps"] == sum(n) == 2 * 40 + 30
        for count in ("failures", "n_air_phases", "n_touchdowns", "missed", "n_liftoffs"):
            assert pooled[count] == sum(e[row][count] for e in each), (row, count)
        for mean in ("accuracy", "brier"):
            want = sum(e[row][mean] * k for e, k in zip(each, n, strict=True)) / sum(n)
            assert pooled[mean] == pytest.approx(want, abs=1e-12), (row, mean)
    assert set(got["vs_probabilistic"]) == {"gm", "kinematic"}
    # The same log twice would count twice; two logs of one name would draw one PNG.
    assert cli.main(["evaluate", str(a), str(tmp_path / "." / "a.h5")]) == 2
    assert "given twice" in capsys.readouterr().err
    # A hard link or a copy is the same log too (a helper's audit: pooled twice, its envs
    # gave the bootstrap calls that one log's 3 envs could not).
    os.link(a, tmp_path / "hard.h5")
    assert cli.main(["evaluate", str(a), str(tmp_path / "hard.h5")]) == 2
    assert f"{str(tmp_path / 'hard.h5')!r} is given twice (as {str(a)!r}" in capsys.readouterr().err
    (tmp_path / "copy.h5").write_bytes(a.read_bytes())
    assert cli.main(["evaluate", str(a), str(tmp_path / "copy.h5")]) == 2
    assert "holds the same bytes as" in capsys.readouterr().err
    (tmp_path / "hard.h5").unlink()
    (tmp_path / "copy.h5").unlink()
    (tmp_path / "other").mkdir()
    a2 = _planar_log(tmp_path / "other" / "a.h5")
    assert cli.main(["evaluate", str(a), str(a2), "--plots", str(tmp_path / "plots")]) == 2
    err = capsys.readouterr().err
    assert "argument --plots" in err and "reliability_a.png" in err
    assert not (tmp_path / "plots").exists()


def test_logs_of_different_robots_are_named_as_such_not_by_rate(tmp_path, capsys):
    """Two logs with truth, one robot each (the planar leg by name, and by its MJCF path
    with another physics' fingerprint, so both load): the notes said the first had "no
    other log at its rate" (both were at 400 Hz) and the second that it was not "the
    pooled logs'" robot, with nothing pooled. The same model by name and by path is one
    robot, pooled, as --gm-grid takes it (a helper's trial: it was not pooled)."""
    from jax_contact.envs.model_files import PLANAR_LEG_XML

    rng = np.random.default_rng(3)
    a = _planar_log(
        tmp_path / "a.h5", n_t=40, n_envs=2, **{"truth/contact": rng.random((40, 2, 1)) < 0.5}
    )
    other = {"robot": str(PLANAR_LEG_XML), "dt": 0.0025, "model_sha256": "0" * 64}
    b = _planar_log(
        tmp_path / "b.h5", n_t=40, n_envs=2, attrs=other,
        **{"truth/contact": rng.random((40, 2, 1)) < 0.5},
    )  # fmt: skip
    assert cli.main(["evaluate", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert f"note: {str(a)!r} is not pooled: no other log of robot 'planar_leg' with" in out
    assert f"note: {str(b)!r} is not pooled: no other log of robot {str(PLANAR_LEG_XML)!r}" in out
    same = {"robot": str(PLANAR_LEG_XML), "dt": 0.0025}
    c = _planar_log(
        tmp_path / "c.h5", n_t=40, n_envs=2, attrs=same,
        **{"truth/contact": rng.random((40, 2, 1)) < 0.5},
    )  # fmt: skip
    assert cli.main(["evaluate", str(a), str(c)]) == 0
    out = capsys.readouterr().out
    assert "2 logs pooled" in out and "not pooled" not in out


def test_the_largest_set_of_one_robot_and_rate_is_pooled_whatever_the_order(tmp_path, capsys):
    """A helper's case: two logs of robot A at two rates and two of robot B at one rate
    pooled nothing ("fewer than two logs ... of one robot and rate"): the robot with the
    most logs was taken first, then its logs split by rate. Now the largest (robot, rate)
    set is pooled, B's two logs, named first or last. (B is the planar leg's MJCF with
    another physics' fingerprint: by its path alone it is A, and pooled with it.)"""
    from jax_contact.envs.model_files import PLANAR_LEG_XML

    rng = np.random.default_rng(4)

    def log(name, robot, dt):
        other = {"model_sha256": "0" * 64} if robot == str(PLANAR_LEG_XML) else {}
        return _planar_log(
            tmp_path / name,
            n_t=40,
            n_envs=2,
            attrs={"robot": robot, "dt": dt, **other},
            time=np.arange(40, dtype=np.float32) * dt,
            **{"truth/contact": rng.random((40, 2, 1)) < 0.5},
        )

    a400, a200 = log("a400.h5", "planar_leg", 0.0025), log("a200.h5", "planar_leg", 0.005)
    b1, b2 = log("b1.h5", str(PLANAR_LEG_XML), 0.0025), log("b2.h5", str(PLANAR_LEG_XML), 0.0025)
    for order in ([a400, a200, b1, b2], [b1, b2, a400, a200]):
        out_json = tmp_path / "r.json"
        assert cli.main(["evaluate", *map(str, order), "--json", str(out_json)]) == 0
        out = capsys.readouterr().out
        got = json.loads(out_json.read_text())
        assert got["pooled_logs"] == [str(b1), str(b2)], order
        for a in (a400, a200):
            want = f"robot 'planar_leg'; the pooled ones' is {str(PLANAR_LEG_XML)!r}"
            assert got["not_pooled"][str(a)] == want
            assert f"note: {str(a)!r} is not pooled: {want}" in out


def test_a_gm_grid_or_validation_log_of_another_robot_or_rate_is_refused_first(
    tmp_path, capsys, monkeypatch
):
    """``evaluate --gm-grid`` took a Barkour log to tune GM for a Go1 log (thresholds in N
    of Barkour's foot load) without a word, and ``tune`` refused a validation log of
    another robot only after loading and compiling the first. Both are refused from the
    logs' attributes now, before any replay or load."""
    from jax_contact.train import evaluate, tune_inputs

    def boom(*args, **kwargs):
        raise AssertionError("a log was replayed or loaded before the logs were checked")

    monkeypatch.setattr(evaluate, "replay", boom)
    monkeypatch.setattr(tune_inputs, "load_tuning_log", boom)
    a = _planar_log(tmp_path / "a.h5")
    b = _planar_log(tmp_path / "b.h5", n_t=13)  # another log (a copy is refused as a's)
    go1 = _planar_log(tmp_path / "go1.h5", attrs={"robot": "go1", "dt": 0.0025})
    slow = _planar_log(tmp_path / "slow.h5", attrs={"robot": "planar_leg", "dt": 0.005})
    for logs, grid, want in (
        ([a], go1, "'go1' at 400 Hz"),
        ([a, b], go1, "'go1' at 400 Hz"),
        ([a], slow, "'planar_leg' at 200 Hz"),
    ):
        argv = ["evaluate", *map(str, logs), "--gm-grid", str(grid)]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert f"argument --gm-grid: log {str(grid)!r} is {want}, the evaluated log" in err, err
    argv = ["tune", str(a), "--validate", str(go1), "--out", str(tmp_path / "t.json")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert f"argument --validate: log {str(go1)!r} has robot 'go1'; the first tuning" in err
    assert not (tmp_path / "t.json").exists()


def test_evaluate_plots_writes_the_reliability_diagram_of_every_scored_row(tmp_path, capsys):
    """``evaluate --plots DIR`` (issue 15): one PNG, named after the log, one curve per
    detector; an unwritable folder is refused before anything runs."""
    rng = np.random.default_rng(1)
    truth = rng.random((40, 2, 1)) < 0.5
    path = _planar_log(tmp_path / "hop.h5", n_t=40, n_envs=2, **{"truth/contact": truth})
    plots = tmp_path / "plots"
    assert cli.main(["evaluate", str(path), "--plots", str(plots)]) == 0
    png = plots / "reliability_hop.png"
    assert f"wrote {png}" in capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and os.listdir(plots) == [png.name]
    (tmp_path / "file").write_text("")
    assert cli.main(["evaluate", str(path), "--plots", str(tmp_path / "file")]) == 2
    assert "argument --plots" in capsys.readouterr().err
    # With --params FILE the JSON records which file (path, hash), and says where it went.
    import hashlib

    import jax_contact as jc
    from jax_contact.train.reproduce import planar_estimator_params

    params = jc.save_params(tmp_path / "planar.json", planar_estimator_params(3, 0.0025))
    out_json = tmp_path / "m.json"
    assert cli.main(["evaluate", str(path), "--params", str(params), "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    assert f"probabilistic: the estimator with --params '{params}'" in out
    assert f"wrote {out_json}" in out
    got = json.loads(out_json.read_text())["params"]
    assert got["source"] == "file" and got["path"] == str(params.resolve())
    assert got["sha256"] == hashlib.sha256(params.read_bytes()).hexdigest()


def test_several_logs_plots_appear_together_or_not_at_all(tmp_path, capsys, monkeypatch):
    """A helper's Ctrl-C after two of three logs left their two PNGs in a new --plots
    folder: the PNGs are now staged and moved in when every log is done. Also: a log
    without truth among several said "pass --json FILE" although --json was given."""
    from jax_contact.train import log_evaluate, recording_batch

    rng = np.random.default_rng(5)
    a, b = (
        _planar_log(
            tmp_path / f"{n}.h5",
            n_t=40,
            n_envs=2,
            **{"truth/contact": rng.random((40, 2, 1)) < 0.5},
        )
        for n in ("a", "b")
    )
    c = _planar_log(tmp_path / "c.h5", n_t=30, n_envs=2, truth=False)
    plots = tmp_path / "new" / "plots"

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:  # the stop after every log's plot was drawn
        m.setattr(recording_batch, "pooled_arrays", stop)
        with pytest.raises(KeyboardInterrupt):
            log_evaluate.evaluate_files([a, b], plots_dir=plots)
    assert not plots.exists() and not (tmp_path / "new").exists()
    capsys.readouterr()
    out_json = tmp_path / "r.json"
    argv = ["evaluate", str(a), str(b), str(c), "--plots", str(plots), "--json", str(out_json)]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert sorted(os.listdir(plots)) == ["reliability_a.png", "reliability_b.png"]
    assert f"wrote 2 reliability diagram(s) into {plots}" in out
    assert f"P(contact) per foot, step and env goes into {out_json} with the other logs'" in out
    assert "pass --json FILE" not in out
    got = json.loads(out_json.read_text())
    assert got["logs"][0]["plots"] == [str(plots / "reliability_a.png")]


def test_a_slow_log_gets_a_gm_observer_that_does_not_diverge(tmp_path, capsys):
    """evaluate's default K_I (50 1/s) on a 20 Hz log has K_I dt = 2.5, where the discrete
    observer diverges (1e8 N, a helper's audit). The default is lowered to 1 / dt with a
    note, and replay refuses a GM with K_I dt > 1, naming it."""
    from jax_contact.baselines import make_gm_params
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.evaluate import replay
    from jax_contact.train.log_evaluate import evaluate_file

    rng = np.random.default_rng(7)
    n_t, dt = 40, 0.05
    path = _planar_log(
        tmp_path / "slow.h5", n_t=n_t, n_envs=2, attrs={"robot": "planar_leg", "dt": dt},
        time=np.arange(n_t, dtype=np.float32) * dt,
        **{"truth/contact": rng.random((n_t, 2, 1)) < 0.5},
    )  # fmt: skip
    result = evaluate_file(path)
    assert "GM observer's default K_I is lowered to 1 / dt = 20 1/s" in capsys.readouterr().out
    assert result["gm"]["K_I"] == pytest.approx(20.0)
    assert np.isfinite(result["outputs"]["gm_force/gm"]).all()
    readings = {k: np.zeros((3, 1, 3), np.float32) for k in ("qpos", "qvel", "qacc", "tau")}
    with pytest.raises(ValueError, match=r"gms\['fast'\] has K_I = 50 1/s, and K_I dt = 2.5 > 1"):
        replay(
            load_robot("planar_leg"), readings, estimators={}, terrain=None,
            gms={"fast": make_gm_params(K_I=50.0)}, dt=dt, progress=False,
        )  # fmt: skip


def test_logs_of_one_file_name_are_titled_by_their_paths(tmp_path, capsys):
    """Two tables both titled 'log.h5' (a helper's audit) could not be told apart."""
    rng = np.random.default_rng(6)
    paths = []
    for d in ("dA", "dB"):
        (tmp_path / d).mkdir()
        truth = {"truth/contact": rng.random((40, 2, 1)) < 0.5}
        paths.append(str(_planar_log(tmp_path / d / "log.h5", n_t=40, n_envs=2, **truth)))
    assert cli.main(["evaluate", *paths]) == 0
    out = capsys.readouterr().out
    assert all(f"{p} " in out or f"{p}\n" in out for p in paths), out
    assert "sensor presets" not in out  # one preset (the logs name none: anymal_like)
    # Logs of two sensor presets pool with a note: each ran its own preset's defaults.
    third = tmp_path / "ideal.h5"
    truth = {"truth/contact": rng.random((40, 2, 1)) < 0.5}
    _planar_log(
        third,
        n_t=40,
        n_envs=2,
        attrs={"robot": "planar_leg", "dt": 0.0025, "noise": "ideal"},
        **truth,
    )
    assert cli.main(["evaluate", paths[0], str(third)]) == 0
    out = capsys.readouterr().out
    assert (
        "note: the pooled logs were simulated with the sensor presets ['anymal_like', 'ideal']"
        in out
    )


def test_tune_refuses_mixed_copied_and_unscoreable_logs(tmp_path):
    """``jax-contact tune``'s logs (tune_inputs.load_logs) are refused before any fit when they
    mix sensor models or periods (the fit would start from whichever came first), when a
    validation log is a tuning log's run under another name, when a tuning log is given
    twice, when a log has no step that counts, and when the tuning logs hold one class
    only."""
    from jax_contact.train import tune_inputs

    rng = np.random.default_rng(2)
    truth = {"truth/contact": rng.random((12, 1, 1)) < 0.5}
    attrs = {"robot": "planar_leg", "dt": 0.0025, "noise": "anymal_like", "gait": "hop"}
    attrs["reading_timing"] = "end_of_step"  # as simulate writes today

    def log(name, seed, **kw):
        a = {**attrs, "seed": seed, **kw.pop("attrs", {})}
        return str(_planar_log(tmp_path / name, attrs=a, **{**truth, **kw}))

    def refused(logs, validate, match):
        args = argparse.Namespace(
            logs=logs, validate=validate, terrain_model="flat", noise_floor="none"
        )
        with pytest.raises(ValueError, match=match):
            tune_inputs.load_logs(args)

    a, b = log("a.h5", 0), log("b.h5", 1)
    harsh = log("harsh.h5", 2, attrs={"noise": "harsh"})
    refused([a, harsh], [b], r"argument LOG: log '.*harsh.h5' has sensor noise 'harsh'; the"
            r" first tuning log '.*a.h5' has 'anymal_like'")  # fmt: skip
    slow = log("slow.h5", 3, attrs={"dt": 0.005})
    refused([a], [slow], r"argument --validate: log '.*slow.h5' has period dt 5 ms \(200 Hz\);"
            r" the first tuning log '.*a.h5' has 2.5 ms \(400 Hz\)")  # fmt: skip
    refused([a, str(Path(a))], [b], r"argument LOG: '.*a.h5' is the same run as tuning log")
    copy = tmp_path / "copy.h5"
    copy.write_bytes(Path(a).read_bytes())
    refused([a], [str(copy)], r"'.*copy.h5' is the same run .* seed 0\) as tuning log")
    dead = log("dead.h5", 4, valid=np.zeros((12, 1), bool))
    refused([a], [dead], r"validation log '.*dead.h5' has no step that counts")
    on = log("on.h5", 5, **{"truth/contact": np.ones((12, 1, 1), bool)})
    refused([on], [b], r"the tuning logs have no air step among their 12 counted steps")
    blind = str(_planar_log(tmp_path / "blind.h5", truth=False, attrs={**attrs, "seed": 6}))
    refused([a], [blind], r"argument --validate: log '.*blind.h5' has no ground truth .*"
            r" neither be tuned on nor validate a fit")  # fmt: skip


def test_sensor_limit_variants_each_remove_only_what_they_name(capsys):
    from jax_contact.benchmarks import sensor_limits
    from jax_contact.envs.sensors import SensorParams

    v = sensor_limits.sensor_variants(18, 0.0025)
    base = v["anymal_like"]
    fields = [f.name for f in dataclasses.fields(SensorParams)]

    def changed(p):
        return {
            f
            for f in fields
            if not np.array_equal(np.asarray(getattr(p, f)), np.asarray(getattr(base, f)))
        }

    assert changed(v["no_latency"]) == {"latency"} and v["no_latency"].latency == 0
    assert changed(v["no_outliers"]) == {"outlier_prob"}
    assert changed(v["no_base_drift"]) == {"bias_rw_q", "bias_rw_qd"}
    assert changed(v["joint_qd_half"]) == {"sigma_qd"}
    # Halved on the 12 joints (0.3 -> 0.15 rad/s, sensors.py's anymal_like), base untouched.
    np.testing.assert_allclose(np.asarray(v["joint_qd_half"].sigma_qd)[6:], 0.15, rtol=1e-6)
    np.testing.assert_array_equal(v["joint_qd_half"].sigma_qd[:6], base.sigma_qd[:6])
    # noise_free keeps the one-step latency and nothing else of anymal_like; ideal is on time.
    assert v["noise_free"].latency == base.latency == 1 and v["ideal"].latency == 0
    for name in ("noise_free", "ideal"):
        for f in ("sigma_q", "sigma_qd", "sigma_tau", "sigma_acc", "bias_rw_q", "bias_rw_qd"):
            assert not np.any(np.asarray(getattr(v[name], f))), (name, f)
        assert float(v[name].outlier_prob) == 0.0
    with pytest.raises(SystemExit) as stop:
        sensor_limits.main(["--envs", "0"])
    assert stop.value.code == 2 and "argument --envs" in capsys.readouterr().err


def test_evaluate_notes_a_kinematic_detector_that_wins_and_prints_no_nan_delays():
    """Hand cases: the estimator's F1 0.695 against the kinematic detector's 0.907 (the
    hexapod's defaults, a user trial) gets the note; 0.90 against 0.91 (within the 0.02
    margin) does not. A delay with no detected event prints as 'none found', not nan±nan."""
    from jax_contact.train.log_evaluate import weaker_than_kinematic
    from jax_contact.train.report import format_delay

    est = {"f1": 0.695, "n_touchdowns": 20}
    note = weaker_than_kinematic({"probabilistic": est, "kinematic": {"f1": 0.907}})
    assert note.startswith("note: the kinematic detector's F1 (0.907) beats the estimator's")
    est = {"f1": 0.90, "n_touchdowns": 100}
    assert weaker_than_kinematic({"probabilistic": est, "kinematic": {"f1": 0.91}}) is None
    # A log too short to judge the parameters (a 2-step log drew it, F1 0.444 vs 0.857).
    est = {"f1": 0.444, "n_touchdowns": 19}
    assert weaker_than_kinematic({"probabilistic": est, "kinematic": {"f1": 0.857}}) is None
    assert weaker_than_kinematic({"probabilistic": {"f1": 0.9}}) is None  # no kinematic row
    assert format_delay((float("nan"), float("nan"))) == "none found"
    # ... and a truth with no event of the kind says so (a 0.5 s walk has no touch-down).
    assert format_delay((float("nan"), float("nan")), n_true=0) == "no true event"
    assert format_delay((float("nan"), float("nan")), n_true=3) == "none found"
    assert format_delay((4.25, 1.5)) == "  4.2±1.5  "


def test_train_checks_its_run_folders_before_anything_runs(tmp_path, capsys):
    """A file where a run folder goes gave '[Errno 20] Not a directory' after JAX loaded;
    an existing run without --overwrite was refused only then too. Both are one line now,
    naming --out; an interrupted run's note is asked when the stop comes, so it says
    whether there is any checkpoint to evaluate."""
    from jax_contact.train.run_folder import EarlierRun

    (tmp_path / "none").write_text("x")
    assert cli.main(["train", "--variants", "none", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "argument --out: run folder" in err and "exists and is not a folder" in err
    run = tmp_path / "runs" / "truth"
    run.mkdir(parents=True)
    (run / "run.json").write_text('{"finished": false}')
    assert cli.main(["train", "--variants", "truth", "--out", str(tmp_path / "runs")]) == 2
    assert "holds an unfinished run" in capsys.readouterr().err
    # Stopped before its first checkpoint, a run holds nothing to evaluate: its folder goes
    # (it was kept, and the next train into it asked for --overwrite: a helper's trial).
    note = EarlierRun(run, False).note()
    assert "nothing of the run is kept" in note and not run.exists(), note
    run.mkdir()
    (run / "run.json").write_text('{"finished": false}')
    (run / "checkpoints" / "000").mkdir(parents=True)  # a save stopped midway: no checkpoint
    assert "nothing of the run is kept" in EarlierRun(run, False).note() and not run.exists()
    (run / "checkpoints" / "000").mkdir(parents=True)
    (run / "checkpoints" / "000" / "ppo_network_config.json").write_text("{}")  # Brax's last
    note = EarlierRun(run, False).note()
    assert "with the checkpoints saved so far:" in note and "policy-eval" in note


def test_a_folder_where_an_output_file_goes_is_refused_at_once(tmp_path, capsys):
    """reproduce and estimate found a folder named like one of their files only at the
    final move, after all the work (minutes at the demo's size), with an errno naming
    their staging folder; evaluate --plots after the metrics."""
    (tmp_path / "rep" / "table3.json").mkdir(parents=True)
    assert cli.main(["reproduce", "--out", str(tmp_path / "rep")]) == 2
    assert "argument --out: " in capsys.readouterr().err
    (tmp_path / "est" / "estimate.csv").mkdir(parents=True)
    argv = [
        "estimate",
        str(ROOT / "tests/fixtures/planar_leg_hop.csv"),
        "--model",
        str(ROOT / "envs/assets/planar_leg.xml"),
    ]
    assert cli.main([*argv, "--out", str(tmp_path / "est")]) == 2
    assert "estimate.csv' is a folder where this command writes a file" in capsys.readouterr().err
    (tmp_path / "plots" / "reliability_planar_leg_hop.png").mkdir(parents=True)
    log = str(ROOT / "tests/fixtures/planar_leg_hop.h5")
    assert cli.main(["evaluate", log, "--plots", str(tmp_path / "plots")]) == 2
    assert "argument --plots: " in capsys.readouterr().err


def test_a_negative_force_threshold_is_refused_before_anything_runs(tmp_path, capsys):
    """--force-threshold -1 read every zero-force row as contact, with only the note's
    "100 % contact" to show it; refused like any bad argument."""
    argv = ["estimate", str(ROOT / "tests/fixtures/planar_leg_hop.csv"), "--model", "planar_leg"]
    assert cli.main([*argv, "--out", str(tmp_path / "o"), "--force-threshold", "-1"]) == 2
    assert "argument --force-threshold: must be a finite force >= 0 N, got -1.0" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "o").exists()


def test_an_output_that_is_an_input_or_a_runs_file_is_refused_at_once(tmp_path, capsys):
    """evaluate's and rates' --json could replace the --params file they read (a tuned
    file lost after minutes of evaluation); policy-eval's and transfer's --json a run's
    run.json (the run then unreadable); estimate's outputs a recording kept in --out;
    tune's --out and deploy-check's --json the --names map. Each is refused before
    anything runs, the input left as it was."""
    params = tmp_path / "tuned.json"
    params.write_text((ROOT / "jax_contact/presets/go1.json").read_text())
    before = params.read_text()
    log = str(ROOT / "tests/fixtures/planar_leg_hop.h5")
    for argv in (
        ["evaluate", log, "--params", str(params), "--json", str(params)],
        ["rates", "--params", str(params), "--json", str(params)],
    ):
        assert cli.main(argv) == 2, argv
        assert "argument --json: " in capsys.readouterr().err
    assert params.read_text() == before

    run = tmp_path / "runs" / "seed0" / "estimate"
    run.mkdir(parents=True)
    record = {"variant": "estimate", "task": "go1", "config": "tiny", "finished": True}
    (run / "run.json").write_text(json.dumps(record))
    (tmp_path / "runs" / "seed0" / "summary.json").write_text("{}")
    for argv in (
        ["policy-eval", str(run), "--json", str(run / "run.json")],
        ["transfer", str(tmp_path / "runs"), "--json", str(run / "run.json")],
        ["transfer", str(tmp_path / "runs"), "--json", str(run / "checkpoints" / "x.json")],
        ["transfer", str(tmp_path / "runs"), "--json", str(tmp_path / "runs/seed0/summary.json")],
    ):
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "argument --json: " in err and "is a file of the run in" in err, err
    assert json.loads((run / "run.json").read_text()) == record

    out = tmp_path / "est"
    out.mkdir()
    recording = out / "estimate.csv"  # the user's recording, kept where the outputs go
    recording.write_text((ROOT / "tests/fixtures/planar_leg_hop.csv").read_text())
    argv = ["estimate", str(recording), "--model", "planar_leg", "--out", str(out)]
    assert cli.main(argv) == 2
    assert "argument --out: " in capsys.readouterr().err
    names = tmp_path / "map.json"
    names.write_text('{"a": "b"}')
    csv = str(ROOT / "tests/fixtures/planar_leg_hop.csv")
    copy = tmp_path / "v.csv"  # a validation recording other than the tuning one
    copy.write_text(Path(csv).read_text())
    argv = ["tune", csv, "--validate", str(copy), "--model", "planar_leg"]
    assert cli.main([*argv, "--names", str(names), "--out", str(names)]) == 2
    assert "argument --out: " in capsys.readouterr().err
    assert names.read_text() == '{"a": "b"}'


def test_rates_says_where_it_wrote_its_json(tmp_path, monkeypatch, capsys):
    """A helper's audit: ``rates --json`` wrote its file without a word, where ``bench``
    and ``policy-eval`` say so. The scene's run is stood in for (its minute is not what
    is tested)."""
    from jax_contact.train import rates

    monkeypatch.setattr(rates, "run", lambda scenes, **kw: {scenes[0]: {"accuracy": 0.9}})
    out = tmp_path / "rates.json"
    assert cli.main(["rates", "--scenes", "planar_leg", "--json", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    assert json.loads(out.read_text()) == {"planar_leg": {"accuracy": 0.9}}


def test_tune_out_replaces_a_parameter_file_but_no_other_json(tmp_path, capsys):
    """A helper's audit: ``tune --out results.json`` replaced an ``evaluate --json`` report
    with a parameter file, saying only 'wrote results.json'. Now another JSON is refused
    before JAX loads, unchanged; a parameter file (or an empty file) is replaced."""
    import jax_contact as jc
    from jax_contact.train.tune_cmd import check_replaces_a_parameter_file

    log = str(ROOT / "tests/fixtures/planar_leg_hop.h5")
    val = tmp_path / "val.h5"
    val.write_bytes(Path(log).read_bytes())
    report = tmp_path / "results.json"
    report.write_text('{"my": "evaluation results I want to keep"}')
    assert cli.main(["tune", log, "--validate", str(val), "--out", str(report)]) == 2
    err = capsys.readouterr().err
    assert f"argument --out: {str(report)!r} exists and holds JSON that is no parameter" in err
    assert report.read_text() == '{"my": "evaluation results I want to keep"}'
    params = tmp_path / "params.json"
    jc.save_params(params, jc.load_params("go1"))
    check_replaces_a_parameter_file("--out", str(params))
    (tmp_path / "empty.json").write_text("")
    check_replaces_a_parameter_file("--out", str(tmp_path / "empty.json"))


def test_json_output_that_is_a_device_fifo_or_log_is_refused_and_a_link_written_through(
    tmp_path, capsys
):
    """A helper's audit: --json onto a FIFO (or, as root, /dev/null) was replaced by a
    5 KB file, as was a symbolic link (its target untouched), and --json naming another
    log overwrote it. Now the FIFO and the log are refused before JAX loads, and the
    library's atomic write refuses a FIFO and writes through a link (the link kept)."""
    from jax_contact.io import write_text_atomic

    log = str(ROOT / "tests/fixtures/planar_leg_hop.h5")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    other = tmp_path / "other.h5"
    other.write_bytes(Path(log).read_bytes())
    # A CSV recording whose header starts "time," passed a first-byte test (a second
    # helper's check): now the file must parse as JSON to be replaced.
    csv = tmp_path / "rec.csv"
    csv.write_text("time,q/FR_hip\n0,0\n")
    for path, says in (
        (fifo, "is a FIFO, not a file"),
        (other, "holds no JSON"),
        (csv, "holds no JSON"),
    ):
        assert cli.main(["evaluate", log, "--json", str(path)]) == 2
        err = capsys.readouterr().err
        assert f"argument --json: {str(path)!r} " in err and says in err, err
    assert fifo.is_fifo() and other.read_bytes() == Path(log).read_bytes()
    assert csv.read_text() == "time,q/FR_hip\n0,0\n"
    csv.unlink()
    # A tuned parameter file is JSON, but a report over it loses minutes of tuning (a
    # helper's trial: evaluate --json replaced a second tuned file without a word).
    import jax_contact as jc

    tuned = tmp_path / "tuned.json"
    jc.save_params(tuned, jc.load_params("go1"))
    held = tuned.read_bytes()
    assert cli.main(["evaluate", log, "--json", str(tuned)]) == 2
    err = capsys.readouterr().err
    assert f"argument --json: {str(tuned)!r} holds a parameter file" in err, err
    assert tuned.read_bytes() == held
    tuned.unlink()
    with pytest.raises(OSError, match=r"cannot replace '.*fifo': it is a FIFO, not a file"):
        write_text_atomic(fifo, "{}")
    assert fifo.is_fifo()
    target = tmp_path / "target.json"
    target.write_text("[]")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_text_atomic(link, '{"a": 1}')
    assert link.is_symlink() and target.read_text() == '{"a": 1}'
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "fifo",
        "link.json",
        "other.h5",
        "target.json",
    ]


def test_a_staged_output_folder_needs_a_writable_parent_and_says_so(tmp_path, monkeypatch, capsys):
    """demo, reproduce and estimate stage their files in a folder beside --out: with --out
    writable and its parent not (a shared project folder), estimate replayed the whole
    recording and then failed on an errno naming '.out.XXXX.tmp'. The parent is probed
    with --out now, and the staging names --out if it fails anyway."""
    import tempfile

    from jax_contact.train.cli_args import check_output_folder

    out = tmp_path / "shared" / "out"
    out.mkdir(parents=True)
    real_mkstemp, real_mkdtemp = tempfile.mkstemp, tempfile.mkdtemp

    def refused(dir):  # as the kernel refuses a user the parent folder (root is never refused)
        if Path(dir) == out.parent:
            raise PermissionError(13, "Permission denied")

    def mkstemp(*args, dir=None, **kwargs):
        refused(dir)
        return real_mkstemp(*args, dir=dir, **kwargs)

    def mkdtemp(*args, dir=None, **kwargs):
        refused(dir)
        return real_mkdtemp(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
    check_output_folder("--out", out)  # files can be made in --out itself
    with pytest.raises(ValueError, match=r"argument --out: .*staging its files beside it"):
        check_output_folder("--out", out, staged=True)
    argv = ["estimate", str(ROOT / "tests/fixtures/planar_leg_hop.csv"), "--model", "planar_leg"]
    assert cli.main([*argv, "--out", str(out)]) == 2
    assert "argument --out: " in capsys.readouterr().err
    with pytest.raises(OSError, match=rf"cannot write into '{out}': its files are staged"):
        with io.staged_folder(out):
            pass
    assert list(out.parent.iterdir()) == [out]
    with pytest.raises(ValueError, match="argument --out: an empty name"):
        check_output_folder("--out", "")  # it meant the working folder


def test_tune_names_the_stance_time_bounds_that_leave_out_the_start(tmp_path, capsys):
    """--stance-time-bounds that do not contain the starting T_s were refused as "pass
    stance_time_bounds that contain it", the Python name; now the option and the value."""
    csv = ROOT / "tests/fixtures/planar_leg_hop.csv"
    lines = csv.read_text().splitlines(keepends=True)
    other = tmp_path / "v.csv"  # another run: the same recording less its last 40 rows
    other.write_text("".join(lines[:-40]))
    out = tmp_path / "p.json"
    argv = ["tune", str(csv), "--validate", str(other), "--model", "planar_leg"]
    argv += ["--stance-time-bounds", "1.5", "2.0", "--out", str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "argument --stance-time-bounds: 1.5 2 s must contain the starting T_s," in err, err
    assert "--freeze stance_time" in err and not out.exists()


def test_evaluate_derives_its_defaults_for_the_logs_sensors(tmp_path):
    """evaluate ran the defaults of the ``anymal_like`` sensors on every log, where tune
    starts from the log's own sensor preset (``simulate --noise``): on a ``harsh`` Go1 log
    it scored F1 0.939 against 0.952 for the defaults of its sensors. Reference: the harsh
    defaults given by hand as a file reproduce the defaults' row to the bit; a log without
    the attribute keeps anymal_like's. A file tuned on other sensors is warned of."""
    import h5py

    import jax_contact as jc
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.log_estimator import default_estimator
    from jax_contact.train.log_evaluate import evaluate_file

    desc = load_robot("planar_leg").description
    harsh = _planar_log(tmp_path / "harsh.h5", attrs={"robot": "planar_leg", "dt": 0.0025})
    with h5py.File(harsh, "a") as f:
        f.attrs["noise"] = "harsh"
    plain = _planar_log(tmp_path / "plain.h5")

    def p_of(path, params_path=None):
        return np.asarray(evaluate_file(path, params_path=params_path)["outputs"]["probabilistic"])

    by_hand = jc.save_params(tmp_path / "h.json", default_estimator(desc, 0.0025, noise="harsh")[0])
    np.testing.assert_array_equal(p_of(harsh), p_of(harsh, by_hand))
    assert not np.allclose(p_of(harsh), p_of(plain), equal_nan=True)
    tuned = {"logs": [{"path": "a.h5", "noise": "anymal_like"}]}
    other = jc.save_params(tmp_path / "o.json", default_estimator(desc, 0.0025)[0], tuned)
    with pytest.warns(UserWarning, match=r"tuned on readings of sensors 'anymal_like'; these"
                      r" are 'harsh'"):  # fmt: skip
        evaluate_file(harsh, params_path=other)


def test_reproduce_lists_only_the_robots_it_takes(tmp_path, capsys):
    """An unknown --robot listed planar_leg among the valid names, which reproduce then
    refuses (Table III needs a quadruped)."""
    argv = ["reproduce", "--robot", "nosuch", "--size", "tiny", "--out", str(tmp_path / "r")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "unknown robot 'nosuch'; valid names: go1, spot, barkour, " in err
    assert "planar_leg" not in err


def test_a_parameter_file_of_another_robot_is_named_as_the_option(capsys):
    """evaluate --params of another robot's preset said "preset 'barkour' is for nv = 18;
    the robot has nv = 3" without the option it came from (a helper's trial); the planar
    leg's log (nv = 3 by its MJCF: a rail, a hip and a knee) against Barkour's 18."""
    argv = ["evaluate", "tests/fixtures/planar_leg_hop.h5", "--params", "barkour"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == (
        "jax-contact evaluate: error: argument --params: preset 'barkour' is for nv = 18;"
        " the robot has nv = 3"
    )


@pytest.mark.parametrize(
    "extra, said",
    [
        # An MJCF robot's legs are counted when it loads (the check before JAX knows the
        # shipped robots'): one leg, no trot.
        (
            ["--robot", "envs/assets/planar_leg.xml", "--gait", "trot"],
            "argument --gait: gait 'trot' needs two or more legs;",
        ),
        (
            ["--robot", "barkour", "--home-qpos", "1", "2"],
            "argument --home-qpos: home_qpos has 2 values; robot 'barkour' has nq = 19",
        ),
    ],
)
def test_simulate_names_the_option_of_a_library_error(tmp_path, capsys, extra, said):
    """A helper's trial: these came as "error: gait 'trot' needs ..." and "error: home_qpos
    has 2 values ...", without the option; nothing is written."""
    out = tmp_path / "x.h5"
    argv = ["simulate", str(out), *extra, "--envs", "1", "--duration", "0.5"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"jax-contact simulate: error: {said}"), err
    assert not out.exists()
