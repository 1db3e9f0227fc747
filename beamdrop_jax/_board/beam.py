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
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._common.checks import Flag, Range, combine, flag_if, float_dtype, is_concrete, on_host, require
from .._common.fields import check_ranges, init_fields, positive, range_flags
from .base import AbstractBoard
from .._common.trig import sincos

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
    phi = _shape_values(np, (b, a, c, d, s), xi[:, None], 0)
    dphi = _shape_values(np, (b, a, c, d, s), xi[:, None], 1)
    scale = np.sqrt(0.5 / (w @ phi**2))
    a, c, d, s = a * scale, c * scale, d * scale, s * scale
    phi, dphi = phi * scale, dphi * scale
    p_A, p_B = -2 * (w * (1 - xi)) @ phi, -2 * (w * xi) @ phi
    g = (w @ dphi**2) / 0.5
    return b, a, c, d, s, p_A, p_B, g


def _shape_values(xp, coeffs, xi, orders):
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


def _frequencies(board, n_modes: int) -> Float[Array, " n"]:
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


def _participation(board, n_modes: int) -> Float[Array, "n 2"]:
    if board.ends == "pinned":
        k = mode_numbers(n_modes)
        return jnp.stack([-2.0 / (k * math.pi), 2.0 * (-1.0) ** k / (k * math.pi)], axis=-1)
    modes = _modes(board.ends, n_modes)
    return jnp.stack([_jnp(modes[5]), _jnp(modes[6])], axis=-1)


def _curvature_scale(board, n_modes: int) -> Float[Array, " n"]:
    """Pinned: -(k pi / L)^2, which turns `mode_shapes(..., curvature=False)` (the sines) into phi_k''; else ones
    (`mode_shapes(..., curvature=True)` is then phi_k'')."""
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
        values = dict(zip(wanted, _shape_values(jnp, coeffs, x / L, wanted)))
        deflection = tuple(values[o] / L**o for o in orders)
        if curvature is False:
            out = deflection
        else:
            out = tuple(jnp.where(curvature, values[o + 2] / L ** (o + 2), v) for o, v in zip(orders, deflection))
    return out[0] if single else out


class Board(AbstractBoard):
    """Euler-Bernoulli board (SI units), its `ends` (at A, at B) one of `"pinned"` (default), `"clamped"`,
    `"clamped-pinned"`, `"pinned-clamped"`, `"clamped-free"`; clamps rotate with the housing.

    `axial_force` N is positive in tension; compression at or past the Euler load of the ends (pinned:
    EI pi^2 / L^2) buckles and is rejected; with ends other than pinned its effect on the frequencies is the
    Galerkin estimate on the unloaded modes. `damping_ratio` is the modal damping ratio zeta, the same for every
    mode, in [0, 1).
    """

    length: Float[Array, ""]
    thickness: Float[Array, ""]
    width: Float[Array, ""]
    youngs_modulus: Float[Array, ""]
    density: Float[Array, ""]
    axial_force: Float[Array, ""]
    damping_ratio: Float[Array, ""]
    ends: str = eqx.field(static=True)

    RANGES: ClassVar[dict] = {
        "length": positive("m", 1e-4, 100.0),
        "thickness": positive("m", 1e-6, 10.0),
        "width": positive("m", 1e-6, 100.0),
        "youngs_modulus": positive("Pa", 1.0, 1e13),
        "density": positive("kg/m^3", 1e-3, 1e6),
        # The buckling bound depends on the other fields: checked in __check_init__ and `flags`.
        "axial_force": (Range(unit="N"), Flag.NONFINITE_INPUT),
        "damping_ratio": (Range(0.0, 1.0, hi_open=True), Flag.DAMPING_RANGE),
    }

    def __init__(
        self,
        length=0.10,
        thickness=1.0e-3,
        width=0.05,
        youngs_modulus=22e9,
        density=1900.0,
        axial_force=0.0,
        damping_ratio=0.0,
        ends="pinned",
    ):
        if ends not in ENDS:
            import difflib

            near = difflib.get_close_matches(str(ends), ENDS, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise ValueError(f"Board.ends = {ends!r}{hint}; valid: {', '.join(ENDS)}")
        self.ends = ends
        init_fields(self, dict(length=length, thickness=thickness, width=width, youngs_modulus=youngs_modulus,
                                density=density, axial_force=axial_force, damping_ratio=damping_ratio))

    def __check_init__(self):
        check_ranges(self)
        if is_concrete(self):
            require(self.axial_force, "Board.axial_force", -float(np.max(on_host(self).buckling_force)), lo_open=True,
                    unit="N")

    @property
    def bending_stiffness(self) -> Float[Array, ""]:
        """EI = E b h^3 / 12, N m^2."""
        return self.youngs_modulus * self.width * self.thickness**3 / 12.0

    @property
    def mass_per_length(self) -> Float[Array, ""]:
        """rho A = rho b h, kg/m."""
        return self.density * self.width * self.thickness

    @property
    def buckling_force(self) -> Float[Array, ""]:
        """Euler load of the board's ends (N; pinned: EI pi^2 / L^2): compression of this size buckles it."""
        return self.bending_stiffness * EULER_LOAD[self.ends] / self.length**2

    SECTION: ClassVar[str] = "board"
    SURFACE: ClassVar[bool] = False

    def modes(self, n_modes: int) -> "Board":
        """A beam's modes are closed-form functions of the board and the mode count: the board is its own modes."""
        return self

    def frequencies(self, n_modes: int) -> Float[Array, " n"]:
        return _frequencies(self, n_modes)

    def participation(self, n_modes: int) -> Float[Array, "n 3"]:
        p = _participation(self, n_modes)
        return jnp.concatenate([p, jnp.zeros_like(p[:, :1])], axis=-1)  # a beam has no width: no roll

    def curvature_scale(self, n_modes: int) -> Float[Array, " n"]:
        return _curvature_scale(self, n_modes)

    TABLE_DURATIONS: ClassVar[bool] = True  # a beam's superposition table spans contact durations

    def mirror_symmetric(self) -> bool:
        """Whether the board's mode shapes are symmetric or antisymmetric about the middle (its ends alike), so a
        drop and its mirror image (A and B swapped) have mirrored peaks."""
        return self.ends in SYMMETRIC_ENDS

    def mode_shapes(self, x, n_modes: int, curvature=False, orders=0):
        """`mode_shapes(self, ...)`."""
        return mode_shapes(self, x, n_modes, curvature, orders)

    def describe(self) -> str:
        return f"beam {float(self.length) * 1e3:g} mm, {self.ends} ends"

    def flags(self):
        """Traceable checks of this board (int32 mask of `Flag`)."""
        return combine(range_flags(self), flag_if(~(self.axial_force > -self.buckling_force), Flag.BUCKLED))
