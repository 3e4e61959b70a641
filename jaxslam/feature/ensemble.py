"""The same landmark filter for many seeds as one compiled program.

:func:`run_landmark_ensemble` runs RB-UPF or ERB-UPF once per seed of ``seeds``:
:func:`jaxslam.feature.filter.init` and :func:`jaxslam.runtime.driver.scan_steps` of
:func:`jaxslam.feature.filter.step` are ``vmap``-ed over the seeds' keys. Seed ``s`` uses exactly the keys of
the single-seed run (``PRNGKey(s)`` and :func:`jaxslam.runtime.driver.step_keys`), so member
``i`` is :func:`jaxslam.feature.experiment.run_landmark_slam` of ``seeds[i]``. The
compiled program is cached per static configuration
(:class:`~jaxslam.feature.params.Config`, dtype, shapes): a sweep over ``Params`` or
seeds of the same count never recompiles, because ``Params`` are traced.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.driver import best_particle, scan_steps
from jaxslam.feature import filter as feature_filter
from jaxslam.feature.experiment import ALGORITHMS, params_for
from jaxslam.feature.params import Config, Params


@dataclasses.dataclass
class LandmarkEnsembleResult:
    """Outcome of :func:`run_landmark_ensemble` (host arrays, leading axis = seed).

    Attributes:
        algorithm, particles, seeds, steps: what was run.
        trajectory: ``(S, T, 3)`` weighted mean pose after each step.
        pose_covs: ``(S, T, 3, 3)`` weighted covariance of the particle poses.
        info: every :class:`~jaxslam.feature.filter.Info` field, ``(S, T, ...)``.
        landmarks: ``(S,)`` landmarks of each seed's best particle at the end
            (:func:`jaxslam.runtime.driver.best_particle`).
        state: the final :class:`~jaxslam.feature.filter.State` of every seed.
        wall_s: run time after compilation [s] (all seeds together).
        compile_s: compilation time [s] (0 when the program was cached).
        params: the parameters used.
        config: the static configuration used.
        particle_poses: ``(S, T, N, 3)`` every particle's pose after each step's
            resampling (with ``record_poses``; None otherwise): with ``info["ancestors"]``
            the input of :func:`jaxslam.metrics.particle_diagnostics.ancestral_path`.
    """

    algorithm: str
    particles: int
    seeds: tuple[int, ...]
    steps: int
    trajectory: np.ndarray
    pose_covs: np.ndarray
    info: dict[str, np.ndarray]
    landmarks: np.ndarray
    state: Any
    wall_s: float
    compile_s: float
    params: Params
    config: Config
    particle_poses: np.ndarray | None = None

    @property
    def resamplings(self) -> np.ndarray:
        """``(S,)`` resampling steps of each seed."""
        return self.info["resampled"].sum(axis=1)


def _step_recording_poses(key, state, control, observation, params, config):
    """:func:`jaxslam.feature.filter.step` that also returns every particle's pose after
    the step (after its resampling)."""
    state, info = feature_filter.step(key, state, control, observation, params, config)
    return state, (info, state.poses)


def _one_seed(key, params, controls, observations, obs_mask, initial_pose, config, record_poses=False):
    state = feature_filter.init(key, params, config, initial_pose)
    observation = feature_filter.Observation(observations, obs_mask)
    step = _step_recording_poses if record_poses else feature_filter.step
    return scan_steps(step, key, state, controls, observation, params, config)


_PROGRAMS: dict[tuple[Config, bool], Any] = {}
_COMPILED: dict[Any, Any] = {}


def ensemble_program(config: Config, record_poses: bool = False):
    """The jitted ``(keys (S,), params, controls, observations, obs_mask, initial_pose)
    -> (final states, infos)`` for ``config``, built once per configuration; with
    ``record_poses`` the second output is ``(infos, particle poses (S, T, N, 3))``."""
    if (config, record_poses) not in _PROGRAMS:
        batched = jax.vmap(_one_seed, (0, None, None, None, None, None, None, None))
        _PROGRAMS[config, record_poses] = jax.jit(lambda *args: batched(*args, config, record_poses))
    return _PROGRAMS[config, record_poses]


def seed_keys(seeds: Sequence[int]) -> jax.Array:
    """``PRNGKey(s)`` for each seed, stacked: the keys the single-seed runs use."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must not be empty")
    if any(s < 0 for s in seeds):
        raise ValueError(f"seeds must be >= 0, got {seeds}")
    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def run_landmark_ensemble(
    sequence: Any,
    algorithm: str = "erb-upf",
    particles: int = 100,
    seeds: Sequence[int] = (0, 1, 2, 3, 4),
    params: Params | dict[str, Any] | None = None,
    config: dict[str, Any] | None = None,
    dtype: Any = jnp.float32,
    record_poses: bool = False,
) -> LandmarkEnsembleResult:
    """Run RB-UPF or ERB-UPF over a whole sequence for every seed as one program.

    Args:
        sequence: Victoria Park or simulator sequence (``controls``, ``observations``,
            ``obs_mask``; ``meta`` as for :func:`~jaxslam.feature.experiment.params_for`).
        algorithm: ``"erb-upf"`` or ``"rb-upf"`` (or ``"erb"``/``"rb"``).
        particles: particles per filter.
        seeds: PRNG seeds; member ``i`` equals
            ``run_landmark_slam(sequence, seed=seeds[i], ...)``.
        params: a full :class:`~jaxslam.feature.params.Params`, or a dict of overrides on
            :func:`~jaxslam.feature.experiment.params_for`.
        config: overrides of the :class:`~jaxslam.feature.params.Config` fields.
        dtype: float dtype of the filters.
        record_poses: also return every particle's pose after each step
            (``particle_poses``, ``S T N 3`` floats).

    Memory grows linearly with ``len(seeds)`` (every seed holds its particles' maps).
    """
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {sorted(ALGORITHMS)}, got {algorithm!r}")
    keys = seed_keys(seeds)
    if not isinstance(params, Params):
        params = params_for(sequence, **(params or {}))
    cfg = Config(num_particles=particles, proposal=ALGORITHMS[algorithm], **(config or {}))
    args = (
        keys,
        feature_filter.cast_params(params, dtype),
        jnp.asarray(sequence.controls, dtype),
        jnp.asarray(sequence.observations, dtype),
        jnp.asarray(sequence.obs_mask, bool),
        jnp.zeros(3, dtype),
    )
    signature = (cfg, record_poses, jax.tree_util.tree_map(lambda x: (jnp.shape(x), jnp.result_type(x)), args))
    compile_s = 0.0
    if signature not in _COMPILED:
        start = time.perf_counter()
        _COMPILED[signature] = ensemble_program(cfg, record_poses).lower(*args).compile()
        compile_s = time.perf_counter() - start
    compiled = _COMPILED[signature]
    start = time.perf_counter()
    state, outputs = jax.block_until_ready(compiled(*args))
    wall_s = time.perf_counter() - start
    infos, particle_poses = outputs if record_poses else (outputs, None)
    info = {name: np.asarray(value) for name, value in infos._asdict().items()}
    state = jax.tree_util.tree_map(np.asarray, state)
    best = [int(best_particle(jax.tree_util.tree_map(lambda x: x[i], state))) for i in range(len(keys))]
    return LandmarkEnsembleResult(
        algorithm=algorithm,
        particles=particles,
        seeds=tuple(int(s) for s in seeds),
        steps=int(np.shape(sequence.controls)[0]),
        trajectory=info["pose_estimate"],
        pose_covs=info["pose_cov"],
        info=info,
        landmarks=np.array([state.landmarks.count[i, b] for i, b in enumerate(best)]),
        state=state,
        wall_s=wall_s,
        compile_s=compile_s,
        params=jax.tree_util.tree_map(lambda x: np.asarray(x).tolist(), params),
        config=cfg,
        particle_poses=None if particle_poses is None else np.asarray(particle_poses),
    )
