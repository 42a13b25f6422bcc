"""The estimator core against the independent float64 oracle (``tests/oracle.py``).

Every comparison feeds the oracle and JAX *the same* inputs (drawn in float64, rounded once
to float32), so the differences measure computation alone: JAX in float32 against the
float64 oracle with named tolerances, and JAX in float64 (``jax.enable_x64``) against the
oracle with much tighter ones. The largest error of every quantity is recorded; ``pytest -s``
prints the table at the end of the module.

Tolerances are ``|jax - oracle| <= atol + rtol * |oracle|``.
"""

from __future__ import annotations

import collections
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest

from jax_contact import (
    LegMeasurement,
    TerrainQuery,
    diff_kinematics_llr,
    dynamics_llr,
    flat,
    foothold_memory,
    init_belief_batch,
    kinematics_llr,
    log_takeoff,
    log_touchdown_monte_carlo,
    log_touchdown_quadrature,
    make_noise,
    make_params,
    step_batch,
)
from jax_contact.measurement import end_of_interval, leg_blocks, sole_gap
from jax_contact.transition import normal_velocity

# (nv, leg dofs, force_rows, unilateral): 3-dof legs in models of 8 and 18 velocities, the
# planar-like 2-dof leg with the x and z rows, a slipping foot with the normal row only.
CONFIGS = {
    "nv8_3dof": (8, 3, (0, 1, 2), True),
    "nv18_3dof_bilateral": (18, 3, (0, 1, 2), False),
    "nv9_2dof_xz": (9, 2, (0, 2), True),
    "nv10_3dof_normal_only": (10, 3, (2,), True),
}
N_CASES = 12  # seeded random cases per configuration, half stance-like, half air-like
F32_EPS = float(np.finfo(np.float32).eps)
F64_EPS = float(np.finfo(np.float64).eps)

# Named tolerances (atol, rtol): float32 JAX vs the float64 oracle. Uncapped LLRs reach
# 1e5 in the sequences; float32 Cholesky factors and solves of the leg blocks (condition
# numbers up to ~1e3 here) leave ~1e-4 relative error.
TOL32 = {
    "llr_dynamics": (1e-3, 2e-4),
    "llr_diff_kinematics": (1e-4, 2e-5),
    "llr_kinematics": (1e-5, 2e-5),
    "force": (1e-4, 0.0),  # relative to the case's largest force component
    "gap": (1e-7, 2e-6),
    "sigma_pf": (1e-9, 2e-6),
    "u": (1e-6, 2e-6),
    "sigma_v": (1e-8, 2e-6),
    # The 16-node quadrature where sigma_pf <= sigma_pi: absolute, and in log space where
    # P(C|A) > 1e-13 (the floor): the Gauss-Legendre rule in the CDF of the velocity tail
    # meets a sqrt(log(1/v)) endpoint singularity, which leaves up to ~0.5 % relative error.
    "touchdown": (5e-6, 5e-3),
    "touchdown_log": (1e-2, 0.0),
    # One step from the same previous belief (teacher forcing): round-off only.
    "logit (one step)": (2e-4, 2e-4),
    "p_contact (one step)": (2e-5, 0.0),
    "p_term": (2e-5, 0.0),
    "foothold": (1e-6, 0.0),
    # Free-running sequences: the quadrature's relative error on small P(C|A) enters the
    # prior of a foot in the air, ~5e-3 in the logit, ~1e-3 in P(C) near P(C) = 1/2.
    "logit (free run)": (2e-2, 2e-4),
    "p_contact (free run)": (2e-3, 0.0),
}
# float64 JAX vs the oracle: round-off only, except where the touch-down quadrature's
# truncation error enters (the free-running sequences).
TOL64 = {
    "llr_dynamics": (1e-9, 1e-10),
    "llr_diff_kinematics": (1e-10, 1e-11),
    "llr_kinematics": (1e-11, 1e-11),
    "force": (1e-10, 0.0),
    "gap": (1e-13, 1e-12),
    "sigma_pf": (1e-15, 1e-12),
    "u": (1e-12, 1e-12),
    "sigma_v": (1e-14, 1e-12),
    "touchdown": (5e-6, 5e-3),
    "touchdown_log": (1e-2, 0.0),
    "logit (one step)": (1e-9, 1e-11),
    "p_contact (one step)": (1e-12, 0.0),
    "p_term": (1e-12, 0.0),
    "foothold": (1e-12, 0.0),
    "logit (free run)": (2e-2, 1e-9),
    "p_contact (free run)": (2e-3, 0.0),
}
# The take-off row is a difference of two log densities, each of magnitude up to |L| (a
# fast foot "in contact" has log densities of -300 and more): its float error is a few ulp
# of |L|, so its tolerance is atol + K_ULP * eps * |L| with |L| from the oracle.
# In float64 the limit is JAX's log_ndtr itself: its asymptotic series below -20 is good to
# ~2e-11 relative (checked against scipy.special.log_ndtr).
TAKEOFF = {"float32": (2e-6, 8 * F32_EPS), "float64": (1e-12, 4e-11)}

ERRORS: dict[str, dict[str, tuple[float, float]]] = collections.defaultdict(dict)
REL_FLOOR = 1e-6  # the table's relative errors are |err| / max(|oracle|, REL_FLOOR)


def _record(name: str, dtype: str, err, rel) -> None:
    old = ERRORS[name].get(dtype, (0.0, 0.0))
    ERRORS[name][dtype] = (max(old[0], float(np.max(err))), max(old[1], float(np.max(rel))))


def _check(name: str, dtype: str, got, ref, tol, extra=0.0) -> None:
    """Records the largest abs and rel error of ``name``, then asserts the tolerance."""
    got = np.asarray(got, np.float64)
    ref = np.asarray(ref, np.float64)
    assert got.shape == ref.shape, (name, got.shape, ref.shape)
    # NaN ("no measurement": an invalid step's terms and force) where the oracle has it.
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref), err_msg=name)
    got, ref = np.nan_to_num(got, nan=0.0), np.nan_to_num(ref, nan=0.0)
    err = np.abs(got - ref)
    _record(name, dtype, err, err / np.maximum(np.abs(ref), REL_FLOOR))
    atol, rtol = tol
    bad = err > atol + rtol * np.abs(ref) + extra
    assert not bad.any(), (
        f"{name} ({dtype}): max abs err {err.max():.3g} at {np.argwhere(bad)[:5].tolist()}:"
        f" got {got[bad][:5]}, want {ref[bad][:5]} (atol {atol}, rtol {rtol})"
    )


@pytest.fixture(scope="module", autouse=True)
def _print_error_table():
    yield
    head = f"  {'quantity':30s} {'f32 abs':>9s} {'f32 rel':>9s} {'f64 abs':>9s} {'f64 rel':>9s}"
    lines = ["", f"max |jax - oracle| per quantity (rel: / max(|oracle|, {REL_FLOOR})):", head]
    for name in sorted(ERRORS):
        cells = []
        for dt in ("float32", "float64"):
            a, r = ERRORS[name].get(dt, (math.nan, math.nan))
            cells.append(f"{a:9.2g} {r:9.2g}")
        lines.append(f"  {name:30s} " + " ".join(cells))
    print("\n".join(lines))


# --------------------------------------------------------------------------- conversions


def _params(case, force_rows, unilateral, **static):
    nv = len(case["noise"]["sigma_q"])
    return make_params(
        make_noise(nv, **case["noise"]),
        **case["scalars"],
        force_rows=force_rows,
        unilateral=unilateral,
        **static,
    )


def _oracle_params(case, force_rows, unilateral):
    return oracle.Params(
        **case["noise"], **case["scalars"], force_rows=tuple(force_rows), unilateral=unilateral
    )


def _to_jax(tree, dtype):
    """NumPy leaves to JAX arrays, floats as ``dtype`` (float64: call inside enable_x64)."""

    def conv(x):
        x = np.asarray(x)
        return jnp.asarray(x, dtype) if np.issubdtype(x.dtype, np.floating) else jnp.asarray(x)

    return jax.tree.map(conv, tree)


def _stack(trees):
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


@functools.cache
def _cases(name: str):
    nv, n_l, rows, _ = CONFIGS[name]
    rng = np.random.default_rng(1000 + list(CONFIGS).index(name))
    return [
        oracle.round32(oracle.random_case(rng, nv, n_l, rows, stance=i % 2 == 0))
        for i in range(N_CASES)
    ]


# --------------------------------------------------------------------------- the terms


def _terms(params, meas, tq):
    end = end_of_interval(params, leg_blocks(params, meas))
    dyn, force = dynamics_llr(params, meas, tq.normal)
    gap, sigma_pf = sole_gap(params, meas, tq)
    u, sigma_v = normal_velocity(params, meas, tq.normal)
    return dict(
        llr_dynamics=dyn,
        force=force,
        llr_diff_kinematics=diff_kinematics_llr(params, meas, tq.normal),
        llr_kinematics=kinematics_llr(params, meas, tq),
        gap=gap,
        sigma_pf=sigma_pf,
        u=u,
        sigma_v=sigma_v,
        log_takeoff=log_takeoff(params, u, sigma_v),
        v_end=end.v_f,
        p_end=end.p_f,
        llr_diff_kinematics_end=diff_kinematics_llr(params, end, tq.normal),
    )


TERMS = jax.jit(jax.vmap(_terms))  # one compile per configuration and dtype


def _jax_terms(name, dtype):
    _, _, rows, uni = CONFIGS[name]
    cases = _cases(name)
    params = _stack([_params(c, rows, uni) for c in cases])
    params = jax.tree.map(lambda x: jnp.asarray(x, dtype), params)
    meas = LegMeasurement(**_to_jax(_stack([c["meas"] for c in cases]), dtype))
    tq = TerrainQuery(**_to_jax(_stack([c["terrain"] for c in cases]), dtype))
    return jax.tree.map(np.asarray, TERMS(params, meas, tq))


@functools.cache
def _oracle_terms(name):
    _, _, rows, uni = CONFIGS[name]
    out = collections.defaultdict(list)
    for c in _cases(name):
        p = _oracle_params(c, rows, uni)
        m = oracle.Meas(**c["meas"])
        end = oracle.end_of_interval(p, m)
        tq = oracle.Query(**c["terrain"])
        dyn, force, info = oracle.dynamics(p, m, tq.normal)
        gap, s_pf = oracle.sole_gap(p, m, tq)
        u, s_v = oracle.normal_velocity(p, m, tq.normal)
        row = dict(
            llr_dynamics=dyn,
            llr_dynamics_raw=info["llr_raw"],
            force=force,
            llr_diff_kinematics=oracle.diff_kinematics(p, m, tq.normal),
            llr_kinematics=oracle.kinematics(p, m, tq),
            gap=gap,
            sigma_pf=s_pf,
            u=u,
            sigma_v=s_v,
            log_takeoff=oracle.takeoff(p, u, s_v),
            takeoff_scale=np.abs(oracle.takeoff_joint(p, u, s_v)).max(),
            v_end=end.v_f,
            p_end=end.p_f,
            llr_diff_kinematics_end=oracle.diff_kinematics(p, end, tq.normal),
        )
        for k, v in row.items():
            out[k].append(v)
    return {k: np.asarray(v) for k, v in out.items()}


def _compare_terms(name, dtype, tol):
    got = _jax_terms(name, jnp.dtype(dtype))
    ref = _oracle_terms(name)
    assert got["llr_dynamics"].dtype == np.dtype(dtype)
    for q in ("llr_dynamics", "llr_diff_kinematics", "llr_kinematics"):
        _check(q, dtype, got[q], ref[q], tol[q])
    _check("llr_diff_kinematics_end", dtype, got["llr_diff_kinematics_end"],
           ref["llr_diff_kinematics_end"], tol["llr_diff_kinematics"])  # fmt: skip
    for q in ("v_end", "p_end"):
        _check(q, dtype, got[q], ref[q], tol["gap"])
    for q in ("gap", "sigma_pf", "u", "sigma_v"):
        _check(q, dtype, got[q], ref[q], tol[q])
    scale = np.maximum(np.abs(ref["force"]).max(axis=1, keepdims=True), 1.0)
    _check("force", dtype, got["force"] / scale, ref["force"] / scale, tol["force"])
    atol, k_eps = TAKEOFF[dtype]
    extra = k_eps * ref["takeoff_scale"][:, None]
    _check("log_takeoff", dtype, got["log_takeoff"], ref["log_takeoff"], (atol, 0.0), extra)
    _check(
        "p_takeoff",
        dtype,
        np.exp(got["log_takeoff"]),
        np.exp(ref["log_takeoff"]),
        (atol, 0.0),
        extra,
    )


@pytest.mark.parametrize("name", list(CONFIGS))
def test_terms_float32(name):
    _compare_terms(name, "float32", TOL32)


@pytest.mark.parametrize("name", ["nv8_3dof", "nv9_2dof_xz"])
def test_terms_float64(name, x64):
    _compare_terms(name, "float64", TOL64)


def test_cases_exercise_both_hypotheses_and_caps():
    """The random cases reach both signs of every term, clipped and unclipped."""
    ref = {
        k: np.concatenate([_oracle_terms(n)[k] for n in CONFIGS])
        for k in ("llr_dynamics", "llr_dynamics_raw", "llr_diff_kinematics", "llr_kinematics")
    }
    for k in ("llr_dynamics", "llr_diff_kinematics"):
        assert (ref[k] > 1.0).any() and (ref[k] < -1.0).any(), k
    # Kinematics is neutral on and below the terrain (kinematics_neutral_below): exactly 0
    # for the stance cases, evidence for air only.
    assert (ref["llr_kinematics"] < -1.0).any() and (ref["llr_kinematics"] == 0.0).any()
    assert (ref["llr_kinematics"] <= 0.0).all()
    clipped = ref["llr_dynamics"] != ref["llr_dynamics_raw"]
    assert clipped.any() and not clipped.all()


def test_takeoff_sweep():
    """log_takeoff over a sweep of velocities, noise, a_F and dt, far tails included."""
    rng = np.random.default_rng(7)
    n = 64
    u = np.concatenate([rng.uniform(-1.0, 1.5, n - 4), [5.0, -5.0, 0.0, 1e-4]])
    sv = oracle._logu(rng, 0.01, 0.4, n)
    a_f = rng.uniform(20.0, 400.0, n)
    dt = rng.choice([0.001, 0.0025, 0.005], n)
    ts = rng.uniform(0.15, 0.6, n)
    u, sv, a_f, dt, ts = (oracle.round32(x) for x in (u, sv, a_f, dt, ts))
    plist, ref, scale = [], [], []
    for i in range(n):
        scalars = dict(_SCALARS, dt=dt[i], stance_time=ts[i], takeoff_accel=a_f[i])
        case = {"noise": {k: np.ones(3) for k in _NOISE_FIELDS}, "scalars": scalars}
        plist.append(_params(case, (0, 1, 2), True))
        p = _oracle_params(case, (0, 1, 2), True)
        ref.append(oracle.takeoff(p, u[i], sv[i]))
        scale.append(np.abs(oracle.takeoff_joint(p, u[i], sv[i])).max())
    params = _stack(plist)
    got = jax.jit(jax.vmap(log_takeoff))(
        params, jnp.asarray(u, jnp.float32), jnp.asarray(sv, jnp.float32)
    )
    atol, k_eps = TAKEOFF["float32"]
    extra = k_eps * np.asarray(scale)[:, None]
    _check("log_takeoff", "float32", got, np.asarray(ref), (atol, 0.0), extra)


_NOISE_FIELDS = ("sigma_q", "sigma_qd", "sigma_qdd", "sigma_d", "sigma_f", "sigma_J",
                 "sigma_qd_prior")  # fmt: skip
_SCALARS = dict(dt=0.0025, stance_time=0.3, swing_time=0.3, takeoff_accel=200.0,
                cap_dynamics=0.99, cap_diff_kinematics=0.9, cap_kinematics=0.99,
                inv_damping=1e-6, initial_contact=0.5)  # fmt: skip


# --------------------------------------------------------------------------- touch-down


def _td_sweep(seed, n, ratio_max):
    """Physically meaningful touch-down inputs (gap, sigma_pf, sigma_pi, u, sigma_u, dt)."""
    rng = np.random.default_rng(seed)
    gap = rng.uniform(-0.02, 0.1, n)
    spi = oracle._logu(rng, 0.005, 0.3, n)
    spf = np.minimum(oracle._logu(rng, 0.001, 0.04, n), ratio_max * spi)
    u = rng.uniform(-3.0, 1.0, n)
    su = oracle._logu(rng, 0.01, 0.3, n)
    dt = rng.choice([0.001, 0.0025, 0.005], n)
    return tuple(oracle.round32(x) for x in (gap, spf, spi, u, su, dt))


@functools.cache
def _td_quad_fn(n_quad):
    return jax.jit(jax.vmap(functools.partial(log_touchdown_quadrature, n_quad=n_quad)))


@functools.cache
def _td_ref(seed, n, ratio_max):
    args = _td_sweep(seed, n, ratio_max)
    return np.array([oracle.touchdown(*map(float, c)) for c in zip(*args, strict=True)])


def test_touchdown_oracle_self_consistent():
    """The oracle's nested quadrature: P(C|A) + P(A|A) = 1, and a NumPy Monte-Carlo agrees.

    2e5 draws with SciPy's truncated normal; tolerance 5 sample standard errors.
    """
    cases = [
        (0.05, 0.01, 0.2, -2.0, 0.1, 0.0025),  # docs/model.md: ~1e-2 at 2 m/s, vague terrain
        (0.003, 0.0005, 0.01, -2.0, 0.03, 0.0025),
        (-0.02, 0.01, 0.05, -1.0, 0.1, 0.0025),
        (0.0, 0.04, 0.01, -0.5, 0.2, 0.0025),  # sigma_pf > sigma_pi
    ]
    for c in cases:
        p_ca, p_aa = oracle.touchdown(*c)
        assert abs(p_ca + p_aa - 1.0) < 1e-10, c
        mc, sd = oracle.touchdown_mc(*c, n=200_000, seed=3)
        assert abs(mc - p_ca) < 5 * sd / math.sqrt(200_000) + 1e-12, (c, mc, p_ca)
    # docs/model.md: "about 1e-2 per 2.5 ms step for a foot falling at 2 m/s" with sigma_pi 0.2 m.
    assert 5e-3 < oracle.touchdown(*cases[0])[0] < 3e-2


def _compare_quadrature(dtype, tol, tol_log):
    args = _td_sweep(11, 24, ratio_max=1.0)
    got = np.exp(np.asarray(_td_quad_fn(16)(*(jnp.asarray(a, dtype) for a in args))))
    ref = _td_ref(11, 24, 1.0)
    _check("touchdown", dtype, got, ref, tol)
    big = ref > 1e-6  # in log space wherever the probability is not negligible
    _check("touchdown_log", dtype, np.log(got[big]), np.log(ref[big]), tol_log)
    assert big[:, 0].sum() >= 8


def test_ndtri_float32_against_scipy():
    """The fitted float32 inverse normal CDF (``_math.ndtri``, used by both touch-down rules)
    against scipy's float64 ``ndtri``, over its whole range: the lower tail down to the
    truncated terrain draws' smallest argument (1e-7 Phi(-8) ~ 6e-23), the centre, and the
    upper tail to 1 - 6e-8. Measured: max relative error 2.0e-7 (jax.scipy's float32 ndtri:
    3.8e-7). Its gradient is 1 / phi(ndtri(p)) (inverse function rule), checked to 1e-5."""
    from scipy.special import ndtri as ndtri64

    from jax_contact._math import ndtri

    p = np.concatenate(
        [
            np.logspace(-22.2, np.log10(0.49), 20_000),
            np.linspace(0.49, 0.51, 2001),
            1.0 - np.logspace(-7.2, np.log10(0.49), 10_000),
        ]
    ).astype(np.float32)
    want = ndtri64(p.astype(np.float64))
    got = np.asarray(jax.jit(ndtri)(p), np.float64)
    rel = np.abs(got - want) / np.maximum(np.abs(want), 1e-6)
    assert rel.max() < 3e-7, (rel.max(), p[rel.argmax()])
    # Near p = 1/2 the quantile is ~ sqrt(2 pi) (p - 1/2): absolute error at float32's level.
    assert np.abs(got - want).max() < 2e-6
    q = np.array([0.5, 0.3, 0.9, 1e-3, 1e-9, 1e-20], np.float32)
    grad = np.asarray(jax.jit(jax.vmap(jax.grad(ndtri)))(q), np.float64)
    x = ndtri64(q.astype(np.float64))
    np.testing.assert_allclose(grad, np.sqrt(2 * np.pi) * np.exp(0.5 * x * x), rtol=1e-5)


def test_truncated_normal_tail_against_scipy(x64):
    """Below the -8 switch the inverse CDF of N(0, 1) truncated to (-inf, b] solves Mills'
    form ``exp(-c t - t^2 / 2) c / (c + t) = v`` (c = |b|, x = b - t). Against scipy's
    float64 ``ndtri(v Phi(b))`` (exact to b ~ -37): max |x error| 4.7e-4 at b = -8 (1.9e-4 at
    -10, 8.7e-6 at -20), and the mean of t within 5e-4 of the truncated normal's. The
    exponential tail used before (t = -log(v) / c) put the mean of t 3.0 % too far at -8
    (2.0 % at -10), so Algorithm 1's Monte-Carlo touch-down came out about 1 % low for a
    sole estimated more than 8 sigma below the terrain (a helper's float64 oracle). The
    bulk (b > -8) is ndtri's; checked there to 1e-12."""
    from scipy import stats
    from scipy.special import ndtr, ndtri

    from jax_contact._math import upper_truncated_normal_icdf

    v = np.concatenate([np.logspace(-7, -1, 200), np.linspace(0.1, 1 - 1e-7, 800)])
    u = (np.arange(100_000) + 0.5) / 100_000  # midpoints: the mean of x by the rule of v
    for b, tol in ((-8.001, 6e-4), (-10.0, 2.5e-4), (-20.0, 1.5e-5), (-3.0, 1e-12)):
        got = np.asarray(upper_truncated_normal_icdf(jnp.asarray(v), jnp.asarray(b)))
        np.testing.assert_allclose(got, ndtri(v * ndtr(b)), rtol=0, atol=tol, err_msg=str(b))
        mean_t = b - np.mean(np.asarray(upper_truncated_normal_icdf(jnp.asarray(u), b)))
        exact_t = b - stats.truncnorm.mean(-np.inf, b)
        assert abs(mean_t / exact_t - 1.0) < 5e-4, (b, mean_t, exact_t)


def test_touchdown_quadrature_float32():
    """16-node quadrature vs the oracle's integral, where sigma_pf <= sigma_pi."""
    _compare_quadrature("float32", TOL32["touchdown"], TOL32["touchdown_log"])


def test_touchdown_quadrature_default_nodes():
    """The default rule (n_quad = 8, 64 evaluations) on the same sweep, float32.

    Measured on this sweep: max |P(C|A) error| 1.1e-5 (4 nodes 2.0e-4, 16 nodes 2.9e-6);
    relative error below 0.3 % wherever P > 1e-4. (A wider float64 sweep of 150 cases,
    sigma_pf <= sigma_pi, reached 1.2e-4 and 0.52 %: a helper's oracle, fifty-fourth
    session.) Stated tolerance: 3e-5 absolute plus 1 % relative.
    """
    assert make_params(make_noise(3)).n_quad == 8
    args = _td_sweep(11, 24, ratio_max=1.0)
    got = np.exp(np.asarray(_td_quad_fn(8)(*(jnp.asarray(a, "float32") for a in args))))
    _check("touchdown_q8", "float32", got, _td_ref(11, 24, 1.0), (3e-5, 1e-2))


def test_touchdown_quadrature_float64(x64):
    """The same in float64: the error left is the rule's truncation error."""
    _compare_quadrature("float64", TOL64["touchdown"], TOL64["touchdown_log"])


def test_touchdown_quadrature_keeps_float32_with_float64_enabled():
    """float32 readings in a process with float64 enabled get the float32 result.

    ``_math.ndtri``'s NumPy float64 constants (not weakly typed) turned its float32 quantiles
    into float64, so ``ndtr_ratio_pair`` took float64's deep-tail switch (-20) for float32
    ``erfc`` values, which underflow below about -13: P(C|A) 0.1715 instead of 0.2660 at
    (gap 0, sigma_pf 8 cm, sigma_pi 1 cm, u -0.5 m/s, sigma_u 0.05 m/s), the case a
    helper's oracle found (0.2541 by the nested integral; the 8-node rule's error there is
    the wide-sigma_pf one recorded below). Also: float64 inputs get float64 nodes, so the
    two entries sum to 1 to float64 round-off (float32 nodes left 4.5e-8).
    """
    from jax_contact._math import ndtri

    case = (0.0, 0.08, 0.01, -0.5, 0.05, 0.0025)
    fn = functools.partial(log_touchdown_quadrature, n_quad=8)
    want = np.exp(np.asarray(fn(*(jnp.asarray(v, jnp.float32) for v in case))))
    with jax.enable_x64(True):
        got = fn(*(jnp.asarray(v, jnp.float32) for v in case))
        assert got.dtype == jnp.float32
        assert ndtri(jnp.asarray([0.3, 1e-20], jnp.float32)).dtype == jnp.float32
        np.testing.assert_allclose(np.exp(np.asarray(got)), want, rtol=1e-6)
        p64 = np.exp(np.asarray(fn(*(jnp.asarray(v, jnp.float64) for v in case))))
        assert abs(p64.sum() - 1.0) < 1e-12
    # The 8-node rule where sigma_pf = 8 sigma_pi (its recorded coarse case, below).
    assert abs(want[0] - oracle.touchdown(*case)[0]) < 2e-2


def test_touchdown_quadrature_wide_foot_sigma():
    """Where sigma_pf > sigma_pi the 16-node Gauss-Hermite rule is coarse (recorded).

    The conditional touch-down probability falls from ~1 to ~0 over ~sigma_pi of foot
    height, a step that a 16-node rule over N(gap, sigma_pf^2) resolves poorly once
    sigma_pf is several sigma_pi (e.g. Table II's 4 cm base position noise over a 1 cm
    terrain or foothold). Largest |P(C|A) error| over 80 cases (sigma_pi 5 mm to 2 cm):

        sigma_pf / sigma_pi   1-2      2-4      4-8
        16 nodes              1.7e-5   1.3e-3   1.4e-2 (14 % relative)
        64 nodes              1.1e-6   3.3e-6   1.0e-3

    Stated tolerances over ratios 1 to 8: 3e-2 at 16 nodes, 3e-3 at 64.
    """
    rng = np.random.default_rng(5)
    n = 10
    spi = oracle._logu(rng, 0.005, 0.02, n)
    spf = spi * rng.uniform(1.0, 8.0, n)
    gap = rng.uniform(-1.0, 2.0, n) * spf
    u = rng.uniform(-2.5, 0.0, n)
    su = oracle._logu(rng, 0.01, 0.2, n)
    dt = np.full(n, 0.0025)
    args = [oracle.round32(x) for x in (gap, spf, spi, u, su, dt)]
    ref = np.array([oracle.touchdown(*map(float, c)) for c in zip(*args, strict=True)])
    for n_quad, atol in ((16, 3e-2), (64, 3e-3)):
        got = np.exp(np.asarray(_td_quad_fn(n_quad)(*map(jnp.asarray, args))))
        _check(f"touchdown_wide_q{n_quad}", "float32", got, ref, (atol, 0.0))


@functools.cache
def _mc_fn(n):
    def one(gap, spf, spi, u, su, dt, key):
        return log_touchdown_monte_carlo(gap, spf, spi, u, su, dt, n, key=key)

    return jax.jit(jax.vmap(one))


@pytest.mark.parametrize("n_samples", [500, 100_000])
def test_touchdown_monte_carlo(n_samples):
    """Algorithm 1 with n draws vs the oracle's integral, within 5 standard errors.

    One draw's value g = Phi(...) has variance E[g^2] - E[g]^2, which the oracle integrates;
    the n-sample mean has std sqrt(var / n). Tolerance 5 sqrt(var / n) plus 2e-6 for float32
    accumulation and the uniform draws' clipping at 1e-7 (a bias below 1e-7). P(A|A) is
    checked too (it averages 1 - g, so the same tolerance applies).
    """
    seed, n = (23, 12) if n_samples == 500 else (29, 6)
    args = _td_sweep(seed, n, ratio_max=8.0)
    keys = jax.random.split(jax.random.key(n_samples), n)
    got = np.exp(np.asarray(_mc_fn(n_samples)(*map(jnp.asarray, args), keys)))
    ref = _td_ref(seed, n, 8.0)
    sd = np.array([oracle.touchdown_std(*map(float, c)) for c in zip(*args, strict=True)])
    tol = 5.0 * sd / math.sqrt(n_samples) + 2e-6
    err = np.abs(got - ref).max(axis=1)
    _record(f"touchdown_mc{n_samples}", "float32", err, err / np.maximum(ref[:, 0], REL_FLOOR))
    _record(f"touchdown_mc{n_samples} / std err", "float32", err / (tol / 5.0), 0.0)
    assert (err <= tol).all(), (err, tol)
    assert (ref[:, 0] > 1e-3).sum() >= 3  # the sweep is not trivially ~0


# --------------------------------------------------------------------------- full step

T_STEPS = 24
N_ENVS, N_LEGS = 2, 2
SEQ_CONFIG = "nv8_3dof"


def _stance(t, env, leg):
    """The synthetic gait: stance or air in blocks of 6 steps, offset per foot."""
    return ((t + 2 * env + 3 * leg) // 6) % 2 == 0


# Two lost readings in the sequence: at UNINVOLVED a coordinate outside the foot's leg that
# neither its rows of M nor its Jacobian involve (another leg's joint) has a NaN velocity
# and acceleration, which no term reads (the step stays valid); at LOST the leg's own torque
# is NaN (the step is the transition-only prediction).
UNINVOLVED, LOST = (9, 1, 0), (15, 0, 1)


@functools.cache
def _sequence():
    """(T, n_envs, n_legs) NumPy measurements and one draw of the parameters."""
    nv, n_l, rows, _ = CONFIGS[SEQ_CONFIG]
    rng = np.random.default_rng(77)
    base = oracle.round32(oracle.random_case(rng, nv, n_l, rows))
    legs = [[np.sort(rng.permutation(nv)[:n_l]) for _ in range(N_LEGS)] for _ in range(N_ENVS)]
    seq = []
    for t in range(T_STEPS):
        row = []
        for e in range(N_ENVS):
            cells = []
            for g in range(N_LEGS):
                c = oracle.random_case(rng, nv, n_l, rows, _stance(t, e, g), legs[e][g])
                # Feet near one spot, so that the foothold memory is used once set.
                c["meas"]["p_f"][:2] = 0.05 * rng.normal(size=2)
                m = oracle.round32(c["meas"])
                if (t, e, g) == UNINVOLVED:
                    k = m["other_dofs"][-1]
                    m["M"][m["leg_dofs"], k] = m["M"][k, m["leg_dofs"]] = 0.0
                    m["J"][:, k] = 0.0
                    m["v_f"] = oracle.round32(m["J"] @ m["qd"])
                    m["qd"][k] = m["qdd"][k] = np.nan
                if (t, e, g) == LOST:
                    m["tau"][m["leg_dofs"][0]] = np.nan
                cells.append(m)
            row.append(cells)
        seq.append(row)
    return base, seq


def _seq_params(capped: bool):
    base, _ = _sequence()
    base = dict(base, scalars=dict(base["scalars"]), noise=dict(base["noise"]))
    # Joint-encoder-like position noise: sigma_pf ~ 1 mm, below sigma_pi (>= 2 cm), where
    # the 16-node quadrature is accurate (see test_touchdown_quadrature_wide_foot_sigma).
    base["noise"]["sigma_q"] = oracle.round32(np.full_like(base["noise"]["sigma_q"], 2e-3))
    caps = (0.99, 0.9, 0.99) if capped else (1.0, 1.0, 1.0)
    for k, c in zip(("cap_dynamics", "cap_diff_kinematics", "cap_kinematics"), caps, strict=True):
        base["scalars"][k] = float(np.float32(c))
    # The library's default reads the kinematic terms at the interval's end; the uncapped
    # (paper) run reads every term at its start.
    base["scalars"]["kinematics_lead"] = 1.0 if capped else 0.0
    _, _, rows, uni = CONFIGS[SEQ_CONFIG]
    return _params(base, rows, uni, touchdown="quadrature"), _oracle_params(base, rows, uni)


def _terrains():
    """Foothold memory over a flat floor: the flat model answers until a foothold is set;
    its height an average over stance steps (smoothing 0.3, so the average is exercised)."""
    jt = foothold_memory(flat(0.0, 0.2), sigma_foothold=0.02, growth=0.3, smoothing=0.3)
    f32 = np.float32
    ot = oracle.Foothold(
        oracle.Flat(0.0, float(f32(0.2))), float(f32(0.02)), float(f32(0.3)), float(f32(0.3))
    )
    return jt, ot


@functools.cache
def _oracle_run(capped: bool):
    _, seq = _sequence()
    p = _seq_params(capped)[1]
    terrain = _terrains()[1]
    # 1e-9 relative is ample next to the quadrature's own ~1e-6 error and twice as fast.
    td = functools.partial(oracle.touchdown, epsrel=1e-9)
    shape = (T_STEPS, N_ENVS, N_LEGS)
    out = {
        k: np.zeros(shape)
        for k in (
            "logit",
            "p_contact",
            "p_dynamics",
            "p_diff_kinematics",
            "p_kinematics",
            "p_takeoff",
            "p_touchdown",
            "takeoff_scale",
        )
    }
    out["force"] = np.zeros(shape + (3,))
    out["foothold"] = np.zeros(shape + (3,))
    for e in range(N_ENVS):
        for g in range(N_LEGS):
            b = oracle.init_belief(p)
            for t in range(T_STEPS):
                b, d = oracle.step(p, terrain, b, oracle.Meas(**seq[t][e][g]), td_fn=td)
                for k in out:
                    out[k][t, e, g] = b.foothold if k == "foothold" else d[k]
    return out


def _scan_steps(params, terrain, belief, meas):
    """step_batch over time, keeping the belief after every step (quadrature: key unused).

    ``run`` itself is compared with a Python loop of ``step_batch`` in test_core_properties.
    """

    def body(b, m):
        b, d = step_batch(params, terrain, b, m, key=jax.random.key(0))
        return b, (b, d)

    return jax.lax.scan(body, belief, meas)[1]


SCAN_STEPS = jax.jit(_scan_steps)


def _oracle_one_steps(capped, beliefs):
    """The oracle's step from JAX's own belief at t - 1, for every t (teacher forcing).

    This checks each step's recursion to round-off without the free-running sequences'
    accumulation of the quadrature's error; the touch-down integral is skipped here (its
    output is checked against the free-running oracle).
    """
    _, seq = _sequence()
    p = _seq_params(capped)[1]
    terrain = _terrains()[1]
    skip_td = lambda *a: np.array([0.5, 0.5])  # noqa: E731
    prev = [[oracle.init_belief(p) for _ in range(N_LEGS)] for _ in range(N_ENVS)]
    out = {k: np.zeros((T_STEPS, N_ENVS, N_LEGS)) for k in ("logit", "p_contact")}
    for t in range(T_STEPS):
        for e in range(N_ENVS):
            for g in range(N_LEGS):
                b = (
                    prev[e][g]
                    if t == 0
                    else oracle.Belief(
                        float(beliefs.logit[t - 1, e, g]),
                        np.asarray(beliefs.log_transition[t - 1, e, g], np.float64),
                        np.asarray(beliefs.foothold[t - 1, e, g], np.float64),
                        bool(beliefs.foothold_valid[t - 1, e, g]),
                    )
                )
                _, d = oracle.step(p, terrain, b, oracle.Meas(**seq[t][e][g]), td_fn=skip_td)
                out["logit"][t, e, g] = d["logit"]
                out["p_contact"][t, e, g] = d["p_contact"]
    return out


def _compare_run(capped: bool, dtype: str, tol):
    _, seq = _sequence()
    params = jax.tree.map(lambda x: jnp.asarray(x, dtype), _seq_params(capped)[0])
    terrain = jax.tree.map(lambda x: jnp.asarray(x, dtype), _terrains()[0])
    stacked = _stack([_stack([_stack(r) for r in row]) for row in seq])
    meas = LegMeasurement(**_to_jax(stacked, dtype))
    belief = init_belief_batch(params, N_ENVS, N_LEGS)
    # init_belief keeps the foothold in float32: under x64 the scan carry must be float64.
    belief = belief.replace(foothold=belief.foothold.astype(dtype))
    beliefs, diags = jax.tree.map(np.asarray, SCAN_STEPS(params, terrain, belief, meas))
    want_valid = np.ones(diags.valid.shape, bool)
    want_valid[LOST] = False
    np.testing.assert_array_equal(diags.valid, want_valid)

    one = _oracle_one_steps(capped, beliefs)
    _check("logit (one step)", dtype, beliefs.logit, one["logit"], tol["logit (one step)"])
    _check(
        "p_contact (one step)",
        dtype,
        diags.p_contact,
        one["p_contact"],
        tol["p_contact (one step)"],
    )

    ref = _oracle_run(capped)
    _check("logit (free run)", dtype, beliefs.logit, ref["logit"], tol["logit (free run)"])
    _check(
        "p_contact (free run)",
        dtype,
        diags.p_contact,
        ref["p_contact"],
        tol["p_contact (free run)"],
    )
    for k in ("p_dynamics", "p_diff_kinematics", "p_kinematics"):
        _check("p_term", dtype, getattr(diags, k), ref[k], tol["p_term"])
    atol, k_eps = TAKEOFF[dtype]
    extra = k_eps * ref["takeoff_scale"]
    _check("p_takeoff", dtype, diags.p_takeoff, ref["p_takeoff"], (atol, 0.0), extra)
    _check("touchdown", dtype, diags.p_touchdown, ref["p_touchdown"], tol["touchdown"])
    live = ref["p_touchdown"] > 2e-13  # above the floor exp(-30)
    _check(
        "touchdown_log",
        dtype,
        np.log(diags.p_touchdown[live]),
        np.log(ref["p_touchdown"][live]),
        tol["touchdown_log"],
    )
    scale = np.maximum(np.abs(ref["force"]).max(axis=-1, keepdims=True), 1.0)
    _check("force", dtype, diags.force / scale, ref["force"] / scale, tol["force"])
    _check("foothold", dtype, beliefs.foothold, ref["foothold"], tol["foothold"])
    # The beliefs moved both ways and the foothold memory was used.
    p = ref["p_contact"]
    assert (p > 0.99).any() and (p < 0.01).any()
    assert beliefs.foothold_valid[-1].all()


@pytest.mark.parametrize("capped", [True, False], ids=["capped", "uncapped"])
def test_run_float32(capped):
    _compare_run(capped, "float32", TOL32)


@pytest.mark.parametrize("capped", [True, False], ids=["capped", "uncapped"])
def test_run_float64(capped, x64):
    _compare_run(capped, "float64", TOL64)


def test_rank_one_gaussian_density_where_the_summed_covariance_fails_in_float32():
    """``log N(x; m, C + v v^T)`` with ``|v|`` 1e5 times the scale of ``C``: the stabilised
    contact's covariance on a nearly singular leg. Summed and factored in float32, the later
    pivots cancel to <= 0 (NaN or inf); the rank-one form matches float64 (hand-checked
    identity: matrix determinant lemma and Sherman-Morrison)."""
    from jax_contact._math import mvn_logpdf, mvn_logpdf_rank1

    C = np.diag([1.0, 2.0, 3.0]) + 0.1
    v = np.array([1e5, 2e5, -1e5])
    x, m = np.array([0.3, -0.2, 0.5]), np.zeros(3)
    S = C + np.outer(v, v)
    r = x - m
    want = -0.5 * (r @ np.linalg.solve(S, r) + np.linalg.slogdet(S)[1] + 3 * math.log(2 * math.pi))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    got = float(mvn_logpdf_rank1(f32(x), f32(m), f32(C), f32(v)))
    np.testing.assert_allclose(got, want, rtol=1e-5)
    summed = float(mvn_logpdf(f32(x), f32(m), f32(S)))
    assert not np.isclose(summed, want, rtol=1e-3)  # what the summed form gave instead


def test_a_non_finite_term_holds_the_prior_and_reports_the_step_invalid():
    """A term that comes out NaN on finite inputs (here: inv_damping 1e-8 on a rank-one leg
    Jacobian, whose float32 Cholesky fails) must not reach the belief: the step keeps the
    prior logit (eq. 1 alone) and says ``valid=False``, so the foot recovers at the next
    good step instead of staying NaN for the rest of the episode."""
    rng = np.random.default_rng(3)
    case = oracle.random_case(rng, 8, 3, (0, 1, 2), stance=True)
    leg = case["meas"]["leg_dofs"]
    J = case["meas"]["J"].copy()
    J[:, leg[1]] = 0.5 * J[:, leg[0]]
    J[:, leg[2]] = -1.3 * J[:, leg[0]]
    case["meas"].update(J=J, v_f=np.array([0.3, -0.2, -3.0]))
    case["scalars"].update(contact_damping=100.0, inv_damping=1e-8, outlier_prob=0.0)
    case = oracle.round32(case)
    params = _params(case, (0, 1, 2), True)
    meas = LegMeasurement(**_to_jax(case["meas"], jnp.float32))
    # Jitted (op by op, these two calls compiled every primitive on its own: ~30 s of a
    # cold suite), as the estimator runs.
    dyn, _ = jax.jit(dynamics_llr)(params, meas, jnp.array([0.0, 0.0, 1.0]))
    assert not np.isfinite(float(dyn))  # the failure this guards against
    terrain = flat(0.0, 0.05)
    belief = init_belief_batch(params, 1, 1)
    batch = jax.tree.map(lambda a: a[None, None], meas)
    new, diag = jax.jit(step_batch)(params, terrain, belief, batch, key=jax.random.key(0))
    # the prior of one step from the initial belief, eq. 1: sum over the previous state
    lt = np.asarray(belief.log_transition[0, 0], np.float64)
    lb = np.array(
        [np.log(jax.nn.sigmoid(belief.logit[0, 0])), np.log(jax.nn.sigmoid(-belief.logit[0, 0]))]
    )
    lp = np.logaddexp(lt[0] + lb[0], lt[1] + lb[1])
    assert bool(diag.valid[0, 0]) is False
    np.testing.assert_allclose(float(new.logit[0, 0]), lp[0] - lp[1], rtol=1e-5, atol=1e-5)
    assert np.isfinite(np.asarray(new.log_transition)).all()
