"""The env batch sharded over 8 simulated CPU devices gives the unsharded result.

Runs in a subprocess, since the device count must be set before JAX starts.
"""

import pytest

from jax_contact.benchmarks.versus import sharded


def test_sharded_equals_unsharded():
    out = sharded(n_envs=64, devices=8)
    assert out["devices"] == 8
    assert "envs" in out["sharding_of_output"]  # the output stays split along envs
    # Each env's arithmetic is the same program on the same inputs on whichever device
    # holds it; only XLA's per-device fusion could differ, so allow float32 round-off.
    assert out["max_abs_diff"] <= 1e-6


def test_bench_finds_the_library_and_the_oracle_where_a_wheel_has_them(monkeypatch, tmp_path):
    """The sharding subprocess imports the library from the folder that holds the package
    (never from inside it: its types.py and io.py would hide the standard library's, as
    they did for an installed wheel); without tests/oracle.py (a wheel) the NumPy
    comparison says why it cannot run instead of an ImportError."""
    from jax_contact.benchmarks import versus

    assert (versus.SITE / "jax_contact" / "__init__.py").is_file()
    assert not (versus.SITE / "types.py").exists()
    monkeypatch.setattr(versus, "ORACLE_DIR", tmp_path)
    with pytest.raises(FileNotFoundError, match=r"oracle.py, which a source checkout has"):
        versus.numpy_speedup(4, 1)
