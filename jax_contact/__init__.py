"""jax-contact: probabilistic foot contact estimation (Hwangbo et al., IROS 2016) in pure JAX.

The public API is listed in ``__all__``; everything else is private. Names load on first use
(PEP 562 ``__getattr__``): ``import jax_contact`` itself imports neither JAX nor NumPy, so the
command line (``jax_contact.train.cli``) checks its arguments before the seconds that JAX takes
to import, and ``jax_contact.deploy`` loads only what it uses.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING

# public name -> the submodule that defines it (None: the name is a submodule)
_LAZY = {
    "deploy": None,
    "export": None,
    "Calibration": "calibration",
    "load_calibration": "calibration",
    "GaitPrior": "defaults",
    "params_for": "defaults",
    "init_belief": "filter",
    "init_belief_batch": "filter",
    "run": "filter",
    "sequence_bce": "filter",
    "step": "filter",
    "step_batch": "filter",
    "step_robot": "filter",
    "load_params": "params_file",
    "preset_names": "params_file",
    "save_params": "params_file",
    "MeasurementTerms": "measurement",
    "diff_kinematics_llr": "measurement",
    "dynamics_llr": "measurement",
    "kinematics_llr": "measurement",
    "leg_blocks": "measurement",
    "measurement_terms": "measurement",
    "robot_leg_blocks": "measurement",
    "EstimatorParams": "params",
    "NoiseParams": "params",
    "make_noise": "params",
    "make_params": "params",
    "validate_params": "params",
    "FlatTerrain": "terrain",
    "FootholdMemory": "terrain",
    "HeightFieldTerrain": "terrain",
    "flat": "terrain",
    "foothold_memory": "terrain",
    "height_field": "terrain",
    "log_takeoff": "transition",
    "log_touchdown": "transition",
    "log_touchdown_monte_carlo": "transition",
    "log_touchdown_quadrature": "transition",
    "log_transition_matrix": "transition",
    "Diagnostics": "types",
    "LegBelief": "types",
    "LegBlocks": "types",
    "LegMeasurement": "types",
    "RobotMeasurement": "types",
    "TerrainQuery": "types",
    "validate_measurement": "types",
    "validate_robot_measurement": "types",
}

if TYPE_CHECKING:  # the same names, eagerly, for type checkers and IDEs
    from jax_contact import deploy, export
    from jax_contact.calibration import Calibration, load_calibration
    from jax_contact.defaults import GaitPrior, params_for
    from jax_contact.filter import (
        init_belief,
        init_belief_batch,
        run,
        sequence_bce,
        step,
        step_batch,
        step_robot,
    )
    from jax_contact.measurement import (
        MeasurementTerms,
        diff_kinematics_llr,
        dynamics_llr,
        kinematics_llr,
        leg_blocks,
        measurement_terms,
        robot_leg_blocks,
    )
    from jax_contact.params import (
        EstimatorParams,
        NoiseParams,
        make_noise,
        make_params,
        validate_params,
    )
    from jax_contact.params_file import load_params, preset_names, save_params
    from jax_contact.terrain import (
        FlatTerrain,
        FootholdMemory,
        HeightFieldTerrain,
        flat,
        foothold_memory,
        height_field,
    )
    from jax_contact.transition import (
        log_takeoff,
        log_touchdown,
        log_touchdown_monte_carlo,
        log_touchdown_quadrature,
        log_transition_matrix,
    )
    from jax_contact.types import (
        Diagnostics,
        LegBelief,
        LegBlocks,
        LegMeasurement,
        RobotMeasurement,
        TerrainQuery,
        validate_measurement,
        validate_robot_measurement,
    )


def _installed_version() -> str:
    """The installed distribution's version; ``"unknown"`` for a source tree never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("jax-contact")
    except PackageNotFoundError:
        return "unknown"


def __getattr__(name: str):
    if name == "__version__":  # read once, from the installed package's metadata
        globals()[name] = _installed_version()
        return globals()[name]
    if name not in _LAZY:
        # Any submodule, as an eager package would have after importing it (``jc.io``,
        # ``jc.baselines``, ``jc.envs``).
        if name.startswith("__") or importlib.util.find_spec(f"jax_contact.{name}") is None:
            raise AttributeError(f"module 'jax_contact' has no attribute {name!r}")
        module = importlib.import_module(f"jax_contact.{name}")
        globals()[name] = module
        return module
    module = importlib.import_module(f"jax_contact.{_LAZY[name] or name}")
    value = module if _LAZY[name] is None else getattr(module, name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | {"__version__"})


__all__ = [
    "Calibration",
    "Diagnostics",
    "EstimatorParams",
    "FlatTerrain",
    "FootholdMemory",
    "GaitPrior",
    "HeightFieldTerrain",
    "LegBelief",
    "LegBlocks",
    "LegMeasurement",
    "MeasurementTerms",
    "NoiseParams",
    "RobotMeasurement",
    "TerrainQuery",
    "deploy",
    "diff_kinematics_llr",
    "dynamics_llr",
    "export",
    "flat",
    "foothold_memory",
    "height_field",
    "init_belief",
    "init_belief_batch",
    "kinematics_llr",
    "leg_blocks",
    "load_calibration",
    "load_params",
    "log_takeoff",
    "log_touchdown",
    "log_touchdown_monte_carlo",
    "log_touchdown_quadrature",
    "log_transition_matrix",
    "make_noise",
    "make_params",
    "measurement_terms",
    "params_for",
    "preset_names",
    "robot_leg_blocks",
    "run",
    "save_params",
    "sequence_bce",
    "step",
    "step_batch",
    "step_robot",
    "validate_measurement",
    "validate_params",
    "validate_robot_measurement",
]
