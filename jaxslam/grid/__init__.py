"""Occupancy-grid SLAM: dense per-particle ``int8`` grids, batched ray updates, scan
matching, a GMapping-style filter and SRUPF-GM (Zandara & Nicholson 2009).

Modules:

* :mod:`~jaxslam.grid.map` — grid geometry (:class:`GridSpec`) and cell type.
* :mod:`~jaxslam.grid.update` — ray updates of all particles' grids at once.
* :mod:`~jaxslam.grid.score` — map evidence at beam end points, scan likelihood.
* :mod:`~jaxslam.grid.matching` — hill climbing (GMapping), the covariance-ellipse
  search (SRUPF-GM) and an optax gradient refinement.
* :mod:`~jaxslam.grid.common` — config, params, state, shared filter steps.
* :mod:`~jaxslam.grid.gmapping`, :mod:`~jaxslam.grid.srupf` — the filters
  (``init``/``step``/``run``).
* :mod:`~jaxslam.grid.export` — PGM + YAML (ROS map_server) and PNG.
* :mod:`~jaxslam.grid.experiment` — :func:`run_grid_slam` on a CARMEN log.
"""

from jaxslam.grid import common, export, gmapping, matching, score, srupf, update
from jaxslam.grid import map as map
from jaxslam.grid.common import (
    GridSlamConfig,
    GridSlamInfo,
    GridSlamParams,
    GridSlamState,
    Odometry,
    Scan,
    best_particle,
    best_trajectory,
    default_params,
    init,
)
from jaxslam.grid.export import save_map
from jaxslam.grid.map import GridSpec

__all__ = [
    "GridSlamConfig",
    "GridSlamInfo",
    "GridSlamParams",
    "GridSlamState",
    "GridSpec",
    "Odometry",
    "Scan",
    "best_particle",
    "best_trajectory",
    "common",
    "default_params",
    "export",
    "gmapping",
    "init",
    "matching",
    "save_map",
    "score",
    "srupf",
    "update",
]
