"""Logs with ground truth -> the inputs of gradient tuning (``jax-contact tune``).

A log is read once (:func:`read_truth_log`: the end-of-step timing convention, the robot
with the log's feet, every shape checked), the MJX adapter runs over its readings once
(:func:`measure_readings`), and the tuning loop then only runs the estimator
(:mod:`jax_contact.tune`). :func:`default_params` are the parameters ``jax-contact
evaluate`` uses for the log's robot, which tuning starts from and its prior is centred on;
:func:`sensor_floor` the least std each noise may be tuned to.

Standard library only at import, like the command line (``jax_contact.train.cli``).
"""

from __future__ import annotations

from pathlib import Path


def measure_readings(robot, readings: dict, *, pairing: str = "delayed", chunk: int = 400):
    """The estimator's inputs of every step of a (T, E) batch of readings, computed once.

    Pairing as ``jax_contact.train.evaluate.replay`` (``"delayed"``: the acceleration and torque of
    reading ``k`` with the state of reading ``k - 1``, scored against the truth of step
    ``k``; the first reading is paired with its own state). The result is a
    :class:`jax_contact.RobotMeasurement` with NumPy float32 leaves
    of leading axes (T, E): the mass matrix once per robot and step, not once per leg
    (Go1: 671 floats, 2.7 kB per robot-step; 16 envs x 8 s: 137 MB).

    Args:
      robot: the nominal :class:`jax_contact.envs.robots.Robot` (the estimator's model).
      readings: ``qpos`` (T, E, nq), ``qvel``/``qacc``/``tau`` (T, E, nv).
      pairing: ``"delayed"`` or ``"raw"``.
      chunk: steps computed per compiled call.
    """
    import jax
    import numpy as np
    from mujoco import mjx

    from jax_contact.adapter import prepare, robot_measurement
    from jax_contact.train.evaluate import pair_delayed

    if pairing not in ("delayed", "raw"):
        raise ValueError(f"pairing must be 'delayed' or 'raw', got {pairing!r}")
    qpos, qvel, qacc, tau = (np.asarray(readings[k]) for k in ("qpos", "qvel", "qacc", "tau"))
    if pairing == "delayed":  # jax_contact.train.evaluate's convention, lost readings included
        qpos, qvel, qacc = pair_delayed(qpos, qvel, qacc)
    m = mjx.put_model(robot.mj_model)
    template = mjx.make_data(m)
    desc = robot.description

    @jax.jit
    def measure(qp, qv, qa, ta):
        def one(qp, qv, qa, ta):
            d = prepare(m, template.replace(qpos=qp, qvel=qv))
            return robot_measurement(m, d, desc, qdd=qa, tau=ta, include_passive=True)

        return jax.vmap(jax.vmap(one))(qp, qv, qa, ta)

    return in_time_chunks(lambda xs: measure(*xs), [qpos, qvel, qacc, tau], chunk)


def in_time_chunks(fn, xs, chunk: int):
    """``fn`` over a pytree ``xs`` of NumPy arrays of leading (time) axis T, ``chunk`` steps
    per call (the last chunk padded with its last step, so ``fn`` compiles once), the
    results concatenated back to T steps as NumPy arrays."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    n_t = jax.tree.leaves(xs)[0].shape[0]
    pieces = []
    for start in range(0, n_t, chunk):
        stop = min(start + chunk, n_t)

        def part(x, start=start, stop=stop):
            x = x[start:stop]
            if stop - start < chunk:  # one shape, one compilation
                x = np.concatenate([x, np.repeat(x[-1:], chunk - x.shape[0], 0)])
            return jnp.asarray(x)

        out = fn(jax.tree.map(part, xs))
        pieces.append(jax.tree.map(lambda a, n=stop - start: np.asarray(a)[:n], out))
    return jax.tree.map(lambda *ys: np.concatenate(ys, axis=0), *pieces)


def read_truth_log(path: str | Path):
    """A log file -> (readings, truth, valid, attrs, robot): ``jax_contact.train.logs.load_log``
    (the end-of-step timing convention, the robot with the log's feet, every shape checked),
    refused without ground truth.

    Raises:
      ValueError: the log has no ground truth, or any error of ``jax_contact.train.logs``' checks.
    """
    from jax_contact.train.logs import load_log

    log = load_log(path)
    if log.truth is None:
        raise ValueError(
            f"{log.name} has no ground truth ('truth/contact'): it can neither be tuned on nor"
            " validate a fit"
        )
    return log.readings, log.truth, log.valid, log.attrs, log.robot


def load_tuning_log(path: str | Path, terrain_model: str = "flat"):
    """A log file -> (TuningData, robot, attrs, default params, terrain).

    ``terrain_model``: the estimator's terrain over the log's plane
    (:func:`jax_contact.train.logs.terrain_for`).

    Raises:
      ValueError: as :func:`read_truth_log`.
    """
    import numpy as np

    from jax_contact.train.logs import terrain_for
    from jax_contact.tune import TuningData

    readings, truth, valid, attrs, robot = read_truth_log(path)
    dt = float(attrs["dt"])
    params, plane = default_params(robot, dt, str(attrs.get("noise", "anymal_like")))
    terrain = terrain_for(plane, terrain_model)
    meas = measure_readings(robot, readings)
    mask = np.broadcast_to(valid[..., None], truth.shape)
    return TuningData(meas=meas, truth=truth, mask=np.array(mask)), robot, attrs, params, terrain


def default_params(robot, dt: float, noise: str = "anymal_like"):
    """(params, terrain) of ``jax-contact evaluate`` for this robot; other sensor presets
    than ``anymal_like`` get ``params_for`` with that preset."""
    import jax_contact as jc
    from jax_contact.envs.sensors import sensor_preset
    from jax_contact.train.reproduce import (
        TERRAIN_SIGMA,
        planar_estimator_params,
        quadruped_estimator_params,
    )

    desc = robot.description
    if desc.n_leg_dofs == 2:
        return planar_estimator_params(desc.nv, dt), jc.flat(0.0, 0.2)
    if noise == "anymal_like":
        return quadruped_estimator_params(desc, dt), jc.flat(0.0, TERRAIN_SIGMA)
    sp = sensor_preset(noise, desc.nv, dt=dt)
    return jc.params_for(desc, sp, dt), jc.flat(0.0, TERRAIN_SIGMA)


def sensor_floor(robot, dt: float, noise: str = "anymal_like") -> dict:
    """The noise floor of ``jax-contact tune --noise-floor sensor``: what the log's sensor
    preset alone puts on each measured quantity (``jax_contact.defaults.sensor_noise_floor``)."""
    from jax_contact.defaults import sensor_noise_floor
    from jax_contact.envs.contact_params import default_sensor_params

    return sensor_noise_floor(robot.description, default_sensor_params(noise, robot, dt), dt)
