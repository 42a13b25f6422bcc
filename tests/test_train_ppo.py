"""Tests of the PPO entry point (train/ppo.py) that need no training run.

Training itself is measured, not tested: ``jax-contact train`` (docs/training.md has the
curves). Here: the configurations, the checkpoint round trip through Brax's own ``save``,
the refusals, and the files a run writes. Nothing here compiles an environment step.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training.acme import running_statistics
from brax.training.agents.ppo import checkpoint as ppo_checkpoint
from brax.training.agents.ppo import networks as ppo_networks

from jax_contact.train import figures, policy_eval, ppo

TINY = ppo.PPOConfig(
    num_timesteps=160,
    num_envs=8,
    batch_size=8,
    num_minibatches=2,
    unroll_length=10,
    num_updates_per_batch=1,
    num_evals=2,
    num_eval_envs=4,
    episode_length=50,
    policy_hidden=(16, 16),
    value_hidden=(16,),
)
SIZES = {"state": (52,), "privileged_state": (123,)}  # Go1 joystick + 4 contact features


def test_full_config_is_playgrounds_published_go1_config():
    from mujoco_playground.config import locomotion_params

    ref = locomotion_params.brax_ppo_config(ppo.ENV_NAME)
    full = ppo.FULL
    for f in (
        "num_timesteps",
        "num_envs",
        "batch_size",
        "num_minibatches",
        "unroll_length",
        "num_updates_per_batch",
        "num_evals",
        "episode_length",
        "learning_rate",
        "entropy_cost",
        "discounting",
        "reward_scaling",
        "max_grad_norm",
        "normalize_observations",
        "num_resets_per_eval",
    ):
        assert getattr(full, f) == ref[f], f
    net = ref.network_factory
    assert full.policy_hidden == tuple(net.policy_hidden_layer_sizes)
    assert full.value_hidden == tuple(net.value_hidden_layer_sizes)
    assert (net.policy_obs_key, net.value_obs_key) == ("state", "privileged_state")
    full.validate()
    ppo.SMALL.validate()
    # SMALL: 2,457,600 steps = 6 epochs x 10 training steps x (256 * 8 * 20) env steps.
    assert ppo.SMALL.num_timesteps == (ppo.SMALL.num_evals - 1) * 10 * 40_960


def test_config_refusals_name_the_field():
    with pytest.raises(ValueError, match="num_envs"):
        dataclasses.replace(TINY, batch_size=6).validate()
    with pytest.raises(ValueError, match="PPOConfig.unroll_length"):
        dataclasses.replace(TINY, unroll_length=0).validate()
    with pytest.raises(ValueError, match="one training step"):
        dataclasses.replace(TINY, num_timesteps=10).validate()
    with pytest.raises(ValueError, match="variant must be one of"):
        ppo.train("oracle", TINY, "unused")
    with pytest.raises(ValueError, match="observe must be one of"):
        ppo.make_env("oracle")


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A run folder with one checkpoint written by Brax's own checkpoint.save."""
    run = tmp_path_factory.mktemp("run") / "truth"
    factory = ppo.network_factory(TINY)
    net = factory(SIZES, 12, preprocess_observations_fn=running_statistics.normalize)
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    spec = {k: jax.ShapeDtypeStruct(v, jnp.float32) for k, v in SIZES.items()}
    normalizer = running_statistics.init_state(spec)
    # Non-trivial normaliser statistics, so that a loader ignoring them would differ.
    normalizer = normalizer.replace(
        mean={k: jnp.full(v, 0.3) for k, v in SIZES.items()},
        std={k: jnp.full(v, 2.0) for k, v in SIZES.items()},
    )
    params = (normalizer, net.policy_network.init(k1), net.value_network.init(k2))
    config = ppo_checkpoint.network_config(SIZES, 12, True, factory)
    ppo_checkpoint.save(run / "checkpoints", 160, params, config)
    (run / "run.json").write_text(
        json.dumps({"variant": "truth", "config": dataclasses.asdict(TINY)})
    )
    return run, net, params


def test_checkpoint_round_trip_gives_the_same_policy(saved):
    run, net, params = saved
    ckpt = policy_eval.latest_checkpoint(run)
    assert ckpt.name == f"{160:012d}"
    policy, sizes = policy_eval.load_policy(ckpt)
    assert sizes == SIZES
    ref = ppo_networks.make_inference_fn(net)(params, deterministic=True)
    obs = {
        k: jax.random.normal(jax.random.PRNGKey(i), (3,) + v)
        for i, (k, v) in enumerate(SIZES.items())
    }
    got = policy(obs, jax.random.PRNGKey(1))[0]
    want = ref(obs, jax.random.PRNGKey(1))[0]
    assert got.shape == (3, 12)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
    # Why policy_eval.load_policy exists: Brax 0.14.2 cannot read back the None initialiser its
    # own save wrote. If this starts passing, Brax's loader can replace ours.
    with pytest.raises(KeyError):
        ppo_checkpoint.load_config(ckpt)


def test_zero_initialised_mean_round_trips_and_holds_the_default_pose(tmp_path):
    """SMALL's policy starts with a zero mean layer: the saved configuration names the
    'constant' initialiser with its kwargs, loads back, and the untrained deterministic
    action is tanh(0) = 0 (the default pose) for any observation."""
    cfg = dataclasses.replace(TINY, distribution="normal", zero_init_mean=True, init_noise_std=0.5)
    factory = ppo.network_factory(cfg)
    net = factory(SIZES, 12, preprocess_observations_fn=running_statistics.normalize)
    spec = {k: jax.ShapeDtypeStruct(v, jnp.float32) for k, v in SIZES.items()}
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    params = (
        running_statistics.init_state(spec),
        net.policy_network.init(k1),
        net.value_network.init(k2),
    )
    ppo_checkpoint.save(
        tmp_path, 0, params, ppo_checkpoint.network_config(SIZES, 12, True, factory)
    )
    config = json.loads((tmp_path / f"{0:012d}" / "ppo_network_config.json").read_text())
    kw = config["network_factory_kwargs"]
    assert kw["mean_kernel_init_fn"] == "constant"
    assert kw["mean_kernel_init_kwargs"] == {"value": 0.0}
    assert (kw["init_noise_std"], kw["distribution_type"]) == (0.5, "normal")
    policy, _ = policy_eval.load_policy(tmp_path / f"{0:012d}")
    obs = {k: 3.0 * jax.random.normal(jax.random.PRNGKey(5), (4,) + v) for k, v in SIZES.items()}
    np.testing.assert_array_equal(policy(obs, jax.random.PRNGKey(0))[0], np.zeros((4, 12)))


def test_evaluate_refuses_an_observation_the_network_cannot_take(saved, tmp_path):
    run, _, _ = saved
    with pytest.raises(ValueError, match=r"shape \(48,\); the checkpoint .* takes \(52,\)"):
        policy_eval.evaluate_policy(run, observe="none", n_envs=2, episode_length=5)
    with pytest.raises(FileNotFoundError, match="no run.json"):
        policy_eval.evaluate_policy(tmp_path)
    (tmp_path / "run.json").write_text(run.joinpath("run.json").read_text())
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        policy_eval.evaluate_policy(tmp_path)
    # A finished run whose checkpoints are gone, and a run folder beside the run an
    # --overwrite set aside (killed before its first checkpoint): said so, not "train first".
    (tmp_path / "checkpoints").mkdir()
    with pytest.raises(FileNotFoundError, match="says its training finished, but its checkpoints"):
        policy_eval.latest_checkpoint(tmp_path)
    (tmp_path.parent / f"{tmp_path.name}.earlier").mkdir()
    with pytest.raises(
        FileNotFoundError, match=rf"the run it replaced is in .*{tmp_path.name}.earlier"
    ):
        policy_eval.latest_checkpoint(tmp_path)
    (tmp_path.parent / f"{tmp_path.name}.earlier").rmdir()
    # A save stopped midway (Brax made the step folder; its config, written last, is not
    # there) is passed over for the newest finished one, or named when it is the only one.
    stopped = tmp_path / "checkpoints" / "000000000320"
    stopped.mkdir()
    with pytest.raises(FileNotFoundError, match=r"folder \(000000000320\) was not finished"):
        policy_eval.latest_checkpoint(tmp_path)
    done = tmp_path / "checkpoints" / "000000000160"
    done.mkdir()
    (done / "ppo_network_config.json").write_text("{}")
    (stopped / "ppo_network_config.json").write_text('{"network_factory_kw')  # cut short
    assert policy_eval.latest_checkpoint(tmp_path) == done


def test_policy_eval_checks_the_run_record_before_jax(saved, tmp_path):
    """`policy-eval`'s argument check (standard library) reads run.json: a parameter file
    stored as a relative path (what `train --params` used to store), a sensor it does not
    know, and an observation the policy was not trained on are refused naming run.json,
    where a user trial waited ~10 s for JAX to load before each."""
    from jax_contact.train.cli_args import check_run_record

    run, _, _ = saved  # trained with "truth"
    check_run_record("run", run, None)
    check_run_record("run", run, "estimate_harsh")
    with pytest.raises(
        ValueError,
        match=r"trained with 'truth' .*run.json'\): its policy sees a"
        r" contact observation, so it can observe one of truth, .*, not 'none'",
    ):
        check_run_record("run", run, "none")
    record = json.loads((run / "run.json").read_text())
    for change, match in (
        ({"estimator_params": "rel.json"}, r"names the parameter file 'rel.json' .*absolute path"),
        ({"estimator_params": "go1"}, None),  # a shipped preset
        ({"sensor": "foo"}, r"config.sensor 'foo' is not one of \('ideal'"),
    ):
        (tmp_path / "run.json").write_text(
            json.dumps(record | {"config": record["config"] | change})
        )
        if match is None:
            check_run_record("run", tmp_path, None)
        else:
            with pytest.raises(ValueError, match=rf"^argument run: '{tmp_path}/run.json'.*{match}"):
                check_run_record("run", tmp_path, None)
    (tmp_path / "run.json").write_text(json.dumps(record | {"variant": "none"}))
    with pytest.raises(ValueError, match=r"policy sees no contact, so it can observe only none"):
        check_run_record("run", tmp_path, "estimate_lat1")
    check_run_record("run", tmp_path, "none")
    # A hop run the same (only Go1's was checked: a user waited for JAX to be told that
    # "an observation of size 7" does not fit "(6,)").
    (tmp_path / "run.json").write_text(json.dumps(record | {"variant": "none", "task": "hop"}))
    with pytest.raises(ValueError, match=r"policy sees no contact, so it can observe only none"):
        check_run_record("run", tmp_path, "estimate_harsh")
    (tmp_path / "run.json").write_text(json.dumps(record | {"task": "hop_blind"}))
    with pytest.raises(ValueError, match=r"sees a contact observation, .* not 'none'"):
        check_run_record("run", tmp_path, "none")


def test_a_damaged_run_folder_is_named_in_one_line(saved, tmp_path, monkeypatch):
    """What a user's disk can do to a run folder: each is a ValueError naming the file (the
    CLI prints it as one line), where JSON's and orbax's own messages named none."""
    run, _, _ = saved
    copy = tmp_path / "truth"
    shutil.copytree(run, copy)
    good = (copy / "run.json").read_text()
    for text, match in (
        ("hello", r"truth/run.json is not JSON \(Expecting value"),
        ("[1]", "run.json holds no JSON object"),
        (good.replace('"truth"', '"bogus"'), r"variant 'bogus' is not one of \('none'"),
        (good.replace('"num_envs"', '"n_envs"'), r"config is not a PPOConfig .*'n_envs'"),
        # A hand-edited task read as "unknown env 'PlanarLegHop'" (a helper's audit).
        (good.replace("{", '{"task": "go2", ', 1), r"run.json: task 'go2' is not one of \("),
    ):
        (copy / "run.json").write_text(text)
        with pytest.raises(ValueError, match=match):
            policy_eval.evaluate_policy(copy, n_envs=2)
    (copy / "run.json").write_text(good)
    ckpt = policy_eval.latest_checkpoint(copy)
    with pytest.raises(
        FileNotFoundError, match=f"checkpoint folder: pass its run folder, '{copy}'"
    ):
        policy_eval.evaluate_policy(ckpt)
    # train's --out, one level above its run folders (a helper's audit: "no run.json" only).
    with pytest.raises(FileNotFoundError, match=r"it holds the run folders \['truth'\]: pass one"):
        policy_eval.evaluate_policy(copy.parent, n_envs=2)
    config = ckpt / "ppo_network_config.json"
    config.write_text("{")
    with pytest.raises(ValueError, match=r"ppo_network_config.json is not JSON .*--overwrite"):
        policy_eval.load_policy(ckpt)
    config.write_text("{}")
    with pytest.raises(ValueError, match=r"not a Brax PPO network config \(missing \['network"):
        policy_eval.load_policy(ckpt)
    shutil.copy(run / ckpt.relative_to(copy) / config.name, config)
    for blob in (ckpt / "d").rglob("*"):  # every data file cut short
        if blob.is_file():
            blob.write_bytes(blob.read_bytes()[:10])
    # The failed restore's reads still in flight reported to orbax's closed event loop:
    # 14-17 tracebacks "RuntimeError: Event loop is closed" through sys.unraisablehook
    # around the one-line error. Those are dropped; any other unraisable still reaches
    # the hook that was there.
    import sys
    import time
    import types

    reached = []
    monkeypatch.setattr(sys, "unraisablehook", reached.append)
    with pytest.raises(ValueError, match=f"the parameters in {ckpt} cannot be read"):
        policy_eval.load_policy(ckpt)
    time.sleep(1.0)  # the late reports arrive within ~0.1 s
    assert reached == [], [str(u.exc_value) for u in reached]
    other = types.SimpleNamespace(exc_value=RuntimeError("something else"))
    sys.unraisablehook(other)
    assert reached == [other]


def test_a_damaged_checkpoint_is_one_line_without_orbaxs_log(saved, tmp_path, caplog):
    """A garbage _METADATA: our one-line error, and none of orbax's absl WARNING lines
    ("Failed to get item metadata ..."), which a user trial saw printed above it."""
    import logging

    run, _, _ = saved
    copy = tmp_path / "truth"
    shutil.copytree(run, copy)
    ckpt = policy_eval.latest_checkpoint(copy)
    (ckpt / "_METADATA").write_text("garbage")
    with caplog.at_level(logging.WARNING, logger="absl"):
        with pytest.raises(ValueError, match=f"the parameters in {ckpt} cannot be read"):
            policy_eval.load_policy(ckpt)
    assert not [r for r in caplog.records if r.name == "absl"], caplog.text


def test_an_unfinished_run_is_evaluated_with_a_warning(saved, tmp_path):
    run, _, _ = saved
    copy = tmp_path / "truth"
    shutil.copytree(run, copy)
    info = json.loads((copy / "run.json").read_text()) | {"finished": False}
    (copy / "run.json").write_text(json.dumps(info))
    # The warning comes before any env is built; the observation check then refuses.
    with pytest.warns(UserWarning, match=r"training did not finish .* checkpoint, 000000000160"):
        with pytest.raises(ValueError, match=r"observing 'none' gives a policy observation"):
            policy_eval.evaluate_policy(copy, observe="none", n_envs=2, episode_length=5)


def test_train_refuses_an_existing_run_folder(tmp_path):
    (tmp_path / "estimate").mkdir()
    (tmp_path / "estimate" / "progress.csv").write_text("keep me\n")
    with pytest.raises(ValueError, match="exists and is not empty: pass --overwrite"):
        ppo.train("estimate", TINY, tmp_path)
    assert (tmp_path / "estimate" / "progress.csv").read_text() == "keep me\n"
    # A run whose training never returned (Ctrl-C) is named as such.
    (tmp_path / "estimate" / "run.json").write_text('{"variant": "estimate", "finished": false}')
    with pytest.raises(ValueError, match="holds an unfinished run .*: pass --overwrite"):
        ppo.train("estimate", TINY, tmp_path)


def test_overwrite_keeps_the_earlier_run_until_the_new_ones_first_checkpoint(tmp_path, monkeypatch):
    """`train --overwrite` deleted the earlier run when the new one started: stopped before
    its first checkpoint, neither was left. The earlier run is now set aside beside it and
    put back if the new run stops first (an error here; Ctrl-C asks the same note), deleted
    once the new run has a checkpoint or finishes."""
    from jax_contact.train import interrupt
    from jax_contact.train.run_folder import EarlierRun, earlier_path

    monkeypatch.setattr(interrupt, "_discarded", [])
    run = tmp_path / "estimate"

    def checkpoint(step: int, finished: bool = True):  # Brax writes the config file last
        folder = run / "checkpoints" / f"{step:012d}"
        folder.mkdir(parents=True)
        if finished:
            (folder / "ppo_network_config.json").write_text("{}")

    checkpoint(160)
    (run / "progress.csv").write_text("earlier\n")
    aside = earlier_path(run)
    assert aside == tmp_path / "estimate.earlier"

    def fails(run_dir, *args, **kwargs):  # the new run starts, then stops: no checkpoint
        run_dir.mkdir()
        (run_dir / "run.json").write_text('{"finished": false}')
        assert (aside / "progress.csv").read_text() == "earlier\n"  # set aside meanwhile
        raise RuntimeError("stopped")

    monkeypatch.setattr(ppo, "_train_into", fails)
    with pytest.raises(RuntimeError, match="stopped"):
        ppo.train("estimate", TINY, tmp_path, overwrite=True)
    assert (run / "progress.csv").read_text() == "earlier\n" and not aside.exists()
    assert not (run / "run.json").exists()  # the new run's files went with it
    # The note a Ctrl-C prints does the same, and says so; the files the new run had
    # written there are no longer listed as written (a user trial found them listed).
    earlier = EarlierRun(run, True)
    run.mkdir()
    assert "the earlier run is back in" in earlier.note()
    other = tmp_path / "estimate2" / "run.json"
    assert interrupt.still_written([str(run / "run.json"), str(other)]) == [str(other)]
    assert (run / "progress.csv").read_text() == "earlier\n" and not aside.exists()
    # A save stopped midway (the step folder made, the config not yet written) is no
    # checkpoint: the earlier run comes back (the audit found it deleted, the new run's
    # half-written folder kept as "the checkpoints saved so far").
    earlier = EarlierRun(run, True)
    checkpoint(320, finished=False)
    earlier.settle()
    assert aside.exists()
    assert "the earlier run is back in" in earlier.note()
    assert (run / "progress.csv").read_text() == "earlier\n" and not aside.exists()
    # Once the new run has a checkpoint it stays and the earlier one goes.
    earlier = EarlierRun(run, True)
    checkpoint(320)
    earlier.settle()
    assert not aside.exists() and not (run / "progress.csv").exists()
    assert "checkpoints saved so far" in earlier.note()
    # A finished run drops it too, checkpoint or not.
    earlier = EarlierRun(run, True)
    run.mkdir()
    earlier.drop()
    assert not aside.exists() and run.is_dir()
    # A run set aside by a process killed outright (no note ran) blocks the folder, named.
    aside.mkdir()
    with pytest.raises(ValueError, match=r"estimate.earlier holds the run that an --overwrite"):
        ppo.check_run_folder(run, True)
    # A new run into a free folder that stops (an error, or Ctrl-C's note) before its first
    # checkpoint leaves nothing: its folder held a run.json only, and blocked the next train.
    shutil.rmtree(aside)
    shutil.rmtree(run)

    def stops(run_dir, *args, **kwargs):
        run_dir.mkdir()
        (run_dir / "run.json").write_text('{"finished": false}')
        raise RuntimeError("stopped")

    monkeypatch.setattr(ppo, "_train_into", stops)
    with pytest.raises(RuntimeError, match="stopped"):
        ppo.train("estimate", TINY, tmp_path)
    assert not run.exists() and ppo.check_run_folder(run, False) is False
    run.mkdir()
    (run / "run.json").write_text('{"finished": false}')
    assert "nothing of the run is kept" in EarlierRun(run, False).note() and not run.exists()


def _fake_train(calls):
    """``ppo.train`` without training: the run folder's run.json and one progress row."""

    def train(variant, cfg, out_dir, *, seed=0, overwrite=False, log=print, task="go1"):
        calls.append(variant)
        run_dir = Path(out_dir) / variant
        if ppo.check_run_folder(run_dir, overwrite):
            shutil.rmtree(run_dir)
        run_dir.mkdir(parents=True)
        (run_dir / "run.json").write_text(json.dumps({"variant": variant, "finished": True}))
        row = dict.fromkeys(ppo.CSV_FIELDS, 1.0) | {"step": len(calls)}
        return ppo.RunResult(run_dir, [row], [], wall_s=1.0, first_eval_s=0.5)

    return train


def test_a_second_train_into_the_same_folder_keeps_the_first(tmp_path, monkeypatch):
    """`train --variants estimate` then `train --variants none` into one --out: the summary
    and the curve files hold both runs (the second call used to drop the first's); a
    summary of another configuration or seed is refused before any training, as is an
    existing run folder of any variant asked for."""
    calls = []
    monkeypatch.setattr(ppo, "train", _fake_train(calls))
    log = []
    ppo.train_variants(TINY, tmp_path, variants=["estimate"], eval_envs=0, log=log.append)
    first = json.loads((tmp_path / "summary.json").read_text())
    summary = ppo.train_variants(TINY, tmp_path, variants=["none"], eval_envs=0, log=log.append)
    assert list(summary["runs"]) == ["estimate", "none"]
    assert summary["runs"]["estimate"] == first["runs"]["estimate"]
    csv_rows = (tmp_path / "reward_curves.csv").read_text().splitlines()[1:]
    assert [r.split(",")[:2] for r in csv_rows] == [["estimate", "1"], ["none", "2"]]
    assert any("kept the earlier runs" in m and "estimate" in m for m in log)
    assert any(m.startswith("wrote summary.json") for m in log)
    # Another seed: refused before training, nothing changed; --overwrite replaces it.
    before = (tmp_path / "summary.json").read_text()
    with pytest.raises(
        ValueError,
        match=r"holds the runs \['estimate', 'none'\] of another seed \(seed 0, not 1\)",
    ):
        ppo.train_variants(TINY, tmp_path, variants=["truth"], seed=1, eval_envs=0, log=log.append)
    # Another configuration: the fields that differ are named (it said "; see its config").
    other = dataclasses.replace(TINY, num_timesteps=TINY.num_timesteps * 2)
    with pytest.raises(
        ValueError,
        match=rf"of another config \(config: num_timesteps {TINY.num_timesteps}, not"
        rf" {2 * TINY.num_timesteps}\)",
    ):
        ppo.train_variants(other, tmp_path, variants=["truth"], eval_envs=0, log=log.append)
    assert calls == ["estimate", "none"] and (tmp_path / "summary.json").read_text() == before
    summary = ppo.train_variants(
        TINY, tmp_path, variants=["truth"], seed=1, overwrite=True, eval_envs=0, log=log.append
    )
    assert list(summary["runs"]) == ["truth"]
    # "estimate" (its folder removed) and "none" asked for, "none" already trained: refused
    # before "estimate" trains.
    shutil.rmtree(tmp_path / "estimate")
    with pytest.raises(ValueError, match=r"run folder .*none exists and is not empty"):
        ppo.train_variants(TINY, tmp_path, variants=["estimate", "none"], seed=1, eval_envs=0)
    assert calls == ["estimate", "none", "truth"]
    # The summary figure is titled by the task's env (it read "Go1 joystick" for the hop).
    from jax_contact.train import figures

    titles = []
    monkeypatch.setattr(figures, "plot_reward_curves", lambda *a, title, **k: titles.append(title))
    ppo.train_variants(TINY, tmp_path / "hop", variants=["none"], eval_envs=0, task="hop")
    ppo.train_variants(TINY, tmp_path / "go1", variants=["none"], eval_envs=0)
    assert titles == ["PlanarLegHop, PPO", "Go1JoystickFlatTerrain, PPO"]
    other = tmp_path / "other"
    other.mkdir()
    (other / "summary.json").write_text("{")
    with pytest.raises(ValueError, match="summary.json is not a summary of jax-contact train"):
        ppo.train_variants(TINY, other, variants=["truth"], eval_envs=0)


def test_a_stopped_overwrite_leaves_no_summary_of_the_replaced_run(tmp_path, monkeypatch):
    """`train --variants estimate --overwrite` into a folder whose summary lists a finished
    `estimate`, stopped during the new run (after its first checkpoint): the summary still
    said the replaced run had finished, with its wall time and returns, beside the new
    unfinished folder (a helper's trial). It is rewritten before the first run, without
    the replaced run, and keeps the other variant's."""
    calls = []
    monkeypatch.setattr(ppo, "train", _fake_train(calls))
    ppo.train_variants(TINY, tmp_path, variants=["estimate", "none"], eval_envs=0, log=print)
    assert list(json.loads((tmp_path / "summary.json").read_text())["runs"]) == [
        "estimate",
        "none",
    ]

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(ppo, "train", stopped)
    with pytest.raises(KeyboardInterrupt):
        ppo.train_variants(
            TINY, tmp_path, variants=["estimate"], overwrite=True, eval_envs=0, log=print
        )
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["runs"]) == ["none"] and summary["final_evaluation"] == "pending"
    csv_rows = (tmp_path / "reward_curves.csv").read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in csv_rows] == ["none"]


def test_a_stop_in_the_final_evaluation_keeps_the_finished_runs(tmp_path, monkeypatch):
    """A user trial stopped `train --variants estimate` (Ctrl-C) during its final
    evaluation: the run had finished, but no summary.json was written, so the next `train
    --variants none` into the folder summarised `none` alone. The summary is now written
    after each run (final_evaluation "pending") and again after the evaluation."""
    from jax_contact.train import policy_eval

    calls = []
    monkeypatch.setattr(ppo, "train", _fake_train(calls))

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(policy_eval, "evaluate_policy", stopped)
    with pytest.raises(KeyboardInterrupt):
        ppo.train_variants(TINY, tmp_path, variants=["estimate", "truth"], log=print)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["runs"]) == ["estimate", "truth"]
    assert summary["final_evaluation"] == "pending" and summary["evaluation"] == []
    summary = ppo.train_variants(TINY, tmp_path, variants=["none"], eval_envs=0, log=print)
    assert list(summary["runs"]) == ["estimate", "truth", "none"]
    assert summary["final_evaluation"] == "skipped"
    csv_rows = (tmp_path / "reward_curves.csv").read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in csv_rows] == ["estimate", "truth", "none"]


def test_progress_csv_and_curve_files(tmp_path):
    rows = [
        {
            "step": 0,
            "wall_s": 10.0,
            "eval_reward": 0.5,
            "eval_reward_std": 0.1,
            "eval_episode_length": 30.0,
            "eval_contact_accuracy": 0.7,
        },
        {
            "step": 40960,
            "wall_s": 70.5,
            "eval_reward": 2.5,
            "eval_reward_std": 0.4,
            "eval_episode_length": 300.0,
            "eval_contact_accuracy": 0.9,
        },
    ]
    (tmp_path / "progress.csv").write_text(ppo._csv_text(rows))
    back = ppo.read_progress(tmp_path)
    assert back == [{k: float(v) for k, v in r.items()} for r in rows]
    train_rows = [
        {"step": 81920, "wall_s": 30.0, "train_episode_return": -1.5, "train_episode_length": 40.0}
    ]
    (tmp_path / "training.csv").write_text(ppo._csv_text(train_rows, ppo.TRAIN_FIELDS))
    assert ppo.read_progress(tmp_path, "training.csv") == train_rows
    png = figures.plot_reward_curves(
        {"estimate": back}, tmp_path / "curve.png", training={"estimate": train_rows}
    )
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp left


def test_unclipped_reward_is_the_sum_of_the_scaled_terms():
    """Playground's Go1 reward is clip(sum(scaled terms) * dt, 0); the wrapper drops the
    clip: terms 2.0 and -5.0 at dt 0.02 give (2 - 5) * 0.02 = -0.06 where the env says 0."""
    from mujoco_playground._src import mjx_env

    class Fake:
        dt = 0.02

        @property
        def unwrapped(self):
            return self

        def step(self, state, action):
            metrics = {
                "reward/tracking": jnp.float32(2.0),
                "reward/orientation": jnp.float32(-5.0),
                "swing_peak": jnp.float32(7.0),
            }
            return state.replace(reward=jnp.float32(0.0), metrics=metrics)

    state = mjx_env.State(None, jnp.zeros(3), jnp.float32(0.0), jnp.float32(0.0), {}, {})
    out = ppo.UnclippedReward(Fake()).step(state, jnp.zeros(2))
    np.testing.assert_allclose(out.reward, -0.06, rtol=1e-6)

    class Silent(Fake):
        def step(self, state, action):
            return state

    with pytest.raises(ValueError, match="no reward/<term> metrics"):
        ppo.UnclippedReward(Silent()).step(state, jnp.zeros(2))
    with pytest.raises(ValueError, match="PPOConfig.reward"):
        dataclasses.replace(TINY, reward="shaped").validate()


def test_eval_row_takes_the_episode_accuracy_as_brax_sums_it():
    # The wrapper's metric is the per-step increment of the running accuracy, so Brax's
    # EvalWrapper sum over a 40-step episode with 34 of 40 updates right is 0.85 (checked on
    # the wrapper itself by test_wrapper_substeps' episode-mean test); dividing it by the
    # episode length again (0.85 / 40 = 0.021) was the bug this pins.
    m = {
        "eval/episode_reward": 3.0,
        "eval/episode_reward_std": 0.5,
        "eval/avg_episode_length": 40.0,
        "eval/episode_contact_est/accuracy": 0.85,
    }
    row = ppo.eval_row(1000, 12.34, m, "eval/episode_contact_est/accuracy")
    assert row == {
        "step": 1000,
        "wall_s": 12.3,
        "eval_reward": 3.0,
        "eval_reward_std": 0.5,
        "eval_episode_length": 40.0,
        "eval_contact_accuracy": 0.85,
    }
    assert np.isnan(ppo.eval_row(0, 0.0, m | {}, "eval/missing")["eval_contact_accuracy"])


def test_estimator_params_reach_the_wrapper_and_the_run_record():
    """``PPOConfig.estimator_params`` (``jax-contact train --params``) is what the wrapped
    env runs, in training and in every transfer column; a run.json written before the field
    existed reads back with the wrapper's defaults; the hop task refuses a file."""
    from jax_contact.train import tasks

    cfg = dataclasses.replace(TINY, estimator_params="go1_playground")
    env = tasks.get_task("go1").make_env("estimate", cfg)
    core = env.contact_core
    assert core.params_source == "go1_playground" and core.calibration is not None
    col = policy_eval.column_env("estimate_harsh", cfg).contact_core
    assert col.params_source == "go1_playground"
    run = {"config": dataclasses.asdict(cfg)}
    assert ppo.config_of(json.loads(json.dumps(run))) == cfg
    del run["config"]["estimator_params"]  # an older run.json
    assert ppo.config_of(run).estimator_params is None
    with pytest.raises(ValueError, match="estimator_params: the hop task"):
        tasks.get_task("hop").make_env("estimate", cfg)


def test_playground_tasks_take_playgrounds_settings_for_their_env():
    """`jax-contact train --task NAME` for any offline Playground locomotion env: its
    configurations are Playground's published ones for that env (a field left out takes
    Brax PPO's default, as Playground's training script does); the run's env, its critic's
    observation key and its record follow the name."""
    from jax_contact.train import tasks

    # The general route on Go1's joystick gives the two configurations checked by hand
    # against Playground's above.
    assert dict(tasks.playground_configs(ppo.ENV_NAME)) == {"small": ppo.SMALL, "full": ppo.FULL}
    assert tasks.get_task("Go1JoystickFlatTerrain").name == "go1"
    # Values read off Playground's locomotion_params for SpotGetup: 100 M steps, 300-step
    # episodes, critic on "state", no clipping_epsilon (Brax's default 0.3), 10 resets.
    spot = tasks.get_task("SpotGetup")
    small, full = (dict(spot.configs)[c] for c in ("small", "full"))
    assert (spot.name, spot.env_name) == ("SpotGetup", "SpotGetup")
    assert (full.num_timesteps, full.episode_length, full.value_obs_key) == (
        100_000_000,
        300,
        "state",
    )
    assert (full.clipping_epsilon, full.num_resets_per_eval, full.num_evals) == (0.3, 10, 10)
    assert full.policy_hidden == (128, 128, 128, 128)
    assert full.value_hidden == (256, 256, 256, 256, 256)
    # small: this CPU's size, networks and reward; the env's episodes and keys.
    assert (small.num_envs, small.num_timesteps, small.policy_hidden, small.reward) == (
        256, 2_457_600, (128, 128, 128), "unclipped"
    )  # fmt: skip
    assert (small.episode_length, small.value_obs_key) == (300, "state")
    # T1 sets clipping_epsilon 0.2 and its critic reads "privileged_state".
    t1 = dict(tasks.get_task("T1JoystickFlatTerrain").configs)["full"]
    assert (t1.clipping_epsilon, t1.value_obs_key, t1.num_evals) == (0.2, "privileged_state", 20)
    with pytest.raises(ValueError, match="task must be one of"):
        tasks.get_task("SpotJoystick")
    # The critic reads the configured key (a dict observation without "privileged_state"
    # would be refused with the default).
    sizes = {"state": (10,)}
    for cfg in (dataclasses.replace(TINY, value_obs_key="state"), TINY):
        factory = ppo.network_factory(cfg)
        if cfg.value_obs_key == "state":
            factory(sizes, 3, preprocess_observations_fn=running_statistics.normalize)
        else:
            with pytest.raises(KeyError, match="privileged_state"):
                factory(sizes, 3, preprocess_observations_fn=running_statistics.normalize)
    # A run of it is evaluated in its own env (run.json's "env"), not Go1's.
    env = policy_eval.ColumnEvaluator(small, 4, env_name="SpotGetup").env("estimate")
    assert type(env.unwrapped).__module__.endswith("spot.getup")
    assert env.contact_core.cfg.observe == "estimate"
    # Spot's envs observe one array: the policy reads all of it, 4 features appended.
    assert policy_eval.policy_obs_shape(env) == (env.env.observation_size + 4,)
