r"""Saved maps that read back: jaxslam's lossless ``map.npz`` and ROS ``map_server`` maps.

:func:`load_map` reads

* a ``jaxslam run`` output folder (its ``map.npz``, else its ``map.yaml``);
* a ``map.npz`` written by :func:`save_map_npz`: the best particle's natural log-odds
  exactly as the filter held them (``(H, W)``, row 0 at the origin's y, rows growing
  with y), stored as the filter's ``int8`` cells and their log-odds unit where those
  give the log-odds back bit for bit (a jaxslam map always does), else as the floats
  themselves; the tile size of the paged maps, ``resolution``, ``origin``
  ``[x, y, yaw]`` and the ``map_server`` thresholds;
* a ROS ``map_server`` YAML file and its image (PGM read here, other formats through
  Pillow, which matplotlib depends on), interpreted as ``map_server``'s
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

As in ROS's AMCL (``convertMap``), a cell is *occupied* where its value is 100, *free*
where it is 0 and unknown otherwise. A map without a free cell is refused unless
``require_free=False``: nothing could be localized in it.

Host-side NumPy. Every problem with a file is a
:class:`~jaxslam.datasets.paths.DataFormatError` (file, line where there is one,
problem) or a :class:`~jaxslam.datasets.paths.DatasetNotFoundError`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import zipfile
from pathlib import Path

import numpy as np

from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError

MAP_NPZ_FORMAT = "jaxslam-map-1"
OCCUPIED_VALUE, FREE_VALUE, UNKNOWN_VALUE = 100, 0, -1
MODES = ("trinary", "scale", "raw")
_REQUIRED = ("image", "resolution", "origin", "occupied_thresh", "free_thresh")


@dataclasses.dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A map read back: ROS OccupancyGrid values on a grid whose row 0 is at the origin.

    Attributes:
        occupancy: ``(H, W)`` int8 OccupancyGrid values: 100 occupied, 0 free, -1
            unknown, ``1 .. 99`` partly occupied (``scale`` mode), anything in
            ``raw`` mode. Row ``r``, column ``c`` covers the map-frame square
            ``[c res, (c+1) res) x [r res, (r+1) res)``.
        resolution: metres per cell.
        origin: ``(x, y, yaw)`` world pose of the corner of cell (0, 0).
        log_odds: ``(H, W)`` float32 natural log-odds (jaxslam maps), else None.
        cells: ``(H, W)`` int8 filter cells with ``log_odds == cells * log_odds_unit``
            exactly (jaxslam maps), else None.
        log_odds_unit: natural log-odds per cell step of ``cells``, else None.
        tile: side in cells of the paged maps' tiles (jaxslam maps), else None.
        occupied_thresh, free_thresh: the thresholds that made ``occupancy``.
        source: the file read.
        pose: ``(x, y, theta)`` the saved run's last pose (jaxslam maps that record
            it), where ``jaxslam run --start-map`` continues by default; else None.
    """

    occupancy: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    log_odds: np.ndarray | None = None
    cells: np.ndarray | None = None
    log_odds_unit: float | None = None
    tile: int | None = None
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196
    source: Path | None = None
    pose: tuple[float, float, float] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.occupancy.shape)

    @property
    def occupied(self) -> np.ndarray:
        """``(H, W)`` bool, value 100 (AMCL's occupied state)."""
        return self.occupancy == OCCUPIED_VALUE

    @property
    def free(self) -> np.ndarray:
        """``(H, W)`` bool, value 0 (AMCL's free state)."""
        return self.occupancy == FREE_VALUE

    def cell_centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """World ``(x, y)`` of the centres of cells ``(rows, cols)``, shape ``(..., 2)``."""
        local_x = (np.asarray(cols, np.float64) + 0.5) * self.resolution
        local_y = (np.asarray(rows, np.float64) + 0.5) * self.resolution
        ox, oy, yaw = self.origin
        c, s = math.cos(yaw), math.sin(yaw)
        return np.stack([ox + c * local_x - s * local_y, oy + s * local_x + c * local_y], -1)


def threshold_values(occupancy_prob: np.ndarray, occupied_thresh: float, free_thresh: float) -> np.ndarray:
    """Trinary OccupancyGrid values of probabilities (``> occupied`` 100, ``< free`` 0, else -1)."""
    values = np.full(occupancy_prob.shape, UNKNOWN_VALUE, np.int8)
    values[occupancy_prob > occupied_thresh] = OCCUPIED_VALUE
    values[occupancy_prob < free_thresh] = FREE_VALUE
    return values


# --------------------------------------------------------------------------- jaxslam's map.npz


def save_map_npz(
    path: os.PathLike | str,
    log_odds: np.ndarray,
    resolution: float,
    origin,
    log_odds_unit: float | None = None,
    tile: int | None = None,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    pose=None,
) -> Path:
    """Write a map losslessly as ``.npz`` (compressed, written atomically).

    Args:
        path: the file.
        log_odds: ``(H, W)`` natural log-odds, row 0 at ``origin`` y (kept as given,
            float32 or float64).
        resolution: m per cell.
        origin: ``(x, y)`` or ``(x, y, yaw)`` of cell (0, 0)'s corner.
        log_odds_unit: the filter's log-odds per ``int8`` step; when
            ``log_odds / unit`` rounds to integers that give ``log_odds`` back bit
            for bit, those ``cells`` (the paged maps' own values) are stored in
            place of the floats.
        tile: side in cells of the paged maps' tiles, recorded with the layout.
        occupied_thresh, free_thresh: the ``map_server`` thresholds of the map's image.
        pose: ``(x, y, theta)`` the run's last pose, recorded with the map.
    """
    log_odds = np.asarray(log_odds)
    if log_odds.ndim != 2:
        raise ValueError(f"log_odds must be (H, W), got shape {log_odds.shape}")
    origin = tuple(float(v) for v in origin)
    origin = origin + (0.0,) * (3 - len(origin))
    arrays = dict(
        format=np.asarray(MAP_NPZ_FORMAT), log_odds_dtype=np.asarray(log_odds.dtype.name),
        resolution=np.float64(resolution), origin=np.asarray(origin, np.float64),
        occupied_thresh=np.float64(occupied_thresh), free_thresh=np.float64(free_thresh),
    )
    cells = _exact_cells(log_odds, log_odds_unit)
    if cells is None:
        arrays["log_odds"] = log_odds
    else:
        arrays.update(cells=cells, log_odds_unit=np.float64(log_odds_unit))
    if tile is not None:
        arrays["tile"] = np.int64(tile)
    if pose is not None:
        arrays["pose"] = np.asarray(pose, np.float64).reshape(3)
    path = Path(path)
    partial = path.with_name(f"{path.name}.{os.getpid()}.tmp.npz")
    try:
        np.savez_compressed(partial, **arrays)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def _exact_cells(log_odds: np.ndarray, unit: float | None) -> np.ndarray | None:
    """``int8`` cells with ``cells * unit == log_odds`` bit for bit, or None."""
    if unit is None or not float(unit) > 0 or log_odds.dtype.kind != "f":
        return None
    step = log_odds.dtype.type(unit)
    with np.errstate(invalid="ignore", over="ignore"):
        steps = np.rint(log_odds / step)
    if not np.all(np.abs(steps) <= 127):
        return None
    cells = steps.astype(np.int8)
    return cells if np.array_equal(cells.astype(log_odds.dtype) * step, log_odds) else None


def _read_npz(path: Path) -> OccupancyMap:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise DataFormatError(path, None, f"cannot read the map: {err}") from None
    if str(arrays.get("format", "")) != MAP_NPZ_FORMAT:
        raise DataFormatError(path, None, f"not a jaxslam map (no format {MAP_NPZ_FORMAT!r})")
    for name in ("resolution", "origin"):
        if name not in arrays:
            raise DataFormatError(path, None, f"the map has no {name!r}")
    cells = arrays.get("cells")
    unit = float(arrays["log_odds_unit"]) if "log_odds_unit" in arrays else None
    if "log_odds" in arrays:
        log_odds = arrays["log_odds"]
    elif cells is not None and unit is not None and cells.dtype == np.int8:
        try:
            dtype = np.dtype(str(arrays.get("log_odds_dtype", "float32")))
        except TypeError:
            raise DataFormatError(path, None, "bad log_odds_dtype") from None
        log_odds = cells.astype(dtype) * dtype.type(unit)
    else:
        raise DataFormatError(path, None, "the map has neither log_odds nor int8 cells with their log_odds_unit")
    if log_odds.ndim != 2 or log_odds.size == 0 or log_odds.dtype.kind != "f":
        raise DataFormatError(path, None, f"log_odds must be a non-empty float (H, W) array, got "
                                          f"{log_odds.dtype} {log_odds.shape}")
    if not np.all(np.isfinite(log_odds)):
        raise DataFormatError(path, None, "log_odds holds NaN or infinite values")
    resolution = _check_resolution(path, None, arrays["resolution"])
    origin = _check_origin(path, None, arrays["origin"])
    occ_th = float(arrays.get("occupied_thresh", 0.65))
    free_th = float(arrays.get("free_thresh", 0.196))
    _check_thresholds(path, None, occ_th, free_th)
    with np.errstate(over="ignore"):
        prob = 1.0 / (1.0 + np.exp(-log_odds.astype(np.float64)))
    tile = int(arrays["tile"]) if "tile" in arrays else None
    pose = None
    if "pose" in arrays:
        pose_array = np.asarray(arrays["pose"])
        if pose_array.shape != (3,) or pose_array.dtype.kind != "f" or not np.all(np.isfinite(pose_array)):
            raise DataFormatError(path, None, f"pose must be three finite numbers, got {pose_array.tolist()!r}")
        pose = tuple(float(v) for v in pose_array)
    return OccupancyMap(
        occupancy=threshold_values(prob, occ_th, free_th), resolution=resolution, origin=origin,
        log_odds=log_odds, cells=cells, log_odds_unit=unit, tile=tile, occupied_thresh=occ_th,
        free_thresh=free_th, source=path, pose=pose,
    )


# --------------------------------------------------------------------------- map_server YAML


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


def _check_resolution(path, line, value) -> float:
    resolution = _number(path, line, "resolution", value.item() if isinstance(value, np.ndarray) else value)
    if not (math.isfinite(resolution) and resolution > 0):
        raise DataFormatError(path, line, f"resolution must be a positive number of metres per cell, got {resolution}")
    return resolution


def _check_origin(path, line, value) -> tuple[float, float, float]:
    items = list(np.asarray(value).tolist()) if isinstance(value, np.ndarray) else value
    if not isinstance(items, list) or len(items) != 3:
        raise DataFormatError(path, line, f"origin must be [x, y, yaw], got {value!r}")
    origin = tuple(_number(path, line, "origin", v) for v in items)
    if not all(math.isfinite(v) for v in origin):
        raise DataFormatError(path, line, f"origin must be finite, got {list(origin)}")
    return origin


def _check_thresholds(path, line, occupied: float, free: float) -> None:
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


def _read_yaml_map(path: Path) -> OccupancyMap:
    values, lines = parse_map_yaml(path)
    for key in _REQUIRED:
        if key not in values:
            raise DataFormatError(path, None, f"the map has no {key!r} (map_server needs {', '.join(_REQUIRED)})")
    image = values["image"]
    if not isinstance(image, str) or not image:
        raise DataFormatError(path, lines["image"], f"image must be a file name, got {image!r}")
    resolution = _check_resolution(path, lines["resolution"], values["resolution"])
    origin = _check_origin(path, lines["origin"], values["origin"])
    occ_th = _number(path, lines["occupied_thresh"], "occupied_thresh", values["occupied_thresh"])
    free_th = _number(path, lines["free_thresh"], "free_thresh", values["free_thresh"])
    _check_thresholds(path, lines["free_thresh"], occ_th, free_th)
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
    return OccupancyMap(occupancy=occupancy, resolution=resolution, origin=origin,
                        occupied_thresh=occ_th, free_thresh=free_th, source=path)


def _checked(grid: OccupancyMap) -> OccupancyMap:
    if not grid.free.any():
        raise DataFormatError(grid.source, None, f"the map ({grid.shape[1]} x {grid.shape[0]} cells) has no free "
                                                 "cell: nothing can be localized in it")
    return grid


def segment_map(segments: np.ndarray, bounds, resolution: float = 0.05, margin: float = 1.0) -> OccupancyMap:
    """The map of a world of line segments (a simulator's walls, :mod:`jaxslam.datasets.laser_sim`).

    Every cell a segment passes through is occupied (the segment sampled at a quarter
    of a cell); the other cells inside ``bounds`` ``(xmin, ymin, xmax, ymax)`` are
    free, those in the ``margin`` around them unknown.
    """
    segments = np.asarray(segments, np.float64).reshape(-1, 4)
    x0, y0 = bounds[0] - margin, bounds[1] - margin
    width = int(math.ceil((bounds[2] - bounds[0] + 2 * margin) / resolution))
    height = int(math.ceil((bounds[3] - bounds[1] + 2 * margin) / resolution))
    cols = (np.arange(width) + 0.5) * resolution + x0
    rows = (np.arange(height) + 0.5) * resolution + y0
    inside = ((rows[:, None] >= bounds[1]) & (rows[:, None] <= bounds[3])
              & (cols[None, :] >= bounds[0]) & (cols[None, :] <= bounds[2]))
    occupancy = np.where(inside, FREE_VALUE, UNKNOWN_VALUE).astype(np.int8)
    for ax, ay, bx, by in segments:
        count = int(math.ceil(math.hypot(bx - ax, by - ay) / (0.25 * resolution))) + 1
        t = np.linspace(0.0, 1.0, count)
        c = np.floor((ax + t * (bx - ax) - x0) / resolution).astype(np.int64)
        r = np.floor((ay + t * (by - ay) - y0) / resolution).astype(np.int64)
        ok = (c >= 0) & (c < width) & (r >= 0) & (r < height)
        occupancy[r[ok], c[ok]] = OCCUPIED_VALUE
    return _checked(OccupancyMap(occupancy=occupancy, resolution=float(resolution), origin=(x0, y0, 0.0)))


def load_map(path: os.PathLike | str, require_free: bool = True) -> OccupancyMap:
    """Read a saved map: a run folder, a ``map.npz`` or a ``map_server`` YAML file.

    Args:
        path: a ``jaxslam run`` output folder (``map.npz`` is read, else
            ``map.yaml``), a ``.npz`` written by :func:`save_map_npz`, or a YAML file
            of the ROS ``map_server`` convention (see the module docstring).
        require_free: refuse a map without a free cell (nothing could be localized
            in it).

    Returns:
        The :class:`~jaxslam.grid.mapfile.OccupancyMap`.

    Raises:
        DatasetNotFoundError: the path (or the folder's map) does not exist.
        DataFormatError: a bad file; the message names the file, the line of a YAML
            key where it is one, and the problem.
    """
    path = Path(path).expanduser()
    if path.is_dir():
        for name in ("map.npz", "map.yaml"):
            if (path / name).is_file():
                path = path / name
                break
        else:
            raise DatasetNotFoundError(f"{str(path)!r} holds no map.npz or map.yaml")
    elif not path.exists():
        raise DatasetNotFoundError(f"map {str(path)!r} does not exist")
    with open(path, "rb") as handle:
        zipped = handle.read(4) == b"PK\x03\x04"
    grid = _read_npz(path) if zipped or path.suffix == ".npz" else _read_yaml_map(path)
    return _checked(grid) if require_free else grid


__all__ = [
    "MAP_NPZ_FORMAT",
    "OccupancyMap",
    "image_to_occupancy",
    "load_map",
    "parse_map_yaml",
    "read_pgm_image",
    "save_map_npz",
    "segment_map",
    "threshold_values",
]
