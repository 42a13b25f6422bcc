"""Ctrl-C that stops a ``jax-contact`` command at once, leaving no partial output file.

:class:`StopOnInterrupt` makes the process exit with code 130 and print
``jax-contact <command>: interrupted``, then the files the command had written completely
(:func:`jax_contact.io.completed_writes`), if any. Python's own ``KeyboardInterrupt``
does not do this in a JAX program: the exception is raised only when the main thread next
runs Python code, which during an XLA compilation can be minutes later, and when that code
is the garbage collector's callback into XLA the exception is printed as ``Exception ignored in:
<function _xla_gc_callback ...>`` and lost, so the run carries on. Instead, the signal's
arrival is read from :func:`signal.set_wakeup_fd` by a watcher thread, which Python's
C-level handler wakes immediately whatever the main thread is doing; the watcher removes
the temporary files of writes in progress (:func:`jax_contact.io.abort_writes`: every
output goes through ``jax_contact.io``'s atomic writes) and ends the process with
``os._exit(130)`` (SIGTERM, e.g. from ``kill`` or ``timeout``: the same, exit code 143).
Output written completely before the signal (e.g. the run folders of
earlier ``train`` variants) stays.

Standard library only, like the rest of the command line's front.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for a command stopped by Ctrl-C
EXIT_TERMINATED = 143  # 128 + SIGTERM (kill, timeout, a job scheduler)

_kept: list = []  # what a command keeps if it is stopped now (set_kept)
_discarded: list = []  # folders whose files this command wrote were removed (discarded)


def set_kept(note) -> None:
    """What a stop at this point leaves behind, or does not (printed after the
    ``interrupted`` line): ``train``'s run folder with its checkpoints, ``tune``'s unwritten
    ``--out``; a callable is asked at the stop (what is kept may change while the command
    runs; it may return None); None: nothing to say."""
    _kept[:] = [note] if note else []


def discarded(folder) -> None:
    """Marks ``folder``: the files this command wrote in it are gone (``train``'s note put
    an earlier run back there), so a stop does not list them as written."""
    _discarded.append(os.path.abspath(folder))


def still_written(paths) -> list:
    """``paths`` less those inside a :func:`discarded` folder."""
    gone = [os.path.join(f, "") for f in _discarded]
    return [p for p in paths if not os.path.abspath(p).startswith(tuple(gone))]


class StopOnInterrupt:
    """Context manager: while active, SIGINT ends the process at once (module docstring),
    and SIGTERM the same way (exit code 143, ``terminated``).

    Outside the main thread (where Python cannot install signal handlers) it does nothing
    and Python's ``KeyboardInterrupt`` applies.
    """

    def __init__(self, prog: str):
        self.prog = prog
        self._active = False

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)  # set_wakeup_fd requires it
        self._watcher = threading.Thread(target=self._watch, name="jax-contact-sigint", daemon=True)
        self._watcher.start()
        # Wake-up fd first: a SIGINT between the two calls then still reaches the watcher.
        self._old_fd = signal.set_wakeup_fd(self._write, warn_on_full_buffer=False)
        self._old_handler = signal.signal(signal.SIGINT, self._note)
        self._old_term = signal.signal(signal.SIGTERM, self._note)
        self._active = True
        return self

    @staticmethod
    def _note(signum, frame) -> None:
        # Runs in the main thread whenever it next runs Python code (possibly inside a GC
        # callback, where an exception would be swallowed): nothing to do here, the
        # watcher has already been woken by the C-level handler through the wake-up fd.
        del signum, frame

    def _watch(self) -> None:
        while True:
            try:
                data = os.read(self._read, 64)
            except OSError:
                return
            if not data:  # the write end was closed: the command finished
                return
            if signal.SIGINT in data:
                self._stop()
            if signal.SIGTERM in data:
                self._stop("terminated", EXIT_TERMINATED)

    def _stop(self, what: str = "interrupted", code: int = EXIT_INTERRUPTED) -> None:
        try:
            # Not imported, or still being imported (a signal during start-up): nothing
            # has been written through it yet, so there is nothing to abort.
            abort = getattr(sys.modules.get("jax_contact.io"), "abort_writes", None)
            if abort is not None:
                abort()  # holds io's lock from here on: no rename can follow
            # Flush what was printed, but never wait on a main thread stuck mid-write.
            flusher = threading.Thread(target=_flush_std, daemon=True)
            flusher.start()
            flusher.join(0.5)
            os.write(2, f"{self.prog}: {what}\n".encode())
            # The notes first: one may put an earlier run back over files just written.
            notes = []
            for note in list(_kept):
                if callable(note):
                    try:
                        note = note()
                    except Exception:  # noqa: BLE001  (a stop must not fail on its note)
                        note = None
                if note:
                    notes.append(note)
            # What this command had written completely (a stop just after "wrote ..."):
            # whole files, said so, since "interrupted" alone reads as if they might not be.
            done = getattr(sys.modules.get("jax_contact.io"), "completed_writes", None)
            if written := still_written(done() if done is not None else []):
                more = f" and {len(written) - 5} more" if len(written) > 5 else ""
                os.write(
                    2,
                    f"{self.prog}: written completely before the stop: "
                    f"{', '.join(written[-5:])}{more}\n".encode(),
                )
            for note in notes:
                os.write(2, f"{self.prog}: {note}\n".encode())
        finally:
            os._exit(code)  # whatever failed above, the command stops

    def __exit__(self, *exc) -> None:
        if not self._active:
            return
        signal.signal(signal.SIGINT, self._old_handler)
        signal.signal(signal.SIGTERM, self._old_term)
        signal.set_wakeup_fd(self._old_fd)
        os.close(self._write)
        self._watcher.join(1.0)
        os.close(self._read)
        self._active = False


def _flush_std() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # a closed or broken stream: nothing more to save
            pass
