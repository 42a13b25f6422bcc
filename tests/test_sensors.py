"""Tests of envs/sensors.py: injected statistics, differentiation, latency, outliers, bias."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jax_contact.envs.sensors import (
    PRESETS,
    make_sensor_params,
    perturb_qpos,
    sensor_init,
    sensor_preset,
    sensor_step,
)

NV = 18  # a quadruped: free joint + 12 joints
DT = 0.0025
N_ENVS = 20000


def _home():
    qpos = np.zeros(NV + 1, np.float32)
    qpos[2] = 0.3
    # A non-trivial orientation: 0.3 rad about a tilted axis.
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    qpos[3:7] = np.concatenate([[np.cos(0.15)], np.sin(0.15) * axis])
    qpos[7:] = np.linspace(-1.0, 1.0, NV - 6)
    qvel = np.linspace(-0.5, 0.7, NV).astype(np.float32)
    tau = np.linspace(-5.0, 5.0, NV).astype(np.float32)
    tau[:6] = 0.0
    return jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(tau)


def _quat_log_np(q: np.ndarray) -> np.ndarray:
    """Rotation vector of a unit quaternion (w, x, y, z), float64."""
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    s = np.linalg.norm(q[1:])
    return 2.0 * np.arctan2(s, q[0]) * q[1:] / max(s, 1e-300)


def _quat_mul_np(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


@pytest.fixture(scope="module")
def one_step_batch():
    """One sensor step for N_ENVS independent keys, anymal_like without outliers/latency."""
    params = sensor_preset("anymal_like", NV, dt=DT).replace(
        outlier_prob=jnp.float32(0.0), latency=0
    )
    qpos, qvel, tau = _home()

    @jax.jit
    @jax.vmap
    def run(key):
        k0, k1 = jax.random.split(key)
        state = sensor_init(params, qpos, qvel, tau, key=k0)
        return sensor_step(params, state, qpos, qvel, tau, key=k1)[1]

    out = run(jax.random.split(jax.random.PRNGKey(0), N_ENVS))
    return params, (qpos, qvel, tau), jax.tree.map(np.asarray, out)


def test_white_noise_std_matches_preset(one_step_batch):
    params, (qpos, qvel, tau), out = one_step_batch
    qpos, qvel, tau = (np.asarray(x, np.float64) for x in (qpos, qvel, tau))
    # The bias after one step has std rw * sqrt(dt) (< 1e-3 of the white noise): negligible.
    sq, sqd, stau = (np.asarray(x) for x in (params.sigma_q, params.sigma_qd, params.sigma_tau))
    # Standard error of a sample std from N draws: sigma / sqrt(2 N) = 0.5 % here; 3 % is
    # about six standard errors.
    tol = 0.03
    np.testing.assert_allclose(np.std(out.qvel - qvel, axis=0), sqd, rtol=tol)
    np.testing.assert_allclose(np.std(out.qpos[:, 7:] - qpos[7:], axis=0), sq[6:], rtol=tol)
    np.testing.assert_allclose(np.std(out.qpos[:, 0:3] - qpos[0:3], axis=0), sq[0:3], rtol=tol)
    act = stau > 0
    np.testing.assert_allclose(np.std(out.tau - tau, axis=0)[act], stau[act], rtol=tol)
    # Unactuated coordinates (the base) carry no torque noise.
    np.testing.assert_array_equal(out.tau[:, ~act] - tau[~act], 0.0)
    # Orientation: the measured quaternion is the true one turned by a body-frame rotation
    # vector with std sigma_q[3:6] per axis, and stays normalised.
    norms = np.linalg.norm(out.qpos[:, 3:7].astype(np.float64), axis=1)
    np.testing.assert_allclose(norms, 1.0, atol=1e-6)
    q_true_inv = qpos[3:7] * np.array([1, -1, -1, -1])
    rotvecs = np.stack([_quat_log_np(_quat_mul_np(q_true_inv, q)) for q in out.qpos[:, 3:7]])
    np.testing.assert_allclose(np.std(rotvecs, axis=0), sq[3:6], rtol=tol)
    np.testing.assert_allclose(np.mean(rotvecs, axis=0), 0.0, atol=4 * sq[3] / np.sqrt(N_ENVS))


def test_qacc_std_of_backward_difference(one_step_batch):
    params, (_, qvel, _), out = one_step_batch
    # qacc = (v + n_1 - (v + n_0)) / dt with n_0, n_1 iid N(0, s^2) (init and first step
    # draw independent noise; the constant true velocity cancels), so its std is
    # sqrt(2) s / dt: 170 rad/s^2 for s = 0.3 rad/s at 400 Hz.
    # Where an accelerometer measures directly (the base's linear coordinates,
    # sigma_acc > 0), qacc is the true (zero) acceleration plus its own white noise.
    imu = np.asarray(params.sigma_acc) > 0
    np.testing.assert_array_equal(imu, np.arange(NV) < 3)
    expected = np.where(imu, params.sigma_acc, np.sqrt(2.0) * np.asarray(params.sigma_qd) / DT)
    np.testing.assert_allclose(np.std(out.qacc, axis=0), expected, rtol=0.03)
    np.testing.assert_allclose(expected[6], 169.7056, rtol=1e-5)
    np.testing.assert_allclose(expected[:3], 0.5)
    np.testing.assert_allclose(
        np.mean(out.qacc[:, :3], axis=0), 0.0, atol=4 * 0.5 / np.sqrt(N_ENVS)
    )


def test_qacc_is_exact_difference_without_noise():
    params = sensor_preset("ideal", NV, dt=DT)
    qpos, _, tau = _home()
    accel = jnp.linspace(-3.0, 3.0, NV)
    state = sensor_init(params, qpos, jnp.zeros(NV), tau, key=jax.random.PRNGKey(1))
    for k in range(1, 4):
        key = jax.random.PRNGKey(k)
        state, out = sensor_step(params, state, qpos, accel * k * DT, tau, key=key)
        # Ideal sensors: the backward difference of a linearly growing velocity is its slope.
        np.testing.assert_allclose(out.qacc, accel, rtol=1e-3, atol=1e-3)


def test_latency_delays_exactly_k_steps():
    k = 3
    params = make_sensor_params(NV, dt=DT, latency=k)
    qpos0, qvel0, tau0 = _home()
    step = jax.jit(sensor_step)
    state = sensor_init(params, qpos0, qvel0, tau0, key=jax.random.PRNGKey(0))
    outs, ins = [], []
    for n in range(10):
        qpos = qpos0.at[7:].add(0.01 * (n + 1))
        qvel = qvel0 + 0.1 * (n + 1)
        tau = tau0.at[6:].add(n + 1.0)
        state, out = step(params, state, qpos, qvel, tau, key=jax.random.PRNGKey(n + 1))
        outs.append(out)
        ins.append((qpos, qvel, tau))
    for n in range(10):
        if n < k:
            # Before the pipeline fills, the initial reading comes out.
            np.testing.assert_array_equal(outs[n].qvel, qvel0)
            np.testing.assert_array_equal(outs[n].qacc, 0.0)
        else:
            qpos, qvel, tau = ins[n - k]
            np.testing.assert_allclose(outs[n].qpos, qpos, atol=1e-7)
            np.testing.assert_array_equal(outs[n].qvel, qvel)
            np.testing.assert_array_equal(outs[n].tau, tau)


def test_outlier_rate_and_size():
    p_out, size = 0.02, 7.0
    joints = np.arange(NV) >= 6
    params = make_sensor_params(
        NV, dt=DT, outlier_prob=p_out, outlier_size=np.where(joints, size, 0.0)
    )
    qpos, qvel, tau = _home()
    state = sensor_init(params, qpos, qvel, tau, key=jax.random.PRNGKey(0))
    keys = jax.random.split(jax.random.PRNGKey(2), 4000)
    out = jax.jit(jax.vmap(lambda k: sensor_step(params, state, qpos, qvel, tau, key=k)[1]))(keys)
    err = np.asarray(out.qvel) - np.asarray(qvel)
    spikes = np.isclose(np.abs(err), size, atol=1e-5)
    # Only the noise-free remainder is exactly zero; every other sample is a spike.
    np.testing.assert_array_equal(spikes | (err == 0.0), True)
    assert not spikes[:, ~joints].any()
    n = spikes[:, joints].size
    rate = spikes[:, joints].mean()
    # Binomial: std of the rate sqrt(p (1 - p) / n) = 5.7e-4 for n = 48000; allow 4 std.
    assert abs(rate - p_out) < 4 * np.sqrt(p_out * (1 - p_out) / n)
    # Both signs occur about equally often.
    assert abs(np.mean(np.sign(err[spikes]))) < 0.05


def test_bias_random_walk_variance_grows_linearly():
    rw = np.where(np.arange(NV) < 6, 0.1, 0.0)
    params = make_sensor_params(NV, dt=DT, bias_rw_q=rw, bias_rw_qd=2 * rw)
    qpos, qvel, tau = _home()
    n_steps, n_envs = 400, 4000

    @jax.jit
    @jax.vmap
    def run(key):
        k0, k1 = jax.random.split(key)
        state = sensor_init(params, qpos, qvel, tau, key=k0)

        def body(s, k):
            s, out = sensor_step(params, s, qpos, qvel, tau, key=k)
            return s, (s.bias_q, out.qvel - qvel, out.qpos[0:3] - qpos[0:3])

        return jax.lax.scan(body, state, jax.random.split(k1, n_steps))[1]

    keys = jax.random.split(jax.random.PRNGKey(3), n_envs)
    bias_q, dqd, dpos = (np.asarray(x) for x in run(keys))
    for k in (49, 199, 399):
        t = (k + 1) * DT
        # Sum of k+1 iid increments of variance rw^2 dt: variance rw^2 t, linear in t.
        # Sample variance of 4000 draws has a relative std of sqrt(2/4000) = 2.2 %.
        np.testing.assert_allclose(np.var(bias_q[:, k, :6], axis=0), 0.01 * t, rtol=0.1)
        np.testing.assert_allclose(np.var(dqd[:, k, :6], axis=0), 0.04 * t, rtol=0.1)
        # Without white noise the measured base position is off by exactly the bias.
        np.testing.assert_allclose(dpos[:, k], bias_q[:, k, :3], atol=2e-6)
    np.testing.assert_array_equal(bias_q[:, :, 6:], 0.0)


def test_preset_latency_is_a_time_not_a_step_count():
    """anymal_like delays its readings 2.5 ms and harsh 7.5 ms at every period, in whole
    steps by Python's round (half to even): 2.5 ms / 4 ms = 0.625 -> 1 step, 7.5 / 4 =
    1.875 -> 2; at 1 kHz 2.5 -> 2 and 7.5 -> 8; at the control rate's 20 ms 0.125 and
    0.375 -> 0. The simulator and the wrapper read the same rule (they differed at any
    period but 2.5 ms: one step whatever its length in the simulator)."""
    from jax_contact.envs.contact_params import default_sensor_params
    from jax_contact.envs.robots import load_robot

    for dt, want in ((0.0025, (1, 3)), (0.004, (1, 2)), (0.001, (2, 8)), (0.02, (0, 0))):
        got = tuple(sensor_preset(n, NV, dt=dt).latency for n in ("anymal_like", "harsh"))
        assert got == want, dt
    leg = load_robot("planar_leg")
    wrapper = default_sensor_params("harsh", leg, 0.004)
    sim = sensor_preset("harsh", 3, dt=0.004, floating_base=False, base_dofs=(0,))
    assert wrapper.latency == sim.latency == 2


def test_presets_and_vmap_matches_loop():
    for name in PRESETS:
        p = sensor_preset(name, NV, dt=DT)
        assert p.nv == NV and p.nq == NV + 1
    harsh, anymal = (sensor_preset(n, NV, dt=DT) for n in ("harsh", "anymal_like"))
    np.testing.assert_allclose(harsh.sigma_qd, 2 * anymal.sigma_qd)
    assert (harsh.latency, anymal.latency) == (3, 1)
    np.testing.assert_allclose(anymal.sigma_qd[6:], 0.3)
    np.testing.assert_allclose(anymal.sigma_q[6:], 0.02)
    leg = sensor_preset("anymal_like", 3, dt=DT, floating_base=False, base_dofs=(0,))
    np.testing.assert_allclose(leg.sigma_qd, [0.2, 0.3, 0.3])  # Table II, planar leg
    # Table II's qdd entry for the rail (2 m/s^2, measured); the joints' qdd is differenced.
    np.testing.assert_allclose(leg.sigma_acc, [2.0, 0.0, 0.0])

    qpos, qvel, tau = _home()
    keys = jax.random.split(jax.random.PRNGKey(5), 3)
    state = sensor_init(anymal, qpos, qvel, tau, key=keys[0])
    batched = jax.vmap(lambda k: sensor_step(anymal, state, qpos, qvel, tau, key=k)[1])(keys)
    for i, k in enumerate(keys):
        single = sensor_step(anymal, state, qpos, qvel, tau, key=k)[1]
        for a, b in zip(jax.tree.leaves(batched), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(a[i], b, rtol=1e-6, atol=1e-6)


def test_perturb_qpos_rotation_vector():
    qpos, _, _ = _home()
    dq = jnp.zeros(NV).at[3:6].set(jnp.array([0.0, 0.0, 0.2]))
    out = np.asarray(perturb_qpos(qpos, dq, floating_base=True), np.float64)
    # q * exp(0.2 about body z): the rotation from true to measured is 0.2 rad about z.
    q_inv = np.asarray(qpos[3:7], np.float64) * np.array([1, -1, -1, -1])
    np.testing.assert_allclose(_quat_log_np(_quat_mul_np(q_inv, out[3:7])), [0, 0, 0.2], atol=1e-6)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="name must be one of"):
        sensor_preset("noisy", NV, dt=DT)
    with pytest.raises(ValueError, match="outlier_prob"):
        make_sensor_params(NV, dt=DT, outlier_prob=1.5)
    with pytest.raises(ValueError, match="sigma_qd"):
        make_sensor_params(NV, dt=DT, sigma_qd=np.ones(3))
    with pytest.raises(ValueError, match="latency"):
        make_sensor_params(NV, dt=DT, latency=-1)
    params = make_sensor_params(NV, dt=DT)
    qpos, qvel, tau = _home()
    with pytest.raises(ValueError, match="true_qvel"):
        sensor_init(params, qpos, qvel[:5], tau, key=jax.random.PRNGKey(0))
