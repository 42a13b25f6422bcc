"""Helpers shared by the wrapper tests (tests/test_wrapper*.py)."""

from __future__ import annotations

import jax
import numpy as np


class Traced:
    """``jax.jit(fn)`` that counts its traces and returns strongly typed arrays.

    Playground's Go1 returns one weakly typed metric from ``step`` and a strong one from
    ``reset``, which would compile ``step`` twice; casting the outputs keeps one compile.
    ``traces`` checks that the wrapped functions do not retrace in a loop.
    """

    def __init__(self, fn):
        self.traces = 0

        def counted(*args):
            self.traces += 1
            out = fn(*args)
            return jax.tree.map(lambda x: jax.lax.convert_element_type(x, x.dtype), out)

        self._jitted = jax.jit(counted)

    def __call__(self, *args):
        return self._jitted(*args)


def logit_of(state, key="contact_est"):
    """(n_envs, n_feet) belief logits the wrapper keeps under ``state.info[key]``."""
    return np.asarray(state.info[key].belief.logit)
