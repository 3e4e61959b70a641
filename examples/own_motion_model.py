"""A filter of one's own: beacon localization with a motion model the library does not have.

The robot drives ``control[0]`` metres along its heading, then turns ``control[1]``
radians (a unicycle with additive noise on both). It measures the range and bearing of
beacons at known places. The filter takes from the library only its parts: the
square-root unscented prediction through the motion model
(:func:`jaxslam.models.odometry.sqrt_unscented_predict`), SRUPF's proposal without a
corrector (the best-scoring propagated sigma point, eq. 10 of Zandara & Nicholson, and
the square-root measurement update, eqs. 11-16), the range-bearing model
(:func:`jaxslam.models.range_bearing.observe`) and systematic resampling when the ESS is
low (:func:`jaxslam.reweight`); :func:`jaxslam.run` scans it.

Run ``python examples/own_motion_model.py`` for the error of the filter and of dead
reckoning on a simulated lap.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.stats import norm

import jaxslam
from jaxslam.core.se2 import wrap_angle
from jaxslam.core.sigma import UTParams
from jaxslam.grid.srupf import best_sigma_point, sqrt_measurement_update
from jaxslam.models.odometry import sqrt_unscented_predict
from jaxslam.models.range_bearing import observe


# --- the filter: from the motion model to a ParticleFilter -------------------------
def forward_then_turn(augmented, control):
    x, y, theta, n_v, n_w = augmented
    v, w = control[0] + n_v, control[1] + n_w
    return jnp.stack([x + v * jnp.cos(theta), y + v * jnp.sin(theta), wrap_angle(theta + w)])


class State(NamedTuple):
    poses: jax.Array  # (N, 3)
    pose_sqrt_covs: jax.Array  # (N, 3, 3)
    log_weights: jax.Array  # (N,)


def beacon_filter(beacons, motion_std, range_std, bearing_std, num_particles):
    noise_sqrt, match_sqrt = jnp.diag(motion_std), jnp.diag(jnp.array([range_std, range_std, bearing_std]))
    def log_likelihood(pose, observation):  # observation: (B, 2) range, bearing of each beacon
        predicted = jax.vmap(observe, (None, 0))(pose, beacons)
        return jnp.sum(norm.logpdf(observation[:, 0], predicted[:, 0], range_std)
                       + norm.logpdf(wrap_angle(observation[:, 1] - predicted[:, 1]), 0.0, bearing_std))
    def particle(key, pose, sqrt_cov, control, observation):
        prediction = sqrt_unscented_predict(pose, sqrt_cov, control, noise_sqrt, UTParams(1.0, 2.0, 0.0),
                                            motion=forward_then_turn)
        nu = best_sigma_point(prediction, jax.vmap(lambda p: log_likelihood(p, observation)))
        update = sqrt_measurement_update(prediction, nu, match_sqrt)
        sample = jaxslam.sample_pose(key, nu, update.sqrt_cov)
        return sample, update.sqrt_cov, log_likelihood(sample, observation)
    def init(pose, sqrt_cov):
        return State(jnp.broadcast_to(pose, (num_particles, 3)), jnp.broadcast_to(sqrt_cov, (num_particles, 3, 3)),
                     jnp.full((num_particles,), -jnp.log(num_particles)))
    def step(key, state, control, observation):
        key_particles, key_resample = jax.random.split(key)
        poses, sqrt_covs, log_liks = jax.vmap(particle, (0, 0, 0, None, None))(
            jax.random.split(key_particles, num_particles), state.poses, state.pose_sqrt_covs, control, observation)
        ancestors, log_weights, info = jaxslam.reweight(key_resample, state.log_weights, log_liks, 0.5,
                                                        "systematic")
        return State(poses[ancestors], sqrt_covs[ancestors], log_weights), info

    return jaxslam.ParticleFilter(init, step)
# ------------------------------------------------------------------------------------


BEACONS = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [5.0, -3.0]])


def simulate(steps: int = 60, seed: int = 0, motion_std=(0.05, 0.02), range_std=0.2, bearing_std=0.03):
    """A lap around the beacons: true poses ``(T + 1, 3)``, the odometry controls
    ``(T, 2)`` (noisy), and observations ``(T, B, 2)``."""
    rng = np.random.default_rng(seed)
    true = [np.array([2.0, 1.0, 0.0])]
    commands = np.tile([0.5, 2 * np.pi / steps], (steps, 1))
    for v, w in commands:
        x, y, theta = true[-1]
        true.append(np.array([x + v * np.cos(theta), y + v * np.sin(theta), np.arctan2(np.sin(theta + w),
                                                                                       np.cos(theta + w))]))
    true = np.array(true)
    controls = commands + rng.normal(0.0, motion_std, commands.shape)
    observations = np.array([np.asarray(jax.vmap(observe, (None, 0))(jnp.asarray(p), jnp.asarray(BEACONS)))
                             for p in true[1:]])
    observations += rng.normal(0.0, [range_std, bearing_std], observations.shape)
    return true, controls, observations


def main() -> None:
    true, controls, observations = simulate()
    filt = beacon_filter(jnp.asarray(BEACONS), jnp.array([0.05, 0.02]), 0.2, 0.03, num_particles=64)
    state = filt.init(jnp.asarray(true[0]), 0.05 * jnp.eye(3))
    final, infos = jax.jit(jaxslam.run, static_argnums=0)(filt, jax.random.PRNGKey(0), state,
                                                          jnp.asarray(controls), jnp.asarray(observations))
    dead_reckoning = true[0]
    for control in controls:
        dead_reckoning = np.asarray(forward_then_turn(jnp.concatenate([jnp.asarray(dead_reckoning), jnp.zeros(2)]),
                                                      jnp.asarray(control)))
    print(f"log Z estimate {float(infos.log_likelihood_increment.sum()):.1f}, resampled "
          f"{int(infos.resampled.sum())} of {len(controls)} steps; final position error: filter "
          f"{np.hypot(*(np.asarray(final.poses).mean(0)[:2] - true[-1][:2])):.3f} m, dead reckoning "
          f"{np.hypot(*(dead_reckoning[:2] - true[-1][:2])):.3f} m")


if __name__ == "__main__":
    main()
