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
last one is refused before the first one's folder is written. Each folder is written as
one (a staged folder); a run stopped or failed part-way keeps the folders it completed,
each complete, and writes no pooled file.
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
      ValueError: two recordings would share a folder (both named).
    """
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
      over every recording with ground truth; None with fewer than two, or periods more
      than :data:`POOL_RATE_TOLERANCE` apart) and ``files`` (the pooled file, if written).

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
    with warnings.catch_warnings():  # said again when each recording is estimated
        warnings.simplefilter("ignore")
        for p in paths:
            to_readings(
                read_recording(p), robot, names=names, units=units, resample=resample,
                force_threshold=force_threshold,
            )  # fmt: skip
    results = {}
    for i, (p, stem) in enumerate(zip(paths, stems, strict=True)):
        print(f"== recording {i + 1} of {len(paths)}: {str(p)!r} -> {str(out_dir / stem)!r}")
        results[stem] = estimate_recording(
            p, model=model, out_dir=out_dir / stem, feet=feet, names=names, units=units,
            resample=resample, force_threshold=force_threshold, **kwargs,
        )  # fmt: skip
    pooled, why = pool(results)
    files = []
    if pooled is None:
        print(f"no pooled metrics: {why}")
    else:
        from jax_contact.io import write_json_atomic
        from jax_contact.train.logs import format_scores

        n = sum(1 for r in results.values() if r["scores"])
        # The columns' legend was printed under each recording's table.
        print(format_scores(pooled, title=f"{n} recordings pooled", legend=False))
        payload = {
            "recordings": {s: str(p) for s, p in zip(stems, paths, strict=True)},
            "pooled": pooled,
            "per_recording": {s: r["scores"] for s, r in results.items() if r["scores"]},
        }
        files.append(write_json_atomic(out_dir / POOLED_FILE, payload))
        print(f"wrote {files[-1]}")
    return {"recordings": results, "pooled": pooled, "files": files}


def pool(results: dict) -> tuple[dict | None, str]:
    """``(scores, "")`` of every detector that scored all the recordings with ground truth,
    over their foot-steps pooled (each recording one env, padded with unscored steps to
    the longest); ``(None, why)`` when fewer than two have ground truth or their periods
    differ by more than :data:`POOL_RATE_TOLERANCE`."""
    import numpy as np

    from jax_contact.train.evaluate import score

    scored = {s: r for s, r in results.items() if r["scores"]}
    if len(scored) < 2:
        return None, f"{len(scored)} of {len(results)} recordings have ground truth"
    dts = {s: float(r["dt"]) for s, r in scored.items()}
    dt = next(iter(dts.values()))
    if any(abs(d - dt) > POOL_RATE_TOLERANCE * dt for d in dts.values()):
        rates = ", ".join(f"{s} {1 / d:.6g} Hz" for s, d in dts.items())
        return None, f"the recordings run at different rates ({rates}): their steps differ"
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
    truth = stacked("truth", False)
    valid = stacked("scored", False)
    known = stacked("truth_known", False)
    return score(outputs, truth, valid, dt=dt, names=rows, truth_known=known), ""
