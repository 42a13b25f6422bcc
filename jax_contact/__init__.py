"""jax-contact: probabilistic foot contact estimation (Hwangbo et al., IROS 2016) in pure JAX.

The public API is listed in ``__all__``; everything else is private.
"""

from jax_contact import deploy, export  # the exported estimator: export it, run it (no mujoco)
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
from jax_contact.io import load_params, preset_names, save_params
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

__all__ = [
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
