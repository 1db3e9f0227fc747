"""Monte-Carlo drops: batched equals one by one, exceedance intervals, chunk size and device count."""

import dataclasses
import json
import math
import os
import subprocess
import sys
import textwrap

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import beamdrop_jax as bd
from beamdrop_jax._common.memo import tree_digest


def _first_strike(scene=None):
    """The default scene on the rigid law (the first strike): these tests check the fast paths and the direct
    path against their references; the near-flat drops' compliant path has tests of its own."""
    scene = bd.Scene.default() if scene is None else scene
    return eqx.tree_at(lambda s: s.contact, scene, scene.contact.with_model("rigid"))


NUMERICS = bd.Numerics(n_modes=6)


def result_distribution():
    return bd.DropDistribution(
        height=("lognormal", 1.2, 0.3),
        friction=("uniform", 0.1, 0.8),
        restitution=("uniform", 0.2, 0.8),
        spin=("uniform", -5.0, 5.0),
        duration=("uniform", 2e-4, 8e-4),
    )


@pytest.fixture(scope="module")
def result():
    dist = result_distribution()
    return bd.montecarlo(_first_strike(), 600, jax.random.PRNGKey(3), dist, NUMERICS, batch_size=256,
                         progress=False, refine_deflection=True, superpose=False)


def test_batched_equals_one_by_one(result):
    assert result.peak_stress.shape == (600,)
    for i in range(0, 600, 41):
        scene = result.scene(i)
        res = bd.simulate(scene, NUMERICS)
        np.testing.assert_allclose(result.peak_stress[i], res.peak.stress, rtol=1e-10)
        np.testing.assert_allclose(result.peak_strain[i], res.peak.strain, rtol=1e-10)
        np.testing.assert_allclose(result.peak_deflection[i], res.peak.deflection, rtol=1e-10)


def test_grid_deflection_is_a_close_lower_bound(result):
    fast = bd.montecarlo(_first_strike(), 600, jax.random.PRNGKey(3), result_distribution(), NUMERICS,
                         batch_size=256, progress=False, superpose=False)
    np.testing.assert_allclose(fast.peak_stress, result.peak_stress, rtol=1e-12)
    ratio = np.asarray(fast.peak_deflection) / np.asarray(result.peak_deflection)
    assert np.all(ratio <= 1 + 1e-12) and np.all(ratio > 0.98)


HARD_DROPS = bd.DropDistribution(height=("uniform", 0.3, 2.0), spin=("uniform", -5.0, 5.0),
                                 horizontal_speed=("uniform", -1.0, 1.0), friction=("uniform", 0.0, 0.8),
                                 restitution=("uniform", 0.1, 0.9))


@pytest.mark.parametrize(
    "name, scene, distribution",
    [
        ("default", _first_strike(), None),
        # Opposite support jumps: several near-equal maxima along a ridge in (x, t), where a clipped Newton step
        # from a coarse grid point used to stall 5 % low.
        ("random height, spin, drift, friction, restitution", _first_strike(), HARD_DROPS),
        # Nine modes and many close local maxima: 2 grid points per period ranked them wrongly (1.8 % low).
        ("0.1 ms pulse", _first_strike().replace(**{"contact.duration": 1e-4}), None),
    ],
)
def test_default_numerics_within_one_percent_of_converged(name, scene, distribution):
    """Both Monte-Carlo ways with their default numerics against 32 modes with the dense, refined search (a
    converged modal series), on 512 drops (largest errors measured: 6.6e-3, 6.8e-3 and 8.5e-3 by the direct
    search; 1024 drops gave 6.6e-3, 7.7e-3 and 9.1e-3)."""
    key = jax.random.PRNGKey(7)
    converged = bd.montecarlo(scene, 512, key, distribution, bd.Numerics(n_modes=32), progress=False,
                              superpose=False)
    assert converged.n_invalid == 0
    for superpose in (False, True):
        lean = bd.montecarlo(scene, 512, key, distribution, progress=False, superpose=superpose)
        assert lean.n_invalid == 0
        error = np.abs(np.asarray(lean.peak_stress) / np.asarray(converged.peak_stress) - 1)
        assert error.max() < 0.01, (name, superpose, error.max())


def test_clattering_defaults_within_half_a_percent_of_converged():
    """Three impacts per drop with `montecarlo_numerics(max_impacts=3)` against 32 modes with the dense, refined
    search (a converged modal series); the windows' grids are built from factors shared between drops."""
    scene, key = _first_strike(), jax.random.PRNGKey(7)
    lean_numerics = bd.montecarlo_numerics(scene, max_impacts=3)
    assert lean_numerics.max_impacts == 3
    converged = bd.montecarlo(scene, 256, key, numerics=bd.Numerics(n_modes=32, max_impacts=3), progress=False)
    lean = bd.montecarlo(scene, 256, key, numerics=lean_numerics, progress=False)
    assert converged.n_invalid == lean.n_invalid == 0
    error = np.abs(np.asarray(lean.peak_stress) / np.asarray(converged.peak_stress) - 1)
    assert error.max() < 0.005, error.max()


@pytest.fixture(scope="module")
def hard_drops():
    """2048 random drops: the superposed peaks and a thorough direct search of the same modes (16 grid points per
    period of the top mode and per mode along the board, 8 candidates, 8 Newton steps)."""
    scene, key = _first_strike(), jax.random.PRNGKey(1)
    numerics = bd.table_numerics(scene)
    fine = bd.Numerics(n_modes=numerics.n_modes, points_per_period=16, x_points_per_mode=16, candidates=8,
                       newton_steps=8)
    table = bd.montecarlo(scene, 2048, key, HARD_DROPS, progress=False)
    dense = bd.montecarlo(scene, 2048, key, HARD_DROPS, fine, progress=False, superpose=False,
                          refine_deflection=True)
    return table, dense, numerics


def test_superposed_peaks_are_close_lower_bounds(hard_drops):
    """Every superposed peak is the field at some point of the board and window, so never above the true peak;
    the table's spacing costs at most the bounds stated in `montecarlo`'s docstring."""
    table, dense, _ = hard_drops
    assert table.n_invalid == dense.n_invalid == 0
    for quantity, bound in (("stress", 1e-4), ("strain", 1e-4), ("deflection", 3e-4)):
        ratio = np.asarray(getattr(table, f"peak_{quantity}")) / np.asarray(getattr(dense, f"peak_{quantity}"))
        assert ratio.max() <= 1 + 1e-12, quantity
        assert ratio.min() >= 1 - bound, (quantity, ratio.min())


def test_superposed_equals_simulate_one_by_one(hard_drops):
    """`simulate` on a sampled drop alone, with the table's numerics, gives its superposed peak (the table is a
    little lower by its spacing, or higher where `simulate`'s own grid ranked a lower local maximum first)."""
    table, _, numerics = hard_drops
    for i in range(0, 2048, 97):
        res = bd.simulate(table.scene(i), numerics)
        np.testing.assert_allclose(table.peak_stress[i], res.peak.stress, rtol=1e-3)
        np.testing.assert_allclose(table.peak_deflection[i], res.peak.deflection, rtol=1e-3)
        assert table.peak_stress[i] >= res.peak.stress * (1 - 1e-4)


def test_every_table_row_carries_its_directions_peak():
    """Half the rows are searched and half mirrored (supports swapped, x -> L - x): each row must still give the
    peak that `board_response` finds for its own direction, on a damped, pre-stressed board with a short pulse
    (so the symmetry must hold beyond the default board)."""
    scene = _first_strike().replace(**{"board.damping_ratio": 0.02, "board.axial_force": 40.0,
                                          "contact.duration": 2e-4})
    numerics = bd.table_numerics(scene)
    n = 24
    table = bd.superposition_table(scene, numerics, n_angles=n)
    for j in range(n):
        p = 2 * j / n
        direction = np.array([1 - p, 1 - abs(1 - p)])
        res = bd.board_response(scene.board, bd.HalfSine(*direction, scene.contact.duration), numerics)
        kappa, deflection = np.asarray(table.peaks(jnp.asarray(direction)))
        half_h = float(scene.board.thickness) / 2
        np.testing.assert_allclose(kappa * half_h, res.peak.strain, rtol=1e-9, err_msg=f"row {j}")
        np.testing.assert_allclose(deflection, res.peak.deflection, rtol=1e-9, err_msg=f"row {j}")
        assert np.all((0 <= table.x[0, j]) & (table.x[0, j] <= float(scene.board.length)))
    with pytest.raises(ValueError, match="multiple of 4"):
        bd.superposition_table(scene, numerics, n_angles=30)


DURATION_DROPS = bd.DropDistribution(height=("uniform", 0.3, 2.0), spin=("uniform", -5.0, 5.0),
                                     horizontal_speed=("uniform", -1.0, 1.0), friction=("uniform", 0.0, 0.8),
                                     restitution=("uniform", 0.1, 0.9), duration=("uniform", 2e-4, 1e-3))


@pytest.mark.parametrize("name, scene, bounds", [
    ("default", _first_strike(), (1e-3, 2.5e-3)),
    # A clamp's peak sits on a clamp, and three local maxima (two clamps, two times) trade places as the duration
    # changes: one of them can win between two table durations without being a table maximiser at either.
    ("clamped", bd.Scene(board=bd.Board(ends="clamped")), (5e-3, 5e-3)),
])
def test_duration_table_against_a_dense_search_per_drop(name, scene, bounds):
    """Drops whose contact duration varies (uniform on [0.2, 1] ms) superpose from a table over the duration: the
    largest of four maximisers moved to the drop's duration is the field at points of the board, so it stays below
    the dense per-drop search (up to the duration interpolation, 1e-4) and close to it (the bounds in
    `montecarlo`'s docstring, with room for other random drops; the clamped board's worst is 3.4e-3 here)."""
    key = jax.random.PRNGKey(4)
    n = 512
    samples = DURATION_DROPS.sample(scene, n, key)
    tau = np.asarray(samples.contact.duration)
    numerics = bd.table_numerics(scene, (tau.min(), tau.max()))
    fine = bd.Numerics(n_modes=numerics.n_modes, points_per_period=16, x_points_per_mode=16, candidates=8,
                       newton_steps=8)
    table = bd.montecarlo(scene, n, key, DURATION_DROPS, progress=False)
    dense = bd.montecarlo(scene, n, key, DURATION_DROPS, fine, progress=False, superpose=False,
                          refine_deflection=True)
    assert table.n_invalid == dense.n_invalid == 0
    for quantity, bound in zip(("stress", "deflection"), bounds):
        ratio = np.asarray(getattr(table, f"peak_{quantity}")) / np.asarray(getattr(dense, f"peak_{quantity}"))
        assert ratio.max() <= 1 + 1e-4, (name, quantity, ratio.max())
        assert ratio.min() >= 1 - bound, (name, quantity, ratio.min())


def test_duration_table_flags_durations_it_does_not_span():
    scene = _first_strike()
    table = bd.superposition_table(scene, durations=(3e-4, 6e-4), n_durations=3, n_angles=16)
    assert table.cells.shape == (2, 9, 16, 4, 2, 2)
    for tau, inside in ((3e-4, True), (4.5e-4, True), (6e-4, True), (2.9e-4, False), (7e-4, False)):
        stress, _, _, flags = table(scene.replace(**{"contact.duration": tau}))
        assert bool(flags & bd.Flag.OUTSIDE_TABLE) is not inside, tau
        assert bool(np.isfinite(stress)) is inside, tau
        if inside:  # at most a few 1e-3 below the drop's own search on 16 directions
            np.testing.assert_allclose(stress, bd.peak_stress(scene.replace(**{"contact.duration": tau}),
                                                              bd.table_numerics(scene, (3e-4, 6e-4))), rtol=5e-3)
    with pytest.raises(ValueError, match=r"durations\[0\]"):
        bd.superposition_table(scene, durations=(0.0, 1e-3))
    with pytest.raises(ValueError, match="shortest < longest"):
        bd.superposition_table(scene, durations=(1e-3, 1e-3))
    for bad in ((1e-3,), "abc", (1e-4, 2e-4, 3e-4)):
        with pytest.raises(ValueError, match=r"durations = .*valid: \(shortest, longest\) in s"):
            bd.superposition_table(scene, durations=bad)


def test_superpose_needs_one_pulse_per_drop():
    with pytest.raises(ValueError, match="max_impacts = 3"):
        bd.montecarlo(_first_strike(), 10, jax.random.PRNGKey(0), numerics=bd.Numerics(max_impacts=3),
                      superpose=True)
    # A table spans durations > 0: sampled durations at or below 0 go the direct way by default.
    spread = bd.DropDistribution(duration=("uniform", -1e-4, 1e-4))
    with pytest.raises(ValueError, match="sampled contact durations reach -"):
        bd.montecarlo(_first_strike(), 10, jax.random.PRNGKey(0), spread, superpose=True)
    res = bd.montecarlo(_first_strike(), 10, jax.random.PRNGKey(0), spread, bd.Numerics(n_modes=4),
                        progress=False)
    negative = np.asarray(res.samples.contact.duration) < 0
    assert 0 < res.n_invalid == int(negative.sum()) < 10
    assert np.all(np.asarray(res.flags)[negative] & bd.Flag.DURATION_NEGATIVE)


def test_samples_follow_the_distribution(result):
    h = np.asarray(result.samples.drop.height)
    np.testing.assert_allclose(np.median(h), 1.2, rtol=0.05)
    np.testing.assert_allclose(np.std(np.log(h)), 0.3, rtol=0.1)
    th = np.asarray(result.samples.drop.orientation)
    assert th.min() >= 0 and th.max() < 2 * math.pi
    # Fixed fields stay scalars.
    assert np.ndim(result.samples.housing.mass) == 0


@pytest.mark.parametrize("superpose", [False, True])
def test_exceedance_with_known_answer(superpose):
    # Peak stress ~ sqrt(height) exactly (elasticity 0.5), so with h ~ U(0.5, 2) and the limit at the stress of
    # h = 1.5 m, P(stress > limit) = P(h > 1.5) = 1/3.
    scene = _first_strike()
    dist = bd.DropDistribution(orientation=None, height=("uniform", 0.5, 2.0))
    res = bd.montecarlo(scene, 3000, jax.random.PRNGKey(11), dist, NUMERICS, progress=False, superpose=superpose)
    at_limit = scene.replace(**{"drop.height": 1.5})
    if superpose:
        limit = float(bd.superposition_table(scene, NUMERICS)(at_limit)[0])
    else:
        limit = float(bd.peak_stress(at_limit, NUMERICS))
    p, (lo, hi), k = res.exceedance(limit * (1 + 1e-9))
    fraction = float(np.mean(np.asarray(res.samples.drop.height) > 1.5))
    assert k == round(fraction * 3000)  # exactly the drops above 1.5 m
    assert lo <= 1 / 3 <= hi, (p, lo, hi)
    assert hi - lo < 0.04


def test_face_biased_orientations_follow_their_mixture():
    # A share s near a face (k pi/2 + N(0, spread)), the rest uniform: the fraction within r of a face is
    # s P(|N| < r / spread) + (1 - s) 8 r / (2 pi) for r < pi/4.
    share, spread, n = 0.4, math.radians(2.0), 40000
    dist = bd.DropDistribution.faces(share, spread)
    th = np.asarray(dist.sample(bd.Scene.default(), n, jax.random.PRNGKey(3)).drop.orientation)
    assert th.shape == (n,) and th.min() >= 0 and th.max() < 2 * math.pi
    off = np.abs(np.angle(np.exp(4j * th))) / 4  # distance to the nearest face
    for k in (1.0, 4.0, 10.0):
        r = k * spread
        expected = share * math.erf(k / math.sqrt(2)) + (1 - share) * 8 * r / (2 * math.pi)
        assert abs(np.mean(off < r) - expected) < 4 * math.sqrt(expected * (1 - expected) / n), k
    faces = np.round(th[off < 4 * spread] / (math.pi / 2)) % 4
    np.testing.assert_allclose(np.bincount(faces.astype(int)) / faces.size, 0.25, atol=0.02)  # every face alike
    assert "0.4 of the drops near a face" in dist.describe() and "deviation of 2 deg" in dist.describe()
    with pytest.raises(ValueError, match="share near a face must be in"):
        bd.DropDistribution.faces(1.5, 0.01)
    with pytest.raises(ValueError, match="for the orientation only"):
        bd.DropDistribution(height=("faces", 0.5, 0.01))


def test_wilson_interval_reference_values():
    # Wilson (1927) interval for 0/10 and 5/10 at 95 %: textbook values.
    assert bd.wilson_interval(0, 10)[0] == 0.0 and bd.wilson_interval(10, 10)[1] == 1.0  # exact, no rounding residue
    np.testing.assert_allclose(bd.wilson_interval(0, 10), (0.0, 0.27753), atol=1e-5)
    np.testing.assert_allclose(bd.wilson_interval(5, 10), (0.23659, 0.76341), atol=1e-5)
    for args, what in (((5, 3), "0 <= k <= n"), ((0.5, 3), "ints"), ((1, 3, 2.0), r"confidence = 2\.0; valid: \(0, 1\)")):
        with pytest.raises(ValueError, match=what):
            bd.wilson_interval(*args)


def test_invalid_drops_are_counted_not_mixed():
    dist = bd.DropDistribution(friction=("uniform", -0.5, 0.5))
    res = bd.montecarlo(_first_strike(), 400, jax.random.PRNGKey(0), dist, NUMERICS, progress=False)
    negative = np.asarray(res.samples.contact.friction) < 0
    assert res.n_invalid == int(negative.sum()) > 100
    assert np.all(np.asarray(res.flags)[negative] & bd.Flag.FRICTION_NEGATIVE)
    assert np.all(np.isnan(np.asarray(res.peak_stress)[negative]))
    assert res.summary()["n"] == 400 - res.n_invalid
    assert np.isfinite(res.summary()["mean"])


def test_bad_distribution_is_named():
    with pytest.raises(ValueError, match="DropDistribution.height"):
        bd.DropDistribution(height=(0.5, 2.0))
    with pytest.raises(ValueError, match="low <= high"):
        bd.DropDistribution(friction=("uniform", 0.8, 0.1))
    with pytest.raises(ValueError, match="n = 0"):
        bd.montecarlo(_first_strike(), 0, jax.random.PRNGKey(0))


SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax
    jax.config.update("jax_num_cpu_devices", 8)
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    import beamdrop_jax as bd
    assert len(jax.devices()) == 8, jax.devices()
    import equinox as eqx
    scene = bd.Scene.default()
    scene = eqx.tree_at(lambda s: s.contact, scene, scene.contact.with_model("rigid"))
    dist = bd.DropDistribution(height=("uniform", 0.5, 2.0), spin=("uniform", -3.0, 3.0))
    numerics = bd.Numerics(n_modes=4)
    key = jax.random.PRNGKey(5)
    runs = {
        "one_device_chunk_1000": dict(batch_size=1000, devices=jax.devices()[:1]),
        "one_device_chunk_96": dict(batch_size=96, devices=jax.devices()[:1]),
        "eight_devices_chunk_64": dict(batch_size=64),
    }
    out = {}
    for superpose in (False, True):
        for name, kw in runs.items():
            res = bd.montecarlo(scene, 1000, key, dist, numerics, progress=False, superpose=superpose, **kw)
            out[f"{name} superpose={superpose}"] = np.asarray(res.peak_stress).tolist()
    json.dump(out, sys.stdout)
    """
)


def test_chunks_and_devices_do_not_change_results():
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = {k: np.asarray(v) for k, v in json.loads(proc.stdout).items()}
    for superpose in (False, True):
        reference = out.pop(f"one_device_chunk_1000 superpose={superpose}")
        assert np.all(np.isfinite(reference))
        for name, values in out.items():
            if name.endswith(f"superpose={superpose}"):
                np.testing.assert_allclose(values, reference, rtol=1e-12, err_msg=name)


def test_near_flat_band_reads_a_table_over_orientation(monkeypatch):
    """Where only the orientation varies, the near-flat band's peaks come from a table over orientation (nodes
    0.05 deg apart, linear between them) once the band's drops lie between fewer nodes than they are. Reference:
    each drop's own solve on the compliant landing's path (`solve_landings`, as `simulate`): within 5e-3 (2e-3
    measured) between 0.5 and 2 deg, where the peak moves fastest with the orientation."""
    from beamdrop_jax._studies import landings, montecarlo as mc

    tables, original = [], mc.orientation_table

    def spy(*args, **kwargs):
        tables.append(original(*args, **kwargs))
        return tables[-1]

    monkeypatch.setattr(mc, "orientation_table", spy)
    monkeypatch.setattr(mc, "_TABLES", type(mc._TABLES)())  # nothing kept from other tests
    monkeypatch.setattr(mc, "_SUPERPOSED", type(mc._SUPERPOSED)())
    builds, build = [], mc.superposition_table
    monkeypatch.setattr(mc, "superposition_table", lambda *a, **k: builds.append(1) or build(*a, **k))
    scene, key = bd.Scene.default(), jax.random.PRNGKey(5)
    near = bd.DropDistribution(orientation=("uniform", math.radians(0.5), math.radians(2.0)))
    res = bd.montecarlo(scene, 64, key, near, progress=False)
    assert np.all(np.asarray(res.landing_weight) > 0) and len(tables) == 1 and tables[0].nodes.size <= 31
    first = np.arange(landings.LANDING_BATCH)
    direct = mc.solve_landings(res.samples, mc.sample_axes(res.samples, scene), first)
    for found, expected in zip((res.peak_stress, res.peak_strain, res.peak_deflection), direct[:3]):
        np.testing.assert_allclose(np.asarray(found)[first], expected, rtol=5e-3)
    assert not np.any(np.asarray(res.flags)) and not np.any(direct[3])
    # Another run on the scene solves no node it keeps, builds no superposition table, and answers the same.
    again = bd.montecarlo(scene, 64, key, near, progress=False)
    assert len(tables) == 1 and len(builds) == 1
    np.testing.assert_array_equal(np.asarray(again.peak_strain), np.asarray(res.peak_strain))
    mc.forget_tables()
    assert not (mc._TABLES or mc._SUPERPOSED or mc._GRID_WEIGHTS)
    # Between nodes it has not solved, a table answers with a flag, never a number.
    far = tables[0].lookup(np.array([math.radians(10.0)]))
    assert np.isnan(far[0][0]) and far[3][0] == bd.Flag.OUTSIDE_TABLE
    # Over uniform orientations the weights come from the weights at the nodes where those are 0 on both sides:
    # equal to each drop's own.
    spread = np.asarray(bd.DropDistribution().sample(scene, 4096, key).drop.orientation)
    np.testing.assert_array_equal(mc._orientation_weights(scene, tree_digest(scene), spread),
                                  np.asarray(mc.landing_weights(scene, 4096, key)))
    # Other distributions solve each band drop (the count the refusal names).
    heights = dataclasses.replace(near, height=("uniform", 1.4, 1.6))
    with pytest.raises(ValueError, match="that takes 64 solves"):
        bd.montecarlo(scene, 64, key, heights, progress=False, max_landings=10)
    with pytest.raises(ValueError, match=r"max_landings = -1; valid: an int >= 0"):
        bd.montecarlo(scene, 64, key, heights, progress=False, max_landings=-1)
    for nodes in ([-1], [7200], [1.5], []):  # node indices, not orientations
        with pytest.raises(ValueError, match=r"valid: a non-empty list of ints in \[0, 7200\)"):
            bd.orientation_table(scene, nodes)


def test_mirror_image_drops_are_solved_once_in_the_orientation_table(monkeypatch):
    """A board centred in the housing, level, that maps onto itself under x -> L - x, dropped without spin or
    horizontal speed: the drops at theta, -theta, pi - theta and pi + theta are mirror images of each other (mirrors
    in the vertical plane, the housing flipped over an axis), so the orientation table solves one of each four
    nodes (101 of the default scene's 404). Reference: every node solved directly (the landing then takes the
    corners in other orders): within 10 times the table solves' tolerance (1e-6; 2.8e-7 measured) near three
    faces; a wrong image is off by a factor (the side's peak is a fifth of the bottom's)."""
    from beamdrop_jax._studies import montecarlo as mc

    scene, n = bd.Scene.default(), mc._node_count()
    ks = np.array([10, 1805])  # 0.5 deg from flat on the bottom, 0.25 deg from a side
    nodes = np.concatenate([ks, (-ks) % n, (n // 2 - ks) % n, (n // 2 + ks) % n])
    solved, solve = [], mc.solve_landings

    def spy(samples, axes, idx, *args, **kwargs):
        solved.append(np.asarray(samples.drop.orientation)[np.asarray(idx)])
        return solve(samples, axes, idx, *args, **kwargs)

    monkeypatch.setattr(mc, "solve_landings", spy)
    table = mc.orientation_table(scene, nodes)
    rtol = 10 * mc.TABLE_NUMERICS.landing_tolerance
    np.testing.assert_allclose(solved[0], np.array([10, 1795]) * mc.ORIENTATION_STEP)  # 2 of 8
    samples = eqx.tree_at(lambda s: s.drop.orientation, scene, jnp.asarray(nodes * mc.ORIENTATION_STEP))
    direct = solve(samples, mc.sample_axes(samples, scene), np.arange(nodes.size), False, mc.TABLE_NUMERICS)
    for found, expected in zip(table.values[:3], direct[:3]):
        np.testing.assert_allclose(found, expected, rtol=rtol)
    assert not np.any(direct[3])
    # The table's solves step across the contacts' kinks at their tolerance: `simulate`'s (1e-10, kinks closed in
    # on) within 5e-4 (4e-5 measured over the default scene's nodes, 2.1e-4 on the JESD22 plate's).
    exact = solve(samples, mc.sample_axes(samples, scene), np.arange(nodes.size))
    assert not mc.TABLE_NUMERICS.landing_kinks
    for found, expected in zip(direct[:3], exact[:3]):
        np.testing.assert_allclose(found, expected, rtol=5e-4)
    counts = [np.unique(mc._representatives(s, mc._orientation_nodes(scene))).size for s in (
        scene, scene.replace(**{"placement.centre": jnp.array([0.0, 5e-3])}))]
    assert counts[0] <= 404 / 4 + 2 and counts[1] <= 404 / 2 + 2
    # What breaks each mirror.
    off = scene.replace(**{"placement.centre": jnp.array([1e-3, 1e-3])})
    assert mc._mirrors(scene) == ("x", "y") and mc._mirrors(off) == ()
    # Unlike ends keep the housing's flip (1.6e-11 measured at (4, 0) mm), not the mirror in x.
    unlike = eqx.tree_at(lambda s: s.board, scene, bd.Board(ends="clamped-pinned"))
    unlike = unlike.replace(**{"placement.centre": jnp.array([4e-3, 0.0])})
    flip = np.array([10, n // 2 - 10])
    samples = eqx.tree_at(lambda s: s.drop.orientation, unlike, jnp.asarray(flip * mc.ORIENTATION_STEP))
    found = np.stack(solve(samples, mc.sample_axes(samples, unlike), np.arange(2), False, mc.TABLE_NUMERICS)[:3])
    np.testing.assert_allclose(found[:, 0], found[:, 1], rtol=rtol)
    assert mc._mirrors(unlike) == ("y",)
    assert mc._mirrors(scene.replace(**{"placement.centre": jnp.array([0.0, 1e-3])})) == ("x",)
    for name, value in (("placement.angle", 0.01), ("drop.spin", 1.0), ("drop.horizontal_speed", 0.1)):
        assert mc._mirrors(scene.replace(**{name: value})) == (), name
    # A box (the default scene 0.1 m deep), untilted and moving in the plane, likewise.
    box = scene.replace(**{"housing.depth": 0.1})
    quad = np.array([10, n - 10, n // 2 - 10, n // 2 + 10])
    samples = eqx.tree_at(lambda s: s.drop.orientation, box, jnp.asarray(quad * mc.ORIENTATION_STEP))
    found = np.stack(solve(samples, mc.sample_axes(samples, box), np.arange(4), False, mc.TABLE_NUMERICS)[:3])
    np.testing.assert_allclose(found, np.repeat(found[:, :1], 4, axis=1), rtol=rtol)
    assert mc._mirrors(box) == ("x", "y") and not any(mc._mirrors(box.replace(**{f"drop.{name}": 0.01}))
                                                     for name in ("tilt", "side_speed", "spin_x", "spin_y"))


def test_landings_that_outgrow_the_first_step_limit_are_solved_again(monkeypatch):
    """`solve_landings` and `simulate` solve a near-flat landing with a short step limit first (a smaller dense
    buffer) and again with `Numerics.landing_steps` where that is not enough. Nearly plastic near-flat landings
    (restitution 0.012 to 0.017, 4900 to 6100 steps) outgrow a first limit of 4096; an ordinary one does not. The
    batch against `simulate` on each drop, to 1e-8: the two are different compiled programs (a batch and one drop),
    whose roundings differ by 1.6e-9 on some CPUs."""
    import beamdrop_jax._response.simulate as simulate_module
    from beamdrop_jax._studies import landings, montecarlo as mc

    monkeypatch.setattr(simulate_module, "FIRST_LANDING_STEPS", 4096)
    short = bd.Numerics(landing_steps=4096)
    scene = bd.Scene.default()
    cases = [(0.01569, 0.4705, 0.01215), (0.03335, 0.3091, 0.01623), (0.00920, 0.4220, 0.01727),
             (0.00873, 0.3, 0.4)]  # (orientation rad, friction, restitution)
    o, mu, e = (jnp.asarray(v) for v in zip(*cases))
    samples = eqx.tree_at(lambda s: (s.drop.orientation, s.contact.friction, s.contact.restitution), scene,
                          (o, mu, e))
    axes = mc.sample_axes(samples, scene)
    first = landings._solve_batches(samples, axes, np.arange(4), short, False)
    assert list(first[3] & bd.Flag.SOLVER_FAILED) == [bd.Flag.SOLVER_FAILED] * 3 + [0]
    stress, strain, deflection, flags = mc.solve_landings(samples, axes, np.arange(4), first=short)
    assert not np.any(flags)
    scenes = [scene.replace(**{"drop.orientation": theta, "contact.friction": f, "contact.restitution": r})
              for theta, f, r in cases]
    for i, one in enumerate(scenes):
        res = bd.simulate(one)
        assert float(res.landing_weight) > 0 and int(res.flags) == 0
        np.testing.assert_allclose([stress[i], strain[i], deflection[i]],
                                   [float(res.peak.stress), float(res.peak.strain), float(res.peak.deflection)],
                                   rtol=1e-8)
    assert first[0][3] == stress[3]  # a landing within the first limit: the same solve
    # A limit the user sets is kept (a flag and NaN); a bad one is named.
    kept = bd.simulate(scenes[0], short)
    assert int(kept.flags) & bd.Flag.SOLVER_FAILED and math.isnan(float(kept.peak.stress))
    # ... and the drop says what to raise, in the Python API and on the command line.
    from beamdrop_jax.cli import main
    from beamdrop_jax.cli._helpers import _cli_note

    note = [n for n in bd.response_notes(scenes[0], kept) if "step limit" in n]
    assert len(note) == 1 and "raise Numerics.landing_steps" in note[0]
    assert "raise --landing-steps (Numerics.landing_steps, 4096 here)" in _cli_note(note[0], short)
    with pytest.raises(SystemExit) as refused:
        main(["drop", "--landing-steps", "20", "--no-plots"])
    assert refused.value.code == 2
    with pytest.raises(ValueError, match="Numerics.landing_steps"):
        bd.Numerics(landing_steps=0)
    with pytest.raises(ValueError, match="Numerics.landing_kinks = 1; valid: True or False"):
        bd.Numerics(landing_kinks=1)


def test_landings_solved_from_several_threads_are_each_drops_own(monkeypatch):
    """`solve_landings` solves its batches of `LANDING_BATCH` near-flat drops from a thread per core: each drop's
    peaks are `simulate`'s on that drop (to 1e-8: a batch's program rounds differently, measured 3e-9), whatever
    batch and thread solved it, for drops asked for in any order (three batches, the last padded; two threads), and
    the same to the last bit as the batches solved one after another in one thread."""
    from beamdrop_jax._studies import landings, montecarlo as mc

    monkeypatch.setattr(landings, "_landing_threads", lambda: 2)
    scene = bd.Scene.default()
    degrees = np.array([0.0, 0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0, 1.2, 1.5, 179.9, 180.2, 180.5, 359.7,
                        359.4, 0.9, 0.7])
    samples = scene.replace(**{"drop.orientation": jnp.asarray(np.radians(degrees))})
    axes = mc.sample_axes(samples, scene)
    idx = np.random.default_rng(3).permutation(degrees.size)[:17]
    stress, strain, deflection, flags = mc.solve_landings(samples, axes, idx)
    assert not np.any(flags)
    monkeypatch.setattr(landings, "_landing_threads", lambda: 1)
    for a, b in zip((stress, strain, deflection), mc.solve_landings(samples, axes, idx)):
        np.testing.assert_array_equal(a, b)
    for k, i in enumerate(idx):
        res = bd.simulate(scene.replace(**{"drop.orientation": math.radians(degrees[i])}))
        assert float(res.landing_weight) > 0
        np.testing.assert_allclose([stress[k], strain[k], deflection[k]],
                                   [float(res.peak.stress), float(res.peak.strain), float(res.peak.deflection)],
                                   rtol=1e-8, err_msg=f"drop {i} ({degrees[i]} deg)")
