"""Pytrees that flow through the estimator: one leg's measurement, belief and diagnostics.

All of these are *unbatched*: they describe one foot of one robot at one time step.
Batches over legs and environments are made with ``jax.vmap`` at the edge (see
``jax_contact.filter.step_batch``), so every leaf below gains leading axes there.

Notation follows ``docs/model.md``: ``nv`` generalised velocities, ``n_l`` joints of the leg,
``n_b = nv - n_l`` the other coordinates (base and the other legs).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class LegMeasurement:
    """What the robot's state estimate and model give for one foot at one time step.

    Everything is expressed in the world frame at the *measured* state; nothing here is
    ground truth. The leg's coordinate split (eq. 4: ``l`` the leg, ``b`` the rest) is given
    by two index arrays so that one pytree layout serves every leg of a robot.

    Attributes:
      q: (nq,) generalised coordinates as estimated (kept for provenance and baselines;
        the terms use the model quantities below, which were evaluated at ``q``).
      qd: (nv,) generalised velocities, m/s and rad/s.
      qdd: (nv,) generalised accelerations, m/s^2 and rad/s^2 (on a robot: the numerical
        derivative of ``qd``).
      tau: (nv,) generalised actuation forces, the paper's ``S^T tau`` (joint torques as
        the torque sensors give them, zero on unactuated coordinates), N and N m.
      M: (nv, nv) joint-space mass matrix M(q), kg, kg m and kg m^2 by coordinate pair.
      h: (nv,) bias forces h(q, qd): Coriolis, centrifugal and gravity, N and N m.
      J: (3, nv) translational Jacobian of the foot point, world frame; m/m on a linear
        coordinate, m/rad on an angular one.
      Jdot_qd: (3,) bias acceleration of the foot point, d/dt(J) qd, m/s^2.
      p_f: (3,) foot point (centre of the foot sphere), world frame, m.
      v_f: (3,) foot point velocity, ``J @ qd``, m/s.
      foot_radius: () radius of the foot sphere, m; the sole is ``p_f - foot_radius * e``.
      leg_dofs: (n_l,) int32 indices into ``nv`` of the leg's joints.
      other_dofs: (nv - n_l,) int32 indices into ``nv`` of every other coordinate.
    """

    q: jax.Array
    qd: jax.Array
    qdd: jax.Array
    tau: jax.Array
    M: jax.Array
    h: jax.Array
    J: jax.Array
    Jdot_qd: jax.Array
    p_f: jax.Array
    v_f: jax.Array
    foot_radius: jax.Array
    leg_dofs: jax.Array
    other_dofs: jax.Array


@struct.dataclass
class RobotMeasurement:
    """One robot's measurement at one time step: what its feet share held once.

    The same quantities as :class:`LegMeasurement`, laid out per robot: the state, the
    mass matrix and the forces once, the foot quantities once per foot, and each leg's
    coordinate split as compile-time constants. :func:`jax_contact.step_batch` accepts it
    in place of per-foot copies and gives the same result; it reads a quarter of the mass
    matrix bytes of a quadruped and slices each leg's blocks with constant indices
    (:func:`jax_contact.robot_leg_blocks`) before the legs run as one vmapped program
    (docs/performance.md: the quadrature update 1.2x faster in a batch than on per-foot
    copies; for a single robot about the same).

    Attributes:
      q: (nq,) generalised coordinates as estimated.
      qd, qdd, tau, h: (nv,) as in :class:`LegMeasurement`.
      M: (nv, nv) joint-space mass matrix.
      J: (n_legs, 3, nv) translational Jacobian of each foot point, world frame.
      Jdot_qd: (n_legs, 3) bias acceleration of each foot point, m/s^2.
      p_f: (n_legs, 3) foot points (sphere centres), world frame, m.
      v_f: (n_legs, 3) foot point velocities, m/s.
      foot_radius: (n_legs,) foot sphere radii, m.
      leg_dofs: static, per leg the indices into ``nv`` of its joints (every leg the same
        number); the other coordinates are the rest of ``range(nv)``, ascending.
    """

    q: jax.Array
    qd: jax.Array
    qdd: jax.Array
    tau: jax.Array
    M: jax.Array
    h: jax.Array
    J: jax.Array
    Jdot_qd: jax.Array
    p_f: jax.Array
    v_f: jax.Array
    foot_radius: jax.Array
    leg_dofs: tuple[tuple[int, ...], ...] = struct.field(pytree_node=False)

    @property
    def n_legs(self) -> int:
        """Number of feet (L)."""
        return len(self.leg_dofs)

    def other_dofs(self, leg: int) -> tuple[int, ...]:
        """The coordinates outside leg ``leg``, ascending."""
        nv = self.qd.shape[-1]
        return tuple(i for i in range(nv) if i not in self.leg_dofs[leg])

    def leg(self, leg: int) -> LegMeasurement:
        """Foot ``leg``'s :class:`LegMeasurement` (unbatched robot; indices as constants)."""
        return LegMeasurement(
            q=self.q,
            qd=self.qd,
            qdd=self.qdd,
            tau=self.tau,
            M=self.M,
            h=self.h,
            J=self.J[leg],
            Jdot_qd=self.Jdot_qd[leg],
            p_f=self.p_f[leg],
            v_f=self.v_f[leg],
            foot_radius=self.foot_radius[leg],
            leg_dofs=jnp.asarray(self.leg_dofs[leg], jnp.int32),
            other_dofs=jnp.asarray(self.other_dofs(leg), jnp.int32),
        )

    def legs(self) -> LegMeasurement:
        """The per-foot layout: every leaf gains axis ``n_legs`` just before its own axes.

        Works on batched leaves too (leading axes before the robot's, e.g. (n_envs,)).
        """
        batch = self.qd.shape[:-1]
        n = self.n_legs

        def tile(x, k):  # k: the number of the field's own (unbatched) axes
            axis = x.ndim - k
            return jnp.broadcast_to(
                jnp.expand_dims(x, axis), x.shape[:axis] + (n,) + x.shape[axis:]
            )

        def indices(rows):
            return jnp.broadcast_to(jnp.asarray(rows, jnp.int32), batch + (n, len(rows[0])))

        return LegMeasurement(
            q=tile(self.q, 1),
            qd=tile(self.qd, 1),
            qdd=tile(self.qdd, 1),
            tau=tile(self.tau, 1),
            M=tile(self.M, 2),
            h=tile(self.h, 1),
            J=self.J,
            Jdot_qd=self.Jdot_qd,
            p_f=self.p_f,
            v_f=self.v_f,
            foot_radius=self.foot_radius,
            leg_dofs=indices(self.leg_dofs),
            other_dofs=indices([self.other_dofs(i) for i in range(n)]),
        )


@struct.dataclass
class LegBlocks:
    """One foot's measurement as the terms read it: split by its leg's coordinates (eq. 4).

    The robot's quantities are split once into the leg's joints ``l`` and the other
    coordinates ``b`` (base and the other legs), and the noise model's per-coordinate
    standard deviations with them, so that no term indexes with the leg's coordinates:
    :func:`jax_contact.measurement.leg_blocks` splits a :class:`LegMeasurement` with its
    index arrays, :func:`jax_contact.measurement.robot_leg_blocks` a
    :class:`RobotMeasurement` with each leg's constant indices (every leaf then gains a
    leading ``n_legs`` axis, and the legs are vmapped like per-foot measurements).

    Attributes:
      M_l: (n_l, n_l) the leg's block of the mass matrix.
      M_lb: (n_l, n_b) its coupling to the other coordinates.
      tau_l, h_l, qdd_l: (n_l,) the leg's torques, bias forces and measured accelerations.
      qd_b, qdd_b: (n_b,) the other coordinates' velocities and accelerations.
      J: (3, nv) the foot point's Jacobian, every column.
      J_l: (3, n_l) its columns of the leg's joints; J_b: (3, n_b) the others.
      Jdot_qd, p_f, v_f: (3,) as in :class:`LegMeasurement`.
      foot_radius: () m.
      sigma_d_l, sigma_qdd_l, sigma_qd_prior_l: (n_l,) the noise model's ``sigma_d``,
        ``sigma_qdd`` and ``sigma_qd_prior`` of the leg's joints.
      sigma_qdd_b: (n_b,) ``sigma_qdd`` of the other coordinates.
    """

    M_l: jax.Array
    M_lb: jax.Array
    tau_l: jax.Array
    h_l: jax.Array
    qdd_l: jax.Array
    qd_b: jax.Array
    qdd_b: jax.Array
    J: jax.Array
    J_l: jax.Array
    J_b: jax.Array
    Jdot_qd: jax.Array
    p_f: jax.Array
    v_f: jax.Array
    foot_radius: jax.Array
    sigma_d_l: jax.Array
    sigma_qdd_l: jax.Array
    sigma_qd_prior_l: jax.Array
    sigma_qdd_b: jax.Array

    # The fields that come from the noise model, not from the measurement.
    NOISE_FIELDS = ("sigma_d_l", "sigma_qdd_l", "sigma_qd_prior_l", "sigma_qdd_b")


@struct.dataclass
class TerrainQuery:
    """The terrain model's answer below one foot (the paper's ``p_i`` and impact axis).

    Attributes:
      height: () mean terrain height below the foot, ``mu_pi``, m.
      sigma: () standard deviation of that height, ``sigma_pi``, m.
      normal: (3,) unit terrain normal ``e`` pointing out of the ground.
    """

    height: jax.Array
    sigma: jax.Array
    normal: jax.Array


@struct.dataclass
class LegBelief:
    """The filter's state for one foot, carried from step to step.

    The belief is kept as a logit so that it never rounds to exactly 0 or 1 (docs/model.md,
    "State and recursion"). The transition matrix for the *next* step is built from this
    step's measurements (eq. 11-17 use the measurements at ``t-1``) and stored here.

    Attributes:
      logit: () log P(C) - log P(A), the filtered contact belief ``b_t`` as a logit.
      log_transition: (2, 2) log T, rows the state at ``t`` (0 = contact C, 1 = air A),
        columns the state at ``t+1``; each row sums to one in probability.
      foothold: (3,) where this foot last stood (sole point), world frame, m; used by the
        foothold-memory terrain model.
      foothold_valid: () bool, whether ``foothold`` has been set.
    """

    logit: jax.Array
    log_transition: jax.Array
    foothold: jax.Array
    foothold_valid: jax.Array


@struct.dataclass
class Diagnostics:
    """Everything one step computed for one foot, for plots, tuning and evaluation.

    Probabilities are in [0, 1]; term probabilities are normalised, ``L(C) / (L(C) + L(A))``,
    after each term's cap.

    Attributes:
      p_contact: () fused posterior ``b_t`` (eq. 2).
      p_dynamics: () dynamics term (eq. 4-7).
      p_diff_kinematics: () differential kinematics term (eq. 8-9).
      p_kinematics: () kinematics term (eq. 10).
      p_takeoff: () P(A at t+1 | C at t), eq. 11-15.
      p_touchdown: () P(C at t+1 | A at t), eq. 16-17 and Algorithm 1.
      force: (3,) contact force the foot exerts on the ground under the contact
        hypothesis (eq. 6), world frame, N; the ground's reaction is ``-force``.
      valid: () bool, False when this step's measurement held a NaN or inf and the
        belief was propagated by the transition model alone.
    """

    p_contact: jax.Array
    p_dynamics: jax.Array
    p_diff_kinematics: jax.Array
    p_kinematics: jax.Array
    p_takeoff: jax.Array
    p_touchdown: jax.Array
    force: jax.Array
    valid: jax.Array


def all_finite(tree) -> jax.Array:
    """() bool: every floating-point leaf of ``tree`` (arrays, a list, a pytree) is finite."""
    leaves = [
        x for x in jax.tree.leaves(tree) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


@jax.named_call
def blocks_are_finite(leg: LegBlocks) -> jax.Array:
    """() bool: every measured field of one foot's :class:`LegBlocks` is finite.

    These are all the readings the foot's terms and transitions read: its rows of ``M``,
    ``tau``, ``h``, its accelerations, the other coordinates it involves (the split leaves
    another leg's joints out, :func:`jax_contact.measurement.leg_blocks`) and its own
    foot quantities. A NaN or inf elsewhere (another leg's joint, ``q``, which the terms do
    not read) leaves this foot valid. The noise model's fields are not readings.
    """
    return all_finite([x for name, x in vars(leg).items() if name not in LegBlocks.NOISE_FIELDS])


def validate_measurement(meas: LegMeasurement, nv: int | None = None) -> tuple[int, ...]:
    """Checks the shapes of a (possibly batched) measurement before anything is traced.

    Every leaf may carry the same leading batch axes (e.g. (T, n_envs, n_legs)).

    Args:
      meas: the measurement pytree, NumPy or JAX arrays.
      nv: expected number of generalised velocities, if known (e.g. from the params).

    Returns:
      The leading batch shape.

    Raises:
      ValueError: naming the field and the shapes when they disagree.
    """
    if not isinstance(meas, LegMeasurement):
        raise ValueError(f"expected a LegMeasurement, got {type(meas).__name__}")
    batch, n = _batch_and_nv(meas, nv)
    n_l = np.shape(meas.leg_dofs)[-1] if np.ndim(meas.leg_dofs) else -1
    expected = {
        "qd": (n,),
        "qdd": (n,),
        "tau": (n,),
        "M": (n, n),
        "h": (n,),
        "J": (3, n),
        "Jdot_qd": (3,),
        "p_f": (3,),
        "v_f": (3,),
        "foot_radius": (),
        "leg_dofs": (n_l,),
        "other_dofs": (n - n_l,),
    }
    _check_shapes(meas, expected, batch, f"nv = {n}, n_leg_dofs = {n_l}")
    for name in ("leg_dofs", "other_dofs"):
        x = getattr(meas, name)
        dtype = x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype  # a tracer has one
        if not np.issubdtype(dtype, np.integer):
            raise ValueError(f"measurement field {name!r} must hold integer indices")
    if n_l < 1 or n_l > n:
        raise ValueError(f"leg_dofs must hold between 1 and nv = {n} indices, got {n_l}")
    try:  # the values, where they are known (not while traced)
        legs = np.asarray(meas.leg_dofs).reshape(-1, n_l)
        others = np.asarray(meas.other_dofs).reshape(len(legs), n - n_l)
    except jax.errors.TracerArrayConversionError:
        return batch
    for leg in np.unique(legs, axis=0):
        if len(set(leg.tolist())) != n_l or not np.all((leg >= 0) & (leg < n)):
            raise ValueError(
                f"leg_dofs {leg.tolist()} must be {n_l} distinct indices into nv = {n}"
            )
    # other_dofs: the rest of range(nv), which the dynamics term's blocks of M and J are
    # taken with (an overlap or a negative index, which wraps, gave plausible wrong
    # numbers; one past nv an IndexError naming nothing).
    for row in np.unique(np.concatenate([legs, others], axis=1), axis=0):
        leg, other = row[:n_l], row[n_l:]
        if sorted(leg.tolist() + other.tolist()) != list(range(n)):
            rest = sorted(set(range(n)) - set(leg.tolist()))
            raise ValueError(
                f"other_dofs {other.tolist()} must be the nv - n_l = {n - n_l} indices of"
                f" range({n}) not in leg_dofs {leg.tolist()}: {rest}"
            )
    return batch


def _batch_and_nv(meas, nv: int | None) -> tuple[tuple[int, ...], int]:
    """(leading batch shape, nv) read from ``qd``, checked against the expected ``nv``."""
    qd = np.shape(meas.qd)
    if len(qd) < 1:
        raise ValueError(f"qd must have shape (..., nv), got {qd}")
    batch, n = qd[:-1], qd[-1]
    if nv is not None and n != nv:
        raise ValueError(f"qd has nv = {n} but the parameters were built for nv = {nv}")
    return batch, n


def _check_shapes(meas, expected: dict, batch: tuple[int, ...], what: str) -> None:
    """Raises naming the first field whose shape is not ``batch + expected[field]``."""
    for name, tail in expected.items():
        value = getattr(meas, name)
        if isinstance(value, list | tuple):  # vmap would map it as a pytree of scalars
            raise ValueError(
                f"measurement field {name!r} must be an array (NumPy or JAX), got"
                f" {type(value).__name__}"
            )
        check_real(f"measurement field {name!r}", value)
        shape = np.shape(value)
        if shape != batch + tail:
            raise ValueError(
                f"measurement field {name!r} has shape {shape}, expected {batch + tail} "
                f"(batch {batch}, {what})"
            )
    q = np.shape(meas.q)
    if q[:-1] != batch:
        raise ValueError(f"measurement field 'q' has shape {q}, expected {batch} + (nq,)")
    try:  # the values, where they are known (not while traced); NaN is a lost reading
        radius = np.asarray(meas.foot_radius, dtype=float)
    except jax.errors.TracerArrayConversionError:
        return
    if np.any(radius < 0):
        raise ValueError(
            f"measurement field 'foot_radius' must be >= 0 (m), got {radius.min()}: the sole"
            " is p_f's height minus the radius (eq. 10)"
        )


def check_real(what: str, value) -> None:
    """Raises, naming ``what``, unless ``value`` holds real numbers (float or int).

    A boolean, complex, string or object array is no reading: a bool would be read as 0
    and 1 (a torque of 1 N m) without a word, as the exported estimator refuses it.
    """
    dtype = value.dtype if hasattr(value, "dtype") else np.asarray(value).dtype
    if not (jnp.issubdtype(dtype, jnp.floating) or jnp.issubdtype(dtype, jnp.integer)):
        raise ValueError(f"{what} has dtype {dtype}; expected real numbers (float)")


def validate_robot_measurement(meas: RobotMeasurement, nv: int | None = None) -> tuple[int, ...]:
    """:func:`validate_measurement` for the per-robot layout, and its leg indices.

    Returns:
      The leading batch shape (e.g. (n_envs,) or (T, n_envs)).

    Raises:
      ValueError: naming the field and the shapes, or the leg whose indices are wrong.
    """
    if not isinstance(meas, RobotMeasurement):
        raise ValueError(f"expected a RobotMeasurement, got {type(meas).__name__}")
    batch, n = _batch_and_nv(meas, nv)
    legs = meas.leg_dofs
    if not isinstance(legs, tuple | list) or not all(isinstance(g, tuple | list) for g in legs):
        raise ValueError(
            "leg_dofs must be a tuple of per-leg tuples of int (static, e.g. ((6, 7, 8), (9, 10,"
            f" 11))), got {type(legs).__name__}; from an array a: tuple(map(tuple, a.tolist()))"
        )
    if not all(isinstance(j, int | np.integer) for g in legs for j in g):
        raise ValueError(f"leg_dofs must hold int indices, got {legs!r}")
    if not legs or len({len(leg) for leg in legs}) != 1 or not legs[0]:
        raise ValueError(f"leg_dofs must give every leg the same number (>= 1) of dofs: {legs}")
    for i, leg in enumerate(legs):
        if len(set(leg)) != len(leg) or not all(0 <= j < n for j in leg):
            raise ValueError(f"leg_dofs[{i}] = {leg} must be distinct indices into nv = {n}")
    k = len(legs)
    expected = {
        "qd": (n,),
        "qdd": (n,),
        "tau": (n,),
        "M": (n, n),
        "h": (n,),
        "J": (k, 3, n),
        "Jdot_qd": (k, 3),
        "p_f": (k, 3),
        "v_f": (k, 3),
        "foot_radius": (k,),
    }
    _check_shapes(meas, expected, batch, f"nv = {n}, {k} legs")
    return batch
