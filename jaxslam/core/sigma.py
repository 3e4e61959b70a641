r"""Scaled unscented transform: sigma points, weights and moments.

For an ``n``-dimensional Gaussian with mean :math:`x` and lower Cholesky factor
:math:`L` (:math:`P = L L^T`), the scaled unscented transform (Julier 2002; Wan &
van der Merwe 2000) uses

.. math::
    \lambda = \alpha^2 (n + \kappa) - n, \qquad \gamma = \sqrt{n + \lambda},

    \chi_0 = x, \quad \chi_i = x + \gamma L_{:,i}, \quad \chi_{n+i} = x - \gamma L_{:,i},
    \quad i = 1..n,

    W^m_0 = \frac{\lambda}{n + \lambda}, \quad
    W^c_0 = \frac{\lambda}{n + \lambda} + 1 - \alpha^2 + \beta, \quad
    W^m_i = W^c_i = \frac{1}{2 (n + \lambda)}.

The order of the points is the one of filterpy's ``MerweScaledSigmaPoints``. The
zeroth weight may be negative (e.g. small alpha); nothing here assumes otherwise.

``n`` is static (it fixes shapes); ``alpha``, ``beta`` and ``kappa`` are traced
values carried in :class:`UTParams`, so sweeping them never recompiles.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array


class UTParams(NamedTuple):
    """Scaling parameters of the unscented transform (traced, not static)."""

    alpha: Array | float = 1.0
    beta: Array | float = 2.0
    kappa: Array | float = 0.0


class UTResult(NamedTuple):
    """Moments of ``y = fn(x)`` estimated by the unscented transform."""

    mean: Array  # (..., m)
    cov: Array  # (..., m, m), without any additive noise
    cross_cov: Array  # (..., n, m), E[(x - x_mean)(y - y_mean)^T]
    sigma_points: Array  # (..., 2n+1, n)
    propagated: Array  # (..., 2n+1, m)


def ut_lambda(n: int, params: UTParams, dtype=None) -> Array:
    """The scaling ``lambda = alpha^2 (n + kappa) - n``."""
    alpha = jnp.asarray(params.alpha, dtype)
    kappa = jnp.asarray(params.kappa, dtype)
    return alpha**2 * (n + kappa) - n


def ut_weights(n: int, params: UTParams, dtype=None) -> tuple[Array, Array, Array]:
    """Mean weights, covariance weights (each ``(2n+1,)``) and ``lambda``.

    Args:
        n: state dimension (static).
        params: alpha, beta, kappa.
        dtype: dtype of the weights; defaults to that of ``params.alpha``.
    """
    if dtype is None:
        dtype = jnp.result_type(params.alpha, params.beta, params.kappa, float)
    lam = ut_lambda(n, params, dtype)
    alpha = jnp.asarray(params.alpha, dtype)
    beta = jnp.asarray(params.beta, dtype)
    rest = jnp.full((2 * n,), 0.5, dtype) / (n + lam)
    w0 = lam / (n + lam)
    mean_weights = jnp.concatenate([w0[None], rest])
    cov_weights = jnp.concatenate([(w0 + 1.0 - alpha**2 + beta)[None], rest])
    return mean_weights, cov_weights, lam


def sigma_points(mean: Array, chol: Array, params: UTParams) -> Array:
    """Sigma points ``(..., 2n+1, n)`` from a mean ``(..., n)`` and a lower factor.

    Batched over any leading axes of ``mean`` and ``chol`` (broadcast together).
    """
    n = mean.shape[-1]
    lam = ut_lambda(n, params, mean.dtype)
    gamma = jnp.sqrt(n + lam).astype(mean.dtype)
    offsets = gamma * jnp.swapaxes(chol, -1, -2)  # rows are the scaled columns of L
    centre = mean[..., None, :]
    return jnp.concatenate([centre, centre + offsets, centre - offsets], axis=-2)


def _default_mean(points: Array, weights: Array) -> Array:
    return jnp.einsum("i,...ij->...j", weights, points)


def _default_residual(a: Array, b: Array) -> Array:
    return a - b


def ut_moments(
    points: Array,
    mean_weights: Array,
    cov_weights: Array,
    mean_fn: Callable[[Array, Array], Array] | None = None,
    residual_fn: Callable[[Array, Array], Array] | None = None,
) -> tuple[Array, Array, Array]:
    """Weighted mean, deviations and covariance of a set of (propagated) points.

    Args:
        points: ``(..., 2n+1, m)``.
        mean_weights, cov_weights: ``(2n+1,)``.
        mean_fn: ``mean_fn(points, weights) -> mean`` for points ``(2n+1, m)``; use
            :func:`jaxslam.core.se2.pose_mean` style functions for angular parts.
        residual_fn: ``residual_fn(a, b) -> a - b`` with angles wrapped.

    Returns:
        ``(mean (..., m), deviations (..., 2n+1, m), cov (..., m, m))``.
    """
    mean_fn = mean_fn or _default_mean
    residual_fn = residual_fn or _default_residual
    batch = points.shape[:-2]
    flat = points.reshape((-1,) + points.shape[-2:])
    mean = jax.vmap(lambda p: mean_fn(p, mean_weights))(flat)
    dev = jax.vmap(jax.vmap(residual_fn, (0, None)))(flat, mean)
    cov = jnp.einsum("i,bij,bik->bjk", cov_weights, dev, dev)
    cov = 0.5 * (cov + jnp.swapaxes(cov, -1, -2))
    m = points.shape[-1]
    return (
        mean.reshape(batch + (m,)),
        dev.reshape(batch + points.shape[-2:]),
        cov.reshape(batch + (m, m)),
    )


def unscented_transform(
    fn: Callable[[Array], Array],
    mean: Array,
    chol: Array,
    params: UTParams,
    *,
    mean_fn: Callable[[Array, Array], Array] | None = None,
    residual_fn: Callable[[Array, Array], Array] | None = None,
    in_residual_fn: Callable[[Array, Array], Array] | None = None,
) -> UTResult:
    """Unscented transform of ``y = fn(x)`` for ``x ~ N(mean, chol chol^T)``.

    ``fn`` maps one point ``(n,)`` to ``(m,)``; it is vmapped over the sigma points
    (and over any leading batch axes of ``mean``/``chol``).

    Args:
        fn: the nonlinear map for one point.
        mean: ``(..., n)``.
        chol: ``(..., n, n)`` lower Cholesky factor of the covariance.
        params: UT scaling.
        mean_fn, residual_fn: output-space mean and residual (angles).
        in_residual_fn: input-space residual used in the cross-covariance.
    """
    n = mean.shape[-1]
    mean_weights, cov_weights, _ = ut_weights(n, params, mean.dtype)
    points = sigma_points(mean, chol, params)
    batch = points.shape[:-2]
    flat_points = points.reshape((-1, 2 * n + 1, n))
    propagated = jax.vmap(jax.vmap(fn))(flat_points)
    propagated = propagated.reshape(batch + propagated.shape[-2:])
    y_mean, y_dev, y_cov = ut_moments(propagated, mean_weights, cov_weights, mean_fn, residual_fn)
    in_residual_fn = in_residual_fn or _default_residual
    x_dev = jax.vmap(jax.vmap(in_residual_fn, (0, None)))(
        flat_points, mean.reshape((-1, n)) * jnp.ones((flat_points.shape[0], 1), mean.dtype)
    ).reshape(points.shape)
    cross = jnp.einsum("i,...ij,...ik->...jk", cov_weights, x_dev, y_dev)
    return UTResult(y_mean, y_cov, cross, points, propagated)
