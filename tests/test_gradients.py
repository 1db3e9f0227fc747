"""Exact gradients of the peak, sensitivities, the smooth peak, and the placement optimiser against a grid."""

import json
import math
import textwrap
from collections import Counter

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.optimize import minimize

import beamdrop_jax as bd

NUMERICS = bd.Numerics(n_modes=6)
# Additive scale for fields whose value is zero (relative perturbation would not move them).
ZERO_SCALE = {
    "placement.centre": 1e-3,
    "placement.angle": 0.01,
    "drop.spin": 1.0,
    "drop.horizontal_speed": 0.1,
    "board.axial_force": 1.0,
    "board.damping_ratio": 0.01,
}


# A plane section refuses a tilt, a depth offset or motion out of the plane (tests/test_box_drops.py differentiates the
# tilt on a box).
BOX_ONLY = ("drop.tilt", "placement.depth_offset", "drop.side_speed", "drop.spin_x", "drop.spin_y")


def _scales(scene):
    def scale(path, leaf):
        name = ".".join(str(getattr(p, "name", p)) for p in path)
        if name in BOX_ONLY and not scene.housing.is_box:
            return jnp.zeros_like(leaf)
        zero = ZERO_SCALE.get(name, 1.0)
        return jnp.where(jnp.asarray(leaf) != 0, jnp.abs(leaf), zero)

    return jax.tree_util.tree_map_with_path(scale, scene)


def _perturbed(z, scene, scales):
    # The rigid law's gradients: on "auto" a traced objective would compile the landing's path too (where these
    # drops, far from flat, never go; test_contact_models.py checks the landing's gradients).
    scene = eqx.tree_at(lambda s: s.contact, scene, scene.contact.with_model("rigid"))
    leaves, treedef = jax.tree_util.tree_flatten(scene)
    parts, start = [], 0
    for v, s in zip(leaves, jax.tree_util.tree_leaves(scales)):
        size = int(np.size(v))
        parts.append(v + s * z[start : start + size].reshape(np.shape(v)))
        start += size
    return jax.tree_util.tree_unflatten(treedef, parts)


@eqx.filter_jit
def _f(z, scene, scales, peak):
    return peak(_perturbed(z, scene, scales), NUMERICS)


_grad_f = eqx.filter_jit(jax.grad(_f))
_f_batch = eqx.filter_jit(jax.vmap(_f, in_axes=(0, None, None, None)))


def dimensionless(scene, peak=bd.peak_stress):
    """f(z) = peak(scene + scale * z): every field perturbed in its own units, so one eps suits all. Returns
    (value, gradient, central differences) at z = 0 with step 1e-6, each compiled once for all scenes."""
    scales = _scales(scene)
    n = sum(int(np.size(v)) for v in jax.tree_util.tree_leaves(scene))
    z = jnp.zeros(n)
    E = jnp.eye(n) * 1e-6
    fd = (_f_batch(E, scene, scales, peak) - _f_batch(-E, scene, scales, peak)) / 2e-6
    return _f(z, scene, scales, peak), _grad_f(z, scene, scales, peak), fd


@jax.jit
def _impacts(batch):
    axes = jax.tree_util.tree_map(lambda v: 0 if jnp.ndim(v) and jnp.shape(v)[0] == 2048 else None, batch)
    return jax.vmap(bd.housing_impact, in_axes=(axes,))(batch)


def _random_scene(rng, size):
    """`size` random drops as one batched scene (every field an array of shape (size,))."""
    u = lambda lo, hi: rng.uniform(lo, hi, size)  # noqa: E731
    return bd.Scene(
        board=bd.Board(length=u(0.06, 0.09), damping_ratio=u(0, 0.05), axial_force=u(-20, 20)),
        placement=bd.Placement(centre=np.stack([u(-0.02, 0.02), u(-0.01, 0.01)], -1), angle=u(-0.1, 0.1)),
        drop=bd.Drop(orientation=u(0.1, 2 * math.pi - 0.1), height=u(0.5, 2.0), spin=u(-30, 30),
                     horizontal_speed=u(-2, 2)),
        # The rigid law's gradients (exact to 1e-5): "rigid", as a few drops with a fast spin would have their far
        # corner strike within the contact (test_contact_models.py tests the landing's gradients).
        contact=bd.Contact(friction=u(0.0, 1.2), restitution=u(0.1, 0.9), duration=u(2e-4, 1e-3), model="rigid"),
    )


def generic_scenes(n_per_mode=10, seed=7):
    """Random valid scenes, at least n_per_mode in each Routh mode, over several striking corners (candidates
    drawn and classified in batches, one compiled impact for all)."""
    rng = np.random.default_rng(seed)
    found, corners, scenes = Counter(), Counter(), []
    while min(found[m] for m in bd.ImpactMode) < n_per_mode:
        batch = _random_scene(rng, 2048)
        hit = jax.device_get(_impacts(batch))
        for i in range(2048):
            th = float(batch.drop.orientation[i])
            if abs(math.sin(2 * th)) < 0.2:
                continue
            mode = bd.ImpactMode(int(hit.impact.mode[i]))
            # Generic: away from the mode boundaries (stick point not within 2 % of the ends or compression).
            pn_s, pn_c, pn_f = (float(v[i]) for v in (hit.impact.Pn_stick, hit.impact.Pn_compression,
                                                        hit.impact.P[:, 1]))
            if mode != bd.ImpactMode.SLIDING and min(abs(pn_s - pn_c), abs(pn_s - pn_f), pn_s) < 0.02 * pn_f:
                continue
            if found[mode] >= n_per_mode:
                continue
            found[mode] += 1
            corners[tuple(np.sign(np.asarray(hit.corner[i])))] += 1
            scenes.append(jax.tree_util.tree_map(lambda v: v[i] if jnp.ndim(v) and jnp.shape(v)[0] == 2048 else v,
                                                 batch))
    return scenes, corners


@pytest.fixture(scope="module")
def scenes():
    return generic_scenes()


def test_gradients_equal_central_differences(scenes):
    scenes, corners = scenes
    assert len(scenes) >= 50 and len(corners) >= 3
    for scene in scenes:
        _, g, fd = dimensionless(scene)
        err = float(jnp.max(jnp.abs(g - fd))) / float(jnp.max(jnp.abs(g)))
        assert err <= 1e-5, (err, np.asarray(g), np.asarray(fd))
        assert np.all(np.isfinite(np.asarray(g)))


def test_check_grads_reverse_mode(scenes):
    scenes, _ = scenes
    for scene in scenes[::10]:
        scales = _scales(scene)
        n = sum(int(np.size(v)) for v in jax.tree_util.tree_leaves(scene))
        f = lambda z: _f(z, scene, scales, bd.peak_stress)  # noqa: E731
        value = float(f(jnp.zeros(n)))
        check_grads(f, (jnp.zeros(n),), order=1, modes=["rev"], eps=1e-6, atol=1e-5 * value, rtol=1e-5)


def test_eager_reverse_mode_and_forward_mode_equal_central_differences():
    # An eager jax.grad and jax.jvp reach the peak's derivative rule by other routes than the compiled gradient.
    scene = bd.Scene.default().replace(**{"drop.spin": 5.0, "board.damping_ratio": 0.02, "drop.horizontal_speed": 0.5})
    _, _, fd = dimensionless(scene)
    scales = _scales(scene)
    f = lambda z: bd.peak_stress(_perturbed(z, scene, scales), NUMERICS)  # noqa: E731
    z = jnp.zeros(fd.shape[0])
    scale = float(jnp.abs(fd).max())
    np.testing.assert_allclose(jax.grad(f)(z), fd, atol=1e-5 * scale)
    direction = jnp.asarray(np.random.default_rng(3).normal(size=fd.shape[0]))
    value, slope = jax.jvp(f, (z,), (direction,))
    assert float(value) == pytest.approx(float(bd.peak_stress(scene, NUMERICS)), rel=1e-12)
    assert float(slope) == pytest.approx(float(fd @ direction), abs=1e-5 * scale * float(jnp.abs(direction).sum()))


@pytest.mark.parametrize("peak", [bd.peak_strain, bd.peak_deflection])
def test_strain_and_deflection_gradients(peak):
    scene = bd.Scene.default().replace(**{"drop.spin": 5.0, "board.damping_ratio": 0.02})
    _, g, fd = dimensionless(scene, peak)
    np.testing.assert_allclose(g, fd, atol=1e-5 * float(jnp.abs(g).max()))


def test_gradients_finite_at_boundaries():
    base = bd.Scene.default()
    grad = jax.jit(jax.grad(lambda s: bd.peak_stress(s, NUMERICS)))
    cases = [
        base,  # S0 = 0
        base.replace(**{"drop.orientation": 0.0}),  # flat landing tie
        base.replace(**{"drop.orientation": math.pi / 2}),
        base.replace(**{"contact.friction": 0.0}),
        base.replace(**{"contact.restitution": 0.0}),
        base.replace(**{"contact.duration": 0.0}),  # ideal impulse
    ]
    for scene in cases:
        g = grad(scene)
        assert all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree_util.tree_leaves(g))


def test_diffrax_gradient_equals_closed_form(users_compile):
    """Compiled as users' programs are: XLA's unoptimised CPU code, which the test run uses to compile faster,
    leaves the derivative through the adaptive diffrax solve off by up to 4e-4 of the closed form's where the
    value still agrees to 1e-10 (and the error does not fall with rtol), while optimised code converges with rtol
    (1.8e-7 at rtol 1e-10, 1.3e-8 at 1e-12)."""
    out = users_compile(textwrap.dedent("""
        import json
        import equinox as eqx
        import jax
        jax.config.update("jax_enable_x64", True)
        import beamdrop_jax as bd
        scene = bd.Scene.default().replace(**{"board.damping_ratio": 0.02, "drop.spin": 3.0})
        scene = eqx.tree_at(lambda s: s.contact, scene, scene.contact.with_model("rigid"))  # traced: one path
        closed = bd.Numerics(n_modes=4)
        numeric = bd.Numerics(n_modes=4, method="diffrax", solver="Dopri8", rtol=1e-10, atol=1e-14, max_steps=20000)
        g_closed = jax.jit(jax.grad(lambda s: bd.peak_stress(s, closed)))(scene)
        g_numeric = jax.jit(jax.grad(lambda s: bd.peak_stress(s, numeric)))(scene)
        print(json.dumps(dict(peak=float(bd.peak_stress(scene, closed)),
                              closed=[v.tolist() for v in jax.tree_util.tree_leaves(g_closed)],
                              numeric=[v.tolist() for v in jax.tree_util.tree_leaves(g_numeric)])))
    """))
    got = json.loads(out.strip().splitlines()[-1])
    for a, b in zip(got["closed"], got["numeric"]):
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * got["peak"])


def test_sensitivities_obey_dimensional_analysis():
    rows = {r.field: r for r in bd.sensitivities(bd.Scene.default())}
    # Peak stress ~ impact velocity ~ sqrt(drop height); the impulse scales with (1 + e); the housing mass cancels
    # (support jumps are P/m with P ~ m); the board width cancels (EI and rho A both ~ b).
    np.testing.assert_allclose(rows["drop.height"].elasticity, 0.5, rtol=1e-9)
    np.testing.assert_allclose(rows["contact.restitution"].elasticity, 0.5 / 1.5, rtol=1e-9)
    assert abs(rows["housing.mass"].elasticity) < 1e-9
    assert abs(rows["board.width"].elasticity) < 1e-9
    # Thickness and contact duration enter the peak only through f1 tau and E h: equal elasticities.
    np.testing.assert_allclose(rows["board.thickness"].elasticity, rows["contact.duration"].elasticity, rtol=1e-6)


def test_smooth_peak_bias_is_bounded():
    scene = bd.Scene.default()
    numerics = bd.Numerics(n_modes=6)
    true = float(bd.peak_stress(scene, numerics))
    nx, nt = numerics.grid_shape()
    for temperature in (0.001, 0.01):
        smooth = float(bd.smooth_peak_stress(scene, numerics, temperature))
        grid_max_lower = true * 0.98
        assert grid_max_lower <= smooth <= true * (1 + temperature * math.log(nx * nt)) * 1.0001
    g = jax.grad(lambda s: bd.smooth_peak_stress(s, numerics, 0.01))(scene)
    assert all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree_util.tree_leaves(g))
    # The stress is linear in the impact speed sqrt(2 g h): d/dh = value / (2 h), exactly.
    value, height = float(bd.smooth_peak_stress(scene, numerics, 0.01)), float(scene.drop.height)
    np.testing.assert_allclose(float(g.drop.height), value / (2 * height), rtol=1e-9)


# ----------------------------------------------------------------------------------------------------------------
# The optimiser finds what a brute-force search finds.


@pytest.mark.parametrize("objective", ["mean", "max"])
def test_optimizer_matches_grid_search(objective):
    scene = bd.Scene.default()
    orientations = np.radians([20.0, 45.0, 70.0])
    numerics = bd.Numerics(n_modes=4)
    drops = bd.drop_set(scene, orientations)
    f = jax.jit(bd.placement_objective(scene, drops, objective, numerics=numerics))
    f_batch = jax.jit(jax.vmap(bd.placement_objective(scene, drops, objective, numerics=numerics)))

    # Dense grid over the whole feasible set (in the optimiser's own feasible parametrisation), then polish.
    b1 = np.arctanh(np.linspace(-0.97, 0.97, 15))
    b2 = np.arctanh(np.linspace(-0.95, 0.95, 7))
    a = np.arctanh(np.linspace(-0.97, 0.97, 13))
    U = np.stack(np.meshgrid(b1, b2, a, indexing="ij"), -1).reshape(-1, 3)
    values = np.asarray(f_batch(jnp.asarray(U)))
    grid_evals = len(U)
    polish = minimize(lambda u: float(f(jnp.asarray(u))), U[values.argmin()], method="Nelder-Mead",
                      options=dict(xatol=1e-4, fatol=1e-3 * values.min(), maxiter=400))
    reference = min(values.min(), polish.fun)
    grid_evals += polish.nfev

    res = bd.optimize_placement(scene, orientations, objective=objective, numerics=numerics, steps=60, starts=4,
                                progress=False)
    assert float(res.value) <= reference * 1.01, (float(res.value), reference)
    assert res.n_evaluations < grid_evals
    # Never outside the housing.
    ends = np.asarray(bd.board_ends(res.placement, scene.board.length))
    assert np.all(np.abs(ends[:, 0]) <= 0.075 + 1e-12) and np.all(np.abs(ends[:, 1]) <= 0.0375 + 1e-12)
    print(f"{objective}: optimiser {float(res.value):.6g} Pa in {res.n_evaluations} evaluations; grid+polish "
          f"{reference:.6g} Pa in {grid_evals}")


def test_margin_keeps_clearance_and_cvar_is_between_mean_and_max():
    scene = bd.Scene.default()
    res = bd.optimize_placement(scene, np.radians([30.0, 60.0]), objective="cvar", alpha=0.5, steps=20, starts=2,
                                numerics=bd.Numerics(n_modes=4), margin=0.005, progress=False)
    ends = np.asarray(bd.board_ends(res.placement, scene.board.length))
    assert np.all(np.abs(ends[:, 0]) <= 0.075 - 0.005 + 1e-12)
    assert np.all(np.abs(ends[:, 1]) <= 0.0375 - 0.005 + 1e-12)
    v = jnp.array([1.0, 4.0, 2.0, 3.0])
    np.testing.assert_allclose(bd.risk(v, "cvar", 0.5), 3.5)
    np.testing.assert_allclose(bd.risk(v, "cvar", 0.0), 2.5)
    np.testing.assert_allclose(bd.risk(v, "cvar", 0.75), 4.0)
    # The objective as a traced index (one compiled program for all three): same values and gradients, by hand.
    by_index = jax.jit(jax.value_and_grad(lambda v, i, a: bd.risk(v, i, a)))
    for i, (value, grad) in enumerate([(2.5, [0.25] * 4), (4.0, [0, 1, 0, 0]), (3.5, [0, 0.5, 0, 0.5])]):
        got = by_index(v, jnp.asarray(i), 0.5)
        np.testing.assert_allclose(got[0], value)
        np.testing.assert_allclose(got[1], grad)
    with pytest.raises(ValueError, match="objective"):
        bd.optimize_placement(scene, objective="median")
    with pytest.raises(ValueError, match="Board.length"):
        bd.optimize_placement(scene, margin=0.03)
