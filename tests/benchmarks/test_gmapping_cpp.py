"""benchmarks/gmapping_cpp.py: keyframe stamps -> scan poses, and a clear error when
GMapping is not built. (Running GMapping itself is a benchmark, not a test.)"""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.datasets.geometry import se2_between, se2_compose

from . import load_benchmark

gmapping_cpp = load_benchmark("gmapping_cpp")


def _odometry(n: int, rng: np.random.Generator) -> np.ndarray:
    steps = np.column_stack([rng.uniform(0, 0.2, n), rng.normal(0, 0.02, n), rng.normal(0, 0.1, n)])
    poses = np.zeros((n, 3))
    for i in range(1, n):
        poses[i] = se2_compose(poses[i - 1], steps[i])
    return poses


def test_keyframes_to_scans_matches_stamps_and_composes_odometry():
    rng = np.random.default_rng(3)
    n = 40
    odom = _odometry(n, rng)
    stamps = 100.0 + np.arange(n) * 0.1
    stamps[[7, 8]] = stamps[7]  # two scans with one stamp, as in the Intel log
    stamps[33] = stamps[20] - 0.01  # a line out of time order, also as in Intel
    kf_idx = np.array([0, 7, 8, 20, 33])
    kf_poses = odom[kf_idx] + rng.normal(0, 0.3, (len(kf_idx), 3))
    # GMapping prints stamps with 6 decimals, sorted by stamp (stable: ties keep log order).
    perm = np.argsort(stamps[kf_idx], kind="stable")
    idx, traj = gmapping_cpp.keyframes_to_scans(np.round(stamps[kf_idx], 6)[perm], kf_poses[perm], stamps, odom)
    np.testing.assert_array_equal(idx, kf_idx)
    np.testing.assert_allclose(traj[kf_idx, :2], kf_poses[:, :2], atol=1e-12)
    # Independent loop: scan i = its last keyframe's pose (+) odometry since that keyframe.
    for i in range(n):
        k = max(j for j in range(len(kf_idx)) if kf_idx[j] <= i) if i >= kf_idx[0] else 0
        expected = se2_compose(kf_poses[k], se2_between(odom[kf_idx[k]], odom[i]))
        np.testing.assert_allclose(traj[i, :2], expected[:2], atol=1e-9)
        assert abs(np.angle(np.exp(1j * (traj[i, 2] - expected[2])))) < 1e-9


def test_keyframe_stamp_without_scan_is_an_error():
    stamps = np.arange(5, dtype=float)
    odom = np.zeros((5, 3))
    with pytest.raises(gmapping_cpp.GMappingRunError, match="2.500000 matches no scan"):
        gmapping_cpp.keyframes_to_scans(np.array([0.0, 2.5]), np.zeros((2, 3)), stamps, odom)


def test_missing_binary_names_build_script(monkeypatch, tmp_path):
    monkeypatch.setenv("GMAPPING_BIN", str(tmp_path / "nothing"))
    if not (gmapping_cpp._tool_dir() / "run.sh").is_file():
        pytest.skip("shared/tools/gmapping not present")
    with pytest.raises(gmapping_cpp.GMappingNotBuiltError, match="build.sh"):
        gmapping_cpp.find_gmapping()
