"""Defaults of the wrapper's estimator: sensor model, parameters, force axes, terrain.

Everything here reads the compiled ``mujoco.MjModel`` once, when an env is wrapped.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import mujoco
import numpy as np

import jax_contact as jc
from jax_contact.envs import sensors
from jax_contact.envs.feet import foot_points_np, home_data
from jax_contact.envs.robots import Robot
from jax_contact.robot import RobotDescription

# A Jacobian row (over a leg's joints, summed over the legs) below this share of the largest
# is not spanned: a planar leg's out-of-plane row is zero up to round-off.
SPAN_TOLERANCE = 1e-6


def floating_base(mj_model: mujoco.MjModel) -> bool:
    free = int(mujoco.mjtJoint.mjJNT_FREE)
    return mj_model.njnt > 0 and int(mj_model.jnt_type[0]) == free and mj_model.jnt_qposadr[0] == 0


def _mj_model_of(robot_or_desc) -> mujoco.MjModel | None:
    return robot_or_desc.mj_model if isinstance(robot_or_desc, Robot) else None


def _desc_of(robot_or_desc) -> RobotDescription:
    if isinstance(robot_or_desc, Robot):
        return robot_or_desc.description
    if isinstance(robot_or_desc, RobotDescription):
        return robot_or_desc
    raise ValueError(
        "robot_or_desc must be a jax_contact.envs.robots.Robot or a"
        f" jax_contact.robot.RobotDescription, got {type(robot_or_desc).__name__}"
    )


def _home_jacobians(mj_model: mujoco.MjModel, desc: RobotDescription, rotational: bool = False):
    """(data at the home pose after ``mj_forward``, per foot its (3, nv) point Jacobian at
    the foot's contact point; with ``rotational``, per foot ``(jacp, jacr)``, the second
    its body's (3, nv) rotational Jacobian): what :func:`choose_force_rows`,
    :func:`push_noise` and :func:`moment_push` read."""
    d = home_data(mj_model)
    mujoco.mj_forward(mj_model, d)
    jacs = []
    for body, point in zip(desc.foot_body_ids, foot_points_np(mj_model, d, desc), strict=True):
        jacp, jacr = np.zeros((3, mj_model.nv)), np.zeros((3, mj_model.nv))
        mujoco.mj_jac(mj_model, d, jacp, jacr, point, body)
        jacs.append((jacp, jacr) if rotational else jacp)
    return d, jacs


def choose_force_rows(mj_model: mujoco.MjModel, desc: RobotDescription) -> tuple[int, ...]:
    """World axes of the contact force the legs can resist: the normal and the best others.

    A leg resists a force only along the directions its Jacobian spans: the rows of ``J``
    (at the feet's contact points, home pose, or ``qpos0`` without a ``home`` key) are
    ranked by their norm over the leg's joints, summed over the legs; the normal (z) is
    always kept (contact is decided along it), and beside it at most ``n_l - 1`` of the
    tangential axes whose row is not zero (:data:`SPAN_TOLERANCE` of the largest row). A
    spatial leg of three or more joints (Go1, Spot, a humanoid's) gets (0, 1, 2); the
    planar leg (hip, knee in the x-z plane) (0, 2); Brax's ant (hip about z, knee) z and
    the larger of x, y; a planar leg of three joints (Brax's walker2d, hopper,
    halfcheetah: hinges about y) (0, 2), where the old rule gave every leg of three
    joints all three axes, one of which its joints cannot push along.
    """
    n_l = desc.n_leg_dofs
    _, jacs = _home_jacobians(mj_model, desc)
    norms = np.zeros(3)
    for jacp, dofs in zip(jacs, desc.leg_dofs, strict=True):
        norms += np.linalg.norm(jacp[:, list(dofs)], axis=1)
    spanned = [i for i in (0, 1) if norms[i] > SPAN_TOLERANCE * np.max(norms)]
    tangential = sorted(spanned, key=lambda i: -norms[i])[: n_l - 1]
    return tuple(sorted([2, *tangential]))


def push_noise(mj_model: mujoco.MjModel, desc: RobotDescription, params) -> np.ndarray:
    """(n_legs,) std of the dynamics term's estimated push ``e . F`` at the home pose, N.

    Eq. 6's force is ``F = Lambda J_f M_l^-1 r + ...``: ``J_f`` the rows
    ``params.force_rows`` of the foot's Jacobian over the leg's joints, ``Lambda = (J_f
    M_l^-1 J_f^T + inv_damping I)^-1`` (damped as the term damps it), and the residual
    ``r = tau - h - M_lb qdd_b`` carries ``Sigma_d`` (the torque noise and the model error
    ``w_d``, ``params.noise.sigma_d``). Along the normal ``e = z`` its std is ``sqrt(g
    Sigma_d g^T)``, ``g = e^T Lambda J_f M_l^-1`` (for a square ``J_f``, ``e^T J_f^-T``).
    Home pose as in :func:`choose_force_rows`; the base acceleration's share of
    ``Sigma_d`` is left out.
    """
    return _push_noise_of(_push_gains(mj_model, desc, params), params)


def _push_noise_of(gains, params) -> np.ndarray:
    """:func:`push_noise` from :func:`_push_gains`' per-leg gains."""
    sigma_d = np.asarray(params.noise.sigma_d, np.float64)
    return np.asarray(
        [float(np.sqrt(np.sum(g**2 * sigma_d[list(dofs)] ** 2))) for g, _, dofs in gains]
    )


def _push_gains(mj_model: mujoco.MjModel, desc: RobotDescription, params):
    """Per leg ``(g, jacr, dofs)`` at the home pose: ``g = e^T Lambda J_f M_l^-1`` (the
    normal push per newton metre of residual torque, over the leg's joints; damped as the
    dynamics term damps it) and the foot body's rotational Jacobian over the leg's joints."""
    d, jacs = _home_jacobians(mj_model, desc, rotational=True)
    M = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, d, M)
    rows = list(params.force_rows)
    e = np.array([0.0, 0.0, 1.0])[rows]
    out = []
    for (jacp, jacr), dofs in zip(jacs, desc.leg_dofs, strict=True):
        dofs = list(dofs)
        J = jacp[rows][:, dofs]
        M_inv = np.linalg.inv(M[np.ix_(dofs, dofs)])
        lam_inv = J @ M_inv @ J.T + float(params.inv_damping) * np.eye(len(rows))
        out.append((e @ np.linalg.solve(lam_inv, J @ M_inv), jacr[:, dofs], dofs))
    return out


def moment_push(mj_model: mujoco.MjModel, desc: RobotDescription, params) -> np.ndarray:
    """(n_legs,) the largest error in the estimated push ``e . F`` per newton of the foot's
    load that a sole's moment can cause, at the home pose (dimensionless).

    Eq. 6 models a foot as a point that transmits a force and no moment. A sole (a box or
    mesh, several spheres or capsules, a capsule) also transmits a moment: its centre of
    pressure may lie anywhere on it, up to ``h`` from the contact point (``h`` the largest
    distance of the sole's corners, spheres' centres or capsules' ends, ``desc.foot_soles``,
    from the foot's point ``desc.foot_offsets``), so under a load ``f``
    the moment is up to ``f h`` about a horizontal axis. Through the leg it is the joint
    torque ``J_r^T m`` (``J_r`` the foot body's rotational Jacobian), which eq. 6 reads as
    push: ``g J_r^T m`` with ``g`` as in :func:`push_noise`. This returns ``h |(g
    J_r^T)_{x,y}|``; a foot of one sphere or point (no sole) gives 0.
    """
    return _moment_push_of(_push_gains(mj_model, desc, params), desc)


def _moment_push_of(gains, desc: RobotDescription) -> np.ndarray:
    """:func:`moment_push` from :func:`_push_gains`' per-leg gains and the description."""
    out = []
    for sole, point, (g, jacr, _) in zip(desc.soles, desc.foot_offsets, gains, strict=True):
        sole = np.asarray(sole, np.float64).reshape(-1, 3)
        h = float(np.max(np.linalg.norm(sole - np.asarray(point), axis=1))) if len(sole) else 0.0
        out.append(h * float(np.linalg.norm((g @ jacr.T)[:2])))
    return np.asarray(out)


def choose_unilateral(mj_model: mujoco.MjModel, desc: RobotDescription, params) -> bool:
    """Whether the dynamics term's sign test (``EstimatorParams.unilateral``) can read a
    stance foot's load: on every leg, a foot's share of the weight, ``f = m g / n_legs``
    (the model's gravity), at least ``sqrt(push_noise^2 + (f moment_push)^2)``: the
    estimated push's noise and, for a foot with a sole (``desc.foot_soles``, as
    :func:`jax_contact.envs.feet.describe` resolves it), the error its moment can cause.

    Below it the estimated push's sign is mostly the torques' noise or the sole's moment,
    which the test (under ``Sigma_f`` alone) would read as a sure "pull". Brax's ant
    (0.91 kg, 2.2 N per foot against 3.6 N of noise) read its trot's stance as air, and
    T1 standing on both soles (155 N each; noise 71 N, a sole's moment up to ~200 N)
    chattered between 0 and 1 at every physics step (docs/training.md, "Brax's ant,
    measured" and "A sole's moment and the sign test"). Measured ratios: Go1 2.2, Barkour
    2.0, Spot 13, the planar leg 5, Berkeley Humanoid 2.0, H1 3.3 keep the test; the ant
    0.61, T1 0.73, G1 0.57, Apollo 0.54 do not (the 17 Playground envs: docs/training.md).
    A description without a mass keeps it.
    """
    margin = sign_test_margin(mj_model, desc, params)
    return margin is None or margin >= 1.0


def sign_test_margin(mj_model: mujoco.MjModel, desc: RobotDescription, params) -> float | None:
    """A foot's share of the weight over the largest of the legs' push errors
    (:func:`choose_unilateral`'s rule: the test runs at 1 or more; ``inf`` where the push
    has no error), None for a description without a mass. The wrapper reports it
    (``contact_report()["sign_test_margin"]``), so a user sees why the test is off."""
    if desc.mass_kg is None:
        return None
    load = float(desc.mass_kg) * float(np.linalg.norm(mj_model.opt.gravity)) / desc.n_legs
    gains = _push_gains(mj_model, desc, params)  # the home pose's Jacobians and M, once
    moment = _moment_push_of(gains, desc)
    noise = float(np.max(np.hypot(_push_noise_of(gains, params), load * moment)))
    # No error at all (a leg fixed to the world reads its push exactly): any load is read.
    return load / noise if noise > 0 else float("inf")


def default_sensor_params(
    sensor: str | sensors.SensorParams, robot_or_desc, dt: float
) -> sensors.SensorParams:
    """The sensor model of a robot at estimator period ``dt``.

    A preset name is built with :func:`jax_contact.envs.sensors.sensor_preset` for the robot's
    coordinates (floating base or not; the base dofs of the description otherwise), whose
    latency is in seconds (``anymal_like``'s 2.5 ms: one step at 400 Hz, none at the
    control rate's 20 ms). A :class:`~jax_contact.envs.sensors.SensorParams` is returned as
    given, after checking its size and period.

    Raises:
      ValueError: an unknown preset (the message lists them), a ``SensorParams`` of the
        wrong ``nv`` or ``dt``, or a robot whose joints the sensor model cannot perturb.
    """
    desc = _desc_of(robot_or_desc)
    mj_model = _mj_model_of(robot_or_desc)
    floating = floating_base(mj_model) if mj_model is not None else desc.nq == desc.nv + 1
    if desc.nq != desc.nv + (1 if floating else 0):
        raise ValueError(
            f"the sensor model handles a free joint first and hinges/slides otherwise; this"
            f" model has nq={desc.nq}, nv={desc.nv}"
        )
    if isinstance(sensor, sensors.SensorParams):
        if sensor.nv != desc.nv or sensor.floating_base != floating:
            raise ValueError(
                f"sensor has nv={sensor.nv}, floating_base={sensor.floating_base}; the robot"
                f" has nv={desc.nv}, floating_base={floating}"
            )
        if not np.isclose(float(sensor.dt), dt, rtol=1e-5):
            raise ValueError(
                f"sensor.dt ({float(sensor.dt)}) must equal the estimator period ({dt}):"
                " qacc is differenced over it"
            )
        return sensor
    if sensor not in sensors.PRESETS:
        raise ValueError(
            f"sensor must be a SensorParams or one of {sensors.PRESETS}, got {sensor!r}"
        )
    return sensors.sensor_preset(
        sensor, desc.nv, dt=dt, floating_base=floating, base_dofs=desc.base_dofs
    )


def with_extra_latency(
    sensor: sensors.SensorParams, extra_env_steps: int, env_dt: float
) -> sensors.SensorParams:
    """``sensor`` with ``extra_env_steps`` env steps more of reading delay, in its own steps.

    The sensor model's latency counts its own steps (``sensor.dt``: the physics step at the
    wrapper's substep rate, the env step at the control rate), so an env step of ``env_dt``
    is ``round(env_dt / sensor.dt)`` of them: the hop task's 10 ms env step is 4 physics
    steps of 2.5 ms, Go1 joystick's 20 ms one is 5 of 4 ms. The one rule of the transfer
    matrix's ``estimate_latK`` columns (:func:`jax_contact.train.transfer.column_setting`),
    for every task.

    Args:
      sensor: the sensor model at the estimator's period.
      extra_env_steps: env steps of delay to add, an int >= 0.
      env_dt: the env step, s; a whole multiple of ``sensor.dt``.

    Returns:
      The sensor model with ``latency + extra_env_steps * round(env_dt / sensor.dt)``.

    Raises:
      ValueError: a negative or non-int ``extra_env_steps``, or an ``env_dt`` that is not a
        whole number (>= 1) of sensor steps.
    """
    if isinstance(extra_env_steps, bool) or not isinstance(extra_env_steps, int | np.integer):
        raise ValueError(f"extra_env_steps must be an int >= 0, got {extra_env_steps!r}")
    if extra_env_steps < 0:
        raise ValueError(f"extra_env_steps must be an int >= 0, got {extra_env_steps!r}")
    ratio = float(env_dt) / float(sensor.dt)
    per_env_step = int(round(ratio))
    if per_env_step < 1 or not np.isclose(ratio, per_env_step, rtol=1e-5):
        raise ValueError(
            f"env_dt ({float(env_dt)}) must be a whole number of sensor steps"
            f" (sensor.dt {float(sensor.dt)})"
        )
    return sensor.replace(latency=int(sensor.latency) + int(extra_env_steps) * per_env_step)


def default_estimator_params(
    robot_or_desc,
    dt: float,
    sensor_params: sensors.SensorParams,
    *,
    sigma_qdd_model: float = 0.0,
    force_rows: Sequence[int] | None = None,
    **params_for_kwargs,
) -> jc.EstimatorParams:
    """Estimator parameters consistent with a sensor model: :func:`jax_contact.params_for`.

    The one source of parameters (its docstring lists the rules), with three things only a
    simulated env knows: the force axes the legs' Jacobians span and whether
    the dynamics term's sign test can read a foot's load (:func:`choose_unilateral`, unless
    ``unilateral`` is given), both read from the model, and ``sigma_qdd_model``, an
    acceleration model error for the control rate, where ``qacc`` is the mean over a
    control period but the dynamics term predicts the instantaneous acceleration,
    combined in quadrature with the sensor-derived
    ``sigma_qdd``. Default 0: measured with :func:`jax_contact.train.rates.compare_rates` (16
    rollouts, 20 ms control period, ``pairing="raw"``), 1000 rad/s^2 raised the control-rate
    accuracy of the hopping planar leg (stiff servos) from 0.858 to 0.905 but lowered the stepping
    Go1's from 0.882 to 0.824.

    Args:
      robot_or_desc: an :class:`jax_contact.envs.robots.Robot` or a ``RobotDescription``.
      dt: estimator period, s (physics step in the substep mode, control period else).
      sensor_params: the sensor model (its ``dt`` must be ``dt``).
      sigma_qdd_model: see above, rad/s^2.
      force_rows: world axes of the contact force; None: :func:`choose_force_rows` with a
        ``Robot`` (any legs); with a description alone (0, 1, 2), for legs of 3+ joints.
      **params_for_kwargs: passed to :func:`jax_contact.params_for` (``gait``,
        ``disturbance``, ``bias_horizon_s``, and any ``make_params`` argument).

    Raises:
      ValueError: a bad argument, naming it.
    """
    desc = _desc_of(robot_or_desc)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite float > 0, got {dt!r}")
    if not isinstance(sensor_params, sensors.SensorParams):
        raise ValueError(
            "sensor_params must be jax_contact.envs.sensors.SensorParams, got"
            f" {type(sensor_params).__name__} (default_sensor_params builds one from a preset name)"
        )
    if sensor_params.nv != desc.nv:
        raise ValueError(f"sensor_params has nv={sensor_params.nv}, the robot nv={desc.nv}")
    if not np.isclose(float(sensor_params.dt), dt, rtol=1e-5):
        raise ValueError(f"sensor_params.dt ({float(sensor_params.dt)}) must equal dt ({dt})")
    if not (np.isfinite(sigma_qdd_model) and sigma_qdd_model >= 0):
        raise ValueError(f"sigma_qdd_model must be >= 0, got {sigma_qdd_model!r}")
    mj_model = _mj_model_of(robot_or_desc)
    if force_rows is None:
        if desc.n_leg_dofs < 3 and mj_model is None:
            raise ValueError(
                f"legs with {desc.n_leg_dofs} joints span only some force axes: pass"
                " force_rows, or a Robot so that they can be read from the model"
            )
        force_rows = choose_force_rows(mj_model, desc) if mj_model is not None else (0, 1, 2)
    params = jc.params_for(desc, sensor_params, dt, force_rows=force_rows, **params_for_kwargs)
    if "unilateral" not in params_for_kwargs and mj_model is not None:
        params = params.replace(unilateral=choose_unilateral(mj_model, desc, params))
    if sigma_qdd_model > 0:
        qdd = np.hypot(np.asarray(params.noise.sigma_qdd), sigma_qdd_model)
        params = params.replace(noise=params.noise.replace(sigma_qdd=jnp.asarray(qdd, jnp.float32)))
    return params


def default_terrain(mj_model: mujoco.MjModel, desc: RobotDescription, sigma: float = 0.05):
    """A flat terrain at the floor plane's height, ``sigma_pi`` = 5 cm (a choice).

    Sharper than the paper's 0.2 m so that the kinematics term can tell a foot held a few
    cm above the floor from contact (docs/model.md). For a height-field floor the mean floor
    height is used with ``sigma`` raised to the field's height range; pass a
    :func:`jax_contact.height_field` terrain for better.
    """
    floor = desc.floor_geom_ids[0]
    if int(mj_model.geom_type[floor]) == int(mujoco.mjtGeom.mjGEOM_PLANE):
        return jc.flat(height=float(mj_model.geom_pos[floor, 2]), sigma=sigma)
    hid = int(mj_model.geom_dataid[floor])
    top = float(mj_model.hfield_size[hid, 2])
    return jc.flat(height=float(mj_model.geom_pos[floor, 2]) + 0.5 * top, sigma=max(sigma, top))
