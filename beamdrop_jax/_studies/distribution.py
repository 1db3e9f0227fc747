"""What varies from drop to drop and how: `DropDistribution` draws random drops of a scene, one stream per randomised
field (the same key gives the same drops whatever else changes), and `sample_axes` says which fields of the drawn
scenes carry the drops' axis."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from .._common.checks import float_dtype
from .._scene.containers import Scene

_FIELDS = {
    "orientation": "drop.orientation",
    "height": "drop.height",
    "spin": "drop.spin",
    "horizontal_speed": "drop.horizontal_speed",
    "friction": "contact.friction",
    "restitution": "contact.restitution",
    "duration": "contact.duration",
    "tilt": "drop.tilt",
    "side_speed": "drop.side_speed",
    "spin_x": "drop.spin_x",
    "spin_y": "drop.spin_y",
}
_PLANE_FIELDS = 7  # the first seven of `_FIELDS` apply to a plane section; the rest to a box


# How `DropDistribution.describe` shows each field: its name, unit and scale from SI.
_SHOWN = {
    "orientation": ("orientation", " deg", 180.0 / math.pi),
    "height": ("height", " m", 1.0),
    "spin": ("spin", " rad/s", 1.0),
    "horizontal_speed": ("horizontal speed", " m/s", 1.0),
    "friction": ("friction", "", 1.0),
    "restitution": ("restitution", "", 1.0),
    "duration": ("contact duration", " ms", 1e3),
    "tilt": ("tilt", " deg", 180.0 / math.pi),
    "side_speed": ("side speed", " m/s", 1.0),
    "spin_x": ("spin about x", " rad/s", 1.0),
    "spin_y": ("spin about y", " rad/s", 1.0),
}


def _check_spec(name, spec):
    if spec is None:
        return
    if not (isinstance(spec, tuple) and len(spec) == 3 and spec[0] in ("uniform", "lognormal", "cosine", "faces")):
        raise ValueError(
            f"DropDistribution.{name} = {spec!r}; valid: None (the scene's value), ('uniform', low, high), "
            "('lognormal', median, sigma), for an angle ('cosine', low, high), or for the orientation ('faces', "
            "share, spread)"
        )
    kind, a, b = spec
    if kind == "faces" and name != "orientation":
        raise ValueError(f"DropDistribution.{name} = {spec!r}: ('faces', share, spread) is for the orientation only")
    if kind == "faces" and not (0.0 <= a <= 1.0 and 0.0 <= b <= math.pi / 4):
        raise ValueError(f"DropDistribution.orientation = {spec!r}: the share near a face must be in [0, 1] and the "
                         f"spread in [0, pi/4] rad, got share {a}, spread {b}")
    if kind == "uniform" and not (math.isfinite(a) and math.isfinite(b) and a <= b):
        raise ValueError(f"DropDistribution.{name}: uniform bounds must be finite with low <= high, got ({a}, {b})")
    if kind == "cosine" and not (-math.pi / 2 <= a <= b <= math.pi / 2):
        raise ValueError(f"DropDistribution.{name}: a cosine density needs -pi/2 <= low <= high <= pi/2 rad, got "
                         f"({a}, {b})")
    if kind == "lognormal" and not (a > 0 and b >= 0):
        raise ValueError(f"DropDistribution.{name}: lognormal needs median > 0 and sigma >= 0, got ({a}, {b})")


class DropDistribution(eqx.Module):
    """Which scene fields vary and how: each is None (the scene's value), `("uniform", low, high)` or
    `("lognormal", median, sigma)`, or for an angle `("cosine", low, high)` (density proportional to its cosine:
    its sine uniform). `orientation=("faces", share, spread)` biases drops toward flat landings, as flat devices
    fall: a `share` of the drops lands near one of the four faces (orientation k pi/2, k uniform, plus a normal
    deviation of standard deviation `spread`, rad), the rest uniformly on [0, 2 pi); `DropDistribution.faces`
    builds it. Default: orientation uniform on [0, 2 pi), everything else as in the scene. Angles in rad,
    heights in m, spin in rad/s, speeds in m/s, durations in s. Use `DropDistribution.uniform` for (low, high)
    shorthand, and `DropDistribution.rotations()` for a box landing in a uniformly random attitude."""

    orientation: tuple | None = eqx.field(static=True, default=("uniform", 0.0, 2 * math.pi))
    height: tuple | None = eqx.field(static=True, default=None)
    spin: tuple | None = eqx.field(static=True, default=None)
    horizontal_speed: tuple | None = eqx.field(static=True, default=None)
    friction: tuple | None = eqx.field(static=True, default=None)
    restitution: tuple | None = eqx.field(static=True, default=None)
    duration: tuple | None = eqx.field(static=True, default=None)
    tilt: tuple | None = eqx.field(static=True, default=None)
    side_speed: tuple | None = eqx.field(static=True, default=None)
    spin_x: tuple | None = eqx.field(static=True, default=None)
    spin_y: tuple | None = eqx.field(static=True, default=None)

    @classmethod
    def rotations(cls, **others) -> "DropDistribution":
        """A box housing (`Housing.depth`) landing in an attitude uniform on the rotation group: the downward
        direction in the body, (-sin theta cos tilt, -cos theta cos tilt, sin tilt), is then uniform on the
        sphere (orientation theta uniform on [0, 2 pi), the sine of the tilt uniform on [-1, 1]); the turn about
        the vertical does not change a drop without horizontal speed. `others` set the other fields."""
        return cls(orientation=("uniform", 0.0, 2 * math.pi), tilt=("cosine", -math.pi / 2, math.pi / 2), **others)

    @classmethod
    def faces(cls, share: float, spread: float, **others) -> "DropDistribution":
        """Face-biased orientations: a `share` in [0, 1] of the drops near a face (k pi/2 plus a normal deviation of
        standard deviation `spread` rad, in [0, pi/4]), the rest uniform over the circle. `others` set the other
        fields."""
        return cls(orientation=("faces", float(share), float(spread)), **others)

    def __check_init__(self):
        for name in _FIELDS:
            _check_spec(name, getattr(self, name))

    def varied(self) -> list[str]:
        return [name for name in _FIELDS if getattr(self, name) is not None]

    def describe(self) -> str:
        """What varies and how, in engineering units: 'orientation uniform on [0, 360] deg; height uniform on
        [0.5, 1.5] m; every other field as in the scene'."""
        parts = []
        for name in self.varied():
            kind, a, b = getattr(self, name)
            what, unit, scale = _SHOWN[name]
            if kind == "uniform":
                parts.append(f"{what} uniform on [{a * scale:.4g}, {b * scale:.4g}]{unit}")
            elif kind == "cosine":
                parts.append(f"{what} with sine uniform, on [{a * scale:.4g}, {b * scale:.4g}]{unit}")
            elif kind == "faces":
                parts.append(f"{what}: {a:.3g} of the drops near a face (0, 90, 180, 270 deg plus a normal deviation "
                             f"of {b * scale:.3g}{unit}), the rest uniform on [0, 360]{unit}")
            else:
                parts.append(f"{what} lognormal, median {a * scale:.4g}{unit}, sigma {b:.4g}")
        return "; ".join(parts + ["every other field as in the scene"])

    def sample(self, scene: Scene, n: int, key) -> Scene:
        """n scenes: the varied fields get a leading axis n, the others stay as in `scene`."""
        _check_key(key)
        out = scene
        # The plane's seven fields keep the streams they had before the box's fields joined them (the same key,
        # the same drops); each box field draws from a key of its own.
        keys = [*jax.random.split(key, _PLANE_FIELDS), *(jax.random.fold_in(key, i + 1)
                                                         for i in range(_PLANE_FIELDS, len(_FIELDS)))]
        for (name, path), k in zip(_FIELDS.items(), keys):
            spec = getattr(self, name)
            if spec is None:
                continue
            kind, a, b = spec
            if kind == "uniform":
                values = jax.random.uniform(k, (n,), minval=a, maxval=b, dtype=float_dtype())
            elif kind == "cosine":
                values = jnp.arcsin(jax.random.uniform(k, (n,), minval=math.sin(a), maxval=math.sin(b),
                                                       dtype=float_dtype()))
            elif kind == "faces":
                k_near, k_face, k_dev, k_any = jax.random.split(k, 4)
                near = jax.random.uniform(k_near, (n,), dtype=float_dtype()) < a
                face = jax.random.randint(k_face, (n,), 0, 4).astype(float_dtype()) * (math.pi / 2)
                deviation = b * jax.random.normal(k_dev, (n,), dtype=float_dtype())
                anywhere = jax.random.uniform(k_any, (n,), minval=0.0, maxval=2 * math.pi, dtype=float_dtype())
                values = jnp.mod(jnp.where(near, face + deviation, anywhere), 2 * math.pi)
            else:
                values = a * jnp.exp(b * jax.random.normal(k, (n,), dtype=float_dtype()))
            out = out.replace(check_ranges=False, **{path: values})
        return out


def _check_key(key) -> None:
    """A `TypeError` naming `key` unless it is one JAX random key: `jax.random.key(seed)` or the raw uint32 pair
    of `jax.random.PRNGKey(seed)` (a seed itself, an int, is not: JAX's own message says only that key data lacks
    a shape)."""
    dtype, shape = getattr(key, "dtype", None), getattr(key, "shape", None)
    typed = dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key) and shape == ()
    raw = dtype == jnp.uint32 and shape == (2,)
    if not (typed or raw):
        given = f"an array of shape {shape} and dtype {dtype}" if shape is not None else repr(key)
        raise TypeError(f"key = {given}; valid: one JAX random key, e.g. jax.random.PRNGKey(0) or jax.random.key(0) "
                        "(a seed, an int, is not a key)")


def sample_axes(samples: Scene, scene: Scene) -> Scene:
    """vmap `in_axes` for scenes sampled from `scene`: 0 where a field of `samples` carries a leading sample axis
    (one more axis than in `scene`), None where it is as in `scene`."""
    return jax.tree_util.tree_map(lambda s, f: 0 if jnp.ndim(s) == jnp.ndim(f) + 1 else None, samples, scene)
