"""Figures in the style of the paper's Fig. 5, 7 and 10 (PNG, matplotlib's object API)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_estimate(
    outputs: dict,
    rollout,
    name: str,
    path: str | Path,
    *,
    env: int = 0,
    leg: int = 0,
    seconds: float = 2.0,
    title: str = "",
    gm: np.ndarray | None = None,
) -> Path:
    """Fused estimate, each term, both transition probabilities and ground truth of one foot.

    Args:
      outputs: from ``jax_contact.train.evaluate.replay`` with ``diagnostics_of=name``.
      rollout: the simulated rollout (``time``, ``contact``, ``force``).
      name: the estimator whose diagnostics to plot.
      path: PNG file to write (its folder must exist).
      env, leg: which foot.
      seconds: how much of the start of the run to show.
      title: figure title.
      gm: optional (T, E, L) GM contact flag to overlay.

    Returns:
      The path written.
    """
    from matplotlib.figure import Figure

    t = np.asarray(rollout.time)
    sl = slice(0, int(min(len(t), max(2, round(seconds / max(t[1] - t[0], 1e-9))))))
    t = t[sl]
    truth = np.asarray(rollout.contact)[sl, env, leg].astype(float)
    fig = Figure(figsize=(10, 9))
    ax = fig.subplots(5, 1, sharex=True)
    ax[0].plot(t, outputs[name][sl, env, leg], label="fused P(contact)")
    ax[0].plot(t, truth, "k--", lw=1, label="ground truth")
    if gm is not None:
        ax[0].plot(t, 0.95 * gm[sl, env, leg], "r:", lw=1, label="GM (x0.95)")
    ax[0].set_ylabel("fused")
    ax[0].legend(loc="lower right", fontsize=8)
    for field, label in (
        ("p_dynamics", "dynamics"),
        ("p_diff_kinematics", "diff. kinematics"),
        ("p_kinematics", "kinematics"),
    ):
        ax[1].plot(t, outputs[f"{name}/{field}"][sl, env, leg], label=label)
    ax[1].set_ylabel("terms")
    ax[1].legend(loc="lower right", fontsize=8)
    ax[2].plot(t, outputs[f"{name}/p_takeoff"][sl, env, leg])
    ax[2].set_ylabel("P(take-off)")
    ax[3].plot(t, outputs[f"{name}/p_touchdown"][sl, env, leg])
    ax[3].set_ylabel("P(touch-down)")
    force = np.asarray(rollout.force)[sl, env, leg]
    ax[4].plot(t, force)
    if not np.isfinite(force).any():  # a recording without force/ columns
        ax[4].text(0.5, 0.5, "no force recorded", ha="center", va="center",
                   transform=ax[4].transAxes)  # fmt: skip
        ax[4].set_yticks([])
    ax[4].set_ylabel("normal force, N")
    ax[4].set_xlabel("time, s")
    for a in ax[:3]:
        a.set_ylim(-0.05, 1.05)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def _save(fig, path: str | Path) -> Path:
    """Writes ``fig`` (a ``matplotlib.figure.Figure``) as PNG atomically.

    The figures are built with matplotlib's object API, never pyplot: no backend is
    switched (switching to Agg here turned off a notebook's inline figures, so the
    Section III notebook showed none), and no figure is left open in pyplot."""
    from jax_contact.io import write_atomic

    return write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=80))


def plot_reward_curves(
    curves: dict, path: str | Path, *, title: str = "", training: dict | None = None
) -> Path:
    """Return against environment steps, one line per training run.

    Args:
      curves: run name -> rows of :mod:`jax_contact.train.ppo`'s ``progress.csv`` (dicts with
      ``step``,
        ``eval_reward``, ``eval_reward_std``): the deterministic policy's evaluations.
      path: PNG file to write.
      title: figure title.
      training: run name -> rows of ``training.csv`` (``step``,
        ``train_episode_return``): drawn in a second panel when given.

    Returns:
      The path written.
    """
    from matplotlib.figure import Figure

    n = 2 if training else 1
    fig = Figure(figsize=(6 * n, 4))
    axes = fig.subplots(1, n, squeeze=False)
    ax = axes[0, 0]
    for name, rows in curves.items():
        x = np.array([r["step"] for r in rows], dtype=float)
        y = np.array([r["eval_reward"] for r in rows], dtype=float)
        sd = np.array([r["eval_reward_std"] for r in rows], dtype=float)
        ax.plot(x, y, marker="o", label=name)
        ax.fill_between(x, y - sd, y + sd, alpha=0.15)
    ax.set_title("evaluation (deterministic policy), mean +- std")
    ax.set_ylabel("episode return")
    if training:
        ax = axes[0, 1]
        for name, rows in training.items():
            x = np.array([r["step"] for r in rows], dtype=float)
            y = np.array([r["train_episode_return"] for r in rows], dtype=float)
            ax.plot(x, y, label=name)
        ax.set_title("training episodes (stochastic policy), running mean")
    for ax in axes[0]:
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # none: a summary of no run yet (matplotlib warns)
            ax.legend(title="contact observation")
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)
