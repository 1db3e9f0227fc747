"""What a drop or a board response reports: `Response` (with the board's `Peak` and `Gauges`), `Fields`, `StrainMap`."""


import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._board.base import Gauges, Peak
from .._common.checks import Flag, is_concrete
from .._impact.clatter import Impacts
from .._impact.box import BoxImpact
from .._impact.kinematics import HousingImpact
from .._impact.routh import ImpactResult
from .._common.report import plain, summary_text
from .._impact.routh import ImpactMode


class Convergence(eqx.Module):
    """What the convergence check measured, each a relative change (0 where the model is exact):

    - `modes`: of the peak stress, with `Response.check_modes` modes instead of `Response.n_modes` (a plate under
      half-sine pulses: every mode of its Ritz basis, at the peak's point and time; `check_cap` is then True, as
      the answer keeps all `Numerics.max_modes` computed modes);
    - `gauges`: of the gauges' peak strains with the check's modes (the largest over the gauges; 0 without);
    - `basis`: of the peak stress and the gauges' peak strains with a Ritz basis 4 functions larger each way, at
      the same points and times, extrapolated to the error of this basis (a plate; 0 for a beam, whose modes are
      exact);
    - `window`: how much more a gauge reads over the next window, (window, 2 window], than its peak within the
      window (the largest over the gauges; 0 where every gauge reads less, without gauges, and where the motion is
      known over the window only: a plate under half-sine pulses is checked). A plate's modes are not harmonics:
      their beats can raise a gauge's strain after one fundamental period.

    `Response.error_estimate` is the larger of `modes` and `gauges` plus `basis`, or `window` where larger;
    `Response.converged` holds when it is within `Numerics.convergence_rtol`; `worst()` names the largest."""

    modes: Float[Array, ""]
    gauges: Float[Array, ""]
    basis: Float[Array, ""]
    window: Float[Array, ""]
    # An array, not a static field: where a traced drop picks between the rigid law's answer and the landing's
    # (`_simulate`'s "either"), the two differ in it.
    check_cap: Bool[Array, ""] = False

    def worst(self) -> tuple[str, float]:
        """(name, value) of the largest estimate (concrete results)."""
        values = {"modes": float(self.modes), "gauges": float(self.gauges), "basis": float(self.basis),
                  "window": float(self.window)}
        name = max(values, key=values.get)
        return name, values[name]


class Response(eqx.Module):
    """What a drop does to the board.

    - `impulse`: the housing's first `ImpactResult` (None from `board_response`); `housing`: its `HousingImpact`.
    - `impacts`: every impact of the drop (`Impacts`; one unless `Numerics.max_impacts` > 1).
    - `support_jumps`: (dvA, dvB) of the first impact, m/s, normal to the board; `roll_jump`: its roll dvR across
      the board's width (m/s; `bd.HalfSine`; 0 in a plane drop).
    - `box`: a box housing's first impact (`bd.BoxImpact`, the 3D law at its lowest vertex; None for a plane
      section). At tilt = 0 the board follows the plane section's impact (`impulse`), which it equals.
    - `mount_jumps`: a plate's mounts' normal velocity jumps in the first impact (m/s, one per mount; None without
      mounts or on a beam): the housing's rigid motion at each mount.
    - `peak`: a `Peak`.
    - `frequencies`: natural frequencies of the computed modes, Hz.
    - `n_modes`: modes in the reported peak; `check_modes`: modes of the convergence check.
    - `error_estimate`: the largest of the convergence estimates (`convergence`: modes, gauges, basis, window),
      relative.
    - `converged`: `error_estimate <= Numerics.convergence_rtol` (and the result not flagged).
    - `convergence`: each estimate (`Convergence`).
    - `window`: time window, s (to one fundamental period after the last impact's pulse). `flags`: `Flag` mask (0 = valid; otherwise the peak fields are NaN).
    - `gauges`: strain gauge readings (`Gauges`) at the points asked for (plates; None otherwise); `is_plate`.
    - `landing_weight`: the compliant landing's share of the supports' motion (`Contact.model`): 0 the rigid law,
      1 the compliant landing, between the two blended (None from `board_response`).
    """

    impulse: ImpactResult | None
    housing: HousingImpact | None
    impacts: Impacts | None
    support_jumps: Float[Array, "2"]
    peak: Peak
    frequencies: Float[Array, " n"]
    n_modes: Int[Array, ""]
    check_modes: Int[Array, ""]
    error_estimate: Float[Array, ""]
    converged: Bool[Array, ""]
    window: Float[Array, ""]
    flags: Int[Array, ""]
    gauges: "Gauges | None" = None
    is_plate: bool = eqx.field(static=True, default=False)
    convergence: "Convergence | None" = None
    landing_weight: "Float[Array, ''] | None" = None
    roll_jump: "Float[Array, ''] | None" = None
    box: "BoxImpact | None" = None
    mount_jumps: "Float[Array, ' m'] | None" = None

    def summary(self) -> dict:
        """The numbers of one response, units in the keys (JSON-ready with `plain`; `repr` prints them)."""

        if jnp.ndim(self.peak.stress) or not is_concrete(self):
            raise ValueError("Response.summary() needs one concrete response (index a batched one first)")
        r = jax.device_get(self)  # NumPy from here: arithmetic on the host, no small programs to compile
        p = r.peak
        out = {}
        weight = 0.0 if r.landing_weight is None else float(r.landing_weight)
        if weight > 0:  # the rigid law's impulse is not what the board felt
            out["landing"] = ("compliant: corners strike together (Contact.model)" if weight == 1.0 else
                              f"{weight:.3g} compliant landing + {1 - weight:.3g} rigid law (strikes nearly overlap)")
        elif r.box is not None and float(r.box.attitude[1, 2]) != 0.0:  # tilted (R[1, 2] = -sin tilt): the 3D law
            out["impulse_Ns"] = r.box.P
            out["struck_point_mm"] = np.asarray(r.box.attitude).T @ np.asarray(r.box.r) * 1e3
            out["contact_mode"] = "3D, ends stuck" if bool(r.box.impact.sticks) else "3D, ends sliding"
        elif r.impulse is not None:
            flat = r.housing is not None and bool(r.housing.flat)
            out["impulse_Ns"] = r.impulse.P
            out["contact_mode"] = "flat landing (translation)" if flat else ImpactMode(int(r.impulse.mode)).label
        if r.impacts is not None and int(r.impacts.count) > 1:
            out["impacts"] = int(r.impacts.count)
        out |= {
            "support_jumps_m_per_s": r.support_jumps,
            **({"roll_jump_m_per_s": r.roll_jump} if r.roll_jump is not None and float(r.roll_jump) else {}),
            **({"mount_jumps_m_per_s": r.mount_jumps} if r.mount_jumps is not None else {}),
            "frequencies_Hz": r.frequencies[:4],
            "n_modes": r.n_modes,
            "check_modes": r.check_modes,
            "peak_stress_MPa": p.stress / 1e6,
            "peak_strain_microstrain": p.strain * 1e6,
            **({"peak_membrane_stress_MPa": p.membrane_stress / 1e6} if float(p.membrane_stress) else {}),
            "peak_stress_x_mm": p.x * 1e3,
            **({"peak_stress_y_mm": p.y * 1e3} if r.is_plate else {}),
            "peak_stress_t_ms": p.t * 1e3,
            **({"peak_strain_x_mm": p.strain_x * 1e3, "peak_strain_y_mm": p.strain_y * 1e3,
                "peak_strain_t_ms": p.strain_t * 1e3} if r.is_plate else {}),
            "peak_deflection_mm": p.deflection * 1e3,
            "peak_deflection_x_mm": p.deflection_x * 1e3,
            **({"peak_deflection_y_mm": p.deflection_y * 1e3} if r.is_plate else {}),
            "peak_deflection_t_ms": p.deflection_t * 1e3,
            "converged": r.converged,
            "error_estimate_relative": r.error_estimate,  # modes and gauges, plus the Ritz basis on a plate
            "window_ms": r.window * 1e3,
            "flags": Flag.describe(r.flags),
        }
        if r.gauges is not None:
            out["gauge_peak_strain_microstrain"] = r.gauges.peak_strain * 1e6
            out["gauge_peak_time_ms"] = r.gauges.peak_time * 1e3
        return plain(out)


    def __repr__(self) -> str:
        try:
            return summary_text(self.summary(), "Response (x from end A, t from the first impact)")
        except ValueError:
            return eqx.tree_pformat(self)


class Fields(eqx.Module):
    """Deflection (m), strain (-) and stress (Pa) on a grid: arrays of shape (len(x), len(t))."""

    x: Float[Array, " nx"]
    t: Float[Array, " nt"]
    deflection: Float[Array, "nx nt"]
    strain: Float[Array, "nx nt"]
    stress: Float[Array, "nx nt"]


class StrainMap(eqx.Module):
    """Largest principal surface strain over a plate at one time: `x` (nx,), `y` (ny,) (m), `strain` (nx, ny)
    (NaN inside the mount discs), `t` (s)."""

    x: Float[Array, " nx"]
    y: Float[Array, " ny"]
    strain: Float[Array, "nx ny"]
    t: Float[Array, ""]
