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
    d = landmark - p
    return jnp.stack([jnp.sqrt(d[0] ** 2 + d[1] ** 2), wrap_angle(jnp.arctan2(d[1], d[0]) - pose[2])])


def inverse_observe(pose: Array, observation: Array, offset: Array | None = None) -> Array:
    """Landmark position ``(2,)`` seen at ``observation = [range, bearing]``."""
    p = pose[:2] if offset is None else sensor_position(pose, offset)
    angle = pose[2] + observation[1]
    return p + observation[0] * jnp.stack([jnp.cos(angle), jnp.sin(angle)])


def observation_residual(a: Array, b: Array) -> Array:
    """``a - b`` for ``[range, bearing]`` rows, bearing wrapped."""
    d = a - b
    return jnp.stack([d[..., 0], wrap_angle(d[..., 1])], -1)
