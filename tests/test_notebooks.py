"""The notebooks run from top to bottom (outputs are not committed; see .pre-commit-config)."""

from __future__ import annotations

import shutil
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


def test_section3_notebook_runs(tmp_path):
    src = NOTEBOOKS / "section3_planar_leg.ipynb"
    nb = nbformat.read(src, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
        "commit notebooks without outputs"
    )
    shutil.copy(src, tmp_path / src.name)
    client = NotebookClient(
        nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError on any failing cell, e.g. its final assert
    text = "".join(
        o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
    )
    assert "per-step accuracy" in text
    assert (tmp_path / "section3_fig5.png").stat().st_size > 10_000
