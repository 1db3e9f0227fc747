"""Independent reference implementations the tests compare the package against.

Nothing here imports beamdrop_jax: each function is its own code path, written from the physics.
"""

import math

import numpy as np


# --------------------------------------------------------------------------------------------------------------
# Darboux-Keller: integrate the contact velocity in the normal impulse, event by event.


def darboux_keller(B, v0, mu, e, law="poisson"):
    """Frictional impact by event-driven integration of dS/dPn, dC/dPn and the normal work in Pn.

    The state is (Pt, Pn, S, C, W) with W = integral of C dPn. In each phase the regime (slide in direction s, or
    stick) is decided from the current state by the Coulomb rule, the state's derivative with respect to Pn is then
    constant, and the phase ends at the nearest event: slip stops (S = 0), maximum compression (C = 0), or the
    law's termination. Returns (Pt, Pn, mode_name).
    """
    B = np.asarray(B, float)
    B1, B2, B3 = B[0, 0], B[1, 1], -B[0, 1]
    Pt, Pn, S, C, W = 0.0, 0.0, float(v0[0]), float(v0[1]), 0.0
    Pn_c = None
    W_c = None
    events = []
    if S == 0.0 and mu * B1 > abs(B3):
        events.append(("stick", True))
    for _ in range(10):
        # Regime from the current state.
        if S != 0.0:
            regime, s = "slide", math.copysign(1.0, S)
        elif mu * B1 >= abs(B3):
            regime, s = "stick", 0.0
        else:
            regime, s = "slide", -math.copysign(1.0, B3) if B3 != 0 else 1.0
        if regime == "stick":
            dPt = B3 / B1
        else:
            dPt = -s * mu
        # (S, C) = (S0, C0) + B (Pt, Pn): the derivatives follow from B and dPt.
        dS = 0.0 if regime == "stick" else B1 * dPt - B3
        dC = -B3 * dPt + B2
        candidates = []
        if regime == "slide" and s * dS < 0 and S != 0.0:
            candidates.append(("stick", -S / dS))
        if Pn_c is None and dC > 0:
            candidates.append(("compression", -C / dC))
        if Pn_c is not None:
            if law == "poisson":
                target = (1.0 + e) * Pn_c - Pn
                candidates.append(("end", max(target, 0.0)))
            elif law == "newton":
                if dC > 0:
                    candidates.append(("end", max((-e * v0[1] - C) / dC, 0.0)))
            elif law == "stronge":
                need = -(e**2) * W_c - (W - W_c)
                # C dp + dC dp^2 / 2 = need, C >= 0 and dC > 0 in restitution.
                if need <= 0:
                    candidates.append(("end", 0.0))
                else:
                    dp = (-C + math.sqrt(C * C + 2.0 * dC * need)) / dC
                    candidates.append(("end", dp))
        name, dp = min(candidates, key=lambda c: c[1])
        Pt += dPt * dp
        Pn += dp
        W += C * dp + 0.5 * dC * dp * dp
        S += dS * dp
        C += dC * dp
        if name == "stick":
            S = 0.0
            events.append(("stick" if mu * B1 >= abs(B3) else "reversal", Pn_c is None))
        elif name == "compression":
            C = 0.0
            Pn_c = Pn
            W_c = W
            if e == 0.0:
                break
        else:
            break
    if not events:
        mode = "SLIDING"
    else:
        kind, before_compression = events[0]
        mode = f"{kind.upper()}_IN_{'COMPRESSION' if before_compression else 'RESTITUTION'}"
    return Pt, Pn, mode


def random_contact(rng):
    """A random physical contact: B from a random body, (S0, C0), mu, e, with S0 = 0 one time in eight."""
    m = rng.uniform(0.1, 3.0)
    k = rng.uniform(0.05, 1.0)
    x = rng.uniform(-1.0, 1.0)
    y = rng.uniform(0.01, 1.0)
    inertia = m * k * k
    B = np.array([[1 / m + y * y / inertia, -x * y / inertia], [-x * y / inertia, 1 / m + x * x / inertia]])
    S0 = 0.0 if rng.random() < 0.125 else rng.uniform(-3.0, 3.0)
    C0 = -rng.uniform(0.1, 3.0)
    mu = rng.uniform(0.0, 2.0)
    e = rng.uniform(0.0, 1.0)
    return B, np.array([S0, C0]), mu, e


# --------------------------------------------------------------------------------------------------------------
# Rigid-body free flight (for clattering and kinematics checks).


def point_velocity(v_G, w, r):
    """Velocity of a rigid-body point at offset r from G: v_G + w z x r."""
    return np.asarray(v_G) + w * np.array([-r[1], r[0]])


# --------------------------------------------------------------------------------------------------------------
# Board: frequencies, modal impulse response, a dense-grid peak.


def beam_frequencies(EI, rhoA, N, L, n):
    """omega_k (rad/s) of a pinned-pinned beam with axial force N, from the textbook formula."""
    k = np.arange(1, n + 1)
    kap = k * np.pi / L
    return np.sqrt((EI * kap**4 + N * kap**2) / rhoA)


def impulse_curvature(dvA, dvB, EI, rhoA, L, n_modes, x, t, times=(0.0,)):
    """Curvature (len(x), len(t)) of an undamped beam after ideal support velocity jumps (see
    `dense_impulse_peak`)."""
    dvA, dvB, times = np.atleast_1d(dvA), np.atleast_1d(dvB), np.atleast_1d(times)
    x, t = np.atleast_1d(x), np.atleast_1d(t)
    xq = np.linspace(0, L, 20001)
    w = beam_frequencies(EI, rhoA, 0.0, L, n_modes)
    curv = np.zeros((x.size, t.size))
    for k in range(1, n_modes + 1):
        shape = np.sin(k * np.pi * xq / L)
        q = np.zeros_like(t)
        for a, b, t0 in zip(dvA, dvB, times):
            rigid = -(a * (1 - xq / L) + b * xq / L)
            beta = np.trapezoid(rigid * shape, xq) / np.trapezoid(shape * shape, xq)
            q += np.where(t >= t0, beta * np.sin(w[k - 1] * (t - t0)) / w[k - 1], 0.0)
        curv -= (k * np.pi / L) ** 2 * np.outer(np.sin(k * np.pi * x / L), q)
    return curv


def dense_impulse_peak(dvA, dvB, EI, rhoA, L, E, h, n_modes, window, nx=801, nt=40001, times=(0.0,)):
    """Peak |stress| of an undamped beam after ideal support velocity jumps, by brute force on a dense grid.

    Each mode is a free oscillation from zero displacement with the modal velocity the jumps leave:
    the Galerkin projection of -(dvA (1 - x/L) + dvB x/L) onto sin(k pi x / L), computed here by quadrature.
    Several jumps (arrays dvA, dvB at `times`) superpose, each starting at its time.
    """
    x = np.linspace(0, L, nx)
    t = np.linspace(0, window, nt)
    curv = impulse_curvature(dvA, dvB, EI, rhoA, L, n_modes, x, t, times)
    i, j = np.unravel_index(np.abs(curv).argmax(), curv.shape)
    return E * h / 2 * abs(curv[i, j]), x[i], t[j]


def duffing_backbone(omega, gamma, amplitude):
    """First-order harmonic balance of q'' + omega^2 q + gamma q^3 = 0: omega_nl^2 = omega^2 + 3/4 gamma A^2."""
    return np.sqrt(omega**2 + 0.75 * gamma * amplitude**2)


# --------------------------------------------------------------------------------------------------------------
# Clattering: rigid-body free flight sampled finely, impact times by bracketing + Brent, impulses by Darboux-Keller.


def clatter_reference(W, H, m, I, theta, v, w, mu, e, n_impacts, g=9.80665, ds=2e-5, horizon=3.0):
    """The first `n_impacts` impacts of a W x H housing (mass m, inertia I about G) whose lowest corner touches
    the ground at angle `theta` with centre-of-mass velocity `v` and spin `w`. Flight is integrated in closed
    form, sampled every `ds` seconds; the first sample with a corner below the ground brackets the impact, which
    `scipy.optimize.brentq` then finds. Returns dicts (t, corner=(q1, q2), Pt, Pn, approach)."""
    from scipy.optimize import brentq

    signs = [(a, b) for a in (-1, 1) for b in (-1, 1)]

    def corner_points(G, th):
        e1 = np.array([math.cos(th), math.sin(th)])
        e2 = np.array([-math.sin(th), math.cos(th)])
        return [G + a * W / 2 * e1 + b * H / 2 * e2 for a, b in signs]

    G = np.zeros(2)
    G[1] = -min(p[1] for p in corner_points(G, theta))
    v = np.asarray(v, float).copy()
    t, out = 0.0, []
    for i in range(n_impacts):
        if i:
            def y_of(s, j):
                return corner_points(G + v * s + np.array([0.0, -0.5 * g * s * s]), theta + w * s)[j][1]

            s_grid = np.arange(1, int(horizon / ds)) * ds
            Gs = G[None] + v[None] * s_grid[:, None]
            Gs[:, 1] -= 0.5 * g * s_grid**2
            ths = theta + w * s_grid
            ys = np.stack([Gs[:, 1] + a * W / 2 * np.sin(ths) + b * H / 2 * np.cos(ths) for a, b in signs], 1)
            below = np.nonzero(ys.min(axis=1) < 0)[0][0]
            j = int(np.argmin(ys[below]))
            s = brentq(lambda s: y_of(s, j), s_grid[below - 1], s_grid[below], xtol=1e-15, rtol=1e-15)
            G = G + v * s + np.array([0.0, -0.5 * g * s * s])
            v = v + np.array([0.0, -g * s])
            theta = theta + w * s
            t += s
        pts = corner_points(G, theta)
        j = int(np.argmin([p[1] for p in pts]))
        rel = pts[j] - G  # S - G
        x, y = -rel  # r = G - S
        B = np.array([[1 / m + y * y / I, -x * y / I], [-x * y / I, 1 / m + x * x / I]])
        vc = v + w * np.array([-rel[1], rel[0]])
        Pt, Pn, _ = darboux_keller(B, vc, mu, e)
        out.append(dict(t=t, corner=(signs[j][0] * W / 2, signs[j][1] * H / 2), Pt=Pt, Pn=Pn, approach=-vc[1]))
        v = v + np.array([Pt, Pn]) / m
        w = w + (rel[0] * Pn - rel[1] * Pt) / I
    return out


# --------------------------------------------------------------------------------------------------------------
# Compliant landing: the rigid housing on hysteretic corner springs with regularised Coulomb friction, integrated
# by SciPy phase by phase, every contact start, turn, release and reload an event.


def compliant_landing_reference(W, H, m, I, theta, v, w, mu, e, tau, v_eps, g=9.80665, t_max=None, rtol=1e-12):
    """The landing of a W x H housing (mass m, inertia I about G) whose lowest corner touches the ground at angle
    `theta` with G moving at `v` and spinning at `w`: each corner below the ground pushes up with a hysteretic
    spring (loading k d; unloading (k / e^2) (d - d_p), d_p = (1 - e^2) d_max; nothing below d_p) of stiffness
    k = m_eff (pi (1 + e) / (2 tau))^2, m_eff = 1 / (1/m + x^2 / I) with x the corner's horizontal lever arm at the
    first touch, and friction -mu N u / sqrt(u^2 + v_eps^2) opposes its horizontal velocity u. Gravity g.

    Each corner is in one of four phases: `free` (no memory), `load` (N = k d), `unload` (on the unloading line),
    `released` (N = 0 but still below the ground: the set d_p = (1 - e^2) d_max relaxes onto the corner,
    d(d_p)/dt = -r (d_p - d), r = 300 / tau, its rate in d_max taken at 1 - e^2 >= 1e-3). Between phase changes the
    equations are smooth and
    `solve_ivp` (DOP853) integrates them; the changes are events: free -> load when the corner reaches the ground;
    load -> unload when its penetration stops growing (d_max = that penetration); unload -> released at d = d_p;
    unload -> load at d = d_max; released -> unload at d = d_p (coming back down); released -> free at the ground.
    The landing ends when no corner is loaded or unloading and every corner below the ground moves up.

    Returns a dict: P (4, 2) per-corner impulses (Pt, Pn) in the corner order (+W/2, +H/2), (-W/2, +H/2),
    (-W/2, -H/2), (+W/2, -H/2); dv_G = sum(P) / m; dw (spin change); t_end; separated; contacts, a list of
    (corner, start, end) times of each force-carrying interval.
    """
    from scipy.integrate import solve_ivp

    q = np.array([[W / 2, H / 2], [-W / 2, H / 2], [-W / 2, -H / 2], [W / 2, -H / 2]])
    v = np.asarray(v, float)

    def rel(th):  # corners from G in the ground frame
        c, s = math.cos(th), math.sin(th)
        return np.stack([q[:, 0] * c - q[:, 1] * s, q[:, 0] * s + q[:, 1] * c], axis=1)

    r0 = rel(theta)
    yG0 = -r0[:, 1].min()
    w1 = math.pi * (1 + e) / (2 * tau)
    k = w1**2 / (1 / m + r0[:, 0] ** 2 / I)
    ku = k / e**2
    # state: X, Y (G's displacement), vx, vy, theta, w, Pt (4), Pn (4)
    # state: X, Y (G's displacement), vx, vy, theta, w, Pt (4), Pn (4), d_max (4)
    y = np.concatenate([[0.0, 0.0, v[0], v[1], theta, w], np.zeros(12)])
    V = math.hypot(math.hypot(v[0], v[1]), w * math.hypot(W, H) / 2)
    L = V * tau
    scale = np.concatenate([[L, L, V, V, L / math.hypot(W, H), V / math.hypot(W, H)], np.full(8, m * V), np.full(4, L)])
    t_max = 10 * tau if t_max is None else t_max

    def kin(y):
        r = rel(y[4])
        d = -(yG0 + y[1] + r[:, 1])
        vel = np.stack([y[2] - y[5] * r[:, 1], y[3] + y[5] * r[:, 0]], axis=1)
        return r, d, -vel[:, 1], vel[:, 0]

    phase = ["free"] * 4
    s_set, r_set = 1 - e**2, 300.0 / tau
    _, d, drate, _ = kin(y)
    for i in range(4):
        if d[i] >= 0 and drate[i] > 0:
            phase[i] = "load"

    def normal(d, dp):  # dp: the sets (1 - e^2) d_max
        N = np.zeros(4)
        for i in range(4):
            if phase[i] == "load":
                N[i] = k[i] * d[i]
            elif phase[i] == "unload":
                N[i] = ku[i] * (d[i] - dp[i])
        return N

    def rhs(t, y):
        r, d, _, u = kin(y)
        dmax = y[14:18]
        N = normal(d, s_set * dmax)
        Ft = -mu * N * u / np.sqrt(u * u + v_eps**2)
        ax, ay = Ft.sum() / m, N.sum() / m - g
        alpha = np.sum(r[:, 0] * N - r[:, 1] * Ft) / I
        ddmax = np.array([-r_set * (s_set * dmax[i] - d[i]) / max(s_set, 1e-3) if phase[i] == "released" else 0.0
                          for i in range(4)])
        return np.concatenate([[y[2], y[3], ax, ay, y[5], alpha], Ft, N, ddmax])

    def events_now():
        """(function, corner, new phase) for every phase change possible from the current phases."""
        out = []

        def make(i, kind, direction):
            def fn(t, y):
                _, d, drate, _ = kin(y)
                dp = s_set * y[14 + i]
                return {"d": d[i], "rate": drate[i], "dp": d[i] - dp, "dmax": d[i] - y[14 + i]}[kind]

            fn.terminal, fn.direction = True, direction
            return fn

        for i in range(4):
            if phase[i] == "free":
                out.append((make(i, "d", 1), i, "load"))
            elif phase[i] == "load":
                out.append((make(i, "rate", -1), i, "unload"))
            elif phase[i] == "unload":
                out.append((make(i, "dp", -1), i, "released"))
                out.append((make(i, "dmax", 1), i, "load"))
            else:
                out.append((make(i, "dp", 1), i, "unload"))
                out.append((make(i, "d", -1), i, "free"))
        return out

    t, contacts, start = 0.0, [], [0.0 if p == "load" else None for p in phase]

    def change(i, new, d, t):
        """Corner i enters phase `new` at time t (penetrations d)."""
        if phase[i] == "load" and new == "unload":
            y[14 + i] = d[i]
        if new == "free":
            y[14 + i] = 0.0
        if new in ("load", "unload") and start[i] is None:
            start[i] = t
        if new in ("released", "free") and start[i] is not None:
            contacts.append((i, start[i], t))
            start[i] = None
        phase[i] = new

    separated = False
    for _ in range(200):
        evs = events_now()
        sol = solve_ivp(rhs, (t, t_max), y, method="DOP853", rtol=rtol, atol=rtol * scale,
                        events=[ev[0] for ev in evs])
        if sol.status != 1:  # reached t_max
            t, y = sol.t[-1], sol.y[:, -1]
            break
        hits = [(sol.t_events[j][0], j) for j in range(len(evs)) if len(sol.t_events[j])]
        t_ev, j = min(hits)
        t, y = t_ev, sol.y_events[j][0].copy()
        _, d, drate, _ = kin(y)
        change(evs[j][1], evs[j][2], d, t)
        # Other corners whose change falls at the same instant (a flat landing's two corners, to round-off): an
        # event function that starts at zero would not be seen to cross it.
        tol_d, tol_v = 1e-9 * L, 1e-9 * V
        for i in range(4):
            dp = s_set * y[14 + i]
            if phase[i] == "load" and drate[i] <= tol_v:
                change(i, "unload", d, t)
            elif phase[i] == "unload" and d[i] - dp <= tol_d and drate[i] < 0:
                change(i, "released", d, t)
            elif phase[i] == "released" and d[i] <= tol_d and drate[i] < 0:
                change(i, "free", d, t)
            elif phase[i] == "free" and d[i] >= -tol_d and drate[i] > 0:
                change(i, "load", d, t)
        if all(p in ("free", "released") for p in phase) and all(d[i] < 0 or drate[i] < 0 for i in range(4)):
            separated = True
            break
    P = np.stack([y[6:10], y[10:14]], axis=1)
    return dict(P=P, dv_G=P.sum(axis=0) / m, dw=y[5] - w, t_end=t, separated=separated, contacts=contacts)
