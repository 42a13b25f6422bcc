"""The env batch sharded over 8 simulated CPU devices gives the unsharded result.

Runs in a subprocess, since the device count must be set before JAX starts.
"""

from jax_contact.benchmarks.versus import sharded


def test_sharded_equals_unsharded():
    out = sharded(n_envs=64, devices=8)
    assert out["devices"] == 8
    assert "envs" in out["sharding_of_output"]  # the output stays split along envs
    # Each env's arithmetic is the same program on the same inputs on whichever device
    # holds it; only XLA's per-device fusion could differ, so allow float32 round-off.
    assert out["max_abs_diff"] <= 1e-6
