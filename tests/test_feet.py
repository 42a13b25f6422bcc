"""Feet as robots have them (envs/feet.py), force axes, and truth from MJX contacts.

Small MJCF models written here, so every expected point is derived by hand from the XML:
a one-legged robot on a rail (hip and knee about y) whose shank ends in a box sole, with
a site at its toe; variants with a rotated sole, two corner spheres and a ``<pair>``-only
sole; a two-joint leg (hip yaw, knee pitch) for the force axes. One compiled program
(a scan of ``mjx.step`` on the box-footed leg) checks the contact-based truth against the
robot's weight.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from jax_contact import adapter
from jax_contact.envs import contact_truth, feet
from jax_contact.envs import wrapper as W
from jax_contact.envs.contact_config import validate_config
from jax_contact.envs.robots import Robot, load_robot
from jax_contact.robot import derive_description

LEG = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <body name="base" pos="0 0 {z}">
      <joint name="rail" type="slide" axis="0 0 1" damping="20"/>
      <geom type="box" size=".1 .1 .05" contype="0" conaffinity="0" mass="5"/>
      <body name="thigh">
        <joint name="hip" axis="0 1 0" damping="2"/>
        <geom type="capsule" fromto="0 0 0 0 0 -.25" size=".02" contype="0" conaffinity="0"/>
        <body name="shank" pos="0 0 -.25">
          <joint name="knee" axis="0 1 0" damping="2"/>
          <geom type="capsule" fromto="0 0 0 0 0 -.25" size=".02" contype="0" conaffinity="0"/>
          {foot}
          <site name="toe" pos="0.08 0 -0.26"/>
        </body>
      </body>
    </body>
  </worldbody>
  {contact}
  <actuator><position joint="hip" kp="500"/><position joint="knee" kp="500"/></actuator>
</mujoco>
"""
BOX = '<geom name="sole" type="box" pos="0.01 0 -0.25" size=".08 .03 .01"/>'


def _model(foot=BOX, contact="", z=0.6) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(LEG.format(foot=foot, contact=contact, z=z))


def _one(m, names=None) -> feet.Foot:
    desc, resolved = feet.describe(m, names)
    assert desc.n_legs == 1 and desc.leg_dofs == ((1, 2),)
    return resolved[0]


def test_box_sole_site_body_and_offset():
    m = _model()
    # Box at (0.01, 0, -0.25) in the shank frame, half height 0.01, axes aligned: the
    # sole is the centre of its bottom face, (0.01, 0, -0.26), radius 0.
    f = _one(m)  # found with no names: the only floor-touching geom on the leg
    assert (f.name, f.kind, f.radius) == ("sole", "box", 0.0)
    np.testing.assert_allclose(f.point, (0.01, 0.0, -0.26), atol=1e-12)
    assert _one(m, ["sole"]) == f
    assert _one(m, ["shank"]).point == f.point  # the body of one geom: that geom
    toe = _one(m, ["toe"])  # a site: its position, radius 0, the body's geoms as truth
    assert toe.kind == "site" and toe.geom_ids == f.geom_ids
    np.testing.assert_allclose(toe.point, (0.08, 0.0, -0.26), atol=1e-7)
    spec = _one(m, [W.FootSpec("heel", body="shank", offset=(-0.07, 0, -0.26), radius=0.005)])
    assert (spec.kind, spec.point, spec.radius) == ("body", (-0.07, 0.0, -0.26), 0.005)
    with pytest.raises(ValueError, match="valid names"):
        feet.describe(m, ["nope"])
    # A geom on the named body (or below it) gives the truth; one elsewhere (here the
    # floor, on the world body) would give this foot another's, and is refused by name.
    named = _one(m, [W.FootSpec("heel", body="shank", geoms=("sole",))])
    assert named.geom_ids == f.geom_ids
    with pytest.raises(ValueError, match=r"FootSpec 'heel': geom 'floor' is on body 'world'"):
        feet.describe(m, [W.FootSpec("heel", body="shank", geoms=("floor",))])


@pytest.mark.parametrize(
    "field, value, want",
    [
        ("offset", (0.0, 0.0), "3 finite numbers"),
        ("offset", "0 0 -0.2", "3 finite numbers"),
        ("offset", (0.0, np.nan, 0.0), "3 finite numbers"),
        ("radius", -1.0, "a finite number >= 0"),
        ("radius", "2", "a finite number >= 0"),
        ("geoms", "sole", "a tuple of geom names"),
        ("body", 3, "a body name or None"),
    ],
)
def test_a_foot_spec_names_its_bad_field(field, value, want):
    """A 2-vector offset was a matmul error at wrap time, a string offset a float() error,
    and a negative radius passed into the report."""
    with pytest.raises(ValueError, match=rf"FootSpec 'heel': {field} must be {want}"):
        W.FootSpec("heel", **{"body": "shank", field: value})
    spec = W.FootSpec("heel", body="shank", offset=np.array([0, 0, -1]), geoms=["sole"])
    assert spec.offset == (0.0, 0.0, -1.0) and spec.geoms == ("sole",)


def test_a_foot_spec_takes_any_real_radius_and_refuses_options_without_a_body():
    """A helper's audit: NumPy's and JAX's float32 radius were refused ("must be a finite
    number >= 0, ..., got np.float32(0.02)"), and without ``body`` the offset, radius and
    geoms were ignored without a word, even a geom name that does not exist."""
    for r in (np.float32(0.02), jnp.float32(0.02), np.int64(0), 1):
        spec = W.FootSpec("heel", body="shank", radius=r)
        assert type(spec.radius) is float and spec.radius == pytest.approx(float(r))
    for bad in (np.array([0.02, 0.03]), True):
        with pytest.raises(ValueError, match="radius must be a finite number >= 0"):
            W.FootSpec("heel", body="shank", radius=bad)
    with pytest.raises(ValueError, match=r"FootSpec 'FR_calf': offset, radius apply to a foot"):
        W.FootSpec("FR_calf", offset=(0, 0, -0.1), radius=0.05)
    with pytest.raises(ValueError, match=r"FootSpec 'FR': geoms apply to a foot given by its body"):
        W.FootSpec("FR", geoms=("nonexistent",))
    assert W.FootSpec("FR").body is None  # the name alone is still a foot


def _all_sphere_model() -> mujoco.MjModel:
    """Two legs (hip, knee) whose thigh and calf carry spheres besides the foot's."""
    leg = (
        '<body name="{s}_thigh" pos="{x} 0 0"><joint name="{s}_hip" axis="0 1 0"/>'
        '<geom type="sphere" size=".03" pos="0 0 -.1"/><body name="{s}_calf" pos="0 0 -.2">'
        '<joint name="{s}_knee" axis="0 1 0"/><geom type="sphere" size=".025" pos="0 0 -.1"/>'
        '<geom name="{s}" type="sphere" size=".02" pos="0 0 -.2"/></body></body>'
    )
    return mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<body name="base" pos="0 0 .45"><freejoint/><geom type="box" size=".2 .1 .05"/>'
        + "".join(leg.format(s=s, x=x) for s, x in (("F", 0.2), ("H", -0.2)))
        + "</body></worldbody><actuator>"
        + "".join(f'<motor joint="{s}_{j}"/>' for s in "FH" for j in ("hip", "knee"))
        + "</actuator></mujoco>"
    )


def test_found_feet_of_an_all_sphere_model_are_the_legs_ends():
    """Menagerie's Go2 MJX model makes every collision geom a sphere: hips, thighs, calves
    and feet. Here two legs whose thigh carries a 3 cm sphere 0.1 m down and whose calf
    carries a 2.5 cm sphere 0.1 m down besides the 2 cm foot 0.2 m down. The found feet are
    the legs' ends (the calves: no floor-touching body below them) and, of a calf's
    spheres, the one at the sole: the calf sphere's lowest point is 0.1 - 0.025 + 0.02 =
    0.095 m above the foot's at the home pose (qpos0, legs straight), beyond SOLE_SPREAD.
    Before, every body with a sphere was a foot: 'every leg must have the same number of
    dofs' (a thigh's leg has one joint, a calf's two)."""
    m = _all_sphere_model()
    desc, resolved = feet.describe(m)
    assert desc.foot_names == ("F", "H") and [f.kind for f in resolved] == ["sphere"] * 2
    assert desc.foot_offsets == ((0.0, 0.0, -0.2),) * 2 and desc.foot_radii == (0.02, 0.02)
    assert desc.leg_dofs == ((6, 7), (8, 9))
    assert derive_description(m).foot_names == desc.foot_names  # the log commands' rule


def test_a_foot_named_above_its_legs_end_is_warned_of():
    """Feet named on the thighs of the all-sphere model (each thigh body carries a
    floor-touching sphere, so the name resolves) leave each knee below its "foot": one
    warning, from both the wrapper's rule and the log commands', names both feet and
    their knees. The real feet raise none."""
    m = _all_sphere_model()
    for describe in (lambda n: feet.describe(m, n), lambda n: derive_description(m, n)):
        with pytest.warns(UserWarning, match="actuated joints below") as caught:
            describe(["F_thigh", "H_thigh"])
        assert len(caught) == 1
        msg = str(caught[0].message)
        assert "'F_thigh' (body 'F_thigh': F_knee)" in msg and "'H_thigh'" in msg, msg
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            describe(["F", "H"])


def test_rotated_box_takes_its_lowest_face():
    # Rotated 90 deg about x: the box's y half-size (0.03) now points down, so its
    # lowest face's centre is 0.03 below the geom centre: (0.01, 0, -0.28).
    m = _model(
        '<geom name="sole" type="box" pos="0.01 0 -0.25" euler="90 0 0" size=".08 .03 .01"/>'
    )
    np.testing.assert_allclose(_one(m).point, (0.01, 0.0, -0.28), atol=1e-9)


def test_corner_spheres_are_one_foot_and_pairs_count_as_contact():
    two = (
        '<geom name="c1" type="sphere" pos="0.05 0 -0.25" size=".015"/>'
        '<geom name="c2" type="sphere" pos="-0.05 0 -0.25" size=".015"/>'
    )
    f = _one(_model(two))
    # One foot (the shank), the mean of the two centres and radii.
    assert (f.name, f.kind, f.radius) == ("shank", "2 sphere geoms", 0.015)
    np.testing.assert_allclose(f.point, (0.0, 0.0, -0.25), atol=1e-12)
    assert len(f.geom_ids) == 2
    # A sole that cannot collide by contype/conaffinity but has an explicit <pair>.
    paired = BOX.replace("/>", ' contype="0" conaffinity="0"/>')
    m = _model(paired, '<contact><pair geom1="floor" geom2="sole"/></contact>')
    assert _one(m).name == "sole"
    with pytest.raises(ValueError, match="no floor contact"):
        feet.describe(_model(paired))


def test_a_named_geom_that_cannot_touch_the_floor_reads_its_bodys_truth():
    """A user trial named T1's foot boxes, which collide only with each other (contype
    4): the truth read that box, so air on every step of a robot standing still. The
    box now gives the point and its body's floor-touching geoms the truth; a body with
    none is refused."""
    # A box of contype/conaffinity 4 (the plane's are 1) beside a sphere that touches it.
    plate = (
        '<geom name="plate" type="box" pos="0.01 0 -0.25" size=".08 .03 .01" contype="4"'
        ' conaffinity="4"/>'
    )
    ball = '<geom name="ball" type="sphere" pos="0 0 -0.25" size=".015"/>'
    m = _model(plate + ball)
    f = _one(m, ["plate"])
    truth = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "ball"),)
    assert (f.kind, f.geom_ids) == ("box", truth)
    np.testing.assert_allclose(f.point, (0.01, 0.0, -0.26), atol=1e-12)  # the plate's sole
    # The only floor-touching geom in a welded child body: the shank has none.
    m = _model(plate + f'<body name="tip">{ball}</body>')
    with pytest.raises(ValueError, match=r"geom 'plate' cannot touch the floor .* body 'shank'"):
        feet.describe(m, ["plate"])


ANT = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <body name="torso" pos="0 0 0.3">
      <freejoint/>
      <geom type="sphere" size=".05" contype="0" conaffinity="0"/>
      <body name="thigh">
        <joint name="hip" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 .2 0 0" size=".02" contype="0" conaffinity="0"/>
        <body name="shank" pos=".2 0 0">
          <joint name="knee" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 .1 0 -.2" size=".02" contype="0" conaffinity="0"/>
          <geom name="foot" type="sphere" pos=".1 0 -.2" size=".02"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="hip"/><motor joint="knee"/></actuator>
  <keyframe><key name="home" qpos="0 0 0.3 1 0 0 0 0 0"/></keyframe>
</mujoco>
"""


def test_force_rows_keep_the_normal():
    """Two-joint leg like Brax's ant, foot at p = (0.3, 0, -0.2) from the hip. Jacobian
    columns: hip (z axis at the origin) z x p = (0, 0.3, 0); knee (y axis at (0.2, 0, 0))
    y x (0.1, 0, -0.2) = (-0.2, 0, -0.1). Row norms x 0.2, y 0.3, z 0.1: the two largest
    are x and y (what the old rule chose, no normal); the normal is kept with the largest
    tangential axis: (1, 2)."""
    m = mujoco.MjModel.from_xml_string(ANT)
    desc, _ = feet.describe(m)
    assert W.choose_force_rows(m, desc) == (1, 2)
    robot = Robot(name="ant", mj_model=m, description=desc, spec=mujoco.MjSpec.from_string(ANT))
    env = W.LeggedPipelineEnv(robot)
    assert W.wrap_contact(env).contact_report()["force_rows"] == (1, 2)
    over = W.wrap_contact(env, W.ContactObsConfig(force_rows=(0, 2)))
    assert over.contact_report()["force_rows"] == (0, 2)
    with pytest.raises(ValueError, match="force_rows"):
        W.wrap_contact(env, W.ContactObsConfig(force_rows=(0, 3)))


# One leg of three hinges, the first about {axis}, then a knee and an ankle about y; the
# foot sphere 0.1 m ahead of and 0.45 m below the hip.
LEG_3 = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <body name="torso" pos="0 0 0.5">
      <freejoint/>
      <geom type="sphere" size=".05" contype="0" conaffinity="0"/>
      <body name="hip_body">
        <joint name="hip" axis="{axis}"/>
        <geom type="capsule" fromto="0 0 0 0 0 -.2" size=".02" contype="0" conaffinity="0"/>
        <body name="thigh" pos="0 0 -.2">
          <joint name="knee" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 .05 0 -.2" size=".02" contype="0" conaffinity="0"/>
          <body name="shank" pos=".05 0 -.2">
            <joint name="ankle" axis="0 1 0"/>
            <geom name="foot" type="sphere" pos=".05 0 -.05" size=".02"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="hip"/><motor joint="knee"/><motor joint="ankle"/></actuator>
</mujoco>
"""


def test_a_planar_leg_of_three_joints_keeps_the_plane():
    """Brax's walker2d, hopper and halfcheetah have legs of three hinges about y: the foot
    moves in the x-z plane only, so the y row of every leg's Jacobian is zero (a hinge
    about y moves a point by y x r, which has no y component) and the leg cannot push
    along y: rows (0, 2), where every leg of three joints used to get (0, 1, 2). The same
    leg with its first hinge about x (a hip abduction) spans y: (0, 1, 2). The log
    commands' defaults (``default_estimator`` with the model) take the same rows; without
    the model a leg of three joints keeps all three."""
    from jax_contact.train.log_estimator import default_estimator

    for axis, rows in (("0 1 0", (0, 2)), ("1 0 0", (0, 1, 2))):
        m = mujoco.MjModel.from_xml_string(LEG_3.format(axis=axis))
        desc, _ = feet.describe(m)
        assert desc.n_leg_dofs == 3
        assert W.choose_force_rows(m, desc) == rows, axis
        assert default_estimator(desc, 0.0025, mj_model=m)[0].force_rows == rows, axis
        assert default_estimator(desc, 0.0025)[0].force_rows == (0, 1, 2), axis


def test_evaluate_and_export_defaults_choose_a_short_legs_force_rows():
    """``evaluate``, ``estimate`` and ``export`` build their defaults with
    ``train.log_estimator.default_estimator``: a floating-base robot of two-joint legs gets the
    wrapper's force rows (the test above: (1, 2)), not the planar leg's estimator (it
    raised 'nv must be the planar leg's 3'); without the model it says what it needs.
    ``tune`` on a simulated log starts from the same (it raised that error on such logs),
    with the log's sensor preset in place of ``anymal_like``."""
    from jax_contact.train.log_estimator import default_estimator
    from jax_contact.train.tune_data import default_params

    m = mujoco.MjModel.from_xml_string(ANT)
    desc, _ = feet.describe(m)
    params, _ = default_estimator(desc, 0.0025, mj_model=m)
    assert params.force_rows == (1, 2) and params.nv == desc.nv == 8
    assert params.unilateral is False  # as the wrapper (the test below)
    with pytest.raises(ValueError, match=r"legs of 2 joints.*pass mj_model"):
        default_estimator(desc, 0.0025)
    robot = Robot(name="ant", mj_model=m, description=desc, spec=None)
    same, _ = default_params(robot, 0.0025, "anymal_like")
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(np.all(a == b)), same, params))
    ideal, _ = default_params(robot, 0.0025, "ideal")
    assert ideal.force_rows == (1, 2) and ideal.unilateral is False
    assert float(ideal.noise.sigma_qd[-1]) < float(params.noise.sigma_qd[-1])  # its own sensors


def test_contact_truth_carries_the_weight():
    """Sole resting on the floor (base at 0.51 m puts the sole's bottom at 0): after 1 s
    the summed normal force of its contacts is the robot's weight (hand check: the rail
    carries no vertical load). Started 0.3 m higher, the foot falls for
    sqrt(2 0.3 / 9.81) = 0.25 s (124 steps): no force and no contact over the first 100."""
    m = _model(z=0.51)
    desc, resolved = feet.describe(m)
    force = contact_truth.contact_normal_force(m, resolved, desc.floor_geom_ids)
    reader, source = contact_truth.truth_reader(m, desc, resolved, "auto", 1.0)
    assert source == "contacts"  # no sensors in this model
    mx = mjx.put_model(m)

    @jax.jit
    def run(d):
        def body(d, _):
            d = mjx.step(mx, d)
            return d, (force(d), reader(d))

        return jax.lax.scan(body, d, (), 500)[1]

    d0 = mjx.make_data(m)
    f_down, t_down = (np.asarray(x) for x in run(d0))
    weight = float(m.body_subtreemass[1]) * 9.81
    np.testing.assert_allclose(f_down[-1], [weight], rtol=0.02)
    assert t_down[-50:].all()
    f_up, t_up = (np.asarray(x) for x in run(d0.replace(qpos=d0.qpos.at[0].set(0.3))))
    np.testing.assert_array_equal(f_up[:100], 0.0)
    assert not t_up[:100].any()
    np.testing.assert_allclose(f_up[-1], [weight], rtol=0.02)  # landed and settled


def _gap_readers():
    """The box-footed leg with its sole's bottom at 0 (base at 0.51 m), and its readers:
    sole-floor distance, the raw force truth, the truth with a 1 mm ``truth_gap``."""
    m = _model(z=0.51)
    desc, resolved = feet.describe(m)
    gap = contact_truth.contact_gap(m, resolved, desc.floor_geom_ids)
    raw, _ = contact_truth.truth_reader(m, desc, resolved, "auto", 1.0)
    tol, _ = contact_truth.truth_reader(m, desc, resolved, "auto", 1.0, gap=0.001)
    return m, mjx.put_model(m), (gap, raw, tol)


def test_truth_gap_counts_a_sole_just_above_the_floor():
    """Base at 0.51 m puts the sole's bottom at 0 (as above); qpos[0] is the rail's height
    offset, so +0.5 mm lifts the sole 0.5 mm: the sole-floor distance reads 0.5 mm, the
    raw truth says air, a 1 mm ``truth_gap`` says contact, and 2 mm up is air for both."""
    m, mx, (gap, raw, tol) = _gap_readers()

    @jax.jit
    def read(lift):
        d = mjx.make_data(m)
        d = mjx.forward(mx, d.replace(qpos=d.qpos.at[0].set(lift)))
        return gap(d), raw(d), tol(d)

    dist, r, t = (np.asarray(x) for x in read(0.0005))
    np.testing.assert_allclose(dist, [0.0005], atol=1e-5)
    assert not r.any() and t.all()
    dist, r, t = (np.asarray(x) for x in read(0.002))
    np.testing.assert_allclose(dist, [0.002], atol=1e-5)
    assert not r.any() and not t.any()


def test_truth_gap_counts_a_sole_inside_the_floor_rising_out_of_it():
    """The sole 3 mm inside the floor: at rest the floor pushes it out (the raw force truth
    says contact); rising at 0.5 m/s the soft constraint is already separating, its force
    is zero (the C library's ``mj_contactForce`` on the same state, the reference), so the
    raw truth says air. Inside the floor is touching it: with a
    ``truth_gap`` the truth says contact in both, as Playground's ``found`` sensors do."""
    m, mx, (gap, raw, tol) = _gap_readers()

    @jax.jit
    def read(v):
        d = mjx.make_data(m)
        d = d.replace(qpos=d.qpos.at[0].set(-0.003), qvel=d.qvel.at[0].set(v))
        d = mjx.forward(mx, d)
        return gap(d), raw(d), tol(d)

    dist, r, t = (np.asarray(x) for x in read(0.0))
    np.testing.assert_allclose(dist, [-0.003], atol=1e-5)
    assert r.all() and t.all()
    d_c = mujoco.MjData(m)
    d_c.qpos[0], d_c.qvel[0] = -0.003, 0.5
    mujoco.mj_forward(m, d_c)
    f6 = np.zeros(6)
    mujoco.mj_contactForce(m, d_c, 0, f6)
    assert d_c.ncon > 0 and f6[0] == 0.0  # the reference: separating, no force
    dist, r, t = (np.asarray(x) for x in read(0.5))
    np.testing.assert_allclose(dist, [-0.003], atol=1e-5)
    assert not r.any() and t.all()


def _sole_points(m, knee: float):
    """(centre, rolling) contact points (3,) with the shank pitched by ``knee`` rad, and
    the C library's data (kinematics done) for the reference."""
    desc, _ = feet.describe(m)
    d = mujoco.MjData(m)
    d.qpos[:] = (0.6, 0.0, knee)
    mujoco.mj_kinematics(m, d)
    dx = mjx.put_data(m, d)
    pts = [np.asarray(adapter.contact_points(desc, dx, s))[0] for s in ("centre", "rolling")]
    return (*pts, desc, d)


def test_rolling_sole_point():
    m = _model()
    b = m.body("shank").id
    # Sole corners in the shank frame: x 0.01 +- 0.08, y +- 0.03, z -0.26 (box at
    # (0.01, 0, -0.25), half sizes .08 .03 .01).
    corners = np.array([(0.01 + sx * 0.08, sy * 0.03, -0.26) for sx in (1, -1) for sy in (1, -1)])
    centre, rolling, desc, d = _sole_points(m, 0.0)
    assert len(desc.foot_soles[0]) == 4
    np.testing.assert_allclose(sorted(desc.foot_soles[0]), sorted(map(tuple, corners)), atol=1e-12)
    # Flat: the four corners are equally low, the rolling point is the sole's centre.
    np.testing.assert_allclose(rolling, centre, atol=1e-6)
    # Pitched 0.2 rad about y (knee > 0 turns x towards -z): the toe corners (x = 0.09)
    # are 0.16 sin(0.2) = 31.8 mm below the heel's, so the heel weighs e^-15.9: the
    # point is the middle of the toe edge, (0.09, 0, -0.26) in the shank frame.
    _, rolling, _, d = _sole_points(m, 0.2)
    toe_mid = d.xpos[b] + d.xmat[b].reshape(3, 3) @ np.array([0.09, 0.0, -0.26])
    np.testing.assert_allclose(rolling, toe_mid, atol=1e-5)
    # Pitched 0.005 rad: toe 0.8 mm lower, a soft mix. Float64 reference: weights
    # exp(-(z - z_min) / SOLE_SOFTNESS) over the C library's world corners.
    centre, rolling, _, d = _sole_points(m, 0.005)
    world = d.xpos[b] + corners @ d.xmat[b].reshape(3, 3).T
    w = np.exp(-(world[:, 2] - world[:, 2].min()) / adapter.SOLE_SOFTNESS)
    np.testing.assert_allclose(rolling, (w / w.sum()) @ world, atol=2e-6)
    # By hand: toe weight 1, heel e^-(0.16 sin 0.005 / 0.002) = e^-0.4 = 0.670, so the
    # point is (0.09 - 0.670 x 0.07) / 1.670 = 0.0258 along the sole, 15.8 mm ahead of
    # the centre.
    assert np.linalg.norm(rolling - centre) == pytest.approx(0.0158, abs=2e-4)
    with pytest.raises(ValueError, match="sole must be one of"):
        adapter.contact_points(desc, mjx.put_data(m, d), "lowest")
    with pytest.raises(ValueError, match="config.sole"):
        validate_config(W.ContactObsConfig(sole="lowest"))


def test_round_feet_roll_nowhere():
    m = _model(foot='<geom name="ball" type="sphere" pos="0.01 0 -0.25" size=".02"/>')
    centre, rolling, desc, _ = _sole_points(m, 0.2)
    assert desc.foot_soles == ((),)
    np.testing.assert_array_equal(rolling, centre)


def test_corner_spheres_roll_to_the_lowest():
    """A foot of spheres of one radius (T1's corner spheres) rolls between their centres, a
    capsule between its segment's ends; spheres of two radii keep the fixed mean point."""
    two = (
        '<geom name="c1" type="sphere" pos="0.05 0 -0.25" size=".015"/>'
        '<geom name="c2" type="sphere" pos="-0.05 0 -0.25" size=".015"/>'
    )
    m = _model(two)
    b = m.body("shank").id
    centre, rolling, desc, _ = _sole_points(m, 0.0)
    assert sorted(desc.foot_soles[0]) == [(-0.05, 0.0, -0.25), (0.05, 0.0, -0.25)]
    assert desc.foot_radii == (0.015,)
    # Level: both centres equally low, the point is their mean (the fixed point).
    np.testing.assert_allclose(rolling, centre, atol=1e-6)
    # Pitched 0.2 rad (knee > 0 turns +x towards -z): c1 is 0.1 sin(0.2) = 19.9 mm
    # below c2, which weighs e^-9.9: the point is c1's centre, the radius kept.
    _, rolling, _, d = _sole_points(m, 0.2)
    c1 = d.xpos[b] + d.xmat[b].reshape(3, 3) @ np.array([0.05, 0.0, -0.25])
    np.testing.assert_allclose(rolling, c1, atol=1e-5)
    # Two radii: the lowest centre is not the lowest sphere, so no rolling point.
    mixed = two.replace('size=".015"/><geom name="c2"', 'size=".02"/><geom name="c2"')
    centre, rolling, desc, _ = _sole_points(_model(mixed), 0.2)
    assert desc.foot_soles == ((),) and desc.foot_radii == (0.0175,)
    np.testing.assert_array_equal(rolling, centre)
    # A capsule along x (fromto -0.05 .. 0.05): its segment's ends roll as the two
    # spheres' centres did, so the same points, level and pitched.
    cap = '<geom name="cap" type="capsule" fromto="-0.05 0 -0.25 0.05 0 -0.25" size=".015"/>'
    centre, rolling, desc, d = _sole_points(_model(cap), 0.2)
    assert sorted(desc.foot_soles[0]) == [(-0.05, 0.0, -0.25), (0.05, 0.0, -0.25)]
    assert desc.foot_radii == (0.015,)
    c1 = d.xpos[b] + d.xmat[b].reshape(3, 3) @ np.array([0.05, 0.0, -0.25])
    np.testing.assert_allclose(rolling, c1, atol=1e-5)
    centre, rolling, _, _ = _sole_points(_model(cap), 0.0)
    np.testing.assert_allclose(rolling, centre, atol=1e-6)  # level: the capsule's centre


def test_robot_measurement_places_site_feet_and_rolling_soles():
    """adapter.robot_measurement reads each foot's fixed point (its body's pose applied to
    foot_offsets) and radius. A site foot on a body that carries a geom is at the site, not
    at the geom's centre: against MuJoCo C in float64 (site_xpos, mj_jac at the site). A
    box sole's point depends on how the sole tilts: by default the rolling point (the log
    commands' and the wrapper's), with sole="centre" the fixed centre; both against the
    C library's frames and mj_jac at that point."""
    from jax_contact import adapter

    m = _model()
    desc_toe, _ = feet.describe(m, ["toe"])
    d = mujoco.MjData(m)
    d.qpos[:] = (0.55, 0.4, -0.7)  # rail, hip, knee: a bent leg, so the frames turn
    d.qvel[:] = (0.1, -1.0, 2.0)
    mujoco.mj_forward(m, d)
    site = m.site("toe").id
    jacp = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jacp, None, site)
    dx = adapter.prepare(mjx.put_model(m), mjx.put_data(m, d))
    meas = adapter.robot_measurement(mjx.put_model(m), dx, desc_toe)
    np.testing.assert_allclose(meas.p_f[0], d.site_xpos[site], atol=2e-6)
    np.testing.assert_allclose(meas.J[0], jacp, atol=2e-6)
    np.testing.assert_allclose(meas.v_f[0], jacp @ d.qvel, atol=2e-5)
    assert float(meas.foot_radius[0]) == 0.0
    # The box centre, where a geom-centre reading put it, is sqrt(0.07^2 + 0.01^2) = 7.1 cm away.
    assert np.linalg.norm(d.geom_xpos[m.geom("sole").id] - d.site_xpos[site]) > 0.07

    desc, _ = feet.describe(m)
    b = m.body("shank").id
    # Knee 0.2 rad: the shank pitches toes down (test_rolling_sole_point), so the rolling
    # point is the middle of the toe edge, (0.09, 0, -0.26) in the shank frame; the
    # centre is the sole's, (0.01, 0, -0.26).
    d.qpos[:] = (0.55, 0.0, 0.2)
    mujoco.mj_forward(m, d)
    dx = adapter.prepare(mjx.put_model(m), mjx.put_data(m, d))
    R = d.xmat[b].reshape(3, 3)
    for sole, local in (("rolling", (0.09, 0.0, -0.26)), ("centre", (0.01, 0.0, -0.26))):
        point = d.xpos[b] + R @ np.array(local)
        jacp = np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, jacp, None, point, b)
        meas = adapter.robot_measurement(mjx.put_model(m), dx, desc, sole=sole)
        np.testing.assert_allclose(meas.p_f[0], point, atol=1e-5)
        np.testing.assert_allclose(meas.J[0], jacp, atol=1e-5)
        np.testing.assert_allclose(meas.v_f[0], jacp @ d.qvel, atol=2e-5)
    with pytest.raises(
        ValueError, match=r"sole must be one of \('rolling', 'centre'\), got 'lowest'"
    ):
        adapter.robot_measurement(mjx.put_model(m), dx, desc, sole="lowest")


def test_a_model_that_is_no_legged_robot_is_told_so():
    """A cart-pole's pole reaches the floor, so the rule finds it as a foot; the error says
    the feet were found by rule, which ones, and how to name them (it used to name only a
    "foot 'pole_1'" the user never called one)."""
    xml = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/>
    <body name="cart" pos="0 0 .5"><joint name="slide" type="slide" axis="1 0 0"/>
      <geom type="box" size=".1 .1 .1"/>
      <body name="pole"><joint name="hinge" type="hinge" axis="0 1 0"/>
        <geom name="pole_1" type="capsule" fromto="0 0 0 0 0 -.45" size=".02"/></body></body>
    </worldbody><actuator><motor joint="slide"/></actuator></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ValueError, match=r"feet found by rule: \['pole_1'\]; is this a legged"):
        feet.describe(m)


def test_sign_test_only_where_the_torques_can_read_a_foots_load():
    """The ant-like leg above: its force rows (y, z) span J_r = [[0.3, 0], [0, -0.1]]
    (hip, knee columns), square, so eq. 6's push along z is e^T J_r^-T r, g = (0, -10):
    std 10 sigma_d(knee). Its 0.6 kg put 6 N on the one foot, below that ~21 N, so the
    wrapper turns the sign test off and says so; a 10 kg torso (98 N) keeps it, as Go1
    (31 N per foot against 14 N) does. A ``unilateral`` given is kept."""
    from jax_contact.envs import contact_params as CP

    def params_of(xml):
        m = mujoco.MjModel.from_xml_string(xml)
        desc, _ = feet.describe(m)
        robot = Robot(name="ant", mj_model=m, description=desc, spec=mujoco.MjSpec.from_string(xml))
        sp = CP.default_sensor_params("anymal_like", robot, 0.0025)
        return robot, CP.default_estimator_params(robot, 0.0025, sp), sp

    robot, params, sp = params_of(ANT)
    knee = robot.description.leg_dofs[0][1]
    noise = CP.push_noise(robot.mj_model, robot.description, params)
    np.testing.assert_allclose(noise, [10.0 * float(params.noise.sigma_d[knee])], rtol=1e-6)
    assert robot.description.mass_kg * 9.81 < noise[0]
    assert params.unilateral is False
    env = W.LeggedPipelineEnv(robot)
    assert W.wrap_contact(env).contact_report()["sign_test"] is False
    kept = CP.default_estimator_params(robot, 0.0025, sp, unilateral=True)
    assert kept.unilateral is True

    torso = '<geom type="sphere" size=".05"'
    robot, params, _ = params_of(ANT.replace(torso, torso + ' mass="10"'))
    noise = CP.push_noise(robot.mj_model, robot.description, params)
    assert robot.description.mass_kg * 9.81 > noise[0]
    assert params.unilateral is True

    go1 = load_robot("go1")
    sp = CP.default_sensor_params("anymal_like", go1, 0.0025)
    assert CP.default_estimator_params(go1, 0.0025, sp).unilateral is True


def test_a_soles_moment_can_turn_the_sign_test_off(tmp_path):
    """The ant-like leg above with a 10 kg torso and a box sole of half-size (a, 0.02) in
    place of the sphere. At home the shank's rotational Jacobian over (hip about z, knee
    about y) is J_r = [[0, 0], [0, 1], [1, 0]] (rows x, y, z), and the sole's centre keeps
    the sphere's point Jacobian rows (y, z) = [[0.3, 0], [0, -0.1]], so g = (0, -10) as
    above and g J_r^T = (0, -10, 0): a moment about y moves the estimated push by 10 N per
    N m. The sole's corners lie h = sqrt(a^2 + 0.02^2) from its centre, so
    ``moment_push`` = 10 h. a = 0.05: 0.539, under the ~21 N noise the load (~104 N) still
    clears sqrt(21^2 + (0.539 * 104)^2) = 60 N, and the test runs; a = 0.12: 1.217 > 1,
    no load can clear it, the test is off. A sphere foot has no sole: 0."""
    from jax_contact.envs import contact_params as CP
    from jax_contact.train.log_estimator import default_estimator

    torso = '<geom type="sphere" size=".05"'
    heavy = ANT.replace(torso, torso + ' mass="10"')
    sphere = '<geom name="foot" type="sphere" pos=".1 0 -.2" size=".02"/>'
    assert heavy.count(sphere) == 1
    for a, expect_push, expect_on in (
        (None, 0.0, True),
        (0.05, 0.5385, True),
        (0.12, 1.2166, False),
    ):
        xml = (
            heavy
            if a is None
            else heavy.replace(
                sphere, f'<geom name="foot" type="box" pos=".1 0 -.2" size="{a} .02 .005"/>'
            )
        )
        m = mujoco.MjModel.from_xml_string(xml)
        desc, resolved = feet.describe(m)
        robot = Robot(name="ant", mj_model=m, description=desc, spec=mujoco.MjSpec.from_string(xml))
        sp = CP.default_sensor_params("anymal_like", robot, 0.0025)
        params = CP.default_estimator_params(robot, 0.0025, sp)
        push = CP.moment_push(m, desc, params)
        np.testing.assert_allclose(push, [expect_push], rtol=2e-4, atol=1e-9)
        assert params.unilateral is expect_on, a
        # The log commands' robot (load_robot: the model's feet as the wrapper resolves
        # them) weighs the same sole: what `jax-contact estimate` and `export` run.
        (tmp_path / "ant.xml").write_text(xml)
        logged = load_robot(str(tmp_path / "ant.xml"))
        assert logged.description.soles == desc.soles  # a sphere: ((),)
        assert default_estimator(logged.description, 0.0025, mj_model=m)[0].unilateral is expect_on
        report = W.wrap_contact(W.LeggedPipelineEnv(robot)).contact_report()
        assert report["sign_test"] is expect_on
        # Why, reported: the load over the push's error, on at 1 or more (here the sign test
        # is the defaults', so the two agree).
        assert (report["sign_test_margin"] >= 1.0) is expect_on
