"""The chunked scan runner equals one lax.scan, resumes exactly, and compiles once."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.progress import make_chunk_runner, run_scan_chunked


def step(carry, x):
    total, count = carry
    total = total * 0.9 + x["value"]
    return (total, count + 1), {"total": total, "twice": 2 * x["value"]}


def inputs(n=53):
    return {"value": jnp.arange(n, dtype=jnp.float64)}


def test_equals_single_scan_with_ragged_last_chunk():
    xs = inputs()
    ref_carry, ref_ys = jax.lax.scan(step, (jnp.array(0.0), jnp.array(0)), xs)
    carry, ys, timing = run_scan_chunked(step, (jnp.array(0.0), jnp.array(0)), xs, chunk=10, progress=False)
    np.testing.assert_allclose(np.asarray(carry[0]), np.asarray(ref_carry[0]))
    assert int(carry[1]) == 53  # padded steps were skipped
    np.testing.assert_allclose(np.asarray(ys["total"]), np.asarray(ref_ys["total"]))
    assert ys["twice"].shape == (53,)
    assert timing.steps == 53 and timing.compile_s >= 0


def test_resume_from_middle_gives_identical_result():
    xs = inputs()
    saved = {}

    def callback(carry, done):
        if done == 20:
            saved["carry"] = jax.tree_util.tree_map(np.asarray, carry)

    full, _, _ = run_scan_chunked(step, (jnp.array(0.0), jnp.array(0)), xs, chunk=10, progress=False,
                                  callback=callback)
    resumed, ys, _ = run_scan_chunked(step, jax.tree_util.tree_map(jnp.asarray, saved["carry"]), xs,
                                      chunk=10, progress=False, start=20)
    assert float(resumed[0]) == float(full[0])
    assert ys["total"].shape == (33,)


def test_runner_compiles_once_across_calls():
    traces = []

    def counting_step(carry, x):
        traces.append(1)
        return step(carry, x)

    runner = make_chunk_runner(counting_step)
    for scale in (1.0, 2.0):
        run_scan_chunked(counting_step, (jnp.array(0.0), jnp.array(0)),
                         {"value": scale * jnp.arange(30.0)}, chunk=8, progress=False, runner=runner)
    # traced once for the step and once for the shape of its output, not per call
    assert len(traces) <= 2
