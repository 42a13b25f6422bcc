"""How the physics-rate estimator reaches the substep loop: one hook, two frameworks.

Both frameworks run an env step's physics substeps in one function that the env looks up
when its ``step`` is traced:

- Playground: every ``MjxEnv`` calls ``mjx_env.step(model, data, action, n_substeps)``
  (``mujoco_playground._src.mjx_env``, a ``lax.scan`` of ``mjx.step``), a module
  attribute read at call time;
- Brax: ``PipelineEnv.step`` calls ``self.pipeline_step(pipeline_state, action)``, a
  method (an instance attribute of the same name shadows it) that scans
  ``n_frames = dt / sys.opt.timestep`` pipeline steps.

:func:`hooked` replaces that function, *for the duration of one call of the wrapped env's
``step``* (that is, while it is traced under ``jit``, or while it runs eagerly), by a loop
that runs the same physics steps, one at a time, and an estimator update after each,
carrying the estimator state through its own ``scan``; the original is restored when the
call returns or raises. The compiled step then holds both. The Playground loop calls the
original ``mjx_env.step`` with ``n_substeps=1`` per substep (its physics is exactly
Playground's); the Brax loop calls ``brax.mjx.pipeline.step(env.sys, ...)``, what
``PipelineEnv.pipeline_step`` scans. If the env calls the loop several times in one step,
the estimator state is chained through the calls. If it never calls it, the wrapper
refuses (``rate="control"`` then).

Only one physics-rate wrapper can hook an env (a second one finds the hook in place and
refuses); control-rate wrappers nest freely inside it. The replacement is a process-wide
module attribute for Playground while one ``step`` is traced: tracing two wrapped
Playground envs concurrently from two threads is not supported.
"""

from __future__ import annotations

import contextlib

import jax
from brax.mjx import pipeline as brax_mjx_pipeline
from mujoco_playground._src import mjx_env

_MISSING = object()
_TAG = "_jax_contact_substep_hook"


@contextlib.contextmanager
def hooked(owner, name: str, fn):
    """``owner.name = fn`` for a while; restores what was there (also on error)."""
    current = getattr(owner, name, None)
    if getattr(current, _TAG, False):
        raise ValueError(
            f"{name} is already hooked by a physics-rate contact wrapper: only one can wrap"
            " an env (give the others config.rate='control')"
        )
    setattr(fn, _TAG, True)
    before = vars(owner).get(name, _MISSING)
    setattr(owner, name, fn)
    try:
        yield
    finally:
        if before is _MISSING:
            delattr(owner, name)
        else:
            setattr(owner, name, before)


class Chain:
    """The estimator state threaded through the loop calls of one step, and their records."""

    def __init__(self, est, update, record):
        self.est, self.update, self.record, self.records = est, update, record, []

    def run(self, physics_step, carry_data, n: int):
        def body(carry, _):
            d, e = carry
            d = physics_step(d)
            e = self.update(e, d)
            return (d, e), self.record(e, d)

        (d, self.est), rec = jax.lax.scan(body, (carry_data, self.est), (), n)
        self.records.append(rec)
        return d


def playground_step(env, state, action, chain: Chain):
    """The wrapped Playground env's ``step`` with ``mjx_env.step`` hooked (docstring)."""
    original = mjx_env.step

    def step(model, data, act, n_substeps: int = 1):
        return chain.run(lambda d: original(model, d, act, 1), data, int(n_substeps))

    with hooked(mjx_env, "step", step):
        return env.step(state, action)


def brax_step(env, inner, state, action, chain: Chain, n_frames: int):
    """The wrapped Brax env's ``step`` with ``inner.pipeline_step`` hooked (docstring).

    ``n_frames``: ``env.dt / sys.opt.timestep``, read when the env was wrapped.
    """

    def pipeline_step(pipeline_state, act):
        return chain.run(
            lambda ps: brax_mjx_pipeline.step(inner.sys, ps, act), pipeline_state, n_frames
        )

    with hooked(inner, "pipeline_step", pipeline_step):
        return env.step(state, action)
