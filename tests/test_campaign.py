"""Standard drop campaigns: heights and drop lists from the standards' tables, each planar drop against the
hand-computed translation it must be, and the CSV / CLI outputs."""

import csv
import math

import equinox as eqx
import numpy as np
import pytest

import beamdrop_jax as bd
from beamdrop_jax.cli import main

G = 9.80665


def translation_peak(scene, dv):
    """Peak stress of the board when both supports jump by dv (a central impact), through the board alone."""
    return float(bd.board_response(scene.board, bd.HalfSine(dv, dv, scene.contact.duration)).peak.stress)


@pytest.mark.parametrize(
    "standard, mass, height",
    [("ista-1a", 5.0, 0.76), ("ista-1a", 12.0, 0.61), ("ista-1a", 20.0, 0.46), ("ista-1a", 30.0, 0.31),
     ("ista-1a", 68.0, 0.20), ("ista-2a", 0.18, 0.97), ("ista-2a", 25.0, 0.66), ("ista-2a", 50.0, 0.31)],
)
def test_ista_heights_follow_the_mass_table(standard, mass, height):
    drops = bd.campaign_drops(bd.Scene.default(), standard, mass=mass)
    assert len(drops) == 10 and {d.height for d in drops} == {height}
    assert [d.attitude for d in drops].count("face") == 6 and drops[0].label == "corner 2-3-5"


def test_drop_lists_of_the_standards():
    scene = bd.Scene.default()
    mil = bd.campaign_drops(scene, "mil-std-810h-516-iv")
    attitudes = [d.attitude for d in mil]
    assert len(mil) == 26 and (attitudes.count("face"), attitudes.count("edge"), attitudes.count("corner")) == (6, 12, 8)
    assert {d.height for d in mil} == {1.22}
    iec = bd.campaign_drops(scene, "iec-60068-2-31", height=0.5)
    assert {d.height for d in iec} == {0.5} and {d.repetitions for d in iec} == {2}
    jesd = bd.campaign_drops(scene, "jesd22-b111")
    assert len(jesd) == 1 and jesd[0].repetitions == 30 and jesd[0].attitude == "board"


def test_face_and_corner_drops_are_the_translations_they_must_be():
    default = bd.Scene.default()  # board along e1: its normal is e2
    # The rigid law: a flat landing is the exact translation.
    scene = eqx.tree_at(lambda s: s.contact, default, default.contact.with_model("rigid"))
    e = float(scene.contact.restitution)
    result = bd.campaign(scene, "mil-std-810h-516-iv")
    v = math.sqrt(2 * G * 1.22)
    by_label = {d.label: i for i, d in enumerate(result.drops)}
    # Face 3 (bottom) down: every point gains (1 + e) v upwards, along the board normal.
    np.testing.assert_allclose(result.stress[by_label["face 3"]], translation_peak(scene, (1 + e) * v), rtol=1e-9)
    # Face 2 down: the velocity change runs along the board, which it does not bend.
    assert abs(result.stress[by_label["face 2"]]) < 1e-6 * result.stress[by_label["face 3"]]
    # G above corner 2-3: a central impact (r_x = 0, no spin change) whose (1 + e) v projects on the board normal
    # with cos(theta), theta = -atan(W / H).
    W, H = float(scene.housing.width), float(scene.housing.height)
    theta = -math.atan(W / H)
    np.testing.assert_allclose(result.drops[by_label["edge 2-3"]].orientation, theta, rtol=1e-14)
    _, r, _ = bd.lowest_corner(scene.replace(**{"drop.orientation": theta}))
    assert abs(float(r[0])) < 1e-15
    want = translation_peak(scene, (1 + e) * v * math.cos(theta))
    for label in ("edge 2-3", "corner 2-3-5", "corner 2-3-6"):
        np.testing.assert_allclose(result.stress[by_label[label]], want, rtol=1e-6)
    # Faces 5 and 6 are out of the plane: NaN, and never the worst.
    assert np.isnan(result.stress[by_label["face 5"]]) and not result.drops[by_label["face 6"]].in_plane
    assert result.drops[result.worst].label in ("face 1", "face 3", "edge 1-5", "edge 3-5", "edge 1-6", "edge 3-6")
    # The default model lands a face drop compliantly: the campaign's row is simulate's flat landing.
    auto = bd.campaign(default, "ista-1a")
    face = next(i for i, d in enumerate(auto.drops) if d.label == "face 3")
    flat = bd.simulate(default.replace(**{"drop.orientation": 0.0, "drop.height": auto.drops[face].height}))
    assert float(flat.landing_weight) == 1.0
    np.testing.assert_allclose(auto.stress[face], float(flat.peak.stress), rtol=1e-6)


def test_jesd22_is_the_board_level_half_sine():
    scene = bd.Scene.default()
    result = bd.campaign(scene, "jesd22-b111")
    dv = 1500 * G * 2 * 0.5e-3 / math.pi  # velocity change of the half-sine, 4.683 m/s
    np.testing.assert_allclose(result.stress[0], translation_peak(scene, dv), rtol=1e-9)
    # A prescribed pulse has no drop height or angle: the table says "-", not nan.
    row = result.table().splitlines()[1].split()
    assert "nan" not in result.table() and row[-8:-6] == ["-", "-"] and row[-5] == f"{result.stress[0] / 1e6:.2f}"


def test_csv_and_cli(tmp_path, capsys):
    result = bd.campaign(bd.Scene.default(), "iec-60068-2-31")
    rows = list(csv.DictReader(result.to_csv(tmp_path / "c.csv").open()))
    # Symmetric drops tie exactly: every drop at the highest stress is marked worst, none other.
    top = np.nanmax(result.stress)
    assert len(rows) == 8 and [r["worst"] == "True" for r in rows] == list(result.stress >= top * (1 - 1e-9))
    np.testing.assert_allclose([float(r["peak_stress_MPa"]) for r in rows], result.stress / 1e6, rtol=1e-12)
    assert main(["campaign", "--standard", "ista-2a", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "<- worst" in out and "not represented in 2-D" in out and "nan" not in out
    assert (tmp_path / "campaign-ista-2a.csv").exists() and (tmp_path / "campaign-ista-2a.png").stat().st_size > 10_000
    assert main(["campaign", "--standard", "ista-1a", "--mass", "80", "--no-plots"]) == 2
    assert "outside (0, 68.04] kg" in capsys.readouterr().err


def test_bad_campaign_input_is_named():
    scene = bd.Scene.default()
    with pytest.raises(ValueError, match="valid: ista-1a, ista-2a"):
        bd.campaign(scene, "ista-3a")
    with pytest.raises(ValueError, match=r"outside \(0, 45.36\) kg"):
        bd.campaign_drops(scene, "mil-std-810h-516-iv", mass=60.0)
    with pytest.raises(ValueError, match="height"):
        bd.campaign_drops(scene, "iec-60068-2-31", height=-1.0)
    # A setting the standard does not take is refused, not ignored.
    with pytest.raises(ValueError, match=r"height = 2.0 m: ista-1a fixes its drops .* give mass instead"):
        bd.campaign_drops(scene, "ista-1a", height=2.0)
    with pytest.raises(ValueError, match=r"mass = 3.0 kg: jesd22-b111's drops do not depend on the packaged mass"):
        bd.campaign(scene, "jesd22-b111", mass=3.0)
    with pytest.raises(ValueError, match=r"mass = 3.0 kg: iec-60068-2-31's"):
        bd.campaign_drops(scene, "iec-60068-2-31", mass=3.0)


def test_json_reports_drops_outside_the_plane_as_null(tmp_path, capsys):
    import json

    scene = bd.Scene.default()
    args = ["campaign", "--standard", "mil-std-810h-516-iv", "--json", "--no-plots", "--contact-model", "rigid",
            "--out", str(tmp_path)]
    assert main(args) == 0
    drops = {d["label"]: d for d in json.loads(capsys.readouterr().out)["drops"]}
    assert drops["face 5"]["peak_stress_MPa"] is None and drops["face 6"]["peak_strain_microstrain"] is None
    v = math.sqrt(2 * G * 1.22)
    want = translation_peak(scene, (1 + float(scene.contact.restitution)) * v) / 1e6
    np.testing.assert_allclose(drops["face 3"]["peak_stress_MPa"], want, rtol=1e-9)
