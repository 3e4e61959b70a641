r"""Dense per-particle occupancy grids: geometry and cell type.

A grid is an ``int8`` array ``(height, width)`` of quantised log-odds
:math:`\ell = \log\frac{p}{1-p} / u` with a unit ``u`` (``GridParams.log_odds_unit``,
natural log-odds per step), clamped to ``[-l_max, l_max]`` (``l_max <= 127``). The
filters hold one grid per particle, ``(particles, height, width)``.

Memory: one byte per cell. A building floor at 5 cm in a 45 m x 45 m box is
900 x 900 = 0.81 MB per particle, 810 MB for 1000 particles (GMapping's
``PointAccumulator`` uses 32 bytes per cell). ``int8`` keeps enough levels for the
usual inverse sensor model (e.g. +4 per hit, -1 per pass-through, clamp at 100) and
halves the resampling copies against ``int16``.

Geometry (:class:`GridSpec`, static): cell ``(row, col)`` covers world
``[ox + col r, ox + (col+1) r) x [oy + row r, oy + (row+1) r)``; rows grow with
``y``. Flat index ``row * width + col``; out-of-grid cells map to the sentinel
``height * width``, which scatters drop and gathers read as unknown (0).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jax import Array

CELL_DTYPE = jnp.int8
"""Cell type of every grid and tile pool (``int8`` quantised log-odds, one byte per cell)."""

CellReader = Callable[[Array, Array], Array]
"""``(cols, rows) -> cells``: the int8 cells of one map at integer coordinates of any
shape, 0 (unknown) outside it. The score functions read maps only through one of
these, so a dense grid (:func:`dense_reader`) and a paged map
(:func:`jaxslam.grid.paged.reader`) score alike."""


@dataclass(frozen=True)
class GridSpec:
    """Static grid geometry: shape, resolution (m/cell) and world origin of cell (0, 0)."""

    height: int
    width: int
    resolution: float = 0.05
    origin_x: float = 0.0
    origin_y: float = 0.0

    @property
    def num_cells(self) -> int:
        return self.height * self.width

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` in metres."""
        return (
            self.origin_x,
            self.origin_y,
            self.origin_x + self.width * self.resolution,
            self.origin_y + self.height * self.resolution,
        )

    def bytes_per_particle(self) -> int:
        return self.num_cells * np.dtype(np.int8).itemsize

    @classmethod
    def from_bounds(
        cls, xmin: float, ymin: float, xmax: float, ymax: float, resolution: float = 0.05, multiple: int = 8
    ) -> GridSpec:
        """The smallest grid covering a box, with sides rounded up to ``multiple`` cells."""
        width = math.ceil((xmax - xmin) / resolution / multiple) * multiple
        height = math.ceil((ymax - ymin) / resolution / multiple) * multiple
        return cls(max(height, multiple), max(width, multiple), float(resolution), float(xmin), float(ymin))

    @classmethod
    def around_path(
        cls, positions: np.ndarray, margin: float, resolution: float = 0.05, multiple: int = 8
    ) -> GridSpec:
        """A grid covering ``positions (k, 2)`` plus ``margin`` metres on every side."""
        positions = np.asarray(positions, np.float64).reshape(-1, 2)
        lo = positions.min(0) - margin
        hi = positions.max(0) + margin
        return cls.from_bounds(lo[0], lo[1], hi[0], hi[1], resolution, multiple)


def init_grids(num_particles: int, spec: GridSpec) -> Array:
    """All-unknown grids ``(particles, height, width)`` of :data:`CELL_DTYPE`."""
    return jnp.zeros((num_particles, spec.height, spec.width), CELL_DTYPE)


def dense_reader(grid: Array, spec: GridSpec) -> CellReader:
    """The :data:`CellReader` of one dense grid ``(H, W)``."""
    flat = grid.reshape(-1)

    def read(cols: Array, rows: Array) -> Array:
        return flat.at[flat_index(cols, rows, spec)].get(mode="fill", fill_value=0)

    return read


def world_to_grid(points: Array, spec: GridSpec) -> Array:
    """Continuous grid coordinates ``(..., 2)`` = ``(col, row)`` of world points."""
    origin = jnp.asarray([spec.origin_x, spec.origin_y], points.dtype)
    return (points - origin) / jnp.asarray(spec.resolution, points.dtype)


def cell_of(points: Array, spec: GridSpec) -> Array:
    """Integer cells ``(..., 2)`` = ``(col, row)`` containing world points (int32)."""
    return jnp.floor(world_to_grid(points, spec)).astype(jnp.int32)


def flat_index(cols: Array, rows: Array, spec: GridSpec) -> Array:
    """Flat indices, with the sentinel ``num_cells`` for cells outside the grid."""
    inside = (cols >= 0) & (cols < spec.width) & (rows >= 0) & (rows < spec.height)
    return jnp.where(inside, rows * spec.width + cols, spec.num_cells).astype(jnp.int32)


def log_odds(grid: Array, unit) -> Array:
    """Natural log-odds (float) of a quantised grid."""
    unit = jnp.asarray(unit)
    return grid.astype(jnp.result_type(unit.dtype, jnp.float32)) * unit


def probability(grid: Array, unit) -> Array:
    """Occupancy probability ``sigmoid(log-odds)``; unknown cells give 0.5."""
    lo = log_odds(grid, unit)
    return 1.0 / (1.0 + jnp.exp(-lo))


__all__ = [
    "CELL_DTYPE",
    "CellReader",
    "dense_reader",
    "GridSpec",
    "cell_of",
    "flat_index",
    "init_grids",
    "log_odds",
    "probability",
    "world_to_grid",
]
