"""The runtime under every filter: XLA compiler options and thread counts, the
compilation cache and exported executables, chunked scans with progress and
checkpoints of their state, and the host-side PRNG keys. It imports no filter and
nothing of the application."""

__all__ = ["cache", "checkpoint", "compiler", "driver", "executables", "keys", "progress"]
