"""High-level landmark SLAM runs: RB-UPF / ERB-UPF on a sequence, with timing.

:func:`run_landmark_slam` takes any sequence with ``times``, ``controls (T, K, 3)``,
``observations (T, Z, 2)`` and ``obs_mask (T, Z)`` (Victoria Park or the simulator),
builds :class:`~jaxslam.feature.params.Params` for it (the paper's noise, the car
geometry from the sequence's ``meta``), runs the filter in jitted chunks with a
progress bar (:func:`jaxslam.runtime.progress.run_scan_chunked` with the chunk runner cached per
static config, :func:`jaxslam.runtime.driver.chunk_runner`; compilation timed apart) and
returns the trajectory, the map of the best particle (:func:`jaxslam.runtime.driver.best_particle`)
and the per-step ``Info`` as NumPy arrays.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.driver import best_particle, chunk_runner
from jaxslam.feature import filter as feature_filter
from jaxslam.feature.params import Config, Params
from jaxslam.runtime.keys import seed_key, split_keys
from jaxslam.models.vehicle import CarGeometry
from jaxslam.runtime.progress import run_scan_chunked

ALGORITHMS = {"erb-upf": "erb", "rb-upf": "rb", "erb": "erb", "rb": "rb"}


@dataclasses.dataclass
class LandmarkSlamResult:
    """Outcome of :func:`run_landmark_slam` (host arrays).

    Attributes:
        algorithm, particles, seed, steps: what was run.
        times: (T,) step times [s].
        trajectory: (T, 3) weighted mean pose after each step (for Victoria Park the
            laser's position and the car's heading).
        pose_covs: (T, 3, 3) weighted covariance of the particle poses.
        landmark_means: (M, 2) active landmarks of the best particle
            (:func:`jaxslam.runtime.driver.best_particle`).
        landmark_covs: (M, 2, 2) their covariances.
        info: every :class:`~jaxslam.feature.filter.Info` field, stacked over T.
        wall_s: run time after compilation [s].
        compile_s: compilation time [s].
        resamplings: number of resampling steps.
        params: the parameters used (floats).
        config: the static configuration used.
        state: the final :class:`~jaxslam.feature.filter.State` (host arrays: every
            particle's pose, factor, weight and map).
    """

    algorithm: str
    particles: int
    seed: int
    steps: int
    times: np.ndarray
    trajectory: np.ndarray
    pose_covs: np.ndarray
    landmark_means: np.ndarray
    landmark_covs: np.ndarray
    info: dict[str, np.ndarray]
    wall_s: float
    compile_s: float
    resamplings: int
    params: Params
    config: Config
    state: Any = None

    @property
    def landmarks(self) -> int:
        return int(self.landmark_means.shape[0])


def params_for(sequence: Any, **overrides: Any) -> Params:
    """Filter parameters for a sequence: the paper's defaults, the car geometry from
    ``sequence.meta`` (``car_geometry`` dict ``L, H, a, b`` for Victoria Park, pose =
    laser; or ``geometry`` ``(L, H, A, B)`` and the simulator's noise levels), then
    ``overrides``."""
    meta = getattr(sequence, "meta", {}) or {}
    values: dict[str, Any] = {}
    if "car_geometry" in meta:
        g = meta["car_geometry"]
        values["geometry"] = CarGeometry(g["L"], g["H"], g["L"] + g["a"], g["b"])
    elif "geometry" in meta:
        values["geometry"] = CarGeometry(*meta["geometry"])
    if meta.get("dataset") == "landmark-sim":
        for name in ("speed_std", "steering_std", "range_std", "bearing_std", "max_range", "fov"):
            values[name] = float(meta[name])
        values["sensor_offset"] = tuple(meta["sensor_offset"])
        # Simulated landmarks are at least `min_separation` apart, so an observation
        # is only new when it is far outside every gate (gate_new=20 suits a cluttered
        # outdoor scene, where a mismatch is likely; here a mismatch is rare and a
        # duplicate landmark is the error to avoid).
        values["gate_new"] = 100.0
    elif "max_range" in meta:
        values["max_range"] = float(meta["max_range"])
    values.update(overrides)
    return Params(**values)


def run_landmark_slam(
    sequence: Any,
    algorithm: str = "erb-upf",
    particles: int = 100,
    seed: int = 0,
    params: Params | dict[str, Any] | None = None,
    config: dict[str, Any] | None = None,
    progress: bool = True,
    chunk: int = 512,
    dtype: Any = jnp.float32,
    checkpoint: Any = None,
    callback: Any = None,
    callback_every: int | None = None,
) -> LandmarkSlamResult:
    """Run RB-UPF or ERB-UPF over a whole sequence.

    The keywords are independent choices of one run, each with a default (the Python
    face of ``jaxslam run``'s options for landmark data).

    Args:
        sequence: Victoria Park or simulator sequence.
        algorithm: ``"erb-upf"`` or ``"rb-upf"``.
        particles: number of particles.
        seed: PRNG seed (the same seed gives RB and ERB the same random streams).
        params: a full :class:`~jaxslam.feature.params.Params`, or a dict of overrides on
            :func:`params_for`.
        config: overrides of the :class:`~jaxslam.feature.params.Config` fields (capacity,
            update, ...).
        progress: show a progress bar and the compilation notice.
        chunk: scans per compiled chunk.
        dtype: float dtype of the filter (float64 needs ``jax_enable_x64``).
        checkpoint: passed to :func:`jaxslam.runtime.progress.run_scan_chunked` (resume/save).
        callback: passed to :func:`jaxslam.runtime.progress.run_scan_chunked`: called on the host
            as ``callback(carry, steps_done)`` after every chunk; the carry is
            ``(State, Params)``.
        callback_every: call ``callback`` every that many steps as well (the same
            compiled chunk: a live view runs the plain run's program).
    """
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {sorted(ALGORITHMS)}, got {algorithm!r}")
    if not isinstance(params, Params):
        params = params_for(sequence, **(params or {}))
    cfg = Config(num_particles=particles, proposal=ALGORITHMS[algorithm], **(config or {}))
    key = seed_key(seed)  # jax.random.PRNGKey(seed), made on the host (jaxslam.runtime.keys)
    steps = int(np.shape(sequence.controls)[0])
    state = feature_filter.init(key, params, cfg, jnp.zeros(3, dtype))
    params_arr = feature_filter.cast_params(params, dtype)
    xs = (
        split_keys(key, steps),
        jnp.asarray(sequence.controls, dtype),
        feature_filter.Observation(jnp.asarray(sequence.observations, dtype), jnp.asarray(sequence.obs_mask, bool)),
    )
    extra = {} if checkpoint is None else {"checkpoint": checkpoint}
    (state, _), infos, timing = run_scan_chunked(
        chunk_runner(feature_filter.step, cfg), (state, params_arr), xs, chunk=chunk, desc=algorithm,
        progress=progress, callback=callback, callback_every=callback_every, **extra,
    )
    state = jax.tree_util.tree_map(np.asarray, state)
    info = {name: np.asarray(value) for name, value in infos._asdict().items()}
    best = int(best_particle(state))
    table = jax.tree_util.tree_map(lambda x: np.asarray(x[best]), state.landmarks)
    return LandmarkSlamResult(
        algorithm=algorithm,
        particles=particles,
        seed=seed,
        steps=steps,
        times=np.asarray(sequence.times),
        trajectory=info["pose_estimate"],
        pose_covs=info["pose_cov"],
        landmark_means=table.means[table.active],
        landmark_covs=table.covs[table.active],
        info=info,
        wall_s=timing.wall_s,
        compile_s=timing.compile_s,
        resamplings=int(info["resampled"].sum()),
        params=jax.tree_util.tree_map(lambda x: np.asarray(x).tolist(), params),
        config=cfg,
        state=state,
    )
