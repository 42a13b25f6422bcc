"""The transfer matrix: trained with one contact signal, evaluated with others.

For the hop task (:mod:`jax_contact.envs.hop_task`), Go1 joystick
(:mod:`jax_contact.train.ppo`) and every other Playground task (evaluated as Go1's, in the
run's own env); :func:`transfer_matrix` dispatches on each run's ``run.json`` ``task``
(absent: ``"go1"``, the runs written before there were tasks).

Rows: the policies trained with ``observe`` in {none, truth, estimate} (one run folder per
seed, written by :func:`jax_contact.train.ppo.train`). Columns (:data:`COLUMNS`): what the
policy sees at evaluation, in the slot it was trained with (:func:`column_setting`):

- ``truth``: the simulator's contact;
- ``estimate``: the estimator with the training sensors (the run's ``sensor`` preset,
  ``anymal_like``);
- ``estimate_harsh``: the estimator with ``harsh`` sensors (more noise, bias, outliers,
  7.5 ms of latency: 3 physics steps of the hop, 2 of Go1's 4 ms);
- ``estimate_lat1``, ``estimate_lat2``: the training sensors with 1 or 2 extra *env* steps
  of sensor latency (hop: 4 or 8 physics steps, 10 or 20 ms; Go1 joystick: 5 or 10, 20 or
  40 ms), :func:`jax_contact.envs.contact_params.with_extra_latency`.

A policy trained with ``none`` sees no contact: its column values differ only by the
evaluation's estimator (which never reaches it), so it is run once and its row repeats it.

Per (row, column) and seed: the deterministic policy on ``n_envs`` episodes from the same
seed (same commands, drop heights and noise in every cell). Hop (:data:`METRICS`):
``return`` (sum of the tracking reward), ``tracking`` (mean reward per alive step),
``apex_error`` (mean |apex - h_cmd| over the apexes of flights, m), ``hops`` (apexes per
episode), ``fell`` and the estimator's ``accuracy``. Go1 (:data:`GO1_METRICS`): ``return``,
``episode_length`` (steps alive), ``fell`` (terminated early) and the estimator's
``accuracy`` and ``f1`` over the steps alive. The matrix gives the mean, the standard
deviation and the per-seed values over seeds.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

COLUMNS = ("truth", "estimate", "estimate_harsh", "estimate_lat1", "estimate_lat2")
METRICS = ("return", "tracking", "apex_error", "hops", "fell", "accuracy")  # hop
GO1_METRICS = ("return", "episode_length", "fell", "accuracy", "f1")


def column_setting(column: str, sensor: str = "anymal_like") -> tuple[str, str, int]:
    """``(observe, sensor preset, extra latency in env steps)`` of a column.

    The one map from a column to what the env is built with, for every task.

    Args:
      column: a name of :data:`COLUMNS`, or ``"none"`` (no contact observed).
      sensor: the training sensor preset (the run's ``PPOConfig.sensor``): every column
        but ``estimate_harsh`` uses it.

    Raises:
      ValueError: an unknown column.
    """
    table = {
        "truth": ("truth", sensor, 0),
        "estimate": ("estimate", sensor, 0),
        "estimate_harsh": ("estimate", "harsh", 0),
        "estimate_lat1": ("estimate", sensor, 1),
        "estimate_lat2": ("estimate", sensor, 2),
        "none": ("none", sensor, 0),
    }
    if column not in table:
        raise ValueError(f"column must be one of {tuple(table)}, got {column!r}")
    return table[column]


def episode_metrics(z, vz, contact, reward, alive, h_cmd) -> dict:
    """Task metrics of rollouts, from arrays of shape (T, n) (``h_cmd``: (n,)).

    An apex is a step where the base velocity turns from up (> 0, previous step) to not up
    (<= 0) with the foot off the ground; its error is ``|z - h_cmd|`` there.

    Returns:
      ``return``, ``tracking``, ``apex_error`` (NaN without any apex), ``hops`` and
      ``fell`` (episode means).
    """
    z, vz, contact, reward, alive = (np.asarray(a) for a in (z, vz, contact, reward, alive))
    h_cmd = np.asarray(h_cmd)
    prev_vz = np.concatenate([np.zeros_like(vz[:1]), vz[:-1]], axis=0)
    apex = (prev_vz > 0) & (vz <= 0) & ~contact.astype(bool) & alive
    err = np.abs(z - h_cmd[None, :])
    n_apex = apex.sum(axis=0)
    total = n_apex.sum()
    return {
        "return": float(np.mean(np.where(alive, reward, 0.0).sum(axis=0))),
        "tracking": float(np.sum(np.where(alive, reward, 0.0)) / max(alive.sum(), 1)),
        "apex_error": float(np.sum(np.where(apex, err, 0.0)) / total) if total else float("nan"),
        "hops": float(np.mean(n_apex)),
        "fell": float(np.mean(~alive[-1])),
    }


class _Evaluator:
    """One compiled rollout per (observe, sensor, latency), the policy parameters an
    argument (so every checkpoint of the same observation size reuses it)."""

    def __init__(self, task_cfg, robot, n_envs: int, t_len: int):
        self.task_cfg, self.robot, self.n_envs, self.t_len = task_cfg, robot, n_envs, t_len
        self._fns: dict = {}

    def rollout_fn(self, column: str, make_policy):
        from jax_contact.envs import hop_task

        key = (column, id(make_policy))
        if key in self._fns:
            return self._fns[key]
        observe, preset, extra = column_setting(column, self.task_cfg.sensor)
        sensor = (
            hop_task.sensor_with_extra_latency(self.robot, preset, extra, self.task_cfg)
            if extra
            else preset
        )
        env = hop_task.make_hop_env(observe, self.task_cfg, sensor=sensor, robot=self.robot)
        n, t_len = self.n_envs, self.t_len
        truth_key = hop_task.INFO_KEY + "_truth"

        @jax.jit
        def rollout(params, rng):
            policy = make_policy(params, deterministic=True)
            k_reset, k_act = jax.random.split(rng)
            state = jax.vmap(env.reset)(jax.random.split(k_reset, n))

            def body(carry, k):
                s, alive = carry
                act, _ = policy(s.obs, k)
                s = jax.vmap(env.step)(s, act)
                alive = alive & (s.done == 0)
                p = s.info[hop_task.INFO_KEY].diag.p_contact[:, 0]
                truth = s.info[truth_key][:, 0]
                out = (
                    s.pipeline_state.qpos[:, 0],
                    s.pipeline_state.qvel[:, 0],
                    truth,
                    s.reward,
                    alive,
                    p,
                )
                return (s, alive), out

            (s, _), outs = jax.lax.scan(
                body, (state, jnp.ones(n, bool)), jax.random.split(k_act, t_len)
            )
            return state.info["h_cmd"], outs

        self._fns[key] = (rollout, env)
        return rollout, env


def _run_cfg(run_dir: Path):
    from jax_contact.train import ppo

    run = ppo.read_run(run_dir)
    return run, ppo.config_of(run)


def _hop_evaluator(run: dict, cfg, n_envs: int, episode_length: int | None) -> _Evaluator:
    """The :class:`_Evaluator` of a hop run: its task's configuration (``run.json``'s
    ``task``) with the run's sensor, episodes of ``episode_length`` (None: the run's)."""
    from jax_contact.envs import hop_task

    task_cfg = dataclasses.replace(hop_task.task_config(run.get("task", "hop")), sensor=cfg.sensor)
    t_len = int(episode_length or cfg.episode_length)
    return _Evaluator(task_cfg, hop_task.hop_robot(), n_envs, t_len)


def _evaluate(ev: _Evaluator, run_dir: Path, column: str, seed: int, loaded=None) -> dict:
    from jax_contact.train import policy_eval

    ckpt = policy_eval.latest_checkpoint(run_dir)
    make_policy, params, sizes = loaded or policy_eval.load_policy(ckpt, parts=True)
    rollout, env = ev.rollout_fn(column, make_policy)
    if tuple(sizes["state"]) != (env.observation_size,):
        raise ValueError(
            f"column {column!r} gives an observation of size {env.observation_size}; the"
            f" checkpoint {ckpt} takes {sizes['state']}"
        )
    t0 = time.perf_counter()
    h_cmd, (z, vz, truth, reward, alive, p) = jax.device_get(
        rollout(params, jax.random.PRNGKey(seed))
    )
    m = episode_metrics(z, vz, truth, reward, alive, h_cmd)
    hit = (np.asarray(p) > 0.5) == np.asarray(truth, bool)
    m["accuracy"] = float(np.sum(np.where(alive, hit, False)) / max(np.sum(alive), 1))
    m["_p"], m["_truth"], m["_alive"] = p, truth, alive
    m["episode_length_mean"] = float(np.mean(np.asarray(alive).sum(axis=0)))
    m["return_std"] = float(np.std(np.where(alive, reward, 0.0).sum(axis=0)))
    m["wall_s"] = round(time.perf_counter() - t0, 1)
    m["checkpoint"] = str(ckpt)
    return m


def evaluate_run(
    run_dir: str | Path,
    *,
    observe: str | None = None,
    column: str | None = None,
    n_envs: int = 64,
    episode_length: int | None = None,
    seed: int = 12345,
) -> dict:
    """One hop run's latest checkpoint evaluated in one column (``policy-eval``'s hop path).

    Args:
      run_dir: a run folder of :func:`jax_contact.train.ppo.train` of a hop task
        (``task`` "hop" or "hop_blind").
      observe: ``"none"``, ``"truth"`` or ``"estimate"`` (the ``anymal_like`` column);
        None: the variant it was trained with.
      column: a :data:`COLUMNS` name (or ``"none"``), instead of ``observe``.
      n_envs, episode_length, seed: episodes in parallel, their length (None: the
        training configuration's), the PRNG seed.
    """
    run_dir = Path(run_dir)
    run, cfg = _run_cfg(run_dir)
    column = column or observe or run["variant"]
    ev = _hop_evaluator(run, cfg, n_envs, episode_length)
    from jax_contact import metrics

    m = _evaluate(ev, run_dir, column, seed)
    p, truth, alive = (np.asarray(m.pop(k)) for k in ("_p", "_truth", "_alive"))
    contact = metrics.evaluate(
        p[..., None],
        truth[..., None].astype(bool),
        alive[..., None],
        dt=float(ev.task_cfg.n_frames * 0.0025),
    )
    return {
        "contact": contact.as_dict(),
        **m,
        # The keys and paths of a Playground run's evaluation (policy_eval.ColumnEvaluator).
        "run": str(run_dir.absolute()),
        "checkpoint": str(Path(m["checkpoint"]).absolute()),
        "trained_with": run["variant"],
        "run_finished": run.get("finished", True),
        "observed": column,
        "n_episodes": n_envs,
        "return_mean": m["return"],
    }


class _HopCells:
    """The hop task's cells: :class:`_Evaluator`'s rollouts, :data:`METRICS`."""

    metrics = METRICS

    def __init__(self, first_run: Path, n_envs: int, episode_length: int | None):
        self._ev = _hop_evaluator(*_run_cfg(first_run), n_envs, episode_length)

    def cell(self, run_dir: Path, column: str, seed: int, loaded) -> dict:
        m = _evaluate(self._ev, run_dir, column, seed, loaded)
        for k in ("_p", "_truth", "_alive"):
            m.pop(k)
        return m

    @staticmethod
    def line(m: dict) -> str:
        return (
            f"return {m['return']:7.2f} apex err {m['apex_error']:.3f} hops {m['hops']:.2f}"
            f" acc {m['accuracy']:.3f}"
        )


class _Go1Cells:
    """The cells of Go1's joystick and every other Playground task:
    :class:`jax_contact.train.policy_eval.ColumnEvaluator` in the runs' env (``run.json``'s
    ``env``), :data:`GO1_METRICS`."""

    metrics = GO1_METRICS

    def __init__(self, first_run: Path, n_envs: int, episode_length: int | None):
        from jax_contact.train import policy_eval, ppo

        run, cfg = _run_cfg(first_run)
        env_name = run.get("env", ppo.ENV_NAME)
        self._ev = policy_eval.ColumnEvaluator(cfg, n_envs, episode_length, env_name)

    def cell(self, run_dir: Path, column: str, seed: int, loaded) -> dict:
        r = self._ev.evaluate(run_dir, column, seed, loaded)
        return {
            "return": r["return_mean"],
            "return_std": r["return_std"],
            "episode_length": r["episode_length_mean"],
            "fell": r["fell"],
            "accuracy": r["contact"]["accuracy"],
            "f1": r["contact"]["f1"],
            "wall_s": r["wall_s"],
            "checkpoint": r["checkpoint"],
        }

    @staticmethod
    def line(m: dict) -> str:
        return (
            f"return {m['return']:8.2f} ep. length {m['episode_length']:6.1f}"
            f" fell {m['fell']:.2f} acc {m['accuracy']:.3f} F1 {m['f1']:.3f}"
        )


# run.json's task -> its cells (a test swaps in its own); the other Playground tasks
# (tasks.PLAYGROUND_TASK_NAMES) take "go1"'s, in their own env.
_CELLS = {"hop": _HopCells, "hop_blind": _HopCells, "go1": _Go1Cells}


def run_task(run_dir: str | Path) -> str:
    """The task of a run folder: ``run.json``'s ``task``, ``"go1"`` when it has none."""
    from jax_contact.train import ppo

    return ppo.read_run(run_dir).get("task", "go1")


def _load(run_dir: Path, makers: dict):
    """``load_policy(parts=True)`` of the latest checkpoint, with one ``make_policy`` per
    network configuration, so that compiled rollouts are shared across checkpoints."""
    from jax_contact.train import policy_eval
    from jax_contact.train.run_folder import CHECKPOINT_CONFIG

    ckpt = policy_eval.latest_checkpoint(run_dir)
    make_policy, params, sizes = policy_eval.load_policy(ckpt, parts=True)
    net = (ckpt.resolve() / CHECKPOINT_CONFIG).read_text()
    return makers.setdefault(net, make_policy), params, sizes


def transfer_matrix(
    runs: Mapping[str, Sequence[str | Path]],
    *,
    columns: Sequence[str] = COLUMNS,
    n_envs: int = 64,
    episode_length: int | None = None,
    seed: int = 12345,
    log=print,
) -> dict:
    """The transfer matrix over seeds, of hop runs or of runs in a Playground env (Go1's
    joystick, ...).

    Args:
      runs: trained variant -> run folders (one per training seed), all of one task
        (``run.json``'s ``task``; none: ``"go1"``) and one configuration.
      columns: the evaluation columns (:data:`COLUMNS`).
      n_envs, episode_length, seed: as :func:`evaluate_run` (the same episodes everywhere).
      log: where one line per evaluated cell goes.

    Returns:
      ``{"task", "metrics", "cells": {variant: {column: {metric: {"mean", "std",
      "per_seed"}}}}, "columns", "n_envs", "seed", "wall_s"}``; the metrics are the
      task's (:data:`METRICS`, :data:`GO1_METRICS`); each cell is :func:`over_seeds` (a
      seed without a value left out, ``std`` NaN below 2 seeds, ``n_seeds``).

    Raises:
      ValueError: runs of several tasks, an unknown task or column, or none at all.
      FileNotFoundError: a folder without run.json or checkpoint.
    """
    t0 = time.perf_counter()
    dirs_all = [Path(d) for dirs in runs.values() for d in dirs]
    if not dirs_all:
        raise ValueError("runs has no run folder")
    for c in columns:
        column_setting(c)
    found = {d: run_task(d) for d in dirs_all}
    task_names = sorted(set(found.values()))
    if len(task_names) > 1:
        raise ValueError(
            f"runs mixes tasks {task_names}: one matrix per task"
            f" ({', '.join(f'{d} is {t}' for d, t in found.items())})"
        )
    task = task_names[0]
    from jax_contact.train import tasks

    kind = "go1" if task in tasks.PLAYGROUND_TASK_NAMES else task  # Go1's cells, its env
    if kind not in _CELLS:
        raise ValueError(f"run.json's task must be one of {tasks.TASK_NAMES}, got {task!r}")
    cells_of = _CELLS[kind](dirs_all[0], n_envs, episode_length)
    cells: dict = {}
    makers: dict = {}  # one make_policy per network, so rollouts are shared
    for variant, dirs in runs.items():
        cells[variant] = {}
        per_col: dict = {c: [] for c in columns}
        for d in dirs:
            d = Path(d)
            loaded = _load(d, makers)
            if variant == "none":  # sees no contact: one evaluation stands for every column
                m = cells_of.cell(d, "none", seed, loaded)
                log(
                    f"[transfer] {variant:>8s} -> {'(every column)':<15s} {cells_of.line(m)}"
                    f"  ({time.perf_counter() - t0:.0f} s)"
                )
                for c in columns:
                    per_col[c].append(m)
                continue
            for c in columns:
                m = cells_of.cell(d, c, seed, loaded)
                per_col[c].append(m)
                log(
                    f"[transfer] {variant:>8s} -> {c:<15s} {cells_of.line(m)}"
                    f"  ({time.perf_counter() - t0:.0f} s)"
                )
        for c, ms in per_col.items():
            cells[variant][c] = {k: over_seeds([m[k] for m in ms]) for k in cells_of.metrics}
    return {
        "task": task,
        "metrics": list(cells_of.metrics),
        "cells": cells,
        "columns": list(columns),
        "n_envs": n_envs,
        "seed": seed,
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def over_seeds(values) -> dict:
    """One cell's metric over seeds: ``mean`` and ``std`` (population) over the seeds whose
    value is a number, ``n_seeds`` of them, and every seed's value in ``per_seed``.

    A seed without a value (a hop policy that never left the ground has no apex, so its
    ``apex_error`` is NaN) is left out rather than turning the cell NaN; ``std`` is NaN
    below 2 such seeds (one seed has no spread), ``mean`` NaN with none.
    """
    v = np.asarray(values, np.float64)
    ok = v[np.isfinite(v)]
    return {
        "mean": float(ok.mean()) if ok.size else float("nan"),
        "std": float(ok.std()) if ok.size >= 2 else float("nan"),
        "n_seeds": int(ok.size),
        "per_seed": list(values),
    }


def _cell_text(cell: dict) -> str:
    """``mean ± std``; ``n/a`` without a value, no ``±`` for one seed, ``(k of n seeds)``
    when some seeds had no value."""
    mean, std, per = cell["mean"], cell["std"], cell["per_seed"]
    if not np.isfinite(mean):
        return "n/a"
    n = cell.get("n_seeds", len(per))
    text = f"{mean:.3f}" + (f" ± {std:.3f}" if np.isfinite(std) and n >= 2 else "")
    return text + (f" ({n} of {len(per)} seeds)" if n < len(per) else "")


def format_matrix(result: dict, metric: str = "return") -> str:
    """A markdown table of one metric, ``mean ± std`` over seeds (:func:`over_seeds`); a
    note under it where the row ``none`` stands for every column with one evaluation."""
    cols = result["columns"]
    lines = ["| trained with | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for variant, row in result["cells"].items():
        vals = [_cell_text(row[c][metric]) for c in cols]
        lines.append(f"| {variant} | " + " | ".join(vals) + " |")
    if metric in ("accuracy", "f1") and "none" in result["cells"]:
        lines.append(
            "row none: its policy sees no contact, so one evaluation (the estimator on the"
            " training sensors) stands for every column; the estimator's columns are the"
            " other rows'"
        )
    return "\n".join(lines)


def check_runs(runs: Mapping[str, Sequence[str | Path]]) -> list[str]:
    """Refuses runs that cannot share a matrix; returns warnings for those that can, but
    differ in what the matrix does not show.

    Refused (a helper's audit found each run into a matrix without a word): a run whose
    ``run.json`` names another variant than its row (a truth run copied into
    ``seed0/estimate`` filled the estimate row with the truth policy), and runs whose
    training configurations differ (``run.json``'s ``config``; the episode length came
    from the first). Warned: rows over different seeds (each cell's ``n_seeds`` says so,
    the table does not), and runs whose training did not finish (``finished`` false).

    Raises:
      ValueError: naming the run folder and the field.
    """
    from jax_contact.train.ppo import read_run

    infos = {}
    for variant, dirs in runs.items():
        for d in dirs:
            d = Path(d)
            info = read_run(d)  # checked: a damaged run.json is named
            if info["variant"] != variant:
                raise ValueError(
                    f"{d}: its run.json says variant {info['variant']!r}, but it is a run of"
                    f" the {variant!r} row (a copied or moved run folder?)"
                )
            infos[d] = info
    first, *rest = infos
    for d in rest:
        a, b = infos[first].get("config", {}), infos[d].get("config", {})
        if differ := sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k)):
            shown = ", ".join(f"{k} {a.get(k)!r} vs {b.get(k)!r}" for k in differ[:4])
            raise ValueError(
                f"{first} and {d} were trained with other configurations ({shown}"
                f"{', ...' if len(differ) > 4 else ''}): one matrix per configuration"
            )
    notes = []
    seeds = {v: sorted(Path(d).parent.name for d in dirs) for v, dirs in runs.items()}
    if len({tuple(s) for s in seeds.values()}) > 1:
        notes.append(
            "the rows are over different seeds ("
            + "; ".join(f"{v}: {', '.join(s)}" for v, s in seeds.items())
            + "): their means are not over the same training runs"
        )
    if unfinished := [str(d) for d, info in infos.items() if not info.get("finished", True)]:
        notes.append(
            f"training did not finish for {unfinished}: their latest checkpoints are evaluated"
        )
    return notes


def runs_under(root: str | Path, variants: Sequence[str] | None = None) -> dict[str, list[Path]]:
    """``root/seed*/<variant>`` run folders (the layout of ``jax-contact train --task TASK
    --seed S --out root/seedS``), per variant, in seed order.

    Raises:
      FileNotFoundError: a variant has no run folder under ``root``.
    """
    from jax_contact.train import ppo
    from jax_contact.train.cli_args import transfer_root_problem

    root = Path(root)
    if problem := transfer_root_problem(root):
        raise FileNotFoundError(problem)
    found = {
        v: sorted(
            (d for d in root.glob(f"seed*/{v}") if (d / "run.json").is_file()),
            key=lambda d: int(d.parent.name[4:]) if d.parent.name[4:].isdigit() else -1,
        )
        for v in (variants or ppo.VARIANTS)
    }
    empty = [v for v, dirs in found.items() if not dirs]
    own = [v for v in found if (root / v / "run.json").is_file()]
    if empty and own:
        # A seed folder given as root: its runs are one level up from where they are sought.
        if root.name.startswith("seed"):
            hint = f"pass the folder of seed*/ folders, {str(root.parent)!r}"
        else:  # not named seed*: its parent holds no seed*/ either (a helper's dead end)
            hint = (
                f"the matrix reads ROOT/seed*/<variant>: move it to ROOT/seed0 (e.g. mv"
                f" {str(root)!r} {str(root.parent / 'seeds' / 'seed0')!r}) and pass ROOT"
            )
        raise FileNotFoundError(
            f"{root} holds run folders itself ({', '.join(own)}): it is one seed's folder; {hint}"
        )
    if empty:
        raise FileNotFoundError(
            f"no run folder {root}/seed*/{empty[0]} (with a run.json): the matrix has a row per"
            f" variant {tuple(found)}; train the missing ones (jax-contact train --variants"
            f" {' '.join(empty)} --seed S --out {root}/seedS)"
        )
    return found


def main(argv: Sequence[str] | None = None) -> dict:
    """``python -m jax_contact.train.transfer ROOT [--envs N] [--episode-length T] [--json
    FILE]``: the matrix of every ``ROOT/seed*/<variant>`` run (hop or Go1, by their
    run.json), printed per metric, written atomically as JSON."""
    import argparse

    from jax_contact.train.cli_args import add_transfer_arguments, check_transfer

    parser = argparse.ArgumentParser(
        prog="python -m jax_contact.train.transfer", description=__doc__.splitlines()[0]
    )
    add_transfer_arguments(parser)
    args = parser.parse_args(argv)
    try:
        check_transfer(args)  # before the matrix's minutes, not after
    except ValueError as err:
        parser.error(str(err))
    return run_transfer(args, parser.error)


def run_transfer(args, error) -> dict:
    """The matrix of ``args`` (:func:`jax_contact.train.cli_args.add_transfer_arguments`'s),
    printed per metric and written as JSON; ``error(message)`` reports a bad ``root``."""
    from jax_contact.io import write_json_atomic
    from jax_contact.train.compile_cache import enable_compilation_cache
    from jax_contact.train.policy_eval import latest_checkpoint
    from jax_contact.train.ppo import read_run

    try:
        runs = runs_under(args.root)
        tasks = {run_task(d) for dirs in runs.values() for d in dirs}
        # Every run's checkpoint found before the first cell: a run without one (stopped
        # before its first save) failed after every earlier run had been evaluated.
        for dirs in runs.values():
            for d in dirs:
                latest_checkpoint(d)
        notes = check_runs(runs)
    except (FileNotFoundError, ValueError) as err:  # ValueError: a damaged run.json
        error(f"argument root: {err}")
    if len(tasks) > 1:
        error(f"argument root: {args.root} holds runs of several tasks {sorted(tasks)}")
    for note in notes:
        print(f"warning: {note}", file=sys.stderr)
    enable_compilation_cache()
    res = transfer_matrix(
        runs, n_envs=args.envs, episode_length=args.episode_length, seed=args.seed
    )
    res["runs"] = {v: [str(d) for d in dirs] for v, dirs in runs.items()}
    for metric in res["metrics"]:
        print(f"\n{metric}\n{format_matrix(res, metric)}")
    res["episode_length"] = args.episode_length  # None: each run's own
    res["config"] = read_run(next(iter(runs.values()))[0])["config"]
    res["warnings"] = notes
    if args.json:
        write_json_atomic(args.json, res)
        print(f"wrote {args.json}")
    return res


if __name__ == "__main__":
    main()
