"""Results kept in memory between calls, under a digest of what they were computed from: the most recently used
few of each kind (a board's modes, a Monte-Carlo table), so that another call on the same inputs skips the work."""

import collections
import hashlib

import jax
import numpy as np


def tree_digest(tree) -> str:
    """A digest of every field of a concrete pytree: its structure and static fields, and each leaf's value, shape
    and dtype."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    digest = hashlib.sha256(str(treedef).encode())
    for leaf in leaves:
        value = np.asarray(leaf)
        digest.update(f"{value.dtype}{value.shape}".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def keep(kept: collections.OrderedDict, key: str, value, size: int):
    """`value` stored under `key` as the most recently used of `kept`, which holds the last `size`; returns it."""
    kept.pop(key, None)
    kept[key] = value
    while len(kept) > size:
        kept.popitem(last=False)
    return value
