"""The shipped presets (``jax_contact/presets/*.json``): how each is made and how it is judged.

- :func:`simulate_log` writes one scenario of ``jax_contact.train.reproduce`` (Table III's
  trot, walk, walk with added mass, rough ground) as a log with ground truth, from the
  world of :func:`scenario_world`.
- :func:`regenerate_preset` rebuilds a preset: tuning logs of seed 1000, validation logs
  of seed 1001 (never the evaluation seed 0), ``jax-contact tune`` with the robot's
  settings (:data:`PRESET_EVENT_WEIGHTS`, :data:`PRESET_TUNE_ALSO`, :data:`PRESET_EXTRA`)
  and its calibration.
- :func:`recalibrate_preset` refits only a preset's calibration map on its tuning logs
  (docs/tuning.md, rule 14), leaving the tuned values as they are.
- :func:`compare` replays the evaluation logs with the defaults and any parameter files
  and scores every Table III cell and ECE (docs/tuning.md's tables); with ``bootstrap`` it
  also says which differences exceed what re-running the rollouts would produce
  (:mod:`jax_contact.bootstrap`).

Standard library only at import, like the command line (``jax_contact.train.cli``).
"""

from __future__ import annotations

from pathlib import Path

from jax_contact.train.tune_data import default_params, read_truth_log

# The scenarios of jax_contact.train.reproduce (Table III): gait, terrain and added mass of each.
SCENARIOS = {
    "trot": ("trot", "flat", False),
    "walk": ("walk", "flat", False),
    "walk_added_mass": ("walk", "flat", True),
    "rough": ("walk", "rough", False),
}
PRESET_ROBOTS = ("go1", "spot", "barkour")
PRESET_TUNE = (("trot", 1000), ("walk", 1000))  # (scenario, seed) of the tuning logs
PRESET_VALIDATE = (("trot", 1001), ("walk", 1001))
# The event term's weight per preset, chosen on each robot's validation seed 1001
# (docs/tuning.md, "Event weight and contact damping" and "Retuned with the sliding
# contact"): among Go1 {0.1, 0.3, 1}, Spot {0.1, 0.3, 1}, Barkour {0.3, 1, 3}, a weight
# whose validation cells are all within a measurement tolerance of the defaults' (Go1's
# 0.3), else the one worse in the fewest cells, ties to the lower validation BCE.
PRESET_EVENT_WEIGHTS = {"go1": 0.3, "spot": 0.1, "barkour": 1.0}
# Optional fields a preset also tunes (same page): contact_damping where tuning it lowered
# the validation loss without more worse cells or +0.5 points of air-phase failures.
PRESET_TUNE_ALSO = {"spot": ("contact_damping",), "barkour": ("contact_damping",)}
# More `jax-contact tune` arguments per preset (docs/tuning.md, rules 12 and 13): each file keeps
# the lowest-loss epoch with no validation cell worse than the defaults beyond the spread,
# fitted with the cells' smooth stand-ins in the objective (Barkour's inside the x8
# plausibility box).
_RULE_12 = ("--select", "spread", "--patience", "12", "--constrain", "0.1")
PRESET_EXTRA = {"spot": _RULE_12, "barkour": (*_RULE_12, "--noise-ratio", "8.0")}
# Presets tuned on one gait's logs only, with their robot's settings (docs/tuning.md,
# "Per-gait presets"): preset name -> (robot, scenarios of PRESET_TUNE kept).
PRESET_GAITS = {
    "spot_walk": ("spot", ("walk",)),
    "barkour_trot": ("barkour", ("trot",)),
    "barkour_walk": ("barkour", ("walk",)),
    "go1_walk": ("go1", ("walk",)),
}


def preset_plan(name: str) -> tuple[str, tuple, tuple]:
    """(robot, tuning logs, validation logs) of preset ``name``: the (scenario, seed) pairs
    of :data:`PRESET_TUNE` and :data:`PRESET_VALIDATE`, those of its gait for a
    :data:`PRESET_GAITS` preset."""
    robot, scenarios = PRESET_GAITS.get(name, (name, None))

    def keep(keys):
        return tuple(k for k in keys if scenarios is None or k[0] in scenarios)

    return robot, keep(PRESET_TUNE), keep(PRESET_VALIDATE)


def preset_path(robot: str) -> Path:
    """The shipped preset file of ``robot`` in this checkout (what regenerate and
    recalibrate write by default)."""
    return Path(__file__).resolve().parents[1] / "jax_contact" / "presets" / f"{robot}.json"


def scenario_world(robot: str, scenario: str, seed: int = 0):
    """(world, gait kind, forward speed range) of one scenario of ``jax_contact.train.reproduce``
    at ``seed`` (the rough floor's): what :func:`jax_contact.envs.simulate.simulate` needs
    besides the sensors and sizes."""
    from jax_contact.train import reproduce

    gait, _, _ = SCENARIOS[scenario]
    cfg = reproduce.ReproduceConfig(robot=robot, seed=seed)
    world = reproduce.scenario_world_of(scenario, cfg)
    return world, gait, reproduce.SPEEDS.get(gait, (0.0, 0.0))


def simulate_log(
    path: str | Path,
    robot: str,
    scenario: str,
    seed: int,
    *,
    n_envs: int = 16,
    duration: float = 8.0,
    noise: str = "anymal_like",
) -> Path:
    """Simulates one scenario of ``jax_contact.train.reproduce`` (its world, gait, speed range and
    sensors) and writes it as a log (the schema of ``jax-contact simulate``)."""
    from jax_contact.envs.gaits import make_gait
    from jax_contact.envs.simulate import simulate
    from jax_contact.io import write_log
    from jax_contact.train import reproduce
    from jax_contact.train.logs import READING_TIMING

    world, gait, speeds = scenario_world(robot, scenario, seed)
    roll = simulate(world, make_gait(gait), noise, n_envs, duration, seed, speed_range=speeds)
    cfg = reproduce.ReproduceConfig(robot=robot)
    attrs = {
        "robot": robot,
        "gait": gait,
        "scenario": scenario,
        "noise": noise,
        "terrain": world.terrain,
        "roughness": world.roughness,
        "added_mass": [list(x) for x in world.added_mass],
        "speed_range": list(speeds),
        "seed": seed,
        "dt": world.dt,
        "rate_hz": 1.0 / world.dt,
        "n_envs": n_envs,
        # The nominal robot's names (load_log resolves them), as simulate_to_file stores:
        # the simulated world calls Barkour's unnamed foot geoms gt_foot<i>.
        "foot_names": list(reproduce.robot_of(cfg).description.foot_names),
        "reading_timing": READING_TIMING,
    }
    return write_log(path, roll.to_arrays(), attrs)


def regenerate_preset(
    name: str,
    out: str | Path | None = None,
    *,
    workdir: str | Path = "/tmp/jax-contact-presets",
    n_envs: int = 16,
    duration: float = 8.0,
    air_penalty: float = 0.0,
    event_weight: float | None = None,
    extra: tuple[str, ...] = (),
) -> int:
    """Rebuilds a shipped preset: simulates the tuning and validation logs (Go1-style
    trot and walk, seeds 1000 and 1001, never the evaluation seed 0) into ``workdir`` unless
    they are there, tunes with the default settings (BCE plus the air-phase event term of
    weight ``event_weight``, by default the robot's :data:`PRESET_EVENT_WEIGHTS` or 0.3;
    the optional fields of :data:`PRESET_TUNE_ALSO` too, and :data:`PRESET_EXTRA`'s
    arguments;
    ``air_penalty`` adds the per-step hinge of the previous
    session; ``extra`` more arguments of ``jax-contact tune``) and ``--calibrate``, and
    writes ``jax_contact/presets/<name>.json`` (or ``out``). ``name`` is a robot, or a
    :data:`PRESET_GAITS` preset (its robot's settings, its gait's logs only).

    ``python -c "from jax_contact.train.tune_cmd import regenerate_preset as r; r('go1')"``
    """
    robot, tune_keys, val_keys = preset_plan(name)
    logs = _preset_logs(robot, Path(workdir), n_envs, duration, tune_keys + val_keys)
    if out is None:
        out = preset_path(name)
    argv = [logs[k] for k in tune_keys] + ["--validate"] + [logs[k] for k in val_keys]
    note = (
        f'regenerate: python -c "from jax_contact.train.tune_cmd import regenerate_preset as r;'
        f" r('{name}')\" (logs: {n_envs} envs x {duration:g} s of jax_contact.train.reproduce's"
        f" scenarios, anymal_like sensors)"
    )
    if event_weight is None:
        event_weight = PRESET_EVENT_WEIGHTS.get(robot, 0.3)
    more = ["--air-penalty", str(air_penalty), "--event-weight", str(event_weight)]
    if PRESET_TUNE_ALSO.get(robot):
        more += ["--tune-also", *PRESET_TUNE_ALSO[robot]]
    more += [*PRESET_EXTRA.get(robot, ()), *extra]
    from jax_contact.train.tune_cmd import main

    return main([*argv, "--out", str(out), "--calibrate", "sign", *more, "--note", note])


def _preset_logs(
    robot: str, workdir: Path, n_envs: int, duration: float, keys=PRESET_TUNE + PRESET_VALIDATE
) -> dict:
    """(scenario, seed) -> path of the tuning and validation logs ``keys``, simulated
    unless there (at this size: the name holds it, so a log of another size is not
    taken for it)."""
    logs = {}
    for scenario, seed in keys:
        path = workdir / f"{robot}_{scenario}_s{seed}_{n_envs}x{duration:g}s.h5"
        if not path.is_file():
            simulate_log(path, robot, scenario, seed, n_envs=n_envs, duration=duration)
        logs[(scenario, seed)] = str(path)
    return logs


def recalibrate_preset(
    name: str,
    out: str | Path | None = None,
    *,
    kind: str = "sign",
    workdir: str | Path = "/tmp/jax-contact-presets",
    n_envs: int = 16,
    duration: float = 8.0,
) -> dict:
    """Refits a shipped preset's calibration map (``kind``,
    :func:`jax_contact.tune.fit_calibration`) on its tuning logs and rewrites the file's
    ``provenance["calibration"]`` (``name``: as :func:`regenerate_preset`'s); nothing
    else in the file changes (the tuned values are
    copied as text). The map it replaces is kept under ``"replaced"``.

    ``python -c "from jax_contact.train.tune_presets import recalibrate_preset as r; r('go1')"``

    Returns:
      The new ``provenance["calibration"]``.
    """
    import json

    from jax_contact.io import write_json_atomic
    from jax_contact.params_file import params_from_dict
    from jax_contact.train.tune_cmd import calibration_entry, code_version
    from jax_contact.train.tune_data import load_tuning_log

    robot, tune_keys, val_keys = preset_plan(name)
    path = preset_path(name)
    payload = json.loads(path.read_text())
    params, prov = params_from_dict(payload, source=str(path)), payload["provenance"]
    logs = _preset_logs(robot, Path(workdir), n_envs, duration, tune_keys + val_keys)
    model = prov.get("terrain_model") or "flat"
    train, vals, terrain = [], [], None
    for key in tune_keys:
        data, _, _, _, terrain = load_tuning_log(logs[key], model)
        train.append(data)
    vals = [load_tuning_log(logs[key], model)[0] for key in val_keys]
    entry = calibration_entry(
        params, terrain, train, vals, [logs[k] for k in tune_keys],
        kind=kind, seed=int(prov["seeds"]["tune"]),
    )  # fmt: skip
    entry["refitted_by"] = {
        "command": f"jax_contact.train.tune_presets.recalibrate_preset({name!r}, kind={kind!r})",
        "code": code_version(),
    }
    if prov.get("calibration") is not None:
        entry["replaced"] = {k: v for k, v in prov["calibration"].items() if k != "replaced"}
    payload["provenance"]["calibration"] = entry
    out = path if out is None else out
    write_json_atomic(out, payload)
    print(f"wrote {out}")
    return entry


def compare(
    robot: str,
    variants: dict,
    *,
    scenarios=("trot", "walk", "walk_added_mass", "rough"),
    seed: int = 0,
    n_envs: int = 16,
    duration: float = 8.0,
    workdir: str | Path = "/tmp/jax-contact-presets",
    plots: str | Path | None = None,
    bootstrap: int = 0,
    reference: str | None = None,
) -> dict:
    """Default vs tuned parameters on the evaluation scenarios (docs/tuning.md's tables).

    Simulates (or reuses from ``workdir``) each scenario's log of ``seed``, replays it with
    every variant on the same inputs (``jax_contact.train.evaluate.replay``) and scores it. A
    variant whose file holds a calibration map also gets a ``<name>+cal`` row: its P(contact)
    mapped by it (flag at calibrated P > 0.5: the raw flag for a per-side map, rule 14).

    Args:
      robot: the robot simulated and evaluated.
      variants: row name -> parameter file or preset name, or None for the defaults, or a
        pair (one of those, terrain model); without a terrain model a file runs on the one
        it was tuned with (:func:`jax_contact.train.log_estimator.file_terrain_model`), the defaults
        on the plane.
      plots: a folder for one reliability diagram per scenario, or None.
      bootstrap: if > 0, the number of env resamples of a paired bootstrap
        (:func:`jax_contact.bootstrap.paired_bootstrap`, 95 %, seed 0) of every other row
        against ``reference``: is each difference larger than re-running the rollouts
        would make it?
      reference: the row the others are compared with (default: the first variant).

    Returns:
      scenario -> row -> metrics (``jax_contact.train.evaluate.score``'s dicts); with
      ``bootstrap``, every row but the reference also has ``"vs_reference"``: statistic ->
      ``[delta, low, high, verdict]`` (:meth:`jax_contact.bootstrap.Difference.as_list`).
    """

    from jax_contact import tune as jt
    from jax_contact.bootstrap import STATISTICS, row_differences
    from jax_contact.robot import model_mass
    from jax_contact.train.calibration import reliability_diagram
    from jax_contact.train.evaluate import replay, score
    from jax_contact.train.log_estimator import file_terrain_model, load_params_for, terrain_for
    from jax_contact.train.logs import log_noise

    def terrain_model_of(source) -> tuple[object, str]:
        if isinstance(source, tuple):
            return source
        return source, (file_terrain_model(source) if source is not None else None) or "flat"

    sources = {name: terrain_model_of(source) for name, source in variants.items()}
    reference = next(iter(variants)) if reference is None else reference
    if bootstrap and reference not in variants:
        raise ValueError(f"reference {reference!r} is not a variant: {list(variants)}")
    results = {}
    for scenario in scenarios:
        path = Path(workdir) / f"{robot}_{scenario}_s{seed}.h5"
        if not path.is_file():
            simulate_log(path, robot, scenario, seed, n_envs=n_envs, duration=duration)
        readings, truth, valid, attrs, robo = read_truth_log(path)
        dt = float(attrs["dt"])
        base, plane = default_params(robo, dt, log_noise(attrs))
        out, cals = {}, {}
        # One replay per terrain model (the replay runs every estimator on one terrain).
        for model in dict.fromkeys(m for _, m in sources.values()):
            estimators = {}
            for name, (source, m) in sources.items():
                if m != model:
                    continue
                if source is None:
                    estimators[name] = base
                    continue
                # evaluate's route: checked against the robot, moved to the log's period.
                params, prov = load_params_for(
                    source, robo.description, dt, model_mass(robo.mj_model),
                    with_provenance=True, mj_model=robo.mj_model, robot=robot,
                )  # fmt: skip
                estimators[name] = params
                if (cal := jt.calibration_of(prov)) is not None:
                    cals[name] = cal
            out.update(
                replay(
                    robo, readings, estimators=estimators, terrain=terrain_for(plane, model),
                    dt=dt, seed=seed, progress=False,
                )
            )  # fmt: skip
        for name, cal in cals.items():
            out[f"{name}+cal"] = jt.calibrate_probability(out[name], cal)
        results[scenario] = score(out, truth, valid, dt=dt)
        if bootstrap:
            for name in results[scenario]:
                if name == reference:
                    continue
                vs = row_differences(
                    out, name, {reference: tuple(STATISTICS)}, truth, valid,
                    dt=dt, n_resamples=bootstrap,
                )  # fmt: skip
                results[scenario][name]["vs_reference"] = vs[reference]
        if plots is not None:
            reliability_diagram(
                out, truth, valid, Path(plots) / f"reliability_{robot}_{scenario}.png",
                title=f"{robot} {scenario}, seed {seed}: reliability of P(contact)",
            )  # fmt: skip
        print(format_comparison({scenario: results[scenario]}), flush=True)
    return results


_SHORT = {
    "f1": "F1",
    "accuracy": "acc",
    "air_phase_failure_rate": "fail",
    "touchdown_delay_ms": "TD",
    "liftoff_delay_ms": "LO",
    "ece": "ECE",
}


def _verdict_cell(vs: dict | None) -> str:
    if vs is None:
        return "reference"
    sides = {"better": [], "worse": []}
    for key, (_, _, _, verdict) in vs.items():
        if verdict in sides:
            sides[verdict].append(_SHORT.get(key, key))
    text = "; ".join(f"{side} {', '.join(keys)}" for side, keys in sides.items() if keys)
    return text or "within noise"


def format_comparison(results: dict) -> str:
    """A Markdown table: scenario x row, the Table III cells and ECE (and, for a comparison
    with ``bootstrap``, which cells differ from the reference beyond the rollouts' spread)."""
    boot = any("vs_reference" in m for rows in results.values() for m in rows.values())
    head = "| scenario | params | F1 | acc | air-phase fail | TD delay ms | LO delay ms | ECE |"
    rule = "|---|---|---|---|---|---|---|---|"
    if boot:
        head, rule = head + " vs reference (95 %, env bootstrap) |", rule + "---|"
    lines = [head, rule]
    for scenario, rows in results.items():
        for name, m in rows.items():
            td, lo = m["touchdown_delay_ms"], m["liftoff_delay_ms"]
            lines.append(
                f"| {scenario} | {name} | {m['f1']:.3f} | {m['accuracy']:.3f} |"
                f" {100 * m['air_phase_failure_rate']:.1f} % | {td[0]:.1f} ± {td[1]:.1f} |"
                f" {lo[0]:.1f} ± {lo[1]:.1f} | {m['ece']:.3f} |"
                + (f" {_verdict_cell(m.get('vs_reference'))} |" if boot else "")
            )
    return "\n".join(lines)
