"""Peers the benchmark measures the package against, written without JAX: a NumPy vectorised closed form (single
drops, pulse trains, the superposition table's lookup) and SciPy's `solve_ivp` on the modal equations. Independent
code paths on the same physics (DESIGN.md sections 1-3), so their agreement checks the package as well as timing it.
"""

import math

import numpy as np

from .._common.checks import GRAVITY
from .._scene.containers import Scene


def numpy_support_jumps(scene: Scene, orientations):
    """Support jumps (dvA, dvB) (m/s) of drops of `scene` at `orientations` (rad), vectorised in NumPy (Poisson
    impact)."""
    f = lambda v: float(np.asarray(v))  # noqa: E731
    hs, bd_, pl, dr, ct = scene.housing, scene.board, scene.placement, scene.drop, scene.contact
    W, H, m, k = f(hs.width), f(hs.height), f(hs.mass), f(hs.radius_of_gyration)
    inertia = m * k * k
    th = np.asarray(orientations, float)
    s, c = np.sin(th), np.cos(th)
    a = np.where(s > 0, -1.0, 1.0) * W / 2
    b = np.where(c > 0, -1.0, 1.0) * H / 2
    x = -(a * c - b * s)
    y = -(a * s + b * c)
    B1, B2, B3 = 1 / m + y * y / inertia, 1 / m + x * x / inertia, x * y / inertia
    S0 = f(dr.horizontal_speed) + f(dr.spin) * y
    C0 = -math.sqrt(2 * GRAVITY * f(dr.height)) - f(dr.spin) * x
    mu, e = f(ct.friction), f(ct.restitution)
    sgn = np.where(S0 > 0, 1.0, np.where(S0 < 0, -1.0, -np.where(B3 >= 0, 1.0, -1.0)))
    slowing = mu * B1 + sgn * B3
    with np.errstate(divide="ignore", invalid="ignore"):
        stick = slowing > 0
        Pn_s = np.where(stick, np.abs(S0) / np.where(stick, slowing, 1.0), np.inf)
        stays = mu * B1 >= np.abs(B3)
        dC1 = B2 + sgn * mu * B3
        dC2 = np.where(stays, (B1 * B2 - B3**2) / B1, B2 - sgn * mu * B3)
        first = (dC1 > 0) & (~stick | (-C0 <= dC1 * np.where(stick, Pn_s, 0.0)))
        C_s = C0 + dC1 * np.where(stick, Pn_s, 0.0)
        Pn_c = np.where(first, -C0 / np.where(first, dC1, 1.0), np.where(stick, Pn_s, 0.0) - C_s / dC2)
    Pn = (1 + e) * Pn_c
    dPt2 = np.where(stays, B3 / B1, sgn * mu)
    Pt = -sgn * mu * np.minimum(Pn, Pn_s) + np.where(stick, dPt2 * np.maximum(Pn - Pn_s, 0.0), 0.0)
    dvG = np.stack([Pt, Pn], -1) / m
    dw = (y * Pt - x * Pn) / inertia
    L, phi = f(bd_.length), f(pl.angle)
    cen = np.asarray(pl.centre, float)
    ends = np.stack([cen - L / 2 * np.array([math.cos(phi), math.sin(phi)]),
                     cen + L / 2 * np.array([math.cos(phi), math.sin(phi)])])
    e1 = np.stack([c, s], -1)
    e2 = np.stack([-s, c], -1)
    t_g = math.cos(phi) * e1 + math.sin(phi) * e2
    n_g = np.stack([-t_g[:, 1], t_g[:, 0]], -1)
    jumps = []
    for q in ends:
        rq = q[0] * e1 + q[1] * e2
        dv = dvG + dw[:, None] * np.stack([-rq[:, 1], rq[:, 0]], -1)
        jumps.append(np.sum(dv * n_g, -1))
    return jumps[0], jumps[1]


def numpy_peak_stress(scene: Scene, orientations, n_modes=6, nx=None, nt=None, durations=None):
    """Peak stress (Pa) of drops of `scene` at `orientations` (rad), vectorised in NumPy: same physics and grid
    rule as the JAX closed form, without the Newton refinement (grid maximum). `durations` (s, > 0; one per drop)
    give each drop its own half-sine and window (default: the scene's contact duration for every drop)."""
    f = lambda v: float(np.asarray(v))  # noqa: E731
    bd_, ct = scene.board, scene.contact
    L = f(bd_.length)
    dvA, dvB = numpy_support_jumps(scene, orientations)
    th = np.asarray(orientations, float)
    EI = f(bd_.youngs_modulus) * f(bd_.width) * f(bd_.thickness) ** 3 / 12
    rhoA = f(bd_.density) * f(bd_.width) * f(bd_.thickness)
    kk = np.arange(1, n_modes + 1)
    kap = kk * math.pi / L
    omega = np.sqrt((EI * kap**4 + f(bd_.axial_force) * kap**2) / rhoA)
    zeta = f(bd_.damping_ratio)
    # One time grid for every drop when they share the duration; otherwise one per drop (a leading drop axis).
    tau = np.asarray(f(ct.duration) if durations is None else np.asarray(durations, float)[:, None, None])
    beta = -(2 / (kk * math.pi)) * (dvA[:, None] - (-1.0) ** kk * dvB[:, None])
    nx = nx or 4 * n_modes + 1
    nt = nt or 4 * (n_modes**2 + 8) + 1
    tt = (tau + 2 * math.pi / omega[0]) * np.linspace(0, 1, nt)[:, None]  # the pulse and one period
    R = _numpy_unit_response(tt, omega, zeta, tau)
    xs = np.linspace(0, L, nx)
    shapes = np.sin(np.outer(xs, kap)) * -(kap**2)
    curv = np.einsum("xk,tk,nk->nxt" if R.ndim == 2 else "xk,ntk,nk->nxt", shapes, R, beta, optimize=True)
    return f(bd_.youngs_modulus) * f(bd_.thickness) / 2 * np.abs(curv).reshape(len(th), -1).max(-1)


def _numpy_unit_response(tt, omega, zeta, tau):
    """Modal response to a unit half-sine of duration `tau` (all > 0) or ideal impulse (all 0) at times `tt` >= 0,
    in NumPy: the textbook partial fractions (singular at resonance, which random drops never hit exactly)."""
    wd = omega * math.sqrt(1 - zeta**2)
    lam = -zeta * omega + 1j * wd
    if np.all(tau > 0):
        T = np.minimum(tt, tau)
        Om = math.pi / tau
        rest = np.exp(lam * (tt - T))
        elt = np.exp(lam * tt)
        with np.errstate(divide="ignore", invalid="ignore"):
            p1 = (rest * np.exp(1j * Om * T) - elt) / (1j * Om - lam)
            p2 = (rest * np.exp(-1j * Om * T) - elt) / (-1j * Om - lam)
        return Om / 2 * np.imag((p1 - p2) / 2j) / wd
    if np.all(tau == 0):
        return np.exp(-zeta * omega * tt) * np.sin(wd * tt) / wd
    raise ValueError("durations: all > 0 (half-sines) or all 0 (ideal impulses)")


def numpy_train_peak_stress(scene: Scene, times, jumps, n_modes, nx=None, nt=None):
    """Peak stress (Pa) of clattering drops of `scene` given their impacts (`times` (n, K) s and support `jumps`
    (n, K, 2) m/s, e.g. from `bd.impact_sequence`), in NumPy: each pulse's shifted response summed on a grid of nt
    points after each impact (the JAX search's windows), grid maximum. A peer for the board's response alone."""
    f = lambda v: float(np.asarray(v))  # noqa: E731
    board, tau = scene.board, f(scene.contact.duration)
    L, E, h = f(board.length), f(board.youngs_modulus), f(board.thickness)
    EI = E * f(board.width) * h**3 / 12
    rhoA = f(board.density) * f(board.width) * h
    kk = np.arange(1, n_modes + 1)
    kap = kk * math.pi / L
    omega = np.sqrt((EI * kap**4 + f(board.axial_force) * kap**2) / rhoA)
    times, jumps = np.asarray(times, float), np.asarray(jumps, float)
    beta = -(2 / (kk * math.pi)) * (jumps[..., :1] - (-1.0) ** kk * jumps[..., 1:])  # (n, K, modes)
    nx = nx or 4 * n_modes + 1
    nt = nt or 4 * (n_modes**2 + 8) + 1
    s = (tau + 2 * math.pi / omega[0]) * np.linspace(0, 1, nt)
    t = (times[:, :, None] + s).reshape(len(times), -1)  # (n, K nt)
    since = t[:, :, None] - times[:, None, :]  # (n, K nt, K)
    R = np.where(since[..., None] >= 0, _numpy_unit_response(np.maximum(since, 0)[..., None], omega,
                                                              f(board.damping_ratio), tau), 0.0)
    q = np.einsum("ntpk,npk->ntk", R, beta)
    shapes = np.sin(np.outer(np.linspace(0, L, nx), kap)) * -(kap**2)
    return E * h / 2 * np.abs(np.einsum("xk,ntk->nxt", shapes, q, optimize=True)).reshape(len(times), -1).max(-1)


def numpy_superposed_peak_stress(scene: Scene, orientations, table):
    """Peak stress (Pa) of drops of `scene` at `orientations` (rad) by the superposition that `bd.montecarlo` uses,
    in NumPy: the impacts vectorised as in `numpy_peak_stress`, then the lookup in `table` (a
    `SuperpositionTable` of the scene, built by beamdrop). A peer for the per-drop work alone: it tells how much
    of the speed-up over `numpy_peak_stress` is the algorithm and how much compiled code."""
    dvA, dvB = numpy_support_jumps(scene, orientations)
    n = table.n_angles
    flip = (dvB < 0) | ((dvB == 0) & (dvA < 0))
    a, b = np.where(flip, -dvA, dvA), np.abs(dvB)
    j = np.clip(np.floor((1.0 - a / (np.abs(a) + b)) * (n / 2)), 0, n - 1).astype(np.intp)
    K = np.asarray(table.curvature[0])  # the one duration
    kappa = np.maximum(np.abs(K[j, 0] * dvA + K[j, 1] * dvB),
                       np.abs(K[(j + 1) % n, 0] * dvA + K[(j + 1) % n, 1] * dvB))
    return float(scene.board.youngs_modulus) * float(scene.board.thickness) / 2 * kappa


# ---------------------------------------------------------------------------------------------------------------
# Peer 2: SciPy solve_ivp per drop on the modal equations (as the thesis's MATLAB ode45 script did).


def scipy_peak_stress(scene: Scene, jumps, method="RK45", n_modes=6, rtol=1e-8, atol=1e-12, nx=None, nt=None):
    """Peak stress of one drop from its support jumps (dvA, dvB) by `scipy.integrate.solve_ivp` (a roll dvR after
    them is ignored: a beam has no width)."""
    from scipy.integrate import solve_ivp

    f = lambda v: float(np.asarray(v))  # noqa: E731
    b = scene.board
    L, E, h = f(b.length), f(b.youngs_modulus), f(b.thickness)
    EI = E * f(b.width) * h**3 / 12
    rhoA = f(b.density) * f(b.width) * h
    kk = np.arange(1, n_modes + 1)
    kap = kk * math.pi / L
    w2 = (EI * kap**4 + f(b.axial_force) * kap**2) / rhoA
    omega = np.sqrt(w2)
    zeta, tau = f(b.damping_ratio), f(scene.contact.duration)
    pA, pB = -2 / (kk * math.pi), 2 * (-1.0) ** kk / (kk * math.pi)
    dvA, dvB = (float(v) for v in np.asarray(jumps)[:2])
    window = tau + 2 * math.pi / omega[0]

    def rhs(t, y):
        g = math.pi / (2 * tau) * math.sin(math.pi * t / tau) if 0 <= t <= tau else 0.0
        q, v = y[:n_modes], y[n_modes:]
        return np.concatenate([v, (pA * dvA + pB * dvB) * g - 2 * zeta * omega * v - w2 * q])

    nx = nx or 4 * n_modes + 1
    nt = nt or 4 * (n_modes**2 + 8) + 1
    t_eval = np.linspace(0, window, nt)
    y0 = np.zeros(2 * n_modes)
    sol1 = solve_ivp(rhs, (0, tau), y0, method=method, rtol=rtol, atol=atol, dense_output=True)
    sol2 = solve_ivp(rhs, (tau, window), sol1.y[:, -1], method=method, rtol=rtol, atol=atol, dense_output=True)
    Q = np.where(t_eval[:, None] <= tau, sol1.sol(np.minimum(t_eval, tau)).T, sol2.sol(np.maximum(t_eval, tau)).T)
    xs = np.linspace(0, L, nx)
    curv = (np.sin(np.outer(xs, kap)) * -(kap**2)) @ Q[:, :n_modes].T
    return E * h / 2 * np.abs(curv).max(), sol1.success and sol2.success
