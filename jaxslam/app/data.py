"""The data a command runs on: a dataset name, a CARMEN log or a ROS bag resolved, the
ROS bag options checked and the laser log loaded and checked.

:func:`resolve_dataset` resolves ``--dataset``, :func:`bag_options` checks the bag
options, :func:`load_log` and :func:`load_checked_log` load the laser log.

``jaxslam run`` (:mod:`jaxslam.app.runs`), ``jaxslam calibrate`` and ``jaxslam
localize`` read their data through these functions, so that every command accepts the
same files and refuses bad ones with the same one-line messages.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from jaxslam.app.errors import RunError
from jaxslam.datasets.checks import MAX_ODOMETRY_STEP, check_laser_log
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.datasets.registry import ALGORITHMS, DATASETS, DatasetInfo, lookup


def kind_of(algorithm: str) -> str:
    """The data an algorithm runs on: ``"landmark"`` or ``"laser"``."""
    return ALGORITHMS[algorithm]


CARMEN_SUFFIXES = (".clf", ".log", ".carmen", ".gz")
"""Names of CARMEN logs (plain or gzipped; any existing file is read as one unless it
is a ROS bag)."""

FILE_KINDS = (
    "a CARMEN log file (.clf, .log or .carmen, plain or gzipped as .gz), a ROS 1 bag (.bag) or a ROS 2 bag "
    "(its folder, with metadata.yaml, or its .db3 or .mcap file)"
)
"""The files ``--dataset`` accepts besides the dataset names (:func:`resolve_dataset`)."""


def resolve_dataset(dataset: str | None, algorithm: str | None) -> tuple[DatasetInfo | None, Path | None, str]:
    """``(info, path, kind)`` for a dataset name, a path to a CARMEN log or a ROS bag,
    or None (the built-in simulator that suits ``algorithm``)."""
    from jaxslam.datasets.rosbag import ROSBAG_SUFFIXES

    if dataset is None:
        kind = kind_of(algorithm) if algorithm else "landmark"
        return lookup("sim-landmarks" if kind == "landmark" else "sim-laser"), None, kind
    candidate = Path(dataset).expanduser()
    if candidate.suffix in CARMEN_SUFFIXES + ROSBAG_SUFFIXES or candidate.exists():
        if not candidate.exists():
            what = "ROS bag" if candidate.suffix in ROSBAG_SUFFIXES else "CARMEN log"
            raise DatasetNotFoundError(f"{what} {str(candidate)!r} does not exist")
        return None, candidate, "laser"
    try:
        info = lookup(dataset)
    except KeyError:
        raise RunError(f"unknown dataset {dataset!r}: no such dataset name nor file; --dataset takes a dataset "
                       f"name ({', '.join(DATASETS)}; `jaxslam datasets` says which are found), {FILE_KINDS}") from None
    return info, None, info.kind


def load_log(info, path, seed, bag, max_range, mixed_geometry=None):
    """The laser log of a registry entry, a ROS bag or a CARMEN log path, and how the
    log cache served it (:mod:`jaxslam.datasets.log_cache`; CARMEN logs only, in the
    compilation-cache folder when that is on)."""
    if path is not None and is_bag(path):
        from jaxslam.datasets.paths import DataFormatError
        from jaxslam.datasets.rosbag import load_rosbag

        try:
            return load_rosbag(path, **(bag or {})), "off"
        except (DataFormatError, FileNotFoundError):
            raise
        except Exception as err:  # noqa: BLE001 - any failure of the bag reader on damaged bytes
            # DataFormatError joins a parser's multi-line message into one line
            detail = f"{type(err).__name__}: {err}" if str(err).strip() else type(err).__name__
            raise DataFormatError(path, None, f"cannot read the bag ({detail})") from None
    options = {"max_range": max_range} if max_range is not None else {}
    if mixed_geometry is not None:
        options["mixed_geometry"] = mixed_geometry
    if info is not None and info.loader != "carmen":
        return info.load(seed=seed, **options), "off"
    from jaxslam.datasets.log_cache import load_carmen_cached

    if info is not None:
        path, options = info.paths()[0], {**info.options, **options}
    return load_carmen_cached(path, log_cache_folder(), **options)


def load_checked_log(info, path, seed=0, bag=None, max_range=None, mixed_geometry=None, max_odometry_step=None,
                     temporal=False):
    """``(log, log_cache, log_checks)``: the laser log of a registry entry ``info`` or
    a ``path`` (CARMEN log or ROS bag), how the log cache served it, and what
    :func:`jaxslam.datasets.checks.check_laser_log` found (a log that cannot give a
    true map raises ``DataFormatError`` naming the file and the scan). A warning line
    says when the scan stamps do not advance."""
    log, log_cache = load_log(info, path, seed, bag, max_range, mixed_geometry)
    log_checks = check_laser_log(log, MAX_ODOMETRY_STEP if max_odometry_step is None else max_odometry_step,
                                 temporal=temporal)
    if not log_checks["stamps_advance"]:
        print(f"jaxslam run: warning: {log.path}: its scan stamps do not advance ({log_checks['scans']} scans over "
              f"{log_checks['stamp_span_s']:g} s); trajectory.tum carries them as logged", file=sys.stderr)
    return log, log_cache, log_checks


def log_cache_folder() -> str | None:
    """The compilation-cache folder (the log cache lives beside the compiled programs),
    or None when that cache is off."""
    import jax

    return jax.config.jax_compilation_cache_dir


BAG_OPTIONS = ("scan_topic", "odom_topic", "base_frame", "laser_offset")
"""The options of :func:`jaxslam.datasets.rosbag.load_rosbag` a command passes on."""


def is_bag(path) -> bool:
    """Whether ``path`` is a ROS 1 or ROS 2 bag (:func:`jaxslam.datasets.rosbag.is_rosbag`)."""
    from jaxslam.datasets.rosbag import is_rosbag

    return is_rosbag(path)


def bag_options(bag: dict | None, path) -> dict:
    """The ROS bag options that are set; an error if set for something that is not a bag."""
    options = {k: v for k, v in (bag or {}).items() if v is not None}
    unknown = set(options) - set(BAG_OPTIONS)
    if unknown:
        raise RunError(f"unknown ROS bag option(s) {sorted(unknown)}; use {', '.join(BAG_OPTIONS)}")
    if options and (path is None or not is_bag(path)):
        raise RunError("--scan-topic/--odom-topic/--base-frame/--laser-mount apply to ROS bags only "
                       "(a .bag file, a ROS 2 bag folder, .mcap or .db3)")
    if "laser_offset" in options:
        options["laser_offset"] = [float(v) for v in options["laser_offset"]]
        if not np.isfinite(options["laser_offset"]).all():
            raise RunError(f"--laser-mount {' '.join(map(str, options['laser_offset']))}: must be three finite numbers")
    return options
