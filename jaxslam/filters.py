"""The library's filters as values: factories that return a :class:`~jaxslam.base.ParticleFilter`.

Each factory closes over a static config and the params and binds them to the filter
module's ``init`` and ``step`` (the very functions the command line runs: the grid
filters' ``step`` is the per-scan step, :func:`jaxslam.grid.tracking.per_scan` of
their keyframe update, :mod:`jaxslam.grid.srupf`, :mod:`jaxslam.grid.gmapping`; the
landmark filters' is :func:`jaxslam.feature.filter.step`). Nothing here is a second
implementation.

* Grid filters: ``init(first_scan, initial_pose) -> GridSlamState``; ``step(key,
  state, odometry, scan)`` with :class:`jaxslam.grid.types.Odometry` since the
  previous scan and its :class:`jaxslam.grid.types.Scan`. The maps keep the config's
  layout: a step they cannot take sets ``state.status`` and the rest of the run
  passes the state through; :func:`jaxslam.grid.experiment.run_grid_slam` grows them
  on the host and repeats the step.
* Landmark filters: ``init(initial_pose=None) -> State``; ``step(key, state,
  controls (K, 3), observation)``.

The configs name the variant (``GridSlamConfig.correction``, ``Config.proposal``); a
factory refuses a config of another filter rather than rewrite it.
"""

from __future__ import annotations

from jaxslam.base import ParticleFilter
from jaxslam.feature import filter as feature_filter
from jaxslam.feature.params import Config, Params
from jaxslam.grid import gmapping as gmapping_module
from jaxslam.grid import srupf as srupf_module
from jaxslam.grid.filter import init as grid_init
from jaxslam.grid.types import GridSlamConfig, GridSlamParams


def _grid_filter(module, config: GridSlamConfig, params: GridSlamParams) -> ParticleFilter:
    def init(first_scan, initial_pose):
        return grid_init(None, params, config, first_scan, initial_pose)

    def step(key, state, control, observation):
        return module.step(key, state, control, observation, params, config)

    return ParticleFilter(init, step)


def _require(config, field: str, value: str, factory: str, hint: str) -> None:
    if getattr(config, field) != value:
        raise ValueError(f"{factory} needs a config with {field}={value!r}, got {getattr(config, field)!r}; {hint}")


def srupf_gm(config: GridSlamConfig, params: GridSlamParams) -> ParticleFilter:
    """SRUPF-GM with pose correction (:mod:`jaxslam.grid.srupf`, ``config.correction
    = "pc"``; ``GRID_ALGORITHMS["srupf-gm"].make_config(...)``,
    :mod:`jaxslam.grid.algorithms`)."""
    _require(config, "correction", "pc", "srupf_gm", "use srupf_gm_npc for 'npc'")
    return _grid_filter(srupf_module, config, params)


def srupf_gm_npc(config: GridSlamConfig, params: GridSlamParams) -> ParticleFilter:
    """SRUPF-GM without pose correction: the best propagated sigma point is the
    corrected pose (eq. 10; ``config.correction = "npc"``,
    ``GRID_ALGORITHMS["srupf-gm-npc"].make_config(...)``)."""
    _require(config, "correction", "npc", "srupf_gm_npc", "use srupf_gm for 'pc'")
    return _grid_filter(srupf_module, config, params)


def gmapping(config: GridSlamConfig, params: GridSlamParams) -> ParticleFilter:
    """The GMapping-style filter (:mod:`jaxslam.grid.gmapping`;
    ``GRID_ALGORITHMS["gmapping"].make_config(...)``)."""
    return _grid_filter(gmapping_module, config, params)


def _landmark_filter(config: Config, params: Params) -> ParticleFilter:
    def init(initial_pose=None):
        return feature_filter.init(None, params, config, initial_pose)

    def step(key, state, control, observation):
        return feature_filter.step(key, state, control, observation, params, config)

    return ParticleFilter(init, step)


def erb_upf(config: Config | None = None, params: Params | None = None) -> ParticleFilter:
    """Unscented FastSLAM with the exactly Rao-Blackwellized proposal
    (:mod:`jaxslam.feature.filter`, ``Config.proposal = "erb"``); defaults: the
    paper's Victoria Park settings (:class:`jaxslam.feature.params.Params`)."""
    config = Config(proposal="erb") if config is None else config
    _require(config, "proposal", "erb", "erb_upf", "use rb_upf for 'rb'")
    return _landmark_filter(config, Params() if params is None else params)


def rb_upf(config: Config | None = None, params: Params | None = None) -> ParticleFilter:
    """Unscented FastSLAM with the RB proposal (eqs. 1-3; ``Config.proposal = "rb"``)."""
    config = Config(proposal="rb") if config is None else config
    _require(config, "proposal", "rb", "rb_upf", "use erb_upf for 'erb'")
    return _landmark_filter(config, Params() if params is None else params)


__all__ = ["erb_upf", "gmapping", "rb_upf", "srupf_gm", "srupf_gm_npc"]
