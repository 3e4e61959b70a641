"""``jaxslam localize``: outputs on a simulated log, one-line errors for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxslam.app.cli import main
from jaxslam.datasets.laser_sim import simulate
from jaxslam.grid.export import save_map
from jaxslam.grid.mapfile import save_map_npz, segment_map


@pytest.fixture(scope="module")
def sim_map(tmp_path_factory):
    """The map of the built-in laser world (`--dataset sim-laser`, seed 0), as a run folder."""
    folder = tmp_path_factory.mktemp("map")
    log = simulate(seed=0)
    grid = segment_map(log.walls, (0.0, 0.0, 16.0, 10.0), 0.05)
    log_odds = np.select([grid.occupied, grid.free], [3.0, -3.0], 0.0).astype(np.float32)
    save_map(folder, log_odds, grid.resolution, grid.origin[:2])
    save_map_npz(folder / "map.npz", log_odds, grid.resolution, grid.origin)
    return folder, log


def test_localize_writes_trajectory_summary_and_figure(sim_map, tmp_path, capsys):
    folder, log = sim_map
    out = tmp_path / "loc"
    pose = [str(v) for v in log.true_poses[0]]
    assert main(["localize", "--map", str(folder / "map.yaml"), "--dataset", "sim-laser", "--initial-pose", *pose,
                 "--particles", "1000", "--max-steps", "120", "--chunk", "60", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())  # strict JSON
    assert summary["scans"] == 120 and summary["converged"] and not summary["global_start"]
    rows = np.loadtxt(out / "trajectory.tum")
    assert rows.shape == (120, 8) and np.all(np.isfinite(rows))
    assert np.hypot(*(rows[:, 1:3] - log.true_poses[:120, :2]).T).mean() < 0.1
    assert (out / "localization.png").stat().st_size > 10_000
    printed = capsys.readouterr().out  # the short report, not the JSON
    assert printed.startswith("localization of 120 scans from the given initial pose")
    assert "converged at scan" in printed and "summary.json" in printed and len(printed.splitlines()) == 5


@pytest.mark.parametrize(
    "args, message",
    [
        (["--global", "--initial-pose", "1", "1", "0"], "exclude each other"),
        (["--initial-std", "1", "1", "1"], "--initial-std needs --initial-pose"),
        (["--initial-pose", "100", "100", "0"], "lies outside the map"),
        (["--initial-pose", "1", "1", "0", "--initial-std", "0", "1", "1"], "must be positive"),
        (["--set", "sigma_hit"], "expected NAME=VALUE"),
        (["--set", "no_such=1"], "no such parameter"),
        (["--set", "sigma_hit=fast"], "must be a number"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(sim_map, tmp_path, capsys, args, message):
    folder, _ = sim_map
    with pytest.raises(SystemExit) as code:
        main(["localize", "--map", str(folder), "--dataset", "sim-laser", "--out", str(tmp_path / "o"), *args])
    assert code.value.code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and err.count("\n") == 0 and "Traceback" not in err


def test_bad_maps_exit_2_naming_the_file(tmp_path, capsys):
    (tmp_path / "m.yaml").write_text("image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    for target, message in [(tmp_path / "m.yaml", "does not exist"), (tmp_path / "none", "does not exist")]:
        with pytest.raises(SystemExit) as code:
            main(["localize", "--map", str(target), "--dataset", "sim-laser", "--out", str(tmp_path / "o")])
        assert code.value.code == 2
        err = capsys.readouterr().err.strip()
        assert message in err and str(target) in err and err.count("\n") == 0
    (tmp_path / "z.yaml").write_text("image: m.pgm\nresolution: 0\norigin: [0, 0, 0]\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    with pytest.raises(SystemExit) as code:
        main(["localize", "--map", str(tmp_path / "z.yaml"), "--dataset", "sim-laser", "--out", str(tmp_path / "o")])
    assert code.value.code == 2 and "line 2: resolution must be a positive" in capsys.readouterr().err


def test_a_grid_run_writes_a_map_that_reads_back(tmp_path):
    from jaxslam.grid.mapfile import load_map

    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--algorithm", "srupf-gm", "--particles", "2", "--max-steps", "6",
                 "--no-progress", "--no-plots"]) == 0
    saved = load_map(out, require_free=False)  # six scans: nothing is free enough yet
    assert saved.source.name == "map.npz" and saved.cells is not None and saved.tile is not None
    arrays = np.load(out / "arrays.npz")
    np.testing.assert_array_equal(saved.log_odds, arrays["log_odds"])
    assert saved.origin[:2] == tuple(arrays["origin"])
    np.testing.assert_array_equal(load_map(out / "map.yaml", require_free=False).occupancy, saved.occupancy)


def test_rerun_without_the_sdk_is_one_line_naming_the_install_command(sim_map, tmp_path, capsys, monkeypatch):
    import sys

    from jaxslam.viz.rerun_log import INSTALL_HINT

    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun now raises ImportError
    folder, _ = sim_map
    with pytest.raises(SystemExit) as code:
        main(["localize", "--map", str(folder), "--dataset", "sim-laser", "--out", str(tmp_path / "o"),
              "--rerun", str(tmp_path / "live.rrd")])
    assert code.value.code == 2
    err = capsys.readouterr().err.strip()
    assert INSTALL_HINT in err and "--rerun" in err and err.count("\n") == 0


def test_rerun_logs_the_run_and_compiles_nothing_the_plain_run_did_not(sim_map, tmp_path):
    """The live view follows the run chunk by chunk (the map, every scan's health, the
    cloud and the path at each chunk's end) and runs the plain run's programs."""
    pytest.importorskip("rerun")
    from jaxslam.runtime.cache import CompileCounter
    from tests.viz.test_rerun_log import decode_map, read_rrd

    folder, log = sim_map
    pose = [str(v) for v in log.true_poses[0]]
    common = ["localize", "--map", str(folder / "map.yaml"), "--dataset", "sim-laser", "--initial-pose", *pose,
              "--particles", "500", "--max-steps", "50", "--chunk", "20", "--no-plots", "--json"]
    assert main([*common, "--out", str(tmp_path / "plain")]) == 0
    with CompileCounter() as counter:
        assert main([*common, "--out", str(tmp_path / "live"), "--rerun", str(tmp_path / "live.rrd")]) == 0
    assert counter.requests == 0, counter.as_dict()
    assert (tmp_path / "live" / "trajectory.tum").read_text() == (tmp_path / "plain" / "trajectory.tum").read_text()
    summary = json.loads((tmp_path / "live" / "summary.json").read_text())
    assert summary["rerun"] == str(tmp_path / "live.rrd")
    rows = read_rrd(tmp_path / "live.rrd")
    assert [r["scan"] for r in rows["/health/ess"]] == list(range(50))
    assert [r["scan"] for r in rows["/health/particles"]] == list(range(50))
    assert [r["scan"] for r in rows["/world/particles"]] == [19, 39, 49]  # chunk ends
    assert len(rows["/world/scan"]) == 50
    path = np.array(rows["/world/trajectory"][-1]["LineStrips3D:strips"][0])[:, :2]
    tum = np.loadtxt(tmp_path / "plain" / "trajectory.tum")
    np.testing.assert_allclose(path, tum[:, 1:3], atol=1e-5)
    image, cell, origin = decode_map(rows["/world/map"][0])
    from jaxslam.grid.mapfile import load_map

    grid = load_map(folder / "map.yaml")
    expected = np.where(grid.occupancy < 0, 255, grid.occupancy.astype(np.int16))
    np.testing.assert_array_equal(image, expected)
    assert cell == pytest.approx(grid.resolution) and origin == pytest.approx(grid.origin[:2])
