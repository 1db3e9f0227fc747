"""Drops of a box housing (`Housing(depth=...)`, `Drop(tilt=...)`): at tilt = 0 the plane section's answer, and the
box's own 3D law equal to it; a tilted drop's supports (a beam's ends, a plate's mounts) moved by the housing's
rigid motion at their points, checked against the rigid-body formula in NumPy; the plate's roll input against a
beam across its width; gradients in the tilt against central differences; scene files and errors.

Scenes share shapes: the default beam scene in a 60 mm deep box, and the embedded `phone` scene (a plate on six
screws), so each program compiles once."""

import equinox as eqx
import jax
import numpy as np
import pytest

import beamdrop_jax as bd
from beamdrop_jax._impact.kinematics import box_housing_impact, box_support_jumps
from beamdrop_jax._response.landing_path import scene_landing

DEPTH = 0.06


@pytest.fixture(scope="module")
def beam_box():
    return bd.Scene.default().replace(**{"housing.depth": DEPTH})


@pytest.fixture(scope="module")
def phone():
    return bd.load_scene("phone")


def _plane_of(scene):
    """The same scene as a plane section (no depth)."""
    h = scene.housing
    d = scene.drop
    return bd.Scene(bd.Housing(h.width, h.height, h.mass, h.radius_of_gyration), scene.board,
                    bd.Placement(scene.placement.centre, scene.placement.angle),
                    bd.Drop(d.orientation, d.height, d.spin, d.horizontal_speed), scene.contact)


def _rigid_normal_jumps(hit, scene, points_body):
    """NumPy: the normal velocity jump dV + dOmega x (R q) . (R n_body) at body points q (m, from G)."""
    R, dV, dW = (np.asarray(v) for v in (hit.attitude, hit.dV, hit.dOmega))
    phi = float(scene.placement.angle)
    n = R @ np.array([-np.sin(phi), np.cos(phi), 0.0])
    return np.array([(dV + np.cross(dW, R @ q)) @ n for q in points_body])


def test_tilt_zero_is_the_plane_section_and_the_box_law_agrees(beam_box, phone):
    for scene in (beam_box, phone):
        scene = eqx_contact(scene.replace(**{"drop.orientation": 0.5, "drop.tilt": 0.0}), "rigid")
        plane = bd.simulate(_plane_of(scene))
        box = bd.simulate(scene)
        for a, b in ((box.peak.stress, plane.peak.stress), (box.peak.strain, plane.peak.strain),
                     (box.peak.t, plane.peak.t)):
            # (The beam's agree to the last bit; the plate's peak search, in two compiled programs, to 1.5e-8.)
            np.testing.assert_allclose(float(a), float(b), rtol=1e-9 if scene.board is beam_box.board else 5e-8)
        # The box's own 3D law at its lowest edge's midpoint (not what the board followed) is the plane's impact.
        scale = float(np.abs(plane.housing.dv_G).max())
        np.testing.assert_allclose(box.box.dV[:2], plane.housing.dv_G, rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(box.box.dOmega[2], plane.housing.dw, rtol=1e-10)
        assert abs(float(box.box.dV[2])) < 1e-12 and np.abs(box.box.dOmega[:2]).max() < 1e-9
        jumps = np.asarray(box_support_jumps(scene, box.box))
        np.testing.assert_allclose(jumps[:2], plane.support_jumps, rtol=0, atol=1e-9 * scale)
        assert abs(jumps[2]) < 1e-9 * scale and float(box.roll_jump) == 0.0


def test_box_landing_is_the_plane_landing_at_tilt_zero_and_continuous_in_tilt(beam_box):
    # The box's compliant landing on its level edge along the depth is the plane section's on that corner: the
    # supports' drive through the whole peak window agrees (two integrators, 2D and 3D, to their tolerance).
    scene = beam_box.replace(**{"drop.orientation": 0.5})
    plane = _plane_of(scene)
    window = 3e-3
    box_landing = scene_landing(scene, window)
    plane_landing = scene_landing(plane, window)
    t = np.linspace(0.0, window, 31)
    ends = np.asarray(bd.board_ends(scene.placement, scene.board.length))
    v3 = np.asarray(box_landing.contact_velocity(t, np.concatenate([ends, np.zeros((2, 1))], axis=1)))
    v2 = np.asarray(plane_landing.contact_velocity(t, ends))
    scale = np.abs(v2).max()
    np.testing.assert_allclose(v3[..., :2], v2, rtol=0, atol=1e-7 * scale)
    assert np.abs(v3[..., 2]).max() < 1e-9 * scale  # no motion out of the plane
    # The public name lands the same box (a `BoxLanding` from `compliant_landing` given a box housing).
    d = scene.drop
    public = bd.compliant_landing(scene.housing, scene.contact, d.orientation, np.asarray(d.velocity()),
                                  np.asarray(d.angular_velocity()), tilt=d.tilt, until=window)
    assert isinstance(public, bd.BoxLanding)
    np.testing.assert_allclose(np.asarray(public.P), np.asarray(box_landing.P), rtol=0,
                               atol=1e-9 * np.abs(box_landing.P).max())
    P = np.asarray(box_landing.P)  # vertex (s1, s2, s3): corner (s1, s2) of the plane, two vertices each
    corners = {(1, 1): 0, (0, 1): 1, (0, 0): 2, (1, 0): 3}  # `housing_corners`' order
    for (s1, s2), k in corners.items():
        pair = P[4 * s1 + 2 * s2] + P[4 * s1 + 2 * s2 + 1]
        np.testing.assert_allclose(pair[:2], np.asarray(plane_landing.P)[k], rtol=0,
                                   atol=1e-7 * np.abs(plane_landing.P).max())
    # `simulate` on "auto", near-flat in the plane: the plane section and the box at tilt 0 both land compliantly
    # (2D and 3D landings), and a hair of tilt changes nothing.
    near_flat = scene.replace(**{"drop.orientation": 0.01})
    box_runs = [bd.simulate(near_flat.replace(**{"drop.tilt": tilt})) for tilt in (0.0, 1e-7)]
    flat = bd.simulate(_plane_of(near_flat))
    assert float(flat.landing_weight) == 1.0 and float(box_runs[0].landing_weight) == 1.0
    for run in box_runs:
        np.testing.assert_allclose(float(run.peak.strain), float(flat.peak.strain), rtol=1e-6)
    # On a corner (30 deg): at tilt 0 the plane's rigid answer; tilted, the edge along the depth lands as one
    # contact while its second vertex strikes within a contact duration of the first, and the 3D rigid law at the
    # lowest vertex takes over over the next two: no jump anywhere.
    tilts = [0.0, 1e-7, 0.005, 0.01, 0.0125, 0.015, 0.0175, 0.02, 0.0225, 0.025, 0.0275, 0.03]
    plane = bd.simulate(_plane_of(beam_box))
    runs = [bd.simulate(beam_box.replace(**{"drop.tilt": tilt})) for tilt in tilts]
    strain = np.array([float(r.peak.strain) for r in runs])
    np.testing.assert_allclose(strain[:2], float(plane.peak.strain), rtol=1e-9)
    vertex = bd.simulate(eqx_contact(beam_box.replace(**{"drop.tilt": tilts[-1]}), "rigid"))
    np.testing.assert_allclose(strain[-1], float(vertex.peak.strain), rtol=1e-9)
    assert strain[0] / strain[-1] > 1.2  # the edge and the lone vertex differ ...
    assert np.abs(np.diff(strain) / strain[:-1]).max() < 0.08  # ... and the tilt goes from one to the other smoothly


def test_tilted_drop_moves_each_support_with_the_housing(beam_box, phone):
    # A beam's ends at their depth.
    scene = beam_box.replace(**{"drop.tilt": 0.3, "placement.depth_offset": 0.004, "placement.angle": 0.2,
                                "placement.centre": (0.01, -0.005)})
    res = bd.simulate(scene)
    assert not bool(res.box.tied) and not int(res.flags)
    ends = np.asarray(bd.board_ends(scene.placement, scene.board.length))
    ref = _rigid_normal_jumps(res.box, scene, [np.append(e, 0.004) for e in ends])
    np.testing.assert_allclose(res.support_jumps, ref, rtol=1e-12)
    # A plate's mounts: the rigid motion at each, from its body point (x along the board, y along e3).
    res = bd.simulate(phone)
    mounts = np.asarray(phone.board.mounts)
    L = float(phone.board.length)
    q = [np.array([-L / 2 + x, 0.0, y]) for x, y in mounts]  # the plate centred on G, along e1
    ref = _rigid_normal_jumps(res.box, phone, q)
    np.testing.assert_allclose(res.mount_jumps, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    # Near and far screws (same x, y = -27.5 and +27.5 mm) are kicked differently by a tilted corner strike.
    across = np.abs(ref[1::2] - ref[0::2])
    assert across.min() > 0.3 * np.abs(ref).max(), (ref, across)


def test_plate_roll_input_is_a_beam_across_the_width():
    """An FSFS plate (free ends, simply supported long sides) with nu = 0 under the roll input bends as a pinned
    beam of span W whose ends move -dvR/2 and +dvR/2 (cylindrical bending)."""
    L, W = 0.1, 0.05
    plate = bd.Plate(length=L, width=W, thickness=1e-3, youngs_modulus=22e9, density=1900.0, poisson_ratio=0.0,
                     edges="FSFS", basis=(4, 24))
    beam = bd.Board(length=W, width=L, thickness=1e-3, youngs_modulus=22e9, density=1900.0)
    p = np.asarray(bd._board.base.support_participation(plate, 48))
    rolling = np.abs(p[:, 2]) > 1e-9
    f_plate = np.asarray(bd.natural_frequencies(plate, 48))[rolling][:3]
    k = np.array([2, 4, 6])  # the beam's antisymmetric modes: 2 (-1)^k / (k pi) / 2 + 2 / (k pi) / 2
    np.testing.assert_allclose(f_plate, np.asarray(bd.natural_frequencies(beam, 6))[k - 1], rtol=1e-6)
    np.testing.assert_allclose(np.abs(p[rolling, 2][:3]), 2 / (k * np.pi), rtol=1e-5)
    assert np.abs(p[~rolling, 2]).max() < 1e-9
    rolled = bd.board_response(plate, bd.HalfSine(0.0, 0.0, 5e-4, 2.0), bd.Numerics(max_modes=48))
    bent = bd.board_response(beam, bd.HalfSine(-1.0, 1.0, 5e-4), bd.Numerics(n_modes=32))
    assert abs(float(rolled.peak.y)) == pytest.approx(W / 2 - float(bent.peak.x), abs=2e-4)
    assert float(rolled.peak.stress) == pytest.approx(float(bent.peak.stress),
                                                      rel=float(rolled.error_estimate) + 5e-4)


def test_gradients_in_tilt_and_orientation_match_central_differences(beam_box):
    scene = beam_box.replace(**{"drop.tilt": 0.3, "drop.orientation": 0.45})
    numerics = bd.Numerics()
    f = lambda s: bd.peak_stress(s, numerics)  # noqa: E731
    grad = jax.grad(f)(scene)
    for path, g in (("drop.tilt", grad.drop.tilt), ("drop.orientation", grad.drop.orientation)):
        x = float(np.asarray(eval(f"scene.{path}")))  # noqa: S307 - a dotted field path
        h = 1e-4
        values = [float(f(scene.replace(**{path: x + k * h}))) for k in (-2, -1, 1, 2)]
        fd = (values[0] - 8 * values[1] + 8 * values[2] - values[3]) / (12 * h)
        assert float(g) == pytest.approx(fd, rel=1e-3, abs=1e-6 * abs(float(f(scene)))), (path, float(g), fd)


def test_scene_files_and_errors(tmp_path, beam_box):
    scene = beam_box.replace(**{"drop.tilt": 0.25, "placement.depth_offset": 0.003})
    path = tmp_path / "box.toml"
    bd.save_scene(scene, path)
    text = path.read_text()
    assert "depth = 0.06" in text and "tilt_deg = " in text
    back = bd.load_scene(path)
    assert float(back.drop.tilt) == pytest.approx(0.25, rel=1e-12)
    assert float(back.housing.depth) == DEPTH and float(back.placement.depth_offset) == 0.003
    given = bd.Scene(housing=bd.Housing(depth=0.06, inertia=(3e-4, 4e-4, 4.2e-4)))
    bd.save_scene(given, path)
    np.testing.assert_allclose(bd.load_scene(path).housing.moments, (3e-4, 4e-4, 4.2e-4))
    bad = [
        ('extends = "default"\n[drop]\ntilt = 0.3\n', "tilt_deg"),
        ('extends = "default"\n[housing]\ndepth = -0.01\n', "depth"),
        ('extends = "default"\n[housing]\nprincipal_inertia = [1e-4, 1e-4]\n', "principal_inertia"),
        ('extends = "default"\n[housing]\ndepth = 0.02\n', "depth/2"),  # the 50 mm board does not fit
    ]
    for body, named in bad:
        path.write_text(body)
        with pytest.raises(ValueError, match=named):
            bd.load_scene(path)
    with pytest.raises(ValueError, match="depth"):
        bd.Housing(inertia=(1e-4, 1e-4, 1e-4))
    with pytest.raises(ValueError, match="triangle"):
        bd.Housing(depth=0.06, inertia=(1e-4, 1e-4, 3e-4))
    tilted = scene.replace(**{"drop.tilt": 0.3})
    with pytest.raises(ValueError, match="max_impacts"):
        bd.simulate(tilted, bd.Numerics(max_impacts=2))
    with pytest.raises(ValueError, match="from_rest = True with Drop.spin"):
        bd.simulate(tilted.replace(**{"drop.spin": 3.0}), bd.Numerics(from_rest=True))
    # Under jit the same drop is flagged, never a silent number.
    res = jax.jit(lambda s: bd.simulate(s, bd.Numerics(max_impacts=2)))(tilted)
    assert int(res.flags) & bd.Flag.OUT_OF_PLANE and np.isnan(float(res.peak.stress))


def eqx_contact(scene, model):
    import equinox as eqx

    return eqx.tree_at(lambda s: s.contact, scene, scene.contact.with_model(model))


def test_campaign_on_a_box_has_every_drop_and_edges_translate(beam_box):
    """ISTA 1A on a box: every row finite (faces 5 and 6 too). A drop from rest with G above an edge's midpoint
    is a central impact that translates the box, so the board sees the face drop's velocity change times the
    cosine of the tilt: edge 3-5 against face 3 (rigid law), exactly."""
    scene = eqx_contact(beam_box, "rigid")
    result = bd.campaign(scene, "ista-1a")
    labels = [d.label for d in result.drops]
    assert np.all(np.isfinite(result.stress)) and len(labels) == 10
    face3, edge35 = labels.index("face 3"), labels.index("edge 3-5")
    tilt = result.drops[edge35].tilt
    assert tilt == pytest.approx(np.arctan2(DEPTH / 2, float(scene.housing.height) / 2), rel=1e-12)
    assert result.stress[edge35] == pytest.approx(np.cos(tilt) * result.stress[face3], rel=1e-9)
    # Faces 5 and 6 move the board along itself: no bending; the corner drop bends it.
    for label in ("face 5", "face 6"):
        assert abs(result.stress[labels.index(label)]) < 1e-6 * result.stress[face3]
    assert result.stress[labels.index("corner 2-3-5")] > 0.1 * result.stress[face3]
    assert "tilt (deg)" in result.table()


def test_montecarlo_over_uniform_attitudes(beam_box):
    """`DropDistribution.rotations()`: the body's downward direction (-sin theta cos tilt, -cos theta cos tilt,
    sin tilt) is uniform on the sphere (each component's mean 0 and mean square 1/3); the superposed peaks of a box
    drop are its `simulate` peaks (the table's bound: at most 6.4e-5 below)."""
    scene = eqx_contact(beam_box, "rigid")
    res = bd.montecarlo(scene, 512, jax.random.PRNGKey(3), bd.DropDistribution.rotations(), progress=False)
    theta, tilt = np.asarray(res.samples.drop.orientation), np.asarray(res.samples.drop.tilt)
    down = np.stack([-np.sin(theta) * np.cos(tilt), -np.cos(theta) * np.cos(tilt), np.sin(tilt)], axis=-1)
    assert np.abs(down.mean(axis=0)).max() < 4 / np.sqrt(3 * 512)  # 4 standard errors
    np.testing.assert_allclose((down**2).mean(axis=0), 1 / 3, atol=4 * np.sqrt(4 / 45 / 512))
    assert not np.any(res.flags) and np.all(np.isfinite(res.peak_stress))
    for i in (0, 1, 2):
        one = scene.replace(**{"drop.orientation": theta[i], "drop.tilt": tilt[i]})
        exact = float(bd.simulate(one).peak.stress)
        assert exact * (1 - 1e-4) <= float(res.peak_stress[i]) <= exact * (1 + 1e-9), (i, res.peak_stress[i], exact)
    with pytest.raises(ValueError, match="depth"):
        bd.montecarlo(bd.Scene.default(), 8, jax.random.PRNGKey(0), bd.DropDistribution.rotations(), progress=False)


def test_mount_gradient_on_a_tilted_phone_and_optimize_mounts_over_3d_drops(phone):
    """d(peak strain)/d(a screw's position) on the tilted phone against central differences, and optimize_mounts
    over two 3D attitudes returns a layout whose strain it reports truthfully (recomputed here)."""
    # The rigid law: at 25 deg of tilt one vertex strikes alone ("auto" would compile the compliant landing too).
    phone = eqx_contact(phone, "rigid")
    numerics = bd.Numerics(n_modes=8)
    strain = eqx.filter_jit(lambda scene: bd.peak_strain(scene, numerics))  # one program for every scene below
    f = lambda m: strain(eqx_tree_mounts(phone, m))  # noqa: E731
    m0 = phone.board.mounts
    g = np.asarray(jax.grad(lambda m: f(m))(m0))
    h = 1e-5
    for i, j in ((1, 0), (6, 1)):
        e = np.zeros(m0.shape)
        e[i, j] = h
        fd = (float(f(m0 + e)) - float(f(m0 - e))) / (2 * h)
        assert g[i, j] == pytest.approx(fd, rel=2e-3, abs=1e-4 * abs(fd) + 1e-9), (i, j, g[i, j], fd)
    res = bd.optimize_mounts(phone, orientations=[0.35, 2.5], tilts=[0.44, -0.3], numerics=numerics, steps=3,
                             starts=1, progress=False)
    assert res.n_drops == 2 and np.isfinite(float(res.value))
    drops = [phone.replace(**{"drop.orientation": th, "drop.tilt": ti}) for th, ti in ((0.35, 0.44), (2.5, -0.3))]
    moved = [float(strain(eqx_tree_mounts(d, res.mounts))) for d in drops]
    assert float(res.value) == pytest.approx(np.mean(moved), rel=1e-6)


def eqx_tree_mounts(scene, mounts):
    import equinox as eqx

    return eqx.tree_at(lambda s: s.board.mounts, scene, mounts)


def test_cli_impact_of_a_tilted_box(tmp_path, capsys):
    from beamdrop_jax.cli import main

    # In this process: --no-cache, so the command leaves JAX's compilation cache settings as the tests have them.
    assert main(["impact", "--scene", "phone", "--json", "--no-plots", "--no-cache", "--out", str(tmp_path)]) == 0
    import json

    report = json.loads(capsys.readouterr().out)
    from beamdrop_jax._response.simulate import drop_motion

    motion = drop_motion(bd.load_scene("phone"))[0]  # what simulate drives the board with
    np.testing.assert_allclose(report["board_jumps_A_B_roll_m_per_s"], motion.first_jumps(), rtol=1e-12)
    assert report["struck_point_from_G_mm"] == pytest.approx([-75.0, -4.0, 37.5])
    assert main(["impact", "--scene", "phone", "--law", "newton", "--no-plots", "--no-cache", "--out",
                 str(tmp_path)]) == 2
    assert "poisson or stronge" in capsys.readouterr().err


def test_optimize_placement_over_3d_drops(beam_box, tmp_path, capsys):
    """`optimize_placement(tilts=...)` pairs each orientation with a tilt: its objective is the mean of each
    drop's own peak stress, and the jumps along the board it reports are the box's 3D rigid motion at the ends."""
    from beamdrop_jax.cli import main

    scene = beam_box.replace(**{"contact.model": "rigid"})
    numerics = bd.Numerics(n_modes=4)
    orientations, tilts = np.radians([30.0, 50.0]), np.array([0.3, -0.2])
    res = bd.optimize_placement(scene, orientations, tilts=tilts, numerics=numerics, steps=1, starts=1,
                                progress=False)
    each = [float(bd.peak_stress(scene.replace(**{"drop.orientation": th, "drop.tilt": ti}), numerics))
            for th, ti in zip(orientations, tilts)]
    np.testing.assert_allclose(float(res.initial_value), np.mean(each), rtol=1e-9)
    flat = bd.optimize_placement(scene, orientations, numerics=numerics, steps=1, starts=1, progress=False)
    assert abs(float(flat.initial_value) / float(res.initial_value) - 1) > 0.05  # the tilts change the drops
    for (th, ti), along in zip(zip(orientations, tilts), np.asarray(res.along_before)):
        hit = box_housing_impact(scene.replace(**{"drop.orientation": th, "drop.tilt": ti}))
        R, dV, dW = (np.asarray(v) for v in (hit.attitude, hit.dV, hit.dOmega))
        half = 0.5 * float(scene.board.length)
        ends = [np.array([-half, 0.0, 0.0]), np.array([half, 0.0, 0.0])]  # the scene's board: centred, level
        np.testing.assert_allclose(along, [(dV + np.cross(dW, R @ q)) @ (R @ [1.0, 0.0, 0.0]) for q in ends],
                                   rtol=1e-9, atol=1e-12)
    assert main(["optimize", "--tilts", "10", "--orientations", "30,40", "--no-plots"]) == 2
    assert "--tilts turns a box housing out of the plane of motion" in capsys.readouterr().err


def _box_contact_numpy(scene):
    """NumPy, from the box's geometry alone: the struck vertex's arm r (ground frame), the contact's inverse
    inertia K and approach velocity u0 in the frame (t1, t2, n) = (x, z, y), with G falling from the drop height
    at (horizontal_speed, -sqrt(2 g h), side_speed) and turning at (spin_x, spin_y, spin)."""
    h, d = scene.housing, scene.drop
    W, H, D, m = (float(v) for v in (h.width, h.height, h.depth, h.mass))
    th, ti = float(d.orientation), float(d.tilt)
    Rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(ti), -np.sin(ti)], [0, np.sin(ti), np.cos(ti)]])
    R = Rx @ Rz
    corners = np.array([[sx * W, sy * H, sz * D] for sx in (-.5, .5) for sy in (-.5, .5) for sz in (-.5, .5)])
    arms = corners @ R.T
    r = arms[np.argmin(arms[:, 1])]
    inertia = R @ np.diag(m / 12 * np.array([H**2 + D**2, W**2 + D**2, W**2 + H**2])) @ R.T
    X = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    K = np.eye(3) / m + X.T @ np.linalg.solve(inertia, X)
    v = np.array([float(d.horizontal_speed), -np.sqrt(2 * 9.80665 * float(d.height)), float(d.side_speed)])
    w = np.array([float(d.spin_x), float(d.spin_y), float(d.spin)])
    u = v + np.cross(w, r)
    order = [0, 2, 1]
    return r, K[np.ix_(order, order)], u[order]


def test_motion_out_of_the_plane_reaches_the_3d_law(beam_box):
    """`Drop.side_speed`, `spin_x` and `spin_y` enter a tilted box's impact: its impulse equals the independent
    event-driven SciPy integrator's on K and u0 built in NumPy from the box (to 1e-8), and each changes the
    answer; a plane section refuses them by name, and scene files carry them."""
    from reference_impact3d import event_driven_impulse

    base = beam_box.replace(**{"drop.tilt": 0.3, "drop.orientation": 0.4})
    moving = base.replace(**{"drop.side_speed": 0.8, "drop.spin_x": 4.0, "drop.spin_y": -6.0, "drop.spin": 2.0,
                             "drop.horizontal_speed": -0.3})
    res = bd.simulate(moving)
    r, K, u0 = _box_contact_numpy(moving)
    np.testing.assert_allclose(np.asarray(res.box.r), r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(res.box.impact.velocity) - np.asarray(res.box.K) @ np.asarray(
        res.box.impact.P), u0, rtol=0, atol=1e-12)
    ref = event_driven_impulse(K, u0, float(moving.contact.friction), float(moving.contact.restitution))
    P = np.asarray(res.box.impact.P)
    assert np.abs(P - ref["P"]).max() <= 1e-8 * np.abs(ref["P"]).max(), (P, ref["P"], ref["modes"])
    assert int(res.flags) == 0 and np.isfinite(float(res.peak.stress))
    still = float(bd.simulate(base).peak.stress)
    for name, value in (("side_speed", 0.8), ("spin_x", 4.0), ("spin_y", -6.0)):
        changed = float(bd.simulate(base.replace(**{f"drop.{name}": value})).peak.stress)
        assert abs(changed / still - 1) > 1e-4, name
    with pytest.raises(ValueError, match="Drop.side_speed = 0.5 m/s"):
        bd.Scene.default().replace(**{"drop.side_speed": 0.5})
    with pytest.raises(ValueError, match="DropDistribution.spin_x .* Housing.depth"):
        bd.montecarlo(bd.Scene.default(), 8, jax.random.PRNGKey(0), bd.DropDistribution(spin_x=("uniform", 0, 1)))
    with pytest.raises(ValueError, match="from_rest = True with Drop.side_speed"):
        bd.simulate(base.replace(**{"drop.side_speed": 0.1}), bd.Numerics(from_rest=True))


def test_an_edge_struck_with_motion_out_of_the_plane(beam_box, tmp_path):
    """At tilt 0 the box lands on an edge along the depth. With motion out of the plane its two vertices strike
    together but unequally: the rigid law refuses it by name; `"auto"` keeps the plane section's answer while the
    asymmetry is small and lands compliantly beyond, continuously in the side speed (no step over 2 % per
    0.02 m/s through the blend), and `"compliant"` agrees with `"auto"` where the asymmetry is large."""
    plane = float(bd.simulate(beam_box).peak.stress)
    with pytest.raises(ValueError, match="model='auto'"):
        bd.simulate(beam_box.replace(**{"drop.side_speed": 0.3, "contact.model": "rigid"}))
    speeds = np.array([0.0, 1e-3, 0.04, 0.06, 0.08, 0.10, 0.12, 0.14, 0.16, 0.18, 0.20])  # the blend: 0.054-0.16
    peaks = []
    for u in speeds:
        res = bd.simulate(beam_box.replace(**{"drop.side_speed": float(u)}))
        assert int(res.flags) == 0
        peaks.append(float(res.peak.stress))
    peaks = np.array(peaks)
    assert peaks[1] == pytest.approx(plane, rel=1e-12)
    assert np.max(np.abs(np.diff(peaks)) / peaks[:-1]) < 0.02, peaks
    compliant = float(bd.simulate(beam_box.replace(**{"drop.side_speed": 0.2, "contact.model": "compliant"}))
                      .peak.stress)
    assert peaks[-1] == pytest.approx(compliant, rel=1e-9)
    path = tmp_path / "side.toml"
    path.write_text('extends = "default"\n[housing]\ndepth = 0.06\n[drop]\nside_speed = 0.3\nspin_x = 1.5\n'
                    'tilt_deg = 10\n')
    back = bd.load_scene(path)
    assert float(back.drop.side_speed) == 0.3 and float(back.drop.spin_x) == 1.5
    bd.save_scene(back, tmp_path / "again.toml")
    assert float(bd.load_scene(tmp_path / "again.toml").drop.spin_x) == 1.5


def test_plate_montecarlo_over_attitudes_uses_a_table_over_the_sphere():
    """A plate in a box dropped in random attitudes rolls its supports across the width: `montecarlo` superposes
    over a table of jump directions on the sphere (dvA, dvB, dvR; the JESD22 board in a 100 mm deep box, its
    mirror images in x and y built from a quarter of the directions). The peaks are fields at points of the plate,
    so they agree with a dense search (16 points per period, 8 candidates, 8 Newton steps) to the table's
    direction spacing: within 1e-3 below (the deflection 3e-3) and 1e-4 above, on 24 random attitudes (each
    drop's own search; measured 4.2e-4 below) and on 24 random jumps of any direction (`board_response` of the
    half-sine with roll; measured 8.3e-4 below, the deflection 2.1e-3)."""
    import dataclasses

    import jax.numpy as jnp

    from beamdrop_jax._response.superposition import table_numerics
    from beamdrop_jax._studies import montecarlo as mc
    from beamdrop_jax._studies.montecarlo import evaluate_batch, sample_axes

    scene = eqx_contact(bd.load_scene("jesd22-board"), "rigid").replace(**{"housing.depth": 0.1})
    result = bd.montecarlo(scene, 24, jax.random.PRNGKey(6), bd.DropDistribution.rotations(), progress=False)
    assert result.n_invalid == 0
    dense = dataclasses.replace(table_numerics(scene), points_per_period=16, candidates=8, newton_steps=8)
    reference = evaluate_batch(result.samples, sample_axes(result.samples, scene),
                               dataclasses.replace(dense, from_rest=True), False, 8)
    assert not np.any(np.asarray(reference[3]))
    table = mc._kept_superposition(scene, table_numerics(scene), None, True)  # `montecarlo`'s, kept: not built again
    assert table.rolls and table.mirrors == (True, True) and table.fields.shape[0] == 33 * 33
    jumps = jax.random.normal(jax.random.PRNGKey(7), (24, 3))
    found = np.asarray(jax.vmap(lambda j: table.peaks(scene.board, j))(jumps))
    tau = scene.contact.duration

    @jax.jit
    def searched(j):
        res = bd.board_response(scene.board, bd.HalfSine(j[0], j[1], tau, j[2]), dense)
        return jnp.stack([res.peak.stress, res.peak.strain, res.peak.deflection])

    direct = np.stack([np.asarray(searched(j)) for j in jumps])
    for k, (a, b) in enumerate([*zip((result.peak_stress, result.peak_strain, result.peak_deflection), reference),
                                *zip(found.T, direct.T)]):
        ratio = np.asarray(a) / np.asarray(b)
        below = 3e-3 if k % 3 == 2 else 1e-3  # a deflection's maximiser can jump between two corners
        assert 1 - below <= ratio.min() and ratio.max() <= 1 + 1e-4, (k, ratio.min(), ratio.max())
    with pytest.raises(ValueError, match="rolls=True"):
        bd.superposition_table(bd.Scene.default(), rolls=True)
