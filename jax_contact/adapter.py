"""MJX model and data -> the estimator's measurement: per robot or one per foot.

The only module of the library that knows MuJoCo. Usage, inside ``jit`` / ``vmap`` over
environments::

    d = d.replace(qpos=qpos_measured, qvel=qvel_measured)
    d = prepare(mjx_model, d)
    meas = leg_measurements(mjx_model, d, desc, qdd=qdd_measured)   # leaves (n_legs, ...)
    meas = robot_measurement(mjx_model, d, desc, qdd=qdd_measured)  # per robot, same values

``desc`` (a :class:`jax_contact.robot.RobotDescription`) is static: close over it or pass it
as a static argument. The model must use MJX's JAX implementation (``mjx.put_model(m,
impl="jax")``; Playground environments default to ``"warp"``).

Where each quantity comes from (all at the state in ``mjx_data``):

- ``M``: ``mjx.full_m`` (includes joint armature, like the C library's ``mj_fullM``).
- ``h``: ``qfrc_bias`` (Coriolis, centrifugal, gravity: ``mjx.rne`` without acceleration);
  with ``include_passive`` also minus ``qfrc_passive`` (joint springs and dampers), which
  the paper's ``h`` does not have but a robot model may know.
- ``tau``: ``qfrc_actuator`` (what joint torque sensors measure: the generalised actuator
  force after force limits), unless given.
- ``qdd``: ``qacc`` of the data (the simulator's true acceleration), unless given.
- ``J``, ``p_f``, ``v_f``: ``mjx.jac`` at the foot's point, its body's pose applied to
  ``desc.foot_offsets`` (:func:`foot_centres`: a sphere geom's centre, a site, a point on a
  body), or for a foot with a sole (``desc.foot_soles``: a flat sole's corners, the
  centres of several spheres, a capsule's ends) the rolling point of
  :func:`contact_points`; ``v_f = J qd``.
- ``Jdot_qd``: the foot centre's acceleration at zero ``qacc`` without gravity, from the
  velocity-stage quantities ``cvel`` and ``cdof_dot`` (see :func:`foot_bias_acceleration`);
  it equals the C library's ``mj_jacDot(point) @ qvel``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from jax_contact.robot import RobotDescription
from jax_contact.types import LegMeasurement, RobotMeasurement, check_real

# Where a foot with a sole touches (contact_points): "rolling" follows the sole's lowest
# edge or corner, "centre" keeps its fixed point.
SOLES = ("rolling", "centre")
# Softness of the rolling sole's lowest point, m: corners this much higher weigh 1/e (set,
# not fitted; docs/training.md measures the rolling point on Berkeley Humanoid).
SOLE_SOFTNESS = 0.002


def prepare(mjx_model: mjx.Model, mjx_data: mjx.Data) -> mjx.Data:
    """Runs the pipeline stages that :func:`leg_measurements` reads, at ``qpos``, ``qvel``.

    Position stage: ``kinematics``, ``com_pos``, ``crb`` (mass matrix); velocity stage:
    ``com_vel`` (``cvel``, ``cdof_dot``), ``passive``, ``rne`` (``qfrc_bias``). Unlike
    ``mjx.forward`` it runs no collision detection, constraint solver, actuation or
    sensors, so ``qacc``, ``qfrc_actuator`` and ``sensordata`` keep the values they had
    (those of the simulation step that produced the data).

    A NaN or inf in ``qpos`` (a dropped encoder reading) is computed at the model's
    ``qpos0`` instead, and the returned data keep the ``qpos`` given: MuJoCo expresses its
    spatial quantities about the root's subtree centre of mass, which one NaN joint would
    make NaN for every body, where only the bodies below that joint depend on it.
    :func:`robot_measurement` then marks the feet below a non-finite ``qpos`` entry
    invalid (their ``p_f`` NaN); the other feet's quantities are those of their own
    branches, the same up to round-off (the subtree centre of mass they are summed about
    moves: ~5e-7 in P on Go1 in float32).

    Args:
      mjx_model: the MJX model (JAX implementation).
      mjx_data: data whose ``qpos`` and ``qvel`` hold the measured state.

    Returns:
      The data with the position- and velocity-dependent fields recomputed.

    Raises:
      ValueError: C MuJoCo's model or data instead of MJX's, or ``qpos``/``qvel`` not of
        one robot of this model (a batch: ``jax.vmap`` it).
    """
    _check_mjx_inputs(mjx_model, mjx_data)
    # NumPy state (a control loop's readings) as JAX arrays: MJX's tree scan over bodies
    # failed on a NumPy qvel outside jit ("numpy arg elements do not match").
    qpos = jnp.asarray(mjx_data.qpos)
    d = mjx_data.replace(
        qpos=jnp.where(jnp.isfinite(qpos), qpos, mjx_model.qpos0), qvel=jnp.asarray(mjx_data.qvel)
    )
    d = mjx.kinematics(mjx_model, d)
    d = mjx.com_pos(mjx_model, d)
    d = mjx.crb(mjx_model, d)
    d = mjx.com_vel(mjx_model, d)
    d = mjx.passive(mjx_model, d)
    return mjx.rne(mjx_model, d).replace(qpos=qpos)


def _motion_cross(u: jax.Array, x: jax.Array) -> jax.Array:
    """Spatial motion cross product ``u x x`` of 6-vectors ``[angular, linear]``."""
    w, v = u[:3], u[3:]
    return jnp.concatenate([jnp.cross(w, x[:3]), jnp.cross(w, x[3:]) + jnp.cross(v, x[:3])])


def _chain_bodies(mjx_model: mjx.Model, body_id: int) -> list[int]:
    """The bodies from ``body_id`` up to (not including) the world."""
    chain = []
    b = int(body_id)
    while b != 0:
        chain.append(b)
        b = int(mjx_model.body_parentid[b])
    return sorted(chain)


def _chain_dof_mask(mjx_model: mjx.Model, body_id: int) -> np.ndarray:
    """(nv,) bool: dofs of the joints between ``body_id`` and the world."""
    return np.isin(np.asarray(mjx_model.dof_bodyid), _chain_bodies(mjx_model, body_id))


def _chain_qpos_mask(mjx_model: mjx.Model, body_id: int) -> np.ndarray:
    """(nq,) bool: ``qpos`` entries of the joints between ``body_id`` and the world."""
    kinds = mujoco.mjtJoint
    sizes = {int(kinds.mjJNT_FREE): 7, int(kinds.mjJNT_BALL): 4}  # slide, hinge: 1
    mask = np.zeros(mjx_model.nq, bool)
    chain = set(_chain_bodies(mjx_model, body_id))
    for j, (body, kind) in enumerate(zip(mjx_model.jnt_bodyid, mjx_model.jnt_type, strict=True)):
        if int(body) in chain:
            start = int(mjx_model.jnt_qposadr[j])
            mask[start : start + sizes.get(int(kind), 1)] = True
    return mask


def _quat_dofs(mjx_model: mjx.Model) -> np.ndarray:
    """(nv,) bool: rotational dofs of ball and free joints (axes fixed in the child body)."""
    jnt = np.asarray(mjx_model.dof_jntid)
    jnt_type = np.asarray(mjx_model.jnt_type)[jnt]
    dof_adr = np.asarray(mjx_model.jnt_dofadr)[jnt]
    ball = jnt_type == int(mujoco.mjtJoint.mjJNT_BALL)
    free = jnt_type == int(mujoco.mjtJoint.mjJNT_FREE)
    free_rot = free & (np.arange(mjx_model.nv) >= dof_adr + 3)
    return ball | free_rot


def foot_bias_acceleration(
    mjx_model: mjx.Model,
    mjx_data: mjx.Data,
    body_id: jax.Array,
    point: jax.Array,
    chain_mask: jax.Array,
) -> jax.Array:
    """``d/dt(J) qd``: acceleration of a point fixed to a body when ``qacc = 0``, m/s^2.

    The translational Jacobian column of dof ``i`` at point ``p`` is ``jacp_i = cdof_i[3:]
    + cdof_i[:3] x (p - c)``, with ``cdof_i`` MuJoCo's motion axis in the world-aligned
    frame at ``c``, the subtree COM of the root (a point held fixed over the derivative).
    Differentiating in time,

        d/dt jacp_i = cdof_dot_i[3:] + cdof_dot_i[:3] x (p - c) + cdof_i[:3] x v_p,

    where ``v_p`` is the point's velocity and ``cdof_dot_i`` the axis' rate of change:
    ``com_vel`` gives ``cvel(parent) x cdof_i`` for hinges and slides; the rotational dofs
    of free and ball joints turn with their own body, so for them it is ``cvel(body) x
    cdof_i``. This is the C library's ``mj_jacDot``; the result is ``sum_i d/dt jacp_i
    qd_i`` over the dofs of the body's chain. It needs only ``cvel``, ``cdof``,
    ``cdof_dot`` and ``subtree_com``, which :func:`prepare` computes, so it costs a few
    cross products rather than another pass of kinematics.

    Args:
      mjx_model: the MJX model.
      mjx_data: data after :func:`prepare`.
      body_id: () int, the body the point is fixed to.
      point: (3,) the point in world coordinates, m.
      chain_mask: (nv,) bool, the dofs between the body and the world.

    Returns:
      (3,) bias acceleration of the point, world frame, m/s^2.
    """
    d = mjx_data
    root = jnp.asarray(mjx_model.body_rootid)[body_id]
    offset = point - d.subtree_com[root]
    cvel_b = d.cvel[body_id]
    v_point = cvel_b[3:] - jnp.cross(offset, cvel_b[:3])
    cdof_dot_quat = jax.vmap(_motion_cross)(d.cvel[jnp.asarray(mjx_model.dof_bodyid)], d.cdof)
    cdof_dot = jnp.where(_quat_dofs(mjx_model)[:, None], cdof_dot_quat, d.cdof_dot)
    col = cdof_dot[:, 3:] + jnp.cross(cdof_dot[:, :3], offset) + jnp.cross(d.cdof[:, :3], v_point)
    # Summed over the chain only: another branch's NaN velocity (its cdof_dot) stays out.
    return jnp.sum(jnp.where(chain_mask[:, None], d.qvel[:, None] * col, 0.0), axis=0)


def _check_mjx_inputs(mjx_model, mjx_data) -> None:
    """MJX's model and data (not MuJoCo's C ones)."""
    if not isinstance(mjx_model, mjx.Model):
        hint = (
            " (mjx.put_model(mj_model, impl='jax'))"
            if isinstance(mjx_model, mujoco.MjModel)
            else ""
        )
        raise ValueError(f"mjx_model must be an mjx.Model{hint}, got {type(mjx_model).__name__}")
    if not isinstance(mjx_data, mjx.Data):
        hint = " (mjx.put_data(mj_model, mj_data))" if isinstance(mjx_data, mujoco.MjData) else ""
        raise ValueError(f"mjx_data must be an mjx.Data{hint}, got {type(mjx_data).__name__}")
    # One robot's data: a batch (or another robot's state) failed deep inside MJX's tree scan.
    for name, n in (("qpos", mjx_model.nq), ("qvel", mjx_model.nv)):
        check_real(f"mjx_data.{name}", getattr(mjx_data, name))
        shape = jnp.shape(getattr(mjx_data, name))
        if shape != (n,):
            hint = (
                ": one robot's data; jax.vmap over envs (as the README's estimate does)"
                if len(shape) == 2 and shape[1] == n
                else f" (the model's {'nq' if name == 'qpos' else 'nv'})"
            )
            raise ValueError(f"mjx_data.{name} has shape {shape}; expected ({n},){hint}")


def _check_description(desc, mjx_model) -> None:
    """``desc`` is the :class:`RobotDescription` of ``mjx_model``."""
    if not isinstance(desc, RobotDescription):
        hint = " (robot.description)" if hasattr(desc, "description") else ""
        raise ValueError(
            f"desc must be a jax_contact.robot.RobotDescription{hint}, got {type(desc).__name__}"
        )
    if (desc.nv, desc.nq) != (mjx_model.nv, mjx_model.nq):
        raise ValueError(
            f"desc has nv={desc.nv}, nq={desc.nq} but mjx_model has nv={mjx_model.nv},"
            f" nq={mjx_model.nq}: derive the description from the same model"
        )


def robot_measurement(
    mjx_model: mjx.Model,
    mjx_data: mjx.Data,
    desc: RobotDescription,
    *,
    qdd: jax.Array | None = None,
    tau: jax.Array | None = None,
    include_passive: bool = False,
    sole: str = "rolling",
) -> RobotMeasurement:
    """The robot's measurement at the state of ``mjx_data`` (after :func:`prepare`).

    Args:
      mjx_model: the MJX model the description was derived from.
      mjx_data: prepared data at the measured ``qpos``, ``qvel``.
      desc: the robot description (static).
      qdd: (nv,) measured generalised accelerations; default ``mjx_data.qacc``.
      tau: (nv,) measured generalised actuation forces; default
        ``mjx_data.qfrc_actuator``.
      include_passive: static; if True, ``h`` also holds the joint spring and damper
        forces: ``h = qfrc_bias - qfrc_passive``.
      sole: static, where a foot with a sole touches (:func:`contact_points`):
        ``"rolling"`` (default) or ``"centre"``; a sphere foot, a site or a body offset
        has its fixed point either way.

    Returns:
      A :class:`RobotMeasurement`: ``q`` (nq,), ``qd``/``qdd``/``tau``/``h`` (nv,), ``M``
      (nv, nv), ``J`` (n_legs, 3, nv), ``Jdot_qd``/``p_f``/``v_f`` (n_legs, 3),
      ``foot_radius`` (n_legs,), ``leg_dofs`` from ``desc``.

    Raises:
      ValueError: ``desc`` does not match the model, ``qdd``/``tau`` have the wrong
        shape, or ``sole`` is not one of :data:`SOLES`.
    """
    m, d = mjx_model, mjx_data
    _check_mjx_inputs(m, d)
    _check_description(desc, m)
    for name, value in (("qdd", qdd), ("tau", tau)):
        if value is not None and jnp.shape(value) != (m.nv,):
            raise ValueError(f"{name} must have shape ({m.nv},) (nv), got {jnp.shape(value)}")
        if value is not None:
            check_real(name, value)
    return measurement_at_points(
        m,
        d,
        desc,
        contact_points(desc, d, sole),
        jnp.asarray(desc.foot_radii, d.xpos.dtype),
        qdd=qdd,
        tau=tau,
        include_passive=include_passive,
    )


def contact_points(desc: RobotDescription, mjx_data: mjx.Data, sole: str = "rolling") -> jax.Array:
    """(n_legs, 3) world positions of the feet's contact points, m.

    Eq. 6 treats a foot as one point. For a foot with a sole (``desc.foot_soles``: a flat
    sole's four corners, or the centres of a foot's spheres and its capsules' segment ends,
    one radius) that point moves: a sole that lands on its heel or rolls over its toe
    touches the floor at that edge, while its centre is centimetres up and moving.
    ``"rolling"`` takes the mean of the sole's points weighted by ``exp(-(z - z_min) /
    SOLE_SOFTNESS)``: the centre when the sole lies flat, the middle of the lowest edge
    when it tilts by more than a degree or two, the lowest corner on a corner.
    ``"centre"`` keeps the fixed point (:func:`foot_centres`), as does every foot without
    a sole.

    Args:
      desc: the robot description.
      mjx_data: data after kinematics (``xpos``, ``xmat``).
      sole: static, ``"rolling"`` or ``"centre"`` (:data:`SOLES`).

    Raises:
      ValueError: ``sole`` is not one of :data:`SOLES`.
    """
    if sole not in SOLES:
        raise ValueError(f"sole must be one of {SOLES}, got {sole!r}")
    if sole == "centre" or not any(desc.foot_soles):
        return foot_centres(desc, mjx_data)
    k = max(len(c) for c in desc.foot_soles)
    # One (k, 3) block per foot: its points repeated cyclically up to k (a foot without a
    # sole: its fixed point k times), which leaves every foot's weighted mean unchanged
    # when k is a multiple of its count.
    blocks = []
    for c, o in zip(desc.foot_soles, desc.foot_offsets, strict=True):
        pts = np.asarray(c or [o], np.float32).reshape(-1, 3)
        blocks.append(pts[np.arange(k) % len(pts)])
    world = on_foot_bodies(desc, mjx_data, np.stack(blocks))
    z = world[..., 2]
    w = jax.nn.softmax(-(z - jnp.min(z, axis=1, keepdims=True)) / SOLE_SOFTNESS, axis=1)
    return jnp.einsum("nk,nki->ni", w, world)


def foot_centres(desc: RobotDescription, mjx_data: mjx.Data) -> jax.Array:
    """(n_legs, 3) world positions of the feet's fixed points, m.

    ``xpos + xmat @ foot_offsets`` of each foot's body: the sphere geom's centre (equal to
    its ``geom_xpos``), or the site or body offset the foot was named by. Needs the data's
    kinematics (``xpos``, ``xmat``).
    """
    return on_foot_bodies(desc, mjx_data, desc.foot_offsets)


def on_foot_bodies(desc: RobotDescription, mjx_data: mjx.Data, local) -> jax.Array:
    """World positions of points fixed to the feet's bodies, m.

    Args:
      desc: the robot description (its ``foot_body_ids``).
      mjx_data: data after kinematics (``xpos``, ``xmat``).
      local: (n_legs, ..., 3) points in each foot body's frame, m.

    Returns:
      (n_legs, ..., 3) ``xpos + xmat @ local`` of each foot's body.
    """
    b = jnp.asarray(desc.foot_body_ids, dtype=jnp.int32)
    local = jnp.asarray(local, mjx_data.xpos.dtype)
    pos = mjx_data.xpos[b].reshape((len(desc.foot_body_ids),) + (1,) * (local.ndim - 2) + (3,))
    return pos + jnp.einsum("nij,n...j->n...i", mjx_data.xmat[b], local)


def measurement_at_points(
    mjx_model: mjx.Model,
    mjx_data: mjx.Data,
    desc: RobotDescription,
    p_f: jax.Array,
    foot_radius: jax.Array,
    *,
    qdd: jax.Array | None = None,
    tau: jax.Array | None = None,
    include_passive: bool = False,
) -> RobotMeasurement:
    """:func:`robot_measurement` with each foot's contact point given.

    The one place the measurement is assembled: ``J`` from ``mjx.jac`` at the point,
    ``Jdot qd`` from :func:`foot_bias_acceleration`, ``M`` from ``mjx.full_m``, ``h`` from
    ``qfrc_bias``. :func:`robot_measurement` passes :func:`contact_points`.

    Args:
      mjx_model, mjx_data, desc: as :func:`robot_measurement` (shapes not re-checked).
      p_f: (n_legs, 3) world positions of the contact points, m; each moves with its
        ``desc.foot_body_ids`` body.
      foot_radius: (n_legs,) distance from each point to the sole, m.
      qdd, tau, include_passive: as :func:`robot_measurement`.
    """
    m, d = mjx_model, mjx_data
    qdd = d.qacc if qdd is None else jnp.asarray(qdd)
    tau = d.qfrc_actuator if tau is None else jnp.asarray(tau)
    h = d.qfrc_bias - d.qfrc_passive if include_passive else d.qfrc_bias
    body_ids = jnp.asarray(desc.foot_body_ids, dtype=jnp.int32)
    masks = jnp.asarray(np.stack([_chain_dof_mask(m, b) for b in desc.foot_body_ids]))

    def per_foot(body_id, point, mask):
        jacp, _ = mjx.jac(m, d, point, body_id)
        return jacp.T, foot_bias_acceleration(m, d, body_id, point, mask)

    J, Jdot_qd = jax.vmap(per_foot)(body_ids, p_f, masks)
    # A foot below a non-finite qpos entry (computed at qpos0 by prepare) is marked
    # invalid by a NaN position; the other feet are left as they are.
    qpos_masks = np.stack([_chain_qpos_mask(m, b) for b in desc.foot_body_ids])
    lost = jnp.any(qpos_masks & ~jnp.isfinite(d.qpos), axis=1)
    p_f = jnp.where(lost[:, None], jnp.nan, p_f)
    M = mjx.full_m(m, d)
    # Unprepared data read as a massless robot (every step invalid, no hint): refused
    # where the data are concrete (not under jit or vmap).
    if not isinstance(M, jax.core.Tracer) and not np.any(np.asarray(M)):
        raise ValueError(
            "mjx_data has no mass matrix (it is all zeros): run prepare(mjx_model, mjx_data)"
            " (or mjx.forward) at the measured qpos, qvel first"
        )
    return RobotMeasurement(
        q=d.qpos,
        qd=d.qvel,
        qdd=qdd,
        tau=tau,
        M=M,
        h=h,
        J=J,
        Jdot_qd=Jdot_qd,
        p_f=p_f,
        # J qd over the columns the foot's Jacobian has: another leg's NaN velocity
        # (times an exact zero) stays in that leg.
        v_f=jnp.sum(jnp.where(J != 0, J * d.qvel, 0.0), axis=-1),
        foot_radius=jnp.asarray(foot_radius),
        leg_dofs=tuple(tuple(int(i) for i in leg) for leg in desc.leg_dofs),
    )


def leg_measurements(
    mjx_model: mjx.Model,
    mjx_data: mjx.Data,
    desc: RobotDescription,
    *,
    qdd: jax.Array | None = None,
    tau: jax.Array | None = None,
    include_passive: bool = False,
    sole: str = "rolling",
) -> LegMeasurement:
    """Per-leg measurements at the state of ``mjx_data`` (after :func:`prepare`).

    :func:`robot_measurement` in the per-foot layout (its ``legs()``); same arguments.

    Returns:
      A :class:`LegMeasurement` whose every leaf has leading axis ``n_legs``: ``q``
      (n_legs, nq), ``qd``/``qdd``/``tau``/``h`` (n_legs, nv), ``M`` (n_legs, nv, nv),
      ``J`` (n_legs, 3, nv), ``Jdot_qd``/``p_f``/``v_f`` (n_legs, 3), ``foot_radius``
      (n_legs,), ``leg_dofs`` (n_legs, n_l) and ``other_dofs`` (n_legs, nv - n_l) int32.

    Raises:
      ValueError: ``desc`` does not match the model, or ``qdd``/``tau`` have the wrong
        shape.
    """
    return robot_measurement(
        mjx_model, mjx_data, desc, qdd=qdd, tau=tau, include_passive=include_passive, sole=sole
    ).legs()
