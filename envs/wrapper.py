"""Drop-in contact observation wrapper: estimated foot contact in the policy observation.

:func:`wrap_contact` wraps a Brax ``PipelineEnv`` (MJX backend) or a MuJoCo Playground
``MjxEnv`` so that the policy sees, in training, the contact it will see on the robot: the
probability of the estimator of Hwangbo et al. fed by simulated, noisy proprioception, not
the simulator's ground truth.

Per estimator update (the flow is one way, truth never reaches the observation):

1. the true ``qpos``, ``qvel``, ``qfrc_actuator`` after a physics step go through the
   sensor model (:mod:`envs.sensors`: noise, bias, outliers, latency, ``qacc`` by
   differencing the noisy velocity);
2. the adapter evaluates the model at the *measured* state (``d.replace(qpos=..., qvel=...)``,
   :func:`jax_contact.adapter.prepare`, :func:`~jax_contact.adapter.robot_measurement` with
   the measured ``qacc`` and torques) on the *nominal* model the env had when it was
   wrapped: domain randomisation changes the simulated robot, never the estimator's model,
   as on hardware; by default (``ContactObsConfig.pairing="delayed"``) at the state read
   at the *previous* update, which the newly differenced acceleration belongs to (the
   pairing :mod:`train.evaluate` explains), with the torque read now (after ``mjx.step``,
   ``qfrc_actuator`` is the force applied over the step just taken), so the belief is one
   estimator period late;
3. :func:`jax_contact.step_robot` updates each foot's belief.

Rates (``ContactObsConfig.rate``):

- ``"substep"``: the estimator runs on every physics step. For a Brax ``PipelineEnv`` the
  wrapper re-implements the env's substep loop (``pipeline_step``: ``_n_frames`` calls of
  the MJX pipeline step) with an estimator update after each substep, and swaps it in for
  the duration of the wrapped env's ``step`` (as Brax's domain-randomisation wrapper swaps
  ``sys``). The env's own ``step`` must call ``self.pipeline_step`` once (or several times
  in sequence), not inside its own ``scan``.
- ``"control"``: one update per env step with ``dt = env.dt`` (the control period), for
  envs whose substeps cannot be reached (Playground's ``mjx_env.step``). Coarser: the
  measured ``qacc`` is the mean acceleration over a control period, and impacts inside it
  are seen only through their end state; :func:`compare_rates` measures the cost.
- ``"auto"``: ``"substep"`` for a Brax ``PipelineEnv``, else ``"control"``.

State, all in ``state.info`` (nothing hidden in the env's own keys; the env's ``info["rng"]``
is never touched): ``info[info_key]`` is a :class:`ContactEstState` (belief, sensor state,
the wrapper's own PRNG key, the last diagnostics); for evaluation only,
``info[info_key + "_truth"]`` holds the ground-truth contact of each foot and
``metrics[info_key + "/accuracy"]`` the fraction of feet whose flag ``p > 0.5`` matches it.

Resets. ``reset`` starts a fresh belief (``P(C) = params.initial_contact``) and fresh
sensors. Brax's ``AutoResetWrapper`` and Playground's ``BraxAutoResetWrapper`` swap in the
first pipeline state and observation when an episode ends but carry ``info`` over, so the
wrapper also restarts whenever the state handed to ``step`` differs from the one it
returned: it keeps the true ``qpos`` and ``qvel`` it returned and compares them bitwise
(an auto-reset replaces them; nothing else between two steps of the training wrappers
does). A change to ``qpos``/``qvel`` made by code outside the wrapper therefore also counts
as a reset.

Observation features, per foot in the description's foot order, blocks in this order:
``p_contact`` (n_legs), then with ``include_logit`` the belief's logit clipped to
``+-logit_clip`` (n_legs), then with ``include_terms`` the per-term probabilities
``p_dynamics, p_diff_kinematics, p_kinematics, p_takeoff, p_touchdown`` (5 x n_legs, a term
without a valid measurement reads 0.5). They are appended to an array observation, or to
each ``obs_keys`` entry of a dict observation (Playground's policy input is ``"state"``,
its critic's ``"privileged_state"``). ``observe="truth"`` fills the same layout with the
ground truth (the privileged baseline), ``observe="none"`` adds nothing; the estimator runs
and its accuracy is in ``metrics`` either way.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs import base as brax_base
from brax.io import mjcf as brax_mjcf
from flax import struct
from mujoco_playground._src import mjx_env as pg_env
from mujoco_playground._src import wrapper as pg_wrapper

import jax_contact as jc
from envs import ground_truth, sensors
from envs.robots import Robot
from jax_contact import adapter, metrics
from jax_contact.robot import RobotDescription, derive_description

RATES = ("auto", "substep", "control")
OBSERVE = ("estimate", "truth", "none")
PAIRINGS = ("delayed", "raw")
TRUTH_SOURCES = ("auto", "force_sensors", "found_sensors", "none")
TERM_NAMES = ("p_dynamics", "p_diff_kinematics", "p_kinematics", "p_takeoff", "p_touchdown")
# The sensor presets' latency is one step at the paper's 400 Hz (2.5 ms); at other rates
# the wrapper keeps that delay in seconds rather than in steps (a choice, see
# default_sensor_params).
_PRESET_LATENCY_DT = 0.0025
# Tag folded into the reset key, so the wrapper's stream is its own and the wrapped env
# gets the caller's key untouched (wrapped and unwrapped envs simulate the same episode).
_KEY_TAG = 0x6A78_636E


# ------------------------------------------------------------------------------ config


@struct.dataclass
class ContactObsConfig:
    """How the wrapper observes contact. Every field is static.

    Attributes:
      rate: one of :data:`RATES` (module docstring).
      observe: what the policy sees, one of :data:`OBSERVE`: ``"estimate"`` the estimator's
        belief; ``"truth"`` the ground-truth contact in the same layout (``p_contact`` 0 or
        1, the logit +-``logit_clip``), for the privileged baseline a policy trained on it
        can then be evaluated with ``"estimate"`` (the sim-to-real check); ``"none"`` no
        features. The estimator runs, and its accuracy is reported, in all three.
      pairing: ``"delayed"`` (default) or ``"raw"``, as :func:`train.evaluate.replay`: the
        update emitted after step ``k`` evaluates the model at the state read at ``k-1``
        with the acceleration differenced over ``[k-1, k]`` and the torque read at ``k``
        (``qfrc_actuator`` after ``mjx.step`` is the force applied over ``[k-1, k]``): one
        consistent sample, one estimator period late; ``"raw"`` takes the state read at
        ``k``.
      include_logit: also observe the belief's logit.
      include_terms: also observe the five per-term probabilities.
      obs_keys: entries of a dict observation that get the features.
      info_key: ``state.info`` key of the estimator state; the truth goes under
        ``info_key + "_truth"``, the metric under ``info_key + "/accuracy"``.
      truth: ground-truth source, one of :data:`TRUTH_SOURCES`: ``force_sensors`` reads
        the contact force sensors of :func:`envs.ground_truth.with_contact_sensors`
        (contact = normal force > ``truth_threshold``); ``found_sensors`` reads the model's
        own foot-floor contact sensors with ``data="found"`` (Playground's
        ``<foot>_floor_found``); ``auto`` takes the first of these the model has for every
        foot, else ``none`` (no truth in ``info``, no metric).
      truth_threshold: normal force above which a foot is in contact, N.
      record_substeps: substep rate only: also keep every substep's ``p_contact`` and
        truth, (n_frames, n_legs), in ``info[info_key + "_substeps"]`` for evaluation.
      include_passive: the estimator's ``h`` includes the model's joint springs and
        dampers (Playground's Go1 implements the PD's D term as joint damping, a force
        the robot knows).
      logit_clip: bound of the observed logit.
    """

    rate: str = struct.field(pytree_node=False, default="auto")
    observe: str = struct.field(pytree_node=False, default="estimate")
    pairing: str = struct.field(pytree_node=False, default="delayed")
    include_logit: bool = struct.field(pytree_node=False, default=False)
    include_terms: bool = struct.field(pytree_node=False, default=False)
    obs_keys: tuple[str, ...] = struct.field(pytree_node=False, default=("state",))
    info_key: str = struct.field(pytree_node=False, default="contact_est")
    truth: str = struct.field(pytree_node=False, default="auto")
    truth_threshold: float = struct.field(pytree_node=False, default=1.0)
    record_substeps: bool = struct.field(pytree_node=False, default=False)
    include_passive: bool = struct.field(pytree_node=False, default=True)
    logit_clip: float = struct.field(pytree_node=False, default=10.0)

    @property
    def n_per_foot(self) -> int:
        if self.observe == "none":
            return 0
        return 1 + int(self.include_logit) + len(TERM_NAMES) * int(self.include_terms)


def _validate_config(cfg: ContactObsConfig) -> None:
    if cfg.rate not in RATES:
        raise ValueError(f"config.rate must be one of {RATES}, got {cfg.rate!r}")
    if cfg.observe not in OBSERVE:
        raise ValueError(f"config.observe must be one of {OBSERVE}, got {cfg.observe!r}")
    if cfg.pairing not in PAIRINGS:
        raise ValueError(f"config.pairing must be one of {PAIRINGS}, got {cfg.pairing!r}")
    if cfg.observe == "truth" and cfg.include_terms:
        raise ValueError(
            "config.include_terms has no ground-truth counterpart: observe='truth'"
            " takes p_contact and the logit only"
        )
    if cfg.truth not in TRUTH_SOURCES:
        raise ValueError(f"config.truth must be one of {TRUTH_SOURCES}, got {cfg.truth!r}")
    if isinstance(cfg.obs_keys, str) or not all(isinstance(k, str) for k in cfg.obs_keys):
        raise ValueError(f"config.obs_keys must be a tuple of str, got {cfg.obs_keys!r}")
    if not cfg.info_key or not isinstance(cfg.info_key, str):
        raise ValueError(f"config.info_key must be a non-empty str, got {cfg.info_key!r}")
    if not (np.isfinite(cfg.truth_threshold) and cfg.truth_threshold >= 0):
        raise ValueError(f"config.truth_threshold must be >= 0 (N), got {cfg.truth_threshold!r}")
    if not (np.isfinite(cfg.logit_clip) and cfg.logit_clip > 0):
        raise ValueError(f"config.logit_clip must be > 0, got {cfg.logit_clip!r}")


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
    """

    belief: jc.LegBelief
    sensor: sensors.SensorState
    key: jax.Array
    diag: jc.Diagnostics
    qpos: jax.Array
    qvel: jax.Array
    prev: sensors.Readings
    n_updates: jax.Array


# ------------------------------------------------------------------- model-side helpers


def _floating_base(mj_model: mujoco.MjModel) -> bool:
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
        "robot_or_desc must be an envs.robots.Robot or a jax_contact.robot.RobotDescription,"
        f" got {type(robot_or_desc).__name__}"
    )


def _force_rows(mj_model: mujoco.MjModel, desc: RobotDescription) -> tuple[int, ...]:
    """World axes the legs' joints span: the ``n_l`` largest rows of the foot Jacobians.

    A leg with three or more joints spans all three; a planar two-joint leg spans the two
    axes of its plane (the planar leg: x and z), read off the Jacobian at ``qpos0`` and the
    home keyframe.
    """
    if desc.n_leg_dofs >= 3:
        return (0, 1, 2)
    d = mujoco.MjData(mj_model)
    norms = np.zeros(3)
    keys = [mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_KEY, "home")]
    for qpos in [mj_model.qpos0] + [mj_model.key_qpos[k] for k in keys if k >= 0]:
        d.qpos[:] = qpos
        mujoco.mj_kinematics(mj_model, d)
        mujoco.mj_comPos(mj_model, d)
        for body, geom, dofs in zip(
            desc.foot_body_ids, desc.foot_geom_ids, desc.leg_dofs, strict=True
        ):
            jacp = np.zeros((3, mj_model.nv))
            mujoco.mj_jac(mj_model, d, jacp, None, d.geom_xpos[geom], body)
            norms += np.linalg.norm(jacp[:, list(dofs)], axis=1)
    return tuple(sorted(int(i) for i in np.argsort(-norms)[: desc.n_leg_dofs]))


def default_sensor_params(
    sensor: str | sensors.SensorParams, robot_or_desc, dt: float
) -> sensors.SensorParams:
    """The sensor model of a robot at estimator period ``dt``.

    A preset name is built with :func:`envs.sensors.sensor_preset` for the robot's
    coordinates (floating base or not; the base dofs of the description otherwise). The
    presets' latency is one step at 400 Hz (2.5 ms); it is kept in seconds here, as
    ``round(latency * 2.5 ms / dt)`` steps, so that the control-rate mode (20 ms steps)
    does not turn a 2.5 ms delay into 20 ms (a choice). A :class:`~envs.sensors.SensorParams`
    is returned as given, after checking its size and period.

    Raises:
      ValueError: an unknown preset (the message lists them), a ``SensorParams`` of the
        wrong ``nv`` or ``dt``, or a robot whose joints the sensor model cannot perturb.
    """
    desc = _desc_of(robot_or_desc)
    mj_model = _mj_model_of(robot_or_desc)
    floating = _floating_base(mj_model) if mj_model is not None else desc.nq == desc.nv + 1
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
    params = sensors.sensor_preset(
        sensor, desc.nv, dt=dt, floating_base=floating, base_dofs=desc.base_dofs
    )
    latency = int(round(params.latency * _PRESET_LATENCY_DT / dt))
    return params.replace(latency=latency)


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

    The one source of parameters (its docstring lists the rules), with two things only a
    simulated env knows: the force axes of legs with fewer than three joints, read from the
    model, and ``sigma_qdd_model``, an acceleration model error for the control rate, where
    ``qacc`` is the mean over a control period but the dynamics term predicts the
    instantaneous acceleration, combined in quadrature with the sensor-derived
    ``sigma_qdd``. Default 0: measured with :func:`compare_rates` (16 rollouts, 20 ms
    control period, ``pairing="raw"``), 1000 rad/s^2 raised the control-rate accuracy of
    the hopping planar leg (stiff servos) from 0.858 to 0.905 but lowered the stepping
    Go1's from 0.882 to 0.824.

    Args:
      robot_or_desc: an :class:`envs.robots.Robot` or a ``RobotDescription``.
      dt: estimator period, s (physics step in the substep mode, control period else).
      sensor_params: the sensor model (its ``dt`` must be ``dt``).
      sigma_qdd_model: see above, rad/s^2.
      force_rows: world axes of the contact force; None: all three for legs of three or
        more joints, else read from the model (a ``Robot`` is then needed).
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
            f"sensor_params must be envs.sensors.SensorParams, got {type(sensor_params).__name__}"
            " (default_sensor_params builds one from a preset name)"
        )
    if sensor_params.nv != desc.nv:
        raise ValueError(f"sensor_params has nv={sensor_params.nv}, the robot nv={desc.nv}")
    if not np.isclose(float(sensor_params.dt), dt, rtol=1e-5):
        raise ValueError(f"sensor_params.dt ({float(sensor_params.dt)}) must equal dt ({dt})")
    if not (np.isfinite(sigma_qdd_model) and sigma_qdd_model >= 0):
        raise ValueError(f"sigma_qdd_model must be >= 0, got {sigma_qdd_model!r}")
    if force_rows is None:
        mj_model = _mj_model_of(robot_or_desc)
        if desc.n_leg_dofs < 3 and mj_model is None:
            raise ValueError(
                f"legs with {desc.n_leg_dofs} joints span only some force axes: pass"
                " force_rows, or a Robot so that they can be read from the model"
            )
        force_rows = (0, 1, 2) if desc.n_leg_dofs >= 3 else _force_rows(mj_model, desc)
    params = jc.params_for(desc, sensor_params, dt, force_rows=force_rows, **params_for_kwargs)
    if sigma_qdd_model > 0:
        qdd = np.hypot(np.asarray(params.noise.sigma_qdd), sigma_qdd_model)
        params = params.replace(noise=params.noise.replace(sigma_qdd=jnp.asarray(qdd, jnp.float32)))
    return params


def default_terrain(mj_model: mujoco.MjModel, desc: RobotDescription, sigma: float = 0.05):
    """A flat terrain at the floor plane's height, ``sigma_pi`` = 5 cm (a choice).

    Sharper than the paper's 0.2 m so that the kinematics term can tell a foot held a few
    cm above the floor from contact (MODEL.md). For a height-field floor the mean floor
    height is used with ``sigma`` raised to the field's height range; pass a
    :func:`jax_contact.height_field` terrain for better.
    """
    floor = desc.floor_geom_ids[0]
    if int(mj_model.geom_type[floor]) == int(mujoco.mjtGeom.mjGEOM_PLANE):
        return jc.flat(height=float(mj_model.geom_pos[floor, 2]), sigma=sigma)
    hid = int(mj_model.geom_dataid[floor])
    top = float(mj_model.hfield_size[hid, 2])
    return jc.flat(height=float(mj_model.geom_pos[floor, 2]) + 0.5 * top, sigma=max(sigma, top))


# ------------------------------------------------------------------------- ground truth


def _found_sensor_adr(mj_model: mujoco.MjModel, desc: RobotDescription) -> tuple[int, ...] | None:
    """Per foot, the ``sensordata`` index of a foot-floor contact sensor's "found" value."""
    geom = int(mujoco.mjtObj.mjOBJ_GEOM)
    contact = int(mujoco.mjtSensor.mjSENS_CONTACT)
    adr = []
    for foot in desc.foot_geom_ids:
        hit = None
        for s in range(mj_model.nsensor):
            if int(mj_model.sensor_type[s]) != contact or not (mj_model.sensor_intprm[s, 0] & 1):
                continue
            pair = {
                (int(mj_model.sensor_objtype[s]), int(mj_model.sensor_objid[s])),
                (int(mj_model.sensor_reftype[s]), int(mj_model.sensor_refid[s])),
            }
            if (geom, foot) in pair and any((geom, f) in pair for f in desc.floor_geom_ids):
                hit = int(mj_model.sensor_adr[s])  # "found" is the first datum when present
                break
        if hit is None:
            return None
        adr.append(hit)
    return tuple(adr)


def _truth_reader(mj_model: mujoco.MjModel, desc: RobotDescription, cfg: ContactObsConfig):
    """A function ``data -> (n_legs,) bool`` ground truth, or None (no source)."""
    robot = Robot(name="wrapped env", mj_model=mj_model, description=desc, spec=None)
    layout = None
    if cfg.truth in ("auto", "force_sensors"):
        try:
            layout = ground_truth.make_truth_layout(robot, threshold=cfg.truth_threshold)
        except ValueError:
            if cfg.truth == "force_sensors":
                raise
    if layout is not None:
        return lambda d: ground_truth.foot_truth(layout, d).contact
    adr = None
    if cfg.truth in ("auto", "found_sensors"):
        adr = _found_sensor_adr(mj_model, desc)
        if adr is None and cfg.truth == "found_sensors":
            raise ValueError(
                "config.truth='found_sensors': the model has no contact sensor with"
                ' data="found" between every foot geom and the floor; feet:'
                f" {list(desc.foot_names)}"
            )
    if adr is not None:
        idx = jnp.asarray(adr)
        return lambda d: d.sensordata[idx] > 0
    return None


# ------------------------------------------------------------------------------ the core


@dataclasses.dataclass(frozen=True, eq=False)
class _Core:
    """Static description of one wrapped env and the pure functions of its estimator."""

    mjx_model: object  # the nominal mjx.Model (a brax System for Brax envs)
    desc: RobotDescription
    params: jc.EstimatorParams
    sensor: sensors.SensorParams
    terrain: object
    cfg: ContactObsConfig
    truth: object  # data -> (n_legs,) bool, or None

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
            p_contact=jax.nn.sigmoid(belief.logit),
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
        )

    def restart_if_reset(self, est: ContactEstState, data) -> ContactEstState:
        """Restarts belief and sensors if ``data`` is not the state last returned."""
        moved = jnp.any(data.qpos != est.qpos) | jnp.any(data.qvel != est.qvel)
        key, k_init = jax.random.split(est.key)
        fresh = self.init(data, k_init)
        return jax.tree.map(lambda a, b: jnp.where(moved, a, b), fresh, est.replace(key=key))

    def update(self, est: ContactEstState, data) -> ContactEstState:
        """One estimator update from the true state in ``data`` (after a physics step)."""
        key, k_sense, k_est = jax.random.split(est.key, 3)
        sensor, r = sensors.sensor_step(
            self.sensor, est.sensor, data.qpos, data.qvel, data.qfrc_actuator, key=k_sense
        )
        # The state the acceleration belongs to (ContactObsConfig.pairing). The torque is
        # always this reading's: ``data.qfrc_actuator`` after ``mjx.step`` is the force
        # computed at the step's start and applied over it, the interval ``qacc`` spans.
        at = est.prev if self.cfg.pairing == "delayed" else r
        d = adapter.prepare(self.mjx_model, data.replace(qpos=at.qpos, qvel=at.qvel))
        meas = adapter.robot_measurement(
            self.mjx_model,
            d,
            self.desc,
            qdd=r.qacc,
            tau=r.tau,
            include_passive=self.cfg.include_passive,
        )
        belief, diag = jc.step_robot(self.params, self.terrain, est.belief, meas, key=k_est)
        return ContactEstState(
            belief=belief,
            sensor=sensor,
            key=key,
            diag=diag,
            qpos=data.qpos,
            qvel=data.qvel,
            prev=r,
            n_updates=est.n_updates + 1,
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
            cols.append(jnp.clip(est.belief.logit, -c, c))
        if self.cfg.include_terms:
            cols += [jnp.nan_to_num(getattr(est.diag, n), nan=0.5) for n in TERM_NAMES]
        return jnp.concatenate(cols).astype(jnp.float32)

    def add_features(self, obs, feats: jax.Array):
        if feats.shape[-1] == 0:
            return obs
        if isinstance(obs, Mapping):
            missing = [k for k in self.cfg.obs_keys if k not in obs]
            if missing:
                raise ValueError(
                    f"config.obs_keys {missing} not in the observation; its keys: {list(obs)}"
                )
            out = dict(obs)
            for k in self.cfg.obs_keys:
                out[k] = jnp.concatenate([obs[k], feats.astype(obs[k].dtype)], axis=-1)
            return out
        return jnp.concatenate([obs, feats.astype(obs.dtype)], axis=-1)

    def add_size(self, size):
        n = self.cfg.n_per_foot * self.desc.n_legs
        if n == 0:
            return size
        if isinstance(size, Mapping):
            out = dict(size)
            for k in self.cfg.obs_keys:
                if k not in size:
                    raise ValueError(
                        f"config.obs_keys: {k!r} not in the observation; its keys: {list(size)}"
                    )
                shape = (size[k],) if isinstance(size[k], int) else tuple(size[k])
                out[k] = shape[:-1] + (shape[-1] + n,)
            return out
        return int(size) + n


def _model_of(env) -> tuple[object, mujoco.MjModel, bool]:
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


def _make_core(env, config, foot_names, sensor, params, terrain) -> tuple[_Core, str]:
    cfg = ContactObsConfig() if config is None else config
    _validate_config(cfg)
    mjx_model, mj_model, is_brax = _model_of(env)
    desc = derive_description(mj_model, foot_names)  # refuses no floor / unknown feet
    rate = cfg.rate
    if rate == "auto":
        rate = "substep" if is_brax else "control"
    if rate == "substep" and not is_brax:
        raise ValueError(
            f"config.rate='substep' needs a Brax PipelineEnv (its pipeline_step and _n_frames);"
            f" {type(env.unwrapped).__name__} hides its substeps: use rate='control'"
        )
    if cfg.record_substeps and rate != "substep":
        raise ValueError("config.record_substeps needs rate='substep'")
    if rate == "substep":
        dt = float(mj_model.opt.timestep)
    else:
        dt = float(np.asarray(env.dt))
    robot = Robot(name="wrapped env", mj_model=mj_model, description=desc, spec=None)
    sensor_params = default_sensor_params(sensor, robot, dt)
    if params is None:
        params = default_estimator_params(robot, dt, sensor_params)
    elif not isinstance(params, jc.EstimatorParams):
        raise ValueError(f"params must be jax_contact.EstimatorParams, got {type(params).__name__}")
    else:
        jc.validate_params(params)
        if params.nv != desc.nv or not np.isclose(float(params.dt), dt, rtol=1e-5):
            raise ValueError(
                f"params has nv={params.nv}, dt={float(params.dt)}; rate={rate!r} needs"
                f" nv={desc.nv}, dt={dt}"
            )
    if terrain is None:
        terrain = default_terrain(mj_model, desc)
    truth = _truth_reader(mj_model, desc, cfg)
    if cfg.observe == "truth" and truth is None:
        raise ValueError(
            f"config.observe='truth' needs ground-truth contact, but config.truth={cfg.truth!r}"
            " finds none for every foot: add sensors (envs.ground_truth.with_contact_sensors)"
        )
    core = _Core(
        mjx_model=mjx_model,
        desc=desc,
        params=params,
        sensor=sensor_params,
        terrain=terrain,
        cfg=cfg,
        truth=truth,
    )
    return core, rate


@contextlib.contextmanager
def _swap_pipeline_step(env, fn):
    """Sets ``env.pipeline_step`` (an instance attribute shadows the method) for a while."""
    if "pipeline_step" in vars(env):
        raise ValueError(
            f"{type(env).__name__}.pipeline_step is already replaced: only one substep-rate"
            " contact wrapper can wrap an env (give the others config.rate='control')"
        )
    env.pipeline_step = fn
    try:
        yield
    finally:
        del env.pipeline_step


class _ContactMixin:
    """reset / step shared by the Brax and the Playground wrapper."""

    _DATA: str  # the State field holding the MJX data

    def _init_contact(self, config, foot_names, sensor, params, terrain) -> None:
        core, rate = _make_core(self.env, config, foot_names, sensor, params, terrain)
        self._core = core
        self._rate = rate
        key = core.cfg.info_key
        self._truth_key = key + "_truth"
        self._substeps_key = key + "_substeps"
        self._metric_key = key + "/accuracy"

    @property
    def contact_core(self) -> _Core:
        """The description, parameters, sensor model and terrain the wrapper uses."""
        return self._core

    @property
    def contact_rate(self) -> str:
        """``"substep"`` or ``"control"``."""
        return self._rate

    @property
    def observation_size(self):
        return self._core.add_size(self.env.observation_size)

    def _finish(self, state, est: ContactEstState, subs=None):
        core = self._core
        data = getattr(state, self._DATA)
        info = dict(state.info)
        info[core.cfg.info_key] = est
        metrics_ = dict(state.metrics)
        if core.truth is not None:
            truth = core.truth(data)
            info[self._truth_key] = truth
            hit = (est.diag.p_contact > 0.5) == truth
            metrics_[self._metric_key] = jnp.mean(hit.astype(jnp.float32))
        if core.cfg.record_substeps:
            info[self._substeps_key] = subs
        obs = core.add_features(state.obs, core.features(est, data))
        return state.replace(obs=obs, info=info, metrics=metrics_)

    def _substep_record(self, est: ContactEstState, data):
        n_frames = int(self.env.unwrapped._n_frames)
        p = jnp.broadcast_to(est.diag.p_contact, (n_frames,) + est.diag.p_contact.shape)
        rec = {"p_contact": p}
        if self._core.truth is not None:
            rec["truth"] = jnp.broadcast_to(self._core.truth(data), p.shape)
        return rec

    def reset(self, rng: jax.Array):
        if jnp.issubdtype(jnp.asarray(rng).dtype, jax.dtypes.prng_key):
            batched = jnp.ndim(rng) != 0
        else:
            batched = jnp.ndim(rng) != 1
        if batched:
            raise ValueError(
                f"reset got a batch of keys (shape {jnp.shape(rng)}): wrap the unbatched env"
                " and apply VmapWrapper (or the training wrappers) outside this wrapper"
            )
        state = self.env.reset(rng)
        if self._core.cfg.info_key in state.info:
            raise ValueError(
                f"state.info already has {self._core.cfg.info_key!r}: give this wrapper another"
                " config.info_key"
            )
        data = getattr(state, self._DATA)
        est = self._core.init(data, jax.random.fold_in(rng, _KEY_TAG))
        subs = self._substep_record(est, data) if self._core.cfg.record_substeps else None
        return self._finish(state, est, subs)

    def step(self, state, action: jax.Array):
        core = self._core
        est = core.restart_if_reset(state.info[core.cfg.info_key], getattr(state, self._DATA))
        if self._rate == "control":
            nstate = self.env.step(state, action)
            est = core.update(est, getattr(nstate, self._DATA))
            return self._finish(nstate, est)
        return self._step_substeps(state, action, est)

    def _step_substeps(self, state, action, est):
        core = self._core
        inner = self.env.unwrapped
        box: dict = {}

        def pipeline_step(pipeline_state, act):
            # Brax's PipelineEnv.pipeline_step with an estimator update after each substep;
            # several calls chain their estimator state.
            def f(carry, _):
                ps, e = carry
                ps = inner._pipeline.step(inner.sys, ps, act, inner._debug)
                e = core.update(e, ps)
                rec = {"p_contact": e.diag.p_contact}
                if core.truth is not None:
                    rec["truth"] = core.truth(ps)
                return (ps, e), rec

            (ps, e), rec = jax.lax.scan(
                f, (pipeline_state, box.get("est", est)), (), inner._n_frames
            )
            box["est"], box["rec"] = e, rec
            return ps

        with _swap_pipeline_step(inner, pipeline_step):
            nstate = self.env.step(state, action)
        if "est" not in box:
            raise ValueError(
                f"{type(inner).__name__}.step did not call self.pipeline_step, so the substep"
                " rate cannot reach its physics steps: use config.rate='control'"
            )
        return self._finish(nstate, box["est"], box["rec"] if core.cfg.record_substeps else None)


class BraxContactWrapper(_ContactMixin, brax_base.Wrapper):
    """Contact observation wrapper for Brax envs (``State.pipeline_state``). See the module."""

    _DATA = "pipeline_state"

    def __init__(
        self, env, config=None, *, foot_names=None, sensor="anymal_like", params=None, terrain=None
    ):
        super().__init__(env)
        self._init_contact(config, foot_names, sensor, params, terrain)


class PlaygroundContactWrapper(_ContactMixin, pg_wrapper.Wrapper):
    """Contact observation wrapper for Playground envs (``State.data``). See the module."""

    _DATA = "data"

    def __init__(
        self, env, config=None, *, foot_names=None, sensor="anymal_like", params=None, terrain=None
    ):
        super().__init__(env)
        self._init_contact(config, foot_names, sensor, params, terrain)


def wrap_contact(
    env,
    config: ContactObsConfig | None = None,
    *,
    foot_names: Sequence[str] | None = None,
    sensor: str | sensors.SensorParams = "anymal_like",
    params: jc.EstimatorParams | None = None,
    terrain=None,
):
    """Wraps an (unbatched) env so that its observation holds the estimated foot contact.

    Apply it before the training wrappers (``brax.envs.wrappers.training.wrap``,
    Playground's ``wrapper.wrap_for_brax_training``), which batch and auto-reset it.

    Args:
      env: a Brax ``PipelineEnv`` with ``backend="mjx"`` or a Playground ``MjxEnv``
        (``impl="jax"``), possibly already wrapped by unbatched wrappers.
      config: a :class:`ContactObsConfig`; None for the defaults.
      foot_names: foot geom or body names in the order the features should have; None
        takes every sphere geom that can touch the floor.
      sensor: a preset name of :data:`envs.sensors.PRESETS` (default ``"anymal_like"``) or
        a :class:`~envs.sensors.SensorParams` at the estimator's period.
      params: estimator parameters at the estimator's period (physics step for the substep
        rate, ``env.dt`` for the control rate); None: :func:`default_estimator_params`.
      terrain: a terrain model of :mod:`jax_contact.terrain`; None:
        :func:`default_terrain`.

    Returns:
      A :class:`BraxContactWrapper` or :class:`PlaygroundContactWrapper`.

    Raises:
      ValueError: with the reason, for an env without an MJX model (or another Brax
        backend, or a Playground model not on ``impl="jax"``), a model without floor or
        floor contact, unknown feet (the message lists valid names), a rate the env
        cannot run, or parameters that do not fit.
    """
    # The unwrapped env decides which State field holds the MJX data.
    inner = getattr(env, "unwrapped", env)
    if isinstance(inner, pg_env.MjxEnv):
        return PlaygroundContactWrapper(
            env, config, foot_names=foot_names, sensor=sensor, params=params, terrain=terrain
        )
    if isinstance(inner, brax_base.Env):
        return BraxContactWrapper(
            env, config, foot_names=foot_names, sensor=sensor, params=params, terrain=terrain
        )
    raise ValueError(
        f"env must be a Brax Env (PipelineEnv, backend='mjx') or a Playground MjxEnv, got"
        f" {type(env).__name__}"
    )


# ------------------------------------------------------------------ a minimal Brax env


class LeggedPipelineEnv(brax_base.PipelineEnv):
    """A minimal Brax ``PipelineEnv`` over a :class:`envs.robots.Robot`: actions are ``ctrl``.

    The project's own kind of environment for the wrapper's substep rate, its tests and
    :func:`compare_rates`: it starts at the robot's home pose at rest, observes the true
    joint positions (after the base coordinates) and all velocities, gives no reward, and
    is done when the state is not finite or the base falls below ``min_base_height``.

    Args:
      robot: the robot (add ground-truth sensors with
        :func:`envs.ground_truth.with_contact_sensors` first to get truth).
      n_frames: physics steps per env step.
      position_servo: (kp N m/rad, kv N m s/rad): turn every joint actuator into a position
        servo with these gains, keeping its force limits (the planar leg's torque motors),
        so that actions are joint targets; None keeps the actuators as they are.
      min_base_height: done below this base height, m; None: never.
    """

    def __init__(
        self,
        robot: Robot,
        *,
        n_frames: int = 1,
        position_servo: tuple[float, float] | None = None,
        min_base_height: float | None = None,
    ):
        mj_model = robot.mj_model
        if position_servo is not None:
            kp, kv = (float(x) for x in position_servo)
            spec = robot.spec.copy()
            for a in spec.actuators:
                limit = np.array(a.ctrlrange) * float(a.gear[0])
                a.set_to_position(kp=kp, kv=kv)
                a.forcelimited = 1
                a.forcerange = limit
                a.ctrllimited = 0
            timestep = mj_model.opt.timestep
            mj_model = spec.compile()
            mj_model.opt.timestep = timestep
        # brax.io.mjcf.load_model writes into the model it is given.
        sys = brax_mjcf.load_model(copy.deepcopy(mj_model))
        super().__init__(sys, backend="mjx", n_frames=n_frames)
        self._robot_mj_model = mj_model
        self._home = jnp.asarray(Robot(robot.name, mj_model, robot.description, None).home_qpos)
        self._n_base_q = 7 if _floating_base(mj_model) else len(robot.description.base_dofs)
        self._base_z = 2 if _floating_base(mj_model) else 0
        self._min_base_height = min_base_height
        key = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_KEY, "home")
        ctrl = mj_model.key_ctrl[key] if key >= 0 else np.zeros(mj_model.nu)
        self._home_ctrl = jnp.asarray(ctrl, dtype=jnp.float32)

    @property
    def mj_model(self) -> mujoco.MjModel:
        return self._robot_mj_model

    @property
    def observation_size(self) -> int:
        # PipelineEnv's default runs an (eager, slow) reset to find out.
        return self.sys.nq - self._n_base_q + self.sys.nv

    def _obs(self, ps) -> jax.Array:
        return jnp.concatenate([ps.qpos[self._n_base_q :], ps.qvel])

    def _done(self, ps) -> jax.Array:
        bad = ~(jnp.all(jnp.isfinite(ps.qpos)) & jnp.all(jnp.isfinite(ps.qvel)))
        if self._min_base_height is not None:
            bad = bad | (ps.qpos[self._base_z] < self._min_base_height)
        return bad.astype(jnp.float32)

    def reset(self, rng: jax.Array) -> brax_base.State:
        del rng  # deterministic start
        ps = self.pipeline_init(self._home, jnp.zeros(self.sys.nv), ctrl=self._home_ctrl)
        zero = jnp.zeros(())
        return brax_base.State(ps, self._obs(ps), zero, zero, {}, {})

    def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
        ps = self.pipeline_step(state.pipeline_state, action)
        return state.replace(pipeline_state=ps, obs=self._obs(ps), done=self._done(ps))


# --------------------------------------------------------------- rate comparison


@dataclasses.dataclass(frozen=True)
class RateComparison:
    """Accuracy of the control-rate mode against the substep mode on one set of rollouts.

    Attributes:
      substep: the substep-rate estimate, scored at the end of every env step.
      control: the control-rate estimate, scored at the same instants.
      substep_all: the substep-rate estimate, scored at every physics step.
      dt_substep, dt_control: the two estimator periods, s.
    """

    substep: metrics.ContactMetrics
    control: metrics.ContactMetrics
    substep_all: metrics.ContactMetrics
    dt_substep: float
    dt_control: float

    def table(self) -> str:
        rows = [
            (f"substep ({self.dt_substep * 1e3:g} ms), at env steps", self.substep),
            (f"control ({self.dt_control * 1e3:g} ms), at env steps", self.control),
            (f"substep ({self.dt_substep * 1e3:g} ms), every substep", self.substep_all),
        ]
        lines = [
            f"{'estimator':42s} {'acc':>6s} {'F1':>6s} {'prec':>6s} {'rec':>6s}"
            f" {'TD delay ms':>14s} {'fails':>5s} {'steps':>7s}"
        ]
        for name, m in rows:
            td = f"{m.touchdown_delay_ms[0]:.1f}+-{m.touchdown_delay_ms[1]:.1f}"
            lines.append(
                f"{name:42s} {m.accuracy:6.3f} {m.f1:6.3f} {m.precision:6.3f} {m.recall:6.3f}"
                f" {td:>14s} {m.failures:5d} {m.n_steps:7d}"
            )
        lines.append(
            f"control - substep: accuracy {self.control.accuracy - self.substep.accuracy:+.3f},"
            f" F1 {self.control.f1 - self.substep.f1:+.3f}"
        )
        return "\n".join(lines)


def compare_rates(
    env: brax_base.PipelineEnv,
    actions: jax.Array,
    *,
    key: jax.Array,
    sensor: str = "anymal_like",
    foot_names: Sequence[str] | None = None,
    params_kwargs: Mapping | None = None,
    control_params_kwargs: Mapping | None = None,
    skip_s: float = 0.0,
    pairing: str = "delayed",
) -> RateComparison:
    """Measures the accuracy lost by the control-rate mode against the substep mode.

    Both estimators run on *the same* rollouts: the env is wrapped twice (control rate
    inside, substep rate outside, under their own ``info`` keys), so one simulation feeds
    both and the physics cannot differ; each has its own sensor noise at its own rate
    (same preset). The physics does not depend on the estimates (the actions are given).

    Args:
      env: an unwrapped Brax ``PipelineEnv`` (MJX) with ground truth sensors
        (:func:`envs.ground_truth.with_contact_sensors`) or ``found`` contact sensors.
      actions: (T, E, nu) actions of E rollouts of T env steps.
      key: PRNG key; env e resets with ``split(key, E)[e]``.
      sensor: sensor preset name.
      foot_names: as :func:`wrap_contact`.
      params_kwargs: extra arguments of :func:`default_estimator_params` for both rates.
      control_params_kwargs: more of them for the control rate only (e.g.
        ``sigma_qdd_model``), applied last.
      skip_s: time at the start of every rollout left out of the scores (settling), s.
      pairing: :attr:`ContactObsConfig.pairing` of both estimators.

    Returns:
      The metrics of :func:`jax_contact.metrics.evaluate` for both, over the steps before
      each rollout's first ``done``.
    """
    acts = jnp.asarray(actions)
    if acts.ndim != 3:
        raise ValueError(f"actions must have shape (T, E, nu), got {acts.shape}")
    mj_model = _model_of(env)[1]
    desc = derive_description(mj_model, foot_names)
    extra = dict(params_kwargs or {})
    n_frames = int(env._n_frames)
    dt_sub = float(mj_model.opt.timestep)
    dt_ctrl = dt_sub * n_frames

    def make_params(dt, more):
        robot = Robot(name="env", mj_model=mj_model, description=desc, spec=None)
        sp = default_sensor_params(sensor, robot, dt)
        return default_estimator_params(robot, dt, sp, **{**extra, **more})

    ctrl_cfg = ContactObsConfig(
        rate="control", info_key="contact_control", truth="auto", pairing=pairing
    )
    sub_cfg = ContactObsConfig(
        rate="substep",
        info_key="contact_substep",
        truth="auto",
        record_substeps=True,
        pairing=pairing,
    )
    inner = BraxContactWrapper(
        env,
        ctrl_cfg,
        foot_names=foot_names,
        sensor=sensor,
        params=make_params(dt_ctrl, dict(control_params_kwargs or {})),
    )
    outer = BraxContactWrapper(
        inner, sub_cfg, foot_names=foot_names, sensor=sensor, params=make_params(dt_sub, {})
    )
    if inner.contact_core.truth is None:
        raise ValueError("env's model has no ground-truth contact sensors for every foot")

    def rollout(k, a_seq):
        state = outer.reset(k)

        def body(s, a):
            s = outer.step(s, a)
            info = s.info
            out = (
                info["contact_control"].diag.p_contact,
                info["contact_control_truth"],
                info["contact_substep_substeps"]["p_contact"],
                info["contact_substep_substeps"]["truth"],
                s.done,
            )
            return s, out

        return jax.lax.scan(body, state, a_seq)[1]

    keys = jax.random.split(key, acts.shape[1])
    p_c, t_c, p_s, t_s, done = jax.jit(jax.vmap(rollout, in_axes=(0, 1)))(keys, acts)
    # (E, T, ...) -> time first.
    p_c, t_c, done = (np.moveaxis(np.asarray(x), 0, 1) for x in (p_c, t_c, done))
    p_s, t_s = (np.moveaxis(np.asarray(x), 0, 1) for x in (p_s, t_s))
    if not np.array_equal(t_s[:, :, -1], t_c):
        raise RuntimeError("the two estimators saw different truths: rollouts diverged")
    t_len = acts.shape[0]
    alive = np.cumsum(done, axis=0) - done == 0  # steps up to and including the first done
    skip = int(round(skip_s / dt_ctrl))
    valid = alive & (np.arange(t_len) >= skip)[:, None]
    valid_c = np.broadcast_to(valid[..., None], p_c.shape)
    valid_s = np.broadcast_to(valid[:, :, None, None], p_s.shape)

    def flat(x):  # (T, E, n_frames, L) -> (T * n_frames, E, L), time order kept
        return np.moveaxis(x, 2, 1).reshape((t_len * n_frames,) + x.shape[1:2] + x.shape[3:])

    return RateComparison(
        substep=metrics.evaluate(p_s[:, :, -1], t_c, valid_c, dt=dt_ctrl),
        control=metrics.evaluate(p_c, t_c, valid_c, dt=dt_ctrl),
        substep_all=metrics.evaluate(flat(p_s), flat(t_s), flat(valid_s), dt=dt_sub),
        dt_substep=dt_sub,
        dt_control=dt_ctrl,
    )
