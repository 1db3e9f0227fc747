import os
import subprocess
import sys
import tempfile

import pytest

# One persistent compilation cache for the test workers, the notebook kernels they start and the CLI runs inside
# them: identical programs compile once per run instead of once per process. A cache only: a cold one works too.
_cache = os.path.join(tempfile.gettempdir(), f"beamdrop-tests-xla-{os.getuid()}")
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _cache)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("BEAMDROP_CACHE_DIR", _cache)


def _faster_compiles():
    """XLA flags for a test run: the tests are mostly compiling (2 cores, hundreds of programs run once or a few
    times), so compile with XLA's classic CPU emitters and without LLVM's optimisation passes (programs compile
    2-3x faster and run up to 3x slower; results agree to rounding). An unknown flag aborts XLA, so the flags are
    probed once in a child process; a jaxlib without them runs the tests with its defaults."""
    flags = "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=0"
    if os.environ.get("BEAMDROP_TEST_XLA_FLAGS") is not None:  # decided already (pytest-xdist workers inherit it)
        return
    env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {flags}".strip(), JAX_PLATFORMS="cpu")
    probe = subprocess.run([sys.executable, "-c", "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"],
                           env=env, capture_output=True, timeout=120)
    os.environ["BEAMDROP_USER_XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "")
    if probe.returncode == 0:
        os.environ["XLA_FLAGS"] = env["XLA_FLAGS"]
    os.environ["BEAMDROP_TEST_XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "")


@pytest.fixture
def users_compile():
    """`run(script) -> stdout` of a child Python that compiles the way users' programs do (without the test run's
    XLA flags): for float32 results, where the compiler's rounding is the thing under test."""
    return _run_as_users_compile


def _run_as_users_compile(script: str) -> str:
    env = dict(os.environ, XLA_FLAGS=os.environ.get("BEAMDROP_USER_XLA_FLAGS", ""))
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


_faster_compiles()

import jax  # noqa: E402

# Accuracy claims are made in float64; tests that exercise float32 use `jax.enable_x64(False)` locally.
jax.config.update("jax_enable_x64", True)
# Synchronous CPU dispatch in the test workers: with asynchronous dispatch (jaxlib 0.10.2, 2 cores) a worker hung for
# good in `block_until_ready` on a buffer that never became ready, every XLA thread idle (3 of 7 fresh-clone runs;
# stacks taken with gdb). Set before the first computation, which creates the CPU client.
jax.config.update("jax_cpu_enable_async_dispatch", False)

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
    "test_validation.py::test_plate_agrees_with_opensees",
    "test_validation.py::test_held_out_shell_layouts",
)


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: not any(name in item.nodeid for name in _LONGEST))


_RSS_LIMIT = 4 * 2**30  # bytes per test worker


def _resident_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):  # not Linux: no reading, no clearing
        return 0


def pytest_runtest_teardown(item, nextitem):
    """Keep each test worker under `_RSS_LIMIT`: its compiled programs grew to 9 GB by the end of a run (two workers
    and the notebooks' kernels near the machine's 23 GB; a worker of a CI run died unannounced). Clearing JAX's
    caches and returning the freed heap to the system takes a worker back to about 2 GB (measured); a program
    needed again comes from the persistent compilation cache, traced again. Each worker clears two or three times
    a run (measured); a limit of 6 GB (one clear at most, 10.5 GB in use on the machine) ran no faster."""
    if _resident_bytes() > _RSS_LIMIT:
        import ctypes
        import gc

        jax.clear_caches()
        gc.collect()
        try:
            ctypes.CDLL("libc.so.6").malloc_trim(0)
        except (OSError, AttributeError):  # not glibc
            pass
