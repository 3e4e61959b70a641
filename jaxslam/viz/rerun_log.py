"""Log a SLAM run to Rerun (https://rerun.io): a ``.rrd`` file or a spawned viewer.

Everything lives in one 3-D scene (z = 0; look at it from the top) on the timeline
``scan`` (the index of the scan in the log), with ``stamp`` (the scan's time
stamp, s) beside it:

* ``world/map``: the best particle's occupancy grid as a ``GridMap`` in the ROS
  ``nav_msgs/OccupancyGrid`` convention (0..100 % occupied, 255 unknown), logged
  as it grows (once per chunk of keyframes);
* ``world/particles``: every particle's pose (points, with heading arrows);
* ``world/trajectory``: the best particle's path so far;
* ``world/scan``: the hits of the scan placed at the best particle's pose;
* ``world/landmarks`` (landmark runs): the best particle's landmarks and their
  3-sigma ellipses;
* ``health/ess`` and ``health/resampled``: effective sample size and resampling.

Hooks. :class:`GridLiveLog` follows a :func:`jaxslam.grid.experiment.run_grid_slam`
run through its ``checkpoint`` slot (called at the end of each chunk with the carry
and the outputs so far; it saves nothing); :meth:`RerunLog.landmark_callback` is a
``callback`` for :func:`jaxslam.feature.experiment.run_landmark_slam`;
:class:`LocalizationLiveLog` is the ``on_chunk`` hook of
:func:`jaxslam.localization.experiment.localize` (the map read back, the particle
cloud, the estimated path, particles in use and injections under ``health/``).

Rerun is an optional dependency; without it :func:`require_rerun` raises an
:class:`ImportError` that names ``pip install "jaxslam[viz]"``.

Rerun's native (Rust) logger writes its warnings straight to the process's standard
error, with ANSI colours, out of reach of Python's warnings and logging. Where this
module calls into it synchronously (creating, connecting and closing the recording),
:func:`native_messages_to_logging` catches what it writes there and passes each line,
without colours or timestamp, to the ``jaxslam.viz.rerun`` logger: one plain line on
the terminal, or wherever the program sends its logging.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import tempfile
from typing import Any

LOGGER = logging.getLogger("jaxslam.viz.rerun")
_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")
# Rerun's native line: "2026-01-01T00:00:00.000000Z  WARN re_log_types::app_id: message"
_NATIVE = re.compile(r"^(?:\S+Z\s+)?(TRACE|DEBUG|INFO|WARN|ERROR)\s+(?:[\w:]+:\s+)?(.*)$")
_LEVELS = {"TRACE": logging.DEBUG, "DEBUG": logging.DEBUG, "INFO": logging.INFO, "WARN": logging.WARNING,
           "ERROR": logging.ERROR}


@contextlib.contextmanager
def native_messages_to_logging():
    """Inside the block, what native code writes to file descriptor 2 is caught; at its
    end each caught line goes to the ``jaxslam.viz.rerun`` logger as
    ``jaxslam: rerun: <message>``, at the level the line names (warning when it names
    none), ANSI colours and timestamp removed."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no file descriptor 2 (an embedded interpreter): nothing to catch
        yield
        return
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            text = caught.read().decode("utf-8", errors="replace")
    for line in text.splitlines():
        line = _ANSI.sub("", line).strip()
        if not line:
            continue
        match = _NATIVE.match(line)
        level, message = (_LEVELS[match.group(1)], match.group(2)) if match else (logging.WARNING, line)
        LOGGER.log(level, "jaxslam: rerun: %s", message)

import numpy as np

INSTALL_HINT = 'pip install "jaxslam[viz]"'


def require_rerun():
    """The ``rerun`` module, or an ImportError naming the install command."""
    try:
        import rerun
    except ImportError as error:
        raise ImportError(f"the live view needs the Rerun SDK: {INSTALL_HINT}") from error
    return rerun


def occupancy_percent(log_odds: np.ndarray) -> np.ndarray:
    """``uint8`` (H, W), top row = largest y: ``round(100 p)`` and 255 where unknown (log-odds 0)."""
    lo = np.asarray(log_odds, np.float64)
    percent = np.rint(100.0 / (1.0 + np.exp(-lo))).astype(np.uint8)
    percent[lo == 0.0] = 255
    return np.ascontiguousarray(percent[::-1])


def ellipse_points(mean: np.ndarray, cov: np.ndarray, sigmas: float = 3.0, segments: int = 32) -> np.ndarray:
    """(segments + 1, 2) closed polyline ``{mean + sigmas L u : |u| = 1}``, ``L L^T = cov``."""
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    axes = vectors * np.sqrt(np.maximum(values, 0.0))[None, :]
    t = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    return mean[None, :] + sigmas * (np.cos(t)[:, None] * axes[:, 0] + np.sin(t)[:, None] * axes[:, 1])


def _xyz(xy: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return np.concatenate([xy, np.zeros((xy.shape[0], 1))], axis=1).astype(np.float32)


def application_id(name: str) -> str:
    """``name`` as a Rerun application id: characters other than ASCII letters, digits,
    space, ``-``, ``_`` and ``:`` (a path's ``/`` and ``.``) become ``-``.

    Rerun (0.41, the version of the ``viz`` extra) takes only such ids; it rewrites
    any other one itself, with a warning that its native logger prints straight to
    the terminal (raw ANSI colours), out of reach of Python's warnings and logging."""
    return re.sub(r"[^A-Za-z0-9 _:-]+", "-", name).strip() or "jaxslam"


class RerunLog:
    """One Rerun recording of a run.

    Args:
        path: write the recording to this ``.rrd`` file.
        spawn: also open (or connect to) a viewer.
        name: the recording's application id (as :func:`application_id` makes it valid).
    """

    def __init__(self, path: os.PathLike | str | None = None, spawn: bool = False, name: str = "jaxslam"):
        rr = require_rerun()
        if path is None and not spawn:
            raise ValueError("give a path for the .rrd file, spawn=True, or both")
        self.rr = rr
        with native_messages_to_logging():
            self.stream = rr.RecordingStream(application_id(name))
            sinks = []
            if path is not None:
                sinks.append(rr.FileSink(str(path)))
            if spawn:
                rr.spawn(connect=False)
                sinks.append(rr.GrpcSink())
            self.stream.set_sinks(*sinks)
        self.path = path

    def at(self, scan: int, stamp: float | None = None) -> None:
        """Put what follows on the timeline at scan index ``scan`` (and time ``stamp``)."""
        self.stream.set_time("scan", sequence=int(scan))
        if stamp is not None and np.isfinite(stamp):
            self.stream.set_time("stamp", duration=float(stamp))

    def grid_map(self, log_odds: np.ndarray, resolution: float, origin) -> None:
        self._map_image(occupancy_percent(log_odds), resolution, origin)

    def occupancy_map(self, grid) -> None:
        """A map read back (:class:`jaxslam.grid.mapfile.OccupancyMap`): its OccupancyGrid
        values (``-1`` unknown) as they are, turned by its origin's yaw."""
        values = np.asarray(grid.occupancy)
        image = np.where(values < 0, 255, np.clip(values.astype(np.int16), 0, 100)).astype(np.uint8)
        self._map_image(np.ascontiguousarray(image[::-1]), grid.resolution, grid.origin)

    def _map_image(self, image: np.ndarray, resolution: float, origin) -> None:
        """``image``: uint8 percent occupied (255 unknown), top row = largest y."""
        rr = self.rr
        height, width = image.shape
        yaw = float(origin[2]) if len(origin) > 2 else 0.0
        turn = rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=yaw) if yaw else None
        self.stream.log("world/map", rr.GridMap(
            data=image.tobytes(),
            format=rr.components.ImageFormat(width=width, height=height, color_model="L", channel_datatype="U8"),
            cell_size=float(resolution), translation=[float(origin[0]), float(origin[1]), -0.01],
            rotation_axis_angle=turn, colormap=rr.components.Colormap.RvizMap))

    def particles(self, poses: np.ndarray, arrow: float = 0.3) -> None:
        rr = self.rr
        poses = np.asarray(poses, np.float64).reshape(-1, 3)
        heads = np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=1) * arrow
        self.stream.log("world/particles", rr.Points3D(_xyz(poses[:, :2]), radii=0.05, colors=[255, 120, 0]))
        self.stream.log("world/particles/heading", rr.Arrows3D(origins=_xyz(poses[:, :2]), vectors=_xyz(heads),
                                                               colors=[255, 120, 0]))

    def trajectory(self, poses: np.ndarray) -> None:
        rr = self.rr
        self.stream.log("world/trajectory", rr.LineStrips3D([_xyz(np.asarray(poses)[:, :2])], colors=[30, 120, 255],
                                                            radii=0.03))

    def scan(self, pose, laser_offset, angles, ranges, valid) -> None:
        """The hits of one scan in the world, seen from robot pose ``pose``."""
        from jaxslam.datasets.geometry import se2_compose

        laser = se2_compose(np.asarray(pose, np.float64), np.asarray(laser_offset, np.float64))
        keep = np.asarray(valid, bool) & np.isfinite(ranges)
        r = np.asarray(ranges, np.float64)[keep]
        a = laser[2] + np.asarray(angles, np.float64)[keep]
        hits = np.stack([laser[0] + r * np.cos(a), laser[1] + r * np.sin(a)], axis=1)
        self.stream.log("world/scan", self.rr.Points3D(_xyz(hits), radii=0.03, colors=[220, 30, 30]))

    def health(self, ess: float, resampled: bool, particles: int | None = None, injected: int | None = None) -> None:
        self.stream.log("health/ess", self.rr.Scalars(float(ess)))
        self.stream.log("health/resampled", self.rr.Scalars(float(bool(resampled))))
        if particles is not None:
            self.stream.log("health/particles", self.rr.Scalars(float(particles)))
        if injected is not None:
            self.stream.log("health/injected", self.rr.Scalars(float(injected)))

    def landmarks(self, means: np.ndarray, covs: np.ndarray, sigmas: float = 3.0) -> None:
        rr = self.rr
        means = np.asarray(means, np.float64).reshape(-1, 2)
        covs = np.asarray(covs, np.float64).reshape(-1, 2, 2)
        self.stream.log("world/landmarks", rr.Points3D(_xyz(means), radii=0.15, colors=[0, 170, 0]))
        strips = [_xyz(ellipse_points(m, c, sigmas)) for m, c in zip(means, covs, strict=True)]
        self.stream.log("world/landmarks/ellipses", rr.LineStrips3D(strips, colors=[0, 170, 0], radii=0.02))

    def landmark_callback(self, times: np.ndarray, offset: int = 0):
        """A ``callback(carry, steps_done)`` for
        :func:`~jaxslam.feature.experiment.run_landmark_slam`: particles and the best
        particle's landmarks after each chunk."""

        from jaxslam.runtime.driver import best_particle

        def callback(carry, done):
            state = carry[0]
            step = int(done) - 1
            self.at(offset + step, float(times[step]) if step < len(times) else None)
            self.particles(np.asarray(state.poses))
            best = int(best_particle(state))
            active = np.asarray(state.landmarks.active[best])
            self.landmarks(np.asarray(state.landmarks.means[best])[active], np.asarray(state.landmarks.covs[best])[active])

        return callback

    def landmark_run(self, result, times: np.ndarray) -> None:
        """After a landmark run: trajectory, ESS and resampling at every step."""
        rr = self.rr
        steps = np.arange(result.trajectory.shape[0])
        self.stream.send_columns("health/ess", indexes=[rr.TimeColumn("scan", sequence=steps)],
                                 columns=rr.Scalars.columns(scalars=np.asarray(result.info["ess"], np.float64)))
        self.stream.send_columns("health/resampled", indexes=[rr.TimeColumn("scan", sequence=steps)],
                                 columns=rr.Scalars.columns(
                                     scalars=np.asarray(result.info["resampled"], np.float64)))
        self.at(int(steps[-1]), float(times[-1]) if len(times) else None)
        self.trajectory(result.trajectory)
        self.landmarks(result.landmark_means, result.landmark_covs)

    def close(self) -> None:
        with native_messages_to_logging():
            self.stream.flush()
            self.stream.disconnect()


def _summary_structure():
    """The pytree structure of a grid run's per-step outputs
    (:func:`jaxslam.grid.driver.summarise`), to name the leaves a checkpoint receives."""
    import jax
    import jax.numpy as jnp

    from jaxslam.grid.driver import summarise
    from jaxslam.grid.types import GridSlamInfo

    # shapes only: summarising arrays would compile a small program per output
    dummy = GridSlamInfo(*([jax.ShapeDtypeStruct((1,), jnp.float32)] * len(GridSlamInfo._fields)))
    return jax.tree_util.tree_structure(jax.eval_shape(summarise, dummy))


class GridLiveLog:
    """Follows a grid run chunk by chunk (through ``run_grid_slam``'s ``checkpoint`` slot).

    At the end of each chunk of ``every`` scans (the run's per-scan steps) it logs,
    for every keyframe of the chunk, the particles, ESS and resampling and the scan at
    the best lineage's pose, then the best particle's path and map. It writes no
    checkpoint file. The keyframes are the filter's own (``Info.keyframe``), collected
    in its ``keyframes`` array (scan indices) as the run goes. The laser mount and the log-odds unit come
    from the run's parameters (the second half of the carry), the map layout from
    ``static["layout"]`` (set by :func:`jaxslam.grid.driver.run_filter` before each
    stretch of the run).

    Args:
        viz: the :class:`RerunLog`.
        log: the :class:`~jaxslam.datasets.carmen.CarmenLog` being run (scans, stamps, beam angles).
        every: scans per chunk (map updates).
    """

    resume = False

    def __init__(self, viz: RerunLog, log, every=100):
        self.viz = viz
        self.log = log
        self.keyframes = np.zeros(1, np.int64)  # scan 0 starts the run
        self.every = int(every)
        self.static: dict[str, Any] = {}
        self._logged = 0
        self._first = True
        self._structure = _summary_structure()

    def due(self, done: int) -> bool:
        return True

    def _scan_at(self, scan: int, pose, laser_offset) -> None:
        log = self.log
        self.viz.scan(pose, laser_offset, log.beam_angles()[scan], np.asarray(log.ranges[scan], np.float64),
                      log.valid[scan])

    def save(self, carry, done: int, leaves: list) -> None:
        import jax

        from jaxslam.grid.experiment import best_trajectory
        from jaxslam.grid.paged import PagedLayout, stitch

        state, params = carry
        laser_offset = np.asarray(params.sensor.laser_offset, np.float64)
        unit = float(params.map.log_odds_unit)
        viz, times = self.viz, np.asarray(self.log.scan_times)
        odom0 = np.asarray(self.log.odom_poses[0], np.float64)
        if self._first:
            self._first = False
            viz.at(0, float(times[0]))
            self._scan_at(0, odom0, laser_offset)
        outputs = jax.tree_util.tree_unflatten(self._structure, [np.asarray(leaf) for leaf in leaves])
        best = int(np.argmax(np.asarray(state.cumulative_log_likelihood)))
        flags = np.asarray(outputs["keyframe"], bool)[: int(done)]
        rows = np.flatnonzero(flags)
        poses = outputs["poses"]
        path = best_trajectory(poses[rows], outputs["ancestors"][rows], best)
        path = np.concatenate([odom0[None], np.asarray(path, np.float64)], 0)
        self.keyframes = np.concatenate([[0], rows + 1]).astype(np.int64)
        for number, step in enumerate(rows):
            if step < self._logged:
                continue
            scan = int(step) + 1
            viz.at(scan, float(times[scan]))
            viz.particles(poses[step])
            viz.health(float(outputs["ess"][step]), bool(outputs["resampled"][step]))
            self._scan_at(scan, path[number + 1], laser_offset)
        viz.trajectory(path)
        layout = PagedLayout(**self.static["layout"])
        # the table row on the host: indexing the device array is a program of its own
        cells, origin = stitch(state.maps.pool, np.asarray(state.maps.tables)[best], state.maps.corner, layout)
        viz.grid_map(cells.astype(np.float32) * unit, layout.resolution, origin)
        self._logged = int(done)


class LocalizationLiveLog:
    """Follows a localization run chunk by chunk (the ``on_chunk`` hook of
    :func:`jaxslam.localization.experiment.localize`).

    The map once, then for every scan of a chunk the ESS, resampling, particles in use,
    injected particles and the scan at the estimate, and at the chunk's end the particle
    cloud (at most ``cloud_points`` of the particles in use) and the path so far.

    Args:
        viz: the :class:`RerunLog`.
        log: the log being localized (scans, stamps, beam angles, laser mount).
        grid: the map (:class:`jaxslam.grid.mapfile.OccupancyMap`).
        cloud_points: particles drawn per chunk.
    """

    def __init__(self, viz: RerunLog, log, grid, cloud_points: int = 5000):
        self.viz = viz
        self.log = log
        self.grid = grid
        self.cloud_points = int(cloud_points)
        self._first = True

    def __call__(self, localizer, lo: int, hi: int) -> None:
        viz, log = self.viz, self.log
        times = np.asarray(log.scan_times, np.float64)
        if self._first:
            self._first = False
            viz.at(lo, float(times[lo]))
            viz.occupancy_map(self.grid)
        info = localizer.info()
        path = localizer.trajectory()
        laser_offset = np.asarray(log.laser_offset, np.float64)
        angles = np.asarray(log.angles, np.float64)
        offsets = getattr(log, "angle_offsets", None)
        for scan in range(lo, hi):
            viz.at(scan, float(times[scan]))
            viz.health(float(info["ess"][scan]), bool(info["resampled"][scan]), int(info["particles"][scan]),
                       int(info["injected"][scan]))
            shift = 0.0 if offsets is None else float(offsets[scan])
            viz.scan(path[scan], laser_offset, angles + shift, np.asarray(log.ranges[scan], np.float64),
                     log.valid[scan])
        viz.particles(localizer.cloud(self.cloud_points))
        viz.trajectory(path[:hi])
