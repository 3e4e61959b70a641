"""Hill climbs written once: the climb against a NumPy climb, and the climbs run in turn
(jaxslam.grid.climbs, jaxslam.grid.matching.climbs_in_turn, the keyframe's
coarse-to-fine match) against the same climbs written out, bit for bit."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.grid.climbs import Phase, best_of, run_phases
from jaxslam.grid.filter import coarse_start, coarse_to_fine
from jaxslam.grid.matching import EllipseBound, get_matcher, gmapping_basis, hill_climb, search_bound
from jaxslam.grid.algorithms import grid_algorithm
from jaxslam.grid.types import with_values
from tests.grid.test_score_matching import coarse_case

TARGET = np.array([0.9, -0.7, 0.4])


def smooth_score(poses, sigma=1.0):
    """A smooth score with its optimum at :data:`TARGET`, wider for a larger ``sigma``."""
    d = poses - jnp.asarray(TARGET, poses.dtype)
    return -(d[..., 0] ** 2 + d[..., 1] ** 2 + 4.0 * d[..., 2] ** 2) / sigma


def numpy_climb(score, center, basis, iterations, bound=None, step=1.0):
    """GMapping's hill climb in NumPy float64: score the start, then per iteration the six
    moves of ``u``; move to the best if it beats the score, else halve the step."""
    wrap = lambda a: (a + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    pose = lambda u: np.concatenate([(center + basis @ u)[:2], [wrap((center + basis @ u)[2])]])  # noqa: E731
    u, best = np.zeros(3), score(center)
    for _ in range(iterations):
        candidates = [u + step * e for e in np.concatenate([np.eye(3), -np.eye(3)])]
        scores = []
        for c in candidates:
            inside = True
            if bound is not None:
                mean, factor, radius = bound
                offset = pose(c) - mean
                offset[2] = wrap(offset[2])
                inside = np.linalg.norm(np.linalg.solve(factor, offset)) <= radius + 1e-12
            scores.append(score(pose(c)) if inside else -np.inf)
        k = int(np.argmax(scores))
        if scores[k] > best:
            u, best = candidates[k], scores[k]
        else:
            step *= 0.5
    return pose(u), best


@pytest.mark.parametrize("bounded", [False, True])
def test_hill_climb_is_gmappings_climb(bounded):
    """:func:`hill_climb` (the start scored in the first pass of its loop) against the
    NumPy climb: the same moves, the same pose and score."""
    center = np.array([0.1, 0.2, 3.0])  # near +pi: the moves wrap the heading
    basis = np.diag([0.05, 0.08, 0.05])
    bound = (center + np.array([0.05, 0.0, 0.02]), np.diag([0.1, 0.12, 0.05]), 1.5) if bounded else None
    with jax.enable_x64(True):
        jax_bound = EllipseBound(*(jnp.asarray(b) for b in bound)) if bounded else None
        got_pose, got_score, _ = jax.jit(
            lambda c: hill_climb(smooth_score, c, jnp.asarray(basis), 9, jax_bound))(jnp.asarray(center))
    want_pose, want_score = numpy_climb(lambda p: float(smooth_score(jnp.asarray(p)[None])[0]), center, basis, 9,
                                        bound)
    np.testing.assert_allclose(np.asarray(got_pose), want_pose, rtol=0, atol=1e-12)
    assert float(got_score) == pytest.approx(want_score, abs=1e-12)
    assert np.linalg.norm(want_pose - center) > 0.1  # it climbed


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_phases_are_the_climbs_written_out(dtype):
    """A program of phases (a coarse climb, a narrow one from where it ended, a climb that
    runs only where the score so far is low, and the best of three starts) gives, bit for
    bit, what the same climbs give written out one after the other. The narrow climb
    starts from the coarse one's end (a climb from the first start would end elsewhere:
    the order is seen), and a climb that does not run changes nothing."""
    config = SimpleNamespace(match_iterations=5, coarse_iterations=3)
    with jax.enable_x64(dtype == jnp.float64):
        params = grid_algorithm("srupf-gm").make_params(np.linspace(-1.0, 1.0, 5), dtype=dtype)
        params = with_values(params, {"matcher.coarse_sigma": jnp.asarray(4.0, dtype), "matcher.score_sigma": jnp.asarray(1.0, dtype)})
        start = jnp.asarray([0.1, 0.2, 0.0], dtype)
        starts = jnp.asarray([[0.5, -0.5, 0.3], [0.85, -0.65, 0.35], [0.0, 0.0, 0.0]], dtype)

        def program(params, bar):
            def coarse_prepare(lane, c):
                return c, jnp.asarray(True), c["matched"]

            def fine_take(lane, c, active, pose, score):
                return {**c, "matched": jnp.where(active, pose, c["matched"]),
                        "score": jnp.where(active, score, c["score"])}

            def low_prepare(lane, c):
                return c, c["score"] < bar, c["matched"] + jnp.asarray([0.3, 0.0, 0.0], dtype)

            def best_prepare(lane, c):
                return c, jnp.asarray(True), starts[lane]

            phases = [Phase(1, True, coarse_prepare, fine_take), Phase(1, False, coarse_prepare, fine_take),
                      Phase(1, False, low_prepare, fine_take), Phase(3, False, best_prepare,
                                                                   lambda lane, c, a, x, s: best_of(c, a, x, s))]
            carry = {"matched": start, "score": jnp.zeros((), dtype), "found": jnp.full((), -jnp.inf, dtype),
                     "found_pose": jnp.zeros((3,), dtype)}
            return run_phases(smooth_score, phases, carry, params, config)

        def written_out(bar, params):
            basis = gmapping_basis(params, dtype)
            wide = lambda p: smooth_score(p, params.matcher.coarse_sigma)  # noqa: E731
            narrow = lambda p: smooth_score(p, params.matcher.score_sigma)  # noqa: E731
            pose, score, _ = hill_climb(wide, start, basis, config.coarse_iterations)
            pose, score, _ = hill_climb(narrow, pose, basis, config.match_iterations)
            if bar > 0:  # every score here is negative
                pose, score, _ = hill_climb(narrow, pose + jnp.asarray([0.3, 0.0, 0.0], dtype), basis,
                                            config.match_iterations)
            ends = [hill_climb(narrow, s, basis, config.match_iterations)[:2] for s in starts]
            return pose, score, ends

        def best_end(ends):
            best = int(np.argmax([float(e[1]) for e in ends]))
            return ends[best]

        for bar in (-1e9, 1e9):  # the third climb skipped, then run
            # params traced, as in the filters' programs (constants fold differently)
            got = jax.jit(program)(params, jnp.asarray(bar, dtype))
            pose, score, ends = jax.jit(written_out, static_argnums=0)(bar, params)
            want = (pose, score, *best_end(ends))
            for value, expected in zip((got["matched"], got["score"], got["found_pose"], got["found"]), want):
                np.testing.assert_array_equal(np.asarray(value), np.asarray(expected))
        direct, _, _ = hill_climb(lambda p: smooth_score(p, params.matcher.score_sigma), start, gmapping_basis(params, dtype),
                                  config.match_iterations)
        assert np.max(np.abs(np.asarray(got["matched"]) - np.asarray(direct))) > 0.01


@pytest.mark.parametrize("matcher", ["ellipse", "hill"])
def test_coarse_to_fine_is_the_coarse_stage_then_the_matcher(matcher):
    """The keyframe's match in one climb (:func:`coarse_to_fine`) gives, bit for bit,
    :func:`coarse_start` followed by the matcher, on the synthetic map from starts off
    the true pose, bounded around a prediction as SRUPF-GM bounds it."""
    from jaxslam.grid.filter import score_model
    from jaxslam.grid.score import make_score_fn

    true_pose, prm, pts, mask, read, config = coarse_case()
    config = SimpleNamespace(**{**vars(config), "matcher": matcher})
    score_fn = make_score_fn(read, pts, mask, prm.sensor.laser_offset, config.layout, score_model(prm), config.score_kernel,
                             config.free_check)
    sqrt_cov = jnp.diag(jnp.asarray([0.05, 0.05, 0.03]))

    def written_out(start, mean):
        begin = coarse_start(read, pts, mask, start, prm, config,
                             search_bound(matcher, mean, sqrt_cov, prm, prm.matcher.coarse_radius))
        return get_matcher(matcher)(score_fn, begin, sqrt_cov, prm, config.match_iterations, 0, prior_mean=mean)

    fused = jax.jit(lambda s, m: coarse_to_fine(read, pts, mask, s, sqrt_cov, prm, config, m, prior_mean=m))
    for offset in ([0.08, -0.05, 0.04], [-0.06, 0.09, -0.03]):
        start = jnp.asarray(true_pose + np.asarray(offset))
        mean = start + jnp.asarray([0.01, -0.01, 0.005])
        got, want = fused(start, mean), jax.jit(written_out)(start, mean)
        for value, expected in zip(got, want):
            np.testing.assert_array_equal(np.asarray(value), np.asarray(expected))
        assert np.hypot(*(np.asarray(got[0]) - true_pose)[:2]) < np.hypot(*offset[:2])  # it matched


def test_the_default_programs_hold_the_score_kernel_a_few_times(sim, monkeypatch):
    """Every call of the map evidence while the per-scan step is traced is one copy of
    the score kernel in the compiled program. With the climbs written once, SRUPF-GM's
    default step (tracking with recovery and loop closure, the keyframe's coarse-to-fine
    match) holds six: per map read, the climb, the turned guesses and the curvature test
    of the tracking; the climb, the curvature test and the likelihood of the keyframe.
    Written out climb by climb it held eighteen. The GMapping-style filter's default step
    holds six as well: the tracking's three, the keyframe's climb and its likelihood at
    the start and at the match."""
    import jaxslam.grid.score as score
    from jaxslam.grid import gmapping, srupf
    from jaxslam.grid.algorithms import grid_algorithm
    from tests.grid.sim_state import state_and_scans

    calls = []
    evidence = score.evidence
    monkeypatch.setattr(score, "evidence", lambda *a, **k: calls.append(1) or evidence(*a, **k))
    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        assert config.closure and config.recover_radius > 0 and config.coarse_iterations > 0
        gmapping_config = grid_algorithm("gmapping").make_config(2, config.layout, config.num_beams, config.max_points)
        for module, cfg, copies in ((srupf, config, 6), (gmapping, gmapping_config, 6)):
            calls.clear()
            jax.eval_shape(lambda s: module.step(jax.random.PRNGKey(0), s, jnp.zeros(3), scans[3], params, cfg),
                           state)
            assert len(calls) == copies, (module.__name__, len(calls))
