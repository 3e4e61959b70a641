"""Localize a laser log in a saved map: :func:`~jaxslam.localization.experiment.localize`
runs :func:`~jaxslam.localization.monte_carlo.mcl`.

The log is any :class:`jaxslam.datasets.carmen.CarmenLog` (a CARMEN log, a ROS bag
read by :func:`jaxslam.datasets.rosbag.load_rosbag`, a simulation). Every scan is one
filter step, its control the odometry increment since the previous scan. The run is
a :class:`~jaxslam.localization.stream.StreamingLocalizer` fed chunks of ``chunk``
scans, each a jitted ``lax.scan`` (one program for full chunks, one for the last); at
a few chunk ends the particle cloud is kept for the figure.

Convergence, judged by the filter itself: the first scan from which, at ``hold``
measurements in a row, the cloud's spread is at most ``converged_spread`` metres and
the estimate's bins hold at least ``converged_weight`` of the weight
(``compact_fraction``: of the measurements from then on, those where that holds). With a reference
trajectory (:func:`tracking_errors`), convergence is the first scan from which the
estimate stays within a distance and an angle of it.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import numpy as np

from jaxslam.grid.mapfile import OccupancyMap
from jaxslam.localization.monte_carlo import MclConfig, MclParams
from jaxslam.localization.stream import StreamingLocalizer, filter_inputs

CLOUD_POINTS = 3000  # particles kept per snapshot for the figure


@dataclasses.dataclass(eq=False)
class LocalizationResult:
    """A localization run (host arrays).

    Attributes:
        times: ``(S,)`` scan stamps; ``trajectory``: ``(S, 3)`` the estimate per scan.
        info: per-scan :class:`jaxslam.localization.monte_carlo.MclInfo` fields as arrays.
        snapshots: ``[(scan, poses (M, 3))]`` particle clouds (at most
            ``CLOUD_POINTS`` of the particles in use each) after that scan;
            scan -1 is the initial cloud.
        config: the static settings; ``params``: the scalar parameters used.
        wall_s: filter time without compilation; ``compile_s``: compilation.
        global_start: whether the particles started over all free space.
    """

    times: np.ndarray
    trajectory: np.ndarray
    info: dict[str, np.ndarray]
    snapshots: list[tuple[int, np.ndarray]]
    config: MclConfig
    params: dict[str, float]
    wall_s: float
    compile_s: float
    global_start: bool


def make_filter_inputs(log, grid: OccupancyMap, particles: int, overrides: dict | None = None,
                       max_beams: int = 60, min_particles: int | None = None, max_distance: float = 2.0,
                       dtype=np.float32) -> tuple[MclConfig, MclParams]:
    """The :class:`~jaxslam.localization.monte_carlo.MclConfig` and :class:`~jaxslam.localization.monte_carlo.MclParams` for a log in a map."""
    return filter_inputs(grid, np.asarray(log.angles, np.float64), float(log.max_range),
                         np.asarray(log.laser_offset, np.float64), particles, overrides, max_beams, min_particles,
                         max_distance, dtype)


def localize(
    log,
    grid: OccupancyMap,
    particles: int = 5000,
    seed: int = 0,
    initial_pose=None,
    initial_std=(0.1, 0.1, 0.05),
    overrides: dict | None = None,
    max_steps: int | None = None,
    chunk: int = 256,
    snapshots: int = 4,
    max_beams: int = 60,
    min_particles: int | None = None,
    dtype=np.float32,
    on_chunk: Callable[[StreamingLocalizer, int, int], None] | None = None,
) -> LocalizationResult:
    """Localize ``log`` in ``grid``: global when ``initial_pose`` is None.

    Args:
        log: a laser log (``ranges``, ``valid``, ``angles``, ``odom_poses``,
            ``scan_times``, ``laser_offset``, ``max_range``).
        grid: the map (:func:`jaxslam.grid.mapfile.load_map`).
        particles: the capacity (the number in use adapts, KLD).
        seed: the run's seed (initial draw and every step's key).
        initial_pose: ``(x, y, theta)`` in the map frame, or None for a uniform start.
        initial_std: standard deviations of the start around ``initial_pose``.
        overrides: ``jaxslam.localization.monte_carlo.DEFAULTS`` values to change.
        max_steps: use the first scans only.
        chunk: scans per compiled chunk.
        snapshots: particle clouds kept: the initial one and ``snapshots - 1`` at
            chunk ends spread over the run (the last included).
        max_beams, min_particles: see :class:`~jaxslam.localization.monte_carlo.MclConfig`.
        dtype: float32 (default) or float64 (needs JAX's 64-bit mode).
        on_chunk: called as ``on_chunk(localizer, lo, hi)`` after the scans ``lo:hi``
            of each chunk (the live view); it runs no filter program of its own.
    """
    times = np.asarray(log.scan_times, np.float64)
    ranges = np.asarray(log.ranges)
    total = ranges.shape[0] if max_steps is None else min(int(max_steps), ranges.shape[0])
    if total < 1:
        raise ValueError("the log has no scans")
    localizer = StreamingLocalizer(
        grid, np.asarray(log.angles, np.float64), float(log.max_range), np.asarray(log.laser_offset, np.float64),
        particles=particles, seed=seed, initial_pose=initial_pose, initial_std=initial_std, overrides=overrides,
        max_beams=max_beams, min_particles=min_particles, dtype=dtype)
    kept: list[tuple[int, np.ndarray]] = [(-1, localizer.cloud(CLOUD_POINTS))] if snapshots > 0 else []
    chunk = max(1, min(int(chunk), total))
    bounds = list(range(0, total, chunk)) + [total]
    wanted = set(np.linspace(1, len(bounds) - 1, max(snapshots - 1, 1)).round().astype(int).tolist())
    odom = np.asarray(log.odom_poses, np.float64)
    valid = np.asarray(log.valid, bool)
    offsets = np.asarray(getattr(log, "angle_offsets", None) if getattr(log, "angle_offsets", None) is not None
                         else np.zeros(ranges.shape[0]))
    loop_started = time.perf_counter()
    for index, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:]), 1):
        localizer.add_scans(times[lo:hi], ranges[lo:hi], valid[lo:hi], odom[lo:hi], offsets[lo:hi])
        if on_chunk is not None:
            on_chunk(localizer, lo, hi)
        if index in wanted and snapshots > 1:
            kept.append((hi - 1, localizer.cloud(CLOUD_POINTS)))
    jax.block_until_ready(localizer.state)
    wall_s = time.perf_counter() - loop_started - localizer.compile_s
    return LocalizationResult(
        times=times[:total], trajectory=localizer.trajectory(), info=localizer.info(), snapshots=kept,
        config=localizer.config, params=localizer.params_used, wall_s=wall_s, compile_s=localizer.compile_s,
        global_start=initial_pose is None,
    )


def self_convergence(result: LocalizationResult, converged_spread: float = 0.5, converged_weight: float = 0.9,
                     hold: int = 10) -> int | None:
    """The first scan from which the cloud is compact (see the module docstring) at
    ``hold`` measurements in a row; None if it never is."""
    info = result.info
    ok = (info["spread"] <= converged_spread) & (info["cluster_weight"] >= converged_weight)
    measured = np.flatnonzero(info["updated"])
    run = 0
    for position, scan in enumerate(measured):
        run = run + 1 if ok[scan] else 0
        if run >= hold:
            return int(measured[position - hold + 1])
    return None


def tracking_errors(trajectory: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distance m, |heading| rad)`` of the estimate from a reference, per scan."""
    trajectory, reference = np.asarray(trajectory, np.float64), np.asarray(reference, np.float64)
    distance = np.hypot(*(trajectory[:, :2] - reference[:, :2]).T)
    heading = np.abs(np.angle(np.exp(1j * (trajectory[:, 2] - reference[:, 2]))))
    return distance, heading


def summary(result: LocalizationResult, converged_spread: float = 0.5, converged_weight: float = 0.9) -> dict:
    """JSON-ready numbers of a run (no NaN: missing values are None)."""
    info = result.info
    times = result.times
    scans = int(times.shape[0])
    converged = self_convergence(result, converged_spread, converged_weight)
    updated = info["updated"].astype(bool)
    ess = info["ess"][updated] if updated.any() else info["ess"]
    return {
        "scans": scans,
        "capacity": int(result.config.capacity),
        "global_start": bool(result.global_start),
        "measurements": int(updated.sum()),
        "resamplings": int(np.sum(info["resampled"])),
        "injections": int(np.sum(info["injected"] > 0)),
        "injected_particles": int(np.sum(info["injected"])),
        "particles_mean": float(np.mean(info["particles"])),
        "particles_min": int(np.min(info["particles"])),
        "particles_max": int(np.max(info["particles"])),
        "particles_final": int(info["particles"][-1]),
        "ess_mean": float(np.mean(ess)),
        "ess_min": float(np.min(ess)),
        "converged": converged is not None,
        "converged_scan": converged,
        "converged_after_s": None if converged is None else float(times[converged] - times[0]),
        "compact_fraction": None if converged is None else float(np.mean(
            ((info["spread"] <= converged_spread) & (info["cluster_weight"] >= converged_weight))[converged:][
                updated[converged:]])),
        "convergence_rule": {"spread_m": converged_spread, "cluster_weight": converged_weight, "hold": 10},
        "final_pose": [float(v) for v in result.trajectory[-1]],
        "final_spread_m": float(info["spread"][-1]),
        "wall_s": result.wall_s,
        "compile_s": result.compile_s,
        "scans_per_s": scans / result.wall_s if result.wall_s > 0 else None,
        "log_duration_s": float(times[-1] - times[0]) if scans > 1 else 0.0,
        "max_beams": int(result.config.max_beams),
        "params": result.params,
    }


__all__ = [
    "CLOUD_POINTS",
    "LocalizationResult",
    "localize",
    "make_filter_inputs",
    "self_convergence",
    "summary",
    "tracking_errors",
]
