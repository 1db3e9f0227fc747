"""Which scene fields matter? Exact derivatives and elasticities of the peak, and a smooth peak for objectives."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._scene.containers import Scene, _section_classes
from .._response.numerics import Numerics
from .._response.surface import _plate_points
from .._response.setup import _setup
from .._response.simulate import drop_motion
from .._response.objectives import peak_deflection, peak_strain, peak_stress
from .._board.beam import mode_shapes
from .._board.search import field_on_grid, near_mounts
from .._board.plate import surface_stress
from .._common.compile import filter_jit
from .._common.reductions import largest

_PEAKS = {"stress": peak_stress, "strain": peak_strain, "deflection": peak_deflection}


def _scalar_fields(scene: Scene) -> list[tuple[str, float, str]]:
    """(dotted name, value, SI unit) of every scalar float in a scene; arrays expand to `name[i]`, `name[i, j]`
    (a plate's mount positions among them)."""
    rows = []
    for section, cls in _section_classes(scene).items():
        module = getattr(scene, section)
        units = {name: spec[0].unit for name, spec in cls.RANGES.items()}
        if getattr(module, "mounts", None) is not None:
            units["mounts"] = "m"
        for name, unit in units.items():
            if getattr(module, name) is None:  # an optional field left out (a plane housing's depth)
                continue
            value = np.asarray(getattr(module, name))
            rows += [(f"{section}.{name}" + (f"[{', '.join(map(str, i))}]" if i else ""), float(value[i]), unit)
                     for i in np.ndindex(value.shape)]
    return rows


def scalar_fields(scene: Scene) -> list[tuple[str, float]]:
    """Dotted names and values of every scalar float in a scene (arrays expand to `name[i]`, `name[i, j]`)."""
    return [(name, value) for name, value, _ in _scalar_fields(scene)]


class Sensitivity(eqx.Module):
    """One row of `sensitivities`: d(peak)/d(field) in peak units per field unit, and the elasticity
    (field / peak) d(peak)/d(field): the % change of the peak per % change of the field (None for a field at 0,
    where a relative change means nothing; its derivative still does)."""

    field: str = eqx.field(static=True)
    value: float = eqx.field(static=True)
    derivative: float = eqx.field(static=True)
    elasticity: float | None = eqx.field(static=True)
    unit: str = eqx.field(static=True, default="")
    """The field's SI unit ("" for dimensionless fields)."""

    def row(self, peak_unit: str = "Pa", scale: float = 1.0) -> dict:
        """The row with the derivative in `peak_unit` (the peak's SI value times `scale`) per field unit."""
        return {"field": self.field, "value": self.value, "unit": self.unit or "-",
                "derivative": self.derivative * scale,
                "derivative_unit": f"{peak_unit} per {self.unit}" if self.unit else peak_unit,
                "elasticity": self.elasticity}


def sensitivities(scene: Scene, numerics: Numerics | None = None, quantity: str = "stress") -> list[Sensitivity]:
    """d(peak)/d(field) and elasticities for every scalar field of a scene, largest |elasticity| first (fields at
    zero, whose elasticity is undefined (None), follow, largest |derivative| first). `quantity`: stress, strain or deflection."""
    if quantity not in _PEAKS:
        raise ValueError(f"quantity = {quantity!r}; valid: {', '.join(_PEAKS)}")
    peak_fn = _PEAKS[quantity]
    numerics = Numerics() if numerics is None else numerics
    # Eager: the peak's derivative rule then sees the scene's values, takes the drop's own landing path and runs one
    # compiled program, kept for later calls (under a `jit` of its own the scene is traced, so `"auto"` would trace
    # and compile both landing paths, every call).
    peak, grad = jax.value_and_grad(lambda s: peak_fn(s, numerics))(scene)
    grads = dict(scalar_fields(grad))
    peak = float(peak)
    rows = [Sensitivity(name, value, grads[name], value * grads[name] / peak if (peak and value != 0.0) else None,
                        unit)
            for name, value, unit in _scalar_fields(scene)]
    return sorted(rows, key=lambda r: (r.elasticity is None, -abs(r.elasticity or 0.0), -abs(r.derivative)))


def smooth_peak_stress(scene: Scene, numerics: Numerics | None = None, temperature: float = 0.01) -> Float[Array, ""]:
    """A smooth stand-in for the peak stress: log-sum-exp of |stress| over the search grid ((x, t) on a beam; on a
    plate (x, y, t), the largest principal stress, mount discs left out) at temperature T = `temperature` x (grid
    maximum).

    Bias against the grid maximum m: 0 <= smooth - m <= T ln(N) for N grid points (N ~ 7e4 by default, so at most
    11 T, i.e. 11 % for temperature 0.01), and the grid maximum itself undershoots the refined peak by the grid's
    resolution. Use it when an objective wants a gradient that blends nearby peaks; `peak_stress` is the true max.
    """
    if not temperature > 0:
        raise ValueError(f"temperature = {temperature}; valid: > 0")
    numerics = Numerics() if numerics is None else numerics
    return _smooth(scene, numerics, temperature)


@filter_jit
def _smooth(scene, numerics, temperature):
    board = scene.board
    motion = drop_motion(scene, numerics)[0]
    # The grid is the answer here, not a search's starts: it must carry gradients (`refine` drops them).
    S = _setup(board, motion, dataclasses.replace(numerics, refine=False), with_check=False)
    mask = S.curvature * (S.k <= S.used)
    if board.SURFACE:
        _, _, points, shapes = _plate_points(board, S.modes)
        _, kxx, kyy, kxy = (field_on_grid(mask, S.Q, v) for v in shapes)
        stress = jnp.where(near_mounts(board, points)[:, None], 0.0, surface_stress(board, kxx, kyy, kxy))
    else:
        stress = jnp.abs(field_on_grid(mask, S.Q, mode_shapes(board, S.x, S.k.shape[0], True)))
        stress = board.youngs_modulus * board.thickness / 2 * stress
    # The shift m cancels (it only keeps exp finite); the temperature scales with the peak, so it carries a gradient.
    top = largest(stress)
    m = jax.lax.stop_gradient(top)
    T = temperature * top
    return m + T * jnp.log(jnp.sum(jnp.exp((stress - m) / T)))
