"""The drops the standards ask for: ISTA 1A/2A, MIL-STD-810H 516.8 IV, IEC 60068-2-31, JESD22-B111, as faces,
edges and corners of a box housing (G above the struck point), or of a plane section's (see `campaign` for how
they map onto the plane). Plain Python, no JAX: the command line lists the standards without loading the
package's numerics."""

import math
from dataclasses import dataclass


FACE_ORIENTATION = {1: math.pi, 2: -math.pi / 2, 3: 0.0, 4: math.pi / 2}
_FACE_SIGN = {1: (None, 1), 2: (1, None), 3: (None, -1), 4: (-1, None)}  # which corner coordinate a face fixes

# ISTA 1A / 2A free-fall heights by packaged-product mass: below 21, 41, 61, 100 lb, and up to 150 lb inclusive.
_LB = 0.45359237
_ISTA_MASS = tuple(lb * _LB for lb in (21, 41, 61, 100, 150))
_ISTA_HEIGHTS = {"ista-1a": (0.76, 0.61, 0.46, 0.31, 0.20), "ista-2a": (0.97, 0.81, 0.66, 0.51, 0.31)}


@dataclass(frozen=True)
class CampaignDrop:
    """One drop of a campaign: `label` (e.g. "corner 2-3-5"), `attitude` ("face", "edge", "corner", "board"),
    `height` (m; NaN for a board-level pulse), `orientation` (rad in the plane; NaN when not represented),
    `repetitions` the standard asks for, `in_plane` whether the model represents it (a plane section: only drops
    in its plane; a box: every drop), `note`, and a box's `tilt` (rad)."""

    label: str
    attitude: str
    height: float
    orientation: float
    repetitions: int = 1
    in_plane: bool = True
    note: str = ""
    tilt: float = 0.0


def _corner_orientation(faces, width, height) -> float:
    """Orientation that puts G straight above the section's corner shared by two in-plane faces."""
    q = [0.0, 0.0]
    for f in faces:
        i, sign = (0, _FACE_SIGN[f][0]) if _FACE_SIGN[f][0] is not None else (1, _FACE_SIGN[f][1])
        q[i] = sign * (width if i == 0 else height) / 2
    return math.atan2(-q[0], -q[1])


def _drop(label: str, width, height, h, repetitions=1) -> CampaignDrop:
    """A drop named as in the standards: 'face 3', 'edge 2-3', 'corner 2-3-5'."""
    attitude, spec = label.split(" ")
    faces = [int(v) for v in spec.split("-")]
    in_plane = [f for f in faces if f <= 4]
    if not in_plane:
        return CampaignDrop(label, attitude, h, math.nan, repetitions, False,
                            "velocity change perpendicular to the plane: not represented in 2-D")
    if len(in_plane) == 1:
        note = "" if attitude == "face" else f"as face {in_plane[0]} (G above an edge along the plane)"
        return CampaignDrop(label, attitude, h, FACE_ORIENTATION[in_plane[0]], repetitions, True, note)
    note = "" if attitude == "edge" else f"as edge {in_plane[0]}-{in_plane[1]} (G above the corner)"
    return CampaignDrop(label, attitude, h, _corner_orientation(in_plane, width, height), repetitions, True, note)


def _box_drop(label: str, width, height, depth, h, repetitions=1) -> CampaignDrop:
    """A drop of a box housing named as in the standards, with G straight above the struck point: the corner
    shared by three faces, the midpoint of the edge shared by two, the centre of one face. Faces 5 and 6 lie at
    +D/2 and -D/2 along e3. The body's downward direction q / |q| fixes the attitude (`bd.box_attitude`):
    sin(tilt) = q3 / |q| and orientation atan2(-q1, -q2)."""
    attitude, spec = label.split(" ")
    q = [0.0, 0.0, 0.0]
    for f in (int(v) for v in spec.split("-")):
        if f <= 4:
            i, sign = (0, _FACE_SIGN[f][0]) if _FACE_SIGN[f][0] is not None else (1, _FACE_SIGN[f][1])
            q[i] = sign * (width if i == 0 else height) / 2
        else:
            q[2] = (depth if f == 5 else -depth) / 2
    orientation = math.atan2(-q[0], -q[1]) if (q[0] or q[1]) else 0.0
    tilt = math.asin(q[2] / math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2))
    return CampaignDrop(label, attitude, h, orientation, repetitions, True, "", tilt)


def _ista(name, mass):
    if not (0 < mass <= _ISTA_MASS[-1]):
        raise ValueError(
            f"{name}: packaged mass = {mass:g} kg is outside (0, {_ISTA_MASS[-1]:.2f}] kg (150 lb); heavier "
            "products use ISTA 1B / 2B"
        )
    h = _ISTA_HEIGHTS[name][sum(mass >= bound for bound in _ISTA_MASS[:-1])]
    labels = ["corner 2-3-5", "edge 2-3", "edge 3-5", "edge 2-5"] + [f"face {f}" for f in (1, 2, 3, 4, 5, 6)]
    return h, [(label, 1) for label in labels]


def _mil(mass):
    if not (0 < mass < 100 * _LB):
        raise ValueError(
            f"mil-std-810h-516-iv: mass = {mass:g} kg is outside (0, 45.36) kg: the 122 cm / 26-drop transit drop is "
            "for materiel under 100 lb; heavier materiel has other heights in the method's table"
        )
    faces = [f"face {f}" for f in range(1, 7)]
    edges = [f"edge {a}-{b}" for a, b in [(1, 2), (2, 3), (3, 4), (1, 4)]]
    edges += [f"edge {a}-{b}" for b in (5, 6) for a in (1, 2, 3, 4)]
    corners = [f"corner {a}-{b}-{c}" for c in (5, 6) for a, b in [(1, 2), (2, 3), (3, 4), (1, 4)]]
    return 1.22, [(label, 1) for label in faces + edges + corners]


def _iec(height):
    # Procedure 1 (free fall): the relevant specification picks the attitudes and a height from the preferred
    # 25, 50, 100, 250, 500, 1000 mm; two falls per attitude unless specified otherwise.
    labels = [f"face {f}" for f in (1, 2, 3, 4)] + [f"edge {a}-{b}" for a, b in [(1, 2), (2, 3), (3, 4), (1, 4)]]
    return height, [(label, 2) for label in labels]


STANDARDS = {
    "ista-1a": "ISTA 1A (packaged products <= 68 kg): 10 drops, corner 2-3-5, its three edges, six faces; height "
    "by packaged mass: 760, 610, 460, 310, 200 mm below 21, 41, 61, 100, 150 lb",
    "ista-2a": "ISTA 2A (packaged products <= 68 kg): the same 10 drops from 970, 810, 660, 510, 310 mm by mass",
    "mil-std-810h-516-iv": "MIL-STD-810H Method 516.8 Procedure IV transit drop, materiel under 45.4 kg: 26 drops "
    "(6 faces, 12 edges, 8 corners) from 122 cm",
    "iec-60068-2-31": "IEC 60068-2-31 free fall, procedure 1: 2 falls on each in-plane face and section corner from "
    "a height the specification picks (default 1000 mm)",
    "jesd22-b111": "JESD22-B111 board-level drop, service condition B: half-sine 1500 g, 0.5 ms at both supports, "
    "30 drops",
}


def campaign_drops(scene, standard: str, *, mass: float | None = None, height: float | None = None):
    """The drops of `standard` for `scene`'s housing: a list of `CampaignDrop`. `mass`: packaged mass for the
    mass-dependent heights (default the housing's mass, kg); `height`: the free-fall height where the standard
    leaves it to the specification (IEC 60068-2-31; default 1.0 m)."""
    if standard not in STANDARDS:
        raise ValueError(f"standard = {standard!r}; valid: {', '.join(STANDARDS)}")
    # A setting the standard does not take would be ignored: refused by name instead.
    if height is not None and not standard.startswith("iec"):
        raise ValueError(f"height = {height!r} m: {standard} fixes its drops"
                         + (" (half-sine pulses of the board)" if standard == "jesd22-b111" else
                            " (their heights follow the packaged mass: give mass instead)")
                         + "; valid: height with iec-60068-2-31 only, which leaves it to the specification")
    if mass is not None and not standard.startswith(("ista", "mil")):
        raise ValueError(f"mass = {mass!r} kg: {standard}'s drops do not depend on the packaged mass; valid: mass "
                         "with ista-1a, ista-2a or mil-std-810h-516-iv (mass-dependent heights) only")
    W, H = float(scene.housing.width), float(scene.housing.height)
    mass = float(scene.housing.mass) if mass is None else float(mass)
    if standard == "jesd22-b111":
        return [CampaignDrop("board-level half-sine 1500 g 0.5 ms", "board", math.nan, math.nan, 30, True,
                             "both supports, no housing")]
    if standard.startswith("ista"):
        h, labels = _ista(standard, mass)
    elif standard.startswith("mil"):
        h, labels = _mil(mass)
    else:
        h = 1.0 if height is None else float(height)
        if not (h > 0 and math.isfinite(h)):
            raise ValueError(f"height = {height!r} m; valid: a finite height > 0 m")
        h, labels = _iec(h)
    if scene.housing.is_box:
        D = float(scene.housing.depth)
        return [_box_drop(label, W, H, D, h, reps) for label, reps in labels]
    return [_drop(label, W, H, h, reps) for label, reps in labels]
