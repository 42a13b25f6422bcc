"""Batched rollouts: scripted gaits in MJX, ground truth, and what the sensors would say.

:func:`simulate` runs ``n_envs`` robots at once (``jax.vmap`` over envs, ``lax.scan`` over
time, in chunks so progress can be shown) and returns time x env x leg arrays of sensor
readings and ground truth. The physics runs at the estimator's rate (``dt``, 400 Hz by
default, as on ANYmal), so every physics step yields one reading.

Timing convention (the same in the wrapper, :mod:`jax_contact.envs.wrapper`, and in the offline
replay, :func:`jax_contact.train.evaluate.replay`): reading ``k`` is what the sensors give *after*
physics step ``k``, as on a robot at the end of a control period: the state at the end of
the step ``(qpos_{k+1}, qvel_{k+1})``, the acceleration over the step (the backward
difference ``(qvel_{k+1} - qvel_k) / dt``) and the actuation force applied during it
(``qfrc_actuator`` of ``mj_step``, computed at the state the step starts from). The ground
truth of step ``k`` is the contact MuJoCo resolved during the step (at ``qpos_k``, where
``mj_step`` computes its forces). Reading ``k`` thus arrives at the end of the interval its
truth describes, for every detector; the estimator's delayed pairing (acceleration and
torque of reading ``k`` with the state of reading ``k - 1``, i.e. ``qpos_k``) describes
exactly that interval.

The simulated robot may carry mass the estimator's model does not know
(:class:`World.sim_model`, the paper's robustness test); everything the estimator uses
comes from the nominal :class:`World.robot`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx

from jax_contact.envs.gaits import GaitParams, gait_control, make_gait, make_gait_robot
from jax_contact.envs.ground_truth import foot_truth, make_truth_layout, with_contact_sensors
from jax_contact.envs.model_files import check_mjx_collisions
from jax_contact.envs.payload import add_mass
from jax_contact.envs.robots import Robot, load_robot, with_terrain
from jax_contact.envs.sensors import SensorParams, sensor_init, sensor_preset, sensor_step
from jax_contact.robot import actuated_dofs, leg_of

TERRAINS = ("flat", "rough")
UPRIGHT_MIN_Z_AXIS = 0.7  # base z-axis . world z, as in the gait survival benchmark


@dataclasses.dataclass(frozen=True, eq=False)
class World:
    """Everything static about one simulated scenario.

    Attributes:
      robot: the nominal robot (with ground-truth contact sensors): the estimator's model.
      sim_model: the model that is simulated (``robot.mj_model`` plus any added mass).
      terrain: ``"flat"`` or ``"rough"``.
      roughness: height std of the rough floor, m (0 for flat).
      added_mass: (body name, kg) pairs the simulated robot carries and the model not.
      dt: physics and estimator period, s.
    """

    robot: Robot
    sim_model: mujoco.MjModel
    terrain: str
    roughness: float
    added_mass: tuple[tuple[str, float], ...]
    dt: float

    @property
    def floating_base(self) -> bool:
        return self.robot.mj_model.nq != self.robot.mj_model.nv


def rough_heights(
    roughness: float, *, size_xy=(10.0, 10.0), cell: float = 0.1, seed: int = 0
) -> np.ndarray:
    """(ny, nx) heights of a random rough floor: smoothed white noise of std ``roughness``, m.

    The field is zero-mean; samples are ``cell`` apart and the smoothing spans about three
    cells (bumps ~0.3 m wide, a quadruped's foot lands on varying heights and slopes).
    """
    rng = np.random.default_rng(seed)
    nx = int(round(2 * size_xy[0] / cell)) + 1
    ny = int(round(2 * size_xy[1] / cell)) + 1
    noise = rng.normal(size=(ny, nx))
    kernel = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
    kernel /= kernel.sum()
    for axis in (0, 1):
        noise = np.apply_along_axis(lambda r: np.convolve(r, kernel, mode="same"), axis, noise)
    noise -= noise.mean()
    return (roughness * noise / max(noise.std(), 1e-12)).astype(np.float64)


def build_world(
    robot: str | Robot,
    *,
    terrain: str = "flat",
    roughness: float = 0.02,
    added_mass: Sequence[tuple[str, float]] = (),
    dt: float = 0.0025,
    terrain_seed: int = 0,
) -> World:
    """Loads a robot and builds the world it is simulated in.

    Args:
      robot: a robot name for :func:`jax_contact.envs.robots.load_robot`, or a loaded robot.
      terrain: ``"flat"`` or ``"rough"`` (a height field of std ``roughness``).
      roughness: height std of the rough floor, m.
      added_mass: (body name, kg) pairs added to the *simulated* robot only.
      dt: physics and estimator period, s.
      terrain_seed: seed of the rough floor.

    Raises:
      ValueError: unknown terrain, non-positive dt, an unknown body name (the message
        lists the bodies), or a rough floor MJX cannot collide a foot with (naming the
        geoms: e.g. a margin on a sphere against the height field).
    """
    if terrain not in TERRAINS:
        raise ValueError(f"terrain must be one of {TERRAINS}, got {terrain!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite float > 0 (s), got {dt!r}")
    robot = load_robot(robot) if isinstance(robot, str) else robot
    if terrain == "rough":
        if not (np.isfinite(roughness) and roughness > 0):
            raise ValueError(f"roughness must be > 0 (m) for a rough floor, got {roughness!r}")
        size = (10.0, 10.0)
        robot = with_terrain(robot, rough_heights(roughness, size_xy=size, seed=terrain_seed), size)
    robot = with_contact_sensors(robot)
    robot.mj_model.opt.timestep = dt
    # Go1 and Spot ship with one solver iteration: touch-downs then bounce for 4-8 ms and
    # the walk shows kN force spikes, which would corrupt the ground truth. Four are clean.
    robot.mj_model.opt.iterations = max(int(robot.mj_model.opt.iterations), 4)
    sim = robot.mj_model
    bodies = [mujoco.mj_id2name(sim, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(sim.nbody)]
    for body, kg in added_mass:
        if body not in bodies:
            raise ValueError(f"added_mass names body {body!r}; the robot's bodies are {bodies}")
        sim = add_mass(sim, body, float(kg))
    sim.opt.timestep = dt
    sim.opt.iterations = robot.mj_model.opt.iterations
    if terrain == "rough":  # a new floor type: pairs MJX cannot collide fail here, named
        check_mjx_collisions(sim, f"{robot.name} on the rough floor")
    return World(
        robot=robot,
        sim_model=sim,
        terrain=terrain,
        roughness=float(roughness) if terrain == "rough" else 0.0,
        added_mass=tuple((str(b), float(k)) for b, k in added_mass),
        dt=float(dt),
    )


@struct.dataclass
class Rollout:
    """Time x env (x leg) arrays of one batched simulation (NumPy).

    Attributes:
      qpos, qvel, qacc, tau: (T, E, nq | nv) sensor readings (see ``jax_contact.envs.sensors``).
      contact: (T, E, L) bool ground-truth contact (normal force > threshold).
      force: (T, E, L) ground-truth normal force on each foot, N.
      distance: (T, E, L) sole-to-floor distance, m.
      valid: (T, E) bool: the env is upright and finite (once fallen, never valid again).
      time: (T,) s.
    """

    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    tau: np.ndarray
    contact: np.ndarray
    force: np.ndarray
    distance: np.ndarray
    valid: np.ndarray
    time: np.ndarray

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays under the log schema's names (see ``jax_contact.io``)."""
        return {
            "readings/qpos": self.qpos,
            "readings/qvel": self.qvel,
            "readings/qacc": self.qacc,
            "readings/tau": self.tau,
            "truth/contact": self.contact,
            "truth/force": self.force,
            "truth/distance": self.distance,
            "valid": self.valid,
            "time": self.time,
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> Rollout:
        names = {f.name: f.name for f in dataclasses.fields(cls)}
        keyed = {"readings/" + k: k for k in ("qpos", "qvel", "qacc", "tau")}
        keyed |= {"truth/" + k: k for k in ("contact", "force", "distance")}
        keyed |= {"valid": "valid", "time": "time"}
        missing = [k for k in keyed if k not in arrays]
        if missing:
            raise ValueError(f"log is missing arrays {missing}")
        return cls(**{names[v]: np.asarray(arrays[k]) for k, v in keyed.items()})


def upright(qpos: jax.Array, floating_base: bool, min_height: float) -> jax.Array:
    """() bool: finite ``qpos``; with a floating base also base z above ``min_height`` (m)
    and the base's up-vector z-component above :data:`UPRIGHT_MIN_Z_AXIS`."""
    finite = jnp.all(jnp.isfinite(qpos))
    if not floating_base:
        return finite
    x, y = qpos[4], qpos[5]
    z_axis_z = 1.0 - 2.0 * (x * x + y * y)
    return finite & (z_axis_z > UPRIGHT_MIN_Z_AXIS) & (qpos[2] > min_height)


def initial_states(world: World, n_envs: int, *, key: jax.Array, joint_noise: float = 0.05):
    """(qpos (E, nq), qvel (E, nv)): the home pose with joint noise, a random heading."""
    home = jnp.asarray(world.robot.home_qpos, jnp.float32)
    m = world.robot.mj_model
    k_q, k_yaw = jax.random.split(key)
    qpos = jnp.broadcast_to(home, (n_envs, m.nq))
    start = 7 if world.floating_base else 1
    dq = joint_noise * jax.random.uniform(k_q, (n_envs, m.nq - start), minval=-1.0, maxval=1.0)
    qpos = qpos.at[:, start:].add(dq)
    if world.floating_base:
        yaw = jax.random.uniform(k_yaw, (n_envs,), minval=-np.pi, maxval=np.pi)
        qpos = qpos.at[:, 3].set(jnp.cos(yaw / 2)).at[:, 6].set(jnp.sin(yaw / 2))
        qpos = qpos.at[:, 4:6].set(0.0)
    return qpos, jnp.zeros((n_envs, m.nv), jnp.float32)


def default_sensor_params(world: World, noise: str | SensorParams) -> SensorParams:
    """A sensor preset for this world's robot at its rate, or the given params."""
    if isinstance(noise, SensorParams):
        return noise
    desc = world.robot.description
    return sensor_preset(
        noise,
        desc.nv,
        dt=world.dt,
        floating_base=world.floating_base,
        base_dofs=desc.base_dofs,
    )


def check_gait_fits(gait: GaitParams, robot: Robot) -> None:
    """Refuses a gait the robot's legs cannot run (it would simulate, meaninglessly).

    The hop (:func:`jax_contact.envs.gaits.make_gait`) drives one leg's base up and down
    its rail; the trot and the walk carry a body on legs that take turns, so a single
    leg on its rail would only drop its base at every swing. A robot fixed to the world
    has no base to move.
    """
    n_legs = robot.description.n_legs
    m, actuated = robot.mj_model, actuated_dofs(robot.mj_model)
    # The legs' joints, and those above several feet (a waist, a spine), which the gaits
    # hold at their standing angle (jax_contact.envs.gait_robot).
    driven = {d for b in robot.description.foot_body_ids for d in leg_of(m, b, actuated)[1]}
    limp = sorted(actuated - driven - set(robot.description.base_dofs))
    if limp:
        joints = sorted({m.joint(int(m.dof_jntid[d])).name for d in limp})
        feet = list(robot.description.foot_names)
        raise ValueError(
            f"actuated joints {joints} are on no leg of the feet {feet}:"
            " the scripted gaits drive the named feet's legs only, and would leave these limp;"
            " name every foot (--feet), and give a leg without one a foot geom at its end (a"
            " sphere that can touch the floor)"
        )
    if not robot.description.base_dofs:
        raise ValueError(
            f"robot {robot.name!r} is fixed to the world (no free joint and no passive base"
            " joint): the scripted gaits move a base; record the leg's readings and use"
            " `jax-contact estimate` (docs/own_robot.md, route 2)"
        )
    if gait.family == "hop" and n_legs != 1:
        raise ValueError(
            f"gait 'hop' runs a one-legged robot (the planar leg); {robot.name!r} has"
            f" {n_legs} legs: use 'trot' or 'walk'"
        )
    if gait.family != "hop" and n_legs < 2:
        raise ValueError(
            f"gait {gait.kind!r} needs two or more legs; {robot.name!r} has one: use 'hop'"
        )
    if gait.family != "hop" and n_legs < 3 and len(robot.description.base_dofs) > 1:
        # A trot or walk of two legs leaves one foot on the floor at times: a point, no
        # support polygon. Berkeley Humanoid fell in 2 of 2 envs within 1 s (a user trial).
        raise ValueError(
            f"gait {gait.kind!r} is scripted without balance control, and {robot.name!r} stands"
            f" on {n_legs} legs with a free base: it falls under it; record the robot under"
            " its own controller and run `jax-contact estimate` on the recording"
            " (docs/own_robot.md, route 2)"
        )


def simulate(
    world: World,
    gait: GaitParams | str,
    noise: str | SensorParams,
    n_envs: int,
    duration: float,
    seed: int,
    *,
    speed_range: tuple[float, float] = (0.0, 0.0),
    chunk_s: float = 1.0,
    progress: bool = True,
) -> Rollout:
    """Runs ``n_envs`` scripted robots for ``duration`` seconds.

    Args:
      world: from :func:`build_world`.
      gait: gait parameters, or a kind name (``"trot"``, ``"walk"``, ``"hop"``) with its
        defaults.
      noise: a sensor preset name (``"ideal"``, ``"anymal_like"``, ``"harsh"``) or params.
      n_envs: batch size.
      duration: simulated time, s.
      seed: seeds initial states, commanded speeds and sensor noise.
      speed_range: each env's forward speed command is uniform in this range, m/s.
      chunk_s: simulated seconds per compiled chunk (progress is printed per chunk).
      progress: print progress to stderr.

    Returns:
      A :class:`Rollout` with ``T = round(duration / dt)`` steps.

    Raises:
      ValueError: a non-positive ``n_envs``, a ``duration`` of fewer than 2 steps, or a
        gait the robot cannot run (the hop needs one leg, the trot and the walk two or
        more).
    """
    if not isinstance(n_envs, int | np.integer) or n_envs < 1:
        raise ValueError(f"n_envs must be a positive int, got {n_envs!r}")
    if not (np.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be > 0 (s), got {duration!r}")
    gait = make_gait(gait) if isinstance(gait, str) else gait
    check_gait_fits(gait, world.robot)
    sensors = default_sensor_params(world, noise)
    grobot = make_gait_robot(world.robot)
    layout = make_truth_layout(world.robot)
    m = mjx.put_model(world.sim_model)
    dt = world.dt
    n_steps = int(round(duration / dt))
    if n_steps < 2:  # every consumer of a log differences a reading with the one before
        raise ValueError(
            f"duration {duration!r} s is {n_steps} step(s) of {dt:.6g} s; a log needs at"
            f" least 2 (duration >= {2 * dt:.6g} s)"
        )
    chunk = max(1, min(n_steps, int(round(chunk_s / dt))))

    key = jax.random.key(seed)
    k_init, k_speed, k_sens, k_run = jax.random.split(key, 4)
    qpos0, qvel0 = initial_states(world, n_envs, key=k_init)
    speeds = jax.random.uniform(
        k_speed, (n_envs,), minval=speed_range[0], maxval=max(speed_range[0], speed_range[1])
    )
    gaits = jax.vmap(lambda s: gait.replace(speed=s))(speeds)

    data, sstate = _init_batch(m, sensors, qpos0, qvel0, jax.random.split(k_sens, n_envs))
    # Committed like the chunk's outputs: jit caches uncommitted and committed arguments
    # apart, and would compile the chunk twice.
    alive = jax.device_put(jnp.ones((n_envs,), bool), jax.devices()[0])

    upright_args = (world.floating_base, 0.5 * float(world.robot.home_qpos[2]))
    # The command line's progress bar (standard library and tqdm only; no JAX at import).
    from jax_contact.train import progress as pg

    pieces = []
    upright = [n_envs]

    def state() -> str:
        return f"{upright[0]}/{n_envs} upright"

    starts = range(0, n_steps, chunk)
    desc = f"simulate {world.robot.name}/{gait.kind} ({n_steps * dt:.1f} s simulated)"
    for done in pg.bar(starts, desc=desc, unit="chunk", enabled=progress, postfix=state):
        k_run, sub = jax.random.split(k_run)
        data, sstate, alive, outs = _run_chunk(
            m,
            grobot,
            layout,
            sensors,
            gaits,
            data,
            sstate,
            alive,
            jnp.float32(done * dt),
            sub,
            dt=dt,
            chunk=chunk,
            upright_args=upright_args,
        )
        pieces.append(jax.device_get(outs))
        upright[0] = int(np.asarray(alive).sum())
    readings, contact, force, dist, ok = jax.tree.map(
        lambda *xs: np.concatenate(xs, axis=0)[:n_steps], *pieces
    )
    return Rollout(
        qpos=readings.qpos,
        qvel=readings.qvel,
        qacc=readings.qacc,
        tau=readings.tau,
        contact=contact,
        force=force,
        distance=dist,
        valid=ok,
        time=(np.arange(n_steps) * dt).astype(np.float32),
    )


# The compiled pieces take the model and every parameter as arguments (not closures), so
# one compilation serves every seed, and every world of the same structure (e.g. the same
# robot with added mass).
@jax.jit
def _init_batch(m, sensors, qpos0, qvel0, keys):
    def one(qpos, qvel, k):
        # No mjx.forward here: the first mjx.step computes everything, and a separate
        # compilation of forward would cost as much as the whole chunk's.
        d = mjx.make_data(m).replace(qpos=qpos, qvel=qvel)
        return d, sensor_init(sensors, qpos, qvel, jnp.zeros_like(qvel), key=k)

    return jax.vmap(one)(qpos0, qvel0, keys)


def _env_step(m, grobot, layout, sensors, upright_args, g, d, s, ok, t, k):
    ctrl = gait_control(g, grobot, t, d)
    d_next = mjx.step(m, d.replace(ctrl=ctrl))
    truth = foot_truth(layout, d_next)
    # Reading k: the state after the step and the force applied during it (module docstring).
    s, readings = sensor_step(sensors, s, d_next.qpos, d_next.qvel, d_next.qfrc_actuator, key=k)
    ok = ok & upright(d_next.qpos, *upright_args)
    return d_next, s, ok, (readings, truth.contact, truth.normal_force, truth.distance, ok)


@functools.partial(jax.jit, static_argnames=("dt", "chunk", "upright_args"))
def _run_chunk(
    m, grobot, layout, sensors, gaits, data, sstate, alive, t0, key, *, dt, chunk, upright_args
):
    n_envs = alive.shape[0]
    batched = jax.vmap(
        functools.partial(_env_step, m, grobot, layout, sensors, upright_args),
        in_axes=(0, 0, 0, 0, None, 0),
    )

    def body(carry, i):
        d, s, ok, kk = carry
        kk, sub = jax.random.split(kk)
        d, s, ok, out = batched(gaits, d, s, ok, t0 + i * dt, jax.random.split(sub, n_envs))
        return (d, s, ok, kk), out

    (d, s, ok, _), outs = jax.lax.scan(body, (data, sstate, alive, key), jnp.arange(chunk))
    return d, s, ok, outs
