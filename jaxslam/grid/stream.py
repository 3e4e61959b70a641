"""Online grid SLAM: odometry and scans one at a time, the map and pose at any time.

:class:`StreamingGridSlam` is the batch run (:func:`jaxslam.grid.experiment.run_grid_slam`)
taken apart. For each scan it

1. takes the odometry pose at the scan's stamp (given, or interpolated from the
   odometry messages received so far; a scan waits until odometry newer than it
   has arrived, so none is dropped);
2. runs one step of the filter module's per-scan step (``step``, the batch
   run's, :mod:`jaxslam.grid.tracking`): the scan is tracked against the best
   particle's map, and where the tracked motion reaches GMapping's linear, angular
   or temporal threshold the scan is a keyframe and the filter updates. The step is
   jitted alone with the batch run's per-step summary (:func:`step_runner`), with the
   same per-scan keys (``jax.random.split(PRNGKey(seed), n)[k]`` does not depend on
   ``n``). It compiles once; a recompilation happens only when the paged maps or the
   ray budget (``max_points``) must grow, as in the batch run.

Same inputs, same result: feeding a log scan by scan gives the batch run's keyframes,
keyframe poses, trajectory (the filter's pose of every scan) and map bit for bit (``tests/grid/test_stream.py``). The
map frame is the odometry frame; the filter starts at the first scan's odometry.

Example::

    slam = StreamingGridSlam(beam_angles, laser_offset, particles=30)
    for stamp, kind, data in messages:
        if kind == "odom":
            slam.add_odometry(stamp, data)          # (x, y, theta)
        else:
            slam.add_scan(stamp, data)              # ranges (B,)
    pose = slam.pose()                               # best particle, latest scan
    log_odds, resolution, origin = slam.map()
"""

from __future__ import annotations

import functools
import time
from types import SimpleNamespace
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.compiler import jit
from jaxslam.datasets.geometry import se2_between
from jaxslam.datasets.odometry_queue import OdometryQueue
from jaxslam.runtime.driver import step_keys
from jaxslam.grid import driver
from jaxslam.grid.algorithms import grid_algorithm
from jaxslam.grid.undone_closures import judge_at_end, reported_undo
from jaxslam.grid.experiment import KEYFRAME_PATHS, best_trajectory, keyframe_rule, map_layout
from jaxslam.grid.paged import stitch
from jaxslam.grid.tracking import scan_trajectory
from jaxslam.grid.types import GridSlamParams, Odometry, Scan
from jaxslam.grid.rays import required_points

__all__ = ["StreamingGridSlam", "step_runner"]


@functools.lru_cache(maxsize=16)
def step_runner(step_fn, config):
    """One jitted filter step with the batch run's per-step summary
    (:func:`jaxslam.grid.driver.summarise`); the carry ``(state, params)`` is donated."""

    def one(carry, key, control, observation):
        state, params = carry
        state, info = step_fn(key, state, control, observation, params, config)
        return (state, params), driver.summarise(info)

    return jit(one, donate_argnums=(0,))


def _budget(need: int, worst: int) -> int:
    """``need`` rounded up to a multiple of 1024, at most ``worst`` (rounded up likewise)."""
    return int(np.ceil(max(min(need, worst), 1) / 1024.0) * 1024)


class StreamingGridSlam:
    """A grid SLAM filter fed one message at a time.

    Args:
        beam_angles: (B,) beam angles of every scan in the laser frame (rad).
        laser_offset: (3,) laser pose in the robot frame.
        algorithm: ``"srupf-gm"``, ``"srupf-gm-npc"`` or ``"gmapping"``.
        particles: number of particles.
        seed: PRNG seed (the batch run's).
        params: values over the algorithm's params, by path (as for
            :func:`jaxslam.grid.experiment.run_grid_slam`).
        config: overrides of the static :class:`~jaxslam.grid.types.GridSlamConfig` fields.
        linear_update, angular_update, temporal_update: keyframe rule on the tracked
            motion (m, rad, s; GMapping's linearUpdate, angularUpdate,
            temporalUpdate; negative temporal disables it); ``None``: the filter's
            default (:func:`jaxslam.grid.experiment.keyframe_rule`).
        resolution: cell size (m).
        margin: the starting page table covers the first pose plus this many metres
            (it grows, with one recompilation, if the robot goes further; a page-table
            entry costs 4 bytes per 3.2 m tile and particle).
        max_points: ray samples per scan; default: twice what the first scan
            needs (at most what ``B`` beams at the usable range can need), doubled
            (one recompilation) when a later scan needs more. The result does not
            depend on it as long as no samples are dropped.
        dtype: float dtype of poses and params.
    """

    def __init__(
        self,
        beam_angles,
        laser_offset=(0.0, 0.0, 0.0),
        *,
        algorithm: str = "srupf-gm",
        particles: int = 30,
        seed: int = 0,
        params: dict[str, Any] | None = None,
        config: dict[str, Any] | None = None,
        linear_update: float | None = None,
        angular_update: float | None = None,
        temporal_update: float | None = None,
        resolution: float = 0.05,
        margin: float = 50.0,
        max_points: int | None = None,
        dtype=jnp.float32,
    ):
        self.algorithm = algorithm
        self.particles = int(particles)
        self.dtype = dtype
        self.rule = keyframe_rule(linear_update, angular_update, temporal_update, algorithm)
        self.resolution = float(resolution)
        self.margin = float(margin)
        self.entry = grid_algorithm(algorithm)
        overrides = dict(params or {})
        if "keyframes" not in overrides:
            for path, value in zip(KEYFRAME_PATHS, self.rule, strict=True):
                overrides.setdefault(path, value)
        self.params: GridSlamParams = self.entry.make_params(
            np.asarray(beam_angles), np.asarray(laser_offset, np.float64), dtype=dtype, values=overrides)
        self.num_beams = int(np.shape(beam_angles)[0])
        self.usable = float(self.params.sensor.usable_range)
        self._config_overrides = dict(config or {})
        self.window_range = float(self._config_overrides.pop("window_range", max(self.usable, 1.0)))
        self.max_points = max_points
        self.key = jax.random.PRNGKey(seed)
        self._keys = None
        self.config = None
        self.state = None
        self.stats = driver.RunStats()
        self.counts = {"scans": 0, "keyframes": 0, "scans_before_odometry": 0, "odometry_out_of_order": 0,
                       "recompilations": 0}
        self._odometry = OdometryQueue(self.counts)  # odometry, and scans waiting for it
        # Every processed scan; keyframes and the filter outputs per keyframe.
        self.scan_times: list[float] = []
        self.odom_poses: list[np.ndarray] = []
        self.keyframes: list[int] = []
        self._step_poses: list[np.ndarray] = []
        self._step_ancestors: list[np.ndarray] = []
        self.info: dict[str, list] = {"ess": [], "resampled": [], "mean_score": [], "best_score": [],
                                      "dropped_points": [], "pd_ok_fraction": []}
        # Per processed scan after the first: keyframe flag, tracked motion, closure undone.
        self._flags: list[bool] = []
        self._motions: list[np.ndarray] = []
        self._undos: list[np.ndarray] = []
        self.latency_s: list[float] = []  # wall time of each keyframe's add_scan

    # ------------------------------------------------------------------ input

    def add_odometry(self, stamp: float, pose) -> list[bool]:
        """An odometry pose ``(x, y, theta)`` at ``stamp``; processes the scans it unblocks.

        Returns the keyframe flags of the scans processed now (oldest first).
        """
        self._odometry.add_odometry(stamp, pose)
        return self._drain()

    def add_scan(self, stamp: float, ranges, valid=None, odom_pose=None, angle_offset: float = 0.0) -> list[bool]:
        """A scan at ``stamp``: ``ranges (B,)`` in m, ``valid (B,)`` usable hits (default:
        finite and positive). With ``odom_pose`` the scan is processed now; otherwise
        when odometry at or after ``stamp`` has arrived (see :meth:`add_odometry`).

        Returns the keyframe flags of the scans processed now (oldest first).
        """
        ranges = np.asarray(ranges, np.float64).reshape(-1)
        if ranges.shape[0] != self.num_beams:
            raise ValueError(f"scan at {stamp!r} has {ranges.shape[0]} beams, the mapper was built for "
                             f"{self.num_beams}")
        if valid is None:
            with np.errstate(invalid="ignore"):
                valid = np.isfinite(ranges) & (ranges > 0)
        valid = np.asarray(valid, bool).reshape(-1)
        if odom_pose is not None:
            return self._drain() + [self._process(float(stamp), ranges, valid, angle_offset,
                                                  np.asarray(odom_pose, np.float64).reshape(3))]
        self._odometry.add_scan(stamp, (ranges, valid, angle_offset))
        return self._drain()

    def _drain(self) -> list[bool]:
        return [self._process(stamp, ranges, valid, offset, pose)
                for stamp, (ranges, valid, offset), pose in self._odometry.ready()]

    # ------------------------------------------------------------------ filter

    def _scan(self, ranges, valid, offset) -> tuple[Scan, int]:
        valid = valid & np.isfinite(ranges)
        ranges = np.where(valid, ranges, 0.0)
        need = required_points(np.minimum(ranges, self.usable), valid, self.resolution)
        scan = Scan(jnp.asarray(ranges, self.dtype), jnp.asarray(valid), jnp.asarray(offset, self.dtype))
        return scan, need

    def _worst_case(self) -> int:
        return required_points(np.full(self.num_beams, self.usable), np.ones(self.num_beams, bool), self.resolution)

    def _step_keys(self, index: int):
        if self._keys is None or index >= self._keys.shape[0]:
            size = 1024 if self._keys is None else 2 * self._keys.shape[0]
            while size <= index:
                size *= 2
            # step_keys(key, n)[i] does not depend on n (threefry-partitionable
            # keys), so a longer table keeps the keys handed out so far.
            self._keys = step_keys(self.key, size)
        return self._keys[index]

    def _process(self, stamp, ranges, valid, offset, odom) -> bool:
        started = time.perf_counter()
        self.counts["scans"] += 1
        index = len(self.scan_times)
        scan, need = self._scan(ranges, valid, offset)
        if index == 0:
            self._start(scan, need, odom)
            keyframe = True
            self.keyframes.append(0)
        else:
            control = Odometry(np.asarray(se2_between(self.odom_poses[-1][None], odom[None])[0], self.dtype),
                               np.asarray(1.0, self.dtype), np.asarray(stamp - self.scan_times[-1], self.dtype))
            keyframe = self._step(control, scan, need)
            if keyframe:
                self.keyframes.append(index)
        self.scan_times.append(stamp)
        self.odom_poses.append(odom)
        if not keyframe:
            return False
        self.counts["keyframes"] += 1
        jax.block_until_ready(self.state)
        self.latency_s.append(time.perf_counter() - started)
        return True

    def _start(self, scan: Scan, need: int, odom: np.ndarray) -> None:
        if self.max_points is None:
            self.max_points = _budget(2 * need, self._worst_case())
        layout = map_layout(SimpleNamespace(odom_poses=odom[None]), np.array([0]), self.resolution, self.margin,
                            self.particles, self.window_range)
        self.config = self.entry.make_config(self.particles, layout, self.num_beams, self.max_points,
                                             window_range=self.window_range, **self._config_overrides)
        self.state, self.config = driver.init_state(self.key, self.params, self.config, scan,
                                                    jnp.asarray(odom, self.dtype), self.stats)
        self.configs_used = {self.config}

    def _step(self, control: Odometry, scan: Scan, need: int) -> bool:
        """One scan through the batch run's per-scan step (a chunk of one); returns
        whether it was a keyframe."""
        import dataclasses

        if need > self.config.max_points:  # a larger ray budget: one recompilation
            budget = _budget(max(need, 2 * self.config.max_points), self._worst_case())
            self.config = dataclasses.replace(self.config, max_points=budget)
            self.counts["recompilations"] += 1
        step = len(self._flags)
        key = self._step_keys(step)
        while True:
            runner = step_runner(self.entry.step, self.config)
            self.configs_used.add(self.config)
            # The runner donates its carry: keep what it returns.
            (self.state, self.params), ys = runner((self.state, self.params), key, control, scan)
            if int(ys["status"]) == 0:
                break
            # The maps are full: move or grow them (a growth recompiles) and run the step again.
            self.state, layout = driver._grown(self.state, self.config.layout, self.stats, step, False)
            if layout != self.config.layout:
                self.config = dataclasses.replace(self.config, layout=layout)
                self.counts["recompilations"] += 1
        ys = jax.device_get(ys)
        keyframe = bool(ys["keyframe"])
        self._flags.append(keyframe)
        self._motions.append(np.asarray(ys["motion"], np.float64))
        self._undos.append(np.asarray(ys["track_undo"], np.float64))
        if keyframe:
            self._step_poses.append(ys["poses"])
            self._step_ancestors.append(ys["ancestors"])
            for name in self.info:
                self.info[name].append(ys[name])
        return keyframe

    # ------------------------------------------------------------------ output

    def best_index(self) -> int:
        """The particle with the largest accumulated log-likelihood (GMapping's choice)."""
        return int(np.argmax(np.asarray(self.state.cumulative_log_likelihood)))

    def keyframe_poses(self) -> np.ndarray:
        """(K, 3) corrected keyframe poses of the best particle's lineage."""
        first = self.odom_poses[self.keyframes[0]][None]
        if len(self.keyframes) < 2:
            return first.copy()
        path = best_trajectory(np.stack(self._step_poses), np.stack(self._step_ancestors), self.best_index())
        return np.concatenate([first, np.asarray(path, np.float64)], 0)

    def trajectory(self) -> np.ndarray:
        """(S, 3) the filter's pose of every scan so far: its keyframe's corrected pose
        and the tracked motion since (as the batch run), a closure still watched judged
        on the scans so far (:func:`jaxslam.grid.undone_closures.judge_at_end`; a later scan may
        keep it)."""
        motions = np.stack(self._motions) if self._motions else np.zeros((0, 3))
        undos = np.stack(self._undos) if self._undos else np.zeros((0, 4))
        end = None if self.state is None else judge_at_end(jax.device_get(self.state.closure), self.params)
        return scan_trajectory(self.odom_poses[0], np.asarray(self._flags, bool), self.keyframe_poses()[1:],
                               motions, reported_undo(undos, end))[1]

    def pose(self) -> np.ndarray:
        """(3,) the best estimate of the latest scan's robot pose."""
        return self.trajectory()[-1]

    def map(self) -> tuple[np.ndarray, float, tuple[float, float]]:
        """``(log_odds (H, W) float32, resolution, origin)`` of the best particle's map
        (row 0 at ``origin`` y)."""
        best = self.best_index()
        maps = self.state.maps
        cells, origin = stitch(maps.pool, np.asarray(maps.tables)[best], maps.corner, self.config.layout)
        return cells.astype(np.float32) * float(self.params.map.log_odds_unit), self.config.layout.resolution, origin

    def step_versions(self) -> int:
        """How many static configurations the step ran under (each one compilation):
        1 unless the maps or the ray budget grew."""
        return len(getattr(self, "configs_used", ()))
