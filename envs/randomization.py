"""Domain randomisation around the contact wrapper.

Playground's ``BraxDomainRandomizationVmapWrapper`` and Brax's
``DomainRandomizationVmapWrapper`` give each env its randomised model by setting it on
``env.unwrapped`` (Playground's ``_mjx_model``, Brax's ``sys``) and then step
``env.unwrapped`` itself: every wrapper in between is skipped, the contact wrapper too. The
observation then lacks the contact slots that ``observation_size`` counts, and no
``contact_est/*`` metric is made. The two classes here set the model where theirs do and
step the whole chain they wrap; :func:`wrap_for_brax_training` (Playground) and
:func:`wrap_for_training` (Brax) are the frameworks' training wrappers with them. Pass
either as Brax PPO's ``wrap_env_fn`` with a ``randomization_fn``::

    ppo.train(wrapped, ..., randomization_fn=rand, wrap_env_fn=wrap_for_brax_training)

The estimator keeps the nominal model it was wrapped with (domain randomisation changes
the simulated robot, never the estimator's model: :mod:`jax_contact.envs.wrapper`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

from brax.envs.wrappers import training as brax_training
from mujoco_playground._src import wrapper as pg_wrapper


@contextlib.contextmanager
def _set(obj, attr: str, value):
    """``obj.attr = value`` for the ``with`` block, then restored."""
    old = getattr(obj, attr)
    try:
        setattr(obj, attr, value)
        yield
    finally:
        setattr(obj, attr, old)


class PlaygroundRandomization(pg_wrapper.BraxDomainRandomizationVmapWrapper):
    """Playground's domain randomisation, stepping the wrapped chain (module docstring)."""

    @contextlib.contextmanager
    def v_env_fn(self, mjx_model):
        # Where Playground's own randomisation puts the model (MjxEnv has no public setter).
        with _set(self.env.unwrapped, "_mjx_model", mjx_model):
            yield self.env


class BraxRandomization(brax_training.DomainRandomizationVmapWrapper):
    """Brax's domain randomisation, stepping the wrapped chain (module docstring)."""

    @contextlib.contextmanager
    def v_env_fn(self, new_sys):
        with _set(self.env.unwrapped, "sys", new_sys):
            yield self.env


def wrap_for_brax_training(
    env,
    episode_length: int = 1000,
    action_repeat: int = 1,
    randomization_fn: Callable | None = None,
    full_reset: bool = False,
):
    """Playground's ``wrap_for_brax_training`` (same arguments; its vision options aside),
    with :class:`PlaygroundRandomization` for ``randomization_fn``."""
    if randomization_fn is None:
        env = brax_training.VmapWrapper(env)
    else:
        env = PlaygroundRandomization(env, randomization_fn)
    env = brax_training.EpisodeWrapper(env, episode_length, action_repeat)
    return pg_wrapper.BraxAutoResetWrapper(env, full_reset=full_reset)


def wrap_for_training(
    env,
    episode_length: int = 1000,
    action_repeat: int = 1,
    randomization_fn: Callable | None = None,
):
    """Brax's ``brax.envs.training.wrap`` (same arguments), with :class:`BraxRandomization`
    for ``randomization_fn``."""
    if randomization_fn is None:
        env = brax_training.VmapWrapper(env)
    else:
        env = BraxRandomization(env, randomization_fn)
    env = brax_training.EpisodeWrapper(env, episode_length, action_repeat)
    return brax_training.AutoResetWrapper(env)
