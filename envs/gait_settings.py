"""Gait settings of a robot: standing pose, base height and joint gains for the scripted gaits.

:class:`GaitSettings` holds what a user may set per robot (:data:`GAIT_SETTINGS` has the
tuned ones of the robots that ship); :func:`resolve_gait_settings` fills every unset field
from the MuJoCo model: the standing pose from a keyframe or, without one, from a short
C MuJoCo settle (:func:`settle`), the base height from that pose, the gains from the
position servos' own or, for torque motors, from the robot's weight. Also the few model
readers that :mod:`jax_contact.envs.gait_robot` shares (free joint, feet in the base
frame, the actuators' affine force law). NumPy and C MuJoCo only, outside ``jit``.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping

import mujoco
import numpy as np

from jax_contact.envs.robots import Robot
from jax_contact.robot import model_mass

KINDS = ("trot", "walk", "hop")
GRAVITY = 9.81

SETTLE_S = 1.0  # s: how long a robot without a standing pose is let settle (see below)
# Derived gains of torque motors: stiff enough that a 1/7 rad deflection carries a leg's
# share of the weight at a lever of the leg's length (what the tuned Go1 and Spot gains
# give: 60 and 400 N m/rad), and kd / kp of the tuned Go1 gains.
_KP_PER_WEIGHT_MOMENT = 7.0
_KD_OVER_KP = 0.025  # s


@dataclasses.dataclass(frozen=True)
class GaitSettings:
    """How the scripted gaits drive one robot; None fields are derived from its model.

    Resolved by :func:`resolve_gait_settings` (which fills every None field):

    Attributes:
      home_key: name of the keyframe that is the standing pose; None: ``home``, else
        ``standing``, else the model's first keyframe, else a standing pose found by a
        short settle (:func:`settle`: :data:`SETTLE_S` of C MuJoCo from ``qpos0`` with its
        joint angles clipped into their ranges and each foot under its hip at 3/4 of the
        leg's reach, held by the gains below).
      home_qpos: (nq,) the standing pose itself (wins over ``home_key``).
      base_height: standing height of the base origin above the floor that the gait
        keeps, m; None: the home pose's (floating base: ``qpos[2]``).
      kp, kd: joint PD gains of the controller, N m/rad, N m s/rad; None: a position
        servo's own stiffness and damping, or for torque motors ``kp = 7 M g h / n_legs``
        (total mass ``M``, base height ``h``) and ``kd = 0.025 s * kp``.
      raibert: foot-placement gain on the velocity error, s.
      trot_speed, walk_speed: (low, high) range of the forward speed commands that
        ``simulate`` draws per env for the trot and the walk, m/s.
    """

    home_key: str | None = None
    home_qpos: tuple[float, ...] | None = None
    base_height: float | None = None
    kp: float | None = None
    kd: float | None = None
    raibert: float = 0.05
    trot_speed: tuple[float, float] = (0.0, 0.4)
    walk_speed: tuple[float, float] = (0.0, 0.15)

    def __post_init__(self):
        if self.home_qpos is not None:
            q = np.asarray(self.home_qpos, dtype=np.float64)
            if q.ndim != 1 or not np.all(np.isfinite(q)):
                raise ValueError(
                    f"home_qpos must be a finite (nq,) sequence, got {self.home_qpos!r}"
                )
            object.__setattr__(self, "home_qpos", tuple(float(x) for x in q))
        if self.home_key is not None and not (isinstance(self.home_key, str) and self.home_key):
            raise ValueError(f"home_key must be a keyframe name, got {self.home_key!r}")
        for name in ("base_height", "kp", "kd"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not (np.isfinite(self.raibert) and self.raibert >= 0):
            raise ValueError(f"raibert must be a finite number >= 0 (s), got {self.raibert!r}")
        for name in ("trot_speed", "walk_speed"):
            v = getattr(self, name)
            ok = len(v) == 2 and all(np.isfinite(x) for x in v) and v[0] <= v[1]
            if not ok:
                raise ValueError(f"{name} must be (low, high) with low <= high (m/s), got {v!r}")
            object.__setattr__(self, name, (float(v[0]), float(v[1])))

    def speed_range(self, kind: str) -> tuple[float, float]:
        """(low, high) forward speed commands of gait ``kind``, m/s (the hop: none)."""
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        return {"trot": self.trot_speed, "walk": self.walk_speed}.get(kind, (0.0, 0.0))


# Tuned on flat ground. Go1's servos have kp = 35, too soft to trot: its trot fell within
# 3 s at 35 and never at 60 or 80.
GAIT_SETTINGS: Mapping[str, GaitSettings] = types.MappingProxyType(
    {
        "go1": GaitSettings(kp=60.0, kd=1.5),
        "spot": GaitSettings(kp=400.0, kd=20.0),
        "barkour": GaitSettings(kp=35.0, kd=0.65),
        "planar_leg": GaitSettings(kp=300.0, kd=8.0),
    }
)


def gait_settings(robot: Robot | str, **overrides) -> GaitSettings:
    """The gait settings of a robot (not yet resolved) with ``overrides`` applied.

    Args:
      robot: a loaded robot (its ``gait`` if set, else :data:`GAIT_SETTINGS` of its name)
        or a robot name.
      **overrides: any :class:`GaitSettings` field.
    """
    if isinstance(robot, str):
        base = GAIT_SETTINGS.get(robot, GaitSettings())
    else:
        base = robot.gait or GAIT_SETTINGS.get(robot.name, GaitSettings())
    unknown = set(overrides) - {f.name for f in dataclasses.fields(GaitSettings)}
    if unknown:
        raise ValueError(f"unknown gait setting(s) {sorted(unknown)}")
    return dataclasses.replace(base, **overrides)


def has_free_joint(m: mujoco.MjModel, base_body: int) -> bool:
    """Whether body ``base_body`` of ``m`` hangs from the world by a free joint."""
    start, num = m.body_jntadr[base_body], m.body_jntnum[base_body]
    return any(
        int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE) for j in range(start, start + num)
    )


# Sole points within this of the lowest at the standing pose are the gait's foot point, m.
SOLE_LEVEL = 1e-3


def gait_foot_points(m: mujoco.MjModel, desc, qpos: np.ndarray) -> np.ndarray:
    """(n_legs, 3) the point of each foot the scripted gaits place, in its body's frame.

    The description's foot point (``desc.foot_offsets``: a sphere's centre, a sole's
    centre, a site), except for a foot with a sole (``desc.soles``: a capsule's segment
    ends, a flat sole's corners): the mean of its sole points within :data:`SOLE_LEVEL` of
    the lowest at ``qpos``. A capsule shin found as the foot is then placed by its lower
    end, not by its centre half a shin higher (the robot fell); a flat sole or a capsule
    lying across the leg keeps its centre.
    """
    return _gait_points(desc, _kinematics(m, qpos))


def _kinematics(m: mujoco.MjModel, qpos: np.ndarray) -> mujoco.MjData:
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    return d


def _gait_points(desc, d: mujoco.MjData) -> np.ndarray:
    """:func:`gait_foot_points` on data whose kinematics are computed."""
    out = []
    for body, point, sole in zip(desc.foot_body_ids, desc.foot_offsets, desc.soles, strict=True):
        if not sole:
            out.append(np.asarray(point, np.float64))
            continue
        local = np.asarray(sole, np.float64)
        z = (d.xmat[body].reshape(3, 3) @ local.T)[2]
        out.append(local[z <= z.min() + SOLE_LEVEL].mean(axis=0))
    return np.stack(out)


def foot_bottoms(desc, d: mujoco.MjData) -> np.ndarray:
    """(n_legs,) the height of each foot's lowest point, m, on data whose kinematics are
    computed: a sphere's centre less its radius; a foot with a sole (``desc.soles``) its
    lowest sole point less its radius (a box's bottom corners, radius 0; a capsule's
    segment ends less its radius). A box foot measured from its centre (radius 0) stood
    27 mm "above the floor" on its corners, and a settled robot was refused."""
    out = []
    for i, (body, sole) in enumerate(zip(desc.foot_body_ids, desc.soles, strict=True)):
        if sole:
            local = np.asarray(sole, np.float64)
            z = d.xpos[body][2] + (d.xmat[body].reshape(3, 3) @ local.T)[2]
            out.append(float(z.min()))
        else:
            out.append(float(d.geom_xpos[desc.foot_geom_ids[i], 2]))
    return np.asarray(out) - np.asarray(desc.foot_radii, np.float64)


def feet_in_base(m: mujoco.MjModel, desc, qpos: np.ndarray) -> np.ndarray:
    """(n_legs, 3) the gaits' foot points (:func:`gait_foot_points`) in the base frame at
    ``qpos``, from MuJoCo."""
    d = _kinematics(m, qpos)
    base_pos = d.xpos[desc.base_body_id]
    base_rot = d.xmat[desc.base_body_id].reshape(3, 3)
    points = _gait_points(desc, d)
    return np.stack(
        [
            base_rot.T @ (d.xpos[b] + d.xmat[b].reshape(3, 3) @ p - base_pos)
            for b, p in zip(desc.foot_body_ids, points, strict=True)
        ]
    )


def actuator_law(m: mujoco.MjModel):
    """(act_dof, bias (nu, 3)) of joint actuators with an affine force law.

    Raises:
      ValueError: naming an actuator that is not an affine joint actuator without
        activation dynamics.
    """
    nu = int(m.nu)
    act_dof = np.zeros(nu, dtype=np.int32)
    for a in range(nu):
        if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            raise ValueError(f"actuator {m.actuator(a).name!r} does not drive a joint")
        if int(m.actuator_dyntype[a]) != int(mujoco.mjtDyn.mjDYN_NONE):
            raise ValueError(f"actuator {m.actuator(a).name!r} has activation dynamics")
        if int(m.actuator_gaintype[a]) != int(mujoco.mjtGain.mjGAIN_FIXED):
            raise ValueError(f"actuator {m.actuator(a).name!r} has a non-fixed gain")
        if int(m.actuator_biastype[a]) not in (
            int(mujoco.mjtBias.mjBIAS_NONE),
            int(mujoco.mjtBias.mjBIAS_AFFINE),
        ):
            raise ValueError(f"actuator {m.actuator(a).name!r} has a non-affine bias")
        act_dof[a] = m.jnt_dofadr[m.actuator_trnid[a, 0]]
    affine = m.actuator_biastype == int(mujoco.mjtBias.mjBIAS_AFFINE)
    bias = np.where(affine[:, None], m.actuator_biasprm[:, :3], 0.0)
    return act_dof, bias


def _gains(m: mujoco.MjModel, desc, settings: GaitSettings, height: float) -> tuple[float, float]:
    _, bias = actuator_law(m)
    servo = m.nu > 0 and bool(np.all(bias[:, 1] < 0))
    if servo:
        kp0, kd0 = float(-bias[0, 1]), float(-bias[0, 2])
        kd0 = kd0 if kd0 > 0 else _KD_OVER_KP * kp0
    else:
        weight_moment = model_mass(m) * GRAVITY * height / desc.n_legs
        kp0 = _KP_PER_WEIGHT_MOMENT * weight_moment
        kd0 = _KD_OVER_KP * kp0
    kp = settings.kp if settings.kp is not None else kp0
    kd = settings.kd if settings.kd is not None else kd0
    return float(kp), float(kd)


def _keyframe(m: mujoco.MjModel, key: str | None) -> np.ndarray | None:
    names = [m.key(i).name for i in range(m.nkey)]
    if key is not None:
        if key not in names:
            raise ValueError(
                f"home_key (--home-key) {key!r} is not a keyframe of the model; keyframes: {names}"
            )
        return np.array(m.key_qpos[names.index(key)])
    for name in ("home", "standing"):
        if name in names:
            return np.array(m.key_qpos[names.index(name)])
    return np.array(m.key_qpos[0]) if m.nkey else None


_CROUCH = 0.75  # settle's initial foot depth below the hip, as a share of the leg's reach
_NUDGE = 0.1  # share of the way from qpos0 to the middle of each joint's range (knee side)


def _crouch(m: mujoco.MjModel, desc, q: np.ndarray, d: mujoco.MjData) -> np.ndarray:
    """``q`` with each leg's joints moved to put its foot level with its first joint along
    x (sideways where it was), at :data:`_CROUCH` of the leg's reach below it.

    Damped least squares on MuJoCo's Jacobian within the joint ranges, started from
    ``q`` nudged :data:`_NUDGE` of the way to the middle of each limited joint's range, so
    a straight leg (singular there) bends to the side its knee's range allows.
    """
    q = np.array(q)
    jacp = np.zeros((3, m.nv))
    for leg, geom in enumerate(desc.foot_geom_ids):
        dofs = list(desc.leg_dofs[leg])
        joints = [int(m.dof_jntid[v]) for v in dofs]
        for j in joints:
            if m.jnt_limited[j]:
                adr = m.jnt_qposadr[j]
                q[adr] += _NUDGE * (np.mean(m.jnt_range[j]) - q[adr])
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        hip = np.array(d.xanchor[joints[0]])
        reach = float(np.linalg.norm(d.geom_xpos[geom] - hip))
        # Sideways the foot stays where it is (a leg offset outward keeps its stance
        # width); along x it goes under the hip.
        target = np.array([hip[0], d.geom_xpos[geom, 1], hip[2] - _CROUCH * reach])
        for _ in range(100):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            err = target - d.geom_xpos[geom]
            if np.linalg.norm(err) < 1e-5:
                break
            mujoco.mj_jacGeom(m, d, jacp, None, geom)
            jac = jacp[:, dofs]
            step = np.linalg.solve(jac.T @ jac + 1e-4 * np.eye(len(dofs)), jac.T @ err)
            step *= min(1.0, 0.2 / max(float(np.max(np.abs(step))), 1e-12))  # <= 0.2 rad
            for j, dq in zip(joints, step, strict=True):
                adr = m.jnt_qposadr[j]
                q[adr] += dq
                if m.jnt_limited[j]:
                    q[adr] = np.clip(q[adr], *m.jnt_range[j])
    return q


def settle(robot: Robot, settings: GaitSettings | None = None, seconds: float = SETTLE_S):
    """A standing pose found by letting the robot settle on the floor (C MuJoCo).

    From ``qpos0`` with its joint angles clipped into their ranges (a straight leg that
    its knee's range forbids comes out bent), each foot then moved under its leg's first
    joint, crouched to 3/4 of the leg's reach (:func:`_crouch`), the base raised or
    lowered so that the lowest foot is 1 mm above the floor, each actuated joint held at
    that angle by the PD gains of ``settings`` (resolved as in
    :func:`resolve_gait_settings`) for ``seconds``.

    Returns:
      (nq,) the settled ``qpos``, base x, y set to 0.

    Raises:
      ValueError: the robot fell or never reached the floor (pass ``home_qpos``).
    """
    settings = gait_settings(robot) if settings is None else settings
    m, desc = robot.mj_model, robot.description
    floating = has_free_joint(m, desc.base_body_id)
    base_joints = set(
        range(
            m.body_jntadr[desc.base_body_id],
            m.body_jntadr[desc.base_body_id] + m.body_jntnum[desc.base_body_id],
        )
    )
    q = np.array(m.qpos0)
    for j in range(m.njnt):
        if j in base_joints or int(m.jnt_type[j]) not in (
            int(mujoco.mjtJoint.mjJNT_HINGE),
            int(mujoco.mjtJoint.mjJNT_SLIDE),
        ):
            continue
        if m.jnt_limited[j]:
            adr = m.jnt_qposadr[j]
            q[adr] = np.clip(q[adr], *m.jnt_range[j])
    d = mujoco.MjData(m)
    q = _crouch(m, desc, q, d)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    low = float(np.min(foot_bottoms(desc, d)))
    floor = max(float(d.geom_xpos[f, 2]) for f in desc.floor_geom_ids)
    height = float(d.xpos[desc.base_body_id, 2]) - low
    if floating:
        q[2] += floor - low + 1e-3
    kp, kd = _gains(m, desc, settings, height)
    act_dof, bias = actuator_law(m)
    dof_q = np.zeros(m.nv)  # joint coordinate per dof (hinge / slide only)
    for j in range(m.njnt):
        if int(m.jnt_type[j]) in (
            int(mujoco.mjtJoint.mjJNT_HINGE),
            int(mujoco.mjtJoint.mjJNT_SLIDE),
        ):
            dof_q[m.jnt_dofadr[j]] = m.jnt_qposadr[j]
    q_adr = dof_q.astype(int)[act_dof]
    target = q[q_adr]
    gear, gain = m.actuator_gear[:, 0], m.actuator_gainprm[:, 0]
    limited = m.actuator_ctrllimited.astype(bool)
    low_c = np.where(limited, m.actuator_ctrlrange[:, 0], -np.inf)
    high_c = np.where(limited, m.actuator_ctrlrange[:, 1], np.inf)
    mujoco.mj_resetData(m, d)
    d.qpos[:] = q
    for _ in range(int(round(seconds / m.opt.timestep))):
        qa, qda = d.qpos[q_adr], d.qvel[act_dof]
        force = (kp * (target - qa) - kd * qda) / gear
        ctrl = (force - bias[:, 0] - bias[:, 1] * gear * qa - bias[:, 2] * gear * qda) / gain
        d.ctrl[:] = np.clip(ctrl, low_c, high_c)
        mujoco.mj_step(m, d)
    out = np.array(d.qpos)
    mujoco.mj_kinematics(m, d)
    gap = foot_bottoms(desc, d) - floor
    upright = not floating or 1.0 - 2.0 * (out[4] ** 2 + out[5] ** 2) > 0.9
    if not (np.all(np.isfinite(out)) and upright and np.all(gap < 0.01)):
        raise ValueError(
            f"robot {robot.name!r} has no standing pose (no keyframe) and did not settle"
            f" standing in {seconds} s from qpos0 (feet {np.round(gap, 3).tolist()} m above"
            " the floor): give it a standing pose (--home-qpos Q ... or --home-key KEY;"
            " GaitSettings(home_qpos=..., home_key=...) in Python), or check that its"
            " actuators' force ranges can hold it up"
        )
    if floating:
        out[0:2] = 0.0
        out[3:7] /= np.linalg.norm(out[3:7])
    return out


def resolve_gait_settings(robot: Robot, settings: GaitSettings | None = None) -> GaitSettings:
    """``settings`` (default :func:`gait_settings` of ``robot``) with every None filled in
    from the model (the rules of :class:`GaitSettings`); the gains stay None on a model
    whose actuators the gaits cannot drive (:func:`make_gait_robot` says which).

    Raises:
      ValueError: a ``home_qpos`` of the wrong size, an unknown ``home_key`` (the
        keyframes listed), or a robot that does not settle standing.
    """
    s = gait_settings(robot) if settings is None else settings
    m, desc = robot.mj_model, robot.description
    if s.home_qpos is not None:
        home = np.array(s.home_qpos)
        if home.shape != (m.nq,):
            raise ValueError(
                f"home_qpos has {home.size} values; robot {robot.name!r} has nq = {m.nq}"
            )
    else:
        home = _keyframe(m, s.home_key)
        if home is None:
            home = settle(robot, s)
    if s.base_height is not None:
        height = s.base_height
    elif has_free_joint(m, desc.base_body_id):
        height = float(home[2])
    else:
        feet = feet_in_base(m, desc, home)
        height = float(-np.min(feet[:, 2]) + desc.foot_radii[0])
    try:
        kp, kd = _gains(m, desc, s, height)
    except ValueError:  # actuators the gaits cannot drive: the pose is still useful
        kp, kd = s.kp, s.kd  # make_gait_robot names the actuator
    return dataclasses.replace(
        s, home_qpos=tuple(float(x) for x in home), base_height=height, kp=kp, kd=kd
    )
