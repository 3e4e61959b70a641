"""Closed-form 2x2 and 3x3 linear algebra, elementwise on leading batch axes.

XLA on CPU runs ``jnp.linalg.cholesky``/``inv`` on tiny matrices as one LAPACK call
per matrix, and batched products of tiny matrices (``einsum`` over 2 or 3 entries,
or a weighted sum over 11 sigma points) as batched ``dot`` or ``reduce`` kernels
that cost far more than their arithmetic; written out as elementwise arithmetic
(the contraction unrolled over its few entries) they fuse into the surrounding
vectorised code, which is what makes per-particle, per-observation filters fast.
Private to :mod:`jaxslam.feature`.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array


def wsum(weights: Array, values: Array, axis: int = -1) -> Array:
    """``sum_i weights[i] * values[..., i, ...]`` over a short static ``axis``, unrolled."""
    values = jnp.moveaxis(values, axis, 0)
    total = weights[0] * values[0]
    for i in range(1, values.shape[0]):
        total = total + weights[i] * values[i]
    return total


def wsum_product(weights: Array, a: Array, b: Array, axis: int = -1) -> Array:
    """``sum_i weights[i] a_i b_i`` (elementwise products) over a short ``axis``, unrolled,
    slicing before multiplying so no product tensor is formed."""
    a = jnp.moveaxis(a, axis, 0)
    b = jnp.moveaxis(b, axis, 0)
    total = weights[0] * (a[0] * b[0])
    for i in range(1, a.shape[0]):
        total = total + weights[i] * (a[i] * b[i])
    return total


def weighted_outer(weights: Array, a: Array, b: Array) -> Array:
    """``sum_i weights[i] a_i b_i^T`` for rows ``a (..., P, m)``, ``b (..., P, n)``:
    ``(..., m, n)`` (a weighted sigma-point covariance), unrolled over ``P``."""
    return wsum_product(weights, a[..., :, :, None], b[..., :, None, :], axis=-3)


def matmul(a: Array, b: Array) -> Array:
    """``a @ b`` for small matrices ``(..., m, k) @ (..., k, n)``, unrolled over ``k``."""
    total = a[..., :, 0, None] * b[..., None, 0, :]
    for j in range(1, a.shape[-1]):
        total = total + a[..., :, j, None] * b[..., None, j, :]
    return total


def matvec(a: Array, x: Array) -> Array:
    """``a @ x`` for small matrices ``(..., m, k)`` and vectors ``(..., k)``."""
    total = a[..., :, 0] * x[..., 0, None]
    for j in range(1, a.shape[-1]):
        total = total + a[..., :, j] * x[..., j, None]
    return total


def quad2(x: Array, a: Array) -> Array:
    """``x^T a x`` for 2-vectors and symmetric 2x2 matrices."""
    return a[..., 0, 0] * x[..., 0] ** 2 + 2.0 * a[..., 0, 1] * x[..., 0] * x[..., 1] + a[..., 1, 1] * x[..., 1] ** 2


def _tiny(x: Array) -> Array:
    return jnp.asarray(jnp.finfo(x.dtype).tiny, x.dtype)


def chol2(a: Array) -> Array:
    """Lower Cholesky factor of symmetric 2x2 matrices (clamped to stay finite)."""
    a00, a10, a11 = a[..., 0, 0], 0.5 * (a[..., 1, 0] + a[..., 0, 1]), a[..., 1, 1]
    l00 = jnp.sqrt(jnp.maximum(a00, _tiny(a)))
    l10 = a10 / l00
    l11 = jnp.sqrt(jnp.maximum(a11 - l10**2, _tiny(a)))
    zero = jnp.zeros_like(l00)
    return jnp.stack([jnp.stack([l00, zero], -1), jnp.stack([l10, l11], -1)], -2)


def floor_eigenvalues2(a: Array, floor: Array) -> tuple[Array, Array]:
    """Symmetrise 2x2 matrices and lift their smallest eigenvalue to at least ``floor``.

    ``A + max(floor - lambda_min, 0) I``: the eigenvectors are kept and the matrix is
    unchanged (bit for bit, up to symmetrisation) when it already clears the floor.
    With ``floor`` a few ``eps`` times the scale of the matrix the result factors
    reliably in its own precision.

    Returns:
        ``(matrix, lifted)`` where ``lifted`` says the floor was applied.
    """
    a00, a01, a11 = a[..., 0, 0], 0.5 * (a[..., 0, 1] + a[..., 1, 0]), a[..., 1, 1]
    half_gap = 0.5 * (a00 - a11)
    lam_min = 0.5 * (a00 + a11) - jnp.sqrt(half_gap**2 + a01**2)
    shift = jnp.maximum(floor - lam_min, 0.0)
    lifted = jnp.stack([jnp.stack([a00 + shift, a01], -1), jnp.stack([a01, a11 + shift], -1)], -2)
    return lifted, shift > 0


def inv2(a: Array) -> tuple[Array, Array]:
    """Inverse and log-determinant of symmetric positive 2x2 matrices."""
    a00, a01, a11 = a[..., 0, 0], 0.5 * (a[..., 0, 1] + a[..., 1, 0]), a[..., 1, 1]
    det = jnp.maximum(a00 * a11 - a01**2, _tiny(a))
    inv = jnp.stack([jnp.stack([a11, -a01], -1), jnp.stack([-a01, a00], -1)], -2) / det[..., None, None]
    return inv, jnp.log(det)


def chol3(a: Array) -> Array:
    """Lower Cholesky factor of symmetric 3x3 matrices (clamped to stay finite)."""
    tiny = _tiny(a)
    sym = 0.5 * (a + jnp.swapaxes(a, -1, -2))
    l00 = jnp.sqrt(jnp.maximum(sym[..., 0, 0], tiny))
    l10 = sym[..., 1, 0] / l00
    l20 = sym[..., 2, 0] / l00
    l11 = jnp.sqrt(jnp.maximum(sym[..., 1, 1] - l10**2, tiny))
    l21 = (sym[..., 2, 1] - l20 * l10) / l11
    l22 = jnp.sqrt(jnp.maximum(sym[..., 2, 2] - l20**2 - l21**2, tiny))
    zero = jnp.zeros_like(l00)
    return jnp.stack(
        [jnp.stack([l00, zero, zero], -1), jnp.stack([l10, l11, zero], -1), jnp.stack([l20, l21, l22], -1)], -2
    )


def tril_inv3(l: Array) -> Array:
    """Inverse of lower-triangular 3x3 matrices (itself lower triangular)."""
    l00, l10, l11, l20, l21, l22 = l[..., 0, 0], l[..., 1, 0], l[..., 1, 1], l[..., 2, 0], l[..., 2, 1], l[..., 2, 2]
    i00 = 1.0 / l00
    i11 = 1.0 / l11
    i22 = 1.0 / l22
    i10 = -l10 * i00 * i11
    i21 = -l21 * i11 * i22
    i20 = -(l20 * i00 + l21 * i10) * i22
    zero = jnp.zeros_like(i00)
    return jnp.stack(
        [jnp.stack([i00, zero, zero], -1), jnp.stack([i10, i11, zero], -1), jnp.stack([i20, i21, i22], -1)], -2
    )


def tril_logdet(l: Array) -> Array:
    """``log det(L L^T)`` of lower-triangular factors."""
    return 2.0 * jnp.sum(jnp.log(jnp.abs(jnp.diagonal(l, axis1=-2, axis2=-1))), -1)


def det3(a: Array) -> Array:
    """Determinant of 3x3 matrices."""
    return (
        a[..., 0, 0] * (a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1])
        - a[..., 0, 1] * (a[..., 1, 0] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 0])
        + a[..., 0, 2] * (a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0])
    )


def sqrt_logdet3(f: Array) -> Array:
    """``log det(F F^T)`` for any square root ``F`` (3x3)."""
    return 2.0 * jnp.log(jnp.maximum(jnp.abs(det3(f)), _tiny(f)))
