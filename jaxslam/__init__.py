"""jaxslam: batched JAX particle filters for SLAM.

Every particle and every sigma point is a row of a batched array, pushed through
``jit``/``vmap``/``lax.scan`` kernels. See ``README.md`` for the algorithms and the
papers they implement.
"""

__version__ = "0.1.0"
