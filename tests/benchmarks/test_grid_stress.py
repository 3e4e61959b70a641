"""benchmarks/grid_stress.py: a run resumed from the kept state with the base seed is
the base run bit for bit; another seed or other parameters change only the scans after
the state; the seed list parser and the Wilson interval."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest

from jaxslam.datasets.laser_sim import simulate

from . import load_benchmark

grid_stress = load_benchmark("grid_stress")


def test_parse_seeds():
    assert grid_stress.parse_seeds("0-2,5, 7-7") == [0, 1, 2, 5, 7]
    with pytest.raises(SystemExit):
        grid_stress.parse_seeds("5-3")
    with pytest.raises(SystemExit):
        grid_stress.parse_seeds(" , ")


@pytest.mark.parametrize("failures,runs", [(0, 10), (6, 100), (3, 30), (30, 30)])
def test_wilson_matches_scipy(failures, runs):
    ci = binomtest(failures, runs).proportion_ci(0.95, method="wilson")
    lo, hi = grid_stress.wilson(failures, runs)
    assert lo == pytest.approx(ci.low, abs=2e-4) and hi == pytest.approx(ci.high, abs=2e-4)


def test_resume_reproduces_the_base_run_and_varies_only_the_stretch(tmp_path):
    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
    assert log.num_scans > 150
    path = tmp_path / "base.npz"
    saved_at, base = grid_stress.base_run(log, "srupf-gm", 4, 0, 100, path)
    assert saved_at == 100 and path.exists()
    again = grid_stress.resumed_run(log, "srupf-gm", 4, 0, {}, path)
    np.testing.assert_array_equal(again.trajectory, base.trajectory)
    np.testing.assert_array_equal(again.map_log_odds, base.map_log_odds)
    # Step t is scan t; the kept state is after step 100, so scans 0..100 are shared.
    for other in (grid_stress.resumed_run(log, "srupf-gm", 4, 7, {}, path),
                  grid_stress.resumed_run(log, "srupf-gm", 4, 0, {"track_noise_scale": 1.0}, path)):
        np.testing.assert_array_equal(other.trajectory[:101], base.trajectory[:101])
        assert not np.array_equal(other.trajectory[101:], base.trajectory[101:])


def test_own_base_is_the_variants_own_history(tmp_path):
    """--own-base: a variant's base run uses its parameters from the first scan, and the
    run resumed from it with the base seed is the variant's whole run."""
    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
    variant = {"track_noise_scale": 1.0}
    default_path = grid_stress.base_path(tmp_path, "sim", "srupf-gm", 4, 0, 100, {})
    own_path = grid_stress.base_path(tmp_path, "sim", "srupf-gm", 4, 0, 100, variant)
    assert own_path != default_path
    assert own_path == grid_stress.base_path(tmp_path, "sim", "srupf-gm", 4, 0, 100, dict(variant))
    _, default = grid_stress.base_run(log, "srupf-gm", 4, 0, 100, default_path)
    _, own = grid_stress.base_run(log, "srupf-gm", 4, 0, 100, own_path, variant)
    # The variant changes the history before the kept state, not only the stretch.
    assert not np.array_equal(own.trajectory[:101], default.trajectory[:101])
    again = grid_stress.resumed_run(log, "srupf-gm", 4, 0, variant, own_path)
    np.testing.assert_array_equal(again.trajectory, own.trajectory)
