"""Consistency (pose NEES) of RB-UPF and ERB-UPF on the landmark simulator, over seeds.

For each particle count and algorithm, one ensemble of seeds (each seed draws its own
world and noise, ``landmark_sim.simulate(seed)``, and its own filter randomness):

* **SLAM**: the filter as it is. Pose NEES of the weighted particle mean under the
  weighted covariance of the particle poses (:mod:`jaxslam.metrics.nees`), averaged
  over the steps of each seed, then mean, standard deviation and 95% confidence
  interval over seeds; also the NEES of the first and the last third of the run.
* **known map**: the same filter with every particle's table holding the true
  landmarks (covariance ``1e-8`` m^2) and no new landmarks: localisation only. If the
  proposal and the weights are right, this NEES is chi-square(3) for many particles;
  the difference to SLAM is what the shared, degenerate map history costs.
* **UKF reference** (``--modes ukf-known-map``): an independent NumPy unscented
  Kalman filter (filterpy's sigma points, the simulator's own car model
  ``landmark_sim._move``) with the true map and the true associations, one Gaussian, no
  particles (:func:`ukf_known_map_nees`). Its NEES is about 3 when the simulator's noise
  is the noise the filters assume and the NEES is computed right (heading wrapped), so
  what the particle filters add above it is theirs.
* **genealogy** (SLAM): distinct ancestors at each resampling, how many of the
  initial particles still have descendants after 50 steps, and how often the
  highest-weight particle does not descend from the previous one.

The band is the two-sided 95% interval of chi-square(3) for a single NEES, [0.216,
9.35], and, for the mean over ``S`` seeds and ``T`` steps treated as independent,
``chi2(3 S T) / (S T)`` (Bar-Shalom et al. 2001, Sec. 5.4).

    python benchmarks/diagnostics/erb_consistency.py [--particles 10 30 100 300 1000] [--seeds 10]

Writes ``benchmarks/results/erb_consistency.json`` and ``erb_consistency.png``.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from _common import RESULTS, print_table, write_json  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from jaxslam.datasets import landmark_sim  # noqa: E402
from jaxslam.datasets.geometry import wrap_angle  # noqa: E402
from jaxslam.runtime.driver import scan_steps  # noqa: E402
from jaxslam.feature import filter as feature_filter  # noqa: E402
from jaxslam.feature.experiment import ALGORITHMS, params_for  # noqa: E402
from jaxslam.feature.params import Config  # noqa: E402
from jaxslam.metrics.nees import nees_band, pose_nees  # noqa: E402
from jaxslam.metrics.stats import mean_ci  # noqa: E402


@partial(jax.jit, static_argnames=("config", "known_map"))
def _ensemble(keys, controls, observations, obs_mask, true_landmarks, params, config, known_map):
    """Run every seed; return the Info stack, the ancestors and the best particle."""

    def one(key, controls, observations, obs_mask, landmarks):
        state = feature_filter.init(key, params, config)
        if known_map:
            n = config.num_particles
            count = landmarks.shape[0]
            table = state.landmarks
            means = table.means.at[:, :count].set(jnp.broadcast_to(landmarks, (n, count, 2)))
            covs = table.covs.at[:, :count].set(1e-8 * jnp.eye(2, dtype=means.dtype))
            active = table.active.at[:, :count].set(True)
            evidence = table.evidence.at[:, :count].set(1.0)
            counts = jnp.full((n,), count, jnp.int32)
            state = state._replace(landmarks=table._replace(means=means, covs=covs, active=active,
                                                            evidence=evidence, count=counts))

        observation = feature_filter.Observation(observations, obs_mask)
        _, infos = scan_steps(feature_filter.step, key, state, controls, observation, params, config)
        return infos, infos.ancestors

    return jax.vmap(one)(keys, controls, observations, obs_mask, true_landmarks)


def ukf_known_map_nees(seq, ut=(1.0, 2.0, 1.0)) -> np.ndarray:
    """Pose NEES ``(T,)`` of an unscented Kalman filter that knows the map and the data
    associations of a simulated sequence (``landmark_sim.simulate``).

    Prediction: for each control row, the unscented transform over ``[pose; speed noise;
    steering noise]`` with covariance ``blockdiag(P, Q)`` through the simulator's car
    model; update: all observations of the step at once, unscented over the pose, with
    additive ``R``. Noise levels, geometry and sensor offset from ``seq.meta``; filterpy's
    scaled sigma points with ``ut = (alpha, beta, kappa)``. Independent of jaxslam's
    filters: it shares only the simulator and :func:`jaxslam.metrics.nees.pose_nees`.
    """
    from filterpy.kalman import MerweScaledSigmaPoints

    meta = seq.meta
    geometry = tuple(meta["geometry"])
    offset = np.asarray(meta["sensor_offset"], np.float64)
    q = np.diag([meta["speed_std"] ** 2, meta["steering_std"] ** 2])
    r = np.diag([meta["range_std"] ** 2, meta["bearing_std"] ** 2])
    predict_points = MerweScaledSigmaPoints(5, *ut)
    update_points = MerweScaledSigmaPoints(3, *ut)
    mean, cov = np.zeros(3), np.eye(3) * 1e-10
    estimates, covs = [], []
    for t in range(seq.controls.shape[0]):
        for speed, steering, dt in seq.controls[t]:
            if dt <= 0:
                continue
            points = predict_points.sigma_points(np.r_[mean, 0.0, 0.0], np.block([[cov, np.zeros((3, 2))],
                                                                                   [np.zeros((2, 3)), q]]))
            moved = landmark_sim._move(points[:, :3].T, speed + points[:, 3], steering + points[:, 4], dt, geometry).T
            moved[:, 2] = moved[0, 2] + wrap_angle(moved[:, 2] - moved[0, 2])
            mean = predict_points.Wm @ moved
            dev = moved - mean
            cov = (predict_points.Wc[:, None] * dev).T @ dev
        seen = seq.obs_mask[t]
        if seen.any():
            landmarks = seq.landmarks[seq.associations[t][seen]]
            points = update_points.sigma_points(mean, cov)
            c, s = np.cos(points[:, 2]), np.sin(points[:, 2])
            sensor = points[:, :2] + np.stack([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]], -1)
            d = landmarks[None] - sensor[:, None]  # (sigma, k, 2)
            bearing = np.arctan2(d[..., 1], d[..., 0]) - points[:, 2:3]
            bearing = bearing[0] + wrap_angle(bearing - bearing[0])
            predicted = np.stack([np.hypot(d[..., 0], d[..., 1]), bearing], -1).reshape(len(points), -1)
            z_mean = update_points.Wm @ predicted
            dz = predicted - z_mean
            innovation_cov = (update_points.Wc[:, None] * dz).T @ dz + np.kron(np.eye(int(seen.sum())), r)
            cross = (update_points.Wc[:, None] * (points - mean)).T @ dz
            gain = cross @ np.linalg.inv(innovation_cov)
            innovation = seq.observations[t][seen].reshape(-1) - z_mean
            innovation[1::2] = wrap_angle(innovation[1::2])
            mean = mean + gain @ innovation
            cov = cov - gain @ innovation_cov @ gain.T
            cov = 0.5 * (cov + cov.T)
        mean[2] = wrap_angle(mean[2])
        estimates.append(mean.copy())
        covs.append(cov.copy())
    return pose_nees(np.array(estimates), np.array(covs), seq.true_poses)


def genealogy(ancestors: np.ndarray, best: np.ndarray, lag: int = 50) -> dict[str, float]:
    """Genealogy statistics of one run from its ancestors ``(T, N)`` and best ``(T,)``.

    ``survivors_after_lag``: of the particles at step ``t``, how many have descendants
    at ``t + lag`` (mean over ``t``). ``best_switches``: steps at which the
    best particle does not descend from the previous step's.
    """
    t_steps, n = ancestors.shape
    switches = 0
    for t in range(1, t_steps):
        if ancestors[t - 1][best[t]] != best[t - 1]:
            switches += 1
    survivors = []
    for start in range(0, t_steps - lag, lag):
        label = np.arange(n)
        for t in range(start, start + lag):
            label = label[ancestors[t]]
        survivors.append(len(np.unique(label)))
    return dict(best_switches=switches, survivors_after_lag=float(np.mean(survivors)) if survivors else float("nan"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[10, 30, 100, 300, 1000])
    parser.add_argument("--algorithms", nargs="+", default=["erb-upf", "rb-upf"])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--max-observations", type=int, default=24)
    parser.add_argument("--lag", type=int, default=50)
    parser.add_argument("--modes", nargs="+", default=["slam", "known-map"])
    parser.add_argument("--name", default="erb_consistency")
    args = parser.parse_args()

    seeds = list(range(args.seeds))
    sequences = [landmark_sim.simulate(seed=s, num_steps=args.steps, max_observations=args.max_observations)
                 for s in seeds]
    full = [landmark_sim.simulate(seed=s, num_steps=args.steps) for s in seeds]
    truncated = sum(int(f.obs_mask.sum() != q.obs_mask.sum()) for f, q in zip(full, sequences))
    params = params_for(sequences[0])
    num_lm = max(q.landmarks.shape[0] for q in sequences)
    true_landmarks = np.stack([np.pad(q.landmarks, ((0, num_lm - q.landmarks.shape[0]), (0, 0)),
                                      constant_values=1e6) for q in sequences])
    arrays = [jnp.asarray(np.stack([getattr(q, f) for q in sequences]), dt)
              for f, dt in (("controls", jnp.float32), ("observations", jnp.float32), ("obs_mask", bool))]
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    truth = np.stack([q.true_poses for q in sequences])
    lo_single, hi_single = nees_band(3)

    rows, curves = [], {}
    if "ukf-known-map" in args.modes:
        nees = np.stack([ukf_known_map_nees(q) for q in sequences])
        per_seed = nees.mean(axis=1)
        stats = mean_ci(per_seed)
        third = args.steps // 3
        rows.append(dict(
            mode="ukf-known-map", algorithm="ukf", particles=0, seeds=len(seeds), nees_mean=stats["mean"],
            nees_std=stats["std"], nees_ci_low=stats["ci_low"], nees_ci_high=stats["ci_high"],
            nees_median_seed=float(np.median(per_seed)), nees_first_third=float(nees[:, :third].mean()),
            nees_last_third=float(nees[:, -third:].mean()),
            fraction_inside_band=float(((nees >= lo_single) & (nees <= hi_single)).mean()), per_seed_nees=per_seed.tolist(),
        ))
        curves["ukf-known-map/ukf/0"] = nees.mean(axis=0)
        print(f"ukf-known-map: NEES {stats['mean']:.2f} [{stats['ci_low']:.2f}, {stats['ci_high']:.2f}]", flush=True)
    for mode in (m for m in args.modes if m != "ukf-known-map"):
        for n in args.particles:
            for algorithm in args.algorithms:
                config = Config(num_particles=n, proposal=ALGORITHMS[algorithm])
                p = params._replace(gate_new=1e9) if mode == "known-map" else params
                infos, ancestors = _ensemble(keys, *arrays, jnp.asarray(true_landmarks, jnp.float32),
                                             feature_filter.cast_params(p, jnp.float32), config, mode == "known-map")
                est = np.asarray(infos.pose_estimate)
                covs = np.asarray(infos.pose_cov)
                nees = np.stack([pose_nees(est[i], covs[i], truth[i]) for i in range(len(seeds))])
                per_seed = nees.mean(axis=1)
                third = args.steps // 3
                stats = mean_ci(per_seed)
                pos_err = np.linalg.norm(est[..., :2] - truth[..., :2], axis=-1).mean(axis=1)
                row = dict(
                    mode=mode, algorithm=algorithm, particles=n, seeds=len(seeds),
                    nees_mean=stats["mean"], nees_std=stats["std"], nees_ci_low=stats["ci_low"],
                    nees_ci_high=stats["ci_high"], nees_median_seed=float(np.median(per_seed)),
                    nees_first_third=float(nees[:, :third].mean()), nees_last_third=float(nees[:, -third:].mean()),
                    fraction_inside_band=float(((nees >= lo_single) & (nees <= hi_single)).mean()),
                    pos_err_mean_m=float(pos_err.mean()),
                    resamplings=float(np.asarray(infos.resampled).sum(axis=1).mean()),
                    per_seed_nees=per_seed.tolist(),
                )
                if mode == "slam":
                    anc = np.asarray(ancestors)
                    best = np.asarray(infos.best_particle)
                    gen = [genealogy(anc[i], best[i], args.lag) for i in range(len(seeds))]
                    row.update(
                        best_switches=float(np.mean([g["best_switches"] for g in gen])),
                        survivors_after_lag=float(np.mean([g["survivors_after_lag"] for g in gen])),
                        ancestors_at_resampling=float(np.asarray(infos.num_ancestors)[np.asarray(infos.resampled)].mean()),
                        weight_entropy_fraction=float((np.exp(np.asarray(infos.weight_entropy)) / n).mean()),
                        association_disagreement=float(np.asarray(infos.association_disagreement).mean()),
                        landmark_count_spread=float((np.asarray(infos.num_landmarks_max)
                                                     - np.asarray(infos.num_landmarks_min)).mean()),
                    )
                rows.append(row)
                curves[f"{mode}/{algorithm}/{n}"] = nees.mean(axis=0)
                print(f"{mode} {algorithm} N={n}: NEES {stats['mean']:.2f} [{stats['ci_low']:.2f}, "
                      f"{stats['ci_high']:.2f}] (first third {row['nees_first_third']:.2f}, last third "
                      f"{row['nees_last_third']:.2f}), pos err {row['pos_err_mean_m']:.3f} m", flush=True)
                write_json(args.name, dict(dataset="landmark-sim", steps=args.steps, seeds=seeds, runs=rows,
                                           truncated_sequences=truncated, complete=False))
    total = len(seeds) * args.steps
    band_mean = [bound / total for bound in nees_band(3 * total)]
    path = write_json(args.name, dict(
        dataset="landmark-sim", steps=args.steps, seeds=seeds, runs=rows, truncated_sequences=truncated,
        band_single=[lo_single, hi_single], band_mean_independent=band_mean, lag=args.lag, complete=True,
    ))
    print_table(rows, ["mode", "algorithm", "particles", "nees_mean", "nees_ci_low", "nees_ci_high",
                       "nees_first_third", "nees_last_third", "fraction_inside_band", "pos_err_mean_m",
                       "resamplings", "survivors_after_lag", "best_switches"])

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    colors = {"erb-upf": "tab:green", "rb-upf": "tab:red"}
    for mode, marker in (("slam", "o-"), ("known-map", "s--")):
        for algorithm in args.algorithms:
            mine = [r for r in rows if r["mode"] == mode and r["algorithm"] == algorithm]
            if not mine:
                continue
            n = np.array([r["particles"] for r in mine])
            mean = np.array([r["nees_mean"] for r in mine])
            err = np.array([[r["nees_mean"] - r["nees_ci_low"] for r in mine], [r["nees_ci_high"] - r["nees_mean"] for r in mine]])
            axes[0].errorbar(n, mean, yerr=err, fmt=marker, color=colors.get(algorithm), capsize=3,
                             label=f"{algorithm} {mode}")
    for row in (r for r in rows if r["mode"] == "ukf-known-map"):
        axes[0].axhline(row["nees_mean"], color="tab:blue", ls=":", label="UKF, true map and associations")
    axes[0].axhspan(lo_single, hi_single, color="0.9", label="95% band, one NEES")
    axes[0].axhline(3.0, color="k", lw=0.8)
    axes[0].set_xscale("log")
    axes[0].set_yscale("log")
    axes[0].set_xlabel("particles")
    axes[0].set_ylabel("mean pose NEES (mean and 95% CI over seeds)")
    axes[0].legend(fontsize=7)
    for key, curve in curves.items():
        mode, algorithm, n = key.split("/")
        if algorithm == "erb-upf":
            axes[1].semilogy(curve, lw=0.8, ls="-" if mode == "slam" else "--", label=f"{mode} N={n}")
        elif algorithm == "ukf":
            axes[1].semilogy(curve, lw=0.8, ls=":", color="tab:blue", label="UKF, true map")
    axes[1].axhline(3.0, color="k", lw=0.8)
    axes[1].set_xlabel("step")
    axes[1].set_ylabel("ERB NEES, mean over seeds")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / f"{args.name}.png", dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
