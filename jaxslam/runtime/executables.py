"""Traced and lowered chunk runners kept on disk, so that a warm run does not trace.

JAX's persistent compilation cache (:mod:`jaxslam.runtime.cache`) saves XLA's work, but each
process still traces the filter's step in Python and lowers it to StableHLO before it
can look the program up: seconds for the grid filters (most of a warm run's
``compile_s``), paid by every run. This
module stores the lowered chunk runner (a :class:`jax.export.Exported`, pickled) in the
subfolder ``exports`` of the compilation-cache folder; a later process loads it, wraps
it in ``jax.jit`` (the carry donated as before) and gets XLA's executable from the
compilation cache, without tracing the step. The result is bit for bit that of the
directly jitted runner (``tests/test_cache.py``).

Why not the compiled executable itself: on the CPU backend
:mod:`jax.experimental.serialize_executable` round-trips it, but running the loaded
grid runner fails (``NOT_FOUND: Function wrapped_broadcast.1 not found``, jax 0.10.2).
Why pickle and not ``Exported.serialize``: the latter needs the ``flatbuffers``
package; the pickle leaves out the VJP rule (a local function, not needed to run).

An entry is used only when everything that determines the program is equal; its file
name is the SHA-256 of

* the bytes of every ``.py`` file of the installed ``jaxslam`` package (any edit to
  the library invalidates every entry);
* the versions of ``jax`` and ``jaxlib``, the backend platform and its version, the
  devices' kinds, JAX's trace context (x64, matmul precision, ...) and ``XLA_FLAGS``;
* the runner's tag: the step function and the summary named by their module and
  qualified name (see :func:`function_name`), the type and ``repr`` of the static
  config, whether the carry is donated;
* the tree structure, shapes, dtypes and weak types of the arguments.

A runner whose step is not a named ``jaxslam`` function (a lambda, a closure built by
a caller, user code) gets no tag and is never stored: its source is not hashed. An
entry that cannot be read (truncated, from another build) is ignored and replaced.
Like the compilation cache, the folder holds executable code: keep it private.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pickle
import sys
from pathlib import Path

__all__ = ["compile_runner", "function_name", "module_function", "runner_tag", "source_digest"]

SUBFOLDER = "exports"


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 of the paths and bytes of every ``.py`` file of the ``jaxslam`` package."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()


def function_name(fn) -> str | None:
    """``"module:qualified name"`` of a ``jaxslam`` function, or None.

    The name is ``fn.__module__`` and ``fn.__qualname__``, accepted only when looking it
    up again (the module in ``sys.modules``, then the attributes along the qualified
    name) gives ``fn`` itself: a function defined inside another (``<locals>``), a
    lambda, a copy under a borrowed name or anything outside ``jaxslam`` has none. A
    ``functools.partial`` is named by its function and the ``repr`` of its bound
    arguments, when those are named and print no address. Nothing here iterates
    ``sys.modules`` or a module's namespace, which another thread may be importing
    into (the plotting prefetch, :func:`jaxslam.app.outputs.prefetch_plotting`).
    """
    if fn is None:
        return "None"
    if isinstance(fn, functools.partial):
        inner = function_name(fn.func)
        if inner is None or inner == "None":
            return None
        bound = [repr(arg) for arg in fn.args] + [f"{key}={value!r}" for key, value in fn.keywords.items()]
        if any(" at 0x" in text for text in bound):
            return None
        return f"functools.partial({', '.join([inner, *bound])})"
    module_name = getattr(fn, "__module__", None)
    qualname = getattr(fn, "__qualname__", None)
    if not isinstance(module_name, str) or not isinstance(qualname, str) or "<" in qualname:
        return None
    if module_name != "jaxslam" and not module_name.startswith("jaxslam."):
        return None
    value = sys.modules.get(module_name)
    for attribute in qualname.split("."):
        value = getattr(value, attribute, None)
    return f"{module_name}:{qualname}" if value is fn and value is not None else None


def module_function(fn, module: str, name: str):
    """``fn``, made by a factory (a decorator) and kept as ``module``'s attribute
    ``name``, renamed so that :func:`function_name` finds it there: its
    ``__module__``, ``__qualname__`` and ``__name__`` set. Returns ``fn``."""
    fn.__module__, fn.__qualname__, fn.__name__ = module, name, name
    return fn


def runner_tag(step_fn, config, summary, donate: bool, kind: str = "chunk_runner") -> tuple | None:
    """What identifies a chunk runner (or another ``kind`` of program made of ``step_fn``
    and a static ``config``) besides its arguments, or None if it cannot be stored (a
    step or summary outside ``jaxslam``, a config whose repr holds an address). The
    last element says whether the first argument is donated."""
    step_name, summary_name = function_name(step_fn), function_name(summary)
    text = repr(config)
    if step_name is None or summary_name is None or " at 0x" in text:
        return None
    config_type = f"{type(config).__module__}.{type(config).__qualname__}"
    return (kind, step_name, summary_name, config_type, text, bool(donate))


def _environment() -> tuple:
    import jax
    import jaxlib
    from jax._src import config as jax_config

    backend = jax.devices()[0].client
    return (
        jax.__version__, jaxlib.__version__, backend.platform, backend.platform_version,
        tuple(device.device_kind for device in jax.devices()),
        _stable(jax_config.trace_context()), os.environ.get("XLA_FLAGS", ""),
    )


def _stable(context) -> str:
    """``repr`` of JAX's trace context with objects that print their address (the empty
    axis environment outside a trace) named by their type."""
    items = context if isinstance(context, tuple) else (context,)
    return repr(tuple(type(item).__qualname__ if " at 0x" in repr(item) else item for item in items))


def _arguments(args) -> tuple:
    import jax

    leaves, treedef = jax.tree_util.tree_flatten(args)
    avals = tuple(
        (tuple(leaf.shape), str(leaf.dtype), bool(getattr(leaf, "weak_type", False)))
        for leaf in map(jax.typeof, leaves)
    )
    return (str(treedef), avals)


def entry_path(folder: Path, tag: tuple, args) -> Path:
    """The file of the runner ``tag`` compiled for ``args`` (see the module docstring)."""
    key = repr((source_digest(), _environment(), tag, _arguments(args)))
    return folder / SUBFOLDER / (hashlib.sha256(key.encode()).hexdigest() + ".pkl")


def compile_runner(runner, *args):
    """``runner.lower(*args).compile()``, kept per argument shapes on ``runner`` for the
    rest of the process, and with the traced and lowered program loaded from or stored
    in the exports folder when the compilation cache is on and ``runner`` has a
    ``jaxslam_tag``.

    Returns:
        ``(compiled, loaded)``: a callable with ``runner``'s signature and whether it
        was not traced here (loaded from disk, or compiled earlier in this process).
    """
    import jax

    tag = getattr(runner, "jaxslam_tag", None)
    folder = jax.config.jax_compilation_cache_dir
    memo = runner.__dict__.setdefault("jaxslam_compiled", {})
    key = (folder, _arguments(args))
    if key in memo:
        return memo[key], True
    if tag is None or folder is None:
        memo[key], loaded = runner.lower(*args).compile(), False
    else:
        leaves, in_tree = jax.tree_util.tree_flatten(args)
        memo[key], loaded = _compile(runner, tag, entry_path(Path(folder), tag, args), args, leaves, in_tree)
    return memo[key], loaded


def _compile(runner, tag, path: Path, args, leaves, in_tree):
    import jax

    exported = out_tree = None
    if path.exists():
        try:
            exported, out_tree = pickle.loads(path.read_bytes())
        except Exception:  # noqa: BLE001 - an unreadable entry is only a cache miss
            exported = None
    loaded = exported is not None
    if not loaded:
        shapes = {}
        # The jitted runner's own function: JAX refuses a nested jit that carries
        # compiler options (jaxslam.runtime.compiler), and the program is the same.
        function = getattr(runner, "__wrapped__", runner)

        def flat(*flat_args):
            outputs = function(*jax.tree_util.tree_unflatten(in_tree, flat_args))
            flat_outputs, shapes["out_tree"] = jax.tree_util.tree_flatten(outputs)
            return flat_outputs

        try:
            exported = jax.export.export(jax.jit(flat))(*leaves)
            out_tree = shapes["out_tree"]
            # Pickled rather than ``Exported.serialize`` (which needs ``flatbuffers``);
            # the VJP rule is a local function and not needed to run the program.
            _store(path, pickle.dumps((dataclasses.replace(exported, _get_vjp=None), out_tree)))
        except (ValueError, NotImplementedError, TypeError, pickle.PicklingError):
            return runner.lower(*args).compile(), False
    donate = tuple(range(len(jax.tree_util.tree_leaves(args[0])))) if tag[-1] else ()
    try:
        options = getattr(runner, "jaxslam_compiler_options", None) or None
        compiled = jax.jit(exported.call, donate_argnums=donate, compiler_options=options).lower(*leaves).compile()
    except Exception:  # noqa: BLE001 - a stored program that does not fit is only a miss
        if not loaded:
            raise
        return runner.lower(*args).compile(), False

    def call(*call_args):
        return jax.tree_util.tree_unflatten(out_tree, compiled(*jax.tree_util.tree_leaves(call_args)))

    return call, loaded


def _store(path: Path, blob: bytes) -> None:
    """Write ``blob`` to ``path`` atomically; a read-only folder only means no storing."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        partial.write_bytes(blob)
        os.replace(partial, path)
    except OSError:
        pass
