"""What the grid filters add to the shared driver: the summary of a step, and map growth.

* The filters' ``run`` is :func:`jaxslam.runtime.driver.scan_runner` of their ``step``, the
  driver shared with the landmark filter (one key per keyframe from
  :func:`jaxslam.runtime.driver.step_keys`, the one way step keys are derived; the host loop
  makes the same bits with :func:`jaxslam.runtime.keys.split_keys`).
* :func:`run_filter` — the host loop used by :func:`jaxslam.grid.experiment.run_grid_slam`,
  the CLI, the notebooks and the benchmarks: ``init`` (jitted), then the steps through
  the shared chunk runner (:func:`jaxslam.runtime.driver.chunk_runner` of the step,
  keeping :func:`summarise` of each, compiled with jaxslam's XLA options) and its host
  loop with a progress bar (:func:`jaxslam.runtime.progress.run_scan_chunked`).
  The chunk runner is cached per (filter, static config), so a sweep over
  ``Params`` or a second run with the same shapes never recompiles. When a step
  is refused because the paged maps are full (:mod:`jaxslam.grid.paged`), the
  page table moves or the layout grows on the host and the run continues from that
  step: one extra compilation per growth (none for a move), counted in
  :class:`RunStats`, and the same result as a run that started with the larger layout.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.compiler import jit_with, options_key
from jaxslam.runtime.driver import chunk_runner
from jaxslam.runtime.executables import compile_runner, runner_tag
from jaxslam.grid.filter import init, reset_status
from jaxslam.grid.paged import PagedLayout, grow
from jaxslam.grid.types import GridSlamConfig
from jaxslam.runtime.keys import split_keys
from jaxslam.runtime.progress import log, run_scan_chunked


DEFAULT_CHUNK = 256
"""Scans per compiled chunk of a run. Each chunk is one call of the compiled program
and one wait for its result, with the cores idle in between (about 1 ms of host work
per chunk, more when the machine is loaded), so fewer, longer chunks waste less; the
result is the same bit for bit for any chunk length. At 256 scans a chunk of a
30-particle run takes a fraction of a second, so the progress bar still moves a few
times a second."""


def summarise(info) -> dict[str, Any]:
    """What a run keeps of each step's ``Info`` (poses and ancestors for the path)."""
    return {
        "poses": info.poses,
        "ancestors": info.ancestors,
        "ess": info.ess,
        "resampled": info.resampled,
        "mean_score": jnp.mean(info.scores),
        "best_score": jnp.max(info.scores),
        "dropped_points": info.dropped_points,
        "pd_ok_fraction": jnp.mean(info.pd_ok.astype(jnp.float32)),
        "status": info.status,
        "keyframe": info.keyframe,
        "motion": info.motion,
        "track_score": info.track_score,
        "track_accepted": info.track_accepted,
        "track_closed": info.track_closed,
        "track_conflict": info.track_conflict,
        "track_undo": info.track_undo,
        "track_search": info.track_search,
    }


@dataclass
class RunStats:
    """How the maps grew during a run, its times, and the XLA options its programs
    were compiled with (:mod:`jaxslam.runtime.compiler`)."""

    growths: list[dict[str, Any]] = field(default_factory=list)
    compile_s: float = 0.0
    wall_s: float = 0.0
    compiler_options: dict[str, Any] = field(default_factory=dict)

    @property
    def recompilations(self) -> int:
        return recompilations(self.growths)


def recompilations(growths: list[dict[str, Any]]) -> int:
    """Growths that changed the layout and so recompiled (a moved page table keeps the
    program; each growth's ``recompiled`` says which)."""
    return sum(1 for g in growths if g["recompiled"])


def layout_json(layout: PagedLayout) -> dict[str, Any]:
    return dataclasses.asdict(layout)


def _grown(state, layout: PagedLayout, stats: RunStats, step: int, progress: bool):
    status = jax.tree_util.tree_map(np.asarray, state.status)
    maps, new_layout = grow(state.maps, layout, status)
    recompiled = new_layout != layout
    what = "pool" if int(status.code) == 1 else "page table" if recompiled else "page table moved"
    stats.growths.append(
        {"step": int(step), "grew": what, "recompiled": recompiled, "slots": new_layout.slots,
         "table": [new_layout.table_width, new_layout.table_height],
         "corner": [int(c) for c in np.asarray(maps.corner)]}
    )
    verb = "grown" if recompiled else "moved (no recompilation)"
    log(f"  maps: {what} {verb} at step {step} (pool {new_layout.slots} tiles, "
        f"table {new_layout.table_width} x {new_layout.table_height})" + ("; recompiling" if recompiled else ""),
        progress)
    return reset_status(state._replace(maps=maps)), new_layout


@functools.lru_cache(maxsize=32)
def _init_runner(config: GridSlamConfig, compiler_options: tuple):
    jitted = jit_with(lambda key, params, scan, pose: init(key, params, config, scan, pose), dict(compiler_options))
    jitted.jaxslam_tag = runner_tag(init, config, None, donate=False, kind="init")
    return jitted


def _init(key, params, config: GridSlamConfig, first_scan, initial_pose):
    """``init``, its lowered program kept on disk like the chunk runner's
    (:mod:`jaxslam.runtime.executables`): a warm run does not trace it."""
    args = (key, params, first_scan, initial_pose)
    runner = _init_runner(config, options_key())
    return compile_runner(runner, *args)[0](*args)


def init_state(key, params, config: GridSlamConfig, first_scan, initial_pose, stats: RunStats, progress=False,
               start=None):
    """``init`` with the layout grown until the first scan fits: ``(state, config)``.

    ``start``: one particle's maps to start from (a saved map,
    :func:`jaxslam.grid.startmap.paged_start`); they grow with the layout."""
    if start is not None:
        while True:
            state = init(key, params, config, first_scan, initial_pose, start)
            if int(state.status.code) == 0:
                return state, config
            grown, layout = _grown(state._replace(maps=start), config.layout, stats, 0, progress)
            start = grown.maps
            config = dataclasses.replace(config, layout=layout)
    while True:
        state = _init(key, params, config, first_scan, initial_pose)
        if int(state.status.code) == 0:
            return state, config
        state, layout = _grown(state, config.layout, stats, 0, progress)
        if layout == config.layout:  # moved: init makes its maps at the layout's corner, so start there
            corner = np.asarray(state.maps.corner)
            layout = dataclasses.replace(layout, table_x0=int(corner[0]), table_y0=int(corner[1]))
        config = dataclasses.replace(config, layout=layout)


def run_filter(
    step_fn,
    key,
    params,
    config: GridSlamConfig,
    first_scan,
    initial_pose,
    controls,
    observations,
    *,
    chunk: int = DEFAULT_CHUNK,
    desc: str = "filter",
    progress: bool = True,
    checkpoint=None,
    unit: str = "keyframe",
    start=None,
):
    """Run a grid filter over steps 1..T (keyframes, or every scan with a per-scan
    step; step 0 is ``first_scan``).

    The positional arguments are the filter's (its ``step``, key, params, config and
    inputs, as for ``init`` and ``run``); the keywords are the host loop's
    (:func:`jaxslam.runtime.progress.run_scan_chunked`), passed on.

    Returns:
        ``(state, ys, config, stats)``: the final state, the stacked
        :func:`summarise` outputs of every step, the config with the final layout
        and :class:`RunStats` (timings, growths).
    """
    stats = RunStats()
    steps = observations.ranges.shape[0]
    keys = split_keys(key, steps)  # jaxslam.runtime.driver.step_keys's bits, made on the host (jaxslam.runtime.keys)
    init_key = key  # init is deterministic; it takes the key only for the protocol
    xs = (keys, controls, observations)
    if checkpoint is not None and checkpoint.resume and checkpoint.path.exists():
        saved = checkpoint.saved_static().get("layout")
        if saved is not None:
            config = dataclasses.replace(config, layout=PagedLayout(**saved))
        template = jax.eval_shape(lambda: init(init_key, params, config, first_scan, initial_pose))
        # NumPy zeros: jnp.zeros would be a small program per leaf that a plain run never compiles
        state = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype), template)
    else:
        state, config = init_state(init_key, params, config, first_scan, initial_pose, stats, progress, start)
    start, prior = 0, None
    while True:
        if checkpoint is not None:
            checkpoint.static = {"layout": layout_json(config.layout)}
        runner = chunk_runner(step_fn, config, summarise, options_key())
        stats.compiler_options = dict(runner.jaxslam_compiler_options)  # what the run was compiled with
        (state, params), ys, timing = run_scan_chunked(
            runner, (state, params), xs, chunk=chunk, desc=desc, unit=unit, progress=progress,
            checkpoint=checkpoint, start=start,
            stop=lambda carry: int(carry[0].status.code) != 0, prior=prior,
        )
        if checkpoint is not None:
            checkpoint.resume = False
        stats.compile_s += timing.compile_s
        stats.wall_s += timing.wall_s
        codes = np.asarray(ys["status"])
        failed = np.flatnonzero(codes != 0)
        if failed.size == 0:
            return state, ys, config, stats
        start = int(failed[0])
        prior = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[:start], ys)
        state, layout = _grown(state, config.layout, stats, start, progress)
        config = dataclasses.replace(config, layout=layout)


__all__ = [
    "DEFAULT_CHUNK",
    "RunStats",
    "init_state",
    "layout_json",
    "recompilations",
    "run_filter",
    "summarise",
]
