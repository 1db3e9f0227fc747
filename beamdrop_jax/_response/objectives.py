"""Differentiable peak objectives of a drop: `peak_stress`, `peak_strain`, `peak_deflection`, each one compiled program that computes the value and its gradient together (a custom JVP), for optimisers and sensitivities."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._common.checks import Flag, combine, flag_if, float_dtype, is_concrete
from .._common.compile import filter_jit, quick_programs
from .._scene.containers import Scene, require_single, scene_flags
from .._board.plate_checks import plate_grid_deflection, response_flags
from .line import _membrane, _search
from .numerics import Numerics
from .setup import _setup
from .landing_path import compliant_branch, compliant_weight
from .simulate import _raise_eagerly, drop_motion, landing_drive
from .surface import _plate_searches, plate_numerics


QUANTITIES = ("stress", "strain", "deflection")


@filter_jit
def _scene_peaks(scene: Scene, numerics: Numerics, quantities: tuple[str, ...], grid_deflection: bool = False,
                 motion_and_flags=None, landing: str = "rigid"):
    """Peaks of the requested quantities (stress, strain, deflection) sharing one modal solution and one batched
    search; returns (values (len(quantities),), flags). `grid_deflection` takes the deflection peak from the grid
    without refinement (Monte-Carlo's cheap option; it undershoots by the grid's resolution). `motion_and_flags`:
    the drop's `(motion, impact flags)` from `drop_motion` when computed already. `landing` (static): the path of
    `landing_drive`, or `"either"`: both, the answer picked by the compliant landing's weight."""
    if landing == "either":
        weight = compliant_weight(scene, numerics, drop_motion(scene, numerics)[2])
        rigid, compliant = (_scene_peaks(drop, numerics, quantities, grid_deflection, landing=kind)
                            for drop, kind in ((scene, "rigid"), (compliant_branch(scene, weight), "compliant")))
        return jax.tree_util.tree_map(lambda a, b: jnp.where(weight > 0, a, b), compliant, rigid)
    board = scene.board
    if motion_and_flags is None:
        motion, numerics, _, _, impact_flags, _, _ = landing_drive(scene, numerics, landing)
    else:
        motion, impact_flags = motion_and_flags
    if board.SURFACE:
        numerics = plate_numerics(board, numerics)
    S = _setup(board, motion, numerics, with_check=False)
    mask = (S.k <= S.used).astype(float_dtype())
    if board.SURFACE:
        values = _plate_searches(S, board, numerics, S.modes, quantities, mask).value
        deflection = (values[quantities.index("deflection")] if "deflection" in quantities
                      else plate_grid_deflection(S.modes, S.Q, mask))
        flags = combine(scene_flags(scene), impact_flags, board.flags(), S.flags, flag_if(S.failed, Flag.SOLVER_FAILED),
                        flag_if(~jnp.all(jnp.isfinite(values)), Flag.NONFINITE_RESULT), response_flags(board, deflection))
        return jnp.where(flags != 0, jnp.nan, values), flags
    kinds = sorted({"deflection" if q == "deflection" else "curvature" for q in quantities})
    rows = jnp.stack([(jnp.ones_like(S.curvature) if k == "deflection" else S.curvature) * mask for k in kinds])
    is_curvature = tuple(k == "curvature" for k in kinds)
    refine = tuple(numerics.refine and not (grid_deflection and k == "deflection") for k in kinds)
    peaks = _search(S, board, numerics, rows, _membrane(board, numerics, rows, is_curvature), curvature=is_curvature,
                    refine=refine).value
    scale = {"stress": board.youngs_modulus * board.thickness / 2, "strain": board.thickness / 2, "deflection": 1.0}
    values = jnp.stack([scale[q] * peaks[kinds.index("deflection" if q == "deflection" else "curvature")]
                        for q in quantities])
    flags = combine(scene_flags(scene), impact_flags, board.flags(), S.flags, flag_if(S.failed, Flag.SOLVER_FAILED),
                    flag_if(~jnp.all(jnp.isfinite(values)), Flag.NONFINITE_RESULT))
    return jnp.where(flags != 0, jnp.nan, values), flags


def _scene_peak(scene: Scene, numerics: Numerics, quantity: str, landing: str):
    floats, rest = eqx.partition(scene, eqx.is_inexact_array)
    return _peak_of_floats(floats, rest, numerics, quantity, landing)


def _peak_value(scene: Scene, numerics: Numerics, quantity: str, landing: str):
    values, flags = _scene_peaks(scene, numerics, (quantity,), landing=landing)
    return values[0], flags


@filter_jit
def _landing_weight(scene: Scene, numerics: Numerics):
    return compliant_weight(scene, numerics, drop_motion(scene, numerics)[2])


@filter_jit
def _landing_weights(drops: Scene, numerics: Numerics):
    return jax.vmap(lambda s: compliant_weight(s, numerics, drop_motion(s, numerics)[2]))(drops)


def landing_batches(drops: Scene, numerics: Numerics) -> list[Scene]:
    """A concrete batch of drops (every leaf batched along its first axis) split by landing path: the drops whose
    strikes do not overlap on `Contact.model` "rigid" (the same numbers, without the landing's program), the rest
    as they are (a traced objective takes both paths for them). Empty parts are left out; a traced batch, or one
    not on "auto", comes back whole, and a list of batches as it is. The objectives' risks do not depend on the
    drops' order."""
    if isinstance(drops, list):
        return drops
    if drops.contact.model != "auto" or numerics.max_impacts > 1 or not is_concrete(drops):
        return [drops]
    weights = np.asarray(_landing_weights(drops, numerics))
    rigid, landing = np.flatnonzero(weights == 0), np.flatnonzero(weights > 0)
    if not landing.size:
        return [eqx.tree_at(lambda s: s.contact, drops, drops.contact.with_model("rigid"))]
    take = lambda idx: jax.tree_util.tree_map(lambda v: v[idx], drops)  # noqa: E731
    parts = [take(landing)]
    if rigid.size:
        part = take(rigid)
        parts.insert(0, eqx.tree_at(lambda s: s.contact, part, part.contact.with_model("rigid")))
    return parts


def objective_landing(scene: Scene, numerics: Numerics) -> str:
    """The landing path (`landing_drive`) of a drop's objective, as `simulate` chooses it: on `"auto"` a concrete
    scene's own (the compliant landing where its strikes overlap: `compliant_weight` > 0), both (`"either"`) for a
    traced one."""
    if scene.contact.model == "rigid" or numerics.max_impacts > 1:
        return "rigid"
    if scene.contact.model == "compliant":
        return "compliant"
    weight = _landing_weight(scene, numerics) if is_concrete(scene) else None
    if weight is None or not is_concrete(weight):  # traced, or a concrete scene closed over by a user's jit
        return "either"
    return "compliant" if float(weight) > 0 else "rigid"


# The derivative of a peak comes from one program that computes the value and its gradient together. Under an eager
# `jax.grad` that program runs at the top level, so it compiles with the package's compile options (a first
# `jax.grad(peak_stress)` 3.7 -> 2.6 s); JAX's own linearisation would stage it into the gradient's programs, where
# no options are allowed. The gradient is taken with respect to the fields whose tangents are not zero (symbolic
# zeros), so an objective of a few fields differentiates only those. The rule is written in JAX, so forward mode,
# `jit` and `vmap` work; a forward-mode derivative costs one reverse-mode gradient.
@functools.partial(jax.custom_jvp, nondiff_argnums=(1, 2, 3, 4))
def _peak_of_floats(floats, rest, numerics: Numerics, quantity: str, landing: str):
    return _peak_value(eqx.combine(floats, rest), numerics, quantity, landing)


@filter_jit
def _peak_and_gradient(moving, fixed, numerics: Numerics, quantity: str, landing: str):
    return jax.value_and_grad(lambda m: _peak_value(eqx.combine(m, fixed), numerics, quantity, landing),
                              has_aux=True)(moving)


@functools.partial(_peak_of_floats.defjvp, symbolic_zeros=True)
def _peak_jvp(rest, numerics, quantity, landing, primals, tangents):
    zero = jax.custom_derivatives.SymbolicZero
    is_moving = jax.tree_util.tree_map(lambda t: not isinstance(t, zero), tangents[0],
                                       is_leaf=lambda t: isinstance(t, zero))
    moving, fixed = eqx.partition(primals[0], is_moving)
    if landing == "either" and is_concrete(primals[0]):
        # An eager jax.grad: the rule sees the scene's values, so it differentiates the drop's own landing path.
        landing = objective_landing(eqx.combine(primals[0], rest), numerics)
    # An eager derivative runs this program on its own, compiled for latency (`quick_programs`: a first
    # `jax.grad(peak_stress)` of the default scene 4.1 -> 2.7 s; later eager calls take as long, their Python
    # dominates). Under a trace (a user's `jit`, `vmap`, an optimiser's step) it is staged into that program.
    with quick_programs(is_concrete(primals[0])):
        (value, flags), gradient = _peak_and_gradient(moving, eqx.combine(fixed, rest), numerics, quantity, landing)
    moving_tangents = eqx.filter(tangents[0], is_moving, is_leaf=lambda t: isinstance(t, zero))
    leaves = jax.tree_util.tree_leaves
    slope = sum((jnp.vdot(g, t) for g, t in zip(leaves(gradient), leaves(moving_tangents))), jnp.zeros_like(value))
    return (value, flags), (slope, np.zeros(np.shape(flags), jax.dtypes.float0))


def _peak(scene: Scene, numerics: Numerics | None, quantity: str):
    numerics = Numerics() if numerics is None else numerics
    require_single(scene, f"peak_{quantity}")
    value, flags = _scene_peak(scene, numerics, quantity, objective_landing(scene, numerics))
    if is_concrete(scene, flags) and int(flags):
        clatter = int(flags) & (Flag.PIVOTING_CONTACT | Flag.SOLVER_FAILED) and numerics.max_impacts > 1
        impacts = drop_motion(scene, numerics)[1] if clatter else None
        _raise_eagerly(scene, numerics, flags, impacts, f"peak_{quantity}", with_check=False)
    return value


def peak_stress(scene: Scene, numerics: Numerics | None = None) -> Float[Array, ""]:
    """Peak bending stress (Pa) of a drop: a scalar, differentiable with respect to every float field of scene.

    Equals `simulate(scene, numerics).peak.stress` but computes only that peak (no deflection search, no mode
    check), so gradients and optimisers pay for nothing else; like `simulate` it follows `Contact.model` (on
    `"auto"` the compliant landing where strikes overlap: a concrete scene takes its own path, a traced one both).
    The gradient is the exact gradient of the piece the scene is on (lowest corner, Routh mode), taken at the
    maximiser (envelope theorem); through the compliant landing it is that of the sampled drive (within 1 % of
    differences in the orientation and the board's position). At `Drop.height` = 0 the
    derivative with respect to the height is infinite (the impact speed is sqrt(2 g h)); everywhere else in the
    valid domain gradients are finite. Forward mode (`jax.jvp`) gives the same derivative. Second derivatives
    (`jax.hessian`) leave out how the maximiser moves, so they are not the peak's curvature. An eager `jax.grad`
    compiles its program for latency (`quick_programs`); inside your own `jit` it compiles with your settings."""
    return _peak(scene, numerics, "stress")


def peak_strain(scene: Scene, numerics: Numerics | None = None) -> Float[Array, ""]:
    """Peak bending strain (-) of a drop; differentiable like `peak_stress`."""
    return _peak(scene, numerics, "strain")


def peak_deflection(scene: Scene, numerics: Numerics | None = None) -> Float[Array, ""]:
    """Peak deflection relative to the chord AB (m) of a drop; differentiable like `peak_stress`."""
    return _peak(scene, numerics, "deflection")
