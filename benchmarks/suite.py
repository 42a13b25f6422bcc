"""Every number of the benchmarks issue in one run and one JSON: the estimator, then versus.

Run::

    python -m jax_contact.benchmarks.suite --json out/bench.json [--envs 1 1024 4096] \
        [--versus-envs 1024]

``jax-contact bench`` runs this. It runs :mod:`jax_contact.benchmarks.estimator` (throughput at each
batch size, single-robot latency, memory) and then :mod:`jax_contact.benchmarks.versus` (ratio to
``mjx.step``, speed-up over per-robot NumPy, sharding), prints both sets of tables, and
writes one JSON holding the keys of both: ``machine``, ``throughput``,
``latency_batch1_us``, ``bytes_per_env``, ``ratio_vs_mjx_step``, ``speedup_vs_numpy``,
``sharding`` and their details. When a part fails, the JSON holds what finished and an
``error`` key.
"""

from __future__ import annotations

from jax_contact.benchmarks import estimator, versus
from jax_contact.benchmarks.common import (
    bench_parser,
    check_json_arg,
    json_of_what_finished,
    run_main,
)
from jax_contact.train.cli_args import BENCH_HELP, positive_int  # the CLI's: one rule, one help


def main(argv=None) -> dict:
    """Runs both benchmarks; with ``--json``, writes what finished even when a part fails
    (then with an ``"error"`` key saying what stopped it)."""
    parser = bench_parser(__doc__)  # every default shown in --help
    # Sizes are checked here, before minutes of benchmarks run on them.
    for flag, kwargs in (
        ("--envs", {"nargs": "+", "default": list(estimator.DEFAULT_ENVS)}),
        ("--versus-envs", {"nargs": "+", "default": [1024, 4096]}),
        ("--latency-calls", {"default": 10_000}),
    ):
        parser.add_argument(flag, type=positive_int, help=BENCH_HELP[flag], **kwargs)
    parser.add_argument("--json", default=None, help="write all results as one JSON here")
    args = parser.parse_args(argv)
    check_json_arg(parser, args.json)

    result: dict = {}
    with json_of_what_finished(args.json, result):
        vs: dict = {}
        try:
            estimator.main(  # fills result as it measures: what finished stays on an error
                # (Ctrl-C writes nothing, as everywhere)
                ["--envs", *map(str, args.envs), "--latency-calls", str(args.latency_calls)],
                into=result,
            )
            print()
            versus.run(args.versus_envs, into=vs)
        finally:
            # Both measured on the same machine in this process; the estimator's description
            # stands.
            result.update({k: v for k, v in vs.items() if k != "machine"})
            # The suite's own arguments, not the estimator's part of them (which had
            # "json": null and no --versus-envs), also in a file an error cut short.
            result["args"] = vars(args)
    return result


if __name__ == "__main__":
    raise SystemExit(run_main(main, "suite"))
