"""The library's profiler scopes: every piece of the paper's update is named in the compiled
program, so a ``jax.profiler`` trace (and ``jax_contact.benchmarks.profile_pieces --trace``) can
charge each kernel to the function it came from."""

from __future__ import annotations

import re

import jax
import pytest

import jax_contact as jc
from jax_contact.benchmarks.common import synthetic
from jax_contact.benchmarks.profile_pieces import SCOPES, _scope

# Each layout has its own split; the finiteness check reads the split blocks in both.
PER_LAYOUT = {
    "robot": set(SCOPES) - {"leg_blocks"},
    "per_foot": set(SCOPES) - {"robot_leg_blocks"},
}


@pytest.mark.parametrize("layout", sorted(PER_LAYOUT))
def test_every_piece_is_named_in_the_compiled_step(layout):
    params = jc.make_params(jc.make_noise(18), touchdown="quadrature")
    meas = synthetic(2, layout)
    belief = jc.init_belief_batch(params, 2, 4)

    def update(b, m, k):
        return jc.step_batch(params, jc.flat(), b, m, key=k)

    text = jax.jit(update).lower(belief, meas, jax.random.key(0)).compile().as_text()
    op_names = re.findall(r'op_name="([^"]*)"', text)
    assert {_scope(name) for name in op_names} >= PER_LAYOUT[layout]


def test_scope_is_the_innermost_library_function():
    assert _scope("jit(f)/vmap(vmap(dynamics_llr))/jit(_where)/select_n") == "dynamics_llr"
    assert _scope("jit(f)/vmap(diff_kinematics_llr)/dot_general") == "diff_kinematics_llr"
    assert _scope("jit(f)/log_touchdown/kinematics_llr/x") == "kinematics_llr"
    assert _scope("jit(f)/vmap()/concatenate").startswith("other")


def test_bench_help_shows_defaults_but_not_none(capsys):
    """The benchmarks' ``--help`` appended "(default: None)" to options whose help says
    what leaving them out does (``--json``); they share the CLI's formatter now."""
    from jax_contact.benchmarks.common import bench_parser

    parser = bench_parser("A benchmark.\n\nMore.")
    parser.add_argument("--envs", type=int, default=16, help="batch size")
    parser.add_argument("--json", default=None, help="write the rows here")
    with pytest.raises(SystemExit):
        parser.parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "batch size (default: 16)" in text
    assert "write the rows here" in text and "(default: None)" not in text
