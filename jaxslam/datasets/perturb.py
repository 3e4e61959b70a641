"""Perturbed logs: GMapping-corrected CARMEN logs with synthetic wheel-odometry error.

The GMapping-corrected logs in ``carmen_gmapping_corrected/`` hold, for every scan,
the laser pose GMapping estimated (both pose triples of each FLASER line). Taken as
the reference trajectory ``x*_0 .. x*_{S-1}``, they let us make logs with known
poses and odometry as bad as we choose: the odometry is the reference increments
with noise and a slowly varying drift, and the scans are the logged ones. A filter
run on the perturbed log is scored against the reference with the relations metric
(:mod:`jaxslam.metrics.relations`) on relations sampled from the reference.

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

Timestamps. The corrected logs print stamps with ``%g`` (6 significant digits):
csail and belgioioso (Unix times) get ties, freiburg-campus and orebro are all zero,
infinite-corridor goes backwards and intel has 4 backward steps. Relations need
one stamp per scan, so the original stamps are kept only when they are finite and
strictly increasing; otherwise *all* scans get ``t_i = i`` seconds (the filters use
stamps only for an optional temporal keyframe rule, off by default), and
:attr:`PerturbedLog.stamps_replaced` says why.

Written log (plain CARMEN, readable by :func:`jaxslam.datasets.carmen.load_carmen`
and by GMapping's reader): the PARAMs that set the beam geometry and range limit
(``laser_front_laser_resolution``/``fov``/``flipped``) copied from the source,
``robot_front_laser_max`` set to the limit jaxslam's reader takes for the source
(80 m for FLASER logs without it; GMapping would take the largest reading), zero laser offsets (the reference poses are laser poses, so
robot = laser frame here), and one ``FLASER`` per scan with the original range
tokens copied byte for byte, the perturbed pose in both pose triples, and the stamp.
Dense ``ODOM`` and ``NEFF`` lines are not written. The ``.relations`` file has the
benchmark's format ``t1 t2 x y z roll pitch yaw``.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose, wrap_angle
from jaxslam.datasets.paths import DataFormatError
from jaxslam.datasets.reader import read_bytes
from jaxslam.datasets.registry import for_file, lookup

__all__ = [
    "CORRECTED_LOGS",
    "DRIFT_RADIUS",
    "NOISE_LEVELS",
    "OdometryNoise",
    "PerturbedLog",
    "ReferenceLog",
    "load_reference_log",
    "make_perturbed_log",
    "perturb_odometry",
    "reference_relations",
    "write_perturbed_log",
]

CORRECTED_LOGS = {
    "acapulco": "acapulco-corrected",
    "belgioioso": "belgioioso-corrected",
    "csail": "csail-corrected",
    "edmonton": "edmonton-corrected",
    "fhw": "fhw-corrected",
    "fr079": "freiburg-079-corrected",
    "fr101": "freiburg-101-corrected",
    "fr-campus": "freiburg-campus-corrected",
    "infinite-corridor": "infinite-corridor-corrected",
    "intel": "intel-corrected",
    "orebro": "orebro-corrected",
    "seattle": "seattle-corrected",
}
"""Short name -> the corrected log's name in :mod:`jaxslam.datasets.registry`."""

DRIFT_RADIUS = 0.3
"""Metres of drift-process "distance" per radian turned in place (``w`` above)."""

_COPIED_PARAMS = (
    "robot_front_laser_max",
    "laser_front_laser_resolution",
    "laser_front_laser_fov",
    "laser_front_laser_flipped",
)


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


@dataclasses.dataclass(frozen=True)
class ReferenceLog:
    """A GMapping-corrected log read for perturbation.

    Attributes:
        path: the source file.
        stamps: (S,) float64 scan stamps to write (originals or ``0, 1, 2 ..``).
        poses: (S, 3) float64 reference (corrected laser) poses.
        range_tokens: S strings, each the ``n r_1 .. r_n`` text of a FLASER line.
        params: PARAM name -> value text copied to the output.
        stamps_replaced: why the stamps were replaced, or None when kept.
    """

    path: Path
    stamps: np.ndarray
    poses: np.ndarray
    range_tokens: tuple[str, ...]
    params: dict[str, str]
    stamps_replaced: str | None


@dataclasses.dataclass(frozen=True)
class PerturbedLog:
    """A written perturbed log and its reference relations.

    Attributes:
        log_path: the CARMEN file written.
        relations_path: the ``.relations`` file written.
        relations: the same relations as a :class:`jaxslam.metrics.relations.Relations`.
        relation_kinds: (R,) ``"local"`` or ``"loop"`` per relation.
        reference: the source log (reference poses and stamps).
        odometry: (S, 3) the perturbed odometry written.
        level: noise level name (or ``"custom"``).
        seed: the seed.
        stamps_replaced: as in :class:`ReferenceLog`.
    """

    log_path: Path
    relations_path: Path
    relations: object
    relation_kinds: np.ndarray
    reference: ReferenceLog
    odometry: np.ndarray
    level: str
    seed: int
    stamps_replaced: str | None


def _resolve(name_or_path: os.PathLike | str) -> Path:
    if str(name_or_path) in CORRECTED_LOGS:
        return lookup(CORRECTED_LOGS[str(name_or_path)]).paths()[0]
    path = Path(name_or_path)
    if not path.exists():
        raise FileNotFoundError(
            f"no corrected log {str(name_or_path)!r}: not a file and not one of {', '.join(CORRECTED_LOGS)}"
        )
    return path


def load_reference_log(name_or_path: os.PathLike | str) -> ReferenceLog:
    """Read a GMapping-corrected log: reference poses, stamps and range text.

    The log is parsed by :func:`jaxslam.datasets.carmen.load_carmen` (its errors name
    the file and line), with the reading options of its
    :mod:`~jaxslam.datasets.registry` entry when the file is one it knows; the range
    tokens are then taken verbatim from the scan lines it reports. Only FLASER logs are accepted (the corrected logs are FLASER).

    Raises:
        DataFormatError: the log is not a FLASER log, or a scan line disagrees with
            the parsed scan.
    """
    from jaxslam.datasets.carmen import load_carmen

    path = _resolve(name_or_path)
    # Corrected logs may have stamps going back arbitrarily (infinite-corridor);
    # they are replaced below, so accept any step here. A file the registry knows
    # gets its reading options (e.g. the zero laser offset of a corrected log).
    info = for_file(path)
    log = load_carmen(path, **{**(info.options if info is not None else {}), "max_backstep": np.inf})
    if log.message != "FLASER":
        raise DataFormatError(path, None, f"expected a FLASER log, got {log.message}")
    raw = read_bytes(path, "CARMEN log")
    lines = raw.split(b"\n")
    tokens = []
    for line_number in log.scan_lines.tolist():
        parts = lines[line_number - 1].split()
        n = int(parts[1])
        if parts[0] != b"FLASER" or n != log.num_beams:
            raise DataFormatError(path, line_number, "scan line does not match the parsed scan")
        tokens.append(b" ".join(parts[1 : 2 + n]).decode("ascii"))
    poses = log.laser_poses if log.laser_poses is not None else log.odom_poses
    stamps = np.asarray(log.scan_times, dtype=np.float64)
    reason = None
    if not np.all(np.isfinite(stamps)):
        reason = "non-finite stamps"
    elif stamps.shape[0] > 1 and not np.all(np.diff(stamps) > 0):
        steps = np.diff(stamps)
        reason = (
            f"stamps not strictly increasing ({int(np.sum(steps == 0))} ties, "
            f"{int(np.sum(steps < 0))} backward steps)"
        )
    if reason is not None:
        stamps = np.arange(stamps.shape[0], dtype=np.float64)
    params = {k: log.params[k] for k in _COPIED_PARAMS if k in log.params and len(log.params[k].split()) == 1}
    # The range limit jaxslam's reader decided, written out so that every reader
    # (GMapping's takes the largest reading otherwise) sees the same one.
    params["robot_front_laser_max"] = repr(float(log.max_range))
    return ReferenceLog(
        path=path,
        stamps=stamps,
        poses=np.asarray(poses, dtype=np.float64),
        range_tokens=tuple(tokens),
        params=params,
        stamps_replaced=reason,
    )


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
    """Relations sampled from reference poses (see the module docstring).

    Returns:
        ``(Relations, kinds (R,) str)``; the relations are ordered local first.
    """
    from jaxslam.metrics.relations import Relations

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


def _write_relations(path: Path, relations, kinds: np.ndarray, header: str) -> None:
    lines = [f"# {line}" for line in header.splitlines()]
    lines.append("# t1 t2 x y z roll pitch yaw  (kinds: local first, then loop)")
    for t1, t2, (x, y, th) in zip(relations.t1.tolist(), relations.t2.tolist(), relations.deltas.tolist()):
        lines.append(f"{t1!r} {t2!r} {x!r} {y!r} 0 0 0 {th!r}")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def write_perturbed_log(
    path: os.PathLike | str, reference: ReferenceLog, odometry: np.ndarray, header: str = ""
) -> Path:
    """Write a CARMEN log: the reference's scans with ``odometry`` as their poses."""
    path = Path(path)
    odom = np.asarray(odometry, dtype=np.float64)
    if odom.shape != reference.poses.shape:
        raise ValueError(f"odometry must have shape {reference.poses.shape}, got {odom.shape}")
    out = [f"# {line}" for line in header.splitlines()]
    out.append("# message formats defined: PARAM FLASER")
    for name in ("robot_frontlaser_offset", "robot_frontlaser_side_offset", "robot_frontlaser_angular_offset"):
        out.append(f"PARAM {name} 0.0 nohost 0")
    for name, value in reference.params.items():
        out.append(f"PARAM {name} {value} nohost 0")
    for tokens, (x, y, th), t in zip(reference.range_tokens, odom.tolist(), reference.stamps.tolist()):
        pose = f"{x!r} {y!r} {th!r}"
        out.append(f"FLASER {tokens} {pose} {pose} {t!r} perturb {t!r}")
    path.write_text("\n".join(out) + "\n", encoding="ascii")
    return path


def make_perturbed_log(
    name_or_path: os.PathLike | str,
    level: str | OdometryNoise,
    seed: int,
    out_dir: os.PathLike | str,
    **relation_options,
) -> PerturbedLog:
    """Write ``<stem>_<level>_s<seed>.log`` and ``.relations`` into ``out_dir``.

    Args:
        name_or_path: a key of :data:`CORRECTED_LOGS` or a corrected log's path.
        level: ``"low"``, ``"high"`` (:data:`NOISE_LEVELS`) or an :class:`OdometryNoise`.
        seed: seeds the odometry noise; the relations' loop sampling uses the
            reference alone (seed 0), so all seeds of a log share one relations set.
        out_dir: output folder (created).
        relation_options: passed to :func:`reference_relations`.
    """
    if isinstance(level, str):
        if level not in NOISE_LEVELS:
            raise ValueError(f"unknown noise level {level!r}; known: {', '.join(NOISE_LEVELS)}")
        noise, level_name = NOISE_LEVELS[level], level
    else:
        noise, level_name = level, "custom"
    reference = load_reference_log(name_or_path)
    odometry, _ = perturb_odometry(reference.poses, noise, seed)
    relations, kinds = reference_relations(reference.stamps, reference.poses, 0, **relation_options)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = reference.path.name.split(".")[0]
    header = (
        f"jaxslam.datasets.perturb: {reference.path.name}, noise {level_name} "
        f"{dataclasses.asdict(noise)}, seed {seed}"
        + (f"\nstamps replaced by 0, 1, 2 ..: {reference.stamps_replaced}" if reference.stamps_replaced else "")
    )
    log_path = write_perturbed_log(out_dir / f"{stem}_{level_name}_s{seed}.log", reference, odometry, header)
    relations_path = out_dir / f"{stem}.relations"
    _write_relations(
        relations_path, relations, kinds,
        f"jaxslam.datasets.perturb: reference relations of {reference.path.name} "
        f"({int(np.sum(kinds == 'local'))} local, {int(np.sum(kinds == 'loop'))} loop)",
    )
    return PerturbedLog(
        log_path=log_path,
        relations_path=relations_path,
        relations=relations,
        relation_kinds=kinds,
        reference=reference,
        odometry=odometry,
        level=level_name,
        seed=int(seed),
        stamps_replaced=reference.stamps_replaced,
    )
