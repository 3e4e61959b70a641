"""The four filters (landmark RB-UPF and ERB-UPF, grid GMapping and SRUPF-GM) share one
protocol (:mod:`jaxslam.runtime.driver`): ``init(key, params, config, ...)``,
``step(key, state, control, observation, params, config) -> (State, Info)``,
``run(key, state, controls, observations, params, config)``; ``Info`` always has
``ess``, ``resampled`` and ``ancestors``; the best particle is the argmax of
``State.cumulative_log_likelihood``; and the path the CLI uses (``run_landmark_slam`` /
``run_grid_slam`` -> the cached :func:`jaxslam.runtime.driver.chunk_runner`) compiles once per
static config, whatever the Params and the seed."""

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.runtime import driver
from jaxslam.runtime.compiler import options_key
from jaxslam.datasets.landmark_sim import simulate as simulate_landmarks
from jaxslam.datasets.laser_sim import simulate as simulate_laser
from jaxslam.feature import filter as feature_filter
from jaxslam.feature.experiment import params_for, run_landmark_slam
from jaxslam.grid import driver as grid_driver
from jaxslam.grid import gmapping, srupf
from jaxslam.grid.experiment import run_grid_slam
from jaxslam.grid.filter import init as grid_init
from jaxslam.grid.types import GridSlamInfo, GridSlamState

# algorithm -> (module, Info type, State type)
FILTERS = {
    "rb-upf": (feature_filter, feature_filter.Info, feature_filter.State),
    "erb-upf": (feature_filter, feature_filter.Info, feature_filter.State),
    "gmapping": (gmapping, GridSlamInfo, GridSlamState),
    "srupf-gm": (srupf, GridSlamInfo, GridSlamState),
}


@pytest.mark.parametrize("algorithm", sorted(FILTERS))
def test_signatures_and_vocabulary(algorithm):
    module, info_type, state_type = FILTERS[algorithm]
    assert list(inspect.signature(module.step).parameters) == [
        "key", "state", "control", "observation", "params", "config"]
    assert list(inspect.signature(module.run).parameters) == [
        "key", "state", "controls", "observations", "params", "config"]
    assert list(inspect.signature(module.init).parameters)[:3] == ["key", "params", "config"]
    if module is not feature_filter:
        assert module.init is grid_init
    for field in ("ess", "resampled", "ancestors", "log_likelihood_increment"):
        assert field in info_type._fields
    for field in ("log_weights", "cumulative_log_likelihood"):
        assert field in state_type._fields


def test_step_keys_and_best_particle():
    key = jax.random.PRNGKey(3)
    np.testing.assert_array_equal(driver.step_keys(key, 5), jax.random.split(key, 5))

    class Particles(tuple):
        cumulative_log_likelihood = jnp.asarray([-3.0, -1.0, -jnp.inf, -2.0])
        log_weights = jnp.asarray([-0.1, -2.0, -3.0, -4.0])

    assert int(driver.best_particle(Particles())) == 1  # not the highest current weight (0)


# ------------------------------------------------------------------ landmark filters

LANDMARK_SIM = dict(num_steps=24, max_observations=10, num_landmarks=30)
LANDMARK_CONFIG = dict(capacity=48, local_size=24)


@pytest.fixture(scope="module")
def landmark_sequence():
    return simulate_landmarks(seed=4, **LANDMARK_SIM)


@pytest.mark.long
@pytest.mark.parametrize("algorithm", ["rb-upf", "erb-upf"])
def test_landmark_cli_path_compiles_once_and_uses_the_run_keys(landmark_sequence, algorithm):
    """Two runs with other Params and another seed reuse the compiled chunk runner of
    the first; the chunked run equals ``init`` + ``run`` with the same key (the same
    step keys through both drivers)."""
    seq = landmark_sequence
    kw = dict(particles=6, progress=False, config=LANDMARK_CONFIG, chunk=8, dtype=jnp.float64)
    first = run_landmark_slam(seq, algorithm, seed=0, **kw)
    runner = driver.chunk_runner(feature_filter.step, first.config)
    compiled = runner._cache_size()
    other = {"range_std": 0.7, "gate_associate": 9.2, "resample_threshold": 0.9, "pose_reset_std": 0.02}
    second = run_landmark_slam(seq, algorithm, seed=1, params=other, **kw)
    assert second.config == first.config
    assert driver.chunk_runner(feature_filter.step, second.config) is runner
    assert runner._cache_size() == compiled
    assert not np.array_equal(first.trajectory, second.trajectory)

    steps, n = seq.controls.shape[0], 6
    for result in (first, second):
        info = result.info
        assert info["ess"].shape == (steps,) and info["resampled"].shape == (steps,)
        assert info["ancestors"].shape == (steps, n) and info["ancestors"].dtype == np.int32
        assert np.all((info["ancestors"] >= 0) & (info["ancestors"] < n))
        identity = np.arange(n)
        assert np.all(info["ancestors"][~info["resampled"]] == identity)
    assert second.info["resampled"].any()

    # the same run through init + run (scan_runner): the same keys, the same numbers
    key = jax.random.PRNGKey(0)
    params = feature_filter.cast_params(params_for(seq), jnp.float64)
    state = feature_filter.init(key, params, first.config, jnp.zeros(3, jnp.float64))
    observations = feature_filter.Observation(jnp.asarray(seq.observations), jnp.asarray(seq.obs_mask))
    final, infos = feature_filter.run(key, state, jnp.asarray(seq.controls), observations, params, first.config)
    np.testing.assert_allclose(np.asarray(infos.pose_estimate), first.trajectory, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(np.asarray(infos.ancestors), first.info["ancestors"])
    best = int(driver.best_particle(final))
    np.testing.assert_array_equal(np.asarray(infos.best_particle[-1]), first.info["best_particle"][-1])
    active = np.asarray(final.landmarks.active[best])
    np.testing.assert_allclose(np.asarray(final.landmarks.means[best])[active], first.landmark_means, atol=1e-9)


# ------------------------------------------------------------------ grid filters


@pytest.fixture(scope="module")
def sim_log():
    return simulate_laser(width=10.0, height=6.0, rooms_x=2, laps=0.3, num_beams=61, seed=7)


GRID_STEPS = {"gmapping": gmapping.step, "srupf-gm": srupf.step}


@pytest.mark.long
@pytest.mark.parametrize("algorithm", ["gmapping", "srupf-gm"])
def test_grid_cli_path_compiles_once_per_config(sim_log, algorithm):
    """Two runs with other Params (noise, thresholds) and another seed reuse the
    compiled chunk runner of the first; the runner is cached per (step, config)."""
    kw = dict(particles=3, progress=False, linear_update=0.5, angular_update=0.3, max_keyframes=17, chunk=8,
              config={"match_iterations": 3}, margin=10.0, pool_slots=512)
    first = run_grid_slam(sim_log, algorithm, seed=0, **kw)
    runner = driver.chunk_runner(GRID_STEPS[algorithm], first.config, grid_driver.summarise, options_key())
    compiled = runner._cache_size()
    second = run_grid_slam(sim_log, algorithm, seed=1, params={
        "gmapping.srr": 0.05, "srupf.q_linear": 0.03, "map.l_occ": 5.0, "weights.resample_threshold": 0.3,
        "sensor.usable_range": 12.0}, **kw)
    assert second.config == first.config
    # the one cached runner of (step, config, summary, the grid programs' XLA options)
    assert driver.chunk_runner(GRID_STEPS[algorithm], second.config, grid_driver.summarise, options_key()) is runner
    assert runner._cache_size() == compiled
    assert not np.array_equal(first.trajectory, second.trajectory)
    for info in (first.info, second.info):
        assert {"ess", "resampled"} <= set(info)  # ancestors are used for the path, then dropped


# ------------------------------------------------------------------ jaxslam.run against the CLI's path

import chex  # noqa: E402

import jaxslam  # noqa: E402
from jaxslam.grid.algorithms import grid_algorithm  # noqa: E402
from jaxslam.grid.experiment import map_layout  # noqa: E402
from jaxslam.grid.rays import required_points  # noqa: E402
from jaxslam.grid.types import Odometry, Scan  # noqa: E402
from jaxslam.metrics.trajectory_io import se2_between  # noqa: E402


@pytest.mark.parametrize("algorithm", ["rb-upf", pytest.param("erb-upf", marks=pytest.mark.long)])
def test_landmark_filter_value_runs_as_the_cli(landmark_sequence, algorithm):
    """``jaxslam.run(jaxslam.erb_upf(...))`` (and RB) gives the ``Info`` of every step
    that ``run_landmark_slam``'s chunked runner gives, and its final state."""
    seq = landmark_sequence
    cli = run_landmark_slam(seq, algorithm, seed=3, particles=6, progress=False, config=LANDMARK_CONFIG, chunk=8,
                            dtype=jnp.float64)
    factory = jaxslam.erb_upf if algorithm == "erb-upf" else jaxslam.rb_upf
    filt = factory(cli.config, feature_filter.cast_params(params_for(seq), jnp.float64))
    observations = feature_filter.Observation(jnp.asarray(seq.observations), jnp.asarray(seq.obs_mask))
    state = filt.init(jnp.zeros(3, jnp.float64))
    final, infos = jax.jit(jaxslam.run, static_argnums=0)(filt, jax.random.PRNGKey(3), state,
                                                          jnp.asarray(seq.controls), observations)
    chex.assert_trees_all_close(infos._asdict(), cli.info, rtol=1e-9, atol=1e-9)
    chex.assert_trees_all_close(final, cli.state, rtol=1e-9, atol=1e-9)
    assert np.all(np.isfinite(cli.info["log_likelihood_increment"]))


def grid_inputs(log, algorithm, particles=3, scans=60):
    """A grid filter's config, params and inputs on the first ``scans`` scans of ``log``,
    as :func:`jaxslam.grid.experiment.run_grid_slam` lays them out."""
    odom = np.asarray(log.odom_poses[:scans])
    ranges = np.where(log.valid[:scans], log.ranges[:scans], 0.0)
    params = grid_algorithm(algorithm).make_params(log.angles, log.laser_offset, dtype=jnp.float32, values={"keyframes.linear_update": 0.5,
                                                                                             "keyframes.angular_update": 0.3})
    layout = map_layout(log, np.arange(scans), 0.05, 10.0, particles, 20.0)
    points = int(np.ceil(required_points(np.minimum(ranges, 20.0), log.valid[:scans], 0.05) / 1024) * 1024)
    config = grid_algorithm(algorithm).make_config(particles, layout, log.num_beams, points, match_iterations=3)
    real = np.float32
    first = Scan(ranges[0].astype(real), np.asarray(log.valid[0]), np.asarray(0.0, real))
    controls = Odometry(se2_between(odom[:-1], odom[1:]).astype(real), np.ones(scans - 1, real),
                        np.diff(log.scan_times[:scans]).astype(real))
    observations = Scan(ranges[1:].astype(real), np.asarray(log.valid[1:scans]), np.zeros(scans - 1, real))
    return config, params, first, odom[0].astype(real), controls, observations


GRID_FACTORIES = {"gmapping": (jaxslam.gmapping, gmapping), "srupf-gm": (jaxslam.srupf_gm, srupf),
                  "srupf-gm-npc": (jaxslam.srupf_gm_npc, srupf)}


@pytest.mark.long
@pytest.mark.parametrize("algorithm", sorted(GRID_FACTORIES))
def test_grid_filter_value_runs_as_the_cli(sim_log, algorithm):
    """``jaxslam.run(jaxslam.srupf_gm(...))`` (and the others) steps every scan as the
    command line does (:func:`jaxslam.grid.driver.run_filter` of the module's ``step``,
    the runner ``run_grid_slam`` uses): the same kept ``Info`` and the same final state."""
    factory, module = GRID_FACTORIES[algorithm]
    config, params, first, pose, controls, observations = grid_inputs(sim_log, algorithm)
    key = jax.random.PRNGKey(5)
    state, ys, cli_config, _ = grid_driver.run_filter(module.step, key, params, config, first, pose, controls,
                                                      observations, progress=False, chunk=16, unit="scan")
    assert cli_config == config  # no growth: both runs see the same layout
    filt = factory(config, params)
    final, infos = jax.jit(jaxslam.run, static_argnums=0)(filt, key, filt.init(first, pose), controls, observations)
    assert int(final.status.code) == 0 and np.asarray(ys["keyframe"]).sum() > 3
    chex.assert_trees_all_close(jax.vmap(grid_driver.summarise)(infos), dict(ys), rtol=1e-6, atol=1e-6)
    chex.assert_trees_all_close(final, state, rtol=1e-6, atol=1e-6)
    assert np.all(np.isfinite(np.asarray(infos.log_likelihood_increment)))
