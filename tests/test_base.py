"""The filter protocol of :mod:`jaxslam.base`: a filter of one's own built from the
library's parts (``examples/own_motion_model.py``), :func:`jaxslam.run`, :func:`jaxslam.reweight`
and the factories' checks."""

import importlib.util
import pathlib

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp

import jaxslam
from jaxslam.core.resampling import log_likelihood_increment
from jaxslam.runtime.driver import step_keys

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "own_motion_model.py"


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("own_motion_model", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def beacon_run(example):
    true, controls, observations = example.simulate(steps=40, seed=1)
    filt = example.beacon_filter(jnp.asarray(example.BEACONS), jnp.array([0.05, 0.02]), 0.2, 0.03, num_particles=32)
    state = filt.init(jnp.asarray(true[0]), 0.05 * jnp.eye(3))
    inputs = (jax.random.PRNGKey(2), state, jnp.asarray(controls), jnp.asarray(observations))
    jitted = jax.jit(jaxslam.run, static_argnums=0)(filt, *inputs)
    return example, filt, inputs, jitted, (true, controls, observations)


def test_the_users_filter_is_under_forty_lines(example):
    lines = EXAMPLE.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("def forward_then_turn"))
    last = next(i for i, line in enumerate(lines) if "return jaxslam.ParticleFilter" in line)
    assert last - first + 1 < 40


def test_the_users_filter_localizes_better_than_dead_reckoning(beacon_run):
    example, _, _, (final, infos), (true, controls, _) = beacon_run
    dead = [true[0]]
    for v, w in controls:
        x, y, theta = dead[-1]
        dead.append(np.array([x + v * np.cos(theta), y + v * np.sin(theta), theta + w]))
    dead_error = np.hypot(*(dead[-1][:2] - true[-1][:2]))
    error = np.hypot(*(np.asarray(final.poses).mean(0)[:2] - true[-1][:2]))
    assert error < 0.2 < dead_error, (error, dead_error)
    assert isinstance(infos, jaxslam.Info)
    chex.assert_shape(infos.ancestors, (40, 32))
    chex.assert_tree_all_finite(infos)


def test_run_is_the_step_keys_loop_with_and_without_jit(beacon_run):
    """:func:`jaxslam.run` equals a Python loop over ``step`` with ``step_keys``, jitted
    or not."""
    _, filt, (key, state, controls, observations), jitted, _ = beacon_run
    keys = step_keys(key, controls.shape[0])
    looped, infos = state, []
    for t in range(controls.shape[0]):
        looped, info = jax.jit(filt.step)(keys[t], looped, controls[t], observations[t])
        infos.append(info)
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *infos)
    chex.assert_trees_all_close((looped, stacked), jitted, rtol=1e-9, atol=1e-9)
    with jax.disable_jit():
        eager = jaxslam.run(filt, key, state, controls[:3], observations[:3])
    short = jax.jit(jaxslam.run, static_argnums=0)(filt, key, state, controls[:3], observations[:3])
    chex.assert_trees_all_close(eager, short, rtol=1e-9, atol=1e-9)


def test_reweight_against_numpy():
    """ESS, the log-likelihood increment and the resampling flag against float64 NumPy."""
    rng = np.random.default_rng(0)
    log_weights = np.log(rng.dirichlet(np.ones(8))) + 3.0  # unnormalised on purpose
    log_liks = rng.normal(0.0, 2.0, 8)
    ancestors, new_log_weights, info = jaxslam.reweight(jax.random.PRNGKey(0), log_weights, log_liks, 0.99)
    prior = log_weights - logsumexp(log_weights)
    posterior = prior + log_liks - logsumexp(prior + log_liks)
    np.testing.assert_allclose(info.log_likelihood_increment, logsumexp(prior + log_liks), rtol=1e-12)
    np.testing.assert_allclose(info.ess, 1.0 / np.sum(np.exp(posterior) ** 2), rtol=1e-12)
    assert bool(info.resampled) == (1.0 / np.sum(np.exp(posterior) ** 2) < 0.99 * 8)
    chex.assert_type(info.ancestors, jnp.int32)
    if bool(info.resampled):
        np.testing.assert_allclose(new_log_weights, np.full(8, -np.log(8)), rtol=1e-12)


def test_log_likelihood_increment_never_nan():
    every_nan = log_likelihood_increment(jnp.zeros(4), jnp.full(4, jnp.nan))
    assert float(every_nan) == -np.inf
    np.testing.assert_allclose(log_likelihood_increment(jnp.zeros(2), jnp.array([0.0, jnp.nan])), np.log(0.5))


def test_factories_refuse_another_filters_config():
    from jaxslam.feature.params import Config

    with pytest.raises(ValueError, match="erb_upf needs a config with proposal='erb'"):
        jaxslam.erb_upf(Config(proposal="rb"))
    with pytest.raises(ValueError, match="rb_upf needs a config with proposal='rb'"):
        jaxslam.rb_upf(Config(proposal="erb"))


def test_import_jaxslam_does_not_import_jax():
    """The command line imports the package on every call; the API loads on first use."""
    import subprocess
    import sys

    code = "import sys, jaxslam; assert 'jax' not in sys.modules; jaxslam.ParticleFilter; assert 'jax' in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_every_public_name_resolves():
    """The package root and every subpackage declare ``__all__``, and each name in it
    is an attribute or a submodule."""
    import importlib

    for package in ("jaxslam", "jaxslam.app", "jaxslam.calibrate", "jaxslam.core", "jaxslam.datasets",
                    "jaxslam.feature", "jaxslam.grid", "jaxslam.metrics", "jaxslam.models", "jaxslam.runtime",
                    "jaxslam.viz"):
        module = importlib.import_module(package)
        assert module.__all__, package
        for name in module.__all__:
            if package == "jaxslam.viz":  # the optional extra: listed, not imported here
                continue
            assert hasattr(module, name) or importlib.import_module(f"{package}.{name}"), (package, name)
