"""From the command to the map: whole-process time of ``jaxslam run``, cold and warm
compilation cache, next to GMapping C++ in the same run.

Usage:
    python benchmarks/end_to_end.py [--cases intel-srupf-30 intel-gmapping-30 ...]
        [--modes cold warm] [--no-gmapping] [--workdir DIR] [--timeout S] [--json NAME]

Cases (``--cases all`` for every one; default ``intel-srupf-30``):

    intel-srupf-30, intel-srupf-100, intel-gmapping-30, intel-gmapping-100,
    killian-srupf-30, clinic-srupf-30, vp-erb-100, vp-erb-1000

(``clinic-srupf-30``: the raw fr-clinic log, long-range scans and no relations to score.)

Every jaxslam run is a fresh ``python -m jaxslam.app.cli run ... --no-progress`` process
(plots on, as a user runs it) under ``nice -n 10``. ``cold``: an empty compilation
cache folder; ``warm``: the same folder again, so every program comes from the cache.
From each run's ``summary.json``: ``load_s`` (reading the data), ``compile_s``
(compiling, or loading compiled programs from the cache), ``wall_s`` (the filter
loop), ``output_s`` (files and figures), ``compiled``/``cache_hits`` (XLA programs);
``process_s`` is the wall clock of the whole process (Python and JAX start-up
included) and ``overhead_s = process_s - wall_s``.

GMapping C++ (``benchmarks/gmapping_cpp.py``: ``../shared/tools/gmapping/run.sh``,
also under ``nice -n 10``) runs on the same log with the same particle count, for the
laser cases, right after the jaxslam runs of that case; ``gmapping_process_s`` is its
whole process, ``gmapping_slam_s`` its own SLAM-loop time. ``speedup_process`` is
GMapping's whole process over jaxslam's, ``speedup_loop`` GMapping's SLAM loop over
jaxslam's filter loop. MRPT is not run here.

``--old-tree DIR`` adds the mode ``old``: the same command run from another checkout
(for example an older revision of jaxslam),
without the cache flags it may not know, right before the cold run of each case, so
that the old and new numbers come from the same run.

The machine may be shared: only ratios measured in the same run are meaningful; the
load average before and after each run is recorded. Writes
benchmarks/results/end_to_end.json (rows, machine, versions, command).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import print_table, write_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# name: (dataset, algorithm, particles, registry name of the CARMEN log or None)
CASES = {
    "intel-srupf-30": ("intel", "srupf-gm", 30, "intel"),
    "intel-srupf-100": ("intel", "srupf-gm", 100, "intel"),
    "intel-gmapping-30": ("intel", "gmapping", 30, "intel"),
    "intel-gmapping-100": ("intel", "gmapping", 100, "intel"),
    "killian-srupf-30": ("mit-killian", "srupf-gm", 30, "mit-killian"),
    "clinic-srupf-30": ("fr-clinic", "srupf-gm", 30, "fr-clinic"),
    "vp-erb-100": ("victoria-park", "erb-upf", 100, None),
    "vp-erb-1000": ("victoria-park", "erb-upf", 1000, None),
}
SUMMARY_FIELDS = ("load_s", "compile_s", "wall_s", "output_s", "total_s")


def run_jaxslam(case: str, cache: Path | None, out: Path, timeout: float, tree: Path = ROOT) -> dict:
    """One ``jaxslam run`` process from the checkout ``tree``; ``cache`` None: no cache
    flag (an old checkout that has no cache)."""
    dataset, algorithm, particles, _ = CASES[case]
    cmd = ["nice", "-n", "10", sys.executable, "-m", "jaxslam.app.cli", "run", "--dataset", dataset,
           "--algorithm", algorithm, "--particles", str(particles), "--out", str(out), "--no-progress"]
    if cache is not None:
        cmd += ["--cache-dir", str(cache)]
    env = {**os.environ, "PYTHONPATH": str(tree) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=str(tree))
    process_s = time.perf_counter() - started
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    summary = json.loads((out / "summary.json").read_text())
    row = {"process_s": process_s, **{k: summary.get(k) for k in SUMMARY_FIELDS}}
    row["overhead_s"] = process_s - summary["wall_s"]
    compilations = summary.get("compilations") or {}  # an old checkout has no count
    row["compiled"] = compilations.get("compiled")
    row["cache_hits"] = compilations.get("cache_hits")
    for key in ("trans_err_mean_m", "rot_err_mean_deg", "gps_mean_m", "keyframes", "steps", "log_cache"):
        if key in summary:
            row[key] = summary[key]
    row["load_average"] = [load_before, os.getloadavg()[0]]
    row["command"] = " ".join(cmd[3:])
    return row


def run_gmapping_case(case: str, workdir: Path, timeout: float) -> dict:
    from gmapping_cpp import run_gmapping

    from jaxslam.datasets.registry import lookup

    _, _, particles, log_name = CASES[case]
    info = lookup(log_name)
    log = info.load()
    load_before = os.getloadavg()[0]
    run = run_gmapping(info.paths()[0], particles=particles, seed=0, log=log,
                       max_range=log.max_range if log.no_return.get("detected") else None,
                       nice=10, timeout=timeout, workdir=workdir)
    row = {"gmapping_process_s": run.wall_s, "gmapping_slam_s": run.info.get("slam_s"),
           "gmapping_keyframes": run.info.get("keyframes"), "gmapping_command": " ".join(run.command),
           "gmapping_load_average": [load_before, os.getloadavg()[0]]}
    try:
        from jaxslam.datasets.registry import lookup
        from jaxslam.metrics.relations import load_relations, relations_metric

        relations = lookup(log_name).relations_path()
        if relations is not None:
            scores = relations_metric(load_relations(relations), run.scan_times, run.trajectory)
            row["gmapping_trans_err_mean_m"] = scores.get("trans_err_mean_m")
            row["gmapping_rot_err_mean_deg"] = scores.get("rot_err_mean_deg")
    except Exception as error:  # scoring is a bonus here; the timing stands on its own
        row["gmapping_relations_error"] = repr(error)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="+", default=["intel-srupf-30"], help="case names or 'all'")
    parser.add_argument("--modes", nargs="+", default=["cold", "warm"], choices=["cold", "warm"])
    parser.add_argument("--no-gmapping", action="store_true", help="do not run GMapping C++")
    parser.add_argument("--workdir", type=Path, default=None, help="outputs and caches (default: a temp folder)")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds per process")
    parser.add_argument("--json", default="end_to_end", help="result name: benchmarks/results/NAME.json")
    parser.add_argument("--old-tree", type=Path, default=None,
                        help="another checkout to run first as mode 'old' (e.g. a git worktree of an older commit)")
    args = parser.parse_args()
    modes = (["old"] if args.old_tree else []) + list(args.modes)
    cases = list(CASES) if args.cases == ["all"] else args.cases
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="jaxslam_end_to_end_"))
    workdir.mkdir(parents=True, exist_ok=True)

    rows = []
    for case in cases:
        cache = workdir / f"cache_{case}"
        shutil.rmtree(cache, ignore_errors=True)
        row: dict = {"case": case}
        for mode in modes:
            if mode == "old":
                result = run_jaxslam(case, None, workdir / f"{case}_old", args.timeout, tree=args.old_tree)
            else:
                result = run_jaxslam(case, cache, workdir / f"{case}_{mode}", args.timeout)
            row.update({f"{mode}_{k}": v for k, v in result.items()})
            print(f"{case} {mode}: process {result['process_s']:.1f} s, filter {result['wall_s']:.1f} s, "
                  f"compile {result['compile_s']} s ({result['compiled']} compiled, "
                  f"{result['cache_hits']} from cache)", flush=True)
        if CASES[case][3] is not None and not args.no_gmapping:
            try:
                row.update(run_gmapping_case(case, workdir / "gmapping", args.timeout))
            except Exception as error:  # not built, failed: say so in the table
                row["gmapping_error"] = f"{type(error).__name__}: {error}"
            if "gmapping_process_s" in row:
                for mode in modes:
                    row[f"{mode}_speedup_process"] = row["gmapping_process_s"] / row[f"{mode}_process_s"]
                row["speedup_loop"] = row["gmapping_slam_s"] / row[f"{args.modes[-1]}_wall_s"]
                print(f"{case} GMapping C++: process {row['gmapping_process_s']:.1f} s, "
                      f"SLAM {row['gmapping_slam_s']:.1f} s", flush=True)
        rows.append(row)
        write_json(args.json, {"rows": rows, "workdir": str(workdir), "old_tree": str(args.old_tree or "")})

    columns = ["case"]
    for mode in modes:
        columns += [f"{mode}_process_s", f"{mode}_load_s", f"{mode}_compile_s", f"{mode}_wall_s",
                    f"{mode}_output_s", f"{mode}_overhead_s", f"{mode}_compiled"]
    columns += ["gmapping_process_s", "gmapping_slam_s"] + [f"{m}_speedup_process" for m in modes]
    columns += ["speedup_loop"]
    print_table(rows, columns)
    path = write_json(args.json, {"rows": rows, "workdir": str(workdir), "old_tree": str(args.old_tree or "")})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
