"""What a long command shows on stderr while it works: compilations and loop progress.

On a 2-core CPU most of a short run's wall time is XLA compiling (``docs/performance.md``),
during which a program is silent for tens of seconds. Three pieces, standard library only at
import (``jax_contact.train.cli`` imports this module before it may import JAX):

- :func:`watch_compiles` (``jax-contact`` wraps every command in it): whenever JAX traces,
  lowers or compiles for longer than ``min_s`` (1 s; 5 s when stderr is not a terminal),
  stderr shows ``jax-contact simulate: compiling (first call)... 12 s``, counting on a
  terminal, then ``jax-contact simulate: compiled in 14.2 s (0 of 3 from the compilation
  cache)``. With
  the persistent cache warm the programs load from it and the time left is JAX's tracing.
  It listens to JAX's own compile events (:mod:`jax.monitoring`: the start and the
  duration of ``/jax/core/compile/*``, the cache's hit and miss events), so it sees every
  ``jit`` of every module without their help.
- :func:`compiling` names what compiles (``compiling the rollout (first call)...``) inside a
  watcher; outside one (a library call from Python) it is itself the timer, shown when the
  block takes longer than ``min_s``.
- :func:`bar` wraps a loop: a ``tqdm`` bar on a terminal; elsewhere (a log file, CI, a
  pipe) a plain line at most every 10 s and one at the end, e.g. ``replay: 3/8 chunks,
  41 s, about 68 s left``. The first item is not shown as a bar step: it usually holds
  the compilation, which the watcher reports.

``JAX_CONTACT_PROGRESS=0`` turns all three off (errors and results are still printed).

The library's long loops use :func:`bar`: the chunks of ``envs.simulate.simulate`` and of
``train.evaluate.replay``, the scenes of ``jax-contact rates``; their ``progress`` flag
turns it off. A loop body that calls a jitted function should wait for its result
(``jax.device_get`` / ``np.asarray``) inside the iteration, since JAX dispatches
asynchronously and the bar would otherwise run ahead of the work. ``bar`` needs ``len()``
of what it wraps (or ``total=``) to show a fraction and an estimate. From a notebook or
script (not ``jax-contact``), wrap the work in ``with pg.watch_compiles("my run"):`` to
get the compile lines too.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TextIO, TypeVar

T = TypeVar("T")

ENV_SWITCH = "JAX_CONTACT_PROGRESS"
# s: shorter compilations (and persistent-cache hits) are not shown; in a log (not a
# terminal) a line is only worth it for a silence longer than a few seconds.
MIN_S, MIN_S_LOG = 1.0, 5.0
PLAIN_EVERY_S = 10.0  # s between plain progress lines (not a terminal)
_COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)

_active: _Watcher | None = None  # the watcher of watch_compiles, if one runs


def is_enabled() -> bool:
    """False when ``JAX_CONTACT_PROGRESS`` is ``0``, ``false``, ``no`` or ``off``."""
    return os.environ.get(ENV_SWITCH, "1").strip().lower() not in ("0", "false", "no", "off")


def _is_tty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class _Timer:
    """A line on ``stream`` that says ``{prefix}compiling{what} (first call)... N s`` while a
    span lasts longer than ``min_s``, then ``{prefix}compiled{what} in N s`` (``loaded{what}
    from the compilation cache in N s`` when every program came from the persistent cache).

    A span opens at :meth:`begin` and closes at an :meth:`end` with ``last=True`` that
    leaves no phase running (JAX traces, lowers and compiles one function as three phases,
    nested for nested ``jit``), or after ``GAP_S`` with no phase running (a trace that
    compiled nothing, e.g. ``jax.eval_shape``).
    """

    GAP_S = 2.0

    def __init__(
        self,
        prefix: str,
        stream: TextIO,
        min_s: float | None,
        doing: str = "compiling{what} (first call)",
        done: str = "compiled{what}",
        cached: str | None = "loaded{what} from the compilation cache",
    ):
        self.prefix, self.stream, self.doing, self.done = prefix, stream, doing, done
        self.cached = cached  # the final line when every program came from the cache
        self.tty = _is_tty(stream)
        self.min_s = (MIN_S if self.tty else MIN_S_LOG) if min_s is None else min_s
        self.what = ""
        self.cache_hits = self.cache_misses = 0  # XLA programs of the span, persistent cache
        self._depth = 0
        self._open = False
        self._since = self._idle_since = 0.0
        self._shown = False
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="jax-contact-progress", daemon=True)
        self._thread.start()

    def begin(self) -> None:
        with self._lock:
            if not self._open:
                self._open, self._since, self._shown = True, time.monotonic(), False
            self._depth += 1
        self._wake.set()

    def end(self, *, last: bool = True) -> None:
        with self._lock:
            self._depth = max(self._depth - 1, 0)
            if self._depth == 0:
                if last:
                    self._finish()
                else:
                    self._idle_since = time.monotonic()

    def close(self) -> None:
        with self._lock:
            self._depth = 0
            self._finish()
        self._stop = True
        self._wake.set()
        self._thread.join(1.0)

    def _finish(self) -> None:
        # Called with the lock held.
        if self._open and self._shown:
            elapsed = time.monotonic() - self._since
            n = self.cache_hits + self.cache_misses
            if n and self.cache_hits == n and self.cached is not None:
                # Nothing was compiled: every program was read from the persistent cache.
                done, note = self.cached.format(what=self.what), ""
            else:
                done = self.done.format(what=self.what)
                note = f" ({self.cache_hits} of {n} from the compilation cache)" if n else ""
            self._write(f"{self.prefix}{done} in {elapsed:.1f} s{note}", final=True)
        self._open = False
        self.cache_hits = self.cache_misses = 0

    def _write(self, text: str, *, final: bool) -> None:
        # Called with the lock held. A terminal gets one line rewritten in place.
        try:
            if self.tty:
                self.stream.write(f"\r{text}\033[K" + ("\n" if final else ""))
            else:
                self.stream.write(text + "\n")
            self.stream.flush()
        except (OSError, ValueError):  # a closed or broken stream: feedback is optional
            pass

    def _run(self) -> None:
        spin = "|/-\\"
        tick = 0
        while not self._stop:
            with self._lock:
                now = time.monotonic()
                if self._open and self._depth == 0 and now - self._idle_since > self.GAP_S:
                    self._finish()
                busy = self._open
                elapsed = now - self._since
                if busy and elapsed >= self.min_s and (self.tty or not self._shown):
                    counter = f" {elapsed:.0f} s {spin[tick % 4]}" if self.tty else ""
                    doing = self.doing.format(what=self.what)
                    self._write(f"{self.prefix}{doing}...{counter}", final=False)
                    self._shown = True
                    tick += 1
            if busy:
                time.sleep(0.5 if elapsed >= self.min_s else self.min_s - elapsed)
            else:
                self._wake.wait(1.0)
                self._wake.clear()


class _Watcher:
    """JAX compile-event listeners driving a :class:`_Timer` (see :func:`watch_compiles`)."""

    def __init__(self, prog: str, stream: TextIO, min_s: float):
        import jax.monitoring

        self.timer = _Timer(f"{prog}: " if prog else "", stream, min_s)
        self._monitoring = jax.monitoring
        jax.monitoring.register_scalar_listener(self._on_start)
        jax.monitoring.register_event_duration_secs_listener(self._on_end)
        jax.monitoring.register_event_listener(self._on_event)

    # JAX records each compile phase's start as a scalar (its start time) and its end as a
    # duration, both under the phase's event name.
    def _on_start(self, event: str, value: float, **kwargs) -> None:
        if event in _COMPILE_EVENTS:
            self.timer.begin()

    def _on_end(self, event: str, duration: float, **kwargs) -> None:
        if event in _COMPILE_EVENTS:
            self.timer.end(last=event == _COMPILE_EVENTS[-1])

    def _on_event(self, event: str, **kwargs) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            self.timer.cache_hits += 1
        elif event == "/jax/compilation_cache/cache_misses":
            self.timer.cache_misses += 1

    def close(self) -> None:
        for unregister, fn in (
            (self._monitoring.unregister_scalar_listener, self._on_start),
            (self._monitoring.unregister_event_duration_listener, self._on_end),
            (self._monitoring.unregister_event_listener, self._on_event),
        ):
            with contextlib.suppress(Exception):  # already cleared by someone else
                unregister(fn)
        self.timer.close()


@contextlib.contextmanager
def watch_compiles(prog: str = "", *, stream: TextIO | None = None, min_s: float | None = None):
    """While active, every JAX compilation longer than ``min_s`` is reported on ``stream``
    (default ``sys.stderr``) as ``{prog}: compiling (first call)... N s``, then
    ``{prog}: compiled in N s``. Imports JAX. Does nothing when :func:`is_enabled` is False."""
    global _active
    if not is_enabled() or _active is not None:
        yield
        return
    watcher = _Watcher(prog, stream or sys.stderr, min_s)
    _active = watcher
    try:
        yield
    finally:
        _active = None
        watcher.close()


@contextlib.contextmanager
def compiling(what: str, *, stream: TextIO | None = None, min_s: float | None = None):
    """Names the compilation of the block: ``compiling {what} (first call)...``.

    Inside :func:`watch_compiles` it only labels the watcher's lines. Elsewhere it times
    the whole block itself and shows the same lines when it lasts longer than ``min_s``.
    """
    label = f" {what}" if what else ""
    if not is_enabled():
        yield
        return
    if _active is not None:
        timer = _active.timer
        old, timer.what = timer.what, label
        try:
            yield
        finally:
            timer.what = old
        return
    timer = _Timer("", stream or sys.stderr, min_s)
    timer.what = label
    timer.begin()
    try:
        yield
    finally:
        timer.close()


@contextlib.contextmanager
def status(
    prog: str, doing: str, done: str, *, stream: TextIO | None = None, min_s: float | None = None
):
    """Shows ``{prog}: {doing}... N s`` while the block runs longer than ``min_s``, then
    ``{prog}: {done} in N s``; e.g. ``jax-contact`` around its first import of JAX."""
    if not is_enabled():
        yield
        return
    timer = _Timer(f"{prog}: " if prog else "", stream or sys.stderr, min_s, doing, done, None)
    timer.begin()
    try:
        yield
    finally:
        timer.close()


def bar(
    iterable: Iterable[T],
    *,
    total: int | None = None,
    desc: str = "",
    unit: str = "it",
    enabled: bool = True,
    stream: TextIO | None = None,
    postfix: Callable[[], str] | None = None,
) -> Iterator[T]:
    """Yields ``iterable``'s items and shows the loop's progress on ``stream`` (stderr).

    A ``tqdm`` bar on a terminal, else a plain line at most every 10 s and one at the end:
    ``{desc}: {k}/{total} {unit}s, {elapsed} s, about {left} s left``. The estimate starts
    after the first item (which usually compiles). ``postfix``, called after each item,
    adds the loop's own state (e.g. ``"16/16 upright"``) to the bar or line.
    ``enabled=False`` (or ``JAX_CONTACT_PROGRESS=0``) yields the items and shows nothing.
    """
    stream = stream or sys.stderr
    if total is None:
        try:
            total = len(iterable)  # type: ignore[arg-type]
        except TypeError:
            total = None
    if not (enabled and is_enabled()):
        yield from iterable
        return
    if _is_tty(stream):
        yield from _tqdm_bar(iterable, total, desc, unit, stream, postfix)
    else:
        yield from _plain_bar(iterable, total, desc, unit, stream, postfix)


def _tqdm_bar(iterable, total, desc, unit, stream, postfix=None):
    from tqdm import tqdm

    it = iter(iterable)
    try:
        first = next(it)
    except StopIteration:
        return
    yield first  # the compiling one, reported by the watcher
    with tqdm(total=total, initial=1, desc=desc, unit=unit, file=stream, leave=True) as pbar:
        if postfix is not None:
            pbar.set_postfix_str(postfix())
        for item in it:
            yield item
            if postfix is not None:
                pbar.set_postfix_str(postfix(), refresh=False)
            pbar.update(1)


def _plain_bar(iterable, total, desc, unit, stream, postfix=None):
    t0 = time.monotonic()
    last = t0
    k, t_first = 0, None
    prefix = f"{desc}: " if desc else ""

    def line() -> str:
        elapsed = time.monotonic() - t0
        of = f"/{total}" if total is not None else ""
        text = f"{prefix}{k}{of} {unit}{'s' if (total or k) != 1 else ''}, {elapsed:.0f} s"
        if total is not None and t_first is not None and k > 1 and k < total:
            rate = (time.monotonic() - t_first) / (k - 1)  # after the compiling first item
            text += f", about {rate * (total - k):.0f} s left"
        return text + (f", {postfix()}" if postfix is not None else "")

    for item in iterable:
        yield item
        k += 1
        now = time.monotonic()
        if k == 1:
            t_first = now
        if now - last >= PLAIN_EVERY_S and (total is None or k < total):
            last = now
            _print(stream, line())
    _print(stream, line())


def _print(stream: TextIO, text: str) -> None:
    try:
        stream.write(text + "\n")
        stream.flush()
    except (OSError, ValueError):
        pass
