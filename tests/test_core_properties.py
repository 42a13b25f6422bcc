"""Structural properties of the estimator core: jit, vmap, keys, scan, long runs, gradients.

Everything runs on the planar leg of the paper's Section III (``oracle.planar_leg``, nv = 3,
force rows x and z) with Table II's noise, through the session-wide jitted entry points of
``conftest.py`` so that compilations are shared with the other test files.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest

from jax_contact import (
    LegMeasurement,
    flat,
    init_belief,
    init_belief_batch,
    log_touchdown_monte_carlo,
    make_noise,
    make_params,
    sequence_bce,
    step,
)

MODES = ("quadrature", "monte_carlo")
PARAMS = {
    mode: make_params(make_noise(3, **oracle.TABLE_II), force_rows=(0, 2), touchdown=mode)
    for mode in MODES
}
TERRAIN = flat(0.0, 0.05)
N_ENVS, N_LEGS = 2, 2

# float32, fused (jit) vs op-by-op (eager) or batched vs unbatched: a few ulp apart.
RTOL, ATOL = 2e-5, 1e-6


def _as_meas(fields) -> LegMeasurement:
    def conv(x):
        x = np.asarray(x)
        return jnp.asarray(x, jnp.int32 if np.issubdtype(x.dtype, np.integer) else jnp.float32)

    return LegMeasurement(**{k: conv(v) for k, v in fields.items()})


def _stack(dicts):
    return {k: np.stack([d[k] for d in dicts]) for k in dicts[0]}


def _batch_meas(rng, lead, stance=None) -> LegMeasurement:
    """Random planar-leg measurements with leading axes ``lead``."""
    n = int(np.prod(lead))
    flat_ = _stack([oracle.random_planar(rng, stance) for _ in range(n)])
    return _as_meas({k: v.reshape(lead + v.shape[1:]) for k, v in flat_.items()})


def _falling_meas() -> LegMeasurement:
    """A foot 1 cm above the floor falling at 1.46 m/s: P(C|A) ~ 0.05 (sigma_pi 5 cm)."""
    return _as_meas(oracle.planar_measurement(*oracle.planar_swing(0.01, 0.3, -1.0, (2.0, 8.0))))


def _random_belief(rng, params, lead):
    b = init_belief_batch(params, *lead) if len(lead) == 2 else init_belief(params)
    return b.replace(logit=jnp.asarray(rng.normal(scale=4.0, size=lead), jnp.float32))


def _assert_trees_close(a, b, rtol=RTOL, atol=ATOL):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol)


def _index(tree, *idx):
    return jax.tree.map(lambda x: x[idx], tree)


def test_jit_equals_no_jit(jit_step):
    """The whole step, op by op and jitted (quadrature), and the Monte-Carlo transition.

    Running a whole step op by op compiles every primitive on its own (~15 s on 2 cores),
    so the Monte-Carlo mode is checked on the one function that differs between the modes.
    """
    rng = np.random.default_rng(1)
    params = PARAMS["quadrature"]
    key = jax.random.key(3)
    meas = _batch_meas(rng, (2,))
    belief = _random_belief(rng, params, ())
    for m in [_index(meas, 0), _index(meas, 1), _falling_meas()]:
        eager = step(params, TERRAIN, belief, m, key=key)
        jitted = jit_step(params, TERRAIN, belief, m, key=key)
        _assert_trees_close(eager, jitted)
    args = (jnp.float32(0.01), jnp.float32(0.04), jnp.float32(0.05), jnp.float32(-1.5),
            jnp.float32(0.2), jnp.float32(0.0025))  # fmt: skip
    eager = log_touchdown_monte_carlo(*args, 500, key=key)
    jitted = jax.jit(log_touchdown_monte_carlo, static_argnums=6)(*args, 500, key=key)
    np.testing.assert_allclose(np.asarray(eager), np.asarray(jitted), rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("mode", MODES)
def test_step_batch_equals_per_foot_step(mode, jit_step, jit_step_batch):
    """vmap over (envs, legs) equals a Python loop of step with the same split keys."""
    rng = np.random.default_rng(2)
    params = PARAMS[mode]
    lead = (N_ENVS, N_LEGS)
    meas = _batch_meas(rng, lead)
    belief = _random_belief(rng, params, lead)
    key = jax.random.key(5)
    got_b, got_d = jit_step_batch(params, TERRAIN, belief, meas, key=key)
    keys = jax.random.split(key, N_ENVS * N_LEGS)  # step_batch's documented split
    for e in range(N_ENVS):
        for leg in range(N_LEGS):
            want = jit_step(
                params,
                TERRAIN,
                _index(belief, e, leg),
                _index(meas, e, leg),
                key=keys[e * N_LEGS + leg],
            )
            _assert_trees_close(_index((got_b, got_d), e, leg), want)


def test_the_key_enters_only_through_algorithm_1s_draws(jit_step):
    """Two keys give two Monte-Carlo estimates of the same touch-down probability, and
    nothing else differs: the terms, the take-off, the posterior (it uses the previous
    step's transitions) and the force are the same to the bit; the quadrature ignores the
    key altogether."""
    params = PARAMS["monte_carlo"]
    belief = init_belief(params)
    meas = _falling_meas()
    a = jit_step(params, TERRAIN, belief, meas, key=jax.random.key(0))
    c = jit_step(params, TERRAIN, belief, meas, key=jax.random.key(1))
    for name in ("p_contact", "p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff"):
        np.testing.assert_array_equal(getattr(a[1], name), getattr(c[1], name), err_msg=name)
    np.testing.assert_array_equal(a[1].force, c[1].force)
    np.testing.assert_array_equal(a[0].logit, c[0].logit)
    p_a, p_c = float(a[1].p_touchdown), float(c[1].p_touchdown)
    assert 0.01 < p_a < 0.99, p_a
    assert p_a != p_c  # a different Monte-Carlo estimate
    assert abs(p_a - p_c) < 0.2  # ... of the same quantity (500 draws)
    # The quadrature ignores the key.
    params = PARAMS["quadrature"]
    q0 = jit_step(params, TERRAIN, belief, meas, key=jax.random.key(0))
    q1 = jit_step(params, TERRAIN, belief, meas, key=jax.random.key(1))
    for x, y in zip(jax.tree.leaves(q0), jax.tree.leaves(q1), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


T_RUN = 6


def _run_inputs(seed, params):
    rng = np.random.default_rng(seed)
    lead = (N_ENVS, N_LEGS)
    seq = [_batch_meas(rng, lead) for _ in range(T_RUN)]
    meas_seq = jax.tree.map(lambda *xs: jnp.stack(xs), *seq)
    return init_belief_batch(params, *lead), meas_seq


def test_run_equals_loop_of_step_batch(jit_run, jit_step_batch):
    """run's lax.scan equals a Python loop of step_batch with run's key schedule."""
    params = PARAMS["monte_carlo"]
    belief, meas_seq = _run_inputs(7, params)
    key = jax.random.key(11)
    got_b, got_d = jit_run(params, TERRAIN, belief, meas_seq, key=key)
    b, k = belief, key
    for t in range(T_RUN):
        k, sub = jax.random.split(k)  # run's documented schedule: split once per step
        b, d = jit_step_batch(params, TERRAIN, b, _index(meas_seq, t), key=sub)
        _assert_trees_close(_index(got_d, t), d)
    _assert_trees_close(got_b, b)


# --------------------------------------------------------------------------- a long run

N_LONG = 1_000_000
PHASE = 100  # steps of stance, then of swing (0.25 s each at 400 Hz)
# The caps bound each step's evidence, the transition floor bounds the prior:
# |prior logit| <= 30 + log 2 and |logit| <= that + sum of logit(caps).
LOGIT_BOUND = 30.0 + np.log(2.0) + 2 * np.log(99.0) + np.log(9.0)


def _long_run(params, terrain, stance, swing):
    def body(carry, t):
        b, lo, hi = carry
        on_ground = (t // PHASE) % 2 == 0
        m = jax.tree.map(lambda a, c: jnp.where(on_ground, a, c), stance, swing)
        b, d = step(params, terrain, b, m, key=jax.random.key(0))
        return (b, jnp.minimum(lo, b.logit), jnp.maximum(hi, b.logit)), d.p_contact

    init = (init_belief(params), jnp.float32(jnp.inf), jnp.float32(-jnp.inf))
    return jax.lax.scan(body, init, jnp.arange(N_LONG, dtype=jnp.int32))


@pytest.mark.slow
def test_million_steps_stay_finite_and_responsive():
    """10^6 steps of alternating stance and swing in one scan: no NaN, no +-inf logit,
    the logit stays within its analytic bound, and the belief still switches at the end.

    0.25 s of stance, then 0.25 s of a fast swing 20 cm up, repeated 2500 times. The
    quadrature has a single node here: the test is about the recursion's numerics, and one
    node makes a step 2.5 times cheaper than 16 (~25 s for the 10^6 steps on 2 busy cores).
    """
    params = PARAMS["quadrature"].replace(n_quad=1)
    stance = _as_meas(oracle.planar_measurement(*oracle.planar_stance()))
    swing = _as_meas(oracle.planar_measurement(*oracle.planar_swing()))
    (belief, lo, hi), p = jax.jit(_long_run)(params, flat(0.0, 0.05), stance, swing)
    p = np.asarray(p)
    assert np.isfinite(p).all()
    assert np.isfinite(float(belief.logit))
    assert -LOGIT_BOUND < float(lo) and float(hi) < LOGIT_BOUND, (float(lo), float(hi))
    assert np.isfinite(np.asarray(belief.log_transition)).all()
    cycles = p.reshape(-1, 2, PHASE)  # (cycle, stance/swing, step)
    # Every phase ends decided, in the first cycle as in the last.
    assert (cycles[:, 0, -1] > 0.99).all() and (cycles[:, 1, -1] < 0.01).all()
    last = cycles[-1]
    assert last[0].max() > 0.99 and last[1].min() < 0.01
    # ... and switches within a few steps of the phase change, not stuck.
    assert (last[0, 5:] > 0.99).all() and (last[1, 5:] < 0.01).all()


# --------------------------------------------------------------------------- gradients

T_GRAD = 8


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
def test_grad_of_sequence_bce_is_finite(mode):
    """d BCE / d noise: finite for every leaf, non-zero for sigma_d, in both modes."""
    params = PARAMS[mode]
    rng = np.random.default_rng(13)
    truth = np.zeros((T_GRAD, 1, N_LEGS), bool)
    seq = []
    for t in range(T_GRAD):
        stance = [(t // 3 + leg) % 2 == 0 for leg in range(N_LEGS)]
        truth[t, 0] = stance
        legs = [_batch_meas(rng, (1,), stance[leg]) for leg in range(N_LEGS)]
        seq.append(jax.tree.map(lambda *xs: jnp.stack(xs, axis=1), *legs))
    meas_seq = jax.tree.map(lambda *xs: jnp.stack(xs), *seq)

    def loss(noise):
        return sequence_bce(
            params.replace(noise=noise),
            TERRAIN,
            meas_seq,
            jnp.asarray(truth),
            key=jax.random.key(2),
        )

    value, grads = jax.jit(jax.value_and_grad(loss))(params.noise)
    assert np.isfinite(float(value))
    for name in params.noise.__dataclass_fields__:
        g = np.asarray(getattr(grads, name))
        assert np.isfinite(g).all(), (name, g)
    assert np.abs(np.asarray(grads.sigma_d)).max() > 0.0


# --------------------------------------------------------------------------- no retracing


def test_no_retrace(jit_step, jit_step_batch):
    """Calls with new values but the same shapes and static parameters reuse the trace.

    The counters are session-wide: this also covers every earlier call through the shared
    fixtures, in this file and the others.
    """
    rng = np.random.default_rng(17)
    for mode in MODES:
        params = PARAMS[mode]
        for i in range(3):
            p = params.replace(dt=jnp.float32(0.002 + 0.001 * i))  # a new leaf value
            m = _batch_meas(rng, (1,))
            jit_step(p, TERRAIN, _random_belief(rng, p, ()), _index(m, 0), key=jax.random.key(i))
            mb = _batch_meas(rng, (N_ENVS, N_LEGS))
            b = _random_belief(rng, p, (N_ENVS, N_LEGS))
            jit_step_batch(p, flat(0.01 * i, 0.1), b, mb, key=jax.random.key(i))
    for fn in (jit_step, jit_step_batch):
        assert fn.traces, "nothing traced"
        assert max(fn.traces.values()) == 1, fn.traces


def test_run_and_sequence_bce_trace_under_x64(x64):
    """float64 params and measurements straight from init_belief (traced only, not run).

    Regression: init_belief once kept the foothold in float32, so under x64 the scan carry
    of run and sequence_bce changed dtype after the first step (TypeError).
    """
    params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), PARAMS["quadrature"])
    terrain = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), TERRAIN)
    fields = oracle.planar_measurement(*oracle.planar_stance())
    meas = LegMeasurement(
        **{k: jnp.asarray(np.broadcast_to(v, (4, 1, 1) + np.shape(v))) for k, v in fields.items()}
    )
    assert meas.qdd.dtype == jnp.float64
    truth = jnp.ones((4, 1, 1))
    out = jax.eval_shape(
        lambda m: sequence_bce(params, terrain, m, truth, key=jax.random.key(0)), meas
    )
    assert out.dtype == jnp.float64 and out.shape == ()


def test_float32_params_run_on_float64_measurements_under_x64(x64):
    """make_params builds float32 parameters; under x64 a user's measurements are float64
    and step_batch computes in float64. run and sequence_bce keep the initial belief's
    float32 carry (they raised a scan carry TypeError) and agree with the float32 run."""
    from jax_contact.filter import run

    params = PARAMS["quadrature"]
    fields = oracle.planar_measurement(*oracle.planar_stance())
    meas = LegMeasurement(
        **{k: jnp.asarray(np.broadcast_to(v, (4, 1, 1) + np.shape(v))) for k, v in fields.items()}
    )
    assert meas.qdd.dtype == jnp.float64 and params.dt.dtype == jnp.float32
    b0 = init_belief_batch(params, 1, 1)
    belief, diag = run(params, TERRAIN, b0, meas, key=jax.random.key(0))
    assert belief.logit.dtype == jnp.float32
    meas32 = jax.tree.map(lambda x: x.astype(jnp.float32) if x.dtype == jnp.float64 else x, meas)
    _, diag32 = run(params, TERRAIN, b0, meas32, key=jax.random.key(0))
    np.testing.assert_allclose(np.asarray(diag.p_contact), np.asarray(diag32.p_contact), atol=1e-5)
    bce = sequence_bce(params, TERRAIN, meas, jnp.ones((4, 1, 1)), key=jax.random.key(0))
    assert np.isfinite(float(bce))


@pytest.mark.parametrize("mode", MODES)
def test_float32_inputs_stay_float32_under_x64(x64, mode):
    """With float64 enabled, float32 params and readings trace the whole filter without one
    implicit promotion (JAX's "strict" promotion raises at the first). Regressions: the
    dynamics term's damping ``eye`` was float64 and turned the operational-space matrix
    float64; ``_math.ndtri``'s NumPy constants turned the touch-down quantiles float64
    (where the float64 deep-tail switch then met float32 ``erfc`` values)."""
    from jax_contact.filter import run

    fields = oracle.planar_measurement(*oracle.planar_stance())
    meas = LegMeasurement(
        **{
            k: jnp.asarray(np.broadcast_to(v, (4, 1, 1) + np.shape(v)), jnp.float32)
            if np.asarray(v).dtype.kind == "f"
            else jnp.asarray(np.broadcast_to(v, (4, 1, 1) + np.shape(v)))
            for k, v in fields.items()
        }
    )
    params = PARAMS[mode]
    b0 = init_belief_batch(params, 1, 1)
    with jax.numpy_dtype_promotion("strict"):
        belief, diag = jax.eval_shape(
            lambda m: run(params, TERRAIN, b0, m, key=jax.random.key(0)), meas
        )
    assert belief.logit.dtype == jnp.float32 and diag.p_contact.dtype == jnp.float32
    assert diag.force.dtype == jnp.float32


def test_stabilised_contact_reads_a_sinking_foot_as_contact():
    """A foot that still moves into the ground at 0.3 m/s and decelerates as the
    stabilised contact predicts (``J qdd + Jdot qd = -b u e``, b = 100 1/s) is contact
    evidence for the stabilised dynamics term and air evidence for the rigid one (which
    predicts zero foot acceleration); a foot that moves away is not stabilised at all."""
    from jax_contact.measurement import dynamics_llr

    rng = np.random.default_rng(7)
    case = oracle.random_case(rng, 18, 3, stance=True)
    meas, e = dict(case["meas"]), np.asarray(case["terrain"]["normal"])
    noise = {k: np.asarray(v) for k, v in case["noise"].items()}
    noise["sigma_qd"] = np.full(18, 0.02)  # a precise velocity, so the shift dominates
    scalars = dict(case["scalars"], outlier_prob=0.0, cap_dynamics=1.0, contact_damping=100.0)
    stab = oracle.Params(**noise, **scalars, unilateral=False)
    rigid = oracle.Params(**noise, **dict(scalars, contact_damping=0.0), unilateral=False)
    leg = meas["leg_dofs"]
    qd = np.array(meas["qd"])
    qd[leg] += np.linalg.lstsq(meas["J"][:, leg], -0.3 * e, rcond=None)[0]
    meas.update(qd=qd, v_f=meas["J"] @ qd)
    _, _, info = oracle.dynamics(stab, oracle.Meas(**meas), e)
    meas["qdd"] = np.array(meas["qdd"])
    meas["qdd"][leg] = info["qdd_contact"]
    m = _as_meas(meas)
    llr, params = {}, {}
    for name, p in (("stab", stab), ("rigid", rigid)):
        fields = {k: v for k, v in vars(p).items() if k not in noise and k != "unilateral"}
        params[name] = make_params(make_noise(18, **noise), **fields, unilateral=False)
        llr[name] = float(dynamics_llr(params[name], m, jnp.asarray(e, jnp.float32))[0])
    assert llr["stab"] > 2.0 and llr["rigid"] < llr["stab"] - 2.0, llr
    # Moving away from the ground (u > 0): nothing is stabilised, the contact force is the
    # rigid one (only the force noise term, added whatever the sign, still differs).
    qd[leg] -= 2 * np.linalg.lstsq(meas["J"][:, leg], -0.3 * e, rcond=None)[0]
    m = _as_meas(dict(meas, qd=qd, v_f=meas["J"] @ qd))
    forces = [np.asarray(dynamics_llr(params[n], m, jnp.asarray(e, jnp.float32))[1]) for n in llr]
    np.testing.assert_allclose(forces[0], forces[1], rtol=1e-5, atol=1e-4)
