"""Run a filter's chunk runner over a log, with a progress bar driven from the host.

A whole run as one ``lax.scan`` is the fastest, but gives no feedback. Here the time
axis is cut into chunks of equal length; one chunk is one call of the jitted chunk
runner (:func:`jaxslam.runtime.driver.chunk_runner`), compiled once (a chunk that
ends before its length, the last one or one that ends at a checkpoint, is padded and
its loop stops before the padding, so it does not recompile). Between chunks the host updates a progress bar with scans per second and
ETA, and may call a callback (checkpointing). Compilation is done ahead of the first
chunk and timed apart.

The chunk length depends only on ``chunk`` and the length of the log (``min(chunk,
T)``), never on where a resumed run starts or how often it checkpoints: a plain run,
a checkpointed one, a resumed one and a live view of the same log run one compiled
program (``tests/test_progress.py``, ``tests/test_compile_counts.py``).

The carry is donated to each chunk: large per-particle buffers (grids) are updated
in place.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.executables import compile_runner


@dataclass(frozen=True)
class Timing:
    """Wall-clock split of a chunked run."""

    compile_s: float
    wall_s: float
    steps: int

    @property
    def steps_per_s(self) -> float:
        return self.steps / self.wall_s if self.wall_s > 0 else float("inf")


def _host(leaf):
    """``leaf`` as a NumPy array, so that slicing and padding it in the host loop runs no
    JAX program (each eager op is a program to compile or load); typed PRNG key arrays,
    which NumPy cannot hold, stay JAX arrays."""
    if isinstance(leaf, jax.Array) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        return leaf
    return np.asarray(leaf)


def _tree_pad(xs, length: int, total: int):
    """Pad every leaf of ``xs`` along axis 0 from ``length`` to ``total`` (repeat last)."""
    if total == length:
        return xs

    def pad(leaf):
        lib = np if isinstance(leaf, np.ndarray) else jnp
        extra = lib.repeat(leaf[-1:], total - length, axis=0)
        return lib.concatenate([leaf, extra], axis=0)

    return jax.tree_util.tree_map(pad, xs)


class ProgressBar:
    """A minimal-dependency wrapper over ``tqdm`` that reports scans/s and ETA."""

    def __init__(self, total: int, desc: str, unit: str, enabled: bool, initial: int = 0):
        self.enabled = enabled
        self._bar = None
        if enabled:
            from tqdm.auto import tqdm

            self._bar = tqdm(
                total=total,
                initial=initial,
                desc=desc,
                unit=unit,
                file=sys.stderr,
                dynamic_ncols=True,
                smoothing=0.1,
            )

    def update(self, n: int) -> None:
        if self._bar is not None:
            self._bar.update(n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def log(message: str, enabled: bool = True) -> None:
    """One status line on stderr (used for the compilation notice)."""
    if enabled:
        print(message, file=sys.stderr, flush=True)


def run_scan_chunked(
    runner,
    carry: Any,
    xs: Any,
    *,
    chunk: int = 256,
    desc: str = "filter",
    unit: str = "scan",
    progress: bool = True,
    start: int = 0,
    callback: Callable[[Any, int], None] | None = None,
    callback_every: int | None = None,
    checkpoint=None,
    stop: Callable[[Any], bool] | None = None,
    prior: Any = None,
):
    """Run ``runner`` over ``xs`` (leading axis = time), chunk by chunk.

    The keyword arguments are the loop's options, each independent of the others;
    together they are one call's description of a run, not a group that travels on.

    Args:
        runner: a chunk runner, :func:`jaxslam.runtime.driver.chunk_runner` of a
            filter's step (its compiled program is kept per argument shapes, so a
            sweep compiles once).
        carry: initial carry ``(state, params)``, donated to the first chunk.
        xs: ``(keys, controls, observations)``, arrays with a common leading time
            axis ``T``.
        chunk: steps per compiled chunk (static; ``min(chunk, T)``); the progress bar
            updates per chunk.
        desc, unit: progress-bar labels.
        progress: show the bar and the compilation line.
        start: first time index to run (to resume a run); steps before it are skipped.
        callback: called on the host as ``callback(carry, steps_done)`` after every
            chunk (e.g. to checkpoint). It must not keep references to donated
            buffers beyond the call (copy to host first).
        callback_every: end a chunk every that many steps as well, so that ``callback``
            sees the run that often (a live view) with the same compiled chunk.
        checkpoint: a :class:`jaxslam.runtime.checkpoint.Checkpoint`. With ``resume`` its file
            (carry, outputs so far, position) replaces ``carry`` and ``start``; with
            ``every`` the state is saved atomically every ``every`` steps (a chunk ends
            there, its remaining steps skipped: the same program). A resumed run's
            ``ys`` cover all steps from 0 and equal those of an uninterrupted run.
        stop: ``stop(carry) -> bool`` checked after every chunk; when true the run
            ends there (no checkpoint is written for that chunk) and ``ys`` cover the
            steps run so far. The caller finds where to continue from.
        prior: outputs (a ``ys`` pytree) of steps ``0..start-1`` from an earlier call,
            prepended to the returned ``ys`` and to the outputs a checkpoint saves.

    Returns:
        ``(carry, ys, timing)`` with ``ys`` stacked over the steps ``start..T-1``
        (from 0 when resuming from a checkpoint).
    """
    prior_leaves: list | None = None
    prior_from = "prior"
    if prior is not None:
        prior_leaves = [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(prior)]
    if checkpoint is not None and checkpoint.resume:
        carry, start, prior_leaves = checkpoint.load(carry)
        prior_from = str(checkpoint.path)
        log(f"{desc}: resumed from {checkpoint.path} at step {start}", progress)
    leaves = jax.tree_util.tree_leaves(xs)
    if not leaves:
        raise ValueError("xs has no arrays to scan over")
    total = int(np.shape(leaves[0])[0])
    if not 0 <= start <= total:
        raise ValueError(f"start={start} outside 0..{total}")
    xs_all = xs
    remaining = total - start
    # The program's length: the same for every start and checkpoint interval (see above).
    chunk = max(1, min(chunk, total))

    if remaining == 0:
        ys = None
        if prior_leaves is not None:
            # shapes only, of host slices: no program of its own for a finished run
            last = jax.tree_util.tree_map(lambda leaf: _host(leaf)[-1:], xs_all)
            shapes = jax.eval_shape(runner, carry, last, np.ones((1,), bool))[1]
            _check_prior(prior_leaves, shapes, prior_from)
            ys = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(shapes), prior_leaves)
        return carry, ys, Timing(0.0, 0.0, 0)

    # On the host, padded by one chunk (the last step repeated) so that a chunk may
    # start at any step: it ends at the log's end or at the next checkpoint.
    xs = _tree_pad(jax.tree_util.tree_map(_host, xs), total, total + chunk)
    until_save = getattr(checkpoint, "steps_to_save", None)

    def chunk_inputs(at: int):
        steps = min(chunk, total - at)
        if until_save is not None:
            steps = min(steps, until_save(at) or steps)
        if callback_every:
            steps = min(steps, callback_every - at % callback_every)
        sl = slice(at, at + chunk)
        return jax.tree_util.tree_map(lambda leaf: leaf[sl], xs), np.arange(chunk) < steps, steps

    xs0, valid0, steps0 = chunk_inputs(start)
    log(f"{desc}: compiling (one time) ...", progress)
    t0 = time.perf_counter()
    compiled, loaded = compile_runner(runner, carry, xs0, valid0)
    compile_s = time.perf_counter() - t0
    log(f"{desc}: {'loaded' if loaded else 'compiled'} in {compile_s:.1f} s", progress)

    bar = ProgressBar(total, desc, unit, progress, initial=start)
    outputs = []
    t0 = time.perf_counter()
    done = start
    try:
        while done < total:
            xs_i, valid_i, n_valid = (xs0, valid0, steps0) if done == start else chunk_inputs(done)
            carry, ys = compiled(carry, xs_i, valid_i)
            jax.block_until_ready(carry)
            if done == start and prior_leaves is not None:
                _check_prior(prior_leaves, ys, prior_from)
            done += n_valid
            outputs.append((ys, n_valid))
            bar.update(n_valid)
            if stop is not None and stop(carry):
                break
            if checkpoint is not None and (checkpoint.due(done) or (checkpoint.every and done == total)):
                leaves = jax.tree_util.tree_leaves(_stack(outputs))
                if prior_leaves is not None:
                    leaves = [np.concatenate([p, np.asarray(c)], 0) for p, c in zip(prior_leaves, leaves)]
                checkpoint.save(carry, done, leaves)
            if callback is not None:
                callback(carry, done)
    finally:
        bar.close()
    wall_s = time.perf_counter() - t0
    ys = _stack(outputs)
    if prior_leaves is not None:
        treedef = jax.tree_util.tree_structure(ys)
        leaves = [jax.device_put(np.concatenate([p, np.asarray(c)], 0))
                  for p, c in zip(prior_leaves, jax.tree_util.tree_leaves(ys))]
        ys = jax.tree_util.tree_unflatten(treedef, leaves)
    return carry, ys, Timing(compile_s, wall_s, done - start)


def _check_prior(prior_leaves: list, ys, where: str) -> None:
    """The outputs of the steps before (a checkpoint's, or ``prior``) must be this
    run's outputs, array for array: a checkpoint written by another version of a
    filter (an output added or removed) is refused rather than joined wrongly."""
    from jaxslam.runtime.checkpoint import CheckpointError

    leaves = jax.tree_util.tree_leaves(ys)
    same = len(leaves) == len(prior_leaves) and all(
        np.shape(p)[1:] == tuple(c.shape)[1:] and np.asarray(p).dtype == np.dtype(c.dtype)
        for p, c in zip(prior_leaves, leaves))
    if not same:
        raise CheckpointError(
            f"{where}: its saved outputs ({len(prior_leaves)} arrays) are not this run's ({len(leaves)} arrays, "
            "per step shapes and dtypes): it was written by another filter or version; start the run again")


def _stack(outputs):
    """Concatenate per-chunk outputs ``(ys, steps run)`` without their padding steps (on
    the host: no JAX program per output leaf; the result is a JAX array as before)."""
    counts = [steps for _ys, steps in outputs]
    return jax.tree_util.tree_map(
        lambda *parts: jax.device_put(np.concatenate([np.asarray(part)[:n] for part, n in zip(parts, counts)], 0)),
        *[ys for ys, _steps in outputs])

