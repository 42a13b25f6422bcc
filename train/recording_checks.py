"""Checks that a recording's readings follow the schema's conventions
(:mod:`jax_contact.train.recording`), each a warning that names the column and the likely
cause, never a refusal: a joint outside its range (degrees), a derivative column that does
not integrate to the column it derives from (sign, degrees), a base orientation upside down
(x, y, z, w order), a gyroscope rate about the wrong axes or in degrees, a base velocity in
the base frame, a base acceleration that holds gravity, force truth in contact on every
row (an offset sensor), and, on the estimator's output, torques that cannot hold the feet
up and truth columns that fit the estimates better in another foot order, or contact/ and
force/ truth that disagree. Each returns the warning's text or None (:func:`force_truth`
always says what it read); the measurements behind each bound are in docs/own_robot.md.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

# A joint's reading may leave its range by sensor noise and compliance; beyond this many
# rad (m) on more than this share of rows it is another unit or another joint.
RANGE_SLACK, RANGE_SHARE = 0.1, 0.05


# What a hinge read in radians beyond 2 pi adds to its range warning.
DEGREES_HINT = "; are they degrees? pass --units deg (names=..., units='deg' in Python)"


def outside_range(m, j: int, q: np.ndarray, *, name: str, hinge: bool, units: str) -> str | None:
    """A warning if ``q`` leaves limited joint ``j`` (``name``)'s range by more than
    :data:`RANGE_SLACK` on more than :data:`RANGE_SHARE` of its finite rows, else None; on
    a ``hinge`` read in radians that exceeds 2 pi it suggests degrees
    (:data:`DEGREES_HINT`)."""
    if not m.jnt_limited[j]:
        return None
    q = q[np.isfinite(q)]
    lo, hi = m.jnt_range[j]
    out = (q < lo - RANGE_SLACK) | (q > hi + RANGE_SLACK)
    if q.size == 0 or out.mean() <= RANGE_SHARE:
        return None
    largest = float(np.abs(q).max())
    hint = DEGREES_HINT if hinge and units == "rad" and largest > 2 * np.pi else ""
    return (
        f"outside the range of joint {name!r}, [{lo:.4g}, {hi:.4g}] {'rad' if hinge else 'm'}"
        f" on {out.mean():.0%} of rows (largest {largest:.4g}){hint}"
    )


def range_warnings(found: Sequence[tuple[str, str]]) -> list[str]:
    """The warning lines of ``found``, (column, :func:`outside_range`'s text) pairs in the
    joints' order: one line per column, and where more than one column suggests degrees the
    suggestion once, after them, naming them all (a recording in degrees read as radians
    put it on every leg joint's line, twelve times on a quadruped)."""
    hinted = [c for c, text in found if text.endswith(DEGREES_HINT)]
    if len(hinted) < 2:
        return [f"WARNING column {c!r}: {text}" for c, text in found]
    lines = [f"WARNING column {c!r}: {text.removesuffix(DEGREES_HINT)}" for c, text in found]
    return [
        *lines,
        f"WARNING columns {hinted}: beyond 2 pi, outside their joints' ranges"
        + DEGREES_HINT.replace("; are they", ": are they", 1),
    ]


def degenerate_quaternion(quat: np.ndarray) -> np.ndarray:
    """(...) bool: the quaternions of ``quat`` ((..., 4), w, x, y, z; a recording's (T, 4),
    a log's (T, E, 4)) whose norm is finite and below
    :data:`jax_contact.export.MIN_QUATERNION_NORM`: no orientation (a driver's zero fill),
    read as lost (NaN) like a dropped packet, by the offline replay and the exported
    estimator alike (docs/deploy.md)."""
    from jax_contact.export import MIN_QUATERNION_NORM

    norm = np.linalg.norm(quat, axis=-1)
    return np.isfinite(norm) & (norm < MIN_QUATERNION_NORM)


def lose_degenerate_quaternions(qpos: np.ndarray, mj_model) -> dict[int, np.ndarray]:
    """Sets to NaN, in ``qpos`` ((..., nq)) itself, every joint quaternion (the base's, a
    ball joint's) that :func:`degenerate_quaternion` finds: a lost reading, as the exported
    estimator reads it. Returns each such quaternion's ``qpos`` address -> its (...) mask,
    only those with one set (empty: none)."""
    from jax_contact.export import quaternion_slices

    lost = {}
    for a in quaternion_slices(mj_model):
        bad = degenerate_quaternion(qpos[..., a : a + 4])
        if bad.any():
            qpos[..., a : a + 4][bad] = np.nan
            lost[a] = bad
    return lost


# Above this share of rows with the base's z axis pointing down, a recording of a robot
# that stood or walked has its quaternion in another order or frame.
UPSIDE_DOWN_SHARE = 0.5


def upside_down(quat: np.ndarray) -> str | None:
    """A warning if the base's z axis points down on more than :data:`UPSIDE_DOWN_SHARE`
    of the finite rows of ``quat`` ((T, 4), w, x, y, z, base -> world), else None.

    The world z component of the base's z axis is ``R[2, 2] = 1 - 2 (x^2 + y^2)`` of the
    unit quaternion. An upright robot's quaternion written in x, y, z, w order (ROS,
    Eigen's ``coeffs()``, SciPy) into these columns reads as a half turn about a
    horizontal axis, ``R[2, 2]`` near -1; read back in that order, ``R[2, 2]`` is near
    +1, and the warning says so.
    """
    q = quat[np.all(np.isfinite(quat), axis=1)]
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    if len(q) == 0:
        return None
    down = 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2) < 0.0
    if down.mean() <= UPSIDE_DOWN_SHARE:
        return None
    # Columns (w, x, y, z) holding (x, y, z, w): the real x and y are columns w and x.
    swapped_up = 1.0 - 2.0 * (q[:, 0] ** 2 + q[:, 1] ** 2) > 0.0
    hint = (
        "; read as x, y, z, w it is upright on"
        f" {swapped_up.mean():.0%}: the columns look like x, y, z, w order (ROS, Eigen"
        " coeffs(), SciPy), write them as w, x, y, z"
        if swapped_up.mean() > UPSIDE_DOWN_SHARE
        else ""
    )
    return (
        f"the base's z axis points down on {down.mean():.0%} of rows (base -> world,"
        f" w, x, y, z){hint}; if the robot did not lie upside down, the orientation is"
        " wrong and so is every term that uses it"
    )


def _valid_quaternions(quat: np.ndarray) -> np.ndarray:
    """(T,) the rows of ``quat`` (T, 4) that hold a rotation: finite and not zero."""
    ok = np.all(np.isfinite(quat), axis=1)
    ok[ok] = np.linalg.norm(quat[ok], axis=1) > 1e-12
    return ok


def _rotation(quat: np.ndarray) -> Rotation:
    """SciPy rotations of unit-or-not quaternions (N, 4) in w, x, y, z order (SciPy's own
    is x, y, z, w)."""
    return Rotation.from_quat(quat[:, [1, 2, 3, 0]])


# The checks of a reading against its derivative compare changes over this window, s: at
# 400 Hz a 1 mm position noise is 0.6 m/s on one step's difference and 1.4 cm/s on a 0.1 s
# displacement (1.4 mm over it).
FRAME_WINDOW_S = 0.1


def window_changes(
    x: np.ndarray, rate: np.ndarray, dt: float, ok: np.ndarray | None = None, change=None
) -> tuple[np.ndarray, np.ndarray]:
    """``(change, integral)``, each (W, d): over every window of :data:`FRAME_WINDOW_S`
    whose rows are all finite (and ``ok``), the change of ``x`` (T, d) and the trapezoidal
    integral of its recorded derivative ``rate`` (T, d) over the same interval.

    ``change``: optional ``(x_start, x_end) -> (W, d)`` for a reading that does not change
    by subtraction (an orientation); default ``x_end - x_start``.
    """
    x, rate = x.reshape(len(x), -1), rate.reshape(len(rate), -1)
    good = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(rate), axis=1)
    if ok is not None:
        good &= ok
    n = max(1, round(FRAME_WINDOW_S / dt))
    if len(x) <= n:
        return np.zeros((0, rate.shape[1])), np.zeros((0, rate.shape[1]))
    bad_before = np.concatenate([[0], np.cumsum(~good)])  # bad rows among 0 .. k-1
    windows = bad_before[n + 1 :] - bad_before[: -n - 1] == 0  # rows k .. k+n all good
    x, rate = np.where(good[:, None], x, 0.0), np.where(good[:, None], rate, 0.0)
    steps = 0.5 * (rate[1:] + rate[:-1]) * dt  # over (t_{k-1}, t_k]
    travelled = np.concatenate([np.zeros((1, rate.shape[1])), np.cumsum(steps, axis=0)])
    start, end = x[:-n][windows], x[n:][windows]
    moved = end - start if change is None else change(start, end)
    return moved, (travelled[n:] - travelled[:-n])[windows]


# A recorded derivative whose integral follows its reading's change with a slope outside
# this range is another unit, sign or column; judged only where the integral moves by more
# than the second value (rad or m; rad/s or m/s for accelerations) at its RMS, or where
# the reading itself changes by more than the third: a derivative 57 times too small (a
# rate in rad/s read with --units deg) never moved its integral past the second, and went
# unnamed. The third is far above a reading's noise over the window (0.02 rad of position
# noise changes by 0.028 rad RMS; 0.3 rad/s of velocity noise by 0.42 rad/s).
SLOPE_RANGE, MOVES = (0.5, 2.0), {"qd/": 0.02, "qdd/": 0.5}
CHANGE_MOVES = {"qd/": 0.1, "qdd/": 2.0}


def _rms(x: np.ndarray) -> float:
    """The RMS over windows of a change (T,) or of a vector change's norm (T, 3)."""
    return float(np.sqrt(np.sum(x**2) / len(x)))


def _too_still(change: np.ndarray, integral: np.ndarray, kind: str) -> bool:
    """Whether neither a reading's change nor its derivative's integral moves enough to
    judge their slope (:data:`MOVES`, :data:`CHANGE_MOVES`), or too few windows."""
    return len(change) < 10 or (_rms(integral) < MOVES[kind] and _rms(change) < CHANGE_MOVES[kind])


def _looks_like_degrees(slope: float) -> bool:
    """A slope near 180 / pi = 57.3 or its inverse: one column in degrees, one in radians."""
    return 40 < abs(slope) < 80 or 1 / 80 < abs(slope) < 1 / 40


def derivative_mismatch(
    x: np.ndarray, rate: np.ndarray, dt: float, kind: str, of: str, hinge: bool
) -> str | None:
    """A warning if the recorded derivative ``rate`` (T,) does not integrate to the change
    of ``x`` (T,), column ``of``, over :data:`FRAME_WINDOW_S` windows (least-squares slope
    of the change on the integral outside :data:`SLOPE_RANGE`), else None; ``kind`` is
    ``"qd/"`` or ``"qdd/"``; ``hinge``: the joint turns (a factor of 57.3 is then named
    as degrees against radians)."""
    change, integral = window_changes(x, rate, dt)
    if _too_still(change, integral, kind):
        return None
    if not np.any(integral):
        return (
            f"over {FRAME_WINDOW_S:g} s windows {of!r} changes by {_rms(change):.3g} (RMS)"
            " while its derivative's column stays 0"
        )
    slope = float(np.sum(change * integral) / np.sum(integral**2))
    if SLOPE_RANGE[0] <= slope <= SLOPE_RANGE[1]:
        return None
    if slope < -SLOPE_RANGE[0]:
        hint = ": the opposite sign (a joint direction that differs between the columns)"
    elif hinge and _looks_like_degrees(slope):
        hint = ": a factor of about 57.3, degrees against radians"
    else:
        hint = ": another unit, or another joint's column"
    return (
        f"over {FRAME_WINDOW_S:g} s windows {of!r} changes by {slope:.3g} times its"
        f" integral (1 when they agree){hint}"
    )


def velocity_in_base_frame(
    pos: np.ndarray, vel: np.ndarray, quat: np.ndarray, dt: float
) -> str | None:
    """A warning if ``vel`` (T, 3) fits ``pos``'s displacements far better rotated from the
    base frame to the world (``quat`` (T, 4), base -> world) than as given, else None.

    Over each window of :data:`FRAME_WINDOW_S` the displacement of ``pos`` is compared
    with the trapezoidal integral of ``vel`` as given (the schema's world frame) and of
    ``vel`` rotated by the base's orientation (a state estimator's body-frame velocity, as
    ROS odometry's twist). Warns when the rotated integral's median error is under half
    the given one's and the given one's exceeds 2 cm (0.2 m/s over the window). The frames
    coincide only while the base heads along the world's x axis (then nothing is wrong),
    and a slow robot's displacement may be within the position noise: neither is named.
    """
    ok = _valid_quaternions(quat)
    rotation = _rotation(np.where(ok[:, None], quat, [1.0, 0.0, 0.0, 0.0]))  # identity if not

    def error(v):
        moved, integral = window_changes(pos, v, dt, ok)
        if len(moved) == 0:
            return 0.0
        return float(np.median(np.linalg.norm(moved - integral, axis=1)))

    as_given, rotated = error(vel), error(rotation.apply(np.where(np.isfinite(vel), vel, 0.0)))
    if not (rotated < 0.5 * as_given and as_given > 0.02):
        return None
    return (
        f"base_pos moves as base_linvel rotated by base_quat says (median error"
        f" {rotated * 100:.2g} cm per {FRAME_WINDOW_S:g} s), not as base_linvel says"
        f" ({as_given * 100:.2g} cm): it looks like the base frame (e.g. ROS odometry's"
        " twist); the schema wants the world frame: rotate it by the base's orientation"
        " or drop the base_linvel columns (then differenced from base_pos)"
    )


def angular_velocity_mismatch(quat: np.ndarray, angvel: np.ndarray, dt: float) -> str | None:
    """A warning if ``angvel`` (T, 3) does not integrate to the turns of ``quat`` (T, 4,
    base -> world) in the base frame, else None.

    Over each :data:`FRAME_WINDOW_S` window the base's turn in its own frame, the rotation
    vector of ``q_k^-1 q_{k+n}``, should equal the integral of the gyroscope's rate (the
    schema's base frame). Named: a least-squares slope of the turn on the integral outside
    :data:`SLOPE_RANGE` (degrees per second, a sign), or a world-frame rate (the turn
    ``q_{k+n} q_k^-1``, world axes, fits with under half the error). Judged only where the
    integral's RMS exceeds 0.02 rad (0.2 rad/s) or the turn's 0.1 rad
    (:data:`CHANGE_MOVES`).
    """
    ok = _valid_quaternions(quat)

    def body(q0, q1):  # q_k^-1 q_{k+n}: the turn about the base's own axes
        return (_rotation(q0).inv() * _rotation(q1)).as_rotvec()

    def world(q0, q1):  # q_{k+n} q_k^-1: the same turn about the world's axes
        return (_rotation(q1) * _rotation(q0).inv()).as_rotvec()

    turn, integral = window_changes(quat, angvel, dt, ok, change=body)
    if _too_still(turn, integral, "qd/"):  # a rate 57 times too small is judged too
        return None
    if not np.any(integral):
        return (
            f"over {FRAME_WINDOW_S:g} s windows the base turns (RMS {_rms(turn):.3g} rad)"
            " while base_angvel stays 0"
        )
    slope = float(np.sum(turn * integral) / np.sum(integral**2))
    if not SLOPE_RANGE[0] <= slope <= SLOPE_RANGE[1]:
        hint = (
            ": degrees per second against radians? convert base_angvel to rad/s (--units deg"
            " would read every angle and rate in degrees, the joints' too)"
            if _looks_like_degrees(slope)
            else ": another unit, sign, axis order or frame (the schema's is the base's,"
            " a gyroscope's)"
        )
        return (
            f"over {FRAME_WINDOW_S:g} s windows the base turns by {slope:.3g} times the"
            f" integral of base_angvel (1 when they agree){hint}"
        )
    turn_world, _ = window_changes(quat, angvel, dt, ok, change=world)
    in_body = float(np.median(np.linalg.norm(turn - integral, axis=1)))
    in_world = float(np.median(np.linalg.norm(turn_world - integral, axis=1)))
    if in_world < 0.5 * in_body and in_body > 0.005:
        return (
            f"base_quat turns as base_angvel says about world axes (median error"
            f" {in_world:.2g} rad per {FRAME_WINDOW_S:g} s), not about the base's own"
            f" ({in_body:.2g} rad): the schema wants the base frame (a gyroscope's reading)"
        )
    return None


# A recording's mean vertical acceleration in the world is ~0 (the robot stays on the
# floor); within this of 9.81 m/s^2 it holds gravity, as an accelerometer's reading does.
GRAVITY_SLACK = 2.0


def holds_gravity(acc: np.ndarray) -> str | None:
    """A warning if the mean of ``acc`` (T, 3)'s z column is within
    :data:`GRAVITY_SLACK` of +-9.81 m/s^2, else None."""
    z = acc[:, 2][np.isfinite(acc[:, 2])]
    if z.size == 0 or abs(abs(float(z.mean())) - 9.81) > GRAVITY_SLACK:
        return None
    return (
        f"base_linacc/z averages {z.mean():.3g} m/s^2 over the recording, where a robot"
        " that stays on the floor averages ~0: it looks like an accelerometer's reading"
        " (gravity included, perhaps in the base frame); the schema wants the world-frame"
        " acceleration without gravity (R f + g for an IMU's specific force f, g = (0, 0,"
        " -9.81)), or drop the base_linacc columns (then differenced from base_linvel)"
    )


# A foot whose dynamics term reads air on more than this share of the steps where the
# differential-kinematics term reads it still (at least MIN_STILL_STEPS of them) is not
# held up by its torques. Measured (docs/own_robot.md): 0.10-0.37 per foot with the
# recorded torques, 0.88-0.97 with their signs flipped, on Go1, Spot and Barkour trotting
# and walking and the planar leg; a 3.4 kg hexapod, whose loads are near anymal_like's
# torque noise, 0.63-0.77 with its own torques.
DYNAMICS_AIR_WHEN_STILL, MIN_STILL_STEPS = 0.8, 40


# A leg whose joints see a vertical force at the foot through less than this share of the
# lever a horizontal one has is nearly straight: its torques cannot show the foot's load.
# Measured by hand: a user's biped standing straight on flat soles 3 cm ahead of its
# ankles, 0.07 (its estimate read air, P 0.004, under 95 N of true load); bent knees, 0.5.
STRAIGHT_LEG_RATIO = 0.15


def straight_legs(mj_model, desc, qpos: np.ndarray, still: np.ndarray) -> dict[str, float]:
    """Feet whose leg is nearly straight where they stand still, with their ratio.

    For each foot with :data:`MIN_STILL_STEPS` still steps, at the ``qpos`` of its middle
    still step: the foot point's translational Jacobian over its leg's joints (C MuJoCo,
    ``mj_jac``), and the ratio of its vertical row's norm (the joint torques per newton
    of vertical force, m) to its largest row's. Below :data:`STRAIGHT_LEG_RATIO` the
    dynamics term cannot read the foot's load, whatever the torques' sign or unit.

    Args:
      mj_model: the robot's model.
      desc: its description (feet, bodies, points and legs).
      qpos: (T, nq) the recording's positions.
      still: (T, L) the steps each foot stands still.
    """
    import mujoco

    d = mujoco.MjData(mj_model)
    out = {}
    for i, name in enumerate(desc.foot_names):
        steps = np.flatnonzero(still[:, i])
        if len(steps) < MIN_STILL_STEPS:
            continue
        middle = qpos[steps[len(steps) // 2]]
        if not np.isfinite(middle).all():
            continue
        d.qpos[:] = middle
        mujoco.mj_kinematics(mj_model, d)
        mujoco.mj_comPos(mj_model, d)
        body = desc.foot_body_ids[i]
        point = d.xpos[body] + d.xmat[body].reshape(3, 3) @ np.asarray(desc.foot_offsets[i])
        jacp = np.zeros((3, mj_model.nv))
        mujoco.mj_jac(mj_model, d, jacp, None, point, body)
        rows = np.linalg.norm(jacp[:, list(desc.leg_dofs[i])], axis=1)
        if rows.max() > 0 and rows[2] / rows.max() < STRAIGHT_LEG_RATIO:
            out[name] = float(rows[2] / rows.max())
    return out


def dynamics_disagrees(
    p_dynamics: np.ndarray,
    p_diff_kinematics: np.ndarray,
    valid: np.ndarray,
    foot_names: Sequence[str],
    foot_columns: Sequence[Sequence[str]] | None = None,
    push: np.ndarray | None = None,
    straight: dict[str, float] | None = None,
) -> str | None:
    """A warning naming the feet whose torques look wrong, and their torque columns, else None.

    A foot that stands still (the differential-kinematics term above 0.5) is usually
    loaded, and the dynamics term then reads contact; torques of the wrong sign (a joint
    axis opposite the model's, a motor current's convention) or scale (amperes, the motor
    side of a gearbox) cannot push the foot into the ground, and it reads air on nearly
    every such step. Where the dynamics term runs without its sign test (a light robot's,
    ``jax_contact.envs.contact_params.choose_unilateral``) it cannot tell a pull from a
    push, so the estimated push itself is read too: a foot whose median ``push`` over its
    still steps is negative pulls on the ground (its torques' sign), whatever the term
    says. Steps with ``valid`` False are left out. The term is one per leg, so it cannot
    say which of a leg's joints is wrong: the message lists them all.

    Args:
      p_dynamics, p_diff_kinematics: (T, L) each term's probability of contact.
      valid: (T, L) the estimator's per-leg validity.
      foot_names: (L,) names for the message.
      foot_columns: (L,) per foot, the recording's ``tau/`` columns of its leg's joints
        (listed after the foot's name), or None.
      push: (T, L) the estimated vertical push of each foot on the ground under the
        contact hypothesis (N; ``-force[..., 2]`` of the diagnostics), or None to judge by
        the dynamics term alone.
      straight: :func:`straight_legs`'s feet: those of them named here are told so first
        (a straight leg reads air whatever its torques, which are then not the likely
        cause).
    """
    still = (p_diff_kinematics > 0.5) & valid.astype(bool)
    n_still = still.sum(axis=0)
    share = ((p_dynamics < 0.5) & still).sum(axis=0) / np.maximum(n_still, 1)
    columns = foot_columns if foot_columns is not None else [()] * len(foot_names)
    push = None if push is None else np.asarray(push)
    bad, flagged = [], []
    for i, (name, s, n, cols) in enumerate(zip(foot_names, share, n_still, columns, strict=True)):
        if n < MIN_STILL_STEPS:
            continue
        median = None if push is None else float(np.median(push[still[:, i], i]))
        if s > DYNAMICS_AIR_WHEN_STILL or (median is not None and median < 0.0):
            told = (
                f"{name} {s:.0%}"
                if median is None
                else f"{name} {s:.0%} air, median push {median:.3g} N"
            )
            bad.append(told + (f" [{', '.join(cols)}]" if cols else ""))
            flagged.append(name)
    if not bad:
        return None
    # The other feet that read air on more than half their still steps (0.10-0.37 with a
    # recording's own torques): a scale error (the motor side of a gearbox) reaches every
    # leg, and naming one foot sent a user to that leg's columns alone.
    also = [
        f"{name} {s:.0%}"
        for name, s, n in zip(foot_names, share, n_still, strict=True)
        if name not in flagged and n >= MIN_STILL_STEPS and s > 0.5
    ]
    if also:
        bad.append("also above half: " + ", ".join(also))
    nearly = {n: r for n, r in (straight or {}).items() if n in flagged}
    first = (
        "legs nearly straight where their feet stand still ("
        + ", ".join(
            f"{n}: a vertical force turns its joints {r:.0%} as much as a horizontal one"
            for n, r in nearly.items()
        )
        + "): their joint torques cannot show the feet's load, so the dynamics term reads"
        " air however the feet are loaded (a point-contact model's limit on a straight"
        " knee; bent knees read it); otherwise, "
        if nearly
        else ""
    )
    own = (
        "it is well under half"
        if push is None
        else "the term reads air on well under half and the push is positive"
    )
    return (
        first
        + "the dynamics term reads air on most steps where the foot stands still"
        + ("" if push is None else ", or the foot pulls on the ground there")
        + " ("
        + "; ".join(bad)
        + f"; with a recording's own torques {own}): check those tau/ columns'"
        " sign (positive along the model's joint axis, as MuJoCo's qfrc_actuator) and unit"
        " (N m at the joint, not amperes or the motor side of a gearbox); on a light robot"
        " the sensor model's torque noise may swamp its loads (jax-contact tune)"
    )


# Another order of the truth columns is named when it agrees with the estimates on this much
# more of the steps (mean over the feet) than the recording's own order. Measured on a
# simulated Go1 trot written as a recording (4 s, seed 1000, docs/own_robot.md): own order
# 0.97 (F1 0.974); the front feet's truth columns swapped, 0.56 against 0.97 in the order
# that undoes it (F1 0.625); the front legs' joint columns swapped, 0.55 against 0.97; the
# diagonal partners' truth swapped (the same pattern in a trot, F1 0.958): not named.
ORDER_MARGIN = 0.1
# ... and only an order that itself agrees on this share of the steps: a swap undone agrees
# as a right recording does (0.97 above), while estimates that fit no order (every tau/
# negated: F1 0.008, the best order 0.52 against the own 0.30; a new user's trial) say
# nothing about the columns' order.
MIN_ORDER_AGREEMENT = 0.8
# Fewer scored steps than this per pair of feet: no comparison.
MIN_ORDER_STEPS = 200


def truth_order(
    p: np.ndarray, truth: np.ndarray, scored: np.ndarray, foot_names: Sequence[str]
) -> str | None:
    """A warning if the truth columns agree with the estimates better in another foot order.

    A names map that gives two feet each other's columns (truth, or a leg's joints) passes
    every check of the readings; in a gait whose feet are not all in phase each of those
    feet's estimates then follows the other foot's truth. Every assignment of the truth
    columns to the feet (up to 6 feet: 720) is scored by the share of steps where
    ``p > 0.5`` equals the column, averaged over the feet; the best one is named when it
    beats the recording's own order by more than :data:`ORDER_MARGIN` and agrees on at
    least :data:`MIN_ORDER_AGREEMENT` of the steps itself.

    Args:
      p: (T, L) the estimator's P(contact).
      truth: (T, L) bool ground truth, as the recording's columns give it.
      scored: (T, L) bool, the steps that count (valid, truth known).
      foot_names: (L,) names for the message.
    """
    n = len(foot_names)
    if not 2 <= n <= 6:
        return None
    est, truth, scored = p > 0.5, np.asarray(truth, bool), np.asarray(scored, bool)
    agree = np.zeros((n, n))  # agree[i, j]: foot i's estimate against column j
    for i, j in itertools.product(range(n), repeat=2):
        both = scored[:, i] & scored[:, j]
        if both.sum() < MIN_ORDER_STEPS:
            return None
        agree[i, j] = np.mean(est[both, i] == truth[both, j])
    own = float(np.mean(np.diag(agree)))
    best = max(itertools.permutations(range(n)), key=lambda o: agree[range(n), o].sum())
    better = float(np.mean(agree[range(n), best]))
    if better - own <= ORDER_MARGIN or better < MIN_ORDER_AGREEMENT:
        return None
    moved = [
        f"{foot_names[i]}'s estimate agrees with the column given as {foot_names[j]}'s on"
        f" {agree[i, j]:.0%} of steps, with its own on {agree[i, i]:.0%}"
        for i, j in enumerate(best)
        if j != i
    ]
    return (
        f"WARNING the truth columns fit the estimates better in another foot order ({better:.0%}"
        f" of steps agree against {own:.0%}): "
        + "; ".join(moved)
        + ". Check the names map (--names) and which foot each contact/ or force/ column,"
        " and each leg's q/, qd/ and tau/ columns, belong to"
    )


# A force/ truth column above the threshold on at least this share of rows, on every foot,
# is warned about (a walking robot lifts each foot; an offset sensor never reads below).
ALWAYS_LOADED = 0.995


def force_truth(forces: dict[str, np.ndarray], threshold: float) -> tuple[str, bool]:
    """What ``threshold`` (N) makes of each foot's ``force/`` truth column (foot -> (T,)):
    ``(text, warn)``, the share of rows in contact and the minimum force per foot (with the
    sensor-offset advice when a foot is in contact on at least :data:`ALWAYS_LOADED` of
    its rows), and whether every foot is (a robot that stood throughout, or sensors whose
    air reading is above the threshold: the metrics then mean nothing)."""
    read = {
        f: (np.mean(col[np.isfinite(col)] > threshold), np.nanmin(col))
        for f, col in forces.items()
        if np.isfinite(col).any()
    }
    shares = ", ".join(f"{f} {s:.0%} (min {low:.3g} N)" for f, (s, low) in read.items())
    text = f"ground truth from force/ above {threshold:g} N: contact on {shares}"
    if any(s >= ALWAYS_LOADED for s, _ in read.values()):  # the advice where it may apply
        text += (
            "; a foot that left the ground but reads contact on every row has a sensor"
            " offset (--force-threshold)"
        )
    warn = all(s >= ALWAYS_LOADED for s, _ in read.values())
    return (text + "; if it stood throughout, ignore this" if warn else text), warn


# A foot's contact/ and force/ columns (above --force-threshold) that disagree on more than
# this share of the rows where both are finite are named: on a simulated Go1 trot written
# as a recording (force/ the normal force, contact/ the simulator's flag) they agree on
# every row; a contact/ column of another foot, or of another convention, disagrees on a
# third to two thirds of them.
TRUTH_DISAGREE_SHARE = 0.05


def truth_columns_disagree(
    contact: dict[str, np.ndarray], forces: dict[str, np.ndarray], threshold: float
) -> str | None:
    """A warning naming the feet whose ``contact/`` and ``force/`` truth columns disagree.

    A foot with both is scored on ``contact/`` (the recording's own flag); a ``force/``
    column that says otherwise on more than :data:`TRUTH_DISAGREE_SHARE` of the rows means
    one of them is not what it says, and the metrics follow the flag.

    Args:
      contact, forces: foot -> (T,) column, for the feet that have both.
      threshold: N, what ``force/`` must exceed to read contact.
    """
    bad = []
    for foot, flag in contact.items():
        force = forces[foot]
        both = np.isfinite(flag) & np.isfinite(force)
        if not both.any():
            continue
        share = float(np.mean((flag[both] > 0.5) != (force[both] > threshold)))
        if share > TRUTH_DISAGREE_SHARE:
            bad.append(f"{foot} on {share:.0%} of the rows")
    if not bad:
        return None
    return (
        f"contact/ and force/ (above {threshold:g} N) disagree: {', '.join(bad)}; the metrics"
        " score contact/ (a foot's flag is preferred to its force): check which column is"
        " right, or drop contact/ to score force/"
    )


# A standing foot's sole is at the floor, so the lowest tenth of a foot's sole heights over
# a recording (its stance) is near z = 0 when the plane the estimator assumes is the floor:
# a base estimate's drift over a minute is a few cm. Beyond this, m, it is not.
FLOOR_OFFSET_M = 0.05
FLOOR_ROWS = 500  # rows sampled (evenly) for the soles' heights
# The soles' lowest heights moving by more than this from the first to the last fifth of a
# recording is a note (floor_offset): a base_pos that drifts (a Go1 trot simulated for 30 s
# with anymal_like's drift moves them 4.6 cm; its plane left 11 touch-downs missed that
# --terrain-model memory found) or ground that is not flat.
FLOOR_DRIFT_M = 0.03


def plane_floor_note(robot, qpos: np.ndarray, terms, terrain_model: str) -> str | None:
    """:func:`floor_offset`'s warning where it applies: the kinematics term runs
    (``terms``) on the plane at z = 0 (``terrain_model`` ``"flat"``); ``robot`` the
    :class:`jax_contact.envs.robots.Robot`, ``qpos`` (T, nq). What ``estimate`` and
    ``tune`` on recordings check."""
    if "kinematics" not in terms or terrain_model != "flat":
        return None
    return floor_offset(robot.mj_model, robot.description, qpos)


def floor_offset(mj_model, desc, qpos: np.ndarray) -> str | None:
    """The warning when the feet's soles, at their lowest (the lowest tenth of the rows,
    median over the feet), sit more than :data:`FLOOR_OFFSET_M` above or below z = 0: the
    floor of ``base_pos``'s frame is elsewhere, or the model is not the recorded robot.
    Either way the kinematics term, which assumes a plane at z = 0, reads nonsense without
    a word (a sole far below the plane is neutral, far above is air). Else a note when
    that height, taken over the first and over the last fifth of the rows, moves by more
    than :data:`FLOOR_DRIFT_M`: the plane fits part of the recording only.

    Args:
      mj_model: the robot's ``mujoco.MjModel``.
      desc: its :class:`jax_contact.robot.RobotDescription` (the feet).
      qpos: (T, nq) the readings' positions.
    """
    import mujoco

    q = np.asarray(qpos, np.float64)
    rows = np.flatnonzero(np.all(np.isfinite(q), axis=1))
    if rows.size == 0:
        return None
    rows = rows[np.linspace(0, rows.size - 1, min(rows.size, FLOOR_ROWS)).astype(int)]
    data = mujoco.MjData(mj_model)
    soles = np.empty((rows.size, desc.n_legs))
    for k, r in enumerate(rows):
        data.qpos[:] = q[r]
        mujoco.mj_kinematics(mj_model, data)
        for i, b in enumerate(desc.foot_body_ids):  # a sphere's lowest point, a sole's centre
            rot_z = data.xmat[b].reshape(3, 3)[2]
            soles[k, i] = data.xpos[b, 2] + rot_z @ desc.foot_offsets[i] - desc.foot_radii[i]
    lowest = np.quantile(soles, 0.1, axis=0)
    offset = float(np.median(lowest))
    if abs(offset) <= FLOOR_OFFSET_M:
        return floor_drift(soles)
    where = "below" if offset < 0 else "above"
    per_foot = ", ".join(
        f"{f} {z * 100:+.0f}" for f, z in zip(desc.foot_names, lowest, strict=True)
    )
    return (
        f"WARNING the feet's soles sit {abs(offset) * 100:.0f} cm {where} z = 0 at their lowest"
        f" (the lowest tenth of the rows, cm: {per_foot}), where a standing foot's sole is on"
        " the floor: the floor of base_pos's frame is not at z = 0 (--terrain-model memory"
        " reads the ground under each foot), or --model is not the robot that was recorded"
    )


def floor_drift(soles: np.ndarray) -> str | None:
    """:func:`floor_offset`'s note on ``soles`` (rows, feet) sole heights, m, in time order:
    the lowest tenth's median over the feet in the first and the last fifth of the rows,
    when they differ by more than :data:`FLOOR_DRIFT_M` (None for fewer than 50 rows)."""
    n = len(soles) // 5
    if n < 10:
        return None
    first, last = (float(np.median(np.quantile(x, 0.1, axis=0))) for x in (soles[:n], soles[-n:]))
    if abs(last - first) <= FLOOR_DRIFT_M:
        return None
    return (
        f"the feet's soles, at their lowest, move by {(last - first) * 100:+.1f} cm from the"
        f" first to the last fifth of the recording ({first * 100:+.1f} -> {last * 100:+.1f}"
        " cm from z = 0): base_pos drifts, or the ground is not flat; the estimator's plane"
        " at z = 0 fits part of it only (--terrain-model memory reads the ground under each"
        " foot where it last stood)"
    )


# A joint torque beyond this multiple of what the model's actuators can apply is no motor's:
# a glitch on a few rows, another unit or sensor on many (RANGE_SHARE of the rows).
TORQUE_SLACK = 2.0


def joint_torque_limit(m, j: int) -> float | None:
    """The largest generalised force the model's actuators put on joint ``j`` (N m, or N
    for a slide): the joint's ``actuatorfrcrange`` if limited, else the sum over the
    actuators on it of ``gear`` times their ``forcerange`` (force-limited) or, for a motor
    (fixed gain, no bias), ``ctrlrange`` times its gain; None when an actuator on it has no
    such bound (a servo whose force follows the state) or none acts on it."""
    import mujoco

    if m.jnt_actfrclimited[j]:
        return float(np.max(np.abs(m.jnt_actfrcrange[j])))
    total, found = 0.0, False
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or m.actuator_trnid[a, 0] != j:
            continue
        gear = abs(float(m.actuator_gear[a, 0]))
        if m.actuator_forcelimited[a]:
            total += gear * float(np.max(np.abs(m.actuator_forcerange[a])))
        elif (
            m.actuator_ctrllimited[a]
            and m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
            and m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
        ):
            gain = abs(float(m.actuator_gainprm[a, 0]))
            total += gear * gain * float(np.max(np.abs(m.actuator_ctrlrange[a])))
        else:
            return None
        found = True
    return total if found and total > 0 else None


def torque_beyond_limit(m, j: int, tau: np.ndarray) -> str | None:
    """The note (a WARNING on more than :data:`RANGE_SHARE` of the rows) when the joint
    torque ``tau`` (T,) of joint ``j`` exceeds :data:`TORQUE_SLACK` times
    :func:`joint_torque_limit` on any finite row, else None."""
    limit = joint_torque_limit(m, j)
    finite = np.isfinite(tau)
    if limit is None or not finite.any():
        return None
    beyond = finite & (np.abs(np.where(finite, tau, 0.0)) > TORQUE_SLACK * limit)
    n = int(beyond.sum())
    if n == 0:
        return None
    many = n / int(finite.sum()) > RANGE_SHARE
    cause = "another unit or sensor?" if many else "a glitch (the estimator bounds its effect)"
    return (
        f"{'WARNING ' if many else ''}beyond {TORQUE_SLACK:g} x the model's actuator limit of"
        f" its joint ({limit:.4g}) on {n} row(s) (first at row {int(np.argmax(beyond))},"
        f" 0-based; largest {float(np.max(np.abs(tau[beyond]))):.4g}): {cause}"
    )
