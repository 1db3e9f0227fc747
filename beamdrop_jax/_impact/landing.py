"""Compliant landing of the planar housing: every corner that reaches the ground carries a hysteretic spring and
regularised Coulomb friction, and the housing's rigid motion is integrated through the whole landing, all
contacts at once (DESIGN.md section 7). Where one corner strikes alone it reproduces the rigid law's impulse as the
contact duration goes to 0; where corners strike together (near-flat landings) it gives the one answer that the
contact's duration selects, and its limit as the angle goes to 0 is the flat landing.

**State.** The centre of mass G = (x, y) and its velocity, the orientation theta (body axes e1 = (cos, sin),
e2 = (-sin, cos)) and the spin w; per corner its penetration d, the largest penetration d_max of its current
contact, and the impulse (Pt, Pn) it has received. The integration starts at the first touch: the lowest corner at
y = 0 with the pre-impact velocity (x = 0 there). Gravity g (default `GRAVITY` = 9.80665 m/s^2) acts throughout.

**Normal force.** Corner i at c_i = G + R(theta) q_i (q_i = (+-W/2, +-H/2)) has height y_i and penetration
d = -y_i. Its normal force is a hysteretic linear spring, continuous in time (no force jump at first touch):
- loading (d = d_max growing): N = k d;
- unloading, and reloading below d_max: N = k d_max (d - d_p) / (d_max - d_p) = (k / e^2)(d - d_p) with
  d_p = d_max (1 - e^2), so the unloading stiffness is k / e^2 and the returned energy is e^2 of the stored one;
- N = 0 below d_p. All three: N = max(0, k (d - (1 / e^2 - 1) max(d_max - d, 0))).
Per corner k = m_eff w1^2 with w1 = pi (1 + e) / (2 tau), tau = `contact.duration`, e = `contact.restitution`,
and m_eff = 1 / B2 the corner's effective mass in the normal direction, B2 = 1/m + x^2 / I_G with
r = G - c_i = (x, y) **at the first-touch configuration**: a constant per corner for the whole landing (the body
turns by O(w tau) during a contact, so this is exact to first order in tau). A single frictionless corner strike,
the turn neglected, is then a quarter sine at w1 and one at w2 = w1 / e: it lasts exactly tau (e = 1: the half-sine
of duration tau), leaves the rebound velocity e v0 and the impulse (1 + e) m_eff v0 (with gravity too, the normal
rebound when the force ends is e v0 exactly: the spring returns e^2 of the work stored, gravity's work cancels).
d_max is reset when the corner leaves the ground: above the ground a contact's memory d_max - d decays as
exp(-300 t / tau), below 1e-12 of itself within 0.1 tau (the event-driven reference resets it at y = 0 exactly).
Above the ground the spring never acts, so a returning corner starts a fresh contact. Below the ground, free of
force, a corner's set relaxes onto it at the same rate (d(d_p)/dt = -r (d_p - d) while d_p > d > 0): a corner
that rebounds free of force and turns back before it clears the ground then meets force almost at once, as one
that just cleared the ground does (were the set kept, the two would differ by a 6 % step in the board's peak
within 0.005 deg, at 1.83 deg on the default scene). Both relaxations start from zero, so the equations stay
continuous where a contact releases. Restitution below
`E_MIN` = 0.01 is computed as 0.01 (the unloading stiffness k / e^2 must stay finite; the rebound is then 1 % of
the approach instead of none).

**Friction.** Regularised Coulomb: F_t = -mu N u_t / sqrt(u_t^2 + v_eps^2), u_t the corner's horizontal velocity,
`v_eps` a small speed (default 1e-3 V, V = sqrt(|v_G|^2 + (w R)^2) the impact's speed scale, R half the housing's
diagonal). It is Coulomb's law where |u_t| >> v_eps; a sticking corner creeps at |u_t| ~ v_eps |F_t| / (mu N).
As tau and v_eps go to 0 a single corner strike tends to the rigid Darboux-Keller impact with Stronge's energetic
restitution (the spring returns e^2 of the compression's normal work): `routh_impulse(..., law="stronge")`, with
errors O(tau) and O(v_eps / V).

**Equations.** m dv_G/dt = sum_i (Ft_i, N_i) - m g y-hat; I_G dw/dt = sum_i (c_i - G) x (Ft_i, N_i);
dd_i/dt = -(vertical velocity of c_i); dd_max/dt = d' while the corner loads (d >= d_max - nu, nu = 1e-12 L, and
d' > 0) and while it is above the ground (d < 0: d_max follows d, so a contact starts with d_max = d and no switch;
a memory d_max - d > nu left from a contact relaxes at 300 / tau), -r (d_p - d) / (1 - e^2) while released below
the ground (d_p > d > 0), else 0; dP_i/dt = (Ft_i, N_i). The penetration
is a state of its own, rather than computed from G and theta, so that d and d_max integrate the very same rate
while loading: their difference holds to round-off and the loading test cannot flip on the solver's error (which it
does when d comes from the positions, costing hundreds of rejected steps per contact). Two more states per corner,
its time in contact and its time loading, have rates that jump where a contact starts, turns from loading to
unloading (the force's second derivative jumps there) or ends: the step controller then closes in on those kinks
instead of stepping across them, which would cost accuracy (5e-8 of the rebound) and derivatives (percents).

**Integration.** diffrax `Tsit5` (explicit Runge-Kutta, order 5 with an embedded 4) with a PID step-size controller,
in nondimensional variables (time / tau, velocities / V, lengths / L), default tolerances 1e-10. The right-hand
side is smooth between events (a contact starts, turns, releases or reloads) and kinked at them; an explicit
method crosses each kink with a few rejected steps, while an implicit one (Kvaerno5, tried) has its Newton
iterations straddle the kinks: 20 times the steps on a frictionless corner, 3 to 4 times the run time on frictional
batches. The stiff part is the friction of a sticking corner, whose slip relaxes at Lambda = mu N m B1 / v_eps per
unit mass (m B1 = 1 + m y^2 / I_G), thousands per tau at the default v_eps. An explicit method's steps must stay
below about 3 / Lambda; its error control keeps the solution stable there, but not the derivatives that reverse
mode carries through the same steps, which grew to 1e28 in a sticking landing. So the solve runs in a warped time
sigma, dt/dsigma = 1 / (1 + Lambda / lambda0) (lambda0 = 20 / tau; the memory's and the set's relaxations, and the
loading corners' (`memory_rate`), count in Lambda too), where no rate exceeds lambda0, with steps
dsigma <= 2.5 / lambda0: stable for the solution and its derivatives, at about 2 / Lambda of physical time per step
while sticking (some 1000 steps per tau at the default v_eps; a sliding or frictionless corner needs about 100). The
physical time is the state's last entry; the solve keeps the state at each step's end, and a physical time is read
by Newton steps on the cubic Hermite interpolant of the step that holds it (`_state_at`). A smaller v_eps needs `max_steps` to match. The solve stops (a diffrax
`Event`, at the end of the step where it holds) when the landing is over: no corner carries force and every corner
still below the ground moves up. A corner above the ground that still approaches it then is a later impact
(clattering), not part of this landing. The time bound `t_max` (default 10 tau) ends a landing that does not
separate (a near-plastic contact pivoting under gravity, say): `Flag.NOT_SEPARATED`. `throw=False`: a failed solve
(the step limit) is `Flag.SOLVER_FAILED`, never an exception under `jit`.

No Python control flow on traced values: the result is differentiable in the orientation, velocities, spin and the
contact's and housing's fields (reverse mode through diffrax's `RecursiveCheckpointAdjoint`), and `vmap`s.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._common.checks import GRAVITY, Flag, as_float, combine, flag_if, is_concrete
from .._common.compile import filter_jit
from .._common.report import plain, summary_text

E_MIN = 0.01
"""Restitution floor of the compliant contact (the unloading stiffness is k / e^2)."""

_NU = 1e-12  # margin of the loading test d >= d_max - nu, in units of L
_NU_WARP = 1e-6  # a memory d_max - d (units of L) below which its forgetting counts in the warp in proportion
_SET_FLOOR = 1e-3  # the smallest set fraction 1 - e^2 whose relaxation counts in full in d_max's rate
_FORGET_RATE = 300.0  # r: above the ground a contact's memory d_max - d decays as exp(-r t / tau)
_LAMBDA0 = 20.0  # the stiffest rate (per tau) the explicit solver meets in the warped time sigma
_T = 30  # where the state holds the physical time
_SIGMA_BOUND = 1e9  # the warped time's bound: the solve ends at separation, `t_max` or `max_steps` first
_DSIGMA_MAX = 0.125  # its largest step: lambda0 dsigma = 2.5, inside Tsit5's stability interval (-3.3, 0]
CLOCK_ATOL = 1e-2
"""The contact and loading clocks' absolute tolerance (units of tau) in a solve that does not close in on the
contacts' kinks (`kinks=False`): the step controller then steps across them. On the JESD22 plate's near-flat
landings at a tolerance of 1e-6 that took 19 % fewer steps (2470 against 3060 on average: the resting housing's
contacts open and close every few steps) and moved the board's peaks by up to 2.1e-4 of the largest against solves
at 1e-10 (1.0e-4 with the kinks closed in on); derivatives through such a solve are not the landing's."""


def housing_corners(width, height) -> Float[Array, "4 2"]:
    """Body coordinates (q1, q2) from G of the four corners: (+W/2, +H/2), (-W/2, +H/2), (-W/2, -H/2),
    (+W/2, -H/2)."""
    w, h = width / 2, height / 2
    return jnp.stack([jnp.stack([w, h]), jnp.stack([-w, h]), jnp.stack([-w, -h]), jnp.stack([w, -h])])


def _rotate(v, c, s):
    """Rotate vectors v (..., 2) by the angle with cosine c and sine s."""
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def _cross_z(v):
    """z x v for vectors v (..., 2)."""
    return jnp.stack([-v[..., 1], v[..., 0]], axis=-1)


def spring_force(kappa, e, d, dmax):
    """The hysteretic corner spring's normal force (units of `kappa`, the loading stiffness, times d): k d on the
    loading line (d >= d_max), (k / e^2)(d - d_p) = k (d - (1 / e^2 - 1)(d_max - d)) below it, 0 below d_p."""
    # On the loading line (d_max - d within the round-off margin nu) the force is k d: the margin carries no
    # derivative, so that a memory's derivative that has not healed yet (`memory_rate`) does not reach the force.
    gap = dmax - d
    below = jnp.where(gap > _NU, gap, jax.lax.stop_gradient(jnp.maximum(gap, 0.0)))
    return jnp.maximum(0.0, kappa * (d - (1.0 / e**2 - 1.0) * below))


def memory_rate(e, d, dmax, d_rate, friction_stiffness):
    """Each corner's memory rate d(d_max)/dt (the module's notes), whether it is compressing (1.0 or 0.0: on its
    loading line, below the ground), and the time warp dt/dsigma = 1 / (1 + Lambda / lambda0), Lambda the stiff
    rates: `friction_stiffness` (the sticking corners', the model's) and the memory's own below.

    - d_max follows d while the corner loads and while it is above the ground (so a contact starts with d_max = d,
      with no switch); the margin nu keeps round-off from flipping the test.
    - Free of force below the ground, the set d_p = (1 - e^2) d_max relaxes onto the corner at the rate r: a corner
      that turns back before it clears the ground meets force (almost) at once, as one that just cleared it does.
    - Above the ground a memory left from a contact relaxes onto d at the rate r.
    Both relaxations start from zero, so the rate is continuous where a contact releases or a corner leaves the
    ground's force (a jump there would be a jump of the derivatives that reverse mode does not see). They count
    in Lambda at r, in full while they exceed `_NU_WARP` and in proportion below: a warp that switched off at the
    forgetting's own threshold made the memory hover there in flight, each step's stages flipping the switch
    (thousands of rejected steps through a drop's flight). Below `_NU_WARP` an explicit step may overshoot the
    memory to a small negative value, where the loading test freezes it: a memory of that size is gone either way.
    - A corner that reloads onto its loading line switches d_max's rate from 0 to d' on a surface the state
      crosses. Reverse mode through the solver's steps misses that switch (its saltation) and kept d_max's
      derivative apart from d's for the rest of the contact, though the two are equal on the loading line (a
      factor of 30 in one corner's impulse, measured). While a corner loads, a term whose value is 0 relaxes
      d_max's derivative onto d's at the rate r, counted in Lambda (6 % more steps on a near-flat landing)."""
    follow = (d >= dmax - _NU) & ((d_rate > 0.0) | (d < 0.0))
    set_fraction = 1.0 - e**2
    gap = set_fraction * dmax - d  # how far the set lies below a released corner
    released = (d > 0.0) & (gap > 0.0)
    forget = (d < 0.0) & (dmax > d + _NU)
    # e -> 1 leaves no set (d_p -> 0); the floor keeps the rate finite.
    ddmax = (jnp.where(follow | forget, d_rate, 0.0) - jnp.where(forget, _FORGET_RATE * (dmax - d), 0.0)
             - jnp.where(released, _FORGET_RATE * gap / jnp.maximum(set_fraction, _SET_FLOOR), 0.0))
    compressing = jnp.where(follow & (d > 0.0), 1.0, 0.0)
    relaxing = (jnp.where(forget, jnp.clip((dmax - d) / _NU_WARP, 0.0, 1.0), 0.0)
                + jnp.where(released, jnp.clip(gap / _NU_WARP, 0.0, 1.0), 0.0))
    # Each corner's memory relaxes on its own (its rate depends on its own d alone): the stiffest of them bounds the
    # explicit step, not their sum (which cost 17 % more steps on a near-flat landing of two corners).
    Lambda = friction_stiffness + _FORGET_RATE * jnp.max(relaxing + compressing)
    warp = 1.0 / (1.0 + Lambda / _LAMBDA0)
    memory = dmax - d
    heal = -_FORGET_RATE * (memory - jax.lax.stop_gradient(memory))
    return ddmax + jnp.where(compressing > 0.0, heal, 0.0), compressing, warp


class _Model(eqx.Module):
    """The landing's equations in nondimensional form (time / T, velocities / V, lengths / L = V T; the angle
    change as R (theta - theta0) / L; impulses / (m V)). The state: G's displacement (2), v_G (2), the angle
    change, the spin w R / V, then per corner (4 each) d, d_max, Pt, Pn, time in contact, time loading, and last
    the physical time."""

    # scales
    T: Array  # tau, s
    V: Array  # speed scale, m/s
    R: Array  # half the housing's diagonal, m
    mass: Array
    inertia: Array
    theta0: Array
    y0: Array  # height of G at first touch, m
    # nondimensional parameters
    o0: Array  # (4, 2) corners from G in the ground frame at first touch / R
    h0: Array  # (4,) corner heights at first touch / L (the lowest: 0)
    kappa: Array  # (4,) k_i T^2 / m
    e: Array
    mu: Array
    eps: Array  # v_eps / V
    g: Array  # g T / V
    mR2_I: Array  # m R^2 / I_G
    L_R: Array  # L / R

    def corner_state(self, y):
        """Corner offsets from G / R (4, 2), penetrations d / L (4,), their rates d' / V (4,), horizontal corner
        velocities / V (4,), all from the state vector y."""
        angle = y[4] * self.L_R
        o = _rotate(self.o0, jnp.cos(angle), jnp.sin(angle))
        vel = y[2:4] + y[5] * _cross_z(o)
        return o, y[6:10], -vel[:, 1], vel[:, 0]

    def forces(self, y):
        """(Ft, N) per corner (4, 2) in units of m V / T, corner offsets / R, penetrations, their rates, and the
        corners' horizontal velocities."""
        o, d, d_rate, u_t = self.corner_state(y)
        dmax = y[10:14]
        N = spring_force(self.kappa, self.e, d, dmax)
        Ft = -self.mu * N * u_t / jnp.sqrt(u_t**2 + self.eps**2)
        return jnp.stack([Ft, N], axis=-1), o, d, d_rate, u_t

    def rhs(self, sigma, y, args=None):
        """dy/dsigma: the equations in physical time (nondimensional t / T, the state's last entry), times the
        warp dt/dsigma."""
        F, o, d, d_rate, u_t = self.forces(y)
        dmax = y[10:14]
        a = jnp.sum(F, axis=0) - jnp.stack([jnp.zeros_like(self.g), self.g])
        alpha = self.mR2_I * jnp.sum(o[:, 0] * F[:, 1] - o[:, 1] * F[:, 0])
        ddmax, compressing, warp = memory_rate(self.e, d, dmax, d_rate, self.friction_stiffness(F[:, 1], o, u_t))
        # Each corner's time in contact and time loading: their rates jump where a contact starts, turns from
        # loading to unloading (the force's second derivative jumps there) or ends, so the step controller closes
        # in on those kinks instead of stepping across them (which costs accuracy and spoils derivatives).
        in_contact = jnp.where(F[:, 1] > 0.0, 1.0, 0.0)
        rate = jnp.concatenate([y[2:4], a, y[5:6], alpha[None], d_rate, ddmax, F[:, 0], F[:, 1], in_contact,
                                compressing, jnp.ones(1)])
        return rate * warp

    def friction_stiffness(self, N, o, u_t):
        """The sticking corners' stiff rate (per T), summed: a sticking corner's slip relaxes at mu N m B1 / v_eps
        (times v_eps^3 / (u_t^2 + v_eps^2)^(3/2), 1 at u_t = 0: sliding is not stiff), m B1 = 1 + m y^2 / I_G."""
        slip = self.eps**2 / (u_t**2 + self.eps**2)
        return jnp.sum(self.mu * N * (1.0 + self.mR2_I * o[:, 1] ** 2) * slip * jax.lax.rsqrt(u_t**2 + self.eps**2))

    def separated(self, y):
        """No corner carries force and every corner below the ground moves up."""
        F, _, d, d_rate, _ = self.forces(y)
        return jnp.all(F[:, 1] <= 0.0) & jnp.all((d < 0.0) | (d_rate < 0.0))

    def dimensional(self, y):
        """(G (2,), v_G (2,), theta, w) in SI units from the state vector."""
        L = self.V * self.T
        G = jnp.stack([y[0] * L, self.y0 + y[1] * L])
        return G, y[2:4] * self.V, self.theta0 + y[4] * L / self.R, y[5] * self.V / self.R


class Landing(eqx.Module):
    """A compliant landing (`compliant_landing`).

    - `P`: impulse (Pt, Pn) each corner received, (4, 2), N s; corners in the order of `corners`.
    - `corners`: the corners' body coordinates (q1, q2) from G, (4, 2), m.
    - `dv_G`: velocity jump of G from the contact forces, sum(P) / m, m/s (gravity's g t_end is not in it: G's
      velocity at `t_end` is v0 + dv_G - (0, g t_end)). `dw`: spin jump, rad/s (gravity has no moment about G).
    - `t_end`: when the solve stopped (the end of the step in which the housing separated), s from first touch.
    - `contact_time`: how long each corner carried force, (4,), s (a single frictionless strike: tau).
      `loading_time`: how long each corner was on its loading line (d = d_max growing), (4,), s.
    - `energy_change`: kinetic plus potential energy at `t_end` minus before, J (<= 0).
    - `separated`: whether the landing ended by separation before `t_max`. `steps`: accepted solver steps.
    - `flags`: `Flag` mask: SOLVER_FAILED, NOT_SEPARATED, SEPARATING_CONTACT (no corner approaches the ground at
      first touch), NONFINITE_RESULT and the inputs' range flags.

    Methods (t in s from first touch; before 0 and after `t_end` the housing flies freely): `velocity(t)`,
    `forces(t)`, `point_velocity(t, q)`, `point_acceleration(t, q)`.
    """

    P: Float[Array, "4 2"]
    corners: Float[Array, "4 2"]
    dv_G: Float[Array, "2"]
    dw: Float[Array, ""]
    t_end: Float[Array, ""]
    contact_time: Float[Array, " 4"]
    loading_time: Float[Array, " 4"]
    energy_change: Float[Array, ""]
    separated: Bool[Array, ""]
    steps: Int[Array, ""]
    flags: Int[Array, ""]
    model: _Model
    solution: eqx.Module  # a diffrax.Solution
    v0: Float[Array, "2"]
    w0: Float[Array, ""]
    end_state: Float[Array, " 31"]
    gravity: Float[Array, ""]

    def summary(self) -> dict:
        """The landing's numbers, units in the keys (JSON-ready; `repr` prints them)."""
        if jnp.ndim(self.t_end):
            raise ValueError("Landing.summary() needs one landing (index a batched one first)")
        return plain({
            "corner_impulses_Ns": self.P,
            "velocity_jump_m_per_s": self.dv_G,
            "spin_jump_rad_per_s": self.dw,
            "contact_times_ms": 1e3 * self.contact_time,
            "end_time_ms": 1e3 * self.t_end,
            "energy_change_J": self.energy_change,
            "solver_steps": self.steps,
            "flags": Flag.describe(self.flags),
        })

    def __repr__(self) -> str:
        try:
            return summary_text(self.summary(), "Landing")
        except (ValueError, TypeError, jax.errors.ConcretizationTypeError):
            return f"Landing(P.shape={tuple(jnp.shape(self.P))})"

    def _state(self, t):
        return _state_at(self.solution, self.model.rhs, _T, self.model.T, self.t_end, t)

    def _rigid(self, t, y):
        """(v_G, theta, w, a_G, alpha, corner forces / (m V / T)) at scalar time t, SI, from the state y there."""
        m = self.model
        _, v, theta, w = m.dimensional(y)
        F, o, _, _, _ = m.forces(y)
        inside = (t >= 0.0) & (t <= self.t_end)
        F = jnp.where(inside, F, 0.0)
        scale = m.V / m.T  # acceleration unit
        a = jnp.sum(F, axis=0) * scale - jnp.stack([jnp.zeros_like(self.gravity), self.gravity])
        alpha = m.mR2_I * jnp.sum(o[:, 0] * F[:, 1] - o[:, 1] * F[:, 0]) * scale / m.R
        # Free flight before the touch and after the end: v changes by gravity only, the spin not at all.
        before = t < 0.0
        after = t > self.t_end
        v = jnp.where(before, self.v0 + jnp.stack([0.0 * t, -self.gravity * t]), v)
        v = jnp.where(after, v + jnp.stack([0.0 * t, -self.gravity * (t - self.t_end)]), v)
        w = jnp.where(before, self.w0, w)
        theta = theta + w * (jnp.minimum(t, 0.0) + jnp.maximum(t - self.t_end, 0.0))
        return v, theta, w, a, alpha, F

    def velocity(self, t) -> Float[Array, "... 3"]:
        """(vx, vy, w) of G at time(s) t (s from first touch): m/s and rad/s."""
        def one(t, y):
            v, _, w, _, _, _ = self._rigid(t, y)
            return jnp.concatenate([v, w[None]])

        return _over_times(one, t, self._state)

    def forces(self, t) -> Float[Array, "... 4 2"]:
        """Contact force (Ft, N) on each corner at time(s) t, N."""
        m = self.model

        def one(t, y):
            return self._rigid(t, y)[5] * m.mass * m.V / m.T

        return _over_times(one, t, self._state)

    def point_velocity(self, t, q) -> Float[Array, "... 2"]:
        """Velocity (ground frame, m/s) at time(s) t of housing points at body coordinates q = (q1, q2) from G
        (shape (..., 2)): v_G + w z x r. The result has shape t.shape + q.shape."""
        q = jnp.asarray(q)

        def one(t, y):
            v, theta, w, _, _, _ = self._rigid(t, y)
            r = _rotate(q, jnp.cos(theta), jnp.sin(theta))
            return v + w[..., None] * _cross_z(r)

        return _over_times(one, t, self._state)

    def point_acceleration(self, t, q) -> Float[Array, "... 2"]:
        """Acceleration (ground frame, m/s^2, gravity included) at time(s) t of housing points at body coordinates
        q = (q1, q2) from G: a_G + alpha z x r - w^2 r, r = R(theta(t)) q, from the solution's state and the contact
        forces there. The result has shape t.shape + q.shape."""
        q = jnp.asarray(q)

        def one(t, y):
            _, theta, w, a, alpha, _ = self._rigid(t, y)
            r = _rotate(q, jnp.cos(theta), jnp.sin(theta))
            return a + alpha * _cross_z(r) - w**2 * r

        return _over_times(one, t, self._state)

    def contact_velocity(self, t, q) -> Float[Array, "... 2"]:
        """The integral of `contact_acceleration` from before the touch to time(s) t: the velocity change the contact
        forces gave housing points at body coordinates q by then, (v_G(t) - v0 + g t) + (w(t) - w0) z x r0 (m/s).
        It is continuous in t and in the inputs where the forces jump (a corner's touch), so samples of it move
        smoothly with the drop."""
        q = jnp.asarray(q)
        r0 = _rotate(q, jnp.cos(self.model.theta0), jnp.sin(self.model.theta0))

        def one(t, y):
            v, _, w, _, _, _ = self._rigid(t, y)
            dv = v - self.v0 + jnp.stack([jnp.zeros_like(t), self.gravity * t])
            return dv + (w - self.w0) * _cross_z(r0)

        return _over_times(one, t, self._state)

    def contact_acceleration(self, t, q) -> Float[Array, "... 2"]:
        """Acceleration from the contact forces alone (ground frame, m/s^2) at time(s) t of housing points at body
        coordinates q = (q1, q2) from G, with the lever arms of the first touch: sum(F) / m + alpha z x r0,
        r0 = R(theta0) q. Gravity and the centripetal -w^2 r act in free flight too, before the landing, and are
        not what the supports add; the turn during the landing (O(w tau)) is left out, as the rigid law's
        `point_velocity_jump` leaves it out. Its integral over the landing is `dv_G + dw z x r0`."""
        q = jnp.asarray(q)
        r0 = _rotate(q, jnp.cos(self.model.theta0), jnp.sin(self.model.theta0))

        def one(t, y):
            _, _, _, a, alpha, _ = self._rigid(t, y)
            a = a + jnp.stack([jnp.zeros_like(self.gravity), self.gravity])
            return a + alpha * _cross_z(r0)

        return _over_times(one, t, self._state)


def _state_at(solution, rhs, time_index: int, T, t_end, t, iterations: int = 3):
    """Nondimensional states at times t (s; a 1D array) of a landing solved in warped time, held at its ends outside
    [0, t_end]: at the warped time sigma where the solution's physical time (state entry `time_index`, in units of
    T; it grows monotonically with sigma) is t. The solve keeps the state at each step's end (`_solve`); within the
    step that holds t the state is the cubic Hermite interpolant of its ends and their rates `rhs` (the order of
    Tsit5's own dense output, in a ninth of the memory: zeroing and filling the dense output's buffers would take
    half of a landing's solve). Safeguarded Newton steps on its time entry (a bisection where a step leaves the bracket) converge to
    round-off in 2 (3 are taken). 60 bisections over the whole solve cost 6 times as much, and a bracket spanning
    several steps meets the warp's kinks, where Newton stalls."""
    target = jnp.clip(t, 0.0, t_end) / T
    sigma_k, y_k = solution.ts, solution.ys  # the start, then each step's end (inf after the last step)
    times = y_k[:, time_index]

    def one(target):
        k = jax.lax.stop_gradient(jnp.clip(jnp.searchsorted(times[1:], target, side="left"), 0, times.shape[0] - 2))
        s0, s1, y0, y1 = sigma_k[k], sigma_k[k + 1], y_k[k], y_k[k + 1]
        h = s1 - s0
        f0, f1 = rhs(s0, y0) * h, rhs(s1, y1) * h

        def hermite(sigma, entry=slice(None)):
            u = (sigma - s0) / h
            a, b, c, d = y0[entry], f0[entry], y1[entry], f1[entry]
            return (a + u * (b + u * ((3 * (c - a) - 2 * b - d) + u * (2 * (a - c) + b + d))))

        def clock(sigma):
            return hermite(sigma, time_index)

        lo, hi = jax.lax.stop_gradient((s0, s1))

        def newton(_, c):
            lo, hi, sigma = c
            f = clock(sigma) - target
            rate = jax.jvp(clock, (sigma,), (jnp.ones_like(sigma),))[1]
            lo, hi = jnp.where(f <= 0.0, sigma, lo), jnp.where(f <= 0.0, hi, sigma)
            step = sigma - f / jnp.where(rate > 0.0, rate, 1.0)
            return lo, hi, jnp.where((step >= lo) & (step <= hi), step, 0.5 * (lo + hi))

        f_lo, f_hi = jax.lax.stop_gradient((times[k] - target, times[k + 1] - target))
        start = jnp.clip(lo - f_lo * (hi - lo) / jnp.where(f_hi > f_lo, f_hi - f_lo, 1.0), lo, hi)
        sigma = jax.lax.stop_gradient(jax.lax.fori_loop(0, iterations, newton, (lo, hi, start))[2])
        # The search's sigma carries no derivative, but the physical time at a fixed sigma moves with the inputs:
        # one more Newton step on t(sigma) = target puts d(sigma)/d(input) = -(dt/d input) / (dt/d sigma) in
        # (implicit function theorem; its value change is below the search's resolution).
        y = hermite(sigma)
        rate = rhs(sigma, y)[time_index]
        return hermite(jnp.clip(sigma - (y[time_index] - target) / rate, lo, hi))

    return jax.vmap(one)(target)


def _over_times(fn, t, states):
    """`fn(t, y)` at time(s) t, y the landing's state there from `states` (times (n,) -> states (n, ...)): shape
    t.shape + fn's."""
    t = jnp.asarray(t, dtype=jnp.result_type(float))
    flat = t.reshape(-1)
    out = jax.vmap(fn)(flat, states(flat))
    return out.reshape(t.shape + out.shape[1:])


def plane_landing(
    housing,
    contact,
    orientation,
    velocity,
    spin,
    *,
    v_eps=None,
    gravity=GRAVITY,
    t_max=None,
    until=None,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    max_steps: int = 4096,
) -> Landing:
    """Compliant landing of a plane section `housing` (a `Housing`; `compliant_landing` takes a box too) on the
    ground with `contact` (a `Contact`: friction mu, restitution e, duration tau > 0), from the first touch: the lowest corner at y = 0, the housing at
    `orientation` theta (rad), G moving at `velocity` (vx, vy) (m/s) and spinning at `spin` w (rad/s). The model is
    in this module's docstring.

    **Keywords:** `v_eps`: the friction's regularising speed (m/s; default 1e-3 V, V = sqrt(|v|^2 + (w R)^2)).
    `gravity` (m/s^2; 0 isolates the contact). `t_max`: time bound (s; default 10 tau). `until`: integrate to this
    time (s) instead of stopping at separation, through free flight and every later strike (a drop's landings over
    the board's peak window; `t_max` is then ignored and `separated` says whether the housing was off the ground
    at the end). `rtol`, `atol`: the step
    controller's tolerances on the nondimensional state (static). `max_steps`: solver step limit (static).

    **Returns:** a `Landing`. Traceable: under `jit`, `vmap` and `grad` problems come back as `flags`.
    """
    h = housing
    args = [as_float(v, name) for v, name in (
        (h.width, "housing.width"), (h.height, "housing.height"), (h.mass, "housing.mass"),
        (h.inertia, "housing.inertia"), (contact.friction, "contact.friction"),
        (contact.restitution, "contact.restitution"), (contact.duration, "contact.duration"),
        (orientation, "orientation"), (velocity, "velocity"), (spin, "spin"), (gravity, "gravity"))]
    v_eps = jnp.asarray(jnp.nan) if v_eps is None else as_float(v_eps, "v_eps")  # NaN: the default
    t_max = jnp.asarray(jnp.nan) if t_max is None else as_float(t_max, "t_max")
    if until is not None:
        t_max = as_float(until, "until")
    if args[8].shape != (2,):
        raise ValueError(f"velocity must be a pair (vx, vy), m/s; got shape {args[8].shape}")
    if is_concrete(args, v_eps, t_max):
        _check_eagerly(*args, v_eps, t_max)
        return _landing_program(*args, v_eps, t_max, rtol=rtol, atol=atol, max_steps=max_steps,
                                through=until is not None)
    return _landing(*args, v_eps, t_max, rtol=rtol, atol=atol, max_steps=max_steps, through=until is not None)


def _check_eagerly(W, H, m, I, mu, e, tau, theta, v, w, g, v_eps, t_max):
    if not float(tau) > 0:
        raise ValueError(f"contact.duration = {float(tau):g} s: the compliant landing needs a duration > 0 "
                         "(0 is the ideal impulse of the rigid law: corner_impact)")
    if not np.all(np.isfinite(np.concatenate([np.ravel(np.asarray(x)) for x in (theta, v, w, g)]))):
        raise ValueError("orientation, velocity, spin and gravity must be finite")
    if not (np.isnan(v_eps) or float(v_eps) > 0):
        raise ValueError(f"v_eps = {float(v_eps):g} m/s: the friction's regularising speed must be > 0")
    if not (np.isnan(t_max) or float(t_max) > 0):
        raise ValueError(f"t_max = {float(t_max):g} s must be > 0")


def _model(W, H, m, I, mu, e, tau, theta, v, w, g, v_eps) -> _Model:
    R = 0.5 * jnp.sqrt(W**2 + H**2)
    speed2 = v[0] ** 2 + v[1] ** 2 + (w * R) ** 2
    V = jnp.sqrt(jnp.where(speed2 > 0, speed2, 1.0))
    T = jnp.where(tau > 0, tau, 1.0)
    L = V * T
    # The default (NaN) is picked before any arithmetic: a NaN in an untaken branch would poison gradients.
    eps = jnp.where(jnp.isnan(v_eps), 1e-3 * V, v_eps) / V
    q = housing_corners(W, H)
    o0 = _rotate(q, jnp.cos(theta), jnp.sin(theta))  # corners from G in the ground frame, m
    y0 = -jnp.min(o0[:, 1])
    h0 = y0 + o0[:, 1]
    e_used = jnp.clip(e, E_MIN, 1.0)
    w1 = math.pi * (1.0 + e_used) / 2.0  # w1 T
    B2 = 1.0 / m + o0[:, 0] ** 2 / I  # x = (G - corner)_x = -o_x
    kappa = w1**2 / (m * B2)  # k_i T^2 / m = (m_eff / m) (w1 T)^2
    return _Model(T=T, V=V, R=R, mass=m, inertia=I, theta0=theta, y0=y0, o0=o0 / R, h0=h0 / L, kappa=kappa,
                  e=e_used, mu=mu, eps=eps, g=g * T / V, mR2_I=m * R**2 / I, L_R=L / R)


def _solve(model, y_init, time_index: int, t_max, *, rtol, atol, max_steps, through: bool,
           clocks: slice | None = None):
    """Integrate a landing's `model` (`rhs` in the warped time, `separated`) from `y_init`: (solution, end state,
    failed, separated). It stops at separation or the bound `t_max` (s; NaN: 10 T), or with `through` at `t_max`
    only. `clocks`: where the state's contact and loading clocks are, to step across the kinks they mark
    (`CLOCK_ATOL`); None: the controller closes in on every kink."""
    import diffrax  # here, not on import: a run of kept programs never traces a landing and skips its second

    if clocks is not None:
        atol = jnp.full(y_init.shape, atol, dtype=y_init.dtype).at[clocks].set(max(CLOCK_ATOL, atol))
    t_bound = jnp.where(jnp.isnan(t_max), 10.0 * model.T, t_max) / model.T
    controller = diffrax.PIDController(rtol=rtol, atol=atol, pcoeff=0.3, icoeff=0.3, dtmax=_DSIGMA_MAX)
    if through:
        event = diffrax.Event(lambda sigma, y, args, **kw: y[time_index] >= t_bound)
    else:
        event = diffrax.Event(lambda sigma, y, args, **kw: model.separated(y) | (y[time_index] >= t_bound))
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(model.rhs), diffrax.Tsit5(), 0.0, _SIGMA_BOUND, None, y_init,
        saveat=diffrax.SaveAt(t0=True, steps=True), stepsize_controller=controller, event=event,
        max_steps=max_steps, throw=False,
    )
    # The start, then each accepted step's end (inf after the last): `_state_at` interpolates between them.
    y_end = sol.ys[jnp.minimum(sol.stats["num_accepted_steps"], max_steps)]
    failed = sol.result != diffrax.RESULTS.event_occurred
    return sol, y_end, failed, ~failed & model.separated(y_end)


def _flags(failed, separated, through: bool, d0, d_rate0, y_end, tau, e, mu):
    """A landing's `Flag` mask from its solve and its contact's fields (d0, d_rate0: penetrations and their rates
    at first touch)."""
    return combine(
        flag_if(failed, Flag.SOLVER_FAILED),
        flag_if(~separated & ~failed & (not through), Flag.NOT_SEPARATED),
        flag_if(~jnp.any((d0 >= 0.0) & (d_rate0 > 0.0)), Flag.SEPARATING_CONTACT),
        flag_if(~jnp.all(jnp.isfinite(y_end)), Flag.NONFINITE_RESULT),
        flag_if(~(tau > 0), Flag.DURATION_NEGATIVE),
        flag_if(~((e >= 0) & (e <= 1)), Flag.RESTITUTION_RANGE),
        flag_if(~(mu >= 0), Flag.FRICTION_NEGATIVE),
    )


def _landing(W, H, m, I, mu, e, tau, theta, v, w, g, v_eps, t_max, *, rtol, atol, max_steps,
             through: bool = False, kinks: bool = True) -> Landing:
    """`compliant_landing` on checked arrays; `through`: integrate to `t_max`, not stopping at separation;
    `kinks=False`: the step controller steps across the contacts' kinks (`CLOCK_ATOL`)."""
    model = _model(W, H, m, I, mu, e, tau, theta, v, w, g, v_eps)
    # d = d_max = minus the corners' heights (no corner has a memory yet); the physical time last.
    y_init = jnp.concatenate([jnp.zeros(2), v / model.V, jnp.zeros(1), (w * model.R / model.V)[None], -model.h0,
                              -model.h0, jnp.zeros(17)])
    sol, y_end, failed, separated = _solve(model, y_init, _T, t_max, rtol=rtol, atol=atol, max_steps=max_steps,
                                           through=through, clocks=None if kinks else slice(22, 30))
    P = jnp.stack([y_end[14:18], y_end[18:22]], axis=-1) * m * model.V
    dv_G = jnp.sum(P, axis=0) / m
    _, v_end, _, w_end = model.dimensional(y_end)
    t_end = y_end[_T] * model.T
    G_rise = y_end[1] * model.V * model.T
    energy = (0.5 * m * (v_end @ v_end - v @ v) + 0.5 * I * (w_end**2 - w**2) + m * g * G_rise)
    _, d0, d_rate0, _ = model.corner_state(y_init)
    flags = combine(_flags(failed, separated, through, d0, d_rate0, y_end, tau, e, mu),
                    flag_if(~jnp.all(jnp.isfinite(jnp.stack([theta, v[0], v[1], w, g]))), Flag.NONFINITE_INPUT))
    return Landing(
        P=P, corners=housing_corners(W, H), dv_G=dv_G, dw=w_end - w, t_end=t_end,
        contact_time=y_end[22:26] * model.T, loading_time=y_end[26:30] * model.T, energy_change=energy,
        separated=separated, steps=sol.stats["num_accepted_steps"], flags=flags, model=model, solution=sol,
        v0=v, w0=w, end_state=y_end, gravity=g,
    )


_landing_program = filter_jit(_landing)
