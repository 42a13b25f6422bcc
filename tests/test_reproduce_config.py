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
