"""``jax-contact estimate`` on several recordings of one robot: each estimated as it would
be alone, into its own folder, and the metrics of those with ground truth pooled.

A day on a robot is many recordings; whether the estimator is good enough to replace the
foot sensors is a question about all of them. ``estimate A.csv B.csv --out DIR`` writes
``DIR/A/`` and ``DIR/B/`` (each what ``estimate A.csv --out DIR/A`` writes:
:func:`jax_contact.train.recording_estimate.estimate_recording`) and, when at least two
have ground truth, ``DIR/pooled_metrics.json``: every detector's metrics over the pooled
foot-steps, each recording one sequence (one env of :func:`jax_contact.metrics.evaluate`:
no event crosses from one recording into the next, so counts such as ``n_steps``,
``failures`` or ``n_air_phases`` are the sums of the recordings' own and the per-step
scores their step-weighted means), beside each recording's.

Every recording is read and converted before any is estimated, so a wrong column in the
last one is refused before the first one's folder is written, and the recordings that
will not be pooled (no ground truth, another rate) are named before the work. Each folder
is written as one (a staged folder). An earlier run's ``pooled_metrics.json`` in the
folder is removed when the estimating starts (it pooled folders this run rewrites), so a
run stopped or failed part-way keeps the recordings' folders it completed, each
complete, and no pooled file that disagrees with them.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

# Recordings whose periods differ by more than this fraction are not pooled: the event
# rules count steps (the early window, the bounce length), so one dt must serve all.
POOL_RATE_TOLERANCE = 1e-3
POOLED_FILE = "pooled_metrics.json"


def recording_folders(paths: Sequence[str | Path]) -> list[str]:
    """Each recording's output folder name (its file name without the suffix).

    Raises:
      ValueError: a recording given twice, or two that would share a folder (both named).
    """
    from jax_contact.train.cli_args import check_distinct_files

    check_distinct_files("recording", paths)
    seen: dict[str, str] = {}
    for p in paths:
        stem = Path(p).stem
        if stem in seen:
            raise ValueError(
                f"argument recording: {seen[stem]!r} and {str(p)!r} would both write to the"
                f" folder {stem!r}; rename one"
            )
        seen[stem] = str(p)
    return list(seen)


def pool_groups(
    dts: dict[str, float | None], kinds: dict[str, str] | None = None
) -> tuple[list[str], dict[str, str]]:
    """Which recordings are pooled: ``(pooled stems, stem -> why not)``.

    ``dts``: stem -> the recording's period, s, or None without ground truth. ``kinds``:
    stem -> what else must agree (``evaluate``'s logs: the robot); None: nothing. The
    pooled ones are the largest set of recordings with ground truth of one kind whose
    periods lie within :data:`POOL_RATE_TOLERANCE` of each other's first (ties: the set of
    the earliest recording); fewer than two pool nothing.
    """
    kinds = kinds or {}
    why: dict[str, str] = {s: "no ground truth" for s, d in dts.items() if d is None}
    groups: list[list[str]] = []
    for stem, dt in dts.items():
        if dt is None:
            continue
        for g in groups:
            first = g[0]
            same_kind = kinds.get(stem) == kinds.get(first)
            if same_kind and abs(dt - dts[first]) <= POOL_RATE_TOLERANCE * dts[first]:
                g.append(stem)
                break
        else:
            groups.append([stem])
    best = max(groups, key=len, default=[])  # max keeps the first of equal lengths
    if len(best) < 2:
        for g in groups:
            of = f" of robot {kinds[g[0]]!r}" if g[0] in kinds else ""
            why[g[0]] = f"no other recording{of} with ground truth at its rate"
        return [], why
    for g in groups:
        for stem in g if g is not best else ():
            if kinds.get(stem) != kinds.get(best[0]):
                why[stem] = f"robot {kinds[stem]!r}; the pooled ones' is {kinds[best[0]]!r}"
            else:
                why[stem] = (
                    f"at {1 / dts[stem]:.6g} Hz, the pooled ones at {1 / dts[best[0]]:.6g} Hz"
                )
    return best, why


def estimate_recordings(
    paths: Sequence[str | Path],
    *,
    model: str,
    out_dir: str | Path,
    feet: Sequence[str] | None = None,
    names=None,
    units: str = "rad",
    resample: bool = False,
    force_threshold: float | None = None,
    **kwargs,
) -> dict:
    """Estimates each recording into ``out_dir/<its stem>/`` and pools their metrics.

    Args:
      paths: the recordings (two or more; distinct file stems).
      model, feet, names, units, resample, force_threshold, kwargs: as
        :func:`jax_contact.train.recording_estimate.estimate_recording`, the same for all.
      out_dir: the folder of the recordings' folders and ``pooled_metrics.json``.

    Returns:
      ``recordings`` (stem -> that recording's result), ``pooled`` (detector -> metrics
      over the recordings :func:`pool_groups` pools; None when it pools none) and
      ``files`` (the pooled file, if written).

    Raises:
      ValueError: as ``estimate_recording`` for any recording (named), before any output
        is written; two recordings of one stem.
    """
    from jax_contact.envs.robots import load_robot
    from jax_contact.train.cli_args import check_output_folder
    from jax_contact.train.recording import read_recording
    from jax_contact.train.recording_convert import FORCE_THRESHOLD, to_readings
    from jax_contact.train.recording_estimate import estimate_recording

    if force_threshold is None:
        force_threshold = FORCE_THRESHOLD
    stems = recording_folders(paths)
    out_dir = Path(out_dir)
    check_output_folder("out_dir", out_dir)
    robot = load_robot(model, foot_names=feet)
    if feet is None:
        from jax_contact.train.logs import note_found_feet

        print(note_found_feet(robot))
    dts = {}
    with warnings.catch_warnings():  # said again when each recording is estimated
        warnings.simplefilter("ignore")
        for p, stem in zip(paths, stems, strict=True):
            conv = to_readings(
                read_recording(p), robot, names=names, units=units, resample=resample,
                force_threshold=force_threshold,
            )  # fmt: skip
            dts[stem] = None if conv.truth is None else float(conv.dt)
    pooled_stems, left_out = pool_groups(dts)
    for stem, why in left_out.items():
        print(f"note: {stem!r} is estimated but not pooled: {why}")
    stale = out_dir / POOLED_FILE
    if stale.is_file():
        stale.unlink()
        print(f"removed the earlier run's {str(stale)!r} (it pooled folders this run rewrites)")
    results = {}
    for i, (p, stem) in enumerate(zip(paths, stems, strict=True)):
        print(f"== recording {i + 1} of {len(paths)}: {str(p)!r} -> {str(out_dir / stem)!r}")
        results[stem] = estimate_recording(
            p, model=model, out_dir=out_dir / stem, feet=feet, names=names, units=units,
            resample=resample, force_threshold=force_threshold, legend=i == 0, robot=robot,
            **kwargs,
        )  # fmt: skip
    # The pre-check's truth and rates are the estimate's own (one conversion rule).
    pooled = pool({s: results[s] for s in pooled_stems}) if pooled_stems else None
    files = []
    if pooled is None:
        print("no pooled metrics: fewer than two recordings with ground truth at one rate")
    else:
        from jax_contact.io import write_json_atomic
        from jax_contact.train.report import format_scores

        # The columns' legend was printed under the first recording's table.
        title = f"{len(pooled_stems)} recordings pooled"
        print(format_scores(pooled, title=title, legend=False))
        payload = {
            "model": str(model),
            "params": None if kwargs.get("params_path") is None else str(kwargs["params_path"]),
            "rate_hz": 1.0 / dts[pooled_stems[0]],
            "recordings": {
                s: {"path": str(p), "pooled": s in pooled_stems}
                | ({} if s in pooled_stems else {"why_not": left_out[s]})
                for s, p in zip(stems, paths, strict=True)
            },
            "pooled": pooled,
            "per_recording": {s: results[s]["scores"] for s in pooled_stems},
        }
        files.append(write_json_atomic(out_dir / POOLED_FILE, payload))
        print(f"wrote {files[-1]}")
    return {"recordings": results, "pooled": pooled, "files": files}


def pool(scored: dict) -> dict:
    """Every detector that scored all of ``scored`` (stem -> an ``estimate_recording``
    result with ground truth; periods within :data:`POOL_RATE_TOLERANCE`,
    :func:`pool_groups`) scored over their foot-steps pooled: each recording one env,
    padded with unscored steps to the longest, at the first one's period."""
    from jax_contact.train.evaluate import score

    outputs, truth, valid, known, dt = pooled_arrays(scored)
    return score(outputs, truth, valid, dt=dt, names=list(outputs), truth_known=known)


def pooled_arrays(scored: dict) -> tuple[dict, object, object, object, float]:
    """``(outputs, truth, scored, truth_known, dt)`` of :func:`pool`: the (T, E, L) arrays
    of every result in ``scored`` (name -> a result with ``dt``, ``scores``, ``outputs``,
    ``truth``, ``scored``, ``truth_known``) side by side along the env axis, each padded
    with unscored steps of unknown truth to the longest; ``outputs`` holds the detectors
    that scored all of them. A result's envs stay its own sequences: no event crosses from
    one into the next."""
    import numpy as np

    dt = float(next(iter(scored.values()))["dt"])
    rows = [
        n
        for n in next(iter(scored.values()))["scores"]
        if all(n in r["scores"] for r in scored.values())
    ]
    n_t = max(r["truth"].shape[0] for r in scored.values())

    def padded(key, r, fill):
        x = np.asarray(r[key])
        pad = [(0, n_t - x.shape[0])] + [(0, 0)] * (x.ndim - 1)
        return np.pad(x, pad, constant_values=fill)

    def stacked(key, fill, source=None):
        return np.concatenate(
            [padded(key, r if source is None else r[source], fill) for r in scored.values()],
            axis=1,
        )

    outputs = {n: stacked(n, 0.0, "outputs") for n in rows}
    return (
        outputs,
        stacked("truth", False),
        stacked("scored", False),
        stacked("truth_known", False),
        dt,
    )
