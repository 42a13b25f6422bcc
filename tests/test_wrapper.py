"""Tests of the contact observation wrapper (envs/wrapper.py) on the planar leg.

Two compiled programs, each built once (module fixtures or one test): the planar leg
(one foot, position servos) as a Brax ``PipelineEnv`` under Brax's training wrappers
(substep rate, ideal sensors and the quadrature touch-down rule, so the estimator is
deterministic and a restarted belief can be compared with a fresh one exactly); the rate
comparison on the hopping planar leg (anymal_like sensors). The rest is not compiled.
Playground's Go1 joystick env, offline, is in tests/test_wrapper_go1.py.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from brax.envs.base import PipelineEnv
from brax.envs.wrappers import training as brax_training
from brax.io import mjcf as brax_mjcf
from mujoco import mjx
from mujoco_playground._src import wrapper as pg_wrapper
from wrapper_helpers import PlaygroundLeg, Traced
from wrapper_helpers import logit_of as _logit

import jax_contact as jc
from jax_contact.envs import ground_truth, sensors
from jax_contact.envs import wrapper as W
from jax_contact.envs.robots import load_robot

N_FRAMES = 4  # planar leg: 2.5 ms physics, 10 ms env step
HOP_HZ, HOP_AMP = 2.0, 0.7  # knee sinusoid that makes the planar leg hop (feet lift and land)


def hop_actions(n_steps: int, dt: float) -> np.ndarray:
    """(n_steps, 2) hip and knee targets: knee -1.2 + 0.7 sin(2 pi 2 t), hip = -knee / 2
    (keeps the foot under the hip), starting from the home pose."""
    t = np.arange(1, n_steps + 1) * dt
    knee = -1.2 + HOP_AMP * np.sin(2 * np.pi * HOP_HZ * t)
    return np.stack([-0.5 * knee, knee], axis=-1).astype(np.float32)


@pytest.fixture(scope="module")
def leg_robot():
    return ground_truth.with_contact_sensors(load_robot("planar_leg"))


@pytest.fixture(scope="module")
def brax_leg(leg_robot):
    return W.LeggedPipelineEnv(leg_robot, n_frames=N_FRAMES, position_servo=(300.0, 8.0))


@pytest.fixture(scope="module")
def pg_leg(brax_leg):
    return PlaygroundLeg(brax_leg.mj_model, N_FRAMES)


IDEAL = dict(sensor="ideal")


# ---------------------------------------------------------------- Brax, substep rate

N_ENVS = 2
EPISODE = 3  # steps; the training wrappers end (truncate) every episode after 3 steps


def _batch(a: np.ndarray) -> jax.Array:
    return jnp.broadcast_to(jnp.asarray(a), (N_ENVS,) + a.shape)


@pytest.fixture(scope="module")
def brax_train(brax_leg):
    """The wrapped leg under brax.envs.wrappers.training.wrap, jitted once."""
    env = W.wrap_contact(brax_leg, W.ContactObsConfig(record_substeps=True), **IDEAL)
    train = brax_training.wrap(env, episode_length=EPISODE)
    return env, Traced(train.reset), Traced(train.step)


def test_brax_substep_observation_and_info(brax_leg, brax_train):
    env, reset, step = brax_train
    assert env.contact_rate == "substep"
    inner_size = brax_leg.observation_size
    assert env.observation_size == inner_size + 1  # one foot, p_contact only
    keys = jax.random.split(jax.random.PRNGKey(0), N_ENVS)
    state = reset(keys)
    init = jc.init_belief(env.contact_core.params)
    np.testing.assert_array_equal(_logit(state), np.full((N_ENVS, 1), init.logit))
    hits = []  # per step, right foot-updates over its substeps (from the records)
    for a in hop_actions(2, float(brax_leg.dt)):
        state = step(state, _batch(a))
        subs = state.info["contact_est_substeps"]
        hits.append(
            np.sum((np.asarray(subs["p_contact"]) > 0.5) == np.asarray(subs["truth"]), axis=(1, 2))
        )
    assert state.obs.shape == (N_ENVS, inner_size + 1)
    # The env's own observation (joint positions after the rail, all velocities) comes
    # first, unchanged; the estimate is appended.
    ps = state.pipeline_state
    np.testing.assert_array_equal(
        state.obs[:, :inner_size], np.concatenate([ps.qpos[:, 1:], ps.qvel], axis=1)
    )
    p = jax.nn.sigmoid(state.info["contact_est"].belief.logit)
    np.testing.assert_allclose(state.obs[:, inner_size:], p, rtol=1e-6)
    # Standing on the floor at first: the belief has left 0.5 towards contact.
    assert np.all(np.asarray(state.info["contact_est_truth"]))
    assert np.all(np.asarray(state.obs[:, -1]) > 0.9)
    # The score counts every physics-step update (one foot): running accuracy after two
    # steps = (hits_1 + hits_2) / 8; the metric is its increment over the first step's
    # hits_1 / 4, so that Brax's episode sums give the episode's accuracy.
    score = state.info["contact_est_score"]
    np.testing.assert_array_equal(score["n"], 2 * N_FRAMES)
    mean2 = (hits[0] + hits[1]) / (2 * N_FRAMES)
    np.testing.assert_allclose(score["mean"], mean2, rtol=1e-6)
    np.testing.assert_allclose(
        state.metrics["contact_est/accuracy"], mean2 - hits[0] / N_FRAMES, rtol=1e-6, atol=1e-7
    )
    assert np.all(hits[1] == N_FRAMES)  # standing: every update of step 2 is right
    subs = state.info["contact_est_substeps"]
    assert subs["p_contact"].shape == (N_ENVS, N_FRAMES, 1)
    np.testing.assert_array_equal(
        subs["p_contact"][:, -1], state.info["contact_est"].diag.p_contact
    )
    # reset clears the belief.
    np.testing.assert_array_equal(_logit(reset(keys)), np.full((N_ENVS, 1), init.logit))


def test_brax_feature_options_sizes(brax_leg):
    cfg = W.ContactObsConfig(include_logit=True, include_terms=True)
    env = W.wrap_contact(brax_leg, cfg, **IDEAL)
    shape = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs.shape
    # p_contact + logit + 5 terms per foot.
    assert env.observation_size == brax_leg.observation_size + 7 == shape[-1]


def test_observe_options_sizes_and_refusals(brax_leg):
    def size(cfg):
        env = W.wrap_contact(brax_leg, cfg, **IDEAL)
        shape = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs.shape
        assert env.observation_size == shape[-1]
        return shape[-1] - brax_leg.observation_size

    assert size(W.ContactObsConfig(observe="none", include_logit=True)) == 0
    assert size(W.ContactObsConfig(observe="truth", include_logit=True)) == 2
    assert size(W.ContactObsConfig(observe="estimate", pairing="raw")) == 1
    with pytest.raises(ValueError, match="config.observe must be one of"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(observe="oracle"))
    with pytest.raises(ValueError, match="config.pairing must be one of"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(pairing="forward"))
    with pytest.raises(ValueError, match="include_terms"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(observe="truth", include_terms=True))
    with pytest.raises(ValueError, match="observe='truth' needs ground-truth"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(observe="truth", truth="none"))


def test_observe_truth_features_are_the_truth(brax_leg):
    """observe='truth': the slots of p_contact and the logit hold the simulator's flag and
    +-logit_clip; the estimator still runs and is scored. The leg is released less than
    the default 1 mm ``truth_gap`` above the floor, so the raw truth (gap 0) is observed."""
    cfg = W.ContactObsConfig(observe="truth", include_logit=True, logit_clip=7.0, truth_gap=0.0)
    env = W.wrap_contact(brax_leg, cfg, **IDEAL)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    seen = []
    for a in hop_actions(3, float(brax_leg.dt)):
        truth = bool(np.asarray(state.info["contact_est_truth"])[0])
        seen.append(truth)
        np.testing.assert_array_equal(state.obs[-2:], [1.0, 7.0] if truth else [0.0, -7.0])
        state = step(state, jnp.asarray(a))
    assert seen[0] is False and seen[-1] is True  # released just above the floor, lands
    assert "contact_est/accuracy" in state.metrics


def test_delayed_pairing_evaluates_the_previous_reading(leg_robot, brax_leg):
    """One update, ideal sensors, one physics step (the substep rate's period) with the foot
    in the air: ``delayed`` uses q, qd read at step 0 with the acceleration
    (qd_1 - qd_0) / dt and the torque read at step 1; ``raw`` uses q, qd of step 1. The
    reference composes the adapter and jax_contact.step by hand; a float64 MuJoCo oracle
    checks the physics of the pairing: after ``mj_step`` the stored ``qfrc_actuator`` is the
    force applied over the step, so ``M(q_0) qdd + c(q_0, qd_0) = tau_1`` in the air, and the
    dynamics term must then call the foot airborne."""
    from jax_contact import adapter

    env = W.wrap_contact(brax_leg, W.ContactObsConfig(pairing="delayed"), **IDEAL)
    raw = W.wrap_contact(brax_leg, W.ContactObsConfig(pairing="raw"), **IDEAL)
    core, core_raw = env.contact_core, raw.contact_core
    m = core.mjx_model
    dt = float(core.sensor.dt)
    assert dt == pytest.approx(float(brax_leg.mj_model.opt.timestep))  # substep rate
    home = jax.jit(brax_leg.reset)(jax.random.PRNGKey(0)).pipeline_state
    lifted = home.replace(qpos=home.qpos.at[0].add(0.3), qvel=home.qvel.at[1].set(2.0))
    # Two steps with different targets, so the torques of the two intervals differ (the
    # second saturates at the motors' 30 N m).
    phys = jax.jit(lambda d, a: mjx.step(m, d.replace(ctrl=a)))
    d0 = phys(lifted, jnp.array([0.6, -1.2]))
    d1 = phys(d0, jnp.array([0.3, -1.5]))
    key = jax.random.PRNGKey(3)

    # Oracle (float64 MuJoCo): the pairing's inverse-dynamics residual in the air.
    mj = brax_leg.mj_model
    dd = mujoco.MjData(mj)
    dd.qpos[:], dd.qvel[:] = np.asarray(d0.qpos), np.asarray(d0.qvel)
    mujoco.mj_forward(mj, dd)
    M = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, dd, M)
    qdd = (np.asarray(d1.qvel, np.float64) - np.asarray(d0.qvel, np.float64)) / dt
    lhs = M @ qdd + dd.qfrc_bias
    np.testing.assert_allclose(lhs, np.asarray(d1.qfrc_actuator), atol=0.05)
    assert np.max(np.abs(lhs - np.asarray(d0.qfrc_actuator))) > 5.0  # the other torque

    def wrapper_update(c, d_prev, d_new):
        est = c.init(d_prev, key)  # ideal sensors: the reading is d_prev exactly
        return c.update(est, d_new)

    def by_hand(d_at, qdd, tau):
        d = adapter.prepare(m, d_at)
        meas = adapter.leg_measurements(m, d, core.desc, qdd=qdd, tau=tau, include_passive=True)
        belief = jax.tree.map(lambda x: x[None], jc.init_belief(core.params))
        b, diag = jax.vmap(lambda b, mm: jc.step(core.params, core.terrain, b, mm, key=key))(
            belief, meas
        )
        return b.logit, diag.p_dynamics, diag.force

    qdd = (d1.qvel - d0.qvel) / dt
    got = jax.jit(wrapper_update, static_argnums=0)(core, d0, d1)
    got_raw = jax.jit(wrapper_update, static_argnums=0)(core_raw, d0, d1)
    want = jax.jit(by_hand)(d0, qdd, d1.qfrc_actuator)
    want_raw = jax.jit(by_hand)(d1, qdd, d1.qfrc_actuator)
    for g, w in ((got, want), (got_raw, want_raw)):
        np.testing.assert_allclose(g.belief.logit, w[0], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(g.diag.p_dynamics, w[1], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(g.diag.force, w[2], rtol=1e-4, atol=1e-3)
    # The state the model is evaluated at differs (eq. 6's holding force depends on it).
    assert np.max(np.abs(want[2] - want_raw[2])) > 0.1
    # Consistent sample, foot in the air: the dynamics term is sure of it (capped at
    # cap_dynamics); with the torque of the interval before, the acceleration is far from
    # both hypotheses' predictions and the term gives no air evidence at all (the shared
    # outlier component makes it exactly neutral; the paper's Gaussians said "held").
    assert float(got.diag.p_dynamics[0]) < 0.02
    stale = jax.jit(by_hand)(d0, qdd, d0.qfrc_actuator)
    assert float(stale[1][0]) >= 0.5


def _check_autoreset(reset, step, acts, obs_of):
    """Runs one episode to its end and one step more; the belief must restart.

    A fresh episode stepped once with the same action is the reference: with ideal sensors
    and the quadrature touch-down rule the estimator is deterministic, so a restarted
    belief and sensor state give exactly its numbers.
    """
    keys = jax.random.split(jax.random.PRNGKey(0), N_ENVS)
    state = reset(keys)
    for a in acts[:EPISODE]:
        state = step(state, _batch(a))
    assert np.all(np.asarray(state.done) == 1.0)  # the auto-reset swapped the state in
    terminal = _logit(state)
    state = step(state, _batch(acts[EPISODE]))
    fresh = step(reset(keys), _batch(acts[EPISODE]))
    np.testing.assert_allclose(_logit(state), _logit(fresh), rtol=1e-6)
    np.testing.assert_allclose(obs_of(state), obs_of(fresh), rtol=1e-6)
    assert np.all(np.abs(terminal - _logit(fresh)) > 0.1)  # the restart is visible
    # One env step after the restart: one estimator update per physics substep.
    np.testing.assert_array_equal(state.info["contact_est"].n_updates, N_FRAMES)
    return state


def test_brax_training_wrap_autoreset_restarts_belief(brax_leg, brax_train):
    _, reset, step = brax_train
    acts = hop_actions(EPISODE + 1, float(brax_leg.dt))
    state = _check_autoreset(reset, step, acts, lambda s: s.obs)
    assert "contact_est/accuracy" in state.info["episode_metrics"]
    assert (reset.traces, step.traces) == (1, 1)


def test_a_nan_state_is_not_an_auto_reset_and_its_updates_are_skipped_unscored(brax_leg):
    """A helper's audit (Go1 handstand, whose termination does not catch NaN): an env
    whose state went NaN was 'moved' on every step (NaN != NaN read as an auto-reset), so
    its belief restarted each step, looking like a fresh prior, and its score was wiped.
    A state equal to the last one NaN for NaN is not moved now; an update from NaN
    readings is skipped (the prediction alone), counted in ``n_skipped`` and not scored."""
    env = W.wrap_contact(brax_leg, **IDEAL)
    core = env.contact_core
    data = brax_leg.reset(jax.random.PRNGKey(0)).pipeline_state
    est = core.init(data, jax.random.PRNGKey(1))
    nan = data.replace(qpos=data.qpos.at[0].set(jnp.nan), qvel=data.qvel * jnp.nan)
    assert not bool(core.moved(est, data)) and bool(core.moved(est, nan))
    assert not bool(core.moved(est.replace(qpos=nan.qpos, qvel=nan.qvel), nan))
    after = jax.jit(core.update)(est, nan)
    assert not bool(after.diag.valid[0]) and int(after.n_skipped) == 1
    assert int(after.n_updates) == 1 and int(est.n_skipped) == 0
    # The one-step prediction alone: finite, a step of the gait prior from the prior's 0.
    assert np.isfinite(np.asarray(after.belief.logit)).all()
    assert float(jnp.abs(after.belief.logit - est.belief.logit).max()) < 0.05
    rec = core.record(after, nan)
    assert rec["scored"].shape == (1,) and not bool(rec["scored"][0])


def test_step_of_a_bare_state_and_a_foot_without_truth_say_so(leg_robot, brax_leg):
    """A helper's audit: ``step`` given the wrapped env's own state raised a bare KeyError
    while tracing; a foot given by a body with no floor-touching geom lost its ground
    truth, and with it the score and metric, without a word."""
    env = W.wrap_contact(brax_leg, **IDEAL)
    act = jnp.zeros(brax_leg.action_size)
    with pytest.raises(ValueError, match="state.info has no 'contact_est': step takes the state"):
        jax.eval_shape(lambda k: env.step(brax_leg.reset(k), act), jax.random.key(0))
    bare = W.ContactObsConfig(feet=(W.FootSpec("foot", body="shank", geoms=()),))
    with pytest.warns(UserWarning, match=r"no ground-truth contact: feet \['foot'\] have no geom"):
        silent = W.wrap_contact(brax_leg, bare, **IDEAL)
    assert silent.contact_report()["truth"] == "none"
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # asked for: no warning
        W.wrap_contact(brax_leg, bare.replace(truth="none"), **IDEAL)


def test_domain_randomisation_steps_the_contact_wrapper(brax_leg, pg_leg):
    """Brax's and Playground's randomisation wrappers set each env's model on
    ``env.unwrapped`` and step ``env.unwrapped``, skipping the contact wrapper (no contact
    slot in the observation, no ``contact_est`` metric). ``W.wrap_for_training`` steps the
    chain it wraps: the leg's bodies 1.0x and 1.5x as heavy in the two envs, same actions,
    the observation has the slot ``observation_size`` counts, the metric is made, and the
    heavier leg moves otherwise (the randomised model reached the physics). Playground's
    counterpart swaps the model where Playground's own does and yields the whole chain
    (not compiled)."""

    def heavier(sys):
        masses = sys.body_mass[None] * jnp.array([1.0, 1.5])[:, None]
        axes = jax.tree.map(lambda _: None, sys).tree_replace({"body_mass": 0})
        return sys.tree_replace({"body_mass": masses}), axes

    env = W.wrap_contact(brax_leg, **IDEAL)
    train = W.wrap_for_training(env, episode_length=EPISODE, randomization_fn=heavier)
    state = jax.jit(train.reset)(jax.random.split(jax.random.PRNGKey(0), N_ENVS))
    step = jax.jit(train.step)
    for a in hop_actions(2, float(brax_leg.dt)):
        state = step(state, _batch(a))
    assert state.obs.shape == (N_ENVS, env.observation_size)
    assert "contact_est/accuracy" in state.metrics and "contact_est" in state.info
    qpos = np.asarray(state.pipeline_state.qpos)
    assert np.abs(qpos[0] - qpos[1]).max() > 1e-4
    assert brax_leg.sys.body_mass.shape == (brax_leg.sys.nbody,)  # restored, unbatched

    wrapped = W.wrap_contact(pg_leg, **IDEAL)
    nominal = pg_leg._mjx_model
    dr = W.PlaygroundRandomization(wrapped, lambda m: (m, jax.tree.map(lambda _: None, m)))
    swapped = object()
    with dr.v_env_fn(swapped) as stepped:
        assert stepped is wrapped and pg_leg._mjx_model is swapped
    assert pg_leg._mjx_model is nominal
    assert isinstance(W.wrap_for_brax_training(wrapped).env.env, brax_training.VmapWrapper)


# ------------------------------------------------------------------------- refusals


def test_refusals(leg_robot, brax_leg, pg_leg):
    with pytest.raises(ValueError, match="valid names"):
        W.wrap_contact(brax_leg, foot_names=["nope"])
    with pytest.raises(ValueError, match="config.rate must be one of"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(rate="fast"))
    # A keyword argument that says otherwise than the config: foot_names silently replaced
    # config.feet (reordering the features, a helper's trial). Equal, or filling a default
    # the config leaves, it is taken.
    from jax_contact.envs.contact_wrappers import _merge

    cfg = W.ContactObsConfig(feet=("foot",), sensor="ideal")
    with pytest.raises(
        ValueError, match=r"foot_names=\('toe',\) and config.feet=\('foot',\) disagree"
    ):
        _merge(cfg, ["toe"], None, None, None)
    with pytest.raises(ValueError, match=r"sensor='harsh' and config.sensor='ideal' disagree"):
        _merge(cfg, None, "harsh", None, None)
    assert _merge(cfg, ["foot"], "ideal", None, None) == cfg
    assert _merge(W.ContactObsConfig(), ["toe"], "harsh", None, None).feet == ("toe",)
    assert _merge(W.ContactObsConfig(), ["toe"], "harsh", None, None).sensor == "harsh"
    with pytest.raises(ValueError, match="record_substeps needs rate='substep'"):
        W.wrap_contact(pg_leg, W.ContactObsConfig(rate="control", record_substeps=True))
    with pytest.raises(ValueError, match="config.obs_keys"):
        _ = W.wrap_contact(pg_leg, W.ContactObsConfig(obs_keys=("policy",))).observation_size
    # An array observation takes the features at its end; keys asked for are refused, not
    # silently ignored (a user feeding the critic would get nothing separate).
    keys = W.ContactObsConfig(obs_keys=("state", "privileged_state"))
    with pytest.raises(ValueError, match=r"obs_keys \['state', 'privileged_state'\]: .* array"):
        _ = W.wrap_contact(brax_leg, keys).observation_size

    class Generalized(PipelineEnv):
        reset = step = None

    sys = brax_mjcf.load_model(load_robot("planar_leg").mj_model)
    with pytest.raises(ValueError, match="valid backend: 'mjx'"):
        W.wrap_contact(Generalized(sys, backend="generalized"))
    with pytest.raises(ValueError, match="Brax Env .* or a Playground MjxEnv"):
        W.wrap_contact(object())
    with pytest.raises(ValueError, match="one of"):
        W.wrap_contact(brax_leg, sensor="noisy")
    with pytest.raises(ValueError, match="with_contact_sensors"):
        W.wrap_contact(
            W.LeggedPipelineEnv(load_robot("planar_leg")), W.ContactObsConfig(truth="force_sensors")
        )

    no_floor = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom type='sphere' size='0.1'/></body>"
        "</worldbody></mujoco>"
    )

    class NoFloor(PlaygroundLeg):
        def __init__(self):  # only the model matters for the refusal
            self._mj, self._mjx_model = no_floor, mjx.put_model(no_floor)

    with pytest.raises(ValueError, match="no floor"):
        W.wrap_contact(NoFloor())
    with pytest.raises(ValueError, match="batch of keys"):
        W.wrap_contact(pg_leg, **IDEAL).reset(jax.random.split(jax.random.PRNGKey(0), 2))
    # Outside the training wrappers: refused when wrapped (a single key gave a raw JAX
    # PRNG error at reset); and each wrapper class refuses the other framework's env.
    trained = pg_wrapper.wrap_for_brax_training(pg_leg, episode_length=10, action_repeat=1)
    with pytest.raises(ValueError, match=r"already wrapped for training \(BraxAutoResetWrapper\)"):
        W.wrap_contact(trained)
    with pytest.raises(ValueError, match="already wrapped for training"):
        W.wrap_contact(brax_training.wrap(brax_leg, episode_length=10))
    with pytest.raises(ValueError, match="PlaygroundContactWrapper wraps a .*MjxEnv"):
        W.PlaygroundContactWrapper(brax_leg)
    with pytest.raises(ValueError, match="BraxContactWrapper wraps a .*Env, got PlaygroundLeg"):
        W.BraxContactWrapper(pg_leg)


@pytest.mark.parametrize(
    "fields, match",
    [
        # A non-str foot name segfaulted the interpreter in mj_name2id.
        (dict(feet=(None,)), r"config.feet\[0\] must be a name \(str\) or a FootSpec"),
        (dict(feet=5), "config.feet must be a non-empty sequence"),
        (dict(feet=("floor",)), "'floor' is a geom of the world body"),
        # include_terms=2 counted the terms twice in observation_size.
        (dict(include_terms=2), "config.include_terms must be True or False, got 2"),
        (dict(include_logit="yes"), "config.include_logit must be True or False"),
        (dict(include_passive="no"), "config.include_passive must be True or False"),
        (dict(truth_threshold="1"), r"config.truth_threshold must be a number >= 0 \(N\)"),
        (dict(logit_clip=None), "config.logit_clip must be a number > 0, got None"),
        (dict(terrain="flat"), "config.terrain must be None or a jax_contact.terrain model"),
        # Built from its class, jc.flat's checks skipped: every update was skipped and the
        # standing robot's score read 1.0 (a helper's audit).
        (
            dict(terrain=jc.FlatTerrain(height=jnp.float32(jnp.nan), sigma=jnp.float32(1.0))),
            r"config.terrain.height must be a finite scalar, got Array\(nan",
        ),
        (dict(force_rows=2), "config.force_rows must be a sequence of axes, got 2"),
        # force_rows was silently dropped beside a parameter file.
        (dict(force_rows=(2,), params="go1"), "config.force_rows .* give one of them"),
        (dict(obs_keys=()), "config.obs_keys is empty"),
        # Accepted before (a user trial): no normal axis, and a 1 m "floor tolerance".
        (dict(force_rows=(0, 1)), r"config.force_rows \(0, 1\) leaves out the normal"),
        (dict(truth_gap=1.0), "config.truth_gap must be at most 0.02 m .* got 1.0"),
    ],
)
def test_config_fields_are_checked_and_named(brax_leg, fields, match):
    with pytest.raises(ValueError, match=match):
        W.wrap_contact(brax_leg, W.ContactObsConfig(**fields))


# ------------------------------------------------ parameter files and calibration maps


def test_a_parameter_file_brings_its_terrain_model(brax_leg, tmp_path):
    """A file tuned on the foothold memory (``tune --terrain-model memory``) runs on it in
    the wrapper as in the log commands: FOOTHOLD_MEMORY over the floor's plane (it ran on
    the plane alone); a file that names none runs on the plane, config.terrain wins over
    both, and a file naming an unknown model is refused naming it and the field."""
    from jax_contact.envs.contact_params import default_terrain
    from jax_contact.terrain import FOOTHOLD_MEMORY, FlatTerrain, FootholdMemory

    core = W.wrap_contact(brax_leg).contact_core
    params, plane = core.params, default_terrain(brax_leg.mj_model, core.desc)
    assert core.terrain == plane
    files = {}
    for name, prov in (("memory", {"terrain_model": "memory"}), ("plain", {}), ("stairs", {})):
        files[name] = str(jc.save_params(tmp_path / f"{name}.json", params, prov))
    # Edited by hand after writing (save_params refuses to write an unknown model).
    stairs = json.loads(Path(files["stairs"]).read_text())
    stairs["provenance"] = {"terrain_model": "stairs"}
    Path(files["stairs"]).write_text(json.dumps(stairs))
    mem = W.wrap_contact(brax_leg, W.ContactObsConfig(params=files["memory"])).contact_core
    assert isinstance(mem.terrain, FootholdMemory)
    assert float(mem.terrain.sigma_foothold) == pytest.approx(FOOTHOLD_MEMORY["sigma_foothold"])
    assert float(mem.terrain.growth) == pytest.approx(FOOTHOLD_MEMORY["growth"])
    assert float(mem.terrain.smoothing) == pytest.approx(FOOTHOLD_MEMORY["smoothing"])
    assert mem.terrain.fallback == plane
    plain = W.wrap_contact(brax_leg, W.ContactObsConfig(params=files["plain"])).contact_core
    assert isinstance(plain.terrain, FlatTerrain) and plain.terrain == plane
    chosen = jc.flat(0.1, 0.01)
    given = W.ContactObsConfig(params=files["memory"], terrain=chosen)
    assert W.wrap_contact(brax_leg, given).contact_core.terrain == chosen
    with pytest.raises(ValueError, match=r"stairs\.json.*'terrain_model'.*'stairs'"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(params=files["stairs"]))


def test_a_parameter_file_brings_its_calibration_map(brax_leg, tmp_path):
    """params given as a file: the wrapper runs the file's parameters and observes (and
    scores) the belief through the file's calibration map, while the recursion runs on the
    raw logit. Reference: the same parameters given as an object (no map) on the same
    readings and key, mapped by hand in float64 (l' = l / T_c for l > 0, l / T_a else)."""
    plain = W.wrap_contact(brax_leg, W.ContactObsConfig(include_logit=True), **IDEAL)
    params = plain.contact_core.params
    cal = jc.Calibration(temperature=2.0, temperature_air=0.5)
    path = tmp_path / "leg.json"
    jc.save_params(path, params, {"calibration": cal.as_dict()})
    mapped = W.wrap_contact(
        brax_leg, W.ContactObsConfig(include_logit=True, logit_clip=30.0, params=str(path)), **IDEAL
    )
    assert mapped.contact_core.calibration == cal
    report = mapped.contact_report()
    assert report["params"] == str(path) and report["calibration"]["temperature_air"] == 0.5
    assert plain.contact_report()["calibration"] is None  # an object brings no map

    home = jax.jit(brax_leg.reset)(jax.random.PRNGKey(0)).pipeline_state
    d1 = jax.jit(lambda d: mjx.step(brax_leg.sys, d))(home)
    key = jax.random.PRNGKey(5)

    def run(core):
        est = core.update(core.init(home, key), d1)
        return est.belief.logit, est.diag.p_contact, core.features(est, d1)

    raw_logit, raw_p, raw_feats = jax.jit(run, static_argnums=0)(plain.contact_core)
    logit, p, feats = jax.jit(run, static_argnums=0)(mapped.contact_core)
    np.testing.assert_array_equal(logit, raw_logit)  # the recursion is untouched
    l64 = np.asarray(raw_logit, np.float64)
    want = np.where(l64 > 0, l64 / 2.0, l64 / 0.5)
    np.testing.assert_allclose(feats[1], np.clip(want, -30, 30), rtol=1e-6)
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-want)), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(feats[0], p, rtol=1e-6)
    np.testing.assert_allclose(raw_feats[0], raw_p, rtol=1e-6)
    assert abs(float(p[0]) - float(raw_p[0])) > 1e-3  # the map moved P
    assert (float(p[0]) > 0.5) == (float(raw_p[0]) > 0.5)  # and kept the decision

    # calibration=None turns the file's map off; an explicit map applies to an object.
    off = W.wrap_contact(brax_leg, W.ContactObsConfig(params=str(path), calibration=None))
    assert off.contact_core.calibration is None
    given = W.wrap_contact(brax_leg, W.ContactObsConfig(params=params, calibration=cal))
    assert given.contact_core.calibration == cal
    with pytest.raises(ValueError, match="config.calibration must be"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(calibration="sign"))
    with pytest.raises(ValueError, match="parameter file .*nope.json.* does not exist"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(params=str(tmp_path / "nope.json")))
    with pytest.raises(ValueError, match="nv = 18; the robot has nv = 3"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(params="go1"))
    # A file made at another period runs at the wrapper's, with a warning.
    jc.save_params(tmp_path / "slow.json", params.replace(dt=jnp.float32(0.01)))
    with pytest.warns(UserWarning, match="dt = 0.01 s; the estimator's"):
        slow = W.wrap_contact(brax_leg, params=tmp_path / "slow.json")
    assert float(slow.contact_core.params.dt) == pytest.approx(float(params.dt))
    # A file tuned on recordings without torques runs no dynamics term: said, not silent.
    jc.save_params(tmp_path / "no_dyn.json", params.replace(terms=params.terms[1:]))
    with pytest.warns(UserWarning, match="run no dynamics term .* support every term"):
        W.wrap_contact(brax_leg, params=tmp_path / "no_dyn.json")


# --------------------------------------------------------------- parameter helpers


def test_default_estimator_params_follow_the_sensor_model(leg_robot):
    dt = 0.0025
    sp = W.default_sensor_params("anymal_like", leg_robot, dt)
    assert not sp.floating_base and sp.latency == 1  # 1 step = 2.5 ms at 400 Hz
    params = W.default_estimator_params(leg_robot, dt, sp)
    assert params.force_rows == (0, 2)  # the planar leg's joints span x and z
    assert params.touchdown == "quadrature"
    # Joints: qd 0.3 rad/s white noise differenced at 400 Hz: sqrt(2) 0.3 / 0.0025 = 169.7.
    np.testing.assert_allclose(params.noise.sigma_qdd[1:], np.sqrt(2) * 0.3 / dt, rtol=1e-6)
    # Torque noise 0.5 N m folded into the 2 N m disturbance: sqrt(4 + 0.25) = 2.0616.
    np.testing.assert_allclose(params.noise.sigma_d[1:], np.sqrt(4.25), rtol=1e-6)
    # Rail: 0.04 m white, 0.01 m/sqrt(s) bias walk over 10 s: sqrt(0.04^2 + 0.001) = 0.0510.
    np.testing.assert_allclose(params.noise.sigma_q[0], np.sqrt(0.0016 + 0.001), rtol=1e-5)
    # Control rate (20 ms): the 2.5 ms latency rounds to 0 steps.
    assert W.default_sensor_params("anymal_like", leg_robot, 0.02).latency == 0
    with pytest.raises(ValueError, match="force_rows"):
        W.default_estimator_params(leg_robot.description, dt, sp)
    with pytest.raises(ValueError, match="must equal dt"):
        W.default_estimator_params(leg_robot, 0.02, sp)
    wrong = sensors.sensor_preset("ideal", 3, dt=0.01, floating_base=False)
    with pytest.raises(ValueError, match="estimator period"):
        W.default_sensor_params(wrong, leg_robot, dt)


def test_params_of_another_robot_or_period_name_what_differs(brax_leg, leg_robot):
    """Another robot's EstimatorParams read "params has nv=24, dt=0.0020000000949949026;
    rate='substep' needs nv=18, dt=0.002": the dt part looked wrong too, though only the
    float32 rounding differed. Now only what differs is named."""
    import jax_contact as jc

    dt = float(brax_leg.sys.opt.timestep)
    sp = sensors.sensor_preset("anymal_like", 18, dt=dt)
    go1 = jc.params_for(load_robot("go1").description, sp, dt)
    with pytest.raises(ValueError, match=r"^params has nv=18 where the robot has nv=3$"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(params=go1))
    slow = W.default_estimator_params(
        leg_robot, 0.01, W.default_sensor_params("anymal_like", leg_robot, 0.01)
    )
    with pytest.raises(ValueError, match=r"^params has dt=0.01 s where rate='substep' runs"):
        W.wrap_contact(brax_leg, W.ContactObsConfig(params=slow))


# -------------------------------------------------- tracking and the two rates compared


def test_substep_belief_tracks_truth_and_rate_comparison(brax_leg):
    """Hopping planar leg, anymal_like sensors: the substep-rate belief carried in info
    tracks the truth (F1 > 0.9); the control-rate numbers come from the same rollouts
    (the same scored steps and true phases) and show the control rate's documented cost."""
    n_steps, n_envs = 150, 2
    acts = np.broadcast_to(hop_actions(n_steps, float(brax_leg.dt))[:, None], (n_steps, n_envs, 2))
    res = W.compare_rates(brax_leg, acts, key=jax.random.PRNGKey(0), skip_s=0.1)
    print("\n" + res.table())
    assert res.substep.n_steps == (n_steps - 10) * n_envs
    assert res.substep_all.n_steps == res.substep.n_steps * N_FRAMES
    assert res.substep_all.n_touchdowns >= 2 * n_envs  # the leg really hops
    assert res.substep.f1 > 0.9
    assert res.substep_all.f1 > 0.9
    # One truth for both rates (the env step's): the same steps, phases and events scored.
    for field in ("n_steps", "n_air_phases", "n_touchdowns", "n_liftoffs"):
        assert getattr(res.control, field) == getattr(res.substep, field), field
    # On the stiff hop the control rate finds the stances but calls part of each swing
    # contact (its acceleration is a mean across the impact; docs/training.md, "Physics rate
    # against control rate": 0.12-0.14 accuracy lost at 20 ms, recall 0.975): here 4
    # substeps, recall 0.98, accuracy 0.22 below the substep rate's on these rollouts.
    assert res.control.recall > 0.9, res.control
    assert res.control.accuracy < res.substep.accuracy - 0.05, (res.control, res.substep)


def test_rate_comparison_closed_loop_and_stop(brax_leg):
    """compare_rates' ``feedback`` drives the physics from the simulator's state and
    ``stop`` ends the score: the hop of the test above computed from ``data.time`` on
    zero open-loop actions, stopped after 0.5 s (the 50th of 60 env steps)."""
    n_steps, n_envs, dt = 60, 2, float(brax_leg.dt)

    def feedback(data):  # hop_actions' target for the step that starts at data.time
        knee = -1.2 + HOP_AMP * jnp.sin(2 * jnp.pi * HOP_HZ * (data.time + dt))
        return jnp.stack([-0.5 * knee, knee])

    acts = np.zeros((n_steps, n_envs, 2), np.float32)
    res = W.compare_rates(
        brax_leg,
        acts,
        key=jax.random.PRNGKey(0),
        skip_s=0.1,
        feedback=feedback,
        stop=lambda data: data.time > 0.495,
    )
    # data.time after env step k (1-based) is k dt = 0.01 k: stop flags step 50 (0.5 s,
    # the first over 0.495), so steps 11..49 are scored (10 skipped), 39 per rollout.
    assert res.ended_rollouts == n_envs
    assert res.substep.n_steps == 39 * n_envs
    assert res.substep_all.n_touchdowns >= n_envs  # the feedback made it hop
    assert res.substep_all.f1 > 0.9


def test_scored_steps_end_at_done_and_nonfinite_and_refuse_nothing():
    """compare_rates' scored steps, by hand: 3 rollouts of 6 env steps of 0.02 s, skip
    0.04 s (2 steps). Rollout 0 never ends: steps 2-5. Rollout 1's done at step 4: steps
    2-3. Rollout 2's estimate is non-finite at step 3 (before its done at 5): step 2."""
    from jax_contact.train.rates import scored_steps

    done = np.zeros((6, 3), bool)
    done[4, 1] = done[5, 2] = True
    finite = np.ones((6, 3), bool)
    finite[3, 2] = False
    valid, n_ended, n_broke = scored_steps(done, finite, 0.04, 0.02)
    want = np.zeros((6, 3), bool)
    want[2:6, 0] = want[2:4, 1] = want[2, 2] = True
    np.testing.assert_array_equal(valid, want)
    assert (n_ended, n_broke) == (2, 1)
    # Every rollout ended by step 4 and 0.1 s (5 steps) skipped: a clear error, not NaN.
    done[4, 0] = True
    with pytest.raises(
        ValueError,
        match=r"^skip_s: nothing left to score: 0.1 s \(5 env steps"
        r"\).*the longest ran 4 env steps \(0.08 s\).*--skip",
    ):
        scored_steps(done, finite, 0.1, 0.02)


def test_rates_refuses_a_file_for_another_robot_before_any_scene_runs():
    """``jax-contact rates --params``: the file's nv is checked against every scene's robot
    before the first scene's minute of compiling (Go1: nv 18, planar leg: nv 3)."""
    from jax_contact.train import rates

    rates.check_params(["go1_walk", "go1"], "go1")
    rates.check_params(["planar_leg"], None)
    # The option named, and a preset called one (it said "parameter file 'go1_playground'"
    # and named no option, a helper's trial).
    with pytest.raises(
        ValueError,
        match="argument --params: preset 'go1' is for nv = 18; scene 'planar_leg'"
        " \\(planar_leg\\) has nv = 3",
    ):
        rates.check_params(["go1_walk", "planar_leg"], "go1")
