"""The ensemble runner: every member equals the single-seed run of its seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxslam.datasets.landmark_sim import simulate
from jaxslam.feature import ensemble
from jaxslam.feature.experiment import run_landmark_slam

SIM = dict(num_steps=30, max_observations=16, max_range=12.0, speed=6.0, num_landmarks=30,
           speed_std=1.0, range_std=1.0, bearing_std=math.radians(3.0))
CONFIG = dict(capacity=64, local_size=32)


@pytest.mark.parametrize("algorithm", [pytest.param("erb-upf", marks=pytest.mark.long),
                                       pytest.param("rb-upf", marks=pytest.mark.slow)])
def test_members_equal_single_seed_runs(algorithm):
    seq = simulate(seed=3, **SIM)
    seeds = (0, 5, 11)
    result = ensemble.run_landmark_ensemble(seq, algorithm, particles=12, seeds=seeds, config=CONFIG)
    assert result.trajectory.shape == (3, 30, 3)
    for i, seed in enumerate(seeds):
        single = run_landmark_slam(seq, algorithm, particles=12, seed=seed, config=CONFIG, progress=False)
        # Bit for bit: vmap over seeds does not change any per-seed arithmetic here.
        np.testing.assert_array_equal(result.trajectory[i], single.trajectory)
        for name, value in single.info.items():
            np.testing.assert_array_equal(result.info[name][i], value, err_msg=name)
        np.testing.assert_array_equal(result.state.log_weights[i], single.state.log_weights)
        np.testing.assert_array_equal(result.state.landmarks.means[i], single.state.landmarks.means)
    # Different seeds give different runs (the keys really differ).
    assert not np.array_equal(result.trajectory[0], result.trajectory[1])


@pytest.mark.long
def test_params_sweep_does_not_recompile():
    seq = simulate(seed=3, **SIM)
    ensemble.run_landmark_ensemble(seq, "erb-upf", particles=12, seeds=(0, 1, 2), config=CONFIG)
    second = ensemble.run_landmark_ensemble(
        seq, "erb-upf", particles=12, seeds=(2, 3, 4), config=CONFIG, params={"range_std": 0.7}
    )
    assert second.compile_s == 0.0
    single = run_landmark_slam(
        seq, "erb-upf", particles=12, seed=3, config=CONFIG, params={"range_std": 0.7}, progress=False
    )
    np.testing.assert_array_equal(second.trajectory[1], single.trajectory)


@pytest.mark.long
def test_recorded_poses_are_the_particles_and_change_nothing_else():
    seq = simulate(seed=3, **SIM)
    seeds = (0, 5, 11)  # the shapes of the tests above: the plain run's program is compiled already
    plain = ensemble.run_landmark_ensemble(seq, "erb-upf", particles=12, seeds=seeds, config=CONFIG)
    recorded = ensemble.run_landmark_ensemble(seq, "erb-upf", particles=12, seeds=seeds, config=CONFIG,
                                              record_poses=True)
    assert plain.particle_poses is None and recorded.particle_poses.shape == (3, 30, 12, 3)
    for name, value in plain.info.items():
        np.testing.assert_array_equal(recorded.info[name], value, err_msg=name)
    np.testing.assert_array_equal(recorded.particle_poses[:, -1], plain.state.poses)


def test_bad_seeds():
    seq = simulate(seed=1, num_steps=3)
    with pytest.raises(ValueError, match="seeds"):
        ensemble.run_landmark_ensemble(seq, seeds=())
    with pytest.raises(ValueError, match="algorithm"):
        ensemble.run_landmark_ensemble(seq, algorithm="nope")
