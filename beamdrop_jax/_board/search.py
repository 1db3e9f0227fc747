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

import functools
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from .._common.trig import sincos
from .beam import mode_shapes
from .plate_checks import clip_to_plate


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


_JACOBI_SWEEPS = 5  # cyclic sweeps: Jacobi converges quadratically, a 3 x 3 matrix to round-off in 4 (2e4 random,
# held, nearly diagonal and diagonally dominant matrices over 16 decades: residual 1e-15 of |A| after 4, 8e-6 after 3)


def symmetric_eigen3(A: Float[Array, "3 3"]) -> tuple[Float[Array, " 3"], Float[Array, "3 3"]]:
    """Eigenvalues (unsorted) and eigenvectors (columns) of a symmetric 3 x 3 matrix by cyclic Jacobi rotations, a
    fixed number of sweeps on its entries: elementwise arithmetic that XLA fuses, where `jnp.linalg.eigh` calls
    LAPACK on CPU, whose BLAS threads then spin and take cores from the threads solving near-flat landings. For
    the Newton refinement, whose steps are not differentiated (the maximiser enters under `stop_gradient`). The
    sweeps are a loop: unrolled, they were a tenth of a plate drop's program and of its compile time."""
    upper = [(i, j) for i in range(3) for j in range(i, 3)]
    every = [(i, j) for i in range(3) for j in range(3)]

    def sweep(_, state):
        a, v = dict(zip(upper, state[0])), dict(zip(every, state[1]))
        for p, q, r in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            apq = a[p, q]
            nonzero = apq != 0
            theta = jnp.clip((a[q, q] - a[p, p]) / (2.0 * jnp.where(nonzero, apq, 1.0)), -1e150, 1e150)
            t = jnp.where(nonzero, jnp.where(theta >= 0, 1.0, -1.0) / (jnp.abs(theta) + jnp.sqrt(theta**2 + 1.0)),
                          0.0)
            c = 1.0 / jnp.sqrt(t**2 + 1.0)
            s = t * c
            rp, rq = tuple(sorted((r, p))), tuple(sorted((r, q)))
            arp, arq = a[rp], a[rq]
            a[p, p], a[q, q], a[p, q] = a[p, p] - t * apq, a[q, q] + t * apq, jnp.zeros_like(apq)
            a[rp], a[rq] = c * arp - s * arq, s * arp + c * arq
            for i in range(3):
                vp, vq = v[i, p], v[i, q]
                v[i, p], v[i, q] = c * vp - s * vq, s * vp + c * vq
        return [a[k] for k in upper], [v[k] for k in every]

    start = ([A[k] for k in upper], [jnp.asarray(float(i == j), A.dtype) for i, j in every])
    a, v = jax.lax.fori_loop(0, _JACOBI_SWEEPS, sweep, start)
    a, v = dict(zip(upper, a)), dict(zip(every, v))
    return (jnp.stack([a[0, 0], a[1, 1], a[2, 2]], axis=-1),
            jnp.stack([jnp.stack([v[i, j] for j in range(3)], axis=-1) for i in range(3)], axis=-2))


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


def _vertex(lo, mid, hi):
    """Offset (cells) of the parabola through three neighbouring grid values, a start inside the right cell, and
    the parabola's gain there over the middle value."""
    curv = lo - 2 * mid + hi
    u = jnp.clip(0.5 * (lo - hi) / jnp.where(curv < 0, curv, -1.0), -0.5, 0.5) * (curv < 0)
    return u, u * (0.5 * (hi - lo) + 0.5 * curv * u)


def _grid_starts(F, A, envelope, x_g, t_g, windows: int, per_window: int, candidates: int):
    """The first step of `find_peak`: Newton starts from the grid (x0, t0, sign, grid x, grid t, grid value)."""
    cell_x, cell_t = x_g[1] - x_g[0], t_g[1] - t_g[0]
    # Candidates: the largest local maxima in time of the spatial envelope (a lone spike at an end counts).
    left = jnp.concatenate([jnp.full((1,), -jnp.inf, A.dtype), envelope[:-1]])
    right = jnp.concatenate([envelope[1:], jnp.full((1,), -jnp.inf, A.dtype)])
    is_local = (envelope >= left) & (envelope >= right)
    scores = jnp.where(is_local, envelope, -jnp.inf).reshape(windows, -1)
    idx = jax.vmap(lambda v: _largest(v, per_window))(scores) + scores.shape[1] * jnp.arange(windows)[:, None]
    idx = idx.ravel()
    where_x = A[:, idx].argmax(axis=0)
    nx, nt = A.shape
    ix_lo, ix_hi = jnp.maximum(where_x - 1, 0), jnp.minimum(where_x + 1, nx - 1)
    it_lo, it_hi = jnp.maximum(idx - 1, 0), jnp.minimum(idx + 1, nt - 1)
    mid = A[where_x, idx]
    (ux, gain_x), (ut, gain_t) = _vertex(A[ix_lo, idx], mid, A[ix_hi, idx]), _vertex(A[where_x, it_lo], mid,
                                                                                 A[where_x, it_hi])
    # (Clipped: a peak at a clamped end has its vertex outside the board.)
    x0 = jnp.clip(x_g[where_x] + cell_x * ux, x_g[0], x_g[-1])
    t0 = jnp.clip(t_g[idx] + cell_t * ut, t_g[0], t_g[-1])
    out = x0, t0, jnp.sign(F[where_x, idx]), x_g[where_x], t_g[idx], mid
    if windows == 1:
        return out
    best = _largest(mid + gain_x + gain_t, min(candidates, idx.shape[0]))
    return tuple(v[best] for v in out)



def _coarse(F, A, envelope, *, x_g, t_g):
    """An unrefined row of `find_peak`: the grid's maximum by a plain max (where it lies only if asked for: XLA
    drops the arg-maxima when unused)."""
    value, j = envelope.max(), envelope.argmax()
    err = (value - jnp.max(envelope[::2])) / jnp.maximum(value, jnp.finfo(A.dtype).tiny)
    return FieldPeak(value, x_g[A[:, j].argmax()], t_g[j], err)


def _finish(x_all, t_all, f_all, gain_all, c, m, cv, *, modal, board, window, length_c, n):
    """The last step of `find_peak`: of one row's refined candidates, the peak, evaluated (with its gradient) at
    the maximiser."""
    # Of candidates that tie (an undamped board repeats its peak every period, mirror images tie exactly),
    # report the earliest: the first time the board sees that stress.
    tied = f_all >= jnp.max(f_all) * (1.0 - 1e-9)
    best = jnp.argmin(jnp.where(tied, t_all, jnp.inf))
    x_best, t_best = jax.lax.stop_gradient((x_all[best], t_all[best]))
    # A peak on end B (a clamp) moves with the board's length: keep that dependence too.
    x_star = jnp.where(x_best >= length_c * (1.0 - 1e-9), board.length, x_best)
    # A peak at the window's end moves with the window (which depends on the board): keep that dependence.
    t_star = jnp.where(t_best >= window * (1.0 - 1e-9), window, t_best)
    q = modal(t_star)
    value = jnp.abs(jnp.sum(c * q * mode_shapes(board, x_star, n, cv)))
    if m is not None:
        value = value + jnp.sum(m * q * q)
    err = jax.lax.stop_gradient(gain_all[best] / jnp.maximum(f_all[best], jnp.finfo(f_all.dtype).tiny))
    return FieldPeak(value, x_star, t_star, err)


def find_peak(
    coeffs: Float[Array, "r n"],
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
    refine: bool | tuple[bool, ...] = True,
    membrane: Float[Array, "r n"] | None = None,
    windows: int = 1,
) -> FieldPeak:
    """Peaks of |field| (+ sum_k membrane_k q_k^2 when `membrane` is given) for each row of modal coefficients
    `coeffs` (rows share the modal solution and the grid), with `modal(t) -> q (n,)` the modal coordinates (a
    pytree callable with `jet(t) -> (q, q', q'')`, e.g. an `eqx.Module`), `Q = modal.grid_factors(t)` on the grid
    (see `field_on_grid`), and the board's deflection shapes or, where `curvature` (a bool or a 0/1 per row) holds,
    its curvature shapes (`_beam.mode_shapes`). Returns a `FieldPeak` of arrays (r,).

    With `windows` > 1 the grid's times are that many windows of equal length (a pulse train's, one per pulse),
    each window nominates its own `candidates`, and the `candidates` best of them by their parabolic
    interpolation through the neighbouring grid values are refined: peaks of nearly equal height in different
    windows are ranked by the interpolated value, not by the coarse grid's.

    `refine` (a bool, or one per row): refine the grid's peaks, or report the grid's maximum; rows of both kinds
    share one evaluation of the grid (one matrix product), and then the grid's maxima carry no gradient. The rows' candidates are refined together in one loop
    over Newton steps (the loop is never itself vmapped: batching a loop re-traces its body, which made most of the
    tracing time)."""
    n, rows = coeffs.shape[-1], coeffs.shape[0]
    curvature = jnp.broadcast_to(jnp.asarray(curvature), coeffs.shape[:1])
    refined = tuple(refine) if isinstance(refine, tuple) else (bool(refine),) * rows
    if any(refined):
        # The grid only picks the starts: no gradient flows through it, so none is built.
        coeffs_g, Q_g, board_g, x_g, t_g, membrane_g = stop_gradient((coeffs, Q, board, x, t, membrane))
    else:
        coeffs_g, Q_g, board_g, x_g, t_g, membrane_g = coeffs, Q, board, x, t, membrane

    def on_grid(c, m, cv):
        F = field_on_grid(c, Q_g, mode_shapes(board_g, x_g, n, cv))
        A = jnp.abs(F)
        if m is not None:
            scale, R = Q_g
            A = A + (R * scale) ** 2 @ m
        # A plain max over x, then arg-maxima only where needed: a full 2-D argmax is a slow variadic reduction.
        return F, A, A.max(axis=0)

    # Every row's grid in one batched product (the rows share the modal factors).
    grids = jax.vmap(on_grid)(coeffs_g, membrane_g, curvature)

    def rows_where(tree, which):
        at = np.asarray([i for i, r in enumerate(refined) if r == which])
        return jax.tree_util.tree_map(lambda v: v[at], tree)

    coarse = functools.partial(_coarse, x_g=x_g, t_g=t_g)

    if not any(refined):
        return jax.vmap(coarse)(*grids)
    coarse_peaks = None if all(refined) else jax.vmap(coarse)(*rows_where(grids, False))
    if coarse_peaks is not None:  # from here on, the refined rows alone
        coeffs, membrane, curvature, grids = rows_where((coeffs, membrane, curvature, grids), True)

    cell_x, cell_t = x_g[1] - x_g[0], t_g[1] - t_g[0]
    per_window = min(candidates, t.shape[0] // windows)

    def starts(F, A, envelope):
        return _grid_starts(F, A, envelope, x_g, t_g, windows, per_window, candidates)

    rows, k = coeffs.shape[0], per_window if windows == 1 else min(candidates, windows * per_window)
    flat = lambda v: v.reshape(rows * k)  # noqa: E731 - (rows, candidates) -> one axis
    x0, t0, sign, x_grid, t_grid, f_grid = (flat(v) for v in jax.vmap(starts)(*grids))
    of_row = jnp.repeat(jnp.arange(rows), k)

    # The search itself is not differentiated: only the final evaluation at the maximiser is.
    coeffs_c, board_c, window_c, modal_c, membrane_c = stop_gradient((coeffs, board, window, modal, membrane))
    if hasattr(modal_c, "for_search"):  # prepared once for the many jets below
        modal_c = modal_c.for_search()
    per_candidate = (coeffs_c[of_row], None if membrane is None else membrane_c[of_row], curvature[of_row], sign)
    length_c = board_c.length

    def value_grad_hess(x, t, c, m, cv, sign):
        # Field derivatives in closed form in x; q, q', q'' from the modal solution's own jet in t. Scalars, not
        # stacked arrays: tiny stacks and transposes inside the loop cost more than the arithmetic under vmap.
        q, dq, ddq = modal_c.jet(t)
        sn, dsn, ddsn = mode_shapes(board_c, x, n, cv, (0, 1, 2))
        a, b = sign * c * q, sign * c * dq
        f = jnp.sum(a * sn)
        g = (jnp.sum(a * dsn), jnp.sum(b * sn))
        H = (jnp.sum(a * ddsn), jnp.sum(b * dsn), jnp.sum(sign * c * ddq * sn))
        if m is not None:
            f = f + jnp.sum(m * q * q)
            g = (g[0], g[1] + 2 * jnp.sum(m * q * dq))
            H = (H[0], H[1], H[2] + 2 * jnp.sum(m * (dq * dq + q * ddq)))
        return f, g, H

    def step_one(carry, c, m, cv, sign):
        # Evaluates the pending point, keeps it if it gains, and proposes the next from the best so far: the
        # start is the first pending point, so the program holds one copy of the evaluation.
        x, t, f, g, H, gain, radius, x_new, t_new = carry
        f_new, g_new, H_new = value_grad_hess(x_new, t_new, c, m, cv, sign)
        better = f_new > f
        keep = lambda a, b: jax.tree_util.tree_map(lambda u, v: jnp.where(better, u, v), a, b)  # noqa: E731
        x, t, f_kept, (gx, gt), (hxx, hxt, htt) = keep((x_new, t_new, f_new, g_new, H_new), (x, t, f, g, H))
        gain = jnp.where(better & (f > -jnp.inf), f_new - f, 0.0)
        radius = jnp.where(better, radius, 0.5 * radius)
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
        return x, t, f_kept, (gx, gt), (hxx, hxt, htt), gain, radius, x_new, t_new

    def step(carry, _):
        return jax.vmap(step_one)(carry, *per_candidate), None

    zero = jnp.zeros_like(x0)
    carry = (x0, t0, jnp.full_like(x0, -jnp.inf), (zero, zero), (zero, zero, zero), zero, jnp.ones_like(x0), x0, t0)
    if newton_steps <= 2:  # unrolled in Python: XLA fuses across the steps (scan's unroll does not)
        for _ in range(newton_steps + 1):
            carry, _ = step(carry, None)
    else:  # a loop: short compile times for the interactive path's many steps
        carry, _ = jax.lax.scan(step, carry, None, length=newton_steps + 1)
    x_r, t_r, f_r, _, _, gain = carry[:6]
    # Never below the grid point it started from (a poor parabolic start can lie lower).
    grid_wins = f_grid > f_r
    x_r, t_r, f_r = jnp.where(grid_wins, x_grid, x_r), jnp.where(grid_wins, t_grid, t_r), jnp.maximum(f_r, f_grid)
    unflat = lambda v: v.reshape(rows, k)  # noqa: E731

    finish = functools.partial(_finish, modal=modal, board=board, window=window, length_c=length_c, n=n)
    peaks = jax.vmap(finish)(unflat(x_r), unflat(t_r), unflat(f_r), unflat(gain), coeffs, membrane, curvature)
    if coarse_peaks is None:
        return peaks
    order = np.argsort([i for which in (True, False) for i, r in enumerate(refined) if r == which])
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b])[order], peaks, coarse_peaks)


_ON_BOUND = 1e-9  # cells: a plate search's coordinate this near a bound is on it


class PlatePeak(eqx.Module):
    """Peak of a surface measure over a plate and the window: `value`, where (`x` from end A, `y` from the centre
    line, m), when (`t`, s), and `error` (relative error estimate of the value: `find_plate_peak`)."""

    value: Float[Array, ""]
    x: Float[Array, ""]
    y: Float[Array, ""]
    t: Float[Array, ""]
    error: Float[Array, ""]


def _over_mounts(plate, point, move):
    """`move((x, y), mount)` applied for each of the plate's mounts in turn, from `point` (a loop: one copy of
    `move` in the program, however many mounts; unrolled, each copy was duplicated into its consumers)."""
    return jax.lax.scan(lambda p, m: (move(p, m), None), point, plate.mounts)[0]


def _outside_mounts(plate, x, y):
    """Projection of points (x, y) (m) out of the mount discs onto their circles; no-op without mounts."""
    if plate.mounts is None:
        return x, y

    def move(point, mount):
        x, y = point
        dx, dy = x - mount[0], y - mount[1]
        d = jnp.sqrt(dx * dx + dy * dy)
        inside = d < plate.mount_radius
        scale = plate.mount_radius / jnp.where(d > 0, d, 1.0)
        return (jnp.where(inside, mount[0] + jnp.where(d > 0, dx * scale, plate.mount_radius), x),
                jnp.where(inside, mount[1] + dy * scale, y))

    return _over_mounts(plate, (x, y), move)


RING_POINTS = 16
"""Search points on each mount's circle, the edge of its disc, where a point support's strain concentrates. The
grid's cells (5.5 x 3.2 mm on the JESD22 board) are as large as a screw's disc, so a peak on a circle lies between
grid points; a search that reached it from the plate's interior, each step projected back onto the circle, stopped
short of the maximum along it: 4.4 % below on a plate on one screw, while its error estimate said 1.5e-3."""


def ring_points(plate):
    """`RING_POINTS` points on each mount's circle (mount-major, at angles 2 pi k / RING_POINTS from the x axis):
    (x, y) (m), each (mounts * RING_POINTS,); empty without mounts."""
    if plate.mounts is None:
        empty = jnp.zeros((0,), jnp.result_type(plate.length))
        return empty, empty
    s, c = sincos(jnp.arange(RING_POINTS, dtype=jnp.result_type(plate.length)) * (2 * math.pi / RING_POINTS))
    return ((plate.mounts[:, :1] + plate.mount_radius * c).ravel(),
            (plate.mounts[:, 1:] + plate.mount_radius * s).ravel())


def near_mounts(plate, points) -> Array:
    """Which search points (x, y) the search leaves out: inside a mount's disc, or off the plate (`ring_points` of
    a mount on an edge); all False without mounts."""
    x, y = points
    if plate.mounts is None:
        return jnp.zeros(x.shape, bool)
    slack = 1e-9 * plate.length
    off = (x < -slack) | (x > plate.length + slack) | (jnp.abs(y) > plate.width / 2 + slack)
    return off | jnp.any(jnp.hypot(x[:, None] - plate.mounts[:, 0], y[:, None] - plate.mounts[:, 1])
                         < plate.mount_radius * (1 - 1e-9), axis=1)


ENVELOPE_CHUNK = 128
"""Times per pass of `plate_envelopes`: the fields of one pass on the JESD22 board's grid (625 points) take 2.6 MB,
so they stay in a core's cache between the matrix products that make them and the measures that read them; the
whole window's (1057 times) took 21 MB, and the grid's search ran two to three times slower where XLA scheduled
its passes beside other work."""


def plate_envelopes(plate, measures, points, *, fields=None, shapes=None, Q=None, mask=None):
    """Each of `measures`' largest value over the search points `points` (x, y) (m; mount discs and points off the
    plate left out) at every time of the grid, (len(measures), nt): from `fields` (u, k_xx, k_yy, k_xy) there, each
    (points, nt), or from the mode shapes there (`shapes`, each (points, n)), the modal factors `Q` = (scale (n,),
    R (nt, n)) and the modal mask `mask`, in passes of `ENVELOPE_CHUNK` times (the fields are never stored
    whole)."""
    near = near_mounts(plate, points)

    def envelope(fields):
        return jnp.stack([jnp.where(near[:, None], -jnp.inf, m(plate, *fields)).max(axis=0) for m in measures])

    if fields is not None:
        return envelope(fields)
    scale, R = Q
    nt, n = R.shape
    passes = -(-nt // ENVELOPE_CHUNK)
    padded = jnp.concatenate([R, jnp.zeros((passes * ENVELOPE_CHUNK - nt, n), R.dtype)])
    weighted = [v * (mask * scale) for v in shapes]
    out = jax.lax.map(lambda Rk: envelope([w @ Rk.T for w in weighted]), padded.reshape(passes, ENVELOPE_CHUNK, n))
    return jnp.moveaxis(out, 0, 1).reshape(len(measures), -1)[:, :nt]


def candidate_times(envelope, candidates: int):
    """Indices of the `candidates` largest local maxima in time of an envelope (nt,) (a lone spike at an end
    counts)."""
    left = jnp.concatenate([jnp.full((1,), -jnp.inf, envelope.dtype), envelope[:-1]])
    right = jnp.concatenate([envelope[1:], jnp.full((1,), -jnp.inf, envelope.dtype)])
    return _largest(jnp.where((envelope >= left) & (envelope >= right), envelope, -jnp.inf),
                    min(candidates, envelope.shape[0]))


def plate_starts(plate, measure: Callable, points, times, at_times):
    """Where a plate search starts: at each of the time indices `times` (e.g. `candidate_times`), the search point
    of `points` (x, y) (m; mount discs and points off the plate left out) with the measure's largest value, from
    the fields there at those times `at_times` (u, k_xx, k_yy, k_xy), each (points, len(times)). Returns the time
    indices, point indices and values."""
    A = jnp.where(near_mounts(plate, points)[:, None], -jnp.inf, measure(plate, *at_times))
    return times, A.argmax(axis=0), A.max(axis=0)


def _with_the_mounts(plate, px, py):
    """A maximiser (px, py) (m; no gradient) as a function of the mounts: on a mount's circle the constrained
    maximiser moves with the mount (and with the radius); elsewhere it stays."""
    if plate.mounts is None:
        return px, py

    def move(point, mount):
        px, py = point
        dx, dy = jax.lax.stop_gradient((px - mount[0], py - mount[1]))
        d = jnp.sqrt(dx * dx + dy * dy)
        on = d <= jax.lax.stop_gradient(plate.mount_radius) * (1 + 1e-6)
        d_safe = jnp.where(d > 0, d, 1.0)
        return (jnp.where(on, mount[0] + plate.mount_radius * dx / d_safe, px),
                jnp.where(on, mount[1] + plate.mount_radius * dy / d_safe, py))

    # Clipped: a disc across an edge (flagged) would put the point off the plate.
    return clip_to_plate(plate, *_over_mounts(plate, (px, py), move))


# The Newton refinement's derivatives: central differences (h = 1/16 cell) from the measure on the 3 x 3 x 3 grid
# around the point, from the modes' shapes at its 9 points in (x, y) and the modal coordinates at its 3 times (one
# product of the two). The 19-point stencil evaluated point by point costs twice the shapes (their Legendre
# recurrence) and six times the modal coordinates for the same numbers; nested automatic differentiation compiles
# to several times the program.
_H = 1.0 / 16
_OFFSETS = np.array([-_H, 0.0, _H])
_IN_PLANE = np.stack(np.meshgrid(_OFFSETS, _OFFSETS, indexing="ij"), axis=-1).reshape(9, 2)


def _central_differences(f: Float[Array, "9 3"]):
    """(value, gradient (3,), Hessian (3, 3)) at the centre of the grid of values `f` (x-major points by times)."""
    f = f.reshape(3, 3, 3)

    def at(*steps):  # the value at the centre + h * steps, (axis, +-1) per coordinate stepped
        index = [1, 1, 1]
        for axis, sign in steps:
            index[axis] += sign
        return f[tuple(index)]

    plus = jnp.stack([at((i, 1)) for i in range(3)])
    minus = jnp.stack([at((i, -1)) for i in range(3)])
    H = jnp.diag((plus - 2 * at() + minus) / _H**2)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        mixed = (at((i, 1), (j, 1)) - at((i, 1), (j, -1)) - at((i, -1), (j, 1)) + at((i, -1), (j, -1))) / (4 * _H**2)
        H = H.at[i, j].set(mixed).at[j, i].set(mixed)
    return at(), (plus - minus) / (2 * _H), H


def find_plate_peak(
    measure: Callable,
    coeffs: Float[Array, " n"],
    modal: Callable,
    modes,
    xi: Float[Array, " nx"],
    eta: Float[Array, " ny"],
    t: Float[Array, " nt"],
    window,
    starts: tuple,
    *,
    newton_steps: int = 6,
    refine: bool = True,
) -> PlatePeak:
    """Peak over a plate and the window of `measure(plate, u, k_xx, k_yy, k_xy)` (e.g. the largest principal
    surface strain) of the field with modal coefficients `coeffs` (the modes' `PlateModes`; `modal(t)` the modal
    coordinates), from the evenly spaced grid `xi` x `eta` (x / L, y / W) and times `t`, starting from `starts`
    (`plate_starts`: grid time and point indices and values; points past the grid's are `ring_points`).
    Each start is refined by Newton's method in (x, y, t) in a trust region of one grid cell (derivatives by
    central differences), steps that enter a mount disc projected onto its circle; a start on a mount's circle is
    refined along the circle, in (angle, t). The value's gradient is taken
    at the maximiser (envelope theorem); on a mount's circle the point moves with the mount. The error estimate is
    the larger of the last step's gain and the gain the quadratic model still expects within a cell of the point
    returned (bounds and discs respected), relative to the value."""
    plate = modes.plate
    n_plane = xi.shape[0] * eta.shape[0]
    cell = jnp.stack([xi[1] - xi[0], eta[1] - eta[0], t[1] - t[0]])
    xi, eta = (v.ravel() for v in jnp.meshgrid(xi, eta, indexing="ij"))
    idx, where_p, f_start = starts

    coeffs_c, modes_c, modal_c, window_c = stop_gradient((coeffs, modes, modal, window))
    plate_c = modes_c.plate
    cell = jax.lax.stop_gradient(cell)

    def point(z, mount):
        """(x, y) (m) of search coordinates z: (xi, eta) / cell on the plane (`mount` < 0), else the angle / its
        cell on that mount's circle (clipped to the plate: a mount on an edge), out of the mount discs."""
        px, py = z[0] * cell[0] * plate_c.length, z[1] * cell[1] * plate_c.width
        if plate_c.mounts is not None:
            s, c = sincos(z[0] * (2 * math.pi / RING_POINTS))
            centre = plate_c.mounts[jnp.maximum(mount, 0)]
            rx, ry = clip_to_plate(plate_c, centre[0] + plate_c.mount_radius * c, centre[1] + plate_c.mount_radius * s)
            px, py = _outside_mounts(plate_c, jnp.where(mount < 0, px, rx), jnp.where(mount < 0, py, ry))
        return px, py

    lo_plane = jnp.stack([0.0, -0.5, 0.0]) / cell
    hi_plane = jnp.stack([1.0, 0.5, window_c]) / cell
    circle_axes = np.array([True, True, False])  # on a circle the angle (and the unused coordinate) is free

    def bounds(mount):
        free = (mount >= 0) & circle_axes
        return jnp.where(free, -jnp.inf, lo_plane), jnp.where(free, jnp.inf, hi_plane)

    def project(z, mount):
        lo, hi = bounds(mount)
        z = jnp.clip(z, lo, hi)
        px, py = _outside_mounts(plate_c, z[0] * cell[0] * plate_c.length, z[1] * cell[1] * plate_c.width)
        # Clipped again: the disc of a mount near an edge reaches off the plate (the plate's checks refuse it).
        plane = jnp.clip(jnp.stack([px / plate_c.length / cell[0], py / plate_c.width / cell[1], z[2]]), lo, hi)
        return jnp.where(mount < 0, plane, z.at[1].set(0.0))

    def derivatives(z, mount):
        px, py = jax.vmap(lambda d: point(z.at[:2].add(d), mount))(_IN_PLANE)
        q = jax.vmap(lambda d: modal_c((z[2] + d) * cell[2]))(_OFFSETS)  # (3 times, n)
        weights = coeffs_c * q
        return _central_differences(measure(plate_c, *(s @ weights.T for s in modes_c.shapes(px, py))))

    def refine_one(z0, f_grid, mount):
        lo, hi = bounds(mount)

        # Each pass evaluates the pending point, keeps it if it gains, and proposes the next from the best so
        # far: the start is the first pending point, so the program holds one copy of the evaluation.
        def step(carry, _):
            z, f, g, H, _, _, radius, z_new = carry
            f_new, g_new, H_new = derivatives(z_new, mount)
            better = f_new > f
            keep = lambda a, b: jax.tree_util.tree_map(lambda u, v: jnp.where(better, u, v), a, b)  # noqa: E731
            z, f_kept, g, H = keep((z_new, f_new, g_new, H_new), (z, f, g, H))
            gain = jnp.where(better & (f > -jnp.inf), f_new - f, 0.0)
            radius = jnp.where(better, radius, 0.5 * radius)
            # Coordinates on a bound with the measure rising outwards stay there (a constrained maximum). "On" to
            # 1e-9 of a cell: a point projected out of a mount's disc comes back through metres and lands a few
            # ulps inside an edge, where a free Newton step outwards, clipped, turns the other coordinates' steps
            # off and the search stalls below the maximum (4e-6 on a screwed plate's edge).
            held = ((z <= lo + _ON_BOUND) & (g < 0)) | ((z >= hi - _ON_BOUND) & (g > 0))
            g_free = jnp.where(held, 0.0, g)
            H_free = jnp.where(held[:, None] | held[None, :], -jnp.eye(3, dtype=H.dtype), H)
            # Newton along the Hessian's concave directions, half a cell uphill along the others (none where the
            # measure is flat: a plate bent uniformly across its width, a circle's unused coordinate).
            w, V = symmetric_eigen3(H_free)
            gv = V.T @ g_free
            uphill = 0.5 * jnp.sign(gv) * (jnp.abs(gv) > 1e-9 * jnp.abs(f_kept))
            u = V @ jnp.where(w < 0, -gv / jnp.where(w < 0, w, -1.0), uphill)
            # What the quadratic model still expects from a step of at most a cell (whatever the trust radius, which
            # shrinks where steps fail): the search's error estimate, which a stalled search cannot hide.
            u_cell = project(z + u / jnp.maximum(1.0, jnp.max(jnp.abs(u))), mount) - z
            expected = jnp.maximum(g @ u_cell + 0.5 * u_cell @ H @ u_cell, 0.0)
            u = u * jnp.minimum(1.0, radius / jnp.maximum(jnp.max(jnp.abs(u)), 1e-30))
            return (z, f_kept, g, H, gain, expected, radius, project(z + u, mount)), None

        zero = jnp.zeros_like(f_grid)
        carry = (z0, jnp.full_like(f_grid, -jnp.inf), jnp.zeros_like(z0), jnp.zeros((3, 3), z0.dtype), zero, zero,
                 jnp.ones_like(f_grid), z0)
        carry, _ = jax.lax.scan(step, carry, None, length=(newton_steps if refine else 0) + 1)
        z, f, _, _, gain, expected = carry[:6]
        grid_wins = ~(f >= f_grid)
        z = jnp.where(grid_wins, z0, z)
        return jnp.stack([*point(z, mount), z[2] * cell[2]]), jnp.maximum(f, f_grid), jnp.maximum(gain, expected)

    ring = where_p - n_plane
    mount = jnp.where(ring >= 0, ring // RING_POINTS, -1)
    plane_p = jnp.minimum(where_p, n_plane - 1)
    z0 = jnp.where((ring >= 0)[:, None], jnp.stack([ring % RING_POINTS, jnp.zeros_like(ring), idx], axis=-1),
                   jnp.stack([xi[plane_p] / cell[0], eta[plane_p] / cell[1], idx], axis=-1)).astype(cell.dtype)
    z0 = z0.at[:, 2].set(t[idx] / cell[2])
    p_all, f_all, gain_all = jax.vmap(refine_one)(jax.lax.stop_gradient(z0), jax.lax.stop_gradient(f_start), mount)
    tied = f_all >= jnp.max(f_all) * (1.0 - 1e-9)
    best = jnp.argmin(jnp.where(tied, p_all[:, 2], jnp.inf))
    p_best = jax.lax.stop_gradient(p_all[best])
    px, py = _with_the_mounts(plate, p_best[0], p_best[1])
    t_star = jnp.where(p_best[2] >= window * (1.0 - 1e-9), window, p_best[2])
    q = modal(t_star)
    f = measure(plate, *(jnp.sum(coeffs * q * s) for s in modes.shapes(px, py)))
    err = jax.lax.stop_gradient(gain_all[best] / jnp.maximum(f_all[best], jnp.finfo(f_all.dtype).tiny))
    return PlatePeak(f, px, py, t_star, err)
