"""Where the shipped parameter presets live (standard library only: the command line's
argument checks use it before JAX, NumPy or h5py are imported)."""

from __future__ import annotations

from importlib import resources


def presets_folder():
    """``jax_contact/presets`` as an importlib resource (package data, not a package)."""
    return resources.files("jax_contact") / "presets"


def preset_names() -> tuple[str, ...]:
    """The names of the tuned parameter files shipped in ``jax_contact/presets``."""
    folder = presets_folder()
    if not folder.is_dir():
        return ()
    return tuple(sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".json")))
