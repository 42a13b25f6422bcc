"""Reading and writing logs (HDF5): the only module of the library that touches files.

A log is a flat set of named arrays whose first axis is time, plus metadata. Writes are
atomic: the file is written under a temporary name in the destination folder and renamed
into place only when complete, so an interrupted or failed write never leaves a partial
file behind. Files get the mode any new file gets (``0o666`` less the user's umask), not
the ``0o600`` of :func:`tempfile.mkstemp`.

Schema of a rollout log (``jax-contact simulate``), all arrays with leading axes
``(T, n_envs)``::

    /readings/qpos    (T, E, nq)  float32  measured generalised coordinates
    /readings/qvel    (T, E, nv)  float32  measured generalised velocities
    /readings/qacc    (T, E, nv)  float32  backward difference of qvel, m/s^2, rad/s^2
    /readings/tau     (T, E, nv)  float32  measured generalised actuation forces, N, N m
    /truth/contact    (T, E, L)   bool     normal force > threshold (ground truth)
    /truth/force      (T, E, L)   float32  contact normal force on the foot, N
    /truth/distance   (T, E, L)   float32  sole-to-floor distance, m
    /valid            (T, E)      bool     env upright and finite at this step
    /time             (T,)        float32  time since the start, s

and root attributes ``robot``, ``gait``, ``noise``, ``terrain``, ``seed``, ``dt`` (s),
``rate_hz``, ``n_envs``, ``foot_names``, ``reading_timing``, ``format_version``.
``reading_timing`` is ``"end_of_step"``: reading ``k`` is what the sensors give at the end
of physics step ``k`` (the state after it, the acceleration over it, the torque applied
during it), and the truth of ``k`` is the contact during that step (train/evaluate.py's
module docstring); a log without the attribute is read that way, except one of an older
``jax-contact simulate`` (``jax_contact.train.logs.reading_timing_of``). Readings are stored at the
estimator's rate; the estimator's inputs (mass matrix, Jacobians, ...) are recomputed from
them and the robot model when the log is replayed, which keeps logs ~40x smaller.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import h5py
import numpy as np

from jax_contact._presets import preset_file, preset_names

FORMAT_VERSION = 1

# Temporary files of writes in progress, so that a process stopped from another thread (the
# CLI on Ctrl-C, :func:`abort_writes`) can remove them. The lock makes "create and
# register" and "rename and unregister" each indivisible with respect to the abort.
_PENDING: set[str] = set()
_LOCK = threading.Lock()
# The files written completely so far (completed_writes).
_DONE: list[str] = []


def write_log(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], attrs: Mapping) -> Path:
    """Writes ``arrays`` (keys like ``"readings/qpos"``) and ``attrs`` to an HDF5 file.

    Args:
      path: destination ``.h5`` file; its folder is created if needed.
      arrays: name -> array; names may contain ``/`` for groups.
      attrs: metadata stored as root attributes (str, numbers, or JSON-serialisable
        sequences, which are stored as JSON strings).

    Returns:
      The path written.

    Raises:
      ValueError: an array holds objects, or an attribute cannot be stored.
    """
    path = Path(path)
    for name, arr in arrays.items():
        if np.asarray(arr).dtype == object:
            raise ValueError(f"array {name!r} has dtype object and cannot be written")

    def write(tmp: str) -> None:
        with h5py.File(tmp, "w") as f:
            for name, arr in arrays.items():
                f.create_dataset(name, data=np.asarray(arr), compression="gzip", compression_opts=1)
            f.attrs["format_version"] = FORMAT_VERSION
            for key, value in attrs.items():
                f.attrs[key] = _attr(key, value)

    return write_atomic(path, write)


def _attr(key: str, value):
    if isinstance(value, str | int | float | bool | np.integer | np.floating):
        return value
    try:
        return json.dumps(value)
    except TypeError as err:
        raise ValueError(
            f"attribute {key!r} of type {type(value).__name__} cannot be stored"
        ) from err


def read_log(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Reads a log written by :func:`write_log`.

    Returns:
      (arrays keyed by their full name, e.g. ``"readings/qpos"``, attributes).

    Raises:
      FileNotFoundError: no such file.
      ValueError: one line naming the file: not an HDF5 file, truncated or otherwise
        unreadable (naming the array that could not be read), not a jax-contact log (no
        ``format_version``) or a newer one.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"log file {str(path)!r} does not exist")
    arrays: dict[str, np.ndarray] = {}
    try:
        f = h5py.File(path, "r")
    except OSError as err:  # h5py's messages name neither the file nor what was expected
        recording = (
            "; a recording of columns (CSV, NPZ) is read by `jax-contact estimate`"
            if path.suffix.lower() in (".csv", ".npz", ".txt")
            else ""
        )
        raise ValueError(
            f"log file {str(path)!r} cannot be read as HDF5 ({_h5_reason(err)}); expected an"
            f" .h5 file written by `jax-contact simulate` (jax_contact.io.write_log){recording}"
        ) from None
    with f:
        version = f.attrs.get("format_version")
        if version is None:
            raise ValueError(f"{str(path)!r} is not a jax-contact log (no format_version)")
        if int(version) > FORMAT_VERSION:
            raise ValueError(
                f"{str(path)!r} has format_version {int(version)}; this library reads up to"
                f" {FORMAT_VERSION}"
            )

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                try:
                    arrays[name] = obj[()]
                except (OSError, KeyError, RuntimeError) as err:  # truncated / corrupt data
                    raise ValueError(
                        f"log file {str(path)!r}: array {name!r} cannot be read"
                        f" ({_h5_reason(err)}); the file is truncated or corrupt"
                    ) from None

        try:
            f.visititems(visit)
            attrs = {k: _decode(v) for k, v in f.attrs.items()}
        except (OSError, KeyError, RuntimeError) as err:
            raise ValueError(
                f"log file {str(path)!r} cannot be read ({_h5_reason(err)}); the file is"
                " truncated or corrupt"
            ) from None
    return arrays, attrs


def _h5_reason(err: BaseException) -> str:
    """The informative part of an h5py error, on one line."""
    text = " ".join(str(err).split())
    return text[:200] or type(err).__name__


def _decode(value):
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value[:1] in "[{":
        try:
            return json.loads(value)
        except json.JSONDecodeError:
            return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_atomic(path: str | os.PathLike, write) -> Path:
    """Creates ``path`` atomically: ``write(tmp_path)`` fills a temporary file in the same
    folder, which is then renamed over ``path``; on any error the temporary file is removed
    and ``path`` is left as it was.

    The file gets mode ``0o666 & ~umask`` (what ``open(path, "w")`` gives a new file),
    also when it replaces an existing file.

    Args:
      path: the file to create or replace (its folder is created).
      write: callable taking the temporary file's path (a ``str``).
    """
    path = Path(path)
    if path.is_dir():  # refused before any write (os.replace would name the temporary file)
        raise IsADirectoryError(errno.EISDIR, f"cannot create {str(path)!r}: it is a folder")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with _LOCK:
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
            _PENDING.add(tmp)
    except OSError as err:  # name the file asked for, not the temporary one
        raise OSError(err.errno, f"cannot create {str(path)!r} ({err.strerror})") from None
    os.close(fd)
    try:
        write(tmp)
        # After write(): a writer may delete and recreate the file (the mode would go).
        os.chmod(tmp, 0o666 & ~_umask())
        with _LOCK:
            os.replace(tmp, path)
            _PENDING.discard(tmp)
            # Inside a staged folder still being written, it is not there yet.
            if not any(path.is_relative_to(p) for p in _PENDING):
                _DONE.append(str(path))
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        with _LOCK:
            _PENDING.discard(tmp)
        raise
    return path


def completed_writes() -> list[str]:
    """The files this process has written completely through :func:`write_atomic` and
    :func:`staged_folder`, in order (the CLI's Ctrl-C handler names them: they are whole).
    Read without the lock, which :func:`abort_writes` holds by then."""
    return list(_DONE)


def abort_writes() -> list[str]:
    """Removes the temporary file of every write in progress, for a process about to exit.

    Called from another thread than the writer's (the CLI's Ctrl-C handler, just before
    ``os._exit``). Returns with the internal lock *held*, so that no write in progress
    can rename its (removed) file into place or report the failure: every later
    :func:`write_atomic` in this process blocks. Each destination is then either as it
    was or completely written, never partial.

    Returns:
      The temporary files removed.
    """
    # A timeout, not a plain acquire: the lock is only held for a rename, so failing to get
    # it in a second means something is badly wrong, and exiting beats hanging.
    _LOCK.acquire(timeout=1.0)
    removed = []
    for tmp in list(_PENDING):
        try:
            if os.path.isdir(tmp):  # a staged folder (staged_folder)
                shutil.rmtree(tmp)
            else:
                os.unlink(tmp)
            removed.append(tmp)
        except OSError:
            pass
    _PENDING.clear()
    return removed


@contextlib.contextmanager
def staged_folder(folder: str | os.PathLike, stale: Callable[[Path], Iterable[str]] | None = None):
    """Writes a set of output files into ``folder`` as one.

    Yields a new temporary folder beside ``folder`` (same file system) to write the files
    into. On a normal exit, under the lock of the atomic writes, the names ``stale(folder)``
    returns (an earlier run's outputs, evaluated then) are removed from ``folder`` unless
    rewritten, and every file of the temporary folder replaces its namesake in ``folder``
    (created if needed; other files in it are kept). On an exception, or on Ctrl-C through
    :func:`abort_writes`, the temporary folder is removed and ``folder`` is as it was: a
    reader never finds this run's files mixed with an earlier run's.

    Args:
      folder: the destination folder.
      stale: ``folder -> names`` of files in it that this run supersedes; None: none.

    Yields:
      The temporary folder (a :class:`~pathlib.Path`).
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    with _LOCK:
        tmp = tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}.", suffix=".tmp")
        _PENDING.add(tmp)
    try:
        yield Path(tmp)
        folder.mkdir(exist_ok=True)
        old = set(stale(folder)) if stale is not None else set()
        with _LOCK:
            names = sorted(os.listdir(tmp))
            # Checked before anything moves: a folder in the way would stop the moves half
            # done, this run's files beside the earlier run's.
            blocked = [str(folder / n) for n in names if (folder / n).is_dir()]
            if blocked:
                raise ValueError(
                    f"cannot write {blocked[0]!r}: it is a folder (the output folder"
                    f" {str(folder)!r} is as it was)"
                )
            for name in sorted(old - set(names)):
                (folder / name).unlink(missing_ok=True)
            for name in names:
                os.replace(os.path.join(tmp, name), folder / name)
            os.rmdir(tmp)
            _PENDING.discard(tmp)
            _DONE.extend(str(folder / name) for name in names)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        with _LOCK:
            _PENDING.discard(tmp)
        raise


def _umask() -> int:
    """The process's umask, read without changing it where the OS allows."""
    # Linux >= 4.7 reports it in /proc; os.umask can only read it by setting it.
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    # Elsewhere: set and restore. For that instant the umask of every thread is 0o077, so a
    # file another thread creates meanwhile is too private rather than too public.
    old = os.umask(0o077)
    os.umask(old)
    return old


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Writes ``text`` to ``path`` atomically (:func:`write_atomic`)."""
    return write_atomic(path, lambda tmp: Path(tmp).write_text(text))


def write_json_atomic(path: str | os.PathLike, payload) -> Path:
    """Writes ``payload`` as JSON atomically (:func:`write_atomic`).

    NaN and infinity are written as ``null``, so the file is strict JSON.
    """
    return write_text_atomic(path, json.dumps(_finite(payload), indent=2))


def _finite(x):
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_finite(v) for v in x]
    if isinstance(x, np.ndarray):
        return _finite(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


# ----------------------------------------------------------------------- parameter files

PARAMS_FORMAT = "jax-contact-params"
PARAMS_VERSION = 1
# Fields added to a section after files of this version were first written, with the value
# that reproduces the model those files were written with: a file without one loads with
# it (a missing field of any other name is an error).
LATER_FIELDS = {
    "values": {
        "contact_damping": 0.0,
        "kinematics_lead": 0.0,
        "min_push": 0.0,
        "slip_prob": 0.0,
        "slip_speed": 0.5,
    }
}


def _param_sections() -> dict[str, tuple[str, ...]]:
    """The field names of each section of a params file: ``noise`` (the NoiseParams),
    ``values`` (EstimatorParams' array leaves) and ``options`` (its static fields)."""
    import dataclasses

    from jax_contact.params import EstimatorParams, NoiseParams

    fields = [f for f in dataclasses.fields(EstimatorParams) if f.name != "noise"]
    return {
        "noise": tuple(NoiseParams.__dataclass_fields__),
        "values": tuple(f.name for f in fields if f.metadata.get("pytree_node", True)),
        "options": tuple(f.name for f in fields if not f.metadata.get("pytree_node", True)),
    }


# The top-level keys of a parameter file (params_to_dict); any other is refused on reading.
PARAMS_KEYS = (
    "format", "version", "library_version", "nv", "noise", "values", "options", "provenance"
)  # fmt: skip


def params_to_dict(params, provenance: Mapping | None = None) -> dict:
    """:class:`~jax_contact.EstimatorParams` as the versioned JSON payload of a params file.

    Layout: ``format``, ``version``, ``library_version``, ``nv``, ``noise`` (field -> list
    of floats), ``values`` (scalar field -> float), ``options`` (the static fields) and
    ``provenance`` (free-form: how the values were obtained).
    """
    from importlib.metadata import PackageNotFoundError, version

    try:
        lib = version("jax-contact")
    except PackageNotFoundError:  # running from a source tree that was never installed
        lib = "unknown"
    names = _param_sections()
    noise = {f: np.asarray(getattr(params.noise, f)).tolist() for f in names["noise"]}
    values = {f: float(np.asarray(getattr(params, f))) for f in names["values"]}
    options = {
        f: list(v) if isinstance(v := getattr(params, f), tuple) else v for f in names["options"]
    }
    return {
        "format": PARAMS_FORMAT,
        "version": PARAMS_VERSION,
        "library_version": lib,
        "nv": params.nv,
        "noise": noise,
        "values": values,
        "options": options,
        "provenance": dict(provenance or {}),
    }


def _is_number(x) -> bool:
    """An int or float of JSON (not a bool, a string or null)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def check_params_header(payload, source: str) -> None:
    """The checks of :func:`params_from_dict` that need no JAX: the format, version,
    top-level keys, sections, the numeric fields' types and the provenance's type (the
    command line runs them before JAX loads). Raises ValueError naming ``source`` and the
    field."""
    if not isinstance(payload, Mapping) or payload.get("format") != PARAMS_FORMAT:
        raise ValueError(
            f"{source}: not a jax-contact parameter file (no format {PARAMS_FORMAT!r})"
        )
    if payload.get("version") != PARAMS_VERSION:
        raise ValueError(
            f"{source}: version {payload.get('version')!r} is not supported (this library reads"
            f" version {PARAMS_VERSION})"
        )
    extra = set(payload) - set(PARAMS_KEYS)
    if extra:
        raise ValueError(
            f"{source}: unknown top-level key(s) {sorted(extra)} (a parameter file has"
            f" {list(PARAMS_KEYS)}; free-form notes go into 'provenance')"
        )
    for section in ("noise", "values", "options"):
        value = payload.get(section)
        if value is None:
            raise ValueError(f"{source}: missing section {section!r}")
        if not isinstance(value, Mapping):
            raise ValueError(
                f"{source}: section {section!r} must be a JSON object of fields, got"
                f" {type(value).__name__}"
            )
    for section in ("noise", "values"):  # numbers (noise: or lists of numbers) only
        for name, value in payload[section].items():
            numbers = value if section == "noise" and isinstance(value, list) else [value]
            if not numbers or not all(_is_number(x) for x in numbers):
                kind = "a number or a list of numbers" if section == "noise" else "a number"
                raise ValueError(f"{source}: {section}.{name} must be {kind}, got {value!r}")
    provenance = payload.get("provenance")
    if provenance is not None and not isinstance(provenance, Mapping):
        raise ValueError(
            f"{source}: 'provenance' must be a mapping (JSON object), got"
            f" {type(provenance).__name__}"
        )
    mass = (provenance or {}).get("robot_mass_kg")
    if mass is not None and not (
        isinstance(mass, int | float)
        and not isinstance(mass, bool)
        and np.isfinite(mass)
        and mass > 0
    ):
        raise ValueError(
            f"{source}: provenance field 'robot_mass_kg' must be a positive number of kg"
            f" (or absent), got {mass!r}"
        )


def read_params_file(path) -> tuple[dict, str]:
    """``(payload, description for errors)`` of a parameter file or preset name, its
    header checked (:func:`check_params_header`); no JAX is imported.

    Raises:
      ValueError: the file is missing (or the name is no preset), not JSON, or its header
        is wrong (named).
    """
    text, source = _params_text(path)
    try:
        payload = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{source} is not JSON: {err}") from None
    check_params_header(payload, source)
    return payload, source


def params_from_dict(payload: Mapping, *, source: str = "params"):
    """The inverse of :func:`params_to_dict`, validated; errors name ``source`` and the field.

    Raises:
      ValueError: not a params payload, an unknown version, a missing or extra field, or
        a value that :func:`jax_contact.make_params` / ``make_noise`` rejects.
    """
    from jax_contact.params import make_noise, make_params

    check_params_header(payload, source)
    want = {section: set(names) for section, names in _param_sections().items()}
    payload = dict(payload)
    for section, added in LATER_FIELDS.items():
        payload[section] = {**added, **payload[section]}
    for section, names in want.items():
        have = set(payload[section])
        if have - names:
            raise ValueError(f"{source}: unknown field(s) {sorted(have - names)} in {section!r}")
        if names - have:
            raise ValueError(f"{source}: missing field(s) {sorted(names - have)} in {section!r}")
    nv = payload.get("nv")
    if not isinstance(nv, int) or nv < 1:
        raise ValueError(f"{source}: nv must be a positive int, got {nv!r}")
    lengths = {
        len(v)
        for k, v in payload["noise"].items()
        if k not in ("sigma_f", "sigma_J") and isinstance(v, list)
    }
    if len(lengths) == 1 and nv not in lengths:  # the header, not one vector, disagrees
        raise ValueError(
            f"{source}: nv is {nv} but every per-dof noise vector has {lengths.pop()} entries"
        )
    try:
        noise = make_noise(nv, **payload["noise"])
        params = make_params(noise, **payload["values"], **payload["options"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"{source}: {err}") from None
    return params


def save_params(path: str | os.PathLike, params, provenance: Mapping | None = None) -> Path:
    """Writes ``params`` as a versioned JSON file (atomically); returns the path.

    Raises:
      ValueError: ``params`` fails :func:`jax_contact.validate_params` (the field named;
        nothing is written: a NaN would be written as ``null`` and the file not load).
      OSError: the file cannot be created (its path named).
    """
    from jax_contact.params import validate_params

    validate_params(params)
    return write_json_atomic(path, params_to_dict(params, provenance))


def load_params(path: str | os.PathLike, *, with_provenance: bool = False):
    """Reads a parameter file written by :func:`save_params`, or a shipped preset by name.

    Args:
      path: a ``.json`` file, or the name of a shipped preset (:func:`preset_names`:
        ``"go1"``, ``"spot"``, ``"barkour"``, tuned by ``jax-contact tune``; each file's
        provenance says how). A name that is also an existing file is read as the file.
      with_provenance: also return the file's ``provenance`` dict (where a calibration map
        fitted by ``jax-contact tune --calibrate`` is kept, ``provenance["calibration"]``,
        see :class:`jax_contact.tune.Calibration`).

    Returns:
      The validated :class:`~jax_contact.EstimatorParams`, or ``(params, provenance)``.

    Raises:
      ValueError: the file is missing (or the name is no preset), is not JSON, or a field
        is wrong (named).
    """
    payload, source = read_params_file(path)
    params = params_from_dict(payload, source=source)
    if with_provenance:
        return params, dict(payload.get("provenance") or {})
    return params


# A file tuned on a robot heavier or lighter than this factor warns (load_params_for): a
# payload or another build of the same robot stays inside it (Go1 12.7 kg, Spot 50.3 kg).
MASS_RATIO_WARN = 1.5
# Periods closer than this fraction are one rate (load_params_for moves a file's values to
# the caller's dt without a warning): a recording's median step, from float32 or epoch
# timestamps, lies a few 1e-5 from its loop's nominal period (399.992 Hz for 400 Hz).
SAME_RATE = 1e-3


def load_params_for(
    path: str | os.PathLike,
    *,
    nv: int,
    dt: float,
    period: str = "the requested period",
    derive=None,
    mass_kg: float | None = None,
    with_provenance: bool = False,
    robot: str | None = None,
    groups: dict | None = None,
):
    """:func:`load_params` of a file or preset, checked against the robot and the period
    it will run at.

    With ``robot`` (the name the caller's robot was loaded by), a file whose provenance
    names another robot (``provenance["robot"]``; both plain names, not paths) warns,
    whatever the masses. With ``groups`` (the caller's coordinate groups,
    ``jax_contact.tune.space.robot_space(desc).named_groups()``), a tuned file whose
    ``provenance["groups"]`` differ warns too: its per-joint noise would land on other
    joints (Go1's file on a biped of the same ``nv``).

    With ``mass_kg`` (the robot's total mass, :func:`jax_contact.robot.model_mass`), a file
    whose provenance records the mass of the robot it was tuned on
    (``provenance["robot_mass_kg"]``, written by ``jax-contact tune`` and ``tune-env``)
    warns when the two differ by more than a factor :data:`MASS_RATIO_WARN`: the file is
    likely another robot's (a file carries over to another robot only in part).

    A file made at another period runs at ``dt``, with a ``UserWarning`` when the two
    differ by more than :data:`SAME_RATE` (a clock's rounding is not another rate). With
    ``derive`` (``dt -> params_for(robot, sensors, dt)`` of the caller's robot and sensors)
    its values are moved to ``dt`` as the rules move their own
    (:func:`jax_contact.defaults.change_period`: what tuning changed is kept relative to
    the derived values, ``sigma_qdd`` scales as ``1 / dt``, the still-side cap's log-odds
    as ``dt``); without it only ``dt`` changes and the rest is the file's, so a file made
    at a higher rate believes the differenced acceleration noisier than it is.

    Args:
      path: a parameter file or preset name.
      nv: the robot's velocity dimension.
      dt: the estimator's period, s.
      period: what ``dt`` is, in the warning (e.g. ``"the env's"``; default ``"the requested
        period"``).
      derive: optional ``dt -> EstimatorParams``, the caller's derived parameters.
      mass_kg: optional, the robot's total mass, kg.
      with_provenance: also return the file's ``provenance`` dict (one read of the file).

    Returns:
      The parameters at ``dt``, or ``(params, provenance)``.

    Raises:
      ValueError: as :func:`load_params`, or the file is for another ``nv``.
    """
    import warnings

    import jax.numpy as jnp

    params, provenance = load_params(path, with_provenance=True)
    what = f"preset {path!r}" if preset_file(path) is not None else f"parameter file {str(path)!r}"
    if params.nv != nv:
        raise ValueError(f"{what} is for nv = {params.nv}; the robot has nv = {nv}")
    file_mass, file_robot = provenance.get("robot_mass_kg"), provenance.get("robot")
    heavier = None
    if mass_kg is not None and isinstance(file_mass, int | float) and file_mass > 0:
        heavier = max(file_mass, mass_kg) / min(file_mass, mass_kg) > MASS_RATIO_WARN
    if heavier:
        warnings.warn(
            f"{what} was tuned on a robot of {file_mass:.3g} kg"
            f" ({provenance.get('robot', 'unnamed')!r}); this one weighs {mass_kg:.3g} kg:"
            " it is likely another robot's, whose noise, caps and gait constants carry"
            " over only in part (tune on this robot: jax-contact tune on its logs,"
            " jax-contact tune-env on a wrapped env)",
            stacklevel=2,
        )
    elif _robot_name(robot) and _robot_name(file_robot) and robot != file_robot:
        # Another robot of about the same mass (Go1's file on Barkour): named, not weighed.
        warnings.warn(
            f"{what} was tuned on robot {file_robot!r}; this one is"
            f" {robot!r}: its noise, caps and gait constants carry over only in part (a"
            f" preset of {robot!r} if one ships, else tune on this robot: jax-contact tune"
            " on its logs, jax-contact tune-env on a wrapped env)",
            stacklevel=2,
        )
    file_groups = provenance.get("groups")
    if groups is not None and isinstance(file_groups, dict):
        ours = {str(k): [int(i) for i in v] for k, v in groups.items()}
        theirs = {str(k): [int(i) for i in v] for k, v in file_groups.items()}
        if ours != theirs:
            warnings.warn(
                f"{what} was tuned on a robot whose coordinates group as {_groups_text(theirs)};"
                f" this one's are {_groups_text(ours)}: its per-joint noise values land on"
                " other joints (another robot's file; tune on this robot: jax-contact tune on"
                " its logs, jax-contact tune-env on a wrapped env)",
                stacklevel=2,
            )
    file_dt = float(params.dt)
    if abs(file_dt - dt) > 1e-6 * dt:  # moved silently within SAME_RATE, else with a warning
        if derive is None:
            how = "noise the file derived from its dt is kept"
            params = params.replace(dt=jnp.float32(dt))
        else:
            from jax_contact.defaults import change_period

            how = "its values moved as params_for moves them, jax_contact.defaults.change_period"
            params = change_period(params, derive(file_dt), derive(dt))
    if abs(file_dt - dt) > SAME_RATE * dt:
        warnings.warn(
            f"{what} has dt = {file_dt:.6g} s; {period} is {dt:.6g} s:"
            f" using {period} ({how}; a file tuned at one rate is best tuned again at another:"
            " jax-contact tune on logs, jax-contact tune-env on a wrapped env)",
            stacklevel=2,
        )
    return (params, provenance) if with_provenance else params


def _groups_text(groups: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in groups.items())


def _robot_name(x) -> bool:
    """Whether ``x`` names a robot (``"go1"``), not a path or a description: what two
    files or a file and a caller can be compared by."""
    return isinstance(x, str) and re.fullmatch(r"[A-Za-z0-9_\-]+", x) is not None


def _params_text(path) -> tuple[str, str]:
    """(text, description for errors) of a parameter file or a preset name."""
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"a parameter file is a path or a preset name, got {type(path).__name__}")
    if str(path).strip() == "":
        raise ValueError("a parameter file is a path or a preset name, got an empty string")
    ref = preset_file(path)
    if ref is not None:
        return ref.read_text(), f"preset {path!r}"
    p = Path(path)
    if isinstance(path, str) and p.suffix == "" and len(p.parts) == 1 and not p.is_file():
        raise ValueError(
            f"parameter file {path!r} does not exist and is no preset name (presets:"
            f" {', '.join(preset_names()) or 'none'})"
        )
    try:
        return p.read_text(), f"parameter file {str(p)!r}"
    except FileNotFoundError:
        raise ValueError(f"parameter file {str(p)!r} does not exist") from None
    except IsADirectoryError:
        raise ValueError(f"parameter file {str(p)!r} is a folder") from None
    except UnicodeDecodeError as err:
        raise ValueError(f"parameter file {str(p)!r} is not JSON: {err}") from None
