"""Standard drop campaigns projected onto the plane of the model.

The model is the housing's section in one plane: width W along e1, height H along e2. Faces are numbered as in
ISTA: 1 top (+e2), 2 right (+e1), 3 bottom (-e2), 4 left (-e1); 5 and 6 are the two faces parallel to the plane.
A 3-D drop maps onto the plane as follows.

- Face 1-4: a flat landing on that face (orientation pi, -pi/2, 0, pi/2): the exact translation answer, every
  point gains (1 + e) times the impact speed.
- Edge between two in-plane faces (2-3, say; it runs perpendicular to the plane), and corner 2-3-5 or 2-3-6: the
  section's corner 2-3 with the centre of gravity above it, orientation atan2(-q1, -q2) for corner (q1, q2). The
  impulse then passes through G: a central impact that translates the housing.
- Edge between an in-plane face and face 5 or 6 (3-5, say): lands with G above a line along the plane, i.e. flat
  on face 3 in the plane. The plane sees at most the full vertical velocity change (the part along the tilted
  section is smaller by the cosine of the tilt, which needs the depth the 2-D model does not have): conservative.
- Face 5 or 6: the velocity change is perpendicular to the plane, which the 2-D model cannot excite. Such drops
  are listed with `in_plane = False` and NaN peaks, and are left out of the worst drop.
- JESD22-B111 is a board-level test: its half-sine (1500 g, 0.5 ms, condition B) drives both supports directly.

Every drop starts from rest (no spin, no drift). Heights and sequences follow the standards' published tables as
summarised in each `STANDARDS` entry; check them against your copy of the standard.
"""

import math
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._common.checks import Flag
from .._impact.motion import JESD22_B111_CONDITION_B, HalfSine

FACE_ORIENTATION = {1: math.pi, 2: -math.pi / 2, 3: 0.0, 4: math.pi / 2}
_FACE_SIGN = {1: (None, 1), 2: (1, None), 3: (None, -1), 4: (-1, None)}  # which corner coordinate a face fixes

# ISTA 1A / 2A free-fall heights by packaged-product mass: below 21, 41, 61, 100 lb, and up to 150 lb inclusive.
_LB = 0.45359237
_ISTA_MASS = tuple(lb * _LB for lb in (21, 41, 61, 100, 150))
_ISTA_HEIGHTS = {"ista-1a": (0.76, 0.61, 0.46, 0.31, 0.20), "ista-2a": (0.97, 0.81, 0.66, 0.51, 0.31)}


@dataclass(frozen=True)
class CampaignDrop:
    """One drop of a campaign: `label` (e.g. "corner 2-3-5"), `attitude` ("face", "edge", "corner", "board"),
    `height` (m; NaN for a board-level pulse), `orientation` (rad in the plane; NaN when not in the plane),
    `repetitions` the standard asks for, `in_plane` whether the 2-D model represents it, `note`."""

    label: str
    attitude: str
    height: float
    orientation: float
    repetitions: int = 1
    in_plane: bool = True
    note: str = ""


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
    return [_drop(label, W, H, h, reps) for label, reps in labels]


@dataclass
class CampaignResult:
    """Peaks of every drop of a standard campaign (`stress` Pa, `strain` -, `deflection` m: arrays over `drops`,
    NaN where a drop is not represented in the plane). `worst`: index of the drop with the highest peak stress."""

    standard: str
    drops: list
    stress: np.ndarray
    strain: np.ndarray
    deflection: np.ndarray
    flags: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    @property
    def worst(self) -> int:
        """Index of the first drop with the highest peak stress (see `worst_drops` for ties)."""
        return self.worst_drops[0]

    @property
    def worst_drops(self) -> list[int]:
        """Indices of every drop whose peak stress equals the highest to 1e-9 (symmetric drops tie exactly)."""
        stress = np.asarray(self.stress, float)
        if not np.any(np.isfinite(stress)):
            return []
        top = np.nanmax(stress)
        return [int(i) for i in np.flatnonzero(stress >= top - 1e-9 * abs(top))]

    def rows(self) -> list[dict]:
        """One dict per drop, in SI-derived engineering units (MPa, microstrain, mm, deg)."""
        worst = set(self.worst_drops)
        out = []
        for i, d in enumerate(self.drops):
            out.append(
                {
                    "drop": i + 1,
                    "label": d.label,
                    "attitude": d.attitude,
                    "height_m": d.height,
                    "orientation_deg": math.degrees(d.orientation),
                    "repetitions": d.repetitions,
                    "peak_stress_MPa": float(self.stress[i]) / 1e6,
                    "peak_strain_microstrain": float(self.strain[i]) * 1e6,
                    "peak_deflection_mm": float(self.deflection[i]) * 1e3,
                    "worst": i in worst,
                    "note": d.note,
                }
            )
        return out

    def to_csv(self, path) -> Path:
        """Write `rows()` as CSV; returns the path."""
        from .._common.report import write_csv

        return write_csv(self.rows(), path)

    def table(self) -> str:
        """The rows as an aligned text table (what `repr` and the CLI show)."""
        lines = [f"  {'#':>2}  {'drop':<36} {'height (m)':>10} {'angle (deg)':>11} {'reps':>4} "
                 f"{'stress (MPa)':>12} {'strain (ue)':>11} {'defl. (mm)':>10}"]
        ties = len(self.worst_drops) > 1
        for r in self.rows():
            mark = (" <- worst (tie)" if ties else " <- worst") if r["worst"] else ("  " + r["note"] if r["note"] else "")
            lines.append(f"  {r['drop']:>2}  {r['label']:<36} {r['height_m']:>10.3f} {r['orientation_deg']:>11.2f} "
                         f"{r['repetitions']:>4} {r['peak_stress_MPa']:>12.2f} {r['peak_strain_microstrain']:>11.1f} "
                         f"{r['peak_deflection_mm']:>10.3f}{mark}")
        return "\n".join(lines)

    def summary(self) -> dict:
        """Standard, drop count and the worst drop(s), units in the keys."""
        worst = self.worst_drops
        return {
            "standard": self.standard,
            "drops": len(self.drops),
            "drops_in_plane": int(np.sum(np.isfinite(np.asarray(self.stress, float)))),
            "worst_drops": [self.drops[i].label for i in worst],
            "worst_peak_stress_MPa": float(self.stress[worst[0]]) / 1e6 if worst else None,
        }

    def __repr__(self) -> str:
        from .._common.report import summary_text

        return summary_text(self.summary(), "CampaignResult") + "\n" + self.table()


def campaign(scene, standard: str, numerics=None, *, mass: float | None = None, height: float | None = None):
    """Run a standard drop campaign on `scene` (its housing, board and contact; the drop fields are replaced by
    each drop of the standard): a `CampaignResult`. Standards: `STANDARDS` (ista-1a, ista-2a, mil-std-810h-516-iv,
    iec-60068-2-31, jesd22-b111); `mass`, `height` as in `campaign_drops`. How each 3-D drop maps onto the plane
    is in this module's notes."""
    from .montecarlo import sample_axes
    from .._response.numerics import Numerics
    from .._response.objectives import _scene_peaks
    from .._response.simulate import board_response

    numerics = Numerics() if numerics is None else numerics
    drops = campaign_drops(scene, standard, mass=mass, height=height)
    n = len(drops)
    if standard == "jesd22-b111":
        peak, duration = JESD22_B111_CONDITION_B
        r = board_response(scene.board, HalfSine.from_peak(peak, duration), numerics)
        return CampaignResult(standard, drops, *(np.array([float(v)]) for v in
                                                 (r.peak.stress, r.peak.strain, r.peak.deflection)),
                              flags=np.array([int(r.flags)]))
    planar = [i for i, d in enumerate(drops) if d.in_plane]
    dtype = jnp.asarray(scene.drop.height).dtype
    batch = scene.replace(
        **{
            "drop.orientation": jnp.asarray([drops[i].orientation for i in planar], dtype),
            "drop.height": jnp.asarray([drops[i].height for i in planar], dtype),
            "drop.spin": jnp.zeros(len(planar), dtype),
            "drop.horizontal_speed": jnp.zeros(len(planar), dtype),
        }
    )
    axes = sample_axes(batch, scene)
    values, flags = jax.vmap(lambda s: _scene_peaks(s, numerics, ("stress", "strain", "deflection")), (axes,))(batch)
    values, flags = np.asarray(values), np.asarray(flags)
    if np.any(flags):
        bad = int(np.flatnonzero(flags)[0])
        raise ValueError(
            f"campaign {standard}: drop '{drops[planar[bad]].label}' is flagged {Flag.describe(int(flags[bad]))}"
        )
    out = np.full((n, 3), np.nan)
    out[planar] = values
    return CampaignResult(standard, drops, out[:, 0], out[:, 1], out[:, 2], flags=np.zeros(n, int))
