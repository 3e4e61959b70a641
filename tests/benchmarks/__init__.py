"""Tests of the benchmark scripts in ``benchmarks/`` (not a package of the library)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def load_benchmark(name: str):
    """Import ``benchmarks/NAME.py`` (``NAME`` may be ``diagnostics/SCRIPT``) as module
    ``SCRIPT``: registered in ``sys.modules`` (dataclasses look their module up there),
    with ``benchmarks/`` on ``sys.path`` for the scripts' own imports (``_common``,
    ``grid_common``, ...)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    path = BENCHMARKS / f"{name}.py"
    module_name = path.stem
    if module_name in sys.modules and getattr(sys.modules[module_name], "__file__", None) == str(path):
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    spec.loader.exec_module(module)
    return module


def turning_path(turns, step: float = 1.0):
    """``(len(turns) + 1, 3)`` poses that drive ``step`` m forward and then turn by each of
    ``turns`` (rad): a path whose heading increments are ``turns``."""
    import numpy as np

    poses = [np.zeros(3)]
    for turn in turns:
        x, y, t = poses[-1]
        poses.append(np.array([x + step * np.cos(t), y + step * np.sin(t), t + turn]))
    return np.array(poses)
