r"""A GMapping-style Rao-Blackwellized particle filter (Grisetti et al. 2005, 2007).

Per particle :math:`i` and keyframe :math:`t` (``GridSlamProcessor::processScan``):

1. proposal :math:`\tilde x^i_t \sim p(x_t | x^i_{t-1}, u_t)` with the srr/srt/str/stt
   odometry model (:func:`jaxslam.models.odometry.sample_gmapping`);
2. scan matching against the particle's own map from :math:`\tilde x^i_t`
   (hill climbing with step halving, :func:`jaxslam.grid.matching.hill_climb_match`);
   the corrected pose :math:`x^i_t` replaces the proposal when its score exceeds
   ``min_score``. With ``config.constrain_matches`` (an option here, off in
   :data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`; not in GMapping) the correction
   keeps the matched heading but moves the position only along the directions the
   scan constrains (:func:`jaxslam.grid.tracking.constrained_shift`, as SRUPF-GM's
   corrector, where it is the default, and the tracking);
3. weight :math:`\log w^i \mathrel{+}= g \log p(z_t | x^i_t, m^i)`;
4. the scan is integrated into the map at :math:`x^i_t`;
5. selective resampling when :math:`N_{eff} < \text{threshold}\, N`.

``init``/``step``/``run`` follow the house pattern; config is static, params traced.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.runtime.driver import scan_runner
from jaxslam.runtime.executables import module_function
from jaxslam.grid.filter import ParticleUpdate, guard, init, keyframe_update, scan_likelihood, scan_score_fn
from jaxslam.grid.types import GridSlamConfig, GridSlamParams, Odometry, noise_scale_of
from jaxslam.grid.map import CellReader
from jaxslam.grid.tracking import keyframe_match, per_scan
from jaxslam.models.odometry import sample_gmapping


def correct_pose(
    read: CellReader,
    pose: Array,
    pose_sqrt_cov: Array,
    local_points: Array,
    mask: Array,
    params: GridSlamParams,
    config: GridSlamConfig,
) -> tuple[Array, Array, Array]:
    """Scan-match one particle and score the result.

    Returns:
        ``(pose, score, log_likelihood)``; ``score`` is the mean occupancy over the
        matched beams (in ``[0, 1]``).
    """
    score_fn = scan_score_fn(read, local_points, mask, params, config)
    best, _, count = keyframe_match(score_fn, read, local_points, mask, pose, pose, pose_sqrt_cov, params, config)
    log_lik_best, score_best = scan_likelihood(read, best, local_points, mask, params, config)
    log_lik_init, score_init = scan_likelihood(read, pose, local_points, mask, params, config)
    accept = score_best / count > params.matcher.min_score
    return (
        jnp.where(accept, best, pose),
        jnp.where(accept, score_best, score_init) / count,
        jnp.where(accept, log_lik_best, log_lik_init),
    )


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
    """One particle's GMapping proposal for a keyframe (the ``propose`` of
    :func:`jaxslam.grid.filter.keyframe_update`): a draw from the srr/srt/str/stt
    odometry model, scan-matched against its own map (:func:`correct_pose`). The noise
    gains are divided by ``sqrt(control.substeps)`` and multiplied by its
    ``noise_scale`` (tracked motion); the covariance is kept.

    Returns:
        A :class:`~jaxslam.grid.filter.ParticleUpdate`: the map is updated at the
        corrected pose and the particle moves there.
    """
    dtype = pose.dtype
    increment = control.increment.astype(dtype)
    scale = noise_scale_of(control, dtype) * jax.lax.rsqrt(jnp.maximum(jnp.asarray(control.substeps, dtype), 1.0))
    g = params.gmapping
    proposal = sample_gmapping(key, pose, increment, scale * g.srr, scale * g.srt, scale * g.str, scale * g.stt)
    corrected, score, log_lik = correct_pose(read, proposal, sqrt_cov, local_points, mask, params, config)
    return ParticleUpdate(corrected, corrected, sqrt_cov, score, log_lik, jnp.asarray(True))


# One GMapping update for a keyframe.
_step = keyframe_update(propose)


# The filter's step, the one ``jaxslam run`` runs: every scan a step, tracked against
# the best particle's map, with the keyframe update where the keyframe rule on the
# tracked motion fires (jaxslam.grid.tracking.per_scan). ``keyframe_step`` is the
# keyframe update alone, for keyframe inputs chosen on the host.
keyframe_step = module_function(guard(_step), __name__, "keyframe_step")
keyframe_run = scan_runner(keyframe_step)
step = module_function(guard(per_scan(_step)), __name__, "step")
run = scan_runner(step)


__all__ = ["correct_pose", "init", "keyframe_run", "keyframe_step", "propose", "run", "step"]
