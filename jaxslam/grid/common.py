r"""Configuration, parameters, state and shared steps of the grid SLAM filters.

Both filters (:mod:`jaxslam.grid.gmapping` and :mod:`jaxslam.grid.srupf`) hold, per
particle, a pose, a lower pose factor (SRUPF-GM only; zeros for GMapping), a
log-weight, GMapping's accumulated log-likelihood (to pick the best particle, as
``weightSum``) and a dense ``int8`` grid. One step consumes an odometry increment
(control) and one laser scan (observation):

1. proposal (filter specific) and scan matching against each particle's own map,
2. log-weights ``log w += weight_gain * log p(z | x, m)`` (see
   :func:`default_params`),
3. the scan is integrated into every grid at the corrected pose,
4. selective resampling when ``ESS < resample_threshold * N`` (Grisetti et al.
   2005/2007); grids are copied in place and only for the particles whose
   ancestor differs (:func:`resample_in_place`), so nothing is copied when no
   resampling happened.

``Info`` keeps, per step, the corrected (map) pose of every particle before
resampling and the ancestors, from which :func:`best_trajectory` rebuilds the path of
any final particle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core.resampling import (
    effective_sample_size,
    normalize_log_weights,
    selective_resample,
)
from jaxslam.grid.map import GridSpec, init_grids
from jaxslam.grid.score import ScoreModel, beam_points
from jaxslam.grid.update import update_grids


@dataclass(frozen=True)
class GridSlamConfig:
    """Static configuration (shapes and branches); hashable, closed over by ``jit``.

    Attributes:
        num_particles: particles ``P``.
        spec: grid geometry.
        num_beams: beams per scan ``B``.
        max_points: ray-sample budget per scan (see :mod:`jaxslam.grid.update`).
        match_stride: scan matching and weighting use beams ``0, s, 2s, ...``.
        match_iterations: hill-climbing iterations (6 candidate poses each).
        refine_steps: optax gradient steps after the search (0: none).
        matcher: ``"hill"`` (GMapping), ``"ellipse"`` (SRUPF-GM), ``"gradient"``.
        correction: SRUPF-GM only: ``"pc"`` (pose correction by the matcher) or
            ``"npc"`` (the best propagated sigma point, eq. 10).
        sampling: SRUPF-GM only: ``"prior"`` (draw after the odometry update, eq. 9,
            and correct the draw) or ``"posterior"`` (Algorithm 2's final draw).
        resampler: name of a :mod:`jaxslam.core.resampling` resampler.
        score_kernel: ``"bilinear"``, ``"gaussian2"`` or ``"gaussian3"``
            (:mod:`jaxslam.grid.score`).
        free_check: scale the evidence of a beam by the freeness of the cell just
            before its end point (GMapping's free-cell test).
    """

    num_particles: int
    spec: GridSpec
    num_beams: int
    max_points: int
    match_stride: int = 1
    match_iterations: int = 8
    refine_steps: int = 0
    matcher: str = "hill"
    correction: str = "pc"
    sampling: str = "prior"
    resampler: str = "systematic"
    score_kernel: str = "gaussian3"
    free_check: bool = True

    @property
    def match_beams(self) -> np.ndarray:
        return np.arange(0, self.num_beams, self.match_stride)


class GridSlamParams(NamedTuple):
    """Traced parameters: a sweep over any of them never recompiles.

    Sensor: ``beam_angles (B,)``, ``laser_offset (3,)``, ``usable_range`` (m; beams are
    cropped here for the map and ignored beyond it for matching).
    Map (quantised log-odds steps): ``l_free``, ``l_occ``, ``l_max`` (clamp),
    ``occ_saturation`` (steps at which a cell scores 1), ``score_sigma`` (m, width of
    the ``gaussian3`` kernel), ``log_odds_unit`` (natural log-odds per step, for
    export).
    Matching: ``linear_step``, ``angular_step`` (GMapping's lstep/astep),
    ``ellipse_radius`` and ``ellipse_step`` (first step; both in standard
    deviations of the prediction), ``ellipse_floor`` (m/rad added to the
    ellipse), ``learning_rate`` (optax refinement, in basis units), ``min_score``
    (below it the uncorrected pose is kept, GMapping's minimumScore, as a fraction
    of the matched beams).
    Weights: ``likelihood_floor`` (per-beam probability of a beam that hits no wall),
    ``weight_gain``, ``resample_threshold`` (ratio of N).
    GMapping motion: ``srr``, ``srt``, ``str_``, ``stt``.
    SRUPF-GM: ``q_linear``, ``q_angular`` (std of the constant Q), ``q_linear_per_m``,
    ``q_angular_per_rad``, ``q_angular_per_m`` (motion-proportional additions), ``ut_alpha``, ``ut_beta``,
    ``ut_kappa``, ``match_noise (3,)`` (std of the corrected pose, added to eq. 12 so
    that the downdate of eq. 16 leaves a positive definite factor; 0 gives the
    paper's literal update), ``initial_std (3,)``.
    """

    beam_angles: Array
    laser_offset: Array
    usable_range: Array
    l_free: Array
    l_occ: Array
    l_max: Array
    occ_saturation: Array
    score_sigma: Array
    log_odds_unit: Array
    linear_step: Array
    angular_step: Array
    ellipse_radius: Array
    ellipse_step: Array
    ellipse_floor: Array
    learning_rate: Array
    min_score: Array
    likelihood_floor: Array
    weight_gain: Array
    resample_threshold: Array
    srr: Array
    srt: Array
    str_: Array
    stt: Array
    q_linear: Array
    q_angular: Array
    q_linear_per_m: Array
    q_angular_per_rad: Array
    q_angular_per_m: Array
    ut_alpha: Array
    ut_beta: Array
    ut_kappa: Array
    match_noise: Array
    initial_std: Array


def default_params(
    beam_angles,
    laser_offset=(0.0, 0.0, 0.0),
    *,
    num_particles: int = 30,
    dtype=jnp.float32,
    **overrides,
) -> GridSlamParams:
    """Defaults tuned on the raw Intel log (see ``benchmarks/``).

    GMapping's defaults where they have a counterpart: ``srr=0.1, srt=0.2,
    str=0.1, stt=0.2``, ``lstep = astep = 0.05``, ``resampleThreshold = 0.5``.
    GMapping normalises its weights with ``gain = 1 / (ogain N)``, ``ogain = 3``,
    which flattens them as ``N`` grows (at 300-1000 particles the filter no longer
    selects); the default here is that gain at GMapping's default ``N = 30``,
    ``1/90``, for every ``N``. ``num_particles`` is kept for callers that want
    the GMapping rule: pass ``weight_gain=1 / (3 * N)``.
    """
    values = {
        "beam_angles": np.asarray(beam_angles),
        "laser_offset": np.asarray(laser_offset),
        "usable_range": 20.0,
        "l_free": -1.0,
        "l_occ": 4.0,
        "l_max": 60.0,
        "occ_saturation": 8.0,
        "score_sigma": 0.05,
        "log_odds_unit": 0.2,
        "linear_step": 0.05,
        "angular_step": 0.05,
        "ellipse_radius": 5.0,
        "ellipse_step": 1.0,
        "ellipse_floor": np.array([0.01, 0.01, 0.005]),
        "learning_rate": 0.3,
        "min_score": 0.15,
        "likelihood_floor": np.exp(-4.0),
        "weight_gain": None,
        "resample_threshold": 0.5,
        "srr": 0.1,
        "srt": 0.2,
        "str_": 0.1,
        "stt": 0.2,
        "q_linear": 0.02,
        "q_angular": 0.02,
        "q_linear_per_m": 0.06,
        "q_angular_per_rad": 0.06,
        "q_angular_per_m": 0.03,
        "ut_alpha": 1.0,
        "ut_beta": 2.0,
        "ut_kappa": 0.0,
        "match_noise": np.array([0.02, 0.02, 0.01]),
        "initial_std": np.array([1e-3, 1e-3, 1e-3]),
    }
    unknown = set(overrides) - set(values)
    if unknown:
        raise ValueError(f"unknown grid SLAM parameters: {sorted(unknown)}")
    values.update(overrides)
    if values["weight_gain"] is None:
        values["weight_gain"] = 1.0 / 90.0
    return GridSlamParams(**{k: jnp.asarray(v, dtype) for k, v in values.items()})


class GridSlamState(NamedTuple):
    """Filter state; ``grids`` is the large buffer (donate it)."""

    poses: Array  # (P, 3)
    pose_sqrt_covs: Array  # (P, 3, 3) lower
    log_weights: Array  # (P,) normalised
    cumulative_log_likelihood: Array  # (P,) GMapping's weightSum
    grids: Array  # (P, H, W) int8


class GridSlamInfo(NamedTuple):
    """Per-step diagnostics (stacked over time by ``run``)."""

    poses: Array  # (P, 3) corrected poses the maps were updated at (before resampling)
    log_weights: Array  # (P,) normalised, before resampling
    scores: Array  # (P,) match score at the corrected pose (fraction of matched beams)
    log_likelihoods: Array  # (P,)
    ancestors: Array  # (P,) int32
    resampled: Array  # () bool
    ess: Array  # ()
    dropped_points: Array  # () int32 ray samples past the budget
    pd_ok: Array  # (P,) bool: SRUPF downdate kept the factor PD (True for GMapping)


class Odometry(NamedTuple):
    """Odometry between two keyframes: the increment ``(3,)`` in the frame of the first
    and the number of laser scans it spans. GMapping draws its motion noise once per
    scan; over ``n`` similar sub-steps the noise standard deviation of the whole
    increment is ``1/sqrt(n)`` of a single draw on it."""

    increment: Array
    substeps: Array | float = 1.0


def as_odometry(control) -> Odometry:
    """Accept a bare ``(3,)`` increment as one sub-step."""
    return control if isinstance(control, Odometry) else Odometry(control, 1.0)


class Scan(NamedTuple):
    """One laser scan: ranges ``(B,)``, the mask of usable hits ``(B,)`` and a shift
    of all beam angles (interleaved start angles of some ROBOTLASER1 logs)."""

    ranges: Array
    valid: Array
    angle_offset: Array | float = 0.0


def scan_angles(observation: Scan, params: GridSlamParams) -> Array:
    """Beam angles ``(B,)`` of this scan in the laser frame."""
    return params.beam_angles + jnp.asarray(observation.angle_offset, params.beam_angles.dtype)


def score_model(params: GridSlamParams) -> ScoreModel:
    """The traced score settings of ``params``."""
    return ScoreModel(params.occ_saturation, params.score_sigma, params.likelihood_floor)


def match_geometry(observation: Scan, params: GridSlamParams, config: GridSlamConfig):
    """Local end points ``(M, 2)`` and mask ``(M,)`` of the beams used for matching."""
    idx = config.match_beams
    ranges = observation.ranges[idx].astype(params.beam_angles.dtype)
    valid = observation.valid[idx] & (ranges <= params.usable_range) & (ranges > 0)
    safe = jnp.where(valid, ranges, 0.0)
    return beam_points(safe, scan_angles(observation, params)[idx]), valid


def integrate_scan(grids: Array, poses: Array, observation: Scan, params: GridSlamParams, config: GridSlamConfig):
    """All particles' grids updated with one scan at ``poses``; also the dropped count."""
    return update_grids(
        grids,
        poses,
        observation.ranges.astype(poses.dtype),
        observation.valid,
        scan_angles(observation, params).astype(poses.dtype),
        params.laser_offset,
        config.spec,
        config.max_points,
        params.usable_range,
        params.l_free,
        params.l_occ,
        params.l_max,
    )


def init(
    params: GridSlamParams,
    config: GridSlamConfig,
    observation: Scan,
    initial_pose: Array | None = None,
) -> GridSlamState:
    """All particles at ``initial_pose`` with a map built from the first scan.

    ``initial_pose`` defaults to the origin; the pose factor starts at
    ``diag(params.initial_std)``. (No key: the initial state is deterministic.)
    """
    dtype = params.beam_angles.dtype
    n = config.num_particles
    pose = jnp.zeros((3,), dtype) if initial_pose is None else jnp.asarray(initial_pose, dtype)
    poses = jnp.broadcast_to(pose, (n, 3))
    sqrt_cov = jnp.diag(params.initial_std.astype(dtype))
    one, _ = integrate_scan(init_grids(1, config.spec), pose[None], observation, params, config)
    grids = jnp.broadcast_to(one, (n,) + config.spec.shape)
    return GridSlamState(
        poses=poses,
        pose_sqrt_covs=jnp.broadcast_to(sqrt_cov, (n, 3, 3)),
        log_weights=jnp.full((n,), -jnp.log(jnp.asarray(n, dtype))),
        cumulative_log_likelihood=jnp.zeros((n,), dtype),
        grids=grids,
    )


def finish_step(
    key: Array,
    state: GridSlamState,
    map_poses: Array,
    next_poses: Array,
    next_sqrt_covs: Array,
    log_likelihoods: Array,
    scores: Array,
    pd_ok: Array,
    observation: Scan,
    params: GridSlamParams,
    config: GridSlamConfig,
) -> tuple[GridSlamState, GridSlamInfo]:
    """Weights, map update at ``map_poses``, selective resampling (shared by filters)."""
    log_weights = normalize_log_weights(state.log_weights + params.weight_gain * log_likelihoods)
    cumulative = state.cumulative_log_likelihood + log_likelihoods
    # A data dependency from every read of the grids (matching, likelihoods) to the
    # map update, so that XLA orders the reads before the in-place write; without it
    # XLA copied the whole grid stack each step to keep the readers' view. (Float
    # ``x * 0`` is not folded away, and the where keeps NaNs out.)
    tie = jnp.sum(log_likelihoods) * 0.0 + jnp.sum(scores) * 0.0
    tie = jnp.where(jnp.isfinite(tie), tie, 0.0)
    grids, dropped = integrate_scan(state.grids, map_poses + tie, observation, params, config)
    ess = effective_sample_size(log_weights)
    ancestors, resampled, new_log_weights = selective_resample(
        key, log_weights, params.resample_threshold, config.resampler
    )
    # Particles are exchangeable, so the ancestors may be sorted; then the grids can
    # be resampled in place. Without resampling the ancestors are the identity and
    # no grid is copied (no lax.cond needed: XLA copied the grids through one).
    ancestors = jnp.sort(ancestors)
    grids = resample_in_place(grids, ancestors)
    new_state = GridSlamState(
        poses=next_poses[ancestors],
        pose_sqrt_covs=next_sqrt_covs[ancestors],
        log_weights=new_log_weights,
        cumulative_log_likelihood=cumulative[ancestors],
        grids=grids,
    )
    info = GridSlamInfo(
        poses=map_poses,
        log_weights=log_weights,
        scores=scores,
        log_likelihoods=log_likelihoods,
        ancestors=ancestors,
        resampled=resampled,
        ess=ess,
        dropped_points=dropped,
        pd_ok=pd_ok,
    )
    return new_state, info


def resample_in_place(buffers: Array, ancestors: Array) -> Array:
    """``buffers[ancestors]`` for non-decreasing ``ancestors``, without a second buffer.

    Two passes of row copies: first, in increasing order, the rows whose source lies
    after them (``a_i > i``), then, in decreasing order, those whose source lies
    before (``a_i < i``). For non-decreasing ``a`` no copy reads a row that an
    earlier copy overwrote: a pass-1 destination ``i`` cannot be the source of a
    pass-2 row ``k > i`` (that would need ``a_k = i < a_i``), and the source
    ``j = a_i`` of a pass-2 row satisfies ``a_j <= j``, so it was not overwritten in
    pass 1. Rows with ``a_i = i`` are not touched, so only the particles that change
    cost a copy, and the grids are never held twice.
    """
    n = buffers.shape[0]

    def copy(i, buf):
        row = jax.lax.dynamic_index_in_dim(buf, ancestors[i], 0, keepdims=False)
        return jax.lax.dynamic_update_index_in_dim(buf, row, i, 0)

    def forward(i, buf):
        return jax.lax.cond(ancestors[i] > i, copy, lambda _, b: b, i, buf)

    def backward(j, buf):
        i = n - 1 - j
        return jax.lax.cond(ancestors[i] < i, copy, lambda _, b: b, i, buf)

    buffers = jax.lax.fori_loop(0, n, forward, buffers)
    return jax.lax.fori_loop(0, n, backward, buffers)


def best_particle(state: GridSlamState) -> Array:
    """Index of the particle with the largest accumulated log-likelihood."""
    return jnp.argmax(state.cumulative_log_likelihood)


def best_trajectory(info_poses, info_ancestors, final_index: int) -> np.ndarray:
    """Corrected poses ``(T, 3)`` of the lineage of final particle ``final_index``.

    Args:
        info_poses: ``(T, P, 3)`` ``GridSlamInfo.poses`` stacked over steps.
        info_ancestors: ``(T, P)`` ``GridSlamInfo.ancestors``.
        final_index: index of a particle in the final state.
    """
    poses = np.asarray(info_poses)
    ancestors = np.asarray(info_ancestors)
    steps = poses.shape[0]
    out = np.empty((steps, 3), poses.dtype)
    idx = int(final_index)
    for t in range(steps - 1, -1, -1):
        idx = int(ancestors[t, idx])
        out[t] = poses[t, idx]
    return out


__all__ = [
    "GridSlamConfig",
    "GridSlamInfo",
    "GridSlamParams",
    "GridSlamState",
    "Odometry",
    "Scan",
    "as_odometry",
    "best_particle",
    "best_trajectory",
    "default_params",
    "finish_step",
    "init",
    "integrate_scan",
    "match_geometry",
    "resample_in_place",
    "score_model",
]


def scan_keyframes(step_fn, key, state, controls, observations, params, config):
    """Scan a filter's ``step`` over keyframes (one key per keyframe, split from ``key``)."""
    keys = jax.random.split(key, observations.ranges.shape[0])

    def body(carry, inputs):
        k, u, z = inputs
        return step_fn(k, carry, u, z, params, config)

    return jax.lax.scan(body, state, (keys, controls, observations))
