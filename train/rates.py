"""Physics-rate against control-rate contact estimation, on the same rollouts.

:func:`compare_rates` wraps one env twice (an estimator at every physics step and one per
env step) so one simulation feeds both. Here it runs on four scripted scenes, 16 rollouts
of 250 env steps (5 s at a 20 ms control period) each, scored from 0.2 s on
(:data:`SKIP_S`), ``anymal_like`` sensors, rollout ``e`` at ``1 + 0.02 e`` times the base
frequency so that the contact events do not line up across rollouts:

- ``planar_leg``: the paper's leg on its rail, joint position servos (300 N m/rad,
  8 N m s/rad), knee ``-1.2 + 0.7 sin(2 pi 2 f t)``, hip ``-knee / 2``: it hops; physics
  2.5 ms x 8 substeps.
- ``go1``: Go1 (its own position actuators) at the home pose, diagonal pairs lifting in
  turn (thigh +0.5 rad, calf -0.8 rad at the peak of a half-sine, 2.5 f Hz): stepping on
  the spot; physics 4 ms x 5 substeps, as Playground's Go1. The half-sine's knee is
  fastest at touch-down: feet hit at 2-3 m/s, sink up to 2 cm into the soft contact and
  bounce out of it, and slide in stance (half the contact steps faster than 0.2 m/s): a
  stress test of the no-slip contact, unlike a gait (docs/training.md).
- ``go1_walk``, ``go1_trot``: the same Go1 and physics under the gaits in place of
  :mod:`jax_contact.envs.scripted` (``sin^2`` swings, feet put down at rest), rollout
  ``e`` at ``1 + 0.02 e`` times the gait's frequency.

``jax-contact rates`` prints the table and writes JSON.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jax_contact import metrics
from jax_contact.envs import feet, scripted
from jax_contact.envs.contact_config import ContactObsConfig
from jax_contact.envs.contact_core import model_of
from jax_contact.envs.contact_params import default_estimator_params, default_sensor_params
from jax_contact.envs.contact_wrappers import wrap_contact
from jax_contact.envs.robots import Robot

SCENES = ("planar_leg", "go1", "go1_walk", "go1_trot")
N_STEPS, N_ROLLOUTS = 250, 16
SKIP_S = 0.2  # s at the start of every rollout left out of the scores (settling)


def robot_of(name: str) -> str:
    """The robot a scene runs (``planar_leg`` or ``go1``)."""
    return "planar_leg" if name == "planar_leg" else "go1"


def scene(name: str, n_steps: int = N_STEPS, n_rollouts: int = N_ROLLOUTS):
    """(env, actions (T, E, nu)) of a scene of the module docstring."""
    from jax_contact.envs import ground_truth
    from jax_contact.envs.legged_env import LeggedPipelineEnv
    from jax_contact.envs.robots import load_robot

    if name not in SCENES:
        raise ValueError(f"scene must be one of {SCENES}, got {name!r}")
    freq = 1.0 + 0.02 * np.arange(n_rollouts)
    robot = ground_truth.with_contact_sensors(load_robot(robot_of(name)))
    if name == "planar_leg":
        env = LeggedPipelineEnv(robot, n_frames=8, position_servo=(300.0, 8.0))
        t = np.arange(1, n_steps + 1)[:, None] * float(env.dt)
        knee = -1.2 + 0.7 * np.sin(2 * np.pi * 2.0 * freq * t)
        acts = np.stack([-0.5 * knee, knee], axis=-1)
    else:
        robot.mj_model.opt.timestep = 0.004
        env = LeggedPipelineEnv(robot, n_frames=5, min_base_height=0.1)
        t = np.arange(1, n_steps + 1)[:, None] * float(env.dt)
        acts = np.tile(robot.mj_model.key_ctrl[0], (n_steps, n_rollouts, 1))
        if name != "go1":
            policy = name.removeprefix("go1_")
            acts += scripted.in_place_offsets(policy, "Go1", t, freq, np.zeros(n_rollouts))
            return env, acts.astype(np.float32)
        for leg, phase in enumerate([0.0, np.pi, np.pi, 0.0]):  # FR FL RR RL
            s = np.maximum(0.0, np.sin(2 * np.pi * 2.5 * freq * t + phase))
            acts[:, :, 3 * leg + 1] += 0.5 * s
            acts[:, :, 3 * leg + 2] -= 0.8 * s
    return env, acts.astype(np.float32)


def check_params(scenes, params) -> None:
    """Raises ValueError, before any scene runs, if the parameter file or preset ``params``
    does not fit a scene's robot (its ``nv``)."""
    if params is None:
        return
    from jax_contact.envs.robots import load_robot
    from jax_contact.params_file import load_params, preset_names

    nv = load_params(params).nv
    for name in scenes:
        robot = robot_of(name)
        have = load_robot(robot).description.nv
        if have != nv:
            what = "preset" if str(params) in preset_names() else "parameter file"
            raise ValueError(
                f"argument --params: {what} {str(params)!r} is for nv = {nv}; scene {name!r}"
                f" ({robot}) has nv = {have}: --params applies to every scene, so pass"
                " --scenes of one robot"
            )


def run(scenes=SCENES, *, seed: int = 0, pairing: str = "delayed", params=None, log=print) -> dict:
    """Runs :func:`compare_rates` on each scene; returns name -> metrics.

    ``pairing`` is ``ContactObsConfig.pairing`` of both estimators; ``params`` the
    physics-rate estimator's file or preset (``compare_rates``' ``substep_params``), None
    the defaults.
    """
    out = {}
    for name in scenes:
        env, acts = scene(name)
        t0 = time.perf_counter()
        res = compare_rates(
            env,
            acts,
            key=jax.random.PRNGKey(seed),
            skip_s=SKIP_S,
            pairing=pairing,
            substep_params=params,
        )
        wall = time.perf_counter() - t0
        log(
            f"{name}: {acts.shape[0]} env steps x {acts.shape[1]} rollouts (scored from"
            f" {SKIP_S:g} s on), anymal_like"
            f" sensors, {pairing} pairing, {res.dt_substep * 1e3:g} ms physics,"
            f" {res.dt_control * 1e3:g} ms control ({wall:.0f} s)\n{res.table()}"
        )
        out[name] = {
            "dt_substep": res.dt_substep,
            "dt_control": res.dt_control,
            "pairing": pairing,
            "params": "defaults" if params is None else str(params),
            "substep": res.substep.as_dict(),
            "control": res.control.as_dict(),
            "substep_every_physics_step": res.substep_all.as_dict(),
            # Every row and line the table prints, so the JSON is the table.
            "substep_every_physics_step_raw_truth": (
                None if res.substep_all_raw is None else res.substep_all_raw.as_dict()
            ),
            "always_contact_accuracy": float(res.contact_fraction),
            "always_air_accuracy": float(1.0 - res.contact_fraction),
            "ended_rollouts": int(res.ended_rollouts),
            "nonfinite_rollouts": int(res.nonfinite_rollouts),
            "wall_s_with_compile": round(wall, 1),
        }
    return out


@dataclasses.dataclass(frozen=True)
class RateComparison:
    """Accuracy of the control-rate mode against the substep mode on one set of rollouts.

    Attributes:
      substep: the substep-rate estimate, scored at the end of every env step.
      control: the control-rate estimate, scored at the same instants.
      substep_all: the substep-rate estimate, scored at every physics step.
      dt_substep, dt_control: the two estimator periods, s.
      contact_fraction: fraction of the scored foot-updates (every physics step) in
        contact: the accuracy of always-contact (and ``1 -`` it of always-air).
      substep_all_raw: ``substep_all`` against the truth source without the wrapper's
        ``truth_gap`` tolerance (None when there is none).
      contact_fraction_raw: ``contact_fraction`` of that raw truth.
      nonfinite_rollouts: rollouts whose estimate went NaN/inf before their first
        ``done``; each is scored up to that step.
      ended_rollouts: rollouts that reached a ``done`` (or ``stop``) before their last
        step; each is scored up to that step.
    """

    substep: metrics.ContactMetrics
    control: metrics.ContactMetrics
    substep_all: metrics.ContactMetrics
    dt_substep: float
    dt_control: float
    contact_fraction: float = float("nan")
    substep_all_raw: metrics.ContactMetrics | None = None
    contact_fraction_raw: float = float("nan")
    nonfinite_rollouts: int = 0
    ended_rollouts: int = 0

    def table(self) -> str:
        rows = [
            (f"substep ({self.dt_substep * 1e3:g} ms), at env steps", self.substep),
            (f"control ({self.dt_control * 1e3:g} ms), at env steps", self.control),
            (f"substep ({self.dt_substep * 1e3:g} ms), every substep", self.substep_all),
        ]
        if self.substep_all_raw is not None:
            rows.append(("  same, against the raw truth (no truth_gap)", self.substep_all_raw))
        lines = [
            f"{'estimator':42s} {'acc':>6s} {'F1':>6s} {'prec':>6s} {'rec':>6s}"
            f" {'TD delay ms':>14s} {'fails':>5s} {'steps':>7s}"
        ]
        for name, m in rows:
            td = f"{m.touchdown_delay_ms[0]:.1f}+-{m.touchdown_delay_ms[1]:.1f}"
            lines.append(
                f"{name:42s} {m.accuracy:6.3f} {m.f1:6.3f} {m.precision:6.3f} {m.recall:6.3f}"
                f" {td:>14s} {m.failures:5d} {m.n_steps:7d}"
            )
        lines.append(
            f"always contact: accuracy {self.contact_fraction:.3f}; always air:"
            f" {1 - self.contact_fraction:.3f} (every physics step)"
        )
        if self.ended_rollouts:
            lines.append(f"{self.ended_rollouts} rollouts ended (done or stop) early")
        if self.nonfinite_rollouts:
            lines.append(
                f"WARNING: {self.nonfinite_rollouts} rollouts' estimate went non-finite before"
                " their first done; scored up to that step"
            )
        lines.append(
            f"control - substep: accuracy {self.control.accuracy - self.substep.accuracy:+.3f},"
            f" F1 {self.control.f1 - self.substep.f1:+.3f}"
        )
        return "\n".join(lines)


def in_time_order(x):
    """(T, E, n_substeps, ...) per env step -> (T * n_substeps, E, ...) per physics step,
    time order kept (NumPy)."""
    t_len, n_envs, n_sub = x.shape[:3]
    return np.moveaxis(x, 2, 1).reshape((t_len * n_sub, n_envs) + x.shape[3:])


def policy_step(wrapped, state, action, feedback=None, stop=None):
    """One step of a scripted policy on a wrapped env: ``feedback(data) -> (nu,)`` (on the
    simulator's state before the step) added to ``action``, and ``ended``, the step's
    ``done`` or ``stop(data)`` of the state after it. Returns ``(state, ended)``."""
    if feedback is not None:
        action = action + feedback(wrapped.sim_data(state))
    state = wrapped.step(state, action)
    ended = state.done
    if stop is not None:
        ended = jnp.maximum(ended, jnp.asarray(stop(wrapped.sim_data(state)), ended.dtype))
    return state, ended


def scored_steps(done, finite, skip_s: float, dt_ctrl: float) -> tuple[np.ndarray, int, int]:
    """Which env steps of :func:`compare_rates`' rollouts are scored.

    A rollout is scored from ``skip_s`` on, up to (not including) its first ``done``
    (whose state may be NaN: Playground ends an episode on NaN physics, and random actions
    get there) and its first step with a non-finite estimate (counted, never hidden).

    Args:
      done: (T, E) the env's ``done`` (or ``stop``) after each env step.
      finite: (T, E) whether both estimators' outputs of that step are finite.
      skip_s: time left out at the start of every rollout, s.
      dt_ctrl: the env step, s.

    Returns:
      ``(valid, n_ended, n_nonfinite)``: the (T, E) mask of scored steps, the rollouts
      that reached a ``done``, those whose estimate went non-finite before it.

    Raises:
      ValueError: naming ``skip_s``, when no step is left to score.
    """
    done, finite = np.asarray(done, bool), np.asarray(finite, bool)
    alive = np.cumsum(done, axis=0) == 0
    n_ended = int((~alive).any(axis=0).sum())
    n_broke = int((alive & ~finite).any(axis=0).sum())
    alive &= np.cumsum(~finite, axis=0) == 0
    skip = int(round(skip_s / dt_ctrl))
    valid = alive & (np.arange(done.shape[0]) >= skip)[:, None]
    if not valid.any():  # else every score is NaN, with numpy's warnings
        last = int(alive.sum(axis=0).max())
        raise ValueError(
            f"skip_s: nothing left to score: {skip_s:g} s ({skip} env steps) are left out of"
            f" every rollout, and the longest ran {last} env steps ({last * dt_ctrl:.2f} s)"
            " before it ended (a done, the stop condition, or a non-finite estimate); use a"
            " smaller skip_s (--skip)"
        )
    return valid, n_ended, n_broke


def compare_rates(
    env,
    actions: jax.Array,
    *,
    key: jax.Array,
    sensor: str = "anymal_like",
    foot_names: Sequence[str] | None = None,
    params_kwargs: Mapping | None = None,
    control_params_kwargs: Mapping | None = None,
    skip_s: float = 0.0,
    pairing: str = "delayed",
    truth_gap: float = 0.001,
    feedback: Callable | None = None,
    stop: Callable | None = None,
    sole: str = "rolling",
    substep_params=None,
) -> RateComparison:
    """Measures the accuracy lost by the control-rate mode against the substep mode.

    Both estimators run on *the same* rollouts: the env is wrapped twice (control rate
    inside, substep rate outside, under their own ``info`` keys), so one simulation feeds
    both and the physics cannot differ; each has its own sensor noise at its own rate
    (same preset). The physics does not depend on the estimates (the actions are given,
    or computed from the simulator's state by ``feedback``, never from an estimate).

    Args:
      env: an unwrapped Brax ``PipelineEnv`` (MJX) or Playground ``MjxEnv`` with ground
        truth (:mod:`jax_contact.envs.contact_truth`).
      actions: (T, E, nu) actions of E rollouts of T env steps.
      key: PRNG key; env e resets with ``split(key, E)[e]``.
      sensor: sensor preset name.
      foot_names: as ``ContactObsConfig.feet``.
      params_kwargs: extra arguments of
        :func:`jax_contact.envs.contact_params.default_estimator_params` for both rates.
      control_params_kwargs: more of them for the control rate only (e.g.
        ``sigma_qdd_model``), applied last.
      skip_s: time at the start of every rollout left out of the scores (settling), s.
      pairing: ``ContactObsConfig.pairing`` of both estimators.
      truth_gap: ``ContactObsConfig.truth_gap`` of both, m; the substep scores are also
        given against the raw truth (``substep_all_raw``).
      feedback: optional closed-loop part of the policy, ``feedback(data) -> (nu,)``
        on one env's simulator state (``mjx.Data``: Playground's ``state.data``, Brax's
        ``state.pipeline_state``), added to that step's action (e.g.
        :mod:`jax_contact.envs.biped_hop`).
      stop: optional ``stop(data) -> bool``: a rollout's score ends before the first
        step whose state it flags (e.g. the robot has fallen), as at a ``done``.
      sole: ``ContactObsConfig.sole`` of both estimators.
      substep_params: ``ContactObsConfig.params`` of the physics-rate estimator instead of
        the defaults: a parameter file or preset name (its calibration map applied, a
        file of another period run at the physics rate with a warning) or
        :class:`jax_contact.EstimatorParams`; ``params_kwargs`` then apply to the
        control rate only.

    Returns:
      The metrics of :func:`jax_contact.metrics.evaluate` for both, over the steps before
      each rollout's first ``done`` or ``stop`` (that step excluded).

    Raises:
      ValueError: ``actions`` not (T, E, nu); after the rollouts, naming ``skip_s``, when
        every rollout ended before ``skip_s`` (nothing to score).
    """
    acts = jnp.asarray(actions)
    if acts.ndim != 3:
        raise ValueError(f"actions must have shape (T, E, nu), got {acts.shape}")
    mj_model = model_of(env)[1]
    desc = feet.describe(mj_model, foot_names)[0]
    extra = dict(params_kwargs or {})
    dt_sub = float(mj_model.opt.timestep)
    n_frames = int(round(float(env.dt) / dt_sub))
    dt_ctrl = dt_sub * n_frames

    def make_params(dt, more):
        robot = Robot(name="env", mj_model=mj_model, description=desc, spec=None)
        sp = default_sensor_params(sensor, robot, dt)
        return default_estimator_params(robot, dt, sp, **{**extra, **more})

    ctrl_cfg = ContactObsConfig(
        rate="control",
        info_key="contact_control",
        truth="auto",
        pairing=pairing,
        truth_gap=truth_gap,
        sole=sole,
    )
    sub_cfg = ContactObsConfig(
        rate="substep",
        info_key="contact_substep",
        truth="auto",
        record_substeps=True,
        pairing=pairing,
        truth_gap=truth_gap,
        sole=sole,
    )
    inner = wrap_contact(
        env,
        ctrl_cfg,
        foot_names=foot_names,
        sensor=sensor,
        params=make_params(dt_ctrl, dict(control_params_kwargs or {})),
    )
    if substep_params is None:
        substep_params = make_params(dt_sub, {})
    outer = wrap_contact(
        inner, sub_cfg, foot_names=foot_names, sensor=sensor, params=substep_params
    )
    if inner.contact_core.truth is None:
        raise ValueError("env's model has no ground-truth contact sensors for every foot")

    # A scan over the batched step (Brax's and Playground's own layout), not a vmap of a
    # scan: vmap re-batches a scan's whole body until its carry's batching settles, and
    # the substep scan inside the step would be re-batched on every round.
    def step(s, a):
        s, ended = policy_step(outer, s, a, feedback, stop)
        info = s.info
        sub = info["contact_substep_substeps"]
        out = (
            info["contact_control"].diag.p_contact,
            info["contact_control_truth"],
            sub["p_contact"],
            sub["truth"],
            sub.get("truth_raw", sub["truth"]),
            ended,
        )
        return s, out

    @jax.jit
    def rollout(keys, a_seq):
        return jax.lax.scan(jax.vmap(step), jax.vmap(outer.reset)(keys), a_seq)[1]

    keys = jax.random.split(key, acts.shape[1])
    p_c, t_c, p_s, t_s, t_raw, done = rollout(keys, jnp.asarray(acts))
    p_c, t_c, done, p_s, t_s, t_raw = map(np.asarray, (p_c, t_c, done, p_s, t_s, t_raw))
    has_raw = outer.contact_core.truth_raw is not None
    if not np.array_equal(t_s[:, :, -1], t_c):
        raise RuntimeError("the two estimators saw different truths: rollouts diverged")
    finite = np.isfinite(p_s).all(axis=(2, 3)) & np.isfinite(p_c).all(axis=-1)
    valid, n_ended, n_broke = scored_steps(done, finite, skip_s, dt_ctrl)
    valid_c = np.broadcast_to(valid[..., None], p_c.shape)
    valid_s = np.broadcast_to(valid[:, :, None, None], p_s.shape)

    flat = in_time_order
    return RateComparison(
        substep=metrics.evaluate(p_s[:, :, -1], t_c, valid_c, dt=dt_ctrl),
        control=metrics.evaluate(p_c, t_c, valid_c, dt=dt_ctrl),
        substep_all=metrics.evaluate(flat(p_s), flat(t_s), flat(valid_s), dt=dt_sub),
        dt_substep=dt_sub,
        dt_control=dt_ctrl,
        contact_fraction=float(np.mean(flat(t_s)[flat(valid_s)])),
        substep_all_raw=(
            metrics.evaluate(flat(p_s), flat(t_raw), flat(valid_s), dt=dt_sub) if has_raw else None
        ),
        contact_fraction_raw=float(np.mean(flat(t_raw)[flat(valid_s)])),
        nonfinite_rollouts=n_broke,
        ended_rollouts=n_ended,
    )
