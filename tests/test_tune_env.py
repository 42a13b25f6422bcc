"""``jax-contact tune-env``: tuning the wrapper's estimator on a wrapped env's own rollouts.

The one claim that makes the command worth having is that it fits what the wrapper sees:
the inputs rebuilt offline from the recorded readings (``Core.measure``) must give the
live wrapper's beliefs. Checked on the planar-leg scene of ``jax-contact rates`` (cheap to
compile; quadrature touch-down, so the filter is deterministic whatever the key). The
command itself runs end to end on the same scene at the same size, so its recording loads
from the compilation cache the first test filled.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import warnings

import jax
import numpy as np
import pytest

import jax_contact as jc
from jax_contact import tune as jt
from jax_contact.train import cli, env_rollouts, tune_env

STEPS, ROLLOUTS = 40, 2  # 40 env steps of 20 ms = 320 physics steps of 2.5 ms


@pytest.fixture(scope="module")
def recorded():
    rec, scene = env_rollouts.record_scene("planar_leg", 3, STEPS, ROLLOUTS)
    return rec, scene, env_rollouts.tuning_data(rec, chunk=STEPS * 8)


def test_rebuilt_inputs_give_the_live_wrappers_beliefs(recorded):
    rec, scene, data = recorded
    assert rec.core.params.touchdown == "quadrature"
    assert rec.truth.shape == (STEPS * 8, ROLLOUTS, 1) and data.meas.M.shape[:2] == (STEPS * 8, 2)
    assert rec.truth[rec.valid].any() and not rec.truth[rec.valid].all()  # it hops
    logits = np.asarray(
        jt.predict_logits(rec.core.params, rec.core.terrain, data, key=jax.random.key(0))
    )
    p = 1.0 / (1.0 + np.exp(-logits.astype(np.float64)))
    # float32 on both sides, the same graph fused differently by XLA (tests/test_timing.py).
    np.testing.assert_allclose(p, rec.p_contact, atol=2e-4)
    # 0.2 s of 2.5 ms steps left out at the start; nothing ends early in this scene.
    assert scene.skip_s == 0.2
    assert not rec.valid[:80].any() and rec.valid[80:].all()


def test_valid_and_held_by_hand():
    # 3 env steps x 2 substeps, 2 envs. Env 0 is done after env step 1 (so its physics
    # steps 2, 3 and everything after are out); env 1 reads NaN at physics step 4.
    q = np.arange(12, dtype=np.float32).reshape(6, 2, 1)
    q[4, 1, 0] = np.nan
    readings = {"q": q}
    done = np.array([[0, 0], [1, 0], [0, 0]], np.float32)
    valid, held = env_rollouts.valid_and_held(readings, done, n_sub=2, dt=0.1, skip_s=0.1)
    expected = np.array([[0, 0], [1, 1], [0, 1], [0, 1], [0, 0], [0, 0]], bool)
    np.testing.assert_array_equal(valid, expected)
    # Env 0 holds physics step 1's reading (2.0) from step 2 on; env 1 step 3's (7.0).
    np.testing.assert_array_equal(held["q"][:, 0, 0], [0, 2, 2, 2, 2, 2])
    np.testing.assert_array_equal(held["q"][:, 1, 0], [1, 3, 5, 7, 7, 7])


def test_tune_env_writes_a_file_the_wrapper_loads(recorded, tmp_path, capsys):
    out = tmp_path / "leg.json"
    argv = ["planar_leg", "--seeds", "3", "--validate-seed", "4", "--out", str(out)]
    argv += ["--steps", str(STEPS), "--rollouts", str(ROLLOUTS), "--epochs", "1"]
    argv += ["--chunk", str(STEPS * 8), "--calibrate"]
    # Through the command line's own entry point, as a user runs it (its parsed arguments
    # go into the file's provenance: a non-JSON one there broke every `jax-contact tune`).
    assert cli.main(["tune-env", *argv]) == 0
    err = capsys.readouterr().err
    assert "recorded planar_leg seed 3" in err and "epoch  1/1" in err
    # A rates scene replays one motion at every seed: validating on one is noted.
    assert "planar_leg: a `jax-contact rates` scene plays the same motion at every seed" in err
    params, prov = jc.load_params(out, with_provenance=True)
    rec = recorded[0]
    assert params.nv == rec.core.params.nv and float(params.dt) == pytest.approx(rec.dt)
    assert [i["seed"] for i in prov["logs"]] == [3] and prov["validation"][0]["seed"] == 4
    assert prov["logs"][0]["scene"] == "planar_leg" and prov["calibration"]["kind"] == "sign"
    assert prov["tool"] == "jax-contact tune-env"
    # The planar leg's mass, envs/assets/planar_leg.xml: base 5.449 + thigh 2.48 + shank 0.31.
    assert prov["robot_mass_kg"] == pytest.approx(5.449 + 2.48 + 0.31)
    # Seed 3 here is the fixture's recording: the same rollouts, to the bit.
    assert prov["logs"][0]["valid_steps"] == int(rec.valid.sum())
    from jax_contact.envs.contact_config import ContactObsConfig

    # The feet and sole point it was fitted with (the planar leg's one foot, the default).
    feet = prov["logs"][0]["feet"]
    assert feet == list(rec.core.desc.foot_names) and len(feet) == 1
    assert prov["logs"][0]["sole"] == ContactObsConfig().sole
    # The file goes back into the wrapper at the scene's physics rate, its map with it.
    from jax_contact.envs.contact_wrappers import wrap_contact

    env = env_rollouts.load_scene("planar_leg", 1, 1).env
    core = wrap_contact(env, ContactObsConfig(params=str(out))).contact_core
    assert core.params_source == str(out) and core.calibration is not None
    np.testing.assert_allclose(
        np.asarray(core.params.noise.sigma_qd), np.asarray(params.noise.sigma_qd)
    )
    json.loads(out.read_text())  # one complete JSON file (written atomically)


def _constant_policy(env, c):
    """A closed-loop policy's signature, ``(obs, key) -> (action, extras)``: ``c`` on every
    actuator, read through the observation so that the wrapped obs must reach it."""
    import jax.numpy as jnp

    def policy(obs, key):
        o = obs["state"] if isinstance(obs, dict) else obs
        return jnp.full((env.action_size,), c) + 0.0 * jnp.sum(o), {}

    return policy


def test_a_policy_in_the_loop_drives_the_recording(recorded):
    # The scene's actions minus c, plus a policy that adds c, are the scene's actions up to
    # float32 rounding of (a - c) + c; the resets and the sensor noise draw the same keys
    # as without a policy (its keys come from fold_in(key, 1)). So the recording is the
    # fixture's: the same truth and beliefs within the rounding's effect (measured: P
    # 1.1e-4, qpos 2.9e-6; without the policy's action the knee would be 0.25 rad off, and
    # with other sensor keys qvel would differ by its 0.3 rad/s noise).
    rec, scene, _ = recorded
    c = 0.25
    record = env_rollouts.recorder(
        scene.env, skip_s=scene.skip_s, policy=_constant_policy(scene.env, c)
    )
    got = record(scene.actions_of(3) - c, jax.random.PRNGKey(3))
    np.testing.assert_array_equal(got.truth, rec.truth)
    np.testing.assert_array_equal(got.valid, rec.valid)
    np.testing.assert_allclose(got.p_contact, rec.p_contact, atol=1e-3)
    np.testing.assert_allclose(got.readings.qpos, rec.readings.qpos, atol=1e-4)
    np.testing.assert_allclose(got.readings.qvel, rec.readings.qvel, atol=1e-2)


def test_a_policy_for_another_observation_is_named(recorded):
    import jax.numpy as jnp

    env = recorded[1].env

    def wrong_obs(obs, key):  # a network trained on one more observation entry
        return obs @ jnp.ones((obs.shape[-1] + 1, env.action_size)), {}

    def wrong_action(obs, key):
        return jnp.zeros(env.action_size + 1) + 0.0 * jnp.sum(obs), {}

    with pytest.raises(ValueError, match="does not take the wrapped env's observation"):
        env_rollouts.recorder(env, policy=wrong_obs)
    with pytest.raises(ValueError, match=f"shape \\({env.action_size + 1},\\); the env takes"):
        env_rollouts.recorder(env, policy=wrong_action)


def test_tune_on_env_from_python(recorded, tmp_path, capsys):
    rec, scene, _ = recorded
    out = tmp_path / "own.json"
    with pytest.raises(ValueError, match="needs actions_of, policy or both"):
        tune_env.tune_on_env(scene.env, seeds=[3], validate_seeds=[4], out=out)
    with pytest.raises(ValueError, match="argument --validate-seed: seed\\(s\\) \\[3\\]"):
        tune_env.tune_on_env(
            scene.env, seeds=[3], validate_seeds=[3], out=out, actions_of=scene.actions_of
        )
    # A height field cannot be named in a parameter file: refused before any recording.
    from jax_contact.envs.contact_config import ContactObsConfig

    field = jc.height_field(np.zeros((2, 2)), origin=(0.0, 0.0), spacing=(1.0, 1.0))
    with pytest.raises(ValueError, match="config.terrain: a HeightFieldTerrain cannot be"):
        tune_env.tune_on_env(
            scene.env, seeds=[3], validate_seeds=[4], out=out,
            actions_of=scene.actions_of, config=ContactObsConfig(terrain=field),
        )  # fmt: skip
    assert not out.exists()
    code = tune_env.tune_on_env(
        scene.env,
        seeds=[3],
        validate_seeds=[4],
        out=out,
        actions_of=scene.actions_of,
        name="my leg",
        n_steps=STEPS,
        n_envs=ROLLOUTS,
        skip_s=scene.skip_s,
        options=["--epochs", "1", "--chunk", str(STEPS * 8)],
    )
    assert code == 0 and "recorded my leg seed 3" in capsys.readouterr().err
    params, prov = jc.load_params(out, with_provenance=True)
    assert prov["robot"] == "wrapped env my leg" and prov["terrain_model"] == "flat"
    assert prov["logs"][0]["policy"] == "my leg: open-loop actions"
    # The same actions, resets and sensor keys as the fixture's seed 3 (the command's).
    assert prov["logs"][0]["valid_steps"] == int(rec.valid.sum())
    assert params.nv == rec.core.params.nv


def test_tune_env_refuses_bad_arguments_before_jax():
    code = (
        "import sys, argparse\n"
        "from jax_contact.train import tune_env as t\n"
        "assert 'jax' not in sys.modules\n"
        "p = argparse.ArgumentParser(); s = p.add_subparsers(); t.add_parser(s)\n"
        "for argv in (['go1', '--seeds', '1', '2', '--validate-seed', '2'],\n"
        "             ['go1', '--seeds', '1', '1', '--validate-seed', '2'],\n"
        "             ['go1', 'go1', '--seeds', '1', '--validate-seed', '2'],\n"
        "             ['go1', '--seeds', '1', '--validate-seed', '2', '--noise-ratio', '1']):\n"
        "    a = p.parse_args(['tune-env', *argv, '--out', 'x.json'])\n"
        "    try:\n        a.check(a)\n    except ValueError as e:\n        print(e)\n"
        "a = p.parse_args(['tune-env', 'go1', '--seeds', '1', '--validate-seed', '2', '--out',"
        " 'x.txt'])\n"
        "try:\n    a.check(a)\nexcept ValueError as e:\n    print(e)\n"
        "assert 'jax' not in sys.modules\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    lines = out.stdout.splitlines()
    assert lines == [
        "argument --validate-seed: seed(s) [2] are also tuning seeds",
        "argument --seeds: repeated seed in [1, 1]",
        "argument SCENE: repeated scene in ['go1', 'go1']",
        "argument --noise-ratio: must be 0 (no box) or > 1, got 1",
        "argument --out: 'x.txt' must end in .json",
    ]


def test_an_unknown_scene_or_policy_is_named():
    with pytest.raises(ValueError, match="unknown scene 'Go2Joystick'.*go1_trot.*SpotGetup"):
        tune_env.check_scene("Go2Joystick")
    with pytest.raises(ValueError, match="policy must be one of walk, trot.*got 'gallop'"):
        tune_env.check_scene("Go1JoystickFlatTerrain:gallop")
    tune_env.check_scene("go1_trot")
    # A rates scene with a policy was called an unknown scene, its name in the list given.
    with pytest.raises(ValueError, match=r"^argument SCENE: 'go1_trot:walk': the `jax-contact"
                       r" rates` scene 'go1_trot' plays its own .* takes no :POLICY"):  # fmt: skip
        tune_env.check_scene("go1_trot:walk")
    tune_env.check_scene("SpotFlatTerrainJoystick:trot")
    # A scripted gait on a robot it was not written for (a user trial's T1 walk ended in
    # a StopIteration traceback after loading the env); random drives any env.
    for scene, robots in (
        ("T1JoystickFlatTerrain:walk", "Go1, Spot"),
        ("T1JoystickFlatTerrain:hop", "BerkeleyHumanoid"),
        ("Go1JoystickFlatTerrain:step", "BerkeleyHumanoid"),
        ("BerkeleyHumanoidJoystickFlatTerrain:trot", "Go1, Spot"),
    ):
        with pytest.raises(ValueError, match=rf"^argument SCENE: '{scene}': policy '.*' is"
                           rf" scripted for {robots}, not .*:random"):  # fmt: skip
            tune_env.check_scene(scene)
    with pytest.raises(
        ValueError,
        match=r"^argument SCENE: 'T1JoystickFlatTerrain:stand': policy"
        r" 'stand' holds every foot on the floor: nothing to tune on",
    ):
        tune_env.check_scene("T1JoystickFlatTerrain:stand")
    tune_env.check_scene("T1JoystickFlatTerrain:random")
    tune_env.check_scene("T1JoystickFlatTerrain")  # its default policy: random


def test_too_few_steps_are_refused_before_compiling():
    """A user trial's ``--steps 20`` on a 20 ms env was refused only after a 57 s compile
    ("no step counts"). 20 x 20 ms = 0.4 s ends inside the 0.5 s left out; 25 steps end
    exactly at it (none counts); 26 leave one 20 ms step."""
    with pytest.raises(ValueError, match=r"^argument --steps: 20 env steps of T1 \(20 ms each\)"
                       r" end within the first 0.5 s .* at least 26$"):  # fmt: skip
        tune_env.check_steps_count("T1", 20, 0.02, 0.5)
    with pytest.raises(ValueError, match="at least 26"):
        tune_env.check_steps_count("T1", 25, 0.02, 0.5)
    tune_env.check_steps_count("T1", 26, 0.02, 0.5)


def test_scenes_of_different_estimators_are_refused(recorded):
    rec = recorded[0]
    other_core = dataclasses.replace(rec.core, desc=dataclasses.replace(rec.core.desc, nv=9))
    other = env_rollouts.Recording(other_core, None, None, None, None, None, rec.dt)
    with pytest.raises(ValueError, match="'b' runs another estimator \\(nv 9"):
        tune_env._same_estimator(rec, other, "b")


def test_rollouts_with_no_step_that_counts_are_refused_before_the_fit(recorded):
    """Rollouts no longer than the skipped start (here the fixture's, masked out) are
    refused naming the scene, the seed and --steps, not tuned on NaN and written."""
    import argparse

    rec = recorded[0]
    dead = dataclasses.replace(rec, valid=np.zeros_like(rec.valid))
    args = argparse.Namespace(steps=STEPS, chunk=STEPS * 8, seeds=[3], validate_seed=[4])
    with pytest.raises(ValueError, match=r"planar_leg seed 3: no step counts .* raise --steps"):
        tune_env._fit(args, [("planar_leg", "d", 3, dead)], "planar_leg")
    # The recorder knows its core and period before any rollout (checked across scenes).
    record = env_rollouts.recorder(env_rollouts.load_scene("planar_leg", 1, 1).env)
    assert record.core.desc.nv == rec.core.desc.nv and record.dt == pytest.approx(rec.dt)


def test_the_go1_playground_preset_is_the_wrappers_own_at_its_physics_step():
    """``go1_playground`` (docs/tuning.md, "Tuning on a wrapped env's own rollouts"): made
    by tune-env on Playground's Go1 at its 4 ms physics step, on seeds that are never
    reported (the wrapper's report seed is 1, the rates scenes' 0), with a map that keeps
    every decision, and no std below what the wrapper's sensor model alone gives (the
    floor recomputed here from that model, not read from the file)."""
    from jax_contact.defaults import sensor_noise_floor
    from jax_contact.envs import playground_offline
    from jax_contact.envs.contact_config import ContactObsConfig
    from jax_contact.envs.contact_wrappers import wrap_contact

    assert "go1_playground" in jc.preset_names()
    params, prov = jc.load_params("go1_playground", with_provenance=True)
    assert prov["tool"] == "jax-contact tune-env" and prov["arguments"]["command"] == "tune-env"
    scenes = {i["scene"] for i in prov["logs"] + prov["validation"]}
    assert scenes == {"Go1JoystickFlatTerrain:trot", "Go1JoystickFlatTerrain:walk"}
    seeds = prov["seeds"]["tuning_logs"] + prov["seeds"]["validation_logs"]
    assert seeds and all(s >= 1000 for s in seeds)
    assert jt.calibration_of(prov).keeps_decisions and prov["calibration"]["kind"] == "sign"
    assert len(prov["code"]["commit"]) == 40 and not prov["code"]["dirty"]
    ratios = [r["ratio"] for r in prov["tuned_vs_default"] if r["field"].startswith("sigma")]
    box = jt.PLAUSIBLE_NOISE_RATIO
    assert all(1 / box <= r <= box for r in ratios), ratios

    env = playground_offline.load("Go1JoystickFlatTerrain")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # made at the env's own period: nothing is moved
        core = wrap_contact(env, ContactObsConfig(params="go1_playground")).contact_core
    assert float(core.params.dt) == pytest.approx(float(env.mj_model.opt.timestep)) == 0.004
    assert core.calibration is not None and core.params_source == "go1_playground"
    floor = sensor_noise_floor(core.desc, core.sensor, 0.004)
    for field, values in floor.items():
        got = np.asarray(getattr(params.noise, field))
        assert np.all(got >= values * (1 - 1e-5)), (field, got / values)
