"""Table III's report: each cell as ``table3.json`` stores it, the printed tables, the
legend and the bootstrap's comparison lines.

:mod:`jax_contact.train.reproduce` computes the scores; this module turns them into what it
writes and prints, and ``jax-contact evaluate`` (:func:`jax_contact.train.report.format_scores`)
prints its table with the same columns.
"""

from __future__ import annotations

import textwrap

import numpy as np

# The row of the robot's tuned parameter file (a shipped preset or --params).
TUNED_ROW = "tuned"

VS_GM_STATISTICS = (
    "f1",
    "accuracy",
    "air_phase_failure_rate",
    "swing_phase_failure_rate",
    "swing_phase_flag_on_rate",
)


def vs_gm(out: dict, truth, valid, dt: float, n_resamples: int) -> dict | None:
    """Issue 13's "better than both GM tunings": ``probabilistic - gm_*`` (the F1-tuned rows
    and, where the run has them, the rows ``*_fl``) of F1, accuracy, the air- and
    swing-phase failure rates and sw-on with their 95 % paired env-bootstrap intervals
    (:func:`jax_contact.bootstrap.paired_bootstrap`, seed 0), or None for ``n_resamples`` 0.

    Returns:
      ``gm_walk`` / ``gm_trot`` (and ``gm_walk_fl`` / ``gm_trot_fl``) -> statistic ->
      ``[delta, low, high, verdict]``.
    """
    if not n_resamples:
        return None
    from jax_contact.bootstrap import row_differences

    gms = {gm: VS_GM_STATISTICS for gm in _gm_rows(out)}
    return row_differences(out, "probabilistic", gms, truth, valid, dt=dt, n_resamples=n_resamples)


def _gm_rows(out: dict) -> tuple[str, ...]:
    """Both GM tunings, and their failure-limited picks where the run has them."""
    return tuple(g for g in ("gm_walk", "gm_trot", "gm_walk_fl", "gm_trot_fl") if g in out)


def tuned_vs(out: dict, truth, valid, dt: float, n_resamples: int) -> dict | None:
    """The row ``tuned`` against both GM tunings (as :func:`vs_gm`) and against the
    defaults (``probabilistic``: every statistic of :data:`jax_contact.bootstrap.STATISTICS`,
    issue 15's "every cell at least as good"), or None for ``n_resamples`` 0."""
    if not n_resamples:
        return None
    from jax_contact.bootstrap import STATISTICS, row_differences

    others = {gm: VS_GM_STATISTICS for gm in _gm_rows(out)}
    others["probabilistic"] = tuple(STATISTICS)
    return row_differences(out, TUNED_ROW, others, truth, valid, dt=dt, n_resamples=n_resamples)


def format_vs_gm(payload: dict) -> str:
    """The printed lines of :func:`vs_gm` and :func:`tuned_vs` (empty without them)."""
    from jax_contact.bootstrap import format_intervals

    lines = []
    for key, row in (("vs_gm", "probabilistic"), ("tuned_vs", TUNED_ROW)):
        vs = payload.get(key)
        if not vs:
            continue
        lines.append(f"{row} - other row, 95 % interval of a paired env bootstrap:")
        for name, per_row in vs.items():
            for other, stats in per_row.items():
                other = "defaults" if other == "probabilistic" else other
                lines.append(f"  {name:16s} vs {other:8s} {format_intervals(stats)}")
    return "\n".join(lines)


def input_lag_ms(dt: float, noise: str = "anymal_like") -> float:
    """The sensors' latency, ms: how old each reading is when the detectors get it.

    Every detector gets the same readings, so it is the same for all, and it is included
    in every reported delay (delays count from the step of the true event to the first
    step whose output detects it).
    """
    from jax_contact.envs.sensors import sensor_preset

    return 1e3 * dt * sensor_preset(noise, 6, dt=dt).latency


def _pair(x) -> list[float]:
    return [float(x[0]), float(x[1])]


def cell(s: dict) -> dict:
    """One detector's metrics on one scenario, as ``table3.json`` stores them."""
    return {
        "touchdown_delay_ms": _pair(s["touchdown_delay_ms"]),
        "liftoff_delay_ms": _pair(s["liftoff_delay_ms"]),
        "touchdown_delay_persist_ms": _pair(s["touchdown_delay_persist_ms"]),
        "liftoff_delay_persist_ms": _pair(s["liftoff_delay_persist_ms"]),
        "touchdown_abs_delay_ms": float(s.get("touchdown_abs_delay_ms", np.nan)),
        "liftoff_abs_delay_ms": float(s.get("liftoff_abs_delay_ms", np.nan)),
        "failures": int(s["failures"]),
        "air_phase_failure_rate": float(s["air_phase_failure_rate"]),
        "swing_phase_failure_rate": float(s.get("swing_phase_failure_rate", np.nan)),
        "swing_phase_flag_on_rate": float(s.get("swing_phase_flag_on_rate", np.nan)),
        "air_false_contact_rate": float(s["air_false_contact_rate"]),
        "missed": int(s["missed"]),
        "missed_liftoffs": int(s["missed_liftoffs"]),
        "touchdown_already_on": int(s["touchdown_already_on"]),
        "false_liftoffs": int(s["false_liftoffs"]),
        "accuracy": float(s["accuracy"]),
        "f1": float(s["f1"]),
        "brier": float(s["brier"]),
        "ece": float(s["ece"]),
        "n_touchdowns": int(s["n_touchdowns"]),
        "n_liftoffs": int(s["n_liftoffs"]),
        "n_air_phases": int(s["n_air_phases"]),
        "is_flag": bool(s.get("is_flag", False)),
    }


ROWS = ("probabilistic", "gm_walk", "gm_trot", "kinematic")
# The rule the estimator's defaults were chosen under (docs/results.md, "How the baselines
# are tuned"): swing-phase failures at most this share on the tuning runs, then the best
# F1; read here on sw-ph + sw-on, so that a flag stuck on through the swings does not pass.
# The rows FAILURE_LIMITED_ROWS are GM and the kinematic detector picked from their grids
# by that rule (jax_contact.train.reproduce.best_setting), beside their F1-tuned rows, so
# that the failure columns also compare rows tuned for the same thing (a fairness audit of
# the forty-ninth session); reproduce's runs have them.
FAILURE_LIMIT = 0.02
FAILURE_LIMITED_ROWS = ("gm_walk_fl", "gm_trot_fl", "kinematic_fl")
FAILURE_RULE = (
    f"the estimator defaults' rule (sw-ph + sw-on <= {100 * FAILURE_LIMIT:g} % on the tuning"
    " run, then F1)"
)
# The printed Table III: the defaults, the tuned row when there is one, the references.
PRINTED_ROWS = ("probabilistic", "tuned", "gm_walk", "gm_trot", "kinematic", *FAILURE_LIMITED_ROWS)
ABLATION_ROWS = (
    "probabilistic",
    "paper_model",
    "no_outlier_model",
    "uncapped_transitions",
    "symmetric_dkin_cap",
    "two_sided_kinematics",
    "a_F_200",
    "rigid_contact",
    "kinematics_at_start",
    "dkin_still_0.7",
    "still_foot",
    "no_transition_model",
    "dynamics_only",
    "diff_kinematics_only",
    "kinematics_only",
)


def short_air_phase_counts(truth, valid, dt: float) -> list[int]:
    """``[short, all]``: a scenario's true air phases of at most
    :func:`jax_contact.metrics.bounce_steps` steps (the bounces that ``sw-ph`` leaves out),
    and all of them (:func:`jax_contact.metrics.short_air_phases`; valid (T, E) over the
    feet)."""
    from jax_contact.metrics import bounce_counts

    return list(bounce_counts(truth, valid, dt))


def format_short_air_phases(payload: dict) -> str | None:
    """The line after Table III that says how many of the scenarios' true air phases last a
    few steps (a resting foot's load dropping for a step), where most of each detector's
    mLO falls. Counted over the complete air phases (:func:`jax_contact.metrics.
    short_air_phases`), not the ``n_air_phases`` of ``air-ph``, which also holds those the
    log's start or end cuts. None when the payload has no counts."""
    from jax_contact.metrics import bounce_steps

    counts, dt = payload.get("short_air_phases") or {}, payload.get("dt")
    if not counts or not dt:
        return None
    steps = bounce_steps(dt)
    listed = ", ".join(f"{n} {s} of {a}" for n, (s, a) in counts.items())
    return textwrap.fill(
        f"short air phases: true air phases of at most {steps} steps ({steps * dt * 1e3:.3g}"
        f" ms), most often a resting foot's load dropping for a step, a lift-off a"
        f" detector misses if its flag stays on through them (mLO; a flag that stays on"
        f" through a longer swing is no failure in air-ph or sw-ph, only an mLO): {listed}"
        " complete air phases (contact before and after; air-ph and sw-ph also count those"
        " the log's start or end cuts)",
        100,
    )


def table3_json(t3: dict) -> dict:
    """The ``table3.json`` payload: scenario -> detector -> cell."""
    scen = {}
    for name, r in t3["results"].items():
        extra = ("probabilistic_mc", TUNED_ROW, *FAILURE_LIMITED_ROWS)
        rows = list(ROWS) + [k for k in extra if k in r["scores"]]
        scen[name] = {row: cell(r["scores"][row]) for row in rows}
    vs = {n: r["vs_gm"] for n, r in t3["results"].items() if r.get("vs_gm")}
    tvs = {n: r["tuned_vs"] for n, r in t3["results"].items() if r.get("tuned_vs")}
    return {
        "scenarios": scen,
        **({"vs_gm": vs} if vs else {}),
        **({"tuned_vs": tvs} if tvs else {}),
        **({"tuned_params": t3["tuned_params"]} if t3.get("tuned_params") else {}),
        "tuned_gm": t3["tuned_gm"],
        "tuned_kinematic": t3.get("tuned_kinematic"),
        # The picks of the rows FAILURE_LIMITED_ROWS and their limit.
        "failure_limited": t3.get("failure_limited"),
        # The baselines' picks that sit on an edge of their grid (none: each pick inside).
        "grid_edges": t3.get("grid_edges", {}),
        "reading_timing": "end_of_step",
        "input_lag_ms": t3.get("input_lag_ms"),
        "dt": t3.get("dt"),
        "short_air_phases": {
            n: r["short_air_phases"] for n, r in t3["results"].items() if "short_air_phases" in r
        },
    }


def _percent(rate) -> str:
    """A rate as ``12.3%``; ``n/a`` where there is none (NaN, null, absent)."""
    if rate is None or not np.isfinite(rate):
        return "n/a"
    return f"{100 * rate:5.1f}%"


def format_delay(mean_std, n_true: int | None = None) -> str:
    """``mean±std`` of a delay, ms; where there is none (NaN), ``no true event`` if the
    truth has no event of the kind (``n_true`` 0), else ``none found`` (none detected)."""
    mean, std = mean_std
    if mean is None or not np.isfinite(mean):  # NaN, or null as table3.json stores it
        return "no true event" if n_true == 0 else "none found"
    return f"{mean:5.1f}±{std:<5.1f}"


# (header, width, cell -> text) of each column of the printed tables.
_COLUMNS = (
    ("TD ms", 13, lambda c: format_delay(c["touchdown_delay_ms"], c.get("n_touchdowns"))),
    ("LO ms", 13, lambda c: format_delay(c["liftoff_delay_ms"], c.get("n_liftoffs"))),
    ("F1", 6, lambda c: f"{c['f1']:.3f}"),
    ("acc", 6, lambda c: f"{c['accuracy']:.3f}"),
    ("fail", 5, lambda c: f"{c['failures']}"),
    ("air-ph", 7, lambda c: _percent(c["air_phase_failure_rate"])),
    ("sw-ph", 7, lambda c: _percent(c.get("swing_phase_failure_rate"))),
    ("sw-on", 7, lambda c: _percent(c.get("swing_phase_flag_on_rate"))),
    ("mTD", 4, lambda c: f"{c['missed']}"),
    ("mLO", 4, lambda c: f"{c['missed_liftoffs']}"),
    ("ECE", 6, lambda c: "flag" if c.get("is_flag") else f"{c['ece']:.3f}"),
)
LEGEND = (
    "TD / LO ms: touch-down / lift-off delay, mean±std, from the step of the true event to"
    " the first step whose output detects it (the input lag included; negative: detected"
    " before the true event, at most 50 ms; none found: no event of the kind detected; no"
    " true event: the truth has none); fail: false contacts in the air, counted as events"
    " (runs of the flag that start in a true air phase; the paper's failures); air-ph:"
    " share of true air phases with a false contact; sw-ph: the same share over the air"
    " phases longer than 10 ms (the truth's bounces of a resting foot left out); sw-on: share"
    " of those swing phases with the flag on throughout (no failure in sw-ph, a missed"
    " lift-off); mTD / mLO:"
    " missed touch-downs / lift-offs; acc, F1: per step; ECE: expected calibration error"
    " (flag: a detector whose output is 0 or 1, whose ECE is 1 - acc); a row *_fl: that"
    f" baseline picked from its grid by {FAILURE_RULE} instead of by F1 alone"
)


def format_table(payload: dict, rows=ROWS, *, legend: bool = True) -> str:
    """The table as text: one block per scenario, rows detectors, metric columns, then
    (``legend``) the columns' legend and the payload's input lag."""
    lines = []
    # The row names' column: at least 20 wide, and one space after the longest name.
    width = max([20] + [len(r) + 1 for r in rows])
    for name, scen in payload["scenarios"].items():
        lines.append(f"{name:{width + 2}s}" + " ".join(h.rjust(w) for h, w, _ in _COLUMNS))
        for row in rows:
            if row in scen:
                cells = " ".join(f(scen[row]).rjust(w) for _, w, f in _COLUMNS)
                lines.append(f"  {row:{width}s}" + cells)
    if not legend:
        return "\n".join(lines)
    lines.append(textwrap.fill(LEGEND, 100))
    if payload.get("input_lag_ms") is not None:
        lines.append(
            f"input lag (sensor latency, every detector, in the delays):"
            f" {payload['input_lag_ms']:.1f} ms"
        )
    return "\n".join(lines)


def format_tuned_source(tp: dict) -> str:
    """Where the row ``tuned`` comes from: one line per file (``table3.json``'s
    ``tuned_params``), with the scenarios each serves under ``per-gait``."""
    if "by_scenario" not in tp:
        return f"{TUNED_ROW}: " + _describe_source(tp)
    by_source: dict[str, list[str]] = {}
    for scenario, info in tp["by_scenario"].items():
        by_source.setdefault(info["source"], []).append(scenario)
    lines = [f"{TUNED_ROW} (per gait):"]
    for scenarios in by_source.values():
        info = tp["by_scenario"][scenarios[0]]
        lines.append(f"  {', '.join(scenarios)}: " + _describe_source(info))
    return "\n".join(lines)


def _describe_source(tp: dict) -> str:
    cal = tp["calibration"]
    return (
        f"{tp['source']} (tuned on seeds {_seeds(tp, 'tuning_logs')},"
        f" validated on {_seeds(tp, 'validation_logs')}"
        + ("" if tp["held_out"] else "; NOT held out")
        + ")"
        + (f", P read through its {cal['kind']} calibration map" if cal else "")
    )


def _seeds(tuned_params: dict, key: str) -> str:
    seeds = tuned_params["seeds"].get(key)
    return "unknown" if not seeds else ", ".join(str(s) for s in sorted(set(seeds)))


def format_scores(scores: dict[str, dict], *, title: str = "log", legend: bool = True) -> str:
    """Every detector's full metric set as one table with a header and (``legend``) the
    legend (``jax_contact.train.report.format_table``'s columns: TD / LO delays, F1,
    accuracy, failures, per-air-phase and per-swing-phase failure rates, missed touch-downs
    and lift-offs, ECE)."""
    rows = sorted(scores, key=lambda d: (not d.startswith("probabilistic"), d == "kinematic", d))
    payload = {"scenarios": {title: {det: cell(scores[det]) for det in rows}}}
    return format_table(payload, rows=rows, legend=legend)
