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
Mounts (u = 0 at points, rotation free) are imposed exactly: the stiffness is projected onto the subspace of basis
combinations that vanish at the mounts, so frequencies and modes are smooth (differentiable) in the mount positions.
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

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._checks import Flag, Range, combine, float_dtype, flag_if, is_concrete, on_host

EDGE_CODES = {"F": 0, "S": 1, "C": 2}  # the power of the distance to the edge in the Ritz basis
"""Edge conditions in Leissa's letters: free, simply supported, clamped."""

BASIS = (12, 12)
"""Ritz basis functions (along x, across y)."""

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


def _basis_1d(xp, z, n: int, codes: tuple[int, int], sines: bool):
    """Values and first and second derivatives (..., n) of the 1-D basis at z in [0, 1] (z = xi, or eta + 1/2)."""
    z = z[..., None]
    if sines:
        k = math.pi * np.arange(1, n + 1)
        sn, cs = xp.sin(k * z), xp.cos(k * z)
        return sn, k * cs, -(k**2) * sn
    p, q = codes
    P, dP, ddP = _legendre(xp, 2 * z[..., 0] - 1, n)
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

    def x(self, xp, xi):
        return _basis_1d(xp, xi, self.nx, self.x_codes, self.sines)

    def y(self, xp, eta):
        return _basis_1d(xp, eta + 0.5, self.ny, self.y_codes, False)


@functools.lru_cache(maxsize=32)
def _integrals(basis: _Basis):
    """Per direction, in the M-orthonormal coordinates of that direction (Cholesky factor C, int X X = C C^T):
    (C^-1 int X'' X'' C^-T, C^-1 int X' X' C^-T, C^-1 int X'' X C^-T, C^-T, moments), float64 NumPy. The moments
    are int X, int xi X (x) and int Y (y)."""
    z, w = np.polynomial.legendre.leggauss(_QUADRATURE)
    z, w = (z + 1) / 2, w / 2
    out = []
    for values, weights, moments in ((basis.x(np, z), w, (w, w * z)), (basis.y(np, z - 0.5), w, (w,))):
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
    1e-10 of the spectrum's scale mix with weight 0 (any basis of a repeated eigenspace is then a stationary
    choice; quantities that sum over that eigenspace get their exact derivative)."""
    lam, V = jnp.linalg.eigh(A)
    return lam, V


@_eigh.defjvp
def _eigh_jvp(primals, tangents):
    (A,), (dA,) = primals, tangents
    lam, V = _eigh(A)
    dA = (dA + dA.T) / 2
    gap = lam[None, :] - lam[:, None]
    close = jnp.abs(gap) <= 1e-10 * jnp.max(jnp.abs(lam))
    F = jnp.where(close, 0.0, 1.0 / jnp.where(close, 1.0, gap))
    VdAV = V.T @ dA @ V
    return (lam, V), (jnp.diagonal(VdAV), V @ (F * VdAV))


class Plate(eqx.Module):
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
                 basis=BASIS):
        from ._scene import _init_fields

        if edges is None:  # DESIGN.md section 4: with mounts and no edges, held by the mounts only
            edges = "SFSF" if mounts is None else "FFFF"
        if not (isinstance(edges, str) and len(edges) == 4 and set(edges) <= set(EDGE_CODES)):
            raise ValueError(f"Plate.edges = {edges!r}; valid: four letters of S (supported), C (clamped), F (free) "
                             "for the edges x = 0, y = -W/2, x = L, y = +W/2, e.g. 'SFSF', 'SSSS', 'FFFF'")
        if not (isinstance(basis, tuple) and len(basis) == 2 and all(isinstance(b, int) and 2 <= b <= 40
                                                                     for b in basis)):
            raise ValueError(f"Plate.basis = {basis!r}; valid: (nx, ny), integers in [2, 40]")
        self.edges, self.basis = edges, basis
        _init_fields(self, dict(length=length, width=width, thickness=thickness, youngs_modulus=youngs_modulus,
                                density=density, poisson_ratio=poisson_ratio, damping_ratio=damping_ratio,
                                mount_radius=mount_radius))
        if mounts is None:
            self.mounts = None
        else:
            from ._checks import as_float

            self.mounts = as_float(mounts, "Plate.mounts", Range(unit="m"))
            if self.mounts.ndim != 2 or self.mounts.shape[-1] != 2 or self.mounts.shape[0] < 1:
                raise ValueError(f"Plate.mounts has shape {self.mounts.shape}; valid: ((x, y), ...), at least one")

    def __check_init__(self):
        from ._scene import _check_ranges

        _check_ranges(self)
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

    def flags(self):
        """Traceable checks of this plate (int32 mask of `Flag`)."""
        from ._scene import _range_flags

        flags = combine(_range_flags(self), flag_if(_single_precision(self), Flag.PRECISION),
                        flag_if(_too_thick(jnp, self), Flag.OUTSIDE_THEORY))
        g = _support_geometry(jnp, self)
        return combine(flags, flag_if(jnp.any(g.off_plate | g.crossing, axis=-1), Flag.MOUNT_OUTSIDE_PLATE),
                       flag_if(~(g.hold >= self.mount_radius), Flag.MECHANISM),
                       flag_if(jnp.any(g.coincide, axis=-1), Flag.MOUNTS_COINCIDE))


THIN_PLATE_RATIO = 0.1
"""Largest thickness over the plate's shorter side for Kirchhoff (thin-plate) theory (see the module notes)."""

DEFLECTION_RATIO = 0.25
"""Largest peak deflection over the plate's shorter side for small-rotation kinematics (see the module notes)."""

_EDGE_NAMES = ("x = 0", "y = -W/2", "x = L", "y = +W/2")


def _edge_distances(xp, plate):
    """Each mount's signed distance (m) to the edges x = 0, y = -W/2, x = L, y = +W/2 (in `edges` order), (..., m, 4);
    negative off the plate."""
    L, W = (xp.asarray(v)[..., None] for v in (plate.length, plate.width))
    x, y = plate.mounts[..., 0], plate.mounts[..., 1]
    return xp.stack(xp.broadcast_arrays(x, y + W / 2, L - x, W / 2 - y), axis=-1)


class _Supports(NamedTuple):
    """The support geometry of a plate (arrays with the plate's batch axes): per mount `off_plate` (not on the
    plate, or not finite) and `crossing` (its disc across an edge it does not sit on), per pair of mounts
    `coincide` (closer than `mount_radius`; pairs (i, j), i < j, in `np.triu_indices` order), and `hold`: over the
    rigid tilts its edges leave free, the least of the largest distance of a mount from the tilt's axis (m; inf
    where the edges hold every rigid motion, 0 for a mechanism)."""

    off_plate: Array
    crossing: Array
    coincide: Array
    hold: Array


def _held_by_edges(edges: str) -> bool:
    """A clamped edge, or two supported edges, leave the plate no rigid motion."""
    return "C" in edges or edges.count("S") >= 2


def _support_geometry(xp, plate) -> _Supports:
    """The plate's `_Supports` with `xp` (NumPy for eager checks and messages, jax.numpy under tracing; no gradient
    flows through a check, and none is built: the distances' square roots are singular where mounts coincide)."""
    if xp is jnp:
        plate = jax.tree_util.tree_map(jax.lax.stop_gradient, plate)
    L, W, r = (xp.asarray(v) for v in (plate.length, plate.width, plate.mount_radius))
    batch = xp.broadcast_shapes(xp.shape(L), xp.shape(W), xp.shape(r),
                                () if plate.mounts is None else xp.shape(plate.mounts)[:-2])
    inf = xp.full(batch, xp.inf, dtype=xp.result_type(L))
    if plate.mounts is None:
        none = xp.zeros(batch + (0,), dtype=bool)
        return _Supports(none, none, none, inf if _held_by_edges(plate.edges) else xp.zeros_like(inf))
    d = _edge_distances(xp, plate)
    m = plate.mounts.shape[-2]
    size = xp.maximum(L, W)[..., None, None]
    on_edge = xp.abs(d) <= 1e-9 * size  # a mount on an edge: a boundary point support (a corner: two edges)
    off_plate = ~xp.all((d >= 0) | on_edge, axis=-1)
    crossing = xp.any((d < r[..., None, None]) & ~on_edge, axis=-1) & ~off_plate
    i, j = np.triu_indices(m, 1)
    sep = plate.mounts[..., j, :] - plate.mounts[..., i, :]  # (..., pairs, 2)
    dist = xp.sqrt(xp.sum(sep * sep, axis=-1))
    coincide = ~(dist >= r[..., None])
    if _held_by_edges(plate.edges):
        hold = inf
    elif "S" in plate.edges:  # the turn about the one supported edge: held by the mount farthest from it
        hold = xp.max(xp.maximum(d[..., plate.edges.index("S")], 0.0), axis=-1)
    elif m < 3:  # free edges: every mount lies on one line
        hold = xp.zeros_like(inf)
    else:
        # Free edges: the mounts' smallest width (the narrowest strip holding them all), halved. It is attained
        # across one side of their convex hull, so the directions normal to the pairs' separations are enough.
        apart = dist > 0
        n = xp.stack([-sep[..., 1], sep[..., 0]], axis=-1) / xp.where(apart, dist, 1.0)[..., None]
        proj = xp.sum(plate.mounts[..., None, :, :] * n[..., :, None, :], axis=-1)  # (..., pairs, m)
        widths = xp.where(apart, xp.max(proj, axis=-1) - xp.min(proj, axis=-1), xp.inf)
        width = xp.min(widths, axis=-1)
        hold = xp.where(width < xp.inf, width / 2, 0.0)  # every pair coincides: a single point
    return _Supports(off_plate, crossing, coincide, xp.broadcast_to(hold, batch))


def _too_thick(xp, plate):
    return ~(xp.asarray(plate.thickness) <= THIN_PLATE_RATIO * xp.minimum(plate.length, plate.width))


def _static_mechanism(plate: Plate) -> str | None:
    """The message for a plate whose edges, without mounts, leave it a rigid motion (known from the edges alone,
    so raised under tracing too), or None."""
    if plate.mounts is not None or _held_by_edges(plate.edges):
        return None
    if "S" in plate.edges:
        edge = _EDGE_NAMES[plate.edges.index("S")]
        return (f"Plate.edges = {plate.edges!r} without mounts is a mechanism: the plate turns freely about its one "
                f"supported edge {edge}; valid: a mount at least mount_radius from that edge (Plate.mounts), a second "
                "supported edge or a clamped one")
    return (f"a plate with free edges (Plate.edges = {plate.edges!r}) and no mounts moves as a rigid body (a "
            "mechanism); valid: at least 3 mounts not on one line (Plate.mounts), or supported or clamped edges")


def _fmt_points(points) -> str:
    return "[" + ", ".join(f"({x:.6g}, {y:.6g})" for x, y in np.asarray(points).reshape(-1, 2)) + "]"


def _plate_problem(plate: Plate) -> str | None:
    """The first problem of a concrete plate (NumPy fields; in a batch, the first plate with one), as a message
    naming the field and its valid range, or None."""
    batch = np.broadcast_shapes(*(np.shape(v) for v in (plate.length, plate.width, plate.thickness,
                                                         plate.mount_radius)),
                                () if plate.mounts is None else np.shape(plate.mounts)[:-2])
    if batch:
        g = _support_geometry(np, plate)
        bad = np.broadcast_to(_too_thick(np, plate), batch)
        if plate.mounts is not None:
            bad = bad | np.broadcast_to(np.any(g.off_plate | g.crossing, axis=-1) | np.any(g.coincide, axis=-1)
                                        | ~(g.hold >= plate.mount_radius), batch)
        if not np.any(bad):
            return None
        k = np.unravel_index(int(np.argmax(bad)), batch)
        pick = lambda v, tail=0: np.broadcast_to(v, batch + np.shape(v)[np.ndim(v) - tail:])[k]  # noqa: E731
        fields = (pick(plate.length), pick(plate.width), pick(plate.thickness), pick(plate.mount_radius))
        single = eqx.tree_at(lambda p: (p.length, p.width, p.thickness, p.mount_radius), plate, fields)
        if plate.mounts is not None:
            single = eqx.tree_at(lambda p: p.mounts, single, pick(plate.mounts, 2))
        return _plate_problem(single)
    L, W, r, h = (float(v) for v in (plate.length, plate.width, plate.mount_radius, plate.thickness))
    if _too_thick(np, plate):
        return (f"Plate.thickness = {h:g} m is {h / min(L, W):.3g} of the plate's shorter side ({min(L, W):g} m): "
                "outside thin-plate (Kirchhoff) theory, which neglects transverse shear and rotary inertia "
                f"(Flag.OUTSIDE_THEORY); valid: thickness <= {THIN_PLATE_RATIO:g} x min(length, width) = "
                f"{THIN_PLATE_RATIO * min(L, W):g} m")
    if plate.mounts is None:
        return None
    g = _support_geometry(np, plate)
    mounts = np.asarray(plate.mounts)
    if np.any(g.off_plate):
        return (f"Plate.mounts = {mounts.tolist()} m; valid: 0 <= x <= length = {L:g} m and |y| <= width/2 = "
                f"{W / 2:g} m (mount {int(np.argmax(g.off_plate))} is off the plate; Flag.MOUNT_OUTSIDE_PLATE)")
    if np.any(g.crossing):
        k = int(np.argmax(g.crossing))
        d = _edge_distances(np, plate)[k]
        e = int(np.argmin(np.where((d < r) & (np.abs(d) > 1e-9 * max(L, W)), d, np.inf)))
        return (f"Plate.mounts[{k}] = ({mounts[k, 0]:g}, {mounts[k, 1]:g}) m: its disc of mount_radius = {r:g} m "
                f"crosses the edge {_EDGE_NAMES[e]} ({d[e]:.3g} m away), so the plate's peak would be sought off "
                "the plate (Flag.MOUNT_OUTSIDE_PLATE); valid: each mount's disc on the plate, "
                + (f"{r:g} <= x <= {L - r:g} m and |y| <= {W / 2 - r:g} m" if 2 * r <= min(L, W) else
                   f"which needs Plate.mount_radius <= min(length, width) / 2 = {min(L, W) / 2:g} m")
                + ", or the mount on the edge itself (a boundary point support)")
    if not g.hold >= r:
        return _mechanism_message(plate, float(g.hold), r)
    if np.any(g.coincide):
        p = int(np.argmax(g.coincide))
        i, j = (int(v[p]) for v in np.triu_indices(mounts.shape[0], 1))
        gap = float(np.hypot(*(mounts[j] - mounts[i])))
        return (f"Plate.mounts {i} and {j} are {gap:.3g} m apart, closer than mount_radius = {r:g} m: the model "
                "cannot tell them apart (one lies in the other's disc, where nothing is resolved; identical mounts "
                f"make the constraint singular) (Flag.MOUNTS_COINCIDE); valid: mounts at least {r:g} m apart")
    return None


def _mechanism_message(plate: Plate, hold: float, r: float) -> str:
    mounts = np.asarray(plate.mounts)
    what = "a mechanism" if hold <= 1e-12 * max(float(plate.length), float(plate.width)) else "a near-mechanism"
    if "S" in plate.edges:
        edge = _EDGE_NAMES[plate.edges.index("S")]
        return (f"Plate.mounts = {_fmt_points(mounts)} m with Plate.edges = {plate.edges!r} leave {what} "
                f"(Flag.MECHANISM): the plate turns about its one supported edge {edge}, and every mount "
                f"(0 to {mounts.shape[0] - 1}) lies within {hold:.3g} m of that edge, so the turn is held only inside "
                f"the mount discs the model leaves out; valid: a mount at least mount_radius = {r:g} m from the "
                "edge, or a second supported or a clamped edge")
    # Free edges: the axis is the centre line of the narrowest strip holding the mounts.
    m = mounts.shape[0]
    i, j = np.triu_indices(m, 1)
    sep = mounts[j] - mounts[i]
    dist = np.hypot(sep[:, 0], sep[:, 1])
    if m >= 3 and np.any(dist > 0):
        n = np.stack([-sep[:, 1], sep[:, 0]], -1) / np.where(dist > 0, dist, 1.0)[:, None]
        proj = n @ mounts.T
        p = int(np.argmin(np.where(dist > 0, proj.max(-1) - proj.min(-1), np.inf)))
        where = (f"mounts {', '.join(map(str, range(m)))} all lie within {hold:.3g} m of one line (along mounts "
                 f"{int(i[p])} and {int(j[p])}): " + ("collinear" if what == "a mechanism" else "nearly collinear"))
    elif m >= 2:
        where = f"mounts {', '.join(map(str, range(m)))} lie on one line (fewer than 3 mounts)"
    else:
        where = "one mount holds a single point"
    close = [(int(a), int(b)) for a, b, dd in zip(i, j, dist) if dd < r]
    if close:
        where += "; " + ", ".join(f"mounts {a} and {b} (nearly) coincident" for a, b in close) + (
            " (Flag.MOUNTS_COINCIDE: closer than mount_radius)")
    return (f"Plate.mounts = {_fmt_points(mounts)} m with free edges (Plate.edges = {plate.edges!r}) leave {what} "
            f"(Flag.MECHANISM): {where}, so the plate tilts about that line held only inside the mount discs the "
            f"model leaves out; valid: at least 3 mounts not on one line, spread at least 2 x mount_radius = "
            f"{2 * r:g} m across any line (no line within mount_radius of every mount), or supported or clamped "
            "edges")


def _gauges_off(xp, plate: Plate, points):
    """Per gauge point (g, 2): not finite, off the plate, or inside a mount's disc (on its circle is on the plate)."""
    if xp is jnp:
        plate, points = jax.tree_util.tree_map(jax.lax.stop_gradient, (plate, points))
    x, y = points[..., 0], points[..., 1]
    on = (xp.isfinite(x) & xp.isfinite(y) & (x >= 0) & (x <= plate.length) & (xp.abs(y) <= plate.width / 2))
    if plate.mounts is None:
        return ~on
    inside = xp.any(xp.hypot(x[..., None] - plate.mounts[:, 0], y[..., None] - plate.mounts[:, 1])
                    < plate.mount_radius * (1 - 1e-9), axis=-1)
    return ~on | inside


def check_gauges(board, points) -> None:
    """Eagerly, a `ValueError` naming the first strain gauge (of points (g, 2), m) that is not finite, off the plate
    or inside a mount's disc (where a point support's strain is singular), and the valid region; no-op when traced
    or for a beam (whose gauges are refused elsewhere)."""
    if points is None or not isinstance(board, Plate) or not is_concrete(board, points):
        return
    plate, points = on_host(board), np.asarray(points)
    off = _gauges_off(np, plate, points)
    if not np.any(off):
        return
    k = int(np.argmax(off))
    L, W = float(plate.length), float(plate.width)
    why = ("is not finite" if not np.all(np.isfinite(points[k])) else
           "is off the plate" if not (0 <= points[k, 0] <= L and abs(points[k, 1]) <= W / 2) else
           f"is inside a mount's disc (mount_radius = {float(plate.mount_radius):g} m), where the point support's "
           "strain is singular")
    discs = "" if plate.mounts is None else (f", outside the discs of mount_radius = {float(plate.mount_radius):g} m"
                                             f" around the mounts {_fmt_points(plate.mounts)} m")
    raise ValueError(f"gauges[{k}] = ({points[k, 0]:g}, {points[k, 1]:g}) m {why} (Flag.GAUGE_OUTSIDE); valid: "
                     f"0 <= x <= length = {L:g} m and |y| <= width/2 = {W / 2:g} m{discs}")


def response_flags(plate: Plate, deflection, gauges=None):
    """Traceable checks of a plate's response: `Flag.OUTSIDE_THEORY` where the peak deflection (m) exceeds
    `DEFLECTION_RATIO` of the shorter side (beyond small rotations), `Flag.GAUGE_OUTSIDE` where a gauge point
    ((g, 2), m, or None) is not finite, off the plate or inside a mount's disc."""
    limit = DEFLECTION_RATIO * jnp.minimum(plate.length, plate.width)
    flags = flag_if(jax.lax.stop_gradient(deflection) > limit, Flag.OUTSIDE_THEORY)
    if gauges is not None:
        flags = combine(flags, flag_if(jnp.any(_gauges_off(jnp, plate, gauges)), Flag.GAUGE_OUTSIDE))
    return flags


def clip_to_plate(plate: Plate, x, y):
    """Points (x, y) (m) moved onto the plate's rectangle where they lie off it (inside, untouched, gradient
    included: a point on an edge keeps its own derivative)."""
    L, W = plate.length, plate.width
    x = jnp.where(x < 0, jnp.zeros_like(x), jnp.where(x > L, L, x))
    y = jnp.where(y < -W / 2, -W / 2, jnp.where(y > W / 2, W / 2, y))
    return x, y


def plate_grid_deflection(modes: "PlateModes", Q, mask):
    """The largest |deflection| (m) on the plate's search grid (2 points per basis function each way, edges
    included), from the modal factors Q = (scale (n,), R (nt, n)) and the mode mask: a cheap stand-in for the
    deflection peak where only `response_flags` needs it (no gradient)."""
    plate = modes.plate
    xi, eta = (jnp.linspace(lo, lo + 1.0, 2 * b + 1) for lo, b in zip((0.0, -0.5), plate.basis))
    XI, ETA = (v.ravel() for v in jnp.meshgrid(xi, eta, indexing="ij"))
    phi = modes.shapes(XI * plate.length, ETA * plate.width, derivatives=False)
    scale, R = Q
    u = (phi * (mask * scale)) @ R.T
    return jax.lax.stop_gradient(jnp.max(jnp.abs(u)))


def blank_readings(gauges, bad):
    """Gauge readings (`Gauges`) NaN where the response is flagged (`bad`): never a silent number."""
    names = ("exx", "eyy", "gxy", "strain", "peak_strain", "peak_time")
    return eqx.tree_at(lambda g: [getattr(g, n) for n in names], gauges,
                       [jnp.where(bad, jnp.nan, getattr(gauges, n)) for n in names])


def raise_if_outside_theory(board, flags, what: str) -> None:
    """Eagerly, a plate response's `Flag.OUTSIDE_THEORY` (its deflection; a thick plate is refused when built) as a
    `ValueError` naming the fields and the valid range."""
    if not isinstance(board, Plate) or not int(flags) & Flag.OUTSIDE_THEORY:
        return
    plate = on_host(board)
    short = float(np.min(np.minimum(plate.length, plate.width)))
    raise ValueError(
        f"{what}: the plate's peak deflection exceeds {DEFLECTION_RATIO:g} of its shorter side "
        f"({DEFLECTION_RATIO * short:.4g} m; Flag.OUTSIDE_THEORY): rotations too large for plate theory, whose "
        "kinematics assume small slopes (a half-wave's slope pi w / a reaches pi/4 there); the board is too flexible "
        f"for this drop (Plate.thickness = {float(np.max(plate.thickness)):g} m, Plate.youngs_modulus = "
        f"{float(np.max(plate.youngs_modulus)):g} Pa); valid: peak deflection <= {DEFLECTION_RATIO:g} x "
        "min(length, width): a thicker or stiffer plate, more support, or a gentler drop")


def plate_notes(plate: Plate, response) -> list[str]:
    """What a reader of a plate's numbers should know beyond a beam's notes (`response_notes`)."""
    notes = []
    h, short = float(plate.thickness), float(min(plate.length, plate.width))
    if h > short / 20:
        notes.append(f"the plate's thickness is {h / short:.2g} of its shorter side: thin-plate (Kirchhoff) theory "
                     "neglects transverse shear and rotary inertia, which lower the frequencies (by about 1 % at "
                     f"1/20, 3.5 % at 1/10, Mindlin); beyond {THIN_PLATE_RATIO:g} the plate is refused")
    return notes


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
    if plate.mounts is not None:
        G = _values(plate, plate.mounts[:, 0] / L, plate.mounts[:, 1] / W) @ jnp.kron(XT, YT)  # (m, n_basis)
        P = jnp.eye(n_basis, dtype=A.dtype) - G.T @ jnp.linalg.solve(G @ G.T, G)
        # The constrained directions move above the spectrum (a shift larger than every eigenvalue).
        A = P @ A @ P + (2 * jnp.trace(A)) * (jnp.eye(n_basis, dtype=A.dtype) - P)
        A = (A + A.T) / 2
    lam, V = _eigh(A)
    return lam[:n_modes] * scale, jnp.kron(XT, YT) @ V[:, :n_modes] / math.sqrt(2.0)


def _values(plate: Plate, xi, eta, derivatives: bool = False):
    """Basis products at points (xi, eta) (normalised coordinates; shapes broadcast): (..., nx * ny) values, or
    with `derivatives` (psi, psi_xx, psi_yy, psi_xy) in physical units (1/m^2)."""
    basis = _basis_of(plate)
    X = basis.x(jnp, jnp.asarray(xi, dtype=float_dtype()))
    Y = basis.y(jnp, jnp.asarray(eta, dtype=float_dtype()))
    outer = lambda a, b: (a[..., :, None] * b[..., None, :]).reshape(a.shape[:-1] + (-1,))  # noqa: E731
    if not derivatives:
        return outer(X[0], Y[0])
    L, W = plate.length, plate.width
    return (outer(X[0], Y[0]), outer(X[2], Y[0]) / L**2, outer(X[0], Y[2]) / W**2, outer(X[1], Y[1]) / (L * W))


class PlateModes(eqx.Module):
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

    def frequencies(self) -> Float[Array, " n"]:
        """omega_k, rad/s."""
        return jnp.sqrt(jnp.maximum(self.omega2, jnp.finfo(self.omega2.dtype).tiny ** 0.25))

    def participation(self) -> Float[Array, "n 2"]:
        """Modal forcing per unit support acceleration (columns p_A, p_B), as the beam's."""
        (_, _, _, _, (mx, mxi)), (_, _, _, _, (my,)) = _integrals(_basis_of(self.plate))
        moments = jnp.asarray(np.stack([np.kron(mx - mxi, my), np.kron(mxi, my)], axis=-1), dtype=float_dtype())
        return -2.0 * self.coeffs.T @ moments

    @property
    def damping_ratio(self):
        return self.plate.damping_ratio

    def flags(self):
        return self.plate.flags()


def plate_modes(plate: Plate, n_modes: int) -> PlateModes:
    """The lowest n modes of a plate (one eigensolve; see `PlateModes`)."""
    return PlateModes(plate, *_eigen(plate, n_modes))


def plate_frequencies(plate: Plate, n_modes: int) -> Float[Array, " n"]:
    """Natural frequencies omega_k (rad/s) of the lowest n modes."""
    return plate_modes(plate, n_modes).frequencies()


def plate_participation(plate: Plate, n_modes: int) -> Float[Array, "n 2"]:
    """Modal forcing per unit support acceleration (columns p_A, p_B), as the beam's."""
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
