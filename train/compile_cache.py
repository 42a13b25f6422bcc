"""The persistent compilation cache of ``jax-contact``: compiled programs kept between runs.

:func:`enable_compilation_cache` turns on JAX's persistent compilation cache, in
``~/.cache/jax-contact/xla/<host_tag()>`` (``$XDG_CACHE_HOME`` is honoured), or in
``$JAX_CONTACT_CACHE_DIR`` (empty: off); a ``JAX_COMPILATION_CACHE_DIR`` of the user's own
wins. On 2 cores most of a short run is compilation, which a second run then loads in about
a second per program. Every program is kept (minimum compile time and entry size 0);
deleting the folder at any time is safe. The command line, the test suite
(``tests/conftest.py``) and the benchmarks all turn it on through this one function.

Standard library only: it must run before JAX is imported.
"""

from __future__ import annotations

import os
import sys

CACHE_ENV = "JAX_CONTACT_CACHE_DIR"


def host_tag(cpuinfo: str | None = None) -> str:
    """A folder name for this host's CPU: its architecture and a hash of its instruction-set
    features (the ``flags`` of ``/proc/cpuinfo``, else the processor's name).

    XLA:CPU compiles for the features of the host it runs on and loads a cached program
    built for other features with only a warning ("could lead to execution errors such as
    SIGILL"): a home folder shared by hosts of different CPUs must not share programs.

    Args:
      cpuinfo: the text of ``/proc/cpuinfo`` (read when None and present).
    """
    import hashlib
    import platform

    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
                cpuinfo = f.read()
        except OSError:
            cpuinfo = ""
    flags = next(
        (
            line.split(":", 1)[1]
            for line in cpuinfo.splitlines()
            if line.split(":")[0].strip() in ("flags", "Features")
        ),
        platform.processor(),
    )
    digest = hashlib.sha256(" ".join(sorted(flags.split())).encode()).hexdigest()[:12]
    return f"{platform.machine() or 'cpu'}-{digest}"


def compilation_cache_dir() -> str | None:
    """jax-contact's persistent compilation cache folder, or None when turned off:
    ``$JAX_CONTACT_CACHE_DIR`` if set (empty: off), else
    ``$XDG_CACHE_HOME/jax-contact/xla/<host_tag()>`` (``~/.cache/jax-contact/xla/...``), one
    folder per CPU feature set."""
    if CACHE_ENV in os.environ:
        return os.environ[CACHE_ENV].strip() or None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "jax-contact", "xla", host_tag())


def enable_compilation_cache() -> str | None:
    """Turns on JAX's persistent compilation cache (module docstring); returns its folder,
    or None when it is off or its folder cannot be created.

    Set through JAX's environment variables, before JAX is imported, so that subprocesses
    (``bench``'s sharding check) share it; when JAX is already imported (a test calling
    :func:`main`), through ``jax.config``, unless a cache folder is configured already.
    """
    folder = os.environ.get("JAX_COMPILATION_CACHE_DIR") or compilation_cache_dir()
    if not folder:
        return None
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:  # e.g. a read-only home: run without the cache
        return None
    settings = {
        "jax_compilation_cache_dir": folder,
        # Keep every program: the measured default thresholds skip most of this code's.
        "jax_persistent_cache_min_compile_time_secs": "0",
        "jax_persistent_cache_min_entry_size_bytes": "0",
    }
    for name, value in settings.items():  # read by JAX when it is imported, here or in a child
        os.environ.setdefault(name.upper(), value)
    jax = sys.modules.get("jax")
    if jax is not None:
        if jax.config.jax_compilation_cache_dir is None:
            jax.config.update("jax_compilation_cache_dir", folder)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder
