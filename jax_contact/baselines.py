"""Baseline contact detectors the estimator is compared with (docs/model.md, "The baseline").

* The generalized-momentum (GM) observer of De Luca et al., the paper's baseline (Table III):
  a first-order filter of the external joint torque, mapped to a foot force through the
  leg's Jacobian and thresholded on the ground reaction along the terrain normal.
* A kinematic threshold detector in the spirit of Hyun et al.: contact when the sole is
  close to the terrain and the foot is slow.

Like the estimator, every function here is unbatched (one foot of one robot); the
``*_batch`` helpers vmap over environments and legs at the edge. Shapes use ``nv``
generalised velocities and ``n_l`` joints of the leg.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jax_contact.types import LegMeasurement, TerrainQuery, all_finite

VELOCITY_MODES = ("norm", "normal")


# ----------------------------------------------------------------------------- validation


def _scalar_param(name: str, value, *, allow_zero: bool = False) -> jnp.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    bad = arr < 0 if allow_zero else arr <= 0
    if arr.shape != () or not np.isfinite(arr) or bad:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite scalar {bound}, got {value!r}")
    return jnp.float32(arr)


def _concrete_float(x) -> float | None:
    """``float(x)`` when ``x`` is a concrete scalar, ``None`` under tracing."""
    if isinstance(x, jax.core.Tracer):
        return None
    return float(np.asarray(x))


def check_gain(K_I, dt, owner: str = "params") -> None:
    """Refuses a GM gain the discrete observer cannot run at the period ``dt``.

    The observer's pole is ``1 - K_I dt`` (:func:`gm_step`): above ``K_I dt = 1`` it
    overshoots, above 2 it diverges (a K_I of 50 1/s on a 20 Hz log ran to 1e8 N). Does
    nothing when either value is traced.

    Args:
      K_I: () observer gain, 1/s.
      dt: () time step, s.
      owner: what holds ``K_I``, for the message (e.g. ``"gms['fast']"``).

    Raises:
      ValueError: ``K_I * dt > 1``, naming ``owner``.
    """
    k_val, dt_val = _concrete_float(K_I), _concrete_float(dt)
    if k_val is not None and dt_val is not None and k_val * dt_val > 1.0:
        raise ValueError(
            f"{owner} has K_I = {k_val:g} 1/s, and K_I dt = {k_val * dt_val:.3g} > 1 at the"
            f" readings' dt = {dt_val:g} s: the discrete observer overshoots above 1 and"
            f" diverges above 2; use K_I <= {1.0 / dt_val:g}"
        )


def _check_dt(dt, K_I=None) -> None:
    dt_val = _concrete_float(dt)
    if dt_val is None:
        return
    if np.shape(dt) != () or not np.isfinite(dt_val) or dt_val <= 0:
        raise ValueError(f"dt must be a finite scalar > 0, got {dt!r}")
    if K_I is not None:
        check_gain(K_I, dt_val)


def _check_meas(meas: LegMeasurement, lead: tuple[int, ...], name: str = "meas") -> None:
    """Checks every leaf of ``meas`` against the layout of ``types.LegMeasurement``."""
    if not isinstance(meas, LegMeasurement):
        raise ValueError(f"{name} must be a LegMeasurement, got {type(meas).__name__}")
    k = len(lead)
    qd = np.shape(meas.qd)
    if len(qd) != k + 1 or tuple(qd[:k]) != lead:
        raise ValueError(f"{name}.qd must have shape {lead + ('nv',)}, got {qd}")
    nv = qd[k]
    n_l = np.shape(meas.leg_dofs)[-1] if np.ndim(meas.leg_dofs) == k + 1 else None
    expected = {
        "qdd": (nv,),
        "tau": (nv,),
        "M": (nv, nv),
        "h": (nv,),
        "J": (3, nv),
        "Jdot_qd": (3,),
        "p_f": (3,),
        "v_f": (3,),
        "foot_radius": (),
    }
    for field, tail in expected.items():
        shape = tuple(np.shape(getattr(meas, field)))
        if shape != lead + tail:
            raise ValueError(f"{name}.{field} must have shape {lead + tail}, got {shape}")
    if n_l is None or np.shape(meas.leg_dofs)[:k] != lead or not 1 <= n_l <= nv:
        raise ValueError(
            f"{name}.leg_dofs must have shape {lead + ('n_l',)} with 1 <= n_l <= nv ({nv}),"
            f" got {np.shape(meas.leg_dofs)}"
        )
    if tuple(np.shape(meas.other_dofs)) != lead + (nv - n_l,):
        raise ValueError(
            f"{name}.other_dofs must have shape {lead + (nv - n_l,)}, got"
            f" {np.shape(meas.other_dofs)}"
        )
    for field in ("leg_dofs", "other_dofs"):
        if not jnp.issubdtype(jnp.asarray(getattr(meas, field)).dtype, jnp.integer):
            raise ValueError(f"{name}.{field} must hold integers")


def _lead_shape(meas: LegMeasurement, n: int, name: str = "meas") -> tuple[int, ...]:
    shape = tuple(np.shape(meas.p_f))
    if len(shape) != n + 1:
        raise ValueError(f"{name}.p_f must have {n} leading axes and a last axis of 3, got {shape}")
    return shape[:-1]


def _check_normal(normal, lead: tuple[int, ...], name: str = "normal") -> jax.Array:
    """Broadcasts ``normal`` to ``lead + (3,)``; a single (3,) serves every step and leg."""
    shape = tuple(np.shape(normal))
    if shape != (3,) and shape != lead + (3,):
        raise ValueError(f"{name} must have shape (3,) or {lead + (3,)}, got {shape}")
    return jnp.broadcast_to(jnp.asarray(normal), lead + (3,))


# ------------------------------------------------------------------ generalized momentum


@struct.dataclass
class GMParams:
    """The two knobs of the GM observer, plus the damping of its force map.

    Attributes:
      K_I: () observer gain, 1/s; the residual follows the external torque with time
        constant ``1 / K_I`` (``K_I dt = 1`` is the unfiltered estimate of Focchi et al.).
      threshold: () ground-reaction force along the terrain normal above which the foot is
        flagged in contact, N.
      damping: () Tikhonov damping of the least-squares force map, in units of ``J^2``
        (m^2 for revolute legs), so that a stretched (singular) leg gives a finite force.
    """

    K_I: jnp.ndarray
    threshold: jnp.ndarray
    damping: jnp.ndarray


def make_gm_params(K_I: float = 50.0, threshold: float = 20.0, damping: float = 1e-6) -> GMParams:
    """Builds and validates :class:`GMParams`.

    The paper tunes ``K_I`` and the threshold per gait and does not print them; the defaults
    (20 ms time constant, 20 N) are a starting point for a ~30 kg quadruped, not its values.

    Raises:
      ValueError: naming the field, for a non-finite or non-positive value.
    """
    params = GMParams(
        K_I=_scalar_param("K_I", K_I),
        threshold=_scalar_param("threshold", threshold),
        damping=_scalar_param("damping", damping),
    )
    validate_gm_params(params)
    return params


def validate_gm_params(params: GMParams) -> None:
    """Raises ``ValueError`` naming the field if one is not a finite scalar > 0."""
    for name in ("K_I", "threshold", "damping"):
        _scalar_param(name, getattr(params, name))


@struct.dataclass
class GMState:
    """What the observer carries from step to step, for one foot.

    Attributes:
      p0: (n_l,) leg momentum ``(M qd)[leg_dofs]`` at the first measurement, N m s.
      integral: (n_l,) the running sum in :func:`gm_step`'s residual, N m s.
      residual: (n_l,) the last residual ``r``, the external joint torque estimate, N m.
      M_prev: (n_l, nv) leg rows of the previous mass matrix, for ``Mdot qd``.
      force: (3,) last force estimate (held across invalid steps), N.
      force_normal: () last ground-reaction normal force, N.
      held: () int32, invalid steps since the last update: the next valid one integrates
        over all of them (``(held + 1) dt``), as the momentum it reads has moved over them.
    """

    p0: jax.Array
    integral: jax.Array
    residual: jax.Array
    M_prev: jax.Array
    force: jax.Array
    force_normal: jax.Array
    held: jax.Array


@struct.dataclass
class GMOutput:
    """One step of the GM observer for one foot.

    Attributes:
      residual: (n_l,) estimated external joint torque of the leg, ``-J_fl^T F``, N m.
      force: (3,) least-squares estimate of the force the foot exerts on the ground, N.
      force_normal: () ground reaction on the foot along the terrain normal, ``-e . F``, N.
      contact: () bool, ``force_normal > threshold``.
      valid: () bool, False when the measurement held a NaN or inf and the state was held.
    """

    residual: jax.Array
    force: jax.Array
    force_normal: jax.Array
    contact: jax.Array
    valid: jax.Array


def _leg_readings(meas: LegMeasurement):
    """What the observer reads for one foot: the leg's rows of ``M``, the velocities they
    involve, the leg's Jacobian columns, and whether all of it (with the leg's ``tau``
    and ``h``) is finite.

    A coordinate that the leg's rows of ``M`` do not involve (another leg's joint: an exact
    zero in a kinematic tree) is read as 0, so another leg's NaN stays in that leg, as in
    the estimator's split (:func:`jax_contact.measurement.leg_blocks`).

    Returns:
      (rows (n_l, nv), qd (nv,), J_l (3, n_l), finite () bool).
    """
    l = meas.leg_dofs
    rows = meas.M[l]
    qd = jnp.where(jnp.any(rows != 0, axis=0), meas.qd, 0.0)
    J_l = meas.J[:, l]
    return rows, qd, J_l, all_finite((rows, qd, J_l, meas.tau[l], meas.h[l]))


def gm_init(meas: LegMeasurement) -> GMState:
    """Starts the observer at the first measurement (residual 0, ``p_0 = (M qd)[leg]``).

    Args:
      meas: unbatched measurement of one foot; what it reads (:func:`_leg_readings`)
        must be finite.
    """
    _check_meas(meas, ())
    rows, qd, _, _ = _leg_readings(meas)
    n_l = rows.shape[0]
    zero = jnp.zeros((n_l,), rows.dtype)
    return GMState(
        p0=rows @ qd,
        integral=zero,
        residual=zero,
        M_prev=rows,
        force=jnp.zeros((3,), rows.dtype),
        force_normal=jnp.zeros((), rows.dtype),
        held=jnp.zeros((), jnp.int32),
    )


def _foot_force(J_l: jax.Array, residual: jax.Array, damping: jax.Array) -> jax.Array:
    """Damped least squares of ``J_l^T F = -r`` through the SVD ``J_l = U S V^T``.

    ``F = -U diag(s / (s^2 + damping)) V^T r``, the same as ``-(J_l J_l^T + damping I)^-1 J_l r``
    but without inverting a rank-deficient 3 x 3 matrix: a 2-joint (planar) leg spans two
    axes, and its third gets zero force rather than round-off amplified by ``1/damping``.
    """
    u, s, vt = jnp.linalg.svd(J_l, full_matrices=False)
    return -u @ ((s / (s * s + damping)) * (vt @ residual))


def _zero_if_not(ok: jax.Array, state: GMState) -> GMState:
    """``state``, or zeros where ``ok`` is False (a start from a non-finite reading)."""
    return jax.tree.map(lambda x: jnp.where(ok, x, jnp.zeros_like(x)), state)


def gm_step(
    params: GMParams, state: GMState, meas: LegMeasurement, dt, normal: jax.Array
) -> tuple[GMState, GMOutput]:
    """One step of the generalized-momentum observer for one foot.

    De Luca's residual, restricted to the leg's rows ``l`` (which hold on their own, so legs
    are independent and vmap), discretised with the rectangle rule at the step's end::

        r_k = K_I (p_k - p_0 - S_k),
        S_k = S_{k-1} + (tau_k + C^T qd_k - g_k + r_{k-1}) dt,        p = (M qd)_l

    The measurement gives ``h = C qd + g``, not ``C^T qd``; since ``Mdot = C + C^T``,
    ``C^T qd - g = Mdot qd - h``, and ``Mdot qd`` is approximated by the backward
    difference ``(M_k - M_{k-1}) qd_k / dt`` (so its ``dt`` cancels in ``S``). With
    ``qd_k = qd_{k-1} + qdd_k dt`` and the equation of motion at step k, ``M qdd + h + J^T F
    = tau``, ``p_k - p_{k-1} = (tau_k - h_k - J^T F_k + Mdot qd_k) dt`` to first order, so
    ``r`` is a first-order low-pass of ``-J_fl^T F`` with pole ``1 - K_I dt``.

    The foot force is the damped least-squares solution of ``J_fl^T F = -r`` (see
    ``_foot_force``); the ground's reaction on the foot is ``-F`` (docs/model.md, "Sign"), so the
    contact flag is ``-e . F > threshold``.

    A measurement with a NaN or inf in what this foot's observer reads (the leg's rows of
    ``M``, ``tau`` and ``h``, the velocities those rows involve, the leg's Jacobian
    columns, and ``normal``; not another leg's joints) leaves the state unchanged and
    repeats the last force. The next finite one catches up over the ``n`` steps since the
    last update as ``n`` steps of the observer would with the readings held constant: the
    residual moves by ``1 - (1 - K_I dt)^n`` of the way to the gap's external torque, not by
    one step's ``K_I n dt`` of it (which overshoots once it exceeds 1).

    Args:
      params: the observer's knobs.
      state: from :func:`gm_init` or the previous step.
      meas: unbatched measurement of one foot at step k.
      dt: () time step, s.
      normal: (3,) unit terrain normal ``e`` below the foot, out of the ground.

    Returns:
      The new state and this step's :class:`GMOutput`.
    """
    _check_meas(meas, ())
    if np.shape(normal) != (3,):
        raise ValueError(f"normal must have shape (3,), got {np.shape(normal)}")
    l = meas.leg_dofs
    rows, qd, J_l, finite = _leg_readings(meas)
    p = rows @ qd
    # (M_k - M_{k-1}) qd_k ~ Mdot qd dt: the C^T qd - g = Mdot qd - h identity.
    mdot_qd_dt = (rows - state.M_prev) @ qd
    # After lost readings the momentum p has moved over every step since the last update:
    # the integral advances over as long (the readings held constant), not one step, which
    # left a spike of K_I times the gap's momentum change (22 N after 3 lost readings of a
    # swinging leg, a helper's audit; 0.2 N this way).
    n = (state.held + 1).astype(rows.dtype)
    integral = state.integral + (meas.tau[l] - meas.h[l] + state.residual) * n * dt + mdot_qd_dt
    residual = params.K_I * (p - state.p0 - integral)
    # That is r_prev + K_I n dt (tau_ext - r_prev): one step's gain over the whole gap,
    # which overshoots once K_I n dt > 1 (173 N for 60 N after 30 lost readings at K_I 40,
    # a helper's audit). n steps of the observer with the gap's readings held give the gain
    # 1 - (1 - K_I dt)^n; the integral is set to match the residual it gives.
    a = jnp.asarray(params.K_I, rows.dtype) * jnp.asarray(dt, rows.dtype)  # the readings' precision
    gain = -jnp.expm1(n * jnp.log1p(-jnp.minimum(a, 1.0))) / (a * n)
    caught_up = state.residual + gain * (residual - state.residual)
    after_gap = state.held > 0
    residual = jnp.where(after_gap, caught_up, residual)
    integral = jnp.where(after_gap, p - state.p0 - residual / params.K_I, integral)
    force = _foot_force(J_l, residual, params.damping)
    force_normal = -jnp.dot(normal, force)

    valid = finite & jnp.all(jnp.isfinite(normal))
    new = GMState(
        p0=state.p0,
        integral=integral,
        residual=residual,
        M_prev=rows,
        force=force,
        force_normal=force_normal,
        held=jnp.zeros((), jnp.int32),
    )
    state = jax.tree.map(
        lambda a, b: jnp.where(valid, a, b), new, state.replace(held=state.held + 1)
    )
    out = GMOutput(
        residual=state.residual,
        force=state.force,
        force_normal=state.force_normal,
        contact=state.force_normal > params.threshold,
        valid=valid,
    )
    return state, out


def gm_run(params: GMParams, meas_seq: LegMeasurement, dt, normal: jax.Array) -> GMOutput:
    """Runs the observer over a sequence of one foot's measurements.

    The first measurement initialises the observer (:func:`gm_init`), so the output at
    step 0 has residual and force 0 and no contact; steps 1.. are :func:`gm_step`. If the
    first measurements hold a NaN or inf, the observer starts at the first finite one:
    the steps before it are invalid (``valid`` False, zero output).

    Args:
      params: the observer's knobs.
      meas_seq: measurements with a leading time axis T >= 1 on every leaf.
      dt: () time step, s; ``K_I * dt`` must be at most 1.
      normal: (3,) or (T, 3) terrain normal.

    Returns:
      :class:`GMOutput` with a leading T axis on every leaf.

    Raises:
      ValueError: naming the argument, for inconsistent shapes, ``dt <= 0`` or
        ``K_I * dt > 1``.
    """
    lead = _lead_shape(meas_seq, 1, "meas_seq")
    _check_meas(meas_seq, lead, "meas_seq")
    normal = _check_normal(normal, lead)
    _check_dt(dt, params.K_I)
    return _gm_scan(params, meas_seq, dt, normal)


def _gm_start(meas: LegMeasurement) -> tuple[GMState, GMOutput]:
    """The observer started at ``meas`` (:func:`gm_init`) and its output there: zero
    residual and force, no contact, valid iff what it reads is finite (else a zero state)."""
    ok = _leg_readings(meas)[3]
    state = _zero_if_not(ok, gm_init(meas))
    out = GMOutput(
        residual=state.residual,
        force=state.force,
        force_normal=state.force_normal,
        contact=jnp.zeros((), bool),
        valid=ok,
    )
    return state, out


def _gm_scan(params, meas_seq, dt, normal):
    """:func:`gm_run` without its checks. The observer starts at the first finite
    measurement (step 0 if it is finite): until then every step is invalid, with zero
    output, and a first reading holding a NaN cannot seed ``p_0`` with it."""
    state, out0 = _gm_start(jax.tree.map(lambda x: x[0], meas_seq))
    rest = jax.tree.map(lambda x: x[1:], (meas_seq, normal))

    def body(carry, xs):
        s, started = carry
        m, n = xs
        stepped, out = gm_step(params, s, m, dt, n)
        # Not started yet: this step (re)starts the observer if its reading is finite.
        fresh, restart = _gm_start(m)
        s, out = jax.tree.map(
            lambda a, b: jnp.where(started, a, b), (stepped, out), (fresh, restart)
        )
        return (s, started | restart.valid), out

    _, outs = jax.lax.scan(body, (state, out0.valid), rest)
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), out0, outs)


def gm_run_batch(params: GMParams, meas_seq: LegMeasurement, dt, normal: jax.Array) -> GMOutput:
    """:func:`gm_run` for every env and leg, time leading: inputs (T, E, L, ...).

    Args:
      params: shared by every env and leg.
      meas_seq: measurements with leading axes (T, E, L) on every leaf.
      dt: () time step, s.
      normal: (3,) shared, or (T, E, L, 3).

    Returns:
      :class:`GMOutput` with leading axes (T, E, L).
    """
    lead = _lead_shape(meas_seq, 3, "meas_seq")
    _check_meas(meas_seq, lead, "meas_seq")
    normal = _check_normal(normal, lead)
    _check_dt(dt, params.K_I)
    per_leg = jax.vmap(_gm_scan, in_axes=(None, 1, None, 1), out_axes=1)
    per_env = jax.vmap(per_leg, in_axes=(None, 1, None, 1), out_axes=1)
    return per_env(params, meas_seq, dt, normal)


# ------------------------------------------------------------------ kinematic threshold


@struct.dataclass
class KinematicParams:
    """Thresholds of the kinematic detector.

    Attributes:
      height_threshold: () largest sole gap above the terrain still called contact, m.
      velocity_threshold: () largest foot speed still called contact, m/s.
      velocity_mode: static; ``"norm"`` thresholds the foot's speed ``|v_f|``,
        ``"normal"`` only its component along the terrain normal, ``|e . v_f|`` (for feet
        that slide on the ground).
    """

    height_threshold: jnp.ndarray
    velocity_threshold: jnp.ndarray
    velocity_mode: str = struct.field(pytree_node=False, default="norm")


def make_kinematic_params(
    height_threshold: float = 0.02,
    velocity_threshold: float = 0.3,
    velocity_mode: str = "norm",
) -> KinematicParams:
    """Builds and validates :class:`KinematicParams` (defaults: 2 cm, 0.3 m/s, ``"norm"``).

    Raises:
      ValueError: naming the field, for a non-positive threshold or an unknown mode.
    """
    params = KinematicParams(
        height_threshold=_scalar_param("height_threshold", height_threshold),
        velocity_threshold=_scalar_param("velocity_threshold", velocity_threshold),
        velocity_mode=velocity_mode,
    )
    validate_kinematic_params(params)
    return params


def validate_kinematic_params(params: KinematicParams) -> None:
    """Raises ``ValueError`` naming the first bad field."""
    for name in ("height_threshold", "velocity_threshold"):
        _scalar_param(name, getattr(params, name))
    if params.velocity_mode not in VELOCITY_MODES:
        raise ValueError(
            f"velocity_mode must be one of {VELOCITY_MODES}, got {params.velocity_mode!r}"
        )


@struct.dataclass
class KinematicOutput:
    """One step of the kinematic detector for one foot.

    Attributes:
      gap: () sole gap above the terrain along the normal, m (negative: penetration).
      speed: () the thresholded speed, m/s.
      contact: () bool.
    """

    gap: jax.Array
    speed: jax.Array
    contact: jax.Array


def _check_terrain_query(terrain) -> None:
    """The detector reads a terrain *answer* below each foot, not a terrain model."""
    if not isinstance(terrain, TerrainQuery):
        hint = (
            ": a terrain model answers with .query(p_f, foothold, foothold_valid), or build"
            " TerrainQuery(height=..., sigma=..., normal=...)"
            if callable(getattr(terrain, "query", None))
            else ""
        )
        raise ValueError(f"terrain must be a TerrainQuery, got {type(terrain).__name__}{hint}")


def kinematic_detect(
    params: KinematicParams, meas: LegMeasurement, terrain: TerrainQuery
) -> KinematicOutput:
    """Contact when the sole is near the terrain and the foot is slow.

    The gap is measured as in eq. 10: from the terrain point ``p_i`` below the foot centre
    (at ``terrain.height``) to the sole ``p_f - r e``, along ``e``:
    ``e . (p_f - r e - p_i) = e_z (z_f - height) - r``, the distance of a sphere foot from the
    local terrain plane. Contact iff ``gap < height_threshold`` and ``speed <
    velocity_threshold``.

    Args:
      params: the thresholds.
      meas: unbatched measurement of one foot (``p_f``, ``v_f``, ``foot_radius`` are used).
      terrain: unbatched terrain answer below the foot.
    """
    _check_meas(meas, ())
    _check_terrain_query(terrain)
    e = terrain.normal
    gap = e[2] * (meas.p_f[2] - terrain.height) - meas.foot_radius
    if params.velocity_mode == "norm":
        # The floor keeps the gradient of the norm finite for a foot at rest.
        speed = jnp.sqrt(jnp.maximum(jnp.sum(meas.v_f**2), 1e-30))
    else:
        speed = jnp.abs(jnp.dot(e, meas.v_f))
    contact = (gap < params.height_threshold) & (speed < params.velocity_threshold)
    return KinematicOutput(gap=gap, speed=speed, contact=contact)


def kinematic_detect_batch(
    params: KinematicParams, meas: LegMeasurement, terrain: TerrainQuery
) -> KinematicOutput:
    """:func:`kinematic_detect` over any leading axes, e.g. (T, E, L).

    Args:
      params: shared thresholds.
      meas: measurements whose leaves share leading axes ``B`` (those of ``p_f[..., 0]``).
      terrain: answers with leading axes ``B``, or one unbatched answer shared by all.

    Returns:
      :class:`KinematicOutput` with leading axes ``B``.
    """
    lead = tuple(np.shape(meas.p_f))[:-1]
    _check_meas(meas, lead)
    _check_terrain_query(terrain)
    for field, tail in (("height", ()), ("sigma", ()), ("normal", (3,))):
        shape = tuple(np.shape(getattr(terrain, field)))
        if shape not in (tail, lead + tail):
            raise ValueError(
                f"terrain.{field} must have shape {tail} or {lead + tail}, got {shape}"
            )
    n = int(np.prod(lead, dtype=np.int64))
    flat_meas = jax.tree.map(lambda x: jnp.reshape(x, (n,) + np.shape(x)[len(lead) :]), meas)
    flat_terrain = TerrainQuery(
        height=jnp.reshape(jnp.broadcast_to(terrain.height, lead), (n,)),
        sigma=jnp.reshape(jnp.broadcast_to(terrain.sigma, lead), (n,)),
        normal=jnp.reshape(jnp.broadcast_to(terrain.normal, lead + (3,)), (n, 3)),
    )
    out = jax.vmap(kinematic_detect, in_axes=(None, 0, 0))(params, flat_meas, flat_terrain)
    return jax.tree.map(lambda x: jnp.reshape(x, lead + np.shape(x)[1:]), out)
