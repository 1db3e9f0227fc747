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
