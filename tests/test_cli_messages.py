"""What the command line tells its user: help texts true to the code and each default
shown once, the short report at the end of a run, evaluate's count of what it scored,
and the unknown-dataset message."""

import argparse
import dataclasses
import json
import math

import numpy as np
import pytest

from jaxslam.app import cli


def run_cli(*argv):
    try:
        return cli.main(list(argv))
    except SystemExit as exc:
        return exc.code


def parsers() -> dict[str, argparse.ArgumentParser]:
    """The top-level parser and every subcommand's."""
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return {"jaxslam": parser, **{f"jaxslam {name}": p for name, p in sub.choices.items()}}


def rendered_help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The help of one option as ``--help`` prints it (defaults filled in), one line."""
    return " ".join(parser._get_formatter()._expand_help(action).split())


def option_help(command: str, option: str) -> str:
    parser = parsers()[command]
    (action,) = [a for a in parser._actions if option in a.option_strings]
    return rendered_help(parser, action)


@pytest.mark.parametrize("command", list(parsers()))
def test_no_help_repeats_its_default_nor_shows_an_empty_one(command):
    parser = parsers()[command]
    for action in parser._actions:
        if not action.help or action.help is argparse.SUPPRESS or isinstance(action, argparse._HelpAction):
            continue
        text = rendered_help(parser, action)
        name = "/".join(action.option_strings) or action.dest
        assert text.lower().count("default") <= 1, f"{command} {name}: {text}"
        for empty in ("(default: None)", "(default: False)", "(default: [])", "(default: )"):
            assert empty not in text, f"{command} {name}: {text}"
        meaningful = action.default not in (None, False, [], argparse.SUPPRESS)
        if meaningful:  # a default that is a value is shown, once
            assert "default" in text.lower(), f"{command} {name} hides its default {action.default!r}: {text}"
    # and nothing of that kind in the whole page either
    page = parser.format_help()
    assert "(default: None)" not in page


def test_help_states_the_defaults_the_code_uses():
    from jaxslam.app.runs import DEFAULT_PARTICLES
    from jaxslam.grid.driver import DEFAULT_CHUNK
    from jaxslam.grid.experiment import keyframe_rule

    srupf, gmapping = keyframe_rule(algorithm="srupf-gm"), keyframe_rule(algorithm="gmapping")
    particles = option_help("jaxslam run", "--particles")
    assert f"{DEFAULT_PARTICLES['landmark']} for landmark data, {DEFAULT_PARTICLES['laser']} for laser data" in particles
    linear = option_help("jaxslam run", "--linear-update")
    assert f"default {srupf[0]:g} for srupf-gm, GMapping's {gmapping[0]:g}" in linear
    assert f"default {srupf[1]:g})" in option_help("jaxslam run", "--angular-update")
    assert srupf[1] == gmapping[1]
    assert f"default {srupf[2]:g}: off" in option_help("jaxslam run", "--temporal-update")
    assert f"{DEFAULT_CHUNK} scans for laser data" in option_help("jaxslam run", "--chunk")
    assert "(default: 20)" in option_help("jaxslam calibrate", "--particles")
    from jaxslam.app.runs import LOCALIZE_PARTICLES, LOCALIZE_SCANS

    assert f"({LOCALIZE_PARTICLES} particles, the first {LOCALIZE_SCANS} scans" in option_help("jaxslam run",
                                                                                               "--localize-first")


def test_loop_closure_help_states_the_searchs_configured_reach():
    from jaxslam.grid import closure
    from jaxslam.grid.algorithms import grid_algorithm
    from jaxslam.grid.types import GridSlamConfig

    config = {f.name: f.default for f in dataclasses.fields(GridSlamConfig)}
    params = grid_algorithm("srupf-gm").make_params(np.zeros(1, np.float32))
    turn_deg = round(config["closure_turn"] / closure.TURN_STEP) * math.degrees(closure.TURN_STEP)
    text = option_help("jaxslam run", "--loop-closure")
    assert f"up to {config['closure_radius']:g} m (each axis) and {turn_deg:.0f} deg" in text
    assert f"up to {config['closure_radius_far']:g} m ({100 * float(params.closure.reach_rate):.0f} cm per m" in text
    assert f"over the next {float(params.closure.watch):g} m is undone" in text


@pytest.mark.long
def test_run_ends_with_a_short_report_and_prints_the_summary_with_json(tmp_path, capsys):
    common = ("--algorithm", "rb-upf", "--particles", "2", "--max-steps", "5", "--no-progress", "--no-plots")
    out = tmp_path / "short"
    assert run_cli("run", "--out", str(out), *common) == 0
    lines = capsys.readouterr().out.splitlines()
    assert 4 <= len(lines) <= 8, lines
    assert lines[0] == "rb-upf on sim-landmarks, 2 particles, seed 0"
    text = "\n".join(lines)
    summary = json.loads((out / "summary.json").read_text())  # the whole summary stays in the folder
    assert f"{summary['pos_err_mean_m']:.3f} m mean" in text and "against the ground truth" in text
    assert "5 steps" in text and f"compilation {summary['compile_s']:.1f} s" in text
    files = next(line for line in lines if line.lstrip().startswith("files"))
    assert str(out) in files and "summary.json" in files and "trajectory.tum" in files

    as_json = tmp_path / "json"
    assert run_cli("run", "--out", str(as_json), "--json", *common) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((as_json / "summary.json").read_text())


def test_report_of_relations_and_gps_scores_names_how_many_were_scored(tmp_path):
    from jaxslam.app.report import report

    (tmp_path / "summary.json").write_text("{}")
    common = {"particles": 30, "seed": 1, "resamplings": 4, "wall_s": 2.0, "compile_s": 9.5, "total_s": 12.25,
              "compilations": {"compiled": 1, "cache_hits": 3}}
    grid = {"algorithm": "srupf-gm", "dataset": "intel", "scans": 764, "keyframes": 61, "closures": 2,
            "closures_undone": 1, "keyframes_per_s": 30.5, "trans_err_mean_m": 0.0256, "trans_err_median_m": 0.0207,
            "trans_err_max_m": 0.194, "n_trans_err_over_0_5m": 0, "rot_err_mean_deg": 0.309, "n_relations": 71,
            "n_unmatched": 2913, "n_total": 2984, **common}
    text = report(grid, tmp_path)
    assert text.splitlines()[0] == "srupf-gm on intel, 30 particles, seed 1"
    assert "764 scans, 61 keyframes, 4 resamplings, 2 loop closures (1 undone)" in text
    assert "0.026 m mean, 0.021 m median, 0.194 m max (0 over 0.5 m), 0.31 deg mean; 71 of 2984 scored" in text
    assert "12.2 s in all: compilation 9.5 s (1 programs compiled, 3 loaded from the cache), filter loop 2.00 s" in text
    assert f"{tmp_path}: summary.json" in text
    gps = {"algorithm": "erb-upf", "dataset": "victoria-park", "steps": 7000, "landmarks": 90, "steps_per_s": 3500.0,
           "gps_mean_m": 2.345, "gps_rms_m": 2.9, "gps_max_m": 8.0, "n_used": 4000, "n_skipped": 466, **common}
    assert "2.35 m mean, 2.90 m RMS, 8.00 m max; 4000 of 4466 fixes used" in report(gps, tmp_path)
    unscored = {**grid, "trans_err_mean_m": float("nan"), "n_relations": 0}
    assert "n/a m mean" in report(unscored, tmp_path) and "0 of 2984 scored" in report(unscored, tmp_path)


def test_evaluate_says_how_many_relations_it_scored_and_warns_below_the_fraction(tmp_path, capsys):
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.metrics.scoring import MIN_MATCHED_FRACTION
    from jaxslam.metrics.trajectory_io import write_tum

    log = load_dataset_log("intel")
    whole, short = tmp_path / "whole.tum", tmp_path / "short.tum"
    write_tum(whole, log.scan_times, log.odom_poses)
    write_tum(short, log.scan_times[:800], log.odom_poses[:800])
    assert run_cli("evaluate", "--relations", "intel", "--trajectory", str(whole)) == 0
    captured = capsys.readouterr()
    assert captured.err == "jaxslam evaluate: scored 2984 of 2984 relations (100.0%)\n"
    assert json.loads(captured.out)["n_relations"] == 2984

    assert run_cli("evaluate", "--relations", "intel", "--trajectory", str(short)) == 0
    captured = capsys.readouterr()
    scores = json.loads(captured.out)
    scored, total = scores["n_relations"], scores["n_total"]
    assert 0 < scored / total < MIN_MATCHED_FRACTION
    (line,) = captured.err.splitlines()
    assert line.startswith(f"jaxslam evaluate: warning: scored {scored} of {total} relations")
    assert f"fewer than {MIN_MATCHED_FRACTION:.0%}" in line
    assert f"{MIN_MATCHED_FRACTION:.0%}" in parsers()["jaxslam evaluate"].format_help()


def test_evaluate_counts_gps_fixes_and_warns_for_part_of_the_drive(tmp_path, capsys):
    from jaxslam.datasets.victoria_park import load_gps
    from jaxslam.metrics.trajectory_io import write_tum

    fixes = load_gps()
    part = fixes.times <= fixes.times[0] + 0.3 * (fixes.times[-1] - fixes.times[0])
    poses = np.column_stack([fixes.xy[part], np.zeros(part.sum())])
    trajectory = tmp_path / "part.tum"
    write_tum(trajectory, fixes.times[part], poses)
    assert run_cli("evaluate", "--gps", "victoria-park", "--trajectory", str(trajectory)) == 0
    captured = capsys.readouterr()
    scores = json.loads(captured.out)
    total = scores["n_used"] + scores["n_skipped"]
    assert total == fixes.times.shape[0]
    (line,) = captured.err.splitlines()
    assert line.startswith(f"jaxslam evaluate: warning: scored {scores['n_used']} of {total} GPS fixes")
    assert run_cli("evaluate", "--gps", "atlantis", "--trajectory", str(trajectory)) == 2
    assert "unknown dataset 'atlantis'" in capsys.readouterr().err


def test_unknown_dataset_names_every_kind_of_input(tmp_path, capsys):
    from jaxslam.datasets.registry import DATASETS
    from jaxslam.datasets.rosbag import ROSBAG_SUFFIXES

    assert run_cli("run", "--dataset", "atlantis", "--out", str(tmp_path / "o")) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("jaxslam run: error: unknown dataset 'atlantis'")
    for name in DATASETS:
        assert name in line
    for kind in ("CARMEN log", ".clf", ".log", ".carmen", ".gz", "ROS 1 bag", "ROS 2 bag", "metadata.yaml",
                 *ROSBAG_SUFFIXES):
        assert kind in line, kind


def test_evaluate_threshold_is_the_scorings():
    """The command line states evaluate's warning threshold without importing the
    metrics at load; it must be the one the scoring uses."""
    from jaxslam.metrics.scoring import MIN_MATCHED_FRACTION

    assert cli.MIN_MATCHED_FRACTION == MIN_MATCHED_FRACTION
