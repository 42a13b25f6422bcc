"""The wheel installs one top-level package, ``jax_contact`` (issue 18).

The repository keeps ``envs/``, ``train/`` and ``benchmarks/`` at its root; pyproject.toml maps
them to ``jax_contact.envs``, ``jax_contact.train`` and ``jax_contact.benchmarks``, so a user's
own ``train.py`` or ``envs`` package neither shadows the library nor is shadowed by it.
"""

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "jax_contact", "envs", "train", "benchmarks")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """A wheel built from a copy of the sources (the build leaves nothing in the checkout)."""
    src = tmp_path_factory.mktemp("src")
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(path, src / name)
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(out), str(src)],
        check=True,
        capture_output=True,
    )
    (path,) = out.glob("jax_contact-*.whl")
    with zipfile.ZipFile(path) as zf:
        return zf.namelist(), {n: zf.read(n).decode() for n in zf.namelist() if n.endswith(".txt")}


def test_wheel_has_one_top_level_package(wheel):
    names, _ = wheel
    top = {n.split("/")[0] for n in names}
    assert top == {"jax_contact", "jax_contact-0.1.0.dist-info"}, top
    for module in ("envs/simulate.py", "train/cli.py", "benchmarks/suite.py", "tune/fit.py"):
        assert f"jax_contact/{module}" in names
    # the data files the code opens next to itself
    assert "jax_contact/envs/assets/planar_leg.xml" in names
    assert "jax_contact/py.typed" in names  # PEP 561: a type checker reads the annotations
    assert {"jax_contact/presets/go1.json", "jax_contact/presets/spot.json"} <= set(names)
    # pyproject's license = "Apache-2.0" ships its text (setuptools >= 77 finds LICENSE)
    licenses = [n for n in names if n.startswith("jax_contact-0.1.0.dist-info/licenses/")]
    assert licenses == ["jax_contact-0.1.0.dist-info/licenses/LICENSE"], licenses


def test_wheel_entry_point_is_namespaced(wheel):
    _, texts = wheel
    entry = texts["jax_contact-0.1.0.dist-info/entry_points.txt"]
    assert "jax-contact = jax_contact.train.cli:console_main" in entry


def test_user_modules_named_like_the_folders_are_not_shadowed(tmp_path):
    """A user's project with its own ``train.py``, ``envs/`` and ``benchmarks.py`` imports its
    own modules, and the library's CLI module still imports from the same folder."""
    (tmp_path / "train.py").write_text("WHO = 'user'\n")
    (tmp_path / "benchmarks.py").write_text("WHO = 'user'\n")
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "__init__.py").write_text("WHO = 'user'\n")
    code = (
        "import train, envs, benchmarks, jax_contact.train.cli as cli;"
        "print(train.WHO, envs.WHO, benchmarks.WHO, cli.__name__)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["user", "user", "user", "jax_contact.train.cli"]


def test_import_is_lazy_and_every_public_name_resolves():
    """``import jax_contact`` imports no JAX (the CLI checks arguments first); each name of
    ``__all__`` then loads from the submodule that defines it."""
    code = (
        "import sys, importlib, jax_contact as jc\n"
        "print(sorted(m for m in ('jax', 'numpy', 'mujoco', 'h5py', 'flax') if m in sys.modules))\n"
        "for n in jc.__all__:\n"
        "    v = getattr(jc, n)\n"
        "    mod = jc._LAZY[n]\n"
        "    want = importlib.import_module('jax_contact.' + (mod or n))\n"
        "    assert v is (want if mod is None else getattr(want, n)), n\n"
        "print(len(jc.__all__))\n"
        "assert jc.io is importlib.import_module('jax_contact.io')\n"
        "assert jc.baselines.make_gm_params is not None\n"
        "try:\n"
        "    jc.no_such_name\n"
        "except AttributeError as e:\n"
        "    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    lines = out.stdout.splitlines()
    assert lines[0] == "[]"
    assert int(lines[1]) == 47
    assert lines[2] == "module 'jax_contact' has no attribute 'no_such_name'"
