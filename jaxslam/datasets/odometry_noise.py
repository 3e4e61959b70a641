"""Synthetic wheel-odometry error on reference poses, and relations sampled from them
(for the perturbed logs of :mod:`jaxslam.datasets.perturb`).

Odometry model (host NumPy, float64; ours, not taken from any filter). With the
reference increment ``u_i = x*_{i-1}^-1 (+) x*_i = (dx, dy, dtheta)``,
``d = hypot(dx, dy)`` and ``a = |dtheta|``:

    dx'     = (1 + s_i) dx + sigma_x  e_x,   sigma_x  = k_tt d + k_tr a
    dy'     = (1 + s_i) dy + sigma_y  e_y,   sigma_y  = k_lat d
    dtheta' = (1 + r_i) dtheta + b_i d + sigma_th e_th,   sigma_th = k_rr a + k_rt d
    odom_0 = x*_0,   odom_i = odom_{i-1} (+) (dx', dy', dtheta')

with ``e ~ N(0, 1)`` independent. The noise is proportional to the motion (no motion,
no error), like wheel odometry. The drift terms -- a translation scale error ``s``,
a rotation scale error ``r`` and a heading bias per metre ``b`` (unequal wheel
radii make the robot curve) -- are Ornstein-Uhlenbeck processes in distance
travelled, stationary with standard deviation ``sigma`` and correlation length
``L`` (m):

    s_i = rho_i s_{i-1} + sigma_s sqrt(1 - rho_i^2) e,   rho_i = exp(-(d + w a) / L)

(``w`` = :data:`DRIFT_RADIUS` m per rad, so turning in place also moves the drift
on), started from the stationary law ``s_0 ~ N(0, sigma_s^2)``. Two levels are
given in :data:`NOISE_LEVELS`; with all coefficients zero the odometry *is* the
reference.

Reference relations (the Kümmerle et al. 2009 metric needs relations between scans,
not a ground-truth trajectory):

* ``local``: ``(i, i + k)`` for every ``i`` and each ``k`` in ``local_offsets``
  (default 1 and 4: neighbouring scans, about 1 m and 4 m of travel apart, since the
  corrected logs hold GMapping keyframes);
* ``loop``: for each scan ``i``, at most one later scan ``j >= i + loop_min_gap``
  whose reference pose is within ``loop_radius`` m and ``loop_max_angle`` rad of
  ``x*_i`` (so the two scans see the same place), drawn at random among those
  (seeded); these score loop closures.

``delta*_ij = x*_i^-1 (+) x*_j``; the relation stamps are the perturbed log's scan
stamps.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose, wrap_angle
from jaxslam.datasets.relations import Relations

DRIFT_RADIUS = 0.3
"""Metres of drift-process "distance" per radian turned in place (``w`` above)."""

@dataclasses.dataclass(frozen=True)
class OdometryNoise:
    """Coefficients of the odometry model in the module docstring.

    Attributes:
        trans_per_m: ``k_tt``, forward noise std per metre travelled.
        trans_per_rad: ``k_tr``, forward noise std (m) per radian turned.
        lateral_per_m: ``k_lat``, sideways noise std per metre.
        rot_per_rad: ``k_rr``, heading noise std per radian turned.
        rot_per_m: ``k_rt``, heading noise std (rad) per metre.
        scale_sigma: ``sigma_s``, std of the translation scale error.
        rot_scale_sigma: ``sigma_r``, std of the rotation scale error.
        bias_sigma: ``sigma_b``, std of the heading bias (rad per metre).
        drift_length: ``L``, correlation length of the drift processes (m).
    """

    trans_per_m: float = 0.0
    trans_per_rad: float = 0.0
    lateral_per_m: float = 0.0
    rot_per_rad: float = 0.0
    rot_per_m: float = 0.0
    scale_sigma: float = 0.0
    rot_scale_sigma: float = 0.0
    bias_sigma: float = 0.0
    drift_length: float = 20.0

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"OdometryNoise.{field.name} must be finite and >= 0, got {value!r}")
        if self.drift_length <= 0:
            raise ValueError(f"OdometryNoise.drift_length must be > 0, got {self.drift_length!r}")


NOISE_LEVELS = {
    # Good wheel odometry: ~2 % distance error, ~0.3 deg/m heading drift.
    "low": OdometryNoise(
        trans_per_m=0.02, trans_per_rad=0.01, lateral_per_m=0.01, rot_per_rad=0.02,
        rot_per_m=0.005, scale_sigma=0.01, rot_scale_sigma=0.01, bias_sigma=0.005,
        drift_length=20.0,
    ),
    # Poor odometry (slipping wheels, carpet): ~5 % noise, ~1 deg/m heading drift,
    # 3 % scale errors.
    "high": OdometryNoise(
        trans_per_m=0.05, trans_per_rad=0.02, lateral_per_m=0.02, rot_per_rad=0.05,
        rot_per_m=0.01, scale_sigma=0.03, rot_scale_sigma=0.03, bias_sigma=0.02,
        drift_length=20.0,
    ),
}
"""The two noise levels of the robustness suite."""

def perturb_odometry(
    reference: np.ndarray, noise: OdometryNoise, seed: int
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Odometry from reference poses with the model in the module docstring.

    Args:
        reference: (S, 3) reference poses.
        noise: the coefficients.
        seed: NumPy generator seed (same seed, same odometry).

    Returns:
        ``(odometry (S, 3), drift)`` where ``drift`` holds the (S - 1,) processes
        ``scale``, ``rot_scale``, ``bias`` used for each increment.
    """
    ref = np.asarray(reference, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 3 or ref.shape[0] < 1:
        raise ValueError(f"reference must have shape (S, 3) with S >= 1, got {ref.shape}")
    rng = np.random.default_rng(seed)
    steps = se2_between(ref[:-1], ref[1:])
    n = steps.shape[0]
    d = np.hypot(steps[:, 0], steps[:, 1])
    a = np.abs(steps[:, 2])
    white = rng.standard_normal((n, 3))
    drive = rng.standard_normal((n, 3))
    start = rng.standard_normal(3)
    sigmas = np.array([noise.scale_sigma, noise.rot_scale_sigma, noise.bias_sigma])
    rho = np.exp(-(d + DRIFT_RADIUS * a) / noise.drift_length)
    drift = np.empty((n, 3))
    state = sigmas * start
    for i in range(n):
        state = rho[i] * state + sigmas * np.sqrt(1.0 - rho[i] ** 2) * drive[i]
        drift[i] = state
    scale, rot_scale, bias = drift[:, 0], drift[:, 1], drift[:, 2]
    sigma_x = noise.trans_per_m * d + noise.trans_per_rad * a
    sigma_y = noise.lateral_per_m * d
    sigma_th = noise.rot_per_rad * a + noise.rot_per_m * d
    noisy = np.column_stack(
        [
            (1.0 + scale) * steps[:, 0] + sigma_x * white[:, 0],
            (1.0 + scale) * steps[:, 1] + sigma_y * white[:, 1],
            (1.0 + rot_scale) * steps[:, 2] + bias * d + sigma_th * white[:, 2],
        ]
    )
    odom = np.empty_like(ref)
    odom[0] = ref[0]
    for i in range(n):
        odom[i + 1] = se2_compose(odom[i], noisy[i])
    return odom, {"scale": scale, "rot_scale": rot_scale, "bias": bias}


def reference_relations(
    stamps: np.ndarray,
    poses: np.ndarray,
    seed: int,
    *,
    local_offsets: tuple[int, ...] = (1, 4),
    loop_min_gap: int = 30,
    loop_radius: float = 1.5,
    loop_max_angle: float = np.pi / 2,
):
    """Relations sampled from reference poses (``local`` and ``loop``: see
    :mod:`jaxslam.datasets.perturb`).

    Returns:
        ``(Relations, kinds (R,) str)``; the relations are ordered local first.
    """
    stamps = np.asarray(stamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    s = poses.shape[0]
    pairs: list[tuple[int, int]] = []
    kinds: list[str] = []
    for k in local_offsets:
        if k < 1:
            raise ValueError(f"local offsets must be >= 1, got {k}")
        i = np.arange(max(s - k, 0))
        pairs.extend(zip(i.tolist(), (i + k).tolist()))
        kinds.extend(["local"] * i.shape[0])
    rng = np.random.default_rng(seed)
    for i in range(s - loop_min_gap):
        j = np.arange(i + loop_min_gap, s)
        close = (np.hypot(poses[j, 0] - poses[i, 0], poses[j, 1] - poses[i, 1]) <= loop_radius) & (
            np.abs(wrap_angle(poses[j, 2] - poses[i, 2])) <= loop_max_angle
        )
        if np.any(close):
            pairs.append((i, int(rng.choice(j[close]))))
            kinds.append("loop")
    index = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    deltas = se2_between(poses[index[:, 0]], poses[index[:, 1]])
    relations = Relations(
        path=None,
        t1=stamps[index[:, 0]],
        t2=stamps[index[:, 1]],
        deltas=deltas,
        lines=np.arange(1, index.shape[0] + 1, dtype=np.int64),
    )
    return relations, np.array(kinds)
