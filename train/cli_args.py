"""Argument types and checks of the ``jax-contact`` command line, standard library only.

They run before JAX is imported (``jax_contact.train.cli``'s module docstring), so a bad
number, name, input file or output folder is reported at once. Types raise
``argparse.ArgumentTypeError`` (argparse names the argument); the checks raise ValueError
naming the argument, which the command line prints as one line.

The lists of names the checks need come from modules that import JAX, so they are copied
here; ``tests/test_cli.py`` checks that each copy equals its original.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

# Copies of the library's lists (importing those modules imports JAX); tests/test_cli.py
# checks that each equals its original.
ROBOT_NAMES = (  # jax_contact.envs.robots.ROBOT_NAMES
    "go1",
    "spot",
    "barkour",
    "planar_leg",
    "anybotics_anymal_b",
    "anybotics_anymal_c",
    "boston_dynamics_spot",
    "google_barkour_v0",
    "google_barkour_vb",
    "unitree_a1",
    "unitree_go1",
    "unitree_go2",
)
# jax_contact.envs.model_files.MENAGERIE_NAMES: loaded from $MENAGERIE_ROOT or the
# mujoco_menagerie package, never bundled.
MENAGERIE_NAMES = tuple(n for n in ROBOT_NAMES if n not in ("go1", "spot", "barkour", "planar_leg"))
GAITS = ("trot", "walk", "hop")  # jax_contact.envs.gaits.KINDS
FAILURE_LIMIT = 0.02  # jax_contact.train.report.FAILURE_LIMIT
BENCH_ENVS = (1, 64, 256, 1024, 4096, 16384)  # jax_contact.benchmarks.estimator.DEFAULT_ENVS
# The help of `jax-contact bench`'s sizes, shared with `python -m jax_contact.benchmarks.suite`.
BENCH_HELP = {
    "--envs": "throughput batch sizes",
    "--versus-envs": "batch sizes vs mjx.step; the largest, rounded up to a multiple of 8, is"
    " also the sharding check's",
    "--latency-calls": "timed calls per single-robot latency row",
}
# The one shipped robot with one leg (the others have four): the hop is its only gait, and
# Table III needs a quadruped.
ONE_LEGGED = ("planar_leg",)
NOISES = ("ideal", "anymal_like", "harsh")  # jax_contact.envs.sensors.PRESETS
TERRAINS = ("flat", "rough")  # jax_contact.envs.simulate.TERRAINS
VARIANTS = ("none", "truth", "estimate")  # jax_contact.train.ppo.VARIANTS
COLUMNS = (  # jax_contact.train.transfer.COLUMNS
    "truth",
    "estimate",
    "estimate_harsh",
    "estimate_lat1",
    "estimate_lat2",
)
# The Playground locomotion envs that load offline:
# jax_contact.envs.playground_offline.offline_names().
PLAYGROUND_ENV_NAMES = (
    "ApolloJoystickFlatTerrain",
    "BerkeleyHumanoidJoystickFlatTerrain",
    "BerkeleyHumanoidJoystickRoughTerrain",
    "G1JoystickFlatTerrain",
    "G1JoystickRoughTerrain",
    "Go1Footstand",
    "Go1Getup",
    "Go1Handstand",
    "Go1JoystickFlatTerrain",
    "Go1JoystickRoughTerrain",
    "H1InplaceGaitTracking",
    "H1JoystickGaitTracking",
    "SpotFlatTerrainJoystick",
    "SpotGetup",
    "SpotJoystickGaitTracking",
    "T1JoystickFlatTerrain",
    "T1JoystickRoughTerrain",
)
# The tasks of `jax-contact train` that are Playground envs by name (Go1's joystick is "go1").
PLAYGROUND_TASKS = tuple(n for n in PLAYGROUND_ENV_NAMES if n != "Go1JoystickFlatTerrain")
HOP_TASKS = ("hop", "hop_blind")  # jax_contact.train.tasks.HOP_TASK_NAMES
TASKS = ("go1", *HOP_TASKS, *PLAYGROUND_TASKS)  # jax_contact.train.tasks.TASK_NAMES
SCENES = ("planar_leg", "go1", "go1_walk", "go1_trot")  # jax_contact.train.rates.SCENES
LOG_SUFFIXES = (".h5", ".hdf5")
# The fewest readings per second the estimator takes, for an export's rate and a
# recording's (slower is no contact estimate, and in a recording most often a time column
# in milliseconds or nanoseconds).
MIN_RATE_HZ = 10.0
# A recording's steps may differ from their median by this fraction (more needs
# --resample), and two periods within it are one rate (tune's logs, deploy-check's log
# against the export): the recordings' tolerance, here where the CLI reads it without numpy.
RATE_TOLERANCE = 0.01
# The most an export's rate may be: no joint-control loop runs faster (a --rate in
# millihertz or a typo, e.g. 1e9, would give a file whose period is 1 ns).
MAX_RATE_HZ = 1e5


# ------------------------------------------------------------------------ argument types
# Types raise argparse.ArgumentTypeError (argparse names the argument); the per-command
# checks raise ValueError with the argument's name, printed by main().


def int_between(minimum: int, maximum: int | None = None):
    """An argparse type: an int >= ``minimum`` (and, given, <= ``maximum``), else an error
    naming the value and the bound."""
    bound = f">= {minimum}" if maximum is None else f"from {minimum} to {maximum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"must be an int {bound}, got {text!r}")
        return value

    return parse


positive_int = int_between(1)
nonnegative_int = int_between(0)

SEED_MAX = 2**31 - 1  # a seed is a non-negative int32: what jax.random.key and NumPy take
seed_int = int_between(0, SEED_MAX)
# Env resamples of a paired bootstrap: 1000 is typical; far more only costs memory.
bootstrap_int = int_between(0, 1_000_000)


def float_above_zero(*, or_zero: bool):
    """An argparse type: a finite float > 0 (``or_zero``: >= 0), else an error naming the
    value."""
    bound = ">= 0" if or_zero else "> 0"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and (value >= 0 if or_zero else value > 0)):
            raise argparse.ArgumentTypeError(f"must be a finite number {bound}, got {text!r}")
        return value

    return parse


positive_float = float_above_zero(or_zero=False)
nonnegative_float = float_above_zero(or_zero=True)


def check_robot(arg: str, name: str | None, names: Sequence[str] = ROBOT_NAMES) -> None:
    """Raises ValueError unless ``name`` is a known robot or an existing MJCF file;
    ``names``: the robot names the command takes (its message lists them)."""
    if name is None or name in ROBOT_NAMES:
        return
    if name.endswith((".xml", ".urdf")) or os.sep in name or "/" in name:  # robots' rule
        path = Path(name).expanduser()
        if path.is_dir():
            raise ValueError(f"argument {arg}: {name!r} is a folder; name the MJCF .xml file")
        if not path.is_file():
            raise ValueError(f"argument {arg}: MJCF file {name!r} does not exist")
        return
    raise ValueError(
        f"argument {arg}: unknown robot {name!r}; valid names: {', '.join(names)}, or a"
        " path to an MJCF .xml file"
    )


def check_gait_for_robot(robot: str, gait: str) -> None:
    """Raises ValueError when a shipped robot's leg count rules the gait out (an MJCF path
    is checked once loaded, by ``jax_contact.envs.simulate``, with the same words)."""
    if robot not in ROBOT_NAMES:
        return
    if gait == "hop" and robot not in ONE_LEGGED:
        raise ValueError(
            f"argument --gait: gait 'hop' runs a one-legged robot (the planar leg); {robot!r}"
            " has 4 legs: use 'trot' or 'walk'"
        )
    if gait != "hop" and robot in ONE_LEGGED:
        raise ValueError(
            f"argument --gait: gait {gait!r} needs two or more legs; {robot!r} has one: use 'hop'"
        )


# Bytes a simulated log holds per step and env at the least: the planar leg's readings
# (qpos 4, qvel, qacc, tau 3 each) and truth in float32; a quadruped's are ~20x more.
_MIN_LOG_BYTES_PER_STEP = 4 * 13
_SIMULATE_DT = 0.0025  # s: the physics and readings of `simulate` run at 400 Hz


def machine_memory_bytes() -> int | None:
    """This machine's physical memory, bytes; None where the OS does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not on this OS
        return None


# The least memory one env holds: the benchmark's estimator alone (Go1, quadrature
# touch-down: 14.5 kB measured, `bytes_per_env` in bench's JSON; Monte-Carlo 56 kB), less
# than any simulated env with it. A batch whose lower bound exceeds the machine's memory is
# refused before JAX loads (10^9 envs in bench ran the other sections first, then died on
# a 9.4 TiB allocation; 10^11 in policy-eval compiled for a minute, its count truncated
# to int32 with a warning).
MIN_BYTES_PER_ENV = 14_000


def check_env_memory(arg: str, n_envs: int) -> None:
    """Raises ValueError when ``n_envs`` envs cannot fit the machine's memory at
    :data:`MIN_BYTES_PER_ENV` each (0 envs, or an unknown memory size, pass)."""
    total = machine_memory_bytes()
    if total and n_envs * MIN_BYTES_PER_ENV > total:
        raise ValueError(
            f"argument {arg}: {n_envs} envs need at least"
            f" {n_envs * MIN_BYTES_PER_ENV / 2**30:.3g} GiB (the estimator's"
            f" {MIN_BYTES_PER_ENV / 1e3:g} kB per env alone); this machine has"
            f" {total / 2**30:.0f} GiB of memory"
        )


def check_log_size(
    envs: int,
    duration: float,
    bytes_per_step: int = _MIN_LOG_BYTES_PER_STEP,
    robot: str | None = None,
) -> None:
    """Raises ValueError when ``envs`` x ``duration`` of ``simulate`` cannot fit in this
    machine's memory (it was killed by the kernel, exit 137, with no word): before JAX
    loads at the smallest robot's log size, and again once the robot is loaded at its own
    (``bytes_per_step`` per step and env, ``robot`` named); or when ``duration`` is under
    the two readings every log needs (the simulation's own check says the same after)."""
    if round(duration / _SIMULATE_DT) < 2:
        raise ValueError(
            f"argument --duration: {duration:g} s is under 2 steps of {_SIMULATE_DT * 1e3:g} ms;"
            f" a log needs at least 2 (--duration >= {2 * _SIMULATE_DT:g})"
        )
    steps = duration / _SIMULATE_DT
    need = envs * steps * bytes_per_step
    total = machine_memory_bytes()
    if total is not None and need > total:
        of = f" of {robot!r}" if robot else ""
        raise ValueError(
            f"arguments --envs and --duration: {envs} envs x {duration:g} s ({steps:.0f} steps"
            f" of {_SIMULATE_DT * 1e3:g} ms) make a log{of} of at least {need / 2**30:.3g} GiB;"
            f" this machine has {total / 2**30:.0f} GiB of memory: simulate fewer envs or"
            " seconds (and several files)"
        )


# What `reproduce` / `demo` and `estimate` write into their --out, by name (copies of
# jax_contact.train.reproduce's OUTPUT_FILES, figures and SCENARIOS, and of
# recording_estimate's fixed outputs; tests/test_cli.py checks them).
REPRODUCE_OUTPUTS = (
    "table3.json",
    "ablation.json",
    "diagnostics.json",
    "section3_fig5.png",
    "table3_trot_fig7.png",
    "reliability_trot.png",
    "reliability_walk.png",
    "reliability_walk_added_mass.png",
    "reliability_rough.png",
)
ESTIMATE_OUTPUTS = ("estimate.h5", "estimate.csv", "metrics.json")


def check_outputs_not_folders(arg: str, folder, names) -> None:
    """Raises ValueError when a file a command writes into ``folder`` would replace a
    folder of that name (found only after the work, at the final move, before)."""
    for name in names:
        path = Path(folder) / name
        if path.is_dir():
            raise ValueError(
                f"argument {arg}: {str(path)!r} is a folder where this command writes a file"
            )


def check_not_an_input(arg: str, out, **inputs) -> None:
    """Raises ValueError when the output ``out`` is one of the command's input files
    (``name=path``): writing it would destroy the input (a log overwritten with JSON).
    An input that is no existing file (None, a preset name, an inline map) is skipped."""
    if not _exists(out):
        return
    for name, path in inputs.items():
        if _exists(path) and os.path.samefile(out, path):
            raise ValueError(
                f"argument {arg}: {str(out)!r} is this command's {name}; writing it would"
                " replace it: pass another path"
            )


def check_no_repeats(arg: str, values, what: str = "value") -> None:
    """Raises ValueError naming ``arg`` when ``values`` names one thing twice."""
    values = list(values or ())
    if len(set(values)) != len(values):
        raise ValueError(f"argument {arg}: repeated {what} in {values}")


def _exists(path) -> bool:
    """Whether ``path`` (None, or text that may be no valid path at all) names a file."""
    if path is None or not str(path):
        return False
    try:
        return Path(path).exists()
    except OSError:  # e.g. an inline --names map longer than a file name may be
        return False


def check_not_a_run_file(arg: str, out, run_dirs, summary_dirs=()) -> None:
    """Raises ValueError when ``out`` is a file that ``jax-contact train`` keeps in one of
    ``run_dirs`` (its record, progress, checkpoints) or in one of the ``summary_dirs`` it
    trained into (``--out``: its summary): replacing it would damage the run."""
    from jax_contact.train.run_folder import RUN_FILES, SUMMARY_FILES

    if out is None:
        return
    target = Path(out).resolve()
    owned = [(Path(d).resolve(), RUN_FILES) for d in run_dirs]
    owned += [(Path(d).resolve(), SUMMARY_FILES) for d in summary_dirs]
    for folder, names in owned:
        inside_checkpoints = folder / "checkpoints" in target.parents
        if inside_checkpoints or (target.parent == folder and target.name in names):
            raise ValueError(
                f"argument {arg}: {str(out)!r} is a file of the run in {str(folder)!r};"
                " writing it would replace it: pass another path"
            )


def check_run_folder(run_dir: Path, overwrite: bool) -> bool:
    """Whether ``run_dir`` holds files that ``overwrite`` lets a new run of ``jax-contact
    train`` replace (stdlib only: the CLI checks it before JAX loads).

    Raises:
      ValueError: it holds files and ``overwrite`` is False (naming the folder, and an
        unfinished run as such), it is not a folder, or the run an earlier ``--overwrite``
        replaced is still set aside beside it (:mod:`jax_contact.train.run_folder`: that
        process was killed before it could put it back or delete it).
    """
    from jax_contact.train.run_folder import earlier_path

    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"run folder {run_dir} exists and is not a folder: pass another --out")
    if (aside := earlier_path(run_dir)).exists():
        raise ValueError(
            f"{aside} holds the run that an --overwrite run into {run_dir} replaced, set aside"
            " until its first checkpoint (that run was killed before it could put it back or"
            f" delete it): move it back to {run_dir} or delete it, then train again"
        )
    if not (run_dir.exists() and any(run_dir.iterdir())):
        return False
    if not overwrite:
        what = "exists and is not empty"
        if unfinished_run(run_dir):
            what = "holds an unfinished run (interrupted, or training in another process)"
        raise ValueError(f"run folder {run_dir} {what}: pass --overwrite to replace it")
    return True


def unfinished_run(run_dir: Path) -> bool:
    """True if ``run_dir/run.json`` says its training never returned (``finished`` false;
    runs written before the key count as finished)."""
    import json

    try:
        return json.loads((Path(run_dir) / "run.json").read_text()).get("finished") is False
    except (OSError, ValueError, AttributeError):
        return False


def not_a_run_folder(path: str | os.PathLike) -> str:
    """Why ``path`` is no run folder of ``jax-contact train`` (it has no ``run.json``), with
    the run folder to pass instead when it is one of its checkpoint folders."""
    path = Path(path)
    if path.is_file():
        return f"{str(path)!r} is a file; pass a run folder of jax-contact train (OUT/<variant>)"
    hint = ""
    if path.parent.name == "checkpoints":
        hint = f"; it is a checkpoint folder: pass its run folder, {str(path.parent.parent)!r}"
    elif runs := sorted(p.parent.name for p in path.glob("*/run.json")):
        # train's --out: its run folders are one level down.
        hint = f"; it holds the run folders {runs}: pass one, e.g. {str(path / runs[0])!r}"
    return f"{str(path)!r} is not a run folder of jax-contact train (no run.json){hint}"


def check_run_record(arg: str, run_dir: str | os.PathLike, observe: str | None) -> None:
    """Raises ValueError, naming ``run.json``, when what ``policy-eval`` would build from a
    run folder's record cannot be built (a parameter file or sensor preset that is not
    there), or when ``observe`` (a variant or a transfer column; None: the run's own) gives
    a policy an observation other than the one it was trained on (a run trained without
    contact takes only ``none``, the others only a contact column; every task's, the
    hop's included). Anything else
    wrong with the record is left to the full check after JAX loads. Standard library only.
    """
    import json

    from jax_contact._presets import preset_file

    path = Path(run_dir) / "run.json"
    try:
        run = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return
    cfg = run.get("config") if isinstance(run, dict) else None
    if not isinstance(cfg, dict):
        return
    params = cfg.get("estimator_params")
    if isinstance(params, str) and preset_file(params) is None and not Path(params).is_file():
        raise ValueError(
            f"argument {arg}: {str(path)!r} names the parameter file {params!r}"
            " (config.estimator_params), which is neither a file nor a shipped preset (a"
            " relative path is read from the current folder: run from the folder the run was"
            " trained in, or write the file's absolute path into run.json)"
        )
    sensor = cfg.get("sensor", "anymal_like")
    if sensor not in NOISES:
        raise ValueError(
            f"argument {arg}: {str(path)!r}: config.sensor {sensor!r} is not one of {NOISES}"
        )
    variant = run.get("variant")
    if observe is None or variant not in VARIANTS:
        return
    if (variant == "none") != (observe == "none"):
        sees = "no contact" if variant == "none" else "a contact observation"
        takes = "only none" if variant == "none" else f"one of {', '.join(COLUMNS)}"
        raise ValueError(
            f"argument {arg}: the run was trained with {variant!r} ({str(path)!r}): its policy"
            f" sees {sees}, so it can observe {takes}, not {observe!r}"
        )


def add_transfer_arguments(p) -> None:
    """The transfer matrix's arguments (``jax-contact transfer`` and ``python -m
    jax_contact.train.transfer``)."""
    p.add_argument("root", help="folder of seed*/{none,truth,estimate} run folders")
    p.add_argument("--envs", type=positive_int, default=32, help="episodes per cell")
    p.add_argument(
        "--episode-length",
        type=positive_int,
        default=None,
        help="env steps per episode (default: the runs' configuration's)",
    )
    p.add_argument("--seed", type=seed_int, default=12345, help="seeds the episodes")
    p.add_argument("--json", default=None, help="write the matrix here")


def check_transfer(args) -> None:
    """Raises ValueError naming the argument: ``root`` is no folder, or ``--json`` cannot
    be written (the run folders under ``root`` are checked once JAX has loaded)."""
    if problem := transfer_root_problem(args.root):
        raise ValueError(f"argument root: {problem}")
    check_env_memory("--envs", args.envs)
    check_output_file("--json", args.json)
    root = Path(args.root)
    runs = [p.parent for p in root.glob("seed*/*/run.json")]
    # Each seed's training summary (jax-contact train --out ROOT/seedS), and ROOT's own.
    trained_into = [root, *(p for p in root.glob("seed*") if p.is_dir())]
    check_not_a_run_file("--json", args.json, runs, summary_dirs=trained_into)


def transfer_root_problem(root: str | os.PathLike) -> str | None:
    """Why ``root`` cannot hold the transfer matrix's ``seed*/`` run folders (a file, or
    nothing there); None if it is a folder."""
    if Path(root).is_file():
        return f"{str(root)!r} is a file; pass the folder of seed*/ run folders"
    if not Path(root).is_dir():
        return f"folder {str(root)!r} does not exist"
    return None


def check_input_file(arg: str, path: str) -> None:
    """Raises ValueError unless ``path`` is an existing file."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"argument {arg}: file {path!r} does not exist")
    if not p.is_file():
        raise ValueError(f"argument {arg}: {path!r} is not a file")


def check_distinct_files(arg: str, paths) -> None:
    """Raises ValueError naming the first of ``paths`` that is given twice: the same file
    under two names (a link, symbolic or hard) or another file of the same bytes (a copy):
    pooled, it would count twice. Files that do not exist are left to the existence check."""
    import hashlib

    seen: dict[str, str] = {}
    same_size: dict[int, list[str]] = {}
    for path in paths:
        p = Path(path)
        try:
            st = p.stat()
        except OSError:
            st = None
        key = f"{st.st_dev}:{st.st_ino}" if st is not None else str(p.resolve())
        if key in seen:
            raise ValueError(
                f"argument {arg}: {str(path)!r} is given twice (as {seen[key]!r}; pooled, it"
                " would count twice)"
            )
        seen[key] = str(path)
        if st is not None and p.is_file():
            same_size.setdefault(st.st_size, []).append(str(path))
    for group in same_size.values():
        digests: dict[bytes, str] = {}
        for path in group if len(group) > 1 else ():
            digest = hashlib.sha256()
            with open(path, "rb") as f:
                for block in iter(lambda f=f: f.read(1 << 20), b""):
                    digest.update(block)
            if (d := digest.digest()) in digests:
                raise ValueError(
                    f"argument {arg}: {path!r} holds the same bytes as {digests[d]!r}, one"
                    " log twice (pooled, it would count twice)"
                )
            digests[d] = path


def check_params_source(arg: str, source: str) -> None:
    """Raises ValueError unless ``source`` is the name of a shipped preset
    (``jax_contact.preset_names()``) or an existing parameter file whose JSON header reads
    (:func:`jax_contact.params_file.read_params_file`), the two things
    :func:`jax_contact.load_params` takes. No JAX is imported."""
    from jax_contact._presets import preset_file, preset_names
    from jax_contact.params_file import read_params_file

    if preset_file(source) is not None:
        return
    if not Path(source).exists():
        raise ValueError(
            f"argument {arg}: {source!r} is neither a file nor a shipped preset"
            f" ({', '.join(preset_names())})"
        )
    check_input_file(arg, source)
    try:  # JSON and header, before JAX loads (the values are checked once it has)
        read_params_file(source)
    except ValueError as err:
        raise ValueError(f"argument {arg}: {err}") from None


def check_output_folder(arg: str, folder: str | os.PathLike, *, staged: bool = False) -> None:
    """Raises ValueError unless files can be created in ``folder`` (once created).

    The nearest existing ancestor is probed by creating and removing a file in it, as the
    atomic writes do: permission bits alone are no answer for root, nor for folders such
    as ``/proc``. With ``staged`` (outputs written through :func:`jax_contact.io.
    staged_folder`, which stages them in a folder beside ``folder``) the parent of an
    existing ``folder`` is probed too.
    """
    p = Path(folder).expanduser().absolute()
    if not str(folder).strip():
        raise ValueError(f"argument {arg}: an empty name; expected a folder")
    if staged and p.is_dir():
        try:
            check_output_folder(arg, p.parent)
        except ValueError as err:
            raise ValueError(
                f"{err}; this command writes {str(p)!r} by staging its files beside it, in"
                f" {str(p.parent)!r}: pass a folder whose parent you can write to"
            ) from None
    if p.exists() and not p.is_dir():
        raise ValueError(f"argument {arg}: {str(p)!r} exists and is not a folder")
    existing = p
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(
            f"argument {arg}: cannot create folder {str(p)!r}: {str(existing)!r} is a file"
        )
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".jax-contact-check.", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        why = err.strerror or err
        if existing != p:  # name what was asked for (/proc/x: /proc exists, x cannot be made)
            raise ValueError(
                f"argument {arg}: cannot create folder {str(p)!r}: {str(existing)!r} takes"
                f" no new files or folders ({why})"
            ) from None
        raise ValueError(
            f"argument {arg}: cannot create files in folder {str(p)!r} ({why})"
        ) from None


def check_output_file(arg: str, path: str | None, suffixes: tuple[str, ...] = ()) -> None:
    """Raises ValueError unless ``path`` (None: none) can be written: the suffix, not a
    folder, no device, FIFO or socket (the atomic write would replace it with a file), a
    writable folder; for a JSON output (``--json``, or ``suffixes`` ``(".json",)``) an
    existing file is replaced only if it holds JSON (``--json`` naming a log destroyed it),
    and a ``--json`` report never replaces a parameter file (:func:`is_parameter_file`).
    A symbolic link is checked, and written, as its target."""
    from jax_contact.io import not_a_file

    if path is None:
        return
    if not str(path).strip():
        raise ValueError(f"argument {arg}: an empty name; expected a file name")
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"argument {arg}: {path!r} is a folder; expected a file name")
    if suffixes and p.suffix not in suffixes:
        raise ValueError(f"argument {arg}: {path!r} must end in {' or '.join(suffixes)}")
    if (kind := not_a_file(p)) is not None:
        raise ValueError(f"argument {arg}: {path!r} is {kind}, not a file; pass a file name")
    if (arg == "--json" or suffixes == (".json",)) and p.is_file() and not _holds_json(p):
        raise ValueError(
            f"argument {arg}: {path!r} exists and holds no JSON (a log or another file);"
            " writing it would replace it: pass a new name or a JSON file to replace"
        )
    if arg == "--json" and is_parameter_file(json_in_file(p)):
        # A report over a tuned file (minutes of tuning) was written without a word, a
        # helper's trial; `tune --out` replaces parameter files, and only those.
        raise ValueError(
            f"argument {arg}: {path!r} holds a parameter file (jax_contact.save_params);"
            " writing this command's results would replace it: pass a new name"
        )
    check_output_folder(arg, p.resolve().parent if p.is_symlink() else p.parent)


# The largest existing file a JSON output may replace after parsing it (this library's
# JSON outputs are far smaller; a larger file is refused unread).
JSON_REPLACE_MAX_BYTES = 64 << 20


# What :func:`json_in_file` returns for a file that holds no JSON value to read.
NO_JSON = object()


def json_in_file(path: str | os.PathLike) -> object:
    """The JSON value the file ``path`` holds, or :data:`NO_JSON`: no file, an empty one,
    one larger than :data:`JSON_REPLACE_MAX_BYTES`, unreadable, or not JSON (the other
    checks name those)."""
    import json

    p = Path(path)
    try:
        if not p.is_file() or p.stat().st_size > JSON_REPLACE_MAX_BYTES:
            return NO_JSON
        text = p.read_bytes()
        return json.loads(text) if text.strip() else NO_JSON
    except (OSError, ValueError):  # JSONDecodeError, UnicodeDecodeError
        return NO_JSON


def is_parameter_file(held: object) -> bool:
    """Whether a JSON value (:func:`json_in_file`) is a parameter file of
    :func:`jax_contact.save_params`: an object whose ``format`` is
    :data:`jax_contact.params_file.PARAMS_FORMAT`."""
    from jax_contact.params_file import PARAMS_FORMAT

    return isinstance(held, dict) and held.get("format") == PARAMS_FORMAT


def _holds_json(path: Path) -> bool:
    """Whether ``path`` is empty or parses as JSON (a CSV whose header starts ``time,``
    passed a first-byte test and was replaced)."""
    import json

    try:
        if path.stat().st_size > JSON_REPLACE_MAX_BYTES:
            return False
        text = path.read_bytes()
    except OSError:
        return True  # unreadable: the write's own error names it
    if not text.strip():
        return True
    try:
        json.loads(text)
    except ValueError:  # JSONDecodeError, UnicodeDecodeError
        return False
    return True


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line, as the commands' own checks print
    theirs, and a pointer to ``--help``: argparse printed the command's whole usage first
    (18 lines for ``tune``), burying the message (a helper's audit). Subparsers made by
    ``add_subparsers`` are of this class too."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n({self.prog} --help lists the options)\n")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default, except the uninformative None and False."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)
