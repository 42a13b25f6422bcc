"""Logs with ground truth -> the inputs of gradient tuning (``jax-contact tune``).

A log is read once (:func:`read_truth_log`: the end-of-step timing convention, the robot
with the log's feet, every shape checked), the MJX adapter runs over its readings once
(:func:`measure_readings`), and the tuning loop then only runs the estimator
(:mod:`jax_contact.tune`). A recording of your own robot with ground truth (the schema of
``jax-contact estimate``) is read as ``estimate`` reads it (:func:`load_tuning_recording`).
:func:`default_params` are the parameters ``jax-contact evaluate`` uses for the log's robot,
which tuning starts from and its prior is centred on; :func:`sensor_floor` the least std
each noise may be tuned to.

Standard library only at import, like the command line (``jax_contact.train.cli``).
"""

from __future__ import annotations

import hashlib
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
    (:func:`jax_contact.train.log_estimator.terrain_for`).

    Raises:
      ValueError: as :func:`read_truth_log`.
    """
    import numpy as np

    from jax_contact.train.log_estimator import terrain_for
    from jax_contact.train.logs import log_noise
    from jax_contact.tune import TuningData

    readings, truth, valid, attrs, robot = read_truth_log(path)
    dt = float(attrs["dt"])
    params, plane = default_params(robot, dt, log_noise(attrs))
    terrain = terrain_for(plane, terrain_model)
    meas = measure_readings(robot, readings)
    mask = np.broadcast_to(valid[..., None], truth.shape) & feet_read(params, readings, meas)
    return TuningData(meas=meas, truth=truth, mask=np.array(mask)), robot, attrs, params, terrain


def feet_read(params, readings: dict, meas):
    """(T, E, L) bool, or True when every reading is finite: the steps at which each foot's
    estimator reads finite inputs (:func:`jax_contact.types.blocks_are_finite`, the filter's
    own rule). Elsewhere the filter predicts only (a lost reading), so the loss leaves those
    steps out, as ``estimate``'s metrics do."""
    import jax
    import numpy as np

    from jax_contact.measurement import robot_leg_blocks
    from jax_contact.types import blocks_are_finite

    if all(np.isfinite(np.asarray(x)).all() for x in readings.values()):
        return True
    per_foot = jax.jit(
        jax.vmap(jax.vmap(lambda m: jax.vmap(blocks_are_finite)(robot_leg_blocks(params, m))))
    )
    return in_time_chunks(per_foot, meas, 400)


# What a recording's tuning starts from: the sensor model ``estimate``'s defaults assume
# (a recording does not say which sensors it was made with).
RECORDING_NOISE = "anymal_like"


def load_tuning_recording(
    path: str | Path,
    robot,
    model: str,
    *,
    names=None,
    units: str = "rad",
    resample: bool = False,
    force_threshold: float = 1.0,
    terrain_model: str = "flat",
):
    """A recording of one robot with ground truth -> (TuningData, attrs, params, terrain).

    The recording (``jax-contact estimate``'s schema, :mod:`jax_contact.train.recording`)
    is converted as ``estimate`` converts it (``names``, ``units``, ``resample`` and
    ``force_threshold`` as there), and the fit starts from the parameters ``estimate``
    uses for the robot by default (:func:`jax_contact.train.log_estimator.default_estimator`, which
    assume ``anymal_like`` sensors: :data:`RECORDING_NOISE`), restricted to the terms the
    recording's columns support (a recording without torques tunes no dynamics term).
    Scored steps: those ``estimate`` scores, a foot's steps whose truth is known and whose
    estimator inputs are finite (:func:`feet_read`). The notes of the conversion and of
    ``estimate``'s floor check (``WARNING ...`` for a reading the model does not fit:
    another unit, frame or floor) come back in ``attrs["notes"]``.

    Args:
      path: the recording (.csv, .npz, .h5).
      robot: the :class:`jax_contact.envs.robots.Robot` it was recorded on (its feet).
      model: the robot's name or MJCF path, for the provenance.

    Returns:
      The :class:`jax_contact.tune.TuningData` (one env), the attributes the provenance
      and the setup checks read (``robot``, ``sha256`` of the file, ``dt``, ``noise``,
      ``kind``, ``terms``, ``n_envs``, ``notes``), the starting parameters and the terrain.

    Raises:
      ValueError: naming the file, for a recording without ground truth or whose joint
        velocities are derived from its positions (naming their columns), or any error of
        the conversion.
    """
    import mujoco
    import numpy as np

    from jax_contact.train.log_estimator import default_estimator
    from jax_contact.train.recording import read_recording
    from jax_contact.train.recording_checks import plane_floor_note
    from jax_contact.train.recording_convert import to_readings
    from jax_contact.tune import TuningData

    JOINT = mujoco.mjtObj.mjOBJ_JOINT

    conv = to_readings(
        read_recording(path), robot, names=names, units=units, resample=resample,
        force_threshold=force_threshold,
    )  # fmt: skip
    name = repr(str(path))
    if conv.truth is None:
        raise ValueError(
            f"recording {name} has no ground truth columns (contact/<foot> or force/<foot>):"
            " it can neither be tuned on nor validate a fit"
        )
    if conv.velocity_from_position:
        m = robot.mj_model
        as_recorded = {v: k for k, v in (names or {}).items() if v}
        missing = [
            "qd/" + as_recorded.get(n := mujoco.mj_id2name(m, JOINT, int(m.dof_jntid[d])), n)
            for d in conv.velocity_from_position
        ]
        raise ValueError(
            f"recording {name} has no column {', '.join(missing)}: those velocities would be"
            " differences of positions, whose extra noise `jax-contact estimate` adds to any"
            " parameters at run time, so a file tuned on them would count it twice; tune on"
            " recordings with the joints' own velocities"
        )
    params, terrain = default_estimator(
        robot.description, conv.dt, terrain_model, mj_model=robot.mj_model
    )
    terms = tuple(t for t in params.terms if t in conv.terms)
    if not terms:
        raise ValueError(f"recording {name}: no measurement term can run on its columns")
    params = params.replace(terms=terms)
    notes = list(conv.notes)
    if floor := plane_floor_note(robot, conv.readings["qpos"][:, 0], terms, terrain_model):
        notes.append(floor)
    meas = measure_readings(robot, conv.readings)
    known = np.asarray(conv.truth_known, bool)
    # The filter's own rule, foot by foot, as estimate scores (not the converter's per-row
    # flag, which also drops the row after a lost reading).
    mask = known & feet_read(params, conv.readings, meas)
    attrs = {
        "robot": model,
        "sha256": hashlib.sha256(Path(path).read_bytes()).hexdigest(),
        "dt": conv.dt,
        "noise": RECORDING_NOISE,
        "kind": "recording",
        "terms": list(terms),
        "n_envs": 1,
        "notes": notes,
    }
    truth = np.where(known, conv.truth, False)
    data = TuningData(meas=meas, truth=truth, mask=np.array(mask), known=known)
    return data, attrs, params, terrain


def default_params(robot, dt: float, noise: str = "anymal_like"):
    """(params, terrain) that ``jax-contact tune`` starts from on a simulated log: those of
    ``jax-contact evaluate`` (:func:`jax_contact.train.log_estimator.default_estimator`, the
    robot's force axes and sign test included) with the log's own sensor preset ``noise``,
    the one :func:`sensor_floor` reads."""
    from jax_contact.train.log_estimator import default_estimator

    return default_estimator(robot.description, dt, mj_model=robot.mj_model, noise=noise)


def sensor_floor(robot, dt: float, noise: str = "anymal_like") -> dict:
    """The noise floor of ``jax-contact tune --noise-floor sensor``: what the log's sensor
    preset alone puts on each measured quantity (``jax_contact.defaults.sensor_noise_floor``)."""
    from jax_contact.defaults import sensor_noise_floor
    from jax_contact.envs.contact_params import default_sensor_params

    return sensor_noise_floor(robot.description, default_sensor_params(noise, robot, dt), dt)
