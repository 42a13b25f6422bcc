"""The paired env bootstrap (jax_contact.bootstrap) against hand-derived intervals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jax_contact.bootstrap import MIN_ENVS, STATISTICS, Difference, paired_bootstrap, verdicts

T, DT = 60, 0.0025


def _always_on_truth(n_envs: int) -> np.ndarray:
    return np.ones((T, n_envs, 1), bool)


def _wrong_steps(counts) -> np.ndarray:
    """P(contact) that is right (1) everywhere except ``counts[i]`` steps of env i (0)."""
    p = np.ones((T, len(counts), 1))
    for i, n in enumerate(counts):
        p[:n, i, 0] = 0.0
    return p


def _gait_like(rng, n_envs: int, n_legs: int = 2):
    """Truth of square-wave phases (random period and offset per sequence), a P(contact)
    that follows it late with noise and blips, and validity with a gap in one env."""
    t = np.arange(T * 4)[:, None, None]
    period = rng.integers(20, 40, (1, n_envs, n_legs))
    truth = ((t + rng.integers(0, 40, (1, n_envs, n_legs))) % period) < period * 0.6
    late = np.roll(truth, 2, axis=0)
    p = np.clip(0.85 * late + 0.1 + rng.normal(0.0, 0.15, truth.shape), 0.0, 1.0)
    p[rng.random(truth.shape) < 0.02] = 0.97  # blips: false contacts in the air
    valid = np.ones(truth.shape[:2], bool)
    valid[50:70, 1] = False
    return truth, p, valid


def test_env_sums_pool_to_evaluate_on_the_resampled_envs():
    """Each pooled metric of a multiset of envs, from the per-env sums, equals
    ``metrics.evaluate`` on the batch of those envs (an env drawn twice appears twice)."""
    from jax_contact.metrics import env_sums, evaluate

    rng = np.random.default_rng(4)
    truth, p, valid = _gait_like(rng, 5)
    # A flag stuck on through the first half of two sequences' swings (rule 9c), so that
    # sw-on differs between envs and its pooling is tested on more than zeros.
    half = np.arange(len(p)) < len(p) // 2
    for env, leg in ((2, 0), (4, 1)):
        p[half, env, leg] = 0.9
    valid3 = np.broadcast_to(valid[..., None], truth.shape)
    # bounce_s 30 ms = 12 steps: the air phases of 8-12 steps (periods 20-30) are left out
    # of the swing phases, so the swing rate is a different ratio from the air rate.
    for bounce_s in (0.01, 0.03):
        sums = env_sums(p, truth, valid3, dt=DT, bounce_s=bounce_s)
        for idx in ([0, 1, 2, 3, 4], [1, 1, 3, 0, 0], [4, 4, 4, 2, 1], [2, 2, 2, 2, 2]):
            want = evaluate(
                np.take(p, idx, 1), np.take(truth, idx, 1), np.take(valid3, idx, 1), dt=DT,
                bounce_s=bounce_s,
            )  # fmt: skip
            got = sums.pooled(np.bincount(idx, minlength=5))
            assert want.n_air_phases > 0 and np.isfinite(want.touchdown_delay_ms[0])
            for key in (
                "f1",
                "accuracy",
                "air_phase_failure_rate",
                "swing_phase_failure_rate",
                "swing_phase_flag_on_rate",
                "ece",
            ):
                assert got[key] == pytest.approx(getattr(want, key), rel=1e-12, abs=1e-15), key
            for key in ("touchdown_delay_ms", "liftoff_delay_ms"):
                assert got[key] == pytest.approx(getattr(want, key)[0], rel=1e-12), key
        assert np.isnan(sums.pooled(np.zeros(5))["f1"])  # no step: 0 / 0, as evaluate's NaN
        # Weights are counts: a negative one gave F1 1.013 and a negative failure rate, a
        # wrong length NumPy's matmul error (a helper's audit).
        with pytest.raises(ValueError, match=r"weights must be finite and >= 0"):
            sums.pooled(np.array([1.0, -1.0, 1.0, 1.0, 1.0]))
        with pytest.raises(ValueError, match=r"weights must have shape \(\.\.\., 5\).*\(4,\)"):
            sums.pooled(np.ones(4))
    every = evaluate(p, truth, valid3, dt=DT, bounce_s=0.03)
    assert 0 < every.n_swing_phases < every.n_air_phases
    assert 0 < every.swing_phases_flag_on < every.n_swing_phases  # rule 9c pooled non-trivially
    assert every.swing_phase_failure_rate != every.air_phase_failure_rate


def test_identical_detectors_differ_by_exactly_nothing():
    rng = np.random.default_rng(3)
    truth = rng.random((T, 4, 2)) < 0.6
    p = np.clip(truth + rng.normal(0.0, 0.3, truth.shape), 0.0, 1.0)
    out = paired_bootstrap(p, p, truth, dt=DT, n_resamples=50)
    for name, d in out.items():
        if np.isfinite(d.reference):
            assert d.delta == 0.0 and d.low == 0.0 and d.high == 0.0, name
            # 4 envs are too few for a verdict; the interval itself reads within noise.
            assert d.verdict == "too few envs", name
            assert dataclasses.replace(d, n_envs=None).verdict == "within noise", name


# t_2(0.95) (scipy.stats.t.ppf(0.95, 2)): the 90 % interval's quantile for 3 envs.
T2_95 = 2.9199855803537242


@pytest.mark.parametrize(
    "counts, delta_m, verdict",
    [
        # Envs wrong on (0, 0, 3m) steps: a resample holds env 3 c ~ Binomial(3, 1/3) times,
        # so the accuracy difference is -m c / T, delta (c = 1) -m / T. The bootstrap's sd
        # is m / T sqrt(2/3) (Var c = 3 (1/3)(2/3)), and the half-width
        # t_2(0.95) sqrt(3/2) sd = t_2(0.95) m / T: [-3.92, 1.92] m / T, within noise.
        ((0, 0, 3), -3.0, "within noise"),
        # Envs wrong on (2m, 2m, 3m): the difference is -m (2 (3 - c) + 3c) / (3T) =
        # -m (6 + c) / (3T), delta -7m / (3T), half-width t_2(0.95) m / (3T):
        # [-9.92, -4.08] m / (3T), worse.
        ((2, 2, 3), -7.0, "worse"),
    ],
)
def test_accuracy_interval_matches_the_binomial_derivation(counts, delta_m, verdict):
    m = 5
    truth = _always_on_truth(3)
    reference = _wrong_steps((0, 0, 0))
    candidate = _wrong_steps([m * c for c in counts])
    out = paired_bootstrap(
        reference, candidate, truth, dt=DT, statistics=("accuracy",), n_resamples=20000,
        level=0.9, seed=1,
    )  # fmt: skip
    d = out["accuracy"]
    assert d.reference == 1.0
    assert d.delta == pytest.approx(delta_m * m / (3 * T))
    half = T2_95 * m / (T if counts[0] == 0 else 3 * T)
    # The bootstrap's sd from 20000 resamples: within 2 % of the binomial one.
    assert (d.low, d.high) == pytest.approx((d.delta - half, d.delta + half), rel=2e-2)
    # Three envs (10 distinct resamples) get no verdict from the table; the interval's own
    # reading is the derivation's.
    assert d.verdict == "too few envs" and verdicts(out) == {"better": [], "worse": []}
    d = dataclasses.replace(d, n_envs=None)
    assert d.verdict == verdict
    assert verdicts({"accuracy": d}) == {
        "better": [],
        "worse": ["accuracy"] if verdict == "worse" else [],
    }


def test_the_half_width_is_students_with_the_bootstrap_variance_unbiased():
    from jax_contact.bootstrap import student_half_width

    # t_15(0.975) = 2.131450 (tables) times sqrt(16 / 15) = 1.032796: 2.201354.
    assert student_half_width(0.95, 16) == pytest.approx(2.131450 * 1.032796, rel=1e-6)
    assert student_half_width(0.9, 3) == pytest.approx(T2_95 * (1.5**0.5), rel=1e-12)
    with pytest.raises(ValueError, match="n_envs must be an integer >= 2, got 1"):
        student_half_width(0.95, 1)


def test_swapping_the_detectors_mirrors_the_interval_and_the_verdict():
    truth = _always_on_truth(3)
    # Wrong on (10, 10, 15) steps: the difference -(30 + 5c) / (3T), delta -35 / (3T),
    # half-width t_2(0.95) 5 / (3T) = 14.6 / (3T): worse one way, better the other.
    a, b = _wrong_steps((0, 0, 0)), _wrong_steps((10, 10, 15))
    kw = dict(dt=DT, statistics=("accuracy",), n_resamples=500, level=0.9, seed=7)
    ab = paired_bootstrap(a, b, truth, **kw)["accuracy"]
    ba = paired_bootstrap(b, a, truth, **kw)["accuracy"]
    assert (ba.low, ba.high) == pytest.approx((-ab.high, -ab.low))
    assert (ab.verdict, ba.verdict) == ("too few envs", "too few envs")  # 3 envs
    ab, ba = (dataclasses.replace(d, n_envs=None) for d in (ab, ba))
    assert (ab.verdict, ba.verdict) == ("worse", "better")


def test_lower_is_better_statistics_read_the_other_way():
    worse_ece = Difference(0.02, 0.03, 0.004, 0.016, higher_is_better=False)
    better_ece = Difference(0.03, 0.02, -0.016, -0.004, higher_is_better=False)
    noise = Difference(0.02, 0.021, -0.002, 0.004, higher_is_better=False)
    assert (worse_ece.verdict, better_ece.verdict, noise.verdict) == (
        "worse",
        "better",
        "within noise",
    )
    assert Difference(0.0, np.nan, np.nan, np.nan, True).verdict == "n/a"
    # The same intervals from fewer than MIN_ENVS envs: no call either way.
    for n, want in ((MIN_ENVS - 1, "too few envs"), (MIN_ENVS, "worse")):
        assert dataclasses.replace(worse_ece, n_envs=n).verdict == want


def test_few_envs_get_no_verdict_from_a_real_bootstrap():
    """A 2-env log drew 'better' on an interval of [-0.20, -0.20] (a user trial): 2 envs
    have 3 distinct resamples. The same detectors on 8 envs are called."""
    truth8 = _always_on_truth(8)
    a8, b8 = _wrong_steps((0,) * 8), _wrong_steps((5,) * 8)
    kw = dict(dt=DT, statistics=("accuracy",), n_resamples=200, seed=3)
    assert paired_bootstrap(a8, b8, truth8, **kw)["accuracy"].verdict == "worse"
    two = paired_bootstrap(a8[:, :2], b8[:, :2], truth8[:, :2], **kw)["accuracy"]
    assert two.high < 0.0 and two.verdict == "too few envs"
    # Printed without that interval, saying why; 8 envs' with it.
    from jax_contact.bootstrap import format_intervals

    assert format_intervals({"accuracy": two.as_list()}) == (
        f"acc {two.delta:+.4f} (no interval: fewer than 5 envs to resample)"
    )
    d8 = paired_bootstrap(a8, b8, truth8, **kw)["accuracy"]
    assert format_intervals({"accuracy": d8.as_list(), "f1": [0.5, 0.25, 0.75, "better"]}) == (
        f"acc {d8.delta:+.4f} [{d8.low:+.4f}, {d8.high:+.4f}] worse;"
        " F1 +0.5000 [+0.2500, +0.7500] better"
    )


def test_same_seed_same_interval_and_a_t_e_validity_broadcasts():
    rng = np.random.default_rng(0)
    truth = rng.random((T, 5, 2)) < 0.5
    a = np.clip(truth + rng.normal(0.0, 0.4, truth.shape), 0.0, 1.0)
    b = np.clip(truth + rng.normal(0.0, 0.4, truth.shape), 0.0, 1.0)
    valid = np.ones((T, 5), bool)
    valid[:10, 2] = False
    kw = dict(dt=DT, statistics=("f1", "ece"), n_resamples=40, seed=11)
    one = paired_bootstrap(a, b, truth, valid, **kw)
    two = paired_bootstrap(a, b, truth, np.broadcast_to(valid[..., None], truth.shape), **kw)
    assert one == two


def test_bad_inputs_name_the_argument():
    truth = _always_on_truth(3)
    p = _wrong_steps((0, 0, 0))
    with pytest.raises(ValueError, match="candidate has shape"):
        paired_bootstrap(p, p[:, :2], truth, dt=DT)
    with pytest.raises(ValueError, match="at least 2 envs"):
        paired_bootstrap(p[:, :1], p[:, :1], truth[:, :1], dt=DT)
    with pytest.raises(ValueError, match="statistics: unknown"):
        paired_bootstrap(p, p, truth, dt=DT, statistics=("f2",))
    with pytest.raises(ValueError, match="level"):
        paired_bootstrap(p, p, truth, dt=DT, level=1.0)
    with pytest.raises(ValueError, match="n_resamples"):
        paired_bootstrap(p, p, truth, dt=DT, n_resamples=0)
    with pytest.raises(ValueError, match="valid has shape"):
        paired_bootstrap(p, p, truth, np.ones((T, 2), bool), dt=DT)
    # Raised by NumPy before, naming nothing (a helper's audit): an OverflowError, a
    # "non-negative integer" of the generator, a str comparison.
    with pytest.raises(ValueError, match=r"n_resamples must be an integer >= 1, got inf"):
        paired_bootstrap(p, p, truth, dt=DT, n_resamples=float("inf"))
    with pytest.raises(ValueError, match=r"seed must be an integer >= 0, got -1"):
        paired_bootstrap(p, p, truth, dt=DT, seed=-1)
    # Which detector holds the NaN (both said "estimate holds ...").
    nan = p.copy()
    nan[5, 1] = np.nan
    with pytest.raises(ValueError, match=r"^candidate holds NaN or inf"):
        paired_bootstrap(p, nan, truth, dt=DT)
    with pytest.raises(ValueError, match=r"^reference holds NaN or inf"):
        paired_bootstrap(nan, p, truth, dt=DT)
    with pytest.raises(ValueError, match=r"level must be a number in \(0, 1\), got '0.9'"):
        paired_bootstrap(p, p, truth, dt=DT, level="0.9")


def test_comparison_table_names_the_cells_beyond_noise():
    from jax_contact.train.tune_presets import format_comparison

    row = {
        "f1": 0.98, "accuracy": 0.97, "air_phase_failure_rate": 0.02, "ece": 0.02,
        "touchdown_delay_ms": [7.0, 3.0], "liftoff_delay_ms": [4.0, 2.0],
    }  # fmt: skip
    vs = {
        "f1": [0.004, 0.001, 0.007, "better"],
        "touchdown_delay_ms": [0.5, 0.1, 0.9, "worse"],
        "ece": [0.001, -0.002, 0.003, "within noise"],
    }
    table = format_comparison({"trot": {"default": row, "tuned": {**row, "vs_reference": vs}}})
    lines = table.splitlines()
    assert lines[0].endswith("| vs reference (95 %, env bootstrap) |")
    assert lines[2].endswith("| reference |") and lines[3].endswith("| better F1; worse TD |")
    quiet = {**row, "vs_reference": {"ece": vs["ece"]}}
    assert format_comparison({"trot": {"a": row, "b": quiet}}).endswith("| within noise |")
    assert "vs reference" not in format_comparison({"trot": {"default": row}})


def _detectors(rng, rows: dict) -> tuple[np.ndarray, dict]:
    """(T, 4, 2) random truth and one output per row: the first row a probability (truth
    plus Gaussian noise of that std, clipped), every other row flags with that share of
    steps flipped."""
    truth = rng.random((T, 4, 2)) < 0.5
    (first, std), *flags = rows.items()
    out = {first: np.clip(truth + rng.normal(0.0, std, truth.shape), 0.0, 1.0)}
    for name, share in flags:
        out[name] = truth ^ (rng.random(truth.shape) < share)
    return truth, out


def test_reproduce_compares_the_estimator_with_both_gm_tunings():
    from jax_contact.metrics import evaluate
    from jax_contact.train import report

    rng = np.random.default_rng(5)
    truth, out = _detectors(rng, {"probabilistic": 0.3, "gm_walk": 0.2, "gm_trot": 0.05})
    valid = np.ones((T, 4), bool)
    assert report.vs_gm(out, truth, valid, DT, 0) is None
    vs = report.vs_gm(out, truth, valid, DT, 30)
    est = evaluate(out["probabilistic"], truth, dt=DT)
    for gm in ("gm_walk", "gm_trot"):
        ref = evaluate(out[gm], truth, dt=DT)
        delta, low, high, _ = vs[gm]["f1"]
        assert delta == pytest.approx(est.f1 - ref.f1) and low <= high
        assert set(vs[gm]) == set(report.VS_GM_STATISTICS)
    assert set(vs) == {"gm_walk", "gm_trot"}
    text = report.format_vs_gm({"vs_gm": {"trot": vs}})
    assert text.count("\n") == 2 and "trot             vs gm_trot" in text
    # A failure-limited GM row (reproduce's *_fl), where the run has one, is compared too.
    with_fl = out | {"gm_trot_fl": out["gm_walk"]}
    vs_fl = report.vs_gm(with_fl, truth, valid, DT, 30)
    assert set(vs_fl) == {"gm_walk", "gm_trot", "gm_trot_fl"}
    assert vs_fl["gm_trot_fl"]["f1"][0] == pytest.approx(vs["gm_walk"]["f1"][0])
    assert report.format_vs_gm({}) == ""
    # The row "tuned" (a preset beside the defaults): against both GM tunings and against
    # the defaults in every statistic, each difference tuned - other.
    out["tuned"] = np.clip(truth + rng.normal(0.0, 0.2, truth.shape), 0.0, 1.0)
    assert report.tuned_vs(out, truth, valid, DT, 0) is None
    tv = report.tuned_vs(out, truth, valid, DT, 30)
    tuned = evaluate(out["tuned"], truth, dt=DT)
    assert set(tv) == {"gm_walk", "gm_trot", "probabilistic"}
    assert tv["gm_trot"]["f1"][0] == pytest.approx(
        tuned.f1 - evaluate(out["gm_trot"], truth, dt=DT).f1
    )
    assert tv["probabilistic"]["ece"][0] == pytest.approx(tuned.ece - est.ece)
    assert set(tv["probabilistic"]) == set(STATISTICS)
    text = report.format_vs_gm({"vs_gm": {"trot": vs}, "tuned_vs": {"trot": tv}})
    assert text.count("\n") == 6 and "tuned - other row" in text
    assert "trot             vs defaults F1 " in text and "; ECE " in text.splitlines()[-1]
    assert "; sw-ph " in text.splitlines()[1]  # the swing-phase rate beside air-ph, vs GM too


def test_row_differences_is_paired_bootstrap_per_other_row():
    """The helper behind reproduce's, evaluate's and compare's JSON: for each other row,
    ``row - other`` on its own statistics, exactly paired_bootstrap's as_list."""
    from jax_contact.bootstrap import row_differences

    truth, out = _detectors(np.random.default_rng(11), {"a": 0.3, "b": 0.1, "c": 0.02})
    got = row_differences(out, "a", {"b": ("f1",), "c": ("ece", "accuracy")}, truth, dt=DT,
                          n_resamples=40)  # fmt: skip
    assert list(got) == ["b", "c"] and list(got["c"]) == ["ece", "accuracy"]
    for other, stats in (("b", ("f1",)), ("c", ("ece", "accuracy"))):
        want = paired_bootstrap(out[other], out["a"], truth, dt=DT, statistics=stats,
                                n_resamples=40)  # fmt: skip
        assert got[other] == {k: d.as_list() for k, d in want.items()}
