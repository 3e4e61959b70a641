"""Every bad input a user really has gets exit status 2 and one line naming the file or
option and the problem, before anything is compiled."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from tests.reliability.conftest import assert_one_line_error
from tests.reliability.logs import carmen_text, flaser, room_log, room_scans


@pytest.fixture
def logs(tmp_path):
    poses, stamps, ranges = room_scans()
    folder = tmp_path / "logs"
    folder.mkdir()

    def write(name, *scans):
        path = folder / name
        path.write_text(carmen_text(*scans))
        return path

    jumped = poses.copy()
    jumped[15:, 0] += 100.0
    lines = carmen_text(poses, stamps, ranges).splitlines()
    lines[10] = flaser(ranges[7][:40], poses[7], stamps[7])
    (folder / "beams.clf").write_text("\n".join(lines) + "\n")
    (folder / "empty.clf").write_text("")
    (folder / "random.bag").write_bytes(np.random.default_rng(0).bytes(4096))
    return {
        "good": room_log(folder / "good.clf"),
        "one": write("one.clf", poses[:1], stamps[:1], ranges[:1]),
        "no_return": write("no_return.clf", poses, stamps, np.full_like(ranges, 1e6)),
        "jump": write("jump.clf", jumped, stamps, ranges),
        "same_stamps": write("same_stamps.clf", poses, np.full_like(stamps, 5.0), ranges),
        "beams": folder / "beams.clf",
        "empty": folder / "empty.clf",
        "bag": folder / "random.bag",
    }


CASES = {
    # name: (argv with {log} placeholders, fragments of the one line)
    "one-scan log": (["--dataset", "{one}"], ["one.clf", "1 scan(s)", "at least two"]),
    "empty log": (["--dataset", "{empty}"], ["empty.clf", "no laser scans"]),
    "all beams no-return": (["--dataset", "{no_return}"], ["no_return.clf", "has a return"]),
    "odometry jump of 100 m": (["--dataset", "{jump}"], ["jump.clf, line 19", "jumps 100 m", "--max-odometry-step"]),
    "stamps that do not advance, temporal rule on": (
        ["--dataset", "{same_stamps}", "--temporal-update", "1"], ["same_stamps.clf", "do not advance"]),
    "beam count changes mid-log": (["--dataset", "{beams}"], ["beams.clf, line 11", "--mixed-geometry pad"]),
    "random bytes named .bag": (["--dataset", "{bag}"], ["random.bag"]),
    "matcher.score_sigma=nan": (["--dataset", "{good}", "--set", "matcher.score_sigma=nan"],
                                ["matcher.score_sigma=nan", "finite"]),
    "map.l_occ=inf": (["--dataset", "{good}", "--set", "map.l_occ=inf"], ["map.l_occ=inf", "finite"]),
    "matcher.score_sigma=-1": (["--dataset", "{good}", "--set", "matcher.score_sigma=-1"],
                               ["matcher.score_sigma=-1", "> 0"]),
    "range_std=0 (landmark)": (["--set", "range_std=0"], ["range_std=0", "> 0"]),
    "a parameter of another filter": (["--dataset", "{good}", "--set", "gmapping.srr=0.1"], ["gmapping.srr", "gmapping"]),
    "a grid parameter by its field name alone": (["--dataset", "{good}", "--set", "closure_trigger=0.3"],
                                                 ["closure_trigger", "did you mean 'closure.trigger'"]),
    "a misspelt parameter": (["--set", "range_sd=1"], ["range_sd", "did you mean 'range_std'"]),
    "--max-steps 1 on laser data": (["--dataset", "{good}", "--max-steps", "1"], ["--max-steps 1"]),
    "--linear-update nan": (["--dataset", "{good}", "--linear-update", "nan"], ["--linear-update", "finite"]),
    "--max-range inf": (["--dataset", "{good}", "--max-range", "inf"], ["--max-range"]),
    "--max-odometry-step 0": (["--dataset", "{good}", "--max-odometry-step", "0"], ["--max-odometry-step"]),
    "--threads 0": (["--threads", "0"], ["'all'"]),
    "--laser-mount nan": (["--dataset", "{good}", "--laser-mount", "0", "nan", "0"], ["ROS bags only"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_before_compilation(run_cli, logs, tmp_path, case):
    argv, fragments = CASES[case]
    argv = [a.format(**{k: str(v) for k, v in logs.items()}) for a in argv]
    out = tmp_path / "out"
    status, stdout, err = run_cli("run", *argv, "--out", out, "--no-progress", "--no-plots")
    assert_one_line_error(status, err, *fragments)
    assert "compiling" not in err
    assert not (out / "summary.json").exists()


def test_too_many_particles_names_what_fits(run_cli, tmp_path):
    from jaxslam.grid.experiment import map_layout
    from jaxslam.grid.paged import PoolLimitError

    log_path = room_log(tmp_path / "room.clf")
    status, _, err = run_cli("run", "--dataset", log_path, "--particles", "100000", "--out", tmp_path / "o",
                             "--no-progress")
    assert_one_line_error(status, err, "--particles 100000", "int32", "particles fit")
    most = int(err.split("at most ")[1].split()[0])
    from jaxslam.datasets.carmen import load_carmen

    log = load_carmen(log_path)
    map_layout(log, np.arange(log.num_scans), 0.05, 30.0, most, 20.0)  # fits
    with pytest.raises(PoolLimitError):
        map_layout(log, np.arange(log.num_scans), 0.05, 30.0, 2 * most + 2, 20.0)


def test_out_naming_a_file(run_cli, tmp_path):
    existing = tmp_path / "a_file"
    existing.write_text("x")
    status, _, err = run_cli("run", "--out", existing)
    assert_one_line_error(status, err, "a_file", "is a file")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_out_in_a_read_only_folder(run_cli, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    status, _, err = run_cli("run", "--out", locked / "run")
    assert_one_line_error(status, err, "locked", "not writable")


@pytest.mark.parametrize("saved, fragment", [
    ({"dataset": "sim-landmarks", "algorithm": "erb-upf", "warp": 9}, "unknown key(s) 'warp'"),
    ([1, 2], "JSON object"),
])
def test_resume_of_a_foreign_run_json(run_cli, tmp_path, saved, fragment):
    (tmp_path / "run.json").write_text(json.dumps(saved))
    status, _, err = run_cli("run", "--resume", tmp_path)
    assert_one_line_error(status, err, "run.json", fragment)


def test_log_checks_pass_on_a_good_log_and_report(tmp_path):
    from jaxslam.datasets.carmen import load_carmen
    from jaxslam.datasets.checks import check_laser_log

    poses, stamps, ranges = room_scans()
    stamps[5] = stamps[4]  # one repeated stamp: kept and counted
    path = tmp_path / "room.clf"
    path.write_text(carmen_text(poses, stamps, ranges))
    report = check_laser_log(load_carmen(path))
    assert report["scans"] == 30 and report["stamp_steps_repeated"] == 1 and report["stamps_advance"]
    assert report["max_odometry_step_m"] == pytest.approx(np.hypot(0.1, 0.02), abs=1e-5)


@pytest.mark.parametrize("fill, fragment", [(np.inf, "has a return"), (np.nan, "has a return"),
                                            (None, "at least two")])
def test_bags_without_returns_or_with_one_scan(run_cli, tmp_path, fill, fragment):
    import dataclasses

    from jaxslam.datasets.carmen import load_carmen
    from jaxslam.datasets.rosbag_write import write_rosbag

    log = load_carmen(room_log(tmp_path / "room.clf"))
    if fill is not None:
        log = dataclasses.replace(log, ranges=np.full_like(log.ranges, fill))
    bag = write_rosbag(log, tmp_path / "robot.bag", version=1, scans=None if fill is not None else slice(0, 1))
    status, _, err = run_cli("run", "--dataset", bag, "--out", tmp_path / "out", "--no-progress")
    assert_one_line_error(status, err, "robot.bag", fragment)
