"""Compliant landing of a box housing: the plane section's compliant contact (`compliant_landing`, its module notes)
at each of the box's eight vertices, the rigid body's motion integrated in three dimensions through the landing
(DESIGN.md section 7). It is the model where several vertices strike together or nearly so: an edge, a face, a
near-flat or nearly edge-on landing, where the single-vertex rigid law (`box_impact`) does not apply.

**Frames** as `box_impact`'s: ground x horizontal in the plane of motion, y up, z out of the plane; the body axes
e1, e2, e3 (width, height, depth) are the columns of the attitude R, at first touch Rx(tilt) Rz(orientation).

**State.** G's displacement and velocity (3 + 3), the attitude as a unit quaternion (4), the angular velocity in
body axes (3; Euler's equations with the principal moments), per vertex its penetration d, the largest
penetration d_max of its current contact, the impulse (Px, Py, Pz) it received, its time in contact and its time
loading (7 each), and the physical time.

**Contact per vertex.** The plane's hysteretic spring N = max(0, k (d - (1 / e^2 - 1) max(d_max - d, 0))) and
regularised Coulomb friction F_t = -mu N u_t / sqrt(|u_t|^2 + v_eps^2), u_t the vertex's horizontal velocity
(x, z). **Stiffness:** each vertex has half the stiffness its edge along the depth (e3) would have as a corner of
the plane model, k = m_edge w1^2 / 2, m_edge the effective mass in the normal direction of that edge's midpoint
at first touch, w1 = pi (1 + e) / (2 tau). An edge along the depth that lands level (tilt = 0) is then the plane
section's corner exactly: its two vertices carry half the plane's force each, the motion stays in the plane and
the contact lasts tau. A lone vertex has a smaller effective mass m_v than its edge, and its contact lasts
tau sqrt(2 m_v / m_edge) (0.7 to 1.2 tau on common boxes) rather than tau.

**Integration** as the plane's: diffrax Tsit5 with a PID controller in nondimensional variables (time / tau,
velocities / V, lengths / L = V tau, V the impact's speed scale), the warped time that keeps a sticking vertex's
friction stable for the solution and its derivatives, the quaternion renormalised where it is read. `throw=False`:
a failed solve is `Flag.SOLVER_FAILED`.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .box import box_vertices
import numpy as np

from .._common.checks import GRAVITY, as_float, is_concrete
from .landing import (E_MIN, _check_eagerly, _flags, _over_times, _solve, _state_at,
                      memory_rate, plane_landing, spring_force)

_N = 8  # vertices
_D, _DMAX, _P, _TC, _TL = 13, 21, 29, 53, 61  # where each vertex block starts in the state
_T3 = 69  # the physical time


def _quaternion(orientation, tilt):
    """Unit quaternion (w, x, y, z) of Rx(tilt) Rz(orientation)."""
    ct, st = jnp.cos(tilt / 2), jnp.sin(tilt / 2)
    co, so = jnp.cos(orientation / 2), jnp.sin(orientation / 2)
    return jnp.stack([ct * co, st * co, -st * so, ct * so])


def _rotation(q):
    """Rotation matrix of the quaternion q (normalised here)."""
    w, x, y, z = q / jnp.sqrt(q @ q)
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])


def _quaternion_rate(q, w_body):
    """dq/dt = q (x) (0, w_body) / 2."""
    a, b, c, d = q
    x, y, z = w_body
    return 0.5 * jnp.stack([-b * x - c * y - d * z, a * x + c * z - d * y, a * y - b * z + d * x,
                            a * z + b * y - c * x])


class _Model3(eqx.Module):
    """The box landing's equations in nondimensional form (time / T, velocities / V, lengths / L = V T, vertex
    arms / R, spin in units V / R, impulses / (m V))."""

    T: Array
    V: Array
    R: Array  # half the box's diagonal, m
    mass: Array
    moments: Array  # (3,) principal moments, kg m^2
    q_body: Array  # (8, 3) vertices in body coordinates / R
    h0: Array  # (8,) heights at first touch / L
    kappa: Array  # (8,) k_i T^2 / m
    e: Array
    mu: Array
    eps: Array
    g: Array
    mR2_I: Array  # (3,) m R^2 / I
    L_R: Array

    def kinematics(self, y):
        """Attitude, vertex arms in the ground frame / R (8, 3), spin in the ground frame, vertex velocities / V
        (8, 3), penetrations / L and their rates."""
        Rot = _rotation(y[6:10])
        o = self.q_body @ Rot.T
        spin = Rot @ y[10:13]
        vel = y[3:6] + jnp.cross(spin, o)
        return Rot, o, vel, y[_D:_DMAX], -vel[:, 1]

    def forces(self, y):
        """Force (Fx, N, Fz) per vertex (8, 3) in units of m V / T, and the kinematics."""
        Rot, o, vel, d, d_rate = self.kinematics(y)
        dmax = y[_DMAX:_P]
        N = spring_force(self.kappa, self.e, d, dmax)
        u = vel[:, jnp.array([0, 2])]
        speed = jnp.sqrt(jnp.sum(u**2, axis=-1) + self.eps**2)
        Ft = -self.mu * (N / speed)[:, None] * u
        return jnp.stack([Ft[:, 0], N, Ft[:, 1]], axis=-1), Rot, o, u, d, d_rate

    def rhs(self, sigma, y, args=None):
        F, Rot, o, u, d, d_rate = self.forces(y)
        dmax = y[_DMAX:_P]
        a = jnp.sum(F, axis=0) - jnp.stack([0.0 * self.g, self.g, 0.0 * self.g])
        torque_body = Rot.T @ jnp.sum(jnp.cross(o, F), axis=0)
        w_b = y[10:13]
        inertia = 1.0 / self.mR2_I  # I / (m R^2)
        alpha = self.mR2_I * torque_body - self.L_R * jnp.cross(w_b, inertia * w_b) / inertia
        ddmax, compressing, warp = memory_rate(self.e, d, dmax, d_rate, self.friction_stiffness(F[:, 1], Rot, o, u))
        in_contact = jnp.where(F[:, 1] > 0.0, 1.0, 0.0)
        rate = jnp.concatenate([y[3:6], a, _quaternion_rate(y[6:10], w_b) * self.L_R, alpha, d_rate, ddmax,
                                F.reshape(-1), in_contact, compressing, jnp.ones(1)])
        return rate * warp

    def friction_stiffness(self, N, Rot, o, u):
        """The sticking vertices' stiff rate as the plane's, with m B1 the trace of the vertex's tangential inverse
        inertia times m (an upper bound of its largest eigenvalue) at the current attitude."""
        u2 = jnp.sum(u**2, axis=-1)
        slip = self.eps**2 / (u2 + self.eps**2)
        tangents = jnp.eye(3, dtype=o.dtype)[jnp.array([0, 2])]  # x, z
        arms = jnp.cross(o[:, None, :], tangents[None, :, :]) @ Rot  # (8, 2, 3): r x t in body axes
        mB1 = 2.0 + jnp.sum(arms**2 * self.mR2_I, axis=(-1, -2))
        stiff = self.mu * N * mB1 * slip * jax.lax.rsqrt(u2 + self.eps**2)
        return jnp.sum(stiff)

    def separated(self, y):
        F, _, _, _, d, d_rate = self.forces(y)
        return jnp.all(F[:, 1] <= 0.0) & jnp.all((d < 0.0) | (d_rate < 0.0))


class BoxLanding(eqx.Module):
    """A box's compliant landing (`box_landing`).

    - `P`: impulse (Px, Py, Pz) each vertex received, (8, 3), N s, vertices in `box_vertices`' order.
    - `dV`: G's velocity jump from the contact forces (gravity's g t not in it), m/s; `dOmega`: the angular
      velocity's change, rad/s (ground frame; gyroscopic turning in it too).
    - `t_end`, `contact_time` (8,), `loading_time` (8,), `energy_change` (J, <= 0), `separated`, `steps`, `flags`:
      as `Landing`'s.

    `contact_velocity(t, q)`: the velocity change the contact forces gave body points at body coordinates q (m, along
    e1, e2, e3 from G) by time(s) t (s from first touch), with the lever arms of the first touch, m/s (ground
    frame).
    """

    P: Float[Array, "8 3"]
    dV: Float[Array, "3"]
    dOmega: Float[Array, "3"]
    t_end: Float[Array, ""]
    contact_time: Float[Array, " 8"]
    loading_time: Float[Array, " 8"]
    energy_change: Float[Array, ""]
    separated: Bool[Array, ""]
    steps: Int[Array, ""]
    flags: Int[Array, ""]
    model: _Model3
    solution: eqx.Module  # a diffrax.Solution
    attitude: Float[Array, "3 3"]
    v0: Float[Array, "3"]
    w0: Float[Array, "3"]
    gravity: Float[Array, ""]

    def _state(self, t):
        return _state_at(self.solution, self.model.rhs, _T3, self.model.T, self.t_end, t)

    def _motion(self, t, y):
        """(v_G, spin) in the ground frame at scalar t, SI, free flight outside the landing, from the state y there."""
        m = self.model
        v = y[3:6] * m.V
        spin = _rotation(y[6:10]) @ y[10:13] * m.V / m.R
        fall = jnp.stack([0.0 * t, -self.gravity * t, 0.0 * t])
        v = jnp.where(t < 0.0, self.v0 + fall, v)
        after = jnp.stack([0.0 * t, -self.gravity * (t - self.t_end), 0.0 * t])
        v = jnp.where(t > self.t_end, v + after, v)
        return v, jnp.where(t < 0.0, self.w0, spin)

    def forces(self, t) -> Float[Array, "... 8 3"]:
        """Contact force (Fx, N, Fz) on each vertex at time(s) t (s from first touch), N (ground frame)."""
        m = self.model

        def one(t, y):
            F = m.forces(y)[0]
            return jnp.where((t >= 0.0) & (t <= self.t_end), F, 0.0) * m.mass * m.V / m.T

        return _over_times(one, t, self._state)

    def contact_velocity(self, t, q) -> Float[Array, "... 3"]:
        q = jnp.asarray(q)
        r0 = q @ self.attitude.T

        def one(t, y):
            v, spin = self._motion(t, y)
            dv = v - self.v0 + jnp.stack([0.0 * t, self.gravity * t, 0.0 * t])
            return dv + jnp.cross(spin - self.w0, r0)

        return _over_times(one, t, self._state)


def _box_model(W, H, D, m, moments, mu, e, tau, orientation, tilt, v, w, g, v_eps) -> tuple[_Model3, Array, Array]:
    R = 0.5 * jnp.sqrt(W**2 + H**2 + D**2)
    # The speed scale (and so the default v_eps) with the plane section's half diagonal: a level edge along e3
    # lands as the plane's corner with the same regularisation.
    speed2 = v @ v + (w @ w) * (W**2 + H**2) / 4
    V = jnp.sqrt(jnp.where(speed2 > 0, speed2, 1.0))
    T = jnp.where(tau > 0, tau, 1.0)
    L = V * T
    eps = jnp.where(jnp.isnan(v_eps), 1e-3 * V, v_eps) / V
    q0 = _quaternion(orientation, tilt)
    Rot = _rotation(q0)
    q = box_vertices(W, H, D)
    o0 = q @ Rot.T
    h0 = o0[:, 1] - jnp.min(o0[:, 1])
    e_used = jnp.clip(e, E_MIN, 1.0)
    w1 = math.pi * (1.0 + e_used) / 2.0
    # The vertex's edge along e3: its midpoint's arm, and the effective mass there in the normal direction y.
    edge = (q * jnp.array([1.0, 1.0, 0.0])) @ Rot.T
    arm = jnp.cross(edge, jnp.array([0.0, 1.0, 0.0]))  # r x n
    B_edge = 1.0 / m + jnp.sum((arm @ Rot) ** 2 / moments, axis=-1)
    kappa = 0.5 * w1**2 / (m * B_edge)
    model = _Model3(T=T, V=V, R=R, mass=m, moments=moments, q_body=q / R, h0=h0 / L, kappa=kappa, e=e_used,
                    mu=mu, eps=eps, g=g * T / V, mR2_I=m * R**2 / moments, L_R=L / R)
    return model, q0, Rot


def box_landing(W, H, D, m, moments, mu, e, tau, orientation, tilt, v, w, g, v_eps, t_max, *, rtol: float = 1e-10,
                atol: float = 1e-10, max_steps: int = 32768, through: bool = False, kinks: bool = True) -> BoxLanding:
    """The compliant landing of a `W` x `H` x `D` box (m) of mass `m` (kg) and principal moments `moments` (3,)
    (kg m^2) from the first touch: its lowest vertex at y = 0, attitude Rx(`tilt`) Rz(`orientation`), G moving at
    `v` (3,) m/s and spinning at `w` (3,) rad/s (ground frame); contact friction `mu`, restitution `e`, duration
    `tau` (s); gravity `g` (m/s^2); `v_eps` the friction's regularising speed (NaN: 1e-3 V); `t_max` the time
    bound (s; NaN: 10 tau), or with `through` the time to integrate to, through every strike; `kinks=False`: the
    step controller steps across the contacts' kinks (`landing.CLOCK_ATOL`). Arrays in, a `BoxLanding` out;
    traceable (problems come back as `flags`)."""
    model, q0, Rot = _box_model(W, H, D, m, moments, mu, e, tau, orientation, tilt, v, w, g, v_eps)
    w_body = Rot.T @ w * model.R / model.V
    y_init = jnp.concatenate([jnp.zeros(3), v / model.V, q0, w_body, -model.h0, -model.h0,
                              jnp.zeros(3 * _N + 2 * _N + 1)])
    sol, y_end, failed, separated = _solve(model, y_init, _T3, t_max, rtol=rtol, atol=atol, max_steps=max_steps,
                                           through=through, clocks=None if kinks else slice(_TC, _T3))
    P = y_end[_P:_TC].reshape(_N, 3) * m * model.V
    v_end = y_end[3:6] * model.V
    w_body_end = y_end[10:13] * model.V / model.R
    spin_end = _rotation(y_end[6:10]) @ w_body_end
    t_end = y_end[_T3] * model.T
    rise = y_end[1] * model.V * model.T
    energy = (0.5 * m * (v_end @ v_end - v @ v) + 0.5 * (moments @ w_body_end**2 - moments @ (Rot.T @ w) ** 2)
              + m * g * rise)
    _, _, _, d0, d_rate0 = model.kinematics(y_init)
    flags = _flags(failed, separated, through, d0, d_rate0, y_end, tau, e, mu)
    return BoxLanding(P=P, dV=jnp.sum(P, axis=0) / m, dOmega=spin_end - w, t_end=t_end,
                      contact_time=y_end[_TC:_TL] * model.T, loading_time=y_end[_TL:_T3] * model.T,
                      energy_change=energy, separated=separated, steps=sol.stats["num_accepted_steps"], flags=flags,
                      model=model, solution=sol, attitude=Rot, v0=v, w0=w, gravity=g)


def compliant_landing(housing, contact, orientation, velocity, spin, *, tilt=0.0, v_eps=None, gravity=GRAVITY,
                      t_max=None, until=None, rtol: float = 1e-10, atol: float = 1e-10, max_steps: int = 4096):
    """Compliant landing of `housing` (a `Housing`) on the ground with `contact` (a `Contact`), from the first touch.

    - A plane section: its four corners, at `orientation` (rad), G moving at `velocity` (vx, vy) (m/s) and spinning
      at `spin` w (rad/s): a `Landing` (the model and the keywords: `plane_landing`, `landing.py`'s notes).
    - A box (`Housing.depth`): its eight vertices, turned by `tilt` (rad) after `orientation` (`bd.box_attitude`),
      with `velocity` (vx, vy, vz) and `spin` (wx, wy, wz) in the ground frame: a `BoxLanding` (the same contact
      at every vertex).

    Traceable: under `jit`, `vmap` and `grad` problems come back as `flags`."""
    keywords = dict(v_eps=v_eps, gravity=gravity, t_max=t_max, until=until, rtol=rtol, atol=atol,
                    max_steps=max_steps)
    if not housing.is_box:
        if is_concrete(tilt) and np.any(np.asarray(tilt) != 0):
            raise ValueError("tilt turns a box housing: give Housing.depth (m), or leave tilt = 0 for the plane "
                             "section")
        return plane_landing(housing, contact, orientation, velocity, spin, **keywords)
    h = housing
    args = [as_float(v, name) for v, name in (
        (h.width, "housing.width"), (h.height, "housing.height"), (h.mass, "housing.mass"),
        (h.moments, "housing.moments"), (contact.friction, "contact.friction"),
        (contact.restitution, "contact.restitution"), (contact.duration, "contact.duration"),
        (orientation, "orientation"), (velocity, "velocity"), (spin, "spin"), (gravity, "gravity"))]
    W, H, m, moments, mu, e, tau, theta, v, w, g = args
    if v.shape != (3,) or w.shape != (3,):
        raise ValueError(f"a box's velocity (vx, vy, vz) (m/s) and spin (wx, wy, wz) (rad/s) are 3-vectors in the "
                         f"ground frame; got shapes {v.shape} and {w.shape}")
    v_eps = jnp.asarray(jnp.nan) if v_eps is None else as_float(v_eps, "v_eps")  # NaN: the default
    t_max = jnp.asarray(jnp.nan) if t_max is None else as_float(t_max, "t_max")
    if until is not None:
        t_max = as_float(until, "until")
    tilt = as_float(tilt, "tilt")
    if is_concrete(args, v_eps, t_max, tilt):
        _check_eagerly(W, H, m, moments, mu, e, tau, theta, v, w, g, v_eps, t_max)
        if not np.isfinite(float(tilt)):
            raise ValueError("tilt must be finite")
    return box_landing(W, H, as_float(h.depth, "housing.depth"), m, moments, mu, e, tau, theta, tilt, v, w, g,
                       v_eps, t_max, rtol=rtol, atol=atol, max_steps=max_steps, through=until is not None)
