"""Ground-truth foot contact for the wrapper's metrics and its ``observe="truth"`` mode.

Sources (``ContactObsConfig.truth``), each a function ``mjx.Data -> (n_legs,) bool``; a
foot is in contact if any of its geoms (:mod:`jax_contact.envs.feet`) is:

- ``"force_sensors"``: the contact force sensors of
  :func:`jax_contact.envs.ground_truth.with_contact_sensors` (normal force > ``truth_threshold``);
- ``"found_sensors"``: the model's own contact sensors with ``data="found"`` between a
  foot geom (or the foot's body) and the floor: Playground's ``<foot>_floor_found``
  (Go1, Spot, Berkeley Humanoid's ``l_foot1_floor_found``...);
- ``"touch_sensors"``: the model's touch sensors on a site of the foot's body (normal
  force in the site's volume > ``truth_threshold``);
- ``"contacts"``: ``mjx.Data.contact`` and ``efc_force``, for models with none of these
  sensors (G1, T1, Brax's ant): the normal force of every contact between a foot geom
  and a floor geom, summed, > ``truth_threshold``. The normal force of a pyramidal-cone
  contact is the sum of its ``2 (dim - 1)`` pyramid-edge forces, of an elliptic one its
  first row (MuJoCo's ``mj_contactForce``). MJX 3.17 exposes ``contact`` and
  ``efc_force`` of the JAX implementation only through ``mjx.Data``'s deprecated
  pass-through (the fields live in the private ``_impl``); it is read through that
  public accessor, its ``DeprecationWarning`` silenced at trace time;
- ``"auto"``: the first of these that covers every foot; ``"none"``: no truth, no metric.

Geometry (``ContactObsConfig.truth_gap``, default 1 mm): a foot whose sole is less than
``truth_gap`` above the floor's surface, or at or below it (the smallest signed
``mjx.Data.contact.dist`` of its geoms' floor contacts ``< truth_gap``), also counts as in
contact, whichever source is read.

- Inside the floor: a sole inside the floor is touching it. Playground's own ``found``
  sensors say so (MuJoCo counts a contact wherever ``dist`` is below the margin, 0 in
  these scenes, whatever its force); a force source alone calls air the steps where a
  foot that struck the soft floor is still inside it and rising out of it with zero
  constraint force. Playground's Go1 scene under random joint targets (plain MuJoCo,
  20000 foot-steps): 1333 foot-steps had a found contact and zero normal force, 1237 of
  them more than 1 mm deep. With this rule the force sensors of ``jax-contact rates``
  and the found sensors of Playground's scenes give one truth.
- Just above it: on Playground's Go1 (soft contact, one solver iteration, 4 ms steps;
  docs/training.md) a loaded foot at rest leaves the floor for 1-2 physics steps by
  0.1-0.7 mm (90 % below 0.7 mm), which every source above calls air; these
  micro-bounces were 45-65 % of all air phases of a scripted trot or walk. No estimator
  reading joint states can (or should) see them.

The rule is causal (no look-ahead), so the online metric keeps it; ``truth_gap=0``
gives the raw source.
"""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import mujoco
import numpy as np

from jax_contact.envs import ground_truth
from jax_contact.envs.robots import Robot

_SENS = mujoco.mjtSensor
_OBJ = mujoco.mjtObj


def _found_adr(m: mujoco.MjModel, foot, floor_ids) -> list[int]:
    geom, body = int(_OBJ.mjOBJ_GEOM), int(_OBJ.mjOBJ_BODY)
    mine = {(geom, g) for g in foot.geom_ids} | {(body, foot.body_id)}
    floors = {(geom, f) for f in floor_ids}
    out = []
    for s in range(m.nsensor):
        if int(m.sensor_type[s]) != int(_SENS.mjSENS_CONTACT) or not (m.sensor_intprm[s, 0] & 1):
            continue
        a = (int(m.sensor_objtype[s]), int(m.sensor_objid[s]))
        b = (int(m.sensor_reftype[s]), int(m.sensor_refid[s]))
        if (a in mine and b in floors) or (b in mine and a in floors):
            out.append(int(m.sensor_adr[s]))  # "found" is the first datum when present
    return out


def _touch_adr(m: mujoco.MjModel, foot) -> list[int]:
    return [
        int(m.sensor_adr[s])
        for s in range(m.nsensor)
        if int(m.sensor_type[s]) == int(_SENS.mjSENS_TOUCH)
        and int(m.site_bodyid[int(m.sensor_objid[s])]) == foot.body_id
    ]


def _any_over(adrs: list[list[int]], threshold: float, strict_positive: bool):
    width = max(len(a) for a in adrs)
    idx = np.array([a + [a[0]] * (width - len(a)) for a in adrs])  # pad with a repeat
    j = jnp.asarray(idx)
    if strict_positive:
        return lambda d: jnp.any(d.sensordata[j] > 0, axis=-1)
    return lambda d: jnp.any(d.sensordata[j] > threshold, axis=-1)


def contact_reader(m: mujoco.MjModel, feet, floor_ids, threshold: float):
    """``data -> (n_legs,) bool`` from ``mjx.Data.contact`` and ``efc_force`` (docstring)."""
    force = contact_normal_force(m, feet, floor_ids)
    return lambda d: force(d) > threshold


def contact_normal_force(m: mujoco.MjModel, feet, floor_ids):
    """``data -> (n_legs,)`` summed normal force of each foot's geoms on the floor, N."""
    foot_of_geom = np.full(m.ngeom, -1)
    for i, f in enumerate(feet):
        foot_of_geom[list(f.geom_ids)] = i
    is_floor = np.zeros(m.ngeom, bool)
    is_floor[list(floor_ids)] = True
    pyramidal = int(m.opt.cone) == int(mujoco.mjtCone.mjCONE_PYRAMIDAL)
    n_legs = len(feet)

    def read(d):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            con, efc_force = d.contact, d.efc_force
        adr, dim = np.asarray(con.efc_address), np.asarray(con.dim)
        if adr.size == 0:
            return jnp.zeros((n_legs,), jnp.float32)
        rows = np.where(pyramidal & (dim > 1), 2 * (dim - 1), 1)
        width = int(rows.max())
        idx = adr[:, None] + np.arange(width)[None]
        use = (np.arange(width)[None] < rows[:, None]) & (adr[:, None] >= 0)
        fn = jnp.sum(jnp.where(use, efc_force[np.clip(idx, 0, None)], 0.0), axis=1)
        g1, g2 = con.geom[:, 0], con.geom[:, 1]
        fog, flo = jnp.asarray(foot_of_geom), jnp.asarray(is_floor)
        leg = jnp.where(flo[g2], fog[g1], jnp.where(flo[g1], fog[g2], -1))
        per_leg = jnp.zeros((n_legs + 1,), fn.dtype).at[jnp.where(leg < 0, n_legs, leg)].add(fn)
        return per_leg[:n_legs]

    return read


def contact_gap(m: mujoco.MjModel, feet, floor_ids):
    """``data -> (n_legs,)`` smallest signed distance of each foot's geoms to a floor, m.

    From ``mjx.Data.contact.dist`` (MJX keeps every candidate geom pair, so a foot above
    the floor has a positive distance); ``inf`` where a foot has no floor pair.
    """
    foot_of_geom = np.full(m.ngeom, -1)
    for i, f in enumerate(feet):
        foot_of_geom[list(f.geom_ids)] = i
    is_floor = np.zeros(m.ngeom, bool)
    is_floor[list(floor_ids)] = True
    n_legs = len(feet)

    def read(d):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            con = d.contact
        if np.asarray(con.dim).size == 0:
            return jnp.full((n_legs,), jnp.inf, jnp.float32)
        g1, g2 = con.geom[:, 0], con.geom[:, 1]
        fog, flo = jnp.asarray(foot_of_geom), jnp.asarray(is_floor)
        leg = jnp.where(flo[g2], fog[g1], jnp.where(flo[g1], fog[g2], -1))
        init = jnp.full((n_legs + 1,), jnp.inf, con.dist.dtype)
        per_leg = init.at[jnp.where(leg < 0, n_legs, leg)].min(con.dist)
        return per_leg[:n_legs]

    return read


def with_gap(reader, m: mujoco.MjModel, feet, floor_ids, gap: float):
    """``reader``, or a sole less than ``gap`` (m) above the floor or inside it (module doc)."""
    if reader is None or gap <= 0 or not all(f.geom_ids for f in feet):
        return reader
    dist = contact_gap(m, feet, floor_ids)
    return lambda d: reader(d) | (dist(d) < gap)


def truth_reader(m: mujoco.MjModel, desc, feet, source: str, threshold: float, gap: float = 0.0):
    """(``data -> (n_legs,) bool`` or None, the source used). Raises if ``source`` fails.

    ``gap``: the tolerance of the module docstring, m (0: none).
    """
    reader, name = _source_reader(m, desc, feet, source, threshold)
    if reader is None:
        return reader, name
    return with_gap(reader, m, feet, desc.floor_geom_ids, gap), name


def _source_reader(m: mujoco.MjModel, desc, feet, source: str, threshold: float):
    if source in ("auto", "force_sensors"):
        robot = Robot(name="wrapped env", mj_model=m, description=desc, spec=None)
        try:
            layout = ground_truth.make_truth_layout(robot, threshold=threshold)
        except (ValueError, IndexError):
            if source == "force_sensors":
                raise ValueError(
                    "config.truth='force_sensors': the model lacks the sensors of"
                    " jax_contact.envs.ground_truth.with_contact_sensors for every foot"
                ) from None
        else:
            return (lambda d: ground_truth.foot_truth(layout, d).contact), "force_sensors"
    floor_ids = desc.floor_geom_ids
    for name, adrs, positive in (
        ("found_sensors", [_found_adr(m, f, floor_ids) for f in feet], True),
        ("touch_sensors", [_touch_adr(m, f) for f in feet], False),
    ):
        if source in ("auto", name):
            if all(adrs):
                return _any_over(adrs, threshold, positive), name
            if source == name:
                missing = [f.name for f, a in zip(feet, adrs, strict=True) if not a]
                raise ValueError(
                    f"config.truth={name!r}: no such sensor between the floor and feet {missing}"
                )
    if source in ("auto", "contacts"):
        if all(f.geom_ids for f in feet):
            return contact_reader(m, feet, floor_ids, threshold), "contacts"
        if source == "contacts":
            raise ValueError("config.truth='contacts': a foot has no geom that touches the floor")
    return None, "none"
