"""A container's float fields: each class lists its fields' valid ranges and flags in `RANGES`; these helpers set
the fields from user values, check them eagerly and flag them under `jit`."""

import jax.numpy as jnp

from .checks import Flag, Range, as_float, combine, flag_if


def positive(unit, lo, hi):
    """A size or material constant: positive, and within magnitudes where the arithmetic stays exact in float64
    (beyond them products such as E h^3 or 1/m over- or underflow, and a result could not name its cause)."""
    return Range(lo, hi, unit=unit), Flag.NONPOSITIVE_SIZE




def init_fields(module, values: dict):
    """Set each field from `values` as a float array, rejecting non-numbers with the field's name and range."""
    cls = type(module)
    for name, value in values.items():
        setattr(module, name, as_float(value, f"{cls.__name__}.{name}", cls.RANGES[name][0]))


def check_ranges(module, skip=()):
    cls = type(module)
    for name, (valid, _) in cls.RANGES.items():
        if name not in skip and getattr(module, name, None) is not None:
            valid.require(getattr(module, name), f"{cls.__name__}.{name}")


def range_flags(module):
    def ok(name, valid):
        inside = valid.contains(getattr(module, name))
        return jnp.all(inside, axis=-1) if name in VECTOR_FIELDS else inside

    return combine(*(flag_if(~ok(name, valid), flag) for name, (valid, flag) in type(module).RANGES.items()
                     if getattr(module, name, None) is not None))


VECTOR_FIELDS = {"centre", "principal_inertia"}  # fields with a trailing axis of their own (a pair), not a batch axis
