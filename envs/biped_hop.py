"""A closed-loop scripted policy for Berkeley Humanoid: hopping in place on both feet.

No open-loop motion keeps Playground's Berkeley Humanoid up: its ankle-roll actuators have
kp = 1 N m/rad, so one foot cannot hold it, and even standing at the home pose it falls
backwards within a second (docs/training.md). To measure the wrapped estimator on a
biped's flat feet without a trained policy, this module hops it in place with both feet
together, a Raibert-style controller (Raibert, *Legged Robots That Balance*, 1986) on the
env's own position actuators:

- **feedforward** (:func:`feedforward`): hip pitch, knee and ankle pitch of both legs
  follow ``h sin(2 pi f t)`` (knee ``-2 h``, ankle ``ankle h``): a squat and a push that
  lifts both feet off the floor;
- **stance feedback** (either foot's floor sensor on): torso pitch ``theta`` and its rate
  to hip pitch (``k_t``, ``k_td``) and ankle pitch (``k_a``, ``k_d``), torso roll and its
  rate to hip abduction (``k_r``, ``k_rd``): the attitude servo;
- **flight feedback**: the base velocity in the heading frame to hip pitch (``k_x``) and
  hip abduction (``k_y``): where the feet land, which brakes the drift.

The stance flag reads the simulator's contact sensors: this is a scripted policy with
privileged state, used to generate motion, not an estimator.

The gains (:data:`BERKELEY_HOP`) were fitted by a cross-entropy search in MuJoCo (C) on
the env's model (:func:`run_mujoco`; ``benchmarks/biped_hop_fit.py``), on 10 resets
drawn as the env draws them (random yaw, joint angles x U(0.5, 1.5), base velocity
U(-0.5, 0.5)), objective: time upright over 4 s plus twice the share of steps each foot
spends in the air (capped at 0.2). On 40 resets it was not fitted on, 32 (80 %) were
upright after 6 s; 7 of the other 8 fell within 1.4 s, still recovering from the reset,
one at 3.4 s. From the standing pose at rest, 9 of 10 starting phases stay up. It hops
at 3.4 Hz, each foot in the air 58 % of the time, lifting off twice a cycle (the landing
bounces once).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class HopGains:
    """Gains of the hop (module docstring); angles rad, rates rad/s, velocities m/s.

    Attributes:
      freq: hop frequency, Hz.
      amplitude: ``h``, hip pitch amplitude of the squat, rad (knee ``-2 h``).
      ankle: ankle pitch amplitude as a multiple of ``h``.
      k_t, k_td: torso pitch (rad) and pitch rate (rad/s) to hip pitch, in stance.
      k_a, k_d: the same to ankle pitch, in stance.
      k_r, k_rd: torso roll and roll rate to hip abduction, in stance.
      k_x, k_y: heading-frame base velocity, forward and lateral (m/s), to hip pitch and
        hip abduction (rad), in flight.
    """

    freq: float
    amplitude: float
    ankle: float
    k_t: float
    k_td: float
    k_a: float
    k_d: float
    k_r: float
    k_rd: float
    k_x: float
    k_y: float


@dataclasses.dataclass(frozen=True)
class LegLayout:
    """Actuator indices of each leg's joints, left then right (position actuators)."""

    hip_abduction: tuple[int, int]
    hip_pitch: tuple[int, int]
    knee: tuple[int, int]
    ankle_pitch: tuple[int, int]
    n_actuators: int


# Berkeley Humanoid (Playground): per leg HR, HAA, HFE, KFE, FFE, FAA; left 0-5, right 6-11.
BERKELEY_LEGS = LegLayout(
    hip_abduction=(1, 7), hip_pitch=(2, 8), knee=(3, 9), ankle_pitch=(4, 10), n_actuators=12
)
BERKELEY_HOP = HopGains(
    freq=3.436,
    amplitude=0.374,
    ankle=0.841,
    k_t=1.222,
    k_td=0.129,
    k_a=3.508,
    k_d=0.377,
    k_r=-2.836,
    k_rd=-0.221,
    k_x=-1.486,
    k_y=-1.416,
)


def feedforward(
    t: np.ndarray,
    rate: np.ndarray,
    phase0: np.ndarray,
    gains: HopGains = BERKELEY_HOP,
    legs: LegLayout = BERKELEY_LEGS,
) -> np.ndarray:
    """Joint position offsets of the squat-and-push, rad.

    Args:
      t: (T, 1) times, s.
      rate: (E,) frequency multipliers of the rollouts (1 = ``gains.freq``).
      phase0: (E,) phase of each rollout's cycle at t = 0, in cycles.
      gains: the hop.
      legs: the actuator layout.

    Returns:
      (T, E, n_actuators) offsets from the standing pose.
    """
    c = np.sin(2 * np.pi * (gains.freq * rate * t + phase0))
    out = np.zeros(c.shape + (legs.n_actuators,))
    h = gains.amplitude
    for joints, scale in (
        (legs.hip_pitch, h),
        (legs.knee, -2.0 * h),
        (legs.ankle_pitch, gains.ankle * h),
    ):
        for j in joints:
            out[..., j] = scale * c
    return out


def tilt_and_velocity(qpos: jnp.ndarray, qvel: jnp.ndarray) -> dict[str, jnp.ndarray]:
    """Torso tilt, body rates and heading-frame velocity of a floating base.

    Args:
      qpos: (nq,) with the free joint first (position, quaternion w x y z).
      qvel: (nv,) with the free joint first (world linear velocity, body angular velocity).

    Returns:
      ``roll``, ``pitch`` (rad; the gravity direction in the base frame, so that a
      rotation by a small angle about the base's x (y) axis gives that roll (pitch)),
      ``roll_rate``, ``pitch_rate`` (rad/s, body x and y), ``vx``, ``vy`` (m/s, the
      world velocity in the frame turned by the base's yaw).
    """
    w, x, y, z = qpos[3], qpos[4], qpos[5], qpos[6]
    # Third row of the rotation matrix (world z in base coordinates) and its yaw.
    gx = 2 * (x * z - w * y)
    gy = 2 * (y * z + w * x)
    yaw = jnp.arctan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return {
        "roll": jnp.arcsin(jnp.clip(gy, -1.0, 1.0)),
        "pitch": -jnp.arcsin(jnp.clip(gx, -1.0, 1.0)),
        "roll_rate": qvel[3],
        "pitch_rate": qvel[4],
        "vx": c * qvel[0] + s * qvel[1],
        "vy": -s * qvel[0] + c * qvel[1],
    }


def feedback(
    qpos: jnp.ndarray,
    qvel: jnp.ndarray,
    stance: jnp.ndarray,
    gains: HopGains = BERKELEY_HOP,
    legs: LegLayout = BERKELEY_LEGS,
) -> jnp.ndarray:
    """Joint position offsets of the hop's feedback (module docstring), rad.

    Args:
      qpos, qvel: the robot's state (free joint first), as :func:`tilt_and_velocity`.
      stance: () bool, a foot is on the floor.
      gains: the hop.
      legs: the actuator layout.

    Returns:
      (n_actuators,) offsets, added to :func:`feedforward`'s.
    """
    st = tilt_and_velocity(qpos, qvel)
    hip = jnp.where(
        stance,
        gains.k_t * st["pitch"] + gains.k_td * st["pitch_rate"],
        gains.k_x * st["vx"],
    )
    ankle = jnp.where(stance, gains.k_a * st["pitch"] + gains.k_d * st["pitch_rate"], 0.0)
    abduction = jnp.where(
        stance,
        gains.k_r * st["roll"] + gains.k_rd * st["roll_rate"],
        gains.k_y * st["vy"],
    )
    out = jnp.zeros(legs.n_actuators, jnp.result_type(qpos))
    for joints, value in (
        (legs.hip_pitch, hip),
        (legs.ankle_pitch, ankle),
        (legs.hip_abduction, abduction),
    ):
        out = out.at[jnp.asarray(joints)].set(value)
    return out


def fallen(qpos: jnp.ndarray, min_height: float = 0.3, max_tilt: float = 0.8) -> jnp.ndarray:
    """() bool: the base is below ``min_height`` (m) or tilted over ``max_tilt`` (rad).

    The tilt is the angle between the base's z axis and the world's (Berkeley Humanoid
    stands with its base at 0.5 m and upright).
    """
    x, y = qpos[4], qpos[5]
    cos_tilt = 1 - 2 * (x * x + y * y)
    return (qpos[2] < min_height) | (cos_tilt < jnp.cos(max_tilt))


@dataclasses.dataclass(frozen=True)
class HopRun:
    """Outcome of :func:`run_mujoco`.

    Attributes:
      upright_s: time until :func:`fallen` first held at a control step, or the whole
        run, s.
      air_share: (2,) share of the physics steps each foot (left, right) spent off the
        floor (its ``*_foot1_floor_found`` sensor at 0), over the upright time.
      liftoffs: (2,) lift-offs of each foot (sensor on -> off) over the upright time.
    """

    upright_s: float
    air_share: np.ndarray
    liftoffs: np.ndarray


def stance_sensors(mj_model) -> np.ndarray:
    """(2,) ``sensordata`` addresses of the ``l_``/``r_foot1_floor_found`` sensors: the hop
    is in stance when either reads > 0."""
    return np.array(
        [mj_model.sensor_adr[mj_model.sensor(f"{s}_foot1_floor_found").id] for s in "lr"]
    )


def env_like_reset(mj_model, data, rng: np.random.Generator, keyframe: int = 0) -> None:
    """Resets ``data`` as Playground's Berkeley Humanoid joystick env does (its ``reset``).

    Yaw U(-pi, pi), joint angles of the keyframe times U(0.5, 1.5), base velocity (linear
    and angular) U(-0.5, 0.5); the actuators' targets at the joint angles. (The env also
    shifts x and y by U(-0.5, 0.5) m, which a flat floor does not feel.)
    """
    import mujoco

    mujoco.mj_resetDataKeyframe(mj_model, data, keyframe)
    pose = data.qpos[7:].copy()
    yaw = rng.uniform(-3.14, 3.14)
    data.qpos[3:7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
    data.qpos[7:] = pose * rng.uniform(0.5, 1.5, pose.shape)
    data.qvel[:6] = rng.uniform(-0.5, 0.5, 6)
    data.ctrl[:] = data.qpos[7:]


def run_mujoco(
    env,
    gains: HopGains = BERKELEY_HOP,
    *,
    t_end: float = 4.0,
    phase0: float = 0.0,
    rate: float = 1.0,
    reset_rng: np.random.Generator | None = None,
    legs: LegLayout = BERKELEY_LEGS,
) -> HopRun:
    """Runs the hop on the env's model in MuJoCo (C), at the env's control period.

    Args:
      env: Playground's ``BerkeleyHumanoidJoystickFlatTerrain`` (its ``mj_model``, ``dt``
        and ``*_foot1_floor_found`` sensors are used; its ``step`` is not).
      gains: the hop.
      t_end: duration, s.
      phase0, rate: as :func:`feedforward`'s for this rollout.
      reset_rng: draws an env-like reset (:func:`env_like_reset`); None starts at rest
        in the keyframe ``home``.
      legs: the actuator layout.

    Returns:
      The run's :class:`HopRun`.
    """
    import mujoco

    m = env.mj_model
    d = mujoco.MjData(m)
    home = m.keyframe("home")
    pose = home.qpos[7:].copy()
    if reset_rng is None:
        mujoco.mj_resetDataKeyframe(m, d, home.id)
    else:
        env_like_reset(m, d, reset_rng, home.id)
    mujoco.mj_forward(m, d)
    adr = stance_sensors(m)
    fb = _jitted_feedback(legs)
    dt = float(env.dt)
    n_sub = int(round(dt / m.opt.timestep))
    n = int(round(t_end / dt))
    ff = feedforward(np.arange(n)[:, None] * dt, np.full(1, rate), np.full(1, phase0), gains, legs)
    air, lifts, prev = np.zeros(2), np.zeros(2, int), np.ones(2, bool)
    steps, upright = 0, t_end
    for k in range(n):
        stance = bool((d.sensordata[adr] > 0).any())
        d.ctrl[:] = pose + ff[k, 0] + np.asarray(fb(d.qpos, d.qvel, stance, gains))
        for _ in range(n_sub):
            mujoco.mj_step(m, d)
            on = d.sensordata[adr] > 0
            lifts += prev & ~on
            air += ~on
            prev = on
            steps += 1
        if bool(fallen(d.qpos)):
            upright = (k + 1) * dt
            break
    return HopRun(upright_s=upright, air_share=air / steps, liftoffs=lifts)


@functools.cache
def _jitted_feedback(legs: LegLayout):
    """:func:`feedback` for one layout, jitted once per process (the gains are traced)."""
    return jax.jit(functools.partial(feedback, legs=legs))
