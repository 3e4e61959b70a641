"""The grid filters by their command-line names: each one's step and its own defaults.

:data:`GRID_ALGORITHMS` maps ``"srupf-gm"``, ``"srupf-gm-npc"`` and ``"gmapping"`` to a
:class:`GridAlgorithm`: the per-scan step it runs (:func:`jaxslam.grid.srupf.step`,
:func:`jaxslam.grid.gmapping.step`), the :class:`~jaxslam.grid.types.GridSlamConfig`
fields it sets apart from that dataclass's defaults and the
:class:`~jaxslam.grid.types.GridSlamParams` leaves (by path) it sets apart from the
parts' defaults. Each such default is stated here once; nothing else in the library
asks which algorithm runs.

SRUPF-GM's keyframe rule is GMapping's (:class:`~jaxslam.grid.types.KeyframeParams`),
but with a keyframe every 0.5 m of tracked travel instead of every metre
(:func:`jaxslam.grid.tracking.is_keyframe`): its keyframe correction moves the
position, and in narrow corridors entered for the first time the walls drawn from
keyframes a metre apart are too sparse to hold that correction, so half the spacing
trades about a third more run time for fewer keyframe slides. The GMapping-style
filter keeps GMapping's own rule, as the baseline it is.

SRUPF-GM alone runs the coarse-to-fine match (``coarse_iterations`` 4,
:func:`jaxslam.grid.filter.coarse_start`), the recovery from odometry jumps
(``recover_radius``, :data:`jaxslam.grid.recovery.RECOVER_RADIUS`) and its wider
proposals after refused matches (``tracking.refused_noise_scale`` 0.5,
:func:`jaxslam.grid.tracking.keyframe_noise_scale`); the design notes
(``docs/design.md``) have the tables with and without each, reproduced by
``benchmarks/grid_robustness.py``. Both SRUPF-GM variants run the loop-closure search
(:mod:`jaxslam.grid.closure`) and the constrained keyframe correction; the
GMapping-style filter, a baseline for GMapping, which has neither, runs them only when
asked.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping

import numpy as np

from jaxslam.grid import gmapping, srupf
from jaxslam.grid.paged import PagedLayout
from jaxslam.grid.recovery import RECOVER_RADIUS
from jaxslam.grid.types import GridSlamConfig, GridSlamParams, get_path


@dataclasses.dataclass(frozen=True)
class GridAlgorithm:
    """A grid filter as the command line names it.

    Attributes:
        step: the per-scan step, ``step(key, state, control, observation, params,
            config) -> (state, info)``.
        config: the :class:`~jaxslam.grid.types.GridSlamConfig` fields it sets apart
            from the dataclass's defaults.
        params: the params leaves, by path, it sets apart from the parts' defaults.
    """

    step: Callable
    config: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def make_config(self, num_particles: int, layout: PagedLayout, num_beams: int, max_points: int,
                    **overrides) -> GridSlamConfig:
        """Its static configuration, with ``overrides`` over its defaults."""
        return GridSlamConfig(num_particles, layout, num_beams, max_points, **{**self.config, **overrides})

    def make_params(self, beam_angles, laser_offset=(0.0, 0.0, 0.0), *, dtype=np.float32,
                    values: Mapping[str, Any] | None = None) -> GridSlamParams:
        """Its params for a laser (:meth:`jaxslam.grid.types.GridSlamParams.create`), with ``values`` (by
        path) over its defaults."""
        return GridSlamParams.create(beam_angles, laser_offset, dtype=dtype, values={**self.params, **(values or {})})

    def config_default(self, name: str) -> Any:
        """The value of config field ``name`` it runs with unless told otherwise."""
        if name in self.config:
            return self.config[name]
        return next(f.default for f in dataclasses.fields(GridSlamConfig) if f.name == name)

    def param_default(self, path: str) -> Any:
        """The value of the params leaf at ``path`` it runs with unless told otherwise."""
        if path in self.params:
            return self.params[path]
        return get_path(GridSlamParams.create(np.zeros(1), dtype=np.float64), path)


_SRUPF_KEYFRAMES = {"keyframes.linear_update": 0.5}

GRID_ALGORITHMS: dict[str, GridAlgorithm] = {
    "srupf-gm": GridAlgorithm(
        srupf.step,
        config={"matcher": "ellipse", "closure": True, "coarse_iterations": 4, "recover_radius": RECOVER_RADIUS},
        params={**_SRUPF_KEYFRAMES, "tracking.refused_noise_scale": 0.5},
    ),
    "srupf-gm-npc": GridAlgorithm(
        srupf.step,
        config={"matcher": "ellipse", "correction": "npc", "sampling": "posterior", "closure": True},
        params=_SRUPF_KEYFRAMES,
    ),
    "gmapping": GridAlgorithm(gmapping.step, config={"constrain_matches": False}),
}
"""Every grid filter by its command-line name (the module docstring says why the
defaults differ)."""


def grid_algorithm(name: str) -> GridAlgorithm:
    """The registry entry of ``name``; a ``ValueError`` naming the choices otherwise."""
    if name not in GRID_ALGORITHMS:
        raise ValueError(f"algorithm must be one of {tuple(GRID_ALGORITHMS)}, got {name!r}")
    return GRID_ALGORITHMS[name]


__all__ = ["GRID_ALGORITHMS", "GridAlgorithm", "grid_algorithm"]
