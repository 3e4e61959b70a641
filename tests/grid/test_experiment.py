"""run_grid_slam end to end: simulated log, and a short real CARMEN log."""

import numpy as np
import pytest

from jaxslam.datasets.laser_sim import simulate
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.grid.experiment import run_grid_slam


@pytest.mark.long
def test_run_grid_slam_on_simulation():
    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
    result = run_grid_slam(log, "srupf-gm", particles=4, seed=0, progress=False, linear_update=0.5,
                           angular_update=0.3, margin=3.0, config={"match_iterations": 6})
    s = log.num_scans
    assert result.trajectory.shape == (s, 3) and result.scan_times.shape == (s,)
    # keyframes keep their corrected pose exactly in the per-scan trajectory
    np.testing.assert_allclose(result.trajectory[result.keyframes], result.keyframe_poses, atol=1e-9)
    err = np.hypot(*(result.trajectory[:, :2] - log.true_poses[:, :2]).T)
    assert err.mean() < 0.1
    h, w = result.map_log_odds.shape
    tile = result.config.layout.tile
    assert h % tile == 0 and w % tile == 0 and h * w <= result.config.layout.table_size * tile * tile
    assert result.map_log_odds.dtype == np.float32 and (result.map_log_odds > 0).any()
    summary = result.summary()
    for key in ("algorithm", "dataset", "particles", "seed", "scans", "keyframes", "wall_s", "compile_s",
                "resamplings"):
        assert key in summary
    assert summary["keyframes"] == len(result.keyframes) and summary["scans"] == s
    assert set(result.info) >= {"ess", "resampled", "mean_score", "dropped_points"}
    assert result.info["ess"].shape == (len(result.keyframes) - 1,)


def test_short_real_log_run():
    """A few keyframes of the raw Intel log (skipped when the data is not staged)."""
    try:
        result = run_grid_slam("intel", "gmapping", particles=4, seed=0, progress=False, max_keyframes=12)
    except DatasetNotFoundError:
        pytest.skip("intel log not available")
    from jaxslam.datasets.carmen import select_keyframes
    from jaxslam.datasets.registry import load_dataset_log

    # The log is cut where GMapping's odometry rule reaches 12 keyframes; the filter's
    # own keyframes follow the tracked motion, so their count is close to 12.
    cut = int(select_keyframes(load_dataset_log("intel").odom_poses)[11]) + 1
    assert result.trajectory.shape == (cut, 3) and result.scan_times.shape == (cut,)
    assert np.all(np.isfinite(result.trajectory))
    assert 9 <= result.summary()["keyframes"] <= 15
    assert int(result.info["dropped_points"].max()) == 0
    # the filter stays near odometry over the first metres (a gross failure would not)
    assert np.abs(result.keyframe_poses[:, :2]).max() < 5.0


def test_grid_programs_compiled_with_jaxslam_options_equal_xla_defaults(monkeypatch):
    """The grid programs are compiled with jaxslam's XLA options (jaxslam.runtime.compiler) and
    compute bit for bit what XLA's defaults compute: the run of the test above (its
    compiled program reused here) against the same run with JAXSLAM_XLA_OPTIONS=xla."""
    from jaxslam.runtime import compiler
    from jaxslam.runtime.driver import chunk_runner
    from jaxslam.grid import driver, gmapping

    monkeypatch.delenv(compiler.ENV_VAR, raising=False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    try:
        ours = run_grid_slam("intel", "gmapping", particles=4, seed=0, progress=False, max_keyframes=12)
    except DatasetNotFoundError:
        pytest.skip("intel log not available")
    runner = chunk_runner(gmapping.step, ours.config, driver.summarise, compiler.options_key())
    assert runner.jaxslam_compiler_options == compiler.OPTIONS
    assert ours.summary()["xla_compiler_options"] == compiler.OPTIONS
    monkeypatch.setenv(compiler.ENV_VAR, "xla")
    xla = run_grid_slam("intel", "gmapping", particles=4, seed=0, progress=False, max_keyframes=12)
    assert xla.summary()["xla_compiler_options"] == {}
    assert xla.compile_s > 0  # compiled anew, not the program of the first run
    np.testing.assert_array_equal(ours.trajectory, xla.trajectory)
    np.testing.assert_array_equal(ours.map_log_odds, xla.map_log_odds)
    np.testing.assert_array_equal(ours.info["ess"], xla.info["ess"])


@pytest.mark.long
def test_full_intel_float32_run_ends_without_nan():
    """The whole Intel log (911 keyframes) in float32: nothing in the final state is NaN."""
    import jax

    try:
        res = run_grid_slam("intel", algorithm="srupf-gm", particles=5, seed=0, progress=False)
    except DatasetNotFoundError as err:
        pytest.skip(str(err))
    assert res.keyframes.shape[0] > 900
    for leaf in jax.tree_util.tree_leaves(res.state):
        leaf = np.asarray(leaf)
        if np.issubdtype(leaf.dtype, np.floating):
            assert leaf.dtype == np.float32
            assert np.all(np.isfinite(leaf))
    assert np.all(np.isfinite(res.trajectory))
    assert np.all(np.isfinite(res.map_log_odds))


def _window_relations_error(result, relations):
    """Relations metric on the scans up to the last keyframe processed."""
    from jaxslam.metrics.relations import relations_metric

    end = int(result.keyframes[-1]) + 1
    return relations_metric(relations, result.scan_times[:end], result.trajectory[:end])


@pytest.mark.slow
def test_fr079_unseen_rotations_are_tracked_with_the_defaults():
    """FR079's odometry misses the robot's turns in doorways (scans 783-834: the scans
    turn by +24 and then -17 deg where the odometry says -18 and -3). With the defaults
    every scan is tracked against the best map, so the keyframe rule and the
    proposals see those turns; without tracking (GMapping's odometry rule) the unseen
    rotation piles up between keyframes and the heading is lost there."""
    from jaxslam.datasets.carmen import select_keyframes
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.metrics.relations import load_dataset_relations

    try:
        log = load_dataset_log("fr079")
        relations = load_dataset_relations("fr079")
    except DatasetNotFoundError as err:
        pytest.skip(str(err))
    from jaxslam.grid.experiment import keyframe_rule

    rule = keyframe_rule(algorithm="srupf-gm")

    # scans 0..999 (two doorway episodes), cut as run_grid_slam cuts: by the run's rule on the odometry
    count = int(np.sum(select_keyframes(log.odom_poses, *rule, times=log.scan_times) < 1000))
    tracked = run_grid_slam(log, "srupf-gm", particles=8, seed=0, progress=False, max_keyframes=count)
    assert tracked.summary()["keyframe_rule"] == dict(zip(("linear_m", "angular_rad", "temporal_s"), rule))
    good = _window_relations_error(tracked, relations)
    assert good["n_relations"] > 150
    assert good["trans_err_mean_m"] < 0.08 and good["rot_err_mean_deg"] < 1.2, good

    blind = run_grid_slam(log, "srupf-gm", particles=8, seed=0, progress=False, max_keyframes=count,
                          config={"tracking": False})
    bad = _window_relations_error(blind, relations)
    assert bad["rot_err_mean_deg"] > 3 * good["rot_err_mean_deg"], (good, bad)
