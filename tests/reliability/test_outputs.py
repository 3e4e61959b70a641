"""Output folders are whole or clearly not: staged files moved into place at the end,
``run.json`` saying ``complete``, ``interrupted`` or ``failed``, and strict JSON."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from jaxslam.app.outputs import STAGE_PREFIX, marked_run, strict_json, write_summary
from tests.reliability.logs import room_log


def _strict_load(path):
    def refuse(constant):
        raise ValueError(f"{path}: {constant} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_summary_holds_null_for_non_finite_values_and_says_where(tmp_path):
    summary = {"a": float("nan"), "b": [1.0, np.float32("inf")], "c": {"d": -math.inf, "e": np.int64(3)},
               "f": (np.bool_(True), None, "x")}
    written = write_summary(tmp_path / "summary.json", summary)
    loaded = _strict_load(tmp_path / "summary.json")
    assert loaded == written
    assert loaded["a"] is None and loaded["b"] == [1.0, None] and loaded["c"] == {"d": None, "e": 3}
    assert loaded["f"] == [True, None, "x"]
    assert loaded["nonfinite_values"] == ["a", "b[1]", "c.d"]
    assert "nonfinite_values" not in write_summary(tmp_path / "s2.json", {"a": 1.0})
    assert strict_json(np.array([[1.0, np.nan]])) == [[1.0, None]]


@pytest.mark.parametrize("ending, status", [(None, "complete"), (RuntimeError("disk\nfull"), "failed"),
                                            (KeyboardInterrupt(), "interrupted")])
def test_marked_run_states(tmp_path, ending, status):
    out = tmp_path / "run"
    out.mkdir()
    (out / "trajectory.tum").write_text("an earlier run's\n")
    (out / f"{STAGE_PREFIX}12345").mkdir()  # left by a killed run
    try:
        with marked_run(out, {"dataset": "d", "seed": 0}) as stage:
            assert _strict_load(out / "run.json")["status"] == "running"
            (stage / "trajectory.tum").write_text("this run's\n")
            (stage / "summary.json").write_text("{}\n")
            if ending is not None:
                raise ending
    except (RuntimeError, KeyboardInterrupt) as err:
        assert err is ending
    saved = _strict_load(out / "run.json")
    assert saved["status"] == status and saved["dataset"] == "d"
    assert not list(out.glob(f"{STAGE_PREFIX}*"))
    if status == "complete":
        assert "reason" not in saved
        assert (out / "trajectory.tum").read_text() == "this run's\n" and (out / "summary.json").exists()
    else:
        assert saved["reason"] in ("RuntimeError: disk", "interrupted by the user (KeyboardInterrupt)")
        assert (out / "trajectory.tum").read_text() == "an earlier run's\n"
        assert not (out / "summary.json").exists()


def test_resume_reads_the_arguments_beside_the_status(tmp_path):
    from jaxslam.app.cli import saved_arguments

    saved = {"dataset": "intel", "particles": 5, "status": "interrupted", "reason": "interrupted by the user"}
    assert saved_arguments(tmp_path / "run.json", saved) == {"dataset": "intel", "particles": 5}


def test_a_laser_run_writes_a_complete_valid_folder(run_cli, tmp_path):
    """The exit-0 side: a short run of the room log, in this process."""
    out = tmp_path / "out"
    status, stdout, err = run_cli("run", "--dataset", room_log(tmp_path / "room.clf"), "--particles", "3",
                                  "--out", out, "--no-progress", "--no-plots")
    assert status == 0, err
    assert "Traceback" not in err
    assert _strict_load(out / "run.json")["status"] == "complete"
    summary = _strict_load(out / "summary.json")
    assert "nonfinite_values" not in summary and summary["finite"]
    assert summary["log_checks"]["scans"] == 30 and summary["log_checks"]["stamps_advance"]
    assert sorted(p.name for p in out.iterdir()) == [
        "arrays.npz", "map.npz", "map.pgm", "map.png", "map.yaml", "run.json", "summary.json", "trajectory.tum"]
    rows = np.loadtxt(out / "trajectory.tum", comments="#")
    assert rows.shape == (30, 8) and np.isfinite(rows).all()
    # the path follows the room's drive (0.1 m a scan from x = 2 m)
    assert abs(rows[-1, 1] - rows[0, 1] - 2.9) < 0.5
