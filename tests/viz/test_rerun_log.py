"""The Rerun live view: map encoding, ellipses, the missing-extra message, and a
recording read back with Rerun's own reader (``rerun.chunk.RrdReader``)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from jaxslam.viz.rerun_log import INSTALL_HINT, ellipse_points, occupancy_percent, require_rerun


def read_rrd(path) -> dict[str, list[dict]]:
    """Rows of every entity in an ``.rrd`` file, with Rerun's reader: ``{entity: [row]}``,
    each row ``{"scan": index or None, "Archetype:component": value, ...}``, in time order."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = {}
    for chunk in RrdReader(path).stream():
        record = chunk.to_record_batch()
        wanted = [n for n in record.schema.names if ":" in n or n == "scan"]
        batch = {n: record.column(n).to_pylist() for n in wanted}
        names = [n for n in batch if ":" in n]
        for i in range(chunk.num_rows):
            row = {"scan": batch["scan"][i] if "scan" in batch else None}
            row.update({n: batch[n][i] for n in names})
            rows.setdefault(chunk.entity_path, []).append(row)
    for entity_rows in rows.values():
        entity_rows.sort(key=lambda row: -1 if row["scan"] is None else row["scan"])
    return rows


def decode_map(row) -> tuple[np.ndarray, float, tuple[float, float]]:
    """``(percent (H, W) with row 0 at the origin's y, cell size, origin)`` of a GridMap row."""
    fmt = row["GridMap:format"][0]
    image = np.array(row["GridMap:data"][0], np.uint8).reshape(fmt["height"], fmt["width"])
    origin = row["GridMap:translation"][0]
    return image[::-1], row["GridMap:cell_size"][0], (origin[0], origin[1])


def test_occupancy_percent_flips_rows_and_marks_unknown():
    log_odds = np.array([[0.0, 10.0], [-10.0, np.log(3.0)]])  # row 0 = lowest y
    image = occupancy_percent(log_odds)
    np.testing.assert_array_equal(image, [[0, 75], [255, 100]])  # top row = largest y


def test_ellipse_points_lie_on_the_three_sigma_contour():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(2, 2))
    cov = a @ a.T + 0.1 * np.eye(2)
    mean = np.array([3.0, -1.0])
    points = ellipse_points(mean, cov, sigmas=3.0, segments=40)
    d = points - mean
    np.testing.assert_allclose(np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d), 9.0, rtol=1e-9)
    np.testing.assert_allclose(points[0], points[-1])


def test_missing_rerun_names_the_install_command(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun now raises ImportError
    with pytest.raises(ImportError, match='pip install "jaxslam\\[viz\\]"'):
        require_rerun()
    from jaxslam.app import cli

    with pytest.raises(SystemExit) as info:
        cli.main(["run", "--dataset", "sim-laser", "--out", str(tmp_path / "x"), "--rerun", str(tmp_path / "x.rrd")])
    assert info.value.code == 2
    assert INSTALL_HINT in capsys.readouterr().err


def test_landmarks_and_health_read_back(tmp_path):
    pytest.importorskip("rerun")
    from jaxslam.viz.rerun_log import RerunLog

    viz = RerunLog(tmp_path / "lm.rrd")
    means = np.array([[1.0, 2.0], [-3.0, 0.5]])
    covs = np.array([np.diag([0.04, 0.01]), [[0.02, 0.01], [0.01, 0.03]]])
    for step in range(3):
        viz.at(step, 10.0 + step)
        viz.particles(np.array([[0.0, 0.0, 0.1 * step], [0.1, 0.0, 0.0]]))
        viz.health(2.0 - 0.5 * step, step == 2)
    viz.landmarks(means, covs)
    viz.close()
    rows = read_rrd(tmp_path / "lm.rrd")
    assert [r["scan"] for r in rows["/health/ess"]] == [0, 1, 2]
    assert [r["Scalars:scalars"][0] for r in rows["/health/ess"]] == [2.0, 1.5, 1.0]
    assert [r["Scalars:scalars"][0] for r in rows["/health/resampled"]] == [0.0, 0.0, 1.0]
    np.testing.assert_allclose(np.array(rows["/world/landmarks"][-1]["Points3D:positions"])[:, :2], means)
    strips = rows["/world/landmarks/ellipses"][-1]["LineStrips3D:strips"]
    assert len(strips) == 2
    np.testing.assert_allclose(np.array(strips[1])[:, :2], ellipse_points(means[1], covs[1]), atol=1e-5)
    assert len(rows["/world/particles"][-1]["Points3D:positions"]) == 2


def test_a_path_as_the_recordings_name_prints_nothing(tmp_path, capfd):
    """Rerun rewrites an application id with a path's ``/`` and ``.`` itself and prints
    a raw warning from its native logger (fd 2, out of reach of Python's warnings); the
    id is made valid first, so nothing reaches the terminal."""
    rr = pytest.importorskip("rerun")
    from jaxslam.viz.rerun_log import RerunLog, application_id

    assert application_id("jaxslam /data/robot.bag") == "jaxslam -data-robot-bag"
    assert application_id("jaxslam intel-corrected_2:a") == "jaxslam intel-corrected_2:a"
    viz = RerunLog(tmp_path / "path.rrd", name="jaxslam /data/runs/intel.clf.gz")
    viz.at(0, 1.0)
    viz.health(2.0, False)
    viz.close()
    assert rr.get_application_id(recording=viz.stream) == "jaxslam -data-runs-intel-clf-gz"
    assert read_rrd(tmp_path / "path.rrd")["/health/ess"][0]["Scalars:scalars"] == [2.0]
    captured = capfd.readouterr()
    assert captured.err == "" and captured.out == ""


def test_a_native_rerun_warning_becomes_one_plain_log_line(capfd, caplog):
    """What Rerun's native logger writes to fd 2 (here its warning about an invalid
    application id, which RerunLog itself never gives it) reaches the terminal only as
    a record of the ``jaxslam.viz.rerun`` logger: no ANSI, no timestamp, one line."""
    rr = pytest.importorskip("rerun")
    from jaxslam.viz.rerun_log import native_messages_to_logging

    with caplog.at_level("WARNING", logger="jaxslam.viz.rerun"):
        with native_messages_to_logging():
            rr.RecordingStream("runs/an.invalid/id")
    assert capfd.readouterr().err == ""
    (record,) = [r for r in caplog.records if r.name == "jaxslam.viz.rerun"]
    message = record.getMessage()
    assert record.levelname == "WARNING" and message.startswith("jaxslam: rerun: Application ID")
    assert "\x1b" not in message and "\n" not in message and "re_log_types" not in message

