"""benchmarks/diagnostics/heading_budget.py: a run's heading error split by trusted and refused scans,
and the odometry-bias predictor it compares."""

from __future__ import annotations

import numpy as np
import pytest

from . import load_benchmark, turning_path

heading_budget = load_benchmark("diagnostics/heading_budget")
grid_common = load_benchmark("grid_common")


def test_budget_puts_the_error_on_the_scans_that_made_it():
    """The run equals the reference except for +2 deg on two refused scans and -1 deg on
    one trusted scan: the refused sum is +4 deg, the trusted one -1 deg, all +3 deg."""
    turns = np.radians([5.0, -3.0, 10.0, 0.0, -7.0, 2.0])
    reference = turning_path(turns)
    wrong = turns.copy()
    wrong[[1, 4]] += np.radians(2.0)
    wrong[2] -= np.radians(1.0)
    run = turning_path(wrong)
    accepted = np.array([1, 0, 1, 1, 0, 1], bool)
    keyframe = np.array([0, 1, 0, 1, 0, 0], bool)
    out = heading_budget.budget(grid_common.heading_errors(run, reference), accepted, keyframe)
    assert out["all_deg"] == pytest.approx(3.0, abs=1e-9)
    assert out["refused_deg"] == pytest.approx(4.0, abs=1e-9)
    assert out["trusted_deg"] == pytest.approx(-1.0, abs=1e-9)
    assert out["refused_keyframe_deg"] == pytest.approx(2.0, abs=1e-9)
    assert out["refused_between_deg"] == pytest.approx(2.0, abs=1e-9)
    assert out["refused_n"] == 2 and out["all_abs_deg"] == pytest.approx(5.0, abs=1e-9)


def test_bias_prediction_learns_a_constant_heading_bias_from_trusted_scans():
    """Odometry that turns 1 deg per metre too far, seen on trusted scans: after a few
    metres the predictor gives that bias for the next (refused) scans. With no trusted
    scans it predicts nothing."""
    rng = np.random.default_rng(0)
    n = 60
    true_turns = rng.normal(0.0, 0.1, n)
    run_inc = np.stack([np.ones(n), np.zeros(n), true_turns], -1)
    odom_inc = run_inc.copy()
    odom_inc[:, 2] += np.radians(1.0)  # 1 deg per 1 m step
    accepted = np.ones(n, bool)
    accepted[40:] = False
    predicted = heading_budget.bias_prediction(odom_inc, run_inc, accepted, length=20.0)
    assert np.degrees(predicted[45]) == pytest.approx(1.0, abs=0.05)
    none = heading_budget.bias_prediction(odom_inc, run_inc, np.zeros(n, bool), length=20.0)
    assert np.all(none == 0.0)


def test_seed_comes_from_the_run_name():
    assert heading_budget.seed_of("/x/fr-campus-high_srupf-gm_W3_s7.npz") == 7
    with pytest.raises(ValueError, match="no seed"):
        heading_budget.seed_of("/x/run.npz")
