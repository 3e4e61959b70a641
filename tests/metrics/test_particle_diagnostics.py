"""Lineage changes and the run summary of the landmark filter's Info."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxslam.metrics.particle_diagnostics import (
    ancestral_path,
    coalescence_depth,
    landmark_run_summary,
    lineage_changes,
)


def _lineage_forward(best, ancestors):
    """Reference: propagate the set of descendants of each step's best particle
    forward through the resampling and test membership of the next best."""
    T, N = ancestors.shape
    changes = 0
    for t in range(T - 1):
        marked = np.zeros(N, bool)
        marked[best[t]] = True
        children = [j for j in range(N) if marked[ancestors[t][j]]]
        if best[t + 1] not in children:
            changes += 1
    return changes


def test_lineage_changes_hand_example():
    ancestors = np.array([[0, 1, 2], [1, 1, 0], [0, 1, 2], [2, 2, 2]])
    # step 0 best 1; step 1 particle 0 descends from 0 (change); best 0 at step 1;
    # step 2 particle 2 descends from ancestors[1][2] = 0 (same); step 3 particle 1
    # descends from 1 != 2 (change)
    best = np.array([1, 0, 2, 1])
    assert lineage_changes(best, ancestors) == 2


def _random_ancestors(rng, T, N, rate):
    """Ancestors of T steps, N particles: the identity, or (with probability ``rate``)
    a multinomial draw."""
    ancestors = np.tile(np.arange(N), (T, 1))
    resample = rng.random(T) < rate
    ancestors[resample] = rng.integers(0, N, (resample.sum(), N))
    return ancestors


@pytest.mark.parametrize("seed", range(5))
def test_lineage_changes_matches_tracing(seed):
    rng = np.random.default_rng(seed)
    ancestors = _random_ancestors(rng, 40, 5, 0.4)
    best = rng.integers(0, 5, 40)
    assert lineage_changes(best, ancestors) == _lineage_forward(best, ancestors)


def test_lineage_changes_bad_shapes():
    with pytest.raises(ValueError, match="ancestors"):
        lineage_changes(np.zeros(3, int), np.zeros((4, 2), int))
    assert lineage_changes(np.zeros(1, int), np.zeros((1, 2), int)) == 0


def _coalescence_by_genealogy(ancestors, t):
    """Reference: the root (step-s particle) of every particle alive after step t, for
    s = t, t-1, ...; the depth is t - s for the latest s where the roots are one."""
    N = ancestors.shape[1]
    for s in range(t, -1, -1):
        roots = set()
        for j in range(N):
            i = ancestors[t][j]
            for r in range(t - 1, s - 1, -1):
                i = ancestors[r][i]
            roots.add(i)
        if len(roots) == 1:
            return t - s
    return t + 1


@pytest.mark.parametrize("seed", range(6))
def test_coalescence_depth_matches_genealogy(seed):
    T = 30
    ancestors = _random_ancestors(np.random.default_rng(seed), T, 4, 0.5)
    for t in range(T):
        assert coalescence_depth(ancestors, t) == _coalescence_by_genealogy(ancestors, t)


def test_coalescence_depth_cases():
    ident = np.tile(np.arange(3), (5, 1))
    assert coalescence_depth(ident, 4) == 5  # never merged: censored at t + 1
    collapsed = ident.copy()
    collapsed[2] = [1, 1, 1]
    assert coalescence_depth(collapsed, 4) == 2
    assert coalescence_depth(collapsed, 2) == 0


def test_landmark_run_summary():
    T, N = 4, 4
    info = dict(
        updated=np.array([True, True, False, True]),
        association_disagreement=np.array([1, 0, 0, 2]),
        num_landmarks_min=np.array([1, 2, 2, 3]),
        num_landmarks_max=np.array([1, 4, 4, 5]),
        num_landmarks=np.array([1, 3, 3, 5]),
        num_landmarks_mean=np.array([1.0, 3.5, 3.0, 4.5]),
        resampled=np.array([False, True, False, True]),
        num_ancestors=np.array([4, 2, 4, 1]),
        weight_entropy=np.full(T, math.log(N) / 2),
        best_particle=np.array([0, 0, 1, 1]),
        ancestors=np.array([[0, 1, 2, 3], [3, 3, 0, 0], [0, 1, 2, 3], [1, 1, 1, 1]]),
        num_dropped=np.array([0, 0, 0, 3]),
        local_overflow=np.array([0, 2, 0, 1]),
        num_nonfinite_particles=np.array([0, 1, 0, 0]),
        num_rejected_landmarks=np.array([2, 0, 0, 1]),
    )
    obs_mask = np.array([[1, 1, 0], [1, 0, 0], [1, 1, 1], [1, 1, 1]], bool)
    s = landmark_run_summary(info, obs_mask, N)
    assert s["disagreement_per_obs"] == pytest.approx(3 / 6)  # the idle step's 3 observations do not count
    assert s["disagreement_per_step"] == pytest.approx(3 / 4)
    assert s["landmark_spread_mean"] == pytest.approx(1.5)
    assert s["landmark_spread_final"] == 2
    assert s["landmarks_best_final"] == 5
    assert s["best_landmark_position"] == pytest.approx((0.5 + 0.5 + 1.0) / 3)
    assert s["best_minus_mean_landmarks"] == pytest.approx((0 - 0.5 + 0 + 0.5) / 4)
    assert s["resamplings"] == 2
    assert s["ancestors_fraction"] == pytest.approx((2 + 1) / 2 / N)
    assert s["entropy_ratio"] == pytest.approx(0.5)
    # step 1: best 0 descends from ancestors[0][0] = 0 == 0; step 2: best 1 from
    # ancestors[1][1] = 3 != 0 (change); step 3: best 1 from ancestors[2][1] = 1 == 1
    assert s["lineage_changes"] == 1
    # sampled step t = 2: survivors {0, 1, 2, 3} -> {3, 0} -> {3, 0}: never one (censored)
    assert s["coalescence_steps"] == 3 and s["coalescence_censored"] == 1.0
    assert s["dropped_landmarks"] == 3
    assert s["max_local_overflow"] == 2
    assert s["nonfinite_particles"] == 1 and s["rejected_landmarks"] == 3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ancestral_path_is_the_history_each_particle_carries(seed):
    """A filter whose particles carry their whole history as a list (copied when
    resampled) gives the same path as tracing the ancestors back."""
    rng = np.random.default_rng(seed)
    steps, n = 30, 6
    histories = [[] for _ in range(n)]
    values = np.zeros((steps, n, 2))
    ancestors = np.zeros((steps, n), np.int64)
    for t in range(steps):
        for j in range(n):
            histories[j].append((t, rng.normal()))
        ancestors[t] = rng.integers(0, n, n) if rng.random() < 0.5 else np.arange(n)
        histories = [list(histories[a]) for a in ancestors[t]]
        values[t] = [h[-1] for h in histories]
    for final in range(n):
        np.testing.assert_array_equal(ancestral_path(values, ancestors, final), np.array(histories[final]))
    with pytest.raises(ValueError):
        ancestral_path(values[:, :3], ancestors, 0)
