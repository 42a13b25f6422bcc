"""The docs and docstrings name files and objects that exist.

The README, docs/ and the docstrings point a reader at ``jax_contact/metrics.py`` or
``jax_contact.envs.wrapper.wrap_contact``; a module split or a rename leaves such a pointer
stale without any other test noticing (two were found by hand: ``jax_contact/tune.py``
after the package split, ``jax_contact.envs.wrap_contact``). Every repository path and
every dotted ``jax_contact`` name they mention must resolve.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEXTS = sorted(
    [ROOT / "README.md", ROOT / "pyproject.toml", *(ROOT / "docs").glob("*.md")]
    + [p for d in ("jax_contact", "envs", "train", "benchmarks") for p in (ROOT / d).rglob("*.py")]
)
# A path in the repository: one of its top folders, not inside another path (out/train/...).
PATH = re.compile(
    r"(?<![\w/.-])(?:jax_contact|envs|train|benchmarks|tests|notebooks|docs)/[\w./-]+"
    r"\.(?:py|md|ipynb|xml|json|csv|h5|sh)\b"
)
NAME = re.compile(r"(?<![\w.])jax_contact(?:\.[A-Za-z_]\w*)+")


def _mentions(pattern: re.Pattern) -> dict[str, str]:
    """Each match of ``pattern`` in the texts -> the first file that has it."""
    found: dict[str, str] = {}
    for path in TEXTS:
        for match in pattern.findall(path.read_text()):
            found.setdefault(match, str(path.relative_to(ROOT)))
    return found


def _resolves(name: str) -> bool:
    """``name`` is a module, or an attribute chain of the longest module it starts with."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        module = ".".join(parts[:i])
        try:
            found = importlib.util.find_spec(module) is not None
        except ModuleNotFoundError:
            found = False
        if found:
            obj = importlib.import_module(module)
            for attr in parts[i:]:
                if not hasattr(obj, attr):
                    return False
                obj = getattr(obj, attr)
            return True
    return False


def test_every_path_the_docs_name_exists():
    mentions = _mentions(PATH)
    assert len(mentions) > 50  # the pattern still finds the docs' paths
    missing = {p: where for p, where in mentions.items() if not (ROOT / p).exists()}
    assert not missing, missing


def test_every_dotted_name_the_docs_use_resolves():
    mentions = _mentions(NAME)
    assert "jax_contact.envs.wrapper.wrap_contact" in mentions
    assert not _resolves("jax_contact.envs.wrap_contact")  # the check can fail
    stale = {n: where for n, where in mentions.items() if not _resolves(n)}
    assert not stale, stale
