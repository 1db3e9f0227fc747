"""Input checks: eager errors that name the field and range, and flags for use under `jit`.

Every check has two faces. When its value is concrete (eager Python), a bad value raises `ValueError` naming the
field, the value and the valid range. When its value is traced (inside `jit`, `vmap`, `grad`) no exception is
possible, so the same condition is returned as a bit in an integer `Flag` mask that results carry.
"""

import dataclasses
import enum
import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np


class Flag(enum.IntFlag):
    """Bits of the `flags` field that results carry. `Flag.OK` (0) means the result can be trusted."""

    OK = 0
    NONFINITE_INPUT = 1
    NONPOSITIVE_SIZE = 2  # a size or material constant <= 0 or outside its magnitude range (`RANGES`)
    RESTITUTION_RANGE = 4
    FRICTION_NEGATIVE = 8
    DURATION_NEGATIVE = 16
    BOARD_OUTSIDE_HOUSING = 32
    BUCKLED = 64
    DAMPING_RANGE = 128
    FLAT_LANDING_WITH_MOTION = 256
    SEPARATING_CONTACT = 512
    SOLVER_FAILED = 1024
    HEIGHT_RANGE = 2048  # a drop height outside [0, 1000] m
    NEGATIVE_HEIGHT = 2048  # the same bit, by its former name
    PIVOTING_CONTACT = 4096
    ANGLE_RANGE = 8192
    NONFINITE_RESULT = 16384
    CONTACT_MATRIX = 32768
    WINDOW_RANGE = 65536  # an explicit `Numerics.window` leaves the top mode < 2 time-grid points per period
    OUTSIDE_TABLE = 131072  # a drop's contact duration outside the durations its `SuperpositionTable` spans
    PRECISION = 262144  # a plate in float32: its Ritz eigenproblem needs float64
    MOUNT_OUTSIDE_PLATE = 524288  # a plate's mount off the plate, or its disc (`mount_radius`) across an edge
    MECHANISM = 1048576  # a plate's supports leave a rigid motion free, or hold it only within a mount's radius
    MOUNTS_COINCIDE = 2097152  # two of a plate's mounts closer than `mount_radius`: the model cannot tell them apart
    GAUGE_OUTSIDE = 4194304  # a strain gauge off the plate, inside a mount's disc, or not finite
    OUTSIDE_THEORY = 8388608  # a plate too thick for thin-plate theory, or deflecting beyond small rotations
    NOT_SEPARATED = 16777216  # a compliant landing still in contact at its time bound
    OUT_OF_PLANE = 33554432  # a tilted box asked of a model built for the plane, or a tilt on a plane section

    @classmethod
    def describe(cls, flags) -> list[str]:
        """Names of the bits set in an integer mask (for messages and reports)."""
        value = int(flags)
        return [f.name for f in cls if f.value and value & f.value]


def is_concrete(*values) -> bool:
    """True when no value is a JAX tracer, so it can be inspected eagerly."""
    return not any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(values))


def on_host(tree):
    """A concrete pytree with its arrays as NumPy arrays: eager checks computed on it run as NumPy, where the same
    expressions on JAX arrays dispatch (and, the first time, compile) one XLA program per operation."""
    return jax.tree_util.tree_map(np.asarray, tree)


def array_module(*values):
    """`numpy` when every value is a NumPy array or a Python number, else `jax.numpy`."""
    host = all(isinstance(v, (np.ndarray, np.generic, int, float)) for v in jax.tree_util.tree_leaves(values))
    return np if host else jnp


def _fmt(bound, open_, side):
    if bound is None:
        return ""
    bracket = ("(" if open_ else "[") if side == "lo" else (")" if open_ else "]")
    return f"{bracket}{bound:g}" if side == "lo" else f"{bound:g}{bracket}"


def in_range(value, lo=None, hi=None, *, lo_open=False, hi_open=False):
    """Boolean array: finite and inside the interval (traceable)."""
    value = jnp.asarray(value)
    ok = jnp.isfinite(value)
    if lo is not None:
        ok = ok & ((value > lo) if lo_open else (value >= lo))
    if hi is not None:
        ok = ok & ((value < hi) if hi_open else (value <= hi))
    return ok


def require(value, name: str, lo=None, hi=None, *, lo_open=False, hi_open=False, unit: str = ""):
    """Raise `ValueError` if a concrete `value` is non-finite or outside the interval; no-op when traced."""
    if not is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    ok = np.isfinite(arr)
    if lo is not None:
        ok &= (arr > lo) if lo_open else (arr >= lo)
    if hi is not None:
        ok &= (arr < hi) if hi_open else (arr <= hi)
    if not np.all(ok):
        bad = arr[~ok] if arr.ndim else arr
        lo_s = _fmt(lo, lo_open, "lo") if lo is not None else "(-inf"
        hi_s = _fmt(hi, hi_open, "hi") if hi is not None else "inf)"
        u = f" {unit}" if unit else ""
        shown = np.array2string(np.asarray(bad).ravel()[:3], precision=6) if np.ndim(bad) else f"{float(bad):g}"
        raise ValueError(f"{name} = {shown}{u} is outside the valid range {lo_s}, {hi_s}{u} (finite values only)")


@dataclasses.dataclass(frozen=True)
class Range:
    """Valid values of a float field: an interval (open or closed ends, None for unbounded), its unit, finite
    values only. `str(Range(0, 1))` is `[0, 1]`."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""

    def __str__(self) -> str:
        lo = _fmt(self.lo, self.lo_open, "lo") if self.lo is not None else "(-inf"
        hi = _fmt(self.hi, self.hi_open, "hi") if self.hi is not None else "inf)"
        return f"{lo}, {hi}" + (f" {self.unit}" if self.unit else "")

    def require(self, value, name: str) -> None:
        """`ValueError` naming `name` if a concrete value is non-finite or outside; no-op when traced."""
        require(value, name, self.lo, self.hi, lo_open=self.lo_open, hi_open=self.hi_open, unit=self.unit)

    def contains(self, value):
        """Boolean array: finite and inside (traceable)."""
        return in_range(value, self.lo, self.hi, lo_open=self.lo_open, hi_open=self.hi_open)


def as_float(value, name: str, valid="", dtype=None):
    """`value` as a float array, or a `ValueError` naming the field when it is not a real number (or an array of
    them): bools, strings, None, complex numbers and objects are rejected, not coerced. Tracers pass through."""
    if isinstance(value, jax.core.Tracer) or (isinstance(value, jax.Array) and jnp.issubdtype(value.dtype, jnp.floating)):
        # Already a float array (e.g. millions of sampled drops): no copy to the host to inspect it.
        return jnp.asarray(value, dtype=dtype or float_dtype())
    where = f"; valid: {valid}" if str(valid) else ""
    if isinstance(value, (bool, np.bool_, str, bytes)) or value is None:
        raise ValueError(f"{name} = {value!r} is a {type(value).__name__}, not a number{where}")
    try:
        arr = np.asarray(value)
    except Exception:  # ragged lists and the like
        raise ValueError(f"{name} = {value!r} is not a number or an array of numbers{where}") from None
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        kind = "bool" if arr.dtype == bool else str(arr.dtype)
        raise ValueError(f"{name} = {value!r} holds {kind} values, not real numbers{where}")
    return jax.device_put(arr.astype(dtype or float_dtype()))  # converted on the host: no program to compile


def as_int(value, name: str, lo: int = 1, hi: int | None = None) -> int:
    """A Python int in [lo, hi] (bools and floats rejected), or a `ValueError` naming the field."""
    valid = f"an int >= {lo}" if hi is None else f"an int in [{lo}, {hi}]"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} = {value!r}; valid: {valid}")
    if value < lo or (hi is not None and value > hi):
        raise ValueError(f"{name} = {value!r}; valid: {valid}")
    return int(value)


def as_real(value, name: str, valid: Range) -> float:
    """A Python float inside `valid` (bools and strings rejected), or a `ValueError` naming the field."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} = {value!r}; valid: a number in {valid}")
    valid.require(float(value), name)
    return float(value)


def flag_if(condition, flag: Flag):
    """`flag` where `condition` holds, else 0, as an int32 array (traceable)."""
    return jnp.where(condition, jnp.int32(flag.value), jnp.int32(0))


def combine(*flags):
    """Bitwise-or of flag arrays (broadcasting)."""
    out = jnp.int32(0)
    for f in flags:
        out = out | jnp.asarray(f, jnp.int32)
    return out


def raise_if_flagged(flags, what: str) -> None:
    """Eagerly turn a concrete non-zero flag mask into a `ValueError` listing the problems."""
    if not is_concrete(flags):
        return
    value = np.bitwise_or.reduce(np.asarray(flags, dtype=np.int64).ravel()) if np.ndim(flags) else int(flags)
    if value:
        raise ValueError(f"{what}: {', '.join(Flag.describe(value))}")


GRAVITY = 9.80665
"""Standard gravity, m/s^2."""

DEG = math.pi / 180.0

IMPULSE_DURATION = 1e-12
"""A contact duration (s) at or below which the contact is an ideal impulse. A board's modes (below 1e6 rad/s)
cannot tell such a pulse from an impulse (they differ by (omega tau)^2 < 1e-12), and the half-sine's amplitude
pi / (2 tau), its rate and their derivatives (up to 1 / tau^3) would overflow for tinier ones, float32 included
(a 1e-292 s pulse gave a peak of 0 and NaN gradients)."""


def is_pulse(duration):
    """Whether a contact of `duration` (s) is a half-sine pulse rather than an ideal impulse
    (`IMPULSE_DURATION`)."""
    return duration > IMPULSE_DURATION


def pulse_duration(duration):
    """`duration` where it is a pulse (`is_pulse`), else 1: a stand-in to divide by, so that the branch not taken
    keeps finite gradients."""
    return jnp.where(is_pulse(duration), duration, 1.0)


def float_dtype():
    """The float dtype JAX uses now: float64 with x64 enabled, float32 otherwise (asks for no truncation)."""
    return jax.dtypes.canonicalize_dtype(jnp.float64)
