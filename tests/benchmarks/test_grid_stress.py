"""benchmarks/grid_stress.py: a run resumed from the kept state with the base seed is
the base run bit for bit; another seed or other parameters change only the scans after
the state; --own-base runs a variant from its own history; merging joins base states
of one kind; the seed list parser and the Wilson interval."""

from __future__ import annotations

import json

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


@pytest.mark.long
def test_resume_reproduces_the_base_run_and_varies_only_the_stretch(tmp_path):
    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
    assert log.num_scans > 150
    path = tmp_path / "base.npz"
    saved_at, base = grid_stress.base_run(log, "srupf-gm", 4, 0, 100, path)
    assert saved_at == 100 and path.exists()
    again = grid_stress.resumed_run(log, "srupf-gm", 4, 0, {}, path)
    np.testing.assert_array_equal(again.trajectory, base.trajectory)
    np.testing.assert_array_equal(again.map_log_odds, base.map_log_odds)
    # Step t is scan t; the kept state is after step 100, so scans 0..100 are shared by
    # one particle's run. (With several, the path reported is the lineage of the final
    # best particle, and another seed can end on a particle that descends from another
    # one of the kept state, whose path before step 100 is its own.)
    one = tmp_path / "one.npz"
    _, single = grid_stress.base_run(log, "srupf-gm", 1, 0, 100, one)
    for other in (grid_stress.resumed_run(log, "srupf-gm", 1, 7, {}, one),
                  grid_stress.resumed_run(log, "srupf-gm", 1, 0, {"track_noise_scale": 1.0}, one)):
        np.testing.assert_array_equal(other.trajectory[:101], single.trajectory[:101])
        assert not np.array_equal(other.trajectory[101:], single.trajectory[101:])


@pytest.mark.long
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


def test_merge_joins_bases_and_refuses_other_kinds_of_base(tmp_path, monkeypatch):
    import _common  # the benchmarks' helpers, loaded with grid_stress

    monkeypatch.setattr(_common, "RESULTS", tmp_path)
    monkeypatch.setattr(grid_stress, "RESULTS", tmp_path)

    def part(name, base_seed, own_base, failed):
        settings = {"log": "intel", "algorithm": "gmapping", "particles": 30, "from_scan": 11000,
                    "base_seeds": [base_seed], "variants": {"v": {}}, "own_base": own_base}
        runs = [{"variant": "v", "base_seed": base_seed, "seed": s, "failed": s < failed, "mean_m": 0.03,
                 "max_m": 0.5, "filter_s": 4.0} for s in range(10)]
        bases = [{"saved_at_scan": 11008, "base_seed": base_seed, "made_with": {}}]
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps({"note": "n", "settings": settings, "bases": bases, "runs": runs}))
        return str(path)

    a, b = part("a", 0, True, 1), part("b", 6, True, 2)
    assert grid_stress.merge([a, b], "joined") == 0
    joined = json.loads((tmp_path / "grid_stress_joined.json").read_text())
    assert joined["settings"]["base_seeds"] == [0, 6] and len(joined["bases"]) == 2
    (row,) = joined["summary"]
    assert (row["runs"], row["failures"]) == (20, 3)
    assert (tmp_path / "grid_stress_joined.png").exists()
    with pytest.raises(SystemExit, match="kind of base state"):
        grid_stress.merge([a, part("c", 9, False, 0)], "mixed")
