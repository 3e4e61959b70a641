r"""Mapping that continues: a saved map as every particle's starting map.

``jaxslam run --start-map`` (:func:`jaxslam.grid.experiment.run_grid_slam`'s
``start_map``) starts every particle from a map read by
:func:`jaxslam.grid.mapfile.load_map` instead of an empty one; the filter then
corrects and extends it, and the map it writes covers the saved run's area and the
new log's.

*Cells.* The paged maps hold ``int8`` steps of ``params.map.log_odds_unit`` natural
log-odds, clamped at ``±params.map.l_max`` steps (:mod:`jaxslam.grid.map`). A jaxslam
``map.npz`` made with the same unit gives its cells back as they are (clamped to
``±l_max`` if the run's clamp is lower); one with another unit, or stored as floats,
is rounded to the nearest step. A ROS ``map_server`` map has no log-odds: an occupied
cell (100) becomes ``+l_max`` steps, a free one (0) ``-l_max``, an unknown one (-1)
0, and a ``scale`` value ``v`` in ``1 .. 99`` the rounded log-odds of ``v / 100``:
the saved map is taken as certain, as a localizer takes it.

*Layout.* The saved map's cell ``(0, 0)`` becomes cell ``(0, 0)`` of the run's
lattice (``PagedLayout.origin_x, origin_y`` are the map's origin), so the cells keep
their places exactly and a map written back has the saved map's origin. The saved
map is cut into the run's tiles (its last row and column of tiles padded with
unknown cells); every tile of that box takes one pool slot, and all particles' page
tables point to the same slots: they share every tile until one of them writes it
(copy on write, :mod:`jaxslam.grid.paged`). The page table covers the map's tiles and
the new log's odometry box moved to start at the initial pose, with the run's
margin. A map rotated against its frame (``origin`` yaw other than 0) is refused: the
cells of a paged map are aligned with the frame's axes.

Host-side NumPy; the result is the one-particle :class:`~jaxslam.grid.paged.PagedMaps`
that :func:`jaxslam.grid.filter.init` takes as ``start``.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose
from jaxslam.grid.map import CELL_DTYPE
from jaxslam.grid.mapfile import FREE_VALUE, OCCUPIED_VALUE, OccupancyMap
from jaxslam.grid.paged import PINNED, PagedLayout, PagedMaps


class StartMapError(ValueError):
    """A saved map that cannot start this run (its resolution, its rotation)."""


def check_start_map(grid: OccupancyMap, resolution: float) -> None:
    """A :class:`StartMapError` naming the map if it cannot start a run at ``resolution``."""
    name = str(grid.source) if grid.source is not None else "the start map"
    if not math.isclose(grid.resolution, resolution, rel_tol=1e-9, abs_tol=0.0):
        raise StartMapError(f"{name}: resolution {grid.resolution:g} m per cell, but the run's maps are "
                            f"{resolution:g} m")
    if grid.origin[2] != 0.0:
        raise StartMapError(f"{name}: origin yaw {grid.origin[2]:g} rad; only maps aligned with their frame "
                            "(yaw 0) can start a run")


def start_cells(grid: OccupancyMap, resolution: float, log_odds_unit: float, l_max: float) -> np.ndarray:
    """The run's ``int8`` cells ``(H, W)`` of a saved map (see the module docstring).

    Raises:
        StartMapError: another resolution than the run's, or a rotated origin.
    """
    check_start_map(grid, resolution)
    limit = int(math.floor(float(l_max)))
    unit = float(log_odds_unit)
    if grid.cells is not None and grid.log_odds_unit == unit:
        steps = grid.cells.astype(np.int64)
    elif grid.log_odds is not None:
        steps = np.rint(grid.log_odds.astype(np.float64) / unit)
    else:
        values = grid.occupancy.astype(np.int64)
        partial = np.clip(values, 1, 99) / 100.0
        steps = np.where((values >= 1) & (values <= 99), np.rint(np.log(partial / (1.0 - partial)) / unit), 0.0)
        steps = np.where(values == OCCUPIED_VALUE, limit, np.where(values == FREE_VALUE, -limit, steps))
    return np.clip(steps, -limit, limit).astype(CELL_DTYPE)


def moved_odometry(odom: np.ndarray, initial_pose) -> np.ndarray:
    """The odometry poses ``(T, 3)`` moved rigidly so that the first is ``initial_pose``."""
    odom = np.asarray(odom, np.float64)
    relative = se2_between(np.broadcast_to(odom[0], odom.shape), odom)
    return se2_compose(np.broadcast_to(np.asarray(initial_pose, np.float64), odom.shape), relative)


def start_layout(cells: np.ndarray, grid: OccupancyMap, base: PagedLayout, odom: np.ndarray, initial_pose,
                 margin: float) -> PagedLayout:
    """The run's starting layout with a saved map: the map's lattice, a table over the
    map and the moved odometry box (plus ``margin`` m), and room in the pool for the
    map's tiles besides ``base.slots`` (the estimate for an empty start)."""
    ox, oy = float(grid.origin[0]), float(grid.origin[1])
    height, width = cells.shape
    path = moved_odometry(odom, initial_pose)[:, :2]
    xmin = min(ox, float(path[:, 0].min()) - margin)
    ymin = min(oy, float(path[:, 1].min()) - margin)
    xmax = max(ox + width * base.resolution, float(path[:, 0].max()) + margin)
    ymax = max(oy + height * base.resolution, float(path[:, 1].max()) + margin)
    layout = PagedLayout.covering(xmin, ymin, xmax, ymax, base.resolution, base.tile_bits, origin=(ox, oy))
    tiles = _tiles_high(height, base) * _tiles_high(width, base)
    slots = int(2 ** math.ceil(math.log2(base.slots + tiles)))
    return dataclasses.replace(layout, slots=slots)


def _tiles_high(cells: int, layout: PagedLayout) -> int:
    return -(-cells // layout.tile)


def paged_start(cells: np.ndarray, layout: PagedLayout) -> PagedMaps:
    """One particle's paged maps holding ``cells`` with cell ``(0, 0)`` at lattice cell
    ``(0, 0)`` of ``layout``; each tile of the map's box has its own slot (1, 2, ...).

    Raises:
        ValueError: the layout's table or pool cannot hold the map.
    """
    t = layout.tile
    rows, cols = _tiles_high(cells.shape[0], layout), _tiles_high(cells.shape[1], layout)
    count = rows * cols
    x0, y0 = layout.table_x0, layout.table_y0
    if not (x0 <= 0 and y0 <= 0 and cols <= x0 + layout.table_width and rows <= y0 + layout.table_height):
        raise ValueError("the layout's page table does not cover the start map")
    if count + 1 > layout.slots:
        raise ValueError(f"the pool ({layout.slots} tiles) cannot hold the start map's {count} tiles")
    padded = np.zeros((rows * t, cols * t), CELL_DTYPE)
    padded[: cells.shape[0], : cells.shape[1]] = cells
    tiles = padded.reshape(rows, t, cols, t).transpose(0, 2, 1, 3).reshape(count, t * t)
    pool = np.zeros((layout.slots, t * t), CELL_DTYPE)
    pool[1 : count + 1] = tiles
    table = np.zeros((layout.table_height, layout.table_width), np.int32)
    table[-y0 : -y0 + rows, -x0 : -x0 + cols] = np.arange(1, count + 1, dtype=np.int32).reshape(rows, cols)
    refcount = np.zeros((layout.slots,), np.int32)
    refcount[1 : count + 1] = 1
    refcount[0] = PINNED
    return PagedMaps(jnp.asarray(pool.reshape(-1)), jnp.asarray(table.reshape(1, -1)), jnp.asarray(refcount),
                     jnp.asarray([x0, y0], jnp.int32))


__all__ = ["StartMapError", "check_start_map", "moved_odometry", "paged_start", "start_cells", "start_layout"]
