import jax

# Accuracy claims are made in float64; tests that exercise float32 use `jax.enable_x64(False)` locally.
jax.config.update("jax_enable_x64", True)
