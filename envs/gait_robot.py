"""The robot constants of the scripted gaits and their leg kinematics.

:func:`make_gait_robot` reads, once and outside ``jit``, each leg's kinematic chain (any
chain of hinges from the base body to the foot: Go1, Spot, Barkour's tilted axes, the
planar leg), the standing pose, the joint ranges, the legs' phase offsets per gait and
the actuators' affine force laws into a :class:`GaitRobot` pytree. :func:`leg_fk` and
:func:`leg_ik` are the foot's forward kinematics in the base frame and a damped
Gauss-Newton inverse, both jittable and vmappable over legs.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from jax_contact.envs.gait_settings import (
    GaitSettings,
    actuator_law,
    feet_in_base,
    gait_foot_points,
    gait_settings,
    has_free_joint,
    resolve_gait_settings,
)
from jax_contact.envs.robots import Robot
from jax_contact.robot import model_mass


@struct.dataclass
class GaitRobot:
    """What the gait controller needs to know about one robot (from its MuJoCo model).

    Kinematic chains are padded to a common length ``n_chain`` with fixed identity links.

    Attributes:
      link_pos: (n_legs, n_chain, 3) each chain body's position in its parent, m.
      link_rot: (n_legs, n_chain, 3, 3) its orientation in its parent.
      joint_pos: (n_legs, n_chain, 3) the body's hinge anchor in the body frame, m.
      joint_axis: (n_legs, n_chain, 3) the hinge axis in the body frame (unit).
      joint_slot: (n_legs, n_chain) int32, which of the leg's joints the hinge is (-1: none,
        or a joint above several feet, folded into the link at its standing angle).
      foot_offset: (n_legs, 3) the foot point the gait places, in the last chain body
        (:func:`jax_contact.envs.gait_settings.gait_foot_points`), m.
      leg_qpos: (n_legs, n_l) int32 ``qpos`` index of each leg joint.
      leg_dof: (n_legs, n_l) int32 ``qvel`` index of each leg joint.
      q_home: (n_legs, n_l) joint angles of the standing pose, rad (the IK's start).
      q_low, q_high: (n_legs, n_l) joint ranges, rad (+-inf where unlimited).
      foot_home: (n_legs, 3) those points in the base frame at the standing pose, m.
      phase_offset: (3, n_legs) leg phase offsets for trot, walk, hop (rows in
        :data:`KINDS` order).
      base_height: () standing height of the base origin above the floor, m.
      foot_radius: () foot sphere radius, m.
      mass: () total mass, kg.
      kp, kd: () joint PD gains, N m / rad, N m s / rad.
      raibert: () foot-placement gain on the velocity error, s.
      act_dof: (nu,) int32 the dof each actuator drives.
      act_gain, act_bias0, act_bias1, act_bias2, act_gear: (nu,) affine actuator law
        ``force = gain ctrl + b0 + b1 gear q + b2 gear qd``, joint torque ``gear force``.
      ctrl_low, ctrl_high: (nu,) control range (+-inf where not limited).
      held_qpos, held_dof: (k,) int32 ``qpos`` / ``qvel`` index of each joint above several
        feet (a waist, a spine: in no leg, :func:`jax_contact.robot.split_legs`), which the
        controller holds at its standing angle ``held_home`` (k,), rad; k = 0 for robots
        whose legs meet only at the base.
      held_kp, held_kd: (k,) their PD gains: a position servo's own stiffness (the servo
        holds the joint as its designer tuned it; damping in the legs' ratio ``kd / kp``),
        else ``kp``, ``kd`` times the number of feet below the joint (it carries their
        loads).
      floating_base: static, whether ``qpos[0:7]`` is a free joint.
      nu: static, number of actuators.
    """

    link_pos: jax.Array
    link_rot: jax.Array
    joint_pos: jax.Array
    joint_axis: jax.Array
    joint_slot: jax.Array
    foot_offset: jax.Array
    leg_qpos: jax.Array
    leg_dof: jax.Array
    q_home: jax.Array
    q_low: jax.Array
    q_high: jax.Array
    foot_home: jax.Array
    phase_offset: jax.Array
    base_height: jax.Array
    foot_radius: jax.Array
    mass: jax.Array
    kp: jax.Array
    kd: jax.Array
    raibert: jax.Array
    act_dof: jax.Array
    act_gain: jax.Array
    act_bias0: jax.Array
    act_bias1: jax.Array
    act_bias2: jax.Array
    act_gear: jax.Array
    ctrl_low: jax.Array
    ctrl_high: jax.Array
    held_qpos: jax.Array
    held_dof: jax.Array
    held_home: jax.Array
    held_kp: jax.Array
    held_kd: jax.Array
    floating_base: bool = struct.field(pytree_node=False, default=True)
    nu: int = struct.field(pytree_node=False, default=12)

    @property
    def n_legs(self) -> int:
        return int(self.foot_offset.shape[0])


# --------------------------------------------------------------------------------------
# Building the robot constants (NumPy, once, outside jit)


def _quat_to_mat_np(q) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(q, dtype=np.float64))
    return mat.reshape(3, 3)


def _leg_chain(m: mujoco.MjModel, foot_body: int, base_body: int) -> list[int]:
    chain = []
    b = foot_body
    while b != base_body:
        if b == 0:
            raise ValueError(f"body {foot_body} does not hang from the base body {base_body}")
        chain.append(b)
        b = int(m.body_parentid[b])
    return chain[::-1]


def leg_phase_offsets(foot_home: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(trot, walk) phase offsets, each (n_legs,), from the standing feet in the base frame.

    Leg roles: left is +y of the base (above the feet's mean), and along each side the legs
    are ranked from the front (+x). The trot alternates along each side and across: a
    quadruped's diagonal pairs (front-left with hind-right, front-right with hind-left half
    a cycle later), a hexapod's alternating tripods, a biped's alternating legs (before,
    any leg count but four trotted every leg in phase: a pronk). A quadruped's walk is the
    lateral sequence: left-hind, left-front, right-hind, right-front lift a quarter cycle
    apart (a leg whose phase is ahead by x lifts x of a cycle earlier, so the offset is
    minus the delay); on other leg counts the walk's legs lift one ``1 / n_legs`` of a
    cycle apart in the order of the feet (``--feet``; found feet: the model's order). One
    leg: 0.
    """
    n = len(foot_home)
    if n == 1:
        return np.zeros(1), np.zeros(1)
    x, y = foot_home[:, 0], foot_home[:, 1]
    left = y - np.mean(y) > 1e-6  # a leg on the axis (a radial hexapod's front) is right
    rank = np.zeros(n, int)  # from the front, along each side
    sequence = []  # a quadruped's walk: the left side hind to front, then the right side
    for side in (True, False):
        legs = np.flatnonzero(left == side)
        front_first = legs[np.argsort(-x[legs], kind="stable")]
        rank[front_first] = np.arange(len(legs))
        sequence += list(front_first[::-1])
    trot = 0.5 * ((rank + left + 1) % 2)
    if n != 4 or left.sum() != 2:
        return trot, np.arange(n) / n
    delay = np.empty(n)
    delay[sequence] = np.arange(n) / n
    return trot, (1.0 - delay) % 1.0


def make_gait_robot(
    robot: Robot,
    settings: GaitSettings | None = None,
    *,
    kp: float | None = None,
    kd: float | None = None,
    raibert: float | None = None,
    base_height: float | None = None,
) -> GaitRobot:
    """Reads the kinematic chains, standing pose and actuators of ``robot``.

    Args:
      robot: from :func:`jax_contact.envs.robots.load_robot`.
      settings: the gait settings (default: :func:`gait_settings` of ``robot``), resolved
        by :func:`resolve_gait_settings`; the keywords below override single fields.
      kp, kd: joint PD gains, N m/rad, N m s/rad.
      raibert: foot-placement gain on the velocity error, s.
      base_height: standing height of the base above the floor, m.

    Raises:
      ValueError: a leg joint that is not a hinge or slide, a body with more than one
        joint on a leg, an actuator that is not an affine joint actuator without
        activation dynamics, or settings that cannot be resolved.
    """
    s = gait_settings(robot) if settings is None else settings
    given = dict(kp=kp, kd=kd, raibert=raibert, base_height=base_height)
    s = resolve_gait_settings(
        robot, dataclasses.replace(s, **{k: v for k, v in given.items() if v is not None})
    )
    kp, kd, raibert, base_height = s.kp, s.kd, s.raibert, s.base_height
    m, desc = robot.mj_model, robot.description
    home = np.asarray(s.home_qpos, dtype=np.float64)
    floating = has_free_joint(m, desc.base_body_id)
    n_legs, n_l = desc.n_legs, desc.n_leg_dofs
    chains = [_leg_chain(m, b, desc.base_body_id) for b in desc.foot_body_ids]
    n_chain = max(len(c) for c in chains)
    link_pos = np.zeros((n_legs, n_chain, 3))
    link_rot = np.tile(np.eye(3), (n_legs, n_chain, 1, 1))
    joint_pos = np.zeros((n_legs, n_chain, 3))
    joint_axis = np.tile(np.array([0.0, 0.0, 1.0]), (n_legs, n_chain, 1))
    joint_slot = -np.ones((n_legs, n_chain), dtype=np.int32)
    leg_qpos = np.zeros((n_legs, n_l), dtype=np.int32)
    leg_dof = np.zeros((n_legs, n_l), dtype=np.int32)
    q_low = np.full((n_legs, n_l), -np.inf)
    q_high = np.full((n_legs, n_l), np.inf)
    held: dict[int, tuple[int, float]] = {}  # dof -> (qpos index, standing angle)
    below: dict[int, int] = {}  # held dof -> number of feet whose chain it is on
    for i, chain in enumerate(chains):
        # Pad at the front: identity links before the first real body change nothing.
        pad = n_chain - len(chain)
        for k, b in enumerate(chain):
            kk = pad + k
            link_pos[i, kk] = m.body_pos[b]
            link_rot[i, kk] = _quat_to_mat_np(m.body_quat[b])
            joints = list(range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]))
            if len(joints) > 1:
                raise ValueError(f"body {m.body(b).name!r} has {len(joints)} joints; one at most")
            if not joints:
                continue
            j = joints[0]
            if int(m.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE):
                raise ValueError(f"leg joint {m.joint(j).name!r} is not a hinge")
            dof = int(m.jnt_dofadr[j])
            if dof not in desc.leg_dofs[i]:
                # Above several feet (a waist): a fixed link at its standing angle, held there.
                angle = float(home[m.jnt_qposadr[j]])
                quat = np.zeros(4)
                mujoco.mju_axisAngle2Quat(quat, np.asarray(m.jnt_axis[j], np.float64), angle)
                r_j = _quat_to_mat_np(quat)
                a = np.asarray(m.jnt_pos[j], dtype=np.float64)
                link_pos[i, kk] = link_pos[i, kk] + link_rot[i, kk] @ (a - r_j @ a)
                link_rot[i, kk] = link_rot[i, kk] @ r_j
                held[dof] = (int(m.jnt_qposadr[j]), angle)
                below[dof] = below.get(dof, 0) + 1
                continue
            slot = desc.leg_dofs[i].index(dof)
            joint_pos[i, kk] = m.jnt_pos[j]
            joint_axis[i, kk] = m.jnt_axis[j]
            joint_slot[i, kk] = slot
            leg_qpos[i, slot] = m.jnt_qposadr[j]
            leg_dof[i, slot] = dof
            if m.jnt_limited[j]:
                q_low[i, slot], q_high[i, slot] = m.jnt_range[j]

    # Foot positions at the standing pose, in the base frame, from MuJoCo itself.
    foot_home = feet_in_base(m, desc, home)
    q_home = home[leg_qpos]

    trot, walk = leg_phase_offsets(foot_home)
    phase_offset = np.stack([trot, walk, np.zeros(n_legs)])

    # Actuators: affine force law, no activation dynamics, on one joint each.
    nu = int(m.nu)
    act_dof, bias = actuator_law(m)
    limited = m.actuator_ctrllimited.astype(bool)
    ctrl_low = np.where(limited, m.actuator_ctrlrange[:, 0], -np.inf)
    ctrl_high = np.where(limited, m.actuator_ctrlrange[:, 1], np.inf)

    held_kp, held_kd = [], []
    for dof in held:
        servo = [a for a in range(nu) if act_dof[a] == dof and bias[a, 1] < 0]
        if servo:
            gear2 = float(m.actuator_gear[servo[0], 0]) ** 2
            held_kp.append(-bias[servo[0], 1] * gear2)
            held_kd.append(held_kp[-1] * kd / kp)
        else:
            held_kp.append(kp * below[dof])
            held_kd.append(kd * below[dof])

    f32 = lambda x: jnp.asarray(x, dtype=jnp.float32)  # noqa: E731
    return GaitRobot(
        link_pos=f32(link_pos),
        link_rot=f32(link_rot),
        joint_pos=f32(joint_pos),
        joint_axis=f32(joint_axis),
        joint_slot=jnp.asarray(joint_slot),
        foot_offset=f32(gait_foot_points(m, desc, home)),
        leg_qpos=jnp.asarray(leg_qpos),
        leg_dof=jnp.asarray(leg_dof),
        q_home=f32(q_home),
        q_low=f32(q_low),
        q_high=f32(q_high),
        foot_home=f32(foot_home),
        phase_offset=f32(phase_offset),
        base_height=f32(base_height),
        foot_radius=f32(desc.foot_radii[0]),
        mass=f32(model_mass(m)),
        kp=f32(kp),
        kd=f32(kd),
        raibert=f32(raibert),
        act_dof=jnp.asarray(act_dof),
        act_gain=f32(m.actuator_gainprm[:, 0]),
        act_bias0=f32(bias[:, 0]),
        act_bias1=f32(bias[:, 1]),
        act_bias2=f32(bias[:, 2]),
        act_gear=f32(m.actuator_gear[:, 0]),
        ctrl_low=f32(ctrl_low),
        ctrl_high=f32(ctrl_high),
        held_qpos=jnp.asarray([q for q, _ in held.values()], dtype=jnp.int32),
        held_dof=jnp.asarray(list(held), dtype=jnp.int32),
        held_home=f32([angle for _, angle in held.values()]),
        held_kp=f32(held_kp),
        held_kd=f32(held_kd),
        floating_base=floating,
        nu=nu,
    )


# --------------------------------------------------------------------------------------
# Kinematics


def _axis_rot(axis: jax.Array, angle: jax.Array) -> jax.Array:
    """(3, 3) rotation by ``angle`` about the unit ``axis`` (Rodrigues)."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return jnp.eye(3) + jnp.sin(angle) * k + (1.0 - jnp.cos(angle)) * (k @ k)


def leg_fk(robot: GaitRobot, leg: int | jax.Array, q_leg: jax.Array) -> jax.Array:
    """(3,) foot centre in the base frame for the leg's joint angles ``q_leg`` (n_l,), m.

    ``leg`` may be traced (e.g. ``vmap`` over legs).
    """
    rot = jnp.eye(3)
    pos = jnp.zeros(3)
    for k in range(robot.link_pos.shape[1]):
        pos = pos + rot @ robot.link_pos[leg, k]
        rot = rot @ robot.link_rot[leg, k]
        slot = robot.joint_slot[leg, k]
        angle = jnp.where(slot >= 0, q_leg[jnp.maximum(slot, 0)], 0.0)
        # A hinge at anchor a: x -> a + R (x - a), in the body frame.
        a = robot.joint_pos[leg, k]
        r_j = _axis_rot(robot.joint_axis[leg, k], angle)
        pos = pos + rot @ (a - r_j @ a)
        rot = rot @ r_j
    return pos + rot @ robot.foot_offset[leg]


def damped_least_squares(jac: jax.Array, rhs: jax.Array, damping: float = 1e-4) -> jax.Array:
    """(n,) damped least-squares solution of ``jac x = rhs`` for ``jac`` (3, n)."""
    n = jac.shape[1]
    return jnp.linalg.solve(jac.T @ jac + damping * jnp.eye(n), jac.T @ rhs)


def leg_ik(
    robot: GaitRobot,
    leg: int | jax.Array,
    target: jax.Array,
    *,
    iterations: int = 6,
    damping: float = 1e-4,
) -> jax.Array:
    """Joint angles (n_l,) that put the foot at ``target`` (3,) in the base frame.

    Damped Gauss-Newton from the standing pose (which keeps the knee on its side); with a
    leg of fewer than three joints the solution is the least-squares one. The result is
    clipped to the joint ranges.
    """

    def body(_, q):
        err = target - leg_fk(robot, leg, q)
        jac = jax.jacfwd(lambda x: leg_fk(robot, leg, x))(q)
        return q + damped_least_squares(jac, err, damping)

    q = jax.lax.fori_loop(0, iterations, body, robot.q_home[leg])
    return jnp.clip(q, robot.q_low[leg], robot.q_high[leg])
