"""benchmarks/scan_pair_agreement.py: the ICP recovers a known motion and reports the
points' disagreement."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import scan_pair_agreement as spa  # noqa: E402


def _room_scan(pose, noise, rng):
    """End points (laser frame) of a scan from ``pose`` in a 10 x 6 m room with a pillar."""
    walls = [((-5, -3), (5, -3)), ((5, -3), (5, 3)), ((5, 3), (-5, 3)), ((-5, 3), (-5, -3)),
             ((1, -0.5), (1.5, -0.5)), ((1.5, -0.5), (1.5, 0.5)), ((1.5, 0.5), (1, 0.5)), ((1, 0.5), (1, -0.5))]
    angles = np.linspace(-np.pi, np.pi, 361)[:-1]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    hits = []
    for a in angles:
        d = np.array([np.cos(a) * c - np.sin(a) * s, np.cos(a) * s + np.sin(a) * c])
        best = np.inf
        for p, q in walls:
            p, q = np.asarray(p, float), np.asarray(q, float)
            m = np.array([d, p - q]).T
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            t, u = np.linalg.solve(m, p - pose[:2])
            if t > 0 and 0 <= u <= 1:
                best = min(best, t)
        hits.append(best + noise * rng.standard_normal())
    hits = np.asarray(hits)
    return np.stack([hits * np.cos(angles), hits * np.sin(angles)], -1)


def test_icp_recovers_a_known_motion_and_reports_the_noise():
    rng = np.random.default_rng(0)
    first, second = np.array([0.0, 0.0, 0.0]), np.array([0.4, -0.2, 0.12])
    a = _room_scan(first, 0.0, rng)
    b = _room_scan(second, 0.0, rng)
    # started 10 cm and 3 deg off the truth (the reference's relative pose in the script)
    pose, inliers, rms = spa.icp(a, b, second + np.array([0.1, -0.05, 0.05]))
    np.testing.assert_allclose(pose, second, atol=0.02)
    assert inliers > 0.9 * b.shape[0]
    # The RMS is the end points' nearest-neighbour distance after the fit: zero for a
    # scan against itself, the spacing of the points along the walls for two poses
    # (no noise), and more with 3 cm of range noise.
    same_pose, same_inliers, same_rms = spa.icp(a, a, np.array([0.05, 0.0, 0.02]))
    np.testing.assert_allclose(same_pose, 0.0, atol=1e-9)
    assert same_rms < 1e-9 and same_inliers == a.shape[0]
    noisy = _room_scan(second, 0.03, rng)
    _, _, rms_noisy = spa.icp(a, noisy, second)
    assert 0.0 < rms < 0.03 and rms_noisy > rms + 0.005, (rms, rms_noisy)
