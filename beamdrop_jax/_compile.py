"""How the package compiles its programs: `filter_jit` and `jit` are Equinox's and JAX's, with XLA's classic CPU
emitters (`xla_cpu_use_fusion_emitters` off), which compile this package's programs 1.4-1.8x faster at the same
run time (`beamdrop bench --latency`). A compile option of each program, not a global setting: the rest of the
user's JAX is untouched, the option follows the programs through `grad` and `vmap`, and a user's own `jit` around
them compiles with the user's options. An `XLA_FLAGS` that sets the emitters wins; a jaxlib that does not know
the option compiles as usual."""

import functools
import os

import equinox as eqx
import jax

_CLASSIC_EMITTERS = "xla_cpu_use_fusion_emitters"


@functools.cache
def compiler_options() -> dict | None:
    """`{"xla_cpu_use_fusion_emitters": False}`, or None where `XLA_FLAGS` sets it or jaxlib does not know it
    (checked once, by compiling a one-operation program with it)."""
    if _CLASSIC_EMITTERS in os.environ.get("XLA_FLAGS", ""):
        return None
    options = {_CLASSIC_EMITTERS: False}
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(0).compile()
    except jax.errors.JaxRuntimeError:  # "No such compile option"
        return None
    return options


class _Compiled:
    """A function compiled with `compiler_options()` where it is called on its own, and as usual where it is traced
    into another program (`grad`, `vmap`, an enclosing `jit`): JAX takes compile options on top-level programs only
    (and says so with a ValueError while tracing, before anything is staged, where no argument shows it)."""

    def __init__(self, make, fun, jit_kwargs):
        self._make, self._fun, self._jit_kwargs = make, fun, jit_kwargs
        self._plain = make(fun, **jit_kwargs)
        self._fast = None  # made on the first call, when JAX is running anyway
        functools.update_wrapper(self, fun)

    def __call__(self, *args, **kwargs):
        # Traced arguments (grad, vmap, an enclosing jit) stage the program into another: no options there.
        if not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves((args, kwargs))):
            if self._fast is None:
                options = compiler_options()
                self._fast = self._plain if options is None else self._make(
                    self._fun, compiler_options=options, **self._jit_kwargs)
            try:
                return self._fast(*args, **kwargs)
            except ValueError as error:
                if "compiler_options" not in str(error):
                    raise
        return self._plain(*args, **kwargs)


def filter_jit(fun=None, **jit_kwargs):
    """`eqx.filter_jit`, compiled with `compiler_options()` at the top level."""
    if fun is None:
        return functools.partial(filter_jit, **jit_kwargs)
    return _Compiled(eqx.filter_jit, fun, jit_kwargs)


def jit(fun=None, **jit_kwargs):
    """`jax.jit`, compiled with `compiler_options()` at the top level."""
    if fun is None:
        return functools.partial(jit, **jit_kwargs)
    return _Compiled(jax.jit, fun, jit_kwargs)
