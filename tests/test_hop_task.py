"""The hop task (envs/hop_task.py), its configurations (train/tasks.py) and the transfer
matrix's metrics (train/transfer.py). Training is measured, not tested
(docs/training_hop.md). One module fixture builds the three envs; only resets and one step
of the truth env are compiled."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jax_contact.envs import hop_task as H
from jax_contact.train import policy_eval, ppo, tasks, transfer

N = 2


@pytest.fixture(scope="module")
def robot():
    return H.hop_robot()


@pytest.fixture(scope="module")
def resets(robot):
    """observe -> (env, batched reset state of keys 0, 1)."""
    keys = jax.random.split(jax.random.PRNGKey(3), N)
    out = {}
    for observe in ("none", "truth", "estimate"):
        env = H.make_hop_env(observe, robot=robot)
        out[observe] = (env, jax.jit(jax.vmap(env.reset))(keys))
    return out


def test_reward_on_hand_computed_states():
    # Flight, going up at 2 m/s from 0.5 m: apex 0.5 + 4 / 19.62 = 0.703874 m.
    apex = 0.5 + 2.0**2 / (2 * 9.81)
    want = math.exp(-(((apex - 0.7) / 0.1) ** 2))  # 0.998500
    np.testing.assert_allclose(H.hop_reward(0.5, 2.0, 0.7, 0.1), want, rtol=1e-6)
    # Going down (or stance): only the height counts: exp(-((0.45 - 0.65) / 0.1)^2) = e^-4.
    np.testing.assert_allclose(H.hop_reward(0.45, -1.0, 0.65, 0.1), math.exp(-4.0), rtol=1e-6)
    # Standing on a straight leg (0.52 m) under a 0.62 m command: e^-1.
    np.testing.assert_allclose(H.hop_reward(0.52, 0.0, 0.62, 0.1), math.exp(-1.0), rtol=1e-6)


def test_episode_metrics_find_the_apexes():
    # Two envs, 6 steps. Env 0: up, up, apex (vz turns <= 0 in flight) at z=0.70, down,
    # lands, pushes up. Env 1 stays on the ground (contact): no apex.
    vz = np.array([[0.5, 0.0], [0.2, 0.0], [-0.1, 0.0], [-0.5, 0.0], [-0.2, 0.0], [0.3, 0.0]])
    z = np.array([[0.6, 0.43], [0.65, 0.43], [0.70, 0.43], [0.66, 0.43], [0.5, 0.43], [0.52, 0.43]])
    contact = np.array([[0, 1], [0, 1], [0, 1], [0, 1], [1, 1], [1, 1]], bool)
    reward = np.full((6, 2), 0.5)
    alive = np.ones((6, 2), bool)
    alive[5, 1] = False  # env 1 falls at the last step
    m = transfer.episode_metrics(z, vz, contact, reward, alive, np.array([0.68, 0.6]))
    assert m["hops"] == 0.5  # one apex over two episodes
    np.testing.assert_allclose(m["apex_error"], 0.02, rtol=1e-9)
    np.testing.assert_allclose(m["return"], (6 * 0.5 + 5 * 0.5) / 2)
    np.testing.assert_allclose(m["tracking"], 0.5)
    assert m["fell"] == 0.5


def test_configs_are_frozen_and_fit_brax():
    with pytest.raises(dataclasses.FrozenInstanceError):
        H.HOP.sigma = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        tasks.HOP_SMALL.num_envs = 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        tasks.HOP_TASK.name = "x"
    for cfg in (tasks.HOP_SMALL, tasks.HOP_REDUCED):
        cfg.validate()
    # 10,240 env steps per training step (128 x 4 x 20): 120 of them in 6 epochs, 40 in 4.
    assert tasks.HOP_SMALL.steps_per_training_step == 10_240
    assert ppo.brax_timesteps(tasks.HOP_SMALL) == 1_228_800
    assert ppo.brax_timesteps(tasks.HOP_REDUCED) == 409_600
    assert tasks.get_task("hop").config("reduced") is tasks.HOP_REDUCED
    assert tasks.get_task("go1").config("small") is ppo.SMALL
    with pytest.raises(ValueError, match="task must be one of"):
        tasks.get_task("walk")
    assert H.HOP.episode_length == tasks.HOP_SMALL.episode_length == 300
    # The command is above what a straight leg can stand at (0.25 + 0.25 + 0.02 m).
    assert H.HOP.cmd_range[0] > 0.52


def test_extra_latency_adds_env_steps(robot):
    base = H.sensor_with_extra_latency(robot, "anymal_like", 0)
    assert base.latency == 1  # the preset's 2.5 ms at the 2.5 ms physics step
    assert H.sensor_with_extra_latency(robot, "anymal_like", 2).latency == 1 + 2 * 4


def test_reset_shapes_and_contact_slots(resets):
    env_n, s_n = resets["none"]
    env_t, s_t = resets["truth"]
    env_e, s_e = resets["estimate"]
    assert env_n.observation_size == 6 and env_t.observation_size == env_e.observation_size == 7
    assert s_n.obs.shape == (N, 6) and s_t.obs.shape == s_e.obs.shape == (N, 7)
    # Same keys: the leg's 5 numbers and the command are the same in all three.
    np.testing.assert_array_equal(s_t.obs[:, :6], s_n.obs)
    np.testing.assert_array_equal(s_e.obs[:, :6], s_n.obs)
    ps = s_n.pipeline_state
    np.testing.assert_array_equal(s_n.obs[:, :5], np.concatenate([ps.qpos[:, 1:], ps.qvel], 1))
    h_cmd = np.asarray(s_n.info["h_cmd"])
    np.testing.assert_allclose(s_n.obs[:, 5], h_cmd - 0.6, rtol=1e-6)
    assert np.all((h_cmd >= 0.55) & (h_cmd <= 0.70))
    z0 = np.asarray(ps.qpos[:, 0])
    assert np.all((z0 >= 0.45) & (z0 <= 0.60))  # above the 0.4327 m standing height
    # The contact slot: truth 0 (dropped from above the floor); estimate = the prior 0.5
    # of a fresh belief, sigmoid(logit).
    np.testing.assert_array_equal(s_t.obs[:, 6], np.asarray(s_t.info["contact_est_truth"][:, 0]))
    assert np.all(np.asarray(s_t.obs[:, 6]) == 0.0)
    p = 1.0 / (1.0 + np.exp(-np.asarray(s_e.info["contact_est"].belief.logit[:, 0])))
    np.testing.assert_allclose(s_e.obs[:, 6], p, rtol=1e-6)
    assert not np.allclose(s_e.obs[:, 6], s_t.obs[:, 6])


def test_step_reward_and_action_mapping(resets):
    env, s = resets["truth"]
    action = jnp.array([[1.0, -1.0], [0.0, 0.0]])
    s1 = jax.jit(jax.vmap(env.step))(s, action)
    assert s1.obs.shape == (N, 7) and s1.reward.shape == (N,) and s1.done.shape == (N,)
    ps = s1.pipeline_state
    z, vz = np.asarray(ps.qpos[:, 0], float), np.asarray(ps.qvel[:, 0], float)
    h_cmd = np.asarray(s.info["h_cmd"], float)
    want = np.exp(-(((z + np.maximum(vz, 0) ** 2 / (2 * 9.81) - h_cmd) / 0.1) ** 2))
    np.testing.assert_allclose(s1.reward, want, rtol=1e-5)
    np.testing.assert_array_equal(s1.done, 0.0)
    # Targets: home (hip 0.6, knee -1.2) + 0.8 * action.
    np.testing.assert_allclose(ps.ctrl, [[1.4, -2.0], [0.6, -1.2]], rtol=1e-6)
    # Env 1 holds its pose: one env step = 4 physics steps of 2.5 ms of free fall from rest.
    np.testing.assert_allclose(vz[1], -9.81 * 0.01, rtol=1e-3)


def test_blind_task_leaves_out_the_rail_velocity(robot):
    """hop_blind: the same env but its observation is (hip, knee; their rates; command),
    4 + 1 numbers, + 1 for the contact slot; task lookup, run.json name and the hop evaluator
    all reach its configuration."""
    assert tasks.get_task("hop_blind").config("small") is tasks.HOP_SMALL
    assert H.task_config("hop_blind") is H.HOP_BLIND and H.task_config("hop") is H.HOP
    with pytest.raises(ValueError, match="hop task must be one of"):
        H.task_config("go1")
    cfg = dataclasses.replace(tasks.HOP_SMALL, sensor="ideal")
    env_b = tasks.get_task("hop_blind").make_env("truth", cfg)
    env_n = H.make_hop_env("none", H.HOP_BLIND, robot=robot)
    assert (env_b.observation_size, env_n.observation_size) == (6, 5)
    keys = jax.random.split(jax.random.PRNGKey(3), N)
    s = jax.jit(jax.vmap(env_b.reset))(keys)
    s1 = jax.jit(jax.vmap(env_b.step))(s, jnp.array([[1.0, -1.0], [0.0, 0.0]]))
    for st in (s, s1):
        ps = st.pipeline_state
        want = np.concatenate([ps.qpos[:, 1:], ps.qvel[:, 1:]], 1)  # hip, knee; their rates
        np.testing.assert_array_equal(st.obs[:, :4], want)
        np.testing.assert_allclose(st.obs[:, 4], np.asarray(st.info["h_cmd"]) - 0.6, rtol=1e-6)
        np.testing.assert_array_equal(st.obs[:, 5], st.info["contact_est_truth"][:, 0])
    # The rail moved (env 1 falls freely for 10 ms: -0.0981 m/s) but is not observed.
    np.testing.assert_allclose(s1.pipeline_state.qvel[1, 0], -9.81 * 0.01, rtol=1e-3)
    assert not np.any(np.isclose(np.asarray(s1.obs[1]), -0.0981, rtol=1e-2))


def test_array_observation_checkpoint_round_trip(tmp_path):
    """Brax's training save writes an array observation's size as {"shape", "dtype"} (the hop
    task's 7 numbers); load_policy rebuilds the same policy from it."""
    from brax.training.acme import running_statistics, specs
    from brax.training.agents.ppo import checkpoint as ppo_checkpoint

    cfg = dataclasses.replace(tasks.HOP_REDUCED, policy_hidden=(8,), value_hidden=(8,))
    factory = ppo.network_factory(cfg)
    net = factory(7, 2, preprocess_observations_fn=running_statistics.normalize)
    k1, k2 = jax.random.split(jax.random.PRNGKey(1))
    normalizer = running_statistics.init_state(jax.ShapeDtypeStruct((7,), jnp.float32))
    normalizer = normalizer.replace(mean=jnp.full(7, 0.2), std=jnp.full(7, 3.0))
    params = (normalizer, net.policy_network.init(k1), net.value_network.init(k2))
    # What ppo.train passes: specs.Array of the observation's last axis.
    obs_spec = specs.Array((7,), jnp.dtype("float32"))
    conf = ppo_checkpoint.network_config(obs_spec, 2, True, factory)
    ppo_checkpoint.save(str(tmp_path / "checkpoints"), 10, params, conf)
    policy, sizes = policy_eval.load_policy(policy_eval.latest_checkpoint(tmp_path))
    assert sizes == {"state": (7,)}
    obs = jnp.linspace(-1.0, 1.0, 14).reshape(2, 7)
    act, _ = policy(obs, jax.random.PRNGKey(0))
    # Reference: the tanh of the mean half of the policy MLP on the normalised observation.
    logits = net.policy_network.apply(normalizer, params[1], obs)
    np.testing.assert_allclose(act, np.tanh(np.asarray(logits[:, :2])), rtol=1e-5, atol=1e-6)


def test_runs_under_finds_each_variants_seeds_in_order(tmp_path):
    from jax_contact.train import transfer

    for seed in (10, 2, 0):
        for v in ("none", "truth", "estimate"):
            (tmp_path / f"seed{seed}" / v).mkdir(parents=True)
            (tmp_path / f"seed{seed}" / v / "run.json").write_text("{}")
    (tmp_path / "seed3" / "truth").mkdir(parents=True)  # no run.json: not a run
    runs = transfer.runs_under(tmp_path)
    assert list(runs) == ["none", "truth", "estimate"]
    assert [d.parent.name for d in runs["truth"]] == ["seed0", "seed2", "seed10"]
    with pytest.raises(FileNotFoundError, match=r"seed\*/other .*--variants other --seed S"):
        transfer.runs_under(tmp_path, variants=("truth", "other"))
    with pytest.raises(FileNotFoundError, match=r"folder '.*nosuch' does not exist"):
        transfer.runs_under(tmp_path / "nosuch")
    (tmp_path / "afile").write_text("")  # a user trial was told it "does not exist"
    with pytest.raises(FileNotFoundError, match=r"'.*afile' is a file; pass the folder"):
        transfer.runs_under(tmp_path / "afile")
