"""jaxslam: batched JAX particle filters for SLAM.

Every particle and every sigma point is a row of a batched array, pushed through
``jit``/``vmap``/``lax.scan`` kernels. See ``README.md`` for the algorithms and the
papers they implement.

The public API:

* filters as values (:mod:`jaxslam.base`, :mod:`jaxslam.filters`): :class:`~jaxslam.base.ParticleFilter`,
  the factories :func:`~jaxslam.filters.srupf_gm`, :func:`~jaxslam.filters.srupf_gm_npc`, :func:`~jaxslam.filters.gmapping`,
  :func:`~jaxslam.filters.erb_upf`, :func:`~jaxslam.filters.rb_upf`, and :func:`~jaxslam.base.run`, which scans any filter; the
  parts of a filter of one's own: :class:`~jaxslam.base.MotionModel`, :class:`~jaxslam.base.MeasurementModel`,
  :func:`~jaxslam.base.sample_pose`, :func:`~jaxslam.base.reweight`, :class:`~jaxslam.base.Info`;
* whole runs on a dataset: :func:`~jaxslam.grid.experiment.run_grid_slam` (a CARMEN log, a ROS bag's scans or
  the laser simulator) with :class:`~jaxslam.grid.experiment.GridSlamResult`, :func:`~jaxslam.feature.experiment.run_landmark_slam`
  (Victoria Park or the landmark simulator) with :class:`~jaxslam.feature.experiment.LandmarkSlamResult`;
* the grid filters' types (:class:`~jaxslam.grid.types.GridSlamConfig`, :class:`~jaxslam.grid.types.GridSlamParams`,
  :class:`~jaxslam.grid.types.GridSlamState`, :class:`~jaxslam.grid.types.GridSlamInfo`, :class:`~jaxslam.grid.types.Odometry`, :class:`~jaxslam.grid.types.Scan`,
  their parts :class:`~jaxslam.grid.types.SensorParams`, :class:`~jaxslam.grid.types.MapParams`,
  :class:`~jaxslam.grid.types.MatcherParams`, :class:`~jaxslam.grid.types.KeyframeParams`, :class:`~jaxslam.grid.types.TrackingParams`,
  :class:`~jaxslam.grid.types.ClosureParams`, :class:`~jaxslam.grid.types.WeightParams`, :class:`~jaxslam.grid.types.GMappingNoise`,
  :class:`~jaxslam.grid.types.SrupfNoise`, :class:`~jaxslam.core.sigma.UTParams`, :func:`~jaxslam.grid.types.with_values`, the
  registry :data:`~jaxslam.grid.algorithms.GRID_ALGORITHMS` with :func:`~jaxslam.grid.algorithms.grid_algorithm`) and the landmark filters'
  (:class:`LandmarkConfig <jaxslam.feature.params.Config>`, :class:`LandmarkParams <jaxslam.feature.params.Params>`, :class:`LandmarkState <jaxslam.feature.filter.State>`,
  :class:`LandmarkInfo <jaxslam.feature.filter.Info>`, :class:`~jaxslam.feature.particle.Observation`);
* maps: :func:`~jaxslam.grid.export.save_map` (PGM + YAML and PNG), :func:`~jaxslam.grid.mapfile.load_map` (a run's lossless
  ``map.npz`` or any ROS ``map_server`` YAML) and :class:`~jaxslam.grid.mapfile.OccupancyMap`;
* localization in a known map: :func:`~jaxslam.localization.monte_carlo.mcl`, Monte Carlo localization on the same
  ``init``/``step`` protocol.

The names are imported on first use: the command line imports this package on every
``jaxslam`` call, and importing JAX here would cost ``jaxslam --help`` a second.
"""

from importlib import import_module

__version__ = "0.1.0"

_HOMES = {
    "ParticleFilter": "jaxslam.base",
    "InitFn": "jaxslam.base",
    "StepFn": "jaxslam.base",
    "MotionModel": "jaxslam.base",
    "MeasurementModel": "jaxslam.base",
    "Info": "jaxslam.base",
    "run": "jaxslam.base",
    "reweight": "jaxslam.base",
    "sample_pose": "jaxslam.base",
    "srupf_gm": "jaxslam.filters",
    "srupf_gm_npc": "jaxslam.filters",
    "gmapping": "jaxslam.filters",
    "erb_upf": "jaxslam.filters",
    "rb_upf": "jaxslam.filters",
    "run_grid_slam": "jaxslam.grid.experiment",
    "GridSlamResult": "jaxslam.grid.experiment",
    "run_landmark_slam": "jaxslam.feature.experiment",
    "LandmarkSlamResult": "jaxslam.feature.experiment",
    "GridSlamConfig": "jaxslam.grid.types",
    "GridSlamParams": "jaxslam.grid.types",
    "GridSlamState": "jaxslam.grid.types",
    "GridSlamInfo": "jaxslam.grid.types",
    "Odometry": "jaxslam.grid.types",
    "Scan": "jaxslam.grid.types",
    "SensorParams": "jaxslam.grid.types",
    "MapParams": "jaxslam.grid.types",
    "MatcherParams": "jaxslam.grid.types",
    "KeyframeParams": "jaxslam.grid.types",
    "TrackingParams": "jaxslam.grid.types",
    "ClosureParams": "jaxslam.grid.types",
    "ClosureState": "jaxslam.grid.types",
    "WeightParams": "jaxslam.grid.types",
    "GMappingNoise": "jaxslam.grid.types",
    "SrupfNoise": "jaxslam.grid.types",
    "UTParams": "jaxslam.core.sigma",
    "with_values": "jaxslam.grid.types",
    "GRID_ALGORITHMS": "jaxslam.grid.algorithms",
    "GridAlgorithm": "jaxslam.grid.algorithms",
    "grid_algorithm": "jaxslam.grid.algorithms",
    "save_map": "jaxslam.grid.export",
    "Observation": "jaxslam.feature.filter",
    "load_map": "jaxslam.grid.mapfile",
    "OccupancyMap": "jaxslam.grid.mapfile",
    "mcl": "jaxslam.localization.monte_carlo",
}
# The landmark filters' types, under names that say so.
_RENAMED = {
    "LandmarkConfig": ("jaxslam.feature.params", "Config"),
    "LandmarkParams": ("jaxslam.feature.params", "Params"),
    "LandmarkState": ("jaxslam.feature.filter", "State"),
    "LandmarkInfo": ("jaxslam.feature.filter", "Info"),
}

__all__ = sorted([*_HOMES, *_RENAMED, "__version__"])


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(import_module(_HOMES[name]), name)
    if name in _RENAMED:
        module, attribute = _RENAMED[name]
        return getattr(import_module(module), attribute)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted({*globals(), *__all__})
