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


def test_the_guard_excludes_an_iterate_under_which_the_run_filter_does_worse():
    """Candidate 2 has the best scores, but one of its guard filters (the filter you
    will run) loses track: candidate 1 is kept. Without the guard, candidate 2."""
    rng = np.random.default_rng(1)
    start = rng.normal(0.0, 1.0, 5)
    scores = np.stack([start, start + 3.0, start + 4.0])
    guard = np.stack([start, start + 2.0, start + 2.5])
    assert select_by_validation(scores, guard=guard) == 2
    guard[2, 3] = start[3] - 10.0  # one filter of candidate 2 lost track
    assert select_by_validation(scores, guard=guard) == 1
    assert select_by_validation(scores) == 2
    guard[1, 0] = np.nan  # a non-finite guard score excludes its candidate too
    assert select_by_validation(scores, guard=guard) == 0
    with pytest.raises(ValueError, match="shape"):
        select_by_validation(scores, guard=guard[:2])


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


@pytest.mark.long
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
    # The guard (the gated filter jaxslam run runs) was scored with the same keys.
    assert result.validation.likelihood == "mixture" and result.validation.guard_likelihood == "gated"
    assert np.asarray(result.validation.guard_scores).shape == (2, 6)


@pytest.mark.long
def test_validation_scores_with_the_weights_of_the_filter_to_be_run():
    """validation_score runs filters of the asked particle count and weights (the
    gated filter that ``jaxslam run`` runs by default) and averages the held-out
    scans' one-step log-likelihoods; the two weights give different scores.

    The filters, keys and window are those of the validation in the test above (8
    particles, 6 keys, the whole 24-scan window), so that its two compiled validation
    programs are reused here; only the references are compiled anew."""
    import dataclasses

    import jax

    from jaxslam.calibrate.landmark import validation_score
    from jaxslam.calibrate.landmark import log_likelihoods, log_noise_of, with_log_noise
    from jaxslam.feature.experiment import ALGORITHMS
    from jaxslam.feature.params import Config

    seq = simulate(seed=2, **SIM)
    names = ("range_std", "bearing_std")
    params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params_for(seq))
    cfg = Config(num_particles=4, proposal=ALGORITHMS["erb-upf"], likelihood="mixture", capacity=48, local_size=24)
    data = (jnp.asarray(seq.controls, jnp.float32), jnp.asarray(seq.observations, jnp.float32),
            jnp.asarray(seq.obs_mask, bool), jnp.zeros(3, jnp.float32))
    keys = jax.random.split(jax.random.PRNGKey(3), 6)
    theta = jnp.asarray(log_noise_of(params_for(seq), names), jnp.float32) - 0.5
    # The reference: one filter run per key, jitted once per config (called eagerly,
    # its scan would be traced and compiled again for every key).
    reference = jax.jit(lambda k, p, c: log_likelihoods(k, p, c, *data, checkpoint=False), static_argnums=2)
    scores = {}
    for lik in ("gated", "mixture"):
        scores[lik] = validation_score(cfg, names, params, data, 16, 8, lik)(keys, theta)
        c = dataclasses.replace(cfg, num_particles=8, likelihood=lik)
        expected = [float(np.mean(np.asarray(reference(k, with_log_noise(params, theta, names), c))[16:]))
                    for k in keys]
        np.testing.assert_allclose(scores[lik], expected, rtol=1e-5, atol=1e-5)
    assert not np.allclose(scores["gated"], scores["mixture"])
    with pytest.raises(ValueError, match="validation likelihood"):
        validation_score(cfg, names, params, data, 16, 8, "soft")
