"""The per-robot measurement layout (``RobotMeasurement``) against the per-foot one.

Both layouts hold the same numbers; ``step_batch`` must give the same beliefs and
diagnostics from either (the per-foot path is the one the oracle tests check against the
float64 NumPy reference), keep a NaN where it was, and ``run`` must scan either. The
robot is synthetic and well conditioned (nv = 9: a 3-dof base and two 3-dof legs), so the
two compiled programs, which round differently, agree to float32 precision.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jax_contact as jc

NV, LEGS = 9, ((3, 4, 5), (8, 6, 7))  # the second leg's dofs deliberately not ascending
N_ENVS, N_LEGS = 3, len(LEGS)
MODES = ("quadrature", "monte_carlo")
PARAMS = {mode: jc.make_params(jc.make_noise(NV), touchdown=mode) for mode in MODES}
TERRAIN = jc.flat(0.0, 0.05)


def _robot(rng, lead=(N_ENVS,)) -> jc.RobotMeasurement:
    """Random well-conditioned robot measurements with leading axes ``lead``."""
    a = rng.normal(size=lead + (NV, NV)) * 0.3
    J = rng.normal(size=lead + (N_LEGS, 3, NV)) * 0.3
    qd = rng.normal(size=lead + (NV,))
    height = rng.uniform(0.0, 0.1, size=lead + (N_LEGS, 1))
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return jc.RobotMeasurement(
        q=f32(rng.normal(size=lead + (NV + 1,))),
        qd=f32(qd),
        qdd=f32(rng.normal(size=lead + (NV,)) * 5.0),
        tau=f32(rng.normal(size=lead + (NV,)) * 5.0),
        M=f32(a @ np.swapaxes(a, -1, -2) + NV * 0.1 * np.eye(NV)),
        h=f32(rng.normal(size=lead + (NV,)) * 5.0),
        J=f32(J),
        Jdot_qd=f32(rng.normal(size=lead + (N_LEGS, 3))),
        p_f=f32(np.concatenate([rng.normal(size=lead + (N_LEGS, 2)), height], axis=-1)),
        v_f=f32(np.einsum("...lij,...j->...li", J, qd)),
        foot_radius=f32(np.full(lead + (N_LEGS,), 0.02)),
        leg_dofs=LEGS,
    )


def _close(got, want, what):
    """Leaf by leaf: float32 rounding of two differently compiled programs."""
    for name, g, w in zip(
        type(want).__dataclass_fields__, jax.tree.leaves(got), jax.tree.leaves(want), strict=True
    ):
        g, w = np.asarray(g), np.asarray(w)
        if g.dtype == bool:
            np.testing.assert_array_equal(g, w, err_msg=f"{what}: {name}")
        else:
            scale = np.nanmax(np.abs(w)) if np.isfinite(w).any() else 1.0
            np.testing.assert_allclose(
                g, w, rtol=1e-4, atol=1e-5 * max(scale, 1.0), err_msg=f"{what}: {name}"
            )


def test_legs_is_the_per_foot_layout(np_rng):
    """``legs()`` tiles the shared fields and fills in each leg's complement, ascending."""
    robot = _robot(np_rng)
    legs = robot.legs()
    jc.validate_robot_measurement(robot, NV)
    assert jc.validate_measurement(legs, NV) == (N_ENVS, N_LEGS)
    for i, leg in enumerate(LEGS):
        other = [j for j in range(NV) if j not in leg]
        np.testing.assert_array_equal(legs.leg_dofs[:, i], np.broadcast_to(leg, (N_ENVS, 3)))
        np.testing.assert_array_equal(legs.other_dofs[:, i], np.broadcast_to(other, (N_ENVS, 6)))
        np.testing.assert_array_equal(legs.M[:, i], robot.M)
        np.testing.assert_array_equal(legs.J[:, i], robot.J[:, i])
        one = jax.tree.map(lambda x, i=i: x[0], robot).leg(i)
        np.testing.assert_array_equal(one.other_dofs, other)
        np.testing.assert_array_equal(one.qdd, robot.qdd[0])


def test_robot_leg_blocks_are_each_legs_blocks(np_rng):
    """The per-robot split (constant indices as slices of ascending runs; the second leg's
    (8, 6, 7) is two runs) equals the per-foot split (gathers with index arrays), exactly:
    both only copy entries. Checked against NumPy indexing of the robot's arrays."""
    params = PARAMS["quadrature"]
    one = jax.tree.map(lambda x: x[0], _robot(np_rng))
    got = jax.jit(lambda m: jc.robot_leg_blocks(params, m))(one)
    M, J = np.asarray(one.M), np.asarray(one.J)
    for i, leg in enumerate(LEGS):
        per_foot = jc.leg_blocks(params, one.leg(i))
        other = [j for j in range(NV) if j not in leg]
        want = {
            "M_l": M[np.ix_(leg, leg)],
            "M_lb": M[np.ix_(leg, other)],
            "qdd_l": np.asarray(one.qdd)[list(leg)],
            "qd_b": np.asarray(one.qd)[other],
            "J_l": J[i][:, list(leg)],
            "J_b": J[i][:, other],
            "sigma_qdd_b": np.asarray(params.noise.sigma_qdd)[other],
        }
        for name, value in want.items():
            np.testing.assert_array_equal(getattr(got, name)[i], value, err_msg=name)
        for name, g, w in zip(
            jc.LegBlocks.__dataclass_fields__,
            jax.tree.leaves(jax.tree.map(lambda x, i=i: x[i], got)),
            jax.tree.leaves(per_foot),
            strict=True,
        ):
            np.testing.assert_array_equal(g, w, err_msg=f"leg {i}: {name}")


@pytest.mark.parametrize("mode", MODES)
def test_step_batch_same_from_either_layout(mode, np_rng, jit_step_batch):
    """Same beliefs, transitions and diagnostics from one robot measurement or per-foot
    copies, Monte-Carlo included (each foot draws from the same key in both)."""
    robot = _robot(np_rng)
    params = PARAMS[mode]
    belief = jc.init_belief_batch(params, N_ENVS, N_LEGS)
    key = jax.random.key(5)
    got = jit_step_batch(params, TERRAIN, belief, robot, key=key)
    want = jit_step_batch(params, TERRAIN, belief, robot.legs(), key=key)
    _close(got[0], want[0], f"{mode} belief")
    _close(got[1], want[1], f"{mode} diagnostics")
    # Not a vacuous comparison: the feet disagree and the terms are not all at their caps.
    p = np.asarray(want[1].p_contact)
    # The random feet give beliefs orders of magnitude apart, so equality is not vacuous
    # (with the kinematics term neutral on the ground they all lean to air here).
    assert p.max() / p.min() > 10.0
    # step_robot on one robot = step of each foot on its leg(i), keys split from its key.
    one, b1 = jax.tree.map(lambda x: x[1], (robot, belief))
    k1 = jax.random.key(8)
    got1 = jax.jit(lambda b, m, k: jc.step_robot(params, TERRAIN, b, m, key=k))(b1, one, k1)
    want1 = jax.jit(jax.vmap(lambda b, m, k: jc.step(params, TERRAIN, b, m, key=k)))(
        b1, one.legs(), jax.random.split(k1, N_LEGS)
    )
    _close(got1[1], want1[1], f"{mode} step_robot")


def test_nan_stays_where_it_was(np_rng, jit_step_batch):
    """A NaN invalidates the feet whose terms read it: one in a foot's Jacobian that foot;
    one in leg 0's own block of the mass matrix leg 0 (leg 1's rows do not hold it); one in
    a base coordinate's acceleration, which every leg's rows involve, every foot of that
    robot (as per-foot copies of it would). The rest is untouched."""
    params = PARAMS["quadrature"]
    robot = _robot(np_rng)
    belief = jc.init_belief_batch(params, N_ENVS, N_LEGS)
    key = jax.random.key(0)
    clean = jit_step_batch(params, TERRAIN, belief, robot, key=key)
    assert LEGS[0] == (3, 4, 5)  # so M[3, 3] is leg 0's, and coordinate 0 the base's
    bad = robot.replace(
        J=robot.J.at[0, 1, 2, 4].set(jnp.nan),
        M=robot.M.at[2, 3, 3].set(jnp.nan),
        qdd=robot.qdd.at[1, 0].set(jnp.nan),
    )
    b, d = jit_step_batch(params, TERRAIN, belief, bad, key=key)
    valid = np.asarray(d.valid)
    np.testing.assert_array_equal(valid, [[True, False], [False, False], [False, True]])
    assert np.isfinite(np.asarray(b.logit)).all()
    assert np.isfinite(np.asarray(b.log_transition)).all()
    for got, want in ((d.p_contact, clean[1].p_contact), (b.logit, clean[0].logit)):
        np.testing.assert_array_equal(np.asarray(got)[valid], np.asarray(want)[valid])


def test_run_scans_either_layout(np_rng, jit_run):
    """``run`` over a (T, n_envs) sequence of robot measurements = over its per-foot copies."""
    params = PARAMS["quadrature"]
    seq = _robot(np_rng, lead=(4, N_ENVS))
    belief = jc.init_belief_batch(params, N_ENVS, N_LEGS)
    got = jit_run(params, TERRAIN, belief, seq, key=jax.random.key(1))
    want = jit_run(params, TERRAIN, belief, seq.legs(), key=jax.random.key(1))
    assert want[1].p_contact.shape == (4, N_ENVS, N_LEGS)
    _close(got[1], want[1], "run diagnostics")


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(J=jnp.zeros((N_ENVS, N_LEGS, 3, NV - 1))), "'J'"),
        (dict(M=jnp.zeros((N_ENVS, NV, NV + 1))), "'M'"),
        (dict(foot_radius=jnp.zeros((N_ENVS, N_LEGS + 1))), "'foot_radius'"),
        (dict(q=jnp.zeros((N_ENVS + 1, NV + 1))), "'q'"),
        (dict(leg_dofs=((3, 4, 5), (6, 7))), "leg_dofs"),
        (dict(leg_dofs=((3, 4, 5), (6, 7, 9))), r"leg_dofs\[1\]"),
        (dict(leg_dofs=((3, 3, 5), (6, 7, 8))), r"leg_dofs\[0\]"),
    ],
)
def test_validate_robot_measurement_names_the_problem(change, match, np_rng):
    robot = _robot(np_rng).replace(**change)
    with pytest.raises(ValueError, match=match):
        jc.validate_robot_measurement(robot, NV)


# The structural switches flipped, as the reproduction's ablation flips them one at a time;
# two variants flip all four between them (each compiled variant costs ~10 s here).
SWITCHED = {
    "default": {},
    "dynamics_only_two_sided": dict(terms=("dynamics",), kinematics_neutral_below=False),
    "kinematic_terms_prior_any_foothold": dict(
        terms=("diff_kinematics", "kinematics"), transition_model=False, foothold_still=False
    ),
}


def test_switches_as_data_equal_the_static_fields():
    """The variants above run as one program, vmapped over their stacked parameters (all
    of ``without_switches``'s structure) with the switches as traced data, as
    ``train/evaluate.replay`` runs them; each equals its own program with the static
    fields (the one the float64 oracle checks): beliefs (the foothold written included)
    and diagnostics, from the per-foot and the per-robot layout."""
    from jax_contact.params import switches_of, without_switches

    # This draw has a foot that stays above the foothold's confidence while the
    # differential-kinematics term says it moves (env 0, leg 1), so the foothold switch
    # changes what is written; one sole below the plane, where the one-sided kinematics
    # term is neutral and the two-sided one is not.
    robot = _robot(np.random.default_rng(0))
    robot = robot.replace(p_f=robot.p_f.at[0, 0, 2].set(-0.05))
    # Two quadrature nodes: the switches do not touch the rule, and the programs compile faster.
    base = PARAMS["quadrature"].replace(n_quad=2)
    variants = {n: base.replace(**kw) for n, kw in SWITCHED.items()}
    # Confident contact to start with, so that the foothold switch decides what is written.
    belief = jc.init_belief_batch(variants["default"], N_ENVS, N_LEGS)
    belief = belief.replace(logit=jnp.full((N_ENVS, N_LEGS), 6.0))
    key = jax.random.key(3)

    def one_step(params, meas, switches=None):
        return jc.step_batch(params, TERRAIN, belief, meas, key=key, switches=switches)

    names = list(variants)
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *(without_switches(variants[n]) for n in names))
    switches = jax.tree.map(lambda *x: jnp.stack(x), *(switches_of(variants[n]) for n in names))
    assert jax.tree.structure(stacked) == jax.tree.structure(without_switches(variants["default"]))
    as_data = jax.jit(jax.vmap(one_step, in_axes=(0, None, 0)))
    got = {
        "legs": as_data(stacked, robot.legs(), switches),
        "robot": as_data(stacked, robot, switches),
    }
    for i, name in enumerate(names):
        want = jax.jit(one_step)(variants[name], robot.legs())
        for layout, out in got.items():
            mine = jax.tree.map(lambda x, i=i: x[i], out)
            _close(mine[0], want[0], f"{name} belief ({layout})")
            _close(mine[1], want[1], f"{name} diagnostics ({layout})")
    # Each switch changes something here, so the comparison is not vacuous: the terms and
    # the transitions the belief, the two-sided kinematics term the sole below the plane,
    # the foothold switch what is written.
    belief_out, diag = got["legs"]
    logit = np.asarray(belief_out.logit)
    assert not np.allclose(logit[1], logit[0]) and not np.allclose(logit[2], logit[0])
    p_kin = np.asarray(diag.p_kinematics)
    assert p_kin[1, 0, 0] > 0.6 and abs(p_kin[0, 0, 0] - 0.5) < 1e-6, p_kin[:, 0, 0]
    foothold = np.asarray(belief_out.foothold_valid)
    assert (foothold[2] != foothold[0]).any(), "the foothold switch wrote nothing else"
