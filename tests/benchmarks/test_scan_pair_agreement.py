"""benchmarks/diagnostics/scan_pair_agreement.py: the ICP recovers a known motion and reports the
points' disagreement."""

import numpy as np

from jaxslam.datasets.laser_sim import raycast

from . import load_benchmark

spa = load_benchmark("diagnostics/scan_pair_agreement")


def _scan(walls, pose, noise, rng):
    """Laser-frame end points of a 360-beam scan from ``pose`` (the project's ray caster)."""
    angles = np.linspace(-np.pi, np.pi, 361)[:-1]
    ranges = raycast(walls, np.asarray(pose[:2], float)[None], (pose[2] + angles)[None], 30.0)[0]
    ranges = ranges + noise * rng.standard_normal(ranges.shape)
    return spa.end_points(ranges, np.isfinite(ranges), angles)


def _room():
    """A 10 x 6 m room around the origin with a 0.5 x 1 m pillar: wall segments (M, 4)."""
    corners = [(-5, -3), (5, -3), (5, 3), (-5, 3)]
    pillar = [(1, -0.5), (1.5, -0.5), (1.5, 0.5), (1, 0.5)]
    return np.array([(*p[i], *p[(i + 1) % 4]) for p in (corners, pillar) for i in range(4)], float)


def test_icp_recovers_a_known_motion_and_reports_the_noise():
    rng = np.random.default_rng(0)
    walls = _room()
    first, second = np.array([0.0, 0.0, 0.0]), np.array([0.4, -0.2, 0.12])
    a = _scan(walls, first, 0.0, rng)
    b = _scan(walls, second, 0.0, rng)
    truth = spa.se2_between(first[None], second[None])[0]
    # started 10 cm and 3 deg off the truth (the reference's relative pose in the script)
    pose, inliers, rms = spa.icp(a, b, truth + np.array([0.1, -0.05, 0.05]))
    np.testing.assert_allclose(pose, truth, atol=0.02)
    assert inliers > 0.9 * b.shape[0]
    # The RMS is the end points' nearest-neighbour distance after the fit: zero for a
    # scan against itself, the spacing of the points along the walls for two poses
    # (no noise), and more with 3 cm of range noise.
    same_pose, same_inliers, same_rms = spa.icp(a, a, np.array([0.05, 0.0, 0.02]))
    np.testing.assert_allclose(same_pose, 0.0, atol=1e-9)
    assert same_rms < 1e-9 and same_inliers == a.shape[0]
    noisy = _scan(walls, second, 0.03, rng)
    _, _, rms_noisy = spa.icp(a, noisy, truth)
    assert 0.0 < rms < 0.03 and rms_noisy > rms + 0.005, (rms, rms_noisy)


def test_grid_search_finds_a_motion_a_wrong_reference_step_misses():
    """The --steps-over check: the reference says the robot stepped 0.9 m sideways,
    the scans were taken 0.5 m forward with a 8 deg turn. The grid search, which does
    not start from the reference, finds the scans' step on its own (within its fine
    grid's 0.02 m and 0.5 deg), and the misfit there is far below the misfit at the
    reference's step."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(1)
    walls = _room()
    first, second = np.array([-1.0, 0.5, 0.1]), np.array([-0.5, 0.55, 0.24])
    a = _scan(walls, first, 0.01, rng)
    b = _scan(walls, second, 0.01, rng)
    truth = spa.se2_between(first[None], second[None])[0]
    tree = cKDTree(a)
    found = spa.grid_search(tree, b)
    np.testing.assert_allclose(found, truth, atol=0.015)
    wrong = np.array([0.05, -0.9, 0.2])
    assert spa.misfit(tree, b, found) < 0.03
    assert spa.misfit(tree, b, wrong) > 4 * spa.misfit(tree, b, found)
