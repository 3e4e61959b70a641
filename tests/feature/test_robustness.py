"""Numerical robustness of the landmark filter, by design (see the policy in the
docstring of :mod:`jaxslam.feature.filter`): underflowing likelihoods, NaN inputs,
particles that go non-finite, landmark covariances that would lose positive
definiteness, and full float32 runs on Victoria Park."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.datasets.landmark_sim import simulate
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.runtime.driver import step_keys
from jaxslam.feature import filter as F
from jaxslam.feature import particle as P
from jaxslam.feature.experiment import params_for, run_landmark_slam
from jaxslam.feature.params import Config

CONFIG = Config(num_particles=8, capacity=64, local_size=32)
# Documented to be NaN when no particle was updated.
NAN_WHEN_IDLE = ("log_det_proposal_erb", "log_det_proposal_rb")


@pytest.fixture(scope="module")
def sim():
    return simulate(seed=0, num_steps=12, max_observations=8)


def _inputs(seq, t, dtype):
    return (
        jnp.asarray(seq.controls[t], dtype),
        F.Observation(jnp.asarray(seq.observations[t], dtype), jnp.asarray(seq.obs_mask[t])),
    )


def _warm_state(seq, params, dtype, steps=10):
    """The state after ``steps`` clean steps (a map to associate against)."""
    state = F.init(None, params, CONFIG, jnp.zeros(3, dtype))
    keys = step_keys(jax.random.PRNGKey(0), steps)
    for t in range(steps):
        state, _ = F.step(keys[t], state, *_inputs(seq, t, dtype), params, CONFIG)
    return state


def _run_steps(seq, params, dtype, controls, observations, mask, seed=0):
    """Step by step (sharing ``F.step``'s compiled code with the other tests):
    ``(final state, stacked Info)``."""
    state = F.init(None, params, CONFIG, jnp.zeros(3, dtype))
    keys = step_keys(jax.random.PRNGKey(seed), controls.shape[0])
    infos = []
    for t in range(controls.shape[0]):
        observation = F.Observation(jnp.asarray(observations[t], dtype), jnp.asarray(mask[t]))
        state, info = F.step(keys[t], state, jnp.asarray(controls[t], dtype), observation, params, CONFIG)
        infos.append(info)
    return state, jax.tree_util.tree_map(lambda *xs: np.stack(xs), *infos)


def _all_finite(tree) -> bool:
    return all(
        np.all(np.isfinite(np.asarray(leaf))) for leaf in jax.tree_util.tree_leaves(tree)
        if np.asarray(leaf).dtype.kind == "f"
    )


def _assert_clean(state: F.State, info: F.Info) -> None:
    """No NaN/inf in the state; weights normalised; Info finite (but the documented NaNs)."""
    assert _all_finite(state)
    assert float(jax.scipy.special.logsumexp(state.log_weights)) == pytest.approx(0.0, abs=1e-5)
    for name, value in info._asdict().items():
        value = np.asarray(value)
        if name in NAN_WHEN_IDLE and not bool(info.updated):
            continue
        assert not np.any(np.isnan(value)), name


# ----------------------------------------------------------------------------- weights


@pytest.mark.parametrize("bad", [-np.inf, np.nan], ids=["minus-inf", "nan"])
def test_all_log_weights_degenerate_gives_uniform_weights_not_nan(sim, dtype, bad):
    params = params_for(sim)
    state = _warm_state(sim, params, dtype)
    state = state._replace(log_weights=jnp.full_like(state.log_weights, bad))
    new, info = F.step(jax.random.PRNGKey(5), state, *_inputs(sim, 10, dtype), params, CONFIG)
    _assert_clean(new, info)
    assert float(info.ess) == pytest.approx(CONFIG.num_particles, rel=1e-4)


def test_every_likelihood_underflows_without_nan(sim):
    """Observations 5 m off every landmark, R a million times too small, gates wide
    open: every particle matches, and every likelihood underflows in linear space
    (float32, where ``exp`` underflows below -104)."""
    dtype = np.float32
    params = params_for(sim)
    state = _warm_state(sim, params, dtype)
    absurd = params._replace(range_std=1e-6, bearing_std=1e-8, gate_associate=1e30, gate_new=1e31)
    control, observation = _inputs(sim, 10, dtype)
    observation = observation._replace(values=observation.values.at[:, 0].add(5.0))
    new, info = F.step(jax.random.PRNGKey(5), state, control, observation, absurd, CONFIG)
    _assert_clean(new, info)
    assert bool(info.updated) and int(info.num_nonfinite_particles) == 0
    # the increments themselves: exp() of every one is 0 in this dtype
    keys = jax.random.split(jax.random.split(jax.random.PRNGKey(5))[0], CONFIG.num_particles)
    particle_steps = jax.jit(jax.vmap(P.particle_step, (0, 0, 0, 0, None, None, None, None)), static_argnums=7)
    out = particle_steps(
        keys, state.poses, state.pose_sqrt_covs, state.landmarks, control, observation,
        F.cast_params(absurd, dtype), CONFIG,
    )
    assert np.all(np.exp(np.asarray(out.log_weight_increment)) == 0.0)


# ----------------------------------------------------------------------------- inputs


def test_nan_controls_and_observations_follow_the_policy(sim, dtype):
    """Non-finite control rows run as dt = 0 and non-finite observation rows are
    masked: the run equals one on the cleaned inputs exactly, and Info counts them."""
    controls = np.array(sim.controls, dtype)
    observations = np.array(sim.observations, dtype)
    mask = np.array(sim.obs_mask)
    dirty_c, dirty_o = controls.copy(), observations.copy()
    dirty_c[3, 2, 0] = np.nan
    dirty_c[5, 0, 2] = np.inf
    dirty_c[5, 4, :] = np.nan
    dirty_o[4, 0, 1] = np.nan
    dirty_o[6, 1, 0] = -np.inf
    dirty_o[7, 2, 0] = -3.0  # a negative range is as invalid as a NaN
    mask[8, -1] = False
    dirty_o[8, -1, :] = np.nan  # a padding row: zeroed, but not counted (mask is False)
    assert mask[4, 0] and mask[6, 1] and mask[7, 2]
    clean_c, clean_o, clean_m = controls.copy(), observations.copy(), mask.copy()
    for t, k in ((3, 2), (5, 0), (5, 4)):
        clean_c[t, k] = 0.0
    for t, k in ((4, 0), (6, 1), (7, 2), (8, mask.shape[1] - 1)):
        clean_o[t, k] = 0.0
        clean_m[t, k] = False
    params = params_for(sim)
    dirty_state, dirty_info = _run_steps(sim, params, dtype, dirty_c, dirty_o, mask, seed=3)
    clean_state, clean_info = _run_steps(sim, params, dtype, clean_c, clean_o, clean_m, seed=3)
    assert _all_finite(dirty_state)
    for a, b in zip(jax.tree_util.tree_leaves(dirty_state), jax.tree_util.tree_leaves(clean_state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(dirty_info.pose_estimate, clean_info.pose_estimate)
    expected_c = np.zeros(sim.n_steps, int)
    expected_c[[3, 5]] = [1, 2]
    expected_o = np.zeros(sim.n_steps, int)
    expected_o[[4, 6, 7]] = 1
    np.testing.assert_array_equal(dirty_info.num_invalid_controls, expected_c)
    np.testing.assert_array_equal(dirty_info.num_invalid_observations, expected_o)
    assert np.all(clean_info.num_invalid_controls == 0) and np.all(clean_info.num_invalid_observations == 0)


def test_an_observation_that_overflows_is_not_stored(sim):
    """A range of 1e30 m in float32 is finite but its landmark covariance overflows:
    the new landmark is refused and counted; nothing non-finite enters the maps."""
    dtype = np.float32
    params = params_for(sim)
    state = _warm_state(sim, params, dtype)
    control, observation = _inputs(sim, 10, dtype)
    observation = F.Observation(observation.values.at[0, 0].set(1e30), observation.mask.at[0].set(True))
    new, info = F.step(jax.random.PRNGKey(5), state, control, observation, params, CONFIG)
    _assert_clean(new, info)
    assert int(info.num_rejected_landmarks) == CONFIG.num_particles


# ----------------------------------------------------------------------------- particles


def _poison(state: F.State, particles, dtype) -> F.State:
    """Give ``particles`` a finite pose factor so large that its square overflows."""
    big = jnp.asarray(1e200 if dtype == np.float64 else 1e20, dtype) * jnp.eye(3, dtype=dtype)
    return state._replace(pose_sqrt_covs=state.pose_sqrt_covs.at[particles].set(big))


def test_a_particle_that_goes_nan_is_reported_and_not_propagated(sim, dtype):
    params = params_for(sim)
    state = _poison(_warm_state(sim, params, dtype), 0, dtype)
    keep = params._replace(resample_threshold=0.0)  # never resample: see the -inf weight
    new, info = F.step(jax.random.PRNGKey(5), state, *_inputs(sim, 10, dtype), keep, CONFIG)
    assert int(info.num_nonfinite_particles) == 1
    assert _all_finite(new._replace(log_weights=new.log_weights[1:],
                                    cumulative_log_likelihood=new.cumulative_log_likelihood[1:]))
    assert float(new.log_weights[0]) == -np.inf  # weight zero: resampling drops it
    assert float(new.cumulative_log_likelihood[0]) == -np.inf  # never the best particle
    assert np.all(np.isfinite(np.asarray(info.pose_estimate))) and np.all(np.isfinite(np.asarray(info.pose_cov)))
    np.testing.assert_array_equal(new.poses[0], state.poses[0])  # kept, not propagated
    np.testing.assert_array_equal(new.landmarks.means[0], state.landmarks.means[0])
    assert not np.array_equal(new.poses[1], state.poses[1])  # the others moved on
    # with resampling the failed particle is dropped
    new, info = F.step(jax.random.PRNGKey(5), state, *_inputs(sim, 10, dtype), params._replace(
        resample_threshold=1.01), CONFIG)
    assert bool(info.resampled) and _all_finite(new)
    assert np.all(np.abs(np.asarray(new.pose_sqrt_covs)) < 1.0)


def test_when_every_particle_fails_the_step_changes_nothing(sim, dtype):
    params = params_for(sim)
    state = _warm_state(sim, params, dtype)
    state = _poison(state, jnp.arange(CONFIG.num_particles), dtype)
    state = state._replace(log_weights=jnp.log(jnp.linspace(1.0, 2.0, CONFIG.num_particles, dtype=dtype)))
    state = state._replace(log_weights=state.log_weights - jax.scipy.special.logsumexp(state.log_weights))
    new, info = F.step(jax.random.PRNGKey(5), state, *_inputs(sim, 10, dtype), params, CONFIG)
    assert int(info.num_nonfinite_particles) == CONFIG.num_particles
    assert not bool(info.resampled)
    for a, b in zip(jax.tree_util.tree_leaves(new), jax.tree_util.tree_leaves(state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# ----------------------------------------------------------------------------- covariances


def _assert_pd(cov) -> None:
    cov = np.asarray(cov, np.float64)
    assert np.all(np.isfinite(cov))
    np.testing.assert_array_equal(cov, np.swapaxes(cov, -1, -2))
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    np.linalg.cholesky(cov)


ADVERSARIAL = {
    # name: (landmark mean, landmark cov, observation offset from the prediction, range_std, bearing_std)
    "tiny-R": ((10.0, 2.0), [[0.5, 0.1], [0.1, 0.3]], (0.3, 0.01), 1e-7, 1e-9),
    "near-singular-prior": ((10.0, 2.0), [[1e3, 1e3 - 1e-4], [1e3 - 1e-4, 1e3]], (0.1, 0.0), 1.0, 0.05),
    "huge-prior-tiny-R": ((10.0, 2.0), [[1e8, 0.0], [0.0, 1e8]], (1.0, 0.1), 1e-6, 1e-8),
    "landmark-at-the-sensor": ((1e-6, 0.0), [[1e-4, 0.0], [0.0, 1e-4]], (0.0, 0.0), 1e-6, 1e-6),
    "far-and-tiny-R": ((1e4, -3e3), [[4.0, 1.0], [1.0, 2.0]], (50.0, 0.5), 1e-5, 1e-9),
}


@pytest.mark.parametrize("case", sorted(ADVERSARIAL))
def test_landmark_update_stays_positive_definite(case, dtype):
    mean, cov, offset, range_std, bearing_std = ADVERSARIAL[case]
    params = F.cast_params(F.Params(range_std=range_std, bearing_std=bearing_std), dtype)
    pose = jnp.zeros(3, dtype)
    mean, cov = jnp.asarray(mean, dtype), jnp.asarray(cov, dtype)
    rel = np.asarray(mean, np.float64)
    predicted = np.array([np.hypot(*rel), np.arctan2(rel[1], rel[0])])
    z = jnp.asarray(predicted + np.asarray(offset), dtype)
    new_mean, new_cov, ok, repaired = jax.jit(P.update_landmark)(pose, mean, cov, z, params)
    assert np.all(np.isfinite(np.asarray(new_mean)))
    _assert_pd(new_cov)
    if not bool(ok):
        np.testing.assert_array_equal(new_cov, cov)
    if case == "tiny-R":  # P - K S K^T cancels to (nearly) zero: the floor is what keeps it PD
        assert bool(ok) and bool(repaired)
    m, c, ok_new = jax.jit(P.initialise_landmark)(pose, z, params)
    assert bool(ok_new) and np.all(np.isfinite(np.asarray(m)))
    _assert_pd(c)


_update_jit = jax.jit(P.update_landmark)


@settings(max_examples=200)
@given(
    log_scale=st.floats(-6.0, 6.0),
    log_r=st.floats(-9.0, 1.0),
    angle=st.floats(-math.pi, math.pi),
    ratio=st.floats(1e-4, 1.0),
    correlation=st.floats(-0.999999, 0.999999),
    distance=st.floats(0.5, 200.0),
    innovation=st.tuples(st.floats(-10.0, 10.0), st.floats(-0.5, 0.5)),
)
def test_landmark_update_is_positive_definite_for_any_valid_input(
    log_scale, log_r, angle, ratio, correlation, distance, innovation
):
    """float32, landmark covariances over 12 decades and condition numbers to 1e4,
    R over 10 decades, correlations to +-0.999999: always finite and PD."""
    dtype = np.float32
    sx, sy = 10.0**log_scale, 10.0**log_scale * math.sqrt(ratio)
    cov = np.array([[sx * sx, correlation * sx * sy], [correlation * sx * sy, sy * sy]])
    mean = distance * np.array([math.cos(angle), math.sin(angle)])
    params = F.cast_params(F.Params(range_std=10.0**log_r, bearing_std=10.0**log_r / 10.0), dtype)
    z = np.array([distance + innovation[0], angle + innovation[1]])
    new_mean, new_cov, _, _ = _update_jit(
        jnp.zeros(3, dtype), jnp.asarray(mean, dtype), jnp.asarray(cov, dtype), jnp.asarray(z, dtype), params
    )
    assert np.all(np.isfinite(np.asarray(new_mean)))
    _assert_pd(new_cov)


# ----------------------------------------------------------------------------- random valid inputs


@settings(max_examples=25)
@given(seed=st.integers(0, 2**16), speed=st.floats(0.5, 12.0), noise=st.floats(0.05, 3.0))
def test_random_valid_simulations_never_produce_nan(seed, speed, noise):
    """Random worlds, speeds and noise levels (float32, 25 steps): state and Info stay
    finite and no particle, landmark or input is ever flagged."""
    seq = simulate(seed=seed, num_steps=25, speed=speed, speed_std=0.5 * noise, range_std=0.3 * noise,
                   bearing_std=math.radians(noise), max_observations=8)
    params = params_for(seq)
    state, info = _run_steps(seq, params, np.float32, seq.controls, seq.observations, seq.obs_mask, seed=seed)
    assert _all_finite(state)
    for name, value in info._asdict().items():
        value = np.asarray(value)
        if name in NAN_WHEN_IDLE:
            value = value[np.asarray(info.updated)]
        assert not np.any(np.isnan(value)), name
    for name in ("num_invalid_controls", "num_nonfinite_particles", "num_rejected_landmarks"):
        assert np.all(np.asarray(getattr(info, name)) == 0), name
    # Gaussian range noise can make the range of a very close landmark negative: such
    # rows (and only those) are masked out and counted.
    negative = (seq.observations[..., 0] <= 0) & seq.obs_mask
    np.testing.assert_array_equal(info.num_invalid_observations, negative.sum(axis=1))


# ----------------------------------------------------------------------------- Victoria Park


@pytest.fixture(scope="module")
def victoria_park():
    from jaxslam.datasets import victoria_park

    try:
        return victoria_park.load_sequence()
    except DatasetNotFoundError as err:
        pytest.skip(str(err))


@pytest.mark.parametrize("algorithm", ["rb", "erb"])
def test_full_victoria_park_run_in_float32_has_no_nan(victoria_park, algorithm):
    result = run_landmark_slam(victoria_park, algorithm, particles=10, seed=0, progress=False, dtype=jnp.float32)
    assert result.steps == 7249
    state = result.state
    assert state.poses.dtype == np.float32
    assert _all_finite(state)
    covs = state.landmarks.covs[state.landmarks.active]
    _assert_pd(covs)
    assert np.all(np.isfinite(result.trajectory)) and np.all(np.isfinite(result.info["pose_cov"]))
    for name in ("num_invalid_controls", "num_invalid_observations", "num_nonfinite_particles",
                 "num_rejected_landmarks"):
        assert result.info[name].sum() == 0, name
