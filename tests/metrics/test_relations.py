"""Tests of the Kümmerle et al. 2009 relation metric."""

from __future__ import annotations

import functools
import gzip
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.datasets.carmen import select_keyframes
from jaxslam.datasets.registry import load_dataset_log
from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError, find
from jaxslam.metrics.relations import (
    Relations,
    load_dataset_relations,
    load_relations,
    match_timestamps,
    relation_errors,
    relations_metric,
)
from jaxslam.metrics.trajectory_io import interpolate_poses, se2_between, se2_compose


def _skip_if_missing(function):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except DatasetNotFoundError as error:
            pytest.skip(str(error))

    return wrapper


@functools.lru_cache(maxsize=None)
@_skip_if_missing
def _log(name):
    # The logs as recorded (no reversing repair): the dataset READMEs score the
    # logged odometry, and these tests reproduce their numbers.
    return load_dataset_log(name, repair_odometry=False)


@functools.lru_cache(maxsize=None)
@_skip_if_missing
def _relations(name):
    return load_dataset_relations(name)


def _relations_of(t1, t2, deltas) -> Relations:
    t1, t2 = np.asarray(t1, float), np.asarray(t2, float)
    return Relations(None, t1, t2, np.asarray(deltas, float), np.arange(1, len(t1) + 1))


def _trajectory(count=30, seed=0):
    rng = np.random.default_rng(seed)
    stamps = 100.0 + 0.2 * np.arange(count)
    poses = np.column_stack([rng.normal(0, 5, count), rng.normal(0, 5, count),
                             rng.uniform(-math.pi, math.pi, count)])
    return stamps, poses


def _reference_errors(relations, stamps, poses):
    """Loop-and-matrix reference of the per-relation errors (exact stamp lookup)."""
    def matrix(p):
        c, s = math.cos(p[2]), math.sin(p[2])
        return np.array([[c, -s, p[0]], [s, c, p[1]], [0, 0, 1.0]])

    trans, rot = [], []
    for t1, t2, delta in zip(relations.t1, relations.t2, relations.deltas):
        i, j = int(np.flatnonzero(stamps == t1)[0]), int(np.flatnonzero(stamps == t2)[0])
        estimate = np.linalg.inv(matrix(poses[i])) @ matrix(poses[j])
        error = np.linalg.inv(matrix(delta)) @ estimate
        trans.append(math.hypot(error[0, 2], error[1, 2]))
        rot.append(abs(math.atan2(error[1, 0], error[0, 0])))
    return np.array(trans), np.array(rot)


def test_identity_has_zero_error():
    stamps, poses = _trajectory()
    pairs = np.array([(i, j) for i in range(30) for j in (i + 1, i + 7) if j < 30])
    relations = _relations_of(stamps[pairs[:, 0]], stamps[pairs[:, 1]],
                              se2_between(poses[pairs[:, 0]], poses[pairs[:, 1]]))
    metric = relations_metric(relations, stamps, poses)
    assert metric["n_relations"] == len(pairs) and metric["n_unmatched"] == 0
    for key in ("trans_err_mean_m", "rot_err_mean_deg", "trans_sq_err_mean_m2",
                "rot_sq_err_mean_deg2", "trans_err_std_m", "rot_sq_err_std"):
        assert metric[key] == pytest.approx(0.0, abs=1e-9)


def test_known_perturbation_gives_known_error():
    stamps, poses = _trajectory(count=4)
    # Relation k says pose k+1 sits at delta_k from pose k; the trajectory puts it at
    # delta_k (+) e_k, so the error e_k has |e_xy| = 0.5, 1.3, 0 m and 0.1, 0.2, 0.3 rad.
    perturbations = np.array([[0.3, 0.4, 0.1], [0.5, -1.2, -0.2], [0.0, 0.0, 0.3]])
    deltas = np.array([[1.0, 0.2, 0.5], [0.3, -0.1, -1.0], [2.0, 0.0, 3.0]])
    for k in range(3):
        poses[k + 1] = se2_compose(poses[k], se2_compose(deltas[k], perturbations[k]))
    relations = _relations_of(stamps[:3], stamps[1:], deltas)
    metric = relations_metric(relations, stamps, poses)
    trans = np.array([0.5, 1.3, 0.0])
    rot_deg = np.degrees([0.1, 0.2, 0.3])
    assert metric["trans_err_mean_m"] == pytest.approx(trans.mean())
    assert metric["trans_err_std_m"] == pytest.approx(trans.std())
    assert metric["rot_err_mean_deg"] == pytest.approx(rot_deg.mean())
    assert metric["rot_err_std_deg"] == pytest.approx(rot_deg.std())
    assert metric["trans_sq_err_mean_m2"] == pytest.approx((trans**2).mean())
    assert metric["trans_sq_err_std"] == pytest.approx((trans**2).std())
    assert metric["rot_sq_err_mean_deg2"] == pytest.approx((rot_deg**2).mean())
    assert metric["rot_sq_err_std"] == pytest.approx((rot_deg**2).std())
    assert metric["n_relations"] == 3 and metric["n_total"] == 3


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 10_000), st.floats(-100, 100), st.floats(-100, 100),
       st.floats(-math.pi, math.pi))
def test_errors_match_reference_and_ignore_the_world_frame(seed, x, y, theta):
    stamps, truth = _trajectory(count=12, seed=seed)
    rng = np.random.default_rng(seed)
    pairs = rng.integers(0, 12, size=(20, 2))
    relations = _relations_of(stamps[pairs[:, 0]], stamps[pairs[:, 1]],
                              se2_between(truth[pairs[:, 0]], truth[pairs[:, 1]]))
    estimate = truth + rng.normal(0, 0.1, truth.shape)
    errors = relation_errors(relations, stamps, estimate)
    trans, rot = _reference_errors(relations, stamps, estimate)
    np.testing.assert_allclose(errors.trans, trans, atol=1e-9)
    np.testing.assert_allclose(errors.rot, rot, atol=1e-9)
    moved = se2_compose(np.array([x, y, theta]), estimate)
    moved_errors = relation_errors(relations, stamps, moved)
    np.testing.assert_allclose(moved_errors.trans, errors.trans, atol=1e-8)
    np.testing.assert_allclose(moved_errors.rot, errors.rot, atol=1e-8)


def test_unmatched_relations_are_counted():
    stamps, poses = _trajectory()
    relations = _relations_of([100.0, 100.2, 150.0, 100.4], [100.2, 99.0, 100.6, 100.6],
                              np.zeros((4, 3)))
    metric = relations_metric(relations, stamps, poses)
    assert metric["n_relations"] == 2 and metric["n_unmatched"] == 2 and metric["n_total"] == 4
    errors = relation_errors(relations, stamps, poses)
    np.testing.assert_array_equal(errors.matched, [True, False, False, True])
    assert np.isnan(errors.trans[1]) and errors.index1[2] == -1
    nothing = relations_metric(relations, stamps + 5.0, poses)
    assert nothing["n_relations"] == 0 and nothing["n_unmatched"] == 4
    assert math.isnan(nothing["trans_err_mean_m"])


def test_match_timestamps():
    stamps = np.array([5.0, 1.0, 3.0, 3.0, 2.0000004])
    indices, found = match_timestamps(np.array([3.0, 2.0, 0.0, 5.0000009, 9.0]), stamps, 1e-6)
    np.testing.assert_array_equal(found, [True, True, False, True, False])
    np.testing.assert_array_equal(indices, [2, 4, -1, 0, -1])  # tie -> earliest index
    indices, found = match_timestamps(np.array([2.4]), stamps, 0.5)
    assert indices[0] == 4
    assert match_timestamps(np.array([1.0]), np.zeros(0), 1.0)[1].tolist() == [False]


def test_load_relations_files():
    for name, count, unique in (("intel", 2984, 1791), ("fr079", 1685, 989),
                                ("mit-killian", 4677, 3838)):
        relations = _relations(name)
        assert len(relations) == count
        assert np.unique(np.concatenate([relations.t1, relations.t2])).size == unique
    intel = _relations("intel")
    assert intel.t1[0] == 976052905.167303 and intel.t2[0] == 976052911.885496
    np.testing.assert_array_equal(intel.deltas[0], [-0.056990, -0.128430, -1.682210])
    assert intel.lines[0] == 1
    with pytest.raises(ValueError, match="mit-csail"):
        load_dataset_relations("mit-csail")


@pytest.mark.parametrize(
    "line, problem",
    [
        ("1 2 0 0 0 0 0", "expected 8 fields"),
        ("1 2 0 0 0 0 0 0 0", "expected 8 fields"),
        ("1 2 x 0 0 0 0 0", "not a number"),
        ("1 2 inf 0 0 0 0 0", "not finite"),
        ("1 2 0 0 0.5 0 0 0", "planar"),
    ],
)
def test_relations_file_errors(tmp_path, line, problem):
    path = tmp_path / "bad.relations"
    path.write_text("0 1 0.1 0 0 0 0 0\n\n" + line + "\n")
    with pytest.raises(DataFormatError, match=problem) as error:
        load_relations(path)
    assert error.value.line == 3 and error.value.path == str(path)


def test_empty_relations_file(tmp_path):
    (tmp_path / "empty.relations").write_text("\n")
    with pytest.raises(DataFormatError, match="no relations"):
        load_relations(tmp_path / "empty.relations")


def test_metric_accepts_a_path(tmp_path):
    stamps, poses = _trajectory(count=3)
    path = tmp_path / "r.relations"
    t1, t2, (x, y, theta) = float(stamps[0]), float(stamps[2]), se2_between(poses[0], poses[2])
    path.write_text(f"{t1!r} {t2!r} {float(x)!r} {float(y)!r} 0 0 0 {float(theta)!r}\n")
    assert relations_metric(path, stamps, poses)["trans_err_mean_m"] == pytest.approx(0.0)


# Raw odometry against the benchmark relations: the figures of
# carmen_raw/README.md and slam_benchmark_relations/README.md.
@pytest.mark.parametrize(
    "name, poses, trans_m, rot_deg, count",
    [
        ("intel", "odom_poses", 7.37, 39.2, 2984),
        ("fr079", "odom_poses", 6.50, 30.3, 1685),  # carmen_raw README (robot pose)
        ("fr079", "laser_poses", 6.51, 30.3, 1685),  # relations README (laser pose)
        ("mit-killian", "odom_poses", 50.3, 9.3, 4677),
    ],
)
def test_raw_odometry_reproduces_readme(name, poses, trans_m, rot_deg, count):
    log = _log(name)
    metric = relations_metric(_relations(name), log.scan_times, getattr(log, poses))
    assert metric["n_relations"] == count and metric["n_unmatched"] == 0
    assert round(metric["trans_err_mean_m"], 2 if trans_m < 10 else 1) == trans_m
    assert round(metric["rot_err_mean_deg"], 1) == rot_deg


@_skip_if_missing
def _gfs_json(kind):
    path = find("intel_gfs_with_unix_stamps", "intel_gfs_with_unix_stamps", f"intel_{kind}.json.gz")
    with gzip.open(path, "rt") as stream:
        scans = json.load(stream)["map"]
    stamps = np.array([float(key) for key in scans])
    poses = np.array([[scan["x"], scan["y"], scan["theta"]] for scan in scans.values()])
    return stamps, poses


@pytest.mark.parametrize("kind, trans_m, rot_deg", [("gfs", 3.31, 17.2),
                                                    ("corrected_log", 0.036, 0.42)])
def test_gmapping_scans_reproduce_readme(kind, trans_m, rot_deg):
    stamps, poses = _gfs_json(kind)
    metric = relations_metric(_relations("intel"), stamps, poses)
    assert metric["n_relations"] == 90 and metric["n_unmatched"] == 2984 - 90
    digits = 3 if trans_m < 0.1 else 2
    assert round(metric["trans_err_mean_m"], digits) == trans_m
    assert round(metric["rot_err_mean_deg"], 2 if rot_deg < 1 else 1) == rot_deg


def test_interpolated_keyframe_trajectory_scores_every_relation():
    # Keyframes at GMapping's default thresholds, "corrected" by odometry itself:
    # interpolation restores a pose for every scan, so every relation is matched and
    # the score equals raw odometry's.
    log = _log("fr079")
    keyframes = select_keyframes(log.odom_poses, linear=1.0, angular=0.5)
    poses = interpolate_poses(keyframes, log.odom_poses[keyframes], log.odom_poses)
    keyframes_only = relations_metric(_relations("fr079"), log.scan_times[keyframes],
                                      log.odom_poses[keyframes])
    every_scan = relations_metric(_relations("fr079"), log.scan_times, poses)
    assert keyframes_only["n_unmatched"] > 0
    assert every_scan["n_unmatched"] == 0
    assert every_scan["trans_err_mean_m"] == pytest.approx(6.5042, abs=1e-3)
