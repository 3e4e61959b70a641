"""The RB/ERB unscented FastSLAM filter on the landmark simulator."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.core.sigma import unscented_transform
from jaxslam.datasets.landmark_sim import simulate
from jaxslam.feature import filter as F
from jaxslam.feature.experiment import params_for, run_landmark_slam
from jaxslam.feature.params import Config
from jaxslam.metrics.nees import pose_errors, pose_nees
from jaxslam.models.vehicle import car_motion_noisy

# Paper-like ratio of noise levels, a short sensor range and a fast car: landmarks are
# often new and uncertain compared with the pose prediction, which is where the RB
# proposal's perfect-map assumption hurts.
SIM = dict(
    num_steps=40, max_observations=24, range_std=1.0, bearing_std=math.radians(3.0), speed_std=1.0,
    max_range=12.0, speed=6.0, num_landmarks=40,
)
SEEDS = (0, 1, 2, 3, 4, 5)
# Simulated landmarks are at least 4 m apart: a wide new-landmark gate suits them.
GATES = dict(gate_new=100.0)
CONFIG = Config(num_particles=50, capacity=96, local_size=48)


def _run(key, seq, params, cfg, dtype=jnp.float64):
    """``init`` then ``run`` over the whole simulated sequence in ``dtype``."""
    state = F.init(key, params, cfg, jnp.zeros(3, dtype))
    observations = F.Observation(jnp.asarray(seq.observations, dtype), jnp.asarray(seq.obs_mask))
    return F.run(key, state, jnp.asarray(seq.controls, dtype), observations, params, cfg)


@pytest.fixture(scope="module")
def sim_runs():
    runs = {"erb": [], "rb": []}
    for seed in SEEDS:
        seq = simulate(seed=seed, **SIM)
        params = params_for(seq, **GATES)
        for proposal in runs:
            cfg = dataclasses.replace(CONFIG, proposal=proposal)
            state, info = _run(jax.random.PRNGKey(seed), seq, params, cfg)
            runs[proposal].append((seq, jax.tree_util.tree_map(np.asarray, info), state))
    return runs


def test_nees_of_erb_closer_to_chi_square_than_rb(sim_runs):
    score = {}
    for proposal, runs in sim_runs.items():
        values = np.concatenate([pose_nees(i.pose_estimate, i.pose_cov, s.true_poses) for s, i, _ in runs])
        score[proposal] = abs(np.mean(np.log(values / 3.0)))
    assert score["erb"] < score["rb"], score


def test_tracks_truth_within_three_sigma(sim_runs):
    inside = []
    for seq, info, _ in sim_runs["erb"]:
        err = np.abs(pose_errors(info.pose_estimate, seq.true_poses))
        sigma = np.sqrt(np.diagonal(info.pose_cov, axis1=1, axis2=2))
        inside.append(np.all(err <= 3 * sigma, axis=1))
        assert np.linalg.norm(err[:, :2], axis=1).max() < 3.0
    assert np.mean(np.concatenate(inside)) > 0.7


def test_erb_proposal_never_smaller_on_same_particles(sim_runs):
    for seq, info, _ in sim_runs["erb"]:
        ok = np.isfinite(info.log_det_proposal_erb)
        assert ok.sum() > 15
        assert np.all(info.log_det_proposal_erb[ok] - info.log_det_proposal_rb[ok] >= -1e-4)


def test_maps_match_the_world(sim_runs):
    for seq, info, state in sim_runs["erb"]:
        best = int(info.best_particle[-1])
        active = np.asarray(state.landmarks.active[best])
        means = np.asarray(state.landmarks.means[best])[active]
        seen = np.unique(seq.associations[seq.associations >= 0])
        d = np.linalg.norm(means[:, None] - seq.landmarks[None, seen], axis=-1)
        assert abs(len(means) - len(seen)) <= 2
        assert np.median(d.min(axis=1)) < 2.0


def test_same_random_streams_for_rb_and_erb(sim_runs):
    # First scan: no landmark yet, so both filters sample from the prediction; with the
    # same key they must draw the same normals and produce the same particles.
    for (_, erb, _), (_, rb, _) in zip(sim_runs["erb"], sim_runs["rb"]):
        for a, b in zip(erb, rb):
            np.testing.assert_array_equal(a[0], b[0])
        assert not np.array_equal(erb.pose_estimate[-1], rb.pose_estimate[-1])


def _sim_run(seq, params, dtype=jnp.float64, proposal="erb"):
    """A run with the module's shapes, so it reuses the fixture's compiled code."""
    cfg = dataclasses.replace(CONFIG, proposal=proposal)
    return _run(jax.random.PRNGKey(0), seq, params, cfg, dtype)


def test_no_recompilation_when_only_params_change(sim_runs):
    seq = simulate(seed=9, **SIM)
    params = params_for(seq, **GATES)
    _sim_run(seq, params)
    size = F.run._cache_size()
    other = params._replace(range_std=0.7, gate_associate=9.2, ut_update=params.ut_update._replace(alpha=0.8))
    _sim_run(seq, other)
    assert F.run._cache_size() == size


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_float32_and_float64(sim_runs, dtype):
    seq = simulate(seed=2, **SIM)
    state, info = _sim_run(seq, params_for(seq, **GATES), dtype)
    for leaf in (state.pose_means, state.pose_sqrts, state.log_weights, state.landmarks.means, info.pose_estimate):
        assert leaf.dtype == dtype
    assert np.all(np.isfinite(np.asarray(info.pose_estimate)))
    err = np.linalg.norm(np.asarray(info.pose_estimate)[:, :2] - seq.true_poses[:, :2], axis=1)
    assert err.max() < 3.0


def test_sequential_update():
    seq = simulate(seed=3, num_steps=25, max_observations=24)
    res = run_landmark_slam(seq, "erb-upf", particles=10, seed=0, progress=False,
                            config=dict(capacity=64, local_size=32, update="sequential"))
    err = np.linalg.norm(res.trajectory[:, :2] - seq.true_poses[:, :2], axis=1)
    assert err.max() < 1.0
    ok = np.isfinite(res.info["log_det_proposal_rb"])
    assert ok.sum() > 10
    assert np.all(res.info["log_det_proposal_erb"][ok] >= res.info["log_det_proposal_rb"][ok] - 1e-3)


def test_prediction_matches_generic_unscented_transform():
    params = F.cast_params(params_for(simulate(seed=0, num_steps=1)), jnp.float64)
    pose = jnp.asarray([1.0, -2.0, 0.7])
    a = jnp.asarray([[0.3, 0.0, 0.0], [0.1, 0.2, 0.0], [0.01, -0.02, 0.05]])
    control = jnp.asarray([3.0, 0.2, 0.1])
    mean, sqrt = F.predict_pose(pose, a, control[None], params)
    aug_mean = jnp.concatenate([pose, jnp.zeros(2)])
    aug_sqrt = jnp.zeros((5, 5)).at[:3, :3].set(a).at[3, 3].set(params.speed_std).at[4, 4].set(params.steering_std)
    ref = unscented_transform(lambda p: car_motion_noisy(p[:3], p[3:], control, params.geometry), aug_mean, aug_sqrt, params.ut_predict)
    np.testing.assert_allclose(np.asarray(mean), np.asarray(ref.mean), atol=1e-12)
    np.testing.assert_allclose(np.asarray(sqrt @ sqrt.T), np.asarray(ref.cov), atol=1e-12)


def test_padded_control_rows_do_not_change_the_prediction():
    params = F.cast_params(params_for(simulate(seed=0, num_steps=1)), jnp.float64)
    pose, sqrt = jnp.asarray([0.0, 1.0, -0.4]), 0.01 * jnp.eye(3)
    rows = jnp.asarray([[2.0, 0.1, 0.025], [2.1, 0.12, 0.025]])
    padded = jnp.concatenate([rows, jnp.zeros((3, 3))])
    a = F.predict_pose(pose, sqrt, rows, params)
    b = F.predict_pose(pose, sqrt, padded, params)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_stationary_scans_are_skipped(sim_runs):
    seq = simulate(seed=0, **SIM)
    still = dataclasses.replace(seq, controls=seq.controls * np.array([0.0, 1.0, 1.0]))
    state, info = _sim_run(still, params_for(seq, **GATES))
    assert int(state.landmarks.count.sum()) == 0 and not np.any(np.asarray(info.updated))
    np.testing.assert_array_equal(np.asarray(state.pose_means), 0.0)


def test_spurious_landmark_is_pruned(sim_runs):
    seq = simulate(seed=4, **SIM)
    obs, mask = seq.observations.copy(), seq.obs_mask.copy()
    free = int(np.argmin(mask[0]))
    obs[0, free] = (6.0, 0.05)  # a "moving object", seen once straight ahead
    mask[0, free] = True
    pose0 = seq.true_poses[0]
    ghost = pose0[:2] + 6.0 * np.array([np.cos(pose0[2] + 0.05), np.sin(pose0[2] + 0.05)])
    spurious = dataclasses.replace(seq, observations=obs, obs_mask=mask)
    counts = {}
    for threshold in (-1e9, -0.5):
        state, _ = _sim_run(spurious, params_for(seq, prune_threshold=threshold, **GATES))
        means = np.asarray(state.landmarks.means[0])[np.asarray(state.landmarks.active[0])]
        counts[threshold] = int((np.linalg.norm(means - ghost, axis=1) < 1.5).sum())
        assert int(state.landmarks.count[0]) == len(means)
    assert counts[-1e9] == 1 and counts[-0.5] == 0
