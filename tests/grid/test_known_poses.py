"""Occupancy mapping with known poses: hits and crossings of single beams."""

from __future__ import annotations

import numpy as np

from jaxslam.grid.known_poses import known_pose_log_odds, known_pose_map


def test_one_beam_marks_its_end_cell_and_clears_the_cells_before_it():
    ranges = np.array([[1.0, 30.0]])
    valid = np.array([[True, False]])
    angles = np.array([0.0, np.pi / 2])
    pose = np.array([[0.02, 0.02, 0.0]])
    log_odds, origin = known_pose_log_odds(ranges, valid, angles, pose, resolution=0.1, max_range=30.0,
                                           free_range=2.0, l_occ=0.85, l_free=0.4, margin=0.5)
    col = lambda x: int(np.floor((x - origin[0]) / 0.1))  # noqa: E731
    row = lambda y: int(np.floor((y - origin[1]) / 0.1))  # noqa: E731
    r0 = row(0.02)
    assert log_odds[r0, col(1.02)] == np.float32(0.85)  # the hit
    assert log_odds[r0, col(0.02)] == np.float32(-0.8)  # the robot's cell: both beams
    np.testing.assert_array_equal(log_odds[r0, col(0.02) + 1:col(1.02)], np.float32(-0.4))  # once each
    # the "no return" beam (up, the range limit) clears 2 m and marks nothing
    up = log_odds[row(0.1):row(1.9), col(0.02)]
    assert np.all(up < 0) and log_odds.max() == np.float32(0.85)
    once = known_pose_map(log_odds, origin, 0.1)  # one pass: p(free cells) = 0.40, unknown
    assert once.occupied.sum() == 1 and once.free.sum() == 0
    four = known_pose_map(4 * log_odds, origin, 0.1)  # as four such scans: -1.6 < logit(0.196)
    assert four.occupied.sum() == 1 and four.free.sum() == np.sum(log_odds < 0)
