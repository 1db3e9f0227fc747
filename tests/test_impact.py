"""Routh's impact law against an independent Darboux-Keller integrator, published vectors and physical laws."""

from collections import Counter

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from jax.test_util import check_grads

import beamdrop_jax as bd
import beamdrop_jax._impact.routh  # noqa: F401 - `bd._impact` below, before any call has loaded it
from references import darboux_keller, random_contact

B_PUBLIC = np.array([[2.5, -1.5], [-1.5, 2.5]])


@pytest.fixture(scope="module")
def random_cases():
    rng = np.random.default_rng(20081)
    cases = [random_contact(rng) for _ in range(2500)]
    stacked = tuple(jnp.asarray(np.array(x)) for x in zip(*cases))
    return cases, stacked


@pytest.mark.parametrize("law", bd._impact.routh.LAWS)
def test_against_darboux_keller(random_cases, law):
    cases, (B, v0, mu, e) = random_cases
    res = jax.jit(jax.vmap(lambda *a: bd.routh_impulse(*a, law=law)))(B, v0, mu, e)
    modes = Counter()
    for i, case in enumerate(cases):
        Pt, Pn, mode = darboux_keller(*case, law=law)
        ref = np.array([Pt, Pn])
        err = np.linalg.norm(np.asarray(res.P[i]) - ref) / np.linalg.norm(ref)
        assert err <= 1e-10, (i, case, res.P[i], ref)
        assert bd.ImpactMode(int(res.mode[i])).name == mode
        modes[mode] += 1
    # Every Wang-Mason mode is exercised, each many times.
    assert set(modes) == {m.name for m in bd.ImpactMode}
    assert min(modes.values()) >= 30, modes


@pytest.mark.parametrize(
    "S0, mu, e, P, mode",
    [
        (-0.5, 0.3, 0.8, (0.263415, 0.878049), bd.ImpactMode.SLIDING),
        (0.2, 0.8, 1.0, (0.58, 1.1), bd.ImpactMode.STICK_IN_COMPRESSION),
    ],
)
def test_public_vectors(S0, mu, e, P, mode):
    res = bd.routh_impulse(B_PUBLIC, jnp.array([S0, -1.0]), mu, e)
    np.testing.assert_allclose(res.P, P, atol=5e-7)
    assert int(res.mode) == mode


def test_uniform_rod_at_45_degrees():
    # Rod m = 1, length 1, I = 1/12; lower end strikes at 45 deg, 1 m/s, no spin, mu = 0.3, e = 0.5.
    r = 0.5 * np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
    B = bd.contact_matrix(jnp.asarray(r), 1.0, 1.0 / 12.0)
    np.testing.assert_allclose(B, B_PUBLIC, rtol=1e-14)
    res = bd.routh_impulse(B, jnp.array([0.0, -1.0]), 0.3, 0.5)
    np.testing.assert_allclose(res.P, (0.219512, 0.731707), atol=5e-7)
    w_after = (r[1] * res.P[0] - r[0] * res.P[1]) * 12.0
    np.testing.assert_allclose(w_after, -2.173060, atol=5e-7)


def test_thesis_chapter4_inputs():
    # Thesis eqs. 4.10-4.12 and chapter 5's e = 0.8. The thesis prints (-1.8, 2.55): its figure 4.2 was read by eye
    # and its termination Pn = 2.55 is not (1 + e) times the compression impulse 1/0.541042 = 1.8483 (that is 3.3269).
    B = np.array([[0.5, -7e-5], [-7e-5, 0.541]])
    res = bd.routh_impulse(B, jnp.array([1.0, -1.0]), 0.6, 0.8)
    np.testing.assert_allclose(res.P, (-1.9961, 3.3269), atol=5e-5)
    assert int(res.mode) == bd.ImpactMode.SLIDING
    np.testing.assert_allclose(res.Pn_compression, 1 / (0.541 + 0.6 * 7e-5), rtol=1e-12)


def test_newton_creates_energy_in_documented_case():
    # Slip stops in compression and sticks; Newton's C_f = -e C0 with e = 1 then gives dT = +7/64 J (hand-derived
    # in the routh_impulse docstring). Poisson and Stronge on the same case lose energy.
    v0 = jnp.array([0.5, -1.0])
    newton = bd.routh_impulse(B_PUBLIC, v0, 0.8, 1.0, law="newton")
    np.testing.assert_allclose(newton.P, (0.4375, 1.0625), rtol=1e-12)
    np.testing.assert_allclose(newton.energy_change, 7 / 64, rtol=1e-12)
    for law in ("poisson", "stronge"):
        assert bd.routh_impulse(B_PUBLIC, v0, 0.8, 1.0, law=law).energy_change <= 1e-15


def test_edge_cases_are_finite_and_exact():
    B = B_PUBLIC
    # mu = 0: frictionless, Pt = 0, Pn = (1 + e) m_eff |C0| with m_eff = 1/B2.
    res = bd.routh_impulse(B, jnp.array([0.7, -1.0]), 0.0, 0.5)
    np.testing.assert_allclose(res.P, (0.0, 1.5 / 2.5), rtol=1e-14)
    # e = 0: ends at maximum compression, where C = 0.
    res = bd.routh_impulse(B, jnp.array([-0.5, -1.0]), 0.3, 0.0)
    np.testing.assert_allclose(res.velocity[1], 0.0, atol=1e-14)
    # mu exactly at |B3|/B1 with S0 = 0: sliding and sticking coincide (dPt/dPn = B3/B1).
    res = bd.routh_impulse(B, jnp.array([0.0, -1.0]), 1.5 / 2.5, 0.5)
    np.testing.assert_allclose(res.velocity[0], 0.0, atol=1e-14)
    np.testing.assert_allclose(res.P[0] / res.P[1], 1.5 / 2.5, rtol=1e-14)
    # S0 = 0 with friction able to hold: sticks from the start.
    res = bd.routh_impulse(B, jnp.array([0.0, -1.0]), 0.9, 0.5)
    assert int(res.mode) == bd.ImpactMode.STICK_IN_COMPRESSION
    # S0 = 0, B3 < 0: slides towards +x (s = -sign(B3) = +1 means S grows positive).
    Bm = np.array([[2.5, 1.5], [1.5, 2.5]])
    res = bd.routh_impulse(Bm, jnp.array([0.0, -1.0]), 0.3, 0.5)
    assert res.velocity[0] > 0 and res.P[0] < 0
    # C0 > 0 separates: no impulse, flagged.
    res = bd.routh_impulse(B, jnp.array([0.3, 0.2]), 0.3, 0.5)
    np.testing.assert_array_equal(res.P, 0.0)
    assert int(res.flags) & bd.Flag.SEPARATING_CONTACT


def test_painleve_type_case_ends_on_stick_line():
    # B2 + s mu B3 < 0: C decreases while sliding; the path must reach the stick line before compression ends.
    B = np.array([[2.0, -1.9], [-1.9, 2.0]])  # B3 = 1.9; s = -1 makes B2 - mu B3 < 0 for mu > 1.05
    v0 = jnp.array([-1.0, -1.0])
    mu = 1.5
    res = bd.routh_impulse(B, v0, mu, 0.5)
    assert B[1, 1] - mu * 1.9 < 0
    Pt, Pn, mode = darboux_keller(B, np.asarray(v0), mu, 0.5)
    np.testing.assert_allclose(res.P, (Pt, Pn), rtol=1e-12)
    assert int(res.mode) == bd.ImpactMode.STICK_IN_COMPRESSION
    # C0 = 0 in the same case: friction drives a "tangential impact" with a non-zero impulse.
    res0 = bd.routh_impulse(B, jnp.array([-1.0, 0.0]), mu, 0.5)
    Pt0, Pn0, _ = darboux_keller(B, np.array([-1.0, 0.0]), mu, 0.5)
    assert res0.P[1] > 0
    np.testing.assert_allclose(res0.P, (Pt0, Pn0), rtol=1e-12)


def test_float32_matches_float64():
    with jax.enable_x64(False):
        res32 = bd.routh_impulse(B_PUBLIC.astype(np.float32), jnp.array([0.2, -1.0]), 0.8, 1.0)
        assert res32.P.dtype == jnp.float32
    np.testing.assert_allclose(res32.P, (0.58, 1.1), rtol=2e-6)


# ----------------------------------------------------------------------------------------------------------------
# Laws that must always hold.

contact = st.builds(
    lambda m, k, x, y, S0, C0: (
        np.array([[1 / m + y * y / (m * k * k), -x * y / (m * k * k)], [-x * y / (m * k * k), 1 / m + x * x / (m * k * k)]]),
        np.array([S0, C0]),
    ),
    m=st.floats(0.05, 5.0),
    k=st.floats(0.02, 1.0),
    x=st.floats(-1.0, 1.0),
    y=st.floats(0.005, 1.0),
    S0=st.one_of(st.just(0.0), st.floats(-5.0, 5.0)),
    C0=st.floats(-5.0, -0.01),
)


_GRADS = {
    law: jax.jit(
        jax.grad(lambda B, v0, mu, e, law=law: jnp.sum(bd.routh_impulse(B, v0, mu, e, law=law).P), argnums=(0, 1, 2, 3))
    )
    for law in bd._impact.routh.LAWS
}
_IMPULSES = {law: jax.jit(lambda B, v0, mu, e, law=law: bd.routh_impulse(B, v0, mu, e, law=law)) for law in bd._impact.routh.LAWS}


@settings(max_examples=500, deadline=None)
@given(contact, st.floats(0.0, 3.0), st.floats(0.0, 1.0), st.sampled_from(["poisson", "stronge"]))
def test_energy_never_created_and_cone_respected(c, mu, e, law):
    B, v0 = c
    res = _IMPULSES[law](jnp.asarray(B), jnp.asarray(v0), jnp.asarray(mu), jnp.asarray(e))
    P = np.asarray(res.P)
    scale = 0.5 * v0 @ np.linalg.solve(B, v0)  # kinetic energy of the contact-point motion
    assert float(res.energy_change) <= 1e-12 * scale
    assert P[1] >= 0
    assert abs(P[0]) <= mu * P[1] * (1 + 1e-12) + 1e-15
    assert float(res.velocity[1]) >= -1e-12 * np.abs(v0).max()
    assert np.all(np.isfinite(P))


@settings(max_examples=300, deadline=None)
@given(contact, st.floats(0.0, 3.0), st.floats(0.0, 1.0), st.sampled_from(bd._impact.routh.LAWS))
def test_gradients_finite_everywhere(c, mu, e, law):
    B, v0 = c
    grads = _GRADS[law](jnp.asarray(B), jnp.asarray(v0), jnp.asarray(mu), jnp.asarray(e))
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g))), (B, v0, mu, e, law, grads)


# ----------------------------------------------------------------------------------------------------------------
# Gradients: exact at generic points of every mode, finite on the boundaries.

GENERIC = {
    bd.ImpactMode.SLIDING: (B_PUBLIC, (-0.5, -1.0), 0.3, 0.8),
    bd.ImpactMode.STICK_IN_COMPRESSION: (B_PUBLIC, (0.2, -1.0), 0.8, 0.7),
    bd.ImpactMode.STICK_IN_RESTITUTION: (B_PUBLIC, (1.0, -1.0), 0.8, 0.9),
    bd.ImpactMode.REVERSAL_IN_COMPRESSION: (B_PUBLIC, (0.5, -1.0), 0.3, 0.6),
    bd.ImpactMode.REVERSAL_IN_RESTITUTION: (B_PUBLIC, (1.0, -1.0), 0.3, 0.9),
}


@pytest.mark.parametrize("law", bd._impact.routh.LAWS)
@pytest.mark.parametrize("mode", list(GENERIC))
def test_gradients_match_finite_differences(mode, law):
    B, v0, mu, e = GENERIC[mode]
    args = (jnp.asarray(B), jnp.asarray(v0), jnp.asarray(mu), jnp.asarray(e))
    assert int(bd.routh_impulse(*args, law=law).mode) == mode

    def f(B, v0, mu, e):
        B = 0.5 * (B + B.T)
        res = bd.routh_impulse(B, v0, mu, e, law=law)
        return jnp.concatenate([res.P, res.energy_change[None]])

    check_grads(f, args, order=1, modes=["rev"], eps=1e-6, atol=1e-7, rtol=1e-7)


def test_gradients_finite_on_mode_boundaries():
    def f(S0, mu, e):
        return jnp.sum(bd.routh_impulse(B_PUBLIC, jnp.stack([S0, -1.0]), mu, e).P)

    grad = jax.grad(f, argnums=(0, 1, 2))
    points = [
        (0.0, 0.3, 0.5),  # S0 = 0, sliding
        (0.0, 0.9, 0.5),  # S0 = 0, sticking
        (0.0, 0.6, 0.5),  # mu = |B3|/B1
        (0.3, 0.6, 0.5),  # mu = |B3|/B1 with slip
        (0.2, 0.0, 0.5),  # mu = 0
        (-0.5, 0.3, 0.0),  # e = 0
        # Stick exactly at maximum compression: Pn_s = S0/(mu B1 + B3) = Pn_c.
        (0.4 * 3.5 / 3.7, 0.8, 0.7),
    ]
    for p in points:
        g = grad(*map(jnp.asarray, p))
        assert all(np.isfinite(np.asarray(x)) for x in g), (p, g)
    g = jax.grad(lambda e: bd.routh_impulse(B_PUBLIC, jnp.array([-0.5, -1.0]), 0.3, e, law="stronge").P[1])(0.0)
    assert np.isfinite(g)


def test_unknown_law_is_named():
    with pytest.raises(ValueError, match="poisson, newton, stronge"):
        bd.routh_impulse(B_PUBLIC, jnp.array([0.0, -1.0]), 0.3, 0.5, law="routh")
