"""The output folder's files (jaxslam.app.outputs)."""

import numpy as np
import pytest

from jaxslam.app.outputs import replot, write_npz


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


def test_replot_redraws_every_figure_of_a_grid_run(tmp_path):
    """A grid folder's figures: map_trajectory.png and health.png (matplotlib) and
    map.png (the map image with the path, written with the map files); `jaxslam plot`
    redraws all three from arrays.npz, map.png with the same pixels."""
    from jaxslam.grid.export import save_map

    rng = np.random.default_rng(0)
    log_odds = np.zeros((120, 90), np.float32)
    log_odds[20:100, 10:80] = rng.normal(0.0, 2.0, (80, 70))
    t = np.linspace(0.0, 2.0 * np.pi, 50)
    trajectory = np.column_stack([1.0 + 0.8 * np.cos(t), 1.5 + 1.2 * np.sin(t), t])
    origin = np.array([-0.3, -0.2])
    save_map(tmp_path, log_odds, 0.05, tuple(origin), name="map", trajectory=trajectory)
    written = (tmp_path / "map.png").read_bytes()
    write_npz(tmp_path / "arrays.npz", kind="laser", times=t, trajectory=trajectory, log_odds=log_odds,
              resolution=0.05, origin=origin, ess=np.full(50, 3.0), resampled=np.zeros(50, bool), particles=4,
              title="srupf-gm, test, 4 particles")
    (tmp_path / "map.png").unlink()
    assert sorted(path.name for path in replot(tmp_path)) == ["health.png", "map.png", "map_trajectory.png"]
    assert (tmp_path / "map.png").read_bytes() == written
