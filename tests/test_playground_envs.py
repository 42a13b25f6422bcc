"""Every Playground locomotion env offline (envs/playground_offline.py), wrapped.

Cheap part for every env that loads (C compiles and one abstract trace of reset each, no
XLA compile): load, wrap with the defaults, the feet the wrapper found (kind and count, by
robot), the truth source, and the observation size against the env's. Jitted reset and
a few steps for one representative env only (Berkeley Humanoid: box feet, the env's
``*_foot1_floor_found`` sensors): each compile costs minutes on 2 cores (G1, whose feet
touch the floor only through ``<pair>``s, took 148 s of a cold suite; its feet and truth
source are checked here unjitted, and truth from MJX contacts is run jitted by
tests/test_feet.py). ``benchmarks/playground_envs.py`` runs every env jitted,
G1 included, and prints the table.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco_playground._src import locomotion
from wrapper_helpers import Traced

from jax_contact.envs import playground_offline
from jax_contact.envs import wrapper as W
from jax_contact.train import cli_args

# robot prefix -> (feet, their kind as jax_contact.envs.feet names it)
FEET = {
    "Go1": (("FR", "FL", "RR", "RL"), "sphere"),
    "Spot": (("FL", "FR", "HL", "HR"), "sphere"),
    "BerkeleyHumanoid": (("l_foot1", "r_foot1"), "box"),
    "G1": (("left_foot", "right_foot"), "box"),
    "T1": (("left_foot_link", "right_foot_link"), "4 sphere geoms"),
    "H1": (("left_ankle_link", "right_ankle_link"), "3 capsule geoms"),
    "Apollo": (("collision_l_sole", "collision_r_sole"), "box"),
}
NAMES = playground_offline.offline_names()


def test_offline_names():
    # Every locomotion env loads offline but Barkour (its scene includes Menagerie's
    # robot XML, not only meshes) and OP3 (bodies without explicit inertials: the
    # placeholder meshes would set their masses).
    assert set(locomotion.ALL_ENVS) - set(NAMES) == {"BarkourJoystick", "Op3Joystick"}
    assert NAMES == cli_args.PLAYGROUND_ENV_NAMES  # the CLI's copy (`train --task`)
    for name in ("BarkourJoystick", "Op3Joystick"):
        with pytest.raises(ValueError, match="cannot be built offline|depends on the mesh"):
            playground_offline.load(name)
    # OP3's reason in words, not only mujoco's "mesh volume is too small".
    with pytest.raises(ValueError, match="bodies without an <inertial> take their mass"):
        playground_offline.load("Op3Joystick")


def test_load_names_what_is_wrong_before_building():
    with pytest.raises(ValueError, match="unknown env 'Go1JoystickFlatTerrian'; did you mean"
                       " 'Go1JoystickFlatTerrain'"):  # fmt: skip
        playground_offline.load("Go1JoystickFlatTerrian")
    with pytest.raises(
        ValueError, match="unknown env 'Foo'; valid names \\(Playground's locomotion envs\\): "
    ):
        playground_offline.load("Foo")
    # A key of no config field: Playground raised a KeyError with the whole config in it.
    with pytest.raises(ValueError, match=r"config_overrides: \['nope'\] name no field of Go1"):
        playground_offline.load("Go1JoystickFlatTerrain", {"nope": 1})
    # impl: the constructor's "'JAX' is not a valid Impl" was reported as a scene that
    # needs more of Menagerie than visual meshes.
    for impl in ("JAX", "warp"):
        said = rf"config_overrides\['impl'\] must be 'jax'.*{impl!r}"
        with pytest.raises(ValueError, match=said):
            playground_offline.load("Go1JoystickFlatTerrain", {"impl": impl})


@pytest.mark.parametrize("name", NAMES)
def test_load_and_wrap(name):
    env = playground_offline.load(name)
    assert env.mjx_model.impl.value == "jax"
    wrapped = W.wrap_contact(env)
    report = wrapped.contact_report()
    names, kind = next(v for k, v in FEET.items() if name.startswith(k))
    assert tuple(f["name"] for f in report["feet"]) == names
    assert {f["kind"] for f in report["feet"]} == {kind}
    assert report["rate"] == "substep"
    assert report["dt"] == pytest.approx(float(env.mj_model.opt.timestep))
    assert report["truth"] == "found_sensors"  # every one of these scenes has them
    assert report["force_rows"] == (0, 1, 2)  # legs of >= 3 joints
    # The ground the estimator assumes and the sole rule are reported too (a user found the
    # rough envs' plane only in contact_core.terrain): a plane at the floor's height; on a
    # height field, between its lowest and highest point.
    assert report["sole"] == "rolling" and report["terrain"]["kind"] == "FlatTerrain"
    # The defaults' sign test runs where the reported margin is 1 or more (T1, G1, Apollo
    # below it: a sole's moment; docs/training.md).
    assert (report["sign_test_margin"] >= 1.0) is report["sign_test"]
    m = env.mj_model
    hfield = int(mujoco.mjtGeom.mjGEOM_HFIELD)
    fields = [g for g in range(m.ngeom) if m.geom_type[g] == hfield and m.geom_bodyid[g] == 0]
    if fields:
        top = float(m.geom_pos[fields[0], 2] + m.hfield_size[m.geom_dataid[fields[0]], 2])
        assert 0.0 < report["terrain"]["height"] < top
    else:
        assert report["terrain"]["height"] == 0.0
    # One abstract trace of the env's reset (wrapped.observation_size would trace it
    # again): the wrapped size is the env's plus one p_contact per foot in "state".
    inner = env.observation_size
    size = wrapped.contact_core.add_size(inner)
    n = len(names)
    if isinstance(inner, dict):
        assert size["state"] == (inner["state"][0] + n,)
        assert {k: v for k, v in size.items() if k != "state"} == {
            k: v for k, v in inner.items() if k != "state"
        }
    else:
        assert size == inner + n


@pytest.mark.parametrize("name", ["BerkeleyHumanoidJoystickFlatTerrain"])
def test_jitted_reset_and_steps(name):
    env = playground_offline.load(name)
    cfg = W.ContactObsConfig(obs_keys=("state", "privileged_state"))
    wrapped = W.wrap_contact(env, cfg)
    # Traced: strongly typed outputs, so step compiles once (reset's weak-typed metrics
    # would give step a second signature after its first call).
    reset, step = Traced(wrapped.reset), Traced(wrapped.step)
    state = reset(jax.random.PRNGKey(0))
    sizes = wrapped.observation_size
    for _ in range(3):
        state = step(state, jnp.zeros(env.action_size))
    for k, shape in sizes.items():
        assert state.obs[k].shape == tuple(shape)
        assert np.all(np.isfinite(np.asarray(state.obs[k])))
    p = np.asarray(state.info["contact_est"].diag.p_contact)
    # The features are the last two entries of both keys (the critic's too).
    np.testing.assert_allclose(np.asarray(state.obs["state"])[-2:], p, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(state.obs["privileged_state"])[-2:], p, rtol=1e-6)
    assert int(state.info["contact_est"].n_updates) == 3 * env.n_substeps
    assert state.info["contact_est_truth"].shape == (2,)
    assert (reset.traces, step.traces) == (1, 1)


def test_the_benchmark_scores_an_episode_up_to_its_done():
    """benchmarks/playground_envs.py's accuracy column: from the skipped reset drop to the
    step whose done ends the episode (a humanoid holding its default pose falls within a
    second; the fallen robot was scored before)."""
    from jax_contact.benchmarks.playground_envs import score_until_done

    records = [
        ([[0.9, 0.1]], [[1, 0]], 0.0),  # skipped (the drop)
        ([[0.9, 0.6], [0.2, 0.4]], [[1, 0], [0, 0]], 0.0),  # 3 of 4 agree (0.6 vs air)
        ([[0.4, 0.7]], [[1, 1]], 1.0),  # 1 of 2; done: the last step scored
        ([[0.0, 0.0]], [[1, 1]], 0.0),  # after the done: not scored
    ]
    assert score_until_done(records, skip=1) == (4, 6, 3)
    no_done = [(p, t, 0.0) for p, t, _ in records]
    assert score_until_done(no_done, skip=1) == (4, 8, None)  # + 0 of 2 on the last step
