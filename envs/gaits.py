"""Scripted gaits: periodic foot trajectories, per-leg inverse kinematics and joint PD.

No trained policy: a clock drives every leg through stance and swing, and a joint-space PD
controller with a weight-bearing feed-forward tracks the resulting foot targets. It is good
enough to produce long, varied runs of touch-downs and lift-offs for the contact estimator
on flat ground, and nothing more (no terrain perception, no turning).

Gaits (``GaitParams.kind``; the trot and the walk differ only in data, the leg phase
offsets and the sway, so one compiled program runs both; the hop is a program of its own):

- ``trot``: diagonal pairs (front-left with hind-right, front-right with hind-left) half a
  period apart.
- ``walk``: a static lateral-sequence walk, one foot at a time (hind-left, front-left,
  hind-right, front-right, a quarter period apart) with ``duty >= 0.75``; the body sways
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
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx

from jax_contact.envs.robots import Robot

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


def _floating(m: mujoco.MjModel, base_body: int) -> bool:
    start, num = m.body_jntadr[base_body], m.body_jntnum[base_body]
    return any(
        int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE) for j in range(start, start + num)
    )


def _feet_in_base(m: mujoco.MjModel, desc, qpos: np.ndarray) -> np.ndarray:
    """(n_legs, 3) foot sphere centres in the base frame at ``qpos``, from MuJoCo."""
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    base_pos = d.xpos[desc.base_body_id]
    base_rot = d.xmat[desc.base_body_id].reshape(3, 3)
    return np.stack([base_rot.T @ (d.geom_xpos[g] - base_pos) for g in desc.foot_geom_ids])


def _actuator_law(m: mujoco.MjModel):
    """(act_dof, bias (nu, 3)) of joint actuators with an affine force law, or ValueError."""
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
    _, bias = _actuator_law(m)
    servo = m.nu > 0 and bool(np.all(bias[:, 1] < 0))
    if servo:
        kp0, kd0 = float(-bias[0, 1]), float(-bias[0, 2])
        kd0 = kd0 if kd0 > 0 else _KD_OVER_KP * kp0
    else:
        weight_moment = float(np.sum(m.body_mass)) * GRAVITY * height / desc.n_legs
        kp0 = _KP_PER_WEIGHT_MOMENT * weight_moment
        kd0 = _KD_OVER_KP * kp0
    kp = settings.kp if settings.kp is not None else kp0
    kd = settings.kd if settings.kd is not None else kd0
    return float(kp), float(kd)


def _keyframe(m: mujoco.MjModel, key: str | None) -> np.ndarray | None:
    names = [m.key(i).name for i in range(m.nkey)]
    if key is not None:
        if key not in names:
            raise ValueError(f"home_key {key!r} is not a keyframe of the model; keyframes: {names}")
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
    floating = _floating(m, desc.base_body_id)
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
    radii = np.array(desc.foot_radii)
    low = float(np.min(d.geom_xpos[list(desc.foot_geom_ids), 2] - radii))
    floor = max(float(d.geom_xpos[f, 2]) for f in desc.floor_geom_ids)
    height = float(d.xpos[desc.base_body_id, 2]) - low
    if floating:
        q[2] += floor - low + 1e-3
    kp, kd = _gains(m, desc, settings, height)
    act_dof, bias = _actuator_law(m)
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
    gap = d.geom_xpos[list(desc.foot_geom_ids), 2] - radii - floor
    upright = not floating or 1.0 - 2.0 * (out[4] ** 2 + out[5] ** 2) > 0.9
    if not (np.all(np.isfinite(out)) and upright and np.all(gap < 0.01)):
        raise ValueError(
            f"robot {robot.name!r} has no standing pose (no keyframe) and did not settle"
            f" standing in {seconds} s from qpos0 (feet {np.round(gap, 3).tolist()} m above"
            " the floor); pass GaitSettings(home_qpos=...) or home_key"
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
    elif _floating(m, desc.base_body_id):
        height = float(home[2])
    else:
        feet = _feet_in_base(m, desc, home)
        height = float(-np.min(feet[:, 2]) + desc.foot_radii[0])
    try:
        kp, kd = _gains(m, desc, s, height)
    except ValueError:  # actuators the gaits cannot drive: the pose is still useful
        kp, kd = s.kp, s.kd  # make_gait_robot names the actuator
    return dataclasses.replace(
        s, home_qpos=tuple(float(x) for x in home), base_height=height, kp=kp, kd=kd
    )


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


@struct.dataclass
class GaitRobot:
    """What the gait controller needs to know about one robot (from its MuJoCo model).

    Kinematic chains are padded to a common length ``n_chain`` with fixed identity links.

    Attributes:
      link_pos: (n_legs, n_chain, 3) each chain body's position in its parent, m.
      link_rot: (n_legs, n_chain, 3, 3) its orientation in its parent.
      joint_pos: (n_legs, n_chain, 3) the body's hinge anchor in the body frame, m.
      joint_axis: (n_legs, n_chain, 3) the hinge axis in the body frame (unit).
      joint_slot: (n_legs, n_chain) int32, which of the leg's joints the hinge is (-1: none).
      foot_offset: (n_legs, 3) foot sphere centre in the last chain body, m.
      leg_qpos: (n_legs, n_l) int32 ``qpos`` index of each leg joint.
      leg_dof: (n_legs, n_l) int32 ``qvel`` index of each leg joint.
      q_home: (n_legs, n_l) joint angles of the standing pose, rad (the IK's start).
      q_low, q_high: (n_legs, n_l) joint ranges, rad (+-inf where unlimited).
      foot_home: (n_legs, 3) foot centres in the base frame at the standing pose, m.
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
    floating = _floating(m, desc.base_body_id)
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
            slot = desc.leg_dofs[i].index(int(m.jnt_dofadr[j]))
            joint_pos[i, kk] = m.jnt_pos[j]
            joint_axis[i, kk] = m.jnt_axis[j]
            joint_slot[i, kk] = slot
            leg_qpos[i, slot] = m.jnt_qposadr[j]
            leg_dof[i, slot] = m.jnt_dofadr[j]
            if m.jnt_limited[j]:
                q_low[i, slot], q_high[i, slot] = m.jnt_range[j]

    # Foot positions at the standing pose, in the base frame, from MuJoCo itself.
    foot_home = _feet_in_base(m, desc, home)
    q_home = home[leg_qpos]

    # Leg roles from the standing feet: front is +x, left is +y of the base.
    front = foot_home[:, 0] > np.mean(foot_home[:, 0])
    left = foot_home[:, 1] > np.mean(foot_home[:, 1])
    trot = np.where(front == left, 0.0, 0.5)  # FL & HR together, FR & HL half a cycle later
    # Lateral sequence: left-hind lifts first, then left-front, right-hind, right-front, a
    # quarter cycle apart. A leg whose phase is ahead by x lifts x of a cycle earlier, so
    # the offset is minus the delay.
    walk_delay = {(False, True): 0.0, (True, True): 0.25, (False, False): 0.5, (True, False): 0.75}
    walk = np.array(
        [(1.0 - walk_delay[(bool(f), bool(lf))]) % 1.0 for f, lf in zip(front, left, strict=True)]
    )
    if n_legs != 4:
        trot = np.zeros(n_legs)
        walk = np.arange(n_legs) / n_legs
    phase_offset = np.stack([trot, walk, np.zeros(n_legs)])

    # Actuators: affine force law, no activation dynamics, on one joint each.
    nu = int(m.nu)
    act_dof, bias = _actuator_law(m)
    limited = m.actuator_ctrllimited.astype(bool)
    ctrl_low = np.where(limited, m.actuator_ctrlrange[:, 0], -np.inf)
    ctrl_high = np.where(limited, m.actuator_ctrlrange[:, 1], np.inf)

    f32 = lambda x: jnp.asarray(x, dtype=jnp.float32)  # noqa: E731
    return GaitRobot(
        link_pos=f32(link_pos),
        link_rot=f32(link_rot),
        joint_pos=f32(joint_pos),
        joint_axis=f32(joint_axis),
        joint_slot=jnp.asarray(joint_slot),
        foot_offset=f32(np.array(desc.foot_offsets)),
        leg_qpos=jnp.asarray(leg_qpos),
        leg_dof=jnp.asarray(leg_dof),
        q_home=f32(q_home),
        q_low=f32(q_low),
        q_high=f32(q_high),
        foot_home=f32(foot_home),
        phase_offset=f32(phase_offset),
        base_height=f32(base_height),
        foot_radius=f32(desc.foot_radii[0]),
        mass=f32(float(np.sum(m.body_mass))),
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


def _damped_solve(jac: jax.Array, rhs: jax.Array, damping: float = 1e-4) -> jax.Array:
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
        return q + _damped_solve(jac, err, damping)

    q = jax.lax.fori_loop(0, iterations, body, robot.q_home[leg])
    return jnp.clip(q, robot.q_low[leg], robot.q_high[leg])


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
        qd_des = _damped_solve(jac_des, target_vel)
        q = qpos[robot.leg_qpos[leg]]
        qd = qvel[robot.leg_dof[leg]]
        # The floor pushes the foot up with `force`; the joints hold it: tau = -J^T f.
        jac = jax.jacfwd(fk)(q)
        return robot.kp * (q_des - q) + robot.kd * (qd_des - qd) - jac.T @ force

    legs = jnp.arange(robot.n_legs)
    tau_legs = jax.vmap(leg_torque)(legs, targets, target_vel, force_b)
    tau = jnp.zeros(qvel.shape[0]).at[robot.leg_dof].set(tau_legs)

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
