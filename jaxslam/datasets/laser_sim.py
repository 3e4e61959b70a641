"""A 2-D laser world simulator: rooms and corridors ray-cast into simulated scans.

The output is a :class:`SimulatedLog`, a :class:`jaxslam.datasets.carmen.CarmenLog`
(same arrays as the CARMEN reader: ``scan_times``, ``ranges (S, B) float32``,
``valid``, ``max_range_mask``, ``angles``, ``max_range``, ``laser_offset``,
``odom_poses`` ...) with the ground truth added: ``true_poses (S, 3)`` and the wall
segments ``walls (M, 4)``. Host-side NumPy only.

World (:func:`office_world`): a rectangular floor with a ring corridor around a
block of rooms; each room opens onto the corridor through a door, and pillars along
the outer wall break the symmetry of the long corridor sides. The robot drives the
corridor centre line (rounded corners) for ``laps`` laps at a constant speed.
:func:`corridor_world` is a straight corridor whose doors repeat at one period, the
aliasing a loop-closure search meets in long office corridors.

Sensor: ``num_beams`` beams over ``fov`` (default 180 deg, right to left), range
noise ``N(0, range_std^2)``, readings beyond ``max_range`` reported as ``max_range``
(no return).

Odometry: the true per-scan increments ``d = x_{k-1}^-1 (+) x_k`` corrupted as
``d_x (1 + scale_err) + N(0, (a_lin |d|)^2)``, ``d_theta (1 + rot_scale_err) +
N(0, (a_rot |d_theta| + a_rt |d|)^2)`` and integrated, so the odometry drifts like a
real wheel encoder (a systematic heading scale error bends the path).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from jaxslam.datasets.carmen import CarmenLog
from jaxslam.datasets.geometry import se2_between, se2_compose

__all__ = ["SimulatedLog", "corridor_world", "office_world", "raycast", "ring_path", "simulate"]


@dataclasses.dataclass(frozen=True, eq=False)
class SimulatedLog(CarmenLog):
    """A :class:`~jaxslam.datasets.carmen.CarmenLog` with ground truth: ``true_poses (S, 3)`` and ``walls (M, 4)``."""

    true_poses: np.ndarray | None = None
    walls: np.ndarray | None = None


def _box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def _wall_with_doors(x0, y0, x1, y1, doors: list[tuple[float, float]]):
    """A straight wall from (x0, y0) to (x1, y1) with gaps at fractions ``(start, end)``."""
    segments = []
    cut = 0.0
    for start, end in sorted(doors):
        if start > cut:
            segments.append((x0 + (x1 - x0) * cut, y0 + (y1 - y0) * cut, x0 + (x1 - x0) * start, y0 + (y1 - y0) * start))
        cut = end
    if cut < 1.0:
        segments.append((x0 + (x1 - x0) * cut, y0 + (y1 - y0) * cut, x1, y1))
    return segments


def office_world(
    width: float = 16.0,
    height: float = 10.0,
    corridor: float = 2.0,
    rooms_x: int = 3,
    door: float = 0.9,
    pillar: float = 0.3,
    pillars_per_side: int = 3,
    seed: int = 0,
) -> np.ndarray:
    """Wall segments ``(M, 4)`` ``(x0, y0, x1, y1)`` of a ring corridor around rooms.

    The floor is ``[0, width] x [0, height]``; the room block is inset by ``corridor``
    and split into ``rooms_x`` rooms along x on two rows (top and bottom), each with a
    door onto the corridor. ``seed`` jitters the door positions and pillar sizes.
    """
    rng = np.random.default_rng(seed)
    walls: list[tuple[float, float, float, float]] = []
    walls += _box(0.0, 0.0, width, height)
    bx0, by0, bx1, by1 = corridor, corridor, width - corridor, height - corridor
    room_w = (bx1 - bx0) / rooms_x
    mid_y = 0.5 * (by0 + by1)
    # Bottom and top walls of the block, with one door per room.
    for y, row in ((by0, 0), (by1, 1)):
        doors = []
        for r in range(rooms_x):
            centre = (r + 0.5 + rng.uniform(-0.25, 0.25)) / rooms_x
            half = 0.5 * door / (bx1 - bx0)
            doors.append((centre - half, centre + half))
        walls += _wall_with_doors(bx0, y, bx1, y, doors)
    walls += [(bx0, by0, bx0, by1), (bx1, by0, bx1, by1), (bx0, mid_y, bx1, mid_y)]
    for r in range(1, rooms_x):
        x = bx0 + r * room_w
        walls += [(x, by0, x, by1)]
    # A desk in every room.
    for r in range(rooms_x):
        for y_lo, y_hi in ((by0, mid_y), (mid_y, by1)):
            cx = bx0 + (r + 0.5) * room_w + rng.uniform(-0.2, 0.2) * room_w
            cy = 0.5 * (y_lo + y_hi) + rng.uniform(-0.15, 0.15) * (y_hi - y_lo)
            walls += _box(cx - 0.4, cy - 0.25, cx + 0.4, cy + 0.25)
    # Pillars along the outer walls.
    for side in range(4):
        for p in range(pillars_per_side):
            f = (p + 0.5 + rng.uniform(-0.2, 0.2)) / pillars_per_side
            s = pillar * rng.uniform(0.8, 1.3)
            if side == 0:
                cx, cy = f * width, s / 2
            elif side == 1:
                cx, cy = width - s / 2, f * height
            elif side == 2:
                cx, cy = (1 - f) * width, height - s / 2
            else:
                cx, cy = s / 2, (1 - f) * height
            walls += _box(cx - s / 2, cy - s / 2, cx + s / 2, cy + s / 2)
    return np.asarray(walls, np.float64)


def corridor_world(
    x0: float, x1: float, y: float, width: float = 2.0, period: float = 3.0, door: float = 0.9, depth: float = 1.0,
) -> np.ndarray:
    """Wall segments ``(M, 4)`` of a straight corridor along x from ``x0`` to ``x1``,
    centred on ``y``, ``width`` wide, closed at ``x0``: both walls open every
    ``period`` metres onto a closet ``door`` wide and ``depth`` deep (centred in the
    period), the same on every period, so that a scan matches equally well wherever it
    is moved along the axis by a multiple of ``period`` (the corridor's ends aside)."""
    half = 0.5 * width
    walls: list[tuple[float, float, float, float]] = [(x0, y - half, x0, y + half)]
    for side in (1.0, -1.0):
        wall, back = y + side * half, y + side * (half + depth)
        for start in np.arange(x0, x1, period):
            d0 = start + 0.5 * (period - door)
            d1 = d0 + door
            walls += [(start, wall, d0, wall), (d0, wall, d0, back), (d0, back, d1, back), (d1, back, d1, wall),
                      (d1, wall, start + period, wall)]
    return np.asarray(walls, np.float64)


def ring_path(
    width: float, height: float, corridor: float, step: float, laps: float = 1.0, corner_radius: float = 0.6
) -> np.ndarray:
    """Poses ``(S, 3)`` every ``step`` metres along the corridor centre line (CCW).

    Starts in the middle of the bottom corridor heading +x; corners are quarter
    circles of ``corner_radius``.
    """
    c = 0.5 * corridor
    x0, y0, x1, y1 = c, c, width - c, height - c
    r = corner_radius
    pieces = []  # (kind, params, length)
    pieces.append(("line", (0.5 * (x0 + x1), y0, x1 - r, y0), x1 - r - 0.5 * (x0 + x1)))
    pieces.append(("arc", (x1 - r, y0 + r, -math.pi / 2), 0.5 * math.pi * r))
    pieces.append(("line", (x1, y0 + r, x1, y1 - r), y1 - y0 - 2 * r))
    pieces.append(("arc", (x1 - r, y1 - r, 0.0), 0.5 * math.pi * r))
    pieces.append(("line", (x1 - r, y1, x0 + r, y1), x1 - x0 - 2 * r))
    pieces.append(("arc", (x0 + r, y1 - r, math.pi / 2), 0.5 * math.pi * r))
    pieces.append(("line", (x0, y1 - r, x0, y0 + r), y1 - y0 - 2 * r))
    pieces.append(("arc", (x0 + r, y0 + r, math.pi), 0.5 * math.pi * r))
    pieces.append(("line", (x0 + r, y0, 0.5 * (x0 + x1), y0), 0.5 * (x0 + x1) - x0 - r))
    lap = sum(p[2] for p in pieces)
    total = lap * laps
    s_values = np.arange(0.0, total + 1e-9, step)
    poses = np.empty((s_values.shape[0], 3))
    bounds = np.cumsum([0.0] + [p[2] for p in pieces])
    for i, s in enumerate(s_values):
        s_lap = s % lap
        k = min(int(np.searchsorted(bounds, s_lap, side="right") - 1), len(pieces) - 1)
        kind, prm, length = pieces[k]
        u = (s_lap - bounds[k]) / max(length, 1e-12)
        if kind == "line":
            ax, ay, bx, by = prm
            poses[i] = (ax + u * (bx - ax), ay + u * (by - ay), math.atan2(by - ay, bx - ax))
        else:
            cx, cy, a0 = prm
            a = a0 + u * 0.5 * math.pi
            poses[i] = (cx + r * math.cos(a), cy + r * math.sin(a), a + 0.5 * math.pi)
    poses[:, 2] = (poses[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return poses


def raycast(walls: np.ndarray, origins: np.ndarray, headings: np.ndarray, max_range: float) -> np.ndarray:
    """Distances ``(S, B)`` from ``origins (S, 2)`` along ``headings (S, B)`` to the walls.

    Beams that hit nothing within ``max_range`` return ``inf``.
    """
    ax, ay, bx, by = (walls[:, i][None, None, :] for i in range(4))
    ex, ey = bx - ax, by - ay
    out = np.empty(headings.shape)
    for start in range(0, headings.shape[0], 64):
        sl = slice(start, start + 64)
        ox = origins[sl, 0][:, None, None]
        oy = origins[sl, 1][:, None, None]
        dx = np.cos(headings[sl])[..., None]
        dy = np.sin(headings[sl])[..., None]
        denom = dx * ey - dy * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((ax - ox) * ey - (ay - oy) * ex) / denom
            s = ((ax - ox) * dy - (ay - oy) * dx) / denom
        hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (s >= 0.0) & (s <= 1.0)
        t = np.where(hit, t, np.inf)
        out[sl] = t.min(-1)
    return np.where(out <= max_range, out, np.inf)


def simulate(
    *,
    width: float = 16.0,
    height: float = 10.0,
    corridor: float = 2.0,
    rooms_x: int = 3,
    laps: float = 1.25,
    speed: float = 0.5,
    rate: float = 5.0,
    num_beams: int = 180,
    fov: float = math.pi,
    max_range: float = 30.0,
    range_std: float = 0.01,
    laser_offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    odom_linear_std: float = 0.02,
    odom_angular_std: float = 0.02,
    odom_rt_std: float = 0.01,
    odom_scale_error: float = 0.01,
    odom_rot_scale_error: float = 0.03,
    seed: int = 0,
) -> SimulatedLog:
    """Simulate a robot driving the ring corridor of :func:`office_world`.

    Each keyword is one knob of the world, the path, the laser or the odometry noise,
    with a default; tests and benchmarks change one or two at a time.

    Args:
        width, height, corridor, rooms_x: world layout (m, count).
        laps: laps of the ring (> 1 closes the loop).
        speed: m/s; ``rate``: scans per second.
        num_beams, fov, max_range, range_std: the laser.
        laser_offset: laser pose in the robot frame.
        odom_*: odometry noise (see module docstring).
        seed: seeds the world jitter and all noise.

    Returns:
        A :class:`SimulatedLog`; its first true pose is the origin of its odometry.
    """
    rng = np.random.default_rng(seed)
    walls = office_world(width, height, corridor, rooms_x, seed=seed)
    true_poses = ring_path(width, height, corridor, speed / rate, laps)
    num_scans = true_poses.shape[0]
    angles = (-0.5 * fov + fov * np.arange(num_beams) / max(num_beams - 1, 1)).astype(np.float64)
    offset = np.asarray(laser_offset, np.float64)
    laser_poses = se2_compose(true_poses, np.broadcast_to(offset, true_poses.shape))
    headings = laser_poses[:, 2:3] + angles[None, :]
    ranges = raycast(walls, laser_poses[:, :2], headings, max_range)
    noisy = ranges + rng.normal(0.0, range_std, ranges.shape)
    no_return = ~np.isfinite(ranges)
    noisy = np.where(no_return, max_range, np.maximum(noisy, 1e-3))

    steps = se2_between(true_poses[:-1], true_poses[1:])
    lin = np.hypot(steps[:, 0], steps[:, 1])
    noisy_steps = steps.copy()
    noisy_steps[:, 0] = steps[:, 0] * (1 + odom_scale_error) + rng.normal(0, 1, lin.shape) * odom_linear_std * lin
    noisy_steps[:, 1] = steps[:, 1] + rng.normal(0, 1, lin.shape) * odom_linear_std * lin
    noisy_steps[:, 2] = steps[:, 2] * (1 + odom_rot_scale_error) + rng.normal(0, 1, lin.shape) * (
        odom_angular_std * np.abs(steps[:, 2]) + odom_rt_std * lin
    )
    odom = np.empty_like(true_poses)
    odom[0] = true_poses[0]
    for k in range(1, num_scans):
        odom[k] = se2_compose(odom[k - 1], noisy_steps[k - 1])

    times = 1000.0 + np.arange(num_scans) / rate
    valid = ~no_return
    resolution = fov / max(num_beams - 1, 1)
    log = SimulatedLog(
        path=Path("<simulated>"),
        message="FLASER",
        scan_times=times,
        logger_times=times - times[0],
        scan_lines=np.arange(1, num_scans + 1, dtype=np.int64),
        ranges=noisy.astype(np.float32),
        valid=valid,
        max_range_mask=no_return,
        angles=angles.astype(np.float32),
        angle_offsets=np.zeros(num_scans, np.float32),
        angular_resolution=float(resolution),
        max_range=float(max_range),
        laser_offset=offset,
        odom_poses=odom,
        laser_poses=se2_compose(odom, np.broadcast_to(offset, odom.shape)),
        odom_times=times.copy(),
        odom_readings=odom.copy(),
        params={},
        stats={"max_range_readings": int(no_return.sum())},
        problems=(),
        true_poses=true_poses,
        walls=walls,
    )
    return log
