"""Reductions whose gradients stay finite.

`jnp.max`'s gradient spreads the cotangent over the entries equal to the maximum and divides by their count. A
compiled program may recompute the entries for the gradient a rounding apart from the maximum it found: the count
is then 0 and the gradient 0 / 0, NaN on a valid input (seen on a placement optimiser's vmapped step). A gather
has no count: the gradient goes to one maximiser, the first (the same as `jnp.max`'s where it is unique)."""

import jax.numpy as jnp
from jaxtyping import Array, Float


def largest(values: Float[Array, "..."]) -> Float[Array, ""]:
    """The largest entry of `values` (NaN if any entry is NaN), by a gather: its gradient is finite where the
    values' is."""
    return values.ravel()[jnp.argmax(values)]
