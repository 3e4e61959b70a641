"""Map export: PGM + YAML in the ROS ``map_server`` convention, and PNG.

``map_server`` reads a greyscale image and a YAML file::

    image: map.pgm
    resolution: 0.05          # m / pixel
    origin: [x, y, 0.0]       # world pose of the lower-left pixel
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196

With ``negate: 0`` a pixel value ``v`` means occupancy ``(255 - v) / 255``. As
``map_saver`` does, cells are written trinary: occupied (``p > occupied_thresh``) as
0, free (``p < free_thresh``) as 254 and unknown as 205. The image's first row is the
top of the map (largest ``y``), so the grid (row 0 at ``origin`` y) is flipped.

Host-side NumPy; the PNG is encoded with zlib (no matplotlib needed).
"""

from __future__ import annotations

import math
import os
import struct
import zlib
from pathlib import Path

import numpy as np

OCCUPIED, FREE, UNKNOWN = 0, 254, 205
_BLOCK_CELLS = 1 << 22  # about this many cells per block of rows (bounded temporaries)


def row_blocks(height: int, row_cells: int, multiple: int = 1):
    """``(r0, r1)`` ranges of rows of about 4.2 million values each (``_BLOCK_CELLS``;
    ``row_cells`` per row), each a multiple of ``multiple`` rows but the last: big maps are converted,
    drawn and encoded block by block, never as one full-size temporary."""
    step = multiple * max(1, _BLOCK_CELLS // max(row_cells * multiple, 1))
    for r0 in range(0, height, step):
        yield r0, min(r0 + step, height)


def occupancy_image(log_odds: np.ndarray, occupied_thresh: float = 0.65, free_thresh: float = 0.196) -> np.ndarray:
    """``uint8`` image (top row = largest y) of a natural log-odds grid ``(H, W)``.

    A cell is occupied when ``p = 1 / (1 + exp(-l)) > occupied_thresh`` and free when
    ``p < free_thresh``. ``p`` grows with ``l``, so this compares ``l`` with the
    thresholds' log-odds instead of computing ``p`` for every cell; cells within
    ``1e-6`` of a threshold (where rounding could decide) get ``p`` in float64 as
    before, so the image is exactly the one of the formula.
    """
    src = np.asarray(log_odds)
    if src.ndim != 2:
        raise ValueError(f"log_odds must be (H, W), got shape {src.shape}")
    h = src.shape[0]
    img = np.empty(src.shape, np.uint8)
    # A float32 map is compared in float32 (no float64 copy: a 5312 x 6400 map took
    # 0.7 s, now about a third of that) against the thresholds rounded to float32. They
    # move by less than 1e-7, far inside the 1e-6 band, so every cell outside the band
    # is on the same side of both.
    real = np.float32 if src.dtype == np.float32 else np.float64
    occupied_lo = real(math.log(occupied_thresh / (1.0 - occupied_thresh)))
    free_lo = real(math.log(free_thresh / (1.0 - free_thresh)))
    # Blocks of rows keep the temporaries small (a 5000 x 7700 map would otherwise need
    # about 1 GB of them); the image is written upside down directly.
    for r0, r1 in row_blocks(h, src.shape[1]):
        lo = src[r0:r1].astype(real, copy=False)
        block = np.full(lo.shape, UNKNOWN, np.uint8)
        with np.errstate(invalid="ignore"):
            block[lo > occupied_lo] = OCCUPIED
            block[lo < free_lo] = FREE
            near = (np.abs(lo - occupied_lo) < 1e-6) | (np.abs(lo - free_lo) < 1e-6)
        if near.any():
            p = 1.0 / (1.0 + np.exp(-lo[near].astype(np.float64)))
            block[near] = np.where(p > occupied_thresh, OCCUPIED, np.where(p < free_thresh, FREE, UNKNOWN))
        img[h - r0 - lo.shape[0] : h - r0] = block[::-1]
    return img


def write_pgm(path: os.PathLike | str, image: np.ndarray) -> None:
    """Binary PGM (P5, maxval 255)."""
    image = np.asarray(image, np.uint8)
    h, w = image.shape
    with open(path, "wb") as f:
        f.write(f"P5\n# jaxslam map\n{w} {h}\n255\n".encode("ascii"))
        f.write(image.tobytes())


def read_pgm(path: os.PathLike | str) -> np.ndarray:
    """Read a binary PGM written by :func:`write_pgm` (or any P5 with maxval 255)."""
    data = Path(path).read_bytes()
    tokens = []
    pos = 0
    while len(tokens) < 4:
        while data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end : end + 1].isspace():
            end += 1
        tokens.append(data[pos:end])
        pos = end
    if tokens[0] != b"P5" or int(tokens[3]) != 255:
        raise ValueError(f"{path}: not an 8-bit binary PGM")
    w, h = int(tokens[1]), int(tokens[2])
    pos += 1
    return np.frombuffer(data[pos : pos + w * h], np.uint8).reshape(h, w)


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def write_png(
    path: os.PathLike | str,
    image: np.ndarray,
    compress_level: int = 1,
    marks: tuple[np.ndarray, np.ndarray] | None = None,
    mark_color: tuple[int, int, int] = (220, 30, 30),
) -> None:
    """8-bit greyscale (``(H, W)``) or RGB (``(H, W, 3)``) image as an RGBA PNG.

    The pixels are what ``matplotlib.image.imsave`` writes for these images (grey
    ``v`` as ``(v, v, v, 255)``, alpha 255), encoded here directly: one IDAT of
    unfiltered rows compressed by zlib at ``compress_level`` (1: fast; a 4000 x 4000
    map in well under a second, where imsave's colormap pass and level-6 compression
    took several times longer). Rows are converted and compressed in blocks, so a
    big map needs no full-size RGBA copy. ``marks``: ``(rows, cols)`` pixel indices
    drawn in ``mark_color`` (the same as setting them in an RGB image first).
    """
    image = np.asarray(image, np.uint8)
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"image must be (H, W) or (H, W, 3), got {image.shape}")
    height, width = image.shape[:2]
    if marks is not None:
        mark_rows, mark_cols = (np.asarray(m, np.int64) for m in marks)
        order = np.argsort(mark_rows, kind="stable")
        mark_rows, mark_cols = mark_rows[order], mark_cols[order]
    compressor = zlib.compressobj(compress_level)
    pieces = []
    for r0, r1 in row_blocks(height, 4 * width + 1):
        rows = np.empty((r1 - r0, 1 + 4 * width), np.uint8)
        rows[:, 0] = 0  # filter type None
        pixels = rows[:, 1:].reshape(r1 - r0, width, 4)
        pixels[..., :3] = image[r0:r1, :, None] if image.ndim == 2 else image[r0:r1]
        pixels[..., 3] = 255
        if marks is not None:
            lo, hi = np.searchsorted(mark_rows, [r0, r1])
            pixels[mark_rows[lo:hi] - r0, mark_cols[lo:hi], :3] = mark_color
        pieces.append(compressor.compress(rows.tobytes()))
    pieces.append(compressor.flush())
    header = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)  # 8-bit RGBA
    with open(path, "wb") as handle:
        handle.write(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", header) + _png_chunk(b"IDAT", b"".join(pieces))
                     + _png_chunk(b"IEND", b""))


def write_map_yaml(
    path: os.PathLike | str,
    image_name: str,
    resolution: float,
    origin: tuple[float, float],
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
) -> None:
    """The ``map_server`` YAML next to an image."""
    text = (
        f"image: {image_name}\n"
        f"resolution: {float(resolution):.6f}\n"
        f"origin: [{float(origin[0]):.6f}, {float(origin[1]):.6f}, 0.000000]\n"
        f"negate: 0\n"
        f"occupied_thresh: {occupied_thresh}\n"
        f"free_thresh: {free_thresh}\n"
    )
    Path(path).write_text(text)


def save_map(
    out_dir: os.PathLike | str,
    log_odds: np.ndarray,
    resolution: float,
    origin: tuple[float, float],
    name: str = "map",
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    trajectory: np.ndarray | None = None,
) -> dict[str, Path]:
    """Write ``name.pgm``, ``name.yaml`` and ``name.png`` into ``out_dir``.

    Args:
        out_dir: folder (created if missing).
        log_odds: ``(H, W)`` natural log-odds, row 0 at ``origin`` y.
        resolution: m per cell.
        origin: world ``(x, y)`` of the lower-left corner of cell (0, 0).
        name: file stem.
        occupied_thresh, free_thresh: ``map_server`` thresholds.
        trajectory: optional ``(T, 2+)`` path drawn in red on the PNG only.

    Returns:
        The paths written, keyed ``pgm``, ``yaml``, ``png``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    image = occupancy_image(log_odds, occupied_thresh, free_thresh)
    paths = {"pgm": out / f"{name}.pgm", "yaml": out / f"{name}.yaml", "png": out / f"{name}.png"}
    write_pgm(paths["pgm"], image)
    write_map_yaml(paths["yaml"], paths["pgm"].name, resolution, origin, occupied_thresh, free_thresh)
    _write_map_image(paths["png"], image, resolution, origin, trajectory)
    return paths


def save_map_png(
    path: os.PathLike | str,
    log_odds: np.ndarray,
    resolution: float,
    origin: tuple[float, float],
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    trajectory: np.ndarray | None = None,
) -> Path:
    """Write the PNG of :func:`save_map` alone (the same pixels), as ``jaxslam plot``
    redraws it from a run's ``arrays.npz``; the arguments are :func:`save_map`'s."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_map_image(path, occupancy_image(log_odds, occupied_thresh, free_thresh), resolution, origin, trajectory)
    return path


def _write_map_image(path: Path, image: np.ndarray, resolution: float, origin, trajectory) -> None:
    """``image`` (:func:`occupancy_image`) as PNG, the cells the trajectory passes red."""
    marks = None
    if trajectory is not None:
        traj = np.asarray(trajectory, np.float64)[:, :2]
        cols = np.floor((traj[:, 0] - origin[0]) / resolution).astype(int)
        rows = image.shape[0] - 1 - np.floor((traj[:, 1] - origin[1]) / resolution).astype(int)
        ok = (cols >= 0) & (cols < image.shape[1]) & (rows >= 0) & (rows < image.shape[0])
        marks = (rows[ok], cols[ok])
    write_png(path, image, marks=marks)


__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "occupancy_image",
    "read_pgm",
    "row_blocks",
    "save_map",
    "save_map_png",
    "write_map_yaml",
    "write_pgm",
    "write_png",
]
