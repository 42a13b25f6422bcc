"""The reproduction's scenario set-up (train/reproduce.py), without simulating."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from jax_contact.envs.robots import load_robot
from jax_contact.train import reproduce as R
from jax_contact.train.report import format_tuned_source


def test_named_feet_reach_every_scenario_world():
    feet = load_robot("go1").description.foot_names
    cfg = R.ReproduceConfig(foot_names=tuple(reversed(feet)))
    for scen in R.SCENARIOS:
        assert R.scenario_world_of(scen, cfg).robot.description.foot_names == tuple(reversed(feet))


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
    assert R.scenario_world_of("walk_added_mass", cfg).added_mass != ()


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


def test_per_gait_rows_are_each_scenarios_gait_preset():
    """``tuned_params="per-gait"``: the trot reads the robot's trot file if one is shipped
    and the walks (plain, added mass, rough) its walk file, else the robot's own file;
    each file is loaded once, its map kept; one line per file names its scenarios."""
    import jax_contact as jc

    assert [R.per_gait_preset("spot", s) for s in R.SCENARIOS] == [
        "spot",
        "spot_walk",
        "spot_walk",
        "spot_walk",
    ]
    assert R.per_gait_preset("barkour", "trot") == "barkour_trot"
    assert R.per_gait_preset("go1", "trot") == "go1" and R.per_gait_preset("go1", "rough") == (
        "go1_walk"
    )
    assert R.per_gait_preset("planar_leg", "walk") is None
    desc = load_robot("barkour").description
    tuned = R.tuned_estimator(R.ReproduceConfig(robot="barkour", tuned_params="per-gait"), desc)
    rows = {s: R.tuned_row_for(tuned, s) for s in R.SCENARIOS}
    assert rows["walk"] is rows["rough"] is rows["walk_added_mass"]
    for scenario, want in (("trot", "barkour_trot"), ("walk", "barkour_walk")):
        assert rows[scenario]["info"]["source"] == want
        assert tuned["info"]["by_scenario"][scenario]["source"] == want
        np.testing.assert_array_equal(
            np.asarray(rows[scenario]["params"].noise.sigma_qd),
            np.asarray(jc.load_params(want).noise.sigma_qd),
        )
    assert not np.array_equal(
        np.asarray(rows["trot"]["params"].noise.sigma_qd),
        np.asarray(rows["walk"]["params"].noise.sigma_qd),
    )
    lines = format_tuned_source(tuned["info"]).splitlines()
    assert lines[0] == "tuned (per gait):"
    assert lines[1].startswith("  trot: barkour_trot (tuned on seeds")
    assert lines[2].startswith("  walk, walk_added_mass, rough: barkour_walk (tuned on seeds")
    # One file for all: the row itself, whatever the scenario.
    one = R.tuned_estimator(R.ReproduceConfig(robot="barkour"), desc)
    assert R.tuned_row_for(one, "rough") is one and R.tuned_row_for(None, "trot") is None
    planar = load_robot("planar_leg").description
    cfg = R.ReproduceConfig(robot="planar_leg", tuned_params="per-gait")
    assert R.tuned_estimator(cfg, planar) is None


def test_a_run_replaces_its_outputs_as_one_or_leaves_them(tmp_path, monkeypatch):
    """An interrupted reproduce left five figures of the new seed beside the old seed's
    table3.json (a user trial). The run writes into a staged folder: on failure --out is as
    it was; on success every earlier output is replaced or removed, other files kept."""
    out = tmp_path / "rep"
    out.mkdir()
    for name, text in (("table3.json", "seed 0"), ("reliability_rough.png", "seed 0"),
                       ("notes.txt", "mine")):  # fmt: skip
        (out / name).write_text(text)

    def fails(cfg, stage):
        (stage / "table3_trot_fig7.png").write_text("seed 5")
        raise KeyboardInterrupt

    monkeypatch.setattr(R, "_run_into", fails)
    with pytest.raises(KeyboardInterrupt):
        R.run(R.ReproduceConfig(), out)
    assert {f.name: f.read_text() for f in out.iterdir()} == {
        "table3.json": "seed 0",
        "reliability_rough.png": "seed 0",
        "notes.txt": "mine",
    }
    assert [f.name for f in tmp_path.iterdir()] == ["rep"]  # no staged folder left

    def succeeds(cfg, stage):
        (stage / "table3.json").write_text("seed 5")
        (stage / "section3_fig5.png").write_text("seed 5")
        return {"wall_s": 1.0}

    monkeypatch.setattr(R, "_run_into", succeeds)
    R.run(R.ReproduceConfig(), out)
    # reliability_rough.png was the earlier run's and this one did not write it: removed.
    assert {f.name: f.read_text() for f in out.iterdir()} == {
        "table3.json": "seed 5",
        "section3_fig5.png": "seed 5",
        "notes.txt": "mine",
    }
    # A run into a folder that does not exist yet creates it only when it completes.
    monkeypatch.setattr(R, "_run_into", fails)
    with pytest.raises(KeyboardInterrupt):
        R.run(R.ReproduceConfig(), tmp_path / "new")
    assert not (tmp_path / "new").exists()


def test_a_robot_without_a_preset_gets_no_tuned_row_and_a_line_saying_why():
    """``--params auto`` on a robot with no shipped preset (ANYmal C, a user trial) has no
    row ``tuned``; the printed line names the robot and the way to add one."""
    cfg = R.ReproduceConfig(robot="anybotics_anymal_c")
    assert "anybotics_anymal_c" not in R.jc.preset_names()
    assert R.tuned_estimator(cfg, desc=None) is None
    line = R.no_tuned_row(cfg.robot)
    assert line.startswith("tuned: no row, 'anybotics_anymal_c' has no shipped preset")
    assert "--params FILE" in line
    assert max(len(x) for x in line.splitlines()) <= 100  # printed wrapped, as the legend


def test_the_kinematic_detector_is_tuned_on_both_gaits_by_mean_f1():
    """The grid point with the best F1 averaged over the walk and trot tuning runs wins,
    ties going to fewer failures over both: a hand example."""

    def s(f1, fails):
        return {"f1": f1, "failures": fails}

    # F1 values exact in binary, so the tie below is exact.
    scores = {
        "walk": {"a": s(0.5, 5), "b": s(0.75, 9), "c": s(1.0, 1)},
        "trot": {"a": s(0.75, 5), "b": s(0.625, 1), "c": s(0.25, 1)},
    }
    # means: a 0.625, b 0.6875, c 0.625 -> b, although c is best on the walk alone
    assert R.best_setting(scores) == "b"
    scores["trot"]["a"] = s(0.875, 0)  # a: mean 0.6875 too, 5 failures against b's 10 -> a
    assert R.best_setting(scores) == "a"
    grid = R.kinematic_grid()
    assert len(grid) == len(R.KIN_HEIGHTS) * len(R.KIN_SPEEDS)
    default, point = R.make_kinematic_params(), grid["kin_h2_v0.3"]  # the defaults: a point
    assert float(point.height_threshold) == float(default.height_threshold)
    assert float(point.velocity_threshold) == float(default.velocity_threshold)


def test_gms_grid_scales_with_the_robot_and_names_a_pick_on_its_edge():
    """GM's thresholds are fractions of a foot's share of the weight (Go1: 12.74 kg x 9.81
    / 4 = 31.25 N, so 0.2 of it is 6.25 N), K_I only where K_I dt <= 1 (300 1/s drops out
    at 200 Hz); a pick at the smallest or largest value of a field is named (the old
    absolute grid's picks sat on its edges)."""
    load = R.foot_load(load_robot("go1"))
    assert load == pytest.approx(12.74 * 9.81 / 4, abs=0.05)
    grid = R.gm_grid(load, 0.0025)
    assert len(grid) == len(R.GM_K_I) * len(R.GM_LOAD_FRACTIONS)
    assert float(grid["gm_K50_F6.25"].threshold) == pytest.approx(0.2 * load, rel=1e-6)
    assert float(grid["gm_K50_F6.25"].K_I) == 50.0
    assert {float(p.K_I) for p in R.gm_grid(load, 0.005).values()} == {2, 5, 20, 50, 150}
    assert R.grid_edges(grid, "gm_K50_F6.25", ("K_I", "threshold")) == []
    assert R.grid_edges(grid, "gm_K300_F1.56", ("K_I", "threshold")) == [
        "K_I at its largest",
        "threshold at its smallest",
    ]
    kins = R.kinematic_grid()
    assert R.grid_edges(kins, "kin_h8_v0.3", ("height_threshold", "velocity_threshold")) == [
        "height_threshold at its largest"
    ]


def test_failure_limited_pick_follows_the_estimators_rule():
    """The rows ``*_fl`` pick a baseline as the estimator's defaults were picked: among the
    grid points whose swing phases with a false contact (sw-ph) or the flag on throughout
    (sw-on) are <= FAILURE_LIMIT on every tuning run, the best mean F1; with none under
    it, the lowest worst-run share. Hand-made scores (sw-ph + sw-on per run):

    - a: F1 0.98 / 0.97 (mean 0.975), 5 % and 1 %: worst 5 %, over the limit;
    - b: F1 0.95 / 0.96 (mean 0.955), 1 % / 1 % + 1 %: eligible (2 %);
    - c: F1 0.94 / 0.94, 0 % and NaN (no swing phase: nothing failed): eligible;
    - d: F1 0.99 / 0.99, sw-ph 0 % but its flag on through 30 % of the swings: not.

    By F1 alone d wins; under the 2 % limit b (0.955 > 0.94; d is stuck on, which sw-ph
    alone would have let through); under 0.5 % only c; with every point over the limit
    the lowest worst share.
    """

    def cell(f1, rate, failures=0, on=0.0):
        return {
            "f1": f1,
            "swing_phase_failure_rate": rate,
            "swing_phase_flag_on_rate": on,
            "failures": failures,
        }

    nan = float("nan")
    runs = {
        "walk": {"a": cell(0.98, 0.05), "b": cell(0.95, 0.01), "c": cell(0.94, 0.0)},
        "trot": {
            "a": cell(0.97, 0.01),
            "b": cell(0.96, 0.01, on=0.01),
            "c": cell(0.94, nan, on=nan),
        },
    }
    runs["walk"]["d"] = runs["trot"]["d"] = cell(0.99, 0.0, on=0.3)
    assert R.best_setting(runs) == "d"
    assert R.swing_share(runs, "d") == pytest.approx(0.3)
    assert R.swing_share(runs, "b") == pytest.approx(0.02)  # its trot: 1 % + 1 %
    assert R.swing_share(runs, "c") == 0.0
    assert R.FAILURE_LIMIT == 0.02
    assert R.best_setting(runs, R.FAILURE_LIMIT) == "b"
    assert R.best_setting(runs, 0.005) == "c"
    over = {
        "walk": {"a": cell(0.98, 0.04), "b": cell(0.95, 0.03)},
        "trot": {"a": cell(0.97, 0.05), "b": cell(0.96, 0.06)},
    }
    # Both over the limit. Worst runs: a 5 %, b 6 %, so a; on the walk alone (4 %, 3 %) b.
    assert R.best_setting(over, R.FAILURE_LIMIT) == "a"
    assert R.best_setting({"walk": over["walk"]}, R.FAILURE_LIMIT) == "b"
    pick, share, met = R.failure_limited_pick(runs)
    assert (pick, met) == ("b", True) and share == pytest.approx(0.02)
    pick, share, met = R.failure_limited_pick(over)
    assert (pick, met) == ("a", False) and share == pytest.approx(0.05)

    # A grid with no point under the limit gets no row; the line says so and why.
    def record(pick, share):
        return {"pick": pick, "swing_share": share, "row": share <= 0.02, "grid_edges": []}

    fl = {"gm_walk_fl": record("w", 0.01), "gm_trot_fl": record("t", 0.0)}
    line = R.format_failure_limited(fl | {"kinematic_fl": record("a", 0.05)})
    assert "gm_walk_fl w; gm_trot_fl t; no row kinematic_fl" in " ".join(line.split())
    assert "(the fewest: a, 5 % of swings)" in " ".join(line.split())
    # The run's log line too: the corner it printed read as a pick (on the grid's edge).
    record_a = record("a", 0.05) | {"grid_edges": ["height_threshold at its smallest"]}
    assert R._limited_line("kinematic_fl", record_a) == (
        "  kinematic_fl by the estimator's rule: no row, no point of its grid meets it (the"
        " fewest: a, 5 % of swings)"
    )
    assert R._limited_line("gm_walk_fl", fl["gm_walk_fl"]) == (
        "  gm_walk_fl by the estimator's rule: w"
    )


def test_each_seed_walks_its_own_rough_floor():
    """Every seed had seed 0's rough floor (terrain_seed 0), so a tuning seed's rough log
    was the evaluation seed's patch of ground; the floor is now drawn with the seed, and
    seed 0's is the one it always was."""
    from jax_contact.envs.simulate import build_world

    def heights(world):
        return np.asarray(world.robot.mj_model.hfield_data).copy()

    cfg = R.ReproduceConfig(robot="go1")
    rough0 = heights(R.scenario_world_of("rough", cfg))
    rough1000 = heights(R.scenario_world_of("rough", R.ReproduceConfig(robot="go1", seed=1000)))
    old = heights(build_world("go1", terrain="rough", roughness=cfg.roughness))
    np.testing.assert_array_equal(rough0, old)
    assert rough0.shape == rough1000.shape and np.abs(rough0 - rough1000).max() > 1e-3
