"""One source of estimator parameters: every value derived from the robot, sensors and gait.

:func:`params_for` is what the reproduction, the observation wrapper, offline evaluation
and the README use, so one robot with one sensor model gets one noise model everywhere.
Its rules (choices, documented in docs/model_choices.md):

Noise, per generalised coordinate, from the sensor model (``sensors``: any object with the
(nv,) fields ``sigma_q, sigma_qd, sigma_tau, sigma_acc, bias_rw_q, bias_rw_qd,
outlier_size`` and the scalar ``outlier_prob``, e.g. ``jax_contact.envs.sensors.SensorParams``):

- ``sigma_q``, ``sigma_qd``: white noise combined in quadrature with the spread the bias
  random walk reaches in ``bias_horizon_s`` (``rw * sqrt(T)``), floored at 1 mm (mrad) and
  0.01 m/s (rad/s) so ideal sensors never make the filter infinitely sure.
- ``sigma_qdd``: where a coordinate's acceleration is measured directly (``sigma_acc > 0``,
  an IMU's accelerometer) that noise; else the raw backward difference of the noisy
  velocity, ``sqrt(2) sigma_qd_white / dt`` (docs/model.md; the bias cancels in the
  difference); floor 0.1.
- ``sigma_d = sqrt(disturbance^2 + sigma_tau^2)``: Table II's 2 N m model error plus the
  torque sensors' noise, which enters the equation of motion the same way.
- the swing prior of eq. 8 (the air hypothesis) from the gait (:class:`GaitPrior`,
  ``swing_joint_speed``).
- ``sigma_f``, the contact force uncertainty (every axis): 10 N, at most
  :data:`FORCE_SHARE` = 0.4 of one foot's share of the robot's weight (``mass_kg g /
  n_legs``, :func:`contact_force_std`). The unilateral weight of the dynamics term,
  ``P(e . F < 0)`` under ``F ~ N(F_hat, sigma_f^2)``, tells a loaded foot from an unloaded
  one only if ``sigma_f`` is below the load; a foot bearing its share then loses at most
  ``log Phi(2.5)`` = -0.006 per step to it. On a light robot a fixed 10 N was a constant
  push to air on every loaded foot (a 3.4 kg hexapod standing still read as airborne).
  Every robot of 2.55 kg per leg or more (Go1, Spot, Barkour, the planar leg, every
  Playground locomotion env) keeps 10 N.

Robustness (docs/model_choices.md, "Robust likelihoods"): the outlier component's weight
``eps = clip(2 n_l p, 0.01, 0.5)`` from the sensors' per-sample outlier probability ``p``
(an outlier of any of the leg's ``n_l`` joints spikes two differenced accelerations),
never below 1 % because a real robot's outliers are never known exactly; its widths from
the outlier spike (``2 size / dt`` for accelerations, with ``size`` the largest spike of
any coordinate, base included; 8000 rad/s^2 when every spike size is 0, whatever the
probability) and 4 m/s for foot velocities. Caps: 0.99 dynamics, 0.9 differential kinematics on
the air side, 0.99 kinematics, 0.9 transitions. The still side of differential kinematics
is a rate of evidence, not a per-step value: :data:`STILL_EVIDENCE_PER_S` log-odds per
second (0.65 per step at 400 Hz, where it was chosen), so ``logit(cap) = rate x dt``, at
most the air side's cap (0.62 at 2 ms, 0.73 at 4 ms, 0.9 at a 20 ms control rate): a slow
swing foot looks still for a *time*, however many readings that is, and a standing foot
must be confirmed in a time that does not grow with the period.

The newest reading (docs/model_choices.md, "The newest reading for the kinematic terms"):
``kinematics_lead = 1``, the kinematic terms and the transitions read the foot at the end
of the interval whose acceleration the dynamics term reads, one step newer.

Contact (docs/model_choices.md, "Stabilised contact"): the dynamics term's contact
hypothesis brings a foot moving into the ground to rest at the rate
``contact_damping = 2 / contact_timeconst`` (critical damping of a contact that settles in
``contact_timeconst``, 20 ms by default: MuJoCo's default contact time constant, and the
order of a rubber foot on hard ground).

Sliding (docs/model_choices.md, "A sliding contact"): the differential-kinematics term's
contact hypothesis is a still foot or, with probability ``SLIP_PROB`` = 0.3, a foot
sliding along the terrain at a tangential speed of std ``SLIP_SPEED`` = 1 m/s (its normal
velocity still ~0); chosen on Go1's tuning seed (1000).
"""

from __future__ import annotations

import dataclasses
import numbers

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact.params import EstimatorParams, make_noise, make_params


def is_number(v) -> bool:
    """A real scalar, Python's, NumPy's (``np.float32(0.3)``) or a concrete 0-d JAX array
    (``jnp.float32(0.3)``), not a bool or a string."""
    if isinstance(v, jax.Array) and not isinstance(v, jax.core.Tracer):
        return v.shape == () and (
            jnp.issubdtype(v.dtype, jnp.floating) or jnp.issubdtype(v.dtype, jnp.integer)
        )
    return isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_)


# The differential-kinematics term's still-side evidence per second: logit(0.65) per 2.5 ms
# step, chosen at 400 Hz on Go1's tuning seed (docs/model_choices.md).
STILL_EVIDENCE_PER_S = float(np.log(0.65 / 0.35) / 0.0025)
CAP_DIFF_KINEMATICS = 0.9
# The sliding contact's weight and tangential speed std (m/s), chosen on tuning seed 1000
# (docs/model_choices.md, "A sliding contact").
SLIP_PROB = 0.3
SLIP_SPEED = 1.0


def still_cap(dt: float, air_cap: float = CAP_DIFF_KINEMATICS) -> float:
    """The still-side cap of the differential-kinematics term at period ``dt`` (s):
    ``sigmoid(STILL_EVIDENCE_PER_S dt)``, at most the air side's cap ``air_cap``
    (:data:`CAP_DIFF_KINEMATICS` unless the parameters set another)."""
    air = float(air_cap)
    logit = STILL_EVIDENCE_PER_S * float(dt)
    if air < 1.0:
        logit = min(logit, float(np.log(air / (1.0 - air))))
    return float(1.0 / (1.0 + np.exp(-logit)))


_SENSOR_VECTORS = (
    "sigma_q",
    "sigma_qd",
    "sigma_tau",
    "sigma_acc",
    "bias_rw_q",
    "bias_rw_qd",
    "outlier_size",
)


@dataclasses.dataclass(frozen=True)
class GaitPrior:
    """What the estimator assumes about the gait (eq. 8, 12, 15).

    Attributes:
      stance_time: ``T_s``, mean stance duration of the gait prior (eq. 12), s.
      swing_time: mean swing duration, s (the prior out of the air: first step, invalid
        steps, ``transition_model=False``).
      swing_joint_speed: std of a swinging leg's joint velocities, the air prior of the
        differential-kinematics term (eq. 8), rad/s (m/s for prismatic joints).
      takeoff_accel: ``a_F``, the largest take-off acceleration of the foot along the
        terrain normal (eq. 15), m/s^2. 100 m/s^2 was chosen on the reproduction's
        tuning seed (Go1 trot and walk, seed 1000; 200 m/s^2, the value of
        ``params.make_params`` and of the reproduction's ``paper_model``, lifted off 0.7 ms
        later there), never on an evaluation seed.

    The defaults (``T_s`` 0.3 s, swing 0.2 s, 25 rad/s: Table I's joint limit) describe a
    quadruped's trot; pass the gait's own numbers where they are known.
    """

    stance_time: float = 0.3
    swing_time: float = 0.2
    swing_joint_speed: float = 25.0
    takeoff_accel: float = 100.0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (is_number(v) and np.isfinite(v) and v > 0):
                raise ValueError(f"GaitPrior.{f.name} must be a finite number > 0, got {v!r}")


def _sensor_fields(sensors, nv: int) -> dict[str, np.ndarray]:
    out = {}
    for name in _SENSOR_VECTORS + ("outlier_prob",):
        if not hasattr(sensors, name):
            raise ValueError(
                f"sensors has no field {name!r}: pass a jax_contact.envs.sensors.SensorParams or"
                f" an object with the fields {_SENSOR_VECTORS + ('outlier_prob',)}"
            )
        arr = np.asarray(getattr(sensors, name), dtype=np.float64)
        want = () if name == "outlier_prob" else (nv,)
        if arr.shape != want:
            raise ValueError(
                f"sensors.{name} has shape {arr.shape}, expected {want} for a robot with nv={nv}"
            )
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ValueError(f"sensors.{name} must be finite and >= 0")
        out[name] = arr
    return out


def _sensor_noise(s: dict, dt: float, *, bias_horizon_s: float) -> dict[str, np.ndarray]:
    """(nv,) stds that the sensors alone put on each measured quantity (module docstring's
    rules, with their floors), the bias drift of ``bias_horizon_s`` folded in."""
    sigma_q = np.sqrt(s["sigma_q"] ** 2 + s["bias_rw_q"] ** 2 * bias_horizon_s)
    sigma_qd = np.sqrt(s["sigma_qd"] ** 2 + s["bias_rw_qd"] ** 2 * bias_horizon_s)
    sigma_qdd = np.where(s["sigma_acc"] > 0, s["sigma_acc"], np.sqrt(2.0) * s["sigma_qd"] / dt)
    return {
        "sigma_q": np.maximum(sigma_q, 1e-3),
        "sigma_qd": np.maximum(sigma_qd, 1e-2),
        "sigma_qdd": np.maximum(sigma_qdd, 0.1),
        "sigma_d": s["sigma_tau"],
    }


def sensor_noise_floor(desc, sensors, dt: float) -> dict[str, np.ndarray]:
    """The smallest stds a tuned noise model may take: what the sensors alone give.

    A filter that believes a joint velocity more precisely than its sensor measures it is
    over-confident, whatever a tuning loss gains from it (docs/tuning.md: tuned joint
    velocity stds at a third of the sensor's were the warning sign). Per (nv,) field of
    ``NoiseParams``: ``sigma_q`` and ``sigma_qd`` the white noise (no bias drift: the
    floor is what any one reading carries), ``sigma_qdd`` the differenced velocity's (or the
    accelerometer's) noise, ``sigma_d`` the torque sensors' noise (the model error above it
    is the tuner's to find). The floors of :func:`params_for` (1 mm, 0.01, 0.1) apply, so
    ``params_for``'s values are never below these. ``sigma_f``, ``sigma_J`` and the swing
    prior are model quantities with no sensor floor (absent from the result).

    Args:
      desc: the robot's ``RobotDescription``.
      sensors: the sensor model (as :func:`params_for`).
      dt: estimator period, s.

    Returns:
      ``{field: (nv,) float64 array}`` for ``sigma_q``, ``sigma_qd``, ``sigma_qdd``,
      ``sigma_d``; ``jax_contact.tune.tune``'s ``floor``.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite float > 0 (s), got {dt!r}")
    return _sensor_noise(_sensor_fields(sensors, int(desc.nv)), dt, bias_horizon_s=0.0)


# The contact force uncertainty's ceiling, N (this library's choice: Table II's entry is
# garbled in the paper), and its largest share of one foot's standing load.
SIGMA_F_MAX, FORCE_SHARE, GRAVITY = 10.0, 0.4, 9.81


def contact_force_std(desc) -> float:
    """``sigma_f`` of :func:`params_for` (module docstring): ``min(10 N, 0.4 m g / n_legs)``,
    10 N where the description has no mass (``mass_kg`` None), N."""
    mass = getattr(desc, "mass_kg", None)
    if mass is None:
        return SIGMA_F_MAX
    if not (np.isfinite(mass) and mass > 0):
        raise ValueError(f"desc.mass_kg must be a finite number > 0 (kg) or None, got {mass!r}")
    return float(min(SIGMA_F_MAX, FORCE_SHARE * mass * GRAVITY / desc.n_legs))


def params_for(
    desc,
    sensors,
    dt: float,
    *,
    gait: GaitPrior | None = None,
    disturbance: float = 2.0,
    bias_horizon_s: float = 10.0,
    contact_timeconst: float = 0.02,
    force_rows=None,
    **overrides,
) -> EstimatorParams:
    """Estimator parameters for a robot with a sensor model, at period ``dt``.

    Args:
      desc: the robot's ``jax_contact.robot.RobotDescription`` (nv, legs).
      sensors: the sensor model (module docstring); its noise is per coordinate.
      dt: estimator period, s.
      gait: the gait prior; default :class:`GaitPrior` ().
      disturbance: ``w_d``, the model error of the joints' equation of motion, N m.
      bias_horizon_s: time over which the sensor bias drift is folded into the noise, s.
      contact_timeconst: time in which a foot's contact brings it to rest, s; the
        dynamics term's ``contact_damping`` is ``2 / contact_timeconst`` (``inf``: the
        paper's rigid contact, ``contact_damping`` 0).
      force_rows: world axes of the contact force; default all three, which needs legs of
        three or more joints (pass them for shorter legs, see ``jax_contact.envs.wrapper``).
      **overrides: any argument of :func:`jax_contact.make_params` (caps, ``touchdown``,
        ...), applied last.

    Returns:
      Validated :class:`EstimatorParams`.

    Raises:
      ValueError: naming the argument or field that is wrong.
    """
    gait = GaitPrior() if gait is None else gait
    if not isinstance(gait, GaitPrior):
        raise ValueError(f"gait must be a GaitPrior, got {type(gait).__name__}")
    if not (is_number(dt) and np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite float > 0 (s), got {dt!r}")
    dt = float(dt)
    missing = [f for f in ("nv", "n_leg_dofs", "n_legs") if not hasattr(desc, f)]
    if missing:
        raise ValueError(
            f"desc must be a RobotDescription (load_robot(...).description or"
            f" jax_contact.robot.derive_description), got {type(desc).__name__} without {missing}"
        )
    for name, v in (("disturbance", disturbance), ("bias_horizon_s", bias_horizon_s)):
        if not (is_number(v) and np.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
    if not (is_number(contact_timeconst) and contact_timeconst > 0):
        raise ValueError(f"contact_timeconst must be a number > 0 (s), got {contact_timeconst!r}")
    nv, n_l = int(desc.nv), int(desc.n_leg_dofs)
    if isinstance(force_rows, str) or not (
        force_rows is None or isinstance(force_rows, tuple | list | np.ndarray)
    ):
        raise ValueError(f"force_rows must be a sequence of axes (e.g. (0, 2)), got {force_rows!r}")
    if force_rows is None:
        if n_l < 3:
            raise ValueError(
                f"legs of {n_l} joints span only some force axes: pass force_rows"
                " (e.g. (0, 2) for a leg in the x-z plane)"
            )
        force_rows = (0, 1, 2)
    elif len(tuple(force_rows)) > n_l:
        raise ValueError(
            f"force_rows {tuple(force_rows)}: legs of {n_l} joints span at most {n_l} force"
            " axes (the operational-space matrix of more is singular and its forces blow up);"
            " keep the normal and the largest tangential ones"
        )
    s = _sensor_fields(sensors, nv)
    # A sensor model with its own period (SensorParams) differentiates velocities at it:
    # sigma_qdd below is for readings at dt.
    if hasattr(sensors, "dt") and not np.isclose(float(np.asarray(sensors.dt)), dt, rtol=1e-4):
        raise ValueError(
            f"sensors.dt = {float(np.asarray(sensors.dt)):g} s but dt = {dt:g} s: build the"
            " sensor model at the estimator's period (sensor_preset(..., dt=dt))"
        )

    white = _sensor_noise(s, dt, bias_horizon_s=0.0)
    drift = _sensor_noise(s, dt, bias_horizon_s=bias_horizon_s)
    noise = make_noise(
        nv,
        sigma_q=drift["sigma_q"],
        sigma_qd=drift["sigma_qd"],
        sigma_qdd=white["sigma_qdd"],
        sigma_d=np.sqrt(disturbance**2 + white["sigma_d"] ** 2),
        sigma_f=contact_force_std(desc),
        sigma_qd_prior=gait.swing_joint_speed,
    )
    spike = float(np.max(s["outlier_size"]))
    kw = dict(
        dt=dt,
        stance_time=gait.stance_time,
        swing_time=gait.swing_time,
        takeoff_accel=gait.takeoff_accel,
        force_rows=tuple(force_rows),
        touchdown="quadrature",
        cap_dynamics=0.99,
        cap_diff_kinematics=CAP_DIFF_KINEMATICS,
        # At most the air side's cap, the one given in overrides where there is one.
        cap_diff_kinematics_still=still_cap(
            dt, overrides.get("cap_diff_kinematics", CAP_DIFF_KINEMATICS)
        ),
        cap_kinematics=0.99,
        cap_transition=0.9,
        outlier_prob=float(np.clip(2 * n_l * float(s["outlier_prob"]), 0.01, 0.5)),
        outlier_qdd=2.0 * spike / dt if spike > 0 else 8000.0,
        outlier_v=4.0,
        contact_damping=2.0 / float(contact_timeconst),
        kinematics_lead=1.0,
        slip_prob=SLIP_PROB,
        slip_speed=SLIP_SPEED,
    )
    return make_params(noise, **(kw | overrides))


def change_period(params: EstimatorParams, derived_old, derived_new) -> EstimatorParams:
    """``params`` made at one period, moved to another as :func:`params_for` moves its own.

    A tuned file keeps what tuning changed, relative to what the rules derived:
    each value becomes ``value x new / old``, where ``old`` and ``new`` are
    :func:`params_for`'s values for the same robot and sensors at the file's period and at
    the new one; the caps, per-step probabilities, in log-odds (``logit(cap) x
    logit(new) / logit(old)``). So what the rules scale with the period moves with it
    (``sigma_qdd`` ~ 1 / dt for a differenced velocity, the still-side cap's log-odds ~ dt,
    the outlier width ~ 1 / dt) and every other value is the file's: where ``old`` equals
    ``new`` it is kept, as is a value whose ``old`` is 0 (or a cap's 0.5 or 1). The still
    side's cap grows to at most the (moved) air side's, as :func:`still_cap`'s.

    Args:
      params: the parameters to move (e.g. a tuned file), at ``derived_old.dt``.
      derived_old, derived_new: :func:`params_for` (or
        :func:`jax_contact.envs.contact_params.default_estimator_params`) of the robot at
        the file's period and at the new one.

    Returns:
      ``params`` at ``derived_new.dt``; static fields (terms, force rows) are ``params``'.
    """
    import jax.numpy as jnp

    def moved(name, value, old, new):
        v, o, n = (np.asarray(x, np.float64) for x in (value, old, new))
        same = (o == n) | (o <= 0) | (name.startswith("cap_") & ((o <= 0.5) | (o >= 1.0)))
        with np.errstate(divide="ignore", invalid="ignore"):
            if name.startswith("cap_"):
                lv, lo, ln = (np.log(x / (1.0 - x)) for x in (v, o, n))
                out = 1.0 / (1.0 + np.exp(-lv * ln / lo))
            else:
                out = v * n / o
        return jnp.asarray(np.where(same, v, out), jnp.float32)

    def fields(obj, skip=()):
        return [
            f.name
            for f in dataclasses.fields(obj)
            if f.metadata.get("pytree_node", True) and f.name not in skip
        ]

    noise = {
        n: moved(
            n,
            getattr(params.noise, n),
            getattr(derived_old.noise, n),
            getattr(derived_new.noise, n),
        )
        for n in fields(params.noise)
    }
    values = {
        n: moved(n, getattr(params, n), getattr(derived_old, n), getattr(derived_new, n))
        for n in fields(params, skip=("noise", "dt"))
    }
    # The still side's log-odds grow with the period; as params_for's, they grow to at most
    # the air side's cap (Spot's tuned 0.876 was passed by a still cap moved from 0.66 at
    # 400 Hz to 0.91 at 100 Hz). A file's own still cap above its air cap is its own.
    values["cap_diff_kinematics_still"] = jnp.minimum(
        values["cap_diff_kinematics_still"],
        jnp.maximum(values["cap_diff_kinematics"], params.cap_diff_kinematics_still),
    )
    return params.replace(
        noise=params.noise.replace(**noise), dt=jnp.float32(derived_new.dt), **values
    )
