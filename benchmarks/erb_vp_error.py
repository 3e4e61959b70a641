"""Where the Victoria Park GPS error of the landmark filter comes from, over seeds.

One ensemble (:func:`jaxslam.feature.ensemble.run_landmark_ensemble`, the defaults,
seeds 0..S-1, every particle's pose recorded), then per seed and as seed statistics:

* **Filtered estimate against the path.** The GPS error (:func:`jaxslam.metrics.gps.gps_error`)
  of the weighted mean of each step (what ``erb_particles.py`` scores) and of the final
  best particle's ancestral path (:func:`jaxslam.metrics.particle_diagnostics.ancestral_path`:
  the trajectory its map was built from, after every loop closure).
* **Error by time** (100 s bins): mean over seeds, smallest and largest seed.
* **Episodes.** For each window of ``--episodes``: the error under the whole-run
  alignment against the error after a rigid alignment on that window alone (the
  trajectory's local shape), the same for dead reckoning alone (the sequence's
  controls, ``.mat`` and ACFR's recalibrated steering), the episode's share of the
  run's squared error, and the coalescence depth of the particles at the episode's end
  (:func:`jaxslam.metrics.particle_diagnostics.coalescence_depth`) beside its length in
  steps.
* **The metric itself.** A body-frame offset between the laser (the filter's pose) and
  the GPS antenna fitted together with the alignment; the GPS shifted in time by
  -0.5..0.5 s; the jump rejection switched off.

    python benchmarks/erb_vp_error.py [--algorithm erb-upf] [--particles 100] [--seeds 10]

Writes ``benchmarks/results/<name>.json`` and ``<name>.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, write_json  # noqa: E402

from jaxslam.datasets import landmark_sim, victoria_park  # noqa: E402
from jaxslam.runtime.driver import best_particle  # noqa: E402
from jaxslam.feature.ensemble import run_landmark_ensemble  # noqa: E402
from jaxslam.metrics.gps import align_rigid_2d, gps_error, gps_jump_mask  # noqa: E402
from jaxslam.metrics.particle_diagnostics import ancestral_path, coalescence_depth  # noqa: E402
from jaxslam.metrics.stats import mean_ci  # noqa: E402

EPISODES = ((1000.0, 1130.0), (1230.0, 1380.0))
"""The two stretches of the drive where the seeds' errors peak (100 s bins of the
default run): the car maps new ground and closes a loop at their end."""


def dead_reckoning(seq) -> np.ndarray:
    """``(T, 3)`` poses of the car model (the simulator's NumPy step) over the
    sequence's control rows, the pose after each step."""
    geometry = (victoria_park.CAR_GEOMETRY["L"], victoria_park.CAR_GEOMETRY["H"], *victoria_park.LASER_OFFSET)
    pose = np.zeros(3)
    poses = np.zeros((seq.controls.shape[0], 3))
    for t, rows in enumerate(seq.controls):
        for speed, steering, dt in rows:
            if dt > 0:
                pose = landmark_sim._move(pose, speed, steering, dt, geometry)
        poses[t] = pose
    return poses


def window_error(seq, times, poses, t0, t1) -> float:
    """Mean GPS error of ``poses`` over the fixes in ``[t0, t1)`` (jump-rejected) after a
    rigid alignment on those fixes alone."""
    keep = gps_jump_mask(seq.gps_times, seq.gps_xy) & (seq.gps_times >= t0) & (seq.gps_times < t1)
    points = np.stack([np.interp(seq.gps_times[keep], times, poses[:, i]) for i in range(2)], axis=1)
    rotation, translation = align_rigid_2d(points, seq.gps_xy[keep])
    return float(np.linalg.norm(points @ rotation.T + translation - seq.gps_xy[keep], axis=1).mean())


def lever_arm_fit(seq, times, poses, iterations: int = 30) -> tuple[np.ndarray, float]:
    """Body-frame offset ``d`` of the GPS antenna from the pose, fitted with the rigid
    alignment (alternating: Kabsch for the rotation, linear least squares for ``d`` and
    the translation); returns ``d`` and the mean error with it."""
    keep = gps_jump_mask(seq.gps_times, seq.gps_xy) & (seq.gps_times >= times[0]) & (seq.gps_times <= times[-1])
    fix_times, fixes = seq.gps_times[keep], seq.gps_xy[keep]
    points = np.stack([np.interp(fix_times, times, poses[:, i]) for i in range(2)], axis=1)
    heading = np.interp(fix_times, times, np.unwrap(poses[:, 2]))
    forward = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    left = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    offset = np.zeros(2)
    for _ in range(iterations):
        rotation, _ = align_rigid_2d(points + forward * offset[0] + left * offset[1], fixes)
        design = np.zeros((2 * len(fixes), 4))
        design[:, 0] = (forward @ rotation.T).reshape(-1)
        design[:, 1] = (left @ rotation.T).reshape(-1)
        design[0::2, 2] = 1.0
        design[1::2, 3] = 1.0
        offset = np.linalg.lstsq(design, (fixes - points @ rotation.T).reshape(-1), rcond=None)[0][:2]
    moved = points + forward * offset[0] + left * offset[1]
    rotation, translation = align_rigid_2d(moved, fixes)
    return offset, float(np.linalg.norm(moved @ rotation.T + translation - fixes, axis=1).mean())


def stats(values) -> dict:
    found = mean_ci(list(values))
    return dict(mean=found["mean"], std=found["std"], ci=[found["ci_low"], found["ci_high"]],
                per_seed=[float(v) for v in values])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algorithm", default="erb-upf")
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--name", default="erb_vp_error")
    args = parser.parse_args()

    seq = victoria_park.load_sequence("detections", max_range=30.0)
    seeds = list(range(args.seeds))
    res = run_landmark_ensemble(seq, args.algorithm, particles=args.particles, seeds=seeds, record_poses=True)
    times = seq.times
    filtered, paths, errors = [], [], []
    for i in range(len(seeds)):
        final = jax.tree_util.tree_map(lambda x: x[i], res.state)
        path = ancestral_path(res.particle_poses[i], res.info["ancestors"][i], int(best_particle(final)))
        found = gps_error(times, res.trajectory[i], seq.gps_times, seq.gps_xy)
        filtered.append(found)
        paths.append(gps_error(times, path, seq.gps_times, seq.gps_xy))
        errors.append(found["errors_m"])
    errors = np.array(errors)
    used = filtered[0]["used"]
    out = dict(algorithm=args.algorithm, particles=args.particles, seeds=seeds, wall_s=res.wall_s)
    out["filtered_gps_mean_m"] = stats([f["gps_mean_m"] for f in filtered])
    out["filtered_gps_rms_m"] = stats([f["gps_rms_m"] for f in filtered])
    out["best_path_gps_mean_m"] = stats([p["gps_mean_m"] for p in paths])
    out["best_path_gps_rms_m"] = stats([p["gps_rms_m"] for p in paths])

    bins = []
    for t0 in np.arange(0.0, times[-1], 100.0):
        inside = used & (seq.gps_times >= t0) & (seq.gps_times < t0 + 100.0)
        per_seed = errors[:, inside].mean(axis=1)
        bins.append(dict(start_s=float(t0), fixes=int(inside.sum()), mean=float(per_seed.mean()),
                         min=float(per_seed.min()), max=float(per_seed.max())))
    out["by_time"] = bins

    dr = {"mat": dead_reckoning(seq), "acfr": dead_reckoning(victoria_park.load_sequence(steering="acfr"))}
    squared_total = np.nansum(errors**2, axis=1)
    episodes = []
    for t0, t1 in EPISODES:
        inside = used & (seq.gps_times >= t0) & (seq.gps_times < t1)
        end = int(np.searchsorted(times, t1)) - 1
        episodes.append(dict(
            window_s=[t0, t1], steps=int(np.sum((times >= t0) & (times < t1))),
            global_alignment=stats(errors[:, inside].mean(axis=1)),
            local_alignment=stats([window_error(seq, times, res.trajectory[i], t0, t1) for i in range(len(seeds))]),
            dead_reckoning_local_mat=window_error(seq, times, dr["mat"], t0, t1),
            dead_reckoning_local_acfr=window_error(seq, times, dr["acfr"], t0, t1),
            share_of_squared_error=stats(np.nansum(errors[:, inside] ** 2, axis=1) / squared_total),
            coalescence_depth_at_end=stats([coalescence_depth(res.info["ancestors"][i], end) for i in range(len(seeds))]),
        ))
    out["episodes"] = episodes
    outside = used.copy()
    for t0, t1 in EPISODES:
        outside &= ~((seq.gps_times >= t0) & (seq.gps_times < t1))
    out["outside_episodes_gps_mean_m"] = stats(errors[:, outside].mean(axis=1))

    levers = [lever_arm_fit(seq, times, res.trajectory[i]) for i in range(len(seeds))]
    out["lever_arm"] = dict(offset_m=[lev[0].tolist() for lev in levers], gps_mean_m=stats([lev[1] for lev in levers]))
    out["time_shift"] = {
        f"{shift:+.1f}": stats([gps_error(times + shift, res.trajectory[i], seq.gps_times, seq.gps_xy)["gps_mean_m"]
                                for i in range(len(seeds))])
        for shift in (-0.5, -0.2, 0.0, 0.2, 0.5)
    }
    out["no_jump_rejection"] = stats([gps_error(times, res.trajectory[i], seq.gps_times, seq.gps_xy,
                                                max_speed=1e12)["gps_mean_m"] for i in range(len(seeds))])
    path = write_json(args.name, out)

    f, p = out["filtered_gps_mean_m"], out["best_path_gps_mean_m"]
    print(f"filtered {f['mean']:.2f} +- {f['std']:.2f} m; best particle's path {p['mean']:.2f} +- {p['std']:.2f} m")
    for e in episodes:
        print(f"episode {e['window_s']}: global {e['global_alignment']['mean']:.2f} m, local "
              f"{e['local_alignment']['mean']:.2f} m, DR local .mat {e['dead_reckoning_local_mat']:.2f} / ACFR "
              f"{e['dead_reckoning_local_acfr']:.2f} m, share of squared error "
              f"{e['share_of_squared_error']['mean']:.2f}, coalescence at end "
              f"{e['coalescence_depth_at_end']['mean']:.0f} of {e['steps']} steps")
    print(f"outside the episodes {out['outside_episodes_gps_mean_m']['mean']:.2f} m; lever arm "
          f"{np.mean(out['lever_arm']['offset_m'], axis=0).round(2)} m -> {out['lever_arm']['gps_mean_m']['mean']:.2f} m; "
          "time shift " + ", ".join(f"{k}: {v['mean']:.2f}" for k, v in out["time_shift"].items())
          + f"; no jump rejection {out['no_jump_rejection']['mean']:.2f} m")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5), gridspec_kw=dict(width_ratios=[1.6, 1]))
    fix_times = seq.gps_times[used]
    axes[0].fill_between(fix_times, np.nanmin(errors[:, used], 0), np.nanmax(errors[:, used], 0), color="0.85",
                         label="smallest to largest seed")
    axes[0].plot(fix_times, np.nanmean(errors[:, used], 0), ".", ms=1.5, color="k", label="mean over seeds")
    for t0, t1 in EPISODES:
        axes[0].axvspan(t0, t1, color="tab:orange", alpha=0.15)
    axes[0].set_xlabel("time [s]")
    axes[0].set_ylabel("GPS error, whole-run alignment [m]")
    axes[0].set_title(f"{args.algorithm}, {args.particles} particles, {len(seeds)} seeds (shaded: episodes)", fontsize=10)
    axes[0].legend(fontsize=8)
    t0, t1 = EPISODES[0]
    window = (times >= t0) & (times <= t1)
    for i, found in enumerate(filtered):
        aligned = res.trajectory[i][:, :2] @ found["rotation"].T + found["translation"]
        axes[1].plot(aligned[window, 0], aligned[window, 1], lw=0.8, label=f"seed {seeds[i]}" if i < 3 else None)
    fixes = used & (seq.gps_times >= t0) & (seq.gps_times <= t1)
    axes[1].plot(seq.gps_xy[fixes, 0], seq.gps_xy[fixes, 1], "k.", ms=2, label="GPS")
    axes[1].set_aspect("equal")
    axes[1].set_title(f"{t0:.0f}-{t1:.0f} s, whole-run alignment", fontsize=10)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / f"{args.name}.png", dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
