"""Checks of the 3D frictional-impact reference (tests/reference_impact3d.py) against closed forms.

Only NumPy/SciPy and the reference itself: these tests vouch for the reference, so that tests of the package can
lean on it. Notation: K the inverse inertia at the contact in (t1, t2, n), u = u0 + K P, p = P_n.
"""

import math

import numpy as np
import pytest

from reference_impact3d import event_driven_impulse, invariant_directions, kinetic_energy_change

LAWS = ("poisson", "stronge")


def random_spd(rng, jitter=0.1):
    A = rng.normal(size=(3, 3))
    return A @ A.T + jitter * np.eye(3)


def piecewise_linear_end(u0n, a1, a2, p_s, e, law):
    """(p_c, p_f) when u_n(p) is piecewise linear: slope a1 up to p_s, slope a2 after (a1, a2 > 0 where used).

    u_n(p) = u0n + a1 p (p <= p_s), u_n(p_s) + a2 (p - p_s) after; W(p) = int_0^p u_n.
    p_c: the zero of u_n. Poisson: p_f = (1 + e) p_c. Stronge: the root p > p_c of W(p) = (1 - e^2) W(p_c), a
    quadratic on whichever segment it falls (W increases after p_c since u_n > 0 there).
    """
    uns = u0n + a1 * p_s if math.isfinite(p_s) else math.inf

    def W(p):
        if p <= p_s:
            return u0n * p + 0.5 * a1 * p * p
        x = p - p_s
        return W(p_s) + uns * x + 0.5 * a2 * x * x

    p_c = -u0n / a1 if uns >= 0 else p_s - uns / a2
    if law == "poisson" or e == 0:
        return p_c, (1 + e) * p_c
    target = (1 - e * e) * W(p_c)
    if p_c < p_s:  # a1/2 p^2 + u0n p - target = 0, larger root
        p = (-u0n + math.sqrt(max(u0n * u0n + 2 * a1 * target, 0.0))) / a1
        if p <= p_s:
            return p_c, p
    c = W(p_s) - target  # a2/2 x^2 + uns x + c = 0, x = p - p_s, larger root
    x = (-uns + math.sqrt(max(uns * uns - 2 * a2 * c, 0.0))) / a2
    return p_c, p_s + x


# --------------------------------------------------------------------------------------------------------------
def test_no_impact_when_separating():
    K = random_spd(np.random.default_rng(0))
    for u0 in ([0.3, -0.2, 0.0], [0.3, -0.2, 1.0]):
        r = event_driven_impulse(K, u0, 0.5, 0.5)
        assert np.all(r["P"] == 0) and np.array_equal(r["velocity"], u0)


# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", LAWS)
def test_frictionless(law):
    """(a) mu = 0: the tangential impulse is 0, u_n has slope K_nn, P_n = (1 + e)(-u0_n)/K_nn (both laws: with a
    constant slope W_n is a parabola symmetric about p_c, so the energetic end is (1 + e) p_c too)."""
    rng = np.random.default_rng(1)
    worst = 0.0
    for i in range(10):
        K = random_spd(rng)
        u0 = rng.normal(size=3)
        u0[2] = -abs(u0[2]) - 0.1
        if i % 3 == 0:
            u0[:2] = 0.0  # from rest: cannot stick (K_tn != 0), slides frictionlessly along K_tn
        for e in (0.0, 0.4, 1.0):
            r = event_driven_impulse(K, u0, 0.0, e, law)
            expect = np.array([0.0, 0.0, (1 + e) * (-u0[2]) / K[2, 2]])
            err = np.abs(r["P"] - expect).max() / expect[2]
            worst = max(worst, err)
            assert err < 1e-12, (r["P"], expect)
            assert abs(r["velocity"][2] + e * u0[2]) < 1e-12 * abs(u0[2])
    print(f"frictionless {law}: worst relative error {worst:.1e}")


# --------------------------------------------------------------------------------------------------------------
KP = np.array([[2.5, 0.0, 1.5], [0.0, 2.0, 0.0], [1.5, 0.0, 2.5]])  # planar: t2 decoupled, B = [[2.5,1.5],[1.5,2.5]]


@pytest.mark.parametrize(
    "name, u0t, mu, law, expect",
    [
        ("slide+", 2.0, 0.8, "poisson", (-0.8 * 1.5 / 1.3, 1.5 / 1.3)),
        ("slide+", 2.0, 0.8, "stronge", (-0.8 * 1.5 / 1.3, 1.5 / 1.3)),
        ("slide-", -2.0, 0.8, "poisson", (0.8 * 1.5 / 3.7, 1.5 / 3.7)),
        ("slide-", -2.0, 0.8, "stronge", (0.8 * 1.5 / 3.7, 1.5 / 3.7)),
        ("stick", 0.2, 0.8, "poisson", (-0.71, 1.05)),
        ("stick", 0.2, 0.8, "stronge", (-(0.2 + 1.5 * (0.7 + math.sqrt(0.115))) / 2.5, 0.7 + math.sqrt(0.115))),
        ("reverse", -0.45, 0.3, "poisson", (-0.06, 0.6)),
        ("reverse", -0.45, 0.3, "stronge",
         (0.3 * 0.2 - 0.3 * (0.2 + math.sqrt(0.091 / 2.05)), 0.4 + math.sqrt(0.091 / 2.05))),
    ],
)
def test_planar_routh_by_hand(name, u0t, mu, law, expect):
    """(b) Planar Routh cases worked by hand. B = [[B_tt, B_tn], [B_tn, B_nn]] = [[2.5, 1.5], [1.5, 2.5]] (t2
    decoupled, K_22 = 2, u0_t2 = 0), u0_n = -1, e = 0.5. sigma = sign(u0_t).

    Sliding: P_t = -mu sigma p, u_t = u0_t + (B_tn - mu sigma B_tt) p, u_n = -1 + a1 p with a1 = B_nn - mu sigma B_tn.
    Stick ratio |B_tn|/B_tt = 0.6; stuck slope a2 = B_nn - B_tn^2/B_tt = 2.5 - 0.9 = 1.6.

    slide+ (u0_t = 2, mu = 0.8): a1 = 2.5 - 1.2 = 1.3, p_c = 1/1.3, p_f = 1.5/1.3 = 1.1538; slip would stop at
      p = 2/(2.0 - 1.5) = 4 > p_f, so sliding throughout: P = (-0.8 p_f, 0, p_f). Constant slope => Stronge = Poisson.
    slide- (u0_t = -2, mu = 0.8): a1 = 2.5 + 1.2 = 3.7, p_c = 1/3.7, p_f = 1.5/3.7 = 0.4054 < stop at
      2/(2.0 + 1.5) = 0.5714: P = (+0.8 p_f, 0, p_f).
    stick (u0_t = 0.2, mu = 0.8 >= 0.6): slip stops at p_s = 0.2/(2.0 - 1.5) = 0.4 with u_n(p_s) = -1 + 1.3*0.4 = -0.48;
      stuck from then on: p_c = 0.4 + 0.48/1.6 = 0.7.
      Poisson: p_f = 1.5*0.7 = 1.05, P_t = -(u0_t + B_tn p_f)/B_tt = -(0.2 + 1.575)/2.5 = -0.71.
      Stronge: W_c = u0_n p_s + a1 p_s^2/2 - u_n(p_s)^2/(2 a2) = -0.4 + 0.104 - 0.072 = -0.368; restitution stuck,
      a2 (p_f - p_c)^2/2 = e^2 |W_c| => p_f = 0.7 + sqrt(2*0.25*0.368/1.6) = 0.7 + sqrt(0.115) = 1.03912,
      P_t = -(0.2 + 1.5 p_f)/2.5.
    reverse (u0_t = -0.45, mu = 0.3 < 0.6): a1 = 2.5 + 0.45 = 2.95, slip stops at p_s = 0.45/(0.75 + 1.5) = 0.2 with
      u_n(p_s) = -1 + 0.59 = -0.41; it cannot stick and resumes along s* = sign(B_tn) = +1 (lambda = -mu B_tt + B_tn
      = 0.75 > 0) with slope a3 = 2.5 - 0.45 = 2.05: p_c = 0.2 + 0.41/2.05 = 0.4.
      Poisson: p_f = 0.6, P_t = +0.3*0.2 - 0.3*(0.6 - 0.2) = -0.06.
      Stronge: W_c = u0_n p_s + a1 p_s^2/2 - u_n(p_s)^2/(2 a3) = -0.2 + 0.059 - 0.041 = -0.182; restitution slides
      along s* with slope a3: a3 (p_f - p_c)^2/2 = e^2 |W_c| => p_f = 0.4 + sqrt(2*0.25*0.182/2.05) = 0.4 + sqrt(0.091/2.05) = 0.61069,
      P_t = +0.3*0.2 - 0.3*(p_f - 0.2).
    """
    r = event_driven_impulse(KP, np.array([u0t, 0.0, -1.0]), mu, 0.5, law)
    P = r["P"]
    err = max(abs(P[0] - expect[0]), abs(P[2] - expect[1]))
    print(f"planar {name} {law}: P = {P}, expected ({expect[0]:.12g}, 0, {expect[1]:.12g}), error {err:.1e}")
    assert err < 1e-11
    assert P[1] == 0.0
    assert r["sticks"] == (name == "stick")
    if name == "reverse":
        assert np.allclose(r["invariant_direction"], [1.0, 0.0]) and abs(r["invariant_lambda"] - 0.75) < 1e-12
        assert abs(r["Pn_stick"] - 0.2) < 1e-11 and r["modes"] == ["slip", "islip"]
    if name == "stick":
        assert abs(r["Pn_stick"] - 0.4) < 1e-11 and abs(r["Pn_compression"] - 0.7) < 1e-11
    if name.startswith("slide"):
        assert r["Pn_stick"] == math.inf


def planar_closed_form(Btt, Btn, Bnn, u0t, u0n, mu, e, law):
    """Planar Routh closed form for any case (slide throughout / stop then stick / stop then reverse)."""
    sig = math.copysign(1.0, u0t)
    decel = mu * Btt - sig * Btn  # -d|u_t|/dp while sliding
    p_s = abs(u0t) / decel if decel > 0 else math.inf
    a1 = Bnn - mu * sig * Btn
    if abs(Btn) <= mu * Btt:
        after = "stick"
        a2 = Bnn - Btn * Btn / Btt
    else:
        after = "reverse"
        s_star = math.copysign(1.0, Btn)
        a2 = Bnn - mu * s_star * Btn
    p_c, p_f = piecewise_linear_end(u0n, a1, a2, p_s, e, law)
    if p_f <= p_s:
        Pt = -mu * sig * p_f
    elif after == "stick":
        Pt = -(u0t + Btn * p_f) / Btt
    else:
        Pt = -mu * sig * p_s - mu * s_star * (p_f - p_s)
    return np.array([Pt, 0.0, p_f]), p_c, p_s


@pytest.mark.parametrize("law", LAWS)
def test_planar_random_against_closed_form(law):
    """(b, more) Random planar contacts (t2 decoupled) against planar_closed_form."""
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(25):
        B = random_spd(rng)[:2, :2]
        K = np.array([[B[0, 0], 0.0, B[0, 1]], [0.0, 1.0 + rng.uniform(), 0.0], [B[0, 1], 0.0, B[1, 1]]])
        u0t, u0n = rng.normal(), -0.1 - abs(rng.normal())
        mu, e = rng.uniform(0.05, 1.2), rng.uniform(0, 1)
        expect, p_c, p_s = planar_closed_form(B[0, 0], B[0, 1], B[1, 1], u0t, u0n, mu, e, law)
        r = event_driven_impulse(K, np.array([u0t, 0.0, u0n]), mu, e, law)
        err = np.abs(r["P"] - expect).max() / expect[2]
        worst = max(worst, err)
        assert err < 1e-10, (r["P"], expect, r["modes"])
        assert abs(r["Pn_compression"] - p_c) < 1e-10 * p_c
    print(f"planar random {law}: worst relative error {worst:.1e}")


# --------------------------------------------------------------------------------------------------------------
K3 = np.array([[3.0, 0.9, 1.2], [0.9, 2.0, -0.7], [1.2, -0.7, 2.5]])  # couples t1, t2 and n


def _dense_resume_directions(K, mu, n=50_000):
    """Independent brute force: sign changes of s x (-mu K_tt s + K_tn) on a dense angle grid, lambda > 0."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    S = np.stack([np.cos(a), np.sin(a)])
    F = -mu * (K[:2, :2] @ S) + K[:2, 2:3]
    g = S[0] * F[1] - S[1] * F[0]
    lam = (S * F).sum(0)
    idx = np.nonzero(np.sign(g) != np.sign(np.roll(g, -1)))[0]
    return [S[:, i] for i in idx if lam[i] > 0]


def test_invariant_direction_unique_and_exists_iff_no_stick():
    """With lambda > 0 there is exactly one invariant direction when sticking fails, none when it holds."""
    rng = np.random.default_rng(3)
    for i in range(30):
        K = K3 if i == 0 else random_spd(rng)
        mu = rng.uniform(0.05, 1.5)
        need = np.linalg.norm(np.linalg.solve(K[:2, :2], K[:2, 2]))
        pos = [(s, lam) for s, lam in invariant_directions(K, mu) if lam > 0]
        brute = _dense_resume_directions(K, mu)
        assert len(pos) == (0 if need <= mu else 1) == len(brute)
        if pos:
            s, lam = pos[0]
            assert np.linalg.norm(-mu * K[:2, :2] @ s + K[:2, 2] - lam * s) < 1e-12 * (1 + lam)
            assert np.linalg.norm(s - brute[0]) < 4 * np.pi / 50_000  # two grid spacings


@pytest.mark.parametrize("law", LAWS)
def test_3d_from_rest_closed_form(law):
    """u0_t = 0. Stick possible (mu >= |K_tt^-1 K_tn| = 0.846 for K3): P_t = -K_tt^-1 K_tn p, slope
    K_eff = K_nn - K_nt K_tt^-1 K_tn, P_n = (1 + e)(-u0_n)/K_eff. Otherwise slip along the invariant s*:
    P_t = -mu s* p, slope K_nn - mu K_nt s*, P_n = (1 + e)(-u0_n)/slope (constant slopes: Stronge = Poisson)."""
    u0 = np.array([0.0, 0.0, -1.3])
    e = 0.6
    for mu in (1.0, 0.5):
        r = event_driven_impulse(K3, u0, mu, e, law)
        rate = -np.linalg.solve(K3[:2, :2], K3[:2, 2])
        if mu >= np.linalg.norm(rate):
            slope = K3[2, 2] + K3[2, :2] @ rate
            assert r["sticks"] and r["invariant_direction"] is None
        else:
            (s, lam), = [(s, lam) for s, lam in invariant_directions(K3, mu) if lam > 0]
            rate = -mu * s
            slope = K3[2, 2] + K3[2, :2] @ rate
            assert not r["sticks"] and np.allclose(r["invariant_direction"], s, atol=1e-12)
            assert np.allclose(r["slip_dir_final"], s, atol=1e-12)
        pf = (1 + e) * 1.3 / slope
        expect = np.r_[rate * pf, pf]
        err = np.abs(r["P"] - expect).max() / pf
        print(f"3D from rest mu={mu} {law}: sticks={r['sticks']} P={r['P']} error {err:.1e}")
        assert err < 1e-12 and r["Pn_stick"] == 0.0


@pytest.mark.parametrize("law", LAWS)
def test_3d_straight_slip_then_stop_closed_form(law):
    """u0_t along an invariant direction s_a with lambda_a < 0 (slip decelerating along a fixed line): u_t stays
    on the line, u_t = (c + lambda_a p) s_a, P_t = -mu s_a p, slope a1 = K_nn - mu K_nt s_a, slip stops at
    p_s = c/|lambda_a|; then either stick (mu = 1.0 for K3) or slip along s* (mu = 0.5) with its own constant slope.
    u_n is piecewise linear: piecewise_linear_end gives p_c, p_f for both laws. The slip direction jumps at the stop
    from s_a to s* (a 3D turn that is still closed-form)."""
    for mu in (0.5, 1.0):
        dirs = invariant_directions(K3, mu)
        sa, la = dirs[-1]
        assert la < 0
        for c, e in ((0.3, 0.7), (1.0, 0.7), (1.0, 0.0), (3.0, 1.0)):
            u0 = np.r_[c * sa, -1.0]
            p_s = c / -la
            a1 = K3[2, 2] - mu * K3[2, :2] @ sa
            rate_stick = -np.linalg.solve(K3[:2, :2], K3[:2, 2])
            stick = mu >= np.linalg.norm(rate_stick)
            if stick:
                a2 = K3[2, 2] + K3[2, :2] @ rate_stick
            else:
                (s_star, _), = [d for d in dirs if d[1] > 0]
                a2 = K3[2, 2] - mu * K3[2, :2] @ s_star
            p_c, p_f = piecewise_linear_end(-1.0, a1, a2, p_s, e, law)
            if p_f <= p_s:
                Pt = -mu * sa * p_f
            elif stick:
                Pt = -np.linalg.solve(K3[:2, :2], u0[:2] + K3[:2, 2] * p_f)
            else:
                Pt = -mu * sa * p_s - mu * s_star * (p_f - p_s)
            r = event_driven_impulse(K3, u0, mu, e, law)
            err = np.abs(r["P"] - np.r_[Pt, p_f]).max() / p_f
            print(f"3D straight mu={mu} c={c} e={e} {law}: modes={r['modes']} error {err:.1e}")
            assert err < 1e-9, (r["P"], np.r_[Pt, p_f], r["modes"])
            assert abs(r["Pn_compression"] - p_c) < 1e-9 * p_c
            if p_s < p_f:
                assert abs(r["Pn_stick"] - p_s) < 1e-9 * p_s and r["sticks"] == stick


# --------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("law", LAWS)
def test_energy_and_friction_cone_random(law):
    """(c) 50 random 3D contacts: kinetic energy never increases, |P_t| <= mu P_n (1 + 1e-9), the end conditions
    hold (Poisson P_n = (1 + e) p_c; Stronge W_n(p_f) - W_n(p_c) = -e^2 W_n(p_c)), u = u0 + K P."""
    rng = np.random.default_rng(4)
    worst_gain, n_modes = -math.inf, {}
    for _ in range(50):
        K = random_spd(rng)
        u0 = rng.normal(size=3)
        u0[2] = -abs(u0[2]) - 0.05
        u0[:2] *= rng.choice([1.0, 0.1])  # small slips stop early: more stick and resumed-slip cases
        mu, e = rng.uniform(0, 1.5), rng.uniform(0, 1)
        r = event_driven_impulse(K, u0, mu, e, law)
        P = r["P"]
        T0 = 0.5 * u0 @ np.linalg.solve(K, u0)
        dT = kinetic_energy_change(K, u0, P)
        worst_gain = max(worst_gain, dT / T0)
        assert dT <= 1e-12 * T0, (dT, r["modes"])
        assert np.linalg.norm(P[:2]) <= mu * P[2] * (1 + 1e-9) + 1e-300
        u = u0 + K @ P
        assert np.allclose(r["velocity"], u, rtol=0, atol=1e-12 * np.linalg.norm(u0))
        assert u[2] >= -1e-12 * abs(u0[2])  # separating (or resting at e = 0)
        if law == "poisson":
            assert abs(P[2] - (1 + e) * r["Pn_compression"]) < 1e-12 * P[2]
        else:
            Wc = r["W_n_compression"]
            assert abs((r["W_n_total"] - Wc) + e * e * Wc) < 1e-10 * abs(Wc)
        n_modes[tuple(r["modes"])] = n_modes.get(tuple(r["modes"]), 0) + 1
    print(f"random {law}: largest dT/T0 {worst_gain:.2e}; regimes {n_modes}")


def _rk4_sliding(K, u0, mu, p_end, n=4000):
    """Independent fixed-step RK4 of dP_t/dp = -mu u_t/|u_t| (valid while slip never stops)."""
    def f(p, Pt):
        ut = u0[:2] + K[:2, :2] @ Pt + K[:2, 2] * p
        return -mu * ut / np.linalg.norm(ut)
    h, Pt, p = p_end / n, np.zeros(2), 0.0
    for _ in range(n):
        k1 = f(p, Pt)
        k2 = f(p + h / 2, Pt + h / 2 * k1)
        k3 = f(p + h / 2, Pt + h / 2 * k2)
        k4 = f(p + h, Pt + h * k3)
        Pt, p = Pt + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), p + h
    return Pt


def test_3d_slip_direction_turns():
    """(d) K3 couples t1, t2 and n; u0_t = (0, 0.5) points at 90 deg. Slip never stops but its direction turns
    towards the invariant direction s* of mu = 0.5 (-42.3 deg). Checked: P_t against an independent fixed-step RK4
    of the same ODE up to the reference's P_n, the friction cone, and a turn of more than 90 degrees."""
    mu, e = 0.5, 0.6
    u0 = np.array([0.0, 0.5, -1.0])
    r = event_driven_impulse(K3, u0, mu, e, "poisson")
    s0, s1 = r["slip_dir_initial"], r["slip_dir_final"]
    a0, a1 = (math.degrees(math.atan2(s[1], s[0])) for s in (s0, s1))
    (s_star, _), = [d for d in invariant_directions(K3, mu) if d[1] > 0]
    print(f"3D turn: slip direction {s0} ({a0:.2f} deg) -> {s1} ({a1:.2f} deg); "
          f"s* = {s_star} ({math.degrees(math.atan2(s_star[1], s_star[0])):.2f} deg); P = {r['P']}")
    assert r["Pn_stick"] == math.inf and r["modes"] == ["slip"]
    turn = math.degrees(math.acos(np.clip(s0 @ s1, -1, 1)))
    assert turn > 90
    Pt = _rk4_sliding(K3, u0, mu, r["P"][2])
    assert np.abs(Pt - r["P"][:2]).max() < 1e-10 * r["P"][2], (Pt, r["P"])
    # the slip direction along the way really is u_t/|u_t| at the end
    ut = (u0 + K3 @ r["P"])[:2]
    assert np.allclose(ut / np.linalg.norm(ut), s1, atol=1e-14)
