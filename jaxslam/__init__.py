"""jaxslam: batched JAX particle filters for SLAM.

Every particle and every sigma point is a row of a batched array, pushed through
``jit``/``vmap``/``lax.scan`` kernels. See ``README.md`` for the algorithms and the
papers they implement.
"""

__version__ = "0.1.0"

_LAZY = {"mcl": ("jaxslam.localization.mcl", "mcl"), "load_map": ("jaxslam.grid.mapfile", "load_map")}


def __getattr__(name):
    """``jaxslam.mcl`` and ``jaxslam.load_map``, imported on first use (``import jaxslam``
    stays free of JAX)."""
    if name in _LAZY:
        import importlib

        module, attribute = _LAZY[name]
        return getattr(importlib.import_module(module), attribute)
    raise AttributeError(f"module 'jaxslam' has no attribute {name!r}")
