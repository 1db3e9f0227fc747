"""Housing kinematics against brute force and hand calculation."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import beamdrop_jax as bd
from references import darboux_keller, point_velocity

G = 9.80665


def corners_ground(W, H, theta):
    e1 = np.array([math.cos(theta), math.sin(theta)])
    e2 = np.array([-math.sin(theta), math.cos(theta)])
    return [(a * W / 2, b * H / 2, a * W / 2 * e1 + b * H / 2 * e2) for a in (-1, 1) for b in (-1, 1)]


@pytest.mark.parametrize("theta_deg", [10, 30, 80, 100, 170, 190, 260, 280, 350, -45])
def test_lowest_corner_brute_force(theta_deg):
    theta = math.radians(theta_deg)
    scene = bd.Scene(drop=bd.Drop(orientation=theta))
    corner, r, flat = bd.lowest_corner(scene)
    q1, q2, pos = min(corners_ground(0.15, 0.075, theta), key=lambda c: c[2][1])
    np.testing.assert_allclose(corner, (q1, q2), rtol=1e-14)
    np.testing.assert_allclose(r, -pos, rtol=1e-12, atol=1e-15)
    assert r[1] > 0 and not bool(flat)


def test_hand_computed_corner_impact_and_support_jumps():
    # A board at an angle and off centre; every number below is recomputed here from first principles.
    W, H, m, k = 0.15, 0.075, 0.18, 0.04
    theta, h, w0, u = math.radians(35), 1.2, 3.0, 0.4
    mu, e = 0.35, 0.6
    c, phi, L = np.array([0.012, -0.008]), math.radians(12), 0.08
    scene = bd.Scene(
        housing=bd.Housing(width=W, height=H, mass=m, radius_of_gyration=k),
        board=bd.Board(length=L),
        placement=bd.Placement(centre=c, angle=phi),
        drop=bd.Drop(orientation=theta, height=h, spin=w0, horizontal_speed=u),
        contact=bd.Contact(friction=mu, restitution=e),
    )
    I = m * k * k
    _, _, S_pos = min(corners_ground(W, H, theta), key=lambda c: c[2][1])
    x, y = -S_pos
    v_G = np.array([u, -math.sqrt(2 * G * h)])
    v_S = point_velocity(v_G, w0, S_pos)
    B = np.array([[1 / m + y * y / I, -x * y / I], [-x * y / I, 1 / m + x * x / I]])
    Pt, Pn, _ = darboux_keller(B, v_S, mu, e)
    P = np.array([Pt, Pn])
    dv_G = P / m
    dw = (S_pos[0] * P[1] - S_pos[1] * P[0]) / I  # (r_S x P)_z with r_S = S - G
    e1 = np.array([math.cos(theta), math.sin(theta)])
    e2 = np.array([-math.sin(theta), math.cos(theta)])
    t = math.cos(phi) * e1 + math.sin(phi) * e2
    n = np.array([-t[1], t[0]])
    A = c - L / 2 * np.array([math.cos(phi), math.sin(phi)])
    Bq = c + L / 2 * np.array([math.cos(phi), math.sin(phi)])
    jumps = [point_velocity(dv_G, dw, q[0] * e1 + q[1] * e2) @ n for q in (A, Bq)]

    hit = bd.housing_impact(scene)
    np.testing.assert_allclose(hit.v0, v_S, rtol=1e-13)
    np.testing.assert_allclose(hit.B, B, rtol=1e-13)
    np.testing.assert_allclose(hit.impact.P, P, rtol=1e-12)
    np.testing.assert_allclose(hit.dv_G, dv_G, rtol=1e-12)
    np.testing.assert_allclose(hit.dw, dw, rtol=1e-12)
    np.testing.assert_allclose(bd.support_jumps(scene, hit), jumps, rtol=1e-12)
    # The contact point's velocity after impact from the rigid-body jumps equals the law's (S, C).
    np.testing.assert_allclose(v_S + point_velocity(hit.dv_G, hit.dw, S_pos), hit.impact.velocity, rtol=1e-12)


@pytest.mark.parametrize("theta", [0.0, math.pi / 2, math.pi, 3 * math.pi / 2])
def test_flat_landing_translates(theta):
    e, h = 0.4, 1.0
    scene = bd.Scene(
        drop=bd.Drop(orientation=theta, height=h),
        contact=bd.Contact(restitution=e, friction=0.8),
        placement=bd.Placement(centre=(0.01, 0.005), angle=0.1),
        board=bd.Board(length=0.06),
    )
    hit = bd.housing_impact(scene)
    assert bool(hit.flat)
    v = math.sqrt(2 * G * h)
    np.testing.assert_allclose(hit.dv_G, (0.0, (1 + e) * v), rtol=1e-13, atol=1e-15)
    assert float(hit.dw) == 0.0
    # Every point gains (1 + e) v upwards, so the support jumps are that projected on the board normal.
    normal_y = math.cos(theta + 0.1)
    np.testing.assert_allclose(bd.support_jumps(scene, hit), [(1 + e) * v * normal_y] * 2, rtol=1e-12, atol=1e-14)


def test_flat_landing_with_spin_is_refused_eagerly_and_flagged_under_jit():
    scene = bd.Scene(drop=bd.Drop(orientation=0.0, spin=1.0))
    with pytest.raises(ValueError, match="flat on a face"):
        bd.housing_impact(scene)
    flags = jax.jit(lambda s: bd.housing_impact(s).flags)(scene)
    assert int(flags) & bd.Flag.FLAT_LANDING_WITH_MOTION
    scene = bd.Scene(drop=bd.Drop(orientation=0.0, horizontal_speed=0.5))
    with pytest.raises(ValueError, match="Drop.horizontal_speed = 0.5"):
        bd.housing_impact(scene)


def test_separating_contact_is_refused():
    scene = bd.Scene(drop=bd.Drop(height=0.0))
    with pytest.raises(ValueError, match="C0"):
        bd.housing_impact(scene)
    flags = jax.jit(lambda s: bd.housing_impact(s).flags)(scene)
    assert int(flags) & bd.Flag.SEPARATING_CONTACT


def test_housing_impact_gradients_finite_at_ties():
    # Orientation exactly at a flat landing: the chosen piece's gradient, finite.
    def f(th):
        s = bd.Scene(drop=bd.Drop(orientation=th), placement=bd.Placement(), board=bd.Board(length=0.06))
        hit = bd.housing_impact(s)
        return jnp.sum(bd.support_jumps(s, hit))

    for th in (0.0, math.pi / 2, 1e-3, math.pi / 2 - 1e-3):
        g = jax.grad(f)(jnp.asarray(th))
        assert np.isfinite(g)
