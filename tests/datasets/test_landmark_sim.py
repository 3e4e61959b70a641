"""The landmark-world simulator: shapes, ground truth and sensor limits."""

from __future__ import annotations

import math

import numpy as np

from jaxslam.datasets.landmark_sim import simulate


def _observe(pose, landmark):
    d = landmark - pose[:2]
    return np.array([np.hypot(*d), (math.atan2(d[1], d[0]) - pose[2] + np.pi) % (2 * np.pi) - np.pi])


def test_shapes_and_format():
    seq = simulate(seed=0, num_steps=50, rows_per_step=6)
    t, k, _ = seq.controls.shape
    assert (t, k) == (50, 6)
    assert seq.observations.shape[:2] == seq.obs_mask.shape == seq.associations.shape
    assert seq.true_poses.shape == (50, 3) and seq.gps_xy.shape == (50, 2)
    assert np.all(np.diff(seq.times) > 0)
    np.testing.assert_allclose(seq.controls[..., 2], 0.025)
    assert np.all(seq.observations[~seq.obs_mask] == 0) and np.all(seq.associations[~seq.obs_mask] == -1)
    assert simulate(seed=0, num_steps=5, max_observations=30).observations.shape[1] == 30


def test_noise_free_observations_match_the_truth():
    seq = simulate(seed=1, num_steps=40, speed_std=0.0, steering_std=0.0, range_std=0.0, bearing_std=0.0)
    np.testing.assert_array_equal(seq.controls, seq.true_controls)
    for t in range(0, 40, 7):
        for j in np.nonzero(seq.obs_mask[t])[0]:
            ref = _observe(seq.true_poses[t], seq.landmarks[seq.associations[t, j]])
            np.testing.assert_allclose(seq.observations[t, j], ref, atol=1e-9)


def test_range_and_field_of_view():
    seq = simulate(seed=2, num_steps=60, max_range=20.0, fov=math.radians(120))
    obs = seq.observations[seq.obs_mask]
    assert obs[:, 0].max() < 20.0 + 5 * 0.3
    assert np.abs(obs[:, 1]).max() < math.radians(60) + 5 * math.radians(1.0)
    # Every landmark in view is reported.
    for t in (0, 30, 59):
        d = [_observe(seq.true_poses[t], m) for m in seq.landmarks]
        visible = sum(1 for r, b in d if r < 20.0 and abs(b) <= math.radians(60))
        assert seq.obs_mask[t].sum() == visible


def test_control_noise_statistics():
    seq = simulate(seed=3, num_steps=400, speed_std=0.5, steering_std=0.03)
    noise = seq.controls - seq.true_controls
    assert abs(noise[..., 0].std() - 0.5) < 0.03
    assert abs(noise[..., 1].std() - 0.03) < 0.002
    assert np.all(noise[..., 2] == 0)


def test_reproducible():
    a, b = simulate(seed=7, num_steps=10), simulate(seed=7, num_steps=10)
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.controls, b.controls)
