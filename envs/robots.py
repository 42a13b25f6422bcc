"""Named robot models that load offline, and a rough height-field floor for any of them.

``load_robot(name)`` returns a :class:`Robot`: the compiled ``mujoco.MjModel``, the
:class:`jax_contact.robot.RobotDescription` derived from it, and the ``MjSpec`` it was
compiled from (for edits such as :func:`with_terrain`). The names and files it
loads, and what is dropped to load them offline (visual meshes, Barkour's block floor),
are in :mod:`jax_contact.envs.model_files`; nothing is downloaded at run time. Menagerie
models and MJCF paths are checked against MJX's collision functions
(:func:`jax_contact.envs.model_files.check_mjx_collisions`).

Each call builds a fresh model; mutate it (e.g. ``robot.mj_model.opt.timestep``) freely.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from jax_contact.envs.model_files import (  # noqa: F401  (the names load_robot takes, its error)
    MENAGERIE_NAMES,
    ROBOT_NAMES,
    RobotUnavailableError,
    check_mjx_collisions,
    compile_spec,
    robot_spec,
)
from jax_contact.robot import RobotDescription

if TYPE_CHECKING:
    from jax_contact.envs.gaits import GaitSettings


@dataclasses.dataclass(frozen=True)
class HeightField:
    """A height-field floor as compiled into the model.

    The field is centred on the world origin in x, y and spans ``[-size_x, size_x] x
    [-size_y, size_y]``; row ``r`` of ``heights`` lies at ``y = -size_y + 2 size_y r /
    (ny - 1)``, column ``c`` at ``x = -size_x + 2 size_x c / (nx - 1)`` (MuJoCo's layout).
    Between samples MuJoCo's surface is two planar triangles per cell, not a bilinear
    patch.

    Attributes:
      heights: (ny, nx) surface height (world z) at each sample, m, as the compiled model
        holds it (MuJoCo stores normalised samples in float32, so these may differ from the
        requested heights by about 1e-7 of their range).
      size_xy: (half-length in x, half-length in y), m.
      geom_name: name of the floor geom.
    """

    heights: np.ndarray
    size_xy: tuple[float, float]
    geom_name: str


@dataclasses.dataclass(frozen=True, eq=False)
class Robot:
    """A compiled robot model and what the estimator needs to know about it.

    Attributes:
      name: the name it was loaded by (or the MJCF path).
      mj_model: the compiled model, including the floor.
      description: feet, legs and dof split derived from ``mj_model``.
      spec: the ``mujoco.MjSpec`` that ``mj_model`` was compiled from; treat as read-only
        (``with_terrain`` edits a copy).
      terrain: the height-field floor added by :func:`with_terrain`, or None.
      gait: the robot's :class:`jax_contact.envs.gaits.GaitSettings` (standing pose, base height,
        gains, speeds), or None for :data:`jax_contact.envs.gaits.GAIT_SETTINGS` of its name (else
        every setting derived from the model). Set it with ``load_robot(..., gait=...)``
        or ``dataclasses.replace(robot, gait=...)``.
    """

    name: str
    mj_model: mujoco.MjModel
    description: RobotDescription
    spec: mujoco.MjSpec = dataclasses.field(repr=False)
    terrain: HeightField | None = None
    gait: GaitSettings | None = None

    @functools.cached_property
    def gait_settings(self) -> GaitSettings:
        """The resolved gait settings (:func:`jax_contact.envs.gaits.resolve_gait_settings`): every
        field set, computed once per robot."""
        from jax_contact.envs.gaits import resolve_gait_settings

        return resolve_gait_settings(self, self.gait)

    @property
    def home_qpos(self) -> np.ndarray:
        """(nq,) standing configuration: the gait settings' ``home_qpos`` or ``home_key``,
        else the keyframe named ``home`` or ``standing``, else the first keyframe, else a
        standing pose found by a short settle (:class:`jax_contact.envs.gaits.GaitSettings`)."""
        return np.array(self.gait_settings.home_qpos)


def load_robot(
    name: str, *, foot_names: Sequence[str] | None = None, gait: GaitSettings | None = None
) -> Robot:
    """Loads a robot by name (see the module docstring) or from an MJCF path.

    Args:
      name: one of :data:`ROBOT_NAMES`, or a path to an MJCF file (with its floor).
      foot_names: the feet, in leg order (:func:`jax_contact.envs.feet.robot_description`):
        sphere geoms or their bodies, or as the wrapper names feet (a box or mesh sole,
        a body of several geoms, a site); None finds them (the distal sphere geom of each
        joint chain that can touch the floor, or a foot's level spheres as one sole; with
        no such sphere, every floor-touching geom on a leg, grouped by body).
      gait: the robot's gait settings (:class:`jax_contact.envs.gaits.GaitSettings`); None takes
        :data:`jax_contact.envs.gaits.GAIT_SETTINGS` of the name, else derives them from the model
        when first needed.

    Returns:
      The compiled robot with its description.

    Raises:
      ValueError: an unknown name (the message lists the valid ones), a path that does not
        exist, or a model the description refuses.
      RobotUnavailableError: a known robot whose files are not on this machine.
    """
    if not isinstance(name, str):
        raise ValueError(f"name must be a str, got {type(name).__name__}")
    spec, source, kept_meshes = robot_spec(name)
    mj_model = compile_spec(spec, name, source, kept_meshes)
    if source is not None:
        check_mjx_collisions(mj_model, source)
    if gait is not None and type(gait).__name__ != "GaitSettings":
        raise ValueError(
            f"gait must be a jax_contact.envs.gaits.GaitSettings, got {type(gait).__name__}"
        )
    from jax_contact.envs.feet import robot_description

    try:
        description = robot_description(mj_model, foot_names)
    except ValueError as err:
        if source is None:
            raise
        raise ValueError(f"MJCF file {str(source)!r}: {err}") from None
    return Robot(
        name=name,
        mj_model=mj_model,
        description=description,
        spec=spec,
        gait=gait,
    )


def with_terrain(
    robot: Robot,
    heights: np.ndarray,
    size_xy: tuple[float, float],
    *,
    base_depth: float = 0.1,
) -> Robot:
    """Returns a copy of ``robot`` whose floor is a height field with the given heights.

    Every floor geom of the world body (plane or height field that a foot can touch) is
    replaced by one height-field geom with the first floor's name, contact and friction
    settings, so contact sensors that name the floor keep working. MuJoCo rescales
    height-field samples to [0, 1] when it compiles, so the geom is placed at
    ``z = min(heights)`` with elevation scale ``max(heights) - min(heights)``; the compiled
    surface then passes through the requested heights.

    Args:
      robot: the robot whose floor to replace (it is not changed).
      heights: (ny, nx) surface heights (world z), m; ny, nx >= 2. Row index runs along y,
        column index along x (see :class:`HeightField`).
      size_xy: (half-length in x, half-length in y) of the field, m, both > 0.
      base_depth: thickness of the solid below the lowest sample, m (MuJoCo's ``size[3]``).

    Returns:
      A new :class:`Robot` with ``terrain`` set to the compiled height field.

    Raises:
      ValueError: naming the argument, for a bad shape or value, or a robot whose floor
        geoms are unnamed.
    """
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"heights must have shape (ny, nx) with ny, nx >= 2, got {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError("heights must be finite")
    sx, sy = (float(v) for v in size_xy)
    if not (sx > 0 and sy > 0):
        raise ValueError(f"size_xy must be two half-lengths > 0, got {size_xy!r}")
    if not base_depth > 0:
        raise ValueError(f"base_depth must be > 0, got {base_depth!r}")

    floor_ids = robot.description.floor_geom_ids
    floor_names = [robot.mj_model.geom(i).name for i in floor_ids]
    spec = robot.spec.copy()
    floors = [g for g in spec.worldbody.geoms if g.name and g.name in floor_names]
    if len(floors) != len(floor_ids):
        raise ValueError(
            f"robot {robot.name!r}: every floor geom must be named to be replaced, got"
            f" {floor_names}"
        )
    template = floors[0]
    geom_name = template.name
    settings = {
        "contype": template.contype,
        "conaffinity": template.conaffinity,
        "condim": template.condim,
        "priority": template.priority,
        "friction": np.array(template.friction),
        "solref": np.array(template.solref),
        "solimp": np.array(template.solimp),
        "margin": template.margin,
        "gap": template.gap,
    }
    for g in floors:
        spec.delete(g)

    field_name = "jax_contact_terrain"
    while any(f.name == field_name for f in spec.hfields):
        field_name += "_"
    low, span = float(h.min()), float(h.max() - h.min())
    # MuJoCo maps a constant field to all zeros; any positive scale then gives height low.
    scale = span if span > 0 else 1e-3
    ny, nx = h.shape
    spec.add_hfield(
        name=field_name,
        nrow=ny,
        ncol=nx,
        size=[sx, sy, scale, float(base_depth)],
        userdata=((h - low) / scale).ravel().tolist(),
    )
    spec.worldbody.add_geom(
        name=geom_name,
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname=field_name,
        pos=[0.0, 0.0, low],
        **settings,
    )
    mj_model = spec.compile()
    hid = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_HFIELD, field_name)
    adr = mj_model.hfield_adr[hid]
    data = np.array(mj_model.hfield_data[adr : adr + ny * nx], dtype=np.float64).reshape(ny, nx)
    gid = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, geom_name)
    terrain = HeightField(
        heights=mj_model.geom_pos[gid, 2] + data * mj_model.hfield_size[hid, 2],
        size_xy=(sx, sy),
        geom_name=geom_name,
    )
    from jax_contact.envs.feet import robot_description

    return Robot(
        name=robot.name,
        mj_model=mj_model,
        description=robot_description(mj_model, robot.description.foot_names),
        spec=spec,
        terrain=terrain,
        gait=robot.gait,
    )
