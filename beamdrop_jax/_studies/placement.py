"""Where should the board sit? Gradient-based placement with optax over a set of drops.

The variables are the board's centre (c1, c2) and angle phi. A smooth reparametrisation keeps the board's ends
inside the housing with a clearance `margin`: phi = phi_max tanh(a), c_i = R_i(phi) tanh(b_i) with
R_1 = W/2 - margin - L/2 |cos phi| and R_2 = H/2 - margin - L/2 |sin phi|. Every unconstrained point maps to a
feasible placement, so the optimiser can never return one outside the housing.

Where a user can put the board is narrower than the housing: a `region` box ((c1_lo, c2_lo), (c1_hi, c2_hi)) for
the centre and a `max_angle` for the tilt. The centre then moves over [max(lo_i, -R_i), min(hi_i, R_i)] (c_i =
mid_i + half_i tanh(b_i)), and phi_max shrinks so that the interval along e2 never empties (R_2 >= the box's
distance from 0); without them the map is the one above.

The objective is the peak bending stress from the support jumps normal to the board, in the plane of the model.
It leaves out the velocity change along the board (tilting the board turns part of a drop's velocity change into
motion along it, which no stress here counts) and everything out of the plane: see
`PlacementResult.summary`, which gives the jumps along the board before and after.
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from tqdm import tqdm

from .._common.checks import as_float, float_dtype
from .._common.reductions import largest
from .._common.checks import Flag, combine
from .._scene.containers import Drop, Placement, Scene, board_ends, check_scene, scene_flags
from .._response.numerics import Numerics
from .._response.objectives import landing_batches, peak_stress
from .._common.compile import filter_jit
from .._common.report import plain
from .optimum import AbstractOptimum
from .._impact.kinematics import body_axes, box_housing_impact, housing_impact

OBJECTIVES = ("mean", "max", "cvar")
LEAVES_OUT = ("motion along the board and out of the plane: the peak bending stress counts only the support jumps "
              "normal to the board, in the plane of the model; the jumps along the board (which push it lengthwise "
              "and shear its joints) and every motion out of the plane count for nothing, so a lower objective "
              "can hide a harder hit along the board")
LEAVES_OUT_BOX = ("motion along the board: the peak bending stress counts only the support jumps normal to the board "
                  "(the box's rigid motion in 3D at each support); the jumps along the board (which push it "
                  "lengthwise and shear its joints) count for nothing, so a lower objective can hide a harder hit "
                  "along the board")


# Without a region or a maximum angle the map is the housing's alone, written as it was before they existed: the
# same program to the last operation (a program with a box that holds the housing gave the same numbers, but its
# gradients turned NaN when compiled without XLA's optimisations, as the tests compile).


def _box(region):
    """The centre's box as a (2, 2) array ((c1_lo, c2_lo), (c1_hi, c2_hi)), m (None stays None: no box)."""
    return None if region is None else jnp.asarray(region, float_dtype())


def _angle_limit(scene: Scene, margin, region=None, max_angle=None):
    H, L = scene.housing.height, scene.board.length
    room = H - 2 * margin
    if region is not None:  # the box's distance from 0 along e2, which the centre must reach
        box = _box(region)
        room = room - 2 * jnp.maximum(0.0, jnp.maximum(box[0, 1], -box[1, 1]))
    limit = jnp.arcsin(jnp.clip(room / L, 0.0, 1.0))
    return limit if max_angle is None else jnp.minimum(limit, max_angle)


def _check_fits(scene: Scene, margin: float, region=None, max_angle=None):
    W, H, L = (float(v) for v in (scene.housing.width, scene.housing.height, scene.board.length))
    if not margin >= 0:
        raise ValueError(f"margin = {margin} m; valid: >= 0")
    if L + 2 * margin > W or 2 * margin >= H:
        raise ValueError(
            f"Board.length + 2 margin = {L + 2 * margin:g} m must be <= Housing.width = {W:g} m and 2 margin < "
            f"Housing.height = {H:g} m for the placement optimiser (board along the width with clearance)"
        )
    if max_angle is not None and not (isinstance(max_angle, (int, float)) and 0 <= max_angle <= math.pi / 2):
        raise ValueError(f"max_angle = {max_angle!r} rad; valid: [0, pi/2]")
    if region is not None:
        box = np.asarray(region, dtype=float)
        if box.shape != (2, 2) or not np.all(np.isfinite(box)) or np.any(box[1] < box[0]):
            raise ValueError(f"region = {np.asarray(region).tolist()}; valid: ((c1_lo, c2_lo), (c1_hi, c2_hi)) in m, "
                             "finite, lo <= hi")
        need = np.maximum(0.0, np.maximum(box[0], -box[1]))
        reach = (W / 2 - margin - L / 2, H / 2 - margin)  # the farthest the centre goes, level (e1) or at all (e2)
        if need[0] > reach[0] or need[1] > reach[1]:
            raise ValueError(f"region = {box.tolist()} m keeps the board's centre {need[0]:g} m along e1 and "
                             f"{need[1]:g} "
                             f"m along e2 from G, but a level board reaches {reach[0]:g} and {reach[1]:g} m inside the "
                             "housing (with the margin)")
    placement = scene.placement
    centre, phi = np.asarray(placement.centre, float), float(placement.angle)
    phi = phi - math.pi if phi > math.pi / 2 else phi + math.pi if phi < -math.pi / 2 else phi
    if region is not None and (np.any(centre < box[0] - 1e-12) or np.any(centre > box[1] + 1e-12)):
        raise ValueError(f"the scene's board centre {(centre * 1e3).tolist()} mm must start inside the region "
                         f"{(box * 1e3).tolist()} mm")
    if max_angle is not None and abs(phi) > max_angle + 1e-12:
        raise ValueError(f"the scene's board angle {math.degrees(phi):g} deg must start within max_angle = "
                         f"{math.degrees(max_angle):g} deg")


def _centre_span(scene: Scene, phi, margin, region):
    """Middle and half-width of the centre's interval along e1 and e2 at angle phi (0 and R without a region)."""
    W, H, L = scene.housing.width, scene.housing.height, scene.board.length
    R1 = W / 2 - margin - L / 2 * jnp.abs(jnp.cos(phi))
    R2 = H / 2 - margin - L / 2 * jnp.abs(jnp.sin(phi))
    if region is None:
        return None, (R1, R2)
    box = _box(region)
    R = jnp.stack([R1, R2])
    lo, hi = jnp.maximum(box[0], -R), jnp.minimum(box[1], R)
    return (lo + hi) / 2, (hi - lo) / 2


def placement_from_unconstrained(scene: Scene, u: Float[Array, "3"], margin=0.0, region=None,
                                 max_angle=None) -> Placement:
    """The feasible placement for unconstrained variables u = (b1, b2, a) (see the module docstring)."""
    phi = _angle_limit(scene, margin, region, max_angle) * jnp.tanh(u[2])
    mid, half = _centre_span(scene, phi, margin, region)
    if mid is None:
        R1, R2 = half
        centre = jnp.stack([jnp.maximum(R1, 0.0) * jnp.tanh(u[0]), jnp.maximum(R2, 0.0) * jnp.tanh(u[1])])
    else:
        centre = mid + jnp.maximum(half, 0.0) * jnp.tanh(u[:2])
    return Placement(centre=centre, angle=phi)


def unconstrained_from_placement(scene: Scene, placement: Placement, margin=0.0, region=None,
                                 max_angle=None) -> Float[Array, "3"]:
    """Inverse of `placement_from_unconstrained` (clipped just inside the feasible set)."""
    limit = _angle_limit(scene, margin, region, max_angle)
    phi = jnp.asarray(placement.angle)
    # A board pointing the other way is the same board with A and B swapped.
    phi = jnp.where(phi > math.pi / 2, phi - math.pi, jnp.where(phi < -math.pi / 2, phi + math.pi, phi))
    clip = 1 - 1e-6
    a = jnp.arctanh(jnp.clip(phi / jnp.maximum(limit, 1e-12), -clip, clip))
    phi = limit * jnp.tanh(a)
    mid, half = _centre_span(scene, phi, margin, region)
    if mid is None:
        R1, R2 = half
        b1 = jnp.arctanh(jnp.clip(placement.centre[0] / jnp.maximum(R1, 1e-12), -clip, clip))
        b2 = jnp.arctanh(jnp.clip(placement.centre[1] / jnp.maximum(R2, 1e-12), -clip, clip))
        return jnp.stack([b1, b2, a])
    b = jnp.arctanh(jnp.clip((placement.centre - mid) / jnp.maximum(half, 1e-12), -clip, clip))
    return jnp.concatenate([b, a[None]])


def risk(values: Float[Array, " n"], objective="mean", alpha=0.9) -> Float[Array, ""]:
    """Aggregate peak stresses over drops: `"mean"`, `"max"` (worst case) or `"cvar"` (mean of the worst
    1 - alpha fraction, with the boundary drop weighted fractionally; alpha = 0 is the mean). `objective` may also
    be its index in `OBJECTIVES` as an integer array: then one compiled program serves every objective."""

    def cvar():
        n = values.shape[0]
        tail = (1.0 - alpha) * n
        weights = jnp.clip(tail - jnp.arange(n), 0.0, 1.0)
        return jnp.sum(weights * jnp.sort(values)[::-1]) / tail

    aggregates = {"mean": lambda: jnp.mean(values), "max": lambda: largest(values), "cvar": cvar}
    if not isinstance(objective, str):  # only the chosen aggregate runs: the others' gradients cannot spoil it
        return jax.lax.switch(objective, [aggregates[name] for name in OBJECTIVES])
    if objective not in aggregates:
        raise ValueError(f"objective = {objective!r}; valid: {', '.join(OBJECTIVES)}")
    return aggregates[objective]()


def _traced_config(objective: str, alpha, numerics, margin=None, region=None, max_angle=None) -> tuple:
    """The optimiser's settings with the objective as an index and alpha, margin, region, max_angle as arrays:
    arguments that `filter_jit` traces, so that every objective, level, clearance and region shares one compiled
    program (a region or a maximum angle, or none, is a program of its own)."""
    dtype = float_dtype()
    config = (jnp.asarray(OBJECTIVES.index(objective)), jnp.asarray(alpha, dtype), numerics)
    if margin is None:
        return config
    return config + (jnp.asarray(margin, dtype), _box(region), None if max_angle is None else
                     jnp.asarray(max_angle, dtype))


def drop_set(scene: Scene, orientations, heights=None, tilts=None) -> Scene:
    """A batch of scenes: every orientation (rad) with every height (m; default the scene's). `tilts` (rad, a box
    housing's; one per orientation) pairs with `orientations` into attitudes."""
    th = _drop_values(orientations, "orientations", "orientation")
    hs = _drop_values(scene.drop.height if heights is None else heights, "heights", "height")
    if tilts is None:
        ti = jnp.broadcast_to(jnp.asarray(scene.drop.tilt, dtype=float_dtype()), th.shape)
    else:
        if not scene.housing.is_box:
            raise ValueError("tilts turn a box housing out of the plane of motion: give Housing.depth (m)")
        ti = _drop_values(tilts, "tilts", "tilt")
        if ti.shape != th.shape:
            raise ValueError(f"tilts pair with orientations (one attitude each): got {ti.shape[0]} tilts for "
                             f"{th.shape[0]} orientations")
    return _drop_grid(scene, th, hs, ti)


def _drop_values(values, name: str, field: str):
    """`drop_set`'s values as a flat float array, or a `ValueError` naming `name` where a concrete one is empty, not
    finite or outside the `Drop` field's range."""
    out = as_float(values, name).reshape(-1)
    if out.shape[0] == 0:
        raise ValueError(f"{name} is empty; valid: at least one value")
    Drop.RANGES[field][0].require(out, name)
    return out


@filter_jit  # one program, not one per operation and field
def _drop_grid(scene: Scene, th, hs, ti) -> Scene:
    TH, HS = jnp.meshgrid(th, hs, indexing="ij")
    TI = jnp.broadcast_to(ti[:, None], TH.shape)
    n = TH.size
    batch = jax.tree_util.tree_map(lambda v: jnp.broadcast_to(v, (n,) + jnp.shape(v)), scene)
    return batch.replace(**{"drop.orientation": TH.reshape(-1), "drop.height": HS.reshape(-1),
                            "drop.tilt": TI.reshape(-1)})


def placement_objective(scene: Scene, drops: Scene, objective="mean", alpha=0.9, numerics=None, margin=0.0,
                        region=None, max_angle=None):
    """f(u) -> risk of the peak stresses (Pa) over `drops` (a batch of scenes, or its `landing_batches`) with the
    board at `placement_from_unconstrained(u)`
    (`margin`, `region`, `max_angle` as there). The peak stress counts the support jumps normal to the board in
    the plane of the model: motion along the board and out of the plane are left out."""
    numerics = Numerics() if numerics is None else numerics
    batches = landing_batches(drops, numerics)

    def f(u):
        placement = placement_from_unconstrained(scene, u, margin, region, max_angle)
        return risk(_placed_peaks(batches, placement.centre, placement.angle, numerics), objective, alpha)

    return f


def _placed_peaks(batches: list[Scene], centre, angle, numerics: Numerics):
    """The peak stresses of the drops in `batches` (`landing_batches`) with the board at (centre, angle)."""
    values = []
    for drops in batches:
        placed = eqx.tree_at(lambda s: (s.placement.centre, s.placement.angle), drops,
                             (jnp.broadcast_to(centre, drops.placement.centre.shape),
                              jnp.broadcast_to(angle, drops.placement.angle.shape)))
        values.append(jax.vmap(lambda s: peak_stress(s, numerics))(placed))
    return jnp.concatenate(values)


class PlacementResult(AbstractOptimum):
    """Outcome of `optimize_placement`.

    - `placement`: the best `Placement` found; `value`: its objective (Pa); `initial_value`: the scene's own.
    - `history`: objective per step of the best start (Pa), shape (steps,); `histories`: every start's.
    - `path`: (c1, c2, phi) per step of the best start, shape (steps + 1, 3).
    - `n_evaluations`: objective evaluations (each with its gradient) over all starts; `n_drops`: drops per
      evaluation.
    - `along_before`, `along_after`: the velocity jumps along the board at its ends (m/s), shape (drops, 2), at
      the scene's placement and at the optimum: what the objective does not count.
    - `region`, `max_angle`: the constraint the optimum kept (m, rad; None: the housing alone).
    """

    placement: Placement
    value: Float[Array, ""]
    initial_value: Float[Array, ""]
    history: Float[Array, " steps"]
    histories: Float[Array, "starts steps"]
    path: Float[Array, "steps1 3"]
    n_evaluations: int = eqx.field(static=True)
    n_drops: int = eqx.field(static=True)
    objective: str = eqx.field(static=True)
    along_before: Float[Array, "drops 2"] | None = None
    along_after: Float[Array, "drops 2"] | None = None
    region: tuple | None = eqx.field(static=True, default=None)
    max_angle: float | None = eqx.field(static=True, default=None)

    def summary(self, scene: Scene | None = None) -> dict:
        """Before (the scene's placement, when given) and after, units in the keys; the constraint kept, what the
        objective leaves out, and the largest jump along the board (over the drops and both ends) before and
        after."""

        def where(p, when):
            return {f"{when}_centre_mm": np.asarray(p.centre) * 1e3, f"{when}_angle_deg": np.degrees(p.angle)}

        out = {"objective": f"{self.objective} peak stress over {self.n_drops} drops"}
        if self.region is not None:
            out["region_centre_box_mm"] = np.asarray(self.region) * 1e3
        if self.max_angle is not None:
            out["max_angle_deg"] = math.degrees(self.max_angle)
        if scene is not None:
            out |= where(scene.placement, "before")
        out |= {"before_objective_MPa": np.asarray(self.initial_value) / 1e6, **where(self.placement, "after"),
                "after_objective_MPa": np.asarray(self.value) / 1e6, "evaluations": self.n_evaluations,
                "objective_leaves_out": LEAVES_OUT_BOX if scene is not None and scene.housing.is_box else LEAVES_OUT}
        if self.along_before is not None:
            out |= {"largest_jump_along_the_board_before_m_per_s": np.max(np.abs(np.asarray(self.along_before))),
                    "largest_jump_along_the_board_after_m_per_s": np.max(np.abs(np.asarray(self.along_after)))}
        return plain(out)


def optimize_placement(
    scene: Scene,
    orientations=None,
    heights=None,
    objective: str = "mean",
    alpha: float = 0.9,
    numerics: Numerics | None = None,
    steps: int = 100,
    optimizer=None,
    starts: int = 4,
    margin: float = 0.0,
    key=None,
    progress: bool = True,
    region=None,
    max_angle: float | None = None,
    tilts=None,
) -> PlacementResult:
    """Place the board where it suffers least over a set of drops.

    **Arguments:**
    - `orientations`: drop orientations (rad); default 7 angles from 15 to 75 degrees. `heights`: drop heights
      (m); default the scene's. `tilts` (rad, a box housing's: one per orientation; default the scene's tilt)
      makes each orientation an attitude in 3D.
    - `objective`: `"mean"`, `"max"` or `"cvar"` (level `alpha`) of the peak stress over the drops.
    - `numerics`: default `Numerics(n_modes=8)`, a converged count for phone-like boards with 0.1-1 ms contacts.
    - `steps`, `optimizer` (default `optax.adam(0.05)` on the unconstrained variables), `starts`: the scene's own
      placement plus `starts - 1` random ones (`key`), optimised together.
    - `margin`: clearance (m) between the board's ends and the housing's edges.
    - `region`: a box ((c1_lo, c2_lo), (c1_hi, c2_hi)) (m, body axes from G) the board's centre stays in;
      `max_angle`: the largest tilt (rad). The scene's placement must satisfy both. Default: the housing alone.

    The objective counts the support jumps normal to the board (for a box housing, the housing's rigid motion in 3D
    at each support); the result holds the jumps along the board (`along_before`, `along_after`), which it leaves
    out.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective = {objective!r}; valid: {', '.join(OBJECTIVES)}")
    if not 0.0 <= alpha < 1.0:
        raise ValueError(f"alpha = {alpha}; valid: [0, 1)")
    if not (isinstance(steps, int) and steps >= 1) or not (isinstance(starts, int) and starts >= 1):
        raise ValueError(f"steps = {steps}, starts = {starts}; both must be ints >= 1")
    _check_fits(scene, margin, region, max_angle)
    numerics = Numerics(n_modes=8) if numerics is None else numerics
    if orientations is None:
        orientations = np.radians(np.linspace(15.0, 75.0, 7))
    check_scene(scene)
    drops = drop_set(scene, orientations, heights, tilts)
    n_drops = int(drops.drop.orientation.shape[0])
    _check_drops(drops, numerics)
    optimizer = _default_optimizer() if optimizer is None else optimizer
    config = _traced_config(objective, alpha, numerics, margin, region, max_angle)
    # The steps between the compiled ones are small programs too: JAX run eagerly compiles one per operation.
    U, state, best_u, best_v = _start(scene, key, starts, optimizer, config)
    history, path_u = [], [U]
    batches = landing_batches(drops, numerics)  # the objective's programs then hold each drop's own path only
    for _ in tqdm(range(steps), desc="optimize_placement", disable=not progress, leave=False):
        U_new, state, values = _step(U, state, scene, batches, optimizer, config)
        best_u, best_v = _keep_best(U, values, best_u, best_v)
        history.append(values)
        U = U_new
        path_u.append(U)
    # The last variables' values from the step's own program (its update unused): no second compilation.
    best_u, best_v = _keep_best(U, _step(U, state, scene, batches, optimizer, config)[2], best_u, best_v)
    placement, value, initial, histories, winners, path = _finish(scene, best_u, best_v, history, path_u, config)
    along_before, along_after = _along_board_jumps(drops, jnp.stack([_params(scene.placement), _params(placement)]),
                                                   numerics.law)
    return PlacementResult(
        placement=placement,
        value=value,
        initial_value=initial,
        history=winners,
        histories=histories,
        path=path,
        n_evaluations=starts * (steps + 1),
        n_drops=n_drops,
        objective=objective,
        along_before=along_before,
        along_after=along_after,
        region=None if region is None else tuple(map(tuple, np.asarray(region, float).tolist())),
        max_angle=None if max_angle is None else float(max_angle),
    )


@filter_jit
def _along_board_jumps(drops: Scene, params, law: str):
    """The velocity jumps along the board at its ends A and B (m/s, (drops, 2)) for each placement (c1, c2, phi)
    of `params`: the motion the objective leaves out."""

    def one(placement, s):
        s = eqx.tree_at(lambda s: (s.placement.centre, s.placement.angle), s, (placement[:2], placement[2]))
        if s.housing.is_box:  # the rigid motion in 3D at the ends, at their depth
            hit = box_housing_impact(s, law=law)
            ends = board_ends(s.placement, s.board.length)
            depth = jnp.broadcast_to(s.placement.depth_offset, ends.shape[:-1])[..., None]
            dv = hit.body_point_velocity_jump(jnp.concatenate([ends, depth], axis=-1))
            c, si = jnp.cos(placement[2]), jnp.sin(placement[2])
            return dv @ (hit.attitude @ jnp.stack([c, si, jnp.zeros_like(c)]))
        hit = housing_impact(s, law=law)
        dv = hit.point_velocity_jump(s.drop.orientation, board_ends(s.placement, s.board.length))
        e1, e2 = body_axes(s.drop.orientation)
        along = jnp.cos(placement[2]) * e1 + jnp.sin(placement[2]) * e2  # the board's direction, ground frame
        return dv @ along

    return [jax.vmap(lambda s: one(p, s))(drops) for p in params]


@filter_jit
def _start(scene, key, starts: int, optimizer, config):
    """The starts' unconstrained variables (the scene's placement first), the optimiser's state, and the best so
    far (none yet)."""
    bounds = config[3:]  # margin, region, max_angle
    key = jax.random.PRNGKey(0) if key is None else key
    u0 = unconstrained_from_placement(scene, scene.placement, *bounds)
    others = jax.random.uniform(key, (starts - 1, 3), minval=-1.5, maxval=1.5)
    U = jnp.concatenate([u0[None], others], axis=0)
    return U, jax.vmap(optimizer.init)(U), U, jnp.full((starts,), jnp.inf, u0.dtype)


@filter_jit
def _keep_best(U, values, best_u, best_v):
    improved = values < best_v
    return jnp.where(improved[:, None], U, best_u), jnp.where(improved, values, best_v)


@filter_jit
def _finish(scene, best_u, best_v, histories, path_u, config):
    """`PlacementResult`'s arrays from the steps' values and variables (lists): the winning start's placement and
    value, the first value, every start's history (starts, steps), the winner's, and the winner's path."""
    bounds = config[3:]  # margin, region, max_angle
    winner = jnp.argmin(best_v)
    to_params = jax.vmap(lambda u: _params(placement_from_unconstrained(scene, u, *bounds)))
    path = to_params(jnp.stack([u[winner] for u in path_u]))
    histories = jnp.stack(histories, axis=1)
    placement = placement_from_unconstrained(scene, best_u[winner], *bounds)
    return placement, best_v[winner], histories[0, 0], histories, histories[winner], path




@filter_jit
def _drop_flags(drops: Scene, law: str):
    impact = box_housing_impact if drops.housing.is_box else housing_impact
    return jax.vmap(lambda s: combine(scene_flags(s), impact(s, law=law).flags))(drops)


def _check_drops(drops: Scene, numerics: Numerics) -> None:
    """Every drop of the set must be inside the model: a flagged drop would make the objective NaN (and its
    gradient zero), so the optimiser would return a non-answer. Name the drops and the reasons instead."""
    flags = np.asarray(_drop_flags(drops, numerics.law))
    bad = np.flatnonzero(flags)
    if bad.size:
        th, h, ti = (np.asarray(v) for v in (drops.drop.orientation, drops.drop.height, drops.drop.tilt))
        listed = "; ".join(f"orientation {np.degrees(th[i]):.4g} deg"
                           + (f", tilt {np.degrees(ti[i]):.4g} deg" if ti[i] else "") + f", height {h[i]:.4g} m: "
                           f"{', '.join(Flag.describe(flags[i]))}" for i in bad[:5])
        raise ValueError(f"optimize_placement: {bad.size} of {flags.size} drops are outside the model ({listed}); "
                         "leave them out of orientations/heights (flat landings are multiples of 90 deg with spin)")


@functools.cache
def _default_optimizer():
    # One object for every call, so the compiled step is reused; optax is imported when used (it takes a second).
    import optax

    return optax.adam(0.05)


@filter_jit
def _step(U, state, scene, drops, optimizer, config):
    f = placement_objective(scene, drops, *config)
    values, grads = jax.vmap(jax.value_and_grad(f))(U)
    updates, state = jax.vmap(optimizer.update)(grads, state, U)
    import optax

    return optax.apply_updates(U, updates), state, values


def _params(p: Placement):
    return jnp.stack([p.centre[0], p.centre[1], p.angle])


def placement_landscape(scene: Scene, result: PlacementResult, orientations=None, heights=None, alpha=0.9,
                        numerics=None, margin=0.0, n=(61, 31), region=None, tilts=None):
    """The objective (Pa) over board-centre positions (c1, c2) at the optimum's angle: (c1 grid, c2 grid, values
    of shape (n1, n2)) over where the centre may go (inside the housing, and the `region` box; default the
    result's). Where the centre has almost no room along one axis (under 10 % of the other's) that axis has one
    point, its middle."""
    numerics = Numerics(n_modes=8) if numerics is None else numerics
    if orientations is None:
        orientations = np.radians(np.linspace(15.0, 75.0, 7))
    drops = drop_set(scene, orientations, heights, tilts)
    phi = result.placement.angle
    W, H, L, angle = (float(v) for v in (scene.housing.width, scene.housing.height, scene.board.length, phi))
    R1 = W / 2 - margin - L / 2 * abs(math.cos(angle))
    R2 = H / 2 - margin - L / 2 * abs(math.sin(angle))
    region = result.region if region is None else region
    box = None if region is None else np.asarray(region, float)
    lo = np.array([-R1, -R2]) if box is None else np.maximum(box[0], [-R1, -R2])
    hi = np.array([R1, R2]) if box is None else np.minimum(box[1], [R1, R2])
    thin = hi - lo < 0.1 * np.max(hi - lo)
    c1 = np.linspace(lo[0], hi[0], n[0]) if not thin[0] else np.array([(lo[0] + hi[0]) / 2])
    c2 = np.linspace(lo[1], hi[1], n[1]) if not thin[1] else np.array([(lo[1] + hi[1]) / 2])
    C1, C2 = np.meshgrid(c1, c2, indexing="ij")
    centres = jnp.asarray(np.stack([C1.ravel(), C2.ravel()], axis=-1), float_dtype())
    config = _traced_config(result.objective, alpha, numerics)
    values = _landscape(centres, phi, landing_batches(drops, config[2]), config)
    return c1, c2, np.asarray(values).reshape(C1.shape)


@filter_jit
def _landscape(centres, phi, batches, config):
    objective, alpha, numerics = config

    def one(centre):
        return risk(_placed_peaks(batches, centre, phi, numerics), objective, alpha)

    return jax.lax.map(one, centres, batch_size=16)
