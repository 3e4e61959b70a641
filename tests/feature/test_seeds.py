"""Ensembles over seeds, padding invariance of the observation slots, and the
diagnostics in the filter's Info."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.datasets.landmark_sim import simulate
from jaxslam.feature import filter as F
from jaxslam.feature.ensemble import run_landmark_ensemble
from jaxslam.feature.experiment import params_for, run_landmark_slam
from jaxslam.feature.params import Config

SIM = dict(num_steps=30, max_observations=20)
CONFIG = dict(capacity=96, local_size=48)


@pytest.fixture(scope="module")
def ensemble():
    seq = simulate(seed=0, **SIM)
    return seq, run_landmark_ensemble(seq, "erb-upf", particles=8, seeds=[0, 2], config=CONFIG)


@pytest.mark.slow
def test_ensemble_equals_single_runs(ensemble):
    seq, ens = ensemble
    assert ens.trajectory.shape == (2, 30, 3)
    for i, seed in enumerate((0, 2)):
        single = run_landmark_slam(seq, "erb-upf", particles=8, seed=seed, config=CONFIG, progress=False)
        # the same random streams; vmap may round differently in float32
        np.testing.assert_allclose(ens.trajectory[i], single.trajectory, atol=2e-3)
        np.testing.assert_array_equal(ens.info["resampled"][i], single.info["resampled"])
    assert not np.allclose(ens.trajectory[0], ens.trajectory[1])


def _step_states(width_extra: int, widths: tuple = (), front: bool = False):
    """Three steps of a 6-particle filter on a simulated log whose observation slots
    are padded by ``width_extra`` (after the real slots, or before them: ``front``).
    The scans keep 2, 3 and 6 of their 6 observations, so narrow widths take some."""
    seq = simulate(seed=1, num_steps=3, max_observations=6)
    params = F.cast_params(params_for(seq), jnp.float32)
    config = Config(num_particles=6, observation_widths=widths, **CONFIG)
    state = F.init(jax.random.PRNGKey(0), params, config)
    infos = []
    pad = (width_extra, 0) if front else (0, width_extra)
    for t in range(3):
        values = np.pad(seq.observations[t], (pad, (0, 0)), constant_values=7.0)
        mask = np.pad(seq.obs_mask[t] & (np.arange(6) < (2, 3, 6)[t]), pad)
        obs = F.Observation(jnp.asarray(values, jnp.float32), jnp.asarray(mask))
        state, info = F.step(jax.random.PRNGKey(t), state, jnp.asarray(seq.controls[t], jnp.float32), obs, params,
                             config)
        infos.append(info)
    return state, infos


def test_observation_widths():
    assert F.observation_widths(Config(observation_widths=(4, 7)), 14) == (4, 7, 14)
    assert F.observation_widths(Config(observation_widths=(7, 4, 20)), 6) == (4, 6)
    assert F.observation_widths(Config(observation_widths=()), 14) == (14,)
    assert Config(observation_widths=[2, 4]).observation_widths == (2, 4)  # hashable
    with pytest.raises(ValueError, match="observation_widths"):
        Config(observation_widths=(0, 4))


@pytest.mark.long
@pytest.mark.parametrize("widths", [(), (2, 4), (4, 7)])
def test_padding_slots_change_nothing(widths):
    """The same particles whatever the padding and the narrower widths compiled
    (``Config.observation_widths``): real observations in the first slots (a narrow
    branch runs where they fit) or in the last ones (only the full width holds them;
    a width chosen by their count instead of the last real slot would drop them).
    """
    reference, ref_infos = _step_states(0)
    for extra, front in ((0, False), (8, False), (8, True)):
        state, infos = _step_states(extra, widths, front)
        np.testing.assert_allclose(state.poses, reference.poses, atol=1e-5)
        np.testing.assert_allclose(state.log_weights, reference.log_weights, atol=1e-4)
        np.testing.assert_allclose(state.landmarks.means, reference.landmarks.means, atol=1e-4)
        np.testing.assert_array_equal(state.landmarks.count, reference.landmarks.count)
        assert [int(i.association_disagreement) for i in infos] == [int(i.association_disagreement) for i in ref_infos]


@pytest.mark.long
def test_diagnostics(ensemble):
    seq, ens = ensemble
    info = {name: value[0] for name, value in ens.info.items()}
    n = ens.particles
    assert np.all(info["num_ancestors"][~info["resampled"]] == n)
    assert np.all((info["num_ancestors"] >= 1) & (info["num_ancestors"] <= n))
    assert np.all(info["num_ancestors"][info["resampled"]] < n)
    assert info["resampled"].any()
    entropy = info["weight_entropy"]
    assert np.all((entropy >= -1e-5) & (entropy <= np.log(n) + 1e-5))
    assert np.all(info["num_landmarks_min"] <= info["num_landmarks_max"])
    assert np.all(info["association_disagreement"] <= seq.obs_mask.sum(axis=1))


def test_disagreement_counts_real_observations_only():
    matched = jnp.array([[True, False, True, False], [True, True, False, False]])
    new = jnp.array([[False, False, False, True], [False, False, True, False]])
    mask = jnp.array([True, True, True, False])
    # obs 0 agree (matched), obs 1 differs, obs 2 differs (match vs new), obs 3 is padding
    assert int(F._disagreement(matched, new, mask)) == 2
