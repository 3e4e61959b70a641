"""Odometry models: GMapping's sampler and the SRUPF-GM unscented prediction."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.core import se2
from jaxslam.core.sigma import UTParams
from jaxslam.models.odometry import (
    augmented_motion,
    gmapping_noise_std,
    motion_noise_sqrt,
    odometry_increment,
    paper_augmented_motion,
    polar_increment,
    sample_gmapping,
    sqrt_unscented_predict,
    unscented_predict,
)


def test_noiseless_augmented_motion_is_composition(dtype):
    pose = jnp.asarray([1.0, -2.0, 0.7], dtype)
    for inc in ([0.8, 0.1, -0.3], [-0.5, 0.05, 0.2], [0.0, 0.0, 0.4]):
        inc = jnp.asarray(inc, dtype)
        aug = jnp.concatenate([pose, jnp.zeros(2, dtype)])
        got = augmented_motion(aug, inc)
        assert got.dtype == dtype
        np.testing.assert_allclose(got, se2.compose(pose, inc), atol=1e-5 if dtype == np.float32 else 1e-12)


def test_paper_motion_formula():
    aug = jnp.asarray([1.0, 2.0, 0.3, 0.1, -0.05])
    v, d = 0.5, 0.2
    got = np.asarray(paper_augmented_motion(aug, jnp.asarray([v, d])))
    V, G = v + 0.1, d - 0.05
    np.testing.assert_allclose(got, [1.0 + V * np.cos(G + 0.3), 2.0 + V * np.sin(G + 0.3), 0.3 + G], atol=1e-12)


def test_polar_increment_backwards():
    p = polar_increment(jnp.asarray([-1.0, -0.1, 0.2]))
    assert float(p.length) < 0
    assert abs(float(p.bearing)) < 0.2
    g = jax.grad(lambda x: polar_increment(x).bearing)(jnp.zeros(3))
    assert np.all(np.isfinite(g))


def test_gmapping_sampler_statistics():
    """Empirical std of the sampled increment matches srr/srt/str/stt (code form)."""
    pose = jnp.asarray([0.3, -0.2, 1.1])
    inc = jnp.asarray([0.9, 0.2, 0.4])
    gains = (0.1, 0.2, 0.1, 0.2)
    keys = jax.random.split(jax.random.PRNGKey(0), 20000)
    samples = jax.jit(jax.vmap(lambda k: sample_gmapping(k, pose, inc, *gains)))(keys)
    noisy_inc = se2.relative(pose, samples)
    std = np.std(np.asarray(noisy_inc), 0)
    np.testing.assert_allclose(std, gmapping_noise_std(inc, *gains), rtol=0.05)
    np.testing.assert_allclose(np.mean(np.asarray(noisy_inc), 0), inc, atol=0.01)
    # srr |dx| + str |dth| + 0.3 srr |dy| for x, stt |dth| + srt |dxy| for theta
    expected = [0.1 * 0.9 + 0.1 * 0.4 + 0.03 * 0.2, 0.1 * 0.2 + 0.1 * 0.4 + 0.03 * 0.9, 0.2 * 0.4 + 0.2 * np.hypot(0.9, 0.2)]
    np.testing.assert_allclose(gmapping_noise_std(inc, *gains), expected, rtol=1e-6)


def test_increment_roundtrip():
    a = jnp.asarray([1.0, 2.0, 0.5])
    b = jnp.asarray([1.5, 2.7, -0.4])
    np.testing.assert_allclose(se2.compose(a, odometry_increment(a, b)), b, atol=1e-12)


SQRT_PREDICT = jax.jit(sqrt_unscented_predict)
DENSE_PREDICT = jax.jit(unscented_predict)


def _random_case(rng, dtype):
    pose = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3, 3)])
    a = rng.normal(size=(3, 3)) * np.array([0.05, 0.05, 0.03])[:, None]
    chol = np.linalg.cholesky(a @ a.T + np.diag([1e-4, 1e-4, 1e-5]))
    inc = np.array([rng.uniform(-0.2, 1.2), rng.uniform(-0.2, 0.2), rng.uniform(-0.6, 0.6)])
    return (jnp.asarray(pose, dtype), jnp.asarray(chol, dtype), jnp.asarray(inc, dtype))


@pytest.mark.parametrize("alpha,kappa", [(1.0, 0.0), (0.5, 0.0), (0.1, 1.0)])
def test_sqrt_prediction_equals_dense(dtype, alpha, kappa):
    """Eqs. (1)-(8): the square-root update gives the dense UT mean and covariance,
    also when the zeroth covariance weight is negative (small alpha)."""
    rng = np.random.default_rng(int(alpha * 10))
    ut = UTParams(alpha, 2.0, kappa)
    sqrt_fn = SQRT_PREDICT
    dense_fn = DENSE_PREDICT
    for _ in range(5):
        pose, chol, inc = _random_case(rng, dtype)
        noise = motion_noise_sqrt(inc, 0.02, 0.02, 0.1, 0.1, 0.05)
        sq = sqrt_fn(pose, chol, inc, noise, ut)
        de = dense_fn(pose, chol, inc, noise, ut)
        tol = 1e-4 if dtype == np.float32 else 1e-10
        np.testing.assert_allclose(sq.mean, de.mean, atol=tol)
        np.testing.assert_allclose(sq.sqrt_cov @ sq.sqrt_cov.T, de.cov, atol=tol * float(np.abs(de.cov).max()) * 10)
        assert sq.mean.dtype == dtype
        assert np.allclose(np.triu(np.asarray(sq.sqrt_cov), 1), 0)


@settings(max_examples=20, deadline=None)
@given(
    st.floats(-1.0, 2.0), st.floats(-0.3, 0.3), st.floats(-1.0, 1.0), st.floats(0.005, 0.2), st.floats(0.005, 0.2)
)
def test_sqrt_prediction_property(dx, dy, dth, s_lin, s_ang):
    """Property: S S^T of the square-root prediction equals the dense UT covariance."""
    pose = jnp.asarray([0.5, -1.0, 2.9])
    chol = jnp.diag(jnp.asarray([0.03, 0.02, 0.01]))
    inc = jnp.asarray([dx, dy, dth])
    noise = motion_noise_sqrt(inc, s_lin, s_ang)
    ut = UTParams(1.0, 2.0, 0.0)
    sq = SQRT_PREDICT(pose, chol, inc, noise, ut)
    de = DENSE_PREDICT(pose, chol, inc, noise, ut)
    np.testing.assert_allclose(sq.sqrt_cov @ sq.sqrt_cov.T, de.cov, atol=1e-10)
    np.testing.assert_allclose(sq.mean, de.mean, atol=1e-10)


def test_prediction_mean_near_composition():
    pose = jnp.asarray([0.0, 0.0, 3.1])  # near the wrap-around
    chol = jnp.diag(jnp.asarray([0.01, 0.01, 0.02]))
    inc = jnp.asarray([1.0, 0.0, 0.1])
    noise = motion_noise_sqrt(inc, 0.01, 0.01)
    pred = SQRT_PREDICT(pose, chol, inc, noise, UTParams(1.0, 2.0, 0.0))
    expected = se2.compose(pose, inc)
    diff = se2.pose_residual(pred.mean, expected)
    assert float(jnp.max(jnp.abs(diff))) < 5e-3
