"""The command line: every subcommand, bad arguments (exit 2), missing datasets."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from jaxslam.app import cli
from jaxslam.datasets import paths


def run_cli(*argv):
    try:
        return cli.main(list(argv))
    except SystemExit as exc:
        return exc.code


@pytest.fixture
def no_data(monkeypatch, tmp_path):
    """Point every data root at an empty folder."""
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv(paths.ENV_VAR, str(empty))
    monkeypatch.setattr(paths, "candidate_roots", lambda: [empty])
    return empty


def test_help_lists_every_subcommand(capsys):
    assert run_cli("--help") == 0
    out = capsys.readouterr().out
    for word in ("run", "evaluate", "datasets", "plot"):
        assert word in out


def test_run_help_explains_options_with_defaults(capsys):
    assert run_cli("run", "--help") == 0
    out = capsys.readouterr().out
    for option in ("--dataset", "--algorithm", "--particles", "--seed", "--out", "--set", "--max-steps"):
        assert option in out
    assert "default" in out


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (("run", "--particles", "0", "--out", "x"), "positive integer"),
        (("run", "--particles", "many", "--out", "x"), "positive integer"),
        (("run", "--algorithm", "kalman", "--out", "x"), "invalid choice"),
        (("run",), "--out"),
        (("run", "--out", "x", "--set", "speed_std"), "NAME=VALUE"),
        (("run", "--out", "x", "--set", "speed_std=fast"), "must be a number"),
        (("evaluate", "--trajectory", "t.tum"), "required"),
        (("frobnicate",), "invalid choice"),
    ],
)
def test_bad_arguments_exit_2_with_message(capsys, argv, fragment):
    assert run_cli(*argv) == 2
    assert fragment in capsys.readouterr().err


def test_unknown_dataset_and_wrong_kind(capsys, tmp_path):
    assert run_cli("run", "--dataset", "atlantis", "--out", str(tmp_path / "o")) == 2
    assert "unknown dataset 'atlantis'" in capsys.readouterr().err
    assert run_cli("run", "--dataset", "victoria-park", "--algorithm", "gmapping", "--out", str(tmp_path / "o")) == 2
    assert "needs laser data" in capsys.readouterr().err


def test_unknown_override_names_the_choices(capsys, tmp_path):
    assert run_cli("run", "--out", str(tmp_path / "o"), "--set", "warp_factor=9") == 2
    err = capsys.readouterr().err
    assert "no parameter 'warp_factor'" in err and "speed_std" in err


def test_missing_dataset_names_dataset_paths_and_env(no_data, capsys, tmp_path):
    assert run_cli("run", "--dataset", "victoria-park", "--out", str(tmp_path / "o")) == 2
    err = capsys.readouterr().err
    assert "victoria-park" in err
    assert str(no_data) in err
    assert "JAXSLAM_DATA" in err


def test_missing_carmen_path(capsys, tmp_path):
    assert run_cli("run", "--dataset", str(tmp_path / "nope.clf.gz"), "--out", str(tmp_path / "o")) == 2
    assert "does not exist" in capsys.readouterr().err


def test_datasets_lists_found_and_missing(capsys, no_data):
    assert run_cli("datasets") == 0
    out = capsys.readouterr().out
    assert "sim-landmarks" in out and "MISSING" in out and "JAXSLAM_DATA" in out


def test_datasets_finds_shipped_data(capsys):
    assert run_cli("datasets") == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if line.startswith("intel "))
    assert "found" in line


@pytest.mark.long
def test_run_simulated_landmarks_writes_outputs_then_evaluate_and_plot(tmp_path, capsys):
    out = tmp_path / "run"
    assert run_cli("run", "--out", str(out), "--particles", "8", "--max-steps", "60", "--no-progress",
                   "--set", "range_std=0.3") == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in ("algorithm", "dataset", "particles", "seed", "steps", "wall_s", "compile_s", "resamplings", "landmarks"):
        assert key in summary
    assert summary["steps"] == 60 and summary["particles"] == 8 and summary["overrides"] == {"range_std": 0.3}
    assert summary["cpus_allowed"] == len(os.sched_getaffinity(0))  # what XLA compiled for (taskset)
    for name in ("trajectory.tum", "landmarks.csv", "trajectory.png", "health.png", "arrays.npz"):
        assert (out / name).stat().st_size > 0
    # The run drew its figures from memory while arrays.npz was written; `plot` redraws
    # them from the file: the same images.
    drawn = {name: (out / name).read_bytes() for name in ("trajectory.png", "health.png")}
    (out / "trajectory.png").unlink()
    capsys.readouterr()
    assert run_cli("plot", str(out)) == 0
    assert {name: (out / name).read_bytes() for name in drawn} == drawn
    assert run_cli("plot", str(tmp_path)) == 2
    assert "arrays.npz" in capsys.readouterr().err


def test_evaluate_relations_of_raw_odometry(tmp_path, capsys):
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.metrics.trajectory_io import write_tum

    log = load_dataset_log("intel")
    traj = tmp_path / "odom.tum"
    write_tum(traj, log.scan_times, log.odom_poses)
    scores_file = tmp_path / "scores.json"
    assert run_cli("evaluate", "--relations", "intel", "--trajectory", str(traj), "--out", str(scores_file)) == 0
    scores = json.loads(scores_file.read_text())
    assert abs(scores["trans_err_mean_m"] - 7.37) < 0.01  # the README's raw-odometry figure
    assert run_cli("evaluate", "--relations", "mit-csail", "--trajectory", str(traj)) == 2
    assert "no relations file" in capsys.readouterr().err
    assert run_cli("evaluate", "--relations", "intel", "--trajectory", str(tmp_path / "none.tum")) == 2


def test_console_script_entry_point():
    result = subprocess.run([sys.executable, "-m", "jaxslam.app.cli", "datasets"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert np.any(["sim-laser" in line for line in result.stdout.splitlines()])


def test_console_script_exits_quickly_after_running_exit_handlers(tmp_path):
    """``console_main`` ends with ``os._exit``: the exit handlers must still run, the
    streams be flushed, and the command's exit status come through."""
    marker = tmp_path / "atexit-ran"
    program = (
        "import atexit, sys\n"
        f"atexit.register(lambda: open({str(marker)!r}, 'w').write('yes'))\n"
        "sys.argv = ['jaxslam', 'datasets']\n"
        "from jaxslam.app.cli import console_main\n"
        "console_main()\n"
        "print('not reached')\n"
    )
    result = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "sim-laser" in result.stdout and "not reached" not in result.stdout
    assert marker.read_text() == "yes"
    failed = subprocess.run([sys.executable, "-m", "jaxslam.app.cli", "evaluate", "--relations", "intel",
                             "--trajectory", str(tmp_path / "none.tum")], capture_output=True, text=True)
    assert failed.returncode == 2 and "none.tum" in failed.stderr


def test_installed_command_is_the_quick_exit_entry_point():
    from importlib.metadata import entry_points

    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "jaxslam"]
    assert script.value == "jaxslam.app.cli:console_main"


@pytest.mark.long
def test_interrupted_run_resumes_to_identical_outputs(tmp_path, monkeypatch, capsys):
    from jaxslam.runtime import checkpoint as ckpt

    common = ("--particles", "6", "--max-steps", "60", "--no-progress", "--no-plots", "--seed", "3")
    straight = tmp_path / "straight"
    assert run_cli("run", "--out", str(straight), *common) == 0

    original_save = ckpt.Checkpoint.save

    def save_then_crash(self, carry, done, leaves):
        original_save(self, carry, done, leaves)
        if done == 40:
            raise KeyboardInterrupt

    monkeypatch.setattr(ckpt.Checkpoint, "save", save_then_crash)
    interrupted = tmp_path / "interrupted"
    assert run_cli("run", "--out", str(interrupted), "--checkpoint-every", "20", *common) == 130
    assert not (interrupted / "summary.json").exists()
    monkeypatch.setattr(ckpt.Checkpoint, "save", original_save)
    assert run_cli("run", "--resume", str(interrupted), "--no-progress", "--no-plots") == 0
    assert (interrupted / "trajectory.tum").read_text() == (straight / "trajectory.tum").read_text()
    assert (interrupted / "landmarks.csv").read_text() == (straight / "landmarks.csv").read_text()
    assert json.loads((interrupted / "summary.json").read_text())["resumed"] is True

    # resuming a folder without a checkpoint is a clear error
    capsys.readouterr()
    assert run_cli("run", "--resume", str(straight)) == 2
    assert "no checkpoint" in capsys.readouterr().err


@pytest.mark.long
def test_grid_run_interrupted_and_resumed_equals_straight_run(tmp_path, monkeypatch):
    from jaxslam.runtime import checkpoint as ckpt

    common = ("--algorithm", "srupf-gm", "--particles", "4", "--max-steps", "24", "--no-progress", "--no-plots",
              "--linear-update", "0.4")
    straight = tmp_path / "straight"
    # Checkpoints every 8 steps as well: the same chunk length, so the three runs share
    # one compiled chunk (the result does not depend on it: tests/grid/test_paged.py).
    assert run_cli("run", "--out", str(straight), "--checkpoint-every", "8", *common) == 0
    rule = json.loads((straight / "summary.json").read_text())["keyframe_rule"]
    assert rule == {"linear_m": 0.4, "angular_rad": 0.5, "temporal_s": -1.0}
    original_save = ckpt.Checkpoint.save

    def save_then_crash(self, carry, done, leaves):
        original_save(self, carry, done, leaves)
        if done == 16:
            raise KeyboardInterrupt

    monkeypatch.setattr(ckpt.Checkpoint, "save", save_then_crash)
    interrupted = tmp_path / "interrupted"
    assert run_cli("run", "--out", str(interrupted), "--checkpoint-every", "8", *common) == 130
    monkeypatch.setattr(ckpt.Checkpoint, "save", original_save)
    assert run_cli("run", "--resume", str(interrupted), "--no-progress", "--no-plots") == 0
    assert (interrupted / "trajectory.tum").read_text() == (straight / "trajectory.tum").read_text()
    assert (interrupted / "map.pgm").read_bytes() == (straight / "map.pgm").read_bytes()
    assert json.loads((interrupted / "run.json").read_text())["keyframes"] == {"linear": 0.4}


@pytest.mark.long
def test_loop_closure_is_srupf_gms_default_can_be_turned_off_and_is_for_laser_data_only(capsys, tmp_path):
    out = tmp_path / "closure"
    assert run_cli("run", "--out", str(out), "--algorithm", "srupf-gm", "--particles", "2", "--max-steps", "6",
                   "--no-progress", "--no-plots") == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["loop_closure"] is True and summary["closures"] >= 0
    assert summary["tracking.refused_noise_scale"] == 0.5  # a parameter under its --set name
    assert isinstance(summary["closure_scans"], list)
    assert 0 <= summary["closures_undone"] <= summary["closures"] and isinstance(summary["undo_scans"], list)
    assert summary["closure_undone_at_end"] in (True, False)  # jaxslam.grid.undone_closures.judge_at_end
    assert json.loads((out / "run.json").read_text())["loop_closure"] is True  # the default, recorded
    off = tmp_path / "off"
    assert run_cli("run", "--out", str(off), "--algorithm", "srupf-gm", "--particles", "2", "--max-steps", "6",
                   "--no-progress", "--no-plots", "--no-loop-closure") == 0
    assert json.loads((off / "summary.json").read_text())["loop_closure"] is False
    assert json.loads((off / "run.json").read_text())["loop_closure"] is False
    capsys.readouterr()
    assert run_cli("run", "--out", str(tmp_path / "o"), "--algorithm", "erb-upf", "--loop-closure") == 2
    assert "laser data only" in capsys.readouterr().err
    assert run_cli("run", "--out", str(tmp_path / "o2"), "--algorithm", "erb-upf", "--no-loop-closure") == 2
    assert "laser data only" in capsys.readouterr().err


def test_keyframe_thresholds_are_for_laser_data_only(capsys, tmp_path):
    assert run_cli("run", "--out", str(tmp_path / "o"), "--linear-update", "0.5") == 2
    assert "laser data only" in capsys.readouterr().err


def test_float64_run_switches_x64_on_for_that_run_only(tmp_path):
    import jax

    from jaxslam.app import runs

    before = jax.config.jax_enable_x64
    summary = runs.run(out=tmp_path, algorithm="rb-upf", particles=2, max_steps=5, float64=True,
                       progress=False, plots=False)
    assert summary["dtype"] == "float64"
    assert np.load(tmp_path / "arrays.npz")["trajectory"].dtype == np.float64
    assert jax.config.jax_enable_x64 == before


@pytest.mark.parametrize("algorithm,linear", [("srupf-gm", 0.5), ("srupf-gm-npc", 0.5), ("gmapping", 1.0)])
def test_listed_params_carry_each_filters_keyframe_rule(algorithm, linear):
    """`--list-params` and the registry give a filter the keyframe rule it runs with."""
    from jaxslam.app.runs import param_fields
    from jaxslam.grid.algorithms import grid_algorithm
    from jaxslam.grid.experiment import KEYFRAME_PATHS, keyframe_rule

    rule = keyframe_rule(algorithm=algorithm)
    assert rule[0] == linear
    fields = param_fields(algorithm)
    assert tuple(fields[path] for path in KEYFRAME_PATHS) == rule
    assert float(grid_algorithm(algorithm).make_params(np.zeros(3)).keyframes.linear_update) == linear
