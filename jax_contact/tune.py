"""Tuning the estimator's continuous parameters by gradient on logs with ground truth.

The filter (eq. 1-3, 11-17) is differentiable end to end, so its noise model, caps and gait
constants can be fitted to a few seconds of data with ground-truth contact instead of by
hand. Everything here is arrays in, arrays out: the measurements of each log are
precomputed once (``jax_contact.train.tune_cmd`` runs the MJX adapter over a log's readings), and
the tuning loop only runs the estimator.

What is tuned (a documented choice, :data:`DEFAULT_FIELDS`), through an unconstrained
vector ``theta``:

- the noise standard deviations (``NoiseParams``), in log space, *relative to their
  physically derived values* ``sigma^0`` (:func:`jax_contact.params_for`: the sensor
  model, Table II's model error): ``sigma_i = sigma^0_i exp(theta_g(i))``. The ``nv``
  coordinates are tied in groups (:func:`robot_space`): the base's linear and rotational
  coordinates, and each joint position along the legs (the j-th joint of every leg
  shares one value, since the legs are alike); ``sigma_f`` has a horizontal and a normal
  group, ``sigma_J`` one. Tying keeps the tuned values interpretable and the problem far
  smaller than the data (5 groups x 7 fields for a quadruped).
- the five confidence caps, in logit space on their allowed interval (0.5, 1):
  ``cap = (1 + sigmoid(theta)) / 2``;
- ``T_s`` (``stance_time``, eq. 12) in a bounded interval, ``T_s = lo + (hi - lo)
  sigmoid(theta)`` (below), and ``a_F`` (``takeoff_accel``, eq. 15) in log space;
- on request only (:data:`OPTIONAL_FIELDS`), the stabilised contact's damping ``b``
  (``contact_damping``, eq. 6 stabilised, docs/model_choices.md) in log space, centred on
  ``params_for``'s ``2 / contact_timeconst``. It is a property of the foot and the ground
  (how fast a landing foot comes to rest), not of the sensors, so nothing floors it; a
  tuned ``b`` far outside ``2 / (0.005 .. 0.1 s)`` = 20-400 1/s no longer describes a
  foot settling into the ground. Opt-in because it changes which swing feet fit the
  contact hypothesis (a braking, still-descending foot fits a large ``b``), a trade
  docs/tuning.md measures per robot before any preset tunes it.

What a plausible ``T_s`` is: the gait prior's mean stance duration (eq. 12, ``P(A | C) =
dt / T_s``), so it should lie among the stance durations of the gaits the robot runs.
The scripted gaits stand for 0.30 s (trot: period 0.5 s, duty 0.6) and 1.02 s (walk:
1.2 s, 0.85); a quadruped of Go1's size trotting at 3 Hz with duty 0.5 stands for
~0.17 s. :data:`STANCE_TIME_BOUNDS` = (0.15, 1.2) s covers these with a margin and no
more. Without the bound, plain-BCE tuning drove ``T_s`` to 61-104 ms (docs/tuning.md): a
knob for earlier lift-offs (a take-off hazard ``dt / T_s`` of 4 % per step), not a stance
duration. The bound is hard (the sigmoid), and the prior below acts on ``theta``.

Floors (``tune(..., floor=...)``; ``jax-contact tune`` passes the log's sensor model's,
:func:`jax_contact.defaults.sensor_noise_floor`): no tuned std may fall below what the
sensors alone give (a joint velocity believed more precisely than its sensor measures it is
over-confidence, whatever the loss gains). Each update is projected back onto the bound
``theta_g >= max_{i in g} log(s_i / sigma^0_i)`` (:func:`theta_lower_bounds`): projected
gradient descent, so the gradient itself, and the finite-difference check of it, are those
of the unbounded loss.

Not tuned: ``dt``, the swing time (used only on invalid steps), the outlier model (from the
sensors' outlier rate), the foothold threshold, the static switches, and
``contact_damping`` unless asked for.

Loss (minimised with ``optax``: Adam after clipping the gradient's global norm)::

    L(theta) = (1 / N) sum_{t,e,l} m_tel BCE(l_tel(theta), y_tel)                 (data)
             + (lambda_sigma / 2) sum_{noise groups g} theta_g^2                 (prior)
             + (lambda_other / 2) sum_{caps, T_s, a_F} (theta_k - theta^0_k)^2
             + (w_e / N_A) sum_{true air phases a} softplus(E_a)                 (events)

    BCE(l, y) = -y log sigmoid(l) - (1 - y) log sigmoid(-l)
    E_a = tau log sum_{t in S_a} exp(l_t / tau)          (smooth maximum of the logit)

The event term (:func:`air_event_terms`; weight ``w_e = 0.3`` (``event_weight``),
temperature ``tau = 0.25`` logit units) prices false contacts as the metrics count them:
per true air phase, not per step. ``sigmoid(E_a)`` stands for the probability of at least
one false contact in phase ``a`` (``E_a`` lies between the largest logit of the phase and
``tau log |S_a|`` above it: at most ~1 for a 0.2 s phase), so ``softplus(E_a) = -log(1 -
sigmoid(E_a))`` is the binary cross-entropy of the phase-level event "no false contact"
(true in every true air phase), and ``N_A`` is the number of air phases. Plain BCE charges
a one-step blip of P = 0.55 in the air 0.8 nats, less than it gains by reaching contact a
step sooner at every touch-down, so plain-BCE tuning bought faster touch-downs with more
failures per air phase (Go1 trot 6.3 % -> 18.1 %, docs/tuning.md); the event term charges
the same blip ``0.3 softplus(0.2) = 0.24`` nats *per phase*, i.e. ~57 foot-steps' worth of
BCE (Go1 trot: 1071 air phases in 204,800 foot-steps). ``S_a`` (:func:`scored_air_steps`,
no gradient through the choice) are the phase's steps between the end of the lift-off's
fall (the stance's flag carried into the air and the fall after it are the lift-off delay,
not a false contact: ``jax_contact.metrics`` rule 7 needs a rise of the flag in the air)
and the start of the touch-down's rise within the metrics' early window (``event_early_s``
= 50 ms; the run into the touch-down is its detection, rule 4). A phase whose highest
scored logit is -4 costs ``softplus(-4 + ~1) = 0.05``; one with a blip to P = 0.6 costs
``softplus(0.4 + ...) >= 0.9``. With windows (below), a phase cut by a window boundary
counts as two phases. No lift-off/touch-down delay term: BCE already charges every late
step of both events (a separate delay term was not tried). The weight was chosen on Go1's
validation seed 1001 (trot and walk, never the evaluation seed): with ``w_e = 1`` the
trot's failures per air phase fell from 3.9 % to 0.2 % but the walk lost accuracy (0.982
-> 0.977), 4 ms of touch-down delay and ECE (0.013 -> 0.021); ``w_e = 0.3`` halved them
(2.1 %) and left every walking number within 0.1 ms and 0.002 ECE of the defaults
(docs/tuning.md). ``TuneConfig``'s default stays 0.3; the presets use a weight per robot
chosen on their validation seed among three (Go1 and Spot 0.1, Barkour 1.0:
``jax_contact.train.tune_cmd.PRESET_EVENT_WEIGHTS``).

Optionally (``constraint_weight`` ``lambda_c > 0``; off by default), the *cells in the
objective*, a constrained fit of issue 15's "every cell at least as good as the
defaults"::

    + lambda_c sum_{c in cells} softplus((s_c(theta) - s_c(theta^0)) / u_c)     (cells)

per window, where ``s_c`` are smooth stand-ins of the validation cells
(:func:`cell_surrogates`: wrong flags per step, air phases with a false contact per
phase, steps of touch-down and lift-off lateness, each counted with the flag ``l > 0``
smoothed to ``sigmoid(l / 0.5)``), ``s_c(theta^0)`` the untuned
parameters' on the same window (:func:`reference_cells`, once before the first epoch) and
``u_c`` the cell's tolerance (:func:`constraint_units`, from :data:`CELL_TOLERANCE`). A
cell worse than the defaults' by ``k`` tolerances costs ~``k lambda_c``; one better by a
few costs ~0. ECE has no stand-in: the BCE is its proper score, and the calibration map
follows.

Optionally (``air_penalty`` ``mu > 0``; off by default: the previous session's
diagnostic, superseded by the event term), a per-step false-contact term ``(mu / N)
sum_{t,e,l} m_tel (1 - y_tel) h(l_tel + m)`` with the smooth hinge ``h(x) = softplus(2
x) / 2`` and margin ``m`` (2: P = 0.12).

Here ``l_tel`` is the filtered belief ``b_t`` of foot ``l`` of env ``e`` as a logit (eq.
1-2, after the measurement update at ``t``), ``y`` the ground-truth contact, ``m`` the mask
of valid steps (env upright, finite) and ``N = sum m``. The prior is a Gaussian on each
log multiplier: it keeps every standard deviation near its physically derived value
(``theta_g = 0``) unless the data pay for moving it; ``lambda_sigma = 1e-3`` per group means
that doubling a std must lower the mean BCE by 2.4e-4 nats per foot-step.

Sequences are long (16 envs x 8 s x 400 Hz), so the gradient is truncated
backpropagation through time: each log is cut into windows of ``chunk`` steps; each
window's loss is differentiated through its scan (with ``jax.checkpoint`` per step, so
only the beliefs are stored and each step is recomputed in the backward pass) and gives
one optimizer update; the belief at the end of a window starts the next one, without
gradient. The filter forgets its past in a few tens of steps (every step's evidence is
capped), so little is lost. An *epoch* is one pass over every tuning log. After each
epoch the validation logs (another seed) are filtered with the current parameters over
their whole length: their loss without the prior (mean BCE + ``w_e`` x the mean event
term, :func:`score_logs`) decides early stopping (``patience`` epochs without improving
by ``min_delta``), and the parameters returned are those of the best validation epoch
(epoch 0, the untuned parameters, included, so tuning never returns a worse validation
loss than the defaults'). The validation air-phase failure rate is reported too. With
``select="cells"`` an epoch is returned only if it is *no worse than epoch 0 in any
validation cell* (:func:`no_worse`: on each validation log separately, F1, accuracy, ECE,
the air-phase failure rate and the magnitude of both mean event delays; ties allowed),
the lowest validation loss among those; when none is, the untuned parameters (epoch 0);
``cell_tolerance`` lets each cell be worse by that many :data:`CELL_TOLERANCE`.
It trades the single loss's optimum for issue 15's "every cell at least as good as the
defaults", measured on validation.

Randomness: the key ``jax.random.key(config.seed)`` is folded with the epoch, log and
window numbers, so a run is reproducible (the key only feeds the Monte-Carlo touch-down;
the quadrature mode is deterministic).

Calibration (:func:`fit_calibration`): a temperature and a bias on the fused logit,
``l' = l / T + c``, fitted by maximum likelihood (Newton's method in float64) on the
tuning logs' logits and applied after the recursion (the filter itself runs on ``l``).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from jax_contact.filter import init_belief_batch, step_batch
from jax_contact.params import EstimatorParams, NoiseParams, validate_params
from jax_contact.types import LegMeasurement, RobotMeasurement

NOISE_FIELDS = tuple(NoiseParams.__dataclass_fields__)
CAP_FIELDS = (
    "cap_dynamics",
    "cap_diff_kinematics",
    "cap_diff_kinematics_still",
    "cap_kinematics",
    "cap_transition",
)
LOG_FIELDS = ("stance_time", "takeoff_accel")
DEFAULT_FIELDS = NOISE_FIELDS + CAP_FIELDS + LOG_FIELDS
# Tuned only when asked (``fields=DEFAULT_FIELDS + ("contact_damping",)``, ``jax-contact tune
# --tune-also contact_damping``), in log space like ``a_F``: module docstring.
OPTIONAL_FIELDS = ("contact_damping",)
TUNABLE_FIELDS = DEFAULT_FIELDS + OPTIONAL_FIELDS
SCALAR_FIELDS = CAP_FIELDS + LOG_FIELDS + OPTIONAL_FIELDS
# Axis groups of the per-axis noise fields: sigma_f horizontal (x, y) and normal (z).
AXIS_GROUPS = {"sigma_f": ((0, 0, 1), ("horizontal", "normal")), "sigma_J": ((0, 0, 0), ("xyz",))}
# Where a cap of exactly 1 (unbounded) is the starting point, it starts just below.
_CAP_MAX = 1.0 - 1e-6
# The interval T_s is tuned in, s (module docstring: what a plausible T_s is).
STANCE_TIME_BOUNDS = (0.15, 1.2)
BOUNDED_FIELDS = ("stance_time",)


# ----------------------------------------------------------------------- the search space


@dataclasses.dataclass(frozen=True)
class ParamSpace:
    """Which parameters are tuned and how the ``nv`` coordinates are tied (static).

    Attributes:
      fields: names of tuned fields, among :data:`TUNABLE_FIELDS`.
      dof_groups: (nv,) the group of each generalised coordinate.
      group_names: a name per coordinate group (for reports).
      stance_time_bounds: (lo, hi), s: the interval ``T_s`` is tuned in (a hard bound,
        :data:`STANCE_TIME_BOUNDS` by default; module docstring).
    """

    fields: tuple[str, ...]
    dof_groups: tuple[int, ...]
    group_names: tuple[str, ...]
    stance_time_bounds: tuple[float, float] = STANCE_TIME_BOUNDS

    def __post_init__(self):
        lo, hi = (float(x) for x in self.stance_time_bounds)
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
            raise ValueError(
                f"stance_time_bounds must be 0 < lo < hi (s), got {self.stance_time_bounds!r}"
            )
        object.__setattr__(self, "stance_time_bounds", (lo, hi))
        bad = [f for f in self.fields if f not in TUNABLE_FIELDS]
        if bad or not self.fields or len(set(self.fields)) != len(self.fields):
            raise ValueError(f"fields must be distinct names among {TUNABLE_FIELDS}, got {bad}")
        n = len(self.group_names)
        if sorted(set(self.dof_groups)) != list(range(n)):
            raise ValueError(
                f"dof_groups must use every group 0..{n - 1} of group_names, got {self.dof_groups}"
            )

    @property
    def nv(self) -> int:
        return len(self.dof_groups)

    def groups_of(self, field: str) -> tuple[tuple[int, ...], tuple[str, ...]]:
        """(index of each entry's group, group names) of a noise field."""
        if field in AXIS_GROUPS:
            return AXIS_GROUPS[field]
        return self.dof_groups, self.group_names


def make_space(
    nv: int,
    *,
    dof_groups: Sequence[int] | None = None,
    group_names: Sequence[str] | None = None,
    fields: Sequence[str] = DEFAULT_FIELDS,
    stance_time_bounds: tuple[float, float] = STANCE_TIME_BOUNDS,
) -> ParamSpace:
    """A :class:`ParamSpace` for ``nv`` coordinates; by default all in one group."""
    groups = tuple(int(g) for g in (dof_groups if dof_groups is not None else (0,) * nv))
    if len(groups) != nv:
        raise ValueError(f"dof_groups must have nv={nv} entries, got {len(groups)}")
    n = max(groups) + 1
    names = tuple(group_names) if group_names is not None else tuple(f"g{i}" for i in range(n))
    return ParamSpace(
        fields=tuple(fields),
        dof_groups=groups,
        group_names=names,
        stance_time_bounds=tuple(stance_time_bounds),
    )


def robot_space(
    desc,
    fields: Sequence[str] = DEFAULT_FIELDS,
    stance_time_bounds: tuple[float, float] = STANCE_TIME_BOUNDS,
) -> ParamSpace:
    """The coordinate groups of a legged robot (``jax_contact.robot.RobotDescription``).

    A free-joint base gives ``base_linear`` (coordinates 0-2) and ``base_rotational``
    (3-5); any other base joints one ``base`` group; the j-th joint of every leg
    ``joint<j>`` (hip abduction, hip flexion, knee on a quadruped); coordinates in no leg
    and not the base ``other``.
    """
    nv = int(desc.nv)
    names: list[str] = []
    groups = [-1] * nv

    def group(name: str) -> int:
        if name not in names:
            names.append(name)
        return names.index(name)

    base = tuple(desc.base_dofs)
    floating = len(base) == 6 and base == tuple(range(6)) and desc.nq == desc.nv + 1
    for i in base:
        groups[i] = group(("base_linear" if i < 3 else "base_rotational") if floating else "base")
    for leg in desc.leg_dofs:
        for j, i in enumerate(leg):
            groups[i] = group(f"joint{j}")
    for i in range(nv):
        if groups[i] < 0:
            groups[i] = group("other")
    return ParamSpace(
        fields=tuple(fields),
        dof_groups=tuple(groups),
        group_names=tuple(names),
        stance_time_bounds=tuple(stance_time_bounds),
    )


def _cap_to_theta(cap) -> np.ndarray:
    c = np.clip(np.asarray(cap, np.float64), 0.5 + 1e-6, _CAP_MAX)
    x = 2.0 * c - 1.0
    return np.log(x) - np.log1p(-x)


def init_theta(space: ParamSpace, base: EstimatorParams) -> dict[str, jax.Array]:
    """The unconstrained values of ``base``: zeros for the noise log multipliers, the caps'
    logits, the scaled logit of ``T_s`` in its bounds and the log of ``a_F`` (module
    docstring).

    Raises:
      ValueError: ``base.stance_time`` is not strictly inside ``space.stance_time_bounds``.
    """
    theta = {}
    for f in space.fields:
        if f in NOISE_FIELDS:
            theta[f] = jnp.zeros(len(space.groups_of(f)[1]), jnp.float32)
        elif f in CAP_FIELDS:
            theta[f] = jnp.asarray(_cap_to_theta(getattr(base, f)), jnp.float32)
        elif f in BOUNDED_FIELDS:
            lo, hi = space.stance_time_bounds
            v = float(getattr(base, f))
            if not lo < v < hi:
                raise ValueError(
                    f"{f} = {v} s lies outside the tuning bounds ({lo}, {hi}) s; pass"
                    " stance_time_bounds that contain it (or freeze it)"
                )
            x = (v - lo) / (hi - lo)
            theta[f] = jnp.asarray(np.log(x) - np.log1p(-x), jnp.float32)
        else:
            v = float(getattr(base, f))
            if not (np.isfinite(v) and v > 0):
                raise ValueError(
                    f"{f} = {v} cannot be tuned in log space (it must be > 0); e.g."
                    " contact_damping 0 is the rigid contact: start from params_for's value"
                )
            theta[f] = jnp.asarray(np.log(v), jnp.float32)
    return theta


def to_params(space: ParamSpace, base: EstimatorParams, theta: dict) -> EstimatorParams:
    """``base`` with the tuned fields set from ``theta`` (differentiable, traceable)."""
    noise = {}
    for f in NOISE_FIELDS:
        ref = getattr(base.noise, f)
        if f in theta:
            idx = np.asarray(space.groups_of(f)[0])
            ref = ref * jnp.exp(theta[f][idx]).astype(ref.dtype)
        noise[f] = ref
    values = {}
    for f in SCALAR_FIELDS:
        if f not in theta:
            continue
        dtype = jnp.result_type(getattr(base, f))
        if f in CAP_FIELDS:
            values[f] = (0.5 + 0.5 * jax.nn.sigmoid(theta[f])).astype(dtype)
        elif f in BOUNDED_FIELDS:
            lo, hi = space.stance_time_bounds
            values[f] = (lo + (hi - lo) * jax.nn.sigmoid(theta[f])).astype(dtype)
        else:
            values[f] = jnp.exp(theta[f]).astype(dtype)
    return base.replace(noise=base.noise.replace(**noise), **values)


def theta_lower_bounds(
    space: ParamSpace, base: EstimatorParams, floor: dict | None
) -> dict[str, jax.Array]:
    """Lower bounds on ``theta`` that keep every tuned std at or above its floor.

    A noise field's std is ``sigma_i = sigma^0_i exp(theta_g(i))`` with one multiplier per
    group, so ``sigma_i >= s_i`` for every coordinate ``i`` of group ``g`` is
    ``theta_g >= max_{i in g} log(s_i / sigma^0_i)``; a floor of 0 bounds nothing
    (``log 0 = -inf``). Fields without a floor, caps, ``T_s`` and ``a_F``: ``-inf``.

    Args:
      space: what is tuned.
      base: the untuned parameters (``sigma^0``).
      floor: ``{noise field: std floor of the field's shape}`` in the field's units, e.g.
        :func:`jax_contact.defaults.sensor_noise_floor`; None: no bound.

    Returns:
      ``theta``'s structure, float32 ``-inf`` where unbounded.

    Raises:
      ValueError: a floor for an unknown field or of the wrong shape, negative or not
        finite, or ``base`` already below its floor (tuning starts from ``base``).
    """
    theta0 = init_theta(space, base)
    lower = {f: jnp.full_like(v, -jnp.inf) for f, v in theta0.items()}
    for f, values in (floor or {}).items():
        if f not in NOISE_FIELDS:
            raise ValueError(f"floor: {f!r} is not a noise field ({NOISE_FIELDS})")
        ref = np.asarray(getattr(base.noise, f), np.float64)
        s = np.asarray(values, np.float64)
        if s.shape != ref.shape:
            raise ValueError(f"floor[{f!r}] has shape {s.shape}, base.noise.{f} {ref.shape}")
        if not np.all(np.isfinite(s)) or np.any(s < 0):
            raise ValueError(f"floor[{f!r}] must be finite and >= 0")
        below = np.flatnonzero(ref < s * (1.0 - 1e-6))
        if below.size:
            i = int(below[0])
            raise ValueError(
                f"base.noise.{f}[{i}] = {ref[i]:.4g} lies below its floor {s[i]:.4g}: tuning"
                " starts from base, so start from parameters at or above the floor"
            )
        if f not in space.fields:
            continue
        idx, names = space.groups_of(f)
        with np.errstate(divide="ignore"):
            ratio = np.log(s / ref)
        bound = np.full(len(names), -np.inf)
        np.maximum.at(bound, np.asarray(idx), ratio)
        # Never above the start (rounding of a std that sits exactly at its floor).
        lower[f] = jnp.asarray(np.minimum(bound, 0.0), jnp.float32)
    return lower


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Settings of one tuning run (frozen: override with ``dataclasses.replace``).

    Attributes:
      learning_rate: Adam's step size, in units of theta (log or logit) per update.
      clip_norm: the gradient's global norm is clipped to this before Adam.
      max_epochs: passes over the tuning logs at most.
      patience: epochs without a validation improvement before stopping.
      min_delta: the improvement of validation BCE that counts, nats per foot-step.
      chunk: steps per truncated-BPTT window (one optimizer update each).
      prior_noise: ``lambda_sigma``, weight of the prior on the noise log multipliers.
      prior_other: ``lambda_other``, weight of the prior on caps, ``T_s``, ``a_F``.
      seed: the run's key, ``jax.random.key(seed)``.
      air_penalty: ``mu``, weight of the per-step false-contact hinge (0: off, the
        default; a diagnostic of the previous session, superseded by ``event_weight``).
      air_margin: ``m``, the logit below which a true air step costs nothing in the hinge.
      event_weight: ``w_e``, weight of the air-phase event term (0: plain BCE).
      event_temperature: ``tau``, the log-sum-exp's temperature (logit units); smaller is
        closer to the hard maximum.
      event_early_s: the early window of ``jax_contact.metrics`` (rule 2), s: a flagged
        run that starts this close before a true touch-down and lasts into it is the
        touch-down's detection, not a false contact, and is not scored.
      select: which validation number picks the epoch returned: ``"loss"`` (BCE plus the
        event term, the default), ``"bce"``, or ``"cells"`` (the lowest loss among the
        epochs no worse than epoch 0 in any validation cell, :func:`no_worse`).
      cell_tolerance: with ``select="cells"``, how much worse than epoch 0 a validation
        cell may be, in units of :data:`CELL_TOLERANCE` (0: not at all).
      constraint_weight: ``lambda_c``, weight of the cells in the objective (0: off): the
        penalty :func:`constraint_penalty` of each window's :func:`cell_surrogates` against
        the untuned parameters' on the same window.
      feasible: reject an epoch whose *tuning* logs' cells (:func:`score_logs`, the hard
        metrics) are worse than epoch 0's beyond ``cell_tolerance``: the parameters and the
        optimiser go back to the last accepted epoch and the learning rate is halved (a
        rejected epoch counts against ``patience``). Costs one filter pass over the tuning
        logs per epoch.
    """

    learning_rate: float = 0.05
    clip_norm: float = 1.0
    max_epochs: int = 12
    patience: int = 3
    min_delta: float = 1e-4
    chunk: int = 400
    prior_noise: float = 1e-3
    prior_other: float = 1e-3
    seed: int = 0
    air_penalty: float = 0.0
    air_margin: float = 2.0
    event_weight: float = 0.3
    event_temperature: float = 0.25
    event_early_s: float = 0.05
    select: str = "loss"
    cell_tolerance: float = 0.0
    constraint_weight: float = 0.0
    feasible: bool = False

    def __post_init__(self):
        for name in ("learning_rate", "clip_norm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"TuneConfig.{name} must be a finite number > 0, got {v!r}")
        for name in (
            "prior_noise", "prior_other", "min_delta", "air_penalty", "air_margin",
            "event_weight", "event_early_s", "cell_tolerance", "constraint_weight",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"TuneConfig.{name} must be a finite number >= 0, got {v!r}")
        if not (np.isfinite(self.event_temperature) and self.event_temperature > 0):
            raise ValueError(
                f"TuneConfig.event_temperature must be a finite number > 0,"
                f" got {self.event_temperature!r}"
            )
        if self.select not in SELECT_RULES:
            raise ValueError(
                f"TuneConfig.select must be one of {SELECT_RULES}, got {self.select!r}"
            )
        for name, low in (("max_epochs", 0), ("patience", 1), ("chunk", 1)):
            v = getattr(self, name)
            if not isinstance(v, int) or v < low:
                raise ValueError(f"TuneConfig.{name} must be an int >= {low}, got {v!r}")


def prior_penalty(space: ParamSpace, theta: dict, theta0: dict, config: TuneConfig) -> jax.Array:
    """() the regulariser of the module docstring."""
    total = jnp.float32(0.0)
    for f in space.fields:
        d = theta[f] - theta0[f]
        w = config.prior_noise if f in NOISE_FIELDS else config.prior_other
        total = total + 0.5 * w * jnp.sum(d * d)
    return total


# ---------------------------------------------------------------------------- the data


@struct.dataclass
class AirPhases:
    """Where the true air phases and touch-downs of a log are (from truth and mask alone).

    Attributes:
      start: (T, E, L) bool, the first step of each true air phase (a valid air step whose
        previous step is not a valid air step: ``jax_contact.metrics`` rule 8).
      td_step: (T, E, L) bool, each true touch-down (a valid contact step after a valid
        air step; rule 2's ``t0``).
      td_window: (T, E, L) bool, the air steps at most ``early`` steps before the
        touch-down that ends their phase (rule 2's early window).
      lo_step: (T, E, L) bool, each true lift-off (a valid air step after a valid contact
        step).
      after_td: (T, E, L) bool, the first ``early`` valid contact steps of each stance
        that begins with a touch-down (:func:`cell_surrogates`' touch-down lateness).
      after_lo: (T, E, L) bool, the first ``early`` valid air steps of each air phase that
        begins with a lift-off.
    """

    start: jax.Array
    td_step: jax.Array
    td_window: jax.Array
    lo_step: jax.Array | None = None
    after_td: jax.Array | None = None
    after_lo: jax.Array | None = None


@struct.dataclass
class TuningData:
    """One log's precomputed estimator inputs and ground truth (NumPy or JAX leaves).

    Attributes:
      meas: a :class:`RobotMeasurement` with leaves of leading axes (T, E) (or a
        :class:`LegMeasurement` with (T, E, L)): the inputs of each step, paired as the
        estimator would see them.
      truth: (T, E, L) bool ground-truth contact at each step.
      mask: (T, E, L) bool, the steps that count (env valid).
      events: the log's :class:`AirPhases` (:func:`with_air_phases`), needed by the event
        term; None until annotated.
    """

    meas: RobotMeasurement | LegMeasurement
    truth: jax.Array
    mask: jax.Array
    events: AirPhases | None = None

    @property
    def n_steps(self) -> int:
        return int(self.truth.shape[0])


def air_phases(truth, mask, early: int) -> AirPhases:
    """The :class:`AirPhases` of a (T, ...) truth and mask (NumPy, whole log at once).

    Args:
      truth, mask: (T, ...) bool.
      early: the early window in steps (``round(early_window_s / dt)``).
    """
    truth = np.asarray(truth, bool)
    air = np.asarray(mask, bool) & ~truth
    prev_air = np.concatenate([np.zeros_like(air[:1]), air[:-1]], axis=0)
    start = air & ~prev_air
    td_step = np.asarray(mask, bool) & truth & prev_air
    # Steps from each air step to the touch-down that ends its phase (a large number where
    # the phase ends otherwise: an invalid step or the end of the log).
    far = np.iinfo(np.int32).max // 2
    dist = np.full(air.shape, far, np.int64)
    cur = np.full(air.shape[1:], far, np.int64)
    for t in range(air.shape[0] - 1, -1, -1):
        cur = np.where(td_step[t], 0, np.where(air[t], cur + 1, far))
        dist[t] = cur
    contact = np.asarray(mask, bool) & truth
    prev_contact = np.concatenate([np.zeros_like(contact[:1]), contact[:-1]], axis=0)
    lo_step = air & prev_contact

    def first_steps(inside, begins):
        # Steps since the event that began each run of ``inside`` (far where none did).
        since = np.full(inside.shape, far, np.int64)
        cur = np.full(inside.shape[1:], far, np.int64)
        for t in range(inside.shape[0]):
            cur = np.where(begins[t], 0, np.where(inside[t], cur + 1, far))
            since[t] = cur
        return inside & (since < early)

    return AirPhases(
        start=start,
        td_step=td_step,
        td_window=air & (dist <= early),
        lo_step=lo_step,
        after_td=first_steps(contact, td_step),
        after_lo=first_steps(air, lo_step),
    )


def with_air_phases(data: TuningData, early: int) -> TuningData:
    """``data`` with its :class:`AirPhases` (``early`` steps of early window)."""
    return data.replace(events=air_phases(data.truth, data.mask, early))


def scored_air_steps(logits: jax.Array, window: TuningData) -> jax.Array:
    """(T, E, L) bool: the true air steps where a rise of the logit could be a failure.

    The steps of a true air phase between the end of the lift-off's fall and the start of
    the touch-down's rise (computed from the logits without gradient; a window's first
    step starts its phases afresh):

    - from the first step, after the flag ``logit > 0`` has been off in the phase, at which
      the logit does not fall (``l_t >= l_{t-1}``): the stance's flag carried into the air
      and the fall after it are the lift-off delay, not a false contact
      (``jax_contact.metrics`` rule 7 needs a rise of the flag in the air);
    - minus the run into the touch-down: going back from the true touch-down ``t0`` over
      the early window (``AirPhases.td_window``), a flagged step followed by a flagged
      step, or an unflagged one below the next logit (the rise toward the detection);
      the detection itself (rule 4) and the approach to it are not false contacts. A
      blip (on, then off) before the detection breaks the run and is scored.
    """
    lg = jax.lax.stop_gradient(logits)
    on = lg > 0
    air = jnp.asarray(window.mask) & ~jnp.asarray(window.truth).astype(bool)
    ev = jax.tree.map(jnp.asarray, window.events)
    prev = jnp.concatenate([lg[:1], lg[:-1]], axis=0)
    nxt = jnp.concatenate([lg[1:], lg[-1:]], axis=0)
    on_next = jnp.concatenate([on[1:], on[-1:]], axis=0)

    def fwd(carry, x):
        dropped, settled = carry
        a, st, o, rising = x
        dropped = a & ((~st & dropped) | ~o)
        settled = dropped & ((~st & settled) | rising)
        return (dropped, settled), settled

    zeros = jnp.zeros(on.shape[1:], bool)
    _, settled = jax.lax.scan(fwd, (zeros, zeros), (air, ev.start, on, lg >= prev))

    def bwd(run, x):
        td, win, into = x
        run = td | (win & run & into)
        return run, run

    into = jnp.where(on, on_next, lg <= nxt)
    # The window's last step: a run there is taken to go on into the next window.
    _, run = jax.lax.scan(
        bwd, jnp.ones(on.shape[1:], bool), (ev.td_step, ev.td_window, into), reverse=True
    )
    return air & settled & ~run


def air_event_terms(logits: jax.Array, window: TuningData, temperature: float):
    """The event term's sum over the window's air phases and their number.

    For each true air phase ``a`` (:class:`AirPhases`; a phase cut by the window's start
    counts from there) with scored steps ``S_a`` (:func:`scored_air_steps`)::

        E_a = tau log sum_{t in S_a} exp(l_t / tau)      (smooth maximum of the logit)
        cost_a = softplus(E_a) = -log(1 - sigmoid(E_a))

    ``sigmoid(E_a)`` stands for the probability of at least one false contact in the phase
    (``E_a`` lies between the largest logit and ``tau log |S_a|`` above it), so ``cost_a``
    is the binary cross-entropy of the event "no false contact in this phase" (true for
    every true air phase). Phases without a scored step cost 0.

    Returns:
      (sum of ``cost_a`` (), number of air phases in the window ()).
    """
    e, has, n_phases = air_phase_maxima(logits, window, temperature)
    return jnp.sum(jnp.where(has, jax.nn.softplus(e), 0.0)), n_phases


def air_phase_maxima(logits: jax.Array, window: TuningData, temperature: float):
    """The smooth maximum ``E_a`` of the logit over each air phase's scored steps.

    Returns:
      (``E`` (S,) per segment, ``has`` (S,) bool: the segment is a phase with a scored
      step (``E`` is 0 elsewhere), the number of air phases in the window ()); segments
      are (column, phase) pairs, so ``S`` is fixed by the window's shape.
    """
    n_t = logits.shape[0]
    cols = int(np.prod(logits.shape[1:]))
    scored = scored_air_steps(logits, window)
    air = jnp.asarray(window.mask) & ~jnp.asarray(window.truth).astype(bool)
    # A phase cut by the window's start begins at its first step.
    first = (jnp.asarray(window.events.start) & air).at[0].set(air[0])
    pid = jnp.cumsum(first, axis=0)  # phase number along each column, >= 1 inside phases
    col = jnp.arange(cols).reshape(logits.shape[1:])
    n_seg = cols * (n_t + 1) + 1
    seg = jnp.where(scored, col * (n_t + 1) + pid, n_seg - 1).reshape(-1)
    x = (logits / temperature).reshape(-1)
    sc = scored.reshape(-1)
    mx = jax.ops.segment_max(jnp.where(sc, jax.lax.stop_gradient(x), -jnp.inf), seg, n_seg)
    has = jax.ops.segment_sum(sc.astype(jnp.int32), seg, n_seg) > 0
    mx = jnp.where(has, mx, 0.0)
    z = jnp.where(sc, x - mx[seg], -60.0)
    total = jax.ops.segment_sum(jnp.where(sc, jnp.exp(z), 0.0), seg, n_seg)
    e = temperature * (mx + jnp.log(jnp.where(has, total, 1.0)))
    return jnp.where(has, e, 0.0), has, jnp.sum(first)


# The cells in the objective (``constraint_weight > 0``): one smooth stand-in per kind of
# validation cell, and how far each may move before it counts as worse.
CONSTRAINT_CELLS = ("errors", "events", "touchdown", "liftoff")


def constraint_units(dt: float) -> np.ndarray:
    """(4,) the tolerance of each of :data:`CONSTRAINT_CELLS`, in its surrogate's units:
    :data:`CELL_TOLERANCE`'s accuracy (errors per step), air-phase failure rate (failed
    phases per phase) and delays (ms -> steps of ``dt``)."""
    tol = CELL_TOLERANCE
    steps = 1e-3 / dt
    return np.array(
        [tol["accuracy"], tol["fail"], tol["touchdown_ms"] * steps, tol["liftoff_ms"] * steps]
    )


# The surrogates' logistic smoothing of the flag ``l > 0``, logit units: a step at ``l =
# -2`` counts 0.02 of a flag, at ``l = -1`` 0.12 (docs/tuning.md: with the probability
# itself, p = sigmoid(l), steps and phases far from the threshold dominate the sums).
CELL_SHARPNESS = 0.5


def cell_surrogates(
    logits: jax.Array,
    window: TuningData,
    temperature: float,
    sharpness: float = CELL_SHARPNESS,
) -> jax.Array:
    """(4,) smooth stand-ins for the validation cells (:data:`CONSTRAINT_CELLS`) of a window.

    Each is the metric's count with the flag ``l > 0`` replaced by ``f = sigmoid(l / k)``
    (``k = sharpness``; ``k`` = 1 would be P itself), over the window's :class:`AirPhases`:

    - ``errors``: the fraction of wrong flags, ``sum m (y (1 - f) + (1 - y) f) / sum m``
      (accuracy's and F1's stand-in);
    - ``events``: the air-phase failure rate, ``sum_a sigmoid(E_a / k) / #air phases``
      with ``E_a`` the smooth maximum of the logit over the phase's scored steps
      (:func:`air_phase_maxima`, the event term's);
    - ``touchdown``: ``sum_{after_td} (1 - f) / #touch-downs``, the steps a touch-down is
      missed in the first ``early`` steps of its stance (for a flag that switches on ``d``
      steps after ``t0`` it is ``d``: the delay in steps);
    - ``liftoff``: ``sum_{after_lo} f / #lift-offs``, the same for lift-offs.

    Every count is floored at 1, so a window without an event gives 0.
    """
    ev = jax.tree.map(jnp.asarray, window.events)
    if ev.after_td is None:
        raise ValueError("the cells' surrogates need AirPhases from air_phases()")
    f = jax.nn.sigmoid(logits / sharpness)
    mask = jnp.asarray(window.mask)
    y = jnp.asarray(window.truth).astype(f.dtype)

    def mean(total, count):
        return total / jnp.maximum(jnp.sum(count), 1).astype(f.dtype)

    wrong = jnp.where(mask, y * (1.0 - f) + (1.0 - y) * f, 0.0)
    e, has, n_phases = air_phase_maxima(logits, window, temperature)
    failed = jnp.sum(jnp.where(has, jax.nn.sigmoid(e / sharpness), 0.0))
    return jnp.stack(
        [
            mean(jnp.sum(wrong), mask),
            mean(failed, n_phases),
            mean(jnp.sum(jnp.where(ev.after_td, 1.0 - f, 0.0)), ev.td_step),
            mean(jnp.sum(jnp.where(ev.after_lo, f, 0.0)), ev.lo_step),
        ]
    )


def constraint_penalty(cells: jax.Array, reference: jax.Array, units: jax.Array) -> jax.Array:
    """() ``sum_c softplus((s_c - r_c) / u_c)``: the cells' surrogates ``s`` against the
    untuned parameters' ``r`` on the same window, in tolerance units ``u``
    (:func:`constraint_units`). ~0 where a cell is better by a few tolerances, ~the excess
    in tolerances where it is worse."""
    return jnp.sum(jax.nn.softplus((cells - reference) / units))


def _window(data: TuningData, start: int, length: int) -> TuningData:
    """Steps [start, start + length) as device arrays, padded with masked copies of the
    last step so every window has one shape (one compilation)."""
    stop = min(start + length, data.n_steps)
    pad = length - (stop - start)

    def take(x):
        x = np.asarray(x[start:stop])
        if pad:
            x = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)], axis=0)
        return jnp.asarray(x)

    out = jax.tree.map(take, data)
    if pad:
        keep = jnp.asarray(np.arange(length) < stop - start)[:, None, None]
        out = out.replace(mask=out.mask & keep)
        if out.events is not None:  # the padding holds no phase start and no event
            out = out.replace(events=jax.tree.map(lambda x: x & keep, out.events))
    return out


def _bce(logit: jax.Array, y: jax.Array) -> jax.Array:
    y = y.astype(logit.dtype)
    return -(y * jax.nn.log_sigmoid(logit) + (1.0 - y) * jax.nn.log_sigmoid(-logit))


def filter_logits(
    params: EstimatorParams, terrain, belief, meas, *, key: jax.Array, remat: bool = False
):
    """Runs the filter over a window; returns (final belief, (T, E, L) logits).

    ``belief`` has leaves of leading axes (E, L); ``meas`` leading axes (T, E[, L]).
    With ``remat`` each step is recomputed in the backward pass (memory: beliefs only).
    """

    def body(carry, m):
        b, k = carry
        k, sub = jax.random.split(k)
        b, _ = step_batch(params, terrain, b, m, key=sub)
        return (b, k), b.logit

    if remat:
        body = jax.checkpoint(body)
    (belief, _), logits = jax.lax.scan(body, (belief, key), meas)
    return belief, logits


def air_hinge(logit: jax.Array, margin: float) -> jax.Array:
    """Smooth hinge ``softplus(2 (l + margin)) / 2``: ~0 below ``-margin``, ~``l + margin``
    above (the false-contact term of the module docstring)."""
    return jax.nn.softplus(2.0 * (logit + margin)) / 2.0


def window_bce(
    params: EstimatorParams,
    terrain,
    belief,
    window: TuningData,
    *,
    key: jax.Array,
    air_margin: float = 2.0,
    event_temperature: float | None = None,
) -> tuple[jax.Array, tuple]:
    """Masked BCE of one window: (sum of BCE, (final belief, number of counted steps, sum
    of the air hinge over the true air steps, sum of the event term over the window's air
    phases, number of air phases, the (T, E, L) logits)); the event sums are 0 unless
    ``event_temperature``."""
    belief, logits = filter_logits(params, terrain, belief, window.meas, key=key, remat=True)
    nll = jnp.where(window.mask, _bce(logits, window.truth), 0.0)
    air = window.mask & ~window.truth.astype(bool)
    hinge = jnp.where(air, air_hinge(logits, air_margin), 0.0)
    if event_temperature is None:
        event, n_phases = jnp.zeros((), logits.dtype), jnp.zeros((), jnp.int32)
    else:
        if window.events is None:
            raise ValueError("the event term needs the window's AirPhases (with_air_phases)")
        event, n_phases = air_event_terms(logits, window, event_temperature)
    return jnp.sum(nll), (belief, jnp.sum(window.mask), jnp.sum(hinge), event, n_phases, logits)


def tuning_loss(
    theta: dict,
    space: ParamSpace,
    base: EstimatorParams,
    theta0: dict,
    terrain,
    belief,
    window: TuningData,
    config: TuneConfig,
    *,
    key: jax.Array,
    cells_reference: tuple[jax.Array, jax.Array] | None = None,
):
    """The loss of the module docstring on one window.

    ``cells_reference``: with ``config.constraint_weight > 0``, the untuned parameters'
    :func:`cell_surrogates` on this window and :func:`constraint_units`, both (4,).

    Returns:
      (loss (), (final belief, mean BCE of the window (), counted steps ())).
    """
    params = to_params(space, base, theta)
    events = config.event_weight > 0 or config.constraint_weight > 0
    total, (belief, n, hinge, event, n_phases, logits) = window_bce(
        params, terrain, belief, window, key=key, air_margin=config.air_margin,
        event_temperature=config.event_temperature if events else None,
    )  # fmt: skip
    scale = 1.0 / jnp.maximum(n, 1).astype(total.dtype)
    data = total * scale
    loss = data + prior_penalty(space, theta, theta0, config)
    if config.air_penalty > 0:
        loss = loss + config.air_penalty * hinge * scale
    if config.event_weight > 0:
        loss = loss + config.event_weight * event / jnp.maximum(n_phases, 1).astype(total.dtype)
    if config.constraint_weight > 0:
        if cells_reference is None:
            raise ValueError("constraint_weight > 0 needs the window's cells_reference")
        reference, units = cells_reference
        cells = cell_surrogates(logits, window, config.event_temperature)
        penalty = constraint_penalty(
            cells, jnp.asarray(reference, cells.dtype), jnp.asarray(units, cells.dtype)
        )
        loss = loss + config.constraint_weight * penalty
    return loss, (belief, data, n)


def _optimizer(config: TuneConfig) -> optax.GradientTransformation:
    if config.feasible:  # the learning rate in the state, so that a rejection can halve it
        adam = optax.inject_hyperparams(optax.adam)(learning_rate=config.learning_rate)
    else:
        adam = optax.adam(config.learning_rate)
    return optax.chain(optax.clip_by_global_norm(config.clip_norm), adam)


def _halve_learning_rate(opt_state):
    """The state of :func:`_optimizer` (``feasible``) with half the learning rate."""
    clip, adam = opt_state
    lr = adam.hyperparams["learning_rate"]
    return (clip, adam._replace(hyperparams={**adam.hyperparams, "learning_rate": lr * 0.5}))


@functools.partial(jax.jit, static_argnames=("space", "config"))
def _train_window(
    theta, opt_state, space, base, theta0, lower, terrain, belief, window, config, key,
    cells_reference=None,
):  # fmt: skip
    grad_fn = jax.value_and_grad(tuning_loss, has_aux=True)
    (loss, (belief, data, n)), grads = grad_fn(
        theta, space, base, theta0, terrain, belief, window, config, key=key,
        cells_reference=cells_reference,
    )  # fmt: skip
    updates, opt_state = _optimizer(config).update(grads, opt_state, theta)
    # Projected gradient step: back onto the floors (theta_lower_bounds) after the update.
    theta = jax.tree.map(jnp.maximum, optax.apply_updates(theta, updates), lower)
    return theta, opt_state, belief, loss, data, n, optax.global_norm(grads)


@jax.jit
def _forward_window(params, terrain, belief, meas, key):
    return filter_logits(params, terrain, belief, meas, key=key)


def predict_logits(
    params: EstimatorParams,
    terrain,
    data: TuningData,
    *,
    key: jax.Array,
    chunk: int = 400,
) -> np.ndarray:
    """(T, E, L) float32 filtered logits of a whole log, in windows of ``chunk`` steps."""
    out = _over_windows(
        params, data, chunk, key, lambda b, win, k: _forward_window(params, terrain, b, win.meas, k)
    )
    return np.concatenate(out, axis=0)[: data.n_steps]


def _over_windows(params, data: TuningData, chunk: int, key, run) -> list[np.ndarray]:
    """``run(belief, window, key) -> (belief, out)`` over a log's windows of ``chunk``
    steps (:func:`_window`), the belief carried from one to the next as in :func:`tune`'s
    epochs; the ``out`` of each window."""
    n_envs, n_legs = data.truth.shape[1:]
    belief = init_belief_batch(params, n_envs, n_legs)
    out = []
    for w, start in enumerate(range(0, data.n_steps, chunk)):
        belief, o = run(belief, _window(data, start, chunk), jax.random.fold_in(key, w))
        out.append(np.asarray(o))
    return out


@functools.partial(jax.jit, static_argnames=("temperature",))
def _window_cells(params, terrain, belief, window, key, temperature):
    belief, logits = filter_logits(params, terrain, belief, window.meas, key=key)
    return belief, cell_surrogates(logits, window, temperature)


def reference_cells(
    params: EstimatorParams,
    terrain,
    data: TuningData,
    *,
    key: jax.Array,
    chunk: int = 400,
    temperature: float = 0.25,
) -> np.ndarray:
    """(n_windows, 4) :func:`cell_surrogates` of ``params`` on each training window of a
    log (the windows and belief carry of :func:`tune`'s epochs)."""
    return np.stack(
        _over_windows(
            params, data, chunk, key,
            lambda b, win, k: _window_cells(params, terrain, b, win, k, temperature),
        )
    )  # fmt: skip


def pooled(datas: Sequence[TuningData]) -> TuningData:
    """Truth and mask of several logs flattened into one (for pooled scores)."""
    return TuningData(
        meas=None,
        truth=np.concatenate([np.asarray(d.truth).reshape(-1) for d in datas]),
        mask=np.concatenate([np.asarray(d.mask).reshape(-1) for d in datas]),
    )


def sigmoid_np(logit) -> np.ndarray:
    """P = sigmoid(logit) in float64 NumPy (no overflow)."""
    x = np.asarray(logit, np.float64)
    return np.exp(-np.logaddexp(0.0, -x))


def score_logits(logits, data: TuningData) -> dict[str, float]:
    """Mean BCE, F1 (flag P > 0.5) and ECE (10 bins) of logits over the masked steps."""
    from jax_contact.metrics import expected_calibration_error, step_scores

    mask = np.asarray(data.mask, bool)
    truth = np.asarray(data.truth, bool)
    x = np.asarray(logits, np.float64)
    bce = np.logaddexp(0.0, -x) * truth + np.logaddexp(0.0, x) * ~truth
    p = sigmoid_np(x)
    return {
        "bce": float(bce[mask].mean()) if mask.any() else float("nan"),
        "f1": step_scores(p, truth, mask).f1,
        "ece": expected_calibration_error(p, truth, mask),
    }


@functools.partial(jax.jit, static_argnames=("temperature",))
def _event_sum(logits, window, temperature):
    return air_event_terms(logits, window, temperature)


def score_logs(
    logits: Sequence, datas: Sequence[TuningData], *, dt: float, config: TuneConfig
) -> dict:
    """Pooled validation scores of whole logs (each (T, E, L) logits with its data).

    ``bce`` (mean over masked foot-steps), ``event`` (the event term's mean over air
    phases; NaN without :class:`AirPhases`), ``loss`` (``bce + event_weight * event``,
    no prior), ``f1``, ``ece`` and ``fail`` (``jax_contact.metrics``' air-phase failure
    rate: air phases with a false contact / air phases, events per log), and ``cells``:
    per log, the numbers :func:`no_worse` compares (:data:`CELL_KEYS`).
    """
    from jax_contact.metrics import evaluate

    out = score_logits(np.concatenate([np.asarray(x).reshape(-1) for x in logits]), pooled(datas))
    ev_sum = n_ph = failed = n_air = 0.0
    cells = []
    for x, d in zip(logits, datas, strict=True):
        if d.events is not None:
            e, n = _event_sum(jnp.asarray(x), d.replace(meas=None), config.event_temperature)
            ev_sum, n_ph = ev_sum + float(e), n_ph + float(n)
        m = evaluate(sigmoid_np(x), np.asarray(d.truth, bool), np.asarray(d.mask, bool), dt=dt)
        failed, n_air = failed + m.air_phases_with_failure, n_air + m.n_air_phases
        cells.append(
            dict(
                f1=float(m.f1),
                accuracy=float(m.accuracy),
                ece=float(m.ece),
                fail=float(m.air_phase_failure_rate),
                touchdown_ms=abs(float(m.touchdown_delay_ms[0])),
                liftoff_ms=abs(float(m.liftoff_delay_ms[0])),
            )
        )
    out["event"] = ev_sum / n_ph if n_ph else float("nan")
    out["loss"] = out["bce"] + (config.event_weight * out["event"] if n_ph else 0.0)
    out["fail"] = failed / n_air if n_air else float("nan")
    out["cells"] = cells
    return out


SELECT_RULES = ("loss", "bce", "cells")
# What "no worse" allows with ``TuneConfig.cell_tolerance = 1`` (docs/tuning.md, rule 6: the
# measurement's resolution at 16 envs x 8 s): F1 and accuracy 0.0005 lower, ECE 0.0005
# higher, 0.25 point more air phases with a false contact, 0.25 ms more |mean delay|.
CELL_TOLERANCE = dict(
    f1=0.0005, accuracy=0.0005, ece=0.0005, fail=0.0025, touchdown_ms=0.25, liftoff_ms=0.25
)
# The validation cells of select="cells": per log, (key, +1 higher is better / -1 lower is).
CELL_KEYS = (
    ("f1", 1),
    ("accuracy", 1),
    ("ece", -1),
    ("fail", -1),
    ("touchdown_ms", -1),
    ("liftoff_ms", -1),
)


def no_worse(cells: Sequence[dict], reference: Sequence[dict], tolerance: float = 0.0) -> bool:
    """Whether every validation cell of ``cells`` is at least as good as ``reference``'s.

    Both are :func:`score_logs`' ``cells`` (one dict per validation log). A cell is a log
    and one of :data:`CELL_KEYS`; ties count as no worse, and a number that is NaN in
    both (e.g. no air phase, no event to time) is not compared; NaN in one only is worse.
    With ``tolerance`` > 0 a cell may be worse by ``tolerance`` x its
    :data:`CELL_TOLERANCE`.
    """
    if len(cells) != len(reference):
        raise ValueError(f"{len(cells)} validation logs' cells against {len(reference)}")
    for got, ref in zip(cells, reference, strict=True):
        for key, sign in CELL_KEYS:
            a, b = float(got[key]), float(ref[key])
            if np.isnan(a) and np.isnan(b):
                continue
            if np.isnan(a) or np.isnan(b) or sign * (a - b) < -tolerance * CELL_TOLERANCE[key]:
                return False
    return True


# ------------------------------------------------------------------------------ tuning


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` returns.

    Attributes:
      params: the parameters of the best validation epoch (validated).
      theta: their unconstrained values.
      history: one dict per epoch (epoch 0: before any update): ``epoch``, ``train_loss``
        (mean over the epoch's windows of the loss, NaN for epoch 0), ``train_bce``,
        ``val_bce``, ``val_event``, ``val_loss``, ``val_f1``, ``val_ece``, ``val_fail``
        (:func:`score_logs`), ``grad_norm``, ``wall_s``; with ``config.feasible`` also
        ``train_cells`` (the tuning logs' cells) and ``rejected``.
      best_epoch: the epoch whose parameters are returned (lowest ``val_loss``, or
        ``val_bce`` with ``config.select == "bce"``, or the lowest ``val_loss`` among the
        epochs :func:`no_worse` than epoch 0 with ``"cells"``).
      stopped_early: whether patience ran out before ``max_epochs``.
      wall_s: total wall time, s (compilation included).
    """

    params: EstimatorParams
    theta: dict
    history: tuple[dict, ...]
    best_epoch: int
    stopped_early: bool
    wall_s: float


def tune(
    base: EstimatorParams,
    terrain,
    train: Sequence[TuningData],
    validation: TuningData | Sequence[TuningData],
    space: ParamSpace,
    config: TuneConfig = TuneConfig(),
    *,
    floor: dict | None = None,
    progress: Callable[[dict], None] | None = None,
) -> TuneResult:
    """Fits the fields of ``space`` to the tuning logs (module docstring).

    Args:
      base: the untuned parameters; their noise is the prior's centre.
      terrain: the estimator's terrain model (e.g. ``jax_contact.flat(0.0, 0.05)``).
      train: the tuning logs, each a :class:`TuningData` (NumPy leaves are fine: windows
        are moved to the device one at a time).
      validation: the log(s) that decide early stopping (other seeds); with several, the
        BCE, F1 and ECE are pooled over all their steps.
      space: what is tuned.
      config: optimiser, windows, prior, seed.
      floor: the smallest std of each floored noise field (``{field: array}``, e.g.
        :func:`jax_contact.defaults.sensor_noise_floor`): every update is projected back
        onto it (:func:`theta_lower_bounds`); None: no floor.
      progress: called with each epoch's history dict as it completes.

    Returns:
      :class:`TuneResult`.

    Raises:
      ValueError: no tuning log, or parameters that fail validation.
    """
    if not train:
        raise ValueError("tune needs at least one tuning log")
    t_start = time.perf_counter()
    key = jax.random.key(config.seed)
    theta = init_theta(space, base)
    theta0 = theta
    lower = theta_lower_bounds(space, base, floor)
    opt_state = _optimizer(config).init(theta)
    val_key = jax.random.fold_in(key, 10**6)

    vals = [validation] if isinstance(validation, TuningData) else list(validation)
    if not vals:
        raise ValueError("tune needs a validation log")

    dt = float(base.dt)
    early = int(round(config.event_early_s / dt))
    train = [d if d.events is not None else with_air_phases(d, early) for d in train]
    vals = [v if v.events is not None else with_air_phases(v, early) for v in vals]

    def validate(th) -> dict:
        params = to_params(space, base, th)
        logits = [
            predict_logits(params, terrain, v, key=jax.random.fold_in(val_key, i),
                           chunk=config.chunk)
            for i, v in enumerate(vals)
        ]  # fmt: skip
        return score_logs(logits, vals, dt=dt, config=config)

    history = []
    first = dict(epoch=0, train_loss=float("nan"), train_bce=float("nan"), grad_norm=float("nan"))
    first.update({f"val_{k}": v for k, v in validate(theta).items()})
    first["wall_s"] = time.perf_counter() - t_start
    history.append(first)
    if progress:
        progress(first)
    crit = "val_bce" if config.select == "bce" else "val_loss"
    best, best_theta, best_epoch, bad = first[crit], theta, 0, 0

    # The compiled training step depends on the loss and optimiser only: one program
    # whatever the epochs, patience or selection rule.
    step_config = dataclasses.replace(
        config, select="loss", max_epochs=0, patience=1, min_delta=0.0, cell_tolerance=0.0
    )

    def admissible(row) -> bool:
        return config.select != "cells" or no_worse(
            row["val_cells"], first["val_cells"], config.cell_tolerance
        )

    def tuning_cells(th) -> list[dict]:
        params = to_params(space, base, th)
        logits = [
            predict_logits(params, terrain, d, key=jax.random.fold_in(key, 3 * 10**6 + i),
                           chunk=config.chunk)
            for i, d in enumerate(train)
        ]  # fmt: skip
        return score_logs(logits, train, dt=dt, config=config)["cells"]

    # The feasible-direction variant: the tuning logs' own cells at the defaults, and the
    # last accepted point.
    train_cells0 = None
    if config.feasible:
        train_cells0 = first["train_cells"] = tuning_cells(theta)
    accepted = (theta, opt_state)

    # The cells in the objective: the untuned parameters' surrogates on every training
    # window (the same windows and belief carry as the epochs below).
    references = [None] * len(train)
    if config.constraint_weight > 0:
        units = jnp.asarray(constraint_units(dt), jnp.float32)
        params0 = to_params(space, base, theta0)
        references = [
            reference_cells(params0, terrain, d, key=jax.random.fold_in(key, 2 * 10**6 + i),
                            chunk=config.chunk, temperature=config.event_temperature)
            for i, d in enumerate(train)
        ]  # fmt: skip

    stopped = False
    for epoch in range(1, config.max_epochs + 1):
        losses, bces, norms, counts = [], [], [], []
        for i, data in enumerate(train):
            n_envs, n_legs = data.truth.shape[1:]
            belief = init_belief_batch(to_params(space, base, theta), n_envs, n_legs)
            for w, start in enumerate(range(0, data.n_steps, config.chunk)):
                win = _window(data, start, config.chunk)
                k = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(key, epoch), i), w)
                ref = None
                if references[i] is not None:
                    ref = (jnp.asarray(references[i][w], jnp.float32), units)
                theta, opt_state, belief, loss, bce, n, gn = _train_window(
                    theta, opt_state, space, base, theta0, lower, terrain, belief, win,
                    step_config, k, ref,
                )  # fmt: skip
                losses.append(float(loss))
                bces.append(float(bce))
                counts.append(float(n))
                norms.append(float(gn))
        w = np.asarray(counts) / max(sum(counts), 1.0)
        row = dict(
            epoch=epoch,
            train_loss=float(np.mean(losses)),
            train_bce=float(np.dot(w, bces)),
            grad_norm=float(np.mean(norms)),
        )
        row.update({f"val_{k}": v for k, v in validate(theta).items()})
        rejected = False
        if config.feasible:
            row["train_cells"] = tuning_cells(theta)
            rejected = not no_worse(row["train_cells"], train_cells0, config.cell_tolerance)
            row["rejected"] = rejected
            if rejected:
                theta, opt_state = accepted[0], _halve_learning_rate(accepted[1])
            accepted = (theta, opt_state)
        row["wall_s"] = time.perf_counter() - t_start
        history.append(row)
        if progress:
            progress(row)
        if not rejected and row[crit] < best - config.min_delta and admissible(row):
            best, best_theta, best_epoch, bad = row[crit], theta, epoch, 0
        else:
            bad += 1
            if bad >= config.patience:
                stopped = epoch < config.max_epochs
                break
    params = jax.tree.map(np.asarray, to_params(space, base, best_theta))
    params = jax.tree.map(jnp.asarray, params)
    validate_params(params)
    return TuneResult(
        params=params,
        theta={k: np.asarray(v) for k, v in best_theta.items()},
        history=tuple(history),
        best_epoch=best_epoch,
        stopped_early=stopped,
        wall_s=time.perf_counter() - t_start,
    )


def describe(space: ParamSpace, base: EstimatorParams, tuned: EstimatorParams) -> list[dict]:
    """One row per tuned value: ``field``, ``group``, ``default``, ``tuned``, ``ratio``.

    For the noise fields the value shown is the group's first coordinate (every coordinate
    of a group is scaled by the same factor, ``ratio``).
    """
    rows = []
    for f in space.fields:
        if f in NOISE_FIELDS:
            idx, names = space.groups_of(f)
            a, b = np.asarray(getattr(base.noise, f)), np.asarray(getattr(tuned.noise, f))
            for g, name in enumerate(names):
                i = list(idx).index(g)
                rows.append(
                    dict(
                        field=f,
                        group=name,
                        default=float(a[i]),
                        tuned=float(b[i]),
                        ratio=float(b[i] / a[i]),
                    )
                )
        else:
            a, b = float(getattr(base, f)), float(getattr(tuned, f))
            rows.append(dict(field=f, group="", default=a, tuned=b, ratio=b / a))
    return rows


# ------------------------------------------------------------------------- calibration


@dataclasses.dataclass(frozen=True)
class Calibration:
    """The map ``l' = l / temperature + bias`` on the fused logit, applied after the
    recursion (the identity: temperature 1, bias 0)."""

    temperature: float = 1.0
    bias: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.temperature) and self.temperature > 0):
            raise ValueError(f"temperature must be a finite number > 0, got {self.temperature!r}")
        if not np.isfinite(self.bias):
            raise ValueError(f"bias must be finite, got {self.bias!r}")

    def as_dict(self) -> dict:
        return {"temperature": float(self.temperature), "bias": float(self.bias)}

    @classmethod
    def from_dict(cls, d) -> Calibration:
        return cls(temperature=float(d["temperature"]), bias=float(d["bias"]))


def apply_calibration(logit, calibration: Calibration):
    """The calibrated logit ``logit / T + bias`` (JAX or NumPy arrays, any shape)."""
    return logit / calibration.temperature + calibration.bias


def calibrate_probability(p, calibration: Calibration) -> np.ndarray:
    """P(contact) mapped by ``calibration`` (float64 NumPy, any shape; NaN stays NaN).

    The logit of ``p`` (clipped to [1e-7, 1 - 1e-7], where the filter's float32 output
    saturates) is mapped by :func:`apply_calibration` and turned back into a probability.
    """
    q = np.clip(np.asarray(p, np.float64), 1e-7, 1.0 - 1e-7)
    return sigmoid_np(apply_calibration(np.log(q) - np.log1p(-q), calibration))


def calibration_of(provenance) -> Calibration | None:
    """The calibration map a parameter file's provenance holds (``jax-contact tune
    --calibrate``), or None."""
    cal = (provenance or {}).get("calibration")
    return None if cal is None else Calibration.from_dict(cal)


def fit_calibration(logits, truth, mask, *, iterations: int = 50) -> Calibration:
    """Maximum-likelihood temperature and bias (logistic regression on the logit).

    Newton's method in float64 on ``a = 1 / T`` and ``c`` with a backtracking line search
    (the BCE of ``sigmoid(a l + c)`` is convex in ``(a, c)``, but a full Newton step can
    overshoot when most logits sit at the caps' bounds), starting from the identity.

    Args:
      logits, truth, mask: (T, E, L) arrays; only masked steps count.

    Raises:
      ValueError: no masked step, only one class, or no finite positive temperature.
    """
    m = np.asarray(mask, bool)
    x = np.asarray(logits, np.float64)[m]
    y = np.asarray(truth, bool)[m].astype(np.float64)
    if x.size == 0 or y.min() == y.max():
        raise ValueError("fit_calibration needs masked steps of both classes")
    x = np.clip(x, -50.0, 50.0)

    def loss(a, c):
        z = a * x + c
        return float(np.mean(np.logaddexp(0.0, z) - y * z))

    a, c = 1.0, 0.0
    current = loss(a, c)
    for _ in range(iterations):
        p = sigmoid_np(a * x + c)
        r = p - y
        g = np.array([np.mean(r * x), np.mean(r)])
        w = p * (1.0 - p)
        h = np.array([[np.mean(w * x * x), np.mean(w * x)], [np.mean(w * x), np.mean(w)]])
        step = np.linalg.solve(h + 1e-9 * np.eye(2), g)
        t = 1.0
        while t > 1e-8:
            trial = loss(a - t * step[0], c - t * step[1])
            if trial <= current:
                break
            t *= 0.5
        else:
            break  # no descent along the Newton direction: at the minimum (to round-off)
        a, c, current = a - t * step[0], c - t * step[1], trial
        if np.max(np.abs(t * step)) < 1e-10:
            break
    if not (np.isfinite(a) and np.isfinite(c) and a > 0):
        raise ValueError(f"the fitted inverse temperature is {a}; no calibration map")
    return Calibration(temperature=float(1.0 / a), bias=float(c))
