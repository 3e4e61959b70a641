"""Tests of the CARMEN reader: every shipped log, malformed input, keyframes, fuzzing."""

from __future__ import annotations

import functools
import gzip
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxslam.datasets.carmen import guess_angular_resolution, load_carmen, select_keyframes
from jaxslam.datasets.registry import load_dataset_log
from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError, find
from jaxslam.datasets.registry import lookup


@functools.lru_cache(maxsize=None)
def _log(name: str, **options):
    try:
        return load_dataset_log(name, **options)
    except DatasetNotFoundError as error:
        pytest.skip(str(error))


def _data(*relative: str) -> Path:
    try:
        return find("carmen test data", *relative)
    except DatasetNotFoundError as error:
        pytest.skip(str(error))


# ---------------------------------------------------------------------------
# Every shipped log. Counts and spans from the datasets' READMEs; first/last scan
# stamps as printed in the files (ipc_timestamp).
# name: (message, scans, beams, ODOM lines, first stamp, last stamp, laser x offset)
SHIPPED = {
    "intel": ("FLASER", 13631, 180, 26915, 976052857.337530, 976055548.624744, 0.0),
    "fr079": ("FLASER", 4934, 360, 8951, 1211.520329, 2272.970282, -0.04),
    "mit-csail": ("FLASER", 1988, 361, 0, 1134864629.895182, 1134865053.892206, 0.0),
    "fr-clinic": ("ROBOTLASER1", 6917, 181, 0, 1232658478.161285, 1232663298.321285, 0.22),
    "mit-killian": ("FLASER", 17480, 180, 0, 1031745824.658, 1031753501.308, 0.0),
    "mrpt-sena": ("ROBOTLASER1", 224, 361, 224, 1137834225.973760, 1137834284.788331, 0.78),
    "mrpt-localization-demo": (
        "ROBOTLASER1", 37, 361, 37, 1137772793.094853, 1137772802.378201, 0.78
    ),
    "mrpt-ual": ("ROBOTLASER1", 3318, 361, 15351, 1400843350.071346, 1400843530.897346, 2.0),
}

# name: (scans, beams, ODOM lines, (first, last) stamp or None)
CORRECTED = {
    "acapulco": (861, 181, 12142, (19.0, 1382.9)),
    "belgioioso": (395, 361, 4442, None),
    "csail": (406, 361, 2394, None),
    "edmonton": (340, 180, 6351, (18.1, 726.1)),
    "fhw": (488, 180, 13935, (180.0, 2187.3)),
    "freiburg-079": (4791, 360, 9725, (0.23, 1061.5)),
    "freiburg-101": (292, 360, 4569, (158.4, 1077.4)),
    "freiburg-campus": (2008, 360, 17691, (0.0, 0.0)),
    "infinite-corridor": (1941, 180, 18191, None),
    "intel": (910, 180, 14541, (32.9, 2683.8)),
    "orebro": (237, 181, 255, (0.0, 0.0)),
    "seattle": (241, 361, 19311, (1244.2, 2409.5)),
}


def _check_invariants(log) -> None:
    num_scans, num_beams = log.ranges.shape
    assert log.ranges.dtype == np.float32 and log.angles.dtype == np.float32
    assert log.scan_times.dtype == np.float64 and log.scan_times.shape == (num_scans,)
    assert log.angles.shape == (num_beams,) and log.angle_offsets.shape == (num_scans,)
    assert log.odom_poses.shape == (num_scans, 3) and log.laser_poses.shape == (num_scans, 3)
    assert log.valid.shape == log.max_range_mask.shape == (num_scans, num_beams)
    assert not np.any(log.valid & log.max_range_mask)
    assert np.all(log.ranges[log.valid] > 0) and np.all(log.ranges[log.valid] < log.max_range)
    assert np.all(log.ranges[log.max_range_mask] >= log.max_range)
    assert log.stats.get("max_range_readings", 0) == int(log.max_range_mask.sum())
    assert np.all(np.isfinite(log.odom_poses)) and np.all(np.isfinite(log.scan_times))
    assert np.all(np.diff(log.scan_lines) > 0)
    assert log.stats.get("skipped_lines", 0) == 0 and log.problems == ()
    with pytest.raises(ValueError):
        log.ranges[0, 0] = 1.0  # arrays are read-only


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_log(name):
    message, scans, beams, odoms, first, last, offset_x = SHIPPED[name]
    log = _log(name)
    assert log.message == message
    assert log.ranges.shape == (scans, beams)
    assert log.odom_times.shape == (odoms,) and log.odom_readings.shape == (odoms, 3)
    assert log.scan_times[0] == first and log.scan_times[-1] == last
    np.testing.assert_allclose(log.laser_offset, [offset_x, 0.0, 0.0], atol=1e-6)
    assert log.stats.get("laser_offset_mismatch_scans", 0) == 0
    _check_invariants(log)


@pytest.mark.parametrize("place", sorted(CORRECTED))
def test_corrected_log(place):
    scans, beams, odoms, span = CORRECTED[place]
    log = _log(f"{place}-corrected")
    assert log.message == "FLASER"
    assert log.ranges.shape == (scans, beams)
    assert log.odom_times.shape == (odoms,)
    assert log.stats["unknown:NEFF"] == scans
    # Both pose triples hold the corrected laser pose.
    np.testing.assert_array_equal(log.odom_poses, log.laser_poses)
    if span is not None:
        np.testing.assert_allclose([log.scan_times[0], log.scan_times[-1]], span, atol=0.06)
    _check_invariants(log)


def test_mrpt_logs_load_by_path():
    for name in ("mrpt-sena", "mrpt-localization-demo", "mrpt-ual"):
        log = load_dataset_log(_data(*lookup(name).files[0]))
        assert log.num_scans == SHIPPED[name][1]


def test_odometry_path_lengths_match_readmes():
    expected = {"intel": 508, "fr079": 392, "fr-clinic": 1402, "mit-killian": 1911,
                "mrpt-sena": 76.4, "mrpt-ual": 524}
    for name, length in expected.items():
        poses = _log(name).odom_poses
        travelled = np.hypot(*np.diff(poses[:, :2], axis=0).T).sum()
        assert travelled == pytest.approx(length, rel=2e-3), name


def test_intel_backwards_stamps_are_kept_and_counted():
    log = _log("intel")
    assert log.stats["backwards_timestamps"] == 631  # README: 631 out of ipc order
    assert int((np.diff(log.scan_times) < 0).sum()) == 631
    with pytest.raises(DataFormatError, match="max_backstep"):
        load_carmen(log.path, max_backstep=0.5)
    assert log.stats["max_range_readings"] == 68313  # the 81.83 m "no return" code


def test_fr079_laser_pose_is_odom_composed_with_offset():
    # As logged: the reversing repair (tests/datasets/test_odometry_repair.py) changes
    # odom_poses only.
    log = _log("fr079", repair_odometry=False)
    assert log.params["robot_frontlaser_offset"] == "-0.04"
    assert log.max_range == pytest.approx(80.99)  # PARAM robot_front_laser_max
    heading = log.odom_poses[:, 2]
    expected = log.odom_poses[:, :2] - 0.04 * np.stack([np.cos(heading), np.sin(heading)], 1)
    np.testing.assert_allclose(log.laser_poses[:, :2], expected, atol=2e-6)


def test_corrected_log_by_path_reports_offset_mismatch():
    log = load_carmen(_data("carmen_gmapping_corrected", "freiburg-079-corrected.log.gz"))
    np.testing.assert_allclose(log.laser_offset, [-0.04, 0.0, 0.0])
    assert log.stats["laser_offset_mismatch_scans"] == 4791


@pytest.mark.parametrize(
    "name, first_deg, last_deg",
    [("intel", -90.0, 89.0), ("fr079", -90.0, 89.5), ("mit-csail", -90.0, 90.0),
     ("mrpt-sena", -90.0, 90.0)],
)
def test_beam_angles(name, first_deg, last_deg):
    log = _log(name)
    np.testing.assert_allclose(np.degrees(log.angles[[0, -1]]), [first_deg, last_deg], atol=1e-4)
    np.testing.assert_allclose(np.diff(log.angles), log.angular_resolution, atol=1e-6)
    assert np.all(log.angle_offsets == 0)


def test_fr_clinic_interleaved_start_angles():
    log = _log("fr-clinic")
    offsets_deg = np.unique(np.round(np.degrees(log.angle_offsets), 3))
    np.testing.assert_allclose(offsets_deg, [0.0, 0.25, 0.5, 0.75], atol=1e-3)
    short = log.angle_offsets > 0  # the 180-beam scans
    assert not log.valid[short, -1].any() and np.isnan(log.ranges[short, -1]).all()
    assert log.stats["padded_beams"] == int(short.sum())
    np.testing.assert_allclose(
        log.beam_angles()[short, 0], log.angles[0] + log.angle_offsets[short]
    )
    with pytest.raises(DataFormatError, match="mixed_geometry='pad'") as error:
        load_carmen(log.path)
    assert error.value.line == 2


def test_guess_angular_resolution():
    assert guess_angular_resolution(180) == pytest.approx(math.radians(1.0))
    assert guess_angular_resolution(361) == pytest.approx(math.radians(0.5))
    assert guess_angular_resolution(91) == pytest.approx(math.pi / 90)
    assert guess_angular_resolution(100) == pytest.approx(math.pi / 100)


def test_load_dataset_log_names():
    with pytest.raises(FileNotFoundError, match="intel"):
        load_dataset_log("no-such-log")
    log = _log("intel-corrected")
    assert log.max_range == pytest.approx(80.0)
    custom = load_dataset_log("orebro-corrected", max_range=10.0)
    assert custom.max_range == 10.0


# ---------------------------------------------------------------------------
# Small synthetic logs.


def _flaser(ranges, t, pose=(0.0, 0.0, 0.0), count=None, logger=None) -> str:
    count = len(ranges) if count is None else count
    pose_text = " ".join(f"{v}" for v in pose)
    body = " ".join(str(r) for r in ranges)
    logger = t if logger is None else logger
    return f"FLASER {count} {body} {pose_text} {pose_text} {t} host {logger}"


def _robotlaser(ranges, t, start=-1.5707963, res=0.7853982, max_range=20.0, laser=(0.5, 0, 0)):
    body = " ".join(str(r) for r in ranges)
    return (f"ROBOTLASER1 0 {start} 3.1415927 {res} {max_range} 0.01 0 {len(ranges)} {body} 0 "
            f"{laser[0]} {laser[1]} {laser[2]} 0 0 0 0 0 0 0 0 {t} host {t}")


def _write(tmp_path: Path, lines, name="log.clf", compress=False) -> Path:
    path = tmp_path / name
    data = ("\n".join(lines) + "\n").encode()
    path.write_bytes(gzip.compress(data) if compress else data)
    return path


GOOD = [
    "# a comment",
    "PARAM robot_frontlaser_offset 0.1 nohost 0",
    _flaser([1.0, 2.0, 3.0, 4.0], 10.0),
    "ODOM 0 0 0 0 0 0 10.05 host 10.05",
    _flaser([1.5, 2.5, 3.5, 4.5], 10.2, pose=(0.1, 0.0, 0.0)),
]


def test_minimal_log_plain_and_gzip(tmp_path):
    for compress in (False, True):
        log = load_carmen(_write(tmp_path, GOOD, f"g{compress}.clf", compress))
        assert log.ranges.shape == (2, 4)
        np.testing.assert_array_equal(log.scan_lines, [3, 5])
        np.testing.assert_allclose(log.laser_offset, [0.1, 0, 0])
        np.testing.assert_allclose(np.degrees(log.angles), [-90, -45, 0, 45], atol=1e-5)
        assert log.max_range == 80.0 and log.valid.all()


def test_crlf_line_endings(tmp_path):
    path = tmp_path / "crlf.clf"
    path.write_bytes(("\r\n".join(GOOD) + "\r\n").encode())
    assert load_carmen(path).num_scans == 2


@pytest.mark.parametrize(
    "bad_line, problem",
    [
        (_flaser([1.0, 2.0, 3.0], 10.1, count=4), "FLASER says 4 beams"),
        (_flaser([1.0, 2.0, 3.0, 4.0, 5.0], 10.1, count=4), "FLASER says 4 beams"),
        (_flaser([1.0, "abc", 3.0, 4.0], 10.1), "not a number"),
        (_flaser([1.0, 2.0, 3.0, 4.0], 10.1, count="4.5"), "not an integer"),
        (_flaser([1.0, 2.0, 3.0, 4.0], 10.1, count=0), "must be positive"),
        (_flaser([1.0, 2.0, 3.0, 4.0], 10.1, pose=("nan", 0, 0)), "not finite"),
        (_flaser([1.0, 2.0, 3.0, 4.0], "x10.1"), "ipc_timestamp is not a number"),
        (_flaser([1.0, 2.0, 3.0, 4.0], 10.1)[:40], "FLASER says 4 beams"),
        ("FLASER", "ends before its beam count"),
        ("ODOM 0 0 0 0 0 0 10.1 host", "ODOM needs 10 fields"),
        ("ODOM 0 zero 0 0 0 0 10.1 host 10.1", "not a number"),
        ("PARAM robot_front_laser_max lots nohost 0", "robot_front_laser_max"),
        (_flaser([1.0, 2.0, 3.0, 4.0], 4.0), "goes back"),
    ],
)
def test_malformed_line_names_file_and_line(tmp_path, bad_line, problem):
    lines = GOOD[:3] + [bad_line] + GOOD[3:]
    path = _write(tmp_path, lines)
    with pytest.raises(DataFormatError, match=problem) as error:
        load_carmen(path)
    assert error.value.line == 4
    assert error.value.path == str(path)
    assert f"{path}, line 4" in str(error.value)


def test_malformed_robotlaser1(tmp_path):
    good = _robotlaser([1.0, 2.0, 3.0, 4.0, 5.0], 1.0)
    parts = good.split()
    parts[8] = "6"  # says 6 beams, has 5
    for bad in (" ".join(parts), good.replace(" 0.7853982 ", " -1 "), good[:60]):
        with pytest.raises(DataFormatError) as error:
            load_carmen(_write(tmp_path, [good, bad]))
        assert error.value.line == 2
    log = load_carmen(_write(tmp_path, [good, _robotlaser([1, 2, 30, 4, 5], 1.1)]))
    np.testing.assert_allclose(log.laser_offset, [0.5, 0, 0])
    assert log.max_range == 20.0 and log.max_range_mask[1, 2] and not log.valid[1, 2]


def test_skip_policy_counts_every_bad_line(tmp_path):
    lines = GOOD[:3] + [
        _flaser([1.0, 2.0], 10.1, count=4),
        "ODOM 0 0 0 0 0 0 10.1 host",
        _flaser([1.0, "x", 3.0, 4.0], 10.15),
        _flaser([1.0, 2.0, 3.0, 4.0], 1.0),
        "NEFF 12",
        "TRUEPOS 0 0 0 0 0 0 10 host 10",
    ] + GOOD[3:]
    log = load_carmen(_write(tmp_path, lines), on_error="skip")
    assert log.num_scans == 2
    assert log.stats["skipped_lines"] == 4
    assert log.stats["skipped:field_count"] == 2
    assert log.stats["skipped:non_numeric"] == 1
    assert log.stats["skipped:backwards_timestamp"] == 1
    assert log.stats["unknown_messages"] == 2 and log.stats["unknown:NEFF"] == 1
    assert len(log.problems) == 4 and "line 4" in log.problems[0]
    with pytest.raises(DataFormatError) as error:
        load_carmen(_write(tmp_path, lines))
    assert error.value.line == 4


def test_small_backstep_is_counted(tmp_path):
    lines = GOOD[:3] + [_flaser([1.0, 2.0, 3.0, 4.0], 9.5)] + GOOD[3:]
    log = load_carmen(_write(tmp_path, lines))
    assert log.stats["backwards_timestamps"] == 1
    np.testing.assert_array_equal(log.scan_times, [10.0, 9.5, 10.2])  # file order kept


def test_differing_beam_counts(tmp_path):
    lines = GOOD + [_flaser([1.0, 2.0, 3.0], 10.4)]
    with pytest.raises(DataFormatError, match="3 beams here, but 4 beams on line 3") as error:
        load_carmen(_write(tmp_path, lines))
    assert error.value.line == 6
    # 3 and 4 FLASER beams imply 90 and 45 deg steps: no common grid to pad to ...
    with pytest.raises(DataFormatError, match="different angular resolutions"):
        load_carmen(_write(tmp_path, lines), mixed_geometry="pad")
    # ... unless the log states its resolution.
    lines = ["PARAM laser_front_laser_resolution 45 nohost 0"] + lines
    log = load_carmen(_write(tmp_path, lines), mixed_geometry="pad")
    assert log.ranges.shape == (3, 4) and not log.valid[2, 3]
    assert np.isnan(log.ranges[2, 3]) and log.stats["padded_beams"] == 1


def test_empty_logs(tmp_path):
    for lines in ([], ["# only a comment", ""], ["ODOM 0 0 0 0 0 0 1 host 1"]):
        for compress in (False, True):
            with pytest.raises(DataFormatError, match="no laser scans") as error:
                load_carmen(_write(tmp_path, lines, compress=compress))
            assert error.value.line is None
    with pytest.raises(DataFormatError, match="2 bad lines were skipped"):
        load_carmen(_write(tmp_path, ["FLASER 3 1", "FLASER x"]), on_error="skip")


def test_truncated_and_corrupt_gzip(tmp_path):
    data = gzip.compress(("\n".join(GOOD * 200) + "\n").encode())
    truncated = tmp_path / "truncated.clf.gz"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFormatError, match="truncated or corrupt"):
        load_carmen(truncated)
    corrupt = bytearray(data)
    for index in range(40, len(corrupt) - 20, 97):
        corrupt[index] ^= 0x5A
    (tmp_path / "corrupt.clf.gz").write_bytes(bytes(corrupt))
    with pytest.raises(DataFormatError):
        load_carmen(tmp_path / "corrupt.clf.gz")


def test_real_truncated_gzip(tmp_path):
    data = _data("carmen_raw", "mit-csail.clf.gz").read_bytes()
    path = tmp_path / "mit-csail-cut.clf.gz"
    path.write_bytes(data[:200_000])
    with pytest.raises(DataFormatError, match="truncated") as error:
        load_carmen(path)
    assert error.value.line > 1


def test_range_policy(tmp_path):
    lines = [
        "PARAM robot_front_laser_max 5.0 nohost 0",
        _flaser([1.0, "nan", "inf", -1.0, 0.0, 5.0, 7.5, 4.99], 1.0),
    ]
    log = load_carmen(_write(tmp_path, lines))
    assert log.max_range == 5.0
    np.testing.assert_array_equal(log.valid[0], [1, 0, 0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(log.max_range_mask[0], [0, 0, 0, 0, 0, 1, 1, 0])
    assert log.stats["nonfinite_readings"] == 2
    assert log.stats["nonpositive_readings"] == 2
    assert log.stats["max_range_readings"] == 2
    assert load_carmen(log.path, max_range=8.0).max_range_mask.sum() == 0


def test_argument_checks(tmp_path):
    path = _write(tmp_path, GOOD)
    with pytest.raises(ValueError):
        load_carmen(path, on_error="ignore")
    with pytest.raises(ValueError):
        load_carmen(path, mixed_geometry="crop")
    with pytest.raises(FileNotFoundError):
        load_carmen(tmp_path / "missing.clf")


def test_other_scan_type_is_counted(tmp_path):
    lines = GOOD + [_robotlaser([1.0, 2.0], 11.0)]
    log = load_carmen(_write(tmp_path, lines))
    assert log.message == "FLASER" and log.stats["other_scan_messages"] == 1
    assert load_carmen(log.path, message="ROBOTLASER1").num_scans == 1


# ---------------------------------------------------------------------------
# Keyframes.


def _straight_path(step: float, count: int) -> np.ndarray:
    return np.stack([step * np.arange(count), np.zeros(count), np.zeros(count)], axis=1)


def test_keyframes_linear():
    # 0.25 m steps are exact in binary: the 4th step reaches 1.0 (GMapping's >=).
    np.testing.assert_array_equal(select_keyframes(_straight_path(0.25, 13)), [0, 4, 8, 12])
    np.testing.assert_array_equal(select_keyframes(_straight_path(0.3, 13)), [0, 4, 8, 12])
    np.testing.assert_array_equal(select_keyframes(_straight_path(0.5, 5), linear=2.0), [0, 4])


def test_keyframes_angular_and_accumulated_path():
    turning = np.zeros((10, 3))
    turning[:, 2] = 0.2 * np.arange(10)
    np.testing.assert_array_equal(select_keyframes(turning, angular=0.5), [0, 3, 6, 9])
    # Back and forth: the path length accumulates although the net motion is zero.
    shuttle = np.zeros((9, 3))
    shuttle[1::2, 0] = 0.4
    np.testing.assert_array_equal(select_keyframes(shuttle, linear=1.0), [0, 3, 6])
    # Heading wraps: a step from 3.1 to -3.1 rad turns 0.083 rad, not 6.2.
    wrap = np.array([[0, 0, 3.1], [0, 0, -3.1], [0, 0, -3.0]])
    np.testing.assert_array_equal(select_keyframes(wrap, angular=0.5), [0])


def test_keyframes_in_robot_frame_and_temporal():
    # Sideways motion in a rotated frame counts its length.
    path = np.zeros((5, 3))
    path[:, 1] = 0.6 * np.arange(5)
    path[:, 2] = math.pi / 2
    np.testing.assert_array_equal(select_keyframes(path), [0, 2, 4])
    still = np.zeros((6, 3))
    times = np.array([0.0, 1.0, 2.0, 3.5, 4.0, 6.0])
    # GMapping's temporalUpdate fires when strictly more than `temporal` s passed.
    np.testing.assert_array_equal(
        select_keyframes(still, temporal=1.5, times=times), [0, 2, 4, 5]
    )
    np.testing.assert_array_equal(select_keyframes(still), [0])
    with pytest.raises(ValueError):
        select_keyframes(still, temporal=1.0)
    assert select_keyframes(np.zeros((0, 3))).shape == (0,)


def test_keyframes_on_intel():
    # Between keyframes the accumulated motion stays below both thresholds until
    # the keyframe's own step, which reaches one of them.
    poses = _log("intel").odom_poses
    keyframes = select_keyframes(poses, linear=1.0, angular=0.5)
    assert keyframes[0] == 0 and np.all(np.diff(keyframes) > 0)
    delta = poses[1:] - poses[:-1]
    step_linear = np.hypot(delta[:, 0], delta[:, 1])  # translation length is frame-free
    step_angular = np.abs((delta[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    bounds = list(keyframes) + [len(poses)]
    for start, stop in zip(bounds[:-1], bounds[1:]):
        # Accumulated motion at poses start+1 .. stop (the next keyframe, if any).
        linear = np.cumsum(step_linear[start:stop])
        angular = np.cumsum(step_angular[start:stop])
        if stop < len(poses):
            assert linear[-1] >= 1.0 or angular[-1] >= 0.5
            linear, angular = linear[:-1], angular[:-1]
        assert np.all(linear < 1.0) and np.all(angular < 0.5)


# ---------------------------------------------------------------------------
# Fuzzing: random corruptions of real lines raise DataFormatError or nothing.


@functools.lru_cache(maxsize=None)
def _real_lines() -> tuple[bytes, ...]:
    path = _data("carmen_raw", "fr079.clf.gz")
    with gzip.open(path, "rb") as stream:
        head = [next(stream) for _ in range(400)]
    def first(prefix: bytes, count: int) -> list[bytes]:
        return [line for line in head if line.startswith(prefix)][:count]

    keep = (first(b"#", 1) + first(b"PARAM robot_front", 3) + first(b"PARAM laser_front", 1)
            + first(b"ODOM", 2) + first(b"FLASER", 4))
    clinic = _data("carmen_raw", "fr-clinic_robotlaser.clf.gz")
    with gzip.open(clinic, "rb") as stream:
        robot = [next(stream) for _ in range(3)]
    return tuple(keep), tuple(robot)


_TOKENS = st.sampled_from(
    [b"", b"nan", b"-inf", b"1e999", b"-1", b"0", b"abc", b"99999999999999999999", b"#",
     b"FLASER", b"ODOM", b"PARAM", b"ROBOTLASER1", b"\xff\xfe", b"\x00", b"1_0", b"0x1"]
)


@st.composite
def _corrupted_log(draw):
    flaser_lines, robot_lines = _real_lines()
    lines = list(draw(st.sampled_from([flaser_lines, robot_lines])))
    for _ in range(draw(st.integers(1, 4))):
        index = draw(st.integers(0, len(lines) - 1))
        parts = lines[index].rstrip(b"\n").split(b" ")
        kind = draw(st.sampled_from(["token", "delete", "insert", "cut", "bytes", "swap", "dup"]))
        position = draw(st.integers(0, max(len(parts) - 1, 0)))
        if kind == "token":
            parts[position] = draw(_TOKENS)
        elif kind == "delete" and len(parts) > 1:
            del parts[position]
        elif kind == "insert":
            parts.insert(position, draw(_TOKENS))
        elif kind == "cut":
            joined = b" ".join(parts)
            parts = [joined[: draw(st.integers(0, len(joined)))]]
        elif kind == "bytes":
            parts[position] = draw(st.binary(max_size=12))
        elif kind == "swap":
            other = draw(st.integers(0, len(lines) - 1))
            lines[index], lines[other] = lines[other], lines[index]
            continue
        elif kind == "dup":
            lines.insert(index, lines[index])
            continue
        lines[index] = b" ".join(parts) + b"\n"
    compress = draw(st.booleans())
    return b"".join(lines), compress


@settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(_corrupted_log(), st.sampled_from(["raise", "skip"]), st.sampled_from(["raise", "pad"]))
def test_fuzz_corrupted_real_lines(case, on_error, mixed_geometry):
    data, compress = case
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.clf"
        path.write_bytes(gzip.compress(data) if compress else data)
        try:
            log = load_carmen(path, on_error=on_error, mixed_geometry=mixed_geometry)
        except DataFormatError as error:
            assert str(path) in str(error)
            return
        assert log.num_scans >= 1
        assert not np.any(log.valid & log.max_range_mask)
        if on_error == "skip":
            assert log.stats.get("skipped_lines", 0) == len(log.problems)
