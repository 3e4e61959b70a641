r"""Types of the grid SLAM filters: static config, traced params, state, info, inputs.

Both filters (:mod:`jaxslam.grid.gmapping` and :mod:`jaxslam.grid.srupf`) hold, per
particle, a pose, a lower pose factor (SRUPF-GM only; zeros for GMapping), a
log-weight, GMapping's accumulated log-likelihood (to pick the best particle, as
``weightSum``) and a paged ``int8`` map (:mod:`jaxslam.grid.paged`). One step
consumes an odometry increment (control, :class:`Odometry`) and one laser scan
(observation, :class:`Scan`); the shared parts of the step are in
:mod:`jaxslam.grid.filter`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core.spec import ParamSpec, at_least, fraction, positive, real
from jaxslam.grid.paged import MapStatus, PagedLayout, PagedMaps


@dataclass(frozen=True)
class GridSlamConfig:
    """Static configuration (shapes and branches); hashable, closed over by ``jit``.

    Attributes:
        num_particles: particles ``P``.
        layout: paged-map geometry (resolution, tile size, page table, pool size).
        window_range: static bound (m) on the usable range, sizing the window of
            tiles a scan can write (``params.usable_range`` is cropped to it).
        num_beams: beams per scan ``B``.
        max_points: ray-sample budget per scan (see :mod:`jaxslam.grid.update`).
        match_stride: scan matching and weighting use beams ``0, s, 2s, ...``.
        match_iterations: hill-climbing iterations (6 candidate poses each).
        coarse_iterations: coarse-to-fine matches: each hill climb first climbs this
            many iterations on the wide kernel of ``params.coarse_sigma`` and then its
            ``match_iterations`` on the narrow one from there
            (:func:`jaxslam.grid.filter.coarse_start`); 0 turns it off (the
            dataclass's default; :func:`jaxslam.grid.experiment.make_config` sets 4 for
            SRUPF-GM).
        coarse_tracking: with ``coarse_iterations``, the tracking's climbs get the
            coarse stage too (else only the particles' at keyframes).
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
        tracking: match every scan between keyframes against the best particle's
            map (:mod:`jaxslam.grid.tracking`); False moves the particles by the
            odometry alone between keyframes (GMapping).
        constrain_matches: the keyframe's pose correction (SRUPF-GM's corrector,
            the GMapping-style hill climb) moves the position only along the
            directions the scan constrains
            (:func:`jaxslam.grid.tracking.constrained_shift`), as the tracking does.
            :func:`jaxslam.grid.experiment.make_config` turns it on for SRUPF-GM and
            off for the GMapping-style filter (GMapping's own correction; the
            suite's measurement is in :mod:`jaxslam.grid.gmapping`).
        closure: where the tracking's match scores under ``closure_trigger``, search
            wide for a better one (:mod:`jaxslam.grid.closure`: a place mapped long
            ago, met again metres and degrees off), with its watch and undo. Off here;
            :func:`jaxslam.grid.experiment.make_config` turns it on for SRUPF-GM and
            leaves it off for the GMapping-style filter (measured in the module
            docstring); ``jaxslam run --loop-closure`` / ``--no-loop-closure`` choose.
        closure_radius: the search's reach in position (m, each axis; the choice
            of 6 m is explained in :mod:`jaxslam.grid.closure`).
        closure_turn: the search's reach in heading (rad, either way).
        closure_radius_far: the longest reach in position (m, a disc) of the search
            that grows with the odometry distance since the last closure
            (``closure_reach_rate``, :mod:`jaxslam.grid.closure`): a second coarse
            stage, run only where that reach exceeds ``closure_radius``; at or below
            ``closure_radius`` there is none.
        recover_radius: where the tracking's match is refused, search this far (m,
            each axis) around its guess for the scan's pose, an odometry that jumped
            (:mod:`jaxslam.grid.recovery`, which has the rule and what it was
            measured to do; :data:`jaxslam.grid.recovery.RECOVER_RADIUS` is the radius
            measured); 0: off. :func:`jaxslam.grid.experiment.make_config` sets
            SRUPF-GM's default (:func:`jaxslam.grid.experiment.recover_default`).
    """

    num_particles: int
    layout: PagedLayout
    num_beams: int
    max_points: int
    match_stride: int = 1
    match_iterations: int = 8
    coarse_iterations: int = 0
    coarse_tracking: bool = True
    refine_steps: int = 0
    matcher: str = "hill"
    correction: str = "pc"
    sampling: str = "prior"
    resampler: str = "systematic"
    score_kernel: str = "gaussian3"
    free_check: bool = True
    window_range: float = 20.0
    tracking: bool = True
    constrain_matches: bool = True
    closure: bool = False
    closure_radius: float = 6.0
    closure_turn: float = 0.14
    closure_radius_far: float = 10.0
    recover_radius: float = 0.0

    def __post_init__(self):
        choices = {
            "matcher": ("hill", "ellipse", "gradient"),
            "correction": ("pc", "npc"),
            "sampling": ("prior", "posterior"),
            "score_kernel": ("bilinear", "gaussian2", "gaussian3"),
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"GridSlamConfig.{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.num_particles < 1 or self.num_beams < 1 or self.max_points < 1 or self.match_stride < 1:
            raise ValueError("num_particles, num_beams, max_points and match_stride must be >= 1")
        if self.coarse_iterations < 0:
            raise ValueError(f"coarse_iterations must be >= 0, got {self.coarse_iterations}")
        if not self.recover_radius >= 0:
            raise ValueError(f"recover_radius must be >= 0 (0: off), got {self.recover_radius}")
        if not self.window_range > 0:
            raise ValueError(f"window_range must be > 0, got {self.window_range}")

    @property
    def match_beams(self) -> np.ndarray:
        return np.arange(0, self.num_beams, self.match_stride)


class GridSlamParams(NamedTuple):
    """Traced parameters: a sweep over any of them never recompiles.

    Sensor: ``beam_angles (B,)``, ``laser_offset (3,)``, ``usable_range`` (m; beams are
    cropped here for the map and ignored beyond it for matching), ``score_range`` (m;
    a beam of range ``r`` counts ``min(1, (score_range / r)**2)`` beams in the match
    score and the log-likelihood, :func:`jaxslam.grid.filter.beam_weights`).
    Map (quantised log-odds steps): ``l_free``, ``l_occ``, ``l_max`` (clamp),
    ``occ_saturation`` (steps at which a cell scores 1), ``score_sigma`` (m, width of
    the ``gaussian3`` kernel), ``coarse_sigma`` (m, its width in the coarse stage of
    ``config.coarse_iterations``; 0.2236 m is GMapping's own kernel,
    ``exp(-d^2 / 0.05 m^2)``), ``coarse_radius`` (standard deviations of the
    prediction: with SRUPF-GM's ellipse matcher the coarse stage stays within this
    Mahalanobis distance of the predicted pose, as the matcher within
    ``ellipse_radius``; :func:`jaxslam.grid.matching.search_bound`),
    ``log_odds_unit`` (natural log-odds per step, for export).
    Matching: ``linear_step``, ``angular_step`` (GMapping's lstep/astep),
    ``ellipse_radius`` and ``ellipse_step`` (first step; both in standard
    deviations of the prediction), ``ellipse_floor`` (m/rad added to the
    ellipse), ``learning_rate`` (optax refinement, in basis units), ``min_score``
    (at or below it the uncorrected pose is kept, GMapping's minimumScore, as a
    fraction of the matched beams; 0 as in GMapping: every match that found a wall
    is taken).
    Keyframes (GMapping's linearUpdate, angularUpdate, temporalUpdate; used by the
    per-scan step, :mod:`jaxslam.grid.tracking`): ``linear_update`` (m),
    ``angular_update`` (rad), ``temporal_update`` (s; negative: off);
    ``track_min_score``: the tracking match between keyframes replaces the odometry
    only above this score (fraction of matched beams; a wall seen once scores at most
    half, so scans a metre apart in corridors score 0.1-0.3 when right); ``track_min_curvature``: its
    position correction is kept only along directions where the score's curvature
    (information, per m^2) reaches this (:func:`jaxslam.grid.tracking.constrained_shift`);
    ``track_noise_scale``: the proposals' motion noise with tracking, as a fraction of
    the odometry model's (:func:`jaxslam.grid.tracking.tracked_noise_scale`);
    ``track_refused_noise_scale``: that fraction instead for a keyframe whose interval
    holds a refused tracking match (:func:`refused_noise_default`; negative:
    ``track_noise_scale`` there too;
    :func:`jaxslam.grid.tracking.keyframe_noise_scale`);
    ``track_turn`` (rad): the tracking match also scores its guess turned by this much
    either way and climbs again from the better one when it beats the converged match
    (0: never; a turn the odometry missed, see :func:`jaxslam.grid.tracking.track`).
    Loop closure (:mod:`jaxslam.grid.closure`, with ``config.closure``): a tracking
    match scoring under ``closure_trigger`` whose beams end in known free space for at
    least ``closure_conflict`` of them starts a wide search, whose best pose replaces
    it if it scores at least ``closure_min_score`` and ``closure_gain`` times the
    match (all fractions of the matched beams; a trigger of 0 turns the search off
    without recompiling) on ``closure_confirm`` scans in a row (the candidate's
    correction followed from scan to scan), moving the match by at most
    ``closure_jump`` (m) or ``closure_drift`` times the odometry distance since the
    last closure, whichever is more. The search reaches ``closure_reach_rate`` (m per m;
    0: the fixed reach) times that distance where this exceeds ``config.closure_radius``,
    up to ``config.closure_radius_far``. A closure taken is watched over the next
    ``closure_watch`` m of odometry: where the share of the tracking's beams ending in
    known free space averages over ``closure_undo`` there, the closure is undone and
    its correction refused (1: never; see :mod:`jaxslam.grid.closure`). Before the
    watch ends, a closure is undone as soon as that share averages over
    ``closure_undo_fast`` over at least two scans and a fifth of the watch (1: never,
    the default; measured in :mod:`jaxslam.grid.closure`). While a closure is watched
    the search does not start (``closure_nest`` 0, the default), so that every closure
    is judged on its own scans; 1 lets a closure be taken inside another's watch.
    A closure still watched when the run ends is judged in the path reported on the
    scans it had: undone where their share averages over ``closure_undo_end`` (at least
    two scans; 1: never; :func:`jaxslam.grid.undone_closures.judge_at_end`).
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
    score_range: Array
    l_free: Array
    l_occ: Array
    l_max: Array
    occ_saturation: Array
    score_sigma: Array
    coarse_sigma: Array
    coarse_radius: Array
    log_odds_unit: Array
    linear_step: Array
    angular_step: Array
    ellipse_radius: Array
    ellipse_step: Array
    ellipse_floor: Array
    learning_rate: Array
    min_score: Array
    linear_update: Array
    angular_update: Array
    temporal_update: Array
    track_min_score: Array
    track_min_curvature: Array
    track_noise_scale: Array
    track_refused_noise_scale: Array
    track_turn: Array
    closure_trigger: Array
    closure_conflict: Array
    closure_min_score: Array
    closure_gain: Array
    closure_confirm: Array
    closure_drift: Array
    closure_reach_rate: Array
    closure_jump: Array
    closure_watch: Array
    closure_undo: Array
    closure_undo_fast: Array
    closure_nest: Array
    closure_undo_end: Array
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


GMAPPING_KEYFRAMES = (1.0, 0.5, -1.0)
"""GMapping's keyframe rule, ``(linearUpdate m, angularUpdate rad, temporalUpdate s)``
(a negative temporal update is off): the GMapping-style filter's default."""

DEFAULT_KEYFRAMES = (0.5, 0.5, -1.0)
"""The keyframe rule of SRUPF-GM (:func:`default_params`' default): GMapping's, but a
keyframe every 0.5 m of tracked travel instead of every metre
(:func:`jaxslam.grid.tracking.is_keyframe`). With 1 m, SRUPF-GM failed 2 of 30 whole
Intel runs (a relation off by more than 1 m) and 6 of 100 runs of Intel's last 2623
scans from one filter state (``benchmarks/grid_stress.py``): keyframe corrections of
0.1-0.3 m along the narrow corridor south of the interior rooms, new ground whose
walls the maps held from keyframes a metre apart. With 0.5 m: none of 100 such runs
and none of 30 whole runs failed, MIT Killian scored 1.01-1.50 m against 1.52-2.06 m
(seeds 0-2), FR079 0.037-0.038 m against 0.034-0.035 m, the perturbed logs as before
or better but for one Seattle seed (0.144 against 0.062 m), and a run takes about a
third longer. Stressed from four filter states that its
own parameters made (``--own-base``), 0.5 m failed 1 of 80 runs, 1 m 4 of 80. The
GMapping-style filter keeps :data:`GMAPPING_KEYFRAMES`: with 0.5 m it failed 3 of 10
whole Intel runs against 2, and 16 of 120 stressed runs from its own states against
5 of 120."""


def default_keyframes(algorithm: str) -> tuple[float, float, float]:
    """The default keyframe rule of a grid filter (:data:`DEFAULT_KEYFRAMES`, or
    :data:`GMAPPING_KEYFRAMES` for ``"gmapping"``)."""
    return GMAPPING_KEYFRAMES if algorithm == "gmapping" else DEFAULT_KEYFRAMES


def refused_noise_default(algorithm: str) -> float:
    """``track_refused_noise_scale`` by default: 0.5 for SRUPF-GM (with the recovery
    from odometry jumps, :func:`jaxslam.grid.experiment.recover_default`; measured over
    the whole robustness suite, ``benchmarks/grid_robustness.py``), -1 (off: the
    proposals keep ``track_noise_scale`` after refused matches) for the other filters,
    which it was not measured on."""
    return 0.5 if algorithm == "srupf-gm" else -1.0


def default_params(
    beam_angles,
    laser_offset=(0.0, 0.0, 0.0),
    *,
    num_particles: int = 30,
    dtype=jnp.float32,
    algorithm: str = "srupf-gm",
    **overrides,
) -> GridSlamParams:
    """Defaults tuned on the raw Intel log (see ``benchmarks/``).

    The keyframe rule (``linear_update``, ``angular_update``, ``temporal_update``) is
    ``algorithm``'s (:func:`default_keyframes`): 0.5 m for SRUPF-GM, GMapping's 1 m
    for the GMapping-style filter.

    GMapping's defaults where they have a counterpart: ``srr=0.1, srt=0.2,
    str=0.1, stt=0.2``, ``lstep = astep = 0.05``, ``resampleThreshold = 0.5``.
    GMapping normalises its weights with ``gain = 1 / (ogain N)``, ``ogain = 3``,
    which flattens them as ``N`` grows (at 300-1000 particles the filter no longer
    selects); the default here is that gain at GMapping's default ``N = 30``,
    ``1/90``, for every ``N``. ``num_particles`` is kept for callers that want
    the GMapping rule: pass ``weight_gain=1 / (3 * N)``.

    ``usable_range`` 20 m with ``score_range`` 20 m (every beam weighs 1): the range
    of indoor logs. :func:`jaxslam.grid.experiment.run_grid_slam` chooses both from
    the log's readings unless they are given (:mod:`jaxslam.grid.range_rule`: both
    80 m where more than a tenth of the readings lie beyond 20 m).
    """
    values = {
        "beam_angles": np.asarray(beam_angles),
        "laser_offset": np.asarray(laser_offset),
        "usable_range": 20.0,
        "score_range": 20.0,
        "l_free": -1.0,
        "l_occ": 4.0,
        "l_max": 60.0,
        "occ_saturation": 8.0,
        "score_sigma": 0.05,
        "coarse_sigma": 0.2236,
        "coarse_radius": 5.0,
        "log_odds_unit": 0.2,
        "linear_step": 0.05,
        "angular_step": 0.05,
        "ellipse_radius": 5.0,
        "ellipse_step": 1.0,
        "ellipse_floor": np.array([0.01, 0.01, 0.005]),
        "learning_rate": 0.3,
        "min_score": 0.0,
        "linear_update": default_keyframes(algorithm)[0],
        "angular_update": default_keyframes(algorithm)[1],
        "temporal_update": default_keyframes(algorithm)[2],
        "track_min_score": 0.1,
        "track_min_curvature": 20.0,
        "track_noise_scale": 0.2,
        "track_refused_noise_scale": refused_noise_default(algorithm),
        "track_turn": 0.15,
        "closure_trigger": 0.25,
        "closure_conflict": 0.0,
        "closure_min_score": 0.35,
        "closure_gain": 1.5,
        "closure_confirm": 3.0,
        "closure_drift": 0.5,
        "closure_reach_rate": 0.02,
        "closure_jump": 0.5,
        "closure_watch": 5.0,
        "closure_undo": 0.11,
        "closure_undo_fast": 1.0,
        "closure_nest": 0.0,
        "closure_undo_end": 0.2,
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
    # NumPy leaves: the jitted programs take them as they are, whereas ``jnp.asarray``
    # runs (and compiles or loads) a conversion program per field, eagerly.
    real = np.dtype(dtype)
    return GridSlamParams(**{k: np.asarray(v, real) for k, v in values.items()})


class ClosureState(NamedTuple):
    r"""What the loop-closure search (:mod:`jaxslam.grid.closure`) carries from scan to
    scan, in the filter's float dtype.

    Attributes:
        held: ``(3,)`` the world correction :math:`C` of the candidate held from the
            scans before (the candidate pose is :math:`C \oplus x_0`).
        held_scans: ``()`` the scans in a row it won (0: no candidate held).
        travelled: ``()`` the odometry distance (m) since the last closure.
        applied: ``(3,)`` the correction :math:`A` of the last closure taken, as the
            tracking applied it (:func:`jaxslam.grid.closure.record_applied`).
        watch: ``()`` 1 while the last closure is watched, -1 once its correction was
            refused (undone), 0 neither.
        conflict_sum: ``()`` the sum of the watched scans' shares of beams ending in
            known free space.
        conflict_count: ``()`` the number of scans watched.
        before: ``()`` the odometry distance before the last closure (restored by an undo).
        found: ``(3,)`` the correction the search found for the last closure (an undone
            closure refuses candidates near it).
    """

    held: Array
    held_scans: Array
    travelled: Array
    applied: Array
    watch: Array
    conflict_sum: Array
    conflict_count: Array
    before: Array
    found: Array

    @classmethod
    def empty(cls, dtype) -> "ClosureState":
        """No candidate held, no closure taken, nothing travelled."""
        zero, pose = jnp.zeros((), dtype), jnp.zeros((3,), dtype)
        return cls(pose, zero, zero, pose, zero, zero, zero, zero, pose)


class GridSlamState(NamedTuple):
    """Filter state; ``maps.pool`` is the large buffer (donate it).

    ``status`` is non-zero after a step that could not be applied because the maps
    need a larger pool or page table (:mod:`jaxslam.grid.paged`); every later step is
    skipped until the host grows the maps and runs that step again.
    """

    poses: Array  # (P, 3)
    pose_sqrt_covs: Array  # (P, 3, 3) lower
    log_weights: Array  # (P,) normalised
    cumulative_log_likelihood: Array  # (P,) GMapping's weightSum
    maps: PagedMaps
    status: MapStatus
    motion: Array  # (3,) tracked motion since the last keyframe (jaxslam.grid.tracking)
    since_keyframe: Array  # (5,) distance, rotation, time, scans and refused tracking matches since the last keyframe
    closure: "ClosureState"  # the loop-closure search's memory (jaxslam.grid.closure)


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
    status: Array  # () int32 map status of this step (0: applied; see jaxslam.grid.paged)
    keyframe: Array  # () bool: this scan was a keyframe (the fields above are its update)
    motion: Array  # (3,) tracked motion since the last keyframe after this scan (0 at one)
    track_score: Array  # () tracking match score (fraction of matched beams)
    track_accepted: Array  # () bool: the tracking match replaced the odometry
    track_closed: Array  # () bool: the loop-closure search's pose replaced the local match, or a closure was undone
    track_conflict: Array  # () share of the tracking match's beams ending in known free space
    track_undo: Array  # (4,) a closure undone here: scans since it was taken, its correction (x, y, θ); else 0
    log_likelihood_increment: Array  # () log sum_m w_m p(z | x_m, m_m)^weight_gain of a keyframe applied here; else 0


class Odometry(NamedTuple):
    """Odometry between two keyframes (or two scans): the increment ``(3,)`` in the
    frame of the first, the number of laser scans it spans and the time it took (s;
    the temporal keyframe rule of the per-scan step). GMapping draws its motion noise
    once per scan; over ``n`` similar sub-steps the noise standard deviation of the
    whole increment is ``1/sqrt(n)`` of a single draw on it.

    ``noise_scale`` multiplies the motion-proportional noise of the proposal: the
    per-scan step (:mod:`jaxslam.grid.tracking`) sets it with tracking
    (:func:`jaxslam.grid.tracking.tracked_noise_scale`); ``None`` (no leaf) is 1, the
    wheel odometry's own noise."""

    increment: Array
    substeps: Array | float = 1.0
    dt: Array | None = None  # None (no leaf): stacked keyframe controls need not carry it
    noise_scale: Array | None = None  # None (no leaf): 1


def noise_scale_of(control: "Odometry", dtype) -> Array:
    """``control.noise_scale`` as an array (1 when not given)."""
    return jnp.asarray(1.0 if control.noise_scale is None else control.noise_scale, dtype)


def as_odometry(control) -> Odometry:
    """Accept a bare ``(3,)`` increment as one sub-step."""
    return control if isinstance(control, Odometry) else Odometry(control, 1.0)


class Scan(NamedTuple):
    """One laser scan: ranges ``(B,)``, the mask of usable hits ``(B,)`` and a shift
    of all beam angles (interleaved start angles of some ROBOTLASER1 logs)."""

    ranges: Array
    valid: Array
    angle_offset: Array | float = 0.0


__all__ = [
    "ClosureState",
    "GridSlamConfig",
    "GridSlamInfo",
    "GridSlamParams",
    "GridSlamState",
    "Odometry",
    "Scan",
    "as_odometry",
    "default_params",
    "refused_noise_default",
    "noise_scale_of",
]


_SRUPF = ("srupf-gm", "srupf-gm-npc")

PARAMETER_SPECS: dict[str, ParamSpec] = {
    "usable_range": positive("m", "beams are cropped here for the map and ignored beyond it for matching "
                                  "(chosen from the log's readings unless set)"),
    "score_range": positive("m", "a beam of range r counts min(1, (score_range / r)^2) beams in the score "
                                 "(chosen from the log's readings unless set)"),
    "l_free": ParamSpec("log-odds steps", "update of a cell a beam passes through", high=0.0),
    "l_occ": at_least(0.0, "log-odds steps", "update of the cell a beam ends in"),
    "l_max": positive("log-odds steps", "clamp of a cell's log-odds"),
    "occ_saturation": positive("log-odds steps", "log-odds at which a cell scores 1 in matching"),
    "score_sigma": positive("m", "width of the matching kernel"),
    "coarse_sigma": positive("m", "width of the matching kernel in the coarse stage"),
    "coarse_radius": positive("std", "reach of the coarse stage around the predicted pose"),
    "log_odds_unit": positive("1", "natural log-odds per step (map export)"),
    "linear_step": positive("m", "first step of the scan matcher in x and y (GMapping lstep)"),
    "angular_step": positive("rad", "first step of the scan matcher in heading (GMapping astep)"),
    "ellipse_radius": positive("std", "reach of the ellipse matcher around the prediction"),
    "ellipse_step": positive("std", "first step of the ellipse matcher"),
    "learning_rate": at_least(0.0, "1", "step of the gradient refinement of a match (basis units)"),
    "min_score": fraction("a match scoring at or below this keeps the uncorrected pose (GMapping minimumScore)"),
    "linear_update": at_least(0.0, "m", "a scan is a keyframe after this much tracked travel (linearUpdate)"),
    "angular_update": at_least(0.0, "rad", "a scan is a keyframe after this much tracked rotation (angularUpdate)"),
    "temporal_update": real("s", "a scan is a keyframe after this many seconds; negative: off (temporalUpdate)"),
    "track_min_score": fraction("the tracking match replaces the odometry only above this score"),
    "track_min_curvature": at_least(0.0, "1/m^2", "score curvature a tracking correction needs along a direction"),
    "track_noise_scale": at_least(0.0, "1", "the proposals' motion noise with tracking, a fraction of the model's"),
    "track_refused_noise_scale": real("1", "that fraction after a refused tracking match; negative: "
                                           "track_noise_scale"),
    "track_turn": at_least(0.0, "rad", "the tracking match also tries its guess turned by this much; 0: never"),
    "closure_trigger": fraction("a tracking match scoring under this starts the loop-closure search; 0: off"),
    "closure_conflict": fraction("share of beams ending in known free space the search also needs"),
    "closure_min_score": fraction("a closure's pose must score at least this"),
    "closure_gain": at_least(0.0, "1", "a closure's pose must also score this many times the tracking match"),
    "closure_confirm": at_least(1.0, "scans", "scans in a row a closure must be confirmed on"),
    "closure_drift": at_least(0.0, "m/m", "a closure moves the match by at most this times the odometry distance"),
    "closure_reach_rate": at_least(0.0, "m/m", "the search's reach per metre of odometry since the last closure"),
    "closure_jump": at_least(0.0, "m", "a closure moves the match by at most this much or closure_drift times the odometry distance, whichever is more"),
    "closure_watch": at_least(0.0, "m", "odometry over which a closure taken is watched"),
    "closure_undo": fraction("a watched closure is undone where the free-space share averages over this; 1: never"),
    "closure_undo_fast": fraction("a watched closure is undone early where the free-space share is over this; 1: never"),
    "closure_nest": fraction("1 lets a closure be taken inside another's watch, 0 does not"),
    "closure_undo_end": fraction("a closure still watched at the end is undone over this share; 1: never"),
    "likelihood_floor": ParamSpec("1", "probability of a beam that hits no wall", low=0.0, high=1.0, low_open=True),
    "weight_gain": positive("1", "gain of the log-likelihood in the weights"),
    "resample_threshold": fraction("resample when the effective sample size falls under this times N"),
    "srr": at_least(0.0, "m/m", "translation noise per metre of translation (GMapping srr)",
                    algorithms=("gmapping",)),
    "srt": at_least(0.0, "m/rad", "translation noise per radian of rotation (GMapping srt)",
                    algorithms=("gmapping",)),
    "str": at_least(0.0, "rad/m", "rotation noise per metre of translation (GMapping str)", field="str_",
                    algorithms=("gmapping",)),
    "stt": at_least(0.0, "rad/rad", "rotation noise per radian of rotation (GMapping stt)",
                    algorithms=("gmapping",)),
    "q_linear": positive("m", "std of the constant motion noise in x and y", algorithms=_SRUPF),
    "q_angular": positive("rad", "std of the constant motion noise in heading", algorithms=_SRUPF),
    "q_linear_per_m": at_least(0.0, "m/m", "motion noise in x and y per metre travelled", algorithms=_SRUPF),
    "q_angular_per_rad": at_least(0.0, "rad/rad", "heading noise per radian turned", algorithms=_SRUPF),
    "q_angular_per_m": at_least(0.0, "rad/m", "heading noise per metre travelled", algorithms=_SRUPF),
    "ut_alpha": positive("1", "unscented transform: spread of the sigma points", algorithms=_SRUPF),
    "ut_beta": real("1", "unscented transform: prior knowledge of the distribution (2: Gaussian)",
                    algorithms=_SRUPF),
    "ut_kappa": real("1", "unscented transform: secondary scaling", algorithms=_SRUPF),
}
"""Every scalar parameter of the grid filters that ``jaxslam run --set NAME=VALUE``
accepts, by its command-line name (see :class:`GridSlamParams` for the model). Left
out: the log's beam angles and laser offset, and the vectors ``ellipse_floor``,
``match_noise``, ``initial_std`` (a calibration file may set those,
``jaxslam run --params``)."""
