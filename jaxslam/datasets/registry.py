"""The datasets jaxslam knows by name, what kind of SLAM they serve, and where they are.

``kind`` is ``"landmark"`` (feature SLAM: RB/ERB) or ``"laser"`` (grid SLAM:
SRUPF-GM, GMapping-style). Names starting with ``sim-`` are built-in simulators that
need no files.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from jaxslam.datasets.paths import DatasetNotFoundError, candidate_roots, find


@dataclass(frozen=True)
class DatasetInfo:
    """A named dataset: its SLAM kind, the files it needs, and scoring files."""

    name: str
    kind: str
    description: str
    files: tuple[tuple[str, ...], ...] = ()
    relations: tuple[str, ...] | None = None
    aliases: tuple[str, ...] = field(default=())

    @property
    def simulated(self) -> bool:
        return not self.files

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


_REL = "slam_benchmark_relations"
DATASETS: dict[str, DatasetInfo] = {
    info.name: info
    for info in [
        DatasetInfo("sim-landmarks", "landmark", "built-in landmark world with ground truth (default)"),
        DatasetInfo("sim-laser", "laser", "built-in laser world (rooms, corridors) with ground truth"),
        DatasetInfo(
            "victoria-park",
            "landmark",
            "ACFR Victoria Park: car, SICK laser, trees as landmarks, GPS",
            files=(
                ("victoria_park", "mat", "aa3_dr.npz"),
                ("victoria_park", "mat", "aa3_gpsx.npz"),
                ("victoria_park", "rfs_slam_ascii", "measurements.dat"),
            ),
            aliases=("victoria_park", "vp"),
        ),
        DatasetInfo("intel", "laser", "Intel Research Lab (Seattle), raw odometry",
                    files=(("carmen_raw", "intel.clf.gz"),), relations=(_REL, "intel.relations")),
        DatasetInfo("fr079", "laser", "Freiburg building 079, raw odometry",
                    files=(("carmen_raw", "fr079.clf.gz"),), relations=(_REL, "fr079.relations")),
        DatasetInfo("mit-csail", "laser", "MIT CSAIL building, raw odometry",
                    files=(("carmen_raw", "mit-csail.clf.gz"),), aliases=("csail",)),
        DatasetInfo("fr-clinic", "laser", "Freiburg university hospital, raw odometry",
                    files=(("carmen_raw", "fr-clinic_robotlaser.clf.gz"),)),
        DatasetInfo("mit-killian", "laser", "MIT Killian Court (rebuilt from an MRPT rawlog)",
                    files=(("carmen_raw", "mit-killian_reconstructed.clf.gz"),),
                    relations=(_REL, "mit-killian.relations")),
    ]
}


def lookup(name: str) -> DatasetInfo:
    """A dataset by name or alias; unknown names raise ``KeyError`` with the choices."""
    key = name.lower()
    for info in DATASETS.values():
        if key == info.name or key in info.aliases:
            return info
    raise KeyError(f"unknown dataset {name!r}; known: {', '.join(DATASETS)} (or a path to a CARMEN log)")


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
