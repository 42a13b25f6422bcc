"""A minimal Brax ``PipelineEnv`` over a project robot, for the wrapper's tests and rates."""

from __future__ import annotations

import copy
import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs import base as brax_base
from brax.io import mjcf as brax_mjcf

from jax_contact.envs.contact_params import floating_base
from jax_contact.envs.robots import Robot


class LeggedPipelineEnv(brax_base.PipelineEnv):
    """A minimal Brax ``PipelineEnv`` over a :class:`jax_contact.envs.robots.Robot`: actions are
    ``ctrl``.

    The project's own kind of environment for the wrapper's substep rate, its tests and
    :func:`compare_rates`: it starts at the robot's home pose at rest, observes the true
    joint positions (after the base coordinates) and all velocities, gives no reward, and
    is done when the state is not finite or the base falls below ``min_base_height``.

    Args:
      robot: the robot (add ground-truth sensors with
        :func:`jax_contact.envs.ground_truth.with_contact_sensors` first to get truth).
      n_frames: physics steps per env step.
      position_servo: (kp N m/rad, kv N m s/rad): turn every joint actuator into a position
        servo with these gains, keeping its force limits (the planar leg's torque motors),
        so that actions are joint targets; None keeps the actuators as they are.
      min_base_height: done below this base height, m; None: never.
    """

    def __init__(
        self,
        robot: Robot,
        *,
        n_frames: int = 1,
        position_servo: tuple[float, float] | None = None,
        min_base_height: float | None = None,
    ):
        mj_model = robot.mj_model
        if position_servo is not None:
            kp, kv = (float(x) for x in position_servo)
            spec = robot.spec.copy()
            for a in spec.actuators:
                limit = np.array(a.ctrlrange) * float(a.gear[0])
                a.set_to_position(kp=kp, kv=kv)
                a.forcelimited = 1
                a.forcerange = limit
                a.ctrllimited = 0
            timestep = mj_model.opt.timestep
            mj_model = spec.compile()
            mj_model.opt.timestep = timestep
        # brax.io.mjcf.load_model writes into the model it is given.
        sys = brax_mjcf.load_model(copy.deepcopy(mj_model))
        super().__init__(sys, backend="mjx", n_frames=n_frames)
        self._robot_mj_model = mj_model
        # The robot's own standing pose (load_robot(..., gait=GaitSettings(home_qpos=...))):
        # rebuilding the Robot from the model alone dropped its gait settings, and a user's
        # pose gave way to the keyframe or a settle. The servo's model settles the same way.
        home = (
            robot if mj_model is robot.mj_model else dataclasses.replace(robot, mj_model=mj_model)
        )
        self._home = jnp.asarray(home.home_qpos)
        self._n_base_q = 7 if floating_base(mj_model) else len(robot.description.base_dofs)
        self._base_z = 2 if floating_base(mj_model) else 0
        self._min_base_height = min_base_height
        key = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_KEY, "home")
        ctrl = mj_model.key_ctrl[key] if key >= 0 else np.zeros(mj_model.nu)
        self._home_ctrl = jnp.asarray(ctrl, dtype=jnp.float32)

    @property
    def mj_model(self) -> mujoco.MjModel:
        return self._robot_mj_model

    @property
    def observation_size(self) -> int:
        # PipelineEnv's default runs an (eager, slow) reset to find out.
        return self.sys.nq - self._n_base_q + self.sys.nv

    def _obs(self, ps) -> jax.Array:
        return jnp.concatenate([ps.qpos[self._n_base_q :], ps.qvel])

    def _done(self, ps) -> jax.Array:
        bad = ~(jnp.all(jnp.isfinite(ps.qpos)) & jnp.all(jnp.isfinite(ps.qvel)))
        if self._min_base_height is not None:
            bad = bad | (ps.qpos[self._base_z] < self._min_base_height)
        return bad.astype(jnp.float32)

    def reset(self, rng: jax.Array) -> brax_base.State:
        del rng  # deterministic start
        ps = self.pipeline_init(self._home, jnp.zeros(self.sys.nv), ctrl=self._home_ctrl)
        zero = jnp.zeros(())
        return brax_base.State(ps, self._obs(ps), zero, zero, {}, {})

    def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
        ps = self.pipeline_step(state.pipeline_state, action)
        return state.replace(pipeline_state=ps, obs=self._obs(ps), done=self._done(ps))
