"""Localize a laser log in a saved map: :func:`~jaxslam.localization.experiment.localize`
runs :func:`~jaxslam.localization.monte_carlo.mcl`.

The log is any :class:`jaxslam.datasets.carmen.CarmenLog` (a CARMEN log, a ROS bag
read by :func:`jaxslam.datasets.rosbag.load_rosbag`, a simulation). Every scan is one
filter step, its control the odometry increment since the previous scan. The run is
a jitted ``lax.scan`` over chunks of ``chunk`` scans (one program for full chunks, one
for the last); at a few chunk ends the particle cloud is kept for the figure.

Convergence, judged by the filter itself: the first scan from which, at ``hold``
measurements in a row, the cloud's spread is at most ``converged_spread`` metres and
the estimate's bins hold at least ``converged_weight`` of the weight
(``compact_fraction``: of the measurements from then on, those where that holds). With a reference
trajectory (:func:`tracking_errors`), convergence is the first scan from which the
estimate stays within a distance and an angle of it.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.datasets.geometry import se2_between
from jaxslam.grid.mapfile import OccupancyMap
from jaxslam.grid.types import Scan
from jaxslam.localization.field import free_cell_centres, likelihood_field
from jaxslam.localization.monte_carlo import DEFAULTS, MclConfig, MclParams, default_params, mcl
from jaxslam.runtime.driver import step_keys
from jaxslam.runtime.keys import seed_key

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


def log_controls(log) -> tuple[np.ndarray, Scan]:
    """``(increments (S, 3), scans)``: odometry increments (zero before the first scan)
    and the scans of a log, as the filter's controls and observations."""
    odom = np.asarray(log.odom_poses, np.float64)
    increments = np.zeros_like(odom)
    increments[1:] = se2_between(odom[:-1], odom[1:])
    ranges = np.asarray(log.ranges, np.float32)
    valid = np.asarray(log.valid, bool) & np.isfinite(ranges)
    offsets = np.asarray(getattr(log, "angle_offsets", np.zeros(ranges.shape[0])), np.float32)
    return increments, Scan(np.where(valid, ranges, 0.0).astype(np.float32), valid, offsets)


def make_filter_inputs(log, grid: OccupancyMap, particles: int, overrides: dict | None = None,
                       max_beams: int = 60, min_particles: int | None = None, max_distance: float = 2.0,
                       dtype=np.float32) -> tuple[MclConfig, MclParams]:
    """The :class:`~jaxslam.localization.monte_carlo.MclConfig` and :class:`~jaxslam.localization.monte_carlo.MclParams` for a log in a map."""
    num_beams = int(np.asarray(log.ranges).shape[1])
    if min_particles is None:
        min_particles = min(particles, max(100, particles // 50))
    config = MclConfig(capacity=int(particles), num_beams=num_beams, max_beams=int(max_beams),
                       min_particles=int(min_particles))
    field = likelihood_field(grid, max_distance, dtype)
    free = free_cell_centres(grid, max_cells=1 << 20)
    params = default_params(field, free, np.asarray(log.angles, np.float64), float(log.max_range),
                            np.asarray(log.laser_offset, np.float64), **(overrides or {}))
    return config, params


@functools.partial(jax.jit, static_argnums=0)
def _run_chunk(config: MclConfig, params: MclParams, state, keys, controls, observations):
    step = mcl(config, params).step

    def body(carry, xs):
        key, control, observation = xs
        return step(key, carry, control, observation)

    return jax.lax.scan(body, state, (keys, controls, observations))


@functools.partial(jax.jit, static_argnums=0)
def _init(config: MclConfig, params: MclParams, key, pose, pose_std):
    return mcl(config, params).init(key, pose, pose_std)


@functools.partial(jax.jit, static_argnums=0)
def _init_global(config: MclConfig, params: MclParams, key):
    return mcl(config, params).init(key)


def _cloud(state, limit: int) -> np.ndarray:
    n = int(state.num_active)
    poses = np.asarray(state.poses[:n], np.float64)
    if n > limit:
        poses = poses[np.linspace(0, n - 1, limit).astype(np.int64)]
    return poses


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
    """
    increments, scans = log_controls(log)
    times = np.asarray(log.scan_times, np.float64)
    total = increments.shape[0] if max_steps is None else min(int(max_steps), increments.shape[0])
    if total < 1:
        raise ValueError("the log has no scans")
    config, params = make_filter_inputs(log, grid, particles, overrides, max_beams, min_particles, dtype=dtype)
    key_init, key_run = jax.random.split(jnp.asarray(seed_key(seed)))
    keys = np.asarray(step_keys(key_run, total))
    if initial_pose is None:
        state = _init_global(config, params, key_init)
    else:
        state = _init(config, params, key_init, np.asarray(initial_pose, dtype), np.asarray(initial_std, dtype))
    state = jax.block_until_ready(state)
    kept: list[tuple[int, np.ndarray]] = [(-1, _cloud(state, CLOUD_POINTS))] if snapshots > 0 else []
    chunk = max(1, min(int(chunk), total))
    bounds = list(range(0, total, chunk)) + [total]
    wanted = set(np.linspace(1, len(bounds) - 1, max(snapshots - 1, 1)).round().astype(int).tolist())
    pieces: list[Any] = []
    compile_s = 0.0
    compiled_lengths: set[int] = set()
    loop_started = time.perf_counter()
    real = np.dtype(dtype)
    for index, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:]), 1):
        args = (config, params, state, keys[lo:hi], increments[lo:hi].astype(real),
                Scan(scans.ranges[lo:hi].astype(real), scans.valid[lo:hi], scans.angle_offset[lo:hi].astype(real)))
        if hi - lo not in compiled_lengths:
            compiling = time.perf_counter()
            lowered = _run_chunk.lower(*args)
            lowered.compile()
            compile_s += time.perf_counter() - compiling
            compiled_lengths.add(hi - lo)
        state, ys = _run_chunk(*args)
        pieces.append(ys)
        if index in wanted and snapshots > 1:
            kept.append((hi - 1, _cloud(state, CLOUD_POINTS)))
    jax.block_until_ready(state)
    wall_s = time.perf_counter() - loop_started - compile_s
    info = {name: np.concatenate([np.asarray(getattr(p, name)) for p in pieces]) for name in pieces[0]._fields
            if name != "ancestors"}
    scalars = {name: float(np.asarray(getattr(params, name))) for name in DEFAULTS}
    return LocalizationResult(
        times=times[:total], trajectory=np.asarray(info["estimate"], np.float64), info=info, snapshots=kept,
        config=config, params=scalars, wall_s=wall_s, compile_s=compile_s, global_start=initial_pose is None,
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
    "log_controls",
    "make_filter_inputs",
    "self_convergence",
    "summary",
    "tracking_errors",
]
