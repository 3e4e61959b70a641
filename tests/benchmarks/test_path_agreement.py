"""benchmarks/path_agreement.py: a path moved rigidly agrees with its reference to
rounding; a path that turns away is found where it parts, by as much as it parted."""

import json

import numpy as np
import pytest

from jaxslam.datasets.geometry import se2_compose

from . import load_benchmark

pa = load_benchmark("path_agreement")


def _walk(n, turn_at=None, turn=0.0):
    """A path of ``n`` poses, 0.1 m and 0.01 rad a scan; from scan ``turn_at`` on it
    turns ``turn`` rad more, once."""
    poses = np.zeros((n, 3))
    for i in range(n - 1):
        extra = turn if i == turn_at else 0.0
        poses[i + 1] = se2_compose(poses[i], np.array([0.1, 0.0, 0.01 + extra]))
    return poses


def test_a_rigidly_moved_path_agrees_and_a_turned_one_parts():
    reference = _walk(400)
    c, s = np.cos(1.2), np.sin(1.2)
    moved = reference.copy()
    moved[:, :2] = reference[:, :2] @ np.array([[c, -s], [s, c]]).T + [5.0, -3.0]
    np.testing.assert_allclose(pa.path_distances(moved, reference, 50), 0.0, atol=1e-9)

    turned = _walk(400, turn_at=200, turn=0.1)
    d = pa.path_distances(turned, reference, 50)
    np.testing.assert_allclose(d[:201], 0.0, atol=1e-9)
    # 0.1 rad at scan 200: the paths part by about 0.1 rad x the distance travelled since
    # (the reference's curve bends the chord a little).
    travelled = 0.1 * (np.arange(400) - 200)
    assert np.all(d[250:] > 0.5 * 0.1 * travelled[250:]) and np.all(d[250:] < 2 * 0.1 * travelled[250:])
    summary = pa.summarize(d, 50, 5)
    assert summary["scans"][0] == 49 and summary["scans"][-1] == 399
    assert summary["max_m"] == pytest.approx(d[49:].max())


def test_bad_arguments_are_named(tmp_path):
    with pytest.raises(ValueError, match="align_scans must be within 2..10"):
        pa.path_distances(np.zeros((10, 3)), np.zeros((12, 3)), 11)
    np.savez(tmp_path / "x.npz", poses=np.zeros((5, 3)))
    with pytest.raises(SystemExit, match="no 'trajectory'"):
        pa.main(["--reference", str(tmp_path / "x.npz"), str(tmp_path / "x.npz")])


def test_main_writes_the_table(tmp_path, monkeypatch):
    monkeypatch.setattr(pa, "write_json", lambda name, payload: (tmp_path / f"{name}.json").write_text(
        json.dumps(payload)) and tmp_path / f"{name}.json")
    np.savez(tmp_path / "ref.npz", trajectory=_walk(100))
    np.savez(tmp_path / "run.npz", trajectory=_walk(100, turn_at=60, turn=0.2))
    assert pa.main(["--reference", str(tmp_path / "ref.npz"), str(tmp_path / "run.npz"),
                    "--align-scans", "30", "--name", "t"]) == 0
    rows = json.loads((tmp_path / "path_agreement_t.json").read_text())["rows"]
    assert rows[0]["run"] == f"{tmp_path.name}/run.npz" and rows[0]["max_m"] > 0.3


class _Log:
    """Two scans of three beams, the laser 0.2 m ahead of the robot and turned 90 deg."""

    laser_offset = np.array([0.2, 0.0, np.pi / 2])
    ranges = np.array([[1.0, 2.0, 3.0], [1.0, 1.0, 1.0]])
    valid = np.array([[True, False, True], [True, True, True]])

    def beam_angles(self):
        return np.tile([-np.pi / 2, 0.0, np.pi / 2], (2, 1))


def test_scan_points_go_through_the_mounting_and_skip_invalid_beams(tmp_path):
    # Robot at (1, 1) facing +y: the laser sits at (1, 1.2) facing -x.
    pts = pa.scan_points(_Log(), np.array([0]), np.array([[1.0, 1.0, np.pi / 2]]))
    # Beam -90 deg of the laser points +y (1 m), beam +90 deg points -y (3 m); the 0 deg beam is invalid.
    np.testing.assert_allclose(pts, [[1.0, 2.2], [1.0, -1.8]], atol=1e-12)
    png = pa.draw_scans(_Log(), np.array([0, 1]), np.array([[1.0, 1.0, np.pi / 2], [0.0, 0.0, 0.0]]),
                        tmp_path / "m" / "a.png", "t")
    assert png.stat().st_size > 1000
