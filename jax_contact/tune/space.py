"""What is tuned: the fields, their groups and the unconstrained ``theta`` (module
``jax_contact.tune``'s docstring)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact.params import EstimatorParams, NoiseParams
from jax_contact.tune.config import check_noise_ratio

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
# --tune-also contact_damping``), in log space like ``a_F``: ``jax_contact.tune``'s docstring.
OPTIONAL_FIELDS = ("contact_damping",)
TUNABLE_FIELDS = DEFAULT_FIELDS + OPTIONAL_FIELDS
SCALAR_FIELDS = CAP_FIELDS + LOG_FIELDS + OPTIONAL_FIELDS
# Axis groups of the per-axis noise fields: sigma_f horizontal (x, y) and normal (z).
AXIS_GROUPS = {"sigma_f": ((0, 0, 1), ("horizontal", "normal")), "sigma_J": ((0, 0, 0), ("xyz",))}
# Where a cap of exactly 1 (unbounded) is the starting point, it starts just below.
_CAP_MAX = 1.0 - 1e-6
# The interval T_s is tuned in, s (``jax_contact.tune``'s docstring: what a plausible T_s is).
STANCE_TIME_BOUNDS = (0.15, 1.2)
BOUNDED_FIELDS = ("stance_time",)
# How far from its derived value a tuned std stays physically plausible: the standing check
# of every shipped preset (docs/tuning.md), and the box ``TuneConfig.noise_ratio`` makes of it.
PLAUSIBLE_NOISE_RATIO = 8.0


# ----------------------------------------------------------------------- the search space


@dataclasses.dataclass(frozen=True)
class ParamSpace:
    """Which parameters are tuned and how the ``nv`` coordinates are tied (static).

    Attributes:
      fields: names of tuned fields, among :data:`TUNABLE_FIELDS`.
      dof_groups: (nv,) the group of each generalised coordinate.
      group_names: a name per coordinate group (for reports).
      stance_time_bounds: (lo, hi), s: the interval ``T_s`` is tuned in (a hard bound,
        :data:`STANCE_TIME_BOUNDS` by default; ``jax_contact.tune``'s docstring).
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

    def named_groups(self) -> dict[str, list[int]]:
        """Group name -> its coordinates, as a tuned file's provenance (``"groups"``)
        records them and ``jax_contact.params_file.load_params_for`` compares them."""
        return {
            name: [i for i, g in enumerate(self.dof_groups) if g == k]
            for k, name in enumerate(self.group_names)
        }

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


def theta_bounds(
    space: ParamSpace, base: EstimatorParams, floor: dict | None, noise_ratio: float = 0.0
) -> tuple[dict[str, jax.Array], dict[str, jax.Array]]:
    """Lower and upper bounds on ``theta``: the floors, and a plausibility box on the noise.

    With ``noise_ratio = r > 1`` every tuned noise multiplier stays within ``[1/r, r]`` of
    its derived value, ``-log r <= theta_g <= log r`` (the floor, when higher, wins below:
    it is at most 0, :func:`theta_lower_bounds`). Caps, ``T_s``, ``a_F`` and the damping
    are not boxed (their own parameterisation bounds the caps and ``T_s``).

    Args:
      space: what is tuned.
      base: the untuned parameters (``sigma^0``).
      floor: as in :func:`theta_lower_bounds`.
      noise_ratio: ``r``; 0 boxes nothing.

    Returns:
      (lower, upper), each ``theta``'s structure in float32, ``-inf`` / ``+inf`` where
      unbounded.

    Raises:
      ValueError: ``noise_ratio`` neither 0 nor > 1, or a bad floor
        (:func:`theta_lower_bounds`).
    """
    r = check_noise_ratio(noise_ratio)
    lower = theta_lower_bounds(space, base, floor)
    upper = {f: jnp.full_like(v, jnp.inf) for f, v in lower.items()}
    if r > 0:
        bound = np.float32(np.log(r))
        for f in lower:
            if f in NOISE_FIELDS:
                lower[f] = jnp.maximum(lower[f], -bound)
                upper[f] = jnp.full_like(lower[f], bound)
    return lower, upper
