"""Choosing the calibrated iterate on held-out scans (jaxslam.calibrate.fit)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.calibrate import calibrate
from jaxslam.calibrate.fit import select_by_validation, split_window, validation_steps
from jaxslam.datasets.landmark_sim import simulate
from jaxslam.feature.experiment import params_for


def test_select_by_validation_keeps_the_start_unless_clearly_better():
    rng = np.random.default_rng(0)
    start = rng.normal(0.0, 1.0, 8)
    noise = rng.normal(0.0, 0.1, (3, 8))
    # Candidate 2 is better in every filter by 0.5 (paired), candidate 1 worse.
    scores = np.stack([start, start - 1.0 + noise[0], start + 0.5 + noise[1]])
    assert select_by_validation(scores) == 2
    # A better mean that is within the noise of the paired difference keeps the start.
    noisy = np.stack([start, start + 0.05 + rng.normal(0.0, 1.0, 8)])
    diff = noisy[1] - noisy[0]
    assert diff.mean() > 0 and diff.mean() < 2 * diff.std(ddof=1) / np.sqrt(8)
    assert select_by_validation(noisy) == 0
    assert select_by_validation(noisy, margin=0.0) == 1
    # All worse: the start.
    assert select_by_validation(np.stack([start, start - 0.1, start - 3.0])) == 0
    # A candidate whose filter diverged (NaN / -inf) is not chosen over a finite start.
    broken = np.stack([start, start + 1.0])
    broken[1, 3] = np.nan
    assert select_by_validation(broken) == 0
    with pytest.raises(ValueError):
        select_by_validation(np.zeros(3))


def test_validation_split_and_candidates():
    assert split_window(200, 0.25) == 150
    assert split_window(200, 0.0) == 200
    with pytest.raises(ValueError):
        split_window(1, 0.5)
    with pytest.raises(ValueError):
        split_window(10, 1.0)
    assert validation_steps(10, 4) == [0, 4, 8, 10]
    assert validation_steps(3, 5) == [0, 3]


SIM = dict(num_steps=24, max_observations=16, num_landmarks=30)


@pytest.mark.parametrize("start_factor, kept", [(1.0, 0), (3.0, 1)])
def test_validation_keeps_the_better_of_start_and_step(start_factor, kept):
    """One Adam step of size 1 on the log levels moves both levels by a factor of e.
    From the true noise that step goes far off, and the held-out scans must keep the
    start; from 3x off it lands near the truth (3/e), and they must take it."""
    seq = simulate(seed=2, **SIM)
    truth = params_for(seq)
    names = ("range_std", "bearing_std")
    start = {n: start_factor * float(getattr(truth, n)) for n in names}
    result = calibrate(seq, "erb-upf", particles=8, filters=2, steps=1, learning_rate=1.0, params=start,
                       names=names, config=dict(capacity=48, local_size=24), validation=0.5, validate_every=1,
                       validation_filters=6, dtype=jnp.float32)
    assert result.fit_window == 12 and result.validation.steps == [0, 1]
    for n in names:
        assert abs(abs(math.log(result.last[n] / start[n])) - 1.0) < 1e-3
    assert result.best_step == kept
    assert result.after == pytest.approx(start if kept == 0 else result.last)
    scores = np.asarray(result.validation.scores)
    assert scores.shape == (2, 6)
    assert (scores[1].mean() > scores[0].mean()) == (kept == 1)
