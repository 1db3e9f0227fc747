"""The 3D single-vertex impact law (`impulse_3d`): its planar reduction to Routh's law, energy and the friction
cone, gradients against central differences, eager errors. Every forward evaluation runs through one compiled,
vmapped program of a fixed batch size (`_batch`), and the gradients through one more."""

import functools

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

import beamdrop_jax as bd
from references import random_contact

BATCH = 64  # every batched call is padded to this size: one program for all of them


@functools.cache
def _program():
    def both(K, u0, mu, e):
        return bd.impulse_3d(K, u0, mu, e, "poisson"), bd.impulse_3d(K, u0, mu, e, "stronge")

    return jax.jit(jax.vmap(both))


def _batch(K, u0, mu, e):
    """(poisson, stronge) results of up to BATCH contacts, as NumPy, in one call of the shared program."""
    K, u0, mu, e = (np.asarray(x, dtype=float) for x in (K, u0, mu, e))
    n = len(mu)
    assert n <= BATCH
    pad = np.arange(BATCH) % n  # repeat the cases to fill the batch
    out = _program()(K[pad], u0[pad], mu[pad], e[pad])
    return tuple(jax.tree_util.tree_map(lambda x: np.asarray(x)[:n], r) for r in out)


def _planar_K(B, k22):
    """K decoupled from t2 whose (t1, n) block is Routh's B."""
    K = np.zeros((3, 3))
    K[np.ix_([0, 2], [0, 2])] = B
    K[1, 1] = k22
    return K


@pytest.fixture(scope="module")
def planar_cases():
    """30 random planar contacts (Routh's conventions: B = [[B1, -B3], [-B3, B2]], v0 = (S0, C0)) covering every
    slip mode under both laws (sliding; stick and reversal, each in compression and in restitution; S0 = 0)."""
    rng = np.random.default_rng(314)
    cases, modes = [], {}
    while len(cases) < 30:
        B, v0, mu, e = random_contact(rng)
        mode = int(bd.routh_impulse(B, v0, mu, e).mode)
        if modes.get(mode, 0) >= 7 and len(modes) < len(bd.ImpactMode):
            continue  # leave room for the rarer modes
        modes[mode] = modes.get(mode, 0) + 1
        cases.append((B, v0, mu, e, rng.uniform(0.5, 5.0)))
    assert set(modes) == {int(m) for m in bd.ImpactMode} and any(v0[0] == 0 for _, v0, *_ in cases), modes
    return cases


def test_planar_inputs_reduce_to_routh(planar_cases):
    K = np.array([_planar_K(B, k22) for B, _, _, _, k22 in planar_cases])
    u0 = np.array([[v0[0], 0.0, v0[1]] for _, v0, *_ in planar_cases])
    mu = np.array([c[2] for c in planar_cases])
    e = np.array([c[3] for c in planar_cases])
    results = dict(zip(("poisson", "stronge"), _batch(K, u0, mu, e)))
    worst = 0.0
    for law, res in results.items():
        assert not res.flags.any()
        for i, (B, v0, mu_i, e_i, _) in enumerate(planar_cases):
            ref = bd.routh_impulse(B, v0, mu_i, e_i, law=law)
            P2 = np.asarray(ref.P)
            scale = np.abs(P2).max()
            assert res.P[i, 1] == 0.0 and res.velocity[i, 1] == 0.0  # stays in the plane, exactly
            err = np.abs(res.P[i, [0, 2]] - P2).max() / scale
            worst = max(worst, err)
            assert err <= 1e-10, (law, i, res.P[i], P2, bd.ImpactMode(int(ref.mode)).label)
            assert abs(res.Pn_compression[i] - float(ref.Pn_compression)) <= 1e-10 * scale
            assert abs(res.energy_change[i] - float(ref.energy_change)) <= 1e-10 * abs(float(ref.energy_change)) + 1e-14
            stuck = int(ref.mode) in (bd.ImpactMode.STICK_IN_COMPRESSION, bd.ImpactMode.STICK_IN_RESTITUTION)
            assert bool(res.sticks[i]) == stuck, (law, i)
    print(f"planar reduction: largest relative error {worst:.2e}")


# A random rigid body and contact: K = 1/m + [r]x^T I^-1 [r]x rotated into a random contact frame.
_unit = st.floats(-1.0, 1.0)


@st.composite
def _contacts(draw):
    m = draw(st.floats(0.1, 5.0))
    inertia = np.array([draw(st.floats(0.02, 1.0)) for _ in range(3)]) * m
    q = np.array([draw(_unit) for _ in range(4)]) + np.array([1e-3, 0, 0, 0])
    w, x, y, z = q / np.linalg.norm(q)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    r = np.array([draw(_unit) for _ in range(3)])
    X = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    K = np.eye(3) / m + X.T @ R @ np.diag(1 / inertia) @ R.T @ X
    K = 0.5 * (K + K.T)
    slip = draw(st.sampled_from(["none", "t1", "any"]))
    u_t = {"none": [0.0, 0.0], "t1": [draw(st.floats(-3, 3)), 0.0], "any": [draw(st.floats(-3, 3)) for _ in range(2)]}
    u0 = np.array([*u_t[slip], -draw(st.floats(0.05, 3.0))])
    return K, u0, draw(st.floats(0.0, 2.0)), draw(st.floats(0.0, 1.0))


@settings(max_examples=25, deadline=None)
@given(st.lists(_contacts(), min_size=1, max_size=BATCH))
def test_energy_is_never_created_and_the_cone_holds(contacts):
    K, u0, mu, e = (np.array(x) for x in zip(*contacts))
    for res in _batch(K, u0, mu, e):
        assert not res.flags.any()
        scale = np.einsum("ni,nij,nj->n", res.P, K, res.P)  # 2 x the kinetic energy the impulse carries
        assert np.all(res.energy_change <= 1e-10 * scale), res.energy_change / scale
        P_t = np.linalg.norm(res.P[:, :2], axis=1)
        assert np.all(P_t <= mu * res.P[:, 2] * (1 + 1e-10) + 1e-14)
        assert np.all(res.P[:, 2] > 0)
        bad = res.velocity[:, 2] < -1e-10 * np.abs(u0[:, 2])  # the contact separates (or stops), never approaches
        assert not bad.any(), (K[bad], u0[bad], mu[bad], e[bad], res.velocity[bad], res.P[bad])


K_GRAD = np.array([[2.5, 0.1, -1.5], [0.1, 1.0, 0.2], [-1.5, 0.2, 2.5]])
GRAD_CASES = {  # (u0, mu, e): slides throughout; slip stops at Pn = 0.2558 and sticks
    "sliding": (np.array([-0.5, 0.2, -1.0]), 0.3, 0.5),
    "stick": (np.array([0.2, 0.1, -1.0]), 0.9, 0.6),
}
WEIGHTS = np.array([1.0, -2.0, 3.0])


def test_gradients_match_central_differences():
    def objective(K, u0, mu, e):
        res = bd.impulse_3d(K, u0, mu, e)
        return res.P @ WEIGHTS + res.energy_change

    grad = jax.jit(jax.grad(objective, argnums=(0, 1, 2, 3)))
    h = 1e-6
    sym = [(i, j) for i in range(3) for j in range(i, 3)]
    rows, labels = [], []
    for name, (u0, mu, e) in GRAD_CASES.items():
        for sign in (1.0, -1.0):
            for i, j in sym:  # K stays symmetric: perturb both (i, j) and (j, i)
                dK = np.zeros((3, 3))
                dK[i, j] = dK[j, i] = sign * h
                rows.append((K_GRAD + dK, u0, mu, e))
            for i in range(3):
                rows.append((K_GRAD, u0 + sign * h * np.eye(3)[i], mu, e))
            rows.append((K_GRAD, u0, mu + sign * h, e))
            rows.append((K_GRAD, u0, mu, e + sign * h))
        labels.append(name)
    K, U, M, E = (np.array(x) for x in zip(*rows))
    res = _batch(K, U, M, E)[0]
    values = res.P @ WEIGHTS + res.energy_change
    per_case = 2 * (len(sym) + 5)
    for c, name in enumerate(labels):
        u0, mu, e = GRAD_CASES[name]
        g = grad(jnp.asarray(K_GRAD), jnp.asarray(u0), jnp.asarray(mu), jnp.asarray(e))
        assert all(np.all(np.isfinite(np.asarray(x))) for x in g), name
        gK = np.asarray(g[0])
        analytic = [gK[i, j] + (gK[j, i] if i != j else 0.0) for i, j in sym] + list(np.asarray(g[1])) + [
            float(g[2]), float(g[3])]
        v = values[c * per_case:(c + 1) * per_case]
        half = per_case // 2
        fd = (v[:half] - v[half:]) / (2 * h)
        np.testing.assert_allclose(analytic, fd, rtol=1e-6, atol=1e-7, err_msg=name)
    assert res.sticks[per_case] and not res.sticks[0] and np.isinf(res.Pn_stick[0])


@pytest.mark.parametrize(
    "args, field",
    [
        ((np.eye(2), [0.0, 0.0, -1.0], 0.3, 0.5), "K"),
        ((np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), [0.0, 0.0, -1.0], 0.3, 0.5), "K"),
        ((np.diag([1.0, -1.0, 1.0]), [0.0, 0.0, -1.0], 0.3, 0.5), "K"),
        ((np.eye(3), [0.0, -1.0], 0.3, 0.5), "u0"),
        ((np.eye(3), [np.nan, 0.0, -1.0], 0.3, 0.5), "u0"),
        ((np.eye(3), [0.0, 0.0, -1.0], -0.1, 0.5), "friction"),
        ((np.eye(3), [0.0, 0.0, -1.0], 0.3, 1.5), "restitution"),
        ((np.eye(3), [0.0, 0.0, -1.0], [0.3, 0.4], 0.5), "friction"),
    ],
)
def test_eager_errors_name_the_field(args, field):
    with pytest.raises(ValueError, match=rf"^{field}\b"):
        bd.impulse_3d(*args)


def test_law_is_checked_and_a_separating_contact_gets_no_impulse():
    with pytest.raises(ValueError, match="law = 'newton'"):
        bd.impulse_3d(np.eye(3), [0.0, 0.0, -1.0], 0.3, 0.5, law="newton")
    res = _batch(np.eye(3)[None], [[0.3, 0.0, 0.5]], [0.3], [0.5])[0]
    assert np.all(res.P == 0) and res.flags[0] == bd.Flag.SEPARATING_CONTACT
