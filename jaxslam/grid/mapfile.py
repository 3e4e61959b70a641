r"""Saved maps that read back: jaxslam's lossless ``map.npz`` and ROS ``map_server`` maps.

:func:`load_map` reads

* a ``jaxslam run`` output folder (its ``map.npz``, else its ``map.yaml``);
* a ``map.npz`` written by :func:`save_map_npz`: the best particle's natural log-odds
  exactly as the filter held them (``(H, W)``, row 0 at the origin's y, rows growing
  with y), stored as the filter's ``int8`` cells and their log-odds unit where those
  give the log-odds back bit for bit (a jaxslam map always does), else as the floats
  themselves; the tile size of the paged maps, ``resolution``, ``origin``
  ``[x, y, yaw]`` and the ``map_server`` thresholds;
* a ROS ``map_server`` YAML file and its image, interpreted as ``map_server``'s
  ``loadMapFromFile`` does (:mod:`jaxslam.grid.map_server`).

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
import zipfile
from pathlib import Path

import numpy as np

from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError
from jaxslam.grid.map_server import (
    FREE_VALUE,
    OCCUPIED_VALUE,
    UNKNOWN_VALUE,
    check_origin,
    check_resolution,
    check_thresholds,
    read_map_yaml,
)

MAP_NPZ_FORMAT = "jaxslam-map-1"


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
    resolution = check_resolution(path, None, arrays["resolution"])
    origin = check_origin(path, None, arrays["origin"])
    occ_th = float(arrays.get("occupied_thresh", 0.65))
    free_th = float(arrays.get("free_thresh", 0.196))
    check_thresholds(path, None, occ_th, free_th)
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
    grid = _read_npz(path) if zipped or path.suffix == ".npz" else OccupancyMap(**read_map_yaml(path), source=path)
    return _checked(grid) if require_free else grid


__all__ = [
    "MAP_NPZ_FORMAT",
    "OccupancyMap",
    "load_map",
    "save_map_npz",
    "segment_map",
    "threshold_values",
]
