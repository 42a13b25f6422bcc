"""Accuracy of the wrapped estimator at the physics rate on Playground envs (docs/training.md).

Scenes (``--envs``, Playground registry names loaded offline, each optionally
``NAME:POLICY``), each E rollouts of T env steps (20 ms), ``anymal_like`` sensors, the
env's own ``*_floor_found`` foot sensors as truth with the wrapper's 1 mm
``truth_gap`` (and, beside it, against the raw sensors), scored at every physics step
after the first ``--skip`` s (the drop at reset) and before each rollout's first ``done``.
Open-loop scripted policies through the env's action interface (:func:`actions_for`):

- ``Go1JoystickFlatTerrain``, ``SpotFlatTerrainJoystick``: ``walk`` (default), a
  lateral-sequence walk in place, or ``trot``, diagonal pairs in turn;
- ``BerkeleyHumanoidJoystickFlatTerrain``: ``hop`` (default), hopping in place on both
  feet, closed loop (:mod:`jax_contact.envs.biped_hop`: squat-and-push feedforward, attitude
  and foot-placement feedback on the simulator's state), each rollout's score ending when
  the robot falls (base below 0.3 m or tilted over 0.8 rad); ``step``, open-loop
  stepping in place (it tips the robot over: no open-loop policy keeps it up,
  docs/training.md);
- ``Go1Getup``, ``Go1Handstand``: ``random``, uniform actions in [-1, 1] (the issue's case);
- any env: ``random``, or ``stand`` (zero actions: the env's default pose held).

Both rates run on the same rollouts (:func:`jax_contact.train.rates.compare_rates`: control-rate
wrapper inside, physics-rate outside). Reported: accuracy, F1, precision, recall at every
physics step, the control rate's accuracy at env steps, and the trivial scores
(always-contact, always-air). Prints a table and writes JSON.

    python -m jax_contact.benchmarks.wrapper_accuracy --seed 1 --json out/wrapper_accuracy.json
    python -m jax_contact.benchmarks.wrapper_accuracy --envs Go1JoystickFlatTerrain:trot
    python -m jax_contact.benchmarks.wrapper_accuracy --envs Go1JoystickFlatTerrain --params go1

The policies' settings were chosen on seed 0 (docs/training.md); report other seeds.
"""

from __future__ import annotations

import time

import jax
import numpy as np

from jax_contact.benchmarks.common import (
    SCORE_COLUMNS,
    bench_parser,
    check_env_arg,
    check_json_arg,
    json_of_what_finished,
    machine,
    print_table,
    run_main,
)
from jax_contact.envs import biped_hop, scripted
from jax_contact.train.cli_args import nonnegative_float, positive_int, seed_int

ENVS = (
    "Go1JoystickFlatTerrain",
    "SpotFlatTerrainJoystick",
    "BerkeleyHumanoidJoystickFlatTerrain",
    "Go1Getup",
    "Go1Handstand",
)
SCALE = {"Go1": 0.5, "Spot": 0.3, "BerkeleyHumanoid": 0.5}  # their configs' action_scale
POLICIES = ("walk", "trot", "step", "hop", "random", "stand")
DEFAULT_POLICY = {"Go1": "walk", "Spot": "walk", "BerkeleyHumanoid": "hop"}


def _robot(name: str) -> str | None:
    """The key of :data:`SCALE` for env ``name``, None for a robot it has none for
    (:func:`check_policy` has passed for a scripted policy)."""
    return next((k for k in SCALE if name.startswith(k)), None)


def check_policy(name: str, policy: str | None) -> None:
    """Raises ValueError naming ``policy`` unless it can drive env ``name`` (None: the
    env's default, :func:`default_policy`): ``random`` and ``stand`` drive any env, the scripted
    gaits only the robots they were written for (:data:`SCALE`'s, with the legs of
    :data:`jax_contact.envs.scripted.PHASES`; ``hop`` and ``step`` Berkeley Humanoid's).
    No JAX is needed."""
    policy = default_policy(name) if policy is None else policy
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    if policy in ("random", "stand"):
        return
    robot = _robot(name)
    if policy in scripted.POLICIES:
        robots = tuple(scripted.PHASES[policy])
    else:  # hop, step
        robots = ("BerkeleyHumanoid",)
    if robot not in robots:
        raise ValueError(
            f"policy {policy!r} is scripted for {', '.join(robots)}, not {name}: drive"
            f" {name} with {name}:random, or with your own actions or trained policy"
            " (jax_contact.train.tune_env.tune_on_env)"
        )


def default_policy(name: str) -> str:
    if "Getup" in name or "Handstand" in name:
        return "random"
    robot = next((k for k in SCALE if name.startswith(k)), None)
    return DEFAULT_POLICY.get(robot, "random")


# Stepping in place of the humanoid: per leg (hip flexion, knee, ankle flexion) at the
# apex, rad; the cycle frequency, Hz; the swing fraction of each leg's cycle.
HUMANOID_STEP = dict(hip=-0.25, knee=0.5, ankle=-0.25, freq=1.25, swing=0.3)


def _humanoid_step(t, jitter, phase0, acts, scale):
    p = HUMANOID_STEP
    for leg, off in enumerate((0.0, 0.5)):  # left, right: 6 actuators each
        s = scripted.swing_profile(t, p["freq"] * jitter, phase0 + off, p["swing"])
        acts[:, :, 6 * leg + 2] += p["hip"] * s / scale
        acts[:, :, 6 * leg + 3] += p["knee"] * s / scale
        acts[:, :, 6 * leg + 4] += p["ankle"] * s / scale
    desc = f"scripted stepping in place ({p['freq']:g} Hz, swing {p['swing']:g} of the cycle)"
    return acts, desc


def actions_for(
    name: str, env, n_steps: int, n_envs: int, seed: int, policy: str | None = None
) -> tuple[np.ndarray, str]:
    """(T, E, nu) actions of an open-loop scripted policy, and a one-line description.

    Actions are in the env's units (rad / action_scale, added to the default pose by the
    env). Rollout ``e`` runs at a frequency in base x [0.9, 1.1] and with a phase drawn
    from ``seed``, so that the events do not line up across rollouts or seeds.

    - ``walk`` (Go1, Spot; the default): a lateral-sequence walk in place, one leg
      swinging at a time for 0.2 of a 1 Hz cycle, hip pitch +0.3 rad and knee -0.6 rad at
      the apex of a sin^2 swing.
    - ``trot`` (Go1, Spot): diagonal pairs in turn, 0.4 of a 2 Hz cycle each, hip +0.4 rad,
      knee -0.7 rad at the apex.
    - ``step`` (Berkeley Humanoid): stepping in place, the legs in turn (see the code).
    - ``hop`` (Berkeley Humanoid): the feedforward of :func:`jax_contact.envs.biped_hop.feedforward`
      (its closed-loop part is :func:`closed_loop_for`'s).
    - ``random``: uniform actions in [-1, 1] (the issue's case for getup and handstand).
    - ``stand``: zero actions, the env's default pose held (any env; a standing check).
    """
    policy = default_policy(name) if policy is None else policy
    check_policy(name, policy)
    nu = env.action_size
    rng = np.random.default_rng(seed)
    if policy == "random":
        return rng.uniform(-1, 1, (n_steps, n_envs, nu)).astype(np.float32), "random U(-1,1)"
    if policy == "stand":
        return np.zeros((n_steps, n_envs, nu), np.float32), "stand (zero actions)"
    robot = _robot(name)
    scale = SCALE[robot]
    t = np.arange(1, n_steps + 1)[:, None] * float(env.dt)
    jitter = 1.0 + 0.1 * rng.uniform(-1, 1, n_envs)
    phase0 = rng.uniform(0, 1, n_envs)
    acts = np.zeros((n_steps, n_envs, nu), np.float32)
    if policy in scripted.POLICIES:  # in_place_offsets names a robot it has no phases for
        acts[:] = scripted.in_place_offsets(policy, robot, t, jitter, phase0) / scale
        freq, swing = scripted.SETTINGS[policy][:2]
        desc = f"scripted {policy} in place ({freq:g} Hz, swing {swing:g} of the cycle)"
        return acts, desc
    if robot != "BerkeleyHumanoid":
        raise ValueError(f"policy {policy!r} is for BerkeleyHumanoid, not {name}")
    if policy == "hop":
        acts[:] = biped_hop.feedforward(t, jitter, phase0) / scale
        desc = f"scripted hop in place, closed loop ({biped_hop.BERKELEY_HOP.freq:g} Hz)"
        return acts, desc
    return _humanoid_step(t, jitter, phase0, acts, scale)


def closed_loop_for(name: str, env, policy: str | None = None):
    """(feedback, stop) of :func:`jax_contact.train.rates.compare_rates` for a policy.

    ``hop``: the feedback of :func:`jax_contact.envs.biped_hop.feedback` in the env's
    action units, in stance when either foot's ``*_foot1_floor_found`` sensor is on, and
    :func:`jax_contact.envs.biped_hop.fallen` as ``stop``. Every other policy is open
    loop: (None, None).
    """
    policy = default_policy(name) if policy is None else policy
    if policy != "hop":
        return None, None
    adr = biped_hop.stance_sensors(env.mj_model)
    scale = SCALE[_robot(name)]

    def feedback(data):
        stance = (data.sensordata[adr] > 0).any()
        return biped_hop.feedback(data.qpos, data.qvel, stance) / scale

    def stop(data):
        return biped_hop.fallen(data.qpos)

    return feedback, stop


def run_one(
    name: str,
    n_steps: int,
    n_envs: int,
    skip_s: float,
    seed: int,
    policy: str | None = None,
    sole: str = "rolling",
    params: str | None = None,
) -> dict:
    from jax_contact.envs import playground_offline
    from jax_contact.train.rates import compare_rates

    env = playground_offline.load(name)
    feedback, stop = closed_loop_for(name, env, policy)
    acts, policy = actions_for(name, env, n_steps, n_envs, seed, policy)
    t0 = time.perf_counter()
    res = compare_rates(
        env,
        acts,
        key=jax.random.PRNGKey(seed),
        skip_s=skip_s,
        feedback=feedback,
        stop=stop,
        sole=sole,
        substep_params=params,
    )
    wall = time.perf_counter() - t0
    print(f"{name}: {policy}, {n_envs} x {n_steps} steps ({wall:.0f} s)\n{res.table()}", flush=True)
    m = res.substep_all
    raw = res.substep_all_raw if res.substep_all_raw is not None else m
    return {
        "env": name,
        "policy": policy,
        "dt_physics_ms": res.dt_substep * 1e3,
        "accuracy": m.accuracy,
        "f1": m.f1,
        "precision": m.precision,
        "recall": m.recall,
        "always_contact": res.contact_fraction,
        "always_air": 1 - res.contact_fraction,
        "control_accuracy": res.control.accuracy,
        "substep_accuracy_at_env_steps": res.substep.accuracy,
        "foot_updates": m.n_steps,
        "seed": seed,
        "sole": sole,
        "params": params or "defaults",
        "ece": m.ece,
        "accuracy_raw_truth": raw.accuracy,
        "f1_raw_truth": raw.f1,
        "always_air_raw_truth": 1 - res.contact_fraction_raw,
        "nonfinite_rollouts": res.nonfinite_rollouts,
        "ended_rollouts": res.ended_rollouts,
        "rollouts": n_envs,
        "wall_s": wall,
        "substep": m.as_dict(),
        "control": res.control.as_dict(),
    }


def main(argv=None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--json", default=None, help="write the rows and the machine here")
    parser.add_argument(
        "--envs",
        nargs="+",  # "--envs" with no names ran nothing and exited 0
        default=list(ENVS),
        help="registry names, each optionally NAME:POLICY (policies: " + ", ".join(POLICIES) + ")",
    )
    parser.add_argument("--steps", type=positive_int, default=150, help="env steps per rollout")
    parser.add_argument("--rollouts", type=positive_int, default=8, help="rollouts per env")
    parser.add_argument(
        "--skip", type=nonnegative_float, default=0.5, help="seconds left out at the start"
    )
    parser.add_argument("--seed", type=seed_int, default=0, help="rollout seed")
    parser.add_argument(
        "--sole", default="rolling", help="ContactObsConfig.sole: rolling or centre (flat feet)"
    )
    parser.add_argument(
        "--params",
        default=None,
        help="the physics-rate estimator's parameter file or preset (go1, spot, barkour,"
        " go1_playground), its calibration map applied; default: the defaults",
    )
    args = parser.parse_args(argv)
    for entry in args.envs:  # refused before anything loads
        name, _, policy = entry.partition(":")
        check_env_arg(parser, "--envs", name)
        try:
            check_policy(name, policy or None)
        except ValueError as err:
            parser.error(f"argument --envs: {entry!r}: {err}")
    if args.sole not in ("rolling", "centre"):
        parser.error(f"argument --sole: must be rolling or centre, got {args.sole!r}")
    if args.params is not None:  # read once here: a bad file was a traceback after loading
        from jax_contact.params_file import load_params

        try:
            load_params(args.params)
        except (OSError, ValueError) as err:
            parser.error(f"argument --params: {err}")
    check_json_arg(parser, args.json)
    result = {"machine": machine(), "args": vars(args), "rows": []}
    with json_of_what_finished(args.json, result):
        for entry in args.envs:
            name, _, policy = entry.partition(":")
            row = run_one(
                name,
                args.steps,
                args.rollouts,
                args.skip,
                args.seed,
                policy or None,
                args.sole,
                args.params,
            )
            result["rows"].append(row)
    cols = [
        ("env", "env", "{}"),
        ("policy", "policy", "{}"),
        *SCORE_COLUMNS,
        ("always_contact", "all-contact", "{:.3f}"),
        ("always_air", "all-air", "{:.3f}"),
        ("accuracy_raw_truth", "acc raw truth", "{:.3f}"),
        ("always_air_raw_truth", "all-air raw", "{:.3f}"),
        ("control_accuracy", "ctrl acc", "{:.3f}"),
        ("foot_updates", "n", "{}"),
    ]
    print_table(result["rows"], cols)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, "wrapper_accuracy"))
