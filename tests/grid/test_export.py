"""Map export: ROS map_server PGM + YAML, and PNG, read back by independent readers:
Pillow for the PNG and the PGM pixels, a few lines of NumPy for the PGM header as the
netpbm specification defines it (https://netpbm.sourceforge.net/doc/pgm.html)."""

import io
import re

import numpy as np
from PIL import Image

from jaxslam.grid.export import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    occupancy_image,
    read_pgm,
    save_map,
)


def test_occupancy_image_thresholds_and_orientation():
    log_odds = np.array([[3.0, -3.0, 0.0], [0.0, 0.0, 0.0]])  # row 0 = bottom (smallest y)
    img = occupancy_image(log_odds)
    assert img.dtype == np.uint8
    # flipped: the bottom grid row is the last image row
    np.testing.assert_array_equal(img[-1], [OCCUPIED, FREE, UNKNOWN])
    np.testing.assert_array_equal(img[0], [UNKNOWN] * 3)
    # map_server (negate 0): occupancy = (255 - v) / 255
    assert (255 - OCCUPIED) / 255 > 0.65 and (255 - FREE) / 255 < 0.196
    assert 0.196 <= (255 - UNKNOWN) / 255 <= 0.65


def _png_pixels(data: bytes) -> np.ndarray:
    """Decode a PNG with Pillow to uint8 grey (when R = G = B) or RGB; alpha must be 255."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(io.BytesIO(data)) as image:
        assert image.format == "PNG"
        rgba = np.asarray(image.convert("RGBA"))
    assert np.all(rgba[..., 3] == 255)
    rgb = rgba[..., :3]
    if np.all(rgb[..., 0] == rgb[..., 1]) and np.all(rgb[..., 1] == rgb[..., 2]):
        return rgb[..., 0]
    return rgb


# netpbm PGM: "P5", whitespace, width, whitespace, height, whitespace, maxval (ASCII
# decimals; a '#' starts a comment to the end of the line), then exactly one
# whitespace character and the raster, one byte per sample when maxval < 256.
_SEP = rb"(?:\s|#[^\r\n]*[\r\n])+"
_PGM_HEADER = re.compile(rb"P5" + _SEP + rb"(\d+)" + _SEP + rb"(\d+)" + _SEP + rb"(\d+)\s")


def _pgm_by_spec(data: bytes) -> np.ndarray:
    header = _PGM_HEADER.match(data)
    assert header is not None, data[:40]
    width, height, maxval = (int(group) for group in header.groups())
    assert 0 < maxval < 256
    assert len(data) == header.end() + width * height  # nothing after the raster
    return np.frombuffer(data, np.uint8, count=width * height, offset=header.end()).reshape(height, width)


def test_pgm_header_parser_follows_the_spec():
    raster = np.arange(6, dtype=np.uint8).reshape(2, 3)
    for header in (b"P5 3 2 255\n", b"P5\n# a comment\n3\t2\r\n# another\n255 ", b"P5\n3\n2\n15\n"):
        np.testing.assert_array_equal(_pgm_by_spec(header + raster.tobytes()), raster)
    assert _PGM_HEADER.match(b"P2 3 2 255\n0 1 2 3 4 5\n") is None  # plain (ASCII) PGM: another format
    assert _PGM_HEADER.match(b"P5 3 2 255") is None  # maxval must be followed by one whitespace
    assert _PGM_HEADER.match(b"P5 3 # no newline ends this comment") is None


def test_save_map_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    log_odds = rng.normal(0, 2, (7, 11))
    paths = save_map(tmp_path / "out", log_odds, 0.05, (-1.25, 3.5))
    data = paths["pgm"].read_bytes()
    pgm = _pgm_by_spec(data)
    np.testing.assert_array_equal(pgm, occupancy_image(log_odds))
    with Image.open(paths["pgm"]) as image:
        assert image.format == "PPM" and image.mode == "L" and image.size == (11, 7)
        np.testing.assert_array_equal(np.asarray(image), pgm)
    np.testing.assert_array_equal(read_pgm(paths["pgm"]), pgm)  # our own reader agrees
    yaml = paths["yaml"].read_text()
    assert "image: map.pgm" in yaml
    assert "resolution: 0.050000" in yaml
    assert "origin: [-1.250000, 3.500000, 0.000000]" in yaml
    assert "negate: 0" in yaml and "occupied_thresh: 0.65" in yaml and "free_thresh: 0.196" in yaml
    png = _png_pixels(paths["png"].read_bytes())
    np.testing.assert_array_equal(png, pgm)


def test_png_with_trajectory(tmp_path):
    log_odds = np.zeros((10, 10))
    traj = np.array([[0.02, 0.02, 0.0], [0.42, 0.42, 0.0]])
    paths = save_map(tmp_path, log_odds, 0.05, (0.0, 0.0), trajectory=traj)
    rgb = _png_pixels(paths["png"].read_bytes())
    assert rgb.shape == (10, 10, 3)
    assert tuple(rgb[9, 0]) == (220, 30, 30)  # (0.02, 0.02) is the bottom-left cell
    assert tuple(rgb[1, 8]) == (220, 30, 30)


def _image_by_formula(log_odds, occupied=0.65, free=0.196):
    p = 1.0 / (1.0 + np.exp(-np.asarray(log_odds, np.float64)))
    img = np.full(p.shape, UNKNOWN, np.uint8)
    img[p > occupied] = OCCUPIED
    img[p < free] = FREE
    return img[::-1]


def test_occupancy_image_equals_the_probability_formula_at_the_thresholds():
    import math

    rng = np.random.default_rng(1)
    occ, free = math.log(0.65 / 0.35), math.log(0.196 / 0.804)
    special = [occ, free, np.nextafter(occ, 0), np.nextafter(occ, 9), np.nextafter(free, -9),
               np.nextafter(free, 0), np.inf, -np.inf, np.nan, 800.0, -800.0, 0.0]
    for dtype in (np.float32, np.float64):
        values = np.concatenate([rng.normal(0, 2, 400), np.array(special),
                                 occ + rng.normal(0, 1e-7, 50), free + rng.normal(0, 1e-7, 50)])
        grid = values.astype(dtype).reshape(-1, 8) if values.size % 8 == 0 else values[:512].astype(dtype).reshape(64, 8)
        with np.errstate(over="ignore", invalid="ignore"):
            np.testing.assert_array_equal(occupancy_image(grid), _image_by_formula(grid))
            np.testing.assert_array_equal(occupancy_image(grid, 0.8, 0.3), _image_by_formula(grid, 0.8, 0.3))


def test_png_pixels_equal_matplotlib_imsave(tmp_path):
    from matplotlib.image import imsave

    from jaxslam.grid.export import write_png

    rng = np.random.default_rng(2)
    # the map's palette (occupied, unknown, free) and any RGB: the same pixels as imsave
    palette = rng.choice(np.array([OCCUPIED, UNKNOWN, FREE], np.uint8), (37, 53))
    rgb = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    for name, image, kwargs in (("grey", palette, {"cmap": "gray", "vmin": 0, "vmax": 255}), ("rgb", rgb, {})):
        write_png(tmp_path / f"{name}.png", image)
        imsave(tmp_path / f"{name}_mpl.png", image, format="png", **kwargs)
        ours = _png_pixels((tmp_path / f"{name}.png").read_bytes())
        theirs = _png_pixels((tmp_path / f"{name}_mpl.png").read_bytes())
        np.testing.assert_array_equal(ours, theirs)
        np.testing.assert_array_equal(ours, image)
    # any grey value is written exactly (imsave's 256-entry grey colormap is off by one
    # for about 10 % of the values, never for the palette above)
    grey = np.arange(256, dtype=np.uint8).reshape(16, 16)
    write_png(tmp_path / "all.png", grey)
    np.testing.assert_array_equal(_png_pixels((tmp_path / "all.png").read_bytes()), grey)
