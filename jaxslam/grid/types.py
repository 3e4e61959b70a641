r"""Types of the grid SLAM filters: static config, traced params, state, info, inputs.

Both filters (:mod:`jaxslam.grid.gmapping` and :mod:`jaxslam.grid.srupf`) hold, per
particle, a pose, a lower pose factor (SRUPF-GM only; zeros for GMapping), a
log-weight, GMapping's accumulated log-likelihood (to pick the best particle, as
``weightSum``) and a paged ``int8`` map (:mod:`jaxslam.grid.paged`). One step
consumes an odometry increment (control, :class:`Odometry`) and one laser scan
(observation, :class:`Scan`); the shared parts of the step are in
:mod:`jaxslam.grid.filter`.

One module, over the usual length, because the params tree, its defaults and the
parameter specs that ``--set``, ``--list-params`` and the documentation read from are
one source: a part's fields, its defaults and the units and meanings of its leaves sit
side by side, so that none of them can drift from the others.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core.sigma import UTParams
from jaxslam.core.spec import ParamSpec, at_least, fraction, positive, real
from jaxslam.grid.paged import MapStatus, PagedLayout, PagedMaps


@dataclass(frozen=True)
class GridSlamConfig:
    """Static configuration (shapes and branches); hashable, closed over by ``jit``.

    Attributes:
        num_particles: particles ``P``.
        layout: paged-map geometry (resolution, tile size, page table, pool size).
        window_range: static bound (m) on the usable range, sizing the window of
            tiles a scan can write (``params.sensor.usable_range`` is cropped to it).
        num_beams: beams per scan ``B``.
        max_points: ray-sample budget per scan (see :mod:`jaxslam.grid.update`).
        match_stride: scan matching and weighting use beams ``0, s, 2s, ...``.
        match_iterations: hill-climbing iterations (6 candidate poses each).
        coarse_iterations: coarse-to-fine matches: each hill climb first climbs this
            many iterations on the wide kernel of ``params.matcher.coarse_sigma`` and then its
            ``match_iterations`` on the narrow one from there
            (:func:`jaxslam.grid.filter.coarse_start`); 0 turns it off (the
            dataclass's default; the registry entry of SRUPF-GM,
            :data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`, sets 4 for
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
            The registry (:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`) turns it on
            for SRUPF-GM and off for the GMapping-style filter (GMapping's own correction; the
            suite's measurement is in :mod:`jaxslam.grid.gmapping`).
        closure: where the tracking's match scores under ``params.closure.trigger``, search
            wide for a better one (:mod:`jaxslam.grid.closure`: a place mapped long
            ago, met again metres and degrees off), with its watch and undo. Off here;
            the registry turns it on for SRUPF-GM and
            leaves it off for the GMapping-style filter (measured in the module
            docstring); ``jaxslam run --loop-closure`` / ``--no-loop-closure`` choose.
        closure_radius: the search's reach in position (m, each axis; the choice
            of 6 m is explained in :mod:`jaxslam.grid.closure`).
        closure_turn: the search's reach in heading (rad, either way).
        closure_radius_far: the longest reach in position (m, a disc) of the search
            that grows with the odometry distance since the last closure
            (``params.closure.reach_rate``, :mod:`jaxslam.grid.closure`): a second coarse
            stage, run only where that reach exceeds ``closure_radius``; at or below
            ``closure_radius`` there is none.
        closure_map_bound: bound a closure's jump by the map's own offset as well: at
            most ``closure_reach_rate`` times the odometry distance since the last
            closure plus the sum of the corrections the closures kept so far (what
            the map drawn before them can be off by), and never more than the
            ``closure_drift`` bound (:func:`jaxslam.grid.closure.closure_outcome`);
            off: the ``closure_drift`` bound alone.
        recover_radius: where the tracking's match is refused, search this far (m,
            each axis) around its guess for the scan's pose, an odometry that jumped
            (:mod:`jaxslam.grid.recovery`, which has the rule and what it was
            measured to do; :data:`jaxslam.grid.recovery.RECOVER_RADIUS` is the radius
            measured); 0: off. SRUPF-GM's registry entry sets it
            (:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`).
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
    closure_map_bound: bool = False
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


class SensorParams(NamedTuple):
    """The laser: its beams, its pose on the robot and how far its readings count.

    Attributes:
        beam_angles: ``(B,)`` beam angles in the laser frame (rad); the log's.
        laser_offset: ``(3,)`` the laser's pose in the robot frame; the log's.
        usable_range: beams are cropped here for the map and ignored beyond it for
            matching (m). :func:`jaxslam.grid.experiment.run_grid_slam` chooses it from
            the log's readings unless it is given (:mod:`jaxslam.grid.range_rule`: 80 m
            where more than a tenth of the readings lie beyond 20 m); 20 m here, the
            range of indoor logs.
        score_range: a beam of range ``r`` counts ``min(1, (score_range / r)**2)``
            beams in the match score and the log-likelihood (m,
            :func:`jaxslam.grid.filter.beam_weights`); chosen with ``usable_range``.
    """

    beam_angles: Array
    laser_offset: Array | tuple = (0.0, 0.0, 0.0)
    usable_range: Array | float = 20.0
    score_range: Array | float = 20.0


class MapParams(NamedTuple):
    """The occupancy update, in quantised log-odds steps of the ``int8`` maps.

    Attributes:
        l_free: update of a cell a beam passes through.
        l_occ: update of the cell a beam ends in.
        l_max: clamp of a cell's log-odds.
        occ_saturation: log-odds at which a cell scores 1 in matching.
        log_odds_unit: natural log-odds per step (map export).
    """

    l_free: Array | float = -1.0
    l_occ: Array | float = 4.0
    l_max: Array | float = 60.0
    occ_saturation: Array | float = 8.0
    log_odds_unit: Array | float = 0.2


class MatcherParams(NamedTuple):
    """The scan matcher (:mod:`jaxslam.grid.matching`) and its score kernel.

    Attributes:
        score_sigma: width (m) of the ``gaussian3`` kernel.
        coarse_sigma: its width (m) in the coarse stage of ``config.coarse_iterations``;
            0.2236 m is GMapping's own kernel, ``exp(-d^2 / 0.05 m^2)``.
        coarse_radius: with SRUPF-GM's ellipse matcher the coarse stage stays within
            this Mahalanobis distance of the predicted pose, as the matcher within
            ``ellipse_radius`` (standard deviations;
            :func:`jaxslam.grid.matching.search_bound`).
        linear_step, angular_step: the hill climb's first steps (m, rad; GMapping's
            lstep and astep, 0.05).
        ellipse_radius, ellipse_step: the ellipse matcher's reach and first step, in
            standard deviations of the prediction.
        ellipse_floor: ``(3,)`` m/rad added to the ellipse.
        learning_rate: the optax refinement's step, in basis units.
        min_score: at or below it a keyframe keeps the uncorrected pose (GMapping's
            minimumScore, as a fraction of the matched beams; 0 as in GMapping: every
            match that found a wall is taken).
    """

    score_sigma: Array | float = 0.05
    coarse_sigma: Array | float = 0.2236
    coarse_radius: Array | float = 5.0
    linear_step: Array | float = 0.05
    angular_step: Array | float = 0.05
    ellipse_radius: Array | float = 5.0
    ellipse_step: Array | float = 1.0
    ellipse_floor: Array | tuple = (0.01, 0.01, 0.005)
    learning_rate: Array | float = 0.3
    min_score: Array | float = 0.0


class KeyframeParams(NamedTuple):
    """GMapping's keyframe rule on the tracked motion (:func:`jaxslam.grid.tracking.is_keyframe`).

    The defaults are GMapping's, the GMapping-style filter's; SRUPF-GM's registry entry
    (:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`) takes a keyframe every 0.5 m.

    Attributes:
        linear_update: a scan is a keyframe after this much tracked travel (m; linearUpdate).
        angular_update: ... or this much tracked rotation (rad; angularUpdate).
        temporal_update: ... or after this many seconds (s; temporalUpdate; negative: off).
    """

    linear_update: Array | float = 1.0
    angular_update: Array | float = 0.5
    temporal_update: Array | float = -1.0


class TrackingParams(NamedTuple):
    """The match of every scan against the best particle's map (:mod:`jaxslam.grid.tracking`).

    Attributes:
        min_score: the match replaces the odometry only above this score (a fraction
            of the matched beams; a wall seen once scores at most half, so scans a
            metre apart in corridors score 0.1-0.3 when right).
        min_curvature: its position correction is kept only along directions where
            the score's curvature (information, per m^2) reaches this
            (:func:`jaxslam.grid.tracking.constrained_shift`).
        noise_scale: the proposals' motion noise with tracking, as a fraction of the
            odometry model's (:func:`jaxslam.grid.tracking.tracked_noise_scale`).
        refused_noise_scale: that fraction instead for a keyframe whose interval holds
            a refused tracking match; negative (the default): ``noise_scale`` there too
            (:func:`jaxslam.grid.tracking.keyframe_noise_scale`; SRUPF-GM's registry
            entry sets 0.5).
        turn: the match also scores its guess turned by this much either way (rad) and
            climbs again from the better one when it beats the converged match (0:
            never; a turn the odometry missed, see :func:`jaxslam.grid.tracking.track`).
    """

    min_score: Array | float = 0.1
    min_curvature: Array | float = 20.0
    noise_scale: Array | float = 0.2
    refused_noise_scale: Array | float = -1.0
    turn: Array | float = 0.15


class ClosureParams(NamedTuple):
    """The loop-closure search, its watch and undo (:mod:`jaxslam.grid.closure`, with
    ``config.closure``).

    A tracking match scoring under ``trigger`` whose beams end in known free space for
    at least ``conflict`` of them starts a wide search, whose best pose replaces it if
    it scores at least ``min_score`` and ``gain`` times the match (all fractions of the
    matched beams; a trigger of 0 turns the search off without recompiling) on
    ``confirm`` scans in a row (the candidate's correction followed from scan to scan),
    moving the match by at most ``jump`` (m) or ``drift`` times the odometry distance
    since the last closure, whichever is more. The search reaches ``reach_rate`` (m per
    m; 0: the fixed reach) times that distance where this exceeds
    ``config.closure_radius``, up to ``config.closure_radius_far``. A closure taken is
    watched over the next ``watch`` m of odometry: where the share of the tracking's
    beams ending in known free space averages over ``undo`` there, the closure is
    undone and its correction refused (1: never). Before the watch ends, a closure is
    undone as soon as that share averages over ``undo_fast`` over at least two scans
    and a fifth of the watch (1: never, the default). While a closure is watched the
    search does not start (``nest`` 0, the default), so that every closure is judged on
    its own scans; 1 lets a closure be taken inside another's watch. A closure still
    watched when the run ends is judged in the path reported on the scans it had:
    undone where their share averages over ``undo_end`` (at least two scans; 1: never;
    :func:`jaxslam.grid.undone_closures.judge_at_end`). Until the first closure is
    taken, ``first_drift`` (m per m, the tracking's own drift; 0: off) bounds the jump
    more tightly, by that times the odometry distance since the start, or ``jump``
    where that is more (:func:`jaxslam.grid.closure.closure_outcome`). A held
    candidate's later scans need only ``confirm_gain`` times the match where that is
    positive (0: ``gain`` on every scan).
    """

    trigger: Array | float = 0.25
    conflict: Array | float = 0.0
    min_score: Array | float = 0.35
    gain: Array | float = 1.5
    confirm: Array | float = 3.0
    drift: Array | float = 0.5
    reach_rate: Array | float = 0.02
    jump: Array | float = 0.5
    watch: Array | float = 5.0
    undo: Array | float = 0.11
    undo_fast: Array | float = 1.0
    nest: Array | float = 0.0
    undo_end: Array | float = 0.2
    first_drift: Array | float = 0.02
    trigger_ratio: Array | float = 0.8
    confirm_gain: Array | float = 0.0


class WeightParams(NamedTuple):
    """The particles' weights and resampling.

    Attributes:
        likelihood_floor: per-beam probability of a beam that hits no wall.
        gain: gain of the log-likelihood in the weights. GMapping normalises its
            weights with ``gain = 1 / (ogain N)``, ``ogain = 3``, which flattens them
            as ``N`` grows (at 300-1000 particles the filter no longer selects); the
            default is that gain at GMapping's default ``N = 30``, ``1/90``, for every
            ``N`` (set ``1 / (3 N)`` for GMapping's rule).
        resample_threshold: resample when the effective sample size falls under this
            times ``N`` (GMapping's resampleThreshold).
    """

    likelihood_floor: Array | float = float(np.exp(-4.0))
    gain: Array | float = 1.0 / 90.0
    resample_threshold: Array | float = 0.5


class GMappingNoise(NamedTuple):
    """The GMapping-style filter's odometry noise (GMapping's defaults), per metre or
    radian of the motion (:mod:`jaxslam.grid.gmapping`).

    Attributes:
        srr: translation noise per metre of translation (m/m).
        srt: translation noise per radian of rotation (m/rad).
        str: rotation noise per metre of translation (rad/m).
        stt: rotation noise per radian of rotation (rad/rad).
    """

    srr: Array | float = 0.1
    srt: Array | float = 0.2
    str: Array | float = 0.1
    stt: Array | float = 0.2


class SrupfNoise(NamedTuple):
    """SRUPF-GM's noise (:mod:`jaxslam.grid.srupf`): the motion noise ``Q``, the
    matcher noise ``R`` and the pose factor's start.

    Attributes:
        q_linear, q_angular: standard deviations of the constant part of ``Q`` (m, rad).
        q_linear_per_m, q_angular_per_rad, q_angular_per_m: its motion-proportional
            parts (m/m, rad/rad, rad/m).
        match_noise: ``(3,)`` standard deviations of the corrected pose, added to eq. 12
            so that the downdate of eq. 16 leaves a positive definite factor (0 gives
            the paper's literal update).
        initial_std: ``(3,)`` the pose factor at the first scan, ``diag(initial_std)``.
    """

    q_linear: Array | float = 0.02
    q_angular: Array | float = 0.02
    q_linear_per_m: Array | float = 0.06
    q_angular_per_rad: Array | float = 0.06
    q_angular_per_m: Array | float = 0.03
    match_noise: Array | tuple = (0.02, 0.02, 0.01)
    initial_std: Array | tuple = (1e-3, 1e-3, 1e-3)


class GridSlamParams(NamedTuple):
    """Traced parameters of the grid filters, one part per component, each part with
    its defaults beside its fields: a sweep over any of them never recompiles.

    Build them with :meth:`GridSlamParams.create` (every leaf a NumPy array of one float dtype);
    :func:`get_path` and :func:`with_values` read and set a leaf by its path
    (``"closure.trigger"``), the names ``jaxslam run --set`` takes
    (:data:`PARAMETER_SPECS`). An algorithm's own defaults, where they differ from the
    parts', are its registry entry's (:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`).
    """

    sensor: SensorParams
    map: MapParams = MapParams()
    matcher: MatcherParams = MatcherParams()
    keyframes: KeyframeParams = KeyframeParams()
    tracking: TrackingParams = TrackingParams()
    closure: ClosureParams = ClosureParams()
    weights: WeightParams = WeightParams()
    gmapping: GMappingNoise = GMappingNoise()
    srupf: SrupfNoise = SrupfNoise()
    unscented: UTParams = UTParams()

    @classmethod
    def create(cls, beam_angles, laser_offset=(0.0, 0.0, 0.0), *, dtype=np.float32,
               values: Mapping[str, Any] | None = None) -> "GridSlamParams":
        """The parts' defaults for a laser of ``beam_angles`` at ``laser_offset``, with
        ``values`` (by path, :func:`with_values`) over them; every leaf a NumPy array of
        ``dtype`` (the jitted programs take them as they are, whereas ``jnp.asarray``
        would run, and compile or load, a conversion program per leaf, eagerly)."""
        params = cls(SensorParams(beam_angles, laser_offset))
        params = jax.tree_util.tree_map(lambda v: np.asarray(v, np.dtype(dtype)), params, is_leaf=_is_value)
        return with_values(params, values or {})


def _is_value(node) -> bool:
    """A leaf of the params tree: anything but a part (a tuple default is one vector)."""
    return not (isinstance(node, tuple) and hasattr(node, "_fields"))


def param_paths(params: GridSlamParams | None = None) -> tuple[str, ...]:
    """Every leaf's path, ``"part.field"``, in the tree's order."""
    params = GridSlamParams(SensorParams(None)) if params is None else params
    return tuple(f"{part}.{name}" for part in GridSlamParams._fields for name in getattr(params, part)._fields)


def get_path(params: GridSlamParams, path: str):
    """The leaf (or, for a bare part name, the part) at ``path``."""
    part, _, name = path.partition(".")
    if part not in GridSlamParams._fields:
        raise KeyError(f"unknown grid SLAM parameter {path!r}")
    node = getattr(params, part)
    if not name:
        return node
    if name not in node._fields:
        raise KeyError(f"unknown grid SLAM parameter {path!r}")
    return getattr(node, name)


def with_values(params: GridSlamParams, values: Mapping[str, Any]) -> GridSlamParams:
    """``params`` with each path of ``values`` set (``"closure.trigger"``: a leaf;
    ``"closure"``: a whole part). A host value takes the dtype of the leaf it
    replaces; a JAX array is cast to it (traced values stay traced)."""
    parts = {}
    for path, value in values.items():
        part, _, name = path.partition(".")
        current = get_path(params, part)  # raises for an unknown part
        if not name:
            parts[part] = type(current)(*(_like(v, old) for v, old in zip(value, current, strict=True)))
            continue
        get_path(params, path)  # raises for an unknown field
        parts[part] = parts.get(part, current)._replace(**{name: _like(value, getattr(current, name))})
    return params._replace(**parts)


def _like(value, leaf):
    dtype = getattr(leaf, "dtype", None)
    if dtype is None:
        return value
    if isinstance(value, jax.Array):
        return value.astype(dtype)
    return np.asarray(value, dtype)


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
        kept: ``()`` the sum of the position corrections of the closures taken and not
            undone (``config.closure_map_bound``; None without it, so that the program
            is the one without the bound).
        level: ``()`` the running mean of the tracking's scores (fraction of the
            matched beams), each scan weighted :data:`jaxslam.grid.tracking.LEVEL_RATE`
            from 0 at the start; ``closure.trigger_ratio`` times it raises the trigger.
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
    kept: Array | None = None
    level: Array | None = None

    @classmethod
    def empty(cls, dtype, map_bound: bool = False) -> "ClosureState":
        """No candidate held, no closure taken, nothing travelled; ``map_bound``: with
        the sum of the kept corrections (``config.closure_map_bound``)."""
        zero, pose = jnp.zeros((), dtype), jnp.zeros((3,), dtype)
        return cls(pose, zero, zero, pose, zero, zero, zero, zero, pose, zero if map_bound else None, zero)


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
    track_search: Array  # (4,) the closure candidate judged here: kind, score, distance, refusals (closure_outcome)
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
    "PARAMETER_SPECS",
    "VECTORS",
    "ClosureParams",
    "ClosureState",
    "GMappingNoise",
    "GridSlamConfig",
    "GridSlamInfo",
    "GridSlamParams",
    "GridSlamState",
    "KeyframeParams",
    "MapParams",
    "MatcherParams",
    "Odometry",
    "Scan",
    "SensorParams",
    "SrupfNoise",
    "TrackingParams",
    "UTParams",
    "WeightParams",
    "as_odometry",
    "get_path",
    "noise_scale_of",
    "param_paths",
    "with_values",
]


_SRUPF = ("srupf-gm", "srupf-gm-npc")

PARAMETER_SPECS: dict[str, ParamSpec] = {
    "sensor.usable_range": positive("m", "beams are cropped here for the map and ignored beyond it for matching "
                                  "(chosen from the log's readings unless set)"),
    "sensor.score_range": positive("m", "a beam of range r counts min(1, (score_range / r)^2) beams in the score "
                                 "(chosen from the log's readings unless set)"),
    "map.l_free": ParamSpec("log-odds steps", "update of a cell a beam passes through", high=0.0),
    "map.l_occ": at_least(0.0, "log-odds steps", "update of the cell a beam ends in"),
    "map.l_max": positive("log-odds steps", "clamp of a cell's log-odds"),
    "map.occ_saturation": positive("log-odds steps", "log-odds at which a cell scores 1 in matching"),
    "matcher.score_sigma": positive("m", "width of the matching kernel"),
    "matcher.coarse_sigma": positive("m", "width of the matching kernel in the coarse stage"),
    "matcher.coarse_radius": positive("std", "reach of the coarse stage around the predicted pose"),
    "map.log_odds_unit": positive("1", "natural log-odds per step (map export)"),
    "matcher.linear_step": positive("m", "first step of the scan matcher in x and y (GMapping lstep)"),
    "matcher.angular_step": positive("rad", "first step of the scan matcher in heading (GMapping astep)"),
    "matcher.ellipse_radius": positive("std", "reach of the ellipse matcher around the prediction"),
    "matcher.ellipse_step": positive("std", "first step of the ellipse matcher"),
    "matcher.learning_rate": at_least(0.0, "1", "step of the gradient refinement of a match (basis units)"),
    "matcher.min_score": fraction("a match scoring at or below this keeps the uncorrected pose (GMapping minimumScore)"),
    "keyframes.linear_update": at_least(0.0, "m", "a scan is a keyframe after this much tracked travel (linearUpdate)"),
    "keyframes.angular_update": at_least(0.0, "rad", "a scan is a keyframe after this much tracked rotation (angularUpdate)"),
    "keyframes.temporal_update": real("s", "a scan is a keyframe after this many seconds; negative: off (temporalUpdate)"),
    "tracking.min_score": fraction("the tracking match replaces the odometry only above this score"),
    "tracking.min_curvature": at_least(0.0, "1/m^2", "score curvature a tracking correction needs along a direction"),
    "tracking.noise_scale": at_least(0.0, "1", "the proposals' motion noise with tracking, a fraction of the model's"),
    "tracking.refused_noise_scale": real("1", "that fraction after a refused tracking match; negative: "
                                              "tracking.noise_scale"),
    "tracking.turn": at_least(0.0, "rad", "the tracking match also tries its guess turned by this much; 0: never"),
    "closure.trigger": fraction("a tracking match scoring under this starts the loop-closure search; 0: off"),
    "closure.conflict": fraction("share of beams ending in known free space the search also needs"),
    "closure.min_score": fraction("a closure's pose must score at least this"),
    "closure.gain": at_least(0.0, "1", "a closure's pose must also score this many times the tracking match"),
    "closure.confirm": at_least(1.0, "scans", "scans in a row a closure must be confirmed on"),
    "closure.confirm_gain": at_least(0.0, "1", "the gain over the tracking match on a held candidate's scans after "
                                     "the first; 0: closure.gain"),
    "closure.drift": at_least(0.0, "m/m", "a closure moves the match by at most this times the odometry distance"),
    "closure.reach_rate": at_least(0.0, "m/m", "the search's reach per metre of odometry since the last closure"),
    "closure.jump": at_least(0.0, "m", "a closure moves the match by at most this much or closure.drift times the odometry distance, whichever is more"),
    "closure.watch": at_least(0.0, "m", "odometry over which a closure taken is watched"),
    "closure.undo": fraction("a watched closure is undone where the free-space share averages over this; 1: never"),
    "closure.undo_fast": fraction("a watched closure is undone early where the free-space share is over this; 1: never"),
    "closure.nest": fraction("1 lets a closure be taken inside another's watch, 0 does not"),
    "closure.undo_end": fraction("a closure still watched at the end is undone over this share; 1: never"),
    "closure.first_drift": at_least(0.0, "m/m", "until a closure is taken, a closure moves the match by at most this "
                                    "times the odometry distance since the start or closure.jump, whichever is "
                                    "more; 0: off"),
    "closure.trigger_ratio": at_least(0.0, "1", "the search also starts under this times the mean score of the "
                                      "recent tracking matches (closure.trigger at least); 0: off"),
    "weights.likelihood_floor": ParamSpec("1", "probability of a beam that hits no wall", low=0.0, high=1.0, low_open=True),
    "weights.gain": positive("1", "gain of the log-likelihood in the weights"),
    "weights.resample_threshold": fraction("resample when the effective sample size falls under this times N"),
    "gmapping.srr": at_least(0.0, "m/m", "translation noise per metre of translation (GMapping srr)",
                    algorithms=("gmapping",)),
    "gmapping.srt": at_least(0.0, "m/rad", "translation noise per radian of rotation (GMapping srt)",
                    algorithms=("gmapping",)),
    "gmapping.str": at_least(0.0, "rad/m", "rotation noise per metre of translation (GMapping str)",
                    algorithms=("gmapping",)),
    "gmapping.stt": at_least(0.0, "rad/rad", "rotation noise per radian of rotation (GMapping stt)",
                    algorithms=("gmapping",)),
    "srupf.q_linear": positive("m", "std of the constant motion noise in x and y", algorithms=_SRUPF),
    "srupf.q_angular": positive("rad", "std of the constant motion noise in heading", algorithms=_SRUPF),
    "srupf.q_linear_per_m": at_least(0.0, "m/m", "motion noise in x and y per metre travelled", algorithms=_SRUPF),
    "srupf.q_angular_per_rad": at_least(0.0, "rad/rad", "heading noise per radian turned", algorithms=_SRUPF),
    "srupf.q_angular_per_m": at_least(0.0, "rad/m", "heading noise per metre travelled", algorithms=_SRUPF),
    "unscented.alpha": positive("1", "unscented transform: spread of the sigma points", algorithms=_SRUPF),
    "unscented.beta": real("1", "unscented transform: prior knowledge of the distribution (2: Gaussian)",
                    algorithms=_SRUPF),
    "unscented.kappa": real("1", "unscented transform: secondary scaling", algorithms=_SRUPF),
}
PARAMETER_SPECS = {path: PARAMETER_SPECS[path] for path in param_paths() if path in PARAMETER_SPECS}  # tree order
"""Every scalar parameter of the grid filters that ``jaxslam run --set PATH=VALUE``
accepts, by its path in :class:`GridSlamParams` (``closure.trigger``; the parts'
docstrings give the model). Left out: the log's beam angles and laser offset, and the
vectors :data:`VECTORS` (a calibration file may set those, ``jaxslam run --params``)."""

VECTORS: dict[str, int] = {"matcher.ellipse_floor": 3, "srupf.match_noise": 3, "srupf.initial_std": 3}
"""The vector parameters of the grid filters (standard deviations, finite and >= 0) that a
calibration file (``jaxslam run --params``) may set, with their lengths."""
