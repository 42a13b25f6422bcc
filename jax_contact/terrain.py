"""Terrain models for the kinematics term and the touch-down transition (eq. 10, 16-17).

A terrain model answers, for a foot at a horizontal position, the mean height of the terrain
below it, that height's standard deviation (the paper's ``sigma_pi``) and the unit normal
``e`` that points out of the ground (the impact axis). Every model is a frozen pytree with a
``query`` method, so it can be passed through ``jit`` and shared by every env of a ``vmap``
(``in_axes=None``), and a ``remember`` method: the foothold the filter keeps in each foot's
belief after a confident, still stance step (only :class:`FootholdMemory` reads it back).

Models:
  * :class:`FlatTerrain`: a plane of known height and a height variance (the paper's choice
    on ANYmal; ``sigma_pi`` = 0.2 m in its simulation).
  * :class:`HeightFieldTerrain`: a grid of heights with a variance, bilinearly interpolated.
  * :class:`FootholdMemory`: the height where the foot last stood, with a variance growing
    with horizontal distance from that foothold (the paper's "conservative estimate"),
    falling back to another model before the first foothold.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jax_contact.types import TerrainQuery

_UP = (0.0, 0.0, 1.0)


@struct.dataclass
class FlatTerrain:
    """A horizontal plane.

    Attributes:
      height: () plane height, m.
      sigma: () standard deviation of the height, m.
    """

    height: jax.Array
    sigma: jax.Array

    def query(self, p: jax.Array, foothold: jax.Array, foothold_valid: jax.Array) -> TerrainQuery:
        """Answers for a foot at ``p`` (3,); the foothold arguments are unused."""
        del p, foothold, foothold_valid
        return TerrainQuery(
            height=self.height, sigma=self.sigma, normal=jnp.asarray(_UP, dtype=jnp.float32)
        )

    def remember(self, foothold: jax.Array, foothold_valid: jax.Array, sole: jax.Array):
        """The sole point (3,) itself (kept for the diagnostics; a plane does not read it)."""
        return _keep_sole(foothold, foothold_valid, sole)


@struct.dataclass
class HeightFieldTerrain:
    """A regular grid of terrain heights, bilinearly interpolated, clamped at its borders.

    Cell ``heights[iy, ix]`` is at ``origin + (ix * spacing[0], iy * spacing[1])``, the
    layout of a MuJoCo height field's elevation data (rows along y).

    Attributes:
      heights: (ny, nx) terrain heights, m.
      origin: (2,) world x, y of ``heights[0, 0]``, m.
      spacing: (2,) grid spacing along x and y, m.
      sigma: () standard deviation of the interpolated height, m.
    """

    heights: jax.Array
    origin: jax.Array
    spacing: jax.Array
    sigma: jax.Array

    def _height(self, xy: jax.Array) -> jax.Array:
        ny, nx = self.heights.shape
        g = (xy - self.origin) / self.spacing
        gx = _clamp(g[0], 0.0, nx - 1.0)
        gy = _clamp(g[1], 0.0, ny - 1.0)
        ix = jnp.clip(jnp.floor(gx).astype(jnp.int32), 0, max(nx - 2, 0))
        iy = jnp.clip(jnp.floor(gy).astype(jnp.int32), 0, max(ny - 2, 0))
        fx = gx - ix
        fy = gy - iy
        ix1 = jnp.minimum(ix + 1, nx - 1)
        iy1 = jnp.minimum(iy + 1, ny - 1)
        h00 = self.heights[iy, ix]
        h01 = self.heights[iy, ix1]
        h10 = self.heights[iy1, ix]
        h11 = self.heights[iy1, ix1]
        return (1 - fy) * ((1 - fx) * h00 + fx * h01) + fy * ((1 - fx) * h10 + fx * h11)

    def query(self, p: jax.Array, foothold: jax.Array, foothold_valid: jax.Array) -> TerrainQuery:
        """Answers for a foot at ``p`` (3,): interpolated height and the surface normal."""
        del foothold, foothold_valid
        xy = p[:2]
        height, grad = jax.value_and_grad(self._height)(xy)
        normal = jnp.array([-grad[0], -grad[1], 1.0])
        normal = normal / jnp.linalg.norm(normal)
        return TerrainQuery(height=height, sigma=self.sigma, normal=normal)

    def remember(self, foothold: jax.Array, foothold_valid: jax.Array, sole: jax.Array):
        """The sole point (3,) itself (kept for the diagnostics; the grid does not read it)."""
        return _keep_sole(foothold, foothold_valid, sole)


def _keep_sole(foothold, foothold_valid, sole):
    del foothold, foothold_valid
    return sole


def _clamp(x: jax.Array, lo: float, hi: float) -> jax.Array:
    """``x`` held inside ``[lo, hi]``, with derivative 1 on the closed interval (``jnp.clip``'s
    is 0.5 at a bound, which halved the normal's slope on the grid's border) and 0 outside
    it (the surface is continued flat beyond the grid)."""
    return jnp.where(x < lo, lo, jnp.where(x > hi, hi, x))


@struct.dataclass
class FootholdMemory:
    """The height where this foot last stood, trusted less the farther the foot has moved.

    ``sigma^2 = sigma_foothold^2 + (growth * d_xy)^2``, with ``d_xy`` the horizontal distance
    from the remembered foothold, never more than the fallback's ``sigma``. Before the first
    foothold, or when the fallback is sharper, the fallback model answers.

    The remembered height is the sole's, measured through the base-state estimate: it moves
    with that estimate's drift, which is what makes it useful where the base position
    drifts (a plane at the true floor height does not: docs/model_choices.md, "Base drift and
    the kinematics term"). ``smoothing`` < 1 averages it over the stance steps,
    ``z <- (1 - smoothing) z + smoothing z_sole`` (an exponential average, about
    ``1 / smoothing`` steps long, that also averages the estimate's white noise), the
    horizontal position always the newest sole's; 1 keeps the newest sole (no averaging).

    Attributes:
      fallback: a terrain model (flat or height field) used before the first foothold.
      sigma_foothold: () height uncertainty at the foothold itself, m.
      growth: () growth of the height's standard deviation per metre of horizontal
        distance, m/m (a slope bound of the terrain).
      smoothing: () weight of the newest sole height in the remembered one, in (0, 1].
    """

    fallback: FlatTerrain | HeightFieldTerrain
    sigma_foothold: jax.Array
    growth: jax.Array
    smoothing: jax.Array = struct.field(default_factory=lambda: jnp.float32(1.0))

    def query(self, p: jax.Array, foothold: jax.Array, foothold_valid: jax.Array) -> TerrainQuery:
        """Answers for a foot at ``p`` (3,) that last stood at ``foothold`` (3,)."""
        base = self.fallback.query(p, foothold, foothold_valid)
        d2 = jnp.sum(jnp.square(p[:2] - foothold[:2]))
        sigma = jnp.sqrt(jnp.square(self.sigma_foothold) + jnp.square(self.growth) * d2)
        use = foothold_valid & (sigma < base.sigma)
        return TerrainQuery(
            height=jnp.where(use, foothold[2], base.height),
            sigma=jnp.where(use, sigma, base.sigma),
            normal=base.normal,
        )

    def remember(self, foothold: jax.Array, foothold_valid: jax.Array, sole: jax.Array):
        """The foothold (3,) after a stance step at ``sole`` (3,): its height averaged."""
        a = self.smoothing
        z = jnp.where(foothold_valid, (1.0 - a) * foothold[2] + a * sole[2], sole[2])
        return sole.at[2].set(z)


def _positive(name: str, value) -> jax.Array:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != () or not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite scalar > 0, got {value!r}")
    return jnp.float32(v)


def flat(height: float = 0.0, sigma: float = 0.2) -> FlatTerrain:
    """A validated :class:`FlatTerrain`: the plane ``z = height`` (m, world frame) with height
    std ``sigma`` (m; 0.2 m as in the paper's Section III).

    A traced value (``height`` or ``sigma`` under ``jit``, ``vmap`` or ``grad``) is taken as
    it is, unchecked, so the terrain can be batched or differentiated; a concrete one is
    checked.
    """
    if isinstance(height, jax.core.Tracer):
        h = jnp.asarray(height)
    else:
        v = np.asarray(height, dtype=np.float64)
        if v.shape != () or not np.isfinite(v):
            raise ValueError(f"height must be a finite scalar, got {height!r}")
        h = jnp.float32(v)
    s = jnp.asarray(sigma) if isinstance(sigma, jax.core.Tracer) else _positive("sigma", sigma)
    return FlatTerrain(height=h, sigma=s)


def height_field(heights, origin, spacing, sigma: float = 0.02) -> HeightFieldTerrain:
    """A validated :class:`HeightFieldTerrain`.

    Args:
      heights: (ny, nx) heights, m, ny and nx >= 2, all finite.
      origin: (2,) world x, y of ``heights[0, 0]``, m.
      spacing: (2,) positive grid spacing, m.
      sigma: standard deviation of the interpolated height, m.
    """
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"heights must have shape (ny, nx) with ny, nx >= 2, got {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError("heights must be finite everywhere")
    o = np.asarray(origin, dtype=np.float64)
    s = np.asarray(spacing, dtype=np.float64)
    if o.shape != (2,):
        raise ValueError(f"origin must have shape (2,), got {o.shape}")
    if s.shape != (2,) or np.any(s <= 0):
        raise ValueError(f"spacing must have shape (2,) and be > 0, got {spacing!r}")
    return HeightFieldTerrain(
        heights=jnp.asarray(h, jnp.float32),
        origin=jnp.asarray(o, jnp.float32),
        spacing=jnp.asarray(s, jnp.float32),
        sigma=_positive("sigma", sigma),
    )


def foothold_memory(
    fallback: FlatTerrain | HeightFieldTerrain,
    sigma_foothold: float = 0.02,
    growth: float = 0.3,
    smoothing: float = 1.0,
) -> FootholdMemory:
    """A validated :class:`FootholdMemory` over ``fallback``.

    Raises:
      ValueError: naming the argument: a fallback of another kind, a non-positive
        ``sigma_foothold`` or ``growth``, a ``smoothing`` outside (0, 1].
    """
    if not isinstance(fallback, FlatTerrain | HeightFieldTerrain):
        raise ValueError(
            f"fallback must be a FlatTerrain or HeightFieldTerrain, got {type(fallback).__name__}"
        )
    a = _positive("smoothing", smoothing)
    if float(a) > 1.0:
        raise ValueError(f"smoothing must be in (0, 1], got {smoothing!r}")
    return FootholdMemory(
        fallback=fallback,
        sigma_foothold=_positive("sigma_foothold", sigma_foothold),
        growth=_positive("growth", growth),
        smoothing=a,
    )


def validate_terrain(terrain, name: str | None = None) -> None:
    """Checks a terrain model's concrete values as its constructor does (:func:`flat`,
    :func:`height_field`, :func:`foothold_memory`): a model built directly from its class
    (``jc.FlatTerrain(height=nan, sigma=-1)``) skipped them, and every update of a NaN
    plane was skipped while the wrapper's score read 1.0. Traced values are not read.

    Args:
      terrain: a terrain model.
      name: how the message names it (default: its class, e.g. ``FlatTerrain``).

    Raises:
      ValueError: naming the field, e.g. ``"FlatTerrain.height must be a finite scalar"``.
    """
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(terrain)):
        return
    name = type(terrain).__name__ if name is None else name
    if isinstance(terrain, FootholdMemory):
        validate_terrain(terrain.fallback, f"{name}.fallback")
    try:
        if isinstance(terrain, FlatTerrain):
            flat(terrain.height, terrain.sigma)
        elif isinstance(terrain, HeightFieldTerrain):
            height_field(terrain.heights, terrain.origin, terrain.spacing, terrain.sigma)
        elif isinstance(terrain, FootholdMemory):
            foothold_memory(
                terrain.fallback, terrain.sigma_foothold, terrain.growth, terrain.smoothing
            )
    except ValueError as err:
        raise ValueError(f"{name}.{err}") from None


# ------------------------------------------------------------------------ named models

# The terrain models a parameter file can name (``provenance["terrain_model"]``, written by
# ``jax-contact tune --terrain-model`` and ``tune-env``), rebuilt from that name over the
# floor's plane by every entry point (the log commands, the reproduction, the wrapper):
# ``"flat"``, the plane itself; ``"memory"``, the height where each foot last stood (its
# stance average) over that plane (docs/model_choices.md, "Base drift and the kinematics
# term").
TERRAIN_MODELS = ("flat", "memory")

# The memory's sigma at the foothold (m), its growth per metre walked, the stance average's
# weight.
FOOTHOLD_MEMORY = dict(sigma_foothold=0.02, growth=0.3, smoothing=0.05)


def check_terrain_model(terrain_model: str) -> None:
    """Raises ValueError unless ``terrain_model`` is one of :data:`TERRAIN_MODELS`."""
    if terrain_model not in TERRAIN_MODELS:
        raise ValueError(f"terrain_model must be one of {TERRAIN_MODELS}, got {terrain_model!r}")


def terrain_for(plane, terrain_model: str):
    """The estimator's terrain of ``terrain_model`` over ``plane``: the plane itself
    (``"flat"``), or a :func:`foothold_memory` over it with :data:`FOOTHOLD_MEMORY`
    (``"memory"``)."""
    check_terrain_model(terrain_model)
    if terrain_model == "memory":
        return foothold_memory(plane, **FOOTHOLD_MEMORY)
    return plane


def terrain_model_of(provenance: dict, source) -> str | None:
    """``provenance["terrain_model"]`` of the parameter file ``source``, checked, or None
    when it does not say (files written before the option: tuned on the plane).

    Raises:
      ValueError: naming ``source`` and the field, for a name not in :data:`TERRAIN_MODELS`.
    """
    return checked_terrain_model(provenance, f"parameter file {str(source)!r}")


def checked_terrain_model(provenance: dict, where: str) -> str | None:
    """:func:`terrain_model_of`, a name not in :data:`TERRAIN_MODELS` raised as a ValueError
    that starts with ``where`` (a file's description) and names the field."""
    model = (provenance or {}).get("terrain_model")
    if model is not None and model not in TERRAIN_MODELS:
        raise ValueError(
            f"{where}: provenance field 'terrain_model' must be one of {TERRAIN_MODELS}, got"
            f" {model!r}"
        )
    return model
