"""Scripted gaits: periodic foot trajectories, per-leg inverse kinematics and joint PD.

No trained policy: a clock drives every leg through stance and swing, and a joint-space PD
controller with a weight-bearing feed-forward tracks the resulting foot targets. It is good
enough to produce long, varied runs of touch-downs and lift-offs for the contact estimator
on flat ground, and nothing more (no terrain perception, no turning).

Gaits (``GaitParams.kind``; the trot and the walk differ only in data, the leg phase
offsets and the sway, so one compiled program runs both; the hop is a program of its own):

- ``trot``: diagonal pairs (front-left with hind-right, front-right with hind-left) half a
  period apart; on other leg counts, legs alternating along each side and across (a
  hexapod's tripods; :func:`jax_contact.envs.gait_robot.leg_phase_offsets`).
- ``walk``: a static lateral-sequence walk, one foot at a time (hind-left, front-left,
  hind-right, front-right, a quarter period apart; on other leg counts one leg after
  another in the feet's order, ``1 / n_legs`` apart) with ``duty >= 0.75``; the body sways
  sideways, away from the side whose feet swing (``sway``), so that the centre of mass
  leaves the diagonal of the two feet beside the lifted one.
- ``hop``: one leg (the planar leg of the paper's Section III on its vertical rail): the
  base is driven down and up through the stance so that it leaves the ground with the
  speed of a ballistic flight of ``(1 - duty) * period``; in the flight the leg retracts
  by ``step_height`` and extends again before landing.

Per leg and control step (:func:`gait_control`, unbatched, ``jax.vmap`` over envs):

1. the leg's phase ``(t / period + offset) mod 1``: stance below ``duty``, swing above;
2. a foot target in the base frame: in stance the foot moves back by ``speed *
   stance_time`` (which carries the body forward); in swing it moves forward along a
   smooth curve, ``step_height`` up at mid-swing, to a touch-down point corrected by
   Raibert's heuristic ``k_v * (v - v_cmd)`` (velocity in the heading frame); the walk's
   sway shifts every target; stance feet at a fixed depth below the hips keep the body
   parallel to the floor;
3. joint targets from a few damped Gauss-Newton steps on the leg's forward kinematics,
   which are built from the MuJoCo model's kinematic tree (any chain of hinges: Go1, Spot,
   Barkour's tilted axes, the planar leg), and joint velocity targets from the foot
   target's time derivative;
4. joint torques ``kp (q* - q) + kd (qd* - qd) - J^T f`` with ``f`` the stance feet's share
   of the body weight (plus the hop's base acceleration), converted to ``ctrl`` by
   inverting each actuator's affine force law, so position servos (Go1, Spot, Barkour)
   and torque motors (planar leg) are driven alike.

The controller reads the *true* state (``qpos``, ``qvel``): it is the simulator's script,
not a consumer of the estimator.

Modules: this one holds the gait commands (:class:`GaitParams`), the foot trajectories and
the controller; the per-robot settings (standing pose, gains, the settle) are in
:mod:`jax_contact.envs.gait_settings`, the robot constants and leg kinematics in
:mod:`jax_contact.envs.gait_robot` (their public names are re-exported here).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from mujoco import mjx

# The settings and the leg kinematics live in their own modules; their public names are
# re-exported here, where the gaits' users have always found them.
from jax_contact.envs.gait_robot import (
    GaitRobot,
    damped_least_squares,
    leg_fk,
    leg_ik,
    make_gait_robot,
)
from jax_contact.envs.gait_settings import (
    GAIT_SETTINGS,
    GRAVITY,
    KINDS,
    SETTLE_S,
    GaitSettings,
    gait_settings,
    resolve_gait_settings,
    settle,
)

__all__ = [
    "GAIT_SETTINGS",
    "GRAVITY",
    "KINDS",
    "SETTLE_S",
    "GaitParams",
    "GaitRobot",
    "GaitSettings",
    "foot_targets",
    "gait_control",
    "gait_settings",
    "leg_fk",
    "leg_ik",
    "leg_phases",
    "make_gait",
    "make_gait_robot",
    "qpos_of_dof",
    "resolve_gait_settings",
    "settle",
    "torque_to_ctrl",
]


@struct.dataclass
class GaitParams:
    """One gait command. Leaves may differ per environment (``vmap`` over them).

    Attributes:
      period: () gait cycle duration, s.
      duty: () fraction of the cycle each foot is on the ground, in (0, 1).
      step_height: () apex of the swing above the stance height (hop: the leg's
        retraction in flight), m.
      speed: () forward speed command, m/s (unused by ``hop``).
      sway: () walk only: sideways excursion of the zero-moment point at the lift-offs,
        as a fraction of the stance half-width (see ``_walk_sway``), in [0, 1].
      ramp_time: () time over which speed, step height and sway rise from zero, s.
      pattern: () int32, the gait's index in :data:`KINDS`: which row of
        ``GaitRobot.phase_offset`` sets the legs' phases, and whether the walk's sway
        applies. Data, not a static field, so that the trot and the walk share one
        compiled program (``jit`` retraces on every static field's value).
      family: static, ``"hop"`` for the one-legged hop (other foot targets, other
        forces) and ``"legged"`` for the trot and the walk.

    The gait's name is :attr:`kind`, read from ``pattern`` (outside ``jit``).
    """

    period: jax.Array
    duty: jax.Array
    step_height: jax.Array
    speed: jax.Array
    sway: jax.Array
    ramp_time: jax.Array
    pattern: jax.Array
    family: str = struct.field(pytree_node=False, default="legged")

    @property
    def kind(self) -> str:
        """The gait's name (one of :data:`KINDS`; ``"mixed"`` for a batch of several).

        Reads ``pattern``'s value, so it is for host code (logs, speed ranges), not for a
        traced function (there: ``family`` and ``pattern``).
        """
        if self.family == "hop":
            return "hop"
        found = np.unique(np.asarray(self.pattern))
        return KINDS[int(found[0])] if found.size == 1 else "mixed"


def make_gait(
    kind: str,
    *,
    period: float | None = None,
    duty: float | None = None,
    step_height: float | None = None,
    speed: float = 0.0,
    sway: float | None = None,
    ramp_time: float = 1.0,
) -> GaitParams:
    """Builds a validated :class:`GaitParams`; unset values take the kind's defaults.

    Defaults: trot period 0.5 s, duty 0.6, step height 0.06 m; walk period 1.2 s, duty
    0.85 (0.12 s of four-foot support between swings), step height 0.06 m, sway 0.35
    (about 0.6 rocked Spot onto two feet, about 0.9 flipped Go1); hop period 0.6 s, duty 0.75
    (0.15 s of flight), retraction 0.05 m.

    Raises:
      ValueError: naming the argument, for an unknown ``kind`` (lists :data:`KINDS`), a
        non-positive period, a duty outside (0, 1) (a walk needs ``duty >= 0.75`` so that
        at most one foot swings), a negative step height, ramp time or sway outside [0, 1].
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    defaults = {
        "trot": dict(period=0.5, duty=0.6, step_height=0.06, sway=0.0),
        "walk": dict(period=1.2, duty=0.85, step_height=0.06, sway=0.35),
        "hop": dict(period=0.6, duty=0.75, step_height=0.05, sway=0.0),
    }[kind]
    period = defaults["period"] if period is None else period
    duty = defaults["duty"] if duty is None else duty
    step_height = defaults["step_height"] if step_height is None else step_height
    sway = defaults["sway"] if sway is None else sway
    if not (np.isfinite(period) and period > 0):
        raise ValueError(f"period must be a finite float > 0 (s), got {period!r}")
    if not (0.0 < duty < 1.0):
        raise ValueError(f"duty must lie in (0, 1), got {duty!r}")
    if kind == "walk" and duty < 0.75:
        raise ValueError(f"duty must be >= 0.75 for kind='walk' (one foot at a time), got {duty}")
    if not (np.isfinite(step_height) and step_height >= 0):
        raise ValueError(f"step_height must be a finite float >= 0 (m), got {step_height!r}")
    if not np.isfinite(speed):
        raise ValueError(f"speed must be finite (m/s), got {speed!r}")
    if not (0.0 <= sway <= 1.0):
        raise ValueError(f"sway must lie in [0, 1], got {sway!r}")
    if not (np.isfinite(ramp_time) and ramp_time >= 0):
        raise ValueError(f"ramp_time must be a finite float >= 0 (s), got {ramp_time!r}")
    f32 = jnp.float32
    return GaitParams(
        period=f32(period),
        duty=f32(duty),
        step_height=f32(step_height),
        speed=f32(speed),
        sway=f32(sway),
        ramp_time=f32(ramp_time),
        pattern=jnp.int32(KINDS.index(kind)),
        family="hop" if kind == "hop" else "legged",
    )


# --------------------------------------------------------------------------------------
# Trajectories


def _smoothstep(s: jax.Array) -> jax.Array:
    """Quintic 0 -> 1 on [0, 1] with zero velocity and acceleration at both ends."""
    s = jnp.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def _quat_to_mat(q: jax.Array) -> jax.Array:
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _kind_index(kind: str) -> int:
    if kind not in KINDS:
        raise ValueError(f"gait.kind must be one of {KINDS}, got {kind!r}")
    return KINDS.index(kind)


def _ramp(gait: GaitParams, t: jax.Array) -> jax.Array:
    return jnp.where(gait.ramp_time > 0, jnp.clip(t / jnp.maximum(gait.ramp_time, 1e-6), 0, 1), 1.0)


def leg_phases(gait: GaitParams, robot: GaitRobot, t: jax.Array) -> jax.Array:
    """(n_legs,) phase of every leg in [0, 1): stance below ``duty``, swing above."""
    offset = robot.phase_offset[gait.pattern]
    return jnp.mod(t / gait.period + offset, 1.0)


def _hop_profile(gait: GaitParams, robot: GaitRobot, t: jax.Array):
    """Leg length (hip to foot centre along -z) and base acceleration command of the hop."""
    phase = jnp.mod(t / gait.period, 1.0)
    t_stance = gait.duty * gait.period
    t_flight = gait.period - t_stance
    # Take-off speed of a ballistic flight that lasts t_flight.
    v_to = 0.5 * GRAVITY * t_flight * _ramp(gait, t)
    length0 = robot.base_height - robot.foot_radius
    s = phase * gait.period
    # Stance: the base dips by v_to t_stance / pi and comes back with speed v_to.
    w = jnp.pi / t_stance
    dip = (v_to / w) * jnp.sin(w * s)
    acc = (v_to * w) * jnp.sin(w * s)
    tau = (s - t_stance) / t_flight
    retract = gait.step_height * _ramp(gait, t) * jnp.sin(jnp.pi * jnp.clip(tau, 0, 1)) ** 2
    in_stance = phase < gait.duty
    length = jnp.where(in_stance, length0 - dip, length0 - retract)
    return length, jnp.where(in_stance, acc, 0.0), in_stance


def _walk_sway(gait: GaitParams, robot: GaitRobot, t: jax.Array) -> jax.Array:
    """(2,) body shift of the walk in the base's x-y plane, m.

    In the lateral-sequence walk both left feet swing in one half of the cycle and both
    right feet in the other. Shifting the body sideways, away from the swinging side, moves
    the centre of mass off the diagonal between the two feet next to the lifted one and
    into the support triangle, for either foot of that side. The shift is a flattened
    cosine of the cycle (``tanh(2 cos) / tanh(2)``), centred on the middle of the left
    feet's swings, with amplitude ``sway`` times half the stance half-width: smooth, with
    small accelerations, yet near its full value when a foot lifts.
    """
    home = robot.foot_home
    centre = jnp.mean(home[:, :2], axis=0)
    left = home[:, 1] > centre[1]
    # Middle of each leg's swing in cycle time (phase = t / period + offset).
    mid = 2.0 * jnp.pi * (0.5 * (1.0 + gait.duty) - robot.phase_offset[_kind_index("walk")])
    tau_left = jnp.arctan2(
        jnp.sum(jnp.where(left, jnp.sin(mid), 0.0)), jnp.sum(jnp.where(left, jnp.cos(mid), 0.0))
    )
    half_width = jnp.mean(jnp.abs(home[:, 1] - centre[1]))
    # Linear inverted pendulum: a body swaying as A cos(w t) at height h moves its zero-
    # moment point by A (1 + w^2 h / g), so the amplitude that puts the ZMP at ``sway``
    # times the half-width is smaller for faster cycles and taller robots.
    omega = 2.0 * jnp.pi / gait.period
    amplitude = gait.sway * half_width / (1.0 + omega**2 * robot.base_height / GRAVITY)
    wave = jnp.tanh(2.0 * jnp.cos(omega * t - tau_left)) / jnp.tanh(2.0)
    return jnp.stack([0.0, -amplitude * wave])


def foot_targets(
    gait: GaitParams, robot: GaitRobot, t: jax.Array, base_vel: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Foot targets of every leg in the base frame.

    Args:
      gait: the gait.
      robot: the robot constants.
      t: () time since the start of the gait, s.
      base_vel: (3,) measured base velocity in the heading frame, m/s (Raibert feedback).

    Returns:
      ``(targets, load, base_acc)``: (n_legs, 3) foot centres, m; (n_legs,) share of the
      body weight each foot should carry (sums to 1 or 0); () commanded vertical base
      acceleration, m/s^2.
    """
    home = robot.foot_home
    if gait.family == "hop":
        length, acc, in_stance = _hop_profile(gait, robot, t)
        targets = jnp.stack(
            [home[:, 0], home[:, 1], jnp.broadcast_to(-length, home[:, 0].shape)], axis=-1
        )
        load = jnp.where(in_stance, 1.0, 0.0) * jnp.ones(robot.n_legs) / robot.n_legs
        return targets, load, acc

    ramp = _ramp(gait, t)
    phase = leg_phases(gait, robot, t)
    stance_t = gait.duty * gait.period
    stride = gait.speed * ramp * stance_t
    z0 = -(robot.base_height - robot.foot_radius)
    in_stance = phase < gait.duty
    s_st = phase / gait.duty
    s_sw = (phase - gait.duty) / (1.0 - gait.duty)
    # Raibert: step further in the direction the body moves faster than commanded.
    vel_err = base_vel[:2] - jnp.stack([gait.speed * ramp, 0.0])
    landing = jnp.stack([0.5 * stride, 0.0]) + robot.raibert * vel_err
    x_st = 0.5 * stride - stride * s_st
    y_st = jnp.zeros_like(s_st)
    blend = _smoothstep(s_sw)
    x_sw = -0.5 * stride + blend * (landing[0] + 0.5 * stride)
    y_sw = blend * landing[1]
    z_sw = gait.step_height * ramp * jnp.sin(jnp.pi * jnp.clip(s_sw, 0, 1)) ** 2
    dx = jnp.where(in_stance, x_st, x_sw)
    dy = jnp.where(in_stance, y_st, y_sw)
    dz = jnp.where(in_stance, 0.0, z_sw)
    nominal = jnp.stack([home[:, 0], home[:, 1], jnp.full_like(home[:, 0], z0)], axis=-1)
    targets = nominal + jnp.stack([dx, dy, dz], axis=-1)

    # The walk's sway; the trot's shift is exactly zero (a trot has no sway, whatever
    # ``sway`` holds).
    is_walk = gait.pattern == _kind_index("walk")
    shift = jnp.where(is_walk, _walk_sway(gait, robot, t) * ramp, 0.0)
    targets = targets - jnp.concatenate([shift, jnp.zeros(1)])[None, :]

    # Weight share: ramps in and out over the first and last 3 % of the stance (a longer
    # ramp leaves a freshly landed foot unloaded and chattering on the floor).
    ease = jnp.clip(jnp.minimum(s_st, 1.0 - s_st) / 0.03, 0.0, 1.0)
    raw = jnp.where(in_stance, ease, 0.0)
    load = raw / jnp.maximum(jnp.sum(raw), 1e-6)
    return targets, load, jnp.zeros(())


# --------------------------------------------------------------------------------------
# The controller


def _base_frames(robot: GaitRobot, qpos: jax.Array, qvel: jax.Array):
    """Base orientation (base -> world) and the base velocity in the heading frame."""
    if not robot.floating_base:
        return jnp.eye(3), jnp.zeros(3).at[2].set(qvel[0])
    rot = _quat_to_mat(qpos[3:7])
    yaw = jnp.arctan2(rot[1, 0], rot[0, 0])
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    rot_yaw = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot, rot_yaw.T @ qvel[0:3]


def gait_control(gait: GaitParams, robot: GaitRobot, t: jax.Array, data: mjx.Data) -> jax.Array:
    """The control input of one step (unbatched; ``vmap`` over envs).

    Args:
      gait: the gait command.
      robot: from :func:`make_gait_robot`.
      t: () time since the gait started, s.
      data: the current (true) ``mjx.Data``; only ``qpos`` and ``qvel`` are read.

    Returns:
      (nu,) ``ctrl`` for ``mjx.step``.
    """
    qpos, qvel = data.qpos, data.qvel
    rot, base_vel = _base_frames(robot, qpos, qvel)

    def targets_of(time):
        tg, _, _ = foot_targets(gait, robot, time, base_vel)
        return tg

    targets, load, base_acc = foot_targets(gait, robot, t, base_vel)
    # Foot target velocities from the clock only (the Raibert term moves slowly). Targets
    # stay in the base frame: in a gravity-levelled frame, feet level below a rolled body
    # would satisfy them just as well and roll would drift freely.
    _, target_vel = jax.jvp(targets_of, (t,), (jnp.ones_like(t),))

    # Ground reaction the stance feet should provide, world z, in the base frame.
    weight = robot.mass * (GRAVITY + base_acc)
    force_b = (load[:, None] * weight) * rot[2][None, :]

    def leg_torque(leg, target, target_vel, force):
        fk = lambda x: leg_fk(robot, leg, x)  # noqa: E731
        q_des = leg_ik(robot, leg, target)
        jac_des = jax.jacfwd(fk)(q_des)
        qd_des = damped_least_squares(jac_des, target_vel)
        q = qpos[robot.leg_qpos[leg]]
        qd = qvel[robot.leg_dof[leg]]
        # The floor pushes the foot up with `force`; the joints hold it: tau = -J^T f.
        jac = jax.jacfwd(fk)(q)
        return robot.kp * (q_des - q) + robot.kd * (qd_des - qd) - jac.T @ force

    legs = jnp.arange(robot.n_legs)
    tau_legs = jax.vmap(leg_torque)(legs, targets, target_vel, force_b)
    tau = jnp.zeros(qvel.shape[0]).at[robot.leg_dof].set(tau_legs)
    # A joint above several feet (a waist, a spine) is in no leg: held where it stands.
    held_q, held_qd = qpos[robot.held_qpos], qvel[robot.held_dof]
    held = robot.held_kp * (robot.held_home - held_q) - robot.held_kd * held_qd
    tau = tau.at[robot.held_dof].set(held)

    return torque_to_ctrl(robot, tau, qpos, qvel)


def torque_to_ctrl(robot: GaitRobot, tau: jax.Array, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
    """(nu,) controls that make the actuators apply the joint torques ``tau`` (nv,), N m.

    Inverts each actuator's affine law ``force = gain ctrl + b0 + b1 L + b2 dL`` with
    ``L = gear q`` (a position servo: ``b1 = -kp``, ``b2 = -kv``; a motor: no bias) and
    joint torque ``gear force``, at the current ``qpos`` (nq,) and ``qvel`` (nv,). The
    result is clipped to the control range, and MuJoCo still clips the force to the
    force range.
    """
    q_act = qpos_of_dof(robot, qpos)[robot.act_dof]
    qd_act = qvel[robot.act_dof]
    gear = robot.act_gear
    force = tau[robot.act_dof] / gear
    ctrl = (
        force - robot.act_bias0 - robot.act_bias1 * gear * q_act - robot.act_bias2 * gear * qd_act
    ) / robot.act_gain
    return jnp.clip(ctrl, robot.ctrl_low, robot.ctrl_high)


def qpos_of_dof(robot: GaitRobot, qpos: jax.Array) -> jax.Array:
    """(nv,) joint coordinate of every dof for hinge/slide joints (free-joint entries 0)."""
    if robot.floating_base:
        return jnp.concatenate([jnp.zeros(6), qpos[7:]])
    return qpos
