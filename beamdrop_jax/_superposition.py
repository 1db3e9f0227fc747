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
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._beam import SYMMETRIC_ENDS, mode_shapes, support_participation
from ._board import unit_response
from ._checks import Flag, combine, flag_if, float_dtype
from ._motion import HalfSine
from ._scene import Board, Scene, scene_flags
from ._simulate import Numerics, _search, _setup, drop_motion

_BUILD_BATCH = 16


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
    into dvB >= 0, which needs one division where an angle would need an `atan2`).

    - `curvature`, `deflection`: (n, 2) rows (K_A, K_B): curvature (1/m per m/s) and deflection (m per m/s) at
      direction j's maximiser, per unit dvA and per unit dvB.
    - `x`, `t`: the curvature maximisers (m from end A, s).
    - `flags`: the board's `Flag` mask; `law`: the restitution law of the impacts.

    Build with `superposition_table`. `table(scene)` gives one drop's (stress, strain, deflection, flags);
    `table_peaks(table, samples, axes)` a batch's.
    """

    curvature: Float[Array, "n 2"]
    deflection: Float[Array, "n 2"]
    x: Float[Array, " n"]
    t: Float[Array, " n"]
    flags: Int[Array, ""]
    law: str = eqx.field(static=True, default="poisson")

    @property
    def n_angles(self) -> int:
        return int(self.curvature.shape[0])

    def peaks(self, jumps: Float[Array, "2"]) -> Float[Array, "2"]:
        """(peak |curvature| (1/m), peak |deflection| (m)) for support jumps (dvA, dvB) (m/s)."""
        n = self.n_angles
        dvA, dvB = jumps[0], jumps[1]
        j = jnp.clip(jnp.floor(_pseudo_angle(dvA, dvB) * (n / 2)), 0, n - 1).astype(jnp.int32)

        # The two table rows around the drop's direction (wrapped: direction p = 2 is p = 0), in one gather; the
        # products written out, since a (2, 2) @ (2,) product and a max would be separate XLA ops under vmap.
        rows = jnp.concatenate([self.curvature, self.deflection], axis=1)
        block = jax.lax.dynamic_slice(jnp.concatenate([rows, rows[:1]]), (j, jnp.zeros_like(j)), (2, 4))
        kappa, deflection = (
            jnp.maximum(jnp.abs(block[0, c] * dvA + block[0, c + 1] * dvB),
                        jnp.abs(block[1, c] * dvA + block[1, c + 1] * dvB))
            for c in (0, 2)
        )
        return jnp.stack([kappa, deflection])

    def response(self, board: Board, jumps: Float[Array, "2"], flags) -> tuple[Array, Array, Array]:
        """Peak stress (Pa), strain (-) and deflection (m) of the table's `board` for support jumps (dvA, dvB)
        (m/s); NaN where the `Flag` mask `flags` is not 0."""
        kappa, deflection = self.peaks(jumps)
        half_h = board.thickness / 2
        values = (board.youngs_modulus * half_h * kappa, half_h * kappa, deflection)
        return tuple(jnp.where(flags != 0, jnp.nan, v) for v in values)

    def __call__(self, scene: Scene):
        """(stress, strain, deflection, flags) of one single-impact drop of the table's board."""
        jumps, flags = _drop_jumps(scene, self.law)
        flags = combine(flags, self.flags)
        return (*self.response(scene.board, jumps, flags), flags)


def _drop_jumps(scene: Scene, law: str):
    """Support jumps (dvA, dvB) of a single-impact drop and its `Flag` mask (scene and impact)."""
    _, impacts, _, flags = drop_motion(scene, Numerics(law=law))
    return impacts.support_jumps[0], combine(scene_flags(scene), flags)


# `jax.jit` rather than `eqx.filter_jit` for these two, called once per chunk: every leaf is an array (or the
# static `axes`), and its dispatch took 76 us against 202 us on the 2-core development machine.
@functools.partial(jax.jit, static_argnums=(1, 2))
def _batch_jumps(samples: Scene, axes, law: str):
    return jax.vmap(lambda scene: _drop_jumps(scene, law), in_axes=(axes,))(samples)


@jax.jit
def _batch_response(table: "SuperpositionTable", board: Board, jumps, flags):
    return jax.vmap(table.response, in_axes=(None, 0, 0))(board, jumps, flags)


def table_peaks(table: SuperpositionTable, samples: Scene, axes):
    """(stress, strain, deflection, flags), each (n,), of the sampled drops `samples` (fields with a leading axis n
    where `axes` says 0) of the table's board.

    Two compiled steps, impacts then table: XLA's CPU fusion recomputes a value inside every fused loop that reads
    it, and in one program the impact's arithmetic was recomputed for each output (measured 2x slower)."""
    jumps, flags = _batch_jumps(samples, axes, table.law)
    flags = combine(flags, table.flags)
    return (*_batch_response(table, samples.board, jumps, flags), flags)


def superposes(numerics: Numerics) -> str | None:
    """Why drops with `numerics` cannot share a table (None when they can)."""
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


@eqx.filter_jit
def _build(board: Board, duration, numerics: Numerics, n_angles: int):
    M = numerics.computed_modes
    if board.ends in SYMMETRIC_ENDS:
        searched, source, mirrored = _mirror_sources(n_angles)
    else:  # no mirror symmetry: every direction is searched
        searched = source = np.arange(n_angles)
        mirrored = np.zeros(n_angles, dtype=bool)
    pseudo = jnp.asarray(searched * (2.0 / n_angles), dtype=float_dtype())

    def node(p):
        direction = _direction(p)
        S = _setup(board, HalfSine(direction[0], direction[1], duration), numerics, with_check=False)
        mask = (S.k <= S.used).astype(float_dtype())
        found = _search(S, board, numerics, jnp.stack([S.curvature * mask, mask]), curvature=(True, False))
        unit = support_participation(board, M)  # modal velocities per unit dvA and per unit dvB

        def at(coeffs, x, t, curvature):
            R = unit_response(t, S.modal.omega, S.modal.zeta, S.modal.duration)
            return (coeffs * R * mode_shapes(board, x, M, curvature)) @ unit

        curvature = at(S.curvature * mask, found.x[0], found.t[0], True)
        deflection = at(mask, found.x[1], found.t[1], False)
        return curvature, deflection, found.x[0], found.t[0], S.failed

    # A few directions at a time: their (x, t) grids then stay in cache (all at once streamed ~40 MB, 2x slower).
    curvature, deflection, x, t, failed = jax.lax.map(node, pseudo, batch_size=_BUILD_BATCH)
    flip = jnp.asarray(mirrored)

    def unfold(rows):  # a mirror image swaps the roles of the two supports
        rows = rows[source]
        return jnp.where(flip[:, None], rows[:, ::-1], rows)

    x = jnp.where(flip, board.length - x[source], x[source])
    return (unfold(curvature), unfold(deflection), x, t[source],
            combine(board.flags(), flag_if(jnp.any(failed), Flag.SOLVER_FAILED)))


def table_numerics(scene: Scene) -> Numerics:
    """The table's peak search: the modes `simulate` keeps for this scene (modes up to f_k tau >= 2), on a grid of
    6 points per period of the top mode and 6 per mode along the board, 6 candidates, 2 Newton steps. Finer than
    `simulate`'s default grid, which missed some drops' peaks by up to 0.37 % among those random drops (a lower
    local maximum); the table pays for it once. Two Newton steps from the grid's parabolic vertex agree with eight
    to 1e-6 (stress) and 1e-5 (deflection) over all directions of the default board and of 0.1 ms and 1 ms pulses,
    and build the table in 13 instead of 18 ms."""
    from ._simulate import _mode_counts, support_motion

    used, _ = _mode_counts(scene.board, support_motion(scene, jnp.ones(2)), Numerics())
    return Numerics(n_modes=int(used), points_per_period=6, x_points_per_mode=6, candidates=6, newton_steps=2)


def superposition_table(scene: Scene, numerics: Numerics | None = None, n_angles: int = 256) -> SuperpositionTable:
    """The `SuperpositionTable` of `scene`'s board and contact duration: the peak search of `numerics` (default
    `table_numerics(scene)`; closed form, one impact) at `n_angles` jump directions (a multiple of 4, >= 8),
    searching n_angles / 2 + 2 of them and mirroring the rest."""
    numerics = table_numerics(scene) if numerics is None else numerics
    why = superposes(numerics)
    if why is not None:
        raise ValueError(f"a superposition table needs one pulse of the closed form, not {why}")
    if not (isinstance(n_angles, int) and n_angles >= 8 and n_angles % 4 == 0):
        raise ValueError(f"n_angles = {n_angles!r}; valid: a multiple of 4, >= 8 (the build uses the board's mirror "
                         "symmetry over quarters of the pseudo-angle)")
    curvature, deflection, x, t, flags = _build(scene.board, scene.contact.duration, numerics, n_angles)
    return SuperpositionTable(curvature, deflection, x, t, flags, law=numerics.law)
