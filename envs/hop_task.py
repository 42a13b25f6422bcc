"""Hopping to a commanded apex height: a small task where contact timing matters.

The planar leg of Hwangbo et al. (Section III, ``envs/assets/planar_leg.xml``: a base on a
vertical rail, hip and knee) under joint position servos hops so that the base reaches a
commanded apex height ``h_cmd`` above the floor. Energy can only enter through the foot
while it is on the ground: a knee extension in flight only moves the leg, one in stance
pushes the base up, so the thrust is well timed only by a policy that knows (or infers)
when the foot touches down and lifts off.

:class:`HopEnv` is a :class:`jax_contact.envs.legged_env.LeggedPipelineEnv` (the planar leg with its
ground-truth contact sensors, position servos, ``n_frames`` physics steps per env step)
with:

- observation: the leg env's own (hip, knee angles; rail, hip, knee velocities; the rail
  velocity left out in :data:`HOP_BLIND`) and the command as ``h_cmd - 0.6`` m. The base
  height is *not* observed (a robot does not measure its height above the ground), so
  contact cannot be read off the foot's height; with the rail velocity it can still be
  inferred from the stance kinematics (``HopConfig.observe_rail_velocity``);
  :func:`make_hop_env` wraps it with :func:`jax_contact.envs.wrapper.wrap_contact`, which appends
  one number for ``observe="truth"`` or ``"estimate"`` and nothing for ``"none"``;
- action in [-1, 1]^2: joint targets ``home + action_scale * action`` (clipped);
- reward per step: ``exp(-((h_pred - h_cmd) / sigma)^2)`` with the ballistic apex of the
  current state ``h_pred = z + max(vz, 0)^2 / (2 g)`` (:func:`hop_reward`): constant and
  equal to the coming apex during a flight, the base height during stance. Hopping to
  ``h_cmd`` scores ~1 in flight; standing on a straight leg (base at most 0.52 m) scores
  ``exp(-((0.52 - h_cmd) / sigma)^2)``;
- reset: at rest, joints at the home pose, base dropped from a random height in
  ``drop_range`` (so the first touchdown time varies), ``h_cmd`` uniform in ``cmd_range``;
  ``state.info["h_cmd"]`` holds the command;
- done: non-finite state or base below ``min_base_height``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs import base as brax_base

from jax_contact.envs.legged_env import LeggedPipelineEnv

GRAVITY = 9.81
CMD_OFFSET = 0.6  # m, subtracted from h_cmd in the observation
INFO_KEY = "contact_est"


@dataclasses.dataclass(frozen=True)
class HopConfig:
    """The hop task.

    Attributes:
      n_frames: physics steps (2.5 ms) per env step: 4 = 10 ms, 100 Hz control.
      servo: (kp N m/rad, kv N m s/rad) of the joint position servos (torque limit 30 N m).
      action_scale: rad of joint target per unit action, about the home pose.
      cmd_range: (low, high) commanded apex base height, m.
      drop_range: (low, high) initial base height, m (home pose, at rest).
      sigma: width of the tracking reward, m.
      min_base_height: done below this base height, m.
      episode_length: env steps per episode (3 s at 10 ms: several hops).
      sensor: sensor preset of the estimator's inputs (:data:`jax_contact.envs.sensors.PRESETS`).
      observe_rail_velocity: whether the observation holds the base's (rail) velocity.
        With it, a policy can read stance off a single observation (in stance the rail
        velocity is the leg's kinematic velocity of the joint rates, the foot fixed);
        without it (:data:`HOP_BLIND`, task ``"hop_blind"``), contact is known only from
        the contact observation or inferred from the joints alone.
    """

    n_frames: int = 4
    servo: tuple[float, float] = (300.0, 8.0)
    action_scale: float = 0.8
    cmd_range: tuple[float, float] = (0.55, 0.70)
    drop_range: tuple[float, float] = (0.45, 0.60)
    sigma: float = 0.1
    min_base_height: float = 0.2
    episode_length: int = 300
    sensor: str = "anymal_like"
    observe_rail_velocity: bool = True


HOP = HopConfig()
HOP_BLIND = HopConfig(observe_rail_velocity=False)
# ``jax-contact train --task`` names of the hop tasks -> their configuration.
TASK_CONFIGS = {"hop": HOP, "hop_blind": HOP_BLIND}


def task_config(task: str) -> HopConfig:
    """The :class:`HopConfig` of a hop task name (a key of :data:`TASK_CONFIGS`)."""
    if task not in TASK_CONFIGS:
        raise ValueError(f"hop task must be one of {tuple(TASK_CONFIGS)}, got {task!r}")
    return TASK_CONFIGS[task]


def hop_reward(z, vz, h_cmd, sigma):
    """``exp(-((z + max(vz, 0)^2 / (2 g) - h_cmd) / sigma)^2)``: the tracking reward."""
    h_pred = z + jnp.maximum(vz, 0.0) ** 2 / (2.0 * GRAVITY)
    return jnp.exp(-(((h_pred - h_cmd) / sigma) ** 2))


def hop_robot():
    """The planar leg with its ground-truth contact sensors."""
    from jax_contact.envs import ground_truth
    from jax_contact.envs.robots import load_robot

    return ground_truth.with_contact_sensors(load_robot("planar_leg"))


class HopEnv(LeggedPipelineEnv):
    """The hop task as a Brax ``PipelineEnv`` (module docstring)."""

    def __init__(self, config: HopConfig = HOP, robot=None):
        robot = robot if robot is not None else hop_robot()
        super().__init__(
            robot,
            n_frames=config.n_frames,
            position_servo=config.servo,
            min_base_height=config.min_base_height,
        )
        self.config = config
        home = np.asarray(robot.home_qpos, dtype=np.float32)
        self._home_q = jnp.asarray(home)
        self._home_joints = jnp.asarray(home[1:])

    @property
    def observation_size(self) -> int:
        return super().observation_size + 1 - (not self.config.observe_rail_velocity)

    def _obs(self, ps) -> jax.Array:
        if self.config.observe_rail_velocity:
            return super()._obs(ps)
        # (hip, knee angles; hip, knee velocities): the rail's slide joint left out.
        return jnp.concatenate([ps.qpos[self._n_base_q :], ps.qvel[self._n_base_q :]])

    @property
    def action_size(self) -> int:
        return 2

    def _with_cmd(self, obs, h_cmd):
        return jnp.concatenate([obs, jnp.reshape(h_cmd - CMD_OFFSET, (1,))])

    def reset(self, rng: jax.Array) -> brax_base.State:
        c = self.config
        k_cmd, k_drop = jax.random.split(rng)
        h_cmd = jax.random.uniform(k_cmd, (), minval=c.cmd_range[0], maxval=c.cmd_range[1])
        z0 = jax.random.uniform(k_drop, (), minval=c.drop_range[0], maxval=c.drop_range[1])
        qpos = self._home_q.at[0].set(z0)
        ps = self.pipeline_init(qpos, jnp.zeros(self.sys.nv), ctrl=self._home_joints)
        obs = self._with_cmd(self._obs(ps), h_cmd)
        zero = jnp.zeros(())
        metrics = {"tracking": zero, "h_pred": zero}
        return brax_base.State(ps, obs, zero, zero, metrics, {"h_cmd": h_cmd})

    def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
        c = self.config
        target = self._home_joints + c.action_scale * jnp.clip(action, -1.0, 1.0)
        h_cmd = state.info["h_cmd"]
        leg_state = state.replace(obs=state.obs[:-1])
        nxt = super().step(leg_state, target)
        ps = nxt.pipeline_state
        z, vz = ps.qpos[0], ps.qvel[0]
        r = hop_reward(z, vz, h_cmd, c.sigma)
        h_pred = z + jnp.maximum(vz, 0.0) ** 2 / (2.0 * GRAVITY)
        metrics = dict(state.metrics, tracking=r, h_pred=h_pred)
        return nxt.replace(obs=self._with_cmd(nxt.obs, h_cmd), reward=r, metrics=metrics)


def make_hop_env(
    observe: str,
    config: HopConfig = HOP,
    *,
    sensor=None,
    robot=None,
):
    """The hop env with the contact wrapper, observing ``observe`` (none/truth/estimate).

    Args:
      observe: ``"none"``, ``"truth"`` or ``"estimate"``.
      config: the task.
      sensor: the estimator's sensor model (a preset name or an
        :class:`jax_contact.envs.sensors.SensorParams`); None: ``config.sensor``.
      robot: the robot (default :func:`hop_robot`), to build several envs from one model.
    """
    from jax_contact.envs import wrapper as W

    cfg = W.ContactObsConfig(observe=observe, info_key=INFO_KEY)
    return W.wrap_contact(HopEnv(config, robot), cfg, sensor=sensor or config.sensor)


def sensor_with_extra_latency(robot, preset: str, extra_steps: int, config: HopConfig = HOP):
    """The preset's sensor model with ``extra_steps`` env steps (``n_frames`` physics steps
    each) of additional reading delay, at the physics period."""
    from jax_contact.envs.contact_params import default_sensor_params, with_extra_latency

    dt = float(robot.mj_model.opt.timestep)
    p = default_sensor_params(preset, robot, dt)
    return with_extra_latency(p, int(extra_steps), config.n_frames * dt)
