"""A recording (:mod:`jax_contact.train.recording`'s schema) -> this library's readings.

:func:`to_readings` converts the named columns of a recording into the ``qpos``, ``qvel``,
``qacc`` and ``tau`` readings of a robot model (one env), deriving what is absent by
backward differences and switching off the terms the recording cannot feed;
:func:`log_to_columns` is the reverse, a simulated log written as a recording.

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

import dataclasses
import math
from collections.abc import Mapping

import mujoco
import numpy as np

from jax_contact.train.cli_args import MIN_RATE_HZ, RATE_TOLERANCE
from jax_contact.train.recording import (
    BASE,
    BASE_QUAT,
    FORCE_THRESHOLD,
    JOINT_PREFIXES,
    TIME,
    TRUTH_PREFIXES,
    UNITS,
    Recording,
    refuse_estimate_output,
)
from jax_contact.train.recording_checks import (
    angular_velocity_mismatch,
    degenerate_quaternion,
    derivative_mismatch,
    force_truth,
    holds_gravity,
    outside_range,
    range_warnings,
    torque_beyond_limit,
    truth_columns_disagree,
    upside_down,
    velocity_in_base_frame,
)


@dataclasses.dataclass(frozen=True)
class Converted:
    """A recording as this library's readings (one env).

    Attributes:
      readings: ``qpos`` (T, 1, nq), ``qvel``, ``qacc``, ``tau`` (T, 1, nv), float64.
      time: (T,) s, the readings' times (after any resampling).
      dt: the period, s.
      valid: (T, 1) bool: every used column finite at this row and the one before.
      truth: (T, 1, L) bool ground-truth contact, or None.
      truth_known: (T, 1, L) bool: the foot's truth column is finite at this row (a
        missing value is no contact or air: metrics leave it out), or None.
      force: (T, 1, L) ground-truth normal force, N, or None.
      terms: the measurement terms the recording supports (``EstimatorParams.terms``).
      has_torque: whether the recording has joint torques.
      notes: what was derived, switched off, ignored or resampled, one line each.
      velocity_from_position: dofs whose velocity is a difference of positions.
      acceleration_from_position: dofs whose acceleration is a second difference of
        positions.
      tau_columns: dof -> the recording's ``tau/`` column that filled it (for messages).
      missing_torques: the actuated joints with no ``tau/`` column (empty when
        ``has_torque``).
    """

    readings: dict
    time: np.ndarray
    dt: float
    valid: np.ndarray
    truth: np.ndarray | None
    truth_known: np.ndarray | None
    force: np.ndarray | None
    terms: tuple[str, ...]
    has_torque: bool
    notes: tuple[str, ...]
    velocity_from_position: tuple[int, ...] = ()
    acceleration_from_position: tuple[int, ...] = ()
    tau_columns: Mapping[int, str] = dataclasses.field(default_factory=dict)
    missing_torques: tuple[str, ...] = ()


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


# The longest reading period accepted, s (cli_args.MIN_RATE_HZ, which says why).
MAX_PERIOD = 1.0 / MIN_RATE_HZ


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
        again = ""
        if t[i] == t[i - 1]:
            # A single repeat is a duplicated row; times that repeat everywhere are times
            # stored too coarsely (float32 epoch seconds step by 128 s at 1.7e9 s).
            repeats = int(np.sum(step == 0))
            again = (
                f"; {repeats / len(step):.0%} of the rows repeat the time before them: times"
                " stored at too low a precision (float32 epoch seconds?): store them as"
                " float64, or relative to the first"
                if repeats >= 3 and repeats > 0.01 * len(step)
                else "; a repeated row (drop duplicates)?"
            )
        raise ValueError(
            f"{src}: column 'time' does not increase at row {i} (0-based): {float(t[i]):.9g} s"
            f" after {float(t[i - 1]):.9g} s{again}"
        )
    dt = float(np.median(step))
    if dt > MAX_PERIOD:
        raise ValueError(
            f"{src}: column 'time' steps by {dt:.6g} (median): time must be in seconds, at"
            f" least {1 / MAX_PERIOD:g} readings per second (milliseconds? divide by 1e3;"
            " nanoseconds, as ROS stamps? by 1e9)"
        )
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
    # The last sample at or before each grid point; a sample within rounding of a grid
    # point (t_0 + k dt drifts from the recorded times by ~1e-14 s) is that grid point's,
    # so a held column (contact) changes on the sample's row, not one row later.
    idx = np.searchsorted(t, grid + 1e-6 * dt, side="right") - 1
    idx = np.clip(idx, 0, len(t) - 1)
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
      names: recording name -> model name, for joints and feet whose names differ; a
        name mapped to ``""`` (or None) has its columns dropped (a joint the model lacks).
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
    names = {k: v or "" for k, v in (names or {}).items()}
    free, joints = model_joints(m, desc.base_body_id)
    model_names = {n for n, _ in joints} | set(desc.foot_names)
    for log_name, model_name in names.items():
        if model_name and model_name not in model_names:
            raise ValueError(
                f"names map: {log_name!r} -> {model_name!r}, but the model has no joint or foot"
                f" {model_name!r}; joints: {[n for n, _ in joints]}, feet: {list(desc.foot_names)}"
            )
    refuse_estimate_output(src, rec.columns)
    rec, lost_quat = _degenerate_quaternion_lost(rec, src)
    read_notes = list(rec.notes) + lost_quat
    rec, dt, notes = _check_time(rec, resample)
    notes = read_notes + notes
    cols = rec.columns
    t_len = len(cols[TIME])
    used: set[str] = {TIME}
    to_model = lambda n: names.get(n, n)  # noqa: E731
    by_model: dict[str, dict[str, str]] = {p: {} for p in JOINT_PREFIXES + TRUTH_PREFIXES}
    joint_names = {n for n, _ in joints}
    named = set()  # the recording's joint and foot names, before the names map
    dropped = []  # columns of names the map sends to "" (a joint or foot the model lacks)
    for col in cols:
        for prefix in JOINT_PREFIXES + TRUTH_PREFIXES:
            if col.startswith(prefix):
                named.add(col[len(prefix) :])
                target = to_model(col[len(prefix) :])
                if target == "":
                    dropped.append(col)
                    break
                valid = joint_names if prefix in JOINT_PREFIXES else set(desc.foot_names)
                if target not in valid:
                    what = "joint" if prefix in JOINT_PREFIXES else "foot"
                    raise ValueError(
                        f"{src}: column {col!r}: the model has no {what} {target!r}"
                        f"{' (through the names map)' if target != col[len(prefix) :] else ''};"
                        f" its {'feet' if what == 'foot' else 'joints'}: {sorted(valid)};"
                        f" map it to one (--names {col[len(prefix) :]}=<model {what}>) or drop"
                        f" it (--names {col[len(prefix) :]}=)"
                    )
                if (first := by_model[prefix].get(target)) is not None:
                    # The later column replaced the first without a word (a names map
                    # that sends an extra column onto a joint that has its own).
                    raise ValueError(
                        f"{src}: columns {first!r} and {col!r} both give {prefix}{target}"
                        " (through the names map): map one to another name, or drop it"
                        f" (--names {col[len(prefix) :]}=)"
                    )
                by_model[prefix][target] = col
    # A joint's entry must name a column (every joint has one): a typo would otherwise pass
    # unnoticed. A foot's may not: a recording without ground truth has no foot columns.
    unused = sorted(k for k, v in names.items() if k not in named and v not in desc.foot_names)
    if unused:
        raise ValueError(
            f"names map: {unused} name no column of {src} (its joints and feet: {sorted(named)})"
        )
    scale = math.pi / 180.0 if units == "deg" else 1.0
    qpos = np.zeros((t_len, m.nq))
    qvel = np.zeros((t_len, m.nv))
    qacc = np.zeros((t_len, m.nv))
    tau = np.zeros((t_len, m.nv))
    missing_tau, missing_qd = [], []
    tau_columns = {}
    dof_of = {}  # joint column -> the dof it reads (a lost one reaches that dof's feet only)
    vel_from_pos, acc_from_pos = [], []
    out_of_range = []  # (column, text) of joints read outside their range
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
        for prefix in ("q/", "qd/", "qdd/", "tau/"):
            if prefix in by_model and name in by_model[prefix]:
                dof_of[by_model[prefix][name]] = va
        if outside := outside_range(m, j, qpos[:, qa], name=name, hinge=hinge, units=units):
            out_of_range.append((col, outside))
        vcol, vcol_named = by_model["qd/"].get(name), False
        if vcol is None:
            qvel[:, va] = _backward_diff(qpos[:, qa], dt)
            missing_qd.append(name)
            vel_from_pos.append(va)
        else:
            qvel[:, va] = cols[vcol] * s
            used.add(vcol)
            if off := derivative_mismatch(qpos[:, qa], qvel[:, va], dt, "qd/", col, hinge):
                notes.append(f"WARNING column {vcol!r}: {off}")
                vcol_named = True  # its qdd/ is not judged against it
        acol = by_model["qdd/"].get(name)
        if acol is None:
            qacc[:, va] = _backward_diff(qvel[:, va], dt)
            if vcol is None:
                acc_from_pos.append(va)
        else:
            qacc[:, va] = cols[acol] * s
            used.add(acol)
            if (
                vcol
                and not vcol_named
                and (off := derivative_mismatch(qvel[:, va], qacc[:, va], dt, "qdd/", vcol, hinge))
            ):
                notes.append(f"WARNING column {acol!r}: {off}")
        tcol = by_model["tau/"].get(name)
        if tcol is None:
            missing_tau.append(name)
        else:
            tau[:, va] = cols[tcol]
            tau_columns[va] = tcol
            used.add(tcol)
            if beyond := torque_beyond_limit(m, j, tau[:, va]):
                text = beyond.removeprefix("WARNING ")
                notes.append(f"{'WARNING ' if text != beyond else ''}column {tcol!r}: {text}")
    notes.extend(range_warnings(out_of_range))
    if missing_qd:
        notes.append(f"joint velocities differentiated from positions: {missing_qd}")
    actuated = sorted(
        {n for n, j in joints if any(int(m.actuator_trnid[a, 0]) == j for a in range(m.nu))}
    )
    gone = [n for n in actuated if n in missing_tau]
    has_torque = not gone
    terms = ["dynamics", "diff_kinematics", "kinematics"]
    if not has_torque:
        terms.remove("dynamics")
        tau[:] = 0.0
        text = f"no joint torques for {gone}: the dynamics term is off (and the GM observer)"
        if len(gone) < len(actuated):
            # Some joints have theirs: a column named otherwise, more likely than a robot
            # without torque sensing on a few joints, and the whole term is lost for it.
            have = [f"tau/{n}" for n in actuated if n not in gone]
            text = (
                f"WARNING {text}, on every leg, though {len(have)} of the {len(actuated)}"
                f" actuated joints have a tau/ column ({', '.join(have[:3])}"
                f"{', ...' if len(have) > 3 else ''}): is the missing one named otherwise?"
            )
        notes.append(text)
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
        upside = upside_down(quat)
        if upside:
            notes.append(f"WARNING columns {list(BASE_QUAT)}: {upside}")
        angvel = np.stack([cols[c] for c in BASE["base_angvel"]], axis=1) * scale
        qvel[:, va + 3 : va + 6] = angvel
        # A wrong orientation also fails the checks that read it; they say so.
        after_quat = "; or a consequence of the base_quat warning above" if upside else ""
        if turned := angular_velocity_mismatch(quat, angvel, dt):
            notes.append(f"WARNING columns {list(BASE['base_angvel'])}: {turned}{after_quat}")
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
            if has["base_pos"]:
                body = velocity_in_base_frame(
                    qpos[:, qa : qa + 3], qvel[:, va : va + 3], qpos[:, qa + 3 : qa + 7], dt
                )
                if body:
                    notes.append(f"WARNING columns {list(BASE['base_linvel'])}: {body}{after_quat}")
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
                if key == "base_linacc" and (held := holds_gravity(qacc[:, sl])):
                    notes.append(f"WARNING columns {list(BASE[key])}: {held}")
            else:
                qacc[:, sl] = _backward_diff(qvel[:, sl], dt)
                acc_from_pos.extend(d for d in range(sl.start, sl.stop) if d in vel_from_pos)
    legs_twice = sorted({d for leg in desc.leg_dofs for d in leg} & set(acc_from_pos))
    if "dynamics" in terms and legs_twice:
        # A second difference of positions carries sqrt(6) sigma_q / dt^2 of noise (7800
        # rad/s^2 for 0.02 rad at 400 Hz), above any acceleration a leg makes; with it the
        # dynamics term only added its noise (the planar leg's sample: F1 0.014 with it,
        # 0.673 without; docs/own_robot.md).
        terms.remove("dynamics")
        dof_joint = {int(m.jnt_dofadr[j]): n for n, j in joints}
        named = [f"qd/{dof_joint[d]}" for d in legs_twice if d in dof_joint]
        n_leg = len({d for leg in desc.leg_dofs for d in leg})
        text = (
            "leg joint accelerations would be second differences of positions (no qd/ or"
            f" qdd/ columns for dofs {legs_twice}: {', '.join(named)}): the dynamics term is"
            " off"
        )
        if len(legs_twice) < n_leg:  # the others have theirs: one named otherwise?
            text = f"WARNING {text}, on every leg; the other leg joints have their qd/ column"
        notes.append(text)
    if not terms:
        raise ValueError(f"{src}: no measurement term can run on this recording")
    truth = truth_known = force = None
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
        flags = {f: cols[c] for f, c in by_model["contact/"].items()}
        source = [
            (cols[by_model["contact/"][f]], 0.5)
            if f in by_model["contact/"]
            else (cols[by_model["force/"][f]], force_threshold)
            for f in feet
        ]
        truth = np.stack([col > bound for col, bound in source], axis=1)[:, None]
        truth_known = np.stack([np.isfinite(col) for col, _ in source], axis=1)[:, None]
        if not truth_known.any():
            raise ValueError(
                f"{src}: the ground-truth columns hold no finite value; drop them to estimate"
                " without metrics"
            )
        if not truth_known.all():
            notes.append(
                "rows where a foot's ground truth is missing (left out of the metrics): "
                + stretches(~truth_known.all(axis=(1, 2)), cols[TIME])
            )
        # A foot with a contact/ column is scored on it; force/ is its truth otherwise.
        from_force = {f: cols[c] for f, c in by_model["force/"].items() if f not in flags}
        if from_force:
            # A sensor with an offset (a foot force sensor's raw reading) reads "contact" on
            # every row: what the threshold made of each column is said.
            line, warn = force_truth(from_force, force_threshold)
            notes.append(f"WARNING {line}" if warn else line)
        if flags:
            notes.append(f"ground truth from contact/ for {[f for f in feet if f in flags]}")
        both = {f: cols[c] for f, c in by_model["force/"].items() if f in flags}
        if disagree := truth_columns_disagree({f: flags[f] for f in both}, both, force_threshold):
            notes.append(f"WARNING {disagree}")
    # A leg joint's column that is never finite loses that leg's foot for good (each foot
    # reads its own leg's joints, docs/model.md "Inputs per step"); the others are estimated.
    never = [c for c in sorted(used) if not np.isfinite(cols[c]).any()]
    legs = [next((i for i, leg in enumerate(desc.leg_dofs) if dof_of.get(c) in leg), None)
            for c in never]  # fmt: skip
    some_feet = bool(never) and None not in legs and len(set(legs)) < len(desc.leg_dofs)
    if some_feet:
        lost = [desc.foot_names[i] for i in sorted(set(legs))]
        notes.append(
            f"WARNING columns {never} are never finite: foot {', '.join(lost)} has no estimate"
            " (valid False on every step, left out of the metrics); the other feet are estimated"
        )
    checked = sorted(set(used) - set(never) if some_feet else used)
    finite_cells = np.isfinite(np.stack([cols[c] for c in checked], axis=1))
    finite = np.all(finite_cells, axis=1)
    valid = finite & np.concatenate([[True], finite[:-1]])  # differences use the row before
    if not valid.any():
        never = [c for c in checked if not np.isfinite(cols[c]).any()]
        which = (
            f"never finite: {never[:5]}{' ...' if len(never) > 5 else ''}"
            if never
            else "NaN or inf in every row or in the row before it"
        )
        raise ValueError(
            f"recording {rec.source!r}: no row has every column the estimator reads finite,"
            f" and the row before it ({len(valid)} rows; {which})"
        )
    if not finite.all():
        lost = [c for c, ok in zip(checked, finite_cells.all(axis=0), strict=True) if not ok]
        notes.append(
            f"readings with NaN or inf: {stretches(~finite, cols[TIME])}, in"
            f" {lost[:5]}{' ...' if len(lost) > 5 else ''}"
        )
    if dropped:
        notes.append(f"columns dropped by the names map: {dropped}")
    ignored = [
        c for c in cols if c not in used and c not in dropped and not c.startswith(TRUTH_PREFIXES)
    ]
    if ignored:
        notes.append(f"columns not in the schema, ignored: {ignored}")
    f32 = lambda a: a[:, None, :]  # noqa: E731
    return Converted(
        readings={"qpos": f32(qpos), "qvel": f32(qvel), "qacc": f32(qacc), "tau": f32(tau)},
        time=np.asarray(cols[TIME]),
        dt=dt,
        valid=valid[:, None],
        truth=truth,
        truth_known=truth_known,
        force=force,
        terms=tuple(terms),
        has_torque=has_torque,
        notes=tuple(notes),
        velocity_from_position=tuple(sorted(vel_from_pos)),
        acceleration_from_position=tuple(sorted(acc_from_pos)),
        tau_columns=tau_columns,
        missing_torques=tuple(gone),
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


def _degenerate_quaternion_lost(rec: Recording, src: str) -> tuple[Recording, list[str]]:
    """``rec`` with the base quaternion's rows of no orientation
    (:func:`jax_contact.train.recording_checks.degenerate_quaternion`, e.g. all zeros) set
    to NaN, a lost reading, and the note naming them; a ValueError naming the columns if no
    row is left with an orientation."""
    cols = rec.columns
    if not all(q in cols for q in BASE_QUAT):
        return rec, []
    quat = np.stack([cols[q] for q in BASE_QUAT], axis=1)
    bad = degenerate_quaternion(quat)
    if not bad.any():
        return rec, []
    from jax_contact.export import MIN_QUATERNION_NORM

    what = f"a norm below {MIN_QUATERNION_NORM:g} (no orientation)"
    if not (np.all(np.isfinite(quat), axis=1) & ~bad).any():
        raise ValueError(
            f"{src}: columns {list(BASE_QUAT)} have {what} or NaN on every row: the base's"
            " orientation is a unit quaternion w, x, y, z (base -> world)"
        )
    out = dict(cols)
    for q in BASE_QUAT:
        out[q] = np.where(bad, np.nan, cols[q])
    note = f"columns {list(BASE_QUAT)} have {what}, read as lost: {stretches(bad, cols[TIME])}"
    return dataclasses.replace(rec, columns=out), [note]


def stretches(mask: np.ndarray, t: np.ndarray) -> str:
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
