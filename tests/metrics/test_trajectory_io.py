"""Tests of SE(2) helpers, TUM files and per-scan pose interpolation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jaxslam.datasets.paths import DataFormatError
from jaxslam.metrics.trajectory_io import (
    interpolate_poses,
    read_tum,
    se2_between,
    se2_compose,
    se2_inverse,
    wrap_angle,
    write_tum,
)


def _matrix(pose) -> np.ndarray:
    """Homogeneous 3x3 matrix of an SE(2) pose: the independent reference."""
    x, y, theta = pose
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def _pose(matrix) -> np.ndarray:
    return np.array([matrix[0, 2], matrix[1, 2], math.atan2(matrix[1, 0], matrix[0, 0])])


def _close_poses(actual, expected, atol=1e-9):
    actual, expected = np.asarray(actual), np.asarray(expected)
    np.testing.assert_allclose(actual[..., :2], expected[..., :2], atol=atol)
    np.testing.assert_allclose(wrap_angle(actual[..., 2] - expected[..., 2]), 0.0, atol=atol)


_poses = hnp.arrays(
    np.float64,
    (3,),
    elements=st.floats(-50, 50, allow_nan=False, allow_infinity=False),
)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(_poses, _poses)
def test_se2_against_matrices(a, b):
    _close_poses(se2_compose(a, b), _pose(_matrix(a) @ _matrix(b)))
    _close_poses(se2_inverse(a), _pose(np.linalg.inv(_matrix(a))))
    _close_poses(se2_between(a, b), _pose(np.linalg.inv(_matrix(a)) @ _matrix(b)))
    _close_poses(se2_between(a, se2_compose(a, b)), b)
    _close_poses(se2_compose(a, se2_inverse(a)), np.zeros(3))


def test_se2_batches_and_wrap():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    batched = se2_compose(a, b)
    for row in range(7):
        _close_poses(batched[row], se2_compose(a[row], b[row]))
    wrapped = wrap_angle(np.array([math.pi, -math.pi, 3 * math.pi, 0.5]))
    assert np.all(wrapped >= -math.pi) and np.all(wrapped < math.pi)


def test_tum_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    stamps = 976052857.33753 + np.cumsum(rng.uniform(0.01, 0.3, size=50))
    stamps[10], stamps[11] = stamps[11], stamps[10]  # order is kept, not sorted
    poses = np.column_stack([rng.normal(0, 20, 50), rng.normal(0, 20, 50),
                             rng.uniform(-math.pi, math.pi, 50)])
    path = write_tum(tmp_path / "traj.txt", stamps, poses, comment="test\nrun 1")
    read_stamps, read_poses = read_tum(path)
    np.testing.assert_array_equal(read_stamps, stamps)
    np.testing.assert_array_equal(read_poses[:, :2], poses[:, :2])
    _close_poses(read_poses, poses, atol=1e-12)
    first = path.read_text().splitlines()
    assert first[0].startswith("#") and first[1] == "# test"
    assert len(first[3].split()) == 8


def test_tum_reads_foreign_planar_quaternions(tmp_path):
    theta = 2.5
    scale = 3.0  # not normalised
    path = tmp_path / "foreign.txt"
    path.write_text(
        f"# header\n\n1.0 1 2 0.5 0 0 {scale * math.sin(theta / 2)} {scale * math.cos(theta / 2)}\n"
        f"2.0 1 2 0 0 0 {-math.sin(theta / 2)} {-math.cos(theta / 2)}\n"  # q and -q
    )
    stamps, poses = read_tum(path)
    np.testing.assert_array_equal(stamps, [1.0, 2.0])
    np.testing.assert_allclose(poses[:, 2], [theta, theta], atol=1e-12)


@pytest.mark.parametrize(
    "line, problem",
    [
        ("1.0 0 0 0 0 0 0", "expected 8 fields"),
        ("1.0 0 0 0 0 0 0 1 9", "expected 8 fields"),
        ("1.0 0 zero 0 0 0 0 1", "not a number"),
        ("1.0 0 nan 0 0 0 0 1", "not finite"),
        ("1.0 0 0 0 0 0 0 0", "quaternion is zero"),
        ("1.0 0 0 0 0.3826834 0 0 0.9238795", "not planar"),
    ],
)
def test_tum_errors_name_file_and_line(tmp_path, line, problem):
    path = tmp_path / "bad.txt"
    path.write_text("# header\n0.5 0 0 0 0 0 0 1\n" + line + "\n")
    with pytest.raises(DataFormatError, match=problem) as error:
        read_tum(path)
    assert error.value.line == 3 and error.value.path == str(path)


def test_tum_empty_and_bad_arguments(tmp_path):
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(DataFormatError, match="no poses"):
        read_tum(tmp_path / "empty.txt")
    with pytest.raises(ValueError):
        write_tum(tmp_path / "x.txt", np.zeros(3), np.zeros((2, 3)))
    with pytest.raises(ValueError):
        write_tum(tmp_path / "x.txt", np.zeros(2), np.full((2, 3), np.nan))


def _odometry(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0, 0.3, count), rng.normal(0, 0.02, count),
                             rng.normal(0, 0.1, count)])
    poses = [np.array([1.0, -2.0, 0.3])]
    for step in steps[1:]:
        poses.append(se2_compose(poses[-1], step))
    return np.array(poses)


def test_interpolate_keeps_keyframes_and_follows_odometry():
    odom = _odometry(40, seed=2)
    keyframes = np.array([3, 10, 25])
    # A corrected keyframe pose = a rigid correction of the odometry pose.
    corrections = np.array([[0.5, -0.2, 0.1], [1.0, 0.3, -0.4], [-2.0, 1.0, 2.0]])
    corrected = se2_compose(corrections, odom[keyframes])
    poses = interpolate_poses(keyframes, corrected, odom)
    assert poses.shape == (40, 3)
    _close_poses(poses[keyframes], corrected, atol=1e-12)
    for scan in range(40):
        slot = max(np.searchsorted(keyframes, scan, side="right") - 1, 0)
        # Independent reference with matrices: T_corr(k) T_odom(k)^-1 T_odom(i).
        expected = (_matrix(corrected[slot]) @ np.linalg.inv(_matrix(odom[keyframes[slot]]))
                    @ _matrix(odom[scan]))
        _close_poses(poses[scan], _pose(expected), atol=1e-9)


def test_interpolate_identity_correction_gives_odometry():
    odom = _odometry(30, seed=3)
    keyframes = np.arange(0, 30, 7)
    _close_poses(interpolate_poses(keyframes, odom[keyframes], odom), odom, atol=1e-9)


def test_interpolate_argument_checks():
    odom = np.zeros((5, 3))
    with pytest.raises(ValueError):
        interpolate_poses(np.array([2, 1]), np.zeros((2, 3)), odom)
    with pytest.raises(ValueError):
        interpolate_poses(np.array([0, 5]), np.zeros((2, 3)), odom)
    with pytest.raises(ValueError):
        interpolate_poses(np.array([0]), np.zeros((2, 3)), odom)
    with pytest.raises(ValueError):
        interpolate_poses(np.array([], dtype=int), np.zeros((0, 3)), odom)
    with pytest.raises(ValueError):
        interpolate_poses(np.array([0.0]), np.zeros((1, 3)), odom)
