"""Gradient tuning (jax_contact.tune): the loss's gradient, a recovery, the calibration map.

Compile cost is kept small: one float64 program (loss and gradient) on a 10-step sequence,
one float32 training program on a one-leg synthetic problem.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import subprocess
import sys
import warnings

import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import oracle
import pytest

from jax_contact import LegMeasurement, flat, init_belief_batch, make_noise, make_params
from jax_contact import tune as jt

# Central differences in float64 with step H: truncation ~H^2 |L'''| and round-off
# ~eps |L| / H, both far below GRAD_TOL's atol for H = 1e-5 and |L| ~ 1.
GRAD_H = 1e-5
GRAD_TOL = (1e-7, 1e-5)  # (atol, rtol): |autodiff - central difference| <= atol + rtol |fd|

# --------------------------------------------------------------------- gradient vs FD

T_STEPS, N_ENVS, N_LEGS, NV, N_L = 10, 1, 2, 8, 3
# (step, leg) of air steps with stance-like inputs.
FD_FALSE_CONTACTS = ((5, 0), (6, 0), (2, 1), (3, 1))


@functools.cache
def _fd_problem():
    """A short random sequence of stance-like and air-like steps (NumPy, float64)."""
    rng = np.random.default_rng(15)
    base = oracle.random_case(rng, NV, N_L)
    legs = [np.array([0, 1, 2]), np.array([3, 4, 5])]
    seq, truth = [], np.zeros((T_STEPS, N_ENVS, N_LEGS), bool)
    for t in range(T_STEPS):
        cells = []
        for g in range(N_LEGS):
            stance = ((t + 3 * g) // 4) % 2 == 0
            truth[t, 0, g] = stance
            # Air steps measured like stance: the logit rises in the air there (a false
            # contact in the making), so the event term has steps to score.
            looks = stance or (t, g) in FD_FALSE_CONTACTS
            cells.append(oracle.random_case(rng, NV, N_L, stance=looks, leg=legs[g])["meas"])
        seq.append([cells])
    stack = lambda trees: jax.tree.map(lambda *xs: np.stack(xs), *trees)  # noqa: E731
    meas = stack([stack([stack(row) for row in env]) for env in seq])
    scalars = dict(base["scalars"])
    # Caps inside (0.5, 1) so that every tuned value has an effect.
    scalars.update(
        cap_dynamics=0.97,
        cap_diff_kinematics=0.9,
        cap_diff_kinematics_still=0.8,
        cap_kinematics=0.95,
        cap_transition=0.9,
        outlier_prob=0.02,
        dt=0.0025,
        contact_damping=100.0,  # the stabilised contact, so that its (optional) b is tuned too
    )
    return base["noise"], scalars, meas, truth


FD_EARLY = 2  # steps of early window in the FD problem (event_early_s = 2 dt)


@functools.cache  # the event test compares with the plain loss's gradient: compiled once
def _fd_setup(event_weight: float = 0.0, touchdown: str = "quadrature"):
    """Float64 params, space, data and a flat-vector loss (call under enable_x64); with
    ``event_weight > 0`` the loss has the air-phase event term. With ``touchdown`` of
    ``"monte_carlo"`` the loss is a smooth function of the parameters too: the key is
    fixed, so the draws are, and each enters through inverse CDFs and Phi."""
    noise, scalars, meas, truth = _fd_problem()
    base = make_params(make_noise(NV, **noise), **scalars, touchdown=touchdown)
    base = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), base)
    space = jt.make_space(NV, dof_groups=(0, 0, 1, 1, 1, 2, 2, 2), fields=jt.TUNABLE_FIELDS)
    theta0 = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), jt.init_theta(space, base))
    meas = LegMeasurement(
        **{
            k: jnp.asarray(v, jnp.float64)
            if np.issubdtype(np.asarray(v).dtype, np.floating)
            else jnp.asarray(v)
            for k, v in meas.items()
        }
    )
    data = jt.TuningData(meas=meas, truth=jnp.asarray(truth), mask=jnp.ones(truth.shape, bool))
    data = jt.with_air_phases(data, FD_EARLY)
    terrain = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), flat(0.0, 0.05))
    belief = init_belief_batch(base, N_ENVS, N_LEGS)
    belief = belief.replace(foothold=belief.foothold.astype(jnp.float64))
    config = jt.TuneConfig(
        prior_noise=1e-2,
        prior_other=1e-2,
        event_weight=event_weight,
        event_early_s=FD_EARLY * scalars["dt"],
        event_temperature=0.5,
    )
    flat0, unravel = jax.flatten_util.ravel_pytree(theta0)
    # Start away from the prior's centre so that its gradient is not zero.
    start = flat0 + 0.1 * jnp.asarray(np.random.default_rng(3).normal(size=flat0.shape))

    def loss(x):
        return jt.tuning_loss(
            unravel(x), space, base, theta0, terrain, belief, data, config, key=jax.random.key(0)
        )[0]

    def logits(x):
        params = jt.to_params(space, base, unravel(x))
        return jt.filter_logits(params, terrain, belief, data.meas, key=jax.random.key(0))[1]

    # One program gives the loss and its gradient (the finite differences read the loss at
    # perturbed points through it too): half the compilation of two programs.
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    return (
        lambda x: value_and_grad(x)[0],
        lambda x: value_and_grad(x)[1],
        start,
        (jax.jit(logits), data, unravel),
    )


@pytest.mark.parametrize(
    "event_weight, touchdown",
    [(0.0, "quadrature"), (5.0, "quadrature"), (0.0, "monte_carlo")],
    ids=["bce", "bce+event", "bce-monte-carlo"],
)
def test_gradient_matches_central_differences(x64, event_weight, touchdown):
    loss, grad, x, (logits, data, unravel) = _fd_setup(event_weight, touchdown)
    assert loss(x).dtype == jnp.float64
    if event_weight:
        # Not vacuous: some air steps are scored at x, and the event term changes the
        # gradient by far more than the tolerance (~1e-5 here).
        scored = np.asarray(jt.scored_air_steps(logits(x), data))
        assert scored.sum() >= 4, scored.sum()
        g0 = np.asarray(_fd_setup(0.0)[1](x))
        assert np.max(np.abs(np.asarray(grad(x)) - g0)) > 1e-2
    g = np.asarray(grad(x))
    fd = np.zeros_like(g)
    for i in range(x.shape[0]):
        e = jnp.zeros_like(x).at[i].set(GRAD_H)
        fd[i] = (float(loss(x + e)) - float(loss(x - e))) / (2 * GRAD_H)
    atol, rtol = GRAD_TOL
    bad = np.abs(g - fd) > atol + rtol * np.abs(fd)
    assert np.all(np.isfinite(g))
    assert not bad.any(), f"entries {np.flatnonzero(bad)}: autodiff {g[bad]}, fd {fd[bad]}"
    # The check is not vacuous: most entries have a gradient well above the tolerance,
    # the optional contact damping's among them.
    assert np.sum(np.abs(g) > 1e-4) >= x.shape[0] // 2
    assert abs(float(unravel(jnp.asarray(g))["contact_damping"][()])) > 1e-4


# ---------------------------------------------------------------- recovery of a std

SIGMA_J_TRUE, SIGMA_J_WRONG = 0.05, 0.2
SIGMA_QD, SIGMA_PRIOR = 0.01, 0.5
DT, DWELL = 0.0025, 0.1  # s; the gait prior's mean stance and swing, as simulated
RECOVERY_RTOL = 0.2  # the tuned sigma_J within 20 % of the truth (4x off at the start)


def _synthetic(seed: int, n_t: int = 1200, n_envs: int = 8) -> jt.TuningData:
    """One foot per env whose states follow the gait prior's Markov chain and whose foot
    velocity follows eq. 8-9 exactly: J = [0 | I3] (the base column has no lever), so
    contact: v ~ N(0, (sigma_qd^2 + sigma_J^2) I), air: v ~ N(0, (prior^2 + ...) I)."""
    rng = np.random.default_rng(seed)
    p_switch = DT / DWELL
    state = np.zeros((n_t, n_envs), bool)
    s = rng.random(n_envs) < 0.5
    for t in range(n_t):
        s = np.where(rng.random(n_envs) < p_switch, ~s, s)
        state[t] = s
    std_c = np.hypot(SIGMA_QD, SIGMA_J_TRUE)
    std_a = np.sqrt(SIGMA_PRIOR**2 + std_c**2)
    v = rng.normal(size=(n_t, n_envs, 3)) * np.where(state, std_c, std_a)[..., None]
    shape = (n_t, n_envs, 1)
    J = np.zeros((3, 4))
    J[:, 1:] = np.eye(3)
    f32 = np.float32

    def tile(x):
        return np.broadcast_to(np.asarray(x, f32), shape + np.shape(x)).copy()

    meas = LegMeasurement(
        q=tile(np.zeros(5)),
        qd=tile(np.zeros(4)),
        qdd=tile(np.zeros(4)),
        tau=tile(np.zeros(4)),
        M=tile(np.eye(4)),
        h=tile(np.zeros(4)),
        J=tile(J),
        Jdot_qd=tile(np.zeros(3)),
        p_f=tile(np.array([0.0, 0.0, 0.3])),
        v_f=v[:, :, None, :].astype(f32),
        foot_radius=tile(0.02),
        leg_dofs=np.broadcast_to(np.arange(1, 4, dtype=np.int32), shape + (3,)).copy(),
        other_dofs=np.zeros(shape + (1,), np.int32),
    )
    return jt.TuningData(meas=meas, truth=state[..., None], mask=np.ones(shape, bool))


def _synthetic_params(sigma_J: float):
    noise = make_noise(
        4, sigma_qd=SIGMA_QD, sigma_J=sigma_J, sigma_qd_prior=SIGMA_PRIOR, sigma_q=1e-3
    )
    return make_params(
        noise,
        dt=DT,
        stance_time=DWELL,
        swing_time=DWELL,
        cap_dynamics=1.0,
        cap_diff_kinematics=1.0,
        cap_kinematics=1.0,
        terms=("diff_kinematics",),
        transition_model=False,
        touchdown="quadrature",
        initial_contact=0.5,
    )


def _recovery_run(select: str):
    """``sigma_J`` tuned from 4x its true value on the synthetic problem: (result,
    validation data, the mis-set params, the config). Both selection rules share the
    training step."""
    train, val = _synthetic(1), _synthetic(2)
    space = jt.make_space(4, fields=("sigma_J",))
    config = jt.TuneConfig(
        learning_rate=0.1, max_epochs=25, patience=5, chunk=300, prior_noise=0.0, seed=0,
        event_weight=0.0, select=select,
    )  # fmt: skip
    wrong = _synthetic_params(SIGMA_J_WRONG)
    return jt.tune(wrong, flat(0.0, 0.05), [train], val, space, config), val, wrong, config


def test_tune_refuses_logs_it_cannot_learn_from():
    """A validation log with no step that counts, or tuning logs of one class, are refused
    naming the log before anything compiles (they gave NaN epochs and a written file)."""
    data = _synthetic(1, n_t=50, n_envs=2)
    dead = data.replace(mask=np.zeros_like(data.mask))
    stance = data.replace(truth=np.ones_like(data.truth))
    space, params = jt.make_space(4, fields=("sigma_J",)), _synthetic_params(SIGMA_J_WRONG)
    with pytest.raises(ValueError, match=r"validation log 2 of 2 has no step that counts"):
        jt.tune(params, flat(0.0, 0.05), [data], [data, dead], space)
    with pytest.raises(ValueError, match=r"tuning logs have no air step among their 100"):
        jt.tune(params, flat(0.0, 0.05), [stance], data, space)
    # Arrays that do not fit each other, named (NumPy's and the windows' errors before): a
    # log's (T, E) valid mask, inputs one step short of the truth (the delayed pairing).
    env_mask = data.replace(mask=np.ones(data.truth.shape[:2], bool))
    with pytest.raises(ValueError, match=r"tuning log 1 of 1: mask has shape \(50, 2\);"):
        jt.tune(params, flat(0.0, 0.05), [env_mask], data, space)
    short = data.replace(meas=jax.tree.map(lambda x: x[:-1], data.meas))
    with pytest.raises(ValueError, match=r"validation log 1 of 1: meas\.qdd has shape \(49,"):
        jt.tune(params, flat(0.0, 0.05), [data], short, space)
    with pytest.raises(ValueError, match=r"space has nv=8 .* base has nv=4"):
        jt.tune(params, flat(0.0, 0.05), [data], data, jt.make_space(8, fields=("sigma_J",)))


def test_tuning_recovers_a_mis_set_noise_std():
    res, val, _, _ = _recovery_run("bce")
    got = float(res.params.noise.sigma_J[0])
    assert abs(got / SIGMA_J_TRUE - 1.0) < RECOVERY_RTOL, (got, res.history)
    hist = res.history
    assert hist[res.best_epoch]["val_bce"] < hist[0]["val_bce"]
    # Everything else is as it was: only the tuned field moved.
    assert float(res.params.noise.sigma_qd[0]) == pytest.approx(SIGMA_QD, rel=1e-6)
    # The right value is (near) a minimum: the loss at the truth is at most the tuned one's
    # plus a little, and far below the mis-set one's.
    truth = jt.score_logits(
        jt.predict_logits(_synthetic_params(SIGMA_J_TRUE), flat(0.0, 0.05), val,
                          key=jax.random.key(0), chunk=300),
        val,
    )  # fmt: skip
    assert truth["bce"] < hist[0]["val_bce"]
    assert abs(hist[res.best_epoch]["val_bce"] - truth["bce"]) < 0.05 * truth["bce"]


def test_a_diverging_fit_stops_and_returns_the_best_epoch_before_it():
    """A helper's audit: at ``--lr 5`` on a small log an update sent a std to NaN, and the
    next window's ``init_belief`` raised it as bad input ("params: noise.sigma_q must be
    finite"): the run died, every finished epoch lost. Adam's first steps move theta by
    about the learning rate, so at 1e3 the first update takes log(sigma_J) ~1000 away:
    sigma_J leaves (0, inf) in window 1, and the fit stops there with epoch 0's values."""
    train, val = _synthetic(1), _synthetic(2)
    space = jt.make_space(4, fields=("sigma_J",))
    config = jt.TuneConfig(
        learning_rate=1e3, max_epochs=3, patience=5, chunk=300, prior_noise=0.0, seed=0,
        event_weight=0.0, select="bce",
    )  # fmt: skip
    wrong = _synthetic_params(SIGMA_J_WRONG)
    res = jt.tune(wrong, flat(0.0, 0.05), [train], val, space, config)
    assert res.diverged.startswith("epoch 1, tuning log 1, window 1: noise.sigma_J must be")
    assert (res.best_epoch, len(res.history), res.stopped_early) == (0, 1, True)
    np.testing.assert_array_equal(res.params.noise.sigma_J, wrong.noise.sigma_J)
    assert _recovery_run("bce")[0].diverged is None  # the converging run: no note


def test_tuning_stops_at_the_noise_floor():
    """The recovery problem with a floor above the truth: sigma_J would fall to 0.05 m/s
    (test above) but may not go below 0.1; projected onto the bound, it ends on it (the
    loss falls all the way down to the floor: its minimum is below it)."""
    train, val = _synthetic(1), _synthetic(2)
    space = jt.make_space(4, fields=("sigma_J",))
    config = jt.TuneConfig(
        learning_rate=0.1, max_epochs=25, patience=5, chunk=300, prior_noise=0.0, seed=0,
        event_weight=0.0, select="bce",
    )  # same config as the recovery: the same compiled training step  # fmt: skip
    floor = {"sigma_J": np.full(3, 0.1)}
    res = jt.tune(_synthetic_params(SIGMA_J_WRONG), flat(0.0, 0.05), [train], val, space,
                  config, floor=floor)  # fmt: skip
    np.testing.assert_allclose(np.asarray(res.params.noise.sigma_J), 0.1, rtol=1e-5)
    assert res.history[res.best_epoch]["val_bce"] < res.history[0]["val_bce"]


def test_tuning_stops_at_the_plausibility_box():
    """The recovery problem with a box of x2: sigma_J would fall from 0.2 to its true
    0.05 m/s (x0.25, test above) but may not go below 0.2 / 2 = 0.1; projected onto the
    box, it ends on it. sigma_qd is not tuned, so the box leaves it alone."""
    train, val = _synthetic(1), _synthetic(2)
    space = jt.make_space(4, fields=("sigma_J",))
    config = jt.TuneConfig(
        learning_rate=0.1, max_epochs=25, patience=5, chunk=300, prior_noise=0.0, seed=0,
        event_weight=0.0, select="bce", noise_ratio=2.0,
    )  # the recovery's training step: the box is traced, not compiled in  # fmt: skip
    res = jt.tune(_synthetic_params(SIGMA_J_WRONG), flat(0.0, 0.05), [train], val, space, config)
    np.testing.assert_allclose(np.asarray(res.params.noise.sigma_J), SIGMA_J_WRONG / 2, rtol=1e-5)
    assert float(res.params.noise.sigma_qd[0]) == pytest.approx(SIGMA_QD, rel=1e-6)
    assert res.history[res.best_epoch]["val_bce"] < res.history[0]["val_bce"]


def test_calibration_entry_fits_a_map_that_keeps_every_flag(capsys):
    """What `jax-contact tune --calibrate` and `recalibrate_preset` store: on the recovery
    problem with sigma_J 4x too large (mis-scaled logits), the per-side map fitted on one
    log lowers the other log's ECE and leaves its F1 (the flags) exactly as they were."""
    from jax_contact.train.tune_cmd import calibration_entry

    train, val = _synthetic(1), _synthetic(2)
    wrong, terrain = _synthetic_params(SIGMA_J_WRONG), flat(0.0, 0.05)
    entry = calibration_entry(wrong, terrain, [train], [val], ["a.h5"], kind="sign", seed=0)
    cal = jt.Calibration.from_dict(entry)
    assert cal.kind == "sign" and entry["fitted_on"] == ["a.h5"]
    raw = jt.score_logits(jt.predict_logits(wrong, terrain, val, key=jax.random.key(0)), val)
    assert entry["validation_after"]["ece"] < raw["ece"], (entry, raw)
    assert abs(np.log(cal.temperature)) > 0.1 and abs(np.log(cal.temperature_air)) > 0.1
    assert entry["validation_after"]["f1"] == pytest.approx(raw["f1"], abs=1e-12)
    assert "calibration (sign): T" in capsys.readouterr().err


def test_select_cells_scores_the_untuned_epoch_as_the_metrics_do():
    """select="cells" on the recovery problem (the same compiled training step): epoch 0's
    cells are jax_contact.metrics of the untuned filter on the validation log (recomputed
    here). Which epoch the rule then keeps is tested on a hand-made history below, where
    lower losses are refused (this run has none to refuse)."""
    from jax_contact.metrics import evaluate

    res, val, wrong, config = _recovery_run("cells")
    hist = res.history
    logits = jt.predict_logits(wrong, flat(0.0, 0.05), val, key=jax.random.key(0), chunk=300)
    m = evaluate(jt.sigmoid_np(np.asarray(logits)), val.truth, val.mask, dt=DT)
    (cell0,) = hist[0]["val_cells"]
    assert cell0["f1"] == pytest.approx(m.f1, abs=1e-6)
    assert cell0["ece"] == pytest.approx(m.ece, abs=1e-6)
    assert cell0["fail"] == pytest.approx(m.swing_phase_failure_rate, abs=1e-9)
    assert cell0["touchdown_ms"] == pytest.approx(abs(m.touchdown_delay_ms[0]), abs=1e-6)


def test_select_epoch_passes_over_lower_losses_the_rule_refuses():
    """The selection on a hand-made history (the recovery runs above keep their lowest-loss
    epoch, so they never reach the refusals). Epochs 0-5, val_loss 1.0, 0.8, 0.5, 0.6,
    0.4, 0.79 and val_bce 0.9, 0.8, 0.7, 0.6, 0.5, 0.1, min_delta 0.05; epoch 2's F1 is
    worse than epoch 0's (0.90 < 0.95) and it has a cell worse beyond the spread; epoch 4
    was rejected (feasible directions). Hand selection, in order from epoch 0:
    "loss": 1 (0.8 < 0.95), 2 (0.5 < 0.75), 3 and 5 not below 0.45, 4 rejected -> 2;
    "cells" and "spread": 1, 2 refused, 3 (0.6 < 0.75), 4 rejected, 5 not below 0.55 -> 3;
    "bce": every bce is more than 0.05 below the one kept but 4's (rejected) -> 5."""
    base = dict(f1=0.95, accuracy=0.95, ece=0.01, fail=0.01, touchdown_ms=5.0, liftoff_ms=3.0)
    ok, bad = dict(base, f1=0.96), dict(base, f1=0.90)
    rows = [
        (1.0, 0.9, base, [], False),
        (0.8, 0.8, ok, [], False),
        (0.5, 0.7, bad, ["f1"], False),
        (0.6, 0.6, ok, [], False),
        (0.4, 0.5, ok, [], True),
        (0.79, 0.1, ok, [], False),
    ]
    history = [
        dict(epoch=e, val_loss=loss, val_bce=bce, val_cells=[cells], val_worse=worse, rejected=rej)
        for e, (loss, bce, cells, worse, rej) in enumerate(rows)
    ]
    pick = lambda **kw: jt.select_epoch(history, jt.TuneConfig(min_delta=0.05, **kw))  # noqa: E731
    assert pick(select="loss") == 2
    assert pick(select="cells") == 3
    assert pick(select="spread") == 3
    assert pick(select="bce") == 5
    # Not rejected, epoch 4 (0.4) is more than 0.05 below 2's and 3's and admissible.
    for row in history:
        row["rejected"] = False
    assert pick(select="loss") == pick(select="cells") == pick(select="spread") == 4
    # min_delta 0.25: epoch 1's 0.8 is not below 1.0 - 0.25, so epoch 0 stays.
    assert jt.select_epoch(history[:2], jt.TuneConfig(min_delta=0.25)) == 0


def test_select_spread_refuses_validation_logs_too_small_for_a_call():
    """select="spread" on validation logs of fewer than bootstrap.MIN_ENVS envs kept the
    lowest loss as if no cell were worse: the bootstrap makes no call there ("too few
    envs"). Refused before anything compiles, naming the log and its envs."""
    from jax_contact.bootstrap import MIN_ENVS

    train, val = _synthetic(1, n_t=50, n_envs=8), _synthetic(2, n_t=50, n_envs=MIN_ENVS - 1)
    config = jt.TuneConfig(max_epochs=1, chunk=50, select="spread")
    space, params = jt.make_space(4, fields=("sigma_J",)), _synthetic_params(SIGMA_J_WRONG)
    with pytest.raises(ValueError, match=rf"no call below {MIN_ENVS}.*log 2 of 2 has 4"):
        jt.tune(params, flat(0.0, 0.05), [train], [train, val], space, config)


def test_select_spread_records_the_cells_worse_beyond_the_bootstrap_spread():
    """select="spread" on the recovery problem: every epoch records the validation cells
    worse than epoch 0's beyond a paired env bootstrap (recomputed here for the epoch kept
    from the logits of its parameters and epoch 0's), and the epoch kept has none. Which
    epoch the rule keeps is tested on a hand-made history above."""
    from jax_contact.bootstrap import paired_bootstrap

    res, val, wrong, config = _recovery_run("spread")
    hist = res.history
    assert hist[0]["val_worse"] == []  # epoch 0 against itself
    chosen = hist[res.best_epoch]
    assert chosen["val_worse"] == []
    key = jax.random.fold_in(jax.random.fold_in(jax.random.key(config.seed), 10**6), 0)
    p0, p1 = (
        jt.sigmoid_np(jt.predict_logits(p, flat(0.0, 0.05), val, key=key, chunk=300))
        for p in (wrong, res.params)
    )
    diffs = paired_bootstrap(p0, p1, val.truth, val.mask, dt=DT)
    assert not any(d.verdict == "worse" for d in diffs.values())


def test_validation_cells_read_the_known_truth(np_rng):
    """``TuningData.known`` (a recording's known truth, wider than the mask where a reading
    was lost): the validation cells are ``metrics.evaluate`` with ``truth_known``, so a
    gap inside a swing does not add an air phase; without it, the mask's rule 8."""
    from jax_contact.metrics import evaluate
    from jax_contact.tune.fit import score_logs

    shape = (300, 2, 2)
    truth = np.zeros(shape, bool)
    for t in range(1, shape[0]):  # a Markov truth, switching every ~15 steps
        flip = np_rng.random(shape[1:]) < 1 / 15
        truth[t] = np.where(flip, ~truth[t - 1], truth[t - 1])
    logits = np.where(truth, 2.0, -2.0) + np_rng.normal(0, 2.0, shape)
    known = np.ones(shape, bool)
    mask = known & (np_rng.random(shape) > 0.05)
    data = jt.TuningData(meas=None, truth=truth, mask=mask, known=known)
    cell = score_logs([logits], [data], dt=0.0025, config=jt.TuneConfig())["cells"][0]
    p = 1 / (1 + np.exp(-logits))
    bridged = evaluate(p, truth, mask, dt=0.0025, truth_known=known)
    split = evaluate(p, truth, mask, dt=0.0025)
    # The swing-phase rate (rule 9b, Table III's sw-ph), not the air-phase rate that the
    # truth's short phases dilute (they differ on this truth: some phases last <= 4 steps).
    assert cell["fail"] == bridged.swing_phase_failure_rate != bridged.air_phase_failure_rate
    assert bridged.n_air_phases < split.n_air_phases  # the gaps did cut phases before
    plain = score_logs([logits], [data.replace(known=None)], dt=0.0025, config=jt.TuneConfig())
    assert plain["cells"][0]["fail"] == split.swing_phase_failure_rate


def test_worse_beyond_spread_names_the_cells_a_bootstrap_calls_worse():
    """A candidate that flips the flag on every env's first 40 steps is worse in accuracy
    and F1 beyond the spread (every env pays alike); the reference against itself has no
    cell worse."""
    val = _synthetic(2)
    truth = np.asarray(val.truth, bool)
    good = np.where(truth, 4.0, -4.0).astype(np.float32)
    bad = good.copy()
    bad[:40] *= -1.0
    assert jt.worse_beyond_spread([good], [good], [val], dt=DT) == []
    worse = jt.worse_beyond_spread([bad], [good], [val], dt=DT)
    assert {"log0:accuracy", "log0:f1"} <= set(worse)
    assert jt.worse_beyond_spread([good], [bad], [val], dt=DT) == []  # better, not worse


def test_no_worse_by_hand():
    ref = [dict(f1=0.9, accuracy=0.9, ece=0.02, fail=0.01, touchdown_ms=5.0, liftoff_ms=3.0)]
    assert jt.no_worse(ref, ref)  # ties are no worse
    better = [dict(ref[0], f1=0.95, ece=0.01)]
    assert jt.no_worse(better, ref) and not jt.no_worse(ref, better)
    for key, worse in [
        ("f1", 0.89), ("accuracy", 0.8), ("ece", 0.03), ("fail", 0.02),
        ("touchdown_ms", 5.5), ("liftoff_ms", 3.1),
    ]:  # fmt: skip
        assert not jt.no_worse([dict(better[0], **{key: worse})], ref), key
    # With a tolerance, a cell may be worse by tolerance x CELL_TOLERANCE (0.25 ms here).
    assert jt.no_worse([dict(ref[0], touchdown_ms=5.2)], ref, tolerance=1.0)
    assert not jt.no_worse([dict(ref[0], touchdown_ms=5.3)], ref, tolerance=1.0)
    assert jt.no_worse([dict(ref[0], touchdown_ms=5.3)], ref, tolerance=2.0)
    nan = [dict(ref[0], fail=float("nan"))]  # no air phase: nothing to compare
    assert jt.no_worse(nan, nan) and not jt.no_worse(nan, ref) and not jt.no_worse(ref, nan)
    two = ref + [dict(ref[0], f1=0.5)]
    assert jt.no_worse(better + [dict(ref[0], f1=0.5)], two)
    assert not jt.no_worse(better + [dict(ref[0], f1=0.49)], two)  # one log's cell is enough
    with pytest.raises(ValueError, match="2 validation logs' cells against 1"):
        jt.no_worse(two, ref)


def test_theta_lower_bounds_by_hand():
    """Group multipliers: exp(theta_g) >= max over the group's coordinates of floor/sigma0.
    sigma_qd = (1, 1, 2, 2, 2, 4, 4, 4) in groups (0, 0, 1, 1, 1, 2, 2, 2) with floor
    (0.5, 0.25, 1, 2, 1, 0, 0, 0): group 0 -> log 0.5, group 1 -> log 1 = 0, group 2 -> no
    bound (-inf); sigma_d has no floor."""
    sigma_qd = np.array([1, 1, 2, 2, 2, 4, 4, 4], float)
    base = make_params(make_noise(8, sigma_qd=sigma_qd))
    space = jt.make_space(8, dof_groups=(0, 0, 1, 1, 1, 2, 2, 2))
    floor = {"sigma_qd": np.array([0.5, 0.25, 1, 2, 1, 0, 0, 0], float)}
    lower = jt.theta_lower_bounds(space, base, floor)
    np.testing.assert_allclose(np.asarray(lower["sigma_qd"]), [np.log(0.5), 0.0, -np.inf])
    assert np.all(np.isneginf(np.asarray(lower["sigma_d"])))
    assert np.all(np.isneginf(np.asarray(lower["cap_dynamics"])))
    assert set(lower) == set(jt.init_theta(space, base))
    with pytest.raises(ValueError, match=r"base.noise.sigma_qd\[3\] = 2 lies below its floor 3"):
        jt.theta_lower_bounds(space, base, {"sigma_qd": np.array([0, 0, 0, 3, 0, 0, 0, 0.0])})
    with pytest.raises(ValueError, match="not a noise field"):
        jt.theta_lower_bounds(space, base, {"stance_time": 0.1})
    with pytest.raises(ValueError, match=r"floor\['sigma_qd'\] has shape \(3,\)"):
        jt.theta_lower_bounds(space, base, {"sigma_qd": np.ones(3)})


def test_theta_bounds_box_the_noise_by_hand():
    """noise_ratio r = 4: every noise group in [-log 4, log 4]; a floor above -log 4 wins
    below (group 1's log 0.5; group 0's floor log 0.125 lies outside the box); caps and
    T_s are not boxed; r = 0 is theta_lower_bounds and +inf."""
    sigma_qd = np.array([1, 1, 2, 2, 2, 4, 4, 4], float)
    base = make_params(make_noise(8, sigma_qd=sigma_qd))
    space = jt.make_space(8, dof_groups=(0, 0, 1, 1, 1, 2, 2, 2))
    floor = {"sigma_qd": np.array([0.125, 0, 1, 0, 0, 0, 0, 0], float)}
    lower, upper = jt.theta_bounds(space, base, floor, noise_ratio=4.0)
    l4 = np.log(4.0)
    np.testing.assert_allclose(np.asarray(lower["sigma_qd"]), [-l4, np.log(0.5), -l4], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(upper["sigma_qd"]), [l4, l4, l4], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(lower["sigma_d"]), -l4, rtol=1e-6)
    for f in ("cap_dynamics", "stance_time", "takeoff_accel"):
        assert np.isneginf(np.asarray(lower[f])).all() and np.isposinf(np.asarray(upper[f])).all()
    lower0, upper0 = jt.theta_bounds(space, base, floor)
    np.testing.assert_array_equal(
        np.asarray(lower0["sigma_qd"]),
        np.asarray(jt.theta_lower_bounds(space, base, floor)["sigma_qd"]),
    )
    assert all(np.isposinf(np.asarray(v)).all() for v in upper0.values())
    for bad in (1.0, 0.5, -2.0, np.inf):
        with pytest.raises(ValueError, match="noise_ratio"):
            jt.theta_bounds(space, base, None, noise_ratio=bad)
        with pytest.raises(ValueError, match="noise_ratio"):
            jt.TuneConfig(noise_ratio=bad)


# ----------------------------------------------------------------------- cheap checks


def test_init_theta_maps_back_to_the_base_params():
    base = make_params(make_noise(8), cap_transition=0.9, cap_diff_kinematics_still=0.75)
    space = jt.make_space(8, dof_groups=(0, 0, 1, 1, 1, 2, 2, 2))
    back = jt.to_params(space, base, jt.init_theta(space, base))
    for a, b in zip(jax.tree.leaves(back), jax.tree.leaves(base), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
    # A log multiplier of log 2 doubles every std of its group and no other.
    theta = jt.init_theta(space, base)
    theta["sigma_d"] = theta["sigma_d"].at[1].set(np.log(2.0))
    got = np.asarray(jt.to_params(space, base, theta).noise.sigma_d)
    np.testing.assert_allclose(got / np.asarray(base.noise.sigma_d), [1, 1, 2, 2, 2, 1, 1, 1],
                               rtol=1e-6)  # fmt: skip


def test_contact_damping_is_tuned_in_log_space_only_when_asked():
    base = make_params(make_noise(8), contact_damping=100.0)
    assert "contact_damping" not in jt.DEFAULT_FIELDS
    space = jt.make_space(8, fields=jt.DEFAULT_FIELDS + ("contact_damping",))
    theta = jt.init_theta(space, base)
    np.testing.assert_allclose(float(theta["contact_damping"]), np.log(100.0), rtol=1e-6)
    # theta + log 2 doubles b: b = b0 exp(theta - theta0), like a_F.
    theta["contact_damping"] = theta["contact_damping"] + np.log(2.0)
    np.testing.assert_allclose(float(jt.to_params(space, base, theta).contact_damping), 200.0,
                               rtol=1e-5)  # fmt: skip
    # The rigid contact (b = 0) has no log: refused, naming the field.
    with pytest.raises(ValueError, match="contact_damping = 0.0 cannot be tuned in log space"):
        jt.init_theta(space, base.replace(contact_damping=jnp.float32(0.0)))
    with pytest.raises(ValueError, match="fields must be distinct names"):
        jt.make_space(8, fields=("contact_damping", "no_such_field"))


def test_caps_stay_in_their_interval():
    """A cap is tuned in logit space over (0.5, 1): cap = 0.5 + 0.5 sigmoid(z), so z = 0
    gives 0.75, z = +-30 the interval's ends (sigmoid(30) = 1 - 9.4e-14), z = 2 gives
    0.5 + 0.5 / (1 + e^-2) = 0.940399."""
    base = make_params(make_noise(3))
    space = jt.make_space(3, fields=("cap_dynamics",))

    def cap(z):
        return float(jt.to_params(space, base, {"cap_dynamics": jnp.float32(z)}).cap_dynamics)

    assert cap(0.0) == pytest.approx(0.75, abs=1e-7)
    assert cap(2.0) == pytest.approx(0.940399, abs=1e-6)
    assert cap(-30.0) == pytest.approx(0.5, abs=1e-7)
    assert cap(30.0) == pytest.approx(1.0, abs=1e-7)


def test_robot_space_groups_go1_like():
    desc = dataclasses.make_dataclass("Desc", ["nv", "nq", "base_dofs", "leg_dofs"])(
        18, 19, tuple(range(6)), tuple(tuple(range(6 + 3 * i, 9 + 3 * i)) for i in range(4))
    )
    space = jt.robot_space(desc)
    assert space.group_names == ("base_linear", "base_rotational", "joint0", "joint1", "joint2")
    assert space.dof_groups == (0, 0, 0, 1, 1, 1) + (2, 3, 4) * 4


def test_fit_calibration_recovers_temperature_and_bias(np_rng):
    # Truth drawn from sigmoid(l / T + c) with T = 2, c = -0.5: maximum likelihood on 2e5
    # samples recovers both to ~1e-2 (standard errors ~5e-3).
    logits = np_rng.normal(scale=4.0, size=200_000)
    p = 1.0 / (1.0 + np.exp(-(logits / 2.0 - 0.5)))
    truth = np_rng.random(p.shape) < p
    cal = jt.fit_calibration(logits, truth, np.ones_like(truth), kind="affine")
    assert cal.temperature == pytest.approx(2.0, abs=0.05)
    assert cal.bias == pytest.approx(-0.5, abs=0.03)
    assert jt.Calibration.from_dict(cal.as_dict()) == cal
    got = jt.apply_calibration(np.array([2.0]), cal)
    np.testing.assert_allclose(got, 2.0 / cal.temperature + cal.bias)
    assert cal.kind == "affine" and not cal.keeps_decisions


def test_fit_calibration_refuses_what_is_not_logits(np_rng):
    """P(contact) (what replay and the diagnostics return) passed as logits put every step
    on the contact side and fitted a map to the wrong quantity without a word; a NaN logit
    made the affine fit return the identity; arrays of different shapes failed in NumPy's
    boolean indexing."""
    logits = np_rng.normal(scale=4.0, size=1000)
    truth = np_rng.random(logits.shape) < 1 / (1 + np.exp(-logits))
    mask = np.ones_like(truth)
    p = 1 / (1 + np.exp(-logits))
    with pytest.raises(ValueError, match=r"logits: every masked value lies in \[0, 1\]"):
        jt.fit_calibration(p, truth, mask)
    bad = logits.copy()
    bad[3] = np.nan
    for kind in ("sign", "affine"):
        with pytest.raises(ValueError, match=r"logits: 1 masked steps are not finite"):
            jt.fit_calibration(bad, truth, mask, kind=kind)
    masked = mask.copy()
    masked[3] = False
    jt.fit_calibration(bad, truth, masked)  # left out of the mask: fitted
    with pytest.raises(ValueError, match=r"one shape, got .*'mask': \(999,\)"):
        jt.fit_calibration(logits, truth, mask[:-1])
    # Truth or mask values that are not 0/1 were read as True (a NaN label moved the air
    # side's temperature from 0.97 to 1.79 in a helper's audit); a truth value outside
    # the mask is not read.
    soft = truth.astype(float)
    soft[5] = np.nan
    with pytest.raises(ValueError, match=r"truth must be bool or hold only 0 and 1"):
        jt.fit_calibration(logits, soft, mask)
    with pytest.raises(ValueError, match=r"truth must be bool or hold only 0 and 1"):
        jt.fit_calibration(logits, truth * 0.3, mask)
    masked = mask.copy()
    masked[5] = False
    jt.fit_calibration(logits, soft, masked)
    with pytest.raises(ValueError, match=r"mask must be bool or hold only 0 and 1"):
        jt.fit_calibration(logits, truth, np.full(truth.shape, 0.5))
    with pytest.raises(ValueError, match=r"iterations must be an int >= 1, got -1"):
        jt.fit_calibration(logits, truth, mask, iterations=-1)  # returned the identity


def test_fit_calibration_per_side_recovers_both_temperatures_and_keeps_every_sign(np_rng):
    # Truth drawn from sigmoid(l / 0.7) where l > 0 and sigmoid(l / 2.5) where l <= 0 (an
    # under-confident contact side, an over-confident air side, as on the validation logs
    # of docs/tuning.md rule 14): each side's one-parameter maximum likelihood on ~1e5
    # samples recovers its temperature to ~2 %.
    logits = np_rng.normal(scale=4.0, size=200_000)
    t_true = np.where(logits > 0, 0.7, 2.5)
    truth = np_rng.random(logits.shape) < 1.0 / (1.0 + np.exp(-logits / t_true))
    cal = jt.fit_calibration(logits, truth, np.ones_like(truth))  # kind="sign", the default
    assert cal.kind == "sign" and cal.keeps_decisions and cal.bias == 0.0
    assert cal.temperature == pytest.approx(0.7, rel=0.03)
    assert cal.temperature_air == pytest.approx(2.5, rel=0.03)
    mapped = jt.apply_calibration(logits, cal)
    np.testing.assert_array_equal(mapped > 0, logits > 0)  # no decision at 0.5 moves
    side_t = np.where(logits > 0, cal.temperature, cal.temperature_air)
    np.testing.assert_allclose(mapped, logits / side_t)
    # The same map on a JAX array (traced inside the filter's consumers), and on P.
    np.testing.assert_allclose(
        np.asarray(jt.apply_calibration(jnp.asarray(logits[:100], jnp.float32), cal)),
        mapped[:100], rtol=1e-5,
    )  # fmt: skip
    p = jt.calibrate_probability(np.array([0.3, 0.5, 0.9]), cal)
    l_03, l_09 = np.log(0.3 / 0.7), np.log(0.9 / 0.1)
    np.testing.assert_allclose(
        p, 1 / (1 + np.exp(-np.array([l_03 / cal.temperature_air, 0.0, l_09 / cal.temperature])))
    )
    with warnings.catch_warnings():  # a lost P stays NaN, without a RuntimeWarning
        warnings.simplefilter("error")
        lost = jt.calibrate_probability(np.array([np.nan, 0.3]), cal)
    assert np.isnan(lost[0]) and lost[1] == pytest.approx(p[0])
    # Round trip, files of the affine map before (no kind, no temperature_air), errors.
    assert jt.Calibration.from_dict(cal.as_dict()) == cal
    old = jt.Calibration.from_dict({"temperature": 2.0, "bias": 0.7})
    assert old.kind == "affine" and old.temperature_air is None
    with pytest.raises(ValueError, match="kind 'sign' does not match its fields"):
        jt.Calibration.from_dict({"kind": "sign", "temperature": 2.0, "bias": 0.0})
    with pytest.raises(ValueError, match="has no bias"):
        jt.Calibration(temperature=1.0, bias=0.5, temperature_air=2.0)
    with pytest.raises(
        ValueError, match=r"temperature_air must be a finite number in \[0.001, 1000\]"
    ):
        jt.Calibration(temperature_air=0.0)
    # A temperature of 1e-40 overflowed 1 / T in float32 and gave P = NaN; a typo in a
    # hand-edited map's field made it affine; a string was read as a number; a logit
    # passed as P came back as a confident P (a helper's audit).
    with pytest.raises(ValueError, match=r"temperature must be a finite number in"):
        jt.Calibration(temperature=1e-40)
    with pytest.raises(ValueError, match=r"unknown field 'tempreature_air'; did you mean"):
        jt.Calibration.from_dict({"temperature": 1.2, "tempreature_air": 0.8})
    with pytest.raises(ValueError, match=r"calibration.temperature must be a number, got '2'"):
        jt.Calibration.from_dict({"temperature": "2"})
    noted = {**cal.as_dict(), "fitted_on": ["a.h5"]}  # a file's notes beside the map
    assert jt.Calibration.from_dict(noted) == cal
    with pytest.raises(ValueError, match=r"p must lie in \[0, 1\] .*not logits.* e\.g\. 3\.2"):
        jt.calibrate_probability(np.array([0.5, 3.2]), cal)
    with pytest.raises(ValueError, match="kind must be one of"):
        jt.fit_calibration(logits, truth, np.ones_like(truth), kind="isotonic")
    # A side that is never wrong has no finite maximum: its temperature stops at 0.05.
    sep = jt.fit_calibration(np.array([1.0, 2.0, -1.0, -2.0]), np.array([1, 1, 0, 1]), np.ones(4))
    assert sep.temperature == pytest.approx(0.05)
    # ... which `tune --calibrate` warns of (a user trial's 50-step fit ended on both
    # bounds without a word); the fit above on 2e5 steps is on neither.
    from jax_contact.tune.calibration import sides_on_bounds

    # The air side's steps (-1 right, -2 wrong) have their BCE falling as a = 1/T -> 0
    # (its slope at a = 0 is mean((0.5 - y) x) = +0.25), so T stops at 20: both sides.
    assert sep.temperature_air == pytest.approx(20.0)
    assert sides_on_bounds(sep) == ["P > 0.5", "P < 0.5"] and sides_on_bounds(cal) == []
    assert sides_on_bounds(jt.Calibration(temperature=2.0, bias=0.5)) == []  # affine: unbounded


def test_load_calibration_reads_a_files_map_and_probability_applies_it(tmp_path):
    """jc.load_calibration: a preset's map is the one in its JSON (read here with json),
    a file without one gives None, a malformed one is refused naming the field; the JAX
    probability() of a logit is sigmoid(l / T_c) for l > 0 and sigmoid(l / T_a) else,
    computed here in float64 NumPy."""
    import json
    from importlib import resources

    import jax_contact as jc
    from jax_contact.calibration import probability

    shipped = json.loads((resources.files("jax_contact") / "presets" / "spot.json").read_text())
    want = shipped["provenance"]["calibration"]
    cal = jc.load_calibration("spot")
    assert (cal.temperature, cal.temperature_air) == (want["temperature"], want["temperature_air"])
    params = jc.load_params("spot")
    jc.save_params(tmp_path / "none.json", params, {"tool": "by hand"})
    assert jc.load_calibration(tmp_path / "none.json") is None
    # Edited by hand after writing (save_params refuses to write such a map).
    bad = json.loads(jc.save_params(tmp_path / "bad.json", params).read_text())
    bad["provenance"] = {"calibration": {"temperature": -1.0}}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="bad.json.*'calibration'.*temperature must be"):
        jc.load_calibration(tmp_path / "bad.json")
    logits = np.array([-30.0, -2.0, 0.0, 0.5, 12.0])
    scaled = np.where(logits > 0, logits / cal.temperature, logits / cal.temperature_air)
    np.testing.assert_allclose(
        np.asarray(probability(jnp.asarray(logits, jnp.float32), cal)),
        1.0 / (1.0 + np.exp(-scaled)), rtol=2e-6, atol=1e-12,
    )  # fmt: skip
    np.testing.assert_allclose(
        np.asarray(probability(jnp.asarray(logits, jnp.float32))),
        1.0 / (1.0 + np.exp(-logits)), rtol=2e-6, atol=1e-12,
    )  # fmt: skip


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="learning_rate"):
        jt.TuneConfig(learning_rate=0.0)
    with pytest.raises(ValueError, match="chunk"):
        jt.TuneConfig(chunk=0)
    with pytest.raises(ValueError, match="fields"):
        jt.make_space(3, fields=("dt",))


def test_tune_cmd_field_list_is_the_librarys():
    import argparse

    from jax_contact.train import log_estimator, tune_cmd

    assert tune_cmd.DEFAULT_FIELDS == jt.DEFAULT_FIELDS
    assert tune_cmd.OPTIONAL_FIELDS == jt.OPTIONAL_FIELDS
    p = tune_cmd.add_parser(argparse.ArgumentParser().add_subparsers())
    choices = {a.dest: a.choices for a in p._actions if a.choices}
    assert tuple(choices["select"]) == jt.SELECT_RULES
    assert tuple(choices["terrain_model"]) == log_estimator.TERRAIN_MODELS
    assert tuple(choices["tune_also"]) == jt.OPTIONAL_FIELDS


def test_tune_cmd_checks_arguments_without_jax(tmp_path):
    log = tmp_path / "a.h5"
    log.write_bytes(b"")
    code = (
        "import sys, jax_contact.train.tune_cmd as t, argparse\n"
        "assert 'jax' not in sys.modules\n"
        "p = argparse.ArgumentParser(); s = p.add_subparsers(); t.add_parser(s)\n"
        f"a = p.parse_args(['tune', {str(log)!r}, '--validate', {str(log)!r}, '--out', 'x.json'])\n"
        "try:\n    a.check(a)\nexcept ValueError as e:\n    print(e)\n"
        f"a = p.parse_args(['tune', {str(log)!r}, '--validate', 'missing.h5', '--out', 'x.json'])\n"
        "try:\n    a.check(a)\nexcept ValueError as e:\n    print(e)\n"
        f"a = p.parse_args(['tune', {str(log)!r}, '--validate', {str(log)!r} + '.h5', '--out',"
        " 'x.json', '--noise-ratio', '1'])\n"
        "a.logs = []; a.validate = []\n"  # only the ratio left to refuse
        "try:\n    a.check(a)\nexcept ValueError as e:\n    print(e)\n"
        "assert 'jax' not in sys.modules\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "also a tuning log" in out.stdout
    assert "--validate" in out.stdout and "does not exist" in out.stdout
    assert "argument --noise-ratio: must be 0 (no box) or > 1, got 1" in out.stdout


def test_reliability_bins_agree_with_metrics_ece_and_the_png_is_written(np_rng, tmp_path):
    from jax_contact.metrics import expected_calibration_error
    from jax_contact.train.calibration import reliability_bins, reliability_diagram

    p = np_rng.random((50, 2, 4))
    truth = np_rng.random(p.shape) < p**2  # over-confident in contact
    valid = np_rng.random((50, 2)) < 0.9
    v3 = np.broadcast_to(valid[..., None], p.shape)
    b = reliability_bins(p, truth, v3)
    assert float(b["ece"]) == pytest.approx(expected_calibration_error(p, truth, v3), abs=1e-12)
    assert b["count"].sum() == v3.sum()
    # A (T, E) mask of a (T, E, L) batch is broadcast over the legs, as the docstring says.
    b2 = reliability_bins(p, truth, valid)
    assert np.array_equal(b2["count"], b["count"]) and float(b2["ece"]) == float(b["ece"])
    with pytest.raises(ValueError, match=r"valid has shape \(50, 3\); expected \(50, 2, 4\)"):
        reliability_bins(p, truth, np.ones((50, 3), bool))
    # The diagram's points give the same number: sum_b n_b |freq_b - mean_p_b| / N.
    keep = b["count"] > 0
    gaps = b["count"][keep] * np.abs(b["freq"][keep] - b["mean_p"][keep])
    assert float(b["ece"]) == pytest.approx(gaps.sum() / v3.sum(), abs=1e-12)
    out = reliability_diagram({"a": p, "b": np.sqrt(p), "a/diag": p}, truth, valid,
                              tmp_path / "fig" / "rel.png", title="test")  # fmt: skip
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Bad outputs are named, nothing drawn (a NaN failed inside NumPy's bincount, a P of 3
    # was drawn, a short array blamed valid's shape).
    bad = tmp_path / "bad.png"
    reliability_diagram({"a": np.where(v3, p, np.nan)}, truth, valid, bad)  # NaN where invalid
    bad.unlink()
    nan = p.copy()
    nan.reshape(-1)[np.flatnonzero(v3)[0]] = np.nan  # one NaN on a valid step
    for outputs, match in (
        ({"a": nan}, r"^outputs\['a'\]: estimate holds NaN or inf at valid"),
        ({"b": 3 * p}, r"^outputs\['b'\]: estimate must lie in \[0, 1\]"),
        ({"c": p[:10]}, r"^outputs\['c'\]: truth has shape \(50, 2, 4\), but prob has shape"),
    ):
        with pytest.raises(ValueError, match=match):
            reliability_diagram(outputs, truth, valid, bad)
        assert not bad.exists()


@pytest.mark.parametrize(
    "name", ["go1", "spot", "barkour", "spot_walk", "barkour_trot", "barkour_walk", "go1_walk"]
)
def test_shipped_presets_load_by_name_with_their_provenance(name):
    import jax_contact as jc
    from jax_contact.train.tune_presets import preset_plan

    assert name in jc.preset_names()
    params, prov = jc.load_params(name, with_provenance=True)
    assert float(params.dt) == pytest.approx(0.0025)
    robot, tune_keys, val_keys = preset_plan(name)
    assert prov["robot"] == robot
    # Tuned and validated on the logs regenerate_preset names (spot_walk: the walk's only).
    for infos, keys in ((prov["logs"], tune_keys), (prov["validation"], val_keys)):
        names = [i["path"].rsplit("/", 1)[-1] for i in infos]
        assert names == [f"{robot}_{scenario}_s{seed}.h5" for scenario, seed in keys]
    # Tuned and validated on seeds that are never evaluated (the evaluation seed is 0).
    seeds = prov["seeds"]["tuning_logs"] + prov["seeds"]["validation_logs"]
    assert seeds and all(s >= 1000 for s in seeds)
    assert {"temperature", "bias"} <= set(prov["calibration"])
    # Its map keeps every decision at 0.5 (rule 14 of docs/tuning.md: one temperature per side).
    assert jt.calibration_of(prov).keeps_decisions and prov["calibration"]["kind"] == "sign"
    assert prov["library_version"] and prov["history"]
    # The prior keeps every std within a factor 8 of its derived value (docs/tuning.md says
    # which tuned values are not physically plausible: Barkour's base position std, 5x).
    ratios = [r["ratio"] for r in prov["tuned_vs_default"] if r["field"].startswith("sigma")]
    box = jt.PLAUSIBLE_NOISE_RATIO
    assert all(1 / box <= r <= box for r in ratios), ratios
    # T_s stays a stance duration (jax_contact.tune's bounds), the loss has the event term,
    # and the file names the commit it was tuned at.
    lo, hi = prov["stance_time_bounds"]
    assert (lo, hi) == jt.STANCE_TIME_BOUNDS and lo <= float(params.stance_time) <= hi
    assert prov["config"]["event_weight"] > 0 and "air phases" in prov["loss"]
    assert len(prov["code"]["commit"]) == 40
    # The weight and optional fields the file was tuned with are the ones regenerate_preset
    # passes, and a tuned contact damping stays a foot settling in 5-100 ms (2 / b).
    from jax_contact.train.tune_presets import PRESET_EVENT_WEIGHTS, PRESET_TUNE_ALSO

    assert prov["config"]["event_weight"] == pytest.approx(PRESET_EVENT_WEIGHTS[robot])
    also = [f for f in prov["fields"] if f in jt.OPTIONAL_FIELDS]
    assert also == list(PRESET_TUNE_ALSO.get(robot, ()))
    # ... and so are the extra arguments (Spot's selection on the spread, rule 12).
    from jax_contact.train.tune_presets import PRESET_EXTRA

    extra = PRESET_EXTRA.get(robot, ())
    args = prov["arguments"]
    for flag, value in zip(extra[::2], extra[1::2], strict=True):
        assert str(args[flag.lstrip("-").replace("-", "_")]) == value, flag
    assert args["select"] == ("spread" if "--select" in extra else "loss")
    if "contact_damping" in also:
        assert 20.0 <= float(params.contact_damping) <= 400.0
    else:
        assert float(params.contact_damping) == pytest.approx(100.0)  # params_for's 2 / 20 ms
    # The sliding contact is not tuned: a file tuned with it holds params_for's values, and
    # a file tuned before it (no such field) loads with the still foot it was tuned with.
    from importlib import resources

    from jax_contact.defaults import SLIP_PROB, SLIP_SPEED

    shipped = resources.files("jax_contact") / "presets" / f"{name}.json"
    values = json.loads(shipped.read_text())["values"]
    assert "slip_prob" not in prov["fields"] and "slip_speed" not in prov["fields"]
    if "slip_prob" in values:
        assert float(params.slip_prob) == pytest.approx(SLIP_PROB)
        assert float(params.slip_speed) == pytest.approx(SLIP_SPEED)
    else:
        assert float(params.slip_prob) == 0.0
    # Tuned with the sensor floor: no std below what the anymal_like sensors alone give,
    # recomputed here from the sensor model (not read from the file).
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.tune_data import sensor_floor

    floor = sensor_floor(load_robot(robot), 0.0025, "anymal_like")
    assert prov["noise_floor"] is not None
    for field, values in floor.items():
        got = np.asarray(getattr(params.noise, field))
        assert np.all(got >= values * (1 - 1e-5)), (field, got / values)


@pytest.mark.parametrize("robot", ["planar_leg", "go1"])
def test_tunes_start_and_floor_read_one_sensor_model(robot):
    """``tune`` on a simulated log starts from ``tune_data.default_params`` and bounds the
    stds by ``tune_data.sensor_floor``, both for the log's sensor preset. They used to read
    different ones (the start kept ``anymal_like`` on the planar leg), so a planar-leg log
    of ``harsh`` sensors was refused: 'base.noise.sigma_q[1] = 0.02 lies below its floor
    0.04'. The bound's own check (``theta_lower_bounds``) now passes for every preset, and
    the start's joint stds are the preset's (``harsh`` doubles ``anymal_like``'s joint
    noise, envs/sensors.py)."""
    from jax_contact.envs.robots import load_robot
    from jax_contact.envs.sensors import PRESETS
    from jax_contact.train.tune_data import default_params, sensor_floor

    r = load_robot(robot)
    space = jt.make_space(r.description.nv, fields=jt.NOISE_FIELDS)
    start = {}
    for noise in PRESETS:
        params, _ = default_params(r, 0.0025, noise)
        jt.theta_lower_bounds(space, params, sensor_floor(r, 0.0025, noise))  # raises if below
        start[noise] = params
    joint = np.asarray(r.description.leg_dofs).reshape(-1)
    ratio = (
        np.asarray(start["harsh"].noise.sigma_q)[joint]
        / np.asarray(start["anymal_like"].noise.sigma_q)[joint]
    )
    np.testing.assert_allclose(ratio, 2.0, rtol=0.05)


def test_fit_calibration_stays_finite_when_logits_sit_at_their_bounds(np_rng):
    # Most logits at +-30 (a capped, confident filter) and a few mistakes among them: a
    # plain Newton step from the identity overshot to T ~ 0 here; the line search keeps
    # the fit a descent to a finite map.
    y = np_rng.random(50_000) < 0.6
    logits = np.where(y, 30.0, -30.0) + np_rng.normal(scale=0.5, size=y.shape)
    flip = np_rng.random(y.shape) < 0.01
    y = y ^ flip
    mid = np_rng.random(y.shape) < 0.05
    logits[mid] = np_rng.normal(scale=2.0, size=mid.sum())
    cal = jt.fit_calibration(logits, y, np.ones_like(y), kind="affine")
    assert np.isfinite(cal.temperature) and 0.5 < cal.temperature < 100
    assert np.isfinite(cal.bias) and abs(cal.bias) < 10


# ------------------------------------------------------------- the air-phase event term


def _event_oracle(logits, truth, mask, early, tau):
    """Float64 loops over columns and phases: (scored mask, sum of costs, phases)."""
    l2 = np.asarray(logits, np.float64).reshape(len(logits), -1)
    y2 = np.asarray(truth, bool).reshape(l2.shape)
    m2 = np.asarray(mask, bool).reshape(l2.shape)
    scored = np.zeros(l2.shape, bool)
    total, phases = 0.0, 0
    n_t = l2.shape[0]
    for c in range(l2.shape[1]):
        air = m2[:, c] & ~y2[:, c]
        on = l2[:, c] > 0
        t = 0
        while t < n_t:
            if not air[t]:
                t += 1
                continue
            a = t
            while t < n_t and air[t]:
                t += 1
            b = t  # the phase is [a, b)
            phases += 1
            col = l2[:, c]
            prev = np.concatenate([col[:1], col[:-1]])  # the previous step's logit
            drop = next((k for k in range(a, b) if not on[k]), None)
            settle = None
            if drop is not None:
                settle = next((k for k in range(drop, b) if col[k] >= prev[k]), None)
            keep = set(range(settle, b)) if settle is not None else set()
            t0 = b if b < n_t and m2[b, c] and y2[b, c] else None
            if t0 is not None:  # the run into the touch-down: flagged, or rising to the next
                k = t0 - 1
                while k >= a and t0 - k <= early:
                    into = on[k + 1] if on[k] else l2[k, c] <= l2[k + 1, c]
                    if not into:
                        break
                    keep.discard(k)
                    k -= 1
            for k in keep:
                scored[k, c] = True
            if keep:
                x = np.array([l2[k, c] for k in sorted(keep)]) / tau
                e = tau * (x.max() + np.log(np.sum(np.exp(x - x.max()))))
                total += np.logaddexp(0.0, e)
    return scored.reshape(np.shape(logits)), total, phases


def _event_data(truth, mask, early):
    d = jt.TuningData(meas=None, truth=np.asarray(truth), mask=np.asarray(mask))
    return jt.with_air_phases(d, early)


def test_event_term_on_a_hand_example(x64):
    # One foot: stance, air at t = 2..8, touch-down at t0 = 9; early window 2 steps.
    #   t:      0  1  2   3   4   5    6    7    8   9  10
    #   logit:  3  3  2  -1  -2  1.5  -2  -1.5  0.5  3  3
    # t = 2 is the stance's flag carried into the air, t = 3-4 its fall: not scored (the
    # lift-off delay). t = 8 is flagged and so is t0: the detection; t = 7 (in the early
    # window, below t = 8) rises into it: not scored either. Scored: t = 5 (the blip, the
    # one failure) and t = 6. With tau = 0.5
    #   E = 0.5 log(e^3 + e^-4) = 1.5 + 0.5 log(1 + e^-7),  cost = softplus(E).
    _assert_hand_example(_event_data(HAND_TRUTH, np.ones_like(HAND_TRUTH), 2))
    # The library's metrics see exactly this one failure in the phase.
    from jax_contact.metrics import evaluate

    m = evaluate(jt.sigmoid_np(HAND_LOGIT), HAND_TRUTH, None, dt=0.0025, early_window_s=0.005)
    assert (m.failures, m.air_phases_with_failure, m.n_air_phases) == (1, 1, 1)


HAND_TRUTH = np.array([1, 1, 0, 0, 0, 0, 0, 0, 0, 1, 1], bool)[:, None, None]
HAND_LOGIT = np.array([3, 3, 2, -1, -2, 1.5, -2, -1.5, 0.5, 3, 3], np.float64)[:, None, None]


def _assert_hand_example(data):
    """The hand example's scored steps (t = 5, 6), cost and one air phase."""
    logit = jnp.asarray(HAND_LOGIT)
    scored = np.asarray(jt.scored_air_steps(logit, data))[:, 0, 0]
    np.testing.assert_array_equal(np.flatnonzero(scored), [5, 6])
    total, n = jt.air_event_terms(logit, data, 0.5)
    e = 1.5 + 0.5 * np.log1p(np.exp(-7.0))
    assert float(total) == pytest.approx(np.logaddexp(0.0, e), abs=1e-12)
    assert int(n) == 1


def test_event_term_reads_a_lost_step_of_known_truth_as_part_of_its_phase(x64):
    """The hand example above with the reading at t = 4 lost (mask false, truth known: a
    recording's NaN). By hand, as metrics rules 7b and 8 read it: still one air phase, the
    fall's t = 4 unscored anyway, the blip at t = 5 a false contact: scored t = 5, 6 and
    the same cost. Read through the mask alone, the lost step splits the phase in two and
    the blip, now the first step of the second, counts as the stance's flag carried in:
    the failure went unpenalised (the tuner's loss before the fortieth session)."""
    mask = np.ones_like(HAND_TRUTH)
    mask[4] = False
    known = np.ones_like(HAND_TRUTH)
    d = jt.TuningData(meas=None, truth=HAND_TRUTH, mask=mask, known=known)
    _assert_hand_example(jt.with_air_phases(d, 2))
    split, logit = _event_data(HAND_TRUTH, mask, 2), jnp.asarray(HAND_LOGIT)
    assert int(jt.air_event_terms(logit, split, 0.5)[1]) == 2
    assert 5 not in np.flatnonzero(np.asarray(jt.scored_air_steps(logit, split)))


EVENT_TOL = 1e-10  # float64 against the loop oracle: sums of a few exponentials


def test_event_term_matches_a_loop_oracle(x64, np_rng):
    n_t, e, legs, early, tau = 80, 2, 3, 3, 0.5
    truth = np.zeros((n_t, e, legs), bool)
    s = np_rng.random((e, legs)) < 0.5
    for t in range(n_t):  # Markov phases of ~8 steps
        s = np.where(np_rng.random((e, legs)) < 0.12, ~s, s)
        truth[t] = s
    mask = np.broadcast_to((np_rng.random((n_t, e)) > 0.03)[..., None], truth.shape)
    # Logits that cross 0 often: a random walk around the truth's side.
    logit = np.where(truth, 2.0, -2.0) + np.cumsum(np_rng.normal(size=truth.shape), 0) * 0.6
    data = _event_data(truth, mask, early)
    want_scored, want_total, want_n = _event_oracle(logit, truth, mask, early, tau)
    assert 10 < want_scored.sum() < (mask & ~truth).sum()  # neither empty nor everything
    got_scored = np.asarray(jt.scored_air_steps(jnp.asarray(logit), data))
    np.testing.assert_array_equal(got_scored, want_scored)
    total, n = jt.air_event_terms(jnp.asarray(logit), data, tau)
    assert int(n) == want_n
    assert abs(float(total) - want_total) <= EVENT_TOL * max(1.0, want_total)
    # jit gives the same, and windows see the same phases as the whole log (no phase is
    # cut here: the window is the log).
    jitted = jax.jit(jt.air_event_terms, static_argnames="temperature")
    assert float(jitted(jnp.asarray(logit), data, temperature=tau)[0]) == pytest.approx(
        float(total), rel=1e-12
    )


def _grad_matches_central_differences(f, x) -> np.ndarray:
    """Asserts jax.grad(f)(x) equals the central differences of f at x within GRAD_TOL;
    returns the gradient, flat."""
    g = np.asarray(jax.grad(f)(x)).reshape(-1)
    fd = np.zeros_like(g)
    for i in range(g.size):
        e = jnp.zeros(g.size).at[i].set(GRAD_H).reshape(x.shape)
        fd[i] = (float(f(x + e)) - float(f(x - e))) / (2 * GRAD_H)
    atol, rtol = GRAD_TOL
    np.testing.assert_allclose(g, fd, atol=atol, rtol=rtol)
    return g


def _crossing_problem(np_rng, n_t: int = 40, early: int = 3):
    """Logits (T, 1, 2) around the truth's side that cross 0 often (alternating phases of
    8 steps), float64, with the data's AirPhases."""
    truth = (np.arange(n_t)[:, None, None] // 8) % 2 == 0
    truth = np.broadcast_to(truth, (n_t, 1, 2)).copy()
    logit = np.where(truth, 2.0, -2.0) + np_rng.normal(scale=1.5, size=truth.shape)
    return jnp.asarray(logit), _event_data(truth, np.ones_like(truth), early)


def test_event_term_gradient_in_the_logits_matches_central_differences(x64, np_rng):
    # The term alone on a random problem whose logits cross 0 often (every scored step has
    # a gradient); the set of scored steps does not change within +-GRAD_H.
    tau = 0.25
    x, data = _crossing_problem(np_rng)
    f = jax.jit(lambda x: jt.air_event_terms(x, data, tau)[0])
    g = _grad_matches_central_differences(f, x)
    scored = np.asarray(jt.scored_air_steps(x, data)).reshape(-1)
    assert np.all(g[~scored] == 0.0) and np.sum(np.abs(g[scored]) > 1e-4) >= 5


def test_event_term_gradient_is_finite_where_no_step_is_scored(x64):
    # All contact: no air phase, nothing scored; the term and its gradient are exactly 0,
    # without NaN from the empty segments.
    truth = np.ones((6, 1, 2), bool)
    data = _event_data(truth, np.ones_like(truth), 2)
    f = lambda x: jt.air_event_terms(x, data, 0.5)[0]  # noqa: E731
    g = jax.grad(f)(jnp.linspace(-3.0, 3.0, 12).reshape(6, 1, 2))
    assert float(f(jnp.zeros((6, 1, 2)))) == 0.0
    assert np.all(np.asarray(g) == 0.0)


def test_stance_time_stays_in_its_bounds():
    base = make_params(make_noise(3), stance_time=0.3)
    space = jt.make_space(3, fields=("stance_time",), stance_time_bounds=(0.15, 1.2))
    th = jt.init_theta(space, base)
    assert float(jt.to_params(space, base, th).stance_time) == pytest.approx(0.3, rel=1e-6)
    for z in (-30.0, 30.0):
        ts = float(jt.to_params(space, base, {"stance_time": jnp.float32(z)}).stance_time)
        assert 0.15 <= ts <= 1.2
    with pytest.raises(ValueError, match="outside the tuning bounds"):
        jt.init_theta(jt.make_space(3, fields=("stance_time",), stance_time_bounds=(0.4, 1.0)),
                      base)  # fmt: skip


def test_padded_window_holds_no_phase_or_touch_down():
    # The last window of a log is padded with copies of its last step: the copies are
    # masked and carry no phase start or touch-down, so they add no air phase.
    truth = np.zeros((7, 1, 1), bool)
    truth[5:] = True  # a touch-down at t = 5
    d = jt.with_air_phases(
        jt.TuningData(meas={"x": np.zeros((7, 1))}, truth=truth, mask=np.ones_like(truth)), 2
    )
    w = jt.loss._window(d, 4, 5)  # steps 4..6 and two copies of step 6
    assert np.asarray(w.mask)[:, 0, 0].tolist() == [True] * 3 + [False] * 2
    assert np.asarray(w.events.td_step)[:, 0, 0].tolist() == [False, True, False, False, False]
    assert not np.asarray(w.events.start)[3:].any()
    # A window longer than the log is the whole log, not 10**8 padded steps.
    whole = jt.loss._window(d, 0, 10**8)
    assert np.asarray(whole.mask).shape == (7, 1, 1) and np.asarray(whole.mask).all()
    assert np.array_equal(np.asarray(whole.events.td_step), np.asarray(d.events.td_step))


# ------------------------------------------------------------ the cells in the objective


def test_cell_surrogates_on_a_hand_example(x64):
    # One foot, early window 2 steps:
    #   t:      0  1  2   3   4   5   6   7  8  9  10
    #   truth:  1  1  0   0   0   0   0   1  1  1  1
    #   logit:  3  3  1  -1  -3  -3  -1  -1  2  3  3
    # Lift-off at t = 2 (the first stance has no touch-down: it starts with the log), the
    # touch-down at t = 7. after_lo = {2, 3}, after_td = {7, 8}. With the flag smoothed
    # to f = sigmoid(l / k), k = 0.5, i.e. f = sigmoid(2 l):
    #   touchdown = (1 - f7) + (1 - f8) = sigmoid(2) + sigmoid(-4)    (one touch-down)
    #   liftoff   = f2 + f3 = sigmoid(2) + sigmoid(-2) = 1            (one lift-off)
    #   errors    = (sum over contact of 1 - f + sum over air of f) / 11
    #   events    = sigmoid(E / k) of the one air phase, E its smooth maximum
    #               (air_phase_maxima), / 1
    truth = np.array([1, 1, 0, 0, 0, 0, 0, 1, 1, 1, 1], bool)[:, None, None]
    logit = np.array([3, 3, 1, -1, -3, -3, -1, -1, 2, 3, 3], np.float64)[:, None, None]
    data = _event_data(truth, np.ones_like(truth), 2)
    ev = data.events
    np.testing.assert_array_equal(np.flatnonzero(ev.lo_step), [2])
    np.testing.assert_array_equal(np.flatnonzero(ev.after_lo), [2, 3])
    np.testing.assert_array_equal(np.flatnonzero(ev.after_td), [7, 8])
    s = np.asarray(jt.cell_surrogates(jnp.asarray(logit), data, 0.5, sharpness=0.5))
    sig = lambda x: 1.0 / (1.0 + np.exp(-x))  # noqa: E731
    f, y = sig(2 * logit[:, 0, 0]), truth[:, 0, 0]
    errors = (np.sum(1 - f[y]) + np.sum(f[~y])) / 11
    e, has, n = jt.air_phase_maxima(jnp.asarray(logit), data, 0.5)
    assert int(n) == 1 and int(np.sum(has)) <= 1
    events = float(np.sum(np.where(has, sig(2 * np.asarray(e)), 0.0)))
    np.testing.assert_allclose(
        s, [errors, events, sig(2.0) + sig(-4.0), 1.0], rtol=1e-12, atol=1e-15
    )
    # The event term is softplus of the same maxima.
    total, _ = jt.air_event_terms(jnp.asarray(logit), data, 0.5)
    assert float(total) == pytest.approx(float(np.sum(np.where(has, np.logaddexp(0, e), 0))))
    # A flag that switches on d steps after the touch-down is late by d steps: a logit
    # of -30 from t = 2 to 8 and +30 elsewhere gives touchdown = 2 (and liftoff = 0).
    late = np.where((np.arange(11) >= 2) & (np.arange(11) <= 8), -30.0, 30.0)[:, None, None]
    got = np.asarray(jt.cell_surrogates(jnp.asarray(late), data, 0.5))
    assert got[2] == pytest.approx(2.0) and got[3] == pytest.approx(0.0, abs=1e-12)
    # A blip to +30 in the air phase (t = 5) is one failed phase of one: events = 1.
    blip = late.copy()
    blip[5] = 30.0
    assert float(jt.cell_surrogates(jnp.asarray(blip), data, 0.5)[1]) == pytest.approx(1.0)
    # The penalty: softplus of the excess in units; equal cells cost 4 log 2.
    u = jnp.asarray([0.1, 0.1, 1.0, 1.0])
    assert float(jt.constraint_penalty(jnp.asarray(s), jnp.asarray(s), u)) == pytest.approx(
        4 * np.log(2.0)
    )
    worse = jnp.asarray(s) + jnp.asarray([0.0, 0.0, 3.0, 0.0])
    want = 3 * np.log(2.0) + np.logaddexp(0.0, 3.0)
    assert float(jt.constraint_penalty(worse, jnp.asarray(s), u)) == pytest.approx(want)


def test_constraint_penalty_gradient_in_the_logits_matches_central_differences(x64, np_rng):
    tau = 0.25
    x, data = _crossing_problem(np_rng)
    ref = jnp.asarray([0.05, 0.05, 1.0, 1.0])
    units = jnp.asarray([0.01, 0.02, 0.5, 0.5])
    f = jax.jit(lambda x: jt.constraint_penalty(jt.cell_surrogates(x, data, tau), ref, units))
    g = _grad_matches_central_differences(f, x)
    assert np.sum(np.abs(g) > 1e-3) >= g.size // 2  # not vacuous: most steps count


def test_constraint_reference_is_the_untuned_windows_own_surrogates():
    """reference_cells gives, per training window, the untuned filter's surrogates on the
    windows and belief carry of tune's epochs: at theta0 each window's penalty is exactly
    4 softplus(0) = 4 log 2 times the weight (cells equal to their reference)."""
    train = jt.with_air_phases(_synthetic(1, n_t=600, n_envs=4), 20)
    space = jt.make_space(4, fields=("sigma_J",))
    base = _synthetic_params(SIGMA_J_WRONG)
    terrain = flat(0.0, 0.05)
    theta0 = jt.init_theta(space, base)
    weight = 0.5
    config = jt.TuneConfig(chunk=300, prior_noise=0.0, event_weight=0.0, constraint_weight=weight)
    plain = dataclasses.replace(config, constraint_weight=0.0)
    key = jax.random.key(0)
    refs = jt.reference_cells(base, terrain, train, key=key, chunk=300)
    assert refs.shape == (2, 4) and np.all(np.isfinite(refs))
    units = jnp.asarray(jt.constraint_units(DT), jnp.float32)
    loss = jax.jit(jt.tuning_loss, static_argnames=("space", "config"))
    belief = init_belief_batch(base, 4, 1)
    for w in range(2):
        win = jt.loss._window(train, 300 * w, 300)
        got, (nxt, _, _) = loss(theta0, space, base, theta0, terrain, belief, win, config,
                                key=key, cells_reference=(jnp.asarray(refs[w]), units))  # fmt: skip
        want, _ = loss(theta0, space, base, theta0, terrain, belief, win, plain, key=key)
        assert float(got) - float(want) == pytest.approx(weight * 4 * np.log(2.0), rel=1e-4)
        belief = nxt
    # Tuning with the cells in the objective needs the references (tune computes them).
    with pytest.raises(ValueError, match="cells_reference"):
        loss(theta0, space, base, theta0, terrain, belief, win, config, key=key)


def test_feasible_rejects_epochs_that_worsen_the_tuning_cells():
    """feasible=True on the recovery problem started *below* the true sigma_J (0.02 <
    0.05): the untuned filter has no false contact in the air there (failure rate 0 on
    the tuning log), and the BCE's way to the truth raises it, so some epochs are
    rejected. Each epoch is rejected exactly when its tuning-log cells are worse than
    epoch 0's (recomputed with jax_contact.metrics), and the epoch returned is an
    accepted one."""
    train, val = _synthetic(1, n_t=600, n_envs=4), _synthetic(2, n_t=600, n_envs=4)
    space = jt.make_space(4, fields=("sigma_J",))
    config = jt.TuneConfig(
        learning_rate=1.0, max_epochs=6, patience=6, chunk=300, prior_noise=0.0, seed=0,
        event_weight=0.0, feasible=True,
    )  # fmt: skip
    base = _synthetic_params(0.02)
    res = jt.tune(base, flat(0.0, 0.05), [train], val, space, config)
    hist = res.history
    first = hist[0]["train_cells"]
    logits = jt.predict_logits(base, flat(0.0, 0.05), jt.with_air_phases(train, 20),
                               key=jax.random.key(0), chunk=300)  # fmt: skip
    from jax_contact.metrics import evaluate

    m = evaluate(jt.sigmoid_np(logits), train.truth, train.mask, dt=DT)
    assert first[0]["f1"] == pytest.approx(m.f1, abs=1e-6)
    assert first[0]["touchdown_ms"] == pytest.approx(abs(m.touchdown_delay_ms[0]), abs=1e-6)
    assert first[0]["fail"] == m.swing_phase_failure_rate == 0.0
    rejected = [row["epoch"] for row in hist[1:] if row["rejected"]]
    accepted = [row["epoch"] for row in hist[1:] if not row["rejected"]]
    assert rejected and accepted, (rejected, accepted)  # both happen at this step size
    for row in hist[1:]:
        assert row["rejected"] == (not jt.no_worse(row["train_cells"], first)), row["epoch"]
    assert res.best_epoch == 0 or not hist[res.best_epoch]["rejected"]
    assert jt.no_worse(hist[res.best_epoch]["train_cells"], first)
    # A validation log of 4 envs (< bootstrap.MIN_ENVS): the bootstrap makes no call, so
    # no count of cells worse beyond the spread (a 0 there read as "none worse").
    assert all("val_worse" not in row for row in hist)
    # The halving: the optimiser's learning rate in the state.
    opt = jt.fit._optimizer(config)
    state = opt.init(jt.init_theta(space, base))
    half = jt.fit._halve_learning_rate(state)
    assert float(half[1].hyperparams["learning_rate"]) == pytest.approx(0.5)


def test_values_far_from_their_derived_ones_are_named():
    """The tune command's warning lists rows of describe's table beyond a factor 4 either
    way (the hexapod's fit: sigma_f normal x4.12, sigma_d x4.46; cap_dynamics x0.936 is
    not one), with the boundary itself inside."""
    from jax_contact.train.tune_cmd import far_from_derived

    table = [
        {"field": "sigma_f", "group": "normal", "ratio": 4.12},
        {"field": "sigma_d", "group": "joint0", "ratio": 4.46},
        {"field": "cap_dynamics", "group": "", "ratio": 0.936},
        {"field": "takeoff_accel", "group": "", "ratio": 0.2},
        {"field": "stance_time", "group": "", "ratio": 0.25},
    ]
    assert far_from_derived(table) == [
        "sigma_f normal x4.12",
        "sigma_d joint0 x4.46",
        "takeoff_accel x0.2",
    ]
    # factor 5: x0.2 is on the boundary (inside); factor 4.2: x4.12 inside, x4.46 not.
    assert far_from_derived(table, factor=5.0) == []
    assert far_from_derived(table, factor=4.2) == ["sigma_d joint0 x4.46", "takeoff_accel x0.2"]


def test_compare_moves_a_file_of_another_period_as_evaluate_does(tmp_path):
    """tune_presets.compare reads a parameter file as ``jax-contact evaluate`` does
    (log_estimator.load_params_for): a file written at 5 ms is moved to the log's 2.5 ms
    by the derivation rules, with the warning naming both periods. The file here is the
    defaults derived at 5 ms, so moved to 2.5 ms it is the 2.5 ms defaults again, and its
    row must score exactly as the defaults' row (before, the file was replayed unmoved,
    and the replay refused its dt)."""
    import shutil
    import warnings
    from pathlib import Path

    import jax_contact as jc
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.log_estimator import default_estimator
    from jax_contact.train.tune_presets import compare

    sample = Path(__file__).parent / "fixtures" / "planar_leg_hop.h5"
    shutil.copy(sample, tmp_path / "planar_leg_trot_s0.h5")
    robot = load_robot("planar_leg")
    slow, _ = default_estimator(robot.description, 0.005, mj_model=robot.mj_model)
    path = jc.save_params(tmp_path / "slow.json", slow, {"robot": "planar_leg"})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = compare(
            "planar_leg", {"defaults": None, "file": str(path)}, scenarios=("trot",),
            workdir=tmp_path,
        )["trot"]  # fmt: skip
    said = [str(w.message) for w in caught]
    assert any("dt = 0.005" in m and "0.0025" in m for m in said), said
    # Same flags; P equal up to the float32 round-off of the move (ECE within 1e-6).
    for key in ("f1", "accuracy", "air_phase_failure_rate"):
        assert got["file"][key] == got["defaults"][key], key
    assert got["file"]["ece"] == pytest.approx(got["defaults"]["ece"], rel=1e-6)
