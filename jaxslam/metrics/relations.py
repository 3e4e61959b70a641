"""The relation (relative displacement) metric of Kümmerle et al. 2009.

R. Kümmerle, B. Steder, C. Dornhege, M. Ruhnke, G. Grisetti, C. Stachniss,
A. Kleiner, "On measuring the accuracy of SLAM algorithms", Autonomous Robots
27(4):387-407, 2009, Sec. 3, Eq. (1)-(2). For ground-truth relations
``delta*_ij`` (the pose at ``t_j`` in the frame of the pose at ``t_i``) and an
estimated trajectory ``x``::

    delta_ij = x_i^-1 (+) x_j
    e_ij     = delta_ij (-) delta*_ij = delta*_ij^-1 (+) delta_ij
    trans_ij = ||e_ij,xy|| = ||t(delta_ij) - t(delta*_ij)||      (m)
    rot_ij   = |wrap(theta(delta_ij) - theta(delta*_ij))|       (reported in deg)

The summary follows the Freiburg ``metricEvaluator`` tool of the benchmark: mean and
standard deviation of the absolute errors (m, deg) and of the squared errors
(m^2, deg^2) over all scored relations, each relation counted once (the paper's
``epsilon(delta) = 1/N sum trans^2 + rot^2`` is the sum of the two squared means).
Standard deviations are population ones (``ddof=0``).

A relation's two stamps are matched to the nearest trajectory stamp; one farther
than ``tolerance`` leaves the relation unmatched. Unmatched relations are not scored
and are counted in ``n_unmatched``. The benchmark stamps equal the logs' FLASER
``ipc_timestamp`` exactly, and a log can hold scans only microseconds apart, so the
default tolerance is 1 us: it absorbs printing round-off and nothing more.

``.relations`` files: one relation per line, ``t1 t2 x y z roll pitch yaw`` (m, rad),
z, roll and pitch zero. Host-side only; never imports jax.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxslam.datasets.paths import DataFormatError, find
from jaxslam.datasets.reader import numeric_rows
from jaxslam.datasets.registry import DATASETS
from jaxslam.datasets.relations import Relations
from jaxslam.metrics.trajectory_io import se2_between

__all__ = [
    "DATASET_RELATIONS",
    "RelationErrors",
    "Relations",
    "load_dataset_relations",
    "load_relations",
    "match_timestamps",
    "relation_errors",
    "relations_metric",
]

DATASET_RELATIONS = {info.name: info.relations for info in DATASETS.values() if info.relations is not None}
"""Dataset name -> path parts of its relations file, for the registry's entries
that have one (a view of ``jaxslam.datasets.registry.DATASETS``)."""

_PLANAR_TOL = 1e-9


class RelationErrors(NamedTuple):
    """Per-relation errors; entries of unmatched relations are NaN.

    Attributes:
        trans: (R,) translational error (m).
        rot: (R,) absolute rotational error (rad).
        matched: (R,) bool, both stamps found in the trajectory.
        index1: (R,) int64 trajectory index matched to ``t1`` (-1 if none).
        index2: (R,) int64 trajectory index matched to ``t2`` (-1 if none).
    """

    trans: np.ndarray
    rot: np.ndarray
    matched: np.ndarray
    index1: np.ndarray
    index2: np.ndarray


def load_relations(path: os.PathLike | str) -> Relations:
    """Read a ``.relations`` file.

    Raises:
        DataFormatError: a line without 8 numbers, a non-finite number, a non-zero
            z/roll/pitch, or no relations; the message names the file and line.
    """
    path = Path(path)
    rows: list[tuple[float, ...]] = []
    lines: list[int] = []
    for line_number, values in numeric_rows(path, "t1 t2 x y z roll pitch yaw", "relations file"):
        if max(abs(values[4]), abs(values[5]), abs(values[6])) > _PLANAR_TOL:
            raise DataFormatError(
                path, line_number, "z, roll and pitch must be 0 for a planar relation"
            )
        rows.append(values)
        lines.append(line_number)
    if not rows:
        raise DataFormatError(path, None, "no relations in the file")
    table = np.array(rows, dtype=np.float64)
    return Relations(
        path=path,
        t1=table[:, 0],
        t2=table[:, 1],
        deltas=table[:, [2, 3, 7]],
        lines=np.array(lines, dtype=np.int64),
    )


def load_dataset_relations(name: str) -> Relations:
    """Load the benchmark relations of a registered dataset (``intel``, ``fr079``,
    ``mit-killian``)."""
    if name not in DATASET_RELATIONS:
        raise ValueError(f"no relations for {name!r}; known: {', '.join(DATASET_RELATIONS)}")
    return load_relations(find(name, *DATASET_RELATIONS[name]))


def match_timestamps(
    queries: np.ndarray, timestamps: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest trajectory index for each query stamp.

    Args:
        queries: (Q,) stamps to look up.
        timestamps: (T,) trajectory stamps, in any order.
        tolerance: largest accepted ``|query - stamp|`` (s).

    Returns:
        ``(indices (Q,) int64, found (Q,) bool)``; ``indices`` is -1 where not found.
        Ties go to the earlier stamp (then the earlier index).
    """
    queries = np.asarray(queries, dtype=np.float64)
    stamps = np.asarray(timestamps, dtype=np.float64)
    if stamps.shape[0] == 0:
        return np.full(queries.shape, -1, dtype=np.int64), np.zeros(queries.shape, bool)
    order = np.argsort(stamps, kind="stable")
    sorted_stamps = stamps[order]
    right = np.clip(np.searchsorted(sorted_stamps, queries, side="left"), 0, len(stamps) - 1)
    left = np.clip(right - 1, 0, len(stamps) - 1)
    # Leftmost of a run of equal stamps, so ties resolve to the earliest index.
    left = np.searchsorted(sorted_stamps, sorted_stamps[left], side="left")
    use_left = np.abs(queries - sorted_stamps[left]) <= np.abs(sorted_stamps[right] - queries)
    nearest = np.where(use_left, left, right)
    found = np.abs(sorted_stamps[nearest] - queries) <= tolerance
    return np.where(found, order[nearest], -1).astype(np.int64), found


def _as_relations(relations: Relations | os.PathLike | str) -> Relations:
    return relations if isinstance(relations, Relations) else load_relations(relations)


def relation_errors(
    relations: Relations | os.PathLike | str,
    timestamps: np.ndarray,
    poses: np.ndarray,
    *,
    tolerance: float = 1e-6,
) -> RelationErrors:
    """Per-relation translational and rotational errors of a trajectory.

    Args:
        relations: a :class:`~jaxslam.datasets.relations.Relations` or a path to a ``.relations`` file.
        timestamps: (T,) stamps of the trajectory (same clock as the relations).
        poses: (T, 3) poses ``(x, y, theta)``.
        tolerance: stamp matching tolerance (s); see the module docstring.
    """
    relations = _as_relations(relations)
    stamps = np.asarray(timestamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    if stamps.ndim != 1 or poses.shape != (stamps.shape[0], 3):
        raise ValueError(
            f"need timestamps (T,) and poses (T, 3); got {stamps.shape} and {poses.shape}"
        )
    index1, found1 = match_timestamps(relations.t1, stamps, tolerance)
    index2, found2 = match_timestamps(relations.t2, stamps, tolerance)
    matched = found1 & found2
    estimated = se2_between(poses[np.maximum(index1, 0)], poses[np.maximum(index2, 0)])
    error = se2_between(relations.deltas, estimated)
    trans = np.where(matched, np.hypot(error[:, 0], error[:, 1]), np.nan)
    rot = np.where(matched, np.abs(error[:, 2]), np.nan)
    return RelationErrors(trans, rot, matched, index1, index2)


def relations_metric(
    relations: Relations | os.PathLike | str,
    timestamps: np.ndarray,
    poses: np.ndarray,
    *,
    tolerance: float = 1e-6,
) -> dict[str, float | int]:
    """Kümmerle et al. 2009 relation metric of a trajectory (see the module docstring).

    Args:
        relations: a :class:`~jaxslam.datasets.relations.Relations` or a path to a ``.relations`` file.
        timestamps: (T,) stamps of the trajectory.
        poses: (T, 3) poses ``(x, y, theta)``.
        tolerance: stamp matching tolerance (s).

    Returns:
        ``trans_err_mean_m``, ``trans_err_std_m``, ``trans_err_median_m``,
        ``trans_err_max_m``, ``n_trans_err_over_0_5m``, ``rot_err_mean_deg``, ``rot_err_median_deg``,
        ``rot_err_std_deg``, ``trans_sq_err_mean_m2``, ``trans_sq_err_std``,
        ``rot_sq_err_mean_deg2``, ``rot_sq_err_std``, and the counts
        ``n_relations`` (scored), ``n_unmatched`` (not scored: a stamp had no pose
        within ``tolerance``) and ``n_total``. The statistics are NaN when nothing
        was scored.
    """
    errors = relation_errors(relations, timestamps, poses, tolerance=tolerance)
    trans = errors.trans[errors.matched]
    rot = np.degrees(errors.rot[errors.matched])

    def stat(values: np.ndarray, reduce) -> float:
        return float(reduce(values)) if values.size else math.nan

    return {
        "trans_err_mean_m": stat(trans, np.mean),
        "trans_err_std_m": stat(trans, np.std),
        "trans_err_median_m": stat(trans, np.median),
        "trans_err_max_m": stat(trans, np.max),
        "n_trans_err_over_0_5m": int(np.sum(trans > 0.5)),
        "rot_err_mean_deg": stat(rot, np.mean),
        "rot_err_median_deg": stat(rot, np.median),
        "rot_err_std_deg": stat(rot, np.std),
        "trans_sq_err_mean_m2": stat(trans**2, np.mean),
        "trans_sq_err_std": stat(trans**2, np.std),
        "rot_sq_err_mean_deg2": stat(rot**2, np.mean),
        "rot_sq_err_std": stat(rot**2, np.std),
        "n_relations": int(errors.matched.sum()),
        "n_unmatched": int((~errors.matched).sum()),
        "n_total": int(errors.matched.shape[0]),
    }
