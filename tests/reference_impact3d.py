"""Independent NumPy/SciPy reference for 3D rigid-body frictional impact at one point (Darboux-Keller).

Nothing here imports beamdrop_jax: it is a separate code path written from the physics, for tests to compare the
package against.

Formulation (Keller 1986; Stronge, "Impact Mechanics", ch. 5; Batlle 1996, "Rough balanced collisions"):

* Contact frame (t1, t2, n). ``K`` is the 3x3 symmetric positive definite inverse inertia at the contact point,
  so the contact velocity is ``u = u0 + K P`` with ``P = (P_t1, P_t2, P_n)`` the impulse on the body.
* The normal impulse ``p = P_n`` is the independent variable (it grows monotonically during the impact).
* Sliding (``u_t != 0``, ``s = u_t / |u_t|``): ``dP_t/dp = -mu s``, so ``du/dp = K (-mu s1, -mu s2, 1)``. In 3D
  the slip direction ``s`` turns during the impact (unless ``u_t`` lies along an invariant direction).
* When ``|u_t|`` reaches 0 (an event) or is 0 at the start:
  - if the friction needed to stick, ``|K_tt^-1 K_tn|``, is ``<= mu``, the contact sticks for the rest of the
    impact (the ratio is constant, so it never needs more friction later): ``dP_t/dp = -K_tt^-1 K_tn``,
    ``du_n/dp = K_nn - K_nt K_tt^-1 K_tn`` (the Schur complement, > 0);
  - else slip resumes along the invariant direction ``s*``: ``(-mu K_tt s* + K_tn) = lambda s*`` with
    ``lambda > 0`` (the slip velocity grows from 0 along ``s*``: ``u_t = lambda (p - p_stop) s*``, so ``s`` stays
    ``s*`` for the rest of the impact).

  Which invariant direction: with ``lambda > 0`` there is exactly one. Write the condition as
  ``(lambda I + mu K_tt) s = K_tn``; for ``lambda > 0`` the matrix is SPD, ``s(lambda) = (lambda I + mu K_tt)^-1 K_tn``
  and ``phi(lambda) = |s(lambda)|^2 = sum_i c_i^2 / (lambda + mu k_i)^2`` (eigen-decomposition of ``K_tt``) is
  strictly decreasing from ``phi(0) = |K_tt^-1 K_tn|^2 / mu^2`` to 0. So a ``lambda > 0`` with ``|s| = 1`` exists iff
  sticking fails (``phi(0) > 1``) and is then unique (Batlle 1996 reaches the same: when the rough contact cannot
  stick there is a single ray of sliding leaving ``u_t = 0``; Stronge ch. 5 calls it the direction of the invariant
  ray along which slip resumes). The other roots of the cross-product condition have ``lambda < 0``: they are the
  directions along which sliding *approaches* ``u_t = 0``, not directions it can leave along. The code finds the
  directions twice, independently: by an angle scan of ``s x (-mu K_tt s + K_tn)`` over ``a in [0, 2 pi)`` with
  Brent polishing, keeping ``lambda > 0``, and by solving the secular equation ``phi(lambda) = 1``; it checks that
  they agree and that the positive root is unique, and raises if not.
* Compression ends at ``u_n = 0`` (first upward crossing), ``p_c``. Poisson: the impact ends at
  ``p_f = (1 + e) p_c``. Stronge (energetic): with ``W_n(p) = int_0^p u_n dp'`` (negative in compression), it ends at
  the first ``p_f > p_c`` where ``W_n(p_f) - W_n(p_c) = -e^2 W_n(p_c)``.

Numerics: the sliding phase is integrated with ``scipy.integrate.solve_ivp`` (DOP853, rtol = atol ~ 1e-13
relative to the problem's scales) on the state ``(P_t1, P_t2, W_n)`` (``u`` is recomputed exactly from ``u0 + K P``),
with terminal events: slip stop, maximum compression, and (Stronge) the restitution work target. The slip-stop
event fires at ``|u_t| = delta`` (``delta = 1e-10 |u0|``, the RHS is singular at ``u_t = 0``) and the last sliver up to
``u_t = 0`` is taken by linear extrapolation (error ~ ``delta^2``), after which ``P_t`` is set so that ``u_t = 0``
exactly. Stick and invariant-direction slip have constant ``dP/dp`` and are integrated with the same machinery
(exact for such right-hand sides), restarting after each event.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

__all__ = ["event_driven_impulse", "invariant_directions", "kinetic_energy_change"]

_RTOL = 1e-13


def kinetic_energy_change(K, u0, P):
    """Change of the body's kinetic energy caused by the contact impulse ``P``: ``P.u0 + P.K.P / 2``."""
    K = np.asarray(K, float)
    P = np.asarray(P, float)
    return float(P @ np.asarray(u0, float) + 0.5 * P @ K @ P)


def _cross_fn(Ktt, Ktn, mu):
    def f(s):
        return -mu * (Ktt @ s) + Ktn

    def g(a):
        s = np.array([math.cos(a), math.sin(a)])
        fs = f(s)
        return s[0] * fs[1] - s[1] * fs[0]

    return f, g


def invariant_directions(K, mu, n_scan=4096):
    """All invariant slip directions at ``u_t = 0``: unit ``s`` with ``-mu K_tt s + K_tn = lambda s``.

    Returns a list of ``(s, lambda)`` sorted by ``lambda`` descending (positive ``lambda``: slip can leave 0 along
    ``s``; negative: slip approaches 0 along ``s``), found by scanning the angle and polishing with Brent.
    """
    K = np.asarray(K, float)
    Ktt, Ktn = K[:2, :2], K[:2, 2]
    f, g = _cross_fn(Ktt, Ktn, mu)
    a = np.linspace(0.0, 2 * math.pi, n_scan + 1)
    S = np.stack([np.cos(a), np.sin(a)])
    F = -mu * (Ktt @ S) + Ktn[:, None]
    ga = S[0] * F[1] - S[1] * F[0]
    scale = max(np.abs(ga).max(), 1e-300)
    roots = []
    for i in range(n_scan):
        if ga[i] == 0.0:
            roots.append(a[i])
        elif ga[i] * ga[i + 1] < 0.0:
            roots.append(brentq(g, a[i], a[i + 1], xtol=1e-15, rtol=1e-15))
    # Also the roots of the degree-2 trigonometric polynomial as a quartic in z = exp(i a), to catch tangent roots
    # (double roots that do not change sign): g(a) = A cos2a + B sin2a + C cos a + D sin a.
    A = -mu * Ktt[0, 1]
    B = -mu * 0.5 * (Ktt[1, 1] - Ktt[0, 0])
    C, D = Ktn[1], -Ktn[0]
    # z^2 g = (A - iB)/2 z^4 + (C - iD)/2 z^3 + 0 z^2 + (C + iD)/2 z + (A + iB)/2
    coeffs = [(A - 1j * B) / 2, (C - 1j * D) / 2, 0.0, (C + 1j * D) / 2, (A + 1j * B) / 2]
    def dg(x):
        return -2 * A * math.sin(2 * x) + 2 * B * math.cos(2 * x) - C * math.sin(x) + D * math.cos(x)

    if any(abs(c) > 0 for c in coeffs):
        for z in np.roots(coeffs):
            if abs(abs(z) - 1.0) < 1e-6:
                x = float(np.angle(z))
                for _ in range(8):  # Newton polish (a double root converges linearly, still far enough)
                    d = dg(x)
                    if d == 0.0 or g(x) == 0.0:
                        break
                    x -= g(x) / d
                roots.append(x % (2 * math.pi))
    out = []
    for r in roots:
        s = np.array([math.cos(r), math.sin(r)])
        lam = float(s @ f(s))
        if abs(g(r)) > 1e-8 * max(scale, 1e-300):
            continue
        if all(np.linalg.norm(s - t) > 1e-6 for t, _ in out):
            out.append((s, lam))
    out.sort(key=lambda x: -x[1])
    return out


def _resume_direction(K, mu):
    """The unique invariant direction with lambda > 0 (slip resumes along it), cross-checked two ways."""
    Ktt, Ktn = K[:2, :2], K[:2, 2]
    if mu == 0:  # frictionless: u_t grows along K_tn (K_tn != 0 here, else sticking would have held)
        return Ktn / np.linalg.norm(Ktn), float(np.linalg.norm(Ktn))
    k, V = np.linalg.eigh(mu * Ktt)
    c = V.T @ Ktn

    def phi_minus_1(lam):
        return float(np.sum(c**2 / (lam + k) ** 2)) - 1.0

    hi = 1.0 + np.linalg.norm(Ktn)
    while phi_minus_1(hi) > 0:
        hi *= 2
    lam = brentq(phi_minus_1, 0.0, hi, xtol=1e-16 * hi, rtol=1e-15)
    s_sec = np.linalg.solve(lam * np.eye(2) + mu * Ktt, Ktn)
    s_sec /= np.linalg.norm(s_sec)
    scan = [(s, lm) for s, lm in invariant_directions(K, mu) if lm > 0]
    if len(scan) != 1 or np.linalg.norm(scan[0][0] - s_sec) > 1e-7:
        raise RuntimeError(f"invariant directions disagree: secular {s_sec, lam}, scan {scan}")
    return s_sec, lam


def event_driven_impulse(K, u0, mu, e, law="poisson", delta_rel=1e-10):
    """Impulse of a frictional single-point impact, by event-driven integration in the normal impulse.

    Parameters: ``K`` 3x3 SPD inverse inertia at the contact in the frame (t1, t2, n); ``u0`` the contact velocity
    before impact (``u0[2] < 0`` approaching); ``mu`` the Coulomb coefficient; ``e`` the restitution coefficient;
    ``law`` ``"poisson"`` (kinetic) or ``"stronge"`` (energetic; ``"energetic"`` accepted).

    Returns a dict:
      P                   impulse (P_t1, P_t2, P_n), shape (3,)
      velocity            final contact velocity u0 + K P, shape (3,)
      Pn_compression      p_c, the normal impulse at maximum compression (u_n = 0)
      Pn_stick            normal impulse where slip first stops (0 if u_t = 0 at the start; inf if it never stops)
      sticks              True if the contact ends the impact stuck (u_t = 0)
      invariant_direction unit (s1, s2) along which slip resumed after stopping (the unique lambda > 0 one), or None
      invariant_lambda    its lambda (d|u_t|/dp along it), or None
      slip_dir_initial    u0_t / |u0_t| (None if u0_t = 0)
      slip_dir_final      final u_t / |u_t| (None if stuck)
      Pn_final            P_n at the end
      W_n_compression     normal work in compression (<= 0); W_n_total the normal work over the whole impact
      energy_change       kinetic energy change P.u0 + P.K.P/2 (<= 0 expected)
      modes               the sequence of regimes, e.g. ["slip", "stick"]
    """
    K = np.asarray(K, float)
    u0 = np.asarray(u0, float)
    law = {"poisson": "poisson", "stronge": "stronge", "energetic": "stronge"}[law]
    if K.shape != (3, 3) or u0.shape != (3,):
        raise ValueError("K must be 3x3 and u0 of shape (3,)")
    if not np.allclose(K, K.T, rtol=1e-12, atol=1e-14 * np.abs(K).max()):
        raise ValueError("K must be symmetric")
    K = 0.5 * (K + K.T)
    if np.linalg.eigvalsh(K).min() <= 0:
        raise ValueError("K must be positive definite")
    if mu < 0 or e < 0 or e > 1:
        raise ValueError("need mu >= 0 and 0 <= e <= 1")

    res = dict(P=np.zeros(3), velocity=u0.copy(), Pn_compression=0.0, Pn_stick=math.inf, sticks=False,
               invariant_direction=None, invariant_lambda=None, slip_dir_initial=None, slip_dir_final=None,
               Pn_final=0.0, W_n_compression=0.0, W_n_total=0.0, energy_change=0.0, modes=[])
    ut0 = np.linalg.norm(u0[:2])
    res["slip_dir_initial"] = u0[:2] / ut0 if ut0 > 0 else None
    if u0[2] >= 0:
        return res

    Ktt, Ktn = K[:2, :2], K[:2, 2]
    vscale = float(np.linalg.norm(u0))
    delta = delta_rel * vscale
    pscale = vscale / np.linalg.eigvalsh(K).min()  # an upper-bound-ish impulse scale
    stick_rate = -np.linalg.solve(Ktt, Ktn)  # dP_t/dp when stuck
    stick_ok = np.linalg.norm(stick_rate) <= mu

    def vel(p, y):
        return u0 + K @ np.array([y[0], y[1], p])

    # State y = (P_t1, P_t2, W_n). Regime: ("slip", None) | ("stick", None) | ("islip", s*)
    p, y = 0.0, np.zeros(3)
    p_c, W_c, p_end = None, None, None

    def regime_at_rest():
        if stick_ok:
            return "stick", None
        s_star, lam = _resume_direction(K, mu)
        res["invariant_direction"], res["invariant_lambda"] = s_star, lam
        return "islip", s_star

    if ut0 <= delta:
        res["Pn_stick"] = 0.0
        y[:2] = -np.linalg.solve(Ktt, u0[:2])  # 0 if u0_t = 0; else a sliver (|u0_t| <= delta) that zeroes u_t
        mode, s_star = regime_at_rest()
    else:
        mode, s_star = "slip", None
    res["modes"].append(mode)

    atol = _RTOL * np.array([pscale, pscale, vscale * pscale])

    nfev = [0]
    for _ in range(50):
        def rhs(q, yy, mode=mode, s_star=s_star):
            nfev[0] += 1
            if nfev[0] > 2_000_000:  # a stop the event missed makes the solver crawl: fail loudly instead
                raise RuntimeError("too many right-hand-side evaluations (slip stop not resolved?)")
            u = vel(q, yy)
            if mode == "slip":
                ut = u[:2]
                d = -mu * ut / np.linalg.norm(ut)
            elif mode == "stick":
                d = stick_rate
            else:
                d = -mu * s_star
            return np.array([d[0], d[1], u[2]])

        events = []
        tags = []
        if mode == "slip":
            def ev_stop(q, yy):
                return np.linalg.norm(vel(q, yy)[:2]) - delta
            ev_stop.terminal, ev_stop.direction = True, -1
            events.append(ev_stop), tags.append("stop")
        if p_c is None:
            def ev_comp(q, yy):
                return vel(q, yy)[2]
            ev_comp.terminal, ev_comp.direction = True, 1
            events.append(ev_comp), tags.append("compression")
        elif law == "stronge":
            target = (1 - e * e) * W_c

            def ev_end(q, yy, target=target):
                return yy[2] - target
            ev_end.terminal, ev_end.direction = True, 1
            events.append(ev_end), tags.append("end")

        span_end = p_end if p_end is not None else p + 4 * pscale + 1e-300
        sol = solve_ivp(rhs, (p, span_end), y, method="DOP853", rtol=_RTOL, atol=atol, events=events or None,
                        dense_output=False)
        if sol.status < 0:
            raise RuntimeError(sol.message)
        # Which terminal event (if any) fired first.
        fired = None
        if sol.status == 1:
            for tag, te in zip(tags, sol.t_events):
                if len(te):
                    fired = tag
                    break
        p, y = float(sol.t[-1]), sol.y[:, -1].copy()

        if fired is None:
            if p_end is not None and p >= p_end:
                break  # Poisson end reached
            continue  # span too short: carry on from here
        if fired == "stop":
            # Extrapolate the last sliver to u_t = 0 with the current derivative, then snap P_t to u_t = 0.
            u = vel(p, y)
            dut = Ktt @ (-mu * u[:2] / np.linalg.norm(u[:2])) + Ktn
            dp = max(-float(u[:2] @ dut) / float(dut @ dut), 0.0)
            if p_end is not None:
                dp = min(dp, p_end - p)
            p_new = p + dp
            Pt_new = -np.linalg.solve(Ktt, u0[:2] + Ktn * p_new)
            un_new = float(u0[2] + K[2, :2] @ Pt_new + K[2, 2] * p_new)
            y = np.array([Pt_new[0], Pt_new[1], y[2] + 0.5 * (u[2] + un_new) * dp])
            p = p_new
            res["Pn_stick"] = p
            mode, s_star = regime_at_rest()
            res["modes"].append(mode)
            if p_end is not None and p >= p_end:
                break
        elif fired == "compression":
            p_c, W_c = p, float(y[2])
            if e == 0:
                break
            if law == "poisson":
                p_end = (1 + e) * p_c
        elif fired == "end":
            break

    else:
        raise RuntimeError("too many phases")

    P = np.array([y[0], y[1], p])
    u = vel(p, y)
    res.update(P=P, velocity=u, Pn_compression=float(p_c), Pn_final=p, W_n_compression=float(W_c),
               W_n_total=float(y[2]), energy_change=kinetic_energy_change(K, u0, P), sticks=(mode == "stick"))
    if mode == "stick":
        res["velocity"][:2] = 0.0
    else:
        ut = u[:2]
        res["slip_dir_final"] = ut / np.linalg.norm(ut) if np.linalg.norm(ut) > 0 else s_star
    return res
