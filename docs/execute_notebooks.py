"""Execute the notebooks of ``notebooks/`` and store their outputs in them.

The documentation renders the notebooks with the outputs stored here (the docs build
does not run them: the particle sweeps take minutes each). Each executed notebook
records, in its metadata under ``jaxslam.source_sha256``, the hash of its code cells'
sources; ``tests/test_notebooks.py`` checks that the hash matches the sources, so a
notebook whose code changed without being executed again fails the test.

Usage, from the repository root (the notebooks run in ``notebooks/``)::

    python docs/execute_notebooks.py                    # all of them
    python docs/execute_notebooks.py notebooks/erb_fig1.ipynb
    python docs/execute_notebooks.py --check            # exit 1 if any is stale

Needs ``nbclient`` and ``ipykernel`` (both in ``jaxslam[test]``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
KEY = "jaxslam"
TIMEOUT_S = 1800  # per cell


def source_hash(notebook: dict) -> str:
    """SHA-256 of the code cells' sources, in order (markdown edits do not need a rerun)."""
    digest = hashlib.sha256()
    for cell in notebook["cells"]:
        if cell["cell_type"] == "code":
            source = cell["source"]
            digest.update(("".join(source) if isinstance(source, list) else source).encode())
            digest.update(b"\0")
    return digest.hexdigest()


def stale(notebook: dict) -> str | None:
    """Why the stored outputs of ``notebook`` are not those of its code, or None."""
    stored = notebook.get("metadata", {}).get(KEY, {}).get("source_sha256")
    if stored is None:
        return "never executed by docs/execute_notebooks.py"
    if stored != source_hash(notebook):
        return "its code changed since its outputs were stored"
    for cell in notebook["cells"]:
        if cell["cell_type"] != "code":
            continue
        if any(output.get("output_type") == "error" for output in cell.get("outputs", [])):
            return "a stored output is an error"
    return None


def execute(path: Path) -> float:
    """Run ``path`` in a fresh kernel (working directory ``notebooks/``), store its
    outputs and hash in place; the wall time in seconds."""
    import nbformat
    from nbclient import NotebookClient

    notebook = nbformat.read(path, as_version=4)
    start = time.perf_counter()
    NotebookClient(notebook, timeout=TIMEOUT_S, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    wall = time.perf_counter() - start
    for cell in notebook.cells:
        cell.metadata.pop("execution", None)  # per-cell timestamps: noise in every diff
    notebook.metadata[KEY] = {"source_sha256": source_hash(notebook)}
    nbformat.write(notebook, path)
    return wall


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="*", type=Path, help="notebooks (default: all of notebooks/)")
    parser.add_argument("--check", action="store_true", help="only say which notebooks are stale; exit 1 if any")
    args = parser.parse_args(argv)
    paths = args.paths or sorted(NOTEBOOKS.glob("*.ipynb"))
    if args.check:
        bad = [(p, why) for p in paths if (why := stale(json.loads(p.read_text()))) is not None]
        for path, why in bad:
            print(f"{path}: stale: {why}")
        return 1 if bad else 0
    for path in paths:
        print(f"{path.name}: {execute(path):.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
