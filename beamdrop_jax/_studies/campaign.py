"""Standard drop campaigns on a box housing, or projected onto the plane of a plane section.

Faces are numbered as in ISTA: 1 top (+e2), 2 right (+e1), 3 bottom (-e2), 4 left (-e1); 5 and 6 are the two
faces parallel to the plane of motion (+e3 and -e3).

**A box housing** (`Housing.depth`): every drop lands as the standard says, G straight above the struck point
(a corner, an edge's midpoint, a face's centre; `standards._box_drop` gives its orientation and tilt). A corner
strikes alone under the 3D rigid law; an edge or a face strikes as one contact at its midpoint, exact by symmetry
for a drop from rest. Edges and faces in the plane of motion (tilt 0) take the plane section's models, as below.

**A plane section** (no depth): width W along e1, height H along e2; a 3-D drop maps onto the plane as follows.

- Face 1-4: a flat landing on that face (orientation pi, -pi/2, 0, pi/2): with `Contact.model` "auto" (the
  default) the compliant flat landing, both corners on springs (so a standard's tolerance of a few degrees on a
  flat drop moves the answer smoothly); with "rigid" the exact translation answer, every point gains (1 + e)
  times the impact speed.
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
from .._common.report import summary_text, write_csv
from .._response.numerics import Numerics
from .._response.objectives import _scene_peaks
from .._response.simulate import board_response
from .landings import solve_landings
from .montecarlo import _weights, sample_axes
from .standards import campaign_drops

UNBENT_NOTE = ("no bending in the plane model: the velocity change runs along the board (a flat landing on a face "
               "perpendicular to the board moves it along itself)")
BOX_UNBENT_NOTE = ("no bending: the velocity change runs along the board (a drop from rest whose impulse passes "
                   "through G and lies in the board's plane moves it along itself)")


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
    def unbent(self) -> list[int]:
        """Indices of the in-plane drops that do not bend the board in the plane model: peak stress 0 to round-off
        (1e-9 of the campaign's largest). Their velocity change runs along the board: a flat landing on a face
        perpendicular to it translates the board along itself."""
        stress = np.asarray(self.stress, float)
        if not np.any(np.isfinite(stress)):
            return []
        tol = 1e-9 * max(float(np.nanmax(np.abs(stress))), 1e-300)
        return [int(i) for i in np.flatnonzero(np.isfinite(stress) & (np.abs(stress) <= tol))]

    @property
    def unbent_note(self) -> str:
        """Why the drops of `unbent` show 0 (a box's drops, or a plane section's)."""
        return BOX_UNBENT_NOTE if any(d.tilt for d in self.drops) else UNBENT_NOTE

    @property
    def total_drops(self) -> int:
        """Drops the standard asks for, repetitions included (JESD22-B111: 30 of one attitude)."""
        return int(sum(d.repetitions for d in self.drops))

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

    def rows(self, limit_strain: float | None = None) -> list[dict]:
        """One dict per drop, in SI-derived engineering units (MPa, microstrain, mm, deg). The note says why a drop
        has no number (out of the plane) or a zero one (no bending in the plane model). With `limit_strain` (a
        fraction: 2000 microstrain is 2e-3), `over_limit` says whether the drop's peak strain exceeds it (None: not
        judged, as the plane model does not represent the drop or does not bend the board in it)."""
        worst, unbent = set(self.worst_drops), set(self.unbent)
        out = []
        for i, d in enumerate(self.drops):
            note = d.note
            if i in unbent:
                note = "; ".join(filter(None, (note, self.unbent_note)))
            out.append(
                {
                    "drop": i + 1,
                    "label": d.label,
                    "attitude": d.attitude,
                    "height_m": d.height,
                    "orientation_deg": math.degrees(d.orientation),
                    "tilt_deg": math.degrees(d.tilt),
                    "repetitions": d.repetitions,
                    "peak_stress_MPa": float(self.stress[i]) / 1e6,
                    "peak_strain_microstrain": float(self.strain[i]) * 1e6,
                    "peak_deflection_mm": float(self.deflection[i]) * 1e3,
                    "worst": i in worst,
                    **({} if limit_strain is None else {"over_limit": bool(self.strain[i] > limit_strain)
                                                        if np.isfinite(self.strain[i]) and i not in unbent else None}),
                    "note": note,
                }
            )
        return out

    def to_csv(self, path) -> Path:
        """Write `rows()` as CSV; returns the path."""

        return write_csv(self.rows(), path)

    def table(self, limit_strain: float | None = None) -> str:
        """The rows as an aligned text table (what `repr` and the CLI show); with `limit_strain` (a fraction) a
        column says which drops exceed it."""
        verdicts = {True: "OVER", False: "ok", None: "n/a"}
        box = any(d.tilt for d in self.drops)
        lines = [f"  {'#':>2}  {'drop':<36} {'height (m)':>10} {'angle (deg)':>11} "
                 + (f"{'tilt (deg)':>10} " if box else "") + f"{'reps':>4} "
                 f"{'stress (MPa)':>12} {'strain (ue)':>11} {'defl. (mm)':>10}"
                 + ("" if limit_strain is None else f" {f'> {limit_strain * 1e6:g} ue':>11}")]
        ties = len(self.worst_drops) > 1
        for r in self.rows(limit_strain):
            mark = ((" <- worst (tie)" if ties else " <- worst") if r["worst"]
                    else ("  " + r["note"] if r["note"] else ""))
            verdict = "" if limit_strain is None else f" {verdicts[r['over_limit']]:>11}"
            lines.append(f"  {r['drop']:>2}  {r['label']:<36} {_cell(r['height_m'], 10, 3)} "
                         f"{_cell(r['orientation_deg'], 11, 2)} " + (f"{_cell(r['tilt_deg'], 10, 2)} " if box else "")
                         + f"{r['repetitions']:>4} {_cell(r['peak_stress_MPa'], 12, 2)} "
                         f"{_cell(r['peak_strain_microstrain'], 11, 1)} {_cell(r['peak_deflection_mm'], 10, 3)}"
                         f"{verdict}{mark}")
        return "\n".join(lines)

    def summary(self) -> dict:
        """Standard, drop count and the worst drop(s), units in the keys."""
        worst = self.worst_drops
        return {
            "standard": self.standard,
            "drops": len(self.drops),
            "drops_with_repetitions": self.total_drops,
            "drops_modelled": int(np.sum(np.isfinite(np.asarray(self.stress, float)))),
            "drops_not_bending_the_board": len(self.unbent),
            "worst_drops": [self.drops[i].label for i in worst],
            "worst_peak_stress_MPa": float(self.stress[worst[0]]) / 1e6 if worst else None,
        }

    def __repr__(self) -> str:
        return summary_text(self.summary(), "CampaignResult") + "\n" + self.table()


def _cell(value, width: int, digits: int) -> str:
    """A table cell: the number, or "-" where the drop has none (a prescribed pulse has no height or angle)."""
    return f"{value:>{width}.{digits}f}" if value is not None and np.isfinite(value) else f"{'-':>{width}}"


def campaign(scene, standard: str, numerics=None, *, mass: float | None = None, height: float | None = None):
    """Run a standard drop campaign on `scene` (its housing, board and contact; the drop fields are replaced by
    each drop of the standard): a `CampaignResult`. Standards: `STANDARDS` (ista-1a, ista-2a, mil-std-810h-516-iv,
    iec-60068-2-31, jesd22-b111); `mass`, `height` as in `campaign_drops`. How each 3-D drop maps onto the plane
    is in this module's notes."""

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
            "drop.tilt": jnp.asarray([drops[i].tilt for i in planar], dtype),
        }
    )
    axes = sample_axes(batch, scene)
    values, flags = jax.vmap(lambda s: _scene_peaks(s, numerics, ("stress", "strain", "deflection")), (axes,))(batch)
    values, flags = np.array(values), np.array(flags)
    if scene.contact.model != "rigid" and numerics.max_impacts == 1:  # face drops: the compliant landing
        band = np.flatnonzero(np.asarray(_weights(batch, axes)) > 0)
        if band.size:
            *peaks, band_flags = solve_landings(batch, axes, band)
            values[band] = np.stack(peaks, axis=-1)
            flags[band] = band_flags
    if np.any(flags):
        bad = int(np.flatnonzero(flags)[0])
        raise ValueError(
            f"campaign {standard}: drop '{drops[planar[bad]].label}' is flagged {Flag.describe(int(flags[bad]))}"
        )
    out = np.full((n, 3), np.nan)
    out[planar] = values
    return CampaignResult(standard, drops, out[:, 0], out[:, 1], out[:, 2], flags=np.zeros(n, int))
