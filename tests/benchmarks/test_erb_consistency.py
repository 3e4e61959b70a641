"""benchmarks/diagnostics/erb_consistency.py: the independent UKF reference with the true map and
associations is consistent on the landmark simulator (the simulator's noise is the
noise the filters assume, and the NEES wraps the heading), and it has the power to see
a wrong noise level."""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxslam.datasets import landmark_sim

from . import load_benchmark

erb_consistency = load_benchmark("diagnostics/erb_consistency")


def _sequences():
    # 150 steps: the car laps the circle more than twice, so the heading crosses +-pi.
    return [landmark_sim.simulate(seed=s, num_steps=150, max_observations=24) for s in range(3)]


def test_ukf_with_true_map_is_consistent_on_the_simulator():
    sequences = _sequences()
    headings = np.concatenate([q.true_poses[:, 2] for q in sequences])
    assert headings.max() > 3.0 and headings.min() < -3.0  # the wrap is exercised
    nees = np.mean([erb_consistency.ukf_known_map_nees(q).mean() for q in sequences])
    # 10 seeds x 300 steps gave 2.98 +- 0.35 (std over seeds); 3 is the expectation.
    assert 2.3 < nees < 3.9


def test_ukf_reference_sees_a_too_small_measurement_noise():
    sequences = _sequences()
    halved = [dataclasses.replace(q, meta={**q.meta, "range_std": 0.5 * q.meta["range_std"],
                                           "bearing_std": 0.5 * q.meta["bearing_std"]}) for q in sequences]
    nees = np.mean([erb_consistency.ukf_known_map_nees(q).mean() for q in halved])
    assert nees > 5.0
