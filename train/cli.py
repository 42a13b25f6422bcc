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
    from benchmarks import suite

    argv = ["--json", args.json] if args.json else []
    if args.envs:
        argv += ["--envs", *map(str, args.envs)]
    if args.versus_envs:
        argv += ["--versus-envs", *map(str, args.versus_envs)]
    suite.main(argv)
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    import dataclasses

    from train import ppo

    cfg = ppo.CONFIGS[args.config]
    if args.timesteps:
        cfg = dataclasses.replace(cfg, num_timesteps=args.timesteps)
    ppo.train_variants(
        cfg,
        args.out,
        variants=args.variants,
        seed=args.seed,
        overwrite=args.overwrite,
        eval_envs=args.eval_envs,
        log=ppo.main_log,
    )
    return 0


def _cmd_policy_eval(args: argparse.Namespace) -> int:
    from jax_contact.io import write_json_atomic
    from train import ppo

    res = ppo.evaluate_policy(args.run, observe=args.observe, n_envs=args.envs, seed=args.seed)
    print(ppo.format_evaluation([res]))
    c = res["contact"]
    print(
        f"contact: touch-down delay {c['touchdown_delay_ms'][0]:.1f} +- "
        f"{c['touchdown_delay_ms'][1]:.1f} ms, failures {c['failures']}, Brier {c['brier']:.3f}"
    )
    if args.json:
        write_json_atomic(args.json, res)
    return 0


def _cmd_rates(args: argparse.Namespace) -> int:
    from jax_contact.io import write_json_atomic
    from train import rates

    out = rates.run(args.scenes, seed=args.seed, pairing=args.pairing)
    if args.json:
        write_json_atomic(args.json, out)
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

    p = sub.add_parser(
        "train", help="PPO on Go1 with no / true / estimated contact in the observation"
    )
    p.add_argument(
        "--variants",
        nargs="+",
        default=["none", "truth", "estimate"],
        choices=("none", "truth", "estimate"),
    )
    p.add_argument(
        "--config",
        choices=("small", "full"),
        default="small",
        help="small: this 2-core CPU, <= 20 min per variant; full: a GPU",
    )
    p.add_argument("--timesteps", type=int, default=None, help="override num_timesteps")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-envs", type=int, default=64, help="episodes of the final evaluation")
    p.add_argument("--out", default="out/train")
    p.add_argument("--overwrite", action="store_true", help="replace existing run folders")
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("policy-eval", help="evaluate a trained policy (returns, contact metrics)")
    p.add_argument("run", help="a run folder of `jax-contact train`, e.g. out/train/estimate")
    p.add_argument(
        "--observe",
        choices=("none", "truth", "estimate"),
        default=None,
        help="contact the policy sees now (default: what it was trained with)",
    )
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--seed", type=int, default=12345)
    p.add_argument("--json", default=None)
    p.set_defaults(func=_cmd_policy_eval)

    p = sub.add_parser(
        "rates", help="estimator at every physics step vs once per control step, same rollouts"
    )
    p.add_argument(
        "--scenes", nargs="+", default=["planar_leg", "go1"], choices=("planar_leg", "go1")
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--pairing",
        default="delayed",
        choices=("delayed", "raw"),
        help="state the differenced acceleration is paired with (ContactObsConfig.pairing)",
    )
    p.add_argument("--json", default=None)
    p.set_defaults(func=_cmd_rates)

    p = sub.add_parser(
        "bench",
        help="estimator throughput, latency and memory; ratio to mjx.step, NumPy, sharding",
    )
    p.add_argument("--json", default=None, help="write every result as one JSON here")
    p.add_argument("--envs", type=int, nargs="+", default=None, help="throughput batch sizes")
    p.add_argument(
        "--versus-envs", type=int, nargs="+", default=None, help="batch sizes vs mjx.step"
    )
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
