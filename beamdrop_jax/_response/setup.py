"""What every response computes first: the modes kept (and the convergence check's), the time window and grid, the modal solution (closed form or diffrax) and its grid factors."""

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._common.checks import Flag, Range, as_float, flag_if, float_dtype
from .._impact.motion import HalfSine, LandingMotion
from .._scene.containers import Scene
from .._board.base import modal_velocity_jumps, natural_frequencies
from .._board.search import stop_gradient
from .closed_form import ClosedFormModes
from .diffrax_path import solve_modes
from .sampled import sampled_modes
from .numerics import Numerics
from .pulses import fundamental_period


def support_motion(scene: Scene, jumps) -> HalfSine:
    """The supports' motion in a drop: a half-sine of the contact's duration (an ideal impulse when it is 0), for
    jumps (dvA, dvB) or (dvA, dvB, dvR)."""
    return HalfSine(jumps[0], jumps[1], scene.contact.duration, *jumps[2:])


def _mode_counts(board, motion, numerics: Numerics):
    M = numerics.computed_modes
    if numerics.n_modes is not None:
        return jnp.int32(M), jnp.int32(max(M // 2, 1))
    duration = motion.pulse_duration()
    f_tau = natural_frequencies(board, M) / (2 * math.pi) * duration
    needed = jnp.sum(f_tau < numerics.pulse_band) + 1  # first k with f_k tau >= target
    used = jnp.clip(needed, numerics.min_modes, M).astype(jnp.int32)
    # Check against more modes whenever the cap leaves any (twice as many when it allows): half as many would
    # measure the error of the smaller model, not of the answer.
    check = jnp.where(used < M, jnp.minimum(2 * used, M), used // 2).astype(jnp.int32)
    return used, check


def _span(board, motion, numerics: Numerics):
    """Window after each pulse's start (the whole window for a single pulse or a record)."""
    if numerics.window is not None:
        return jnp.asarray(numerics.window, dtype=float_dtype())
    return motion.window_forcing() + fundamental_period(board)


def _time_grid(board, motion, numerics: Numerics, nt: int):
    """(window, t): for a pulse train, nt points after each pulse's start (the free vibration that follows is
    periodic in the fundamental period when N = 0, so its peak lies within one period of the pulse)."""
    span = _span(board, motion, numerics)
    unit = jnp.linspace(0.0, 1.0, nt)
    times = motion.pulse_times()
    if times.shape[0] > 1:
        return times[-1] + span, (times[:, None] + unit * span).ravel()
    return span, unit * span


def _grid_factors(modal, board, motion, numerics: Numerics, t):
    """`modal.grid_factors` on the search grid `t` of `_time_grid`; a pulse train's closed form by windows that
    share the board's factors between batched drops (`ClosedFormModes.train_grid_factors`)."""
    if modal.windows > 1:
        nt = t.shape[0] // modal.windows
        s = jnp.linspace(0.0, 1.0, nt) * _span(board, motion, numerics)
        return modal.train_grid_factors(s, overlap_points=max(nt // 8, 2))
    return modal.grid_factors(t)


def _modal_solution(board, motion, numerics: Numerics, window, mask):
    M = numerics.computed_modes
    if numerics.method == "closed_form":
        jumps, times, duration = motion.pulses()
        beta = jax.vmap(lambda j: modal_velocity_jumps(board, j, M))(jumps) * mask
        omega = natural_frequencies(board, M)
        return ClosedFormModes(omega, board.damping_ratio, duration, beta, times), jnp.asarray(False)
    if isinstance(motion, LandingMotion) and not numerics.stretching:
        return sampled_modes(board, motion, M, mask, window), jnp.asarray(False)
    return solve_modes(
        board,
        motion,
        M,
        window,
        mask,
        solver=numerics.solver,
        rtol=numerics.rtol,
        atol=numerics.atol,
        max_steps=numerics.max_steps,
        stretching=numerics.stretching,
    )


class _Setup(NamedTuple):
    used: Array
    check: Array
    window: Array
    modal: eqx.Module
    failed: Array
    x: Array
    t: Array
    Q: Array
    k: Array
    curvature: Array
    flags: Array
    modes: eqx.Module  # the board's modes (`AbstractBoard.modes`), solved once


MIN_POINTS_PER_PERIOD = 2
"""Time-grid points per period of the top mode below which an explicit `Numerics.window` is flagged: the grid
then cannot see that mode's peaks and Newton refinement starts from the wrong ones."""


def _window_points(board, numerics: Numerics, used, span=None):
    """Time-grid points per period of the top used mode over an explicit window, or over a plate's default
    window `span` (its grid follows an estimate of the plate's frequencies); inf with a beam's default window,
    which spans one fundamental period after the pulse and is sized for it."""
    if numerics.window is None and (span is None or numerics.frequency_growth != 1):
        return jnp.asarray(jnp.inf, dtype=float_dtype())
    omega = natural_frequencies(board, numerics.computed_modes)
    f_top = omega[jnp.clip(used, 1, numerics.computed_modes) - 1] / (2 * math.pi)
    window = numerics.window if numerics.window is not None else span
    return (numerics.grid_shape()[1] - 1) / (window * f_top)


def _raise_if_window(board, motion, numerics: Numerics, flags, what: str, with_check: bool) -> None:
    """Eagerly, `Flag.WINDOW_RANGE` as a `ValueError` naming the field, its value and the valid range."""
    if not int(flags) & Flag.WINDOW_RANGE:
        return
    numerics = numerics.for_board(board)
    if numerics.window is None:  # a plate's default window: its grid's estimate of its frequencies fell short
        used, check = _mode_counts(board.modes(numerics.computed_modes), motion, numerics)
        used = int(max(used, check) if with_check else used)
        raise ValueError(
            f"{what}: the time grid leaves mode {used} of this {board.describe()} fewer than "
            f"{MIN_POINTS_PER_PERIOD} points per period (its frequencies grow faster with the mode count than the "
            "grid assumes; Flag.WINDOW_RANGE); valid: Numerics(points_per_period=...) larger than "
            f"{numerics.points_per_period}, or fewer modes (Numerics.max_modes)")
    used, check = _mode_counts(board, motion, numerics)
    used = int(max(used, check) if with_check else used)
    points = float(_window_points(board, numerics, used))
    nt = numerics.grid_shape()[1]
    longest = numerics.window * points / MIN_POINTS_PER_PERIOD
    needed = math.ceil(numerics.points_per_period * MIN_POINTS_PER_PERIOD / points)
    raise ValueError(
        f"{what}: Numerics.window = {numerics.window:g} s leaves mode {used} (the highest computed) {points:.3g} "
        f"time-grid points per period ({nt} points in all; Flag.WINDOW_RANGE); valid: window <= {longest:.4g} s "
        f"with points_per_period = {numerics.points_per_period}, or points_per_period >= {needed} for this window"
    )


def _setup(board, motion, numerics: Numerics, with_check: bool, model=None) -> _Setup:
    """`model`: the board's lowest `Numerics.computed_modes` modes when the caller has solved them already."""
    numerics = numerics.for_board(board)
    M = numerics.computed_modes
    # A plate's modes come from one eigensolve, shared by everything below.
    model = board.modes(M) if model is None else model
    used, check = _mode_counts(model, motion, numerics)
    nx, nt = numerics.grid_shape()
    window, t = _time_grid(model, motion, numerics, nt)
    k = jnp.arange(1, M + 1)
    computed = jnp.maximum(used, check) if with_check else used
    modal, failed = _modal_solution(model, motion, numerics, window, (k <= computed).astype(float_dtype()))
    x = jnp.linspace(0.0, 1.0, nx) * board.length
    # With refinement the grid only picks the searches' starts: no gradient flows through it, so none is built.
    Q = (_grid_factors(*stop_gradient((modal, model, motion)), numerics, jax.lax.stop_gradient(t)) if numerics.refine
         else _grid_factors(modal, model, motion, numerics, t))
    top = jnp.maximum(used, check) if with_check else used
    flags = flag_if(_window_points(model, numerics, top, _span(model, motion, numerics)) < MIN_POINTS_PER_PERIOD,
                    Flag.WINDOW_RANGE)
    curvature = model.curvature_scale(M)
    return _Setup(used, check, window, modal, failed, x, t, Q, k, curvature, flags, model)


def _gauge_points(gauges):
    """Gauge points as an (g, 2) array, or None; a clear error for anything else."""
    if gauges is None:
        return None
    points = as_float(gauges, "gauges", Range(unit="m"))
    if points.ndim != 2 or points.shape[-1] != 2 or points.shape[0] < 1:
        raise ValueError(f"gauges has shape {points.shape}; valid: ((x, y), ...) in m, x from end A, y from the "
                         "centre line")
    return points
