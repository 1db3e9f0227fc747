"""The beam board model: natural frequencies, participation of the supports' rigid motion, and mode shapes for every
end condition (`Board.ends`).

The relative deflection u(x, t) from the chord AB (x from A) obeys
rho A u_tt + EI u_xxxx - N u_xx = -rho A [a_A(t) (1 - x/L) + a_B(t) x/L] (+ modal damping),
with u = 0 at pinned and clamped ends, u_x = 0 at clamps (relative to the housing: clamps rotate with it) and zero
moment and shear at a free end. With modes phi_k normalised so that int_0^1 phi_k(xi)^2 dxi = 1/2 (as sin(k pi xi)):
q_k'' + 2 zeta omega_k q_k' + omega_k^2 q_k = p_kA a_A(t) + p_kB a_B(t),
p_kA = -2 int_0^1 (1 - xi) phi_k, p_kB = -2 int_0^1 xi phi_k; for pinned ends p_kA = -2/(k pi), p_kB = 2 (-1)^k/(k pi).

Every mode is phi(xi) = a e^{b (xi - 1)} + c e^{-b xi} + d cos(b xi) + s sin(b xi) with b = beta L a root of the
end conditions' characteristic equation (pinned: k pi, clamped-clamped: cos b cosh b = 1, clamped-pinned:
tan b = tanh b, clamped-free: cos b cosh b = -1): the hyperbolic parts written as decaying exponentials, so no
term overflows or cancels at high mode numbers, in float32 too. The roots and coefficients are computed once per
(ends, mode count) in float64 NumPy. The modes are exact for N = 0; with an axial force the frequencies of
non-pinned boards take the Galerkin (Rayleigh) value on these modes, omega^2 = (EI b^4 + N L^2 g) / (rho A L^4)
with g = int phi'^2 / int phi^2, exact for pinned ends. Rotation-induced (centrifugal, Euler) loads are neglected.
"""

import functools
import math

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._checks import float_dtype
from ._plate import Plate, PlateModes, plate_frequencies, plate_participation
from ._trig import sincos

ENDS = ("pinned", "clamped", "clamped-pinned", "pinned-clamped", "clamped-free")
"""End conditions (end A, end B): pinned-pinned, clamped-clamped, clamped at A and pinned at B, ..."""

# Euler buckling loads in units of EI / L^2 (exact: pi^2, 4 pi^2, 2.0457 pi^2 (tan x = x), pi^2 / 4).
EULER_LOAD = {"pinned": math.pi**2, "clamped": 4 * math.pi**2, "clamped-pinned": 20.190728556426,
              "pinned-clamped": 20.190728556426, "clamped-free": math.pi**2 / 4}

# Ends whose mode shapes are symmetric or antisymmetric about the middle: a drop and its mirror image (the roles
# of A and B swapped) have mirrored peaks.
SYMMETRIC_ENDS = ("pinned", "clamped")


def _characteristic(ends: str, b):
    """A root function of the characteristic equation, divided by cosh so that it stays bounded."""
    if ends == "clamped":
        return np.cos(b) - 1 / np.cosh(b)
    if ends == "clamped-free":
        return np.cos(b) + 1 / np.cosh(b)
    return np.sin(b) - np.cos(b) * np.tanh(b)  # clamped-pinned, pinned-clamped


@functools.lru_cache(maxsize=64)
def _modes(ends: str, n_modes: int) -> tuple[np.ndarray, ...]:
    """(b, a, c, d, s, p_A, p_B, g) per mode, float64 NumPy (see the module docstring)."""
    k = np.arange(1, n_modes + 1, dtype=np.float64)
    if ends == "pinned":
        b = k * np.pi
        zero = np.zeros(n_modes)
        return b, zero, zero, zero, np.ones(n_modes), -2 / b, 2 * (-1) ** k / b, b**2
    guess = {"clamped": (k + 0.5) * np.pi, "clamped-free": (k - 0.5) * np.pi}.get(ends, (k + 0.25) * np.pi)
    lo, hi = guess - 0.45, guess + 0.45
    f_lo = _characteristic(ends, lo)
    for _ in range(80):  # bisection: each bracket holds one sign change
        mid = (lo + hi) / 2
        f_mid = _characteristic(ends, mid)
        left = np.sign(f_mid) == np.sign(f_lo)
        lo, f_lo, hi = np.where(left, mid, lo), np.where(left, f_mid, f_lo), np.where(left, hi, mid)
    b = (lo + hi) / 2
    sn, cs, em = np.sin(b), np.cos(b), np.exp(-b)
    # phi = (cosh y - cos y) - sigma (sinh y - sin y), y = b xi, clamped at xi = 0; sigma from the far end's
    # condition. cosh y - sigma sinh y = ((1 - sigma) e^y + (1 + sigma) e^-y) / 2, with (1 - sigma) e^b in closed
    # form (no cancellation).
    if ends == "clamped-free":
        den = 1 - em**2 + 2 * sn * em
        sigma = (1 + em**2 + 2 * cs * em) / den
        a = (sn - cs - em) / den  # (1 - sigma) e^b / 2
    else:
        den = 1 - em**2 - 2 * sn * em
        sigma = (1 + em**2 - 2 * cs * em) / den
        a = (cs - sn - em) / den
    c, d, s = (1 + sigma) / 2, -np.ones(n_modes), sigma
    if ends == "pinned-clamped":  # the mirror image of clamped-pinned: phi(1 - xi)
        a, c, d, s = c, a, d * cs + s * sn, d * sn - s * cs
    # Normalise to int phi^2 = 1/2, and the participation factors and g, by Gauss-Legendre quadrature.
    xg, wg = np.polynomial.legendre.leggauss(max(64, 8 * n_modes))
    xi, w = (xg + 1) / 2, wg / 2
    phi = _evaluate(np, (b, a, c, d, s), xi[:, None], 0)
    dphi = _evaluate(np, (b, a, c, d, s), xi[:, None], 1)
    scale = np.sqrt(0.5 / (w @ phi**2))
    a, c, d, s = a * scale, c * scale, d * scale, s * scale
    phi, dphi = phi * scale, dphi * scale
    p_A, p_B = -2 * (w * (1 - xi)) @ phi, -2 * (w * xi) @ phi
    g = (w @ dphi**2) / 0.5
    return b, a, c, d, s, p_A, p_B, g


def _evaluate(xp, coeffs, xi, orders):
    """d^order phi / d xi^order at xi (broadcast against the modes) for each of `orders` (an int gives one array),
    with array module xp (numpy or jax.numpy); the exponentials and the sine and cosine are evaluated once."""
    b, a, c, d, s = coeffs
    ep, em = xp.exp(b * (xi - 1)), xp.exp(-b * xi)
    if xp is np:
        sn, cs = np.sin(b * xi), np.cos(b * xi)
    else:
        sn, cs = sincos(b * xi)
    # Derivatives of d cos + s sin cycle with period 4.
    trig = (d * cs + s * sn, s * cs - d * sn, -(d * cs + s * sn), d * sn - s * cs)
    one = lambda order: b**order * (a * ep + (-1) ** order * c * em + trig[order % 4])  # noqa: E731
    return one(orders) if isinstance(orders, int) else tuple(one(o) for o in orders)


def _jnp(values) -> Array:
    return jnp.asarray(values, dtype=float_dtype())


def mode_numbers(n_modes: int) -> Float[Array, " n"]:
    return jnp.arange(1, n_modes + 1, dtype=float_dtype())


def wavenumbers(board, n_modes: int) -> Float[Array, " n"]:
    """beta_k = b_k / L for k = 1..n (k pi / L for pinned ends), 1/m."""
    if board.ends == "pinned":
        return mode_numbers(n_modes) * math.pi / board.length
    return _jnp(_modes(board.ends, n_modes)[0]) / board.length


def natural_frequencies(board, n_modes: int) -> Float[Array, " n"]:
    """Undamped natural frequencies omega_k (rad/s), k = 1..n, including the axial force.

    A buckled board (axial force at or past the Euler load of its ends) has no real frequency; it is flagged by
    `Board.flags()` and the frequencies are clamped to a tiny positive value so nothing downstream is NaN.
    A `Plate` gives its lowest n (`_plate`).
    """
    if isinstance(board, Plate):
        return plate_frequencies(board, n_modes)
    if isinstance(board, PlateModes):  # a plate's modes, solved once per drop
        return board.frequencies()[:n_modes]
    # Pinned ends in closed form: traced, these compile to a faster per-drop loop than the same numbers as
    # constants (measured: direct Monte-Carlo 2.5x faster).
    if board.ends == "pinned":
        beta = wavenumbers(board, n_modes)
        geometric = beta**2
    else:
        modes = _modes(board.ends, n_modes)
        beta = _jnp(modes[0]) / board.length
        geometric = _jnp(modes[7]) / board.length**2
    omega2 = (board.bending_stiffness * beta**4 + board.axial_force * geometric) / board.mass_per_length
    tiny = jnp.finfo(omega2.dtype).tiny ** 0.25
    return jnp.sqrt(jnp.maximum(omega2, tiny))


def support_participation(board, n_modes: int) -> Float[Array, "n 2"]:
    """Modal forcing per unit support acceleration: F_k = p_kA a_A + p_kB a_B (columns p_A, p_B); beams and
    plates (`_plate`)."""
    if isinstance(board, Plate):
        return plate_participation(board, n_modes)
    if isinstance(board, PlateModes):
        return board.participation()[:n_modes]
    if board.ends == "pinned":
        k = mode_numbers(n_modes)
        return jnp.stack([-2.0 / (k * math.pi), 2.0 * (-1.0) ** k / (k * math.pi)], axis=-1)
    modes = _modes(board.ends, n_modes)
    return jnp.stack([_jnp(modes[5]), _jnp(modes[6])], axis=-1)


def modal_velocity_jumps(board, jumps: Float[Array, "2"], n_modes: int) -> Float[Array, " n"]:
    """The modal velocities an ideal impulse with support velocity jumps (dvA, dvB) leaves, m/s."""
    return support_participation(board, n_modes) @ jnp.asarray(jumps)


def curvature_scale(board, n_modes: int) -> Float[Array, " n"]:
    """Per mode, the factor that turns `mode_shapes(..., curvature=False)` into curvature shapes phi_k'' where
    that is possible (pinned: -(k pi / L)^2), else ones (`mode_shapes(..., curvature=True)` is then phi_k'')."""
    if board.ends == "pinned":
        return -(wavenumbers(board, n_modes) ** 2)
    return jnp.ones(n_modes, dtype=float_dtype())


def mode_shapes(board, x, n_modes: int, curvature=False, orders=0):
    """The deflection shapes phi_k(x / L) (x in m, from end A; shape (..., n)) or their x-derivatives of each of
    `orders` (a tuple gives a tuple, evaluated together), or with `curvature` (a bool or a traced 0/1) those of
    the curvature shapes phi_k''; pinned boards always give the sine and its derivatives (their curvature is the
    sine times `curvature_scale`)."""
    x = jnp.asarray(x)[..., None]
    L = board.length
    single = isinstance(orders, int)
    orders = (orders,) if single else tuple(orders)
    if board.ends == "pinned":
        k = mode_numbers(n_modes) * (math.pi / L)
        sn, cs = sincos(x * k)
        # Plain products (integer powers here compiled slower in the peak search's inner loop).
        derivative = {0: sn, 1: k * cs, 2: -(k * k) * sn, 3: -(k * k * k) * cs, 4: (k * k) * (k * k) * sn}
        out = tuple(derivative[o] for o in orders)
    else:
        coeffs = tuple(_jnp(v) for v in _modes(board.ends, n_modes)[:5])
        wanted = orders if curvature is False else orders + tuple(o + 2 for o in orders)
        values = dict(zip(wanted, _evaluate(jnp, coeffs, x / L, wanted)))
        deflection = tuple(values[o] / L**o for o in orders)
        if curvature is False:
            out = deflection
        else:
            out = tuple(jnp.where(curvature, values[o + 2] / L ** (o + 2), v) for o, v in zip(orders, deflection))
    return out[0] if single else out
