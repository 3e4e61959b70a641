"""SE(2) helpers against matrix (homogeneous transform) arithmetic in NumPy."""

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.core import se2


def as_matrix(p):
    c, s = np.cos(p[2]), np.sin(p[2])
    return np.array([[c, -s, p[0]], [s, c, p[1]], [0, 0, 1]])


def from_matrix(m):
    return np.array([m[0, 2], m[1, 2], np.arctan2(m[1, 0], m[0, 0])])


pose = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-10, 10)).map(np.array)


@settings(max_examples=50, deadline=None)
@given(pose, pose)
def test_compose_inverse_relative_match_matrices(a, b):
    got = np.asarray(se2.compose(jnp.asarray(a), jnp.asarray(b)))
    ref = from_matrix(as_matrix(a) @ as_matrix(b))
    np.testing.assert_allclose(got[:2], ref[:2], atol=1e-9)
    assert abs(np.asarray(se2.wrap_angle(got[2] - ref[2]))) < 1e-9
    inv = np.asarray(se2.inverse(jnp.asarray(a)))
    ref_inv = from_matrix(np.linalg.inv(as_matrix(a)))
    np.testing.assert_allclose(inv[:2], ref_inv[:2], atol=1e-9)
    rel = np.asarray(se2.relative(jnp.asarray(a), jnp.asarray(b)))
    back = np.asarray(se2.compose(jnp.asarray(a), jnp.asarray(rel)))
    np.testing.assert_allclose(back[:2], b[:2], atol=1e-8)
    assert abs(float(se2.wrap_angle(back[2] - b[2]))) < 1e-9


def test_wrap_angle_range(dtype):
    a = jnp.asarray(np.linspace(-20, 20, 1001), dtype)
    w = np.asarray(se2.wrap_angle(a))
    assert w.dtype == dtype
    assert np.all(w >= -np.pi - 1e-6) and np.all(w < np.pi + 1e-6)
    np.testing.assert_allclose(np.cos(w), np.cos(np.asarray(a)), atol=1e-5)


def test_transform_points_batched():
    poses = jnp.array([[1.0, 2.0, 0.5], [0.0, 0.0, -1.0]])
    pts = jnp.array([[[1.0, 0.0], [0.0, 1.0]], [[2.0, 0.0], [0.0, 0.0]]])
    got = np.asarray(se2.transform_points(poses, pts))
    for i in range(2):
        m = as_matrix(np.asarray(poses[i]))
        for j in range(2):
            np.testing.assert_allclose(got[i, j], (m @ np.r_[np.asarray(pts[i, j]), 1])[:2], atol=1e-12)


def test_circular_means_across_pi():
    angles = jnp.array([np.pi - 0.1, -np.pi + 0.1])
    assert abs(abs(float(se2.circular_mean(angles))) - np.pi) < 1e-9
    w = jnp.array([0.5, 0.5])
    assert abs(abs(float(se2.angle_mean_about(angles, w, angles[0]))) - np.pi) < 1e-9
    # negative weights (unscented zeroth weight) summing to one
    w3 = jnp.array([-1.0, 1.0, 1.0])
    angles3 = jnp.array([3.0, 3.1, -3.1])
    expected = 3.0 + (-0.0 + 0.1 + (2 * np.pi - 6.1))
    assert abs(float(se2.wrap_angle(se2.angle_mean_about(angles3, w3, angles3[0]) - expected))) < 1e-9


def test_pose_residual_wraps_heading():
    r = np.asarray(se2.pose_residual(jnp.array([1.0, 1.0, 3.1]), jnp.array([0.0, 0.0, -3.1])))
    np.testing.assert_allclose(r, [1.0, 1.0, 6.2 - 2 * np.pi], atol=1e-12)
