"""The measurement model of eq. 3: dynamics, differential kinematics and kinematics terms.

Each term returns the *log-likelihood ratio* ``log L(C) - log L(A)`` of one foot's
measurement under the contact (C) and air (A) hypotheses, already clipped to the term's
confidence cap (docs/model.md, "State and recursion"). Only ratios enter the recursion, since
eq. 2 normalises ``alpha`` over the two states.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct
from jax.scipy.special import log_ndtr

from jax_contact._math import cap_llr, mvn_logpdf, mvn_logpdf_rank1, robust_llr, spd_solve
from jax_contact.params import EstimatorParams
from jax_contact.types import LegBlocks, LegMeasurement, RobotMeasurement, TerrainQuery


@struct.dataclass
class MeasurementTerms:
    """Capped log-likelihood ratios ``log L(C) - log L(A)`` (nats) of the three terms, and
    the eq. 6 contact force.

    Attributes:
      dynamics: () eq. 4-7.
      diff_kinematics: () eq. 8-9.
      kinematics: () eq. 10.
      force: (3,) force the foot exerts on the ground under the contact hypothesis, N.
    """

    dynamics: jax.Array
    diff_kinematics: jax.Array
    kinematics: jax.Array
    force: jax.Array


def _taker(indices):
    """``take(x, axis)``: the entries ``indices`` of ``x`` along ``axis``.

    Static indices (a tuple of ints) become slices of their ascending runs, so a leg whose
    joints are contiguous costs one slice; an index array becomes a gather.
    """
    if isinstance(indices, tuple):
        runs = []  # [start, stop) of each run of consecutive ascending indices
        for i in indices:
            if runs and runs[-1][1] == i:
                runs[-1][1] = i + 1
            else:
                runs.append([i, i + 1])

        def take(x, axis):
            # No indices (a leg fixed to the world has no other coordinates): an empty block.
            parts = [jax.lax.slice_in_dim(x, a, b, axis=axis) for a, b in runs or [[0, 0]]]
            return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=axis)

        return take
    return lambda x, axis: x[(slice(None),) * axis + (indices,)]


# The fields of a foot's measurement that are its own (the rest are the robot's).
_FOOT_FIELDS = ("Jdot_qd", "p_f", "v_f", "foot_radius")


def _split(params: EstimatorParams, robot, J, foot, take_l, take_b) -> LegBlocks:
    """The eq. 4 split of one foot's quantities: ``robot`` holds q, qd, qdd, tau, M, h."""
    noise = params.noise
    M_rows = take_l(robot.M, 0)
    M_lb, J_b = take_b(M_rows, 1), take_b(J, 1)
    # The other coordinates that this leg's rows involve. A column of both M_lb and J_b
    # that is exactly zero (another leg's joint: a separate branch of the kinematic tree)
    # multiplies its velocity and acceleration by zero in every term, so they are read as
    # 0: another leg's NaN or inf then stays in that leg instead of reaching this one as
    # 0 x NaN. A NaN column of M_lb or J_b counts as involved (docs/model.md, "Inputs per
    # step").
    involved = jnp.any(M_lb != 0, axis=0) | jnp.any(J_b != 0, axis=0)
    return LegBlocks(
        M_l=take_l(M_rows, 1),
        M_lb=M_lb,
        tau_l=take_l(robot.tau, 0),
        h_l=take_l(robot.h, 0),
        qdd_l=take_l(robot.qdd, 0),
        qd_b=jnp.where(involved, take_b(robot.qd, 0), 0.0),
        qdd_b=jnp.where(involved, take_b(robot.qdd, 0), 0.0),
        J=J,
        J_l=take_l(J, 1),
        J_b=J_b,
        sigma_d_l=take_l(noise.sigma_d, 0),
        sigma_qdd_l=take_l(noise.sigma_qdd, 0),
        sigma_qd_prior_l=take_l(noise.sigma_qd_prior, 0),
        sigma_qdd_b=take_b(noise.sigma_qdd, 0),
        **foot,
    )


@jax.named_call
def leg_blocks(params: EstimatorParams, meas: LegMeasurement | LegBlocks) -> LegBlocks:
    """One foot's :class:`LegBlocks`, split with its own index arrays (eq. 4).

    A :class:`LegBlocks` is returned as it is, so the terms below take either.
    """
    if isinstance(meas, LegBlocks):
        return meas
    foot = {f: getattr(meas, f) for f in _FOOT_FIELDS}
    return _split(params, meas, meas.J, foot, _taker(meas.leg_dofs), _taker(meas.other_dofs))


@jax.named_call
def robot_leg_blocks(params: EstimatorParams, meas: RobotMeasurement) -> LegBlocks:
    """Every foot's :class:`LegBlocks` of one robot, leaves with leading axis (n_legs,).

    Each leg's indices are constants, so its blocks are slices of the robot's mass matrix,
    forces and state, read once per robot; the feet then run as one vmapped program.
    Equal to :func:`leg_blocks` of ``meas.leg(i)`` for every leg ``i``.
    """
    legs = []
    for i in range(meas.n_legs):
        foot = {f: getattr(meas, f)[i] for f in _FOOT_FIELDS}
        take_l, take_b = _taker(meas.leg_dofs[i]), _taker(meas.other_dofs(i))
        legs.append(_split(params, meas, meas.J[i], foot, take_l, take_b))
    return jax.tree.map(lambda *xs: jnp.stack(xs), *legs)


@jax.named_call
def dynamics_llr(
    params: EstimatorParams, meas: LegMeasurement | LegBlocks, normal: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Dynamics term (eq. 4-7): is the leg's measured acceleration that of a free or a pinned leg?

    The leg's rows of ``M qdd + h + J^T F = tau`` with the other coordinates' accelerations
    taken as measured. Air: ``F = 0``. Contact: the foot does not accelerate, which fixes
    ``F`` (eq. 6). Only the rows of ``J_f`` in ``params.force_rows`` are used (a 2-joint leg
    spans two), and the operational-space matrix is damped by ``params.inv_damping`` so that
    a leg at full extension stays finite. With ``params.contact_damping`` ``b > 0`` the
    contact hypothesis is a stabilised (soft) contact: the foot's acceleration is
    ``-b min(e . v_f, 0) e`` rather than 0, so a foot still sinking into the ground in its
    first steps of contact fits it, and ``Sigma_f`` gains the velocity noise that the
    stabilising term carries, ``b^2 var(e . v_f) Lambda e e^T Lambda`` with ``Lambda`` the
    (damped) operational-space matrix.

    With ``params.unilateral`` the contact hypothesis is weighted by ``P(-e . F > f_min)``
    under ``F ~ N(F_hat, diag(sigma_f^2))``, ``f_min = params.min_push`` (0 by default:
    ``P(e . F < 0)``): a foot that the ground would have to *pull*, or with ``f_min > 0`` a
    foot that bears almost no load, is evidence for air (a documented choice, docs/model.md
    "Sign"; docs/model_choices.md, "A loaded contact"). The sign test's variance is the
    force's own, without the stabilising term's velocity noise that the contact
    hypothesis's covariance carries (measured: docs/model_choices.md, "Stabilised
    contact").

    Args:
      params: estimator parameters.
      meas: one foot's measurement, or its :class:`LegBlocks`.
      normal: (3,) terrain normal ``e`` at the foot.

    Returns:
      (capped log-likelihood ratio (), contact force F (3,) in N).
    """
    noise = params.noise
    leg = leg_blocks(params, meas)
    M_l, M_lb, qdd_l, qdd_b = leg.M_l, leg.M_lb, leg.qdd_l, leg.qdd_b
    rows = jnp.asarray(params.force_rows)
    J_fl = leg.J_l[rows]
    J_fb = leg.J_b[rows]

    M_inv = spd_solve(M_l, jnp.eye(M_l.shape[0], dtype=M_l.dtype))
    # eq. 5: the leg's acceleration with no contact force, base accelerating as measured.
    residual = leg.tau_l - M_lb @ qdd_b - leg.h_l
    qdd_air = M_inv @ residual
    # eq. 6: the force that keeps the foot still, J_fl qdd_l + J_fb qdd_b + Jdot qd = 0,
    # stabilised: a foot that still moves into the ground is brought to rest at the rate
    # contact_damping, J_f qdd + Jdot qd = -b min(e . v_f, 0) e (0: the paper's rigid form).
    e_rows = normal[rows]
    approach = jnp.minimum(jnp.dot(normal, leg.v_f), 0.0)
    lam_inv = J_fl @ M_inv @ J_fl.T + params.inv_damping * jnp.eye(J_fl.shape[0], dtype=J_fl.dtype)
    stop = params.contact_damping * approach * e_rows
    force_rows = spd_solve(lam_inv, J_fl @ qdd_air + J_fb @ qdd_b + leg.Jdot_qd[rows] + stop)
    qdd_contact = M_inv @ (residual - J_fl.T @ force_rows)

    # eq. 7: model error, plus the measured base acceleration's noise entering through M_lb.
    sigma_d = jnp.diag(jnp.square(leg.sigma_d_l)) + M_lb @ (
        jnp.square(leg.sigma_qdd_b)[:, None] * M_lb.T
    )
    sigma_qdd = jnp.diag(jnp.square(leg.sigma_qdd_l))
    sigma_f = jnp.diag(jnp.square(noise.sigma_f[rows]))
    # The stabilising term carries the measured normal velocity's noise into the force:
    # F gains Lambda e_rows b du, du ~ N(0, e^T (J Sigma_qd J^T + Sigma_J) e).
    Je = normal @ leg.J
    var_u = jnp.dot(Je * Je, jnp.square(noise.sigma_qd)) + jnp.dot(
        normal * normal, jnp.square(noise.sigma_J)
    )
    # In qdd: the rank-one covariance v v^T, v = b sqrt(var_u) M^-1 J_fl^T Lambda e, kept
    # apart (mvn_logpdf_rank1): near a singular leg Lambda e is ~1/inv_damping and the summed
    # matrix is no longer positive definite in float32.
    lam_e = spd_solve(lam_inv, e_rows)
    v_stab = params.contact_damping * jnp.sqrt(var_u) * (M_inv @ (J_fl.T @ lam_e))
    cov_air = M_inv @ sigma_d @ M_inv.T + sigma_qdd
    cov_contact = M_inv @ (sigma_d + J_fl.T @ sigma_f @ J_fl) @ M_inv.T + sigma_qdd
    # Both hypotheses share a broad outlier component (uniform over +-outlier_qdd per
    # joint): an acceleration spike far from both predictions (a differentiated velocity
    # outlier) is evidence for neither, where the narrower Sigma_A would have lost to
    # Sigma_C.
    log_outlier = -M_l.shape[0] * jnp.log(2.0 * params.outlier_qdd)
    llr = robust_llr(
        mvn_logpdf_rank1(qdd_l, qdd_contact, cov_contact, v_stab),
        mvn_logpdf(qdd_l, qdd_air, cov_air),
        params.outlier_prob,
        log_outlier,
    )

    # The wider of the two types: float64 params on float32 readings keep float64.
    force = jnp.zeros(3, jnp.result_type(leg.J, force_rows)).at[rows].set(force_rows)
    if params.unilateral:
        push = jnp.dot(e_rows, force_rows)
        push_var = jnp.dot(e_rows * e_rows, jnp.square(noise.sigma_f[rows]))
        # P(-push > min_push); Phi(0) when e has no component along the kept rows (the
        # force then says nothing about the normal).
        loaded = log_ndtr((-push - params.min_push) / jnp.sqrt(push_var + 1e-12))
        llr = llr + jnp.where(push_var > 0, loaded, jnp.log(0.5))
    return cap_llr(llr, params.cap_dynamics), force


@jax.named_call
def diff_kinematics_llr(
    params: EstimatorParams, meas: LegMeasurement | LegBlocks, normal: jax.Array | None = None
) -> jax.Array:
    """Differential kinematics term (eq. 8-9): is the foot still?

    Contact (eq. 9): ``v_f ~ N(0, J Sigma_qd J^T + Sigma_J)``. Air (eq. 8): the leg's
    joints move with the zero-mean prior ``Sigma_prior`` while the other coordinates move
    as measured,
    ``v_f ~ N(J_fb qd_b, J_fl Sigma_prior J_fl^T + J Sigma_qd J^T + Sigma_J)``.

    With ``params.slip_prob`` ``rho > 0`` the contact hypothesis is the mixture
    ``(1 - rho) N(0, S) + rho N(0, S + s^2 (I - e e^T))``, ``S`` the still foot's covariance
    above and ``s`` = ``params.slip_speed``: a sliding foot stays on the terrain's tangent
    plane (its normal velocity is still ~0) and moves along it (docs/model_choices.md,
    "A sliding contact").

    Args:
      params: estimator parameters.
      meas: one foot's measurement, or its :class:`LegBlocks`.
      normal: (3,) terrain normal ``e`` at the foot; world z when None (used only with
        ``slip_prob > 0``).

    Returns:
      () capped log-likelihood ratio.
    """
    noise = params.noise
    leg = leg_blocks(params, meas)
    J, J_fl = leg.J, leg.J_l
    cov_meas = J @ (jnp.square(noise.sigma_qd)[:, None] * J.T) + jnp.diag(jnp.square(noise.sigma_J))
    cov_air = J_fl @ (jnp.square(leg.sigma_qd_prior_l)[:, None] * J_fl.T) + cov_meas
    mean_air = leg.J_b @ leg.qd_b
    zero = jnp.zeros(3, J.dtype)
    log_still = mvn_logpdf(leg.v_f, zero, cov_meas)
    if normal is None:
        normal = jnp.array([0.0, 0.0, 1.0], J.dtype)
    tangent = jnp.eye(3, dtype=J.dtype) - jnp.outer(normal, normal)
    log_slide = mvn_logpdf(leg.v_f, zero, cov_meas + jnp.square(params.slip_speed) * tangent)
    rho = params.slip_prob
    # rho = 0 selects the still foot exactly (and keeps log(0) out of every gradient).
    log_rho = jnp.log(jnp.where(rho > 0, rho, 1.0))
    mixed = jnp.logaddexp(jnp.log1p(-rho) + log_still, log_rho + log_slide)
    llr = robust_llr(
        jnp.where(rho > 0, mixed, log_still),
        mvn_logpdf(leg.v_f, mean_air, cov_air),
        params.outlier_prob,
        -3.0 * jnp.log(2.0 * params.outlier_v),
    )
    # A still foot is weaker evidence for contact than a moving one is for air: a swing
    # foot is slow at lift-off and near its apex (docs/model_choices.md).
    return cap_llr(llr, params.cap_diff_kinematics, params.cap_diff_kinematics_still)


@jax.named_call
def end_of_interval(params: EstimatorParams, leg: LegBlocks) -> LegBlocks:
    """One foot's blocks moved ``kinematics_lead`` of the way to the end of the measured
    interval (1: the newest reading).

    The delayed pairing gives the estimator the state ``(q_k, qd_k)`` that the acceleration
    ``qdd_k`` and torque ``tau_k`` belong to, one reading old. The velocity at the end of
    the interval is ``qd_k + dt qdd_k`` (for a differenced acceleration exactly the newest
    measured velocity), so the foot's is ``v_f + dt (J qdd + Jdot qd)`` and its position,
    after one semi-implicit Euler step, ``p_f + dt v_f'``; ``J`` is kept (it changes by
    O(dt)). The kinematic terms and the transitions read this state, one step newer than
    the dynamics term's (docs/model_choices.md); ``kinematics_lead`` 0 returns the
    blocks' values unchanged.

    Args:
      params: estimator parameters (``kinematics_lead``, ``dt`` s).
      leg: one foot's blocks (:func:`leg_blocks`).

    Returns:
      The blocks with ``v_f`` (3,) m/s, ``p_f`` (3,) m and ``qd_b`` moved to the end of
      the interval; everything else as given.
    """
    dt = params.kinematics_lead * params.dt
    a_f = leg.J_l @ leg.qdd_l + leg.J_b @ leg.qdd_b + leg.Jdot_qd
    v_end = leg.v_f + dt * a_f
    return leg.replace(v_f=v_end, p_f=leg.p_f + dt * v_end, qd_b=leg.qd_b + dt * leg.qdd_b)


def sole_gap(
    params: EstimatorParams, meas: LegMeasurement | LegBlocks, terrain: TerrainQuery
) -> tuple[jax.Array, jax.Array]:
    """Mean and std of the gap ``phi = e . (p_f - p_i)`` between sole and terrain (eq. 10).

    The sole is ``p_f - r e`` for a sphere foot of radius r, and the terrain point ``p_i``
    is the one below the foot centre at the queried height, so
    ``e . (p_f - r e - p_i) = e_z (z_f - height) - r``: the sole's distance from the
    terrain's tangent plane. ``sigma_pf^2 = e^T J Sigma_q J^T e``.

    Args:
      params: estimator parameters (``noise.sigma_q``, (nv,) m and rad).
      meas: one foot's measurement, or its ``LegBlocks`` (``p_f`` (3,) m, ``J`` (3, nv)).
      terrain: the terrain at the foot (``height`` m, ``normal`` (3,)).

    Returns:
      (mean gap (), foot-position std along e sigma_pf ()), both in m.
    """
    e = terrain.normal
    gap = e[2] * (meas.p_f[2] - terrain.height) - meas.foot_radius
    Je = e @ meas.J
    sigma_pf = jnp.sqrt(jnp.dot(Je * Je, jnp.square(params.noise.sigma_q)) + 1e-12)
    return gap, sigma_pf


@jax.named_call
def kinematics_llr(
    params: EstimatorParams,
    meas: LegMeasurement | LegBlocks,
    terrain: TerrainQuery,
    neutral_below: jax.Array | None = None,
) -> jax.Array:
    """Kinematics term (eq. 10): ``L(C) = P(phi <= 0)``, ``L(A) = 1 - P(phi <= 0)``.

    ``phi ~ N(gap, sigma_pf^2 + sigma_pi^2)``. Neutral on the ground, evidence for air when
    the foot is high above the terrain.

    Args:
      neutral_below: () bool, ``params.kinematics_neutral_below`` as data (None: that
        field; see :class:`jax_contact.params.Switches`).

    Returns:
      () capped log-likelihood ratio.
    """
    if neutral_below is None:
        neutral_below = params.kinematics_neutral_below
    gap, sigma_pf = sole_gap(params, meas, terrain)
    z = gap / jnp.sqrt(sigma_pf**2 + terrain.sigma**2)
    llr = log_ndtr(-z) - log_ndtr(z)
    # Neutral on and below the terrain: a sole estimated below the plane (base height
    # drift, terrain error) says nothing about contact, only a high foot says "air".
    llr = jnp.where(neutral_below, jnp.minimum(llr, 0.0), llr)
    return cap_llr(llr, params.cap_kinematics)


def measurement_terms(
    params: EstimatorParams,
    meas: LegMeasurement | LegBlocks,
    terrain: TerrainQuery,
    kin: LegBlocks | None = None,
    neutral_below: jax.Array | None = None,
) -> MeasurementTerms:
    """All three capped terms of eq. 3 for one foot.

    Args:
      kin: the blocks the kinematic terms read, :func:`end_of_interval` of ``meas`` when
        None.
      neutral_below: see :func:`kinematics_llr`.
    """
    meas = leg_blocks(params, meas)
    if kin is None:
        kin = end_of_interval(params, meas)
    dyn, force = dynamics_llr(params, meas, terrain.normal)
    return MeasurementTerms(
        dynamics=dyn,
        diff_kinematics=diff_kinematics_llr(params, kin, terrain.normal),
        kinematics=kinematics_llr(params, kin, terrain, neutral_below),
        force=force,
    )
