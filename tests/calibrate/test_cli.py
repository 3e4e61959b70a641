"""``jaxslam calibrate`` and ``jaxslam run --params``."""

from __future__ import annotations

import json

import pytest

from jaxslam.app.calibrate import load_params_file
from jaxslam.app.cli import main
from jaxslam.datasets.paths import DataFormatError
from jaxslam.app.runs import RunError


def test_params_file_errors(tmp_path):
    with pytest.raises(RunError, match="no such file"):
        load_params_file(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DataFormatError, match="not valid JSON"):
        load_params_file(bad)
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"params_after": {"range_std": "x"}}))
    with pytest.raises(DataFormatError, match="params_after"):
        load_params_file(wrong)
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"params_after": {"range_std": 0.5}}))
    assert load_params_file(good) == {"range_std": 0.5}


def test_gmapping_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--algorithm", "gmapping", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "no differentiable proposal" in capsys.readouterr().err


@pytest.mark.slow
def test_calibrate_then_run_with_params(tmp_path):
    out = tmp_path / "cal"
    assert main(["calibrate", "--out", str(out), "--particles", "4", "--filters", "2", "--steps", "3",
                 "--window", "16", "--learning-rate", "0.1", "--validate-every", "1",
                 "--validation-filters", "2"]) == 0
    payload = json.loads((out / "calibration.json").read_text())
    assert len(payload["log_likelihood"]) == 3
    assert (out / "calibration.png").exists()
    assert payload["params_last"] != payload["params_before"]
    best = payload["parameter_trajectory"][payload["best_step"]]
    assert [payload["params_after"][n] for n in payload["names"]] == pytest.approx(best)
    assert payload["fit_window"] == 12 and payload["validation"]["steps"] == [0, 1, 2, 3]
    assert payload["validation"]["selected_step"] == payload["best_step"]
    assert payload["log_likelihood"][payload["train_best_step"]] == max(payload["log_likelihood"])
    run_out = tmp_path / "run"
    assert main(["run", "--out", str(run_out), "--particles", "4", "--max-steps", "16", "--no-plots",
                 "--no-progress", "--params", str(out / "calibration.json")]) == 0
    summary = json.loads((run_out / "summary.json").read_text())
    assert summary["overrides"] == payload["params_after"]


def test_grid_calibration_is_given_the_log(tmp_path, monkeypatch):
    """The grid branch reads the CARMEN log (through the runs' loader) and hands the
    log itself to calibrate_grid (stopped there: a calibration is a slow test)."""
    import jaxslam.calibrate.grid as grid_calibration
    from jaxslam.datasets.carmen import CarmenLog
    from tests.datasets.test_carmen import GOOD, _write

    class Stop(Exception):
        pass

    seen = {}

    def fake(log, **options):
        seen["log"] = log
        raise Stop

    monkeypatch.setattr(grid_calibration, "calibrate_grid", fake)
    log_path = _write(tmp_path, GOOD)
    with pytest.raises(Stop):
        main(["calibrate", "--algorithm", "srupf-gm", "--dataset", str(log_path), "--out", str(tmp_path / "cal")])
    assert isinstance(seen["log"], CarmenLog) and seen["log"].num_scans == 2


def payload_of_a_calibration(validation=True):
    return {"dataset": "sim-landmarks", "algorithm": "erb-upf", "params_before": {"range_std": 0.9, "q": [1.0, 2.0]},
            "params_after": {"range_std": 0.31, "q": [0.5, 2.5]}, "best_step": 2, "steps": 3,
            "log_likelihood": [-3.0, -2.0, -1.5], "log_likelihood_unit": "log Z / scans (mean over filters)",
            "validation": {"steps": [0, 1, 2, 3], "mean_scores": [-4.0, -3.0, -2.5, -2.6], "selected_step": 2}
            if validation else None, "compile_s": 12.0, "time_s": 3.5}


def test_the_short_summary_names_values_objectives_and_files(tmp_path):
    from jaxslam.app.calibrate import report, summary

    (tmp_path / "calibration.json").write_text("{}")
    text = report(summary(payload_of_a_calibration()), tmp_path)
    assert text.splitlines()[0] == "erb-upf calibrated on sim-landmarks"
    assert "0.9 -> 0.31" in text and "[1, 2] -> [0.5, 2.5]" in text
    assert "-3.0000 -> -1.5000 per fitted scan" in text and "-4.0000 -> -2.5000 per held-out scan" in text
    assert "Adam iterate 2 of 3" in text and f"{tmp_path}: calibration.json" in text
    assert len(text.splitlines()) <= 10
    assert "- -> -" not in text
    without = summary(payload_of_a_calibration(validation=False))
    assert without["objective_held_out"] is None
    assert "-3.0000 -> -1.5000 per fitted scan (log Z" in report(without, tmp_path)
