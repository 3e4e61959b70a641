"""Odometry that loses the sign of reversing (jaxslam.datasets.odometry_repair): a
synthetic log whose poses drive forward while its velocities say backwards is
repaired to the true path; a log that reverses correctly, or carries no velocities,
is left alone; FR079's repair moves its odometry towards the GMapping-corrected log."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.datasets.carmen import load_carmen, load_dataset_log
from jaxslam.datasets.geometry import se2_between, se2_compose
from jaxslam.datasets.odometry_repair import interval_speeds, repair_reverse_odometry
from jaxslam.datasets.paths import DatasetNotFoundError


def _path(reverse_from: int, reverse_to: int, n: int = 60):
    """Truth: forward 0.1 m per scan with a gentle turn, backwards (same turn rate)
    for scans [reverse_from, reverse_to). Returns true poses, speed-only poses (the
    sign of every backwards step lost) and the signed speeds per scan interval."""
    speed = np.where((np.arange(n - 1) >= reverse_from) & (np.arange(n - 1) < reverse_to), -1.0, 1.0)
    true = np.zeros((n, 3))
    lost = np.zeros((n, 3))
    for i in range(n - 1):
        step = np.array([0.1 * speed[i], 0.0, 0.02])
        true[i + 1] = se2_compose(true[i], step)
        lost[i + 1] = se2_compose(lost[i], np.abs(step) * [1, 1, 0] + [0, 0, 0.02])
    return true, lost, 0.5 * speed


def _write_log(path, poses, speeds, with_odom=True):
    """A FLASER log (one scan per pose, 0.2 s apart) with one ODOM line per interval
    carrying the interval's signed speed."""
    lines = []
    for i, pose in enumerate(poses):
        t = 100.0 + 0.2 * i
        if with_odom and i > 0:
            lines.append(f"ODOM {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f} {speeds[i - 1]:.3f} 0.1 0 {t - 0.1:.6f} h {t - 0.1:.6f}")
        ranges = " ".join(["2.0"] * 8)
        p = f"{pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f}"
        lines.append(f"FLASER 8 {ranges} {p} {p} {t:.6f} h {t:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_lost_reversing_is_detected_and_repaired(tmp_path):
    true, lost, speeds = _path(20, 35)
    log = load_carmen(_write_log(tmp_path / "lost.log", lost, speeds))
    assert log.odometry_repair["repaired"] and log.odometry_repair["sign_lost"] == 15
    assert log.stats["odometry_sign_repaired"] == 15
    assert log.odometry_repair["scans"][0] == 21
    np.testing.assert_allclose(log.odom_poses, true, atol=2e-5)  # the file holds 6 decimals
    # The logged ODOM poses stay as logged; repair off gives the logged scan poses.
    np.testing.assert_allclose(log.odom_readings, lost[1:], atol=1e-6)
    off = load_carmen(tmp_path / "lost.log", repair_odometry=False)
    assert not off.odometry_repair["repaired"]
    np.testing.assert_allclose(off.odom_poses, lost, atol=1e-6)


def test_correct_reversing_and_missing_velocities_are_left_alone(tmp_path):
    true, _, speeds = _path(20, 35)
    log = load_carmen(_write_log(tmp_path / "signed.log", true, speeds))
    assert log.odometry_repair["checked"] and not log.odometry_repair["repaired"]
    assert log.odometry_repair["sign_kept"] == 15 and log.odometry_repair["sign_lost"] == 0
    np.testing.assert_allclose(log.odom_poses, true, atol=1e-6)
    plain = load_carmen(_write_log(tmp_path / "plain.log", true, speeds, with_odom=False))
    assert not plain.odometry_repair["checked"] and "odometry_sign_repaired" not in plain.stats


def test_a_few_lost_steps_among_many_signed_ones_are_not_repaired():
    """Below MIN_FRACTION of the reversing steps: noise, not a sign-less log."""
    true, _, speeds = _path(5, 55)
    poses = true.copy()
    increments = se2_between(true[:-1], true[1:])
    increments[10:20, :2] *= -1  # 10 of 50 reversing steps "lost"
    for i, u in enumerate(increments):
        poses[i + 1] = se2_compose(poses[i], u)
    times = 100.0 + 0.2 * np.arange(true.shape[0])
    out, report = repair_reverse_odometry(poses, times, times[1:] - 0.1, speeds)
    assert report["sign_lost"] == 10 and report["sign_kept"] == 40 and not report["repaired"]
    assert out is poses


def test_interval_speeds_average_the_messages_of_each_interval():
    speeds = interval_speeds(np.array([0.0, 1.0, 2.0, 3.0]), np.array([0.5, 0.7, 2.5, 1.0]),
                             np.array([1.0, 3.0, -4.0, 5.0]))
    # (0, 1]: 1, 3, 5 -> 3 (unsorted stamps are sorted first); (1, 2]: none; (2, 3]: -4
    np.testing.assert_allclose(speeds, [3.0, np.nan, -4.0])


def test_fr079_repair_moves_the_odometry_towards_the_corrected_log():
    """FR079 backs up at 202 scan increments, and its poses drive forward at every one
    of them; repaired, far fewer odometry increments are off the corrected log's by
    more than 0.1 m."""
    try:
        raw = load_dataset_log("fr079")
        reference = load_dataset_log("fr079-corrected")
    except (DatasetNotFoundError, KeyError) as error:
        pytest.skip(str(error))
    assert raw.odometry_repair["repaired"] and raw.odometry_repair["sign_lost"] == 202
    assert raw.odometry_repair["sign_kept"] == 0
    logged = load_carmen(raw.path, repair_odometry=False)
    keys = {np.round(raw.ranges[i], 2).tobytes(): i for i in range(raw.num_scans)}
    index = np.array([keys.get(np.round(reference.ranges[i], 2).tobytes(), -1) for i in range(reference.num_scans)])
    both = (index[:-1] >= 0) & (index[1:] >= 0)
    want = se2_between(reference.odom_poses[:-1], reference.odom_poses[1:])[both]

    def off(log):
        got = se2_between(log.odom_poses[index[:-1][both]], log.odom_poses[index[1:][both]])
        return int(np.sum(np.hypot(*(got[:, :2] - want[:, :2]).T) > 0.1))

    assert off(raw) < 0.5 * off(logged), (off(raw), off(logged))
