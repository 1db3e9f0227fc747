"""Peak of |sum_k c_k q_k(t) sin(k pi x / L)| over x in [0, L] and t in [0, window].

A coarse grid finds candidate peaks (the largest local maxima in time of the spatial envelope); Newton's method on
the modal series refines each within a grid cell; the largest wins. The peak's gradient is the gradient at the
maximiser (envelope theorem), so the maximiser enters under `stop_gradient`, except at the window's end, where the
window's own dependence on the parameters counts.
"""

import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float
from ._checks import float_dtype


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


def mode_shapes(x, length, n_modes: int) -> Float[Array, "... n"]:
    k = jnp.arange(1, n_modes + 1, dtype=float_dtype())
    return jnp.sin(jnp.asarray(x)[..., None] * k * math.pi / length)


def field_on_grid(coeffs, Q, x, length) -> Float[Array, "nx nt"]:
    """Field sum_k coeffs_k q_k(t) sin(k pi x / L) on the grid x (nx,) by t (nt,), with the modal coordinates
    given as factors Q = (scale (n,), R (nt, n)), q_k(t_j) = scale_k R[j, k].

    Keeping the factors apart matters under `vmap`: when only `scale` varies between drops (the board and pulse
    are shared), R is computed once and the drops fold into one large matrix product."""
    scale, R = Q
    return (mode_shapes(x, length, R.shape[-1]) * (coeffs * scale)) @ R.T


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
    length,
    window,
    *,
    candidates: int = 4,
    newton_steps: int = 6,
    refine: bool = True,
) -> FieldPeak:
    """Peak of |field| with `modal(t) -> q (n,)` the modal coordinates (a pytree callable with `jet(t) -> (q, q',
    q'')`, e.g. an `eqx.Module`)
    and `Q = modal.grid_factors(t)` on the grid (see `field_on_grid`)."""
    F = field_on_grid(coeffs, Q, x, length)
    A = jnp.abs(F)
    # A plain max over x, then arg-maxima only where needed: a full 2-D argmax is a slow variadic reduction.
    envelope = A.max(axis=0)
    if not refine:
        j = envelope.argmax()
        coarse = jnp.max(envelope[::2])
        err = (envelope[j] - coarse) / jnp.maximum(envelope[j], jnp.finfo(A.dtype).tiny)
        return FieldPeak(envelope[j], x[A[:, j].argmax()], t[j], err)

    # Candidates: the largest local maxima in time of the spatial envelope (a lone spike at an end counts).
    left = jnp.concatenate([jnp.full((1,), -jnp.inf, A.dtype), envelope[:-1]])
    right = jnp.concatenate([envelope[1:], jnp.full((1,), -jnp.inf, A.dtype)])
    is_local = (envelope >= left) & (envelope >= right)
    k_cand = min(candidates, envelope.shape[0])
    idx = _largest(jnp.where(is_local, envelope, -jnp.inf), k_cand)
    where_x = A[:, idx].argmax(axis=0)
    x0 = x[where_x]
    t0 = t[idx]
    sign0 = jnp.sign(F[where_x, idx])
    cell = jnp.stack([x[1] - x[0], t[1] - t[0]])
    lo = jnp.stack([jnp.zeros_like(length), jnp.zeros_like(window)])
    hi = jnp.stack([length, window])

    # The search itself is not differentiated: only the final evaluation at the maximiser is.
    coeffs_c, length_c, modal_c = stop_gradient((coeffs, length, modal))
    k = jnp.arange(1, coeffs.shape[-1] + 1, dtype=float_dtype()) * math.pi / length_c

    def value_grad_hess(p, sign):
        # Field derivatives in closed form in x; q, q', q'' from the modal solution's own jet in t.
        q, dq, ddq = modal_c.jet(p[1])
        sn, cs = jnp.sin(k * p[0]), jnp.cos(k * p[0])
        c = sign * coeffs_c
        f = jnp.sum(c * q * sn)
        g = jnp.stack([jnp.sum(c * q * k * cs), jnp.sum(c * dq * sn)])
        H = jnp.stack(
            [
                jnp.stack([-jnp.sum(c * q * k * k * sn), jnp.sum(c * dq * k * cs)]),
                jnp.stack([jnp.sum(c * dq * k * cs), jnp.sum(c * ddq * sn)]),
            ]
        )
        return f, g, H

    def refine_one(x0, t0, sign):
        def step(carry, _):
            p, f, g, H, gain = carry
            det = H[0, 0] * H[1, 1] - H[0, 1] ** 2
            concave = (H[0, 0] < 0) & (det > 0)
            det_safe = jnp.where(concave, det, 1.0)
            newton = -jnp.stack([H[1, 1] * g[0] - H[0, 1] * g[1], H[0, 0] * g[1] - H[0, 1] * g[0]]) / det_safe
            uphill = 0.5 * cell * jnp.sign(g)
            d = jnp.clip(jnp.where(concave, newton, uphill), -cell, cell)
            p_new = jnp.clip(p + d, lo, hi)
            f_new, g_new, H_new = value_grad_hess(p_new, sign)
            better = f_new > f
            keep = lambda a, b: jnp.where(better, a, b)  # noqa: E731
            return (keep(p_new, p), keep(f_new, f), keep(g_new, g), keep(H_new, H), keep(f_new - f, 0.0)), None

        p0 = jnp.stack([x0, t0])
        f0, g0, H0 = value_grad_hess(p0, sign)
        (p, f, _, _, gain), _ = jax.lax.scan(step, (p0, f0, g0, H0, jnp.zeros_like(f0)), None, length=newton_steps)
        return p, f, gain

    p_all, f_all, gain_all = jax.vmap(refine_one)(*stop_gradient((x0, t0, sign0)))
    best = jnp.argmax(f_all)
    p_best = jax.lax.stop_gradient(p_all[best])
    x_star = p_best[0]
    # A peak at the window's end moves with the window (which depends on the board): keep that dependence.
    at_end = p_best[1] >= window * (1.0 - 1e-9)
    t_star = jnp.where(at_end, window, p_best[1])
    q = modal(t_star)
    value = jnp.abs(jnp.sum(coeffs * q * mode_shapes(x_star, length, q.shape[-1])))
    err = jax.lax.stop_gradient(gain_all[best] / jnp.maximum(f_all[best], jnp.finfo(A.dtype).tiny))
    return FieldPeak(value, x_star, t_star, err)
