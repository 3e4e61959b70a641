"""Range-bearing observation model with a sensor offset, and its inverse."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.models.range_bearing import inverse_observe, observation_residual, observe, sensor_position


@settings(max_examples=50, deadline=None)
@given(
    x=st.floats(-50, 50),
    y=st.floats(-50, 50),
    th=st.floats(-math.pi, math.pi),
    r=st.floats(0.5, 80),
    b=st.floats(-3.1, 3.1),
    ox=st.floats(-4, 4),
    oy=st.floats(-2, 2),
)
def test_inverse_inverts_observation(x, y, th, r, b, ox, oy):
    pose = jnp.asarray([x, y, th])
    offset = jnp.asarray([ox, oy])
    z = jnp.asarray([r, b])
    landmark = jax.jit(inverse_observe)(pose, z, offset)
    back = jax.jit(observe)(pose, landmark, offset)
    np.testing.assert_allclose(float(back[0]), r, rtol=1e-9, atol=1e-9)
    assert abs(float(observation_residual(back, z)[1])) < 1e-8


def test_known_geometry(dtype):
    pose = jnp.asarray([1.0, 2.0, math.pi / 2], dtype)
    offset = jnp.asarray([3.0, 0.5], dtype)
    # Heading +y: the sensor is 3 ahead (+y) and 0.5 left (-x).
    np.testing.assert_allclose(np.asarray(sensor_position(pose, offset)), [0.5, 5.0], atol=1e-6)
    z = observe(pose, jnp.asarray([0.5, 15.0], dtype), offset)
    assert z.dtype == dtype
    np.testing.assert_allclose(np.asarray(z), [10.0, 0.0], atol=1e-5)
    z_left = observe(pose, jnp.asarray([-9.5, 5.0], dtype), offset)
    np.testing.assert_allclose(np.asarray(z_left), [10.0, math.pi / 2], atol=1e-5)


def test_bearing_wraps():
    pose = jnp.asarray([0.0, 0.0, 3.0])
    z = observe(pose, jnp.asarray([-10.0, -0.5]))
    assert -math.pi <= float(z[1]) < math.pi
    d = observation_residual(jnp.asarray([1.0, 3.1]), jnp.asarray([1.0, -3.1]))
    np.testing.assert_allclose(float(d[1]), 6.2 - 2 * math.pi, atol=1e-12)
