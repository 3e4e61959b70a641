"""Figures with matplotlib (no display needed). The core never imports this module.

Every function takes NumPy-convertible arrays and returns the ``Figure``; ``save``
writes it as PNG and closes it.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from jaxslam.grid.export import row_blocks  # noqa: E402


def save(fig, path: str | Path, dpi: int = 130) -> Path:
    """Save ``fig`` as PNG and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # zlib level 1: files about 5% larger, written in two thirds of the time.
    fig.savefig(path, dpi=dpi, bbox_inches="tight", pil_kwargs={"compress_level": 1})
    plt.close(fig)
    return path


def covariance_ellipse(mean, cov, n_sigma: float = 3.0, **kwargs) -> Ellipse:
    """The ``n_sigma`` ellipse of a 2-D Gaussian as a matplotlib patch."""
    cov = np.asarray(cov, float)
    cov = 0.5 * (cov + cov.T)
    evals, evecs = np.linalg.eigh(cov)
    evals = np.clip(evals, 0.0, None)
    angle = np.degrees(np.arctan2(evecs[1, 1], evecs[0, 1]))
    width, height = 2 * n_sigma * np.sqrt(evals[1]), 2 * n_sigma * np.sqrt(evals[0])
    kwargs.setdefault("fill", False)
    return Ellipse(xy=np.asarray(mean, float), width=width, height=height, angle=angle, **kwargs)


def plot_landmark_slam(
    trajectory,
    landmark_means=None,
    landmark_covs=None,
    reference_xy=None,
    reference_label: str = "GPS",
    true_landmarks=None,
    title: str = "",
    n_sigma: float = 3.0,
):
    """Estimated path, a reference path (GPS or ground truth), landmarks with ellipses."""
    trajectory = np.asarray(trajectory)
    fig, ax = plt.subplots(figsize=(8, 8))
    if reference_xy is not None and len(reference_xy):
        ref = np.asarray(reference_xy)
        ax.plot(ref[:, 0], ref[:, 1], ".", ms=2, color="tab:blue", alpha=0.6, label=reference_label)
    if true_landmarks is not None and len(true_landmarks):
        tl = np.asarray(true_landmarks)
        ax.plot(tl[:, 0], tl[:, 1], "k+", ms=5, alpha=0.6, label="true landmarks")
    ax.plot(trajectory[:, 0], trajectory[:, 1], "-", color="tab:red", lw=1.0, label="estimate")
    if landmark_means is not None and len(landmark_means):
        lm = np.asarray(landmark_means)
        ax.plot(lm[:, 0], lm[:, 1], "x", color="tab:red", ms=3, label="landmarks")
        if landmark_covs is not None:
            for mean, cov in zip(lm, np.asarray(landmark_covs)):
                ax.add_patch(covariance_ellipse(mean, cov, n_sigma, color="k", lw=0.5, alpha=0.7))
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or f"trajectory and landmarks ({n_sigma:g}-sigma ellipses)")
    return fig


_MAX_FIGURE_CELLS = 2048


def plot_grid_map(log_odds, resolution: float, origin, trajectory=None, title: str = ""):
    """An occupancy map (log-odds, rows = y) with the trajectory over it.

    The view is cropped to the observed cells (non-zero log-odds) plus a 1 m margin;
    maps larger than 2048 cells are drawn from k x k block means.
    """
    log_odds = np.asarray(log_odds)
    observed_rows = np.zeros(log_odds.shape[0], bool)
    observed_cols = np.zeros(log_odds.shape[1], bool)
    for r0, r1 in row_blocks(log_odds.shape[0], log_odds.shape[1]):
        observed = np.abs(log_odds[r0:r1]) > 1e-6
        observed_rows[r0:r1] = observed.any(1)
        observed_cols |= observed.any(0)
    if observed_rows.any():
        pad = int(np.ceil(1.0 / resolution))
        rows, cols = np.nonzero(observed_rows)[0], np.nonzero(observed_cols)[0]
        r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, log_odds.shape[0])
        c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, log_odds.shape[1])
        log_odds = log_odds[r0:r1, c0:c1]
        origin = (origin[0] + c0 * resolution, origin[1] + r0 * resolution)
    h, w = log_odds.shape
    # A figure is about 1000 pixels wide: average blocks of k x k cells first so that
    # at most ~2000 x 2000 values reach matplotlib, whose resampling of a full-size
    # big map took seconds (the map files keep every cell). Done k rows at a time, so
    # a big map needs no full-size float copy.
    k = max(1, -(-max(h, w) // _MAX_FIGURE_CELLS))
    hk, wk = -(-h // k) * k, -(-w // k) * k
    free = np.empty((hk // k, wk // k), np.float32)
    for r0, r1 in row_blocks(h, wk, multiple=k):
        block = np.asarray(log_odds[r0:r1], np.float32)
        rows = -(-block.shape[0] // k) * k
        block = np.pad(block, ((0, rows - block.shape[0]), (0, wk - w)), mode="edge")
        with np.errstate(over="ignore"):
            block = 1.0 / (1.0 + np.exp(block))  # 1 - p(occupied)
        free[r0 // k : (r0 + rows) // k] = block.reshape(rows // k, k, wk // k, k).mean(axis=(1, 3))
    extent = [origin[0], origin[0] + wk * resolution, origin[1], origin[1] + hk * resolution]
    fig, ax = plt.subplots(figsize=(8, 8 * h / max(w, 1) + 0.5))
    ax.imshow(free, cmap="gray", origin="lower", extent=extent, vmin=0, vmax=1)
    if trajectory is not None:
        traj = np.asarray(trajectory)
        ax.plot(traj[:, 0], traj[:, 1], "-", color="tab:red", lw=0.8, label="trajectory")
        ax.legend(loc="best", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or "occupancy map")
    return fig


def plot_filter_health(ess, resampled, particles: int, weight_variance=None, title: str = ""):
    """Effective sample size (and weight variance) over steps, resampling steps marked."""
    ess = np.asarray(ess, float)
    resampled = np.asarray(resampled, bool)
    steps = np.arange(len(ess))
    rows = 2 if weight_variance is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(9, 2.8 * rows), sharex=True, squeeze=False)
    ax = axes[0, 0]
    ax.plot(steps, ess, lw=0.8, label="ESS")
    ax.axhline(particles, color="gray", lw=0.5, ls=":")
    if resampled.any():
        ax.plot(steps[resampled], ess[resampled], "v", color="tab:red", ms=3,
                label=f"resampled ({int(resampled.sum())})")
    ax.set_ylabel("ESS")
    ax.set_ylim(0, particles * 1.05)
    ax.legend(loc="best", fontsize=8)
    if weight_variance is not None:
        axes[1, 0].semilogy(steps, np.maximum(np.asarray(weight_variance, float), 1e-300), lw=0.8)
        axes[1, 0].set_ylabel("weight variance")
    axes[-1, 0].set_xlabel("step")
    axes[0, 0].set_title(title or "filter health")
    return fig
