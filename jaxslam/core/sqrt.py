r"""Square-root covariance tools: triangularisation, rank-1 Cholesky updates, SR-UT.

Everything works on *lower* Cholesky factors, :math:`P = S S^T`.

* :func:`tria` — the QR-based "triangularize" of a stacked factor: for any
  :math:`A \in \mathbb{R}^{n \times m}` it returns lower :math:`S` with
  :math:`S S^T = A A^T` (from the QR decomposition :math:`A^T = Q R`, :math:`S = R^T`).
* :func:`chol_update` — rank-1 update or downdate
  :math:`S' S'^T = S S^T + \sigma\, v v^T`, :math:`\sigma = \pm 1` (the ``cholupdate`` of
  MATLAB), in :math:`O(n^2)`; :func:`chol_update_many` applies the columns of a
  matrix in turn.
* :func:`sqrt_ut_moments` — the square-root unscented transform of van der Merwe &
  Wan, "The square-root unscented Kalman filter for state and parameter-estimation",
  ICASSP 2001, eqs. (20)-(22): a QR of the weighted deviations of points ``1..2n``
  (and of any additive noise factor), then a rank-1 update with the zeroth deviation,
  a downdate when the zeroth covariance weight is negative.

A downdate can lose positive definiteness in finite precision (or because the
requested matrix is not PD). :func:`chol_update` detects this per pivot, clamps the
pivot to a small dtype-aware positive value (so no NaN appears) and reports it
through ``chol_update_checked``.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core.numerics import safe_divide
from jaxslam.core.sigma import _default_mean, _default_residual


def tria(a: Array) -> Array:
    """Lower-triangular ``S`` with ``S S^T = A A^T`` for ``A`` of shape ``(..., n, m)``.

    Works for ``m >= n`` (the usual stacked factor) and ``m < n`` (then ``S`` has
    zero trailing columns). The diagonal of ``S`` is made non-negative.
    """
    n, m = a.shape[-2:]
    if m < n:
        a = jnp.concatenate([a, jnp.zeros(a.shape[:-1] + (n - m,), a.dtype)], axis=-1)
    r = jnp.linalg.qr(jnp.swapaxes(a, -1, -2), mode="r")[..., :n, :n]
    s = jnp.swapaxes(r, -1, -2)
    signs = jnp.where(jnp.diagonal(s, axis1=-2, axis2=-1) < 0, -1.0, 1.0).astype(a.dtype)
    return s * signs[..., None, :]


def _chol_update_one(chol: Array, vec: Array, sign: Array) -> tuple[Array, Array]:
    n = chol.shape[-1]
    dtype = chol.dtype
    tiny = jnp.finfo(dtype).eps
    rows = jnp.arange(n)

    def column(k, carry):
        chol, vec, ok = carry
        lkk = chol[k, k]
        xk = vec[k]
        r2 = lkk * lkk + sign * xk * xk
        floor = tiny * jnp.maximum(lkk * lkk, tiny)
        ok = ok & (r2 > floor)
        r = jnp.sqrt(jnp.maximum(r2, floor))
        # a zero pivot: the rotation is the identity (c = 1, s = 0), with finite gradients
        c = safe_divide(r, lkk, 1.0)
        s = safe_divide(xk, lkk, 0.0)
        below = rows > k
        col = chol[:, k]
        new_col = jnp.where(below, (col + sign * s * vec) / c, col)
        new_col = jnp.where(rows == k, r, new_col)
        vec = jnp.where(below, c * vec - s * new_col, vec)
        chol = jax.lax.dynamic_update_slice_in_dim(chol, new_col[:, None], k, axis=1)
        return chol, vec, ok

    chol, _, ok = jax.lax.fori_loop(0, n, column, (chol, vec, jnp.array(True)))
    return chol, ok


def chol_update_checked(chol: Array, vec: Array, sign: Array | float = 1.0) -> tuple[Array, Array]:
    """Rank-1 update/downdate with a flag that is False where a downdate lost PD.

    Args:
        chol: ``(..., n, n)`` lower Cholesky factor.
        vec: ``(..., n)``.
        sign: +1 for an update, -1 for a downdate (traced, broadcastable to the batch).

    Returns:
        ``(new_chol, ok)``; where ``ok`` is False at least one pivot was clamped.
    """
    sign = jnp.asarray(sign, chol.dtype)
    fn = jnp.vectorize(_chol_update_one, signature="(n,n),(n),()->(n,n),()")
    return fn(chol, vec, sign)


def chol_update(chol: Array, vec: Array, sign: Array | float = 1.0) -> Array:
    """Lower factor of ``chol chol^T + sign * vec vec^T`` (batched over leading axes)."""
    return chol_update_checked(chol, vec, sign)[0]


def chol_update_many(chol: Array, vecs: Array, sign: Array | float = 1.0) -> Array:
    """Apply :func:`chol_update` with each row of ``vecs`` ``(..., k, n)`` in turn.

    Equivalent to the factor of ``chol chol^T + sign * vecs^T vecs``.
    """
    return chol_update_many_checked(chol, vecs, sign)[0]


def chol_update_many_checked(
    chol: Array, vecs: Array, sign: Array | float = 1.0
) -> tuple[Array, Array]:
    """:func:`chol_update_many` with the positive-definiteness flag."""
    sign = jnp.asarray(sign, chol.dtype)

    def one(c, vs, sg):
        def body(carry, v):
            c, ok = carry
            c, ok_v = _chol_update_one(c, v, sg)
            return (c, ok & ok_v), None

        (c, ok), _ = jax.lax.scan(body, (c, jnp.array(True)), vs)
        return c, ok

    fn = jnp.vectorize(one, signature="(n,n),(k,n),()->(n,n),()")
    return fn(chol, vecs, sign)


def sqrt_ut_moments(
    points: Array,
    mean_weights: Array,
    cov_weights: Array,
    mean_fn: Callable[[Array, Array], Array] | None = None,
    residual_fn: Callable[[Array, Array], Array] | None = None,
    noise_chol: Array | None = None,
) -> tuple[Array, Array, Array]:
    """Square-root unscented moments of propagated points ``(..., 2n+1, m)``.

    ``S = tria([sqrt(W^c_1) (Y_1..2n - y), noise_chol])`` followed by
    ``S = cholupdate(S, sqrt(|W^c_0|) (Y_0 - y), sign(W^c_0))``.

    Returns:
        ``(mean (..., m), chol (..., m, m), deviations (..., 2n+1, m))`` where
        ``chol chol^T`` equals the dense UT covariance (plus ``noise_chol noise_chol^T``).
    """
    mean_fn = mean_fn or _default_mean
    residual_fn = residual_fn or _default_residual
    batch = points.shape[:-2]
    npts, m = points.shape[-2:]
    flat = points.reshape((-1, npts, m))
    mean = jax.vmap(lambda p: mean_fn(p, mean_weights))(flat)
    dev = jax.vmap(jax.vmap(residual_fn, (0, None)))(flat, mean)
    # W^c_i, i >= 1, are equal and positive whenever n + lambda > 0.
    weighted = jnp.sqrt(cov_weights[1:])[None, :, None] * dev[:, 1:, :]  # (b, 2n, m)
    stacked = jnp.swapaxes(weighted, -1, -2)  # (b, m, 2n): columns are deviations
    if noise_chol is not None:
        noise = jnp.broadcast_to(noise_chol, batch + (m, m)).reshape((-1, m, m))
        stacked = jnp.concatenate([stacked, noise.astype(stacked.dtype)], axis=-1)
    chol = tria(stacked)
    w0 = cov_weights[0]
    chol = chol_update(chol, jnp.sqrt(jnp.abs(w0)) * dev[:, 0, :], jnp.sign(w0))
    return (
        mean.reshape(batch + (m,)),
        chol.reshape(batch + (m, m)),
        dev.reshape(batch + (npts, m)),
    )
