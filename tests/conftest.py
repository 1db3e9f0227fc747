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
