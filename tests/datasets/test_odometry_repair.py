"""Odometry that loses the sign of reversing (jaxslam.datasets.odometry_repair): a
synthetic log whose poses drive forward while its velocities say backwards is
repaired to the true path; a log that reverses correctly, or carries no velocities,
is left alone; FR079's repair moves its odometry towards the GMapping-corrected log."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.datasets.carmen import load_carmen
from jaxslam.datasets.registry import load_dataset_log
from jaxslam.datasets.geometry import se2_between, se2_compose, se2_exp, se2_log
from jaxslam.datasets.odometry_repair import interval_speeds, repair_reverse_odometry, repair_stale_odometry
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


# --- stale odometry (repair_stale_odometry) -------------------------------------------


def _arc(n: int, step=(0.1, 0.0, 0.08), start=(1.0, -2.0, 0.3)):
    """Truth: ``n`` poses, a constant step per scan (an arc)."""
    poses = np.empty((n, 3))
    poses[0] = start
    for i in range(n - 1):
        poses[i + 1] = se2_compose(poses[i], np.asarray(step))
    return poses


def _stale(true: np.ndarray, first: int, count: int) -> np.ndarray:
    """The truth with scans ``first .. first+count-1`` repeating scan ``first-1``."""
    logged = true.copy()
    logged[first : first + count] = true[first - 1]
    return logged


def test_a_stale_stretch_is_spread_over_its_time():
    """Four scans repeat the pose before them, then the fifth carries their motion (MIT
    CSAIL's dropouts): the repair gives every scan of the stretch the steady motion
    back; the scans around it are not touched."""
    true = _arc(40)
    times = 5.0 + 0.2 * np.arange(40)
    logged = _stale(true, 20, 4)
    poses, report = repair_stale_odometry(logged, times)
    assert report == {"stale_stretches": 1, "repaired": 1, "repaired_scans": 4, "extended": 0, "scans": [20]}
    # Outside the stretch: the logged poses, to the bit.
    np.testing.assert_array_equal(np.delete(poses, np.s_[20:24], 0), np.delete(logged, np.s_[20:24], 0))
    # Inside: the steady arc's poses (the truth here, a constant step per scan).
    np.testing.assert_allclose(poses[20:24], true[20:24], atol=1e-12)
    steps = se2_between(poses[:-1], poses[1:])
    np.testing.assert_allclose(steps[18:25], np.tile([0.1, 0.0, 0.08], (7, 1)), atol=1e-12)
    # The logged increments, by contrast: four zero steps, then five steps in one.
    logged_steps = se2_between(logged[:-1], logged[1:])
    assert np.all(logged_steps[19:23] == 0) and logged_steps[23, 2] == pytest.approx(5 * 0.08)


def test_a_catch_up_over_two_readings_is_spread_too():
    """MIT CSAIL's second dropout: the first fresh reading brings part of the stretch's
    motion and the next the rest. Both join the catch-up; the steps after it are the
    logged ones."""
    true = _arc(40)
    logged = _stale(true, 20, 4)
    # The first fresh reading: most of the way, little of the turn (CSAIL: 0.95 m and
    # 8 deg, then 0.49 m and 29 deg).
    logged[24] = se2_compose(true[19], np.array([0.45, 0.05, 0.1]))
    poses, report = repair_stale_odometry(logged, 0.2 * np.arange(40))
    assert report["repaired"] == 1 and report["extended"] == 1 and report["repaired_scans"] == 5
    np.testing.assert_allclose(poses[20:25], true[20:25], atol=1e-12)
    np.testing.assert_array_equal(poses[25:], logged[25:])
    # Without the second reading's excess (a steady step after the first), no extension.
    logged[24] = true[24]
    _, report = repair_stale_odometry(logged, 0.2 * np.arange(40))
    assert report["extended"] == 0


def test_stale_stretch_spread_by_time_and_by_scan_when_stamps_run_backwards():
    true = _arc(30)
    times = np.cumsum(np.r_[0.0, np.full(29, 0.1)])
    times[11:14] += [0.02, 0.05, 0.07]  # uneven gaps inside the stretch (scans 10-13 stale, 14 new)
    poses, _ = repair_stale_odometry(_stale(true, 10, 4), times)
    # A steady arc over the stretch's time, a whole step per 0.1 s: f steps are
    # exp(f log(step)) (test_se2_exp_and_log_are_inverse_and_give_the_arc).
    fraction = (times[10:14] - times[9]) / 0.1
    expected = se2_compose(true[9], se2_exp(fraction[:, None] * se2_log(np.array([0.1, 0.0, 0.08]))[None]))
    np.testing.assert_allclose(poses[10:14], expected, atol=1e-12)
    backwards = times.copy()
    backwards[12] = backwards[9] - 0.5  # out of order: spread by scan count
    poses, report = repair_stale_odometry(_stale(true, 10, 4), backwards)
    assert report["repaired"] == 1
    np.testing.assert_allclose(poses[10:14], true[10:14], atol=1e-12)


@pytest.mark.parametrize(
    "case",
    ["stop", "small", "end", "none"],
)
def test_stops_small_catch_ups_and_stretches_at_the_end_are_left_alone(case):
    """A robot that really stands still and drives off (its first step no larger than
    the ones after), a catch-up within any matcher's reach, and a stretch with no new
    pose after it keep their logged poses: the very same array comes back."""
    n = 40
    if case == "stop":  # decelerate, stand 6 scans, accelerate
        speeds = np.r_[np.full(14, 0.3), 0.2, 0.1, np.zeros(6), 0.08, 0.15, 0.25, np.full(n - 26, 0.3)]
        steps = np.stack([speeds, np.zeros(n - 1), 0.5 * speeds], 1)
        logged = np.empty((n, 3))
        logged[0] = 0.0
        for i in range(n - 1):
            logged[i + 1] = logged[i] if speeds[i] == 0 else se2_compose(logged[i], steps[i])
        stretches = 1
    elif case == "small":  # 1 cm and 0.6 deg a scan: a catch-up of 5 cm and 3 deg is below the floor
        logged = _stale(_arc(n, step=(0.009, 0.0, 0.009)), 20, 4)
        stretches = 1
    elif case == "end":
        logged = _stale(_arc(n), n - 4, 4)
        stretches = 0
    else:
        logged = _arc(n)
        stretches = 0
    poses, report = repair_stale_odometry(logged, 0.2 * np.arange(n))
    assert poses is logged
    assert report["repaired"] == 0 and report["stale_stretches"] == stretches


def test_the_carmen_reader_repairs_stale_stretches(tmp_path):
    """Through ``load_carmen``: the counter, the report under ``odometry_repair["stale"]``,
    and ``repair_odometry=False`` for the poses as logged."""
    true = _arc(30)
    logged = _stale(true, 12, 3)
    path = _write_log(tmp_path / "stale.log", logged, None, with_odom=False)
    log = load_carmen(path)
    assert log.stats["odometry_stale_repaired"] == 3
    assert log.odometry_repair["stale"]["scans"] == [12]
    np.testing.assert_allclose(log.odom_poses[12:15], true[12:15], atol=2e-5)  # the file holds 6 decimals
    off = load_carmen(path, repair_odometry=False)
    np.testing.assert_allclose(off.odom_poses, logged, atol=1e-6)
    assert "odometry_stale_repaired" not in off.stats


def test_real_logs_stale_stretches():
    """MIT CSAIL's three dropouts are repaired; Intel, FR079 and MIT Killian repeat
    poses only while standing or creeping, and are left as logged."""
    try:
        csail = load_dataset_log("mit-csail")
    except DatasetNotFoundError:
        pytest.skip("carmen_raw not available")
    assert csail.odometry_repair["stale"]["scans"] == [321, 798, 1580]
    for name in ("intel", "fr079", "mit-killian"):
        log = load_dataset_log(name)
        assert log.odometry_repair["stale"]["stale_stretches"] > 0
        assert log.odometry_repair["stale"]["repaired"] == 0, name


def test_the_perturbed_logs_have_no_stale_stretch(tmp_path):
    """The suite's perturbed logs (seed 0 of each, both levels) give the repair nothing
    to do, so their runs are those from before it (seeds 0-19 high and 0-9 low were
    checked by hand against the log)."""
    from jaxslam.datasets.perturb import CORRECTED_LOGS, make_perturbed_log

    try:
        made = [make_perturbed_log(name, level, 0, tmp_path) for name in CORRECTED_LOGS for level in ("low", "high")]
    except DatasetNotFoundError:
        pytest.skip("carmen_gmapping_corrected not available")
    for item in made:
        stale = load_carmen(item.log_path).odometry_repair["stale"]
        assert stale["repaired"] == 0 and stale["stale_stretches"] == 0, item.log_path


def test_se2_exp_and_log_are_inverse_and_give_the_arc():
    """``se2_log`` inverts ``se2_exp`` (headings in [-pi, pi), through the series near 0),
    and ``exp(k * twist)`` is ``k`` steps of ``exp(twist)`` composed: a steady arc."""
    rng = np.random.default_rng(3)
    twists = np.concatenate([rng.normal(0, 1.0, (200, 3)), rng.normal(0, 1e-8, (20, 3))])
    twists[:, 2] = np.clip(twists[:, 2], -3.1, 3.1)
    np.testing.assert_allclose(se2_log(se2_exp(twists)), twists, atol=1e-9)
    poses = np.c_[rng.normal(0, 3, (50, 2)), rng.uniform(-np.pi, np.pi, 50)]
    np.testing.assert_allclose(se2_exp(se2_log(poses)), poses, atol=1e-9)
    for twist in twists[:20]:
        steps = [se2_exp(twist / 4.0)] * 4
        pose = np.zeros(3)
        for step in steps:
            pose = se2_compose(pose, step)
        np.testing.assert_allclose(pose, se2_exp(twist), atol=1e-9)
