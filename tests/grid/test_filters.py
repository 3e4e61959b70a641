"""GMapping-style filter and SRUPF-GM on the laser simulator."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.core import se2
from jaxslam.core.sigma import UTParams
from jaxslam.datasets.carmen import select_keyframes
from jaxslam.datasets.laser_sim import simulate
from jaxslam.grid import gmapping, srupf
from jaxslam.grid.experiment import best_trajectory
from jaxslam.grid.filter import best_particle, init
from jaxslam.grid.paged import PagedLayout, stitch
from jaxslam.grid.algorithms import grid_algorithm
from jaxslam.grid.types import GridSlamConfig, Odometry, Scan
from jaxslam.grid.update import required_points
from jaxslam.models.odometry import motion_noise_sqrt, sqrt_unscented_predict

SPEC = PagedLayout.covering(-1.5, -1.5, 13.5, 9.5, 0.05, slots=1024)


@functools.cache
def sim_problem(keyframes: int = 40):
    """A small simulated office run: keyframe controls, scans, truth and odometry."""
    log = simulate(width=12.0, height=8.0, corridor=2.0, rooms_x=2, laps=1.1, num_beams=91, seed=3)
    kf = select_keyframes(log.odom_poses, 0.5, 0.3)[:keyframes]
    odom = log.odom_poses[kf]
    ranges = np.where(log.valid[kf], log.ranges[kf], 0.0)
    controls = np.asarray(se2.relative(jnp.asarray(odom[:-1]), jnp.asarray(odom[1:])))
    max_points = required_points(np.minimum(ranges, 20.0), log.valid[kf], SPEC.resolution)
    return log, kf, odom, ranges, controls, max_points


def run_filter(module, config, dtype, seed=0, **overrides):
    log, kf, odom, ranges, controls, _ = sim_problem()
    params = grid_algorithm("srupf-gm").make_params(log.angles, log.laser_offset, dtype=dtype, values=overrides)
    key = jax.random.PRNGKey(seed)
    state = init(key, params, config, Scan(jnp.asarray(ranges[0], dtype), jnp.asarray(log.valid[kf[0]])),
                 jnp.asarray(odom[0], dtype))
    xs_u = Odometry(jnp.asarray(controls, dtype), jnp.asarray(np.diff(kf), dtype))
    xs_z = Scan(jnp.asarray(ranges[1:], dtype), jnp.asarray(log.valid[kf[1:]]), jnp.zeros(len(kf) - 1, dtype))
    state, info = module.keyframe_run(key, state, xs_u, xs_z, params, config)
    assert int(state.status.code) == 0
    traj = best_trajectory(info.poses, info.ancestors, int(best_particle(state)))
    return state, info, np.concatenate([odom[:1], traj]), params


def make_config(kind, particles=8, **kw):
    *_, max_points = sim_problem()
    base = {"matcher": "hill" if kind == "gmapping" else "ellipse", "match_iterations": 8, "score_kernel": "gaussian2"}
    base.update(kw)
    return GridSlamConfig(particles, SPEC, 91, max_points, **base)


@functools.cache
def cached_run(kind):
    module = gmapping if kind == "gmapping" else srupf
    return run_filter(module, make_config(kind), jnp.float32)


@pytest.mark.parametrize("kind", ["gmapping", "srupf-gm"])
def test_simulated_run_beats_odometry(kind):
    """SLAM keeps the path within a few cm of the truth where odometry drifts away."""
    log, kf, odom, *_ = sim_problem()
    state, info, traj, _ = cached_run(kind)
    truth = log.true_poses[kf]
    slam_err = np.hypot(*(traj[:, :2] - truth[:, :2]).T)
    odom_err = np.hypot(*(odom[:, :2] - truth[:, :2]).T)
    heading_err = np.abs(np.asarray(se2.wrap_angle(jnp.asarray(traj[:, 2] - truth[:, 2]))))
    assert odom_err.max() > 0.3
    assert slam_err.mean() < 0.08, slam_err.mean()
    assert slam_err.max() < 0.2, slam_err.max()
    assert heading_err.max() < 0.05
    assert int(info.dropped_points.max()) == 0
    assert bool(np.all(np.asarray(info.pd_ok)))
    g, _ = stitch(state.maps.pool, state.maps.tables[int(best_particle(state))], state.maps.corner, SPEC)
    assert g.dtype == np.int8 and (g > 0).sum() > 500


@pytest.mark.parametrize("kind", ["gmapping", "srupf-gm"])
def test_coarse_to_fine_matches_keep_the_simulated_path(kind):
    """With ``coarse_iterations`` (the particles' climbs start from a climb on the wide
    kernel) both filters still keep the path within a few cm of the truth."""
    log, kf, *_ = sim_problem()
    module = gmapping if kind == "gmapping" else srupf
    state, info, traj, _ = run_filter(module, make_config(kind, coarse_iterations=3), jnp.float32)
    slam_err = np.hypot(*(traj[:, :2] - log.true_poses[kf][:, :2]).T)
    heading_err = np.abs(np.asarray(se2.wrap_angle(jnp.asarray(traj[:, 2] - log.true_poses[kf][:, 2]))))
    assert slam_err.mean() < 0.08, slam_err.mean()
    assert heading_err.max() < 0.05


def test_npc_runs_and_float64():
    """SRUPF-GM without pose correction, in float64: finite, dtype kept, factors PD."""
    config = make_config("srupf-gm", particles=6, correction="npc", sampling="posterior")
    state, info, traj, _ = run_filter(srupf, config, jnp.float64)
    assert state.poses.dtype == jnp.float64
    assert np.all(np.isfinite(traj))
    diag = np.diagonal(np.asarray(state.pose_sqrt_covs), axis1=-2, axis2=-1)
    assert np.all(diag > 0) and np.all(np.isfinite(diag))
    assert bool(np.all(np.asarray(info.pd_ok)))


def test_no_recompile_when_params_change():
    """Traced Params: new noise levels, thresholds and increments reuse the compilation."""
    config = make_config("gmapping", particles=4)
    run_filter(gmapping, config, jnp.float32, seed=1)
    after_first = gmapping.keyframe_run._cache_size()
    run_filter(gmapping, config, jnp.float32, seed=2, **{
        "gmapping.srr": 0.05, "map.l_occ": 6.0, "matcher.linear_step": 0.03, "weights.resample_threshold": 0.3,
        "sensor.usable_range": 15.0, "weights.gain": 0.1})
    assert gmapping.keyframe_run._cache_size() == after_first


def test_downdate_keeps_factor_pd_over_run():
    """With match noise the downdates of eq. (16) never lose positive definiteness."""
    state, info, _, _ = cached_run("srupf-gm")
    assert bool(np.all(np.asarray(info.pd_ok)))
    s = np.asarray(state.pose_sqrt_covs)
    eig = np.linalg.eigvalsh(s @ np.swapaxes(s, -1, -2))
    assert np.all(eig > 0)


def dense_measurement_update(points, mean, wc, prior_cov, nu, r_cov):
    """Float64 NumPy eqs. (11)-(16) with the measurement noise in (12)."""
    def res(a, b):
        d = a - b
        d[..., 2] = (d[..., 2] + np.pi) % (2 * np.pi) - np.pi
        return d

    dmu, dnu = res(points, mean), res(points, nu)
    cross = np.einsum("i,ij,ik->jk", wc, dmu, dnu)
    p_nu = np.einsum("i,ij,ik->jk", wc, dnu, dnu) + r_cov
    gain = cross @ np.linalg.inv(p_nu)
    return prior_cov - gain @ p_nu @ gain.T


PREDICT = jax.jit(sqrt_unscented_predict)
UPDATE = jax.jit(srupf.sqrt_measurement_update)


def test_sqrt_measurement_update_equals_dense():
    rng = np.random.default_rng(0)
    for alpha in (1.0, 0.5):
        pose = jnp.asarray([1.0, 2.0, 3.0])
        chol = jnp.asarray(np.linalg.cholesky(np.diag([0.01, 0.02, 0.005]) + 0.001))
        inc = jnp.asarray([0.8, 0.05, 0.3])
        pred = PREDICT(pose, chol, inc, motion_noise_sqrt(inc, 0.05, 0.05), UTParams(alpha, 2.0, 0.0))
        nu = pred.mean + jnp.asarray(rng.normal(0, 0.03, 3))
        r = jnp.diag(jnp.asarray([0.02, 0.02, 0.01]))
        up = UPDATE(pred, nu, r)
        want = dense_measurement_update(np.asarray(pred.propagated), np.asarray(pred.mean), np.asarray(pred.cov_weights),
                                        np.asarray(pred.cov), np.asarray(nu), np.asarray(r @ r.T))
        got = np.asarray(up.sqrt_cov @ up.sqrt_cov.T)
        np.testing.assert_allclose(got, want, atol=1e-10)
        assert bool(up.pd_ok)
        assert np.all(np.linalg.eigvalsh(got) > 0)
        # the update only shrinks the covariance
        assert np.all(np.linalg.eigvalsh(np.asarray(pred.cov) - got) > -1e-12)


def test_literal_update_stays_finite():
    """The paper's update without measurement noise collapses S; clamped, never NaN."""
    pose = jnp.asarray([0.0, 0.0, 0.0])
    chol = jnp.diag(jnp.asarray([0.05, 0.05, 0.02]))
    inc = jnp.asarray([1.0, 0.0, 0.0])
    pred = PREDICT(pose, chol, inc, motion_noise_sqrt(inc, 0.05, 0.05), UTParams(1.0, 2.0, 0.0))
    up = UPDATE(pred, pred.mean, jnp.zeros((3, 3)))
    assert np.all(np.isfinite(np.asarray(up.sqrt_cov)))
    assert float(jnp.max(jnp.abs(up.sqrt_cov @ up.sqrt_cov.T))) < 1e-6


def test_best_trajectory_follows_ancestors():
    # 3 steps, 3 particles; after step 1 particle 2 is copied twice.
    poses = np.arange(3 * 3 * 3, dtype=float).reshape(3, 3, 3)
    ancestors = np.array([[0, 1, 2], [2, 2, 0], [0, 1, 2]])
    traj = best_trajectory(poses, ancestors, 1)
    # final particle 1 <- step 2 index 1 <- step 1 index 2 <- step 0 index 2
    np.testing.assert_array_equal(traj[2], poses[2, 1])
    np.testing.assert_array_equal(traj[1], poses[1, 2])
    np.testing.assert_array_equal(traj[0], poses[0, 2])
