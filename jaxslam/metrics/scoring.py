r"""Scores of a run, by what its dataset's registry entry offers.

:mod:`jaxslam.datasets.registry` says how a dataset is scored:

* ``"relations"`` — Kümmerle et al.'s relations metric
  (:func:`jaxslam.metrics.relations.relations_metric`);
* ``"gps"`` — the error against GPS after rigid alignment
  (:func:`jaxslam.metrics.gps.gps_error`);
* ``"ground truth"`` — the simulators' true poses: the position error
  :math:`e_t = \lVert \hat p_t - p_t \rVert` summarised by :func:`position_errors`, and
  for landmark runs the mean pose NEES (:func:`jaxslam.metrics.nees.pose_nees`,
  expectation 3).

Host-side NumPy.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

NEES_EXPECTED = 3.0
"""Expected pose NEES of a consistent filter (the pose has 3 degrees of freedom)."""

MIN_MATCHED_FRACTION = 0.9
"""Below this share of the relations (or GPS fixes) scored, ``jaxslam evaluate`` warns
that its score covers part of the reference only. A whole run matches nearly all of
them: a benchmark relation is made between two scans of its log, and only GPS fixes
that jump are dropped (a percent or less)."""


def matched_counts(scores: dict[str, Any]) -> tuple[int, int, str] | None:
    """``(scored, total, what)`` of a score dict: the relations scored of those in the
    file (:func:`jaxslam.metrics.relations.relations_metric`), or the GPS fixes used of
    those loaded (:func:`jaxslam.metrics.gps.gps_error`); None for other scores."""
    if "n_relations" in scores and "n_total" in scores:
        return int(scores["n_relations"]), int(scores["n_total"]), "relations"
    if "n_used" in scores and "n_skipped" in scores:
        return int(scores["n_used"]), int(scores["n_used"]) + int(scores["n_skipped"]), "GPS fixes"
    return None


def position_errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Mean, RMS and largest distance between the positions of two ``(T, >=2)`` pose
    arrays: ``pos_err_mean_m``, ``pos_err_rms_m``, ``pos_err_max_m``."""
    errors = np.linalg.norm(np.asarray(estimate)[:, :2] - np.asarray(truth)[:, :2], axis=1)
    return {"pos_err_mean_m": float(errors.mean()), "pos_err_rms_m": float(np.sqrt((errors**2).mean())),
            "pos_err_max_m": float(errors.max())}


@dataclasses.dataclass
class LandmarkScores:
    """Scores of a landmark run and the reference drawn beside its trajectory.

    Attributes:
        scores: summary entries (see the module docstring).
        reference_xy: ``(R, 2)`` GPS fixes mapped into the filter's frame, or the true
            positions; None when the dataset has no reference.
        reference_label: the reference's legend label.
        true_landmarks: ``(M, 2)`` the simulator's landmarks, or None.
    """

    scores: dict[str, Any]
    reference_xy: np.ndarray | None = None
    reference_label: str = ""
    true_landmarks: np.ndarray | None = None


def score_landmark_run(info, result, sequence) -> LandmarkScores:
    """Score a landmark run (:class:`jaxslam.feature.experiment.LandmarkSlamResult`) on
    ``sequence`` as its registry entry ``info`` says."""
    if info.scoring == "gps":
        from jaxslam.metrics.gps import gps_error

        found = gps_error(result.times, result.trajectory[:, :2], sequence.gps_times, sequence.gps_xy)
        scores = {k: found[k] for k in ("gps_mean_m", "gps_rms_m", "gps_max_m", "n_used", "n_skipped")}
        scores["gps_alignment"] = {"rotation_rad": found["rotation_rad"], "translation": found["translation"]}
        rot, trans = np.asarray(found["rotation"]), np.asarray(found["translation"])
        reference_xy = (np.asarray(sequence.gps_xy) - trans) @ rot  # GPS mapped into the filter frame
        return LandmarkScores(scores, reference_xy[np.asarray(found["used"], bool)], "GPS (aligned)")
    if info.scoring == "ground truth":
        from jaxslam.metrics.nees import pose_nees

        scores: dict[str, Any] = position_errors(result.trajectory, sequence.true_poses)
        nees = pose_nees(result.trajectory, result.pose_covs, sequence.true_poses)
        scores["nees_mean"] = float(np.nanmean(nees))
        scores["nees_expected"] = NEES_EXPECTED
        return LandmarkScores(scores, sequence.true_poses[:, :2], "ground truth", sequence.landmarks)
    return LandmarkScores({})


def score_grid_run(info, result, log) -> dict[str, Any]:
    """Score a grid run (:class:`jaxslam.grid.experiment.GridSlamResult`) on ``log``:
    the relations metric where the registry entry ``info`` has a relations file that is
    found, the position error where the log carries true poses (simulator)."""
    scores: dict[str, Any] = {}
    relations = info.relations_path() if info is not None else None
    if relations is not None:
        from jaxslam.metrics.relations import load_relations, relations_metric

        scores.update(relations_metric(load_relations(relations), result.scan_times, result.trajectory))
    if hasattr(log, "true_poses"):
        # A run cut short (max_keyframes) has poses for the scans it processed.
        scores.update(position_errors(result.trajectory, log.true_poses[: result.trajectory.shape[0]]))
    return scores
