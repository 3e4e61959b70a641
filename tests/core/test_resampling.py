"""Resamplers: valid indices, unbiased copy counts, float32 edge cases, selective logic."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.core import resampling
from jaxslam.core.resampling import (
    RESAMPLERS,
    effective_sample_size,
    normalize_log_weights,
    selective_resample,
)

METHODS = sorted(RESAMPLERS)


@pytest.mark.parametrize("method", METHODS)
def test_indices_valid_and_unbiased(method):
    rng = np.random.default_rng(0)
    n = 16
    weights = rng.dirichlet(np.ones(n) * 0.7)
    log_w = jnp.log(jnp.asarray(weights))
    keys = jax.random.split(jax.random.PRNGKey(0), 4000)
    fn = jax.jit(jax.vmap(lambda k: RESAMPLERS[method](k, log_w)))
    idx = np.asarray(fn(keys))
    assert idx.dtype == np.int32 and idx.min() >= 0 and idx.max() < n
    counts = np.stack([np.bincount(row, minlength=n) for row in idx])
    assert np.all(counts.sum(1) == n)
    mean_counts = counts.mean(0)
    # Standard error of the mean count is at most sqrt(n w (1-w) / runs).
    stderr = np.sqrt(n * weights * (1 - weights) / len(keys)) + 1e-3
    assert np.all(np.abs(mean_counts - n * weights) < 5 * stderr), (mean_counts, n * weights)


@pytest.mark.parametrize("method", ["systematic", "stratified", "residual"])
def test_low_variance_resamplers_keep_floor_copies(method):
    weights = np.array([0.56, 0.27, 0.1, 0.07])  # away from integer N*w (rounding)
    idx = np.asarray(jax.vmap(lambda k: RESAMPLERS[method](k, jnp.log(jnp.asarray(weights))))(
        jax.random.split(jax.random.PRNGKey(1), 200)))
    counts = np.stack([np.bincount(r, minlength=4) for r in idx])
    if method != "stratified":
        assert np.all(counts >= np.floor(4 * weights))


@pytest.mark.parametrize("method", METHODS)
def test_float32_cumsum_below_one_never_out_of_range(method):
    # Many tiny float32 weights: the cumulative sum ends visibly below 1 in float32.
    n = 100_000
    log_w = jnp.full((n,), -jnp.log(float(n)), jnp.float32) + jnp.float32(-1e-4)
    fn = jax.jit(lambda k: RESAMPLERS[method](k, log_w))
    for seed in range(5):
        idx = np.asarray(fn(jax.random.PRNGKey(seed)))
        assert idx.min() >= 0 and idx.max() < n


def test_uniform_draw_at_edge_stays_in_range():
    # Positions right at the top of a CDF that ends below one map to the last index.
    cdf = jnp.array([0.2, 0.5, 0.9999], jnp.float32)
    idx = resampling._invert_cdf(cdf / cdf[-1], jnp.array([0.99999994], jnp.float32))
    assert int(idx[0]) == 2


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-50, 5), min_size=2, max_size=40), st.integers(0, 1000))
def test_property_indices_in_range(log_weights, seed):
    lw = jnp.asarray(log_weights)
    for method in METHODS:
        idx = np.asarray(RESAMPLERS[method](jax.random.PRNGKey(seed), lw))
        assert idx.shape == (len(log_weights),)
        assert idx.min() >= 0 and idx.max() < len(log_weights)


def test_all_weights_underflow_gives_uniform_not_nan(dtype):
    lw = jnp.full((8,), -jnp.inf, dtype)
    norm = normalize_log_weights(lw)
    assert np.all(np.isfinite(np.asarray(norm)))
    np.testing.assert_allclose(np.exp(np.asarray(norm)), 1 / 8, rtol=1e-6)
    np.testing.assert_allclose(float(effective_sample_size(lw)), 8.0, rtol=1e-5)
    lw_nan = jnp.array([0.0, jnp.nan, -1.0], dtype)
    assert np.all(np.isfinite(np.asarray(normalize_log_weights(lw_nan))[[0, 2]]))
    assert float(jnp.exp(normalize_log_weights(lw_nan))[1]) == 0.0


def test_very_negative_log_weights_normalise_in_log_space(dtype):
    lw = jnp.asarray([-1e4, -1e4 - 1.0, -1e4 - 2.0], dtype)
    w = np.exp(np.asarray(normalize_log_weights(lw), np.float64))
    ref = np.exp([0, -1, -2]) / np.exp([0, -1, -2]).sum()
    # float32 resolves 1e4 only to ~1e-3, which bounds the achievable accuracy here
    np.testing.assert_allclose(w, ref, rtol=2e-3 if dtype == np.float32 else 1e-9)


def test_ess_extremes():
    assert float(effective_sample_size(jnp.zeros(10))) == pytest.approx(10.0)
    assert float(effective_sample_size(jnp.array([0.0] + [-jnp.inf] * 9))) == pytest.approx(1.0)


def test_selective_resample_threshold():
    key = jax.random.PRNGKey(3)
    even = jnp.zeros(10)
    anc, did, new_lw = jax.jit(selective_resample, static_argnames="method")(key, even, 0.5, method="residual")
    assert not bool(did)
    np.testing.assert_array_equal(np.asarray(anc), np.arange(10))
    skewed = jnp.array([0.0] + [-20.0] * 9)
    anc, did, new_lw = selective_resample(key, skewed, 0.5)
    assert bool(did)
    assert np.all(np.asarray(anc) == 0)
    np.testing.assert_allclose(np.asarray(new_lw), -np.log(10))


def test_selective_resample_no_recompile_on_threshold_change():
    traces = []

    @jax.jit
    def f(key, lw, thr):
        traces.append(1)
        return selective_resample(key, lw, thr)

    f(jax.random.PRNGKey(0), jnp.zeros(5), 0.5)
    f(jax.random.PRNGKey(1), jnp.ones(5), 0.9)
    assert len(traces) == 1


def test_unknown_method_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown resampler"):
        selective_resample(jax.random.PRNGKey(0), jnp.zeros(3), 0.5, method="bogus")


@pytest.mark.parametrize("block", [1, 7, 32])
def test_systematic_rows_block_by_block_are_the_systematic_draw(block):
    """The rows of a draw of ``num`` taken block by block, on the unnormalised running
    sum of the weights, are :func:`systematic`'s indices for the same key (float64),
    for a draw the size of the weights and a smaller one."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(block)
        log_weights = jnp.asarray(rng.normal(size=64) * 2.0)
        key = jax.random.PRNGKey(3)
        cdf = jnp.cumsum(jnp.exp(log_weights))
        for num in (64, 40):
            rows = [resampling.systematic_rows(key, cdf, num, start, block) for start in range(0, num, block)]
            drawn = np.concatenate([np.asarray(r) for r in rows])[:num]
            np.testing.assert_array_equal(drawn, np.asarray(resampling.systematic(key, log_weights, num)))
