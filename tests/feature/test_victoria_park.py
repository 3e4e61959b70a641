"""ERB/RB on the first scans of Victoria Park (real data; skipped without the dataset)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.feature.experiment import run_landmark_slam
from jaxslam.metrics.gps import gps_error


@pytest.fixture(scope="module")
def sequence():
    from jaxslam.datasets import victoria_park

    try:
        return victoria_park.load_sequence("detections", max_range=30.0, max_steps=800)
    except DatasetNotFoundError as err:
        pytest.skip(str(err))


def test_erb_on_victoria_park_start(sequence):
    res = run_landmark_slam(sequence, "erb-upf", particles=10, seed=0, progress=False, config=dict(capacity=256))
    err = gps_error(res.times, res.trajectory, sequence.gps_times, sequence.gps_xy)
    assert err["gps_mean_m"] < 3.0
    assert 20 < res.landmarks < 256
    info = res.info
    ok = np.isfinite(info["log_det_proposal_erb"])
    assert ok.sum() > 500
    # The paper's Fig. 1 claim on the same particles (float32 rounding allowed).
    assert np.all(info["log_det_proposal_erb"][ok] - info["log_det_proposal_rb"][ok] >= -1e-4)
    assert info["num_dropped"].sum() == 0
