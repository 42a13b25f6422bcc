"""Calibration of P(contact): reliability diagrams, one curve per detector.

A detector is calibrated when, among the steps where it says P(contact) = p, the foot is
in contact a fraction p of the time. The diagram bins the valid steps by the predicted
probability (the 10 equal-width bins of :func:`jax_contact.metrics.expected_calibration_error`)
and plots each bin's observed contact frequency against its mean prediction; the diagonal
is perfect calibration. The legend gives each detector's ECE (the bins' gaps weighted by
their share of the steps), so the plot and the number agree by construction.

Drawn by ``jax-contact evaluate LOG --plots DIR`` (``DIR/reliability_<log stem>.png``),
by the reproduction (``reliability_<scenario>.png`` beside its other figures) and by
``jax_contact.train.tune_presets.compare(..., plots=DIR)``: :func:`reliability_diagram`
takes the ``replay`` outputs as they are.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from jax_contact.metrics import as_bool, ece_bins, expected_calibration_error


def reliability_bins(prob, truth, valid=None, *, n_bins: int = 10) -> dict[str, np.ndarray]:
    """Per-bin statistics of the reliability diagram.

    Args:
      prob: (T, ...) P(contact) in [0, 1] (or bool flags).
      truth: (T, ...) bool ground truth.
      valid: optional bool mask of ``prob``'s shape, or of its leading axes (e.g. (T, E)
        for a (T, E, L) ``prob``), broadcast over the rest.
      n_bins: equal-width bins on [0, 1].

    Returns:
      ``count`` (n_bins,) steps per bin, ``mean_p`` mean prediction and ``freq`` observed
      contact frequency per bin (NaN for an empty bin), and ``ece`` (a () array), equal to
      :func:`jax_contact.metrics.expected_calibration_error`.

    Raises:
      ValueError: as :func:`jax_contact.metrics.expected_calibration_error` (a NaN, inf or
        value outside [0, 1] of ``prob`` at a valid step, a ``truth`` other than 0 / 1), or
        ``truth`` or ``valid`` of another shape than ``prob``.
    """
    p, g = np.asarray(prob), np.asarray(truth)
    if g.shape != p.shape:
        raise ValueError(f"truth has shape {g.shape}, but prob has shape {p.shape}")
    v = np.ones(p.shape, bool) if valid is None else _mask_like(valid, p.shape)
    # The metric's own checks (values in [0, 1] where valid, truth 0 / 1), and its number.
    ece = expected_calibration_error(p, g, v, n_bins=n_bins)
    p, g = p.astype(np.float64), as_bool("truth", g, v)
    count, sum_g, sum_p = ece_bins(p, g, v, n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_p = np.where(count > 0, sum_p / count, np.nan)
        freq = np.where(count > 0, sum_g / count, np.nan)
    return {"count": count, "mean_p": mean_p, "freq": freq, "ece": np.asarray(ece)}


def _mask_like(valid, shape: tuple[int, ...]) -> np.ndarray:
    """``valid`` broadcast to ``shape``: a mask of ``shape``'s leading axes gets the rest
    appended (a (T, E) mask of a (T, E, L) batch); a clear error if it does not fit."""
    v = np.asarray(valid, bool)
    v = v.reshape(v.shape + (1,) * (len(shape) - v.ndim)) if v.ndim < len(shape) else v
    try:
        return np.broadcast_to(v, shape)
    except ValueError:
        raise ValueError(
            f"valid has shape {np.shape(valid)}; expected {shape} or its leading axes"
        ) from None


def reliability_diagram(
    outputs: Mapping[str, np.ndarray],
    truth,
    valid,
    path: str | Path,
    *,
    names: list[str] | None = None,
    n_bins: int = 10,
    title: str | None = None,
) -> Path:
    """Writes a reliability diagram (PNG) with one curve per detector, ECE in the legend.

    Args:
      outputs: detector -> (T, E, L) P(contact) (e.g. ``jax_contact.train.evaluate.replay``'s
        outputs; keys containing ``/`` are diagnostics and are skipped unless named).
      truth: (T, E, L) bool ground truth.
      valid: (T, E) or (T, E, L) bool validity (broadcast over legs).
      path: the PNG to write (atomically; its folder is created).
      names: detectors to plot (default: every key without ``/``).
      n_bins: bins on [0, 1].
      title: the figure's title.

    Returns:
      The path written. A lower panel shows the share of steps per bin (log scale), since
      a bin's gap matters in proportion to how often it is used.
    """
    from matplotlib.figure import Figure

    from jax_contact.io import write_atomic

    names = names or [k for k in outputs if "/" not in k]
    # matplotlib's object API, no pyplot: the caller's backend is left as it is
    # (jax_contact.train.figures._save says why).
    fig = Figure(figsize=(5.5, 6.5))
    ax, hist = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="perfect calibration")
    centres = (np.arange(n_bins) + 0.5) / n_bins
    width = 0.8 / (n_bins * max(len(names), 1))
    for i, name in enumerate(names):
        try:
            b = reliability_bins(outputs[name], truth, valid, n_bins=n_bins)
        except ValueError as err:
            raise ValueError(f"outputs[{name!r}]: {err}") from None
        keep = b["count"] > 0
        line = ax.plot(
            b["mean_p"][keep], b["freq"][keep], marker="o", ms=4,
            label=f"{name} (ECE {float(b['ece']):.3f})",
        )[0]  # fmt: skip
        share = b["count"] / max(b["count"].sum(), 1.0)
        offset = (i - (len(names) - 1) / 2) * width
        hist.bar(centres + offset, share, width=width, color=line.get_color())
    ax.set_ylabel("observed contact frequency")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=10)
    hist.set_yscale("log")
    hist.set_xlabel("predicted P(contact), bin mean")
    hist.set_ylabel("share of steps")
    hist.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    return path
