"""Scenes: validation (eager errors, flags under jit), TOML round trip, batching."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import beamdrop_jax as bd


@pytest.mark.parametrize(
    "build, field, shown",
    [
        (lambda: bd.Housing(width=0.0), "Housing.width", "[0.0001, 100] m"),
        (lambda: bd.Housing(height=-0.1), "Housing.height", "[0.0001, 100] m"),
        (lambda: bd.Housing(mass=0.0), "Housing.mass", "[1e-06, 100000] kg"),
        (lambda: bd.Housing(radius_of_gyration=-1.0), "Housing.radius_of_gyration", "[1e-05, 100] m"),
        (lambda: bd.Board(length=0.0), "Board.length", "[0.0001, 100] m"),
        (lambda: bd.Board(thickness=-1e-3), "Board.thickness", "[1e-06, 10] m"),
        (lambda: bd.Board(youngs_modulus=0.0), "Board.youngs_modulus", "[1, 1e+13] Pa"),
        (lambda: bd.Board(density=-1.0), "Board.density", "[0.001, 1e+06] kg/m^3"),
        (lambda: bd.Board(damping_ratio=1.0), "Board.damping_ratio", "[0, 1)"),
        (lambda: bd.Board(axial_force=-100.0), "Board.axial_force", "(-90.4"),
        (lambda: bd.Board(length=float("nan")), "Board.length", "finite"),
        (lambda: bd.Contact(restitution=1.2), "Contact.restitution", "[0, 1]"),
        (lambda: bd.Contact(friction=-0.1), "Contact.friction", "[0"),
        (lambda: bd.Contact(duration=-1e-4), "Contact.duration", "[0"),
        (lambda: bd.Drop(height=-1.0), "Drop.height", "[0"),
        (lambda: bd.Drop(orientation=float("inf")), "Drop.orientation", "finite"),
        (lambda: bd.Placement(centre=(0.0, float("nan"))), "Placement.centre", "finite"),
        (lambda: bd.Scene(placement=bd.Placement(centre=(0.03, 0.0))), "outside the housing", "0.075"),
        (lambda: bd.Scene(placement=bd.Placement(angle=math.pi / 2)), "outside the housing", "0.0375"),
    ],
)
def test_validation_errors_name_field_and_range(build, field, shown):
    with pytest.raises(ValueError) as err:
        build()
    assert field in str(err.value)
    assert shown in str(err.value)


def test_buckling_limit_is_euler_load():
    board = bd.Board()
    EI = 22e9 * 0.05 * 1e-3**3 / 12
    np.testing.assert_allclose(board.buckling_force, EI * math.pi**2 / 0.1**2, rtol=1e-14)
    bd.Board(axial_force=-0.999 * float(board.buckling_force))
    with pytest.raises(ValueError, match="Board.axial_force"):
        bd.Board(axial_force=-float(board.buckling_force))


def test_flags_under_jit():
    scene = bd.Scene.default()

    @jax.jit
    def flags_of(e, mu, tau, force, c1, h):
        s = scene.replace(
            **{
                "contact.restitution": e,
                "contact.friction": mu,
                "contact.duration": tau,
                "board.axial_force": force,
                "drop.height": h,
            }
        )
        s = eqx_tree_at_centre(s, c1)
        return bd.scene_flags(s)

    ok = flags_of(0.5, 0.3, 5e-4, 0.0, 0.0, 1.5)
    assert int(ok) == 0
    cases = {
        bd.Flag.RESTITUTION_RANGE: (1.5, 0.3, 5e-4, 0.0, 0.0, 1.5),
        bd.Flag.FRICTION_NEGATIVE: (0.5, -0.3, 5e-4, 0.0, 0.0, 1.5),
        bd.Flag.DURATION_NEGATIVE: (0.5, 0.3, -5e-4, 0.0, 0.0, 1.5),
        bd.Flag.BUCKLED: (0.5, 0.3, 5e-4, -1e3, 0.0, 1.5),
        bd.Flag.BOARD_OUTSIDE_HOUSING: (0.5, 0.3, 5e-4, 0.0, 0.05, 1.5),
        bd.Flag.HEIGHT_RANGE: (0.5, 0.3, 5e-4, 0.0, 0.0, -1.0),
        bd.Flag.NONFINITE_INPUT: (0.5, 0.3, 5e-4, 0.0, 0.0, float("nan")),
    }
    for flag, args in cases.items():
        assert int(flags_of(*args)) & flag, flag
    # Above 1000 m (a 140 m/s impact, past any device's terminal speed in air) is out of range too.
    assert int(flags_of(0.5, 0.3, 5e-4, 0.0, 0.0, 1e300)) == bd.Flag.HEIGHT_RANGE


def eqx_tree_at_centre(scene, c1):
    import equinox as eqx

    return eqx.tree_at(lambda s: s.placement.centre, scene, jnp.stack([c1, jnp.zeros_like(c1)]))


def test_toml_round_trip(tmp_path):
    scene = bd.Scene(
        housing=bd.Housing(width=0.16, height=0.08, mass=0.2, radius_of_gyration=0.05),
        board=bd.Board(length=0.09, axial_force=3.0, damping_ratio=0.02),
        placement=bd.Placement(centre=(0.01, -0.01), angle=0.1),
        drop=bd.Drop(orientation=1.1, height=0.8, spin=2.0, horizontal_speed=-0.5),
        contact=bd.Contact(friction=0.4, restitution=0.3, duration=1e-4),
    )
    path = tmp_path / "scene.toml"
    bd.save_scene(scene, path)
    text = path.read_text()
    assert "orientation_deg" in text and "angle_deg" in text
    back = bd.load_scene(path)
    for a, b in zip(jax.tree_util.tree_leaves(scene), jax.tree_util.tree_leaves(back)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-16)


def test_embedded_scenes_load_and_default_matches_design():
    assert {"default", "jedec", "thesis"} <= set(bd.embedded_scenes())
    s = bd.Scene.default()
    np.testing.assert_allclose(s.drop.orientation, math.radians(30), rtol=1e-14)
    np.testing.assert_allclose([s.housing.width, s.housing.height, s.housing.mass], [0.15, 0.075, 0.18])
    np.testing.assert_allclose(s.housing.radius_of_gyration, math.sqrt((0.15**2 + 0.075**2) / 12), rtol=1e-14)
    with pytest.raises(FileNotFoundError, match="embedded scenes"):
        bd.load_scene("nonexistent")


def test_unknown_toml_keys_are_named(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[housing]\nwidht = 0.1\n")
    with pytest.raises(ValueError, match="widht"):
        bd.load_scene(path)
    path.write_text("[housng]\nwidth = 0.1\n")
    with pytest.raises(ValueError, match="housng"):
        bd.load_scene(path)


def random_scenes(n, seed=0):
    """A batch of n valid scenes (a Scene whose leaves have a leading axis n), on the rigid law (the first strike:
    a traced scene on "auto" would compute the compliant landing too, for every drop)."""
    rng = np.random.default_rng(seed)
    base = bd.Scene.default()
    base = bd.Scene(base.housing, base.board, base.placement, base.drop, base.contact.with_model("rigid"))
    th = rng.uniform(0.05, 2 * np.pi - 0.05, n)
    th = np.where(np.abs(np.sin(2 * th)) < 0.05, th + 0.1, th)
    updates = {
        "drop.orientation": th,
        "drop.height": rng.uniform(0.3, 2.0, n),
        "drop.spin": rng.uniform(-5, 5, n),
        "drop.horizontal_speed": rng.uniform(-1, 1, n),
        "contact.friction": rng.uniform(0.0, 1.0, n),
        "contact.restitution": rng.uniform(0.0, 1.0, n),
        "placement.angle": rng.uniform(-0.2, 0.2, n),
    }
    batch = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), base)
    return batch.replace(**updates)


def test_a_file_can_extend_a_scene_that_extends_another(tmp_path):
    # jesd22-board extends jedec: a file extending jesd22-board gets both, and changes only what it gives.
    jesd = bd.load_scene("jesd22-board")
    thicker = tmp_path / "thicker.toml"
    thicker.write_text('extends = "jesd22-board"\n[plate]\nthickness = 1.2e-3\n[drop]\nheight = 1.0\n')
    scene = bd.load_scene(thicker)
    assert float(scene.board.thickness) == 1.2e-3 and float(scene.drop.height) == 1.0
    np.testing.assert_array_equal(scene.board.mounts, jesd.board.mounts)
    assert scene.board.edges == jesd.board.edges and float(scene.housing.mass) == float(jesd.housing.mass)
    # A [board] (a beam) replaces the base's [plate] whole, so every key is needed, and the error says why.
    beam = tmp_path / "beam.toml"
    beam.write_text('extends = "jesd22-board"\n[board]\nlength = 0.1\n')
    with pytest.raises(ValueError, match=r"\[board\]: missing 'thickness'.*board is a \[plate\], which a \[board\] "
                                         r"replaces whole: give every \[board\] key"):
        bd.load_scene(beam)


def test_vmap_over_scenes_equals_loop():
    n = 1000
    batch = random_scenes(n)

    def one(scene):
        hit = bd.housing_impact(scene)
        return hit.impact.P, bd.support_jumps(scene, hit), hit.flags

    P, jumps, flags = jax.jit(jax.vmap(one))(batch)
    for i in range(0, n, 37):
        scene_i = jax.tree_util.tree_map(lambda x: x[i], batch)
        hit = bd.housing_impact(scene_i)
        np.testing.assert_allclose(P[i], hit.impact.P, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(jumps[i], bd.support_jumps(scene_i, hit), rtol=1e-13, atol=1e-15)
    # Loop the full batch through the jitted single-scene function too (cheap), all 1000.
    one_jit = jax.jit(one)
    loop = [one_jit(jax.tree_util.tree_map(lambda x: x[i], batch)) for i in range(n)]
    np.testing.assert_allclose(P, np.stack([l[0] for l in loop]), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(jumps, np.stack([l[1] for l in loop]), rtol=1e-13, atol=1e-15)
    assert not np.any(np.asarray(flags))
