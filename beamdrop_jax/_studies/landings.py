"""Near-flat drops on the compliant landing's path, solved in batches from a thread per core: what `montecarlo`,
`orientation_table` and `campaign` call for the drops whose strikes overlap."""

import concurrent.futures
import dataclasses
import os

import jax
import numpy as np
from tqdm import tqdm

from .._common.checks import Flag, float_dtype
from .._common.compile import filter_jit
from .._response.landing_path import FIRST_LANDING_STEPS
from .._response.numerics import Numerics
from .._response.simulate import _simulate
from .._response.surface import kept_modes, plate_time_grid

LANDING_BATCH = 8
"""Near-flat drops solved at once on the compliant path (each a diffrax solve of its landing)."""


def solve_landings(samples, axes, idx, progress: bool = False,
                   first: Numerics = Numerics(landing_steps=FIRST_LANDING_STEPS)):
    """Peak stress, strain, deflection and flags of drops `idx` of a batch on the compliant landing's path
    (`simulate`'s, default numerics), `LANDING_BATCH` at a time: four arrays of len(idx). Each drop is solved first
    with `first` (`simulate`'s first step limit, `FIRST_LANDING_STEPS`: a smaller buffer), and again with the
    default `Numerics.landing_steps` where that is not enough: the same numbers as `simulate`'s. A plate shared by
    every drop is solved for its modes once, and its drops take the time grid its frequencies allow, as
    `simulate`'s (`kept_modes`, `plate_time_grid`)."""
    idx = np.asarray(idx, dtype=int)
    modes = None
    if all(a is None for a in jax.tree_util.tree_leaves(axes.board, is_leaf=lambda a: a is None)):
        modes = kept_modes(samples.board)
        duration = np.asarray(samples.contact.duration)
        first = plate_time_grid(first, modes, duration[idx].max() if duration.ndim else duration)
    out = _solve_batches(samples, axes, idx, first, progress, modes)
    again = np.flatnonzero(out[3] & Flag.SOLVER_FAILED)
    last = dataclasses.replace(first, landing_steps=Numerics().landing_steps)
    if again.size and last.landing_steps > first.landing_steps:
        for o, v in zip(out, _solve_batches(samples, axes, idx[again], last, progress, modes)):
            o[again] = v
    return out


def _solve_batches(samples, axes, idx, numerics: Numerics, progress: bool, modes=None):
    out = [np.empty(idx.size, dtype) for dtype in (float_dtype(),) * 3 + (np.int32,)]
    leaves, treedef = jax.tree_util.tree_flatten(samples)
    batched = [a is not None for a in treedef.flatten_up_to(axes)]
    x64 = jax.config.jax_enable_x64  # the caller's, which may be a thread's own (`jax.enable_x64(False)`)

    def solve(start):
        part = idx[start:start + LANDING_BATCH]
        padded = np.concatenate([part, np.repeat(part[-1:], LANDING_BATCH - part.size)])  # one compiled shape
        chunk = treedef.unflatten([np.asarray(v)[padded] if b else v for v, b in zip(leaves, batched)])
        with jax.enable_x64(x64):
            for o, v in zip(out, _compliant_peaks(chunk, axes, numerics, modes)):
                o[start:start + part.size] = np.asarray(v)[:part.size]

    starts = range(0, idx.size, LANDING_BATCH)
    if not starts:
        return out
    with tqdm(total=len(starts), desc="near-flat landings", disable=not progress, leave=False) as bar:
        solve(starts[0])  # compiles, once
        bar.update(1)
        # XLA on CPU runs one batch's solve (a loop of small steps) on one core, and JAX runs the calls of one
        # thread one after another: batches solved from several threads keep the other cores busy (on 2 cores a
        # table of 404 near-flat landings took 4.2 against 7.8 ms each).
        pool = concurrent.futures.ThreadPoolExecutor(_landing_threads())
        try:
            for _ in pool.map(solve, starts[1:]):
                bar.update(1)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)  # on Ctrl-C: the batches running finish, no others
    return out


def _landing_threads() -> int:
    """Threads solving near-flat landings at once: one per core, at most 4."""
    return max(1, min(4, os.cpu_count() or 1))


@filter_jit
def _compliant_peaks(samples, axes, numerics: Numerics, modes=None):
    def one(s):
        r = _simulate(s, numerics, None, "compliant", modes)
        return r.peak.stress, r.peak.strain, r.peak.deflection, r.flags

    return jax.vmap(one, in_axes=(axes,))(samples)
