"""``jax-contact estimate`` on recordings the library did not make (issue 16).

The round trip: the shipped simulated log (``tests/fixtures/planar_leg_hop.h5``, the planar
leg hopping, 2 s) exported as a recording with shuffled columns, renamed joints and feet
and degrees gives the probabilities that ``evaluate`` gives on the log itself. The
conversion of a floating-base robot (Go1) is checked against the readings it came from,
with NumPy differences as the reference where columns are missing; bad input gets one
line naming what is wrong. Only the round trip runs the estimator (one planar replay).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from jax_contact.envs.robots import load_robot
from jax_contact.io import read_log
from jax_contact.train import estimate_cmd
from jax_contact.train.recording import Recording, read_recording, write_recording_csv
from jax_contact.train.recording_convert import log_to_columns, to_readings

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures"
LOG = FIXTURES / "planar_leg_hop.h5"
CSV = FIXTURES / "planar_leg_hop.csv"
# Model name -> the recording's name for it.
RENAME = {"rail": "slider_z", "hip": "HIP_J", "knee": "KNEE_J", "foot": "toe"}
# How the round trip's recording reads back: its names and its degrees.
AS_RECORDED = {"names": {v: k for k, v in RENAME.items()}, "units": "deg"}


def _estimate(path, out_dir, **kw):
    """``estimate_recording`` of a planar-leg recording, without the progress line."""
    from jax_contact.train.recording_estimate import estimate_recording

    return estimate_recording(path, model="planar_leg", out_dir=out_dir, progress=False, **kw)


def _parser():
    p = argparse.ArgumentParser(prog="jax-contact")
    estimate_cmd.add_parser(p.add_subparsers(dest="command"))
    return p


@pytest.fixture(scope="module")
def planar_log():
    from jax_contact.train.logs import load_log

    return load_log(LOG)


@pytest.fixture(scope="module")
def round_trip(planar_log, tmp_path_factory):
    """evaluate on the log, and estimate on its shuffled, renamed, degree recording."""
    from jax_contact.train.log_evaluate import evaluate_file

    tmp = tmp_path_factory.mktemp("estimate")
    evaluated = evaluate_file(LOG, gm_grid_log=LOG)
    arrays, _ = read_log(LOG)
    cols = log_to_columns(planar_log, names=RENAME, units="deg", truth_force=arrays["truth/force"])
    order = np.random.default_rng(0).permutation(list(cols))
    write_recording_csv(tmp / "robot.csv", {k: cols[k] for k in order})
    estimated = _estimate(tmp / "robot.csv", tmp / "out", **AS_RECORDED)
    return SimpleNamespace(evaluated=evaluated, estimated=estimated, tmp=tmp, order=order)


def test_round_trip_gives_evaluates_probabilities(round_trip):
    assert list(round_trip.order)[:2] != ["time", "q/slider_z"]  # shuffled
    p_eval = np.asarray(round_trip.evaluated["outputs"]["probabilistic"])
    p_est = np.asarray(round_trip.estimated["outputs"]["probabilistic"])
    assert p_eval.shape == p_est.shape == (800, 1, 1)
    # Degrees and back cost a float64 rounding; the readings are float32 in the replay.
    np.testing.assert_allclose(p_est, p_eval, atol=1e-5)
    assert 0.3 < float(np.mean(p_eval > 0.5)) < 0.95  # a hop: both phases present
    s_eval = round_trip.evaluated["scores"]["probabilistic"]
    s_est = round_trip.estimated["scores"]["probabilistic"]
    for key in ("accuracy", "f1", "ece", "failures", "n_touchdowns"):
        assert s_est[key] == pytest.approx(s_eval[key], abs=1e-6), key
    assert round_trip.estimated["terms"] == ("dynamics", "diff_kinematics", "kinematics")


def test_evaluate_prints_every_metric_and_tunes_gm_on_a_grid_log(round_trip):
    from jax_contact.train.log_evaluate import tune_gm
    from jax_contact.train.report import format_scores
    from jax_contact.train.reproduce import GM_K_I, GM_LOAD_FRACTIONS

    ev = round_trip.evaluated
    best, gm, grid_scores = tune_gm(LOG)  # compiled already by evaluate's own tuning
    # Every K_I with K_I dt <= 1 at the log's 400 Hz (all five) x every load fraction.
    assert len(grid_scores) == len(GM_K_I) * len(GM_LOAD_FRACTIONS)
    # The grid point with the best F1 (ties: fewer failures) is the one evaluate used.
    f1 = {k: (v["f1"], -v["failures"]) for k, v in grid_scores.items()}
    assert f1[best] == max(f1.values())
    assert ev["gm"] == {"name": best, "K_I": float(gm.K_I), "threshold": float(gm.threshold)}
    # The kinematic detector is tuned on the same log by its own grid (best F1).
    from jax_contact.train.log_evaluate import tune_baselines

    tuned = tune_baselines(LOG)
    kin_name, kin = tuned["kinematic"]
    assert ev["kinematic"] == {
        "height_threshold": float(kin.height_threshold),
        "velocity_threshold": float(kin.velocity_threshold),
    }

    # GM by the estimator's rule (the reproduction's gm_fl), recomputed from the grid's
    # scores: among the points with sw-ph + sw-on <= 2 %, the best F1.
    def share(v):
        return np.nan_to_num(v["swing_phase_failure_rate"]) + np.nan_to_num(
            v["swing_phase_flag_on_rate"]
        )

    eligible = {k: v for k, v in grid_scores.items() if share(v) <= 0.02}
    fl = tuned["failure_limited"]["gm_fl"]
    assert eligible, "the hop's grid has points under the limit"
    assert fl["pick"] in eligible and f1[fl["pick"]] == max(f1[k] for k in eligible)
    evaluated_fl = ev["failure_limited"]["gm_fl"]
    assert evaluated_fl["pick"] == fl["pick"] and evaluated_fl["row"]
    assert ev["scores"]["gm_fl"]["f1"] == pytest.approx(grid_scores[fl["pick"]]["f1"])
    kin_rows = {"kinematic_fl"} if tuned["failure_limited"]["kinematic_fl"]["row"] else set()
    assert set(tuned["failure_limited_params"]) == {"gm_fl"} | kin_rows
    assert set(ev["scores"]) == {"probabilistic", best, "kinematic", "gm_fl"} | kin_rows
    text = format_scores(ev["scores"], title="planar_leg_hop.h5")
    lines = text.splitlines()
    for col in ("TD ms", "LO ms", "F1", "acc", "fail", "air-ph", "mTD", "mLO", "ECE"):
        assert col in lines[0]
    assert [ln.split()[0] for ln in lines[1:4]] == ["probabilistic", best, "gm_fl"]
    assert "ECE: expected calibration error" in text and "lift-off" in text
    s = ev["scores"]["probabilistic"]
    assert f"{s['accuracy']:.3f}" in lines[1] and f"{s['ece']:.3f}" in lines[1]


def test_logs_replay_with_the_feet_they_store(tmp_path):
    from jax_contact.train.logs import load_log

    arrays, attrs = read_log(LOG)
    from jax_contact.io import write_log

    write_log(tmp_path / "heel.h5", arrays, attrs | {"foot_names": ["heel"]})
    # The list is of the floor-touching geoms and their bodies, said so (a user read it as
    # every valid name, though any site or body names a foot too).
    said = r"foot 'heel' is no geom, site or body of the model; valid names: any site or body"
    with pytest.raises(ValueError, match=said + r" of the model, or a floor-.* \[.*'foot'.*\]"):
        load_log(tmp_path / "heel.h5")
    assert load_log(LOG).robot.description.foot_names == ("foot",)


def test_estimate_writes_hdf5_csv_png_and_metrics(round_trip):
    out = round_trip.tmp / "out"
    outputs = round_trip.estimated["outputs"]
    with h5py.File(out / "estimate.h5", "r") as f:
        np.testing.assert_array_equal(f["p_contact"][:, 0], outputs["probabilistic"][:, 0, 0])
        for field in ("p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff"):
            np.testing.assert_array_equal(f[field][:], outputs[f"probabilistic/{field}"][:, 0])
        assert json.loads(f.attrs["foot_names"]) == ["foot"]
        np.testing.assert_array_equal(
            f["truth/contact"][:], read_log(LOG)[0]["truth/contact"][:, 0]
        )
    table = read_recording(out / "estimate.csv").columns
    np.testing.assert_allclose(
        table["p_touchdown/foot"], outputs["probabilistic/p_touchdown"][:, 0, 0]
    )
    np.testing.assert_allclose(table["time"], (np.arange(800) + 1) * 0.0025)
    assert (out / "foot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["probabilistic"]["f1"] == pytest.approx(
        round_trip.estimated["scores"]["probabilistic"]["f1"]
    )
    assert not list(out.glob(".*.tmp"))  # atomic writes leave no temporary file


def test_missing_ground_truth_is_left_out_of_the_metrics(round_trip, tmp_path, capsys):
    """Blank truth cells (rows 50-59 of the foot's contact and force columns) are neither
    contact nor air: a note names the rows, ``truth/known`` marks them, and the metrics are
    those of the same outputs with those rows masked (they used to count as air, silently)."""
    from jax_contact.metrics import evaluate

    cols = dict(read_recording(round_trip.tmp / "robot.csv").columns)
    for name in ("contact/toe", "force/toe"):
        cols[name] = cols[name].copy()
        cols[name][50:60] = np.nan
    write_recording_csv(tmp_path / "gap.csv", cols)
    got = _estimate(tmp_path / "gap.csv", tmp_path / "out", plots=False, **AS_RECORDED)
    assert any("ground truth is missing" in n and "rows 50-59" in n for n in got["notes"])
    with h5py.File(tmp_path / "out" / "estimate.h5", "r") as f:
        known = f["truth/known"][:, 0]
    assert np.flatnonzero(~known).tolist() == list(range(50, 60))
    full = round_trip.estimated
    truth = read_log(LOG)[0]["truth/contact"]  # (T, 1, 1)
    mask = np.ones(truth.shape, bool)
    mask[50:60] = False
    want = evaluate(full["outputs"]["probabilistic"], truth, mask, dt=0.0025).as_dict()
    scores = got["scores"]["probabilistic"]
    assert scores["n_steps"] == full["scores"]["probabilistic"]["n_steps"] - 10
    for key in ("n_steps", "f1", "accuracy", "ece", "missed_liftoffs"):
        assert scores[key] == pytest.approx(want[key]), key


def test_lost_readings_inside_an_air_phase_do_not_cut_it(round_trip, tmp_path):
    """Three rows of the knee velocity lost in the middle of a true air phase: the foot's
    estimate is invalid there and left out of the metrics, but its truth is known, so the
    air phase stays one (metrics rule 8); until the thirty-eighth session the gap split it
    in two and added an air phase without a false contact, for every detector."""
    from jax_contact.metrics import evaluate

    truth = read_log(LOG)[0]["truth/contact"].astype(bool)  # (T, 1, 1)
    air = ~truth[:, 0, 0]
    edges = np.flatnonzero(np.diff(air.astype(int))) + 1  # first steps of new runs
    phases = [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if air[a]]
    a, b = max(phases, key=lambda ab: ab[1] - ab[0])
    mid = (a + b) // 2
    cols = dict(read_recording(round_trip.tmp / "robot.csv").columns)
    cols["qd/KNEE_J"] = cols["qd/KNEE_J"].copy()
    cols["qd/KNEE_J"][mid : mid + 3] = np.nan
    write_recording_csv(tmp_path / "lost.csv", cols)
    got = _estimate(tmp_path / "lost.csv", tmp_path / "out", plots=False, **AS_RECORDED)
    valid = np.asarray(got["outputs"]["probabilistic/valid"], bool).reshape(truth.shape)
    lost = np.flatnonzero(~valid[:, 0, 0])
    assert lost.size >= 3 and a < lost.min() and lost.max() < b  # inside the air phase
    clean = round_trip.estimated["scores"]
    for name, scores in got["scores"].items():
        out = np.asarray(got["outputs"][name]).reshape(truth.shape)
        assert scores["n_air_phases"] == clean[name]["n_air_phases"], name
        want = evaluate(out, truth, valid, dt=0.0025, truth_known=np.ones_like(valid))
        for key, value in want.as_dict().items():
            assert scores[key] == pytest.approx(value, rel=1e-9, nan_ok=True), (name, key)
        # The rule before: the gap cut the phase, one air phase more.
        split = evaluate(out, truth, valid, dt=0.0025).n_air_phases
        assert split == clean[name]["n_air_phases"] + 1, name


# The round trip's recording names, as --names reads them inline.
NAMES_INLINE = ",".join(f"{v}={k}" for k, v in RENAME.items())


def _halves(round_trip, tmp_path, change=None):
    """The round trip's recording (renamed, degrees) cut into two runs of 1 s, as files."""
    cols = dict(read_recording(round_trip.tmp / "robot.csv").columns)
    if change:
        change(cols)
    half = len(cols["time"]) // 2
    paths = []
    for name, part in (("first", slice(None, half)), ("second", slice(half, None))):
        paths.append(tmp_path / f"{name}.csv")
        write_recording_csv(paths[-1], {k: v[part] for k, v in cols.items()})
    return [str(x) for x in paths]


def test_tune_on_recordings_starts_where_estimate_does(round_trip, tmp_path, capsys):
    """``jax-contact tune --model`` tunes on recordings of your robot, read as ``estimate``
    reads them (--names, --units): epoch 0 of the fit is the untuned defaults of
    ``estimate``, so its validation BCE and F1 are those of ``estimate``'s output on the
    validation recording (BCE recomputed here in float64 from that output); the file
    records the recordings and the terms they support, and ``estimate --params`` takes it."""
    import jax_contact as jc
    from jax_contact.train import tune_cmd

    first, second = _halves(round_trip, tmp_path)
    out = tmp_path / "tuned.json"
    argv = [first, "--validate", second, "--model", "planar_leg", "--names", NAMES_INLINE]
    argv += ["--units", "deg", "--epochs", "2", "--out", str(out)]
    assert tune_cmd.main(argv) == 0
    assert "which assume `anymal_like` sensors, and no noise is tuned below" in (
        capsys.readouterr().err
    )
    _, prov = jc.load_params(out, with_provenance=True)
    (log,), (val,) = prov["logs"], prov["validation"]
    assert (log["kind"], log["robot"], log["steps"], val["steps"]) == (
        "recording",
        "planar_leg",
        400,
        400,
    )
    assert log["terms"] == ["dynamics", "diff_kinematics", "kinematics"]
    assert log["sha256"] == hashlib.sha256(Path(first).read_bytes()).hexdigest()
    ref = _estimate(second, tmp_path / "ref", plots=False, **AS_RECORDED)
    p = np.asarray(ref["outputs"]["probabilistic"], np.float64).reshape(-1)
    with h5py.File(tmp_path / "ref" / "estimate.h5", "r") as f:
        truth = f["truth/contact"][:].reshape(-1)
    p = np.clip(p, 1e-7, 1 - 1e-7)
    bce = -np.mean(truth * np.log(p) + (1 - truth) * np.log(1 - p))
    epoch0 = prov["history"][0]
    assert epoch0["val_bce"] == pytest.approx(bce, rel=1e-4)
    assert epoch0["val_f1"] == pytest.approx(ref["scores"]["probabilistic"]["f1"], abs=1e-6)
    got = _estimate(second, tmp_path / "tuned", plots=False, params_path=out, **AS_RECORDED)
    assert got["scores"]["probabilistic"]["n_steps"] == 400


def test_tuning_leaves_out_the_steps_estimate_predicts_only(round_trip, tmp_path):
    """The knee velocity lost on rows 300-304 of a recording: the tuning loss leaves out
    exactly the steps at which ``estimate``'s filter predicted only (its ``valid``), and
    the steps whose truth is missing (rows 100-109)."""
    from jax_contact.envs.robots import load_robot as load
    from jax_contact.train.tune_data import load_tuning_recording

    def change(cols):
        cols["qd/KNEE_J"] = cols["qd/KNEE_J"].copy()
        cols["qd/KNEE_J"][300:305] = np.nan
        for name in ("contact/toe", "force/toe"):
            cols[name] = cols[name].copy()
            cols[name][100:110] = np.nan

    first, _ = _halves(round_trip, tmp_path, change)
    data, attrs, _, _ = load_tuning_recording(
        first, load("planar_leg"), "planar_leg", names=AS_RECORDED["names"], units="deg"
    )
    ref = _estimate(first, tmp_path / "ref", plots=False, **AS_RECORDED)
    valid = np.asarray(ref["outputs"]["probabilistic/valid"], bool).reshape(-1)
    assert not valid[300:305].all() and valid[:300].all()
    known = np.ones(400, bool)
    known[100:110] = False
    np.testing.assert_array_equal(np.asarray(data.mask).reshape(-1), valid & known)
    # The lost rows keep their truth for the validation cells' air phases (metrics rule 8).
    np.testing.assert_array_equal(np.asarray(data.known).reshape(-1), known)


@pytest.mark.parametrize(
    "case, match",
    [
        ("copy", r"argument --validate: recording '.*copy.csv' has the same content as tuning"),
        ("no_truth", r"argument LOG: recording '.*first.csv' has no ground truth columns"),
        ("no_qd", r"argument LOG: recording '.*first.csv' has no column qd/KNEE_J: those"),
        ("other_terms", r"--validate: recording '.*second.csv' has measurement terms \['diff"),
        ("val_twice", r"argument --validate: '.*second.csv' is the same run as validation log"),
        (
            "simulate_log",
            r"argument --validate: '.*planar_leg_hop.h5' is a log of `jax-contact"
            r" simulate`: tune on simulated logs without --model",
        ),
    ],
)
def test_tune_refuses_recordings_it_cannot_tune_on(round_trip, tmp_path, case, match):
    """Before any fit: a validation recording that is a copy of a tuning one, a recording
    without ground truth, one whose joint velocities would be differences of positions
    (``estimate`` adds their noise to any parameters, so a tuned file would count it
    twice), recordings whose columns support different terms, a validation recording
    given twice, and a simulated log given with --model."""
    from jax_contact.train import tune_inputs

    def change(cols):
        if case == "no_truth":
            del cols["contact/toe"], cols["force/toe"]
        if case == "no_qd":
            del cols["qd/KNEE_J"]

    first, second = _halves(round_trip, tmp_path, change)
    if case == "copy":
        second = str(tmp_path / "copy.csv")
        Path(second).write_bytes(Path(first).read_bytes())
    if case == "simulate_log":
        second = str(LOG)
    if case == "other_terms":  # no torques in the second: no dynamics term there
        cols = dict(read_recording(second).columns)
        write_recording_csv(second, {k: v for k, v in cols.items() if not k.startswith("tau/")})
    validate = [second, second] if case == "val_twice" else [second]
    args = argparse.Namespace(
        logs=[first], validate=validate, terrain_model="flat", noise_floor="none",
        model="planar_leg", feet=None, names=NAMES_INLINE, units="deg", resample=False,
        force_threshold=1.0,
    )  # fmt: skip
    with pytest.raises(ValueError, match=match):
        tune_inputs.load_logs(args)


def test_tune_warns_on_recordings_the_model_does_not_fit(round_trip, tmp_path, capsys):
    """Readings the model does not fit: ``tune`` used to tune on them without a word and
    write the file. The rail reading 30 cm too high (a floor not at z = 0): ``estimate``'s
    floor warning for each recording and a summary naming them (reading alone). Angles in
    degrees read as radians: after the fit, the untuned estimator's validation F1 (near 0)
    with what to check."""
    from jax_contact.train import tune_cmd, tune_inputs

    def raised(cols):
        cols["q/slider_z"] = cols["q/slider_z"] + 0.3

    first, second = _halves(round_trip, tmp_path, raised)
    args = argparse.Namespace(
        logs=[first], validate=[second], terrain_model="flat", noise_floor="none",
        model="planar_leg", feet=None, names=NAMES_INLINE, units="deg", resample=False,
        force_threshold=1.0,
    )  # fmt: skip
    tune_inputs.load_logs(args)
    err = capsys.readouterr().err
    for path in (first, second):
        assert re.search(
            rf"warning: {re.escape(path)}: the feet's soles sit 2\d cm above z = 0", err
        )
    assert f"warning: 2 of 2 recordings read with warnings ({first}, {second})" in err
    first, second = _halves(round_trip, tmp_path)
    argv = [first, "--validate", second, "--model", "planar_leg", "--names", NAMES_INLINE]
    argv += ["--epochs", "1", "--out", str(tmp_path / "t.json")]  # no --units deg
    assert tune_cmd.main(argv) == 0
    err = capsys.readouterr().err
    f1 = re.search(r"warning: the untuned estimator's validation F1 is (\d\.\d+): the", err)
    assert f1 and float(f1.group(1)) < 0.5, err[-2000:]


def test_estimate_says_when_a_file_runs_fewer_terms_than_the_recording_supports(
    round_trip, tmp_path
):
    """A parameter file without the dynamics term (tuned on recordings without torques)
    on a recording with torques: a note says so (it ran silently without it)."""
    import jax_contact as jc
    from jax_contact.train.reproduce import planar_estimator_params

    params = planar_estimator_params(3, 0.0025)
    path = jc.save_params(tmp_path / "no_dyn.json", params.replace(terms=params.terms[1:]))
    got = _estimate(
        round_trip.tmp / "robot.csv", tmp_path / "out", plots=False, params_path=path,
        **AS_RECORDED,
    )  # fmt: skip
    assert params.terms[0] == "dynamics"
    assert f"the parameters {str(path)!r} run no dynamics term, which this recording's" in (
        "\n".join(got["notes"])
    )
    # The term it ran without is blank in estimate.csv (its diagnostics, computed anyway,
    # held probabilities nothing used: a helper's audit), the others are not.
    out = read_recording(tmp_path / "out" / "estimate.csv").columns
    assert np.isnan(out["p_dynamics/foot"]).all()
    assert np.isfinite(out["p_kinematics/foot"]).any() and np.isfinite(out["p_contact/foot"]).all()
    with h5py.File(tmp_path / "out" / "estimate.h5", "r") as f:
        assert np.isnan(f["p_dynamics"][:]).all() and np.isfinite(f["p_contact"][:]).all()


def test_tune_checks_recording_flags_without_jax(tmp_path):
    """The recording flags need --model, a recording needs --model, and --select spread
    (a bootstrap over envs) has nothing to resample in a recording: refused by ``check``,
    before JAX loads."""
    rec, log = tmp_path / "run.csv", tmp_path / "run.h5"
    rec2, log2 = tmp_path / "other.csv", tmp_path / "other.h5"
    for f in (rec, rec2):
        f.write_text("time\n")
    for f in (log, log2):
        f.write_bytes(b"")
    code = (
        "import sys, argparse, jax_contact.train.tune_cmd as t\n"
        "p = argparse.ArgumentParser(); t.add_parser(p.add_subparsers())\n"
        "for argv in sys.argv[1:]:\n"
        "    a = p.parse_args(['tune', *argv.split()])\n"
        "    try:\n        a.check(a)\n    except ValueError as e:\n        print(e)\n"
        "assert 'jax' not in sys.modules\n"
    )
    cases = [
        f"{rec} --validate {log} --out x.json",
        f"{log} --validate {log2} --names a=b --out x.json",
        f"{rec} --validate {rec2} --model planar_leg --select spread --out x.json",
        f"{rec} --validate {rec2} --model planar_leg --force-threshold -1 --out x.json",
    ]
    out = subprocess.run([sys.executable, "-c", code, *cases], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == (
        f"argument LOG: {str(rec)!r} is a recording: tune on recordings of your robot with"
        " --model ROBOT (read as `jax-contact estimate` reads them)"
    )
    assert lines[1].startswith("argument --names: says how a recording is read; it needs --model")
    assert lines[2].startswith("argument --select: spread resamples the validation logs' envs")
    assert lines[3].startswith("argument --force-threshold: must be a finite force >= 0 N")


def test_a_degree_recording_read_as_radians_warns(round_trip, tmp_path, capsys):
    """The round trip's recording holds degrees; read as radians (no units='deg') the hip
    leaves its +-1.6 rad range and the leg reads air throughout: both are printed as
    warnings (before, only the usual notes and a summary of 0.00)."""

    got = _estimate(
        round_trip.tmp / "robot.csv", tmp_path / "out", names=AS_RECORDED["names"], plots=False
    )
    text = capsys.readouterr().out
    # No --feet: the feet the rule found are named, as simulate names them.
    assert "note: feet found in the model: ['foot'] (name them with --feet)" in text
    assert "warning: column 'q/HIP_J': outside the range of joint 'hip', [-1.6, 1.6] rad" in text
    assert "pass --units deg" in text
    assert np.mean(got["outputs"]["probabilistic"] > 0.5) < 0.01
    assert "warning: every foot reads air on more than 99 % of the steps" in text


def test_every_foot_in_the_air_is_no_warning_on_a_few_readings():
    """``deploy-check --steps 1`` warned that every foot reads air on 99 % of one step:
    the belief starts at its prior, so under a second of readings draws no warning."""
    from jax_contact.train.recording_estimate import ALL_AIR_MIN_S, contact_summary

    air = np.zeros(2)
    line, warning = contact_summary(air, ["L", "R"], seconds=0.0025)
    assert line.endswith("L 0.00  R 0.00") and warning is None
    assert contact_summary(air, ["L", "R"], seconds=ALL_AIR_MIN_S)[1].startswith("every foot")
    assert contact_summary(np.array([0.0, 0.02]), ["L", "R"], seconds=9.0)[1] is None
    # A foot with no estimated step (every one predicted only) has no share, and no verdict.
    line, warning = contact_summary(np.array([0.0, np.nan]), ["L", "R"], seconds=9.0)
    assert line.endswith("L 0.00  R -") and warning is None


def test_torques_of_the_wrong_sign_warn_naming_the_foot(round_trip, tmp_path, capsys):
    """The planar sample's torques, negated (a joint axis opposite the model's): the
    dynamics term reads air on 94 % of the steps where the foot stands still (15 % with
    the recorded torques, the round trip above, which does not warn)."""

    assert not [n for n in round_trip.estimated["notes"] if "dynamics term reads air" in n]
    rec = read_recording(CSV)
    cols = {k: -v if k.startswith("tau/") else v for k, v in rec.columns.items()}
    write_recording_csv(tmp_path / "flipped.csv", cols)
    got = _estimate(tmp_path / "flipped.csv", tmp_path / "out", plots=False)
    text = capsys.readouterr().out
    warned = [n for n in got["notes"] if "dynamics term reads air" in n]
    assert len(warned) == 1 and "warning: the dynamics term reads air" in text
    # The planar leg's one foot, with its leg's two torque columns (the rail has none); its
    # estimated push on the still steps is negative (the recorded sample's is about +100 N).
    assert re.search(
        r"\(foot 9\d% air, median push -\d+(\.\d)? N \[tau/hip, tau/knee\];", warned[0]
    )
    assert "check those tau/ columns' sign" in warned[0]
    assert "consequence of the warnings above" not in warned[0]  # the only warning
    # With the rail's acceleration negated as well, its warning comes first and the torque
    # warning defers to it (the dynamics term reads that acceleration too).
    cols["qdd/rail"] = -cols["qdd/rail"]
    write_recording_csv(tmp_path / "two.csv", cols)
    got = _estimate(tmp_path / "two.csv", tmp_path / "two", plots=False)
    warned = [n for n in got["notes"] if n.startswith("WARNING")]
    assert [n.split("'")[1] for n in warned[:1]] == ["qdd/rail"] and len(warned) == 2
    assert warned[1].endswith("or a consequence of the warnings above (fix those first)")


def test_truth_columns_in_another_foot_order_are_named(monkeypatch):
    """A trot's pattern over 400 steps: feet a and d in phase, b and c in the other phase
    (contact on 60 % of each 40-step cycle, so opposite feet share 20 % of the steps in
    contact). The estimate is the truth with every 25th step flipped (96 % agreement).

    - Own order: quiet.
    - Columns a and b exchanged: a's estimate against column "b" agrees on 96 %. Against
      its own column (b's truth): a and b are both in contact on 20 % of the steps and
      never both in the air, so the truth agrees on 20 %, and with 4 % of the estimate
      flipped 0.2 x 0.96 + 0.8 x 0.04 = 0.224; the mean over feet is (2 x 0.224 + 2 x
      0.96) / 4 = 0.592 in the given order against 0.96: named (a gain above the 0.1
      margin), with both feet and nothing about c or d.
    - Columns a and d exchanged (in phase): the same agreement either way: quiet.
    - 150 steps only (under 200 per pair): quiet.
    - An estimate that fits no order well (a new user's negated torques: the best order
      0.52 against the own 0.30): every 4th step flipped, 75 % agreement. The exchanged
      columns as above give (2 x (0.2 x 0.75 + 0.8 x 0.25) + 2 x 0.75) / 4 = 0.55 against
      0.75 in the order that undoes it: a gain above the margin, but an order that agrees
      on under 0.8 itself: quiet.
    """
    from jax_contact.train.recording_checks import truth_order

    t = np.arange(400)
    phase = (t % 40) < 24
    truth = np.stack([phase, np.roll(phase, 20), np.roll(phase, 20), phase], axis=1)
    flip = (t % 25 == 0)[:, None]
    p = np.where(truth ^ flip, 0.9, 0.1)
    scored = np.ones_like(truth)
    feet = ["a", "b", "c", "d"]
    assert truth_order(p, truth, scored, feet) is None
    text = truth_order(p, truth[:, [1, 0, 2, 3]], scored, feet)
    assert text.startswith("WARNING the truth columns fit the estimates better")
    assert "(96% of steps agree against 59%)" in text
    assert "a's estimate agrees with the column given as b's on 96% of steps, with its own" in text
    assert "c's" not in text and "d's" not in text
    assert truth_order(p, truth[:, [3, 1, 2, 0]], scored, feet) is None
    assert truth_order(p[:150], truth[:150, [1, 0, 2, 3]], scored[:150], feet) is None
    noisy = np.where(truth ^ (t % 4 == 0)[:, None], 0.9, 0.1)
    assert truth_order(noisy, truth[:, [1, 0, 2, 3]], scored, feet) is None
    # Without the agreement floor it would be named, with these numbers:
    from jax_contact.train import recording_checks

    monkeypatch.setattr(recording_checks, "MIN_ORDER_AGREEMENT", 0.7)
    text = truth_order(noisy, truth[:, [1, 0, 2, 3]], scored, feet)
    assert "(75% of steps agree against 55%)" in text


def test_the_torque_check_counts_only_valid_still_steps():
    """Hand counts: foot a is still on 50 valid steps, the dynamics term says air on 41 of
    them (82 % > 80 %): named. Foot b: the same with 40 of 50 (80 %, not above): not
    flagged, but listed as above half once another foot is (a scale error reaches every
    leg; a user's motor-side torques named one foot of four). Foot c: air on every still
    step but only 39 of them valid: too few to judge."""
    from jax_contact.train.recording_checks import dynamics_disagrees

    t = 60
    p_dk = np.zeros((t, 3))
    p_dk[:50] = 0.65
    p_dyn = np.full((t, 3), 0.9)
    p_dyn[:41, 0] = 0.1
    p_dyn[:40, 1] = 0.1
    p_dyn[:, 2] = 0.1
    valid = np.ones((t, 3), bool)
    valid[39:, 2] = False
    text = dynamics_disagrees(p_dyn, p_dk, valid, ["a", "b", "c"])
    assert text.startswith("the dynamics term reads air on most steps where the foot stands")
    assert "(a 82%; also above half: b 80%;" in text and " c " not in text
    cols = [["tau/a1", "tau/a2"], ["tau/b1"], ["tau/c1"]]
    text = dynamics_disagrees(p_dyn, p_dk, valid, ["a", "b", "c"], cols)
    assert "(a 82% [tau/a1, tau/a2]; also above half: b 80%;" in text and "tau/b1" not in text
    p_dyn[:25, 1] = 0.9  # b air on 15 of 50 still steps, 30 %: a right foot's share
    assert "also above half" not in dynamics_disagrees(p_dyn, p_dk, valid, ["a", "b", "c"])
    assert dynamics_disagrees(p_dyn[:, 1:], p_dk[:, 1:], valid[:, 1:], ["b", "c"]) is None


def test_the_torque_check_tells_a_straight_leg_from_wrong_torques():
    """A user's biped standing straight on flat soles read air (P 0.004 under 95 N) and the
    warning blamed the torques' sign or unit. A one-legged model on a rail (hip and knee
    about y) with a box sole whose centre is 1 cm ahead of the shank: straight (qpos0),
    the sole centre relative to the hip is (0.01, 0, -0.51) and to the knee (0.01, 0,
    -0.26); a hinge about y moves it by y x r = (r_z, 0, -r_x) per radian, so the Jacobian
    over (hip, knee) has rows x (-0.51, -0.26) and z (-0.01, -0.01): ratio
    0.01 sqrt(2) / sqrt(0.51^2 + 0.26^2) = 0.0247, below STRAIGHT_LEG_RATIO. Knees bent
    (hip 0.5 rad, knee -1 rad) it is not named. The warning then names the straight leg
    first."""
    import mujoco

    from jax_contact.envs import feet
    from jax_contact.train.recording_checks import (
        MIN_STILL_STEPS,
        STRAIGHT_LEG_RATIO,
        dynamics_disagrees,
        straight_legs,
    )

    leg = (
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<body name="base" pos="0 0 .6"><joint name="rail" type="slide" axis="0 0 1"/>'
        '<geom type="box" size=".1 .1 .05" contype="0" conaffinity="0" mass="5"/>'
        '<body name="thigh"><joint name="hip" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -.25" size=".02" contype="0" conaffinity="0"/>'
        '<body name="shank" pos="0 0 -.25"><joint name="knee" axis="0 1 0"/>'
        '<geom name="sole" type="box" pos="0.01 0 -0.25" size=".08 .03 .01"/></body></body>'
        '</body></worldbody><actuator><motor joint="hip"/><motor joint="knee"/></actuator>'
        "</mujoco>"
    )
    m = mujoco.MjModel.from_xml_string(leg)
    desc, _ = feet.describe(m, ["sole"])
    still = np.ones((MIN_STILL_STEPS, 1), bool)
    straight = straight_legs(m, desc, np.zeros((MIN_STILL_STEPS, 3)), still)
    want = 0.01 * np.sqrt(2.0) / np.hypot(0.51, 0.26)
    assert want < STRAIGHT_LEG_RATIO and straight == {"sole": pytest.approx(want, rel=1e-6)}
    bent = np.tile([0.0, 0.5, -1.0], (MIN_STILL_STEPS, 1))
    assert straight_legs(m, desc, bent, still) == {}
    assert straight_legs(m, desc, bent, still[:-1]) == {}  # too few still steps to judge
    p_dyn, p_dk = np.full((60, 1), 0.1), np.full((60, 1), 0.65)
    text = dynamics_disagrees(p_dyn, p_dk, np.ones((60, 1), bool), ["sole"], straight=straight)
    assert text.startswith("legs nearly straight where their feet stand still (sole: a vertical")
    assert "2% as much as a horizontal one" in text and "; otherwise, the dynamics term" in text


def test_the_torque_check_reads_a_pulling_foot_without_the_sign_test():
    """Where the dynamics term runs without its sign test (a light robot) it reads air on
    few still steps whatever the torques' sign; the push tells. Hand-made: 50 still steps
    of three feet whose dynamics term reads air on 10 of them (20 %, under the 80 % bound).
    Foot a's push is -3 N on 30 still steps and +5 N on 20 (median -3 N): named as pulling.
    Foot b's is +5 N on 30 and -3 N on 20 (median +5 N): quiet. Foot c pulls on every step
    but is still on 39 valid steps only: too few to judge. Without ``push`` all are quiet
    (the dynamics term alone)."""
    from jax_contact.train.recording_checks import dynamics_disagrees

    t = 60
    p_dk = np.zeros((t, 3))
    p_dk[:50] = 0.65
    p_dyn = np.full((t, 3), 0.9)
    p_dyn[:10] = 0.1
    valid = np.ones((t, 3), bool)
    valid[39:, 2] = False
    push = np.full((t, 3), 5.0)
    push[:30, 0] = -3.0
    push[30:50, 1] = -3.0
    push[:, 2] = -3.0
    push[50:] = -100.0  # steps that are not still do not count
    assert dynamics_disagrees(p_dyn, p_dk, valid, ["a", "b", "c"]) is None
    text = dynamics_disagrees(p_dyn, p_dk, valid, ["a", "b", "c"], push=push)
    assert text.startswith(
        "the dynamics term reads air on most steps where the foot stands still, or the foot"
        " pulls on the ground there (a 20% air, median push -3 N;"
    )
    assert " b " not in text and " c " not in text


def test_the_python_call_checks_its_output_folder_first(tmp_path):
    """``estimate_recording`` refuses an ``out_dir`` that is a file before reading anything
    (the recording named here does not exist): it used to run the whole replay and then
    raise a bare FileExistsError."""
    from jax_contact.train.recording_estimate import estimate_recording

    (tmp_path / "afile").write_text("x")
    with pytest.raises(ValueError, match=r"argument out_dir: .*afile' exists and is not a folder"):
        estimate_recording(tmp_path / "none.csv", model="planar_leg", out_dir=tmp_path / "afile")


def test_a_rerun_says_which_earlier_outputs_it_removed(round_trip, tmp_path, capsys):
    """A run without ground truth into a folder holding an earlier run's metrics.json
    removes it (the folder then holds one run) and says so; a note of the user's stays."""

    cols = read_recording(round_trip.tmp / "robot.csv").columns
    write_recording_csv(
        tmp_path / "no_truth.csv", {k: v for k, v in cols.items() if "/toe" not in k}
    )
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    (out / "notes.txt").write_text("mine")
    _estimate(
        tmp_path / "no_truth.csv",
        out,
        names={v: k for k, v in RENAME.items() if k != "foot"},
        units="deg",
        plots=False,
    )
    text = capsys.readouterr().out
    assert "removed the earlier run's ['metrics.json']" in text
    assert sorted(p.name for p in out.iterdir()) == ["estimate.csv", "estimate.h5", "notes.txt"]


def test_baselines_are_tuned_on_the_foot_steps_they_are_scored_on(tmp_path):
    """evaluate leaves out of every detector's score the foot-steps where the estimator
    skipped a foot for a lost reading (scored_steps); tune_baselines scored the grid on
    every valid step, so the rows it picked were tuned on more steps than they are
    scored on. The knee's velocity lost on readings 200-219 of the hop: the grid's scores
    of the pick now count the steps evaluate's row counts, and give its F1."""
    from jax_contact.io import write_log
    from jax_contact.train.log_evaluate import evaluate_file, tune_baselines

    arrays, attrs = read_log(LOG)
    arrays = {k: np.array(v) for k, v in arrays.items()}
    arrays["readings/qvel"][200:220, 0, 2] = np.nan
    lost = write_log(tmp_path / "lost.h5", arrays, attrs)
    tuned = tune_baselines(lost)
    name = tuned["gm"][0]
    got = evaluate_file(lost, gm_grid_log=lost, tuned_baselines=tuned)["scores"][name]
    grid = tuned["scores"]["gm"][name]
    assert got["n_steps"] < 800 and grid["n_steps"] == got["n_steps"]
    assert grid["f1"] == pytest.approx(got["f1"], abs=1e-12)


def test_evaluate_on_a_recording_points_to_estimate():
    from jax_contact.io import read_log

    with pytest.raises(ValueError, match=r"cannot be read as HDF5.*read by `jax-contact estimate`"):
        read_log(CSV)


def test_the_command_runs_on_the_shipped_sample(round_trip, tmp_path, capsys):
    args = _parser().parse_args(
        ["estimate", str(CSV), "--model", "planar_leg", "--out", str(tmp_path), "--no-plots"]
    )
    args.check(args)
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "estimator terms: dynamics, diff_kinematics, kinematics" in text
    assert "probabilistic" in text and "TD ms" in text  # the metrics table
    got = read_recording(tmp_path / "estimate.csv").columns["p_contact/foot"]
    want = round_trip.evaluated["outputs"]["probabilistic"][:, 0, 0]
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_shipped_sample_is_the_export_of_the_shipped_log(planar_log):
    assert CSV.stat().st_size < 1_000_000 and LOG.stat().st_size < 1_000_000
    arrays, attrs = read_log(LOG)
    assert attrs["robot"] == "planar_leg" and attrs["foot_names"] == ["foot"]
    want = log_to_columns(planar_log, truth_force=arrays["truth/force"])
    got = read_recording(CSV).columns
    assert list(got) == list(want)
    for k in want:
        np.testing.assert_array_equal(got[k], want[k], err_msg=k)


# --------------------------------------------------------------- floating-base conversion


@pytest.fixture(scope="module")
def go1_log():
    """A synthetic Go1 log (random states; the conversion needs no physics)."""
    robot = load_robot("go1")
    rng = np.random.default_rng(3)
    t_len, dt = 40, 0.0025
    qpos = np.tile(robot.home_qpos, (t_len, 1, 1)) + rng.normal(0, 0.05, (t_len, 1, 19))
    qpos[..., 3:7] /= np.linalg.norm(qpos[..., 3:7], axis=-1, keepdims=True)
    qvel = rng.normal(0, 0.5, (t_len, 1, 18))
    readings = {
        "qpos": qpos,
        "qvel": qvel,
        "qacc": rng.normal(0, 5, (t_len, 1, 18)),
        "tau": rng.normal(0, 3, (t_len, 1, 18)) * (np.arange(18) >= 6),
    }
    truth = rng.random((t_len, 1, 4)) > 0.5
    return SimpleNamespace(readings=readings, robot=robot, dt=dt, truth=truth)


def test_a_zero_base_quaternion_is_a_lost_reading_and_never_one_is_refused(go1_log):
    """A base quaternion of zeros (a driver's zero fill) is no orientation: its rows convert
    as NaN, a lost reading (a note names them; the steps that read them are invalid, as
    for a NaN), not as a rotation of zeros normalised to NaN with NumPy's warning. Zeros or
    NaN on every row refuse the recording, naming the columns."""
    import warnings

    cols = log_to_columns(go1_log)
    quat = [f"base_quat/{c}" for c in "wxyz"]
    zeroed, nan = dict(cols), dict(cols)
    for c in quat:
        zeroed[c] = np.where(np.arange(40) // 2 == 10, 0.0, cols[c])  # rows 20-21
        nan[c] = np.where(np.arange(40) // 2 == 10, np.nan, cols[c])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "invalid value encountered in divide"
        got = to_readings(Recording(zeroed, "r"), go1_log.robot)
    want = to_readings(Recording(nan, "r"), go1_log.robot)
    for key in ("qpos", "qvel", "qacc", "tau"):
        np.testing.assert_array_equal(got.readings[key], want.readings[key], err_msg=key)
    np.testing.assert_array_equal(got.valid, want.valid)
    assert not got.valid[20:22].any() and got.valid[:20].all()
    lost = [n for n in got.notes if n.startswith(f"columns {quat} have a norm below 0.1")]
    assert len(lost) == 1 and lost[0].endswith("read as lost: rows 20-21 (0.0525-0.055 s)")
    for c in quat:
        zeroed[c] = np.where(np.arange(40) < 5, np.nan, 0.0)
    with pytest.raises(ValueError, match=r"recording 'r': columns \['base_quat/w', .* every row"):
        to_readings(Recording(zeroed, "r"), go1_log.robot)


@pytest.mark.parametrize("fmt", ["csv", "npz", "h5"])
def test_go1_columns_convert_back_to_the_readings(go1_log, tmp_path, fmt):
    names = {"FR_hip_joint": "fr_abad", "RL_calf_joint": "rl_knee", "FL": "front_left"}
    cols = log_to_columns(go1_log, names=names, units="deg")
    path = tmp_path / f"rec.{fmt}"
    if fmt == "csv":
        write_recording_csv(path, cols)
    elif fmt == "npz":
        np.savez(path, **cols)
    else:
        with h5py.File(path, "w") as f:
            for k, v in cols.items():
                f[k] = v
    conv = to_readings(
        read_recording(path), go1_log.robot, names={v: k for k, v in names.items()}, units="deg"
    )
    for key in ("qpos", "qvel", "qacc", "tau"):
        np.testing.assert_allclose(
            conv.readings[key], go1_log.readings[key], atol=1e-12, err_msg=key
        )
    np.testing.assert_array_equal(conv.truth, go1_log.truth)
    assert conv.dt == pytest.approx(0.0025) and conv.valid.all()
    assert conv.terms == ("dynamics", "diff_kinematics", "kinematics")
    assert conv.notes == ("ground truth from contact/ for ['FR', 'FL', 'RR', 'RL']",)


def _diff(x, dt):
    """The reference: backward difference, the first row repeating the second's."""
    d = np.diff(x, axis=0) / dt
    return np.concatenate([d[:1], d], axis=0)


def test_missing_velocities_accelerations_and_torques_are_derived(go1_log):
    cols = log_to_columns(go1_log, velocities=False, accelerations=False, torques=False)
    for k in [c for c in cols if c.startswith("base_linvel/")]:
        del cols[k]
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    dt, r = go1_log.dt, go1_log.readings
    np.testing.assert_allclose(
        conv.readings["qvel"][..., 6:], _diff(r["qpos"][..., 7:], dt), atol=1e-9
    )
    np.testing.assert_allclose(
        conv.readings["qvel"][..., :3], _diff(r["qpos"][..., :3], dt), atol=1e-9
    )
    np.testing.assert_allclose(conv.readings["qvel"][..., 3:6], r["qvel"][..., 3:6], atol=1e-12)
    np.testing.assert_allclose(
        conv.readings["qacc"][..., 6:], _diff(_diff(r["qpos"][..., 7:], dt), dt), atol=1e-6
    )
    np.testing.assert_allclose(
        conv.readings["qacc"][..., 3:6], _diff(r["qvel"][..., 3:6], dt), atol=1e-9
    )
    assert np.all(conv.readings["tau"] == 0)
    assert conv.terms == ("diff_kinematics", "kinematics") and not conv.has_torque
    text = "\n".join(conv.notes)
    assert "dynamics term is off" in text and "differentiated from base_pos" in text
    assert "joint velocities differentiated from positions" in text


def test_positions_alone_switch_the_dynamics_term_off(go1_log):
    """With torques but no qd/ or qdd/ columns the legs' accelerations would be second
    differences of positions (0.02 rad at 400 Hz: 7800 rad/s^2 of noise): the dynamics term
    is off, with a note naming the dofs; with velocities recorded it stays on."""
    cols = log_to_columns(go1_log, velocities=False, accelerations=False)
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    assert conv.has_torque and "dynamics" not in conv.terms
    note = [n for n in conv.notes if "second differences of positions" in n]
    assert len(note) == 1 and "dofs [6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17]" in note[0]
    with_qd = log_to_columns(go1_log, accelerations=False)
    assert "dynamics" in to_readings(Recording(with_qd, "r"), go1_log.robot).terms


def test_one_missing_torque_or_velocity_column_is_a_warning_naming_it(go1_log):
    """A helper's audit: one tau/ column named otherwise ('torque/...') or one qd/ column
    missing switched the dynamics term off on all four legs with only a note, the qd/ one
    naming a dof index. With the other joints' columns present it is a warning now, and
    the qd/ note names the column."""
    cols = log_to_columns(go1_log)
    tau = dict(cols)
    tau["torque/FL_thigh_joint"] = tau.pop("tau/FL_thigh_joint")
    conv = to_readings(Recording(tau, "r"), go1_log.robot)
    assert "dynamics" not in conv.terms
    (note,) = [n for n in conv.notes if "no joint torques for" in n]
    assert note.startswith("WARNING no joint torques for ['FL_thigh_joint']: the dynamics")
    assert "though 11 of the 12 actuated joints have a tau/ column" in note
    qd = {k: v for k, v in cols.items() if k not in ("qd/RR_calf_joint", "qdd/RR_calf_joint")}
    conv = to_readings(Recording(qd, "r"), go1_log.robot)
    (note,) = [n for n in conv.notes if "second differences of positions" in n]
    assert note.startswith("WARNING ") and "qd/RR_calf_joint" in note
    # All torques absent (a robot without torque sensing): a note, as before.
    none = {k: v for k, v in cols.items() if not k.startswith("tau/")}
    (note,) = [n for n in to_readings(Recording(none, "r"), go1_log.robot).notes if "torques" in n]
    assert note.startswith("no joint torques for")


def test_without_base_position_and_velocity_only_the_dynamics_run(go1_log):
    cols = log_to_columns(go1_log)
    for k in [c for c in cols if c.startswith(("base_pos/", "base_linvel/"))]:
        del cols[k]
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    assert conv.terms == ("dynamics",)
    text = "\n".join(conv.notes)
    assert "kinematics term is off" in text and "differential-kinematics term is off" in text
    for k in [c for c in cols if c.startswith("tau/")]:
        del cols[k]
    with pytest.raises(ValueError, match="no measurement term can run"):
        to_readings(Recording(cols, "r"), go1_log.robot)


def test_a_nan_stretch_marks_those_rows_invalid(go1_log):
    cols = log_to_columns(go1_log)
    cols["q/FL_thigh_joint"] = cols["q/FL_thigh_joint"].copy()
    cols["q/FL_thigh_joint"][10:13] = np.nan
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    # Rows 10-12 and row 13, whose velocity difference reaches back to row 12.
    assert np.flatnonzero(~conv.valid[:, 0]).tolist() == [10, 11, 12, 13]
    assert np.isnan(conv.readings["qpos"][10:13, 0, 7 + 4]).all()
    # The note names the rows that hold the NaN and the column (which steps of which foot
    # the estimator then predicts only is said after it runs: predicted_only).
    lost = [n for n in conv.notes if n.startswith("readings with NaN")]
    assert len(lost) == 1 and "rows 10-12" in lost[0] and "['q/FL_thigh_joint']" in lost[0]


def test_a_leg_column_never_finite_loses_that_foot_only(go1_log):
    """A joint column with no finite row (a dead encoder) used to refuse the recording; each
    foot reads its own leg's joints, so the others are estimated and a warning names the
    foot. A base column never finite still refuses (every foot reads it)."""
    cols = log_to_columns(go1_log)
    cols["q/FL_calf_joint"] = np.full_like(cols["q/FL_calf_joint"], np.nan)
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    warned = [n for n in conv.notes if "never finite" in n]
    assert warned == [
        "WARNING columns ['q/FL_calf_joint'] are never finite: foot FL has no estimate (valid"
        " False on every step, left out of the metrics); the other feet are estimated"
    ]
    assert conv.valid.all() and not [n for n in conv.notes if "ignored" in n]
    cols["base_pos/z"] = np.full_like(cols["base_pos/z"], np.nan)
    with pytest.raises(ValueError, match=r"never finite: \['base_pos/z', 'q/FL_calf_joint'\]"):
        to_readings(Recording(cols, "r"), go1_log.robot)


def test_the_predicted_only_note_names_each_foots_steps():
    from jax_contact.train.recording_estimate import predicted_only

    conv = SimpleNamespace(time=np.arange(1, 21) * 0.01)
    desc = SimpleNamespace(foot_names=("FR", "FL"))
    valid = np.ones((20, 2), bool)
    assert predicted_only(valid, conv, desc) is None
    valid[5:8, 1] = False
    assert predicted_only(valid, conv, desc) == (
        "steps predicted only (valid = False in the output, left out of the metrics): FL rows"
        " 5-7 (0.06-0.08 s)"
    )
    valid[5:8, 0] = False
    assert predicted_only(valid, conv, desc).endswith(": every foot rows 5-7 (0.06-0.08 s)")


def test_angles_outside_the_joint_range_are_flagged_with_the_unit_hint(go1_log):
    """Go1's home pose near its joints' ranges in radians passes quietly; the same log in
    degrees read as radians leaves the hinges' ranges (Go1's calf joint: -2.818 to -0.888
    rad, home -1.8 rad, i.e. -103 in degrees): each such column gets a warning that names
    it, and the suggestion of --units deg comes once, naming the columns beyond 2 pi (a
    helper's trial had it on each of twelve lines). Which columns are outside, and which
    beyond 2 pi, is recomputed here from the columns and the model's ranges."""
    import mujoco

    from jax_contact.train.recording_checks import DEGREES_HINT, RANGE_SHARE, RANGE_SLACK

    cols = log_to_columns(go1_log)
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    assert not [n for n in conv.notes if n.startswith("WARNING")]
    deg = log_to_columns(go1_log, units="deg")
    m = go1_log.robot.mj_model
    notes = to_readings(Recording(deg, "r"), go1_log.robot).notes
    outside, beyond_2pi = [], []
    for j in range(m.njnt):
        if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE or not m.jnt_limited[j]:
            continue
        col = f"q/{mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)}"
        lo, hi = m.jnt_range[j]
        if np.mean((deg[col] < lo - RANGE_SLACK) | (deg[col] > hi + RANGE_SLACK)) > RANGE_SHARE:
            outside.append(col)
            if np.abs(deg[col]).max() > 2 * np.pi:
                beyond_2pi.append(col)
    assert "q/FL_calf_joint" in beyond_2pi and len(beyond_2pi) >= 8  # thighs and calves
    lines = [n for n in notes if "outside the range of joint" in n]
    assert [n.split("'")[1] for n in lines] == outside
    calf = next(n for n in lines if "'q/FL_calf_joint'" in n)
    assert "100% of rows" in calf and "degrees" not in calf
    assert [n for n in notes if "--units deg" in n] == [
        f"WARNING columns {beyond_2pi}: beyond 2 pi, outside their joints' ranges:"
        + DEGREES_HINT.removeprefix(";")
    ]
    # Read as degrees, nothing is outside.
    notes = to_readings(Recording(deg, "r"), go1_log.robot, units="deg").notes
    assert not [n for n in notes if "range" in n]


def test_a_quaternion_in_x_y_z_w_order_warns_with_the_order_hint(go1_log):
    """R[2, 2] = 1 - 2 (x^2 + y^2) is the world z of the base's z axis.

    - The log's own orientations (near Go1's home, the identity): upright, no warning.
    - Upright and yawed a half turn, (w, x, y, z) = (0, 0, 0, 1), written in x, y, z, w
      order: the columns w, x, y, z hold (0, 0, 1, 0), a half turn about y, R[2, 2] = -1 on
      every row: the warning; read back as x, y, z, w the real x, y are columns w, x = 0,
      R[2, 2] = +1: the order hint.
    - Upside down, a half turn about (1, 1, 0) / sqrt(2), (0, s, s, 0) with s = 0.5**0.5,
      in the right order: R[2, 2] = 1 - 2 (s^2 + s^2) = -1: the warning; read as x, y, z,
      w the real x, y are (0, s), R[2, 2] = 1 - 2 s^2 = 0, not upright: no order hint.
    """
    cols = log_to_columns(go1_log)
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    assert not [n for n in conv.notes if "z axis" in n]
    t_len, s = len(cols["time"]), 0.5**0.5

    def warned(w, x, y, z):
        quat = {
            f"base_quat/{c}": np.full(t_len, v) for c, v in zip("wxyz", (w, x, y, z), strict=True)
        }
        notes = to_readings(Recording(dict(cols, **quat), "r"), go1_log.robot).notes
        return [n for n in notes if "z axis" in n]

    yawed = warned(0.0, 0.0, 1.0, 0.0)
    assert len(yawed) == 1 and yawed[0].startswith("WARNING columns ['base_quat/w'")
    assert "points down on 100% of rows" in yawed[0] and "x, y, z, w order" in yawed[0]
    flipped = warned(0.0, s, s, 0.0)
    assert len(flipped) == 1 and "x, y, z, w order" not in flipped[0]


def test_a_joint_velocity_of_another_sign_or_unit_warns():
    """The shipped planar sample (its columns agree: no warning). With qd/hip negated,
    q/hip changes by -1 times qd/hip's integral over 0.1 s windows (the sample's own
    integration error makes it -1.02, hence the two digits checked), and qdd/hip, which
    still belongs to the true velocity, integrates to -1 times qd/hip's change as well;
    qd/knee in degrees per second: 1/57.3 = 0.0175, named as degrees. The rail is a slide
    joint: its velocity in mm/s (x1000) is 'another unit', never degrees."""
    rec = read_recording(CSV)
    robot = load_robot("planar_leg")
    assert not [n for n in to_readings(rec, robot).notes if n.startswith("WARNING")]
    cols = dict(rec.columns)
    cols["qd/hip"] = -cols["qd/hip"]
    cols["qd/knee"] = np.degrees(cols["qd/knee"])
    cols["qd/rail"] = 1000 * cols["qd/rail"]
    warned = {n.split("'")[1]: n for n in to_readings(Recording(cols, "r"), robot).notes
              if n.startswith("WARNING")}  # fmt: skip
    assert re.search(r"'q/hip' changes by -1\.0\d times its integral", warned["qd/hip"])
    assert "the opposite sign" in warned["qd/hip"]
    # A named qd/ is not the reference for its qdd/ (which is right, and would read -1).
    assert not {"qdd/hip", "qdd/knee", "qdd/rail"} & set(warned)
    assert re.search(r"changes by 0\.017\d times", warned["qd/knee"])
    assert "degrees against radians" in warned["qd/knee"]
    assert "another unit" in warned["qd/rail"] and "degrees" not in warned["qd/rail"]
    # The other way (a helper's audit): qd/knee in rad/s read as degrees per second (what
    # --units deg does to a rate recorded in rad/s), 57.3 times too small. Its integral
    # never moved past 0.02 rad, so nothing was judged; q/knee's own change (well above
    # 0.1 rad RMS over 0.1 s on the hop) now is: 57.3 times its integral, named.
    small = dict(rec.columns, **{"qd/knee": np.radians(rec.columns["qd/knee"])})
    warned = {n.split("'")[1]: n for n in to_readings(Recording(small, "r"), robot).notes
              if n.startswith("WARNING")}  # fmt: skip
    assert re.search(r"'q/knee' changes by 5[67]\.\d times its integral", warned["qd/knee"])
    assert "degrees against radians" in warned["qd/knee"]
    zero = dict(rec.columns, **{"qd/knee": np.zeros_like(rec.columns["qd/knee"])})
    warned = [n for n in to_readings(Recording(zero, "r"), robot).notes if "qd/knee" in n]
    assert any("while its derivative's column stays 0" in n for n in warned), warned


def test_a_gyroscope_rate_in_degrees_or_world_axes_warns():
    """A base yawed by 45 degrees rolls about its own x axis at 1 rad/s for 1 s at 400 Hz:
    q(t) = q_yaw(45) q_x(t). In its frame the rate is (1, 0, 0): quiet. In degrees per
    second the base turns by 1/57.3 = 0.0175 times the integral: named as degrees. About
    world axes the rate is R_yaw (1, 0, 0) = (0.707, 0.707, 0): its integral projects on
    the body-frame turn with slope cos 45 = 0.707 (inside [0.5, 2]), but the turn about
    world axes, q_{k+n} q_k^-1, matches it exactly: named as the world frame."""
    from jax_contact.train.recording_checks import angular_velocity_mismatch

    dt, t_len = 0.0025, 400
    t = np.arange(t_len) * dt
    c, s = np.cos(np.pi / 8), np.sin(np.pi / 8)  # half of 45 degrees
    # q_yaw(45) q_x(t) = (c, 0, 0, s) (cos t/2, sin t/2, 0, 0), multiplied out.
    quat = np.stack(
        [c * np.cos(t / 2), c * np.sin(t / 2), s * np.sin(t / 2), s * np.cos(t / 2)], axis=1
    )
    body = np.tile([1.0, 0.0, 0.0], (t_len, 1))
    world = np.tile([0.5**0.5, 0.5**0.5, 0.0], (t_len, 1))
    assert angular_velocity_mismatch(quat, body, dt) is None
    deg = angular_velocity_mismatch(quat, np.degrees(body), dt)
    assert re.search(r"turns by 0\.0175 times the integral", deg)
    assert "convert base_angvel to rad/s (--units deg would read every angle" in deg
    # 57.3 times too small (rad/s read as degrees per second), rolling at 2 rad/s: the
    # integral moves 0.0035 rad over a window, the turn 0.2 rad (> 0.1, CHANGE_MOVES);
    # judged on the turn now, named as degrees.
    u = t  # the same turn at twice the rate: angle 2t, half-angle t
    quat2 = np.stack([c * np.cos(u), c * np.sin(u), s * np.sin(u), s * np.cos(u)], axis=1)
    assert angular_velocity_mismatch(quat2, 2 * body, dt) is None
    small = angular_velocity_mismatch(quat2, np.radians(2 * body), dt)
    assert re.search(r"turns by 57\.\d times the integral", small)
    assert "degrees per second against radians" in small
    still = np.zeros((t_len, 3))
    assert "while base_angvel stays 0" in angular_velocity_mismatch(quat2, still, dt)
    text = angular_velocity_mismatch(quat, world, dt)
    assert text.startswith("base_quat turns as base_angvel says about world axes")


def test_force_truth_says_what_the_threshold_made_of_each_foot(tmp_path, capsys):
    """The planar sample's force/foot column with a 20 N offset (a foot sensor's raw
    reading) is contact on every row at the 1 N default, which the note says (100 %, its
    minimum 20 N); --force-threshold 21 gives back the sample's own truth (its contact/foot
    is its force/foot above 1 N). With both columns the note names contact/ as the truth
    (it is what the metrics score), and warns when the two disagree."""
    rec = read_recording(CSV)
    robot = load_robot("planar_leg")
    plain = to_readings(rec, robot)
    assert "ground truth from contact/ for ['foot']" in plain.notes
    assert not [n for n in plain.notes if "force/ above" in n or "disagree" in n]
    share = np.mean(rec.columns["force/foot"] > 1.0)
    no_flag = {k: v for k, v in rec.columns.items() if k != "contact/foot"}
    forced = to_readings(Recording(no_flag, "r"), robot)
    assert f"contact on foot {share:.0%} (min 0 N)" in "\n".join(forced.notes)
    # A foot that reads air on some rows gets no sensor-offset advice (a user trial found
    # it repeated on every recording with force truth).
    assert "sensor offset" not in "\n".join(forced.notes)
    np.testing.assert_array_equal(forced.truth, plain.truth)
    # A contact/ flag that reads air on every row: the metrics would score it; named.
    zeroed = dict(rec.columns, **{"contact/foot": np.zeros_like(rec.columns["contact/foot"])})
    warned = [n for n in to_readings(Recording(zeroed, "r"), robot).notes if "disagree" in n]
    assert warned == [
        f"WARNING contact/ and force/ (above 1 N) disagree: foot on {share:.0%} of the rows;"
        " the metrics score contact/ (a foot's flag is preferred to its force): check which"
        " column is right, or drop contact/ to score force/"
    ]
    cols = dict(rec.columns)
    del cols["contact/foot"]
    cols["force/foot"] = cols["force/foot"] + 20.0
    assert not [n for n in plain.notes if n.startswith("WARNING")]
    biased = to_readings(Recording(cols, "r"), robot)
    assert biased.truth.all()
    warned = [n for n in biased.notes if n.startswith("WARNING ground truth from force/")]
    assert len(warned) == 1 and "contact on foot 100% (min 20 N)" in warned[0]
    assert "has a sensor offset (--force-threshold)" in warned[0]
    write_recording_csv(tmp_path / "biased.csv", cols)
    args = _parser().parse_args(
        ["estimate", str(tmp_path / "biased.csv"), "--model", "planar_leg", "--out",
         str(tmp_path / "out"), "--no-plots", "--force-threshold", "21"]
    )  # fmt: skip
    args.check(args)
    fixed = to_readings(Recording(cols, "r"), robot, force_threshold=args.force_threshold)
    np.testing.assert_array_equal(fixed.truth, plain.truth)


def test_checks_that_read_a_wrong_quaternion_say_so(go1_log):
    """Go1 held still for 1 s at 400 Hz, its base yawed a half turn and rolling about its
    own x axis at 1 rad/s: q(t) = (0, 0, 0, 1) (cos t/2, sin t/2, 0, 0) = (0, 0, sin t/2,
    cos t/2), upright (R[2, 2] = cos t > 0.5). Written in x, y, z, w order the columns read
    (0, sin t/2, cos t/2, 0): R[2, 2] = -1, the quaternion warning; and its turns are about
    the base's z axis (q0^-1 q1 = (cos d/2, 0, 0, sin d/2)) while the gyroscope's (1, 0, 0)
    integrates about x: slope 0, the gyroscope warning, which names the quaternion's as a
    possible cause. In the right order neither fires."""
    t_len, dt = 400, 0.0025
    t = np.arange(t_len) * dt
    cols = {k: np.full(t_len, v[0]) for k, v in log_to_columns(go1_log).items()}
    cols["time"] = t + dt
    for k in cols:
        if k.startswith(("qd/", "qdd/", "base_linvel/", "base_linacc/", "base_angacc/")):
            cols[k] = np.zeros(t_len)
    cols.update({f"base_angvel/{c}": np.full(t_len, float(c == "x")) for c in "xyz"})
    right = (np.zeros(t_len), np.zeros(t_len), np.sin(t / 2), np.cos(t / 2))
    for order, values in (("wxyz", right), ("xyzw", right[1:] + right[:1])):
        cols.update({f"base_quat/{c}": v for c, v in zip("wxyz", values, strict=True)})
        warned = [
            n for n in to_readings(Recording(cols, "r"), go1_log.robot).notes if n[:7] == "WARNING"
        ]
        if order == "wxyz":
            assert warned == []
        else:
            assert [n.split("'")[1] for n in warned] == ["base_quat/w", "base_angvel/x"]
            assert warned[1].endswith("; or a consequence of the base_quat warning above")


def test_a_base_velocity_in_the_base_frame_warns():
    """A base yawed by a quarter turn walks +x in the world at 0.5 m/s for 1 s at 400 Hz,
    its position read with 1 mm of noise. In the world frame its velocity is (0.5, 0, 0);
    in its own frame (0, -0.5, 0) (R_z(90 deg)^T (0.5, 0, 0)). Over 0.1 s windows the
    world-frame integral misses the displacement by the noise only (~1.4 mm); the body-frame
    one read as world by |(0.05, 0.05)| = 7.1 cm, and rotated back by the noise only: the
    warning, naming both errors. Without a turn (yaw 0) the frames coincide: quiet."""
    from jax_contact.train.recording_checks import velocity_in_base_frame

    dt, t_len = 0.0025, 400
    rng = np.random.default_rng(0)
    t = np.arange(t_len) * dt
    pos = np.stack([0.5 * t, np.zeros(t_len), np.full(t_len, 0.3)], 1)
    pos = pos + rng.normal(0, 1e-3, pos.shape)
    yawed = np.tile([0.5**0.5, 0.0, 0.0, 0.5**0.5], (t_len, 1))  # 90 deg about z
    world = np.tile([0.5, 0.0, 0.0], (t_len, 1))
    body = np.tile([0.0, -0.5, 0.0], (t_len, 1))
    assert velocity_in_base_frame(pos, world, yawed, dt) is None
    text = velocity_in_base_frame(pos, body, yawed, dt)
    assert text.startswith("base_pos moves as base_linvel rotated by base_quat says")
    assert re.search(r"\(median error 0\.\d+ cm per 0\.1 s\).*\(7\.\d cm\)", text)
    upright = np.tile([1.0, 0.0, 0.0, 0.0], (t_len, 1))
    assert velocity_in_base_frame(pos, world, upright, dt) is None
    # A NaN row leaves out the windows over it, and the rest still decide.
    pos[200] = np.nan
    assert "looks like the base frame" in velocity_in_base_frame(pos, body, yawed, dt)


def test_an_accelerometer_reading_as_base_acceleration_warns(go1_log):
    """The log's base acceleration averages ~0 (random, zero mean): quiet. With gravity
    added, as an IMU's specific force at rest reads (0, 0, +9.81): the warning."""
    cols = log_to_columns(go1_log)
    assert not [n for n in to_readings(Recording(cols, "r"), go1_log.robot).notes if "9.81" in n]
    imu = dict(cols, **{"base_linacc/z": cols["base_linacc/z"] + 9.81})
    notes = to_readings(Recording(imu, "r"), go1_log.robot).notes
    warned = [n for n in notes if "base_linacc/z averages" in n]
    assert len(warned) == 1 and warned[0].startswith("WARNING columns ['base_linacc/x'")
    assert "an accelerometer's reading" in warned[0]


def test_a_cut_last_line_is_dropped_with_a_note(go1_log, tmp_path):
    """A logger killed mid-write leaves a last line with fewer fields: it was refused
    (the whole recording lost); now dropped, said in the notes. A short line elsewhere is
    still refused."""
    cols = log_to_columns(go1_log)
    path = write_recording_csv(tmp_path / "r.csv", cols)
    whole = path.read_text()
    lines = whole.splitlines()
    cut = tmp_path / "cut.csv"
    cut.write_text(whole + ",".join(lines[-1].split(",")[:5]))  # 5 fields, no line end
    rec = read_recording(cut)
    assert len(rec) == len(lines) - 1 == len(cols["time"])
    note = f"the last line ({len(lines) + 1}) has 5 of the header's {len(cols)} fields: dropped"
    assert rec.notes[0].startswith(note)
    assert to_readings(rec, go1_log.robot).notes[0].startswith(note)
    middle = tmp_path / "middle.csv"
    middle.write_text("\n".join(lines[:3] + [lines[3][:5]] + lines[4:]) + "\n")
    with pytest.raises(ValueError, match=r"line 4 has \d+ fields; the header has"):
        read_recording(middle)
    # --robot is the same flag as --model (simulate and evaluate call it --robot).
    args = _parser().parse_args(["estimate", str(cut), "--robot", "go1"])
    assert args.model == "go1"


def test_text_in_a_column_the_schema_does_not_read_is_ignored(tmp_path):
    """The docs say columns the schema does not name are ignored; a logger's text column
    ('mode': WALK) aborted the run. Text in a column the schema reads is still refused,
    naming line and column, in a CSV and in an HDF5 file alike."""
    csv_path = tmp_path / "r.csv"
    csv_path.write_text("time,q/FR_hip_joint,mode\n0.0,0.1,WALK\n0.0025,0.2,STAND\n")
    cols = read_recording(csv_path).columns
    np.testing.assert_array_equal(cols["q/FR_hip_joint"], [0.1, 0.2])
    assert np.isnan(cols["mode"]).all()  # to_readings lists it among the ignored columns
    csv_path.write_text("time,q/FR_hip_joint,mode\n0.0,0.1,WALK\n0.0025,oops,STAND\n")
    with pytest.raises(ValueError, match=r"line 3, column 'q/FR_hip_joint': 'oops' is not a"):
        read_recording(csv_path)
    h5_path = tmp_path / "r.h5"
    with h5py.File(h5_path, "w") as f:
        f["time"] = [0.0, 0.0025, 0.005]
        f["q/FR_hip_joint"] = [0.1, 0.2, 0.3]
        f["mode"] = np.array([b"WALK", b"WALK", b"STAND"])
    assert np.isnan(read_recording(h5_path).columns["mode"]).all()
    with h5py.File(h5_path, "a") as f:
        f["tau/FR_hip_joint"] = np.array([b"a", b"b", b"c"])
    with pytest.raises(ValueError, match=r"column 'tau/FR_hip_joint' is not numeric"):
        read_recording(h5_path)


def test_a_torque_no_actuator_can_apply_is_named(go1_log):
    """A helper's trial: a 1e6 N m torque on one row (a glitch) passed without a word. It
    is a note naming the column and row; on many rows (another unit) a warning. Go1's calf
    actuators are limited to 35.55 N m (forcerange in its MJCF, gear 1), Spot's joints by
    their actuatorfrcrange."""
    from jax_contact.train.recording_checks import joint_torque_limit

    m = go1_log.robot.mj_model
    calf = mujoco_joint(m, "RL_calf_joint")
    assert joint_torque_limit(m, calf) == pytest.approx(35.55)
    spot = load_robot("spot").mj_model
    j = 1 + next(i for i in range(spot.njnt - 1) if spot.jnt_actfrclimited[i + 1])
    assert joint_torque_limit(spot, j) == pytest.approx(np.abs(spot.jnt_actfrcrange[j]).max())
    cols = log_to_columns(go1_log)
    assert not [n for n in to_readings(Recording(cols, "r"), go1_log.robot).notes if "x the" in n]
    glitch = dict(cols)
    glitch["tau/RL_calf_joint"] = cols["tau/RL_calf_joint"].copy()
    glitch["tau/RL_calf_joint"][7] = 1e6
    notes = [n for n in to_readings(Recording(glitch, "r"), go1_log.robot).notes if "x the" in n]
    assert notes == [
        "column 'tau/RL_calf_joint': beyond 2 x the model's actuator limit of its joint (35.55)"
        " on 1 row(s) (first at row 7, 0-based; largest 1e+06): a glitch (the estimator bounds its"
        " effect)"
    ]
    unit = dict(cols, **{"tau/RL_calf_joint": cols["tau/RL_calf_joint"] * 1000 + 100})
    notes = [n for n in to_readings(Recording(unit, "r"), go1_log.robot).notes if "x the" in n]
    assert len(notes) == 1 and notes[0].startswith("WARNING column 'tau/RL_calf_joint'")
    assert notes[0].endswith("another unit or sensor?")


def mujoco_joint(m, name: str) -> int:
    import mujoco

    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)


def test_a_floor_not_at_z_0_or_another_robots_model_warns(go1_log):
    """A helper's trial: a base_pos whose frame starts at the base (z - 0.28 m), or has
    its floor 30 cm lower, and a Go1 recording read with Spot's model gave plausible,
    wrong numbers without a word (the kinematics term neutral or 'air' on every row)."""
    import mujoco

    from jax_contact.train.recording_checks import FLOOR_OFFSET_M, floor_offset

    robot = go1_log.robot
    m, desc = robot.mj_model, robot.description
    home = np.tile(robot.home_qpos, (20, 1))
    # The reference: MuJoCo's own foot geom positions at the home pose, minus the radius.
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home_qpos
    mujoco.mj_kinematics(m, d)
    sole = d.geom_xpos[list(desc.foot_geom_ids), 2] - m.geom_size[list(desc.foot_geom_ids), 0]
    assert np.all(np.abs(sole) < FLOOR_OFFSET_M)  # standing on the floor: no warning
    assert floor_offset(m, desc, home) is None
    for shift, where in ((-0.28, "below"), (0.30, "above")):
        moved = home.copy()
        moved[:, 2] += shift
        got = floor_offset(m, desc, moved)
        cm = round(abs(float(np.median(sole)) + shift) * 100)
        assert got.startswith(f"WARNING the feet's soles sit {cm} cm {where} z = 0"), got
        assert "--terrain-model memory" in got and desc.foot_names[0] in got
    # NaN rows are left out, not read as a floor.
    with_nan = home.copy()
    with_nan[::2] = np.nan
    assert floor_offset(m, desc, with_nan) is None


def test_a_floor_that_drifts_over_the_recording_is_a_note(go1_log):
    """base_pos drifting upward linearly by 6 cm over the recording (a state estimator's
    drift) moves every sole by the same amount. By hand: the first fifth of the rows holds
    0 .. 0.2 of the ramp and the last 0.8 .. 1, and the lowest tenth of each is its first
    tenth, so the two heights differ by 0.8 x 6 = 4.8 cm. 2 cm of drift is no note."""
    from jax_contact.train.recording_checks import FLOOR_DRIFT_M, floor_offset

    robot = go1_log.robot
    m, desc = robot.mj_model, robot.description
    home = np.tile(robot.home_qpos, (500, 1))
    for drift in (0.06, 0.02):
        moved = home.copy()
        moved[:, 2] += np.linspace(0.0, drift, len(moved))
        got = floor_offset(m, desc, moved)
        if drift <= FLOOR_DRIFT_M:
            assert got is None, got
            continue
        cm = float(re.search(r"move by \+([0-9.]+) cm", got).group(1))
        assert cm == pytest.approx(100 * drift * 0.8, abs=0.3), got
        assert "--terrain-model memory" in got and not got.startswith("WARNING")


def test_a_joint_the_model_lacks_is_dropped_by_mapping_it_to_nothing(go1_log):
    """A recording with a column for a joint the model does not have (a gripper) is refused
    naming it; mapped to "" its columns are dropped with a note and the readings equal the
    recording's without them."""
    cols = log_to_columns(go1_log)
    plain = to_readings(Recording(cols, "r"), go1_log.robot)
    extra = dict(cols, **{"q/gripper": np.ones(len(cols["time"])), "tau/gripper": cols["time"]})
    with pytest.raises(ValueError, match=r"column 'q/gripper'.*--names gripper="):
        to_readings(Recording(extra, "r"), go1_log.robot)
    conv = to_readings(Recording(extra, "r"), go1_log.robot, names={"gripper": ""})
    for key in ("qpos", "qvel", "qacc", "tau"):
        np.testing.assert_array_equal(conv.readings[key], plain.readings[key], err_msg=key)
    assert "columns dropped by the names map: ['q/gripper', 'tau/gripper']" in conv.notes
    from jax_contact.train.estimate_cmd import parse_names

    assert parse_names("gripper=,FL=front_left") == {"gripper": "", "FL": "front_left"}
    # An inline map longer than a file name may be (12 joints) is a map, not a path.
    long = ",".join(f"joint_number_{i:02d}_of_the_robot=model_joint_{i:02d}" for i in range(12))
    assert len(long) > 255 and len(parse_names(long)) == 12


# --------------------------------------------------------------------------- bad input


def _planar_cols():
    t = (np.arange(10) + 1) * 0.0025
    cols = {"time": t}
    for j in ("rail", "hip", "knee"):
        cols[f"q/{j}"] = np.linspace(0.1, 0.2, 10)
    for j in ("hip", "knee"):
        cols[f"tau/{j}"] = np.ones(10)
    return cols


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda c: c.pop("q/knee"), r"missing column 'q/knee' \(position of joint 'knee'\)"),
        (lambda c: c.update({"q/ankle": c["q/hip"]}), r"column 'q/ankle': the model has no joint"),
        (lambda c: c["time"].__setitem__(5, c["time"][3]), r"'time' does not increase at row 5"),
        (
            lambda c: c["time"].__setitem__(5, c["time"][4]),
            r"does not increase at row 5 .*a repeated row \(drop duplicates\)\?",
        ),
        # Epoch seconds stored as float32 (steps of 128 s at 1.7e9 s): nearly every row
        # repeats; "drop duplicates" would have deleted them (a helper's audit).
        (
            lambda c: c.update({"time": np.float32(1.7e9) + np.float32(c["time"])}),
            r"does not increase at row 1 .*100% of the rows repeat .*float32 epoch seconds",
        ),
        (
            lambda c: c.update({"time": c["time"] * 1e9}),
            r"'time' steps by 2\.5e\+06 \(median\): time must be in seconds.*nanoseconds",
        ),
        (lambda c: c["time"].__setitem__(5, c["time"][5] + 0.001), r"irregular time steps"),
        (lambda c: c.update({"contact/heel": np.ones(10)}), r"column 'contact/heel': .*no foot"),
        (
            lambda c: c.update({"q/hip": np.full(10, np.nan)}),
            r"no row has every column the estimator reads finite.*never finite: \['q/hip'\]",
        ),
    ],
)
def test_bad_input_is_one_line_naming_it(change, match):
    cols = _planar_cols()
    cols["time"] = cols["time"].copy()
    change(cols)
    with pytest.raises(ValueError, match=match) as err:
        to_readings(Recording(cols, "rec.csv"), load_robot("planar_leg"))
    assert "\n" not in str(err.value) and "rec.csv" in str(err.value)


def test_two_columns_named_onto_one_joint_are_refused():
    """A helper's audit: ``--names knee_copy=knee`` beside a ``q/knee`` column replaced the
    real column by the copy (the later one won), calling q/knee 'not in the schema'."""
    cols = _planar_cols()
    cols["q/knee_copy"] = cols["q/knee"] + 1.0
    with pytest.raises(ValueError, match=r"columns 'q/knee' and 'q/knee_copy' both give q/knee"):
        to_readings(
            Recording(cols, "rec.csv"), load_robot("planar_leg"), names={"knee_copy": "knee"}
        )


def test_irregular_steps_are_resampled_by_the_stated_rule():
    cols = _planar_cols()
    # Samples at 0.0025 s steps but one missing (row 5): the grid keeps the median step.
    keep = np.arange(10) != 5
    rec = Recording({k: v[keep] for k, v in cols.items()}, "r")
    conv = to_readings(rec, load_robot("planar_leg"), resample=True)
    np.testing.assert_allclose(conv.time, cols["time"])
    # Linear columns are interpolated exactly; the gap is 2 dt wide, within 1.5 dt of samples.
    np.testing.assert_allclose(conv.readings["qpos"][:, 0, 1], cols["q/hip"], atol=1e-12)
    assert any("resampled" in n for n in conv.notes)


def test_resampling_keeps_the_contact_on_its_own_rows():
    """A held column (contact) changes on the grid row of the sample where it changes: the
    grid ``t_0 + k dt`` differs from the recorded times by rounding, which must not move
    the truth one row late (that shortened every measured delay by dt)."""
    # Times as a CSV holds them (0.0025, 0.005, ...): over 800 rows the median step is
    # 0.0024999999999999467 s and the grid falls below the samples from row 1 on.
    n = 800
    t = np.round((np.arange(n) + 1) * 0.0025, 6)
    contact = ((np.arange(n) // 37) % 2).astype(float)  # changes every 37 rows
    cols = {"time": t.copy(), "q/rail": np.linspace(0.3, 0.4, n), "contact/foot": contact}
    for j in ("hip", "knee"):
        cols[f"q/{j}"] = np.linspace(0.1, 0.2, n)
        cols[f"tau/{j}"] = np.ones(n)
    cols["time"][200] += 0.001  # one irregular step: resampled
    conv = to_readings(Recording(cols, "r"), load_robot("planar_leg"), resample=True)
    # Grid row k is the sample at t[k] (row 200 holds sample 199's contact, which is the
    # same: 200 is not a change row).
    np.testing.assert_array_equal(conv.truth[:, 0, 0], contact)


def test_a_simulate_log_given_as_a_recording_says_which_command_reads_it():
    with pytest.raises(ValueError, match=r"is a log of `jax-contact simulate`.*evaluate"):
        read_recording(LOG)


def test_a_csv_with_a_byte_order_mark_reads_and_other_separators_are_named(tmp_path):
    """A spreadsheet's "CSV UTF-8" starts with a byte-order mark, which read as text made
    the first column '\\ufefftime' ("missing column 'time'"): it reads as the plain file.
    A header of one field holding ';' or a tab (another separator) says so."""
    cols = _planar_cols()
    plain = write_recording_csv(tmp_path / "plain.csv", cols)
    text = plain.read_text()
    (tmp_path / "bom.csv").write_text(text, encoding="utf-8-sig")
    assert (tmp_path / "bom.csv").read_bytes()[:3] == b"\xef\xbb\xbf"
    got, want = read_recording(tmp_path / "bom.csv"), read_recording(plain)
    assert list(got.columns) == list(want.columns)
    for k in want.columns:
        np.testing.assert_array_equal(got.columns[k], want.columns[k])
    for sep in (";", "\t"):
        (tmp_path / "sep.csv").write_text(text.replace(",", sep))
        with pytest.raises(
            ValueError, match="sep.csv': the header is one field holding " + re.escape(repr(sep))
        ):
            read_recording(tmp_path / "sep.csv")
    # A binary file named .csv and a Latin-1 export (a helper's audit: "'utf-8' codec
    # can't decode byte ...", naming no file among several); a CSV named .npz ("allow_pickle").
    (tmp_path / "latin.csv").write_bytes("time,temp \u00b0C\n0,1\n".encode("latin-1"))
    (tmp_path / "h5.csv").write_bytes(LOG.read_bytes())
    for name in ("latin.csv", "h5.csv"):
        with pytest.raises(ValueError, match=rf"recording '.*{name}' is not UTF-8 text \(byte"):
            read_recording(tmp_path / name)
    (tmp_path / "csv.npz").write_text(text)
    with pytest.raises(ValueError, match=r"'.*csv.npz' is not an NPZ archive"):
        read_recording(tmp_path / "csv.npz")
    # A matrix of every joint's positions: the layout expected is said.
    np.savez(tmp_path / "matrix.npz", time=cols["time"], q=np.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"column 'q' has shape \(10, 3\); expected \(N,\): one"):
        read_recording(tmp_path / "matrix.npz")


def test_an_estimate_output_given_as_input_is_named(round_trip, tmp_path):
    """``estimate.h5`` / ``estimate.csv`` given back to ``estimate`` (or ``deploy-check``)
    was "column 'p_contact' has shape (T, L)"; to ``evaluate`` or ``tune``, "no attribute
    'robot'". Both now say what the file is."""
    from jax_contact.train.logs import load_log

    out = round_trip.tmp / "out"
    with pytest.raises(ValueError, match=r"is an output of `jax-contact estimate`"):
        read_recording(out / "estimate.h5")
    table = read_recording(out / "estimate.csv")  # a table of columns, as any CSV
    with pytest.raises(ValueError, match=r"is an output of `jax-contact estimate`"):
        to_readings(table, load_robot("planar_leg"))
    with pytest.raises(ValueError, match=r"output of `jax-contact estimate` .*not a log of"):
        load_log(out / "estimate.h5")


def test_a_names_entry_for_a_column_the_recording_lacks_is_refused():
    """A typo in the map (a joint's recording name that no column has) is named, where it
    used to be ignored; a foot's entry may be unused (no ground truth, no foot column)."""
    cols = _planar_cols()
    with pytest.raises(ValueError, match=r"names map: \['hipp'\] name no column"):
        to_readings(Recording(cols, "rec.csv"), load_robot("planar_leg"), names={"hipp": "hip"})
    conv = to_readings(Recording(cols, "rec.csv"), load_robot("planar_leg"), names={"toe": "foot"})
    assert conv.truth is None


def test_names_map_to_a_missing_joint_is_refused():
    with pytest.raises(ValueError, match=r"names map: 'HIP' -> 'hips'"):
        to_readings(Recording(_planar_cols(), "r"), load_robot("planar_leg"), names={"HIP": "hips"})


def test_arguments_are_checked_without_jax(tmp_path):
    code = (
        "import sys, jax_contact.train.estimate_cmd;"
        " print([m for m in ('jax', 'numpy', 'mujoco', 'h5py') if m in sys.modules])"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0 and res.stdout.strip() == "[]", res.stderr
    p = _parser()
    bad = [
        (["estimate", str(tmp_path / "no.csv"), "--model", "go1"], "does not exist"),
        (["estimate", str(LOG.with_suffix(".py")), "--model", "go1"], "does not exist"),
        (["estimate", str(CSV), "--model", "dog"], "unknown robot 'dog'"),
        (["estimate", str(CSV), "--model", "go1", "--names", "a=b,c"], "'c' is not log_name"),
        (["estimate", str(CSV), "--model", "go1", "--params", "nope.json"], "--params"),
        (
            ["estimate", str(CSV), "--model", "go1", "--params", "go2"],
            r"--params: 'go2' is neither a file nor a shipped preset"
            r" \(barkour, barkour_trot, barkour_walk, go1, go1_playground, go1_walk, spot,"
            r" spot_walk\)",
        ),
    ]
    for argv, match in bad:
        args = p.parse_args(argv)
        with pytest.raises(ValueError, match=match):
            args.check(args)
    # A shipped preset's name is taken where a parameter file is (jc.load_params takes both).
    args = p.parse_args(["estimate", str(CSV), "--model", "go1", "--params", "go1"])
    args.check(args)
    (tmp_path / "map.json").write_text(json.dumps({"HIP_J": "hip"}))
    assert estimate_cmd.parse_names(str(tmp_path / "map.json")) == {"HIP_J": "hip"}
    assert estimate_cmd.parse_names("a=b, c = d") == {"a": "b", "c": "d"}


def test_robot_flags_map_onto_gait_settings():
    from jax_contact.envs.gaits import GaitSettings, gait_settings

    p = argparse.ArgumentParser()
    estimate_cmd.add_feet_flag(p)
    estimate_cmd.add_gait_flags(p)
    p.add_argument("--gait", default="trot")
    args = p.parse_args(
        ["--feet", "FL", "FR", "--kp", "80", "--home-key", "home", "--speed", "0.1", "0.3"]
    )
    assert args.feet == ["FL", "FR"]
    over = estimate_cmd.gait_overrides(args)
    assert over == {"kp": 80.0, "home_key": "home", "trot_speed": (0.1, 0.3)}
    s = gait_settings("go1", **over)
    assert s == GaitSettings(kp=80.0, kd=1.5, home_key="home", trot_speed=(0.1, 0.3))
    assert estimate_cmd.gait_overrides(p.parse_args([])) == {}
    with pytest.raises(ValueError, match="--kd"):
        estimate_cmd.gait_overrides(p.parse_args(["--kd", "-1"]))
    with pytest.raises(ValueError, match="'hop' gait has no speed"):
        estimate_cmd.gait_overrides(p.parse_args(["--gait", "hop", "--speed", "0", "1"]))


def test_the_commands_copies_equal_the_librarys():
    from jax_contact.train import recording

    assert estimate_cmd.RECORDING_SUFFIXES == recording.SUFFIXES
    assert estimate_cmd.UNITS == recording.UNITS
    assert estimate_cmd.FORCE_THRESHOLD == recording.FORCE_THRESHOLD
    from jax_contact.train import log_estimator

    assert estimate_cmd.TERRAIN_MODELS == log_estimator.TERRAIN_MODELS


def test_terrain_model_reaches_the_replay_of_evaluate_and_estimate(
    planar_log, tmp_path, monkeypatch
):
    """--terrain-model memory: a foothold memory over the same plane, with FOOTHOLD_MEMORY's
    numbers, is what evaluate's and estimate's replay get; flat the plane itself; an unknown
    name is refused naming the argument."""
    import jax_contact as jc
    from jax_contact.train import evaluate, log_estimator, log_evaluate

    desc = planar_log.robot.description
    _, plane = log_estimator.default_estimator(desc, planar_log.dt)
    _, memo = log_estimator.default_estimator(desc, planar_log.dt, "memory")
    assert isinstance(plane, jc.FlatTerrain) and isinstance(memo, jc.FootholdMemory)
    np.testing.assert_allclose(
        [memo.fallback.height, memo.fallback.sigma], [plane.height, plane.sigma]
    )
    np.testing.assert_allclose(
        [memo.sigma_foothold, memo.growth, memo.smoothing], [0.02, 0.3, 0.05], rtol=1e-6
    )
    with pytest.raises(ValueError, match="terrain_model must be one of"):
        log_estimator.default_estimator(desc, planar_log.dt, "rough")

    seen = []

    class Stop(Exception):
        pass

    def fake_replay(*args, terrain, **kwargs):
        seen.append(terrain)
        raise Stop

    monkeypatch.setattr(evaluate, "replay", fake_replay)
    args = _parser().parse_args(["estimate", "r.csv", "--model", "m.xml", "--out", "o"])
    assert args.terrain_model is None  # the --params file's own, else flat
    with pytest.raises(Stop):
        log_evaluate.evaluate_file(LOG, terrain_model="memory")
    cols = log_to_columns(planar_log, names=RENAME, units="rad")
    write_recording_csv(tmp_path / "r.csv", cols)
    with pytest.raises(Stop):
        _estimate(
            tmp_path / "r.csv", tmp_path / "out", names=AS_RECORDED["names"], terrain_model="memory"
        )
    assert [type(t).__name__ for t in seen] == ["FootholdMemory", "FootholdMemory"]


def test_a_params_file_runs_on_the_terrain_model_it_was_tuned_with(tmp_path, monkeypatch):
    """A file whose provenance says ``terrain_model: memory`` (``jax-contact tune
    --terrain-model memory``) is replayed on the foothold memory unless the user names a
    terrain model; a file that does not say, and no file, on the plane; a provenance naming
    an unknown model is refused naming the file and the field."""
    import jax_contact as jc
    from jax_contact.train import evaluate, log_estimator, log_evaluate

    desc = load_robot("planar_leg").description
    params, _ = log_estimator.default_estimator(desc, 0.0025)
    jc.save_params(tmp_path / "mem.json", params, {"terrain_model": "memory"})
    jc.save_params(tmp_path / "old.json", params, {"tool": "before the option"})
    # Edited by hand after writing (save_params refuses to write an unknown model).
    bad = json.loads(jc.save_params(tmp_path / "bad.json", params).read_text())
    bad["provenance"] = {"terrain_model": "stairs"}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert log_estimator.file_terrain_model(tmp_path / "mem.json") == "memory"
    assert log_estimator.file_terrain_model(tmp_path / "old.json") is None
    assert log_estimator.resolve_terrain_model(None, None) == "flat"
    assert log_estimator.resolve_terrain_model("flat", tmp_path / "mem.json") == "flat"
    with pytest.raises(ValueError, match=r"bad\.json.*'terrain_model'.*'stairs'"):
        log_estimator.resolve_terrain_model(None, tmp_path / "bad.json")

    seen = []

    class Stop(Exception):
        pass

    def fake_replay(*args, terrain, **kwargs):
        seen.append(type(terrain).__name__)
        raise Stop

    monkeypatch.setattr(evaluate, "replay", fake_replay)
    for path, model in [("mem.json", None), ("mem.json", "flat"), ("old.json", None)]:
        with pytest.raises(Stop):
            log_evaluate.evaluate_file(LOG, params_path=tmp_path / path, terrain_model=model)
    assert seen == ["FootholdMemory", "FlatTerrain", "FlatTerrain"]

    # Parameters, terrain model, calibration map and the recorded hash come from one read
    # of the file: here the file is replaced as soon as it is read (another run writing
    # it), and the record still names the bytes that were parsed (it hashed a second
    # read before the forty-sixth session).
    import jax_contact.params_file as jc_io

    reads = []
    read_bytes = jc_io._params_bytes
    original = (tmp_path / "mem.json").read_bytes()

    def read_then_replace(p):
        reads.append(p)
        out = read_bytes(p)
        Path(p).write_text((tmp_path / "old.json").read_text())
        return out

    monkeypatch.setattr(jc_io, "_params_bytes", read_then_replace)
    got, model, terrain, calibration, record = log_estimator.estimator_for(
        desc, 0.0025, tmp_path / "mem.json", None
    )
    assert (model, type(terrain).__name__, calibration) == ("memory", "FootholdMemory", None)
    assert len(reads) == 1
    assert float(got.stance_time) == float(params.stance_time)
    assert record["source"] == "file" and record["path"] == str((tmp_path / "mem.json").resolve())
    assert record["sha256"] == hashlib.sha256(original).hexdigest()
    assert record["file_provenance"] == json.loads(original)["provenance"]


def test_estimate_reports_p_through_the_files_calibration_map(round_trip, tmp_path, capsys):
    """``estimate --params`` with a file that holds a calibration map writes P through the
    map: sigmoid(logit(P_raw) / T_c) where P_raw > 0.5, / T_a elsewhere, computed here by
    hand from the round trip's raw P (the file holds the defaults, so the recursion is the
    same), and records the map in the HDF5 attributes."""
    import jax_contact as jc
    from jax_contact.train import log_estimator

    desc = load_robot("planar_leg").description
    params, _ = log_estimator.default_estimator(desc, 0.0025)
    cal = jc.Calibration(temperature=1.5, temperature_air=3.0)
    jc.save_params(tmp_path / "cal.json", params, {"calibration": cal.as_dict()})
    args = _parser().parse_args(
        ["estimate", str(CSV), "--model", "planar_leg", "--out", str(tmp_path / "o")]
        + ["--no-plots", "--params", str(tmp_path / "cal.json")]
    )
    args.check(args)
    assert args.func(args) == 0
    assert "calibration map (T 1.500 for P > 0.5, 3.000 for P < 0.5)" in capsys.readouterr().out
    raw = np.clip(
        round_trip.evaluated["outputs"]["probabilistic"][:, 0, 0].astype(float),
        np.finfo(np.float32).tiny,  # float32's P keeps its logit down to -87
        1 - 1e-7,
    )
    logit = np.log(raw / (1 - raw))
    want = 1 / (1 + np.exp(-np.where(logit > 0, logit / 1.5, logit / 3.0)))
    got = read_recording(tmp_path / "o" / "estimate.csv").columns["p_contact/foot"]
    np.testing.assert_allclose(got, want, atol=2e-5)
    assert np.mean(np.abs(got - raw)) > 0.01  # the map moved P
    np.testing.assert_array_equal(got > 0.5, raw > 0.5)  # and kept every decision
    with h5py.File(tmp_path / "o" / "estimate.h5", "r") as f:
        assert json.loads(f.attrs["calibration"]) == cal.as_dict()


def test_evaluate_adds_the_calibrated_row_of_a_file_with_a_calibration_map(tmp_path, capsys):
    """A params file holding a calibration map (``jax-contact tune --calibrate``) gets a
    ``probabilistic+cal`` row: P mapped by ``sigmoid(logit(P) / T + c)`` after the
    recursion, scored like any detector. Its ECE and flags are recomputed here from the
    raw row's P by hand (NumPy, T = 2, c = 0.7); the raw row is the same as without a
    map, and a file without one adds no row."""
    import jax_contact as jc
    from jax_contact.metrics import expected_calibration_error, step_scores
    from jax_contact.train import log_estimator, log_evaluate, logs

    desc = load_robot("planar_leg").description
    params, _ = log_estimator.default_estimator(desc, 0.0025)
    jc.save_params(
        tmp_path / "cal.json", params, {"calibration": {"temperature": 2.0, "bias": 0.7}}
    )
    jc.save_params(tmp_path / "plain.json", params, {"tool": "no map"})
    got = log_evaluate.evaluate_file(LOG, params_path=tmp_path / "cal.json")
    plain = log_evaluate.evaluate_file(LOG, params_path=tmp_path / "plain.json")
    assert "probabilistic+cal" in got["scores"] and "probabilistic+cal" not in plain["scores"]
    assert "probabilistic+cal" in capsys.readouterr().out  # printed in the table
    assert got["scores"]["probabilistic"] == plain["scores"]["probabilistic"]
    # The file holds the defaults, so the defaults row that a file adds scores the same. The
    # two run as lanes of one vmap (train/evaluate.py, _groups), which XLA may round apart
    # in the last bit (P within 1e-12 absolute; 3 of 800 steps differed by 5e-14 once).
    out = got["outputs"]
    np.testing.assert_allclose(out["defaults"], out["probabilistic"], rtol=0, atol=1e-12)
    want = got["scores"]["probabilistic"]
    assert set(got["scores"]["defaults"]) == set(want)
    for key, value in got["scores"]["defaults"].items():
        assert value == (want[key] if value is None else pytest.approx(want[key], abs=1e-9)), key
    with pytest.raises(ValueError, match="needs at least 2"):  # the fixture has one env
        log_evaluate.evaluate_file(LOG, bootstrap=10)

    log = logs.load_log(LOG)
    # The float32 P keeps its logit down to -87 (its smallest normal); above 1 - 6e-8 it is 1.
    p = np.asarray(got["outputs"]["probabilistic"], np.float64)
    p = np.clip(p, np.finfo(np.float32).tiny, 1 - 1e-7)
    by_hand = 1.0 / (1.0 + np.exp(-(np.log(p / (1.0 - p)) / 2.0 + 0.7)))
    np.testing.assert_allclose(got["outputs"]["probabilistic+cal"], by_hand, rtol=1e-12)
    valid = np.broadcast_to(np.asarray(log.valid)[..., None], p.shape)
    cal = got["scores"]["probabilistic+cal"]
    assert cal["ece"] == pytest.approx(expected_calibration_error(by_hand, log.truth, valid))
    flags = step_scores(by_hand, log.truth, valid)
    assert cal["f1"] == pytest.approx(flags.f1) and cal["accuracy"] == pytest.approx(flags.accuracy)
    # The map moves P: a bias of +0.7 calls more steps contact than the raw row does.
    assert np.mean(by_hand[valid] > 0.5) > np.mean(p[valid] > 0.5)


def test_a_params_file_is_checked_against_the_robot_and_rate(tmp_path):
    import jax_contact as jc
    from jax_contact.train.log_estimator import default_estimator, load_params_for

    desc = load_robot("planar_leg").description
    params, _ = default_estimator(desc, 0.005)
    jc.save_params(tmp_path / "p.json", params.replace(cap_dynamics=np.float32(0.95)))
    with pytest.warns(UserWarning, match="dt = 0.005 s; the log's is 0.0025 s"):
        got = load_params_for(tmp_path / "p.json", desc, 0.0025)
    assert float(got.cap_dynamics) == pytest.approx(0.95) and float(got.dt) == pytest.approx(0.0025)
    # Moved to 400 Hz as the rules move their own (jax_contact.defaults.change_period): a
    # file equal to the defaults at 200 Hz in a derived value becomes the defaults at
    # 400 Hz there (the joints' differenced acceleration noise sqrt(2) sigma_qd / dt
    # doubles, the rail's measured 2 m/s^2 does not, the still-side cap's log-odds halve);
    # what the file changed (cap_dynamics, not a function of dt) is kept.
    at_400, _ = default_estimator(desc, 0.0025)
    np.testing.assert_allclose(got.noise.sigma_qdd, at_400.noise.sigma_qdd, rtol=1e-6)
    np.testing.assert_allclose(got.noise.sigma_qdd[0], params.noise.sigma_qdd[0], rtol=1e-6)
    np.testing.assert_allclose(got.noise.sigma_qdd[1:], 2 * params.noise.sigma_qdd[1:], rtol=1e-6)
    lo = np.log(
        float(params.cap_diff_kinematics_still) / (1 - float(params.cap_diff_kinematics_still))
    )
    assert float(got.cap_diff_kinematics_still) == pytest.approx(
        1 / (1 + np.exp(-lo / 2)), rel=1e-6
    )
    assert float(got.cap_diff_kinematics_still) == pytest.approx(
        float(at_400.cap_diff_kinematics_still), rel=1e-6
    )
    np.testing.assert_allclose(got.noise.sigma_d, params.noise.sigma_d)  # no function of dt
    # A tuned factor is kept: x3 on the acceleration noise at 200 Hz is x3 at 400 Hz.
    from jax_contact.defaults import change_period

    tuned = params.replace(noise=params.noise.replace(sigma_qdd=3 * params.noise.sigma_qdd))
    moved = change_period(tuned, params, at_400)
    np.testing.assert_allclose(moved.noise.sigma_qdd, 3 * at_400.noise.sigma_qdd, rtol=1e-6)
    go1 = load_robot("go1").description
    with pytest.raises(ValueError, match="nv = 3; the robot has nv = 18"):
        load_params_for(tmp_path / "p.json", go1, 0.0025)


def test_another_robots_file_warns_by_its_mass():
    import warnings

    import jax_contact as jc
    from jax_contact.params_file import MASS_RATIO_WARN, load_params_for
    from jax_contact.robot import model_mass

    go1, spot = load_robot("go1").mj_model, load_robot("spot").mj_model
    # The masses by hand from the MJCF's <inertial> elements: Go1's trunk 5.204 kg + four
    # legs of 0.68 + 1.009 + 0.196 kg (hip, thigh, calf with foot) = 12.74 kg.
    assert model_mass(go1) == pytest.approx(5.204 + 4 * (0.68 + 1.009 + 0.196), abs=0.01)
    for name, model in (("go1", go1), ("spot", spot)):  # the presets record their robot's
        _, prov = jc.load_params(name, with_provenance=True)
        assert prov["robot_mass_kg"] == pytest.approx(model_mass(model))
    # Spot's file on Go1 (50.3 kg against 12.7 kg, both nv 18) warns, naming both.
    with pytest.warns(UserWarning, match=r"tuned on a robot of 50.3 kg \('spot'\); this one"
                      r" weighs 12.7 kg"):  # fmt: skip
        load_params_for("spot", nv=18, dt=0.0025, mass_kg=model_mass(go1))
    # Go1's own file, Go1's with a payload inside the factor, or no mass given: silent.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_params_for("go1", nv=18, dt=0.0025, mass_kg=model_mass(go1))
        load_params_for("go1", nv=18, dt=0.0025, mass_kg=model_mass(go1) * 0.98 * MASS_RATIO_WARN)
        load_params_for("spot", nv=18, dt=0.0025)
        # Named robots: the file's own, or a path (an MJCF of unknown name): silent.
        load_params_for("go1", nv=18, dt=0.0025, robot="go1", mass_kg=model_mass(go1))
        load_params_for("go1", nv=18, dt=0.0025, robot="/robots/go1.xml")
    # Go1's file on Barkour (11.5 kg: inside the factor) was silent; it is named.
    barkour = model_mass(load_robot("barkour").mj_model)
    with pytest.warns(UserWarning, match=r"'go1' was tuned on robot 'go1'; this one is 'barkour'"):
        load_params_for("go1", nv=18, dt=0.0025, robot="barkour", mass_kg=barkour)
    # Where the masses differ too, one warning: the mass's.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_params_for("spot", nv=18, dt=0.0025, robot="go1", mass_kg=model_mass(go1))
    assert len(caught) == 1 and "tuned on a robot of 50.3 kg" in str(caught[0].message)
    # Go1's file on a biped of the same nv (two legs of six joints, Berkeley Humanoid's
    # layout) of about the same mass was silent: its per-joint noise landed on other joints.
    from jax_contact.tune.space import robot_space

    base = {"base_linear": [0, 1, 2], "base_rotational": [3, 4, 5]}
    quadruped = {**base, **{f"joint{j}": [6 + j, 9 + j, 12 + j, 15 + j] for j in range(3)}}
    biped = {**base, **{f"joint{j}": [6 + j, 12 + j] for j in range(6)}}
    assert robot_space(load_robot("go1").description).named_groups() == quadruped
    with pytest.warns(UserWarning, match=r"coordinates group as .*joint0 \[6, 9, 12, 15\].*"
                      r" this one's are .*joint0 \[6, 12\]"):  # fmt: skip
        load_params_for("go1", nv=18, dt=0.0025, groups=biped, mass_kg=16.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_params_for("go1", nv=18, dt=0.0025, groups=quadruped, mass_kg=model_mass(go1))


def test_differentiated_coordinates_get_the_differences_noise(go1_log):
    from jax_contact.train.log_estimator import default_estimator
    from jax_contact.train.recording_convert import noise_for_differences

    cols = log_to_columns(go1_log, velocities=False, accelerations=False)
    for k in [c for c in cols if c.startswith("base_linvel/")]:
        del cols[k]
    conv = to_readings(Recording(cols, "r"), go1_log.robot)
    assert conv.velocity_from_position == tuple(range(3)) + tuple(range(6, 18))
    assert conv.acceleration_from_position == tuple(range(3)) + tuple(range(6, 18))
    params, _ = default_estimator(go1_log.robot.description, conv.dt)
    got = noise_for_differences(params, conv).noise
    n, dt = params.noise, conv.dt
    sq, sqd, sqdd = (np.asarray(x, np.float64) for x in (n.sigma_q, n.sigma_qd, n.sigma_qdd))
    # Hand formula: var of x_k - x_{k-1} is 2 sigma_q^2; of x_k - 2 x_{k-1} + x_{k-2}, 6.
    d = np.r_[0:3, 6:18]
    want_qd, want_qdd = sqd.copy(), sqdd.copy()
    want_qd[d] = np.hypot(sqd[d], np.sqrt(2) * sq[d] / dt)
    want_qdd[d] = np.hypot(sqdd[d], np.sqrt(6) * sq[d] / dt**2)
    np.testing.assert_allclose(got.sigma_qd, want_qd, rtol=1e-6)
    np.testing.assert_allclose(got.sigma_qdd, want_qdd, rtol=1e-6)
    np.testing.assert_array_equal(got.sigma_qd[3:6], n.sigma_qd[3:6])  # gyro measured


def test_bad_input_through_the_command_is_one_line(tmp_path, capsys):
    cols = _planar_cols()
    del cols["q/knee"]
    write_recording_csv(tmp_path / "rec.csv", cols)
    argv = [str(tmp_path / "rec.csv"), "--model", "planar_leg", "--out", str(tmp_path / "o")]
    assert estimate_cmd.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jax-contact estimate: error: recording")
    assert "missing column 'q/knee'" in err[0] and "rec.csv" in err[0]
    assert not (tmp_path / "o").exists()  # nothing written


def test_a_simulated_barkour_log_stores_feet_its_robot_resolves(tmp_path, monkeypatch):
    # Barkour's foot geoms have no names; the simulated world (with its ground-truth geoms)
    # calls them gt_foot<i>, which the nominal robot that load_log loads does not have. The
    # log must store the nominal robot's names. The simulation itself is replaced (no
    # compile): only the attributes written are checked.
    import types

    from jax_contact.envs import simulate as sim
    from jax_contact.envs.robots import load_robot
    from jax_contact.train import logs

    written = {}
    fake = types.SimpleNamespace(
        qpos=np.zeros((3, 1, 19)), valid=np.ones((3, 1), bool), to_arrays=lambda: {}
    )
    monkeypatch.setattr(sim, "simulate", lambda *a, **k: fake)
    monkeypatch.setattr(logs, "write_log", lambda path, arrays, attrs: written.update(attrs))
    logs.simulate_to_file(tmp_path / "b.h5", robot="barkour", n_envs=1, duration=0.01)
    feet = written["foot_names"]
    assert not any(f.startswith("gt_foot") for f in feet), feet
    assert load_robot("barkour", foot_names=feet).description.foot_names == tuple(feet)
    assert len(feet) == 4


def _split(round_trip, tmp_path, rows: int, drop: str | None = None):
    """The round trip's recording cut after ``rows`` rows into two files of unequal
    length, ``drop`` (a column) left out of the second."""
    cols = dict(read_recording(round_trip.tmp / "robot.csv").columns)
    first, second = tmp_path / "first.csv", tmp_path / "second.csv"
    write_recording_csv(first, {k: v[:rows] for k, v in cols.items()})
    write_recording_csv(second, {k: v[rows:] for k, v in cols.items() if k != drop})
    return str(first), str(second)


def test_several_recordings_are_estimated_each_and_their_metrics_pooled(round_trip, tmp_path):
    """``estimate A B``: each recording's folder holds what ``estimate A`` alone writes, and
    the pooled metrics treat each recording as one sequence. Reference, by hand: no event
    crosses from one recording into the other, so every count of the pooled row is the sum
    of the recordings' counts, the accuracy their step-weighted mean and the touch-down
    delay's mean the mean of theirs weighted by their matched touch-downs."""
    first, second = _split(round_trip, tmp_path, 480)  # 1.2 s and 0.8 s
    out = tmp_path / "out"
    argv = [first, second, "--model", "planar_leg", "--names", NAMES_INLINE, "--units", "deg"]
    assert estimate_cmd.main([*argv, "--out", str(out), "--no-plots"]) == 0
    alone = _estimate(first, tmp_path / "alone", plots=False, **AS_RECORDED)
    got = read_recording(out / "first" / "estimate.csv").columns["p_contact/foot"]
    np.testing.assert_allclose(got, alone["outputs"]["probabilistic"][:, 0, 0], atol=1e-6)
    each = [json.loads((out / s / "metrics.json").read_text()) for s in ("first", "second")]
    pooled = json.loads((out / "pooled_metrics.json").read_text())
    assert pooled["per_recording"] == {"first": each[0], "second": each[1]}
    assert pooled["recordings"]["second"] == {"path": second, "pooled": True}
    assert (pooled["model"], pooled["rate_hz"]) == ("planar_leg", pytest.approx(400.0))
    assert set(pooled["pooled"]) == {"probabilistic", "gm", "kinematic"}
    for row, m in pooled["pooled"].items():
        a, b = each[0][row], each[1][row]
        assert a["n_steps"] == 480 and b["n_steps"] == 320
        for key in ("n_steps", "failures", "n_air_phases", "air_phases_with_failure",
                    "n_touchdowns", "missed", "touchdown_already_on", "n_liftoffs",
                    "missed_liftoffs"):  # fmt: skip
            assert m[key] == a[key] + b[key], (row, key)
        assert m["accuracy"] == pytest.approx((480 * a["accuracy"] + 320 * b["accuracy"]) / 800)
        matched = [x["n_touchdowns"] - x["missed"] - x["touchdown_already_on"] for x in (a, b)]
        assert min(matched) > 0, row
        mean = matched[0] * a["touchdown_delay_ms"][0] + matched[1] * b["touchdown_delay_ms"][0]
        assert m["touchdown_delay_ms"][0] == pytest.approx(mean / sum(matched), rel=1e-9)


def test_several_recordings_are_all_read_before_any_is_estimated(round_trip, tmp_path, capsys):
    """A column missing from the second recording is refused, naming it, before the first
    one's folder is written; two recordings of one name are refused before any work."""
    first, second = _split(round_trip, tmp_path, 480, drop="q/KNEE_J")
    out = tmp_path / "out"
    argv = [first, second, "--model", "planar_leg", "--names", NAMES_INLINE, "--units", "deg"]
    assert estimate_cmd.main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "second.csv" in err and "missing column 'q/KNEE_J'" in err, err
    assert not out.exists()
    (tmp_path / "again").mkdir()
    twin = str(tmp_path / "again" / "first.csv")
    Path(twin).write_bytes(Path(first).read_bytes())
    # A copy is one recording twice (pooled, its envs would count twice).
    assert estimate_cmd.main([first, twin, "--model", "planar_leg", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"argument recording: {twin!r} holds the same bytes as {first!r}" in err, err
    Path(twin).write_bytes(Path(first).read_bytes() + b"\n")  # another recording, one name
    assert estimate_cmd.main([first, twin, "--model", "planar_leg", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{first!r} and {twin!r} would both write to the folder 'first'" in err, err
    assert estimate_cmd.main([first, first, "--model", "planar_leg", "--out", str(out)]) == 2
    assert f"argument recording: {first!r} is given twice" in capsys.readouterr().err


def test_recordings_at_another_rate_are_estimated_and_left_out_of_the_pool(
    round_trip, tmp_path, capsys
):
    """A recording at another rate (every other row: 200 Hz) is estimated, named before
    the work, and left out of the pool, which holds the two 400 Hz ones; a run that pools
    nothing leaves no earlier run's pooled file behind (it would describe folders this
    run rewrote)."""
    first, second = _split(round_trip, tmp_path, 480)
    cols = dict(read_recording(round_trip.tmp / "robot.csv").columns)
    slow = str(tmp_path / "slow.csv")
    write_recording_csv(slow, {k: v[::2] for k, v in cols.items()})
    out = tmp_path / "out"
    out.mkdir()
    (out / "pooled_metrics.json").write_text('{"recordings": "an earlier run"}')
    flags = ["--model", "planar_leg", "--names", NAMES_INLINE, "--units", "deg", "--no-plots"]
    assert estimate_cmd.main([first, slow, second, *flags, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "note: 'slow' is estimated but not pooled: at 200 Hz, the pooled ones at 400 Hz" in text
    pooled = json.loads((out / "pooled_metrics.json").read_text())
    assert set(pooled["per_recording"]) == {"first", "second"}
    assert pooled["recordings"]["slow"]["pooled"] is False
    assert pooled["pooled"]["probabilistic"]["n_steps"] == 800
    assert (
        json.loads((out / "slow" / "metrics.json").read_text())["probabilistic"]["n_steps"] == 400
    )
    assert estimate_cmd.main([first, slow, *flags, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "removed the earlier run's" in text and "no pooled metrics" in text
    assert not (out / "pooled_metrics.json").exists()


def test_pooling_takes_the_largest_set_of_recordings_at_one_rate():
    """By hand: two recordings at 400 Hz (one off by 1e-5, inside the 0.1 % tolerance) and
    two at 200 Hz tie; the set of the earliest recording is pooled and the rest named; one
    recording per rate pools nothing."""
    from jax_contact.train.recording_batch import pool_groups

    dts = {"a": 0.0025, "b": 0.005, "c": 0.0025 * (1 + 1e-5), "d": None, "e": 0.005}
    pooled, why = pool_groups(dts)
    assert pooled == ["a", "c"]
    at_200 = "at 200 Hz, the pooled ones at 400 Hz"
    assert why == {"d": "no ground truth", "b": at_200, "e": at_200}
    pooled, why = pool_groups({"a": 0.0025, "b": 0.005, "d": None})
    assert pooled == [] and set(why) == {"a", "b", "d"}
