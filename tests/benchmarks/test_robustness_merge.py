"""benchmarks/grid_robustness_merge.py: later parts replace earlier runs of the same
(log, filter, seed), and PATH:FILTERS takes only those filters' runs of a file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

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


def test_a_variant_is_taken_under_another_name_and_keeps_its_old_one(tmp_path):
    variants = _part(tmp_path / "variants.json", [("intel", "srupf-gm[l05]", 0, 0.03),
                                                  ("intel", "srupf-gm[c40]", 0, 0.9), ("intel", "srupf-gm", 1, 0.7)])
    later = _part(tmp_path / "later.json", [("intel", "srupf-gm", 1, 0.04)])
    rows, replaced = merge_module.merge([f"{variants}:srupf-gm[l05]=srupf-gm,srupf-gm", str(later)])
    got = {(r["log"], r["filter"], r["seed"]): (r["mean_m"], r.get("renamed_from")) for r in rows}
    # c40 is not picked; l05 counts as the defaults' seed 0; the later file's seed 1 replaces the earlier one.
    assert got == {("intel", "srupf-gm", 0): (0.03, "srupf-gm[l05]"), ("intel", "srupf-gm", 1): (0.04, None)}
    assert replaced == ["intel srupf-gm seed 1: variants.json -> later.json"]
    with pytest.raises(SystemExit, match="empty filter name"):
        merge_module.parse_source(f"{variants}:srupf-gm[l05]=")


def test_markdown_rows_carry_the_worst_seed_and_the_counts():
    rows = [{"log": "intel", "filter": "srupf-gm", "seed": s, "mean_m": m, "max_m": x, "over_0.5m": o,
             "jump_max_m": 0.1, "wall_s": 1.0, "cpu_s": 1.0}
            for s, m, x, o in [(0, 0.03, 0.4, 0), (1, 0.13, 2.4, 159)]]
    rows += [{"log": "fr-clinic", "filter": "gmapping", "seed": 0, "jump_max_m": 0.27, "wall_s": 1.0, "cpu_s": 1.0}]
    table = merge_module.markdown(merge_module.summarize(rows)).splitlines()
    assert table[0] == "| log | srupf-gm | gmapping |"
    assert table[2] == "| intel | 0.080 (0.130), 2.40 m, 159 [2] |  |"
    assert table[3] == "| fr-clinic |  | largest correction 0.27 m [1] |"


def test_a_table_of_no_runs_prints_its_header(capsys):
    """A suite part whose every filter was left out (GMapping C++ not found) prints an
    empty table instead of crashing after the runs it did make."""
    common = load_benchmark("_common")
    common.print_table([], ["log", "mean_m"])
    assert capsys.readouterr().out.split("\n")[0].split() == ["log", "mean_m"]


def test_runs_under_two_code_splits_are_two_runs_and_two_columns(tmp_path):
    import json

    def part(path, split):
        runs = [{"log": "intel", "filter": "srupf-gm", "seed": 0, "mean_m": 0.03 if split == 8 else 0.3,
                 "max_m": 1.0, "over_0.5m": 0, "jump_max_m": 0.1, "wall_s": 1.0, "cpu_s": 1.0, "code_split": split}]
        path.write_text(json.dumps({"runs": runs}))
        return str(path)

    rows, replaced = merge_module.merge([part(tmp_path / "a.json", 8), part(tmp_path / "b.json", 32)])
    assert [r["code_split"] for r in rows] == [8, 32] and replaced == []
    table = merge_module.markdown(merge_module.summarize(rows)).splitlines()
    assert table[0] == "| log | srupf-gm, code split 8 | srupf-gm, code split 32 |"
    assert table[2] == "| intel | 0.030 (0.030), 1.00 m, 0 [1] | 0.300 (0.300), 1.00 m, 0 [1] |"


def test_a_merged_run_keeps_the_cpu_of_its_part(tmp_path):
    """XLA compiles for the CPU it runs on, so a merge of parts made on two machines
    records each run's CPU, and a run merged again keeps the one it had."""
    def part(path, cpu, runs):
        machine = {"cpu": cpu[0], "cpu_family_model": cpu[1], "cores": 2}
        path.write_text(json.dumps({"machine": machine, "runs": [
            {"log": "intel", "filter": "srupf-gm", "seed": s, "mean_m": 0.03} for s in runs]}))
        return path

    first = part(tmp_path / "a.json", ("AMD EPYC", "26/2"), [0, 1])
    second = part(tmp_path / "b.json", ("Intel(R) Xeon(R) Processor", "6/207"), [1])
    rows, _ = merge_module.merge([first, second])
    assert {r["seed"]: r["cpu"] for r in rows} == {0: "AMD EPYC 26/2", 1: "Intel(R) Xeon(R) Processor 6/207"}
    merged = tmp_path / "merged.json"
    merged.write_text(json.dumps({"machine": {"cpu": "Other", "cpu_family_model": "1/1"}, "runs": rows}))
    again, _ = merge_module.merge([merged])
    assert {r["seed"]: r["cpu"] for r in again} == {0: "AMD EPYC 26/2", 1: "Intel(R) Xeon(R) Processor 6/207"}


def test_every_variant_and_code_split_is_a_series_of_the_plot():
    """The plot took only the filters' plain names, so a variant's runs
    (``srupf-gm[first]``) and a second code split's fell out of it."""
    rows = [{"log": "intel", "filter": name, "seed": 0, "mean_m": 0.1, **({"code_split": split} if split else {})}
            for name, split in [("srupf-gm[off]", None), ("gmapping-cpp", None), ("srupf-gm[first]", 32),
                                ("srupf-gm[first]", None), ("srupf-gm", None)]]
    assert merge_module.series(rows) == [("srupf-gm", None), ("srupf-gm[first]", None), ("srupf-gm[first]", 32),
                                         ("srupf-gm[off]", None), ("gmapping-cpp", None)]


def test_common_keeps_the_logs_and_seeds_every_arm_ran():
    """Two arms on log a (seeds 0-2 and 0-1), one arm on log b, the first arm again under
    code split 32: only log a's seeds 0 and 1 compare the arms."""
    def run(log, filter_, seed, split=None):
        return {"log": log, "filter": filter_, "seed": seed, **({} if split is None else {"code_split": split})}

    rows = ([run("a", "srupf-gm[x]", s) for s in (0, 1, 2)] + [run("a", "srupf-gm[y]", s) for s in (0, 1)]
            + [run("b", "srupf-gm[x]", 0), run("a", "srupf-gm[x]", 0, 32)])
    kept = merge_module.common(rows)
    assert sorted((r["log"], r["filter"], r["seed"]) for r in kept) == [
        ("a", "srupf-gm[x]", 0), ("a", "srupf-gm[x]", 1), ("a", "srupf-gm[y]", 0), ("a", "srupf-gm[y]", 1)]
