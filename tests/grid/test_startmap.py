"""Mapping that continues: a saved map as every particle's starting map."""

import numpy as np
import pytest

from jaxslam.app import cli
from jaxslam.grid.mapfile import OccupancyMap, load_map, save_map_npz
from jaxslam.grid.paged import PagedLayout, PINNED, read_cells, stitch
from jaxslam.grid.startmap import StartMapError, paged_start, start_cells, start_layout

UNIT, L_MAX = 0.2, 60.0


def run_cli(*argv):
    try:
        return cli.main(list(argv))
    except SystemExit as exc:
        return exc.code


def saved_map(tmp_path, shape=(128, 192), origin=(-3.2, 6.4), seed=0, name="map.npz"):
    rng = np.random.default_rng(seed)
    cells = rng.integers(-60, 61, size=shape).astype(np.int8)
    cells[rng.random(shape) < 0.5] = 0
    log_odds = cells.astype(np.float32) * np.float32(UNIT)
    path = save_map_npz(tmp_path / name, log_odds, 0.05, origin, log_odds_unit=UNIT, tile=64,
                        pose=(1.0, 2.0, 0.5))
    return path, cells


def paged(grid, odom=np.zeros((2, 3)), pose=(0.0, 0.0, 0.0), base=PagedLayout(0.05, 6, slots=8)):
    cells = start_cells(grid, 0.05, UNIT, L_MAX)
    layout = start_layout(cells, grid, base, odom, pose, margin=5.0)
    return cells, layout, paged_start(cells, layout)


def test_a_saved_map_paged_and_written_back_is_the_same_file(tmp_path):
    path, cells = saved_map(tmp_path)
    grid = load_map(path, require_free=False)
    assert grid.pose == (1.0, 2.0, 0.5)
    steps, layout, maps = paged(grid)
    np.testing.assert_array_equal(steps, cells)
    back, origin = stitch(maps.pool, maps.tables[0], maps.corner, layout)
    np.testing.assert_array_equal(back, cells)
    assert origin == (-3.2, 6.4)
    again = save_map_npz(tmp_path / "again.npz", back.astype(np.float32) * np.float32(UNIT), layout.resolution,
                         origin, log_odds_unit=UNIT, tile=layout.tile, pose=grid.pose)
    with np.load(path) as a, np.load(again) as b:
        assert sorted(a.files) == sorted(b.files)
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_every_cell_reads_back_where_it_was_saved_through_the_page_table(tmp_path):
    path, cells = saved_map(tmp_path, shape=(100, 70), origin=(1.6, -0.8))  # not whole tiles
    grid = load_map(path, require_free=False)
    odom = np.array([[5.0, 5.0, 0.3], [40.0, -20.0, 1.0]])
    _, layout, maps = paged(grid, odom, pose=(0.0, 0.0, 0.0))
    rows, cols = np.mgrid[-3:103, -3:73]
    read = np.asarray(read_cells(maps.pool, maps.tables[0], maps.corner, cols, rows, layout))
    expected = np.zeros(rows.shape, np.int64)
    expected[3:103, 3:73] = cells
    np.testing.assert_array_equal(read, expected)
    # the page table reaches the odometry moved to start at the initial pose (+ margin)
    path_xy = np.array([35.0 * np.cos(-0.3) - (-25.0) * np.sin(-0.3), 35.0 * np.sin(-0.3) + (-25.0) * np.cos(-0.3)])
    tile = layout.tile_metres
    tx = np.floor((path_xy[0] - layout.origin_x) / tile) - layout.table_x0
    ty = np.floor((path_xy[1] - layout.origin_y) / tile) - layout.table_y0
    assert 0 <= tx < layout.table_width and 0 <= ty < layout.table_height
    # one holder per slot of the map (the filter's init shares them among particles)
    count = int(np.count_nonzero(maps.tables))
    assert np.asarray(maps.refcount)[0] == PINNED and int(np.sum(np.asarray(maps.refcount)[1:])) == count


def test_a_map_server_map_starts_as_certain_cells():
    occupancy = np.array([[100, 0, -1, 50], [75, 25, 100, 0]], np.int8)
    grid = OccupancyMap(occupancy=occupancy, resolution=0.05, origin=(0.0, 0.0, 0.0))
    steps = start_cells(grid, 0.05, UNIT, L_MAX)
    logit = lambda p: int(np.rint(np.log(p / (1 - p)) / UNIT))  # noqa: E731
    np.testing.assert_array_equal(steps, [[60, -60, 0, 0], [logit(0.75), logit(0.25), 60, -60]])


def test_another_unit_is_rounded_to_the_runs_steps_and_clamped(tmp_path):
    log_odds = np.array([[0.5, -0.5, 30.0, -0.04]], np.float32)
    path = save_map_npz(tmp_path / "m.npz", log_odds, 0.05, (0.0, 0.0), log_odds_unit=0.1)
    steps = start_cells(load_map(path, require_free=False), 0.05, UNIT, L_MAX)
    np.testing.assert_array_equal(steps, [[2, -2, 60, 0]])


def test_a_map_of_another_resolution_or_rotated_is_refused(tmp_path):
    log_odds = np.zeros((4, 4), np.float32)
    coarse = load_map(save_map_npz(tmp_path / "c.npz", log_odds, 0.1, (0, 0)), require_free=False)
    with pytest.raises(StartMapError, match="resolution 0.1 m per cell, but the run's maps are 0.05 m"):
        start_cells(coarse, 0.05, UNIT, L_MAX)
    turned = load_map(save_map_npz(tmp_path / "t.npz", log_odds, 0.05, (0, 0, 0.2)), require_free=False)
    with pytest.raises(StartMapError, match="origin yaw 0.2 rad"):
        start_cells(turned, 0.05, UNIT, L_MAX)


@pytest.mark.parametrize("case", ["missing", "resolution", "not-a-map", "pose-without-map", "landmark", "both"])
def test_bad_start_maps_get_one_line_and_exit_2(tmp_path, capsys, case):
    out = str(tmp_path / "o")
    args = ["run", "--dataset", "sim-laser", "--out", out, "--start-map"]
    if case == "missing":
        args.append(str(tmp_path / "nothing.npz"))
        expect = "does not exist"
    elif case == "resolution":
        args.append(str(save_map_npz(tmp_path / "c.npz", np.zeros((4, 4), np.float32), 0.1, (0, 0))))
        expect = "--start-map"
    elif case == "not-a-map":
        (tmp_path / "x.npz").write_bytes(b"PK\x03\x04 nothing")
        args.append(str(tmp_path / "x.npz"))
        expect = "cannot read the map"
    elif case == "pose-without-map":
        args = ["run", "--dataset", "sim-laser", "--out", out, "--initial-pose", "0", "0", "0"]
        expect = "need --start-map"
    elif case == "landmark":
        args = ["run", "--algorithm", "erb-upf", "--out", out, "--start-map", str(saved_map(tmp_path)[0])]
        expect = "grid filters"
    else:
        args += [str(saved_map(tmp_path)[0]), "--initial-pose", "0", "0", "0", "--localize-first"]
        expect = "exclude each other"
    assert run_cli(*args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and expect in lines[0], lines


@pytest.mark.long
def test_a_simulated_map_continued_on_its_log_stays_on_the_saved_path(tmp_path):
    """Map part of a simulated log, then run again from that map at the first run's
    first pose: every scan matches the saved map, so the path stays on the first run's
    and the map written back holds the saved one's extent."""
    from jaxslam.datasets.laser_sim import simulate
    from jaxslam.grid.experiment import run_grid_slam

    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
    options = dict(particles=4, max_keyframes=12, progress=False, margin=3.0, config={"match_iterations": 6})
    first = run_grid_slam(log, **options)
    path = save_map_npz(tmp_path / "map.npz", first.map_log_odds, first.resolution, first.origin,
                        log_odds_unit=first.params["map.log_odds_unit"], tile=64, pose=first.trajectory[-1])
    grid = load_map(path)
    again = run_grid_slam(log, start_map=grid, initial_pose=first.trajectory[0], **options)
    # the first scan is matched in the saved map from the given pose: a climb of a cell at most
    assert again.start_match["moved_m"] < 0.05 and abs(again.start_match["turned_deg"]) < 1.0
    np.testing.assert_allclose(again.trajectory[0], first.trajectory[0], atol=0.05)
    gap = np.hypot(*(again.trajectory[:, :2] - first.trajectory[:, :2]).T)
    assert gap.max() < 0.15, gap.max()
    assert again.origin[0] <= first.origin[0] and again.origin[1] <= first.origin[1]
    assert again.map_log_odds.shape[0] >= first.map_log_odds.shape[0]
    # where the first run saw an obstacle, the continued map still has one
    rows, cols = np.nonzero(first.map_log_odds > 2.0)
    dy = int(round((first.origin[1] - again.origin[1]) / first.resolution))
    dx = int(round((first.origin[0] - again.origin[0]) / first.resolution))
    assert np.mean(again.map_log_odds[rows + dy, cols + dx] > 0) > 0.95


@pytest.mark.long
def test_a_continued_run_matches_its_first_scan_in_the_saved_map(tmp_path):
    """Started 12 cm and 2.3 degrees off the pose the saved map was made at, the first
    scan is matched into the saved map's walls before it is written, so the continued
    run starts where the first run was, not where it was told."""
    from jaxslam.datasets.laser_sim import simulate
    from jaxslam.grid.experiment import run_grid_slam

    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
    options = dict(particles=4, max_keyframes=12, progress=False, margin=3.0, config={"match_iterations": 6})
    first = run_grid_slam(log, **options)
    path = save_map_npz(tmp_path / "map.npz", first.map_log_odds, first.resolution, first.origin,
                        log_odds_unit=first.params["map.log_odds_unit"], tile=64, pose=first.trajectory[-1])
    told = first.trajectory[0] + np.array([0.09, -0.08, 0.04])
    again = run_grid_slam(log, start_map=load_map(path), initial_pose=told, max_keyframes=2, particles=4,
                          progress=False, margin=3.0, config={"match_iterations": 6})
    start = again.trajectory[0]
    assert np.hypot(*(start[:2] - first.trajectory[0][:2])) < 0.03, start
    assert abs(start[2] - first.trajectory[0][2]) < np.radians(1.0), start  # from 2.3 degrees
    assert again.start_match["score_matched"] > again.start_match["score_given"]
    np.testing.assert_allclose(again.start_match["given_pose"], told)


def test_a_log_cut_from_a_scan_keeps_every_per_scan_array_in_step():
    from jaxslam.datasets.carmen import scan_range
    from jaxslam.datasets.laser_sim import simulate

    log = simulate(width=6.0, height=4.0, rooms_x=1, laps=0.2, num_beams=31, seed=1)
    cut = scan_range(log, 5)
    scans = log.ranges.shape[0]
    assert cut.ranges.shape[0] == scans - 5
    np.testing.assert_array_equal(cut.scan_times, log.scan_times[5:])
    np.testing.assert_array_equal(cut.odom_poses, log.odom_poses[5:])
    np.testing.assert_array_equal(cut.valid, log.valid[5:])
    np.testing.assert_array_equal(cut.angles, log.angles)
    if getattr(log, "true_poses", None) is not None:
        np.testing.assert_array_equal(cut.true_poses, log.true_poses[5:])


@pytest.mark.long
def test_the_command_line_continues_a_simulated_run_from_its_folder(tmp_path, capsys):
    import json

    first, again = tmp_path / "first", tmp_path / "again"
    assert run_cli("run", "--dataset", "sim-laser", "--max-steps", "6", "--particles", "4", "--no-progress",
                   "--no-plots", "--out", str(first)) in (0, None)
    start = np.loadtxt(first / "trajectory.tum")[0]
    assert np.load(first / "map.npz")["pose"].shape == (3,)
    pose = [str(start[1]), str(start[2]), str(2.0 * np.arctan2(start[6], start[7]))]
    assert run_cli("run", "--dataset", "sim-laser", "--max-steps", "6", "--particles", "4", "--no-progress",
                   "--no-plots", "--start-map", str(first), "--initial-pose", *pose, "--out", str(again)) in (0, None)
    summary = json.loads((again / "summary.json").read_text())
    assert summary["start_map"]["pose_from"] == "--initial-pose"
    assert json.loads((again / "run.json").read_text())["start_map"] == str((first / "map.npz").resolve())
    a, b = np.loadtxt(first / "trajectory.tum"), np.loadtxt(again / "trajectory.tum")
    count = min(len(a), len(b))
    assert np.hypot(*(a[:count, 1:3] - b[:count, 1:3]).T).max() < 0.15
    saved, continued = load_map(first, require_free=False), load_map(again, require_free=False)
    assert continued.origin[0] <= saved.origin[0] and continued.origin[1] <= saved.origin[1]
