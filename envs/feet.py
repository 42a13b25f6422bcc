"""Feet as robots have them: the contact point the estimator uses, per foot.

The estimator models a foot as one point ``p_f`` (with a radius ``r``: the kinematics term
compares ``p_f,z - r`` with the terrain) fixed to a body. A foot can be named as

- a **sphere geom**: its centre, its radius (Go1, Spot, ANYmal);
- a **box, cylinder or mesh geom**: the centre of its lowest face at the home pose (the
  sole), radius 0, and that face's four corners (the rolling point below); a mesh is
  taken as its bounding box (``geom_aabb``); a **capsule**: its centre and radius, and
  its segment's two ends (the rolling point below: the lower end when it tilts);
- a **site**: its position, radius 0;
- a **body** with an offset in the body frame (:class:`FootSpec`), radius 0 by default;
- a **body** whose several geoms touch the floor: one foot, the mean of their contact
  points and radii (T1's four corner spheres, H1's three capsules); spheres and capsules
  of one radius, or flat geoms, also give the rolling point below (the spheres' centres
  and the capsules' ends, or every sole's corners). G1's feet touch the
  floor only through explicit ``<pair>`` elements (``contype = 0``): pairs count as
  floor contact here.

With no names, the feet are the floor-touching sphere geoms on legs, grouped by body, at the
ends of the legs (no floor-touching geom on a body below), a body's spheres within
``SOLE_SPREAD`` of its lowest at the home pose (T1's four corners, not a calf sphere above
the foot's); if there is no such sphere, every floor-touching geom on a leg, grouped by
body, at the ends of the legs (Berkeley Humanoid's boxes ``l_foot1``, ``r_foot1``; G1;
Apollo). The geoms of a foot are what the
ground truth reads (:mod:`jax_contact.envs.contact_truth`): a named geom that cannot touch
the floor (T1's foot boxes ``left_foot``, ``right_foot`` collide only with each other)
gives the foot its point and its body's floor-touching geoms the truth, as a site does; a
body with none is refused.

What a point contact means for a flat foot: eq. (6) and the dynamics term model the foot
as a point that transmits a force and no moment. A sole in full contact also transmits a
moment (up to ``f_n`` times half its length); that moment reaches the joints as a torque
the model does not predict, and it is folded into the disturbance ``Sigma_d`` and the
force prior ``Sigma_f`` of the dynamics term, as any model error.

Which point: a flat sole that lands on its toe or heel, or rolls over an edge, touches the
floor at that edge, not at its centre, which is then centimetres above the floor and
moving (the kinematics and differential-kinematics terms say air). So by default
(``ContactObsConfig.sole = "rolling"``) a flat foot's point is recomputed at each step
from its sole's four corners (:func:`jax_contact.adapter.contact_points`; for round
geoms of one radius, the spheres' centres and the capsules' segment ends, the radius
kept): their mean weighted by ``exp(-(z_i - z_min) / adapter.SOLE_SOFTNESS)``,
``SOLE_SOFTNESS`` = 2 mm (set, not fitted): the
centre when the sole lies flat, the middle of the lowest edge when it is tilted by more
than a degree or two, the lowest corner on a corner. The Jacobian, the foot's velocity and
height are those of that point. ``sole = "centre"`` keeps the fixed centre.
docs/training.md measures both on Berkeley Humanoid.

:func:`describe` returns a :class:`jax_contact.robot.RobotDescription` (foot points as
``foot_offsets``, ``foot_geom_ids`` the first geom of each foot, -1 for a site or a bare
body); :func:`jax_contact.adapter.robot_measurement` takes such a description and
computes the estimator's input at those points (``sole``: the rolling point, or the
fixed one), the wrapper's as the log commands'.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import mujoco
import numpy as np

from jax_contact.robot import (
    NO_FLOOR,
    RobotDescription,
    actuated_dofs,
    body_chain,
    derive_description,
    floor_spheres,
    leg_of,
    model_mass,
    sphere_foot_names,
    split_legs,
    unactuated_leg,
    warn_joints_below,
)

_T = mujoco.mjtGeom
_FLOOR_TYPES = (int(_T.mjGEOM_PLANE), int(_T.mjGEOM_HFIELD))
_ROUND = ("sphere", "capsule")  # geoms with a radius; the others' soles are flat (radius 0)
# A found foot's spheres: those whose lowest points at the home pose lie within this of the
# lowest, m (T1's four corners lie level; a calf's sphere lies a calf above its foot's).
SOLE_SPREAD = 0.01


@dataclasses.dataclass(frozen=True)
class FootSpec:
    """A foot given as a body and a point in its frame (or any name, with options).

    Attributes:
      name: the foot's label; when ``body`` is None, the foot is the geom, else the site,
        else the body of this name, in that order (a site that shares its name with a
        geom, as Go1's ``FR`` and T1's ``left_foot`` do, is reached as ``body`` and
        ``offset``).
      body: a body name: the foot is ``offset`` in this body's frame.
      offset: (x, y, z) point in the body frame, m; only with ``body``.
      radius: the foot's radius, m; only with ``body``.
      geoms: geom names whose contact is this foot's ground truth; default: the body's
        floor-touching geoms; only with ``body``.
    """

    name: str
    body: str | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    geoms: tuple[str, ...] | None = None

    def __post_init__(self):
        # Each field named (a 2-vector offset was a matmul error at wrap time, a string one
        # a float() error; a negative radius passed).
        bad = lambda field, want: ValueError(  # noqa: E731
            f"FootSpec {self.name!r}: {field} must be {want}, got {getattr(self, field)!r}"
        )
        if not isinstance(self.name, str) or not self.name:
            raise bad("name", "a non-empty str")
        if self.body is not None and not isinstance(self.body, str):
            raise bad("body", "a body name or None")
        try:
            offset = np.asarray(self.offset, dtype=float)
        except (TypeError, ValueError):
            offset = np.zeros(0)
        if isinstance(self.offset, str) or offset.shape != (3,) or not np.isfinite(offset).all():
            raise bad("offset", "3 finite numbers (x, y, z) in the body frame, m")
        object.__setattr__(self, "offset", tuple(float(x) for x in offset))
        # Any real scalar (NumPy's and JAX's float32 were refused by an isinstance test).
        radius = np.asarray(self.radius) if not isinstance(self.radius, str | bool) else None
        real = radius is not None and radius.shape == () and radius.dtype.kind in "iuf"
        if not (real and math.isfinite(float(radius)) and float(radius) >= 0):
            raise bad("radius", "a finite number >= 0, m")
        object.__setattr__(self, "radius", float(radius))
        if self.geoms is not None:
            if isinstance(self.geoms, str) or not all(isinstance(g, str) for g in self.geoms):
                raise bad("geoms", "a tuple of geom names or None")
            object.__setattr__(self, "geoms", tuple(self.geoms))
        if self.body is None:
            # Without a body the foot is the geom, site or body called name, as it is: these
            # options were ignored without a word (even a geom name that does not exist).
            set_ = {
                "offset": self.offset != (0.0, 0.0, 0.0),
                "radius": self.radius != 0.0,
                "geoms": self.geoms is not None,
            }
            given = [f for f, is_set in set_.items() if is_set]
            if given:
                raise ValueError(
                    f"FootSpec {self.name!r}: {', '.join(given)} apply to a foot given by its"
                    f" body (FootSpec({self.name!r}, body=..., ...)); without body the foot is"
                    f" the geom, site or body named {self.name!r} as it is"
                )


@dataclasses.dataclass(frozen=True)
class Foot:
    """A resolved foot. ``kind`` says which rule of the module docstring gave its point."""

    name: str
    kind: str
    body_id: int
    point: tuple[float, float, float]
    radius: float
    geom_ids: tuple[int, ...]
    sole: tuple[tuple[float, float, float], ...] = ()


def floors(m: mujoco.MjModel) -> list[int]:
    return [
        g for g in range(m.ngeom) if m.geom_bodyid[g] == 0 and int(m.geom_type[g]) in _FLOOR_TYPES
    ]


def touches(m: mujoco.MjModel, g: int, floor_ids) -> bool:
    """Can geom ``g`` touch a floor geom (contype/conaffinity, or an explicit pair)?"""
    for f in floor_ids:
        if (m.geom_contype[g] & m.geom_conaffinity[f]) or (
            m.geom_contype[f] & m.geom_conaffinity[g]
        ):
            return True
    for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True):
        if (a == g and b in floor_ids) or (b == g and a in floor_ids):
            return True
    return False


def home_data(m) -> mujoco.MjData:
    """A new ``MjData`` of ``m`` at its home pose (the keyframe ``home``, else the first
    keyframe, else ``qpos0``), kinematics computed: where the feet's soles are compared."""
    d = mujoco.MjData(m)
    key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    if key >= 0:
        d.qpos[:] = m.key_qpos[key]
    elif m.nkey > 0:
        d.qpos[:] = m.key_qpos[0]
    mujoco.mj_kinematics(m, d)
    return d


def _lowest_spheres(m, d, geoms: list[int]) -> list[int]:
    """The spheres among ``geoms`` whose lowest point at the home pose (``d``) is within
    :data:`SOLE_SPREAD` of the lowest one's."""
    bottom = {g: float(d.geom_xpos[g][2] - m.geom_size[g, 0]) for g in geoms}
    low = min(bottom.values())
    return [g for g in geoms if bottom[g] - low <= SOLE_SPREAD]


def _geom_point(m, d, g: int) -> tuple[str, np.ndarray, float, tuple]:
    """(kind, contact point in the body frame, radius, rolling points in the body frame)
    of one geom (module docstring): a flat sole's four corners, a capsule's two segment
    ends, none for a sphere."""
    t = int(m.geom_type[g])
    size = np.asarray(m.geom_size[g], np.float64)
    if t == int(_T.mjGEOM_SPHERE):
        return "sphere", np.asarray(m.geom_pos[g], np.float64), float(size[0]), ()
    if t == int(_T.mjGEOM_CAPSULE):
        pos = np.asarray(m.geom_pos[g], np.float64)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, np.asarray(m.geom_quat[g], np.float64))
        half = rot.reshape(3, 3)[:, 2] * size[1]  # the segment along the geom's z axis
        ends = tuple(tuple(float(x) for x in pos + s * half) for s in (1.0, -1.0))
        return "capsule", pos, float(size[0]), ends
    if t == int(_T.mjGEOM_BOX):
        centre, half, kind = np.zeros(3), size, "box"
    elif t == int(_T.mjGEOM_CYLINDER):
        centre, half, kind = np.zeros(3), np.array([size[0], size[0], size[1]]), "cylinder"
    elif t == int(_T.mjGEOM_ELLIPSOID):
        centre, half, kind = np.zeros(3), size, "ellipsoid"
    else:  # mesh and anything else: its bounding box in the geom frame
        aabb = np.asarray(m.geom_aabb[g], np.float64)
        centre, half, kind = aabb[:3], aabb[3:], "mesh"
    # The face whose outward normal points most downward at the home pose: the sole.
    rot_world = np.asarray(d.geom_xmat[g], np.float64).reshape(3, 3)
    axis = int(np.argmax(np.abs(rot_world[2])))
    sign = -np.sign(rot_world[2, axis]) or -1.0
    local = centre.copy()
    local[axis] += sign * half[axis]
    rot_body = np.zeros(9)
    mujoco.mju_quat2Mat(rot_body, np.asarray(m.geom_quat[g], np.float64))
    rot_body = rot_body.reshape(3, 3)
    pos = np.asarray(m.geom_pos[g], np.float64)
    # The sole's four corners: the face's extremes along its two in-plane axes (a
    # cylinder's or ellipsoid's: four points of its rim, one at each end of each axis).
    a, b = (i for i in range(3) if i != axis)
    round_sole = kind in ("cylinder", "ellipsoid")
    signs = (
        ((1, 0), (0, -1), (-1, 0), (0, 1)) if round_sole else ((1, 1), (1, -1), (-1, -1), (-1, 1))
    )
    corners = []
    for sa, sb in signs:
        c = local.copy()
        c[a] += sa * half[a]
        c[b] += sb * half[b]
        corners.append(tuple(float(x) for x in pos + rot_body @ c))
    return kind, pos + rot_body @ local, 0.0, tuple(corners)


def _name_of(m, obj, i) -> str:
    return mujoco.mj_id2name(m, obj, i) or ""


def _resolve(m, d, spec, floor_ids, colliders) -> Foot:
    G, S, B = mujoco.mjtObj.mjOBJ_GEOM, mujoco.mjtObj.mjOBJ_SITE, mujoco.mjtObj.mjOBJ_BODY
    if isinstance(spec, FootSpec) and spec.body is not None:
        b = mujoco.mj_name2id(m, B, spec.body)
        if b < 0:
            raise ValueError(f"FootSpec {spec.name!r}: no body named {spec.body!r}")
        if spec.geoms is not None:
            geoms = tuple(mujoco.mj_name2id(m, G, n) for n in spec.geoms)
            if min(geoms, default=0) < 0:
                raise ValueError(f"FootSpec {spec.name!r}: unknown geom in {spec.geoms}")
            for n, g in zip(spec.geoms, geoms, strict=True):  # another foot's would be its truth
                up = int(m.geom_bodyid[g])
                while up not in (b, 0):
                    up = int(m.body_parentid[up])
                if up != b:
                    raise ValueError(
                        f"FootSpec {spec.name!r}: geom {n!r} is on body"
                        f" {_name_of(m, B, int(m.geom_bodyid[g]))!r}, not on {spec.body!r} or below"
                        " it: its contacts would be this foot's ground truth"
                    )
        else:
            geoms = tuple(g for g in colliders if m.geom_bodyid[g] == b)
        return Foot(spec.name, "body", b, tuple(map(float, spec.offset)), float(spec.radius), geoms)
    name = spec.name if isinstance(spec, FootSpec) else spec
    if not isinstance(name, str):  # mj_name2id of a non-str can crash the interpreter
        raise ValueError(f"foot {name!r}: a foot is named by a str (or a FootSpec)")
    g = mujoco.mj_name2id(m, G, name)
    if g >= 0 and m.geom_bodyid[g] == 0:
        raise ValueError(f"foot {name!r} is a geom of the world body (the floor?), not a foot")
    if g >= 0:
        kind, p, r, sole = _geom_point(m, d, g)
        b = int(m.geom_bodyid[g])
        geoms = (g,)
        if g not in colliders:
            # A geom that cannot touch the floor (T1's foot boxes collide only with each
            # other): its point is the foot's, the truth its body's floor contacts, as a
            # site's; a body with none has no ground truth at all.
            geoms = tuple(c for c in colliders if m.geom_bodyid[c] == b)
            if not geoms:
                raise ValueError(
                    f"foot {name!r}: geom {name!r} cannot touch the floor (contype/conaffinity,"
                    f" no <pair>), nor can any geom of its body {_name_of(m, B, b)!r}: no"
                    " ground truth of its contact; name a geom that touches the floor"
                )
        return Foot(name, kind, b, tuple(p), r, geoms, sole)
    s = mujoco.mj_name2id(m, S, name)
    if s >= 0:
        b = int(m.site_bodyid[s])
        geoms = tuple(g for g in colliders if m.geom_bodyid[g] == b)
        return Foot(name, "site", b, tuple(map(float, m.site_pos[s])), 0.0, geoms)
    b = mujoco.mj_name2id(m, B, name)
    if b >= 0:
        geoms = [g for g in colliders if m.geom_bodyid[g] == b]
        spheres = [g for g in geoms if int(m.geom_type[g]) == int(_T.mjGEOM_SPHERE)]
        return _body_foot(m, d, name, b, spheres or geoms)
    named = {_name_of(m, G, g) for g in colliders} | {
        _name_of(m, B, m.geom_bodyid[g]) for g in colliders
    }
    valid = sorted(named - {""})  # _name_of gives "" for an unnamed geom or body
    raise ValueError(
        f"foot {name!r} is no geom, site or body of the model; valid names: any site or body"
        f" of the model, or a floor-touching geom or its body, which are {valid}"
    )


def _body_foot(m, d, name, b, geoms) -> Foot:
    if not geoms:
        return Foot(name, "body", b, (0.0, 0.0, 0.0), 0.0, ())
    if len(geoms) == 1:
        kind, p, r, sole = _geom_point(m, d, geoms[0])
        return Foot(name, kind, b, tuple(p), r, tuple(geoms), sole)
    pts = [_geom_point(m, d, g) for g in geoms]
    kinds = sorted({k for k, _, _, _ in pts})
    p = np.mean([q for _, q, _, _ in pts], axis=0)
    radii = [r for _, _, r, _ in pts]
    r = float(np.mean(radii))
    if set(kinds) <= set(_ROUND) and max(radii) - min(radii) <= 1e-9:
        # Spheres and capsules of one radius (T1's four corner spheres, H1's three
        # capsules): the spheres' centres and the capsules' segment ends are the points
        # that roll (the lowest of them is the lowest geom's), the radius is theirs.
        sole = tuple(c for k, q, _, cs in pts for c in (cs if k == "capsule" else (tuple(q),)))
    elif not set(kinds) & set(_ROUND):
        sole = tuple(c for *_, cs in pts for c in cs)  # flat geoms: every sole's corners
    else:
        sole = ()  # round and flat, or round of several radii: a fixed point
    label = f"{len(geoms)} {'/'.join(kinds)} geoms"
    return Foot(name, label, b, tuple(p), r, tuple(geoms), sole)


def find_feet(m: mujoco.MjModel, feet=None) -> tuple[tuple[Foot, ...], list[int]]:
    """(the feet, the floor geoms): module docstring for the rules."""
    floor_ids = floors(m)
    if not floor_ids:
        raise ValueError(NO_FLOOR)
    colliders = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0 and touches(m, g, floor_ids)]
    if not colliders:
        raise ValueError(
            "mj_model has no floor contact: no geom outside the world body can collide with"
            " the floor (check contype/conaffinity and <pair>)"
        )
    d = home_data(m)
    if feet is not None:
        out = tuple(_resolve(m, d, f, floor_ids, colliders) for f in feet)
        if len({(f.body_id, f.point) for f in out}) != len(out):
            raise ValueError(f"feet name the same foot twice: {[f.name for f in out]}")
        return out, floor_ids
    actuated = actuated_dofs(m)
    on_legs = [g for g in colliders if leg_of(m, int(m.geom_bodyid[g]), actuated)[1]]
    spheres = [g for g in on_legs if int(m.geom_type[g]) == int(_T.mjGEOM_SPHERE)]
    chosen = spheres or on_legs
    if not chosen:
        raise ValueError(
            "mj_model has no floor contact through a leg: the geoms that can touch the floor"
            " have no joint between them and the base"
        )
    bodies = list(dict.fromkeys(int(m.geom_bodyid[g]) for g in chosen))
    # Keep the ends of the legs: no floor-touching geom further down (a model whose every
    # collision geom is a sphere, Menagerie's Go2, has spheres on hips, thighs and calves).
    bodies = [b for b in bodies if not any(b in body_chain(m, o)[1:] for o in bodies)]
    out = []
    for b in bodies:
        geoms = [g for g in chosen if m.geom_bodyid[g] == b]
        if spheres:  # the sole's spheres (T1's corners), not a calf's sphere above its foot
            geoms = _lowest_spheres(m, d, geoms)
        label = _name_of(m, mujoco.mjtObj.mjOBJ_GEOM, geoms[0]) if len(geoms) == 1 else ""
        out.append(_body_foot(m, d, label or _name_of(m, mujoco.mjtObj.mjOBJ_BODY, b), b, geoms))
    return tuple(out), floor_ids


def describe(m: mujoco.MjModel, feet=None) -> tuple[RobotDescription, tuple[Foot, ...]]:
    """The description the estimator needs, and the resolved feet, of a compiled model."""
    resolved, floor_ids = find_feet(m, feet)
    actuated = actuated_dofs(m)
    legs, bases = [], []
    # Feet the user did not name were found by a rule; say so, since a model that is no
    # legged robot (a cart-pole) fails here on a "foot" nobody called one.
    found = (
        ""
        if feet
        else f" (feet found by rule: {[f.name for f in resolved]}; is this a legged robot?"
        " name its feet: foot_names, or --feet)"
    )
    for f in resolved:
        base, dofs = leg_of(m, f.body_id, actuated)
        if not dofs:
            raise ValueError(f"foot {f.name!r} has no leg: no joint between it and the base{found}")
        if not actuated.intersection(dofs):
            raise unactuated_leg(m, f.name, dofs, actuated, found)
        legs.append(tuple(dofs))
        bases.append(base)
    legs, others = split_legs(m, legs, [f.name for f in resolved], actuated)
    if feet:  # feet found by rule are at the ends of the legs
        warn_joints_below(m, [f.body_id for f in resolved], [f.name for f in resolved], actuated)
    if len({len(x) for x in legs}) != 1:
        per = ", ".join(f"{f.name}: {len(x)}" for f, x in zip(resolved, legs, strict=True))
        raise ValueError(f"every leg must have the same number of dofs, got {per}")
    if len(set(bases)) != 1:
        raise ValueError(f"the feet hang from different bases: {sorted(set(bases))}")
    base = bases[0]
    geoms = [g for f in resolved for g in f.geom_ids]
    used = tuple(fl for fl in floor_ids if not geoms or any(touches(m, g, [fl]) for g in geoms))
    start, n = int(m.body_dofadr[base]), int(m.body_dofnum[base])
    desc = RobotDescription(
        foot_names=tuple(f.name for f in resolved),
        foot_body_ids=tuple(f.body_id for f in resolved),
        foot_geom_ids=tuple(f.geom_ids[0] if f.geom_ids else -1 for f in resolved),
        foot_offsets=tuple(tuple(float(x) for x in f.point) for f in resolved),
        foot_radii=tuple(f.radius for f in resolved),
        foot_soles=tuple(f.sole for f in resolved),
        leg_dofs=legs,
        other_dofs=others,
        base_dofs=tuple(range(start, start + n)) if n > 0 else (),
        base_body_id=int(base),
        floor_geom_ids=used or tuple(floor_ids),
        nq=int(m.nq),
        nv=int(m.nv),
        mass_kg=model_mass(m),
    )
    return desc, resolved


def robot_description(m: mujoco.MjModel, foot_names=None) -> RobotDescription:
    """The description of a robot model that ``load_robot`` (the log commands: simulate,
    evaluate, estimate, export, tune) uses.

    Where the feet are single sphere geoms (no names and some floor-touching sphere, or
    every name a floor-touching sphere geom or the body of one), :func:`jax_contact.robot.
    derive_description`'s: the distal sphere of each joint chain. Otherwise
    :func:`describe`'s, as the wrapper resolves feet (module docstring): a box, cylinder
    or mesh sole (Berkeley Humanoid's ``l_foot1``), a body of several geoms (T1's corner
    spheres, G1's ``<pair>`` feet), a site, a body; without names, where a foot found by
    its rule is several level spheres (T1), or no floor-touching sphere exists. Its errors
    name the foot and list the valid names.
    """
    if foot_names is not None and (isinstance(foot_names, str) or not len(foot_names)):
        raise ValueError(f"foot_names must be a non-empty sequence of names, got {foot_names!r}")
    _, spheres = floor_spheres(m)
    if foot_names is None:
        use_spheres = bool(spheres)
        if use_spheres:
            # Feet of several level spheres (T1's corners) are found as the wrapper finds
            # them, one sole each; feet of one sphere by the distal-sphere rule, as before.
            try:
                desc, resolved = describe(m)
            except ValueError:
                pass  # derive_description's rule, and its errors
            else:
                if any(len(f.geom_ids) > 1 for f in resolved):
                    return desc
    else:
        # A body whose several spheres touch the floor (T1's four corners) is one foot of
        # those spheres, as the wrapper reads its name, not its first sphere.
        per_body = Counter(int(m.geom_bodyid[g]) for g in spheres)
        names = sphere_foot_names(m, spheres) - {
            m.body(b).name for b, n in per_body.items() if n > 1
        } | {m.geom(g).name for g in spheres if m.geom(g).name}
        use_spheres = all(isinstance(n, str) and n in names for n in foot_names)
    if use_spheres:
        return derive_description(m, foot_names)
    return describe(m, foot_names)[0]


def foot_points_np(m: mujoco.MjModel, d: mujoco.MjData, desc: RobotDescription) -> np.ndarray:
    """(n_legs, 3) world contact points from C-library data (after kinematics)."""
    return np.stack(
        [
            d.xpos[b] + d.xmat[b].reshape(3, 3) @ np.asarray(off)
            for b, off in zip(desc.foot_body_ids, desc.foot_offsets, strict=True)
        ]
    )
