r"""Paged per-particle occupancy maps: tiles in one shared pool, copy on write.

Cells are ``int8`` quantised log-odds as in :mod:`jaxslam.grid.map`. They live in
square tiles of ``T x T`` cells (``T = 2**tile_bits``, 64 by default: 3.2 m at 5 cm)
held in one flat pool of ``S * T*T`` cells (slot ``s`` is cells ``[s T^2, (s+1) T^2)``)
shared by all particles. Each particle has a page table
``(TY * TX,)`` from tile coordinates to pool slots; the table covers the tile box
``[x_c, x_c + TX) x [y_c, y_c + TY)`` in the map frame (``(x_c, y_c)`` the table's
*corner*, ``PagedMaps.corner``, a traced value: see *Growth*), whose
cell ``(c, r)`` is the square ``[c r_s, (c+1) r_s) x [r r_s, (r+1) r_s)`` (``r_s``
the resolution; negative coordinates are fine). A cell is read as

.. math:: \mathrm{pool}\big[T^2\, \mathrm{table}[t_y - y_c, t_x - x_c] + (r \bmod T)\,T + (c \bmod T)\big],
    \qquad t_x = \lfloor c / T \rfloor,\ t_y = \lfloor r / T \rfloor,

with slot 0 a tile that is never written: unknown (0) everywhere, so unallocated
tiles and tiles outside the table read as unknown.

*Sharing.* ``refcount[s]`` counts the page-table entries (over all particles) that
point to slot ``s``. Resampling gathers page tables, never cells, and recounts
(a scatter-add over the tables, only at steps that resample). A write goes through
:func:`plan_writes`: every tile a particle will write this step is *touched*; a
touched tile that is unallocated gets a fresh slot (a copy of slot 0), one shared
with other particles gets a private copy first (copy on write). When all holders
of a shared slot write it in the same step, the first of them (lowest particle
index) keeps the original and only the others copy. A slot whose count drops to 0
is free: allocation takes the lowest free slots (``nonzero`` order), so the slots a
run uses do not depend on how large the pool is, and a run that grows its pool
gives the same maps as one that started with the larger pool. Freed slots are
reclaimed by that same rule (no separate sweep); their old content is overwritten
by the copy that fills them.

*Growth.* The pool and the table have static shapes; the table's corner does not.
When a step needs more free slots than the pool has, or touches a tile outside the
table, the step is not applied: :class:`MapStatus` records why and what was wanted,
the state is left as it was, and the host makes room (:func:`grow`) and runs the
step again. A full pool doubles (one recompilation). A table that the robot leaves
is first *moved*: if the box of the tiles any particle holds, joined with the wanted
tiles, fits in the table's size with ``margin_tiles`` to spare on each side, the
corner moves so that this box sits in the middle and the entries move with it (a
host copy of the tables, no recompilation, the same cells). Only when it does not
fit does the table grow (to that box with the margin, and by at least half its size
in each dimension that is too small; one recompilation). The starting table covers the odometry box, which on
a log with heading drift can lie far from where the robot really goes (hundreds of
metres off on a long log): moving it costs nothing where growing it twice cost two compilations of the filter.

Cost: a write touches only the tiles under the scan; resampling copies page tables
(``P x TY x TX`` int32) and no cells; memory is ``S x T^2`` bytes for the pool, so it
grows with the area actually seen and with how far the particles' maps differ,
not with particles times the box of the environment.

Size: one module of a little over 400 lines on purpose: the layout, reads, the write
plan with its reference counts, resampling, growth and stitching all maintain the
same invariant (``refcount`` equals the number of table entries per slot, slot 0
pinned), and keeping them side by side is what makes that invariant checkable.

One module of about 480 lines: the layout, the reads, the write plan, the resampling
copies and the growth all index the same pool and page tables, and change together
whenever the layout does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.grid.map import CELL_DTYPE

PINNED = 1 << 30
"""Reference count of slot 0, the unknown tile, which is never freed and never written."""

STATUS_OK = 0
STATUS_POOL_FULL = 1
STATUS_OUTSIDE_TABLE = 2


class PoolLimitError(ValueError):
    """The maps need a pool of more cells than ``int32`` indexing reaches (2**31)."""


@dataclass(frozen=True)
class PagedLayout:
    """Static geometry of paged maps: resolution, tile size, page-table box, pool size.

    Attributes:
        resolution: metres per cell.
        tile_bits: tiles are ``2**tile_bits`` cells on a side.
        table_x0, table_y0: tile coordinates of page-table entry ``(0, 0)`` when the
            maps are made; the table can move later (``PagedMaps.corner``).
        table_width, table_height: page-table size in tiles (``TX``, ``TY``).
        slots: pool size in tiles, slot 0 (unknown) included.
        origin_x, origin_y: world position (m) of the corner of cell ``(0, 0)``
            (0 by default; any value shifts the whole cell lattice).
    """

    resolution: float = 0.05
    tile_bits: int = 6
    table_x0: int = 0
    table_y0: int = 0
    table_width: int = 1
    table_height: int = 1
    slots: int = 2
    origin_x: float = 0.0
    origin_y: float = 0.0

    def __post_init__(self):
        if not self.resolution > 0:
            raise ValueError(f"resolution must be > 0, got {self.resolution}")
        if not 2 <= self.tile_bits <= 10:
            raise ValueError(f"tile_bits must be in 2..10, got {self.tile_bits}")
        if self.table_width < 1 or self.table_height < 1:
            raise ValueError("the page table needs at least one tile")
        if self.slots < 2:
            raise ValueError(f"the pool needs at least 2 slots, got {self.slots}")
        if self.slots * self.tile_cells >= 2**31:
            raise PoolLimitError(f"a map pool of {self.slots} tiles of {self.tile_cells} cells exceeds int32 cell "
                                 "indexing (2**31 cells)")

    @property
    def tile(self) -> int:
        return 1 << self.tile_bits

    @property
    def tile_cells(self) -> int:
        return self.tile * self.tile

    @property
    def tile_metres(self) -> float:
        return self.tile * self.resolution

    @property
    def table_size(self) -> int:
        return self.table_width * self.table_height

    def pool_bytes(self) -> int:
        return self.slots * self.tile_cells * np.dtype(np.int8).itemsize

    @classmethod
    def covering(
        cls, xmin: float, ymin: float, xmax: float, ymax: float, resolution: float = 0.05, tile_bits: int = 6,
        slots: int = 2, origin: tuple[float, float] = (0.0, 0.0),
    ) -> PagedLayout:
        """A table over the tiles that cover the box ``[xmin, xmax] x [ymin, ymax]`` (m)."""
        tm = (1 << tile_bits) * resolution
        x0, y0 = math.floor((xmin - origin[0]) / tm), math.floor((ymin - origin[1]) / tm)
        x1, y1 = math.floor((xmax - origin[0]) / tm), math.floor((ymax - origin[1]) / tm)
        return cls(float(resolution), tile_bits, x0, y0, x1 - x0 + 1, y1 - y0 + 1, int(slots), float(origin[0]),
                   float(origin[1]))

    def with_table(self, x0: int, y0: int, x1: int, y1: int) -> PagedLayout:
        """The same layout with a table over tiles ``[x0, x1] x [y0, y1]`` (inclusive)."""
        return replace(self, table_x0=int(x0), table_y0=int(y0), table_width=int(x1 - x0 + 1),
                       table_height=int(y1 - y0 + 1))


class PagedMaps(NamedTuple):
    """The maps of all particles: the shared pool, page tables, reference counts."""

    pool: Array  # (S*T*T,) int8, flat (see ``reader``)
    tables: Array  # (P, TY*TX) int32 slot per tile (0: unknown)
    refcount: Array  # (S,) int32
    corner: Array  # (2,) int32 tile (x, y) of table entry 0 (moves when the table does)


class MapStatus(NamedTuple):
    """Why the last step was not applied (``code != 0``) and what it needed."""

    code: Array  # () int32: STATUS_OK / STATUS_POOL_FULL / STATUS_OUTSIDE_TABLE
    slots_needed: Array  # () int32 new slots the step needed
    tile_lo: Array  # (2,) int32 smallest touched tile (x, y)
    tile_hi: Array  # (2,) int32 largest touched tile (x, y)


def ok_status() -> MapStatus:
    return MapStatus(jnp.int32(0), jnp.int32(0), jnp.zeros((2,), jnp.int32), jnp.zeros((2,), jnp.int32))


def init_maps(num_particles: int, layout: PagedLayout) -> PagedMaps:
    """Empty maps: every table entry unknown, every slot but 0 free."""
    return PagedMaps(
        pool=jnp.zeros((layout.slots * layout.tile_cells,), CELL_DTYPE),
        tables=jnp.zeros((num_particles, layout.table_size), jnp.int32),
        refcount=jnp.zeros((layout.slots,), jnp.int32).at[0].set(PINNED),
        corner=jnp.asarray([layout.table_x0, layout.table_y0], jnp.int32),
    )


# ----------------------------------------------------------------------------- reads


def local_cell(cols: Array, rows: Array, layout: PagedLayout) -> Array:
    """Index of cell ``(cols, rows)`` inside its tile."""
    mask = layout.tile - 1
    return ((rows & mask) << layout.tile_bits) | (cols & mask)


def read_cells(pool: Array, table: Array, corner: Array, cols: Array, rows: Array, layout: PagedLayout) -> Array:
    """Cells ``(cols, rows)`` (int32, any shape) of one particle's map; unknown is 0."""
    return reader(pool, table, corner, layout)(cols, rows)


def reader(pool: Array, table: Array, corner: Array, layout: PagedLayout):
    """``(cols, rows) -> cells`` for one particle (the score functions' cell reader).

    The page table is read with one more column and one more row, of slot 0, past its
    ends, and a tile's table coordinates are clamped to them as unsigned integers (a
    tile left of or below the table wraps to a large one): every tile outside the table
    reads slot 0 through two minimums, without comparisons or selects per cell. The
    cells read are those of the plain rule (module docstring), faster than with the four
    comparisons and two selects per cell of a bounds test. The padded table is indexed by (row, column), not through a flat
    index: a score kernel outside a loop otherwise reads it through a reshape that
    XLA fuses into the kernel, as a division of each flat index by the table's width,
    slower for the kernels outside loops (those inside the climbs' loops are as fast
    either way). The pool is held flat in :class:`PagedMaps` for the same reason: a
    ``(slot, cell)`` pool flattened here was fused into the kernels outside loops as
    index arithmetic, and indexed by ``(slot, cell)`` the climbs' kernels are slower. Any shape of ``pool`` is read as its flat cells."""
    width, height = layout.table_width, layout.table_height
    padded = jnp.pad(table.reshape(height, width), ((0, 1), (0, 1)))
    cells = pool.reshape(-1)

    def read(cols: Array, rows: Array) -> Array:
        ix = ((cols >> layout.tile_bits) - corner[0]).astype(jnp.uint32)
        iy = ((rows >> layout.tile_bits) - corner[1]).astype(jnp.uint32)
        slot = padded[jnp.minimum(iy, height), jnp.minimum(ix, width)]
        # unsigned indices: no wrap-around of negative ones to compute (there are none)
        return cells[(slot * layout.tile_cells).astype(jnp.uint32) + local_cell(cols, rows, layout).astype(jnp.uint32)]

    return read


# ----------------------------------------------------------------------------- writes


class WritePlan(NamedTuple):
    """Where one step's writes go: a window of tiles around each particle's sensor."""

    window_x0: Array  # (P,) int32 tile x of window column 0
    window_y0: Array  # (P,) int32
    slots: Array  # (P, K) int32 slot of each window tile after copy on write (0: untouched)
    maps: PagedMaps  # tables and refcounts after allocation; pool after the copies
    status: MapStatus


def window_side(usable_range: float, layout: PagedLayout) -> int:
    """Tiles per side of the window that holds every cell of a scan (static)."""
    reach = math.ceil((usable_range / layout.resolution + 2.0) / layout.tile)
    return 2 * reach + 1


def window_index(cols: Array, rows: Array, x0: Array, y0: Array, side: int, layout: PagedLayout) -> Array:
    """Window entry of the tiles of cells ``(cols, rows)`` (``side * side`` if outside)."""
    wx = (cols >> layout.tile_bits) - x0
    wy = (rows >> layout.tile_bits) - y0
    inside = (wx >= 0) & (wx < side) & (wy >= 0) & (wy < side)
    return jnp.where(inside, wy * side + wx, side * side)


def plan_writes(maps: PagedMaps, touched: Array, x0: Array, y0: Array, side: int, layout: PagedLayout) -> WritePlan:
    """Allocate and copy the tiles that the particles will write (copy on write).

    Args:
        maps: current maps.
        touched: ``(P, side*side)`` bool, the window tiles each particle writes.
        x0, y0: ``(P,)`` tile coordinates of each particle's window corner.
        side: window side (static).
        layout: static layout.

    Returns:
        The plan; when ``plan.status.code != 0`` its ``maps`` are the input maps,
        untouched, and nothing may be written.
    """
    num_particles, k = touched.shape
    wx = jnp.arange(k, dtype=jnp.int32) % side
    wy = jnp.arange(k, dtype=jnp.int32) // side
    tx = x0[:, None] + wx[None, :]
    ty = y0[:, None] + wy[None, :]
    ix = tx - maps.corner[0]
    iy = ty - maps.corner[1]
    inside = (ix >= 0) & (ix < layout.table_width) & (iy >= 0) & (iy < layout.table_height)
    entry = jnp.where(inside, iy * layout.table_width + ix, 0)
    slot = jnp.where(inside, jnp.take_along_axis(maps.tables, entry, 1), 0)
    outside = jnp.any(touched & ~inside)
    big = jnp.int32(2**30)
    tile_lo = jnp.stack([jnp.min(jnp.where(touched, tx, big)), jnp.min(jnp.where(touched, ty, big))])
    tile_hi = jnp.stack([jnp.max(jnp.where(touched, tx, -big)), jnp.max(jnp.where(touched, ty, -big))])

    # Copy on write. Holders of a shared slot that all write it: the first keeps it.
    flat_touched = touched.reshape(-1)
    flat_slot = slot.reshape(-1)
    order = jnp.arange(flat_slot.shape[0], dtype=jnp.int32)
    shared = flat_touched & (flat_slot != 0) & (maps.refcount[flat_slot] > 1)
    writers = jnp.zeros_like(maps.refcount).at[flat_slot].add(shared.astype(jnp.int32))
    first = jnp.full_like(maps.refcount, big).at[flat_slot].min(jnp.where(shared, order, big))
    keep = shared & (writers[flat_slot] == maps.refcount[flat_slot]) & (first[flat_slot] == order)
    need = flat_touched & ((flat_slot == 0) | shared) & ~keep
    slots_needed = jnp.sum(need, dtype=jnp.int32)
    free = maps.refcount == 0
    pool_full = slots_needed > jnp.sum(free, dtype=jnp.int32)
    code = jnp.where(outside, STATUS_OUTSIDE_TABLE, jnp.where(pool_full, STATUS_POOL_FULL, STATUS_OK))
    status = MapStatus(code.astype(jnp.int32), slots_needed, tile_lo, tile_hi)

    # No lax.cond here: a refused plan allocates nothing by masking (a conditional
    # around the pool made XLA copy the whole pool every step).
    ok = code == STATUS_OK
    need = need & ok
    slots_needed_ok = jnp.where(ok, slots_needed, 0)
    free_slots = jnp.nonzero(free, size=need.shape[0], fill_value=0)[0].astype(jnp.int32)
    rank = jnp.cumsum(need.astype(jnp.int32)) - 1
    new_slot = jnp.where(need, free_slots[jnp.clip(rank, 0, need.shape[0] - 1)], flat_slot)
    # Copies in batches of 32 tiles, only as many batches as this step needs.
    which = jnp.nonzero(need, size=need.shape[0], fill_value=0)[0]
    src = flat_slot[which]
    dst = jnp.where(jnp.arange(need.shape[0]) < slots_needed_ok, new_slot[which], layout.slots)
    batch = 32
    pad = -(-need.shape[0] // batch) * batch - need.shape[0]
    src = jnp.pad(src, (0, pad))
    dst = jnp.pad(dst, (0, pad), constant_values=layout.slots)

    def copy(i, tiles):
        s = jax.lax.dynamic_slice_in_dim(src, i * batch, batch)
        d = jax.lax.dynamic_slice_in_dim(dst, i * batch, batch)
        return tiles.at[d].set(tiles[s], mode="drop")

    tiles = maps.pool.reshape(layout.slots, layout.tile_cells)
    pool = jax.lax.fori_loop(0, (slots_needed_ok + batch - 1) // batch, copy, tiles).reshape(-1)
    refcount = maps.refcount.at[jnp.where(need, flat_slot, layout.slots)].add(-1, mode="drop")
    refcount = refcount.at[jnp.where(need, new_slot, layout.slots)].set(1, mode="drop")
    refcount = refcount.at[0].set(PINNED)
    new_slot = new_slot.reshape(num_particles, k)
    rows = jnp.arange(num_particles)[:, None]
    tables = maps.tables.at[rows, jnp.where(need.reshape(num_particles, k), entry, layout.table_size)].set(
        new_slot, mode="drop"
    )
    window_slots = jnp.where(touched & ok, new_slot, 0)
    return WritePlan(x0, y0, window_slots, PagedMaps(pool, tables, refcount, maps.corner), status)


def resample_maps(maps: PagedMaps, ancestors: Array, resampled: Array) -> PagedMaps:
    """Particle ``i`` takes the page table of ``ancestors[i]``; counts are redone.

    Only page tables move; no cell is copied. Without resampling (``ancestors`` the
    identity) the recount is skipped.
    """

    def take(tables_refcount):
        tables = tables_refcount[0][ancestors]
        counts = jnp.zeros_like(maps.refcount).at[tables.reshape(-1)].add(1)
        return tables, counts.at[0].set(PINNED)

    tables, refcount = jax.lax.cond(resampled, take, lambda tr: tr, (maps.tables, maps.refcount))
    return PagedMaps(maps.pool, tables, refcount, maps.corner)


# ----------------------------------------------------------------------------- host side


def grow(maps: PagedMaps, layout: PagedLayout, status: MapStatus, margin_tiles: int = 4) -> tuple[PagedMaps, PagedLayout]:
    """Host: room for a step that was refused (see the module docstring).

    A full pool doubles (or more, to fit the request with room to spare). A step
    outside the table moves the table's corner where the box of the held and the wanted
    tiles fits with ``margin_tiles`` to spare on each side; the layout, and so the
    compiled program, stays the same. Otherwise the table grows to fit that box (at
    least half its size again in each dimension that is too small). Cell contents and
    slot numbers are unchanged, so the run continues exactly as one with the larger
    layout would. Returns ``(maps, layout)``; the layout is ``layout`` itself after a
    move.
    """
    code = int(status.code)
    pool = np.asarray(maps.pool).reshape(layout.slots, layout.tile_cells)
    tables = np.asarray(maps.tables)
    refcount = np.asarray(maps.refcount)
    corner = np.asarray(maps.corner).astype(np.int64)
    new = layout
    if code == STATUS_POOL_FULL:
        used = int(np.sum(refcount != 0))
        slots = max(2 * layout.slots, used + 2 * int(status.slots_needed))
        new = replace(layout, slots=slots)
        pool = np.concatenate([pool, np.zeros((slots - layout.slots, pool.shape[1]), pool.dtype)])
        refcount = np.concatenate([refcount, np.zeros((slots - layout.slots,), refcount.dtype)])
    elif code == STATUS_OUTSIDE_TABLE:
        width, height = layout.table_width, layout.table_height
        grid = tables.reshape(tables.shape[0], height, width)
        rows, cols = np.nonzero(np.any(grid != 0, axis=0))
        lo = np.asarray(status.tile_lo).astype(np.int64)
        hi = np.asarray(status.tile_hi).astype(np.int64)
        if cols.size:
            held_lo = np.array([cols.min(), rows.min()]) + corner
            held_hi = np.array([cols.max(), rows.max()]) + corner
            lo, hi = np.minimum(lo, held_lo), np.maximum(hi, held_hi)
        size = hi - lo + 1
        need = size + 2 * margin_tiles
        if need[0] > width or need[1] > height:
            width = width if need[0] <= width else int(max(need[0], width + width // 2))
            height = height if need[1] <= height else int(max(need[1], height + height // 2))
        new_corner = lo - (np.array([width, height]) - size) // 2
        out = np.zeros((tables.shape[0], height, width), tables.dtype)
        if cols.size:
            src = grid[:, rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]
            dx, dy = held_lo - new_corner
            out[:, dy : dy + src.shape[1], dx : dx + src.shape[2]] = src
        tables = out.reshape(tables.shape[0], -1)
        corner = new_corner
        if (width, height) != (layout.table_width, layout.table_height):
            new = layout.with_table(corner[0], corner[1], corner[0] + width - 1, corner[1] + height - 1)
    else:
        raise ValueError(f"nothing to grow for status {code}")
    maps = PagedMaps(jnp.asarray(pool.reshape(-1)), jnp.asarray(tables), jnp.asarray(refcount),
                     jnp.asarray(corner, jnp.int32))
    return maps, new


def stitch(pool, table, corner, layout: PagedLayout) -> tuple[np.ndarray, tuple[float, float]]:
    """Host: one particle's map as a dense ``(H, W)`` int8 array over its allocated tiles
    (``corner``: the table's, :attr:`PagedMaps.corner`).

    Returns:
        ``(grid, (origin_x, origin_y))``: row 0 at ``origin_y``, rows grow with y;
        a map with no tile yet gives one unknown tile at the table's corner.
    """
    pool = np.asarray(pool).reshape(-1, layout.tile_cells)
    corner = np.asarray(corner).astype(np.int64)
    table = np.asarray(table).reshape(layout.table_height, layout.table_width)
    t = layout.tile
    ys, xs = np.nonzero(table)
    if ys.size == 0:
        ys = xs = np.zeros((1,), np.int64)
    ty0, ty1, tx0, tx1 = ys.min(), ys.max(), xs.min(), xs.max()
    sub = table[ty0 : ty1 + 1, tx0 : tx1 + 1]
    tiles = pool[sub].reshape(sub.shape[0], sub.shape[1], t, t)  # slot 0 is all zeros
    grid = tiles.transpose(0, 2, 1, 3).reshape(sub.shape[0] * t, sub.shape[1] * t)
    origin = (
        layout.origin_x + float(corner[0] + tx0) * layout.tile_metres,
        layout.origin_y + float(corner[1] + ty0) * layout.tile_metres,
    )
    return grid, origin


def pool_stats(maps: PagedMaps, layout: PagedLayout) -> dict[str, int | float]:
    """Host: pool size, tiles in use, tiles per particle and tiles shared by several."""
    tables = np.asarray(maps.tables)
    refcount = np.asarray(maps.refcount)
    used = refcount[1:] > 0
    per_particle = np.count_nonzero(tables, axis=1)
    return {
        "pool_slots": int(layout.slots),
        "pool_mb": layout.pool_bytes() / 1e6,
        "tiles_used": int(np.count_nonzero(used)),
        "tiles_shared": int(np.count_nonzero(refcount[1:] > 1)),
        "tiles_per_particle_mean": float(per_particle.mean()) if per_particle.size else 0.0,
        "tiles_per_particle_max": int(per_particle.max()) if per_particle.size else 0,
        "table_tiles": int(layout.table_size),
        "tile_cells": int(layout.tile),
    }


__all__ = [
    "PINNED",
    "PoolLimitError",
    "STATUS_OK",
    "STATUS_OUTSIDE_TABLE",
    "STATUS_POOL_FULL",
    "MapStatus",
    "PagedLayout",
    "PagedMaps",
    "WritePlan",
    "grow",
    "init_maps",
    "local_cell",
    "ok_status",
    "plan_writes",
    "pool_stats",
    "read_cells",
    "reader",
    "resample_maps",
    "stitch",
    "window_index",
    "window_side",
]
