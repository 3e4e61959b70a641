"""The application's user-facing error: a problem with a command's arguments or its
output folder, which the command line reports in one line with exit status 2."""

from __future__ import annotations

__all__ = ["RunError"]


class RunError(ValueError):
    """A user-facing problem with a run's arguments (the CLI exits with status 2)."""
