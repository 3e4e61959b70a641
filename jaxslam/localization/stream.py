"""Online localization in a known map: odometry and scans one at a time, the pose at any time.

:class:`StreamingLocalizer` is the batch run (:func:`jaxslam.localization.experiment.localize`)
taken apart, as :class:`jaxslam.grid.stream.StreamingGridSlam` is for grid SLAM. Each
scan is one step of :func:`jaxslam.localization.monte_carlo.mcl`, its control the
odometry increment since the previous scan (zero for the first), its key the batch
run's key of that scan (``step_keys(key, n)[k]`` does not depend on ``n``).
:meth:`~StreamingLocalizer.add_scan` runs one jitted step; :meth:`~StreamingLocalizer.add_scans`
runs a chunk of scans as one ``lax.scan``, the batch run's program for a chunk of that
length (the batch run is this class fed its chunks). Same inputs, same trajectory,
whether fed scan by scan or in chunks (``tests/localization/test_stream.py``).

The odometry pose of a scan is given with it, or interpolated from the odometry
messages received so far (:meth:`~StreamingLocalizer.add_odometry`; a scan waits until
odometry at or after its stamp has arrived).

Example::

    loc = StreamingLocalizer(load_map("runs/intel"), beam_angles, max_range=30.0, particles=10000)
    for stamp, kind, data in messages:
        if kind == "odom":
            loc.add_odometry(stamp, data)           # (x, y, theta)
        else:
            loc.add_scan(stamp, data)               # ranges (B,)
    loc.pose(), loc.ess(), loc.particles_in_use(), loc.injections()
"""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.datasets.geometry import se2_between
from jaxslam.datasets.odometry_queue import OdometryQueue
from jaxslam.grid.mapfile import OccupancyMap
from jaxslam.grid.types import Scan
from jaxslam.localization.field import free_cell_centres, likelihood_field
from jaxslam.localization.monte_carlo import DEFAULTS, MclConfig, MclParams, default_params, mcl
from jaxslam.runtime.driver import step_keys
from jaxslam.runtime.keys import seed_key


def filter_inputs(grid: OccupancyMap, beam_angles, max_range: float, laser_offset=(0.0, 0.0, 0.0),
                  particles: int = 5000, overrides: dict | None = None, max_beams: int = 60,
                  min_particles: int | None = None, max_distance: float = 2.0,
                  dtype=np.float32) -> tuple[MclConfig, MclParams]:
    """The :class:`~jaxslam.localization.monte_carlo.MclConfig` and
    :class:`~jaxslam.localization.monte_carlo.MclParams` for a laser in a map.

    ``min_particles`` defaults to a fiftieth of the capacity (at least 100, at most the
    capacity); ``max_distance`` caps the likelihood field (m).
    """
    beam_angles = np.asarray(beam_angles, np.float64)
    if min_particles is None:
        min_particles = min(particles, max(100, particles // 50))
    config = MclConfig(capacity=int(particles), num_beams=int(beam_angles.shape[0]), max_beams=int(max_beams),
                       min_particles=int(min_particles))
    field = likelihood_field(grid, max_distance, dtype)
    free = free_cell_centres(grid, max_cells=1 << 20)
    params = default_params(field, free, beam_angles, float(max_range), np.asarray(laser_offset, np.float64),
                            **(overrides or {}))
    return config, params


@functools.partial(jax.jit, static_argnums=0)
def run_chunk(config: MclConfig, params: MclParams, state, keys, controls, observations):
    """``lax.scan`` of the filter's step over a chunk of scans: ``(state, info per scan)``."""
    step = mcl(config, params).step

    def body(carry, xs):
        key, control, observation = xs
        return step(key, carry, control, observation)

    return jax.lax.scan(body, state, (keys, controls, observations))


@functools.partial(jax.jit, static_argnums=0)
def run_step(config: MclConfig, params: MclParams, state, key, control, observation):
    """One step of the filter: ``(state, info)``."""
    return mcl(config, params).step(key, state, control, observation)


@functools.partial(jax.jit, static_argnums=0)
def init_state(config: MclConfig, params: MclParams, key, pose, pose_std):
    """The filter's start around ``pose`` (standard deviations ``pose_std``)."""
    return mcl(config, params).init(key, pose, pose_std)


@functools.partial(jax.jit, static_argnums=0)
def init_global(config: MclConfig, params: MclParams, key):
    """The filter's start spread uniformly over the map's free space."""
    return mcl(config, params).init(key)


class StreamingLocalizer:
    """Monte Carlo localization in ``grid`` fed one message at a time.

    Args:
        grid: the map (:func:`jaxslam.grid.mapfile.load_map`).
        beam_angles: (B,) beam angles of every scan in the laser frame (rad).
        max_range: the laser's range limit (m).
        laser_offset: (3,) laser pose in the robot frame.
        particles: the capacity (the number in use adapts, KLD).
        seed: the run's seed (the batch run's: initial draw and every step's key).
        initial_pose: ``(x, y, theta)`` in the map frame, or None for a uniform start.
        initial_std: standard deviations of the start around ``initial_pose``.
        overrides: ``jaxslam.localization.monte_carlo.DEFAULTS`` values to change.
        max_beams, min_particles: see :class:`~jaxslam.localization.monte_carlo.MclConfig`.
        dtype: float32 (default) or float64 (needs JAX's 64-bit mode).
    """

    def __init__(self, grid: OccupancyMap, beam_angles, max_range: float, laser_offset=(0.0, 0.0, 0.0), *,
                 particles: int = 5000, seed: int = 0, initial_pose=None, initial_std=(0.1, 0.1, 0.05),
                 overrides: dict | None = None, max_beams: int = 60, min_particles: int | None = None,
                 dtype=np.float32):
        self.dtype = np.dtype(dtype)
        self.config, self.params = filter_inputs(grid, beam_angles, max_range, laser_offset, particles, overrides,
                                                 max_beams, min_particles, dtype=dtype)
        self.num_beams = self.config.num_beams
        self.global_start = initial_pose is None
        key_init, self.key = jax.random.split(jnp.asarray(seed_key(seed)))
        if initial_pose is None:
            state = init_global(self.config, self.params, key_init)
        else:
            state = init_state(self.config, self.params, key_init, np.asarray(initial_pose, self.dtype),
                               np.asarray(initial_std, self.dtype))
        self.state = jax.block_until_ready(state)
        self._keys = None
        self.compile_s = 0.0
        self._compiled: set[int] = set()
        self.scan_times: list[float] = []
        self._last_odom: np.ndarray | None = None
        self._info: list[dict[str, np.ndarray]] = []  # per call, arrays with a leading scan axis
        self.counts = {"scans": 0, "scans_before_odometry": 0, "odometry_out_of_order": 0}
        self._odometry = OdometryQueue(self.counts)  # odometry, and scans waiting for it

    @property
    def params_used(self) -> dict[str, float]:
        """The scalar parameters of the filter (``DEFAULTS`` and the overrides)."""
        return {name: float(np.asarray(getattr(self.params, name))) for name in DEFAULTS}

    # ------------------------------------------------------------------ input

    def add_odometry(self, stamp: float, pose) -> list[bool]:
        """An odometry pose ``(x, y, theta)`` at ``stamp``; processes the scans it unblocks.

        Returns whether each scan processed now was a measurement (oldest first).
        """
        self._odometry.add_odometry(stamp, pose)
        return self._drain()

    def add_scan(self, stamp: float, ranges, valid=None, odom_pose=None, angle_offset: float = 0.0) -> list[bool]:
        """A scan at ``stamp``: ``ranges (B,)`` in m, ``valid (B,)`` usable hits (default:
        finite, positive and below the range limit). With ``odom_pose`` the scan is
        processed now; otherwise when odometry at or after ``stamp`` has arrived.

        Returns whether each scan processed now was a measurement (oldest first).
        """
        ranges, valid = self._checked(stamp, ranges, valid)
        if odom_pose is not None:
            pose = np.asarray(odom_pose, np.float64).reshape(3)
            return self._drain() + [bool(self._run(np.array([stamp]), ranges[None], valid[None], pose[None],
                                                   np.array([angle_offset]), one=True)[0])]
        self._odometry.add_scan(stamp, (ranges, valid, float(angle_offset)))
        return self._drain()

    def add_scans(self, stamps, ranges, valid, odom_poses, angle_offsets=None) -> np.ndarray:
        """A chunk of ``S`` scans with their odometry poses ``(S, 3)``, run as one compiled
        ``lax.scan`` (one program per chunk length). Returns ``(S,)`` bool: which
        scans were measurements."""
        stamps = np.asarray(stamps, np.float64).reshape(-1)
        ranges = np.asarray(ranges).reshape(stamps.shape[0], -1)
        if ranges.shape[1] != self.num_beams:
            raise ValueError(f"scans have {ranges.shape[1]} beams, the localizer was built for {self.num_beams}")
        valid = np.asarray(valid, bool).reshape(ranges.shape) & np.isfinite(ranges)
        offsets = np.zeros(stamps.shape[0]) if angle_offsets is None else np.asarray(angle_offsets).reshape(-1)
        return self._run(stamps, ranges, valid, np.asarray(odom_poses, np.float64).reshape(-1, 3), offsets)

    def _checked(self, stamp, ranges, valid):
        ranges = np.asarray(ranges, np.float64).reshape(-1)
        if ranges.shape[0] != self.num_beams:
            raise ValueError(f"scan at {stamp!r} has {ranges.shape[0]} beams, the localizer was built for "
                             f"{self.num_beams}")
        with np.errstate(invalid="ignore"):
            if valid is None:
                valid = np.isfinite(ranges) & (ranges > 0) & (ranges < float(self.params.max_range))
        return ranges, np.asarray(valid, bool).reshape(-1) & np.isfinite(ranges)

    def _drain(self) -> list[bool]:
        return [bool(self._run(np.array([stamp]), ranges[None], valid[None], pose[None], np.array([offset]),
                               one=True)[0])
                for stamp, (ranges, valid, offset), pose in self._odometry.ready()]

    # ------------------------------------------------------------------ filter

    def _step_keys(self, stop: int):
        if self._keys is None or stop > self._keys.shape[0]:
            size = 1024 if self._keys is None else 2 * self._keys.shape[0]
            while size < stop:
                size *= 2
            self._keys = np.asarray(step_keys(self.key, size))
        return self._keys

    def _run(self, stamps, ranges, valid, odom, offsets, one: bool = False) -> np.ndarray:
        count = stamps.shape[0]
        first = len(self.scan_times)
        previous = odom[:1] if self._last_odom is None else self._last_odom[None]
        increments = se2_between(np.concatenate([previous, odom[:-1]]), odom)
        real = self.dtype
        keys = self._step_keys(first + count)[first: first + count]
        scans = Scan(np.where(valid, ranges, 0.0).astype(real), valid, np.asarray(offsets, real))
        if one:
            args = (self.config, self.params, self.state, keys[0], increments[0].astype(real),
                    Scan(scans.ranges[0], scans.valid[0], scans.angle_offset[0]))
            function, length = run_step, 0
        else:
            args = (self.config, self.params, self.state, keys, increments.astype(real), scans)
            function, length = run_chunk, count
        if length not in self._compiled:
            compiling = time.perf_counter()
            function.lower(*args).compile()
            self.compile_s += time.perf_counter() - compiling
            self._compiled.add(length)
        self.state, info = function(*args)
        info = {name: np.asarray(value) for name, value in info._asdict().items() if name != "ancestors"}
        if one:
            info = {name: value[None] for name, value in info.items()}
        self._info.append(info)
        self.scan_times.extend(float(t) for t in stamps)
        self._last_odom = odom[-1].copy()
        self.counts["scans"] += count
        return info["updated"].astype(bool)

    # ------------------------------------------------------------------ output

    def info(self) -> dict[str, np.ndarray]:
        """Per-scan :class:`~jaxslam.localization.monte_carlo.MclInfo` fields (without
        ``ancestors``) of every scan so far, as arrays with a leading scan axis."""
        if not self._info:
            return {}
        if len(self._info) > 1:
            self._info = [{name: np.concatenate([part[name] for part in self._info]) for name in self._info[0]}]
        return self._info[0]

    def trajectory(self) -> np.ndarray:
        """(S, 3) the estimate (the heaviest mode of the cloud) after every scan so far."""
        info = self.info()
        return np.asarray(info["estimate"], np.float64) if info else np.zeros((0, 3))

    def pose(self) -> np.ndarray:
        """(3,) the estimate after the latest scan."""
        return self.trajectory()[-1]

    def ess(self) -> float:
        """The effective sample size of the latest scan (before its resampling)."""
        return float(self.info()["ess"][-1])

    def particles_in_use(self) -> int:
        """The particles in use now (KLD-adaptive, at most the capacity)."""
        return int(self.state.num_active)

    def injections(self) -> int:
        """The resamplings so far that injected free-space particles (augmented MCL)."""
        info = self.info()
        return int(np.sum(info["injected"] > 0)) if info else 0

    def cloud(self, limit: int | None = None) -> np.ndarray:
        """(M, 3) the particles in use (at most ``limit`` of them, evenly picked)."""
        n = int(self.state.num_active)
        poses = np.asarray(self.state.poses[:n], np.float64)
        if limit is not None and n > limit:
            poses = poses[np.linspace(0, n - 1, limit).astype(np.int64)]
        return poses


__all__ = ["StreamingLocalizer", "filter_inputs", "init_global", "init_state", "run_chunk", "run_step"]
