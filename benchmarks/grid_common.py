"""Shared helpers of the grid SLAM benchmarks (``benchmarks/grid_*.py``).

Each measured run happens in a fresh worker process (``python grid_common.py
--worker JSON``) so that its peak memory (``ru_maxrss``) is its own and a crash or a
memory blow-up cannot take the sweep down. The worker prints one JSON line: the run
summary of :func:`jaxslam.grid.experiment.run_grid_slam`, the relations metric when
the dataset has relations, and ``peak_rss_mb``.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parents[1]

# GMapping (OpenSLAM C++, single thread) on the full raw Intel log, 930 keyframes,
# measured on a 2-core cloud VM: seconds per run; peak 474 MB.
GMAPPING_CPP_INTEL_S = {10: 17.8, 30: 55.0, 50: 96.0, 100: 197.0}
GMAPPING_CPP_PEAK_MB = 474.0


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def worker(spec: dict) -> dict:
    """Run one configuration in this process and return its record."""
    from jaxslam.grid.experiment import run_grid_slam
    from jaxslam.grid.export import save_map
    from jaxslam.metrics.relations import (
        DATASET_RELATIONS,
        load_dataset_relations,
        relations_metric,
    )

    t0 = time.perf_counter()
    result = run_grid_slam(
        spec["dataset"],
        spec.get("algorithm", "srupf-gm"),
        particles=int(spec.get("particles", 30)),
        seed=int(spec.get("seed", 0)),
        params=spec.get("params") or None,
        config=spec.get("config") or None,
        progress=bool(spec.get("progress", False)),
        max_keyframes=spec.get("max_keyframes"),
    )
    record = result.summary()
    record["total_process_s"] = time.perf_counter() - t0
    record["params_overrides"] = spec.get("params") or {}
    record["config_overrides"] = spec.get("config") or {}
    if spec["dataset"] in DATASET_RELATIONS:
        metric = relations_metric(load_dataset_relations(spec["dataset"]), result.scan_times, result.trajectory)
        record.update(metric)
    if spec.get("map_dir"):
        paths = save_map(spec["map_dir"], result.map_log_odds, result.resolution, result.origin,
                         trajectory=result.keyframe_poses if spec.get("draw_path") else None)
        record["map_files"] = {k: str(v) for k, v in paths.items()}
    record["peak_rss_mb"] = peak_rss_mb()
    return record


def run_in_subprocess(spec: dict, timeout: float = 3600.0, tree: str | os.PathLike | None = None) -> dict:
    """Run :func:`worker` in a fresh Python process; returns its record (or an error).

    ``tree``: import jaxslam from another source tree (e.g. a checkout of an older
    commit, to time old and new code in the same run)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree or ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(spec)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, check=False)
    except subprocess.TimeoutExpired:
        return {**spec, "error": f"timeout after {timeout} s"}
    lines = [line for line in out.stdout.splitlines() if line.startswith("{")]
    if out.returncode != 0 or not lines:
        return {**spec, "error": (out.stderr or out.stdout)[-2000:]}
    return json.loads(lines[-1])


def raw_scan_indices(raw, ranges) -> "np.ndarray":
    """Index in the raw log ``raw`` (a :class:`jaxslam.datasets.carmen.CarmenLog`) of each
    scan given by its range vector, matched byte for byte (the first such raw scan); -1
    where none. GMapping's corrected logs, and the perturbed logs written from them,
    copy the raw log's range readings unchanged."""
    import numpy as np

    by_ranges: dict[bytes, int] = {}
    for index in range(raw.num_scans):
        by_ranges.setdefault(raw.ranges[index].tobytes(), index)
    return np.array([by_ranges.get(np.asarray(r).tobytes(), -1) for r in ranges], np.int64)


def robot_poses(laser_poses, laser_offset) -> "np.ndarray":
    """Robot poses ``r`` with ``r (+) laser_offset`` = ``laser_poses (S, 3)``: the laser
    poses of a corrected log or a run, in the robot frame the benchmark relations use."""
    import numpy as np

    from jaxslam.datasets.geometry import se2_compose, se2_inverse

    laser_poses = np.asarray(laser_poses, np.float64)
    back = se2_inverse(np.asarray(laser_offset, np.float64))
    return se2_compose(laser_poses, np.broadcast_to(back, laser_poses.shape))


def heading_errors(poses, reference) -> "np.ndarray":
    """``(n-1,)`` heading error (rad) of each scan-to-scan increment of ``poses`` against
    ``reference`` over their ``n`` common scans: ``wrap(dtheta_k - dtheta_ref_k)``, entry
    ``k - 1`` for the increment that ends at scan ``k``."""
    import numpy as np

    from jaxslam.datasets.geometry import se2_between, wrap_angle

    poses, reference = np.asarray(poses, np.float64), np.asarray(reference, np.float64)
    n = min(len(poses), len(reference))
    step = se2_between(poses[:n - 1], poses[1:n])[:, 2] - se2_between(reference[:n - 1], reference[1:n])[:, 2]
    return wrap_angle(step)


def saved_undo(run, end_only: bool = False) -> "np.ndarray":
    """``(S, 4)`` the undo rows a saved run's reported path took back
    (:func:`jaxslam.grid.undone_closures.reported_undo`): ``info_track_undo`` of scans 1..S-1
    (zeros with ``end_only``), then the end's judgment ``info_track_undo_end`` (zeros in
    older saved runs, which have none)."""
    import numpy as np

    from jaxslam.grid.undone_closures import reported_undo

    end = run["info_track_undo_end"] if "info_track_undo_end" in run.files else None
    rows = np.zeros((run["trajectory"].shape[0] - 1, 4)) if end_only else run["info_track_undo"]
    return reported_undo(rows, end)


def save_json(path: Path, payload) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(payload, indent=2, sort_keys=True))


def machine_info() -> dict:
    import platform

    import jax

    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
        "load_avg_at_start": os.getloadavg(),
    }


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        print(json.dumps(worker(json.loads(sys.argv[2]))), flush=True)
    else:
        sys.exit("usage: grid_common.py --worker JSON")
