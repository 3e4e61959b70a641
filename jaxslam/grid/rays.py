r"""Ray geometry of one scan: which cells each beam crosses, laid out for batching.

Cells along a beam are the integer Bresenham line between the sensor cell
:math:`c_0` and the end cell :math:`c_1` (as GMapping's ``GridLineTraversal``): with
:math:`\Delta = c_1 - c_0` and :math:`n = \max(|\Delta_x|, |\Delta_y|)`,

.. math:: c_k = c_0 + \left\lfloor \frac{2 k \Delta + n}{2 n} \right\rfloor,
    \qquad k = 0, \dots, n,

cells :math:`k < n` are free and :math:`c_n` is the hit (not for a beam cropped at
the usable range, as in GMapping). The quotient is evaluated as
:math:`k \cdot \mathrm{fl}(\Delta/n)` in float32 with a tie margin (see
:func:`ray_geometry`), one multiply per cell, and equals the integer formula for beams
up to 1600 cells, whatever the pose dtype.

Batching: :math:`n \le \lfloor d/r \rfloor + 1` for a beam of length :math:`d`, a
bound shared by all particles. :func:`beam_layout` lays the samples ``(beam, k)`` of
one scan out in rows of :data:`ROW` consecutive samples of one beam,
``ceil(K_b / ROW)`` rows for ``K_b = floor(d_b / r) + 2``, within a static budget
(samples past it are dropped and counted), so a scan costs about its total beam
length in cells, not beams x the longest beam, and per-beam values are gathered once
per row.

The updates that use these cells are in :mod:`jaxslam.grid.update`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core import se2
from jaxslam.grid.map import GridSpec, flat_index

ROW = 16
"""Slots per layout row (a row holds ``ROW`` consecutive samples of one beam)."""


class BeamLayout(NamedTuple):
    """Row layout of the ray samples of one scan (shared by all particles).

    Row ``j`` holds samples ``k = first[j] .. first[j] + ROW - 1`` of beam ``beam[j]``;
    per-beam quantities are gathered once per row, not once per sample.
    """

    beam: Array  # (R,) int32 beam of each row
    first: Array  # (R,) int32 first sample index k of each row
    active: Array  # (R,) bool row in use
    rows: Array  # () int32 rows in use
    dropped: Array  # () int32 samples that did not fit


def beam_lengths(ranges: Array, beam_valid: Array, usable_range) -> tuple[Array, Array]:
    """Traced length of each beam for the map and whether it ends in a hit.

    Args:
        ranges: ``(B,)`` measured ranges.
        beam_valid: ``(B,)`` bool; False for missing, NaN or no-return readings.
        usable_range: beams are cropped here (free cells only, no hit).

    Returns:
        ``(lengths (B,), hits (B,))``; invalid beams get length 0 and no hit.
    """
    usable = jnp.asarray(usable_range, ranges.dtype)
    safe = jnp.where(beam_valid, ranges, 0.0)
    lengths = jnp.where(beam_valid, jnp.minimum(safe, usable), 0.0)
    hits = beam_valid & (safe <= usable)
    return lengths, hits


def samples_per_beam(lengths: Array, beam_valid: Array, resolution: float) -> Array:
    """``K_b = floor(d_b / r) + 2`` samples per valid beam (0 for invalid beams)."""
    per = jnp.floor(lengths / jnp.asarray(resolution, lengths.dtype)).astype(jnp.int32) + 2
    return jnp.where(beam_valid, per, 0)


def num_rows(max_points: int, num_beams: int) -> int:
    """Static row count for a budget of ``max_points`` samples (worst-case padding)."""
    return -(-max_points // ROW) + num_beams


def beam_layout(lengths: Array, beam_valid: Array, resolution: float, max_rows: int) -> BeamLayout:
    """Lay the Bresenham samples of one scan out in ``max_rows`` rows of :data:`ROW`."""
    per = samples_per_beam(lengths, beam_valid, resolution)
    rows_per = (per + ROW - 1) // ROW
    ends = jnp.cumsum(rows_per)
    starts = ends - rows_per
    row = jnp.arange(max_rows, dtype=jnp.int32)
    beam = jnp.minimum(jnp.searchsorted(ends, row, side="right"), lengths.shape[0] - 1).astype(jnp.int32)
    first = (row - starts[beam]) * ROW
    total = ends[-1]
    active = row < total
    # Samples of rows past the budget are lost; count the real samples in them.
    kept_per_beam = jnp.clip(max_rows - starts, 0, rows_per) * ROW
    lost = jnp.sum(jnp.maximum(per - kept_per_beam, 0))
    return BeamLayout(beam, first, active, jnp.minimum(total, max_rows).astype(jnp.int32), lost.astype(jnp.int32))


def required_points(lengths, beam_valid, resolution: float) -> int:
    """Host helper: the samples one scan needs (``sum K_b``, max over scans), for
    sizing ``max_points``."""
    import numpy as np

    # In place on one float64 copy (a whole log is millions of beams); the sums of
    # whole numbers are exact in float64.
    per = np.array(lengths, np.float64)
    per /= resolution
    np.floor(per, out=per)
    per += 2.0
    np.copyto(per, 0.0, where=~np.asarray(beam_valid, bool))  # also an invalid NaN
    return int(per.sum(-1).max()) if per.ndim > 1 else int(per.sum())


_TIE_EPS = 1e-4


class RayGeometry(NamedTuple):
    """Per-particle Bresenham geometry of one scan: sensor cell and per-beam steps."""

    start: Array  # (2,) int32 sensor cell (col, row)
    end: Array  # (B, 2) int32 end cells
    steps: Array  # (B, 2) float32 per-step increments Delta / n
    count: Array  # (B,) int32 n = max(|Delta_col|, |Delta_row|)


def ray_geometry(sensor_pose: Array, lengths: Array, angles: Array, spec: GridSpec) -> RayGeometry:
    """Sensor and end cells of every beam for one particle's laser pose ``(3,)``."""
    dtype = sensor_pose.dtype
    heading = sensor_pose[2] + angles.astype(dtype)
    ends = sensor_pose[:2] + lengths.astype(dtype)[:, None] * jnp.stack([jnp.cos(heading), jnp.sin(heading)], -1)
    res = jnp.asarray(spec.resolution, dtype)
    origin = jnp.asarray([spec.origin_x, spec.origin_y], dtype)
    start = jnp.floor((sensor_pose[:2] - origin) / res).astype(jnp.int32)
    end = jnp.floor((ends - origin) / res).astype(jnp.int32)
    delta = end - start
    count = jnp.max(jnp.abs(delta), -1)
    steps = delta.astype(jnp.float32) / jnp.maximum(count, 1).astype(jnp.float32)[:, None]
    return RayGeometry(start, end, steps, count)


def free_cell_coords(geometry: RayGeometry, beam: Array, first: Array, active: Array) -> tuple[Array, Array, Array]:
    r"""Cells ``(cols, rows)`` ``(R, ROW)`` of the free samples of rows ``(beam, first, active)``
    and whether each slot holds one.

    Cell ``k`` of a beam is :math:`c_0 + \mathrm{round}(k \Delta / n)` (ties up), for
    ``k < n``. ``k \Delta / n`` is formed as ``k * fl(Delta / n)``, whose float32 error
    stays below ``1e-4`` for ``k <= 1600``; adding that margin before the floor rounds
    exact ties up (as ``floor((2 k Delta + n) / (2 n))``) while the nearest non-tie is
    ``1 / (2n) > 3e-4`` away, so the cells equal the integer formula for beams of up to
    1600 cells.
    """
    k = first[:, None] + jnp.arange(ROW, dtype=jnp.int32)[None, :]
    count = jnp.where(active, geometry.count[beam], 0)
    cols, rows = cell_at(geometry, beam[:, None], k)
    return cols, rows, k < count[:, None]


def cell_at(geometry: RayGeometry, beam: Array, k: Array) -> tuple[Array, Array]:
    """Cell ``k`` of beam ``beam`` (broadcasting), by the rounding rule of :func:`free_cell_coords`."""
    kf = k.astype(jnp.float32)
    steps = geometry.steps[beam]
    cols = geometry.start[0] + jnp.floor(kf * steps[..., 0] + (0.5 + _TIE_EPS)).astype(jnp.int32)
    rows = geometry.start[1] + jnp.floor(kf * steps[..., 1] + (0.5 + _TIE_EPS)).astype(jnp.int32)
    return cols, rows


def free_cells(geometry: RayGeometry, beam: Array, first: Array, active: Array, spec: GridSpec) -> Array:
    """Flat indices ``(R, ROW)`` of the free cells of rows ``(beam, first, active)`` in a
    dense grid (:func:`free_cell_coords`); other slots get the sentinel."""
    cols, rows, ok = free_cell_coords(geometry, beam, first, active)
    return jnp.where(ok, flat_index(cols, rows, spec), spec.num_cells)


def hit_cells(geometry: RayGeometry, hits: Array, spec: GridSpec) -> Array:
    """Flat indices ``(B,)`` of the end cells of the beams that hit (sentinel otherwise)."""
    return jnp.where(hits, flat_index(geometry.end[:, 0], geometry.end[:, 1], spec), spec.num_cells)


def ray_cells(
    sensor_pose: Array,
    lengths: Array,
    hits: Array,
    angles: Array,
    layout: BeamLayout,
    spec: GridSpec,
) -> tuple[Array, Array]:
    """Flat indices of the free cells ``(R * ROW,)`` and hit cells ``(B,)`` of one particle.

    Unused slots and cells outside the grid get the sentinel ``spec.num_cells``.
    """
    geometry = ray_geometry(sensor_pose, lengths, angles, spec)
    free = free_cells(geometry, layout.beam, layout.first, layout.active, spec)
    return free.reshape(-1), hit_cells(geometry, hits, spec)


def sensor_pose_of(pose: Array, laser_offset: Array) -> Array:
    """The laser pose ``pose ⊕ laser_offset``."""
    return se2.compose(pose, laser_offset.astype(pose.dtype))


class ScanRays(NamedTuple):
    """One scan's ray samples for every particle, laid out in chunks of rows."""

    geometry: RayGeometry  # batched over particles
    beam: Array  # (padded_rows,) int32
    first: Array  # (padded_rows,) int32
    active: Array  # (padded_rows,) bool
    hits: Array  # (B,) bool
    num_chunks: Array  # () int32 chunks this scan uses
    chunk_rows: int
    dropped: Array  # () int32 samples past the budget


def scan_rays(
    poses: Array,
    ranges: Array,
    beam_valid: Array,
    angles: Array,
    laser_offset: Array,
    frame,
    max_points: int,
    usable_range,
    chunk_rows: int = 128,
) -> ScanRays:
    """Ray geometry of one scan at robot ``poses (P, 3)`` and its chunked row layout.

    ``frame`` is anything with ``resolution``, ``origin_x`` and ``origin_y`` (a
    :class:`~jaxslam.grid.map.GridSpec` or a paged layout).
    """
    num_beams = ranges.shape[0]
    lengths, hits = beam_lengths(ranges, beam_valid, usable_range)
    max_rows = num_rows(max_points, num_beams)
    chunk_rows = min(chunk_rows, max_rows)
    padded_rows = -(-max_rows // chunk_rows) * chunk_rows
    layout = beam_layout(lengths, beam_valid, frame.resolution, max_rows)
    pad = padded_rows - max_rows
    sensor = sensor_pose_of(poses, laser_offset)
    geometry = jax.vmap(lambda p: ray_geometry(p, lengths, angles, frame))(sensor)
    return ScanRays(
        geometry,
        jnp.pad(layout.beam, (0, pad)),
        jnp.pad(layout.first, (0, pad)),
        jnp.pad(layout.active, (0, pad)),
        hits,
        (layout.rows + chunk_rows - 1) // chunk_rows,
        chunk_rows,
        layout.dropped,
    )


def chunk_rows_of(rays: ScanRays, i) -> tuple[Array, Array, Array]:
    """Rows ``(chunk_rows,)`` of chunk ``i``: their beam, first cell and whether in use."""
    start = i * rays.chunk_rows
    return tuple(jax.lax.dynamic_slice_in_dim(a, start, rays.chunk_rows) for a in (rays.beam, rays.first, rays.active))


def chunk_cell_coords(rays: ScanRays, i) -> tuple[Array, Array, Array]:
    """Free cells ``(P, chunk_rows * ROW)`` (cols, rows, in use) of chunk ``i``."""
    cols, rows, ok = jax.vmap(free_cell_coords, (0, None, None, None))(rays.geometry, *chunk_rows_of(rays, i))
    shape = (cols.shape[0], -1)
    return cols.reshape(shape), rows.reshape(shape), ok.reshape(shape)


__all__ = [
    "BeamLayout",
    "ROW",
    "RayGeometry",
    "ScanRays",
    "beam_layout",
    "beam_lengths",
    "cell_at",
    "chunk_cell_coords",
    "chunk_rows_of",
    "free_cell_coords",
    "free_cells",
    "hit_cells",
    "num_rows",
    "ray_cells",
    "ray_geometry",
    "required_points",
    "samples_per_beam",
    "scan_rays",
    "sensor_pose_of",
]
