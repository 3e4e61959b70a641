r"""NaN-safe elementary functions: the double ``where`` in one place.

``jnp.where(c, f(x), g)`` does not protect a gradient: both branches are
differentiated, and where ``f`` is singular (``1/0``, ``sqrt`` at 0, ``atan2(0, 0)``)
its cotangent is ``inf * 0 = NaN`` even though the branch is not taken. The safe form
swaps a harmless argument in *before* ``f`` (as jaxlie does):

.. math:: \operatorname{safe}(x) = \begin{cases} f(x) & d(x) \\ g & \neg d(x) \end{cases}
    \quad\text{computed as}\quad
    \texttt{where}(d, f(\texttt{where}(d, x, x_{safe})), g),

so forward values are those of ``f`` wherever it is defined, and gradients are finite
everywhere (zero on the fallback side). The library never sets ``jax_enable_x64``;
these functions follow the dtype of their inputs.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array
from jax.scipy.special import logsumexp


def safe_divide(numerator: Array, denominator: Array, fallback: Array | float = 0.0,
                defined: Array | None = None) -> Array:
    """``numerator / denominator`` where ``defined`` (default ``denominator != 0``),
    ``fallback`` elsewhere; finite gradients on both sides."""
    defined = denominator != 0 if defined is None else defined
    safe = jnp.where(defined, denominator, jnp.ones_like(denominator))
    return jnp.where(defined, numerator / safe, fallback)


def safe_sqrt(x: Array) -> Array:
    """``sqrt(x)`` for ``x > 0``, 0 elsewhere; the gradient at 0 is 0, not ``inf``/NaN."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, jnp.ones_like(x))), jnp.zeros_like(x))


def safe_norm(x: Array, axis: int = -1) -> Array:
    """The Euclidean norm along ``axis`` (:func:`safe_sqrt` of the sum of squares)."""
    return safe_sqrt(jnp.sum(x * x, axis=axis))


def safe_atan2(y: Array, x: Array, defined: Array | None = None, fallback: Array | float = 0.0) -> Array:
    """``atan2(y, x)`` where ``defined`` (default: not both 0), ``fallback`` elsewhere;
    finite gradients at the origin."""
    defined = (x != 0) | (y != 0) if defined is None else defined
    return jnp.where(defined, jnp.arctan2(jnp.where(defined, y, jnp.zeros_like(y)),
                                          jnp.where(defined, x, jnp.ones_like(x))), fallback)


def normalize_log_weights(log_weights: Array) -> Array:
    """Log-weights that sum to one in linear space (uniform if all underflow or NaN)."""
    clean = jnp.where(jnp.isnan(log_weights), -jnp.inf, log_weights)
    total = logsumexp(clean)
    degenerate = ~jnp.isfinite(total)
    n = log_weights.shape[-1]
    uniform = jnp.full_like(clean, -jnp.log(jnp.asarray(n, clean.dtype)))
    safe_total = jnp.where(degenerate, 0.0, total)
    return jnp.where(degenerate, uniform, clean - safe_total)


__all__ = ["normalize_log_weights", "safe_atan2", "safe_divide", "safe_norm", "safe_sqrt"]
