"""``jaxslam export-bag``: a laser log written as a ROS bag that ``jaxslam run`` reads
back as the same scans, odometry and laser mount."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.app.cli import main
from jaxslam.datasets.registry import lookup
from jaxslam.datasets.rosbag import load_rosbag


@pytest.fixture(scope="module")
def sim_log():
    return lookup("sim-laser").load(seed=0)


@pytest.mark.parametrize("name, storage", [("sim.bag", "sqlite3"), ("sim_ros2", "sqlite3"), ("sim_mcap", "mcap")])
def test_the_bag_reads_back_as_the_log(tmp_path, capsys, sim_log, name, storage):
    out = tmp_path / name
    assert main(["export-bag", "--dataset", "sim-laser", "--max-scans", "40", "--storage", storage,
                 "--out", str(out)]) == 0
    line = capsys.readouterr().out
    assert line.startswith(f"wrote {out}: ROS {1 if name.endswith('.bag') else 2} bag") and "40 scans" in line
    back = load_rosbag(out)
    assert back.num_scans == 40
    np.testing.assert_allclose(back.ranges, sim_log.ranges[:40], rtol=1e-6)
    np.testing.assert_allclose(back.odom_poses, sim_log.odom_poses[:40], atol=1e-6)
    np.testing.assert_allclose(back.laser_offset, sim_log.laser_offset, atol=1e-6)


def test_odometry_on_tf(tmp_path, capsys, sim_log):
    out = tmp_path / "tf.bag"
    assert main(["export-bag", "--dataset", "sim-laser", "--max-scans", "10", "--odometry", "tf",
                 "--out", str(out)]) == 0
    assert "/tf," in capsys.readouterr().out
    np.testing.assert_allclose(load_rosbag(out).odom_poses, sim_log.odom_poses[:10], atol=1e-6)


@pytest.mark.parametrize("argv, message", [
    (["--dataset", "sim-landmarks"], "writes laser logs"),
    (["--dataset", "no-such-log"], "unknown dataset"),
    (["--dataset", "missing.clf"], "does not exist"),
])
def test_bad_input_is_one_line_and_status_2(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exit_:
        main(["export-bag", *argv, "--out", str(tmp_path / "x.bag")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_an_existing_bag_is_not_overwritten(tmp_path, capsys):
    out = tmp_path / "x.bag"
    out.write_text("keep")
    with pytest.raises(SystemExit) as exit_:
        main(["export-bag", "--dataset", "sim-laser", "--out", str(out)])
    assert exit_.value.code == 2 and "already exists" in capsys.readouterr().err
    assert out.read_text() == "keep"
