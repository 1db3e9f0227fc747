"""Peak of |sum_k c_k q_k(t) phi_k(x)| + sum_k m_k q_k(t)^2 over x in [0, L] and t in [0, window], phi_k the
board's deflection or curvature mode shapes (`_beam.mode_shapes`).

The second term (optional, uniform along the board) is the membrane strain of mid-plane stretching, which adds to
the bending strain on the face in tension.

A coarse grid finds candidate peaks (the largest local maxima in time of the spatial envelope); each is refined
from the vertex of the parabolas through its grid neighbours by Newton's method on the modal series, steps scaled
into a trust radius of one grid cell that halves when a step does not gain; the largest wins, never below its grid
value. Of candidates that tie to 1e-9 the earliest is reported. The peak's gradient is the gradient at the
maximiser (envelope theorem), so the maximiser enters under `stop_gradient`, except at the window's end and at end
B of the board, whose own dependence on the parameters counts; on an end (a clamp's peak) the search runs in t
alone, so the peak is stationary in t there.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float
from ._beam import mode_shapes


class FieldPeak(eqx.Module):
    """Peak of |field|: `value`, where (`x` from end A, m) and when (`t`, s), and `error`: relative estimate of
    the peak's remaining error from the search (last Newton gain, or grid-halving difference without refinement)."""

    value: Float[Array, ""]
    x: Float[Array, ""]
    t: Float[Array, ""]
    error: Float[Array, ""]


def stop_gradient(tree):
    """`jax.lax.stop_gradient` on every inexact array of a pytree (other leaves pass through)."""
    return jax.tree_util.tree_map(lambda v: jax.lax.stop_gradient(v) if eqx.is_inexact_array(v) else v, tree)


def field_on_grid(coeffs, Q, shapes) -> Float[Array, "nx nt"]:
    """Field sum_k coeffs_k q_k(t) phi_k(x) on a grid, with the mode shapes `shapes` (nx, n) on the grid's x and
    the modal coordinates given as factors Q = (scale (n,), R (nt, n)), q_k(t_j) = scale_k R[j, k].

    Keeping the factors apart matters under `vmap`: when only `scale` varies between drops (the board and pulse
    are shared), R is computed once and the drops fold into one large matrix product."""
    scale, R = Q
    return (shapes * (coeffs * scale)) @ R.T


def _largest(values: Float[Array, " n"], k: int):
    """Indices of the k largest values, by k argmax passes: `lax.top_k` sorts, which is several times slower on
    CPU under vmap for the few candidates wanted here."""
    positions = jnp.arange(values.shape[0])
    picked = []
    for _ in range(k):
        i = jnp.argmax(values)
        picked.append(i)
        values = jnp.where(positions == i, -jnp.inf, values)
    return jnp.stack(picked)


def find_peak(
    coeffs: Float[Array, " n"],
    modal: Callable,
    Q: tuple,
    x: Float[Array, " nx"],
    t: Float[Array, " nt"],
    board,
    window,
    *,
    curvature=False,
    candidates: int = 4,
    newton_steps: int = 6,
    refine: bool = True,
    membrane: Float[Array, " n"] | None = None,
) -> FieldPeak:
    """Peak of |field| (+ sum_k membrane_k q_k^2 when `membrane` is given) with `modal(t) -> q (n,)` the modal
    coordinates (a pytree callable with `jet(t) -> (q, q', q'')`, e.g. an `eqx.Module`),
    `Q = modal.grid_factors(t)` on the grid (see `field_on_grid`), and the board's deflection shapes or, with
    `curvature` (a bool or a traced 0/1), its curvature shapes (`_beam.mode_shapes`)."""
    n = coeffs.shape[-1]
    F = field_on_grid(coeffs, Q, mode_shapes(board, x, n, curvature))
    A = jnp.abs(F)
    if membrane is not None:
        scale, R = Q
        A = A + (R * scale) ** 2 @ membrane
    # A plain max over x, then arg-maxima only where needed: a full 2-D argmax is a slow variadic reduction.
    envelope = A.max(axis=0)
    if not refine:
        # The value by a plain max (where it lies only if asked for: XLA drops the arg-maxima when unused).
        value = envelope.max()
        j = envelope.argmax()
        err = (value - jnp.max(envelope[::2])) / jnp.maximum(value, jnp.finfo(A.dtype).tiny)
        return FieldPeak(value, x[A[:, j].argmax()], t[j], err)

    # Candidates: the largest local maxima in time of the spatial envelope (a lone spike at an end counts).
    left = jnp.concatenate([jnp.full((1,), -jnp.inf, A.dtype), envelope[:-1]])
    right = jnp.concatenate([envelope[1:], jnp.full((1,), -jnp.inf, A.dtype)])
    is_local = (envelope >= left) & (envelope >= right)
    k_cand = min(candidates, envelope.shape[0])
    idx = _largest(jnp.where(is_local, envelope, -jnp.inf), k_cand)
    where_x = A[:, idx].argmax(axis=0)
    sign0 = jnp.sign(F[where_x, idx])
    cell_x, cell_t = x[1] - x[0], t[1] - t[0]

    def vertex(lo, mid, hi):
        # Offset (cells) of the parabola through three neighbouring grid values: a start inside the right cell.
        curv = lo - 2 * mid + hi
        return jnp.clip(0.5 * (lo - hi) / jnp.where(curv < 0, curv, -1.0), -0.5, 0.5) * (curv < 0)

    nx, nt = A.shape
    ix_lo, ix_hi = jnp.maximum(where_x - 1, 0), jnp.minimum(where_x + 1, nx - 1)
    it_lo, it_hi = jnp.maximum(idx - 1, 0), jnp.minimum(idx + 1, nt - 1)
    mid = A[where_x, idx]
    # (Clipped: a peak at a clamped end has its vertex outside the board.)
    x0 = jnp.clip(x[where_x] + cell_x * vertex(A[ix_lo, idx], mid, A[ix_hi, idx]), x[0], x[-1])
    t0 = jnp.clip(t[idx] + cell_t * vertex(A[where_x, it_lo], mid, A[where_x, it_hi]), t[0], t[-1])

    # The search itself is not differentiated: only the final evaluation at the maximiser is.
    coeffs_c, board_c, window_c, modal_c, membrane_c = stop_gradient((coeffs, board, window, modal, membrane))
    length_c = board_c.length

    def value_grad_hess(x, t, sign):
        # Field derivatives in closed form in x; q, q', q'' from the modal solution's own jet in t. Scalars, not
        # stacked arrays: tiny stacks and transposes inside the loop cost more than the arithmetic under vmap.
        q, dq, ddq = modal_c.jet(t)
        sn, dsn, ddsn = mode_shapes(board_c, x, n, curvature, (0, 1, 2))
        a, b = sign * coeffs_c * q, sign * coeffs_c * dq
        f = jnp.sum(a * sn)
        g = (jnp.sum(a * dsn), jnp.sum(b * sn))
        H = (jnp.sum(a * ddsn), jnp.sum(b * dsn), jnp.sum(sign * coeffs_c * ddq * sn))
        if membrane is not None:
            f = f + jnp.sum(membrane_c * q * q)
            g = (g[0], g[1] + 2 * jnp.sum(membrane_c * q * dq))
            H = (H[0], H[1], H[2] + 2 * jnp.sum(membrane_c * (dq * dq + q * ddq)))
        return f, g, H

    def refine_one(x0, t0, sign, x_grid, t_grid, f_grid):
        def step(carry, _):
            x, t, f, (gx, gt), (hxx, hxt, htt), _, radius = carry
            det = hxx * htt - hxt**2
            concave = (hxx < 0) & (det > 0)
            det_safe = jnp.where(concave, det, 1.0)
            # In grid cells: a Newton step where the field is concave, else half a cell uphill; scaled as a whole
            # (not clipped per axis, which turns steps along a curved ridge off it) into the trust radius,
            # which halves after a step that does not gain.
            ux = jnp.where(concave, -(htt * gx - hxt * gt) / det_safe / cell_x, 0.5 * jnp.sign(gx))
            ut = jnp.where(concave, -(hxx * gt - hxt * gx) / det_safe / cell_t, 0.5 * jnp.sign(gt))
            # On an end of the board with the field rising outwards (a clamp's peak) the maximum is constrained
            # there: search in t alone, so that the peak is stationary in t (its gradient then holds).
            edge = ((x <= 0.0) & (gx < 0)) | ((x >= length_c) & (gx > 0))
            falls = htt < 0
            ut_edge = jnp.where(falls, -gt / jnp.where(falls, htt, 1.0) / cell_t, 0.5 * jnp.sign(gt))
            ux, ut = jnp.where(edge, 0.0, ux), jnp.where(edge, ut_edge, ut)
            shrink = jnp.minimum(1.0, radius / jnp.maximum(jnp.maximum(jnp.abs(ux), jnp.abs(ut)), 1e-30))
            x_new = jnp.clip(x + shrink * ux * cell_x, 0.0, length_c)
            t_new = jnp.clip(t + shrink * ut * cell_t, 0.0, window_c)
            f_new, g_new, H_new = value_grad_hess(x_new, t_new, sign)
            better = f_new > f
            keep = lambda a, b: jax.tree_util.tree_map(lambda u, v: jnp.where(better, u, v), a, b)  # noqa: E731
            new = keep((x_new, t_new, f_new, g_new, H_new), carry[:5])
            return (*new, jnp.where(better, f_new - f, 0.0), jnp.where(better, radius, 0.5 * radius)), None

        f0, g0, H0 = value_grad_hess(x0, t0, sign)
        carry = (x0, t0, f0, g0, H0, jnp.zeros_like(f0), jnp.ones_like(f0))
        if newton_steps <= 2:  # unrolled in Python: XLA fuses across the steps (scan's unroll does not)
            for _ in range(newton_steps):
                carry, _ = step(carry, None)
        else:  # a loop: short compile times for the interactive path's many steps
            carry, _ = jax.lax.scan(step, carry, None, length=newton_steps)
        x, t, f, _, _, gain, _ = carry
        # Never below the grid point it started from (a poor parabolic start can lie lower).
        grid_wins = f_grid > f
        x, t, f = jnp.where(grid_wins, x_grid, x), jnp.where(grid_wins, t_grid, t), jnp.maximum(f, f_grid)
        return jnp.stack([x, t]), f, gain

    starts = (x0, t0, sign0, x[where_x], t[idx], A[where_x, idx])
    p_all, f_all, gain_all = jax.vmap(refine_one)(*stop_gradient(starts))
    # Of candidates that tie (an undamped board repeats its peak every period, mirror images tie exactly), report
    # the earliest: the first time the board sees that stress.
    tied = f_all >= jnp.max(f_all) * (1.0 - 1e-9)
    best = jnp.argmin(jnp.where(tied, p_all[:, 1], jnp.inf))
    p_best = jax.lax.stop_gradient(p_all[best])
    # A peak on end B (a clamp) moves with the board's length: keep that dependence too.
    x_star = jnp.where(p_best[0] >= length_c * (1.0 - 1e-9), board.length, p_best[0])
    # A peak at the window's end moves with the window (which depends on the board): keep that dependence.
    at_end = p_best[1] >= window * (1.0 - 1e-9)
    t_star = jnp.where(at_end, window, p_best[1])
    q = modal(t_star)
    value = jnp.abs(jnp.sum(coeffs * q * mode_shapes(board, x_star, n, curvature)))
    if membrane is not None:
        value = value + jnp.sum(membrane * q * q)
    err = jax.lax.stop_gradient(gain_all[best] / jnp.maximum(f_all[best], jnp.finfo(A.dtype).tiny))
    return FieldPeak(value, x_star, t_star, err)
