r"""SRUPF-GM: square-root unscented particle filter for grid maps.

Zandara & Nicholson, "Square Root Unscented Particle Filtering for Grid Mapping",
AI 2009, Algorithm 2. Per particle :math:`i` with pose :math:`x` and lower factor
:math:`S` (:math:`P = S S^T`):

*Odometry update* (eqs. 1-9; :func:`jaxslam.models.odometry.sqrt_unscented_predict`):
sigma points of :math:`[x; 0]` with factor :math:`\mathrm{diag}(S, \sqrt Q)`, pushed
through ``f``; mean :math:`\mu` (6), :math:`S = \mathrm{qr}[\sqrt{W^c_{1..2n}}
(\overline{sp}_i - \mu)]` (7) and a rank-1 update with the zeroth deviation (8).

*Measurement update* (eqs. 10-16), with the corrected pose :math:`\nu`:

* ``"pc"``: :math:`\nu` from the pose corrector started at :math:`\mu`, searching
  inside the covariance ellipse (:func:`jaxslam.grid.matching.ellipse_match`);
* ``"npc"``: :math:`\nu = h(\overline{sp}_i, z)` is the best-scoring propagated
  sigma point (10).

.. math::
    \Sigma^{\mu\nu} &= \textstyle\sum_i W^c_i (\overline{sp}_i - \mu)
        (\overline{sp}_i - \nu)^T && (11) \\
    S_\nu &= \mathrm{qr}\big[\sqrt{W^c_{1..2n}} (\overline{sp}_i - \nu),\
        \sqrt R\big] && (12) \\
    S_\nu &= \mathrm{cholupdate}(S_\nu, \sqrt{|W^c_0|}(\overline{sp}_0 - \nu),
        \mathrm{sgn}\, W^c_0) && (13) \\
    K &= \Sigma^{\mu\nu} (S_\nu S_\nu^T)^{-1} && (14) \\
    \mu &= \nu && (15) \\
    S &= \mathrm{cholupdate}(S, K S_\nu, -1)\ \text{(one downdate per column)} && (16)

The paper's eq. (12) has no measurement noise; then (16) removes the whole spread
(for :math:`\nu = \mu`, :math:`K S_\nu = S`) and a resampled particle's copies would
never separate again. ``srupf.match_noise`` (:math:`\sqrt R`, the spread of the
corrector's pose) restores a proper Kalman update, :math:`P^+ \approx P (P + R)^{-1}
R \succ 0`; ``match_noise = 0`` gives the literal equations, where
:func:`jaxslam.core.sqrt.chol_update` clamps the lost pivots (``Info.pd_ok`` is False).

*Sampling.* The paper places the random draw twice: Sec. 3.1 samples
:math:`x \sim \mathcal N(\mu, S S^T)` at the end of the odometry update (eq. 9)
and Sec. 3.2 says that no sampling follows the scan matching, while Algorithm 2
samples at the very end (``sample_new_pose``). ``config.sampling = "prior"`` follows
the text: the corrector starts from the eq. (9) sample (its ellipse from
:math:`S`), and the particle stays at :math:`\nu`. ``"posterior"`` follows
Algorithm 2 literally: the corrector starts at :math:`\mu` and the particle moves to
:math:`x \sim \mathcal N(\nu, S^+ S^{+T})` after the update. Either way the map is
built at :math:`\nu`. With ``"posterior"`` the copies of a resampled particle only
separate by the small posterior spread, so ``"prior"`` is the default for ``pc``;
``npc`` (no corrector) uses ``"posterior"``. Weights, map integration and selective
resampling are as in GMapping (:func:`jaxslam.grid.filter.finish_step`).

*Constrained correction* (``config.constrain_matches``, default on; not in the
paper). :math:`\nu` keeps the corrector's heading, but its position moves from the
start only along the directions where the score is curved at the match
(:func:`jaxslam.grid.tracking.constrained_shift`, the test the per-scan tracking
uses): in a corridor the hill climb slides along the axis on map noise, by up to its
reach, and a particle that slides at a keyframe builds its map there. Along such an
axis the proposal's position is kept (``docs/design.md``, "Per-scan tracking").
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array
from jax.scipy.linalg import cho_solve

from jaxslam.base import sample_pose
from jaxslam.core import se2
from jaxslam.core.sigma import UTParams
from jaxslam.core.sqrt import chol_update, chol_update_many_checked, tria
from jaxslam.runtime.driver import scan_runner
from jaxslam.runtime.executables import module_function
from jaxslam.grid.filter import ParticleUpdate, guard, init, keyframe_update, scan_likelihood, scan_score_fn
from jaxslam.grid.types import GridSlamConfig, GridSlamParams, Odometry, noise_scale_of
from jaxslam.grid.map import CellReader
from jaxslam.grid.tracking import keyframe_match, per_scan
from jaxslam.models.odometry import (
    Prediction,
    motion_noise_sqrt,
    sqrt_unscented_predict,
)


class MeasurementUpdate(NamedTuple):
    """Result of eqs. (11)-(16) for one particle."""

    mean: Array  # (3,) = nu
    sqrt_cov: Array  # (3, 3) lower
    gain: Array  # (3, 3) K
    innovation_sqrt_cov: Array  # (3, 3) S_nu
    pd_ok: Array  # () bool


def sqrt_measurement_update(prediction: Prediction, nu: Array, match_noise_sqrt: Array) -> MeasurementUpdate:
    """Eqs. (11)-(16) of Zandara & Nicholson for one particle (see module docstring)."""
    points = prediction.propagated
    wc = prediction.cov_weights
    dev_mu = se2.pose_residual(points, prediction.mean)
    dev_nu = se2.pose_residual(points, nu)
    cross = jnp.einsum("i,ij,ik->jk", wc, dev_mu, dev_nu)  # (11)
    weighted = jnp.sqrt(wc[1:])[:, None] * dev_nu[1:]  # (2n, 3)
    stacked = jnp.concatenate([weighted.T, match_noise_sqrt.astype(points.dtype)], -1)
    s_nu = tria(stacked)  # (12)
    s_nu = chol_update(s_nu, jnp.sqrt(jnp.abs(wc[0])) * dev_nu[0], jnp.sign(wc[0]))  # (13)
    gain = cho_solve((s_nu, True), cross.T).T  # (14)
    columns = gain @ s_nu
    sqrt_cov, ok = chol_update_many_checked(prediction.sqrt_cov, columns.T, -1.0)  # (16)
    return MeasurementUpdate(nu, sqrt_cov, gain, s_nu, ok)


def best_sigma_point(prediction: Prediction, score) -> Array:
    """Eq. (10), the pose without a corrector: the propagated sigma point that
    ``score`` (``(M, 3) -> (M,)``, larger is better) ranks first."""
    return prediction.propagated[jnp.argmax(score(prediction.propagated))]


def ut_params(params: GridSlamParams) -> UTParams:
    return params.unscented


def predict(
    pose: Array, pose_sqrt_cov: Array, control: Array, params: GridSlamParams, noise_scale: Array | float = 1.0
) -> Prediction:
    """Odometry update, eqs. (1)-(8), for one particle; ``noise_scale`` multiplies the
    motion-proportional part of Q (tracked motion, :class:`jaxslam.grid.types.Odometry`)."""
    noise_sqrt = motion_noise_sqrt(
        control,
        params.srupf.q_linear,
        params.srupf.q_angular,
        noise_scale * params.srupf.q_linear_per_m,
        noise_scale * params.srupf.q_angular_per_rad,
        noise_scale * params.srupf.q_angular_per_m,
    )
    return sqrt_unscented_predict(pose, pose_sqrt_cov, control, noise_sqrt, ut_params(params))


def particle_update(
    key: Array,
    read: CellReader,
    pose: Array,
    pose_sqrt_cov: Array,
    control: Array,
    local_points: Array,
    mask: Array,
    params: GridSlamParams,
    config: GridSlamConfig,
    noise_scale: Array | float = 1.0,
):
    """Algorithm 2 for one particle: returns a :class:`~jaxslam.grid.filter.ParticleUpdate`
    ``(nu, next_pose, S, score, log_lik, pd_ok)``.

    ``config.sampling`` places the random draw (see the module docstring):
    ``"prior"`` draws ``x ~ N(mu, S S^T)`` after the odometry update (eq. 9) and
    starts the corrector there (then ``next_pose = nu``); ``"posterior"`` starts at
    ``mu`` and draws the next pose around ``nu`` after the measurement update
    (Algorithm 2, last line).
    """
    dtype = pose.dtype
    prediction = predict(pose, pose_sqrt_cov, control, params, noise_scale)
    score_fn = scan_score_fn(read, local_points, mask, params, config)
    count = jnp.maximum(jnp.sum(mask), 1).astype(dtype)
    key_prior, key_post = jax.random.split(key)
    if config.sampling == "prior":
        start = sample_pose(key_prior, prediction.mean, prediction.sqrt_cov)
    elif config.sampling == "posterior":
        start = prediction.mean
    else:
        raise ValueError(f"sampling must be 'prior' or 'posterior', got {config.sampling!r}")
    if config.correction == "pc":
        best, best_score, _ = keyframe_match(score_fn, read, local_points, mask, start, prediction.mean,
                                             prediction.sqrt_cov, params, config, prior_mean=prediction.mean)
        accept = best_score / count > params.matcher.min_score
        nu = jnp.where(accept, best, start)
    elif config.correction == "npc":
        nu = best_sigma_point(prediction, score_fn)
    else:
        raise ValueError(f"correction must be 'pc' or 'npc', got {config.correction!r}")
    update = sqrt_measurement_update(prediction, nu, jnp.diag(params.srupf.match_noise.astype(dtype)))
    log_lik, score = scan_likelihood(read, nu, local_points, mask, params, config)
    if config.sampling == "posterior":
        next_pose = sample_pose(key_post, nu, update.sqrt_cov)
    else:
        next_pose = nu
    return ParticleUpdate(nu, next_pose, update.sqrt_cov, score / count, log_lik, update.pd_ok)


def propose(
    key: Array,
    read: CellReader,
    pose: Array,
    sqrt_cov: Array,
    control: Odometry,
    local_points: Array,
    mask: Array,
    params: GridSlamParams,
    config: GridSlamConfig,
):
    """One particle's SRUPF-GM update (Algorithm 2) for a keyframe (the ``propose`` of
    :func:`jaxslam.grid.filter.keyframe_update`): :func:`particle_update` with the
    keyframe's increment. Q is per keyframe (``control.substeps`` is not used;
    ``noise_scale`` multiplies Q's motion-proportional part); ``config.correction``
    picks pc / npc."""
    dtype = pose.dtype
    return particle_update(key, read, pose, sqrt_cov, control.increment.astype(dtype), local_points, mask, params,
                           config, noise_scale_of(control, dtype))


# One SRUPF-GM update (Algorithm 2) for a keyframe.
_step = keyframe_update(propose)


# The filter's step, the one ``jaxslam run`` runs: every scan a step, tracked against
# the best particle's map, with the keyframe update where the keyframe rule on the
# tracked motion fires (jaxslam.grid.tracking.per_scan). ``keyframe_step`` is the
# keyframe update alone, for keyframe inputs chosen on the host.
keyframe_step = module_function(guard(_step), __name__, "keyframe_step")
keyframe_run = scan_runner(keyframe_step)
step = module_function(guard(per_scan(_step)), __name__, "step")
run = scan_runner(step)


__all__ = [
    "MeasurementUpdate", "best_sigma_point", "init", "keyframe_run", "keyframe_step", "particle_update", "predict",
    "propose", "run",
    "sqrt_measurement_update", "step",
]
