"""The scene: housing, board, where the board sits, how the device lands, and the ground contact.

Every physical number is a JAX array field, so `jax.grad` reaches it and a batch of scenes can be `vmap`ped. Each
class lists its fields' valid ranges in `RANGES` (one table used by the constructors, `Scene.replace`, the scene
files and `scene_flags`). Construction checks concrete values eagerly (`ValueError` naming the field, its value and
the valid range; a bool or a string where a number is meant is an error, never coerced); traced values are checked
by `scene_flags`, which results carry.
"""

import difflib
import functools
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._board.beam import Board
from .._common.fields import VECTOR_FIELDS, check_ranges, init_fields, positive, range_flags
from .._common.compile import filter_jit
from .._common.checks import (DEG, GRAVITY, IMPULSE_DURATION, Flag, Range, array_module, as_float, combine, flag_if,
                               is_concrete, on_host, raise_if_flagged)

# Angles beyond this many radians (about 1600 turns) are rejected: no drop needs them, and the sine and cosine of
# larger arguments lose their argument reduction in the fast polynomial the response uses.
MAX_ANGLE = 1.0e4

_ANGLE = (Range(-MAX_ANGLE, MAX_ANGLE, unit="rad"), Flag.ANGLE_RANGE)
_ANY = {unit: (Range(unit=unit), Flag.NONFINITE_INPUT) for unit in ("m", "rad/s", "m/s")}


class Housing(eqx.Module):
    """Rigid rectangular housing: `width` W and `height` H (m) in the plane of motion, `mass` (kg),
    `radius_of_gyration` k (m) about G.

    - `radius_of_gyration=None` takes a uniform plate's k = sqrt((W^2 + H^2) / 12).
    - `depth=None` (default) keeps the plane section; a `depth` D (m, out of the plane) makes the housing a box
      W x H x D (DESIGN.md section 7), whose principal moments about e1, e2, e3 through G are a uniform box's,
      (m (H^2 + D^2) / 12, m (W^2 + D^2) / 12, m k^2), unless `inertia` (I1, I2, I3) (kg m^2) is given (then
      k = sqrt(I3 / m)).
    """

    width: Float[Array, ""]
    height: Float[Array, ""]
    mass: Float[Array, ""]
    radius_of_gyration: Float[Array, ""]
    depth: Float[Array, ""] | None
    principal_inertia: Float[Array, "3"] | None

    RANGES: ClassVar[dict] = {
        "width": positive("m", 1e-4, 100.0),
        "height": positive("m", 1e-4, 100.0),
        "mass": positive("kg", 1e-6, 1e5),
        "radius_of_gyration": positive("m", 1e-5, 100.0),
        "depth": positive("m", 1e-4, 100.0),
        "principal_inertia": positive("kg m^2", 1e-16, 1e9),
    }

    def __init__(self, width=0.15, height=0.075, mass=0.18, radius_of_gyration=None, depth=None, inertia=None):
        init_fields(self, dict(width=width, height=height, mass=mass))
        self.depth = self.principal_inertia = None
        if depth is not None:
            init_fields(self, dict(depth=depth))
        if inertia is not None:
            if depth is None:
                raise ValueError("Housing.inertia (principal moments I1, I2, I3) describes a box: give Housing.depth "
                                 "too (m), or radius_of_gyration for the plane section")
            if radius_of_gyration is not None:
                raise ValueError("give Housing.inertia or Housing.radius_of_gyration, not both (k = sqrt(I3 / m))")
            init_fields(self, dict(principal_inertia=inertia))
            if jnp.shape(self.principal_inertia)[-1:] != (3,):
                raise ValueError(f"Housing.inertia must be the principal moments (I1, I2, I3) about e1, e2, e3 "
                                 f"through G, kg m^2; got shape {jnp.shape(self.principal_inertia)}")
            i3, m = self.principal_inertia[..., 2], self.mass
            radius_of_gyration = (np.sqrt(on_host(i3) / on_host(m)) if is_concrete(i3, m) else jnp.sqrt(i3 / m))
        if radius_of_gyration is None:
            w, h = (on_host(v) if is_concrete(v) else v for v in (self.width, self.height))
            radius_of_gyration = array_module(w, h).sqrt((w**2 + h**2) / 12.0)
        init_fields(self, dict(radius_of_gyration=radius_of_gyration))

    def __check_init__(self):
        check_ranges(self)
        if self.principal_inertia is not None and is_concrete(self.principal_inertia):
            i = np.sort(np.asarray(self.principal_inertia), axis=-1)
            if np.any(i[..., 0] + i[..., 1] < i[..., 2] * (1 - 1e-9)):
                raise ValueError(f"Housing.inertia = {np.asarray(self.principal_inertia).tolist()} kg m^2 breaks the "
                                 "triangle inequality of a rigid body's principal moments (each <= the sum of the "
                                 "other two); valid: e.g. a uniform box's (leave inertia out)")

    @property
    def is_box(self) -> bool:
        """Whether the housing is a box (`depth` given; static)."""
        return self.depth is not None

    @property
    def inertia(self) -> Float[Array, ""]:
        """Moment of inertia about G, out of the plane (e3), kg m^2."""
        if self.principal_inertia is not None:
            return self.principal_inertia[..., 2]
        return self.mass * self.radius_of_gyration**2

    @property
    def moments(self) -> Float[Array, "3"]:
        """A box's principal moments (I1, I2, I3) about e1, e2, e3 through G, kg m^2 (`Housing` says which)."""
        if self.depth is None:
            raise ValueError("Housing.moments needs a box: give Housing.depth (m)")
        if self.principal_inertia is not None:
            return self.principal_inertia
        m, w2, h2, d2 = self.mass, self.width**2, self.height**2, self.depth**2
        return jnp.stack([m * (h2 + d2) / 12.0, m * (w2 + d2) / 12.0, self.inertia], axis=-1)


class Placement(eqx.Module):
    """Where the board sits: `centre` (c1, c2) in housing axes from G (m), `angle` phi from e1 (rad), and in a box
    housing `depth_offset` (m): its centre line's distance from G along e3 (0: centred in depth). The board's
    width lies along e3."""

    centre: Float[Array, "2"]
    angle: Float[Array, ""]
    depth_offset: Float[Array, ""]

    RANGES: ClassVar[dict] = {"centre": _ANY["m"], "angle": _ANGLE, "depth_offset": _ANY["m"]}

    def __init__(self, centre=(0.0, 0.0), angle=0.0, depth_offset=0.0):
        init_fields(self, dict(centre=centre, angle=angle, depth_offset=depth_offset))

    def __check_init__(self):
        if jnp.shape(self.centre)[-1:] != (2,):
            raise ValueError(f"Placement.centre must be a pair (c1, c2) in m, got shape {jnp.shape(self.centre)}")
        check_ranges(self)


class Drop(eqx.Module):
    """How the housing lands: `orientation` theta of e1 from the ground (rad), drop `height` (m),
    `spin` (rad/s about z, counter-clockwise positive) and `horizontal_speed` (m/s along x) just before impact;
    `tilt` (rad) turns a box housing (`Housing.depth`) about the ground's horizontal axis in the plane of motion,
    after `orientation` (0: the plane drop; `bd.box_attitude`). A box's motion may also leave the plane:
    `side_speed` (m/s along z, out of the plane), `spin_x` and `spin_y` (rad/s about the ground's x and y axes);
    a plane section has none of these."""

    orientation: Float[Array, ""]
    height: Float[Array, ""]
    spin: Float[Array, ""]
    horizontal_speed: Float[Array, ""]
    tilt: Float[Array, ""]
    side_speed: Float[Array, ""]
    spin_x: Float[Array, ""]
    spin_y: Float[Array, ""]

    RANGES: ClassVar[dict] = {
        "orientation": _ANGLE,
        "height": (Range(0.0, 1000.0, unit="m"), Flag.HEIGHT_RANGE),
        "spin": _ANY["rad/s"],
        "horizontal_speed": _ANY["m/s"],
        "tilt": _ANGLE,
        "side_speed": _ANY["m/s"],
        "spin_x": _ANY["rad/s"],
        "spin_y": _ANY["rad/s"],
    }

    def __init__(self, orientation=30 * DEG, height=1.5, spin=0.0, horizontal_speed=0.0, tilt=0.0, side_speed=0.0,
                 spin_x=0.0, spin_y=0.0):
        init_fields(self, dict(orientation=orientation, height=height, spin=spin, horizontal_speed=horizontal_speed,
                               tilt=tilt, side_speed=side_speed, spin_x=spin_x, spin_y=spin_y))

    def __check_init__(self):
        check_ranges(self)

    def velocity(self) -> Float[Array, "3"]:
        """G's velocity (x, y, z) just before impact, m/s, ground frame: falling from `height`."""
        fall = -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(self.height, 0.0))
        return jnp.stack(jnp.broadcast_arrays(self.horizontal_speed, fall, self.side_speed), axis=-1)

    def angular_velocity(self) -> Float[Array, "3"]:
        """The housing's angular velocity (about x, y, z) just before impact, rad/s, ground frame."""
        return jnp.stack(jnp.broadcast_arrays(self.spin_x, self.spin_y, self.spin), axis=-1)

    def in_plane(self):
        """Whether the motion stays in the plane of motion: no `side_speed`, `spin_x` or `spin_y` (elementwise)."""
        xp = array_module(self)
        return (xp.asarray(self.side_speed) == 0) & (xp.asarray(self.spin_x) == 0) & (xp.asarray(self.spin_y) == 0)


CONTACT_MODELS = ("auto", "rigid", "compliant")
"""`Contact.model`: how the housing's landing is modelled (DESIGN.md section 7)."""


class Contact(eqx.Module):
    """Ground contact: Coulomb `friction` mu >= 0, `restitution` e in [0, 1], how long a corner's contact lasts,
    `duration` (s; 0, or up to `IMPULSE_DURATION` = 1e-12 s, means an ideal impulse), and the landing `model`:

    - `"rigid"`: Routh's law at the lowest corner, one corner at a time (exact where a corner strikes alone);
    - `"compliant"`: every corner that reaches the ground carries a spring-dashpot and Coulomb friction, the
      housing's rigid motion is integrated through the board's peak window with diffrax (`compliant_landing`),
      every strike in it included, and the board feels the supports' acceleration history;
    - `"auto"` (default): `"rigid"` where the first corner strikes alone (the next strike comes after its contact
      has ended), the compliant landing where strikes overlap (near-flat landings), blended between the two over a
      band of the next strike's time, so that the answer has no jump (`_response/landing_path.py` says what each
      follows). With `duration = 0` (ideal impulses, which overlap only exactly flat) `"auto"` is `"rigid"`.
    """

    friction: Float[Array, ""]
    restitution: Float[Array, ""]
    duration: Float[Array, ""]
    model: str = eqx.field(static=True)

    RANGES: ClassVar[dict] = {
        "friction": (Range(0.0), Flag.FRICTION_NEGATIVE),
        "restitution": (Range(0.0, 1.0), Flag.RESTITUTION_RANGE),
        "duration": (Range(0.0, unit="s"), Flag.DURATION_NEGATIVE),
    }

    def __init__(self, friction=0.3, restitution=0.5, duration=5e-4, model="auto"):
        init_fields(self, dict(friction=friction, restitution=restitution, duration=duration))
        if model not in CONTACT_MODELS:
            near = difflib.get_close_matches(str(model), CONTACT_MODELS, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise ValueError(f"Contact.model = {model!r}{hint}; valid: {', '.join(CONTACT_MODELS)}")
        self.model = model

    def with_model(self, model: str) -> "Contact":
        """The same contact with another `model`."""
        return Contact(self.friction, self.restitution, self.duration, model=model)

    def __check_init__(self):
        check_ranges(self)
        if (self.model == "compliant" and is_concrete(self.duration)
                and np.any(np.asarray(self.duration) <= IMPULSE_DURATION)):
            raise ValueError(
                f"Contact.duration = {float(np.min(self.duration)):g} s with Contact.model = {self.model!r}: the "
                "compliant landing needs a pulse (its springs' stiffness comes from the duration); valid: duration > "
                f'{IMPULSE_DURATION:g} s, or Contact(model="rigid") for an ideal impulse (duration 0)')


SECTIONS = {"housing": Housing, "board": Board, "placement": Placement, "drop": Drop, "contact": Contact}


def board_ends(placement: Placement, length) -> Float[Array, "2 2"]:
    """Board ends A and B (rows) in housing axes from G, m (a leading batch axis carries through)."""
    xp = array_module(placement, length)  # NumPy in eager checks and plots
    angle = xp.asarray(placement.angle)
    axis = xp.stack([xp.cos(angle), xp.sin(angle)], axis=-1)
    half = 0.5 * xp.asarray(length)[..., None] * axis
    return xp.stack([placement.centre - half, placement.centre + half], axis=-2)


def _board_outside(scene) -> jax.Array:
    xp = array_module(scene)
    ends = board_ends(scene.placement, scene.board.length)
    half = xp.stack(xp.broadcast_arrays(scene.housing.width, scene.housing.height), axis=-1)[..., None, :] / 2
    # A relative slack absorbs round-off for a board that spans the housing exactly.
    slack = 1e-9 * xp.max(half, axis=(-2, -1), keepdims=True)
    outside = xp.any(xp.abs(ends) > half + slack, axis=(-2, -1))
    if scene.housing.depth is not None:
        half_depth = xp.asarray(scene.housing.depth) / 2
        outside = outside | (xp.abs(scene.placement.depth_offset) + xp.asarray(scene.board.width) / 2
                             > half_depth * (1 + 1e-9))
    return outside


class Scene(eqx.Module):
    """Everything one drop needs: `housing`, `board`, `placement`, `drop`, `contact`."""

    housing: Housing
    board: Board
    placement: Placement
    drop: Drop
    contact: Contact

    def __init__(self, housing=None, board=None, placement=None, drop=None, contact=None):
        self.housing = Housing() if housing is None else housing
        self.board = Board() if board is None else board
        self.placement = Placement() if placement is None else placement
        self.drop = Drop() if drop is None else drop
        self.contact = Contact() if contact is None else contact

    def __check_init__(self):
        _check_fits(self)

    @classmethod
    def default(cls) -> "Scene":
        """The embedded phone-like scene (`beamdrop_jax/scenes/default.toml`)."""
        from .file import load_scene

        return load_scene("default")

    def replace(self, *, check_ranges: bool = True, **paths) -> "Scene":
        """A copy with fields replaced by dotted path, e.g. `scene.replace(**{"drop.height": 1.0})`, or
        `scene.replace(**{"contact.model": "auto"})` for the landing model (a string, `Contact.model`).

        Values are checked as the constructors check them (type, range; the board inside the housing and below
        its buckling load), naming the path; arrays with a leading batch axis are welcome. `check_ranges=False`
        keeps out-of-range values (types are still checked), to be flagged per scene under `jit`, as random
        drops are."""
        out = self
        for path, value in paths.items():
            if path == "contact.model":
                out = eqx.tree_at(lambda s: s.contact, out, out.contact.with_model(value))
                continue
            cls, name = _field_at(path, self)
            valid = cls.RANGES[name][0]
            new = as_float(value, path, valid)
            if name == "principal_inertia":
                if not self.housing.is_box:
                    raise ValueError(f"{path} (I1, I2, I3) describes a box: give housing.depth first (m), or "
                                     "housing.radius_of_gyration for the plane section")
                if jnp.shape(new)[-1:] != (3,):
                    raise ValueError(f"{path} must be the principal moments (I1, I2, I3), kg m^2; got shape "
                                     f"{jnp.shape(new)}")
            if check_ranges:
                valid.require(new, path)
            section = path.split(".")[0]
            out = eqx.tree_at(lambda s, section=section, name=name: getattr(getattr(s, section), name), out, new,
                              is_leaf=lambda x: x is None)
        if check_ranges and is_concrete(out):
            out.board.__check_init__()
            _check_fits(out)
        return out


def _section_classes(scene) -> dict:
    """The class of each section of a scene (the board's is `Board` or `Plate`)."""
    return {section: type(getattr(scene, section)) for section in SECTIONS}


def _field_at(path: str, scene=None):
    """(class, field name) of a dotted scene path, or a `ValueError` listing the valid paths."""
    import difflib

    classes = SECTIONS if scene is None else _section_classes(scene)
    # contact.model (a string, which `Scene.replace` takes apart from the numbers) is a path too.
    valid = [f"{section}.{name}" for section, cls in classes.items() for name in cls.RANGES] + ["contact.model"]
    parts = path.split(".")
    if len(parts) != 2 or parts[0] not in classes or parts[1] not in classes[parts[0]].RANGES:
        close = difflib.get_close_matches(path, valid, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else f"; valid: {', '.join(valid)}"
        raise ValueError(f"no scene field {path!r}{hint}")
    return classes[parts[0]], parts[1]


def _box_only(scene):
    """Box-only fields set on a plane section (no `Housing.depth`): a tilt or a depth offset that would change
    nothing. False for a box."""
    if scene.housing.is_box:
        return False
    xp = array_module(scene)
    return ((xp.asarray(scene.drop.tilt) != 0) | (xp.asarray(scene.placement.depth_offset) != 0)
            | ~scene.drop.in_plane())


def _largest(v) -> float:
    return float(np.max(np.abs(v)))


def _check_fits(scene) -> None:
    if not is_concrete(scene):
        return
    scene = on_host(scene)
    if np.any(_box_only(scene)):
        raise ValueError(
            f"Drop.tilt = {_largest(scene.drop.tilt):g} rad, Placement.depth_offset = "
            f"{_largest(scene.placement.depth_offset):g} m, Drop.side_speed = {_largest(scene.drop.side_speed):g} "
            f"m/s, Drop.spin_x = {_largest(scene.drop.spin_x):g} and Drop.spin_y = {_largest(scene.drop.spin_y):g} "
            "rad/s turn or move things out of the plane of motion, which a plane section does not have; valid: 0 for "
            "each, or a box housing (Housing.depth, m)")
    if not np.any(_board_outside(scene)):
        return
    ends = board_ends(scene.placement, scene.board.length)
    w, h = (float(np.max(v)) for v in (scene.housing.width, scene.housing.height))
    if scene.housing.depth is not None:
        d, z, b = (float(np.max(np.abs(v))) for v in (scene.housing.depth, scene.placement.depth_offset,
                                                         scene.board.width))
        if z + b / 2 > d / 2 * (1 + 1e-9):
            raise ValueError(
                f"the board's width {b:g} m at Placement.depth_offset = {z:g} m reaches {z + b / 2:g} m from G "
                f"along e3, outside the box (Housing.depth/2 = {d / 2:g} m); valid: |depth_offset| + width/2 <= "
                "depth/2")
    raise ValueError(
        f"Placement puts the board ends at {np.round(ends.reshape(-1, 2, 2)[0], 6).tolist()} (m, housing axes from "
        f"G), outside the housing: each end must satisfy |q1| <= {w / 2:g} and |q2| <= {h / 2:g} "
        "(Housing.width/2, Housing.height/2); move or turn the board (Placement.centre, Placement.angle) or change "
        "Board.length"
    )


def scene_flags(scene: Scene):
    """Traceable validation of a scene: an int32 mask of `Flag` bits (0 when everything is valid)."""
    # A chain of ands, not a stack: under vmap a stack broadcasts every fixed field to the batch.
    finite = functools.reduce(jnp.logical_and, [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(scene)])
    return combine(
        flag_if(~finite, Flag.NONFINITE_INPUT),
        *(range_flags(getattr(scene, section)) for section in SECTIONS if section != "board"),
        scene.board.flags(),
        flag_if(_board_outside(scene), Flag.BOARD_OUTSIDE_HOUSING),
        flag_if(_box_only(scene), Flag.OUT_OF_PLANE),
    )


def require_single(scene: Scene, what: str) -> None:
    """Raise `ValueError` naming the field if `scene` is a batch (a field with a leading axis): `what` takes one
    scene (batches go through `jax.vmap` or `montecarlo`). Shapes are static, so this holds under jit too."""
    for section, cls in _section_classes(scene).items():
        for name in cls.RANGES:
            if getattr(getattr(scene, section), name, None) is None:  # an optional field left out
                continue
            shape = jnp.shape(getattr(getattr(scene, section), name))
            if len(shape) != (1 if name in VECTOR_FIELDS else 0):
                raise ValueError(f"{what} takes one scene, but {section}.{name} has shape {shape}: give one value "
                                 "(for many drops use jax.vmap or bd.montecarlo)")


def check_scene(scene: Scene) -> None:
    """Raise `ValueError` naming the field, its value and the valid range if a concrete scene (or batch of scenes)
    has any flagged problem (no-op under tracing)."""
    if not is_concrete(scene):
        return
    flags = np.asarray(_scene_flags_program(scene))  # one compiled program, not one per operation
    if not np.any(flags):
        return
    for section in SECTIONS:
        getattr(scene, section).__check_init__()
    _check_fits(scene)
    raise_if_flagged(np.bitwise_or.reduce(flags.ravel()), "invalid scene")


_scene_flags_program = filter_jit(scene_flags)
