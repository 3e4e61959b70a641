"""The grid filters' params tree: parts with their defaults, paths, and the registry
that states each algorithm's own defaults once."""

import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.grid.algorithms import GRID_ALGORITHMS, grid_algorithm
from jaxslam.grid.types import (
    PARAMETER_SPECS, VECTORS, ClosureParams, GridSlamParams, get_path, param_paths, with_values,
)


def test_every_leaf_is_an_array_of_the_dtype_and_has_a_path():
    params = GridSlamParams.create(np.linspace(-1.0, 1.0, 7), (0.1, 0.0, 0.0), dtype=np.float64)
    leaves = jax.tree_util.tree_leaves(params)
    assert len(leaves) == len(param_paths()) == 60
    assert all(isinstance(leaf, np.ndarray) and leaf.dtype == np.float64 for leaf in leaves)
    assert get_path(params, "sensor.beam_angles").shape == (7,)
    assert get_path(params, "matcher.ellipse_floor").shape == (3,)
    assert float(get_path(params, "closure.trigger")) == ClosureParams().trigger
    # every path is a scalar with a specification or one of the vectors (or the log's sensor geometry)
    assert set(param_paths()) == set(PARAMETER_SPECS) | set(VECTORS) | {"sensor.beam_angles", "sensor.laser_offset"}


def test_with_values_sets_leaves_and_parts_by_path_in_the_leaves_dtype():
    params = GridSlamParams.create(np.zeros(3))
    moved = with_values(params, {"closure.trigger": 0.3, "gmapping.str": 0.4})
    assert moved.closure.trigger.dtype == np.float32 and float(moved.closure.trigger) == np.float32(0.3)
    assert float(moved.gmapping.str) == np.float32(0.4)
    assert moved.closure._replace(trigger=params.closure.trigger) == params.closure  # nothing else moved
    whole = with_values(params, {"closure": ClosureParams(watch=7.0)})
    assert float(whole.closure.watch) == 7.0 and whole.closure.watch.dtype == np.float32
    traced = jax.jit(lambda x: with_values(params, {"closure.gain": x}).closure.gain)(jnp.asarray(2.0, jnp.float32))
    assert float(traced) == 2.0
    for bad in ("closure.trigge", "closure_trigger", "nowhere.trigger"):
        with pytest.raises(KeyError, match="unknown grid SLAM parameter"):
            with_values(params, {bad: 1.0})


@pytest.mark.parametrize("name", sorted(GRID_ALGORITHMS))
def test_an_algorithm_differs_from_the_parts_only_where_its_entry_says(name):
    entry = grid_algorithm(name)
    parts = GridSlamParams.create(np.zeros(3))
    own = entry.make_params(np.zeros(3))
    differ = {path for path in param_paths()
              if not np.array_equal(get_path(parts, path), get_path(own, path))}
    assert differ <= set(entry.params)
    config = entry.make_config(2, None, 3, 1024)
    assert {k: getattr(config, k) for k in entry.config} == dict(entry.config)
    assert entry.config_default("match_iterations") == config.match_iterations


def test_the_library_does_not_dispatch_on_algorithm_names():
    """The registry maps a command-line name to a step and its defaults once; no module
    below the application compares the name itself."""
    package = pathlib.Path(__file__).resolve().parents[2] / "jaxslam"
    found = [f"{path.relative_to(package)}:{i}" for path in package.rglob("*.py") if "app" not in path.parts
             for i, line in enumerate(path.read_text().splitlines(), 1)
             if re.search(r"algorithm\s*(==|!=)", line)]
    assert not found, found
