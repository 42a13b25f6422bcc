"""Ground-truth foot contact from the simulator: normal force, contact flag, gap to the floor.

Route chosen: MJCF contact sensors, read from ``mjx.Data.sensordata`` (public API).
:func:`with_contact_sensors` adds, for every foot and every floor geom, one
``<contact geom1="foot" geom2="floor" data="force normal tangent" reduce="mindist">``
sensor. MJX fills them inside ``mjx.step`` from the constraint solver's forces (its
``support.contact_force_dim``, which decodes pyramidal cones), so reading them is a slice of
``sensordata``: jittable, vmappable, and nothing private is touched. The alternatives were
worse: ``mujoco.mjx._src.support.contact_force`` is private and takes a Python contact index
(not vmappable); reading ``d._impl.efc_force`` at ``d._impl.contact.efc_address`` works but
depends on MJX internals that change between releases; ``qfrc_constraint`` mixes the foot
force with joint-limit and friction-loss constraints.

Each sensor slot gives the force in the contact frame ``(f_n, f_t1, f_t2)`` and the frame's
normal and first tangent, oriented from geom1 (the foot) to geom2 (the floor); the force
on the foot is ``-(f_n n + f_t1 t1 + f_t2 t2)`` with ``t2 = n x t1`` (checked against
``mujoco.mj_contactForce`` in ``tests/test_ground_truth.py``). A plane touches a sphere at
one point, so that sensor has one slot; a capsule sole touches a plane at 2, a box,
cylinder or mesh sole at up to 4, and a height field any foot at up to 4 (MJX's
``hfield_sphere``), so those sensors have 4 slots and the slots are summed.

The force of a foot is the floor's force on its body: the foot geom's, plus that of every
other geom of the foot's body that can collide with the floor (one more sensor each). Read
from the foot geom alone, a foot geom that does not carry its leg's load makes the truth
describe a pad: Menagerie's A1 (``solimp="0.015 1 0.031"`` on its foot spheres) stands on
its calf capsules, which end at the spheres' centres; standing, each sphere is 10 mm into
the floor and pushes 1.4-1.6 N, the capsule 26-33 N, and a trot's stance force read from the
sphere was 2-5 N, dipping below the 1 N threshold within stances (docs/own_robot.md, "Soft
foot pads"). Go1, Spot, Barkour and the planar leg have no such geom: their truth is the
foot geom's.

Contact flag: the normal force above a threshold, 1 N by default (Isaac Lab's and
legged_gym's choice). Gap: the signed distance of the foot sphere's lowest point to the
floor, ``n . (c - p_floor) - r`` for a plane (exact) and the vertical clearance
``c_z - h(c_x, c_y) - r`` in the height field's frame, with MuJoCo's two triangles per cell,
for a height field (exact on flat patches, larger than the true distance on slopes);
the minimum over the floor geoms.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx

from jax_contact.envs.feet import robot_description, touches
from jax_contact.envs.robots import Robot

SENSOR_PREFIX = "gt_contact"
# MuJoCo contact-sensor data bits (mjtConDataType): found 0, force 1, torque 2, dist 3,
# pos 4, normal 5, tangent 6.
_DATA_FORCE_NORMAL_TANGENT = (1 << 1) | (1 << 5) | (1 << 6)
_SLOT_SIZE = 9  # force (3) + normal (3) + tangent (3)
_REDUCE_MINDIST = 1
_PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
_HFIELD = int(mujoco.mjtGeom.mjGEOM_HFIELD)
# Contacts a geom pair generates: a sphere on a plane 1; a capsule on a plane 2, a box,
# cylinder or mesh up to 4; on a height field up to 4 (MJX's hfield_sphere; the sensor
# keeps the 4 deepest). A slot with no contact reads zero force.
_SPHERE = int(mujoco.mjtGeom.mjGEOM_SPHERE)
_SLOTS = 4


def _slots(m: mujoco.MjModel, geom: int, floor_geom: int) -> int:
    """Slots of the sensor between a foot's geom (the foot geom or another of its body's)
    and a floor geom: one for a sphere on a plane, else :data:`_SLOTS` (a box or capsule
    sole on a plane read through one slot lost half its force or more)."""
    plane = int(m.geom_type[floor_geom]) == _PLANE
    return 1 if plane and int(m.geom_type[geom]) == _SPHERE else _SLOTS


def _sensor_name(foot: int, floor_geom: int) -> str:
    return f"{SENSOR_PREFIX}_foot{foot}_geom{floor_geom}"


def _body_sensor_name(foot: int, floor_geom: int, geom: int) -> str:
    return f"{SENSOR_PREFIX}_foot{foot}_geom{floor_geom}_body{geom}"


def _body_geoms(m: mujoco.MjModel, foot_geom: int, floor_geom: int) -> list[int]:
    """The other geoms of the foot's body that can touch ``floor_geom`` (:func:`feet.touches`:
    contype/conaffinity, or an explicit ``<pair>``).

    Menagerie's A1 stands on them: its foot spheres' ``solimp="0.015 1 0.031"`` is a pad
    that pushes 1-5 N while it sinks 10 mm, and the calf capsule that ends at the sphere's
    centre then lands and carries 95 % of the leg's load (module docstring)."""
    body = int(m.geom_bodyid[foot_geom])
    return [
        g
        for g in range(m.ngeom)
        if g != foot_geom and int(m.geom_bodyid[g]) == body and touches(m, g, [floor_geom])
    ]


def with_contact_sensors(robot: Robot) -> Robot:
    """A copy of ``robot`` with one contact sensor per (foot, floor geom) pair.

    Unnamed foot or floor geoms get a name (``gt_foot<i>`` / ``gt_floor<id>``) in the copy,
    since a sensor refers to geoms by name. Sensors are appended after the existing ones,
    so ids of bodies, geoms, joints and actuators, and the robot's description, are
    unchanged. Calling it on a robot that already has the sensors returns the robot.

    The copy is compiled from ``robot.spec``: edits made to ``robot.mj_model`` after
    compiling are lost, except ``opt`` (timestep, solver iterations, ...), which is copied
    over. Apply :func:`jax_contact.envs.payload.add_mass` and similar model edits after this call.

    Args:
      robot: a robot from :func:`jax_contact.envs.robots.load_robot` (or ``with_terrain``).

    Returns:
      A new :class:`jax_contact.envs.robots.Robot`.
    """
    desc = robot.description
    m = robot.mj_model
    names = [_sensor_name(i, f) for i in range(desc.n_legs) for f in desc.floor_geom_ids]
    names += [
        _body_sensor_name(i, f, g)
        for i, foot in enumerate(desc.foot_geom_ids)
        for f in desc.floor_geom_ids
        for g in _body_geoms(m, foot, f)
    ]
    if all(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, n) >= 0 for n in names):
        return robot
    spec = robot.spec.copy()
    geoms = spec.geoms
    if len(geoms) != m.ngeom:
        raise ValueError(
            f"robot: its spec has {len(geoms)} geoms but its model {m.ngeom}; the spec must be"
            " the one the model was compiled from"
        )

    def name_of(gid: int, fallback: str) -> str:
        g = geoms[gid]
        if not g.name:
            g.name = fallback
        return g.name

    for i, foot in enumerate(desc.foot_geom_ids):
        foot_name = name_of(foot, f"gt_foot{i}")
        for f in desc.floor_geom_ids:
            floor_name = name_of(f, f"gt_floor{f}")
            spec.add_sensor(
                name=_sensor_name(i, f),
                type=mujoco.mjtSensor.mjSENS_CONTACT,
                objtype=mujoco.mjtObj.mjOBJ_GEOM,
                objname=foot_name,
                reftype=mujoco.mjtObj.mjOBJ_GEOM,
                refname=floor_name,
                intprm=[_DATA_FORCE_NORMAL_TANGENT, _REDUCE_MINDIST, _slots(m, foot, f)],
            )
            for g in _body_geoms(m, foot, f):
                spec.add_sensor(
                    name=_body_sensor_name(i, f, g),
                    type=mujoco.mjtSensor.mjSENS_CONTACT,
                    objtype=mujoco.mjtObj.mjOBJ_GEOM,
                    objname=name_of(g, f"gt_foot{i}_body{g}"),
                    reftype=mujoco.mjtObj.mjOBJ_GEOM,
                    refname=floor_name,
                    intprm=[_DATA_FORCE_NORMAL_TANGENT, _REDUCE_MINDIST, _slots(m, g, f)],
                )
    mj_model = spec.compile()
    # Keep the caller's physics options (e.g. a changed timestep or solver iterations).
    for field in (
        "timestep",
        "iterations",
        "ls_iterations",
        "tolerance",
        "ls_tolerance",
        "integrator",
        "cone",
        "solver",
        "disableflags",
        "enableflags",
    ):
        setattr(mj_model.opt, field, getattr(m.opt, field))
    return dataclasses.replace(
        robot,
        mj_model=mj_model,
        description=robot_description(mj_model, desc.foot_names),
        spec=spec,
    )


@struct.dataclass
class TruthLayout:
    """Where each foot's contact sensors sit in ``sensordata``, and the floor's shape.

    Build it with :func:`make_truth_layout`; pass it to :func:`foot_truth` (a pytree: the
    height-field samples are leaves, everything else is static).

    Attributes:
      sensor_adr: static, per foot, per floor geom, the sensor's first index in
        ``sensordata``.
      sensor_slots: static, per foot, per floor geom, the number of contact slots of its
        sensor (one for a sphere on a plane, else 4).
      body_sensors: static, per foot, ``(first index, slots)`` of the sensors between the
        floor and the foot body's other geoms (none on most robots).
      foot_geom_ids: static, the foot sphere geoms.
      foot_radii: static, their radii, m.
      floor_geom_ids: static, the floor geoms.
      floor_types: static, their ``mjtGeom`` types (plane or height field).
      hfield_size: static, per floor geom, MuJoCo's ``hfield_size`` (x, y, top, base) for a
        height field, else None.
      hfield_heights: per floor geom, (nrow, ncol) surface heights in the field's frame, m,
        for a height field; a (1, 1) dummy for a plane.
      threshold: () normal force above which a foot counts as in contact, N.
    """

    sensor_adr: tuple[tuple[int, ...], ...] = struct.field(pytree_node=False)
    sensor_slots: tuple[tuple[int, ...], ...] = struct.field(pytree_node=False)
    body_sensors: tuple[tuple[tuple[int, int], ...], ...] = struct.field(pytree_node=False)
    foot_geom_ids: tuple[int, ...] = struct.field(pytree_node=False)
    foot_radii: tuple[float, ...] = struct.field(pytree_node=False)
    floor_geom_ids: tuple[int, ...] = struct.field(pytree_node=False)
    floor_types: tuple[int, ...] = struct.field(pytree_node=False)
    hfield_size: tuple[tuple[float, float, float, float] | None, ...] = struct.field(
        pytree_node=False
    )
    hfield_heights: tuple[jax.Array, ...]
    threshold: jax.Array


@struct.dataclass
class FootTruth:
    """Ground truth of every foot at one physics step.

    Attributes:
      force: (n_feet, 3) contact force of the floor on the foot, world frame, N (summed
        over the contact points of the foot geom and of its body's other geoms).
      normal_force: (n_feet,) its component along the contact normal (pushing the foot
        out of the floor), N, >= 0.
      contact: (n_feet,) bool, ``normal_force > threshold``.
      distance: (n_feet,) gap between the foot sphere's lowest point and the floor, m
        (negative: penetration).
    """

    force: jax.Array
    normal_force: jax.Array
    contact: jax.Array
    distance: jax.Array


def make_truth_layout(robot: Robot, *, threshold: float = 1.0) -> TruthLayout:
    """Finds the contact sensors of ``robot`` (see :func:`with_contact_sensors`).

    Args:
      robot: a robot returned by :func:`with_contact_sensors`.
      threshold: contact flag threshold on the normal force, N (1 N: Isaac Lab,
        legged_gym).

    Raises:
      ValueError: the robot lacks the sensors (call :func:`with_contact_sensors`), its floor
        is neither a plane nor a height field, or ``threshold`` is negative.
    """
    if not (np.isfinite(threshold) and threshold >= 0):
        raise ValueError(f"threshold must be a finite float >= 0 (N), got {threshold!r}")
    m, desc = robot.mj_model, robot.description
    adr, slots, body = [], [], []
    for i in range(desc.n_legs):
        row, row_slots = [], []
        for f in desc.floor_geom_ids:
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, _sensor_name(i, f))
            if sid < 0:
                raise ValueError(
                    f"robot {robot.name!r} has no ground-truth contact sensor for foot"
                    f" {desc.foot_names[i]!r}; pass it through with_contact_sensors first"
                )
            row.append(int(m.sensor_adr[sid]))
            row_slots.append(int(m.sensor_dim[sid]) // _SLOT_SIZE)
        adr.append(tuple(row))
        slots.append(tuple(row_slots))
        extra = []
        for f in desc.floor_geom_ids:
            for g in _body_geoms(m, desc.foot_geom_ids[i], f):
                sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, _body_sensor_name(i, f, g))
                if sid < 0:
                    raise ValueError(
                        f"robot {robot.name!r} lacks the ground-truth sensor of geom {g} on"
                        f" foot {desc.foot_names[i]!r}'s body; pass it through"
                        " with_contact_sensors first"
                    )
                extra.append((int(m.sensor_adr[sid]), int(m.sensor_dim[sid]) // _SLOT_SIZE))
        body.append(tuple(extra))
    types, sizes, heights = [], [], []
    for f in desc.floor_geom_ids:
        t = int(m.geom_type[f])
        if t not in (_PLANE, _HFIELD):
            raise ValueError(f"floor geom {f} has type {t}; only plane and height field work")
        types.append(t)
        if t == _HFIELD:
            h = int(m.geom_dataid[f])
            nrow, ncol = int(m.hfield_nrow[h]), int(m.hfield_ncol[h])
            a = int(m.hfield_adr[h])
            size = tuple(float(x) for x in m.hfield_size[h])
            data = np.asarray(m.hfield_data[a : a + nrow * ncol]).reshape(nrow, ncol)
            sizes.append(size)
            heights.append(jnp.asarray(data * size[2], dtype=jnp.float32))
        else:
            sizes.append(None)
            heights.append(jnp.zeros((1, 1), dtype=jnp.float32))
    return TruthLayout(
        sensor_adr=tuple(adr),
        sensor_slots=tuple(slots),
        body_sensors=tuple(body),
        foot_geom_ids=tuple(desc.foot_geom_ids),
        foot_radii=tuple(desc.foot_radii),
        floor_geom_ids=tuple(desc.floor_geom_ids),
        floor_types=tuple(types),
        hfield_size=tuple(sizes),
        hfield_heights=tuple(heights),
        threshold=jnp.float32(threshold),
    )


def _hfield_height(heights: jax.Array, size, xy: jax.Array) -> jax.Array:
    """() surface height at ``xy`` (2,) in the field's frame, MuJoCo's triangulation.

    Each cell is cut along the diagonal from (col, row) to (col + 1, row + 1), as in
    ``mjx._src.collision_convex._hfield_collision``; outside the field the border cell is
    extended.
    """
    nrow, ncol = heights.shape
    gx = (xy[0] + size[0]) / (2.0 * size[0]) * (ncol - 1)
    gy = (xy[1] + size[1]) / (2.0 * size[1]) * (nrow - 1)
    c = jnp.clip(jnp.floor(gx), 0, ncol - 2).astype(jnp.int32)
    r = jnp.clip(jnp.floor(gy), 0, nrow - 2).astype(jnp.int32)
    fx = jnp.clip(gx - c, 0.0, 1.0)
    fy = jnp.clip(gy - r, 0.0, 1.0)
    h00 = heights[r, c]
    h10 = heights[r, c + 1]
    h01 = heights[r + 1, c]
    h11 = heights[r + 1, c + 1]
    lower = h00 + fx * (h10 - h00) + fy * (h11 - h10)  # triangle (c,r), (c+1,r), (c+1,r+1)
    upper = h00 + fy * (h01 - h00) + fx * (h11 - h01)  # triangle (c,r), (c+1,r+1), (c,r+1)
    return jnp.where(fx >= fy, lower, upper)


def foot_truth(layout: TruthLayout, d: mjx.Data) -> FootTruth:
    """Ground truth of every foot from one (unbatched) ``mjx.Data`` after ``mjx.step``.

    ``mjx.step`` computes positions, constraint forces and sensors at the state it starts
    from and then integrates, so after a step the truth (like ``d.geom_xpos`` and
    ``d.qfrc_actuator``) describes the *start* of that step, one ``dt`` before ``d.qpos``.

    Args:
      layout: from :func:`make_truth_layout`.
      d: MJX data of the instrumented model; ``sensordata`` as ``mjx.step`` /
        ``mjx.forward`` left it.

    Returns:
      The :class:`FootTruth` of this step.
    """
    forces, normals = [], []
    for row, row_slots, extra in zip(
        layout.sensor_adr, layout.sensor_slots, layout.body_sensors, strict=True
    ):
        f_world = jnp.zeros(3)
        f_normal = jnp.zeros(())
        pairs = list(zip(row, row_slots, strict=True)) + list(extra)
        for adr, n_slots in pairs:
            block = d.sensordata[adr : adr + n_slots * _SLOT_SIZE].reshape(n_slots, _SLOT_SIZE)
            f_c, n, t1 = block[:, 0:3], block[:, 3:6], block[:, 6:9]
            t2 = jnp.cross(n, t1)
            # The frame points from the foot (geom1) into the floor and the force is what
            # the foot exerts on the floor; the floor pushes back with the opposite.
            f_on_floor = f_c[:, 0:1] * n + f_c[:, 1:2] * t1 + f_c[:, 2:3] * t2
            f_world = f_world - jnp.sum(f_on_floor, axis=0)
            f_normal = f_normal + jnp.sum(f_c[:, 0])
        forces.append(f_world)
        normals.append(f_normal)
    force = jnp.stack(forces)
    normal_force = jnp.stack(normals)

    dists = []
    for g, r in zip(layout.foot_geom_ids, layout.foot_radii, strict=True):
        centre = d.geom_xpos[g]
        gaps = []
        for f, t, size, heights in zip(
            layout.floor_geom_ids,
            layout.floor_types,
            layout.hfield_size,
            layout.hfield_heights,
            strict=True,
        ):
            local = d.geom_xmat[f].T @ (centre - d.geom_xpos[f])
            if t == _PLANE:
                gaps.append(local[2] - r)
            else:
                gaps.append(local[2] - _hfield_height(heights, size, local[:2]) - r)
        dists.append(jnp.min(jnp.stack(gaps)))
    return FootTruth(
        force=force,
        normal_force=normal_force,
        contact=normal_force > layout.threshold,
        distance=jnp.stack(dists),
    )
