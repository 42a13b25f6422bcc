"""Which estimator runs on a log or recording: the robot's defaults or a parameter file,
and the terrain model.

``jax-contact evaluate``, ``estimate``, ``export`` and ``deploy-check`` build their
estimator here, so that one robot, one period and one ``--params`` give the same parameters
in every command (the one source of parameters: :func:`jax_contact.params_for`).
"""

from __future__ import annotations

from typing import NamedTuple

# The named terrain models (``--terrain-model``, a parameter file's provenance) live with the
# terrains; imported here, where the log commands read them.
from jax_contact.terrain import (  # noqa: F401  (TERRAIN_MODELS, FOOTHOLD_MEMORY: re-exported)
    FOOTHOLD_MEMORY,
    TERRAIN_MODELS,
    check_terrain_model,
    terrain_for,
    terrain_model_of,
)


def default_estimator(
    desc, dt: float, terrain_model: str = "flat", *, mj_model=None, noise: str = "anymal_like"
):
    """(EstimatorParams, terrain) that ``evaluate``, ``estimate``, ``export`` and ``tune``
    use for a robot: the planar leg's Section III estimator for one 2-joint leg on a 1-dof
    rail, else Table III's (the one source: :func:`jax_contact.params_for` with the sensor
    preset ``noise``, ``anymal_like`` unless a simulated log names its own,
    ``jax_contact.train.reproduce``). With ``mj_model`` the legs resist the force axes
    their Jacobians span, as in the wrapper
    (:func:`jax_contact.envs.contact_params.choose_force_rows`: all three for a spatial
    leg, x and z for a planar one such as Brax's walker2d); legs of fewer than three joints
    (a biped's, Brax's ant's) need it. With ``mj_model`` the sign test runs only where the
    legs' torques can read a foot's load
    (:func:`jax_contact.envs.contact_params.choose_unilateral`), as in the wrapper.
    ``terrain_model`` (:data:`TERRAIN_MODELS`): ``"flat"`` the plane of the reproduction,
    ``"memory"`` a :func:`jax_contact.foothold_memory` over it with :data:`FOOTHOLD_MEMORY`,
    for base positions that drift.

    Raises:
      ValueError: an unknown terrain model, or legs of fewer than three joints (not the
        planar leg's) without ``mj_model``.
    """
    import jax_contact as jc
    from jax_contact.train.reproduce import (
        TERRAIN_SIGMA,
        planar_estimator_params,
        quadruped_estimator_params,
    )

    check_terrain_model(terrain_model)
    if is_planar_leg(desc):
        params, plane = planar_estimator_params(desc.nv, dt, noise=noise), jc.flat(0.0, 0.2)
    else:
        if desc.n_leg_dofs < 3 and mj_model is None:
            raise ValueError(
                f"legs of {desc.n_leg_dofs} joints: their force axes are chosen from the"
                " robot's model (pass mj_model)"
            )
        rows = (0, 1, 2)  # a spatial leg's; without the model, legs of 3+ joints get them
        if mj_model is not None:  # the wrapper's rule: the axes the legs' Jacobians span
            from jax_contact.envs.contact_params import choose_force_rows

            rows = choose_force_rows(mj_model, desc)
        params = quadruped_estimator_params(desc, dt, force_rows=rows, noise=noise)
        plane = jc.flat(0.0, TERRAIN_SIGMA)
    if mj_model is not None:
        from jax_contact.envs.contact_params import choose_unilateral

        params = params.replace(unilateral=choose_unilateral(mj_model, desc, params))
    return params, terrain_for(plane, terrain_model)


def is_planar_leg(desc) -> bool:
    """Whether ``desc`` is Section III's planar leg (one 2-joint leg on a 1-dof rail), which
    gets that section's estimator rather than Table III's."""
    return desc.n_leg_dofs == 2 and desc.n_legs == 1 and len(desc.base_dofs) == 1 and desc.nv == 3


def file_terrain_model(path) -> str | None:
    """The terrain model a parameter file (or preset name) was tuned with
    (``provenance["terrain_model"]`` of ``jax-contact tune``), or None when it does not say
    (files written before the option: tuned on the plane)."""
    from jax_contact.params_file import load_params

    _, prov = load_params(path, with_provenance=True)
    return terrain_model_of(prov, path)


def resolve_terrain_model(
    terrain_model: str | None, params_path, provenance: dict | None = None
) -> str:
    """``--terrain-model`` as given, else the parameter file's own
    (:func:`file_terrain_model`), else ``"flat"``: parameters tuned with a foothold memory
    are run with it unless the user says otherwise. ``provenance``: the file's, when the
    caller has read it already (the file is then not read again)."""
    if terrain_model is not None:
        check_terrain_model(terrain_model)
        return terrain_model
    if params_path is not None:
        if provenance is not None:
            return terrain_model_of(provenance, params_path) or "flat"
        return file_terrain_model(params_path) or "flat"
    return "flat"


def params_record(read) -> dict:
    """What ``evaluate --json`` and ``export`` record of the ``--params`` they ran: where
    the parameter file or shipped preset came from (its resolved path, or the preset's
    name), the SHA-256 of the bytes that were parsed, and the file's own ``provenance``
    (``read``: :func:`jax_contact.params_file.read_params`)."""
    return {**read.record, "file_provenance": read.payload.get("provenance", {})}


class EstimatorSetup(NamedTuple):
    """What :func:`estimator_for` gives: ``params``, the ``terrain_model`` name and its
    ``terrain``, the file's ``calibration`` map (None without one) and ``params_record``
    (:func:`params_record` of the file read, None for the defaults)."""

    params: object
    terrain_model: str
    terrain: object
    calibration: object
    params_record: dict | None


def estimator_for(
    desc,
    dt: float,
    params_path,
    terrain_model: str | None,
    mass_kg=None,
    *,
    mj_model=None,
    period: str = "the log's",
    robot: str | None = None,
    noise: str | None = None,
):
    """The :class:`EstimatorSetup` of ``evaluate``, ``estimate`` and ``export``: the
    defaults (:func:`default_estimator`) or ``params_path`` checked against the robot
    (``robot``: the name it was loaded by) and period, with the file's calibration map, on
    the terrain model given, else the file's own (:func:`resolve_terrain_model`), which
    is then printed. The file is read once: its parameters, map and recorded hash come
    from the same bytes. ``period`` names ``dt`` in the warning of a file of another
    period (e.g. ``"the export's"``). ``noise``: the readings' sensor preset where known
    (a simulated log's, :func:`jax_contact.train.logs.log_noise`): the defaults are
    derived with it, and a file tuned on logs of other sensors is warned of; None (a
    recording's, unknown): the defaults' ``anymal_like``, no warning."""
    from jax_contact.calibration import file_calibration
    from jax_contact.params_file import read_params
    from jax_contact.train.logs import DEFAULT_LOG_NOISE

    provenance, calibration, record = None, None, None
    if params_path is not None:
        try:
            read = read_params(params_path)
            file_params, provenance = load_params_for(
                params_path, desc, dt, mass_kg, with_provenance=True, mj_model=mj_model,
                period=period, robot=robot, read=read,
            )  # fmt: skip
            calibration = file_calibration(provenance, params_path)
        except ValueError as err:  # the commands' option (evaluate said "preset 'barkour'
            # is for nv = 18; the robot has nv = 3" without it, a helper's trial)
            if str(err).startswith("argument "):
                raise
            raise ValueError(f"argument --params: {err}") from None
        record = params_record(read)
        warn_other_sensors(provenance, noise, params_path)
    model = resolve_terrain_model(terrain_model, params_path, provenance)
    if terrain_model is None and model != "flat":
        print(f"terrain model {model!r}: the one {str(params_path)!r} was tuned with")
    params, terrain = default_estimator(
        desc, dt, model, mj_model=mj_model, noise=noise or DEFAULT_LOG_NOISE
    )
    if params_path is not None:
        params = file_params
    return EstimatorSetup(params, model, terrain, calibration, record)


def warn_other_sensors(provenance: dict, noise: str | None, source) -> None:
    """A ``UserWarning`` when a parameter file was tuned on logs of sensor presets (its
    provenance's ``logs[*].noise``) that do not include ``noise``, the readings' own (None:
    unknown, no warning): its noise values are another sensor model's."""
    import warnings

    logs = provenance.get("logs")
    tuned = sorted(
        {str(e["noise"]) for e in logs if isinstance(e, dict) and "noise" in e}
        if isinstance(logs, list)
        else set()
    )
    if noise is None or not tuned or noise in tuned:
        return
    warnings.warn(
        f"{str(source)!r} was tuned on readings of sensors {', '.join(map(repr, tuned))};"
        f" these are {noise!r}: its noise values are another sensor model's (tune on logs"
        " with these sensors: jax-contact tune)",
        stacklevel=2,
    )


def load_params_for(
    path,
    desc,
    dt,
    mass_kg=None,
    *,
    with_provenance=False,
    mj_model=None,
    period="the log's",
    robot=None,
    read=None,
):
    """A params file, checked against the robot (its ``nv`` and, given, its mass and the
    name it was loaded by, ``robot``) and the log's period
    (:func:`jax_contact.params_file.load_params_for`; ``with_provenance`` and ``read`` as
    there; ``mj_model`` as :func:`default_estimator`'s, whose values move the file's
    period)."""
    from jax_contact.params_file import load_params_for as load
    from jax_contact.tune.space import robot_space

    derive = lambda d: default_estimator(desc, d, mj_model=mj_model)[0]  # noqa: E731
    return load(
        path,
        nv=desc.nv,
        dt=dt,
        derive=derive,
        mass_kg=mass_kg,
        with_provenance=with_provenance,
        period=period,
        robot=robot,
        groups=robot_space(desc).named_groups(),
        read=read,
    )
