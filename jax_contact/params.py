"""Estimator parameters: noise model (Table II), gait prior, caps and numerical options.

Parameters are frozen pytrees. Array-valued numbers are leaves (so they can be tuned by
gradient, see ``jax.grad`` over ``NoiseParams``); sizes and mode switches are static
fields. Build them with :func:`make_params`, which validates everything *before* any
tracing and names the offending field; never mutate a shared default, use
``params.replace(...)`` and validate again with :func:`validate_params`.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np
from flax import struct

TOUCHDOWN_MODES = ("monte_carlo", "quadrature")
TERMS = ("dynamics", "diff_kinematics", "kinematics")


@struct.dataclass
class NoiseParams:
    """Standard deviations of the Gaussian noise model (docs/model.md; paper Table II).

    Per-coordinate entries have length ``nv`` and are indexed by each leg's dofs, so one
    object serves every leg of a robot.

    Attributes:
      sigma_q: (nv,) position noise ``w_q``, m and rad.
      sigma_qd: (nv,) velocity noise ``w_qd``, m/s and rad/s.
      sigma_qdd: (nv,) acceleration noise ``w_qdd`` of the accelerations actually used
        (a raw difference of ``qd`` at rate 1/dt has std ``sqrt(2) sigma_qd / dt``), m/s^2
        and rad/s^2.
      sigma_d: (nv,) generalised disturbance / model error ``w_d``, N and N m.
      sigma_f: (3,) contact force uncertainty ``Sigma_f`` per world axis, N (Table II's
        entry is garbled in the paper; 10 N is this library's default choice, at most 0.4
        of a foot's share of the weight: :func:`jax_contact.defaults.contact_force_std`).
      sigma_J: (3,) foot velocity noise of the no-slip hypothesis ``Sigma_J``, m/s.
      sigma_qd_prior: (nv,) prior spread of a swinging leg's joint velocities (the air
        hypothesis of eq. 8, whose ``qd`` the text after eq. 9 takes from a prior), rad/s;
        by default the gait prior's ``swing_joint_speed`` (25 rad/s, Table I's joint speed
        limit of the planar leg; ``jax_contact.defaults.GaitPrior``).
    """

    sigma_q: jnp.ndarray
    sigma_qd: jnp.ndarray
    sigma_qdd: jnp.ndarray
    sigma_d: jnp.ndarray
    sigma_f: jnp.ndarray
    sigma_J: jnp.ndarray
    sigma_qd_prior: jnp.ndarray


# The largest static sizes of the touch-down transition: Monte-Carlo draws per foot and
# quadrature nodes per dimension (docs/model_choices.md: 8 is the default, 32-64 where the
# foot's height is far more uncertain than the terrain's).
MAX_N_SAMPLES = 100_000
MAX_N_QUAD = 128


@struct.dataclass
class EstimatorParams:
    """Everything the estimator needs besides the measurements and the terrain.

    Attributes:
      noise: the Gaussian noise model.
      dt: () time step between estimator updates, s.
      stance_time: () mean stance duration ``T_s`` of the gait prior (eq. 12), s.
      swing_time: () mean swing duration, s; the gait prior's transition out of the air
        (``dt / swing_time``, not in the paper), used at initialisation, on a step whose
        measurement is invalid (NaN) and on every step with ``transition_model=False``.
      takeoff_accel: () ``a_F``, the largest take-off acceleration of the foot along the
        terrain normal, m/s^2; ``u_max = a_F dt`` (eq. 15).
      cap_dynamics, cap_diff_kinematics, cap_kinematics: () confidence caps in (0.5, 1]:
        each term's log-likelihood ratio is clipped to ``+-logit(cap)`` (docs/model.md).
      cap_diff_kinematics_still: () cap of the differential-kinematics term on the
        contact side only: a still foot is weaker evidence for contact than a moving foot
        is for air, since a swinging foot is slow near its apex and at lift-off
        (docs/model_choices.md, "Robust likelihoods"); equal to ``cap_diff_kinematics``
        for the paper's symmetric cap.
      cap_transition: () cap in (0.5, 1] on each transition's log-odds against staying,
        ``log P(A|C) / P(C|C)`` and ``log P(C|A) / P(A|A)`` clipped from above to
        ``logit(cap)`` (staying is bounded only by ``transition.LOG_FLOOR``): one velocity
        sample alone never moves a confident belief past this probability (1: unbounded,
        the paper's transitions).
      outlier_prob: () probability ``eps`` of the broad outlier component that the
        contact and the air hypotheses share, in the dynamics and differential-kinematics
        terms and in the take-off velocity model: each hypothesis' density is
        ``(1 - eps) N(...) + eps U``, so a gross outlier is evidence for neither (0: the
        paper's pure Gaussians).
      outlier_qdd: () half-width of the uniform outlier density of a joint's measured
        acceleration, rad/s^2 (m/s^2 for prismatic joints).
      outlier_v: () half-width of the uniform outlier density of each foot velocity
        component, m/s.
      foothold_confidence: () P(C) above which a step writes the foothold memory; it is
        written only where the differential-kinematics term also says the foot is still
        (``foothold_still``), so a false contact in the air does not store the swing
        height as terrain.
      inv_damping: () Tikhonov damping of the operational-space inverse of eq. 6, in units
        of ``1 / kg``, so a leg at full extension stays finite.
      contact_damping: () ``b``, 1/s: the rate at which the ground brings a foot that
        moves into it to rest under the contact hypothesis of the dynamics term. The
        constraint of eq. 6 becomes ``J qdd + Jdot qd = -b min(e . v_f, 0) e`` (a soft
        contact's reference acceleration, as MuJoCo's ``b = 2 / timeconst``) instead of
        ``= 0``, so a foot still decelerating in its first steps on the ground fits the
        contact hypothesis; the measured velocity's noise enters ``Sigma_f`` through it.
        0 is the paper's rigid constraint (docs/model_choices.md, "Stabilised contact").
      initial_contact: () belief P(C) before the first measurement.
      n_samples: static, Monte-Carlo samples of Algorithm 1 (500 in the paper).
      touchdown: static, ``"monte_carlo"`` (Algorithm 1) or ``"quadrature"`` (the same
        integral by a deterministic Gauss rule).
      n_quad: static, nodes per dimension of the quadrature rule.
      force_rows: static, the world axes of the contact force the leg's joints span
        (``(0, 1, 2)`` for a 3-dof leg; ``(0, 2)`` for the planar leg; ``(2,)`` keeps the
        normal only, for slipping feet).
      unilateral: static; if True the contact hypothesis is also weighed by the
        probability that the estimated force pushes into the ground (``e . F < 0``), so a
        foot that would need the ground to pull it counts as evidence for air.
      min_push: () N, with ``unilateral``: the contact hypothesis's foot pushes into the
        ground with at least this force, ``P(-e . F > min_push)``; 0 (default) is the
        sign rule above. A loaded foot, not a foot the ground merely touches: a braking
        swing foot whose deceleration the stabilised contact explains with almost no
        force counts as air (docs/model_choices.md, "A loaded contact").
      slip_prob: () probability ``rho`` in [0, 1) that a foot in contact slides: the
        differential-kinematics term's contact hypothesis is the mixture of the still
        foot (eq. 9) and, with weight ``rho``, a foot that keeps to the terrain's
        tangent plane and moves along it with std ``slip_speed`` per tangent axis. 0
        (default) is the paper's still foot (docs/model_choices.md, "A sliding contact").
      slip_speed: () m/s, the sliding foot's tangential velocity std (with ``slip_prob``).
      terms: static, the measurement terms that enter eq. 3 (all three by default); a
        subset is for ablations (diagnostics still report every term).
      transition_model: static; if False the measurement-dependent transitions (eq.
        11-17) are replaced by the gait prior alone, for ablations.
      kinematics_neutral_below: static; if True (default) the kinematics term is neutral
        wherever the sole is at or below the terrain (docs/model.md, "Kinematics": neutral
        on the ground, evidence for air above it); False is the two-sided ratio
        ``P(phi <= 0) / P(phi > 0)``, which reads a sole estimated below the plane (base
        height drift) as contact evidence.
      foothold_still: static; see ``foothold_confidence``. The filter reads these four
        switches (``terms`` to ``foothold_still``) through :class:`Switches`, which can
        also carry them as data.
      kinematics_lead: () in [0, 1], the fraction of the measured interval by which the
        state that the differential-kinematics and kinematics terms, the transitions and
        the foothold memory read is advanced: 1 reads the foot at the *end* of the
        interval (the newest reading, ``qd + dt qdd``), while the dynamics term keeps the
        state its acceleration belongs to (docs/model_choices.md, "The newest reading for
        the kinematic terms"); 0 reads every term at the interval's start (the paper).
    """

    noise: NoiseParams
    dt: jnp.ndarray
    stance_time: jnp.ndarray
    swing_time: jnp.ndarray
    takeoff_accel: jnp.ndarray
    cap_dynamics: jnp.ndarray
    cap_diff_kinematics: jnp.ndarray
    cap_kinematics: jnp.ndarray
    cap_diff_kinematics_still: jnp.ndarray
    cap_transition: jnp.ndarray
    outlier_prob: jnp.ndarray
    outlier_qdd: jnp.ndarray
    outlier_v: jnp.ndarray
    foothold_confidence: jnp.ndarray
    inv_damping: jnp.ndarray
    initial_contact: jnp.ndarray
    contact_damping: jnp.ndarray
    kinematics_lead: jnp.ndarray
    min_push: jnp.ndarray
    slip_prob: jnp.ndarray
    slip_speed: jnp.ndarray
    n_samples: int = struct.field(pytree_node=False, default=500)
    touchdown: str = struct.field(pytree_node=False, default="monte_carlo")
    n_quad: int = struct.field(pytree_node=False, default=8)
    force_rows: tuple[int, ...] = struct.field(pytree_node=False, default=(0, 1, 2))
    unilateral: bool = struct.field(pytree_node=False, default=True)
    terms: tuple[str, ...] = struct.field(pytree_node=False, default=TERMS)
    transition_model: bool = struct.field(pytree_node=False, default=True)
    kinematics_neutral_below: bool = struct.field(pytree_node=False, default=True)
    foothold_still: bool = struct.field(pytree_node=False, default=True)

    @property
    def nv(self) -> int:
        """The model's number of generalised velocities, from the noise model's size."""
        return int(np.shape(self.noise.sigma_qd)[0])


@struct.dataclass
class Switches:
    """The four structural switches of :class:`EstimatorParams` as data.

    ``terms``, ``transition_model``, ``kinematics_neutral_below`` and ``foothold_still``
    are static fields: each value is its own compiled program, and the branch it turns off
    is not computed. The filter reads them through this class (:func:`switches_of`: NumPy
    constants, which XLA folds, so the default program is unchanged); a caller that runs
    several variants differing only in these switches passes them as arrays instead
    (``step_batch(..., switches=)``) and ``vmap``s one program over the variants
    (``train/evaluate.replay``: the reproduction's 15 ablation variants as one program,
    not seven).

    Attributes:
      terms: (3,) bool, whether each term of :data:`TERMS` (in that order) enters eq. 3.
      transition_model: () bool, ``EstimatorParams.transition_model``.
      kinematics_neutral_below: () bool, ``EstimatorParams.kinematics_neutral_below``.
      foothold_still: () bool, ``EstimatorParams.foothold_still``.
    """

    terms: jnp.ndarray
    transition_model: jnp.ndarray
    kinematics_neutral_below: jnp.ndarray
    foothold_still: jnp.ndarray


def switches_of(params: EstimatorParams) -> Switches:
    """``params``' static switches as a :class:`Switches` of NumPy bools (constants)."""
    return Switches(
        terms=np.array([t in params.terms for t in TERMS]),
        transition_model=np.bool_(params.transition_model),
        kinematics_neutral_below=np.bool_(params.kinematics_neutral_below),
        foothold_still=np.bool_(params.foothold_still),
    )


def without_switches(params: EstimatorParams) -> EstimatorParams:
    """``params`` with the four switches at their defaults (every term, the transition
    model, the one-sided kinematics term, the still foothold): with :func:`switches_of` of
    the original passed as data, the same filter (``step_batch(..., switches=)``)."""
    return params.replace(
        terms=TERMS, transition_model=True, kinematics_neutral_below=True, foothold_still=True
    )


def _per_dof(name: str, value, nv: int) -> jnp.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((nv,), float(arr))
    if arr.shape != (nv,):
        raise ValueError(f"{name} must be a scalar or have shape ({nv},) (nv), got {arr.shape}")
    return jnp.asarray(arr, dtype=jnp.float32)


def _per_axis(name: str, value) -> jnp.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((3,), float(arr))
    if arr.shape != (3,):
        raise ValueError(f"{name} must be a scalar or have shape (3,), got {arr.shape}")
    return jnp.asarray(arr, dtype=jnp.float32)


def make_noise(
    nv: int,
    *,
    sigma_q: float | Sequence[float] = 0.02,
    sigma_qd: float | Sequence[float] = 0.3,
    sigma_qdd: float | Sequence[float] = 170.0,
    sigma_d: float | Sequence[float] = 2.0,
    sigma_f: float | Sequence[float] = 10.0,
    sigma_J: float | Sequence[float] = 0.05,
    sigma_qd_prior: float | Sequence[float] = 25.0,
) -> NoiseParams:
    """Builds and validates a :class:`NoiseParams` for a model with ``nv`` velocities.

    Scalars are broadcast to every coordinate (or every axis for ``sigma_f``, ``sigma_J``).
    The defaults are Table II's joint values with ``sigma_qdd`` for a raw 400 Hz difference
    of ``qd`` (``sqrt(2) * 0.3 / 0.0025`` ~ 170 rad/s^2) and this library's choices
    ``Sigma_f`` = 10 N (Table II's entry is garbled; :func:`jax_contact.params_for` lowers
    it on a light robot), ``Sigma_J`` = 0.05 m/s, prior 25 rad/s (Table I's joint limit).

    Raises:
      ValueError: a field has the wrong shape or a non-positive or non-finite entry.
    """
    if not isinstance(nv, int | np.integer) or nv < 1:
        raise ValueError(f"nv must be a positive int, got {nv!r}")
    noise = NoiseParams(
        sigma_q=_per_dof("sigma_q", sigma_q, nv),
        sigma_qd=_per_dof("sigma_qd", sigma_qd, nv),
        sigma_qdd=_per_dof("sigma_qdd", sigma_qdd, nv),
        sigma_d=_per_dof("sigma_d", sigma_d, nv),
        sigma_f=_per_axis("sigma_f", sigma_f),
        sigma_J=_per_axis("sigma_J", sigma_J),
        sigma_qd_prior=_per_dof("sigma_qd_prior", sigma_qd_prior, nv),
    )
    validate_noise(noise)
    return noise


def _shown(v) -> str:
    """A value for an error message: a scalar as a plain number (``nan``, ``-0.1``), not
    NumPy's ``array(-0.1, dtype=float32)``; anything else as a list."""
    a = np.asarray(v)
    if a.dtype.kind in "fiub":
        return f"{a.item():g}" if a.shape == () else str(a.tolist())
    return repr(v)


def validate_noise(noise: NoiseParams) -> None:
    """Raises ``ValueError`` naming the field if any standard deviation is not > 0."""
    nv = None
    for name in NoiseParams.__dataclass_fields__:
        arr = np.asarray(getattr(noise, name))
        if name in ("sigma_f", "sigma_J"):
            if arr.shape != (3,):
                raise ValueError(f"noise.{name} must have shape (3,), got {arr.shape}")
        else:
            if arr.ndim != 1:
                raise ValueError(f"noise.{name} must have shape (nv,), got {arr.shape}")
            if nv is None:
                nv = arr.shape[0]
            elif arr.shape[0] != nv:
                raise ValueError(
                    f"noise.{name} has shape {arr.shape} but other per-dof fields have ({nv},)"
                )
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            worst = arr[~np.isfinite(arr)][0] if not np.all(np.isfinite(arr)) else arr.min()
            what = "min" if np.all(np.isfinite(arr)) else "non-finite"
            raise ValueError(
                f"noise.{name} must be finite and > 0 everywhere, got {what} {_shown(worst)}"
            )


def make_params(
    noise: NoiseParams,
    *,
    dt: float = 0.0025,
    stance_time: float = 0.3,
    swing_time: float = 0.3,
    takeoff_accel: float = 200.0,
    cap_dynamics: float = 0.99,
    cap_diff_kinematics: float = 0.9,
    cap_kinematics: float = 0.99,
    cap_diff_kinematics_still: float | None = None,
    cap_transition: float = 1.0,
    outlier_prob: float = 0.0,
    outlier_qdd: float = 8000.0,
    outlier_v: float = 4.0,
    foothold_confidence: float = 0.5,
    inv_damping: float = 1e-6,
    initial_contact: float = 0.5,
    contact_damping: float = 0.0,
    n_samples: int = 500,
    touchdown: str = "monte_carlo",
    n_quad: int = 8,
    force_rows: Sequence[int] = (0, 1, 2),
    unilateral: bool = True,
    terms: Sequence[str] = TERMS,
    transition_model: bool = True,
    kinematics_neutral_below: bool = True,
    foothold_still: bool = True,
    kinematics_lead: float = 0.0,
    min_push: float = 0.0,
    slip_prob: float = 0.0,
    slip_speed: float = 0.5,
) -> EstimatorParams:
    """Builds and validates :class:`EstimatorParams`.

    Defaults: 400 Hz (the paper's rate on ANYmal), ``T_s`` = 0.3 s, ``a_F`` = 200 m/s^2,
    caps 0.99 / 0.9 / 0.99 (dynamics / differential kinematics / kinematics;
    docs/model_choices.md, "term caps"),
    the paper's rigid contact constraint (``contact_damping`` 0).

    Raises:
      ValueError: naming the field, for a non-positive time or acceleration, a cap outside
        (0.5, 1], ``n_samples`` or ``n_quad`` below 1, an unknown ``touchdown`` mode or
        invalid ``force_rows``.
    """
    flags = dict(
        unilateral=unilateral,
        transition_model=transition_model,
        kinematics_neutral_below=kinematics_neutral_below,
        foothold_still=foothold_still,
    )
    for name, flag in flags.items():  # bool("no") is True: a string is a mistake
        if not isinstance(flag, bool | np.bool_):
            raise ValueError(f"{name} must be True or False, got {flag!r}")
    for name, seq in (("terms", terms), ("force_rows", force_rows)):
        if isinstance(seq, str) or not isinstance(seq, Sequence | np.ndarray):
            raise ValueError(f"{name} must be a sequence (e.g. a tuple), got {seq!r}")
    # Entries of the right kind before they are converted: (0.9, 2.5) became (0, 2).
    if any(
        isinstance(r, bool | np.bool_) or not isinstance(r, int | np.integer) for r in force_rows
    ):
        raise ValueError(f"force_rows must hold integer axes among (0, 1, 2), got {force_rows!r}")
    if any(not isinstance(t, str) for t in terms):
        raise ValueError(f"terms must hold names among {TERMS}, got {terms!r}")
    params = EstimatorParams(
        noise=noise,
        dt=jnp.float32(dt),
        stance_time=jnp.float32(stance_time),
        swing_time=jnp.float32(swing_time),
        takeoff_accel=jnp.float32(takeoff_accel),
        cap_dynamics=jnp.float32(cap_dynamics),
        cap_diff_kinematics=jnp.float32(cap_diff_kinematics),
        cap_kinematics=jnp.float32(cap_kinematics),
        cap_diff_kinematics_still=jnp.float32(
            cap_diff_kinematics if cap_diff_kinematics_still is None else cap_diff_kinematics_still
        ),
        cap_transition=jnp.float32(cap_transition),
        outlier_prob=jnp.float32(outlier_prob),
        outlier_qdd=jnp.float32(outlier_qdd),
        outlier_v=jnp.float32(outlier_v),
        foothold_confidence=jnp.float32(foothold_confidence),
        inv_damping=jnp.float32(inv_damping),
        initial_contact=jnp.float32(initial_contact),
        contact_damping=jnp.float32(contact_damping),
        kinematics_lead=jnp.float32(kinematics_lead),
        min_push=jnp.float32(min_push),
        slip_prob=jnp.float32(slip_prob),
        slip_speed=jnp.float32(slip_speed),
        n_samples=n_samples,
        touchdown=touchdown,
        n_quad=n_quad,
        force_rows=tuple(int(r) for r in force_rows),
        unilateral=bool(unilateral),
        terms=tuple(terms),
        transition_model=bool(transition_model),
        kinematics_neutral_below=bool(kinematics_neutral_below),
        foothold_still=bool(foothold_still),
    )
    validate_params(params)
    return params


# Units named in the errors of validate_params.
_UNITS = {"contact_damping": " (1/s)", "min_push": " (N)", "slip_speed": " (m/s)"}


def validate_params(params: EstimatorParams) -> None:
    """Checks every field of ``params``; raises ``ValueError`` naming the first bad one."""
    if not isinstance(params, EstimatorParams):
        raise ValueError(
            f"params must be EstimatorParams (params_for, make_params, load_params), got"
            f" {type(params).__name__}"
            + (": a params file's dict loads with load_params" if isinstance(params, dict) else "")
        )
    validate_noise(params.noise)
    for name in ("dt", "stance_time", "swing_time", "takeoff_accel"):
        v = np.asarray(getattr(params, name))
        if v.shape != () or not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be a finite scalar > 0, got {_shown(v)}")
    if float(params.stance_time) <= float(params.dt):
        raise ValueError(
            f"stance_time ({float(params.stance_time)}) must exceed dt ({float(params.dt)}):"
            " the gait prior P(A|C) = dt / T_s must be below 1"
        )
    if float(params.swing_time) <= float(params.dt):
        raise ValueError(
            f"swing_time ({float(params.swing_time)}) must exceed dt ({float(params.dt)})"
        )
    for name in (
        "cap_dynamics",
        "cap_diff_kinematics",
        "cap_kinematics",
        "cap_diff_kinematics_still",
        "cap_transition",
    ):
        v = np.asarray(getattr(params, name))
        if v.shape != () or not (0.5 < float(v) <= 1.0):
            raise ValueError(f"{name} must lie in (0.5, 1], got {_shown(v)}")
    for name in ("outlier_prob", "slip_prob"):
        v = np.asarray(getattr(params, name))
        if v.shape != () or not (0.0 <= float(v) < 1.0):
            raise ValueError(f"{name} must lie in [0, 1), got {_shown(v)}")
    for name in ("outlier_qdd", "outlier_v", "slip_speed"):
        v = np.asarray(getattr(params, name))
        if v.shape != () or not np.isfinite(v) or v <= 0:
            raise ValueError(
                f"{name} must be a finite scalar > 0{_UNITS.get(name, '')}, got {_shown(v)}"
            )
    v = np.asarray(params.foothold_confidence)
    if v.shape != () or not (0.0 < float(v) < 1.0):
        raise ValueError(f"foothold_confidence must lie in (0, 1), got {_shown(v)}")
    for name in ("inv_damping", "contact_damping", "min_push"):
        v = np.asarray(getattr(params, name))
        if v.shape != () or not np.isfinite(v) or v < 0:
            raise ValueError(
                f"{name} must be a finite scalar >= 0{_UNITS.get(name, '')}, got {_shown(v)}"
            )
    v = np.asarray(params.kinematics_lead)
    if v.shape != () or not (0.0 <= float(v) <= 1.0):
        raise ValueError(f"kinematics_lead must lie in [0, 1], got {_shown(v)}")
    v = np.asarray(params.initial_contact)
    if v.shape != () or not (0.0 < float(v) < 1.0):
        raise ValueError(f"initial_contact must lie in (0, 1), got {_shown(v)}")
    # Bounded: a file's n_quad of 1e6 built 1e12 nodes per foot at the first step.
    for name, top in (("n_samples", MAX_N_SAMPLES), ("n_quad", MAX_N_QUAD)):
        v = getattr(params, name)
        if (
            isinstance(v, bool | np.bool_)
            or not isinstance(v, int | np.integer)
            or not 1 <= v <= top
        ):
            raise ValueError(f"{name} must be an int in [1, {top}], got {v!r}")
    if params.touchdown not in TOUCHDOWN_MODES:
        raise ValueError(f"touchdown must be one of {TOUCHDOWN_MODES}, got {params.touchdown!r}")
    rows = params.force_rows
    if len(rows) == 0 or len(set(rows)) != len(rows) or any(r not in (0, 1, 2) for r in rows):
        raise ValueError(f"force_rows must be distinct axes among (0, 1, 2), got {rows!r}")
    terms = params.terms
    if len(terms) == 0 or len(set(terms)) != len(terms) or any(t not in TERMS for t in terms):
        raise ValueError(f"terms must be distinct names among {TERMS}, got {terms!r}")
