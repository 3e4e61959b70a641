"""The Victoria Park car model (Guivant & Nebot 2001) against a NumPy float64 reference."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.models.vehicle import CarGeometry, car_motion, car_motion_noisy, centre_speed


def reference_step(pose, speed, steering, dt, L=2.83, H=0.76, A=3.78, B=0.5):
    """UFastSLAM predictACFRu.m equations, written out in NumPy."""
    vc = speed / (1 - math.tan(steering) * H / L)
    x = pose[0] + dt * (vc * math.cos(pose[2]) - vc / L * math.tan(steering) * (A * math.sin(pose[2]) + B * math.cos(pose[2])))
    y = pose[1] + dt * (vc * math.sin(pose[2]) + vc / L * math.tan(steering) * (A * math.cos(pose[2]) - B * math.sin(pose[2])))
    th = pose[2] + vc * dt * math.tan(steering) / L
    return np.array([x, y, (th + math.pi) % (2 * math.pi) - math.pi])


@settings(max_examples=30, deadline=None)
@given(
    x=st.floats(-100, 100),
    y=st.floats(-100, 100),
    th=st.floats(-3.1, 3.1),
    v=st.floats(-1, 7),
    s=st.floats(-0.55, 0.55),
    dt=st.floats(0.001, 0.1),
)
def test_matches_reference(x, y, th, v, s, dt):
    pose = np.array([x, y, th])
    ours = np.asarray(jax.jit(car_motion)(jnp.asarray(pose), jnp.asarray([v, s, dt])))
    np.testing.assert_allclose(ours, reference_step(pose, v, s, dt), atol=1e-9)


def test_padded_rows_are_no_ops(dtype):
    pose = jnp.asarray([3.0, -2.0, 3.0], dtype)
    out = jax.jit(car_motion)(pose, jnp.zeros(3, dtype))
    assert out.dtype == dtype
    np.testing.assert_array_equal(np.asarray(out), np.asarray(pose))
    noisy = jax.jit(car_motion_noisy)(pose, jnp.asarray([1.0, 0.1], dtype), jnp.zeros(3, dtype))
    np.testing.assert_array_equal(np.asarray(noisy), np.asarray(pose))


def test_straight_and_turning(dtype):
    geometry = CarGeometry(2.0, 0.0, 0.0, 0.0)  # rear-axle centre, no encoder offset
    pose = jnp.zeros(3, dtype)
    out = car_motion(pose, jnp.asarray([2.0, 0.0, 0.5], dtype), geometry)
    np.testing.assert_allclose(np.asarray(out), [1.0, 0.0, 0.0], atol=1e-6)
    # Constant steering: yaw rate v tan(s) / L.
    control = jnp.asarray([1.0, 0.2, 0.01], dtype)
    step = jax.jit(lambda p: car_motion(p, control, geometry))
    p = pose
    for _ in range(100):
        p = step(p)
    np.testing.assert_allclose(float(p[2]), 1.0 * math.tan(0.2) / 2.0, rtol=1e-4)


def test_encoder_offset_speeds_up_left_turns():
    g = CarGeometry()
    assert float(centre_speed(1.0, 0.3, g)) > 1.0
    assert float(centre_speed(1.0, -0.3, g)) < 1.0
    assert float(centre_speed(1.0, 0.0, g)) == pytest.approx(1.0)


def test_batched_with_vmap():
    poses = jnp.zeros((5, 3))
    controls = jnp.tile(jnp.asarray([[1.0, 0.1, 0.1]]), (5, 1)).at[2, 2].set(0.0)
    out = jax.vmap(car_motion)(poses, controls)
    assert out.shape == (5, 3)
    np.testing.assert_array_equal(np.asarray(out[2]), 0.0)
    assert float(out[0, 0]) > 0
