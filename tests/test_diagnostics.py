"""train/diagnostics.py on hand-made sequences (values derived in the comments)."""

from __future__ import annotations

import numpy as np

from jax_contact.train.diagnostics import event_profiles, false_contact_terms, format_profiles


def _out(p, dyn, dkin, kin, to, td):
    a = lambda x: np.asarray(x, np.float32)[:, None, None]  # noqa: E731
    return {
        "e": a(p),
        "e/p_dynamics": a(dyn),
        "e/p_diff_kinematics": a(dkin),
        "e/p_kinematics": a(kin),
        "e/p_takeoff": a(to),
        "e/p_touchdown": a(td),
    }


# One foot, 10 steps: contact 0-3, air 4-6, contact 7-9. Lift-off at 4, touch-down at 7.
TRUTH = np.array([1, 1, 1, 1, 0, 0, 0, 1, 1, 1], bool)[:, None, None]
STEP = np.arange(10) / 10.0  # each series' value is its step index / 10
OUT = _out(STEP, STEP + 1, STEP + 2, STEP + 3, STEP + 4, STEP + 5)


def test_profiles_read_each_series_at_its_offset_from_the_event():
    valid = np.ones((10, 1), bool)
    prof = event_profiles(OUT, TRUTH, valid, "e", offsets=(-1, 0, 2))
    lo, td = prof["liftoff"], prof["touchdown"]
    assert lo["n_events"] == td["n_events"] == 1
    # Lift-off's first air step is 4: offsets -1, 0, 2 read steps 3, 4, 6.
    np.testing.assert_allclose(lo["p_contact"], [0.3, 0.4, 0.6], atol=1e-6)
    np.testing.assert_allclose(lo["p_diff_kinematics"], [2.3, 2.4, 2.6], atol=1e-6)
    np.testing.assert_allclose(lo["truth"], [1, 0, 0])
    # Touch-down at 7: steps 6, 7, 9.
    np.testing.assert_allclose(td["p_touchdown"], [5.6, 5.7, 5.9], atol=1e-6)
    np.testing.assert_allclose(td["truth"], [0, 1, 1])
    assert "touchdown (1 events)" in format_profiles(prof)


def test_events_whose_window_is_not_valid_or_cut_are_dropped():
    valid = np.ones((10, 1), bool)
    valid[8] = False  # inside the touch-down's window (7 + 2 = 9 reaches step 8)
    prof = event_profiles(OUT, TRUTH, valid, "e", offsets=(-1, 0, 2))
    assert prof["liftoff"]["n_events"] == 1 and prof["touchdown"]["n_events"] == 0
    # A window past the end (touch-down 7 + 3 = 10) is cut: no event.
    prof = event_profiles(OUT, TRUTH, np.ones((10, 1), bool), "e", offsets=(0, 3))
    assert prof["touchdown"]["n_events"] == 0 and prof["liftoff"]["n_events"] == 1


def test_false_contact_terms_average_over_the_flagged_air_steps():
    # Air steps 4, 5, 6 with P(C) 0.2, 0.5, 0.9: only step 6 is flagged (0.5 is not
    # above the threshold), so the flagged steps' p_dynamics (STEP) is 0.6 alone.
    p = np.array([1, 1, 1, 1, 0.2, 0.5, 0.9, 1, 1, 1])
    out = _out(p, STEP, STEP, STEP, STEP, STEP)
    res = false_contact_terms(out, TRUTH, np.ones((10, 1), bool), "e")
    assert res["n_false_contact_steps"] == 1 and res["n_air_steps"] == 3
    np.testing.assert_allclose(res["p_dynamics"]["false_contact"], 0.6, atol=1e-6)
    # With step 5 at 0.6, steps 5 and 6 are flagged: p_dynamics 0.5 and 0.6.
    out["e"][5] = 0.6
    res = false_contact_terms(out, TRUTH, np.ones((10, 1), bool), "e")
    assert res["n_false_contact_steps"] == 2 and res["n_air_steps"] == 3
    np.testing.assert_allclose(res["p_dynamics"]["false_contact"], (0.5 + 0.6) / 2, atol=1e-6)
    np.testing.assert_allclose(res["p_dynamics"]["air"], (0.4 + 0.5 + 0.6) / 3, atol=1e-6)
