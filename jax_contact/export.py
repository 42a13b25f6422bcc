"""The estimator as a file a robot can run: ``jax.export`` serialisation plus a JSON header.

Two layers:

- :func:`export_flat` serialises any function of pytrees (a benchmark's step, the robot
  update below) as a ``jax.export.Exported`` of plain arrays: pytrees are flattened and a
  PRNG key travels as its raw ``uint32`` data, as a runtime without this library needs.
- :func:`export_robot` traces one robot's whole update, the MJX adapter included (the
  model's kinematics and dynamics become part of the program), so the runtime needs only
  ``jax``: :mod:`jax_contact.deploy` loads it without importing ``mujoco``. MuJoCo is
  imported inside :func:`export_robot` only; this module itself never imports it.

The exported update takes **one reading per call**, as a control loop has it, and keeps
what the pairing needs in its state. A reading ``k`` is what the sensors give after physics
step ``k``: the state at its end (``qpos``, ``qvel``), the acceleration over it (``qacc``)
and the torque applied during it (``tau``). The offline estimator
(``jax_contact.train.evaluate.replay``) pairs ``qacc`` and ``tau`` of reading ``k`` with the state
of reading ``k - 1``, the state the step started from (see its module docstring), so the state
carries the previous reading's ``qpos`` and ``qvel``. The first call has no previous reading and
uses its own state, as replay's :func:`~jax_contact.train.evaluate.delay_one_step` repeats the
first reading.

File layout (``.contact``)::

    MAGIC (16 bytes) | header length n (8 bytes, little-endian) | header (n bytes JSON, UTF-8)
    | payload (jax.export serialisation; its SHA-256 is in the header)

The exported function is ``update(state, key, *readings) -> (state, key, out)``: ``state``
a float32 vector and ``key`` the raw PRNG key (both opaque to the caller; their layouts are
in the header), ``readings`` in header order, ``out`` a float32 vector holding P(contact)
and the diagnostics (layout in the header); P is read through the calibration map the
header's ``calibration`` holds, if any (the parameter file's, :mod:`jax_contact.calibration`),
the diagnostics are the raw terms. Packing into a few vectors keeps the per-call
overhead of the Python runtime small (every argument and result is one buffer to move).
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import os
import platform
import struct
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jax_contact
from jax_contact.calibration import probability

MAGIC = b"JAX-CONTACT-EXP\n"  # 16 bytes
# A joint quaternion (the base's free joint, a ball joint) shorter than this is no
# orientation (a driver's zero fill): the exported update and the offline replay
# (jax_contact.train.recording_checks.degenerate_quaternion) read it as a lost reading, NaN.
MIN_QUATERNION_NORM = 0.1
FORMAT = "jax-contact-deploy"
FORMAT_VERSION = 1
# What the state carries from one reading to the next, and which reading fields are paired
# with it (module docstring): the acceleration and torque of reading k are paired with
# the state of reading k - 1.
PAIRING = {
    "delayed": ("qpos", "qvel"),
    "current": ("qacc", "tau"),
    "first_call": "the first reading is paired with its own state",
}
DIAGNOSTIC_FIELDS = (
    ("p_dynamics", ()),
    ("p_diff_kinematics", ()),
    ("p_kinematics", ()),
    ("p_takeoff", ()),
    ("p_touchdown", ()),
    ("force", (3,)),
    ("valid", ()),
)


# ------------------------------------------------------------------------ generic export


def export_flat(fn: Callable, *args, platforms: Sequence[str] | None = None):
    """``jax.export`` of ``fn(*args)`` with every pytree flattened and keys as raw data.

    Args:
      fn: a function of pytrees of arrays (typed PRNG keys allowed anywhere), returning a
        pytree of arrays.
      *args: example arguments (their shapes and dtypes are what the export accepts).
      platforms: passed to ``jax.export.export`` (default: the current backend).

    Returns:
      ``(exported, flat_args)``: the ``jax.export.Exported`` of a function of the flat
      leaves (keys as ``uint32`` key data) returning the flat output leaves, and the
      example arguments in that flat form.
    """
    leaves, treedef = jax.tree.flatten(args)
    is_key = [_is_key(x) for x in leaves]
    impls = [jax.random.key_impl(x) if k else None for x, k in zip(leaves, is_key, strict=True)]
    flat = [jax.random.key_data(x) if k else x for x, k in zip(leaves, is_key, strict=True)]

    def flat_fn(*raw):
        typed = [
            jax.random.wrap_key_data(x, impl=impl) if k else x
            for x, k, impl in zip(raw, is_key, impls, strict=True)
        ]
        out = fn(*jax.tree.unflatten(treedef, typed))
        return [jax.random.key_data(x) if _is_key(x) else x for x in jax.tree.leaves(out)]

    kw = {} if platforms is None else {"platforms": tuple(platforms)}
    exported = jax.export.export(jax.jit(flat_fn), **kw)(*flat)
    return exported, flat


def _is_key(x) -> bool:
    return isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jax.dtypes.prng_key)


def load_exported(payload: bytes | bytearray):
    """The ``jax.export.Exported`` of a serialised payload."""
    return jax.export.deserialize(bytearray(payload))


# ------------------------------------------------------------------------------ the file


def write_artefact(path: str | os.PathLike, header: Mapping, payload: bytes) -> Path:
    """Writes header and payload as one ``.contact`` file (atomically); returns the path.

    The header gets ``payload_sha256`` and ``payload_bytes`` added.
    """
    from jax_contact.io import write_atomic  # the library's one module that writes files

    header = dict(header)
    header["payload_sha256"] = hashlib.sha256(payload).hexdigest()
    header["payload_bytes"] = len(payload)
    header["header_sha256"] = _header_digest(header)
    head = json.dumps(header, indent=1).encode()

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(MAGIC + struct.pack("<Q", len(head)) + head + bytes(payload))

    return write_atomic(path, write)


def _header_digest(header: Mapping) -> str:
    """SHA-256 of a header's canonical JSON, its own ``header_sha256`` left out: an edited
    rate, noise value or layout (the program does not read them back) is caught."""
    rest = {k: v for k, v in header.items() if k != "header_sha256"}
    return hashlib.sha256(json.dumps(rest, sort_keys=True).encode()).hexdigest()


def read_artefact(path: str | os.PathLike) -> tuple[dict, bytes]:
    """``(header, payload)`` of a ``.contact`` file.

    Raises:
      FileNotFoundError: no such file.
      ValueError: naming the file: not an exported estimator, a newer format, truncated,
        a header or payload whose checksum differs from the one written with it (files
        written before the header had one are read without that check).
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"exported estimator {str(path)!r} is a folder; expected a .contact file")
    if not path.is_file():
        raise FileNotFoundError(f"exported estimator {str(path)!r} does not exist")
    data = path.read_bytes()
    name = f"exported estimator {str(path)!r}"
    if not data.startswith(MAGIC) or len(data) < len(MAGIC) + 8:
        raise ValueError(f"{name} is not a jax-contact export (written by `jax-contact export`)")
    (n,) = struct.unpack("<Q", data[len(MAGIC) : len(MAGIC) + 8])
    start = len(MAGIC) + 8
    if n > len(data) - start:
        raise ValueError(
            f"{name}: its header length ({n} bytes) exceeds the file ({len(data)} bytes): the"
            " file is truncated or corrupt"
        )
    try:
        header = json.loads(data[start : start + n].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{name}: the header is not JSON ({err}); the file is corrupt") from None
    if not isinstance(header, dict):
        raise ValueError(f"{name}: the header is not a JSON object; the file is corrupt")
    if header.get("format") != FORMAT:
        raise ValueError(f"{name}: header format is {header.get('format')!r}, not {FORMAT!r}")
    # The checksum first: an edited field (the version too) reads as an edit.
    if "header_sha256" in header and _header_digest(header) != header["header_sha256"]:
        raise ValueError(f"{name}: the header does not match its checksum (edited or corrupt)")
    version = header.get("format_version", 0)
    if isinstance(version, bool) or not isinstance(version, int):
        raise ValueError(
            f"{name}: format_version {version!r} is not an integer; the file is corrupt"
        )
    if version > FORMAT_VERSION:
        raise ValueError(
            f"{name} has format_version {version}; this library reads up to {FORMAT_VERSION}"
        )
    payload = data[start + n :]
    if len(payload) != header.get("payload_bytes") or (
        hashlib.sha256(payload).hexdigest() != header.get("payload_sha256")
    ):
        raise ValueError(f"{name}: the payload does not match its checksum (truncated or corrupt)")
    return header, payload


# ------------------------------------------------------------------------- state layouts


def _layout(fields: Sequence[tuple[str, tuple[int, ...]]]) -> list[dict]:
    """Offsets of fields packed one after the other into a flat vector."""
    out, offset = [], 0
    for name, shape in fields:
        size = int(np.prod(shape, dtype=np.int64))
        out.append({"name": name, "shape": list(shape), "offset": offset, "size": size})
        offset += size
    return out


def state_layout(n_legs: int, nq: int, nv: int) -> list[dict]:
    """Fields of the float32 state vector (booleans as 0/1)."""
    return _layout(
        [
            ("logit", (n_legs,)),
            ("log_transition", (n_legs, 2, 2)),
            ("foothold", (n_legs, 3)),
            ("foothold_valid", (n_legs,)),
            ("prev_qpos", (nq,)),
            ("prev_qvel", (nv,)),
            ("has_prev", ()),
        ]
    )


def output_layout(n_legs: int) -> list[dict]:
    """Fields of the float32 output vector: P(contact) then the diagnostics (per foot)."""
    fields = [("p_contact", (n_legs,))]
    fields += [(name, (n_legs,) + shape) for name, shape in DIAGNOSTIC_FIELDS]
    return _layout(fields)


def _pack(layout: list[dict], values: Mapping[str, jax.Array]) -> jax.Array:
    return jnp.concatenate([jnp.ravel(values[f["name"]]).astype(jnp.float32) for f in layout])


def _unpack(layout: list[dict], vec: jax.Array) -> dict[str, jax.Array]:
    return {
        f["name"]: vec[f["offset"] : f["offset"] + f["size"]].reshape(f["shape"]) for f in layout
    }


# ---------------------------------------------------------------- the robot's update (MJX)


def robot_update_fn(
    mj_model, desc, params, terrain, *, include_passive: bool = True, calibration=None
):
    """The single-robot update of :func:`export_robot`, as a jittable function.

    ``calibration`` (a :class:`jax_contact.Calibration` or None) maps the belief's logit
    before the output ``p_contact`` (:func:`jax_contact.calibration.probability`); the
    state keeps the raw logit the recursion runs on.

    Returns:
      ``(update, init)``: ``update(state, key, qpos, qvel, qacc, tau) -> (state, key, out)``
      on float32 vectors laid out by :func:`state_layout` / :func:`output_layout` (``key``
      a typed PRNG key), and ``init(seed) -> (state, key)``.
    """
    from mujoco import mjx  # only when exporting: the exported program needs no MuJoCo

    import jax_contact as jc
    from jax_contact.adapter import prepare, robot_measurement

    m = mjx.put_model(mj_model)
    template = mjx.make_data(m)
    n_legs, nq, nv = desc.n_legs, desc.nq, desc.nv
    s_layout, o_layout = state_layout(n_legs, nq, nv), output_layout(n_legs)

    quats = quaternion_slices(mj_model)

    def update(state, key, qpos, qvel, qacc, tau):
        s = _unpack(s_layout, state)
        for a in quats:  # no orientation: a lost reading (MIN_QUATERNION_NORM)
            lost = jnp.linalg.norm(qpos[a : a + 4]) < MIN_QUATERNION_NORM
            qpos = qpos.at[a : a + 4].set(jnp.where(lost, jnp.nan, qpos[a : a + 4]))
        has_prev = s["has_prev"] > 0.5
        # Pairing (module docstring): this reading's acceleration and torque with the
        # previous reading's state; the first reading with its own. Entry by entry: a
        # non-finite entry of the previous reading (a lost encoder sample, kept as it came)
        # is replaced by this reading's own, as on the first call, so a lost joint reading
        # is one call's invalid step for the feet below that joint only.
        prev_qpos, prev_qvel = s["prev_qpos"], s["prev_qvel"]
        qpos_s = jnp.where(has_prev & jnp.isfinite(prev_qpos), prev_qpos, qpos)
        qvel_s = jnp.where(has_prev & jnp.isfinite(prev_qvel), prev_qvel, qvel)
        # A coordinate whose velocity is not finite has no acceleration over this step.
        qacc = jnp.where(jnp.isfinite(qvel), qacc, jnp.nan)
        with jax.named_scope("adapter"):  # names the kernels in a profile
            d = prepare(m, template.replace(qpos=qpos_s, qvel=qvel_s))
            meas = robot_measurement(m, d, desc, qdd=qacc, tau=tau, include_passive=include_passive)
        belief = jc.LegBelief(
            logit=s["logit"],
            log_transition=s["log_transition"],
            foothold=s["foothold"],
            foothold_valid=s["foothold_valid"] > 0.5,
        )
        # replay's key schedule: split once per step, then once per foot.
        key, sub = jax.random.split(key)
        with jax.named_scope("estimator"):
            belief, diag = jc.step_robot(params, terrain, belief, meas, key=sub)
        new_state = _pack(
            s_layout,
            {
                "logit": belief.logit,
                "log_transition": belief.log_transition,
                "foothold": belief.foothold,
                "foothold_valid": belief.foothold_valid,
                "prev_qpos": qpos,
                "prev_qvel": qvel,
                "has_prev": jnp.ones((), jnp.float32),
            },
        )
        p = diag.p_contact if calibration is None else probability(belief.logit, calibration)
        out = _pack(o_layout, {"p_contact": p} | _diag_dict(diag))
        return new_state, key, out

    def init(seed: int = 0):
        b = jc.init_belief_batch(params, 1, n_legs)
        state = _pack(
            s_layout,
            {
                "logit": b.logit[0],
                "log_transition": b.log_transition[0],
                "foothold": b.foothold[0],
                "foothold_valid": b.foothold_valid[0],
                "prev_qpos": jnp.zeros(nq),
                "prev_qvel": jnp.zeros(nv),
                "has_prev": jnp.zeros(()),
            },
        )
        return state, jax.random.key(seed)

    return update, init


def _diag_dict(diag) -> dict[str, jax.Array]:
    return {name: getattr(diag, name) for name, _ in DIAGNOSTIC_FIELDS}


def check_rate_hz(rate_hz) -> float:
    """``rate_hz`` as a float: a finite number > 0 (Hz), else a ValueError naming it."""
    number = not isinstance(rate_hz, bool) and isinstance(
        rate_hz, int | float | np.integer | np.floating
    )
    if not (number and np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a finite number > 0 (Hz), got {rate_hz!r}")
    return float(rate_hz)


def export_robot(
    mj_model,
    desc,
    params,
    terrain,
    *,
    rate_hz: float,
    robot_source: str,
    provenance: Mapping | None = None,
    seed: int = 0,
    include_passive: bool = True,
    calibration=None,
) -> tuple[dict, bytes]:
    """Exports one robot's estimator update, its kinematics and dynamics included.

    Args:
      mj_model: the robot's compiled ``mujoco.MjModel`` (the estimator's nominal model).
      desc: its :class:`jax_contact.robot.RobotDescription` (feet, legs).
      params: the estimator parameters; ``params.dt`` must be ``1 / rate_hz``.
      terrain: the estimator's terrain model (``jax_contact.flat(...)``).
      rate_hz: the rate the readings arrive at, Hz.
      robot_source: how the model was loaded (a robot name or an MJCF path), recorded so
        that ``deploy-check`` can run the offline estimator on the same model.
      provenance: where the parameters came from (free-form, stored in the header).
      seed: seed of the PRNG key that :func:`jax_contact.deploy.Estimator.init` starts
        from (used by a Monte-Carlo touch-down only).
      include_passive: ``h`` includes the joint springs and dampers (as replay does).
      calibration: a :class:`jax_contact.Calibration` applied to the logit before the
        output ``p_contact`` (a parameter file's map, :func:`jax_contact.load_calibration`),
        stored in the header; None: P is the belief's own.

    Returns:
      ``(header, payload)`` for :func:`write_artefact`.

    Raises:
      ValueError: ``params.dt`` and ``rate_hz`` disagree, or the model is not the
        description's.
    """
    from jax_contact.params_file import params_to_dict

    check_rate_hz(rate_hz)
    dt = float(np.asarray(params.dt))
    if abs(dt * rate_hz - 1.0) > 1e-6:
        raise ValueError(
            f"the parameters' dt is {dt} s but the rate is {rate_hz} Hz (dt {1.0 / rate_hz} s):"
            " export parameters made for this rate"
        )
    if (mj_model.nq, mj_model.nv) != (desc.nq, desc.nv):
        raise ValueError(
            f"desc has nq={desc.nq}, nv={desc.nv} but the model has nq={mj_model.nq},"
            f" nv={mj_model.nv}: derive the description from the same model"
        )
    update, init = robot_update_fn(
        mj_model, desc, params, terrain, include_passive=include_passive, calibration=calibration
    )
    state0, key0 = init(seed)
    zeros = [jnp.zeros(n, jnp.float32) for n in (desc.nq, desc.nv, desc.nv, desc.nv)]
    exported, _ = export_flat(update, state0, key0, *zeros)
    payload = exported.serialize()
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "library_version": jax_contact.__version__,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "exported_with": {
            "jax": jax.__version__,
            "jaxlib": _version("jaxlib"),
            "mujoco": _version("mujoco"),
            "python": platform.python_version(),
            "platforms": list(exported.platforms),
            "serialization_version": int(exported.calling_convention_version),
        },
        "robot": _robot_header(mj_model, desc, robot_source),
        "rate_hz": float(rate_hz),
        "dt": 1.0 / float(rate_hz),
        "dtype": "float32",
        "call": {
            "signature": "update(state, key, qpos, qvel, qacc, tau) -> (state, key, out)",
            "arguments": ["state", "key", "qpos", "qvel", "qacc", "tau"],
            "results": ["state", "key", "out"],
        },
        "readings": readings_header(mj_model),
        "pairing": dict(PAIRING),
        "state": {
            "size": int(state0.shape[0]),
            "dtype": "float32",
            "layout": state_layout(desc.n_legs, desc.nq, desc.nv),
            "initial": np.asarray(state0).tolist(),
        },
        "key": {
            "shape": list(jax.random.key_data(key0).shape),
            "dtype": "uint32",
            "impl": str(jax.random.key_impl(key0)),
            "seed": int(seed),
            "initial": np.asarray(jax.random.key_data(key0)).tolist(),
        },
        "outputs": {
            "size": sum(f["size"] for f in output_layout(desc.n_legs)),
            "dtype": "float32",
            "layout": output_layout(desc.n_legs),
            "feet": list(desc.foot_names),
        },
        "terrain": _terrain_header(terrain),
        "include_passive": bool(include_passive),
        "params": params_to_dict(params, provenance),
        "calibration": None if calibration is None else calibration.as_dict(),
    }
    # As it reads back from the file (tuples become lists).
    return json.loads(json.dumps(header)), bytes(payload)


def quaternion_slices(mj_model) -> tuple[int, ...]:
    """The ``qpos`` address of each joint quaternion (w first): a free joint's at its
    address + 3, a ball joint's at its address."""
    import mujoco

    jt = mujoco.mjtJoint
    kinds = {int(jt.mjJNT_FREE): 3, int(jt.mjJNT_BALL): 0}
    return tuple(
        int(mj_model.jnt_qposadr[j]) + kinds[int(mj_model.jnt_type[j])]
        for j in range(mj_model.njnt)
        if int(mj_model.jnt_type[j]) in kinds
    )


def readings_header(mj_model) -> list[dict]:
    """Name, order, shape, unit and per-element labels of each reading, from the model."""
    import mujoco

    q_labels, q_units, v_labels, v_units = [], [], [], []
    jt = mujoco.mjtJoint
    for j in range(mj_model.njnt):
        name = mj_model.joint(j).name or f"joint{j}"
        kind = int(mj_model.jnt_type[j])
        if kind == int(jt.mjJNT_FREE):
            q_labels += [f"{name}:{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
            q_units += ["m"] * 3 + ["1"] * 4
            v_labels += [f"{name}:{c}" for c in ("vx", "vy", "vz", "wx", "wy", "wz")]
            v_units += ["m"] * 3 + ["rad"] * 3
        elif kind == int(jt.mjJNT_BALL):
            q_labels += [f"{name}:{c}" for c in ("qw", "qx", "qy", "qz")]
            q_units += ["1"] * 4
            v_labels += [f"{name}:{c}" for c in ("wx", "wy", "wz")]
            v_units += ["rad"] * 3
        else:
            unit = "m" if kind == int(jt.mjJNT_SLIDE) else "rad"
            q_labels.append(name)
            q_units.append(unit)
            v_labels.append(name)
            v_units.append(unit)

    def per(units, suffix):
        return [u + suffix if u != "1" else "1" for u in units]

    force = ["N" if u == "m" else "N m" for u in v_units]
    common = "float32; one reading per call, at the header's rate"
    return [
        {
            "name": "qpos",
            "shape": [int(mj_model.nq)],
            "labels": q_labels,
            "units": per(q_units, ""),
            "description": "measured generalised coordinates at the end of the physics step"
            " (MuJoCo order; a free joint: world position, then unit quaternion w, x, y, z),"
            f" {common}",
        },
        {
            "name": "qvel",
            "shape": [int(mj_model.nv)],
            "labels": v_labels,
            "units": per(v_units, "/s"),
            "description": "measured generalised velocities at the end of the step (a free"
            " joint: linear velocity in the world frame, angular velocity in the body frame,"
            f" MuJoCo's convention), {common}",
        },
        {
            "name": "qacc",
            "shape": [int(mj_model.nv)],
            "labels": v_labels,
            "units": per(v_units, "/s^2"),
            "description": "generalised acceleration over the step (backward difference of"
            " qvel, or an accelerometer for the base's linear coordinates), same frames as"
            f" qvel, {common}",
        },
        {
            "name": "tau",
            "shape": [int(mj_model.nv)],
            "labels": v_labels,
            "units": force,
            "description": "generalised actuation forces applied during the step (joint"
            f" torque sensors; zero on the base's coordinates), {common}",
        },
    ]


def _robot_header(mj_model, desc, source: str) -> dict:
    from jax_contact.robot import model_fingerprint, model_mass  # mujoco: at export time only

    soles = desc.soles
    return {
        "source": str(source),
        "nq": int(desc.nq),
        "nv": int(desc.nv),
        "feet": list(desc.foot_names),
        "leg_dofs": [list(leg) for leg in desc.leg_dofs],
        "base_dofs": list(desc.base_dofs),
        "foot_radii": list(desc.foot_radii),
        # Each foot's contact point on its body (m, body frame): a fixed point, or for a
        # foot with a sole its rolling point over these points (adapter.contact_points).
        "foot_points": [list(p) for p in desc.foot_offsets],
        "foot_soles": [[list(c) for c in sole] for sole in soles],
        "contact_point": "rolling" if any(soles) else "fixed",
        "total_mass_kg": model_mass(mj_model),
        "timestep_s": float(mj_model.opt.timestep),
        # The physics' fingerprint, as simulated logs store it: deploy-check compares them.
        "model_sha256": model_fingerprint(mj_model),
    }


def _terrain_header(terrain) -> dict:
    """The terrain model's type and scalar settings (a fallback model nested), for the
    header; a height field's grid is left out."""
    out = {"type": type(terrain).__name__}
    for f in dataclasses.fields(terrain):
        value = getattr(terrain, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = _terrain_header(value)
        elif np.ndim(value) == 0:
            out[f.name] = float(value)
    return out


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "unknown"
