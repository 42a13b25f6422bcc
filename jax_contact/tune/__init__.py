"""Tuning the estimator's continuous parameters by gradient on logs with ground truth.

The filter (eq. 1-3, 11-17) is differentiable end to end, so its noise model, caps and gait
constants can be fitted to a few seconds of data with ground-truth contact instead of by
hand. Everything here is arrays in, arrays out: the measurements of each log are
precomputed once (``jax_contact.train.tune_data`` runs the MJX adapter over a log's readings), and
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
knob for earlier lift-offs (a take-off hazard ``dt / T_s`` of 2.5-4 % per step), not a stance
duration. The bound is hard (the sigmoid), and the prior below acts on ``theta``.

Floors (``tune(..., floor=...)``; ``jax-contact tune`` passes the log's sensor model's,
:func:`jax_contact.defaults.sensor_noise_floor`): no tuned std may fall below what the
sensors alone give (a joint velocity believed more precisely than its sensor measures it is
over-confidence, whatever the loss gains). Each update is projected back onto the bound
``theta_g >= max_{i in g} log(s_i / sigma^0_i)`` (:func:`theta_lower_bounds`): projected
gradient descent, so the gradient itself, and the finite-difference check of it, are those
of the unbounded loss.

Plausibility box (``TuneConfig.noise_ratio = r``, ``jax-contact tune --noise-ratio R``; off
by default): every tuned std stays within ``[1/r, r]`` of its derived value,
``|theta_g| <= log r`` (:func:`theta_bounds`), projected the same way. With ``r = 8``
(:data:`PLAUSIBLE_NOISE_RATIO`) it is the standing check of the shipped presets made a
bound of the fit, so a run can no longer end on a value that check refuses (Barkour's
normal force noise at x0.016, docs/tuning.md rule 12).

Not tuned: ``dt``, the swing time (the prior out of the air: first and invalid steps),
the outlier model (from the sensors' outlier rate), the foothold threshold, the static
switches, and ``contact_damping`` unless asked for.

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
chosen on their validation seed among three (Go1 0.3, Spot 0.1, Barkour 1.0:
``jax_contact.train.tune_presets.PRESET_EVENT_WEIGHTS``).

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
loss than the defaults'). The validation swing-phase failure rate is reported too
(``jax_contact.metrics`` rule 9b: the air phases longer than a bounce with a false
contact, Table III's ``sw-ph``; before the fortieth session the air-phase rate, which the
truth's bounces dilute on the walks). With
``select="cells"`` an epoch is returned only if it is *no worse than epoch 0 in any
validation cell* (:func:`no_worse`: on each validation log separately, F1, accuracy, ECE,
the swing-phase failure rate and the magnitude of both mean event delays; ties allowed),
the lowest validation loss among those; when none is, the untuned parameters (epoch 0);
``cell_tolerance`` lets each cell be worse by that many :data:`CELL_TOLERANCE`.
It trades the single loss's optimum for issue 15's "every cell at least as good as the
defaults", measured on validation. ``select="spread"`` asks the same with a statistical
tolerance instead of a fixed one: an epoch is admissible when no validation cell is
worse than epoch 0's beyond the rollouts' spread (:func:`worse_beyond_spread`: the whole
95 % interval of a paired bootstrap over the validation log's envs,
:mod:`jax_contact.bootstrap`, on the worse side of 0). Every epoch's such cells are in
its history (``val_worse``) whatever the rule.

Randomness: the key ``jax.random.key(config.seed)`` is folded with the epoch, log and
window numbers, so a run is reproducible (the key only feeds the Monte-Carlo touch-down;
the quadrature mode is deterministic).

Calibration (:func:`fit_calibration`): a monotone map on the fused logit, fitted by
maximum likelihood (Newton's method in float64) on the tuning logs' logits and applied
after the recursion (the filter itself runs on ``l``). By default one temperature per side
of 0, ``l' = l / T_c`` for ``l > 0`` and ``l / T_a`` otherwise: it keeps the sign of every
logit, so every decision at P = 0.5 (F1, accuracy, failures, delays) is the raw P's and
only the probabilities move (docs/tuning.md, rule 14: on validation the air side is
over-confident, ``T_a`` 1.8-2.6). ``kind="affine"``, ``l' = l / T + c``, is the map before;
its bias moves the 0.5 threshold.
"""

from jax_contact.tune.calibration import (
    CALIBRATION_KINDS,
    Calibration,
    apply_calibration,
    calibrate_probability,
    calibration_of,
    fit_calibration,
)
from jax_contact.tune.cells import (
    CELL_KEYS,
    CELL_SHARPNESS,
    CELL_TOLERANCE,
    CONSTRAINT_CELLS,
    cell_surrogates,
    constraint_penalty,
    constraint_units,
    no_worse,
    worse_beyond_spread,
)
from jax_contact.tune.config import SELECT_RULES, TuneConfig
from jax_contact.tune.events import (
    AirPhases,
    TuningData,
    air_event_terms,
    air_phase_maxima,
    air_phases,
    check_scored_steps,
    scored_air_steps,
    with_air_phases,
)
from jax_contact.tune.fit import (
    TuneResult,
    describe,
    pooled,
    predict_logits,
    reference_cells,
    score_logits,
    score_logs,
    select_epoch,
    sigmoid_np,
    tune,
)
from jax_contact.tune.loss import air_hinge, filter_logits, prior_penalty, tuning_loss, window_bce
from jax_contact.tune.space import (
    AXIS_GROUPS,
    BOUNDED_FIELDS,
    CAP_FIELDS,
    DEFAULT_FIELDS,
    LOG_FIELDS,
    NOISE_FIELDS,
    OPTIONAL_FIELDS,
    PLAUSIBLE_NOISE_RATIO,
    SCALAR_FIELDS,
    STANCE_TIME_BOUNDS,
    TUNABLE_FIELDS,
    ParamSpace,
    init_theta,
    make_space,
    robot_space,
    theta_bounds,
    theta_lower_bounds,
    to_params,
)

__all__ = [
    "air_event_terms",
    "air_hinge",
    "air_phase_maxima",
    "air_phases",
    "AirPhases",
    "apply_calibration",
    "AXIS_GROUPS",
    "BOUNDED_FIELDS",
    "calibrate_probability",
    "Calibration",
    "CALIBRATION_KINDS",
    "calibration_of",
    "CAP_FIELDS",
    "CELL_KEYS",
    "CELL_SHARPNESS",
    "cell_surrogates",
    "CELL_TOLERANCE",
    "check_scored_steps",
    "CONSTRAINT_CELLS",
    "constraint_penalty",
    "constraint_units",
    "DEFAULT_FIELDS",
    "describe",
    "filter_logits",
    "fit_calibration",
    "init_theta",
    "LOG_FIELDS",
    "make_space",
    "no_worse",
    "worse_beyond_spread",
    "NOISE_FIELDS",
    "OPTIONAL_FIELDS",
    "ParamSpace",
    "PLAUSIBLE_NOISE_RATIO",
    "pooled",
    "predict_logits",
    "prior_penalty",
    "reference_cells",
    "robot_space",
    "SCALAR_FIELDS",
    "score_logits",
    "select_epoch",
    "score_logs",
    "scored_air_steps",
    "SELECT_RULES",
    "sigmoid_np",
    "STANCE_TIME_BOUNDS",
    "theta_bounds",
    "theta_lower_bounds",
    "to_params",
    "TUNABLE_FIELDS",
    "tune",
    "TuneConfig",
    "TuneResult",
    "tuning_loss",
    "TuningData",
    "window_bce",
    "with_air_phases",
]
