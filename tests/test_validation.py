"""The impact law against measured rebounds (Kharaz, Gorham & Salman, Powder Technology 120 (2001) 281-291):
5 mm alumina spheres on glass at 3.9 m/s, mu = 0.092, e = 0.98. Notebook 09 shows the same comparison."""

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
