"""Occupancy-grid SLAM: paged per-particle ``int8`` maps, batched ray updates, scan
matching, a GMapping-style filter and SRUPF-GM (Zandara & Nicholson 2009).

Modules:

* :mod:`~jaxslam.grid.map` — dense grid geometry (:class:`~jaxslam.grid.map.GridSpec`), cell type, readers.
* :mod:`~jaxslam.grid.paged` — paged maps: tile pool, page tables, copy on write, growth.
* :mod:`~jaxslam.grid.rays` — the cells each beam crosses (Bresenham), laid out for batching.
* :mod:`~jaxslam.grid.update` — ray updates of all particles' maps at once.
* :mod:`~jaxslam.grid.score` — map evidence at beam end points, scan likelihood.
* :mod:`~jaxslam.grid.matching` — hill climbing (GMapping), the covariance-ellipse
  search (SRUPF-GM) and an optax gradient refinement.
* :mod:`~jaxslam.grid.types` — config, params (one part per component, each with its
  defaults), state, info, inputs.
* :mod:`~jaxslam.grid.algorithms` — the filters by their command-line names: each one's
  step and its own defaults.
* :mod:`~jaxslam.grid.filter` — ``init`` and the keyframe update both filters share
  (:func:`~jaxslam.grid.filter.keyframe_update`: each filter gives its per-particle
  ``propose``).
* :mod:`~jaxslam.grid.driver` — the grid run loop: the step's summary and map growth
  around the one chunk runner of :mod:`jaxslam.runtime.driver`.
* :mod:`~jaxslam.grid.gmapping`, :mod:`~jaxslam.grid.srupf` — the filters
  (``init``/``step``/``run``).
* :mod:`~jaxslam.grid.export` — PGM + YAML (ROS map_server) and PNG.
* :mod:`~jaxslam.grid.mapfile` — the lossless ``map.npz`` and :func:`~jaxslam.grid.mapfile.load_map` (it, a
  run folder or any ROS map_server YAML).
* :mod:`~jaxslam.grid.map_server` — ROS map_server maps read as ``map_server`` reads them.
* :mod:`~jaxslam.grid.startmap` — a saved map as every particle's starting map (``jaxslam run --start-map``).
* :mod:`~jaxslam.grid.experiment` — :func:`~jaxslam.grid.experiment.run_grid_slam` on a CARMEN log.
"""

from jaxslam.grid import (
    algorithms, driver, export, filter, gmapping, matching, paged, rays, score, srupf, types, update,
)
from jaxslam.grid import map as map
from jaxslam.grid.filter import best_particle, init
from jaxslam.grid.algorithms import GRID_ALGORITHMS, GridAlgorithm, grid_algorithm
from jaxslam.grid.types import (
    ClosureParams,
    ClosureState,
    GMappingNoise,
    GridSlamConfig,
    GridSlamInfo,
    GridSlamParams,
    GridSlamState,
    KeyframeParams,
    MapParams,
    MatcherParams,
    Odometry,
    Scan,
    SensorParams,
    SrupfNoise,
    TrackingParams,
    WeightParams,
    get_path,
    with_values,
)
from jaxslam.grid.export import save_map
from jaxslam.grid.mapfile import OccupancyMap, load_map
from jaxslam.grid.map import GridSpec

# The whole-run entry points read logs (jaxslam.datasets): loaded on first use, so that
# importing a kernel module does not import the loaders.
_ENTRY_POINTS = {"GridSlamResult": "jaxslam.grid.experiment", "run_grid_slam": "jaxslam.grid.experiment"}


def __getattr__(name: str):
    if name in _ENTRY_POINTS:
        from importlib import import_module

        return getattr(import_module(_ENTRY_POINTS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "GRID_ALGORITHMS",
    "ClosureParams",
    "ClosureState",
    "GMappingNoise",
    "GridAlgorithm",
    "KeyframeParams",
    "MapParams",
    "MatcherParams",
    "SensorParams",
    "SrupfNoise",
    "TrackingParams",
    "WeightParams",
    "algorithms",
    "get_path",
    "grid_algorithm",
    "with_values",
    "GridSlamConfig",
    "GridSlamResult",
    "GridSlamInfo",
    "GridSlamParams",
    "GridSlamState",
    "GridSpec",
    "OccupancyMap",
    "Odometry",
    "Scan",
    "best_particle",
    "driver",
    "filter",
    "paged",
    "rays",
    "types",
    "export",
    "gmapping",
    "init",
    "load_map",
    "map",
    "matching",
    "run_grid_slam",
    "save_map",
    "score",
    "srupf",
    "update",
]
