"""``jax-contact estimate``: P(contact) per foot for a recording not made by this library.

:func:`estimate_recording` reads the recording (:mod:`jax_contact.train.recording`),
converts it (:mod:`jax_contact.train.recording_convert`), runs
:func:`jax_contact.train.evaluate.replay` and writes per-foot P(contact), each term's
probability and the two transition probabilities as HDF5 and CSV (atomically,
:mod:`jax_contact.io`), a Fig.-5-style PNG per foot, and the metrics when the recording
has ground truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from jax_contact.train.recording import (
    DIAGNOSTICS,
    FORCE_THRESHOLD,
    read_recording,
    write_recording_csv,
)
from jax_contact.train.recording_checks import (
    dynamics_disagrees,
    plane_floor_note,
    straight_legs,
    truth_order,
)
from jax_contact.train.recording_convert import noise_for_differences, stretches, to_readings


def estimate_recording(
    path: str | Path,
    *,
    model: str,
    out_dir: str | Path,
    feet: Sequence[str] | None = None,
    names: Mapping[str, str] | None = None,
    params_path: str | Path | None = None,
    units: str = "rad",
    resample: bool = False,
    plots: bool = True,
    plot_seconds: float = 4.0,
    progress: bool = True,
    terrain_model: str | None = None,
    force_threshold: float = FORCE_THRESHOLD,
    legend: bool = True,
    robot=None,
) -> dict:
    """``jax-contact estimate``: P(contact) per foot for a recording (module docstring).

    ``terrain_model``: the estimator's terrain model
    (:data:`jax_contact.train.log_estimator.TERRAIN_MODELS`): ``"flat"`` a plane at z = 0 of the
    recording's world frame, ``"memory"`` the feet's own footholds, for a ``base_pos`` that
    drifts (a state estimator's, over a long recording); None: the one ``params_path`` was
    tuned with, else ``"flat"``. ``force_threshold``: a ``force/<foot>`` column above it
    is contact, N (raise it for a foot sensor with an offset). ``legend``: print the
    metrics table's column legend (several recordings print it once). ``robot``: ``model``
    already loaded with ``feet`` (:func:`jax_contact.envs.robots.load_robot`; several
    recordings load it once), or None to load it here.

    Writes into ``out_dir``: ``estimate.h5`` (``time`` (T,), ``p_contact``, each of
    :data:`DIAGNOSTICS` and ``valid`` as (T, L) arrays, ``truth/contact`` and
    ``truth/known`` with ground truth; attributes ``model``, ``recording``,
    ``terrain_model``, ``foot_names``, ``terms``, ``dt``, ``notes``, ``reading_timing``,
    ``calibration``, ``format_version``; docs/own_robot.md, "The output files"),
    ``estimate.csv``
    (``time`` and ``<field>/<foot>`` columns), ``<foot>.png`` per foot, and with ground
    truth ``metrics.json``. Prints the notes (derived columns, terms off), a summary per
    foot and, with ground truth, the metrics table of ``jax-contact evaluate``.

    Returns:
      ``notes``, ``terms``, ``foot_names``, ``dt``, ``files`` (written), ``outputs`` (the
      replay's (T, 1, L) arrays), ``scores`` (empty without ground truth); with ground
      truth also ``truth``, ``scored`` and ``truth_known``, the (T, 1, L) arrays the
      scores were computed on.

    Raises:
      ValueError: ``out_dir`` is a file or cannot take files (before any work), or the
        recording, model or parameters are wrong (one line naming the column or file).
    """
    from jax_contact.baselines import make_gm_params, make_kinematic_params
    from jax_contact.calibration import calibrate_probability
    from jax_contact.envs.robots import load_robot
    from jax_contact.io import staged_folder, write_json_atomic, write_log
    from jax_contact.robot import model_mass
    from jax_contact.train.cli_args import check_output_folder
    from jax_contact.train.evaluate import replay, score
    from jax_contact.train.log_estimator import estimator_for
    from jax_contact.train.log_evaluate import UNTUNED_BASELINES
    from jax_contact.train.report import format_scores

    # Before any work: the folder must take files (the command checks it the same way).
    check_output_folder("out_dir", out_dir)
    rec = read_recording(path)
    if robot is None:
        robot = load_robot(model, foot_names=feet)
        if feet is None:
            from jax_contact.train.logs import note_found_feet

            print(note_found_feet(robot))
    conv = to_readings(
        rec, robot, names=names, units=units, resample=resample, force_threshold=force_threshold
    )
    desc = robot.description
    params, terrain_model, terrain, calibration, _ = estimator_for(
        desc, conv.dt, params_path, terrain_model, model_mass(robot.mj_model),
        mj_model=robot.mj_model, robot=robot.name,
    )  # fmt: skip
    terms = tuple(t for t in params.terms if t in conv.terms)
    if not terms:
        raise ValueError(
            f"the parameters' terms {params.terms} and the recording's {conv.terms} share none"
        )
    params = noise_for_differences(params.replace(terms=terms), conv)
    notes = list(conv.notes)
    if params_path is not None and (unused := [t for t in conv.terms if t not in terms]):
        notes.append(
            f"the parameters {str(params_path)!r} run no {' or '.join(unused)} term, which"
            " this recording's columns support (a file tuned on recordings without them);"
            " the defaults run every term"
        )
    if conv.velocity_from_position:
        notes.append(
            "the estimator's velocity and acceleration noise of the differentiated"
            " coordinates raised to that of the differences (sqrt(2) sigma_q / dt,"
            " sqrt(6) sigma_q / dt^2)"
        )
    notes.insert(0, f"estimator terms: {', '.join(terms)}; rate {1.0 / conv.dt:.6g} Hz")
    if floor := plane_floor_note(robot, conv.readings["qpos"][:, 0], terms, terrain_model):
        notes.append(floor)
    for line in notes:
        print_note(line)
    has_truth = conv.truth is not None
    out = replay(
        robot,
        conv.readings,
        estimators={"probabilistic": params},
        terrain=terrain,
        gms={"gm": make_gm_params()} if has_truth and conv.has_torque else None,
        kinematic=make_kinematic_params() if has_truth else None,
        dt=conv.dt,
        diagnostics_of="probabilistic",
        progress=progress,
    )
    if line := predicted_only(np.asarray(out["probabilistic/valid"], bool)[:, 0], conv, desc):
        notes.append(line)
        print_note(line)
    terms_of = {k: np.asarray(out[f"probabilistic/{k}"])[:, 0] for k in TORQUE_CHECK_INPUTS}
    if warned := torque_note(terms_of, terms, desc, conv, notes, robot.mj_model):
        notes.append(warned)
        print_note(warned)
    if calibration is not None:
        # What the file defines as its output: the belief through its calibration map
        # (jax_contact.calibration), as the wrapper and the exported estimator report it.
        out["probabilistic"] = calibrate_probability(out["probabilistic"], calibration)
        line = f"p_contact through the file's calibration map ({calibration.describe()})"
        notes.append(line)
        print_note(line)
    out_dir = Path(out_dir)
    # The earlier run's outputs, read once: they are superseded, and named if not rewritten.
    earlier = [n for n in _earlier_outputs(out_dir) if (out_dir / n).is_file()]
    with staged_folder(out_dir, stale=lambda _: earlier) as stage:
        feet_names = list(desc.foot_names)
        fields = {"p_contact": out["probabilistic"]} | {
            f: out[f"probabilistic/{f}"] for f in DIAGNOSTICS
        }
        # A term the estimator ran without (e.g. the dynamics without torques) is still
        # computed in the diagnostics, from zeros: its column is NaN (blank in the CSV),
        # not a probability that nothing used.
        for term in ("dynamics", "diff_kinematics", "kinematics"):
            if term not in terms and f"p_{term}" in fields:
                fields[f"p_{term}"] = np.full(np.shape(fields[f"p_{term}"]), np.nan)
        fields["valid"] = out["probabilistic/valid"].astype(np.float64)
        arrays = {"time": conv.time} | {
            k: np.asarray(v[:, 0], np.float32) for k, v in fields.items()
        }
        if has_truth:
            arrays["truth/contact"] = conv.truth[:, 0]
            arrays["truth/known"] = conv.truth_known[:, 0]
        attrs = {
            "model": str(model),
            "recording": str(path),
            "terrain_model": terrain_model,
            "foot_names": feet_names,
            "terms": list(terms),
            "dt": conv.dt,
            "notes": notes,
            "reading_timing": "end_of_step",
            "calibration": None if calibration is None else calibration.as_dict(),
        }
        files = [write_log(stage / "estimate.h5", arrays, attrs)]
        columns = {"time": conv.time}
        for field, value in fields.items():
            for i, foot in enumerate(feet_names):
                columns[f"{field}/{foot}"] = np.asarray(value[:, 0, i], np.float64)
        files.append(write_recording_csv(stage / "estimate.csv", columns))
        if plots:
            from types import SimpleNamespace

            from jax_contact.train.figures import plot_estimate

            nan = np.full(out["probabilistic"].shape, np.nan)
            shown = SimpleNamespace(
                time=conv.time - conv.time[0],
                contact=np.where(conv.truth_known, conv.truth, np.nan) if has_truth else nan,
                force=conv.force if conv.force is not None else nan,
            )
            for i, foot in enumerate(feet_names):
                files.append(
                    plot_estimate(
                        out,
                        shown,
                        "probabilistic",
                        stage / f"{_safe(foot)}.png",
                        leg=i,
                        seconds=plot_seconds,
                        title=f"{Path(path).name}: foot {foot!r} (terms: {', '.join(terms)})",
                    )
                )
        p = np.asarray(out["probabilistic"])[:, 0]
        # Over the steps each foot was estimated, not predicted only (valid).
        estimated = np.asarray(out["probabilistic/valid"], bool)[:, 0]
        with np.errstate(invalid="ignore"):
            share = np.sum((p > 0.5) & estimated, axis=0) / np.sum(estimated, axis=0)
        line, all_air = contact_summary(share, feet_names, seconds=len(p) * conv.dt)
        print(f"{len(p)} readings at {conv.dt * 1e3:.4g} ms; {line}")
        if all_air:
            print(f"warning: {all_air}")
        scores = {}
        if has_truth:
            # Steps whose truth is missing are scored as neither contact nor air, and so are
            # a foot's steps that read a lost reading (the estimator's valid: a joint's NaN
            # is its own foot's, a base reading's every foot's); every detector alike. The
            # latter keep their truth, so they do not cut a true air phase in two.
            scored = np.asarray(out["probabilistic/valid"], bool) & conv.truth_known
            scores = score(out, conv.truth, scored, dt=conv.dt, truth_known=conv.truth_known)
            if swapped := truth_order(p, conv.truth[:, 0], scored[:, 0], feet_names):
                swapped = after_warnings(swapped, notes)
                notes.append(swapped)
                print_note(swapped)
            if legend and ("gm" in scores or "kinematic" in scores):  # once for several
                print(UNTUNED_BASELINES)
            print(format_scores(scores, title=Path(path).name, legend=legend))
            files.append(write_json_atomic(stage / "metrics.json", scores))
        else:
            print("no ground truth columns (contact/<foot> or force/<foot>): no metrics")
    files = [out_dir / f.name for f in files]
    print("wrote " + ", ".join(str(f) for f in files))
    removed = sorted(set(earlier) - {f.name for f in files})
    if removed:
        print(f"removed the earlier run's {removed} from {str(out_dir)!r} (not written this time)")
    result = {
        "notes": notes,
        "terms": terms,
        "foot_names": feet_names,
        "dt": conv.dt,
        "files": files,
        "outputs": out,
        "scores": scores,
    }
    if has_truth:  # what the scores were computed on, for pooling several recordings
        result |= {"truth": conv.truth, "scored": scored, "truth_known": conv.truth_known}
    return result


# The per-step diagnostics (each (T, L), force (T, L, 3)) that :func:`torque_note` reads.
TORQUE_CHECK_INPUTS = ("p_dynamics", "p_diff_kinematics", "valid", "force")


def torque_note(
    terms_of: Mapping[str, np.ndarray],
    terms: Sequence[str],
    desc,
    conv,
    notes: Sequence[str],
    mj_model=None,
):
    """The torque check's note (``"WARNING ..."``) for a recording's estimate, or None
    (also when the estimator ran without the dynamics or differential-kinematics term).

    Args:
      terms_of: :data:`TORQUE_CHECK_INPUTS` -> (T, L) of the estimate of the recording
        (``force`` (T, L, 3), world frame, N: its vertical push is checked too).
      terms: the measurement terms the estimator ran with.
      desc: the robot description (feet and their legs' dofs).
      conv: the recording as :func:`~jax_contact.train.recording_convert.to_readings`
        converted it (its ``tau/`` columns, named in the warning).
      notes: the notes so far: after an earlier warning the torque warning says it may be
        that one's consequence (a wrong quaternion or base acceleration also makes the
        dynamics term read air).
      mj_model: the robot's model, to tell a nearly straight leg (whose torques cannot
        show its load) from wrong torques (:func:`recording_checks.straight_legs`); None
        does not look.
    """
    if not {"dynamics", "diff_kinematics"} <= set(terms):
        return None
    columns = [[conv.tau_columns[d] for d in leg if d in conv.tau_columns] for leg in desc.leg_dofs]
    p_dyn, p_dk, valid, force = (np.asarray(terms_of[k]) for k in TORQUE_CHECK_INPUTS)
    straight = None
    if mj_model is not None:
        still = (p_dk > 0.5) & valid.astype(bool)
        straight = straight_legs(mj_model, desc, conv.readings["qpos"][:, 0], still)
    disagrees = dynamics_disagrees(
        p_dyn, p_dk, valid, desc.foot_names, columns, push=-force[..., 2], straight=straight
    )
    if not disagrees:
        return None
    return f"WARNING {after_warnings(disagrees, notes)}"


def after_warnings(text: str, notes: Sequence[str]) -> str:
    """``text``, a warning's, with "or a consequence of the warnings above" when ``notes``
    already hold one (``"WARNING ..."``): a wrong quaternion or base acceleration also makes
    the torques and the truth's foot order look wrong."""
    if any(n.startswith("WARNING") for n in notes):
        return text + "; or a consequence of the warnings above (fix those first)"
    return text


# The shortest replay (s) whose "every foot reads air" is a warning: the belief starts at
# its prior, so a few readings (deploy-check --steps 1) say nothing about the recording.
ALL_AIR_MIN_S = 1.0


def contact_summary(
    share: np.ndarray,
    feet: Sequence[str],
    floor_hint: str = "--terrain-model memory",
    *,
    seconds: float | None = None,
) -> tuple[str, str | None]:
    """``(line, warning or None)``: each foot's ``share`` (L,) of steps estimated in contact
    (P > 0.5) as one line (NaN: the foot has no estimated step, ``-``), and a warning when
    every foot reads air on more than 99 % of them: a robot that stood or walked does not,
    a recording read in the wrong unit, quaternion order or floor height does
    (``floor_hint``: what to do about a floor that is not at z = 0). No warning for a
    replay of fewer than :data:`ALL_AIR_MIN_S` ``seconds``."""
    line = "share of steps estimated in contact (P > 0.5): " + "  ".join(
        f"{f} {s:.2f}" if np.isfinite(s) else f"{f} -" for f, s in zip(feet, share, strict=True)
    )
    if not np.all(share < 0.01) or (seconds is not None and seconds < ALL_AIR_MIN_S):
        return line, None
    return line, (
        "every foot reads air on more than 99 % of the steps; if the robot stood or walked,"
        " check the angles' unit (--units), the base quaternion's order (w, x, y, z) and"
        f" that the floor is at z = 0 in base_pos's frame (else {floor_hint})"
    )


def predicted_only(valid: np.ndarray, conv, desc) -> str | None:
    """The note naming, per foot, the steps the estimator predicted only (``valid`` (T, L)
    False: a reading that foot reads was lost, on that step or in the state it pairs
    with), or None when every step was valid."""
    if valid.all():
        return None
    if (valid == valid[:, :1]).all():  # a base reading: every foot alike
        lost = [f"every foot {stretches(~valid[:, 0], conv.time)}"]
    else:
        lost = [
            f"{foot} {stretches(~valid[:, i], conv.time)}"
            for i, foot in enumerate(desc.foot_names)
            if not valid[:, i].all()
        ]
    return (
        "steps predicted only (valid = False in the output, left out of the metrics): "
        + "; ".join(lost)
    )


def print_note(note: str, source: str | None = None, file=None) -> None:
    """Prints one of the run's notes: those that flag a reading as another unit or frame
    (prefixed ``WARNING ``, as :func:`to_readings` writes them) as ``warning:``, the others
    as ``note:``; ``source`` (e.g. the recording's path) after the prefix, ``file`` as
    :func:`print`'s."""
    warned = note.removeprefix("WARNING ")
    where = "" if source is None else f"{source}: "
    print(f"{'warning' if warned != note else 'note'}: {where}{warned}", file=file)


def _earlier_outputs(folder: Path) -> list[str]:
    """The files an earlier ``estimate`` wrote into ``folder``: its fixed names and the
    PNG of each foot its ``estimate.h5`` names (unreadable: the fixed names only)."""
    names = ["estimate.h5", "estimate.csv", "metrics.json"]
    try:
        from jax_contact.io import read_log

        _, attrs = read_log(folder / "estimate.h5")
        names += [f"{_safe(f)}.png" for f in attrs.get("foot_names", [])]
    except (OSError, ValueError):
        pass
    return names


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "foot"
