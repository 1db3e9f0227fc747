"""The board: frequencies, closed form against diffrax, limits, the JESD22-B111 board, peaks, bad input."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import beamdrop_jax as bd
import beamdrop_jax._board.beam  # noqa: F401 - `bd._board...` below, before any call has loaded it
import beamdrop_jax._response.pulses  # noqa: F401
from beamdrop_jax._response.diffrax_path import solve_modes
from references import beam_frequencies, duffing_backbone

G = 9.80665


def thesis_board():
    # L = 1, EI = 1, rho A = 1, N = 1: E b h^3 / 12 = 1 with b = h = 1 gives E = 12; rho b h = 1 gives rho = 1.
    return bd.Board(length=1.0, thickness=1.0, width=1.0, youngs_modulus=12.0, density=1.0, axial_force=1.0)


def jedec_board(**kw):
    return bd.Board(length=0.1, thickness=1e-3, width=0.077, youngs_modulus=24e9, density=1850.0, **kw)


def test_thesis_nondimensional_frequencies():
    omega2 = bd.natural_frequencies(thesis_board(), 4) ** 2
    # k^4 pi^4 + k^2 pi^2; the thesis prints 7929.6 for mode 3 (a transcription slip), 7979.0 is right.
    np.testing.assert_allclose(omega2, [107.3, 1598.0, 7979.0, 25094.6], rtol=5e-4)
    np.testing.assert_allclose(omega2, [k**4 * math.pi**4 + k**2 * math.pi**2 for k in range(1, 5)], rtol=1e-14)


@pytest.mark.parametrize("N", [-50.0, 0.0, 120.0])
def test_frequencies_with_axial_force(N):
    board = bd.Board(axial_force=N)
    EI = 22e9 * 0.05 * 1e-9 / 12
    rhoA = 1900 * 0.05 * 1e-3
    np.testing.assert_allclose(bd.natural_frequencies(board, 10), beam_frequencies(EI, rhoA, N, 0.1, 10), rtol=1e-13)


TIGHT = dict(method="diffrax", solver="Dopri8", rtol=1e-11, atol=1e-15, max_steps=200000)


@pytest.mark.parametrize("zeta", [0.0, 0.03])
@pytest.mark.parametrize("duration", [0.0, 5e-4, 2e-3])
def test_closed_form_equals_diffrax(zeta, duration):
    board = bd.Board(damping_ratio=zeta, axial_force=5.0)
    motion = bd.HalfSine(3.0, -1.2, duration)
    closed = bd.board_response(board, motion, bd.Numerics(n_modes=6))
    numeric = bd.board_response(board, motion, bd.Numerics(n_modes=6, **TIGHT))
    assert int(numeric.flags) == 0
    for field in ("stress", "strain", "deflection"):
        a, b = getattr(closed.peak, field), getattr(numeric.peak, field)
        np.testing.assert_allclose(b, a, rtol=1e-6, err_msg=field)
    np.testing.assert_allclose(numeric.peak.x, closed.peak.x, rtol=1e-4)
    np.testing.assert_allclose(numeric.peak.t, closed.peak.t, rtol=1e-4)


def test_closed_form_modal_history_equals_diffrax():
    board = bd.Board(damping_ratio=0.02)
    motion = bd.HalfSine(2.0, 0.5, 4e-4)
    M = 5
    omega = bd.natural_frequencies(board, M)
    beta = bd._board.base.modal_velocity_jumps(bd.Board(), jnp.array([2.0, 0.5]), M)
    modes, failed = solve_modes(board, motion, M, jnp.asarray(0.01), jnp.ones(M), solver="Dopri8", rtol=1e-12, atol=1e-16)
    assert not bool(failed)
    for t in np.linspace(0.0, 0.01, 23):
        closed = beta * bd.unit_response(t, omega, 0.02, 4e-4)
        np.testing.assert_allclose(modes(t), closed, rtol=1e-7, atol=1e-10 * float(jnp.abs(closed).max() + 1e-12))


def _duhamel(t, omega, zeta, tau, order):
    """d^order/dt^order of the unit response by quadrature of the Duhamel integral (h(0) = 0, h'(0) = 1)."""
    from scipy.integrate import quad

    wd = omega * math.sqrt(1.0 - zeta**2)

    def h(u):  # impulse response and its first two derivatives
        e, s, c = math.exp(-zeta * omega * u), math.sin(wd * u), math.cos(wd * u)
        return (e * s / wd, e * (c - zeta * omega * s / wd),
                e * ((zeta * omega) ** 2 * s / wd - 2 * zeta * omega * c - wd * s))[order]

    def a(s):
        return math.pi / (2 * tau) * math.sin(math.pi * s / tau) if s <= tau else 0.0

    T = min(t, tau)
    value = quad(lambda s: h(t - s) * a(s), 0.0, T, limit=500, epsabs=0.0, epsrel=1e-13)[0]
    return value + (a(t) if order == 2 else 0.0)


@settings(max_examples=60, deadline=None)
@given(
    log_tau=st.floats(-5.0, -2.0),
    ratio=st.one_of(st.just(1.0), st.floats(0.999, 1.001), st.floats(0.01, 100.0)),
    zeta=st.one_of(st.just(0.0), st.floats(1e-4, 0.3)),
    phase=st.floats(0.0, 3.0),
)
def test_unit_response_and_its_jet_equal_the_duhamel_integral(log_tau, ratio, zeta, phase):
    # omega = ratio * pi / tau: ratio 1 is exact resonance of an undamped mode with the pulse, where the closed
    # form switches to its series; the quadrature knows nothing of that.
    tau = 10.0**log_tau
    omega = ratio * math.pi / tau
    t = phase * tau
    got = bd._response.pulses.unit_response_jet(jnp.asarray(t), omega, zeta, tau) if t > 0 else None
    scale = (1 / omega, 1.0, omega)  # the size of q, q', q'' after a unit velocity change
    value = float(bd.unit_response(t, omega, zeta, tau))
    assert abs(value - _duhamel(t, omega, zeta, tau, 0)) <= 1e-9 * scale[0]
    if got is not None:
        for order in range(3):
            assert abs(float(got[order]) - _duhamel(t, omega, zeta, tau, order)) <= 1e-8 * scale[order], order


def test_half_sine_tends_to_impulse():
    board = bd.Board()
    impulse = bd.board_response(board, bd.Impulse(2.0, 1.0), bd.Numerics(n_modes=4)).peak.stress
    errors = []
    for tau in (1e-4, 1e-5, 1e-6):
        pulse = bd.board_response(board, bd.HalfSine(2.0, 1.0, tau), bd.Numerics(n_modes=4)).peak.stress
        errors.append(abs(float(pulse / impulse) - 1))
    assert errors[-1] < 1e-6
    assert errors[0] > errors[1] > errors[2]  # monotone approach, O(tau^2)


def test_long_pulse_is_quasi_static():
    # A pulse much longer than the fundamental period T1 loads the board quasi-statically: midspan deflection of a
    # uniformly loaded pinned beam, 5 q L^4 / (384 EI) with q = rho A a_peak. The half-sine starts with a finite
    # jerk-free slope, whose dynamic overshoot is about T1 / (2 tau): the error must shrink like 1/tau.
    board = bd.Board()
    period = float(2 * math.pi / bd.natural_frequencies(board, 1)[0])
    a_peak = 100 * G
    static = 5 * float(board.mass_per_length) * a_peak * 0.1**4 / (384 * float(board.bending_stiffness))
    errors = []
    for ratio in (50, 200):
        tau = ratio * period
        motion = bd.HalfSine.from_peak(a_peak, tau)
        # A window of many periods needs a finer grid than the default's (Flag.WINDOW_RANGE otherwise).
        res = bd.board_response(board, motion, bd.Numerics(n_modes=9, window=1.05 * tau, points_per_period=2 * ratio))
        err = float(res.peak.deflection) / static - 1
        assert 0 < err < 1.5 * period / (2 * tau), (ratio, err)
        np.testing.assert_allclose(res.peak.deflection_x, 0.05, rtol=1e-6)
        np.testing.assert_allclose(res.peak.deflection_t, tau / 2, rtol=0.05)
        errors.append(err)
    np.testing.assert_allclose(errors[0] / errors[1], 4.0, rtol=0.3)


def test_jesd22_b111_first_mode_and_convergence():
    board = jedec_board()
    peak_acc, tau = bd.JESD22_B111_CONDITION_B
    motion = bd.HalfSine.from_peak(peak_acc, tau)
    dv = peak_acc * 2 * tau / math.pi
    np.testing.assert_allclose(motion.dvA, dv)
    # First mode by hand: both supports move together, beta_1 = -(2/pi)(dv + dv). The pulse's Fourier transform
    # gives the residual amplitude beta cos(w tau / 2) / (w (1 - (w tau / pi)^2)); for w tau < pi the maximum
    # comes after the pulse, at midspan.
    w = float(bd.natural_frequencies(board, 1)[0])
    assert w * tau < math.pi
    amplitude = 4 * dv / math.pi * math.cos(w * tau / 2) / (w * (1 - (w * tau / math.pi) ** 2))
    strain_1 = 1e-3 / 2 * (math.pi / 0.1) ** 2 * amplitude
    one = bd.board_response(board, motion, bd.Numerics(n_modes=1))
    np.testing.assert_allclose(one.peak.strain, strain_1, rtol=1e-9)
    np.testing.assert_allclose(one.peak.x, 0.05, rtol=1e-9)
    # The converged strain (the automatic mode count says converged) is stable to 0.1 % as modes are added.
    auto = bd.board_response(board, motion)
    assert bool(auto.converged)
    strains = [float(bd.board_response(board, motion, bd.Numerics(n_modes=n)).peak.strain) for n in (8, 16, 32)]
    for s in [float(auto.peak.strain)] + strains:
        assert abs(s / strains[-1] - 1) < 1e-3, (float(auto.peak.strain), strains)
    # Four modes (the thesis's choice) are not enough here: f_4 tau = 1.3 < 2.
    four = float(bd.board_response(board, motion, bd.Numerics(n_modes=4)).peak.strain)
    assert abs(four / strains[-1] - 1) > 1e-3


def test_refined_peak_matches_dense_grid():
    board = bd.Board(damping_ratio=0.01)
    motion = bd.HalfSine(4.0, -2.5, 3e-4)
    numerics = bd.Numerics(n_modes=8)
    res = bd.board_response(board, motion, numerics)
    # Brute force: the same modal series on a grid 40x denser in time and 16x in space.
    M = 8
    omega = bd.natural_frequencies(board, M)
    beta = bd._board.base.modal_velocity_jumps(bd.Board(), jnp.array([4.0, -2.5]), M)
    t = np.linspace(0, float(res.window), 80001)
    x = np.linspace(0, 0.1, 2001)
    Q = np.asarray(jax.vmap(lambda s: beta * bd.unit_response(s, omega, 0.01, 3e-4))(t))
    k = np.arange(1, M + 1)
    curv = (np.sin(np.outer(x, k) * np.pi / 0.1) * -((k * np.pi / 0.1) ** 2)) @ Q.T
    dense = 22e9 * 0.5e-3 * np.abs(curv).max()
    assert float(res.peak.stress) >= dense * (1 - 1e-9)
    np.testing.assert_allclose(res.peak.stress, dense, rtol=2e-6)
    # The coarse grid alone is worse, and its error estimate says so.
    coarse = bd.board_response(board, motion, bd.Numerics(n_modes=8, refine=False))
    assert float(coarse.peak.stress) < float(res.peak.stress)


def test_damping_lowers_the_peak():
    peaks = [
        float(bd.board_response(bd.Board(damping_ratio=z), bd.HalfSine(3.0, 1.0, 5e-4)).peak.stress)
        for z in (0.0, 0.02, 0.1, 0.3)
    ]
    assert all(a > b for a, b in zip(peaks, peaks[1:])), peaks


def test_ideal_impulse_reports_not_converged():
    res = bd.board_response(bd.Board(), bd.Impulse(3.0, 1.0))
    assert not bool(res.converged)
    assert int(res.n_modes) == 16 and int(res.check_modes) == 8
    assert float(res.error_estimate) > 0.02


def test_record_equals_half_sine():
    board = bd.Board(damping_ratio=0.02)
    tau = 5e-4
    t = np.linspace(0.0, tau, 2001)
    g = math.pi / (2 * tau) * np.sin(math.pi * t / tau)
    record = bd.Record(t, 3.0 * g, 1.0 * g)
    np.testing.assert_allclose(record.velocity_jumps, [3.0, 1.0, 0.0], rtol=1e-6)
    numerics = bd.Numerics(n_modes=6, method="diffrax", rtol=1e-10, atol=1e-14, max_steps=100000)
    from_record = bd.board_response(board, record, numerics)
    closed = bd.board_response(board, bd.HalfSine(3.0, 1.0, tau), bd.Numerics(n_modes=6))
    np.testing.assert_allclose(from_record.peak.stress, closed.peak.stress, rtol=1e-5)


def test_record_csv(tmp_path):
    path = tmp_path / "pulse.csv"
    path.write_text("t_ms,aA_g,aB_g\n0,0,0\n0.25,1500,1400\n0.5,0,0\n")
    rec = bd.Record.from_csv(path, time_unit=1e-3, acceleration_unit=G)
    np.testing.assert_allclose(rec.t, [0, 2.5e-4, 5e-4])
    np.testing.assert_allclose(rec.aA[1], 1500 * G)
    np.testing.assert_allclose(rec.velocity_jumps, [1500 * G * 2.5e-4, 1400 * G * 2.5e-4, 0.0])


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: bd.Record([0.0], [1.0], [1.0]), "at least 2 samples"),
        (lambda: bd.Record([], [], []), "at least 2 samples"),
        (lambda: bd.Record([0.0, 1.0, 0.5], [0, 1, 0], [0, 1, 0]), "strictly increasing"),
        (lambda: bd.Record([0.0, 1.0], [0, 1, 2], [0, 1]), "shape"),
        (lambda: bd.HalfSine(1.0, 1.0, -1e-4), "HalfSine.duration"),
        (lambda: bd.HalfSine.from_peak(1000.0, 0.0), "HalfSine.duration"),
        (lambda: bd.Board(axial_force=-1e4), "Board.axial_force"),
        (lambda: bd.Numerics(method="rk4"), "Numerics.method"),
        (lambda: bd.Numerics(solver="Euler"), "Numerics.solver"),
        (lambda: bd.Numerics(n_modes=0), "Numerics.n_modes"),
        # The field the user set, not min_modes (which once took the blame with "valid: an int in [1, 3]").
        (lambda: bd.Numerics(max_modes=3), r"Numerics.max_modes = 3; valid: an int >= Numerics.min_modes = 4 .*"
                                           r"Numerics\(max_modes=3, min_modes=3\)"),
        (lambda: bd.Numerics(stretching=True), "stretching"),
        (lambda: bd.Numerics(window=-1.0), "Numerics.window"),
        (lambda: bd.board_response(bd.Board(), bd.Record([0, 1e-3], [0, 1], [0, 1])), "diffrax"),
        (lambda: bd.board_response(bd.Board(), (1.0, 2.0)), "Impulse, HalfSine, PulseTrain or Record"),
    ],
)
def test_bad_input_is_named(make, match):
    with pytest.raises((ValueError, TypeError), match=match):
        make()


def test_buckled_board_is_flagged_under_jit():
    board = bd.Board()
    res = jax.jit(lambda f: bd.board_response(eqx_tree_at_force(board, f), bd.HalfSine(1.0, 1.0, 5e-4)))(-200.0)
    assert int(res.flags) & bd.Flag.BUCKLED
    assert np.isnan(float(res.peak.stress))


def eqx_tree_at_force(board, force):
    import equinox as eqx

    return eqx.tree_at(lambda b: b.axial_force, board, jnp.asarray(force, float))


def test_stretching_reduces_to_linear_at_small_amplitude():
    board = bd.Board()
    motion = bd.HalfSine(1e-4, 1e-4, 5e-4)  # deflection ~ 1e-7 m << thickness
    lin = bd.board_response(board, motion, bd.Numerics(n_modes=4, method="diffrax", rtol=1e-10, atol=1e-18))
    nl = bd.board_response(
        board, motion, bd.Numerics(n_modes=4, method="diffrax", rtol=1e-10, atol=1e-18, stretching=True)
    )
    # The bending part is linear to (deflection / thickness)^2 ~ 1e-8; the membrane part, relative, is below deflection / h.
    np.testing.assert_allclose(nl.peak.stress - nl.peak.membrane_stress, lin.peak.stress, rtol=1e-6)
    assert 0 < float(nl.peak.membrane_stress / nl.peak.stress) < float(lin.peak.deflection) / 1e-3


@pytest.mark.parametrize("ratio", [0.1, 0.3])
def test_stretching_single_mode_follows_duffing_backbone(ratio):
    # One mode, free vibration: q'' + w^2 q + gamma q^3 = 0 with gamma = E (pi/L)^4 / (4 rho). Pick the amplitude
    # so that gamma A^2 / w^2 = ratio, start from the matching velocity, and measure the period.
    board = bd.Board()
    w = float(bd.natural_frequencies(board, 1)[0])
    gamma = 22e9 * (math.pi / 0.1) ** 4 / (4 * 1900.0)
    A = math.sqrt(ratio * w * w / gamma)
    v0 = math.sqrt(w * w * A * A + 0.5 * gamma * A**4)  # energy: v^2/2 = w^2 A^2/2 + gamma A^4/4
    beta_to_jump = -math.pi / 4  # beta_1 = -(2/pi)(dvA + dvB) with dvA = dvB
    motion = bd.Impulse(v0 * beta_to_jump, v0 * beta_to_jump)
    window = 6 * 2 * math.pi / w
    modes, failed = solve_modes(
        board, motion, 1, jnp.asarray(window), jnp.ones(1), solver="Dopri8", rtol=1e-11, atol=1e-16, stretching=True
    )
    assert not bool(failed)
    t = np.linspace(0, window, 60001)
    q = np.asarray(jax.vmap(modes)(t))[:, 0]
    np.testing.assert_allclose(q.max(), A, rtol=1e-6)
    crossings = t[1:][(q[:-1] > 0) & (q[1:] <= 0)]
    period = np.mean(np.diff(crossings))
    omega_nl = 2 * math.pi / period
    backbone = duffing_backbone(w, gamma, A)
    assert omega_nl / w - 1 > 0.02  # clearly hardening
    np.testing.assert_allclose(omega_nl, backbone, rtol=3e-3 * ratio / 0.1)


@pytest.mark.parametrize("ratio", [0.1, 1.0])
def test_stretching_peak_adds_membrane_strain(ratio):
    # One mode, free vibration of amplitude A: the bending strain peaks at mid-span, (h/2) (pi/L)^2 A, when the
    # membrane strain (1/4) (pi/L)^2 A^2 peaks too, so the face in tension sees their sum (closed form).
    board = bd.Board()
    E, h, L = 22e9, 1e-3, 0.1
    w = float(bd.natural_frequencies(board, 1)[0])
    gamma = E * (math.pi / L) ** 4 / (4 * 1900.0)
    A = math.sqrt(ratio * w * w / gamma)
    v0 = math.sqrt(w * w * A * A + 0.5 * gamma * A**4)
    motion = bd.Impulse(-v0 * math.pi / 4, -v0 * math.pi / 4)
    numerics = bd.Numerics(n_modes=1, method="diffrax", solver="Dopri8", rtol=1e-11, atol=1e-16, stretching=True)
    res = bd.board_response(board, motion, numerics)
    kappa2 = (math.pi / L) ** 2
    bending, membrane = h / 2 * kappa2 * A, kappa2 * A * A / 4
    np.testing.assert_allclose(res.peak.strain, bending + membrane, rtol=1e-6)
    np.testing.assert_allclose(res.peak.stress, E * (bending + membrane), rtol=1e-6)
    np.testing.assert_allclose(res.peak.membrane_stress, E * membrane, rtol=1e-5)
    np.testing.assert_allclose(res.peak.x, L / 2, rtol=1e-6)
    assert "peak_membrane_stress_MPa" in res.summary()
    # Without stretching the membrane part is zero.
    linear = bd.board_response(board, motion, bd.Numerics(n_modes=1))
    assert float(linear.peak.membrane_stress) == 0.0


def test_float32_close_to_float64():
    res64 = bd.simulate(bd.Scene.default())
    with jax.enable_x64(False):
        res32 = bd.simulate(bd.Scene.default())
        assert res32.peak.stress.dtype == jnp.float32
        assert int(res32.flags) == 0
    np.testing.assert_allclose(res32.peak.stress, res64.peak.stress, rtol=1e-4)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["random", "held", "diagonal", "repeated"]))
def test_symmetric_eigen3_agrees_with_lapack(seed, kind):
    """The Newton refinement's 3 x 3 eigensolver (Jacobi rotations, no LAPACK call): A V = V diag(w) and V
    orthonormal to 1e-13 of |A|, eigenvalues as NumPy's LAPACK `eigvalsh`, on random, held (a row and column
    replaced by -e_i, as the refinement holds a coordinate on a bound), nearly diagonal and repeated-eigenvalue
    matrices over 16 decades of scale."""
    from beamdrop_jax._board.search import symmetric_eigen3

    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-8, 8)
    A = A + A.T
    if kind == "held":
        i = rng.integers(3)
        A[i, :] = A[:, i] = 0.0
        A[i, i] = -1.0
    elif kind == "diagonal":
        A = np.diag(rng.normal(size=3))
        A[1, 2] = A[2, 1] = 1e-20
    elif kind == "repeated":
        A = -np.eye(3)
        A[2, 2] = rng.normal()
    with jax.enable_x64(True):
        w, V = (np.asarray(v) for v in jax.jit(symmetric_eigen3)(jnp.asarray(A, dtype=jnp.float64)))
    scale = np.abs(A).max()
    assert np.abs(A @ V - V * w).max() <= 1e-13 * scale
    assert np.abs(V.T @ V - np.eye(3)).max() <= 1e-13
    np.testing.assert_allclose(np.sort(w), np.linalg.eigvalsh(A), rtol=0, atol=1e-13 * scale)
