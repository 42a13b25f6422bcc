"""Offline evaluation: replay sensor readings (simulated or logged) through the detectors.

Timing (one convention for :mod:`jax_contact.envs.simulate`, the wrapper and this replay): reading
``k`` is what the sensors give at the end of physics step ``k``: the state after the step
``(q_{k+1}, qd_{k+1})``, the acceleration over it, ``(qd_{k+1} - qd_k) / dt``, and the
actuation torque applied during it, ``tau_k``. The truth of step ``k`` is the contact
during that step. Every detector's output at ``k`` is available when reading ``k``
arrives and is scored against the truth of step ``k``; sensor latency (readings that are
``latency`` steps old, :mod:`jax_contact.envs.sensors`) is the only input lag, and it counts in
every reported delay.

Pairing of readings (``pairing="delayed"``, the default): the differenced acceleration of
reading ``k`` describes the interval that *starts* at ``q_k``, the state of reading
``k - 1`` (MuJoCo's semi-implicit Euler step ``qd_{k+1} = qd_k + dt qdd_k``; on a robot the
same half-step offset holds), and so does the torque of reading ``k``. The estimator's
dynamics at ``k`` are therefore evaluated at the state of reading ``k - 1`` with the
acceleration and torque of reading ``k``: one consistent sample of the equation of
motion, eq. (4). Pairing the
acceleration with the state of reading ``k`` instead (``pairing="raw"``) mixes two
instants: a swinging leg under PD control changes its velocity-dependent forces within a
step, and the dynamics term then called most air phases contact (ideal sensors, planar
leg: 79 % vs 99.9 % accuracy of the term alone). The baselines (GM observer, kinematic
detector) read no differenced acceleration and get reading ``k`` whole: the GM observer's
momentum change to ``qd_{k+1}`` is driven by ``tau_k``, the same interval.

Lost readings (NaN or inf, and a quaternion of norm near zero, read as NaN), with the
delayed pairing, entry by entry as the exported update
(:mod:`jax_contact.export`) takes them: a coordinate whose velocity in reading ``k`` is
lost has no acceleration over step ``k``, and a lost entry of reading ``k - 1``'s state is
replaced by reading ``k``'s own (as the first reading uses its own state). Each foot's step
is then invalid only where it reads a lost entry (docs/model.md, "Inputs per step").

:func:`replay` recomputes the estimator's inputs from the readings and the robot's nominal
model with the MJX adapter, one estimator step per reading, and runs, on the same inputs
in the same scan, any number of estimator variants (e.g. the ablations), generalized-
momentum observers and the kinematic threshold detector. Only (T, E, L) outputs are kept:
the per-leg inputs (an 18 x 18 mass matrix per leg and step) are never stored.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

import jax_contact as jc
from jax_contact.adapter import leg_measurements, prepare
from jax_contact.baselines import (
    GMParams,
    KinematicParams,
    check_gain,
    gm_init,
    gm_step,
    kinematic_detect,
)
from jax_contact.metrics import evaluate
from jax_contact.params import switches_of, without_switches

DIAGNOSTIC_FIELDS = (
    "p_contact",
    "p_dynamics",
    "p_diff_kinematics",
    "p_kinematics",
    "p_takeoff",
    "p_touchdown",
    "force",
)


def replay(
    robot,
    readings: Mapping[str, np.ndarray],
    *,
    estimators: Mapping[str, jc.EstimatorParams],
    terrain,
    gms: Mapping[str, GMParams] | None = None,
    kinematic: KinematicParams | Mapping[str, KinematicParams] | None = None,
    dt: float,
    seed: int = 0,
    diagnostics_of: str | None = None,
    pairing: str = "delayed",
    previous: Mapping[str, np.ndarray] | None = None,
    chunk: int = 400,
    progress: bool = True,
) -> dict[str, np.ndarray]:
    """Runs the detectors over a (T, E) batch of readings.

    Args:
      robot: the nominal :class:`jax_contact.envs.robots.Robot` (its model is the estimator's
      model). readings: ``qpos`` (T, E, nq), ``qvel``/``qacc``/``tau`` (T, E, nv).
      estimators: name -> estimator parameters; each runs its own filter.
      terrain: the estimator's terrain model (``jax_contact.terrain``).
      gms: name -> generalized-momentum observer parameters.
      kinematic: kinematic threshold detector parameters (output ``"kinematic"``), or
        name -> parameters (one output each, as ``gms``: a grid to tune on), or None.
      dt: period of the readings, s.
      seed: seeds the Monte-Carlo touch-down draws.
      diagnostics_of: an estimator name whose per-term diagnostics are also returned.
      pairing: ``"delayed"`` (the acceleration and torque of each reading with the state
        of the reading before; see the module docstring) or ``"raw"``.
      previous: ``qpos`` (E, nq) and ``qvel`` (E, nv) of the reading before ``readings[0]``
        (e.g. the sensors' reading of the initial state), the state the delayed pairing
        gives the first acceleration. Without it the first reading's own state is used.
      chunk: readings per compiled scan.
      progress: print progress to stderr.

    Returns:
      name -> (T, E, L) array: each estimator's P(contact), each GM observer's and
      kinematic detector's contact flag (as float 0/1), ``"gm_force/<name>"`` normal forces,
      and ``"<estimator>/<field>"`` for every diagnostic field of ``diagnostics_of``
      (:data:`DIAGNOSTIC_FIELDS`; ``force`` is (T, E, L, 3), world frame, N),
      ``"<estimator>/valid"`` the estimator's input-validity flag.
    """
    for arg, value, kind in (("estimators", estimators, "EstimatorParams"),
                             ("gms", gms, "GMParams")):  # fmt: skip
        if value is not None and not isinstance(value, Mapping):
            raise ValueError(
                f"{arg} must be a mapping name -> {kind} (e.g. {{'estimate': params}}), got"
                f" {type(value).__name__}"
            )
    gms = dict(gms or {})
    if kinematic is None:
        kinematic = {}
    elif isinstance(kinematic, KinematicParams):
        kinematic = {"kinematic": kinematic}
    else:
        kinematic = dict(kinematic)
    _check_output_names(estimators, gms, kinematic)
    if pairing not in ("delayed", "raw"):
        raise ValueError(f"pairing must be 'delayed' or 'raw', got {pairing!r}")
    if diagnostics_of is not None and diagnostics_of not in estimators:
        raise ValueError(
            f"diagnostics_of {diagnostics_of!r} is not one of estimators {list(estimators)}"
        )
    for name, params in estimators.items():
        # Another period's gait prior, sigma_qdd and caps would run silently.
        if not np.isclose(float(params.dt), float(dt), rtol=1e-4):
            raise ValueError(
                f"estimators[{name!r}] has dt={float(params.dt):g} s but the readings' period"
                f" is dt={float(dt):g} s: move the parameters to it"
                " (jax_contact.params_file.load_params_for)"
            )
    for name, gp in gms.items():
        # Checked here, before the jitted replay, where gm_batch's own check sees tracers.
        check_gain(gp.K_I, dt, owner=f"gms[{name!r}]")
    _check_readings(readings, robot)
    qpos, qvel, qacc, tau = (np.asarray(readings[k]) for k in ("qpos", "qvel", "qacc", "tau"))
    # A quaternion of norm near zero (a driver's zero fill) is lost, NaN, as the exported
    # estimator reads it; replay read it as an orientation, P up to 0.75 from the export's
    # for 15 steps (a helper's audit; the log and recording loaders set it already). In a
    # copy: the caller's readings stay as they were.
    from jax_contact.train.recording_checks import lose_degenerate_quaternions

    qpos = qpos.copy()
    lose_degenerate_quaternions(qpos, robot.mj_model)
    # The baselines read no differenced acceleration, so they get each reading when it
    # arrives (no delayed pairing): scored on what they would use on the robot.
    raw = (qpos, qvel, qacc, tau)
    if pairing == "delayed":
        first = None
        if previous is not None:
            first = {k: np.asarray(previous[k])[None] for k in ("qpos", "qvel")}
            for k in ("qpos", "qvel"):
                if first[k].shape[1:] != readings[k].shape[1:]:
                    raise ValueError(
                        f"previous[{k!r}] has shape {first[k].shape[1:]}, expected"
                        f" {readings[k].shape[1:]} (one reading of every env)"
                    )
        qpos, qvel, qacc = pair_delayed(qpos, qvel, qacc, first)
    n_t, n_envs = qpos.shape[:2]
    m = mjx.put_model(robot.mj_model)
    desc = robot.description
    template = mjx.make_data(m)
    models = (m, template, dict(estimators), terrain, gms, kinematic)
    kw = dict(desc=desc, dt=jnp.float32(dt), diagnostics_of=diagnostics_of)
    separate = pairing != "raw" and bool(gms or kinematic)
    kw["separate_baselines"] = separate
    first = tuple(jnp.asarray(np.nan_to_num(a[0])) for a in (qpos, qvel, qacc, tau))
    beliefs, gm_states = _replay_init(*models, first, **kw)
    # Committed like the chunk's outputs, or jit would compile the chunk a second time.
    carry = jax.device_put((beliefs, gm_states, jax.random.key(seed)), jax.devices()[0])
    from jax_contact.train import progress as pg

    pieces = []
    starts = range(0, n_t, chunk)
    for start in pg.bar(starts, desc=f"replay ({n_t} steps)", unit="chunk", enabled=progress):
        stop = min(start + chunk, n_t)
        arrays = (qpos, qvel, qacc, tau) + (raw if separate else ())
        xs = tuple(jnp.asarray(_pad(a[start:stop], chunk)) for a in arrays)
        carry, out = _replay_chunk(*models, carry, xs, **kw)
        pieces.append({k: np.asarray(v)[: stop - start] for k, v in out.items()})
    return {k: np.concatenate([p[k] for p in pieces], axis=0) for k in pieces[0]}


def _check_readings(readings: Mapping, robot) -> None:
    """``readings`` hold ``qpos`` (T, E, nq) and ``qvel``, ``qacc``, ``tau`` (T, E, nv) of
    ``robot``'s model, over one (T, E).

    Raises:
      ValueError: naming the missing keys, or the array, its shape and the one expected.
    """
    keys = ("qpos", "qvel", "qacc", "tau")
    if missing := [k for k in keys if k not in readings]:
        raise ValueError(
            f"readings lack {missing}: replay needs qpos (T, E, nq) and qvel, qacc, tau"
            f" (T, E, nv), got keys {sorted(readings)[:8]}"
        )
    m = robot.mj_model
    lead = np.shape(readings["qpos"])[:2]
    for k in keys:
        shape = np.shape(readings[k])
        n = m.nq if k == "qpos" else m.nv
        if len(shape) != 3 or shape[2] != n or shape[:2] != lead:
            raise ValueError(
                f"readings[{k!r}] has shape {shape}; expected (T, E, {n}) for robot"
                f" {robot.name!r} ({'nq' if k == 'qpos' else 'nv'} = {n}; one env: add the"
                " axis, readings[k][:, None])"
            )


def _check_output_names(estimators: Mapping, gms: Mapping, kinematic: Mapping) -> None:
    """Every detector's name is an output key of :func:`replay`: the three sets must not
    share one (the later detector's output would replace the earlier's without a word),
    and no name may hold ``/`` (the diagnostics' ``<estimator>/<field>`` and GM's
    ``gm_force/<name>`` keys).

    Raises:
      ValueError: naming the argument and the name.
    """
    seen: dict[str, str] = {}
    for arg, names in (("estimators", estimators), ("gms", gms), ("kinematic", kinematic)):
        for name in names:
            if not isinstance(name, str) or not name or "/" in name:
                raise ValueError(
                    f"{arg}: detector name {name!r} must be a non-empty str without '/'"
                )
            if name in seen:
                raise ValueError(
                    f"{arg} and {seen[name]} both name a detector {name!r}: each name is one"
                    " output of replay"
                )
            seen[name] = arg


def _measure_batch(m, template, desc, qpos, qvel, qacc, tau):
    """(E, ...) readings -> LegMeasurement with leaves (E, L, ...), at the measured state."""

    def one(qp, qv, qa, ta):
        d = prepare(m, template.replace(qpos=qp, qvel=qv))
        return leg_measurements(m, d, desc, qdd=qa, tau=ta, include_passive=True)

    return jax.vmap(one)(qpos, qvel, qacc, tau)


# ``dt`` is traced, not static: one compiled program serves every rate (recordings whose
# clocks differ by float noise, or 200 and 400 Hz logs of one robot).
_STATIC = ("desc", "diagnostics_of", "separate_baselines")


def _groups(tree: Mapping) -> list[list[str]]:
    """Names of ``tree`` (name -> params pytree) grouped by pytree structure, in order.

    Variants whose parameters differ only in values (every field a traced array, the static
    fields equal) share one group, and :func:`_replay_chunk` runs a group as one ``vmap``
    over its stacked parameters: one copy of the estimator in the compiled program per
    structure instead of one per variant. Estimators are grouped with their four
    structural switches taken out as data (:func:`jax_contact.params.without_switches`,
    ``Switches``), so the reproduction's 15 ablation variants are one structure (they were
    seven: the Go1 replay's cold compile 90 -> 49 s, docs/performance.md), its GM grid
    another. Results equal a loop over the variants up to float rounding (same keys).
    """
    by_def: dict = {}
    for name, params in tree.items():
        by_def.setdefault(jax.tree.structure(params), []).append(name)
    return list(by_def.values())


def _canonical(estimators: Mapping) -> dict:
    """Each estimator's parameters with its switches at their defaults (see _groups)."""
    return {n: without_switches(p) for n, p in estimators.items()}


def _stack(tree: Mapping, names: list[str]):
    return jax.tree.map(
        lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *(tree[n] for n in names)
    )


@functools.partial(jax.jit, static_argnames=_STATIC)
def _replay_init(
    m,
    template,
    estimators,
    terrain,
    gms,
    kinematic,
    x0,
    *,
    desc,
    dt,
    diagnostics_of,
    separate_baselines,
):
    del terrain, kinematic, dt, diagnostics_of, separate_baselines
    meas0 = _measure_batch(m, template, desc, *x0)
    n_envs, n_legs = meas0.p_f.shape[:2]
    beliefs = {n: jc.init_belief_batch(p, n_envs, n_legs) for n, p in estimators.items()}
    gm_states = {n: jax.vmap(jax.vmap(gm_init))(meas0) for n in gms}
    # Carried stacked by group (see _groups), as _replay_chunk's vmaps take them.
    return (
        [_stack(beliefs, g) for g in _groups(_canonical(estimators))],
        [_stack(gm_states, g) for g in _groups(gms)],
    )


@functools.partial(jax.jit, static_argnames=_STATIC)
def _replay_chunk(
    m,
    template,
    estimators,
    terrain,
    gms,
    kinematic,
    carry,
    xs,
    *,
    desc,
    dt,
    diagnostics_of,
    separate_baselines,
):
    normal = jnp.array([0.0, 0.0, 1.0])
    canonical = _canonical(estimators)
    switches = {n: switches_of(p) for n, p in estimators.items()}
    est_groups, gm_groups = _groups(canonical), _groups(gms)
    # Each group's parameters stacked along a leading variant axis (traced once per chunk).
    est_stacked = [(_stack(canonical, g), _stack(switches, g)) for g in est_groups]
    gm_stacked = [_stack(gms, g) for g in gm_groups]
    order = list(estimators)  # the keys are split in this order, as a loop would

    def gm_one(gp, st, ms):
        return jax.vmap(jax.vmap(lambda s, m_: gm_step(gp, s, m_, dt, normal)))(st, ms)

    def one_step(carry, inputs):
        beliefs, gm_states, key = carry
        meas = _measure_batch(m, template, desc, *inputs[:4])
        base_meas = _measure_batch(m, template, desc, *inputs[4:]) if separate_baselines else meas
        subs = {}
        for name in order:
            key, subs[name] = jax.random.split(key)
        out = {}
        new_beliefs = []
        for names, (params, sw), b_in in zip(est_groups, est_stacked, beliefs, strict=True):
            k_in = jnp.stack([subs[n] for n in names])
            b, diag = jax.vmap(
                lambda p, s, bl, k: jc.step_batch(p, terrain, bl, meas, key=k, switches=s)
            )(params, sw, b_in, k_in)
            new_beliefs.append(b)
            for i, name in enumerate(names):
                out[name] = diag.p_contact[i]
                if name == diagnostics_of:
                    for field in DIAGNOSTIC_FIELDS[1:]:
                        out[f"{name}/{field}"] = getattr(diag, field)[i]
                    out[f"{name}/valid"] = diag.valid[i]
        new_gm = []
        for names, gp, st in zip(gm_groups, gm_stacked, gm_states, strict=True):
            s, o = jax.vmap(gm_one, in_axes=(0, 0, None))(gp, st, base_meas)
            new_gm.append(s)
            for i, name in enumerate(names):
                out[name] = o.contact[i].astype(jnp.float32)
                out[f"gm_force/{name}"] = o.force_normal[i]
        if kinematic:
            # The terrain below each foot, queried once per step for every setting.
            below = jax.vmap(
                jax.vmap(lambda ms: terrain.query(ms.p_f, jnp.zeros(3), jnp.array(False)))
            )(base_meas)
            for name, kp in kinematic.items():
                flag = jax.vmap(
                    jax.vmap(lambda ms, tq, kp=kp: kinematic_detect(kp, ms, tq).contact)
                )
                out[name] = flag(base_meas, below).astype(jnp.float32)
        return (new_beliefs, new_gm, key), out

    return jax.lax.scan(one_step, carry, xs)


def delay_one_step(a: np.ndarray, first: np.ndarray | None = None) -> np.ndarray:
    """``a`` shifted one step later along time; ``first`` (1, ...) or else ``a[:1]`` leads."""
    lead = a[:1] if first is None else np.asarray(first, a.dtype)
    return np.concatenate([lead, a[:-1]], axis=0)


def pair_delayed(qpos, qvel, qacc, first: Mapping[str, np.ndarray] | None = None):
    """The delayed pairing (module docstring): each reading's acceleration with the state of
    the reading before, lost readings taken entry by entry as the exported update takes them.

    Args:
      qpos: (T, ..., nq), qvel, qacc: (T, ..., nv) readings.
      first: ``qpos`` and ``qvel`` (1, ..., n) of the reading before ``qpos[0]``; None: the
        first reading's own state.

    Returns:
      (qpos, qvel, qacc) for the estimator: the state one reading late (a lost entry replaced
      by the reading's own), the acceleration NaN where the reading's velocity is lost.
    """
    first = first or {}
    delayed = {k: delay_one_step(x, first.get(k)) for k, x in (("qpos", qpos), ("qvel", qvel))}
    return (
        np.where(np.isfinite(delayed["qpos"]), delayed["qpos"], qpos),
        np.where(np.isfinite(delayed["qvel"]), delayed["qvel"], qvel),
        np.where(np.isfinite(qvel), qacc, np.nan),
    )


def _pad(a: np.ndarray, n: int) -> np.ndarray:
    """Pads the time axis to ``n`` by repeating the last entry, so one compile serves all."""
    if a.shape[0] == n:
        return a
    return np.concatenate([a, np.repeat(a[-1:], n - a.shape[0], axis=0)], axis=0)


def score(
    outputs: Mapping[str, np.ndarray],
    truth: np.ndarray,
    valid: np.ndarray,
    *,
    dt: float,
    names: list[str] | None = None,
    truth_known: np.ndarray | None = None,
) -> dict[str, dict]:
    """Metrics of each detector's output against ground truth, as plain dicts.

    Args:
      outputs: from :func:`replay`.
      truth: (T, E, L) bool ground-truth contact.
      valid: (T, E) bool env validity, broadcast over legs; or (T, E, L) per foot.
      dt: period, s.
      names: which outputs to score (default: every P(contact) and flag output).
      truth_known: None (= ``valid``) or the steps whose truth is known, shaped as
        ``valid``; it holds every valid step. Invalid steps of known truth (a foot's lost
        readings in a recording) do not cut the true air phases
        (:mod:`jax_contact.metrics`, rules 7b and 8).
    """

    def per_foot(mask):
        mask = np.asarray(mask)
        return mask if mask.shape == truth.shape else np.broadcast_to(mask[..., None], truth.shape)

    valid = per_foot(valid)
    known = None if truth_known is None else per_foot(truth_known)
    names = names or [k for k in outputs if "/" not in k]
    scores = {}
    for n in names:
        scores[n] = evaluate(outputs[n], truth, valid, dt=dt, truth_known=known).as_dict()
        scores[n]["is_flag"] = is_flag(outputs[n])
    return scores


def is_flag(p) -> bool:
    """Whether an output is a 0/1 flag (GM, the kinematic detector), not a probability:
    its ECE and Brier score are then ``1 - accuracy`` and say nothing of calibration."""
    p = np.asarray(p)
    return bool(np.all((p == 0) | (p == 1) | np.isnan(p)))
