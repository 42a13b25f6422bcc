"""Reading and writing logs (HDF5), and the atomic writes every output of the library
goes through (parameter files: :mod:`jax_contact.params_file`).

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

and root attributes ``robot``, ``gait``, ``noise``, ``terrain``, ``roughness``, ``seed``,
``dt`` (s), ``rate_hz``, ``n_envs``, ``foot_names``, ``gait_settings``, ``reading_timing``,
``format_version`` and ``model_sha256`` (the simulated model's fingerprint: loading warns
when the robot's model now differs). A ``rough`` log's floor is drawn with its ``seed``
(since the forty-ninth session; before, every seed had seed 0's floor).
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
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import h5py
import numpy as np

FORMAT_VERSION = 1

# Temporary files of writes in progress, so that a process stopped from another thread (the
# CLI on Ctrl-C, :func:`abort_writes`) can remove them. The lock makes "create and
# register" and "rename and unregister" each indivisible with respect to the abort.
_PENDING: set[str] = set()
_LOCK = threading.Lock()
# The files written completely so far (completed_writes).
_DONE: list[str] = []
# Output folders a staged_folder or write_atomic in progress made, deepest first: removed if
# still empty when the output is not written (an exception, or abort_writes).
_MADE_DIRS: list[Path] = []


def _remove_empty(dirs) -> None:
    """Removes each folder of ``dirs`` (deepest first) while it is empty."""
    for made in dirs:
        try:
            made.rmdir()
        except OSError:  # not empty (another output went there meanwhile), or gone
            break


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
      ValueError: naming the array or attribute, before the file is opened: an array name
        that is empty or also another array's group, an array that is ragged or not of
        bool, integer or float dtype, an attribute name that is no str, an attribute that
        cannot be stored, or ``attrs`` sets ``format_version`` to another value than the
        library's (a file it would refuse to read; the attributes of a log read by
        :func:`read_log` carry the same value).
    """
    path = Path(path)
    if attrs.get("format_version", FORMAT_VERSION) != FORMAT_VERSION:
        raise ValueError(
            f"attrs: 'format_version' {attrs['format_version']!r} is not this library's"
            f" ({FORMAT_VERSION}), which write_log writes itself: leave it out"
        )
    _check_log_contents(arrays, attrs)

    def write(tmp: str) -> None:
        with h5py.File(tmp, "w") as f:
            for name, arr in arrays.items():
                f.create_dataset(name, data=np.asarray(arr), compression="gzip", compression_opts=1)
            f.attrs["format_version"] = FORMAT_VERSION
            for key, value in attrs.items():
                f.attrs[key] = _attr(key, value)

    return write_atomic(path, write)


def _check_log_contents(arrays: Mapping, attrs: Mapping) -> None:
    """Names and dtypes HDF5 can store, checked before the file is opened (h5py's own
    errors name neither the array nor the attribute)."""
    names = list(arrays)
    for name in names:
        if not isinstance(name, str) or not name.strip("/"):
            raise ValueError(
                f"array name {name!r}: expected a non-empty str such as 'readings/qpos'"
            )
        try:
            dtype = np.asarray(arrays[name]).dtype
        except ValueError as err:  # a ragged nested list
            raise ValueError(f"array {name!r} is not rectangular: {err}") from None
        if dtype.kind not in "biuf":
            raise ValueError(
                f"array {name!r} has dtype {dtype} and cannot be written: expected bool,"
                " integer or float arrays (strings and metadata go into attrs)"
            )
    # "a" and "a/b" (or "a/b/c"): a dataset cannot also be a group, at any depth.
    paths = [n.strip("/").split("/") for n in names]
    groups = {"/".join(p[:i]) for p in paths for i in range(1, len(p))}
    for name, p in zip(names, paths, strict=True):
        if "/".join(p) in groups:
            raise ValueError(
                f"array {name!r} is also a group of another array's name; rename one of them"
            )
    for key in attrs:
        if not isinstance(key, str) or not key:
            raise ValueError(f"attribute name {key!r}: expected a non-empty str")


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
      ValueError: one line naming the file: a folder, not an HDF5 file, truncated or otherwise
        unreadable (naming the array that could not be read), not a jax-contact log (no
        ``format_version``) or a newer one.
    """
    return _read(path, arrays=True)


def read_log_attrs(path: str | os.PathLike) -> dict:
    """The attributes of a log written by :func:`write_log`, without reading its arrays
    (a check of several logs' robots and rates before any is loaded).

    Raises:
      FileNotFoundError, ValueError: as :func:`read_log`.
    """
    return _read(path, arrays=False)[1]


def _read(path: str | os.PathLike, arrays: bool) -> tuple[dict[str, np.ndarray], dict]:
    """:func:`read_log`, or its attributes alone (``arrays`` False: an empty dict)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"log file {str(path)!r} is a folder")
    if not path.is_file():
        raise FileNotFoundError(f"log file {str(path)!r} does not exist")
    out: dict[str, np.ndarray] = {}
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
        try:
            version = int(version)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(
                f"{str(path)!r}: format_version {version!r} is not an integer; not a"
                " jax-contact log, or a corrupt one"
            ) from None
        if version > FORMAT_VERSION:
            raise ValueError(
                f"{str(path)!r} has format_version {version}; this library reads up to"
                f" {FORMAT_VERSION}"
            )

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                try:
                    out[name] = obj[()]
                except (OSError, KeyError, RuntimeError) as err:  # truncated / corrupt data
                    raise ValueError(
                        f"log file {str(path)!r}: array {name!r} cannot be read"
                        f" ({_h5_reason(err)}); the file is truncated or corrupt"
                    ) from None

        try:
            if arrays:
                f.visititems(visit)
            attrs = {k: _decode(v) for k, v in f.attrs.items()}
        except (OSError, KeyError, RuntimeError) as err:
            raise ValueError(
                f"log file {str(path)!r} cannot be read ({_h5_reason(err)}); the file is"
                " truncated or corrupt"
            ) from None
    return out, attrs


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

    A symbolic link is written through: its target is replaced and the link kept. A path
    that is no regular file (a device such as ``/dev/null``, a FIFO, a socket) is refused:
    the rename would replace the device itself with a file.

    Args:
      path: the file to create or replace (its folder is created, and removed again,
        if still empty, when the write fails or is stopped).
      write: callable taking the temporary file's path (a ``str``).

    Raises:
      OSError: ``path`` is a folder or no regular file (named), or cannot be created.
    """
    path = Path(path)
    if path.is_symlink():
        path = path.resolve()
    if path.is_dir():  # refused before any write (os.replace would name the temporary file)
        raise IsADirectoryError(errno.EISDIR, f"cannot create {str(path)!r}: it is a folder")
    if (kind := not_a_file(path)) is not None:
        raise OSError(errno.EEXIST, f"cannot replace {str(path)!r}: it is {kind}, not a file")
    # Removed again (when empty) if the write fails or is stopped, as staged_folder's, so a
    # failed run leaves no empty folder behind.
    created = _missing_folders(path.parent)
    try:
        with _LOCK:
            _make_folders(path.parent, created)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
            _PENDING.add(tmp)
    except OSError as err:  # name the file asked for, not the temporary one
        _unmake(created)
        raise OSError(err.errno, f"cannot create {str(path)!r} ({err.strerror})") from None
    os.close(fd)
    try:
        write(tmp)
        # After write(): a writer may delete and recreate the file (the mode would go).
        os.chmod(tmp, 0o666 & ~_umask())
        with _LOCK:
            os.replace(tmp, path)
            _PENDING.discard(tmp)
            _forget_made(created)
            # Inside a staged folder still being written, it is not there yet.
            if not any(path.is_relative_to(p) for p in _PENDING):
                _DONE.append(str(path))
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        _unmake(created, tmp)
        raise
    return path


def not_a_file(path: str | os.PathLike) -> str | None:
    """What ``path`` is when it exists and is neither a regular file nor a folder (links
    followed): ``"a character device"``, ``"a block device"``, ``"a FIFO"``, ``"a socket"``;
    None otherwise."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, kind in (
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return kind
    return None


def completed_writes() -> list[str]:
    """The files this process has written completely through :func:`write_atomic` and
    :func:`staged_folder`, in order (the CLI's Ctrl-C handler names them: they are whole).
    Read without the lock, which :func:`abort_writes` holds by then. A file written
    more than once (``train``'s ``progress.csv`` after each evaluation) is named once, at
    its latest write."""
    return list(reversed(dict.fromkeys(reversed(_DONE))))


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
    _remove_empty(list(_MADE_DIRS))
    _MADE_DIRS.clear()
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
    # The folders above ``folder`` made here: removed again (when empty) if nothing is
    # written, so a stopped run leaves no empty output folder behind.
    created = _missing_folders(folder.parent)
    try:
        with _LOCK:
            _make_folders(folder.parent, created)
            tmp = tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}.", suffix=".tmp")
            _PENDING.add(tmp)
    except OSError as err:  # named, not the temporary folder's errno
        _unmake(created)
        raise OSError(
            f"cannot write into {str(folder)!r}: its files are staged beside it, in"
            f" {str(folder.parent)!r}, which takes no new folders ({err.strerror or err})"
        ) from None
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
            _swap_in(folder, Path(tmp), names, sorted(old - set(names)))
            os.rmdir(tmp)
            _PENDING.discard(tmp)
            _DONE.extend(str(folder / name) for name in names)
            _forget_made(created)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _unmake(created, tmp)
        raise


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and the folders above it that do not exist yet, deepest first."""
    return [p for p in [folder, *folder.parents] if not p.exists()]


def _make_folders(folder: Path, created: list[Path]) -> None:
    """Creates ``folder`` and registers ``created`` (:func:`_missing_folders`) in
    :data:`_MADE_DIRS`, for :func:`abort_writes` (under ``_LOCK``)."""
    folder.mkdir(parents=True, exist_ok=True)
    _MADE_DIRS[:0] = created


def _unmake(created: list[Path], tmp: str | None = None) -> None:
    """After an output failed or was stopped: forgets the temporary ``tmp`` (already
    removed) and ``created``, and removes those folders while empty."""
    with _LOCK:
        _PENDING.discard(tmp)
        _forget_made(created)
    _remove_empty(created)


def _forget_made(dirs) -> None:
    """Drops ``dirs`` from :data:`_MADE_DIRS` (under ``_LOCK``)."""
    for made in dirs:
        if made in _MADE_DIRS:
            _MADE_DIRS.remove(made)


def _swap_in(folder: Path, tmp: Path, names: list[str], stale: list[str]) -> None:
    """Moves ``tmp``'s files ``names`` into ``folder`` and removes its files ``stale``, all
    or nothing: the files they replace are first moved aside (a folder beside ``folder``),
    and a rename that fails midway (a file that cannot be replaced, Ctrl-C) puts every
    file back where it was before the error is raised. A move one by one left a user's
    folder half this run's, half the earlier run's, when its 11th file could not be
    replaced. Called under ``_LOCK``."""
    aside = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}.", suffix=".old"))
    moved_aside, moved_in = [], []
    try:
        for name in names + stale:
            if (folder / name).exists():
                os.replace(folder / name, aside / name)
                moved_aside.append(name)
        for name in names:
            os.replace(tmp / name, folder / name)
            moved_in.append(name)
    except BaseException as err:
        for name in reversed(moved_in):  # back into the staged folder, which is then removed
            os.replace(folder / name, tmp / name)
        for name in reversed(moved_aside):
            os.replace(aside / name, folder / name)
        os.rmdir(aside)
        if isinstance(err, OSError):
            raise OSError(
                err.errno,
                f"cannot replace the files of {str(folder)!r} ({err.strerror or err}:"
                f" {err.filename!r}); the output folder is as it was",
            ) from None
        raise
    shutil.rmtree(aside)


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
    return write_text_atomic(path, json.dumps(json_safe(payload), indent=2))


def json_safe(x):
    """``x`` as JSON values: numpy arrays and scalars as Python ones, NaN and inf as None."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x
