"""`python -m beamdrop_jax.cli` is the `beamdrop` command."""

from . import run

run()
