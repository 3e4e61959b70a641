"""Saved maps read back: the lossless map.npz and the ROS map_server convention."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError
from jaxslam.grid.export import save_map, write_pgm
from jaxslam.grid.map_server import parse_map_yaml, read_pgm_image
from jaxslam.grid.mapfile import load_map, save_map_npz


def _map_server_value(pixel, has_alpha, mode, negate, occ_th, free_th):
    """map_server's loadMapFromFile for one pixel, written out as the C++ does it."""
    n = len(pixel)
    avg_channels = n if (mode == "trinary" or not has_alpha) else n - 1
    color_avg = sum(pixel[:avg_channels]) / float(avg_channels)
    alpha = 1 if n == 1 else pixel[n - 1]
    if negate:
        color_avg = 255 - color_avg
    if mode == "raw":
        value = int(color_avg) & 0xFF
        return value - 256 if value > 127 else value
    occ = (255 - color_avg) / 255.0
    if occ > occ_th:
        return 100
    if occ < free_th:
        return 0
    if mode == "trinary" or alpha < 1.0:
        return -1
    return int(1 + 98 * (occ - free_th) / (occ_th - free_th))


def _yaml(path, image, resolution=0.05, origin=(0.0, 0.0, 0.0), negate=0, occ=0.65, free=0.196, mode=None):
    text = (f"image: {image}\nresolution: {resolution}\norigin: [{origin[0]}, {origin[1]}, {origin[2]}]\n"
            f"negate: {negate}\noccupied_thresh: {occ}\nfree_thresh: {free}\n")
    if mode is not None:
        text += f"mode: {mode}\n"
    path.write_text(text)
    return path


def _log_odds(seed, shape=(37, 53), unit=0.05):
    rng = np.random.default_rng(seed)
    cells = rng.integers(-100, 101, shape).astype(np.int8)
    cells[:, :3] = -100  # some free space for certain
    return cells, cells.astype(np.float32) * np.float32(unit)


def test_map_npz_reads_back_bit_for_bit(tmp_path):
    cells, log_odds = _log_odds(0)
    save_map_npz(tmp_path / "map.npz", log_odds, 0.05, (-3.25, 7.5), log_odds_unit=0.05, tile=32)
    loaded = load_map(tmp_path / "map.npz")
    assert loaded.log_odds.dtype == np.float32
    np.testing.assert_array_equal(loaded.log_odds, log_odds)
    np.testing.assert_array_equal(loaded.cells, cells)
    assert loaded.log_odds_unit == 0.05 and loaded.tile == 32
    assert loaded.resolution == 0.05 and loaded.origin == (-3.25, 7.5, 0.0)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([np.float32, np.float64]))
def test_map_npz_keeps_arbitrary_log_odds_bit_for_bit(tmp_path_factory, seed, dtype):
    rng = np.random.default_rng(seed)
    log_odds = (rng.normal(0, 3, (9, 14)) * rng.integers(0, 2, (9, 14))).astype(dtype)
    log_odds[0, 0] = -5.0
    path = tmp_path_factory.mktemp("npz") / "m.npz"
    save_map_npz(path, log_odds, 0.1, (1.0, 2.0, 0.3), log_odds_unit=0.05)
    loaded = load_map(path)
    assert loaded.log_odds.dtype == dtype
    np.testing.assert_array_equal(loaded.log_odds, log_odds)
    assert loaded.origin == (1.0, 2.0, 0.3)


def test_npz_and_pgm_yaml_of_one_map_agree(tmp_path):
    _, log_odds = _log_odds(1)
    save_map(tmp_path, log_odds, 0.05, (2.0, -1.0))
    save_map_npz(tmp_path / "map.npz", log_odds, 0.05, (2.0, -1.0), log_odds_unit=0.05)
    from_npz = load_map(tmp_path)  # the folder: map.npz first
    from_yaml = load_map(tmp_path / "map.yaml")
    assert from_npz.source.name == "map.npz" and from_yaml.log_odds is None
    np.testing.assert_array_equal(from_npz.occupancy, from_yaml.occupancy)
    assert from_yaml.origin == (2.0, -1.0, 0.0) and from_yaml.resolution == 0.05
    # p > 0.65 occupied, p < 0.196 free, row 0 at the origin (the image is upside down)
    p = 1 / (1 + np.exp(-log_odds.astype(np.float64)))
    expected = np.where(p > 0.65, 100, np.where(p < 0.196, 0, -1))
    np.testing.assert_array_equal(from_yaml.occupancy, expected)


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("negate", [0, 1])
def test_pgm_yaml_follows_map_server(tmp_path, mode, negate):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (11, 17)).astype(np.uint8)
    image[0, :3] = 254, 0, 255  # a free cell in every mode
    write_pgm(tmp_path / "m.pgm", image)
    _yaml(tmp_path / "m.yaml", "m.pgm", 0.1, (-1.5, 2.25, 0.5), negate, 0.6, 0.25, mode)
    loaded = load_map(tmp_path / "m.yaml")
    expected = np.array([[_map_server_value([int(v)], False, mode, negate, 0.6, 0.25) for v in row]
                         for row in image[::-1]])
    np.testing.assert_array_equal(loaded.occupancy, expected)
    assert loaded.origin == (-1.5, 2.25, 0.5) and loaded.resolution == 0.1


@pytest.mark.parametrize("mode", ["trinary", "scale"])
def test_png_with_alpha_follows_map_server(tmp_path, mode):
    from PIL import Image

    rng = np.random.default_rng(4)
    rgba = rng.integers(0, 256, (6, 9, 4)).astype(np.uint8)
    rgba[..., 3] = rng.choice([0, 255], (6, 9))
    rgba[0, 0] = (254, 254, 254, 255)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "m.png")
    sub = tmp_path / "yaml"
    sub.mkdir()
    _yaml(sub / "m.yaml", "../m.png", mode=mode)  # relative to the YAML file's folder
    loaded = load_map(sub / "m.yaml")
    expected = np.array([[_map_server_value([int(c) for c in px], True, mode, 0, 0.65, 0.196) for px in row]
                         for row in rgba[::-1]])
    np.testing.assert_array_equal(loaded.occupancy, expected)


def test_plain_and_16_bit_pgm(tmp_path):
    image = np.array([[0, 128, 255], [254, 205, 1]], np.uint8)
    (tmp_path / "p2.pgm").write_text("P2\n# comment\n3 2\n255\n" + " ".join(map(str, image.ravel())) + "\n")
    np.testing.assert_array_equal(read_pgm_image(tmp_path / "p2.pgm"), image)
    wide = (image.astype(">u2") * 257)
    (tmp_path / "p5.pgm").write_bytes(b"P5\n3 2\n65535\n" + wide.tobytes())
    np.testing.assert_array_equal(read_pgm_image(tmp_path / "p5.pgm"), image)


def test_cell_centres_follow_the_origin_yaw(tmp_path):
    save_map_npz(tmp_path / "m.npz", np.full((4, 5), -3.0, np.float32), 0.5, (1.0, 2.0, math.pi / 2))
    grid = load_map(tmp_path / "m.npz")
    np.testing.assert_allclose(grid.cell_centres(np.array(0), np.array(1)), [1.0 - 0.25, 2.0 + 0.75])


def test_yaml_subset_parser(tmp_path):
    (tmp_path / "m.yaml").write_text("---\nimage: 'my map.pgm'  # quoted\nresolution: 5e-2\n"
                                     "origin: [ -1, 2.5 ,0 ]\nnegate: 0\nmode: scale\n")
    values, lines = parse_map_yaml(tmp_path / "m.yaml")
    assert values == {"image": "my map.pgm", "resolution": 0.05, "origin": [-1, 2.5, 0], "negate": 0,
                      "mode": "scale"}
    assert lines["origin"] == 4


def _good(tmp_path):
    write_pgm(tmp_path / "m.pgm", np.full((4, 4), 254, np.uint8))
    return tmp_path / "m.yaml"


@pytest.mark.parametrize(
    "edit, message",
    [
        ({"image": "missing.pgm"}, "does not exist"),
        ({"resolution": 0}, "resolution must be a positive"),
        ({"resolution": -0.05}, "resolution must be a positive"),
        ({"origin": "[1, 2]"}, "origin must be [x, y, yaw]"),
        ({"free_thresh": 0.9}, "must be below occupied_thresh"),
        ({"mode": "fancy"}, "mode must be one of"),
        ({"negate": 3}, "negate must be 0 or 1"),
        ({"resolution": "fine"}, "resolution must be a number"),
    ],
)
def test_bad_yaml_maps_get_one_line_errors(tmp_path, edit, message):
    fields = {"image": "m.pgm", "resolution": 0.05, "origin": "[0, 0, 0]", "negate": 0,
              "occupied_thresh": 0.65, "free_thresh": 0.196, **edit}
    path = _good(tmp_path)
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
    with pytest.raises(DataFormatError, match=re.escape(message)) as err:
        load_map(path)
    text = str(err.value)
    assert "\n" not in text and str(path) in text and ", line " in text


@pytest.mark.parametrize(
    "text, message",
    [
        ("image: m.pgm\n  nested: 1\n", "line 2: nested YAML"),
        ("image m.pgm\n", "line 1: expected 'key: value'"),
        ("image: m.pgm\nimage: n.pgm\n", "line 2: 'image' given twice"),
        ("image: m.pgm\nresolution: 0.05\n", "no 'origin'"),
        ("origin: [1, 2\n", "unterminated list"),
    ],
)
def test_malformed_yaml(tmp_path, text, message):
    path = _good(tmp_path)
    path.write_text(text)
    with pytest.raises(DataFormatError, match=message):
        load_map(path)


def test_maps_without_free_space_or_with_bad_images_are_refused(tmp_path):
    write_pgm(tmp_path / "dark.pgm", np.zeros((3, 3), np.uint8))
    _yaml(tmp_path / "dark.yaml", "dark.pgm")
    with pytest.raises(DataFormatError, match="no free cell"):
        load_map(tmp_path / "dark.yaml")
    save_map_npz(tmp_path / "unknown.npz", np.zeros((3, 3), np.float32), 0.05, (0, 0))
    with pytest.raises(DataFormatError, match="no free cell"):
        load_map(tmp_path / "unknown.npz")
    (tmp_path / "cut.pgm").write_bytes(b"P5\n10 10\n255\n" + bytes(20))
    _yaml(tmp_path / "cut.yaml", "cut.pgm")
    with pytest.raises(DataFormatError, match="truncated PGM"):
        load_map(tmp_path / "cut.yaml")
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    _yaml(tmp_path / "junk.yaml", "junk.png")
    with pytest.raises(DataFormatError, match="cannot read the map image"):
        load_map(tmp_path / "junk.yaml")
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(DataFormatError, match="cannot read the map"):
        load_map(tmp_path / "junk.npz")
    with pytest.raises(DatasetNotFoundError, match="does not exist"):
        load_map(tmp_path / "nothing.yaml")
    with pytest.raises(DatasetNotFoundError, match="no map.npz or map.yaml"):
        load_map(tmp_path)

