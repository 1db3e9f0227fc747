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
from .._response.objectives import _scene_peaks
from .._response.simulate import _simulate
from .._common.compile import filter_jit
from .._common.report import plain


class MountResult(AbstractOptimum):
    """Outcome of `optimize_mounts`: `mounts` (m, 2) the best found (m), `value` its objective, `initial_value`
    the scene's own mounts' (strain, -), `history` the objective per step, `n_evaluations`, `n_drops`."""

    mounts: Float[Array, "m 2"]
    value: Float[Array, ""]
    initial_value: Float[Array, ""]
    history: Float[Array, " steps"]
    n_evaluations: int = eqx.field(static=True)
    n_drops: int = eqx.field(static=True)
    objective: str = eqx.field(static=True)

    def summary(self) -> dict:
        return plain({"objective": f"{self.objective} peak strain over {self.n_drops} drops",
                      "before_microstrain": self.initial_value * 1e6, "after_microstrain": self.value * 1e6,
                      "mounts_mm": self.mounts * 1e3, "evaluations": self.n_evaluations})


def _region(plate: Plate, region) -> np.ndarray:
    m = plate.mounts.shape[0]
    L, W, r = float(plate.length), float(plate.width), float(plate.mount_radius)
    if region is None:  # anywhere on the plate, the disc inside it
        return np.broadcast_to(np.array([[r, -W / 2 + r], [L - r, W / 2 - r]]), (m, 2, 2)).copy()
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
    mounts = np.asarray(plate.mounts)
    if np.any(mounts < box[:, 0] - 1e-12) or np.any(mounts > box[:, 1] + 1e-12):
        raise ValueError(f"the scene's mounts {mounts.tolist()} m must start inside their region boxes")
    return box


def optimize_mounts(
    scene: Scene,
    *,
    region=None,
    min_spacing: float = 0.0,
    gauges=None,
    orientations=None,
    heights=None,
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
      plate (outside the mount discs).
    - `orientations`, `heights`: the drops (default the scene's own drop); `objective`: `"mean"`, `"max"` or
      `"cvar"` (level `alpha`) over them.
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
    box = jnp.asarray(_region(scene.board, region), dtype=float_dtype())
    lo, span = box[:, 0], box[:, 1] - box[:, 0]
    drops = scene if orientations is None and heights is None else drop_set(
        scene, scene.drop.orientation if orientations is None else orientations, heights)
    batched = orientations is not None or heights is not None
    n_drops = int(drops.drop.orientation.shape[0]) if batched else 1
    frac = jnp.clip((scene.board.mounts - lo) / jnp.where(span > 0, span, 1.0), 1e-6, 1 - 1e-6)
    z0 = jnp.where(span > 0, jnp.log(frac / (1 - frac)), 0.0)

    def mounts_of(z):
        return lo + span * jax.nn.sigmoid(z)

    def peak(s):
        if points is None:
            return _scene_peaks(s, numerics, ("strain",))[0][0]
        return jnp.max(_simulate(s, numerics, points).gauges.peak_strain)

    def f(z):
        m = mounts_of(z)
        moved = eqx.tree_at(lambda s: s.board.mounts, drops, jnp.broadcast_to(m, drops.board.mounts.shape))
        values = jax.vmap(peak)(moved) if batched else peak(moved)[None]
        value = risk(values, objective, alpha)
        if min_spacing > 0:
            d = jnp.sqrt(jnp.sum((m[:, None] - m[None]) ** 2, axis=-1) + jnp.eye(m.shape[0]))
            value = value * (1 + 1e3 * jnp.sum(jnp.triu(jnp.maximum(min_spacing - d, 0.0), 1) ** 2) / min_spacing**2)
        return value

    optimizer = optax.adam(learning_rate)
    key = jax.random.PRNGKey(0) if key is None else key
    others = jax.random.uniform(key, (starts - 1,) + z0.shape, minval=-2.5, maxval=2.5) * (span > 0)
    Z = jnp.concatenate([z0[None], others])

    @filter_jit
    def step(Z, state):
        values, grads = jax.vmap(jax.value_and_grad(f))(Z)
        updates, state = jax.vmap(optimizer.update)(grads, state, Z)
        return optax.apply_updates(Z, updates), state, values

    state = jax.vmap(optimizer.init)(Z)
    best_z, best_v, history = Z, jnp.full((starts,), jnp.inf), []
    for _ in tqdm(range(steps), desc="optimize_mounts", disable=not progress, leave=False):
        Z_new, state, values = step(Z, state)
        improved = jnp.isfinite(values) & (values < best_v)  # a flagged (NaN) step is never the best
        best_v, best_z = jnp.where(improved, values, best_v), jnp.where(improved[:, None, None], Z, best_z)
        history.append(values)
        Z = Z_new
    final = filter_jit(jax.vmap(f))(Z)
    improved = jnp.isfinite(final) & (final < best_v)
    best_v, best_z = jnp.where(improved, final, best_v), jnp.where(improved[:, None, None], Z, best_z)
    winner = int(jnp.argmin(best_v))
    histories = jnp.stack(history, axis=1)
    return MountResult(mounts_of(best_z[winner]), best_v[winner], histories[0, 0], histories[winner],
                       starts * (steps + 1), n_drops, objective)
