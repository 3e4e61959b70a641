"""Paged maps: equal to dense grids cell for cell, particles isolated, pool growth
invisible in the results, tiles reclaimed, checkpoints of growing runs resume exactly."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.runtime.checkpoint import Checkpoint
from jaxslam.datasets.laser_sim import simulate
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.grid.experiment import run_grid_slam
from jaxslam.grid.map import GridSpec
from jaxslam.grid.paged import PINNED, PagedLayout, grow, init_maps, read_cells, stitch
from jaxslam.grid.paged import resample_maps as _resample_maps
from jaxslam.grid.update import update_grids, update_paged

SPEC = GridSpec(1280, 1280, 0.05, -32.0, -32.0)  # the dense reference: 64 m x 64 m
MAX_POINTS = 16384


@jax.jit  # eager, its scan would be traced and compiled again at every call
def dense_update(grids, poses, ranges, valid, angles):
    return update_grids(grids, poses, ranges, valid, angles, jnp.zeros(3), SPEC, MAX_POINTS, 12.0, -1.0, 4.0, 40.0)[0]


resample_maps = jax.jit(_resample_maps)  # (eager, its cond would compile at every call)


@functools.cache
def paged_update(layout):  # one program per layout
    @jax.jit
    def update(maps, poses, ranges, valid, angles):
        return update_paged(maps, layout, poses, ranges, valid, angles, jnp.zeros(3), MAX_POINTS, 12.0, 12.0,
                            -1.0, 4.0, 40.0)

    return update


def apply_paged(maps, layout, poses, ranges, valid, angles):
    """One write, growing the layout on the host as the driver does."""
    while True:
        new, _, status = paged_update(layout)(maps, poses, ranges, valid, angles)
        if int(status.code) == 0:
            return new, layout
        maps, layout = grow(maps, layout, status)


def assert_same_as_dense(maps, layout, grids):
    """Every particle's stitched map equals its dense grid; nothing lies outside."""
    grids = np.asarray(grids)
    for p in range(grids.shape[0]):
        cells, (ox, oy) = stitch(maps.pool, maps.tables[p], maps.corner, layout)
        c0 = int(round((ox - SPEC.origin_x) / SPEC.resolution))
        r0 = int(round((oy - SPEC.origin_y) / SPEC.resolution))
        expect = np.zeros_like(cells)
        # the part of the stitched box that the dense grid covers
        rs, cs = max(r0, 0), max(c0, 0)
        re, ce = min(r0 + cells.shape[0], SPEC.height), min(c0 + cells.shape[1], SPEC.width)
        expect[rs - r0 : re - r0, cs - c0 : ce - c0] = grids[p, rs:re, cs:ce]
        np.testing.assert_array_equal(cells, expect, err_msg=f"particle {p}")
        outside = grids[p].copy()
        outside[rs:re, cs:ce] = 0
        assert not outside.any(), f"particle {p} has cells outside its tiles"


def check_refcounts(maps):
    counts = np.bincount(np.asarray(maps.tables).ravel(), minlength=maps.refcount.shape[0])
    refcount = np.asarray(maps.refcount)
    assert refcount[0] == PINNED
    np.testing.assert_array_equal(refcount[1:], counts[1:])


@functools.cache
def intel_segment(scans: int = 40):
    from jaxslam.datasets.registry import load_dataset_log

    try:
        log = load_dataset_log("intel")
    except DatasetNotFoundError:
        pytest.skip("intel log not available")
    idx = np.arange(0, 8 * scans, 8)
    ranges = np.where(log.valid[idx], log.ranges[idx], 0.0).astype(np.float32)
    return log.odom_poses[idx].astype(np.float32), ranges, log.valid[idx], log.angles.astype(np.float32)


def write_path(layout, scans: int = 40):
    """Intel scans at their odometry poses (3 particles jittered apart, resampled every
    5th scan), written as paged maps (growing or moving as the driver does) and as
    dense grids: ``(maps, layout, grids, corners the table had)``."""
    poses, ranges, valid, angles = intel_segment(scans)
    rng = np.random.default_rng(0)
    num = 3
    maps = init_maps(num, layout)
    grids = jnp.zeros((num,) + SPEC.shape, jnp.int8)
    angles = jnp.asarray(angles)
    corners = [tuple(np.asarray(maps.corner))]
    for t in range(poses.shape[0]):
        p = jnp.asarray(poses[t] + rng.normal(0, 0.05, (num, 3)), jnp.float32)
        r, v = jnp.asarray(ranges[t]), jnp.asarray(valid[t])
        maps, layout = apply_paged(maps, layout, p, r, v, angles)
        grids = dense_update(grids, p, r, v, angles)
        if t % 5 == 4:
            anc = jnp.asarray(np.sort(rng.integers(0, num, num)))
            maps = resample_maps(maps, anc, jnp.asarray(True))
            grids = grids[anc]
        check_refcounts(maps)
        if tuple(np.asarray(maps.corner)) != corners[-1]:
            corners.append(tuple(np.asarray(maps.corner)))
    return maps, layout, grids, corners


def test_paged_equals_dense_on_real_scans():
    """Cell for cell the dense result, in a layout that starts with one tile and a
    2-slot pool, so both the table and the pool grow along the way."""
    layout = PagedLayout(0.05, 6, -1, -1, 1, 1, slots=2, origin_x=SPEC.origin_x, origin_y=SPEC.origin_y)
    maps, layout, grids, _ = write_path(layout)
    assert layout.slots > 2 and layout.table_size > 1
    assert_same_as_dense(maps, layout, grids)


@pytest.mark.parametrize("corner", [(-3, 2), (5, -4)])
def test_reader_reads_the_tile_of_every_cell_and_unknown_outside_the_table(corner):
    """read_cells against the rule of the module docstring, written in NumPy: cells of
    a box that reaches 3 tiles past the table on every side (negative coordinates
    included), through a table whose entries point to random slots of a random pool.
    A tile outside the table must read slot 0 (unknown), not a border tile's slot."""
    layout = PagedLayout(0.05, 3, 0, 0, 5, 4, slots=12)  # 8 x 8-cell tiles, a 5 x 4 table
    rng = np.random.default_rng(1)
    pool = rng.integers(-100, 100, (layout.slots, layout.tile_cells)).astype(np.int8)
    pool[0] = 0
    table = rng.integers(1, layout.slots, layout.table_size).astype(np.int32)
    corner = np.asarray(corner, np.int32)
    t = layout.tile
    cols, rows = np.meshgrid(np.arange((corner[0] - 3) * t, (corner[0] + layout.table_width + 3) * t),
                             np.arange((corner[1] - 3) * t, (corner[1] + layout.table_height + 3) * t))
    tx, ty = cols // t - corner[0], rows // t - corner[1]
    inside = (tx >= 0) & (tx < layout.table_width) & (ty >= 0) & (ty < layout.table_height)
    slot = np.where(inside, table[np.clip(ty, 0, layout.table_height - 1) * layout.table_width
                                  + np.clip(tx, 0, layout.table_width - 1)], 0)
    expect = pool[slot, (rows % t) * t + cols % t]
    got = jax.jit(read_cells, static_argnums=5)(jnp.asarray(pool), jnp.asarray(table), jnp.asarray(corner),
                                               jnp.asarray(cols, jnp.int32), jnp.asarray(rows, jnp.int32), layout)
    assert inside.any() and not inside.all()
    np.testing.assert_array_equal(np.asarray(got), expect)


@settings(max_examples=6, deadline=None)
@given(st.data())
def test_one_particles_writes_never_change_another(data):
    """Random resampling, and writes by two random particles of four (the others' page
    tables are left out of the write; reference counts stay global): a particle
    that did not write keeps its map exactly, and every particle's map equals its own
    dense grid."""
    num = 4
    # A pool that does not grow here (one compiled write; growth has its own tests).
    layout = PagedLayout.covering(-12.0, -12.0, 12.0, 12.0, 0.05, slots=256, origin=(SPEC.origin_x, SPEC.origin_y))
    maps = init_maps(num, layout)
    grids = jnp.zeros((num,) + SPEC.shape, jnp.int8)
    angles = jnp.asarray(np.linspace(-np.pi, np.pi, 36, endpoint=False), jnp.float32)
    for _ in range(data.draw(st.integers(2, 4))):
        # two of the four write (one compiled shape); hypothesis picks which two
        writers = np.sort(np.asarray(data.draw(st.permutations(range(num)))[:2]))
        xy = np.asarray(data.draw(st.lists(st.floats(-4, 4), min_size=2 * num, max_size=2 * num))).reshape(num, 2)
        poses = jnp.asarray(np.c_[xy, np.zeros(num)], jnp.float32)
        r = jnp.asarray(data.draw(st.lists(st.floats(0.2, 6.0), min_size=36, max_size=36)), jnp.float32)
        v = jnp.ones((36,), bool)
        before = [stitch(maps.pool, maps.tables[p], maps.corner, layout)[0] for p in range(num)]
        if writers.size:
            idx = jnp.asarray(writers)
            sub = maps._replace(tables=maps.tables[idx])
            new, grown = apply_paged(sub, layout, poses[idx], r, v, angles)
            assert grown == layout  # the box and the pool cover every write
            layout = grown
            maps = maps._replace(pool=new.pool, tables=maps.tables.at[idx].set(new.tables), refcount=new.refcount)
            grids = grids.at[idx].set(dense_update(grids[idx], poses[idx], r, v, angles))
        check_refcounts(maps)
        for p in set(range(num)) - set(writers.tolist()):
            np.testing.assert_array_equal(stitch(maps.pool, maps.tables[p], maps.corner, layout)[0], before[p])
        anc = np.sort(np.asarray(data.draw(st.lists(st.integers(0, num - 1), min_size=num, max_size=num))))
        maps = resample_maps(maps, jnp.asarray(anc), jnp.asarray(True))
        grids = grids[anc]
        check_refcounts(maps)
    assert_same_as_dense(maps, layout, grids)


def test_tiles_are_reclaimed_after_resampling():
    """After every particle takes particle 0's map, the others' private tiles are free
    again, and the next writes reuse them instead of growing the pool."""
    num = 4
    layout = PagedLayout.covering(-8.0, -8.0, 8.0, 8.0, 0.05, slots=512)
    maps = init_maps(num, layout)
    angles = jnp.asarray(np.linspace(-np.pi, np.pi, 90, endpoint=False), jnp.float32)
    r = jnp.full((90,), 5.0, jnp.float32)
    v = jnp.ones((90,), bool)
    poses = jnp.asarray([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, -1.0, 0.0]], jnp.float32)
    maps, layout = apply_paged(maps, layout, poses, r, v, angles)
    used_before = int(np.sum(np.asarray(maps.refcount)[1:] > 0))
    maps = resample_maps(maps, jnp.zeros((num,), jnp.int32), jnp.asarray(True))
    check_refcounts(maps)
    used_after = int(np.sum(np.asarray(maps.refcount)[1:] > 0))
    assert used_after * num <= used_before + 3 * num  # only particle 0's tiles are left
    highest = int(np.max(np.nonzero(np.asarray(maps.refcount)[1:] > 0)[0])) + 1
    maps, layout2 = apply_paged(maps, layout, poses + 0.1, r, v, angles)
    assert layout2 == layout  # no growth: the freed slots were enough
    new_slots = np.setdiff1d(np.asarray(maps.tables).ravel(), [0])
    assert new_slots.max() <= highest + used_before  # reused, not appended
    check_refcounts(maps)


@pytest.fixture(scope="module")
def sim_log():
    return simulate(width=12.0, height=8.0, rooms_x=2, laps=0.3, num_beams=61, seed=5)


def _run(log, **kw):
    # The loop-closure search off: these runs test the paging, and the search, compiled
    # into each of their chunk runners, nearly doubles the compilation (about 40 s of
    # this module); the search reads the maps through the same page tables
    # (tests/grid/test_closure.py).
    kw.setdefault("chunk", 8)
    return run_grid_slam(log, "srupf-gm", particles=3, seed=1, progress=False, linear_update=0.5,
                         angular_update=0.3, config={"match_iterations": 3, "closure": False},
                         max_keyframes=33, **kw)


# Grows the page table at init (before the chunk runner compiles) and the pool at step
# 11: two compilations of the chunk runner (the old box and pool needed five).
SMALL = {"bounds": (0.0, 0.0, 6.0, 8.0), "pool_slots": 16}


@pytest.fixture(scope="module")
def growing_run(sim_log):
    return _run(sim_log, **SMALL)


def _box_of(layout):
    """A box over the centres of the first and last tiles of ``layout``'s page table."""
    tm = layout.tile_metres
    x0 = layout.origin_x + (layout.table_x0 + 0.5) * tm
    y0 = layout.origin_y + (layout.table_y0 + 0.5) * tm
    return (x0, y0, x0 + (layout.table_width - 1) * tm, y0 + (layout.table_height - 1) * tm)


@pytest.mark.long
def test_growing_run_equals_run_with_large_layout(sim_log, growing_run):
    """A run that starts with a small pool and table (and grows both) gives the same
    trajectory and map as one that starts large enough."""
    # Started with the grown run's final layout (a box over the centres of its first and
    # last table tiles, its pool size): no growth, and the same compiled program as the
    # grown run's last stretch.
    grown = growing_run.config.layout
    large = _run(sim_log, bounds=_box_of(grown), pool_slots=grown.slots)
    grew = {g["grew"] for g in growing_run.growths}
    assert grew == {"pool", "page table"} and large.summary()["map_growths"] == 0
    assert large.config.layout == grown
    np.testing.assert_array_equal(growing_run.trajectory, large.trajectory)
    np.testing.assert_array_equal(growing_run.map_log_odds, large.map_log_odds)
    assert growing_run.origin == large.origin


@pytest.mark.long
def test_run_does_not_depend_on_chunk_length(sim_log, growing_run):
    """Chunks of 8 scans with two growths, or the whole log (about 100 scans) in one
    chunk: the same trajectory and map (a step refused for want of map space holds the
    state through the rest of its chunk)."""
    one_chunk = _run(sim_log, **{**SMALL, "chunk": 4096})
    scans = growing_run.trajectory.shape[0]
    assert one_chunk.summary()["map_growths"] == growing_run.summary()["map_growths"] > 0
    assert scans > 8 * 4
    np.testing.assert_array_equal(growing_run.trajectory, one_chunk.trajectory)
    np.testing.assert_array_equal(growing_run.map_log_odds, one_chunk.map_log_odds)


@pytest.mark.long
def test_checkpoint_of_growing_run_resumes_bit_for_bit(sim_log, growing_run, tmp_path):
    """Interrupted after the maps grew, resumed from the checkpoint (which records the
    grown layout): the same trajectory and map as the uninterrupted run."""
    path = tmp_path / "ck.npz"
    original_save = Checkpoint.save

    class Crash(Exception):
        pass

    def save_then_crash(self, carry, done, leaves):
        original_save(self, carry, done, leaves)
        if done >= 16:  # after the pool grew (step 11)
            raise Crash

    Checkpoint.save = save_then_crash
    try:
        with pytest.raises(Crash):
            _run(sim_log, checkpoint=Checkpoint(path, every=8), **SMALL)
    finally:
        Checkpoint.save = original_save
    assert Checkpoint(path).saved_static()["layout"]["slots"] > SMALL["pool_slots"]
    resumed = _run(sim_log, checkpoint=Checkpoint(path, every=8, resume=True), **SMALL)
    np.testing.assert_array_equal(resumed.trajectory, growing_run.trajectory)
    np.testing.assert_array_equal(resumed.map_log_odds, growing_run.map_log_odds)


def test_a_table_the_robot_leaves_moves_without_changing_a_cell():
    """grow() on a step outside the table: where the held and the wanted tiles fit with
    the margin to spare, the layout stays (no recompilation), the corner moves so that
    they sit in the middle, and every held tile keeps its slot at its world tile;
    otherwise the table grows."""
    from jaxslam.grid.paged import STATUS_OUTSIDE_TABLE, MapStatus, PagedMaps

    rng = np.random.default_rng(0)
    layout = PagedLayout(0.05, 6, table_x0=-3, table_y0=2, table_width=24, table_height=12, slots=64)
    tables = np.zeros((3, 12, 24), np.int32)
    tables[:, 4:7, 17:21] = rng.integers(1, 64, (3, 3, 4))  # held tiles x 14..17, y 6..8
    tables[1, 5, 22] = 17  # x 19, y 7, held by one particle
    maps = PagedMaps(jnp.zeros((64 * layout.tile_cells,), jnp.int8), jnp.asarray(tables.reshape(3, -1)),
                     jnp.ones((64,), jnp.int32), jnp.asarray([-3, 2], jnp.int32))

    def held(m, lay):
        corner = np.asarray(m.corner)
        grid = np.asarray(m.tables).reshape(3, lay.table_height, lay.table_width)
        return {(p, int(x) + corner[0], int(y) + corner[1]): int(grid[p, y, x]) for p, y, x in zip(*np.nonzero(grid))}

    def outside(lo, hi):
        return MapStatus(jnp.int32(STATUS_OUTSIDE_TABLE), jnp.int32(0), jnp.asarray(lo), jnp.asarray(hi))

    # wanted: tiles x 21..22, y 7..8, past the table's right edge (x -3..20)
    moved, same = grow(maps, layout, outside([21, 7], [22, 8]))
    assert same is layout  # the program stays
    assert held(moved, layout) == held(maps, layout)  # every held tile where it was in the world
    np.testing.assert_array_equal(moved.corner, [14 - (24 - 9) // 2, 6 - (12 - 3) // 2])  # box x 14..22, y 6..8

    # wanted far away: the box (x 14..41, with the margin 36 tiles) no longer fits in 24
    grown, bigger = grow(moved, layout, outside([40, 7], [41, 8]))
    assert (bigger.table_width, bigger.table_height) == (36, 12)
    assert held(grown, bigger) == held(maps, layout)
    assert (bigger.table_x0, bigger.table_y0) == tuple(int(c) for c in np.asarray(grown.corner))


def test_a_table_the_path_leaves_moves_and_the_maps_equal_the_dense_ones():
    """Intel scans whose path leaves a starting table of 24 x 24 tiles placed with the
    start near its lower left corner: the table moves (the layout, so the compiled
    write, stays), and every particle's map equals its dense grid."""
    layout = PagedLayout(0.05, 6, 6, 6, 24, 24, slots=1024, origin_x=SPEC.origin_x, origin_y=SPEC.origin_y)
    maps, end, grids, corners = write_path(layout, 120)
    assert end == layout and len(corners) > 1  # moved, never grown
    assert_same_as_dense(maps, end, grids)


@pytest.mark.long
def test_a_run_that_starts_off_its_table_moves_it_and_equals_a_run_that_started_there(sim_log):
    """A starting table of a good size in the wrong place (30 m off the path, as a
    drifting odometry box can be): init moves it instead of growing it, and the run
    equals one whose table started where it was moved to."""
    tm = PagedLayout().tile_metres
    off = _run(sim_log, bounds=(30.0, 30.0, 30.0 + 15.5 * tm, 30.0 + 15.5 * tm), pool_slots=256)
    assert [g["grew"] for g in off.growths] == ["page table moved"] and off.summary()["map_recompilations"] == 0
    layout = off.config.layout
    assert (layout.table_width, layout.table_height) == (16, 16)
    np.testing.assert_array_equal(off.state.maps.corner, [layout.table_x0, layout.table_y0])
    assert layout.table_x0 < 0 < layout.table_x0 + 16  # around the path now, not at 30 m
    there = _run(sim_log, bounds=_box_of(layout), pool_slots=256)
    assert there.summary()["map_growths"] == 0 and there.config.layout == layout
    np.testing.assert_array_equal(off.trajectory, there.trajectory)
    np.testing.assert_array_equal(off.map_log_odds, there.map_log_odds)
    assert off.origin == there.origin
