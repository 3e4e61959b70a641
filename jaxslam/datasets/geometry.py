"""Host-side SE(2) in float64 NumPy, for loaders, simulators and metrics.

The jitted kernels use :mod:`jaxslam.core.se2`; this is its NumPy twin for code that
must not depend on JAX's dtype settings (log parsing, ground truth, error metrics),
where poses are kept in float64 whatever ``jax_enable_x64`` says.
"""

from __future__ import annotations

import numpy as np

__all__ = ["se2_between", "se2_compose", "se2_exp", "se2_inverse", "se2_log", "wrap_angle"]


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


def _arc_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sin(t)/t`` and ``(1 - cos(t))/t``, by their series near ``t = 0``."""
    small = np.abs(theta) < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, theta / 2.0 - theta**3 / 24.0, (1.0 - np.cos(t)) / t)
    return a, b


def se2_exp(twist: np.ndarray) -> np.ndarray:
    r"""The pose reached from the origin by moving at the constant body velocity
    ``(v_x, v_y, omega)`` for unit time (an arc), for (..., 3) twists:

    .. math::
        x = a v_x - b v_y, \quad y = b v_x + a v_y, \quad \theta = \omega, \qquad
        a = \frac{\sin\omega}{\omega}, \ b = \frac{1 - \cos\omega}{\omega}
    """
    twist = np.asarray(twist, dtype=np.float64)
    a, b = _arc_coefficients(twist[..., 2])
    vx, vy = twist[..., 0], twist[..., 1]
    return np.stack([a * vx - b * vy, b * vx + a * vy, wrap_angle(twist[..., 2])], axis=-1)


def se2_log(pose: np.ndarray) -> np.ndarray:
    """The twist of :func:`se2_exp` that reaches ``pose`` (heading in ``[-pi, pi)``),
    for (..., 3) poses: ``se2_exp(alpha * se2_log(p))`` is the steady motion's pose
    after the fraction ``alpha`` of its time."""
    pose = np.asarray(pose, dtype=np.float64)
    theta = wrap_angle(pose[..., 2])
    a, b = _arc_coefficients(theta)
    det = a * a + b * b
    x, y = pose[..., 0], pose[..., 1]
    return np.stack([(a * x + b * y) / det, (a * y - b * x) / det, theta], axis=-1)
