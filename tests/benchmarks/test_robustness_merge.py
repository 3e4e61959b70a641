"""benchmarks/grid_robustness_merge.py: later parts replace earlier runs of the same
(log, filter, seed), and PATH:FILTERS takes only those filters' runs of a file."""

from __future__ import annotations

import json
from pathlib import Path

from . import load_benchmark

merge_module = load_benchmark("grid_robustness_merge")


def _part(path: Path, runs: list[tuple[str, str, int, float]]) -> Path:
    payload = {"runs": [{"log": log, "filter": name, "seed": seed, "mean_m": mean} for log, name, seed, mean in runs]}
    path.write_text(json.dumps(payload))
    return path


def test_later_parts_replace_earlier_runs_and_filters_can_be_picked(tmp_path):
    old = _part(tmp_path / "old.json", [("intel", "srupf-gm", 0, 0.5), ("intel", "gmapping-cpp", 0, 0.047),
                                        ("fr079", "srupf-gm", 1, 0.9)])
    new = _part(tmp_path / "new.json", [("intel", "srupf-gm", 0, 0.025), ("intel", "gmapping", 0, 0.027)])
    rows, replaced = merge_module.merge([f"{old}:gmapping-cpp", str(new)])
    got = {(r["log"], r["filter"], r["seed"]): (r["mean_m"], r["source"]) for r in rows}
    # Only the C++ run of the old part is taken; the old srupf-gm runs are not.
    assert got == {("intel", "gmapping-cpp", 0): (0.047, "old.json"),
                   ("intel", "srupf-gm", 0): (0.025, "new.json"),
                   ("intel", "gmapping", 0): (0.027, "new.json")}
    assert replaced == []
    rows, replaced = merge_module.merge([old, new])
    got = {(r["log"], r["filter"], r["seed"]): r["mean_m"] for r in rows}
    assert got[("intel", "srupf-gm", 0)] == 0.025 and got[("fr079", "srupf-gm", 1)] == 0.9
    assert len(replaced) == 1 and "old.json -> new.json" in replaced[0]
