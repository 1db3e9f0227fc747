"""Compliant landing: against an event-driven SciPy reference, exact flat and single-corner answers, the rigid
law's limit as the contact shortens (sliding and sticking), energy, gradients and continuity through flat.

Two compiled programs serve the whole file: `_program` (the landing, vmapped over rows of parameters) and
`_grad_program` (with the gradient of the vertical velocity after it in every input); batches are padded to a
fixed size so that neither recompiles. About 40 s on the shared 2-core development machine with a cold
compilation cache, 30 s warm (most of it the reverse passes of the property test)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import beamdrop_jax as bd
from references import compliant_landing_reference

G = 9.80665
HOUSING = bd.Housing()  # 0.15 x 0.075 m, 0.18 kg, a uniform plate's inertia
FIELDS = ("width", "height", "mass", "k", "mu", "e", "tau", "theta", "vx", "vy", "w", "v_eps", "g")
ROWS = 8  # every batch is padded to this many rows


def row(theta, vx, vy, w=0.0, mu=0.3, e=0.5, tau=5e-4, v_eps=math.nan, g=G, housing=HOUSING):
    """One landing's parameters (`FIELDS`); v_eps NaN takes compliant_landing's default, 1e-3 V."""
    h = housing
    return [float(h.width), float(h.height), float(h.mass), float(h.radius_of_gyration), mu, e, tau, theta, vx, vy,
            w, v_eps, g]


def default_v_eps(p):
    """compliant_landing's default regularising speed for row p: 1e-3 V, V = sqrt(|v|^2 + (w R)^2)."""
    R = 0.5 * math.hypot(p[0], p[1])
    return 1e-3 * math.sqrt(p[8] ** 2 + p[9] ** 2 + (p[10] * R) ** 2)


def _landing(p):
    housing = bd.Housing(width=p[0], height=p[1], mass=p[2], radius_of_gyration=p[3])
    contact = bd.Contact(friction=p[4], restitution=p[5], duration=p[6])
    return bd.compliant_landing(housing, contact, p[7], p[8:10], p[10], v_eps=p[11], gravity=p[12])


@jax.jit
@jax.vmap
def _program(p):
    return _landing(p)


@jax.jit
@jax.vmap
def _grad_program(p):
    """The landing's numbers and the gradient of the vertical velocity after it in every parameter of the row
    (one reverse pass gives them all)."""

    def vy_after(p):
        res = _landing(p)
        return p[9] + res.dv_G[1], _numbers(res)

    (_, numbers), grad = jax.value_and_grad(vy_after, has_aux=True)(p)
    return {**numbers, "grad": grad}


def _numbers(res):
    return {"P": res.P, "dv": res.dv_G, "dw": res.dw, "contact_time": res.contact_time, "t_end": res.t_end,
            "energy": res.energy_change, "flags": res.flags, "steps": res.steps}


def _padded(rows):
    rows = np.asarray(rows, float)
    assert len(rows) <= ROWS
    return jnp.asarray(np.concatenate([rows, np.repeat(rows[-1:], ROWS - len(rows), axis=0)]))


def batch(rows, landings=False):
    """The landings of `rows` as NumPy arrays (and, with `landings`, the batched `Landing` itself)."""
    res = _program(_padded(rows))
    out = {key: np.asarray(value)[: len(rows)] for key, value in _numbers(res).items()}
    assert np.all(out["steps"] < 4096)
    return (out, res) if landings else out


def batch_grad(rows):
    """`batch` and the gradients (a second program: reverse mode costs some 7 times the landing)."""
    return {key: np.asarray(value)[: len(rows)] for key, value in _grad_program(_padded(rows)).items()}


def routh(p, law="stronge"):
    """The rigid law for the lowest corner of row p, and that corner's index."""
    W, H, m, k, mu, e, _, theta, vx, vy, w = p[:11]
    housing = bd.Housing(width=W, height=H, mass=m, radius_of_gyration=k)
    hit = bd.corner_impact(housing, bd.Contact(friction=mu, restitution=e, duration=0.0), theta,
                           jnp.array([vx, vy]), w, law=law)
    return hit, int(np.argmin(_corner_heights(W, H, theta)))


def _corner_heights(W, H, theta):
    """Heights from G of the corners (+W/2, +H/2), (-W/2, +H/2), (-W/2, -H/2), (+W/2, -H/2)."""
    q = np.array([[W / 2, H / 2], [-W / 2, H / 2], [-W / 2, -H / 2], [W / 2, -H / 2]])
    return q[:, 0] * math.sin(theta) + q[:, 1] * math.cos(theta)


# --------------------------------------------------------------------------------------------------------------
# 1. The SciPy reference: same model, written from the physics, integrated phase by phase with events.


def _reference_rows():
    rng = np.random.default_rng(20240611)
    rows, kinds = [], []
    for kind in ("corner", "corner", "corner", "corner", "near-flat", "near-flat", "flat", "flat"):
        W, H = rng.uniform(0.06, 0.3), rng.uniform(0.015, 0.12)
        housing = bd.Housing(width=W, height=H, mass=rng.uniform(0.05, 2.0),
                             radius_of_gyration=rng.uniform(0.8, 1.2) * math.sqrt((W * W + H * H) / 12))
        v0, tau = rng.uniform(2.0, 6.0), rng.uniform(2e-4, 1e-3)
        quarter = rng.integers(4) * math.pi / 2
        if kind == "corner":
            theta = quarter + rng.choice([-1, 1]) * math.radians(rng.uniform(8.0, 82.0))
            vx, w = rng.uniform(-1.5, 1.5), rng.uniform(-10.0, 10.0)
        elif kind == "near-flat":  # the second corner arrives while the first still pushes
            span = W if quarter % math.pi == 0 else H
            theta = quarter + rng.choice([-1, 1]) * rng.uniform(0.1, 0.5) * v0 * tau / span
            vx, w = rng.uniform(-0.5, 0.5), 0.0
        else:
            theta, vx, w = quarter, rng.uniform(-0.5, 0.5), rng.uniform(-3.0, 3.0)
        R = 0.5 * math.hypot(W, H)
        v_eps = 1e-2 * math.sqrt(vx * vx + v0 * v0 + (w * R) ** 2)  # a mild regularisation: SciPy's steps are slow
        rows.append(row(theta, vx, -v0, w, mu=rng.uniform(0.0, 0.9), e=rng.uniform(0.15, 1.0), tau=tau,
                        v_eps=v_eps, housing=housing))
        kinds.append(kind)
    return rows, kinds


def test_agrees_with_the_event_driven_reference():
    rows, kinds = _reference_rows()
    out = batch(rows)
    assert not np.any(out["flags"]), [bd.Flag.describe(f) for f in out["flags"]]
    overlapping = 0
    for i, (p, kind) in enumerate(zip(rows, kinds)):
        W, H, m, k, mu, e, tau, theta, vx, vy, w, v_eps, g = p
        ref = compliant_landing_reference(W, H, m, m * k * k, theta, (vx, vy), w, mu, e, tau, v_eps, g)
        assert ref["separated"], kind
        # Relative to the largest impulse: 1e-6 asked, 1e-11 measured (1e-8 here leaves room for other machines).
        scale = np.abs(ref["P"]).max()
        np.testing.assert_allclose(out["P"][i], ref["P"], rtol=0, atol=1e-8 * scale, err_msg=kind)
        np.testing.assert_allclose(out["dv"][i], ref["dv_G"], rtol=0, atol=1e-8 * scale / m, err_msg=kind)
        R = 0.5 * math.hypot(W, H)
        np.testing.assert_allclose(out["dw"][i], ref["dw"], rtol=0, atol=1e-8 * scale * R / (m * k * k))
        touched = {c for c, _, _ in ref["contacts"]}
        if kind == "corner":
            assert len(touched) == 1
        else:
            assert len(touched) == 2  # both low corners carry force, at overlapping times
            starts = {c: s for c, s, _ in ref["contacts"]}
            ends = {c: t for c, _, t in ref["contacts"]}
            overlapping += max(starts.values()) < min(ends.values())
    assert overlapping == 4


# --------------------------------------------------------------------------------------------------------------
# 2. Flat and frictionless (or without drift: friction then does nothing): pure translation, rebound e v0.


def test_flat_landing_translates_and_rebounds_at_e_v0():
    v0, e = 5.0, 0.6
    rows = [row(0.0, 0.0, -v0, mu=0.0, e=e, g=0.0), row(math.pi / 2, 0.0, -v0, mu=0.0, e=e, g=0.0),
            row(0.0, 0.0, -v0, mu=0.7, e=e, g=0.0), row(0.0, 0.0, -v0, mu=0.0, e=e, g=G),
            row(math.pi, 0.0, -v0, mu=0.0, e=1.0, g=0.0)]
    out = batch(rows)
    assert not np.any(out["flags"])
    m = float(HOUSING.mass)
    for i, p in enumerate(rows):
        e_i = p[5]
        lo = np.argsort(_corner_heights(p[0], p[1], p[7]))[:2]  # the two corners on the ground
        P = out["P"][i]
        assert np.all(P[:, 0] == 0.0) and np.all(P[np.setdiff1d(np.arange(4), lo)] == 0.0)
        np.testing.assert_allclose(P[lo[0], 1], P[lo[1], 1], rtol=1e-12)
        assert out["dw"][i] == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(out["contact_time"][i][lo[0]], out["contact_time"][i][lo[1]], rtol=1e-12)
        # The normal velocity when the springs let go is exactly e v0 (gravity's impulse is g times the contact).
        rebound = -v0 + out["dv"][i][1] - p[12] * out["contact_time"][i][lo[0]]
        assert rebound == pytest.approx(e_i * v0, rel=1e-9)
        assert P[:, 1].sum() == pytest.approx(m * (out["dv"][i][1]), rel=1e-12)


# --------------------------------------------------------------------------------------------------------------
# 3. One frictionless corner: Routh's impulse and a contact of duration tau, as tau goes to 0.


def test_single_frictionless_corner_gives_routh_and_lasts_tau():
    theta, vx, vy, w, e = 0.4, 0.5, -4.0, 3.0, 0.7
    taus = (1e-4, 1e-6, 1e-8)
    rows = [row(theta, vx, vy, w, mu=0.0, e=e, tau=tau, g=0.0) for tau in taus]
    out = batch(rows)
    assert not np.any(out["flags"])
    errors, durations = [], []
    for law in ("stronge", "poisson"):
        hit, corner = routh(rows[0], law)
        for i, tau in enumerate(taus):
            assert out["P"][i, corner, 0] == 0.0 and np.count_nonzero(out["P"][i, :, 1]) == 1
            errors.append(abs(out["P"][i, corner, 1] / float(hit.impact.P[1]) - 1.0))
            durations.append(abs(out["contact_time"][i, corner] / tau - 1.0))
    # The error is first order in tau (the housing turns during the contact): it falls 100-fold per 100-fold tau.
    assert errors[2] < 1e-6 and errors[1] < 1e-4 and errors[0] > 10 * errors[1] > 100 * errors[2]
    assert errors[:3] == pytest.approx(errors[3:], rel=1e-9)  # Stronge = Poisson without friction
    assert durations[2] < 1e-6 and durations[0] > 10 * durations[1] > 100 * durations[2]


# --------------------------------------------------------------------------------------------------------------
# 4. With friction: the compliant impulse tends to Stronge's rigid impulse, sliding and sticking.


CONVERGENCE = ((1e-3, 1e-2), (1e-4, 3e-3), (1e-5, 1e-3))  # (tau, v_eps / V)


@pytest.mark.parametrize("case", ["sliding", "sticking", "slip-then-stick"])
def test_friction_converges_to_stronge_as_the_contact_shortens(case):
    vx, mu = {"sliding": (-2.0, 0.2), "sticking": (0.0, 0.9), "slip-then-stick": (0.5, 0.6)}[case]
    theta, vy, e = 0.5, -4.0, 0.6
    V = math.hypot(vx, vy)
    rows = [row(theta, vx, vy, mu=mu, e=e, tau=tau, v_eps=ratio * V) for tau, ratio in CONVERGENCE]
    hit, corner = routh(rows[0])
    mode = bd.ImpactMode(int(hit.impact.mode))
    assert mode == {"sliding": bd.ImpactMode.SLIDING, "sticking": bd.ImpactMode.STICK_IN_COMPRESSION,
                    "slip-then-stick": bd.ImpactMode.STICK_IN_COMPRESSION}[case]
    if case == "slip-then-stick":
        assert 0 < float(hit.impact.Pn_stick) < float(hit.impact.Pn_compression)
    out = batch(rows)
    assert not np.any(out["flags"])
    rigid = np.asarray(hit.impact.P)
    errors = [np.abs(out["P"][i, corner] - rigid).max() / rigid[1] for i in range(len(rows))]
    assert errors[0] > 2 * errors[1] > 4 * errors[2], errors
    assert errors[2] < 1e-3, errors


# --------------------------------------------------------------------------------------------------------------
# 5. Energy never grows; no NaN value or gradient anywhere.


@settings(max_examples=4, deadline=None)
@given(st.lists(st.tuples(
    st.floats(-math.pi, math.pi),  # orientation
    st.floats(0.0, 1.5),  # friction
    st.floats(0.0, 1.0),  # restitution
    st.floats(-30.0, 30.0),  # spin
    st.floats(-2.0, 2.0),  # horizontal speed
), min_size=ROWS, max_size=ROWS))
def test_energy_never_grows_and_nothing_is_nan(cases):
    # A regularisation of 1e-2 V keeps sticking contacts to a few hundred steps (the property holds for any).
    rows = [row(theta, vx, -4.0, w, mu=mu, e=e, g=0.0, v_eps=1e-2 * math.hypot(vx, 4.0)) for theta, mu, e, w, vx in
            cases[:-1]]
    # And one at the default v_eps, 1e-3 V, with friction up to 0.6 (a sticking corner then costs 1000 steps).
    theta, mu, e, w, vx = cases[-1]
    rows.append(row(theta, vx, -4.0, w, mu=0.4 * mu, e=e, g=0.0))
    out = batch_grad(rows)
    grads = out["grad"]
    m, inertia = float(HOUSING.mass), float(HOUSING.inertia)
    for i, p in enumerate(rows):
        v = np.array([p[8], p[9]])
        before = 0.5 * m * v @ v + 0.5 * inertia * p[10] ** 2
        v1, w1 = v + out["dv"][i], p[10] + out["dw"][i]
        after = 0.5 * m * v1 @ v1 + 0.5 * inertia * w1**2
        assert out["flags"][i] & ~int(bd.Flag.NOT_SEPARATED) == 0, bd.Flag.describe(out["flags"][i])
        assert after <= before * (1 + 1e-9), (p, before, after)
        assert out["energy"][i] == pytest.approx(after - before, abs=1e-9 * before)
        assert np.all(np.isfinite(out["P"][i])) and np.all(np.isfinite(grads[i])), (p, grads[i])


def test_gradient_matches_the_reference_difference_quotient():
    """d(post-landing vertical velocity)/d(inputs) through diffrax, at the default v_eps, against central
    differences of the SciPy reference: a single corner (orientation, drift, spin, duration, restitution,
    friction; 1e-8 to 1e-6 measured) and a near-flat landing whose second corner strikes mid-contact while the
    first, released below the ground, turns back onto its relaxing set (orientation; 2e-5 measured)."""
    rows = [row(0.3, 0.3, -5.0, w=2.0), row(0.01, 0.3, -5.0)]
    grads = batch_grad(rows)["grad"]
    h = HOUSING
    checks = [(0, FIELDS.index(name), 1e-5, 1e-6) for name in ("theta", "vx", "w", "tau", "e", "mu")]
    # The near-flat row's value moves with the reference's tolerance by some 1e-10 of itself: a wider step.
    checks.append((1, FIELDS.index("theta"), 1e-3, 1e-4))
    for i, field, tol, relative_step in checks:
        p = list(rows[i])
        p[11] = default_v_eps(p)  # held fixed: only the one input moves

        def vy(x, p=p, field=field):
            q = list(p)
            q[field] = x
            ref = compliant_landing_reference(q[0], q[1], q[2], float(h.inertia), q[7], (q[8], q[9]), q[10], q[4],
                                              q[5], q[6], q[11], q[12])
            return q[9] + ref["dv_G"][1]

        step = relative_step * max(abs(p[field]), 1e-3 if field != FIELDS.index("tau") else 1e-4)
        expected = (vy(p[field] + step) - vy(p[field] - step)) / (2 * step)
        # The default v_eps moves with the velocities: its share, d(vy)/d(v_eps) d(v_eps)/dx, is in the gradient.
        if field in (FIELDS.index("vx"), FIELDS.index("w")):
            dv_eps = 1e-6 * p[11]
            share = (vy(p[11] + dv_eps, field=11) - vy(p[11] - dv_eps, field=11)) / (2 * dv_eps)
            R = 0.5 * math.hypot(p[0], p[1])
            expected += share * 1e-6 * (p[8] if field == FIELDS.index("vx") else p[10] * R * R) / p[11]
        assert grads[i][field] == pytest.approx(expected, rel=tol), FIELDS[field]


# --------------------------------------------------------------------------------------------------------------
# 6. No jump at flat: the answer moves smoothly with the angle, where the rigid law jumps.


def test_continuous_through_flat():
    degrees = (0.0, 1e-6, 1e-4, 1e-2, -1e-4)
    v0 = math.sqrt(2 * G * 1.5)
    rows = [row(math.radians(a), 0.0, -v0) for a in degrees]
    out = batch(rows)
    assert not np.any(out["flags"])
    final = np.concatenate([out["dv"], out["dw"][:, None] * 0.5 * math.hypot(0.15, 0.075)], axis=1)  # m/s
    change = np.abs(final - final[0]).max(axis=1) / v0
    assert change[2] < 1e-3 and change[4] < 1e-3
    # Linear in the angle near flat (100 times the angle, 100 times the change), odd in it (the mirror landing
    # spins the other way).
    assert change[2] / change[1] == pytest.approx(100, rel=1e-3)
    assert change[3] / change[2] == pytest.approx(100, rel=0.1)
    assert out["dw"][4] == pytest.approx(-out["dw"][2], rel=1e-6)
    # The rigid law at 1e-4 deg jumps to a single-corner strike with a spin of its own.
    rigid = bd.corner_impact(HOUSING, bd.Contact(), math.radians(1e-4), jnp.array([0.0, -v0]), 0.0)
    assert abs(float(rigid.dw)) > 1e3 * abs(out["dw"][2])


# --------------------------------------------------------------------------------------------------------------
# What the supports feel: the dense solution's accelerations integrate to its velocity changes.


def test_point_acceleration_integrates_to_point_velocity():
    theta, w = 0.3, 2.0
    p = row(theta, 0.4, -5.0, w=w)
    out, landings = batch([p], landings=True)
    assert not out["flags"][0]
    res = jax.tree_util.tree_map(lambda x: x[0], landings)
    q = jnp.array([[0.05, 0.01], [-0.06, 0.02]])
    start = -2e-4
    ts = jnp.linspace(start, float(res.t_end) + 2e-4, 6001)
    a, v, vG, F = (np.asarray(x) for x in jax.jit(lambda res, ts: (
        res.point_acceleration(ts, q), res.point_velocity(ts, q), res.velocity(ts), res.forces(ts)))(res, ts))
    scale = np.abs(v).max()
    np.testing.assert_allclose(np.trapezoid(a, np.asarray(ts), axis=0), v[-1] - v[0], rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose(np.trapezoid(F, np.asarray(ts), axis=0), np.asarray(res.P), rtol=0,
                               atol=1e-6 * float(jnp.abs(res.P).max()))
    # Before the touch the housing flies: v = v0 - g t y-hat, a = -g y-hat - w^2 r.
    np.testing.assert_allclose(vG[0], [0.4, -5.0 - G * start, w], rtol=0, atol=1e-12)
    th = theta + w * start
    r = np.asarray(q) @ np.array([[math.cos(th), math.sin(th)], [-math.sin(th), math.cos(th)]])
    np.testing.assert_allclose(a[0], -(w**2) * r - [0.0, G], rtol=0, atol=1e-9)
