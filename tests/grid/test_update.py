"""Ray updates against a plain float64 NumPy Bresenham reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.grid.map import GridSpec
from jaxslam.grid.paged import PagedLayout, window_side
from jaxslam.grid.update import (
    ROW,
    beam_layout,
    beam_lengths,
    chunk_cell_coords,
    num_rows,
    ray_cells,
    required_points,
    scan_rays,
    touched_tiles,
    update_grid,
    update_grids,
)

SPEC = GridSpec(height=48, width=56, resolution=0.1, origin_x=-2.0, origin_y=-1.5)


def compose(a, b):
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def bresenham(c0, r0, c1, r1):
    """Integer line from (c0, r0) to (c1, r1): c_k = c_0 + floor((2 k d + n) / (2 n))."""
    dc, dr = c1 - c0, r1 - r0
    n = max(abs(dc), abs(dr))
    if n == 0:
        return [(c0, r0)]
    return [(c0 + (2 * k * dc + n) // (2 * n), r0 + (2 * k * dr + n) // (2 * n)) for k in range(n + 1)]


def reference_update(grid, sensor, ranges, valid, angles, usable, spec, l_free, l_occ, l_max):
    """Float64 loop: free cells once per scan, then hit cells once per scan."""
    grid = grid.astype(np.int64).copy()
    free, hit = set(), set()

    def cell(x, y):
        return int(np.floor((x - spec.origin_x) / spec.resolution)), int(np.floor((y - spec.origin_y) / spec.resolution))

    c0, r0 = cell(sensor[0], sensor[1])
    for r, ok, a in zip(ranges, valid, angles):
        if not ok:
            continue
        d = min(r, usable)
        ex, ey = sensor[0] + d * np.cos(sensor[2] + a), sensor[1] + d * np.sin(sensor[2] + a)
        line = bresenham(c0, r0, *cell(ex, ey))
        free.update(line[:-1])
        if r <= usable:
            hit.add(line[-1])
    for cells, inc in ((free, l_free), (hit, l_occ)):
        for c, r in cells:
            if 0 <= c < spec.width and 0 <= r < spec.height:
                grid[r, c] = np.clip(grid[r, c] + inc, -l_max, l_max)
    return grid


def random_scan(rng, num_beams=37):
    angles = np.linspace(-np.pi / 2, np.pi / 2, num_beams)
    ranges = rng.uniform(0.05, 4.5, num_beams)
    valid = rng.uniform(size=num_beams) > 0.15
    return angles, ranges, valid


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_update_grid_matches_reference_float64(seed):
    rng = np.random.default_rng(seed)
    angles, ranges, valid = random_scan(rng)
    pose = np.array([rng.uniform(-1.0, 2.0), rng.uniform(-1.0, 2.0), rng.uniform(-np.pi, np.pi)])
    offset = np.array([0.1, -0.05, 0.02])
    sensor = compose(pose, offset)
    usable = 3.0
    start = rng.integers(-5, 5, SPEC.shape).astype(np.int8)
    expected = reference_update(start, sensor, ranges, valid, angles, usable, SPEC, -1, 3, 6)

    lengths, hits = beam_lengths(jnp.asarray(ranges), jnp.asarray(valid), usable)
    max_rows = num_rows(required_points(np.minimum(ranges, usable), valid, SPEC.resolution), len(ranges))
    layout = beam_layout(lengths, jnp.asarray(valid), SPEC.resolution, max_rows)
    free, hit = jax.jit(ray_cells, static_argnames="spec")(jnp.asarray(sensor), lengths, hits, jnp.asarray(angles),
                                                            layout, SPEC)
    got = jax.jit(update_grid)(jnp.asarray(start), free, hit, -1.0, 3.0, 6.0)
    assert int(layout.dropped) == 0
    np.testing.assert_array_equal(np.asarray(got), expected)


def test_update_grids_batched_equals_reference(dtype):
    """All particles at once (chunked loop), float32 and float64, vs the reference."""
    rng = np.random.default_rng(7)
    angles, ranges, valid = random_scan(rng, 61)
    particles = 4
    poses = np.stack([[rng.uniform(-1, 2), rng.uniform(-1, 2), rng.uniform(-np.pi, np.pi)] for _ in range(particles)])
    offset = np.array([0.05, 0.0, 0.0])
    grids = rng.integers(-3, 3, (particles,) + SPEC.shape).astype(np.int8)
    max_points = required_points(np.minimum(ranges, 3.5), valid, SPEC.resolution)
    fn = jax.jit(update_grids, static_argnames=("spec", "max_points", "chunk_rows"))
    got, dropped = fn(
        jnp.asarray(grids), jnp.asarray(poses, dtype), jnp.asarray(ranges, dtype), jnp.asarray(valid),
        jnp.asarray(angles, dtype), jnp.asarray(offset, dtype), SPEC, max_points, 3.5, -1.0, 2.0, 5.0, chunk_rows=8,
    )
    assert int(dropped) == 0
    got = np.asarray(got)
    for p in range(particles):
        expected = reference_update(grids[p], compose(poses[p], offset), ranges, valid, angles, 3.5, SPEC, -1, 2, 5)
        mismatch = np.mean(got[p] != expected)
        if dtype == np.float64:
            assert mismatch == 0
        else:  # float32 may put a point that lies on a cell boundary in the neighbour
            assert mismatch < 2e-3, mismatch


def test_budget_overflow_is_counted():
    rng = np.random.default_rng(3)
    _angles, ranges, valid = random_scan(rng)
    need = required_points(np.minimum(ranges, 5.0), valid, SPEC.resolution)
    lengths, _ = beam_lengths(jnp.asarray(ranges), jnp.asarray(valid), 5.0)
    small = beam_layout(lengths, jnp.asarray(valid), SPEC.resolution, max_rows=4)
    assert int(small.dropped) > 0
    full = beam_layout(lengths, jnp.asarray(valid), SPEC.resolution, num_rows(need, len(ranges)))
    assert int(full.dropped) == 0


def test_update_is_clamped_and_int8():
    """Repeated scans saturate at +-l_max instead of wrapping around."""
    angles = np.linspace(-1.0, 1.0, 25)
    ranges = np.full(25, 1.5)
    valid = np.ones(25, bool)
    grids = jnp.zeros((2,) + SPEC.shape, jnp.int8)
    poses = jnp.zeros((2, 3))
    fn = jax.jit(update_grids, static_argnames=("spec", "max_points", "chunk_rows"))
    for _ in range(60):
        grids, _ = fn(grids, poses, jnp.asarray(ranges), jnp.asarray(valid), jnp.asarray(angles),
                      jnp.zeros(3), SPEC, 1024, 10.0, -4.0, 7.0, 100.0)
    g = np.asarray(grids)
    assert g.dtype == np.int8
    assert g.max() == 100 and g.min() == -100


@pytest.mark.parametrize("seed", [0, 1])
def test_touched_tiles_cover_every_written_cell_and_little_more(seed):
    """The tiles that :func:`touched_tiles` marks for allocation: every tile that
    holds a free or hit cell of the scan (else that write would be dropped), and
    only tiles of a beam row's first/last cell combinations or of a hit (checked
    in NumPy on the cells the write loop itself visits)."""
    rng = np.random.default_rng(seed)
    angles, ranges, valid = random_scan(rng, 91)
    ranges = ranges * 2.5  # beams that cross several 16-cell tiles
    layout = PagedLayout(0.05, 4, -8, -8, 16, 16, slots=64, origin_x=0.0, origin_y=0.0)
    poses = jnp.asarray(rng.uniform([-3.0, -3.0, -np.pi], [3.0, 3.0, np.pi], (5, 3)), jnp.float32)
    rays = scan_rays(poses, jnp.asarray(ranges, jnp.float32), jnp.asarray(valid), jnp.asarray(angles, jnp.float32),
                     jnp.zeros(3), layout, 16384, 8.0, chunk_rows=16)
    side = window_side(8.0, layout)
    x0 = (rays.geometry.start[:, 0] >> layout.tile_bits) - side // 2
    y0 = (rays.geometry.start[:, 1] >> layout.tile_bits) - side // 2
    marks = np.asarray(jax.jit(lambda a, b: touched_tiles(rays, a, b, side, layout))(x0, y0))
    x0, y0 = np.asarray(x0), np.asarray(y0)

    def tile(p, cols, rows):
        return ((np.asarray(rows) >> layout.tile_bits) - y0[p]) * side + ((np.asarray(cols) >> layout.tile_bits) - x0[p])

    chunks = [chunk_cell_coords(rays, i) for i in range(int(rays.num_chunks))]
    end, hits = np.asarray(rays.geometry.end), np.asarray(rays.hits)
    for p in range(poses.shape[0]):
        need = set(tile(p, end[p, hits, 0], end[p, hits, 1]).tolist())
        for cols, rows, ok in chunks:
            ok = np.asarray(ok[p])
            need |= set(tile(p, np.asarray(cols[p])[ok], np.asarray(rows[p])[ok]).tolist())
        got = set(np.flatnonzero(marks[p]).tolist())
        assert need <= got, f"particle {p}: tiles {sorted(need - got)} would be written without a slot"
        # each row of ROW cells spans at most a 2 x 2 block of tiles: nothing else is marked
        allowed = set(need)
        for cols, rows, ok in chunks:
            c = np.asarray(cols[p]).reshape(-1, ROW)
            r = np.asarray(rows[p]).reshape(-1, ROW)
            o = np.asarray(ok[p]).reshape(-1, ROW)
            for cc, rr in zip(c[o.any(1)], r[o.any(1)]):
                for a in (cc.min(), cc.max()):
                    for b in (rr.min(), rr.max()):
                        allowed.add(int(tile(p, a, b)))
        assert got <= allowed, f"particle {p}: tiles {sorted(got - allowed)} marked that no cell needs"
        assert len(got) > 4
