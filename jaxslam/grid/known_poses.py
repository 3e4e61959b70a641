r"""Occupancy mapping with known poses (host NumPy): the map a corrected trajectory makes.

For every scan at a known laser pose, each usable beam adds ``l_occ`` to the log-odds
of its end point's cell and ``-l_free`` to the cells its ray crosses before it (a
reading at the range limit clears up to ``free_range`` but marks nothing). Rays are
sampled once per cell length, so a cell a ray crosses obliquely may count twice and
one it only clips may be skipped; the last cell length before the end point is not
cleared (rays nearly parallel to a wall end in its cells and would otherwise erode
their neighbours). The usual inverse sensor model (Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 9.1) without a clamp:

.. math:: \ell_c = \sum_{\text{hits in } c} \ell_{occ} - \sum_{\text{rays through } c} \ell_{free}.

The log-odds are returned with the grid's corner; :func:`known_pose_map` wraps them as
an :class:`~jaxslam.grid.mapfile.OccupancyMap` with ``map_server``'s thresholds.
"""

from __future__ import annotations

import math

import numpy as np

from jaxslam.grid.mapfile import OccupancyMap, threshold_values


def known_pose_log_odds(
    ranges: np.ndarray,
    valid: np.ndarray,
    angles: np.ndarray,
    laser_poses: np.ndarray,
    resolution: float = 0.05,
    max_range: float = 80.0,
    free_range: float = 20.0,
    l_occ: float = 0.85,
    l_free: float = 0.4,
    margin: float = 1.0,
    angle_offsets: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple[float, float]]:
    """``(log_odds (H, W) float32, (origin_x, origin_y))`` of scans at known laser poses.

    Args:
        ranges: ``(S, B)`` metres; valid: ``(S, B)`` usable hits; angles: ``(B,)``.
        laser_poses: ``(S, 3)`` world poses of the laser.
        resolution: metres per cell.
        max_range: readings at or beyond it are "no return" (they clear, never hit).
        free_range: rays clear at most this far.
        l_occ, l_free: log-odds added per hit and removed per crossing.
        margin: metres of unknown cells around everything observed.
        angle_offsets: ``(S,)`` per-scan shift of ``angles``.
    """
    ranges = np.asarray(ranges, np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(ranges) & (ranges > 0)
    poses = np.asarray(laser_poses, np.float64)
    offsets = np.zeros(ranges.shape[0]) if angle_offsets is None else np.asarray(angle_offsets, np.float64)
    no_return = np.isfinite(ranges) & (ranges >= max_range)
    hits = valid & (ranges < max_range)
    clear = np.where(hits, np.minimum(ranges, free_range), np.where(no_return, free_range, 0.0))
    heading = poses[:, 2:3] + angles[None, :] + offsets[:, None]
    ends = poses[:, None, :2] + ranges[..., None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    reach = poses[:, None, :2] + clear[..., None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    points = np.concatenate([poses[:, :2], ends[hits], reach.reshape(-1, 2)])
    lo = points.min(0) - margin
    hi = points.max(0) + margin
    width = int(math.ceil((hi[0] - lo[0]) / resolution))
    height = int(math.ceil((hi[1] - lo[1]) / resolution))
    hit_count = np.zeros(height * width, np.int64)
    free_count = np.zeros(height * width, np.int64)
    for s in range(ranges.shape[0]):
        beams = np.flatnonzero(clear[s] > 0)
        if beams.size:
            # one sample per cell length before the end point (the end cell is the hit's)
            t = np.arange(int(math.ceil(clear[s, beams].max() / resolution))) * resolution
            inside = t[None, :] < clear[s, beams][:, None] - resolution
            xs = poses[s, 0] + t[None, :] * np.cos(heading[s, beams])[:, None]
            ys = poses[s, 1] + t[None, :] * np.sin(heading[s, beams])[:, None]
            cells = (np.floor((ys[inside] - lo[1]) / resolution).astype(np.int64) * width
                     + np.floor((xs[inside] - lo[0]) / resolution).astype(np.int64))
            free_count += np.bincount(cells, minlength=height * width)
        if hits[s].any():
            e = ends[s, hits[s]]
            idx = (np.floor((e[:, 1] - lo[1]) / resolution).astype(np.int64) * width
                   + np.floor((e[:, 0] - lo[0]) / resolution).astype(np.int64))
            hit_count += np.bincount(idx, minlength=height * width)
    log_odds = (l_occ * hit_count - l_free * free_count).astype(np.float32).reshape(height, width)
    return log_odds, (float(lo[0]), float(lo[1]))


def known_pose_map(log_odds: np.ndarray, origin, resolution: float, occupied_thresh: float = 0.65,
                   free_thresh: float = 0.196) -> OccupancyMap:
    """An :class:`~jaxslam.grid.mapfile.OccupancyMap` of natural log-odds (``map_server``'s thresholds)."""
    with np.errstate(over="ignore"):  # exp overflows to inf for very free cells: p = 0
        prob = 1.0 / (1.0 + np.exp(-np.asarray(log_odds, np.float64)))
    return OccupancyMap(occupancy=threshold_values(prob, occupied_thresh, free_thresh), resolution=float(resolution),
                        origin=(float(origin[0]), float(origin[1]), 0.0), log_odds=np.asarray(log_odds),
                        occupied_thresh=occupied_thresh, free_thresh=free_thresh)


__all__ = ["known_pose_log_odds", "known_pose_map"]
