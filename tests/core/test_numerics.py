"""NaN-safe numerics: forward values of the plain functions where they are defined,
finite gradients at the singular points, and jacfwd = jacrev = finite differences
(float64) for what calibration differentiates, at theta = 0, at zero motion and at a
zero pivot."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.core.numerics import safe_atan2, safe_divide, safe_norm, safe_sqrt
from jaxslam.core.sigma import UTParams
from jaxslam.core.sqrt import chol_update
from jaxslam.models.odometry import motion_noise_sqrt, polar_increment, sqrt_unscented_predict


def finite_difference(f, x, step=1e-6):
    x = np.asarray(x, np.float64)
    columns = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = step
        columns.append((np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * step))
    return np.stack(columns, -1)


def assert_derivatives_agree(f, x, fd=True, atol=1e-6):
    x = jnp.asarray(x, jnp.float64)
    forward, reverse = np.asarray(jax.jacfwd(f)(x)), np.asarray(jax.jacrev(f)(x))
    assert np.all(np.isfinite(forward)) and np.all(np.isfinite(reverse))
    np.testing.assert_allclose(forward, reverse, atol=1e-12)
    if fd:
        np.testing.assert_allclose(forward, finite_difference(f, x).reshape(forward.shape), atol=atol)


def test_values_are_the_plain_functions_where_defined():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=50), rng.normal(size=50)
    x, y = jnp.asarray(x), jnp.asarray(y)
    np.testing.assert_array_equal(safe_divide(x, y), x / y)
    np.testing.assert_array_equal(safe_sqrt(x * x), jnp.sqrt(x * x))
    np.testing.assert_array_equal(safe_atan2(y, x), jnp.arctan2(y, x))
    np.testing.assert_allclose(safe_norm(np.stack([x, y], -1)), np.hypot(x, y), rtol=1e-15)
    assert float(safe_divide(1.0, 0.0, 7.0)) == 7.0 and float(safe_atan2(0.0, 0.0)) == 0.0


@pytest.mark.parametrize("f, x", [
    (lambda v: safe_divide(v[0], v[1]), [1.0, 0.0]),
    (lambda v: safe_sqrt(v[0]), [0.0]),
    (lambda v: safe_norm(v), [0.0, 0.0]),
    (lambda v: safe_atan2(v[0], v[1]), [0.0, 0.0]),
])
def test_gradients_at_the_singular_points_are_finite(f, x):
    """The plain functions give NaN or inf here; the safe ones a finite gradient."""
    assert_derivatives_agree(f, x, fd=False)


def test_polar_increment_at_zero_motion_and_theta_zero():
    """Zero motion is the singular point of the length and the bearing (atan2(0, 0));
    a straight step and a turn in place are smooth in the heading."""
    def polar(u):
        p = polar_increment(u)
        return jnp.stack([p.length, p.rotation, p.bearing])

    assert_derivatives_agree(polar, [0.0, 0.0, 0.0], fd=False)  # |d| has no derivative at 0
    assert_derivatives_agree(polar, [0.3, 0.1, 0.0])  # theta = 0
    assert_derivatives_agree(polar, [-0.3, 0.05, 0.2])  # backwards


@pytest.mark.parametrize("increment", [[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.0, 0.3]])
def test_prediction_factor_in_the_noise_levels(increment):
    """What grid calibration differentiates: the square-root unscented prediction's
    factor as a function of Q's five levels, at zero motion, straight (theta = 0) and
    turning in place, from a pose at theta = 0."""
    pose = jnp.zeros(3, jnp.float64)
    sqrt_cov = jnp.diag(jnp.array([0.02, 0.03, 0.01]))
    u = jnp.asarray(increment, jnp.float64)

    def factor(levels):
        noise = motion_noise_sqrt(u, *levels)
        prediction = sqrt_unscented_predict(pose, sqrt_cov, u, noise, UTParams(1.0, 2.0, 0.0))
        return prediction.sqrt_cov @ prediction.sqrt_cov.T  # the covariance: smooth in the levels

    assert_derivatives_agree(factor, [0.05, 0.02, 0.1, 0.1, 0.05])


def test_rank_one_update_at_a_zero_pivot():
    """A zero pivot in the factor (a state the prediction has not spread yet): the
    update is defined (the rotation is the identity there) and its gradient finite."""
    chol = jnp.array([[0.0, 0.0, 0.0], [0.1, 0.5, 0.0], [0.2, 0.1, 0.4]], jnp.float64)

    def updated(vec):
        return chol_update(chol, vec, 1.0)

    assert_derivatives_agree(updated, [0.0, 0.3, 0.1], fd=False)
    full = jnp.array([[0.6, 0.0, 0.0], [0.1, 0.5, 0.0], [0.2, 0.1, 0.4]], jnp.float64)
    assert_derivatives_agree(lambda v: chol_update(full, v, 1.0), [0.2, 0.3, 0.1])
