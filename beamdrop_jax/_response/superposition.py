"""Peaks of many single-impact drops of one board from a table over the direction of the support jumps.

The board's response is linear in its two support jumps: with one pulse shape (the contact's duration) the
curvature is kappa(x, t) = dvA K_A(x, t) + dvB K_B(x, t), and likewise the deflection, with K_A and K_B fixed by
the board and the pulse. The peak of |kappa| is therefore |(dvA, dvB)| times a function of the jumps' direction
alone (of period pi). Drops that differ only in how the housing lands (orientation, height, spin, drift, friction,
restitution) share one `SuperpositionTable`: for n directions the peak search finds its maximiser (x_j, t_j) and
the table keeps K_A and K_B there. A drop's peak is the larger |dvA K_A + dvB K_B| of the two table directions
around its own. Both are values of the field at a point of the board and window, so the result never exceeds the
true peak of the modal series, and it misses it only by the maximiser's drift between neighbouring directions,
which is second order in their spacing (the envelope theorem): at most 6.4e-5 of the stress and 2.4e-4 of the
deflection with the default 256 directions, measured against a 16-points-per-period search on drops with random
height, spin, drift, friction and restitution (tests/test_montecarlo.py). A drop then costs its impact and a few
multiply-adds, about 40 ns on the 2-core development machine against about 3 us for its own peak search.

When the contact duration varies from drop to drop, the table holds the search at m durations as well, and for
each cell between two of them the fields at the four surrounding maximisers (two directions, two durations), each
moved to the drop's duration along the maximiser's own path (its derivative in the duration, by implicit
differentiation of grad f = 0) and tabulated at 8 durations per cell. A drop interpolates these linearly in the
duration and keeps the largest of the four: still fields at points of the board (to the interpolation), now
missing the peak by the maximiser's drift in direction and duration together. With 17 durations over [0.2, 1] ms
and 128 directions: at most 4.6e-4 (stress) and 1.7e-3 (deflection) below a dense per-drop search, 3.5e-5 above
it, for pinned and stiff damped boards; up to 3.4e-3 on a clamped board, where three local maxima (two clamps,
two times) trade places and one can win between two table durations without being a table maximiser at either
(tests/test_montecarlo.py). About 150 ns a drop.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._board.beam import mode_shapes

from .._board.base import support_participation
from .pulses import unit_response, unit_response_jet
from .._common.checks import Flag, Range, as_int, as_real, combine, flag_if, float_dtype, is_concrete
from .._impact.motion import HalfSine
from .._board.plate import Plate
from .._board.search import ring_points
from .._board.beam import Board
from .._scene.containers import Scene, scene_flags
from .surface import PLATE_MEASURES, _eigen_of, _plate_points, _plate_searches, kept_modes, plate_time_grid
from .numerics import Numerics
from .line import _search
from .setup import _setup
from .simulate import drop_motion
from .._board.plate_checks import response_flags
from .._common.compile import filter_jit, jit
from .setup import _mode_counts, support_motion

_BUILD_BATCH = 16
DURATION_NODES = 17
# Durations per cell: the fields at the moved maximisers are 60 % of the table's build; 8 rather than 16 built it
# in 0.34 instead of 0.48 s (one core) and moved the peaks by 2e-5 at most (the interpolation's overshoot above a
# dense per-drop search: 3.5e-5 against 8e-6).
FINE_DURATIONS = 8


def _pseudo_angle(dvA, dvB):
    """A monotone stand-in for the direction's angle mod pi, in [0, 2]: p = 1 - a / (|a| + b) with (a, b) the jump
    folded into b >= 0 (the angle would need an `atan2`, ten times the cost of this division on CPU)."""
    flip = (dvB < 0) | ((dvB == 0) & (dvA < 0))
    a, b = jnp.where(flip, -dvA, dvA), jnp.abs(dvB)
    norm = jnp.abs(a) + b
    return 1.0 - a / jnp.where(norm > 0, norm, 1.0)


def _direction(p):
    """The jump direction (unnormalised) of pseudo-angle p in [0, 2]."""
    return jnp.stack([1.0 - p, 1.0 - jnp.abs(1.0 - p)])


class SuperpositionTable(eqx.Module):
    """Unit-jump fields at the peak search's maximisers for n support-jump directions, evenly spaced in the
    pseudo-angle p in [0, 2) (direction (1 - p, 1 - |1 - p|); p = 1 - dvA / (|dvA| + |dvB|) after folding the jump
    into dvB >= 0, which needs one division where an angle would need an `atan2`), at m contact durations.

    - `durations`: (m,) contact durations (s), evenly spaced (m = 1: the one duration of every drop).
    - `curvature`, `deflection`: (m, n, 2): the curvature (1/m per m/s) and deflection (m per m/s) at duration i
      and direction j's maximiser, per unit dvA and per unit dvB.
    - `x`, `t`: (m, n, 2): the maximisers (m from end A, s) of the curvature and of the deflection.
    - `cells` (m - 1, F + 1, n, 4, 2, 2), with m > 1: for durations tau between nodes i and i + 1, the unit-jump
      curvature and deflection at four points, the maximisers of directions j and j + 1 at durations i and i + 1,
      each moved to tau along its path (dx/dtau, dt/dtau), at F + 1 evenly spaced tau of the cell (F = 8); a
      drop interpolates linearly between the two around its own duration.
    - `flags`: the board's `Flag` mask; `law`: the restitution law of the impacts.

    Build with `superposition_table`. `table(scene)` gives one drop's (stress, strain, deflection, flags);
    `table_peaks(table, samples, axes)` a batch's.
    """

    durations: Float[Array, " m"]
    curvature: Float[Array, "m n 2"]
    deflection: Float[Array, "m n 2"]
    x: Float[Array, "m n 2"]
    t: Float[Array, "m n 2"]
    cells: Float[Array, "m1 F1 n 4 2 2"] | None
    flags: Int[Array, ""]
    law: str = eqx.field(static=True, default="poisson")

    @property
    def n_angles(self) -> int:
        return int(self.curvature.shape[1])

    @property
    def n_durations(self) -> int:
        return int(self.curvature.shape[0])

    def peaks(self, jumps: Float[Array, "2"], duration=None) -> Float[Array, "2"]:
        """(peak |curvature| (1/m), peak |deflection| (m)) for support jumps (dvA, dvB) (m/s) and, for a table
        over several durations, the contact `duration` (s)."""
        n, m = self.n_angles, self.n_durations
        dvA, dvB = jumps[0], jumps[1]
        j = jnp.clip(jnp.floor(_pseudo_angle(dvA, dvB) * (n / 2)), 0, n - 1).astype(jnp.int32)
        if m == 1:
            # The two table rows around the drop's direction (wrapped: direction p = 2 is p = 0), in one gather;
            # the products written out, since a (2, 2) @ (2,) product and a max would be separate XLA ops under
            # vmap.
            rows = jnp.concatenate([self.curvature[0], self.deflection[0]], axis=1)
            block = jax.lax.dynamic_slice(jnp.concatenate([rows, rows[:1]]), (j, jnp.zeros_like(j)), (2, 4))
            return jnp.stack([
                jnp.maximum(jnp.abs(block[0, c] * dvA + block[0, c + 1] * dvB),
                            jnp.abs(block[1, c] * dvA + block[1, c + 1] * dvB))
                for c in (0, 2)
            ])
        # The maximisers of the two directions around the drop's at the two durations around its own, each moved
        # to the drop's duration: every one is the field at a point of the board and window (to the interpolation
        # in duration), so their largest does not exceed the true peak.
        lo, hi = self.durations[0], self.durations[-1]
        F = self.cells.shape[1] - 1
        s = jnp.clip((duration - lo) * ((m - 1) * F / (hi - lo)), 0.0, (m - 1) * F)
        i = jnp.clip(jnp.floor(s / F), 0, m - 2).astype(jnp.int32)
        f = jnp.clip(jnp.floor(s - i * F), 0, F - 1).astype(jnp.int32)
        w = s - (i * F + f)
        # Two whole rows of a flat table: XLA compiles this gather to row copies, where a vmapped `dynamic_slice`
        # of the multi-dimensional table took several times as long.
        points = self.cells.shape[3]
        rows = self.cells.reshape((m - 1) * (F + 1) * n, points * 4)
        at = (i * (F + 1) + f) * n + j
        fields = ((1.0 - w) * rows[at] + w * rows[at + n]).reshape(points, 2, 2)
        return jnp.max(jnp.abs(fields[..., 0] * dvA + fields[..., 1] * dvB), axis=0)

    def outside(self, duration) -> Array:
        """`Flag.OUTSIDE_TABLE` where a contact `duration` (s) lies outside the table's durations."""
        lo, hi = self.durations[0], self.durations[-1]
        slack = 1e-9 * hi
        return flag_if((duration < lo - slack) | (duration > hi + slack), Flag.OUTSIDE_TABLE)

    def response(self, board: Board, jumps: Float[Array, "2"], duration, flags) -> tuple[Array, Array, Array, Array]:
        """Peak stress (Pa), strain (-) and deflection (m) of the table's `board` for support jumps (dvA, dvB)
        (m/s) and contact `duration` (s), and the `Flag` mask; NaN where the mask `flags` is not 0."""
        kappa, deflection = self.peaks(jumps, duration)
        half_h = board.thickness / 2
        values = (board.youngs_modulus * half_h * kappa, half_h * kappa, deflection)
        return (*(jnp.where(flags != 0, jnp.nan, v) for v in values), flags)

    def __call__(self, scene: Scene):
        """(stress, strain, deflection, flags) of one single-impact drop of the table's board."""
        jumps, flags = _drop_jumps(scene, self.law)
        duration = scene.contact.duration
        flags = combine(flags, self.flags, self.outside(duration))
        return self.response(scene.board, jumps, duration, flags)


PLATE_QUANTITIES = ("stress", "strain", "deflection")


class PlateTable(eqx.Module):
    """A plate's `SuperpositionTable`: for n support-jump directions (the pseudo-angle of `SuperpositionTable`) and
    one contact duration, the unit-jump fields at the maximisers of each peak quantity (principal surface stress
    and strain and the deflection have maximisers of their own on a plate).

    - `fields`: (n, 3, 4, 2): at direction j's maximiser of quantity q (stress, strain, deflection), the deflection
      (m per m/s) and curvatures k_xx, k_yy, k_xy (1/m per m/s) per unit dvA and per unit dvB.
    - `x`, `y`, `t`: (n, 3): the maximisers (m from end A, m from the centre line, s).
    - `durations`: (1,) the contact duration (s); `flags`, `law` as in `SuperpositionTable`.
    - Over the sphere (`rolls`, a box's drops out of the plane): n = k * k directions (dvA, dvB, dvR) of
      `_sphere_directions`, `fields` (n, 3, 4, 3) with a third column per unit roll dvR; a drop takes the largest
      measure at the maximisers of the four grid directions around its own, and, where `mirrors` says the plate
      is its own mirror image in x or y, at their mirror images too.

    The principal strain and stress are homogeneous of degree 1 in the jumps, so each direction's peak scales with
    |(dvA, dvB)|, and a drop's peak is the larger value of the measure at the maximisers of the two table directions
    around its own: points of the plate and window, never above the true peak of the modal series.
    """

    fields: Float[Array, "n 3 4 2"]
    x: Float[Array, "n 3"]
    y: Float[Array, "n 3"]
    t: Float[Array, "n 3"]
    durations: Float[Array, " 1"]
    flags: Int[Array, ""]
    law: str = eqx.field(static=True, default="poisson")
    mirrors: tuple = eqx.field(static=True, default=(False, False))

    @property
    def n_angles(self) -> int:
        return int(self.fields.shape[0])

    @property
    def rolls(self) -> bool:
        """Whether the table spans jumps with a roll across the width (a sphere of directions; `superposition_table`
        with `rolls=True`) rather than plane drops (a circle)."""
        return self.fields.shape[-1] == 3

    def peaks(self, plate: Plate, jumps: Float[Array, "2"]) -> Float[Array, "3"]:
        """(peak principal stress (Pa), strain (-), deflection (m)) of `plate` for support jumps (dvA, dvB) (m/s), or
        (dvA, dvB, dvR) on a table that `rolls`."""
        if self.rolls:
            return self._sphere_peaks(plate, jumps)
        n = self.n_angles
        dvA, dvB = jumps[0], jumps[1]
        j = jnp.clip(jnp.floor(_pseudo_angle(dvA, dvB) * (n / 2)), 0, n - 1).astype(jnp.int32)
        # Two rows of a flat table (wrapped: direction p = 2 is p = 0) in one slice, the products written out: a
        # gather per row and a matrix product under vmap took 10x as long.
        rows = self.fields.reshape(n, -1)
        block = jax.lax.dynamic_slice(jnp.concatenate([rows, rows[:1]]), (j, jnp.zeros_like(j)), (2, rows.shape[1]))
        # Scalars per drop, which vmap turns into contiguous vectors: measures on slices of a (2, 3, 4) block
        # took 3x as long.
        def value(d, q, c):
            col = (q * 4 + c) * 2
            return block[d, col] * dvA + block[d, col + 1] * dvB

        return jnp.stack([jnp.maximum(*(PLATE_MEASURES[quantity](plate, *(value(d, q, c) for c in range(4)))
                                        for d in range(2)))
                          for q, quantity in enumerate(PLATE_QUANTITIES)])

    def _sphere_peaks(self, plate: Plate, jumps):
        """`peaks` over the sphere: the largest measure at the maximisers of the four grid directions around the
        jump's own (`_sphere_cell`)."""
        n = int(round(np.sqrt(self.n_angles)))
        i, j = _sphere_cell(jumps, n)
        rows = self.fields.reshape(n * n, -1)
        zero = jnp.zeros_like(i)
        blocks = [jax.lax.dynamic_slice(rows, ((i + di) * n + j, zero), (2, rows.shape[1])) for di in (0, 1)]

        # On a mirror-symmetric plate a direction's peak sits at its maximiser or at the maximiser's mirror image
        # (pure roll has two, at either long edge): the measures there are the maximiser's own at the mirrored
        # jumps, (dvB, dvA, dvR) for x -> L - x and (dvA, dvB, -dvR) for y -> -y (k_xy's sign does not count).
        a, b, c = jumps[0], jumps[1], jumps[2]
        images = [(a, b, c)]
        if self.mirrors[0]:
            images.append((b, a, c))
        if self.mirrors[1]:
            images += [(u, v, -w) for u, v, w in images]

        def value(block, d, q, k, jump):
            col = (q * 4 + k) * 3
            return block[d, col] * jump[0] + block[d, col + 1] * jump[1] + block[d, col + 2] * jump[2]

        return jnp.stack([functools.reduce(jnp.maximum, [
            PLATE_MEASURES[quantity](plate, *(value(block, d, q, k, jump) for k in range(4)))
            for block in blocks for d in range(2) for jump in images]) for q, quantity in enumerate(PLATE_QUANTITIES)])

    def outside(self, duration) -> Array:
        """`Flag.OUTSIDE_TABLE` where a contact `duration` (s) is not the table's."""
        return flag_if(jnp.abs(duration - self.durations[0]) > 1e-9 * self.durations[0], Flag.OUTSIDE_TABLE)

    def response(self, board: Plate, jumps: Float[Array, "3"], duration, flags) -> tuple[Array, Array, Array, Array]:
        """Peak stress (Pa), strain (-) and deflection (m) of the table's plate `board` for support jumps
        (dvA, dvB, dvR) (m/s), and the `Flag` mask: `flags`, with `Flag.OUTSIDE_TABLE` where the roll dvR is not 0
        (the table spans plane drops) and `Flag.OUTSIDE_THEORY` where the plate deflects beyond small rotations, as
        `simulate` flags it; NaN where the mask is not 0."""
        if jumps.shape[-1] > 2 and not self.rolls:
            flags = combine(flags, flag_if(jumps[2] != 0, Flag.OUTSIDE_TABLE))
        values = self.peaks(board, jumps)
        flags = combine(flags, response_flags(board, values[2]))
        return (*(jnp.where(flags != 0, jnp.nan, v) for v in values), flags)

    def __call__(self, scene: Scene):
        """(stress, strain, deflection, flags) of one single-impact drop of the table's plate."""
        jumps, flags = _drop_jumps(scene, self.law)
        flags = combine(flags, self.flags, self.outside(scene.contact.duration))
        return self.response(scene.board, jumps, scene.contact.duration, flags)


def _sphere_directions(n: int) -> np.ndarray:
    """The (n * n, 3) jump directions (dvA, dvB, dvR) of a `PlateTable` over the sphere: the nodes of an n x n grid
    over the square (s, u) in [-1, 1]^2, which maps onto the diamond |p| + |q| <= 1 by p = (s + u) / 2,
    q = (s - u) / 2, and that onto the half sphere of roll >= 0 by (p, q, 1 - |p| - |q|) (an octahedral map:
    no trigonometry to find a drop's cell)."""
    s, u = (v.ravel() for v in np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="ij"))
    p, q = (s + u) / 2, (s - u) / 2
    return np.stack([p, q, 1.0 - np.abs(p) - np.abs(q)], axis=-1)


def _sphere_sources(n: int, x_mirror: bool, y_mirror: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                        np.ndarray]:
    """Which nodes of `_sphere_directions(n)` the build searches, and how the others follow from them by the
    plate's mirror symmetries. x -> L - x swaps the end supports: direction (a, b, c) -> (b, a, c), node (i, j) ->
    (i, n - 1 - j). y -> -y turns the roll: (a, b, c) -> (a, b, -c), one peak with (-a, -b, c), node (i, j) ->
    (n - 1 - i, n - 1 - j).

    **Returns:** `(searched, source, x_flip, y_flip)`: the searched node indices, and for each of the n * n rows
    the position in `searched` it comes from and the mirrors that carry it there."""
    i, j = np.divmod(np.arange(n * n), n)
    options = [(False, False)] + [(fx, fy) for fx, fy in ((True, False), (False, True), (True, True))
                                  if (x_mirror or not fx) and (y_mirror or not fy)]

    def image(fx, fy):
        ii = np.where(fy, n - 1 - i, i)
        jj = np.where(fx != fy, n - 1 - j, j)  # both mirrors turn j twice
        return ii * n + jj

    images = np.stack([image(fx, fy) for fx, fy in options])  # (ops, n * n)
    pick = np.argmin(images, axis=0)  # each node's representative: its smallest image
    canonical = images[pick, np.arange(n * n)]
    searched = np.unique(canonical)
    ops = np.array(options)[pick]
    return searched, np.searchsorted(searched, canonical), ops[:, 0], ops[:, 1]


def _sphere_cell(jumps, n: int):
    """The grid cell (i, j) of `_sphere_directions(n)` that holds the direction of `jumps` (dvA, dvB, dvR), folded
    onto roll >= 0 (a jump and its negative have one peak)."""
    a, b, c = jumps[0], jumps[1], jumps[2]
    flip = c < 0
    a, b, c = (jnp.where(flip, -v, v) for v in (a, b, c))
    norm = jnp.abs(a) + jnp.abs(b) + c
    norm = jnp.where(norm > 0, norm, 1.0)
    p, q = a / norm, b / norm
    cell = lambda v: jnp.clip(jnp.floor((v + 1.0) * (0.5 * (n - 1))), 0, n - 2).astype(jnp.int32)  # noqa: E731
    return cell(p + q), cell(p - q)


@filter_jit
def _build_plate(plate: Plate, duration, numerics: Numerics, directions, columns: int, batch: int = _BUILD_BATCH,
                 kept=None):
    """`PlateTable` contents at the jump `directions` (k, columns) (unnormalised): the unit-jump fields on the
    search grid once, each direction's measures as their combination, then each direction's refinement.
    `columns` (static): 2 for plane drops (dvA, dvB), 3 with the roll across the width; `batch` (static):
    directions searched at once; `kept`: the plate's `kept_modes` (else it is solved here)."""
    model = None if kept is None else _eigen_of(plate, kept)[0].first(numerics.for_board(plate).computed_modes)
    S = _setup(plate, HalfSine(1.0, 0.0, duration), numerics, with_check=False, model=model)
    modes = S.modes
    mask = (S.k <= S.used).astype(float_dtype())
    unit = support_participation(modes, mask.shape[0])[:, :columns] * mask[:, None]
    _, R = S.Q
    _, _, _, shapes = _plate_points(plate, modes)
    # On the grid and on the mounts' circles (`ring_points`; none without mounts): each (C, 4, points, nt).
    rings = modes.shapes(*ring_points(plate)) if plate.mounts is not None else None
    G = [None if part is None else jnp.stack([jnp.stack([(v * unit[:, c]) @ R.T for v in part])
                                              for c in range(columns)]) for part in (shapes, rings)]
    omega, zeta = S.modal.omega, S.modal.zeta

    def direction(d):
        beta = unit @ d
        D = S._replace(modal=eqx.tree_at(lambda modal: modal.beta, S.modal, beta[None]), Q=(beta, R))
        components = tuple(None if part is None else jnp.tensordot(d, part, axes=1) for part in G)
        found = _plate_searches(D, plate, numerics, modes, PLATE_QUANTITIES, mask, fields=components)
        response = unit_response(found.t[:, None], omega, zeta, duration)  # (3, M)
        at = modes.shapes(found.x, found.y)  # 4 x (3, M)
        fields = jnp.stack([(v * response) @ unit for v in at], axis=1)  # (3, 4, C)
        return fields, found.x, found.y, found.t

    fields, x, y, t = jax.lax.map(direction, directions, batch_size=batch)
    return fields, x, y, t, combine(plate.flags(), flag_if(S.failed, Flag.SOLVER_FAILED))


def _plane_plate_table(plate: Plate, duration, numerics: Numerics, n_angles: int, symmetric: bool, kept=None):
    """A plane drops' `PlateTable` contents (n_angles pseudo-angles); for a mirror-symmetric plate (`symmetric`)
    half the directions are searched, the others by the mirror (`_mirror_sources`; x -> L - x also turns the sign
    of k_xy)."""
    if symmetric:
        searched, source, mirrored = _mirror_sources(n_angles)
    else:
        searched = source = np.arange(n_angles)
        mirrored = np.zeros(n_angles, dtype=bool)
    pseudo = jnp.asarray(searched * (2.0 / n_angles), dtype=float_dtype())
    fields, x, y, t, flags = _build_plate(plate, duration, numerics, jax.vmap(_direction)(pseudo), 2, kept=kept)
    fields, x, y, t = (v[source] for v in (fields, x, y, t))
    flip = jnp.asarray(mirrored)
    image = fields[..., ::-1] * jnp.asarray([1.0, 1.0, 1.0, -1.0])[:, None]  # supports swapped, k_xy turned
    fields = jnp.where(flip[:, None, None, None], image, fields)
    x = jnp.where(flip[:, None], plate.length - x, x)
    return fields, x, y, t, flags


def _sphere_plate_table(plate: Plate, duration, numerics: Numerics, n: int, kept=None):
    """A `PlateTable` over the sphere (`_sphere_directions(n)`): the directions a mirror-symmetric plate does not
    need searched (`_sphere_sources`) are the mirror images of those it does. Returns (fields, x, y, t, flags)."""
    searched, source, x_flip, y_flip = _sphere_sources(n, plate.mirror_symmetric("x"), plate.mirror_symmetric("y"))
    directions = jnp.asarray(_sphere_directions(n)[searched], dtype=float_dtype())
    # Four directions at a time: the phone's table (16 x 16 basis) peaked at 0.8 GB against 1.6 GB with 16, in
    # the same time.
    fields, x, y, t, flags = _build_plate(plate, duration, numerics, directions, 3, 4, kept=kept)
    fields, x, y, t = (v[source] for v in (fields, x, y, t))
    k_xy = jnp.asarray([1.0, 1.0, 1.0, -1.0])[:, None]  # (4 components, 1)
    # x -> L - x: the end supports' columns swap and k_xy turns; y -> -y: k_xy turns, and the roll's column turns
    # with the plate (its field is odd in y, k_xy of it even).
    x_image = fields[..., jnp.array([1, 0, 2])] * k_xy
    fields = jnp.where(jnp.asarray(x_flip)[:, None, None, None], x_image, fields)
    y_image = fields * k_xy * jnp.asarray([1.0, 1.0, -1.0])
    fields = jnp.where(jnp.asarray(y_flip)[:, None, None, None], y_image, fields)
    x = jnp.where(jnp.asarray(x_flip)[:, None], plate.length - x, x)
    y = jnp.where(jnp.asarray(y_flip)[:, None], -y, y)
    return fields, x, y, t, flags


def _drop_jumps(scene: Scene, law: str, from_rest: bool = False):
    """Rigid-motion inputs (dvA, dvB, dvR) of a single-impact drop (a tilted box's from its 3D impact) and its
    `Flag` mask (scene and impact)."""
    motion, _, _, flags = drop_motion(scene, Numerics(law=law, from_rest=from_rest))
    return motion.first_jumps(), combine(scene_flags(scene), flags)


# `jax.jit` rather than `eqx.filter_jit` for these two, called once per chunk: every leaf is an array (or the
# static `axes`), and its dispatch took 76 us against 202 us on the 2-core development machine.
@functools.partial(jit, static_argnums=(1, 2, 3))
def _batch_jumps(samples: Scene, axes, law: str, from_rest: bool):
    return jax.vmap(lambda scene: _drop_jumps(scene, law, from_rest), in_axes=(axes,))(samples)


@functools.partial(jit, static_argnums=(3,))
def _batch_response(table: "SuperpositionTable", board: Board, durations, batched: bool, jumps, flags):
    flags = combine(flags, table.outside(durations))
    return jax.vmap(table.response, in_axes=(None, 0, 0 if batched else None, 0))(board, jumps, durations, flags)


def table_peaks(table: SuperpositionTable, samples: Scene, axes, from_rest: bool = False):
    """(stress, strain, deflection, flags), each (n,), of the sampled drops `samples` (fields with a leading axis n
    where `axes` says 0) of the table's board.

    Two compiled steps, impacts then table: XLA's CPU fusion recomputes a value inside every fused loop that reads
    it, and in one program the impact's arithmetic was recomputed for each output (measured 2x slower).
    `from_rest` (static): every drop starts from rest (`Numerics.from_rest`)."""
    jumps, flags = _batch_jumps(samples, axes, table.law, from_rest)
    flags = combine(flags, table.flags)
    batched = axes.contact.duration is not None
    return _batch_response(table, samples.board, samples.contact.duration, batched, jumps, flags)


def superposes(numerics: Numerics, board, durations=None) -> str | None:
    """Why drops of `board` with `numerics` (and contact durations spanning `durations` = (shortest, longest),
    when they vary) cannot share a table (None when they can)."""
    if durations is not None and not board.TABLE_DURATIONS:
        return (f"the contact durations vary ({durations[0]:g} to {durations[1]:g} s) and a plate's table holds one "
                "duration")
    if numerics.method != "closed_form":
        return f'Numerics.method = "{numerics.method}" (the table is built from the closed form)'
    if numerics.max_impacts != 1:
        return (f"Numerics.max_impacts = {numerics.max_impacts} (a clattering drop's pulses come at times of its "
                "own)")
    return None


def _mirror_sources(n_angles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which directions the build searches, and how the others follow from them by the board's mirror symmetry.

    Swapping the supports maps the field of jumps (dvA, dvB) at (x, t) onto that of (dvB, dvA) at (L - x, t)
    (q_k -> -(-1)^k q_k and sin(k pi (L - x)/L) = -(-1)^k sin(k pi x/L)): the direction of pseudo-angle p in
    [0, 1] mirrors onto 1 - p, and p in [1, 2) onto 3 - p. So only p in [0, 1/2] and [1, 3/2] are searched.

    **Returns:** `(searched, source, mirrored)`: the searched indices j (pseudo-angle 2 j / n), and for each of the
    n table rows the position in `searched` it comes from and whether it is that direction's mirror image."""
    quarter = n_angles // 4
    searched = np.concatenate([np.arange(quarter + 1), np.arange(2 * quarter, 3 * quarter + 1)])
    j = np.arange(n_angles)
    mirrored = ((j > quarter) & (j < 2 * quarter)) | (j > 3 * quarter)
    own = np.where(j < 2 * quarter, np.where(mirrored, 2 * quarter - j, j), np.where(mirrored, 6 * quarter - j, j))
    source = np.searchsorted(searched, own)
    return searched, source, mirrored


@filter_jit
def _build(board: Board, durations, numerics: Numerics, n_angles: int):
    M = numerics.computed_modes
    if board.mirror_symmetric():
        searched, source, mirrored = _mirror_sources(n_angles)
    else:  # no mirror symmetry: every direction is searched
        searched = source = np.arange(n_angles)
        mirrored = np.zeros(n_angles, dtype=bool)
    m = durations.shape[0]
    pseudo = jnp.asarray(searched * (2.0 / n_angles), dtype=float_dtype())
    unit = support_participation(board, M)[:, :2]  # modal velocities per unit dvA and per unit dvB (plane drops)

    def node(duration):
        # The time functions of the grid depend on the pulse alone: computed once per duration, shared by its
        # directions (per direction they took 9/10 of the build).
        S = _setup(board, HalfSine(1.0, 0.0, duration), numerics, with_check=False)
        mask = (S.k <= S.used).astype(float_dtype())
        rows = jnp.stack([S.curvature * mask, mask])
        omega, zeta = S.modal.omega, S.modal.zeta
        _, R = S.Q

        def direction_node(p):
            direction = _direction(p)
            beta = (unit @ direction) * mask
            D = S._replace(modal=eqx.tree_at(lambda modal: modal.beta, S.modal, beta[None]), Q=(beta, R))
            found = _search(D, board, numerics, rows, curvature=(True, False))
            x, t = found.x, found.t
            fields = jnp.stack([_unit_fields(board, unit, c, xq, tq, omega, zeta, duration, curvature)
                                for c, xq, tq, curvature in zip(rows, x, t, (True, False))])
            if m == 1:
                return fields, x, t, None
            rates = jnp.stack([_maximiser_motion(board, c * beta, xq, tq, omega, zeta, duration, curvature)
                               for c, xq, tq, curvature in zip(rows, x, t, (True, False))])
            return fields, x, t, rates

        # A few directions at a time: their (x, t) grids then stay in cache (all at once streamed ~40 MB, 2x
        # slower).
        return (*jax.lax.map(direction_node, pseudo, batch_size=_BUILD_BATCH), rows, S.failed)

    fields, x, t, rates, rows, failed = jax.lax.map(node, durations)
    flip = jnp.asarray(mirrored)

    def unfold(v, swap=True):  # a mirror image swaps the roles of the two supports (the last axis)
        v = v[:, source]
        return jnp.where(flip.reshape((1, -1) + (1,) * (v.ndim - 2)), v[..., ::-1] if swap else -v, v)

    fields = unfold(fields)
    x = jnp.where(flip[:, None], board.length - x[:, source], x[:, source])
    t = t[:, source]
    cells = None
    if m > 1:
        # Mirrored maximisers move the other way along the board, at the same pace in time.
        rates = jnp.stack([unfold(rates[..., 0], swap=False), rates[..., 1][:, source]], axis=-1)
        S = _setup(board, HalfSine(1.0, 0.0, durations[0]), numerics, with_check=False)
        rows = jnp.broadcast_to(rows[:, None], x.shape[:2] + rows.shape[1:])
        cells = _cells(board, unit, rows, x, t, rates, S.modal.omega, S.modal.zeta, durations)
    return (fields[:, :, 0], fields[:, :, 1], x, t, cells,
            combine(board.flags(), flag_if(jnp.any(failed), Flag.SOLVER_FAILED)))


def _unit_fields(board, unit, coeffs, x, t, omega, zeta, duration, curvature):
    """The field of modal coefficients `coeffs` at (x, t) per unit dvA and per unit dvB (last axis, 2)."""
    M = coeffs.shape[-1]
    R = unit_response(t[..., None], omega, zeta, duration)
    return jnp.sum((coeffs * mode_shapes(board, x, M, curvature) * R)[..., None] * unit, axis=-2)


def _maximiser_motion(board, coeffs, x, t, omega, zeta, duration, curvature):
    """(dx/dtau, dt/dtau) of a maximiser (x, t) of |field| as the pulse's duration changes, by implicit
    differentiation of grad f = 0 (on an end of the board, where a clamp's peak sits, of df/dt = 0 alone); the
    pulse's centre, (0, 1/2), where the field is not locally concave."""
    M = coeffs.shape[-1]
    # The second derivatives in closed form (mode shapes' x-derivatives, the response's jet in t, one forward
    # derivative in the duration): `jax.hessian` of the composite made the varied-duration build's program 2x
    # larger, most of its compile time.
    phi, dphi, ddphi = (coeffs * v for v in mode_shapes(board, x, M, curvature, (0, 1, 2)))
    (q, dq, ddq), (q_tau, dq_tau, _) = jax.jvp(lambda tau: unit_response_jet(t, omega, zeta, tau), (duration,),
                                               (jnp.ones_like(duration),))
    hxx, hxt, htt = jnp.sum(ddphi * q), jnp.sum(dphi * dq), jnp.sum(phi * ddq)
    bx, bt = jnp.sum(dphi * q_tau), jnp.sum(phi * dq_tau)
    det = hxx * htt - hxt**2
    interior = (x > 0) & (x < board.length) & (det > 0)
    det = jnp.where(interior, det, 1.0)
    along_t = jnp.abs(htt) > 0
    rx = jnp.where(interior, -(htt * bx - hxt * bt) / det, 0.0)
    rt = jnp.where(interior, -(hxx * bt - hxt * bx) / det,
                   jnp.where(along_t, -bt / jnp.where(along_t, htt, 1.0), 0.5))
    return jnp.stack([rx, rt])


def _cells(board, unit, rows, x, t, rates, omega, zeta, durations):
    """`SuperpositionTable.cells` from the maximisers (x, t) (m, n, 2 quantities) of the modal coefficients
    `rows` (m, n, 2, M), each moved to the cell's durations tau along its `rates` (m, n, 2, 2)."""
    m, F = durations.shape[0], FINE_DURATIONS
    node_durations = jnp.broadcast_to(durations[:, None, None], x.shape)

    def corners(v):  # the points of cell (i, j): directions j, j + 1 (wrapped) at durations i, i + 1
        v = jnp.stack([v, jnp.roll(v, -1, axis=1)], axis=2)
        return jnp.concatenate([v[:-1], v[1:]], axis=2)  # (m - 1, n, 4, 2 quantities, ...)

    C, X, T, V, D = (corners(v) for v in (rows, x, t, rates, node_durations))
    h = (durations[-1] - durations[0]) / (m - 1)
    tau = durations[:-1, None] + h * jnp.linspace(0.0, 1.0, F + 1)  # (m - 1, F + 1)

    def cell(C, X, T, V, D, tau):  # one cell at one of its durations: (n, 4, 2 quantities, 2 columns)
        x = jnp.clip(X + V[..., 0] * (tau - D), 0.0, board.length)
        t = jnp.maximum(T + V[..., 1] * (tau - D), 0.0)
        return jnp.stack([_unit_fields(board, unit, C[..., q, :], x[..., q], t[..., q], omega, zeta, tau, curvature)
                          for q, curvature in enumerate((True, False))], axis=-2)

    per_cell = jax.vmap(cell, in_axes=(None,) * 5 + (0,))
    return jax.vmap(per_cell)(C, X, T, V, D, tau)


@filter_jit
def _modes_used(scene: Scene, kept=None):
    """How many modes `simulate` uses for a scene's pulse (one compiled program: op by op, a plate's eigensolve took
    0.25 s; none with the plate's `kept_modes`)."""
    numerics = Numerics().for_board(scene.board)
    M = numerics.computed_modes
    model = scene.board.modes(M) if kept is None else _eigen_of(scene.board, kept)[0].first(M)
    return _mode_counts(model, support_motion(scene, jnp.ones(2)), numerics)[0]


def table_numerics(scene: Scene, durations=None) -> Numerics:
    """The table's peak search: the modes `simulate` keeps for this scene (modes up to f_k tau >= 2, for the
    shortest of `durations` when given), on a grid of 6 points per period of the top mode and 6 per mode along the
    board, 6 candidates, 2 Newton steps (a plate: 4 points per period, 3 candidates). Finer than `simulate`'s default grid, which missed some drops' peaks by up
    to 0.37 % among those random drops (a lower local maximum); the table pays for it once. Two Newton steps from
    the grid's parabolic vertex agree with eight to 1e-6 (stress) and 1e-5 (deflection) over all directions of the
    default board and of 0.1 ms and 1 ms pulses, and build the table in 13 instead of 18 ms."""
    if durations is not None:
        scene = scene.replace(**{"contact.duration": float(min(durations))})
    used = _modes_used(scene, kept_modes(scene.board))
    if scene.board.SURFACE:
        # A plate's grid is 2 points per basis function each way (625 points for 12 x 12): 4 points per period
        # and 3 candidates build the JESD22 board's table in half the time of 6 and 6, with no larger errors (over
        # 256 random drops the stress within 1.5e-4 below a 16-points-per-period search, and up to 4.4e-4 above
        # it where that search missed a peak).
        return Numerics(n_modes=int(used), points_per_period=4, candidates=3, newton_steps=2)
    return Numerics(n_modes=int(used), points_per_period=6, x_points_per_mode=6, candidates=6, newton_steps=2)


SPHERE_NODES = 33
"""Grid nodes along each side of a `PlateTable` over the sphere of jump directions (33 x 33 = 1089 searches)."""


def superposition_table(scene: Scene, numerics: Numerics | None = None, n_angles: int | None = None,
                        durations=None, n_durations: int = DURATION_NODES, rolls: bool = False,
                        sphere_nodes: int = SPHERE_NODES) -> SuperpositionTable:
    """The `SuperpositionTable` of `scene`'s board: the peak search of `numerics` (default
    `table_numerics(scene, durations)`; closed form, one impact) at `n_angles` jump directions (a multiple of 4,
    >= 8), searching n_angles / 2 + 2 of them and mirroring the rest.

    With `durations=(shortest, longest)` (s) the table spans contact durations from `shortest` to `longest` at
    `n_durations` evenly spaced durations (>= 2), for drops whose contact duration varies; otherwise it holds the
    scene's one duration.

    `rolls` (a plate, one duration): the table spans jumps with a roll across the width (dvA, dvB, dvR), a box's
    drops out of the plane, over a `sphere_nodes` x `sphere_nodes` grid of directions on the half sphere
    (`_sphere_directions`), instead of plane drops."""
    if n_angles is None:
        n_angles = 256 if durations is None else 128
    if durations is None:
        nodes = jnp.reshape(jnp.asarray(scene.contact.duration, dtype=float_dtype()), (1,))
    else:
        if isinstance(durations, str) or np.shape(durations) != (2,):
            raise ValueError(f"durations = {durations!r}; valid: (shortest, longest) in s, or None for the scene's "
                             "one Contact.duration")
        lo, hi = (as_real(v, f"durations[{i}]", Range(0.0, 1.0, lo_open=True, unit="s"))
                  for i, v in enumerate(durations))
        if not hi > lo:
            raise ValueError(f"durations = ({lo:g}, {hi:g}) s; valid: shortest < longest (for one duration give "
                             "none: the scene's Contact.duration)")
        as_int(n_durations, "n_durations", 2, 1024)
        nodes = jnp.linspace(lo, hi, n_durations, dtype=float_dtype())
    numerics = table_numerics(scene, None if durations is None else durations) if numerics is None else numerics
    why = superposes(numerics, scene.board)
    if why is not None:
        raise ValueError(f"a superposition table needs one pulse of the closed form, not {why}")
    if not (isinstance(n_angles, int) and n_angles >= 8 and n_angles % 4 == 0):
        raise ValueError(f"n_angles = {n_angles!r}; valid: a multiple of 4, >= 8 (the build uses the board's mirror "
                         "symmetry over quarters of the pseudo-angle)")
    if rolls and not (scene.board.SURFACE and durations is None):
        raise ValueError("rolls=True spans a plate's jumps with a roll across the width at one contact duration; a "
                         "beam has no roll input, and durations must be None")
    if rolls:
        as_int(sphere_nodes, "sphere_nodes", 3, 257)
    # A plate's modes from `kept_modes` (solved once for its drops and tables), and for plane drops the shorter
    # time grid they allow (`plate_time_grid`: the JESD22 table in a third of the time). Not over the sphere: there
    # it moved a deflection 1.05e-4 above the dense search of tests/test_box_drops.py, whose bound is 1e-4.
    kept = kept_modes(scene.board)
    if kept is not None and not rolls and is_concrete(nodes):
        numerics = plate_time_grid(numerics, kept, float(np.max(np.asarray(nodes))))
    if scene.board.SURFACE and rolls:
        fields, x, y, t, flags = _sphere_plate_table(scene.board, nodes[0], numerics, sphere_nodes, kept)
        mirrors = (scene.board.mirror_symmetric("x"), scene.board.mirror_symmetric("y"))
        return PlateTable(fields, x, y, t, nodes, flags, law=numerics.law, mirrors=mirrors)
    if scene.board.SURFACE:  # the table follows the board's domain (a surface: one measure per quantity)
        fields, x, y, t, flags = _plane_plate_table(scene.board, nodes[0], numerics, n_angles,
                                                    scene.board.mirror_symmetric(), kept)
        return PlateTable(fields, x, y, t, nodes, flags, law=numerics.law)
    return SuperpositionTable(nodes, *_build(scene.board, nodes, numerics, n_angles), law=numerics.law)
