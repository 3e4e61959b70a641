"""Run GMapping C++ (OpenSLAM, ros-perception/openslam_gmapping) on a CARMEN log.

A measuring tool for benchmarks that put jaxslam side by side with GMapping in one
run; it is not part of the package and holds none of GMapping's code. It drives the
command-line tool in ``../shared/tools/gmapping/`` (``build.sh`` builds it from a
git mirror of GMapping; ``run.sh LOG PARTICLES OUT.tum SEED [-- options]`` runs it,
see that folder's README), times the whole process, parses the JSON line the tool
prints last, and gives every scan of the log a pose so that the relations metric
scores GMapping exactly as it scores jaxslam:

    pose_i = keyframe_pose_k (+) (odom_k^-1 (+) odom_i)

for the last keyframe ``k <= i`` (the first keyframe for scans before it); see
:func:`jaxslam.metrics.trajectory_io.interpolate_poses`. GMapping's poses are robot
poses (it takes the odometry of each laser line and the laser offset separately),
the same frame as ``CarmenLog.odom_poses``.

GMapping stamps its keyframes with the laser line's ``ipc_timestamp`` (printed with
6 decimals); each keyframe is matched to the scan of the log with the nearest
``scan_times`` entry (within ``stamp_tolerance``), and a stamp shared by several
scans is given to them in log order.

    from benchmarks.gmapping_cpp import run_gmapping
    run = run_gmapping("../shared/datasets/carmen_raw/intel.clf.gz", particles=30, seed=0)
    run.trajectory, run.wall_s, run.info["slam_s"]

Run as a script for one log: ``python benchmarks/gmapping_cpp.py LOG [-p 30] [--seed 0]``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

__all__ = [
    "GMappingNotBuiltError",
    "GMappingRun",
    "GMappingRunError",
    "find_gmapping",
    "keyframes_to_scans",
    "run_gmapping",
]


class GMappingNotBuiltError(RuntimeError):
    """The GMapping command-line tool is not built (or its folder is missing)."""


class GMappingRunError(RuntimeError):
    """GMapping ran but failed, or its output could not be read."""


@dataclasses.dataclass(frozen=True)
class GMappingRun:
    """One GMapping C++ run on one log.

    Attributes:
        log_path: the log given to GMapping.
        particles: particle count.
        seed: GMapping's random seed (0 = its deterministic default).
        scan_times: (S,) ``ipc_timestamp`` of every scan of the log (jaxslam's reader).
        trajectory: (S, 3) robot pose of every scan (keyframes + odometry since).
        keyframe_indices: (K,) scan index of each GMapping keyframe, increasing.
        keyframe_poses: (K, 3) the best particle's keyframe poses.
        keyframe_times: (K,) their stamps as GMapping printed them.
        wall_s: wall time of the whole GMapping process (parse + SLAM + output).
        info: GMapping's JSON line: keyframes, laser_readings, slam_s, slam_cpu_s,
            parse_s, total_s, nan.
        command: the command line that was run.
        stdout: GMapping's standard output.
    """

    log_path: Path
    particles: int
    seed: int
    scan_times: np.ndarray
    trajectory: np.ndarray
    keyframe_indices: np.ndarray
    keyframe_poses: np.ndarray
    keyframe_times: np.ndarray
    wall_s: float
    info: dict[str, Any]
    command: tuple[str, ...]
    stdout: str

    def summary(self) -> dict[str, Any]:
        """JSON-friendly facts of the run (no arrays)."""
        return {
            "log": str(self.log_path),
            "particles": self.particles,
            "seed": self.seed,
            "wall_s": self.wall_s,
            "num_scans": int(self.scan_times.shape[0]),
            "num_keyframes": int(self.keyframe_indices.shape[0]),
            "command": " ".join(self.command),
            **{f"gmapping_{k}": v for k, v in self.info.items()},
        }


def _tool_dir() -> Path:
    """``../shared/tools/gmapping`` relative to the checkout (or ``$GMAPPING_TOOL_DIR``)."""
    env = os.environ.get("GMAPPING_TOOL_DIR")
    if env:
        return Path(env)
    for base in (ROOT, *ROOT.parents):
        candidate = base.parent / "shared" / "tools" / "gmapping"
        if candidate.is_dir():
            return candidate
    return ROOT.parent / "shared" / "tools" / "gmapping"


def _binary() -> Path:
    return Path(os.environ.get("GMAPPING_BIN", "/tmp/gmapping_build/gmapping_carmen"))


def find_gmapping(*, build: bool = False) -> tuple[Path, Path]:
    """``(run.sh, binary)`` of the GMapping tool; builds it first if ``build``.

    Raises:
        GMappingNotBuiltError: the tool folder or the binary is missing (the message
            says how to build it), or the build failed.
    """
    tool = _tool_dir()
    run_sh, build_sh, binary = tool / "run.sh", tool / "build.sh", _binary()
    if not run_sh.is_file():
        raise GMappingNotBuiltError(
            f"GMapping tool not found: no {run_sh}. Set GMAPPING_TOOL_DIR to the folder "
            "that holds run.sh and build.sh (shared/tools/gmapping)."
        )
    if not (binary.is_file() and os.access(binary, os.X_OK)) and build:
        out = subprocess.run(["bash", str(build_sh)], capture_output=True, text=True, check=False)
        if out.returncode != 0:
            raise GMappingNotBuiltError(
                f"{build_sh} failed (exit {out.returncode}): {(out.stderr or out.stdout)[-1500:]}"
            )
    if not (binary.is_file() and os.access(binary, os.X_OK)):
        raise GMappingNotBuiltError(
            f"GMapping is not built: {binary} is missing. Build it with `{build_sh}` "
            "(needs cmake, g++ and a git mirror of ros-perception/openslam_gmapping; see "
            f"{tool / 'README.md'}), or point GMAPPING_BIN at a built gmapping_carmen."
        )
    return run_sh, binary


def keyframes_to_scans(
    keyframe_times: np.ndarray,
    keyframe_poses: np.ndarray,
    scan_times: np.ndarray,
    odom_poses: np.ndarray,
    *,
    stamp_tolerance: float = 2e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """Scan indices of stamped keyframes and a pose for every scan.

    Args:
        keyframe_times: (K,) keyframe stamps (any order).
        keyframe_poses: (K, 3) their poses.
        scan_times: (S,) stamps of every scan of the log.
        odom_poses: (S, 3) odometry of every scan.
        stamp_tolerance: largest accepted ``|keyframe stamp - scan stamp|`` (s).

    Returns:
        ``(keyframe_indices (K,) increasing, trajectory (S, 3))``; keyframe poses
        reordered with the indices.

    Raises:
        GMappingRunError: a keyframe stamp matches no scan, or more keyframes share
            a stamp than scans have it.
    """
    from jaxslam.metrics.trajectory_io import interpolate_poses

    kf_t = np.asarray(keyframe_times, dtype=np.float64)
    kf_p = np.asarray(keyframe_poses, dtype=np.float64)
    stamps = np.asarray(scan_times, dtype=np.float64)
    if kf_t.shape[0] == 0:
        raise GMappingRunError("GMapping produced no keyframes")
    order = np.argsort(stamps, kind="stable")
    sorted_stamps = stamps[order]
    lo = np.searchsorted(sorted_stamps, kf_t - stamp_tolerance, side="left")
    hi = np.searchsorted(sorted_stamps, kf_t + stamp_tolerance, side="right")
    indices = np.empty(kf_t.shape[0], dtype=np.int64)
    used: set[int] = set()
    for k in np.argsort(kf_t, kind="stable"):
        candidates = sorted(int(i) for i in order[lo[k]:hi[k]] if int(i) not in used)
        if not candidates:
            what = "no scan" if hi[k] == lo[k] else "no scan left"
            raise GMappingRunError(
                f"GMapping keyframe stamp {kf_t[k]:.6f} matches {what} within "
                f"{stamp_tolerance} s of the log's scan stamps"
            )
        # Nearest stamp first, then log order.
        best = min(candidates, key=lambda i: (abs(stamps[i] - kf_t[k]), i))
        indices[k] = best
        used.add(best)
    sort = np.argsort(indices, kind="stable")
    indices, kf_p = indices[sort], kf_p[sort]
    return indices, interpolate_poses(indices, kf_p, odom_poses)


def _read_kf(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise GMappingRunError(f"GMapping wrote no keyframe file {path}")
    rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    for number, row in enumerate(rows, start=1):
        if len(row) != 4:
            raise GMappingRunError(f"{path}, line {number}: expected 't x y theta', got {len(row)} fields")
    data = np.array(rows, dtype=np.float64).reshape(-1, 4)
    if not np.all(np.isfinite(data)):
        raise GMappingRunError(f"{path}: non-finite keyframe poses (GMapping diverged)")
    return data[:, 0], data[:, 1:]


def _parse_info(stdout: str) -> dict[str, Any]:
    for line in reversed(stdout.splitlines()):
        line = line.strip()
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError as error:
                raise GMappingRunError(f"GMapping's last JSON line is malformed: {line!r} ({error})") from None
    raise GMappingRunError(f"GMapping printed no JSON line; its output ends: {stdout[-800:]!r}")


def run_gmapping(
    log_path: os.PathLike | str,
    particles: int = 30,
    seed: int = 0,
    *,
    log: Any = None,
    max_range: float | None = None,
    extra_args: Sequence[str] = (),
    nice: int | None = None,
    timeout: float | None = None,
    workdir: os.PathLike | str | None = None,
    stamp_tolerance: float = 2e-6,
) -> GMappingRun:
    """Run GMapping C++ on a CARMEN log and give every scan a pose.

    Args:
        log_path: a CARMEN log (plain or gzipped) that GMapping's reader accepts.
        particles: particle count.
        seed: GMapping's seed (0 is its deterministic default).
        log: the same log read by :func:`jaxslam.datasets.carmen.load_carmen` (its
            ``scan_times`` and ``odom_poses`` are used); read here when None.
        max_range: passed as ``-maxrange`` (GMapping's default: the log's laser range
            minus 0.01; logs whose no-return readings sit above the real range need it).
        extra_args: more ``gmapping_carmen`` options.
        nice: run under ``nice -n`` this (default None: the caller's own niceness; a
            niced caller plus nice 10 starves GMapping on a shared machine).
        timeout: seconds before the process is killed (GMappingRunError).
        workdir: where the TUM/KF files go (a temporary folder when None; kept).
        stamp_tolerance: see :func:`keyframes_to_scans`.

    Returns:
        A :class:`GMappingRun`.

    Raises:
        GMappingNotBuiltError: the tool is not built.
        GMappingRunError: GMapping failed, timed out, or its output is unreadable.
    """
    run_sh, _ = find_gmapping()
    log_path = Path(log_path)
    if not log_path.is_file():
        raise FileNotFoundError(f"no log {log_path}")
    if log is None:
        from jaxslam.datasets.carmen import load_carmen

        log = load_carmen(log_path)
    out_dir = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="gmapping_"))
    out_dir.mkdir(parents=True, exist_ok=True)
    tum = out_dir / f"gmapping_p{particles}_s{seed}.tum"
    options = list(extra_args)
    if max_range is not None:
        options = ["-maxrange", repr(float(max_range)), *options]
    cmd: list[str] = []
    if nice is not None and shutil.which("nice"):
        cmd = ["nice", "-n", str(int(nice))]
    cmd += ["bash", str(run_sh), str(log_path), str(int(particles)), str(tum), str(int(seed))]
    if options:
        cmd += ["--", *options]
    t0 = time.perf_counter()
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        raise GMappingRunError(f"GMapping timed out after {timeout} s: {' '.join(cmd)}") from None
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise GMappingRunError(
            f"GMapping failed (exit {out.returncode}) on {log_path}: "
            f"{(out.stderr or out.stdout)[-1500:]}"
        )
    info = _parse_info(out.stdout)
    kf_times, kf_poses = _read_kf(tum.with_suffix(".kf"))
    indices, trajectory = keyframes_to_scans(
        kf_times, kf_poses, log.scan_times, log.odom_poses, stamp_tolerance=stamp_tolerance
    )
    return GMappingRun(
        log_path=log_path,
        particles=int(particles),
        seed=int(seed),
        scan_times=np.asarray(log.scan_times, dtype=np.float64),
        trajectory=trajectory,
        keyframe_indices=indices,
        keyframe_poses=trajectory[indices],
        keyframe_times=np.sort(kf_times),
        wall_s=wall,
        info=info,
        command=tuple(cmd),
        stdout=out.stdout,
    )


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("log", help="CARMEN log (or a dataset name with relations: intel, fr079, mit-killian)")
    parser.add_argument("-p", "--particles", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-range", type=float, default=None)
    parser.add_argument("--out", default=None, help="write the per-scan trajectory as TUM here")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.metrics.relations import DATASET_RELATIONS, load_dataset_relations, relations_metric

    log = load_dataset_log(args.log)
    try:
        run = run_gmapping(log.path, args.particles, args.seed, log=log, max_range=args.max_range)
    except (GMappingNotBuiltError, GMappingRunError) as error:
        print(f"gmapping_cpp: {error}", file=sys.stderr)
        return 1
    record = run.summary()
    if args.log in DATASET_RELATIONS:
        record.update(relations_metric(load_dataset_relations(args.log), run.scan_times, run.trajectory))
    if args.out:
        from jaxslam.metrics.trajectory_io import write_tum

        write_tum(args.out, run.scan_times, run.trajectory, comment=record["command"])
    print(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
