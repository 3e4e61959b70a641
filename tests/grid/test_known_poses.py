"""Occupancy mapping with known poses: hits and crossings of single beams."""

from __future__ import annotations

import numpy as np

from jaxslam.grid.known_poses import known_pose_log_odds, known_pose_map


def test_one_beam_marks_its_end_cell_and_clears_the_ray_before_it():
    ranges = np.array([[1.0, 30.0]])
    valid = np.array([[True, False]])
    angles = np.array([0.0, np.pi / 2])
    pose = np.array([[0.02, 0.02, 0.0]])
    log_odds, origin = known_pose_log_odds(ranges, valid, angles, pose, resolution=0.1, max_range=30.0,
                                           free_range=2.0, l_occ=0.85, l_free=0.4, margin=0.5)
    col = lambda x: int(np.floor((x - origin[0]) / 0.1 + 1e-9))  # noqa: E731
    row = lambda y: int(np.floor((y - origin[1]) / 0.1 + 1e-9))  # noqa: E731
    r0 = row(0.02)
    assert log_odds[r0, col(1.02)] == np.float32(0.85)  # the hit, once
    ray = log_odds[r0, col(0.12):col(0.82)]  # the ray before it is cleared (a cell may be skipped)
    assert np.all(ray <= 0) and np.sum(ray < 0) >= ray.size - 1
    assert log_odds[r0, col(0.97)] == 0.0  # the last cell length before the hit is not
    # the "no return" beam (up, at the range limit) clears up to 2 m and marks nothing
    up = log_odds[row(0.12):row(1.82), col(0.02)]
    assert np.all(up <= 0) and np.sum(up < 0) >= up.size - 2
    assert log_odds.max() == np.float32(0.85) and np.sum(log_odds > 0) == 1
    free_below = np.log(0.196 / 0.804)  # map_server's free_thresh as log-odds
    for scans in (1, 4):
        grid = known_pose_map(scans * log_odds, origin, 0.1)
        assert grid.occupied.sum() == 1 and grid.free.sum() == np.sum(scans * log_odds < free_below)
    assert known_pose_map(4 * log_odds, origin, 0.1).free.sum() >= 20  # about 0.9 m + 1.9 m of rays
