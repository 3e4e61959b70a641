r"""The XLA compiler options of jaxslam's programs, the ``jit`` that applies them, and
the number of threads XLA's CPU runtime runs them on (:func:`~jaxslam.runtime.compiler.set_threads`).

The grid filters' programs that jaxslam compiles and runs itself (the chunk runners
of :func:`jaxslam.grid.driver.run_filter`, which every CLI run, benchmark and notebook
goes through, the ``init`` program, the streaming step and the grid calibration's
objectives) are compiled with :func:`options`, through :func:`jit` (``jax.jit`` with
``compiler_options``) or :func:`jaxslam.runtime.driver.chunk_runner` (given
:func:`options_key`). Today that is two
options:

* ``xla_cpu_use_fusion_emitters = False``. XLA's CPU backend can emit the loops of
  its fused kernels in two ways: the newer MLIR "fusion emitters" (XLA's default in
  jax 0.10) or the older LLVM loop emitters. The grid filters' steps are mostly
  gathers through page tables inside ``while`` loops (scan matching), and there the
  older emitters compile and run faster, with the trajectory and the map bit for bit
  the same (``docs/design.md``, "The fixed XLA code split", has the numbers).

* ``xla_cpu_parallel_codegen_split_count = 8``: the same run whatever the thread
  count or CPU set. XLA splits the generated LLVM module into parts that
  it compiles in parallel, and with the loop emitters the split changes the machine
  code, and so the rounding, of some loops. Left to XLA, the split follows the
  thread pool: with one thread (``--threads 1``, or a process pinned to one core
  with ``taskset``) the runs are those of an unsplit module, with more those of 32
  parts. So one seed could give two runs, and the filters' chaotic loop closures
  made them two different maps. A fixed split removes the dependence: 1, 2, 8 and
  16 parts all give the one-thread program's run bit for bit, with one, two or four
  threads and pinned (32 gives the other), and 8 parts compile faster than 1 or 2.
  ``tests/test_compiler.py`` checks the bits. Code for another CPU model (other
  vector instructions) can still differ, so runs are reproducible on one kind of
  machine, not bit for bit across machines.

The landmark filters keep XLA's defaults: with this option they compile faster but do
not run faster, and their results change in float rounding, which the chaotic data
association turns into a different run; their programs with XLA's defaults give the
same bits on one and two threads.

The option is read by the CPU backend only. ``JAXSLAM_XLA_OPTIONS=xla`` in the
environment compiles with XLA's own defaults instead (read when a program is first
built in a process). An
``XLA_FLAGS`` that sets an option itself wins: :func:`options` leaves that option
out.

JAX accepts compiler options only on a top-level ``jax.jit``, so the filters' public
``init`` / ``step`` / ``run`` stay plain ``jax.jit`` functions that can be called
inside a user's own ``jit``, ``vmap`` or ``grad``; a user who runs them as the
top-level program gets XLA's defaults unless they pass the same options,
``jax.jit(f, compiler_options=jaxslam.runtime.compiler.options())`` (or use :func:`jit`).
"""

from __future__ import annotations

import os
from typing import Any

ENV_VAR = "JAXSLAM_XLA_OPTIONS"
"""``xla``: compile with XLA's default options instead of :data:`OPTIONS`."""

OPTIONS: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False, "xla_cpu_parallel_codegen_split_count": 8}
"""jaxslam's XLA options (see the module docstring)."""

__all__ = [
    "ENV_VAR", "OPTIONS", "THREADS_ENV", "auto_threads", "compile_environment", "cpus_allowed", "jit", "jit_with",
    "options", "options_key", "set_threads", "thread_pool",
]


def options() -> dict[str, Any]:
    """The compiler options jaxslam's programs are jitted with: :data:`OPTIONS`, less
    any option that ``XLA_FLAGS`` sets, or none when ``JAXSLAM_XLA_OPTIONS=xla``."""
    choice = os.environ.get(ENV_VAR, "").strip().lower()
    if choice == "xla":
        return {}
    if choice not in ("", "jaxslam"):
        raise ValueError(f"{ENV_VAR} must be 'jaxslam' (the default) or 'xla', got {choice!r}")
    flags = os.environ.get("XLA_FLAGS", "")
    return {name: value for name, value in OPTIONS.items() if f"--{name}" not in flags}


def options_key() -> tuple:
    """:func:`options` as sorted ``(name, value)`` pairs: hashable, the form in which
    :func:`jaxslam.runtime.driver.chunk_runner` takes them (a cache key)."""
    return tuple(sorted(options().items()))


def jit_with(fun, compiler_options: dict[str, Any] | None, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiled with exactly ``compiler_options`` (none when
    empty), which are kept on the result as ``jaxslam_compiler_options`` (a program
    loaded from disk is compiled with them, :mod:`jaxslam.runtime.executables`)."""
    import jax

    chosen = dict(compiler_options or {})
    jitted = jax.jit(fun, compiler_options=chosen or None, **kwargs)
    jitted.jaxslam_compiler_options = chosen
    return jitted


def jit(fun=None, /, **kwargs):
    """``jax.jit`` with jaxslam's compiler options (:func:`options`) and any given
    ``compiler_options`` on top; usable as a decorator, with or without keyword
    arguments (``@jit(static_argnames=...)``)."""
    if fun is None:
        return lambda f: jit(f, **kwargs)
    return jit_with(fun, {**options(), **(kwargs.pop("compiler_options", None) or {})}, **kwargs)


THREADS_ENV = "JAXSLAM_THREADS"
"""Threads of XLA's CPU runtime for a run, a count or ``all`` (XLA's default, every
core); unset: :func:`auto_threads`. An explicit ``threads`` argument wins."""

SINGLE_THREAD_MAX_PARTICLES = {"erb-upf": 300, "rb-upf": 300}
"""Filters that :func:`auto_threads` runs on one XLA thread, up to how many particles."""


def auto_threads(algorithm: str, particles: int) -> int | None:
    """The thread count jaxslam picks: one for the filters and particle counts of
    :data:`SINGLE_THREAD_MAX_PARTICLES` (the landmark filters up to 300 particles),
    else ``None`` (XLA's default: every core).

    At these sizes a landmark filter's step is many small kernels (about a thousand
    per scan, each over a few hundred to a few thousand numbers), and XLA's CPU
    runtime spreads independent kernels and the iterations of each over its threads;
    the hand-overs cost more than a second core gives, and the results are the same
    bit for bit (``docs/reproducibility.md``, "Threads"). From about a thousand
    particles the kernels are large enough for more threads to pay.

    The grid filters keep every core: their kernels depend on the log as much as on
    the particle count (long rays and large maps make bigger kernels), so no particle
    count picks the faster setting for every log.
    """
    limit = SINGLE_THREAD_MAX_PARTICLES.get(algorithm)
    return 1 if limit is not None and particles <= limit else None


def _parse_threads(value: Any, source: str) -> int | None:
    text = str(value).strip().lower()
    if text == "all" or (text == "0" and source == "NPROC"):
        return None
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 1:
        raise ValueError(f"{source} must be a positive thread count or 'all' for every core, got {value!r}")
    return count


_STARTED_WITH: dict[str, int | None] | None = None
"""The pool :func:`set_threads` started XLA's backend with (``threads``: None for all)."""


def cpus_allowed() -> int:
    """How many CPUs this process may run on (its affinity, as ``taskset`` sets it; the
    CPU count where the platform has no affinity). XLA's CPU compiler builds a
    different program for a different count (:func:`compile_environment`), and the
    rounding can differ. Runs recorded with it can be compared like for like."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def thread_pool() -> int | None:
    """The size of XLA's CPU thread pool in this process (None: XLA's default, every
    core): the count :func:`set_threads` started the backend with, else the ``NPROC``
    XLA reads when its backend starts."""
    if _STARTED_WITH is not None:
        return _STARTED_WITH["threads"]
    current = os.environ.get("NPROC", "").strip()
    return int(current) if current.isdigit() and int(current) > 0 else None


def compile_environment() -> str:
    """What XLA's CPU compiler builds a program for besides its text and options: the
    CPUs this process may use (:func:`cpus_allowed`) and XLA's thread pool
    (:func:`thread_pool`). Either can change the compiled program (XLA splits the
    generated code by the parallelism it sees) and so, with the loop emitters, its
    rounding: under XLA's own split, a grid run compiled with one thread (``--threads
    1``, or pinned with ``taskset -c 0``) can differ from one compiled with two.
    jaxslam's grid programs fix the split
    (:data:`OPTIONS`), but programs compiled with other options (the landmark filters,
    a user's own) do not. JAX's cache key includes neither, so :mod:`jaxslam.runtime.cache`
    adds this string to it."""
    pool = thread_pool()
    return f"cpus={cpus_allowed()};threads={'all' if pool is None else pool}"


def set_threads(threads: int | str | None, algorithm: str, particles: int) -> dict[str, Any]:
    """Size XLA's CPU thread pool for this process before its CPU backend starts.

    ``threads``: a count, ``"all"`` for XLA's default (every core; 0 is refused), or ``None``: then
    ``$JAXSLAM_THREADS``, else a ``NPROC`` the user set, else :func:`auto_threads` of
    ``algorithm`` (a ``jaxslam run`` name: ``srupf-gm``, ``erb-upf``, ...) and
    ``particles``.
    XLA reads the pool size from the environment variable ``NPROC`` once, when the
    CPU backend starts (its ``DefaultThreadPoolSize``), so this sets ``NPROC``, starts
    the backend (``jax.devices()``) and puts ``NPROC`` back as it was: the processes
    this one starts later do not inherit the choice. Once any JAX computation has run
    in the process it has no effect: then nothing changes and the returned record says
    so. The pool size is part of the compiled program's cache key
    (:func:`compile_environment`): a run with another count compiles (and caches) its
    programs once.

    Returns:
        ``{"threads": count or "all", "source": ...}`` for ``summary.json``; the source
        is ``argument``, ``JAXSLAM_THREADS``, ``NPROC``, ``auto`` or ``backend already
        started`` (with the pool XLA already has, ``NPROC`` or ``all``).
    """
    from jax._src import xla_bridge

    def record(count, source):
        return {"threads": "all" if count is None else count, "source": source}

    global _STARTED_WITH
    if threads is not None:
        _parse_threads(threads, "threads")  # a bad count is refused even where it could not act
    if xla_bridge.backends_are_initialized():
        return record(thread_pool(), "backend already started")
    if threads is not None:
        count, source = _parse_threads(threads, "threads"), "argument"
    elif os.environ.get(THREADS_ENV, "").strip():
        count, source = _parse_threads(os.environ[THREADS_ENV], THREADS_ENV), THREADS_ENV
    elif os.environ.get("NPROC", "").strip():
        return record(_parse_threads(os.environ["NPROC"], "NPROC"), "NPROC")
    else:
        count, source = auto_threads(algorithm, particles), "auto"
    import jax

    previous = os.environ.get("NPROC")
    if count is None:
        os.environ.pop("NPROC", None)
    else:
        os.environ["NPROC"] = str(count)
    try:
        jax.devices()  # the CPU backend starts now and reads NPROC
    finally:
        if previous is None:
            os.environ.pop("NPROC", None)
        else:
            os.environ["NPROC"] = previous
    _STARTED_WITH = {"threads": count}
    return record(count, source)
