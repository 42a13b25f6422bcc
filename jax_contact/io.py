"""Reading and writing logs (HDF5): the only module of the library that touches files.

A log is a flat set of named arrays whose first axis is time, plus metadata. Writes are
atomic: the file is written under a temporary name in the destination folder and renamed
into place only when complete, so an interrupted or failed write never leaves a partial
file behind.

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
``rate_hz``, ``n_envs``, ``foot_names``, ``format_version``. Readings are stored at the
estimator's rate; the estimator's inputs (mass matrix, Jacobians, ...) are recomputed from
them and the robot model when the log is replayed, which keeps logs ~40x smaller.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

import h5py
import numpy as np

FORMAT_VERSION = 1


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
      ValueError: the file is not a jax-contact log (no ``format_version``) or a newer one.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"log file {str(path)!r} does not exist")
    arrays: dict[str, np.ndarray] = {}
    with h5py.File(path, "r") as f:
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
                arrays[name] = obj[()]

        f.visititems(visit)
        attrs = {k: _decode(v) for k, v in f.attrs.items()}
    return arrays, attrs


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

    Args:
      path: the file to create or replace (its folder is created).
      write: callable taking the temporary file's path (a ``str``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


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
