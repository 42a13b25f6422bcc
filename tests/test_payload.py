"""Tests of envs/payload.py: a point mass added to a body, against the parallel-axis theorem."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from jax_contact.envs.payload import add_mass
from jax_contact.envs.robots import load_robot


def test_add_mass_payload():
    robot = load_robot("go1")
    m0 = robot.mj_model
    base = robot.description.base_body_id
    pos = np.array([0.1, 0.0, 0.05])
    m1 = add_mass(m0, base, 3.0, pos=pos)
    assert m1 is not m0 and m0.body_mass[base] == pytest.approx(5.204)
    np.testing.assert_allclose(m1.body_mass[base], 5.204 + 3.0)
    # mj_setConst refreshed the derived constants: the whole robot is 3 kg heavier.
    np.testing.assert_allclose(m1.body_subtreemass[0], m0.body_subtreemass[0] + 3.0, rtol=1e-9)
    c0 = m0.body_ipos[base]
    c1 = (5.204 * c0 + 3.0 * pos) / 8.204
    np.testing.assert_allclose(m1.body_ipos[base], c1, atol=1e-12)

    # Parallel-axis theorem about the new COM: I1 = I0 + m0 (|a|^2 E - a a^T) + m (|b|^2 E - b b^T)
    # with a = c0 - c1, b = pos - c1.
    a, b = c0 - c1, pos - c1
    expected = (
        inertia_of(m0, base)
        + 5.204 * (a @ a * np.eye(3) - np.outer(a, a))
        + 3.0 * (b @ b * np.eye(3) - np.outer(b, b))
    )
    np.testing.assert_allclose(inertia_of(m1, base), expected, atol=1e-9)
    # 200 g on a shank, at its COM: mass only.
    shank = robot.description.foot_body_ids[0]
    m2 = add_mass(m0, int(shank), 0.2)
    np.testing.assert_allclose(m2.body_mass[shank], m0.body_mass[shank] + 0.2)
    np.testing.assert_allclose(inertia_of(m2, shank), inertia_of(m0, shank), atol=1e-12)
    with pytest.raises(ValueError, match="valid names"):
        add_mass(m0, "no_such_body", 1.0)
    with pytest.raises(ValueError, match="mass_kg"):
        add_mass(m0, base, -1.0)


def inertia_of(m, body):
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[body])
    rot = rot.reshape(3, 3)
    return rot @ np.diag(m.body_inertia[body]) @ rot.T
