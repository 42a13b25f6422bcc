"""Shared pytest fixtures: generic helpers only.

* ``x64``: float64 JAX for one test.
* ``np_rng``: a NumPy generator seeded from the test's id (independent of test order).
* the ``slow`` marker, for tests that take tens of seconds on 2 CPU cores.
* ``jit_step``, ``jit_step_batch``, ``jit_run``: the estimator's entry points jitted once
  per session, so every test file that calls them with the same shapes and static
  parameters shares one compilation; each counts its traces (see :class:`CountingJit`).

JAX's persistent compilation cache is on for the whole suite, in the folder the command
line uses (``jax_contact.train.compile_cache.enable_compilation_cache``:
``~/.cache/jax-contact/xla``, or ``$JAX_CONTACT_CACHE_DIR``, empty for off), set before JAX
is imported so that every pytest-xdist worker and every subprocess a test starts (the CLI,
the README's blocks) shares it: a second ``make test`` loads the programs the first one
compiled. Tracing still runs, so tests that count traces are unaffected.
"""

from __future__ import annotations

import collections
import os
import zlib

from jax_contact.train.compile_cache import enable_compilation_cache

enable_compilation_cache()  # before JAX is imported: through JAX's environment variables
# Importing JAX sets TF_CPP_MIN_LOG_LEVEL=1 when it is unset, and every subprocess a test
# starts (the CLI, the README's blocks) would inherit that and print XLA's E-level lines
# (e.g. loading a cached program); the CLI's own default for a user who set nothing is 3.
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import jax_contact  # noqa: E402


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "slow: takes tens of seconds on 2 CPU cores (deselect with -m 'not slow')"
    )


@pytest.fixture
def x64():
    """Enables float64 in JAX for the duration of one test, then restores the setting.

    ``jax.enable_x64`` (jax 0.9; there is no ``jax.experimental.enable_x64`` any more) is a
    context manager over the config option; jit traces made inside it see float64 and are
    cached apart from float32 ones. Build float64 arrays *inside* the test that uses this.
    """
    with jax.enable_x64(True):
        yield


@pytest.fixture
def np_rng(request) -> np.random.Generator:
    """A NumPy generator seeded from the test's own id: stable, independent of test order."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


def _signature(args, kwargs) -> str:
    """What jit's cache is keyed on: the pytree structure (static fields included), the
    shape and dtype of every leaf, and the float64 switch."""
    leaves, treedef = jax.tree.flatten((args, kwargs))
    avals = tuple((np.shape(x), str(getattr(x, "dtype", type(x)))) for x in leaves)
    return f"{treedef}|{avals}|x64={jax.config.jax_enable_x64}"


class CountingJit:
    """``jax.jit(fn)`` that counts how often ``fn`` is traced, per abstract signature.

    ``traces[sig] > 1`` means jit traced the same shapes and static values again.
    """

    def __init__(self, fn):
        self.fn = fn
        self.traces: collections.Counter[str] = collections.Counter()
        self._jitted = jax.jit(self._traced)

    def _traced(self, *args, **kwargs):
        self.traces[_signature(args, kwargs)] += 1
        return self.fn(*args, **kwargs)

    def __call__(self, *args, **kwargs):
        return self._jitted(*args, **kwargs)


@pytest.fixture(scope="session")
def jit_step() -> CountingJit:
    return CountingJit(jax_contact.step)


@pytest.fixture(scope="session")
def jit_step_batch() -> CountingJit:
    return CountingJit(jax_contact.step_batch)


@pytest.fixture(scope="session")
def jit_run() -> CountingJit:
    return CountingJit(jax_contact.run)
