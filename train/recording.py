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
``contact/<foot>``            no        ground truth: 1 in contact, 0 not
``force/<foot>``              no        ground truth: normal force, N (contact above
                                        1 N, the simulator's threshold)
============================  ========  ==========================================

Columns the schema does not name are ignored (their names are listed). A missing needed
column, a ``q/`` column of a joint the model lacks, a time that does not increase, or an
irregular rate is an error naming it. A row with a NaN in a column that is used is not
dropped: the estimator receives the NaN and its per-leg validity (``valid = False``: the
belief only follows the transition prior) handles it; the rows are listed in the output
and left out of the metrics.

Timing (:mod:`jax_contact.train.evaluate`'s convention): row ``j`` *is* reading ``j``. Everything in
a row describes its instant ``t_j`` or the interval ``(t_{j-1}, t_j]`` that ends at it:
the state measured at ``t_j``, the acceleration over the interval (the backward
difference ``(qd_j - qd_{j-1}) / (t_j - t_{j-1})`` where it is differentiated), the
torque that acted during it (a torque sensor's or motor current's reading at ``t_j``; a
log that stores the command sent at ``t_j`` must shift its torque column one row later),
and the ground truth of that interval. The estimator pairs reading ``j``'s acceleration
and torque with reading ``j - 1``'s state, as in simulation. The first row has no
interval before it: its differences repeat the second row's.

Rate: the estimator runs at the recording's rate, ``dt`` the median step of ``time``.
Steps that differ from it by more than 1 % are refused, or with ``resample=True`` the
recording is resampled onto the uniform grid ``t_0 + k dt``: columns linearly
interpolated (the quaternion then normalised), ``contact/`` columns held from the last
sample, and grid points more than ``1.5 dt`` from every sample set to NaN (a gap).
"""

from __future__ import annotations

import csv
import dataclasses
import io as _io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import mujoco
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
RATE_TOLERANCE = 0.01
DIAGNOSTICS = ("p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff", "p_touchdown")


@dataclasses.dataclass(frozen=True)
class Recording:
    """Named (N,) float64 columns of one recording.

    Attributes:
      columns: name -> (N,) values, in file order.
      source: the file, for messages.
    """

    columns: Mapping[str, np.ndarray]
    source: str

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
    if suffix == ".csv":
        columns = _read_csv(path, src)
    elif suffix == ".npz":
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
    out = {}
    for name, col in columns.items():
        if col.ndim != 1:
            raise ValueError(f"{src}: column {name!r} has shape {col.shape}; expected (N,)")
        try:
            out[name] = col.astype(np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{src}: column {name!r} is not numeric ({col.dtype})") from None
    if TIME not in out:
        raise ValueError(f"{src}: missing column {TIME!r} (sample time, s)")
    lengths = {len(c) for c in out.values()}
    if len(lengths) != 1:
        raise ValueError(
            f"{src}: columns have different lengths: "
            + ", ".join(f"{k} {len(v)}" for k, v in out.items() if len(v) != len(out[TIME]))
        )
    return Recording(out, str(path))


def _read_csv(path: Path, src: str) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise ValueError(f"{src} is empty; expected a header row of column names")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise ValueError(f"{src}: column name(s) {dup} appear more than once")
    data = np.full((len(rows) - 1, len(header)), np.nan)
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise ValueError(
                f"{src}: line {i + 2} has {len(row)} fields; the header has {len(header)}"
            )
        for j, cell in enumerate(row):
            cell = cell.strip()
            if cell == "" or cell.lower() == "nan":
                continue
            try:
                data[i, j] = float(cell)
            except ValueError:
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


# ------------------------------------------------------------------------ conversion


@dataclasses.dataclass(frozen=True)
class Converted:
    """A recording as this library's readings (one env).

    Attributes:
      readings: ``qpos`` (T, 1, nq), ``qvel``, ``qacc``, ``tau`` (T, 1, nv), float64.
      time: (T,) s, the readings' times (after any resampling).
      dt: the period, s.
      valid: (T, 1) bool: every used column finite at this row and the one before.
      truth: (T, 1, L) bool ground-truth contact, or None.
      force: (T, 1, L) ground-truth normal force, N, or None.
      terms: the measurement terms the recording supports (``EstimatorParams.terms``).
      has_torque: whether the recording has joint torques.
      notes: what was derived, switched off, ignored or resampled, one line each.
      velocity_from_position: dofs whose velocity is a difference of positions.
      acceleration_from_position: dofs whose acceleration is a second difference of
        positions.
    """

    readings: dict
    time: np.ndarray
    dt: float
    valid: np.ndarray
    truth: np.ndarray | None
    force: np.ndarray | None
    terms: tuple[str, ...]
    has_torque: bool
    notes: tuple[str, ...]
    velocity_from_position: tuple[int, ...] = ()
    acceleration_from_position: tuple[int, ...] = ()


def model_joints(mj_model: mujoco.MjModel, base_body: int):
    """(free joint id or None, [(name, joint id)] of every other joint), or ValueError for
    an unnamed joint, a ball joint, or a free joint that is not the base's."""
    free, joints = None, []
    for j in range(mj_model.njnt):
        kind = int(mj_model.jnt_type[j])
        if kind == int(mujoco.mjtJoint.mjJNT_FREE):
            if int(mj_model.jnt_bodyid[j]) != base_body or free is not None:
                body = mj_model.body(mj_model.jnt_bodyid[j]).name
                raise ValueError(
                    f"the model has a free joint on body {body!r}, which is not the robot's"
                    " base; a recording cannot give its state"
                )
            free = j
            continue
        if kind == int(mujoco.mjtJoint.mjJNT_BALL):
            raise ValueError(f"joint {mj_model.joint(j).name!r} is a ball joint (not supported)")
        name = mj_model.joint(j).name
        if not name:
            raise ValueError(f"joint {j} of the model has no name; recordings name joints")
        joints.append((name, j))
    return free, joints


def _backward_diff(x: np.ndarray, dt: float) -> np.ndarray:
    d = np.empty_like(x)
    d[1:] = (x[1:] - x[:-1]) / dt
    d[0] = d[1] if len(x) > 1 else 0.0
    return d


def _check_time(rec: Recording, resample: bool) -> tuple[Recording, float, list[str]]:
    src = f"recording {rec.source!r}"
    t = rec.columns[TIME]
    if len(t) < 3:
        raise ValueError(f"{src} has {len(t)} rows; expected at least 3")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"{src}: column 'time' is not finite at row {int(bad[0])} (0-based)")
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"{src}: column 'time' does not increase at row {i} (0-based): {t[i]!r} s after"
            f" {t[i - 1]!r} s"
        )
    dt = float(np.median(step))
    off = np.abs(step / dt - 1.0)
    if off.max() <= RATE_TOLERANCE:
        return rec, dt, []
    worst = int(np.argmax(off))
    if not resample:
        raise ValueError(
            f"{src}: irregular time steps: step {worst + 1} is {step[worst]:.6g} s, the median"
            f" {dt:.6g} s (more than {100 * RATE_TOLERANCE:g} % apart); resample it"
            " (--resample: linear interpolation onto a uniform grid) or fix the time column"
        )
    return (
        _resample(rec, dt),
        dt,
        [
            f"resampled onto a uniform {dt:.6g} s grid (steps from {step.min():.6g} to"
            f" {step.max():.6g} s): linear interpolation, quaternion normalised, contact held,"
            " points over 1.5 dt from every sample NaN"
        ],
    )


def _resample(rec: Recording, dt: float) -> Recording:
    t = rec.columns[TIME]
    n = int(math.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    grid = t[0] + dt * np.arange(n)
    idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
    nxt = np.clip(idx + 1, 0, len(t) - 1)
    near = np.minimum(np.abs(grid - t[idx]), np.abs(t[nxt] - grid))
    gap = near > 1.5 * dt
    out = {TIME: grid}
    for name, col in rec.columns.items():
        if name == TIME:
            continue
        if name.startswith("contact/"):
            val = col[idx]
        else:
            val = np.interp(grid, t, col)
        out[name] = np.where(gap, np.nan, val)
    if all(q in out for q in BASE_QUAT):
        quat = np.stack([out[q] for q in BASE_QUAT], axis=1)
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        for k, q in enumerate(BASE_QUAT):
            out[q] = quat[:, k]
    return Recording(out, rec.source)


def to_readings(
    rec: Recording,
    robot,
    *,
    names: Mapping[str, str] | None = None,
    units: str = "rad",
    resample: bool = False,
    force_threshold: float = FORCE_THRESHOLD,
) -> Converted:
    """Converts a recording to readings of ``robot`` (module docstring: schema, timing).

    Args:
      rec: from :func:`read_recording`.
      robot: an :class:`jax_contact.envs.robots.Robot` (its model and feet).
      names: recording name -> model name, for joints and feet whose names differ.
      units: ``"rad"`` or ``"deg"``: the unit of hinge angles, their velocities and
        accelerations and of the base's angular velocity and acceleration.
      resample: resample an irregular recording instead of refusing it.
      force_threshold: normal force above which a ``force/`` column means contact, N.

    Raises:
      ValueError: one line naming the column, joint or row that is wrong.
    """
    if units not in UNITS:
        raise ValueError(f"units must be one of {UNITS}, got {units!r}")
    src = f"recording {rec.source!r}"
    m, desc = robot.mj_model, robot.description
    names = dict(names or {})
    free, joints = model_joints(m, desc.base_body_id)
    model_names = {n for n, _ in joints} | set(desc.foot_names)
    for log_name, model_name in names.items():
        if model_name not in model_names:
            raise ValueError(
                f"names map: {log_name!r} -> {model_name!r}, but the model has no joint or foot"
                f" {model_name!r}; joints: {[n for n, _ in joints]}, feet: {list(desc.foot_names)}"
            )
    rec, dt, notes = _check_time(rec, resample)
    cols = rec.columns
    t_len = len(cols[TIME])
    used: set[str] = {TIME}
    to_model = lambda n: names.get(n, n)  # noqa: E731
    by_model: dict[str, dict[str, str]] = {p: {} for p in JOINT_PREFIXES + TRUTH_PREFIXES}
    joint_names = {n for n, _ in joints}
    for col in cols:
        for prefix in JOINT_PREFIXES + TRUTH_PREFIXES:
            if col.startswith(prefix):
                target = to_model(col[len(prefix) :])
                valid = joint_names if prefix in JOINT_PREFIXES else set(desc.foot_names)
                if target not in valid:
                    what = "joint" if prefix in JOINT_PREFIXES else "foot"
                    raise ValueError(
                        f"{src}: column {col!r}: the model has no {what} {target!r}"
                        f"{' (through the names map)' if target != col[len(prefix) :] else ''};"
                        f" its {what}s: {sorted(valid)}"
                    )
                by_model[prefix][target] = col
    scale = math.pi / 180.0 if units == "deg" else 1.0
    qpos = np.zeros((t_len, m.nq))
    qvel = np.zeros((t_len, m.nv))
    qacc = np.zeros((t_len, m.nv))
    tau = np.zeros((t_len, m.nv))
    missing_tau, missing_qd = [], []
    vel_from_pos, acc_from_pos = [], []
    for name, j in joints:
        col = by_model["q/"].get(name)
        if col is None:
            log = next((k for k, v in names.items() if v == name), name)
            raise ValueError(f"{src}: missing column 'q/{log}' (position of joint {name!r})")
        hinge = int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE)
        s = scale if hinge else 1.0
        qa, va = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        qpos[:, qa] = cols[col] * s
        used.add(col)
        vcol = by_model["qd/"].get(name)
        if vcol is None:
            qvel[:, va] = _backward_diff(qpos[:, qa], dt)
            missing_qd.append(name)
            vel_from_pos.append(va)
        else:
            qvel[:, va] = cols[vcol] * s
            used.add(vcol)
        acol = by_model["qdd/"].get(name)
        if acol is None:
            qacc[:, va] = _backward_diff(qvel[:, va], dt)
            if vcol is None:
                acc_from_pos.append(va)
        else:
            qacc[:, va] = cols[acol] * s
            used.add(acol)
        tcol = by_model["tau/"].get(name)
        if tcol is None:
            missing_tau.append(name)
        else:
            tau[:, va] = cols[tcol]
            used.add(tcol)
    if missing_qd:
        notes.append(f"joint velocities differentiated from positions: {missing_qd}")
    actuated = sorted(
        {n for n, j in joints if any(int(m.actuator_trnid[a, 0]) == j for a in range(m.nu))}
    )
    has_torque = not any(n in missing_tau for n in actuated)
    terms = ["dynamics", "diff_kinematics", "kinematics"]
    if not has_torque:
        terms.remove("dynamics")
        tau[:] = 0.0
        gone = [n for n in actuated if n in missing_tau]
        notes.append(f"no joint torques for {gone}: the dynamics term is off (and the GM observer)")
    if free is not None:
        qa, va = int(m.jnt_qposadr[free]), int(m.jnt_dofadr[free])
        missing = [c for c in BASE_QUAT + BASE["base_angvel"] if c not in cols]
        if missing:
            raise ValueError(
                f"{src}: missing column(s) {missing} (the base's orientation quaternion w, x, y, z"
                " and angular velocity in the base frame: the robot has a floating base)"
            )
        quat = np.stack([cols[c] for c in BASE_QUAT], axis=1)
        qpos[:, qa + 3 : qa + 7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        angvel = np.stack([cols[c] for c in BASE["base_angvel"]], axis=1) * scale
        qvel[:, va + 3 : va + 6] = angvel
        used.update(BASE_QUAT + BASE["base_angvel"])
        has = {k: all(c in cols for c in v) for k, v in BASE.items()}
        if has["base_pos"]:
            qpos[:, qa : qa + 3] = np.stack([cols[c] for c in BASE["base_pos"]], axis=1)
            used.update(BASE["base_pos"])
        else:
            terms.remove("kinematics")
            notes.append("no base position (base_pos/x,y,z): the kinematics term is off")
        if has["base_linvel"]:
            qvel[:, va : va + 3] = np.stack([cols[c] for c in BASE["base_linvel"]], axis=1)
            used.update(BASE["base_linvel"])
        elif has["base_pos"]:
            qvel[:, va : va + 3] = _backward_diff(qpos[:, qa : qa + 3], dt)
            notes.append("base linear velocity differentiated from base_pos")
            vel_from_pos.extend(range(va, va + 3))
        else:
            terms.remove("diff_kinematics")
            notes.append(
                "no base linear velocity or position: the differential-kinematics term is off"
                " and the dynamics use zero base linear velocity and acceleration"
            )
        for key, sl, s in (
            ("base_linacc", slice(va, va + 3), 1.0),
            ("base_angacc", slice(va + 3, va + 6), scale),
        ):
            if has[key]:
                qacc[:, sl] = np.stack([cols[c] for c in BASE[key]], axis=1) * s
                used.update(BASE[key])
            else:
                qacc[:, sl] = _backward_diff(qvel[:, sl], dt)
                acc_from_pos.extend(d for d in range(sl.start, sl.stop) if d in vel_from_pos)
    if not terms:
        raise ValueError(f"{src}: no measurement term can run on this recording")
    truth = force = None
    feet = desc.foot_names
    if by_model["contact/"] or by_model["force/"]:
        have = set(by_model["contact/"]) | set(by_model["force/"])
        lacking = [f for f in feet if f not in have]
        if lacking:
            raise ValueError(
                f"{src}: ground truth for some feet but not {lacking}; give contact/<foot> or"
                f" force/<foot> for every foot of {list(feet)}"
            )
        if len(by_model["force/"]) == len(feet):
            force = np.stack([cols[by_model["force/"][f]] for f in feet], axis=1)[:, None]
        truth = np.stack(
            [
                cols[by_model["contact/"][f]] > 0.5
                if f in by_model["contact/"]
                else cols[by_model["force/"][f]] > force_threshold
                for f in feet
            ],
            axis=1,
        )[:, None]
    finite = np.all(np.isfinite(np.stack([cols[c] for c in sorted(used)], axis=1)), axis=1)
    valid = finite & np.concatenate([[True], finite[:-1]])  # differences use the row before
    if not valid.all():
        notes.append(
            f"rows with NaN (the estimator's valid = False there): {_stretches(~valid, cols[TIME])}"
        )
    ignored = [c for c in cols if c not in used and not c.startswith(TRUTH_PREFIXES)]
    if ignored:
        notes.append(f"columns not in the schema, ignored: {ignored}")
    f32 = lambda a: a[:, None, :]  # noqa: E731
    return Converted(
        readings={"qpos": f32(qpos), "qvel": f32(qvel), "qacc": f32(qacc), "tau": f32(tau)},
        time=np.asarray(cols[TIME]),
        dt=dt,
        valid=valid[:, None],
        truth=truth,
        force=force,
        terms=tuple(terms),
        has_torque=has_torque,
        notes=tuple(notes),
        velocity_from_position=tuple(sorted(vel_from_pos)),
        acceleration_from_position=tuple(sorted(acc_from_pos)),
    )


def noise_for_differences(params, conv: Converted):
    """``params`` with the noise of differentiated coordinates raised to what the
    differences carry: a velocity that is a backward difference of positions with white
    noise ``sigma_q`` has ``sqrt(2) sigma_q / dt`` more, an acceleration that is a second
    difference ``sqrt(6) sigma_q / dt^2`` more (weights 1, -2, 1), added in quadrature to
    the parameters' own ``sigma_qd`` and ``sigma_qdd``. The parameters' ``sigma_q`` (which
    may include a bias drift that the difference cancels) makes this conservative.
    """
    import jax.numpy as jnp

    if not conv.velocity_from_position:
        return params
    n, dt = params.noise, conv.dt
    sq = np.asarray(n.sigma_q, np.float64)
    sqd = np.array(n.sigma_qd, np.float64)
    sqdd = np.array(n.sigma_qdd, np.float64)
    v, a = list(conv.velocity_from_position), list(conv.acceleration_from_position)
    sqd[v] = np.sqrt(sqd[v] ** 2 + 2.0 * (sq[v] / dt) ** 2)
    sqdd[a] = np.sqrt(sqdd[a] ** 2 + 6.0 * (sq[a] / dt**2) ** 2)
    noise = n.replace(
        sigma_qd=jnp.asarray(sqd, jnp.float32), sigma_qdd=jnp.asarray(sqdd, jnp.float32)
    )
    return params.replace(noise=noise)


def _stretches(mask: np.ndarray, t: np.ndarray) -> str:
    """'rows a-b (t0-t1 s), ...' of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    runs = [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    text = ", ".join(f"rows {a}-{b} ({t[a]:.4g}-{t[b]:.4g} s)" for a, b in runs[:5])
    return text + (f" and {len(runs) - 5} more" if len(runs) > 5 else "")


def log_to_columns(
    log,
    *,
    env: int = 0,
    names: Mapping[str, str] | None = None,
    units: str = "rad",
    velocities: bool = True,
    accelerations: bool = True,
    torques: bool = True,
    truth_force: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """One env of a simulated log (:func:`jax_contact.train.logs.load_log`) as recording columns.

    Reading ``k`` becomes row ``k`` at ``time = (k + 1) dt`` (the end of its step), so
    that :func:`to_readings` gives the log's readings back (with every column) and the
    estimator the same probabilities.

    Args:
      names: model name -> recording name (the inverse of :func:`to_readings`' map).
      units: ``"deg"`` writes hinge angles and angular rates in degrees.
      velocities, accelerations, torques: write those columns.
      truth_force: (T, E, L) normal forces to write as ``force/<foot>``.
    """
    r = log.readings
    m, desc = log.robot.mj_model, log.robot.description
    names = dict(names or {})
    scale = 180.0 / math.pi if units == "deg" else 1.0
    free, joints = model_joints(m, desc.base_body_id)
    t_len = r["qpos"].shape[0]
    cols = {TIME: (np.arange(t_len) + 1.0) * log.dt}
    pick = lambda key, i: np.asarray(r[key][:, env, i], np.float64)  # noqa: E731
    for name, j in joints:
        s = scale if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE) else 1.0
        label = names.get(name, name)
        qa, va = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        cols[f"q/{label}"] = pick("qpos", qa) * s
        if velocities:
            cols[f"qd/{label}"] = pick("qvel", va) * s
        if accelerations:
            cols[f"qdd/{label}"] = pick("qacc", va) * s
        if torques and any(int(m.actuator_trnid[a, 0]) == j for a in range(m.nu)):
            cols[f"tau/{label}"] = pick("tau", va)
    if free is not None:
        qa, va = int(m.jnt_qposadr[free]), int(m.jnt_dofadr[free])
        for k, c in enumerate(BASE["base_pos"]):
            cols[c] = pick("qpos", qa + k)
        for k, c in enumerate(BASE_QUAT):
            cols[c] = pick("qpos", qa + 3 + k)
        for k, c in enumerate(BASE["base_linvel"]):
            cols[c] = pick("qvel", va + k)
        for k, c in enumerate(BASE["base_angvel"]):
            cols[c] = pick("qvel", va + 3 + k) * scale
        if accelerations:
            for k, c in enumerate(BASE["base_linacc"]):
                cols[c] = pick("qacc", va + k)
            for k, c in enumerate(BASE["base_angacc"]):
                cols[c] = pick("qacc", va + 3 + k) * scale
    for i, foot in enumerate(desc.foot_names):
        label = names.get(foot, foot)
        if log.truth is not None:
            cols[f"contact/{label}"] = log.truth[:, env, i].astype(np.float64)
        if truth_force is not None:
            cols[f"force/{label}"] = np.asarray(truth_force[:, env, i], np.float64)
    return cols


# ------------------------------------------------------------------------ estimation


def estimate_recording(
    path: str | Path,
    *,
    model: str,
    out_dir: str | Path,
    feet: Sequence[str] | None = None,
    names: Mapping[str, str] | None = None,
    params_path: str | Path | None = None,
    units: str = "rad",
    resample: bool = False,
    plots: bool = True,
    plot_seconds: float = 4.0,
    progress: bool = True,
    terrain_model: str | None = None,
) -> dict:
    """``jax-contact estimate``: P(contact) per foot for a recording (module docstring).

    ``terrain_model``: the estimator's terrain model
    (:data:`jax_contact.train.logs.TERRAIN_MODELS`): ``"flat"`` a plane at z = 0 of the
    recording's world frame, ``"memory"`` the feet's own footholds, for a ``base_pos`` that
    drifts (a state estimator's, over a long recording); None: the one ``params_path`` was
    tuned with, else ``"flat"``.

    Writes into ``out_dir``: ``estimate.h5`` (``time`` (T,), ``p_contact``, each of
    :data:`DIAGNOSTICS` and ``valid`` as (T, L) arrays, ``truth/contact`` when known;
    attributes ``model``, ``foot_names``, ``terms``, ``dt``, ``notes``), ``estimate.csv``
    (``time`` and ``<field>/<foot>`` columns), ``<foot>.png`` per foot, and with ground
    truth ``metrics.json``. Prints the notes (derived columns, terms off), a summary per
    foot and, with ground truth, the metrics table of ``jax-contact evaluate``.

    Returns:
      ``notes``, ``terms``, ``foot_names``, ``dt``, ``files`` (written), ``outputs`` (the
      replay's (T, 1, L) arrays), ``scores`` (empty without ground truth).
    """
    from jax_contact.baselines import make_gm_params, make_kinematic_params
    from jax_contact.envs.robots import load_robot
    from jax_contact.io import write_json_atomic, write_log
    from jax_contact.train.evaluate import replay, score
    from jax_contact.train.logs import _estimator_for, format_scores

    rec = read_recording(path)
    robot = load_robot(model, foot_names=feet)
    conv = to_readings(rec, robot, names=names, units=units, resample=resample)
    desc = robot.description
    params, terrain_model, terrain = _estimator_for(desc, conv.dt, params_path, terrain_model)
    terms = tuple(t for t in params.terms if t in conv.terms)
    if not terms:
        raise ValueError(
            f"the parameters' terms {params.terms} and the recording's {conv.terms} share none"
        )
    params = noise_for_differences(params.replace(terms=terms), conv)
    notes = list(conv.notes)
    if conv.velocity_from_position:
        notes.append(
            "the estimator's velocity and acceleration noise of the differentiated"
            " coordinates raised to that of the differences (sqrt(2) sigma_q / dt,"
            " sqrt(6) sigma_q / dt^2)"
        )
    notes.insert(0, f"estimator terms: {', '.join(terms)}; rate {1.0 / conv.dt:.6g} Hz")
    for line in notes:
        print(f"note: {line}")
    has_truth = conv.truth is not None
    out = replay(
        robot,
        conv.readings,
        estimators={"probabilistic": params},
        terrain=terrain,
        gms={"gm": make_gm_params()} if has_truth and conv.has_torque else None,
        kinematic=make_kinematic_params() if has_truth else None,
        dt=conv.dt,
        diagnostics_of="probabilistic",
        progress=progress,
    )
    out_dir = Path(out_dir)
    feet_names = list(desc.foot_names)
    fields = {"p_contact": out["probabilistic"]} | {
        f: out[f"probabilistic/{f}"] for f in DIAGNOSTICS
    }
    fields["valid"] = out["probabilistic/valid"].astype(np.float64)
    arrays = {"time": conv.time} | {k: np.asarray(v[:, 0], np.float32) for k, v in fields.items()}
    if has_truth:
        arrays["truth/contact"] = conv.truth[:, 0]
    attrs = {
        "model": str(model),
        "recording": str(path),
        "terrain_model": terrain_model,
        "foot_names": feet_names,
        "terms": list(terms),
        "dt": conv.dt,
        "notes": notes,
        "reading_timing": "end_of_step",
    }
    files = [write_log(out_dir / "estimate.h5", arrays, attrs)]
    columns = {"time": conv.time}
    for field, value in fields.items():
        for i, foot in enumerate(feet_names):
            columns[f"{field}/{foot}"] = np.asarray(value[:, 0, i], np.float64)
    files.append(write_recording_csv(out_dir / "estimate.csv", columns))
    if plots:
        from types import SimpleNamespace

        from jax_contact.train.figures import plot_estimate

        nan = np.full(out["probabilistic"].shape, np.nan)
        shown = SimpleNamespace(
            time=conv.time - conv.time[0],
            contact=conv.truth if has_truth else nan,
            force=conv.force if conv.force is not None else nan,
        )
        for i, foot in enumerate(feet_names):
            files.append(
                plot_estimate(
                    out,
                    shown,
                    "probabilistic",
                    out_dir / f"{_safe(foot)}.png",
                    leg=i,
                    seconds=plot_seconds,
                    title=f"{Path(path).name}: foot {foot!r} (terms: {', '.join(terms)})",
                )
            )
    p = np.asarray(out["probabilistic"])[:, 0]
    summary = "  ".join(f"{f} {np.nanmean(p[:, i] > 0.5):.2f}" for i, f in enumerate(feet_names))
    print(f"{len(p)} readings at {conv.dt * 1e3:.4g} ms; share of steps in contact: {summary}")
    scores = {}
    if has_truth:
        scores = score(out, conv.truth, conv.valid, dt=conv.dt)
        print(format_scores(scores, title=Path(path).name))
        files.append(write_json_atomic(out_dir / "metrics.json", scores))
    else:
        print("no ground truth columns (contact/<foot> or force/<foot>): no metrics")
    print("wrote " + ", ".join(str(f) for f in files))
    return {
        "notes": notes,
        "terms": terms,
        "foot_names": feet_names,
        "dt": conv.dt,
        "files": files,
        "outputs": out,
        "scores": scores,
    }


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "foot"
