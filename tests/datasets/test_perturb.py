"""jaxslam.datasets.perturb: the odometry noise model, the written log, the relations."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.datasets.carmen import load_carmen
from jaxslam.datasets.geometry import se2_between, se2_compose, wrap_angle
from jaxslam.datasets.perturb import (
    NOISE_LEVELS,
    OdometryNoise,
    load_reference_log,
    make_perturbed_log,
    perturb_odometry,
    reference_relations,
)
from jaxslam.metrics.relations import load_relations, relations_metric


def _path(steps: np.ndarray) -> np.ndarray:
    poses = np.zeros((steps.shape[0] + 1, 3))
    for i, u in enumerate(steps):
        poses[i + 1] = se2_compose(poses[i], u)
    return poses


def _loop_path(n: int = 120) -> np.ndarray:
    """Twice round a 4 m x 4 m square, 0.4 m steps and 90 deg turns."""
    steps = []
    for _ in range(2):
        for _ in range(4):
            steps += [(0.4, 0.0, 0.0)] * 10 + [(0.0, 0.0, np.pi / 2)]
    return _path(np.array(steps[:n]))


def _write_corrected(path, poses, stamps, beams=180):
    rng = np.random.default_rng(0)
    lines = ["PARAM robot_front_laser_max 30.0 nohost 0"]
    for (x, y, th), t in zip(poses.tolist(), stamps):
        ranges = " ".join(f"{r:.3f}" for r in rng.uniform(0.5, 29.0, beams))
        lines.append(f"FLASER {beams} {ranges} {x!r} {y!r} {th!r} {x!r} {y!r} {th!r} {t} pippo {t}")
        lines.append("NEFF 12.5")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_zero_noise_gives_back_the_reference(tmp_path):
    ref = _loop_path()
    odom, drift = perturb_odometry(ref, OdometryNoise(), seed=5)
    np.testing.assert_allclose(odom, ref, atol=1e-12)
    assert all(np.all(v == 0) for v in drift.values())
    # ... also through the written file.
    src = _write_corrected(tmp_path / "c.log", ref, [f"{10 + i * 0.5:g}" for i in range(len(ref))])
    out = make_perturbed_log(src, OdometryNoise(), 3, tmp_path / "out")
    written, original = load_carmen(out.log_path), load_carmen(src)
    np.testing.assert_array_equal(written.odom_poses, original.laser_poses)
    np.testing.assert_array_equal(written.ranges, original.ranges)
    np.testing.assert_array_equal(written.scan_times, original.scan_times)
    assert written.max_range == 30.0 and np.all(written.laser_offset == 0)
    assert out.stamps_replaced is None
    metric = relations_metric(load_relations(out.relations_path), written.scan_times, written.odom_poses)
    assert metric["n_unmatched"] == 0 and metric["trans_err_mean_m"] < 1e-9


def test_same_seed_same_log_other_seed_other_log(tmp_path):
    ref = _loop_path()
    a, _ = perturb_odometry(ref, NOISE_LEVELS["high"], seed=1)
    b, _ = perturb_odometry(ref, NOISE_LEVELS["high"], seed=1)
    c, _ = perturb_odometry(ref, NOISE_LEVELS["high"], seed=2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-3
    src = _write_corrected(tmp_path / "c.log", ref, [f"{i}" for i in range(len(ref))])
    one = make_perturbed_log(src, "low", 7, tmp_path / "x").log_path.read_bytes()
    two = make_perturbed_log(src, "low", 7, tmp_path / "y").log_path.read_bytes()
    assert one == two


def test_white_noise_has_the_asked_standard_deviations():
    rng = np.random.default_rng(0)
    n = 20000
    steps = np.column_stack([rng.uniform(0.05, 1.0, n), rng.normal(0, 0.05, n), rng.uniform(-0.6, 0.6, n)])
    ref = _path(steps)
    noise = OdometryNoise(trans_per_m=0.05, trans_per_rad=0.02, lateral_per_m=0.03, rot_per_rad=0.04, rot_per_m=0.01)
    odom, _ = perturb_odometry(ref, noise, seed=11)
    true = se2_between(ref[:-1], ref[1:])
    got = se2_between(odom[:-1], odom[1:])
    d, a = np.hypot(true[:, 0], true[:, 1]), np.abs(true[:, 2])
    z = np.column_stack(
        [
            (got[:, 0] - true[:, 0]) / (0.05 * d + 0.02 * a),
            (got[:, 1] - true[:, 1]) / (0.03 * d),
            wrap_angle(got[:, 2] - true[:, 2]) / (0.04 * a + 0.01 * d),
        ]
    )
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.03)
    np.testing.assert_allclose(z.std(axis=0), 1.0, rtol=0.03)


def test_drift_processes_have_the_asked_spread_and_correlation():
    n, step, length = 40000, 0.5, 20.0
    ref = _path(np.tile([step, 0.0, 0.0], (n, 1)))
    noise = OdometryNoise(scale_sigma=0.03, bias_sigma=0.02, drift_length=length)
    odom, drift = perturb_odometry(ref, noise, seed=4)
    got = se2_between(odom[:-1], odom[1:])
    scale = got[:, 0] / step - 1.0  # recovered from the odometry, not taken from `drift`
    bias = got[:, 2] / step
    np.testing.assert_allclose(scale, drift["scale"], atol=1e-9)
    rho = np.exp(-step / length)
    for series, sigma in ((scale, 0.03), (bias, 0.02)):
        assert abs(series.std() / sigma - 1.0) < 0.1
        lag1 = np.corrcoef(series[:-1], series[1:])[0, 1]
        assert abs(lag1 - rho) < 0.01
    assert np.all(drift["rot_scale"] == 0)


def test_bad_noise_is_rejected():
    with pytest.raises(ValueError, match="trans_per_m"):
        OdometryNoise(trans_per_m=-0.1)
    with pytest.raises(ValueError, match="unknown noise level"):
        make_perturbed_log("intel", "medium", 0, "/nonexistent")


def test_relations_local_and_loop():
    ref = _loop_path()
    stamps = np.arange(len(ref), dtype=float)
    rel, kinds = reference_relations(stamps, ref, seed=0, local_offsets=(1, 4), loop_min_gap=30)
    s = len(ref)
    assert np.sum(kinds == "local") == (s - 1) + (s - 4)
    loop = kinds == "loop"
    assert loop.sum() > 10  # the second lap revisits the first
    i, j = rel.t1[loop].astype(int), rel.t2[loop].astype(int)
    assert np.all(j - i >= 30)
    assert np.all(np.hypot(*(ref[j, :2] - ref[i, :2]).T) <= 1.5)
    np.testing.assert_allclose(rel.deltas, se2_between(ref[rel.t1.astype(int)], ref[rel.t2.astype(int)]))


def test_unusable_stamps_are_replaced(tmp_path):
    ref = _loop_path(20)
    tied = _write_corrected(tmp_path / "tied.log", ref, ["1.13486e+09"] * len(ref))
    back = _write_corrected(tmp_path / "back.log", ref, [f"{5 - 0.1 * i:g}" for i in range(len(ref))])
    for path in (tied, back):
        log = load_reference_log(path)
        assert log.stamps_replaced is not None
        np.testing.assert_array_equal(log.stamps, np.arange(len(ref)))
    assert "20 ties" in load_reference_log(tied).stamps_replaced
