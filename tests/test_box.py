"""A box housing's single-vertex strike (`box_impact`): its inertia, attitude and lowest vertex against NumPy brute
force, its contact matrix against the velocity a unit impulse gives a rigid body, the plane section's answer at a
symmetric edge landing, energy, the friction cone, an elastic frictionless strike, the rigid-motion field at a
plate's mounts, and gradients in the angles against central differences.

Every impact runs eagerly through `impulse_3d`'s one compiled program (both laws share it); the gradients add one
more program."""

import itertools

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

import beamdrop_jax as bd
from beamdrop_jax._impact.kinematics import lowest_corner_at

MASS, WIDTH, HEIGHT, DEPTH = 0.18, 0.15, 0.075, 0.012


# ---------------------------------------------------------------------------------------------------------------
# Independent NumPy references.


def _attitude(orientation, tilt):
    """Rx(tilt) @ Rz(orientation) from the two textbook rotations."""
    c, s = np.cos(orientation), np.sin(orientation)
    ct, st = np.cos(tilt), np.sin(tilt)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, ct, -st], [0.0, st, ct]])
    return Rx @ Rz


def _vertices(width, height, depth):
    return np.array(list(itertools.product((-width / 2, width / 2), (-height / 2, height / 2),
                                           (-depth / 2, depth / 2))))


def _kinetic_energy(mass, inertia_world, v, w):
    return 0.5 * mass * v @ v + 0.5 * w @ inertia_world @ w


def _uniform_box_inertia(mass, width, height, depth):
    """Principal moments by 2-point Gauss-Legendre quadrature per axis (exact for the quadratic integrands)."""
    g = np.array([-1.0, 1.0]) / np.sqrt(3.0)
    pts = np.array(list(itertools.product(g * width / 2, g * height / 2, g * depth / 2)))
    x, y, z = pts.T
    return mass * np.array([np.mean(y**2 + z**2), np.mean(x**2 + z**2), np.mean(x**2 + y**2)])


def _random_drop(rng):
    """A generic attitude (no level axis), approach state, friction and restitution; the vertex approaches."""
    while True:
        orientation, tilt = rng.uniform(0, 2 * np.pi), rng.uniform(-1.4, 1.4)
        R = _attitude(orientation, tilt)
        if np.min(np.abs(R[1])) < 0.05:
            continue
        dims = rng.uniform([0.05, 0.02, 0.005], [0.3, 0.15, 0.1])
        v = np.array([rng.uniform(-1, 1), rng.uniform(-5, -0.5), rng.uniform(-1, 1)])
        w = rng.uniform(-20, 20, 3)
        verts = _vertices(*dims) @ R.T
        r = verts[np.argmin(verts[:, 1])]
        if (v + np.cross(w, r))[1] < -0.05:
            return {"orientation": orientation, "tilt": tilt, "dims": dims, "velocity": v, "spin": w, "r": r,
                    "R": R, "friction": rng.uniform(0, 1), "restitution": rng.uniform(0, 1)}


def _hit(d, law="poisson", friction=None, restitution=None):
    W, H, D = d["dims"]
    return bd.box_impact(MASS, W, H, D, None, d["orientation"], d["tilt"], d["velocity"], d["spin"],
                         d["friction"] if friction is None else friction,
                         d["restitution"] if restitution is None else restitution, law=law)


def _after(d, hit):
    """World-frame state after the impact and the inertia tensor, from the test's own attitude."""
    R = d["R"]
    inertia_world = R @ np.diag(_uniform_box_inertia(MASS, *d["dims"])) @ R.T
    return d["velocity"] + np.asarray(hit.dV), d["spin"] + np.asarray(hit.dOmega), inertia_world


@pytest.fixture(scope="module")
def drops():
    rng = np.random.default_rng(2024)
    return [_random_drop(rng) for _ in range(24)]


# ---------------------------------------------------------------------------------------------------------------
# Geometry.


def test_inertia_and_attitude():
    np.testing.assert_allclose(bd.box_inertia(MASS, WIDTH, HEIGHT, DEPTH),
                               _uniform_box_inertia(MASS, WIDTH, HEIGHT, DEPTH), rtol=1e-14)
    # The box's third moment is the plane section's default m k^2.
    assert np.isclose(bd.box_inertia(MASS, WIDTH, HEIGHT, DEPTH)[2], bd.Housing(WIDTH, HEIGHT, MASS).inertia,
                      rtol=1e-14)
    for orientation, tilt in [(0.3, 0.0), (2.5, 0.7), (-1.2, -0.4)]:
        R = np.asarray(bd.box_attitude(orientation, tilt))
        np.testing.assert_allclose(R, _attitude(orientation, tilt), atol=1e-15)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
        assert np.isclose(np.linalg.det(R), 1.0)
    # At tilt = 0 the in-plane axes are the plane code's exactly; the tilt turns +y towards +z.
    R0 = np.asarray(bd.box_attitude(0.3, 0.0))
    np.testing.assert_array_equal(R0[:2, :2], np.asarray(bd.body_axes(jnp.asarray(0.3))).T)
    np.testing.assert_allclose(np.asarray(bd.box_attitude(0.0, 0.2)) @ [0, 1, 0], [0, np.cos(0.2), np.sin(0.2)])
    np.testing.assert_allclose(bd.box_vertices(WIDTH, HEIGHT, DEPTH), _vertices(WIDTH, HEIGHT, DEPTH))


_lowest_batch = jax.jit(jax.vmap(bd.lowest_vertex, in_axes=(0, 0, None, None, None)))


@settings(max_examples=20, deadline=None)
@given(st.floats(0.02, 0.5), st.floats(0.02, 0.5), st.floats(0.002, 0.3), st.integers(0, 2**31))
def test_lowest_vertex_is_the_brute_force_lowest(width, height, depth, seed):
    rng = np.random.default_rng(seed)
    orientation, tilt = rng.uniform(-7, 7, 64), rng.uniform(-4, 4, 64)
    got = _lowest_batch(orientation, tilt, width, height, depth)
    verts = _vertices(width, height, depth)
    for i in range(64):
        y = verts @ _attitude(orientation[i], tilt[i]).T
        order = np.argsort(y[:, 1])
        if np.asarray(got.tied[i]):
            continue
        assert int(got.index[i]) == order[0]
        np.testing.assert_allclose(got.r[i], y[order[0]], atol=1e-15)
        np.testing.assert_allclose(got.vertex[i], verts[order[0]], atol=0)
        np.testing.assert_allclose(got.clearance[i], y[order[1], 1] - y[order[0], 1], rtol=1e-12, atol=1e-16)


def test_lowest_vertex_at_tilt_zero_is_the_plane_corner_on_an_edge():
    for orientation in (0.4, 2.0, -2.9, 4.0):
        lv = bd.lowest_vertex(orientation, 0.0, WIDTH, HEIGHT, DEPTH)
        _, r_plane, _ = lowest_corner_at(jnp.asarray(orientation), WIDTH, HEIGHT)
        assert bool(lv.tied) and float(lv.clearance) == 0.0
        np.testing.assert_allclose(lv.r[:2], -np.asarray(r_plane), atol=1e-16)  # the plane's r is G - S


def test_contact_matrix_is_the_velocity_a_unit_impulse_gives(drops):
    for d in drops[:6]:
        inertia_world = d["R"] @ np.diag(_uniform_box_inertia(MASS, *d["dims"])) @ d["R"].T
        K = np.asarray(bd.vertex_contact_matrix(d["r"], MASS, inertia_world))
        # Column j: the contact point's velocity change (t1, t2, n) = (x, z, y) for a unit impulse along t_j.
        axes = np.eye(3)[[0, 2, 1]]
        ref = np.array([(a / MASS + np.cross(np.linalg.solve(inertia_world, np.cross(d["r"], a)), d["r"]))
                        @ axes.T for a in axes]).T
        np.testing.assert_allclose(K, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


# ---------------------------------------------------------------------------------------------------------------
# Impacts.


@pytest.mark.parametrize("law", ["poisson", "stronge"])
def test_symmetric_edge_landing_is_the_plane_answer(law):
    """At tilt = 0 with motion in the plane, the lowest edge struck at mid-depth is the plane section's corner."""
    worst = 0.0
    housing = bd.Housing(WIDTH, HEIGHT, MASS)
    for orientation, vx, vy, spin, mu, e in [(0.4, 0.0, -3.0, 0.0, 0.3, 0.5), (2.0, 0.8, -2.0, 5.0, 0.1, 0.9),
                                            (-2.5, -0.5, -4.0, -12.0, 0.8, 0.2), (4.3, 0.3, -1.0, 3.0, 0.0, 1.0)]:
        plane = bd.corner_impact(housing, bd.Contact(friction=mu, restitution=e), jnp.asarray(orientation),
                                 jnp.array([vx, vy]), jnp.asarray(spin), law=law)
        lv = bd.lowest_vertex(orientation, 0.0, WIDTH, HEIGHT, DEPTH)
        R = np.asarray(bd.box_attitude(orientation, 0.0))
        inertia_world = R @ np.diag(np.asarray(bd.box_inertia(MASS, WIDTH, HEIGHT, DEPTH))) @ R.T
        r_mid = np.asarray(lv.r) * [1.0, 1.0, 0.0]
        hit = bd.rigid_vertex_impact(r_mid, MASS, inertia_world, [vx, vy, 0.0], [0.0, 0.0, spin], mu, e, law=law)
        assert not int(hit.flags) and not int(plane.flags)
        box = np.array([hit.dV[0], hit.dV[1], hit.dOmega[2]])
        ref = np.array([plane.dv_G[0], plane.dv_G[1], plane.dw])
        worst = max(worst, np.abs(box - ref).max())
        assert np.abs(box - ref).max() <= 1e-10 * max(1.0, np.abs(ref).max()), (box, ref)
        assert np.abs(hit.dV[2]) < 1e-14 and np.abs(hit.dOmega[:2]).max() < 1e-12  # stays in the plane
    print(f"{law}: largest difference from the plane section {worst:.2e}")


def test_energy_friction_cone_and_frames(drops):
    worst = {"energy": -np.inf, "cone": -np.inf, "frame": 0.0}
    ends = []
    for d in drops:
        T0 = _kinetic_energy(MASS, d["R"] @ np.diag(_uniform_box_inertia(MASS, *d["dims"])) @ d["R"].T,
                             d["velocity"], d["spin"])
        for law in ("poisson", "stronge"):
            hit = _hit(d, law)
            assert not int(hit.flags) and not bool(hit.tied)
            ends.append(bool(hit.impact.sticks))
            np.testing.assert_allclose(hit.r, d["r"], atol=1e-15)
            v, w, inertia_world = _after(d, hit)
            T1 = _kinetic_energy(MASS, inertia_world, v, w)
            worst["energy"] = max(worst["energy"], (T1 - T0) / T0)
            assert T1 <= T0 * (1 + 1e-9), (T0, T1, law)
            np.testing.assert_allclose(T1 - T0, hit.impact.energy_change, rtol=1e-7, atol=1e-10 * T0)
            P = np.asarray(hit.P)
            mu = d["friction"]
            worst["cone"] = max(worst["cone"], np.hypot(P[0], P[2]) - mu * P[1])
            assert P[1] > 0 and np.hypot(P[0], P[2]) <= mu * P[1] * (1 + 1e-9) + 1e-15
            # The world-frame jumps move the struck point as the law's contact velocity says, axis by axis.
            u_after = v + np.cross(w, d["r"])
            u_law = np.asarray(hit.impact.velocity)[[0, 2, 1]]
            worst["frame"] = max(worst["frame"], np.abs(u_after - u_law).max())
            np.testing.assert_allclose(u_after, u_law, atol=1e-10 * np.abs(d["velocity"]).max())
    assert 0 < sum(ends) < len(ends)  # the sweep ends both stuck and sliding
    print(f"{sum(ends)} of {len(ends)} end stuck; largest relative energy gain, cone excess (N s), frame mismatch "
          f"(m/s): {worst}")


def test_frictionless_elastic_strike_reverses_the_normal_velocity(drops):
    worst = 0.0
    for d in drops[:10]:
        hit = _hit(d, "poisson", friction=0.0, restitution=1.0)
        v, w, inertia_world = _after(d, hit)
        T0 = _kinetic_energy(MASS, inertia_world, d["velocity"], d["spin"])
        T1 = _kinetic_energy(MASS, inertia_world, v, w)
        un0 = (d["velocity"] + np.cross(d["spin"], d["r"]))[1]
        un1 = (v + np.cross(w, d["r"]))[1]
        worst = max(worst, abs(T1 - T0) / T0, abs(un1 + un0) / abs(un0))
        assert abs(T1 - T0) <= 1e-9 * T0 and abs(un1 + un0) <= 1e-9 * abs(un0)
        assert np.asarray(hit.P)[[0, 2]].tolist() == [0.0, 0.0]
    print(f"frictionless elastic: largest relative energy change or normal-velocity mismatch {worst:.2e}")


MOUNTS = np.array([[q1, 0.01, q3] for q1 in (-0.06, 0.0, 0.06) for q3 in (-0.004, 0.004)] + [[0.03, 0.01, 0.0]])


def _mount_fit(hit):
    """Normal jumps at the mounts (board normal e2) and the least-squares plane a + b q1 + c q3 through them."""
    n = np.asarray(hit.attitude)[:, 1]
    dv_n = np.asarray(hit.body_point_velocity_jump(MOUNTS)) @ n
    A = np.column_stack([np.ones(len(MOUNTS)), MOUNTS[:, 0], MOUNTS[:, 2]])
    coef = np.linalg.lstsq(A, dv_n, rcond=None)[0]
    return dv_n, coef, np.abs(A @ coef - dv_n).max()


def test_mount_jumps_are_a_rigid_field_that_varies_across_the_depth():
    tilted = bd.box_impact(MASS, WIDTH, HEIGHT, DEPTH, None, 0.5, 0.3, [0.2, -3.0, 0.0], [0.0, 0.0, 2.0], 0.3, 0.5)
    dv_n, coef, residual = _mount_fit(tilted)
    moments = tuple(float(I) for I in bd.box_inertia(MASS, WIDTH, HEIGHT, DEPTH))
    given_inertia = bd.box_impact(MASS, WIDTH, HEIGHT, DEPTH, moments, 0.5, 0.3, [0.2, -3.0, 0.0], [0.0, 0.0, 2.0],
                                  0.3, 0.5)
    np.testing.assert_allclose(given_inertia.dOmega, tilted.dOmega, rtol=1e-13)
    assert residual < 1e-12 * np.abs(dv_n).max(), residual
    across = abs(coef[2]) * 0.008  # the change between the near and far mounts
    assert across > 0.02 * np.abs(dv_n).max(), (coef, dv_n)
    # The same points checked through the ground-frame method.
    p = MOUNTS @ np.asarray(tilted.attitude).T
    np.testing.assert_allclose(tilted.point_velocity_jump(p), np.asarray(tilted.dV) + np.cross(tilted.dOmega, p),
                               atol=1e-14)
    # A symmetric edge landing struck at mid-depth kicks near and far mounts alike.
    R = np.asarray(bd.box_attitude(0.5, 0.0))
    r_mid = np.asarray(bd.lowest_vertex(0.5, 0.0, WIDTH, HEIGHT, DEPTH).r) * [1.0, 1.0, 0.0]
    inertia_world = R @ np.diag(np.asarray(bd.box_inertia(MASS, WIDTH, HEIGHT, DEPTH))) @ R.T
    flat = bd.rigid_vertex_impact(r_mid, MASS, inertia_world, [0.2, -3.0, 0.0], [0.0, 0.0, 2.0], 0.3, 0.5,
                                  attitude=R)
    dv_n0, coef0, residual0 = _mount_fit(flat)
    assert residual0 < 1e-12 * np.abs(dv_n0).max() and abs(coef0[2]) * 0.008 < 1e-12 * np.abs(dv_n0).max()
    print(f"mount plane residual {residual:.1e}, near-far difference tilted {across:.4f} m/s of "
          f"{np.abs(dv_n).max():.3f}; mid-depth edge {abs(coef0[2]) * 0.008:.1e}")


def _mount_jump(orientation, tilt):
    hit = bd.box_impact(MASS, WIDTH, HEIGHT, DEPTH, None, orientation, tilt, jnp.array([0.3, -3.0, 0.1]),
                        jnp.array([1.0, 2.0, -3.0]), 0.3, 0.5)
    return hit.body_point_velocity_jump(jnp.array([0.06, 0.01, 0.004]))[1]


def test_gradients_in_the_angles_match_central_differences():
    angles = (0.4, 0.25)
    grad = jax.jit(jax.grad(_mount_jump, argnums=(0, 1)))(*map(jnp.asarray, angles))
    h = 1e-5
    fd = [(_mount_jump(*(a + h * (i == j) for j, a in enumerate(angles)))
           - _mount_jump(*(a - h * (i == j) for j, a in enumerate(angles)))) / (2 * h) for i in range(2)]
    rel = [abs(float(g) - float(f)) / abs(float(f)) for g, f in zip(grad, fd)]
    print(f"d(mount jump)/d(orientation, tilt) = {[float(g) for g in grad]}, FD relative differences {rel}")
    assert max(rel) < 1e-6, (grad, fd)


def test_float32_under_jit_and_vmap(drops):
    """The same drops in float32, batched: close to float64, float32 throughout, and flat landings say so."""
    cases = drops[:4]
    expected = [np.asarray(_hit(d).dV) for d in cases]
    stack = lambda key: np.array([d[key] for d in cases], dtype=np.float32)
    dims = stack("dims")
    with jax.enable_x64(False):
        run = jax.jit(jax.vmap(lambda W, H, D, th, ti, v, w, mu, e: bd.box_impact(
            MASS, W, H, D, None, th, ti, v, w, mu, e)))
        got = run(dims[:, 0], dims[:, 1], dims[:, 2], stack("orientation"), stack("tilt"), stack("velocity"),
                  stack("spin"), stack("friction"), stack("restitution"))
        assert got.dV.dtype == jnp.float32 and got.dOmega.dtype == jnp.float32 and not np.any(got.flags)
        edge = bd.lowest_vertex(np.float32(0.7), np.float32(0.0), WIDTH, HEIGHT, DEPTH)
        assert bool(edge.tied) and edge.r.dtype == jnp.float32
    err = max(np.abs(np.asarray(g) - x).max() / np.abs(x).max() for g, x in zip(got.dV, expected))
    print(f"float32 against float64: largest relative difference of dV {err:.1e}")
    assert err < 1e-4
