"""Where should the screws go? Gradient-based placement of a plate's mounts with optax.

Each mount moves inside its own box `region[i] = ((x_lo, y_lo), (x_hi, y_hi))` (m): mount = lo + (hi - lo)
sigmoid(z) for unconstrained z, so every step is feasible (a box of zero width holds that coordinate fixed). A
minimum spacing between mounts is a quadratic penalty. The objective is the mean, max or CVaR over a set of drops of
the peak principal surface strain over the plate or, with `gauges`, the largest gauge reading (the part you care
about).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from tqdm import tqdm

from .._common.checks import float_dtype
from .optimum import AbstractOptimum
from .placement import OBJECTIVES, drop_set, risk
from .._board.plate import Plate
from .._scene.containers import Scene, check_scene
from .._response.numerics import Numerics
from .._response.setup import _gauge_points
from .._response.objectives import _scene_peaks, landing_batches, objective_landing
from .._response.simulate import _simulate
from .._common.compile import filter_jit
from .._common.reductions import largest
from .._common.report import plain


class MountResult(AbstractOptimum):
    """Outcome of `optimize_mounts`: `mounts` (m, 2) the best found (m); `value` its objective and
    `initial_value` the scene's own mounts' (strain, -: the mean, max or CVaR peak strain, without the spacing
    penalty); `history` the penalised objective per step of the best start; `spacing` the smallest distance
    between the returned mounts (m) against `min_spacing`; `converged` whether the best start's objective changed
    by less than 1e-3 over its last fifth of steps; `n_evaluations`, `n_drops`."""

    mounts: Float[Array, "m 2"]
    value: Float[Array, ""]
    initial_value: Float[Array, ""]
    history: Float[Array, " steps"]
    spacing: Float[Array, ""]
    min_spacing: float = eqx.field(static=True)
    converged: bool = eqx.field(static=True)
    n_evaluations: int = eqx.field(static=True)
    n_drops: int = eqx.field(static=True)
    objective: str = eqx.field(static=True)

    @property
    def spacing_met(self) -> bool:
        """Whether the returned mounts keep `min_spacing` (to 1 %)."""
        return bool(self.spacing >= 0.99 * self.min_spacing)

    def summary(self) -> dict:
        drops = f"{self.n_drops} drop" + ("" if self.n_drops == 1 else "s")
        out = {"objective": f"{self.objective} peak strain over {drops}",
               "before_microstrain": self.initial_value * 1e6, "after_microstrain": self.value * 1e6,
               "mounts_mm": self.mounts * 1e3, "evaluations": self.n_evaluations,
               "converged": self.converged}
        if self.min_spacing > 0:
            out["smallest_spacing_mm"] = self.spacing * 1e3
            out["min_spacing_met"] = self.spacing_met
        return plain(out)


def _region(plate: Plate, region) -> np.ndarray:
    """Each mount's box, its disc kept on the plate: a box of some width is cut to where a disc of `mount_radius`
    fits (a box of zero width may hold a mount on an edge itself, a boundary point support)."""
    m = plate.mounts.shape[0]
    L, W, r = float(plate.length), float(plate.width), float(plate.mount_radius)
    fits = np.array([[r, -W / 2 + r], [L - r, W / 2 - r]])
    if region is None:  # anywhere on the plate, the disc inside it
        return np.broadcast_to(fits, (m, 2, 2)).copy()
    box = np.asarray(region, dtype=float)
    if box.shape == (2, 2):
        box = np.broadcast_to(box, (m, 2, 2)).copy()
    if box.shape != (m, 2, 2) or not np.all(np.isfinite(box)):
        raise ValueError(f"region has shape {box.shape}; valid: ((x_lo, y_lo), (x_hi, y_hi)) in m, one box for "
                         f"every mount or one per mount ({m}, 2, 2)")
    inside = (box[:, :, 0] >= 0) & (box[:, :, 0] <= L) & (np.abs(box[:, :, 1]) <= W / 2)
    if not np.all(inside) or np.any(box[:, 1] < box[:, 0]):
        raise ValueError(f"region {box.tolist()} m; valid: boxes with lo <= hi on the plate (0 <= x <= {L:g}, "
                         f"|y| <= {W / 2:g})")
    wide = box[:, 1] > box[:, 0]
    cut = np.where(wide[:, None], np.stack([np.maximum(box[:, 0], fits[0]), np.minimum(box[:, 1], fits[1])], 1), box)
    empty = wide[:, None] & (cut[:, 1] < cut[:, 0])
    if np.any(empty):
        i = int(np.argwhere(empty)[0][0])
        raise ValueError(f"region[{i}] = {box[i].tolist()} m leaves no place where a mount's disc (mount_radius = "
                         f"{r:g} m) fits on the plate; valid: boxes reaching into {r:g} <= x <= {L - r:g} m, "
                         f"|y| <= {W / 2 - r:g} m")
    mounts = np.asarray(plate.mounts)
    if np.any(mounts < cut[:, 0] - 1e-12) or np.any(mounts > cut[:, 1] + 1e-12):
        raise ValueError(f"the scene's mounts {mounts.tolist()} m must start inside their region boxes, each cut to "
                         f"where a mount's disc fits on the plate ({cut.tolist()} m)")
    return cut


def _check_spacing(box: np.ndarray, min_spacing: float) -> None:
    """A `min_spacing` the boxes cannot give every pair of mounts is refused: two mounts whose boxes' farthest
    points are closer than it could never meet it."""
    m = box.shape[0]
    for i in range(m):
        for j in range(i + 1, m):
            gap = np.maximum(np.abs(box[i, 1] - box[j, 0]), np.abs(box[j, 1] - box[i, 0]))
            if float(np.hypot(*gap)) < min_spacing:
                raise ValueError(f"min_spacing = {min_spacing:g} m cannot be met: mounts {i} and {j} can be at most "
                                 f"{float(np.hypot(*gap)):.4g} m apart in their boxes; valid: min_spacing <= that, "
                                 "or larger boxes (region)")


def optimize_mounts(
    scene: Scene,
    *,
    region=None,
    min_spacing: float = 0.0,
    gauges=None,
    orientations=None,
    heights=None,
    tilts=None,
    objective: str = "mean",
    alpha: float = 0.9,
    numerics: Numerics | None = None,
    steps: int = 40,
    learning_rate: float = 0.3,
    starts: int = 4,
    key=None,
    progress: bool = True,
) -> MountResult:
    """Move a plate's mounts (screws) to minimise the peak strain over a set of drops.

    **Arguments:**
    - `region`: per mount a box ((x_lo, y_lo), (x_hi, y_hi)) (m) it stays in (one box for all, or one each);
      default anywhere on the plate. `min_spacing`: least distance between mounts (m; a penalty).
    - `gauges`: points ((x, y), ...) (m); the objective is then their largest peak reading, else the peak over the
      plate (outside the mount discs). A gauge off the plate, not finite or inside a mount's disc at the start is
      refused (`ValueError`, as `simulate` refuses it).
    - `orientations`, `heights`: the drops (default the scene's own drop), every orientation (rad) at every height
      (m); `tilts` (rad, a box housing's: one per orientation) makes each orientation an attitude in 3D;
      `objective`: `"mean"`, `"max"` or `"cvar"` (level `alpha`) over them.
    - `numerics` (default `Numerics(n_modes=8)`), `steps` and `learning_rate` of optax's Adam on the unconstrained
      variables, from the scene's mounts and `starts - 1` random positions in the boxes (`key`), optimised together
      (the strain is not convex in the mount positions: a screw next to the gauge can be a local optimum).
    """
    import optax

    if getattr(scene.board, "mounts", None) is None:
        raise ValueError("optimize_mounts moves the mounts of a plate: the scene's board must be a bd.Plate with mounts")
    if objective not in OBJECTIVES:
        raise ValueError(f"objective = {objective!r}; valid: {', '.join(OBJECTIVES)}")
    if not (isinstance(steps, int) and steps >= 1) or not (isinstance(starts, int) and starts >= 1):
        raise ValueError(f"steps = {steps!r}, starts = {starts!r}; valid: ints >= 1")
    if not min_spacing >= 0:
        raise ValueError(f"min_spacing = {min_spacing!r} m; valid: >= 0")
    check_scene(scene)
    numerics = Numerics(n_modes=8) if numerics is None else numerics
    points = _gauge_points(gauges)
    scene.board.check_gauges(points)  # a gauge off the plate would be optimised silently
    box = _region(scene.board, region)
    _check_spacing(box, float(min_spacing))
    box = jnp.asarray(box, dtype=float_dtype())
    lo, span = box[:, 0], box[:, 1] - box[:, 0]
    if tilts is not None and orientations is None:
        raise ValueError("tilts pair with orientations (one attitude each): give orientations too (rad)")
    drops = scene if orientations is None and heights is None else drop_set(
        scene, scene.drop.orientation if orientations is None else orientations, heights, tilts)
    batched = orientations is not None or heights is not None
    n_drops = int(drops.drop.orientation.shape[0]) if batched else 1
    # A start on a box's edge would sit where the sigmoid is flat (and never move): a hundredth inside it.
    frac = jnp.clip((scene.board.mounts - lo) / jnp.where(span > 0, span, 1.0), 1e-2, 1 - 1e-2)
    z0 = jnp.where(span > 0, jnp.log(frac / (1 - frac)), 0.0)

    def mounts_of(z):
        return lo + span * jax.nn.sigmoid(z)

    # Each drop on its own landing path: a batch split by `landing_batches` (the drops on the rigid law alone in a
    # program without the landing's), one drop by `objective_landing`.
    batches = landing_batches(drops, numerics) if batched else [drops]

    def landing_of(batch):
        if not batched:
            return objective_landing(batch, numerics)
        return "rigid" if batch.contact.model == "rigid" or numerics.max_impacts > 1 else "either"

    def peak(s, landing):
        if points is None:
            return _scene_peaks(s, numerics, ("strain",), landing=landing)[0][0]
        return largest(_simulate(s, numerics, points, landing=landing).gauges.peak_strain)

    kinds = [landing_of(b) for b in batches]

    def strain_at(m):
        values = []
        for batch, landing in zip(batches, kinds):
            moved = eqx.tree_at(lambda s: s.board.mounts, batch, jnp.broadcast_to(m, batch.board.mounts.shape))
            values.append(jax.vmap(lambda s: peak(s, landing))(moved) if batched else peak(moved, landing)[None])
        return risk(jnp.concatenate(values), objective, alpha)

    def penalised(m):
        value = strain_at(m)
        if min_spacing > 0:
            d = jnp.sqrt(jnp.sum((m[:, None] - m[None]) ** 2, axis=-1) + jnp.eye(m.shape[0]))
            return value * (1 + 1e3 * jnp.sum(jnp.triu(jnp.maximum(min_spacing - d, 0.0), 1) ** 2) / min_spacing**2), value
        return value, value

    # One compiled program evaluates every layout: the steps', the last one's and the report's (the strain of the
    # layout returned and of the scene's own), so the optimiser compiles its objective once.
    @filter_jit
    def evaluate(M):
        """Each layout's objective, its gradient in the mounts, and its strain (the objective without penalty)."""
        (values, strains), grads = jax.vmap(jax.value_and_grad(penalised, has_aux=True))(M)
        return values, grads, strains

    optimizer = optax.adam(learning_rate)

    @filter_jit
    def update(Z, grads, state):
        s = jax.nn.sigmoid(Z)
        updates, state = jax.vmap(optimizer.update)(grads * span * s * (1 - s), state, Z)
        return optax.apply_updates(Z, updates), state

    def strains(layouts):
        """The strain of each layout, `starts` at a time (the shape `evaluate` compiled for)."""
        out = []
        for i in range(0, layouts.shape[0], starts):
            part = layouts[i:i + starts]
            fill = jnp.broadcast_to(part[:1], (starts - part.shape[0],) + part.shape[1:])
            out.append(evaluate(jnp.concatenate([part, fill]))[2][:part.shape[0]])
        return jnp.concatenate(out)

    key = jax.random.PRNGKey(0) if key is None else key
    others = jax.random.uniform(key, (starts - 1,) + z0.shape, minval=-2.5, maxval=2.5) * (span > 0)
    Z = jnp.concatenate([z0[None], others])
    state = jax.vmap(optimizer.init)(Z)
    best_z, best_v, history = Z, jnp.full((starts,), jnp.inf), []
    for _ in tqdm(range(steps), desc="optimize_mounts", disable=not progress, leave=False):
        values, grads, _ = evaluate(mounts_of(Z))
        improved = jnp.isfinite(values) & (values < best_v)  # a flagged (NaN) step is never the best
        best_v, best_z = jnp.where(improved, values, best_v), jnp.where(improved[:, None, None], Z, best_z)
        history.append(values)
        Z, state = update(Z, grads, state)
    final = evaluate(mounts_of(Z))[0]
    improved = jnp.isfinite(final) & (final < best_v)
    best_v, best_z = jnp.where(improved, final, best_v), jnp.where(improved[:, None, None], Z, best_z)
    winner = int(jnp.argmin(best_v))
    histories = jnp.stack(history, axis=1)
    best = mounts_of(best_z[winner])
    # What the user reads is the strain of the layout returned and of the scene's own, not the penalised objective.
    value, initial = strains(jnp.stack([best, jnp.asarray(scene.board.mounts, best.dtype)]))
    d = jnp.sqrt(jnp.sum((best[:, None] - best[None]) ** 2, axis=-1))
    spacing = jnp.min(jnp.where(jnp.eye(best.shape[0], dtype=bool), jnp.inf, d)) if best.shape[0] > 1 else jnp.inf
    tail = np.asarray(histories[winner])[-max(2, steps // 5):]
    converged = bool(np.ptp(tail) <= 1e-3 * abs(float(best_v[winner])))
    return MountResult(best, value, initial, histories[winner], spacing, float(min_spacing), converged,
                       starts * (steps + 1), n_drops, objective)
