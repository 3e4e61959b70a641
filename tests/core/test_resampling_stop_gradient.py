"""Stop-gradient resampling: forward values unchanged, gradients the score."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxslam.core.resampling import (
    RESAMPLERS,
    normalize_log_weights,
    selective_resample,
    selective_resample_stop_gradient,
    stop_gradient_log_weights,
)


@pytest.mark.parametrize("method", sorted(RESAMPLERS))
@given(seed=st.integers(0, 2**31 - 1), threshold=st.sampled_from([0.0, 0.5, 1.1]))
def test_forward_bit_identical(method, seed, threshold):
    key = jax.random.PRNGKey(seed)
    log_w = 3.0 * jax.random.normal(jax.random.fold_in(key, 7), (17,))
    log_w = log_w.at[3].set(-jnp.inf)
    a, r, w = selective_resample(key, log_w, threshold, method)
    a2, r2, w2 = selective_resample_stop_gradient(key, log_w, threshold, method)
    np.testing.assert_array_equal(a, a2)
    np.testing.assert_array_equal(r, r2)
    np.testing.assert_array_equal(w, w2)


def test_gradient_is_score_of_resampled_particles():
    # One parameter theta shifts particle i's log-weight by theta * c_i; after
    # resampling, d/dtheta of sum_j w_j f_j with the carried weights is
    # (1/N) sum_j f_j (c_{a_j} - sum_i w_i c_i), the score estimator.
    n = 8
    c = jnp.arange(n, dtype=jnp.float64) / n
    f = jnp.linspace(-1.0, 2.0, n)
    base = jax.random.normal(jax.random.PRNGKey(1), (n,), jnp.float64)
    key = jax.random.PRNGKey(2)

    def estimate(theta):
        log_w = normalize_log_weights(base + theta * c)
        a, _, new_w = selective_resample_stop_gradient(key, log_w, 2.0)
        return jnp.sum(jnp.exp(new_w) * f[a]), a

    (value, a), grad = jax.value_and_grad(estimate, has_aux=True)(0.3)
    w = jnp.exp(normalize_log_weights(base + 0.3 * c))
    expected = jnp.mean(f[a] * (c[a] - w @ c))
    np.testing.assert_allclose(value, jnp.mean(f[a]), rtol=1e-12)
    np.testing.assert_allclose(grad, expected, rtol=1e-10, atol=1e-14)


def test_non_finite_weight_gives_no_nan():
    def total(s):
        log_w = jnp.stack([s, -jnp.inf, 0.0 * s])
        return jnp.sum(stop_gradient_log_weights(log_w, jnp.array([1, 0, 0])))

    value, grad = jax.value_and_grad(total)(0.5)
    np.testing.assert_allclose(value, -3 * np.log(3.0))
    np.testing.assert_allclose(grad, 2.0)
