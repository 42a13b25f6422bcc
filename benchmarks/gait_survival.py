"""Survival of the scripted gaits on flat ground: upright and stepping, per robot and gait.

For each robot and gait, a batch of environments starts from the standing pose with small
random perturbations (joint angles, base height, orientation and velocity) and a random
forward-speed command, and runs ``--duration`` seconds of MJX physics with the gait
controller at every physics step (``jit`` + ``vmap`` + ``lax.scan``, in chunks).

Definitions (per environment):

- upright: at every physics step the base is above ``0.5 x`` its standing height, the
  z-component of the base's up-vector exceeds 0.7, and ``qpos`` is finite (Playground's
  NaN guard; the same check as ``jax_contact.envs.simulate.upright``). A failure is latched.
- touch-down of a foot: the ground-truth flag (normal force > 1 N,
  :mod:`jax_contact.envs.ground_truth`) turns on after the foot was off the ground for at least
  ``--min-air`` seconds (so contact chatter during stance does not count).
- stepping: upright, and for every foot, from ``ramp_time + 2 periods`` until the end,
  no interval longer than ``1.5`` gait periods passes without a touch-down of that foot
  (the interval still open at the end counts).

Prints a table (robot, gait, n_envs, upright %, stepping % (which implies upright),
touch-downs per foot per period, median achieved / commanded speed, env-steps/s, compile
time) and writes JSON. Barkour's height-field floor is replaced by a plane (flat ground).
Run ``python -m jax_contact.benchmarks.gait_survival --help``.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx

from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    check_robot_arg,
    json_of_what_finished,
    machine,
    run_main,
)
from jax_contact.envs.gaits import gait_control, make_gait, make_gait_robot
from jax_contact.envs.ground_truth import foot_truth, make_truth_layout, with_contact_sensors
from jax_contact.envs.robots import Robot, load_robot
from jax_contact.envs.sensors import perturb_qpos
from jax_contact.envs.simulate import upright as is_upright
from jax_contact.robot import derive_description
from jax_contact.train.cli_args import nonnegative_float, positive_float, positive_int, seed_int

# Forward-speed command ranges (m/s), per gait.
SPEEDS = {"trot": (0.0, 0.5), "walk": (0.0, 0.15)}


@struct.dataclass
class Tally:
    """Per-environment bookkeeping carried through the scan."""

    fallen: jax.Array  # () bool
    t_fall: jax.Array  # () s
    air_time: jax.Array  # (n_feet,) s since the foot last had contact
    last_td: jax.Array  # (n_feet,) time of the last touch-down after the warm-up, s
    max_gap: jax.Array  # (n_feet,) longest interval without touch-down after warm-up, s
    n_td: jax.Array  # (n_feet,) touch-downs
    start_x: jax.Array  # () base x at the start, m


def flat_floor(robot: Robot) -> Robot:
    """``robot`` with every height-field floor replaced by a plane at z = 0 (Barkour)."""
    desc = robot.description
    if all(robot.mj_model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE for g in desc.floor_geom_ids):
        return robot
    spec = robot.spec.copy()
    for g in desc.floor_geom_ids:
        geom = spec.geoms[g]
        geom.type = mujoco.mjtGeom.mjGEOM_PLANE
        geom.hfieldname = ""
        geom.size = [0.0, 0.0, 0.05]
        geom.pos = [0.0, 0.0, 0.0]
    mj_model = spec.compile()
    return Robot(
        name=robot.name,
        mj_model=mj_model,
        description=derive_description(mj_model, desc.foot_names),
        spec=spec,
    )


def run_one(
    robot_name: str,
    kind: str,
    *,
    n_envs: int,
    duration: float,
    seed: int,
    chunk_s: float,
    min_air: float,
    speeds: tuple[float, float],
) -> dict:
    robot = with_contact_sensors(flat_floor(load_robot(robot_name)))
    m = robot.mj_model
    dt = float(m.opt.timestep)
    gr = make_gait_robot(robot)
    layout = make_truth_layout(robot)
    mx = mjx.put_model(m)
    n_feet = robot.description.n_legs
    home = jnp.asarray(robot.home_qpos, dtype=jnp.float32)
    base_height = float(gr.base_height)

    key = jax.random.PRNGKey(seed)
    k_speed, k_q, k_base, k_rot, k_vel = jax.random.split(key, 5)
    speed = jax.random.uniform(k_speed, (n_envs,), minval=speeds[0], maxval=speeds[1])
    template = make_gait(kind)
    gaits = jax.tree.map(lambda x: jnp.broadcast_to(x, (n_envs,)), template)
    gaits = gaits.replace(speed=speed)

    # Initial states: joints +-0.05 rad, base height +-1 cm, tilt up to ~0.05 rad per axis,
    # base linear velocity +-0.1 m/s.
    nv = m.nv
    dq = jnp.zeros((n_envs, nv))
    dq = dq.at[:, 6:].set(jax.random.uniform(k_q, (n_envs, nv - 6), minval=-0.05, maxval=0.05))
    dq = dq.at[:, 2].set(jax.random.uniform(k_base, (n_envs,), minval=-0.01, maxval=0.01))
    dq = dq.at[:, 3:6].set(jax.random.uniform(k_rot, (n_envs, 3), minval=-0.05, maxval=0.05))
    qpos0 = jax.vmap(lambda d: perturb_qpos(home, d, floating_base=True))(dq)
    qvel0 = (
        jnp.zeros((n_envs, nv))
        .at[:, 0:3]
        .set(jax.random.uniform(k_vel, (n_envs, 3), minval=-0.1, maxval=0.1))
    )

    def init(qpos, qvel):
        d = mjx.make_data(m).replace(qpos=qpos, qvel=qvel)
        return mjx.forward(mx, d)

    data = jax.jit(jax.vmap(init))(qpos0, qvel0)
    tally = Tally(
        fallen=jnp.zeros(n_envs, bool),
        t_fall=jnp.full(n_envs, jnp.inf),
        air_time=jnp.zeros((n_envs, n_feet)),
        last_td=jnp.zeros((n_envs, n_feet)),
        max_gap=jnp.zeros((n_envs, n_feet)),
        n_td=jnp.zeros((n_envs, n_feet), jnp.int32),
        start_x=qpos0[:, 0],
    )
    warmup = float(template.ramp_time) + 2.0 * float(template.period)

    def env_step(gait, d, tl, t):
        ctrl = gait_control(gait, gr, t, d)
        d = mjx.step(mx, d.replace(ctrl=ctrl))
        truth = foot_truth(layout, d)
        t_new = t + dt
        bad = ~is_upright(d.qpos, True, 0.5 * base_height)
        fallen = tl.fallen | bad
        t_fall = jnp.where(bad & ~tl.fallen, t_new, tl.t_fall)
        was_air = tl.air_time >= min_air
        td = truth.contact & was_air
        air_time = jnp.where(truth.contact, 0.0, tl.air_time + dt)
        after = t_new > warmup
        last_td = jnp.where(after, jnp.where(td, t_new, tl.last_td), t_new)
        gap = jnp.where(after, t_new - tl.last_td, 0.0)
        max_gap = jnp.maximum(tl.max_gap, gap)
        tl = tl.replace(
            fallen=fallen,
            t_fall=t_fall,
            air_time=air_time,
            last_td=last_td,
            max_gap=max_gap,
            n_td=tl.n_td + td.astype(jnp.int32),
        )
        return d, tl

    n_chunk = max(1, int(round(chunk_s / dt)))
    n_total = int(round(duration / dt))
    simulated = -(-n_total // n_chunk) * n_chunk * dt  # whole chunks
    if simulated <= float(template.ramp_time):  # before the compile, not after the run
        raise ValueError(
            f"--duration: {simulated:g} s simulated is not past the"
            f" {float(template.ramp_time):g} s speed ramp of {robot_name}'s {kind}: nothing to"
            " measure the speed on"
        )

    @jax.jit
    def chunk(data, tally, t0):
        def body(carry, i):
            d, tl = carry
            t = t0 + i * dt
            d, tl = jax.vmap(env_step, in_axes=(0, 0, 0, None))(gaits, d, tl, t)
            return (d, tl), None

        (data, tally), _ = jax.lax.scan(body, (data, tally), jnp.arange(n_chunk))
        return data, tally

    data, tally = jax.block_until_ready((data, tally))  # not running while it compiles
    t_compile = time.perf_counter()
    lowered = chunk.lower(data, tally, jnp.float32(0.0)).compile()
    t_compile = time.perf_counter() - t_compile
    t_run = time.perf_counter()
    steps = 0
    while steps < n_total:
        data, tally = lowered(data, tally, jnp.float32(steps * dt))
        steps += n_chunk
    jax.block_until_ready(tally)
    t_run = time.perf_counter() - t_run
    sim_time = steps * dt

    fallen = np.asarray(tally.fallen)
    upright = ~fallen
    stepping = upright & np.all(np.asarray(tally.max_gap) <= 1.5 * float(template.period), axis=1)
    dist = np.asarray(data.qpos[:, 0] - tally.start_x)
    cmd = np.asarray(speed)
    # Mean speed over the run after the ramp (the ramp covers half its time at full speed).
    mean_speed = dist / (sim_time - 0.5 * float(template.ramp_time))
    result = {
        "robot": robot_name,
        "gait": kind,
        "n_envs": n_envs,
        "sim_seconds": sim_time,
        "dt": dt,
        "period": float(template.period),
        "duty": float(template.duty),
        "speed_range": list(speeds),
        "upright_pct": 100.0 * float(np.mean(upright)),
        "stepping_pct": 100.0 * float(np.mean(stepping)),
        "fall_times_s": sorted(float(x) for x in np.asarray(tally.t_fall)[fallen]),
        "max_gap_over_period_median": float(np.median(np.max(np.asarray(tally.max_gap), 1)))
        / float(template.period),
        "touchdowns_per_foot_per_period": float(np.mean(np.asarray(tally.n_td)[upright]))
        / (sim_time / float(template.period))
        if upright.any()
        else 0.0,
        "speed_tracking_ratio_median": float(
            np.median(mean_speed[upright & (cmd > 0.1)] / cmd[upright & (cmd > 0.1)])
        )
        if np.any(upright & (cmd > 0.1))
        else float("nan"),
        "env_steps_per_s": n_envs * steps / t_run,
        "compile_s": t_compile,
        "run_s": t_run,
    }
    return result


def main(argv=None) -> None:
    parser = bench_parser(__doc__)
    parser.add_argument("--robots", nargs="+", default=["go1", "spot"], help="robots to walk")
    parser.add_argument(
        "--gaits", nargs="+", default=["trot", "walk"], choices=list(SPEEDS), help="gaits"
    )
    parser.add_argument("--n-envs", type=positive_int, default=256, help="envs per robot and gait")
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=20.0,
        help="simulated seconds, rounded up to whole --chunk scans; more than the gaits'"
        " speed ramp (1 s)",
    )
    parser.add_argument("--chunk", type=positive_float, default=2.0, help="seconds per jitted scan")
    parser.add_argument("--min-air", type=nonnegative_float, default=0.02, help="s off the ground")
    parser.add_argument("--seed", type=seed_int, default=0, help="simulation seed")
    parser.add_argument("--json", help="write the rows and the machine as JSON (atomically)")
    args = parser.parse_args(argv)
    for name in args.robots:
        check_robot_arg(parser, "--robots", name)
    check_json_arg(parser, args.json)
    if args.duration < args.chunk:  # it ran no step at all, and divided by the 0 s simulated
        parser.error(
            f"argument --duration: {args.duration:g} s is shorter than --chunk {args.chunk:g} s"
        )
    # The speed is measured after each gait's ramp: refused here, before any model loads
    # (run_one's own check came after loading the first robot, with a traceback).
    ramp = max(float(make_gait(kind).ramp_time) for kind in args.gaits)
    simulated = -(-args.duration // args.chunk) * args.chunk  # whole chunks, as run_one
    if simulated <= ramp:
        parser.error(
            f"argument --duration: {simulated:g} s simulated (whole --chunk scans) is not past"
            f" the gaits' {ramp:g} s speed ramp: nothing to measure the speed on"
        )

    result = {"machine": machine(), "rows": []}
    with json_of_what_finished(args.json, result):  # the robots that finished, if one fails
        _run_all(args, result["rows"])


def _run_all(args, results: list[dict]) -> None:
    """Runs every robot and gait, appending each row to ``results`` and printing it."""
    header = (
        f"{'robot':<8} {'gait':<5} {'n_envs':>6} {'upright%':>9} {'stepping%':>10}"
        f" {'td/foot/period':>14} {'v/v_cmd':>8} {'steps/s':>9} {'compile_s':>9}"
    )
    print(header, flush=True)
    for name in args.robots:
        for kind in args.gaits:
            r = run_one(
                name,
                kind,
                n_envs=args.n_envs,
                duration=args.duration,
                seed=args.seed,
                chunk_s=args.chunk,
                min_air=args.min_air,
                speeds=SPEEDS[kind],
            )
            results.append(r)
            print(
                f"{name:<8} {kind:<5} {r['n_envs']:>6} {r['upright_pct']:>9.1f}"
                f" {r['stepping_pct']:>10.1f} {r['touchdowns_per_foot_per_period']:>14.2f}"
                f" {r['speed_tracking_ratio_median']:>8.2f} {r['env_steps_per_s']:>9.0f}"
                f" {r['compile_s']:>9.1f}",
                flush=True,
            )


if __name__ == "__main__":
    raise SystemExit(run_main(main, "gait_survival"))
