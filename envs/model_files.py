"""Where each named robot's MJCF comes from, and how it loads offline.

:func:`robot_spec` resolves a name of :data:`ROBOT_NAMES` or a path to the ``mujoco.MjSpec``
that :func:`jax_contact.envs.robots.load_robot` compiles. Nothing is downloaded at run
time:

- ``go1``, ``spot``: the MJX scenes that ship with the ``playground`` package
  (``mujoco_playground/_src/locomotion/{go1,spot}/xmls/scene_mjx_feetonly_flat_terrain.xml``,
  the feet-only-contact scene of the joystick environments, with its flat floor). They
  reference Menagerie meshes that the package does not ship; those meshes are visual only
  (every body has an explicit ``<inertial>`` and every mesh geom has ``contype = conaffinity
  = 0``), so the mesh geoms and mesh assets are deleted before compiling. Masses,
  inertias, joints, actuators and collision geoms stay exactly as shipped.
- ``barkour``: ``mujoco/mjx/test_data/barkour_v0/assets/barkour_v0_mjx.xml`` from the
  ``mujoco-mjx`` package, meshes included. The scene's floor, a height field of random
  blocks (0-5 cm), is replaced by a plane at ``z = 0`` (until 2026-12-03 it was kept, so
  Barkour's "flat" runs before then were on those blocks: docs/model_choices.md).
- ``planar_leg``: the paper's Section III leg, ``envs/assets/planar_leg.xml``.
- MuJoCo Menagerie names (``anybotics_anymal_c``, ...): from a local Menagerie checkout
  named by the ``MENAGERIE_ROOT`` environment variable, the MJX variant
  ``$MENAGERIE_ROOT/<name>/scene_mjx.xml`` where the model ships one, else
  ``$MENAGERIE_ROOT/<name>/scene.xml``; else through the ``mujoco_menagerie`` package,
  which downloads on first use. When neither works :class:`RobotUnavailableError` says
  what to do. As for the Playground robots, visual meshes (mesh geoms that cannot
  collide) and their assets are deleted before compiling, so the mesh files need not be on
  disk; masses and inertias are unchanged (a body whose inertia would come from a deleted
  mesh is refused). A mesh geom that can collide is kept and needs its file.
- any path to an MJCF file: its visual meshes are deleted in the same way where every
  body that holds one has an explicit ``<inertial>``; otherwise it is loaded as it is.

Menagerie models and MJCF paths are checked against MJX's collision functions: a pair of
geoms that can touch but whose types MJX cannot collide (e.g. a cylinder and a box in
ANYmal C's full ``anymal_c.xml``) is refused with a ValueError naming both geoms and the
file, rather than failing later in ``mjx.put_model``.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import mujoco

ASSETS_DIR = Path(__file__).resolve().parent / "assets"
PLANAR_LEG_XML = ASSETS_DIR / "planar_leg.xml"

# Quadrupeds of MuJoCo Menagerie this loader knows by name (loaded from MENAGERIE_ROOT or
# the mujoco_menagerie package, never bundled).
MENAGERIE_NAMES = (
    "anybotics_anymal_b",
    "anybotics_anymal_c",
    "boston_dynamics_spot",
    "google_barkour_v0",
    "google_barkour_vb",
    "unitree_a1",
    "unitree_go1",
    "unitree_go2",
)


class RobotUnavailableError(ValueError):
    """A known robot whose model files are not on this machine (and cannot be fetched)."""


def _package_dir(module: str) -> Path:
    import importlib.util

    spec = importlib.util.find_spec(module)
    if spec is None or not spec.submodule_search_locations:
        raise RobotUnavailableError(f"the Python package {module!r} is not installed")
    return Path(next(iter(spec.submodule_search_locations)))


def playground_xml(robot: str) -> Path:
    root = _package_dir("mujoco_playground")
    return root / "_src" / "locomotion" / robot / "xmls" / "scene_mjx_feetonly_flat_terrain.xml"


def _barkour_xml() -> Path:
    root = _package_dir("mujoco")
    return root / "mjx" / "test_data" / "barkour_v0" / "assets" / "barkour_v0_mjx.xml"


def _strip_meshes(spec: mujoco.MjSpec, source: Path, *, keep_colliding: bool = False) -> None:
    """Deletes visual-only mesh geoms and the mesh assets no geom uses any more, in place.

    A mesh geom that can collide is refused (ValueError), or kept with ``keep_colliding``
    (its mesh file is then needed to compile). Refuses (ValueError) if a deleted mesh
    geom could carry mass into a body's inertia, since deleting it would then change the
    dynamics.
    """
    bodies_with_meshes = set()
    kept_meshes = set()
    for geom in list(spec.geoms):
        if geom.type != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        if geom.contype != 0 or geom.conaffinity != 0:
            if keep_colliding:
                kept_meshes.add(geom.meshname)
                continue
            raise ValueError(
                f"{source}: mesh geom {geom.name or '<unnamed>'} can collide"
                f" (contype {geom.contype}, conaffinity {geom.conaffinity}); its mesh file is"
                " needed, so this model cannot be loaded without the Menagerie assets"
            )
        bodies_with_meshes.add(geom.parent.name)
        spec.delete(geom)
    inertia_from_geom = spec.compiler.inertiafromgeom
    for body in spec.bodies:
        if body.name not in bodies_with_meshes:
            continue
        explicit = body.explicitinertial
        if inertia_from_geom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or not explicit:
            raise ValueError(
                f"{source}: body {body.name!r} takes its inertia from geoms including meshes;"
                " deleting the meshes would change its mass"
            )
    for mesh in list(spec.meshes):
        if mesh.name not in kept_meshes:
            spec.delete(mesh)
    # Textures read from files are visual only (Menagerie's A1 paints its trunk with
    # trunk_A1.png): deleted with the meshes, so their files need not exist either.
    dropped = {texture.name for texture in spec.textures if texture.file}
    for material in spec.materials:
        material.textures = ["" if name in dropped else name for name in material.textures]
    for texture in list(spec.textures):
        if texture.name in dropped:
            spec.delete(texture)


def check_mjx_collisions(mj_model: mujoco.MjModel, source: str | Path) -> None:
    """Raises ValueError naming two geoms and ``source`` if MJX cannot collide them.

    ``mjx.put_model`` refuses a model with a pair of geoms that can touch (contype /
    conaffinity, explicit ``<pair>``) whose types have no MJX collision function, or whose
    margin or gap MJX does not implement for those types (a sphere foot with Menagerie's
    ``margin="0.001"`` on a height field), with a message that names only the two types;
    this names the first such pair.
    """
    from mujoco import mjx

    try:
        mjx.put_model(mj_model)
    except NotImplementedError as err:
        message = str(err)
        found = re.search(
            r"(mjGEOM_\w+), (?:mjtGeom\.)?(mjGEOM_\w+)\) (collisions|margin/gap) not", message
        )
        pair = None
        margin = bool(found) and found.group(3) == "margin/gap"

        def has_gap(g: int) -> bool:
            return bool(mj_model.geom_margin[g] or mj_model.geom_gap[g])

        if found:
            want = {
                getattr(mujoco.mjtGeom, found.group(1)),
                getattr(mujoco.mjtGeom, found.group(2)),
            }
            try:  # MJX's own enumeration of candidate pairs (private; only on this error path)
                from mujoco.mjx._src.collision_driver import geom_pairs

                for g1, g2, _ in geom_pairs(mj_model):
                    types = {mujoco.mjtGeom(int(mj_model.geom_type[g])) for g in (g1, g2)}
                    if types == want and (not margin or has_gap(g1) or has_gap(g2)):
                        pair = (g1, g2)
                        break
            except ImportError:
                pass
        if pair is None:
            raise ValueError(f"{source}: MJX cannot load this model ({message})") from None

        def label(g: int) -> str:
            kind = mujoco.mjtGeom(int(mj_model.geom_type[g])).name.removeprefix("mjGEOM_")
            body = mj_model.body(mj_model.geom_bodyid[g]).name
            return f"{mj_model.geom(g).name or '<unnamed>'} ({kind.lower()}, body {body})"

        names = [label(g) for g in pair]
        if margin:
            with_margin = [
                f"{names[i]}: margin {mj_model.geom_margin[g]:g}, gap {mj_model.geom_gap[g]:g}"
                for i, g in enumerate(pair)
                if has_gap(g)
            ]
            raise ValueError(
                f"{source}: geoms {names[0]} and {names[1]} can collide with a margin or gap"
                f" ({'; '.join(with_margin)}), which MJX does not implement for that pair of"
                f' types ({message.rstrip(".")}); set margin="0" gap="0" on those geoms in a'
                " copy of the model and pass its path"
            ) from None
        raise ValueError(
            f"{source}: geoms {names[0]} and {names[1]} can collide, but MJX has no collision"
            f" function for that pair of types ({message.rstrip('.')}); use the model's MJX"
            " variant (scene_mjx.xml) or set contype/conaffinity so they cannot touch"
        ) from None


def _load_playground(robot: str) -> mujoco.MjSpec:
    path = playground_xml(robot)
    if not path.is_file():
        raise RobotUnavailableError(
            f"{path} not found: the installed playground package does not ship the {robot}"
            " MJX model (playground==0.2.0 does)"
        )
    spec = mujoco.MjSpec.from_file(str(path))
    _strip_meshes(spec, path)
    return spec


def _load_barkour() -> mujoco.MjSpec:
    path = _barkour_xml()
    if not path.is_file():
        raise RobotUnavailableError(
            f"{path} not found: the installed mujoco-mjx package does not ship barkour_v0"
        )
    spec = mujoco.MjSpec.from_file(str(path))
    # MJX's test scene stands the robot on random blocks (height field "rand_uniform":
    # 0-5 cm, std 1.5 cm, 14 cm cells), not a floor: give it the flat floor every other
    # built-in robot has (the scene's own commented-out plane, at z = 0), so that the
    # reproduction's flat scenarios are flat and its "rough" one is the only rough floor.
    floor = spec.geom("hfield_floor")
    hfield = spec.hfield(floor.hfieldname)
    floor.name, floor.type, floor.hfieldname = "floor", mujoco.mjtGeom.mjGEOM_PLANE, ""
    floor.size, floor.material = [0.0, 0.0, 0.05], "groundplane"
    spec.delete(hfield)
    return spec


MENAGERIE_SCENES = ("scene_mjx.xml", "scene.xml")  # the MJX variant first


def _load_menagerie(name: str) -> tuple[mujoco.MjSpec, Path | str]:
    """The spec of a Menagerie model (visual meshes deleted) and the file it came from."""
    root = os.environ.get("MENAGERIE_ROOT")
    if root:
        for scene in MENAGERIE_SCENES:
            path = Path(root) / name / scene
            if path.is_file():
                spec = mujoco.MjSpec.from_file(str(path))
                _strip_meshes(spec, path, keep_colliding=True)
                return spec, path
        raise RobotUnavailableError(
            f"robot {name!r}: MENAGERIE_ROOT={root!r} has no {name}/scene.xml (nor"
            f" {name}/scene_mjx.xml); point MENAGERIE_ROOT at a checkout of"
            " github.com/google-deepmind/mujoco_menagerie"
        )
    try:
        import mujoco_menagerie  # optional; it downloads models on first use
    except ImportError as err:
        raise RobotUnavailableError(
            f"robot {name!r} comes from MuJoCo Menagerie, which is not available here: set"
            " MENAGERIE_ROOT to a local checkout of github.com/google-deepmind/"
            "mujoco_menagerie, or `pip install mujoco-menagerie` on a machine with internet"
            " access (it downloads the model on first use)"
        ) from err
    try:
        entry = mujoco_menagerie.get(name)
        spec = entry.spec(entry.default_scene)  # the scene: robot, floor and lights
    except Exception as err:  # the package raises its own DownloadError offline
        raise RobotUnavailableError(
            f"robot {name!r} could not be loaded through mujoco_menagerie ({err}); the model"
            " must be downloaded first, or MENAGERIE_ROOT set to a local Menagerie checkout"
        ) from err
    source = f"mujoco_menagerie {name}"
    _strip_meshes(spec, Path(source), keep_colliding=True)
    return spec, source


_BUILTIN: dict[str, Callable[[], mujoco.MjSpec]] = {
    "go1": lambda: _load_playground("go1"),
    "spot": lambda: _load_playground("spot"),
    "barkour": _load_barkour,
    "planar_leg": lambda: mujoco.MjSpec.from_file(str(PLANAR_LEG_XML)),
}

BUILTIN_NAMES = tuple(_BUILTIN)  # shipped with the installed packages
ROBOT_NAMES = BUILTIN_NAMES + MENAGERIE_NAMES


def _looks_like_path(name: str) -> bool:
    return name.endswith((".xml", ".urdf")) or os.sep in name or "/" in name


def _refuse_urdf(path: Path) -> None:
    """Raises ValueError for a URDF (root element ``<robot>``), whatever its suffix: it has
    no floor, actuators or free base for the checks that follow to find."""
    with open(path, "rb") as f:
        head = f.read(4096).decode("utf-8", "replace")
    root = re.search(r"<\s*([A-Za-z_][\w.-]*)", re.sub(r"<[?!][^>]*>", "", head))
    if path.suffix.lower() == ".urdf" or (root and root.group(1) == "robot"):
        raise ValueError(
            f"{str(path)!r} is a URDF (root element <robot>); jax-contact reads MJCF: compile it"
            " with MuJoCo (mujoco.MjModel.from_xml_path, then mujoco.mj_saveLastXML) and add a"
            " floor plane, a free joint on the base and the joints' actuators"
        )


def _spec_from_file(path: Path) -> mujoco.MjSpec:
    """``MjSpec.from_file``, its parse error (two lines, no file name) as one line naming
    the file."""
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as err:
        reason = " ".join(str(err).split())
        raise ValueError(f"MJCF file {str(path)!r} cannot be read: {reason}") from None


def robot_spec(name: str) -> tuple[mujoco.MjSpec, Path | str | None, str | None]:
    """The spec of a robot name or MJCF path, before it is compiled.

    Args:
      name: one of :data:`ROBOT_NAMES`, or a path to an MJCF file (with its floor).

    Returns:
      ``(spec, source, kept_meshes)``: the spec (visual meshes deleted where that keeps
      the dynamics); the file whose collisions MJX must support (Menagerie models and
      paths), else None; why a file's visual meshes could not be dropped, else None.

    Raises:
      ValueError: an unknown name (the message lists the valid ones), a folder, a path
        that does not exist, a URDF or a file MuJoCo cannot parse.
      RobotUnavailableError: a known robot whose files are not on this machine.
    """
    source = None  # the file whose collisions MJX must support (Menagerie, paths)
    kept_meshes = None  # why a file's visual meshes could not be dropped
    if name in _BUILTIN:
        spec = _BUILTIN[name]()
    elif name in MENAGERIE_NAMES:
        spec, source = _load_menagerie(name)
    elif _looks_like_path(name):
        path = Path(name).expanduser()
        if path.is_dir():
            raise ValueError(f"MJCF file {str(path)!r} is a folder; name the .xml file in it")
        if not path.is_file():
            raise ValueError(f"MJCF file {str(path)!r} does not exist")
        _refuse_urdf(path)
        spec, source = _spec_from_file(path), path
        try:
            _strip_meshes(spec, path, keep_colliding=True)
        except ValueError as err:  # some inertia comes from a mesh: the model needs its files
            spec = _spec_from_file(path)
            kept_meshes = str(err).removeprefix(f"{path}: ")
    else:
        raise ValueError(
            f"unknown robot {name!r}; valid names: {', '.join(ROBOT_NAMES)}, or a path to an"
            " MJCF .xml file"
        )
    return spec, source, kept_meshes


def compile_spec(
    spec: mujoco.MjSpec, name: str, source: Path | str | None, kept_meshes: str | None
) -> mujoco.MjModel:
    """Compiles :func:`robot_spec`'s spec; MuJoCo's compiler error as one line naming the
    file (and, where a mesh file is missing, why the visual meshes were kept)."""
    try:
        return spec.compile()
    except ValueError as err:  # MuJoCo's compiler errors, e.g. a missing collision mesh
        message = f"{source or name}: {' '.join(str(err).split())}"
        if kept_meshes is not None:
            message += (
                f" (a mesh file's path is relative to {str(source.parent)!r}, or to the"
                f" compiler's meshdir; the visual meshes could not be dropped: {kept_meshes})"
            )
        raise ValueError(message) from None
