"""What a run compiles, counted with :class:`jaxslam.runtime.cache.CompileCounter`: a
checkpointed, a resumed and a live-viewed run of a plain run's configuration compile
nothing new, and a particle sweep compiles the filter once per particle count."""

from __future__ import annotations

import pytest

from jaxslam.app import runs
from jaxslam.runtime.cache import CompileCounter

# A simulated laser log, 24 keyframes (93 scans) in chunks of 32 scans: checkpoints
# every 8 scans end chunks early, the resume starts in the middle of one.
COMMON = dict(algorithm="srupf-gm", particles=4, max_steps=24, progress=False, plots=False,
              keyframes={"linear": 0.4}, chunk=32)


def _same_result(a, b):
    assert (a / "trajectory.tum").read_text() == (b / "trajectory.tum").read_text()
    assert (a / "map.pgm").read_bytes() == (b / "map.pgm").read_bytes()


@pytest.mark.long
def test_checkpointed_resumed_and_live_runs_compile_nothing_the_plain_run_did_not(tmp_path, monkeypatch):
    from jaxslam.runtime import checkpoint as ckpt

    runs.run(out=tmp_path / "plain", **COMMON)
    original_save = ckpt.Checkpoint.save

    def save_then_crash(self, carry, done, leaves):
        original_save(self, carry, done, leaves)
        if done >= 40:
            raise KeyboardInterrupt

    with CompileCounter() as counter:
        runs.run(out=tmp_path / "checkpointed", checkpoint_every=8, **COMMON)
        monkeypatch.setattr(ckpt.Checkpoint, "save", save_then_crash)
        with pytest.raises(KeyboardInterrupt):
            runs.run(out=tmp_path / "interrupted", checkpoint_every=8, **COMMON)
        monkeypatch.setattr(ckpt.Checkpoint, "save", original_save)
        resumed = runs.run(out=tmp_path / "interrupted", resume=True, **COMMON)
    assert counter.requests == 0, counter.as_dict()
    assert resumed["resumed"] is True
    _same_result(tmp_path / "checkpointed", tmp_path / "plain")
    _same_result(tmp_path / "interrupted", tmp_path / "plain")

    try:
        import rerun  # noqa: F401
    except ImportError:
        return  # the live view needs the viz extra
    with CompileCounter() as counter:
        runs.run(out=tmp_path / "live", rerun=tmp_path / "live.rrd", **COMMON)
    assert counter.requests == 0, counter.as_dict()
    _same_result(tmp_path / "live", tmp_path / "plain")


@pytest.mark.long
def test_a_particle_sweep_compiles_init_and_the_chunk_runner_once_per_count(tmp_path):
    """The particle count shapes every array of the filter, so each count is one
    ``init`` and one chunk runner (the per-run host work compiles nothing after the
    first run); a count seen before compiles nothing."""
    counts = []
    for particles in (2, 3, 5, 3):
        with CompileCounter() as counter:
            runs.run(out=tmp_path / f"p{particles}_{len(counts)}", **{**COMMON, "particles": particles})
        counts.append(counter.requests)
    assert counts[0] >= 2 and counts[1:] == [2, 2, 0], counts


@pytest.mark.long
def test_the_usable_range_is_traced_two_range_limits_share_one_program():
    """``usable_range`` is a traced parameter: a second range limit under the same
    static bounds (the write window, ``window_range``, and the ray budget,
    ``max_points``, both fixed here) compiles nothing and still changes the result."""
    import numpy as np

    from jaxslam.datasets.laser_sim import simulate
    from jaxslam.grid.experiment import run_grid_slam

    log = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.3, num_beams=91, seed=2)
    options = dict(particles=3, progress=False, max_keyframes=12, config={"max_points": 16384, "window_range": 20.0})
    near = run_grid_slam(log, params={"sensor.usable_range": 4.0}, **options)
    with CompileCounter() as counter:
        far = run_grid_slam(log, params={"sensor.usable_range": 6.0}, **options)
    assert counter.requests == 0, counter.as_dict()
    assert near.config == far.config
    assert not np.array_equal(near.map_log_odds, far.map_log_odds)
