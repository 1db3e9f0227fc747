"""The plate board model: a Kirchhoff plate on edges and point mounts, by the Ritz method.

The plate spans x in [0, L] from end A along the board and y in [-W/2, W/2] across it (perpendicular to the plane
of motion), thickness h, D = E h^3 / (12 (1 - nu^2)). Its relative deflection u obeys
D lap^2 u + rho h u_tt = -rho h [a_A(t) (1 - x/L) + a_B(t) x/L] with the edges' and mounts' conditions, so with
modes normalised as the beam's (int int phi^2 dxi deta = 1/2, xi = x/L, eta = y/W) the modal equations are the
beam's, q_k'' + 2 zeta omega_k q_k' + omega_k^2 q_k = p_kA a_A + p_kB a_B with p_kA = -2 int int (1 - xi) phi_k and
p_kB = -2 int int xi phi_k: every closed form and solver of the beam applies unchanged.

Ritz basis psi_ab = X_a(xi) Y_b(eta):
- along x: sin(a pi xi) when both x-edges are simply supported (Levy type: the x-dependence is exact and the modes
  of each a decouple; with nu = 0 and free sides the beam's modes are members of the basis, so the plate equals
  the pinned-pinned beam to rounding), else Legendre polynomials times xi^p (1 - xi)^q (p, q = 0 free,
  1 supported, 2 clamped), which meets the edges' geometric conditions;
- across: Legendre polynomials times (1/2 + eta)^p (1/2 - eta)^q.
Mounts (u = 0 at points, rotation free) are imposed exactly: the stiffness is reduced to the subspace of basis
combinations that vanish at the mounts (Householder reflections), so frequencies and modes are smooth
(differentiable) in the mount positions. (Shifting the held directions above the spectrum instead, by twice the
stiffness's trace, which spans ~1e11 at a 32 x 32 basis, cost the lowest eigenvalues ~3e-5 of their accuracy.)
The basis integrals are constants (Gauss-Legendre quadrature in NumPy float64); the plate's size and material enter
as scalars, so `jax.grad` reaches every float field.

Surface strains on the face z = h/2 from the curvatures k_xx = u_xx, k_yy = u_yy, k_xy = u_xy: with
c = (k_xx + k_yy) / 2 and r = sqrt(((k_xx - k_yy) / 2)^2 + k_xy^2) the principal strains are -(h/2) (c +- r), so the
largest magnitude is (h/2) (|c| + r); the largest principal plane stress is E (h/2) (|c| / (1 - nu) + r / (1 + nu)).

Where the model stops holding (each check raises a `ValueError` naming the field and its valid range on concrete
values, and sets a `Flag` bit under `jit`, where the results are NaN):
- Mechanisms (`Flag.MECHANISM`). A Kirchhoff plate's bending energy vanishes exactly for its rigid motions
  w = a + b x + c y, so the plate is held iff its supports leave none of them free: a clamped edge, or two supported
  edges, hold them all; one supported edge leaves the turn about that edge, which the mounts must hold; free edges
  leave heave and every tilt, which the mounts must hold. The criterion is geometric, so it is exact and cheap, and
  it is graded by the one length the model does not resolve, `mount_radius`: the plate is refused when some rigid
  tilt its edges allow moves every mount by less than `mount_radius` per unit slope, i.e. all the mounts lie within
  `mount_radius` of the tilt's axis (with free edges: of some line, so the mounts' smallest width is below
  2 `mount_radius`; with one supported edge: of that edge). The plate is then held against that tilt only inside the
  discs where the point supports' moments are singular and a real screw's head clamps, which the model leaves out:
  with zero lever it is a mechanism (today's frequency would be 0 to rounding), and just above zero the first
  frequency falls towards 0 with the lever. On the JESD22 board (132 x 77 x 1 mm, `mount_radius` 3 mm) with a third
  screw off the line of two, the fundamental in Leissa's parameter omega L^2 sqrt(rho h / D) (L the longer side) is
  0.0009, 0.035, 0.35, 1.0, 2.0, 3.3 for offsets of 1e-6, 1e-4, 1e-3, 3e-3, 6e-3, 1e-2 m, against 11.6 on its four
  corner screws and 3.5 for a cantilever clamped along a short edge: offsets below 6 mm are refused.
- Mounts that the model cannot tell apart (`Flag.MOUNTS_COINCIDE`): two mounts closer than `mount_radius` (one
  inside the other's disc; identical mounts make the constraint singular, nearly identical ones ill-conditioned).
- Mount discs (`Flag.MOUNT_OUTSIDE_PLATE`): every mount lies on the plate, and its disc of `mount_radius` too,
  except where the mount sits on an edge itself (a boundary point support, as Leissa's corner-supported plates):
  each mount's distance to each edge is 0 or at least `mount_radius`. The peak search stays on the plate.
- Thin-plate theory (`Flag.OUTSIDE_THEORY`). Kirchhoff's theory neglects transverse shear and rotary inertia, so it
  holds for thickness small against the span: the plate is refused when its thickness exceeds a tenth of its
  shorter side (`THIN_PLATE_RATIO`), the usual limit of thin-plate theory (e.g. Szilard, Theories and Applications
  of Plate Analysis, 2004, ch. 1; at h/a = 0.1 the simply supported square plate's fundamental is already 3.5 %
  below Kirchhoff's in Mindlin's theory and in exact 3-D elasticity, Srinivas, Rao & Rao 1970). Its kinematics
  (and von Karman's) need small rotations: a response whose peak deflection exceeds a quarter of the shorter side
  (`DEFLECTION_RATIO`; a half-wave's slope pi w / a reaches pi/4) is flagged too, and `plate_notes` says when the
  deflection exceeds the thickness (linear theory then overestimates it: mid-plane stretching is not modelled).
"""

import dataclasses
import functools
from typing import ClassVar
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._common.checks import Flag, Range, as_float, combine, float_dtype, flag_if, is_concrete, on_host
from .._common.fields import check_ranges, init_fields, range_flags
from .base import AbstractBoard, AbstractModal
from .plate_checks import (_plate_problem, check_gauges, raise_if_outside_theory, _static_mechanism, _support_geometry, _too_thick, plate_notes)

EDGE_CODES = {"F": 0, "S": 1, "C": 2}  # the power of the distance to the edge in the Ritz basis
"""Edge conditions in Leissa's letters: free, simply supported, clamped."""

BASIS = (12, 12)
"""Ritz basis functions (along x, across y), the default of `Plate.basis`; the response checks it against a basis
4 larger each way (`Response.convergence.basis`). Point mounts make the strain near a screw (log r) need a richer
basis: on the JESD22 board a gauge between two screws moves by 6e-3 from 12 x 12 to 16 x 16 functions, by 2.2e-3
from 16 x 16 to 20 x 20 and by 1.5e-4 from 20 x 20 to 24 x 24, with 48 modes."""
BASIS_LIMITS = (2, 40)
"""The fewest and most Ritz functions `Plate.basis` takes each way (the scene file's `basis` and `--basis` too)."""

_QUADRATURE = 64  # Gauss-Legendre points per direction: exact for the polynomial products, 1e-16 for the sines


def _legendre(xp, s, n: int):
    """P_j(s), P_j'(s), P_j''(s) for j < n, stacked on a last axis (three-term recurrences; in JAX one loop, whose
    program stays small however many terms: unrolled, every evaluation site compiled its own long chain)."""
    one, zero = xp.ones_like(s), xp.zeros_like(s)

    def step(carry, j):
        (p0, p1), (dp0, dp1), (ddp0, ddp1) = carry
        p2 = ((2 * j + 1) * s * p1 - j * p0) / (j + 1)
        dp2, ddp2 = dp0 + (2 * j + 1) * p1, ddp0 + (2 * j + 1) * dp1
        return ((p1, p2), (dp1, dp2), (ddp1, ddp2)), (p2, dp2, ddp2)

    carry = ((one, s), (zero, one), (zero, zero))
    degrees = np.arange(1, max(n - 1, 1), dtype=np.float64)
    if xp is np:
        rows = []
        for j in degrees:
            carry, row = step(carry, j)
            rows.append(row)
        rest = tuple(np.stack(r, axis=-1) for r in zip(*rows)) if rows else (np.zeros(s.shape + (0,)),) * 3
    else:
        _, rest = jax.lax.scan(step, carry, jnp.asarray(degrees, dtype=s.dtype))
        rest = tuple(jnp.moveaxis(r, 0, -1) for r in rest)
    first = ((one, s), (zero, one), (zero, zero))
    return tuple(xp.concatenate([xp.stack(f, axis=-1), r], axis=-1)[..., :n] for f, r in zip(first, rest))


def _basis_1d(xp, z, n: int, codes: tuple[int, int], sines: bool, legendre=None):
    """Values and first and second derivatives (..., n) of the 1-D basis at z in [0, 1] (z = xi, or eta + 1/2);
    `legendre`: `_legendre(xp, 2 z - 1, n)` where the caller has it."""
    z = z[..., None]
    if sines:
        k = math.pi * np.arange(1, n + 1)
        sn, cs = xp.sin(k * z), xp.cos(k * z)
        return sn, k * cs, -(k**2) * sn
    p, q = codes
    P, dP, ddP = _legendre(xp, 2 * z[..., 0] - 1, n) if legendre is None else legendre
    dP, ddP = 2 * dP, 4 * ddP  # d/dz of P(2z - 1)
    f = z**p * (1 - z) ** q
    df = (p * z ** max(p - 1, 0) * (1 - z) ** q if p else 0.0) - (q * z**p * (1 - z) ** max(q - 1, 0) if q else 0.0)
    ddf = (
        (p * (p - 1) * z ** max(p - 2, 0) * (1 - z) ** q if p > 1 else 0.0)
        - (2 * p * q * z ** max(p - 1, 0) * (1 - z) ** max(q - 1, 0) if p and q else 0.0)
        + (q * (q - 1) * z**p * (1 - z) ** max(q - 2, 0) if q > 1 else 0.0)
    )
    return f * P, df * P + f * dP, ddf * P + 2 * df * dP + f * ddP


class _Basis(eqx.Module):
    """The Ritz basis of an edge set: per direction the 1-D functions and their constant integrals (float64)."""

    nx: int = eqx.field(static=True)
    ny: int = eqx.field(static=True)
    x_codes: tuple = eqx.field(static=True)
    y_codes: tuple = eqx.field(static=True)
    sines: bool = eqx.field(static=True)

    def x(self, xp, xi, legendre=None):
        return _basis_1d(xp, xi, self.nx, self.x_codes, self.sines, legendre)

    def y(self, xp, eta, legendre=None):
        return _basis_1d(xp, eta + 0.5, self.ny, self.y_codes, False, legendre)


@functools.lru_cache(maxsize=32)
def _integrals(basis: _Basis):
    """Per direction, in the M-orthonormal coordinates of that direction (Cholesky factor C, int X X = C C^T):
    (C^-1 int X'' X'' C^-T, C^-1 int X' X' C^-T, C^-1 int X'' X C^-T, C^-T, moments), float64 NumPy. The moments
    are int X, int xi X (x) and int Y, int eta Y (y, eta = y / W from the centre line)."""
    z, w = np.polynomial.legendre.leggauss(_QUADRATURE)
    z, w = (z + 1) / 2, w / 2
    out = []
    for values, weights, moments in ((basis.x(np, z), w, (w, w * z)), (basis.y(np, z - 0.5), w, (w, w * (z - 0.5)))):
        X, dX, ddX = values
        gram = lambda a, b: (a * weights[:, None]).T @ b  # noqa: E731
        C = np.linalg.cholesky(gram(X, X))
        Ci = np.linalg.inv(C)
        T = lambda m: Ci @ m @ Ci.T  # noqa: E731
        out.append((T(gram(ddX, ddX)), T(gram(dX, dX)), T(gram(ddX, X)), Ci.T, tuple(m @ X for m in moments)))
    return tuple(out)


@jax.custom_jvp
def _eigh(A):
    """Symmetric eigendecomposition whose derivative stays finite where eigenvalues repeat: pairs closer than
    1e-10 of their size mix with weight 0 (any basis of a repeated eigenspace is then a stationary
    choice; quantities that sum over that eigenspace get their exact derivative)."""
    lam, V = jnp.linalg.eigh(A)
    return lam, V


@_eigh.defjvp
def _eigh_jvp(primals, tangents):
    (A,), (dA,) = primals, tangents
    lam, V = _eigh(A)
    dA = (dA + dA.T) / 2
    gap = lam[None, :] - lam[:, None]
    close = jnp.abs(gap) <= 1e-10 * jnp.maximum(jnp.abs(lam)[None, :], jnp.abs(lam)[:, None])
    F = jnp.where(close, 0.0, 1.0 / jnp.where(close, 1.0, gap))
    VdAV = V.T @ dA @ V
    return (lam, V), (jnp.diagonal(VdAV), V @ (F * VdAV))


class Plate(AbstractBoard):
    """Kirchhoff plate board (SI units): `length` along the board from end A to end B (in the plane of motion),
    `width` across it, `thickness`; `edges` the conditions of the edges x = 0, y = -W/2, x = L, y = +W/2 in
    Leissa's letters (S supported, C clamped, F free; "SFSF": held at both ends, free sides); `mounts` points
    (x, y) (m, x from end A, y from the centre line) where the plate is held (u = 0, rotation free; screws,
    standoffs), with peaks searched outside discs of `mount_radius` around them (the bending moments are singular
    at a point support). `edges=None` means "FFFF" (held by its mounts only) when mounts are given, else "SFSF".
    Edges and mounts move with the housing; clamps rotate with it. `damping_ratio` is the modal damping ratio, the
    same for every mode. The supports must hold the plate, the mounts' discs lie on it and the plate be thin (see
    the module notes: `ValueError` on concrete values, `flags()` under `jit`).
    """

    length: Float[Array, ""]
    width: Float[Array, ""]
    thickness: Float[Array, ""]
    youngs_modulus: Float[Array, ""]
    density: Float[Array, ""]
    poisson_ratio: Float[Array, ""]
    damping_ratio: Float[Array, ""]
    mounts: Float[Array, "m 2"] | None
    mount_radius: Float[Array, ""]
    edges: str = eqx.field(static=True)
    basis: tuple = eqx.field(static=True)

    RANGES = {
        "length": (Range(1e-4, 100.0, unit="m"), Flag.NONPOSITIVE_SIZE),
        "width": (Range(1e-4, 100.0, unit="m"), Flag.NONPOSITIVE_SIZE),
        "thickness": (Range(1e-6, 10.0, unit="m"), Flag.NONPOSITIVE_SIZE),
        "youngs_modulus": (Range(1.0, 1e13, unit="Pa"), Flag.NONPOSITIVE_SIZE),
        "density": (Range(1e-3, 1e6, unit="kg/m^3"), Flag.NONPOSITIVE_SIZE),
        "poisson_ratio": (Range(0.0, 0.5, hi_open=True), Flag.NONPOSITIVE_SIZE),
        "damping_ratio": (Range(0.0, 1.0, hi_open=True), Flag.DAMPING_RANGE),
        "mount_radius": (Range(0.0, 1.0, lo_open=True, unit="m"), Flag.NONPOSITIVE_SIZE),
    }

    def __init__(self, length=0.132, width=0.077, thickness=1.0e-3, youngs_modulus=22e9, density=1900.0,
                 poisson_ratio=0.2, damping_ratio=0.0, edges=None, mounts=None, mount_radius=2.5e-3,
                 basis=None):
        if edges is None:  # DESIGN.md section 4: with mounts and no edges, held by the mounts only
            edges = "SFSF" if mounts is None else "FFFF"
        if not (isinstance(edges, str) and len(edges) == 4 and set(edges) <= set(EDGE_CODES)):
            raise ValueError(f"Plate.edges = {edges!r}; valid: four letters of S (supported), C (clamped), F (free) "
                             "for the edges x = 0, y = -W/2, x = L, y = +W/2, e.g. 'SFSF', 'SSSS', 'FFFF'")
        if basis is None:
            basis = BASIS
        if not (isinstance(basis, tuple) and len(basis) == 2 and all(isinstance(b, int) and BASIS_LIMITS[0] <= b <= BASIS_LIMITS[1]
                                                                     for b in basis)):
            raise ValueError(f"Plate.basis = {basis!r}; valid: (nx, ny), integers in [{BASIS_LIMITS[0]}, "
                             f"{BASIS_LIMITS[1]}]")
        self.edges, self.basis = edges, basis
        init_fields(self, dict(length=length, width=width, thickness=thickness, youngs_modulus=youngs_modulus,
                                density=density, poisson_ratio=poisson_ratio, damping_ratio=damping_ratio,
                                mount_radius=mount_radius))
        if mounts is None:
            self.mounts = None
        else:
            self.mounts = as_float(mounts, "Plate.mounts", Range(unit="m"))
            if self.mounts.ndim != 2 or self.mounts.shape[-1] != 2 or self.mounts.shape[0] < 1:
                raise ValueError(f"Plate.mounts has shape {self.mounts.shape}; valid: ((x, y), ...), at least one")

    def __check_init__(self):
        check_ranges(self)
        static = _static_mechanism(self)
        if static:
            raise ValueError(static)
        if is_concrete(self):
            if _single_precision(self):
                raise ValueError(PRECISION_MESSAGE)
            problem = _plate_problem(on_host(self))
            if problem:
                raise ValueError(problem)

    @property
    def bending_stiffness(self) -> Float[Array, ""]:
        """D = E h^3 / (12 (1 - nu^2)), N m."""
        return self.youngs_modulus * self.thickness**3 / (12.0 * (1.0 - self.poisson_ratio**2))

    SECTION: ClassVar[str] = "plate"
    SURFACE: ClassVar[bool] = True


    def modes(self, n_modes: int) -> "PlateModes":
        """The lowest `n_modes` modes (one eigensolve)."""
        return plate_modes(self, n_modes)

    def frequencies(self, n_modes: int) -> Float[Array, " n"]:
        return plate_frequencies(self, n_modes)

    def participation(self, n_modes: int) -> Float[Array, "n 3"]:
        return plate_participation(self, n_modes)

    def rigid_motion(self, jumps: Float[Array, "3"], points=None) -> Float[Array, " m"] | None:
        """The supports' rigid normal motion w = w_A (1 - x/L) + w_B x/L + w_R y/W at `points` (m; default the
        mounts; None without mounts) for inputs `jumps` (A, B, R) (`bd.HalfSine`)."""
        points = self.mounts if points is None else jnp.asarray(points)
        if points is None:
            return None
        s = points[..., 0] / self.length
        return jumps[0] * (1 - s) + jumps[1] * s + jumps[2] * points[..., 1] / self.width

    TABLE_DURATIONS: ClassVar[bool] = False  # a plate's superposition table holds one contact duration

    def check_gauges(self, points) -> None:
        check_gauges(self, points)

    def raise_if_outside_theory(self, flags, what: str) -> None:
        raise_if_outside_theory(self, flags, what)

    def notes(self, response) -> list[str]:
        return plate_notes(self, response)

    def refined(self, step: int = 4) -> "Plate":
        """The same plate with a Ritz basis `step` functions larger each way (at most 40): the basis check."""
        return dataclasses.replace(self, basis=tuple(min(b + step, 40) for b in self.basis))

    def mirror_symmetric(self, axis: str = "x") -> bool:
        """Whether a concrete plate maps onto itself under x -> L - x (`axis="x"`: its two ends alike, its mounts in
        mirror pairs) or under y -> -y (`axis="y"`: its two long edges alike, its mounts in pairs across the centre
        line); False for traced plates."""
        if axis not in ("x", "y"):
            raise ValueError(f"axis = {axis!r}; valid: 'x' (x -> L - x) or 'y' (y -> -y)")
        k = 0 if axis == "x" else 1
        if not is_concrete(self) or self.edges[k] != self.edges[k + 2]:
            return False
        if self.mounts is None:
            return True
        m = np.asarray(self.mounts)
        mirror = np.stack([float(self.length) - m[:, 0], m[:, 1]] if k == 0 else [m[:, 0], -m[:, 1]], axis=1)
        gaps = np.abs(m[:, None, :] - mirror[None, :, :]).max(axis=-1).min(axis=1)
        return bool(np.all(gaps <= 1e-9 * float(self.length)))

    def file_extras(self) -> dict:
        extras = {"edges": self.edges, "basis": list(self.basis)}
        if self.mounts is not None:
            extras["mounts"] = np.asarray(self.mounts).tolist()
        return extras

    def describe(self) -> str:
        mounts = "" if self.mounts is None else f", {self.mounts.shape[-2]} mounts"
        return (f"plate {float(self.length) * 1e3:g} x {float(self.width) * 1e3:g} mm, edges {self.edges}"
                f"{mounts}")

    def flags(self):
        """Traceable checks of this plate (int32 mask of `Flag`)."""
        flags = combine(range_flags(self), flag_if(_single_precision(self), Flag.PRECISION),
                        flag_if(_too_thick(jnp, self), Flag.OUTSIDE_THEORY))
        g = _support_geometry(jnp, self)
        return combine(flags, flag_if(jnp.any(g.off_plate | g.crossing, axis=-1), Flag.MOUNT_OUTSIDE_PLATE),
                       flag_if(~(g.hold >= self.mount_radius), Flag.MECHANISM),
                       flag_if(jnp.any(g.coincide, axis=-1), Flag.MOUNTS_COINCIDE))


PRECISION_MESSAGE = (
    "Plate fields are float32, and a plate needs float64: the Ritz stiffness spans ~1e9 between its lowest and "
    "highest eigenvalues, so float32 loses the low modes (errors of 1 % to 160 % in the frequencies). Enable "
    "float64 before building the scene: jax.config.update('jax_enable_x64', True) (the CLI: leave out --float32)")


def _single_precision(plate: Plate) -> bool:
    """Static: the plate's fields are float32 (or narrower)."""
    return jnp.finfo(jnp.result_type(plate.length)).bits < 64


def _basis_of(plate: Plate) -> _Basis:
    e = plate.edges
    sines = e[0] == e[2] == "S"
    return _Basis(plate.basis[0], plate.basis[1], (EDGE_CODES[e[0]], EDGE_CODES[e[2]]),
                  (EDGE_CODES[e[1]], EDGE_CODES[e[3]]), sines)


def _eigen(plate: Plate, n_modes: int):
    """(omega^2 (n,), modal coefficients in the basis (nx * ny, n)) of the lowest n modes, normalised so that
    int int phi^2 dxi deta = 1/2. Levy plates (sines along x, no mounts) solve one small problem per x-wave number,
    so the modes stay separated where frequencies of different wave numbers coincide (a square plate)."""
    basis = _basis_of(plate)
    (X2, X1, Xc, XT, _), (Y2, Y1, Yc, YT, _) = (tuple(jnp.asarray(v, dtype=float_dtype()) if isinstance(v, np.ndarray)
                                                       else v for v in d) for d in _integrals(basis))
    L, W, nu = plate.length, plate.width, plate.poisson_ratio
    n_basis = basis.nx * basis.ny
    if n_modes > n_basis:
        raise ValueError(f"{n_modes} modes asked of a plate with a Ritz basis of {n_basis} functions "
                         f"(Plate.basis = {plate.basis}); valid: n_modes <= {n_basis}")
    scale = plate.bending_stiffness / (plate.density * plate.thickness)
    if basis.sines and plate.mounts is None:
        d = lambda m: jnp.diagonal(m)[:, None, None]  # noqa: E731 - the x-integrals are diagonal for sines
        blocks = (d(X2) * jnp.eye(basis.ny, dtype=X2.dtype) / L**4 + Y2 / W**4 + nu * d(Xc) * (Yc + Yc.T) / (L * W) ** 2
                  + 2 * (1 - nu) * d(X1) * Y1 / (L * W) ** 2)
        lam, V = jax.vmap(_eigh)((blocks + jnp.swapaxes(blocks, 1, 2)) / 2)  # (nx, ny), (nx, ny, ny)
        order = jnp.argsort(lam.ravel())[:n_modes]
        a, j = order // basis.ny, order % basis.ny
        cols = (YT @ V)[a, :, j]  # (n, ny)
        coeffs = jax.nn.one_hot(a, basis.nx, dtype=lam.dtype)[:, :, None] * (jnp.diagonal(XT)[a][:, None, None]
                                                                              * cols[:, None, :])
        return lam.ravel()[order] * scale, coeffs.reshape(n_modes, n_basis).T / math.sqrt(2.0)
    Ix, Iy = jnp.eye(basis.nx, dtype=X2.dtype), jnp.eye(basis.ny, dtype=X2.dtype)
    A = (jnp.kron(X2, Iy) / L**4 + jnp.kron(Ix, Y2) / W**4
         + nu * (jnp.kron(Xc, Yc.T) + jnp.kron(Xc.T, Yc)) / (L * W) ** 2 + 2 * (1 - nu) * jnp.kron(X1, Y1) / (L * W) ** 2)
    A = (A + A.T) / 2
    if plate.mounts is None:
        lam, V = _eigh(A)
    else:
        # The combinations that vanish at the mounts: the last n - m coordinates after m Householder reflections.
        G = _values(plate, plate.mounts[:, 0] / L, plate.mounts[:, 1] / W) @ jnp.kron(XT, YT)  # (m, n_basis)
        m = G.shape[0]
        reflectors = _householder(G.T)
        B = _reflect(reflectors, _reflect(reflectors, A).T)[m:, m:]
        lam, V = _eigh((B + B.T) / 2)
        V = _reflect(reflectors, jnp.concatenate([jnp.zeros((m, V.shape[1]), V.dtype), V]), inverse=True)
        # The m directions the mounts hold come last, above the spectrum, with no shape (`PlateModes.n_free`).
        lam = jnp.concatenate([lam, jnp.full(m, 2 * jnp.trace(B), lam.dtype)])
        V = jnp.concatenate([V, jnp.zeros((n_basis, m), V.dtype)], axis=1)
    return lam[:n_modes] * scale, jnp.kron(XT, YT) @ V[:, :n_modes] / math.sqrt(2.0)


def _householder(Gt):
    """Unit vectors (m, n) of the Householder reflections H_k = I - 2 v_k v_k^T that make H_m ... H_1 Gt upper
    triangular (Gt (n, m) of full column rank; m static): the last n - m columns of H_1 ... H_m span the vectors
    that Gt^T maps to 0. Differentiable in Gt (a QR of a tall matrix in full mode is not, in JAX)."""
    n, m = Gt.shape
    out = []
    for k in range(m):
        x = jnp.where(jnp.arange(n) >= k, Gt[:, k], 0.0)
        v = x.at[k].add(jnp.where(x[k] >= 0, 1.0, -1.0) * jnp.linalg.norm(x))  # no cancellation
        v = v / jnp.linalg.norm(v)
        Gt = Gt - 2.0 * jnp.outer(v, v @ Gt)
        out.append(v)
    return jnp.stack(out)


def _reflect(reflectors, X, inverse: bool = False):
    """H_m ... H_1 X (the reflections of `_householder`), or with `inverse` H_1 ... H_m X."""
    for v in (reflectors[::-1] if inverse else reflectors):
        X = X - 2.0 * jnp.outer(v, v @ X)
    return X


def _values(plate: Plate, xi, eta, derivatives: bool = False):
    """Basis products at points (xi, eta) (normalised coordinates; shapes broadcast): (..., nx * ny) values, or
    with `derivatives` (psi, psi_xx, psi_yy, psi_xy) in physical units (1/m^2)."""
    basis = _basis_of(plate)
    xi, eta = jnp.asarray(xi, dtype=float_dtype()), jnp.asarray(eta, dtype=float_dtype())
    if basis.sines:
        X, Y = basis.x(jnp, xi), basis.y(jnp, eta)
    else:  # both directions' polynomials from one recurrence (one loop in the program, not two)
        both = _legendre(jnp, 2 * jnp.stack(jnp.broadcast_arrays(xi, eta + 0.5)) - 1, max(basis.nx, basis.ny))
        X = basis.x(jnp, xi, tuple(v[0, ..., : basis.nx] for v in both))
        Y = basis.y(jnp, eta, tuple(v[1, ..., : basis.ny] for v in both))
    outer = lambda a, b: (a[..., :, None] * b[..., None, :]).reshape(a.shape[:-1] + (-1,))  # noqa: E731
    if not derivatives:
        return outer(X[0], Y[0])
    L, W = plate.length, plate.width
    return (outer(X[0], Y[0]), outer(X[2], Y[0]) / L**2, outer(X[0], Y[2]) / W**2, outer(X[1], Y[1]) / (L * W))


class PlateModes(AbstractModal):
    """The lowest modes of a plate: `omega2` (rad^2/s^2) and Ritz coefficients (nx * ny, n); evaluates shapes."""

    plate: Plate
    omega2: Float[Array, " n"]
    coeffs: Float[Array, "b n"]

    def shapes(self, x, y, derivatives: bool = True):
        """Mode shapes at points (x, y) (m; shapes broadcast): (phi, phi_xx, phi_yy, phi_xy), each (..., n), or
        phi alone without `derivatives`."""
        values = _values(self.plate, jnp.asarray(x) / self.plate.length, jnp.asarray(y) / self.plate.width,
                         derivatives=derivatives)
        return tuple(v @ self.coeffs for v in values) if derivatives else values @ self.coeffs

    def first(self, n_modes: int) -> "PlateModes":
        """The lowest `n_modes` of these modes (no new eigensolve)."""
        _check_mode_count(self.plate, n_modes)
        return PlateModes(self.plate, self.omega2[:n_modes], self.coeffs[:, :n_modes])

    @property
    def n_free(self) -> int:
        """How many of these modes are the plate's (static): the rest stand for the directions its mounts hold,
        above the spectrum and with no shape (`_eigen`)."""
        basis = self.plate.basis[0] * self.plate.basis[1]
        mounts = 0 if self.plate.mounts is None else self.plate.mounts.shape[-2]
        return min(self.omega2.shape[0], basis - mounts)

    def frequencies(self, n_modes: int | None = None) -> Float[Array, " n"]:
        """omega_k, rad/s (the lowest `n_modes`; all without)."""
        return jnp.sqrt(jnp.maximum(self.omega2, jnp.finfo(self.omega2.dtype).tiny ** 0.25))[:n_modes]


    def participation(self, n_modes: int | None = None) -> Float[Array, "n 3"]:
        """Modal forcing per unit support acceleration (columns p_A, p_B as the beam's, and p_R for the roll
        w = a_R y / W across the width; the lowest `n_modes`, all without)."""
        (_, _, _, _, (mx, mxi)), (_, _, _, _, (my, myi)) = _integrals(_basis_of(self.plate))
        moments = jnp.asarray(np.stack([np.kron(mx - mxi, my), np.kron(mxi, my), np.kron(mx, myi)], axis=-1),
                              dtype=float_dtype())
        return (-2.0 * self.coeffs.T @ moments)[:n_modes]

    @property
    def damping_ratio(self):
        return self.plate.damping_ratio

    def flags(self):
        return self.plate.flags()

    def describe(self) -> str:
        return f"modes of the {self.plate.describe()}"


def plate_modes(plate: Plate, n_modes: int) -> PlateModes:
    """The lowest n modes of a plate (one eigensolve; see `PlateModes`)."""
    _check_mode_count(plate, n_modes)
    return PlateModes(plate, *_eigen(plate, n_modes))


def _check_mode_count(plate: Plate, n_modes: int) -> None:
    """A basis with fewer functions than the modes asked of it is a configuration error (static: raised under
    `jit` too), named with the settings that fix it."""
    nx, ny = plate.basis
    if n_modes > nx * ny:
        raise ValueError(f"Plate.basis = ({nx}, {ny}) holds {nx * ny} functions, fewer than the {n_modes} modes "
                         f"computed (Numerics.max_modes or n_modes; 16 by default); valid: nx * ny >= {n_modes} "
                         "(`basis = [nx, ny]` in the scene file's [plate], --basis NX,NY), or fewer modes "
                         "(--max-modes, --n-modes)")


def plate_frequencies(plate: Plate, n_modes: int) -> Float[Array, " n"]:
    """Natural frequencies omega_k (rad/s) of the lowest n modes."""
    return plate_modes(plate, n_modes).frequencies()


def plate_participation(plate: Plate, n_modes: int) -> Float[Array, "n 3"]:
    """Modal forcing per unit support acceleration (columns p_A, p_B, p_R; `PlateModes.participation`)."""
    return plate_modes(plate, n_modes).participation()


def surface_strain(plate: Plate, kxx, kyy, kxy):
    """Largest principal surface strain magnitude from the curvatures (broadcast)."""
    c, r = _centre_radius(kxx, kyy, kxy)
    return plate.thickness / 2 * (jnp.abs(c) + r)


def surface_stress(plate: Plate, kxx, kyy, kxy):
    """Largest principal plane-stress magnitude (Pa) on the faces from the curvatures (broadcast)."""
    c, r = _centre_radius(kxx, kyy, kxy)
    nu = plate.poisson_ratio
    return plate.youngs_modulus * plate.thickness / 2 * (jnp.abs(c) / (1 - nu) + r / (1 + nu))


def _centre_radius(kxx, kyy, kxy):
    half = (kxx - kyy) / 2
    r2 = half * half + kxy * kxy
    # sqrt has an infinite derivative at 0 (equal principal curvatures); the gradient there is taken as 0.
    safe = r2 > 0
    return (kxx + kyy) / 2, jnp.where(safe, jnp.sqrt(jnp.where(safe, r2, 1.0)), 0.0)


def principal_strains(plate: Plate, kxx, kyy, kxy):
    """(e_1, e_2) on the face z = +h/2 (e = -z k), e_1 >= e_2, from the curvatures."""
    c, r = _centre_radius(kxx, kyy, kxy)
    z = plate.thickness / 2
    return -z * c + z * r, -z * c - z * r
