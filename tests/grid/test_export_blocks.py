"""Big maps are exported and drawn block by block: the blocks must not show.

Each function is compared with the plain whole-array formula on maps whose size is
not a multiple of the block, with the block size made small so that many blocks
and a ragged last one occur.
"""

import io
import math

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.image import imread  # noqa: E402

from jaxslam.app import plotting  # noqa: E402
from jaxslam.grid import export  # noqa: E402


def _reference_image(log_odds, occupied=0.65, free=0.196):
    p = 1.0 / (1.0 + np.exp(-np.asarray(log_odds, np.float64)))
    img = np.full(p.shape, export.UNKNOWN, np.uint8)
    img[p > occupied] = export.OCCUPIED
    img[p < free] = export.FREE
    return img[::-1]


@pytest.mark.parametrize("block_cells", [7, 64, 1 << 22])
def test_occupancy_image_blocks_equal_the_formula(monkeypatch, block_cells):
    rng = np.random.default_rng(0)
    log_odds = rng.normal(0.0, 2.0, (37, 23)).astype(np.float32)
    log_odds.flat[:5] = np.float32(math.log(0.65 / 0.35))  # on the thresholds
    log_odds.flat[5:10] = np.float32(math.log(0.196 / 0.804))
    monkeypatch.setattr(export, "_BLOCK_CELLS", block_cells)
    np.testing.assert_array_equal(export.occupancy_image(log_odds), _reference_image(log_odds))


def test_png_marks_equal_an_rgb_image(tmp_path):
    rng = np.random.default_rng(1)
    grey = rng.integers(0, 256, (301, 517)).astype(np.uint8)
    rows = rng.integers(0, 301, 400)
    cols = rng.integers(0, 517, 400)
    rgb = np.repeat(grey[..., None], 3, -1)
    rgb[rows, cols] = (220, 30, 30)
    export.write_png(tmp_path / "a.png", grey, marks=(rows, cols))
    export.write_png(tmp_path / "b.png", rgb)
    a = imread(io.BytesIO((tmp_path / "a.png").read_bytes()), format="png")
    b = imread(io.BytesIO((tmp_path / "b.png").read_bytes()), format="png")
    np.testing.assert_array_equal(np.round(a * 255).astype(np.uint8)[..., :3], rgb)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("shape", [(100, 160), (2500, 4300), (4301, 900)])
def test_figure_block_means_equal_the_formula(shape):
    rng = np.random.default_rng(2)
    log_odds = np.zeros(shape, np.float32)
    log_odds[30:-25, 21:-17] = rng.normal(0.0, 2.0, (shape[0] - 55, shape[1] - 38))
    fig = plotting.plot_grid_map(log_odds, 0.05, (1.0, -2.0))
    shown = fig.axes[0].images[0]
    # Reference: crop to the observed cells + 1 m (20 cells), k x k block means of
    # 1 - p(occupied) over an edge-padded map.
    r0, r1, c0, c1 = 30 - 20, shape[0] - 25 + 20, 21 - 20, shape[1] - 17 + 20
    crop = log_odds[r0:r1, c0:c1].astype(np.float64)
    h, w = crop.shape
    k = max(1, -(-max(h, w) // 2048))
    hk, wk = -(-h // k) * k, -(-w // k) * k
    free = np.pad(1.0 / (1.0 + np.exp(crop)), ((0, hk - h), (0, wk - w)), mode="edge")
    expected = free.reshape(hk // k, k, wk // k, k).mean(axis=(1, 3))
    np.testing.assert_allclose(np.asarray(shown.get_array()), expected, atol=1e-6)
    x0, y0 = 1.0 + c0 * 0.05, -2.0 + r0 * 0.05
    np.testing.assert_allclose(shown.get_extent(), [x0, x0 + wk * 0.05, y0, y0 + hk * 0.05])
    matplotlib.pyplot.close(fig)
