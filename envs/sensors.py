"""Proprioceptive sensor model: what the estimator would see on a real robot.

The simulator knows the true state; a robot does not. :func:`sensor_step` turns the true
``qpos``, ``qvel`` and joint torques of one physics (or estimator) step into noisy readings:

- white Gaussian noise on positions, velocities and torques, one standard deviation per
  generalised velocity coordinate (``nv``); positions are perturbed in the tangent space,
  so a free joint's quaternion is turned by a small random rotation and stays normalised;
- a slowly varying bias (a Gaussian random walk) on positions and velocities, meant for the
  base-state estimate, whose drift a real state estimator has;
- velocity outliers: with probability ``outlier_prob`` a velocity sample is replaced by the
  true value plus a spike of fixed size and random sign (ANYmal's joint velocity outliers,
  the reason the paper caps the differential-kinematics term);
- ``qacc`` as the backward difference of the *noisy* velocity at the sensor rate, as on
  ANYmal (its std is ``sqrt(2) sigma_qd / dt`` for white velocity noise);
- a latency of ``latency`` steps: readings come out of a ring buffer ``latency`` steps late.

Model error (a payload the estimator does not know about, the paper's robustness test) is a
property of the simulated robot, not of the sensors: :func:`jax_contact.envs.payload.add_mass`.

Coordinates: with ``floating_base=True`` the model's first joint is a free joint (``qpos[0:7]``
position and unit quaternion ``w, x, y, z``; ``qvel[0:6]`` linear velocity in the world frame
and angular velocity in the body frame, MuJoCo's convention) and every other joint is a hinge
or slide (``qpos[7 + i]`` <-> ``qvel[6 + i]``). Otherwise ``nq == nv`` and ``qpos[i]`` <->
``qvel[i]`` (e.g. the planar leg's rail, hip and knee).

Functions are pure and unbatched; ``jax.vmap`` them over environments.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

PRESETS = ("ideal", "anymal_like", "harsh")
# The presets' reading delay, s: one estimator period at the paper's 400 Hz (a choice;
# `harsh` has three). Kept in seconds, so a preset at another period delays as long.
PRESET_LATENCY_S = 0.0025


@struct.dataclass
class SensorParams:
    """Noise, bias, outlier and latency settings of the sensor model.

    Per-coordinate entries have length ``nv`` (velocity space; for a free joint: 3 linear,
    then 3 rotational about the body axes). A zero entry switches that effect off.

    Attributes:
      sigma_q: (nv,) white position noise, m and rad.
      sigma_qd: (nv,) white velocity noise, m/s and rad/s.
      sigma_tau: (nv,) white generalised-force noise, N and N m (zero on unactuated
        coordinates: nothing measures a torque there).
      bias_rw_q: (nv,) random-walk intensity of the position bias, m/sqrt(s) and
        rad/sqrt(s): after ``t`` seconds the bias has variance ``bias_rw_q**2 * t``.
      bias_rw_qd: (nv,) random-walk intensity of the velocity bias, m/s/sqrt(s) and
        rad/s/sqrt(s).
      outlier_prob: () probability that one velocity sample (one coordinate, one step) is an
        outlier.
      outlier_size: (nv,) size of a velocity outlier's spike, m/s and rad/s.
      sigma_acc: (nv,) white noise of a directly measured acceleration, m/s^2 and rad/s^2.
        Where it is > 0 that coordinate's ``qacc`` is the true acceleration over the step
        plus this noise (an IMU's accelerometer for the base's linear coordinates); where
        it is 0, ``qacc`` is the backward difference of the measured velocity.
      dt: () period between two calls of :func:`sensor_step`, s; the differentiation step
        of ``qacc`` and the time step of the bias random walk.
      latency: static, delay of the readings in steps (0: none).
      floating_base: static, whether ``qpos[0:7]`` / ``qvel[0:6]`` are a free joint.
    """

    sigma_q: jax.Array
    sigma_qd: jax.Array
    sigma_tau: jax.Array
    bias_rw_q: jax.Array
    bias_rw_qd: jax.Array
    outlier_prob: jax.Array
    outlier_size: jax.Array
    sigma_acc: jax.Array
    dt: jax.Array
    latency: int = struct.field(pytree_node=False, default=0)
    floating_base: bool = struct.field(pytree_node=False, default=True)

    @property
    def nv(self) -> int:
        return int(np.shape(self.sigma_qd)[0])

    @property
    def nq(self) -> int:
        return self.nv + 1 if self.floating_base else self.nv


@struct.dataclass
class Readings:
    """One step of sensor readings, as the estimator receives them.

    Attributes:
      qpos: (nq,) measured generalised coordinates (unit quaternion for a free joint).
      qvel: (nv,) measured generalised velocities.
      qacc: (nv,) backward difference of the measured velocities, ``(qvel_k - qvel_{k-1})
        / dt``, m/s^2 and rad/s^2.
      tau: (nv,) measured generalised actuation forces, N and N m.
    """

    qpos: jax.Array
    qvel: jax.Array
    qacc: jax.Array
    tau: jax.Array


@struct.dataclass
class SensorState:
    """What the sensor model carries from one step to the next.

    Attributes:
      prev_qvel: (nv,) the previous measured velocity (before the latency), for ``qacc``.
      prev_true_qvel: (nv,) the previous true velocity, for directly measured
        accelerations (``sigma_acc > 0``).
      bias_q: (nv,) current position bias (tangent space), m and rad.
      bias_qd: (nv,) current velocity bias, m/s and rad/s.
      buffer: the last ``latency`` readings, every leaf with a leading axis of length
        ``max(latency, 1)``; slot ``head`` holds the oldest.
      head: () int32 index of the oldest reading in ``buffer``.
    """

    prev_qvel: jax.Array
    prev_true_qvel: jax.Array
    bias_q: jax.Array
    bias_qd: jax.Array
    buffer: Readings
    head: jax.Array


# --------------------------------------------------------------------------------------
# Construction and validation


def _vec(name: str, value, nv: int) -> jax.Array:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((nv,), float(arr))
    if arr.shape != (nv,):
        raise ValueError(f"{name} must be a scalar or have shape ({nv},) (nv), got {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must be finite and >= 0 everywhere, got min {arr.min()!r}")
    return jnp.asarray(arr, dtype=jnp.float32)


def make_sensor_params(
    nv: int,
    *,
    dt: float,
    floating_base: bool = True,
    sigma_q: float | Sequence[float] = 0.0,
    sigma_qd: float | Sequence[float] = 0.0,
    sigma_tau: float | Sequence[float] = 0.0,
    bias_rw_q: float | Sequence[float] = 0.0,
    bias_rw_qd: float | Sequence[float] = 0.0,
    outlier_prob: float = 0.0,
    outlier_size: float | Sequence[float] = 0.0,
    sigma_acc: float | Sequence[float] = 0.0,
    latency: int = 0,
) -> SensorParams:
    """Builds and validates :class:`SensorParams`; scalars broadcast to every coordinate.

    The defaults are ideal sensors (no noise, bias, outliers or latency).

    Raises:
      ValueError: naming the argument, for a bad shape, a negative or non-finite entry,
        ``outlier_prob`` outside [0, 1], a non-positive ``dt``, a negative ``latency``, or
        ``nv < 7`` with ``floating_base``.
    """
    if not isinstance(nv, int | np.integer) or nv < 1:
        raise ValueError(f"nv must be a positive int, got {nv!r}")
    if floating_base and nv < 6:
        raise ValueError(f"nv must be >= 6 with floating_base=True (a free joint), got {nv}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite float > 0, got {dt!r}")
    if not (0.0 <= float(outlier_prob) <= 1.0):
        raise ValueError(f"outlier_prob must lie in [0, 1], got {outlier_prob!r}")
    if not isinstance(latency, int | np.integer) or latency < 0:
        raise ValueError(f"latency must be an int >= 0 (steps), got {latency!r}")
    return SensorParams(
        sigma_q=_vec("sigma_q", sigma_q, nv),
        sigma_qd=_vec("sigma_qd", sigma_qd, nv),
        sigma_tau=_vec("sigma_tau", sigma_tau, nv),
        bias_rw_q=_vec("bias_rw_q", bias_rw_q, nv),
        bias_rw_qd=_vec("bias_rw_qd", bias_rw_qd, nv),
        outlier_prob=jnp.float32(outlier_prob),
        outlier_size=_vec("outlier_size", outlier_size, nv),
        sigma_acc=_vec("sigma_acc", sigma_acc, nv),
        dt=jnp.float32(dt),
        latency=int(latency),
        floating_base=bool(floating_base),
    )


def sensor_preset(
    name: str,
    nv: int,
    *,
    dt: float,
    floating_base: bool = True,
    base_dofs: Sequence[int] | None = None,
) -> SensorParams:
    """One of the named sensor models.

    ``ideal``: no noise, bias, outliers or latency (the readings are the true state and
    ``qacc`` is the finite difference of the true velocity).

    ``anymal_like``: the paper's Table II magnitudes (its simulation; ANYmal at 400 Hz),
    carried over to a quadruped coordinate by coordinate:

    - joints: ``q`` 0.02 rad, ``qd`` 0.3 rad/s (Table II's joint entries, also the
      defaults of :func:`jax_contact.make_noise`, so estimator and simulator agree);
      torque 0.5 N m (Table II gives no torque noise, only the 2 N m disturbance
      ``w_d`` that the estimator assumes; 0.5 N m is a quarter of it, a choice);
      outliers with probability 1e-3 per sample and a 10 rad/s spike (the paper
      mentions velocity outliers on ANYmal without numbers; a choice).
    - base of the planar leg (``floating_base=False``, its rail): Table II as printed,
      position 0.04 m, velocity 0.2 m/s, plus the floating base's bias random walks
      below, 0.01 m/sqrt(s) and 0.02 m/s/sqrt(s) (a choice), acceleration 2 m/s^2 (an
      accelerometer on the base, as the floating base's IMU below). Not a difference of
      the rail velocity: that would carry ``sqrt(2) 0.2 / 0.0025`` = 113 m/s^2 of noise,
      with which the dynamics term reads a still, loaded foot as air
      (docs/model_choices.md, "A base acceleration read by differencing").
    - floating base, linear: a quadruped's base state comes from a filter fusing an IMU
      with leg kinematics (Bloesch et al. 2013), not from a raw sensor, so its white
      jitter is far below Table II's rail figures while it drifts: position 0.01 m and
      velocity 0.05 m/s white, bias random walks 0.01 m/sqrt(s) and 0.02 m/s/sqrt(s)
      (after 20 s the position bias has a std of 4.5 cm, a leg-odometry drift); the
      linear acceleration is the IMU's accelerometer, 0.5 m/s^2 white (a consumer MEMS
      part at 400 Hz), not a difference of the velocity estimate (which would carry
      ``sqrt(2) 0.05 / 0.0025`` = 28 m/s^2 of noise). All choices.
    - floating base, rotational: orientation 0.01 rad and angular velocity 0.01 rad/s
      white (a gyro), bias random walks 0.002 rad/sqrt(s) and 0.005 rad/s/sqrt(s);
      angular acceleration differentiated from the gyro (5.7 rad/s^2). Choices.
    - latency 2.5 ms (one estimator period at 400 Hz: a choice), kept in seconds: at
      period ``dt`` it is ``round(2.5 ms / dt)`` steps (the control rate's 20 ms
      steps get none rather than a 20 ms delay; 1 kHz gets 2 steps).

    ``harsh``: ``anymal_like`` with twice the white noise, three times the bias random
    walks, outliers ten times as often (1e-2) and 7.5 ms of latency (3 steps at 400 Hz).

    Args:
      name: one of :data:`PRESETS`.
      nv: number of generalised velocities.
      dt: sensor period, s (the estimator's rate; 0.0025 s is the paper's 400 Hz).
      floating_base: the model has a free joint first (coordinates 0-2 linear, 3-5
        rotational base coordinates).
      base_dofs: without a floating base, the coordinates that belong to the base (e.g.
        ``(0,)`` for the planar leg's rail); they are treated as linear base coordinates.
        Ignored with a floating base.

    Raises:
      ValueError: unknown ``name`` (the message lists :data:`PRESETS`) or bad sizes.
    """
    if name not in PRESETS:
        raise ValueError(f"name must be one of {PRESETS}, got {name!r}")
    if not isinstance(nv, int | np.integer) or nv < 1:
        raise ValueError(f"nv must be a positive int, got {nv!r}")
    if name == "ideal":
        return make_sensor_params(nv, dt=dt, floating_base=floating_base)

    lin = np.zeros(nv, dtype=bool)
    rot = np.zeros(nv, dtype=bool)
    if floating_base:
        if nv < 6:
            raise ValueError(f"nv must be >= 6 with floating_base=True, got {nv}")
        lin[:3] = True
        rot[3:6] = True
    else:
        dofs = tuple(base_dofs or ())
        if any(not (0 <= int(i) < nv) for i in dofs):
            raise ValueError(f"base_dofs must be indices in [0, {nv}), got {dofs!r}")
        lin[list(dofs)] = True
    joint = ~(lin | rot)

    def per(j: float, bl: float, br: float) -> np.ndarray:
        return np.where(joint, j, np.where(lin, bl, np.where(rot, br, 0.0)))

    noise_scale, bias_scale, p_out, latency_s = 1.0, 1.0, 1e-3, PRESET_LATENCY_S
    if name == "harsh":
        noise_scale, bias_scale, p_out, latency_s = 2.0, 3.0, 1e-2, 3 * PRESET_LATENCY_S
    # The floating base is a fused state estimate with an IMU (see the docstring); the
    # planar leg's rail keeps Table II's figures, its 2 m/s^2 acceleration included.
    base_q, base_qd, gyro = (0.01, 0.05, 0.01) if floating_base else (0.04, 0.2, 0.05)
    accel = 0.5 if floating_base else 2.0
    return make_sensor_params(
        nv,
        dt=dt,
        floating_base=floating_base,
        sigma_q=noise_scale * per(0.02, base_q, 0.01),
        sigma_qd=noise_scale * per(0.3, base_qd, gyro),
        sigma_acc=noise_scale * per(0.0, accel, 0.0),
        sigma_tau=noise_scale * per(0.5, 0.0, 0.0),
        bias_rw_q=bias_scale * per(0.0, 0.01, 0.002),
        bias_rw_qd=bias_scale * per(0.0, 0.02, 0.005),
        outlier_prob=p_out,
        outlier_size=per(10.0, 0.0, 0.0),
        latency=int(round(latency_s / dt)),
    )


# --------------------------------------------------------------------------------------
# Quaternion helpers (w, x, y, z), kept local so that envs/ needs no private MJX module.


def _quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return jnp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def _rotvec_to_quat(v: jax.Array) -> jax.Array:
    """Unit quaternion of the rotation by angle ``|v|`` about ``v / |v|``."""
    # sinc-based form so that v = 0 is smooth (and gradients are finite) there.
    angle = jnp.sqrt(jnp.sum(v * v) + 1e-30)
    half = 0.5 * angle
    return jnp.concatenate([jnp.cos(half)[None], v * (0.5 * jnp.sinc(half / jnp.pi))])


def perturb_qpos(qpos: jax.Array, dq: jax.Array, *, floating_base: bool) -> jax.Array:
    """``qpos`` moved by the tangent vector ``dq``.

    Args:
      qpos: (nq,) generalised coordinates.
      dq: (nv,) displacement: linear parts added; for a free joint the rotational part
        ``dq[3:6]`` is a rotation vector in the body frame, applied as
        ``quat * exp(dq[3:6])`` and renormalised.
      floating_base: static, whether ``qpos[0:7]`` is a free joint.

    Returns:
      (nq,) perturbed coordinates.
    """
    if not floating_base:
        return qpos + dq
    quat = _quat_mul(qpos[3:7], _rotvec_to_quat(dq[3:6]))
    quat = quat / jnp.linalg.norm(quat)
    return jnp.concatenate([qpos[0:3] + dq[0:3], quat, qpos[7:] + dq[6:]])


# --------------------------------------------------------------------------------------
# The model


def _check_shapes(params: SensorParams, qpos, qvel, tau) -> None:
    nv, nq = params.nv, params.nq
    for name, x, n in (("true_qpos", qpos, nq), ("true_qvel", qvel, nv), ("true_tau", tau, nv)):
        if jnp.shape(x) != (n,):
            raise ValueError(
                f"{name} must have shape ({n},) for nv={nv}, floating_base="
                f"{params.floating_base}; got {jnp.shape(x)} (vmap over environments)"
            )


def _measure(params: SensorParams, bias_q, bias_qd, qpos, qvel, tau, key):
    """Noisy position, velocity and torque of one step, before differentiation."""
    k_q, k_qd, k_tau, k_hit, k_sign = jax.random.split(key, 5)
    nv = params.nv
    dq = bias_q + params.sigma_q * jax.random.normal(k_q, (nv,))
    q_m = perturb_qpos(qpos, dq, floating_base=params.floating_base)
    qd_m = qvel + bias_qd + params.sigma_qd * jax.random.normal(k_qd, (nv,))
    hit = jax.random.bernoulli(k_hit, params.outlier_prob, (nv,)) & (params.outlier_size > 0)
    sign = jnp.where(jax.random.bernoulli(k_sign, 0.5, (nv,)), 1.0, -1.0)
    qd_m = jnp.where(hit, qvel + sign * params.outlier_size, qd_m)
    tau_m = tau + params.sigma_tau * jax.random.normal(k_tau, (nv,))
    return q_m, qd_m, tau_m


def sensor_init(
    params: SensorParams,
    true_qpos: jax.Array,
    true_qvel: jax.Array,
    true_tau: jax.Array | None = None,
    *,
    key: jax.Array,
) -> SensorState:
    """The sensor state at the first step.

    The biases start at zero. One noisy reading of the initial state (with ``qacc = 0``)
    fills the latency buffer and is the previous velocity of the first difference, so the
    first ``latency`` readings repeat it and the first ``qacc`` is a difference of two
    independent noise draws.

    Args:
      params: the sensor model.
      true_qpos: (nq,) initial coordinates.
      true_qvel: (nv,) initial velocities.
      true_tau: (nv,) initial generalised actuation forces; None for zeros.
      key: PRNG key for the initial reading's noise.

    Returns:
      The initial :class:`SensorState`.
    """
    tau = jnp.zeros_like(true_qvel) if true_tau is None else true_tau
    _check_shapes(params, true_qpos, true_qvel, tau)
    zeros = jnp.zeros((params.nv,), dtype=jnp.float32)
    q_m, qd_m, tau_m = _measure(params, zeros, zeros, true_qpos, true_qvel, tau, key)
    reading = Readings(qpos=q_m, qvel=qd_m, qacc=jnp.zeros_like(qd_m), tau=tau_m)
    n_buf = max(params.latency, 1)
    buffer = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_buf,) + x.shape), reading)
    return SensorState(
        prev_qvel=qd_m,
        prev_true_qvel=jnp.asarray(true_qvel, jnp.float32),
        bias_q=zeros,
        bias_qd=zeros,
        buffer=buffer,
        head=jnp.int32(0),
    )


def sensor_step(
    params: SensorParams,
    state: SensorState,
    true_qpos: jax.Array,
    true_qvel: jax.Array,
    true_tau: jax.Array,
    *,
    key: jax.Array,
) -> tuple[SensorState, Readings]:
    """Advances the sensors by one period ``params.dt`` and returns the delayed readings.

    Args:
      params: the sensor model.
      state: the state from :func:`sensor_init` or the previous call.
      true_qpos: (nq,) true coordinates now.
      true_qvel: (nv,) true velocities now.
      true_tau: (nv,) true generalised actuation forces now (e.g. ``mjx.Data.qfrc_actuator``).
      key: PRNG key; split here into one key per random effect.

    Returns:
      The next state, and the readings the estimator gets now: those sampled ``latency``
      steps ago.
    """
    _check_shapes(params, true_qpos, true_qvel, true_tau)
    k_bq, k_bqd, k_meas = jax.random.split(key, 3)
    nv = params.nv
    sqrt_dt = jnp.sqrt(params.dt)
    # A Gaussian random walk: increments of variance rw^2 dt, so Var(bias(t)) = rw^2 t.
    bias_q = state.bias_q + params.bias_rw_q * sqrt_dt * jax.random.normal(k_bq, (nv,))
    bias_qd = state.bias_qd + params.bias_rw_qd * sqrt_dt * jax.random.normal(k_bqd, (nv,))
    q_m, qd_m, tau_m = _measure(params, bias_q, bias_qd, true_qpos, true_qvel, true_tau, k_meas)
    # Backward difference of the noisy velocity, as a robot without acceleration sensors
    # computes it; white noise sigma gives a std of sqrt(2) sigma / dt.
    qacc_m = (qd_m - state.prev_qvel) / params.dt
    # An accelerometer measures the true acceleration over the same interval, plus its
    # own white noise, instead of differentiating a noisy velocity.
    k_meas, k_acc = jax.random.split(k_meas)
    qacc_imu = (true_qvel - state.prev_true_qvel) / params.dt + params.sigma_acc * (
        jax.random.normal(k_acc, (nv,))
    )
    qacc_m = jnp.where(params.sigma_acc > 0, qacc_imu, qacc_m)
    now = Readings(qpos=q_m, qvel=qd_m, qacc=qacc_m, tau=tau_m)

    if params.latency == 0:
        out, buffer, head = now, state.buffer, state.head
    else:
        # Ring buffer: the oldest slot was written `latency` steps ago; read it, overwrite.
        out = jax.tree.map(lambda b: b[state.head], state.buffer)
        buffer = jax.tree.map(lambda b, x: b.at[state.head].set(x), state.buffer, now)
        head = (state.head + 1) % params.latency
    new_state = SensorState(
        prev_qvel=qd_m,
        prev_true_qvel=jnp.asarray(true_qvel, jnp.float32),
        bias_q=bias_q,
        bias_qd=bias_qd,
        buffer=buffer,
        head=head,
    )
    return new_state, out
