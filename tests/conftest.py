"""Shared test configuration.

float64 is enabled for the test process so that kernels can be checked at double
precision against NumPy/SciPy/filterpy references; the library itself never sets it
and follows the dtype of its inputs, so tests that want float32 pass float32 arrays
(see the ``dtype`` fixture).
"""

import os

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

jax.config.update("jax_enable_x64", True)

# The default suite is reproducible: hypothesis draws the same examples every run.
# HYPOTHESIS_PROFILE=explore searches new random examples (for local bug hunting).
settings.register_profile("default", derandomize=True, deadline=None)
settings.register_profile("explore", derandomize=False, deadline=None, max_examples=500)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return request.param

