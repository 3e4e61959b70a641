r"""Per-run summaries of a particle filter's ``Info`` history (host-side NumPy).

**Lineage changes of the best particle.** ``best[t]`` is the index of the best
particle at step ``t`` (before that step's resampling) and ``ancestors[t]`` the
resampling ancestors of step ``t`` (the identity when it did not resample): particle
``j`` of step ``t + 1`` descends from particle ``ancestors[t][j]`` of step ``t``.
The best particle changes lineage at step ``t + 1`` when it does not descend from the
best particle of step ``t``,

.. math:: \mathrm{changes} = \#\{t : a_t[b_{t+1}] \ne b_t\}.

A filter whose best particle keeps one history has few changes; one whose ranking of
histories flips (competing data associations, say) has many.

:func:`landmark_run_summary` reduces the landmark filter's ``Info`` of one run
(:class:`jaxslam.feature.filter.Info`, fields stacked over ``T``) to scalars: how often
the particles disagree on a data association, the spread of their landmark counts,
resamplings and surviving ancestors, weight entropy and the lineage changes.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np


def lineage_changes(best, ancestors) -> int:
    """Steps at which the best particle does not descend from the previous best.

    Args:
        best: ``(T,)`` index of the best particle per step (before resampling).
        ancestors: ``(T, N)`` resampling ancestors per step.
    """
    best = np.asarray(best)
    ancestors = np.asarray(ancestors)
    if best.ndim != 1 or ancestors.ndim != 2 or ancestors.shape[0] != best.shape[0]:
        raise ValueError(f"need best (T,) and ancestors (T, N), got {best.shape} and {ancestors.shape}")
    if best.size < 2:
        return 0
    parent = ancestors[np.arange(best.size - 1), best[1:]]
    return int(np.sum(parent != best[:-1]))


def coalescence_depth(ancestors, t: int) -> int:
    """Steps back from step ``t`` until every particle alive after step ``t`` has one
    common ancestor (``t + 1`` if they have none: a lower bound, as far back as the run).

    ``S_t = {a_t[j]}`` are the particles of step ``t`` (before resampling) with
    descendants; ``S_{s-1} = {a_{s-1}[i] : i in S_s}``; the depth is ``t - s`` for the
    latest ``s`` with ``|S_s| = 1``. It is how far back the particles' maps are one map:
    a landmark seen before that step exists in one version only.
    """
    ancestors = np.asarray(ancestors)
    alive = np.unique(ancestors[t])
    s = t
    while alive.size > 1 and s > 0:
        s -= 1
        alive = np.unique(ancestors[s][alive])
    return t - s if alive.size == 1 else t + 1


def ancestral_path(values, ancestors, final: int) -> np.ndarray:
    """The history of one particle: ``values`` of its ancestors at every step.

    ``values[t]`` are the particles' values after step ``t``'s resampling (``(T, N,
    ...)``, e.g. the state's poses) and ``ancestors[t]`` that resampling's ancestors
    (:class:`jaxslam.feature.filter.Info`): particle ``j`` after step ``t`` descends
    from particle ``ancestors[t][j]`` after step ``t - 1``. For the particle ``final``
    after the last step, ``j_{T-1} = final``, ``j_{t-1} = a_t[j_t]`` and the path is
    ``values[t][j_t]``: in a FastSLAM filter, the trajectory that particle's map was built
    from (the path posterior's sample), where the weighted mean of each step is the
    filtered estimate.

    Returns:
        ``(T, ...)``.
    """
    values = np.asarray(values)
    ancestors = np.asarray(ancestors)
    if ancestors.ndim != 2 or values.shape[:2] != ancestors.shape:
        raise ValueError(f"need values (T, N, ...) and ancestors (T, N), got {values.shape} and {ancestors.shape}")
    index = np.empty(ancestors.shape[0], np.int64)
    j = int(final)
    for t in range(ancestors.shape[0] - 1, -1, -1):
        index[t] = j
        j = int(ancestors[t, j])
    return values[np.arange(index.size), index]


def landmark_run_summary(
    info: Mapping[str, np.ndarray], obs_mask, particles: int, coalescence_stride: int = 50
) -> dict[str, float]:
    """Scalars of one landmark-filter run from its ``Info`` (fields ``(T, ...)``).

    Args:
        info: the stacked ``Info`` fields of one run (as a mapping of arrays).
        obs_mask: ``(T, Z)`` real observations of the sequence.
        particles: particle count ``N``.
        coalescence_stride: step stride of the coalescence samples.

    Returns:
        ``disagreement_per_obs``: observations whose decision (match/new/ignore)
        differs between particles, over the real observations of the steps in which
        the filter updated; ``disagreement_per_step`` the mean per step;
        ``landmark_spread_mean``/``landmark_spread_final``: most minus fewest landmarks
        over the particles, mean over steps and at the end; ``landmarks_best_final``;
        ``resamplings``; ``ancestors_fraction``: distinct survivors over ``N`` at the
        resampling steps (mean; NaN if it never resampled); ``entropy_ratio``: weight
        entropy over ``log N`` (mean over steps; NaN for ``N = 1``);
        ``lineage_changes`` (:func:`lineage_changes`); ``coalescence_steps``: mean of
        :func:`coalescence_depth` over every ``coalescence_stride``-th step of the
        second half of the run (``coalescence_censored``: the fraction that reached
        the start, lower bounds); ``dropped_landmarks`` (full
        tables), ``max_local_overflow``, ``nonfinite_particles`` and
        ``rejected_landmarks`` (totals over the run).
    """
    obs = np.asarray(obs_mask).sum(axis=1)
    updated = np.asarray(info["updated"], bool)
    disagree = np.asarray(info["association_disagreement"], np.float64)
    real = obs[updated].sum()
    spread = np.asarray(info["num_landmarks_max"]) - np.asarray(info["num_landmarks_min"])
    resampled = np.asarray(info["resampled"], bool)
    best_count = np.asarray(info["num_landmarks"], np.float64)
    low = np.asarray(info["num_landmarks_min"], np.float64)
    spread_steps = spread > 0
    T = resampled.size
    sample = np.arange(T // 2, T, coalescence_stride)
    depths = np.array([coalescence_depth(info["ancestors"], int(t)) for t in sample])
    return dict(
        disagreement_per_obs=float(disagree.sum() / real) if real else float("nan"),
        disagreement_per_step=float(disagree.mean()),
        landmark_spread_mean=float(spread.mean()),
        landmark_spread_final=float(spread[-1]),
        landmarks_best_final=float(np.asarray(info["num_landmarks"])[-1]),
        best_landmark_position=float(np.mean((best_count - low)[spread_steps] / spread[spread_steps]))
        if spread_steps.any() else float("nan"),
        best_minus_mean_landmarks=float(np.mean(best_count - np.asarray(info["num_landmarks_mean"]))),
        resamplings=int(resampled.sum()),
        ancestors_fraction=float(np.asarray(info["num_ancestors"])[resampled].mean() / particles)
        if resampled.any() else float("nan"),
        entropy_ratio=float(np.mean(info["weight_entropy"]) / math.log(particles)) if particles > 1 else float("nan"),
        lineage_changes=lineage_changes(info["best_particle"], info["ancestors"]),
        coalescence_steps=float(depths.mean()) if depths.size else float("nan"),
        coalescence_censored=float(np.mean(depths > sample)) if depths.size else float("nan"),
        dropped_landmarks=int(np.sum(info["num_dropped"])),
        max_local_overflow=int(np.max(info["local_overflow"])),
        nonfinite_particles=int(np.sum(info["num_nonfinite_particles"])),
        rejected_landmarks=int(np.sum(info["num_rejected_landmarks"])),
    )
