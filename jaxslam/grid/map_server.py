r"""ROS ``map_server`` maps: a YAML file and its image (PGM read here, other formats
through Pillow, which matplotlib depends on), interpreted as ``map_server``'s
``loadMapFromFile`` does:

- ``image``: path of the image, relative to the YAML file's folder unless absolute;
- ``resolution``: metres per pixel; ``origin``: ``[x, y, yaw]`` pose of the
  lower-left pixel (yaw counter-clockwise);
- each pixel's value ``c`` is the mean of its colour channels (alpha included in
  ``trinary`` mode or when the image has no alpha channel, left out otherwise);
  ``negate: 1`` takes ``255 - c``; then ``occ = (255 - c) / 255``;
- ``mode: trinary`` (the default): ``occ > occupied_thresh`` is occupied (100),
  ``occ < free_thresh`` free (0), everything else unknown (-1);
- ``mode: scale``: as trinary at both ends; in between ``1 + 98 r`` truncated,
  ``r = (occ - free_thresh) / (occupied_thresh - free_thresh)``, or unknown where
  the pixel's alpha is 0;
- ``mode: raw``: the value ``c`` itself (truncated), stored as the ``int8`` of an
  OccupancyGrid (so 255 reads as -1, unknown);
- the image's first row is the top of the map (largest y), flipped here so that
  row 0 is at the origin, as jaxslam's grids are.

``image``, ``resolution``, ``origin``, ``occupied_thresh`` and ``free_thresh`` are
required (``map_server`` refuses a file without them); ``negate`` defaults to 0 and
``mode`` to ``trinary``. The YAML read is the flat ``key: value`` subset map files
use (numbers, plain or quoted strings, flow lists ``[a, b, c]``, ``#`` comments), so
PyYAML is not needed.

A module apart from :mod:`jaxslam.grid.mapfile` (jaxslam's own ``map.npz``, and
:func:`~jaxslam.grid.mapfile.load_map`, which reads either): this is ROS's file
convention, parsed here line by line. Host-side NumPy. Every problem with a file is a
:class:`~jaxslam.datasets.paths.DataFormatError` (file, line where there is one,
problem).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from jaxslam.datasets.paths import DataFormatError

# The values of a ROS OccupancyGrid cell.
OCCUPIED_VALUE, FREE_VALUE, UNKNOWN_VALUE = 100, 0, -1
MODES = ("trinary", "scale", "raw")
_REQUIRED = ("image", "resolution", "origin", "occupied_thresh", "free_thresh")


_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _scalar(text: str):
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    if _NUMBER.match(text):
        return float(text) if any(ch in text for ch in ".eE") else int(text)
    if text.lower() in ("true", "yes", "on"):
        return True
    if text.lower() in ("false", "no", "off"):
        return False
    return text


def _strip_comment(line: str) -> str:
    quote = None
    for i, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i]
    return line


def parse_map_yaml(path: os.PathLike | str) -> tuple[dict, dict]:
    """The keys of a ``map_server`` YAML file and the line each was on.

    Reads the flat subset map files use: ``key: value`` lines with numbers, plain or
    quoted strings, flow lists ``[a, b, c]`` and ``#`` comments; a ``---`` document
    start is skipped. Anything else is a :class:`~jaxslam.datasets.paths.DataFormatError` naming the line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DataFormatError(path, None, "not a text file (a map YAML is expected)") from None
    values: dict = {}
    lines: dict = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = _strip_comment(raw).rstrip()
        if not line.strip() or line.strip() in ("---", "..."):
            continue
        if line[0].isspace():
            raise DataFormatError(path, number, f"nested YAML is not part of a map file: {raw.strip()!r}")
        key, sep, value = line.partition(":")
        if not sep or not key.strip() or " " in key.strip():
            raise DataFormatError(path, number, f"expected 'key: value', got {raw.strip()!r}")
        key, value = key.strip(), value.strip()
        if key in values:
            raise DataFormatError(path, number, f"{key!r} given twice (first on line {lines[key]})")
        if value.startswith("["):
            if not value.endswith("]"):
                raise DataFormatError(path, number, f"{key}: unterminated list {value!r}")
            inner = value[1:-1].strip()
            parsed = [_scalar(item) for item in inner.split(",")] if inner else []
        elif value.startswith("{") or value in ("|", ">"):
            raise DataFormatError(path, number, f"{key}: only numbers, strings and [lists] are read here")
        else:
            parsed = _scalar(value)
        values[key], lines[key] = parsed, number
    return values, lines


def _number(path, line, key, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataFormatError(path, line, f"{key} must be a number, got {value!r}")
    return float(value)


def check_resolution(path, line, value) -> float:
    resolution = _number(path, line, "resolution", value.item() if isinstance(value, np.ndarray) else value)
    if not (math.isfinite(resolution) and resolution > 0):
        raise DataFormatError(path, line, f"resolution must be a positive number of metres per cell, got {resolution}")
    return resolution


def check_origin(path, line, value) -> tuple[float, float, float]:
    items = list(np.asarray(value).tolist()) if isinstance(value, np.ndarray) else value
    if not isinstance(items, list) or len(items) != 3:
        raise DataFormatError(path, line, f"origin must be [x, y, yaw], got {value!r}")
    origin = tuple(_number(path, line, "origin", v) for v in items)
    if not all(math.isfinite(v) for v in origin):
        raise DataFormatError(path, line, f"origin must be finite, got {list(origin)}")
    return origin


def check_thresholds(path, line, occupied: float, free: float) -> None:
    if not (0.0 <= free <= 1.0 and 0.0 <= occupied <= 1.0):
        raise DataFormatError(path, line, f"occupied_thresh and free_thresh must lie in [0, 1], got "
                                          f"{occupied} and {free}")
    if not free < occupied:
        raise DataFormatError(path, line, f"free_thresh ({free}) must be below occupied_thresh ({occupied})")


def read_pgm_image(path: os.PathLike | str) -> np.ndarray:
    """A PGM image (binary P5 or plain P2, maxval up to 65535) as ``uint8`` ``(H, W)``.

    Values with a maxval other than 255 are scaled to ``0 .. 255`` (rounded), as an
    8-bit image loader does.
    """
    path = Path(path)
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if pos >= len(data):
            raise DataFormatError(path, None, "truncated PGM header")
        if data[pos : pos + 1] == b"#":
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        end = pos
        while end < len(data) and not data[end : end + 1].isspace():
            end += 1
        tokens.append(data[pos:end])
        pos = end
        if tokens[0] not in (b"P5", b"P2"):
            raise DataFormatError(path, None, f"not a greyscale PGM (magic {tokens[0][:8]!r}, expected P5 or P2)")
    try:
        width, height, maxval = (int(t) for t in tokens[1:4])
    except ValueError:
        raise DataFormatError(path, None, f"bad PGM header {b' '.join(tokens).decode('latin-1')!r}") from None
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise DataFormatError(path, None, f"bad PGM size {width} x {height} or maxval {maxval}")
    count = width * height
    if tokens[0] == b"P5":
        pos += 1  # the single whitespace after maxval
        dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
        need = count * dtype.itemsize
        if len(data) - pos < need:
            raise DataFormatError(path, None, f"truncated PGM: {len(data) - pos} bytes of pixels, expected {need}")
        pixels = np.frombuffer(data, dtype, count, pos).astype(np.int64)
    else:
        try:
            pixels = np.array(data[pos:].split(), np.int64)
        except ValueError:
            raise DataFormatError(path, None, "plain PGM pixels must be integers") from None
        if pixels.size < count:
            raise DataFormatError(path, None, f"truncated PGM: {pixels.size} pixels, expected {count}")
        pixels = pixels[:count]
    if pixels.max(initial=0) > maxval:
        raise DataFormatError(path, None, f"PGM pixel above its maxval {maxval}")
    if maxval != 255:
        pixels = (pixels * 255 + maxval // 2) // maxval
    return pixels.astype(np.uint8).reshape(height, width)


def _read_image(path: Path) -> tuple[np.ndarray, bool]:
    """``(pixels (H, W, C) uint8, has_alpha)`` of a map image."""
    with open(path, "rb") as handle:
        magic = handle.read(2)
    if magic in (b"P5", b"P2"):
        return read_pgm_image(path)[..., None], False
    try:
        from PIL import Image, UnidentifiedImageError
    except ImportError:  # pragma: no cover - matplotlib depends on Pillow
        raise DataFormatError(path, None, "reading this image needs Pillow (pip install pillow)") from None
    try:
        with Image.open(path) as image:
            image.load()
            if image.mode in ("I;16", "I;16B", "I"):
                pixels = (np.asarray(image, np.int64) >> (8 if image.mode != "I" else 0)).clip(0, 255)
                return pixels.astype(np.uint8)[..., None], False
            if image.mode not in ("L", "LA", "RGB", "RGBA"):
                image = image.convert("RGBA" if "A" in image.mode or "transparency" in image.info else "RGB")
            pixels = np.asarray(image, np.uint8)
            has_alpha = image.mode in ("LA", "RGBA")
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as err:
        raise DataFormatError(path, None, f"cannot read the map image: {err}") from None
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    return pixels, has_alpha


def image_to_occupancy(pixels: np.ndarray, has_alpha: bool, mode: str, negate: bool,
                       occupied_thresh: float, free_thresh: float) -> np.ndarray:
    """``map_server``'s pixel rule: ``(H, W, C)`` uint8 image -> ``(H, W)`` int8 values,
    flipped so that row 0 is the image's bottom row."""
    channels = pixels.shape[2]
    averaged = channels if (mode == "trinary" or not has_alpha) else channels - 1
    color = pixels[..., :averaged].astype(np.float64).sum(-1) / averaged
    alpha = np.ones(color.shape) if channels == 1 else pixels[..., -1].astype(np.float64)
    if negate:
        color = 255.0 - color
    if mode == "raw":
        values = np.trunc(color).astype(np.uint8).view(np.int8)
    else:
        occ = (255.0 - color) / 255.0
        values = np.full(color.shape, UNKNOWN_VALUE, np.int8)
        if mode == "scale":
            ratio = (occ - free_thresh) / (occupied_thresh - free_thresh)
            scaled = np.trunc(1.0 + 98.0 * ratio).astype(np.int64)
            values = np.where(alpha < 1.0, UNKNOWN_VALUE, scaled).astype(np.int8)
        values[occ > occupied_thresh] = OCCUPIED_VALUE
        values[occ < free_thresh] = FREE_VALUE
    return np.ascontiguousarray(values[::-1])


def read_map_yaml(path: Path) -> dict:
    """The map of a ``map_server`` YAML file and its image (module docstring), as the
    fields ``occupancy``, ``resolution``, ``origin``, ``occupied_thresh`` and
    ``free_thresh`` of a :class:`jaxslam.grid.mapfile.OccupancyMap`."""
    path = Path(path)
    values, lines = parse_map_yaml(path)
    for key in _REQUIRED:
        if key not in values:
            raise DataFormatError(path, None, f"the map has no {key!r} (map_server needs {', '.join(_REQUIRED)})")
    image = values["image"]
    if not isinstance(image, str) or not image:
        raise DataFormatError(path, lines["image"], f"image must be a file name, got {image!r}")
    resolution = check_resolution(path, lines["resolution"], values["resolution"])
    origin = check_origin(path, lines["origin"], values["origin"])
    occ_th = _number(path, lines["occupied_thresh"], "occupied_thresh", values["occupied_thresh"])
    free_th = _number(path, lines["free_thresh"], "free_thresh", values["free_thresh"])
    check_thresholds(path, lines["free_thresh"], occ_th, free_th)
    negate = values.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise DataFormatError(path, lines.get("negate"), f"negate must be 0 or 1, got {negate!r}")
    mode = values.get("mode", "trinary")
    if mode not in MODES:
        raise DataFormatError(path, lines.get("mode"), f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    image_path = Path(image).expanduser()
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    if not image_path.is_file():
        raise DataFormatError(path, lines["image"], f"the map image {str(image_path)!r} does not exist")
    pixels, has_alpha = _read_image(image_path)
    occupancy = image_to_occupancy(pixels, has_alpha, mode, bool(negate), occ_th, free_th)
    return {"occupancy": occupancy, "resolution": resolution, "origin": origin, "occupied_thresh": occ_th,
            "free_thresh": free_th}


__all__ = [
    "FREE_VALUE",
    "MODES",
    "OCCUPIED_VALUE",
    "UNKNOWN_VALUE",
    "image_to_occupancy",
    "check_origin",
    "check_resolution",
    "check_thresholds",
    "parse_map_yaml",
    "read_map_yaml",
    "read_pgm_image",
]
