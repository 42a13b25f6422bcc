"""Fit and check the closed-loop hop of Berkeley Humanoid (jax_contact.envs.biped_hop).

MuJoCo (C) on Playground's ``BerkeleyHumanoidJoystickFlatTerrain`` model, 20 ms control
(:func:`jax_contact.envs.biped_hop.run_mujoco`). A rollout ``s`` draws, from
``numpy.random.default_rng(s)``, its phase U(0, 1), its rate 1 + U(-0.1, 0.1), then an
env-like reset (random yaw, joint angles x U(0.5, 1.5), base velocity U(-0.5, 0.5)).

- ``--fit ITERS``: cross-entropy search (40 samples an iteration, the best 8 kept) from
  the shipped gains (or ``--start JSON``) on the fitting seeds 100-109, objective: mean
  time upright over 4 s plus twice the mean, over rollouts, of the smaller air share of
  the two feet capped at 0.2; prints the best gains each iteration.
- always: the gains (shipped, or the fit's) on the held-out seeds 110-149 for 6 s and on
  10 starts from rest at phases 0, 0.1, ..., 0.9: upright counts, air share, lift-offs.

    python -m jax_contact.benchmarks.biped_hop_fit --json out/biped_hop.json
    python -m jax_contact.benchmarks.biped_hop_fit --fit 14 --json out/biped_hop_fit.json

The shipped gains came from this search (14 iterations, an earlier fall test: base below
0.3 m or |roll| + |pitch| > 0.9 rad, where :func:`biped_hop.fallen` tests the tilt > 0.8
rad).
"""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np

from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    json_of_what_finished,
    machine,
    print_table,
    run_main,
)
from jax_contact.envs import biped_hop as bh
from jax_contact.train.cli_args import nonnegative_int

FIT_SEEDS = tuple(range(100, 110))
HELD_OUT = tuple(range(110, 150))
FIELDS = tuple(f.name for f in dataclasses.fields(bh.HopGains))
# Search box, in FIELDS order.
LOW = np.array([1.5, 0.2, 0.0, -4, -0.4, 0, 0, -4, -0.4, -2, -2])
HIGH = np.array([3.5, 0.5, 1.0, 4, 0.4, 8, 0.5, 4, 0.4, 2, 2])


def rollout(env, gains: bh.HopGains, seed: int, t_end: float) -> bh.HopRun:
    rng = np.random.default_rng(seed)
    phase0, rate = rng.uniform(), 1 + 0.1 * rng.uniform(-1, 1)
    return bh.run_mujoco(env, gains, t_end=t_end, phase0=phase0, rate=rate, reset_rng=rng)


def objective(env, gains: bh.HopGains, seeds=FIT_SEEDS, t_end: float = 4.0) -> float:
    runs = [rollout(env, gains, s, t_end) for s in seeds]
    return float(
        np.mean([r.upright_s for r in runs])
        + 2 * np.mean([min(r.air_share.min(), 0.2) for r in runs])
    )


def fit(env, start: bh.HopGains, iters: int, seed: int = 0, log=print) -> bh.HopGains:
    rng = np.random.default_rng(seed)
    mu = np.array([getattr(start, f) for f in FIELDS])
    sd = (HIGH - LOW) / 6
    for it in range(iters):
        xs = np.clip(mu + sd * rng.normal(size=(40, len(FIELDS))), LOW, HIGH)
        xs[0] = mu
        scores = np.array([objective(env, bh.HopGains(*map(float, x))) for x in xs])
        elite = xs[np.argsort(-scores)[:8]]
        mu, sd = elite.mean(0), np.maximum(elite.std(0), (HIGH - LOW) / 60)
        log(f"iter {it}: best {scores.max():.3f}, elite mean {np.sort(scores)[-8:].mean():.3f}")
    return bh.HopGains(*map(float, mu))


def check(env, gains: bh.HopGains) -> list[dict]:
    rows = []
    held = [rollout(env, gains, s, 6.0) for s in HELD_OUT]
    rest = [bh.run_mujoco(env, gains, t_end=6.0, phase0=p) for p in np.arange(10) / 10]
    for name, runs, t_end in (("held-out resets", held, 6.0), ("from rest", rest, 6.0)):
        up = [r for r in runs if r.upright_s == t_end]
        rows.append(
            {
                "starts": name,
                "n": len(runs),
                "upright": len(up),
                "fell_at_s": [round(r.upright_s, 2) for r in runs if r.upright_s < t_end],
                "air_share": float(np.mean([r.air_share for r in up])) if up else float("nan"),
                "liftoffs_per_cycle": (
                    float(np.mean([r.liftoffs for r in up])) / (gains.freq * t_end)
                    if up
                    else float("nan")
                ),
            }
        )
    return rows


def main(argv=None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument(
        "--fit", type=nonnegative_int, default=0, help="CEM iterations (0: check only)"
    )
    parser.add_argument(
        "--start",
        default=None,
        help="a JSON string (not a file) of HopGains fields to start from, e.g."
        """ '{"freq": 2.0}'""",
    )
    parser.add_argument("--json", default=None, help="write the gains and rows here")
    args = parser.parse_args(argv)
    check_json_arg(parser, args.json)
    gains = bh.BERKELEY_HOP
    if args.start:  # checked before the env loads
        try:
            start = json.loads(args.start)
            if not isinstance(start, dict):
                raise ValueError(f"a JSON object of fields, got {type(start).__name__}")
            gains = dataclasses.replace(gains, **start)
        except (ValueError, TypeError) as err:  # bad JSON, an unknown field
            fields = [f.name for f in dataclasses.fields(gains)]
            parser.error(f"argument --start: {err} (HopGains fields: {fields})")
    from jax_contact.envs import playground_offline

    env = playground_offline.load("BerkeleyHumanoidJoystickFlatTerrain")
    result = {"machine": machine(), "args": vars(args)}
    with json_of_what_finished(args.json, result):
        if args.fit:
            t0 = time.perf_counter()
            gains = fit(env, gains, args.fit)
            result["fit_s"] = time.perf_counter() - t0
        result["gains"] = {f: round(getattr(gains, f), 4) for f in FIELDS}
        print("gains:", json.dumps(result["gains"]))
        result["rows"] = check(env, gains)
    print_table(
        result["rows"],
        [
            ("starts", "starts", "{}"),
            ("n", "n", "{}"),
            ("upright", "upright 6 s", "{}"),
            ("fell_at_s", "fell at (s)", "{}"),
            ("air_share", "air share", "{:.2f}"),
            ("liftoffs_per_cycle", "lift-offs/cycle", "{:.2f}"),
        ],
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main(main, "biped_hop_fit"))
