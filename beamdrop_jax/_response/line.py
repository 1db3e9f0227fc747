"""Peaks of a board whose domain is a line (a beam): curvature and deflection along x, mid-plane stretching."""

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._board.base import Peak, natural_frequencies
from .._board.beam import wavenumbers
from .._board.search import FieldPeak, find_peak
from .._common.checks import Flag, combine, flag_if
from .numerics import Numerics
from .results import Convergence, Response
from .setup import _Setup, _setup


def _membrane(board, numerics: Numerics, rows, is_curvature) -> Array | None:
    """Per row, the weights m_k of the membrane strain of mid-plane stretching, (1/4) sum_k (k pi/L)^2 q_k^2, in
    curvature units (divided by h/2) for curvature rows and zero for deflection rows; None without stretching."""
    if not numerics.stretching:
        return None
    kappa2 = wavenumbers(board, numerics.computed_modes) ** 2
    return jnp.stack([kappa2 / (2 * board.thickness) * (c != 0) * curv for c, curv in zip(rows, is_curvature)])


def _search(setup: _Setup, board, numerics: Numerics, coeffs, membrane=None, *, curvature,
            refine=None) -> FieldPeak:
    """Peaks of the fields with modal coefficients `coeffs` (rows; plus the membrane term of each row when
    `membrane` is given) over the board's curvature shapes (rows where `curvature`, a tuple of bools, is True) or
    deflection shapes, in one batched search (one compiled copy). `refine`: per row (a tuple of bools), refined or
    the grid's maximum; None: `numerics.refine`."""
    return find_peak(coeffs, setup.modal, setup.Q, setup.x, setup.t, board, setup.window, curvature=curvature,
                     membrane=membrane, candidates=numerics.candidates, newton_steps=numerics.newton_steps,
                     refine=numerics.refine if refine is None else refine, windows=setup.modal.windows)


def _respond_line(board, motion, numerics: Numerics, flags) -> Response:
    S = _setup(board, motion, numerics, with_check=True)
    used, check, window, k, curvature, failed = S.used, S.check, S.window, S.k, S.curvature, S.failed
    M = numerics.computed_modes
    coeffs = jnp.stack([curvature * (k <= used), curvature * (k <= check), jnp.ones(M) * (k <= used)])
    rows = (True, True, False)
    peaks = _search(S, board, numerics, coeffs, _membrane(board, numerics, coeffs, rows), curvature=rows)
    kappa, kappa_check, deflection = (jax.tree_util.tree_map(lambda v: v[i], peaks) for i in range(3))
    error = jnp.abs(kappa.value - kappa_check.value) / jnp.maximum(kappa.value, jnp.finfo(window.dtype).tiny)

    half_h = board.thickness / 2
    # Valid inputs whose magnitudes overflow or underflow the arithmetic: a flag, never a silent NaN.
    nonfinite = ~jnp.isfinite(kappa.value) | ~jnp.isfinite(deflection.value)
    flags = combine(flags, board.flags(), S.flags, flag_if(failed, Flag.SOLVER_FAILED),
                    flag_if(nonfinite, Flag.NONFINITE_RESULT))
    bad = flags != 0
    nan = lambda v: jnp.where(bad, jnp.nan, v)  # noqa: E731 - flagged results are NaN, never a wrong number
    if numerics.stretching:
        q = S.modal(kappa.t) * (k <= used)
        membrane_strain = jnp.sum(wavenumbers(board, M) ** 2 * q * q) / 4
    else:
        membrane_strain = jnp.zeros_like(kappa.value)
    peak = Peak(
        stress=nan(board.youngs_modulus * half_h * kappa.value),
        membrane_stress=nan(board.youngs_modulus * membrane_strain),
        strain=nan(half_h * kappa.value),
        x=nan(kappa.x),
        t=nan(kappa.t),
        deflection=nan(deflection.value),
        deflection_x=nan(deflection.x),
        deflection_t=nan(deflection.t),
        search_error=kappa.error,
        y=jnp.zeros_like(kappa.x),
        deflection_y=jnp.zeros_like(kappa.x),
        strain_x=nan(kappa.x),
        strain_y=jnp.zeros_like(kappa.x),
        strain_t=nan(kappa.t),
    )
    return Response(
        impulse=None,
        housing=None,
        impacts=None,
        support_jumps=motion.first_jumps()[:2], roll_jump=motion.first_jumps()[2],
        peak=peak,
        frequencies=natural_frequencies(board, M) / (2 * math.pi),
        n_modes=used,
        check_modes=check,
        error_estimate=error,
        converged=(error <= numerics.convergence_rtol) & ~bad,
        convergence=Convergence(error, *(jnp.zeros_like(error),) * 3),
        window=window,
        flags=flags,
    )
