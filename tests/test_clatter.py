"""Clattering drops: impact sequences against an independent free-flight reference, exact bounce sequences,
pivot detection, superposed board response and gradients through impact times."""

import json
import math
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import beamdrop_jax as bd
from references import clatter_reference, dense_impulse_peak, impulse_curvature, point_velocity

G = 9.80665

SCENES = {
    "default": bd.Scene.default(),
    # Spin, drift, a rough contact and a lively restitution: the second corner is the far one, the third again.
    "spinning": bd.Scene.default().replace(
        **{
            "drop.orientation": math.radians(65.0),
            "drop.spin": -4.0,
            "drop.horizontal_speed": 0.5,
            "drop.height": 0.8,
            "contact.friction": 0.5,
            "contact.restitution": 0.7,
        }
    ),
    # Nearly flat: the first corner barely turns the housing, the far corner slaps down harder (Goyal's clatter).
    "slap": bd.Scene.default().replace(**{"drop.orientation": math.radians(2.0)}),
}


def reference(scene, n):
    h, d, c = scene.housing, scene.drop, scene.contact
    return clatter_reference(
        float(h.width), float(h.height), float(h.mass), float(h.inertia), float(d.orientation),
        (float(d.horizontal_speed), -math.sqrt(2 * G * float(d.height))), float(d.spin),
        float(c.friction), float(c.restitution), n,
    )


@pytest.mark.parametrize("name", list(SCENES))
def test_first_three_impacts_match_free_flight_reference(name):
    scene = SCENES[name]
    impacts, _ = bd.impact_sequence(scene, max_impacts=3)
    ref = reference(scene, 3)
    assert int(impacts.count) == 3 and int(impacts.flags) == 0
    for i, r in enumerate(ref):
        np.testing.assert_allclose(float(impacts.t[i]), r["t"], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(np.asarray(impacts.corner[i]), r["corner"], rtol=1e-12)
        np.testing.assert_allclose(np.asarray(impacts.P[i]), (r["Pt"], r["Pn"]), rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(float(impacts.approach_speed[i]), r["approach"], rtol=1e-8)
    # Not one corner hit over and over: the sequence really moves between corners.
    assert len({tuple(r["corner"]) for r in ref}) >= 2


def test_support_jumps_of_each_impact_from_rigid_body_velocities():
    scene = SCENES["spinning"]
    impacts, _ = bd.impact_sequence(scene, max_impacts=3)
    ref = reference(scene, 3)
    m, inertia = float(scene.housing.mass), float(scene.housing.inertia)
    ends = np.asarray(bd.board_ends(scene.placement, scene.board.length))
    phi = float(scene.placement.angle)
    for i, r in enumerate(ref):
        theta = float(impacts.orientation[i])
        e1 = np.array([math.cos(theta), math.sin(theta)])
        e2 = np.array([-math.sin(theta), math.cos(theta)])
        S = r["corner"][0] * e1 + r["corner"][1] * e2  # from G
        P = np.array([r["Pt"], r["Pn"]])
        dw = (S[0] * P[1] - S[1] * P[0]) / inertia
        t = math.cos(phi) * e1 + math.sin(phi) * e2
        n = np.array([-t[1], t[0]])
        want = [point_velocity(P / m, dw, q[0] * e1 + q[1] * e2) @ n for q in ends]
        np.testing.assert_allclose(np.asarray(impacts.support_jumps[i]), want, rtol=1e-8, atol=1e-12)


def test_second_impact_can_be_harder_than_the_first():
    scene = SCENES["slap"]
    impacts, _ = bd.impact_sequence(scene, max_impacts=2)
    ref = reference(scene, 2)
    v = np.asarray(impacts.approach_speed)
    np.testing.assert_allclose(v, [r["approach"] for r in ref], rtol=1e-8)
    assert v[1] > 1.3 * v[0]  # 7.75 m/s after 5.42 m/s
    single = bd.simulate(scene, bd.Numerics(max_impacts=1)).peak.stress
    double = bd.simulate(scene, bd.Numerics(max_impacts=2))
    assert float(double.peak.stress) > float(single)
    assert float(double.peak.t) >= float(double.impacts.t[1])  # the worst moment follows the slap


def test_flat_bounces_are_the_exact_geometric_sequence_and_end_at_rest():
    scene = bd.Scene.default().replace(**{"drop.orientation": 0.0})
    e, v = 0.5, math.sqrt(2 * G * 1.5)
    numerics = bd.Numerics(max_impacts=12, rest_speed=0.02)
    impacts, _ = bd.impact_sequence(scene, numerics.max_impacts, numerics.rest_speed)
    k = int(impacts.count)
    # Approach speeds v e^i until the next one falls below rest_speed: 5.42 * 0.5^9 = 0.0106 < 0.02.
    assert k == 9 and int(impacts.ending) == bd.Ending.AT_REST and int(impacts.flags) == 0
    np.testing.assert_allclose(np.asarray(impacts.approach_speed[:k]), v * e ** np.arange(k), rtol=1e-12)
    flights = 2 * v * e ** np.arange(1, k) / G
    np.testing.assert_allclose(np.asarray(impacts.t[:k]), np.concatenate([[0.0], np.cumsum(flights)]), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(impacts.P[:k, 0]), 0.0, atol=1e-15)
    assert not np.any(np.asarray(impacts.applied[k:]))
    np.testing.assert_allclose(np.asarray(impacts.P[k:]), 0.0)
    # Every impact is a uniform translation, impact i a copy of the first scaled by e^i: the undamped board's ringing
    # adds up, between the first impact's peak and the sum of all the copies' peaks.
    one = float(bd.simulate(scene).peak.stress)
    many = float(bd.simulate(scene, numerics).peak.stress)
    assert one * 1.01 < many < one * np.sum(e ** np.arange(k))


def test_restitution_zero_is_a_pivot_not_a_wrong_sequence():
    scene = bd.Scene.default().replace(**{"contact.restitution": 0.0})
    impacts, _ = bd.impact_sequence(scene, max_impacts=3)
    assert int(impacts.count) == 1 and bool(impacts.pivot)
    assert int(impacts.flags) & bd.Flag.PIVOTING_CONTACT
    with pytest.raises(ValueError, match=r"pivot phase.*PIVOTING_CONTACT.*max_impacts=1"):
        bd.simulate(scene, bd.Numerics(max_impacts=3))
    with pytest.raises(ValueError, match="PIVOTING_CONTACT"):
        bd.peak_stress(scene, bd.Numerics(max_impacts=3))
    flagged = jax.jit(lambda s: bd.simulate(s, bd.Numerics(max_impacts=3)))(scene)
    assert int(flagged.flags) & bd.Flag.PIVOTING_CONTACT and bool(jnp.isnan(flagged.peak.stress))
    # The single impact is still answered.
    assert float(bd.simulate(scene).peak.stress) > 0


def test_chattering_corner_is_reported_as_a_pivot():
    # A low, nearly upright drop: the corner bounces on itself with ever smaller approach speeds while the
    # housing keeps turning about it.
    scene = bd.Scene.default().replace(
        **{"drop.orientation": math.radians(80.0), "drop.height": 0.05, "contact.restitution": 0.3}
    )
    impacts, _ = bd.impact_sequence(scene, max_impacts=30, rest_speed=0.02)
    k = int(impacts.count)
    assert bool(impacts.pivot), np.asarray(impacts.approach_speed)
    assert float(impacts.approach_speed[k]) < 0.02 <= float(impacts.approach_speed[k - 1])
    same = np.asarray(impacts.corner[k - 1]) == np.asarray(impacts.corner[k])
    assert same.all()


def test_pulse_train_superposes_shifted_responses():
    board = bd.Board()
    numerics = bd.Numerics(n_modes=4)
    T1 = 2 * math.pi / float(bd.natural_frequencies(board, 1)[0])
    times, dvA, dvB = np.array([0.0, 0.37 * T1, 2.6 * T1]), np.array([3.0, -1.0, 0.5]), np.array([1.0, 2.5, -2.0])
    response = bd.board_response(board, bd.PulseTrain(times, dvA, dvB, 0.0), numerics)
    window = times[-1] + T1
    np.testing.assert_allclose(float(response.window), window, rtol=1e-12)
    want, _, _ = dense_impulse_peak(
        dvA, dvB, float(board.bending_stiffness), float(board.mass_per_length), float(board.length),
        float(board.youngs_modulus), float(board.thickness), 4, window, nt=120001, times=times,
    )
    np.testing.assert_allclose(float(response.peak.stress), want, rtol=2e-4)
    # Where: the reference field at the reported point carries the reported peak. (This train has two equal
    # maxima, mirror images 0.5 T1 apart, so the dense grid's pick need not be the reported one.)
    curv = impulse_curvature(dvA, dvB, float(board.bending_stiffness), float(board.mass_per_length),
                             float(board.length), 4, float(response.peak.x), float(response.peak.t), times)
    at_peak = float(board.youngs_modulus) * float(board.thickness) / 2 * abs(curv[0, 0])
    np.testing.assert_allclose(at_peak, float(response.peak.stress), rtol=1e-7)  # quadrature of the projection
    # One pulse as a train is the single pulse.
    one = bd.board_response(board, bd.PulseTrain([0.0], [3.0], [1.0], 5e-4), numerics)
    ref = bd.board_response(board, bd.HalfSine(3.0, 1.0, 5e-4), numerics)
    np.testing.assert_allclose(float(one.peak.stress), float(ref.peak.stress), rtol=1e-12)


@pytest.mark.parametrize("case", ["apart", "overlapping", "padded", "damped impulse", "long pulse", "resonant",
                                  "near resonant"])
def test_windowed_train_factors_equal_the_sum_of_shifted_responses(case):
    """The search grid's modal coordinates of a pulse train, built from factors shared between drops (each window
    cut at the next pulse), equal the direct sum of every pulse's shifted unit response at each kept point."""
    from beamdrop_jax._response.pulses import unit_response
    from beamdrop_jax._response.closed_form import ClosedFormModes

    board = bd.Board(damping_ratio=0.03) if case == "damped impulse" else bd.Board()
    omega = bd.natural_frequencies(board, 5)
    # Resonant: the pulse's half period is mode 2's (pi / tau = omega_2), where the running pulse's closed form
    # has a removable singularity.
    resonant = math.pi / float(omega[1])
    tau = {"damped impulse": 0.0, "long pulse": 4e-3, "resonant": resonant,
           "near resonant": resonant * (1 + 3e-5)}.get(case, 5e-4)
    times = {"apart": [0.0, 3.1e-3, 0.41], "overlapping": [0.0, 2e-4, 4.5e-4], "padded": [0.0, 1e-4, 1e-4],
             "damped impulse": [0.0, 1e-3, 1.2e-3], "long pulse": [0.0, 1e-3, 6e-3]}.get(case, [0.0, 3e-4, 5e-4])
    beta = jnp.asarray(np.random.default_rng(3).normal(size=(3, 5)))
    modal = ClosedFormModes(omega, board.damping_ratio, jnp.asarray(tau), beta, jnp.asarray(times))
    s = jnp.linspace(0.0, 1.0, 65) * (tau + 2 * math.pi / float(omega[0]))
    _, R = modal.train_grid_factors(s, overlap_points=8)
    t = np.asarray(times)[:, None] + np.asarray(s)
    cut = np.append(times[1:], np.inf)[:, None]
    direct = sum(np.asarray(beta[p]) * np.asarray(unit_response(t[..., None] - times[p], omega, board.damping_ratio, tau))
                 for p in range(3))
    kept = t < cut
    scale = np.abs(direct).max()
    np.testing.assert_allclose(np.asarray(R).reshape(3, 65, 5)[kept], direct[kept], atol=1e-12 * scale)
    assert np.all(np.asarray(R).reshape(3, 65, 5)[~kept] == 0)
    assert kept[-1].all() and (case != "padded" or not kept[1].any())


@pytest.mark.parametrize("case", ["apart", "overlapping", "padded", "damped impulse", "long pulse", "resonant"])
def test_search_jets_of_a_pulse_train_equal_the_sum_of_shifted_pulse_jets(case):
    """The Newton search's jets of a pulse train (`ClosedFormModes.for_search`: from the last pulse started, the
    earlier pulses as free vibration plus the running ones' corrections) equal every pulse's own shifted closed
    form summed: q against `unit_response`, q' and q'' against `unit_response_jet`, at times inside each pulse,
    at its end, between pulses and long after."""
    from beamdrop_jax._response.pulses import unit_response, unit_response_jet
    from beamdrop_jax._response.closed_form import ClosedFormModes

    board = bd.Board(damping_ratio=0.03) if case == "damped impulse" else bd.Board()
    omega = bd.natural_frequencies(board, 5)
    resonant = math.pi / float(omega[1])
    tau = {"damped impulse": 0.0, "long pulse": 4e-3, "resonant": resonant}.get(case, 5e-4)
    times = {"apart": [0.0, 3.1e-3, 0.41], "overlapping": [0.0, 2e-4, 4.5e-4], "padded": [0.0, 1e-4, 1e-4],
             "damped impulse": [0.0, 1e-3, 1.2e-3], "long pulse": [0.0, 1e-3, 6e-3]}.get(case, [0.0, 3e-4, 5e-4])
    beta = jnp.asarray(np.random.default_rng(4).normal(size=(3, 5)))
    modal = ClosedFormModes(omega, board.damping_ratio, jnp.asarray(tau), beta, jnp.asarray(times))
    search = modal.for_search()
    ts = sorted({float(t0 + d) for t0 in times for d in (0.0, 1e-5, 0.5 * tau, tau, tau + 1e-6, 2e-3)}
                | set(np.linspace(0.0, times[-1] + 0.01, 23).tolist()))
    jets = np.asarray(jax.jit(jax.vmap(search.jet))(jnp.asarray(ts)))  # (3, len(ts), n)
    since = np.asarray(ts)[:, None, None] - np.asarray(times)[None, :, None]  # (t, pulse, 1)
    q = np.sum(np.asarray(beta) * np.asarray(unit_response(since, omega, board.damping_ratio, tau)), axis=1)
    d = [np.sum(np.where(since >= 0, np.asarray(beta) * np.asarray(r), 0.0), axis=1)
         for r in unit_response_jet(since, omega, board.damping_ratio, tau)[1:]]
    for got, ref, rate in zip(jets, [q, *d], (1.0, omega, omega**2)):
        scale = np.abs(np.asarray(beta)).max() / np.asarray(omega) * np.asarray(rate)
        np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=1e-11)


def test_windowed_train_factors_with_a_duration_per_drop_equal_the_sum_of_shifted_responses():
    """Batched drops with their own contact durations (Monte-Carlo over the duration): a short pulse corrected on
    the window's head and a long one corrected everywhere, side by side in one vmapped call."""
    from beamdrop_jax._response.pulses import unit_response
    from beamdrop_jax._response.closed_form import ClosedFormModes

    board = bd.Board()
    omega = bd.natural_frequencies(board, 5)
    taus = np.array([5e-4, 4e-3])
    times = np.array([[0.0, 2e-4, 4.5e-4], [0.0, 1e-3, 2.5e-3]])
    beta = jnp.asarray(np.random.default_rng(4).normal(size=(2, 3, 5)))
    unit = jnp.linspace(0.0, 1.0, 65)

    def factors(tau, t0, b):
        s = unit * (tau + 2 * math.pi / omega[0])
        return ClosedFormModes(omega, board.damping_ratio, tau, b, t0).train_grid_factors(s, overlap_points=8)[1]

    R = np.asarray(jax.vmap(factors)(jnp.asarray(taus), jnp.asarray(times), beta)).reshape(2, 3, 65, 5)
    for d in range(2):
        t = times[d][:, None] + np.asarray(unit) * (taus[d] + 2 * math.pi / float(omega[0]))
        direct = sum(np.asarray(beta[d, p]) * np.asarray(unit_response(t[..., None] - times[d, p], omega, 0.0,
                                                                       taus[d])) for p in range(3))
        kept = t < np.append(times[d, 1:], np.inf)[:, None]
        np.testing.assert_allclose(R[d][kept], direct[kept], atol=1e-12 * np.abs(direct).max())


def test_windowed_train_factors_have_finite_gradients_on_a_damped_board_long_after_impact():
    """A later pulse's negative lag would overflow e^{lam (lag - duration)} on a damped board; the gradient through
    the masked terms stays finite."""
    from beamdrop_jax._response.closed_form import ClosedFormModes

    board = bd.Board(damping_ratio=0.03)
    omega = bd.natural_frequencies(board, 5)
    s = jnp.linspace(0.0, 1.0, 33) * (5e-4 + 2 * math.pi / float(omega[0]))

    def total(times, beta):
        modal = ClosedFormModes(omega, board.damping_ratio, jnp.asarray(5e-4), beta, times)
        return jnp.sum(modal.train_grid_factors(s, overlap_points=4)[1] ** 2)

    grads = jax.grad(total, argnums=(0, 1))(jnp.asarray([0.0, 1e-3, 1.2]), jnp.ones((3, 5)))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in grads)


FIELDS = ["drop.height", "drop.orientation", "contact.friction", "contact.restitution", "drop.spin"]


@pytest.mark.parametrize("name", ["default", "spinning"])
def test_gradients_through_impact_times_match_finite_differences(name):
    # Without spin and drift the contact starts at S0 = 0, where the sliding direction (so the impulse) has a
    # kink in spin: give the default drop a little spin to sit on one smooth piece.
    scene = SCENES[name].replace(**{"drop.spin": 1.0}) if name == "default" else SCENES[name]
    numerics = bd.Numerics(max_impacts=3)

    @jax.jit  # one program for the 20 differences, not one per eager operation
    def f(values):
        s = scene.replace(**dict(zip(FIELDS, values)))
        impacts, _ = bd.impact_sequence(s, max_impacts=3)
        return jnp.stack([impacts.t[1], impacts.t[2], bd.peak_stress(s, numerics) / 1e8])

    x0 = jnp.asarray([float(getattr(getattr(scene, p.split(".")[0]), p.split(".")[1])) for p in FIELDS])
    J = jax.jacrev(f)(x0)
    assert np.all(np.isfinite(np.asarray(J)))
    for j in range(len(FIELDS)):
        # Fourth-order differences: the peak curves fast in the impact times (the board rings at kHz).
        h = 1e-6 * max(1.0, abs(float(x0[j])))
        d = [f(x0.at[j].add(k * h)) - f(x0.at[j].add(-k * h)) for k in (1, 2)]
        fd = (8 * d[0] - d[1]) / (12 * h)
        np.testing.assert_allclose(np.asarray(J[:, j]), np.asarray(fd), rtol=2e-5, atol=1e-7, err_msg=FIELDS[j])


def test_bad_clatter_numerics_are_named():
    with pytest.raises(ValueError, match="max_impacts"):
        bd.Numerics(max_impacts=0)
    with pytest.raises(ValueError, match="rest_speed"):
        bd.Numerics(rest_speed=0.0)
    with pytest.raises(ValueError, match=r"max_impacts = 3 needs Numerics.method"):
        bd.Numerics(max_impacts=3, method="diffrax")
    with pytest.raises(ValueError, match="non-decreasing"):
        bd.PulseTrain([0.0, 2e-3, 1e-3], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], 5e-4)


from hypothesis import example, given, settings, strategies as st  # noqa: E402

_sequence = jax.jit(lambda s: bd.impact_sequence(s, max_impacts=6)[0])


@settings(max_examples=60, deadline=None)
@given(
    theta=st.floats(0.05, 2 * math.pi - 0.05),
    height=st.floats(0.05, 2.0),
    spin=st.floats(-8.0, 8.0),
    drift=st.floats(-1.0, 1.0),
    mu=st.floats(0.0, 1.5),
    e=st.floats(0.0, 1.0),
)
@example(theta=0.125, height=1.0, spin=0.0, drift=0.0, mu=0.0, e=6.103515625e-05)  # rocks onto its face
def test_every_sequence_obeys_the_laws(theta, height, spin, drift, mu, e):
    if min(abs(math.sin(theta)), abs(math.cos(theta))) < 1e-3:
        theta += 0.01  # flat landings with motion are outside the single-contact law (tested elsewhere)
    scene = bd.Scene.default().replace(
        **{"drop.orientation": theta, "drop.height": height, "drop.spin": spin, "drop.horizontal_speed": drift,
           "contact.friction": mu, "contact.restitution": e}
    )
    if float(bd.housing_impact(scene).v0[1]) >= 0:
        return  # spin lifts the corner: no impact at all (an eager error, tested elsewhere)
    imp = _sequence(scene)
    applied = np.asarray(imp.applied)
    k = int(imp.count)
    leaves = [np.asarray(v, float) for v in jax.tree_util.tree_leaves(imp)]
    assert all(np.all(np.isfinite(v)) for v in leaves)
    assert applied[:k].all() and not applied[k:].any()
    # Only two ways out of the model: a pivot, or rocking that converges onto a face, so that two corners land at
    # once with the housing still turning (found by hypothesis: mu = 0, e ~ 0, 7 deg).
    flags = int(imp.flags)
    assert flags & ~(bd.Flag.PIVOTING_CONTACT | bd.Flag.FLAT_LANDING_WITH_MOTION) == 0
    assert bool(imp.pivot) == bool(flags & bd.Flag.PIVOTING_CONTACT)
    if flags & bd.Flag.FLAT_LANDING_WITH_MOTION:
        theta_k = np.asarray(imp.orientation)[1:k]
        assert np.min(np.abs(np.sin(2 * theta_k))) < 1e-12
    t = np.asarray(imp.t)
    assert np.all(np.diff(t) >= 0)
    P = np.asarray(imp.P)[:k]
    assert np.all(P[:, 1] >= 0) and np.all(np.abs(P[:, 0]) <= mu * P[:, 1] * (1 + 1e-9) + 1e-15)  # friction cone
    assert np.all(np.asarray(imp.energy_change)[:k] <= 1e-12)  # Poisson never creates energy
    assert np.all(np.asarray(imp.approach_speed)[1:k] >= 0.02)  # later impacts only above rest_speed


def test_random_clattering_drops_have_finite_gradients():
    from test_scene import random_scenes

    from beamdrop_jax._response.objectives import _scene_peaks

    n = 12
    batch = random_scenes(n, seed=3)
    numerics = bd.Numerics(max_impacts=3)

    def peak(s):
        v, flags = _scene_peaks(s, numerics, ("stress",))
        return jnp.where(flags == 0, v[0], 0.0), flags

    grads, flags = jax.jit(jax.vmap(jax.grad(peak, has_aux=True)))(batch)
    ok = np.asarray(flags) == 0
    assert ok.sum() >= n // 2
    for leaf in jax.tree_util.tree_leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))


def test_float32_sequence_and_peak_agree_with_float64(users_compile):
    scene = SCENES["default"]
    imp64, _ = bd.impact_sequence(scene, max_impacts=4)
    peak64 = float(bd.simulate(scene, bd.Numerics(max_impacts=3)).peak.stress)
    # float32 rounding depends on how XLA compiles: computed by a child compiling as users' programs do.
    out = json.loads(users_compile(textwrap.dedent("""
        import json, jax, jax.numpy as jnp, numpy as np
        import beamdrop_jax as bd
        s32 = jax.tree_util.tree_map(lambda v: jnp.asarray(np.asarray(v), jnp.float32), bd.Scene.default())
        imp32, _ = bd.impact_sequence(s32, max_impacts=4)
        peak32 = bd.simulate(s32, bd.Numerics(max_impacts=3)).peak.stress
        assert imp32.t.dtype == jnp.float32 and peak32.dtype == jnp.float32
        print(json.dumps(dict(t=imp32.t.tolist(), speed=imp32.approach_speed.tolist(), peak=float(peak32))))
    """)))
    np.testing.assert_allclose(out["t"], np.asarray(imp64.t), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(out["speed"], np.asarray(imp64.approach_speed), rtol=1e-5)
    np.testing.assert_allclose(out["peak"], peak64, rtol=1e-4)


def test_search_that_gives_up_is_not_called_a_pivot():
    # At 3e4 rad/s the conservative free-flight steps (~ 1 / spin^2) run out before the next impact: that is the
    # search giving up, not a corner staying on the ground.
    scene = bd.Scene.default().replace(**{"drop.spin": 3e4})
    impacts, _ = bd.impact_sequence(scene, 3)
    assert int(impacts.ending) == bd.Ending.SEARCH_GAVE_UP
    assert int(impacts.flags) & bd.Flag.SOLVER_FAILED and not int(impacts.flags) & bd.Flag.PIVOTING_CONTACT
    with pytest.raises(ValueError, match="gave up") as err:
        bd.simulate(scene, bd.Numerics(max_impacts=3))
    assert "stays on the ground" not in str(err.value)
    with pytest.raises(ValueError, match="gave up"):
        bd.peak_stress(scene, bd.Numerics(max_impacts=3))
    # A spin of 1e4 rad/s still finds its impacts.
    assert int(bd.impact_sequence(bd.Scene.default().replace(**{"drop.spin": 1e4}), 3)[0].ending) == bd.Ending.MAX_IMPACTS
