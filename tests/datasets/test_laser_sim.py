"""The laser world simulator."""

import numpy as np

from jaxslam.datasets.carmen import CarmenLog, select_keyframes
from jaxslam.datasets.laser_sim import corridor_world, office_world, raycast, ring_path, simulate


def test_raycast_box_distances():
    walls = np.array([[0, 0, 4, 0], [4, 0, 4, 2], [4, 2, 0, 2], [0, 2, 0, 0]], float)
    origins = np.array([[1.0, 0.5]])
    headings = np.array([[0.0, np.pi / 2, np.pi, -np.pi / 2, np.arctan2(1.5, 3.0)]])
    d = raycast(walls, origins, headings, 30.0)[0]
    np.testing.assert_allclose(d, [3.0, 1.5, 1.0, 0.5, np.hypot(3.0, 1.5)], atol=1e-12)
    assert np.isinf(raycast(walls, origins, headings, 0.2)[0]).all()


def test_ring_path_stays_in_corridor():
    poses = ring_path(16.0, 10.0, 2.0, 0.1, laps=1.0)
    assert np.all(poses[:, 0] > 0.5) and np.all(poses[:, 0] < 15.5)
    assert np.all(poses[:, 1] > 0.5) and np.all(poses[:, 1] < 9.5)
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    np.testing.assert_allclose(steps, 0.1, atol=2e-3)
    # a closed loop: the last pose is one step before the first
    assert np.hypot(*(poses[-1, :2] - poses[0, :2])) < 0.11


def test_simulated_log_is_a_carmen_log():
    log = simulate(laps=0.3, num_beams=61, seed=1)
    assert isinstance(log, CarmenLog)
    s, b = log.ranges.shape
    assert b == 61 and log.ranges.dtype == np.float32
    assert log.angles.shape == (61,) and log.odom_poses.shape == (s, 3) and log.scan_times.shape == (s,)
    assert log.valid.shape == (s, b) and not np.any(log.valid & log.max_range_mask)
    np.testing.assert_allclose(log.angles[[0, -1]], [-np.pi / 2, np.pi / 2], atol=1e-6)
    assert log.true_poses.shape == (s, 3)
    np.testing.assert_allclose(log.odom_poses[0], log.true_poses[0])
    # ranges are the true distances plus small noise
    walls = office_world(seed=1)
    truth = raycast(walls, log.true_poses[:, :2], log.true_poses[:, 2:3] + log.angles[None].astype(float), 30.0)
    err = (log.ranges - truth)[log.valid]
    # (a float32 angle can put a beam that grazes a corner on the other surface)
    assert abs(np.median(err)) < 0.002 and 0.005 < np.median(np.abs(err)) * 1.4826 < 0.02
    assert np.mean(np.abs(err) < 0.05) > 0.98
    assert len(select_keyframes(log.odom_poses, 0.5, 0.3)) > 5


def test_odometry_drifts_and_is_seeded():
    a = simulate(laps=1.0, num_beams=31, seed=5)
    b = simulate(laps=1.0, num_beams=31, seed=5)
    np.testing.assert_array_equal(a.ranges, b.ranges)
    np.testing.assert_array_equal(a.odom_poses, b.odom_poses)
    drift = np.hypot(*(a.odom_poses[-1, :2] - a.true_poses[-1, :2]))
    assert drift > 0.3


def test_corridor_scans_repeat_with_the_doors_period():
    """A scan in the corridor of :func:`corridor_world` reads the same ranges one period
    further along (its ends out of range), and not half a period further: the doors
    and their closets break the corridor into equal periods."""
    walls = corridor_world(0.0, 30.0, 4.0, period=3.0)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 91)[None]
    origins = np.array([[10.2, 4.1], [13.2, 4.1], [11.7, 4.1]])
    ranges = raycast(walls, origins, np.zeros((3, 1)) + angles, 5.0)
    np.testing.assert_allclose(ranges[1], ranges[0], atol=1e-9)
    both = np.isfinite(ranges[2]) & np.isfinite(ranges[0])
    assert np.max(np.abs(ranges[2][both] - ranges[0][both])) > 0.5
    # the wall 1 m from the centre line between doors (at 1.05-1.95 m of each period),
    # the closet 1 m deep behind a door
    side = raycast(walls, np.array([[9.0, 4.1], [10.5, 4.1]]), np.full((2, 1), np.pi / 2), 5.0)[:, 0]
    np.testing.assert_allclose(side, [0.9, 1.9], atol=1e-9)
