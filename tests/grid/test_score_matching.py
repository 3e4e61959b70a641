"""Map evidence kernels against NumPy, and scan matchers on a synthetic map."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.datasets.laser_sim import office_world, raycast
from jaxslam.grid.filter import coarse_start, score_model
from jaxslam.grid.map import GridSpec, dense_reader, init_grids
from jaxslam.grid.algorithms import grid_algorithm
from jaxslam.grid.types import GridSlamParams, with_values
from jaxslam.grid.matching import (
    EllipseBound,
    ellipse_factor,
    get_matcher,
    hill_climb,
    hill_climb_match,
    search_bound,
)
from jaxslam.grid.score import (
    ScoreModel,
    beam_points,
    bilinear_occupancy,
    gaussian_nearest_occupancy,
    gaussian_window_occupancy,
    make_score_fn,
    scan_log_likelihood,
)
from jaxslam.grid.update import update_grids

SPEC = GridSpec(height=24, width=30, resolution=0.1, origin_x=-1.0, origin_y=-0.5)


def np_occ(grid, col, row, sat):
    if 0 <= col < grid.shape[1] and 0 <= row < grid.shape[0]:
        return np.clip(grid[row, col], 0, sat) / sat
    return 0.0


def np_bilinear(grid, x, y, spec, sat):
    u = (x - spec.origin_x) / spec.resolution - 0.5
    v = (y - spec.origin_y) / spec.resolution - 0.5
    c, r = int(np.floor(u)), int(np.floor(v))
    fx, fy = u - c, v - r
    return (
        (1 - fx) * (1 - fy) * np_occ(grid, c, r, sat)
        + fx * (1 - fy) * np_occ(grid, c + 1, r, sat)
        + (1 - fx) * fy * np_occ(grid, c, r + 1, sat)
        + fx * fy * np_occ(grid, c + 1, r + 1, sat)
    )


def bump(x):
    return max(1 - x / 4, 0.0) ** 4


def np_window(grid, x, y, spec, sat, sigma, half):
    """Max over the (2 half + 1)^2 cells around the end point (or its 2x2 stencil)."""
    u = (x - spec.origin_x) / spec.resolution
    v = (y - spec.origin_y) / spec.resolution
    if half == 1:
        c0 = int(np.floor(u)) - 1
        r0 = int(np.floor(v)) - 1
        cells = [(c0 + i, r0 + j) for i in range(3) for j in range(3)]
    else:
        c0 = int(np.floor(u - 0.5))
        r0 = int(np.floor(v - 0.5))
        cells = [(c0 + i, r0 + j) for i in range(2) for j in range(2)]
    best = 0.0
    for c, r in cells:
        dx2 = ((c + 0.5 - u) * spec.resolution) ** 2 / sigma**2
        dy2 = ((r + 0.5 - v) * spec.resolution) ** 2 / sigma**2
        best = max(best, np_occ(grid, c, r, sat) * bump(dx2) * bump(dy2))
    return best


@pytest.mark.parametrize("kernel", ["bilinear", "gaussian2", "gaussian3"])
def test_evidence_kernels_match_numpy(kernel, dtype):
    rng = np.random.default_rng(1)
    grid = rng.integers(-10, 12, SPEC.shape).astype(np.int8)
    pts = np.stack([rng.uniform(-1.3, 2.3, 200), rng.uniform(-0.8, 2.2, 200)], -1)
    g, p = dense_reader(jnp.asarray(grid), SPEC), jnp.asarray(pts, dtype)
    if kernel == "bilinear":
        got = bilinear_occupancy(g, p, SPEC, 8.0)
        want = [np_bilinear(grid, x, y, SPEC, 8.0) for x, y in pts]
    elif kernel == "gaussian2":
        got = gaussian_nearest_occupancy(g, p, SPEC, 8.0, 0.07)
        want = [np_window(grid, x, y, SPEC, 8.0, 0.07, 0) for x, y in pts]
    else:
        got = gaussian_window_occupancy(g, p, SPEC, 8.0, 0.07)
        want = [np_window(grid, x, y, SPEC, 8.0, 0.07, 1) for x, y in pts]
    assert got.dtype == dtype
    np.testing.assert_allclose(np.asarray(got), want, atol=1e-5 if dtype == np.float32 else 1e-12)


def test_log_likelihood_floor():
    grid = jnp.zeros(SPEC.shape, jnp.int8)
    pts = jnp.asarray([[0.5, 0.0], [1.0, 0.2]])
    ll, score = scan_log_likelihood(
        dense_reader(grid, SPEC), jnp.zeros(3), pts, jnp.asarray([True, False]), jnp.zeros(3), SPEC, ScoreModel(8.0, 0.05, 0.01)
    )
    np.testing.assert_allclose(float(ll), np.log(0.01), rtol=1e-6)
    assert float(score) == 0.0


def test_beam_weights_match_numpy():
    from jaxslam.grid.filter import beam_weights

    rng = np.random.default_rng(3)
    ranges = np.concatenate([[0.0, 1e-30, 20.0, 20.0001, 80.0], rng.uniform(0.0, 90.0, 200)])
    valid = rng.random(ranges.size) > 0.2
    got = np.asarray(beam_weights(jnp.asarray(ranges), jnp.asarray(valid), 20.0))
    with np.errstate(divide="ignore"):
        want = np.where(valid, np.minimum(1.0, (20.0 / ranges) ** 2), 0.0)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert np.all(got[valid & (ranges <= 20.0)] == 1.0)  # exactly the mask within score_range
    assert np.all(np.isfinite(got))


def test_weighted_score_and_log_likelihood_match_numpy():
    """Weights in place of the mask: sum_b w_b o_b and sum_b w_b log(eps + (1 - eps) o_b)."""
    rng = np.random.default_rng(4)
    grid = rng.integers(-10, 12, SPEC.shape).astype(np.int8)
    pts = np.stack([rng.uniform(-0.9, 1.9, 50), rng.uniform(-0.4, 1.8, 50)], -1)
    weights = np.where(rng.random(50) > 0.3, rng.uniform(0.0, 1.0, 50), 0.0)
    pose = np.array([0.1, -0.05, 0.2])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    world = pts @ np.array([[c, s], [-s, c]]) + pose[:2]
    occ = np.array([np_bilinear(grid, x, y, SPEC, 8.0) for x, y in world])
    eps = 0.01
    ll, score = scan_log_likelihood(dense_reader(jnp.asarray(grid), SPEC), jnp.asarray(pose), jnp.asarray(pts),
                                    jnp.asarray(weights), jnp.zeros(3), SPEC, ScoreModel(8.0, 0.05, eps))
    np.testing.assert_allclose(float(score), np.sum(weights * occ), rtol=1e-10)
    np.testing.assert_allclose(float(ll), np.sum(weights * np.log(eps + (1 - eps) * occ)), rtol=1e-10)
    # a boolean mask is the weights 0 and 1
    mask = weights > 0
    ll_m, score_m = scan_log_likelihood(dense_reader(jnp.asarray(grid), SPEC), jnp.asarray(pose), jnp.asarray(pts),
                                        jnp.asarray(mask), jnp.zeros(3), SPEC, ScoreModel(8.0, 0.05, eps))
    ll_1, score_1 = scan_log_likelihood(dense_reader(jnp.asarray(grid), SPEC), jnp.asarray(pose), jnp.asarray(pts),
                                        jnp.asarray(mask.astype(float)), jnp.zeros(3), SPEC, ScoreModel(8.0, 0.05, eps))
    assert float(ll_m) == float(ll_1) and float(score_m) == float(score_1)


# --- scan matching on a synthetic office map -------------------------------------

# Walls of the office lie on multiples of 5 cm; a misaligned origin keeps them off
# cell boundaries, where a cell-centre score would be biased by half a cell.
WORLD_SPEC = GridSpec(height=240, width=360, resolution=0.05, origin_x=-1.0137, origin_y=-0.9871)


@functools.cache
def synthetic_map():
    """A map of the simulated office from exact scans at known poses, and a test scan."""
    walls = office_world(16.0, 10.0, 2.0, 3, seed=0)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    poses = np.array([[x, 1.0, 0.0] for x in np.arange(1.0, 15.0, 1.0)] + [[15.0, y, np.pi / 2] for y in np.arange(1.0, 9.0, 1.0)])
    ranges = raycast(walls, poses[:, :2], poses[:, 2:3] + angles, 30.0)
    valid = np.isfinite(ranges)
    ranges = np.where(valid, ranges, 0.0)
    def body(grids, scan):
        pose, r, v = scan
        return update_grids(grids, pose[None], r, v, jnp.asarray(angles), jnp.zeros(3), WORLD_SPEC, 40000,
                            20.0, -1.0, 4.0, 60.0)[0], None

    grids, _ = jax.jit(lambda g, xs: jax.lax.scan(body, g, xs))(
        init_grids(1, WORLD_SPEC), (jnp.asarray(poses), jnp.asarray(ranges), jnp.asarray(valid))
    )
    true_pose = np.array([7.3, 1.1, 0.05])
    z = raycast(walls, true_pose[None, :2], true_pose[2] + angles[None], 30.0)[0]
    return grids[0], angles, z, true_pose


def params_for(angles) -> GridSlamParams:
    return grid_algorithm("srupf-gm").make_params(angles, dtype=jnp.float64)


@pytest.mark.parametrize("matcher,kernel", [("hill", "gaussian2"), ("ellipse", "gaussian3"), ("gradient", "bilinear")])
def test_matcher_recovers_known_offset(matcher, kernel):
    grid, angles, z, true_pose = synthetic_map()
    prm = params_for(angles)
    valid = np.isfinite(z)
    pts = beam_points(jnp.asarray(np.where(valid, z, 0.0)), jnp.asarray(angles))
    score_fn = make_score_fn(dense_reader(grid, WORLD_SPEC), pts, jnp.asarray(valid), jnp.zeros(3), WORLD_SPEC, score_model(prm), kernel)
    sqrt_cov = jnp.diag(jnp.asarray([0.08, 0.08, 0.04]))
    fn = jax.jit(lambda p: get_matcher(matcher)(score_fn, p, sqrt_cov, prm, 12, 0, prior_mean=p))
    for offset in ([0.06, -0.05, 0.03], [-0.04, 0.07, -0.025], [0.03, 0.03, 0.0]):
        start = true_pose + np.asarray(offset)
        best, score = fn(jnp.asarray(start))
        err = np.asarray(best) - true_pose
        assert np.hypot(err[0], err[1]) < 0.025, (matcher, offset, err)
        assert abs(err[2]) < 0.01, (matcher, offset, err)
        assert float(score) >= float(score_fn(jnp.asarray(start)[None])[0])


def test_ellipse_bound_is_respected():
    """No accepted candidate leaves the Mahalanobis ellipse around the bound centre."""
    target = jnp.asarray([1.0, 0.0, 0.0])

    def score_fn(poses):  # maximised far outside the ellipse
        return -jnp.sum((poses - target) ** 2, -1)

    centre = jnp.zeros(3)
    chol = jnp.diag(jnp.asarray([0.1, 0.1, 0.1]))
    bound = EllipseBound(centre, chol, jnp.asarray(2.0))
    best, _, _ = hill_climb(score_fn, centre, jnp.diag(jnp.asarray([0.1, 0.1, 0.1])), 30, bound)
    maha = float(jnp.linalg.norm(jnp.linalg.solve(chol, best - centre)))
    assert maha <= 2.0 + 1e-9
    assert float(best[0]) > 0.15  # it did move towards the target


def coarse_case():
    """The synthetic map's scan at its true pose, for the coarse-stage tests:
    ``(true_pose, params, local points, mask, reader, config)``."""
    from types import SimpleNamespace

    grid, angles, z, true_pose = synthetic_map()
    valid = np.isfinite(z)
    pts = beam_points(jnp.asarray(np.where(valid, z, 0.0)), jnp.asarray(angles))
    config = SimpleNamespace(
        coarse_iterations=4, layout=WORLD_SPEC, score_kernel="gaussian3", free_check=False, sampling="posterior",
        correction="pc", matcher="ellipse", match_iterations=8, refine_steps=0, constrain_matches=False,
    )
    return true_pose, params_for(angles), pts, jnp.asarray(valid), dense_reader(grid, WORLD_SPEC), config


def test_coarse_start_widens_the_basin_of_the_narrow_match():
    """A coarse-to-fine match (:func:`jaxslam.grid.filter.coarse_start`) recovers more
    starts than the narrow climb alone, and more than as many narrow iterations: the
    gain is the wide kernel's, not the extra iterations'."""
    from types import SimpleNamespace

    true_pose, prm, pts, mask, read, config = coarse_case()
    score_fn = make_score_fn(read, pts, mask, jnp.zeros(3), WORLD_SPEC, score_model(prm), "gaussian3")
    start = jnp.asarray(true_pose + 0.1)
    assert coarse_start(read, pts, mask, start, prm, SimpleNamespace(coarse_iterations=0)) is start

    def recovered(params, coarse):
        def match(p):
            if coarse:
                p = coarse_start(read, pts, mask, p, params, config)
            return hill_climb_match(score_fn, p, None, prm, 8)[0]

        match = jax.jit(match)
        rng = np.random.default_rng(0)
        count = 0
        for _ in range(40):
            start = true_pose + rng.uniform([-0.2, -0.2, -0.1], [0.2, 0.2, 0.1])
            err = np.asarray(match(jnp.asarray(start))) - true_pose
            count += bool(np.hypot(err[0], err[1]) < 0.025 and abs(err[2]) < 0.01)
        return count

    fine = recovered(prm, False)
    wide = recovered(prm, True)  # coarse_sigma 0.2236 m, GMapping's kernel
    narrow = recovered(with_values(prm, {"matcher.coarse_sigma": prm.matcher.score_sigma}), True)  # 4 + 8 narrow iterations
    assert wide >= 2 * fine, (fine, wide)
    assert wide >= narrow + 3, (narrow, wide)


def test_coarse_start_stays_in_the_matchers_ellipse():
    """The coarse stage bounded as the filters bound it (:func:`search_bound` with
    ``coarse_radius``) never leaves its ellipse, where the unbounded wide climb does: a
    prediction 0.15 m and 0.06 rad off the true pose with a covariance whose ellipse
    reaches about 0.1 m and 0.05 rad, so the map's optimum lies outside it."""
    true_pose, prm, pts, mask, read, config = coarse_case()
    mean = jnp.asarray(true_pose + np.array([0.15, 0.0, 0.06]))
    radius = float(prm.matcher.coarse_radius)
    sqrt_cov = jnp.diag(jnp.asarray([0.1, 0.1, 0.05]) / radius)
    bound = search_bound("ellipse", mean, sqrt_cov, prm, prm.matcher.coarse_radius)
    assert search_bound("hill", mean, sqrt_cov, prm, prm.matcher.coarse_radius) is None
    assert search_bound(hill_climb_match, mean, sqrt_cov, prm, prm.matcher.coarse_radius) is None
    assert float(search_bound(get_matcher("ellipse"), mean, sqrt_cov, prm, prm.matcher.coarse_radius).radius) == radius
    np.testing.assert_allclose(np.asarray(bound.sqrt_cov), np.asarray(ellipse_factor(sqrt_cov, prm)))
    assert float(bound.radius) == radius
    assert float(search_bound("ellipse", mean, sqrt_cov, prm).radius) == float(prm.matcher.ellipse_radius)

    def mahalanobis(pose):
        d = np.asarray(pose) - np.asarray(mean)
        return float(np.linalg.norm(np.linalg.solve(np.asarray(bound.sqrt_cov), d)))

    free = np.asarray(coarse_start(read, pts, mask, mean, prm, config))
    held = np.asarray(coarse_start(read, pts, mask, mean, prm, config, bound))
    assert mahalanobis(free) > radius, free  # the wide climb left the region
    assert mahalanobis(held) <= radius + 1e-9, held
    assert np.linalg.norm(held - np.asarray(mean)) > 0.02  # and still climbed inside it


def test_srupf_particle_update_keeps_the_coarse_stage_in_its_ellipse():
    """SRUPF-GM's particle update passes the bound to its coarse stage: with a tight
    prediction 0.14 m and 0.08 rad off the map's optimum, the corrected pose stays within
    ``max(coarse_radius, ellipse_radius)`` standard deviations of the prediction; with
    the bound lifted (``coarse_radius`` 1e6) the wide climb carries it past that."""
    from jaxslam.grid.srupf import particle_update, predict

    true_pose, prm, pts, mask, read, config = coarse_case()
    prm = with_values(prm, {"srupf.q_linear": 0.005, "srupf.q_angular": 0.005})
    pose = jnp.asarray(true_pose + np.array([0.1, 0.1, 0.08]))
    sqrt_cov = jnp.diag(jnp.full((3,), 1e-3))
    control = jnp.zeros(3)
    prediction = predict(pose, sqrt_cov, control, prm)
    factor = np.asarray(ellipse_factor(prediction.sqrt_cov, prm))

    def mahalanobis(p):
        return float(np.linalg.norm(np.linalg.solve(factor, np.asarray(p) - np.asarray(prediction.mean))))

    def corrected(params):
        return particle_update(jax.random.PRNGKey(0), read, pose, sqrt_cov, control, pts, mask, params, config)[0]

    reach = max(float(prm.matcher.coarse_radius), float(prm.matcher.ellipse_radius))
    held, free = mahalanobis(corrected(prm)), mahalanobis(corrected(with_values(prm, {"matcher.coarse_radius": jnp.asarray(1e6)})))
    assert held <= reach + 1e-6, (held, free)
    assert free > reach, (held, free)
