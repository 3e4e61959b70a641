r"""Range-bearing observation of a point landmark from a sensor mounted on a vehicle.

The sensor sits at ``offset = (s_x, s_y)`` in the vehicle frame (forward, left) and
looks along the vehicle's heading. For a pose :math:`(x, y, \phi)` the sensor is at

.. math::
    p = (x, y) + R(\phi)\, s ,

and a landmark :math:`m` is observed as

.. math::
    r = \lVert m - p \rVert, \qquad
    \beta = \operatorname{wrap}(\operatorname{atan2}(m_y - p_y, m_x - p_x) - \phi)

(bearing 0 straight ahead, left positive). The inverse model, used to initialise a
landmark from its first observation, is

.. math::
    m = p + r\,(\cos(\phi + \beta), \sin(\phi + \beta)).

For Victoria Park the pose is already the laser's (see :mod:`jaxslam.models.vehicle`),
so the offset is zero. Functions are for one pose and one landmark; ``vmap`` them.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxslam.core.se2 import wrap_angle


def sensor_position(pose: Array, offset: Array) -> Array:
    """World position ``(2,)`` of a sensor at ``offset`` ``(2,)`` in the vehicle frame."""
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    return jnp.stack([pose[0] + c * offset[0] - s * offset[1], pose[1] + s * offset[0] + c * offset[1]])


def observe(pose: Array, landmark: Array, offset: Array | None = None) -> Array:
    """Range and bearing ``(2,)`` of ``landmark`` ``(2,)`` from the sensor of ``pose``."""
    p = pose[:2] if offset is None else sensor_position(pose, offset)
    rng, bearing = observe_unwrapped(p[None], pose[2:3], landmark[None])[0]
    return jnp.stack([rng, wrap_angle(bearing)])


def observe_unwrapped(sensors: Array, headings: Array, landmarks: Array) -> Array:
    r"""Range and bearing ``(n, 2)`` of ``landmarks[i]`` seen from ``sensors[i]`` with
    heading ``headings[i]``, the bearings unwrapped about the first one's:

    .. math::
        eta_i = eta_0 + \operatorname{atan2}(d_0 	imes d_i,\ d_0 \cdot d_i)
        - (\phi_i - \phi_0), \qquad d_i = m_i - p_i,

    which equals :math:`eta_0 + \operatorname{wrap}(eta_i - eta_0)` with one
    arctangent per point and no wrapping. This is the form an unscented transform
    needs (the weighted mean of the sigma points' bearings is then valid); the
    bearings are wrapped only where a residual is formed.

    Args:
        sensors: ``(n, 2)`` sensor positions (:func:`sensor_position`).
        headings: ``(n,)`` headings of the poses.
        landmarks: ``(n, 2)`` landmark positions.
    """
    d = landmarks - sensors
    dx, dy = d[:, 0], d[:, 1]
    rng = jnp.sqrt(dx * dx + dy * dy)
    bearing0 = jnp.arctan2(dy[0], dx[0]) - headings[0]
    bearing = bearing0 + jnp.arctan2(dx[0] * dy - dy[0] * dx, dx[0] * dx + dy[0] * dy) - (headings - headings[0])
    return jnp.stack([rng, bearing], -1)


def inverse_observe(pose: Array, observation: Array, offset: Array | None = None) -> Array:
    """Landmark position ``(2,)`` seen at ``observation = [range, bearing]``."""
    p = pose[:2] if offset is None else sensor_position(pose, offset)
    angle = pose[2] + observation[1]
    return p + observation[0] * jnp.stack([jnp.cos(angle), jnp.sin(angle)])


def observation_residual(a: Array, b: Array) -> Array:
    """``a - b`` for ``[range, bearing]`` rows, bearing wrapped."""
    d = a - b
    return jnp.stack([d[..., 0], wrap_angle(d[..., 1])], -1)
