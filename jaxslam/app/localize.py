"""``jaxslam localize``: Monte Carlo localization of a laser log in a saved map.

``jaxslam localize --map DIR|map.yaml|map.npz --dataset LOG|BAG [--initial-pose X Y
THETA [--initial-std SX SY STH]] [--global] --out DIR`` reads the map
(:func:`jaxslam.grid.mapfile.load_map`) and the log as ``jaxslam run`` does (a dataset name,
a CARMEN log or a ROS bag), runs :func:`jaxslam.localization.experiment.localize` and
writes into ``OUT``:

* ``trajectory.tum`` — the estimate at every scan (TUM format, map frame);
* ``summary.json`` — what ran, when the filter converged (its own rule: the cloud's
  spread and the weight near the estimate, ``convergence_rule``), ESS, particles in
  use, injections, timings (strict JSON: no NaN);
* ``localization.png`` — the path on the map with the particle cloud at a few moments.

``--rerun FILE.rrd`` / ``--rerun-spawn`` log the run to Rerun as it goes, once per chunk
(:class:`jaxslam.viz.rerun_log.LocalizationLiveLog`): the run is the plain run's
compiled program.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np


def add_parser(sub, positive_int, nonneg_int) -> None:
    loc = sub.add_parser(
        "localize",
        help="localize a laser log in a saved map (Monte Carlo localization: KLD-adaptive, augmented MCL)",
    )
    loc.add_argument("--map", type=Path, required=True, metavar="DIR|MAP.yaml|MAP.npz",
                     help="a `jaxslam run` output folder, its map.npz, or a ROS map_server YAML file")
    loc.add_argument("--dataset", required=True,
                     help="dataset name (see `jaxslam datasets`), a CARMEN log or a ROS bag")
    loc.add_argument("--out", type=Path, required=True, help="output folder (created)")
    loc.add_argument("--initial-pose", type=float, nargs=3, default=None, metavar=("X", "Y", "THETA"),
                     help="start pose in the map frame (m, m, rad); without it the start is global")
    loc.add_argument("--initial-std", type=float, nargs=3, default=None, metavar=("SX", "SY", "STH"),
                     help="standard deviations around --initial-pose (default 0.1 m, 0.1 m, 0.05 rad)")
    loc.add_argument("--global", dest="global_start", action="store_true",
                     help="start with the particles spread uniformly over the map's free space (the default "
                          "without --initial-pose)")
    loc.add_argument("--particles", type=positive_int, default=5000,
                     help="particle capacity; the number in use adapts inside it (KLD sampling)")
    loc.add_argument("--seed", type=nonneg_int, default=0, help="random seed")
    loc.add_argument("--max-steps", type=positive_int, default=None, help="use the first this many scans")
    loc.add_argument("--max-beams", type=positive_int, default=60, help="beams used per scan, evenly spaced")
    loc.add_argument("--set", dest="overrides", action="append", default=[], metavar="NAME=VALUE",
                     help="change a filter parameter (repeatable): " + ", ".join(_param_names()))
    loc.add_argument("--chunk", type=positive_int, default=256, help="scans per compiled chunk")
    loc.add_argument("--max-range", type=float, default=None, metavar="M",
                     help="CARMEN logs: range limit in m (as for `jaxslam run`)")
    loc.add_argument("--rerun", type=Path, default=None, metavar="FILE.rrd",
                     help="log the run to a Rerun recording as it goes: map, particles, path, scans, ESS, "
                          'particles in use, injections (needs pip install "jaxslam[viz]")')
    loc.add_argument("--rerun-spawn", action="store_true", help="... and/or open the Rerun viewer live")
    loc.add_argument("--no-plots", action="store_true", help="skip localization.png")
    loc.add_argument("--json", action="store_true",
                     help="print summary.json instead of the short report at the end")
    bag = loc.add_argument_group("ROS bags")
    bag.add_argument("--scan-topic", default=None, help="sensor_msgs/LaserScan topic; default: the only one")
    bag.add_argument("--odom-topic", default=None, help="nav_msgs/Odometry topic, or /tf")
    bag.add_argument("--base-frame", default=None, help="robot base frame")
    bag.add_argument("--laser-mount", type=float, nargs=3, default=None, metavar=("X", "Y", "THETA"),
                     help="laser pose in the base frame (m, m, rad); default: from /tf_static")


def report(summary: dict, out: Path) -> str:
    """A few lines for the terminal after a localization run: how it converged, the
    particles and times, and where the files are (``summary.json`` has everything)."""
    start = "a uniform start over free space" if summary["global_start"] else "the given initial pose"
    if summary["converged"]:
        converged = (f"converged at scan {summary['converged_scan']} "
                     f"({summary['converged_after_s']:.1f} s of log time), compact cloud in "
                     f"{summary['compact_fraction']:.0%} of the measurements after it")
    else:
        converged = "did not converge (the cloud never stayed compact)"
    rate = summary["scans_per_s"]
    lines = [
        f"localization of {summary['scans']} scans from {start}",
        f"  estimate         {converged}; final spread {summary['final_spread_m']:.2f} m",
        f"  particles        {summary['particles_mean']:.0f} in use on average (capacity {summary['capacity']}), "
        f"{summary['resamplings']} resamplings, {summary['injections']} injections",
        f"  time             compilation {summary['compile_s']:.1f} s, filter loop {summary['wall_s']:.1f} s"
        + (f" ({rate:.0f} scans/s)" if rate else ""),
        f"  files            {out}: " + ", ".join(sorted(p.name for p in out.iterdir() if p.is_file())),
    ]
    return "\n".join(lines)


def _param_names() -> list[str]:
    from jaxslam.localization.monte_carlo import DEFAULTS

    return sorted(DEFAULTS)


def _overrides(items: list[str]) -> dict[str, float]:
    from jaxslam.app.errors import RunError
    from jaxslam.localization.monte_carlo import DEFAULTS

    values = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep:
            raise RunError(f"--set {item!r}: expected NAME=VALUE")
        if name not in DEFAULTS:
            raise RunError(f"--set {name}: no such parameter; use one of {', '.join(sorted(DEFAULTS))}")
        try:
            value = float(text)
        except ValueError:
            raise RunError(f"--set {name}: value must be a number, got {text!r}") from None
        if not math.isfinite(value) or value < 0:
            raise RunError(f"--set {name}: value must be a finite number >= 0, got {text!r}")
        values[name] = value
    return values


def _check_pose(option: str, values, positive: bool = False) -> None:
    from jaxslam.app.errors import RunError

    if values is None:
        return
    if not all(math.isfinite(v) for v in values):
        raise RunError(f"{option}: values must be finite, got {list(values)}")
    if positive and not all(v > 0 for v in values):
        raise RunError(f"{option}: standard deviations must be positive, got {list(values)}")


def _strict(value):
    """JSON without NaN or infinity (None in their place)."""
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def plot_localization(grid, trajectory, snapshots, times, title: str = "", converged: int | None = None):
    """The map, the estimated path (dotted before the scan ``converged``, where the
    estimate jumps between hypotheses) and the particle clouds of ``snapshots``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    occupancy = grid.occupancy
    shade = np.full(occupancy.shape, 0.8)  # unknown
    shade[grid.free] = 1.0
    shade[grid.occupied] = 0.0
    h, w = occupancy.shape
    ox, oy, yaw = grid.origin
    if abs(yaw) > 1e-9:  # drawn in the map frame; the path and particles are taken into it
        c, s = math.cos(yaw), math.sin(yaw)

        def to_map(xy):
            d = np.asarray(xy)[:, :2] - (ox, oy)
            return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1)
        extent = [0, w * grid.resolution, 0, h * grid.resolution]
    else:
        def to_map(xy):
            return np.asarray(xy)[:, :2]
        extent = [ox, ox + w * grid.resolution, oy, oy + h * grid.resolution]
    fig, ax = plt.subplots(figsize=(8, 8 * h / max(w, 1) + 0.6))
    ax.imshow(shade, cmap="gray", origin="lower", extent=extent, vmin=0, vmax=1, interpolation="nearest")
    colours = plt.cm.plasma(np.linspace(0.0, 0.85, max(len(snapshots), 1)))
    for (scan, poses), colour in zip(snapshots, colours):
        xy = to_map(poses)
        label = "start" if scan < 0 else f"scan {scan} ({times[scan] - times[0]:.1f} s)"
        # a wide cloud in small dots, a compact one (tracking) in larger ones
        size = 2 if np.ptp(xy, axis=0).max(initial=0) > 5.0 else 10
        ax.scatter(xy[:, 0], xy[:, 1], s=size, color=colour, alpha=0.6, lw=0, label=f"particles, {label}")
    path = to_map(trajectory)
    start = 0 if converged is None else int(converged)
    if start > 0:
        ax.plot(path[: start + 1, 0], path[: start + 1, 1], ":", color="tab:green", lw=0.8,
                label="estimate before convergence")
    ax.plot(path[start:, 0], path[start:, 1], "-", color="tab:green", lw=1.0, label="estimate")
    ax.plot(path[-1:, 0], path[-1:, 1], "o", color="tab:green", ms=4)
    known = np.nonzero(occupancy != -1)
    if known[0].size:  # the view: the known cells and 1 m around them
        pad = 1.0
        lo = np.array([known[1].min(), known[0].min()]) * grid.resolution - pad
        hi = (np.array([known[1].max(), known[0].max()]) + 1) * grid.resolution + pad
        if abs(yaw) <= 1e-9:
            lo, hi = lo + (ox, oy), hi + (ox, oy)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)" if abs(yaw) <= 1e-9 else "map x (m)")
    ax.set_ylabel("y (m)" if abs(yaw) <= 1e-9 else "map y (m)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=7, markerscale=2, framealpha=0.8)
    return fig


def run(args) -> dict[str, Any]:
    """``jaxslam localize`` with parsed arguments; returns the summary."""
    from jaxslam.app import data
    from jaxslam.app.errors import RunError
    from jaxslam.app.outputs import open_live_view, write_trajectory
    from jaxslam.grid.mapfile import load_map
    from jaxslam.localization.experiment import localize, summary

    if args.global_start and args.initial_pose is not None:
        raise RunError("--global and --initial-pose exclude each other")
    if args.initial_std is not None and args.initial_pose is None:
        raise RunError("--initial-std needs --initial-pose")
    _check_pose("--initial-pose", args.initial_pose)
    _check_pose("--initial-std", args.initial_std, positive=True)
    if args.max_range is not None and not args.max_range > 0:
        raise RunError(f"--max-range must be positive, got {args.max_range}")
    overrides = _overrides(args.overrides)
    grid = load_map(args.map)
    info, path, kind = data.resolve_dataset(args.dataset, None)
    if kind != "laser":
        raise RunError(f"--dataset {args.dataset!r} is {kind} data; localization needs a laser log")
    if info is not None and not info.simulated:
        info.paths()
    bag = data.bag_options({"scan_topic": args.scan_topic, "odom_topic": args.odom_topic,
                             "base_frame": args.base_frame, "laser_offset": args.laser_mount}, path)
    loading = time.perf_counter()
    log, _ = data.load_log(info, path, args.seed, bag, args.max_range)
    load_s = time.perf_counter() - loading
    if np.asarray(log.ranges).shape[0] < 1:
        raise RunError(f"--dataset {args.dataset!r}: the log has no scans")
    pose = None if args.initial_pose is None else np.asarray(args.initial_pose, np.float64)
    std = args.initial_std or (0.1, 0.1, 0.05)
    if pose is not None:
        inside = _free_at(grid, pose)
        if inside is None:
            raise RunError(f"--initial-pose {list(args.initial_pose)} lies outside the map "
                                f"({str(grid.source)!r})")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    name = info.name if info is not None else str(Path(path).resolve())
    viz = open_live_view(args.rerun, args.rerun_spawn, Path(name).name)
    live = None
    if viz is not None:
        from jaxslam.viz.rerun_log import LocalizationLiveLog

        live = LocalizationLiveLog(viz, log, grid)
    try:
        result = localize(log, grid, particles=args.particles, seed=args.seed, initial_pose=pose, initial_std=std,
                          overrides=overrides, max_steps=args.max_steps, chunk=args.chunk, max_beams=args.max_beams,
                          on_chunk=live)
    finally:
        if viz is not None:
            viz.close()
    record = {
        "command": "localize", "map": str(Path(grid.source).resolve()), "dataset": name,
        "seed": args.seed, "initial_pose": None if pose is None else [float(v) for v in pose],
        "initial_std": None if pose is None else [float(v) for v in std],
        **summary(result), "load_s": load_s,
        "map_shape": list(grid.shape), "map_resolution": grid.resolution, "map_origin": list(grid.origin),
        "jaxslam_version": __import__("jaxslam").__version__,
    }
    if args.rerun is not None:
        record["rerun"] = str(args.rerun)
    record["total_s"] = time.perf_counter() - started + load_s
    record = _strict(record)
    if not all(np.isfinite(result.trajectory).ravel()):
        raise RunError("the estimate is not finite (a bug); no trajectory written")
    write_trajectory(out, result.times, result.trajectory,
                     f"jaxslam localize {name} in {grid.source}, {args.particles} particles, seed {args.seed}")
    if not args.no_plots:
        from jaxslam.app.plotting import save

        mode = "global start" if pose is None else "start at the given pose"
        title = f"MCL in {Path(grid.source).name}: {Path(name).name}, {args.particles} particles, {mode}"
        save(plot_localization(grid, result.trajectory, result.snapshots, result.times, title,
                               record.get("converged_scan")), out / "localization.png")
    (out / "summary.json").write_text(json.dumps(record, indent=2, allow_nan=False) + "\n")
    return record


def _free_at(grid, pose) -> bool | None:
    """Whether ``pose``'s cell is free; None outside the map."""
    ox, oy, yaw = grid.origin
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = pose[0] - ox, pose[1] - oy
    col = math.floor((c * dx + s * dy) / grid.resolution)
    row = math.floor((-s * dx + c * dy) / grid.resolution)
    if not (0 <= row < grid.shape[0] and 0 <= col < grid.shape[1]):
        return None
    return bool(grid.free[row, col])
