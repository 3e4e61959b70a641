"""The differentiable landmark step: the filter's forward pass, plus finite gradients."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.calibrate import landmark as L
from jaxslam.datasets.landmark_sim import simulate
from jaxslam.runtime.driver import step_keys
from jaxslam.feature import filter as F
from jaxslam.feature.experiment import params_for
from jaxslam.feature.params import Config

SIM = dict(num_steps=25, max_observations=16, max_range=12.0, speed=6.0, num_landmarks=30,
           speed_std=1.0, range_std=1.0, bearing_std=math.radians(3.0))
CONFIG = Config(num_particles=10, capacity=64, local_size=32)


def test_forward_pass_is_the_filter():
    """Same keys, same particles, weights, maps and resampling decisions as filter.step,
    and the same log-likelihood increment as the filter's ``Info``.

    Not bit for bit: the two steps are compiled in one program and XLA fuses them
    differently (float32 differs in the last bits); in float64 they agree to 1e-9.
    """
    seq = simulate(seed=3, **SIM)
    params = params_for(seq, resample_threshold=0.9)
    key = jax.random.PRNGKey(4)

    @jax.jit
    def both(key):
        state = F.init(key, params, CONFIG, jnp.zeros(3, jnp.float64))
        keys = step_keys(key, SIM["num_steps"])

        def body(carry, xs):
            a, b = carry
            k, u, z, m = xs
            a, info = F.step(k, a, u, F.Observation(z, m), params, CONFIG)
            b, ll = L.differentiable_step(k, b, u, F.Observation(z, m), params, CONFIG)
            return (a, b), (info.resampled, a, b, ll, info.log_likelihood_increment)

        return jax.lax.scan(body, (state, state), (keys, seq.controls, seq.observations, seq.obs_mask))

    _, (resampled, a, b, ll, increment) = both(key)
    assert np.asarray(resampled).sum() >= 2  # resampling really happened
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        if np.issubdtype(np.asarray(x).dtype, np.floating):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-9, atol=1e-9)
        else:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert np.all(np.isfinite(np.asarray(ll)))
    np.testing.assert_allclose(np.asarray(increment), np.asarray(ll), rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_gradient_is_finite_and_matches_finite_differences():
    seq = simulate(seed=3, **SIM)
    params = params_for(seq)
    theta = jnp.asarray(L.log_noise_of(params))
    f = jax.jit(lambda th, k: jnp.sum(L.log_likelihoods(k, L.with_log_noise(params, th), CONFIG, seq.controls,
                                                       seq.observations, seq.obs_mask, jnp.zeros(3))))
    value, grad = jax.value_and_grad(f)(theta, jax.random.PRNGKey(0))
    assert np.isfinite(value) and np.all(np.isfinite(grad))
