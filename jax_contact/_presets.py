"""Where the shipped parameter presets live (standard library only: the command line's
argument checks use it before JAX, NumPy or h5py are imported)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def presets_folder():
    """``jax_contact/presets`` as an importlib resource (package data, not a package)."""
    return resources.files("jax_contact") / "presets"


def preset_names() -> tuple[str, ...]:
    """The names of the tuned parameter files shipped in ``jax_contact/presets``."""
    folder = presets_folder()
    if not folder.is_dir():
        return ()
    return tuple(sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".json")))


def preset_file(source):
    """The shipped preset that ``source`` names, or None.

    ``source`` names a preset when it is a bare name (no folder, no suffix) among
    :func:`preset_names` and no file of that name exists: a file always wins, so a user's
    own ``go1`` file is read, not the preset.
    """
    if not isinstance(source, str):
        return None
    p = Path(source)
    if p.suffix or len(p.parts) != 1 or p.is_file() or source not in preset_names():
        return None
    return presets_folder() / f"{source}.json"
