"""Scene files: strict TOML in, TOML out.

A scene file has the sections `[housing]`, `[board]` (a beam; or `[plate]` for a `Plate`, with `edges` in
Leissa's letters and `mounts` a list of [x, y] pairs in m), `[placement]`, `[drop]` and `[contact]`, in SI units, with
angles in degrees under keys ending in `_deg` (`orientation_deg`, `angle_deg`). It either gives every required key
of every section, or names the embedded scene it changes with a top-level `extends = "default"` and gives only
what differs. Keys that may always be left out, because leaving them out means something physical rather than
borrowing a number from another device: `radius_of_gyration` (a uniform plate's), `axial_force`, `damping_ratio`,
`spin` and `horizontal_speed` (all 0), `model` in `[contact]` (`"auto"`), and the box housing's `depth` (none: the
plane section), `principal_inertia` ([I1, I2, I3]; a uniform box's), `tilt_deg` in `[drop]` and `depth_offset` in
`[placement]`, and a box's motion out of the plane, `side_speed`, `spin_x` and `spin_y` in `[drop]` (0).

Reading is strict: a value of the wrong type (a string, a bool, a list where a number is meant), an unknown key
(with a "did you mean"), a bare angle key (it would be read as radians), a missing key or section, a value out of
range: each is a `ValueError` that names the file, the section, the key and the valid range.
"""

import difflib
import importlib.resources
import re
import tomllib
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .._board.beam import ENDS
from .._board.plate import BASIS_LIMITS
from .._common.checks import DEG, Range, as_float
from .._common.fields import VECTOR_FIELDS
from .._board.plate import Plate
from .containers import CONTACT_MODELS, MAX_ANGLE, SECTIONS, Scene

ANGLE_KEYS = {("placement", "angle"), ("drop", "orientation"), ("drop", "tilt")}
OPTIONAL_KEYS = {
    ("housing", "radius_of_gyration"),
    ("housing", "depth"),
    ("housing", "principal_inertia"),
    ("placement", "depth_offset"),
    ("drop", "tilt"),
    ("board", "axial_force"),
    ("board", "damping_ratio"),
    ("drop", "spin"),
    ("drop", "horizontal_speed"),
    ("drop", "side_speed"),
    ("drop", "spin_x"),
    ("drop", "spin_y"),
    ("board", "ends"),
    ("contact", "model"),
    ("plate", "damping_ratio"),
    ("plate", "poisson_ratio"),
    ("plate", "mounts"),
    ("plate", "mount_radius"),
    ("plate", "basis"),
}
# `[plate]` stands where `[board]` would: the board is then a `Plate`.
FILE_SECTIONS = {**SECTIONS, "plate": Plate}
PLATE_EXTRA_KEYS = ("edges", "mounts", "basis")
# Keys whose value is a name from a list (the others are numbers).
CHOICE_KEYS = {("board", "ends"): ENDS, ("contact", "model"): CONTACT_MODELS}
# File keys (field names) whose constructor argument has another name.
KWARGS = {"principal_inertia": "inertia"}
_DEG_RANGE = Range(-MAX_ANGLE / DEG, MAX_ANGLE / DEG, unit="deg")


def embedded_scenes() -> list[str]:
    """Names of the scenes shipped in the package (`load_scene(name)` loads one)."""
    folder = importlib.resources.files("beamdrop_jax") / "scenes"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def embedded_scene_text(name: str) -> str:
    """The TOML text of embedded scene `name` (a start for a scene file of one's own: an `extends` in it names
    another embedded scene, which a copy reads as well)."""
    if name not in embedded_scenes():
        near = difflib.get_close_matches(name, embedded_scenes(), n=1)
        raise ValueError(f"no embedded scene {name!r}{f'; did you mean {near[0]!r}?' if near else ''} (embedded "
                         f"scenes: {', '.join(embedded_scenes())})")
    return (importlib.resources.files("beamdrop_jax") / "scenes" / f"{name}.toml").read_text(encoding="utf-8")


def embedded_scene_summary(name: str) -> str:
    """The first sentence of embedded scene `name`'s opening comment: what it models."""
    header = []
    for line in embedded_scene_text(name).splitlines():
        if not line.startswith("#"):
            break
        header.append(line.lstrip("#").strip())
    text = " ".join(header)
    end = re.search(r"\.\s+(?=[A-Z])", text)  # not at an abbreviation ("eqs. 4.10")
    return text if end is None else text[:end.start() + 1]


def _scene_path(path) -> Path:
    text = str(path)
    if not text.endswith(".toml") and "/" not in text and "\\" not in text and not Path(text).exists():
        resource = importlib.resources.files("beamdrop_jax") / "scenes" / f"{text}.toml"
        if resource.is_file():
            return Path(str(resource))
        near = difflib.get_close_matches(text, embedded_scenes(), n=1)
        raise FileNotFoundError(f"no embedded scene {text!r} and no such file{f' (did you mean {near[0]!r}?)' if near else ''}"
                                f"; embedded scenes: {', '.join(embedded_scenes())}")
    return Path(path)


def file_keys(section: str) -> list[str]:
    """The keys a scene file's `[section]` takes (angles under `_deg`)."""
    return [f"{name}_deg" if (section, name) in ANGLE_KEYS else name for name in FILE_SECTIONS[section].RANGES] + [
        name for (s, name) in CHOICE_KEYS if s == section] + (list(PLATE_EXTRA_KEYS) if section == "plate" else [])


def _read_toml(path: Path, source: str) -> dict:
    try:
        data = path.read_bytes()
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        column = err.start - (data.rfind(b"\n", 0, err.start) + 1) + 1
        raise ValueError(f"{source}: not UTF-8 text: byte 0x{data[err.start]:02x} at line {line}, column {column} "
                         f"(byte offset {err.start}); TOML files are UTF-8 (save it as UTF-8)") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{source}: not valid TOML: {err}") from None
    except FileNotFoundError:
        raise FileNotFoundError(f"{source}: no such scene file") from None
    except OSError as err:
        raise ValueError(f"{source}: cannot be read: {err.strerror or err}") from None


def _suggest(word: str, choices) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"did you mean {close[0]!r}? " if close else ""


def _section(section: str, table, source: str, hint: str | None = None):
    """One section built from its table, each value checked for type and range, every required key there (`hint`:
    how to give them, when the generic advice does not apply)."""
    where = f"{source}: [{section}]"
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table of keys, got {table!r}")
    cls = FILE_SECTIONS[section]
    keys = file_keys(section)
    kwargs = {}
    for key, value in table.items():
        if section == "plate" and key == "edges":
            if not isinstance(value, str):
                raise ValueError(f"{where} edges = {value!r}: must be a string of four letters S, C or F")
            kwargs[key] = value
            continue
        if section == "plate" and key == "mounts":
            if not (isinstance(value, list) and all(isinstance(p, list) and len(p) == 2 for p in value)):
                raise ValueError(f"{where} mounts = {value!r}: must be a list of [x, y] pairs in m (or [] for none)")
            if value:  # [] is no mounts: it clears those of the scene this one extends
                kwargs[key] = as_float(value, f"{where} mounts", Range(unit="m"))
            continue
        if section == "plate" and key == "basis":
            if not (isinstance(value, list) and len(value) == 2
                    and all(isinstance(b, int) and not isinstance(b, bool) for b in value)):
                raise ValueError(f"{where} basis = {value!r}: must be a pair [nx, ny] of integers in "
                                 f"[{BASIS_LIMITS[0]}, {BASIS_LIMITS[1]}] (the Ritz functions along x and across the "
                                 "width)")
            kwargs[key] = tuple(value)
            continue
        if (section, key) in ANGLE_KEYS:
            raise ValueError(f"{where} {key} = {value!r}: angles in scene files are in degrees under "
                             f"'{key}_deg' (a bare '{key}' would be read as radians)")
        if key not in keys:
            raise ValueError(f"{where}: unknown key {key!r}; {_suggest(key, keys)}valid keys: {', '.join(keys)}")
        if (section, key) in CHOICE_KEYS:
            choices = CHOICE_KEYS[(section, key)]
            if value not in choices:
                raise ValueError(f"{where} {key} = {value!r}; {_suggest(str(value), choices)}valid: "
                                 + ", ".join(f'"{c}"' for c in choices))
            kwargs[key] = value
            continue
        name = key.removesuffix("_deg") if (section, key.removesuffix("_deg")) in ANGLE_KEYS else key
        valid = _DEG_RANGE if name != key else cls.RANGES[name][0]
        shown = f"{where} {key}"
        if name == "centre" and not (isinstance(value, list) and len(value) == 2):
            raise ValueError(f"{shown} = {value!r}: must be a pair [c1, c2] of numbers in m")
        if name == "principal_inertia" and not (isinstance(value, list) and len(value) == 3):
            raise ValueError(f"{shown} = {value!r}: must be the principal moments [I1, I2, I3] about e1, e2, e3 "
                             "through G, in kg m^2")
        if name not in VECTOR_FIELDS and isinstance(value, (list, dict)):
            raise ValueError(f"{shown} = {value!r}: must be a single number; valid: {valid}")
        number = as_float(value, shown, valid)
        valid.require(number, shown)
        kwargs[KWARGS.get(name, name)] = as_float(np.asarray(number) * DEG, shown) if name != key else number
    _require_all(where, [repr(k) for k in keys
                         if k not in table and (section, k.removesuffix("_deg")) not in OPTIONAL_KEYS], "key", hint)
    return _build(where, cls, kwargs)


def _require_all(where: str, missing: list[str], what: str, hint: str | None = None) -> None:
    if missing:
        hint = hint or f"give every {what}, or start the file with extends = \"default\" to change only some"
        raise ValueError(f"{where}: missing {', '.join(missing)} ({hint})")


def _build(where: str, cls, kwargs: dict):
    """`cls(**kwargs)`, its errors prefixed with where they come from."""
    try:
        return cls(**kwargs)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None


def _extended(data: dict, source: str, hints: dict) -> dict:
    """`data` with the scene it extends (and what that extends) merged under it; `hints` gets, per section that
    replaces the base's board of the other kind, how to fill it."""
    data = dict(data)
    extends = data.pop("extends", None)
    unknown = [k for k in data if k not in FILE_SECTIONS]
    if unknown:
        raise ValueError(f"{source}: unknown section or key {unknown[0]!r}; {_suggest(unknown[0], FILE_SECTIONS)}"
                         f"valid sections: {', '.join(FILE_SECTIONS)} (and a top-level extends = \"SCENE\")")
    if "board" in data and "plate" in data:
        raise ValueError(f"{source}: give [board] (a beam) or [plate], not both")
    if extends is None:
        return data
    if not isinstance(extends, str) or extends not in embedded_scenes():
        raise ValueError(f"{source}: extends = {extends!r}; valid: one of the embedded scenes "
                         f"{', '.join(embedded_scenes())}")
    base = _extended(_read_toml(_scene_path(extends), extends), extends, {})
    for given, other in (("plate", "board"), ("board", "plate")):
        if given in data and other in base:  # the file's board replaces the base's, beam or plate
            base.pop(other)
            hints[given] = (f"the {extends!r} scene's board is a [{other}], which a [{given}] replaces whole: "
                            f"give every [{given}] key")
    for section, table in data.items():
        if not isinstance(table, dict):
            raise ValueError(f"{source}: [{section}] must be a table of keys, got {table!r}")
        merged = dict(base.get(section, {}))
        for key in table:
            # A key given in the file replaces the base's, in whichever unit the file uses.
            merged.pop(key.removesuffix("_deg") + "_deg", None)
            merged.pop(key.removesuffix("_deg"), None)
        merged.update(table)
        base[section] = merged
    return base


def scene_from_dict(data: dict, source: str = "scene") -> Scene:
    """Build a scene from a TOML-shaped dict (see the module notes); `source` names it in errors."""
    hints = {}
    data = _extended(data, source, hints)
    # The sections that are there first: a typo in one explains more than the sections that are missing.
    parts = {section: _section(section, data[section], source, hints.get(section)) for section in SECTIONS
             if section in data}
    if "plate" in data:
        parts["board"] = _section("plate", data["plate"], source, hints.get("plate"))
    _require_all(source, [f"section [{s}]" for s in SECTIONS if s not in parts], "section")
    return _build(source, Scene, parts)


def load_scene(path) -> Scene:
    """Load a scene from a TOML file, or an embedded scene by name (`embedded_scenes()`: `"default"`, ...).

    Strict: see the module notes. Errors are `ValueError`s that name the file, the key and the valid range
    (`FileNotFoundError` for a missing file)."""
    resolved = _scene_path(path)
    return scene_from_dict(_read_toml(resolved, str(path)), str(path))


def _toml_value(x) -> str:
    if isinstance(x, str):
        return f'"{x}"'
    if isinstance(x, list):
        return "[" + ", ".join(_toml_value(v) for v in x) + "]"
    if isinstance(x, int) and not isinstance(x, bool):  # counts (a plate's basis) stay integers
        return str(x)
    return repr(float(x))


def scene_to_dict(scene: Scene) -> dict:
    """The TOML-shaped dict of a concrete scene (angles in degrees under `_deg` keys)."""
    out = {}
    for section in SECTIONS:
        module = getattr(scene, section)
        cls = type(module)
        section = getattr(module, "SECTION", section)  # a board names its own section
        fields = {}
        for name in cls.RANGES:
            if getattr(module, name) is None or (name == "radius_of_gyration" and module.principal_inertia is not None):
                continue  # left out: its default (or, with the moments given, k follows from them)
            value = np.asarray(jnp.asarray(getattr(module, name))).tolist()
            if (section, name) in ANGLE_KEYS:
                fields[f"{name}_deg"] = value / DEG
            else:
                fields[name] = value
        for (s, name) in CHOICE_KEYS:
            if s == section:
                fields[name] = getattr(module, name)
        if section == getattr(module, "SECTION", None):
            fields |= module.file_extras()
        out[section] = fields
    return out


def save_scene(scene: Scene, path) -> None:
    """Write a concrete scene as a complete TOML scene file (round-trips through `load_scene`)."""
    lines = ["# beamdrop_jax scene (SI units; angles in degrees under *_deg keys)"]
    for section, fields in scene_to_dict(scene).items():
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in fields.items()]
    Path(path).write_text("\n".join(lines) + "\n")
