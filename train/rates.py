"""Physics-rate against control-rate contact estimation, on the same rollouts.

:func:`envs.wrapper.compare_rates` wraps one Brax env twice (an estimator at every physics
step and one per env step) so one simulation feeds both. Here it runs on two scripted
scenes, 16 rollouts of 250 env steps (5 s at a 20 ms control period) each, ``anymal_like``
sensors, rollout ``e`` at ``1 + 0.02 e`` times the base frequency so that the contact
events do not line up across rollouts:

- ``planar_leg``: the paper's leg on its rail, joint position servos (300 N m/rad,
  8 N m s/rad), knee ``-1.2 + 0.7 sin(2 pi 2 f t)``, hip ``-knee / 2``: it hops; physics
  2.5 ms x 8 substeps.
- ``go1``: Go1 (its own position actuators) at the home pose, diagonal pairs lifting in
  turn (thigh +0.5 rad, calf -0.8 rad at the peak of a half-sine, 2.5 f Hz): stepping on
  the spot; physics 4 ms x 5 substeps, as Playground's Go1.

``jax-contact rates`` prints the table and writes JSON.
"""

from __future__ import annotations

import time

import jax
import numpy as np

SCENES = ("planar_leg", "go1")
N_STEPS, N_ROLLOUTS = 250, 16


def scene(name: str, n_steps: int = N_STEPS, n_rollouts: int = N_ROLLOUTS):
    """(env, actions (T, E, nu)) of a scene of the module docstring."""
    from envs import ground_truth
    from envs import wrapper as W
    from envs.robots import load_robot

    if name not in SCENES:
        raise ValueError(f"scene must be one of {SCENES}, got {name!r}")
    freq = 1.0 + 0.02 * np.arange(n_rollouts)
    robot = ground_truth.with_contact_sensors(load_robot(name))
    if name == "planar_leg":
        env = W.LeggedPipelineEnv(robot, n_frames=8, position_servo=(300.0, 8.0))
        t = np.arange(1, n_steps + 1)[:, None] * float(env.dt)
        knee = -1.2 + 0.7 * np.sin(2 * np.pi * 2.0 * freq * t)
        acts = np.stack([-0.5 * knee, knee], axis=-1)
    else:
        robot.mj_model.opt.timestep = 0.004
        env = W.LeggedPipelineEnv(robot, n_frames=5, min_base_height=0.1)
        t = np.arange(1, n_steps + 1)[:, None] * float(env.dt)
        acts = np.tile(robot.mj_model.key_ctrl[0], (n_steps, n_rollouts, 1))
        for leg, phase in enumerate([0.0, np.pi, np.pi, 0.0]):  # FR FL RR RL
            s = np.maximum(0.0, np.sin(2 * np.pi * 2.5 * freq * t + phase))
            acts[:, :, 3 * leg + 1] += 0.5 * s
            acts[:, :, 3 * leg + 2] -= 0.8 * s
    return env, acts.astype(np.float32)


def run(scenes=SCENES, *, seed: int = 0, pairing: str = "delayed", log=print) -> dict:
    """Runs :func:`envs.wrapper.compare_rates` on each scene; returns name -> metrics.

    ``pairing`` is :attr:`envs.wrapper.ContactObsConfig.pairing` of both estimators.
    """
    from envs import wrapper as W

    out = {}
    for name in scenes:
        env, acts = scene(name)
        t0 = time.perf_counter()
        res = W.compare_rates(env, acts, key=jax.random.PRNGKey(seed), skip_s=0.2, pairing=pairing)
        wall = time.perf_counter() - t0
        log(
            f"{name}: {acts.shape[0]} env steps x {acts.shape[1]} rollouts, anymal_like"
            f" sensors, {pairing} pairing, {res.dt_substep * 1e3:g} ms physics,"
            f" {res.dt_control * 1e3:g} ms control ({wall:.0f} s)\n{res.table()}"
        )
        out[name] = {
            "dt_substep": res.dt_substep,
            "dt_control": res.dt_control,
            "pairing": pairing,
            "substep": res.substep.as_dict(),
            "control": res.control.as_dict(),
            "substep_every_physics_step": res.substep_all.as_dict(),
            "wall_s": round(wall, 1),
        }
    return out
