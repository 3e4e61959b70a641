"""Per-scan tracking (jaxslam.grid.tracking): the keyframe rule on the tracked motion,
the fallback of an untrusted match, and the filter's own pose for every scan."""

import dataclasses
import functools

import chex
import jax
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from jaxslam.datasets.geometry import se2_between, se2_compose
from jaxslam.datasets.keyframes import select_keyframes
from jaxslam.datasets.odometry_repair import repair_stale_odometry
from jaxslam.grid import srupf
from jaxslam.grid.algorithms import grid_algorithm
from jaxslam.grid.experiment import run_grid_slam
from jaxslam.grid.recovery import RECOVER_RADIUS, RECOVER_SLIP, jumped, slip
from jaxslam.grid.tracking import constrained_shift, is_keyframe, scan_trajectory
from jaxslam.grid.tracking import track as _track
from jaxslam.grid.types import Scan, with_values
from tests.grid.sim_state import state_and_scans


def _compose_all(start, increments):
    poses = np.empty((increments.shape[0] + 1, 3))
    poses[0] = start
    for i, u in enumerate(increments):
        poses[i + 1] = se2_compose(poses[i], u)
    return poses


@pytest.fixture(scope="module")
def blind_turns(sim):
    """The simulated log with odometry that reports only 20% of every rotation (the
    FR079 doorway case, everywhere: the robot turns, the wheels barely notice)."""
    true = sim.true_poses
    increments = se2_between(true[:-1], true[1:])
    increments[:, 2] *= 0.2
    return dataclasses.replace(sim, odom_poses=_compose_all(true[0], increments))


def _position_error(result, log):
    return np.hypot(*(result.trajectory[:, :2] - log.true_poses[: result.trajectory.shape[0], :2]).T)


@pytest.mark.long
def test_odometry_that_misses_turns_is_mapped_with_the_defaults(blind_turns):
    """With the defaults every scan is tracked, so the keyframe rule sees the real
    rotation and the proposals start from it; the error stays at the cell scale for
    every scan, not only at keyframes. Without tracking (GMapping's odometry rule) the
    same log is lost: the test can fail."""
    true_turn = np.abs(se2_between(blind_turns.true_poses[:-1], blind_turns.true_poses[1:])[:, 2]).sum()
    odom_turn = np.abs(se2_between(blind_turns.odom_poses[:-1], blind_turns.odom_poses[1:])[:, 2]).sum()
    assert odom_turn < 0.25 * true_turn
    # A margin of 8 m gives a page table that holds both runs' maps from the start: no
    # growth, so one compiled chunk runner serves both runs (with 3 m each run grew its
    # table once, at another step, and compiled three runners; the maps and
    # trajectories are the same either way).
    options = dict(particles=4, seed=0, progress=False, margin=8.0, config={"match_iterations": 8})
    tracked = run_grid_slam(blind_turns, "srupf-gm", **options)
    err = _position_error(tracked, blind_turns)
    assert tracked.trajectory.shape == (blind_turns.num_scans, 3)
    # Within a few cells on average. Along the directions a scan leaves flat the
    # keyframe correction keeps the odometry (constrain_matches), so with 4 particles
    # the position drifts by up to a few decimetres before a turn pins it (seeds 0-2:
    # mean 0.09-0.14 m, max 0.23-0.38 m; 0.04-0.09 / 0.11-0.19 m unconstrained).
    assert err.mean() < 0.15 and err.max() < 0.5, (err.mean(), err.max())
    # More keyframes than the odometry rule would give: the tracked rotation counts.
    assert tracked.keyframes.shape[0] > select_keyframes(blind_turns.odom_poses).shape[0]
    assert tracked.info["track_accepted"].mean() > 0.8

    # Without tracking: every match refused (the odometry kept) and the odometry's own
    # motion noise (track_noise_scale 1), which is the run of config tracking=False bit
    # for bit (checked: the same trajectory and keyframes), in the program compiled above
    # (params are traced, the config is static).
    blind = run_grid_slam(blind_turns, "srupf-gm", **{**options, "params": {"tracking.min_score": 1e9,
                                                                             "tracking.noise_scale": 1.0}})
    assert not blind.info["track_accepted"].any()
    assert _position_error(blind, blind_turns).mean() > 5 * err.mean()


@pytest.mark.long
def test_stale_odometry_breaks_tracking_and_its_repair_maps_with_the_defaults(sim):
    """MIT CSAIL's dropouts on the simulated log: at the four sharpest turns the
    odometry repeats one pose for five scans and the sixth carries the whole motion.
    The tracking follows the robot's turn through the stretch and then adds the
    catch-up again: the map is lost (metres of error, the test can fail). The CARMEN
    reader's repair (jaxslam.datasets.odometry_repair.repair_stale_odometry) spreads
    each catch-up over its stretch, and the run is as good as with clean odometry."""
    true = sim.true_poses
    turn = np.convolve(np.abs(se2_between(true[:-1], true[1:])[:, 2]), np.ones(6), "valid")
    starts: list[int] = []
    for s in np.argsort(-turn):
        if 10 < s < sim.num_scans - 20 and all(abs(s - t) > 30 for t in starts):
            starts.append(int(s))
    starts = starts[:4]
    stale = np.array(sim.odom_poses, dtype=np.float64)
    for s in starts:
        stale[s + 1 : s + 6] = stale[s]
    repaired, report = repair_stale_odometry(stale, np.asarray(sim.scan_times))
    assert report["repaired"] == 4 and report["repaired_scans"] == 20
    options = dict(particles=4, seed=0, progress=False, margin=8.0, config={"match_iterations": 8})
    errors = {}
    for name, odom in (("clean", sim.odom_poses), ("stale", stale), ("repaired", repaired)):
        run = run_grid_slam(dataclasses.replace(sim, odom_poses=odom), "srupf-gm", **options)
        errors[name] = _position_error(run, sim).mean()
    # Measured (seed 0): clean 0.031 m, stale 3.6 m, repaired 0.045 m.
    assert errors["stale"] > 1.0, errors
    assert errors["repaired"] < 0.1 and errors["repaired"] < 2 * errors["clean"] + 0.02, errors


def test_tracking_corrects_a_wrong_increment_and_falls_back_on_a_bad_match(sim):
    # Compiled once per config (eagerly, op by op in float64, the four calls took 30 s).
    track = jax.jit(_track, static_argnums=4)
    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        wrong = true_step + np.array([0.03, -0.02, 0.04])
        motion, score, accepted, *_ = track(state, wrong, scans[3], params, config)
        assert bool(accepted) and float(score) > float(params.tracking.min_score)
        # The match removes most of the heading error of the odometry increment; in
        # this corridor the position along it is weakly constrained, so the position
        # error may only stay about where it was.
        before = np.abs(se2_between(true_step[None], wrong[None])[0])
        after = np.abs(se2_between(true_step[None], np.asarray(motion)[None])[0])
        assert after[2] < 0.25 * before[2], (before, after)
        assert np.hypot(*after[:2]) < np.hypot(*before[:2]) + 0.015, (before, after)

        # A scan that does not fit the map (a different room's ranges, shuffled)
        # scores below track_min_score: the odometry is kept exactly, no jump.
        rng = np.random.default_rng(0)
        junk = Scan(rng.permutation(np.asarray(scans[3].ranges)), scans[3].valid, 0.0)
        motion, score, accepted, *_ = track(state, wrong, junk, params, config)
        assert not bool(accepted) and float(score) < float(params.tracking.min_score)
        np.testing.assert_allclose(np.asarray(motion), wrong, atol=1e-12)

        # Where the score is not curved enough (here: nowhere) the position keeps the
        # odometry's and only the heading is corrected.
        flat = with_values(params, {"tracking.min_curvature": np.float64(1e9)})
        motion, _, accepted, *_ = track(state, wrong, scans[3], flat, config)
        assert bool(accepted)
        np.testing.assert_allclose(np.asarray(motion)[:2], wrong[:2], atol=1e-12)
        assert abs(float(se2_between(true_step[None], np.asarray(motion)[None])[0, 2])) < 0.25 * 0.04

        # tracking=False: the odometry alone, no match.
        off = dataclasses.replace(config, tracking=False)
        motion, _, accepted, *_ = track(state, wrong, scans[3], params, off)
        assert not bool(accepted)
        np.testing.assert_allclose(np.asarray(motion), wrong, atol=1e-12)


def test_coarse_to_fine_tracking_corrects_a_wrong_increment(sim):
    """With ``coarse_iterations`` the tracking's climb starts where a climb on the wide
    kernel ended: an increment 0.1 m and 0.1 rad wrong, where the plain climb stops in
    a worse optimum, is corrected; with ``coarse_tracking`` off the tracking is the
    plain one, to the last digit."""
    track = jax.jit(_track, static_argnums=4)
    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        config = dataclasses.replace(config, coarse_iterations=0)  # the plain climb (SRUPF-GM's default has it)
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        wrong = true_step + np.array([0.1, 0.05, -0.1])
        coarse = dataclasses.replace(config, coarse_iterations=3)
        plain = track(state, wrong, scans[3], params, config)
        motion, score, accepted, *_ = track(state, wrong, scans[3], params, coarse)
        assert bool(accepted) and float(score) > float(plain[1])
        stuck = np.abs(se2_between(true_step[None], np.asarray(plain[0])[None])[0])
        after = np.abs(se2_between(true_step[None], np.asarray(motion)[None])[0])
        assert stuck[2] > 0.1, stuck  # the plain climb's worse optimum
        assert after[2] < 0.01 and np.hypot(*after[:2]) < 0.02, after
        particles_only = track(state, wrong, scans[3], params, dataclasses.replace(coarse, coarse_tracking=False))
        chex.assert_trees_all_equal(plain, particles_only)


def test_constrained_shift_drops_the_flat_direction_of_a_corridor():
    """A score that is a ridge along x (a corridor along x) gives no information on x:
    the correction keeps only its y part; a bowl keeps both."""
    import jax.numpy as jnp

    params = grid_algorithm("srupf-gm").make_params(np.zeros(3), dtype=np.float64)
    guess = np.array([1.0, 2.0, 0.3])
    matched = np.array([1.3, 2.1, 0.35])
    count = jnp.asarray(100.0)

    def ridge(poses):  # 100 beams, score falls with (y - 2.1)^2 only
        return 100 * (0.6 - 40.0 * (poses[:, 1] - 2.1) ** 2)

    def bowl(poses):
        return 100 * (0.6 - 40.0 * (poses[:, 1] - 2.1) ** 2 - 40.0 * (poses[:, 0] - 1.3) ** 2)

    with jax.enable_x64(True):
        shift = constrained_shift(ridge, jnp.asarray(matched), jnp.asarray(guess), ridge(matched[None])[0], count,
                                  params)
        np.testing.assert_allclose(np.asarray(shift), [0.0, 0.1], atol=1e-9)
        shift = constrained_shift(bowl, jnp.asarray(matched), jnp.asarray(guess), bowl(matched[None])[0], count,
                                  params)
        np.testing.assert_allclose(np.asarray(shift), [0.3, 0.1], atol=1e-9)


def test_keyframe_rule_matches_select_keyframes():
    """The in-filter rule is GMapping's (``select_keyframes``) on the given motion."""
    params = grid_algorithm("srupf-gm").make_params(np.zeros(3), dtype=np.float64, values={"keyframes.linear_update": 1.0, "keyframes.angular_update": 0.5, "keyframes.temporal_update": 2.0})
    cases = [((0.99, 0.0, 0.0), False), ((1.0, 0.0, 0.0), True), ((0.0, 0.5, 0.0), True),
             ((0.0, 0.49, 2.0), False), ((0.0, 0.0, 2.01), True)]
    for (distance, rotation, time), expected in cases:
        since = np.array([distance, rotation, time, 1.0])
        assert bool(is_keyframe(since, params)) == expected, since
    off = with_values(params, {"keyframes.temporal_update": np.float64(-1.0)})
    assert not bool(is_keyframe(np.array([0.0, 0.0, 1e6, 1.0]), off))


def test_untracked_per_scan_run_keeps_gmappings_keyframes(sim):
    """With tracking off the per-scan step picks exactly the odometry keyframes of
    select_keyframes, and every scan's pose is its keyframe pose composed with the
    odometry since (the motion the filter was given)."""
    result = run_grid_slam(sim, "gmapping", particles=3, seed=0, progress=False, margin=3.0,
                           config={"tracking": False, "match_iterations": 4})
    np.testing.assert_array_equal(result.keyframes, select_keyframes(sim.odom_poses))
    owner = np.searchsorted(result.keyframes, np.arange(sim.num_scans), side="right") - 1
    anchors = result.keyframe_poses[owner]
    since = se2_between(sim.odom_poses[result.keyframes[owner]], sim.odom_poses)
    np.testing.assert_allclose(result.trajectory, se2_compose(anchors, since), atol=2e-4)


def test_scan_trajectory_composes_keyframe_poses_and_motion():
    flags = np.array([False, True, False, False, True])
    kf_poses = np.array([[1.0, 0.0, np.pi / 2], [1.0, 2.0, 3.0]])
    motions = np.array([[0.5, 0.0, 0.1], [0, 0, 0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.2], [0, 0, 0]])
    keyframes, trajectory = scan_trajectory(np.zeros(3), flags, kf_poses, motions)
    np.testing.assert_array_equal(keyframes, [0, 2, 5])
    expected = [np.zeros(3), [0.5, 0.0, 0.1], kf_poses[0], se2_compose(kf_poses[0], [0.0, 1.0, 0.0]),
                se2_compose(kf_poses[0], [1.0, 0.0, 0.2]), kf_poses[1]]
    np.testing.assert_allclose(trajectory, np.array(expected), atol=1e-12)


def test_each_filter_steps_every_scan_and_keeps_its_keyframe_update():
    """A grid filter's ``step`` is the per-scan step (:func:`per_scan` of its keyframe
    update), the one ``run_grid_slam`` runs; ``keyframe_step`` is that update alone."""
    from jaxslam.grid import gmapping

    for module in (gmapping, srupf):
        assert module.step.__wrapped__.__name__ == "scan_step"
        assert module.keyframe_step.__wrapped__ is module._step
        assert callable(module.run) and callable(module.keyframe_run)


def test_keyframe_correction_moves_only_along_constrained_directions(sim):
    """``constrain_matches``: the SRUPF-GM pose correction at a keyframe moves the
    position only along the directions the scan constrains (the tracking's
    :func:`constrained_shift`). With every direction declared flat the corrected pose
    keeps the predicted position and takes the matched heading; with none flat it is
    the unconstrained match, which did move the position (so the test can fail)."""
    from jaxslam.grid.filter import match_geometry, particle_reader

    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        # "posterior" starts the corrector at the predicted mean (no random draw).
        config = dataclasses.replace(config, sampling="posterior", matcher="ellipse")
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        wrong = true_step + np.array([0.03, -0.02, 0.04])

        @functools.partial(jax.jit, static_argnums=2)
        def correct(state, params, config):
            local_points, mask = match_geometry(scans[3], params, config)
            read = particle_reader(state, state.maps.tables[0], config)
            pose, sqrt_cov = state.poses[0], state.pose_sqrt_covs[0]
            mean = srupf.predict(pose, sqrt_cov, wrong, params).mean
            nu = srupf.particle_update(jax.random.PRNGKey(0), read, pose, sqrt_cov, wrong, local_points, mask,
                                       params, config)[0]
            return mean, nu

        mean, free = correct(state, params, config)
        assert np.hypot(*(np.asarray(free) - np.asarray(mean))[:2]) > 1e-3
        on = dataclasses.replace(config, constrain_matches=True)
        _, flat = correct(state, with_values(params, {"tracking.min_curvature": np.float64(1e9)}), on)
        np.testing.assert_allclose(np.asarray(flat)[:2], np.asarray(mean)[:2], atol=1e-12)
        np.testing.assert_allclose(float(flat[2]), float(free[2]), atol=1e-12)
        _, curved = correct(state, with_values(params, {"tracking.min_curvature": np.float64(-1e9)}), on)
        np.testing.assert_allclose(np.asarray(curved), np.asarray(free), atol=1e-9)


def test_gmapping_correction_moves_only_along_constrained_directions(sim):
    """``constrain_matches`` in the GMapping-style filter's correction
    (:func:`jaxslam.grid.gmapping.correct_pose`): the hill climb's position change is
    kept only along the directions the scan constrains. All directions flat: the
    proposal's position with the matched heading; none flat: the unconstrained match,
    which did move the position (so the test can fail). Off: GMapping's own
    correction, the unconstrained match."""
    from jaxslam.grid.filter import match_geometry, particle_reader
    from jaxslam.grid.gmapping import correct_pose

    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        config = dataclasses.replace(config, matcher="hill")
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        proposal = se2_compose(np.asarray(state.poses[0]), true_step + np.array([0.03, -0.02, 0.04]))

        @functools.partial(jax.jit, static_argnums=2)
        def correct(state, params, config):
            local_points, mask = match_geometry(scans[3], params, config)
            read = particle_reader(state, state.maps.tables[0], config)
            return correct_pose(read, proposal, state.pose_sqrt_covs[0], local_points, mask, params, config)

        off = dataclasses.replace(config, constrain_matches=False)
        free, score, _ = correct(state, params, off)
        assert float(score) > float(params.matcher.min_score)
        assert np.hypot(*(np.asarray(free) - proposal)[:2]) > 1e-3
        on = dataclasses.replace(config, constrain_matches=True)
        flat = correct(state, with_values(params, {"tracking.min_curvature": np.float64(1e9)}), on)[0]
        np.testing.assert_allclose(np.asarray(flat)[:2], proposal[:2], atol=1e-12)
        np.testing.assert_allclose(float(flat[2]), float(free[2]), atol=1e-12)
        curved = correct(state, with_values(params, {"tracking.min_curvature": np.float64(-1e9)}), on)[0]
        np.testing.assert_allclose(np.asarray(curved), np.asarray(free), atol=1e-9)
    # The defaults: on for SRUPF-GM, GMapping's own correction for the GMapping-style filter.
    layout = config.layout
    assert grid_algorithm("srupf-gm").make_config(2, layout, sim.num_beams, 4096).constrain_matches
    assert not grid_algorithm("gmapping").make_config(2, layout, sim.num_beams, 4096).constrain_matches
    # The loop-closure search likewise: SRUPF-GM's default, not the GMapping-style filter's.
    assert grid_algorithm("srupf-gm").make_config(2, layout, sim.num_beams, 4096).closure
    assert grid_algorithm("srupf-gm").config_default("closure")
    assert not grid_algorithm("gmapping").make_config(2, layout, sim.num_beams, 4096).closure
    assert not grid_algorithm("gmapping").config_default("closure")
    # The coarse-to-fine match: SRUPF-GM's default (four wide climbs), off for the others.
    assert grid_algorithm("srupf-gm").make_config(2, layout, sim.num_beams, 4096).coarse_iterations == 4
    srupf_gm = grid_algorithm("srupf-gm")
    assert srupf_gm.make_config(2, layout, sim.num_beams, 4096, coarse_iterations=0).coarse_iterations == 0
    assert grid_algorithm("gmapping").make_config(2, layout, sim.num_beams, 4096).coarse_iterations == 0
    assert grid_algorithm("srupf-gm-npc").make_config(2, layout, sim.num_beams, 4096).coarse_iterations == 0
    # The recovery from an odometry jump: SRUPF-GM's default (jaxslam.grid.algorithms),
    # off for the others.
    assert grid_algorithm("srupf-gm").make_config(2, layout, sim.num_beams, 4096).recover_radius == RECOVER_RADIUS > 0
    assert grid_algorithm("gmapping").make_config(2, layout, sim.num_beams, 4096).recover_radius == 0.0
    assert grid_algorithm("srupf-gm-npc").make_config(2, layout, sim.num_beams, 4096).recover_radius == 0.0


def test_keyframe_control_carries_the_tracked_noise_scale(sim):
    """The per-scan step hands the keyframe step the tracked motion with noise scale
    ``track_noise_scale`` (also after a refused match: the run is tracked), and 1, the
    odometry model's own noise, with tracking off."""
    from jaxslam.grid.filter import empty_info
    from jaxslam.grid.tracking import per_scan
    from jaxslam.grid.types import Odometry, noise_scale_of

    def recording_keyframe_step(key, state, control, observation, params, config):
        # Report the control's noise scale through the state's weights.
        scale = noise_scale_of(control, state.poses.dtype)
        return state._replace(log_weights=state.log_weights * 0 + scale), empty_info(state, config)

    step = jax.jit(per_scan(recording_keyframe_step), static_argnums=5)
    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        # tracking.refused_noise_scale off (negative) first: kappa after refused matches too.
        params = with_values(params, {"keyframes.linear_update": np.float64(0.0), "tracking.noise_scale": np.float64(0.25),
                                      "tracking.refused_noise_scale": np.float64(-1.0)})
        # The state's particles are at scan 0 with no motion tracked since.
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        control = Odometry(true_step, 1.0, 0.1)
        new, info = step(jax.random.PRNGKey(1), state, control, scans[3], params, config)
        assert bool(info.track_accepted)
        np.testing.assert_allclose(np.asarray(new.log_weights), 0.25, rtol=1e-12)
        junk = Scan(np.random.default_rng(0).permutation(np.asarray(scans[3].ranges)), scans[3].valid, 0.0)
        new, info = step(jax.random.PRNGKey(1), state, control, junk, params, config)
        assert not bool(info.track_accepted)
        np.testing.assert_allclose(np.asarray(new.log_weights), 0.25, rtol=1e-12)
        off = dataclasses.replace(config, tracking=False)
        new, _ = step(jax.random.PRNGKey(1), state, control, scans[3], params, off)
        np.testing.assert_allclose(np.asarray(new.log_weights), 1.0, rtol=1e-12)

        # tracking.refused_noise_scale (negative: off): that scale for a keyframe whose
        # interval holds a refused match, kappa otherwise. SRUPF-GM's default is 0.5,
        # the others' off.
        assert float(grid_algorithm("srupf-gm").make_params(sim.angles).tracking.refused_noise_scale) == 0.5
        assert float(grid_algorithm("gmapping").make_params(sim.angles).tracking.refused_noise_scale) < 0
        wide = with_values(params, {"tracking.refused_noise_scale": np.float64(1.0)})
        new, info = step(jax.random.PRNGKey(1), state, control, scans[3], wide, config)
        assert bool(info.track_accepted)
        np.testing.assert_allclose(np.asarray(new.log_weights), 0.25, rtol=1e-12)
        new, info = step(jax.random.PRNGKey(1), state, control, junk, wide, config)
        assert not bool(info.track_accepted)
        np.testing.assert_allclose(np.asarray(new.log_weights), 1.0, rtol=1e-12)
        # The count runs between keyframes: a refused scan that is not a keyframe ...
        never = with_values(wide, {"keyframes.linear_update": np.float64(1e9), "keyframes.angular_update": np.float64(1e9), "keyframes.temporal_update": np.float64(-1.0)})
        between, info = step(jax.random.PRNGKey(1), state, control, junk, never, config)
        assert not bool(info.track_accepted)
        np.testing.assert_allclose(np.asarray(between.since_keyframe)[3:], [1.0, 1.0])
        # ... widens the next keyframe's proposals although its own match is trusted,
        later = state._replace(since_keyframe=between.since_keyframe)
        new, info = step(jax.random.PRNGKey(1), later, control, scans[3], wide, config)
        assert bool(info.track_accepted)
        np.testing.assert_allclose(np.asarray(new.log_weights), 1.0, rtol=1e-12)
        # and the keyframe starts the count again.
        np.testing.assert_array_equal(np.asarray(new.since_keyframe), 0.0)
        new, _ = step(jax.random.PRNGKey(1), later, control, scans[3], params, config)
        np.testing.assert_allclose(np.asarray(new.log_weights), 0.25, rtol=1e-12)


def test_tracking_finds_a_turn_beyond_the_hill_climbs_reach(sim):
    """A turn the odometry missed by 0.15 rad: the hill climb from the guess alone
    stops in a worse optimum (0.025 rad or the whole miss left, in this scene); the
    guess turned by track_turn scores above that match, and the second climb from it
    finds the true heading. A small miss is found by the first climb, and the result is
    the plain match's."""
    track = jax.jit(_track, static_argnums=4)
    with jax.enable_x64(True):
        state, scans, params, default = state_and_scans(sim)
        config = dataclasses.replace(default, coarse_iterations=0)  # the hill climb alone, no coarse stage
        plain = with_values(params, {"tracking.turn": np.float64(0.0)})
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        for miss in (0.15, -0.15):
            wrong = true_step + np.array([0.0, 0.0, miss])
            # SRUPF-GM's default (the coarse stage before each climb) finds the turn too.
            moved, _, taken, *_ = track(state, wrong, scans[3], params, default)
            off = np.abs(se2_between(true_step[None], np.asarray(moved)[None])[0])
            assert default.coarse_iterations > 0 and bool(taken) and off[2] < 0.005, (miss, off)
            motion, score, accepted, *_ = track(state, wrong, scans[3], params, config)
            motion0, score0, *_ = track(state, wrong, scans[3], plain, config)
            error = np.abs(se2_between(true_step[None], np.asarray(motion)[None])[0])
            error0 = np.abs(se2_between(true_step[None], np.asarray(motion0)[None])[0])
            assert bool(accepted) and error[2] < 0.005 and np.hypot(*error[:2]) < 0.02, (miss, error)
            assert error0[2] > 0.02 and float(score0) < float(score) - 0.05, (miss, error0, score0, score)
        small = true_step + np.array([0.0, 0.0, 0.05])
        got = track(state, small, scans[3], params, config)
        got0 = track(state, small, scans[3], plain, config)
        np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(got0[0]))


def test_tracking_recovers_from_an_odometry_glitch(sim):
    """An increment 0.8 m off sideways (an odometry that jumped; the perturbed campus's
    reference has twelve such steps): the match from its guess is refused. With the
    recovery (config.recover_radius, SRUPF-GM's default, jaxslam.grid.recovery) the search around the guess
    finds the scan's pose and the tracked motion is the true one within a few
    centimetres; without it the odometry's jump is kept exactly. A scan that fits
    nowhere stays refused with the recovery too: no jump."""
    track = jax.jit(_track, static_argnums=4)
    with jax.enable_x64(True):
        state, scans, params, config = state_and_scans(sim)
        assert config.recover_radius == RECOVER_RADIUS  # SRUPF-GM's default
        off = dataclasses.replace(config, recover_radius=0.0)
        true_step = se2_between(sim.true_poses[0][None], sim.true_poses[3][None])[0]
        glitch = true_step + np.array([0.0, 0.8, 0.03])
        motion, score, accepted, *_ = track(state, glitch, scans[3], params, off)
        assert not bool(accepted)
        np.testing.assert_allclose(np.asarray(motion), glitch, atol=1e-12)
        motion, score, accepted, *_ = track(state, glitch, scans[3], params, config)
        error = np.abs(se2_between(true_step[None], np.asarray(motion)[None])[0])
        assert bool(accepted) and np.hypot(*error[:2]) < 0.05 and error[2] < 0.01, (error, float(score))

        rng = np.random.default_rng(0)
        junk = Scan(rng.permutation(np.asarray(scans[3].ranges)), scans[3].valid, 0.0)
        motion, score, accepted, *_ = track(state, glitch, junk, params, config)
        assert not bool(accepted)
        np.testing.assert_allclose(np.asarray(motion), glitch, atol=1e-12)

        # The same 0.8 m sideways, but gathered before this scan (the state's motion
        # since the keyframe) while this scan's increment is a wheeled base's: the
        # odometry did not jump here, and the refused match keeps it, as for a scan
        # of new ground (the test can fail: the search would find the pose).
        assert float(slip(true_step)) < RECOVER_SLIP < float(slip(glitch))
        drifted = state._replace(motion=np.array([0.0, 0.8, 0.03]))
        motion, score, accepted, *_ = track(drifted, true_step, scans[3], params, config)
        assert not bool(accepted)
        np.testing.assert_allclose(np.asarray(motion), se2_compose(drifted.motion, true_step), atol=1e-12)


@settings(max_examples=50)
@given(st.floats(-2.0, 2.0), st.floats(-1.5, 1.5))
def test_slip_of_an_arc_is_zero_and_of_a_sideways_step_is_the_step(length, turn):
    """A wheeled base driving an arc (length ``length``, turning by ``turn``) ends
    at ``(r sin t, r (1 - cos t), t)`` with ``r = length / t``: no slip. The same
    motion with 0.4 m added sideways (robot frame of the start) slips 0.4 m."""
    assume(turn == 0.0 or abs(turn) > 1e-6)  # r = length / turn stays finite
    if turn == 0.0:
        arc = np.array([length, 0.0, turn])
    else:
        r = length / turn
        arc = np.array([r * np.sin(turn), r * 2.0 * np.sin(0.5 * turn) ** 2, turn])  # 1 - cos t = 2 sin^2(t/2)
    with jax.enable_x64(True):
        assert float(slip(arc)) < 1e-9 and not bool(jumped(arc))
        assert float(slip(arc + np.array([0.0, 0.4, 0.0]))) == pytest.approx(0.4, abs=1e-9)


def test_a_jump_slips_far_and_for_its_length():
    """The campus's reference jump at scan 238 (0.08 m ahead, 1.00 m sideways, 13.3
    deg) jumped; a long step of a fast robot that turns on the way (3 m, 0.55 m
    sideways beyond its arc: Orebro's kind) slips more than RECOVER_SLIP but not for
    its length; 0.2 m sideways on a short step is under RECOVER_SLIP."""
    with jax.enable_x64(True):
        assert bool(jumped(np.array([0.08, -1.00, np.radians(13.3)])))
        long_step = np.array([3.0, 0.55, 0.0])
        assert float(slip(long_step)) > RECOVER_SLIP and not bool(jumped(long_step))
        assert not bool(jumped(np.array([0.3, 0.2, 0.0])))
