"""Small laser logs for the reliability tests: a robot driving through a rectangular
room, written as CARMEN text (FLASER lines) with the ranges ray-cast exactly."""

from __future__ import annotations

import numpy as np

ROOM = (0.0, 0.0, 12.0, 8.0)
"""The room's walls, ``(xmin, ymin, xmax, ymax)`` in m."""


def room_ranges(pose, angles) -> np.ndarray:
    """Distance from ``pose`` along each beam angle to the first wall of :data:`ROOM`."""
    x, y, theta = pose
    xmin, ymin, xmax, ymax = ROOM
    dx, dy = np.cos(theta + angles), np.sin(theta + angles)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, (xmax - x) / dx, np.where(dx < 0, (xmin - x) / dx, np.inf))
        ty = np.where(dy > 0, (ymax - y) / dy, np.where(dy < 0, (ymin - y) / dy, np.inf))
    return np.minimum(tx, ty)


def room_scans(scans: int = 30, beams: int = 61, step: float = 0.1):
    """``(poses, stamps, ranges)`` of a drive along the room's middle, ``step`` m per scan
    with a slow turn, 0.2 s apart."""
    i = np.arange(scans)
    poses = np.stack([2.0 + step * i, 4.0 + 0.02 * i, 0.01 * i], axis=1)
    angles = np.linspace(-np.pi / 2, np.pi / 2, beams)
    ranges = np.stack([room_ranges(p, angles) for p in poses])
    return poses, 100.0 + 0.2 * i, ranges


def flaser(ranges, pose, stamp) -> str:
    """One FLASER line (laser pose = odometry pose)."""
    pose_text = " ".join(f"{v:.6f}" for v in pose)
    body = " ".join(f"{r:.3f}" for r in ranges)
    return f"FLASER {len(ranges)} {body} {pose_text} {pose_text} {stamp:.6f} host {stamp:.6f}"


def carmen_text(poses, stamps, ranges) -> str:
    """A CARMEN log of the scans (a field of view of 180 degrees)."""
    lines = ["# jaxslam reliability test log", "PARAM robot_front_laser_max 30.0 nohost 0",
             "PARAM laser_front_laser_fov 180 nohost 0"]
    lines += [flaser(r, p, t) for p, t, r in zip(poses, stamps, ranges)]
    return "\n".join(lines) + "\n"


def room_log(path, **kwargs):
    """Write :func:`room_scans` as a CARMEN log at ``path``; returns ``path``."""
    path.write_text(carmen_text(*room_scans(**kwargs)))
    return path
