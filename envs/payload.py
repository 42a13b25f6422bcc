"""Model error on the simulator side: a payload the estimator does not know about.

The paper's robustness test (Table III, "walk with added mass") simulates a heavier robot
than the estimator's model: :func:`add_mass` returns a copy of a ``mujoco.MjModel`` with a
point mass attached to one body, to simulate with, while the estimator keeps the nominal
model.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import mujoco
import numpy as np


def add_mass(
    mj_model: mujoco.MjModel,
    body: str | int,
    mass_kg: float,
    *,
    pos: Sequence[float] | None = None,
) -> mujoco.MjModel:
    """A copy of ``mj_model`` with a point mass rigidly attached to ``body``.

    The body's mass, centre of mass and inertia (about its new centre of mass, by the
    parallel-axis theorem, re-diagonalised into ``body_iquat``) are updated and MuJoCo's
    derived constants recomputed (``mj_setConst``), so the copy simulates the heavier
    robot. Use it for the simulated robot only; the estimator keeps the nominal model
    (the paper's +3 kg on the base, +200 g on a shank).

    Args:
      mj_model: the nominal model (not modified).
      body: body name or id (not the world).
      mass_kg: the added mass, kg, > 0.
      pos: (3,) where the point mass sits, in the body frame, m; None for the body's
        current centre of mass (then the inertia is unchanged).

    Returns:
      The modified copy.

    Raises:
      ValueError: an unknown body (the message lists the valid names), the world body, a
        non-positive mass or a ``pos`` of the wrong shape.
    """
    m = copy.deepcopy(mj_model)
    names = [m.body(i).name for i in range(1, m.nbody)]
    if isinstance(body, str):
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
        if bid < 1:
            raise ValueError(f"body: unknown body {body!r}; valid names: {names}")
    elif isinstance(body, int | np.integer) and 1 <= int(body) < m.nbody:
        bid = int(body)
    else:
        raise ValueError(f"body must be a body name or an id in [1, {m.nbody}), got {body!r}")
    if not (np.isfinite(mass_kg) and mass_kg > 0):
        raise ValueError(f"mass_kg must be a finite float > 0, got {mass_kg!r}")

    m0 = float(m.body_mass[bid])
    c0 = np.array(m.body_ipos[bid], dtype=np.float64)
    p = c0.copy() if pos is None else np.asarray(pos, dtype=np.float64)
    if p.shape != (3,):
        raise ValueError(f"pos must have shape (3,), got {p.shape}")
    # Inertia of the body about its old COM, in the body frame.
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(m.body_iquat[bid], dtype=np.float64))
    rot = rot.reshape(3, 3)
    inertia = rot @ np.diag(m.body_inertia[bid]) @ rot.T
    m1 = m0 + mass_kg
    c1 = (m0 * c0 + mass_kg * p) / m1

    def shift(mass: float, r: np.ndarray) -> np.ndarray:
        return mass * (np.dot(r, r) * np.eye(3) - np.outer(r, r))

    inertia1 = inertia + shift(m0, c0 - c1) + shift(mass_kg, p - c1)
    evals, evecs = np.linalg.eigh(0.5 * (inertia1 + inertia1.T))
    if np.linalg.det(evecs) < 0:
        evecs[:, 0] = -evecs[:, 0]
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, evecs.reshape(-1))
    m.body_mass[bid] = m1
    m.body_ipos[bid] = c1
    m.body_inertia[bid] = evals
    m.body_iquat[bid] = quat
    mujoco.mj_setConst(m, mujoco.MjData(m))
    return m
