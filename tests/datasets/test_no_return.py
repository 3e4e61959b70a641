"""The "no return" sentinel detector of the CARMEN reader (detect_no_return)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.datasets import carmen
from jaxslam.datasets.carmen import detect_no_return, load_carmen
from jaxslam.datasets.registry import load_dataset_log
from jaxslam.datasets.paths import DatasetNotFoundError

BEAMS = 180
ANGLES = np.radians(np.arange(BEAMS) - 90.0)


def _room_ranges(rng, scans: int, half_width: float, length: float, speed: float = 0.2) -> np.ndarray:
    """A robot driving along the middle of a long hall: exact ranges to its walls."""
    ranges = np.empty((scans, BEAMS))
    for index in range(scans):
        x = (index * speed) % (0.8 * length)
        c, s = np.cos(ANGLES), np.sin(ANGLES)
        with np.errstate(divide="ignore"):
            to_side = np.where(np.abs(s) > 1e-9, half_width / np.abs(s), np.inf)
            to_end = np.where(c > 1e-9, (length - x) / c, np.where(c < -1e-9, x / -c, np.inf))
        ranges[index] = np.minimum(to_side, to_end) + rng.normal(0.0, 0.01, BEAMS)
    return ranges


def _killian_like(rng, scans: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Real echoes up to 50 m (a 30 x 120 m hall) plus "no return" codes at 51.05-51.22 m
    where the hall is longer than the laser's 50 m range, as the MIT Killian log has."""
    ranges = _room_ranges(rng, scans, half_width=15.0, length=120.0)
    no_echo = ranges > 50.0
    codes = rng.choice([51.05, 51.06, 51.06, 51.06, 51.07, 51.11, 51.22], size=ranges.shape)
    return np.where(no_echo, codes, ranges), no_echo


def _write_flaser(path, ranges: np.ndarray) -> None:
    lines = [b"# synthetic, no PARAM lines\n"]
    for index, scan in enumerate(ranges):
        values = " ".join(f"{r:.2f}" for r in scan)
        x = 0.2 * index
        lines.append(f"FLASER {len(scan)} {values} {x} 0 0 {x} 0 0 {index * 0.1:.3f} host {index * 0.1:.3f}\n"
                     .encode())
    path.write_bytes(b"".join(lines))


def test_killian_like_log_is_detected_and_its_codes_never_hit(tmp_path):
    rng = np.random.default_rng(0)
    ranges, no_echo = _killian_like(rng)
    assert 0.01 < no_echo.mean() < 0.2
    path = tmp_path / "killian_like.clf"
    _write_flaser(path, ranges)
    log = load_carmen(path)
    assert log.no_return["detected"] and log.no_return["source"] == "detected"
    assert log.max_range == pytest.approx(51.05)
    np.testing.assert_array_equal(log.max_range_mask, no_echo)
    assert not np.any(log.valid & no_echo)
    assert log.valid.sum() == (~no_echo).sum()
    assert log.stats["no_return_sentinel_readings"] == no_echo.sum() == log.no_return["readings"]
    assert log.stats["max_range_readings"] == no_echo.sum()
    # an explicit limit wins and switches the detector off; so does detect_sentinel=False
    explicit = load_carmen(path, max_range=60.0)
    assert explicit.max_range == 60.0 and explicit.valid.sum() == ranges.size
    assert explicit.no_return == {"detected": False, "source": "max_range argument"}
    off = load_carmen(path, detect_sentinel=False)
    assert off.max_range == carmen.DEFAULT_FLASER_MAX_RANGE and not off.no_return["detected"]


def test_sentinel_alone_in_array_form():
    rng = np.random.default_rng(1)
    ranges, no_echo = _killian_like(rng, scans=300)
    found = detect_no_return(ranges, 80.0)
    assert found["detected"] and found["range_m"] == pytest.approx(51.05)
    assert found["beam_share"] > 0.1 and found["contrast"] > 100
    # per-scan limits: readings already at or above the limit are not looked at
    assert not detect_no_return(ranges, np.full(ranges.shape[0], 51.0))["detected"]


def test_walls_at_the_top_of_the_range_are_not_sentinels():
    rng = np.random.default_rng(2)
    # 1. A hall whose far end lies just inside the laser's range: the top of the
    # histogram is real echoes from a flat wall (d / cos spread), not a spike.
    hall = _room_ranges(rng, 400, half_width=10.0, length=49.5, speed=0.0)
    assert not detect_no_return(hall, 50.0)["detected"]
    moving = _room_ranges(rng, 400, half_width=10.0, length=49.5, speed=0.1)
    assert not detect_no_return(moving, 50.0)["detected"]
    # 2. A corridor 2 x 49.9 m wide seen only sideways: the side beam sees its wall
    # at a constant 49.9 m in every scan, the top of the observed range, a narrow
    # pile, but on a handful of beams only.
    corridor = np.full((2000, BEAMS), np.nan)
    corridor[:, 85:95] = rng.uniform(5.0, 40.0, size=(2000, 10))
    corridor[:, 88:91] = 49.9 + rng.normal(0.0, 0.01, size=(2000, 3))
    found = detect_no_return(corridor, 80.0)
    assert not found["detected"] and found["beam_share"] < 0.1 and found["contrast"] > 20
    # 3. Few readings: nothing to decide on.
    assert not detect_no_return(np.full((3, 4), 51.06), 80.0)["detected"]


def _real(name: str):
    try:
        return load_dataset_log(name)
    except DatasetNotFoundError as error:
        pytest.skip(str(error))


def test_real_logs_killian_orebro_detected_intel_not():
    killian = _real("mit-killian")
    assert killian.no_return["detected"] and killian.max_range == pytest.approx(51.05)
    assert 39_000 < killian.stats["no_return_sentinel_readings"] < 41_000
    # the codes (51.05-51.22 m) are never hits; the real echoes' tail (up to 51.01 m,
    # about 5 readings per cm like those below 51 m) stays
    assert np.all(killian.ranges[killian.valid] < 51.05)
    assert np.sum(killian.valid & (killian.ranges > 50.5)) > 50
    orebro = _real("orebro-corrected")
    assert orebro.no_return["detected"] and 32.7 <= orebro.max_range <= 32.76
    assert 900 < orebro.stats["no_return_sentinel_readings"] < 1000
    for name in ("intel", "fr079", "intel-corrected"):
        log = _real(name)
        assert not log.no_return["detected"], name
        assert "no_return_sentinel_readings" not in log.stats
        assert log.max_range >= 80.0


def test_a_path_gets_what_the_name_gets():
    by_name = _real("mit-killian")
    by_path = load_carmen(by_name.path)
    assert by_path.max_range == by_name.max_range
    np.testing.assert_array_equal(by_path.valid, by_name.valid)
    np.testing.assert_array_equal(by_path.max_range_mask, by_name.max_range_mask)


def test_cli_max_range_option(tmp_path):
    from jaxslam.app import cli, runs

    args = cli.build_parser().parse_args(["run", "--dataset", "x.clf", "--max-range", "50", "--out", str(tmp_path)])
    assert args.max_range == 50.0
    with pytest.raises(runs.RunError, match="CARMEN logs only"):
        runs.run(out=tmp_path, dataset=None, algorithm="srupf-gm", max_range=50.0)
    with pytest.raises(runs.RunError, match="positive"):
        path = tmp_path / "log.clf"
        path.write_text("FLASER 1 1.0 0 0 0 0 0 0 1 h 1\n")
        runs.run(out=tmp_path / "out", dataset=str(path), algorithm="srupf-gm", max_range=-1.0)
