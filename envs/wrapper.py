"""Drop-in contact observation wrapper: estimated foot contact in the policy observation.

:func:`wrap_contact` wraps a Brax ``PipelineEnv`` (MJX backend) or a MuJoCo Playground
``MjxEnv`` so that the policy sees, in training, the contact it will see on the robot: the
probability of the estimator of Hwangbo et al. fed by simulated, noisy proprioception, not
the simulator's ground truth. This module is the public face; the parts live in

- :mod:`jax_contact.envs.contact_config`: :class:`ContactObsConfig`, the one object that holds every
  option (feet, sensor model, parameters, force axes, terrain, rate, truth, placement);
- :mod:`jax_contact.envs.feet`: which point of each foot the estimator uses (sphere, box or mesh
sole,
  site, body and offset, several geoms as one foot);
- :mod:`jax_contact.envs.contact_params`: default sensor model, estimator parameters, force axes and
  terrain for a model;
- :mod:`jax_contact.envs.contact_truth`: ground truth from the env's own sensors or its contacts;
- :mod:`jax_contact.envs.contact_core`: the estimator's state (:class:`ContactEstState`) and update;
- :mod:`jax_contact.envs.substeps`: how the physics-rate estimator reaches the substep loop;
- :mod:`jax_contact.envs.contact_wrappers`: the Brax and Playground adapters and
:func:`wrap_contact`;
- :mod:`jax_contact.envs.legged_env`: :class:`LeggedPipelineEnv`, a minimal Brax env over a robot;
- :mod:`jax_contact.envs.randomization`: Playground's and Brax's training wrappers with a domain
  randomisation that steps the contact wrapper (theirs skip it);
- :mod:`jax_contact.train.rates`: ``compare_rates``, physics against control rate on one rollout.

Per estimator update (truth never reaches the observation): the true ``qpos``, ``qvel``,
``qfrc_actuator`` after a physics step go through the sensor model
(:mod:`jax_contact.envs.sensors`); the model is evaluated at the *measured* state on the *nominal*
model the env had when it was wrapped (domain randomisation changes the simulated robot, never the
estimator's model), by default (``pairing="delayed"``) at the state read at the previous update with
the torque read now; :func:`jax_contact.step_robot` updates each foot's belief.

Rates (``ContactObsConfig.rate``, the wrapped env's ``contact_rate`` says which runs):
``"substep"`` (the default, also via ``"auto"``): an update after every physics step, for
Playground and Brax envs alike, by hooking the substep loop for the duration of the
wrapped ``step`` (:mod:`jax_contact.envs.substeps`); ``"control"``: one update per env step with
``dt = env.dt``, coarser (the measured ``qacc`` is a mean over the control period).

State, all in ``state.info`` (the env's own keys, ``info["rng"]`` included, are never
touched): ``info[info_key]`` is a :class:`ContactEstState` (belief, sensor state, PRNG key,
last diagnostics, last readings ``prev``, ``n_skipped`` foot-updates whose readings held a
NaN or inf); with truth, ``info[info_key + "_truth"]`` holds each foot's true contact and
``info[info_key + "_score"]`` the episode's running score (``n`` updates scored, each
counting the share of its feet whose readings were finite, ``hits``, ``mean`` = accuracy
so far; a skipped foot-update is not scored, as ``jax_contact.metrics`` leaves out a log's
lost readings).

Metrics. ``metrics[info_key + "/accuracy"]`` is the *increment* of the episode's running
accuracy (over every estimator update: every physics step at the substep rate, feet
averaged) since the training wrappers' step began, so that Brax's ``EpisodeWrapper`` and
``EvalWrapper``, which sum each metric over an episode once per step of ``action_repeat``
env steps, report the episode's accuracy (``episode_metrics[...]``,
``eval/episode_contact_est/accuracy``), not ~episode length times it. The step is read from
``EpisodeWrapper``'s ``info["steps"]``; without it, each env step is one.

Resets. ``reset`` starts a fresh belief and sensors. The training wrappers' auto-reset
swaps in the first state but carries ``info`` over, so the wrapper also restarts whenever
the state handed to ``step`` differs (bitwise ``qpos``/``qvel``) from the one it returned.

Observation features, per foot in foot order, blocks in this order: ``p_contact``
(n_legs); with ``include_logit`` the logit clipped to ``+-logit_clip``; with
``include_terms`` ``p_dynamics, p_diff_kinematics, p_kinematics, p_takeoff, p_touchdown``
(5 x n_legs, 0.5 without a valid measurement). They are appended to an array observation,
or to each of ``config.obs_keys`` of a dict observation, any set of them (Playground's
policy reads ``"state"``, its critic ``"privileged_state"``). ``observe="truth"`` fills
the same layout with the ground truth, ``observe="none"`` adds nothing.
"""

from __future__ import annotations

from jax_contact.envs.contact_config import (
    OBSERVE,
    PAIRINGS,
    RATES,
    TERM_NAMES,
    TRUTH_SOURCES,
    ContactObsConfig,
    validate_config,
)
from jax_contact.envs.contact_core import ContactEstState, Core, make_core, model_of
from jax_contact.envs.contact_params import (
    choose_force_rows,
    default_estimator_params,
    default_sensor_params,
    default_terrain,
    floating_base,
)
from jax_contact.envs.contact_wrappers import (
    BraxContactWrapper,
    PlaygroundContactWrapper,
    wrap_contact,
)
from jax_contact.envs.feet import FootSpec
from jax_contact.envs.legged_env import LeggedPipelineEnv
from jax_contact.envs.randomization import (
    BraxRandomization,
    PlaygroundRandomization,
    wrap_for_brax_training,
    wrap_for_training,
)


def __getattr__(name):
    # compare_rates moved to jax_contact.train.rates (train sits above envs); kept importable here.
    if name in ("compare_rates", "RateComparison"):
        from jax_contact.train import rates

        return getattr(rates, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "OBSERVE",
    "PAIRINGS",
    "RATES",
    "TERM_NAMES",
    "TRUTH_SOURCES",
    "BraxContactWrapper",
    "BraxRandomization",
    "ContactEstState",
    "ContactObsConfig",
    "Core",
    "FootSpec",
    "LeggedPipelineEnv",
    "PlaygroundContactWrapper",
    "PlaygroundRandomization",
    "choose_force_rows",
    "default_estimator_params",
    "default_sensor_params",
    "default_terrain",
    "floating_base",
    "make_core",
    "model_of",
    "validate_config",
    "wrap_contact",
    "wrap_for_brax_training",
    "wrap_for_training",
]
