"""Bad input: invalid parameters and shapes raise early and name the field; a NaN or inf in
one foot's measurement stays in that foot.

Batches use the planar leg (``oracle.random_planar``) and the session-wide jitted entry
points of ``conftest.py``, with the shapes and static parameters of
``test_core_properties`` so that the compilations are shared.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest

import jax_contact as jc
from jax_contact import (
    LegMeasurement,
    flat,
    init_belief,
    init_belief_batch,
    make_noise,
    make_params,
    step,
    validate_measurement,
    validate_params,
)

NOISE_FIELDS = (
    "sigma_q",
    "sigma_qd",
    "sigma_qdd",
    "sigma_d",
    "sigma_f",
    "sigma_J",
    "sigma_qd_prior",
)
MODES = ("quadrature", "monte_carlo")
PARAMS = {
    mode: make_params(make_noise(3, **oracle.TABLE_II), force_rows=(0, 2), touchdown=mode)
    for mode in MODES
}
TERRAIN = flat(0.0, 0.05)
N_ENVS, N_LEGS = 2, 2


# --------------------------------------------------------------------------- parameters


NV = 4  # distinct from the 3 world axes of sigma_f and sigma_J


def _length(field):
    return 3 if field in ("sigma_f", "sigma_J") else NV


@pytest.mark.parametrize("field", NOISE_FIELDS)
@pytest.mark.parametrize("value", [0.0, -1.0, np.nan, np.inf])
def test_noise_std_must_be_positive(field, value):
    with pytest.raises(ValueError, match=field):
        make_noise(NV, **{field: value})
    # One bad entry among good ones.
    arr = np.full(_length(field), 0.5)
    arr[1] = value
    with pytest.raises(ValueError, match=field):
        make_noise(NV, **{field: arr})
    # A params object edited after construction is caught by validate_params.
    good = make_params(make_noise(NV))
    bad_noise = good.noise.replace(**{field: jnp.asarray(arr, jnp.float32)})
    with pytest.raises(ValueError, match=field):
        validate_params(good.replace(noise=bad_noise))


@pytest.mark.parametrize("field", NOISE_FIELDS)
def test_noise_shape_is_checked(field):
    with pytest.raises(ValueError, match=field):
        make_noise(NV, **{field: np.ones(_length(field) + 1)})


@pytest.mark.parametrize("cap", ["cap_dynamics", "cap_diff_kinematics", "cap_kinematics"])
@pytest.mark.parametrize("value", [0.5, 0.3, 0.0, -0.2, 1.01, np.nan])
def test_caps_outside_half_open_interval(cap, value):
    with pytest.raises(ValueError, match=cap):
        make_params(make_noise(3), **{cap: value})


@pytest.mark.parametrize("value", [-0.1, 1.01, np.nan, np.inf])
def test_kinematics_lead_outside_unit_interval(value):
    with pytest.raises(ValueError, match="kinematics_lead"):
        make_params(make_noise(3), kinematics_lead=value)
    for ok in (0.0, 0.5, 1.0):
        assert float(make_params(make_noise(3), kinematics_lead=ok).kinematics_lead) == ok


@pytest.mark.parametrize("value", [-1.0, np.nan, np.inf])
def test_min_push_negative_or_not_finite(value):
    with pytest.raises(ValueError, match="min_push"):
        make_params(make_noise(3), min_push=value)


@pytest.mark.parametrize(
    "field, value",
    [("slip_prob", -0.1), ("slip_prob", 1.0), ("slip_prob", np.nan)]
    + [("slip_speed", v) for v in (0.0, -1.0, np.inf)],
)
def test_sliding_contact_out_of_range(field, value):
    with pytest.raises(ValueError, match=field):
        make_params(make_noise(3), **{field: value})


@pytest.mark.parametrize("cap", ["cap_dynamics", "cap_diff_kinematics", "cap_kinematics"])
def test_caps_inside_interval_are_accepted(cap):
    for value in (0.500001, 0.9, 1.0):
        make_params(make_noise(3), **{cap: value})


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(n_samples=0), "n_samples"),
        (dict(n_samples=-3), "n_samples"),
        (dict(n_samples=2.5), "n_samples"),
        (dict(n_quad=0), "n_quad"),
        # Accepted before a helper's audit: a bool count, a size that hangs the first step,
        # axes truncated to integers ((0.9, 2.5) became (0, 2)), a term that is no name.
        (dict(n_samples=True), "n_samples must be an int in \\[1, 100000\\], got True"),
        (dict(n_quad=10**6), "n_quad must be an int in \\[1, 128\\]"),
        (dict(force_rows=(0.9, 2.5)), "force_rows must hold integer axes"),
        (dict(force_rows=(True,)), "force_rows must hold integer axes"),
        (dict(terms=(["dynamics"],)), "terms must hold names"),
        (dict(touchdown="mc"), "touchdown"),
        (dict(touchdown=""), "touchdown"),
        (dict(force_rows=()), "force_rows"),
        (dict(force_rows=(0, 0)), "force_rows"),
        (dict(force_rows=(3,)), "force_rows"),
        (dict(force_rows=(-1, 2)), "force_rows"),
        (dict(force_rows=(0, 1, 2, 1)), "force_rows"),
        (dict(dt=0.0), "dt"),
        (dict(dt=np.nan), "dt"),
        (dict(stance_time=-0.3), "stance_time"),
        (dict(stance_time=0.002), "stance_time"),  # not above dt = 0.0025
        (dict(swing_time=0.0025), "swing_time"),
        (dict(takeoff_accel=0.0), "takeoff_accel"),
        (dict(inv_damping=-1e-6), "inv_damping"),
        (dict(initial_contact=0.0), "initial_contact"),
        (dict(initial_contact=1.0), "initial_contact"),
    ],
)
def test_bad_scalar_and_static_params(kwargs, field):
    with pytest.raises(ValueError, match=field):
        make_params(make_noise(3), **kwargs)


def test_the_first_belief_is_built_only_from_valid_parameters():
    """init_belief read any params: an initial_contact of 1 gave an infinite logit, NaN a
    NaN one, which a later step with other, valid params carried on (a helper's audit);
    a bool batch size was taken for 1."""
    params = make_params(make_noise(3))
    for bad in (1.0, np.nan):
        with pytest.raises(ValueError, match=r"init_belief: params: initial_contact must lie"):
            init_belief(params.replace(initial_contact=jnp.float32(bad)))
    with pytest.raises(ValueError, match=r"init_belief: params must be EstimatorParams"):
        init_belief({})
    with pytest.raises(ValueError, match=r"n_envs must be a positive int, got True"):
        init_belief_batch(params, True, 2)
    # p = 0.5: logit 0, the gait prior's transition, no foothold (the contract).
    b = init_belief(params.replace(initial_contact=jnp.float32(0.5)))
    assert float(b.logit) == 0.0 and not bool(b.foothold_valid)


def test_bad_static_field_after_replace():
    params = make_params(make_noise(3))
    for kwargs, field in [
        (dict(n_samples=0), "n_samples"),
        (dict(touchdown="exact"), "touchdown"),
        (dict(force_rows=(0, 5)), "force_rows"),
    ]:
        with pytest.raises(ValueError, match=field):
            validate_params(params.replace(**kwargs))


# --------------------------------------------------------------------------- shapes


def _meas_fields(lead=()):
    fields = oracle.planar_measurement(*oracle.planar_stance())
    return {k: np.broadcast_to(np.asarray(v), lead + np.shape(v)).copy() for k, v in fields.items()}


def _as_meas(fields) -> LegMeasurement:
    def conv(x):
        x = np.asarray(x)
        return jnp.asarray(x, jnp.int32 if np.issubdtype(x.dtype, np.integer) else jnp.float32)

    return LegMeasurement(**{k: conv(v) for k, v in fields.items()})


def test_validate_measurement_accepts_good_shapes():
    assert validate_measurement(LegMeasurement(**_meas_fields())) == ()
    assert validate_measurement(LegMeasurement(**_meas_fields((4, 2))), nv=3) == (4, 2)


@pytest.mark.parametrize(
    "field, bad_shape",
    [
        ("qdd", (4,)),
        ("tau", (2,)),
        ("M", (3, 2)),
        ("M", (3,)),
        ("h", (3, 1)),
        ("J", (2, 3)),
        ("J", (3, 4)),
        ("Jdot_qd", (2,)),
        ("p_f", (4,)),
        ("v_f", ()),
        ("foot_radius", (1,)),
        ("other_dofs", (2,)),
    ],
)
@pytest.mark.parametrize("lead", [(), (5,), (2, 3)], ids=["unbatched", "T", "envs_legs"])
def test_validate_measurement_names_field_and_shapes(field, bad_shape, lead):
    fields = _meas_fields(lead)
    fields[field] = np.zeros(lead + bad_shape, fields[field].dtype)
    with pytest.raises(ValueError, match=field) as info:
        validate_measurement(LegMeasurement(**fields))
    assert str(lead + bad_shape) in str(info.value)  # the shape it got
    if field != "other_dofs":
        assert "expected" in str(info.value)


def test_the_update_names_a_measurement_or_belief_that_does_not_fit():
    """Shapes are checked where the update is traced (static, no cost once compiled): a
    batched measurement given to ``step``, parameters of another robot, a belief of
    another batch, a negative batch size; each error names the argument and both shapes
    (they used to surface as XLA's slice or concatenate errors)."""
    from jax_contact import step_batch

    params, key = PARAMS["quadrature"], jax.random.key(0)
    one = _as_meas(_meas_fields())
    batched = _as_meas(_meas_fields((N_ENVS, N_LEGS)))
    belief = init_belief_batch(params, N_ENVS, N_LEGS)
    b0 = jax.tree.map(lambda x: x[0, 0], belief)
    with pytest.raises(ValueError, match=r"step: meas\.qdd has shape \(2, 2, 3\); expected \(3,\)"):
        step(params, TERRAIN, b0, batched, key=key)
    other = make_params(make_noise(NV), force_rows=(0, 2))  # nv 4, not 3
    with pytest.raises(ValueError, match=r"meas\.qdd has shape \(3,\); expected \(4,\).*nv = 4"):
        step(other, TERRAIN, init_belief_batch(other, 1, 1), one, key=key)
    # The batch is read from the belief, so the measurement is the one named.
    with pytest.raises(
        ValueError, match=r"step_batch: meas\.qdd .* \(2, 2, 3\); expected \(3, 2, 3\)"
    ):
        step_batch(params, TERRAIN, init_belief_batch(params, 3, N_LEGS), batched, key=key)
    with pytest.raises(ValueError, match=r"step_batch: belief has shape \(\).*\(n_envs, n_legs\)"):
        step_batch(params, TERRAIN, b0, batched, key=key)
    with pytest.raises(ValueError, match="n_envs must be a positive int, got -1"):
        init_belief_batch(params, -1, N_LEGS)
    # The belief's other leaves and the params' type, before anything reads them (an
    # audit: an AttributeError on None, XLA broadcasting errors for a (3, 3) transition).
    for field, value, want in (
        ("log_transition", np.zeros((3, 3)), r"\(3, 3\); expected \(2, 2\)"),
        ("foothold", np.zeros(2), r"\(2,\); expected \(3,\)"),
        ("foothold_valid", np.zeros(2, bool), r"\(2,\); expected \(\)"),
    ):
        with pytest.raises(ValueError, match=rf"step: belief\.{field} has shape {want}"):
            step(params, TERRAIN, b0.replace(**{field: value}), one, key=key)
    with pytest.raises(ValueError, match=r"step: belief must be a LegBelief .* got NoneType"):
        step(params, TERRAIN, None, one, key=key)
    with pytest.raises(ValueError, match=r"step: params must be EstimatorParams .* got dict"):
        step({}, TERRAIN, b0, one, key=key)
    # Every other field is checked too, named (they gave XLA slice or vmap size errors).
    bad_m = batched.replace(M=batched.M[..., :2, :2])
    with pytest.raises(ValueError, match=r"step_batch: measurement field 'M' has shape \(2, 2, 2"):
        step_batch(params, TERRAIN, belief, bad_m, key=key)
    bad_r = batched.replace(foot_radius=np.zeros((N_ENVS, 1)))
    with pytest.raises(ValueError, match=r"step_batch: measurement field 'foot_radius'"):
        step_batch(params, TERRAIN, belief, bad_r, key=key)
    as_list = one.replace(qd=np.asarray(one.qd).tolist())
    with pytest.raises(ValueError, match=r"step: measurement field 'qd' must be an array .* list"):
        step(params, TERRAIN, b0, as_list, key=key)
    # Leg indices out of range or repeated (a step that silently read the prior).
    assert one.leg_dofs.tolist() == [1, 2]  # the planar leg: hip and knee after the rail
    for legs in ([1, 3], [1, 1]):
        bad = one.replace(leg_dofs=np.array(legs, np.int32))
        with pytest.raises(ValueError, match=r"step: leg_dofs .* distinct indices into nv = 3"):
            step(params, TERRAIN, b0, bad, key=key)
    # The other indices: the rest of range(nv). A negative one wraps to a leg joint and an
    # overlap takes the wrong blocks of M and J (p_dynamics 0.110 -> 0.046 on one sample, a
    # helper's audit); one past nv was an IndexError naming nothing.
    assert one.other_dofs.tolist() == [0]
    for others in ([-1], [1], [7]):
        bad = one.replace(other_dofs=np.array(others, np.int32))
        with pytest.raises(
            ValueError,
            match=rf"step: other_dofs \[{others[0]}\] must be the nv - n_l = 1 indices of"
            r" range\(3\) not in leg_dofs \[1, 2\]: \[0\]",
        ):
            step(params, TERRAIN, b0, bad, key=key)


def test_validate_measurement_other_mistakes():
    fields = _meas_fields((2, 2))
    fields["p_f"] = np.zeros((2, 3, 3))  # a batch axis that disagrees with qd's
    with pytest.raises(ValueError, match="p_f"):
        validate_measurement(LegMeasurement(**fields))
    with pytest.raises(ValueError, match="nv"):
        validate_measurement(LegMeasurement(**_meas_fields()), nv=4)
    fields = _meas_fields()
    fields["q"] = np.zeros((2, 3))
    with pytest.raises(ValueError, match="'q'"):
        validate_measurement(LegMeasurement(**fields))
    fields = _meas_fields()
    fields["leg_dofs"] = fields["leg_dofs"].astype(np.float32)
    with pytest.raises(ValueError, match="leg_dofs"):
        validate_measurement(LegMeasurement(**fields))
    # A negative radius where the values are known (the sole is p_f,z - r, eq. 13: -0.02
    # moved P by 0.03, a helper's audit); NaN is a lost reading, not refused.
    fields = _meas_fields((2,))
    fields["foot_radius"] = np.array([0.02, -0.02])
    with pytest.raises(ValueError, match=r"'foot_radius' must be >= 0 \(m\), got -0\.02"):
        validate_measurement(LegMeasurement(**fields))
    fields["foot_radius"] = np.array([0.02, np.nan])
    assert validate_measurement(LegMeasurement(**fields)) == (2,)
    fields = _meas_fields()
    fields["leg_dofs"] = np.zeros((0,), np.int32)
    fields["other_dofs"] = np.arange(3, dtype=np.int32)
    with pytest.raises(ValueError, match="leg_dofs"):
        validate_measurement(LegMeasurement(**fields))


# --------------------------------------------------------------------------- NaN isolation


def _batch(seed):
    rng = np.random.default_rng(seed)
    cells = [oracle.random_planar(rng) for _ in range(N_ENVS * N_LEGS)]
    stacked = {k: np.stack([c[k] for c in cells]) for k in cells[0]}
    return {k: v.reshape((N_ENVS, N_LEGS) + v.shape[1:]) for k, v in stacked.items()}


def _belief(params, seed):
    rng = np.random.default_rng(seed)
    b = init_belief_batch(params, N_ENVS, N_LEGS)
    logit = jnp.asarray(rng.normal(scale=3.0, size=(N_ENVS, N_LEGS)), jnp.float32)
    # A non-trivial transition matrix, as after a real step.
    p_off = rng.uniform(0.001, 0.5, (N_ENVS, N_LEGS))
    p_on = rng.uniform(0.001, 0.5, (N_ENVS, N_LEGS))
    T = np.stack([np.stack([1 - p_off, p_off], -1), np.stack([p_on, 1 - p_on], -1)], -2)
    return b.replace(logit=logit, log_transition=jnp.asarray(np.log(T), jnp.float32))


def _transition_only(belief, e, g):
    """eq. 1 without the measurement: log sum_x' T(x' -> x) b(x'), as a logit."""
    l = float(belief.logit[e, g])
    T = np.exp(np.asarray(belief.log_transition[e, g], np.float64))
    b = np.array([1.0 / (1.0 + np.exp(-l)), 1.0 / (1.0 + np.exp(l))])
    prior = b @ T
    return np.log(prior[0]) - np.log(prior[1])


# (field, value, flat index) of readings the foot's terms read; the planar leg's
# coordinates are (base height, hip, knee), its leg (1, 2): M's flat 3 is M[1, 0], the
# hip's row in the base's column (M_lb).
BAD = [("qdd", np.nan, 1), ("M", np.nan, 3), ("J", np.inf, 1), ("p_f", -np.inf, 1),
       ("tau", np.inf, 1), ("v_f", np.nan, 1), ("foot_radius", np.nan, 0), ("qd", np.nan, 0),
       ("h", np.inf, 2)]  # fmt: skip


def _poisoned(fields, field, value, where, index):
    """A copy of ``fields`` with ``value`` at flat ``index`` of ``field``'s cell ``where``."""
    bad = {k: v.copy() for k, v in fields.items()}
    target = bad[field][where]
    if target.ndim:
        target.flat[index] = value
    else:
        bad[field][where] = value
    return bad


def _check_isolated(fn, params, field, value, where, index):
    fields = _batch(3)
    belief = _belief(params, 4)
    key = jax.random.key(9)
    clean_b, clean_d = fn(params, TERRAIN, belief, _as_meas(fields), key=key)
    e, g = where
    bad = _poisoned(fields, field, value, where, index)
    got_b, got_d = fn(params, TERRAIN, belief, _as_meas(bad), key=key)
    for i in range(N_ENVS):
        for j in range(N_LEGS):
            if (i, j) == (e, g):
                continue
            for x, y in zip(
                jax.tree.leaves((got_b, got_d)), jax.tree.leaves((clean_b, clean_d)), strict=True
            ):
                np.testing.assert_array_equal(np.asarray(x)[i, j], np.asarray(y)[i, j])
    assert not bool(got_d.valid[e, g]) and bool(clean_d.valid[e, g])
    logit = float(got_b.logit[e, g])
    assert np.isfinite(logit)
    np.testing.assert_allclose(logit, _transition_only(belief, e, g), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(float(got_d.p_contact[e, g]), 1 / (1 + np.exp(-logit)), rtol=1e-6)
    # Next transition: the gait prior; foothold kept; terms and force flagged as NaN.
    dt, ts, tsw = (float(params.dt), float(params.stance_time), float(params.swing_time))
    prior_t = np.log([[1 - dt / ts, dt / ts], [dt / tsw, 1 - dt / tsw]])
    np.testing.assert_allclose(np.asarray(got_b.log_transition[e, g]), prior_t, rtol=1e-6)
    np.testing.assert_array_equal(
        np.asarray(got_b.foothold[e, g]), np.asarray(belief.foothold[e, g])
    )
    assert bool(got_b.foothold_valid[e, g]) == bool(belief.foothold_valid[e, g])
    assert np.isnan(float(got_d.p_dynamics[e, g])) and np.isnan(np.asarray(got_d.force[e, g])).all()
    for leaf in jax.tree.leaves(got_b):
        assert np.isfinite(np.asarray(leaf, np.float64)).all()


def test_nan_foot_eager():
    """One foot op by op (no jit): the same transition-only prediction.

    Unbatched, so that it reuses the primitives compiled for test_core_properties'
    jit-vs-no-jit test; batch isolation is checked jitted, in both modes, below.
    """
    params = PARAMS["quadrature"]
    fields = _batch(3)
    belief = _belief(params, 4)
    bad = {k: v[1, 0].copy() for k, v in fields.items()}
    bad["qdd"][2] = np.nan
    b = jax.tree.map(lambda x: x[1, 0], belief)
    got_b, got_d = step(params, TERRAIN, b, _as_meas(bad), key=jax.random.key(0))
    assert not bool(got_d.valid)
    np.testing.assert_allclose(
        float(got_b.logit), _transition_only(belief, 1, 0), rtol=1e-5, atol=1e-5
    )
    assert np.isnan(float(got_d.p_dynamics))
    assert np.isfinite(np.asarray(got_b.log_transition)).all()


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("i", range(len(BAD)), ids=[f"{f}-{v}" for f, v, _ in BAD])
def test_nan_stays_in_its_foot_jit(mode, i, jit_step_batch):
    field, value, index = BAD[i]
    where = (i % N_ENVS, (i // 2) % N_LEGS)
    _check_isolated(jit_step_batch, PARAMS[mode], field, value, where, index)


# Readings no term reads: q (the model quantities were evaluated at it), the base's row of
# M (flat 1: M[0, 1]), the leg's own velocities (v_f stands for them), the base's torque.
UNREAD = [("q", np.nan, 1), ("M", np.nan, 1), ("qd", np.inf, 2), ("tau", np.nan, 0)]


@pytest.mark.parametrize("i", range(len(UNREAD)), ids=[f"{f}-{j}" for f, _, j in UNREAD])
def test_a_nan_the_terms_do_not_read_changes_nothing(i, jit_step_batch):
    """The validity check covers what the foot's terms read, not every field: a NaN
    elsewhere leaves the foot valid and its step bitwise the clean one."""
    params = PARAMS["quadrature"]
    fields = _batch(3)
    belief = _belief(params, 4)
    key = jax.random.key(9)
    clean = jit_step_batch(params, TERRAIN, belief, _as_meas(fields), key=key)
    field, value, index = UNREAD[i]
    bad = _poisoned(fields, field, value, (1, 1), index)
    got = jit_step_batch(params, TERRAIN, belief, _as_meas(bad), key=key)
    for x, y in zip(jax.tree.leaves(got), jax.tree.leaves(clean), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert bool(np.all(got[1].valid))


T_RUN = 6  # as test_core_properties, to share run's compilation


def test_nan_in_run_recovers(jit_run):
    """A NaN at step 2 in one foot of a run: that step is the transition-only prediction,
    the other feet are untouched, and the foot recovers once its measurements are good."""
    params = PARAMS["monte_carlo"]
    rng = np.random.default_rng(21)
    seq = []
    for t in range(T_RUN):
        cells = [oracle.random_planar(rng, stance=(t < 3) != (k % 2 == 0)) for k in range(4)]
        stacked = {k: np.stack([c[k] for c in cells]) for k in cells[0]}
        seq.append({k: v.reshape((N_ENVS, N_LEGS) + v.shape[1:]) for k, v in stacked.items()})
    clean = {k: np.stack([s[k] for s in seq]) for k in seq[0]}
    bad = {k: v.copy() for k, v in clean.items()}
    bad["qdd"][2, 0, 1, 1] = np.nan
    belief = init_belief_batch(params, N_ENVS, N_LEGS)
    key = jax.random.key(4)
    clean_b, clean_d = jit_run(params, TERRAIN, belief, _as_meas(clean), key=key)
    got_b, got_d = jit_run(params, TERRAIN, belief, _as_meas(bad), key=key)

    valid = np.asarray(got_d.valid)
    assert not valid[2, 0, 1] and valid.sum() == valid.size - 1
    # The other feet: bitwise the clean run, beliefs (envs, legs, ...) and diagnostics
    # (T, envs, legs, ...).
    others = [(e, g) for e in range(N_ENVS) for g in range(N_LEGS) if (e, g) != (0, 1)]
    for x, y in zip(jax.tree.leaves(got_b), jax.tree.leaves(clean_b), strict=True):
        for e, g in others:
            np.testing.assert_array_equal(np.asarray(x)[e, g], np.asarray(y)[e, g])
    for x, y in zip(jax.tree.leaves(got_d), jax.tree.leaves(clean_d), strict=True):
        for e, g in others:
            np.testing.assert_array_equal(np.asarray(x)[:, e, g], np.asarray(y)[:, e, g])
    # Step 2 of that foot: eq. 1 alone, from step 1's belief and transition.
    p1 = float(got_d.p_contact[1, 0, 1])
    to, td = float(got_d.p_takeoff[1, 0, 1]), float(got_d.p_touchdown[1, 0, 1])
    np.testing.assert_allclose(
        float(got_d.p_contact[2, 0, 1]), p1 * (1 - to) + (1 - p1) * td, rtol=1e-5
    )
    # Recovery: valid again, and back on the clean run's belief.
    assert valid[3:, 0, 1].all()
    p_got = np.asarray(got_d.p_contact[:, 0, 1])
    p_clean = np.asarray(clean_d.p_contact[:, 0, 1])
    assert abs(p_got[-1] - p_clean[-1]) < 1e-3, (p_got, p_clean)
    assert np.isfinite(np.asarray(got_b.logit)).all()


# ------------------------------------------------- the API's other arguments (a user's trial)


def test_key_terrain_and_params_are_named_before_anything_is_traced():
    """A key that is not a PRNG key, a terrain that is not a model, and parameters edited
    out of range after construction (``replace`` skips make_params' checks; ``dt = 0``
    gave P = 1 exactly) are refused by name where the update is traced."""
    from jax_contact import run, step_batch

    params, key = PARAMS["quadrature"], jax.random.key(0)
    one = _as_meas(_meas_fields())
    b0 = jax.tree.map(lambda x: x[0, 0], init_belief_batch(params, 1, 1))
    for bad in (None, 0):
        with pytest.raises(ValueError, match=r"step: key must be a PRNG key.*jax\.random\.key"):
            step(params, TERRAIN, b0, one, key=bad)
    with pytest.raises(ValueError, match=r"step: terrain must be a terrain model.*NoneType"):
        step(params, None, b0, one, key=key)
    # Built from its class, jc.flat's checks skipped: a NaN plane skipped every update.
    nan_plane = jc.FlatTerrain(height=jnp.float32(jnp.nan), sigma=jnp.float32(0.05))
    with pytest.raises(ValueError, match=r"step: terrain: FlatTerrain\.height must be a finite"):
        step(params, nan_plane, b0, one, key=key)
    no_growth = jc.foothold_memory(TERRAIN).replace(growth=jnp.float32(-1.0))
    with pytest.raises(ValueError, match=r"step: terrain: FootholdMemory\.growth must be"):
        step(params, no_growth, b0, one, key=key)
    for field, value in (("cap_dynamics", 2.0), ("dt", 0.0)):
        with pytest.raises(ValueError, match=rf"step: params: {field} "):
            step(params.replace(**{field: jnp.float32(value)}), TERRAIN, b0, one, key=key)
    # One key per env (jax.random.split's output): jax.random.split then raised 'split
    # accepts a single key ... use jax.vmap', the wrong advice for step_batch.
    batch = init_belief_batch(params, 2, 1)
    meas2 = _as_meas(_meas_fields((2, 1)))
    for keys in (jax.random.split(key, 2), jax.random.split(jax.random.PRNGKey(0), 2)):
        with pytest.raises(ValueError, match=r"step_batch: key must be one PRNG key .*\(2,"):
            step_batch(params, TERRAIN, batch, meas2, key=keys)
    step_batch(params, TERRAIN, batch, meas2, key=jax.random.PRNGKey(0))  # a raw key is one
    noise = params.noise.replace(sigma_qdd=-params.noise.sigma_qdd)
    with pytest.raises(ValueError, match=r"step_batch: params: noise\.sigma_qdd"):
        step_batch(
            params.replace(noise=noise),
            TERRAIN,
            init_belief_batch(params, 1, 1),
            _as_meas(_meas_fields((1, 1))),
            key=key,
        )
    with pytest.raises(ValueError, match=r"params must be EstimatorParams.*dict.*load_params"):
        validate_params({"dt": 0.0025})
    # A sequence whose fields are not arrays fails before lax.scan reads it.
    seq = _meas_fields((3, 1, 1))
    with pytest.raises(ValueError, match=r"run: measurement field 'qd' must be an array.*list"):
        run(params, TERRAIN, init_belief_batch(params, 1, 1), _as_meas(seq).replace(
            qd=seq["qd"].tolist()), key=key)  # fmt: skip
    # The envs before the time axis: named as the sequence, with the axes it needs (it
    # said "meas.qdd ... expected (3, 3, 3)" with no word of time).
    swapped = _as_meas(_meas_fields((2, 5, 1)))  # (n_envs, T, n_legs) for a belief of 2 envs
    with pytest.raises(
        ValueError,
        match=r"run: meas_seq\.qdd has shape \(2, 5, 1, 3\); expected \(2, 2, 1, 3\) \(the"
        r" time axis T = 2, then the belief's batch \(2, 1\).*time first",
    ):
        run(params, TERRAIN, init_belief_batch(params, 2, 1), swapped, key=key)
    for dtype in ("U8", np.complex64, bool):  # a bool was read as torques of 0 and 1 N m
        bad = _as_meas(seq).replace(tau=np.zeros((3, 1, 1, 3), dtype))
        with pytest.raises(ValueError, match=r"run: measurement field 'tau' has dtype"):
            run(params, TERRAIN, init_belief_batch(params, 1, 1), bad, key=key)


def test_sequence_bce_checks_its_truth():
    from jax_contact import sequence_bce

    params, key = PARAMS["quadrature"], jax.random.key(0)
    seq = _as_meas(_meas_fields((4, 1, 2)))
    with pytest.raises(ValueError, match=r"sequence_bce: truth has shape \(4, 1\); expected"):
        sequence_bce(params, TERRAIN, seq, np.ones((4, 1)), key=key)
    # One step short: the measurement's time axis is named against the truth's.
    with pytest.raises(ValueError, match=r"sequence_bce: meas_seq\.qdd has shape \(4, 1, 2, 3\);"
                       r" expected \(3, 1, 2, 3\)"):  # fmt: skip
        sequence_bce(params, TERRAIN, seq, np.ones((3, 1, 2)), key=key)
    # {0, 2} gave a negative cross-entropy.
    with pytest.raises(ValueError, match=r"truth must hold 0 and 1 \(or bool\) only, found \[2"):
        sequence_bce(params, TERRAIN, seq, np.array([0, 2, 0, 0] * 2).reshape(4, 1, 2), key=key)


def test_robot_measurement_leg_dofs_must_be_static_tuples():
    from jax_contact import RobotMeasurement, validate_robot_measurement

    f = _meas_fields()
    legs = np.array([[1, 2]])  # e.g. after a round trip through np.savez
    meas = RobotMeasurement(
        **{k: f[k] for k in ("q", "qd", "qdd", "tau", "M", "h")},
        **{k: np.asarray(f[k])[None] for k in ("J", "Jdot_qd", "p_f", "v_f", "foot_radius")},
        leg_dofs=legs,
    )
    with pytest.raises(ValueError, match=r"leg_dofs must be a tuple of per-leg tuples of int"
                       r".*ndarray.*tuple\(map\(tuple, a\.tolist\(\)\)\)"):  # fmt: skip
        validate_robot_measurement(meas)
    fixed = meas.replace(leg_dofs=tuple(map(tuple, legs.tolist())))
    assert validate_robot_measurement(fixed) == ()


def test_a_nan_belief_is_reported_invalid_and_stays_in_its_foot(jit_step_batch):
    """A belief set to NaN by hand cannot be updated: its foot reports valid False at
    every step (it read True), and no other foot changes."""
    params = PARAMS["quadrature"]
    fields = _batch(3)
    belief = _belief(params, 4)
    key = jax.random.key(9)
    clean_b, clean_d = jit_step_batch(params, TERRAIN, belief, _as_meas(fields), key=key)
    bad = belief.replace(logit=belief.logit.at[1, 0].set(jnp.nan))
    got_b, got_d = jit_step_batch(params, TERRAIN, bad, _as_meas(fields), key=key)
    assert np.asarray(clean_d.valid).all()
    np.testing.assert_array_equal(np.asarray(got_d.valid), [[True, True], [False, True]])
    others = [(0, 0), (0, 1), (1, 1)]
    for x, y in zip(jax.tree.leaves((got_b, got_d)), jax.tree.leaves((clean_b, clean_d)),
                    strict=True):  # fmt: skip
        for e, g in others:
            np.testing.assert_array_equal(np.asarray(x)[e, g], np.asarray(y)[e, g])


def test_flat_terrain_can_be_traced_and_differentiated():
    """``flat`` checked its arguments with NumPy, so ``grad`` or ``vmap`` over the plane's
    height failed; a traced height is taken as it is. Reference: central differences of
    the same step (float64, the kinematics term depends on the height smoothly)."""
    with jax.enable_x64(True):
        params = make_params(make_noise(3, **oracle.TABLE_II), force_rows=(0, 2))
        fields = oracle.planar_measurement(*oracle.planar_stance())
        meas = LegMeasurement(
            **{
                k: jnp.asarray(v, jnp.int32 if "dofs" in k else jnp.float64)
                for k, v in fields.items()
            }  # fmt: skip
        )
        b0 = jax.tree.map(lambda x: x[0, 0], init_belief_batch(params, 1, 1))
        key = jax.random.key(0)

        def p(h):
            return step(params, flat(height=h, sigma=0.05), b0, meas, key=key)[1].p_kinematics

        h0, eps = -0.01, 1e-5  # the sole 1 cm above the plane (below it: neutral)
        fd = (float(p(h0 + eps)) - float(p(h0 - eps))) / (2 * eps)
        g = float(jax.grad(p)(h0))
        assert abs(fd) > 1.0  # the height matters here
        np.testing.assert_allclose(g, fd, rtol=1e-5)
        batched = jax.vmap(p)(jnp.array([h0, -h0]))
        np.testing.assert_allclose(np.asarray(batched), [float(p(h0)), float(p(-h0))], rtol=1e-6)
    with pytest.raises(ValueError, match="sigma must be a finite scalar > 0"):
        flat(0.0, sigma=-1.0)


def test_float64_numpy_readings_outside_jit_warn_nothing():
    """A measurement of float64 NumPy arrays (a control loop's readings), eager: JAX warned
    from inside the update ("Explicitly requested dtype float64 requested in eye is not
    available"). Now converted at the entry, the same P as from float32 arrays."""
    import warnings

    params, key = PARAMS["quadrature"], jax.random.key(0)
    fields = _meas_fields()
    f64 = LegMeasurement(
        **{k: v.astype(np.float64) if v.dtype.kind == "f" else v for k, v in fields.items()}
    )
    b0 = jax.tree.map(lambda x: x[0, 0], init_belief_batch(params, 1, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, d64 = step(params, TERRAIN, b0, f64, key=key)
    _, d32 = step(params, TERRAIN, b0, _as_meas(fields), key=key)
    assert d64.p_contact.dtype == jnp.float32
    np.testing.assert_array_equal(d64.p_contact, d32.p_contact)


def test_float64_params_on_float32_readings_warn_nothing(recwarn):
    """Under x64, float64 parameters on float32 readings (a float32 log) scattered the
    float64 force into a float32 array: JAX's FutureWarning, an error in later releases."""
    import warnings

    with jax.enable_x64(True):
        params = jax.tree.map(
            lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x,
            PARAMS["quadrature"],
        )
        one = _as_meas(_meas_fields())  # float32
        b0 = jax.tree.map(lambda x: x[0, 0], init_belief_batch(params, 1, 1))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _, d = step(params, TERRAIN, b0, one, key=jax.random.key(0))
        assert d.force.dtype == jnp.float64 and bool(d.valid)


def test_the_belief_keeps_its_type_under_x64():
    """Under x64, float32 parameters and belief fed float64 readings computed the new
    belief in float64, so a hand-written loop of ``step`` traced a second program after
    its first step (``run`` cast its carry back; ``step`` did not). Every entry point now
    returns the belief in the type it was given, the P as before."""
    params, key = PARAMS["quadrature"], jax.random.key(0)
    fields = _meas_fields()
    b0 = jax.tree.map(lambda x: x[0, 0], init_belief_batch(params, 1, 1))
    with jax.enable_x64(True):
        f64 = LegMeasurement(
            **{
                k: jnp.asarray(v, jnp.float64) if v.dtype.kind == "f" else jnp.asarray(v)
                for k, v in fields.items()
            }  # fmt: skip
        )
        b1, _ = step(params, TERRAIN, b0, f64, key=key)
        for got, was in zip(jax.tree.leaves(b1), jax.tree.leaves(b0), strict=True):
            assert got.dtype == was.dtype
        # The same update in float64 throughout, cast: the same belief to float32 rounding.
        b0_64 = jax.tree.map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x, b0)
        ref, _ = step(params, TERRAIN, b0_64, f64, key=key)
        assert ref.logit.dtype == jnp.float64
        np.testing.assert_allclose(float(b1.logit), float(ref.logit), rtol=1e-6)
