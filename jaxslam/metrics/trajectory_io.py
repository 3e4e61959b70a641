"""Planar trajectories: SE(2) algebra in NumPy, TUM files, and a pose for every scan.

SE(2) poses are ``(x, y, theta)`` rows. Composition and its inverse::

    a (+) b = (x_a + cos(t_a) x_b - sin(t_a) y_b,
               y_a + sin(t_a) x_b + cos(t_a) y_b,
               wrap(t_a + t_b))
    a^-1 (+) b = (R(t_a)^T (p_b - p_a), wrap(t_b - t_a))

TUM format (Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems",
IROS 2012): one pose per line, ``timestamp x y z qx qy qz qw``, ``#`` comments. A
planar pose is written with ``z = 0`` and the yaw quaternion
``(0, 0, sin(theta/2), cos(theta/2))``.

Host-side only; never imports jax.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose, se2_inverse, wrap_angle
from jaxslam.datasets.paths import DataFormatError
from jaxslam.datasets.reader import numeric_rows

__all__ = [
    "interpolate_poses",
    "read_tum",
    "se2_between",
    "se2_compose",
    "se2_inverse",
    "wrap_angle",
    "write_tum",
]


def _check_trajectory(timestamps: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    stamps = np.asarray(timestamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    if stamps.ndim != 1:
        raise ValueError(f"timestamps must have shape (T,), got {stamps.shape}")
    if poses.shape != (stamps.shape[0], 3):
        raise ValueError(f"poses must have shape ({stamps.shape[0]}, 3), got {poses.shape}")
    if not (np.all(np.isfinite(stamps)) and np.all(np.isfinite(poses))):
        raise ValueError("timestamps and poses must be finite")
    return stamps, poses


def write_tum(
    path: os.PathLike | str,
    timestamps: np.ndarray,
    poses: np.ndarray,
    *,
    comment: str | None = None,
) -> Path:
    """Write planar poses as a TUM trajectory; numbers round-trip exactly.

    Args:
        path: output file.
        timestamps: (T,) seconds.
        poses: (T, 3) ``(x, y, theta)``.
        comment: optional text for a ``#`` header line.

    Returns:
        The path written.
    """
    stamps, poses = _check_trajectory(timestamps, poses)
    half = 0.5 * poses[:, 2]
    qz, qw = np.sin(half), np.cos(half)
    lines = ["# timestamp x y z qx qy qz qw"]
    if comment:
        lines.extend(f"# {line}" for line in comment.splitlines())
    for t, (x, y, _), z, w in zip(stamps.tolist(), poses.tolist(), qz.tolist(), qw.tolist()):
        lines.append(f"{t!r} {x!r} {y!r} 0.0 0.0 0.0 {z!r} {w!r}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


def read_tum(
    path: os.PathLike | str, *, max_tilt: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory of planar poses.

    The order of the lines is kept (it is not sorted by time). The quaternion is
    normalised; the yaw is its rotation about z.

    Args:
        path: a TUM file.
        max_tilt: largest roll/pitch (rad) accepted as planar.

    Returns:
        ``(timestamps (T,), poses (T, 3))`` as float64.

    Raises:
        DataFormatError: a line without 8 numbers, a non-finite number, a zero or
            non-planar quaternion, or a file with no poses; the message names the
            file and line.
    """
    path = Path(path)
    stamps: list[float] = []
    poses: list[tuple[float, float, float]] = []
    rows = numeric_rows(path, "timestamp x y z qx qy qz qw", "TUM file", commas=True)
    for line_number, (t, x, y, _z, qx, qy, qz, qw) in rows:
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if norm < 1e-9:
            raise DataFormatError(path, line_number, "the quaternion is zero")
        qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
        # The body z axis has world z-component 1 - 2(qx^2 + qy^2) = cos(tilt).
        cos_tilt = min(1.0, max(-1.0, 1.0 - 2.0 * (qx * qx + qy * qy)))
        if math.acos(cos_tilt) > max_tilt:
            raise DataFormatError(
                path,
                line_number,
                f"pose is not planar: tilt {math.acos(cos_tilt):.3g} rad > max_tilt {max_tilt}",
            )
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        stamps.append(t)
        poses.append((x, y, yaw))
    if not stamps:
        raise DataFormatError(path, None, "no poses in the file")
    return np.array(stamps, dtype=np.float64), np.array(poses, dtype=np.float64)


def interpolate_poses(
    keyframe_indices: np.ndarray,
    keyframe_poses: np.ndarray,
    odom_poses: np.ndarray,
) -> np.ndarray:
    """A corrected pose for every scan from corrected keyframes and odometry.

    Scan ``i`` takes the last keyframe ``k <= i`` (the first keyframe for scans
    before it) and adds the odometry since then:

        pose_i = keyframe_pose_k (+) (odom_k^-1 (+) odom_i)

    so keyframes keep their corrected pose exactly.

    Args:
        keyframe_indices: (K,) strictly increasing scan indices.
        keyframe_poses: (K, 3) corrected poses of those scans.
        odom_poses: (S, 3) odometry of every scan.

    Returns:
        (S, 3) float64 poses.
    """
    indices = np.asarray(keyframe_indices)
    corrected = np.asarray(keyframe_poses, dtype=np.float64)
    odom = np.asarray(odom_poses, dtype=np.float64)
    if odom.ndim != 2 or odom.shape[1] != 3:
        raise ValueError(f"odom_poses must have shape (S, 3), got {odom.shape}")
    if indices.ndim != 1 or indices.shape[0] == 0:
        raise ValueError("keyframe_indices must be a non-empty 1-D array")
    if not np.issubdtype(indices.dtype, np.integer):
        raise ValueError(f"keyframe_indices must be integers, got {indices.dtype}")
    if corrected.shape != (indices.shape[0], 3):
        raise ValueError(
            f"keyframe_poses must have shape ({indices.shape[0]}, 3), got {corrected.shape}"
        )
    if np.any(np.diff(indices) <= 0):
        raise ValueError("keyframe_indices must be strictly increasing")
    if indices[0] < 0 or indices[-1] >= odom.shape[0]:
        raise ValueError(f"keyframe_indices must lie in [0, {odom.shape[0]})")
    slot = np.searchsorted(indices, np.arange(odom.shape[0]), side="right") - 1
    slot = np.maximum(slot, 0)
    since = se2_between(odom[indices[slot]], odom)
    return se2_compose(corrected[slot], since)
