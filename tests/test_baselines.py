"""Tests of the GM observer and the kinematic threshold detector against float64 oracles."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jax_contact.baselines import (
    gm_init,
    gm_run,
    gm_run_batch,
    gm_step,
    kinematic_detect,
    kinematic_detect_batch,
    make_gm_params,
    make_kinematic_params,
)
from jax_contact.types import LegMeasurement, TerrainQuery

NV = 9  # 3 base coordinates and two 3-joint legs
LEGS = (np.array([3, 4, 5]), np.array([6, 7, 8]))
DT = 0.0025
# One jitted entry point per function, shared by every test (one compile per dtype / shape).
GM_RUN = jax.jit(gm_run)
GM_RUN_BATCH = jax.jit(gm_run_batch)


def _spd(rng, n):
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


def _other(leg):
    return np.setdiff1d(np.arange(NV), leg)


def _meas(lead, rng, leg, **fields):
    """A LegMeasurement with leading axes ``lead``, random where ``fields`` says nothing."""
    shape = {
        "q": (NV + 1,),
        "qd": (NV,),
        "qdd": (NV,),
        "tau": (NV,),
        "h": (NV,),
        "Jdot_qd": (3,),
        "p_f": (3,),
        "v_f": (3,),
        "foot_radius": (),
    }
    out = {k: rng.normal(size=lead + s) for k, s in shape.items()}
    out["foot_radius"] = np.full(lead, 0.02)
    out["M"] = np.broadcast_to(_spd(rng, NV), lead + (NV, NV)).copy()
    out["J"] = rng.normal(scale=0.3, size=lead + (3, NV))
    out["leg_dofs"] = np.broadcast_to(leg, lead + leg.shape).astype(np.int32)
    other = _other(leg)
    out["other_dofs"] = np.broadcast_to(other, lead + other.shape).astype(np.int32)
    out.update(fields)
    return out


def _to_jax(d, dtype):
    return LegMeasurement(
        **{k: jnp.asarray(v, jnp.int32 if k.endswith("dofs") else dtype) for k, v in d.items()}
    )


def gm_oracle(K_I, threshold, damping, dt, m, normal):
    """Float64 loop over the recursion of ``gm_step``, force by the normal equations.

    Returns residual (T, n_l), force (T, 3), normal force (T,), contact (T,).
    """
    qd, tau, h, M, J, leg = m["qd"], m["tau"], m["h"], m["M"], m["J"], m["leg_dofs"][0]
    T = qd.shape[0]
    n_l = leg.size
    rows = M[0][leg, :]
    p0 = rows @ qd[0]
    s = np.zeros(n_l)
    r = np.zeros(n_l)
    force = np.zeros(3)
    m_prev = rows
    p_prev = p0
    held = 0  # lost readings since the last update: the next one integrates over them too
    out_r, out_f, out_n = [np.zeros(n_l)], [np.zeros(3)], [0.0]
    for k in range(1, T):
        # What the observer reads: the leg's rows of M, the velocities they involve
        # (another leg's, times exact zeros, are not), the leg's tau, h and J columns.
        rows_k = M[k][leg, :]
        qd_k = np.where(np.any(rows_k != 0, axis=0), qd[k], 0.0)
        read = (rows_k, qd_k, tau[k][leg], h[k][leg], J[k][:, leg])
        if all(np.all(np.isfinite(x)) for x in read):
            rows = rows_k
            # The gap's held + 1 steps run one by one, as the observer would with this
            # reading's torques held over them and the momentum moving linearly from the
            # last update's to this one (one step without a gap).
            n, p_k = held + 1, rows @ qd_k
            for j in range(1, n + 1):
                s = s + (tau[k][leg] - h[k][leg] + r) * dt + (rows - m_prev) @ qd_k / n
                r = K_I * (p_prev + (p_k - p_prev) * j / n - p0 - s)
            held = 0
            p_prev = p_k
            jl = J[k][:, leg]
            force = -np.linalg.solve(jl @ jl.T + damping * np.eye(3), jl @ r)
            m_prev = rows
        else:
            held += 1
        out_r.append(r.copy())
        out_f.append(force.copy())
        out_n.append(-normal @ force)
    fn = np.array(out_n)
    return np.array(out_r), np.array(out_f), fn, fn > threshold


@pytest.fixture(scope="module")
def gm_params():
    return make_gm_params(K_I=40.0, threshold=5.0, damping=1e-6)


def _moving_meas(rng, T: int) -> dict:
    """T steps of one foot whose mass matrix changes every step (so the Mdot qd term
    matters), with torques large enough for non-trivial forces."""
    m = _meas((T,), rng, LEGS[0])
    m["M"] = np.stack([_spd(rng, NV) for _ in range(T)])
    m["tau"] = 20.0 * rng.normal(size=(T, NV))
    return m


def test_gm_matches_float64_oracle_with_varying_mass_and_a_nan_step(gm_params):
    T = 40
    m = _moving_meas(np.random.default_rng(0), T)
    m["tau"][17, 4] = np.nan  # held step: state and output repeat step 16's
    m["tau"][23, 2] = np.nan  # a base torque, which the leg's rows do not read: not held
    m["qdd"][29, 3] = np.inf  # nor an acceleration
    # 12 lost readings: the catch-up spans 13 steps, K_I n dt = 1.3 (one step's gain over
    # the gap overshot there; the observer's 13 steps give 1 - 0.9^13 = 0.75).
    m["tau"][25:37, 4] = np.nan
    normal = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    K_I, th, damp = (float(gm_params.K_I), float(gm_params.threshold), float(gm_params.damping))
    ref_r, ref_f, ref_n, ref_c = gm_oracle(K_I, th, damp, DT, m, normal)
    with jax.enable_x64(True):
        out = GM_RUN(gm_params, _to_jax(m, jnp.float64), DT, jnp.asarray(normal))
        np.testing.assert_allclose(out.residual, ref_r, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(out.force, ref_f, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(out.force_normal, ref_n, rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(out.contact, ref_c)
        expected_valid = np.ones(T, bool)
        expected_valid[17] = False
        expected_valid[25:37] = False
        np.testing.assert_array_equal(out.valid, expected_valid)
    assert np.abs(ref_n).max() > 1.0  # the comparison saw non-trivial forces
    assert 0 < ref_c.sum() < T  # and both flags


def test_gm_leaves_another_legs_nan_in_that_leg(gm_params):
    # A tree's mass matrix couples two legs through the base only: M[leg 0, leg 1] is
    # exactly 0, and so is J's leg-1 block for foot 0. NaN readings of leg 1's joints
    # (velocity, torque, bias force) then enter none of foot 0's sums: its observer is
    # the float64 oracle on the clean readings, every step valid.
    T = 30
    m = _moving_meas(np.random.default_rng(11), T)
    m["M"][:, LEGS[0][:, None], LEGS[1]] = 0.0
    m["M"][:, LEGS[1][:, None], LEGS[0]] = 0.0
    m["J"][:, :, LEGS[1]] = 0.0
    bad = {k: v.copy() for k, v in m.items()}
    bad["qd"][5:9, LEGS[1][0]] = np.nan
    bad["tau"][12, LEGS[1][1]] = np.inf
    bad["h"][20, LEGS[1][2]] = np.nan
    normal = np.array([0.0, 0.0, 1.0])
    K_I, th, damp = (float(gm_params.K_I), float(gm_params.threshold), float(gm_params.damping))
    ref = gm_oracle(K_I, th, damp, DT, m, normal)
    with jax.enable_x64(True):
        out = GM_RUN(gm_params, _to_jax(bad, jnp.float64), DT, jnp.asarray(normal))
    np.testing.assert_array_equal(out.valid, np.ones(T, bool))
    np.testing.assert_allclose(out.force_normal, ref[2], rtol=1e-9, atol=1e-9)
    assert np.abs(ref[2]).max() > 1.0


def test_gm_starts_at_the_first_finite_reading_of_each_env(gm_params):
    # A NaN in an env's first readings used to seed p_0 with NaN: that env's force was NaN
    # for good while later steps were marked valid. The observer now starts at the first
    # finite reading, so env 1 from step 2 on is the float64 oracle run on readings 2..,
    # and env 0 (finite throughout) is untouched.
    T = 30
    m = _moving_meas(np.random.default_rng(7), T)
    bad = {k: v.copy() for k, v in m.items()}
    bad["qd"][0, 4] = np.nan
    bad["tau"][1, 3] = np.inf
    batch = {k: np.stack([m[k], bad[k]], axis=1)[:, :, None] for k in m}  # (T, E=2, L=1)
    normal = np.array([0.0, 0.0, 1.0])
    K_I, th, damp = (float(gm_params.K_I), float(gm_params.threshold), float(gm_params.damping))
    with jax.enable_x64(True):
        out = GM_RUN_BATCH(gm_params, _to_jax(batch, jnp.float64), DT, jnp.asarray(normal))
    ref_all = gm_oracle(K_I, th, damp, DT, m, normal)
    ref_late = gm_oracle(K_I, th, damp, DT, {k: v[2:] for k, v in m.items()}, normal)
    np.testing.assert_allclose(out.force_normal[:, 0, 0], ref_all[2], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(out.valid[:, 1, 0], [False, False] + [True] * (T - 2))
    np.testing.assert_array_equal(out.force_normal[:2, 1, 0], [0.0, 0.0])
    np.testing.assert_allclose(out.residual[2:, 1, 0], ref_late[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(out.force_normal[2:, 1, 0], ref_late[2], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(out.contact[2:, 1, 0], ref_late[3])
    assert np.abs(ref_late[2]).max() > 1.0


def _constant_mass_meas(rng, leg, M, J, **readings) -> dict:
    """A (T,) sequence of one foot's measurements with a constant mass matrix and
    Jacobian, ``readings`` (qd, qdd, tau, h) given per step."""
    T = readings["qd"].shape[0]
    return _meas(
        (T,),
        rng,
        leg,
        M=np.broadcast_to(M, (T, NV, NV)),
        J=np.broadcast_to(J, (T, 3, NV)),
        **readings,
    )


def test_gm_moving_leg_with_constant_mass_follows_closed_form(gm_params):
    # Constant M, qd_k = qd_{k-1} + qdd_k dt (backward difference), tau_k = M qdd_k + h_k
    # + J^T F with a constant foot force F. Then in gm_step, p_k - p_{k-1} = M_l qdd_k dt
    # = (tau_k - h_k)_l dt - J_l^T F dt and the Mdot term is 0, so with S_k the sum:
    #   r_k/K_I = p_k - p_0 - S_k = r_{k-1}/K_I - (J_l^T F + r_{k-1}) dt
    #   => r_k = (1 - K_I dt) r_{k-1} - K_I dt J_l^T F,  r_0 = 0
    #   => r_k = -J_l^T F (1 - (1 - K_I dt)^k),
    # exactly, however the leg moves; a leg standing still (qdd = 0) is the special case.
    # The force estimate is the same fraction of F (J_l square, damping negligible), and
    # the time constant is -dt / log(1 - K_I dt) ~ 1/K_I.
    rng = np.random.default_rng(1)
    T = 60
    leg = LEGS[1]
    M = _spd(rng, NV)
    J = rng.normal(scale=0.3, size=(3, NV))
    J[:, LEGS[0]] = 0.0  # the other leg's joints do not move this foot
    F = np.array([3.0, -4.0, -60.0])  # foot pushes down: ground reaction +60 N up
    qdd = rng.normal(size=(T, NV))
    qd = 0.5 + np.cumsum(qdd * DT, axis=0)
    h = rng.normal(size=(T, NV))
    tau = qdd @ M.T + h + J.T @ F
    m = _constant_mass_meas(rng, leg, M, J, qd=qd, qdd=qdd, tau=tau, h=h)
    K_I = float(gm_params.K_I)
    frac = 1.0 - (1.0 - K_I * DT) ** np.arange(T)
    normal = np.array([0.0, 0.0, 1.0])
    with jax.enable_x64(True):
        params = make_gm_params(K_I=K_I, threshold=30.0, damping=1e-12)
        out = GM_RUN(params, _to_jax(m, jnp.float64), DT, jnp.asarray(normal))
        np.testing.assert_allclose(
            out.residual, -frac[:, None] * (J[:, leg].T @ F), rtol=1e-7, atol=1e-8
        )
        np.testing.assert_allclose(out.force, frac[:, None] * F, rtol=1e-7, atol=1e-7)
        # Normal reaction 60 frac_k crosses 30 N when frac_k > 1/2.
        np.testing.assert_array_equal(out.contact, 60.0 * frac > 30.0)
    assert 0 < np.sum(60.0 * frac > 30.0) < T


def test_gm_planar_leg_force_map_stays_in_the_plane():
    # A 2-joint leg moving in the x-z plane: J_l has a zero y row, so J_l J_l^T is singular.
    # Solving J_l^T F = -r in the plane gives F_xz = -(J_xz^T)^-1 r and F_y = 0 (hand:
    # the least-squares solution lies in the range of J_l). In float32 the y component
    # must not pick up round-off amplified by 1 / damping.
    rng = np.random.default_rng(2)
    leg = np.array([3, 4])
    j_xz = np.array([[0.3, 0.1], [-0.2, 0.25]])
    r = np.array([4.0, -7.0])
    J = np.zeros((3, NV))
    J[0, leg], J[2, leg] = j_xz[0], j_xz[1]
    m = _meas((), rng, leg, J=J, qd=np.zeros(NV))
    m["M"] = _spd(rng, NV)
    meas = _to_jax(m, jnp.float32)
    params = make_gm_params(K_I=100.0, threshold=1.0, damping=1e-6)
    state = gm_init(meas)
    # One step from rest with tau - h = -r / (K_I dt) on the leg rows gives residual r:
    # r_1 = K_I (0 - 0 - (tau - h) dt) with qd = 0 and constant M.
    tau = np.zeros(NV)
    tau[leg] = -r / (100.0 * DT)
    meas = meas.replace(tau=jnp.asarray(tau, jnp.float32), h=jnp.zeros(NV, jnp.float32))
    _, out = gm_step(params, state, meas, DT, jnp.array([0.0, 0.0, 1.0]))
    f_xz = -np.linalg.solve(j_xz.T, r)
    np.testing.assert_allclose(out.residual, r, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(out.force)[[0, 2]], f_xz, rtol=1e-4)
    assert abs(float(out.force[1])) < 1e-4 * np.abs(f_xz).max()
    np.testing.assert_allclose(out.force_normal, -f_xz[1], rtol=1e-4)


def test_gm_batch_equals_loop(gm_params):
    rng = np.random.default_rng(3)
    T, E, L = 12, 2, 2
    per = {}
    for e in range(E):
        for l in range(L):
            m = _meas((T,), rng, LEGS[l])
            m["tau"] = 10.0 * rng.normal(size=(T, NV))
            per[e, l] = m
    batch = {
        k: np.stack([np.stack([per[e, l][k] for l in range(L)], 1) for e in range(E)], 1)
        for k in per[0, 0]
    }
    normal = np.array([0.0, 0.0, 1.0])
    out = GM_RUN_BATCH(gm_params, _to_jax(batch, jnp.float32), DT, normal)
    assert out.force_normal.shape == (T, E, L)
    for e in range(E):
        for l in range(L):
            ref = GM_RUN(gm_params, _to_jax(per[e, l], jnp.float32), DT, normal)
            np.testing.assert_allclose(out.residual[:, e, l], ref.residual, rtol=1e-5, atol=1e-4)
            np.testing.assert_allclose(out.force[:, e, l], ref.force, rtol=1e-5, atol=1e-3)
            np.testing.assert_array_equal(out.contact[:, e, l], ref.contact)


def test_gm_bad_input_raises():
    with pytest.raises(ValueError, match="K_I"):
        make_gm_params(K_I=-1.0)
    with pytest.raises(ValueError, match="threshold"):
        make_gm_params(threshold=0.0)
    with pytest.raises(ValueError, match="damping"):
        make_gm_params(damping=float("nan"))
    rng = np.random.default_rng(4)
    params = make_gm_params(K_I=40.0)
    m = _meas((5,), rng, LEGS[0])
    good = _to_jax(m, jnp.float32)
    with pytest.raises(ValueError, match=r"meas_seq\.M"):
        gm_run(params, good.replace(M=good.M[:, :3]), DT, jnp.ones(3))
    with pytest.raises(ValueError, match=r"meas_seq\.other_dofs"):
        gm_run(params, good.replace(other_dofs=good.other_dofs[:, :2]), DT, jnp.ones(3))
    with pytest.raises(ValueError, match="normal"):
        gm_run(params, good, DT, jnp.ones(2))
    # K_I dt = 40 * 0.1 = 4 > 1: the pole 1 - K_I dt = -3 diverges.
    with pytest.raises(ValueError, match=r"params has K_I = 40 1/s, and K_I dt = 4 > 1"):
        gm_run(params, good, 0.1, jnp.ones(3))
    with pytest.raises(ValueError, match="dt"):
        gm_run(params, good, -DT, jnp.ones(3))
    with pytest.raises(ValueError, match="leading axes"):
        gm_run_batch(params, good, DT, jnp.ones(3))


# ----------------------------------------------------------------------------- kinematic


def kinematic_oracle(h_th, v_th, mode, p_f, v_f, radius, height, normal):
    """Float64 loops: gap = e . (p_f - r e - p_i), p_i = (x_f, y_f, height), and speed."""
    B = p_f.shape[:-1]
    gap, speed, contact = np.zeros(B), np.zeros(B), np.zeros(B, bool)
    for idx in np.ndindex(*B):
        e = normal[idx]
        p_i = np.array([p_f[idx][0], p_f[idx][1], height[idx]])
        gap[idx] = e @ (p_f[idx] - radius[idx] * e - p_i)
        speed[idx] = np.linalg.norm(v_f[idx]) if mode == "norm" else abs(e @ v_f[idx])
        contact[idx] = gap[idx] < h_th and speed[idx] < v_th
    return gap, speed, contact


@pytest.mark.parametrize("mode", ["norm", "normal"])
def test_kinematic_batch_matches_oracle(mode):
    rng = np.random.default_rng(5)
    B = (6, 2, 3)
    m = _meas(B, rng, LEGS[0])
    m["p_f"] = np.concatenate([rng.normal(size=B + (2,)), rng.uniform(0, 0.06, B + (1,))], -1)
    m["v_f"] = rng.normal(scale=0.3, size=B + (3,))
    height = rng.uniform(-0.01, 0.01, B)
    tilt = rng.normal(scale=0.2, size=B + (3,)) + np.array([0.0, 0.0, 1.0])
    normal = tilt / np.linalg.norm(tilt, axis=-1, keepdims=True)
    params = make_kinematic_params(
        height_threshold=0.02, velocity_threshold=0.3, velocity_mode=mode
    )
    gap, speed, contact = kinematic_oracle(
        0.02, 0.3, mode, m["p_f"], m["v_f"], m["foot_radius"], height, normal
    )
    terrain = TerrainQuery(
        height=jnp.asarray(height, jnp.float32),
        sigma=jnp.full(B, 0.05, jnp.float32),
        normal=jnp.asarray(normal, jnp.float32),
    )
    out = kinematic_detect_batch(params, _to_jax(m, jnp.float32), terrain)
    np.testing.assert_allclose(out.gap, gap, atol=1e-6)
    np.testing.assert_allclose(out.speed, speed, rtol=1e-5)
    # Cases within float32 round-off of a threshold could flip; the seed has none.
    assert np.min(np.abs(gap - 0.02)) > 1e-5 and np.min(np.abs(speed - 0.3)) > 1e-5
    np.testing.assert_array_equal(out.contact, contact)
    assert 0 < contact.sum() < contact.size
    # The batch equals the unbatched function, one element at a time.
    idx = (4, 1, 2)
    one = kinematic_detect(
        params,
        _to_jax({k: v[idx] for k, v in m.items()}, jnp.float32),
        TerrainQuery(
            height=terrain.height[idx], sigma=terrain.sigma[idx], normal=terrain.normal[idx]
        ),
    )
    np.testing.assert_allclose(one.gap, out.gap[idx], atol=1e-7)
    assert bool(one.contact) == bool(out.contact[idx])


def test_kinematic_hand_case_and_bad_input():
    # Flat ground at 0.1 m, foot radius 0.02 m, centre at 0.13 m: sole gap 0.01 m < 0.02 m.
    # Speed (0.1, 0, -0.2): norm 0.2236 < 0.3 -> contact ("normal" mode: 0.2, below).
    rng = np.random.default_rng(6)
    m = _meas((), rng, LEGS[0], p_f=np.array([5.0, -3.0, 0.13]), v_f=np.array([0.1, 0.0, -0.2]))
    terrain = TerrainQuery(
        height=jnp.float32(0.1), sigma=jnp.float32(0.05), normal=jnp.array([0.0, 0.0, 1.0])
    )
    params = make_kinematic_params(0.02, 0.3)
    out = kinematic_detect(params, _to_jax(m, jnp.float32), terrain)
    np.testing.assert_allclose(out.gap, 0.01, atol=1e-6)
    np.testing.assert_allclose(out.speed, np.sqrt(0.05), rtol=1e-6)
    assert bool(out.contact)
    # With a 0.2 m/s threshold the same foot (0.2236 m/s) is too fast -> air.
    slow = make_kinematic_params(0.02, 0.2)
    assert not bool(kinematic_detect(slow, _to_jax(m, jnp.float32), terrain).contact)
    # 0.21 m/s separates the modes: the norm (0.2236) is above it -> air; the component
    # along the normal, |e . v_f| = 0.2 (the sideways 0.1 left out), is below -> contact.
    norm = kinematic_detect(make_kinematic_params(0.02, 0.21), _to_jax(m, jnp.float32), terrain)
    normal = kinematic_detect(
        make_kinematic_params(0.02, 0.21, velocity_mode="normal"), _to_jax(m, jnp.float32), terrain
    )
    assert not bool(norm.contact) and bool(normal.contact)
    np.testing.assert_allclose(normal.speed, 0.2, rtol=1e-6)
    np.testing.assert_allclose(normal.gap, 0.01, atol=1e-6)
    with pytest.raises(ValueError, match="height_threshold"):
        make_kinematic_params(height_threshold=-0.01)
    with pytest.raises(ValueError, match="velocity_threshold"):
        make_kinematic_params(velocity_threshold=0.0)
    with pytest.raises(ValueError, match="velocity_mode"):
        make_kinematic_params(velocity_mode="tangent")
    with pytest.raises(ValueError, match=r"terrain\.normal"):
        batch = _to_jax(_meas((4,), rng, LEGS[0]), jnp.float32)
        kinematic_detect_batch(params, batch, terrain.replace(normal=jnp.ones((3, 3))))
    # A terrain model where its answer belongs (an AttributeError on '.normal' before).
    from jax_contact import flat

    with pytest.raises(ValueError, match=r"terrain must be a TerrainQuery, got FlatTerrain.*query"):
        kinematic_detect_batch(params, batch, flat())


def test_gm_after_lost_readings_integrates_over_the_gap():
    # The closed form above with constant qdd and h (so tau constant): once converged,
    # r = -J_l^T F exactly. After n lost readings p has moved by (n + 1) M_l qdd dt; the
    # integral must advance by (tau - h + r)_l (n + 1) dt for r to stay -J_l^T F. Advancing
    # it by one dt (before a helper's audit) left r off by K_I n (M qdd)_l dt: a force
    # spike of tens of newtons on a swinging leg after a gap.
    rng = np.random.default_rng(4)
    T, gap = 400, slice(300, 303)
    leg = LEGS[1]
    M = _spd(rng, NV)
    J = rng.normal(scale=0.3, size=(3, NV))
    J[:, LEGS[0]] = 0.0
    F = np.array([3.0, -4.0, -60.0])
    qdd = np.broadcast_to(rng.normal(scale=5.0, size=NV), (T, NV))
    qd = 0.5 + np.cumsum(qdd * DT, axis=0)
    h = np.broadcast_to(rng.normal(size=NV), (T, NV))
    tau = qdd @ M.T + h + J.T @ F
    tau[gap] = np.nan  # three lost readings
    m = _constant_mass_meas(rng, leg, M, J, qd=qd, qdd=qdd, tau=tau, h=h)
    with jax.enable_x64(True):
        params = make_gm_params(K_I=40.0, threshold=30.0, damping=1e-12)
        out = GM_RUN(params, _to_jax(m, jnp.float64), DT, jnp.array([0.0, 0.0, 1.0]))
        force = np.asarray(out.force)
    # Converged before the gap (1 - 0.9^299 ~ 1), held through it, and F right after it.
    np.testing.assert_allclose(force[299], F, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(out.valid)[gap], False)
    np.testing.assert_allclose(force[303:], np.broadcast_to(F, (T - 303, 3)), atol=1e-6)
    ref = gm_oracle(40.0, 30.0, 1e-12, DT, m, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(force, ref[1], atol=1e-6)
