"""Monte Carlo localization: its parts against references, and runs on simulated worlds."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.core.resampling import effective_sample_size
from jaxslam.grid.mapfile import segment_map
from jaxslam.grid.types import Scan
from jaxslam.localization.experiment import localize, make_filter_inputs, summary, tracking_errors
from jaxslam.localization.monte_carlo import (MclConfig, bin_keys, count_bins, kld_bound, mcl, mode_estimate, pose_bins,
                                              sample_free_poses, tempering_power)
from tests.localization.worlds import BOUNDS, crate_world, kidnapped_poses, laser_log, ring_poses

CHUNK = 128


def test_kld_bound_is_foxs_formula():
    for k in (2, 5, 40, 1000):
        z, eps = 2.326, 0.02
        expected = (k - 1) / (2 * eps) * (1 - 2 / (9 * (k - 1)) + math.sqrt(2 / (9 * (k - 1))) * z) ** 3
        assert float(kld_bound(jnp.asarray(k), eps, z)) == pytest.approx(expected, rel=1e-5)
    assert float(kld_bound(jnp.asarray(1), 0.02, 2.326)) == 1.0


_count_bins = jax.jit(count_bins)
_pose_bins = jax.jit(pose_bins)
_tempering_power = jax.jit(tempering_power)
_ess = jax.jit(effective_sample_size)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.05, 3.0), st.floats(0.0, 1.0))
def test_count_bins_counts_distinct_bins(seed, extent, keep):
    rng = np.random.default_rng(seed)
    poses = rng.uniform([-extent, -extent, -np.pi], [extent, extent, np.pi], (128, 3)).astype(np.float32)
    mask = rng.random(128) < keep
    bins = np.asarray(_pose_bins(jnp.asarray(poses), 0.5, math.radians(10)))
    expected = len({tuple(b) for b in bins[mask]})
    assert int(_count_bins(jnp.asarray(bins), jnp.asarray(mask))) == expected


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.05, 0.9))
def test_tempering_power_keeps_the_ess_and_is_the_largest(seed, fraction):
    rng = np.random.default_rng(seed)
    n = 64
    log_w = jnp.asarray(np.log(rng.dirichlet(np.ones(n))), jnp.float32)
    loglik = jnp.asarray(rng.normal(0, 30, n), jnp.float32)
    lam = float(_tempering_power(log_w, loglik, 1.0, fraction * n))
    ess = float(_ess(log_w + lam * loglik))
    if lam < 1.0 and lam > 1e-6 * 1.01:
        assert ess >= fraction * n * (1 - 1e-3)
        assert float(_ess(log_w + min(1.0, lam * 1.01) * loglik)) < fraction * n * (1 + 1e-3)
    elif lam == 1.0:
        assert ess >= fraction * n * (1 - 1e-4)


def test_mode_estimate_takes_the_heavier_mode_not_the_mean():
    rng = np.random.default_rng(0)
    a = np.c_[rng.normal(1.0, 0.05, (60, 2)), rng.normal(3.1, 0.02, 60)]  # near the +-pi wrap
    b = np.c_[rng.normal(-4.0, 0.05, (40, 2)), rng.normal(0.0, 0.02, 40)]
    poses = jnp.asarray(np.concatenate([a, b]), jnp.float32)
    estimate, weight, spread = jax.jit(mode_estimate)(poses, jnp.zeros(100), 0.5, math.radians(10))
    np.testing.assert_allclose(np.asarray(estimate)[:2], a[:, :2].mean(0), atol=0.03)
    assert abs(np.angle(np.exp(1j * (float(estimate[2]) - 3.1)))) < 0.02
    assert float(weight) == pytest.approx(0.6, abs=0.02) and float(spread) > 3.0


@pytest.fixture(scope="module")
def world():
    walls = crate_world()
    return walls, segment_map(walls, BOUNDS, 0.05)


def _first_good(trajectory, truth, metres=0.5, degrees=10.0):
    distance, heading = tracking_errors(trajectory, truth)
    bad = np.flatnonzero((distance >= metres) | (heading >= math.radians(degrees)))
    return 0 if bad.size == 0 else int(bad[-1]) + 1


def test_tracks_from_a_known_start(world):
    walls, grid = world
    log = laser_log(walls, ring_poses()[:2 * CHUNK], seed=3)
    result = localize(log, grid, particles=2000, seed=0, initial_pose=log.true_poses[0], chunk=CHUNK)
    distance, heading = tracking_errors(result.trajectory, log.true_poses)
    assert distance.mean() < 0.05 and distance.max() < 0.15
    assert np.degrees(heading).mean() < 1.0
    info = result.info
    assert info["particles"].max() <= 2000 and info["particles"][-1] < 1000  # the cloud shrank (KLD)
    record = summary(result)
    assert record["converged"] and record["injections"] == 0


def test_converges_from_a_uniform_start(world):
    walls, grid = world
    log = laser_log(walls, ring_poses()[:CHUNK], seed=0)
    result = localize(log, grid, particles=40000, seed=0, chunk=CHUNK)
    start = _first_good(result.trajectory, log.true_poses)
    assert start < 60  # within 12 s of log time, and then it stays
    assert result.info["particles"][0] == 40000 and result.info["particles"][-1] < 5000
    assert summary(result)["converged"]


def test_bin_keys_tell_apart_the_bins_of_a_building():
    ix, iy, it = np.meshgrid(np.arange(-300, 300, 7), np.arange(-300, 300, 5), np.arange(0, 36), indexing="ij")
    bins = np.stack([ix.ravel(), iy.ravel(), it.ravel()], -1).astype(np.int32)
    keys = np.asarray(bin_keys(jnp.asarray(bins)))
    assert np.unique(keys).size == bins.shape[0] and keys.min() >= 0 and keys.max() < 2**30


def _filter(world, capacity=512, block=64, **overrides):
    walls, grid = world
    log = laser_log(walls, ring_poses()[:2], seed=0)
    config, params = make_filter_inputs(log, grid, capacity, overrides=overrides, min_particles=100)
    config = MclConfig(capacity=capacity, num_beams=config.num_beams, max_beams=config.max_beams,
                       min_particles=config.min_particles, block=block)
    scan = Scan(jnp.asarray(log.ranges[0]), jnp.asarray(log.valid[0]), jnp.zeros((), jnp.float32))
    return mcl(config, params), params, log, scan


def _in_use(state, num, filler):
    """``state`` with only the first ``num`` slots in use, the others holding ``filler``."""
    slots = jnp.arange(state.poses.shape[0])
    weights = jnp.where(slots < num, -jnp.log(float(num)), -jnp.inf)
    poses = jnp.where((slots < num)[:, None], state.poses, filler)
    return state._replace(poses=poses, log_weights=weights.astype(state.log_weights.dtype),
                          num_active=jnp.asarray(num, jnp.int32))


@pytest.mark.parametrize("jit", [True, pytest.param(False, marks=pytest.mark.long)], ids=["jit", "no-jit"])
@pytest.mark.parametrize("ess_threshold", [0.0, 1.1], ids=["no-resampling", "resampling"])
@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), num=st.integers(100, 500))
def test_slots_not_in_use_change_nothing(world, jit, ess_threshold, seed, num):
    filt, params, log, scan = _filter(world, ess_threshold=ess_threshold)
    step = jax.jit(filt.step) if jit else filt.step
    state = filt.init(jax.random.key(seed), jnp.asarray(log.true_poses[0], jnp.float32), jnp.asarray([0.3, 0.3, 0.1]))
    control = jnp.asarray([0.1, 0.0, 0.02], jnp.float32)
    key = jax.random.key(seed + 1)
    garbage = np.random.default_rng(seed).uniform(-1e6, 1e6, (512, 3)).astype(np.float32)
    results = [step(key, _in_use(state, num, filler), control, scan)
               for filler in (jnp.nan, jnp.asarray(garbage), 0.0)]
    (ref_state, ref_info), others = results[0], results[1:]
    n = int(ref_state.num_active)
    for new_state, info in others:
        assert int(new_state.num_active) == n
        np.testing.assert_array_equal(np.asarray(new_state.poses[:n]), np.asarray(ref_state.poses[:n]))
        np.testing.assert_array_equal(np.asarray(new_state.log_weights), np.asarray(ref_state.log_weights))
        for field in ("estimate", "cluster_weight", "spread", "ess", "occupied_bins", "resampled", "injected"):
            np.testing.assert_array_equal(np.asarray(getattr(info, field)), np.asarray(getattr(ref_info, field)))
    assert np.all(np.isfinite(np.asarray(ref_state.poses[:n]))) and np.isfinite(np.asarray(ref_info.estimate)).all()
    assert bool(ref_info.resampled) == (ess_threshold > 1)


def _two_clusters(state, mass_near):
    """``state`` holding two clusters, 256 particles in use: 200 spread over several bins
    around (1, 1, 0.3) with weight ``mass_near`` in all, 56 in one bin 5 m away with the
    rest, NaN in the slots not in use; no odometry travelled since the last measurement
    (the step measures nothing)."""
    rng = np.random.default_rng(0)
    near = np.c_[rng.normal(1.0, 0.3, (200, 2)), rng.normal(0.3, 0.05, 200)]
    far = np.c_[rng.normal([-4.0, 2.0], 0.02, (56, 2)), rng.normal(1.0, 0.01, 56)]
    poses = np.full((state.poses.shape[0], 3), np.nan)  # slots not in use: never read
    poses[:256] = np.concatenate([near, far])
    weights = np.full(poses.shape[0], -np.inf)
    weights[:200] = np.log(mass_near / 200)
    weights[200:256] = np.log((1 - mass_near) / 56)
    return state._replace(poses=jnp.asarray(poses, jnp.float32), log_weights=jnp.asarray(weights, jnp.float32),
                          num_active=jnp.asarray(256, jnp.int32), travel=jnp.zeros(2, jnp.float32))


@pytest.mark.parametrize("jit", [True, False], ids=["jit", "no-jit"])
def test_the_estimate_keeps_its_cluster_until_another_is_clearly_heavier(world, jit):
    """The far cluster's one bin outweighs every bin of the spread one: the mode lies
    there. The estimate that followed the spread cluster stays on it while the far
    one holds less than ``estimate_switch`` (2) times its weight (0.6 against 0.4),
    and moves when it holds more (0.9 against 0.1). Without a last estimate (a global
    start) it is the mode, as it is for every step of a filter without the memory:
    the test fails there."""
    filt, params, log, scan = _filter(world)
    step = jax.jit(filt.step) if jit else filt.step
    state = filt.init(jax.random.key(0), jnp.asarray([1.0, 1.0, 0.3], jnp.float32), jnp.asarray([0.1, 0.1, 0.05]))
    zero = jnp.zeros(3, jnp.float32)
    kept, kept_info = step(jax.random.key(1), _two_clusters(state, 0.4), zero, scan)
    moved, moved_info = step(jax.random.key(1), _two_clusters(state, 0.1), zero, scan)
    fresh = _two_clusters(state, 0.4)._replace(estimate=jnp.full(3, jnp.nan, jnp.float32))
    mode, mode_info = step(jax.random.key(1), fresh, zero, scan)
    assert not bool(kept_info.updated) and float(params.estimate_switch) == 2.0
    np.testing.assert_allclose(np.asarray(kept_info.estimate)[:2], [1.0, 1.0], atol=0.15)
    assert 0.1 < float(kept_info.cluster_weight) < 0.4
    np.testing.assert_array_equal(np.asarray(kept.estimate), np.asarray(kept_info.estimate))
    for info in (moved_info, mode_info):
        np.testing.assert_allclose(np.asarray(info.estimate), [-4.0, 2.0, 1.0], atol=0.05)
    assert float(mode_info.cluster_weight) == pytest.approx(0.6, abs=1e-3)


def test_a_spread_cloud_with_few_in_use_draws_more_than_it_had(world):
    capacity = 4096
    filt, params, log, scan = _filter(world, capacity=capacity, block=128, ess_threshold=1.1, likelihood_power=1e-6)
    state = filt.init(jax.random.key(0))  # uniform over the free space
    state = _in_use(state, 100, jnp.nan)
    new_state, info = jax.jit(filt.step)(jax.random.key(1), state, jnp.zeros(3, jnp.float32), scan)
    assert bool(info.resampled)
    # the 100 in use occupy about 100 bins, whose bound asks for thousands: the draw
    # grows past the first 100 to the bound
    bound = math.ceil(float(kld_bound(info.occupied_bins, params.kld_epsilon, params.kld_z)))
    assert int(info.occupied_bins) > 90 and bound > 3000
    assert int(new_state.num_active) == min(bound, capacity)
    assert np.all(np.isfinite(np.asarray(new_state.poses[:int(new_state.num_active)])))


@pytest.mark.long
def test_recovers_from_a_kidnapping(world):
    # whether the free-space draws land near the new place within 30 s is a matter of
    # chance (three or four seeds of these six): half of them must make it
    walls, grid = world
    at = 150
    poses = kidnapped_poses(at, 200)[:3 * CHUNK]
    quick = 0
    for seed in range(1, 7):
        log = laser_log(walls, poses, seed=seed, jump_at=at)
        result = localize(log, grid, particles=10000, seed=seed, initial_pose=poses[0], chunk=CHUNK)
        distance, _ = tracking_errors(result.trajectory, poses)
        assert distance[:at].max() < 0.2
        assert distance[at] > 3.0  # carried away
        assert result.info["injected"][at:].sum() > 0
        quick += at < _first_good(result.trajectory, poses) < at + 150  # within 30 s of log time
    assert quick >= 3
