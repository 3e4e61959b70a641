"""Sigma points, weights and the unscented transform against filterpy and exact maps."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints
from filterpy.kalman import unscented_transform as fp_unscented_transform

from jaxslam.core import UTParams, sigma_points, unscented_transform, ut_moments, ut_weights
from jaxslam.core.se2 import pose_mean, pose_residual


def random_spd(rng, n, dtype=np.float64):
    a = rng.standard_normal((n, n))
    return (a @ a.T + n * np.eye(n)).astype(dtype)


CASES = [
    (2, 1.0, 2.0, 0.0),
    (3, 0.3, 2.0, 0.0),  # negative zeroth weight
    (5, 1e-3, 2.0, 0.0),  # strongly negative zeroth weight
    (4, 0.5, 0.0, 3.0 - 4),
    (7, 1.0, 2.0, 1.0),
]


@pytest.mark.parametrize("n,alpha,beta,kappa", CASES)
def test_matches_filterpy_merwe_points(n, alpha, beta, kappa):
    rng = np.random.default_rng(n)
    mean = rng.standard_normal(n)
    cov = random_spd(rng, n)
    ref = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    params = UTParams(alpha, beta, kappa)
    points = sigma_points(jnp.asarray(mean), jnp.linalg.cholesky(jnp.asarray(cov)), params)
    mean_w, cov_w, _ = ut_weights(n, params)
    np.testing.assert_allclose(np.asarray(points), ref.sigma_points(mean, cov), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(mean_w), ref.Wm, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(cov_w), ref.Wc, rtol=1e-12, atol=1e-12)


def test_zeroth_weight_negative_case_is_covered():
    mean_w, _, _ = ut_weights(3, UTParams(0.3, 2.0, 0.0))
    assert float(mean_w[0]) < 0
    np.testing.assert_allclose(float(jnp.sum(mean_w)), 1.0, rtol=1e-12)


@pytest.mark.parametrize("alpha", [1.0, 0.5, 0.1])
def test_linear_map_is_exact(dtype, alpha):
    rng = np.random.default_rng(0)
    n, m = 4, 3
    mean = rng.standard_normal(n).astype(dtype)
    cov = random_spd(rng, n, dtype)
    a = rng.standard_normal((m, n)).astype(dtype)
    b = rng.standard_normal(m).astype(dtype)
    result = jax.jit(
        lambda mu, chol: unscented_transform(lambda x: a @ x + b, mu, chol, UTParams(alpha, 2.0, 0.0))
    )(jnp.asarray(mean), jnp.linalg.cholesky(jnp.asarray(cov)))
    rtol = 5e-3 if dtype == np.float32 else 1e-9
    assert result.mean.dtype == dtype
    np.testing.assert_allclose(np.asarray(result.mean), a @ mean + b, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(np.asarray(result.cov), a @ cov @ a.T, rtol=rtol, atol=rtol * 10)
    np.testing.assert_allclose(np.asarray(result.cross_cov), cov @ a.T, rtol=rtol, atol=rtol * 10)


def test_nonlinear_matches_filterpy_unscented_transform():
    rng = np.random.default_rng(3)
    n = 3
    mean = np.array([1.0, -0.5, 0.3])
    cov = 0.1 * random_spd(rng, n)
    params = UTParams(0.5, 2.0, 0.0)
    fn = lambda x: jnp.stack([jnp.hypot(x[0], x[1]), jnp.sin(x[2]) * x[0]])  # noqa: E731
    result = unscented_transform(fn, jnp.asarray(mean), jnp.linalg.cholesky(jnp.asarray(cov)), params)
    ref = MerweScaledSigmaPoints(n, alpha=0.5, beta=2.0, kappa=0.0)
    pts = ref.sigma_points(mean, cov)
    ys = np.stack([np.asarray(fn(jnp.asarray(p))) for p in pts])
    ref_mean, ref_cov = fp_unscented_transform(ys, ref.Wm, ref.Wc)
    np.testing.assert_allclose(np.asarray(result.mean), ref_mean, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(result.cov), ref_cov, rtol=1e-9, atol=1e-12)


def test_batched_over_leading_axes_equals_loop():
    rng = np.random.default_rng(1)
    means = rng.standard_normal((5, 2, 3))
    covs = np.stack([[random_spd(rng, 3) for _ in range(2)] for _ in range(5)])
    chols = np.linalg.cholesky(covs)
    params = UTParams(0.7, 2.0, 0.0)
    batched = sigma_points(jnp.asarray(means), jnp.asarray(chols), params)
    assert batched.shape == (5, 2, 7, 3)
    for i in range(5):
        for j in range(2):
            single = sigma_points(jnp.asarray(means[i, j]), jnp.asarray(chols[i, j]), params)
            np.testing.assert_allclose(np.asarray(batched[i, j]), np.asarray(single))
    vmapped = jax.vmap(jax.vmap(lambda m, c: sigma_points(m, c, params)))(means, chols)
    np.testing.assert_allclose(np.asarray(vmapped), np.asarray(batched))


def test_angular_hooks_handle_wraparound():
    # A heading near +pi: a naive mean of the propagated points would be near 0.
    mean = jnp.array([0.0, 0.0, jnp.pi - 0.01])
    chol = jnp.diag(jnp.array([0.1, 0.1, 0.2]))
    params = UTParams(1.0, 2.0, 0.0)
    result = unscented_transform(lambda x: x, mean, chol, params, mean_fn=pose_mean, residual_fn=pose_residual,
                                 in_residual_fn=pose_residual)
    assert abs(abs(float(result.mean[2])) - np.pi) < 0.05
    np.testing.assert_allclose(np.asarray(result.cov), np.diag([0.01, 0.01, 0.04]), atol=1e-9)


def test_ut_moments_shapes():
    pts = jnp.ones((4, 7, 2))
    wm, wc, _ = ut_weights(3, UTParams())
    mean, dev, cov = ut_moments(pts, wm, wc)
    assert mean.shape == (4, 2) and dev.shape == (4, 7, 2) and cov.shape == (4, 2, 2)


def test_no_recompile_when_only_values_change():
    traces = []

    @jax.jit
    def f(mean, chol, params):
        traces.append(1)
        return unscented_transform(jnp.sin, mean, chol, params).mean

    mean, chol = jnp.zeros(3), jnp.eye(3)
    f(mean, chol, UTParams(jnp.asarray(1.0), jnp.asarray(2.0), jnp.asarray(0.0)))
    f(mean + 1, 2 * chol, UTParams(jnp.asarray(0.3), jnp.asarray(1.0), jnp.asarray(1.0)))
    assert len(traces) == 1
