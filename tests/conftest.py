"""Shared test configuration.

float64 is enabled for the test process so that kernels can be checked at double
precision against NumPy/SciPy/filterpy references; the library itself never sets it
and follows the dtype of its inputs, so tests that want float32 pass float32 arrays
(see the ``dtype`` fixture).
"""

import os

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
# Tests that call the CLI in-process would otherwise switch the whole pytest process
# onto the per-user persistent compilation cache (shared with every run on the
# machine); one full-suite run aborted inside XLA while compiling-and-writing to it.
# The cache's own tests set their folders explicitly (in subprocesses).
os.environ.setdefault("JAXSLAM_CACHE_DIR", "off")

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


@pytest.fixture(autouse=True, scope="module")
def _fresh_jax_per_module():
    """After each test module: no persistent compilation cache left switched on, and
    JAX's in-memory caches dropped. The full suite in one process had aborted inside
    XLA while compiling-and-writing to a cache that an earlier module had switched on
    (JAX memoises whether the cache is used until ``reset_cache``), and it keeps every
    compiled program of every module alive otherwise."""
    yield
    from jax.experimental.compilation_cache import compilation_cache

    if jax.config.jax_compilation_cache_dir is not None:
        jax.config.update("jax_compilation_cache_dir", None)
    compilation_cache.reset_cache()
    jax.clear_caches()


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return request.param



# A short stretch of the Intel log and one grid SLAM run on it, shared by the ROS bag
# tests (tests/datasets/test_rosbag.py) and the streaming tests (tests/grid/test_stream.py)
# so that the default suite compiles that run once.
INTEL_SEGMENT = 300
INTEL_GRID_OPTIONS = dict(particles=4, seed=3, max_keyframes=6, progress=False)


@pytest.fixture(scope="session")
def intel_segment():
    import dataclasses

    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.datasets.paths import DatasetNotFoundError

    try:
        log = load_dataset_log("intel")
    except DatasetNotFoundError as error:
        pytest.skip(str(error))
    changes = {}
    for field in dataclasses.fields(log):
        value = getattr(log, field.name)
        if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == log.num_scans:
            changes[field.name] = value[:INTEL_SEGMENT]
    return dataclasses.replace(log, **changes)


@pytest.fixture(scope="session")
def intel_grid_reference(intel_segment):
    """``run_grid_slam`` on the segment. Named "intel" (from its path), the run takes
    Intel's keyframe rule; so do runs on bags whose files are named intel.*."""
    from jaxslam.grid.experiment import run_grid_slam

    return run_grid_slam(intel_segment, **INTEL_GRID_OPTIONS)


# Notebooks that are experiments rather than walkthroughs: several filters, particle
# counts and seeds each (about 2-4 minutes apiece on a 2-core CPU). nbmake collects
# them with the rest; they join the ``slow`` runs (``python -m pytest -m slow``).
SLOW_NOTEBOOKS = {"grid_particle_sweep.ipynb", "landmark_particle_sweep.ipynb"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.suffix == ".ipynb" and item.path.name in SLOW_NOTEBOOKS:
            item.add_marker(pytest.mark.slow)
