"""Where datasets are found on disk.

The root is ``$JAXSLAM_DATA`` when set, else ``../shared/datasets`` relative to the
current directory or the nearest of its parents that has one (so a notebook run
from ``notebooks/`` finds the same data as the repository root), else
``../shared/datasets`` beside the source tree. A
missing file raises :class:`DatasetNotFoundError`, which names the dataset, every
place that was searched, and how to point ``JAXSLAM_DATA`` at it.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "JAXSLAM_DATA"


class DatasetNotFoundError(FileNotFoundError):
    """A dataset file is not where jaxslam looked for it."""


class DataFormatError(ValueError):
    """A data file is malformed. The message names the file, the line and the problem,
    on one line: a problem text of several lines (a parser's message quoting the damaged
    bytes) is joined into one and cut at ``MAX_PROBLEM_CHARS`` characters."""

    MAX_PROBLEM_CHARS = 240

    def __init__(self, path: os.PathLike | str, line: int | None, problem: str):
        self.path = str(path)
        self.line = line
        problem = " ".join(str(problem).split())
        if len(problem) > self.MAX_PROBLEM_CHARS:
            problem = problem[: self.MAX_PROBLEM_CHARS - 3].rstrip() + "..."
        self.problem = problem
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {problem}")


def candidate_roots() -> list[Path]:
    """The data roots in the order they are searched."""
    roots: list[Path] = []
    env = os.environ.get(ENV_VAR)
    if env:
        roots.append(Path(env).expanduser())
    cwd = Path.cwd()
    roots.append(cwd / ".." / "shared" / "datasets")
    for parent in cwd.parents:
        if (parent / ".." / "shared" / "datasets").is_dir():
            roots.append(parent / ".." / "shared" / "datasets")
            break
    roots.append(Path(__file__).resolve().parents[2] / ".." / "shared" / "datasets")
    seen: set[Path] = set()
    unique = []
    for root in roots:
        resolved = root.resolve()
        if resolved not in seen:
            seen.add(resolved)
            unique.append(resolved)
    return unique


def data_root() -> Path:
    """The first existing data root (or the first candidate if none exists)."""
    roots = candidate_roots()
    for root in roots:
        if root.is_dir():
            return root
    return roots[0]


def find(dataset: str, *relative: str) -> Path:
    """Return the path of ``relative`` inside the data root, or raise a clear error.

    Args:
        dataset: human name of the dataset, used in the error message.
        relative: path parts below the data root, e.g. ``("carmen_raw", "intel.clf.gz")``.
    """
    tried = []
    for root in candidate_roots():
        path = root.joinpath(*relative)
        if path.exists():
            return path
        tried.append(str(path))
    raise DatasetNotFoundError(
        f"dataset {dataset!r} not found: looked for {', '.join(tried)}. "
        f"Set {ENV_VAR} to the folder that holds '{relative[0]}/' "
        f"(for example: export {ENV_VAR}=/path/to/shared/datasets)."
    )
