"""The physics-rate hook (envs/substeps.py) and the metrics under Brax's episode wrappers.

The planar leg as a minimal Playground env (tests/wrapper_helpers.PlaygroundLeg, whose
``step`` calls ``mjx_env.step`` as every Playground env does) and as a Brax
``PipelineEnv``. References are explicit Python loops over the physics substeps, one
``mjx.step`` and one ``Core.update`` each, with the same starting estimator state, so the
beliefs must agree to float32 round-off (the noisy sensor model draws from the same keys).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.wrappers import training as brax_training
from mujoco import mjx
from mujoco_playground._src import mjx_env
from mujoco_playground._src import wrapper as pg_wrapper
from wrapper_helpers import PlaygroundLeg

from jax_contact.envs import ground_truth
from jax_contact.envs import wrapper as W
from jax_contact.envs.robots import load_robot

N_SUB = 4  # 2.5 ms physics, 10 ms env step
KNEE = np.array([[0.3, -1.5], [0.6, -0.9], [0.2, -1.6], [0.5, -1.0], [0.4, -1.2]], np.float32)


@pytest.fixture(scope="module")
def brax_leg():
    robot = ground_truth.with_contact_sensors(load_robot("planar_leg"))
    return W.LeggedPipelineEnv(robot, n_frames=N_SUB, position_servo=(300.0, 8.0))


@pytest.fixture(scope="module")
def pg_leg(brax_leg):
    return PlaygroundLeg(brax_leg.mj_model, N_SUB)


def _reference(core, mjx_model, est, data, actions):
    """(logits, p_contact) after each env step from an explicit per-substep loop. Each env
    step first checks for an auto-reset, as the wrapper does (``Core.restart``: nothing
    moved here, but it splits the sensors' key, so the noise draws follow it)."""
    phys = jax.jit(lambda d, a: mjx.step(mjx_model, d.replace(ctrl=a)))
    update = jax.jit(core.update)
    restart = jax.jit(lambda e, d: core.restart(e, d, core.moved(e, d)))
    logit, p = [], []
    for a in actions:
        est = restart(est, data)
        for _ in range(N_SUB):
            data = phys(data, jnp.asarray(a))
            est = update(est, data)
        logit.append(np.asarray(est.belief.logit))
        p.append(np.asarray(est.diag.p_contact))
    return np.stack(logit), np.stack(p)


def test_substep_hook_equals_explicit_loop(pg_leg, brax_leg):
    """Playground: the hooked mjx_env.step gives the beliefs of an explicit loop. (Brax's
    hooked pipeline_step is checked the same way by tests/test_wrapper.py's pairing and
    auto-reset tests, which count one update per substep.)"""
    wrapped = W.wrap_contact(pg_leg, W.ContactObsConfig(include_logit=True))  # anymal_like
    assert wrapped.contact_rate == "substep"
    core = wrapped.contact_core
    assert float(core.params.dt) == pytest.approx(0.0025)
    original = mjx_env.step
    state = jax.jit(wrapped.reset)(jax.random.PRNGKey(0))
    step = jax.jit(wrapped.step)
    got, got_p = [], []
    for a in KNEE:
        state = step(state, jnp.asarray(a))
        got.append(np.asarray(state.info["contact_est"].belief.logit))
        got_p.append(np.asarray(state.info["contact_est"].diag.p_contact))
        # The hook lived only while step was traced.
        assert mjx_env.step is original
    assert int(state.info["contact_est"].n_updates) == N_SUB * len(KNEE)
    first = jax.jit(wrapped.reset)(jax.random.PRNGKey(0))
    want, want_p = _reference(core, core.mjx_model, first.info["contact_est"], first.data, KNEE)
    # One scan against separate jitted calls: float32 round-off only. Deep in the air the
    # logit is ~-37 (p ~ 1e-16), where round-off of the physics moves it by up to ~0.7
    # (seen with a different fusion of the same program): compared up to |logit| 30.
    np.testing.assert_allclose(np.stack(got_p), want_p, atol=1e-5)
    np.testing.assert_allclose(np.clip(np.stack(got), -30, 30), np.clip(want, -30, 30), rtol=1e-2)
    assert np.ptp(want) > 0.5  # the belief moved: the comparison is not vacuous


class _Fails(PlaygroundLeg):
    def step(self, state, action):
        super().step(state, action)
        raise RuntimeError("env step failed")


def test_hook_restored_after_error_and_refuses_nesting(pg_leg, brax_leg):
    original = mjx_env.step
    failing = W.wrap_contact(_Fails(brax_leg.mj_model, N_SUB))
    # Shapes only (eval_shape): an eager reset would dispatch MJX op by op, ~40 s of a cold
    # suite, and the hook is installed and removed while step is traced, which this is.
    state = jax.eval_shape(failing.reset, jax.random.PRNGKey(0))
    with pytest.raises(RuntimeError, match="env step failed"):
        jax.eval_shape(failing.step, state, jnp.zeros(2))
    assert mjx_env.step is original
    wrapped = W.wrap_contact(pg_leg)
    # Refused when wrapping: a second physics-rate wrapper, or one info_key twice.
    with pytest.raises(ValueError, match="already wrapped by a physics-rate contact wrapper"):
        W.wrap_contact(wrapped, W.ContactObsConfig(info_key="again"))
    with pytest.raises(ValueError, match="already wrapped .* info_key 'contact_est'"):
        W.wrap_contact(wrapped, W.ContactObsConfig(rate="control"))
    # The hook itself refuses a second hook (a nesting the wrapper chain does not show).
    from jax_contact.envs import substeps

    with substeps.hooked(mjx_env, "step", lambda *a: None):
        with pytest.raises(ValueError, match="already hooked"):
            with substeps.hooked(mjx_env, "step", lambda *a: None):
                pass
    assert mjx_env.step is original
    # A control-rate wrapper nests inside a physics-rate one.
    inner = W.wrap_contact(pg_leg, W.ContactObsConfig(rate="control", info_key="ctrl"))
    outer = W.wrap_contact(inner)
    s = jax.eval_shape(outer.step, jax.eval_shape(outer.reset, jax.random.PRNGKey(0)), jnp.zeros(2))
    assert s.info["contact_est"].n_updates.shape == ()


EPISODE = 5


def test_accuracy_metric_is_the_episode_mean_through_brax_wrappers(pg_leg):
    """Brax's EpisodeWrapper (via Playground's wrap_for_brax_training) and EvalWrapper sum
    every metric over an episode; the sum of the wrapper's metric must be the episode's
    accuracy over every physics-step update, computed here from the recorded substeps."""
    cfg = W.ContactObsConfig(record_substeps=True)
    env = W.wrap_contact(pg_leg, cfg)
    train = pg_wrapper.wrap_for_brax_training(env, episode_length=EPISODE)
    ev = brax_training.EvalWrapper(train)
    n_envs = 2
    state = jax.jit(ev.reset)(jax.random.split(jax.random.PRNGKey(1), n_envs))
    step = jax.jit(ev.step)
    hits = np.zeros(n_envs)
    for a in KNEE[:EPISODE]:
        state = step(state, jnp.broadcast_to(jnp.asarray(a), (n_envs, 2)))
        subs = state.info["contact_est_substeps"]
        right = (np.asarray(subs["p_contact"]) > 0.5) == np.asarray(subs["truth"])
        hits += right.sum(axis=(1, 2))
    assert np.all(np.asarray(state.done) == 1.0)  # the episode was truncated at its end
    want = hits / (EPISODE * N_SUB)
    assert np.all((want > 0.3) & (want < 1.0))  # neither trivial nor all right
    got_eval = np.asarray(state.info["eval_metrics"].episode_metrics["contact_est/accuracy"])
    got_train = np.asarray(state.info["episode_metrics"]["contact_est/accuracy"])
    np.testing.assert_allclose(got_eval, want, rtol=1e-5)
    np.testing.assert_allclose(got_train, want, rtol=1e-5)


def test_accuracy_metric_with_action_repeat(pg_leg):
    """With ``action_repeat`` = 2 EpisodeWrapper adds only the last of its two env steps'
    metrics: the wrapper's increment runs from the start of the training step, so the
    episode metric is still the running accuracy (it read 0.0 and -0.2 against 0.66 and
    0.48 with per-env-step increments)."""
    env = W.wrap_contact(pg_leg)
    train = pg_wrapper.wrap_for_brax_training(env, episode_length=2 * EPISODE, action_repeat=2)
    n_envs = 2
    state = jax.jit(train.reset)(jax.random.split(jax.random.PRNGKey(1), n_envs))
    step = jax.jit(train.step)
    for a in KNEE[:EPISODE]:
        state = step(state, jnp.broadcast_to(jnp.asarray(a), (n_envs, 2)))
        got = np.asarray(state.info["episode_metrics"]["contact_est/accuracy"])
        want = np.asarray(state.info["contact_est_score"]["mean"])
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    assert np.all(np.asarray(state.done) == 1.0) and np.all((want > 0.3) & (want < 1.0))
