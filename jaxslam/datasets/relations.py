"""Relations between two poses of a log, the data of Kümmerle et al.'s (2009) benchmark
files: for each, the stamps of the two poses and the second pose in the frame of the
first. Read from a file by :func:`jaxslam.metrics.relations.load_relations`, sampled from
reference poses by :func:`jaxslam.datasets.odometry_noise.reference_relations`, scored by
:func:`jaxslam.metrics.relations.relations_metric`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

__all__ = ["Relations"]


@dataclasses.dataclass(frozen=True, eq=False)
class Relations:
    """Ground-truth relations, in file order.

    Attributes:
        path: the file read (None when built in memory).
        t1: (R,) float64 stamp of the reference pose.
        t2: (R,) float64 stamp of the other pose.
        deltas: (R, 3) float64 pose at ``t2`` in the frame of the pose at ``t1``.
        lines: (R,) int64 1-based line numbers.
    """

    path: Path | None
    t1: np.ndarray
    t2: np.ndarray
    deltas: np.ndarray
    lines: np.ndarray

    def __len__(self) -> int:
        return int(self.t1.shape[0])
