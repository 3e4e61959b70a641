r"""The XLA compiler options of jaxslam's programs, and the ``jit`` that applies them.

The grid filters' programs that jaxslam compiles and runs itself (the chunk runners
of :func:`jaxslam.grid.driver.run_filter`, which every CLI run, benchmark and notebook
goes through, the ``init`` program, the streaming step and the grid calibration's
objectives) are compiled with :func:`options`, through :func:`jit` (``jax.jit`` with
``compiler_options``) or :func:`jaxslam.driver.chunk_runner`. Today that is one
option:

* ``xla_cpu_use_fusion_emitters = False``. XLA's CPU backend can emit the loops of
  its fused kernels in two ways: the newer MLIR "fusion emitters" (XLA's default in
  jax 0.10) or the older LLVM loop emitters. The grid filters' steps are mostly
  gathers through page tables inside ``while`` loops (scan matching), and there the
  older emitters win on both counts. Measured on the whole Intel log, 30 particles,
  one process per variant pinned to one core of a 2-core Xeon VM, compilation cache
  off (the README has the run): ``srupf-gm`` filter loop 38.8 s -> 21.2 s and XLA
  compilation 17.9 s -> 10.0 s, the GMapping-style filter 34.1 s -> 20.7 s and
  13.1 s -> 8.6 s, with the trajectory and the map bit for bit the same.

  One caveat, measured: with these emitters the result can depend on the number of
  threads XLA uses. XLA splits the generated LLVM module into parts compiled in
  parallel, one per thread, and with the loop emitters the split changes the machine
  code of some loops. Intel, ``srupf-gm``: at 30 particles one and two threads give
  the same result (and the same as XLA's defaults); at 100 particles two threads give
  another run than one thread, whereas XLA's defaults gave the one-thread result on
  both. ``xla_cpu_parallel_codegen_split_count=1`` (in ``XLA_FLAGS``) removes the
  dependence, at 3-4 s more compilation on two cores and the same run time. Code for
  another CPU model (other vector instructions) can differ in any case, so runs are
  reproducible on one machine, not bit for bit across machines.

The landmark filters keep XLA's defaults: with this option they compile about 25 %
faster but do not run faster (Victoria Park, ERB, 100 particles: 4.6 s either way
for 2000 steps), and their results change in float rounding, which the chaotic
association turns into a different run (GPS error 2.2 / 5.1 / 4.5 m for seeds 0-2
with XLA's defaults, 7.5 / 2.9 / 4.6 m with the option).

The option is read by the CPU backend only. ``JAXSLAM_XLA_OPTIONS=xla`` in the
environment compiles with XLA's own defaults instead (read when a program is first
built in a process). An
``XLA_FLAGS`` that sets an option itself wins: :func:`options` leaves that option
out.

JAX accepts compiler options only on a top-level ``jax.jit``, so the filters' public
``init`` / ``step`` / ``run`` stay plain ``jax.jit`` functions that can be called
inside a user's own ``jit``, ``vmap`` or ``grad``; a user who runs them as the
top-level program gets XLA's defaults unless they pass the same options,
``jax.jit(f, compiler_options=jaxslam.compiler.options())`` (or use :func:`jit`).
"""

from __future__ import annotations

import os
from typing import Any

ENV_VAR = "JAXSLAM_XLA_OPTIONS"
"""``xla``: compile with XLA's default options instead of :data:`OPTIONS`."""

OPTIONS: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False}
"""jaxslam's XLA options (see the module docstring)."""

__all__ = ["ENV_VAR", "OPTIONS", "jit", "jit_with", "options"]


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


def jit_with(fun, compiler_options: dict[str, Any] | None, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiled with exactly ``compiler_options`` (none when
    empty), which are kept on the result as ``jaxslam_compiler_options`` (a program
    loaded from disk is compiled with them, :mod:`jaxslam.executables`)."""
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
