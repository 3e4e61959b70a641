"""JAX's persistent compilation cache for jaxslam, on by default for the command line.

XLA compiles every jitted program once per process; the filters' scanned programs
take seconds. JAX can keep the compiled executables on disk and load them in the next
process instead (the "persistent compilation cache"); a second ``jaxslam run``, a
notebook re-run or a CI job with a kept cache folder then compiles nothing new.

Where the cache lives, first match wins:

1. the ``cache_dir`` argument of :func:`enable_compilation_cache` (the CLI's
   ``--cache-dir DIR``; ``--no-cache`` passes ``"off"``);
2. the environment variable ``JAXSLAM_CACHE_DIR`` (``off``, ``none``, ``0``,
   ``false`` or an empty value disable it);
3. ``$XDG_CACHE_HOME/jaxslam/jax``, or ``~/.cache/jaxslam/jax`` when
   ``XDG_CACHE_HOME`` is not set.

Every program is cached, however small or quick to compile
(``jax_persistent_cache_min_compile_time_secs = 0`` and
``jax_persistent_cache_min_entry_size_bytes = -1``): a run compiles about a hundred
small programs besides the filter's scan, and together they cost seconds. JAX keys
each entry by the program text, the compile options, the JAX/XLA versions and the
device; jaxslam adds the CPUs the process may use and XLA's thread pool
(:func:`jaxslam.runtime.compiler.compile_environment`, through JAX's ``custom_hook`` of its
cache key), which change what XLA's CPU compiler builds but which JAX's key leaves out.
So a stale entry is never used, and a cached executable computes bit for bit what a
freshly compiled one computes in the same process (``tests/test_cache.py`` checks
both: a run with one thread after one with two, or pinned to one core after an
unpinned one, compiles its own programs).

The filters' chunk runners and the grid ``init`` are also kept there already traced
and lowered (subfolder ``exports``, :mod:`jaxslam.runtime.executables`), so that a warm run
skips tracing them too; those entries are keyed by the jaxslam sources as well.

The cache is trusted code: do not point it at a folder that others can write to.

Library users call :func:`enable_compilation_cache` once, before the first
compilation (JAX reads the folder when it first compiles)::

    from jaxslam.runtime.cache import enable_compilation_cache
    enable_compilation_cache()            # or enable_compilation_cache("/scratch/jax")

:class:`CompileCounter` counts what was compiled and what came from the cache, from
``jax.monitoring`` events.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

__all__ = [
    "CompileCounter",
    "DISABLED",
    "ENV_VAR",
    "default_cache_dir",
    "enable_compilation_cache",
    "resolve_cache_dir",
]

ENV_VAR = "JAXSLAM_CACHE_DIR"
DISABLED = frozenset({"off", "none", "0", "false", "no", "disable", "disabled"})
"""Values of ``JAXSLAM_CACHE_DIR`` (or ``cache_dir``) that turn the cache off."""

_BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
_TRACE = "/jax/core/compile/jaxpr_trace_duration"
_LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_CACHE_HITS = "/jax/compilation_cache/cache_hits"


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/jaxslam/jax``, or ``~/.cache/jaxslam/jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or ""
    root = Path(base).expanduser() if base.strip() else Path.home() / ".cache"
    return root / "jaxslam" / "jax"


def resolve_cache_dir(cache_dir: os.PathLike | str | None = None) -> Path | None:
    """The cache folder to use, or None when the cache is off (see the module docstring)."""
    if cache_dir is None:
        cache_dir = os.environ.get(ENV_VAR)
        if cache_dir is None:
            return default_cache_dir()
    text = str(cache_dir).strip()
    if not text or text.lower() in DISABLED:
        return None
    return Path(text).expanduser()


def enable_compilation_cache(cache_dir: os.PathLike | str | None = None) -> Path | None:
    """Point JAX's persistent compilation cache at the jaxslam cache folder.

    Call it before the first compilation of the process. Calling it again with
    another folder re-points the cache (JAX's in-process state is reset).

    Args:
        cache_dir: a folder, ``"off"`` to disable, or None for the environment
            variable ``JAXSLAM_CACHE_DIR`` and then the per-user default.

    Returns:
        The folder in use (created if missing), or None if the cache is off.

    Raises:
        OSError: the folder cannot be created (the message names it).
    """
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    path = resolve_cache_dir(cache_dir)
    current = jax.config.jax_compilation_cache_dir
    if path is None:
        if current is not None:
            jax.config.update("jax_compilation_cache_dir", None)
            compilation_cache.reset_cache()
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OSError(
            f"cannot create the compilation cache folder {str(path)!r} ({error.strerror or error}); "
            f"set {ENV_VAR} to another folder or to 'off'"
        ) from error
    _key_the_compile_environment()
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    if current != str(path):
        jax.config.update("jax_compilation_cache_dir", str(path))
        compilation_cache.reset_cache()
    return path


def _key_the_compile_environment() -> None:
    """Add :func:`jaxslam.runtime.compiler.compile_environment` to every persistent-cache key
    (JAX's ``cache_key.custom_hook``, called each time a key is made, so a thread pool
    sized after the cache was turned on is keyed as well). Once per process."""
    from jax._src import cache_key

    from jaxslam.runtime.compiler import compile_environment

    previous = getattr(cache_key, "custom_hook", None)
    if previous is None:  # every JAX this project supports (>= 0.4.30) has it
        raise RuntimeError("this JAX has no compilation-cache key hook; run with JAXSLAM_CACHE_DIR=off")
    if getattr(previous, "jaxslam", False):
        return

    def custom_hook() -> str:
        return previous() + "|jaxslam:" + compile_environment()

    custom_hook.jaxslam = True
    cache_key.custom_hook = custom_hook


class CompileCounter:
    """Counts XLA compilations in a ``with`` block, from ``jax.monitoring`` events.

    Attributes:
        requests: programs that went to the backend (compiled or loaded from the cache).
        cache_hits: of those, loaded from the persistent cache.
        seconds: time spent in those requests (XLA compiling, or loading).
        trace_s: time spent tracing Python functions to jaxprs (a jit traced inside
            another's trace counted once).
        lower_s: time spent lowering jaxprs to StableHLO.
    """

    def __init__(self) -> None:
        self.requests = 0
        self.cache_hits = 0
        self.seconds = 0.0
        self._spans: dict[str, list[tuple[float, float]]] = {_TRACE: [], _LOWER: []}

    @property
    def trace_s(self) -> float:
        return _covered(self._spans[_TRACE])

    @property
    def lower_s(self) -> float:
        return _covered(self._spans[_LOWER])

    @property
    def compiled(self) -> int:
        """Programs XLA really compiled (requests that did not come from the cache)."""
        return self.requests - self.cache_hits

    def _on_event(self, event: str, **_kwargs) -> None:
        if event == _CACHE_HITS:
            self.cache_hits += 1

    def _on_duration(self, event: str, duration: float, **_kwargs) -> None:
        if event == _BACKEND_COMPILE:
            self.requests += 1
            self.seconds += duration
        elif event in self._spans:  # reported as it ends: the span is [now - duration, now]
            now = time.perf_counter()
            self._spans[event].append((now - duration, now))

    def __enter__(self) -> CompileCounter:
        import jax.monitoring

        jax.monitoring.register_event_listener(self._on_event)
        jax.monitoring.register_event_duration_secs_listener(self._on_duration)
        return self

    def __exit__(self, *exc) -> None:
        import jax.monitoring

        jax.monitoring.unregister_event_listener(self._on_event)
        jax.monitoring.unregister_event_duration_listener(self._on_duration)

    def as_dict(self) -> dict[str, float | int]:
        """``{"programs", "compiled", "cache_hits", "seconds", "trace_s", "lower_s"}`` for
        a summary (``seconds``: XLA's compilation or the cache's loads)."""
        return {"programs": self.requests, "compiled": self.compiled,
                "cache_hits": self.cache_hits, "seconds": round(self.seconds, 3),
                "trace_s": round(self.trace_s, 3), "lower_s": round(self.lower_s, 3)}


def _covered(spans: list[tuple[float, float]]) -> float:
    """The length of the union of ``(start, end)`` spans (nested traces counted once)."""
    total, reach = 0.0, float("-inf")
    for start, end in sorted(spans):
        if end > reach:
            total += end - max(start, reach)
            reach = end
    return total
