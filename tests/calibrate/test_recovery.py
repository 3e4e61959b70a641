"""Simulator recovery of the measurement noise (slow: compiles the landmark gradient)."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from jaxslam.calibrate import calibrate
from jaxslam.datasets.landmark_sim import simulate
from jaxslam.feature.experiment import params_for


@pytest.mark.slow
@pytest.mark.parametrize("factor", [3.0, 1.0 / 3.0])
def test_recovers_measurement_noise_from_3x_off(factor):
    seq = simulate(seed=0, num_steps=60)
    truth = params_for(seq)
    names = ("range_std", "bearing_std")
    start = {n: float(getattr(truth, n)) * factor for n in names}
    result = calibrate(seq, "erb-upf", particles=20, filters=4, steps=60, learning_rate=0.1, params=start,
                       names=names, config=dict(capacity=96, local_size=48), dtype=jnp.float32)
    for n in names:
        assert abs(result.after[n] / float(getattr(truth, n)) - 1) < 0.2, (n, result.after, factor)
    assert result.log_likelihood[-1] > result.log_likelihood[0]
