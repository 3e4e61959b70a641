"""Run a grid SLAM filter on a CARMEN log (or a simulated one) from end to end.

:func:`run_grid_slam` runs the chosen filter's per-scan step over every scan of the
log (:mod:`jaxslam.grid.tracking`: each scan is tracked against the best particle's
map, and GMapping's linear and angular update thresholds on that tracked motion pick
the keyframes, where the filter itself runs), lays out the paged maps (a page table
over the odometry box plus a margin; it grows if the corrected path leaves it, and so
does the tile pool: :mod:`jaxslam.grid.paged`), runs in jitted chunks with a progress
bar (:func:`jaxslam.grid.driver.run_filter`; compile time is reported apart), rebuilds
the best particle's path (largest accumulated log-likelihood, as GMapping) and gives
the filter's own pose for every scan: the lineage's keyframe pose composed with the
tracked motion since (:func:`jaxslam.grid.tracking.scan_trajectory`). The map frame is
the odometry frame: the filter starts at the first scan's odometry pose, or, continuing
a saved map (``start_map``), at ``initial_pose`` in that map's frame.

One module, a little over the usual length: :func:`run_grid_slam` is the one place
where a log becomes the filter's inputs (keyframe rule, range rule, layout, ray
budget, start map) and its outputs become a result (best lineage, undone closures,
the per-scan path), and each half reads the other's intermediate arrays.
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.datasets.carmen import CarmenLog, select_keyframes
from jaxslam.datasets.registry import load_dataset_log
from jaxslam.grid.algorithms import GRID_ALGORITHMS, GridAlgorithm, grid_algorithm
from jaxslam.grid.driver import DEFAULT_CHUNK, recompilations, run_filter
from jaxslam.grid.filter import best_particle, match_start
from jaxslam.grid.mapfile import OccupancyMap
from jaxslam.grid.paged import PagedLayout, PoolLimitError, pool_stats, stitch, window_side
from jaxslam.grid.startmap import paged_start, start_cells, start_layout
from jaxslam.grid.types import GridSlamConfig, GridSlamParams, Odometry, Scan, get_path, param_paths
from jaxslam.grid.undone_closures import judge_at_end, reported_undo, take_back
from jaxslam.grid.range_rule import apply_range_rule
from jaxslam.grid.rays import required_points
from jaxslam.grid.tracking import scan_trajectory
from jaxslam.runtime.keys import seed_key
from jaxslam.metrics.trajectory_io import se2_between

ALGORITHMS = tuple(GRID_ALGORITHMS)
KEYFRAME_PATHS = ("keyframes.linear_update", "keyframes.angular_update", "keyframes.temporal_update")
# Per-scan outputs of the run kept for every scan (the rest is kept per keyframe).
PER_SCAN_KEYS = ("poses", "ancestors", "keyframe", "motion", "track_score", "track_accepted", "track_closed",
                 "track_conflict", "track_undo", "track_search")

def keyframe_rule(linear=None, angular=None, temporal=None,
                  algorithm: str | GridAlgorithm = "srupf-gm") -> tuple[float, float, float]:
    """``(linear, angular, temporal)`` thresholds: the given ones, else the filter's
    defaults (``keyframes`` of its params, :mod:`jaxslam.grid.algorithms`), applied
    inside the filter to the tracked motion (:mod:`jaxslam.grid.tracking`), the same
    for every log."""
    entry = grid_algorithm(algorithm) if isinstance(algorithm, str) else algorithm
    given = (linear, angular, temporal)
    return tuple(float(entry.param_default(path) if g is None else g)
                 for g, path in zip(given, KEYFRAME_PATHS, strict=True))


@dataclasses.dataclass
class GridSlamResult:
    """Everything a run produced (NumPy arrays on the host).

    Attributes:
        trajectory: ``(S, 3)`` a pose for every scan of the log.
        scan_times: ``(S,)`` the scans' timestamps.
        keyframes: ``(K,)`` indices of the keyframes into the scans.
        keyframe_poses: ``(K, 3)`` corrected keyframe poses of the best particle.
        map_log_odds: ``(H, W)`` float32 natural log-odds of the best particle's map
            (row 0 at ``origin`` y, rows grow with y).
        resolution: m per cell; ``origin``: world ``(x, y)`` of cell (0, 0)'s corner.
        info: per-keyframe diagnostics (``ess``, ``resampled``, ``mean_score``,
            ``best_score``, ``dropped_points``, ``pd_ok_fraction``).
        wall_s: run time without compilation; ``compile_s``: compilation.
        resamplings: number of resampling steps.
        state: the final filter state (particles, maps, weights) as host arrays.
        map_stats: pool and tile counts of the final maps (:func:`jaxslam.grid.paged.pool_stats`).
        growths: each growth of the maps (step, what grew, new sizes, whether it
            recompiled: a moved page table does not).
        compiler_options: the XLA options the run's programs were compiled with
            (:mod:`jaxslam.runtime.compiler`).
    """

    algorithm: str
    dataset: str
    particles: int
    seed: int
    trajectory: np.ndarray
    scan_times: np.ndarray
    keyframes: np.ndarray
    keyframe_poses: np.ndarray
    map_log_odds: np.ndarray
    resolution: float
    origin: tuple[float, float]
    info: dict[str, np.ndarray]
    wall_s: float
    compile_s: float
    resamplings: int
    config: GridSlamConfig
    params: dict[str, Any]
    state: Any = None
    keyframe_rule: tuple[float, float, float] = (0.5, 0.5, -1.0)
    map_stats: dict[str, Any] = dataclasses.field(default_factory=dict)
    growths: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    compiler_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    range_rule: dict[str, Any] = dataclasses.field(default_factory=dict)
    start_match: dict[str, Any] | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready scalars."""
        return {
            "algorithm": self.algorithm,
            "dataset": self.dataset,
            "particles": self.particles,
            "seed": self.seed,
            "scans": int(self.trajectory.shape[0]),
            "keyframes": int(self.keyframes.shape[0]),
            "keyframe_rule": dict(zip(("linear_m", "angular_rad", "temporal_s"), self.keyframe_rule, strict=True)),
            "range_rule": dict(self.range_rule),
            "wall_s": self.wall_s,
            "compile_s": self.compile_s,
            "resamplings": self.resamplings,
            "s_per_keyframe": self.wall_s / max(int(self.keyframes.shape[0]) - 1, 1),
            "map_shape": list(self.map_log_odds.shape),
            "resolution": self.resolution,
            "match_beams": len(self.config.match_beams),
            "match_iterations": self.config.match_iterations,
            "max_points": self.config.max_points,
            "dropped_points_max": int(np.max(self.info["dropped_points"])) if self.info["dropped_points"].size else 0,
            "maps": dict(self.map_stats),
            "map_growths": len(self.growths),
            "map_growth_steps": [g["step"] for g in self.growths],
            "map_recompilations": recompilations(self.growths),
            "xla_compiler_options": dict(self.compiler_options),
            **self.closure_summary(),
        }

    def closure_summary(self) -> dict[str, Any]:
        """How often the loop-closure search replaced the tracking's match or undid a
        closure (:mod:`jaxslam.grid.closure`) and at which scans (the first 100 of each); a
        closure the end's judgment took back (:func:`jaxslam.grid.undone_closures.judge_at_end`)
        counts as undone at scan ``S``, and ``closure_undone_at_end`` says so."""
        closed = np.flatnonzero(np.asarray(self.info.get("track_closed", np.zeros(0, bool)), bool)) + 1
        # the rows the reported path took back: every undo, and the end's judgment last (scan S)
        undo = reported_undo(self.info.get("track_undo", np.zeros((0, 4))), self.info.get("track_undo_end"))
        undone = np.flatnonzero(undo[:, 0] > 0) + 1
        return {"closures": int(closed.shape[0]), "closure_scans": closed[:100].tolist(),
                "closures_undone": int(undone.shape[0]), "undo_scans": undone[:100].tolist(),
                "undone_scans_moved": int(np.sum(undo[:, 0])), "closure_undone_at_end": bool(undo[-1, 0] > 0)}


def _dataset_name(log_or_name) -> str:
    if isinstance(log_or_name, (str, os.PathLike)):
        return os.path.basename(str(log_or_name)).split(".")[0] if os.path.exists(str(log_or_name)) else str(log_or_name)
    path = getattr(log_or_name, "path", None)
    return os.path.basename(str(path)).split(".")[0] if path is not None else "log"


def map_layout(
    log: CarmenLog, keyframes: np.ndarray, resolution: float, margin: float, particles: int, window_range: float,
    bounds=None,
) -> PagedLayout:
    """The starting layout of a run's paged maps.

    The page table covers ``bounds`` if given, else the odometry box of the keyframes
    plus ``margin`` metres (it grows when the corrected path leaves it; a page-table
    entry is 4 bytes per 3.2 m tile and particle, so a generous box is cheap). The pool
    starts with room for about one map of the table plus a window of fresh tiles per
    particle, and doubles when it runs out.
    """
    if bounds is not None:
        xmin, ymin, xmax, ymax = bounds
    else:
        lo = log.odom_poses[keyframes, :2].min(0) - margin
        hi = log.odom_poses[keyframes, :2].max(0) + margin
        xmin, ymin, xmax, ymax = lo[0], lo[1], hi[0], hi[1]
    layout = PagedLayout.covering(float(xmin), float(ymin), float(xmax), float(ymax), resolution)
    side = window_side(window_range, layout)
    slots = 1 + min(layout.table_size, 4096) + particles * side * side // 4
    slots = int(2 ** np.ceil(np.log2(slots)))
    if slots * layout.tile_cells >= 2**31:
        fit = 2 ** int(np.floor(np.log2((2**31 - 1) // layout.tile_cells)))  # the largest pool
        most = max(0, (fit - 1 - min(layout.table_size, 4096)) * 4 // (side * side))
        raise PoolLimitError(f"{particles} particles need a map pool of {slots} tiles of {layout.tile_cells} "
                             f"cells, beyond int32 cell indexing (2**31 cells); at most {most} particles fit its starting "
                             "pool")
    return dataclasses.replace(layout, slots=slots)


def best_trajectory(info_poses, info_ancestors, final_index: int) -> np.ndarray:
    """Host: corrected poses ``(T, 3)`` of the lineage of final particle ``final_index``.

    Args:
        info_poses: ``(T, P, 3)`` ``GridSlamInfo.poses`` stacked over steps.
        info_ancestors: ``(T, P)`` ``GridSlamInfo.ancestors``.
        final_index: index of a particle in the final state.
    """
    poses = np.asarray(info_poses)
    ancestors = np.asarray(info_ancestors)
    steps = poses.shape[0]
    out = np.empty((steps, 3), poses.dtype)
    idx = int(final_index)
    for t in range(steps - 1, -1, -1):
        idx = int(ancestors[t, idx])
        out[t] = poses[t, idx]
    return out


RESOLUTION = 0.05
"""Cell size (m) of a run's maps by default (:func:`run_grid_slam`'s ``resolution``)."""


def run_grid_slam(
    log_or_sim: CarmenLog | str | os.PathLike,
    algorithm: str = "srupf-gm",
    particles: int = 30,
    seed: int = 0,
    params: dict[str, Any] | None = None,
    *,
    config: dict[str, Any] | None = None,
    progress: bool = True,
    linear_update: float | None = None,
    angular_update: float | None = None,
    temporal_update: float | None = None,
    resolution: float = RESOLUTION,
    margin: float | None = None,
    bounds: tuple[float, float, float, float] | None = None,
    pool_slots: int | None = None,
    max_keyframes: int | None = None,
    dtype=jnp.float32,
    chunk: int = DEFAULT_CHUNK,
    checkpoint: Any = None,
    start_map: OccupancyMap | None = None,
    initial_pose=None,
) -> GridSlamResult:
    """Run ``algorithm`` on a log and collect trajectory, map and diagnostics.

    The keywords are independent choices of one run, each with a default that suits
    every log (the Python face of ``jaxslam run``'s options); a caller changes one or
    two of them, which keywords keep readable.

    Args:
        log_or_sim: a :class:`~jaxslam.datasets.carmen.CarmenLog` (or
            :class:`~jaxslam.datasets.laser_sim.SimulatedLog`), a dataset name known to
            :func:`jaxslam.datasets.registry.load_dataset_log`, or a path.
        algorithm: ``"srupf-gm"`` (pose correction), ``"srupf-gm-npc"`` or
            ``"gmapping"`` (:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`: its step
            and its defaults).
        particles: number of particles.
        seed: PRNG seed.
        params: values over the algorithm's params, by path (``{"closure.trigger":
            0.3}``, or a whole part: ``{"closure": ClosureParams(...)}``;
            :func:`jaxslam.grid.types.with_values`).
        config: overrides of the static :class:`~jaxslam.grid.types.GridSlamConfig` fields
            (``match_stride``, ``match_iterations``, ``refine_steps``, ``matcher``,
            ``resampler``, ``max_points``, ``window_range``).
        progress: show the progress bar.
        linear_update, angular_update, temporal_update: keyframe thresholds (m, rad,
            s; GMapping's linearUpdate, angularUpdate, temporalUpdate) on the tracked
            motion (:mod:`jaxslam.grid.tracking`). ``None``: the filter's defaults
            (``keyframes`` of its params: 0.5 m for SRUPF-GM, GMapping's 1 m for the
            GMapping-style filter; 0.5 rad; no temporal update), for every log.
        resolution: cell size (m).
        margin: margin (m) around the odometry box for the starting page table
            (:func:`map_layout`; the maps grow beyond it when needed). ``None``: the
            static beam reach (``window_range``) plus 10 m for odometry drift, so that
            a run whose corrected path stays near its odometry never grows the table
            (each growth costs a compilation; a table entry costs 4 bytes per 3.2 m
            tile and particle).
        bounds: a starting map box ``(xmin, ymin, xmax, ymax)`` instead.
        pool_slots: starting pool size in tiles (default: :func:`map_layout`'s
            estimate); it doubles whenever a step needs more.
        max_keyframes: stop after about this many keyframes (short runs, CI): the log
            is cut where GMapping's rule on the odometry reaches this many.
        dtype: float dtype of poses and params.
        chunk: scans per compiled chunk (:data:`jaxslam.grid.driver.DEFAULT_CHUNK`);
            the result does not depend on it.
        checkpoint: a :class:`jaxslam.runtime.checkpoint.Checkpoint` to save the state every N
            scans and/or resume from it (see :func:`jaxslam.runtime.progress.run_scan_chunked`).
        start_map: a saved map (:func:`jaxslam.grid.mapfile.load_map`) that every
            particle starts from (:mod:`jaxslam.grid.startmap`); the trajectory and the
            map are then in its frame.
        initial_pose: ``(x, y, theta)`` of the first scan. ``None``: the log's first
            odometry pose, or with ``start_map`` the saved run's last pose where the
            map records it (:attr:`~jaxslam.grid.mapfile.OccupancyMap.pose`), else
            ``(0, 0, 0)``. With ``start_map`` the first scan is matched in the saved
            map from there before it is written (:func:`jaxslam.grid.filter.match_start`);
            the result's ``start_match`` says how far that moved it.
    """
    name = _dataset_name(log_or_sim)
    log = log_or_sim if isinstance(log_or_sim, CarmenLog) else load_dataset_log(log_or_sim)
    entry = grid_algorithm(algorithm)
    rule = keyframe_rule(linear_update, angular_update, temporal_update, entry)
    scans = log.num_scans
    if max_keyframes is not None:
        # Cut the log where GMapping's rule on the odometry reaches this many keyframes
        # (the filter's own keyframes follow the tracked motion, so the count is close).
        odometric = select_keyframes(log.odom_poses, *rule, times=log.scan_times)
        if odometric.shape[0] > max_keyframes:
            scans = int(odometric[max_keyframes - 1]) + 1
    if scans < 2:
        raise ValueError("the log has fewer than two scans; nothing to filter")
    odom = np.asarray(log.odom_poses[:scans], np.float64)
    increments = se2_between(odom[:-1], odom[1:])
    times = np.asarray(log.scan_times[:scans], np.float64)

    overrides = dict(params or {})
    angles = overrides.pop("sensor.beam_angles", log.angles)
    laser_offset = overrides.pop("sensor.laser_offset", log.laser_offset)
    if "keyframes" in overrides:  # a whole part
        rule = tuple(float(v) for v in overrides["keyframes"])
    else:
        for path, value in zip(KEYFRAME_PATHS, rule, strict=True):
            overrides.setdefault(path, value)
        rule = tuple(float(overrides[path]) for path in KEYFRAME_PATHS)
    overrides, ranging = apply_range_rule(overrides, log)
    prm: GridSlamParams = entry.make_params(angles, laser_offset, dtype=dtype, values=overrides)
    usable = float(prm.sensor.usable_range)
    ranges = np.asarray(log.ranges[:scans], np.float64)
    valid = np.asarray(log.valid[:scans]) & np.isfinite(ranges)
    ranges = np.where(valid, ranges, 0.0)
    cfg_over = dict(config or {})
    # Static bound on the usable range (it sizes the tile window of a write): 20 m or
    # the usable range rounded up to 10 m, so that sweeping usable_range below it
    # never recompiles.
    window_range = float(cfg_over.pop("window_range", max(20.0, 10.0 * np.ceil(usable / 10.0))))
    if margin is None:
        margin = window_range + 10.0
    if initial_pose is None:
        initial_pose = odom[0] if start_map is None else (start_map.pose if start_map.pose is not None else (0, 0, 0))
    initial_pose = np.asarray(initial_pose, np.float64).reshape(3)
    layout = map_layout(log, np.arange(scans), resolution, margin, particles, window_range, bounds)
    if pool_slots is not None:
        layout = dataclasses.replace(layout, slots=int(pool_slots))
    start = None
    if start_map is not None:
        start_steps = start_cells(start_map, resolution, float(prm.map.log_odds_unit), float(prm.map.l_max))
        layout = start_layout(start_steps, start_map, layout, odom, initial_pose, margin)
        start = paged_start(start_steps, layout)
    max_points = cfg_over.pop("max_points", None)
    if max_points is None:
        need = required_points(np.minimum(ranges, usable), valid, resolution)
        max_points = int(np.ceil(need / 1024.0) * 1024)
    cfg = entry.make_config(particles, layout, log.num_beams, max_points, window_range=window_range, **cfg_over)

    offsets = np.asarray(log.angle_offsets[:scans], np.float64)
    # NumPy inputs: the jitted init and chunk runner take them as they are, whereas
    # jnp.asarray would run (and compile or load) a conversion program for each.
    real = np.dtype(dtype)
    first = Scan(np.asarray(ranges[0], real), np.asarray(valid[0]), np.asarray(offsets[0], real))
    controls = Odometry(np.asarray(increments, real), np.ones(scans - 1, real), np.asarray(np.diff(times), real))
    observations = Scan(np.asarray(ranges[1:], real), np.asarray(valid[1:]), np.asarray(offsets[1:], real))
    unit = float(prm.map.log_odds_unit)
    params_record = {path: np.asarray(get_path(prm, path)).tolist() for path in param_paths()
                     if path != "sensor.beam_angles"}
    start_match = None
    if start is not None:  # the first scan matched in the saved map before it is written
        started = time.perf_counter()
        matched, before, after = jax.device_get(match_start(start, first, np.asarray(initial_pose, real), prm, cfg))
        moved = se2_between(initial_pose, np.asarray(matched, np.float64))
        start_match = {"given_pose": initial_pose.tolist(), "moved_m": float(np.hypot(moved[0], moved[1])),
                       "turned_deg": float(np.degrees(moved[2])), "score_given": float(before),
                       "score_matched": float(after), "seconds": time.perf_counter() - started}
        initial_pose = np.asarray(matched, np.float64)
    state, ys, cfg, stats = run_filter(
        entry.step, seed_key(seed), prm, cfg, first, np.asarray(initial_pose, real), controls,
        observations, chunk=chunk, desc=f"{algorithm} {name} N={particles}", progress=progress,
        checkpoint=checkpoint, unit="scan", start=start,
    )
    state = jax.tree_util.tree_map(np.asarray, state)  # once, to the host: best particle, map, result
    best = int(best_particle(state))
    flags = np.asarray(ys["keyframe"], bool)
    kf_rows = np.flatnonzero(flags)
    kf_poses = best_trajectory(np.asarray(ys["poses"])[kf_rows], np.asarray(ys["ancestors"])[kf_rows], best)
    # a closure still watched at the end is judged on the scans it had (the undo row after the last scan's)
    end_undo = judge_at_end(state.closure, prm)
    undo = reported_undo(ys["track_undo"], end_undo)
    keyframes, trajectory = scan_trajectory(initial_pose, flags, kf_poses, ys["motion"], undo)
    kf_poses = take_back(np.concatenate([initial_pose[None], np.asarray(kf_poses, np.float64)], 0), keyframes, undo)
    cells, origin = stitch(state.maps.pool, state.maps.tables[best], state.maps.corner, cfg.layout)
    grid = cells.astype(np.float32) * unit
    info = {k: np.asarray(v)[kf_rows] for k, v in ys.items() if k not in PER_SCAN_KEYS}
    info.update({k: np.asarray(ys[k]) for k in PER_SCAN_KEYS if k not in ("poses", "ancestors")})
    info["track_undo_end"] = end_undo
    return GridSlamResult(
        algorithm=algorithm,
        dataset=name,
        particles=particles,
        seed=seed,
        trajectory=trajectory,
        scan_times=times,
        keyframes=keyframes,
        keyframe_poses=kf_poses,
        map_log_odds=grid,
        resolution=cfg.layout.resolution,
        origin=origin,
        info=info,
        wall_s=stats.wall_s,
        compile_s=stats.compile_s + (start_match["seconds"] if start_match else 0.0),
        resamplings=int(np.sum(info["resampled"])),
        config=cfg,
        params=params_record,
        state=state,
        keyframe_rule=rule,
        range_rule=ranging,
        start_match=start_match,
        map_stats=pool_stats(state.maps, cfg.layout),
        growths=stats.growths,
        compiler_options=stats.compiler_options,
    )


__all__ = [
    "ALGORITHMS",
    "KEYFRAME_PATHS",
    "RESOLUTION",
    "GridSlamResult",
    "best_trajectory",
    "keyframe_rule",
    "map_layout",
    "run_grid_slam",
]
