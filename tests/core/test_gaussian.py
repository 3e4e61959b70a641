"""Gaussian log-density and Mahalanobis distance against SciPy."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import multivariate_normal

from jaxslam.core.gaussian import chol_logdet, log_pdf, mahalanobis_sq, safe_cholesky


def test_log_pdf_matches_scipy(dtype):
    rng = np.random.default_rng(0)
    for k in (1, 2, 3, 5):
        a = rng.standard_normal((k, k))
        cov = a @ a.T + np.eye(k)
        r = rng.standard_normal(k)
        chol = jnp.asarray(np.linalg.cholesky(cov), dtype)
        got = float(jax.jit(log_pdf)(jnp.asarray(r, dtype), chol))
        ref = multivariate_normal(np.zeros(k), cov).logpdf(r)
        tol = 1e-4 if dtype == np.float32 else 1e-10
        assert abs(got - ref) < tol * max(1, abs(ref))
        md = float(mahalanobis_sq(jnp.asarray(r, dtype), chol))
        assert abs(md - r @ np.linalg.solve(cov, r)) < tol * max(1, md)
        assert abs(float(chol_logdet(chol)) - np.linalg.slogdet(cov)[1]) < tol * 10


def test_broadcast_over_batches():
    chol = jnp.eye(2) * 2.0
    r = jnp.ones((4, 3, 2))
    assert mahalanobis_sq(r, chol).shape == (4, 3)
    np.testing.assert_allclose(np.asarray(mahalanobis_sq(r, chol)), 0.5)


def test_safe_cholesky_repairs_non_pd(dtype):
    good = jnp.asarray([[2.0, 0.5], [0.5, 1.0]], dtype)
    chol, ok = safe_cholesky(good)
    assert bool(ok)
    np.testing.assert_allclose(np.asarray(chol @ chol.T), np.asarray(good), rtol=1e-5)
    bad = jnp.asarray([[1.0, 2.0], [2.0, 1.0]], dtype)  # indefinite
    chol, ok = safe_cholesky(bad)
    assert not bool(ok)
    assert np.all(np.isfinite(np.asarray(chol)))
    semidef = jnp.zeros((3, 3), dtype)
    chol, ok = safe_cholesky(semidef)
    assert np.all(np.isfinite(np.asarray(chol)))
