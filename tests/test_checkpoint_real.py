"""Checkpoint/resume and determinism on real data: ERB-UPF on the first 1500 scans of
Victoria Park. An interrupted-and-resumed run equals the uninterrupted one bit for bit
(trajectory, every Info array, every particle's pose, weight and map); the same seed
gives the same run, another seed another one."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.runtime.checkpoint import Checkpoint, CheckpointError
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.feature.experiment import LandmarkSlamResult, run_landmark_slam

STEPS = 1500
EVERY = 250  # also the chunk length, so every run shares one compiled chunk
INTERRUPT_AT = 750


class Interrupted(Exception):
    """Stands for a crash (or a kill) in the middle of a run."""


@pytest.fixture(scope="module")
def sequence():
    from jaxslam.datasets import victoria_park

    try:
        return victoria_park.load_sequence(max_steps=STEPS)
    except DatasetNotFoundError as err:
        pytest.skip(str(err))


def _run(sequence, seed=0, **kwargs) -> LandmarkSlamResult:
    return run_landmark_slam(sequence, "erb", particles=10, seed=seed, progress=False, chunk=EVERY, **kwargs)


def _fingerprint(seed: int) -> dict:
    return {"algorithm": "erb", "dataset": "victoria-park", "particles": 10, "seed": seed, "steps": STEPS}


def _arrays(result: LandmarkSlamResult) -> dict[str, np.ndarray]:
    """Everything a run produces, by name."""
    arrays = {
        "trajectory": result.trajectory,
        "pose_covs": result.pose_covs,
        "landmark_means": result.landmark_means,
        "landmark_covs": result.landmark_covs,
    }
    arrays.update({f"info.{name}": value for name, value in result.info.items()})
    state = result.state
    arrays.update({f"state.{name}": np.asarray(getattr(state, name)) for name in ("poses", "pose_sqrt_covs",
                                                                                  "log_weights")})
    arrays.update({f"state.landmarks.{name}": np.asarray(value) for name, value in state.landmarks._asdict().items()})
    return arrays


def _assert_bitwise_equal(a: LandmarkSlamResult, b: LandmarkSlamResult) -> None:
    left, right = _arrays(a), _arrays(b)
    assert left.keys() == right.keys()
    for name in left:
        x, y = np.asarray(left[name]), np.asarray(right[name])
        assert x.shape == y.shape and x.dtype == y.dtype, name
        assert x.tobytes() == y.tobytes(), f"{name} differs"


@pytest.fixture(scope="module")
def uninterrupted(sequence):
    return _run(sequence)


@pytest.mark.long
def test_interrupted_and_resumed_run_equals_uninterrupted_bit_for_bit(sequence, uninterrupted, tmp_path):
    path = tmp_path / "erb.ckpt.npz"

    def crash(_carry, done):
        if done >= INTERRUPT_AT:
            raise Interrupted

    with pytest.raises(Interrupted):
        _run(sequence, checkpoint=Checkpoint(path, every=EVERY, fingerprint=_fingerprint(0)), callback=crash)
    assert path.exists() and not path.with_name(path.name + ".tmp").exists()

    progress = []
    resumed = _run(sequence, checkpoint=Checkpoint(path, every=EVERY, fingerprint=_fingerprint(0), resume=True),
                   callback=lambda _carry, done: progress.append(done))
    assert progress == list(range(INTERRUPT_AT + EVERY, STEPS + 1, EVERY))  # it did continue from the checkpoint
    assert resumed.steps == STEPS and resumed.trajectory.shape == (STEPS, 3)
    _assert_bitwise_equal(resumed, uninterrupted)

    # the checkpoint of this run is refused by a run with another seed
    with pytest.raises(CheckpointError, match="seed"):
        _run(sequence, seed=1, checkpoint=Checkpoint(path, fingerprint=_fingerprint(1), resume=True))


def test_same_seed_same_run_other_seed_other_run(sequence, uninterrupted):
    _assert_bitwise_equal(_run(sequence, seed=0), uninterrupted)
    other = _run(sequence, seed=1)
    assert not np.array_equal(other.trajectory, uninterrupted.trajectory)
    assert np.all(np.isfinite(other.trajectory))
