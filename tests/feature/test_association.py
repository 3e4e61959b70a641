"""Data association, landmark tables and local candidate sets on constructed cases
(the association decisions in float64 and in the production float32)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.feature.association import associate
from jaxslam.feature.landmarks import LandmarkTable, empty_table, free_slots, local_slots, prefix_count
from jaxslam.feature.params import Params

from .conftest import observe_np

PARAMS = Params(range_std=0.3, bearing_std=math.radians(1.0), max_range=30.0)


def _table(points, capacity=8, std=0.2, dtype=np.float64):
    t = empty_table(capacity, dtype)
    n = len(points)
    means = t.means.at[:n].set(jnp.asarray(points, dtype))
    covs = t.covs.at[:n].set(std**2 * jnp.eye(2, dtype=dtype))
    active = t.active.at[:n].set(True)
    return LandmarkTable(means, covs, t.evidence, active, jnp.asarray(n, jnp.int32))


def _run(table, pose, observations, mask=None, candidates=2):
    dtype = table.means.dtype
    pose = jnp.asarray(pose, dtype)
    sqrt = jnp.diag(jnp.asarray([0.05, 0.05, 0.002], dtype))
    obs = jnp.asarray(observations, dtype)
    mask = jnp.ones(obs.shape[0], bool) if mask is None else jnp.asarray(mask)
    local, valid, _ = local_slots(table, pose[:2], pose[2], PARAMS.max_range, math.pi / 2, 5.0, 6)
    return jax.jit(associate, static_argnames="num_candidates")(
        pose, sqrt, table, local, valid, obs, mask, PARAMS, num_candidates=candidates
    )


def test_picks_the_right_landmark(dtype):
    # Three trees 2.5 m apart across the line of sight; observe the middle one.
    lms = np.array([[10.0, -2.5], [10.0, 0.0], [10.0, 2.5]])
    table = _table(lms, dtype=dtype)
    pose = np.zeros(3)
    z = observe_np(pose, lms[1] + np.array([0.1, -0.05]))
    out = _run(table, pose, [z])
    assert bool(out.matched[0])
    assert int(out.slots[0]) == 1
    assert not bool(out.new[0])
    assert out.landmark_means.dtype == dtype
    np.testing.assert_allclose(np.asarray(out.landmark_means[0]), lms[1])


def test_new_ignored_and_padding(dtype):
    lms = np.array([[10.0, 0.0]])
    table = _table(lms, dtype=dtype)
    pose = np.zeros(3)
    far = observe_np(pose, np.array([10.0, 8.0]))  # far from everything: new landmark
    between = observe_np(pose, np.array([10.0, 0.9]))  # outside the gate, not far enough: ignored
    out = _run(table, pose, [far, between, [0.0, 0.0]], mask=[True, True, False])
    assert not bool(out.matched[0]) and bool(out.new[0])
    assert not bool(out.matched[1]) and not bool(out.new[1])
    assert float(out.distance_sq[1]) > PARAMS.gate_associate
    assert float(out.distance_sq[1]) < PARAMS.gate_new
    assert not bool(out.matched[2]) and not bool(out.new[2])


def test_one_landmark_one_observation(dtype):
    lms = np.array([[12.0, 1.0]])
    table = _table(lms, dtype=dtype)
    pose = np.zeros(3)
    close = observe_np(pose, lms[0] + np.array([0.02, 0.0]))
    worse = observe_np(pose, lms[0] + np.array([0.3, 0.1]))
    out = _run(table, pose, [worse, close])
    assert bool(out.matched[1]) and int(out.slots[1]) == 0
    assert not bool(out.matched[0])


def test_empty_map_makes_everything_new(dtype):
    table = empty_table(8, dtype)
    out = _run(table, np.zeros(3), [[5.0, 0.1], [7.0, -0.3]])
    assert np.all(np.asarray(out.new))
    assert not np.any(np.asarray(out.matched))


def test_local_slots_footprint_and_overflow():
    pts = np.array([[5.0, 0.0], [-20.0, 0.0], [0.0, 29.0], [50.0, 0.0], [10.0, 1.0], [3.0, -3.0]])
    table = _table(pts, capacity=8)
    slots, valid, overflow = local_slots(table, jnp.zeros(2), 0.0, 30.0, math.pi / 2, 2.0, 4)
    kept = set(np.asarray(slots)[np.asarray(valid)].tolist())
    assert kept == {0, 2, 4, 5}  # behind (1) and beyond range (3) left out
    assert int(overflow) == 0
    slots, valid, overflow = local_slots(table, jnp.zeros(2), 0.0, 30.0, math.pi / 2, 2.0, 2)
    assert np.asarray(slots).tolist() == [0, 2] and int(overflow) == 2


def test_prefix_count_and_free_slots():
    rng = np.random.default_rng(1)
    mask = rng.random(512) < 0.3
    np.testing.assert_array_equal(np.asarray(prefix_count(jnp.asarray(mask))), np.cumsum(mask))
    np.testing.assert_array_equal(np.asarray(prefix_count(jnp.asarray(mask[:100]))), np.cumsum(mask[:100]))
    active = jnp.asarray([True, False, True, False, False, True])
    np.testing.assert_array_equal(np.asarray(free_slots(active, 4)), [1, 3, 4, 6])
