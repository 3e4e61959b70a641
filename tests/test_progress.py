"""The chunked run of a chunk runner equals one lax.scan, resumes exactly, and compiles once."""

import jax
import pytest
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.driver import chunk_runner, scan_steps
from jaxslam.runtime.progress import run_scan_chunked


def step(key, state, control, observation, params, config):
    """A toy filter step of the protocol: a decaying sum of the controls."""
    total, count = state
    total = total * params + control
    return (total, count + 1), {"total": total, "twice": 2 * observation}


def runner():
    return chunk_runner(step, "toy")


def inputs(n=53, dtype=jnp.float64, values=None):
    """``(keys, controls, observations)`` of ``n`` steps."""
    values = jnp.arange(n, dtype=dtype) if values is None else values
    return jax.random.split(jax.random.PRNGKey(0), values.shape[0]), values, values


def init(dtype=jnp.float64, total=None):
    """The carry ``(state, params)``."""
    total = jnp.array(0.0, dtype) if total is None else total
    return (total, jnp.array(0, jnp.int32)), jnp.array(0.9, dtype)


def test_equals_single_scan_with_ragged_last_chunk():
    xs = inputs()
    ref_state, ref_ys = scan_steps(step, jax.random.PRNGKey(0), init()[0], xs[1], xs[2], init()[1], "toy")
    (state, _), ys, timing = run_scan_chunked(runner(), init(), xs, chunk=10, progress=False)
    np.testing.assert_allclose(np.asarray(state[0]), np.asarray(ref_state[0]))
    assert int(state[1]) == 53  # padded steps were skipped
    np.testing.assert_allclose(np.asarray(ys["total"]), np.asarray(ref_ys["total"]))
    assert ys["twice"].shape == (53,)
    assert timing.steps == 53 and timing.compile_s >= 0


def test_resume_from_middle_gives_identical_result():
    xs = inputs()
    saved = {}

    def callback(carry, done):
        if done == 20:
            saved["carry"] = jax.tree_util.tree_map(np.asarray, carry)

    full, _, _ = run_scan_chunked(runner(), init(), xs, chunk=10, progress=False, callback=callback)
    resumed, ys, _ = run_scan_chunked(runner(), jax.tree_util.tree_map(jnp.asarray, saved["carry"]), xs,
                                      chunk=10, progress=False, start=20)
    assert float(resumed[0][0]) == float(full[0][0])
    assert ys["total"].shape == (33,)


def test_runner_compiles_once_across_calls():
    traces = []

    def counting_step(*args):
        traces.append(1)
        return step(*args)

    counting = chunk_runner(counting_step, "toy")
    assert chunk_runner(counting_step, "toy") is counting  # one runner per (step, config)
    for scale in (1.0, 2.0):
        run_scan_chunked(counting, init(), inputs(values=scale * jnp.arange(30.0)), chunk=8, progress=False)
    # traced once for the step and once for the shape of its output, not per call
    assert len(traces) <= 2


def test_checkpoint_interrupt_and_resume_is_bit_identical(tmp_path, monkeypatch):
    import pytest

    from jaxslam.runtime.checkpoint import Checkpoint, CheckpointError

    xs = inputs(values=jnp.sin(jnp.arange(47, dtype=jnp.float32)))
    f32 = jnp.float32
    (full_state, _), full_ys, _ = run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False)

    path = tmp_path / "ckpt.npz"
    fingerprint = {"algorithm": "toy", "seed": 0}

    class Interrupt(Exception):
        pass

    def crash(_carry, done):
        if done >= 24:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, every=8, fingerprint=fingerprint), callback=crash)
    assert path.exists() and not path.with_name(path.name + ".tmp").exists()
    resumed = Checkpoint(path, every=8, fingerprint=fingerprint, resume=True)
    (state, _), ys, timing = run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False, checkpoint=resumed)
    assert timing.steps == 47 - 24
    assert np.asarray(state[0]).tobytes() == np.asarray(full_state[0]).tobytes()
    assert int(state[1]) == 47
    np.testing.assert_array_equal(np.asarray(ys["total"]), np.asarray(full_ys["total"]))

    # a checkpoint from another run is refused, naming what differs
    with pytest.raises(CheckpointError, match="seed"):
        run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint={"algorithm": "toy", "seed": 1}, resume=True))
    # a checkpoint written by another version of jaxslam's source (or JAX's) is refused,
    # naming the file; the digest covers the JAX version
    from jaxslam.runtime import checkpoint as checkpoint_module

    with monkeypatch.context() as patch:
        patch.setattr(jax, "__version__", jax.__version__ + ".other")
        assert checkpoint_module.code_digest.__wrapped__() != checkpoint_module.code_digest()
    assert checkpoint_module.code_digest.__wrapped__() == checkpoint_module.code_digest()

    with monkeypatch.context() as patch:
        patch.setattr(checkpoint_module, "code_digest", lambda: "0123456789abcdef")
        with pytest.raises(CheckpointError, match=r"ckpt\.npz: written by another version of jaxslam"):
            run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False,
                             checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    # a state of another shape is refused
    with pytest.raises(CheckpointError, match="shape"):
        run_scan_chunked(runner(), init(f32, total=jnp.zeros(3, f32)), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))

    # outputs of another version of the step (one more output) are refused, not joined
    def step_more(*args):
        state, ys = step(*args)
        return state, {**ys, "more": jnp.zeros(2)}

    more = chunk_runner(step_more, "toy")
    with pytest.raises(CheckpointError, match="outputs"):  # a finished run's checkpoint
        run_scan_chunked(more, init(f32), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    half = tmp_path / "half.npz"  # an interrupted run's: refused at its first chunk
    with pytest.raises(Interrupt):
        run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(half, every=8, fingerprint=fingerprint), callback=crash)
    with pytest.raises(CheckpointError, match="outputs"):
        run_scan_chunked(more, init(f32), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(half, fingerprint=fingerprint, resume=True))
    # a truncated file is refused as corrupt
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(CheckpointError, match="corrupt"):
        run_scan_chunked(runner(), init(f32), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    with pytest.raises(CheckpointError, match="no checkpoint"):
        Checkpoint(tmp_path / "none.npz", resume=True).load(init(f32))


def test_checkpoint_load_leading_restores_only_the_leading_state(tmp_path):
    import pytest

    from jaxslam.runtime.checkpoint import Checkpoint, CheckpointError

    state = {"a": np.arange(3, dtype=np.float32), "b": np.array(7, np.int32)}
    carry = (state, np.array([0.5, 2.0], np.float32))  # (state, params)
    ckpt = Checkpoint(tmp_path / "c.npz")
    ckpt.save(carry, 12, [np.arange(12)])
    template = {"a": np.zeros(3, np.float32), "b": np.array(0, np.int32)}
    restored, done, outputs = Checkpoint(tmp_path / "c.npz").load_leading(template)
    assert done == 12 and set(restored) == {"a", "b"}
    np.testing.assert_array_equal(np.asarray(restored["a"]), state["a"])
    assert int(restored["b"]) == 7
    np.testing.assert_array_equal(outputs[0], np.arange(12))
    # load() still wants the whole structure; load_leading still checks every leaf it restores
    with pytest.raises(CheckpointError, match="structure"):
        Checkpoint(tmp_path / "c.npz").load(template)
    with pytest.raises(CheckpointError, match="shape"):
        Checkpoint(tmp_path / "c.npz").load_leading({"a": np.zeros(4, np.float32), "b": np.array(0, np.int32)})
    with pytest.raises(CheckpointError, match="needs 4"):
        Checkpoint(tmp_path / "c.npz").load_leading([np.zeros(3, np.float32)] * 4)


def test_checkpoints_resumes_and_live_updates_run_the_plain_runs_program(tmp_path):
    """The chunk length follows the log only: a checkpoint interval shorter than the
    chunk, a resume in the middle of a chunk and a callback every few steps run the
    plain run's compiled chunk (nothing compiled anew), with the plain run's result."""
    from jaxslam.runtime.cache import CompileCounter
    from jaxslam.runtime.checkpoint import Checkpoint

    xs = inputs(values=jnp.sin(jnp.arange(47, dtype=jnp.float32)))

    def start():
        return init(jnp.float32)

    class Interrupt(Exception):
        pass

    def crash(_carry, done):
        if done >= 20:
            raise Interrupt

    run = runner()
    plain_carry, plain_ys, _ = run_scan_chunked(run, start(), xs, chunk=16, progress=False)
    seen = []
    with CompileCounter() as counter:
        path, half = tmp_path / "ckpt.npz", tmp_path / "half.npz"
        checkpointed = run_scan_chunked(run, start(), xs, chunk=16, progress=False,
                                        checkpoint=Checkpoint(path, every=5))
        finished = run_scan_chunked(run, start(), xs, chunk=16, progress=False,
                                    checkpoint=Checkpoint(path, resume=True))
        with pytest.raises(Interrupt):
            run_scan_chunked(run, start(), xs, chunk=16, progress=False,
                             checkpoint=Checkpoint(half, every=5), callback=crash)
        resumed = run_scan_chunked(run, start(), xs, chunk=16, progress=False,
                                   checkpoint=Checkpoint(half, every=5, resume=True))
        live = run_scan_chunked(run, start(), xs, chunk=16, progress=False,
                                callback=lambda _carry, done: seen.append(done), callback_every=7)
        middle = run_scan_chunked(run, start(), xs, chunk=16, progress=False, start=21)
    assert counter.requests == 0, counter.as_dict()
    assert seen == [7, 14, 21, 28, 35, 42, 47]
    assert resumed[2].steps == 47 - 20
    plain_state = plain_carry[0]
    for (state, _), ys, _timing in (checkpointed, finished, resumed, live):
        assert np.asarray(state[0]).tobytes() == np.asarray(plain_state[0]).tobytes() and int(state[1]) == 47
        assert np.asarray(ys["total"]).tobytes() == np.asarray(plain_ys["total"]).tobytes()
    assert int(middle[0][0][1]) == 47 - 21 and middle[1]["total"].shape == (26,)


def test_a_checkpoint_interval_shorter_than_the_chunk_saves_at_every_interval(tmp_path):
    from jaxslam.runtime.checkpoint import Checkpoint

    saved = []

    class Recording(Checkpoint):
        def save(self, carry, done, output_leaves):
            saved.append((done, int(carry[0][1]), output_leaves[0].shape[0]))
            super().save(carry, done, output_leaves)

    run_scan_chunked(runner(), init(jnp.float32), inputs(values=jnp.arange(23, dtype=jnp.float32)), chunk=10,
                     progress=False, checkpoint=Recording(tmp_path / "c.npz", every=4))
    assert saved == [(d, d, d) for d in (4, 8, 12, 16, 20, 23)]
