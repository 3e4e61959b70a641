"""The grid filters share one protocol: ``init(key, params, config, observation, pose)``,
``step(key, state, control, observation, params, config) -> (State, Info)``, ``run``;
Info always has ``ess``, ``resampled`` and ``ancestors``; the path the CLI uses
(``run_grid_slam`` -> ``driver.run_filter`` -> cached chunk runner) compiles once per
static config, whatever the Params."""

import inspect

import numpy as np
import pytest

from jaxslam.datasets.laser_sim import simulate
from jaxslam.grid import driver, gmapping, srupf
from jaxslam.grid.experiment import run_grid_slam
from jaxslam.grid.filter import init
from jaxslam.grid.types import GridSlamInfo, GridSlamState

FILTERS = {"gmapping": gmapping, "srupf-gm": srupf, "srupf-gm-npc": srupf}


@pytest.mark.parametrize("module", [gmapping, srupf])
def test_signatures(module):
    assert list(inspect.signature(module.step).parameters) == [
        "key", "state", "control", "observation", "params", "config"]
    assert list(inspect.signature(module.run).parameters) == [
        "key", "state", "controls", "observations", "params", "config"]
    assert module.init is init
    assert list(inspect.signature(init).parameters)[:3] == ["key", "params", "config"]
    for field in ("ess", "resampled", "ancestors", "log_weights", "poses"):
        assert field in GridSlamInfo._fields
    assert "maps" in GridSlamState._fields


@pytest.fixture(scope="module")
def sim_log():
    return simulate(width=10.0, height=6.0, rooms_x=2, laps=0.3, num_beams=61, seed=7)


@pytest.mark.parametrize("algorithm", ["srupf-gm"])
def test_cli_path_compiles_once_per_config(sim_log, algorithm):
    """Two runs with other Params (noise, thresholds) and another seed reuse the
    compiled chunk runner of the first; the runner is cached per (step, config)."""
    kw = dict(particles=3, progress=False, linear_update=0.5, angular_update=0.3, max_keyframes=17, chunk=8,
              config={"match_iterations": 3}, margin=10.0, pool_slots=512)
    first = run_grid_slam(sim_log, algorithm, seed=0, **kw)
    runner = driver.chunk_runner(FILTERS[algorithm].step, first.config)
    compiled = runner._cache_size()
    second = run_grid_slam(sim_log, algorithm, seed=1, params={"srr": 0.05, "q_linear": 0.03, "l_occ": 5.0,
                                                               "resample_threshold": 0.3, "usable_range": 12.0}, **kw)
    assert second.config == first.config
    assert driver.chunk_runner(FILTERS[algorithm].step, second.config) is runner
    assert runner._cache_size() == compiled
    assert not np.array_equal(first.trajectory, second.trajectory)
    for info in (first.info, second.info):
        assert {"ess", "resampled"} <= set(info)
