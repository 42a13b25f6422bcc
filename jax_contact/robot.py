"""What the estimator needs to know about a legged robot, derived from its MuJoCo model.

A :class:`RobotDescription` names the feet and splits the generalised velocities into each
leg's joints and the rest (eq. 4's ``l`` and ``b``). It holds only Python ints, floats,
strings and tuples, so it is hashable and can be a static argument of ``jax.jit``.

:func:`derive_description` reads a compiled ``mujoco.MjModel`` (C library only, no MJX):

- the floor: geoms of the world body of type plane or height field;
- the feet: sphere geoms of other bodies that can collide with a floor geom (MuJoCo's
  contype/conaffinity rule: ``(contype_a & conaffinity_b) | (contype_b & conaffinity_a)``),
  or the geoms / bodies named by the caller. Unnamed, only the distal sphere of each joint
  chain is a foot: a sphere on a body below which no other body carries such a sphere, and
  of that body's spheres the one farthest from its joint (the body origin where it has
  none). On models whose every collision geom is a sphere (Menagerie's Go2 MJX model:
  hips, thighs, calves and feet) that is the foot at the end of each leg;
- the base: the body with a free joint on the chain from a foot to the world, else the
  first body under the world on that chain (e.g. the planar leg's base on its rail);
- each leg: the dofs of the joints on the chain from the foot's body up to, not including,
  the base, except a joint that other feet hang from too (a waist, a spine): it counts
  with the base (:func:`split_legs`).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence

import mujoco
import numpy as np

_FLOOR_TYPES = (int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_HFIELD))
_JOINT_TRANSMISSIONS = (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT))
# dofs per joint type, indexed by mjtJoint (free, ball, slide, hinge)
_JOINT_DOFS = (6, 3, 1, 1)
_ROTARY = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_BALL))


# The refusal of a model without a floor (a model converted from URDF has none).
NO_FLOOR = (
    "the robot model has no floor: no plane or height-field geom in its world body; add one"
    ' to <worldbody>, e.g. <geom name="floor" type="plane" size="5 5 .1"/>, at the height'
    " of the ground the readings stand on (z = 0 for a base estimate relative to the ground)"
)


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """Feet, legs and coordinate split of a legged robot. Hashable; all fields static.

    Legs are listed in foot order; every leg has the same number ``n_l`` of dofs.

    Attributes:
      foot_names: foot geom names (the body name where the geom has none).
      foot_body_ids: body carrying each foot geom.
      foot_geom_ids: the foot sphere geoms.
      foot_offsets: each foot sphere's centre in its body frame, (x, y, z), m.
      foot_radii: each foot sphere's radius, m.
      foot_soles: per foot, the points its contact rolls between, in its body frame,
        ((x, y, z), ...), m: a flat sole's corners, or the centres of a foot's spheres and
        the ends of its capsules (one radius), for the rolling contact point of
        :func:`jax_contact.adapter.contact_points`; empty for a sphere foot (default:
        none; :attr:`soles` has one entry per foot either way).
      leg_dofs: per leg, the indices into ``nv`` of its joints' dofs, base side first: the
        joints between the foot and the base that no other foot hangs from
        (:func:`split_legs`; a waist or spine above several feet is not in any leg).
      other_dofs: per leg, the complement of ``leg_dofs`` in ``range(nv)``, ascending.
      base_dofs: dofs of the base's own joints (6 for a free joint, 1 for the planar
        leg's rail, empty for a fixed base).
      base_body_id: the base body.
      floor_geom_ids: world geoms (plane or height field) that some foot can touch.
      nq: number of generalised coordinates.
      nv: number of generalised velocities.
      mass_kg: the model's total mass (:func:`model_mass`), kg; None where unknown. It
        scales the contact force uncertainty that :func:`jax_contact.params_for` derives.
    """

    foot_names: tuple[str, ...]
    foot_body_ids: tuple[int, ...]
    foot_geom_ids: tuple[int, ...]
    foot_offsets: tuple[tuple[float, float, float], ...]
    foot_radii: tuple[float, ...]
    leg_dofs: tuple[tuple[int, ...], ...]
    other_dofs: tuple[tuple[int, ...], ...]
    base_dofs: tuple[int, ...]
    base_body_id: int
    floor_geom_ids: tuple[int, ...]
    nq: int
    nv: int
    foot_soles: tuple[tuple[tuple[float, float, float], ...], ...] = ()
    mass_kg: float | None = None

    @property
    def n_legs(self) -> int:
        """Number of feet (L)."""
        return len(self.foot_names)

    @property
    def soles(self) -> tuple[tuple[tuple[float, float, float], ...], ...]:
        """``foot_soles`` with one entry per foot, ``()`` for a foot without a sole (a
        description of sphere feet leaves ``foot_soles`` empty)."""
        return self.foot_soles or ((),) * self.n_legs

    @property
    def n_leg_dofs(self) -> int:
        """``n_l``, the number of dofs of every leg."""
        return len(self.leg_dofs[0])


def model_mass(m: mujoco.MjModel) -> float:
    """The robot's mass, kg: every body that moves under the physics (``body_weldid != 0``,
    not a mocap body).

    A body welded to the world (a staircase of the scene) or a mocap body (a target the
    user moves) is scenery: Go1's Playground stairs scene holds a 300 kg static ``stairs``
    body, which counted as robot made Go1 weigh 312.7 kg there, so the sign-test rule
    (``envs.contact_params.choose_unilateral``) read a foot load of 767 N instead of 31 N
    and Go1's own preset warned that it was tuned on another robot (masses x24.5). No
    shipped robot or other Playground robot scene has a static body with mass: their masses
    are unchanged.
    """
    return float(np.sum(m.body_mass[(m.body_weldid != 0) & (m.body_mocapid < 0)]))


# The compiled model's arrays that the estimator and the physics read: bodies' kinematic
# tree and inertia, joints, dofs, collision geoms and actuators (no names, keyframes or
# visuals, so a renamed or re-meshed file keeps its fingerprint).
_FINGERPRINT_FIELDS = (
    "body_parentid", "body_pos", "body_quat", "body_mass", "body_ipos", "body_iquat",
    "body_inertia", "jnt_type", "jnt_bodyid", "jnt_pos", "jnt_axis", "jnt_range",
    "dof_armature", "dof_damping", "dof_frictionloss", "geom_type", "geom_bodyid",
    "geom_size", "geom_pos", "geom_quat", "geom_contype", "geom_conaffinity",
    "actuator_trnid", "actuator_gear", "actuator_gainprm", "actuator_biasprm",
)  # fmt: skip


def model_fingerprint(m: mujoco.MjModel) -> str:
    """SHA-256 (hex) of the compiled model's physics (:data:`_FINGERPRINT_FIELDS`, float
    fields rounded to 9 significant digits): two loads of one robot agree, an edited leg
    or mass does not. Stored in simulated logs; a replay on another model warns."""
    import hashlib

    h = hashlib.sha256(f"nq={m.nq} nv={m.nv} nbody={m.nbody}".encode())
    for name in _FINGERPRINT_FIELDS:
        a = np.asarray(getattr(m, name))
        if a.dtype.kind == "f":
            a = np.round(a.astype(np.float64), 9)
        h.update(name.encode() + a.tobytes())
    return h.hexdigest()


def _can_collide(m: mujoco.MjModel, a: int, b: int) -> bool:
    return bool(
        (m.geom_contype[a] & m.geom_conaffinity[b]) or (m.geom_contype[b] & m.geom_conaffinity[a])
    )


def _geom_label(m: mujoco.MjModel, g: int) -> str:
    return m.geom(g).name or m.body(m.geom_bodyid[g]).name


def body_chain(m: mujoco.MjModel, body: int) -> list[int]:
    """Bodies from ``body`` up to (not including) the world, ``body`` first."""
    chain = []
    while body != 0:
        chain.append(body)
        body = int(m.body_parentid[body])
    return chain


def _body_dofs(m: mujoco.MjModel, body: int) -> list[int]:
    start, num = int(m.body_dofadr[body]), int(m.body_dofnum[body])
    return list(range(start, start + num)) if num > 0 else []


def actuated_dofs(m: mujoco.MjModel) -> set[int]:
    """The dofs of every joint a joint actuator drives (``joint`` or ``jointinparent``)."""
    out: set[int] = set()
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) in _JOINT_TRANSMISSIONS:
            j = int(m.actuator_trnid[a, 0])
            start = int(m.jnt_dofadr[j])
            out.update(range(start, start + _JOINT_DOFS[int(m.jnt_type[j])]))
    return out


def leg_of(m: mujoco.MjModel, body: int, actuated: set[int]) -> tuple[int, list[int]]:
    """(base body, sorted dofs of the joints between ``body`` and the base).

    The base is the body with the free joint on ``body``'s chain. Without one, it is the
    chain's top body (a mount: the planar leg's passive rail, a cart), unless that body
    turns on actuated hinges: then it is a hip bolted to the world, the base is the world
    (body 0, no dofs) and the hip is a leg joint like the others.
    """
    chain = body_chain(m, body)
    joints = lambda b: range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b])  # noqa: E731
    free = int(mujoco.mjtJoint.mjJNT_FREE)
    with_free = [b for b in chain if any(int(m.jnt_type[j]) == free for j in joints(b))]
    top = chain[-1]
    if with_free:
        base = with_free[0]
    elif actuated.intersection(_body_dofs(m, top)) and all(
        int(m.jnt_type[j]) in _ROTARY for j in joints(top)
    ):
        base = 0  # a hip bolted to the world
    else:
        base = top
    leg_bodies = chain[: chain.index(base)] if base else chain
    return base, sorted(d for b in leg_bodies for d in _body_dofs(m, b))


def unactuated_leg(
    m: mujoco.MjModel, label: str, dofs: Sequence[int], actuated: set[int], note: str = ""
) -> ValueError:
    """The refusal of a foot whose leg has no joint actuator, naming its joints."""
    joints = [m.joint(int(m.dof_jntid[d])).name or f"<dof {d}>" for d in dofs]
    every = "" if actuated else " (the model has no joint actuator at all)"
    return ValueError(
        f"foot {label!r}: none of its leg's joints {joints} is driven by a joint"
        f" actuator{every}; the estimator needs joint torques (add a motor or position"
        f" actuator per joint){note}"
    )


def split_legs(
    m: mujoco.MjModel,
    chains: Sequence[Sequence[int]],
    labels: Sequence[str],
    actuated: set[int],
) -> tuple[tuple[tuple[int, ...], ...], tuple[tuple[int, ...], ...]]:
    """Eq. 4's split of each foot's coordinates into its leg ``l`` and the rest ``b``.

    ``chains`` holds, per foot, the dofs between it and the base (:func:`leg_of`). A dof on
    the chains of several feet (a waist or a spine above two legs) carries the forces of
    every foot below it, while eq. 6 explains the leg's torques by its own foot's force
    alone: such a dof counts with the base, in every foot's ``b``. Robots whose legs meet
    only at the base (every shipped robot) keep their whole chains.

    Returns:
      ``(leg_dofs, other_dofs)`` as :class:`RobotDescription` holds them.

    Raises:
      ValueError: a foot with no actuated joint of its own (two feet on one body or one
        chain: name them as one foot), naming the feet that share its joints.
    """
    uses: dict[int, int] = {}
    for chain in chains:
        for d in set(chain):
            uses[d] = uses.get(d, 0) + 1
    legs = tuple(tuple(d for d in chain if uses[d] == 1) for chain in chains)
    for leg, chain, label in zip(legs, chains, labels, strict=True):
        if not actuated.intersection(leg):
            sharing = [
                other
                for other, c in zip(labels, chains, strict=True)
                if other != label and set(c) & set(chain)
            ]
            joints = [m.joint(int(m.dof_jntid[d])).name or f"<dof {d}>" for d in chain]
            raise ValueError(
                f"foot {label!r} has no actuated joint of its own: its joints {joints} are"
                f" shared with foot(s) {sharing}, whose forces they also carry; feet on one"
                " body or one chain are one foot (name their body, or one of them)"
            )
    others = tuple(tuple(d for d in range(m.nv) if d not in leg) for leg in legs)
    return legs, others


def warn_joints_below(
    m: mujoco.MjModel, bodies: Sequence[int], labels: Sequence[str], actuated: set[int]
) -> None:
    """Warns, once, naming each foot whose body has actuated joints below it.

    A foot is the end of a leg: the estimator explains the leg's torques by a force at the
    foot (eq. 6), so a "foot" named on a hip or a thigh leaves the real foot's contact
    forces in joints it treats as the rest of the body (eq. 4's ``b``), and its estimate
    means nothing. A joint below the foot can be legitimate (a toe), so this warns instead
    of refusing, naming the joints.
    """
    found = []
    for body, label in zip(bodies, labels, strict=True):
        below = [
            int(m.dof_jntid[d])
            for c in range(m.nbody)
            if body in body_chain(m, c)[1:]
            for d in _body_dofs(m, c)
            if d in actuated
        ]
        if below:
            names = [m.joint(j).name or f"<joint {j}>" for j in dict.fromkeys(below)]
            found.append(f"{label!r} (body {m.body(body).name!r}: {', '.join(names)})")
    if found:
        warnings.warn(
            f"feet with actuated joints below them: {'; '.join(found)}. A foot is the end of"
            " its leg, so these look like hips, thighs or knees; name each foot's geom, site"
            " or lowest body. The estimate means contact only where the named point is what"
            " touches the ground",
            stacklevel=3,
        )


def _distal(spheres: list[int], m: mujoco.MjModel) -> list[int]:
    """The distal sphere of each joint chain among ``spheres``, in geom order."""
    bodies = {int(m.geom_bodyid[g]) for g in spheres}
    # A body is inner if another candidate body hangs below it.
    inner = {b for c in bodies for b in body_chain(m, c)[1:]}
    out = []
    for b in sorted(bodies - inner):
        on_body = [g for g in spheres if int(m.geom_bodyid[g]) == b]
        anchor = m.jnt_pos[m.body_jntadr[b]] if m.body_jntnum[b] > 0 else np.zeros(3)
        out.append(max(on_body, key=lambda g: float(np.linalg.norm(m.geom_pos[g] - anchor))))
    return sorted(out)


def floor_spheres(m: mujoco.MjModel) -> tuple[list[int], list[int]]:
    """(the floor geoms: planes and height fields of the world body; the sphere geoms
    outside the world body that can collide with one of them), geom ids."""
    floors = [
        g for g in range(m.ngeom) if m.geom_bodyid[g] == 0 and int(m.geom_type[g]) in _FLOOR_TYPES
    ]
    spheres = [
        g
        for g in range(m.ngeom)
        if int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_SPHERE)
        and m.geom_bodyid[g] != 0
        and any(_can_collide(m, g, f) for f in floors)
    ]
    return floors, spheres


def sphere_foot_names(m: mujoco.MjModel, spheres: Sequence[int]) -> set[str]:
    """The names that :func:`derive_description` takes as feet: those of ``spheres``
    (:func:`floor_spheres`) and of their bodies (unnamed ones left out)."""
    return {m.geom(g).name for g in spheres if m.geom(g).name} | {
        m.body(m.geom_bodyid[g]).name for g in spheres if m.body(m.geom_bodyid[g]).name
    }


def derive_description(
    mj_model: mujoco.MjModel, foot_names: Sequence[str] | None = None
) -> RobotDescription:
    """Derives feet, legs and the coordinate split from a compiled model.

    Args:
      mj_model: the compiled model, including its floor.
      foot_names: geom or body names of the feet, in the order the legs should have; None
        takes the distal sphere of each joint chain that can touch the floor (module
        docstring), in geom order.

    Returns:
      The robot's description.

    Raises:
      ValueError: with the reason, if the model has no floor, no foot can touch the floor,
        a name is not a foot (the message lists the valid names), a foot's leg has no
        actuated joint, or the legs have different numbers of dofs.
    """
    m = mj_model
    floors, candidates = floor_spheres(m)
    if not floors:
        raise ValueError(NO_FLOOR)
    if not candidates:
        raise ValueError(
            "mj_model has no floor contact: no sphere geom outside the world body can collide"
            " with the floor (check contype/conaffinity)"
        )

    actuated = actuated_dofs(m)
    if foot_names is None:
        # A sphere on the base itself (a bumper) can touch the floor but is no foot.
        feet = _distal([g for g in candidates if leg_of(m, int(m.geom_bodyid[g]), actuated)[1]], m)
        if not feet:
            raise ValueError(
                "mj_model has no floor contact through a leg: the sphere geoms that can touch"
                " the floor have no joint between them and the base"
            )
    else:
        if isinstance(foot_names, str) or len(foot_names) == 0:
            raise ValueError(
                f"foot_names must be a non-empty sequence of names, got {foot_names!r}"
            )
        valid = sorted(sphere_foot_names(m, candidates))
        feet = []
        for name in foot_names:
            by_geom = [g for g in candidates if m.geom(g).name == name]
            by_body = [g for g in candidates if m.body(m.geom_bodyid[g]).name == name]
            if by_geom:
                feet.append(by_geom[0])
            elif by_body:
                feet.append(by_body[0])
            else:
                raise ValueError(
                    f"foot_names: {name!r} is not a sphere geom (or the body of one) that can"
                    f" touch the floor; valid names: {valid}"
                )
        if len(set(feet)) != len(feet):
            raise ValueError(f"foot_names name the same foot twice: {list(foot_names)}")

    legs, bases = [], []
    for g in feet:
        base, dofs = leg_of(m, int(m.geom_bodyid[g]), actuated)
        label = _geom_label(m, g)
        if not dofs:
            raise ValueError(f"foot {label!r} has no leg: no joint between it and the base")
        if not actuated.intersection(dofs):
            raise unactuated_leg(m, label, dofs, actuated)
        legs.append(tuple(dofs))
        bases.append(base)
    legs, others = split_legs(m, legs, [_geom_label(m, g) for g in feet], actuated)
    if foot_names is not None:  # found feet are at the ends of their chains (_distal)
        warn_joints_below(m, [int(m.geom_bodyid[g]) for g in feet], list(foot_names), actuated)

    if len({len(d) for d in legs}) != 1:
        raise ValueError(
            "every leg must have the same number of dofs, got "
            + ", ".join(f"{_geom_label(m, g)}: {len(d)}" for g, d in zip(feet, legs, strict=True))
        )
    if len(set(bases)) != 1:
        raise ValueError(
            "the feet hang from different bases: "
            + ", ".join(
                f"{_geom_label(m, g)}: {m.body(b).name}" for g, b in zip(feet, bases, strict=True)
            )
        )
    base = bases[0]
    used_floors = tuple(f for f in floors if any(_can_collide(m, g, f) for g in feet))
    return RobotDescription(
        foot_names=tuple(_geom_label(m, g) for g in feet),
        foot_body_ids=tuple(int(m.geom_bodyid[g]) for g in feet),
        foot_geom_ids=tuple(int(g) for g in feet),
        foot_offsets=tuple(tuple(float(x) for x in m.geom_pos[g]) for g in feet),
        foot_radii=tuple(float(m.geom_size[g, 0]) for g in feet),
        leg_dofs=legs,
        other_dofs=others,
        base_dofs=tuple(_body_dofs(m, base)),
        base_body_id=int(base),
        floor_geom_ids=used_floors,
        nq=int(m.nq),
        nv=int(m.nv),
        mass_kg=model_mass(m),
    )
