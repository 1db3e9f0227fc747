"""End-to-end `simulate`: against a hand calculation and a brute-force grid; batching; flags under jit."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import beamdrop_jax as bd
from references import darboux_keller, dense_impulse_peak, impulse_curvature, point_velocity
from test_scene import random_scenes

G = 9.80665


def test_simulate_against_hand_calculation():
    # A board at an angle and off centre, ideal impulse, 4 modes: support jumps by hand, then a brute-force peak.
    W, H, m = 0.15, 0.075, 0.18
    k = math.sqrt((W * W + H * H) / 12)
    theta, h, mu, e = math.radians(25), 1.0, 0.3, 0.5
    c, phi, L = np.array([0.01, 0.005]), math.radians(10), 0.09
    scene = bd.Scene(
        board=bd.Board(length=L),
        placement=bd.Placement(centre=c, angle=phi),
        drop=bd.Drop(orientation=theta, height=h),
        contact=bd.Contact(friction=mu, restitution=e, duration=0.0),
    )
    e1 = np.array([math.cos(theta), math.sin(theta)])
    e2 = np.array([-math.sin(theta), math.cos(theta)])
    S = -W / 2 * e1 - H / 2 * e2  # lowest corner for 0 < theta < 90 deg
    x, y = -S
    inertia = m * k * k
    B = np.array([[1 / m + y * y / inertia, -x * y / inertia], [-x * y / inertia, 1 / m + x * x / inertia]])
    Pt, Pn, _ = darboux_keller(B, np.array([0.0, -math.sqrt(2 * G * h)]), mu, e)
    dv_G = np.array([Pt, Pn]) / m
    dw = (S[0] * Pn - S[1] * Pt) / inertia
    axis = np.array([math.cos(phi), math.sin(phi)])
    t_hat = axis[0] * e1 + axis[1] * e2
    n_hat = np.array([-t_hat[1], t_hat[0]])
    ends = [c - L / 2 * axis, c + L / 2 * axis]
    dvA, dvB = (point_velocity(dv_G, dw, q[0] * e1 + q[1] * e2) @ n_hat for q in ends)

    res = bd.simulate(scene, bd.Numerics(n_modes=4))
    np.testing.assert_allclose(res.support_jumps, (dvA, dvB), rtol=1e-12)
    np.testing.assert_allclose(res.impulse.P, (Pt, Pn), rtol=1e-12)
    EI = 22e9 * 0.05 * 1e-9 / 12
    window = 2 * math.pi / (math.pi / L) ** 2 / math.sqrt(EI / (1900 * 0.05e-3))
    np.testing.assert_allclose(res.window, window, rtol=1e-12)
    stress, _, _ = dense_impulse_peak(dvA, dvB, EI, 1900 * 0.05e-3, L, 22e9, 1e-3, 4, window)
    # The brute-force grid (800 x 40000 cells) can only undershoot, by at most ~(2 pi / cells per wave)^2 / 2.
    assert stress * (1 - 1e-9) <= float(res.peak.stress) <= stress * (1 + 2e-5)
    # Where: the reference field at the reported point carries the reported peak (this free vibration has near-equal
    # maxima at other places, so the dense grid's pick need not be the reported one).
    curv = impulse_curvature(dvA, dvB, EI, 1900 * 0.05e-3, L, 4, float(res.peak.x), float(res.peak.t))
    np.testing.assert_allclose(22e9 * 1e-3 / 2 * abs(curv[0, 0]), float(res.peak.stress), rtol=1e-7)
    np.testing.assert_allclose(res.peak.strain, res.peak.stress / 22e9, rtol=1e-12)


def test_default_scene_numbers():
    res = bd.simulate(bd.Scene.default())
    assert int(res.flags) == 0 and bool(res.converged)
    # DESIGN.md: the half-sine drop converges to 68.7 MPa by 4-8 modes.
    np.testing.assert_allclose(res.peak.stress, 68.7e6, rtol=1e-3)
    assert int(res.n_modes) == 6 and int(res.check_modes) == 12
    ref = bd.simulate(bd.Scene.default(), bd.Numerics(n_modes=32))
    np.testing.assert_allclose(res.peak.stress, ref.peak.stress, rtol=2 * float(res.error_estimate) + 1e-6)


def test_ideal_impulse_grows_with_modes():
    scene = bd.Scene.default().replace(**{"contact.duration": 0.0})
    peaks = [float(bd.simulate(scene, bd.Numerics(n_modes=n)).peak.stress) for n in (4, 16, 64)]
    assert peaks[0] < peaks[1] < peaks[2]
    # DESIGN.md: 82 MPa with 4 modes, 97 with 16.
    np.testing.assert_allclose(peaks[:2], [82e6, 97e6], rtol=0.01)
    res = bd.simulate(scene)
    assert not bool(res.converged) and int(res.n_modes) == 16


def test_a_pulse_too_short_for_the_board_to_tell_is_the_ideal_impulse():
    """A contact no longer than `IMPULSE_DURATION` (1e-12 s) is the ideal impulse, eagerly and under `jit`, with
    finite gradients (a 1e-292 s pulse's amplitude pi / (2 tau) overflowed: its peak was 0 and its gradients NaN);
    a 1e-9 s pulse is a pulse, within (omega tau)^2 of the impulse."""
    numerics = bd.Numerics(n_modes=6)
    impulse = bd.Scene.default().replace(**{"contact.duration": 0.0})
    value = jax.jit(lambda s: bd.peak_stress(s, numerics))
    grad = jax.jit(jax.grad(lambda s: bd.peak_stress(s, numerics)))
    reference = float(bd.peak_stress(impulse, numerics))
    for tau in (1e-292, 1e-13, 1e-9):
        scene = impulse.replace(**{"contact.duration": tau})
        for peak in (bd.peak_stress(scene, numerics), value(scene)):
            np.testing.assert_allclose(float(peak), reference, rtol=1e-7 if tau == 1e-9 else 1e-12)
        leaves = jax.tree_util.tree_leaves(grad(scene))
        assert all(np.all(np.isfinite(np.asarray(g))) for g in leaves), (tau, leaves)


def test_vmap_simulate_equals_loop():
    batch = random_scenes(24, seed=3)
    numerics = bd.Numerics(n_modes=6)
    batched = jax.jit(jax.vmap(lambda s: bd.simulate(s, numerics).peak.stress))(batch)
    loop = [float(bd.simulate(jax.tree_util.tree_map(lambda v: v[i], batch), numerics).peak.stress) for i in range(24)]
    np.testing.assert_allclose(batched, loop, rtol=1e-12)


def test_flags_under_jit_and_eager_errors():
    scene = bd.Scene.default()
    scene = bd.Scene(scene.housing, scene.board, scene.placement, scene.drop, scene.contact.with_model("rigid"))
    with pytest.raises(ValueError, match=r"contact.restitution = 1.5 .* \[0, 1\]"):
        scene.replace(**{"contact.restitution": 1.5})
    bad = eqx.tree_at(lambda s: s.contact.restitution, scene, jnp.asarray(1.5))
    res = jax.jit(bd.simulate)(bad)
    assert int(res.flags) & bd.Flag.RESTITUTION_RANGE
    assert np.isnan(float(res.peak.stress))
    flat = scene.replace(**{"drop.orientation": 0.0, "drop.spin": 2.0})
    res = jax.jit(bd.simulate)(flat)
    assert int(res.flags) & bd.Flag.FLAT_LANDING_WITH_MOTION
    with pytest.raises(ValueError, match="flat on a face"):
        bd.simulate(flat)
    with pytest.raises(ValueError, match="C0"):
        bd.simulate(scene.replace(**{"drop.height": 0.0}))


def test_fields_agree_with_peak():
    scene = bd.Scene.default()
    res = bd.simulate(scene)
    f = bd.response_fields(scene, nx=201, nt=2001)
    assert f.stress.shape == (201, 2001)
    # The grid maximum is below the refined peak and close to it.
    grid_max = float(np.abs(f.stress).max())
    assert grid_max <= float(res.peak.stress) * (1 + 1e-9)
    assert grid_max >= 0.98 * float(res.peak.stress)
    np.testing.assert_allclose(np.abs(f.deflection).max(), res.peak.deflection, rtol=0.02)
    np.testing.assert_allclose(f.strain * 22e9, f.stress, rtol=1e-12)


def test_sampled_drive_response_is_exact():
    """The board's modal response to a sampled drive (the compliant landing's: linear between samples, zero after
    the last) in closed form per interval, against SciPy's DOP853 on the modal equations with the same forcing,
    integrated interval by interval (rtol 1e-12): q, q' and q'' at times between, on and after uneven samples,
    undamped and damped, from a start with modal velocities, to 1e-9 of the largest."""
    from scipy.integrate import solve_ivp

    from beamdrop_jax._response.sampled import SampledModes

    rng = np.random.default_rng(7)
    t = np.sort(np.concatenate([[0.0], rng.uniform(0.0, 2e-3, 30)]))
    omega, end = np.array([700.0, 2900.0, 9000.0]), 3e-3
    force = rng.normal(size=(t.size, 3)) * 1e3
    query = np.sort(np.concatenate([rng.uniform(0.0, end, 16), t[[3, 17, -1]]]))
    for zeta in (0.0, 0.05):
        v0 = rng.normal(size=3)
        modes = SampledModes(*map(jnp.asarray, (t, force, omega, zeta, v0)))
        found = np.stack([np.concatenate(modes.jet(jnp.asarray(s))) for s in query])

        def rhs(s, y, f, slope, s0):
            return np.concatenate([y[3:], f + slope * (s - s0) - 2 * zeta * omega * y[3:] - omega**2 * y[:3]])

        y, expected = np.concatenate([np.zeros(3), v0]), []
        edges = np.append(t, end)
        for j in range(t.size):
            last = j == t.size - 1
            f = np.zeros(3) if last else force[j]
            slope = np.zeros(3) if last else (force[j + 1] - force[j]) / (t[j + 1] - t[j])
            sol = solve_ivp(rhs, (edges[j], edges[j + 1]), y, method="DOP853", rtol=1e-12, atol=1e-16,
                            args=(f, slope, edges[j]), dense_output=True)
            for s in query[(query >= edges[j]) & ((query < edges[j + 1]) | last)]:
                state = sol.sol(s)
                expected.append(np.concatenate([state, rhs(s, state, f, slope, edges[j])[3:]]))
            y = sol.y[:, -1]
        expected = np.array(expected)
        scale = np.abs(expected).max(axis=0)
        np.testing.assert_allclose(found / scale, expected / scale, rtol=0, atol=1e-9)
