r"""How the landmark filter's weights depend on each particle's data association,
Victoria Park.

The weight increment of a particle (eq. 11, batch form) is the joint likelihood of the
observations it *matched*; an observation it starts a new landmark from, or ignores
(between the two gates), contributes nothing (a factor 1). Particles that explain the
same scan differently therefore get likelihoods of different dimension. This script
measures the effect: it runs the filter (:func:`jaxslam.feature.filter.step`, the keys
of the single-seed run) and, at every step, the per-particle part of the same step
(:func:`jaxslam.feature.particle.particle_step` with the same per-particle keys) to
read each particle's matched / new / ignored counts and weight increment. Per step
with particles that disagree on the number of matches, the within-step least-squares
slope of the weight increment on the matched count (nats per extra match) and the
correlation; pooled over steps (fixed effects: each step's means removed).

    python benchmarks/erb_association_weights.py [--particles 100] [--seeds 0 1 2] [--steps N]

Writes ``benchmarks/results/erb_association_weights.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import write_json  # noqa: E402

from jaxslam.datasets import victoria_park  # noqa: E402
from jaxslam.runtime.driver import step_keys  # noqa: E402
from jaxslam.feature import filter as F  # noqa: E402
from jaxslam.feature.experiment import ALGORITHMS, params_for  # noqa: E402
from jaxslam.feature.params import Config  # noqa: E402
from jaxslam.feature.particle import particle_step  # noqa: E402


def run(seq, algorithm: str, particles: int, seed: int, params_override: dict):
    """Scan the filter and return per step and particle ``(matched, new, log_w_inc)``
    plus the filter's moving-step flag and the GPS-aligned trajectory input."""
    params = F.cast_params(params_for(seq, **params_override), jnp.float32)
    config = Config(num_particles=particles, proposal=ALGORITHMS[algorithm])
    key = jax.random.PRNGKey(seed)
    state = F.init(key, params, config, jnp.zeros(3, jnp.float32))
    keys = step_keys(key, seq.controls.shape[0])

    @jax.jit
    def scan(state, keys, controls, values, masks):
        def body(state, inputs):
            k, u, z, m = inputs
            obs = F.Observation(z, m)
            u_clean, obs_clean, *_ = F.clean_inputs(u, obs)
            k_sample, _ = jax.random.split(k)
            pkeys = jax.random.split(k_sample, particles)
            out = jax.vmap(particle_step, (0, 0, 0, 0, None, None, None, None))(
                pkeys, state.poses, state.pose_sqrt_covs, state.landmarks, u_clean, obs_clean, params, config)
            new_state, info = F.step(k, state, u, obs, params, config)
            moving = jnp.any((u_clean[:, 2] > 0) & (u_clean[:, 0] != 0))
            per = (jnp.sum(out.matched, 1), jnp.sum(out.new, 1), out.log_weight_increment, out.has_match)
            return new_state, (per, moving, info.pose_estimate, info.resampled)

        return jax.lax.scan(body, state, (keys, controls, values, masks))

    _, (per, moving, trajectory, resampled) = scan(
        state, keys, jnp.asarray(seq.controls, jnp.float32), jnp.asarray(seq.observations, jnp.float32),
        jnp.asarray(seq.obs_mask, bool))
    matched, new, inc, has_match = (np.asarray(a) for a in per)
    return matched, new, inc, has_match, np.asarray(moving), np.asarray(trajectory), np.asarray(resampled)


def analyse(seq, matched, new, inc, has_match, moving) -> dict:
    real = np.asarray(seq.obs_mask).sum(axis=1)
    ignored = real[:, None] - matched - new
    finite = np.isfinite(inc).all(axis=1)
    use = moving & finite & (matched.std(axis=1) > 0)
    m = matched[use] - matched[use].mean(axis=1, keepdims=True)
    w = inc[use] - inc[use].mean(axis=1, keepdims=True)
    slope = float((m * w).sum() / (m * m).sum())
    corr = float((m * w).sum() / np.sqrt((m * m).sum() * (w * w).sum()))
    per_obs = inc[moving & finite][has_match[moving & finite]] / matched[moving & finite][has_match[moving & finite]]
    # the particle of largest increment against the particle of most matches, per step
    top = np.argmax(inc[use], axis=1)
    rows = np.arange(top.size)
    return dict(
        steps_used=int(use.sum()),
        slope_nats_per_match=slope,
        within_step_correlation=corr,
        log_likelihood_per_matched_obs_median=float(np.median(per_obs)),
        log_likelihood_per_matched_obs_mean=float(np.mean(per_obs)),
        top_particle_matches_minus_step_max=float(np.mean(matched[use][rows, top] - matched[use].max(axis=1))),
        top_particle_matches_minus_step_mean=float(np.mean(matched[use][rows, top] - matched[use].mean(axis=1))),
        mean_new_per_particle_step=float(new[moving].mean()),
        mean_ignored_per_particle_step=float(ignored[moving].mean()),
        mean_matched_per_particle_step=float(matched[moving].mean()),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--algorithm", default="erb-upf")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--name", default="erb_association_weights")
    args = parser.parse_args()
    from jaxslam.metrics.gps import gps_error

    seq = victoria_park.load_sequence("detections", max_range=30.0, max_steps=args.steps)
    rows = []
    for seed in args.seeds:
        matched, new, inc, has_match, moving, traj, resampled = run(seq, args.algorithm, args.particles, seed, {})
        row = dict(algorithm=args.algorithm, particles=args.particles, seed=seed,
                   **analyse(seq, matched, new, inc, has_match, moving),
                   gps_mean_m=gps_error(seq.times, traj, seq.gps_times, seq.gps_xy)["gps_mean_m"],
                   resamplings=int(resampled.sum()))
        rows.append(row)
        print(row, flush=True)
    write_json(args.name, dict(dataset="victoria-park", steps=int(seq.controls.shape[0]), runs=rows,
                               command="python " + " ".join(sys.argv)))


if __name__ == "__main__":
    main()
