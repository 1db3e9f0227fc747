"""beamdrop_jax: a differentiable JAX simulator of what a drop does to the board inside a device."""

import lazy_loader as _lazy

# Import each private module when one of its names is first used: a call pays for what it needs (the names and
# where they live are in __init__.pyi, which type checkers read too).
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)

__version__ = "0.1.0"
