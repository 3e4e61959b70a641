"""Ctrl-C on the command line: one line, exit status 130, at any moment.

Python turns SIGINT into a ``KeyboardInterrupt`` raised wherever the main thread runs
Python next, which can be inside a garbage-collection callback (JAX registers one;
there the exception is only printed as ignored and the run goes on to exit 0) or
while XLA's threads are still compiling, and the interpreter's teardown that follows
the exception then runs under them. :func:`exit_on_interrupt` replaces that with a
handler that runs in the main thread between two Python instructions, so never inside
XLA's compilation or a running program (they return first): it runs the callbacks
registered with :func:`on_interrupt` (a run marks its ``run.json`` interrupted),
flushes the standard streams, writes ``jaxslam COMMAND: interrupted`` and ends the
process with :func:`os._exit` (status 130), tearing nothing down.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator

__all__ = ["exit_on_interrupt", "on_interrupt"]

_callbacks: list[Callable[[], None]] = []


@contextlib.contextmanager
def on_interrupt(callback: Callable[[], None]) -> Iterator[None]:
    """Run ``callback`` (quick, must not raise) if the process is interrupted inside
    the ``with`` block while :func:`exit_on_interrupt` is in effect."""
    _callbacks.append(callback)
    try:
        yield
    finally:
        _callbacks.remove(callback)


def _progress_bar_open() -> bool:
    """Whether a ``tqdm`` bar (:class:`jaxslam.runtime.progress.ProgressBar`) is on
    screen, its line unfinished."""
    bar_type = getattr(sys.modules.get("tqdm.std"), "tqdm", None)
    return bool(getattr(bar_type, "_instances", ()))


@contextlib.contextmanager
def exit_on_interrupt(command: str | None) -> Iterator[None]:
    """Inside the block, SIGINT ends the process with status 130 and one line,
    ``jaxslam COMMAND: interrupted`` (see the module docstring); only in the main
    thread, where signals are delivered."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupted(signum, frame):
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C while finishing
        for callback in reversed(_callbacks):
            try:
                callback()
            except Exception:  # noqa: BLE001 - the exit must happen
                pass
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, RuntimeError):  # RuntimeError: a write under way
                pass
        fresh_line = "\n" if _progress_bar_open() else ""  # not after the bar on its line
        os.write(2, f"{fresh_line}jaxslam{' ' + command if command else ''}: interrupted\n".encode())
        os._exit(130)

    previous = signal.signal(signal.SIGINT, interrupted)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
