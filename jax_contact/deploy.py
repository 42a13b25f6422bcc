"""Run an exported estimator (``jax-contact export``) on a robot: ``jax`` and NumPy only.

Usage, in a control loop at the export's rate::

    from jax_contact import deploy

    est = deploy.load("go1.contact")          # reads, checks and compiles (seconds, once)
    belief = est.init()
    while running:
        r = {"qpos": qpos, "qvel": qvel, "qacc": qacc, "tau": tau}   # one reading
        belief, p_contact, diag = est.update(belief, r)              # p_contact: (n_feet,)

This module never imports ``mujoco``: the robot's kinematics and dynamics are part of the
exported program. Readings are checked against the file's header (names and lengths; a
wrong one raises a ValueError naming it). Finite values are not required: a reading with
a NaN is the estimator's invalid step, which predicts from the gait prior alone.
See docs/deploy.md.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import NamedTuple

import jax
import numpy as np

from jax_contact.export import load_exported, read_artefact


class Belief(NamedTuple):
    """What the estimator carries from one call to the next (opaque to the caller).

    Attributes:
      state: float32 vector: per foot the contact logit, the next transition, the foothold
        memory, and the previous reading's ``qpos`` and ``qvel`` (layout: the header's
        ``state.layout``).
      key: uint32 raw PRNG key (used by a Monte-Carlo touch-down only).
    """

    state: np.ndarray
    key: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class Estimator:
    """A loaded exported estimator. Build it with :func:`load`.

    Attributes:
      header: the file's JSON header (readings, state and output layouts, parameters and
        their provenance, versions).
      path: the file it was loaded from.
    """

    header: dict
    path: str
    _call: object = dataclasses.field(repr=False)
    _readings: tuple[tuple[str, int], ...] = dataclasses.field(repr=False)
    _outputs: tuple[tuple[str, int, int, tuple[int, ...]], ...] = dataclasses.field(repr=False)

    @property
    def feet(self) -> list[str]:
        """Foot names, the order of ``p_contact``."""
        return list(self.header["outputs"]["feet"])

    @property
    def reading_names(self) -> list[str]:
        """The readings :meth:`update` expects, in order."""
        return [name for name, _ in self._readings]

    @property
    def rate_hz(self) -> float:
        return float(self.header["rate_hz"])

    def init(self) -> Belief:
        """The belief before the first reading (the parameters' initial contact prior)."""
        return Belief(
            state=np.asarray(self.header["state"]["initial"], np.float32),
            key=np.asarray(self.header["key"]["initial"], np.uint32),
        )

    def update(
        self, belief: Belief, readings: Mapping[str, np.ndarray]
    ) -> tuple[Belief, np.ndarray, dict[str, np.ndarray]]:
        """One estimator step on one reading.

        Args:
          belief: from :meth:`init` or the previous call.
          readings: ``qpos`` (nq,), ``qvel``, ``qacc``, ``tau`` (nv,) of this reading
            (units, frames and the joint order: the header's ``readings``); converted to
            float32.

        Returns:
          ``(belief, p_contact, diagnostics)``: the next belief, (n_feet,) P(contact) per
          foot, and per foot ``p_dynamics``, ``p_diff_kinematics``, ``p_kinematics``,
          ``p_takeoff``, ``p_touchdown`` (n_feet,), ``force`` (n_feet, 3) N and ``valid``
          (n_feet,) bool (False: a non-finite reading, the step predicted only; there the
          three terms' probabilities and ``force`` are NaN, "no measurement", as in
          :class:`jax_contact.Diagnostics`, while ``p_contact`` and the transitions are
          the prediction's).

        Raises:
          ValueError: a missing or unknown reading, one of the wrong length or not of
            real numbers (named); a belief not of this file's layout.
        """
        state, key = self._belief_arrays(belief)
        if not isinstance(readings, Mapping):
            raise ValueError(
                f"readings must be a mapping of {self.reading_names} to arrays, got"
                f" {type(readings).__name__}"
            )
        args = []
        for name, n in self._readings:
            try:
                x = readings[name]
            except KeyError:
                raise ValueError(
                    f"readings has no {name!r}: expected {self.reading_names}"
                ) from None
            x = np.asarray(x)
            if x.dtype.kind not in "fiu":  # bool, complex, str, None (object): no reading
                raise ValueError(
                    f"readings[{name!r}] must hold real numbers (float or int), got dtype {x.dtype}"
                )
            with np.errstate(over="ignore"):  # beyond float32: inf, a lost reading
                x = x.astype(np.float32, copy=False)
            if x.shape != (n,):
                raise ValueError(
                    f"readings[{name!r}] has shape {x.shape}, expected ({n},): "
                    f"{_size_note(self.header, name)}"
                )
            args.append(x)
        if len(readings) != len(self._readings):
            extra = sorted(set(readings) - set(self.reading_names))
            raise ValueError(f"unknown reading(s) {extra}: expected {self.reading_names}")
        state, key, out = self._call(state, key, *args)
        out = np.asarray(out)
        diag = {name: out[a:b].reshape(shape) for name, a, b, shape in self._outputs}
        diag["valid"] = diag["valid"] > 0.5
        p_contact = diag.pop("p_contact")
        return Belief(np.asarray(state), np.asarray(key)), p_contact, diag

    def _belief_arrays(self, belief: Belief) -> tuple[np.ndarray, np.ndarray]:
        """(state float32, key uint32) of a belief, checked against this file's layout."""
        state, key = getattr(belief, "state", None), getattr(belief, "key", None)
        if state is None or key is None:
            raise ValueError(
                "belief must be the Belief that init() or the previous update() returned, got"
                f" {type(belief).__name__}"
            )
        want = {
            "state": ((self.header["state"]["size"],), np.float32, "f"),
            "key": (tuple(self.header["key"]["shape"]), np.uint32, "iu"),
        }
        out = []
        for field, x in (("state", state), ("key", key)):
            shape, dtype, kinds = want[field]
            x = np.asarray(x)
            if x.shape != shape or x.dtype.kind not in kinds:
                raise ValueError(
                    f"belief.{field} has shape {x.shape} and dtype {x.dtype}; this file's is"
                    f" {shape} {np.dtype(dtype)} (a belief of another exported estimator, or"
                    " one rebuilt by hand? keep the Belief that update() returned)"
                )
            out.append(x.astype(dtype, copy=False))
        return out[0], out[1]


def _size_note(header: dict, name: str) -> str:
    for r in header["readings"]:
        if r["name"] == name:
            head = ", ".join(r["labels"][:3])
            return f"{len(r['labels'])} entries ({head}, ... in the model's order)"
    return "see the header"


def load(path: str | os.PathLike, *, compile: bool = True) -> Estimator:
    """Loads an exported estimator (``jax-contact export``).

    Args:
      path: the ``.contact`` file.
      compile: compile now (seconds; the first :meth:`Estimator.update` is then as fast
        as the others) rather than at the first call.

    Returns:
      The :class:`Estimator`.

    Raises:
      FileNotFoundError: no such file.
      ValueError: not an exported estimator, a newer format, or a corrupt file (naming
        the file).
    """
    header, payload = read_artefact(path)
    name = f"exported estimator {str(path)!r}"
    # A file written before the header had a checksum is read unchecked: a missing or
    # malformed entry is named here, not as a KeyError or a pytree mismatch of jax.export.
    try:
        readings = tuple((r["name"], int(r["shape"][0])) for r in header["readings"])
        outputs = tuple(
            (f["name"], int(f["offset"]), int(f["offset"]) + int(f["size"]), tuple(f["shape"]))
            for f in header["outputs"]["layout"]
        )
        avals = (
            jax.ShapeDtypeStruct((int(header["state"]["size"]),), np.float32),
            jax.ShapeDtypeStruct(tuple(int(n) for n in header["key"]["shape"]), np.uint32),
        ) + tuple(jax.ShapeDtypeStruct((n,), np.float32) for _, n in readings)
        # The period three ways: rate_hz, dt and the parameters' dt (float32), which the
        # export wrote equal. A rate edited in a header without a checksum ran the program
        # at its own period while rate_hz said another (a helper's trial).
        rate, periods = float(header["rate_hz"]), (header["dt"], header["params"]["values"]["dt"])
    except (KeyError, IndexError, TypeError, ValueError) as err:
        raise ValueError(
            f"{name}: its header lacks or garbles {type(err).__name__} {err}; the file is"
            " corrupt (export it again)"
        ) from None
    if not all(isinstance(d, int | float) and abs(d * rate - 1.0) < 1e-5 for d in periods):
        raise ValueError(
            f"{name}: its header's rate_hz ({rate:g}) disagrees with its dt and its"
            f" parameters' dt ({', '.join(repr(d) for d in periods)} s): edited or corrupt"
            " (export it again)"
        )
    try:
        exported = load_exported(payload)
    except Exception as err:  # flatbuffers' and jax's own errors name no file
        raise ValueError(
            f"{name}: its payload is not an exported program ({type(err).__name__}); the file"
            " is corrupt (export it again)"
        ) from None
    if len(exported.in_avals) != len(avals) or any(
        a.shape != b.shape for a, b in zip(exported.in_avals, avals, strict=False)
    ):
        raise ValueError(
            f"{name}: the header's state, key and readings do not match the program's inputs"
            f" ({[a.shape for a in avals]} against {[a.shape for a in exported.in_avals]});"
            " the file is corrupt (export it again)"
        )
    call = jax.jit(exported.call)
    if compile:
        call = call.lower(*avals).compile()
    return Estimator(
        header=header, path=str(path), _call=call, _readings=readings, _outputs=outputs
    )
