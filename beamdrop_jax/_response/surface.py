"""Peaks of a board whose domain is a surface (a plate): principal surface strain and stress, deflection over (x, y), strain gauges."""

import collections
import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._board.base import Gauges, Peak
from .._board.plate import PlateModes, surface_strain, surface_stress
from .._board.plate_checks import blank_readings, response_flags
from .._board.search import candidate_times, field_on_grid, find_plate_peak, plate_envelopes, plate_starts, ring_points
from .._common.checks import Flag, combine, flag_if, float_dtype, is_concrete
from .._common.compile import filter_jit
from .._common.memo import keep, tree_digest
from .closed_form import ClosedFormModes
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
    grid and on the mounts' circles (`ring_points`) once (or `fields`, (u, k_xx, k_yy, k_xy) on the grid and the same
    on the circles, when the caller has them), each kind's own candidates on the grid and, half as many, on the
    circles (a peak at a screw need not outdo the plate's interior at the same time to be searched; one candidate
    set let a circle's maximum displace the interior's, 874 against 880 microstrain), then one batched refinement (one
    compiled copy). With a second mask `check`, one more row: the first kind's peak with that mask, started at the
    first kind's candidate times (its fields are evaluated at those times alone: it measures the same peak with
    more modes)."""
    _, _, points, shapes = _plate_points(plate, modes)
    parts = [(points, shapes)]
    if plate.mounts is not None:
        rings = ring_points(plate)
        parts.append((rings, modes.shapes(*rings)))
    measures = [PLATE_MEASURES[k] for k in kinds]
    candidates = numerics.candidates if numerics.refine else 1
    scale, R = S.Q
    starts = [[] for _ in measures]
    for part, (where, part_shapes) in enumerate(parts):
        given = None if fields is None else fields[part]
        envelopes = plate_envelopes(plate, measures, where, fields=given, shapes=part_shapes, Q=S.Q, mask=mask)
        for m, (measure, envelope) in enumerate(zip(measures, envelopes)):
            times = candidate_times(envelope, candidates if part == 0 else -(-candidates // 2))
            at_times = ([field_on_grid(mask, (scale, R[times]), v) for v in part_shapes] if given is None
                        else [f[:, times] for f in given])
            starts[m].append(plate_starts(plate, measure, where, times, at_times))
    # One set of starts per measure: the grid's, then the circles' (their points past the grid's: `find_plate_peak`).
    n_plane = points[0].shape[0]
    starts = [tuple(jnp.concatenate([a[k] + (n_plane * i if k == 1 else 0) for i, a in enumerate(rows)])
                    for k in range(3)) for rows in starts]
    masks = [mask] * len(kinds)
    if check is not None:
        times = starts[0][0]
        every = [jnp.concatenate(v) for v in zip(*(p[1] for p in parts))]
        at_times = [field_on_grid(check, (scale, R[times]), v) for v in every]
        starts.append(plate_starts(plate, measures[0], tuple(jnp.concatenate(v) for v in zip(*(p[0] for p in parts))),
                                   times, at_times))
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
    # The shapes at the gauges once: every reading below is a modal solution dotted with them.
    _, *curvatures = modes.shapes(gx, gy)
    kxx, kyy, kxy = (field_on_grid(mask, S.Q, v) for v in curvatures)
    z = plate.thickness / 2
    strain = surface_strain(plate, kxx, kyy, kxy)
    # Peak time of each gauge: grid maximum, then Newton in t on the modal solution.
    j = strain.argmax(axis=1)

    def reading(shapes, t):
        q = S.modal(t) * mask
        return surface_strain(plate, *(jnp.sum(q * v) for v in shapes))

    dt = S.t[1] - S.t[0]
    offsets = jnp.array([-1.0, 0.0, 1.0]) * (dt / 16)

    def refine(shapes, t0):
        # Newton in t on derivatives from a three-point stencil (one batched evaluation, a small program); each
        # pass evaluates the pending time and keeps it if it gains.
        def step(carry, _):
            t, f, g, h, t_new = carry
            lo, mid, hi = jax.vmap(lambda s: reading(shapes, s))(t_new + offsets)
            g_new, h_new = (hi - lo) / (2 * offsets[2]), (hi - 2 * mid + lo) / offsets[2] ** 2
            better = mid > f
            t, f, g, h = (jnp.where(better, a, b) for a, b in zip((t_new, mid, g_new, h_new), (t, f, g, h)))
            move = jnp.where(h < 0, -g / jnp.where(h < 0, h, -1.0), 0.0)
            return (t, f, g, h, jnp.clip(t + jnp.clip(move, -dt, dt), 0.0, S.window)), None

        start = (t0, jnp.full_like(t0, -jnp.inf), jnp.zeros_like(t0), jnp.zeros_like(t0), t0)
        return jax.lax.scan(step, start, None, length=5)[0][0]

    t_peak = jax.lax.stop_gradient(jax.vmap(refine)(curvatures, S.t[j]))
    peak = jnp.maximum(jax.vmap(reading)(curvatures, t_peak), strain[jnp.arange(gx.shape[0]), j])
    return Gauges(gx, gy, S.t, -z * kxx, -z * kyy, -2 * z * kxy, strain, peak, t_peak)


def plate_numerics(plate, numerics: Numerics) -> Numerics:
    """`numerics` for `plate`: the board's own defaults, and under half-sine pulses (the closed form) all
    `computed_modes` kept (on the search grid they cost what fewer would)."""
    numerics = numerics.for_board(plate)
    if numerics.method != "closed_form":
        return numerics
    return dataclasses.replace(numerics, n_modes=numerics.computed_modes)


def plate_eigen(plate):
    """Every mode of the plate's Ritz basis and every mode of the basis check's (`Plate.refined`): two
    eigensolves, `(PlateModes, PlateModes)`. The answer keeps the lowest `Numerics.computed_modes` of the first;
    the convergence check reads the rest and the second."""
    finer = plate.refined()
    return plate.modes(plate.basis[0] * plate.basis[1]), finer.modes(finer.basis[0] * finer.basis[1])


@filter_jit
def _plate_eigen_jit(plate):
    # Arrays only: a program that returns the two `PlateModes` (each holding its plate) took 2.5 ms more a call.
    full, finer = plate_eigen(plate)
    return full.omega2, full.coeffs, finer.omega2, finer.coeffs


def _eigen_of(plate, modes):
    """`plate_eigen(plate)`, from the arrays of `kept_modes` where given."""
    if modes is None:
        return plate_eigen(plate)
    return PlateModes(plate, *modes[:2]), PlateModes(plate.refined(), *modes[2:])


_KEPT_MODES = 4
"""How many plates' modes `kept_modes` keeps in memory (the most recently used)."""
_MODES: "collections.OrderedDict[str, tuple]" = collections.OrderedDict()


def kept_modes(board):
    """The arrays of `plate_eigen(board)` (frequencies and Ritz coefficients of both bases) of a concrete plate,
    kept for the last `_KEPT_MODES` plates asked for, so that another drop of the same plate skips its two
    eigensolves (on the JESD22 board, 140 and 252 functions, half of a drop); None for a beam, a traced plate, or
    one asked for inside a trace (the program solves them then)."""
    if not board.SURFACE or not is_concrete(board):
        return None
    key = tree_digest(board) + str(float_dtype())
    modes = _MODES.get(key)
    if modes is None:
        modes = _plate_eigen_jit(board)
        if not is_concrete(modes):  # a concrete plate closed over by a user's jit: staged there, not kept
            return None
    return keep(_MODES, key, modes, _KEPT_MODES)


def plate_time_grid(numerics: Numerics, modes, forcing) -> Numerics:
    """`numerics` with the time grid a concrete plate's own frequencies allow. Where `Numerics.frequency_growth` is
    left None and the top computed mode (of the plate's `kept_modes`) makes at most 2 M + 8 periods over the window
    (`forcing`, s, plus the fundamental period; or `Numerics.window`): `frequency_growth=1`, the grid of 2 M + 8
    periods at `points_per_period` each (on the JESD22 board 161 times instead of 1057: its 16th mode is 19 times
    its first; a quarter of a drop's time, peaks the same to 1e-11). Else unchanged: M^2 + 8 periods, a bound for
    any board, which traced plates keep."""
    if modes is None or numerics.frequency_growth is not None:
        return numerics
    M = numerics.computed_modes
    omega2 = np.asarray(modes[0])
    if M > omega2.shape[0]:  # too few functions for the modes asked: the program says so
        return numerics
    f1, f_top = np.sqrt(omega2[[0, M - 1]]) / (2 * math.pi)
    span = numerics.window if numerics.window is not None else float(forcing) + 1.0 / f1
    if f_top * span <= 2 * M + 8:  # also False for NaN and for a mechanism's f1 ~ 0
        return dataclasses.replace(numerics, frequency_growth=1)
    return numerics


def forget_modes() -> None:
    """Drop every plate's modes `kept_modes` keeps."""
    _MODES.clear()


def _respond_plate(plate, motion, numerics: Numerics, flags, gauges=None, modes=None) -> Response:
    """`modes`: the plate's `kept_modes` when the caller has them, else they are solved here."""
    if numerics.stretching:
        raise ValueError("Numerics.stretching = True models pinned beams only, not plates")
    numerics = plate_numerics(plate, numerics)
    tiny = jnp.finfo(float_dtype()).tiny
    full, finer = _eigen_of(plate, modes)
    M = numerics.computed_modes
    if numerics.method == "closed_form":
        # Every mode of the Ritz basis from one eigensolve: the answer keeps the lowest computed_modes, the check
        # adds the rest at the peak and the gauges.
        S = _setup(plate, motion, numerics, with_check=False, model=full.first(M))._replace(check=jnp.int32(full.n_free))
        mask = jnp.ones(M, dtype=float_dtype())
        found = _plate_searches(S, plate, numerics, S.modes, ("stress", "strain", "deflection"), mask)
        stress, strain, deflection = (jax.tree_util.tree_map(lambda v: v[i], found) for i in range(3))
        read = None if gauges is None else _gauges(plate, S, S.modes, mask, gauges)
        modes_error, gauges_error, basis_error = _exact_errors(plate, motion, full, finer, M, stress, read, tiny)
    else:
        S = _setup(plate, motion, numerics, with_check=True, model=full.first(M))
        mask = (S.k <= S.used).astype(float_dtype())
        check_mask = (S.k <= S.check).astype(float_dtype())
        found = _plate_searches(S, plate, numerics, S.modes, ("stress", "strain", "deflection"), mask,
                                check=check_mask)
        stress, strain, deflection, check = (jax.tree_util.tree_map(lambda v: v[i], found) for i in range(4))
        modes_error = jnp.abs(stress.value - check.value) / jnp.maximum(stress.value, tiny)
        read = None if gauges is None else _gauges(plate, S, S.modes, mask, gauges)
        gauges_error = jnp.zeros_like(modes_error) if read is None else jnp.max(
            jnp.abs(_readings(plate, S.modal, S.modes, check_mask, read) - read.peak_strain)
            / jnp.maximum(read.peak_strain, tiny))
        basis_error = _basis_error(plate, motion, numerics, S, finer.first(M), stress, read, tiny)
    modes = S.modes
    window_error = (_after_window(plate, S, mask, read) if read is not None and numerics.method == "closed_form"
                    and S.modal.windows == 1 else jnp.zeros_like(modes_error))
    convergence = Convergence(modes_error, gauges_error, basis_error, window_error,
                              check_cap=jnp.asarray(numerics.method == "closed_form"))
    # The modes' and the basis's errors add: the basis check measures the error of the answer's modes.
    error = jnp.maximum(jnp.maximum(modes_error, gauges_error) + basis_error, window_error)
    nonfinite = ~jnp.isfinite(stress.value) | ~jnp.isfinite(deflection.value)
    flags = combine(flags, plate.flags(), S.flags, flag_if(S.failed, Flag.SOLVER_FAILED),
                    flag_if(nonfinite, Flag.NONFINITE_RESULT), response_flags(plate, deflection.value, gauges))
    bad = flags != 0
    nan = lambda v: jnp.where(bad, jnp.nan, v)  # noqa: E731
    peak = Peak(
        stress=nan(stress.value), membrane_stress=jnp.zeros_like(stress.value), strain=nan(strain.value),
        x=nan(stress.x), t=nan(stress.t), deflection=nan(deflection.value), deflection_x=nan(deflection.x),
        deflection_t=nan(deflection.t), search_error=stress.error, y=nan(stress.y), deflection_y=nan(deflection.y),
        strain_x=nan(strain.x), strain_y=nan(strain.y), strain_t=nan(strain.t),
    )
    return Response(
        impulse=None, housing=None, impacts=None, support_jumps=motion.first_jumps()[:2],
        roll_jump=motion.first_jumps()[2], mount_jumps=plate.rigid_motion(motion.first_jumps()), peak=peak,
        frequencies=modes.frequencies() / (2 * math.pi), n_modes=S.used, check_modes=S.check, error_estimate=error,
        converged=(error <= numerics.convergence_rtol) & ~bad, window=S.window, flags=flags,
        gauges=None if read is None else blank_readings(read, bad), is_plate=True, convergence=convergence,
    )


_AFTER_WINDOW_POINTS = 8


def _after_window(plate, S: _Setup, mask, read: Gauges):
    """`Convergence.window`: how much more a gauge reads over (window, 2 window] than its peak within the window,
    relative (0 where it reads less), the largest over the gauges; on `_AFTER_WINDOW_POINTS` times per interval of
    the window's grid (a grid maximum falls short of the peak by the square of the spacing: on the phone board's
    grid of 161 times, 2.8e-4 of a 12 % rise), from the closed form, which holds after the pulse too."""
    later = S.window + jnp.linspace(0.0, S.window, _AFTER_WINDOW_POINTS * (S.t.shape[0] - 1) + 1)[1:]
    scale, R = S.modal.grid_factors(jax.lax.stop_gradient(later))
    _, *curvatures = S.modes.shapes(read.x, read.y)
    strain = surface_strain(plate, *(field_on_grid(mask, (scale, R), v) for v in curvatures))
    peak = jnp.maximum(read.peak_strain, jnp.finfo(read.peak_strain.dtype).tiny)
    return jax.lax.stop_gradient(jnp.max(jnp.maximum(jnp.max(strain, axis=1) / peak - 1.0, 0.0)))


def _readings(plate, modal, modes, mask, read: Gauges):
    """The gauges' strains at their peak times with another modal solution or mask (a convergence check)."""

    def reading(x, y, t):
        q = modal(t) * mask
        _, a, b, c = (jnp.sum(q * v) for v in modes.shapes(x, y))
        return surface_strain(plate, a, b, c)

    return jax.vmap(reading)(read.x, read.y, read.peak_time)


def _exact_response(plate, motion, modes):
    """The exact response to `motion`'s half-sine pulses of every one of `modes` that is the plate's own (the
    directions its mounts hold are left out): a function of (strain, x, y, t, counts) giving, for each n of `counts`
    (None: all), the measure at the points (x, y) and times t (arrays (P,)) from the lowest n modes: the largest
    principal surface strain where `strain` (a bool per point) holds, else the stress. One evaluation of the shapes
    and of the modal solution for all the points and counts (each evaluation site is a copy in the program)."""
    free = (jnp.arange(modes.omega2.shape[0]) < modes.n_free).astype(float_dtype())
    jumps, times, duration = motion.pulses()
    beta = jax.vmap(lambda j: modes.participation() @ j)(jumps) * free
    modal = ClosedFormModes(modes.frequencies(), plate.damping_ratio, duration, beta, times)

    def value(strain, x, y, t, counts):
        q = jax.vmap(modal)(t)
        shapes = modes.shapes(x, y)[1:]
        out = []
        for n in counts:
            kept = q if n is None else q * (jnp.arange(free.shape[0]) < n)
            a, b, c = (jnp.sum(kept * v, axis=-1) for v in shapes)
            out.append(jnp.where(strain, surface_strain(plate, a, b, c), surface_stress(plate, a, b, c)))
        return out

    return value


def _exact_errors(plate, motion, full, finer_full, used: int, stress, read, tiny):
    """(modes, gauges, basis) of `Convergence` for a plate under half-sine pulses, from the exact response of every
    mode at the peak's point and time and the gauges' (few points, so all the modes cost little):

    - modes, gauges: the relative change when every mode of the Ritz basis joins the `used` ones. A plate's modes
      come in families whose next member can lie far up the spectrum (a strip supported along its long sides: the
      first mode with three half-waves across is its 15th), which a check with twice the modes misses; the peak is
      stationary, so its change at the same point is the first-order change of the peak.
    - basis: the change from all the modes of this basis to all the modes of one 4 functions larger each way,
      extrapolated to this basis's error (`BASIS_ORDER`). Whole responses are compared: the k-th mode of two bases
      need not be the same mode high in the spectrum."""
    finer = finer_full.plate
    here, there = _exact_response(plate, motion, full), _exact_response(finer, motion, finer_full)
    points = [stress.x[None], stress.y[None], stress.t[None]]
    if read is not None:
        points = [jnp.concatenate([a, b]) for a, b in zip(points, (read.x, read.y, read.peak_time))]
    strain = np.arange(points[0].shape[0]) > 0  # the peak's stress, then the gauges' strains
    answer, whole = here(strain, *points, (used, None))
    (finer_whole,) = there(strain, *points, (None,))
    scale = jnp.maximum(answer, tiny)
    modes = jnp.abs(whole - answer) / scale
    basis = _richardson(plate, finer) * jnp.max(jnp.abs(finer_whole - whole) / scale)
    gauges = jnp.max(modes[1:]) if read is not None else jnp.zeros_like(modes[0])
    return tuple(jax.lax.stop_gradient(v) for v in (modes[0], gauges, basis))


BASIS_ORDER = 2
"""The order assumed of the Ritz basis's convergence, error ~ n^-BASIS_ORDER in its size n each way (point supports
make it algebraic; measured n^-2.4 on a plate on one screw between 12 and 16 functions, against 28): the change
between n and n + 4 functions is scaled to the error of n by Richardson's extrapolation, 1 / (1 - (n / (n + 4))^2)."""


def _richardson(plate, finer) -> float:
    """The factor from the change between two bases to the error of the smaller (`BASIS_ORDER`)."""
    n, m = min(plate.basis), min(finer.basis)
    return 1.0 / (1.0 - (n / m) ** BASIS_ORDER) if m > n else 1.0


def _basis_error(plate, motion, numerics: Numerics, S: _Setup, finer_modes, stress, read, tiny):
    """The relative change of the peak stress (at its point and time) and of the gauges' peak strains (at theirs)
    with a Ritz basis 4 functions larger each way, extrapolated to the error of this basis (`BASIS_ORDER`): the peak
    is stationary there, so the change at the same point measures the basis's error to first order without a second
    search."""
    finer = finer_modes.plate
    F = _setup(finer, motion, numerics, with_check=False, model=finer_modes)
    mask = (F.k <= S.used).astype(float_dtype())
    q = F.modal(stress.t) * mask
    _, kxx, kyy, kxy = (jnp.sum(q * v) for v in F.modes.shapes(stress.x, stress.y))
    error = jnp.abs(surface_stress(finer, kxx, kyy, kxy) - stress.value) / jnp.maximum(stress.value, tiny)
    if read is not None:
        fine = _readings(finer, F.modal, F.modes, mask, read)
        error = jnp.maximum(error, jnp.max(jnp.abs(fine - read.peak_strain) / jnp.maximum(read.peak_strain, tiny)))
    return jax.lax.stop_gradient(_richardson(plate, finer) * error)
