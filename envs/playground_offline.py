"""MuJoCo Playground locomotion envs built offline, from the mesh-stripped robot models.

The route. Playground's registry (``registry.load`` / ``locomotion.load``) calls
``mjx_env.ensure_menagerie_exists()``, which runs ``git clone`` of MuJoCo Menagerie when
``mjx_env.MENAGERIE_PATH`` does not exist: that fails without network. The env classes
themselves do not clone: ``Go1Env.__init__`` / ``SpotEnv.__init__`` read the scene file
named by ``xml_path`` and compile it with the assets found (the package's own XMLs, and
whatever of Menagerie is on disk). The scenes include Menagerie meshes, so compiling fails
when they are absent. Those meshes are visual only: every body has an explicit
``<inertial>`` and every mesh geom has ``contype = conaffinity = 0`` (checked by
:func:`envs.robots.load_robot`, which refuses otherwise).

So :func:`load` builds a subclass of the env class directly, bypassing the registry. Its
``__init__`` is the env's own with ``xml_path`` pointed at the scene that
:func:`envs.robots.load_robot` compiles (the same ``scene_mjx_feetonly_flat_terrain.xml``,
mesh geoms and mesh assets deleted, everything else as shipped), written out as one
flattened MJCF file (``MjSpec.to_xml``). The base class' ``__init__`` (``Go1Env`` /
``SpotEnv``) then runs unchanged: it sets the timestep, the PD gains, the solver options
and ``mjx.put_model`` exactly as it would online. Collision geometry, masses, inertias,
joints, actuators, sensors and keyframes are those of the shipped model; only the visual
meshes are missing (renders show the collision geoms only). Nothing in Playground is
patched and no module global is changed.

The flattened files are written once per process under the system's temporary directory
(``jax_contact_playground/<robot>-<hash>.xml``, the hash of the content, so concurrent
processes agree). ``impl`` defaults to ``"jax"`` here (Playground's default ``"warp"``
compiles for minutes on a CPU and the contact wrapper needs MJX's JAX implementation).
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from pathlib import Path

from mujoco_playground._src.locomotion.go1 import base as go1_base
from mujoco_playground._src.locomotion.go1 import joystick as go1_joystick
from mujoco_playground._src.locomotion.spot import base as spot_base
from mujoco_playground._src.locomotion.spot import joystick as spot_joystick

from envs.robots import load_robot


@functools.cache
def stripped_scene_xml(robot: str) -> Path:
    """Path of the flattened, mesh-stripped flat-terrain scene of ``robot`` (go1, spot)."""
    xml = load_robot(robot).spec.to_xml()
    digest = hashlib.sha256(xml.encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "jax_contact_playground"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{robot}-{digest}.xml"
    if not path.is_file():
        tmp = folder / f".{robot}-{digest}.{os.getpid()}.tmp"
        tmp.write_text(xml)
        os.replace(tmp, path)  # atomic: another process may write the same file
    return path


class OfflineGo1Joystick(go1_joystick.Joystick):
    """Playground's Go1 joystick env (flat terrain) built from the stripped scene."""

    def __init__(self, config, config_overrides=None):
        # Joystick.__init__ for task="flat_terrain", with our scene file as xml_path.
        go1_base.Go1Env.__init__(
            self,
            xml_path=stripped_scene_xml("go1").as_posix(),
            config=config,
            config_overrides=config_overrides,
        )
        self._post_init()


class OfflineSpotJoystick(spot_joystick.Joystick):
    """Playground's Spot joystick env (flat terrain) built from the stripped scene."""

    def __init__(self, config, config_overrides=None):
        # Joystick.__init__ for task="flat_terrain", with our scene file as xml_path.
        spot_base.SpotEnv.__init__(
            self,
            xml_path=stripped_scene_xml("spot").as_posix(),
            config=config,
            config_overrides=config_overrides,
        )
        self._post_init()
        self._pert_func = (
            self._maybe_apply_perturbation
            if self._config.pert_config.enable
            else lambda state, _: state
        )


# Playground registry name -> (offline class, default config factory)
_ENVS = {
    "Go1JoystickFlatTerrain": (OfflineGo1Joystick, go1_joystick.default_config),
    "SpotFlatTerrainJoystick": (OfflineSpotJoystick, spot_joystick.default_config),
}
ENV_NAMES = tuple(_ENVS)


def load(name: str, config_overrides: dict | None = None):
    """Builds a Playground locomotion env offline.

    Args:
      name: one of :data:`ENV_NAMES` (Playground's registry names).
      config_overrides: flattened config overrides, as Playground's ``registry.load``
        takes them; ``impl`` defaults to ``"jax"``.

    Returns:
      The env, an instance of a subclass of Playground's env class.

    Raises:
      ValueError: an unknown name (the message lists the valid ones).
    """
    if name not in _ENVS:
        raise ValueError(f"unknown env {name!r}; valid names: {', '.join(ENV_NAMES)}")
    cls, default_config = _ENVS[name]
    overrides = {"impl": "jax", **(config_overrides or {})}
    # A fresh default config: Playground's default argument is one shared, mutable object.
    return cls(default_config(), config_overrides=overrides)
