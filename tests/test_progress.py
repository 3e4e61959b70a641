"""The chunked scan runner equals one lax.scan, resumes exactly, and compiles once."""

import jax
import pytest
import jax.numpy as jnp
import numpy as np

from jaxslam.runtime.progress import make_chunk_runner, run_scan_chunked


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


def test_checkpoint_interrupt_and_resume_is_bit_identical(tmp_path, monkeypatch):
    import pytest

    from jaxslam.runtime.checkpoint import Checkpoint, CheckpointError

    xs = {"value": jnp.sin(jnp.arange(47, dtype=jnp.float32))}
    init = (jnp.array(0.0, jnp.float32), jnp.array(0))
    full_carry, full_ys, _ = run_scan_chunked(step, init, xs, chunk=8, progress=False)

    path = tmp_path / "ckpt.npz"
    fingerprint = {"algorithm": "toy", "seed": 0}

    class Interrupt(Exception):
        pass

    def crash(_carry, done):
        if done >= 24:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_scan_chunked(step, (jnp.array(0.0, jnp.float32), jnp.array(0)), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, every=8, fingerprint=fingerprint), callback=crash)
    assert path.exists() and not path.with_name(path.name + ".tmp").exists()
    resumed = Checkpoint(path, every=8, fingerprint=fingerprint, resume=True)
    carry, ys, timing = run_scan_chunked(step, (jnp.array(0.0, jnp.float32), jnp.array(0)), xs, chunk=8,
                                         progress=False, checkpoint=resumed)
    assert timing.steps == 47 - 24
    assert np.asarray(carry[0]).tobytes() == np.asarray(full_carry[0]).tobytes()
    assert int(carry[1]) == 47
    np.testing.assert_array_equal(np.asarray(ys["total"]), np.asarray(full_ys["total"]))

    # a checkpoint from another run is refused, naming what differs
    with pytest.raises(CheckpointError, match="seed"):
        run_scan_chunked(step, init, xs, chunk=8, progress=False,
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
            run_scan_chunked(step, init, xs, chunk=8, progress=False,
                             checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    # a state of another shape is refused
    with pytest.raises(CheckpointError, match="shape"):
        run_scan_chunked(step, (jnp.zeros(3, jnp.float32), jnp.array(0)), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    # outputs of another version of the step (one more output) are refused, not joined
    def step_more(carry, x):
        carry, ys = step(carry, x)
        return carry, {**ys, "more": jnp.zeros(2)}

    with pytest.raises(CheckpointError, match="outputs"):  # a finished run's checkpoint
        run_scan_chunked(step_more, (jnp.array(0.0, jnp.float32), jnp.array(0)), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    half = tmp_path / "half.npz"  # an interrupted run's: refused at its first chunk
    with pytest.raises(Interrupt):
        run_scan_chunked(step, (jnp.array(0.0, jnp.float32), jnp.array(0)), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(half, every=8, fingerprint=fingerprint), callback=crash)
    with pytest.raises(CheckpointError, match="outputs"):
        run_scan_chunked(step_more, (jnp.array(0.0, jnp.float32), jnp.array(0)), xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(half, fingerprint=fingerprint, resume=True))
    # a truncated file is refused as corrupt
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(CheckpointError, match="corrupt"):
        run_scan_chunked(step, init, xs, chunk=8, progress=False,
                         checkpoint=Checkpoint(path, fingerprint=fingerprint, resume=True))
    with pytest.raises(CheckpointError, match="no checkpoint"):
        Checkpoint(tmp_path / "none.npz", resume=True).load(init)


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

    xs = {"value": jnp.sin(jnp.arange(47, dtype=jnp.float32))}
    runner = make_chunk_runner(step)

    def init():
        return (jnp.array(0.0, jnp.float32), jnp.array(0, jnp.int32))

    class Interrupt(Exception):
        pass

    def crash(_carry, done):
        if done >= 20:
            raise Interrupt

    plain_carry, plain_ys, _ = run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner)
    seen = []
    with CompileCounter() as counter:
        path, half = tmp_path / "ckpt.npz", tmp_path / "half.npz"
        checkpointed = run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner,
                                        checkpoint=Checkpoint(path, every=5))
        finished = run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner,
                                    checkpoint=Checkpoint(path, resume=True))
        with pytest.raises(Interrupt):
            run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner,
                             checkpoint=Checkpoint(half, every=5), callback=crash)
        resumed = run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner,
                                   checkpoint=Checkpoint(half, every=5, resume=True))
        live = run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner,
                                callback=lambda _carry, done: seen.append(done), callback_every=7)
        middle = run_scan_chunked(None, init(), xs, chunk=16, progress=False, runner=runner, start=21)
    assert counter.requests == 0, counter.as_dict()
    assert seen == [7, 14, 21, 28, 35, 42, 47]
    assert resumed[2].steps == 47 - 20
    for carry, ys, _timing in (checkpointed, finished, resumed, live):
        assert np.asarray(carry[0]).tobytes() == np.asarray(plain_carry[0]).tobytes() and int(carry[1]) == 47
        assert np.asarray(ys["total"]).tobytes() == np.asarray(plain_ys["total"]).tobytes()
    assert int(middle[0][1]) == 47 - 21 and middle[1]["total"].shape == (26,)


def test_a_checkpoint_interval_shorter_than_the_chunk_saves_at_every_interval(tmp_path):
    from jaxslam.runtime.checkpoint import Checkpoint

    saved = []

    class Recording(Checkpoint):
        def save(self, carry, done, output_leaves):
            saved.append((done, int(carry[1]), output_leaves[0].shape[0]))
            super().save(carry, done, output_leaves)

    xs = {"value": jnp.arange(23, dtype=jnp.float32)}
    run_scan_chunked(step, (jnp.array(0.0, jnp.float32), jnp.array(0)), xs, chunk=10, progress=False,
                     checkpoint=Recording(tmp_path / "c.npz", every=4))
    assert saved == [(d, d, d) for d in (4, 8, 12, 16, 20, 23)]
