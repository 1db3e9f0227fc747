"""The package against measurements and an independent code, as notebook 09 shows them: measured rebounds of spheres
(Kharaz, Gorham & Salman, Powder Technology 120 (2001) 281-291: 5 mm alumina on glass at 3.9 m/s, mu = 0.092,
e = 0.98), rocking blocks' corner impacts (ElGawady et al.), OpenSees beam and shell elements, and a board-level
drop test (Fuchs & Major 2011)."""

import math

import jax
import numpy as np
import pytest

import beamdrop_jax as bd

THETA_ET = np.array([1.84, 3.70, 9.50, 20.01, 30.13, 39.38, 49.69, 60.02])
ET = np.array([0.7934, 0.7453, 0.6726, 0.5969, 0.6876, 0.7715, 0.8476, 0.9014])
THETA_SPIN = np.array([6.14, 10.99, 21.25, 31.16, 39.14, 50.35, 60.33])
SPIN = np.array([136.2, 265.7, 577.7, 612.9, 595.5, 453.2, 382.1])
R, SPEED, MU, E = 2.5e-3, 3.9, 0.092, 0.98
MASS = 4000.0 * 4 / 3 * math.pi * R**3
INERTIA = 0.4 * MASS * R**2
B = np.array([[1 / MASS + R**2 / INERTIA, 0.0], [0.0, 1 / MASS]])
THETA_STICK = math.degrees(math.atan(3.5 * MU * (1 + E)))  # the sphere slides throughout above this angle


def rebound(theta_deg, law="poisson"):
    th = np.radians(theta_deg)
    v0 = np.stack([SPEED * np.sin(th), -SPEED * np.cos(th)], -1)
    P = np.asarray(jax.vmap(lambda v: bd.routh_impulse(B, v, MU, E, law=law).P)(v0))
    return 1 + P[:, 0] / (MASS * v0[:, 0]), np.abs(R * P[:, 0] / INERTIA)


@pytest.mark.parametrize("law", ["poisson", "newton", "stronge"])
def test_sliding_regime_matches_measured_rebounds(law):
    et, _ = rebound(THETA_ET, law)
    _, spin = rebound(THETA_SPIN, law)
    sliding_et, sliding_spin = THETA_ET > THETA_STICK, THETA_SPIN > THETA_STICK
    assert sliding_et.sum() == 3 and sliding_spin.sum() == 3
    np.testing.assert_allclose(et[sliding_et], ET[sliding_et], rtol=0.02)  # measured within 0.9 %
    np.testing.assert_allclose(spin[sliding_spin], SPIN[sliding_spin], rtol=0.10)  # within 8 %
    # Closed form of a sphere sliding throughout: e_t = 1 - mu (1 + e) cot(theta).
    th = np.radians(THETA_ET[sliding_et])
    np.testing.assert_allclose(et[sliding_et], 1 - MU * (1 + E) / np.tan(th), rtol=1e-12)


def test_stick_regime_deviates_as_the_notebook_says():
    et, _ = rebound(THETA_ET)
    _, spin = rebound(THETA_SPIN)
    stick_et, stick_spin = THETA_ET < THETA_STICK, THETA_SPIN < THETA_STICK
    # A rigid sticking contact: e_t = 1 - 1 / (1 + m R^2 / I) = 5/7 whatever the angle.
    np.testing.assert_allclose(et[stick_et], 5 / 7, rtol=1e-12)
    # Measured: above 5/7 near normal incidence, below it at 10-20 deg (tangential compliance); the spin is
    # under-predicted by 6 to 30 %.
    deviation = et[stick_et] / ET[stick_et] - 1
    np.testing.assert_allclose(deviation, [-0.100, -0.042, 0.062, 0.197, 0.039], atol=2e-3)
    spin_deviation = spin[stick_spin] / SPIN[stick_spin] - 1
    assert np.all(spin_deviation < -0.05) and np.all(spin_deviation > -0.31)



# A box striking on its corner: a rocking block of half-width b = 1, half-height h = aspect and mass 1 rotating at
# Omega = 1 about one bottom corner; the other corner (r = (b, -h) from the centre) strikes with S0 = 0, C0 = -2b.
def rocking(aspect, mu, e=0.0):
    b, h = 1.0, aspect
    inertia = (b**2 + h**2) / 3
    B = np.array([[1 + h**2 / inertia, b * h / inertia], [b * h / inertia, 1 + b**2 / inertia]])
    result = bd.routh_impulse(B, np.array([0.0, -2 * b]), mu, e)
    Pt, Pn = (float(p) for p in result.P)
    return 1 - (b * Pn + h * Pt) / inertia, int(result.mode)


@pytest.mark.parametrize("aspect", [1.5, 3.0, 5.0])
def test_rocking_block_corner_impact_matches_its_closed_forms(aspect):
    b, h, inertia = 1.0, aspect, (1 + aspect**2) / 3
    mu_stick = 3 * aspect / (4 * aspect**2 + 1)  # |B3| / B1
    # Sticking: angular momentum about the new corner is conserved (Housner 1963).
    eta, mode = rocking(aspect, 1.01 * mu_stick)
    assert mode == bd.ImpactMode.STICK_IN_COMPRESSION
    np.testing.assert_allclose(eta, 1 - 1.5 / (1 + aspect**2), rtol=1e-12)
    # Sliding throughout: Pt = -mu Pn, compression ends at C = 0.
    for mu in (0.0, 0.5 * mu_stick, 0.99 * mu_stick):
        eta, mode = rocking(aspect, mu)
        assert mode == bd.ImpactMode.SLIDING
        Pn = 2 * b / (1 + b**2 / inertia - mu * b * h / inertia)
        np.testing.assert_allclose(eta, 1 - (b - mu * h) * Pn / inertia, rtol=1e-12)


def test_rocking_block_against_measured_restitution_as_the_notebook_says():
    # ElGawady, Ma, Butterworth & Ingham (doi:10.1201/9781003060888-45): measured coefficient of restitution =
    # 0.97 (h/b = 3) and 0.95 (h/b = 5) x Housner's prediction on concrete, 0.67 x on rubber (h/b = 5). Read as an
    # angular-velocity ratio or as its square (both definitions are in use), the measured omega+ / omega- is
    # ratio x or sqrt(ratio) x 1 - 1.5 sin^2(alpha). The rigid corner law (concrete's friction is far above the
    # 0.24 and 0.15 these blocks need to stick) is 1.5 to 5 % above the measurement on concrete, 22 to 49 % on rubber.
    for aspect, ratio, low, high in ((3.0, 0.97, 0.015, 0.032), (5.0, 0.95, 0.025, 0.054), (5.0, 0.67, 0.22, 0.50)):
        eta, _ = rocking(aspect, 0.6)
        housner = 1 - 1.5 / (1 + aspect**2)
        for measured in (ratio * housner, math.sqrt(ratio) * housner):
            assert low <= eta / measured - 1 <= high

# The board against an independent finite-element code: OpenSees, Euler-Bernoulli beam elements with consistent
# mass, supports driven by imposed motions, Newmark average acceleration (mesh and step convergence in notebook 09).
# Per case: board, motion, package numerics, FE elements, FE step, FE window as a fraction of the package's window,
# and mid-plane stretching (the FE side then uses corotational elements between axially fixed supports).
# The 0.1 ms pulse excites modes up to ~20 kHz: the package keeps 48 modes (its default 12 are within 8e-4) and the
# FE side needs 80 elements and 0.5 us; an undamped board's second half-period mirrors its first (u(L - x, t + T1/2)
# = -u(x, t)), so the FE side stops at half the window, before Newmark's phase error in the high modes grows.
JEDEC_BOARD = dict(length=0.1, thickness=1e-3, width=0.077, youngs_modulus=24e9, density=1850.0)
FE_CASES = {
    "default drop": lambda: (bd.Scene.default().board, "default", bd.Numerics(), 40, 2e-6, 1.0, False),
    "JESD22-B111 board, condition B": lambda: (
        bd.Board(**JEDEC_BOARD), bd.HalfSine.from_peak(*bd.JESD22_B111_CONDITION_B), bd.Numerics(), 40, 2e-6, 1.0,
        False,
    ),
    "unequal jumps, 0.1 ms pulse": lambda: (bd.Board(), bd.HalfSine(2.0, -0.5, 1e-4), bd.Numerics(n_modes=48),
                                            80, 5e-7, 0.5, False),
    # Deflection 0.57 x the thickness: the membrane part is 43 % of the peak surface stress.
    "JESD22-B111 board with mid-plane stretching": lambda: (
        bd.Board(**JEDEC_BOARD), bd.HalfSine.from_peak(*bd.JESD22_B111_CONDITION_B),
        bd.Numerics(method="diffrax", stretching=True, n_modes=12, rtol=1e-9, atol=1e-14), 40, 2e-6, 1.0, True,
    ),
}


@pytest.mark.parametrize("case", sorted(FE_CASES))
def test_board_agrees_with_opensees(case):
    board, motion, numerics, n_elements, dt, part, stretching = FE_CASES[case]()
    if motion == "default":
        scene = bd.Scene.default()
        jumps = bd.simulate(scene).support_jumps
        motion = bd.HalfSine(jumps[0], jumps[1], scene.contact.duration)
    res = bd.board_response(board, motion, numerics)
    # (A fixed mode count's check compares with half as many modes; 8, 10 and 12 modes agree to 3e-4 here.)
    assert bool(res.converged) or numerics.n_modes is not None
    fe = bd.opensees_board_response(board, motion, part * float(res.window), n_elements=n_elements, dt=dt,
                                    stretching=stretching)
    np.testing.assert_allclose(fe.frequencies, np.asarray(res.frequencies[:4]), rtol=2e-5)
    np.testing.assert_allclose(fe.stress, float(res.peak.stress), rtol=2e-3)
    # Where and when: the finite-element board at the package's peak sees the package's peak stress (an undamped
    # board's peak recurs, so the two searches may report different instants of the same peak).
    np.testing.assert_allclose(fe.stress_at(float(res.peak.x), float(res.peak.t)), float(res.peak.stress), rtol=2e-3)


def test_plate_agrees_with_opensees_shell_elements():
    # An SFSF plate (Levy modes) whose ends jump unequally over 0.3 ms, against OpenSees discrete-Kirchhoff shells
    # (ShellDKGQ), supports driven by imposed motions, Newmark average acceleration (notebook 09: the JESD22 board
    # on screws and the convergence of both sides).
    plate = bd.Plate(length=0.06, width=0.03, thickness=1e-3, youngs_modulus=24e9, density=1850.0, poisson_ratio=0.3,
                     edges="SFSF")
    motion, gauges = bd.HalfSine(1.0, 0.6, 3e-4), ((0.03, 0.0), (0.02, 0.01))
    res = bd.board_response(plate, motion, bd.Numerics(max_modes=32), gauges=gauges)
    package = np.asarray(res.frequencies[:4])
    # Frequencies: the shell mesh converges as h^2 onto the package's exact Levy modes; Richardson's extrapolation
    # from 2 and 1.5 mm elements removes the leading error.
    fine, finer = (bd.opensees_plate_response(plate, None, 0.0, element_size=h).frequencies for h in (2e-3, 1.5e-3))
    assert np.all(np.abs(finer / package - 1) < np.abs(fine / package - 1))
    extrapolated = finer + (finer - fine) * 1.5**2 / (2**2 - 1.5**2)
    np.testing.assert_allclose(extrapolated, package, rtol=3e-4)
    # The strain gauges' peaks and their times (central differences of the shell's nodal deflections).
    fe = bd.opensees_plate_response(plate, motion, 1.3 * float(res.gauges.peak_time.max()), gauges=gauges,
                                    element_size=1.5e-3, dt=5e-6)
    np.testing.assert_allclose(fe.peak_strain, np.asarray(res.gauges.peak_strain), rtol=2e-3)
    np.testing.assert_allclose(fe.peak_time, np.asarray(res.gauges.peak_time), atol=2 * fe.dt)


# Held-out shell layouts (issue 38): plates the package was not tuned on (not the SFSF plate above, nor notebook 09's
# JESD22 board), against OpenSees shells (ShellDKGQ) on two meshes, and against a much finer run of the package.
# Every point of interest (mounts, gauges) lies on a uniform grid of the coarse FE mesh, so both meshes are uniform.
# Per layout: plate (1 mm FR4-like, E 24 GPa, rho 1850 kg/m^3, nu 0.3), support jumps (dvA, dvB m/s, tau s), gauges
# (m), FE meshes (coarse, fine), FE step; Newmark's step error there is below 1e-3 (measured against half the step on
# the fine mesh: 7e-4 on the screwed plate, 2e-4 elsewhere).
SHELL_LAYOUTS = {
    # Supported along its long sides, free ends, a short pulse: the modes come in families across the width (1, 2, 3
    # half-waves); modes 6 to 14 barely participate, and the 3-half-wave family starts at mode 15 (9 f1, f tau = 7.7,
    # a third of the first mode's participation and 8.5 times its curvature at the centre).
    "FSFS strip, 0.2 ms pulse": dict(
        plate=dict(length=0.048, width=0.02, edges="FSFS"), jumps=(1.0, 0.5, 2e-4),
        gauges=((0.024, 0.0), (0.006, 0.004)), meshes=(2e-3, 1e-3), dt=2e-6),
    # Hinged along end A (a connector), free elsewhere, propped by one screw near end B.
    "SFFF, one screw": dict(
        plate=dict(length=0.06, width=0.04, edges="SFFF", mounts=((0.052, 0.004),), mount_radius=3e-3),
        jumps=(1.0, 0.8, 3e-4), gauges=((0.024, -0.012), (0.04, -0.004)), meshes=(4e-3, 2e-3), dt=1e-5),
    # Free edges on five irregular screws, one inside; a gauge 17 mm from the screws, between them, and one 5.7 mm from
    # the inner screw, where a point support's strain is steep (log r).
    "FFFF, five screws": dict(
        plate=dict(length=0.08, width=0.048, edges="FFFF", mount_radius=2.5e-3,
                   mounts=((0.008, -0.016), (0.072, -0.02), (0.076, 0.016), (0.012, 0.02), (0.044, -0.004))),
        jumps=(1.0, 0.7, 3e-4), gauges=((0.032, 0.008), (0.048, 0.0)), meshes=(4e-3, 2e-3), dt=1e-5),
}
SHELL_MATERIAL = dict(thickness=1e-3, youngs_modulus=24e9, density=1850.0, poisson_ratio=0.3)
SHELL_SETTINGS = {
    "default": (None, bd.Numerics()),
    # What a screwed board needs (the JESD22 board's: DESIGN.md section 6, Numerics' notes).
    "converged": ((20, 20), bd.Numerics(max_modes=48, pulse_modes=3, frequency_growth=1)),
    # What the strip's default note asks for: more modes (its 3-half-wave family starts at mode 15).
    "more modes": (None, bd.Numerics(max_modes=64, frequency_growth=1)),
    # The strip's reference: 96 modes in a 16 x 16 basis (within 1e-4 of 28 x 28 with 96 modes).
    "finer modes": ((16, 16), bd.Numerics(n_modes=96, frequency_growth=1)),
}
# The package's runs per layout; each compiles its own program (10 to 20 s), so only those that say something new.
# The strip's default says it is not converged and names more modes, which then say converged: checked against a
# finer run. The screwed plates say they are not converged at these settings (the basis converges slowly on point
# supports: 2e-3 at 28 x 28 on the one-screw plate), which their notes and error estimates must cover.
SHELL_RUNS = {"FSFS strip, 0.2 ms pulse": ("default", "more modes", "finer modes"), "SFFF, one screw": ("default",),
              "FFFF, five screws": ("default", "converged")}


def _shell_plate(layout, basis=None):
    return bd.Plate(**SHELL_MATERIAL, **SHELL_LAYOUTS[layout]["plate"], basis=basis)


def _shell_package(layout, settings):
    basis, numerics = SHELL_SETTINGS[settings]
    case = SHELL_LAYOUTS[layout]
    return bd.board_response(_shell_plate(layout, basis), bd.HalfSine(*case["jumps"]), numerics,
                             gauges=case["gauges"])


def _shell_fe(layout, window):
    """OpenSees on the coarse and the fine mesh over [0, window]."""
    case = SHELL_LAYOUTS[layout]
    return tuple(bd.opensees_plate_response(_shell_plate(layout), bd.HalfSine(*case["jumps"]), window,
                                            gauges=case["gauges"], element_size=h, dt=case["dt"])
                 for h in case["meshes"])


@pytest.mark.parametrize("layout", sorted(SHELL_LAYOUTS))
def test_held_out_shell_layouts_against_opensees_and_a_finer_run(layout):
    """A layout's whole check in one test, so that pytest-xdist does not split one layout's runs (the compiles) between
    its workers: frequencies and gauges against OpenSees, the notes where the package says it is not converged, and
    converged=True against a much finer run of the package."""
    runs = SHELL_RUNS[layout]
    res = {s: _shell_package(layout, s) for s in runs}
    # OpenSees over 1.3 x the latest gauge peak of the package's runs.
    window = 1.3 * max(float(np.max(np.asarray(r.gauges.peak_time))) for r in res.values())
    coarse, fine = _shell_fe(layout, window)

    # Frequencies. The shell mesh converges as h^2: Richardson's extrapolation from the two meshes, its correction
    # (extrapolated - fine) the FE error. The Ritz frequencies are upper bounds converging from above in the basis
    # (slowly on point supports, about as n^-2 in the functions each way): the change from the default basis (n = 12)
    # to 28 x 28 functions, extrapolated to n = 12 by Richardson (1 / (1 - (12 / 28)^2)), is their error.
    package = np.asarray(res[runs[0]].frequencies[:4])
    previous = np.asarray(_shell_plate(layout, (28, 28)).frequencies(4)) / (2 * np.pi)
    extrapolated = fine.frequencies + (fine.frequencies - coarse.frequencies) / 3
    fe_error, ritz_error = np.abs(extrapolated - fine.frequencies), np.abs(previous - package) / (1 - (12 / 28) ** 2)
    print(f"\n{layout}: frequencies (Hz) package {package} ({runs[0]}; 28 x 28 basis {previous}), OpenSees "
          f"{coarse.frequencies} / {fine.frequencies} -> {extrapolated} (FE error {fe_error})")
    assert np.all(np.abs(package - extrapolated) <= fe_error + ritz_error + 1e-4 * package)

    # Gauges. The fine mesh's FE error is at most its change from the coarse mesh (h halved, convergence of order
    # >= 1), plus 1e-3 for the step; peak times to two steps and the meshes' difference.
    fe_error = np.abs(fine.peak_strain - coarse.peak_strain) + 1e-3 * fine.peak_strain
    for s in (s for s in runs if not s.startswith("finer")):
        r = res[s]
        strain, times, c = np.asarray(r.gauges.peak_strain), np.asarray(r.gauges.peak_time), r.convergence
        print(f"{layout}, {s}: converged={bool(r.converged)} ({int(r.n_modes)} modes against {int(r.check_modes)}: "
              f"{float(c.modes):.1e}, gauges {float(c.gauges):.1e}; basis {float(c.basis):.1e}); gauges {strain} at "
              f"{times} s; OpenSees {fine.peak_strain} at {fine.peak_time} s (coarse mesh {coarse.peak_strain}): off "
              f"by {np.abs(strain / fine.peak_strain - 1)}, FE error {fe_error / fine.peak_strain}")
        np.testing.assert_allclose(times, fine.peak_time, atol=2 * fine.dt + float(np.max(np.abs(
            fine.peak_time - coarse.peak_time))))
        if bool(r.converged):
            # converged=True: within convergence_rtol of OpenSees, to the FE error.
            assert np.all(np.abs(strain - fine.peak_strain) <= fe_error + 1e-3 * strain), (layout, s)
        else:
            # converged=False: one note names the estimate that failed and its fix, and the error the package
            # reports covers its distance from OpenSees, to the FE error.
            scene = bd.Scene(board=_shell_plate(layout, SHELL_SETTINGS[s][0]))
            notes = [n for n in bd.response_notes(scene, r) if n.startswith("not converged")]
            print(f"  {notes}")
            assert len(notes) == 1 and any(fix in notes[0] for fix in (
                "raise Plate.basis", "raise Numerics.max_modes", "raise Numerics.pulse_modes")), notes
            if layout.startswith("FSFS") and s == "default":
                assert "raise Numerics.max_modes" in notes[0], notes  # what "more modes" then does
            assert np.all(np.abs(strain - fine.peak_strain) <= fe_error + float(r.error_estimate) * strain)

    # converged=True implies agreement with a much finer run of the package within 2e-3 (twice convergence_rtol: the
    # estimates are first-order ones), at the gauges and at the peak.
    if runs[-1].startswith("finer"):
        finer = res[runs[-1]]
        reference = np.append(np.asarray(finer.gauges.peak_strain), float(finer.peak.strain))
        claimed = [s for s in runs[:-1] if bool(res[s].converged)]
        assert claimed, f"{layout}: no run says converged"
        for s in claimed:
            value = np.append(np.asarray(res[s].gauges.peak_strain), float(res[s].peak.strain))
            change = np.abs(value / reference - 1)
            print(f"{layout}, {s} against finer: gauges and peak strain {value} against {reference} (its own "
                  f"estimate {float(finer.error_estimate):.1e}): off by {change}")
            assert np.all(change <= 2e-3), (layout, s, change)


# A board-level drop test (Fuchs & Major, Frattura ed Integrita Strutturale 15 (2011) 64-73): the board oscillated
# at 280 Hz, the strain at its centre at the first deflection was 2e-3, its largest peak-to-peak deflection about
# 5 mm, under 1500 g over a 1 ms pulse as the paper states. The paper does not dimension its board, so notebook 09
# builds boards from the measured frequency (FR4 of the jesd22-board scene).
FUCHS_F1, FUCHS_STRAIN, FUCHS_DEFLECTION = 280.0, 2e-3, 5e-3 / 2


def _board_at_fuchs_frequency(length):
    c = math.sqrt(24e9 / (12 * 1850.0))
    return bd.Board(length=length, thickness=FUCHS_F1 * 2 / math.pi * length**2 / c, width=0.077,
                    youngs_modulus=24e9, density=1850.0)


def test_board_level_drop_measurement_as_the_notebook_says():
    pulses = {tau: bd.HalfSine.from_peak(1500 * bd.GRAVITY, tau) for tau in (1e-3, 0.5e-3)}
    res = {(L, tau): bd.board_response(_board_at_fuchs_frequency(L), p)
           for L in (0.10, 0.15) for tau, p in pulses.items()}
    for tau in pulses:
        np.testing.assert_allclose(float(res[0.10, tau].frequencies[0]), FUCHS_F1, rtol=1e-9)
        # At a given first frequency the board's size does not matter.
        np.testing.assert_allclose(float(res[0.15, tau].peak.strain), float(res[0.10, tau].peak.strain), rtol=1e-6)
    r = res[0.10, 0.5e-3]
    # Strain per centre deflection, first mode's closed form: (h / 2) pi^2 / L^2 = pi f1 / sqrt(E / (12 rho)).
    per_deflection = float(r.peak.strain) / float(r.peak.deflection)
    np.testing.assert_allclose(per_deflection, math.pi * FUCHS_F1 / math.sqrt(24e9 / (12 * 1850.0)), rtol=5e-3)
    # The measured deflection through it: 6 % above the measured strain (the notebook's "where it agrees").
    assert abs(per_deflection * FUCHS_DEFLECTION / FUCHS_STRAIN - 1.06) < 0.01
    # The response to the pulse: 2.66 times the measurement at the stated 1 ms, 1.40 at condition B's 0.5 ms.
    np.testing.assert_allclose(float(res[0.10, 1e-3].peak.strain) / FUCHS_STRAIN, 2.66, atol=0.01)
    np.testing.assert_allclose(float(r.peak.strain) / FUCHS_STRAIN, 1.40, atol=0.01)
