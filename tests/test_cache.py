"""The persistent compilation cache (jaxslam.runtime.cache): where it lives, that a warm cache
compiles nothing new in a fresh process, and that cached programs compute bit for bit
what freshly compiled ones do."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxslam.runtime.cache import ENV_VAR, default_cache_dir, resolve_cache_dir

ROOT = Path(__file__).resolve().parents[1]

# A small program built from library kernels: a scanned particle step (SE(2)
# composition, Gaussian log-densities, systematic resampling) plus a few eager ops.
PROGRAM = r"""
import json, sys
from jaxslam.runtime.cache import CompileCounter, enable_compilation_cache
path = enable_compilation_cache(sys.argv[1] if len(sys.argv) > 1 else None)
import jax, jax.numpy as jnp
from jaxslam.core import resampling, se2

def step(carry, key):
    poses, log_w = carry
    k1, k2 = jax.random.split(key)
    noise = 0.05 * jax.random.normal(k1, poses.shape, poses.dtype)
    poses = jax.vmap(se2.compose)(poses, noise + jnp.array([0.1, 0.0, 0.02], poses.dtype))
    log_w = log_w - 2.0 * jnp.sum((poses[:, :2] - 1.0) ** 2, axis=1)
    index = resampling.systematic(k2, log_w)
    return (poses[index], jnp.zeros_like(log_w)), poses.mean(0)

@jax.jit
def run(key):
    poses = jnp.zeros((64, 3), jnp.float32)
    return jax.lax.scan(step, (poses, jnp.zeros(64, jnp.float32)), jax.random.split(key, 50))

with CompileCounter() as counter:
    (poses, _), means = run(jax.random.key(3))
    extra = jnp.cumsum(jnp.sin(means[:, 0])) * 2.0
print(json.dumps({"cache": None if path is None else str(path), "counts": counter.as_dict(),
                  "result": [poses.tobytes().hex(), means.tobytes().hex(), extra.tobytes().hex()]}))
"""


def _run(args: list[str], env_extra: dict[str, str]) -> dict:
    return _run_program(PROGRAM, args, env_extra)


def _run_program(program: str, args: list[str], env_extra: dict[str, str] | None = None) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), **(env_extra or {})}
    proc = subprocess.run([sys.executable, "-c", program, *args], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_cache_dir_resolution(monkeypatch, tmp_path):
    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "jaxslam" / "jax"
    assert resolve_cache_dir() == tmp_path / "xdg" / "jaxslam" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert resolve_cache_dir() == Path.home() / ".cache" / "jaxslam" / "jax"
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    assert resolve_cache_dir() == tmp_path / "env"
    assert resolve_cache_dir(tmp_path / "arg") == tmp_path / "arg"  # the argument wins
    for off in ("off", "OFF", "none", "0", "", " false "):
        monkeypatch.setenv(ENV_VAR, off)
        assert resolve_cache_dir() is None
        assert resolve_cache_dir(off) is None


def test_warm_cache_compiles_nothing_and_results_are_bit_identical(tmp_path):
    cache = tmp_path / "cache"
    cold = _run([], {ENV_VAR: str(cache)})
    assert cold["cache"] == str(cache)
    assert cold["counts"]["compiled"] >= 2 and cold["counts"]["cache_hits"] == 0
    assert any(cache.iterdir())
    warm = _run([], {ENV_VAR: str(cache)})
    assert warm["counts"]["compiled"] == 0, warm["counts"]
    assert warm["counts"]["cache_hits"] == cold["counts"]["programs"]
    off = _run(["off"], {ENV_VAR: str(cache)})  # the argument overrides the variable
    assert off["cache"] is None and off["counts"]["cache_hits"] == 0 and off["counts"]["compiled"] >= 2
    assert cold["result"] == warm["result"] == off["result"]


def _run_pinned(args: list[str], env_extra: dict[str, str], cpus: set[int] | None) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), **env_extra}
    if "NPROC" not in env_extra:
        env.pop("NPROC", None)
    # Pinned by the child itself, first thing (a preexec_fn would run Python between fork
    # and exec in this multithreaded process).
    pin = "" if cpus is None else f"import os; os.sched_setaffinity(0, {sorted(cpus)!r})\n"
    proc = subprocess.run([sys.executable, "-c", pin + PROGRAM, *args], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs at least two CPUs and CPU affinity")
def test_each_thread_pool_and_cpu_set_gets_its_own_entries(tmp_path):
    """XLA compiles another program for another thread pool or CPU set (its rounding can
    differ), and JAX's own key leaves both out: an entry stored with one thread must
    not serve a run with all, nor one stored unpinned a run pinned to one core. Each
    gets its own entries, and a repeat of the same setting hits them."""
    from jaxslam.runtime.compiler import compile_environment

    cache = str(tmp_path / "cache")
    one_cpu = {min(os.sched_getaffinity(0))}
    runs = {
        "one thread": _run_pinned([cache], {"NPROC": "1"}, None),
        "all threads": _run_pinned([cache], {}, None),
        "pinned": _run_pinned([cache], {}, one_cpu),
        "one thread again": _run_pinned([cache], {"NPROC": "1"}, None),
        "pinned again": _run_pinned([cache], {}, one_cpu),
    }
    for name in ("one thread", "all threads", "pinned"):
        assert runs[name]["counts"]["cache_hits"] == 0, (name, runs[name]["counts"])
    for name in ("one thread again", "pinned again"):
        assert runs[name]["counts"]["compiled"] == 0, (name, runs[name]["counts"])
    assert runs["one thread"]["result"] == runs["one thread again"]["result"]
    assert runs["pinned"]["result"] == runs["pinned again"]["result"]
    assert compile_environment().startswith(f"cpus={len(os.sched_getaffinity(0))};threads=")


def test_cli_no_cache_and_cache_dir_flags(tmp_path):
    from jaxslam.app import cli

    args = cli.build_parser().parse_args(["run", "--no-cache", "--out", str(tmp_path)])
    assert args.no_cache and args.cache_dir is None
    args = cli.build_parser().parse_args(["run", "--cache-dir", str(tmp_path / "c"), "--out", str(tmp_path)])
    assert args.cache_dir == tmp_path / "c"


@pytest.mark.slow
def test_cli_runs_identical_cold_warm_and_off(tmp_path):
    """Whole `jaxslam run`s in fresh processes: same files with the cache cold, warm and off,\nand with one XLA thread (the default at 8 particles) or all."""
    cache = tmp_path / "cache"
    outputs = {}
    for name, flags in (("cold", ["--cache-dir", str(cache)]), ("warm", ["--cache-dir", str(cache)]),
                        ("off", ["--no-cache"]), ("all threads", ["--no-cache", "--threads", "all"])):
        out = tmp_path / name
        proc = subprocess.run(
            [sys.executable, "-m", "jaxslam.app.cli", "run", "--max-steps", "20", "--particles", "8", "--no-plots",
             "--no-progress", "--out", str(out), *flags],
            capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        outputs[name] = (out / "trajectory.tum").read_bytes(), (out / "landmarks.csv").read_bytes()
        summary = json.loads((out / "summary.json").read_text())
        if name == "warm":
            assert summary["compilations"]["compiled"] == 0, summary["compilations"]
            assert summary["compilations"]["cache_hits"] > 0
        if name == "off":
            assert summary["cache_dir"] is None and summary["compilations"]["cache_hits"] == 0
        assert summary["cpus_allowed"] == len(os.sched_getaffinity(0))
        if name == "all threads":
            assert summary["xla_threads"] == {"threads": "all", "source": "argument"}
        else:
            assert summary["xla_threads"] == {"threads": 1, "source": "auto"}
    assert outputs["cold"] == outputs["warm"] == outputs["off"] == outputs["all threads"]


def test_unusable_cache_folder(tmp_path, monkeypatch, capsys):
    """An explicit folder that cannot be made is an error naming it; an unusable
    default only costs the cache (a warning), never the run."""
    from jaxslam.app import cli
    from jaxslam.runtime import cache

    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(OSError, match="cannot create the compilation cache folder"):
        cache.enable_compilation_cache(blocker / "sub")
    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    args = cli.build_parser().parse_args(["run", "--out", str(tmp_path / "o"), "--list-params"])
    args.list_params = False
    monkeypatch.setattr("jaxslam.app.cli.run_from_args", lambda _args: None)
    assert cli.cmd_run(args) == 0
    assert "running without the compilation cache" in capsys.readouterr().err
    args.cache_dir = blocker / "sub"
    with pytest.raises(cli.CliError, match="cannot create"):
        cli.cmd_run(args)


# A chunk runner (jaxslam.runtime.driver) with a tag, compiled through jaxslam.runtime.executables:
# the first process stores the lowered program, a later one loads it without tracing.
EXPORT_PROGRAM = r"""
import json, sys
from jaxslam.runtime.cache import enable_compilation_cache
enable_compilation_cache(sys.argv[1])
import jax, jax.numpy as jnp
from jaxslam.core import se2
from jaxslam.runtime.executables import compile_runner, entry_path
from jaxslam.runtime.driver import chunk_runner

def step(key, state, control, observation, params, config):
    poses, total = state
    noise = params * jax.random.normal(key, poses.shape, poses.dtype)
    poses = jax.vmap(se2.compose)(poses, noise + control)
    return (poses, total + jnp.sum(poses[:, 0] * observation)), poses.mean(0)

def carry():
    return (jnp.zeros((16, 3), jnp.float32), jnp.zeros((), jnp.float32)), jnp.array(0.05, jnp.float32)

controls = jnp.tile(jnp.array([0.1, 0.0, 0.02], jnp.float32), (8, 1))
xs = (jax.random.split(jax.random.key(5), 8), controls, jnp.linspace(0.5, 1.5, 8, dtype=jnp.float32))
valid = jnp.arange(8) < 6
# argv[2] "options": the runner carries jaxslam's XLA options (as the grid runners do)
from jaxslam.runtime.compiler import OPTIONS
options = tuple(sorted(OPTIONS.items())) if sys.argv[2:] == ["options"] else ()
runner = chunk_runner(step, "toy", None, options)
# a step outside jaxslam gets no tag (its source is not hashed); this one is named by hand
runner.jaxslam_tag = ("test-export", "v1", True)
compiled, loaded = compile_runner(runner, carry(), xs, valid)
((poses, total), _), means = compiled(carry(), xs, valid)
((poses_direct, total_direct), _), means_direct = runner(carry(), xs, valid)  # jitted, not through the exports
print(json.dumps({"loaded": loaded, "entry": str(entry_path(__import__("pathlib").Path(sys.argv[1]), runner.jaxslam_tag, (carry(), xs, valid))),
                  "result": [poses.tobytes().hex(), total.tobytes().hex(), means.tobytes().hex()],
                  "direct": [poses_direct.tobytes().hex(), total_direct.tobytes().hex(), means_direct.tobytes().hex()]}))
"""


@pytest.mark.parametrize("options", ["none", "options"])
def test_exported_chunk_runner_is_stored_loaded_and_bit_identical(tmp_path, options):
    """Cold: stored, not loaded; warm: loaded from disk; an unreadable entry is a miss
    and is replaced; every time the result equals the directly jitted runner's. Also
    for a runner with XLA compiler options (jaxslam.runtime.compiler), which JAX refuses on a
    nested jit: the export traces the runner's function instead."""
    cache = tmp_path / "cache"
    runs = []
    for _ in range(2):
        runs.append(_run_program(EXPORT_PROGRAM, [str(cache), options]))
    entry = Path(runs[0]["entry"])
    assert entry.parent == cache / "exports" and entry.exists()
    entry.write_bytes(b"truncated")
    runs.append(_run_program(EXPORT_PROGRAM, [str(cache), options]))
    assert [run["loaded"] for run in runs] == [False, True, False]
    assert entry.read_bytes() != b"truncated"
    for run in runs:
        assert run["result"] == run["direct"] == runs[0]["result"]


def test_export_entry_depends_on_source_tag_and_shapes(monkeypatch, tmp_path):
    """A stale entry is never used: the file name changes with the jaxslam sources, the
    runner's tag and the arguments' shapes and dtypes."""
    import jax.numpy as jnp

    from jaxslam.runtime import executables

    args = (jnp.zeros((4, 3), jnp.float32), jnp.zeros(2, jnp.int32))
    base = executables.entry_path(tmp_path, ("t", 1), args)
    assert base == executables.entry_path(tmp_path, ("t", 1), args)
    assert base != executables.entry_path(tmp_path, ("t", 2), args)
    assert base != executables.entry_path(tmp_path, ("t", 1), (jnp.zeros((5, 3), jnp.float32), args[1]))
    assert base != executables.entry_path(tmp_path, ("t", 1), (args[0].astype(jnp.float16), args[1]))
    assert base != executables.entry_path(tmp_path, ("t", 1), [args[0], args[1]])  # tree structure
    monkeypatch.setattr(executables, "source_digest", lambda: "an edited library")
    assert base != executables.entry_path(tmp_path, ("t", 1), args)


def test_runner_tag_only_for_library_functions():
    """Steps outside jaxslam (their source is not hashed) get no tag and are not stored."""
    from jaxslam.runtime.executables import runner_tag
    from jaxslam.grid import driver, srupf

    config = ("a config",)
    assert runner_tag(srupf.step, config, driver.summarise, True)[1:3] == (
        "jaxslam.grid.srupf:step", "jaxslam.grid.driver:summarise")
    assert runner_tag(lambda *a: a, config, None, True) is None
    assert runner_tag(srupf.step, config, lambda info: info, True) is None
    assert runner_tag(srupf.step, object(), None, True) is None  # repr holds an address


def test_compile_counter_times_tracing_lowering_and_xla_apart():
    """:class:`CompileCounter` reports tracing, lowering and XLA's compilation apart; a
    jit traced inside another's trace is counted once (the union of the spans), so
    tracing never exceeds the block's wall time."""
    import time

    import jax
    import jax.numpy as jnp

    from jaxslam.runtime.cache import CompileCounter, _covered

    assert _covered([]) == 0.0
    assert _covered([(0.0, 4.0), (1.0, 2.0), (3.0, 5.0), (7.0, 8.0)]) == pytest.approx(6.0)

    inner = jax.jit(lambda x: jnp.sin(x) * 2.0)
    started = time.perf_counter()
    with CompileCounter() as counter:
        jax.jit(lambda x: inner(x) + inner(x + 1.0))(jnp.arange(7.0)).block_until_ready()
    wall = time.perf_counter() - started
    summary = counter.as_dict()
    assert summary["compiled"] >= 1 and summary["seconds"] > 0
    assert 0 < summary["trace_s"] <= wall and 0 < summary["lower_s"] <= wall
    assert summary["trace_s"] + summary["lower_s"] + summary["seconds"] <= wall + 1e-3
