"""Beam end conditions: exact modes against published roots and independent quadrature, the transient against an
independent finite-element discretisation (OpenSees), and the end conditions through scenes, files and studies."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

import beamdrop_jax as bd
import beamdrop_jax._board.beam  # noqa: F401 - `bd._board...` below, before any call has loaded it
import beamdrop_jax._response.pulses  # noqa: F401

# Roots b = beta L of the characteristic equations (Blevins, Formulas for natural frequency and mode shape, table 8-1).
ROOTS = {
    "pinned": (math.pi, 2 * math.pi, 3 * math.pi),
    "clamped": (4.73004074, 7.85320462, 10.99560784),
    "clamped-pinned": (3.92660231, 7.06858275, 10.21017612),
    "pinned-clamped": (3.92660231, 7.06858275, 10.21017612),
    "clamped-free": (1.87510407, 4.69409113, 7.85475744),
}


@pytest.mark.parametrize("ends", bd.ENDS)
def test_frequencies_are_the_published_roots(ends):
    board = bd.Board(ends=ends)
    omega = np.asarray(bd.natural_frequencies(board, 3))
    scale = math.sqrt(float(board.bending_stiffness) / float(board.mass_per_length)) / 0.1**2
    np.testing.assert_allclose(omega, np.square(ROOTS[ends]) * scale, rtol=2e-8)


def _textbook_shape(ends, b):
    """Blevins' unnormalised mode shape phi(xi) on [0, 1] with clamped (or pinned) end A."""
    if ends == "pinned":
        return lambda xi: math.sin(b * xi)
    if ends == "clamped-free":
        sigma = (math.cosh(b) + math.cos(b)) / (math.sinh(b) + math.sin(b))
    else:
        sigma = (math.cosh(b) - math.cos(b)) / (math.sinh(b) - math.sin(b))
    shape = lambda xi: math.cosh(b * xi) - math.cos(b * xi) - sigma * (math.sinh(b * xi) - math.sin(b * xi))  # noqa: E731
    return (lambda xi: shape(1 - xi)) if ends == "pinned-clamped" else shape


@pytest.mark.parametrize("ends", bd.ENDS)
def test_participation_and_shapes_against_quadrature(ends):
    board = bd.Board(ends=ends)
    p = np.asarray(bd._board.base.support_participation(board, 3))
    assert np.all(p[:, 2] == 0.0)  # a beam has no width: the roll input does not drive it
    p = p[:, :2]
    x = np.linspace(0.0, 0.1, 7)
    shapes = np.asarray(bd._board.beam.mode_shapes(board, jnp.asarray(x), 3))
    curvature = np.asarray(bd._board.beam.mode_shapes(board, jnp.asarray(x), 3, curvature=True)
                           * bd._board.base.curvature_scale(board, 3))
    for k, b in enumerate(ROOTS[ends]):
        phi = _textbook_shape(ends, b)
        norm = math.sqrt(0.5 / quad(lambda s: phi(s) ** 2, 0, 1, epsabs=1e-13)[0])
        pA = -2 * norm * quad(lambda s: (1 - s) * phi(s), 0, 1, epsabs=1e-13)[0]
        pB = -2 * norm * quad(lambda s: s * phi(s), 0, 1, epsabs=1e-13)[0]
        # The sign of a mode is a convention: compare through the product p phi, which enters the response.
        sign = np.sign(pA if abs(pA) > 1e-6 else pB) * np.sign(p[k, 0] if abs(p[k, 0]) > 1e-6 else p[k, 1])
        np.testing.assert_allclose(p[k], sign * np.array([pA, pB]), rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(shapes[:, k], sign * norm * np.array([phi(v / 0.1) for v in x]), atol=1e-7)
        # Curvature: phi'' by central differences of the textbook shape.
        h = 1e-4
        d2 = [(phi(v / 0.1 + h) - 2 * phi(v / 0.1) + phi(v / 0.1 - h)) / h**2 / 0.1**2 for v in x[1:-1]]
        np.testing.assert_allclose(curvature[1:-1, k], sign * norm * np.array(d2), rtol=1e-4, atol=1e-3 * b**2 / 0.01)


@pytest.mark.parametrize("ends", ["clamped", "clamped-pinned", "pinned-clamped", "clamped-free"])
def test_clamped_board_peak_at_the_clamp_agrees_with_opensees(ends):
    # OpenSees: 40 beam elements, clamps driven to turn with the chord, Newmark at 2 us (independent of the modes).
    board, motion = bd.Board(ends=ends), bd.HalfSine(3.0, 1.0, 5e-4)
    res = bd.board_response(board, motion, bd.Numerics(n_modes=24))
    fe = bd.opensees_board_response(board, motion, float(res.window), n_elements=40, dt=2e-6)
    np.testing.assert_allclose(fe.frequencies, np.asarray(res.frequencies[:4]), rtol=3e-5)  # FE mesh: O(h^4)
    np.testing.assert_allclose(fe.stress, float(res.peak.stress), rtol=1e-3)
    clamp = 0.0 if ends.startswith("clamped") and (ends != "clamped" or fe.x < 0.05) else 0.1
    assert float(res.peak.x) == pytest.approx(clamp, abs=1e-9) and fe.x == pytest.approx(clamp, abs=1e-9)
    np.testing.assert_allclose(fe.stress_at(float(res.peak.x), float(res.peak.t)), float(res.peak.stress), rtol=1e-3)


def test_clamped_free_static_limit_is_the_cantilever_formula():
    # A long pulse on a cantilever's clamp (both ends' rigid motion equal): quasi-static root moment
    # M = rho A a L^2 / 2, so the peak strain tends to (h/2) M / EI with the overshoot of a slow pulse.
    board = bd.Board(ends="clamped-free")
    a = 200.0
    tau = 40 / float(bd.natural_frequencies(board, 1)[0] / (2 * math.pi))  # f1 tau = 40
    res = bd.board_response(board, bd.HalfSine.from_peak(a, tau), bd.Numerics(n_modes=8))
    static = 1e-3 / 2 * float(board.mass_per_length) * a * 0.1**2 / 2 / float(board.bending_stiffness)
    assert float(res.peak.x) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(float(res.peak.strain), static, rtol=0.03)


def test_buckling_load_follows_the_ends():
    euler = 4 * math.pi**2 * float(bd.Board().bending_stiffness) / 0.1**2
    bd.Board(ends="clamped", axial_force=-0.99 * euler)
    with pytest.raises(ValueError, match="axial_force"):
        bd.Board(ends="clamped", axial_force=-1.01 * euler)
    with pytest.raises(ValueError, match="did you mean 'clamped'"):
        bd.Board(ends="clamp")
    with pytest.raises(ValueError, match="pinned ends only"):
        bd.board_response(bd.Board(ends="clamped"), bd.HalfSine(1.0, 1.0, 5e-4),
                          bd.Numerics(method="diffrax", stretching=True))


def test_axial_force_on_clamped_board_is_the_rayleigh_quotient():
    # Galerkin on the unloaded mode: omega^2 = (EI b^4 / L^4 + N g / L^2) / rho A with g = int phi'^2 / int phi^2;
    # for a clamped-clamped first mode g = 12.3026 (Blevins' beam functions).
    board = bd.Board(ends="clamped", axial_force=50.0)
    omega = float(bd.natural_frequencies(board, 1)[0])
    b = ROOTS["clamped"][0]
    phi = _textbook_shape("clamped", b)
    dphi = lambda s, h=1e-6: (phi(s + h) - phi(s - h)) / (2 * h)  # noqa: E731
    g = quad(lambda s: dphi(s) ** 2, 0, 1)[0] / quad(lambda s: phi(s) ** 2, 0, 1)[0]
    expected = (float(board.bending_stiffness) * b**4 / 0.1**4 + 50.0 * g / 0.1**2) / float(board.mass_per_length)
    np.testing.assert_allclose(omega**2, expected, rtol=1e-7)
    assert g == pytest.approx(12.3026, rel=1e-4)


def test_ends_through_scene_files_simulate_and_gradients(tmp_path):
    scene = bd.Scene.default().replace(**{"board.length": 0.09})
    scene = bd.Scene(housing=scene.housing, board=bd.Board(length=0.09, ends="clamped-pinned"),
                     placement=scene.placement, drop=scene.drop, contact=scene.contact)
    path = tmp_path / "clamped.toml"
    bd.save_scene(scene, path)
    assert 'ends = "clamped-pinned"' in path.read_text()
    loaded = bd.load_scene(path)
    assert loaded.board.ends == "clamped-pinned"
    (tmp_path / "bad.toml").write_text('extends = "default"\n[board]\nends = "clamped-pined"\n')
    with pytest.raises(ValueError, match="did you mean 'clamped-pinned'"):
        bd.load_scene(tmp_path / "bad.toml")
    res = bd.simulate(loaded)
    assert float(res.peak.x) in (0.0, 0.09) or float(res.peak.stress) > 0
    # The gradient of the peak with respect to the board's length and the placement against central differences.
    numerics = bd.Numerics(n_modes=8)
    f = lambda L, c: bd.peak_stress(loaded.replace(**{"board.length": L, "placement.centre": c}), numerics)  # noqa: E731
    L0, c0 = jnp.asarray(0.09), jnp.asarray(loaded.placement.centre)
    gL, gc = jax.grad(f, argnums=(0, 1))(L0, c0)
    h = 1e-6
    fdL = (f(L0 + h, c0) - f(L0 - h, c0)) / (2 * h)
    fdc = (f(L0, c0 + jnp.array([h, 0.0])) - f(L0, c0 - jnp.array([h, 0.0]))) / (2 * h)
    np.testing.assert_allclose(gL, fdL, rtol=1e-5)
    np.testing.assert_allclose(gc[0], fdc, rtol=1e-5)


def test_superposed_montecarlo_on_an_asymmetric_board_matches_per_drop_search():
    scene = bd.Scene.default()
    scene = bd.Scene(housing=scene.housing, board=bd.Board(ends="clamped-free"), placement=scene.placement,
                     drop=scene.drop, contact=scene.contact.with_model("rigid"))  # the first strike's paths
    key = jax.random.PRNGKey(3)
    fast = bd.montecarlo(scene, 256, key, progress=False)  # every direction searched: no mirror symmetry here
    dense = bd.montecarlo(scene, 256, key, superpose=False, numerics=bd.table_numerics(scene), progress=False)
    lean = bd.montecarlo(scene, 256, key, superpose=False, progress=False)  # montecarlo_numerics
    ok = np.isfinite(np.asarray(dense.peak_stress))
    assert ok.sum() > 200
    ratio = np.asarray(fast.peak_stress)[ok] / np.asarray(dense.peak_stress)[ok]
    assert ratio.max() <= 1 + 1e-9 and ratio.min() >= 1 - 1e-4, (ratio.min(), ratio.max())
    np.testing.assert_allclose(np.asarray(lean.peak_stress)[ok], np.asarray(dense.peak_stress)[ok], rtol=1e-3)
