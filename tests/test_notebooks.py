"""Notebooks are committed without outputs (they are executed fresh by nbmake in CI)."""

import json
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 2


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_committed_without_outputs(path):
    notebook = json.loads(path.read_text())
    for cell in notebook["cells"]:
        if cell["cell_type"] == "code":
            assert cell.get("outputs", []) == [], f"{path.name} has stale outputs; clear them before committing"
            assert cell.get("execution_count") is None
    first_code = next(c for c in notebook["cells"] if c["cell_type"] == "code")
    assert "Parameters" in "".join(first_code["source"]), "the first code cell is the parameter cell"
