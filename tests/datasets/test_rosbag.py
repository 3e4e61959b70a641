"""Tests of the ROS bag reader: Intel through ROS 1 / ROS 2 bags equals the CARMEN log
bit for bit (arrays, then a grid SLAM run), and every kind of bad bag."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from jaxslam.datasets.paths import DataFormatError
from jaxslam.datasets.rosbag import (
    LASER_SCAN,
    ODOMETRY,
    TF_MESSAGE,
    inspect_rosbag,
    is_rosbag,
    load_rosbag,
    ns_to_seconds,
    quaternion_yaw,
    seconds_to_ns,
    write_rosbag,
)

from tests.conftest import INTEL_GRID_OPTIONS as GRID_OPTIONS
from tests.conftest import INTEL_SEGMENT as SEGMENT

FIELDS = ("scan_times", "ranges", "valid", "max_range_mask", "angles", "angle_offsets", "odom_poses",
          "laser_offset")


@pytest.fixture(scope="module")
def intel(intel_segment):
    return intel_segment


@pytest.fixture(scope="module")
def bags(intel, tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    return {
        "ros1-odom": write_rosbag(intel, root / "intel.bag", version=1),
        "ros2-sqlite3-tf": write_rosbag(intel, root / "sqlite" / "intel", version=2, odometry="tf"),
        "ros2-mcap-odom": write_rosbag(intel, root / "mcap" / "intel", version=2, storage="mcap"),
    }


@pytest.mark.parametrize("kind", ["ros1-odom", "ros2-sqlite3-tf", "ros2-mcap-odom"])
def test_bag_arrays_equal_carmen(intel, bags, kind):
    log = load_rosbag(bags[kind])
    assert log.num_scans == intel.num_scans and log.num_beams == intel.num_beams
    for name in FIELDS:
        ours, theirs = getattr(log, name), getattr(intel, name)
        assert ours.dtype == theirs.dtype, name
        np.testing.assert_array_equal(ours, theirs, err_msg=name, strict=True)
    assert log.angular_resolution == intel.angular_resolution
    assert log.max_range == intel.max_range
    # Intel's short backward stamps are kept and counted, as the CARMEN reader does.
    assert log.stats["backwards_timestamps"] == int(np.sum(np.diff(intel.scan_times) < 0)) > 0
    assert log.stats["max_range_readings"] == int(intel.max_range_mask.sum())
    assert log.params["scan_topic"] == "/scan"
    assert log.params["odom_topic"] == ("/tf" if "tf" in kind else "/odom")


@pytest.fixture(scope="module")
def reference(intel_grid_reference):
    return intel_grid_reference


@pytest.mark.slow  # a third compile; the ROS 1 bag runs in the default suite (below) through the CLI
def test_grid_slam_on_bag_is_bit_identical(reference, bags):
    from jaxslam.grid.experiment import run_grid_slam

    result = run_grid_slam(load_rosbag(bags["ros2-sqlite3-tf"]), **GRID_OPTIONS)
    np.testing.assert_array_equal(result.keyframes, reference.keyframes)
    np.testing.assert_array_equal(result.trajectory, reference.trajectory)
    np.testing.assert_array_equal(result.map_log_odds, reference.map_log_odds)
    assert np.count_nonzero(reference.map_log_odds) > 1000  # the map is not empty


@pytest.mark.long
def test_cli_run_on_bag_is_bit_identical(reference, bags, tmp_path, capsys):
    from jaxslam.app import cli
    from jaxslam.metrics.trajectory_io import read_tum

    out = tmp_path / "run"
    code = cli.main(["run", "--dataset", str(bags["ros1-odom"]), "--scan-topic", "/scan", "--odom-topic", "/odom",
                     "--particles", "4", "--seed", "3", "--max-steps", "6", "--no-progress", "--no-plots",
                     "--out", str(out), "--rerun", str(tmp_path / "run.rrd")])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["bag"]["scan_topic"] == "/scan" and summary["keyframes"] == 6
    arrays = np.load(out / "arrays.npz")
    np.testing.assert_array_equal(arrays["trajectory"], reference.trajectory)
    np.testing.assert_array_equal(arrays["log_odds"], reference.map_log_odds)
    times, _ = read_tum(out / "trajectory.tum")
    np.testing.assert_array_equal(times, reference.scan_times)  # the bag's header stamps, exactly
    assert (out / "map.pgm").exists() and (out / "map.yaml").exists()
    _check_recording(tmp_path / "run.rrd", reference)


def _check_recording(path, reference):
    """The live view's recording, read back with Rerun's reader, holds the run."""
    from jaxslam.viz.rerun_log import occupancy_percent
    from tests.viz.test_rerun_log import decode_map, read_rrd

    rows = read_rrd(path)
    keyframe_scans = reference.keyframes[1:].tolist()
    assert [r["scan"] for r in rows["/world/particles"]] == keyframe_scans
    assert all(len(r["Points3D:positions"]) == 4 for r in rows["/world/particles"])
    assert [r["scan"] for r in rows["/health/ess"]] == keyframe_scans
    image, cell, origin = decode_map(rows["/world/map"][-1])
    assert rows["/world/map"][-1]["scan"] == keyframe_scans[-1]
    np.testing.assert_array_equal(image, occupancy_percent(reference.map_log_odds)[::-1])
    assert cell == pytest.approx(reference.resolution) and origin == pytest.approx(reference.origin)
    path_xy = np.array(rows["/world/trajectory"][-1]["LineStrips3D:strips"][0])[:, :2]
    np.testing.assert_allclose(path_xy, reference.keyframe_poses[:, :2], atol=1e-5)
    # The last scan, placed at the best pose, falls on cells the map calls occupied.
    hits = np.array(rows["/world/scan"][-1]["Points3D:positions"])[:, :2]
    cells = np.floor((hits - np.array(origin)) / cell).astype(int)
    assert np.mean(image[cells[:, 1], cells[:, 0]] > 50) > 0.8


def test_cli_inspect_and_bag_errors(bags, tmp_path, capsys):
    from jaxslam.app import cli

    assert cli.main(["datasets", "--inspect", str(bags["ros2-mcap-odom"])]) == 0
    out = capsys.readouterr().out
    assert "/scan" in out and "sensor_msgs/msg/LaserScan" in out and "300" in out and "/tf_static" in out

    def fails(*argv):
        with pytest.raises(SystemExit) as info:
            cli.main(list(argv))
        assert info.value.code == 2
        return capsys.readouterr().err

    run = ("run", "--no-progress", "--no-plots", "--out", str(tmp_path / "x"))
    assert "topic /laser is not in the bag" in fails(*run, "--dataset", str(bags["ros1-odom"]), "--scan-topic",
                                                    "/laser")
    assert "apply to ROS bags only" in fails(*run, "--dataset", "sim-laser", "--scan-topic", "/scan")
    assert "ROS bag" in fails(*run, "--dataset", str(tmp_path / "nothing.bag"))
    assert "does not exist" in fails("datasets", "--inspect", str(tmp_path / "nothing.bag"))
    (tmp_path / "text.bag").write_text("not a bag")
    assert "cannot read the bag" in fails("datasets", "--inspect", str(tmp_path / "text.bag"))


def test_inspect_lists_topics(bags):
    rows = {row["topic"]: row for row in inspect_rosbag(bags["ros1-odom"])}
    assert set(rows) == {"/scan", "/odom", "/tf_static"}
    assert rows["/scan"]["type"] == LASER_SCAN and rows["/scan"]["count"] == SEGMENT
    assert rows["/odom"]["type"] == ODOMETRY and rows["/tf_static"]["count"] == 1
    assert 4.0 < rows["/scan"]["rate_hz"] < 8.0  # Intel: about 5 scans per second
    assert is_rosbag(bags["ros1-odom"]) and is_rosbag(bags["ros2-mcap-odom"])


def test_stamp_and_heading_round_trips():
    rng = np.random.default_rng(0)
    stamps = rng.uniform(0, 2e9, 2000).round(6)
    assert all(ns_to_seconds(seconds_to_ns(t)) == t for t in stamps)
    headings = rng.uniform(-np.pi, np.pi, 5000).round(6)  # decimal headings: exact
    yaw, cos_tilt = quaternion_yaw(0.0, 0.0, np.sin(headings / 2), np.cos(headings / 2))
    np.testing.assert_array_equal(yaw, headings)
    np.testing.assert_allclose(cos_tilt, 1.0)
    raw = rng.uniform(-np.pi, np.pi, 5000)  # any float64: within one ulp
    yaw, _ = quaternion_yaw(0.0, 0.0, np.sin(raw / 2), np.cos(raw / 2))
    assert np.max(np.abs(yaw - raw) / np.spacing(np.abs(raw))) <= 1.0
    # General quaternions (one upside down) against SciPy's rotation matrix.
    from scipy.spatial.transform import Rotation

    for euler in ([0.0, 0.0, 0.7], [np.pi, 0.0, -2.0], [0.05, -0.02, 3.0]):
        rot = Rotation.from_euler("xyz", euler)
        qx, qy, qz, qw = rot.as_quat()
        matrix = rot.as_matrix()
        yaw, cos_tilt = quaternion_yaw(qx, qy, qz, qw)
        assert yaw == pytest.approx(np.arctan2(matrix[1, 0], matrix[0, 0]), abs=1e-12)
        assert cos_tilt == pytest.approx(matrix[2, 2], abs=1e-12)


# --------------------------------------------------------------------------- bad bags


def _write(path, scans=(), odoms=(), statics=(("base_link", "laser", (0.0, 0.0, 0.0)),), extra=(),
           version=2):
    """A small bag. ``scans``: (stamp_s, ranges, frame, topic) with optional
    range_max; ``odoms``: (stamp_s, x, y, theta); ``extra``: (topic, msgtype)."""
    store = get_typestore(Stores.ROS2_HUMBLE if version == 2 else Stores.ROS1_NOETIC)
    if TF_MESSAGE not in store.types:
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))
    T = store.types

    def header(t, frame):
        ns = seconds_to_ns(t)
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        if version == 1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def ser(msg, typ):
        return store.serialize_cdr(msg, typ) if version == 2 else store.serialize_ros1(msg, typ)

    def quat(theta, roll=0.0):  # Rz(theta) Rx(roll)
        cr, sr = np.cos(roll / 2), np.sin(roll / 2)
        cy, sy = np.cos(theta / 2), np.sin(theta / 2)
        return T["geometry_msgs/msg/Quaternion"](x=cy * sr, y=sy * sr, z=sy * cr, w=cy * cr)

    def tfs(t, parent, child, pose, roll=0.0):
        return T[TF_MESSAGE](transforms=[T["geometry_msgs/msg/TransformStamped"](
            header=header(t, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=pose[0], y=pose[1], z=0.0),
                rotation=quat(pose[2], roll)))])

    if version == 1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=9)
    zero3 = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    with writer:
        conns = {}

        def conn(topic, typ):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, typ, typestore=store)
            return conns[topic]

        record = 1
        for parent, child, pose, *roll in statics:
            writer.write(conn("/tf_static", TF_MESSAGE), record, ser(tfs(0.0, parent, child, pose, *roll), TF_MESSAGE))
            record += 1
        for topic, typ in extra:
            conn(topic, typ)
        # Odometry first, then the scans in the given order (record time keeps it).
        events = [(t, "odom", (x, y, th)) for t, x, y, th in odoms] + [(s[0], "scan", s) for s in scans]
        for t, what, data in events:
            if what == "odom":
                msg = T[ODOMETRY](
                    header=header(t, "odom"), child_frame_id="base_link",
                    pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=data[0], y=data[1], z=0.0),
                        orientation=quat(data[2])), covariance=np.zeros(36)),
                    twist=T["geometry_msgs/msg/TwistWithCovariance"](
                        twist=T["geometry_msgs/msg/Twist"](linear=zero3, angular=zero3), covariance=np.zeros(36)))
                writer.write(conn("/odom", ODOMETRY), record, ser(msg, ODOMETRY))
            else:
                stamp, ranges, frame, topic, *rest = data
                ranges = np.asarray(ranges, np.float32)
                msg = T[LASER_SCAN](
                    header=header(stamp, frame), angle_min=-np.pi / 2, angle_max=np.pi / 2,
                    angle_increment=np.pi / max(ranges.shape[0] - 1, 1), time_increment=0.0, scan_time=0.0,
                    range_min=0.1, range_max=rest[0] if rest else 10.0, ranges=ranges,
                    intensities=np.zeros(0, np.float32))
                writer.write(conn(topic, LASER_SCAN), record, ser(msg, LASER_SCAN))
            record += 1
    return path


def _scans(times, beams=5, frame="laser", topic="/scan", value=2.0):
    return [(t, np.full(beams, value), frame, topic) for t in times]


def _odoms(times):
    return [(t, 0.1 * i, 0.0, 0.01 * i) for i, t in enumerate(times)]


def _error(path, match, **options):
    with pytest.raises(DataFormatError, match=match) as info:
        load_rosbag(path, **options)
    assert str(path) in str(info.value)
    return str(info.value)


def test_good_small_bag_interpolates_odometry(tmp_path):
    bag = _write(tmp_path / "ok", _scans([10.25, 10.5, 10.75]), _odoms([10.0, 10.5, 11.0]))
    log = load_rosbag(bag)
    np.testing.assert_allclose(log.odom_poses[:, 0], [0.05, 0.1, 0.15], rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.odom_poses[:, 2], [0.005, 0.01, 0.015], rtol=0, atol=1e-12)
    assert log.odom_poses[1, 2] == 0.01  # stamped exactly at an odometry message: that pose
    np.testing.assert_array_equal(log.scan_times, [10.25, 10.5, 10.75])


def test_missing_topic(tmp_path):
    bag = _write(tmp_path / "b", _scans([1.0, 2.0]), _odoms([0.5, 2.5]))
    text = _error(bag, r"topic /front_scan is not in the bag; its topics: /odom \(nav_msgs", scan_topic="/front_scan")
    assert "/scan (sensor_msgs/msg/LaserScan)" in text
    _error(bag, "topic /wheel_odom is not in the bag", odom_topic="/wheel_odom")


def test_no_scan_topic(tmp_path):
    bag = _write(tmp_path / "b", (), _odoms([0.5, 2.5]))
    _error(bag, "no sensor_msgs/msg/LaserScan topic in the bag")


def test_wrong_type(tmp_path):
    bag = _write(tmp_path / "b", _scans([1.0, 2.0]), _odoms([0.5, 2.5]))
    _error(bag, "topic /odom has type nav_msgs/msg/Odometry, but the scan topic needs sensor_msgs/msg/LaserScan",
           scan_topic="/odom")
    _error(bag, "topic /scan has type sensor_msgs/msg/LaserScan, but odometry needs nav_msgs/msg/Odometry or "
           "tf2_msgs/msg/TFMessage", odom_topic="/scan")


def test_two_scan_topics_need_a_choice(tmp_path):
    scans = _scans([1.0, 2.0]) + _scans([1.1, 2.1], topic="/rear_scan")
    bag = _write(tmp_path / "b", scans, _odoms([0.5, 2.5]))
    _error(bag, r"2 sensor_msgs/msg/LaserScan topics \(/rear_scan, /scan\); choose one with scan_topic")
    assert load_rosbag(bag, scan_topic="/rear_scan").num_scans == 2


def test_no_odometry(tmp_path):
    bag = _write(tmp_path / "b", _scans([1.0, 2.0]), (), statics=())
    _error(bag, "no odometry: neither a nav_msgs/msg/Odometry topic nor /tf")


def test_non_monotonic_stamps(tmp_path):
    bag = _write(tmp_path / "b", _scans([1.0, 2.0, 3.0, 1.5, 4.0]), _odoms([0.5, 4.5]))
    _error(bag, r"topic /scan, message 3: header stamp 1.5 goes back 1.5 s from the previous scan \(message 2\)")
    skipped = load_rosbag(bag, on_error="skip")
    assert skipped.num_scans == 4 and skipped.stats["skipped:backwards_timestamp"] == 1
    assert "message 3" in skipped.problems[0]
    small = _write(tmp_path / "small", _scans([1.0, 2.0, 1.8, 3.0]), _odoms([0.5, 4.5]))
    assert load_rosbag(small).stats["backwards_timestamps"] == 1  # kept and counted
    _error(small, "message 2: header stamp 1.8 goes back", max_backstep=0.0)


def test_beam_count_changes(tmp_path):
    scans = _scans([1.0, 2.0]) + _scans([3.0], beams=7) + _scans([4.0])
    bag = _write(tmp_path / "b", scans, _odoms([0.5, 4.5]))
    _error(bag, r"topic /scan, message 2: beam count changes: 7 beams .* but 5 beams .* in message 0")
    skipped = load_rosbag(bag, on_error="skip")
    assert skipped.num_scans == 3 and skipped.stats["skipped:geometry_change"] == 1


def test_nonfinite_and_max_range_readings(tmp_path):
    ranges = np.array([2.0, np.nan, np.inf, -np.inf, 10.0, 12.0, 0.05, 0.0, -1.0, 3.0], np.float32)
    scans = [(1.0, ranges, "laser", "/scan"), (2.0, np.full(10, 2.0), "laser", "/scan")]
    log = load_rosbag(_write(tmp_path / "b", scans, _odoms([0.5, 2.5])))
    np.testing.assert_array_equal(log.valid[0], [1, 0, 0, 0, 0, 0, 0, 0, 0, 1])
    # +inf (REP 117: no return) and r >= range_max clear free space but are never hits.
    np.testing.assert_array_equal(log.max_range_mask[0], [0, 0, 1, 0, 1, 1, 0, 0, 0, 0])
    assert not np.any(log.valid & log.max_range_mask)
    assert log.stats["max_range_readings"] == 2 and log.stats["inf_readings"] == 1
    assert log.stats["nonfinite_readings"] == 2  # NaN and -inf
    assert log.stats["below_range_min_readings"] == 1 and log.stats["nonpositive_readings"] == 2
    assert log.max_range == 10.0
    assert load_rosbag(_write(tmp_path / "c", scans, _odoms([0.5, 2.5])), max_range=11.0).max_range_mask[0, 4] == 0


def test_zero_stamp(tmp_path):
    bag = _write(tmp_path / "b", _scans([0.0, 1.0, 2.0]), _odoms([0.5, 2.5]))
    _error(bag, "topic /scan, message 0: header stamp is zero")


def test_missing_laser_transform(tmp_path):
    bag = _write(tmp_path / "b", _scans([1.0, 2.0], frame="lidar"), _odoms([0.5, 2.5]))
    _error(bag, "no transform from the base frame 'base_link' to the laser frame 'lidar'")
    log = load_rosbag(bag, laser_offset=(0.2, 0.0, 0.0))
    np.testing.assert_array_equal(log.laser_offset, [0.2, 0.0, 0.0])


def test_mount_chain_flip_and_tilt(tmp_path):
    statics = (("base_link", "plate", (0.1, 0.0, np.pi / 2)), ("plate", "laser", (0.2, 0.0, 0.0)))
    log = load_rosbag(_write(tmp_path / "chain", _scans([1.0, 2.0]), _odoms([0.5, 2.5]), statics=statics))
    np.testing.assert_allclose(log.laser_offset, [0.1, 0.2, np.pi / 2], atol=1e-12)
    flipped = (("base_link", "laser", (0.0, 0.0, 0.0), np.pi),)
    log = load_rosbag(_write(tmp_path / "flip", _scans([1.0, 2.0]), _odoms([0.5, 2.5]), statics=flipped))
    assert log.params["laser_flipped"] == "true" and log.angles[0] > 0 > log.angles[-1]
    tilted = (("base_link", "laser", (0.0, 0.0, 0.0), 0.5),)
    _error(_write(tmp_path / "tilt", _scans([1.0, 2.0]), _odoms([0.5, 2.5]), statics=tilted),
           "the laser frame 'laser' is tilted by 0.5 rad")


def test_scans_outside_odometry_are_dropped_and_counted(tmp_path):
    bag = _write(tmp_path / "b", _scans([0.2, 1.0, 2.0, 3.0]), _odoms([0.5, 2.5]))
    log = load_rosbag(bag)
    assert log.num_scans == 2 and log.stats["scans_outside_odometry"] == 2
    assert "messages [0, 3]" in log.problems[0]
    _error(_write(tmp_path / "c", _scans([5.0, 6.0]), _odoms([0.5, 2.5])), "no scan is stamped within the odometry")


def test_not_a_bag(tmp_path):
    text = tmp_path / "scans.bag"
    text.write_text("this is not a bag\n")
    _error(text, "cannot read the bag")
    folder = tmp_path / "folder"
    folder.mkdir()
    _error(folder, "not a ROS bag")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_rosbag(tmp_path / "missing.bag")


def test_ros1_small_bag_and_tf_odometry(tmp_path):
    bag = _write(tmp_path / "b.bag", _scans([1.0, 2.0]), _odoms([0.5, 2.5]), version=1)
    log = load_rosbag(bag)
    assert log.num_scans == 2 and log.params["base_frame"] == "base_link"
