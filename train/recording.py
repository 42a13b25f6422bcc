"""Recordings not made by this library (a robot's logs) -> the estimator, and back.

:func:`estimate_recording` is ``jax-contact estimate``: it reads a recording with named
columns (CSV, NPZ or HDF5), converts it to this library's readings for a robot model
(:func:`to_readings`), runs :func:`jax_contact.train.evaluate.replay` and writes per-foot
P(contact), each term's probability and the two transition probabilities as HDF5 and CSV
(atomically,
:mod:`jax_contact.io`), a Fig.-5-style PNG per foot, and the metrics when the recording
has ground truth.

Schema (one row per sample; names are case-sensitive; ``<joint>`` is a joint name of the
model, or a name that the names map sends to one; ``<foot>`` likewise a foot name):

============================  ========  ==========================================
column                        needed    meaning, unit
============================  ========  ==========================================
``time``                      yes       sample time, s, strictly increasing
``q/<joint>``                 yes       every joint of the model but the base's free
                                        joint: position, rad (``--units deg``: deg) or m
``qd/<joint>``                no        joint velocity, rad/s (deg/s) or m/s;
                                        absent: backward difference of ``q``
``qdd/<joint>``               no        joint acceleration; absent: difference of ``qd``
                                        (with ``qd`` absent too: the dynamics term off)
``tau/<joint>``               no        joint torque (force), N m or N; absent: the
                                        dynamics term is switched off (said in the output)
``base_quat/{w,x,y,z}``       floating  base orientation, base -> world (MuJoCo order)
``base_angvel/{x,y,z}``       floating  base angular velocity in the base frame (the
                                        IMU's gyroscope), rad/s (deg/s)
``base_pos/{x,y,z}``          no        base position in the world, m; absent: the
                                        kinematics term is switched off
``base_linvel/{x,y,z}``       no        base linear velocity in the world frame, m/s;
                                        absent: difference of ``base_pos``, or with
                                        neither the differential-kinematics term off
``base_linacc/{x,y,z}``       no        base linear acceleration, world, m/s^2 (no
                                        gravity); absent: difference of ``base_linvel``
``base_angacc/{x,y,z}``       no        base angular acceleration, base frame; absent:
                                        difference of ``base_angvel``
``contact/<foot>``            no        ground truth: 1 in contact, 0 not; a blank
                                        cell is unknown (left out of the metrics)
``force/<foot>``              no        ground truth: normal force, N (contact above
                                        ``--force-threshold``, 1 N by default, the
                                        simulator's threshold)
============================  ========  ==========================================

Columns the schema does not name are ignored (their names are listed). A missing needed
column, a ``q/`` column of a joint the model lacks (the names map can drop it: a name
mapped to ``""``), a time that does not increase, or an irregular rate is an error naming
it. Readings that look like another convention are warned about: a joint's ``qd/`` or
``qdd/`` column that does not integrate to the change of the column it is the derivative
of (sign, degrees), a gyroscope rate that does not integrate to the base orientation's
turns (degrees, sign, world axes), a base orientation whose z axis points down on most
rows (with a hint when the columns look like x, y, z, w order), a base velocity that fits
``base_pos`` only rotated from the base frame, a base acceleration that holds gravity,
and (after the replay) torques that cannot hold the feet up
(:mod:`jax_contact.train.recording_checks`).

A row with a NaN in a column that is used is not dropped: the estimator receives the NaN
and its per-leg validity (``valid = False``: the belief only follows the transition
prior) handles it; the rows are listed in the output, and the steps of the feet whose terms read
the lost value (a joint's: its leg's foot; a base reading's: every foot) are left out of
the metrics.

The conversion of a recording into readings (the timing of a row, the rate, resampling)
is :mod:`jax_contact.train.recording_convert`; the ``jax-contact estimate`` job is
:mod:`jax_contact.train.recording_estimate`.
"""

from __future__ import annotations

import csv
import dataclasses
import io as _io
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

TIME = "time"
AXES = ("x", "y", "z")
BASE_QUAT = tuple(f"base_quat/{c}" for c in "wxyz")
BASE = {
    name: tuple(f"{name}/{a}" for a in AXES)
    for name in ("base_pos", "base_linvel", "base_angvel", "base_linacc", "base_angacc")
}
JOINT_PREFIXES = ("q/", "qd/", "qdd/", "tau/")
TRUTH_PREFIXES = ("contact/", "force/")
SUFFIXES = (".csv", ".npz", ".h5", ".hdf5")
UNITS = ("rad", "deg")
FORCE_THRESHOLD = 1.0  # N, jax_contact.envs.ground_truth's default
DIAGNOSTICS = ("p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff", "p_touchdown")


class SimulateLogGiven(ValueError):
    """A log of ``jax-contact simulate`` given where a recording is read: the commands that
    read recordings say which of theirs reads the log."""


def in_schema(name: str) -> bool:
    """Whether the schema reads a column of this name (the rest are ignored, with a note)."""
    base = set(BASE_QUAT).union(*BASE.values())
    return name == TIME or name in base or name.startswith(JOINT_PREFIXES + TRUTH_PREFIXES)


@dataclasses.dataclass(frozen=True)
class Recording:
    """Named (N,) float64 columns of one recording.

    Attributes:
      columns: name -> (N,) values, in file order.
      source: the file, for messages.
      notes: what reading the file left out (a CSV's incomplete last line), one line each.
    """

    columns: Mapping[str, np.ndarray]
    source: str
    notes: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.columns[TIME]) if TIME in self.columns else 0


def read_recording(path: str | Path) -> Recording:
    """Reads a CSV (header row of names), NPZ (one 1-D array per name) or HDF5 (one 1-D
    dataset per name; ``/`` in a name is a group) recording.

    Raises:
      ValueError: one line naming the file: an unknown suffix, an unreadable file, a
        non-numeric CSV cell (its line and column), columns of different lengths, a
        column that is not 1-D, or no ``time`` column.
    """
    path = Path(path)
    src = f"recording {str(path)!r}"
    if not path.is_file():
        raise ValueError(f"{src} does not exist")
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"{src}: unknown format {path.suffix!r}; expected one of {SUFFIXES}")
    notes: list[str] = []
    if suffix == ".csv":
        columns = _read_csv(path, src, notes)
    elif suffix == ".npz":
        import zipfile

        if not zipfile.is_zipfile(path):  # numpy's own message spoke of allow_pickle
            raise ValueError(f"{src} is not an NPZ archive (another file renamed .npz?)")
        try:
            with np.load(path, allow_pickle=False) as z:
                columns = {k: np.asarray(z[k]) for k in z.files}
        except (OSError, ValueError) as err:
            raise ValueError(f"{src} cannot be read as NPZ ({err})") from None
    else:
        import h5py

        columns = {}
        try:
            with h5py.File(path, "r") as f:
                f.visititems(
                    lambda name, obj: (
                        columns.__setitem__(name, np.asarray(obj[()]))
                        if isinstance(obj, h5py.Dataset)
                        else None
                    )
                )
        except OSError as err:
            raise ValueError(
                f"{src} cannot be read as HDF5 ({' '.join(str(err).split())})"
            ) from None
    if "readings/qpos" in columns and "time" in columns:  # a jax_contact.io log
        raise SimulateLogGiven(
            f"{src} is a log of `jax-contact simulate` (readings/qpos, ... per env): run"
            " `jax-contact evaluate` on it; `estimate` reads a recording of named columns"
        )
    # Before a column's shape is refused: estimate.h5's p_contact is (T, L). (A table of
    # 1-D columns, estimate.csv's, still reads: to_readings refuses it as input.)
    refuse_estimate_output(src, [n for n, col in columns.items() if col.ndim != 1])
    out = {}
    for name, col in columns.items():
        if col.ndim != 1:
            raise ValueError(
                f"{src}: column {name!r} has shape {col.shape}; expected (N,): one 1-D array"
                " per column, named as a CSV header's (q/<joint>, tau/<joint>, base_quat/w,"
                " ...), not a matrix of several"
            )
        try:
            out[name] = col.astype(np.float64)
        except (TypeError, ValueError):
            if in_schema(name):
                raise ValueError(f"{src}: column {name!r} is not numeric ({col.dtype})") from None
            out[name] = np.full(col.shape, np.nan)  # text the schema does not read: ignored
    if TIME not in out:
        raise ValueError(f"{src}: missing column {TIME!r} (sample time, s)")
    lengths = {len(c) for c in out.values()}
    if len(lengths) != 1:
        raise ValueError(
            f"{src}: columns have different lengths: "
            + ", ".join(f"{k} {len(v)}" for k, v in out.items() if len(v) != len(out[TIME]))
        )
    return Recording(out, str(path), tuple(notes))


def refuse_estimate_output(src: str, names) -> None:
    """A ValueError if the column ``names`` are an output of ``jax-contact estimate``
    (``p_contact``, or its CSV's ``p_contact/<foot>``) given where a recording is read."""
    if any(n == "p_contact" or n.startswith("p_contact/") for n in names):
        raise ValueError(
            f"{src} is an output of `jax-contact estimate` (its p_contact); give the recording"
            " it was estimated from"
        )


def _read_csv(path: Path, src: str, notes: list[str]) -> dict[str, np.ndarray]:
    """The CSV's columns; an incomplete last line (fewer fields than the header: a logger
    stopped mid-write) is dropped with a line in ``notes``; any other line of the wrong
    length is refused. A byte-order mark (a spreadsheet's "CSV UTF-8") is read past."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as err:  # a binary file named .csv, or a Latin-1 export
        raise ValueError(
            f"{src} is not UTF-8 text (byte {err.start}: {err.reason}); a recording's CSV is"
            " UTF-8 (another file renamed .csv? a spreadsheet's Latin-1 export: save it as"
            ' "CSV UTF-8")'
        ) from None
    if not rows:
        raise ValueError(f"{src} is empty; expected a header row of column names")
    header = [h.strip() for h in rows[0]]
    if len(header) == 1 and (sep := next((c for c in ";\t|" if c in header[0]), None)):
        raise ValueError(
            f"{src}: the header is one field holding {sep!r}; a recording's CSV separates its"
            " columns by commas"
        )
    if len(rows) > 2 and len(rows[-1]) < len(header):
        notes.append(
            f"the last line ({len(rows)}) has {len(rows[-1])} of the header's {len(header)}"
            " fields: dropped (a logger stopped mid-write leaves such a line)"
        )
        rows = rows[:-1]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise ValueError(f"{src}: column name(s) {dup} appear more than once")
    data = np.full((len(rows) - 1, len(header)), np.nan)
    text = set()  # columns the schema does not read that hold text: ignored (left NaN)
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise ValueError(
                f"{src}: line {i + 2} has {len(row)} fields; the header has {len(header)}"
            )
        for j, cell in enumerate(row):
            cell = cell.strip()
            if cell == "" or cell.lower() == "nan" or j in text:
                continue
            try:
                data[i, j] = float(cell)
            except ValueError:
                if not in_schema(header[j]):
                    text.add(j)
                    data[:, j] = np.nan
                    continue
                raise ValueError(
                    f"{src}: line {i + 2}, column {header[j]!r}: {cell!r} is not a number"
                ) from None
    return {h: data[:, j] for j, h in enumerate(header)}


def write_recording_csv(path: str | Path, columns: Mapping[str, np.ndarray]) -> Path:
    """Writes named (N,) columns as a CSV with a header row (atomically); NaN as empty."""
    from jax_contact.io import write_text_atomic

    names = list(columns)
    data = np.stack([np.asarray(columns[n], np.float64) for n in names], axis=1)
    buf = _io.StringIO()
    buf.write(",".join(names) + "\n")
    for row in data:
        buf.write(",".join("" if not math.isfinite(v) else repr(float(v)) for v in row) + "\n")
    return write_text_atomic(path, buf.getvalue())
