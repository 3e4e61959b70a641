"""jaxslam's XLA compiler options (jaxslam.runtime.compiler): what options() returns, that jit
applies them and keeps them on the jitted function, and the size of XLA's CPU thread
pool (set_threads)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from jaxslam.runtime import compiler


def test_options_default_environment_and_xla_flags(monkeypatch):
    monkeypatch.delenv(compiler.ENV_VAR, raising=False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    assert compiler.options() == compiler.OPTIONS == {"xla_cpu_use_fusion_emitters": False,
                                                      "xla_cpu_parallel_codegen_split_count": 8}
    assert compiler.options() is not compiler.OPTIONS  # a copy: callers cannot change the defaults
    monkeypatch.setenv(compiler.ENV_VAR, "xla")
    assert compiler.options() == {}
    monkeypatch.setenv(compiler.ENV_VAR, " JAXSLAM ")
    assert compiler.options() == compiler.OPTIONS
    monkeypatch.setenv(compiler.ENV_VAR, "fast")
    with pytest.raises(ValueError, match="JAXSLAM_XLA_OPTIONS.*'fast'"):
        compiler.options()
    monkeypatch.delenv(compiler.ENV_VAR)
    # An option that XLA_FLAGS sets is left to XLA_FLAGS.
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true --xla_force_host_platform_device_count=1")
    assert compiler.options() == {"xla_cpu_parallel_codegen_split_count": 8}
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_parallel_codegen_split_count=32 --xla_cpu_use_fusion_emitters=true")
    assert compiler.options() == {}
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
    assert compiler.options() == compiler.OPTIONS


def test_jit_applies_and_records_options(monkeypatch):
    monkeypatch.delenv(compiler.ENV_VAR, raising=False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)

    def f(x, n):
        return jnp.cumsum(jnp.sin(x)) * n

    jitted = compiler.jit(f, static_argnames=("n",))
    assert jitted.jaxslam_compiler_options == compiler.OPTIONS
    x = jnp.linspace(0.0, 3.0, 50, dtype=jnp.float32)
    np.testing.assert_array_equal(np.asarray(jitted(x, n=2)), np.asarray(f(x, 2)))
    decorated = compiler.jit(static_argnames=("n",))(f)
    np.testing.assert_array_equal(np.asarray(decorated(x, n=3)), np.asarray(f(x, 3)))
    # A caller's options are added to (and override) jaxslam's.
    merged = compiler.jit(f, static_argnames=("n",), compiler_options={"xla_cpu_use_fusion_emitters": True})
    assert merged.jaxslam_compiler_options == {**compiler.OPTIONS, "xla_cpu_use_fusion_emitters": True}
    np.testing.assert_array_equal(np.asarray(merged(x, n=2)), np.asarray(f(x, 2)))
    # An unknown option is XLA's error, not silently ignored.
    with pytest.raises(Exception, match="no_such_option"):
        compiler.jit(f, static_argnames=("n",), compiler_options={"xla_no_such_option": 1})(x, n=1)
    monkeypatch.setenv(compiler.ENV_VAR, "xla")
    assert compiler.jit(f, static_argnames=("n",)).jaxslam_compiler_options == {}
    # jit_with: exactly the given options, jaxslam's not added
    assert compiler.jit_with(f, None, static_argnames=("n",)).jaxslam_compiler_options == {}
    monkeypatch.delenv(compiler.ENV_VAR)
    exact = compiler.jit_with(f, {}, static_argnames=("n",))
    assert exact.jaxslam_compiler_options == {}
    np.testing.assert_array_equal(np.asarray(exact(x, n=2)), np.asarray(f(x, 2)))


@pytest.fixture
def fresh_backend(monkeypatch):
    """set_threads as if no JAX computation had run yet in this process (it has: the
    real pool is not touched). Returns a list of the ``NPROC`` each backend start saw
    (``None``: unset), which is what XLA reads."""
    import jax
    from jax._src import xla_bridge

    seen = []
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)
    monkeypatch.setattr(jax, "devices", lambda *a, **k: seen.append(os.environ.get("NPROC")))
    monkeypatch.setattr(compiler, "_STARTED_WITH", None)
    for name in (compiler.THREADS_ENV, "NPROC"):
        monkeypatch.delenv(name, raising=False)
    return seen


def test_set_threads_precedence(fresh_backend, monkeypatch):
    seen = fresh_backend
    for algorithm, limit in compiler.SINGLE_THREAD_MAX_PARTICLES.items():
        assert compiler.auto_threads(algorithm, limit) == 1 and compiler.auto_threads(algorithm, limit + 1) is None
    for grid in ("gmapping", "srupf-gm"):
        assert compiler.auto_threads(grid, 1) is None
    assert compiler.set_threads(None, "erb-upf", 100) == {"threads": 1, "source": "auto"}
    assert seen[-1] == "1"
    assert "NPROC" not in os.environ  # put back: child processes do not inherit it
    assert compiler.set_threads(None, "erb-upf", 1000) == {"threads": "all", "source": "auto"}
    assert seen[-1] is None
    monkeypatch.setenv(compiler.THREADS_ENV, "all")
    assert compiler.set_threads(None, "erb-upf", 100) == {"threads": "all", "source": "JAXSLAM_THREADS"}
    assert seen[-1] is None
    # the argument wins over the environment
    assert compiler.set_threads(2, "erb-upf", 100) == {"threads": 2, "source": "argument"}
    assert seen[-1] == "2"
    assert compiler.set_threads("all", "erb-upf", 100) == {"threads": "all", "source": "argument"}
    assert seen[-1] is None
    with pytest.raises(ValueError, match="'all' for every core"):  # 0 is no count and not a silent 'all'
        compiler.set_threads("0", "erb-upf", 100)
    monkeypatch.delenv(compiler.THREADS_ENV)
    # a user's own NPROC is kept, and an argument overrides it only for the backend start
    monkeypatch.setenv("NPROC", "3")
    starts = len(seen)
    assert compiler.set_threads(None, "erb-upf", 10) == {"threads": 3, "source": "NPROC"}
    assert os.environ["NPROC"] == "3" and len(seen) == starts  # left to XLA as it is
    assert compiler.set_threads(1, "erb-upf", 10) == {"threads": 1, "source": "argument"}
    assert seen[-1] == "1" and os.environ["NPROC"] == "3"
    for bad in ("-1", "two", 1.5):
        with pytest.raises(ValueError, match="threads must be a positive thread count or 'all'"):
            compiler.set_threads(bad, "erb-upf", 100)
    monkeypatch.setenv(compiler.THREADS_ENV, "x")
    with pytest.raises(ValueError, match="JAXSLAM_THREADS must be"):
        compiler.set_threads(None, "erb-upf", 100)


def test_set_threads_after_the_backend_started_changes_nothing(monkeypatch):
    jnp.zeros(1).block_until_ready()  # the backend of this process has started
    monkeypatch.delenv("NPROC", raising=False)
    monkeypatch.setattr(compiler, "_STARTED_WITH", None)  # started by JAX itself: XLA's default
    assert compiler.set_threads(1, "erb-upf", 100) == {"threads": "all", "source": "backend already started"}
    assert "NPROC" not in os.environ
    monkeypatch.setattr(compiler, "_STARTED_WITH", {"threads": 1})  # started by set_threads
    assert compiler.set_threads("all", "erb-upf", 1000) == {"threads": 1, "source": "backend already started"}


def _xla_threads_in_subprocess(threads) -> int:
    code = (
        "import os, jax.numpy as jnp\n"
        "from jaxslam.runtime.compiler import set_threads\n"
        f"set_threads({threads!r}, 'erb-upf', 100)\n"
        "jnp.zeros(3).block_until_ready()\n"
        "names = [open(f'/proc/self/task/{t}/comm').read().strip() for t in os.listdir('/proc/self/task')]\n"
        "assert 'NPROC' not in os.environ  # not left for child processes\n"
        "print(sum('XLAEigen' in n for n in names))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("NPROC", compiler.THREADS_ENV)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1])



@pytest.mark.skipif(not os.path.isdir("/proc/self/task") or (os.cpu_count() or 1) < 2,
                    reason="counts the threads of XLA's pool in /proc on a multi-core machine")
def test_set_threads_sizes_xla_thread_pool():
    # XLA reads NPROC when its CPU backend starts (DefaultThreadPoolSize); if a JAX
    # upgrade stops doing so, this fails.
    assert _xla_threads_in_subprocess(1) == 1
    assert _xla_threads_in_subprocess("all") == min(os.cpu_count(), len(os.sched_getaffinity(0)))


def test_results_do_not_depend_on_xla_threads():
    """The same program (test_cache's) in fresh processes with one XLA thread and with
    two gives the same bits."""
    from tests.test_cache import PROGRAM, _run_program

    one = _run_program(PROGRAM, ["off"], {"NPROC": "1"})
    two = _run_program(PROGRAM, ["off"], {"NPROC": "2"})
    assert one["result"] == two["result"]


@pytest.mark.long
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2 if hasattr(os, "sched_getaffinity") else True,
                    reason="needs two CPUs: XLA splits its code by the thread pool only with more than one")
def test_grid_runs_do_not_depend_on_xla_threads(tmp_path):
    """The grid filter itself, as ``jaxslam run`` runs it, in fresh processes with one XLA
    thread and with every core: the same trajectory and map bit for bit. XLA splits a
    program's generated code by its thread pool, and with the loop emitters the split
    changes the rounding (:mod:`jaxslam.runtime.compiler`); the fixed split count of
    :data:`jaxslam.runtime.compiler.OPTIONS` keeps that out. This segment (Intel, 30 particles,
    150 keyframes) is one where it shows: with
    ``XLA_FLAGS=--xla_cpu_parallel_codegen_split_count=32`` (XLA's split on two threads)
    this test fails on the project's 2-core machine (checked when it was written, jax
    0.10.2); 40 keyframes, or 16 particles and 100, gave the same bits either way."""
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.datasets.paths import DatasetNotFoundError

    try:
        load_dataset_log("intel")
    except DatasetNotFoundError as error:
        pytest.skip(str(error))
    env = {k: v for k, v in os.environ.items() if k not in ("NPROC", compiler.THREADS_ENV)}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    outputs = {}
    for threads in ("1", "all"):
        out = tmp_path / threads
        proc = subprocess.run(
            [sys.executable, "-m", "jaxslam.app.cli", "run", "--dataset", "intel", "--algorithm", "srupf-gm",
             "--particles", "30", "--max-steps", "150", "--threads", threads, "--no-cache", "--no-plots",
             "--no-progress", "--out", str(out)],
            capture_output=True, text=True, env=env, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        outputs[threads] = [(out / name).read_bytes() for name in ("trajectory.tum", "map.pgm")]
    assert outputs["1"] == outputs["all"]


def test_cpus_allowed_follows_the_affinity_taskset_sets():
    """The count summary.json and the benchmarks record: the CPUs the process may run
    on, not the machine's, so a run pinned with taskset says so."""
    code = (
        "import os\n"
        "os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})\n"
        "from jaxslam.runtime.compiler import cpus_allowed\n"
        "print(cpus_allowed())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1"]
    assert compiler.cpus_allowed() == len(os.sched_getaffinity(0))
