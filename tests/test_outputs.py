"""The output folder's files (jaxslam.app.outputs)."""

import numpy as np
import pytest

from jaxslam.app.outputs import write_npz


def test_write_npz_reads_back_with_np_load(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {
        "log_odds": rng.normal(0.0, 2.0, (37, 23)).astype(np.float32),
        "trajectory": rng.normal(size=(50, 3)),
        "resampled": rng.random(50) < 0.3,
        "particles": 30,
        "kind": "laser",
        "title": "srupf-gm, intel, 30 particles",
        "empty": np.zeros((0, 2)),
    }
    write_npz(tmp_path / "arrays.npz", **arrays)
    with np.load(tmp_path / "arrays.npz", allow_pickle=False) as data:
        assert sorted(data.files) == sorted(arrays)
        for name, value in arrays.items():
            np.testing.assert_array_equal(data[name], np.asarray(value))
            assert data[name].dtype == np.asarray(value).dtype
        assert str(data["kind"]) == "laser"


def test_write_npz_leaves_no_file_when_an_array_cannot_be_written(tmp_path):
    path = tmp_path / "arrays.npz"
    path.write_bytes(b"previous")
    with pytest.raises(ValueError):
        write_npz(path, fine=np.arange(3), objects=np.array([{"a": 1}], dtype=object))
    assert path.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arrays.npz"]
