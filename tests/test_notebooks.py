"""Notebooks are committed with their outputs, the documentation renders them as they
are, so the stored outputs must be those of the code: ``docs/execute_notebooks.py``
runs a notebook and records the hash of its code cells, and a notebook whose code
changed since is stale. (nbmake runs the short ones again in the default suite, the
particle sweeps with ``-m slow``; it checks that they run, not what they show.)"""

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
sys.path.insert(0, str(ROOT / "docs"))

import execute_notebooks  # noqa: E402


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 2


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_committed_with_current_outputs(path):
    notebook = json.loads(path.read_text())
    why = execute_notebooks.stale(notebook)
    assert why is None, f"{path.name}: {why}; run python docs/execute_notebooks.py {path.relative_to(ROOT)}"
    code = [c for c in notebook["cells"] if c["cell_type"] == "code"]
    assert [c["execution_count"] for c in code] == list(range(1, len(code) + 1)), "executed top to bottom, once"
    drawing = [c for c in code if re.search(r"\bplt\.subplots|\bplot_\w+\(", "".join(c["source"]))]
    assert drawing, "a walkthrough draws a figure"
    for cell in drawing:  # each cell that draws shows its figure in the stored outputs
        assert any("image/png" in o.get("data", {}) for o in cell["outputs"]), "".join(cell["source"])[:200]
    assert "Parameters" in "".join(code[0]["source"]), "the first code cell is the parameter cell"


def test_an_edited_notebook_is_stale():
    notebook = json.loads(NOTEBOOKS[0].read_text())
    assert execute_notebooks.stale(notebook) is None
    code = next(c for c in notebook["cells"] if c["cell_type"] == "code")
    code["source"] = ["SEED = 1\n"]
    assert "changed" in execute_notebooks.stale(notebook)
    del notebook["metadata"]["jaxslam"]
    assert "never executed" in execute_notebooks.stale(notebook)
