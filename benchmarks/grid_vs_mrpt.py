"""Side by side on the Intel log: MRPT's ``rbpf-slam`` (C++) and jaxslam's SRUPF-GM.

Usage:
    python benchmarks/grid_vs_mrpt.py [--particles 30 100] [--max-scans N]
        [--skip-jaxslam] [--mrpt-algorithm 3] [--seed 0] [--workdir DIR]

Both systems get exactly the same scans: the raw Intel log is read once with
:func:`jaxslam.datasets.registry.load_dataset_log` (file order, beams at -90 .. +89 deg,
readings >= 80 m invalid) and handed to MRPT through ``benchmarks/mrpt/scans2rawlog``,
a small C++ tool (built here on first use) that writes an MRPT rawlog in the
actions / sensory-frames format ``rbpf-slam`` reads: MRPT 2.5's own
``carmen2rawlog`` writes the observations-only format, on which ``rbpf-slam`` 2.5.8
crashes, and its CARMEN parser takes a 0.5 deg beam spacing for the Intel log, which
has no resolution PARAM (it is 1 deg).

MRPT runs headless (``benchmarks/mrpt/rbpf_gridmapping_intel.ini``: grid RBPF with
the auxiliary-PF optimal sampling of Blanco et al., 5 cm cells, an update every 1 m
or 28.65 deg of odometry as GMapping's 1 m / 0.5 rad, GMapping's odometry noise
``srr srt str stt = 0.1 0.2 0.1 0.2`` in MRPT's Gaussian motion model; MRPT counts the
net odometric displacement since the last update where GMapping and jaxslam sum the
path, so it makes a few fewer keyframes). Its trajectory is the path of
the most likely particle at the end (``most_likely_path.txt``, one pose per filter
update) with a pose for every scan filled in as the last keyframe pose composed with
the odometry since, exactly as jaxslam does for its best particle. Both are scored
with the Kümmerle et al. relations of ``intel.relations``.

Timing: ``mrpt_wall_s`` is the wall clock of the whole ``rbpf-slam`` process
(reading the rawlog included); jaxslam's ``wall_s`` excludes XLA compilation, given
apart as ``compile_s``. ``speedup`` is MRPT's wall time over jaxslam's, and
``speedup_incl_compile`` counts compilation. Both run one after the other in the same
invocation, on the same (possibly shared) cores; the load average is recorded.

Writes benchmarks/results/grid_vs_mrpt.json and grid_vs_mrpt.png; converted rawlogs,
MRPT logs and TUM trajectories go to ``--workdir`` (default /tmp/jaxslam_grid_vs_mrpt),
never into the repository.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, print_table, write_json

from jaxslam.datasets.carmen import CarmenLog
from jaxslam.datasets.registry import load_dataset_log
from jaxslam.metrics.relations import (
    load_dataset_relations,
    relation_errors,
    relations_metric,
)
from jaxslam.metrics.trajectory_io import interpolate_poses, se2_compose, write_tum

HERE = Path(__file__).resolve().parent
MRPT_DIR = HERE / "mrpt"
DEFAULT_INI = MRPT_DIR / "rbpf_gridmapping_intel.ini"
CONVERTER_SOURCE = MRPT_DIR / "scans2rawlog.cpp"
MRPT_LIBS = ["obs", "poses", "serialization", "io", "system", "math", "rtti", "core"]

INSTALL_HINT = (
    "MRPT's rbpf-slam is not installed. On Debian/Ubuntu:\n"
    "    sudo apt-get install mrpt-apps libmrpt-obs-dev g++\n"
    "(mrpt-apps gives rbpf-slam; libmrpt-obs-dev and g++ build the small rawlog "
    "writer benchmarks/mrpt/scans2rawlog.cpp). Or run only jaxslam's side elsewhere."
)

# MRPT's Gaussian odometry model (CActionRobotMovement2D::TOptions_GaussianModel in MRPT
# 2.5): std_xy = minStdXY + a1 * dist + a2 * |dphi| and std_phi = minStdPHI + a3 * dist +
# a4 * |dphi|, SI units with angles in rad (its comments say m/deg and deg/m for a2 and
# a3, but the code uses rad); minStdPHI is given here in deg. MRPT applies it to the
# odometry accumulated between two filter updates. The default here is GMapping's
# srr, srt, str, stt = 0.1, 0.2, 0.1, 0.2 (also jaxslam's): MRPT's own defaults
# (0.01, 0.057, 0.017, 0.05, 0.01 m, 0.2 deg) are too tight for the Intel odometry
# (2.9 m mean relation error on the first 4000 scans against 0.5 m).
GMAPPING_MOTION = (0.1, 0.2, 0.1, 0.2, 0.01, 0.2)
MRPT_DEFAULT_MOTION = (0.01, float(np.degrees(0.001)), float(np.radians(1.0)), 0.05, 0.01, 0.2)

PER_SCAN_FIELDS = (
    "scan_times", "logger_times", "scan_lines", "ranges", "valid", "max_range_mask",
    "angle_offsets", "odom_poses", "laser_poses",
)


# ---------------------------------------------------------------------------------------
# MRPT side
# ---------------------------------------------------------------------------------------


def require_mrpt() -> str:
    """Path of ``rbpf-slam``, or exit with install instructions."""
    exe = shutil.which("rbpf-slam")
    if exe is None:
        raise SystemExit(f"error: `rbpf-slam` not found on PATH.\n{INSTALL_HINT}")
    return exe


def mrpt_version(exe: str) -> dict[str, str | None]:
    """MRPT library version (from the banner) and the Debian package version."""
    banner = subprocess.run(
        [exe, "/nonexistent.ini"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60
    )
    match = re.search(r"MRPT (\d+\.\d+\.\d+)", banner.stdout + banner.stderr)
    package = None
    if shutil.which("dpkg-query"):
        q = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "mrpt-apps"], capture_output=True, text=True)
        package = q.stdout.strip() or None
    return {"mrpt": match.group(1) if match else None, "debian_package_mrpt_apps": package}


def build_converter(workdir: Path) -> Path:
    """Compile ``scans2rawlog.cpp`` against the installed MRPT (once per source change)."""
    binary = workdir / "scans2rawlog"
    if binary.exists() and binary.stat().st_mtime >= CONVERTER_SOURCE.stat().st_mtime:
        return binary
    compiler = shutil.which("g++") or shutil.which("c++")
    includes = sorted(Path("/usr/include/mrpt").glob("*/include"))
    if compiler is None or not (Path("/usr/include/mrpt/obs/include")).is_dir():
        raise SystemExit(f"error: cannot build {CONVERTER_SOURCE.name}: need g++ and MRPT headers.\n{INSTALL_HINT}")
    cmd = [compiler, "-O2", "-std=c++17", *(f"-I{p}" for p in includes), str(CONVERTER_SOURCE),
           "-o", str(binary), *(f"-lmrpt-{lib}" for lib in MRPT_LIBS)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"error: building {CONVERTER_SOURCE.name} failed:\n{done.stderr[-3000:]}\n{INSTALL_HINT}")
    return binary


def write_rawlog(log: CarmenLog, converter: Path, workdir: Path, motion: tuple[float, ...]) -> Path:
    """The scans of ``log`` as an MRPT actions/sensory-frames rawlog (via a text file)."""
    text = workdir / f"scans_{log.num_scans}.txt"
    rawlog = workdir / f"intel_{log.num_scans}.rawlog"
    ranges = np.where(log.valid, log.ranges, 0.0)
    with open(text, "w") as fh:
        header = [log.num_scans, log.num_beams, float(log.angles[0]), float(log.angular_resolution),
                  float(log.max_range), *map(float, log.laser_offset)]
        fh.write(" ".join(repr(v) for v in header) + "\n")
        for k in range(log.num_scans):
            pose = " ".join(repr(float(v)) for v in log.odom_poses[k])
            beams = " ".join(f"{r:.3f}" for r in ranges[k])
            fh.write(f"{log.scan_times[k]:.6f} {pose} {beams}\n")
    cmd = [str(converter), str(text), str(rawlog), *(repr(float(m)) for m in motion)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"error: {' '.join(cmd)} failed:\n{done.stderr}")
    text.unlink()
    return rawlog


def mrpt_ini(template: Path, overrides: dict[str, Any]) -> str:
    """``template`` with ``key=value`` lines of [MappingApplication] replaced or added."""
    lines = template.read_text().splitlines()
    section, seen, out = None, set(), []
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("["):
            if section == "MappingApplication":
                out.extend(f"{k}={v}" for k, v in overrides.items() if k not in seen)
                seen.update(overrides)
            section = stripped.strip("[]")
        key = stripped.split("=", 1)[0].strip() if "=" in stripped and not stripped.startswith("#") else None
        if section == "MappingApplication" and key in overrides:
            out.append(f"{key}={overrides[key]}")
            seen.add(key)
            continue
        out.append(line)
    if section == "MappingApplication":
        out.extend(f"{k}={v}" for k, v in overrides.items() if k not in seen)
    return "\n".join(out) + "\n"


def _read_numbers(path: Path) -> np.ndarray:
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("%")]
    return np.array(rows, dtype=np.float64).reshape(len(rows), -1)


def read_mrpt_map(out_dir: Path) -> dict[str, Any] | None:
    """The final most-likely grid image and its limits, if MRPT wrote them."""
    png = out_dir / "finalMap_mrpt__maps__COccupancyGridMap2D_00.png"
    limits = out_dir / "finalMap_mrpt__maps__COccupancyGridMap2D_00_limits.txt"
    if not (png.exists() and limits.exists()):
        return None
    x_min, x_max, y_min, y_max = _read_numbers(limits)[0][:4]
    return {"png": png, "extent": (x_min, x_max, y_min, y_max)}


def run_mrpt(
    exe: str, rawlog: Path, log: CarmenLog, template: Path, particles: int, algorithm: int, seed: int,
    workdir: Path,
) -> dict[str, Any]:
    """Run ``rbpf-slam`` once; wall time, trajectory (a pose per scan) and diagnostics."""
    out_dir = workdir / f"mrpt_n{particles}_s{log.num_scans}"
    overrides = {
        "rawlog_file": str(rawlog),
        "logOutput_dir": str(out_dir),
        "sampleSize": particles,
        "PF_algorithm": algorithm,
        "RANDOM_SEED": seed,
    }
    ini = workdir / f"rbpf_n{particles}.ini"
    ini.write_text(mrpt_ini(template, overrides))
    console = workdir / f"rbpf_n{particles}.log"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(console, "w") as fh:
        done = subprocess.run([exe, str(ini)], stdin=subprocess.DEVNULL, stdout=fh, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        tail = console.read_text()[-2000:]
        raise SystemExit(f"error: rbpf-slam exited with {done.returncode}; see {console}:\n{tail}")

    times = _read_numbers(out_dir / "log_times.txt")  # step, ms, map size, inserted?
    if times.shape[0] != log.num_scans:
        raise SystemExit(f"rbpf-slam processed {times.shape[0]} steps for {log.num_scans} scans")
    keyframes = np.flatnonzero(times[:, 3] > 0.5).astype(np.int64)
    # One path entry for the initial pose, then one per filter update; with equal
    # insertion and localization thresholds the updates are the insertion steps.
    path = _read_numbers(out_dir / "most_likely_path.txt")
    if path.shape[0] != keyframes.shape[0] + 1:
        raise SystemExit(
            f"most_likely_path.txt has {path.shape[0]} poses for {keyframes.shape[0]} insertions; "
            "keep insertion and localization thresholds equal in the .ini"
        )
    # MRPT's world frame is the robot frame at the first scan: move it to the odometry
    # frame, like jaxslam's.
    start = log.odom_poses[0]
    kf_poses = se2_compose(np.broadcast_to(start, (keyframes.shape[0], 3)), path[1:, :3])
    trajectory = interpolate_poses(keyframes, kf_poses, log.odom_poses)
    # The filtered per-step mean (no smoothing), for reference.
    est = _read_numbers(out_dir / "log_estimated_path.txt")  # step x y z yaw pitch roll t
    mean_path = se2_compose(np.broadcast_to(start, (est.shape[0], 3)), est[:, [1, 2, 4]])
    stats = _read_numbers(out_dir / "log_ParticlesStats.txt")
    peak_rss = max(after.ru_maxrss, before.ru_maxrss) / 1024.0  # MiB; children's peak
    return {
        "wall_s": wall,
        "filter_s": float(np.sum(times[:, 1]) / 1000.0),
        "cpu_user_s": after.ru_utime - before.ru_utime,
        "cpu_sys_s": after.ru_stime - before.ru_stime,
        "peak_rss_mib_children": peak_rss,
        "keyframes": int(keyframes.shape[0]),
        "final_ess": float(stats[-1, 2]) if stats.size else None,
        "trajectory": trajectory,
        "mean_path": mean_path,
        "keyframe_poses_mrpt_frame": path[1:, :3],
        "map": read_mrpt_map(out_dir),
        "out_dir": str(out_dir),
        "ini": str(ini),
    }


# ---------------------------------------------------------------------------------------
# jaxslam side
# ---------------------------------------------------------------------------------------


def run_jaxslam(log: CarmenLog, particles: int, seed: int) -> dict[str, Any]:
    try:
        from jaxslam.grid.experiment import run_grid_slam
    except ImportError as err:
        raise SystemExit(f"error: jaxslam's grid SLAM is not available ({err}); use --skip-jaxslam") from err
    t0 = time.perf_counter()
    result = run_grid_slam(log, algorithm="srupf-gm", particles=particles, seed=seed, progress=False)
    total = time.perf_counter() - t0
    return {
        "wall_s": float(result.wall_s),
        "compile_s": float(result.compile_s),
        "total_s": total,
        "keyframes": int(result.keyframes.shape[0]),
        "resamplings": int(result.resamplings),
        "trajectory": result.trajectory,
        "map": {
            "log_odds": result.map_log_odds,
            "resolution": float(result.resolution),
            "origin": tuple(float(v) for v in result.origin),
        },
    }


# ---------------------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------------------


def cut_log(log: CarmenLog, max_scans: int | None) -> CarmenLog:
    """The first ``max_scans`` scans of ``log`` (all of them if None)."""
    if max_scans is None or max_scans >= log.num_scans:
        return log
    cut = {f: getattr(log, f)[:max_scans] for f in PER_SCAN_FIELDS if getattr(log, f) is not None}
    return dataclasses.replace(log, **cut)


def score(relations, log: CarmenLog, trajectory: np.ndarray) -> dict[str, float]:
    """Relations metric (mean and std) plus medians, which show how heavy the tail is."""
    metric = relations_metric(relations, log.scan_times, trajectory)
    keys = ("trans_err_mean_m", "trans_err_std_m", "rot_err_mean_deg", "rot_err_std_deg",
            "n_relations", "n_unmatched", "n_total")
    out = {k: metric[k] for k in keys}
    errors = relation_errors(relations, log.scan_times, trajectory)
    matched = errors.matched
    out["trans_err_median_m"] = float(np.median(errors.trans[matched])) if matched.any() else float("nan")
    out["rot_err_median_deg"] = float(np.degrees(np.median(errors.rot[matched]))) if matched.any() else float("nan")
    return out


def plot(runs: list[dict[str, Any]], path: Path) -> Path | None:
    """Maps and trajectories of the run with the most particles."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.image as mpimg
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    run = max(runs, key=lambda r: r["particles"])
    panels = [("MRPT rbpf-slam", run.get("_mrpt")), ("jaxslam SRUPF-GM", run.get("_jaxslam"))]
    panels = [(t, r) for t, r in panels if r is not None]
    fig, axes = plt.subplots(1, len(panels) + 1, figsize=(6 * (len(panels) + 1), 6))
    axes = np.atleast_1d(axes)
    for ax, (title, r) in zip(axes, panels):
        m = r["map"]
        if m is not None and "png" in m:
            # MRPT's map and its most likely path, in MRPT's frame (robot at scan 0).
            ax.imshow(mpimg.imread(m["png"]), cmap="gray", extent=m["extent"], origin="upper")
            xy = r["keyframe_poses_mrpt_frame"]
        elif m is not None:
            lo = m["log_odds"]
            prob = 1.0 - 1.0 / (1.0 + np.exp(lo))
            ox, oy = m["origin"]
            res = m["resolution"]
            ax.imshow(1.0 - prob, cmap="gray", origin="lower", vmin=0, vmax=1,
                      extent=(ox, ox + lo.shape[1] * res, oy, oy + lo.shape[0] * res))
            xy = r["trajectory"]
        else:
            xy = r["trajectory"]
        ax.plot(xy[:, 0], xy[:, 1], "r-", lw=0.6)
        ax.set_title(f"{title}, N={run['particles']}")
        ax.set_aspect("equal")
    ax = axes[-1]
    for (title, r), colour in zip(panels, ("tab:blue", "tab:orange")):
        ax.plot(r["trajectory"][:, 0], r["trajectory"][:, 1], color=colour, lw=0.7, label=title)
    ax.set_title("trajectories, odometry frame (a pose per scan)")
    ax.set_aspect("equal")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[30])
    parser.add_argument("--max-scans", type=int, default=None, help="use only the first N scans of the log")
    parser.add_argument("--skip-jaxslam", action="store_true", help="run MRPT only")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mrpt-algorithm", type=int, default=3, choices=[0, 1, 2, 3],
                        help="rbpf-slam PF_algorithm: 2 = optimal proposal by scan matching, "
                             "3 = auxiliary-PF optimal sampling (default, MRPT's Intel example)")
    parser.add_argument("--mrpt-config", type=Path, default=DEFAULT_INI)
    parser.add_argument("--motion", type=float, nargs=6, default=list(GMAPPING_MOTION),
                        metavar=("A1", "A2", "A3", "A4", "MIN_STD_XY", "MIN_STD_PHI_DEG"),
                        help="MRPT Gaussian odometry model (default: GMapping's srr srt str stt, "
                             f"0.01 m, 0.2 deg; MRPT's own defaults are {MRPT_DEFAULT_MOTION})")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/jaxslam_grid_vs_mrpt"))
    parser.add_argument("--name", default="grid_vs_mrpt", help="results file stem")
    parser.add_argument("--no-plot", action="store_true")
    args = parser.parse_args(argv)

    exe = require_mrpt()
    version = mrpt_version(exe)
    args.workdir.mkdir(parents=True, exist_ok=True)
    converter = build_converter(args.workdir)

    log = cut_log(load_dataset_log("intel"), args.max_scans)
    relations = load_dataset_relations("intel")
    rawlog = write_rawlog(log, converter, args.workdir, tuple(args.motion))
    load_before = os.getloadavg()

    runs, rows = [], []
    for particles in args.particles:
        run: dict[str, Any] = {"particles": particles, "scans": log.num_scans}
        mrpt = run_mrpt(exe, rawlog, log, args.mrpt_config, particles, args.mrpt_algorithm, args.seed,
                        args.workdir)
        mrpt_score = score(relations, log, mrpt["trajectory"])
        write_tum(args.workdir / f"mrpt_n{particles}.tum", log.scan_times, mrpt["trajectory"])
        run["mrpt"] = {k: v for k, v in mrpt.items()
                       if k not in ("trajectory", "mean_path", "keyframe_poses_mrpt_frame", "map")}
        run["mrpt"].update(mrpt_score)
        run["mrpt"]["filtered_mean_path"] = score(relations, log, mrpt["mean_path"])
        run["_mrpt"] = mrpt
        rows.append({"system": "mrpt rbpf-slam", "N": particles, "keyframes": mrpt["keyframes"],
                     "wall_s": mrpt["wall_s"], "compile_s": 0.0, **mrpt_score})
        print(f"MRPT N={particles}: {mrpt['wall_s']:.1f} s, trans {mrpt_score['trans_err_mean_m']:.3f} m, "
              f"rot {mrpt_score['rot_err_mean_deg']:.2f} deg", flush=True)

        if not args.skip_jaxslam:
            jx = run_jaxslam(log, particles, args.seed)
            jx_score = score(relations, log, jx["trajectory"])
            write_tum(args.workdir / f"jaxslam_n{particles}.tum", log.scan_times, jx["trajectory"])
            run["jaxslam"] = {k: v for k, v in jx.items() if k not in ("trajectory", "map")}
            run["jaxslam"].update(jx_score)
            run["_jaxslam"] = jx
            run["speedup"] = mrpt["wall_s"] / jx["wall_s"]
            run["speedup_incl_compile"] = mrpt["wall_s"] / (jx["wall_s"] + jx["compile_s"])
            rows.append({"system": "jaxslam srupf-gm", "N": particles, "keyframes": jx["keyframes"],
                         "wall_s": jx["wall_s"], "compile_s": jx["compile_s"], **jx_score})
            print(f"jaxslam N={particles}: {jx['wall_s']:.1f} s (+{jx['compile_s']:.1f} s compile), "
                  f"trans {jx_score['trans_err_mean_m']:.3f} m, rot {jx_score['rot_err_mean_deg']:.2f} deg, "
                  f"MRPT/jaxslam wall = {run['speedup']:.2f}", flush=True)
        runs.append(run)

    print()
    print_table(rows, ["system", "N", "keyframes", "wall_s", "compile_s", "trans_err_mean_m", "trans_err_std_m",
                       "rot_err_mean_deg", "rot_err_std_deg", "trans_err_median_m", "rot_err_median_deg",
                       "n_relations"])
    for run in runs:
        if "speedup" in run:
            print(f"N={run['particles']}: MRPT wall / jaxslam wall = {run['speedup']:.2f} "
                  f"({run['speedup_incl_compile']:.2f} counting compilation)")

    figure = None
    if not args.no_plot:
        figure = plot(runs, RESULTS / f"{args.name}.png")
    payload = {
        "dataset": "intel",
        "scans": log.num_scans,
        "max_scans": args.max_scans,
        "seed": args.seed,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "mrpt": {
            **version,
            "executable": exe,
            "config_template": str(args.mrpt_config.relative_to(HERE.parent))
            if args.mrpt_config.is_relative_to(HERE.parent) else str(args.mrpt_config),
            "config_text": mrpt_ini(args.mrpt_config, {"PF_algorithm": args.mrpt_algorithm, "RANDOM_SEED": args.seed}),
            "PF_algorithm": args.mrpt_algorithm,
            "motion_model_gaussian": dict(zip(("a1", "a2_m_per_rad", "a3_rad_per_m", "a4", "minStdXY_m",
                                               "minStdPHI_deg"), args.motion)),
            "rawlog_writer": str(CONVERTER_SOURCE.relative_to(HERE.parent)),
            "trajectory": "most likely particle's path (most_likely_path.txt) at the filter updates, "
                          "odometry in between",
        },
        "jaxslam": None if args.skip_jaxslam else {"algorithm": "srupf-gm", "entry": "run_grid_slam"},
        "runs": [{k: v for k, v in r.items() if not k.startswith("_")} for r in runs],
        "figure": figure.name if figure else None,
    }
    out = write_json(args.name, payload)
    print(f"wrote {out}" + (f" and {figure}" if figure else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
