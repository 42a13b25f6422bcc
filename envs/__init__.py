"""Simulated worlds for jax_contact: robots, gaits, terrain, sensor noise, wrappers."""

from jax_contact.envs.robots import (
    MENAGERIE_NAMES,
    ROBOT_NAMES,
    HeightField,
    Robot,
    RobotUnavailableError,
    load_robot,
    with_terrain,
)

__all__ = [
    "MENAGERIE_NAMES",
    "ROBOT_NAMES",
    "HeightField",
    "Robot",
    "RobotUnavailableError",
    "load_robot",
    "with_terrain",
]
