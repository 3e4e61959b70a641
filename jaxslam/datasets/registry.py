"""The one registry of what jaxslam knows about a dataset, and the algorithm names.

Each :class:`DatasetInfo` says

* what it is: its SLAM ``kind``, ``"landmark"`` (feature SLAM: RB/ERB) or ``"laser"``
  (grid SLAM: SRUPF-GM, GMapping-style), and a description;
* how to load it: its ``files`` below the data root, the ``loader`` that reads them
  and that loader's keyword ``options`` (how the files are to be read, e.g. the
  range limit of a log without one, or a zero laser offset for logs whose poses are
  laser poses); :meth:`DatasetInfo.load` does it;
* how to score a run on it: a ``relations`` file (Kümmerle et al.'s benchmark), its
  ``gps`` fixes, or the simulator's ``ground_truth`` (:attr:`DatasetInfo.scoring`).

Nothing an algorithm tunes on lives here: noise levels, thresholds and keyframe rules
come from the caller. Names starting with ``sim-`` are built-in simulators that need
no files. :data:`ALGORITHMS` maps each algorithm name to the kind of data it runs on.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.carmen import DEFAULT_FLASER_MAX_RANGE, CarmenLog, load_carmen
from jaxslam.datasets.paths import DatasetNotFoundError, candidate_roots, find

ALGORITHMS: dict[str, str] = {
    "erb-upf": "landmark",
    "rb-upf": "landmark",
    "srupf-gm": "laser",
    "srupf-gm-npc": "laser",
    "gmapping": "laser",
}
"""Every algorithm name, with the kind of data it runs on."""

DEFAULT_ALGORITHM = {"landmark": "erb-upf", "laser": "srupf-gm"}
"""The algorithm run on a kind of data when none is named."""

LOADERS = ("carmen", "victoria-park", "sim-landmarks", "sim-laser")


def algorithms(kind: str) -> tuple[str, ...]:
    """The algorithm names for ``kind`` data, in :data:`ALGORITHMS` order."""
    return tuple(name for name, of in ALGORITHMS.items() if of == kind)


@dataclass(frozen=True)
class DatasetInfo:
    """A named dataset: its SLAM kind, how to load it, how to score a run on it.

    Attributes:
        name: the name used on the command line.
        kind: ``"landmark"`` or ``"laser"``.
        description: one line for ``jaxslam datasets``.
        loader: one of ``LOADERS``: a CARMEN log (:func:`~jaxslam.datasets.carmen.load_carmen`
            on the single file), Victoria Park (:func:`~jaxslam.datasets.victoria_park.load_sequence`),
            or a simulator.
        files: path parts below the data root of each file needed.
        options: keyword defaults of the loader (how to read the files); a caller's
            keywords override them.
        relations: path parts of the benchmark relations file, if any.
        gps: scored against its GPS fixes (Victoria Park).
        aliases: other accepted names.
    """

    name: str
    kind: str
    description: str
    loader: str = "carmen"
    files: tuple[tuple[str, ...], ...] = ()
    options: dict[str, Any] = field(default_factory=dict)
    relations: tuple[str, ...] | None = None
    gps: bool = False
    aliases: tuple[str, ...] = field(default=())

    def __post_init__(self):
        if self.loader not in LOADERS:
            raise ValueError(f"dataset {self.name!r}: loader must be one of {LOADERS}, got {self.loader!r}")
        if self.kind not in DEFAULT_ALGORITHM:
            raise ValueError(f"dataset {self.name!r}: kind must be 'landmark' or 'laser', got {self.kind!r}")

    @property
    def simulated(self) -> bool:
        return not self.files

    @property
    def ground_truth(self) -> bool:
        """The simulators know the true poses (and, for landmarks, the true map)."""
        return self.simulated

    @property
    def scoring(self) -> str | None:
        """How a run is scored, one of ``"relations"``, ``"gps"``, ``"ground truth"`` or None."""
        if self.relations is not None:
            return "relations"
        if self.gps:
            return "gps"
        if self.ground_truth:
            return "ground truth"
        return None

    def paths(self) -> list[Path]:
        """Absolute paths of the files (raises DatasetNotFoundError naming what is missing)."""
        return [find(self.name, *parts) for parts in self.files]

    def found(self) -> bool:
        try:
            self.paths()
        except DatasetNotFoundError:
            return False
        return True

    def relations_path(self) -> Path | None:
        if self.relations is None:
            return None
        try:
            return find(self.name, *self.relations)
        except DatasetNotFoundError:
            return None

    def load(self, seed: int = 0, max_steps: int | None = None, **options: Any):
        """Load the dataset (or draw the simulator's world from ``seed``).

        A landmark sequence is cut to its first ``max_steps`` scans; a laser log is
        read whole (the grid runner stops after ``max_steps`` keyframes). ``options``
        go to the loader, over :attr:`options`.
        """
        options = {**self.options, **options}
        if self.loader == "carmen":
            from jaxslam.datasets.carmen import load_carmen

            return load_carmen(self.paths()[0], **options)
        if self.loader == "sim-laser":
            from jaxslam.datasets import laser_sim

            return laser_sim.simulate(seed=seed, **options)
        if self.loader == "sim-landmarks":
            from jaxslam.datasets import landmark_sim

            sequence = landmark_sim.simulate(seed=seed, **options)
        else:
            from jaxslam.datasets import victoria_park

            sequence = victoria_park.load_sequence(max_steps=max_steps, **options)
        return sequence if max_steps is None else truncate(sequence, max_steps)


def truncate(sequence, max_steps: int):
    """A landmark sequence cut to its first ``max_steps`` steps (GPS fixes are kept)."""
    t = sequence.times.shape[0]
    if max_steps >= t:
        return sequence
    changes = {}
    for item in dataclasses.fields(sequence):
        value = getattr(sequence, item.name)
        if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == t and not item.name.startswith("gps"):
            changes[item.name] = value[:max_steps]
    return dataclasses.replace(sequence, **changes)


def _carmen(name: str, description: str, folder: str, filename: str, **extra: Any) -> DatasetInfo:
    return DatasetInfo(name, "laser", description, files=((folder, filename),), **extra)


_REL = "slam_benchmark_relations"
_ENTRIES = [
    DatasetInfo("sim-landmarks", "landmark", "built-in landmark world with ground truth (default)",
                loader="sim-landmarks"),
    DatasetInfo("sim-laser", "laser", "built-in laser world (rooms, corridors) with ground truth", loader="sim-laser"),
    DatasetInfo(
        "victoria-park",
        "landmark",
        "ACFR Victoria Park: car, SICK laser, trees as landmarks, GPS",
        loader="victoria-park",
        files=(
            ("victoria_park", "mat", "aa3_dr.npz"),
            ("victoria_park", "mat", "aa3_gpsx.npz"),
            ("victoria_park", "rfs_slam_ascii", "measurements.dat"),
        ),
        gps=True,
        aliases=("victoria_park", "vp"),
    ),
    _carmen("intel", "Intel Research Lab (Seattle), raw odometry", "carmen_raw", "intel.clf.gz",
            relations=(_REL, "intel.relations")),
    _carmen("fr079", "Freiburg building 079, raw odometry", "carmen_raw", "fr079.clf.gz",
            relations=(_REL, "fr079.relations")),
    _carmen("mit-csail", "MIT CSAIL building, raw odometry", "carmen_raw", "mit-csail.clf.gz", aliases=("csail",)),
    # A ROBOTLASER1 log whose scans change geometry: padded to one beam count.
    _carmen("fr-clinic", "Freiburg university hospital, raw odometry", "carmen_raw", "fr-clinic_robotlaser.clf.gz",
            options={"mixed_geometry": "pad", "max_range": DEFAULT_FLASER_MAX_RANGE}),
    _carmen("mit-killian", "MIT Killian Court (rebuilt from an MRPT rawlog)", "carmen_raw",
            "mit-killian_reconstructed.clf.gz", relations=(_REL, "mit-killian.relations")),
    _carmen("mrpt-sena", "MRPT: SENA Telecom faculty, one loop", "mrpt",
            "2006-01ENE-21-SENA_Telecom_Faculty_one_loop_only.clf.gz"),
    _carmen("mrpt-localization-demo", "MRPT: localization demo", "mrpt", "localization_demo.clf.gz"),
    _carmen("mrpt-ual", "MRPT: UAL 2014 2-D laser and odometry", "mrpt", "ual_dataset_2014_05_23_2dlaser_odo.clf.gz"),
]
# GMapping-corrected logs: both pose triples of a FLASER line hold the corrected laser
# pose, so the laser offset is zero. No per-log range limits: the "no return" piles of
# Killian, Acapulco, FHW, Infinite Corridor and Orebro (about 51.1 m and 32.76 m) are
# found by detect_no_return, for a path as for a name.
_CORRECTED_ALIASES = {"freiburg-079": ("fr079-corrected",), "csail": ("mit-csail-corrected",)}
for _place in (
    "acapulco belgioioso csail edmonton fhw freiburg-079 freiburg-101 freiburg-campus "
    "infinite-corridor intel orebro seattle"
).split():
    _ENTRIES.append(_carmen(
        f"{_place}-corrected", f"{_place}, GMapping-corrected poses", "carmen_gmapping_corrected",
        f"{_place}-corrected.log.gz", options={"laser_offset": (0.0, 0.0, 0.0)},
        aliases=_CORRECTED_ALIASES.get(_place, ()),
    ))

DATASETS: dict[str, DatasetInfo] = {info.name: info for info in _ENTRIES}


def lookup(name: str) -> DatasetInfo:
    """A dataset by name or alias; unknown names raise ``KeyError`` with the choices."""
    key = name.lower()
    for info in DATASETS.values():
        if key == info.name or key in info.aliases:
            return info
    raise KeyError(f"unknown dataset {name!r}; known: {', '.join(DATASETS)}")


def for_file(path: Path | str) -> DatasetInfo | None:
    """The registered CARMEN log whose file has the name of ``path``, or None."""
    name = Path(path).name
    for info in DATASETS.values():
        if info.loader == "carmen" and Path(*info.files[0]).name == name:
            return info
    return None


def load_dataset_log(name: os.PathLike | str, **options: Any) -> CarmenLog:
    """Load a registered CARMEN log by name, or any CARMEN log by path.

    Names are those of :mod:`jaxslam.datasets.registry` with a CARMEN loader:
    ``intel``, ``fr079``, ``mit-csail``, ``fr-clinic``, ``mit-killian`` (raw logs in
    ``carmen_raw/``), ``<place>-corrected`` (GMapping-corrected logs in
    ``carmen_gmapping_corrected/``, with ``laser_offset`` zero because their poses are
    laser poses), and ``mrpt-sena``, ``mrpt-localization-demo``, ``mrpt-ual``; each
    entry's ``options`` are its reading defaults.

    Args:
        name: a name above, or a path to a log file.
        **options: keyword arguments for :func:`~jaxslam.datasets.carmen.load_carmen`; they override the
            per-log defaults.
    """
    key = str(name)
    try:
        info = lookup(key)
    except KeyError:
        info = None
    if info is not None and info.loader == "carmen":
        return info.load(**options)
    path = Path(name)
    if path.is_file():
        return load_carmen(path, **options)
    known = ", ".join(sorted(n for n, i in DATASETS.items() if i.loader == "carmen"))
    raise FileNotFoundError(f"{key!r} is neither a known CARMEN log ({known}) nor a file")


def describe() -> list[dict]:
    """One row per dataset: name, kind, found, where (for ``jaxslam datasets``)."""
    rows = []
    for info in DATASETS.values():
        if info.simulated:
            rows.append({"name": info.name, "kind": info.kind, "found": True, "where": "(built in)",
                         "description": info.description})
            continue
        try:
            where = ", ".join(str(p) for p in info.paths())
            found = True
        except DatasetNotFoundError:
            where = "missing: " + ", ".join("/".join(parts) for parts in info.files)
            found = False
        rows.append({"name": info.name, "kind": info.kind, "found": found, "where": where,
                     "description": info.description})
    return rows


def roots_text() -> str:
    return ", ".join(str(r) for r in candidate_roots())
