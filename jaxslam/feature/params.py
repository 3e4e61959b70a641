"""Parameters (traced) and configuration (static) of the landmark filters.

:class:`Params` holds every number a sweep may change without recompiling: noise
levels, geometry, gates, thresholds, unscented-transform scalings. :class:`Config`
holds what fixes shapes or branches: particle count, table capacity, which proposal,
batch or sequential update, the resampler.

Defaults are the paper's Victoria Park settings (Kim, Kim & Chung 2011, Sec. IV):
process noise 2 m/s on the speed and 6 deg on the steering, measurement noise 1 m and
3 deg, 30 m perception range, and UFastSLAM's gate of 5.991 (chi-square, 2 dof, 95%).
The new-landmark gate (20: an observation whose squared Mahalanobis distance to every
associated landmark exceeds it starts a new landmark) lies between UFastSLAM's 100,
which folds detections of nearby trees into one landmark, and a tight gate such as
10, which starts duplicates of landmarks seen with a large innovation; it was chosen
on real data with ``benchmarks/erb_particles.py --label`` (a variant per gate).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

from jax import Array

from jaxslam.core.sigma import UTParams
from jaxslam.core.spec import ParamSpec, at_least, fraction, positive, real
from jaxslam.models.vehicle import CarGeometry


class Params(NamedTuple):
    """Traced parameters of the landmark filters.

    Attributes:
        speed_std: std of the encoder speed noise per control row [m/s].
        steering_std: std of the steering noise per control row [rad].
        range_std: std of the range noise [m].
        bearing_std: std of the bearing noise [rad].
        geometry: the car model's geometry.
        sensor_offset: ``(2,)`` sensor position in the vehicle frame [m].
        max_range: sensor range [m] (observations beyond it never occur).
        fov: sensor field of view, full angle [rad].
        gate_associate: chi-square gate on the squared Mahalanobis distance for a match.
        gate_new: an observation whose every candidate is farther than this starts a
            new landmark (between the two gates it is ignored).
        resample_threshold: resample when ``ESS < resample_threshold * N``.
        ut_predict: UT scaling of the prediction over ``[pose; control noise]`` (n=5).
        ut_update: UT scaling of the proposal over ``[pose; landmark]`` (n=5).
        ut_landmark: UT scaling of landmark updates and initialisation (n=2).
        pose_reset_std: std the pose covariance is reset to after sampling [m, rad].
        candidate_margin: extra range around the sensor's footprint in which stored
            landmarks are candidates for association [m].
        visibility_margin: a landmark counts as missed only when it is this far inside
            the sensor's range and field of view [m].
        new_evidence: evidence of a newly created landmark.
        prune_threshold: a landmark whose evidence falls below this is deleted
            (each match adds 1, each miss while expected visible subtracts 1).
        detection_probability: :math:`P_D` of the mixture likelihood
            (``Config.likelihood = "mixture"``; unused by the paper's weights).
    """

    speed_std: Array | float = 2.0
    steering_std: Array | float = math.radians(6.0)
    range_std: Array | float = 1.0
    bearing_std: Array | float = math.radians(3.0)
    geometry: CarGeometry = CarGeometry()
    sensor_offset: Array | tuple = (0.0, 0.0)
    max_range: Array | float = 30.0
    fov: Array | float = math.pi
    gate_associate: Array | float = 5.991
    gate_new: Array | float = 20.0
    resample_threshold: Array | float = 0.5
    ut_predict: UTParams = UTParams(1.0, 2.0, 1.0)
    ut_update: UTParams = UTParams(1.0, 2.0, 1.0)
    ut_landmark: UTParams = UTParams(1.0, 2.0, 1.0)
    pose_reset_std: Array | float = 1e-4
    candidate_margin: Array | float = 5.0
    visibility_margin: Array | float = 2.0
    new_evidence: Array | float = 1.0
    prune_threshold: Array | float = -1e9
    detection_probability: Array | float = 0.9


PARAMETER_SPECS: dict[str, ParamSpec] = {
    "speed_std": positive("m/s", "std of the encoder speed noise per control row"),
    "steering_std": positive("rad", "std of the steering noise per control row"),
    "range_std": positive("m", "std of the range noise"),
    "bearing_std": positive("rad", "std of the bearing noise"),
    "max_range": positive("m", "sensor range"),
    "fov": ParamSpec("rad", "sensor field of view, full angle", low=0.0, high=2 * math.pi, low_open=True),
    "gate_associate": positive("1", "chi-square gate on the squared Mahalanobis distance of a match"),
    "gate_new": positive("1", "an observation farther than this from every candidate starts a landmark"),
    "resample_threshold": fraction("resample when the effective sample size falls under this times N"),
    "pose_reset_std": positive("m, rad", "std the pose covariance is reset to after sampling"),
    "candidate_margin": at_least(0.0, "m", "extra range around the sensor's footprint for association candidates"),
    "visibility_margin": real("m", "a landmark counts as missed only this far inside the range and field of view"),
    "new_evidence": real("1", "evidence of a newly created landmark"),
    "prune_threshold": real("1", "a landmark whose evidence falls below this is deleted"),
    "detection_probability": ParamSpec("1", "detection probability of the mixture likelihood", low=0.0, high=1.0,
                                       low_open=True),
}
"""Every scalar parameter of :class:`Params` that ``jaxslam run --set NAME=VALUE``
accepts for the landmark filters, with its unit, meaning and allowed values (the
geometry, the sensor offset and the unscented-transform scalings are not scalars)."""


PROPOSALS = ("rb", "erb")
UPDATES = ("batch", "sequential")
LIKELIHOODS = ("gated", "mixture")


@dataclasses.dataclass(frozen=True)
class Config:
    r"""Static configuration (shapes and branches); hashable, passed to ``jit`` as static.

    Attributes:
        num_particles: number of particles ``N``.
        capacity: landmark slots per particle ``C``.
        proposal: ``"erb"`` (exactly Rao-Blackwellized, Sec. III-A) or ``"rb"``
            (conventional, perfect-map innovation, eqs. 1-3).
        update: ``"batch"`` (all observations of a scan at once, as the paper) or
            ``"sequential"`` (one observation after the other).
        local_size: stored landmarks near the sensor gathered per particle and scan
            (the association search space).
        candidates: nearest landmarks (Euclidean, from the predicted pose) per
            observation that get the full sigma-point Mahalanobis test.
        observation_widths: narrower copies of the step that are compiled besides the
            full observation width (only those under it): a scan runs on the
            narrowest that holds its last real observation, since the per-particle
            work grows with the padded width (:func:`jaxslam.feature.filter.step`).
        resampler: ``systematic``, ``stratified``, ``multinomial`` or ``residual``.
        skip_stationary: skip a scan whose controls all have zero speed (UFastSLAM).
        compare_proposals: also compute the other proposal's covariance for
            :class:`~jaxslam.feature.filter.Info` (free in batch mode; a second pass in sequential mode).
        likelihood: the weight increment. ``"gated"`` (the paper's eq. 11): the
            joint innovation likelihood of the matched observations; unmatched ones
            contribute nothing. ``"mixture"``: every observation contributes
            :math:`\log(P_D\,\mathcal N(\nu; 0, \mathcal S) + (1 - P_D)\,\lambda)`
            with its most likely candidate and the uniform density
            :math:`\lambda = 1 / (r_{max} \cdot \mathrm{fov})` of a new landmark or
            clutter in range and bearing (see :mod:`jaxslam.feature.particle`; the
            objective of :mod:`jaxslam.calibrate`).
    """

    num_particles: int = 100
    capacity: int = 512
    proposal: str = "erb"
    update: str = "batch"
    local_size: int = 64
    candidates: int = 2
    observation_widths: tuple = (4, 7)
    resampler: str = "systematic"
    skip_stationary: bool = True
    compare_proposals: bool = True
    likelihood: str = "gated"

    def __post_init__(self):
        if self.proposal not in PROPOSALS:
            raise ValueError(f"proposal must be one of {PROPOSALS}, got {self.proposal!r}")
        if self.update not in UPDATES:
            raise ValueError(f"update must be one of {UPDATES}, got {self.update!r}")
        if self.likelihood not in LIKELIHOODS:
            raise ValueError(f"likelihood must be one of {LIKELIHOODS}, got {self.likelihood!r}")
        if min(self.num_particles, self.capacity, self.local_size, self.candidates) < 1:
            raise ValueError("num_particles, capacity, local_size and candidates must be >= 1")
        object.__setattr__(self, "observation_widths", tuple(self.observation_widths))
        if any(not isinstance(w, int) or w < 1 for w in self.observation_widths):
            raise ValueError(f"observation_widths must be positive ints, got {self.observation_widths!r}")
        if self.candidates > self.local_size:
            raise ValueError("candidates must not exceed local_size")
