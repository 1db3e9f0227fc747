"""The rigid frictional impact of one vertex in 3D (DESIGN.md section 7): Darboux-Keller in the normal impulse.

**Frame and law.** The contact frame is (t1, t2, n); K is the contact's inverse inertia there (3 x 3, symmetric
positive definite), u = u0 + K P the contact velocity as the impulse P grows. Write A = K_tt (the tangential 2 x 2
block), b = K_tn (the tangential-normal column), so that with the normal impulse p as the clock
du_t/dp = A dP_t/dp + b and du_n/dp = b . dP_t/dp + K_nn. While the contact slides with slip direction
s = u_t / |u_t|, dP_t/dp = -mu s, so du_t/dp = f(s) = b - mu A s: s turns during the impact. In 2D (b and A
scalars, s = +-1) this is Routh's law, and `routh_impulse`'s B = [[B1, -B3], [-B3, B2]] is exactly the (t1, n)
block of K: the conventions map one to one (P = (P_t1, P_n), u0 = (S0, C0)).

**Where slip stops.** When |u_t| reaches 0 the contact sticks if friction can hold it: the tangential impulse rate
that keeps u_t = 0 is -A^-1 b, admissible when |A^-1 b| <= mu; then du_t/dp = 0 and du_n/dp = K_nn - b . A^-1 b.
Otherwise it slides on along an invariant direction s*: a unit vector along which slip grows from zero, i.e.
f(s*) = lam s* with lam > 0, which is (mu A + lam I) s* = b. Its length |(mu A + lam I)^-1 b| falls strictly
as lam grows (A is positive definite), from |A^-1 b| / mu > 1 at lam = 0 (no stick) to at most 1 at lam = |b|:
so there is **exactly one** outward invariant direction, found by bisection on lam in [0, |b|] and a Newton step
(which also carries the implicit derivative). The direction equation s x f(s) = 0 has two or four roots on the
circle; the others have lam < 0: rays along which slip comes *to* a stop, not ones it can leave along. (In 2D:
s* = -sign(B3), lam = |B3| - mu B1, Routh's reversal. It is the diverging invariant ray of the slip flow: Batlle
1996; Stronge, Impact Mechanics, ch. 5. At s* the direction is also stable: d(s x f)/dphi = -lam -
mu s_perp . A s_perp < 0.) Along s* slip grows linearly and du_n/dp = K_nn - mu b . s* >=
K_nn - b . A^-1 b > 0. Either way the path after the stop is a straight line in impulse space, exactly (no
solver), and slip never stops again.

**The sliding phase, without the singularity.** Near the stop the direction s approaches an inward ray like
|u_t|^alpha with any alpha > 0, not smoothly in p, so the sliding phase runs in a clock tau with dp/dtau = |u_t|:
with the state (s, rho = log |u_t|, p, P_t, W) (W the normal work, the integral of u_n dp) the equations
ds/dtau = f - (s . f) s, drho/dtau = s . f, dp/dtau = e^rho, dP_t/dtau = -mu s e^rho, dW/dtau = u_n e^rho are smooth
and bounded, and the stop is rho -> -inf, reached exponentially in tau. (s is a unit vector, not an angle, so a
planar slip stays planar to the last bit.) The solve stops where the rest of the way to the stop is a straight
line to within 1e-13 (`_settled`: slip shrinks and the direction has reached its ray; at once on a planar path),
or at the latest where |u_t| falls to 1e-13 |u0| (`_SLIP_STOP`); the tail to the exact stop is then added along
the current direction (p += |u_t| / |s . f|). Likewise where growing slip has turned onto s* to within 1e-13
(`_aligned`) the rest is the straight line along s*: without this a slip that grows slowly along s* is stiff
(the direction relaxes far faster than the slip grows) and costs thousands of steps.

**Events and derivatives.** Compression ends at u_n = 0 (the first crossing, p_c); Poisson ends at (1 + e) p_c,
Stronge where W = (1 - e^2) W(p_c) (restitution work = -e^2 times the compression work). The sliding phase runs in
at most two segments (to compression or slip stop; then to the law's end or slip stop), each a diffrax `Dopri8`
solve (tolerances 1e-12) whose events end it at the end of the step where they hold; a reached target is then
located inside that step by Newton's method safeguarded by bisection, integrating from a known end of the step
with the solver's own method. The rest of the path after a stop (or once on s*) is closed form. The solves are
differentiated by their variational equations (forward sensitivities of the state at the final clock time,
chained through the segments by `_walk`'s custom derivative: a linear map on the tangents, which reverse mode
transposes; no derivative passes through diffrax's loops), and each event's state is moved onto its event surface
by one first-order step along the path, which gives its derivative the implicit-function form. No Python control
flow on traced values: the result `jit`s, `vmap`s and differentiates in forward and reverse mode with respect to
K, u0, mu and e.

Everything inside is nondimensional: K / trace(K), u / |u0|, impulses / (|u0| / trace(K)).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._common.checks import Flag, as_float, combine, flag_if, is_concrete
from .._common.compile import jit
from .._common.report import plain, summary_text
from .routh import FRICTION, RESTITUTION, _safe_div, _safe_sqrt

LAWS_3D = ("poisson", "stronge")

_SLIP_STOP = 1e-13  # the slip stop: |u_t| below this times |u0| (float64; float32 uses 1e-6)
_TAU_END = 1e12  # the sliding clock's bound: a segment ends at an event or at `_MAX_STEPS` first
_MAX_STEPS = 4096
_SOLVER = "Dopri8"  # a diffrax solver's name: diffrax is imported where a solve is traced, not on import
_TOL = 1e-12  # the solves' relative and absolute tolerances (float64; float32 uses 1e-6)


class Impact3D(eqx.Module):
    """Outcome of one 3D single-vertex impact (`impulse_3d`), in the contact frame (t1, t2, n).

    - `P`: final impulse (P_t1, P_t2, P_n), N s.
    - `velocity`: contact velocity (u_t1, u_t2, u_n) after the impact, m/s.
    - `Pn_compression`: normal impulse at maximum compression (u_n = 0), N s.
    - `Pn_stick`: normal impulse where slip stops (inf when it never does before the end); from there the contact
      sticks or slides along the invariant direction.
    - `energy_change`: change of kinetic energy, P . (u0 + u) / 2 = u0 . P + P . K P / 2, J (<= 0).
    - `sticks`: whether the contact ends stuck (slip stopped and friction holds it).
    - `steps`: accepted solver steps of the sliding phase (0 when slip stops at once).
    - `flags`: `Flag` mask: SEPARATING_CONTACT (u0_n >= 0: then P = 0), SOLVER_FAILED, NONFINITE_RESULT and the
      inputs' range flags (these with NaN numbers).
    """

    P: Float[Array, "3"]
    velocity: Float[Array, "3"]
    Pn_compression: Float[Array, ""]
    Pn_stick: Float[Array, ""]
    energy_change: Float[Array, ""]
    sticks: Bool[Array, ""]
    steps: Int[Array, ""]
    flags: Int[Array, ""]

    def summary(self) -> dict:
        """The impact's numbers, units in the keys (JSON-ready; `repr` prints them)."""
        if jnp.ndim(self.energy_change):
            raise ValueError("Impact3D.summary() needs one impact (index a batched one first)")
        return plain({
            "impulse_Ns": self.P,
            "normal_impulse_at_max_compression_Ns": self.Pn_compression,
            "normal_impulse_at_slip_stop_Ns": self.Pn_stick,
            "contact_at_end": ("no impact" if int(self.flags) & Flag.SEPARATING_CONTACT
                               else "stuck" if bool(self.sticks) else "sliding"),
            "contact_velocity_after_m_per_s": self.velocity,
            "energy_change_J": self.energy_change,
            "solver_steps": self.steps,
            "flags": Flag.describe(self.flags),
        })

    def __repr__(self) -> str:
        try:
            return summary_text(self.summary(), "Impact3D")
        except (ValueError, TypeError, jax.errors.ConcretizationTypeError):
            return eqx.tree_pformat(self)


# ---------------------------------------------------------------------------------------------------------------
# The nondimensional contact and its sliding flow.


class _Contact(eqx.Module):
    A: Array  # K_tt / trace K
    b: Array  # K_tn / trace K
    Knn: Array
    u0n: Array  # u0_n / |u0|
    mu: Array
    log_stop: Array  # log of the slip-stop threshold

    def u_n(self, p, Pt):
        return self.u0n + self.b @ Pt + self.Knn * p

    def slip(self, y):
        """The unit slip direction s (from the state's first two entries), du_t/dp = f(s) = b - mu A s, the
        turning rate g = s x f and the growth rate h = s . f of log |u_t|, both per unit tau."""
        s = y[0:2] / jnp.sqrt(y[0:2] @ y[0:2])
        f = self.b - self.mu * (self.A @ s)
        return s, f, s[0] * f[1] - s[1] * f[0], s @ f

    def field(self, tau, y, args):
        """d/dtau of (s1, s2, rho, p, P_t1, P_t2, W), dp/dtau = |u_t| = e^rho. The direction is a unit vector, not
        an angle, so that a planar slip (s2 = 0, K decoupled from t2) stays planar to the last bit."""
        s, f, _, h = self.slip(y)
        r = jnp.exp(y[2])
        u_n = self.u_n(y[3], y[4:6])
        return jnp.concatenate([f - h * s, h[None], r[None], -self.mu * s * r, (u_n * r)[None]])


class _Walk(eqx.Module):
    """Where the sliding walk stands: the physical state z = (p, P_t1, P_t2, W, u_t1, u_t2) (nondimensional; W the
    normal work from the start, and from compression on once compressed, when the compression work is W_c) and what
    has happened."""

    z: Array
    compressed: Array
    p_c: Array
    W_c: Array
    stopped: Array  # slip stopped at z (then z stays there)
    aligned: Array  # slip runs along the invariant direction from z on (then z stays there)
    done: Array  # the law's end reached at z
    failed: Array
    steps: Array


def _to_state(z, log_stop):
    """(s1, s2, rho, p, P_t, W) from z, finite also where u_t = 0 (an idle segment's input)."""
    ut = z[4:6]
    r2 = ut @ ut
    moving = r2 > 0
    ut_safe = jnp.where(moving, ut, jnp.array([1.0, 0.0], dtype=z.dtype))
    rho = jnp.where(moving, 0.5 * jnp.log(jnp.where(moving, r2, 1.0)), log_stop)
    return jnp.concatenate([ut_safe / jnp.sqrt(ut_safe @ ut_safe), rho[None], z[0:4]])


def _step_along(c: _Contact, y, dp):
    """z after moving dp along the sliding path from the state y with the direction held (exact in P and W on a
    straight piece, first order in u_t: the moves here are root finder residuals or the last stretch to a stop)."""
    s, f, _, _ = c.slip(y)
    r = jnp.exp(y[2])
    p, Pt, W = y[3], y[4:6], y[6]
    u_n = c.u_n(p, Pt)
    dun = c.Knn - c.mu * (c.b @ s)
    return jnp.concatenate([(p + dp)[None], Pt - c.mu * s * dp, (W + u_n * dp + 0.5 * dun * dp**2)[None],
                            r * s + f * dp])


class _Target(eqx.Module):
    """What a segment slides to: before compression u_n = 0; after it Poisson's p = (1 + e) p_c or Stronge's
    restitution work W = -e^2 W_c (W counts from compression on then), the last as sqrt(W) = sqrt(W_T), a simple
    root also where e is small (W grows as (p - p_c)^2 from compression on)."""

    a_un: Array  # weights of the three kinds, one of them 1
    a_p: Array
    a_W: Array
    p_T: Array
    W_T: Array

    def value(self, c: _Contact, y):
        """Below 0 before the target, 0 on it."""
        root = _safe_sqrt(y[6]) - _safe_sqrt(self.W_T)
        return self.a_un * c.u_n(y[3], y[4:6]) + self.a_p * (y[3] - self.p_T) + self.a_W * root

    def rate(self, c: _Contact, y):
        """d value / dp while sliding."""
        s, _, _, _ = c.slip(y)
        u_n = c.u_n(y[3], y[4:6])
        d_root = _safe_div(u_n, 2.0 * _safe_sqrt(y[6]), y[6] > 0)
        return self.a_un * (c.Knn - c.mu * (c.b @ s)) + self.a_p + self.a_W * d_root

    def clear_of(self, c: _Contact, y, tail):
        """Whether the target is surely not reached within `tail` of p along the current direction."""
        s, _, _, _ = c.slip(y)
        u_n = c.u_n(y[3], y[4:6])
        dun = jnp.abs(c.Knn - c.mu * (c.b @ s))
        W_far = y[6] + jnp.abs(u_n) * tail + 0.5 * dun * tail**2
        linear = self.a_un * (u_n + dun * tail) + self.a_p * (y[3] + tail - self.p_T)
        margin = 1e-9  # nondimensional: a target that near the tail's end is left to the solve's events
        return jnp.where(self.a_W > 0, W_far < self.W_T - margin, linear < -margin)


def _settled(c: _Contact, y, target: _Target):
    """Whether the rest of the way to the slip stop is a straight line to within 1e-13 (relative): slip shrinks
    (h < 0) and the direction has (nearly) reached its ray. Near a ray s_r with g(s_r) = 0 the direction is off by
    delta ~ |g / g'| (g' = dg/dphi = -h - mu s_perp . A s_perp); the tail, of length r / |h|, then bends by
    delta, or, where the ray repels (g' > 0, growth alpha = g' / |h| per e-fold of r), leaves it where r has
    fallen by delta^(1 / alpha). The error of the straight tail is r delta^q (1 + mu + |h'/h|) / |h| with
    q = min(1, 1 / alpha) where it repels, else 1. Also: the law's target must not be reached on the tail (the
    solve goes on to it instead)."""
    tiny = jnp.finfo(y.dtype).tiny
    s, f, g, h = c.slip(y)
    s_perp = jnp.stack([-s[1], s[0]])
    As_perp = c.A @ s_perp
    dg = -h - c.mu * (s_perp @ As_perp)
    dh = g - c.mu * (s @ As_perp)
    shrinks = h < 0
    h_ = jnp.where(shrinks, -h, 1.0)
    delta = jnp.abs(g) / jnp.maximum(jnp.abs(dg), tiny)
    q = jnp.where(dg > 0, jnp.minimum(1.0, h_ / jnp.maximum(dg, tiny)), 1.0)
    log_err = y[2] + q * jnp.log(delta + tiny) + jnp.log((1.0 + c.mu + jnp.abs(dh) / h_) / h_)
    tail = jnp.exp(y[2]) / h_
    return shrinks & (log_err <= c.log_stop) & target.clear_of(c, y, tail)


def _aligned(c: _Contact, y, can_stick):
    """Whether slip, growing, has turned onto the invariant direction s* to within 1e-13 (relative), so that the
    rest of the way is the straight line along s*: s* is the one ray with g = 0 and h > 0 (friction cannot hold
    the contact), and it attracts (g' = -h - mu s_perp . A s_perp < 0). Off it by delta ~ |g / g'|, the
    direction closes in as exp(g' tau) while p runs at r exp(h tau), so taking the line from here misses the path
    by about mu r delta / (|g'| - h) in P_t, and as much again through u_n in P_n. (Without this a slip that grows
    slowly along s* is stiff: the direction relaxes |g'| / h times faster than the slip grows.)"""
    tiny = jnp.finfo(y.dtype).tiny
    s, f, g, h = c.slip(y)
    s_perp = jnp.stack([-s[1], s[0]])
    dg = -h - c.mu * (s_perp @ (c.A @ s_perp))
    closing = jnp.maximum(-dg - h, tiny)
    delta = jnp.abs(g) / jnp.maximum(-dg, tiny)
    log_err = y[2] + jnp.log(delta + tiny) + jnp.log(2.0 * (1.0 + c.mu) * (1.0 + jnp.linalg.norm(c.b) / c.Knn)
                                                    / closing)
    return ~can_stick & (h > 0) & (dg < 0) & (log_err <= c.log_stop)


def _pack(c: _Contact):
    """The contact's numbers as one vector (9,): A (row-major), b, K_nn, u0_n, mu."""
    return jnp.concatenate([c.A.reshape(4), c.b, jnp.stack([c.Knn, c.u0n, c.mu])])


def _unpack(theta, log_stop) -> _Contact:
    return _Contact(A=theta[0:4].reshape(2, 2), b=theta[4:6], Knn=theta[6], u0n=theta[7], mu=theta[8],
                    log_stop=log_stop)


def _advance(solver, term, Y, dtau, substeps: int = 2):
    """Y moved by dtau along the flow, by steps of the solver's own method (|dtau| is within the solver's last
    accepted step, so each of these has its accuracy)."""
    h = dtau / substeps
    for i in range(substeps):
        state = solver.init(term, i * h, (i + 1) * h, Y, None)
        Y = solver.step(term, i * h, (i + 1) * h, Y, None, state, made_jump=False)[0]
    return Y


def _solve(theta, y0, log_stop, target: _Target, can_stick, idle, tol, sensitivities: bool):
    """The sliding solve from y0 to the first event, each event at the end of the step where it holds; a reached
    target is then located within that last step (Newton's method safeguarded by bisection, each try integrated
    afresh by the solver's method from a known end of the step). With `sensitivities` it also carries S = d y / d (y0, theta)
    (7 x 16) by the variational equations dS/dtau = J_y S + [0 | J_theta]. Returns y (at the located target, else
    at the end), S (or None), the event mask (reached, stopped, settled, aligned) and the accepted steps. No derivative
    passes through diffrax here (`_walk` supplies them), so its loops are plain `lax` ones."""
    import diffrax

    c = _unpack(theta, log_stop)

    def field(tau, Y, args):
        y = Y[0]
        dy = c.field(tau, y, None)
        if not sensitivities:
            return (dy,)
        J_y, J_theta = jax.jacfwd(lambda y, th: _unpack(th, log_stop).field(tau, y, None), argnums=(0, 1))(y, theta)
        dS = J_y @ Y[1] + jnp.concatenate([jnp.zeros((7, 7), y.dtype), J_theta], axis=1)
        return dy, dS

    def reach(t, Y, args, **kwargs):
        return target.value(c, Y[0]) > 0

    def stop(t, Y, args, **kwargs):
        return Y[0][2] <= c.log_stop

    def settled(t, Y, args, **kwargs):
        return _settled(c, Y[0], target)

    def aligned(t, Y, args, **kwargs):
        return _aligned(c, Y[0], can_stick)

    def skip(t, Y, args, **kwargs):
        return idle

    solver = getattr(diffrax, _SOLVER)(scan_kind="lax")
    Y0 = (y0, jnp.eye(7, 16, dtype=y0.dtype)) if sensitivities else (y0,)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), solver, 0.0, _TAU_END, None, Y0,
        stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol),
        event=diffrax.Event((reach, stop, settled, aligned, skip)), max_steps=_MAX_STEPS, saveat=diffrax.SaveAt(t1=True),
        adjoint=diffrax.ForwardMode(), throw=False,
    )
    reached, stopped, settles, aligns, _ = sol.event_mask
    Y_end = jax.tree_util.tree_map(lambda x: x[-1], sol.ys)

    # Newton's method safeguarded by bisection, integrating from the nearer known end of the last step: its end, or
    # the segment's start when it is the first step (where the work W, counted from compression, is tiny and
    # must keep its relative accuracy for Stronge's end at small e). Only evaluations near the root, inside the
    # last step, need to be accurate, and are.
    plain = diffrax.ODETerm(lambda tau, Y, args: (c.field(tau, Y[0], None),))
    first = sol.stats["num_accepted_steps"] == 1
    tau_end = sol.ts[-1]
    base = jax.tree_util.tree_map(lambda a, b: jnp.where(first, a, b), Y0, Y_end)

    def newton(_, state):
        dtau, lo, hi = state
        (y,) = _advance(solver, plain, (base[0],), dtau)
        value = target.value(c, y)
        rate = jnp.exp(y[2]) * target.rate(c, y)
        lo, hi = jnp.where(value > 0, lo, dtau), jnp.where(value > 0, dtau, hi)
        step = dtau - _safe_div(value, rate, rate > 0)
        inside = (rate > 0) & (step > lo) & (step < hi)
        return jnp.where(inside, step, 0.5 * (lo + hi)), lo, hi

    zero = jnp.zeros((), y0.dtype)
    lo, hi = jnp.where(first, zero, -tau_end), jnp.where(first, tau_end, zero)
    dtau, _, _ = jax.lax.fori_loop(0, 40, newton, (zero, lo, hi))
    dtau = jnp.where(reached, dtau, 0.0)
    Y_out = _advance(solver, diffrax.ODETerm(field), jax.tree_util.tree_map(
        lambda a, b: jnp.where(reached, a, b), base, Y_end), dtau)
    masks = jnp.stack([reached, stopped, settles, aligns]).astype(y0.dtype)
    S = Y_out[1] if sensitivities else None
    return Y_out[0], S, masks, sol.stats["num_accepted_steps"].astype(y0.dtype)


def _target(walk: _Walk, p_c, W_c, e, stronge) -> _Target:
    """Before compression: u_n = 0. After it: Poisson's p = (1 + e) p_c, Stronge's restitution work -e^2 W_c."""
    one, nil = jnp.ones_like(p_c), jnp.zeros_like(p_c)
    law_p = jnp.where(stronge, nil, one)
    after = walk.compressed
    return _Target(a_un=jnp.where(after, nil, one), a_p=jnp.where(after, law_p, nil),
                   a_W=jnp.where(after, one - law_p, nil), p_T=(1.0 + e) * p_c, W_T=-(e**2) * W_c)


def _segment(theta, e, stronge, log_stop, walk: _Walk, tol: float, sensitivities: bool):
    """Slide from `walk` until the target is reached, slip stops or it runs along the invariant direction; an idle
    walk (stopped, aligned, done or failed) passes through. Returns the next walk and, with `sensitivities`, the
    derivative of its numbers v = (z, p_c, W_c) with respect to (theta, e, v) as three matrices."""
    c = _unpack(theta, log_stop)
    target = _target(walk, walk.p_c, walk.W_c, e, stronge)
    busy = ~(walk.stopped | walk.aligned | walk.done | walk.failed)
    hold = _solve2(c.A, c.b)
    can_stick = hold @ hold <= c.mu**2
    y0 = _to_state(walk.z, log_stop)
    # What holds at the start is decided here, not by the solve's first look at its events: slip already below the
    # stop threshold (at the start, or left so by the compression event), the target already reached (e = 0), the
    # rest of the way to the stop already straight (a planar slip that slows) or slip already on the ray s*.
    at_rest = busy & (y0[2] <= log_stop)
    at_target = busy & ~at_rest & (target.value(c, y0) >= 0)
    straight = busy & ~at_rest & ~at_target & _settled(c, y0, target)
    on_ray = busy & ~at_rest & ~at_target & ~straight & _aligned(c, y0, can_stick)
    idle = ~busy | at_rest | at_target | straight | on_ray
    # A reached target comes back located; a stop needs no location (the tail to it is extrapolated).
    y, S, masks, steps = _solve(theta, y0, log_stop, target, can_stick, idle, tol, sensitivities)
    reached = (masks[0] > 0) & ~idle | at_target
    stopped = (masks[1] > 0) | (masks[2] > 0)
    stopped = stopped & ~idle | straight
    aligned = (masks[3] > 0) & ~idle | on_ray
    failed = ~idle & ~reached & ~stopped & ~aligned
    first = reached & ~walk.compressed

    def onward(y, v, theta, e):
        """The walk's next numbers (z, p_c, W_c) from the solve's end state y: onto the event surface by one
        first-order step for the located target's residual (which gives the derivative its implicit-function
        form), or the straight tail to the stop, or the start of the line along s*."""
        c = _unpack(theta, log_stop)
        z_old, p_c, W_c = v[:6], v[6], v[7]
        target = _target(walk, p_c, W_c, e, stronge)
        rate = target.rate(c, y)
        z_reach = _step_along(c, y, -_safe_div(target.value(c, y), rate, rate > 0))
        _, _, _, h = c.slip(y)
        z_stop = _step_along(c, y, _safe_div(jnp.exp(y[2]), -h, h < 0)).at[4:6].set(0.0)
        z_ray = _step_along(c, y, 0.0)
        z = jnp.where(reached, z_reach, jnp.where(stopped, z_stop, jnp.where(aligned, z_ray, z_old)))
        z = jnp.where(at_rest, z_old.at[4:6].set(0.0), z)
        # The work counts from compression on.
        return jnp.concatenate([jnp.where(first, z.at[3].set(0.0), z), jnp.where(first, z[0], p_c)[None],
                                jnp.where(first, z[3], W_c)[None]])

    v = jnp.concatenate([walk.z, jnp.stack([walk.p_c, walk.W_c])])
    v_next = onward(y, v, theta, e)
    nxt = _Walk(z=v_next[:6], compressed=walk.compressed | first, p_c=v_next[6], W_c=v_next[7],
                stopped=walk.stopped | stopped | at_rest, aligned=walk.aligned | aligned,
                done=walk.done | (reached & walk.compressed), failed=walk.failed | failed,
                steps=walk.steps + steps.astype(jnp.int32))
    if not sensitivities:
        return nxt, None
    # d v_next = G_y dy + G_v dv + G_theta dtheta + G_e de, with dy = S_y0 (d y0 / d z) dz + S_theta dtheta.
    G_y, G_v, G_theta, G_e = jax.jacfwd(onward, argnums=(0, 1, 2, 3))(y, v, theta, e)
    dy_dv = S[:, :7] @ jax.jacfwd(_to_state)(v[:6], log_stop) @ jnp.eye(6, 8, dtype=v.dtype)
    return nxt, (G_y @ S[:, 7:] + G_theta, G_e, G_y @ dy_dv + G_v)


def _start(z0, dtype) -> _Walk:
    zero, no = jnp.zeros((), dtype), jnp.array(False)
    return _Walk(z=z0, compressed=no, p_c=zero, W_c=zero, stopped=no, aligned=no, done=no, failed=no,
                 steps=jnp.zeros((), jnp.int32))


def _numbers(walk: _Walk):
    """The walk's numbers v = (z, p_c, W_c) and its status (compressed, stopped, aligned, done, failed, steps) as
    floats (the custom derivative's outputs)."""
    v = jnp.concatenate([walk.z, jnp.stack([walk.p_c, walk.W_c])])
    status = jnp.stack([walk.compressed, walk.stopped, walk.aligned, walk.done, walk.failed]).astype(v.dtype)
    return v, jnp.concatenate([status, walk.steps.astype(v.dtype)[None]])


@functools.partial(jax.custom_jvp, nondiff_argnums=(4,))
def _walk(theta, e, stronge, z0, tol: float):
    """The sliding walk from z0 = (0, 0, 0, 0, u0_t / |u0|): at most two segments (to compression or a stop; then
    to the law's end or a stop), one compiled solve in a `fori_loop`. Returns its numbers and status (`_numbers`).
    Differentiated as a whole (forward sensitivities of each solve at its final tau, chained through the event
    projections by `_segment`): no derivative passes through diffrax's loops, and the derivative is a linear map on
    the tangents, which reverse mode transposes."""
    log_stop = _log_stop(z0.dtype)
    walk = jax.lax.fori_loop(0, 2, lambda _, w: _segment(theta, e, stronge, log_stop, w, tol, False)[0],
                             _start(z0, z0.dtype))
    return _numbers(walk)


@_walk.defjvp
def _walk_jvp(tol, primals, tangents):
    theta, e, stronge, z0 = primals
    d_theta, d_e, _, d_z0 = tangents
    log_stop = _log_stop(z0.dtype)

    def step(_, carry):
        walk, J_theta, J_e, J_v = carry  # d v / d theta (8 x 9), d v / d e (8,), d v / d v0 (8 x 8)
        walk, (G_theta, G_e, G_v) = _segment(theta, e, stronge, log_stop, walk, tol, True)
        return walk, G_v @ J_theta + G_theta, G_v @ J_e + G_e, G_v @ J_v

    eye = jnp.eye(8, dtype=z0.dtype)
    walk, J_theta, J_e, J_v = jax.lax.fori_loop(
        0, 2, step, (_start(z0, z0.dtype), jnp.zeros((8, 9), z0.dtype), jnp.zeros(8, z0.dtype), eye))
    v, status = _numbers(walk)
    dv = J_theta @ d_theta + J_e * d_e + J_v[:, :6] @ d_z0
    return (v, status), (dv, jnp.zeros_like(status))


def _log_stop(dtype):
    return jnp.log(jnp.asarray(_SLIP_STOP if dtype == jnp.float64 else 1e-6, dtype))


# ---------------------------------------------------------------------------------------------------------------
# After the stop: stick or the invariant direction.


def _solve2(M, v):
    """M^-1 v for a 2 x 2 `M` by Cramer's rule: under `vmap` a LAPACK solve per drop cost 20x the arithmetic."""
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return jnp.stack([M[1, 1] * v[0] - M[0, 1] * v[1], M[0, 0] * v[1] - M[1, 0] * v[0]]) / det


_INVARIANT_STEPS = 8
"""Safeguarded Newton steps on 1/|s(lam)| for `_invariant_direction`: enough for round-off from lam = 0 on
condition numbers of A to 1e8 (`tests/test_impulse3d.py` checks the root)."""


def _invariant_direction(A, b, mu):
    """The unit s* with (mu A + lam I) s* = b and lam > 0 (unique; the caller makes sure |A^-1 b| > mu).

    Newton's method on phi(lam) = 1 / |s(lam)| - 1 with s(lam) = (mu A + lam I)^-1 b (Moré and Sorensen's secular
    equation: phi is nearly linear, so Newton converges in a few steps), kept inside a bracket [lo, hi] that
    bisects where a step leaves it."""
    eye = jnp.eye(2, dtype=A.dtype)

    def phi(A, b, mu, lam):
        x = _solve2(mu * A + lam * eye, b)
        n2 = x @ x
        # d|x|/dlam = -x . (M^-1 x) / |x|, so dphi/dlam = x . (M^-1 x) / |x|^3.
        return jax.lax.rsqrt(n2) - 1.0, (x @ _solve2(mu * A + lam * eye, x)) * n2**-1.5

    A_, b_, mu_ = jax.lax.stop_gradient((A, b, mu))

    def step(_, state):
        lam, lo, hi = state
        f, df = phi(A_, b_, mu_, lam)
        below = ~(f >= 0)  # NaN too: mu A is singular at lam = 0 when mu = 0, and the root is above 0
        lo, hi = jnp.where(below, lam, lo), jnp.where(below, hi, lam)
        newton = lam - f / df
        inside = (newton > lo) & (newton < hi)
        return jnp.where(inside, newton, 0.5 * (lo + hi)), lo, hi

    # phi(0) < 0 (|A^-1 b| > mu) and phi(|b|) >= 0 (|s(|b|)| <= 1 as mu A is positive definite): a bracket.
    start = jnp.zeros_like(mu_)
    lam, _, _ = jax.lax.fori_loop(0, _INVARIANT_STEPS, step, (start, start, jnp.linalg.norm(b_) + start))
    # One Newton step with the gradient: the implicit derivative -dphi/dtheta / phi'(lam) at the root.
    f, df = phi(A, b, mu, lam)
    lam = lam - f / df
    s = _solve2(mu * A + lam * eye, b)
    return s / jnp.linalg.norm(s), lam


def _after_stop(c: _Contact, e, stronge, walk: _Walk):
    """The final normal impulse p_f, tangential impulse and compression (p_c) once the walk has stopped or aligned,
    along the straight piece that follows: sticking (|A^-1 b| <= mu) or sliding along the invariant direction."""
    hold = _solve2(c.A, c.b)  # A^-1 b
    sticks = hold @ hold <= c.mu**2
    safe = (jnp.eye(2, dtype=c.A.dtype), jnp.array([1.0, 0.0], dtype=c.A.dtype), jnp.zeros_like(c.mu))
    A, b, mu = (jnp.where(sticks, s, v) for s, v in zip(safe, (c.A, c.b, c.mu)))
    s_star, _ = _invariant_direction(A, b, mu)
    dPt = jnp.where(sticks & ~walk.aligned, -hold, -c.mu * s_star)
    dun = c.Knn + c.b @ dPt  # > 0 on both
    p_s, Pt_s, W_s = walk.z[0], walk.z[1:3], walk.z[3]
    un_s = c.u_n(p_s, Pt_s)
    # Compression on the straight piece when it had not ended before the stop.
    dc = _safe_div(-un_s, dun, dun > 0)
    p_c = jnp.where(walk.compressed, walk.p_c, p_s + dc)
    W_c = jnp.where(walk.compressed, walk.W_c, W_s + un_s * dc + 0.5 * dun * dc**2)
    # The law's end from the later of the stop and the compression (the work counts from compression on: the
    # restitution work there is W_s if the stop came after compression, else 0).
    p0 = jnp.where(walk.compressed, p_s, p_c)
    un0 = jnp.where(walk.compressed, un_s, 0.0)
    dW = jnp.maximum(-(e**2) * W_c - jnp.where(walk.compressed, W_s, 0.0), 0.0)
    root = un0 + _safe_sqrt(un0**2 + 2.0 * dun * dW)
    p_stronge = p0 + _safe_div(2.0 * dW, root, root > 0)
    p_f = jnp.where(stronge, p_stronge, (1.0 + e) * p_c)
    return p_f, Pt_s + dPt * (p_f - p_s), p_c, sticks


# ---------------------------------------------------------------------------------------------------------------
# The public function.


def _positive_definite(K):
    """Finite, symmetric to round-off and positive definite (leading minors of the symmetric part; traceable)."""
    xp = np if isinstance(K, np.ndarray) else jnp
    scale = xp.max(xp.abs(K))
    symmetric = xp.all(xp.abs(K - K.T) <= 1e-12 * scale)
    S = 0.5 * (K + K.T)
    m2 = S[0, 0] * S[1, 1] - S[0, 1] ** 2
    m3 = (S[0, 0] * (S[1, 1] * S[2, 2] - S[1, 2] ** 2) - S[0, 1] * (S[0, 1] * S[2, 2] - S[1, 2] * S[0, 2])
          + S[0, 2] * (S[0, 1] * S[1, 2] - S[1, 1] * S[0, 2]))
    return xp.all(xp.isfinite(K)) & symmetric & (S[0, 0] > 0) & (m2 > 0) & (m3 > 0)


def _check_eagerly(K, u0, mu, e):
    if K.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3) (the contact's inverse inertia in the frame (t1, t2, n)); got "
                         f"shape {K.shape}")
    if u0.shape != (3,):
        raise ValueError(f"u0 must have shape (3,) (the contact velocity (u_t1, u_t2, u_n), m/s); got shape "
                         f"{u0.shape}")
    FRICTION.require(mu, "friction")
    RESTITUTION.require(e, "restitution")
    if not np.all(np.isfinite(np.asarray(u0))):
        raise ValueError(f"u0 = {np.asarray(u0).tolist()}: the contact velocity (u_t1, u_t2, u_n) must be finite, "
                         "m/s")
    with np.errstate(invalid="ignore", over="ignore"):
        positive_definite = bool(_positive_definite(np.asarray(K, dtype=float)))
    if not positive_definite:
        raise ValueError(f"K = {np.asarray(K).tolist()}: the contact's inverse inertia must be a finite, symmetric, "
                         "positive definite 3 x 3 matrix in the frame (t1, t2, n), 1/kg")


def impulse_3d(K: Float[Array, "3 3"], u0: Float[Array, "3"], friction, restitution, law: str = "poisson", *,
               from_rest: bool = False) -> Impact3D:
    """Impulse of a frictional impact at one vertex in 3D (Darboux-Keller; the method is in this module's
    docstring).

    **Arguments:**
    - `K`: inverse inertia at the contact in the frame (t1, t2, n), 3 x 3 symmetric positive definite, 1/kg
      (K = (1/m) 1 + [r]x^T I^-1 [r]x for a rigid body with r from G to the contact).
    - `u0`: contact velocity (u_t1, u_t2, u_n) before impact, m/s; u_n < 0 approaches the ground.
    - `friction`: Coulomb coefficient mu >= 0. `restitution`: e in [0, 1].
    - `law`: `"poisson"` (default; the normal impulse ends at (1 + e) p_c, p_c where u_n = 0) or `"stronge"`
      (restitution work = -e^2 times the compression work; the work of the normal force is the integral of u_n dp).
    - `from_rest` (static): the contact has no slip at first (u0_t1 = u0_t2 = 0, a drop from rest): the law is then
      one straight piece (stick, or slide along the invariant direction) in closed form, with no solve. A contact
      that does slip gets NaN and `Flag.SOLVER_FAILED`.

    **Returns:** an `Impact3D`. With u0_n >= 0 the contact separates: P = 0 and `Flag.SEPARATING_CONTACT` is set.
    With K decoupled from t2 and u0_t2 = 0 the result is `routh_impulse`'s with B = the (t1, n) block of K.
    Traceable: under `jit`, `vmap` and `grad` bad inputs come back as `flags` (and NaN numbers).
    """
    if law not in LAWS_3D:
        raise ValueError(f"law = {law!r}; valid laws: {', '.join(LAWS_3D)}")
    K = as_float(K, "K", "a symmetric positive definite 3 x 3 matrix, 1/kg")
    u0 = as_float(u0, "u0", "(u_t1, u_t2, u_n), finite, m/s")
    mu = as_float(friction, "friction", FRICTION)
    e = as_float(restitution, "restitution", RESTITUTION)
    for name, value in (("friction", mu), ("restitution", e)):
        if value.shape != ():
            raise ValueError(f"{name} must be one number (shape ()); got shape {value.shape}; for many contacts, "
                             "jax.vmap impulse_3d")
    if is_concrete(K, u0, mu, e):
        _check_eagerly(K, u0, mu, e)
    elif K.shape != (3, 3) or u0.shape != (3,):
        raise ValueError(f"K must have shape (3, 3) and u0 shape (3,); got {K.shape} and {u0.shape} (for many "
                         "contacts, jax.vmap impulse_3d)")
    return _impulse_3d(K, u0, mu, e, jnp.asarray(law == "stronge"), from_rest=bool(from_rest))


@functools.partial(jit, static_argnames=("from_rest",))  # one compiled program for both laws
def _impulse_3d(K, u0, mu, e, stronge, from_rest: bool = False) -> Impact3D:
    """`impulse_3d` on arrays. `from_rest` (static): the caller knows u0_t = 0, so slip is stopped from the start
    and the law is the straight piece alone (`_after_stop`; no solve); a contact that slips gets NaN and
    `Flag.SOLVER_FAILED`."""
    dtype = K.dtype
    tol = _TOL if dtype == jnp.float64 else 1e-6
    separating = u0[2] >= 0
    valid = (_positive_definite(K) & jnp.all(jnp.isfinite(u0)) & FRICTION.contains(mu) & RESTITUTION.contains(e))
    use = valid & ~separating
    # Invalid or separating contacts are computed on a harmless stand-in and their results replaced.
    K_ = jnp.where(use, 0.5 * (K + K.T), jnp.eye(3, dtype=dtype))
    u0_ = jnp.where(use, u0, jnp.array([0.0, 0.0, -1.0], dtype=dtype))
    mu_ = jnp.where(use, mu, 0.0)
    e_ = jnp.where(use, e, 0.0)
    k = jnp.trace(K_)
    V = jnp.linalg.norm(u0_)
    Kh, uh = K_ / k, u0_ / V
    c = _Contact(A=Kh[:2, :2], b=Kh[:2, 2], Knn=Kh[2, 2], u0n=uh[2], mu=mu_, log_stop=_log_stop(dtype))
    # Slip below the stop threshold from the start stops at p = 0 (the first segment sees to it).
    z0 = jnp.concatenate([jnp.zeros(4, dtype), uh[:2]])
    if from_rest:
        walk = eqx.tree_at(lambda w: (w.stopped, w.failed), _start(z0, dtype),
                           (jnp.array(True), jnp.any(u0_[:2] != 0)))
    else:
        v, status = _walk(_pack(c), e_, stronge, z0, tol)
        flag = status[:5] > 0
        walk = _Walk(z=v[:6], compressed=flag[0], p_c=v[6], W_c=v[7], stopped=flag[1], aligned=flag[2],
                     done=flag[3], failed=flag[4], steps=status[5].astype(jnp.int32))
    p_lin, Pt_lin, p_c_lin, holds = _after_stop(c, e_, stronge, walk)
    straight = walk.stopped | walk.aligned
    p_f = jnp.where(straight, p_lin, walk.z[0])
    Pt_f = jnp.where(straight, Pt_lin, walk.z[1:3])
    p_c = jnp.where(straight, p_c_lin, walk.p_c)

    scale = V / k
    P = jnp.concatenate([Pt_f, p_f[None]]) * scale
    P = jnp.where(use & ~walk.failed, P, jnp.where(valid & separating, 0.0, jnp.nan))
    Pn_c = jnp.where(use, p_c * scale, jnp.where(valid, 0.0, jnp.nan))
    Pn_stick = jnp.where(use & walk.stopped, walk.z[0] * scale, jnp.inf)
    velocity = u0 + K @ P
    energy_change = u0 @ P + 0.5 * P @ K @ P
    finite = jnp.all(jnp.isfinite(P)) & jnp.isfinite(energy_change)
    flags = combine(
        flag_if(separating, Flag.SEPARATING_CONTACT),
        flag_if(use & walk.failed, Flag.SOLVER_FAILED),
        flag_if(use & ~walk.failed & ~finite, Flag.NONFINITE_RESULT),
        flag_if(~RESTITUTION.contains(e), Flag.RESTITUTION_RANGE),
        flag_if(~FRICTION.contains(mu), Flag.FRICTION_NEGATIVE),
        flag_if(~jnp.all(jnp.isfinite(u0)), Flag.NONFINITE_INPUT),
        flag_if(~_positive_definite(K), Flag.CONTACT_MATRIX),
    )
    return Impact3D(P=P, velocity=velocity, Pn_compression=Pn_c, Pn_stick=Pn_stick, energy_change=energy_change,
                    sticks=use & walk.stopped & holds, steps=walk.steps, flags=flags)
