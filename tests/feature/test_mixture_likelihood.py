"""The detection/clutter mixture likelihood (``Config.likelihood = "mixture"``): the
per-observation predictive densities against the dense float64 UKF reference, the
weight increment against its formula, and its limit: with P_D -> 1 and one matched
observation it is the paper's gated weight."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.feature.association import associate
from jaxslam.feature.landmarks import LandmarkTable, empty_table, local_slots
from jaxslam.feature.params import Config, Params
from jaxslam.feature.particle import Observation, particle_step

from .conftest import dense_proposal, observe_np

PARAMS = Params(range_std=0.3, bearing_std=math.radians(1.0), max_range=30.0)
POSE = np.array([1.0, -0.5, 0.3])
POSE_SQRT = np.diag([0.05, 0.05, 0.002])
LANDMARK_STD = 0.2


def _table(points, capacity=8):
    t = empty_table(capacity, jnp.float64)
    n = len(points)
    return LandmarkTable(
        t.means.at[:n].set(jnp.asarray(points)),
        t.covs.at[:n].set(LANDMARK_STD**2 * jnp.eye(2)),
        t.evidence,
        t.active.at[:n].set(True),
        jnp.asarray(n, jnp.int32),
    )


def _reference_log_density(landmarks, z):
    """max over landmarks of log N(nu; 0, S), S and nu from filterpy's sigma points."""
    R = np.diag([PARAMS.range_std**2, PARAMS.bearing_std**2])
    cov = POSE_SQRT @ POSE_SQRT.T
    return max(
        dense_proposal(POSE, cov, [lm], [LANDMARK_STD**2 * np.eye(2)], [np.asarray(z)], R)[2] for lm in landmarks
    )


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


LANDMARKS = np.array([[10.0, 2.0], [9.0, -3.0], [14.0, 4.0]])


def _observations():
    return np.stack([
        observe_np(POSE, LANDMARKS[0] + np.array([0.1, -0.05])),  # matched
        observe_np(POSE, LANDMARKS[1] + np.array([0.9, 0.6])),  # outside the gate: its density still counts
        observe_np(POSE, LANDMARKS[2] + np.array([-0.3, 0.2])),
        np.zeros(2),  # padding
    ])


def test_log_density_matches_the_dense_ukf():
    table = _table(LANDMARKS)
    z = _observations()
    mask = np.array([True, True, True, False])

    @jax.jit  # one program, not op by op
    def gather_and_associate(pose, table, z, mask):
        local, valid, _ = local_slots(table, pose[:2], pose[2], PARAMS.max_range, math.pi / 2, 5.0, 6)
        return associate(pose, jnp.asarray(POSE_SQRT), table, local, valid, z, mask, PARAMS, 3)

    out = gather_and_associate(jnp.asarray(POSE), table, jnp.asarray(z), jnp.asarray(mask))
    assert bool(out.matched[0]) and not bool(out.matched[1])
    for j in range(3):
        np.testing.assert_allclose(float(out.log_density[j]), _reference_log_density(LANDMARKS, z[j]), rtol=1e-9,
                                   atol=1e-9)
    assert float(out.log_density[3]) == -np.inf


@functools.partial(jax.jit, static_argnums=4)  # one program per likelihood and shape, not op by op
def _step(table, z, mask, params, likelihood):
    config = Config(num_particles=1, capacity=8, local_size=6, candidates=3, likelihood=likelihood)
    controls = jnp.zeros((1, 3))  # dt = 0: the prediction keeps the pose and its factor
    return particle_step(jax.random.PRNGKey(0), jnp.asarray(POSE), jnp.asarray(POSE_SQRT), table, controls,
                         Observation(jnp.asarray(z), jnp.asarray(mask)), params, config)


def test_mixture_weight_is_the_sum_over_observations():
    table = _table(LANDMARKS)
    z = _observations()
    mask = np.array([True, True, True, False])
    pd = 0.8
    params = PARAMS._replace(detection_probability=pd)
    out = _step(table, z, mask, params, "mixture")
    clutter = math.log((1 - pd) / (PARAMS.max_range * PARAMS.fov))
    expected = sum(np.logaddexp(math.log(pd) + _reference_log_density(LANDMARKS, z[j]), clutter) for j in range(3))
    np.testing.assert_allclose(float(out.log_weight_increment), expected, rtol=1e-9)
    # An observation with no landmark anywhere contributes the clutter term alone.
    empty = _step(_table(np.zeros((0, 2))), z, mask, params, "mixture")
    np.testing.assert_allclose(float(empty.log_weight_increment), 3 * clutter, rtol=1e-12)
    # The gated weight ignores the observations outside the gate.
    gated = _step(table, z, mask, params, "gated")
    assert float(gated.log_weight_increment) != pytest.approx(float(out.log_weight_increment))


def test_mixture_tends_to_the_gated_weight_for_one_matched_observation():
    table = _table(LANDMARKS[:1])
    z = _observations()[:1]
    mask = np.array([True])
    params = PARAMS._replace(detection_probability=1.0 - 1e-13)
    mixture = _step(table, z, mask, params, "mixture")
    gated = _step(table, z, mask, params, "gated")
    assert bool(gated.has_match)
    np.testing.assert_allclose(float(mixture.log_weight_increment), float(gated.log_weight_increment), rtol=1e-9)


def test_unknown_likelihood_is_refused():
    with pytest.raises(ValueError, match="likelihood"):
        Config(likelihood="soft")
