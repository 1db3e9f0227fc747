import os
import tempfile

# One persistent compilation cache for the test workers, the notebook kernels they start and the CLI runs inside
# them: identical programs compile once per run instead of once per process. A cache only: a cold one works too.
_cache = os.path.join(tempfile.gettempdir(), f"beamdrop-tests-xla-{os.getuid()}")
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _cache)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("BEAMDROP_CACHE_DIR", _cache)

import jax  # noqa: E402

# Accuracy claims are made in float64; tests that exercise float32 use `jax.enable_x64(False)` locally.
jax.config.update("jax_enable_x64", True)

# The longest tests (30 s to 100 s each on 2 cores, mostly compiling) start first, so that the two test workers
# share them instead of one finishing the run alone.
_LONGEST = (
    "test_cli.py::test_bench_tiny",
    "test_notebooks.py::",
    "test_montecarlo.py::test_chunks_and_devices",
    "test_cli.py::test_montecarlo_and_optimize",
    "test_montecarlo.py::test_default_numerics_within_one_percent",
    "test_gradients.py::test_diffrax_gradient_equals_closed_form",
    "test_gradients.py::test_optimizer_matches_grid_search",
    "test_clatter.py::test_gradients_through_impact_times",
    "test_beam_ends.py::test_superposed_montecarlo_on_an_asymmetric_board",
    "test_plate.py::test_mount_",
)


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: not any(name in item.nodeid for name in _LONGEST))
