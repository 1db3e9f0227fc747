"""Peaks of a board whose domain is a surface (a plate): principal surface strain and stress, deflection over (x, y), strain gauges."""

import math

import jax
import jax.numpy as jnp

from .._board.base import Gauges, Peak
from .._board.plate import surface_strain, surface_stress
from .._board.plate_checks import blank_readings, response_flags
from .._board.search import field_on_grid, find_plate_peak, plate_starts
from .._common.checks import Flag, combine, flag_if, float_dtype
from .numerics import Numerics
from .results import Convergence, Response
from .setup import _Setup, _setup


def _plate_strain(plate, u, kxx, kyy, kxy):
    return surface_strain(plate, kxx, kyy, kxy)


def _plate_stress(plate, u, kxx, kyy, kxy):
    return surface_stress(plate, kxx, kyy, kxy)


def _plate_deflection(plate, u, kxx, kyy, kxy):
    return jnp.abs(u)


PLATE_MEASURES = {"stress": _plate_stress, "strain": _plate_strain, "deflection": _plate_deflection}


def _plate_grid(plate):
    """Normalised search grid (xi, eta): two points per basis function along each direction, edges included."""
    return jnp.linspace(0.0, 1.0, 2 * plate.basis[0] + 1), jnp.linspace(-0.5, 0.5, 2 * plate.basis[1] + 1)


def _plate_points(plate, modes):
    """The search grid (xi, eta), its points (x, y) (m, xi-major) and the mode shapes (phi, phi_xx, phi_yy, phi_xy)
    there."""
    xi, eta = _plate_grid(plate)
    XI, ETA = (v.ravel() for v in jnp.meshgrid(xi, eta, indexing="ij"))
    x, y = XI * plate.length, ETA * plate.width
    return xi, eta, (x, y), modes.shapes(x, y)


def _plate_searches(S: _Setup, plate, numerics: Numerics, modes, kinds: tuple[str, ...], mask, check=None,
                    fields=None):
    """Peaks of the measures `kinds` (of `PLATE_MEASURES`) of the field with modal mask `mask`: the fields on the
    grid once (or `fields`, (u, k_xx, k_yy, k_xy) on the grid, when the caller has them), each kind's own
    candidates, then one batched refinement (one compiled copy). With a second mask `check`, one more row: the
    first kind's peak with that mask, started at the first kind's candidate times (its fields are evaluated at
    those times alone: it measures the same peak with more modes)."""
    _, _, points, shapes = _plate_points(plate, modes)
    fields = [field_on_grid(mask, S.Q, v) for v in shapes] if fields is None else fields
    measures = [PLATE_MEASURES[k] for k in kinds]
    candidates = numerics.candidates if numerics.refine else 1
    starts = [plate_starts(plate, m, fields, points, candidates) for m in measures]
    masks = [mask] * len(kinds)
    if check is not None:
        scale, R = S.Q
        times = starts[0][0]
        at_times = [field_on_grid(check, (scale, R[times]), v) for v in shapes]
        starts.append(plate_starts(plate, measures[0], None, points, candidates, times, at_times))
        masks.append(check)
        measures.append(measures[0])
    xi, eta = _plate_grid(plate)

    def search(mask, which, *start):
        def measure(*args):
            return jnp.select([which == i for i in range(len(measures))], [m(*args) for m in measures])

        return find_plate_peak(measure, mask, S.modal, modes, xi, eta, S.t, S.window, start,
                               newton_steps=numerics.newton_steps, refine=numerics.refine)

    return jax.vmap(search)(jnp.stack(masks), jnp.arange(len(masks)), *(jnp.stack(v) for v in zip(*starts)))


def _gauges(plate, S: _Setup, modes, mask, points) -> Gauges:
    points = jnp.asarray(points, dtype=float_dtype())
    gx, gy = points[:, 0], points[:, 1]
    _, kxx, kyy, kxy = (field_on_grid(mask, S.Q, v) for v in modes.shapes(gx, gy))
    z = plate.thickness / 2
    strain = surface_strain(plate, kxx, kyy, kxy)
    # Peak time of each gauge: grid maximum, then Newton in t on the modal solution.
    j = strain.argmax(axis=1)

    def reading(x, y, t):
        q = S.modal(t) * mask
        _, a, b, c = (jnp.sum(q * v) for v in modes.shapes(x, y))
        return surface_strain(plate, a, b, c)

    dt = S.t[1] - S.t[0]
    offsets = jnp.array([-1.0, 0.0, 1.0]) * (dt / 16)

    def refine(x, y, t0):
        # Newton in t on derivatives from a three-point stencil (one batched evaluation, a small program); each
        # pass evaluates the pending time and keeps it if it gains.
        def step(carry, _):
            t, f, g, h, t_new = carry
            lo, mid, hi = jax.vmap(lambda s: reading(x, y, s))(t_new + offsets)
            g_new, h_new = (hi - lo) / (2 * offsets[2]), (hi - 2 * mid + lo) / offsets[2] ** 2
            better = mid > f
            t, f, g, h = (jnp.where(better, a, b) for a, b in zip((t_new, mid, g_new, h_new), (t, f, g, h)))
            move = jnp.where(h < 0, -g / jnp.where(h < 0, h, -1.0), 0.0)
            return (t, f, g, h, jnp.clip(t + jnp.clip(move, -dt, dt), 0.0, S.window)), None

        start = (t0, jnp.full_like(t0, -jnp.inf), jnp.zeros_like(t0), jnp.zeros_like(t0), t0)
        return jax.lax.scan(step, start, None, length=5)[0][0]

    t_peak = jax.lax.stop_gradient(jax.vmap(refine)(gx, gy, S.t[j]))
    peak = jnp.maximum(jax.vmap(reading)(gx, gy, t_peak), strain[jnp.arange(gx.shape[0]), j])
    return Gauges(gx, gy, S.t, -z * kxx, -z * kyy, -2 * z * kxy, strain, peak, t_peak)


def _respond_plate(plate, motion, numerics: Numerics, flags, gauges=None) -> Response:
    if numerics.stretching:
        raise ValueError("Numerics.stretching = True models pinned beams only, not plates")
    S = _setup(plate, motion, numerics, with_check=True)
    modes = S.modes
    used_mask = (S.k <= S.used).astype(float_dtype())
    found = _plate_searches(S, plate, numerics, modes, ("stress", "strain", "deflection"), used_mask,
                            check=(S.k <= S.check).astype(float_dtype()))
    stress, strain, deflection, check = (jax.tree_util.tree_map(lambda v: v[i], found) for i in range(4))
    tiny = jnp.finfo(S.window.dtype).tiny
    modes_error = jnp.abs(stress.value - check.value) / jnp.maximum(stress.value, tiny)
    check_mask = (S.k <= S.check).astype(float_dtype())
    read = None if gauges is None else _gauges(plate, S, modes, used_mask, gauges)
    gauges_error = jnp.zeros_like(modes_error) if read is None else jnp.max(
        jnp.abs(_readings(plate, S.modal, modes, check_mask, read) - read.peak_strain)
        / jnp.maximum(read.peak_strain, tiny))
    basis_error = _basis_error(plate, motion, numerics, S, stress, read, tiny)
    convergence = Convergence(modes_error, gauges_error, basis_error)
    error = jnp.maximum(jnp.maximum(modes_error, gauges_error), basis_error)
    nonfinite = ~jnp.isfinite(stress.value) | ~jnp.isfinite(deflection.value)
    flags = combine(flags, plate.flags(), S.flags, flag_if(S.failed, Flag.SOLVER_FAILED),
                    flag_if(nonfinite, Flag.NONFINITE_RESULT), response_flags(plate, deflection.value, gauges))
    bad = flags != 0
    nan = lambda v: jnp.where(bad, jnp.nan, v)  # noqa: E731
    peak = Peak(
        stress=nan(stress.value), membrane_stress=jnp.zeros_like(stress.value), strain=nan(strain.value),
        x=nan(stress.x), t=nan(stress.t), deflection=nan(deflection.value), deflection_x=nan(deflection.x),
        deflection_t=nan(deflection.t), search_error=stress.error, y=nan(stress.y), deflection_y=nan(deflection.y),
    )
    return Response(
        impulse=None, housing=None, impacts=None, support_jumps=motion.first_jumps(), peak=peak,
        frequencies=modes.frequencies() / (2 * math.pi), n_modes=S.used, check_modes=S.check, error_estimate=error,
        converged=(error <= numerics.convergence_rtol) & ~bad, window=S.window, flags=flags,
        gauges=None if read is None else blank_readings(read, bad), is_plate=True, convergence=convergence,
    )


def _readings(plate, modal, modes, mask, read: Gauges):
    """The gauges' strains at their peak times with another modal solution or mask (a convergence check)."""

    def reading(x, y, t):
        q = modal(t) * mask
        _, a, b, c = (jnp.sum(q * v) for v in modes.shapes(x, y))
        return surface_strain(plate, a, b, c)

    return jax.vmap(reading)(read.x, read.y, read.peak_time)


def _basis_error(plate, motion, numerics: Numerics, S: _Setup, stress, read, tiny):
    """The relative change of the peak stress (at its point and time) and of the gauges' peak strains (at theirs)
    with a Ritz basis 4 functions larger each way: the peak is stationary there, so the change at the same point
    measures the basis's error to first order without a second search."""
    finer = plate.refined()
    F = _setup(finer, motion, numerics, with_check=False)
    mask = (F.k <= S.used).astype(float_dtype())
    q = F.modal(stress.t) * mask
    _, kxx, kyy, kxy = (jnp.sum(q * v) for v in F.modes.shapes(stress.x, stress.y))
    error = jnp.abs(surface_stress(finer, kxx, kyy, kxy) - stress.value) / jnp.maximum(stress.value, tiny)
    if read is not None:
        fine = _readings(finer, F.modal, F.modes, mask, read)
        error = jnp.maximum(error, jnp.max(jnp.abs(fine - read.peak_strain) / jnp.maximum(read.peak_strain, tiny)))
    return jax.lax.stop_gradient(error)
