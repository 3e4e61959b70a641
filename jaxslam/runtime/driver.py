r"""The filter protocol that the landmark and the grid filters share, and its driver.

Every filter module (:mod:`jaxslam.feature.filter`, :mod:`jaxslam.grid.gmapping`,
:mod:`jaxslam.grid.srupf`) offers

* ``init(key, params, config, ...) -> State``, jitted with a static ``config``. The
  initial state is deterministic: ``key`` is accepted for the common signature and
  not used (an ``init`` that ever draws must use ``fold_in(key, ...)``, not the
  step keys below).
* ``step(key, state, control, observation, params, config) -> (State, Info)``, a
  pure function traced inside ``run`` and the chunk runners (the landmark ``step`` is
  also jitted on its own, for direct calls; the grid ``step`` is not);
  ``Info`` always has ``ess`` (before resampling), ``resampled`` and ``ancestors``
  ``(N,)`` (the identity when it did not resample).
* ``run(key, state, controls, observations, params, config) -> (State, Info)``:
  :func:`scan_runner` of its ``step``, ``Info`` stacked over the steps.

These module functions take the params and the static config as arguments, so that
the chunk runners below carry the params (a sweep never recompiles). The filters as
values, with the config and params bound (:class:`jaxslam.base.ParticleFilter`,
:func:`jaxslam.filters.srupf_gm` and the other factories), wrap these same functions.

**Step keys.** Step ``t`` of a run uses ``step_keys(key, T)[t]``, i.e.
``jax.random.split(key, T)[t]`` (:func:`step_keys`), whichever driver runs it
(:func:`scan_steps`, the chunked runner of the CLI, the seed ensembles).

**Best particle.** The particle with the largest accumulated log-likelihood
:math:`\sum_t \log p(z_t \mid x^{[m]}_t, m^{[m]}_{t-1})` of its history (GMapping's
``weightSum``), carried with the particle through resampling in
``State.cumulative_log_likelihood`` (:func:`best_particle`). Not the highest current
weight: right after a resampling every weight is equal and the argmax would be an
arbitrary particle, and the grid filters temper their weights (``weight_gain``).

**Runners.** :func:`chunk_runner` is the one jitted chunk runner of a ``step`` under
a static config, cached per ``(step, config, summary, compiler options)``: every
chunked run (the CLI, the notebooks and the benchmarks, the landmark and the grid
filters alike, plain, checkpointed, resumed or viewed live) goes through it and the
host loop :func:`jaxslam.runtime.progress.run_scan_chunked`, so a sweep over ``Params``
(traced) never recompiles. With
the compilation cache on, the compiled runner is also kept on disk
(:mod:`jaxslam.runtime.executables`): a later process loads it without tracing.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.runtime.compiler import jit_with
from jaxslam.runtime.executables import runner_tag


def step_keys(key: Array, num_steps: int) -> Array:
    """The keys of steps ``0..num_steps-1`` of a run started with ``key``."""
    return jax.random.split(key, num_steps)


def num_steps(xs: Any) -> int:
    """The common leading (time) length of the arrays of ``xs``."""
    leaves = jax.tree_util.tree_leaves(xs)
    if not leaves:
        raise ValueError("the inputs have no arrays to scan over")
    return int(jnp.shape(leaves[0])[0])


def scan_steps(step_fn, key: Array, state, controls, observations, params, config):
    """``lax.scan`` of ``step_fn`` over the steps, one key per step (:func:`step_keys`)."""
    keys = step_keys(key, num_steps(observations))

    def body(carry, inputs):
        k, u, z = inputs
        return step_fn(k, carry, u, z, params, config)

    return jax.lax.scan(body, state, (keys, controls, observations))


def scan_runner(step_fn):
    """A filter module's ``run``: :func:`scan_steps` of ``step_fn``, jitted with a static
    ``config``. It does not donate the caller's state."""

    @functools.partial(jax.jit, static_argnames=("config",))
    def run(key, state, controls, observations, params, config):
        """Scan ``step`` over a sequence: ``controls`` and ``observations`` stacked over
        the steps; step ``t`` uses ``step_keys(key, T)[t]``.

        Returns:
            ``(final_state, infos)`` with every ``Info`` field stacked over the steps.
        """
        return scan_steps(step_fn, key, state, controls, observations, params, config)

    return run


@functools.lru_cache(maxsize=32)
def chunk_runner(step_fn, config, summary: Callable[[Any], Any] | None = None, compiler_options: tuple = ()):
    """The jitted chunk runner of ``step_fn`` under ``config``: one per
    ``(step_fn, config, summary, compiler_options)`` (cached), so a sweep over the
    params (traced) or a second run of the same shapes never retraces.

    The runner is ``(carry, xs_chunk, valid) -> (carry, ys_chunk)`` over one chunk of
    steps (:func:`jaxslam.runtime.progress.run_scan_chunked` drives it): the carry is
    ``(state, params)``, donated; ``xs_chunk`` the ``(key, control, observation)`` of
    each step, stacked; ``valid`` (bool, the chunk's length) marks the steps to run, a
    prefix (the outputs of the others are zeros); the outputs are ``summary(info)``
    of each step (``info`` itself by default).

    ``compiler_options``: XLA's, as ``(name, value)`` pairs
    (:func:`jaxslam.runtime.compiler.options_key`; none by default), kept on the
    runner as ``jaxslam_compiler_options`` for a program loaded from disk. The runner's
    ``jaxslam_tag`` (:func:`jaxslam.runtime.executables.runner_tag`) names what besides
    the arguments determines the program; with it the compiled runner is kept on disk
    next to the compilation cache (:mod:`jaxslam.runtime.executables`)."""

    def body(carry, x):
        state, params = carry
        key, control, observation = x
        state, info = step_fn(key, state, control, observation, params, config)
        return (state, params), info if summary is None else summary(info)

    # Jitted so that it is traced once: ``eval_shape`` below and the loop body reuse
    # the same trace (the step is the bulk of the tracing time of a run).
    step_jit = jax.jit(body)

    def run_chunk(carry, xs_chunk, valid):
        # ``valid`` is a prefix: its steps run, in a loop of that many iterations, and
        # the padding steps after it are not run at all (their outputs are zeros). A
        # ``lax.cond`` per step would pass the carry through a skipped step, a copy of
        # every map buffer.
        x0 = jax.tree_util.tree_map(lambda leaf: leaf[0], xs_chunk)
        y_shape = jax.eval_shape(step_jit, carry, x0)[1]
        length = valid.shape[0]
        ys = jax.tree_util.tree_map(lambda s: jnp.zeros((length, *s.shape), s.dtype), y_shape)

        def body(i, c_ys):
            c, ys = c_ys
            x = jax.tree_util.tree_map(lambda leaf: jax.lax.dynamic_index_in_dim(leaf, i, keepdims=False), xs_chunk)
            c, y = step_jit(c, x)
            ys = jax.tree_util.tree_map(lambda buf, v: jax.lax.dynamic_update_index_in_dim(buf, v, i, 0), ys, y)
            return c, ys

        return jax.lax.fori_loop(0, jnp.sum(valid.astype(jnp.int32)), body, (carry, ys))

    runner = jit_with(run_chunk, dict(compiler_options), donate_argnums=(0,))
    runner.jaxslam_tag = runner_tag(step_fn, config, summary, donate=True)
    return runner


def best_particle(state) -> Array:
    """Index of the particle with the largest accumulated log-likelihood (see above); on
    the host (NumPy, no JAX program) when the state holds NumPy arrays."""
    scores = state.cumulative_log_likelihood
    if isinstance(scores, np.ndarray):
        return np.argmax(scores)
    return jnp.argmax(scores)


__all__ = ["best_particle", "chunk_runner", "num_steps", "scan_runner", "scan_steps", "step_keys"]
