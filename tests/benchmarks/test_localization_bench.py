"""benchmarks/localization.py: the kidnapped log keeps every odometry step but the one
across the cut, which shows no motion, and convergence is the first scan from which
the errors stay in bounds."""

import dataclasses

import numpy as np
import pytest

from jaxslam.datasets.geometry import se2_between, se2_compose

from . import load_benchmark

loc = load_benchmark("localization")


@dataclasses.dataclass
class _Log:
    """The per-scan arrays of a laser log that the cut touches."""

    odom_poses: np.ndarray
    scan_times: np.ndarray
    logger_times: np.ndarray
    ranges: np.ndarray
    valid: np.ndarray


def _log(n=30, seed=0):
    rng = np.random.default_rng(seed)
    odom = [np.array([1.0, 2.0, 0.3])]
    for _ in range(n - 1):
        odom.append(se2_compose(odom[-1], np.array([rng.uniform(0.1, 0.5), 0.0, rng.normal(0, 0.2)])))
    odom = np.stack(odom)
    stamps = 100.0 + 2.0 * np.arange(n)
    return _Log(odom_poses=odom, scan_times=stamps, logger_times=stamps + 0.5,
                ranges=np.arange(n * 4, dtype=np.float32).reshape(n, 4), valid=np.ones((n, 4), bool))


def test_kidnapped_log_jumps_in_its_scans_not_in_its_odometry():
    log = _log()
    reference = log.odom_poses + 5.0  # any poses, one per scan
    cut, resume = 9, 20
    cut_log, truth, times = loc.kidnapped(log, reference, log.scan_times, cut, resume)
    rows = np.r_[0:cut + 1, resume:30]
    np.testing.assert_array_equal(cut_log.ranges, log.ranges[rows])
    np.testing.assert_array_equal(truth, reference[rows])
    steps = se2_between(cut_log.odom_poses[:-1], cut_log.odom_poses[1:])
    original = se2_between(log.odom_poses[rows][:-1], log.odom_poses[rows][1:])
    np.testing.assert_allclose(steps[cut], 0.0, atol=1e-12)  # carried: the wheels do not turn
    np.testing.assert_allclose(np.delete(steps, cut, 0), np.delete(original, cut, 0), atol=1e-9)
    np.testing.assert_allclose(np.diff(cut_log.scan_times), 2.0)  # the second part follows the first
    np.testing.assert_allclose(np.diff(times), 2.0)
    np.testing.assert_allclose(cut_log.logger_times - cut_log.scan_times, 0.5)


def test_kidnap_points_are_far_enough_apart():
    poses = np.stack([np.linspace(0, 50, 400), np.zeros(400), np.zeros(400)], 1)
    for seed in range(5):
        cut, resume = loc.kidnap_points(poses, seed, 10.0)
        assert 100 <= cut < 200 <= resume < 300
        assert abs(poses[resume, 0] - poses[cut, 0]) >= 10.0


def test_converged_scan_is_where_the_error_stays_in_bounds():
    distance = np.array([5.0, 0.1, 0.2, 0.6, 0.1, 0.1, 0.1])
    heading = np.zeros(7)
    assert loc.converged_scan(distance, heading, hold=1) == 4
    assert loc.converged_scan(distance, heading, start=5, hold=1) == 5
    assert loc.converged_scan(distance, heading, hold=3) == 4
    assert loc.converged_scan(distance, heading, hold=4) is None  # only the last three scans
    heading[5] = np.radians(11)
    assert loc.converged_scan(distance, heading, hold=1) == 6
    assert loc.converged_scan(np.full(3, 1.0), np.zeros(3)) is None
    assert loc.converged_scan(np.r_[np.ones(5), np.zeros(10)], np.zeros(15)) == 5  # the default: 10 scans


def test_the_scan_rate_drawn_is_the_raw_logs(tmp_path):
    """A log of 30 scans 0.2 s apart (5.8 s) records 30 / 5.8 scans per second, however the
    corrected log made from it spaces its keyframes."""
    from tests.reliability.logs import carmen_text, room_scans

    path = tmp_path / "room.log"
    path.write_text(carmen_text(*room_scans(30)))
    assert loc.raw_scan_rates([path]) == {"room.log": pytest.approx(30 / 5.8)}
