"""Simulated laser logs for the localization tests: the office world, and a kidnapping."""

from __future__ import annotations

import types

import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose
from jaxslam.datasets.laser_sim import office_world, raycast, ring_path

BOUNDS = (0.0, 0.0, 16.0, 10.0)
# Crates against the outer walls: the ring corridor of the office world is nearly
# symmetric under a half turn, these make every place tell itself apart.
CRATES = [(3.0, 0.0, 3.6, 0.4), (15.6, 6.0, 16.0, 6.8), (9.0, 9.6, 10.2, 10.0), (0.0, 2.5, 0.5, 3.0)]


def _box(x0, y0, x1, y1):
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def crate_world(seed: int = 1) -> np.ndarray:
    walls = [tuple(w) for w in office_world(seed=seed)]
    for crate in CRATES:
        walls += _box(*crate)
    return np.asarray(walls, np.float64)


def laser_log(walls, true_poses, seed: int = 0, odom_std: float = 0.02, jump_at: int | None = None,
              num_beams: int = 180, max_range: float = 30.0):
    """A log of scans at ``true_poses``; the odometry integrates the true increments with
    noise, except that the increment into ``jump_at`` is the one before it (a kidnapping:
    the robot is carried away and its wheels do not know)."""
    rng = np.random.default_rng(seed)
    angles = np.linspace(-np.pi / 2, np.pi / 2, num_beams)
    ranges = raycast(walls, true_poses[:, :2], true_poses[:, 2:3] + angles[None, :], max_range)
    no_return = ~np.isfinite(ranges)
    ranges = np.where(no_return, max_range, ranges + rng.normal(0, 0.01, ranges.shape))
    steps = se2_between(true_poses[:-1], true_poses[1:])
    if jump_at is not None:
        steps[jump_at - 1] = steps[jump_at - 2]
    lin = np.hypot(steps[:, 0], steps[:, 1])
    steps = steps + rng.normal(0, 1, steps.shape) * odom_std * lin[:, None]
    odom = [true_poses[0]]
    for step in steps:
        odom.append(se2_compose(odom[-1], step))
    scans = true_poses.shape[0]
    return types.SimpleNamespace(
        ranges=ranges.astype(np.float32), valid=~no_return, angles=angles.astype(np.float32),
        angle_offsets=np.zeros(scans, np.float32), odom_poses=np.asarray(odom), scan_times=np.arange(scans) / 5.0,
        laser_offset=np.zeros(3), max_range=max_range, true_poses=true_poses,
    )


def ring_poses(laps: float = 1.0) -> np.ndarray:
    return ring_path(16.0, 10.0, 2.0, 0.1, laps)


def kidnapped_poses(at: int, skip: int, laps: float = 1.6) -> np.ndarray:
    poses = ring_poses(laps)
    return np.concatenate([poses[:at], poses[at + skip:]])
