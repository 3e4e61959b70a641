"""benchmarks/diagnostics/loop_drift.py: the drift of scan b relative to scan a, against the reference."""

from __future__ import annotations

import numpy as np
import pytest

from . import load_benchmark

loop_drift = load_benchmark("diagnostics/loop_drift")


def test_drift_of_a_rotated_and_shifted_run():
    """The reference goes 10 m along x and comes back to the start, turned by pi. The
    run ends 1 m left of where it started (y = 1) and turned 10 deg too far: relative
    to scan 0 that is 1 m off and 10 deg. A run offset and rotated as a whole has no
    drift."""
    reference = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, np.pi / 2], [0.0, 0.0, np.pi]])
    run = reference.copy()
    run[2] = [0.0, 1.0, np.pi + np.radians(10.0)]
    metres, degrees = loop_drift.drift(run, reference, 0, 2)
    assert metres == pytest.approx(1.0, abs=1e-9)
    assert degrees == pytest.approx(10.0, abs=1e-9)
    c, s = np.cos(0.3), np.sin(0.3)
    moved = np.stack([c * reference[:, 0] - s * reference[:, 1] + 5.0,
                      s * reference[:, 0] + c * reference[:, 1] - 2.0, reference[:, 2] + 0.3], -1)
    metres, degrees = loop_drift.drift(moved, reference, 0, 2)
    assert metres == pytest.approx(0.0, abs=1e-9)
    assert degrees == pytest.approx(0.0, abs=1e-9)


def test_pair_beyond_the_run_is_refused():
    with pytest.raises(ValueError, match="beyond the run"):
        loop_drift.drift(np.zeros((3, 3)), np.zeros((5, 3)), 0, 4)
