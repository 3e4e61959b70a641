r"""The path a run reports after the loop-closure watch undid closures (host, NumPy).

:func:`jaxslam.grid.closure.closure_phases` watches every closure it takes over the next
``closure.watch`` m of odometry and undoes one whose scans keep ending in space the old
map has seen through. On the device the undo only moves the pose back from the scan
that decides it (``Info.track_undo``); the scans tracked in the closure's frame before
that keep their poses. This module is what the reports do with those rows on the host:
:func:`take_back` moves the undone windows back into the frame the filter kept,
:func:`put_back` restores the path as tracked (for diagnostics of the closures
themselves), and :func:`judge_at_end` judges the closure still watched when the log
ends, on the scans it had (:func:`reported_undo` appends its row).
"""

from __future__ import annotations

import numpy as np

from jaxslam.datasets.geometry import se2_compose, se2_inverse


def take_back(poses: np.ndarray, scans: np.ndarray, undo: np.ndarray) -> np.ndarray:
    r"""Host: ``poses`` (world, of scans ``scans``) with every closure that was undone
    taken back on the scans it moved.

    ``undo (S-1, 4)`` is ``Info.track_undo`` of scans ``1..S-1``
    (:func:`jaxslam.grid.closure.closure_phases`): at a scan :math:`b` that undid a closure
    taken :math:`n` scans before with correction :math:`A`, the scans
    :math:`b-n \le s < b` were tracked in the closure's frame
    (:math:`x = A \oplus x_{local}`), and scan :math:`b` on is back in the frame before
    it. The filter has decided that the closure was an alias, so the path it reports
    puts those scans where the frame it kept has them, :math:`A^{-1} \oplus x_s`, as a
    lineage's poses are reported after the resamplings that chose it. (The maps keep
    what those scans wrote.) Undone windows never overlap: a closure taken inside
    another's watch restarts it, and only the last one is undone.
    """
    return _move_windows(poses, scans, undo, inverse=True)


def put_back(poses: np.ndarray, scans: np.ndarray, undo: np.ndarray) -> np.ndarray:
    r"""Host: the inverse of :func:`take_back`, the path as it was tracked
    (:math:`A \oplus x_s` on each undone window): what a diagnostic of the closures
    themselves has to read, since the reported path hides an undone one."""
    return _move_windows(poses, scans, undo, inverse=False)


def judge_at_end(memory, params) -> np.ndarray:
    r"""Host: the closure still watched when the run ends, judged on the scans it had.

    The watch of :func:`jaxslam.grid.closure.closure_phases` runs over ``closure.watch`` m of
    odometry; a log that ends sooner leaves its last closure unjudged. The path reported
    judges it on the :math:`n` scans watched (``memory.conflict_count``, after the closure's own
    scan), whose shares of beams ending in known free space sum to :math:`\Sigma`
    (``memory.conflict_sum``): it is undone where

    .. math:: n \ge 2, \qquad \Sigma > u_{end}\, n

    (``closure.undo_end``, 1: never). The bar is above ``closure.undo`` because fewer
    scans are averaged: over a few watched scans the share of a right closure
    often exceeds ``closure.undo`` by chance, and rarely 0.2, while most closures that
    a full watch undoes exceed it.

    Args:
        memory: the final state's :class:`~jaxslam.grid.types.ClosureState` (host values).
        params: the run's :class:`~jaxslam.grid.types.GridSlamParams` (host values).

    Returns:
        ``(4,)`` the row :func:`take_back` reads after the last scan's: ``[n + 1, A]``
        (the closure's scan and the ``n`` watched ones, ``A`` the correction the
        tracking applied, ``memory.applied``), or zeros.
    """
    count, total = float(memory.conflict_count), float(memory.conflict_sum)
    if float(memory.watch) > 0 and count >= 2 and total > float(params.closure.undo_end) * count:
        return np.concatenate([[count + 1.0], np.asarray(memory.applied, np.float64)])
    return np.zeros(4)


def reported_undo(track_undo: np.ndarray, end: np.ndarray | None) -> np.ndarray:
    """``(S, 4)``: ``Info.track_undo`` of scans ``1..S-1`` and the end's row
    (:func:`judge_at_end`; None: zeros), for :func:`take_back` over ``S`` scans."""
    rows = np.asarray(track_undo, np.float64).reshape(-1, 4)
    last = np.zeros(4) if end is None else np.asarray(end, np.float64).reshape(4)
    return np.concatenate([rows, last[None]], 0)


def _move_windows(poses, scans, undo, inverse: bool) -> np.ndarray:
    out = np.array(poses, np.float64, copy=True)
    undo = np.asarray(undo, np.float64).reshape(-1, 4)
    scans = np.asarray(scans, np.int64)
    for row in np.flatnonzero(undo[:, 0] > 0):
        b = row + 1
        inside = (scans >= b - int(round(undo[row, 0]))) & (scans < b)
        if np.any(inside):
            correction = se2_inverse(undo[row, 1:]) if inverse else undo[row, 1:]
            out[inside] = se2_compose(correction[None], out[inside])
    return out


__all__ = ["judge_at_end", "put_back", "reported_undo", "take_back"]
