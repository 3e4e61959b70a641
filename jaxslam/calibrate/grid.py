r"""Calibrating SRUPF-GM's odometry and matcher noise: what is differentiable, and the
predictive scan likelihood that is.

**What carries no gradient in SRUPF-GM** (:mod:`jaxslam.grid.srupf`; the per-scan step
with tracking, :mod:`jaxslam.grid.tracking`). A keyframe of particle :math:`m`
predicts :math:`\mathcal N(\mu_m, P_m)` by the square-root UT of the odometry model
(:math:`Q` from the params' ``srupf.q_linear``, ``srupf.q_angular``, ``srupf.q_linear_per_m``,
``srupf.q_angular_per_rad``, ``srupf.q_angular_per_m``), draws a start
:math:`s_m = \mu_m + S_m \epsilon` (reparameterised), hill-climbs from it to the
corrected pose :math:`\nu_m`, weights by :math:`g \log p(z \mid \nu_m, \text{map}_m)`
and updates the factor with the matcher noise :math:`R` (``srupf.match_noise``, eqs.
11-16). The weight depends on :math:`Q` and :math:`R` only through :math:`\nu_m`,
and :math:`\nu_m` is the start plus a move chosen by ``argmax`` over a lattice of
candidates (:func:`jaxslam.grid.matching.hill_climb`), projected on the directions
the scan constrains. Holding the chosen moves fixed, :math:`\partial \nu / \partial
\theta` is :math:`\partial s / \partial \theta`, and since :math:`\nu` sits at a
local maximum of the score, :math:`\nabla_\nu \log p(z \mid \nu)` is about zero
there: the pathwise gradient of the filter's own weights is noise, and the real
dependence (which basin the climb ends in) is a discrete one. There is also no
:math:`Q`-dependent term in the weight at all (no prior or proposal density, as in
GMapping), so the filter's :math:`\log \hat Z = \sum_t \log \sum_m \bar w_m
p(z_t \mid \nu_m)^g` is not a likelihood of :math:`Q` and :math:`R`. Further:
the maps are ``int8`` log-odds written at cells found by ``floor`` (no gradient),
the keyframe rule and the tracking's acceptance are thresholds, resampling and the
best particle are indices. Stop-gradient resampling would add only the gradient of
these weights, so it is not used here.

**What is differentiable, and what this module maximises.** The prediction itself:
:math:`\mu_m` and :math:`S_m` are smooth functions of :math:`Q` and of the previous
factor, which the measurement update made from :math:`R` (eqs. 12-16, a QR and
rank-1 up/downdates). And the scan likelihood of :mod:`jaxslam.grid.score` is
differentiable almost everywhere in the pose (bilinear / polynomial kernels). The
objective is the particle estimate of the predictive likelihood of each keyframe's
scan under SRUPF-GM's own prediction and tempered weight,

.. math::
    \log \hat p(z_t \mid z_{1:t-1}) = \log \sum_m \bar w_m \frac1K \sum_{k=1}^K
        p(z_t \mid \mu_m + S_m \epsilon_{mk}, \text{map}_m)^{g},
    \qquad \epsilon_{mk} \sim \mathcal N(0, I_3),

(:math:`\bar w` the filter's normalised weights before the step, :math:`g` =
``weights.gain``, :math:`K` = ``samples``; the samples are drawn apart from the
filter's own keys; :math:`\mu_m, S_m` the prediction from the particle's keyframe
pose and factor with the motion known before scan :math:`t`: the motion tracked up to
scan :math:`t-1` composed with scan :math:`t`'s odometry), an importance-sampling
estimate of
:math:`\int p(z_t \mid x)^g \mathcal N(x; \mu_m, P_m)\,dx`: too small a prediction
misses the scan's likelihood peak, too large a one spreads over poses that do not
fit. Its gradient flows through the samples :math:`\mu_m + S_m \epsilon` into the
scan likelihood and through :math:`S_m` into :math:`Q` and, via the previous
update's factor (recomputed here from the filter's own :math:`\nu`, treated as data,
and carried through its resampling), into :math:`R`. The filter's particles, maps,
weights and resampling are held fixed: the forward pass is the filter's own
(``srupf.step``, unchanged), and the gradient is the conditional one given the
particle system, not the derivative of how the particles would move (each Adam step
runs the filter again at the new levels).

With per-scan tracking (the default) the filter's keyframe control is the tracked
motion, which has already matched the keyframe's own scan against the best particle's
map; a likelihood of that scan under it is not predictive (the prediction already
sits at the scan's best match, so it rewards :math:`Q \to 0`). So the prediction in
the objective stops one scan short: the tracked motion up to scan :math:`t-1` and the
odometry of scan :math:`t` (without tracking this is the filter's own control). The
calibrated :math:`Q` is then the spread of the motion the filter predicts with,
tracking error plus one scan of odometry, not the raw wheel odometry's error over a
keyframe; use the levels with the same configuration.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.runtime.compiler import jit
from jaxslam.core import se2
from jaxslam.core.resampling import normalize_log_weights
from jaxslam.runtime.driver import step_keys
from jaxslam.grid import srupf
from jaxslam.grid.filter import match_geometry, particle_reader, score_model
from jaxslam.grid.score import scan_log_likelihood
from jaxslam.grid.tracking import keyframe_noise_scale, track
from jaxslam.grid.types import (
    GridSlamConfig, GridSlamParams, GridSlamState, Odometry, Scan, as_odometry, get_path, param_paths, with_values,
)

# The noise levels calibrated by default (log space), by their paths in the params tree:
# Q's constant and motion-proportional parts, and the matcher noise R (a vector of three).
GRID_NOISE_NAMES = ("srupf.q_linear", "srupf.q_angular", "srupf.q_linear_per_m", "srupf.q_angular_per_rad",
                    "srupf.q_angular_per_m", "srupf.match_noise")


class Carry(NamedTuple):
    """The filter's state and the differentiable copy of its pose factors."""

    state: GridSlamState
    pose_sqrt_covs: Array  # (P, 3, 3), equal in value to state.pose_sqrt_covs


def noise_sizes(params: GridSlamParams, names: Sequence[str]) -> list[int]:
    """Entries of each parameter, by path (1 for a scalar, 3 for ``srupf.match_noise``)."""
    return [int(np.size(get_path(params, name))) for name in names]


def with_log_noise(params: GridSlamParams, log_noise: Array, names: Sequence[str]) -> GridSlamParams:
    """``params`` with the levels at ``names`` (paths) set to ``exp`` of consecutive
    entries of ``log_noise`` (a vector parameter takes as many entries as it has)."""
    values, i = {}, 0
    for name, size in zip(names, noise_sizes(params, names)):
        current = get_path(params, name)
        values[name] = jnp.exp(log_noise[i:i + size]).reshape(jnp.shape(current)).astype(current.dtype)
        i += size
    return with_values(params, values)


def log_noise_of(params: GridSlamParams, names: Sequence[str]) -> np.ndarray:
    """The log of the named levels, flattened in order."""
    return np.log(np.concatenate([np.ravel(np.asarray(get_path(params, n), np.float64)) for n in names]))


def values_of(log_noise: Any, params: GridSlamParams, names: Sequence[str]) -> dict[str, Any]:
    """``{name: value}`` (a float, or a list for a vector parameter) of a log vector."""
    out, i = {}, 0
    values = np.exp(np.asarray(log_noise, np.float64))
    for name, size in zip(names, noise_sizes(params, names)):
        chunk = values[i:i + size]
        out[name] = float(chunk[0]) if np.ndim(get_path(params, name)) == 0 else chunk.tolist()
        i += size
    return out


def predictive_log_likelihood(
    key: Array, state: GridSlamState, pose_sqrt_covs: Array, motion: Array, observation: Scan,
    params: GridSlamParams, config: GridSlamConfig, samples: int,
) -> tuple[Array, srupf.Prediction]:
    r""":math:`\log \hat p(z_t \mid z_{1:t-1})` of a keyframe (module docstring) and the
    particles' predictions, from the state before the step and the keyframe's motion.
    The motion-proportional noise is scaled as the filter scales it
    (:func:`jaxslam.grid.tracking.keyframe_noise_scale`, from the matches refused since
    the last keyframe before this scan), so the calibrated levels are the parameters
    ``jaxslam run --params`` takes."""
    dtype = state.poses.dtype
    scale = keyframe_noise_scale(params, config, state.since_keyframe[4])
    prediction = jax.vmap(srupf.predict, (0, 0, None, None, None))(state.poses, pose_sqrt_covs, motion, params, scale)
    eps = jax.random.normal(key, (config.num_particles, samples, 3), dtype)
    poses = prediction.mean[:, None, :] + jnp.einsum("pij,pkj->pki", prediction.sqrt_cov, eps)
    poses = poses.at[..., 2].set(se2.wrap_angle(poses[..., 2]))
    local_points, mask = match_geometry(observation, params, config)
    model = score_model(params)

    def particle(table, particle_poses):
        read = particle_reader(state, table, config)

        def one(pose):
            return scan_log_likelihood(read, pose, local_points, mask, params.sensor.laser_offset, config.layout, model,
                                       config.score_kernel, config.free_check)[0]

        return jax.vmap(one)(particle_poses)

    log_lik = params.weights.gain * jax.vmap(particle)(state.maps.tables, poses)  # (P, K)
    per_particle = logsumexp(log_lik, axis=1) - jnp.log(jnp.asarray(samples, dtype))
    total = logsumexp(normalize_log_weights(state.log_weights) + per_particle)
    return total, prediction


def differentiable_scan_step(
    key: Array, carry: Carry, control: Odometry | Array, observation: Scan, params: GridSlamParams,
    config: GridSlamConfig, samples: int = 4,
) -> tuple[Carry, Array]:
    """One scan of SRUPF-GM's per-scan step (``srupf.step``, unchanged, on
    stop-gradient inputs) and, at a keyframe, the predictive log-likelihood of its scan
    (0 elsewhere). Carries the pose factors again, differentiably: the filter's
    measurement update (eqs. 11-16) recomputed from its corrected poses, gathered by its
    ancestors."""
    fixed = jax.lax.stop_gradient(carry.state)
    fixed_params = jax.lax.stop_gradient(params)
    control = as_odometry(control)
    state, info = srupf.step(key, fixed, control, observation, fixed_params, config)
    # The prediction before the scan is seen: the motion tracked up to the previous scan
    # and this scan's odometry. (With tracking the filter's own keyframe control has
    # also matched this scan, so a likelihood of the scan under it would not be
    # predictive, and would pull Q to 0.)
    predicted = se2.compose(fixed.motion, control.increment.astype(fixed.motion.dtype))
    total, _ = predictive_log_likelihood(
        jax.random.fold_in(key, 1), fixed, carry.pose_sqrt_covs, predicted, observation, params, config, samples
    )
    # The factor update of the filter itself, from its keyframe control (as per_scan
    # computes it: a deterministic function of the same inputs) and corrected poses.
    motion, _, accepted, *_ = track(fixed, control.increment, observation, fixed_params, config)
    scale = keyframe_noise_scale(params, config, fixed.since_keyframe[4] + jnp.logical_not(accepted))
    prediction = jax.vmap(srupf.predict, (0, 0, None, None, None))(fixed.poses, carry.pose_sqrt_covs, motion, params,
                                                                   scale)
    noise = jnp.diag(params.srupf.match_noise.astype(prediction.mean.dtype))
    update = jax.vmap(srupf.sqrt_measurement_update, (0, 0, None))(
        prediction, jax.lax.stop_gradient(info.poses), noise
    )
    applied = info.keyframe & (state.status.code == 0)
    sqrt_covs = jnp.where(applied, update.sqrt_cov[info.ancestors], carry.pose_sqrt_covs)
    return Carry(state, sqrt_covs), jnp.where(applied, total, 0.0)


class Inputs(NamedTuple):
    """A window of a log as the per-scan step takes it."""

    first_scan: Scan
    initial_pose: Array
    controls: Odometry
    observations: Scan


def log_likelihoods(
    key: Array, params: GridSlamParams, config: GridSlamConfig, inputs: Inputs, samples: int = 4,
) -> tuple[Array, Array]:
    """``(increments (T,), final status code)`` over a window: the filter started as
    :func:`jaxslam.grid.driver.run_filter` starts it (``init`` with ``key``, step
    ``t`` with ``step_keys(key, T)[t]``), so its forward pass is that of
    ``run_grid_slam`` with the same seed. A status other than 0 means the maps needed
    to grow (the increments after it are 0): give the config a larger pool."""
    state = srupf.init(key, jax.lax.stop_gradient(params), config, inputs.first_scan, inputs.initial_pose)
    steps = inputs.observations.ranges.shape[0]

    def body(carry, xs):
        k, control, observation = xs
        return differentiable_scan_step(k, carry, control, observation, params, config, samples)

    carry = Carry(state, state.pose_sqrt_covs)
    carry, increments = jax.lax.scan(body, carry, (step_keys(key, steps), inputs.controls, inputs.observations))
    return increments, carry.state.status.code


def window_inputs(log: Any, scans: int, dtype: Any = jnp.float32) -> Inputs:
    """The first ``scans`` scans of a CARMEN log as :func:`log_likelihoods` takes them,
    built as :func:`jaxslam.grid.experiment.run_grid_slam` builds them."""
    from jaxslam.metrics.trajectory_io import se2_between

    scans = min(int(scans), int(log.num_scans))
    if scans < 2:
        raise ValueError("the window needs at least two scans")
    real = np.dtype(dtype)
    odom = np.asarray(log.odom_poses[:scans], np.float64)
    ranges = np.asarray(log.ranges[:scans], np.float64)
    valid = np.asarray(log.valid[:scans]) & np.isfinite(ranges)
    ranges = np.where(valid, ranges, 0.0).astype(real)
    offsets = np.asarray(log.angle_offsets[:scans], real)
    times = np.asarray(log.scan_times[:scans], np.float64)
    return Inputs(
        Scan(ranges[0], valid[0], offsets[0]),
        odom[0].astype(real),
        Odometry(se2_between(odom[:-1], odom[1:]).astype(real), np.ones(scans - 1, real),
                 np.diff(times).astype(real)),
        Scan(ranges[1:], valid[1:], offsets[1:]),
    )


_PROGRAMS: dict[Any, Any] = {}


def programs(config: GridSlamConfig, names: tuple[str, ...], samples: int):
    """Jitted ``(keys (S,), log_noise, params, inputs) -> (values (S,), grads (S, K))``
    of the mean increment per filter (NaN where the maps would have needed to grow),
    and ``(keys, log_noise, params, inputs) -> (S, T)`` increments (forward only)."""
    if (config, names, samples) not in _PROGRAMS:

        def increments(key, log_noise, params, inputs):
            values, status = log_likelihoods(key, with_log_noise(params, log_noise, names), config, inputs, samples)
            return jnp.where(status == 0, values, jnp.nan)

        def mean(log_noise, key, params, inputs):
            return jnp.mean(increments(key, log_noise, params, inputs))

        gradient = jax.vmap(jax.value_and_grad(mean), (None, 0, None, None))
        _PROGRAMS[(config, names, samples)] = (
            jit(lambda keys, th, params, inputs: gradient(th, keys, params, inputs)),
            jit(jax.vmap(increments, (0, None, None, None))),
        )
    return _PROGRAMS[(config, names, samples)]


def calibrate_grid(
    log: Any,
    particles: int = 10,
    filters: int = 2,
    steps: int = 30,
    learning_rate: float = 0.1,
    window: int = 600,
    seed: int = 0,
    params: dict[str, Any] | None = None,
    names: Sequence[str] = GRID_NOISE_NAMES,
    config: dict[str, Any] | None = None,
    samples: int = 4,
    dtype: Any = jnp.float32,
    callback: Any = None,
    decay: float = 1.0,
    validation: float = 0.25,
    validate_every: int = 5,
    validation_filters: int = 4,
    validation_particles: int | None = None,
    validation_margin: float = 2.0,
):
    """Fit SRUPF-GM's noise levels (default ``GRID_NOISE_NAMES``) on the first
    ``window`` scans of a CARMEN log by Adam on the predictive scan log-likelihood
    (module docstring), keeping the iterate chosen on the held-out end of the window
    (:func:`jaxslam.calibrate.fit.ascend`, then
    :func:`jaxslam.calibrate.fit.select_iterate`; the arguments as for
    :func:`jaxslam.calibrate.landmark.calibrate`). ``samples``: draws per particle and
    keyframe. ``params``/``config``: overrides as for
    :func:`jaxslam.grid.experiment.run_grid_slam`, whose layout (pool doubled) the
    programs use: a window that needs more map than that gives non-finite values."""
    import dataclasses

    from jaxslam.calibrate.fit import CalibrationResult, ascend, select_iterate, split_window
    from jaxslam.datasets.carmen import scan_range
    from jaxslam.grid.experiment import run_grid_slam
    from jaxslam.grid.range_rule import apply_range_rule
    from jaxslam.grid.algorithms import grid_algorithm

    names = tuple(names)
    if min(particles, filters, steps, samples, validation_filters) < 1:
        raise ValueError("particles, filters, steps, samples and validation_filters must be >= 1")
    window = min(int(window), int(log.num_scans))
    fit_window = split_window(window, validation)
    if fit_window < 2:
        raise ValueError(f"the fitted part of the window must hold at least two scans, got {fit_window}")
    # The ranges the run on the whole log would use (jaxslam.grid.range_rule), for the
    # reference run's layout and the fitted parameters alike.
    overrides, _ = apply_range_rule(dict(params or {}), log)
    val_particles = validation_particles or particles
    # The layout (and ray budget) of the filter's own run on the window, pool doubled
    # for other noise levels and seeds.
    reference = run_grid_slam(scan_range(log, 0, window), "srupf-gm", particles=max(particles, val_particles),
                              seed=seed, params=overrides, config=config, progress=False, dtype=dtype)
    layout = dataclasses.replace(reference.config.layout, slots=2 * reference.config.layout.slots)
    cfg = dataclasses.replace(reference.config, layout=layout, num_particles=particles)
    angles = overrides.pop("sensor.beam_angles", log.angles)
    offset = overrides.pop("sensor.laser_offset", log.laser_offset)
    prm = grid_algorithm("srupf-gm").make_params(angles, offset, dtype=dtype, values=overrides)
    unknown = [n for n in names if n not in param_paths()]
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}")
    gradient, _ = programs(cfg, names, samples)
    theta = jnp.asarray(log_noise_of(prm, names), dtype)
    fit_inputs = jax.tree_util.tree_map(jnp.asarray, window_inputs(log, fit_window, dtype))
    score = None
    if fit_window < window:
        _, increments = programs(dataclasses.replace(cfg, num_particles=val_particles), names, samples)
        val_inputs = jax.tree_util.tree_map(jnp.asarray, window_inputs(log, window, dtype))

        def score(keys, th):
            # Step t of the inputs is scan t + 1: the held-out scans are steps fit_window - 1 on.
            return np.asarray(increments(keys, th.astype(dtype), prm, val_inputs))[:, fit_window - 1:].mean(1)

    ascent = ascend(gradient, (prm, fit_inputs), theta, steps, learning_rate, filters, seed, decay, callback)
    best, train_best, record = select_iterate(ascent, seed, score, (fit_window, window, val_particles), validate_every,
                                              validation_filters, validation_margin)
    path = ascent.trajectory
    after = with_log_noise(prm, jnp.log(jnp.asarray(path[best], dtype)), names)
    return CalibrationResult(
        names=names, before=values_of(theta, prm, names), after=values_of(np.log(path[best]), prm, names),
        last=values_of(np.log(path[-1]), prm, names), best_step=best, train_best_step=train_best,
        log_likelihood=ascent.log_likelihood, gradient_variance=ascent.gradient_variance, trajectory=path,
        validation=record, compile_s=ascent.compile_s, wall_s=ascent.wall_s, config=cfg, params=after,
        window=window, fit_window=fit_window, filters=filters, columns=trajectory_columns(prm, names),
    )


def trajectory_columns(params: GridSlamParams, names: Sequence[str]) -> tuple[str, ...]:
    """A name per entry of the log vector (``srupf.match_noise[0]`` ... for a vector)."""
    return tuple(name if size == 1 and np.ndim(get_path(params, name)) == 0 else f"{name}[{i}]"
                 for name, size in zip(names, noise_sizes(params, names)) for i in range(size))


__all__ = [
    "GRID_NOISE_NAMES",
    "calibrate_grid",
    "Carry",
    "Inputs",
    "differentiable_scan_step",
    "log_likelihoods",
    "log_noise_of",
    "predictive_log_likelihood",
    "values_of",
    "window_inputs",
    "with_log_noise",
]
