"""Tests of the evaluation metrics: hand-built sequences and float64 loop oracles."""

from __future__ import annotations

import numpy as np
import pytest

from jax_contact.metrics import (
    bounce_steps,
    brier_score,
    ece_bins,
    evaluate,
    expected_calibration_error,
    match_events,
    step_scores,
)

DT = 0.0025  # 400 Hz; the default 50 ms early window is 20 steps
T = 80


def _seq(on, n=T, lo=0.1, hi=0.9):
    """Probabilities ``lo`` everywhere and ``hi`` on the [start, end) intervals in ``on``."""
    p = np.full(n, lo)
    for a, b in on:
        p[a:b] = hi
    return p


def _truth(on, n=T):
    return _seq(on, n, 0.0, 1.0) > 0.5


# ----------------------------------------------------------------------------- hand cases


def test_delay_and_step_scores_by_hand():
    # Truth on [30, 50), estimate on [33, 52).
    # Touch-down t0 = 30: window from max(30 - 20, 0) = 10 (evaluable: 10 >= 0) to the
    # lift-off at 50; first estimate rise at 33 -> delay 3 * 2.5 ms = 7.5 ms.
    # Lift-off t1 = 50: estimate falls at 52 -> 2 * 2.5 ms = 5 ms.
    # Steps: TP [33, 50) = 17, FP [50, 52) = 2, FN [30, 33) = 3, TN 80 - 22 = 58.
    #   accuracy 75/80, precision 17/19, recall 17/20, F1 = 34 / (34 + 2 + 3) = 34/39.
    # Brier: 75 right steps at (0.1)^2 and 5 wrong at (0.9)^2 -> (0.75 + 4.05) / 80 = 0.06.
    # ECE (10 bins): bin 1 holds p = 0.1 with 58 TN + 3 FN: |3 - 6.1| / 80;
    #   bin 9 holds p = 0.9 with 17 TP + 2 FP: |17 - 17.1| / 80; total 3.2 / 80 = 0.04.
    p, g = _seq([(33, 52)]), _truth([(30, 50)])
    m = evaluate(p, g, dt=DT)
    assert m.touchdown_delay_ms == pytest.approx((7.5, 0.0))
    assert m.liftoff_delay_ms == pytest.approx((5.0, 0.0))
    assert (m.n_touchdowns, m.missed, m.failures, m.chatter) == (1, 0, 0, 0)
    assert (m.n_liftoffs, m.missed_liftoffs, m.false_liftoffs) == (1, 0, 0)
    assert m.accuracy == pytest.approx(75 / 80)
    assert m.precision == pytest.approx(17 / 19)
    assert m.recall == pytest.approx(17 / 20)
    assert m.f1 == pytest.approx(34 / 39)
    assert m.brier == pytest.approx(0.06)
    assert m.ece == pytest.approx(0.04)
    assert m.n_steps == T
    d = m.as_dict()
    assert d["touchdown_delay_ms"] == m.touchdown_delay_ms and d["failures"] == 0
    # The same as flags: the probability is 0 / 1, so every wrong step costs 1 in Brier.
    mf = evaluate(p > 0.5, g, dt=DT)
    assert mf.touchdown_delay_ms == m.touchdown_delay_ms
    assert mf.brier == pytest.approx(5 / 80)


def test_blip_in_the_air_is_one_failure_and_chatter_follows_the_debounce():
    # Truth on [30, 50); estimate on [33, 52) and 1-step blips at 60, 62, 64 (air).
    # min_on = 1 (raw flag): every blip is a solid run starting in the air, matched to no
    #   touch-down -> 3 failures, no chatter; the touch-down delay is still 7.5 ms.
    # min_on = 2: the blips are shorter than 2 steps -> 0 failures, 3 chatter; the real
    #   run [33, 52) is 19 steps long, so the delay is unchanged. Off-blips at 61 and 63
    #   start in the air, so they are not false lift-offs either way.
    g = _truth([(30, 50)])
    one = match_events(_seq([(33, 52), (65, 66)]), g, dt=DT)
    assert (one.touchdown.false_edges, one.touchdown.chatter) == (1, 0)
    p = _seq([(33, 52), (60, 61), (62, 63), (64, 65)])
    raw = evaluate(p, g, dt=DT, min_on=1)
    assert (raw.failures, raw.chatter) == (3, 0)
    deb = evaluate(p, g, dt=DT, min_on=2)
    assert (deb.failures, deb.chatter) == (0, 3)
    for m in (raw, deb):
        assert m.touchdown_delay_ms == pytest.approx((7.5, 0.0))
        assert m.liftoff_delay_ms == pytest.approx((5.0, 0.0))
        assert (m.false_liftoffs, m.liftoff_chatter) == (0, 0)


def test_early_detection_already_on_and_missed():
    # (a) Truth on [30, 50), estimate on [26, 50): rises 4 steps early, inside the 20-step
    #     early window -> delay -10 ms, and it is the match, not a failure.
    m = evaluate(_seq([(26, 50)]), _truth([(30, 50)]), dt=DT)
    assert m.touchdown_delay_ms == pytest.approx((-10.0, 0.0))
    assert (m.failures, m.missed, m.touchdown_already_on) == (0, 0, 0)
    # (b) Estimate on [5, 50): on since step 5, before the window start 10, and still on at
    #     t0 = 30 -> "already on": no delay, not missed; the run began in the air -> failure.
    m = evaluate(_seq([(5, 50)]), _truth([(30, 50)]), dt=DT)
    assert m.n_touchdowns == 1 and m.touchdown_already_on == 1
    assert m.missed == 0 and m.failures == 1
    assert np.isnan(m.touchdown_delay_ms[0])
    # (c) Truth on [30, 50) and [70, 78); estimate on [72, 80) only.
    #     Touch-down 30: no rise in [10, 50) -> missed. Its lift-off at 50: the estimate
    #     has been off since the start, before the window [30, 78) -> "already off".
    #     Touch-down 70: window [max(50, 50), 78) -> rise at 72, delay 5 ms.
    #     Lift-off at 78: contact from 70 (window [70, 80)); the estimate stays on to the
    #     end of the data -> no detection and no next true touch-down: not evaluated.
    m = evaluate(_seq([(72, 80)]), _truth([(30, 50), (70, 78)]), dt=DT)
    assert (m.n_touchdowns, m.missed, m.touchdown_already_on) == (2, 1, 0)
    assert m.touchdown_delay_ms == pytest.approx((5.0, 0.0))
    assert (m.n_liftoffs, m.missed_liftoffs, m.liftoff_already_off) == (1, 0, 1)
    # (d) A dropout in stance: truth on [30, 60), estimate on [32, 40) and [45, 62).
    #     The lift-off at 60 has the window [max(60 - 20, 30), 80) = [40, 80). The fall at
    #     40 is inside it but the estimate is back on before the true lift-off (45 < 60),
    #     so it is a false lift-off, not the detection; the fall at 62 is matched: 5 ms.
    #     The touch-down (rise at 32) is 5 ms late.
    p, g = _seq([(32, 40), (45, 62)]), _truth([(30, 60)])
    m = evaluate(p, g, dt=DT)
    assert m.liftoff_delay_ms == pytest.approx((5.0, 0.0)) and m.false_liftoffs == 1
    assert m.touchdown_delay_ms == pytest.approx((5.0, 0.0)) and m.failures == 0
    # (e) The same for touch-downs: truth on [30, 50), estimate on [22, 24) and [33, 52).
    #     The run [22, 24) starts in the early window [10, 50) but ends before t0 = 30: a
    #     false contact in the air (1 failure); the rise at 33 is the match, 7.5 ms.
    m = evaluate(_seq([(22, 24), (33, 52)]), _truth([(30, 50)]), dt=DT)
    assert m.touchdown_delay_ms == pytest.approx((7.5, 0.0)) and m.failures == 1


def test_valid_mask_is_respected():
    g = _truth([(30, 50)])
    p = _seq([(33, 52), (65, 66)])
    valid = np.ones(T, bool)
    # (a) Steps [0, 20) invalid: the air phase before t0 = 30 starts with the valid data at
    #     20, and t0 - 20 = 10 < 20, so the 50 ms early window is not all valid: the
    #     touch-down is not evaluated. A 25 ms window (10 steps) fits: 30 - 10 = 20 -> 7.5 ms.
    v = valid.copy()
    v[:20] = False
    p_nan = p.copy()
    p_nan[:20] = np.nan  # estimates at invalid steps are ignored, NaN included
    m = evaluate(p_nan, g, v, dt=DT)
    assert m.n_touchdowns == 0 and np.isnan(m.touchdown_delay_ms[0])
    m = evaluate(p_nan, g, v, dt=DT, early_window_s=0.025)
    assert m.n_touchdowns == 1 and m.touchdown_delay_ms == pytest.approx((7.5, 0.0))
    assert m.n_steps == 60
    # (b) The blip at 65 is the only failure; masking step 65 removes it, and the step
    #     after the gap is the start of a new valid stretch, not an edge.
    assert evaluate(p, g, dt=DT).failures == 1
    v = valid.copy()
    v[65] = False
    m = evaluate(p, g, v, dt=DT)
    assert m.failures == 0
    # Per-step scores drop step 65 (a false positive): 80 steps had 3 FN + 2 FP + the blip
    # wrong, so 74 of the 79 remaining steps are right.
    assert m.accuracy == pytest.approx(74 / 79) and m.n_steps == 79


def test_batch_pools_events_over_envs_and_legs():
    # (T, E=2, L=2), truth on [30, 50) everywhere; estimates rise at 33, 26, 31 and 34:
    # delays 7.5, -10, 2.5 and 10 ms, plus one blip failure at 70. Mean 2.5 ms,
    # population std sqrt((25 + 156.25 + 0 + 56.25) / 4) = sqrt(59.375) ms.
    g = _truth([(30, 50)])
    est = np.stack(
        [
            np.stack([_seq([(33, 52)]), _seq([(26, 50)])], -1),
            np.stack([_seq([(31, 50)]), _seq([(34, 50), (70, 71)])], -1),
        ],
        1,
    )
    truth = np.broadcast_to(g[:, None, None], est.shape)
    m = evaluate(est, truth, dt=DT)
    assert m.n_touchdowns == 4 and m.failures == 1
    assert m.touchdown_delay_ms == pytest.approx((2.5, np.sqrt(59.375)))
    # The same numbers come back from one sequence per call, pooled by hand.
    delays = []
    for e in range(2):
        for leg in range(2):
            delays.extend(match_events(est[:, e, leg], g, dt=DT).touchdown.delays_ms)
    np.testing.assert_allclose(np.sort(delays), [-10.0, 2.5, 7.5, 10.0])


def test_air_phase_failure_rate_by_hand():
    # (a) Truth on [20, 30) and [45, 55): air phases [0, 20), [30, 45), [55, 80) -> 3,
    #     with 20 + 15 + 25 = 60 air steps. Estimate on [22, 32), [38, 39), [46, 57),
    #     [60, 61) and [63, 65); min_on = 1, early window 20 steps.
    #     Touch-down 20: window [0, 30), the run from 22 is the match (5 ms); touch-down 45:
    #     window [max(25, 30), 55) = [30, 55); the blip [38, 39) is off again before 45, so
    #     the run from 46 is the match (2.5 ms). The runs from 22 and 46 start in stance.
    #     Failures: the blip at 38 (phase 2) and the runs at 60 and 63 (both phase 3) -> 3
    #     failures in 2 of the 3 phases: rate 2/3. Flag on at air steps: 30, 31 (late
    #     lift-off), 38, 55, 56, 60, 63, 64 -> 8 of 60 = 2/15.
    g = _truth([(20, 30), (45, 55)])
    p = _seq([(22, 32), (38, 39), (46, 57), (60, 61), (63, 65)])
    m = evaluate(p, g, dt=DT)
    assert m.touchdown_delay_ms == pytest.approx((3.75, 1.25))
    assert (m.failures, m.n_air_phases, m.air_phases_with_failure) == (3, 3, 2)
    assert m.air_phase_failure_rate == 2 / 3
    assert m.air_false_contact_rate == 8 / 60
    # Flags and probabilities give the same rates. min_on = 2 debounces the 1-step blips
    # at 38 and 60 (chatter, not failures); the 2-step run at 63 stays a failure, so only
    # phase 3 has one: 1/3. The step rate is the raw flag's either way.
    assert evaluate(p > 0.5, g, dt=DT).air_phase_failure_rate == 2 / 3
    deb = evaluate(p, g, dt=DT, min_on=2)
    assert (deb.failures, deb.chatter, deb.air_phases_with_failure) == (1, 2, 1)
    assert deb.air_phase_failure_rate == 1 / 3 and deb.air_false_contact_rate == 8 / 60
    # (b) A solid false run spanning a stance: truth on [40, 50) and [60, 70) (air phases
    #     [0, 40), [50, 60), [70, 80): 40 + 10 + 10 = 60 steps); estimate on [5, 55) and
    #     [62, 72). Touch-down 40: window [20, 50); the flag has been on since 5 < 20 and
    #     stays on past 40 -> already on, and the run [5, 55) began in the air unmatched ->
    #     1 failure, attributed to phase 1 only, although it is still on in phase 2 until
    #     55. Lift-off 50: window [40, 60), the fall at 55 is the match (12.5 ms), so it is
    #     not a missed lift-off. Touch-down 60: window [50, 70), the run from 62 (5 ms);
    #     lift-off 70: the fall at 72 (5 ms) -> lift-off delays (8.75, 3.75) ms.
    #     Rate 1/3; the step rate sees phase 2: air steps on [5, 40), [50, 55), [70, 72)
    #     -> 35 + 5 + 2 = 42 of 60 = 0.7.
    g = _truth([(40, 50), (60, 70)])
    m = evaluate(_seq([(5, 55), (62, 72)]), g, dt=DT)
    assert (m.n_touchdowns, m.touchdown_already_on, m.failures) == (2, 1, 1)
    assert m.touchdown_delay_ms == pytest.approx((5.0, 0.0))
    assert m.liftoff_delay_ms == pytest.approx((8.75, 3.75)) and m.missed_liftoffs == 0
    assert (m.n_air_phases, m.air_phases_with_failure) == (3, 1)
    assert m.air_phase_failure_rate == 1 / 3 and m.air_false_contact_rate == 42 / 60
    # (c) No air phase at all (truth on throughout): both rates are 0 / 0 -> NaN.
    m = evaluate(_seq([(0, T)]), np.ones(T, bool), dt=DT)
    assert m.n_air_phases == 0 and m.air_phases_with_failure == 0
    assert np.isnan(m.air_phase_failure_rate) and np.isnan(m.air_false_contact_rate)


def test_swing_phase_failure_rate_leaves_the_truths_bounces_out():
    # Truth on [10, 30), [32, 50), [70, 80): air phases [0, 10) (10 steps), [30, 32) (2
    # steps: a resting foot's load dropping, a bounce), [50, 70) (20 steps) -> 3. The
    # estimate is on [12, 50) (through the bounce: a missed lift-off, no failure), a blip
    # at [60, 61) (a failure in [50, 70)) and on [72, 80). Rule 9: 1 of 3 phases. Rule 9b
    # (bounce_s 10 ms = 4 steps at 400 Hz): swing phases [0, 10) and [50, 70), 1 of 2.
    g = _truth([(10, 30), (32, 50), (70, 80)])
    p = _seq([(12, 50), (60, 61), (72, 80)])
    m = evaluate(p, g, dt=DT)
    assert (m.failures, m.n_air_phases, m.air_phases_with_failure) == (1, 3, 1)
    assert (m.n_swing_phases, m.swing_phases_with_failure) == (2, 1)
    assert m.air_phase_failure_rate == 1 / 3 and m.swing_phase_failure_rate == 1 / 2
    # bounce_s = 0: every air phase is a swing phase, the two rates agree; 30 ms (12
    # steps) leaves the 10-step phase out too.
    m0 = evaluate(p, g, dt=DT, bounce_s=0.0)
    assert (m0.n_swing_phases, m0.swing_phase_failure_rate) == (3, 1 / 3)
    m30 = evaluate(p, g, dt=DT, bounce_s=0.03)
    assert (m30.n_swing_phases, m30.swing_phase_failure_rate) == (1, 1.0)
    for bad in (-0.01, float("nan"), "x"):
        with pytest.raises(ValueError, match="bounce_s must be a number >= 0"):
            evaluate(p, g, dt=DT, bounce_s=bad)


def test_a_flag_on_through_a_whole_swing_is_counted_by_rule_9c():
    """A helper's fairness audit: stance 40 / swing 40 / stance 40 / swing 40 / stance 40
    steps. Detector A stays on through the first swing (steps [40, 80) all wrong) and is
    right elsewhere: no failure, sw-ph 0, 50 % of the air steps wrong; detector B has one
    3-step blip in the first swing: sw-ph 1/2. Rule 9c counts A's swing, 1 of 2 phases,
    and none of B's (its flag falls)."""
    n = 200
    g = _truth([(0, 40), (80, 120), (160, 200)], n)
    a = evaluate(_seq([(0, 120), (160, 200)], n), g, dt=DT)
    b = evaluate(_seq([(0, 40), (50, 53), (80, 120), (160, 200)], n), g, dt=DT)
    assert (a.failures, a.swing_phase_failure_rate, a.missed_liftoffs) == (0, 0.0, 1)
    assert a.air_false_contact_rate == 0.5
    assert (a.swing_phases_flag_on, a.swing_phase_flag_on_rate) == (1, 0.5)
    assert (b.failures, b.swing_phase_failure_rate) == (1, 0.5)
    assert (b.swing_phases_flag_on, b.swing_phase_flag_on_rate) == (0, 0.0)
    # A bounce the flag stays on through is no swing phase (rule 9b's bounce_s): the
    # earlier test's sequence holds one, [30, 32), and no swing phase the flag holds on.
    m = evaluate(
        _seq([(12, 50), (60, 61), (72, 80)]), _truth([(10, 30), (32, 50), (70, 80)]), dt=DT
    )
    assert (m.n_swing_phases, m.swing_phases_flag_on) == (2, 0)
    assert (
        evaluate(
            _seq([(12, 50), (60, 61), (72, 80)]),
            _truth([(10, 30), (32, 50), (70, 80)]),
            dt=DT,
            bounce_s=0.0,
        ).swing_phases_flag_on
        == 1
    )


def test_evaluates_bounce_note_counts_rule_9bs_bounces_at_any_rate():
    """``evaluate``'s note on a log full of bounces counts the air phases rule 9b leaves
    out (10 ms), in steps of the log's own period: until the thirty-sixth session it
    counted 4 steps at any rate (10 ms only at 400 Hz)."""
    from jax_contact.train.log_evaluate import bounce_note

    # One env, one leg: contact with three 6-step and three 30-step air phases between
    # contact runs; the first and last runs are contact, so all six phases count.
    seq = np.ones(300, bool)
    for start, n in ((20, 6), (50, 6), (80, 6), (120, 30), (170, 30), (220, 30)):
        seq[start : start + n] = False
    truth, valid = seq[:, None, None], np.ones((300, 1), bool)
    # 1 kHz: 10 ms is 10 steps, so the 6-step phases are bounces: 3 of 6.
    note = bounce_note(truth, valid, 0.001)
    assert note.startswith("note: 3 of 6 true air phases last at most 10 steps (10 ms)")
    assert "sw-ph leaves them out" in note
    # 400 Hz: 10 ms is 4 steps, so the same 6-step phases (15 ms) are swings: no note.
    assert bounce_note(truth, valid, 0.0025) is None
    # A quarter or fewer: no note (1 of 4 at 1 kHz once two bounces are filled in).
    seq[50:56] = seq[80:86] = True
    assert bounce_note(seq[:, None, None], valid, 0.001) is None


def test_air_phase_cut_by_an_invalid_step_counts_twice():
    # Truth on [20, 30) and [60, 70); estimate on [22, 32), [45, 46), [50, 51), [62, 72).
    # All valid: air phases [0, 20), [30, 60), [70, 80) -> 3. The blips at 45 and 50 are
    #   2 failures, both in phase 2 -> rate 1/3; flag on at air steps 30, 31, 45, 50, 70,
    #   71 -> 6 of 60 = 0.1.
    # Step 45 invalid (NaN there): stretches [0, 45) and [46, 80). The air phase [30, 60)
    #   is cut into [30, 45) and [46, 60) -> 4 air phases. The blip at 45 is dropped; the
    #   blip at 50 is a failure in [46, 60) (the touch-down at 60 is not evaluated, as its
    #   air phase starts with the stretch at 46 > 60 - 20, but the run from 62 is still
    #   its match) -> 1 failure, 1 of 4 phases. Air steps 20 + 15 + 14 + 10 = 59, flag on
    #   at 30, 31, 50, 70, 71 -> 5 / 59.
    g = _truth([(20, 30), (60, 70)])
    p = _seq([(22, 32), (45, 46), (50, 51), (62, 72)])
    m = evaluate(p, g, dt=DT)
    assert (m.failures, m.n_air_phases, m.air_phases_with_failure) == (2, 3, 1)
    assert m.air_phase_failure_rate == 1 / 3 and m.air_false_contact_rate == 0.1
    valid = np.ones(T, bool)
    valid[45] = False
    p[45] = np.nan
    m = evaluate(p, g, valid, dt=DT)
    assert (m.failures, m.n_air_phases, m.air_phases_with_failure) == (1, 4, 1)
    assert m.n_touchdowns == 1
    assert m.air_phase_failure_rate == 1 / 4 and m.air_false_contact_rate == 5 / 59
    # A flag already on where a stretch starts has no edge, so it is no failure (rule 7),
    # but the step rate counts it: estimate also on [46, 48) -> 7 / 59, phases unchanged.
    p[46:48] = 0.9
    m = evaluate(p, g, valid, dt=DT)
    assert (m.failures, m.air_phases_with_failure) == (1, 1)
    assert m.air_false_contact_rate == 7 / 59


def test_gap_of_known_truth_does_not_cut_an_air_phase():
    """Rules 7b and 8 with ``truth_known``: invalid steps whose truth is known (a lost
    reading in a recording whose truth column is intact) leave the air phase whole, and a
    false contact that rose during them is still a failure."""
    # The case of the test above, step 45 invalid with its truth known (air): the phase
    # [30, 60) stays one phase -> 3 phases, as with every step valid. The blip at 45 is not
    # seen; the blip at 50 (edge at 49) is a failure -> 1 of 3 (the default split: 1 of 4).
    g = _truth([(20, 30), (60, 70)])
    p = _seq([(22, 32), (45, 46), (50, 51), (62, 72)])
    valid = np.ones(T, bool)
    valid[45] = False
    p[45] = np.nan
    known = np.ones(T, bool)
    m = evaluate(p, g, valid, dt=DT, truth_known=known)
    assert (m.failures, m.n_air_phases, m.air_phases_with_failure) == (1, 3, 1)
    assert m.air_phase_failure_rate == 1 / 3 and m.air_false_contact_rate == 5 / 59
    # Rule 7b: the flag also on at [46, 48), off at 44 (the last valid step), truth air
    # and known from 44 through 46: it rose in the gap -> a failure starting at 46 (the
    # default, rule 7 alone: no edge, no failure). Failures 46 and 50, both in phase 2.
    p[46:48] = 0.9
    m = evaluate(p, g, valid, dt=DT, truth_known=known)
    assert (m.failures, m.n_air_phases, m.air_phases_with_failure) == (2, 3, 1)
    assert evaluate(p, g, valid, dt=DT).failures == 1
    # With min_on = 3 the 2-step run after the gap is a blip (chatter), as the one at 50.
    deb = evaluate(p, g, valid, dt=DT, truth_known=known, min_on=3)
    assert (deb.failures, deb.chatter) == (0, 2)
    # On at 44 as well ([43, 45), an edge at 43: a failure of its own): the run after the
    # gap continues it, no second failure -> 43 and 50.
    p[43:45] = 0.9
    m = evaluate(p, g, valid, dt=DT, truth_known=known)
    assert (m.failures, m.air_phases_with_failure) == (2, 1)
    # The truth at 45 unknown: it cuts the phase, and nothing rose in a known air phase
    # -> the default's counts (4 phases; failures 43 and 50).
    known[45] = False
    m = evaluate(p, g, valid, dt=DT, truth_known=known)
    assert (m.failures, m.n_air_phases) == (2, 4)
    d = evaluate(p, g, valid, dt=DT).as_dict()
    assert m.as_dict().keys() == d.keys()
    for k, v in m.as_dict().items():
        np.testing.assert_equal(v, d[k], err_msg=k)
    # Lift-offs (rule 7b on the complements): truth on [10, 70); the flag on [12, 40) and
    # [42, 72), step 40 invalid with known truth (contact): the flag was on at 39 and is
    # off at 41, so it fell in the gap -> a false lift-off at 41; the default has none.
    g = _truth([(10, 70)])
    p = _seq([(12, 40), (42, 72)])
    valid = np.ones(T, bool)
    valid[40] = False
    p[40] = np.nan
    m = evaluate(p, g, valid, dt=DT, truth_known=np.ones(T, bool))
    assert (m.false_liftoffs, evaluate(p, g, valid, dt=DT).false_liftoffs) == (1, 0)
    # A valid step whose truth is not known cannot be scored; shapes must agree.
    with pytest.raises(ValueError, match="truth_known is False at valid steps"):
        evaluate(np.nan_to_num(p, nan=0.1), g, dt=DT, truth_known=valid)
    with pytest.raises(ValueError, match=r"truth_known has shape \(79,\)"):
        evaluate(p, g, valid, dt=DT, truth_known=np.ones(T - 1, bool))


def test_air_phase_rates_pool_over_envs_and_legs():
    # (T, E=2, L=2), one sequence per (env, leg), counts pooled:
    #   [0, 0]: case (a) of the hand test: 3 phases, 2 with a failure, 8 of 60 air steps.
    #   [0, 1]: case (b): 3 phases, 1 with a failure, 42 of 60.
    #   [1, 0]: truth on [30, 50), estimate on [33, 52): phases [0, 30), [50, 80), no
    #           failure, air steps 50, 51 on -> 2 of 60.
    #   [1, 1]: truth off throughout, a blip at 40: 1 phase, 1 failure, 1 of 80.
    # Pooled: 9 phases, 4 with a failure -> 4/9; (8 + 42 + 2 + 1) / 260 = 53/260.
    cases = [
        ([(20, 30), (45, 55)], [(22, 32), (38, 39), (46, 57), (60, 61), (63, 65)]),
        ([(40, 50), (60, 70)], [(5, 55), (62, 72)]),
        ([(30, 50)], [(33, 52)]),
        ([], [(40, 41)]),
    ]
    truth = np.stack([_truth(g) for g, _ in cases], -1).reshape(T, 2, 2)
    est = np.stack([_seq(f) for _, f in cases], -1).reshape(T, 2, 2)
    m = evaluate(est, truth, dt=DT)
    assert (m.n_air_phases, m.air_phases_with_failure, m.failures) == (9, 4, 5)
    assert m.air_phase_failure_rate == 4 / 9
    assert m.air_false_contact_rate == 53 / 260
    # The same counts come back from one sequence per call, added up by hand.
    singles = [evaluate(est[:, e, leg], truth[:, e, leg], dt=DT) for e in (0, 1) for leg in (0, 1)]
    assert [(s.n_air_phases, s.air_phases_with_failure) for s in singles] == [
        (3, 2),
        (3, 1),
        (2, 0),
        (1, 1),
    ]


def test_persistent_delays_by_hand():
    # Truth on [30, 50); estimate on [31, 32), [33, 52) and [53, 56).
    # min_on = 1: the 1-step run at 31 is on at t0 = 30's window and still on after 30,
    #   so it is the touch-down match: 2.5 ms. Lift-off 50: the 1-step fall at 52 is the
    #   match, 5 ms (the fall at 32 is back on before 50: a false lift-off), and the run
    #   [53, 56) that starts in the air is a failure.
    # persist_steps = 3: the runs at 31 and the fall at 52 are blips; the first run of 3
    #   steps is [33, 52) -> 7.5 ms, the first fall of 3 steps is at 56 -> 15 ms.
    # A second sequence, estimate on [33, 52) only, gives 7.5 / 5 ms for both, so the
    # pooled raw touch-down delays are (2.5, 7.5): mean 5, std 2.5; persistent (7.5, 7.5).
    g = _truth([(30, 50)])
    est = np.stack([_seq([(31, 32), (33, 52), (53, 56)]), _seq([(33, 52)])], -1)
    truth = np.stack([g, g], -1)
    m = evaluate(est, truth, dt=DT)
    assert m.touchdown_delay_ms == pytest.approx((5.0, 2.5))
    assert m.touchdown_delay_persist_ms == pytest.approx((7.5, 0.0))
    assert m.liftoff_delay_ms == pytest.approx((5.0, 0.0))
    assert m.liftoff_delay_persist_ms == pytest.approx((10.0, 5.0))
    assert m.failures == 1
    # The persistent numbers are match_events with min_on = persist_steps, and equal the
    # plain delays when the two debounces agree.
    ev = match_events(est, truth, dt=DT, min_on=3)
    assert m.touchdown_delay_persist_ms == pytest.approx(ev.touchdown.delay_mean_std_ms)
    assert m.liftoff_delay_persist_ms == pytest.approx(ev.liftoff.delay_mean_std_ms)
    m2 = evaluate(est, truth, dt=DT, persist_steps=2)
    assert m2.touchdown_delay_persist_ms == pytest.approx((7.5, 0.0))
    m1 = evaluate(est, truth, dt=DT, persist_steps=1)
    assert m1.touchdown_delay_persist_ms == m1.touchdown_delay_ms
    assert m1.liftoff_delay_persist_ms == m1.liftoff_delay_ms
    # No persistent run at all: NaN, like the plain delays without a match.
    short = evaluate(_seq([(31, 32)]), g, dt=DT)
    assert np.isnan(short.touchdown_delay_persist_ms[0])


def test_absolute_delays_do_not_cancel_by_hand():
    # Truth on [30, 50) in both sequences. Estimate on [28, 52): its run starts 2 steps
    # before t0 = 30, inside the early window, and is still on at 30, so it is the match
    # (rule 4): -5 ms; it falls at 52: +5 ms. Estimate on [32, 52): +5 ms and +5 ms.
    # Touch-downs: signed mean 0, std 5, mean |delay| 5; lift-offs: 5, 0, 5.
    g = _truth([(30, 50)])
    est = np.stack([_seq([(28, 52)]), _seq([(32, 52)])], -1)
    m = evaluate(est, np.stack([g, g], -1), dt=DT)
    assert m.touchdown_delay_ms == pytest.approx((0.0, 5.0))
    assert m.touchdown_abs_delay_ms == pytest.approx(5.0)
    assert m.liftoff_delay_ms == pytest.approx((5.0, 0.0))
    assert m.liftoff_abs_delay_ms == pytest.approx(5.0)
    assert m.failures == 0
    # No match: NaN, like the signed mean.
    none = evaluate(_seq([]), g, dt=DT)
    assert np.isnan(none.touchdown_abs_delay_ms) and np.isnan(none.touchdown_delay_ms[0])
    assert "touchdown_abs_delay_ms" in m.as_dict()


def test_summary_holds_the_new_and_the_kept_fields():
    d = evaluate(_seq([(33, 52)]), _truth([(30, 50)]), dt=DT).as_dict()
    for key in (
        "missed_liftoffs",
        "touchdown_already_on",
        "touchdown_delay_persist_ms",
        "liftoff_delay_persist_ms",
        "n_air_phases",
        "air_phases_with_failure",
        "air_phase_failure_rate",
        "swing_phase_failure_rate",
        "swing_phase_flag_on_rate",
        "air_false_contact_rate",
    ):
        assert key in d
    assert d["touchdown_delay_persist_ms"] == pytest.approx((7.5, 0.0))
    assert (d["n_air_phases"], d["air_phases_with_failure"]) == (2, 0)
    assert d["air_false_contact_rate"] == 2 / 60


# ----------------------------------------------------------------------------- oracles


def _oracle_segment(g, f, early, min_on):
    """Plain-loop version of the module's rules 2-7 on one valid stretch (0/1 lists)."""
    n = len(g)

    def runs(x):
        out, s = [], 0
        for t in range(1, n + 1):
            if t == n or x[t] != x[s]:
                out.append((s, t, x[s]))
                s = t
        return out

    gr, fr = runs(g), runs(f)
    res = {"delays": [], "n": 0, "missed": 0, "already": 0, "false": 0, "chatter": 0}
    res["false_starts"] = []
    matched = set()
    for i, (t0, t1, v) in enumerate(gr):
        if v != 1 or t0 == 0:
            continue
        a0 = gr[i - 1][0]
        w0 = max(t0 - early, a0)
        evaluable = a0 > 0 or t0 - early >= a0
        s, e, fv = next(r for r in fr if r[0] <= w0 < r[1])
        already = fv == 1 and e - s >= min_on and e > t0 and not (s == w0 and s > 0)
        match = None
        if not already:
            for r in fr:
                solid_edge = r[2] == 1 and r[1] - r[0] >= min_on and r[0] > 0
                if solid_edge and w0 <= r[0] < t1 and r[1] > t0:
                    match = r
                    break
        if match is not None:
            matched.add(match)
        if not evaluable:
            continue
        if match is not None:
            res["n"] += 1
            res["delays"].append(match[0] - t0)
        elif already:
            res["n"] += 1
            res["already"] += 1
        elif t1 < n:
            res["n"] += 1
            res["missed"] += 1
    for r in fr:
        s, e, v = r
        if v != 1 or s == 0 or g[s] != 0:
            continue
        if e - s >= min_on and r not in matched:
            res["false"] += 1
            res["false_starts"].append(s)
        elif e - s < min_on and e < n:
            res["chatter"] += 1
    return res


def _stretches(flag, truth, valid):
    """Yields (truth, flag) as int lists for every valid stretch of every sequence.

    Sequences are the trailing axes; a stretch is a maximal run of valid steps.
    """
    f2, g2, v2 = (x.reshape(x.shape[0], -1) for x in (flag, truth, valid))
    for j in range(f2.shape[1]):
        t = 0
        while t < f2.shape[0]:
            if not v2[t, j]:
                t += 1
                continue
            end = t
            while end < f2.shape[0] and v2[end, j]:
                end += 1
            yield [int(x) for x in g2[t:end, j]], [int(x) for x in f2[t:end, j]]
            t = end


def _oracle(est_flag, truth, valid, early, min_on):
    """Pools ``_oracle_segment`` over sequences (trailing axes) and valid stretches."""
    tot = {"delays": [], "n": 0, "missed": 0, "already": 0, "false": 0, "chatter": 0}
    for g, f in _stretches(est_flag, truth, valid):
        seg = _oracle_segment(g, f, early, min_on)
        for k in tot:
            tot[k] = tot[k] + seg[k]
    return tot


def _random_case(rng, shape):
    """A Markov truth, an estimate that lags it with noise, and a mask with gaps."""
    n = shape[0]
    truth = np.zeros(shape, bool)
    state = rng.random(shape[1:]) < 0.5
    for t in range(n):
        state = np.where(rng.random(shape[1:]) < 1 / 12, ~state, state)
        truth[t] = state
    lag = rng.integers(-3, 6, size=shape[1:])
    idx = np.clip(np.arange(n)[:, None, None] - lag, 0, n - 1)
    est = np.take_along_axis(truth, idx, 0) ^ (rng.random(shape) < 0.06)
    prob = np.where(est, rng.uniform(0.5, 1.0, shape), rng.uniform(0.0, 0.5, shape))
    valid = rng.random(shape) > 0.01
    valid[40:45, 0] = False
    return prob, truth, valid


@pytest.mark.parametrize("min_on", [1, 3])
def test_event_matching_matches_loop_oracle(min_on):
    rng = np.random.default_rng(10 + min_on)
    for _ in range(3):
        prob, truth, valid = _random_case(rng, (300, 3, 2))
        ev = match_events(prob, truth, valid, dt=DT, early_window_s=0.02, min_on=min_on)
        flag = prob > 0.5
        for kind, f, g in (("touchdown", flag, truth), ("liftoff", ~flag, ~truth)):
            ref = _oracle(f, g, valid, early=8, min_on=min_on)
            got = getattr(ev, kind)
            assert ref["n"] > 20
            np.testing.assert_allclose(
                np.sort(got.delays_ms), np.sort(np.array(ref["delays"]) * DT * 1e3)
            )
            # The mean |delay| of the oracle's delays (lags of -3..5 steps: both signs).
            assert got.delay_abs_mean_ms == pytest.approx(
                np.mean(np.abs(ref["delays"])) * DT * 1e3, rel=1e-12
            )
            assert (got.n_events, got.missed, got.already, got.false_edges, got.chatter) == (
                ref["n"],
                ref["missed"],
                ref["already"],
                ref["false"],
                ref["chatter"],
            )


def _air_oracle(flag, truth, valid, early, min_on):
    """Loop version of rules 8-10: air phases, the ones a failure starts in, air steps.

    Walks every sequence and valid stretch step by step; the failures come from
    ``_oracle_segment`` (rules 2-7), and each is put in the air phase holding its start.
    """
    n_phases = with_failure = air_steps = air_on = 0
    for g, f in _stretches(flag, truth, valid):
        for gt, ft in zip(g, f, strict=True):
            if not gt:
                air_steps += 1
                air_on += bool(ft)
        starts = _oracle_segment(g, f, early, min_on)["false_starts"]
        a = 0
        while a < len(g):
            b = a
            while b < len(g) and g[b] == g[a]:
                b += 1
            if g[a] == 0:
                n_phases += 1
                with_failure += any(a <= s < b for s in starts)
            a = b
    return n_phases, with_failure, air_steps, air_on


def _random_air_case(rng, shape):
    """Markov truth, a lagged noisy estimate with false bursts and dropouts, masked steps.

    Any ndim: the trailing axes are the sequences. Bursts of 1-4 steps make solid false
    runs (and, with a debounce, blips), and masked runs cut air phases.
    """
    n, rest = shape[0], shape[1:]
    truth = np.zeros(shape, bool)
    state = rng.random(rest) < 0.5
    for t in range(n):
        state = np.where(rng.random(rest) < 1 / 15, ~state, state)
        truth[t] = state
    lag = rng.integers(-3, 6, size=rest)
    idx = np.clip(np.arange(n).reshape((n,) + (1,) * len(rest)) - lag, 0, n - 1)
    est = np.take_along_axis(truth, np.broadcast_to(idx, shape), 0)
    est = est ^ (rng.random(shape) < 0.04)
    starts, dropout = rng.random(shape) < 0.04, rng.random(shape) < 0.01
    length = rng.integers(1, 8, size=shape)
    burst = np.zeros(shape, bool)
    for k in range(min(7, n)):
        burst[k:] |= starts[: n - k] & (length[: n - k] > k)
    est = (est | burst) & ~dropout
    prob = np.where(est, rng.uniform(0.5, 1.0, shape), rng.uniform(0.0, 0.5, shape))
    valid = rng.random(shape) > 0.03
    valid[n // 3 : n // 3 + 4] = False
    prob[~valid] = np.nan
    return prob, truth, valid


@pytest.mark.parametrize("min_on", [1, 3])
@pytest.mark.parametrize("shape", [(400,), (200, 5), (150, 3, 2), (60, 2, 2, 2), (4, 6)])
def test_air_rates_match_loop_oracle(shape, min_on):
    rng = np.random.default_rng([min_on, *shape])
    phases = hit = failures = 0
    for _ in range(3):
        prob, truth, valid = _random_air_case(rng, shape)
        m = evaluate(prob, truth, valid, dt=DT, early_window_s=0.02, min_on=min_on)
        n_phases, with_failure, air_steps, air_on = _air_oracle(
            prob > 0.5, truth, valid, early=8, min_on=min_on
        )
        assert (m.n_air_phases, m.air_phases_with_failure) == (n_phases, with_failure)
        phases, hit, failures = phases + n_phases, hit + with_failure, failures + m.failures
        if n_phases:
            assert m.air_phase_failure_rate == with_failure / n_phases
        else:
            assert np.isnan(m.air_phase_failure_rate)
        if air_steps:
            assert m.air_false_contact_rate == air_on / air_steps
        else:
            assert np.isnan(m.air_false_contact_rate)
    if shape[0] > 50:
        # Enough happens for the agreement to mean something: phases with and without a
        # failure, and (raw flag) phases with several, so the per-phase count is no
        # restatement of the failure count.
        assert phases > 30 and 0 < hit < phases
        assert failures > hit or min_on > 1


def _gap_oracle(flag, truth, valid, known, early, min_on):
    """Loop version of rules 7, 7b, 8 and 9 with ``truth_known``: (phases, phases with a
    failure, failures, chatter, failures by rule 7b) for touch-downs, walking each sequence
    step by step."""
    f2, g2, v2, k2 = (x.reshape(x.shape[0], -1) for x in (flag, truth, valid, known))
    n_t = f2.shape[0]
    phases = with_failure = failures = chatter = rose_in_gap = 0
    for j in range(f2.shape[1]):
        f, g, v, k = (list(x[:, j]) for x in (f2, g2, v2, k2))
        starts = []
        t = 0
        while t < n_t:
            if not v[t]:
                t += 1
                continue
            end = t
            while end < n_t and v[end]:
                end += 1
            seg = _oracle_segment([int(x) for x in g[t:end]], [int(x) for x in f[t:end]],
                                  early, min_on)  # fmt: skip
            starts += [t + s for s in seg["false_starts"]]
            failures += seg["false"]
            chatter += seg["chatter"]
            # Rule 7b at the stretch's first step t: the last valid step before it, b.
            b = max((u for u in range(t) if v[u]), default=None)
            if b is not None and f[t] and not g[t] and not f[b]:
                if all(k[u] and not g[u] for u in range(b, t + 1)):
                    e = t
                    while e < end and f[e]:
                        e += 1
                    if e - t >= min_on:
                        failures += 1
                        rose_in_gap += 1
                        starts.append(t)
                    elif e < end:
                        chatter += 1
            t = end
        t = 0
        while t < n_t:
            if not (k[t] and not g[t]):
                t += 1
                continue
            end = t
            while end < n_t and k[end] and not g[end]:
                end += 1
            if any(v[t:end]):
                phases += 1
                with_failure += any(t <= s < end for s in starts)
            t = end
    return phases, with_failure, failures, chatter, rose_in_gap


@pytest.mark.parametrize("min_on", [1, 3])
@pytest.mark.parametrize("shape", [(800,), (200, 5), (150, 3, 2)])
def test_gap_rules_match_loop_oracle(shape, min_on):
    """``truth_known`` wider than ``valid`` (rules 7b, 8): touch-downs and lift-offs
    against ``_gap_oracle``; with ``truth_known = valid`` every metric is the default's."""
    rng = np.random.default_rng([7, min_on, *shape])
    bridged = 0
    for _ in range(3):
        prob, truth, valid = _random_air_case(rng, shape)
        # Gaps of 1-3 invalid steps, most with their truth known.
        drop = np.zeros(shape, bool)
        for k in range(3):
            drop[k:] |= (rng.random(shape) < 0.04)[: shape[0] - k]
        valid &= ~drop
        prob[~valid] = np.nan
        known = valid | (rng.random(shape) < 0.8)
        kw = {"dt": DT, "early_window_s": 0.02, "min_on": min_on}
        m = evaluate(prob, truth, valid, truth_known=known, **kw)
        ev = match_events(prob, truth, valid, truth_known=known, **kw)
        flag = prob > 0.5
        ref = _gap_oracle(flag, truth, valid, known, early=8, min_on=min_on)
        got = (m.n_air_phases, m.air_phases_with_failure, m.failures, m.chatter)
        assert got == ref[:4]
        assert (ev.touchdown.false_edges, ev.touchdown.chatter) == ref[2:4]
        ref_lo = _gap_oracle(~flag, ~truth, valid, known, early=8, min_on=min_on)
        assert (m.false_liftoffs, m.liftoff_chatter) == ref_lo[2:4]
        bridged += ref[4] + ref_lo[4]
        same = evaluate(prob, truth, valid, truth_known=valid.copy(), **kw).as_dict()
        for k, v in evaluate(prob, truth, valid, **kw).as_dict().items():
            np.testing.assert_equal(same[k], v, err_msg=k)
    # Rule 7b did happen (false edges that rose in a gap), so the oracle's branch was tested.
    assert bridged > 0


def test_brier_ece_and_scores_match_loop_oracle():
    rng = np.random.default_rng(20)
    shape = (50, 3, 2)
    prob = rng.random(shape)
    truth = rng.random(shape) < prob  # roughly calibrated, so the ECE is small but not 0
    valid = rng.random(shape) > 0.2
    n_bins = 7
    se, n, sum_p, sum_g, cnt = 0.0, 0, np.zeros(n_bins), np.zeros(n_bins), np.zeros(n_bins)
    tp = fp = fn = right = 0
    for idx in np.ndindex(*shape):
        if not valid[idx]:
            continue
        p, y = float(prob[idx]), float(truth[idx])
        se += (p - y) ** 2
        n += 1
        for b in range(n_bins):
            if b / n_bins <= p < (b + 1) / n_bins or (b == n_bins - 1 and p == 1.0):
                sum_p[b] += p
                sum_g[b] += y
                cnt[b] += 1
        flag = p > 0.5
        tp += flag and y == 1
        fp += flag and y == 0
        fn += (not flag) and y == 1
        right += flag == (y == 1)
    ece = sum(
        cnt[b] / n * abs(sum_g[b] / cnt[b] - sum_p[b] / cnt[b]) for b in range(n_bins) if cnt[b]
    )
    assert brier_score(prob, truth, valid) == pytest.approx(se / n, rel=1e-12)
    got = expected_calibration_error(prob, truth, valid, n_bins=n_bins)
    assert got == pytest.approx(ece, rel=1e-12) and got > 0
    s = step_scores(prob, truth, valid)
    assert s.n_steps == n
    assert s.accuracy == pytest.approx(right / n)
    assert s.precision == pytest.approx(tp / (tp + fp))
    assert s.recall == pytest.approx(tp / (tp + fn))
    assert s.f1 == pytest.approx(2 * tp / (2 * tp + fp + fn))
    # ECE of a perfectly calibrated bin: p = 0.25 everywhere, truth on 1 step in 4 -> 0.
    p = np.full(8, 0.25)
    y = np.array([1, 0, 0, 0, 0, 1, 0, 0], bool)
    assert expected_calibration_error(p, y) == pytest.approx(0.0, abs=1e-15)


def test_ece_bins_each_p_by_the_edges_themselves():
    # The docstring's bin b holds b/n <= p < (b+1)/n. int(p * n) rounded across an edge: the
    # float one ulp below 0.9 times 10 is 9.0 (bin 9, not 8), and 15/22 * 22 is
    # 14.999999999999998 (bin 14, not 15). A helper's metrics oracle found both.
    below = np.nextafter(0.9, 0.0)
    p = np.array([below, 0.91])
    g = np.array([True, False])
    count, _, _ = ece_bins(p, g, np.ones(2, bool), 10)
    assert count[8] == 1 and count[9] == 1
    # Each step alone in its bin: ECE = (|1 - below| + |0 - 0.91|) / 2 = 0.505 (0.405 with
    # both in bin 9: |1 - (below + 0.91)| / 2).
    assert expected_calibration_error(p, g, n_bins=10) == pytest.approx(
        (1 - below + 0.91) / 2, rel=1e-12
    )
    count, _, _ = ece_bins(np.array([15 / 22, 1.0, 0.0]), np.ones(3, bool), np.ones(3, bool), 22)
    assert count[15] == 1 and count[21] == 1 and count[0] == 1  # 1.0 in the last bin


def test_a_truth_not_0_or_1_where_known_names_truth_known():
    # Step 2 is invalid but its truth known: the message names the mask that was checked.
    with pytest.raises(ValueError, match=r"truth must be bool .* \(where truth_known\)"):
        evaluate(
            np.array([0.1, 0.9, 0.3, 0.9]),
            np.array([0, 1, np.nan, 1.0]),
            np.array([1, 1, 0, 1], bool),
            dt=0.0025,
            truth_known=np.ones(4, bool),
        )


def test_bad_input_raises():
    p, g = _seq([(33, 52)]), _truth([(30, 50)])
    with pytest.raises(ValueError, match="truth"):
        evaluate(p, g[:-1], dt=DT)
    with pytest.raises(ValueError, match="valid"):
        evaluate(p, g, np.ones(T - 1, bool), dt=DT)
    bad = p.copy()
    bad[3] = 1.2
    with pytest.raises(ValueError, match="estimate"):
        evaluate(bad, g, dt=DT)
    bad[3] = np.nan
    with pytest.raises(ValueError, match="estimate"):
        brier_score(bad, g)
    with pytest.raises(ValueError, match="truth"):
        step_scores(p, g.astype(int) * 2)
    with pytest.raises(ValueError, match="dt"):
        match_events(p, g, dt=0.0)
    # A period in ms or a rate in Hz (the early window rounded to 0 steps and every delay
    # scaled by 1000 or more, silently).
    for wrong in (2.5, 400.0):
        with pytest.raises(ValueError, match=r"dt is the period .* in seconds .* got"):
            evaluate(p, g, dt=wrong)
    evaluate(p, g, dt=1.0)  # 1 Hz, the slowest taken
    with pytest.raises(ValueError, match="min_on"):
        match_events(p, g, dt=DT, min_on=0)
    for bad_persist in (0, 2.5, True):
        with pytest.raises(ValueError, match="persist_steps"):
            evaluate(p, g, dt=DT, persist_steps=bad_persist)
    with pytest.raises(ValueError, match="early_window_s"):
        match_events(p, g, dt=DT, early_window_s=-0.01)
    with pytest.raises(ValueError, match="threshold"):
        step_scores(p, g, threshold=1.0)
    with pytest.raises(ValueError, match="n_bins"):
        expected_calibration_error(p, g, n_bins=0)
    with pytest.raises(ValueError, match="estimate"):
        evaluate(np.zeros(()), np.zeros((), bool), dt=DT)
    # NumPy's or Python's own errors before, naming nothing (a helper's audit); a complex
    # estimate lost its imaginary part with only a warning.
    with pytest.raises(ValueError, match=r"threshold must be a number in \[0, 1\), got 'abc'"):
        evaluate(p, g, dt=DT, threshold="abc")
    for wrong in (None, np.array([0.01, 0.02])):
        with pytest.raises(ValueError, match=r"dt must be a finite number > 0"):
            evaluate(p, g, dt=wrong)
    with pytest.raises(ValueError, match=r"early_window_s must be at most 10 s, got 1e\+30"):
        evaluate(p, g, dt=DT, early_window_s=1e30)
    with pytest.raises(ValueError, match=r"estimate must be float probabilities or bool"):
        evaluate(p.astype(complex) + 0.5j, g, dt=DT)
    with pytest.raises(ValueError, match=r"dt must be finite and > 0, got 0.0"):
        bounce_steps(0.0)
