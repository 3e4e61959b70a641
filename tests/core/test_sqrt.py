"""Square-root tools against dense NumPy factorisations (incl. hypothesis properties)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.core import (
    UTParams,
    chol_update,
    chol_update_checked,
    chol_update_many,
    sigma_points,
    sqrt_ut_moments,
    tria,
    ut_moments,
    ut_weights,
)
from jaxslam.core.se2 import pose_mean, pose_residual

update_jit = jax.jit(chol_update)
update_checked_jit = jax.jit(chol_update_checked)


def spd(seed, n, dtype):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    return (a @ a.T + 0.5 * n * np.eye(n)).astype(dtype), rng


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 7), f64=st.booleans())
def test_update_equals_cholesky_of_updated_matrix(seed, n, f64):
    dtype = np.float64 if f64 else np.float32
    cov, rng = spd(seed, n, np.float64)
    vec = rng.standard_normal(n)
    chol = np.linalg.cholesky(cov)
    got = update_jit(jnp.asarray(chol, dtype), jnp.asarray(vec, dtype), 1.0)
    expected = np.linalg.cholesky(cov + np.outer(vec, vec))
    tol = 1e-4 if dtype == np.float32 else 1e-10
    assert got.dtype == dtype
    np.testing.assert_allclose(np.asarray(got, np.float64), expected, rtol=tol, atol=tol * np.abs(expected).max())


@pytest.mark.parametrize("n", [1, 3, 5])
def test_update_gradient_equals_the_dense_cholesky_gradient(n):
    """Reverse mode through the update's loop over columns equals JAX's gradient of the
    dense Cholesky factor of ``L L^T + v v^T`` (float64)."""
    cov, rng = spd(n, n, np.float64)
    chol, vec = jnp.asarray(np.linalg.cholesky(cov)), jnp.asarray(rng.standard_normal(n))
    weights = jnp.asarray(rng.standard_normal((n, n)))

    def loss_update(c, v):
        return jnp.sum(weights * chol_update(c, v, 1.0))

    def loss_dense(c, v):
        return jnp.sum(weights * jnp.linalg.cholesky(c @ c.T + jnp.outer(v, v)))

    got = jax.grad(loss_update, argnums=(0, 1))(chol, vec)
    expected = jax.grad(loss_dense, argnums=(0, 1))(chol, vec)
    # the dense factor reads only the lower triangle's products, so compare on it
    lower = jnp.tril(jnp.ones((n, n)))
    np.testing.assert_allclose(np.asarray(got[1]), np.asarray(expected[1]), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(np.asarray(got[0] * lower), np.asarray(expected[0] * lower), rtol=1e-8, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 7), f64=st.booleans(),
       fraction=st.floats(0.0, 0.9))
def test_downdate_equals_cholesky_of_downdated_matrix(seed, n, f64, fraction):
    dtype = np.float64 if f64 else np.float32
    cov, rng = spd(seed, n, np.float64)
    direction = rng.standard_normal(n)
    # Largest admissible downdate along `direction` keeps the matrix PD: v^T C^-1 v < 1.
    limit = 1.0 / np.sqrt(direction @ np.linalg.solve(cov, direction))
    vec = fraction * limit * direction
    chol = np.linalg.cholesky(cov)
    got, ok = update_checked_jit(jnp.asarray(chol, dtype), jnp.asarray(vec, dtype), -1.0)
    expected = np.linalg.cholesky(cov - np.outer(vec, vec))
    tol = 2e-3 if dtype == np.float32 else 1e-8
    assert bool(ok)
    np.testing.assert_allclose(np.asarray(got, np.float64), expected, rtol=tol, atol=tol * np.abs(expected).max())


def test_sign_matters():
    # Guards against a flipped sign in the downdate: update and downdate must differ.
    cov, rng = spd(0, 4, np.float64)
    vec = 0.3 * rng.standard_normal(4)
    chol = jnp.asarray(np.linalg.cholesky(cov))
    up = np.asarray(chol_update(chol, vec, 1.0))
    down = np.asarray(chol_update(chol, vec, -1.0))
    np.testing.assert_allclose(up @ up.T, cov + np.outer(vec, vec), atol=1e-10)
    np.testing.assert_allclose(down @ down.T, cov - np.outer(vec, vec), atol=1e-10)


def test_downdate_losing_pd_is_flagged_not_nan(dtype):
    chol = jnp.eye(3, dtype=dtype)
    got, ok = chol_update_checked(chol, jnp.array([2.0, 0.0, 0.0], dtype), -1.0)
    assert not bool(ok)
    assert np.all(np.isfinite(np.asarray(got)))
    assert np.all(np.diag(np.asarray(got)) > 0)


def test_batched_and_traced_sign():
    covs = np.stack([spd(s, 3, np.float64)[0] for s in range(6)])
    vecs = np.random.default_rng(1).standard_normal((6, 3)) * 0.2
    signs = np.array([1.0, -1.0] * 3)
    got = jax.jit(chol_update)(jnp.asarray(np.linalg.cholesky(covs)), jnp.asarray(vecs), jnp.asarray(signs))
    for i in range(6):
        expected = np.linalg.cholesky(covs[i] + signs[i] * np.outer(vecs[i], vecs[i]))
        np.testing.assert_allclose(np.asarray(got[i]), expected, atol=1e-10)


def test_update_many_applies_each_column():
    cov, rng = spd(2, 5, np.float64)
    vecs = 0.2 * rng.standard_normal((3, 5))
    got = chol_update_many(jnp.asarray(np.linalg.cholesky(cov)), jnp.asarray(vecs), -1.0)
    np.testing.assert_allclose(np.asarray(got), np.linalg.cholesky(cov - vecs.T @ vecs), atol=1e-10)


@pytest.mark.parametrize("shape", [(3, 3), (3, 8), (4, 2), (2, 5, 9)])
def test_tria_reproduces_outer_product(shape):
    a = np.random.default_rng(0).standard_normal(shape)
    s = np.asarray(tria(jnp.asarray(a)))
    np.testing.assert_allclose(s @ np.swapaxes(s, -1, -2), a @ np.swapaxes(a, -1, -2), atol=1e-10)
    assert np.allclose(np.triu(s, 1), 0)
    assert np.all(np.diagonal(s, axis1=-2, axis2=-1) >= 0)


@pytest.mark.parametrize("alpha", [1.0, 0.3, 1e-2])  # the last two give negative W0
def test_sqrt_ut_equals_dense_ut(alpha):
    rng = np.random.default_rng(4)
    n = 5
    cov = spd(7, n, np.float64)[0] * 0.05
    mean = np.array([1.0, 2.0, 0.4, 0.0, 0.0])
    params = UTParams(alpha, 2.0, 0.0)
    pts = sigma_points(jnp.asarray(mean), jnp.linalg.cholesky(jnp.asarray(cov)), params)

    def motion(p):  # [pose; noise] -> pose, as in an odometry prediction
        v, w = 1.0 + p[3], 0.2 + p[4]
        return jnp.stack([p[0] + v * jnp.cos(p[2] + w), p[1] + v * jnp.sin(p[2] + w), p[2] + w])

    prop = jax.vmap(motion)(pts)
    wm, wc, _ = ut_weights(n, params)
    noise = np.diag([0.01, 0.02, 0.003])
    _, _, dense_cov = ut_moments(prop, wm, wc, pose_mean, pose_residual)
    sq_mean, sq_chol, _ = sqrt_ut_moments(prop, wm, wc, pose_mean, pose_residual, jnp.asarray(noise))
    got = np.asarray(sq_chol) @ np.asarray(sq_chol).T
    np.testing.assert_allclose(got, np.asarray(dense_cov) + noise @ noise.T, rtol=1e-8, atol=1e-12)
    assert np.allclose(np.triu(np.asarray(sq_chol), 1), 0)
    del rng
