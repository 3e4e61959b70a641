"""A filter state on the simulated log of the ``sim`` fixture (tests/grid/conftest.py)."""

import jax
import numpy as np

from jaxslam.grid.algorithms import grid_algorithm
from jaxslam.grid.experiment import map_layout
from jaxslam.grid.filter import init, integrate_scan
from jaxslam.grid.types import Scan


def state_and_scans(sim):
    """A two-particle SRUPF-GM state (float64) whose maps hold the simulated scans 0-2
    at their true poses, the scans of the log, its params and config."""
    params = grid_algorithm("srupf-gm").make_params(sim.angles, sim.laser_offset, dtype=np.float64)
    layout = map_layout(sim, np.arange(sim.num_scans), 0.05, 3.0, 2, 20.0)
    config = grid_algorithm("srupf-gm").make_config(2, layout, sim.num_beams, 4096)
    scans = [Scan(np.where(sim.valid[i], sim.ranges[i], 0.0), sim.valid[i], 0.0) for i in range(sim.num_scans)]
    with jax.enable_x64(True):
        state = jax.jit(init, static_argnums=2)(jax.random.PRNGKey(0), params, config, scans[0], sim.true_poses[0])
        # Two more scans at their true poses, so that the walls score well (one hit
        # is half of occ_saturation).
        maps = state.maps
        integrate = jax.jit(integrate_scan, static_argnums=4)
        for i in (1, 2):
            maps, _, _ = integrate(maps, np.repeat(sim.true_poses[i][None], 2, 0), scans[i], params, config)
    return state._replace(maps=maps), scans, params, config
