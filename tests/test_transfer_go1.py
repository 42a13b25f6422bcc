"""The transfer matrix on Go1 joystick runs (issue 19): columns, latency, dispatch, CLI, shim.

Cheap only: no rollout is compiled. The Go1 envs of the columns are built (their sensor
models are read, nothing runs); the matrix's dispatch on ``run.json``'s ``task`` is
checked with fake run folders and fake cell evaluators; the CLI's ``--column`` through its
entry point and with a fake evaluator; the ``jax.device_put_replicated`` shim of
``train/_compat.py`` against jax's own function on this CPU. The GPU run itself is
``benchmarks/gpu_go1_transfer.sh`` (docs/training.md, "Transfer matrix on Go1").
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jax_contact.benchmarks import gpu_go1_transfer as G
from jax_contact.envs import contact_params, sensors
from jax_contact.train import _compat, cli, policy_eval, ppo, transfer

ROOT = Path(__file__).resolve().parents[1]
_ENTRY = Path(sys.executable).parent / "jax-contact"
CLI = [str(_ENTRY)] if _ENTRY.exists() else [sys.executable, "-m", "jax_contact.train.cli"]


# ------------------------------------------------------------------------- columns


def test_column_setting_for_every_column():
    assert transfer.COLUMNS == cli.COLUMNS == G.COLUMNS
    want = {
        "truth": ("truth", "anymal_like", 0),
        "estimate": ("estimate", "anymal_like", 0),
        "estimate_harsh": ("estimate", "harsh", 0),
        "estimate_lat1": ("estimate", "anymal_like", 1),
        "estimate_lat2": ("estimate", "anymal_like", 2),
        "none": ("none", "anymal_like", 0),
    }
    assert {c: transfer.column_setting(c) for c in (*transfer.COLUMNS, "none")} == want
    # The training preset is the run's: every column but estimate_harsh follows it.
    assert transfer.column_setting("estimate_lat2", "ideal") == ("estimate", "ideal", 2)
    assert transfer.column_setting("estimate_harsh", "ideal") == ("estimate", "harsh", 0)
    with pytest.raises(ValueError, match="column must be one of .*'estimate_lat3'"):
        transfer.column_setting("estimate_lat3")


def _sensor(dt: float, latency: int) -> sensors.SensorParams:
    return sensors.sensor_preset("anymal_like", 18, dt=dt).replace(latency=latency)


def test_extra_latency_is_env_steps_in_sensor_steps():
    # Go1 joystick: 20 ms env step, 4 ms physics step: 5 sensor steps per env step.
    go1 = _sensor(0.004, 1)
    assert contact_params.with_extra_latency(go1, 0, 0.02).latency == 1
    assert contact_params.with_extra_latency(go1, 1, 0.02).latency == 1 + 5
    assert contact_params.with_extra_latency(go1, 2, 0.02).latency == 1 + 10
    # The hop task: 10 ms env step of 2.5 ms physics steps; the control rate: 1 per step.
    assert contact_params.with_extra_latency(_sensor(0.0025, 1), 2, 0.01).latency == 1 + 8
    assert contact_params.with_extra_latency(_sensor(0.02, 0), 3, 0.02).latency == 3
    delayed = contact_params.with_extra_latency(go1, 2, 0.02)
    np.testing.assert_array_equal(delayed.sigma_qd, go1.sigma_qd)  # only the delay changes
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="extra_env_steps must be an int >= 0"):
            contact_params.with_extra_latency(go1, bad, 0.02)
    with pytest.raises(ValueError, match="env_dt .* whole number of sensor steps"):
        contact_params.with_extra_latency(go1, 1, 0.021)


def test_go1_columns_build_their_sensors():
    """Each Go1 column's env (nothing compiled): observation slot, sensor preset, delay."""
    envs = {c: policy_eval.column_env(c, ppo.SMALL) for c in transfer.COLUMNS}
    est = envs["estimate"].contact_core.sensor
    assert float(envs["estimate"].dt) == pytest.approx(0.02)
    assert float(est.dt) == pytest.approx(0.004)  # the physics rate
    assert est.latency == 1  # anymal_like's 2.5 ms at 4 ms steps, kept in seconds: 1 step
    lat = {c: envs[c].contact_core.sensor.latency for c in transfer.COLUMNS}
    # harsh: 3 steps of 2.5 ms = 7.5 ms -> 2 physics steps; latK: + 5 K physics steps.
    assert lat == {
        "truth": 1,
        "estimate": 1,
        "estimate_harsh": 2,
        "estimate_lat1": 6,
        "estimate_lat2": 11,
    }
    sigma = {c: float(envs[c].contact_core.sensor.sigma_qd[6]) for c in transfer.COLUMNS}
    assert sigma["estimate_lat1"] == sigma["estimate_lat2"] == sigma["estimate"]
    assert sigma["estimate_harsh"] == pytest.approx(2 * sigma["estimate"])
    assert {c: envs[c].contact_core.cfg.observe for c in transfer.COLUMNS} == {
        "truth": "truth",
        **{c: "estimate" for c in transfer.COLUMNS[1:]},
    }
    assert {tuple(e.observation_size["state"]) for e in envs.values()} == {(52,)}


def test_latency_columns_run_the_estimate_columns_estimator():
    """A run trained with a parameter file of another period (``go1``: 2.5 ms, the Go1
    joystick's physics step 4 ms): the wrapper moves it to 4 ms by re-deriving the preset's
    values there (``load_params_for``'s ``derive``), which it can do only from a preset
    name. The latency columns are built with a delayed ``SensorParams`` and ran the file
    with only its ``dt`` replaced; they now run the estimate column's estimator, leaf for
    leaf, with its map and terrain, and differ from it in their readings' latency alone."""
    cfg = dataclasses.replace(ppo.SMALL, estimator_params="go1")
    with pytest.warns(UserWarning, match="period"):
        envs = {c: policy_eval.column_env(c, cfg) for c in ("estimate", "estimate_lat1")}
    est, lat = (envs[c].contact_core for c in ("estimate", "estimate_lat1"))
    leaves = zip(jax.tree.leaves(est.params), jax.tree.leaves(lat.params), strict=True)
    assert jax.tree.structure(est.params) == jax.tree.structure(lat.params)
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in leaves)
    assert float(est.params.dt) == pytest.approx(0.004)
    assert est.calibration == lat.calibration and est.calibration is not None
    assert est.terrain == lat.terrain
    assert (est.sensor.latency, lat.sensor.latency) == (1, 6)


# ----------------------------------------------------------------------- dispatch


def _run_folder(path: Path, variant: str, task: str | None, checkpoint: bool = True) -> Path:
    path.mkdir(parents=True)
    run = {"variant": variant, "config": dataclasses.asdict(ppo.SMALL)}
    if task is not None:
        run["task"] = task
    (path / "run.json").write_text(json.dumps(run))
    if checkpoint:  # a step folder as Brax leaves it, its config file written last
        (path / "checkpoints" / "000000000100").mkdir(parents=True)
        (path / "checkpoints" / "000000000100" / "ppo_network_config.json").write_text("{}")
    return path


def test_evaluate_policy_dispatches_hop_runs_with_the_column(tmp_path, monkeypatch):
    run = _run_folder(tmp_path / "truth", "truth", "hop")
    seen = {}
    monkeypatch.setattr(transfer, "evaluate_run", lambda d, **kw: seen.update(kw) or {"ok": 1})
    assert policy_eval.evaluate_policy(run, column="estimate_harsh", n_envs=3) == {"ok": 1}
    assert seen["column"] == "estimate_harsh" and seen["observe"] is None
    assert seen["n_envs"] == 3
    with pytest.raises(ValueError, match="observe or column, not both"):
        policy_eval.evaluate_policy(run, observe="truth", column="estimate")
    with pytest.raises(ValueError, match="observe must be one of"):
        policy_eval.evaluate_policy(run, observe="estimate_harsh")
    # An interrupted hop run is evaluated with the warning a Go1 run gets (it had none).
    info = json.loads((run / "run.json").read_text()) | {"finished": False}
    (run / "run.json").write_text(json.dumps(info))
    with pytest.warns(UserWarning, match=r"training did not finish .* checkpoint, 000000000100"):
        assert policy_eval.evaluate_policy(run, n_envs=3) == {"ok": 1}
    # No task in run.json is a Go1 run: it needs a checkpoint, not the hop evaluation.
    go1 = _run_folder(tmp_path / "old" / "truth", "truth", None, checkpoint=False)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        policy_eval.evaluate_policy(go1, column="estimate_lat1")


class _FakeCells:
    """A cell evaluator whose numbers say which run, seed and column they came from."""

    metrics = ("return", "fell")
    calls: list = []

    def __init__(self, first_run, n_envs, episode_length):
        self.kind = type(self).__name__
        _FakeCells.calls.append(("init", self.kind, n_envs, episode_length))

    def cell(self, run_dir, column, seed, loaded):
        _FakeCells.calls.append((self.kind, run_dir.parent.name, run_dir.name, column))
        s = int(run_dir.parent.name[4:])
        c = (*transfer.COLUMNS, "none").index(column)
        return {"return": 10.0 * s + c, "fell": 0.5 * s}

    @staticmethod
    def line(m):
        return f"return {m['return']}"


class _FakeGo1(_FakeCells):
    pass


class _FakeHop(_FakeCells):
    pass


@pytest.fixture
def fake_cells(monkeypatch):
    monkeypatch.setattr(transfer, "_CELLS", {"go1": _FakeGo1, "hop": _FakeHop})
    monkeypatch.setattr(transfer, "_load", lambda d, makers: ("make_policy", d, {}))
    _FakeCells.calls = []
    return _FakeCells.calls


def test_transfer_matrix_dispatches_on_the_runs_task(tmp_path, fake_cells):
    runs = {
        v: [
            _run_folder(tmp_path / f"seed{s}" / v, v, None if s == 0 else "go1")  # absent: go1
            for s in (0, 2)
        ]
        for v in ("none", "truth", "estimate")
    }
    res = transfer.transfer_matrix(runs, n_envs=5, episode_length=7, log=lambda m: None)
    assert res["task"] == "go1" and res["metrics"] == ["return", "fell"]
    assert fake_cells[0] == ("init", "_FakeGo1", 5, 7)
    evaluated = fake_cells[1:]
    # The none row: one evaluation per seed, in the "none" column, repeated in every column.
    assert [c for c in evaluated if c[2] == "none"] == [
        ("_FakeGo1", "seed0", "none", "none"),
        ("_FakeGo1", "seed2", "none", "none"),
    ]
    assert len(evaluated) == 2 + 2 * 2 * len(transfer.COLUMNS)
    none = res["cells"]["none"]
    assert [none[c]["return"]["per_seed"] for c in transfer.COLUMNS] == [[5.0, 25.0]] * 5
    lat2 = res["cells"]["estimate"]["estimate_lat2"]["return"]
    assert lat2 == {"mean": 14.0, "std": 10.0, "n_seeds": 2, "per_seed": [4.0, 24.0]}
    fell = res["cells"]["truth"]["truth"]["fell"]
    assert fell == {"mean": 0.5, "std": 0.5, "n_seeds": 2, "per_seed": [0, 1]}


def test_a_seed_without_a_value_is_left_out_of_its_cell():
    """A hop seed whose policy never left the ground has no apex (apex_error NaN): the
    cell's mean and std were NaN for every seed. Now over the seeds with a value, counted;
    one seed has no std ("± 0.000" before)."""
    nan = float("nan")
    cell = transfer.over_seeds([0.2, nan, 0.4])
    assert cell["mean"] == pytest.approx(0.3) and cell["std"] == pytest.approx(0.1)
    assert cell["n_seeds"] == 2 and len(cell["per_seed"]) == 3
    one, none = transfer.over_seeds([0.25]), transfer.over_seeds([nan])
    assert one["mean"] == 0.25 and np.isnan(one["std"]) and np.isnan(none["mean"])
    res = {
        "columns": ["truth", "estimate"],
        "cells": {
            "none": {"truth": {"accuracy": one}, "estimate": {"accuracy": one}},
            "truth": {"truth": {"accuracy": cell}, "estimate": {"accuracy": none}},
        },
    }
    table = transfer.format_matrix(res, "accuracy").splitlines()
    assert table[2] == "| none | 0.250 | 0.250 |"
    assert table[3] == "| truth | 0.300 ± 0.100 (2 of 3 seeds) | n/a |"
    assert table[4].startswith("row none: its policy sees no contact, so one evaluation")
    for row in res["cells"].values():  # the return: the same for the none row in every column
        for c in row:
            row[c]["return"] = one
    assert len(transfer.format_matrix(res, "return").splitlines()) == 4  # no note


def test_transfer_matrix_hop_runs_and_mixed_tasks(tmp_path, fake_cells):
    hop = {v: [_run_folder(tmp_path / "seed1" / v, v, "hop")] for v in ("truth", "estimate")}
    res = transfer.transfer_matrix(hop, columns=("estimate",), log=lambda m: None)
    assert res["task"] == "hop" and {c[0] for c in fake_cells[1:]} == {"_FakeHop"}
    assert res["cells"]["truth"]["estimate"]["return"]["per_seed"] == [11.0]
    mixed = dict(hop, none=[_run_folder(tmp_path / "seed1" / "none", "none", None)])
    with pytest.raises(ValueError, match=r"runs mixes tasks \['go1', 'hop'\]"):
        transfer.transfer_matrix(mixed, log=lambda m: None)
    with pytest.raises(ValueError, match="column must be one of"):
        transfer.transfer_matrix(hop, columns=("estimate_lat9",), log=lambda m: None)


def test_transfer_main_prints_the_go1_metrics(tmp_path, fake_cells, monkeypatch, capsys):
    monkeypatch.setattr(cli, "enable_compilation_cache", lambda: None)
    for v in ("none", "truth", "estimate"):
        _run_folder(tmp_path / "seed0" / v, v, None)
    res = transfer.main([str(tmp_path), "--envs", "3", "--json", str(tmp_path / "m.json")])
    out = capsys.readouterr().out
    assert f"wrote {tmp_path / 'm.json'}" in out
    saved = json.loads((tmp_path / "m.json").read_text())
    assert saved["episode_length"] is None and saved["config"]["num_timesteps"] > 0
    assert "\nreturn\n| trained with | truth | estimate | estimate_harsh" in out
    assert "| truth | 0.000 | 1.000 | 2.000 |" in out  # one seed: no spread to show
    saved = json.loads((tmp_path / "m.json").read_text())["cells"]
    cell = saved["truth"]["estimate"]["return"]
    assert cell == {"mean": 1.0, "std": None, "n_seeds": 1, "per_seed": [1.0]}  # NaN: null
    assert np.isnan(res["cells"]["truth"]["estimate"]["return"]["std"])
    # A run stopped before its first checkpoint is named before any cell is evaluated
    # (it failed after every earlier run's cells, and nothing was written).
    _run_folder(tmp_path / "seed1" / "estimate", "estimate", None, checkpoint=False)
    fake_cells.clear()
    with pytest.raises(SystemExit):
        transfer.main([str(tmp_path), "--json", str(tmp_path / "m2.json")])
    err = capsys.readouterr().err
    assert "argument root: no checkpoint in" in err and "seed1/estimate" in err, err
    assert fake_cells == [] and not (tmp_path / "m2.json").exists()
    _run_folder(tmp_path / "seed2" / "truth", "truth", "hop")
    with pytest.raises(SystemExit):
        transfer.main([str(tmp_path)])
    assert "argument root:" in capsys.readouterr().err


def test_runs_that_cannot_share_a_matrix_are_refused_and_uneven_ones_named(tmp_path):
    """A helper's audit ran each of these into a matrix without a word: a truth run copied
    into the estimate row's folder (the row was the truth policy's), runs of two training
    configurations, rows over different seeds, an unfinished run."""
    runs = {v: [_run_folder(tmp_path / "seed0" / v, v, "go1")] for v in ("none", "truth")}
    assert transfer.check_runs(runs) == []
    copied = _run_folder(tmp_path / "seed0" / "estimate", "truth", "go1")
    with pytest.raises(ValueError, match=r"estimate: its run.json says variant 'truth', but it"):
        transfer.check_runs(dict(runs, estimate=[copied]))
    other = _run_folder(tmp_path / "seed1" / "truth", "truth", "go1")
    info = json.loads((other / "run.json").read_text())
    info["config"]["num_timesteps"] = 320
    info["finished"] = False
    (other / "run.json").write_text(json.dumps(info))
    uneven = {"none": runs["none"], "truth": [*runs["truth"], other]}
    with pytest.raises(ValueError, match=r"other configurations \(num_timesteps \d+ vs 320\)"):
        transfer.check_runs(uneven)
    info["config"]["num_timesteps"] = ppo.SMALL.num_timesteps
    (other / "run.json").write_text(json.dumps(info))
    notes = transfer.check_runs(uneven)
    assert notes[0] == (
        "the rows are over different seeds (none: seed0; truth: seed0, seed1): their means"
        " are not over the same training runs"
    )
    assert notes[1].startswith("training did not finish for [") and "seed1/truth" in notes[1]


def test_a_seed_folder_given_as_root_names_its_parent(tmp_path):
    """A helper's audit: ``transfer ROOT/seed0`` suggested training into
    ``ROOT/seed0/seedS``, a level deeper; it names the folder to pass."""
    for v in ("none", "truth", "estimate"):
        _run_folder(tmp_path / "seed0" / v, v, "go1")
    with pytest.raises(FileNotFoundError, match=r"it is one seed's folder; pass the folder of"):
        transfer.runs_under(tmp_path / "seed0")
    assert set(transfer.runs_under(tmp_path)) == {"none", "truth", "estimate"}
    # A folder not named seed*: its parent holds no seed*/ either, so passing it led to
    # "no run folder ./seed*/none" (a second helper's trial); the hint says to move it.
    for v in ("none", "truth", "estimate"):
        _run_folder(tmp_path / "other" / "runs" / v, v, "go1")
    with pytest.raises(FileNotFoundError, match=r"one seed's folder; the matrix reads ROOT/seed"):
        transfer.runs_under(tmp_path / "other" / "runs")
    (tmp_path / "other" / "seeds").mkdir()
    (tmp_path / "other" / "runs").rename(tmp_path / "other" / "seeds" / "seed0")  # as it says
    assert set(transfer.runs_under(tmp_path / "other" / "seeds")) == {"none", "truth", "estimate"}


# ----------------------------------------------------------------------------- CLI


@pytest.mark.parametrize(
    "extra, names",
    [
        (["--observe", "truth", "--column", "estimate_harsh"], ["argument --column", "--observe"]),
        (["--column", "estimate_lat3"], ["argument --column", "'estimate_lat3'"]),
    ],
)
def test_policy_eval_column_errors_are_one_line(tmp_path, extra, names):
    run = _run_folder(tmp_path / "truth", "truth", None)
    res = subprocess.run(
        CLI + ["policy-eval", str(run), *extra], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 2, (res.stdout, res.stderr)
    errors = [line for line in res.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and errors[0].startswith("jax-contact policy-eval: error:")
    for name in names:
        assert name in errors[0], (name, errors[0])


def test_policy_eval_passes_the_column(tmp_path, monkeypatch, capsys):
    run = _run_folder(tmp_path / "truth", "truth", None)
    seen = {}
    contact = {"accuracy": 0.9, "f1": 0.8, "touchdown_delay_ms": [1.0, 2.0], "failures": 3}
    contact |= {"swing_phase_failure_rate": 0.125, "swing_phase_flag_on_rate": 0.25}

    def fake(run_dir, **kw):
        seen.update(kw, run_dir=run_dir)
        return {
            "trained_with": "truth",
            "observed": kw["column"],
            "return_mean": 1.5,
            "return_std": 0.5,
            "episode_length_mean": 20.0,
            "fell": 0.25,
            "contact": dict(contact, brier=0.1),
        }

    monkeypatch.setattr(policy_eval, "evaluate_policy", fake)
    monkeypatch.setattr(cli, "enable_compilation_cache", lambda: None)
    assert cli.main(["policy-eval", str(run), "--column", "estimate_lat2", "--envs", "2"]) == 0
    assert seen == {
        "run_dir": str(run),
        "observe": None,
        "column": "estimate_lat2",
        "n_envs": 2,
        "seed": 12345,
    }
    out = capsys.readouterr().out
    assert "truth  estimate_lat2     1.50 +-  0.50       20.0  0.25" in out
    # Table III's swing columns beside the failures (a flag on through a swing is none).
    assert "failures 3, sw-ph 12.5 %, sw-on 25.0 %, Brier 0.100" in out


# ------------------------------------------------------------------- the GPU script


def test_gpu_script_budget_and_merge():
    full = G.config_for("full", 6)
    unit = 5 * 10 * 256 * 32 * 20  # epochs x resets per eval x training step = 8,192,000
    assert G.budget_timesteps(full, 16_000_000) == 2 * unit
    assert G.budget_timesteps(full, 1) == unit
    assert ppo.brax_timesteps(dataclasses.replace(full, num_timesteps=2 * unit)) == 2 * unit

    def cell(v):
        return {"return": {"mean": v, "std": 0.0, "per_seed": [v]}}

    parts = [
        {"task": "go1", "metrics": ["return"], "cells": {"none": {"truth": cell(1.0)}}},
        {"task": "go1", "metrics": ["return"], "cells": {"truth": {"estimate": cell(2.0)}}},
        {"cells": {"truth": {"truth": cell(3.0)}, "estimate": {"truth": cell(4.0)}}},
    ]
    m = G.merge_parts(parts, ["truth", "estimate"])
    assert m["cells"]["none"] == {"truth": cell(1.0), "estimate": cell(1.0)}
    assert m["cells"]["truth"] == {"truth": cell(3.0), "estimate": cell(2.0)}
    assert m["missing"] == ["estimate/estimate"]
    assert m["task"] == "go1" and m["metrics"] == ["return"]


def test_gpu_script_deadline_stops_only_at_an_evaluation_after_it():
    lines = []
    late = G.deadline_log(time.time() - 1.0, out=lambda m, flush: lines.append(m))
    late("[truth] training Go1JoystickFlatTerrain, ...; compiling ...")  # not an evaluation
    late("[truth] step          0/16,384,000  return 1.00")  # before training: no checkpoint
    with pytest.raises(G.DeadlineReached, match="step 3,276,800"):
        late("[truth] step 3,276,800/16,384,000  return 1.00")
    on_time = G.deadline_log(time.time() + 3600.0, out=lambda m, flush: lines.append(m))
    on_time("[truth] step  3,276,800/16,384,000  return 1.00")
    G.deadline_log(None, out=lambda m, flush: lines.append(m))("[none] step 0/320")
    assert len(lines) == 5  # every line is still printed


# ---------------------------------------------------------------------------- shim


def test_device_put_replicated_shim_equals_jax():
    """On the pinned jax (0.9) the shim is not installed; where it would be, it gives what
    jax's own function gives, also through a pmap."""
    devices = jax.local_devices()
    tree = {
        "w": jnp.arange(6.0, dtype=jnp.float32).reshape(2, 3),
        "step": jnp.int32(7),
        "key": jax.random.PRNGKey(3),
    }
    got = _compat.device_put_replicated(tree, devices)
    want = jax.device_put_replicated(tree, devices)
    for k in tree:
        assert got[k].shape == want[k].shape == (len(devices),) + tree[k].shape
        assert got[k].dtype == want[k].dtype
        np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(want[k]))
        assert got[k].sharding.device_set == set(devices)
    f = jax.pmap(lambda t: jax.tree.map(lambda x: x * 2 + 1, t))
    for a, b in zip(jax.tree.leaves(f(got)), jax.tree.leaves(f(want)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="non-empty sequence"):
        _compat.device_put_replicated(tree, [])


def test_install_only_where_jax_lacks_it(monkeypatch):
    assert _compat.install() is False  # the pinned jax has its own
    assert jax.device_put_replicated is not _compat.device_put_replicated
    fake = types.SimpleNamespace()  # a jax without it (0.10 and later)
    monkeypatch.setattr(_compat, "jax", fake)
    assert _compat.install() is True
    assert fake.device_put_replicated is _compat.device_put_replicated


@pytest.mark.parametrize(
    "argv",
    [
        ["--train-s", "-1"],  # became one epoch through max(1, ...)
        ["--train-deadline-s", "0"],  # killed every training process at once
        ["--assumed-sps", "nan"],
        ["--seeds", "-3"],
        ["--eval-seed", "1.5"],
    ],
)
def test_gpu_script_refuses_bad_numbers_before_anything_runs(argv, capsys):
    """The GPU script's sizes and deadlines are checked by argparse (exit 2, the argument
    named), not found out minutes into a lent machine's time."""
    with pytest.raises(SystemExit) as stop:
        G.build_parser().parse_args(["run", *argv])
    assert stop.value.code == 2
    assert f"argument {argv[0]}" in capsys.readouterr().err


def test_gpu_script_run_help_explains_every_option(capsys):
    """``run --help`` listed ten options with no word of what they do; each now has a help,
    and a default is shown where there is one (not "(default: None)")."""
    import argparse

    parser = G.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    run = sub.choices["run"]
    for action in run._actions:
        assert action.help, action.option_strings
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: 555.0)" in text and "(default: None)" not in text


def test_gpu_script_refuses_what_would_mix_runs_before_anything_runs(tmp_path, capsys):
    """Run folders of an earlier run in --runs made every training child refuse to start
    while the matrix evaluated the earlier checkpoints as this run's; a repeated seed,
    deadlines out of order and an unwritable --out were found only on the lent machine.
    Each exits 2 naming the argument, before anything is spawned."""
    runs = tmp_path / "runs"
    (runs / "seed0" / "truth").mkdir(parents=True)
    base = ["run", "--out", str(tmp_path / "out"), "--runs", str(runs)]
    cases = [
        (["--seeds", "0"], "argument --runs: ", "seed0/truth"),
        (["--seeds", "1", "1"], "argument --seeds: repeated seed in [1, 1]", ""),
        (["--seeds", "1", "--train-deadline-s", "600"], "argument --train-deadline-s: 600 s", ""),
        (["--seeds", "1", "--out", "/proc/x"], "argument --out: ", "'/proc'"),
    ]
    for extra, message, detail in cases:
        with pytest.raises(SystemExit) as stop:
            G.main([*base, *extra])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and message in err and detail in err, (extra, err)
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in runs.iterdir()) == ["seed0"]


def test_gpu_script_tars_atomically(tmp_path, monkeypatch):
    """runs.tar.gz was written at its final path: a run stopped at its deadline while
    taring left a truncated archive there."""
    import tarfile

    run = _run_folder(tmp_path / "runs" / "seed0" / "truth", "truth", None)
    (run / "progress.csv").write_text("step\n0\n")
    real_add = tarfile.TarFile.add

    def stopped(self, *args, **kwargs):  # the deadline's signal, after the first file
        real_add(self, *args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(tarfile.TarFile, "add", stopped)
    with pytest.raises(KeyboardInterrupt):
        G._tar_runs(tmp_path / "runs", tmp_path / "runs.tar.gz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]  # nothing half-written
    monkeypatch.setattr(tarfile.TarFile, "add", real_add)
    G._tar_runs(tmp_path / "runs", tmp_path / "runs.tar.gz")
    with tarfile.open(tmp_path / "runs.tar.gz") as tar:
        names = sorted(tar.getnames())
    assert names == [
        "seed0/truth/checkpoints/000000000100",
        "seed0/truth/checkpoints/000000000100/ppo_network_config.json",
        "seed0/truth/progress.csv",
        "seed0/truth/run.json",
    ]
