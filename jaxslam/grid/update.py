r"""Ray updates of per-particle grids: every particle and every beam at once.

Inverse sensor model (Thrun, Burgard & Fox 2005, ch. 9, in quantised log-odds): for
one scan, every cell a beam passes through gets :math:`\ell \leftarrow
\mathrm{clip}(\ell + \ell_{free})` and every beam end cell
:math:`\ell \leftarrow \mathrm{clip}(\ell + \ell_{occ})`, each cell at most once per
scan per kind (free first, then occupied), clamped to ``[-l_max, l_max]``.

The cells of each beam (Bresenham lines, laid out in rows for batching over
particles and beams) come from :mod:`jaxslam.grid.rays`; names from there are
re-exported here for existing callers.

The update gathers the old values, computes the new ones and scatters them back
with ``set``: a cell touched by several beams gets the same value from each, which
gives the once-per-scan semantics and never overflows ``int8``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.grid.map import GridSpec
from jaxslam.grid.paged import (
    STATUS_OK,
    MapStatus,
    PagedLayout,
    PagedMaps,
    local_cell,
    plan_writes,
    window_index,
    window_side,
)
from jaxslam.grid.rays import (  # re-exported (see __all__) for existing callers
    BeamLayout,
    ROW,
    RayGeometry,
    ScanRays,
    beam_layout,
    beam_lengths,
    cell_at,
    chunk_cell_coords,
    chunk_rows_of,
    free_cell_coords,
    free_cells,
    hit_cells,
    num_rows,
    ray_cells,
    ray_geometry,
    required_points,
    samples_per_beam,
    scan_rays,
    sensor_pose_of,
)


def _apply(flat: Array, idx: Array, increment: Array, l_max: Array) -> Array:
    old = flat.at[idx].get(mode="fill", fill_value=0).astype(jnp.int32)
    new = jnp.clip(old + increment, -l_max, l_max).astype(flat.dtype)
    return flat.at[idx].set(new, mode="drop")


def quantise(value) -> Array:
    """A traced log-odds increment as an int32 step count."""
    return jnp.round(jnp.asarray(value)).astype(jnp.int32)


def update_grid(grid: Array, free_cells: Array, hit_cells: Array, l_free, l_occ, l_max) -> Array:
    """Integrate one scan into one particle's grid ``(H, W)`` (see module docstring).

    Args:
        grid: ``(H, W)`` int8 quantised log-odds.
        free_cells, hit_cells: flat indices of the scan's free and hit cells, from
            :func:`~jaxslam.grid.rays.ray_cells` (the sentinel ``H * W`` skips a slot).
        l_free, l_occ, l_max: log-odds steps (traced, rounded to integers).
    """
    flat = grid.reshape(-1)
    l_max = jnp.clip(quantise(l_max), 0, 127)
    flat = _apply(flat, free_cells, quantise(l_free), l_max)
    flat = _apply(flat, hit_cells, quantise(l_occ), l_max)
    return flat.reshape(grid.shape)


def integrate_rays(flat: Array, rays: ScanRays, index_of, l_free, l_occ, l_max) -> Array:
    """Apply the inverse sensor model of one scan to a flat cell buffer.

    ``index_of(cols, rows, ok) -> (P, n)`` maps the cells of every particle to
    indices into ``flat`` (``flat.shape[0]`` or more for slots to skip). Pass 1 reads
    every free cell before pass 2 writes any, so that a cell crossed by beams of
    several chunks still changes once per scan (pass 1 keeps the indices it computed,
    so pass 2 does not look the cells up again); then the hit cells. Both passes run
    only over the chunks this scan uses; the buffer rides through the loops as loop
    state so that XLA can update a donated buffer in place.
    """
    l_max = jnp.clip(quantise(l_max), 0, 127)
    inc_free, inc_occ = quantise(l_free), quantise(l_occ)
    num_particles = rays.geometry.start.shape[0]
    width = rays.chunk_rows * ROW
    chunks = rays.beam.shape[0] // rays.chunk_rows  # static; the rows are padded to whole chunks

    # Chunk-major buffers (chunk, particle, cell): a chunk's values are one contiguous
    # block. Indices are unsigned (never negative; the skip index is ``flat.shape[0]``
    # or more): no wrap-around of negative indices per cell. The old values are
    # gathered through the indices just stored, so the cells' coordinates are computed
    # once, not again inside the gather's kernel.
    def read_body(i, carry):
        flat, olds, idxs = carry
        idxs = jax.lax.dynamic_update_index_in_dim(idxs, index_of(*chunk_cell_coords(rays, i)).astype(jnp.uint32), i, 0)
        old = flat.at[jax.lax.dynamic_index_in_dim(idxs, i, 0, keepdims=False)].get(mode="fill", fill_value=0)
        return flat, jax.lax.dynamic_update_index_in_dim(olds, old, i, 0), idxs

    olds = jnp.zeros((chunks, num_particles, width), flat.dtype)
    idxs = jnp.zeros((chunks, num_particles, width), jnp.uint32)
    flat, olds, idxs = jax.lax.fori_loop(0, rays.num_chunks, read_body, (flat, olds, idxs))
    # The scatter takes its indices and values flat. Flattened here, outside the loop (a
    # bitcast of the buffers), each chunk is one linear slice; flattened per chunk, XLA's
    # loop emitters copy it element by element (about 50 us a chunk for each buffer).
    olds, idxs = olds.reshape(chunks, -1), idxs.reshape(chunks, -1)

    def write_body(i, flat):
        idx = jax.lax.dynamic_index_in_dim(idxs, i, 0, keepdims=False)
        old = jax.lax.dynamic_index_in_dim(olds, i, 0, keepdims=False).astype(jnp.int32)
        new = jnp.clip(old + inc_free, -l_max, l_max).astype(flat.dtype)
        return flat.at[idx].set(new, mode="drop")

    flat = jax.lax.fori_loop(0, rays.num_chunks, write_body, flat)
    end = rays.geometry.end
    hit_idx = index_of(end[..., 0], end[..., 1], jnp.broadcast_to(rays.hits, end.shape[:-1]))
    return _apply(flat, hit_idx, inc_occ, l_max)


def update_grids(
    grids: Array,
    poses: Array,
    ranges: Array,
    beam_valid: Array,
    angles: Array,
    laser_offset: Array,
    spec: GridSpec,
    max_points: int,
    usable_range,
    l_free,
    l_occ,
    l_max,
    chunk_rows: int = 128,
) -> tuple[Array, Array]:
    """Integrate one scan into dense grids ``(P, H, W)`` at robot ``poses (P, 3)``.

    Same result as :func:`update_grid` of each particle's
    :func:`~jaxslam.grid.rays.ray_cells`, but the free cells are processed
    ``chunk_rows`` rows at a time and only as many chunks run as this scan needs
    (:func:`integrate_rays`), so a short scan does not pay for the
    ``max_points`` budget. The dense reference of the paged maps
    (:func:`update_paged`).

    Returns:
        ``(grids, dropped)`` where ``dropped`` counts ray samples past the budget.
    """
    rays = scan_rays(poses, ranges, beam_valid, angles, laser_offset, spec, max_points, usable_range, chunk_rows)
    base = (jnp.arange(grids.shape[0], dtype=jnp.int32) * spec.num_cells)[:, None]
    total = grids.size

    def index_of(cols, rows, ok):
        inside = ok & (cols >= 0) & (cols < spec.width) & (rows >= 0) & (rows < spec.height)
        return jnp.where(inside, base + rows * spec.width + cols, total)

    flat = integrate_rays(grids.reshape(-1), rays, index_of, l_free, l_occ, l_max)
    return flat.reshape(grids.shape), rays.dropped


def touched_tiles(rays: ScanRays, x0: Array, y0: Array, side: int, layout: PagedLayout) -> Array:
    """``(P, side * side)`` bool: the window tiles that one scan's cells fall in.

    A row of :data:`~jaxslam.grid.rays.ROW` consecutive cells of one beam (``ROW`` < tile size) spans at
    most two tile columns and two tile rows; marking the tiles of its first and last
    cell and of their two corner combinations covers every tile it touches (and at
    most one it only passes by, which then gets a slot it does not need). Hit cells are
    marked one by one.
    """
    entries = side * side + 1
    offset = (jnp.arange(rays.geometry.start.shape[0], dtype=jnp.int32) * entries)[:, None]

    def mark(marks, cols, rows, ok):
        # One flat index per cell into (P, side * side + 1) marks, the last column for
        # cells to skip: XLA's CPU scatter with one index per update is about twice as
        # fast as with (row, column) pairs.
        rel = window_index(cols, rows, x0[:, None], y0[:, None], side, layout)
        return marks.at[(jnp.where(ok, rel, side * side) + offset).reshape(-1)].set(True)

    def chunk(i, marks):  # only the chunks the write loop runs (rays.num_chunks)
        beam, first, active = chunk_rows_of(rays, i)
        k_last = jnp.minimum(first + ROW - 1, jnp.where(active, rays.geometry.count[:, beam], 0) - 1)
        used = active & (first <= k_last)
        c0, r0 = jax.vmap(cell_at, (0, None, None))(rays.geometry, beam, first)
        c1, r1 = jax.vmap(cell_at, (0, None, 0))(rays.geometry, beam, k_last)
        return mark(marks, jnp.concatenate([c0, c1, c0, c1], 1), jnp.concatenate([r0, r1, r1, r0], 1),
                    jnp.concatenate([used, used, used, used], 1))

    end = rays.geometry.end
    marks = jnp.zeros((offset.shape[0] * entries,), bool)
    marks = mark(marks, end[..., 0], end[..., 1], jnp.broadcast_to(rays.hits, end.shape[:-1]))
    marks = jax.lax.fori_loop(0, rays.num_chunks, chunk, marks)
    return marks.reshape(-1, entries)[:, :-1]


def update_paged(
    maps: PagedMaps,
    layout: PagedLayout,
    poses: Array,
    ranges: Array,
    beam_valid: Array,
    angles: Array,
    laser_offset: Array,
    max_points: int,
    usable_range,
    window_range: float,
    l_free,
    l_occ,
    l_max,
    chunk_rows: int = 128,
) -> tuple[PagedMaps, Array, MapStatus]:
    """Integrate one scan into every particle's paged map at robot ``poses (P, 3)``.

    The arguments are those of :func:`update_grids` (the scan, the sensor and the map's
    log-odds values, as the filter holds them in its state, config and params) with
    the paged maps and their layout in place of the dense grids.

    The cells and values are those of :func:`update_grids` on dense grids; the tiles
    they fall in are allocated or copied first (:func:`jaxslam.grid.paged.plan_writes`).
    ``window_range`` (static, m) sizes the window of tiles around each sensor; the
    traced ``sensor.usable_range`` is cropped to it. When the plan is refused (pool full, or a tile outside the page table)
    the maps come back unchanged with the reason in the status.

    Returns:
        ``(maps, dropped, status)``.
    """
    usable = jnp.minimum(usable_range, jnp.asarray(window_range, poses.dtype))
    rays = scan_rays(poses, ranges, beam_valid, angles, laser_offset, layout, max_points, usable, chunk_rows)
    side = window_side(float(window_range), layout)
    half = side // 2
    x0 = (rays.geometry.start[:, 0] >> layout.tile_bits) - half
    y0 = (rays.geometry.start[:, 1] >> layout.tile_bits) - half
    plan = plan_writes(maps, touched_tiles(rays, x0, y0, side, layout), x0, y0, side, layout)
    slots = jnp.pad(plan.slots, ((0, 0), (0, 1)))
    pool_size = plan.maps.pool.size
    rows_p = jnp.arange(slots.shape[0])[:, None]

    def index_of(cols, rows, ok):
        rel = window_index(cols, rows, x0[:, None], y0[:, None], side, layout)
        slot = slots[rows_p, rel]
        use = ok & (slot > 0)
        return jnp.where(use, slot * layout.tile_cells + local_cell(cols, rows, layout), pool_size)

    # A refused plan writes nothing: no chunk runs and every hit index is dropped
    # (masks, not a conditional, which would copy the pool).
    rays = rays._replace(num_chunks=jnp.where(plan.status.code == STATUS_OK, rays.num_chunks, 0),
                         hits=rays.hits & (plan.status.code == STATUS_OK))
    pool = plan.maps.pool
    pool = integrate_rays(pool.reshape(-1), rays, index_of, l_free, l_occ, l_max).reshape(pool.shape)
    return plan.maps._replace(pool=pool), rays.dropped, plan.status


__all__ = [
    "ROW",
    "BeamLayout",
    "RayGeometry",
    "beam_layout",
    "beam_lengths",
    "ScanRays",
    "cell_at",
    "chunk_cell_coords",
    "free_cell_coords",
    "free_cells",
    "integrate_rays",
    "scan_rays",
    "hit_cells",
    "num_rows",
    "quantise",
    "ray_cells",
    "ray_geometry",
    "required_points",
    "samples_per_beam",
    "sensor_pose_of",
    "touched_tiles",
    "update_grid",
    "update_paged",
    "update_grids",
]
