r"""SE(2) poses ``[x, y, theta]`` as arrays; every function broadcasts over leading axes.

* :func:`compose` — :math:`a \oplus b = (a_{xy} + R(a_\theta) b_{xy},\; a_\theta + b_\theta)`
* :func:`inverse` — :math:`\ominus a = (-R(a_\theta)^T a_{xy},\; -a_\theta)`
* :func:`relative` — :math:`\ominus a \oplus b`, the pose of ``b`` seen from ``a``
* :func:`wrap_angle` — to :math:`[-\pi, \pi)`
* :func:`circular_mean`, :func:`pose_mean`, :func:`pose_residual` — means and
  differences that respect the angle's wrap-around, for unscented transforms.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array


def wrap_angle(angle: Array) -> Array:
    """Wrap angles to ``[-pi, pi)``."""
    pi = jnp.asarray(jnp.pi, jnp.result_type(angle, float))
    return jnp.remainder(angle + pi, 2 * pi) - pi


def rotation(theta: Array) -> Array:
    """Rotation matrices ``(..., 2, 2)``."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)


def compose(a: Array, b: Array) -> Array:
    """``a ⊕ b`` for poses ``(..., 3)``."""
    c, s = jnp.cos(a[..., 2]), jnp.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return jnp.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], -1)


def inverse(a: Array) -> Array:
    """``⊖ a`` for poses ``(..., 3)``."""
    c, s = jnp.cos(a[..., 2]), jnp.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return jnp.stack([x, y, wrap_angle(-a[..., 2])], -1)


def relative(a: Array, b: Array) -> Array:
    """The pose of ``b`` in the frame of ``a``: ``⊖ a ⊕ b``."""
    return compose(inverse(a), b)


def transform_points(pose: Array, points: Array) -> Array:
    """Map points ``(..., k, 2)`` from the frame of ``pose`` ``(..., 3)`` to the world."""
    c = jnp.cos(pose[..., 2])[..., None]
    s = jnp.sin(pose[..., 2])[..., None]
    x = pose[..., 0][..., None] + c * points[..., 0] - s * points[..., 1]
    y = pose[..., 1][..., None] + s * points[..., 0] + c * points[..., 1]
    return jnp.stack([x, y], -1)


def circular_mean(angles: Array, weights: Array | None = None, axis: int = -1) -> Array:
    """Weighted circular mean ``atan2(sum w sin, sum w cos)`` along ``axis``."""
    if weights is None:
        weights = jnp.ones_like(angles)
    s = jnp.sum(weights * jnp.sin(angles), axis=axis)
    c = jnp.sum(weights * jnp.cos(angles), axis=axis)
    return jnp.arctan2(s, c)


def angle_mean_about(angles: Array, weights: Array, reference: Array) -> Array:
    """Weighted mean of angles as ``ref + sum w wrap(a - ref)``, wrapped.

    Unlike :func:`circular_mean` this is exact for weights that sum to one but may be
    negative (the zeroth unscented weight), as long as the angles are within pi of
    the reference. Angles ``(..., k)``, weights ``(k,)``, reference ``(...)``.
    """
    return wrap_angle(reference + jnp.sum(weights * wrap_angle(angles - reference[..., None]), -1))


def pose_mean(poses: Array, weights: Array) -> Array:
    """Weighted mean of poses ``(k, 3)``; the heading is averaged about ``poses[0]``.

    Intended as the ``mean_fn`` of an unscented transform over poses, whose zeroth
    sigma point is the centre.
    """
    xy = jnp.einsum("k,kj->j", weights, poses[:, :2])
    theta = angle_mean_about(poses[:, 2], weights, poses[0, 2])
    return jnp.concatenate([xy, theta[None]])


def pose_residual(a: Array, b: Array) -> Array:
    """``a - b`` for poses, heading difference wrapped."""
    d = a - b
    return d.at[..., 2].set(wrap_angle(d[..., 2]))
