"""Host-side SE(2) in float64 NumPy, for loaders, simulators and metrics.

The jitted kernels use :mod:`jaxslam.core.se2`; this is its NumPy twin for code that
must not depend on JAX's dtype settings (log parsing, ground truth, error metrics),
where poses are kept in float64 whatever ``jax_enable_x64`` says.
"""

from __future__ import annotations

import numpy as np

__all__ = ["se2_between", "se2_compose", "se2_inverse", "wrap_angle"]


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped into ``[-pi, pi)``."""
    return (np.asarray(angle, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


def se2_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a (+) b`` for broadcastable (..., 3) poses."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            wrap_angle(a[..., 2] + b[..., 2]),
        ],
        axis=-1,
    )


def se2_inverse(a: np.ndarray) -> np.ndarray:
    """``a^-1`` for (..., 3) poses."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            -c * a[..., 0] - s * a[..., 1],
            s * a[..., 0] - c * a[..., 1],
            wrap_angle(-a[..., 2]),
        ],
        axis=-1,
    )


def se2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 (+) b``: pose ``b`` in the frame of pose ``a``, for (..., 3) poses."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1
    )
