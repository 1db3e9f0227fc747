"""Routh's frictional impact law for one 2D contact, in closed form.

The contact velocity (S, C) (tangential, normal) moves linearly with the impulse P = (Pt, Pn):
(S, C) = (S0, C0) + B P, with B = [[B1, -B3], [-B3, B2]] symmetric positive definite. The normal impulse Pn grows
monotonically, and between events the impulse path is a straight line, so Routh's graphical method is exact:

1. slide with s = sign(S0) (for S0 = 0: stick at once if mu >= |B3|/B1, else slide with s = -sign(B3)),
   dPt/dPn = -s mu;
2. if mu B1 + s B3 > 0 the slip stops on the stick line S = 0 at Pn_s = |S0| / (mu B1 + s B3);
3. on the stick line it stays stuck (dPt/dPn = B3/B1) when mu >= |B3|/B1, otherwise slip reverses for good
   (dPt/dPn = s mu).

So the path has at most two straight pieces and the normal velocity C(Pn) is piecewise linear. Maximum compression is
the first point where C = 0; the restitution law picks the termination point on the same path. Every division is
guarded (`_safe_div`), so the untaken branches of `jnp.where` cannot put NaN into gradients (jax#1052).

References: Routh (1905); Wang & Mason, "Two-dimensional rigid-body collisions with friction", J. Appl. Mech. 59
(1992); Stronge, "Impact Mechanics" (2000).
"""

import enum
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._common.checks import Flag, Range, array_module, as_float, combine, flag_if, is_concrete
from .._common.compile import jit
from .._common.report import plain, summary_text


class ImpactMode(enum.IntEnum):
    """How the contact slips during the impact (Wang & Mason's cases)."""

    SLIDING = 0
    """Slides in one direction throughout."""
    STICK_IN_COMPRESSION = 1
    """Slip stops (or never starts) before maximum compression and the contact stays stuck."""
    STICK_IN_RESTITUTION = 2
    """Slip stops after maximum compression and the contact stays stuck."""
    REVERSAL_IN_COMPRESSION = 3
    """Slip stops before maximum compression and reverses (mu < |B3|/B1)."""
    REVERSAL_IN_RESTITUTION = 4
    """Slip stops after maximum compression and reverses."""

    @property
    def label(self) -> str:
        return self.name.lower().replace("_", " ")


LAWS = ("poisson", "newton", "stronge")


class ImpactResult(eqx.Module):
    """Outcome of one impact.

    - `P`: final impulse (Pt, Pn), N s.
    - `Pn_compression`: normal impulse at maximum compression.
    - `Pn_stick`: normal impulse where slip stops or reverses (inf when it never does).
    - `mode`: an `ImpactMode` value (int array).
    - `velocity`: contact velocity (S, C) after the impact.
    - `energy_change`: change of kinetic energy, J (<= 0 for Poisson and Stronge).
    - `path`: vertices of the impulse path, (3, 2) rows (Pt, Pn): start, stick/reversal point (clipped to the
      end), end.
    - `flags`: `Flag` mask (SEPARATING_CONTACT when C0 > 0: then P = 0).
    """

    P: Float[Array, "2"]
    Pn_compression: Float[Array, ""]
    Pn_stick: Float[Array, ""]
    mode: Int[Array, ""]
    velocity: Float[Array, "2"]
    energy_change: Float[Array, ""]
    path: Float[Array, "3 2"]
    flags: Int[Array, ""]

    def summary(self) -> dict:
        """The impact's numbers, units in the keys (JSON-ready; `repr` prints them)."""

        if jnp.ndim(self.mode):
            raise ValueError("ImpactResult.summary() needs one impact (index a batched one first)")
        return plain({
            "impulse_Ns": self.P,
            "normal_impulse_at_max_compression_Ns": self.Pn_compression,
            "contact_mode": ImpactMode(int(self.mode)).label,
            "contact_velocity_after_m_per_s": self.velocity,
            "energy_change_J": self.energy_change,
            "flags": Flag.describe(self.flags),
        })

    def __repr__(self) -> str:
        try:
            return summary_text(self.summary(), "ImpactResult")
        except (ValueError, TypeError, jax.errors.ConcretizationTypeError):
            return eqx.tree_pformat(self)


@jax.custom_jvp
def _div(num, den):
    return num / den


@_div.defjvp
def _div_jvp(primals, tangents):
    # JAX's own rule forms den**-2, which underflows for den ~ 1e-160 although num/den is representable.
    num, den = primals
    t_num, t_den = tangents
    quotient = num / den
    return quotient, (t_num - quotient * t_den) / den


def _safe_div(num, den, ok):
    """num / den where `ok`, else 0; the untaken branch divides by 1 so its gradient stays finite."""
    den_safe = jnp.where(ok, den, 1.0)
    return jnp.where(ok, _div(num, den_safe), 0.0)


def _safe_sqrt(x):
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


class _Path(eqx.Module):
    """The impulse path as two straight pieces in Pn: [0, Pn_s] and [Pn_s, inf)."""

    Pn_s: Array  # end of piece 1 (inf when slip never stops)
    has_stick: Array
    dPt1: Array  # dPt/dPn on each piece
    dPt2: Array
    dC1: Array  # dC/dPn on each piece
    dC2: Array
    C0: Array
    stays_stuck: Array

    def C_at_stick(self):
        return self.C0 + self.dC1 * jnp.where(self.has_stick, self.Pn_s, 0.0)

    def Pt(self, Pn):
        first = jnp.minimum(Pn, self.Pn_s)
        second = jnp.maximum(Pn - self.Pn_s, 0.0)
        return self.dPt1 * first + jnp.where(self.has_stick, self.dPt2 * second, 0.0)

    def Pn_where_C_reaches(self, target):
        """First Pn >= 0 at which C = target (target >= 0 > C0), with division only by positive slopes."""
        rise = target - self.C0
        # On piece 1 iff it rises (dC1 > 0) and gets there before the stick point: rise <= dC1 Pn_s.
        on_first = (self.dC1 > 0) & (~self.has_stick | (rise <= self.dC1 * jnp.where(self.has_stick, self.Pn_s, 0.0)))
        pn_first = _safe_div(rise, self.dC1, on_first)
        pn_second = jnp.where(self.has_stick, self.Pn_s, 0.0) + _safe_div(
            target - self.C_at_stick(), self.dC2, ~on_first
        )
        return jnp.where(on_first, pn_first, pn_second)

    def work(self, Pn):
        """Normal work integral of C dPn from 0 to Pn (trapezoids are exact on the linear pieces)."""
        pn_s = jnp.where(self.has_stick, self.Pn_s, jnp.inf)
        p1 = jnp.minimum(Pn, pn_s)
        w1 = self.C0 * p1 + 0.5 * self.dC1 * p1**2
        p2 = jnp.maximum(Pn - jnp.where(self.has_stick, self.Pn_s, 0.0), 0.0)
        p2 = jnp.where(self.has_stick, p2, 0.0)
        w2 = self.C_at_stick() * p2 + 0.5 * self.dC2 * p2**2
        return w1 + w2


def _path(B, v0, mu) -> _Path:
    B1, B2, B3 = B[0, 0], B[1, 1], -B[0, 1]
    S0, C0 = v0[0], v0[1]
    sign_B3 = jnp.where(B3 >= 0, 1.0, -1.0)
    # S0 = 0: slide against B3 (if friction cannot hold, that is the only consistent direction; if it can, the
    # stick point is at Pn = 0 below and the direction never matters).
    s = jnp.where(S0 > 0, 1.0, jnp.where(S0 < 0, -1.0, -sign_B3))
    slowing = mu * B1 + s * B3
    # Slowing within a few ulps of zero puts the stick point beyond any termination (and 1/slowing^2 in its
    # gradient past overflow); at that boundary sliding and sticking follow the same line anyway.
    has_stick = slowing > 16 * jnp.finfo(slowing.dtype).eps * (mu * B1 + jnp.abs(B3))
    # No impact impulse exceeds |v0| / lambda_min(B) <= |v0| trace(B) / det(B) by much, so a stick point 1e3 times
    # further out is never reached: calling it "no stick" is exact and keeps 1/slowing^2 finite in gradients.
    reach = 1e3 * (jnp.abs(S0) + jnp.abs(C0)) * (B1 + B2) / (B1 * B2 - B3**2)
    has_stick = has_stick & (jnp.abs(S0) < slowing * reach)
    moving = has_stick & (S0 != 0)
    Pn_s = jnp.where(has_stick, _safe_div(jnp.abs(S0), slowing, moving), jnp.inf)
    stays_stuck = mu * B1 >= jnp.abs(B3)
    dPt1 = -s * mu
    dPt2 = jnp.where(stays_stuck, B3 / B1, s * mu)
    dC1 = B2 + s * mu * B3
    dC2 = jnp.where(stays_stuck, (B1 * B2 - B3**2) / B1, B2 - s * mu * B3)
    return _Path(Pn_s, has_stick, dPt1, dPt2, dC1, dC2, C0, stays_stuck)


FRICTION = Range(0.0)
RESTITUTION = Range(0.0, 1.0)


def _positive_definite(B):
    """Finite, symmetric to round-off, and positive definite (traceable)."""
    xp = array_module(B)
    scale = xp.max(xp.abs(B))
    symmetric = xp.abs(B[0, 1] - B[1, 0]) <= 1e-12 * scale
    # The determinant of the symmetric part: an asymmetry within round-off of a huge entry must not make a
    # singular B look definite (B = [[1e30, -1], [1e-300, 0]] did, and its impulse was NaN).
    off = (B[0, 1] + B[1, 0]) / 2
    det = B[0, 0] * B[1, 1] - off * off
    return xp.all(xp.isfinite(B)) & symmetric & (B[0, 0] > 0) & (B[1, 1] > 0) & (det > 0)


def _check_eagerly(B, v0, mu, e):
    FRICTION.require(mu, "friction")
    RESTITUTION.require(e, "restitution")
    if not np.all(np.isfinite(np.asarray(v0))):
        raise ValueError(f"v0 = {np.asarray(v0).tolist()}: the approach velocity (S0, C0) must be finite, m/s")
    with np.errstate(invalid="ignore", over="ignore"):  # inf * 0 in a bad B: that B is refused below
        positive_definite = bool(_positive_definite(np.asarray(B)))
    if not positive_definite:
        raise ValueError(f"B = {np.asarray(B).tolist()}: the contact's inverse inertia must be a finite, symmetric, "
                         "positive definite 2 x 2 matrix [[B1, -B3], [-B3, B2]] (B1 > 0, B1 B2 - B3^2 > 0), 1/kg")


def routh_impulse(
    B: Float[Array, "2 2"],
    v0: Float[Array, "2"],
    friction,
    restitution,
    law: str = "poisson",
) -> ImpactResult:
    """Impulse of a frictional 2D impact by Routh's method, exact and branch-free.

    **Arguments:**
    - `B`: inverse inertia at the contact, [[B1, -B3], [-B3, B2]] (1/kg), positive definite.
    - `v0`: contact velocity (S0, C0) before impact, m/s; C0 < 0 approaches the ground.
    - `friction`: Coulomb coefficient mu >= 0. `restitution`: e in [0, 1].
    - `law`: `"poisson"` (default; Pn_f = (1 + e) Pn_c), `"newton"` (C_f = -e C0; can create energy when slip
      stops or reverses) or `"stronge"` (restitution work = -e^2 compression work).

    **Returns:** an `ImpactResult`. With C0 > 0 the contact separates: P = 0 and `Flag.SEPARATING_CONTACT` is set.
    With C0 = 0 the impulse is zero unless the Painleve-type case B2 + s mu B3 < 0 holds, where friction drives the
    contact into compression ("tangential impact", Wang & Mason 1992); the path formula then gives that impulse.

    Poisson and Stronge never create kinetic energy in a single 2D contact; Newton can. Example: B1 = B2 = 2.5,
    B3 = 1.5, (S0, C0) = (0.5, -1), mu = 0.8, e = 1: slip stops at Pn = 1/7, the contact sticks, and Newton ends at
    P = (0.4375, 1.0625) with an energy *gain* of 7/64 J, where Poisson ends at P = (0.325, 0.875) and loses 0.05 J.
    """
    if law not in LAWS:
        raise ValueError(f"law = {law!r}; valid laws: {', '.join(LAWS)}")
    B = as_float(B, "B", "a symmetric positive definite 2 x 2 matrix, 1/kg")
    v0 = as_float(v0, "v0", "(S0, C0), finite, m/s")
    mu = as_float(friction, "friction", FRICTION)
    e = as_float(restitution, "restitution", RESTITUTION)
    if B.shape != (2, 2) or v0.shape != (2,):  # one contact per call: `jax.vmap` for many
        raise ValueError(f"B must have shape (2, 2) and v0 shape (2,); got {B.shape} and {v0.shape}")
    for name, value in (("friction", mu), ("restitution", e)):
        if value.shape != ():
            raise ValueError(f"{name} must be one number (shape ()); got shape {value.shape}; for many contacts, "
                             "jax.vmap routh_impulse")
    if is_concrete(B, v0, mu, e):
        _check_eagerly(B, v0, mu, e)
    return _routh(B, v0, mu, e, law)


@functools.partial(jit, static_argnums=4)  # one compiled program, not one per operation, when called eagerly
def _routh(B, v0, mu, e, law: str) -> ImpactResult:
    separating = v0[1] > 0
    # Separating contacts are computed as if C0 = 0 so every intermediate stays finite; the result is zeroed.
    v0_used = jnp.stack([v0[0], jnp.minimum(v0[1], 0.0)])
    path = _path(B, v0_used, mu)
    C0 = v0_used[1]

    Pn_c = path.Pn_where_C_reaches(jnp.zeros_like(C0))
    if law == "poisson":
        Pn_f = (1.0 + e) * Pn_c
    elif law == "newton":
        Pn_f = path.Pn_where_C_reaches(-e * C0)
    else:
        Pn_f = _stronge_end(path, Pn_c, e)
    Pn_f = jnp.where(separating, 0.0, Pn_f)
    Pn_c = jnp.where(separating, 0.0, Pn_c)
    Pt_f = path.Pt(Pn_f)
    P = jnp.stack([Pt_f, Pn_f])

    stick_happens = path.has_stick & (path.Pn_s < Pn_f)
    in_compression = path.Pn_s <= Pn_c
    mode = jnp.where(
        ~stick_happens,
        ImpactMode.SLIDING,
        jnp.where(
            path.stays_stuck,
            jnp.where(in_compression, ImpactMode.STICK_IN_COMPRESSION, ImpactMode.STICK_IN_RESTITUTION),
            jnp.where(in_compression, ImpactMode.REVERSAL_IN_COMPRESSION, ImpactMode.REVERSAL_IN_RESTITUTION),
        ),
    ).astype(jnp.int32)

    velocity = v0 + B @ P
    energy_change = v0 @ P + 0.5 * P @ B @ P
    Pn_mid = jnp.minimum(jnp.where(path.has_stick, path.Pn_s, Pn_f), Pn_f)
    vertices = jnp.stack([jnp.zeros(2, dtype=P.dtype), jnp.stack([path.Pt(Pn_mid), Pn_mid]), P])
    flags = combine(
        flag_if(separating, Flag.SEPARATING_CONTACT),
        flag_if(~RESTITUTION.contains(e), Flag.RESTITUTION_RANGE),
        flag_if(~FRICTION.contains(mu), Flag.FRICTION_NEGATIVE),
        flag_if(~jnp.all(jnp.isfinite(v0)), Flag.NONFINITE_INPUT),
        flag_if(~_positive_definite(B), Flag.CONTACT_MATRIX),
    )
    return ImpactResult(
        P=P,
        Pn_compression=Pn_c,
        Pn_stick=path.Pn_s,
        mode=mode,
        velocity=velocity,
        energy_change=energy_change,
        path=vertices,
        flags=flags,
    )


def _stronge_end(path: _Path, Pn_c, e):
    """Pn where the restitution work reaches -e^2 times the compression work."""
    W_target = -(e**2) * path.work(Pn_c)  # >= 0
    pn_s = jnp.where(path.has_stick, path.Pn_s, jnp.inf)
    stick_after = pn_s > Pn_c
    # After Pn_c, C >= 0 and rises with slope c on the piece that holds Pn_c.
    c_here = jnp.where(stick_after, path.dC1, path.dC2)
    gap = jnp.where(stick_after & path.has_stick, path.Pn_s - Pn_c, jnp.inf)
    W_to_stick = jnp.where(jnp.isfinite(gap), 0.5 * c_here * jnp.where(jnp.isfinite(gap), gap, 0.0) ** 2, jnp.inf)
    within = W_target <= W_to_stick
    c_ok = c_here > 0
    end_within = Pn_c + _safe_sqrt(_safe_div(2.0 * W_target, c_here, c_ok))
    # Past the stick point: C_s dp + c2 dp^2 / 2 = W_rest, in the cancellation-free root form.
    C_s = path.C_at_stick()
    W_rest = jnp.maximum(W_target - jnp.where(within, 0.0, W_to_stick), 0.0)
    root = C_s + _safe_sqrt(C_s**2 + 2.0 * path.dC2 * W_rest)
    dp = _safe_div(2.0 * W_rest, root, root > 0)
    end_after = jnp.where(path.has_stick, path.Pn_s, 0.0) + dp
    return jnp.where(within, end_within, end_after)
