"""Per-phase diagnostics: what each term and transition says around the true events.

Where a detector is late or wrong, the reproduction shows *which* term or transition is
responsible with two views of the estimator's diagnostics (:func:`jax_contact.train.evaluate.replay`
with ``diagnostics_of``):

- :func:`event_profiles`: the mean of P(contact), of each term's probability (dynamics,
  differential kinematics, kinematics) and of both transition probabilities at each step
  offset from the true lift-offs and touch-downs (offset 0: the first step of the new
  phase). A term that stays on the old phase's side after offset 0 is what holds the
  belief back.
- :func:`false_contact_terms`: each term's mean probability on the air steps the
  estimate calls contact, beside its mean over all air steps: the term that says
  "contact" there is the cause of the false contacts.

Only steps of valid envs count, and an event counts only when its whole window is valid.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

TERM_FIELDS = ("p_dynamics", "p_diff_kinematics", "p_kinematics")
PROFILE_FIELDS = ("p_contact", *TERM_FIELDS, "p_takeoff", "p_touchdown")


def _series(out: Mapping[str, np.ndarray], name: str, field: str) -> np.ndarray:
    return np.asarray(out[name] if field == "p_contact" else out[f"{name}/{field}"])


def event_profiles(
    out: Mapping[str, np.ndarray],
    truth: np.ndarray,
    valid: np.ndarray,
    name: str,
    offsets: Sequence[int] = tuple(range(-3, 11)),
) -> dict:
    """Mean diagnostics at each offset from the true events.

    Args:
      out: replay outputs with ``name`` and its ``"<name>/<field>"`` diagnostics.
      truth: (T, E, L) bool true contact.
      valid: (T, E) bool.
      name: the estimator's name in ``out``.
      offsets: step offsets from the first step of each new phase.

    Returns:
      ``{"liftoff" | "touchdown": {"n_events": int, "offsets": [...], field: [mean per
      offset], ...}}`` with the fields of :data:`PROFILE_FIELDS` and ``"truth"`` (the
      true contact's mean, which shows how clean the phases around the events are).
    """
    truth = np.asarray(truth, bool)
    valid = np.asarray(valid, bool)
    n_t = truth.shape[0]
    offsets = [int(o) for o in offsets]
    lo, hi = min(offsets), max(offsets)
    series = {f: _series(out, name, f) for f in PROFILE_FIELDS}
    series["truth"] = truth.astype(np.float64)
    result = {}
    starts = {"liftoff": truth[:-1] & ~truth[1:], "touchdown": ~truth[:-1] & truth[1:]}
    for kind, ev in starts.items():
        t, e, leg = np.nonzero(ev)
        t = t + 1  # the first step of the new phase
        keep = (t + lo >= 0) & (t + hi < n_t)
        t, e, leg = t[keep], e[keep], leg[keep]
        window = np.stack([valid[t + o, e] for o in range(lo, hi + 1)])
        ok = window.all(axis=0)
        t, e, leg = t[ok], e[ok], leg[ok]
        prof = {"n_events": int(t.size), "offsets": offsets}
        for f, x in series.items():
            prof[f] = [
                float(np.mean(x[t + o, e, leg])) if t.size else float("nan") for o in offsets
            ]
        result[kind] = prof
    return result


def false_contact_terms(
    out: Mapping[str, np.ndarray],
    truth: np.ndarray,
    valid: np.ndarray,
    name: str,
    threshold: float = 0.5,
) -> dict:
    """Each term's mean probability on false-contact steps and on all air steps.

    Returns:
      ``{"n_false_contact_steps", "n_air_steps", field: {"false_contact": mean,
      "air": mean}}`` for the fields of :data:`TERM_FIELDS`.
    """
    truth = np.asarray(truth, bool)
    air = ~truth & np.asarray(valid, bool)[..., None]
    false = air & (_series(out, name, "p_contact") > threshold)
    res = {"n_false_contact_steps": int(false.sum()), "n_air_steps": int(air.sum())}
    for f in TERM_FIELDS:
        x = _series(out, name, f)
        res[f] = {
            "false_contact": float(x[false].mean()) if false.any() else float("nan"),
            "air": float(x[air].mean()) if air.any() else float("nan"),
        }
    return res


def format_profiles(prof: dict) -> str:
    """Text table: one block per event kind, a row per offset, a column per field."""
    cols = ("truth", *PROFILE_FIELDS)
    short = {
        "p_contact": "P(C)",
        "p_dynamics": "dyn",
        "p_diff_kinematics": "dkin",
        "p_kinematics": "kin",
        "p_takeoff": "P(to)",
        "p_touchdown": "P(td)",
        "truth": "truth",
    }
    lines = []
    for kind in ("liftoff", "touchdown"):
        p = prof[kind]
        label = f"{kind} ({p['n_events']} events)"
        lines.append(f"  {label}  offset " + " ".join(f"{short[c]:>6s}" for c in cols))
        for i, o in enumerate(p["offsets"]):
            # The offset right-aligned under "offset", each value under its header.
            lines.append(
                f"  {'':{len(label)}s}  {o:6d} " + " ".join(f"{p[c][i]:6.3f}" for c in cols)
            )
    return "\n".join(lines)
