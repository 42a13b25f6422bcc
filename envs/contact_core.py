"""The estimator inside the wrapper: its state, its update, its features, built per env.

:class:`Core` holds what is fixed when an env is wrapped (the nominal MJX model, the
robot description and feet, parameters, sensor model, terrain, truth reader, config) and
the pure functions of one env's estimator: ``init``, ``restart`` (after an auto-reset),
``update`` (one estimator step from the true state after a physics step), ``features``
and the observation placement. :func:`make_core` builds it from an env and a
:class:`jax_contact.envs.contact_config.ContactObsConfig`.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs import base as brax_base
from flax import struct

import jax_contact as jc
from jax_contact import adapter
from jax_contact.calibration import Calibration, apply_calibration, file_calibration, probability
from jax_contact.envs import contact_params, contact_truth, feet, sensors
from jax_contact.envs.contact_config import (
    DEFAULT_OBS_KEYS,
    TERM_NAMES,
    ContactObsConfig,
    validate_config,
)
from jax_contact.envs.robots import Robot
from jax_contact.params import TERMS
from jax_contact.params_file import load_params_for
from jax_contact.robot import RobotDescription, model_mass
from jax_contact.terrain import terrain_for, terrain_model_of
from jax_contact.tune.space import robot_space


@struct.dataclass
class ContactEstState:
    """What the wrapper carries in ``state.info[info_key]`` (one env, unbatched).

    Attributes:
      belief: the estimator's belief, leaves with leading axis n_legs.
      sensor: the sensor model's state.
      key: the wrapper's PRNG key, split at every update.
      diag: diagnostics of the last update, leaves (n_legs, ...); at reset the prior
        (``valid`` False).
      qpos: (nq,) the true ``qpos`` the wrapper last returned (auto-reset detection).
      qvel: (nv,) the true ``qvel`` the wrapper last returned.
      prev: the previous sensor readings (delayed pairing; at reset the initial reading).
      n_updates: () int32, estimator updates since the belief last (re)started.
      n_skipped: () int32, foot-updates since then whose readings held a NaN or inf: the
        foot kept the estimator's prediction alone (``diag.valid`` False) and the running
        score leaves it out, as ``jax_contact.metrics`` leaves out a log's lost readings.
    """

    belief: jc.LegBelief
    sensor: sensors.SensorState
    key: jax.Array
    diag: jc.Diagnostics
    qpos: jax.Array
    qvel: jax.Array
    prev: sensors.Readings
    n_updates: jax.Array
    n_skipped: jax.Array


@dataclasses.dataclass(frozen=True, eq=False)
class Core:
    """Static description of one wrapped env and the pure functions of its estimator.

    Attributes:
      mjx_model: the nominal MJX model (a Brax ``System`` for Brax envs): the estimator's
        model, whatever domain randomisation does to the simulated one.
      desc: the robot description (feet as :mod:`jax_contact.envs.feet` resolves them).
      feet: the resolved feet (kind, body, contact point, radius, geoms).
      params, sensor, terrain, cfg: the estimator's parameters, sensor model, terrain and
        the wrapper's config.
      truth: ``data -> (n_legs,) bool`` ground truth, or None.
      truth_raw: the same source without ``cfg.truth_gap`` (recorded beside it).
      truth_source: which :mod:`jax_contact.envs.contact_truth` source ``truth`` reads.
      rate: ``"substep"`` or ``"control"``.
      calibration: the map on the logit before it is observed and scored, or None
        (``cfg.calibration`` resolved).
      params_source: where ``params`` came from: ``"default"``, ``"given"`` or the file or
        preset name.
      sign_test_margin: :func:`jax_contact.envs.contact_params.sign_test_margin` of
        ``params`` (the defaults run the sign test at 1 or more), None without a mass.
    """

    mjx_model: object
    desc: RobotDescription
    feet: tuple
    params: jc.EstimatorParams
    sensor: sensors.SensorParams
    terrain: object
    cfg: ContactObsConfig
    truth: object
    truth_source: str
    rate: str
    truth_raw: object = None
    calibration: Calibration | None = None
    params_source: str = "given"
    sign_test_margin: float | None = None

    def moved(self, est: ContactEstState, data) -> jax.Array:
        """() bool: ``data`` is not the state the wrapper last returned (an auto-reset).

        A NaN equals a NaN here: an env whose state went NaN is not restarted on every step
        (NaN != NaN read as an auto-reset each step, so its belief showed a fresh prior and
        its score was wiped)."""

        def differs(a, b):
            return jnp.any((a != b) & ~(jnp.isnan(a) & jnp.isnan(b)))

        return differs(data.qpos, est.qpos) | differs(data.qvel, est.qvel)

    def restart(self, est: ContactEstState, data, moved: jax.Array) -> ContactEstState:
        """Restarts belief and sensors where ``moved``."""
        key, k_init = jax.random.split(est.key)
        fresh = self.init(data, k_init)
        return jax.tree.map(lambda a, b: jnp.where(moved, a, b), fresh, est.replace(key=key))

    def record(self, est: ContactEstState, data) -> dict:
        """What one update leaves for the metrics: p_contact, and truth and hits if any."""
        rec = {"p_contact": est.diag.p_contact}
        if self.cfg.record_substeps:
            rec["reading"] = est.prev  # the readings of this update (its ``r``)
        if self.truth is not None:
            rec["truth"] = self.truth(data)
            rec["hit"] = (est.diag.p_contact > 0.5) == rec["truth"]
            rec["scored"] = est.diag.valid  # a skipped foot-update is not scored
            if self.cfg.record_substeps and self.truth_raw is not None:
                rec["truth_raw"] = self.truth_raw(data)
        return rec

    def init(self, data, key: jax.Array) -> ContactEstState:
        key, k_sense = jax.random.split(key)
        sensor = sensors.sensor_init(
            self.sensor, data.qpos, data.qvel, data.qfrc_actuator, key=k_sense
        )
        one = jc.init_belief(self.params)
        n = self.desc.n_legs
        belief = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + x.shape), one)
        half = jnp.full((n,), 0.5, jnp.float32)
        diag = jc.Diagnostics(
            p_contact=probability(belief.logit, self.calibration),
            p_dynamics=half,
            p_diff_kinematics=half,
            p_kinematics=half,
            p_takeoff=jnp.exp(belief.log_transition[:, 0, 1]),
            p_touchdown=jnp.exp(belief.log_transition[:, 1, 0]),
            force=jnp.zeros((n, 3), jnp.float32),
            valid=jnp.zeros((n,), bool),
        )
        return ContactEstState(
            belief=belief,
            sensor=sensor,
            key=key,
            diag=diag,
            qpos=data.qpos,
            qvel=data.qvel,
            prev=jax.tree.map(lambda b: b[sensor.head], sensor.buffer),
            n_updates=jnp.int32(0),
            n_skipped=jnp.int32(0),
        )

    def measure(self, data, prev: sensors.Readings, r: sensors.Readings):
        """The estimator's inputs of one update (a ``RobotMeasurement``) from the readings
        ``r`` and the ones before them, ``prev``: the state of ``prev`` (``cfg.pairing``
        ``"delayed"``) or of ``r`` (``"raw"``), the acceleration and torque of ``r``.

        ``data`` is any ``mjx.Data`` of the model: only its ``qpos`` and ``qvel`` are
        replaced and the stages the measurement reads recomputed (``adapter.prepare``), so
        the same inputs can be rebuilt offline from recorded readings
        (:mod:`jax_contact.train.env_rollouts`).
        """
        # The state the acceleration belongs to (ContactObsConfig.pairing). The torque is
        # always this reading's: ``data.qfrc_actuator`` after ``mjx.step`` is the force
        # computed at the step's start and applied over it, the interval ``qacc`` spans.
        at = prev if self.cfg.pairing == "delayed" else r
        d = adapter.prepare(self.mjx_model, data.replace(qpos=at.qpos, qvel=at.qvel))
        return adapter.robot_measurement(
            self.mjx_model,
            d,
            self.desc,
            qdd=r.qacc,
            tau=r.tau,
            include_passive=self.cfg.include_passive,
            sole=self.cfg.sole,
        )

    def update(self, est: ContactEstState, data) -> ContactEstState:
        """One estimator update from the true state in ``data`` (after a physics step)."""
        key, k_sense, k_est = jax.random.split(est.key, 3)
        sensor, r = sensors.sensor_step(
            self.sensor, est.sensor, data.qpos, data.qvel, data.qfrc_actuator, key=k_sense
        )
        meas = self.measure(data, est.prev, r)
        belief, diag = jc.step_robot(self.params, self.terrain, est.belief, meas, key=k_est)
        if self.calibration is not None:
            diag = diag.replace(p_contact=probability(belief.logit, self.calibration))
        return ContactEstState(
            belief=belief,
            sensor=sensor,
            key=key,
            diag=diag,
            qpos=data.qpos,
            qvel=data.qvel,
            prev=r,
            n_updates=est.n_updates + 1,
            n_skipped=est.n_skipped + jnp.sum(~diag.valid).astype(jnp.int32),
        )

    def features(self, est: ContactEstState, data) -> jax.Array:
        """(n_per_foot * n_legs,) observation features (module docstring for the layout)."""
        c = self.cfg.logit_clip
        if self.cfg.observe == "none":
            return jnp.zeros((0,), jnp.float32)
        if self.cfg.observe == "truth":
            truth = self.truth(data)
            cols = [truth.astype(jnp.float32)]
            if self.cfg.include_logit:
                cols.append(jnp.where(truth, c, -c))
            return jnp.concatenate(cols).astype(jnp.float32)
        cols = [est.diag.p_contact]
        if self.cfg.include_logit:
            logit = est.belief.logit
            if self.calibration is not None:
                logit = apply_calibration(logit, self.calibration)
            cols.append(jnp.clip(logit, -c, c))
        if self.cfg.include_terms:
            cols += [jnp.nan_to_num(getattr(est.diag, n), nan=0.5) for n in TERM_NAMES]
        return jnp.concatenate(cols).astype(jnp.float32)

    def _check_placement(self, obs) -> None:
        """The configured ``obs_keys`` fit the observation (a dict's keys, or an array:
        then only the default placement, appended to it)."""
        keys = self.cfg.obs_keys
        if isinstance(obs, Mapping):
            missing = [k for k in keys if k not in obs]
            if missing:
                raise ValueError(
                    f"config.obs_keys {missing} not in the observation; its keys: {list(obs)}"
                )
        elif tuple(keys) != DEFAULT_OBS_KEYS:
            raise ValueError(
                f"config.obs_keys {list(keys)}: the observation is an array, not a dict of"
                " keys; the features are appended to it (leave obs_keys at its default)"
            )

    def add_features(self, obs, feats: jax.Array):
        if feats.shape[-1] == 0:
            return obs
        self._check_placement(obs)
        if isinstance(obs, Mapping):
            out = dict(obs)
            for k in self.cfg.obs_keys:
                out[k] = jnp.concatenate([obs[k], feats.astype(obs[k].dtype)], axis=-1)
            return out
        return jnp.concatenate([obs, feats.astype(obs.dtype)], axis=-1)

    def add_size(self, size):
        n = self.cfg.n_per_foot * self.desc.n_legs
        if n == 0:
            return size
        self._check_placement(size)
        if isinstance(size, Mapping):
            out = dict(size)
            for k in self.cfg.obs_keys:
                shape = (size[k],) if isinstance(size[k], int) else tuple(size[k])
                out[k] = shape[:-1] + (shape[-1] + n,)
            return out
        return int(size) + n


def model_of(env) -> tuple[object, mujoco.MjModel, bool]:
    """(nominal mjx model, its mujoco.MjModel, is a Brax PipelineEnv) of an env."""
    inner = env.unwrapped
    if isinstance(inner, brax_base.PipelineEnv):
        if inner.backend != "mjx":
            raise ValueError(
                f"env uses the Brax {inner.backend!r} backend; the wrapper needs an MJX model:"
                " valid backend: 'mjx'"
            )
        sys = inner.sys
        if getattr(sys, "mj_model", None) is None:
            raise ValueError("env.sys has no mj_model: build the System with brax.io.mjcf")
        return sys, sys.mj_model, True
    mjx_model = getattr(inner, "mjx_model", None)
    mj_model = getattr(inner, "mj_model", None)
    if mjx_model is None or mj_model is None:
        raise ValueError(
            f"env ({type(inner).__name__}) has no MJX model: the wrapper takes a Brax"
            " PipelineEnv with backend='mjx' or a MuJoCo Playground MjxEnv"
        )
    impl = getattr(getattr(mjx_model, "impl", None), "value", "jax")
    if impl != "jax":
        raise ValueError(
            f"env's MJX model uses impl={impl!r}; the estimator's adapter runs MJX's JAX"
            " implementation: build the env with config_overrides={'impl': 'jax'}"
        )
    return mjx_model, mj_model, False


def make_core(env, cfg: ContactObsConfig) -> Core:
    """Checks ``cfg`` against ``env`` and builds its :class:`Core` (raises with the reason)."""
    validate_config(cfg)
    mjx_model, mj_model, _ = model_of(env)
    desc, resolved = feet.describe(mj_model, cfg.feet)
    rate = "substep" if cfg.rate == "auto" else cfg.rate
    if cfg.record_substeps and rate != "substep":
        raise ValueError("config.record_substeps needs rate='substep'")
    dt = float(mj_model.opt.timestep) if rate == "substep" else float(np.asarray(env.dt))
    robot = Robot(name="wrapped env", mj_model=mj_model, description=desc, spec=None)
    sensor_params = contact_params.default_sensor_params(cfg.sensor, robot, dt)
    params, params_source, calibration_in_file = cfg.params, "given", None
    file_terrain = None  # the terrain model a parameter file was tuned with, if it says
    if params is None:
        params_source = "default"
        params = contact_params.default_estimator_params(
            robot, dt, sensor_params, force_rows=cfg.force_rows
        )
    elif isinstance(params, str | os.PathLike):
        params_source = str(params)
        derive = None
        if isinstance(cfg.sensor, str):  # a preset can be made at the file's period too

            def derive(d):
                sp = contact_params.default_sensor_params(cfg.sensor, robot, d)
                return contact_params.default_estimator_params(
                    robot, d, sp, force_rows=cfg.force_rows
                )

        params, provenance = load_params_for(
            params,
            nv=desc.nv,
            dt=dt,
            period=f"the estimator's ({rate} rate)",
            derive=derive,
            mass_kg=model_mass(mj_model),
            with_provenance=True,
            groups=robot_space(desc).named_groups(),
        )
        calibration_in_file = file_calibration(provenance, cfg.params)
        file_terrain = terrain_model_of(provenance, cfg.params)
        if unused := [t for t in TERMS if t not in params.terms]:
            # The wrapped env reads every joint torque, so every term can run here.
            warnings.warn(
                f"the parameters {str(cfg.params)!r} run no {' or '.join(unused)} term (a file"
                " tuned on recordings without their columns); the wrapped env's readings"
                " support every term, and the defaults run them all",
                stacklevel=2,
            )
    elif not isinstance(params, jc.EstimatorParams):
        raise ValueError(
            "params must be jax_contact.EstimatorParams, a parameter file or a preset name, got"
            f" {type(params).__name__}"
        )
    else:
        jc.validate_params(params)
        # Named: only what differs, dt as the float32 it is stored in rounds it.
        wrong = []
        if params.nv != desc.nv:
            wrong.append(f"nv={params.nv} where the robot has nv={desc.nv}")
        if not np.isclose(float(params.dt), dt, rtol=1e-5):
            wrong.append(
                f"dt={float(params.dt):.6g} s where rate={rate!r} runs the estimator every"
                f" {dt:.6g} s (make them at that period: jax_contact.params_for(..., dt))"
            )
        if wrong:
            raise ValueError(f"params has {'; and '.join(wrong)}")
    terrain = cfg.terrain
    if terrain is None:
        # The floor's plane, or the model a parameter file was tuned with over it (as the
        # log commands run it: jax_contact.train.log_estimator.resolve_terrain_model).
        plane = contact_params.default_terrain(mj_model, desc)
        terrain = terrain_for(plane, file_terrain or "flat")
    truth_raw, source = contact_truth.truth_reader(
        mj_model, desc, resolved, cfg.truth, cfg.truth_threshold
    )
    floors = desc.floor_geom_ids
    truth = contact_truth.with_gap(truth_raw, mj_model, resolved, floors, cfg.truth_gap)
    if truth is None or truth is truth_raw:
        truth_raw = None
    if cfg.truth == "auto" and truth is None and cfg.observe != "truth":
        # A foot without a floor-touching geom lost the score without a word (a named geom
        # that cannot touch the floor is refused by feet.resolve_feet; a site's, a body's
        # or a FootSpec's body with none was not).
        bare = [f.name for f in resolved if not f.geom_ids]
        warnings.warn(
            f"no ground-truth contact: feet {bare} have no geom that touches the floor, nor"
            " contact sensors, so the wrapper"
            " reports no contact_est score or accuracy metric; name each foot's floor geoms"
            " (FootSpec(name, body=..., geoms=(...))) or add sensors"
            " (jax_contact.envs.ground_truth.with_contact_sensors); config.truth='none'"
            " silences this",
            stacklevel=3,
        )
    if cfg.observe == "truth" and truth is None:
        raise ValueError(
            f"config.observe='truth' needs ground-truth contact, but config.truth={cfg.truth!r}"
            " finds none for every foot: add sensors"
            " (jax_contact.envs.ground_truth.with_contact_sensors)"
        )
    # "auto": the map of a file or preset, if any; else the config's (None or a map).
    calibration = calibration_in_file if cfg.calibration == "auto" else cfg.calibration
    return Core(
        mjx_model=mjx_model,
        desc=desc,
        feet=resolved,
        params=params,
        sensor=sensor_params,
        terrain=terrain,
        cfg=cfg,
        truth=truth,
        truth_source=source,
        rate=rate,
        truth_raw=truth_raw,
        calibration=calibration,
        params_source=params_source,
        sign_test_margin=contact_params.sign_test_margin(mj_model, desc, params),
    )


def _terrain_summary(terrain) -> dict | str:
    """A terrain model as plain values: its kind and each field (nested terrains as dicts),
    e.g. ``{"kind": "FlatTerrain", "height": 0.025, "sigma": 0.05}``."""
    if not dataclasses.is_dataclass(terrain):
        return type(terrain).__name__
    out: dict = {"kind": type(terrain).__name__}
    for f in dataclasses.fields(terrain):
        v = getattr(terrain, f.name)
        if dataclasses.is_dataclass(v):
            out[f.name] = _terrain_summary(v)
        elif np.ndim(v) == 0:
            out[f.name] = round(float(v), 6)
        else:
            out[f.name] = f"array of shape {np.shape(v)}"
    return out


def report(core: Core) -> dict:
    """What the wrapper chose, for the user to read (nothing is chosen silently)."""
    return {
        "rate": core.rate,
        "dt": float(core.params.dt),
        "feet": [
            {
                "name": f.name,
                "kind": f.kind,
                "point_in_body": [round(float(x), 5) for x in f.point],
                "radius": float(f.radius),
                "n_geoms": len(f.geom_ids),
            }
            for f in core.feet
        ],
        "sole": core.cfg.sole,  # a flat foot's contact point: rolling, or its centre
        "leg_dofs": len(core.desc.leg_dofs[0]),
        "force_rows": tuple(int(i) for i in core.params.force_rows),
        "sign_test": bool(core.params.unilateral),
        # Why: a foot's share of the weight over its estimated push's error (>= 1: on).
        "sign_test_margin": None
        if core.sign_test_margin is None
        else round(float(core.sign_test_margin), 3),
        # The ground the estimator assumes (a height field's plane at its mean height).
        "terrain": _terrain_summary(core.terrain),
        "truth": core.truth_source,
        "truth_gap_m": float(core.cfg.truth_gap) if core.truth_raw is not None else 0.0,
        "observe": core.cfg.observe,
        "n_features": core.cfg.n_per_foot * core.desc.n_legs,
        "obs_keys": core.cfg.obs_keys,
        "params": core.params_source,
        "calibration": None if core.calibration is None else core.calibration.as_dict(),
    }
