"""Random damage to laser logs and bags: the command line's loading and checks either
give a log a filter can run on, or one line naming the file and the problem.

Each case goes through :func:`jaxslam.app.data.load_checked_log`, what ``jaxslam run``
does before it compiles anything (most damaged logs end there); a few go through the
whole command line in this process (exit status 2, one line). The exit-0 side (a
complete, valid output folder) is :mod:`tests.reliability.test_outputs`. The default
hypothesis profile is derandomized (``tests/conftest.py``).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxslam.app.data import load_checked_log
from jaxslam.datasets.paths import DataFormatError
from tests.reliability.conftest import assert_one_line_error
from tests.reliability.logs import carmen_text, flaser, room_scans

FUZZ = settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
JUNK = ["nan", "inf", "-inf", "-1", "0", "1e309", "abc", "", "1e6", "3.5.2", "FLASER", "\x00", "99999999999"]


def _check(path: Path):
    """The loaded log (every reading it keeps finite and its odometry finite), or the
    one-line DataFormatError that names ``path``; anything else fails the test."""
    try:
        log, _, report = load_checked_log(None, path, max_range=None)
    except DataFormatError as err:
        text = str(err)
        assert str(path) in text and "\n" not in text.strip(), text
        return None
    ranges = np.asarray(log.ranges)
    assert np.isfinite(ranges[np.asarray(log.valid)]).all()
    assert np.isfinite(np.asarray(log.odom_poses)).all()
    assert report["scans"] >= 2 and report["max_odometry_step_m"] <= report["odometry_step_bound_m"]
    return log


@pytest.fixture(scope="module")
def good_text():
    return carmen_text(*room_scans(scans=12, beams=31))


@FUZZ
@given(cut=st.integers(0, 10**6))
def test_truncated_log(good_text, cut):
    data = good_text.encode()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cut.clf"
        path.write_bytes(data[: cut % (len(data) + 1)])
        _check(path)


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(3, 14), st.integers(0, 80), st.sampled_from(JUNK)), min_size=1,
                      max_size=4))
def test_corrupted_fields(good_text, edits):
    lines = good_text.splitlines()
    for line, field, junk in edits:
        words = lines[line % len(lines)].split(" ")
        words[field % len(words)] = junk
        lines[line % len(lines)] = " ".join(words)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "corrupt.clf"
        path.write_text("\n".join(lines) + "\n")
        _check(path)


@FUZZ
@given(beams=st.lists(st.integers(1, 40), min_size=1, max_size=8),
       stamps=st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=1, max_size=8),
       jump=st.floats(0.0, 50.0))
def test_random_beam_counts_stamps_and_odometry(beams, stamps, jump):
    poses, _, _ = room_scans(scans=len(stamps))
    poses[len(stamps) // 2:, 1] += jump * 0.1
    rng = np.random.default_rng(len(beams))
    lines = ["PARAM robot_front_laser_max 30.0 nohost 0"]
    for i, stamp in enumerate(stamps):
        count = beams[i % len(beams)]
        lines.append(flaser(rng.uniform(0.1, 40.0, count), poses[i], stamp))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "random.clf"
        path.write_text("\n".join(lines) + "\n")
        log = _check(path)
    if log is not None:
        assert len(set(beams[: len(stamps)])) == 1  # a change of beam count is refused


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory):
    from jaxslam.datasets.carmen import load_carmen
    from jaxslam.datasets.rosbag_write import write_rosbag

    folder = tmp_path_factory.mktemp("bag")
    log_path = folder / "room.clf"
    log_path.write_text(carmen_text(*room_scans(scans=8, beams=21)))
    bag = write_rosbag(load_carmen(log_path), folder / "room.bag", version=1)
    return bag.read_bytes()


@FUZZ
@given(damage=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=6),
       cut=st.one_of(st.none(), st.integers(0, 10**6)))
def test_damaged_bag(good_bag, damage, cut):
    data = bytearray(good_bag)
    for offset, value in damage:
        data[offset % len(data)] = value
    if cut is not None:
        data = data[: cut % (len(data) + 1)]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "damaged.bag"
        path.write_bytes(bytes(data))
        _check(path)


@pytest.mark.parametrize("damage", ["truncated", "zeros", "random"])
def test_damaged_inputs_on_the_command_line(run_cli, tmp_path, good_bag, good_text, damage):
    """Through ``jaxslam run`` itself: exit status 2 and one line naming the file."""
    rng = np.random.default_rng(1)
    bag = tmp_path / "robot.bag"
    log = tmp_path / "robot.clf"
    if damage == "truncated":
        bag.write_bytes(good_bag[: len(good_bag) // 3])
        log.write_text(good_text[: good_text.index("FLASER") + 40])
    elif damage == "zeros":
        bag.write_bytes(bytes(len(good_bag)))
        log.write_bytes(bytes(500))
    else:
        bag.write_bytes(rng.bytes(len(good_bag)))
        log.write_bytes(rng.bytes(500))
    for path in (bag, log):
        status, _, err = run_cli("run", "--dataset", path, "--out", tmp_path / "out", "--no-progress")
        assert_one_line_error(status, err, str(path))


def test_bag_with_a_damaged_message_definition(good_bag):
    """A byte changed inside a connection's message definition: the bag library's
    error quotes the whole definition over many lines; the message stays one line."""
    data = bytearray(good_bag)
    data[good_bag.rindex(b"float32 angle_min") + 3] = 0x07
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "damaged.bag"
        path.write_bytes(bytes(data))
        assert _check(path) is None
