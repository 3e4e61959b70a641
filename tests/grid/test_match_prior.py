"""SRUPF-GM corrector with the motion prior (``match_prior``): a flat or ambiguous
score does not make the pose jump to the edge of the search ellipse."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxslam.grid.matching import ellipse_match
from jaxslam.grid.srupf import predict, prior_penalized
from jaxslam.grid.types import default_params


def _setup(match_prior: float):
    params = default_params(np.linspace(-np.pi / 2, np.pi / 2, 8), match_prior=match_prior, dtype=jnp.float32)
    pose = jnp.zeros(3, jnp.float32)
    sqrt_cov = jnp.eye(3, dtype=jnp.float32) * 1e-3
    prediction = predict(pose, sqrt_cov, jnp.array([1.0, 0.0, 0.0], jnp.float32), params)
    return params, prediction


def _corridor_score(poses):
    """A corridor along x: sharp in y, flat in x except a slight pull towards +x
    (the kind of score that lures a hill climber along a corridor)."""
    x, y = poses[:, 0], poses[:, 1]
    return 100.0 * jnp.exp(-((y - 1e-3) ** 2) / 1e-3) + 2.0 * (x - 1.0)


def _mahalanobis(pose, prediction, params):
    from jaxslam.grid.matching import ellipse_factor

    factor = np.asarray(ellipse_factor(prediction.sqrt_cov, params), np.float64)
    dev = np.asarray(pose, np.float64) - np.asarray(prediction.mean, np.float64)
    return float(np.linalg.norm(np.linalg.solve(factor, dev)))


def test_flat_score_falls_back_towards_the_prediction():
    distances = {}
    for prior in (0.0, 4.0):
        params, prediction = _setup(prior)
        best, _ = ellipse_match(
            prior_penalized(_corridor_score, prediction, params), prediction.mean, prediction.sqrt_cov,
            params, 30, 0, prior_mean=prediction.mean,
        )
        distances[prior] = _mahalanobis(best, prediction, params)
        # Across the corridor the score is sharp: both find y.
        assert abs(float(best[1]) - 1e-3) < 0.02
    # Without the prior the climb runs along the corridor to the ellipse edge (5 sigma);
    # with it the pose stays within about a standard deviation of the prediction.
    assert distances[0.0] > 4.0
    assert distances[4.0] < 1.5


def test_prior_penalty_is_the_mahalanobis_distance():
    params, prediction = _setup(3.0)
    rng = np.random.default_rng(0)
    poses = np.asarray(prediction.mean)[None] + rng.normal(0, 0.1, (5, 3))
    zero = lambda p: jnp.zeros(p.shape[0], p.dtype)  # noqa: E731
    got = np.asarray(prior_penalized(zero, prediction, params)(jnp.asarray(poses, jnp.float32)))
    want = [-1.5 * _mahalanobis(p, prediction, params) ** 2 for p in poses]
    np.testing.assert_allclose(got, want, rtol=1e-3)
    params0, _ = _setup(0.0)
    got0 = np.asarray(prior_penalized(_corridor_score, prediction, params0)(jnp.asarray(poses, jnp.float32)))
    np.testing.assert_allclose(got0, np.asarray(_corridor_score(jnp.asarray(poses, jnp.float32))), rtol=1e-6)
