"""Helpers shared by the wrapper tests (tests/test_wrapper*.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from ml_collections import config_dict
from mujoco import mjx
from mujoco_playground._src import mjx_env


def _strong(x: jax.Array) -> jax.Array:
    return jax.lax.convert_element_type(x, x.dtype)


class Traced:
    """``jax.jit(fn)`` that counts its traces and returns strongly typed arrays.

    Playground's Go1 returns one weakly typed metric from ``step`` and a strong one from
    ``reset``, which would compile ``step`` twice; casting the outputs keeps one compile.
    ``traces`` checks that the wrapped functions do not retrace in a loop.
    """

    def __init__(self, fn):
        self.traces = 0

        def counted(*args):
            self.traces += 1
            out = fn(*args)
            # jnp.asarray first: an env may return a Python number (Berkeley Humanoid's info).
            return jax.tree.map(lambda x: _strong(jnp.asarray(x)), out)

        self._jitted = jax.jit(counted)

    def __call__(self, *args):
        return self._jitted(*args)


def logit_of(state, key="contact_est"):
    """(n_envs, n_feet) belief logits the wrapper keeps under ``state.info[key]``."""
    return np.asarray(state.info[key].belief.logit)


class PlaygroundLeg(mjx_env.MjxEnv):
    """The planar leg as a minimal Playground env (dict observation), for the refusals."""

    def __init__(self, mj_model: mujoco.MjModel, n_substeps: int):
        dt = float(mj_model.opt.timestep)
        super().__init__(config_dict.create(ctrl_dt=dt * n_substeps, sim_dt=dt))
        self._mj = mj_model
        self._mjx_model = mjx.put_model(mj_model)

    def reset(self, rng):
        # From the model's home keyframe (the planar leg's qpos0 puts the foot 0.52 m
        # inside the floor, a start no physics has).
        data = mjx_env.make_data(self._mj, impl="jax")
        if self._mj.nkey:
            data = data.replace(qpos=jnp.asarray(self._mj.key_qpos[0], data.qpos.dtype))
        data = mjx.forward(self._mjx_model, data)
        zero = jnp.zeros(())
        obs = {"state": jnp.concatenate([data.qpos, data.qvel])}
        return mjx_env.State(data, obs, zero, zero, {}, {"rng": rng})

    def step(self, state, action):
        data = mjx_env.step(self._mjx_model, state.data, action, self.n_substeps)
        return state.replace(data=data, obs={"state": jnp.concatenate([data.qpos, data.qvel])})

    @property
    def xml_path(self) -> str:
        return ""

    @property
    def action_size(self) -> int:
        return self._mj.nu

    @property
    def mj_model(self):
        return self._mj

    @property
    def mjx_model(self):
        return self._mjx_model
