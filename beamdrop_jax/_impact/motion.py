"""What the board's supports do: an ideal velocity jump, a half-sine pulse, or a measured acceleration record.

Each support's normal acceleration is a(t) = dv g(t) with the integral of g equal to 1 (for `Impulse` and
`HalfSine`), or a sampled record (`Record`). Velocities in m/s, accelerations in m/s^2, times in s.

**Three rigid-motion inputs.** The supports move with the housing, rigidly: over the board the normal motion is
w(x, y) = w_A (1 - x/L) + w_B x/L + w_R y/W, with ends A and B on the centre line and y across the width (a plate's;
along the housing's depth axis e3). `dvA`, `dvB` and the roll `dvR` (the side y = +W/2's jump less the side
y = -W/2's) are those inputs' velocity jumps; a plane drop has dvR = 0, and a beam, which has no width, ignores it.
Accelerations and jumps are 3-vectors (A, B, R).
"""

import abc
import math
from pathlib import Path
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._common.checks import float_dtype
from .._common.checks import GRAVITY, is_concrete, is_pulse, pulse_duration, require


def _f(x):
    return jnp.asarray(x, dtype=float_dtype())


class AbstractMotion(eqx.Module):
    """What the response needs from a support motion: the first velocity jumps, the pulses (for the closed
    form), the forcing (for diffrax), a duration that sets the modes kept, and when the forcing ends.

    `METHODS` lists the `Numerics.method`s that can solve it."""

    METHODS: ClassVar[tuple[str, ...]] = ("closed_form", "diffrax")

    @abc.abstractmethod
    def acceleration(self, t) -> Float[Array, "3"]:
        """(aA, aB, aR) at time t, m/s^2."""

    @abc.abstractmethod
    def first_jumps(self) -> Float[Array, "3"]:
        """(dvA, dvB, dvR) of the first pulse (of the whole record), m/s."""

    @abc.abstractmethod
    def pulse_duration(self) -> Float[Array, ""]:
        """The duration of one pulse (of the whole record), s: it sets the modes the response keeps."""

    @property
    @abc.abstractmethod
    def end_time(self):
        """When the forcing ends, s."""

    def window_forcing(self) -> Float[Array, ""]:
        """How long the forcing lasts after a search window's start (one per pulse), s."""
        return self.pulse_duration()

    def pulses(self) -> tuple[Float[Array, "K 3"], Float[Array, " K"], Float[Array, ""]]:
        """(jumps (K, 3), start times (K,), duration) of the half-sine pulses that make the motion, for the
        closed form (a single pulse: K = 1 at t = 0)."""
        pulse = self.as_half_sine()
        return pulse.first_jumps()[None], jnp.zeros(1, dtype=pulse.duration.dtype), pulse.duration

    def pulse_times(self) -> Float[Array, " K"]:
        """Start times of the pulses (s); each has a search window of its own."""
        return self.pulses()[1]

    def forcing(self, modal_jumps, window):
        """For the diffrax path: (initial modal velocities per unit of `modal_jumps` (a function of (dvA, dvB, dvR)),
        the acceleration function, the forcing's kinks to step onto, the largest step)."""
        pulse = self.as_half_sine()
        pulsed = is_pulse(pulse.duration)
        v0 = jnp.where(pulsed, 0.0, modal_jumps(pulse.first_jumps()))
        # The pulse's end is a kink in the forcing: step onto it exactly (DESIGN: declare it as a jump time).
        jumps = jnp.where(pulsed, pulse.duration, window)[None]
        # A pulse starts at zero force from rest: the initial step-size guess sees no motion and a low-order
        # solver's error estimate can step over the whole pulse (ImplicitEuler did, returning ~0). Cap the step.
        dtmax = jnp.where(pulsed, pulse.duration / 8, window)
        return v0, pulse.acceleration, jumps, dtmax


class Impulse(AbstractMotion):
    """Ideal impulse: the supports' normal velocities jump by `dvA`, `dvB` at t = 0 (the thesis's model), and a
    plate's across its width by the roll `dvR` (module notes)."""

    dvA: Float[Array, ""]
    dvB: Float[Array, ""]
    dvR: Float[Array, ""]

    def __init__(self, dvA, dvB, dvR=0.0):
        self.dvA = _f(dvA)
        self.dvB = _f(dvB)
        self.dvR = _f(dvR)

    def __check_init__(self):
        require(self.dvA, "Impulse.dvA", unit="m/s")
        require(self.dvB, "Impulse.dvB", unit="m/s")
        require(self.dvR, "Impulse.dvR", unit="m/s")

    def as_half_sine(self) -> "HalfSine":
        return HalfSine(self.dvA, self.dvB, 0.0, self.dvR)

    def acceleration(self, t) -> Float[Array, "3"]:
        return self.as_half_sine().acceleration(t)

    def first_jumps(self) -> Float[Array, "3"]:
        return jnp.stack([self.dvA, self.dvB, self.dvR])

    def pulse_duration(self) -> Float[Array, ""]:
        return jnp.zeros_like(self.dvA)

    @property
    def end_time(self):
        return jnp.zeros_like(self.dvA)


class HalfSine(AbstractMotion):
    """Half-sine pulse of `duration` tau at both supports: a(t) = dv pi/(2 tau) sin(pi t / tau) on [0, tau].

    The velocity change of each support is `dvA`, `dvB`, and a plate's across its width the roll `dvR` (module
    notes); `duration = 0` (or up to `IMPULSE_DURATION`) is the ideal impulse.
    """

    dvA: Float[Array, ""]
    dvB: Float[Array, ""]
    duration: Float[Array, ""]
    dvR: Float[Array, ""]

    def __init__(self, dvA, dvB, duration, dvR=0.0):
        self.dvA = _f(dvA)
        self.dvB = _f(dvB)
        self.duration = _f(duration)
        self.dvR = _f(dvR)

    def __check_init__(self):
        require(self.dvA, "HalfSine.dvA", unit="m/s")
        require(self.dvB, "HalfSine.dvB", unit="m/s")
        require(self.dvR, "HalfSine.dvR", unit="m/s")
        require(self.duration, "HalfSine.duration", 0.0, unit="s")

    @classmethod
    def from_peak(cls, peak_acceleration, duration) -> "HalfSine":
        """The same pulse at both supports from its peak acceleration (m/s^2), e.g. JESD22-B111 condition B:
        `HalfSine.from_peak(1500 * bd.GRAVITY, 0.5e-3)`. The velocity change is peak * 2 tau / pi."""
        require(duration, "HalfSine.duration", 0.0, lo_open=True, unit="s")
        require(peak_acceleration, "HalfSine peak_acceleration", unit="m/s^2")
        dv = _f(peak_acceleration) * 2.0 * _f(duration) / math.pi
        return cls(dv, dv, duration)

    def as_half_sine(self) -> "HalfSine":
        return self

    def first_jumps(self) -> Float[Array, "3"]:
        return jnp.stack([self.dvA, self.dvB, self.dvR])

    def pulse_duration(self) -> Float[Array, ""]:
        return self.duration

    def acceleration(self, t) -> Float[Array, "3"]:
        """(aA, aB, aR) at time t, m/s^2."""
        tau = self.duration
        on = (t >= 0) & (t <= tau) & is_pulse(tau)
        tau_safe = pulse_duration(tau)
        g = jnp.where(on, math.pi / (2 * tau_safe) * jnp.sin(math.pi * t / tau_safe), 0.0)
        return self.first_jumps() * g

    @property
    def end_time(self):
        return self.duration


class PulseTrain(AbstractMotion):
    """Half-sine pulses of one `duration` starting at `times` (K,) (s, non-decreasing), pulse i changing the
    supports' normal velocities by `dvA[i]`, `dvB[i]` and the roll `dvR[i]` (m/s; zeros when left out): the
    supports' motion in a clattering drop. The board is linear, so its response is the sum of each pulse's response
    shifted to its time. Closed form only."""

    METHODS: ClassVar[tuple[str, ...]] = ("closed_form",)

    times: Float[Array, " K"]
    dvA: Float[Array, " K"]
    dvB: Float[Array, " K"]
    duration: Float[Array, ""]
    dvR: Float[Array, " K"]

    def __init__(self, times, dvA, dvB, duration, dvR=None):
        self.times = jnp.atleast_1d(_f(times))
        self.dvA = jnp.atleast_1d(_f(dvA))
        self.dvB = jnp.atleast_1d(_f(dvB))
        self.duration = _f(duration)
        self.dvR = jnp.zeros_like(self.dvA) if dvR is None else jnp.atleast_1d(_f(dvR))

    def __check_init__(self):
        if is_concrete(self.times, self.dvA, self.dvB, self.dvR):
            if not (np.shape(self.times) == np.shape(self.dvA) == np.shape(self.dvB) == np.shape(self.dvR)):
                raise ValueError(
                    f"PulseTrain.times, dvA, dvB and dvR need one shape, got {np.shape(self.times)}, "
                    f"{np.shape(self.dvA)}, {np.shape(self.dvB)}, {np.shape(self.dvR)}"
                )
            require(self.times, "PulseTrain.times", 0.0, unit="s")
            if np.any(np.diff(np.asarray(self.times)) < 0):
                raise ValueError("PulseTrain.times must be non-decreasing")
        require(self.dvA, "PulseTrain.dvA", unit="m/s")
        require(self.dvB, "PulseTrain.dvB", unit="m/s")
        require(self.dvR, "PulseTrain.dvR", unit="m/s")
        require(self.duration, "PulseTrain.duration", 0.0, unit="s")

    def acceleration(self, t) -> Float[Array, "3"]:
        """(aA, aB, aR) at time t, m/s^2."""
        shape = HalfSine(1.0, 1.0, self.duration).acceleration(t - self.times)[0]
        return self.pulses()[0].T @ shape

    @property
    def end_time(self):
        return self.times[-1] + self.duration

    def first_jumps(self) -> Float[Array, "3"]:
        return self.pulses()[0][0]

    def pulse_duration(self) -> Float[Array, ""]:
        return self.duration

    def pulses(self):
        return jnp.stack([self.dvA, self.dvB, self.dvR], -1), self.times, self.duration

    def forcing(self, modal_jumps, window):
        raise ValueError('a PulseTrain support motion needs Numerics(method="closed_form")')


JESD22_B111_CONDITION_B = (1500.0 * GRAVITY, 0.5e-3)
"""(peak acceleration m/s^2, duration s) of JESD22-B111 service condition B."""


class Record(AbstractMotion):
    """A measured support-acceleration record: samples `t` (s, increasing), `aA`, `aB` and the roll `aR` (m/s^2;
    zeros when left out), linearly interpolated and zero outside [t[0], t[-1]]. Needs the diffrax path
    (`Numerics(method="diffrax")`)."""

    METHODS: ClassVar[tuple[str, ...]] = ("diffrax",)

    t: Float[Array, " n"]
    aA: Float[Array, " n"]
    aB: Float[Array, " n"]
    aR: Float[Array, " n"]

    def __init__(self, t, aA, aB, aR=None):
        self.t = _f(t)
        self.aA = _f(aA)
        self.aB = _f(aB)
        self.aR = jnp.zeros_like(self.aA) if aR is None else _f(aR)

    def __check_init__(self):
        if is_concrete(self.t, self.aA, self.aB, self.aR):
            n = np.shape(self.t)
            if len(n) != 1 or n[0] < 2:
                raise ValueError(f"Record.t needs at least 2 samples in a 1-D array, got shape {n}")
            if np.shape(self.aA) != n or np.shape(self.aB) != n or np.shape(self.aR) != n:
                raise ValueError(
                    f"Record.aA, Record.aB and Record.aR must have the shape of Record.t {n}, got "
                    f"{np.shape(self.aA)}, {np.shape(self.aB)} and {np.shape(self.aR)}"
                )
            require(self.t, "Record.t", 0.0, unit="s")
            require(self.aA, "Record.aA", unit="m/s^2")
            require(self.aB, "Record.aB", unit="m/s^2")
            require(self.aR, "Record.aR", unit="m/s^2")
            if not np.all(np.diff(np.asarray(self.t)) > 0):
                raise ValueError("Record.t must be strictly increasing")

    @classmethod
    def from_csv(cls, path, *, time_unit: float = 1.0, acceleration_unit: float = 1.0) -> "Record":
        """Load a CSV with columns t, aA, aB (a header line is skipped). Scale with `time_unit` (e.g. 1e-3 for ms)
        and `acceleration_unit` (e.g. `bd.GRAVITY` for g)."""
        text = Path(path).read_text().strip().splitlines()
        rows = [line for line in text if line.strip() and not line.lstrip().startswith("#")]
        try:
            float(rows[0].split(",")[0])
        except ValueError:
            rows = rows[1:]
        data = np.array([[float(v) for v in line.split(",")[:3]] for line in rows]) if rows else np.zeros((0, 3))
        if data.ndim != 2 or data.shape[1] != 3:
            raise ValueError(f"{path}: expected three comma-separated columns t, aA, aB")
        return cls(data[:, 0] * time_unit, data[:, 1] * acceleration_unit, data[:, 2] * acceleration_unit)

    def acceleration(self, t) -> Float[Array, "3"]:
        inside = (t >= self.t[0]) & (t <= self.t[-1])
        return jnp.where(inside, jnp.stack([jnp.interp(t, self.t, a) for a in (self.aA, self.aB, self.aR)]), 0.0)

    @property
    def end_time(self):
        return self.t[-1]

    def first_jumps(self) -> Float[Array, "3"]:
        return self.velocity_jumps

    def pulse_duration(self) -> Float[Array, ""]:
        return self.t[-1] - self.t[0]

    def window_forcing(self) -> Float[Array, ""]:
        return self.end_time

    def pulses(self):
        raise ValueError('a Record support motion needs Numerics(method="diffrax") (it has no closed form)')

    def pulse_times(self) -> Float[Array, " K"]:
        return jnp.zeros(1, dtype=self.t.dtype)

    def forcing(self, modal_jumps, window):
        return jnp.zeros_like(modal_jumps(jnp.zeros(3, dtype=self.t.dtype))), self.acceleration, self.t, None

    @property
    def velocity_jumps(self) -> Float[Array, "3"]:
        """Integral of each input's acceleration (A, B, R; trapezoids), m/s."""
        return jnp.stack([jnp.trapezoid(a, self.t) for a in (self.aA, self.aB, self.aR)])


class LandingMotion(Record):
    """The supports' normal acceleration through a compliant landing (`Contact(model="compliant")`, or `"auto"`
    where corners strike together), sampled on [0, window] from the first touch: a `Record` whose modes and search
    window follow one corner contact's `duration` (as the rigid law's half-sine does), not the record's length.
    `weight` is the compliant landing's share where `"auto"` blends it with the rigid law's half-sine (1: the
    landing alone). Built by `landing_motion`; the board answers it in closed form per sample interval
    (`SampledModes`)."""

    duration: Float[Array, ""]
    weight: Float[Array, ""]

    def __init__(self, t, aA, aB, duration, weight=1.0, aR=None):
        super().__init__(t, aA, aB, aR)
        self.duration = _f(duration)
        self.weight = _f(weight)

    def pulse_duration(self) -> Float[Array, ""]:
        return self.duration

    def window_forcing(self) -> Float[Array, ""]:
        return self.duration

    def forcing(self, modal_jumps, window):
        # The samples' kinks are small and smooth out over a contact: the step controller crosses them (stepping
        # onto each of a thousand samples cost 8500 steps a drop; its largest step a quarter contact).
        v0, accel, _, _ = super().forcing(modal_jumps, window)
        return v0, accel, None, self.duration / 4
