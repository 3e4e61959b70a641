"""Perturbed logs: GMapping-corrected CARMEN logs with synthetic wheel-odometry error.

The GMapping-corrected logs in ``carmen_gmapping_corrected/`` hold, for every scan,
the laser pose GMapping estimated (both pose triples of each FLASER line). Taken as
the reference trajectory ``x*_0 .. x*_{S-1}``, they let us make logs with known
poses and odometry as bad as we choose: the odometry is the reference increments
with noise and a slowly varying drift, and the scans are the logged ones. A filter
run on the perturbed log is scored against the reference with the relations metric
(:mod:`jaxslam.metrics.relations`) on relations sampled from the reference.

Odometry model: :mod:`jaxslam.datasets.odometry_noise` (noise proportional to the
motion plus slowly varying scale and heading drifts; :data:`~jaxslam.datasets.odometry_noise.NOISE_LEVELS`
gives two levels); so are the reference relations below
(:func:`~jaxslam.datasets.odometry_noise.reference_relations`).

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

from jaxslam.datasets.odometry_noise import (
    DRIFT_RADIUS,
    NOISE_LEVELS,
    OdometryNoise,
    perturb_odometry,
    reference_relations,
)
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

_COPIED_PARAMS = (
    "robot_front_laser_max",
    "laser_front_laser_resolution",
    "laser_front_laser_fov",
    "laser_front_laser_flipped",
)

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
        relations: the same relations as a :class:`~jaxslam.datasets.relations.Relations`.
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
        level: ``"low"``, ``"high"`` (:data:`~jaxslam.datasets.odometry_noise.NOISE_LEVELS`) or an
            :class:`~jaxslam.datasets.odometry_noise.OdometryNoise`.
        seed: seeds the odometry noise; the relations' loop sampling uses the
            reference alone (seed 0), so all seeds of a log share one relations set.
        out_dir: output folder (created).
        relation_options: passed to :func:`~jaxslam.datasets.odometry_noise.reference_relations`.
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
