"""Parameter files: the versioned JSON of :class:`~jax_contact.EstimatorParams`.

:func:`save_params` writes one (atomically, :func:`jax_contact.io.write_text_atomic`),
:func:`load_params` reads one or a shipped preset by name (:func:`preset_names`), and
:func:`load_params_for` reads one for a given robot and period, warning where the file is
another robot's or another rate's. Layout (:func:`params_to_dict`): ``format``,
``version``, ``library_version``, ``nv``, ``noise``, ``values``, ``options``,
``provenance``; a bad file is refused with a ValueError naming the file and the field.
Reading a header needs no JAX (:func:`read_params_file`: the command line checks
``--params`` before JAX loads).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from jax_contact._presets import preset_file, preset_names

PARAMS_FORMAT = "jax-contact-params"
PARAMS_VERSION = 1
# Fields added to a section after files of this version were first written, with the value
# that reproduces the model those files were written with: a file without one loads with
# it (a missing field of any other name is an error).
LATER_FIELDS = {
    "values": {
        "contact_damping": 0.0,
        "kinematics_lead": 0.0,
        "min_push": 0.0,
        "slip_prob": 0.0,
        "slip_speed": 0.5,
    }
}


def _param_sections() -> dict[str, tuple[str, ...]]:
    """The field names of each section of a params file: ``noise`` (the NoiseParams),
    ``values`` (EstimatorParams' array leaves) and ``options`` (its static fields)."""
    import dataclasses

    from jax_contact.params import EstimatorParams, NoiseParams

    fields = [f for f in dataclasses.fields(EstimatorParams) if f.name != "noise"]
    return {
        "noise": tuple(NoiseParams.__dataclass_fields__),
        "values": tuple(f.name for f in fields if f.metadata.get("pytree_node", True)),
        "options": tuple(f.name for f in fields if not f.metadata.get("pytree_node", True)),
    }


# The top-level keys of a parameter file (params_to_dict); any other is refused on reading.
PARAMS_KEYS = (
    "format", "version", "library_version", "nv", "noise", "values", "options", "provenance"
)  # fmt: skip


def params_to_dict(params, provenance: Mapping | None = None) -> dict:
    """:class:`~jax_contact.EstimatorParams` as the versioned JSON payload of a params file.

    Layout: ``format``, ``version``, ``library_version``, ``nv``, ``noise`` (field -> list
    of floats), ``values`` (scalar field -> float), ``options`` (the static fields) and
    ``provenance`` (free-form: how the values were obtained).
    """
    import jax_contact

    lib = jax_contact.__version__
    names = _param_sections()
    noise = {f: np.asarray(getattr(params.noise, f)).tolist() for f in names["noise"]}
    values = {f: float(np.asarray(getattr(params, f))) for f in names["values"]}
    options = {
        f: list(v) if isinstance(v := getattr(params, f), tuple) else v for f in names["options"]
    }
    return {
        "format": PARAMS_FORMAT,
        "version": PARAMS_VERSION,
        "library_version": lib,
        "nv": params.nv,
        "noise": noise,
        "values": values,
        "options": options,
        "provenance": dict(provenance or {}),
    }


def _is_number(x) -> bool:
    """An int or float of JSON (not a bool, a string or null)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def check_params_header(payload, source: str) -> None:
    """The checks of :func:`params_from_dict` that need no JAX: the format, version,
    top-level keys, sections, the numeric fields' types, the provenance's type, its robot
    mass and its calibration map (the command line runs them before JAX loads). Raises
    ValueError naming ``source`` and the field."""
    if not isinstance(payload, Mapping) or payload.get("format") != PARAMS_FORMAT:
        raise ValueError(
            f"{source}: not a jax-contact parameter file (no format {PARAMS_FORMAT!r})"
        )
    if payload.get("version") != PARAMS_VERSION:
        raise ValueError(
            f"{source}: version {payload.get('version')!r} is not supported (this library reads"
            f" version {PARAMS_VERSION})"
        )
    extra = set(payload) - set(PARAMS_KEYS)
    if extra:
        raise ValueError(
            f"{source}: unknown top-level key(s) {sorted(extra)} (a parameter file has"
            f" {list(PARAMS_KEYS)}; free-form notes go into 'provenance')"
        )
    for section in ("noise", "values", "options"):
        value = payload.get(section)
        if value is None:
            raise ValueError(f"{source}: missing section {section!r}")
        if not isinstance(value, Mapping):
            raise ValueError(
                f"{source}: section {section!r} must be a JSON object of fields, got"
                f" {type(value).__name__}"
            )
    for section in ("noise", "values"):  # numbers (noise: or lists of numbers) only
        for name, value in payload[section].items():
            numbers = value if section == "noise" and isinstance(value, list) else [value]
            if not numbers or not all(_is_number(x) for x in numbers):
                kind = "a number or a list of numbers" if section == "noise" else "a number"
                raise ValueError(f"{source}: {section}.{name} must be {kind}, got {value!r}")
    provenance = payload.get("provenance")
    if provenance is not None and not isinstance(provenance, Mapping):
        raise ValueError(
            f"{source}: 'provenance' must be a mapping (JSON object), got"
            f" {type(provenance).__name__}"
        )
    mass = (provenance or {}).get("robot_mass_kg")
    if mass is not None and not (
        isinstance(mass, int | float)
        and not isinstance(mass, bool)
        and np.isfinite(mass)
        and mass > 0
    ):
        raise ValueError(
            f"{source}: provenance field 'robot_mass_kg' must be a positive number of kg"
            f" (or absent), got {mass!r}"
        )
    # A malformed calibration map is refused on reading, as save_params refuses to write
    # one: the wrapper warned of the file's dt first and only then refused its map.
    from jax_contact.calibration import checked_calibration

    checked_calibration(provenance, source)


@dataclasses.dataclass(frozen=True)
class ParamsRead:
    """A parameter file or preset as read, once.

    Attributes:
      payload: the JSON payload, its header checked (:func:`check_params_header`).
      source: how errors and warnings name it (``"preset 'go1'"``, ``"parameter file
        '...'"``).
      record: what a run records of it: ``source`` (``"preset"`` with its ``name``, or
        ``"file"`` with its resolved ``path``) and the ``sha256`` of the bytes read.
    """

    payload: dict
    source: str
    record: dict


def read_params(path) -> ParamsRead:
    """A parameter file or preset name, read once (:class:`ParamsRead`); no JAX is
    imported. A run that records which file it ran hashes the bytes it parsed, not a later
    read of a file that may have been replaced since.

    Raises:
      ValueError: the file is missing (or the name is no preset), not JSON, or its header
        is wrong (named).
    """
    raw, source, where = _params_bytes(path)
    try:
        payload = json.loads(raw.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{source} is not JSON: {err}") from None
    check_params_header(payload, source)
    return ParamsRead(payload, source, {**where, "sha256": hashlib.sha256(raw).hexdigest()})


def read_params_file(path) -> tuple[dict, str]:
    """``(payload, description for errors)`` of :func:`read_params`."""
    read = read_params(path)
    return read.payload, read.source


def params_from_dict(payload: Mapping, *, source: str = "params"):
    """The inverse of :func:`params_to_dict`, validated; errors name ``source`` and the field.

    Raises:
      ValueError: not a params payload, an unknown version, a missing or extra field, or
        a value that :func:`jax_contact.make_params` / ``make_noise`` rejects.
    """
    from jax_contact.params import make_noise, make_params
    from jax_contact.terrain import checked_terrain_model

    check_params_header(payload, source)
    checked_terrain_model(payload.get("provenance"), source)
    want = {section: set(names) for section, names in _param_sections().items()}
    payload = dict(payload)
    for section, added in LATER_FIELDS.items():
        payload[section] = {**added, **payload[section]}
    for section, names in want.items():
        have = set(payload[section])
        if have - names:
            raise ValueError(f"{source}: unknown field(s) {sorted(have - names)} in {section!r}")
        if names - have:
            raise ValueError(f"{source}: missing field(s) {sorted(names - have)} in {section!r}")
    nv = payload.get("nv")
    if not isinstance(nv, int) or nv < 1:
        raise ValueError(f"{source}: nv must be a positive int, got {nv!r}")
    lengths = {
        len(v)
        for k, v in payload["noise"].items()
        if k not in ("sigma_f", "sigma_J") and isinstance(v, list)
    }
    if len(lengths) == 1 and nv not in lengths:  # the header, not one vector, disagrees
        raise ValueError(
            f"{source}: nv is {nv} but every per-dof noise vector has {lengths.pop()} entries"
        )
    try:
        noise = make_noise(nv, **payload["noise"])
        params = make_params(noise, **payload["values"], **payload["options"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"{source}: {err}") from None
    return params


def robot_provenance(mj_model, desc, name: str | None = None) -> dict:
    """What a parameter file records of the robot it was made for, as ``jax-contact tune``
    writes it: ``{"robot_mass_kg", "groups"}`` and ``"robot"`` if ``name`` is given.

    Pass it to :func:`save_params` (``provenance=robot_provenance(...) | {...}``): the
    wrapper, the CLI and :func:`load_params_for` then warn when the file is loaded for a
    robot 1.5x heavier or lighter, of another name, or whose joints group otherwise. A
    file saved without it loads on any robot of the same ``nv`` without a word (Go1's
    parameters on Berkeley Humanoid, both ``nv`` 18: 4 legs of 3 joints against 2 of 6).

    Args:
      mj_model: the robot's ``mujoco.MjModel`` (its mass,
        :func:`jax_contact.robot.model_mass`).
      desc: its :class:`jax_contact.robot.RobotDescription`.
      name: the name it is loaded by (e.g. ``"go1"``), or None.
    """
    from jax_contact.robot import model_mass
    from jax_contact.tune.space import robot_space

    out = {"robot_mass_kg": model_mass(mj_model), "groups": robot_space(desc).named_groups()}
    return out if name is None else {"robot": str(name), **out}


def save_params(path: str | os.PathLike, params, provenance: Mapping | None = None) -> Path:
    """Writes ``params`` as a versioned JSON file (atomically, its folder created if it does
    not exist); returns the path.

    Raises:
      ValueError: ``params`` fails :func:`jax_contact.validate_params` (the field named;
        nothing is written: a NaN would be written as ``null`` and the file not load), or
        ``provenance`` is not a mapping of JSON values (the key named), or holds what the
        file's readers refuse (``robot_mass_kg``, as :func:`load_params`; a NaN mass is
        refused, not written as null; ``calibration`` and ``terrain_model``, as the
        commands and the wrapper): a file that could not be read back is not written.
      OSError: the file cannot be created (its path named).
    """
    import json

    from jax_contact.calibration import file_calibration
    from jax_contact.io import json_safe, write_text_atomic
    from jax_contact.params import validate_params
    from jax_contact.terrain import terrain_model_of

    validate_params(params)
    if provenance is not None and not isinstance(provenance, Mapping):
        raise ValueError(
            f"provenance must be a mapping of JSON values (e.g. {{'note': ...}}), got"
            f" {type(provenance).__name__}"
        )
    mass = (provenance or {}).get("robot_mass_kg")
    if isinstance(mass, float | np.floating) and not np.isfinite(mass):
        # Refused here: JSON would turn it into null, which reads back as "no mass".
        raise ValueError(
            f"provenance['robot_mass_kg'] must be a positive number of kg (or absent), got {mass!r}"
        )
    try:
        text = json.dumps(json_safe(params_to_dict(params, provenance)), indent=2)
    except (TypeError, ValueError):  # params_to_dict's own values are numbers: a provenance key
        for key, value in provenance.items():
            try:
                json.dumps(json_safe(value))
            except (TypeError, ValueError) as err:
                hint = " (a Calibration: pass cal.as_dict())" if hasattr(value, "as_dict") else ""
                raise ValueError(f"provenance[{key!r}] is not a JSON value{hint}: {err}") from None
        raise
    # The file as load_params will read it back, checked before it is written.
    payload = json.loads(text)
    source = str(path)
    file_calibration(payload["provenance"], source)
    terrain_model_of(payload["provenance"], source)
    check_params_header(payload, source)
    return write_text_atomic(path, text)


def load_params(path: str | os.PathLike, *, with_provenance: bool = False):
    """Reads a parameter file written by :func:`save_params`, or a shipped preset by name.

    Args:
      path: a ``.json`` file, or the name of a shipped preset (:func:`preset_names`:
        ``"go1"``, ``"spot"``, ``"barkour"``, tuned by ``jax-contact tune``; each file's
        provenance says how). A name that is also an existing file is read as the file.
      with_provenance: also return the file's ``provenance`` dict (where a calibration map
        fitted by ``jax-contact tune --calibrate`` is kept, ``provenance["calibration"]``,
        see :class:`jax_contact.tune.Calibration`).

    Returns:
      The validated :class:`~jax_contact.EstimatorParams`, or ``(params, provenance)``;
      every value float32, as :func:`jax_contact.make_params` makes them, whatever the
      precision the file was written at (a float64 value saved and read back is its
      float32 rounding).

    Raises:
      ValueError: the file is missing (or the name is no preset), is not JSON, or a field
        is wrong (named).
    """
    payload, source = read_params_file(path)
    params = params_from_dict(payload, source=source)
    if with_provenance:
        return params, dict(payload.get("provenance") or {})
    return params


# A file tuned on a robot heavier or lighter than this factor warns (load_params_for): a
# payload or another build of the same robot stays inside it (Go1 12.7 kg, Spot 50.3 kg).
MASS_RATIO_WARN = 1.5
# Periods closer than this fraction are one rate (load_params_for moves a file's values to
# the caller's dt without a warning): a recording's median step, from float32 or epoch
# timestamps, lies a few 1e-5 from its loop's nominal period (399.992 Hz for 400 Hz).
SAME_RATE = 1e-3


def load_params_for(
    path: str | os.PathLike,
    *,
    nv: int,
    dt: float,
    period: str = "the requested period",
    derive=None,
    mass_kg: float | None = None,
    with_provenance: bool = False,
    robot: str | None = None,
    groups: dict | None = None,
    read: ParamsRead | None = None,
):
    """:func:`load_params` of a file or preset, checked against the robot and the period
    it will run at.

    With ``robot`` (the name the caller's robot was loaded by), a file whose provenance
    names another robot (``provenance["robot"]``; both plain names, not paths) warns,
    whatever the masses. With ``groups`` (the caller's coordinate groups,
    ``jax_contact.tune.space.robot_space(desc).named_groups()``), a tuned file whose
    ``provenance["groups"]`` differ warns too: its per-joint noise would land on other
    joints (Go1's file on a biped of the same ``nv``).

    With ``mass_kg`` (the robot's total mass, :func:`jax_contact.robot.model_mass`), a file
    whose provenance records the mass of the robot it was tuned on
    (``provenance["robot_mass_kg"]``, written by ``jax-contact tune`` and ``tune-env``)
    warns when the two differ by more than a factor :data:`MASS_RATIO_WARN`: the file is
    likely another robot's (a file carries over to another robot only in part).

    A file made at another period runs at ``dt``, with a ``UserWarning`` when the two
    differ by more than :data:`SAME_RATE` (a clock's rounding is not another rate). With
    ``derive`` (``dt -> params_for(robot, sensors, dt)`` of the caller's robot and sensors)
    its values are moved to ``dt`` as the rules move their own
    (:func:`jax_contact.defaults.change_period`: what tuning changed is kept relative to
    the derived values, ``sigma_qdd`` scales as ``1 / dt``, the still-side cap's log-odds
    as ``dt``); without it only ``dt`` changes and the rest is the file's, so a file made
    at a higher rate believes the differenced acceleration noisier than it is.

    Args:
      path: a parameter file or preset name.
      nv: the robot's velocity dimension.
      dt: the estimator's period, s.
      period: what ``dt`` is, in the warning (e.g. ``"the env's"``; default ``"the requested
        period"``).
      derive: optional ``dt -> EstimatorParams``, the caller's derived parameters.
      mass_kg: optional, the robot's total mass, kg.
      with_provenance: also return the file's ``provenance`` dict (one read of the file).
      read: ``path`` as :func:`read_params` read it already (a caller that records the
        file's hash parses the same bytes); None reads it here.

    Returns:
      The parameters at ``dt``, or ``(params, provenance)``.

    Raises:
      ValueError: as :func:`load_params`, or the file is for another ``nv``.
    """
    import warnings

    import jax.numpy as jnp

    read = read or read_params(path)
    params = params_from_dict(read.payload, source=read.source)
    provenance = dict(read.payload.get("provenance") or {})
    what = read.source
    if params.nv != nv:
        raise ValueError(f"{what} is for nv = {params.nv}; the robot has nv = {nv}")
    file_mass, file_robot = provenance.get("robot_mass_kg"), provenance.get("robot")
    heavier = None
    if mass_kg is not None and isinstance(file_mass, int | float) and file_mass > 0:
        heavier = max(file_mass, mass_kg) / min(file_mass, mass_kg) > MASS_RATIO_WARN
    if heavier:
        warnings.warn(
            f"{what} was tuned on a robot of {file_mass:.3g} kg"
            f" ({provenance.get('robot', 'unnamed')!r}); this one weighs {mass_kg:.3g} kg:"
            " it is likely another robot's, whose noise, caps and gait constants carry"
            " over only in part (tune on this robot: jax-contact tune on its logs,"
            " jax-contact tune-env on a wrapped env)",
            stacklevel=2,
        )
    elif _robot_name(robot) and _robot_name(file_robot) and robot != file_robot:
        # Another robot of about the same mass (Go1's file on Barkour): named, not weighed.
        warnings.warn(
            f"{what} was tuned on robot {file_robot!r}; this one is"
            f" {robot!r}: its noise, caps and gait constants carry over only in part (a"
            f" preset of {robot!r} if one ships, else tune on this robot: jax-contact tune"
            " on its logs, jax-contact tune-env on a wrapped env)",
            stacklevel=2,
        )
    file_groups = provenance.get("groups")
    if groups is not None and isinstance(file_groups, dict):
        ours = {str(k): [int(i) for i in v] for k, v in groups.items()}
        theirs = {str(k): [int(i) for i in v] for k, v in file_groups.items()}
        if ours != theirs:
            warnings.warn(
                f"{what} was tuned on a robot whose coordinates group as {_groups_text(theirs)};"
                f" this one's are {_groups_text(ours)}: its per-joint noise values land on"
                " other joints (another robot's file; tune on this robot: jax-contact tune on"
                " its logs, jax-contact tune-env on a wrapped env)",
                stacklevel=2,
            )
    file_dt = float(params.dt)
    if abs(file_dt - dt) > 1e-6 * dt:  # moved silently within SAME_RATE, else with a warning
        if derive is None:
            how = "noise the file derived from its dt is kept"
            params = params.replace(dt=jnp.float32(dt))
        else:
            from jax_contact.defaults import change_period

            how = "its values moved as params_for moves them, jax_contact.defaults.change_period"
            params = change_period(params, derive(file_dt), derive(dt))
    if abs(file_dt - dt) > SAME_RATE * dt:
        warnings.warn(
            f"{what} has dt = {file_dt:.6g} s; {period} is {dt:.6g} s:"
            f" using {period} ({how}; a file tuned at one rate is best tuned again at another:"
            " jax-contact tune on logs, jax-contact tune-env on a wrapped env)",
            stacklevel=2,
        )
    return (params, provenance) if with_provenance else params


def _groups_text(groups: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in groups.items())


def _robot_name(x) -> bool:
    """Whether ``x`` names a robot (``"go1"``), not a path or a description: what two
    files or a file and a caller can be compared by."""
    return isinstance(x, str) and re.fullmatch(r"[A-Za-z0-9_\-]+", x) is not None


def _params_bytes(path) -> tuple[bytes, str, dict]:
    """(bytes, description for errors, where they came from) of a parameter file or a
    preset name: the one read of :func:`read_params`."""
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"a parameter file is a path or a preset name, got {type(path).__name__}")
    if str(path).strip() == "":
        raise ValueError("a parameter file is a path or a preset name, got an empty string")
    ref = preset_file(path)
    if ref is not None:
        return ref.read_bytes(), f"preset {path!r}", {"source": "preset", "name": str(path)}
    p = Path(path)
    if p.is_dir():  # before the preset-name case, which called a folder missing
        raise ValueError(f"parameter file {str(p)!r} is a folder")
    if isinstance(path, str) and p.suffix == "" and len(p.parts) == 1 and not p.is_file():
        raise ValueError(
            f"parameter file {path!r} does not exist and is no preset name (presets:"
            f" {', '.join(preset_names()) or 'none'})"
        )
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        # "go1.json" for the preset "go1": name the preset the stem is.
        hint = f" (the preset is named {p.stem!r})" if p.stem in preset_names() else ""
        raise ValueError(f"parameter file {str(p)!r} does not exist{hint}") from None
    except IsADirectoryError:
        raise ValueError(f"parameter file {str(p)!r} is a folder") from None
    return raw, f"parameter file {str(p)!r}", {"source": "file", "path": str(p.resolve())}
