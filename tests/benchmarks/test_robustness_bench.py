"""benchmarks/grid_robustness.py: a perturbed log made from a raw benchmark log is scored
on the raw log's relations: its scans found in the raw log by their range readings
(``grid_common.raw_scan_indices``), laser poses turned into robot poses, and the
relation error checked against an independent computation by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from jaxslam.metrics.relations import Relations

from . import load_benchmark

robustness = load_benchmark("grid_robustness")
grid_common = load_benchmark("grid_common")


def _raw(n: int = 6, offset=(0.0, 0.0, 0.0)) -> SimpleNamespace:
    """A raw log: n scans of 4 beams with distinct readings, stamps 0.2 s apart."""
    ranges = (np.arange(n * 4, dtype=np.float32).reshape(n, 4) + 1.0) * 0.25
    return SimpleNamespace(num_scans=n, ranges=ranges, scan_times=1000.0 + 0.2 * np.arange(n),
                           laser_offset=np.asarray(offset))


def test_scans_are_found_by_their_readings():
    raw = _raw()
    other = np.stack([raw.ranges[4], raw.ranges[1], raw.ranges[1] + 0.01])
    np.testing.assert_array_equal(grid_common.raw_scan_indices(raw, other), [4, 1, -1])


def test_too_few_scans_found_gives_no_benchmark():
    raw = _raw()
    log = SimpleNamespace(ranges=np.concatenate([raw.ranges[:3], raw.ranges[:3] + 0.01]))
    assert robustness.benchmark_reference(raw, None, log) is None


def _relation(a: np.ndarray, b: np.ndarray) -> list[float]:
    """Pose b in the frame of pose a, written out."""
    c, s = np.cos(a[2]), np.sin(a[2])
    d = b[:2] - a[:2]
    return [c * d[0] + s * d[1], -s * d[0] + c * d[1], b[2] - a[2]]


def test_benchmark_score_equals_the_relation_error_by_hand():
    offset = np.array([-0.3, 0.1, 0.2])  # laser pose in the robot frame
    raw = _raw(offset=offset)
    kept = np.array([0, 2, 3, 5])  # the perturbed log holds these raw scans, in this order
    log = SimpleNamespace(ranges=raw.ranges[kept])
    rng = np.random.default_rng(0)
    laser = np.cumsum(rng.normal(size=(len(kept), 3)) * [1.0, 1.0, 0.3], axis=0)
    # robot pose r with r (+) offset = laser pose, by hand
    robot = []
    for x, y, th in laser:
        phi = th - offset[2]
        c, s = np.cos(phi), np.sin(phi)
        robot.append([x - (c * offset[0] - s * offset[1]), y - (s * offset[0] + c * offset[1]), phi])
    robot = np.array(robot)
    t = raw.scan_times
    # exact, 0.5 m off along x, and one relation to a scan the perturbed log lacks
    true = np.array([_relation(robot[0], robot[1]), _relation(robot[1], robot[3]), [1.0, 0.0, 0.0]])
    true[1, 0] += 0.5
    relations = Relations(path=None, t1=np.array([t[0], t[2], t[3]]), t2=np.array([t[2], t[5], t[4]]),
                          deltas=true, lines=np.arange(1, 4))
    bench = robustness.benchmark_reference(raw, relations, log)
    np.testing.assert_array_equal(bench[0], t[kept])
    got = robustness.score_benchmark(bench, laser)
    assert got["bench_n_relations"] == 2
    assert got["bench_mean_m"] == pytest.approx(0.25, abs=1e-9)
    assert got["bench_max_m"] == pytest.approx(0.5, abs=1e-9)
    # a run cut short scores the scans it has; a longer trajectory is an error
    assert robustness.score_benchmark(bench, laser[:2])["bench_mean_m"] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="not one pose per scan"):
        robustness.score_benchmark(bench, np.zeros((5, 3)))
    assert robustness.score_benchmark(None, laser) == {}


def test_the_tail_is_the_share_of_seeds_over_twice_the_median_seed():
    median, share = robustness.tail([0.04, 0.05, 0.06, 0.13, 1.2])
    assert median == pytest.approx(0.06)
    assert share == pytest.approx(2 / 5)  # 0.13 and 1.2 are over twice the median, 0.12
    assert robustness.tail([0.05, 0.1]) == (pytest.approx(0.075), 0.0)
    assert robustness.tail([0.05, 0.05, 0.1000001])[1] == pytest.approx(1 / 3)


def test_each_code_split_is_summarised_on_its_own_seeds():
    def row(seed, mean, split=None):
        r = {"log": "mit-killian", "filter": "srupf-gm", "seed": seed, "mean_m": mean, "max_m": 10 * mean,
             "over_0.5m": int(mean > 0.5), "jump_max_m": 0.1, "wall_s": 1.0, "cpu_s": 1.0}
        return r if split is None else {**r, "code_split": split}

    rows = [row(0, 0.05, 8), row(1, 0.05, 8), row(2, 0.9, 8), row(0, 0.04, 32), row(1, 0.05, 32), row(2, 0.06, 32)]
    cells = {s["code_split"]: s for s in robustness.summarize(rows)}
    assert set(cells) == {8, 32}
    assert cells[8]["tail_share"] == pytest.approx(1 / 3) and cells[8]["worst_max_m"] == pytest.approx(9.0)
    assert cells[32]["tail_share"] == 0.0 and cells[32]["median_seed_mean_m"] == pytest.approx(0.05)
    assert "code_split" not in robustness.summarize([row(0, 0.05)])[0]


def test_another_code_split_reaches_the_worker_through_xla_flags():
    assert robustness.split_flags("", None) == ""
    assert robustness.split_flags("--xla_dump_to=/tmp/d", None) == "--xla_dump_to=/tmp/d"
    assert robustness.split_flags("", 32) == f"--{robustness.SPLIT_OPTION}=32"
    assert robustness.split_flags("--xla_dump_to=/tmp/d", 1) == f"--xla_dump_to=/tmp/d --{robustness.SPLIT_OPTION}=1"
