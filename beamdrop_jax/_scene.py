"""The scene: housing, board, where the board sits, how the device lands, and the ground contact.

Every physical number is a JAX array field, so `jax.grad` reaches it and a batch of scenes can be `vmap`ped.
Construction checks concrete values eagerly (`ValueError` naming the field and the valid range); traced values are
checked by `scene_flags`, which results carry.
"""

import functools
import importlib.resources
import math
import tomllib
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._checks import float_dtype
from ._checks import DEG, Flag, combine, flag_if, in_range, is_concrete, raise_if_flagged, require


def _f(x):
    return jnp.asarray(x, dtype=float_dtype())


class Housing(eqx.Module):
    """Rigid rectangular housing: `width` W and `height` H (m), `mass` (kg), `radius_of_gyration` k (m) about G.

    `radius_of_gyration=None` takes a uniform plate's k = sqrt((W^2 + H^2) / 12).
    """

    width: Float[Array, ""]
    height: Float[Array, ""]
    mass: Float[Array, ""]
    radius_of_gyration: Float[Array, ""]

    def __init__(self, width=0.15, height=0.075, mass=0.18, radius_of_gyration=None):
        self.width = _f(width)
        self.height = _f(height)
        self.mass = _f(mass)
        if radius_of_gyration is None:
            radius_of_gyration = jnp.sqrt((self.width**2 + self.height**2) / 12.0)
        self.radius_of_gyration = _f(radius_of_gyration)

    def __check_init__(self):
        require(self.width, "Housing.width", 0.0, lo_open=True, unit="m")
        require(self.height, "Housing.height", 0.0, lo_open=True, unit="m")
        require(self.mass, "Housing.mass", 0.0, lo_open=True, unit="kg")
        require(self.radius_of_gyration, "Housing.radius_of_gyration", 0.0, lo_open=True, unit="m")

    @property
    def inertia(self) -> Float[Array, ""]:
        """Moment of inertia about G, kg m^2."""
        return self.mass * self.radius_of_gyration**2


class Board(eqx.Module):
    """Pinned-pinned Euler-Bernoulli board (SI units).

    `axial_force` N is positive in tension; N <= -EI pi^2 / L^2 buckles and is rejected.
    `damping_ratio` is the modal damping ratio zeta, the same for every mode, in [0, 1).
    """

    length: Float[Array, ""]
    thickness: Float[Array, ""]
    width: Float[Array, ""]
    youngs_modulus: Float[Array, ""]
    density: Float[Array, ""]
    axial_force: Float[Array, ""]
    damping_ratio: Float[Array, ""]

    def __init__(
        self,
        length=0.10,
        thickness=1.0e-3,
        width=0.05,
        youngs_modulus=22e9,
        density=1900.0,
        axial_force=0.0,
        damping_ratio=0.0,
    ):
        self.length = _f(length)
        self.thickness = _f(thickness)
        self.width = _f(width)
        self.youngs_modulus = _f(youngs_modulus)
        self.density = _f(density)
        self.axial_force = _f(axial_force)
        self.damping_ratio = _f(damping_ratio)

    def __check_init__(self):
        require(self.length, "Board.length", 0.0, lo_open=True, unit="m")
        require(self.thickness, "Board.thickness", 0.0, lo_open=True, unit="m")
        require(self.width, "Board.width", 0.0, lo_open=True, unit="m")
        require(self.youngs_modulus, "Board.youngs_modulus", 0.0, lo_open=True, unit="Pa")
        require(self.density, "Board.density", 0.0, lo_open=True, unit="kg/m^3")
        require(self.damping_ratio, "Board.damping_ratio", 0.0, 1.0, hi_open=True)
        if is_concrete(self.axial_force, self.length, self.thickness, self.width, self.youngs_modulus):
            require(self.axial_force, "Board.axial_force", -float(self.buckling_force), lo_open=True, unit="N")

    @property
    def bending_stiffness(self) -> Float[Array, ""]:
        """EI = E b h^3 / 12, N m^2."""
        return self.youngs_modulus * self.width * self.thickness**3 / 12.0

    @property
    def mass_per_length(self) -> Float[Array, ""]:
        """rho A = rho b h, kg/m."""
        return self.density * self.width * self.thickness

    @property
    def buckling_force(self) -> Float[Array, ""]:
        """Euler load EI pi^2 / L^2 (N): compression of this size buckles the board."""
        return self.bending_stiffness * math.pi**2 / self.length**2

    def flags(self):
        """Traceable checks of this board (int32 mask of `Flag`)."""
        sizes = [self.length, self.thickness, self.width, self.youngs_modulus, self.density]
        return combine(
            *(flag_if(~in_range(v, 0.0, lo_open=True), Flag.NONPOSITIVE_SIZE) for v in sizes),
            flag_if(~in_range(self.damping_ratio, 0.0, 1.0, hi_open=True), Flag.DAMPING_RANGE),
            flag_if(~(self.axial_force > -self.buckling_force), Flag.BUCKLED),
            flag_if(~jnp.isfinite(self.axial_force), Flag.NONFINITE_INPUT),
        )


class Placement(eqx.Module):
    """Where the board sits: `centre` (c1, c2) in housing axes from G (m), `angle` phi from e1 (rad)."""

    centre: Float[Array, "2"]
    angle: Float[Array, ""]

    def __init__(self, centre=(0.0, 0.0), angle=0.0):
        self.centre = _f(centre)
        self.angle = _f(angle)

    def __check_init__(self):
        if is_concrete(self.centre) and jnp.shape(self.centre)[-1:] != (2,):
            raise ValueError(f"Placement.centre must have shape (2,), got {jnp.shape(self.centre)}")
        require(self.centre, "Placement.centre", unit="m")
        require(self.angle, "Placement.angle", unit="rad")


class Drop(eqx.Module):
    """How the housing lands: `orientation` theta of e1 from the ground (rad), drop `height` (m),
    `spin` (rad/s, counter-clockwise positive) and `horizontal_speed` (m/s) just before impact."""

    orientation: Float[Array, ""]
    height: Float[Array, ""]
    spin: Float[Array, ""]
    horizontal_speed: Float[Array, ""]

    def __init__(self, orientation=30 * DEG, height=1.5, spin=0.0, horizontal_speed=0.0):
        self.orientation = _f(orientation)
        self.height = _f(height)
        self.spin = _f(spin)
        self.horizontal_speed = _f(horizontal_speed)

    def __check_init__(self):
        require(self.orientation, "Drop.orientation", unit="rad")
        require(self.height, "Drop.height", 0.0, unit="m")
        require(self.spin, "Drop.spin", unit="rad/s")
        require(self.horizontal_speed, "Drop.horizontal_speed", unit="m/s")


class Contact(eqx.Module):
    """Ground contact: Coulomb `friction` mu >= 0, `restitution` e in [0, 1], and how long the contact lasts,
    `duration` (s; 0 means an ideal impulse)."""

    friction: Float[Array, ""]
    restitution: Float[Array, ""]
    duration: Float[Array, ""]

    def __init__(self, friction=0.3, restitution=0.5, duration=5e-4):
        self.friction = _f(friction)
        self.restitution = _f(restitution)
        self.duration = _f(duration)

    def __check_init__(self):
        require(self.friction, "Contact.friction", 0.0)
        require(self.restitution, "Contact.restitution", 0.0, 1.0)
        require(self.duration, "Contact.duration", 0.0, unit="s")


def board_ends(placement: Placement, length) -> Float[Array, "2 2"]:
    """Board ends A and B (rows) in housing axes from G, m."""
    axis = jnp.stack([jnp.cos(placement.angle), jnp.sin(placement.angle)])
    half = 0.5 * length * axis
    return jnp.stack([placement.centre - half, placement.centre + half])


def _board_outside(scene) -> jax.Array:
    ends = board_ends(scene.placement, scene.board.length)
    half = jnp.stack([scene.housing.width, scene.housing.height]) / 2
    # A relative slack absorbs round-off for a board that spans the housing exactly.
    slack = 1e-9 * jnp.max(half)
    return jnp.any(jnp.abs(ends) > half + slack)


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
        if is_concrete(self) and bool(jnp.any(_board_outside(self))):
            ends = board_ends(self.placement, self.board.length)
            w, h = float(self.housing.width), float(self.housing.height)
            raise ValueError(
                f"Placement puts the board ends at {ends.tolist()} (m, housing axes from G), outside the housing: "
                f"each end must satisfy |q1| <= {w / 2:g} and |q2| <= {h / 2:g} (Housing.width/2, Housing.height/2)"
            )

    @classmethod
    def default(cls) -> "Scene":
        """The embedded phone-like scene (`beamdrop_jax/scenes/default.toml`)."""
        return load_scene("default")

    def replace(self, **paths) -> "Scene":
        """A copy with fields replaced by dotted path, e.g. `scene.replace(**{"drop.height": 1.0})`."""
        out = self
        for path, value in paths.items():
            parts = path.split(".")

            def where(s, parts=parts):
                for p in parts:
                    s = getattr(s, p)
                return s

            out = eqx.tree_at(where, out, jnp.asarray(value, dtype=float_dtype()))
        return out


def scene_flags(scene: Scene):
    """Traceable validation of a scene: an int32 mask of `Flag` bits (0 when everything is valid)."""
    h, c, d = scene.housing, scene.contact, scene.drop
    # A chain of ands, not a stack: under vmap a stack broadcasts every fixed field to the batch.
    finite = functools.reduce(jnp.logical_and, [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(scene)])
    return combine(
        flag_if(~finite, Flag.NONFINITE_INPUT),
        *(
            flag_if(~in_range(v, 0.0, lo_open=True), Flag.NONPOSITIVE_SIZE)
            for v in (h.width, h.height, h.mass, h.radius_of_gyration)
        ),
        scene.board.flags(),
        flag_if(~in_range(c.restitution, 0.0, 1.0), Flag.RESTITUTION_RANGE),
        flag_if(~in_range(c.friction, 0.0), Flag.FRICTION_NEGATIVE),
        flag_if(~in_range(c.duration, 0.0), Flag.DURATION_NEGATIVE),
        flag_if(~in_range(d.height, 0.0), Flag.NEGATIVE_HEIGHT),
        flag_if(_board_outside(scene), Flag.BOARD_OUTSIDE_HOUSING),
    )


def check_scene(scene: Scene) -> None:
    """Raise `ValueError` if a concrete scene has any flagged problem (no-op under tracing)."""
    raise_if_flagged(scene_flags(scene), "invalid scene")


# ----------------------------------------------------------------------------------------------------------------
# TOML in and out. Angles are stored in degrees under keys ending in `_deg`.

_ANGLE_KEYS = {("placement", "angle"), ("drop", "orientation")}
_SECTIONS = {"housing": Housing, "board": Board, "placement": Placement, "drop": Drop, "contact": Contact}


def _scene_path(path) -> Path:
    text = str(path)
    if not text.endswith(".toml") and "/" not in text and "\\" not in text:
        resource = importlib.resources.files("beamdrop_jax") / "scenes" / f"{text}.toml"
        if resource.is_file():
            return Path(str(resource))
        names = sorted(p.name[:-5] for p in (importlib.resources.files("beamdrop_jax") / "scenes").iterdir()
                       if p.name.endswith(".toml"))
        raise FileNotFoundError(f"no embedded scene {text!r}; embedded scenes: {', '.join(names)}")
    return Path(path)


def embedded_scenes() -> list[str]:
    """Names of the scenes shipped in the package (`load_scene(name)` loads one)."""
    folder = importlib.resources.files("beamdrop_jax") / "scenes"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def scene_from_dict(data: dict) -> Scene:
    """Build a scene from a TOML-shaped dict (sections housing, board, placement, drop, contact)."""
    unknown = set(data) - set(_SECTIONS)
    if unknown:
        raise ValueError(f"unknown scene section(s) {sorted(unknown)}; valid: {sorted(_SECTIONS)}")
    parts = {}
    for section, cls in _SECTIONS.items():
        kwargs = {}
        for key, value in data.get(section, {}).items():
            if key.endswith("_deg") and (section, key[:-4]) in _ANGLE_KEYS:
                kwargs[key[:-4]] = float(value) * DEG
            else:
                kwargs[key] = value
        try:
            parts[section] = cls(**kwargs)
        except TypeError as err:
            raise ValueError(f"[{section}]: {err}") from None
    return Scene(**parts)


def load_scene(path) -> Scene:
    """Load a scene from a TOML file, or an embedded scene by name (`"default"`, `"jedec"`, `"thesis"`)."""
    with open(_scene_path(path), "rb") as fh:
        return scene_from_dict(tomllib.load(fh))


def _toml_value(x) -> str:
    if isinstance(x, list):
        return "[" + ", ".join(_toml_value(v) for v in x) + "]"
    return repr(float(x))


def scene_to_dict(scene: Scene) -> dict:
    """The TOML-shaped dict of a concrete scene (angles in degrees under `_deg` keys)."""
    out = {}
    for section in _SECTIONS:
        module = getattr(scene, section)
        fields = {}
        for name in module.__dataclass_fields__:
            value = jnp.asarray(getattr(module, name)).tolist()
            if (section, name) in _ANGLE_KEYS:
                fields[f"{name}_deg"] = value / DEG
            else:
                fields[name] = value
        out[section] = fields
    return out


def save_scene(scene: Scene, path) -> None:
    """Write a concrete scene as TOML (round-trips through `load_scene`)."""
    lines = ["# beamdrop_jax scene (SI units; angles in degrees under *_deg keys)"]
    for section, fields in scene_to_dict(scene).items():
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in fields.items()]
    Path(path).write_text("\n".join(lines) + "\n")
