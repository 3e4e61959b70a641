r"""Gaussian log-densities and Mahalanobis distances through a lower Cholesky factor.

For :math:`\Sigma = L L^T` and a residual :math:`r`:

.. math::
    d^2 = \lVert L^{-1} r \rVert^2, \qquad
    \log \mathcal{N}(r; 0, \Sigma) = -\tfrac12 d^2 - \textstyle\sum_i \log L_{ii}
    - \tfrac{k}{2} \log 2\pi .

All functions broadcast over leading axes.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array
from jax.scipy.linalg import solve_triangular


def whiten(residual: Array, chol: Array) -> Array:
    """``L^{-1} r`` for residuals ``(..., k)`` and factors ``(..., k, k)``."""
    batch = jnp.broadcast_shapes(residual.shape[:-1], chol.shape[:-2])
    k = residual.shape[-1]
    r = jnp.broadcast_to(residual, batch + (k,))
    c = jnp.broadcast_to(chol, batch + (k, k))
    return solve_triangular(c, r[..., None], lower=True)[..., 0]


def mahalanobis_sq(residual: Array, chol: Array) -> Array:
    """Squared Mahalanobis distance ``r^T (L L^T)^{-1} r``."""
    return jnp.sum(whiten(residual, chol) ** 2, -1)


def chol_logdet(chol: Array) -> Array:
    """``log det(L L^T)`` from a lower factor."""
    return 2.0 * jnp.sum(jnp.log(jnp.abs(jnp.diagonal(chol, axis1=-2, axis2=-1))), -1)


def log_pdf(residual: Array, chol: Array) -> Array:
    """``log N(r; 0, L L^T)``."""
    k = residual.shape[-1]
    log_two_pi = jnp.log(2 * jnp.pi).astype(jnp.result_type(residual, float))
    return -0.5 * (mahalanobis_sq(residual, chol) + chol_logdet(chol) + k * log_two_pi)


def safe_cholesky(cov: Array, jitter: Array | float | None = None) -> tuple[Array, Array]:
    """Cholesky factor of a symmetrised covariance, never NaN.

    A covariance that fails to factor (not PD in finite precision) is retried with a
    diagonal jitter (default: ``1e-6`` of its largest diagonal entry); if that fails
    too, the factor of its absolute diagonal is used. The flag says whether the plain
    factor was valid, so callers can count such repairs.

    Returns:
        ``(chol, ok)``.
    """
    sym = 0.5 * (cov + jnp.swapaxes(cov, -1, -2))
    chol = jnp.linalg.cholesky(sym)
    ok = jnp.all(jnp.isfinite(chol), axis=(-2, -1))
    k = cov.shape[-1]
    diag = jnp.abs(jnp.diagonal(sym, axis1=-2, axis2=-1))
    scale = jnp.maximum(jnp.max(diag, -1), jnp.finfo(sym.dtype).tiny)
    if jitter is None:
        jitter = 1e-6 * scale
    eye = jnp.eye(k, dtype=sym.dtype)
    jittered = jnp.linalg.cholesky(sym + jnp.asarray(jitter, sym.dtype)[..., None, None] * eye)
    jitter_ok = jnp.all(jnp.isfinite(jittered), axis=(-2, -1))
    diagonal = jnp.sqrt(jnp.maximum(diag, jnp.asarray(jitter, sym.dtype)[..., None]))[..., None] * eye
    fallback = jnp.where(jitter_ok[..., None, None], jittered, diagonal)
    return jnp.where(ok[..., None, None], chol, fallback), ok
