"""The ``jax-contact`` command line: a thin layer that parses arguments and calls library code."""

from __future__ import annotations

import argparse
import sys


def _cmd_demo(args: argparse.Namespace) -> int:
    import dataclasses

    from train import reproduce

    reproduce.run(dataclasses.replace(reproduce.DEMO, seed=args.seed), args.out)
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    import dataclasses

    from train import reproduce

    cfg = reproduce.FULL if args.size == "full" else reproduce.DEMO
    overrides = {k: v for k, v in (("robot", args.robot), ("seed", args.seed)) if v is not None}
    reproduce.run(dataclasses.replace(cfg, **overrides), args.out)
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from train import logs

    logs.simulate_to_file(
        args.output,
        robot=args.robot,
        gait=args.gait,
        noise=args.noise,
        terrain=args.terrain,
        n_envs=args.envs,
        duration=args.duration,
        seed=args.seed,
    )
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from train import logs

    logs.evaluate_file(args.log, json_path=args.json)
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from benchmarks import estimator

    argv = ["--json", args.json] if args.json else []
    if args.envs:
        argv += ["--envs", *map(str, args.envs)]
    estimator.main(argv)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jax-contact",
        description="Probabilistic foot contact estimation (Hwangbo et al., IROS 2016) in JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("demo", help="the reproduction at its default size (what `make demo` runs)")
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    p.add_argument("--seed", type=int, default=0, help="evaluation seed (default: 0)")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("reproduce", help="Section III, Table III and the ablation in simulation")
    p.add_argument("--size", choices=("demo", "full"), default="demo")
    p.add_argument("--robot", default=None, help="quadruped of Table III (default: go1)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--out", default="out/reproduce")
    p.set_defaults(func=_cmd_reproduce)

    p = sub.add_parser("simulate", help="simulate scripted robots and save the logs as HDF5")
    p.add_argument("output", help="the .h5 file to write (atomically)")
    p.add_argument("--robot", default="go1")
    p.add_argument("--gait", default="trot", choices=("trot", "walk", "hop"))
    p.add_argument("--noise", default="anymal_like", choices=("ideal", "anymal_like", "harsh"))
    p.add_argument("--terrain", default="flat", choices=("flat", "rough"))
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--duration", type=float, default=10.0, help="simulated seconds")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("evaluate", help="run the estimator and baselines on a saved log")
    p.add_argument("log", help="an .h5 log written by `jax-contact simulate`")
    p.add_argument("--json", default=None, help="write the metrics here")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser("bench", help="estimator throughput, latency and memory")
    p.add_argument("--json", default=None)
    p.add_argument("--envs", type=int, nargs="+", default=None)
    p.set_defaults(func=_cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as err:
        print(f"jax-contact {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
