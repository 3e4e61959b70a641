"""From the command to the map: whole-process time of ``jaxslam run``, cold and warm
compilation cache, next to GMapping C++ in the same run, for one checkout or several.

Usage:
    python benchmarks/end_to_end.py [--cases intel-srupf-30 intel200-bag intel200-sweep vp-erb-100 ...]
        [--modes cold warm] [--cold-only CASE ...] [--sweep-particles 10,20,30,50,100]
        [--tree old=/path/to/checkout --tree new=.] [--no-gmapping]
        [--workdir DIR] [--timeout S] [--json NAME | --json /path/to/file.json]

Cases (``--cases all`` for every one; default ``intel-srupf-30``):

    intel-srupf-30, intel-srupf-100, intel-gmapping-30, intel-gmapping-100,
    killian-srupf-30, clinic-srupf-30, vp-erb-100, vp-erb-1000: a whole log;
    intel200-bag: SRUPF-GM, 30 particles, on a ROS 2 bag of the Intel log's first
    2400 scans (written into the work folder with :mod:`jaxslam.datasets.rosbag_write`),
    ``--max-steps 200`` keyframes: a user's first look at a short bag;
    intel200-sweep: SRUPF-GM on Intel's first 200 keyframes with 10, 20, 30, 50 and 100
    particles one after the other in one Python process (``jaxslam.app.runs.run``, no
    figures) with one compilation cache, always cold: what a notebook sweep compiles
    (``compiled``, ``compile_s``: the whole sweep's; ``trace_s``, ``lower_s`` apart).

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
whole-log laser cases, right after the jaxslam runs of that case; ``gmapping_process_s``
is its whole process, ``gmapping_slam_s`` its own SLAM-loop time. ``speedup_process`` is
GMapping's whole process over jaxslam's, ``speedup_loop`` GMapping's SLAM loop over
jaxslam's filter loop. MRPT is not run here.

``--tree NAME=PATH`` (repeatable) runs every case and mode with each checkout in turn
(``cold`` of every tree, then ``warm`` of every tree, each tree with its own cache
folder), so that old and new numbers come from the same run; one row per case and
tree. A checkout whose command line is ``jaxslam.cli`` (older layouts) is run as such.
The default is this checkout, named ``new``.

The machine may be shared: only ratios measured in the same run are meaningful; the
load average before and after each run is recorded. Writes
benchmarks/results/NAME.json (default ``end_to_end``), or the given ``.json`` path
(rows, machine, versions, command).
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

BAG_CASE = "intel200-bag"
BAG_SCANS, SHORT_KEYFRAMES = 2400, 200
SWEEP_CASE = "intel200-sweep"
SWEEP_PARTICLES = (10, 20, 30, 50, 100)

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
    BAG_CASE: ("intel-bag", "srupf-gm", 30, None),
    SWEEP_CASE: ("intel", "srupf-gm", None, None),
}
SUMMARY_FIELDS = ("load_s", "compile_s", "wall_s", "output_s", "total_s")

# The sweep: one process, one cache, runs.run per particle count, every compilation counted.
SWEEP_PROGRAM = r"""
import json, sys, time
started = time.perf_counter()
cache, out, dataset, steps = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
counts = [int(c) for c in sys.argv[5].split(",")]
try:
    from jaxslam.runtime.cache import CompileCounter, enable_compilation_cache
    from jaxslam.app import runs
except ImportError:  # an older layout
    from jaxslam.cache import CompileCounter, enable_compilation_cache
    from jaxslam import runs
enable_compilation_cache(cache)
rows = []
with CompileCounter() as total:
    for n in counts:
        t0 = time.perf_counter()
        summary = runs.run(out=f"{out}/p{n}", dataset=dataset, algorithm="srupf-gm", particles=n, max_steps=steps,
                           progress=False, plots=False)
        counted = summary.get("compilations") or {}
        rows.append({"particles": n, "run_s": time.perf_counter() - t0, "compile_s": summary["compile_s"],
                     "wall_s": summary["wall_s"], "compiled": counted.get("compiled"),
                     "keyframes": summary.get("keyframes")})
print(json.dumps({"runs": rows, "total": total.as_dict(), "process_s": time.perf_counter() - started}))
"""


def cli_module(tree: Path) -> str:
    """The checkout's command-line module."""
    return "jaxslam.app.cli" if (Path(tree) / "jaxslam" / "app" / "cli.py").exists() else "jaxslam.cli"


def tree_env(tree: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(tree) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def write_short_bag(workdir: Path) -> Path:
    """A ROS 2 bag of the Intel log's first :data:`BAG_SCANS` scans (written once)."""
    from jaxslam.datasets.registry import lookup
    from jaxslam.datasets.rosbag_write import write_rosbag

    path = workdir / f"intel_first_{BAG_SCANS}"
    if not path.exists():
        write_rosbag(lookup("intel").load(), path, version=2, scans=slice(0, BAG_SCANS))
    return path


def run_sweep(cache: Path, out: Path, timeout: float, tree: Path, particles: tuple = SWEEP_PARTICLES) -> dict:
    """The particle sweep of :data:`SWEEP_CASE` in one process of the checkout ``tree``."""
    counts = ",".join(map(str, particles))
    cmd = ["nice", "-n", "10", sys.executable, "-c", SWEEP_PROGRAM, str(cache), str(out), "intel",
           str(SHORT_KEYFRAMES), counts]
    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=tree_env(tree), timeout=timeout, cwd=str(tree))
    process_s = time.perf_counter() - started
    if proc.returncode != 0:
        raise RuntimeError(f"the sweep in {tree} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    total = result["total"]
    return {"process_s": process_s, "compile_s": sum(r["compile_s"] for r in result["runs"]),
            "wall_s": sum(r["wall_s"] for r in result["runs"]), "compiled": total["compiled"],
            "cache_hits": total["cache_hits"], "xla_s": total["seconds"], "trace_s": total.get("trace_s"),
            "lower_s": total.get("lower_s"), "runs": result["runs"], "overhead_s": process_s - sum(
                r["wall_s"] for r in result["runs"]),
            "load_average": [load_before, os.getloadavg()[0]],
            "command": f"python -c SWEEP_PROGRAM {cache} {out} intel {SHORT_KEYFRAMES} {counts}"}


def run_jaxslam(case: str, cache: Path | None, out: Path, timeout: float, tree: Path = ROOT,
                dataset: str | None = None, extra: tuple = ()) -> dict:
    """One ``jaxslam run`` process from the checkout ``tree``; ``cache`` None: no cache
    flag (an old checkout that has no cache)."""
    name, algorithm, particles, _ = CASES[case]
    cmd = ["nice", "-n", "10", sys.executable, "-m", cli_module(tree), "run", "--dataset", dataset or name,
           "--algorithm", algorithm, "--particles", str(particles), "--out", str(out), "--no-progress", *extra]
    if cache is not None:
        cmd += ["--cache-dir", str(cache)]
    env = tree_env(tree)
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
    row["trace_s"], row["lower_s"] = compilations.get("trace_s"), compilations.get("lower_s")
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


def run_case(case: str, mode: str, cache: Path, out: Path, args, tree: Path, bag: Path | None) -> dict:
    if case == SWEEP_CASE:
        return run_sweep(cache, out, args.timeout, tree, args.sweep_particles)
    if case == BAG_CASE:
        return run_jaxslam(case, cache, out, args.timeout, tree, dataset=str(bag),
                           extra=("--max-steps", str(SHORT_KEYFRAMES)))
    return run_jaxslam(case, cache, out, args.timeout, tree)


def write_result(target: str, payload: dict) -> Path:
    if target.endswith(".json"):
        from _common import machine_info

        path = Path(target)
        path.write_text(json.dumps({"machine": machine_info(), **payload}, indent=2, default=float) + "\n")
        return path
    return write_json(target, payload)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="+", default=["intel-srupf-30"], help="case names or 'all'")
    parser.add_argument("--modes", nargs="+", default=["cold", "warm"], choices=["cold", "warm"])
    parser.add_argument("--no-gmapping", action="store_true", help="do not run GMapping C++")
    parser.add_argument("--workdir", type=Path, default=None, help="outputs and caches (default: a temp folder)")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds per process")
    parser.add_argument("--json", default="end_to_end",
                        help="result: benchmarks/results/NAME.json, or a path ending in .json")
    parser.add_argument("--cold-only", nargs="*", default=[], metavar="CASE", help="cases to run cold only")
    parser.add_argument("--sweep-particles", type=lambda t: tuple(int(c) for c in t.split(",")),
                        default=SWEEP_PARTICLES, metavar="N,N,...",
                        help=f"the sweep's particle counts (default {','.join(map(str, SWEEP_PARTICLES))})")
    parser.add_argument("--tree", action="append", default=[], metavar="NAME=PATH",
                        help="a checkout to run (repeatable; default: this one, as 'new')")
    args = parser.parse_args()
    trees = [tuple(t.split("=", 1)) for t in args.tree] or [("new", str(ROOT))]
    for tree in trees:
        if len(tree) != 2 or not os.path.isdir(tree[1]):
            parser.error(f"--tree {'='.join(tree)}: expected NAME=PATH of a checkout")
    trees = [(name, Path(path).resolve()) for name, path in trees]
    cases = list(CASES) if args.cases == ["all"] else args.cases
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="jaxslam_end_to_end_"))
    workdir.mkdir(parents=True, exist_ok=True)
    bag = write_short_bag(workdir) if BAG_CASE in cases else None
    meta = {"workdir": str(workdir), "trees": [[name, str(path)] for name, path in trees],
            "bag": None if bag is None else {"path": str(bag), "scans": BAG_SCANS, "max_steps": SHORT_KEYFRAMES},
            "sweep_particles": list(args.sweep_particles)}

    rows = []
    for case in cases:
        modes = ["cold"] if case == SWEEP_CASE or case in args.cold_only else list(args.modes)
        case_rows = {name: {"case": case, "tree": name} for name, _ in trees}
        for name, _ in trees:
            shutil.rmtree(workdir / f"cache_{case}_{name}", ignore_errors=True)
        for mode in modes:
            for name, path in trees:
                cache = workdir / f"cache_{case}_{name}"
                try:
                    result = run_case(case, mode, cache, workdir / f"{case}_{name}_{mode}", args, path, bag)
                except (RuntimeError, subprocess.TimeoutExpired) as error:  # one failed run: say so, go on
                    case_rows[name][f"{mode}_error"] = str(error)[-500:]
                    print(f"{case} {name} {mode}: failed: {str(error)[-500:]}", flush=True)
                    continue
                case_rows[name].update({f"{mode}_{k}": v for k, v in result.items()})
                print(f"{case} {name} {mode}: process {result['process_s']:.1f} s, filter {result['wall_s']:.1f} s, "
                      f"compile {result['compile_s']:.2f} s ({result['compiled']} compiled, "
                      f"{result['cache_hits']} from cache)", flush=True)
        if CASES[case][3] is not None and not args.no_gmapping:
            gmapping: dict = {}
            try:
                gmapping = run_gmapping_case(case, workdir / "gmapping", args.timeout)
            except Exception as error:  # not built, failed: say so in the table
                gmapping = {"gmapping_error": f"{type(error).__name__}: {error}"}
            for row in case_rows.values():
                row.update(gmapping)
                if "gmapping_process_s" in row and f"{modes[-1]}_wall_s" in row:
                    for mode in modes:
                        row[f"{mode}_speedup_process"] = row["gmapping_process_s"] / row[f"{mode}_process_s"]
                    row["speedup_loop"] = row["gmapping_slam_s"] / row[f"{modes[-1]}_wall_s"]
            if "gmapping_process_s" in gmapping:
                print(f"{case} GMapping C++: process {gmapping['gmapping_process_s']:.1f} s, "
                      f"SLAM {gmapping['gmapping_slam_s']:.1f} s", flush=True)
            else:
                print(f"{case} GMapping C++: {gmapping.get('gmapping_error')}", flush=True)
        rows.extend(case_rows.values())
        write_result(args.json, {"rows": rows, **meta})

    columns = ["case", "tree"]
    for mode in args.modes:
        columns += [f"{mode}_process_s", f"{mode}_load_s", f"{mode}_compile_s", f"{mode}_trace_s",
                    f"{mode}_wall_s", f"{mode}_output_s", f"{mode}_compiled"]
    columns += ["gmapping_process_s", "gmapping_slam_s"] + [f"{m}_speedup_process" for m in args.modes]
    columns += ["speedup_loop"]
    print_table(rows, columns)
    path = write_result(args.json, {"rows": rows, **meta})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
