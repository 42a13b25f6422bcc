"""The reproduction's scenario set-up (train/reproduce.py), without simulating."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from jax_contact.envs.robots import load_robot
from jax_contact.train import reproduce as R


def test_named_feet_reach_every_scenario_world():
    feet = load_robot("go1").description.foot_names
    cfg = R.ReproduceConfig(foot_names=tuple(reversed(feet)))
    for scen in R.SCENARIOS:
        assert R._scenario_world(scen, cfg).robot.description.foot_names == tuple(reversed(feet))


@pytest.mark.parametrize("robot", ["spot", "barkour"])
def test_added_mass_is_go1s_share_of_the_total_mass(robot):
    """Go1: 3 kg + 0.2 kg of its total mass; other robots: 24 % and 1.6 % of theirs, on the
    base body (the world's child) and the first foot's body."""
    rb = load_robot(robot)
    m = rb.mj_model
    total = m.body_mass.sum()
    (base, kg_base), (foot, kg_foot) = R.added_mass_for(robot)
    assert m.body_parentid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, base)] == 0
    foot_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, foot)
    assert foot_id == rb.description.foot_body_ids[0]
    np.testing.assert_allclose([kg_base, kg_foot], [0.24 * total, 0.016 * total], atol=5e-4)  # g
    # The walk with added mass is not the plain walk (Spot's was, before).
    cfg = R.ReproduceConfig(robot=robot)
    assert R._scenario_world("walk_added_mass", cfg).added_mass != ()


def test_the_tuned_row_is_the_robots_preset_read_through_a_map_that_keeps_decisions(capsys):
    """Row ``tuned``: "auto" is the robot's shipped preset (Go1's file, its per-side map,
    seed 0 held out); a robot without a preset, or None, has no row; a file whose map moves
    the 0.5 threshold runs without it; an evaluation seed the file was tuned on is named."""
    import jax_contact as jc

    desc = load_robot("go1").description
    row = R.tuned_estimator(R.ReproduceConfig(), desc)
    params, prov = jc.load_params("go1", with_provenance=True)
    np.testing.assert_array_equal(
        np.asarray(row["params"].noise.sigma_qd), np.asarray(params.noise.sigma_qd)
    )
    assert row["calibration"].keeps_decisions and row["info"]["calibration"]["kind"] == "sign"
    assert row["info"]["held_out"] and row["info"]["source"] == "go1"
    assert row["info"]["seeds"]["tuning_logs"] == prov["seeds"]["tuning_logs"]
    planar = load_robot("planar_leg").description
    assert R.tuned_estimator(R.ReproduceConfig(robot="planar_leg"), planar) is None
    assert R.tuned_estimator(R.ReproduceConfig(tuned_params=None), desc) is None
    capsys.readouterr()
    row = R.tuned_estimator(R.ReproduceConfig(seed=1001), desc)
    assert not row["info"]["held_out"] and "not held out" in capsys.readouterr().err


def test_the_tuned_row_skips_an_affine_map(tmp_path, capsys):
    import jax_contact as jc

    desc = load_robot("go1").description
    params, prov = jc.load_params("go1", with_provenance=True)
    path = jc.save_params(
        tmp_path / "affine.json", params, {**prov, "calibration": {"temperature": 1.3, "bias": 0.9}}
    )
    row = R.tuned_estimator(R.ReproduceConfig(tuned_params=str(path)), desc)
    assert row["calibration"] is None and row["info"]["calibration"] is None
    assert "moves the 0.5 threshold" in capsys.readouterr().err
