"""MuJoCo Playground locomotion envs built offline: any registry name whose meshes are visual.

The route. Playground's registry (``locomotion.load``) first calls
``mjx_env.ensure_menagerie_exists()``, which runs ``git clone`` of MuJoCo Menagerie when
``mjx_env.MENAGERIE_PATH`` does not exist: that fails without network. The env classes do
not clone: each robot's ``base.get_assets()`` reads the package's own XMLs and whatever is
under ``MENAGERIE_PATH / "<robot folder>"``, and the env compiles its scene with them. The
locomotion scenes include Menagerie *meshes* only, and only as visuals.

So :func:`load` (1) writes a stand-in Menagerie folder once per process (under the system's
temporary directory, ``jax_contact_playground/menagerie-<hash>``): for every robot package
of ``mujoco_playground._src.locomotion``, its Menagerie folder (the name its ``base.py``
joins to ``MENAGERIE_PATH``) with one placeholder file (a 1 cm tetrahedron, STL or OBJ) per
mesh file that the package's XMLs name; (2) points ``mjx_env.MENAGERIE_PATH`` at it *for
the duration of the env's construction only* (restored after, also on error; the folder
exists, so no clone is attempted) and calls the registry's ``locomotion.load`` with a fresh
default config; (3) checks that the placeholders changed nothing but visuals: the scene is
compiled again with placeholders 20 times larger, and every body mass, inertia and centre
of mass must be equal (explicit ``<inertial>`` everywhere), and every mesh geom must be
unable to collide (``contype = conaffinity = 0``, in no ``<pair>``). An env whose scene
needs more of Menagerie than its meshes (its robot XML, e.g. Barkour) or whose meshes carry
mass or collide is refused with the reason: :func:`offline_names` lists those that load.

``impl`` defaults to ``"jax"`` (Playground's default ``"warp"`` compiles for minutes on a
CPU, and the contact wrapper needs MJX's JAX implementation).
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import hashlib
import importlib
import os
import re
import struct
import tempfile
from pathlib import Path

import mujoco
import numpy as np
from mujoco_playground._src import locomotion, mjx_env

_MESH_FILE = re.compile(r'file="([^"]+\.(?:stl|STL|obj|OBJ))"')
_MENAGERIE_DIR = re.compile(r'MENAGERIE_PATH\s*/\s*"([A-Za-z0-9_]+)"')
_PACKAGES = Path(locomotion.__file__).parent


def _tetra(scale: float) -> np.ndarray:
    return np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32) * 0.01 * scale


def placeholder_mesh(name: str, scale: float = 1.0) -> bytes:
    """A tetrahedron (1 cm x ``scale``) as binary STL or OBJ, by ``name``'s suffix."""
    v = _tetra(scale)
    tris = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    if name.lower().endswith(".obj"):
        lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
        lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in tris]
        return ("\n".join(lines) + "\n").encode()
    out = b"\0" * 80 + struct.pack("<I", len(tris))
    for t in tris:
        out += struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *v[i]) for i in t)
        out += b"\0\0"
    return out


def _robot_packages() -> dict[str, tuple[str, tuple[str, ...]]]:
    """robot package -> (its Menagerie folder name, mesh file names its XMLs use)."""
    out = {}
    for pkg in sorted(p for p in _PACKAGES.iterdir() if (p / "base.py").is_file()):
        dirs = _MENAGERIE_DIR.findall((pkg / "base.py").read_text())
        if not dirs:
            continue
        meshes = set()
        for xml in pkg.rglob("*.xml"):
            meshes.update(Path(f).name for f in _MESH_FILE.findall(xml.read_text()))
        out[pkg.name] = (dirs[0], tuple(sorted(meshes)))
    return out


@functools.cache
def standin_menagerie() -> Path:
    """The stand-in Menagerie folder (module docstring), written once per process."""
    packages = _robot_packages()
    digest = hashlib.sha256(repr(sorted(packages.items())).encode()).hexdigest()[:16]
    root = Path(tempfile.gettempdir()) / "jax_contact_playground" / f"menagerie-{digest}"
    done = root / ".complete"
    if not done.is_file():
        for folder, meshes in packages.values():
            assets = root / folder / "assets"
            assets.mkdir(parents=True, exist_ok=True)
            for name in meshes:
                tmp = assets / f".{name}.{os.getpid()}.tmp"
                tmp.write_bytes(placeholder_mesh(name))
                os.replace(tmp, assets / name)  # atomic: another process may write it too
        done.write_text("")
    return root


@contextlib.contextmanager
def _menagerie_at(path: Path):
    """``mjx_env.MENAGERIE_PATH`` = ``path`` for a while (get_assets reads it at call time)."""
    old = mjx_env.MENAGERIE_PATH
    mjx_env.MENAGERIE_PATH = type(old)(path)
    try:
        yield
    finally:
        mjx_env.MENAGERIE_PATH = old


ENV_NAMES = tuple(sorted(locomotion.ALL_ENVS))  # every locomotion registry name


def _base_module(env):
    pkg = type(env).__module__.rsplit(".", 1)[0]
    return importlib.import_module(pkg + ".base")


def check_visual_only(env) -> None:
    """Raises ValueError unless the placeholder meshes can change nothing but visuals."""
    m = env.mj_model
    mesh = int(mujoco.mjtGeom.mjGEOM_MESH)
    paired = set(np.asarray(m.pair_geom1).tolist()) | set(np.asarray(m.pair_geom2).tolist())
    for g in range(m.ngeom):
        if int(m.geom_type[g]) == mesh and (
            m.geom_contype[g] or m.geom_conaffinity[g] or g in paired
        ):
            raise ValueError(
                f"mesh geom {m.geom(g).name or g!r} can collide: its stand-in would change the"
                " physics"
            )
    if not any(int(t) == mesh for t in m.geom_type):
        return
    with _menagerie_at(standin_menagerie()):
        assets = _base_module(env).get_assets()
    big = {
        k: placeholder_mesh(k, 20.0) if k.lower().endswith((".stl", ".obj")) else v
        for k, v in assets.items()
    }
    ref = mujoco.MjModel.from_xml_string(Path(env.xml_path).read_text(), assets=big)
    for field in ("body_mass", "body_inertia", "body_ipos"):
        a, b = getattr(m, field), getattr(ref, field)
        if a.shape != b.shape or not np.allclose(a, b, rtol=1e-6, atol=1e-9):
            raise ValueError(
                f"{field} depends on the mesh files (a body without an explicit <inertial>):"
                " this env needs Menagerie's real meshes"
            )


def check_name(name: str) -> None:
    """Raises ValueError unless ``name`` is in :data:`ENV_NAMES` (the message lists the
    valid names and the closest); cheap, no model is built."""
    if name not in locomotion.ALL_ENVS:
        close = difflib.get_close_matches(str(name), ENV_NAMES, n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(map(repr, close))}?" if close else ";"
        raise ValueError(
            f"unknown env {name!r}{hint} valid names (Playground's locomotion envs):"
            f" {', '.join(ENV_NAMES)}"
            " (offline_names() lists those that load offline)"
        )


def load(name: str, config_overrides: dict | None = None, *, check: bool = True):
    """Builds a Playground locomotion env offline (module docstring for the route).

    Args:
      name: a registry name of ``mujoco_playground.locomotion`` (:data:`ENV_NAMES`).
      config_overrides: flattened config overrides, as Playground's ``registry.load``
        takes them; ``impl`` defaults to ``"jax"``.
      check: run :func:`check_visual_only` (one more C compile of the scene).

    Returns:
      The env, an instance of Playground's own env class.

    Raises:
      ValueError: an unknown name (the message lists the valid ones and the closest), an
        override that names no field of the env's config, an ``impl`` other than
        ``"jax"``, or an env that needs more of Menagerie than stand-in visual meshes (with
        the reason).
    """
    check_name(name)
    overrides = {"impl": "jax", **(config_overrides or {})}
    # A fresh default config: Playground's default argument is one shared, mutable object.
    config = locomotion.get_default_config(name)
    unknown = [k for k in (config_overrides or {}) if str(k).split(".")[0] not in config]
    if unknown:
        raise ValueError(
            f"config_overrides: {unknown} name no field of {name}'s config (its fields:"
            f" {sorted(config)})"
        )
    if overrides["impl"] != "jax":
        # Checked here: the constructor's ValueError read as a scene that needs Menagerie.
        raise ValueError(
            f"config_overrides['impl'] must be 'jax' (MJX's JAX implementation, the one the"
            f" estimator's adapter reads), got {overrides['impl']!r}"
        )
    with _menagerie_at(standin_menagerie()):
        try:
            # The folder exists, so the registry's ensure_menagerie_exists clones nothing.
            env = locomotion.load(name, config=config, config_overrides=overrides)
        except ValueError as e:  # mujoco's compile error: a file Menagerie would supply
            why = " ".join(str(e).split())
            if "mesh volume" in why or "inertia" in why:  # bodies massed by their meshes
                why = (
                    "bodies without an <inertial> take their mass from their meshes, which"
                    f" stand-ins cannot supply; mujoco: {why}"
                )
            raise ValueError(
                f"{name} cannot be built offline: its scene needs more of Menagerie than"
                f" visual meshes ({why})"
            ) from e
    if check:
        check_visual_only(env)
    return env


@functools.cache
def offline_names() -> tuple[str, ...]:
    """Registry names :func:`load` builds (cheap: C compiles, no JAX tracing)."""
    ok = []
    for name in ENV_NAMES:
        try:
            load(name)
        except ValueError:
            continue
        ok.append(name)
    return tuple(ok)


__all__ = ["ENV_NAMES", "check_visual_only", "load", "offline_names", "standin_menagerie"]
