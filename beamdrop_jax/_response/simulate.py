"""From a scene (or a board and its support motion) to peak stress, strain and deflection.

`simulate` validates eagerly, then runs one compiled function: housing impact (and, with `max_impacts` > 1, the
clattering impacts that follow) -> support jumps -> support motion -> modal response (closed form or diffrax) ->
peaks and a convergence check. The board's domain decides the peak search: a line (`line.py`) or a surface
(`surface.py`)."""


import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._board.base import AbstractBoard
from .._common.checks import Flag, combine, flag_if, is_concrete, is_pulse, raise_if_flagged
from .._common.compile import filter_jit
from .._impact.clatter import MAX_ADVANCES, Ending, Impacts, impact_sequence
from .._impact.kinematics import housing_impact, plane_drop
from .._impact.motion import AbstractMotion, PulseTrain
from .._scene.containers import Scene, _largest, check_scene, require_single, scene_flags
from .landing_path import FIRST_LANDING_STEPS, compliant_branch, compliant_weight, first_jumps, landing_motion
from .line import _respond_line
from .numerics import Numerics
from .results import Response
from .setup import _gauge_points, _raise_if_window, support_motion
from .surface import _eigen_of, _respond_plate, kept_modes, plate_time_grid


def _respond(board, motion, numerics: Numerics, flags, gauges=None, modes=None) -> Response:
    """The board's response to its supports' motion; the peak search follows the board's domain. `modes`: a
    plate's `kept_modes`, or None."""
    if board.SURFACE:
        return _respond_plate(board, motion, numerics, flags, gauges, modes)
    if gauges is not None:
        raise ValueError("gauges are read on plates (bd.Plate); a beam's strain along x is in bd.response_fields")
    return _respond_line(board, motion, numerics, flags)


@filter_jit
def _board_response_jit(board, motion, numerics, gauges, modes=None):
    return _respond(board, motion, numerics, jnp.int32(0), gauges, modes)


def board_response(board: AbstractBoard, motion, numerics: Numerics | None = None, gauges=None) -> Response:
    """Peak response of a board (`Board` or `Plate`) to a support motion: `Impulse`, `HalfSine`, `PulseTrain`
    (closed form only) or `Record` (needs `Numerics(method="diffrax")`). On a plate, `gauges=((x, y), ...)` (m)
    reads strain gauges there (`Response.gauges`). Jit- and vmap-able."""
    if not isinstance(board, AbstractBoard):  # input check: the interface, not a board type
        raise TypeError(f"board must be a bd.Board or a bd.Plate, got {type(board).__name__}")
    numerics = Numerics() if numerics is None else numerics
    if not isinstance(motion, AbstractMotion):
        raise TypeError(f"motion must be an Impulse, HalfSine, PulseTrain or Record, got {type(motion).__name__}")
    if numerics.method not in motion.METHODS:
        methods = " or ".join(f'"{m}"' for m in motion.METHODS)
        extra = " (it has no closed form)" if "closed_form" not in motion.METHODS else ""
        raise ValueError(f"a {type(motion).__name__} support motion needs Numerics(method={methods}){extra}")
    board.check_gauges(points := _gauge_points(gauges))
    modes = kept_modes(board)
    if modes is not None and is_concrete(motion):
        numerics = plate_time_grid(numerics, modes, motion.window_forcing())
    response = _board_response_jit(board, motion, numerics, points, modes)
    if is_concrete(board, motion, response.flags) and int(response.flags):
        board.__check_init__()
        board.raise_if_outside_theory(response.flags, "board_response")
        _raise_if_window(board, motion, numerics, response.flags, "board_response", with_check=True)
        raise_if_flagged(response.flags & ~Flag.SOLVER_FAILED, "board_response")
    return response


def drop_motion(scene: Scene, numerics: Numerics | None = None):
    """The supports' motion in a drop: `(motion, impacts, first, flags)` with `motion` a `HalfSine` (one impact)
    or a `PulseTrain` (`Numerics.max_impacts` > 1), `impacts` the `Impacts`, `first` the first `HousingImpact`
    and `flags` the impacts' `Flag` mask. A tilted box's first impact is its 3D one (`drop_jumps`)."""
    return _drop_motion(scene, Numerics() if numerics is None else numerics)[:4]


def _drop_motion(scene: Scene, numerics: Numerics):
    impacts, first = impact_sequence(scene, numerics.max_impacts, numerics.rest_speed, numerics.law)
    jumps, box = first_jumps(scene, numerics, impacts.support_jumps[0])
    flags = impacts.flags
    if box is not None:
        out = ~plane_drop(scene)
        box_flags = box.flags
        if scene.contact.model != "rigid" and numerics.max_impacts == 1:
            # An edge struck unequally (motion out of the plane at tilt 0) is the edge's as one contact or the
            # compliant landing's (`edge_weight`), given a contact duration.
            box_flags = jnp.where(is_pulse(scene.contact.duration), box_flags & ~Flag.FLAT_LANDING_WITH_MOTION, box_flags)
        flags = combine(flags, jnp.where(out, box_flags, 0), flag_if(out & (numerics.max_impacts > 1),
                                                                     Flag.OUT_OF_PLANE))
    if numerics.max_impacts == 1:
        motion = support_motion(scene, jumps)
    else:
        plane = impacts.support_jumps
        motion = PulseTrain(impacts.t, plane[:, 0], plane[:, 1], scene.contact.duration)
    return motion, impacts, first, flags, box


def landing_drive(scene: Scene, numerics: Numerics, landing: str = "rigid", modal=None):
    """What the board sees in a drop, by the landing path (`landing`, static): `(motion, numerics, impacts, first,
    flags, weight)`. `"rigid"`: `drop_motion`'s; `"compliant"`: the compliant landing's supports' acceleration,
    blended with the rigid law's by `compliant_weight` (`weight`): the landing solved with diffrax, the board's
    response to its samples in closed form (`SampledModes`). `modal`: the board's solved modes where the caller
    has them (a plate's `kept_modes`), for its fundamental period."""
    motion, impacts, hit, flags, box = _drop_motion(scene, numerics)
    if landing == "rigid":
        return motion, numerics, impacts, hit, flags, jnp.zeros_like(scene.contact.duration), box
    weight = compliant_weight(scene, numerics, hit, modal)
    blended, path = landing_motion(scene, numerics, weight, motion.first_jumps(), modal=modal)
    return (blended, dataclasses.replace(numerics, method="diffrax"), impacts, hit, combine(flags, path.flags),
            weight, box)


def _simulate(scene: Scene, numerics: Numerics, gauges=None, landing: str = "rigid", modes=None) -> Response:
    """One drop. `landing` (static): `"rigid"` or `"compliant"` (`landing_drive`), or `"either"`: both, the
    answer picked by the compliant landing's weight (traced scenes). `modes`: the board's `kept_modes`, or None."""
    modal = None if modes is None else _eigen_of(scene.board, modes)[0]

    def respond(drop, kind):
        motion, used, impacts, hit, flags, weight, box = landing_drive(drop, numerics, kind, modal)
        response = _respond(scene.board, motion, used, combine(scene_flags(scene), flags), gauges, modes)
        return response, (impacts, hit, weight, box)

    response, (impacts, hit, weight, box) = respond(scene, "rigid" if landing == "either" else landing)
    if landing == "either":
        weight = compliant_weight(scene, numerics, hit, modal)
        compliant, _ = respond(compliant_branch(scene, weight), "compliant")
        response = jax.tree_util.tree_map(lambda a, b: jnp.where(weight > 0, a, b), compliant, response)
    elif landing == "rigid" and scene.contact.model == "auto" and numerics.max_impacts == 1:
        # The rigid law's answer, and whether the drop wants the landing instead (`simulate` then runs that).
        weight = compliant_weight(scene, numerics, hit, modal)
    return eqx.tree_at(
        lambda r: (r.impulse, r.housing, r.impacts, r.landing_weight, r.box), response,
        (hit.impact, hit, impacts, weight, box), is_leaf=lambda x: x is None
    )


def _landing_kind(scene: Scene, numerics: Numerics) -> str:
    """Which path `_simulate` takes first (`landing`): a concrete scene on "auto" the rigid law's, whose response
    says (`landing_weight`) whether the drop wants the landing; a traced one both."""
    if scene.contact.model == "rigid" or numerics.max_impacts > 1:
        return "rigid"
    if scene.contact.model == "compliant":
        return "compliant"
    return "rigid" if is_concrete(scene) else "either"


_simulate_jit = filter_jit(_simulate)


def _raise_eagerly(scene: Scene, numerics: Numerics, flags, impacts: Impacts | None, what: str,
                   with_check: bool = True):
    """The compiled run found a problem: the eager checks name the field and its valid range."""
    check_scene(scene)
    housing_impact(scene, law=numerics.law)
    scene.board.raise_if_outside_theory(flags, what)
    _raise_if_window(scene.board, drop_motion(scene, numerics)[0], numerics, flags, what, with_check)
    if impacts is not None and int(impacts.ending) == Ending.SEARCH_GAVE_UP:
        n = int(impacts.count)
        raise ValueError(
            f"{what}: after impact {n} (t = {float(impacts.t[n - 1]) * 1e3:.4g} ms) the search for the next impact "
            f"gave up after {MAX_ADVANCES} conservative steps (Flag.SOLVER_FAILED): the housing spins so fast "
            f"(Drop.spin = {float(scene.drop.spin):.4g} rad/s) that free flight needs finer steps. Use "
            f"Numerics(max_impacts={n}) for the response to the impacts before it."
        )
    if impacts is not None and int(flags) & Flag.PIVOTING_CONTACT:
        n = int(impacts.count)
        raise ValueError(
            f"{what}: after impact {n} (t = {float(impacts.t[n - 1]) * 1e3:.4g} ms) a corner stays on the ground "
            f"(next approach speed {float(impacts.approach_speed[n]):.3g} m/s < Numerics.rest_speed = "
            f"{numerics.rest_speed:g} m/s) while the housing still turns: a pivot phase that free flight does not "
            f"describe (Flag.PIVOTING_CONTACT). Use Numerics(max_impacts={n}) for the response to the impacts before "
            "it; bd.impact_sequence(scene) shows the sequence."
        )
    raise_if_flagged(flags & ~Flag.SOLVER_FAILED, what)


def _raise_if_out_of_plane(scene: Scene, numerics: Numerics) -> None:
    """A box asked to clatter out of the plane (tilted, or moving out of the plane), which clattering, following
    the plane section only, cannot (`Flag.OUT_OF_PLANE` under jit); a box landing on an edge (tilt 0) with motion
    out of the plane under the rigid law, whose vertices strike together but unequally
    (`Flag.FLAT_LANDING_WITH_MOTION` under jit)."""
    if not scene.housing.is_box or not is_concrete(scene.drop):
        return
    d = scene.drop
    edge = (np.asarray(d.tilt) == 0) & ~np.asarray(d.in_plane())
    if np.any(edge) and (scene.contact.model == "rigid" or numerics.max_impacts > 1):
        raise ValueError(f"Drop.tilt = 0 with Drop.side_speed = {_largest(d.side_speed):g} m/s, Drop.spin_x = "
                         f"{_largest(d.spin_x):g} and Drop.spin_y = {_largest(d.spin_y):g} rad/s: the box lands on "
                         "an edge whose two vertices strike together but unequally, outside the single-vertex rigid "
                         "law; valid: Contact(model='auto') or 'compliant' (the compliant landing; max_impacts = 1), "
                         "a tilt other than 0, or motion in the plane")
    if numerics.max_impacts == 1 or np.all(np.asarray(plane_drop(scene))):
        return
    raise ValueError(f"Numerics.max_impacts = {numerics.max_impacts} with Drop.tilt = {_largest(d.tilt):g} rad, "
                     f"Drop.side_speed = {_largest(d.side_speed):g} m/s, Drop.spin_x = {_largest(d.spin_x):g} and "
                     f"Drop.spin_y = {_largest(d.spin_y):g} rad/s: clattering follows the plane section only; valid: "
                     "max_impacts = 1 for a drop out of the plane (or Contact(model='compliant'), whose landing "
                     "includes every strike in the board's peak window), or tilt = 0 with motion in the plane")


_FROM_REST_ZERO = ("spin", "horizontal_speed", "side_speed", "spin_x", "spin_y")


def _raise_if_not_from_rest(scene: Scene, numerics: Numerics) -> None:
    """`Numerics.from_rest` asked of a drop with spin or horizontal speed (NaN and `Flag.SOLVER_FAILED` under jit)."""
    if not (numerics.from_rest and scene.housing.is_box and is_concrete(scene.drop)):
        return
    for name in _FROM_REST_ZERO:
        value = np.asarray(getattr(scene.drop, name))
        if np.any(value != 0):
            raise ValueError(f"Numerics.from_rest = True with Drop.{name} = {_largest(value):g}: the closed-form 3D "
                             f"law holds for drops from rest only; valid: Drop.{' = 0, Drop.'.join(_FROM_REST_ZERO)} "
                             "= 0, or Numerics.from_rest = False")


def _compliant_eagerly(scene: Scene, numerics: Numerics, points, modes) -> Response:
    """A concrete drop on the compliant landing's path: solved first with a step limit of `FIRST_LANDING_STEPS`
    (a smaller buffer), again with `numerics.landing_steps` where that is not enough; the same numbers."""
    first = dataclasses.replace(numerics, landing_steps=min(FIRST_LANDING_STEPS, numerics.landing_steps))
    response = _simulate_jit(scene, first, points, landing="compliant", modes=modes)
    if first.landing_steps < numerics.landing_steps and int(response.flags) & Flag.SOLVER_FAILED:
        response = _simulate_jit(scene, numerics, points, landing="compliant", modes=modes)
    return response


def simulate(scene: Scene, numerics: Numerics | None = None, gauges=None) -> Response:
    """Simulate one drop: the housing's corner impact (and with `Numerics(max_impacts=K)` the clattering impacts
    after it), the board's support jumps, its vibration, and the peak bending stress, strain and deflection, where
    and when.

    Concrete scenes are validated eagerly (`ValueError` naming the field and range); under `jit`/`vmap` problems
    come back in `Response.flags` with NaN peaks. With a `Plate` board, `gauges=((x, y), ...)` (m) reads strain
    gauges (`Response.gauges`).
    """
    numerics = Numerics() if numerics is None else numerics
    require_single(scene, "simulate")
    scene.board.check_gauges(points := _gauge_points(gauges))
    if scene.contact.model == "compliant" and numerics.max_impacts > 1:
        raise ValueError(f"Numerics.max_impacts = {numerics.max_impacts} (--max-impacts) follows rigid strikes, and "
                         'Contact.model = "compliant" (--contact-model compliant) follows every strike in the peak '
                         'window itself; valid: max_impacts = 1 with "compliant", or model "rigid" or "auto" with '
                         "max_impacts > 1")
    _raise_if_out_of_plane(scene, numerics)
    _raise_if_not_from_rest(scene, numerics)
    kind = _landing_kind(scene, numerics)
    modes = kept_modes(scene.board)
    numerics = plate_time_grid(numerics, modes, scene.contact.duration)
    if kind == "compliant" and is_concrete(scene):
        response = _compliant_eagerly(scene, numerics, points, modes)
    else:
        response = _simulate_jit(scene, numerics, points, landing=kind, modes=modes)
    if kind == "rigid" and scene.contact.model == "auto" and numerics.max_impacts == 1:
        wanted = response.landing_weight
        if not is_concrete(wanted):  # a concrete scene closed over by a user's jit
            response = _simulate_jit(scene, numerics, points, landing="either", modes=modes)
        elif float(wanted) > 0:  # strikes overlap: the compliant landing
            response = _compliant_eagerly(scene, numerics, points, modes)
    if is_concrete(scene, response.flags) and int(response.flags):
        _raise_eagerly(scene, numerics, response.flags, response.impacts, "simulate")
    return response
