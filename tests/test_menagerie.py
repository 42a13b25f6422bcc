"""Menagerie models load offline from ``MENAGERIE_ROOT`` as they ship (issue 16).

A Menagerie-style folder is made in each test: a robot MJCF whose visual mesh file does
not exist, a full ``scene.xml`` with a cylinder-box pair that MJX cannot collide, and a
``scene_mjx.xml`` with sphere collisions only. References are independent of the loader:
the ``<inertial>`` elements parsed with ElementTree, and hand sums of their masses.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from jax_contact.envs.model_files import MENAGERIE_SCENES
from jax_contact.envs.robots import load_robot

NAME = "unitree_go2"  # a Menagerie name the loader knows; the model is the test's own

_LEG = """
    <body name="{s}_thigh" pos="{x} 0 0">
      <joint name="{s}_hip" axis="0 1 0" range="-1.5 1.5"/>
      <inertial pos="0 0 -0.1" mass="0.8" diaginertia="0.004 0.004 0.001"/>
      <geom class="visual" mesh="thigh_mesh"/>
      {extra}
      <body name="{s}_calf" pos="0 0 -0.2">
        <joint name="{s}_knee" axis="0 1 0" range="-2.5 -0.2"/>
        <inertial pos="0 0 -0.1" mass="0.2" diaginertia="0.002 0.002 0.0005"/>
        <geom class="visual" mesh="calf_mesh"/>
        <geom name="{s}" type="sphere" size="0.02" pos="0 0 -0.2"/>
      </body>
    </body>"""


def _robot_xml(extra_on_front: str) -> str:
    legs = "".join(
        _LEG.format(s=s, x=x, extra=extra_on_front if s == "F" else "")
        for s, x in (("F", 0.2), ("H", -0.2))
    )
    motors = "".join(
        f'<motor name="{s}_{j}_m" joint="{s}_{j}" gear="1"/>' for s in "FH" for j in ("hip", "knee")
    )
    return f"""<mujoco model="tiny">
  <compiler angle="radian" meshdir="assets" autolimits="true"/>
  <default><default class="visual"><geom type="mesh" contype="0" conaffinity="0" group="2"/>
  </default></default>
  <asset>
    <mesh name="base_mesh" file="base_0.obj"/>
    <mesh name="thigh_mesh" file="thigh_0.obj"/>
    <mesh name="calf_mesh" file="calf_0.obj"/>
  </asset>
  <worldbody>
    <body name="base" pos="0 0 0.45">
      <freejoint/>
      <inertial pos="0.01 0 0" quat="1 0 0 0.1" mass="5.5" diaginertia="0.02 0.05 0.06"/>
      <geom class="visual" mesh="base_mesh"/>
      <geom name="trunk_col" type="sphere" size="0.05" contype="0" conaffinity="0"/>
      {legs}
    </body>
  </worldbody>
  <actuator>{motors}</actuator>
  <keyframe><key name="home" qpos="0 0 0.38 1 0 0 0 0.4 -0.8 0.4 -0.8"/></keyframe>
</mujoco>
"""


def _scene(robot_file: str, floor: str) -> str:
    return f"""<mujoco model="scene"><include file="{robot_file}"/>
  <worldbody>{floor}</worldbody></mujoco>"""


PLANE = '<geom name="floor" type="plane" size="5 5 0.1"/>'
# A step on the floor that the front thigh's cylinder can touch: MJX has no cylinder-box.
STEP = PLANE + '<geom name="step" type="box" size="0.1 0.1 0.05" pos="1 0 0.05"/>'
CYLINDER = '<geom name="F_thigh_col" type="cylinder" size="0.02 0.08" pos="0 0 -0.1"/>'


def _menagerie(tmp_path, *, mjx_variant: bool = True):
    folder = tmp_path / NAME
    folder.mkdir()
    (folder / "tiny.xml").write_text(_robot_xml(CYLINDER))
    (folder / "scene.xml").write_text(_scene("tiny.xml", STEP))
    if mjx_variant:
        (folder / "tiny_mjx.xml").write_text(_robot_xml(""))
        (folder / "scene_mjx.xml").write_text(_scene("tiny_mjx.xml", PLANE))
    return folder


def _xml_inertials(path) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """body -> (mass, COM, 3x3 inertia about the COM in the body frame), from the XML."""
    out = {}
    for body in ET.parse(path).getroot().iter("body"):
        inertial = body.find("inertial")
        quat = np.array([float(x) for x in inertial.get("quat", "1 0 0 0").split()])
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, quat / np.linalg.norm(quat))
        rot = rot.reshape(3, 3)
        diag = np.array([float(x) for x in inertial.get("diaginertia").split()])
        pos = np.array([float(x) for x in inertial.get("pos").split()])
        out[body.get("name")] = (float(inertial.get("mass")), pos, rot @ np.diag(diag) @ rot.T)
    return out


def test_mjx_variant_loads_without_meshes_and_keeps_the_inertias(monkeypatch, tmp_path):
    folder = _menagerie(tmp_path)
    assert not (folder / "assets").exists()  # no mesh file on disk at all
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    assert MENAGERIE_SCENES[0] == "scene_mjx.xml"
    robot = load_robot(NAME)
    m = robot.mj_model
    # The MJX variant was loaded: it has no cylinder and no step.
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "F_thigh_col") == -1
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "step") == -1
    assert m.nmesh == 0 and not np.any(m.geom_type == mujoco.mjtGeom.mjGEOM_MESH)
    reference = _xml_inertials(folder / "tiny_mjx.xml")
    for body, (mass, com, inertia) in reference.items():
        b = m.body(body).id
        np.testing.assert_allclose(m.body_mass[b], mass, rtol=1e-12, err_msg=body)
        np.testing.assert_allclose(m.body_ipos[b], com, atol=1e-12, err_msg=body)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, m.body_iquat[b])
        rot = rot.reshape(3, 3)
        got = rot @ np.diag(m.body_inertia[b]) @ rot.T
        np.testing.assert_allclose(got, inertia, rtol=1e-9, atol=1e-12, err_msg=body)
    # 5.5 + 2 x (0.8 + 0.2) = 7.5 kg
    np.testing.assert_allclose(m.body_mass.sum(), 7.5, rtol=1e-12)
    assert robot.description.foot_names == ("F", "H")
    assert robot.description.n_leg_dofs == 2


def test_full_scene_with_an_mjx_unsupported_pair_is_refused_by_name(monkeypatch, tmp_path):
    folder = _menagerie(tmp_path, mjx_variant=False)
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    with pytest.raises(ValueError) as err:
        load_robot(NAME)
    text = str(err.value)
    for part in ("F_thigh_col", "step", str(folder / "scene.xml"), "cylinder", "box"):
        assert part in text, text
    assert "\n" not in text


def test_an_mjcf_path_with_a_colliding_missing_mesh_names_the_file(tmp_path):
    # A mesh that can collide is kept, so its missing file is an error that says so.
    folder = tmp_path / "robot"
    folder.mkdir()
    xml = _robot_xml('<geom name="col_mesh" type="mesh" mesh="thigh_mesh"/>')
    (folder / "tiny.xml").write_text(xml)
    (folder / "scene.xml").write_text(_scene("tiny.xml", PLANE))
    with pytest.raises(ValueError, match="thigh_0.obj"):
        load_robot(str(folder / "scene.xml"))


def test_a_texture_file_that_does_not_exist_is_dropped_with_the_meshes(monkeypatch, tmp_path):
    """Menagerie's A1 paints its trunk with a texture file (trunk_A1.png) that, like the
    meshes, is visual only: the model loads without it, its physics unchanged."""
    folder = tmp_path / NAME
    folder.mkdir()
    painted = (
        _robot_xml("")
        .replace(
            "<asset>",
            '<asset><texture name="skin" type="2d" file="skin.png"/>'
            '<material name="painted" texture="skin"/>',
        )
        .replace('name="trunk_col"', 'name="trunk_col" material="painted"')
    )
    (folder / "tiny.xml").write_text(painted)
    (folder / "scene.xml").write_text(_scene("tiny.xml", PLANE))
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    m = load_robot(NAME).mj_model
    assert m.ntex == 0 and m.nmat == 1
    np.testing.assert_allclose(m.body_mass.sum(), 7.5, rtol=1e-12)
