"""SRUPF-GM's predictive scan likelihood (jaxslam.calibrate.grid): the filter's own
forward pass, the carried pose factors, finite gradients."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.calibrate import grid as G
from jaxslam.app.cli import main
from jaxslam.datasets.carmen import scan_range
from jaxslam.datasets.laser_sim import simulate
from jaxslam.grid import srupf
from jaxslam.grid.experiment import run_grid_slam
from jaxslam.grid.algorithms import grid_algorithm

SCANS = 36
PARTICLES = 4
# Keyframes every 0.5 m; resampling at every keyframe (so the gathers are exercised).
KEYFRAMES = {"keyframes.linear_update": 0.5, "keyframes.angular_update": 0.3, "weights.resample_threshold": 1.0,
             "weights.gain": 0.1}


@pytest.fixture(scope="module")
def setup():
    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.3, num_beams=91, seed=2)
    # The loop-closure search off: a 36-scan window closes no loop, and compiled into the
    # gradient programs it costs these tests about 40 s. (The slow
    # test_calibrate_srupf_then_run_with_params calibrates with the default
    # configuration, search included.)
    reference = run_grid_slam(scan_range(log, 0, SCANS), "srupf-gm", particles=PARTICLES, seed=0, progress=False,
                              params=KEYFRAMES, config={"match_iterations": 6, "closure": False})
    params = grid_algorithm("srupf-gm").make_params(log.angles, log.laser_offset, values=KEYFRAMES)
    inputs = jax.tree_util.tree_map(jnp.asarray, G.window_inputs(log, SCANS))
    return log, reference.config, params, inputs


def test_log_noise_round_trip():
    params = grid_algorithm("srupf-gm").make_params(np.zeros(3), values={"srupf.match_noise": np.array([0.02, 0.03, 0.01])})
    names = ("srupf.q_linear", "srupf.match_noise")
    theta = G.log_noise_of(params, names)
    np.testing.assert_allclose(np.exp(theta), [0.02, 0.02, 0.03, 0.01], rtol=1e-6)
    again = G.with_log_noise(params, jnp.asarray(theta) + np.log(2.0), names)
    np.testing.assert_allclose(np.asarray(again.srupf.match_noise), [0.04, 0.06, 0.02], rtol=1e-6)
    assert G.values_of(theta, params, names)["srupf.match_noise"] == pytest.approx([0.02, 0.03, 0.01])
    assert G.trajectory_columns(params, names) == ("srupf.q_linear", "srupf.match_noise[0]", "srupf.match_noise[1]",
                                                  "srupf.match_noise[2]")


@pytest.mark.long
def test_forward_pass_is_the_filter_bit_for_bit(setup):
    """The filter state carried by the differentiable run is srupf.run's, bit for
    bit (poses, factors, weights, maps), and the differentiable copy of the pose factors
    equals the filter's own."""
    log, config, params, inputs = setup
    key = jax.random.PRNGKey(0)
    state = srupf.init(key, params, config, inputs.first_scan, inputs.initial_pose)
    reference, info = srupf.run(key, state, inputs.controls, inputs.observations, params, config)

    @jax.jit
    def carried(params):
        def body(carry, xs):
            return G.differentiable_scan_step(xs[0], carry, xs[1], xs[2], params, config)

        steps = jax.random.split(key, SCANS - 1)
        return jax.lax.scan(body, G.Carry(state, state.pose_sqrt_covs), (steps, inputs.controls,
                                                                           inputs.observations))

    carry, increments = carried(params)
    keyframes = np.asarray(info.keyframe)
    assert keyframes.sum() >= 4 and np.asarray(info.resampled).any()
    for a, b in zip(jax.tree_util.tree_leaves(carry.state), jax.tree_util.tree_leaves(reference)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(carry.pose_sqrt_covs), np.asarray(reference.pose_sqrt_covs))
    increments = np.asarray(increments)
    assert np.all(increments[~keyframes] == 0) and np.all(np.isfinite(increments))
    assert np.all(increments[keyframes] != 0)


def test_predictive_likelihood_matches_a_direct_computation(setup):
    """One keyframe's estimate against the formula evaluated draw by draw with the score
    module's scan likelihood, in float64 (the kernel's cell windows make the likelihood
    jump where a beam end crosses a cell edge, so float32 rounding of the draws could
    flip a beam)."""
    from jax.scipy.special import logsumexp

    from jaxslam.grid.filter import match_geometry, particle_reader, score_model
    from jaxslam.grid.score import scan_log_likelihood

    log, config, _, _ = setup
    with jax.enable_x64(True):
        params = grid_algorithm("srupf-gm").make_params(log.angles, log.laser_offset, dtype=jnp.float64, values=KEYFRAMES)
        inputs = jax.tree_util.tree_map(jnp.asarray, G.window_inputs(log, SCANS, jnp.float64))
        key = jax.random.PRNGKey(3)
        state = srupf.init(key, params, config, inputs.first_scan, inputs.initial_pose)
        weights = np.array([0.1, 0.2, 0.3, 0.4])
        state = state._replace(log_weights=jnp.log(jnp.asarray(weights)))
        sqrt = jnp.broadcast_to(jnp.diag(jnp.array([0.05, 0.04, 0.02])), (PARTICLES, 3, 3))
        motion = jnp.array([0.4, 0.02, 0.05])
        scan = jax.tree_util.tree_map(lambda x: x[4], inputs.observations)
        # Both sides jitted (as the library runs them), so that they are not run op by op.
        estimate = jax.jit(lambda *a: G.predictive_log_likelihood(*a, params, config, samples=3))
        total, prediction = estimate(key, state, sqrt, motion, scan)
        eps = np.asarray(jax.random.normal(key, (PARTICLES, 3, 3), jnp.float64))
        points, mask = match_geometry(scan, params, config)

        @jax.jit
        def likelihood(state, table, pose):
            read = particle_reader(state, table, config)
            return scan_log_likelihood(read, pose, points, mask, params.sensor.laser_offset, config.layout,
                                       score_model(params), config.score_kernel, config.free_check)[0]

        per_particle = []
        for m in range(PARTICLES):
            values = []
            for k in range(3):
                pose = np.asarray(prediction.mean[m]) + np.asarray(prediction.sqrt_cov[m]) @ eps[m, k]
                lik = likelihood(state, state.maps.tables[m], jnp.asarray(pose))
                values.append(float(params.weights.gain) * float(lik))
            per_particle.append(float(logsumexp(np.array(values))) - np.log(3))
        expected = float(logsumexp(np.log(weights) + np.array(per_particle)))
        assert float(total) == pytest.approx(expected, rel=1e-9, abs=1e-9)


@pytest.mark.long
def test_gradients_are_finite_and_reach_every_level(setup):
    log, config, params, inputs = setup
    names = G.GRID_NOISE_NAMES
    gradient, increments = G.programs(config, names, 4)
    theta = jnp.asarray(G.log_noise_of(params, names), jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    values, grads = gradient(keys, theta, params, inputs)
    assert np.all(np.isfinite(np.asarray(values))) and np.all(np.isfinite(np.asarray(grads)))
    assert grads.shape == (2, len(theta)) and np.all(np.abs(np.asarray(grads)).sum(0) > 0)
    np.testing.assert_allclose(np.asarray(increments(keys, theta, params, inputs)).mean(1), np.asarray(values),
                               rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_calibrate_srupf_then_run_with_params(tmp_path):
    out = tmp_path / "cal"
    assert main(["calibrate", "--algorithm", "srupf-gm", "--out", str(out), "--particles", "3", "--filters", "2",
                 "--steps", "2", "--window", "60", "--validate-every", "1", "--validation-filters", "2",
                 "--samples", "2"]) == 0
    payload = json.loads((out / "calibration.json").read_text())
    assert set(payload["params_after"]) == set(G.GRID_NOISE_NAMES)
    assert len(payload["params_after"]["srupf.match_noise"]) == 3 and payload["validation"]["steps"] == [0, 1, 2]
    assert (out / "calibration.png").exists()
    run_out = tmp_path / "run"
    assert main(["run", "--algorithm", "srupf-gm", "--out", str(run_out), "--particles", "3", "--max-steps", "4",
                 "--no-plots", "--no-progress", "--params", str(out / "calibration.json")]) == 0
    summary = json.loads((run_out / "summary.json").read_text())
    assert summary["overrides"] == payload["params_after"]


@pytest.mark.long
def test_calibration_takes_the_runs_range_rule(monkeypatch):
    """On a far-field log the fitted parameters and the reference layout use the ranges
    the run on the whole log would use (jaxslam.grid.range_rule), not the 20 m default.

    The gradient program is replaced by one with zero gradients: what is checked here
    is what the calibration builds around it, and its own compilation (over
    three minutes on a 2-core machine) is checked by
    ``test_gradients_are_finite_and_reach_every_level`` above, and with the default
    configuration by the slow ``test_calibrate_srupf_then_run_with_params``."""
    import dataclasses

    from jaxslam.grid.range_rule import choose_range

    base = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.3, num_beams=91, seed=2, max_range=60.0)
    far = dataclasses.replace(base, ranges=base.ranges * 6.0)  # readings stretched: a far field
    want = choose_range(far.ranges, far.valid, far.max_range)
    assert want["far_field"]
    seen = {}

    def programs(config, names, samples):
        seen["config"] = config

        @jax.jit
        def gradient(keys, theta, params, inputs):
            return jnp.zeros(keys.shape[0], theta.dtype), jnp.zeros((keys.shape[0], theta.shape[0]), theta.dtype)

        return gradient, None

    monkeypatch.setattr(G, "programs", programs)
    result = G.calibrate_grid(far, particles=2, filters=1, steps=1, window=24, samples=1, validation=0.0,
                              params=KEYFRAMES)
    assert float(result.params.sensor.usable_range) == want["usable_range"]
    assert float(result.params.sensor.score_range) == want["score_range"]
    window_range = 10.0 * np.ceil(want["usable_range"] / 10.0)
    assert result.config.window_range == window_range and seen["config"].window_range == window_range
    assert seen["config"].window_range > 20.0  # not the default's
