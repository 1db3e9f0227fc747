"""From a scene (or a board and its support motion) to peak stress, strain and deflection.

`simulate` validates eagerly, then runs one compiled function: housing impact (and, with `max_impacts` > 1, the
clattering impacts that follow) -> support jumps -> support motion -> modal response (closed form or diffrax) ->
peaks and a convergence check.
"""

import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float, Int

from ._checks import float_dtype
from ._beam import curvature_scale, modal_velocity_jumps, mode_shapes, natural_frequencies, wavenumbers
from ._board import fundamental_period, free_phasor, pulse_phasors, unit_response, unit_response_jet
from ._trig import cexp, sincos
from ._checks import Flag, Range, as_float, as_int, as_real, combine, flag_if, is_concrete, raise_if_flagged, require
from ._impact import LAWS, ImpactResult
from ._integrate import SOLVERS, solve_modes
from ._clatter import MAX_ADVANCES, Ending, Impacts, impact_sequence
from ._kinematics import HousingImpact, housing_impact
from ._motion import HalfSine, Impulse, PulseTrain, Record
from ._peaks import FieldPeak, field_on_grid, find_peak, find_plate_peak, plate_starts, stop_gradient
from ._plate import (Plate, PlateModes, blank_readings, check_gauges, plate_grid_deflection, plate_modes, plate_notes,
                     raise_if_outside_theory, response_flags, surface_strain, surface_stress)
from ._scene import Board, Scene, check_scene, require_single, scene_flags
from ._compile import filter_jit

METHODS = ("closed_form", "diffrax")


class Numerics(eqx.Module):
    """How to compute the board's response (all fields are static configuration).

    - `method`: `"closed_form"` (exact modal response to an impulse or half-sine, damped or not) or `"diffrax"`
      (numerical; needed for a `Record` and for `stretching`).
    - `solver`, `rtol`, `atol`, `max_steps`: the diffrax solver by name (Tsit5, Dopri5, Dopri8, Kvaerno3,
      Kvaerno5, ImplicitEuler, Heun, Bosh3) and its PID controller.
    - `n_modes`: `None` picks the count from the scene (modes up to f_k tau >= `pulse_modes`, at least
      `min_modes`, at most `max_modes`) and checks it against twice as many, or `max_modes` when twice as many
      exceed it (half as many only when the count is at the cap);
      an int means exactly modes 1..n_modes, checked against half as many.
    - `window`: time window (s); `None` is the pulse duration plus one fundamental period. With several impacts
      it is the window searched after each impact (the free vibration between impacts repeats with the
      fundamental period when the axial force is 0, so one period after each pulse holds the peak).
    - `points_per_period`: time-grid points per period of the highest computed mode (N = 0 estimate);
      `x_points_per_mode`: spatial grid points per computed mode.
    - `refine`: Newton refinement of the grid's best `candidates` peaks (`newton_steps` each).
    - `convergence_rtol`: `converged` when the mode check changes the peak stress by less than this.
    - `stretching`: nonlinear mid-plane stretching for axially immovable supports (diffrax only).
    - `law`: restitution law of the housing impact.
    - `max_impacts`: impacts followed (1: the first corner impact only, the thesis's model; more: the housing
      flies freely after each impact and clatters onto the next corner, closed form only). `rest_speed` (m/s):
      a next impact approaching slower than this ends the sequence.
    """

    method: str = eqx.field(static=True, default="closed_form")
    solver: str = eqx.field(static=True, default="Tsit5")
    n_modes: int | None = eqx.field(static=True, default=None)
    max_modes: int = eqx.field(static=True, default=16)
    min_modes: int = eqx.field(static=True, default=4)
    pulse_modes: float = eqx.field(static=True, default=2.0)
    window: float | None = eqx.field(static=True, default=None)
    rtol: float = eqx.field(static=True, default=1e-8)
    atol: float = eqx.field(static=True, default=1e-12)
    max_steps: int = eqx.field(static=True, default=16384)
    points_per_period: int = eqx.field(static=True, default=4)
    x_points_per_mode: int = eqx.field(static=True, default=4)
    refine: bool = eqx.field(static=True, default=True)
    candidates: int = eqx.field(static=True, default=4)
    newton_steps: int = eqx.field(static=True, default=6)
    convergence_rtol: float = eqx.field(static=True, default=1e-3)
    stretching: bool = eqx.field(static=True, default=False)
    law: str = eqx.field(static=True, default="poisson")
    max_impacts: int = eqx.field(static=True, default=1)
    rest_speed: float = eqx.field(static=True, default=0.02)

    def __check_init__(self):
        def bad(field, value, valid):
            raise ValueError(f"Numerics.{field} = {value!r}; valid: {valid}")

        for name, choices in (("method", METHODS), ("solver", SOLVERS), ("law", LAWS)):
            if not (isinstance(getattr(self, name), str) and getattr(self, name) in choices):
                bad(name, getattr(self, name), ", ".join(choices))
        for name, flag in (("refine", self.refine), ("stretching", self.stretching)):
            if not isinstance(flag, bool):
                bad(name, flag, "True or False")
        if self.n_modes is not None:
            as_int(self.n_modes, "Numerics.n_modes", 1, 512)
        as_int(self.max_modes, "Numerics.max_modes", 2, 512)
        as_int(self.min_modes, "Numerics.min_modes", 1, self.max_modes)
        for name in ("points_per_period", "x_points_per_mode", "candidates", "max_steps", "max_impacts"):
            as_int(getattr(self, name), f"Numerics.{name}", 1)
        as_int(self.newton_steps, "Numerics.newton_steps", 0)
        if self.window is not None:
            as_real(self.window, "Numerics.window", Range(0.0, 10.0, lo_open=True, unit="s"))
        for name in ("rtol", "atol", "convergence_rtol"):
            as_real(getattr(self, name), f"Numerics.{name}", Range(0.0, 1.0, lo_open=True))
        as_real(self.pulse_modes, "Numerics.pulse_modes", Range(0.0, 100.0, lo_open=True))
        as_real(self.rest_speed, "Numerics.rest_speed", Range(0.0, lo_open=True, unit="m/s"))
        if self.max_impacts > 1 and self.method != "closed_form":
            raise ValueError(
                f"Numerics.max_impacts = {self.max_impacts} needs Numerics.method = \"closed_form\": the flight "
                "between impacts spans thousands of board periods, which the closed form skips exactly"
            )
        if self.stretching and self.method != "diffrax":
            raise ValueError('Numerics.stretching = True needs Numerics.method = "diffrax" (it has no closed form)')

    @property
    def computed_modes(self) -> int:
        return self.max_modes if self.n_modes is None else self.n_modes

    def grid_shape(self) -> tuple[int, int]:
        """(nx, nt): with N = 0 mode k makes k^2 oscillations per fundamental period, so the top mode needs about
        M^2 + a few periods over the default window."""
        M = self.computed_modes
        return self.x_points_per_mode * M + 1, self.points_per_period * (M * M + 8) + 1


class Peak(eqx.Module):
    """Peak bending response over the board and the window.

    `stress` (Pa), `strain` (-), where (`x` from end A, m) and when (`t`, s); `deflection` (m, relative to the
    chord AB) with its own `deflection_x`, `deflection_t`; `search_error`: relative error estimate of the stress
    peak search. With mid-plane stretching (`Numerics(stretching=True)`) `stress` and `strain` are those of the
    face in tension, bending plus membrane, and `membrane_stress` (Pa) is the membrane part at the peak (0
    without stretching). On a plate `stress` and `strain` are the largest principal surface values, `y` and
    `deflection_y` (m, from the centre line) say where across the width (0 for a beam)."""

    stress: Float[Array, ""]
    membrane_stress: Float[Array, ""]
    strain: Float[Array, ""]
    x: Float[Array, ""]
    t: Float[Array, ""]
    deflection: Float[Array, ""]
    deflection_x: Float[Array, ""]
    deflection_t: Float[Array, ""]
    search_error: Float[Array, ""]
    y: Float[Array, ""]
    deflection_y: Float[Array, ""]


class Response(eqx.Module):
    """What a drop does to the board.

    - `impulse`: the housing's first `ImpactResult` (None from `board_response`); `housing`: its `HousingImpact`.
    - `impacts`: every impact of the drop (`Impacts`; one unless `Numerics.max_impacts` > 1).
    - `support_jumps`: (dvA, dvB) of the first impact, m/s, normal to the board.
    - `peak`: a `Peak`.
    - `frequencies`: natural frequencies of the computed modes, Hz.
    - `n_modes`: modes in the reported peak; `check_modes`: modes of the convergence check.
    - `error_estimate`: |peak(n_modes) - peak(check_modes)| / peak(n_modes), relative, for the stress.
    - `converged`: `error_estimate <= Numerics.convergence_rtol`.
    - `window`: time window, s (to one fundamental period after the last impact's pulse). `flags`: `Flag` mask (0 = valid; otherwise the peak fields are NaN).
    - `gauges`: strain gauge readings (`Gauges`) at the points asked for (plates; None otherwise); `is_plate`.
    """

    impulse: ImpactResult | None
    housing: HousingImpact | None
    impacts: Impacts | None
    support_jumps: Float[Array, "2"]
    peak: Peak
    frequencies: Float[Array, " n"]
    n_modes: Int[Array, ""]
    check_modes: Int[Array, ""]
    error_estimate: Float[Array, ""]
    converged: Bool[Array, ""]
    window: Float[Array, ""]
    flags: Int[Array, ""]
    gauges: "Gauges | None" = None
    is_plate: bool = eqx.field(static=True, default=False)

    def summary(self) -> dict:
        """The numbers of one response, units in the keys (JSON-ready with `plain`; `repr` prints them)."""
        from ._impact import ImpactMode
        from ._report import plain

        if jnp.ndim(self.peak.stress) or not is_concrete(self):
            raise ValueError("Response.summary() needs one concrete response (index a batched one first)")
        r = jax.device_get(self)  # NumPy from here: arithmetic on the host, no small programs to compile
        p = r.peak
        out = {}
        if r.impulse is not None:
            flat = r.housing is not None and bool(r.housing.flat)
            out["impulse_Ns"] = r.impulse.P
            out["contact_mode"] = "flat landing (translation)" if flat else ImpactMode(int(r.impulse.mode)).label
        if r.impacts is not None and int(r.impacts.count) > 1:
            out["impacts"] = int(r.impacts.count)
        out |= {
            "support_jumps_m_per_s": r.support_jumps,
            "frequencies_Hz": r.frequencies[:4],
            "n_modes": r.n_modes,
            "check_modes": r.check_modes,
            "peak_stress_MPa": p.stress / 1e6,
            "peak_strain_microstrain": p.strain * 1e6,
            **({"peak_membrane_stress_MPa": p.membrane_stress / 1e6} if float(p.membrane_stress) else {}),
            "peak_stress_x_mm": p.x * 1e3,
            **({"peak_stress_y_mm": p.y * 1e3} if r.is_plate else {}),
            "peak_stress_t_ms": p.t * 1e3,
            "peak_deflection_mm": p.deflection * 1e3,
            "peak_deflection_x_mm": p.deflection_x * 1e3,
            **({"peak_deflection_y_mm": p.deflection_y * 1e3} if r.is_plate else {}),
            "peak_deflection_t_ms": p.deflection_t * 1e3,
            "converged": r.converged,
            "mode_check_relative_change": r.error_estimate,
            "window_ms": r.window * 1e3,
            "flags": Flag.describe(r.flags),
        }
        if r.gauges is not None:
            out["gauge_peak_strain_microstrain"] = r.gauges.peak_strain * 1e6
            out["gauge_peak_time_ms"] = r.gauges.peak_time * 1e3
        return plain(out)


    def __repr__(self) -> str:
        from ._report import summary_text

        try:
            return summary_text(self.summary(), "Response (x from end A, t from the first impact)")
        except ValueError:
            return eqx.tree_pformat(self)


class ClosedFormModes(eqx.Module):
    """q_k(t) = sum_i beta_ik R_k(t - t_i): exact modal response to half-sine (or ideal impulse) pulses at the
    supports starting at `times` t_i, pulse i leaving modal velocities `beta[i]`."""

    omega: Float[Array, " n"]
    zeta: Float[Array, ""]
    duration: Float[Array, ""]
    beta: Float[Array, "K n"]
    times: Float[Array, " K"]

    def _since(self, t):
        return jnp.asarray(t)[..., None, None] - self.times[:, None]

    def __call__(self, t) -> Float[Array, " n"]:
        return jnp.sum(self.beta * unit_response(self._since(t), self.omega, self.zeta, self.duration), axis=-2)

    def jet(self, t):
        """(q, q', q'') at time t, each (n,)."""
        since = self._since(t)
        started = since >= 0  # the impulse's jet is not zero before its pulse
        jets = unit_response_jet(since, self.omega, self.zeta, self.duration)
        return tuple(jnp.sum(jnp.where(started, self.beta * r, 0.0), axis=-2) for r in jets)

    def for_search(self) -> "eqx.Module":
        """The same modal response, prepared for many `jet` calls (`find_peak`'s Newton steps): a pulse train as
        `_TrainJet`, one pulse as itself."""
        return self if self.times.shape[0] == 1 else _TrainJet.of(self)

    def grid_factors(self, t):
        """(scale, R) with q_k(t_j) = scale_k R[j, k]. With one pulse R depends only on the board and the pulse
        (scale = beta), which lets batched drops share it."""
        if self.beta.shape[0] == 1:
            R = jax.vmap(lambda s: unit_response(s - self.times[0], self.omega, self.zeta, self.duration))(t)
            return self.beta[0], R
        return jnp.ones_like(self.omega), jax.vmap(self)(t)

    def _pairs(self):
        """The pairs (i, l) of pulses, l < i (pulse l acts on window i): `later` i and `earlier` l (static),
        their lags t_i - t_l (P,), the free phasors Zf(lag) and, for a pulse still running at a later window's
        start, its exact continuation less the free one, D = Z(lag) - Zf(lag) (P, n), and sin, cos(Omega lag).
        The grid's factors and the search's jets use the same (one evaluation in the compiled program)."""
        K = self.times.shape[0]
        later, earlier = (np.asarray(v, dtype=int) for v in zip(*[(i, l) for i in range(K) for l in range(i)]))
        lags = self.times[later] - self.times[earlier]
        Z_free, _, _ = free_phasor(lags, self.omega, self.zeta, self.duration)
        Z_lag, _, _, _, Omega = pulse_phasors(lags[:, None], self.omega, self.zeta, self.duration)
        sin_lag, cos_lag = sincos(Omega * lags)
        return later, earlier, lags, Z_free, Z_lag - Z_free, sin_lag, cos_lag

    def train_grid_factors(self, s, overlap_points: int):
        """(ones, R) on a pulse train's search grid t = times[i] + s[j] (window i, R of shape (K nt, n)), each
        window cut at the next pulse's start (R = 0 there; the next window covers those times), so that only
        earlier pulses act on it. The pulse's own response, the free-vibration factors e^{lam s} and the running
        pulse's factors (`pulse_phasors`) depend only on the board and the pulse: batched drops share them. An
        earlier pulse acts as free vibration, Im(Z e^{lam s}) / omega_d, except where it is still running
        (t_i - t_l + s < duration), corrected exactly there: on the first `overlap_points` of each window, or on
        all of them when the pulse is longer."""
        K, nt = self.times.shape[0], s.shape[0]
        Z_sin, Z_cos, lam, omega_d, Omega = pulse_phasors(s[:, None], self.omega, self.zeta, self.duration)
        own, own_cos = jnp.imag(Z_sin) / omega_d, jnp.imag(Z_cos) / omega_d  # (nt, n)
        # Im(Z e^{lam s}) / omega_d = Re(Z) decay_sin + Im(Z) decay_cos: real arithmetic per drop (XLA on CPU
        # does not vectorise complex arithmetic).
        decay = cexp(lam * s[:, None])
        decay_sin, decay_cos = jnp.imag(decay) / omega_d, jnp.real(decay) / omega_d
        later, earlier, lags, Z_free, D, sin_lag, cos_lag = self._pairs()
        acting = self.beta[earlier] * Z_free
        A = jnp.stack([jnp.zeros_like(acting[0])] + [jnp.sum(acting[later == i], axis=0) for i in range(1, K)])
        R = (self.beta[:, None, :] * own[None] + jnp.real(A)[:, None, :] * decay_sin[None]
             + jnp.imag(A)[:, None, :] * decay_cos[None])  # (i, j, n)

        def running(p):
            rows = [jnp.zeros_like(own[:p])] * K
            for q, (i, l) in enumerate(zip(later, earlier)):
                fix = self.beta[l] * (jnp.real(D[q]) * decay_sin[:p] + jnp.imag(D[q]) * decay_cos[:p]
                                      + cos_lag[q] * own[:p] + sin_lag[q] * own_cos[:p])
                rows[i] = rows[i] + jnp.where((lags[q] + s[:p] < self.duration)[:, None], fix, 0.0)
            return jnp.stack(rows)

        head = lambda: jnp.pad(running(overlap_points), ((0, 0), (0, nt - overlap_points), (0, 0)))  # noqa: E731
        R = R + jax.lax.cond(jnp.sum(s < self.duration) <= overlap_points, head, lambda: running(nt))
        cut = jnp.concatenate([self.times[1:], jnp.full((1,), jnp.inf, self.times.dtype)])
        inside = self.times[:, None] + s[None] < cut[:, None]
        return jnp.ones_like(self.omega), jnp.where(inside[..., None], R, 0.0).reshape(K * nt, -1)


class _TrainJet(eqx.Module):
    """A pulse train's jet from the last pulse i started by t, s = t - t_i: every pulse l <= i goes on as
    Z_l = Zf(lag) e^{lam s} (its free vibration, lag = t_i - t_l), corrected while it still runs (lag + s < tau)
    by the expansion of `pulse_phasors`. The sums over pulses are made once (`of`); a jet then costs one pulse
    response and one e^{lam s} per mode, whatever the number of pulses."""

    modes: ClosedFormModes
    lag: Float[Array, "K K"]  # (i, l): t_i - t_l where l <= i
    C: Complex[Array, "K n"]  # sum over l <= i of beta_l Zf(lag)
    D: Complex[Array, "K K n"]  # beta_l (Z(lag) - Zf(lag)): a running pulse's correction
    sin_lag: Float[Array, "K K"]
    cos_lag: Float[Array, "K K"]

    @classmethod
    def of(cls, modes: ClosedFormModes) -> "_TrainJet":
        K, n = modes.beta.shape
        later, earlier, lags, Z_free, D, sin_lag, cos_lag = modes._pairs()
        # A pulse on its own window: lag 0, Z(0) = 0.
        Z0, _, _ = free_phasor(jnp.zeros(()), modes.omega, modes.zeta, modes.duration)
        diag = np.arange(K)
        lag = jnp.zeros((K, K), lags.dtype).at[later, earlier].set(lags)
        Zf = jnp.zeros((K, K, n), Z_free.dtype).at[later, earlier].set(Z_free).at[diag, diag].set(Z0)
        D_all = jnp.zeros((K, K, n), D.dtype).at[later, earlier].set(D).at[diag, diag].set(-Z0)
        sin_all = jnp.zeros((K, K), lags.dtype).at[later, earlier].set(sin_lag)
        cos_all = jnp.ones((K, K), lags.dtype).at[later, earlier].set(cos_lag)
        return cls(modes, lag, jnp.sum(modes.beta * Zf, axis=1), modes.beta * D_all, sin_all, cos_all)

    def __call__(self, t):
        return self.modes(t)

    def jet(self, t):
        """(q, q', q'') at time t (a scalar), each (n,)."""
        m = self.modes
        K = m.times.shape[0]
        i = jnp.clip(jnp.sum(m.times <= t) - 1, 0, K - 1)
        s = jnp.maximum(t - m.times[i], 0.0)
        Z_sin, Z_cos, lam, omega_d, Omega = pulse_phasors(s, m.omega, m.zeta, m.duration)
        E = cexp(lam * s)
        sin_s, cos_s = sincos(Omega * s)
        is_pulse = m.duration > 0
        amp = jnp.where(is_pulse, math.pi / (2.0 * jnp.where(is_pulse, m.duration, 1.0)), 0.0)
        sin_lag, cos_lag = self.sin_lag[i][:, None], self.cos_lag[i][:, None]
        running = ((jnp.arange(K) <= i) & (self.lag[i] + s < m.duration) & is_pulse)[:, None]  # (l, 1)
        W = self.C[i] * E + jnp.sum(jnp.where(running, self.D[i] * E + m.beta * (cos_lag * Z_sin + sin_lag * Z_cos),
                                              0.0), axis=0)
        # The running pulses' forcing sin(Omega (lag + s)) and its rate, expanded.
        g = jnp.sum(jnp.where(running, m.beta * amp * (sin_lag * cos_s + cos_lag * sin_s), 0.0), axis=0)
        dg = jnp.sum(jnp.where(running, m.beta * amp * Omega * (cos_lag * cos_s - sin_lag * sin_s), 0.0), axis=0)
        dW = lam * W + g
        ddW = lam * dW + dg
        started = t >= m.times[0]
        return tuple(jnp.where(started, jnp.imag(v) / omega_d, 0.0) for v in (W, dW, ddW))


def support_motion(scene: Scene, jumps) -> HalfSine:
    """The supports' motion in a drop: a half-sine of the contact's duration (an ideal impulse when it is 0)."""
    return HalfSine(jumps[0], jumps[1], scene.contact.duration)


def _pulse_duration(motion):
    if isinstance(motion, Record):
        return motion.t[-1] - motion.t[0]
    return motion.duration if isinstance(motion, PulseTrain) else motion.as_half_sine().duration


def _mode_counts(board: Board, motion, numerics: Numerics):
    M = numerics.computed_modes
    if numerics.n_modes is not None:
        return jnp.int32(M), jnp.int32(max(M // 2, 1))
    duration = _pulse_duration(motion)
    f_tau = natural_frequencies(board, M) / (2 * math.pi) * duration
    needed = jnp.sum(f_tau < numerics.pulse_modes) + 1  # first k with f_k tau >= target
    used = jnp.clip(needed, numerics.min_modes, M).astype(jnp.int32)
    # Check against more modes whenever the cap leaves any (twice as many when it allows): half as many would
    # measure the error of the smaller model, not of the answer.
    check = jnp.where(used < M, jnp.minimum(2 * used, M), used // 2).astype(jnp.int32)
    return used, check


def _span(board: Board, motion, numerics: Numerics):
    """Window after each pulse's start (the whole window for a single pulse or a record)."""
    if numerics.window is not None:
        return jnp.asarray(numerics.window, dtype=float_dtype())
    end = motion.end_time if isinstance(motion, Record) else _pulse_duration(motion)
    return end + fundamental_period(board)


def _time_grid(board: Board, motion, numerics: Numerics, nt: int):
    """(window, t): for a pulse train, nt points after each pulse's start (the free vibration that follows is
    periodic in the fundamental period when N = 0, so its peak lies within one period of the pulse)."""
    span = _span(board, motion, numerics)
    unit = jnp.linspace(0.0, 1.0, nt)
    if isinstance(motion, PulseTrain):
        return motion.times[-1] + span, (motion.times[:, None] + unit * span).ravel()
    return span, unit * span


def _grid_factors(modal, board: Board, motion, numerics: Numerics, t):
    """`modal.grid_factors` on the search grid `t` of `_time_grid`; a pulse train's closed form by windows that
    share the board's factors between batched drops (`ClosedFormModes.train_grid_factors`)."""
    if isinstance(modal, ClosedFormModes) and isinstance(motion, PulseTrain) and motion.times.shape[0] > 1:
        nt = t.shape[0] // motion.times.shape[0]
        s = jnp.linspace(0.0, 1.0, nt) * _span(board, motion, numerics)
        return modal.train_grid_factors(s, overlap_points=max(nt // 8, 2))
    return modal.grid_factors(t)


def _modal_solution(board: Board, motion, numerics: Numerics, window, mask):
    M = numerics.computed_modes
    if numerics.method == "closed_form":
        if isinstance(motion, Record):
            raise ValueError('a Record support motion needs Numerics(method="diffrax") (it has no closed form)')
        if isinstance(motion, PulseTrain):
            jumps, times, duration = jnp.stack([motion.dvA, motion.dvB], -1), motion.times, motion.duration
        else:
            pulse = motion.as_half_sine()
            jumps, times, duration = jnp.stack([pulse.dvA, pulse.dvB])[None], jnp.zeros(1), pulse.duration
        beta = jax.vmap(lambda j: modal_velocity_jumps(board, j, M))(jumps) * mask
        omega = natural_frequencies(board, M)
        return ClosedFormModes(omega, board.damping_ratio, duration, beta, times), jnp.asarray(False)
    if isinstance(motion, PulseTrain):
        raise ValueError('a PulseTrain support motion needs Numerics(method="closed_form")')
    return solve_modes(
        board,
        motion,
        M,
        window,
        mask,
        solver=numerics.solver,
        rtol=numerics.rtol,
        atol=numerics.atol,
        max_steps=numerics.max_steps,
        stretching=numerics.stretching,
    )


class _Setup(NamedTuple):
    used: Array
    check: Array
    window: Array
    modal: eqx.Module
    failed: Array
    x: Array
    t: Array
    Q: Array
    k: Array
    curvature: Array
    flags: Array
    modes: "PlateModes | None"  # a plate's modes (None for a beam)


MIN_POINTS_PER_PERIOD = 2
"""Time-grid points per period of the top mode below which an explicit `Numerics.window` is flagged: the grid
then cannot see that mode's peaks and Newton refinement starts from the wrong ones."""


def _window_points(board: Board, numerics: Numerics, used):
    """Time-grid points per period of the top used mode over an explicit window (inf with the default window,
    which spans one fundamental period after the pulse and is sized for it)."""
    if numerics.window is None:
        return jnp.asarray(jnp.inf, dtype=float_dtype())
    omega = natural_frequencies(board, numerics.computed_modes)
    f_top = omega[jnp.clip(used, 1, numerics.computed_modes) - 1] / (2 * math.pi)
    return (numerics.grid_shape()[1] - 1) / (numerics.window * f_top)


def _raise_if_window(board: Board, motion, numerics: Numerics, flags, what: str, with_check: bool) -> None:
    """Eagerly, `Flag.WINDOW_RANGE` as a `ValueError` naming the field, its value and the valid range."""
    if not int(flags) & Flag.WINDOW_RANGE:
        return
    used, check = _mode_counts(board, motion, numerics)
    used = int(max(used, check) if with_check else used)
    points = float(_window_points(board, numerics, used))
    nt = numerics.grid_shape()[1]
    longest = numerics.window * points / MIN_POINTS_PER_PERIOD
    needed = math.ceil(numerics.points_per_period * MIN_POINTS_PER_PERIOD / points)
    raise ValueError(
        f"{what}: Numerics.window = {numerics.window:g} s leaves mode {used} (the highest computed) {points:.3g} "
        f"time-grid points per period ({nt} points in all; Flag.WINDOW_RANGE); valid: window <= {longest:.4g} s "
        f"with points_per_period = {numerics.points_per_period}, or points_per_period >= {needed} for this window"
    )


def _setup(board: Board, motion, numerics: Numerics, with_check: bool) -> _Setup:
    M = numerics.computed_modes
    # A plate's modes come from one eigensolve, shared by everything below.
    model = plate_modes(board, M) if isinstance(board, Plate) else board
    used, check = _mode_counts(model, motion, numerics)
    nx, nt = numerics.grid_shape()
    window, t = _time_grid(model, motion, numerics, nt)
    k = jnp.arange(1, M + 1)
    computed = jnp.maximum(used, check) if with_check else used
    modal, failed = _modal_solution(model, motion, numerics, window, (k <= computed).astype(float_dtype()))
    x = jnp.linspace(0.0, 1.0, nx) * board.length
    # With refinement the grid only picks the searches' starts: no gradient flows through it, so none is built.
    Q = (_grid_factors(*stop_gradient((modal, model, motion)), numerics, jax.lax.stop_gradient(t)) if numerics.refine
         else _grid_factors(modal, model, motion, numerics, t))
    top = jnp.maximum(used, check) if with_check else used
    flags = flag_if(_window_points(model, numerics, top) < MIN_POINTS_PER_PERIOD, Flag.WINDOW_RANGE)
    curvature = jnp.ones(M, dtype=float_dtype()) if isinstance(board, Plate) else curvature_scale(board, M)
    return _Setup(used, check, window, modal, failed, x, t, Q, k, curvature, flags,
                  model if isinstance(board, Plate) else None)


def _membrane(board: Board, numerics: Numerics, rows, is_curvature) -> Array | None:
    """Per row, the weights m_k of the membrane strain of mid-plane stretching, (1/4) sum_k (k pi/L)^2 q_k^2, in
    curvature units (divided by h/2) for curvature rows and zero for deflection rows; None without stretching."""
    if not numerics.stretching:
        return None
    kappa2 = wavenumbers(board, numerics.computed_modes) ** 2
    return jnp.stack([kappa2 / (2 * board.thickness) * (c != 0) * curv for c, curv in zip(rows, is_curvature)])


def _windows(modal) -> int:
    """Search windows: one per pulse of a closed-form pulse train (`_time_grid`)."""
    return modal.times.shape[0] if isinstance(modal, ClosedFormModes) else 1


def _search(setup: _Setup, board: Board, numerics: Numerics, coeffs, membrane=None, *, curvature,
            refine=None) -> FieldPeak:
    """Peaks of the fields with modal coefficients `coeffs` (rows; plus the membrane term of each row when
    `membrane` is given) over the board's curvature shapes (rows where `curvature`, a tuple of bools, is True) or
    deflection shapes, in one batched search (one compiled copy). `refine`: per row (a tuple of bools), refined or
    the grid's maximum; None: `numerics.refine`."""
    return find_peak(coeffs, setup.modal, setup.Q, setup.x, setup.t, board, setup.window, curvature=curvature,
                     membrane=membrane, candidates=numerics.candidates, newton_steps=numerics.newton_steps,
                     refine=numerics.refine if refine is None else refine, windows=_windows(setup.modal))


def _gauge_points(gauges):
    """Gauge points as an (g, 2) array, or None; a clear error for anything else."""
    if gauges is None:
        return None
    points = as_float(gauges, "gauges", Range(unit="m"))
    if points.ndim != 2 or points.shape[-1] != 2 or points.shape[0] < 1:
        raise ValueError(f"gauges has shape {points.shape}; valid: ((x, y), ...) in m, x from end A, y from the "
                         "centre line")
    return points


def _first_jumps(motion):
    """(dvA, dvB) of a support motion's first pulse."""
    if isinstance(motion, Record):
        return motion.velocity_jumps
    if isinstance(motion, PulseTrain):
        return jnp.stack([motion.dvA[0], motion.dvB[0]])
    pulse = motion.as_half_sine()
    return jnp.stack([pulse.dvA, pulse.dvB])


def _respond(board: Board, motion, numerics: Numerics, flags, gauges=None) -> Response:
    if isinstance(board, Plate):
        return _respond_plate(board, motion, numerics, flags, gauges)
    if gauges is not None:
        raise ValueError("gauges are read on plates (bd.Plate); a beam's strain along x is in bd.response_fields")
    S = _setup(board, motion, numerics, with_check=True)
    used, check, window, k, curvature, failed = S.used, S.check, S.window, S.k, S.curvature, S.failed
    M = numerics.computed_modes
    coeffs = jnp.stack([curvature * (k <= used), curvature * (k <= check), jnp.ones(M) * (k <= used)])
    rows = (True, True, False)
    peaks = _search(S, board, numerics, coeffs, _membrane(board, numerics, coeffs, rows), curvature=rows)
    kappa, kappa_check, deflection = (jax.tree_util.tree_map(lambda v: v[i], peaks) for i in range(3))
    error = jnp.abs(kappa.value - kappa_check.value) / jnp.maximum(kappa.value, jnp.finfo(window.dtype).tiny)

    half_h = board.thickness / 2
    # Valid inputs whose magnitudes overflow or underflow the arithmetic: a flag, never a silent NaN.
    nonfinite = ~jnp.isfinite(kappa.value) | ~jnp.isfinite(deflection.value)
    flags = combine(flags, board.flags(), S.flags, flag_if(failed, Flag.SOLVER_FAILED),
                    flag_if(nonfinite, Flag.NONFINITE_RESULT))
    bad = flags != 0
    nan = lambda v: jnp.where(bad, jnp.nan, v)  # noqa: E731 - flagged results are NaN, never a wrong number
    if numerics.stretching:
        q = S.modal(kappa.t) * (k <= used)
        membrane_strain = jnp.sum(wavenumbers(board, M) ** 2 * q * q) / 4
    else:
        membrane_strain = jnp.zeros_like(kappa.value)
    peak = Peak(
        stress=nan(board.youngs_modulus * half_h * kappa.value),
        membrane_stress=nan(board.youngs_modulus * membrane_strain),
        strain=nan(half_h * kappa.value),
        x=nan(kappa.x),
        t=nan(kappa.t),
        deflection=nan(deflection.value),
        deflection_x=nan(deflection.x),
        deflection_t=nan(deflection.t),
        search_error=kappa.error,
        y=jnp.zeros_like(kappa.x),
        deflection_y=jnp.zeros_like(kappa.x),
    )
    return Response(
        impulse=None,
        housing=None,
        impacts=None,
        support_jumps=_first_jumps(motion),
        peak=peak,
        frequencies=natural_frequencies(board, M) / (2 * math.pi),
        n_modes=used,
        check_modes=check,
        error_estimate=error,
        converged=(error <= numerics.convergence_rtol) & ~bad,
        window=window,
        flags=flags,
    )


class Gauges(eqx.Module):
    """Strain gauges on a plate's face z = +h/2 (where the peak is largest in magnitude both faces read the same
    magnitude): at points (`x`, `y`) (m), over the time grid `t` (s), the rosette components `exx`, `eyy`,
    `gxy` (engineering shear) and the largest principal strain magnitude `strain`, each (gauges, nt); and per
    gauge its `peak_strain` and `peak_time` (refined between grid points)."""

    x: Float[Array, " g"]
    y: Float[Array, " g"]
    t: Float[Array, " nt"]
    exx: Float[Array, "g nt"]
    eyy: Float[Array, "g nt"]
    gxy: Float[Array, "g nt"]
    strain: Float[Array, "g nt"]
    peak_strain: Float[Array, " g"]
    peak_time: Float[Array, " g"]

    def rosette(self, angle) -> Float[Array, "g nt"]:
        """The strain a gauge at `angle` (rad from the x axis) reads: exx cos^2 + eyy sin^2 + gxy sin cos."""
        c, s = math.cos(angle), math.sin(angle)
        return self.exx * c * c + self.eyy * s * s + self.gxy * s * c


def _plate_strain(plate, u, kxx, kyy, kxy):
    return surface_strain(plate, kxx, kyy, kxy)


def _plate_stress(plate, u, kxx, kyy, kxy):
    return surface_stress(plate, kxx, kyy, kxy)


def _plate_deflection(plate, u, kxx, kyy, kxy):
    return jnp.abs(u)


PLATE_MEASURES = {"stress": _plate_stress, "strain": _plate_strain, "deflection": _plate_deflection}


def _plate_grid(plate: Plate):
    """Normalised search grid (xi, eta): two points per basis function along each direction, edges included."""
    return jnp.linspace(0.0, 1.0, 2 * plate.basis[0] + 1), jnp.linspace(-0.5, 0.5, 2 * plate.basis[1] + 1)


def _plate_points(plate: Plate, modes):
    """The search grid (xi, eta), its points (x, y) (m, xi-major) and the mode shapes (phi, phi_xx, phi_yy, phi_xy)
    there."""
    xi, eta = _plate_grid(plate)
    XI, ETA = (v.ravel() for v in jnp.meshgrid(xi, eta, indexing="ij"))
    x, y = XI * plate.length, ETA * plate.width
    return xi, eta, (x, y), modes.shapes(x, y)


def _plate_searches(S: _Setup, plate: Plate, numerics: Numerics, modes, kinds: tuple[str, ...], mask, check=None,
                    fields=None):
    """Peaks of the measures `kinds` (of `PLATE_MEASURES`) of the field with modal mask `mask`: the fields on the
    grid once (or `fields`, (u, k_xx, k_yy, k_xy) on the grid, when the caller has them), each kind's own
    candidates, then one batched refinement (one compiled copy). With a second mask `check`, one more row: the
    first kind's peak with that mask, started at the first kind's candidate times (its fields are evaluated at
    those times alone: it measures the same peak with more modes)."""
    _, _, points, shapes = _plate_points(plate, modes)
    fields = [field_on_grid(mask, S.Q, v) for v in shapes] if fields is None else fields
    measures = [PLATE_MEASURES[k] for k in kinds]
    candidates = numerics.candidates if numerics.refine else 1
    starts = [plate_starts(plate, m, fields, points, candidates) for m in measures]
    masks = [mask] * len(kinds)
    if check is not None:
        scale, R = S.Q
        times = starts[0][0]
        at_times = [field_on_grid(check, (scale, R[times]), v) for v in shapes]
        starts.append(plate_starts(plate, measures[0], None, points, candidates, times, at_times))
        masks.append(check)
        measures.append(measures[0])
    xi, eta = _plate_grid(plate)

    def search(mask, which, *start):
        def measure(*args):
            return jnp.select([which == i for i in range(len(measures))], [m(*args) for m in measures])

        return find_plate_peak(measure, mask, S.modal, modes, xi, eta, S.t, S.window, start,
                               newton_steps=numerics.newton_steps, refine=numerics.refine)

    return jax.vmap(search)(jnp.stack(masks), jnp.arange(len(masks)), *(jnp.stack(v) for v in zip(*starts)))


def _gauges(plate: Plate, S: _Setup, modes, mask, points) -> Gauges:
    points = jnp.asarray(points, dtype=float_dtype())
    gx, gy = points[:, 0], points[:, 1]
    _, kxx, kyy, kxy = (field_on_grid(mask, S.Q, v) for v in modes.shapes(gx, gy))
    z = plate.thickness / 2
    strain = surface_strain(plate, kxx, kyy, kxy)
    # Peak time of each gauge: grid maximum, then Newton in t on the modal solution.
    j = strain.argmax(axis=1)

    def reading(x, y, t):
        q = S.modal(t) * mask
        _, a, b, c = (jnp.sum(q * v) for v in modes.shapes(x, y))
        return surface_strain(plate, a, b, c)

    dt = S.t[1] - S.t[0]
    offsets = jnp.array([-1.0, 0.0, 1.0]) * (dt / 16)

    def refine(x, y, t0):
        # Newton in t on derivatives from a three-point stencil (one batched evaluation, a small program); each
        # pass evaluates the pending time and keeps it if it gains.
        def step(carry, _):
            t, f, g, h, t_new = carry
            lo, mid, hi = jax.vmap(lambda s: reading(x, y, s))(t_new + offsets)
            g_new, h_new = (hi - lo) / (2 * offsets[2]), (hi - 2 * mid + lo) / offsets[2] ** 2
            better = mid > f
            t, f, g, h = (jnp.where(better, a, b) for a, b in zip((t_new, mid, g_new, h_new), (t, f, g, h)))
            move = jnp.where(h < 0, -g / jnp.where(h < 0, h, -1.0), 0.0)
            return (t, f, g, h, jnp.clip(t + jnp.clip(move, -dt, dt), 0.0, S.window)), None

        start = (t0, jnp.full_like(t0, -jnp.inf), jnp.zeros_like(t0), jnp.zeros_like(t0), t0)
        return jax.lax.scan(step, start, None, length=5)[0][0]

    t_peak = jax.lax.stop_gradient(jax.vmap(refine)(gx, gy, S.t[j]))
    peak = jnp.maximum(jax.vmap(reading)(gx, gy, t_peak), strain[jnp.arange(gx.shape[0]), j])
    return Gauges(gx, gy, S.t, -z * kxx, -z * kyy, -2 * z * kxy, strain, peak, t_peak)


def _respond_plate(plate: Plate, motion, numerics: Numerics, flags, gauges=None) -> Response:
    if numerics.stretching:
        raise ValueError("Numerics.stretching = True models pinned beams only, not plates")
    S = _setup(plate, motion, numerics, with_check=True)
    modes = S.modes
    used_mask = (S.k <= S.used).astype(float_dtype())
    found = _plate_searches(S, plate, numerics, modes, ("stress", "strain", "deflection"), used_mask,
                            check=(S.k <= S.check).astype(float_dtype()))
    stress, strain, deflection, check = (jax.tree_util.tree_map(lambda v: v[i], found) for i in range(4))
    error = jnp.abs(stress.value - check.value) / jnp.maximum(stress.value, jnp.finfo(S.window.dtype).tiny)
    nonfinite = ~jnp.isfinite(stress.value) | ~jnp.isfinite(deflection.value)
    flags = combine(flags, plate.flags(), S.flags, flag_if(S.failed, Flag.SOLVER_FAILED),
                    flag_if(nonfinite, Flag.NONFINITE_RESULT), response_flags(plate, deflection.value, gauges))
    bad = flags != 0
    nan = lambda v: jnp.where(bad, jnp.nan, v)  # noqa: E731
    peak = Peak(
        stress=nan(stress.value), membrane_stress=jnp.zeros_like(stress.value), strain=nan(strain.value),
        x=nan(stress.x), t=nan(stress.t), deflection=nan(deflection.value), deflection_x=nan(deflection.x),
        deflection_t=nan(deflection.t), search_error=stress.error, y=nan(stress.y), deflection_y=nan(deflection.y),
    )
    return Response(
        impulse=None, housing=None, impacts=None, support_jumps=_first_jumps(motion), peak=peak,
        frequencies=modes.frequencies() / (2 * math.pi), n_modes=S.used, check_modes=S.check, error_estimate=error,
        converged=(error <= numerics.convergence_rtol) & ~bad, window=S.window, flags=flags,
        gauges=None if gauges is None else blank_readings(_gauges(plate, S, modes, used_mask, gauges), bad),
        is_plate=True,
    )


@filter_jit
def _board_response_jit(board, motion, numerics, gauges):
    return _respond(board, motion, numerics, jnp.int32(0), gauges)


def board_response(board: Board | Plate, motion, numerics: Numerics | None = None, gauges=None) -> Response:
    """Peak response of a board (`Board` or `Plate`) to a support motion: `Impulse`, `HalfSine`, `PulseTrain`
    (closed form only) or `Record` (needs `Numerics(method="diffrax")`). On a plate, `gauges=((x, y), ...)` (m)
    reads strain gauges there (`Response.gauges`). Jit- and vmap-able."""
    if not isinstance(board, (Board, Plate)):
        raise TypeError(f"board must be a bd.Board or a bd.Plate, got {type(board).__name__}")
    numerics = Numerics() if numerics is None else numerics
    if not isinstance(motion, (Impulse, HalfSine, PulseTrain, Record)):
        raise TypeError(f"motion must be an Impulse, HalfSine, PulseTrain or Record, got {type(motion).__name__}")
    if isinstance(motion, PulseTrain) and numerics.method != "closed_form":
        raise ValueError('a PulseTrain support motion needs Numerics(method="closed_form")')
    if isinstance(motion, Record) and numerics.method != "diffrax":
        raise ValueError('a Record support motion needs Numerics(method="diffrax") (it has no closed form)')
    check_gauges(board, points := _gauge_points(gauges))
    response = _board_response_jit(board, motion, numerics, points)
    if is_concrete(board, motion, response.flags) and int(response.flags):
        board.__check_init__()
        raise_if_outside_theory(board, response.flags, "board_response")
        _raise_if_window(board, motion, numerics, response.flags, "board_response", with_check=True)
        raise_if_flagged(response.flags & ~Flag.SOLVER_FAILED, "board_response")
    return response


def drop_motion(scene: Scene, numerics: Numerics | None = None):
    """The supports' motion in a drop: `(motion, impacts, first, flags)` with `motion` a `HalfSine` (one impact)
    or a `PulseTrain` (`Numerics.max_impacts` > 1), `impacts` the `Impacts`, `first` the first `HousingImpact`
    and `flags` the impacts' `Flag` mask."""
    numerics = Numerics() if numerics is None else numerics
    impacts, first = impact_sequence(scene, numerics.max_impacts, numerics.rest_speed, numerics.law)
    if numerics.max_impacts == 1:
        motion = support_motion(scene, impacts.support_jumps[0])
    else:
        jumps = impacts.support_jumps
        motion = PulseTrain(impacts.t, jumps[:, 0], jumps[:, 1], scene.contact.duration)
    return motion, impacts, first, impacts.flags


def _simulate(scene: Scene, numerics: Numerics, gauges=None) -> Response:
    motion, impacts, hit, flags = drop_motion(scene, numerics)
    response = _respond(scene.board, motion, numerics, combine(scene_flags(scene), flags), gauges)
    return eqx.tree_at(
        lambda r: (r.impulse, r.housing, r.impacts), response, (hit.impact, hit, impacts), is_leaf=lambda x: x is None
    )


_simulate_jit = filter_jit(_simulate)


def _raise_eagerly(scene: Scene, numerics: Numerics, flags, impacts: Impacts | None, what: str,
                   with_check: bool = True):
    """The compiled run found a problem: the eager checks name the field and its valid range."""
    check_scene(scene)
    housing_impact(scene, law=numerics.law)
    raise_if_outside_theory(scene.board, flags, what)
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
    check_gauges(scene.board, points := _gauge_points(gauges))
    response = _simulate_jit(scene, numerics, points)
    if is_concrete(scene, response.flags) and int(response.flags):
        _raise_eagerly(scene, numerics, response.flags, response.impacts, "simulate")
    return response


QUANTITIES = ("stress", "strain", "deflection")


@filter_jit
def _scene_peaks(scene: Scene, numerics: Numerics, quantities: tuple[str, ...], grid_deflection: bool = False,
                 motion_and_flags=None):
    """Peaks of the requested quantities (stress, strain, deflection) sharing one modal solution and one batched
    search; returns (values (len(quantities),), flags). `grid_deflection` takes the deflection peak from the grid
    without refinement (Monte-Carlo's cheap option; it undershoots by the grid's resolution). `motion_and_flags`:
    the drop's `(motion, impact flags)` from `drop_motion` when computed already."""
    board = scene.board
    if motion_and_flags is None:
        motion, _, _, impact_flags = drop_motion(scene, numerics)
    else:
        motion, impact_flags = motion_and_flags
    S = _setup(board, motion, numerics, with_check=False)
    mask = (S.k <= S.used).astype(float_dtype())
    if isinstance(board, Plate):
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


def _scene_peak(scene: Scene, numerics: Numerics, quantity: str):
    floats, rest = eqx.partition(scene, eqx.is_inexact_array)
    return _peak_of_floats(floats, rest, numerics, quantity)


def _peak_value(scene: Scene, numerics: Numerics, quantity: str):
    values, flags = _scene_peaks(scene, numerics, (quantity,))
    return values[0], flags


# The derivative of a peak comes from one program that computes the value and its gradient together. Under an eager
# `jax.grad` that program runs at the top level, so it compiles with the package's compile options (a first
# `jax.grad(peak_stress)` 3.7 -> 2.6 s); JAX's own linearisation would stage it into the gradient's programs, where
# no options are allowed. The gradient is taken with respect to the fields whose tangents are not zero (symbolic
# zeros), so an objective of a few fields differentiates only those. The rule is written in JAX, so forward mode,
# `jit` and `vmap` work; a forward-mode derivative costs one reverse-mode gradient.
@functools.partial(jax.custom_jvp, nondiff_argnums=(1, 2, 3))
def _peak_of_floats(floats, rest, numerics: Numerics, quantity: str):
    return _peak_value(eqx.combine(floats, rest), numerics, quantity)


@filter_jit
def _peak_and_gradient(moving, fixed, numerics: Numerics, quantity: str):
    return jax.value_and_grad(lambda m: _peak_value(eqx.combine(m, fixed), numerics, quantity), has_aux=True)(moving)


@functools.partial(_peak_of_floats.defjvp, symbolic_zeros=True)
def _peak_jvp(rest, numerics, quantity, primals, tangents):
    zero = jax.custom_derivatives.SymbolicZero
    is_moving = jax.tree_util.tree_map(lambda t: not isinstance(t, zero), tangents[0],
                                       is_leaf=lambda t: isinstance(t, zero))
    moving, fixed = eqx.partition(primals[0], is_moving)
    (value, flags), gradient = _peak_and_gradient(moving, eqx.combine(fixed, rest), numerics, quantity)
    moving_tangents = eqx.filter(tangents[0], is_moving, is_leaf=lambda t: isinstance(t, zero))
    leaves = jax.tree_util.tree_leaves
    slope = sum((jnp.vdot(g, t) for g, t in zip(leaves(gradient), leaves(moving_tangents))), jnp.zeros_like(value))
    return (value, flags), (slope, np.zeros(np.shape(flags), jax.dtypes.float0))


def _peak(scene: Scene, numerics: Numerics | None, quantity: str):
    numerics = Numerics() if numerics is None else numerics
    require_single(scene, f"peak_{quantity}")
    value, flags = _scene_peak(scene, numerics, quantity)
    if is_concrete(scene, flags) and int(flags):
        clatter = int(flags) & (Flag.PIVOTING_CONTACT | Flag.SOLVER_FAILED) and numerics.max_impacts > 1
        impacts = drop_motion(scene, numerics)[1] if clatter else None
        _raise_eagerly(scene, numerics, flags, impacts, f"peak_{quantity}", with_check=False)
    return value


def peak_stress(scene: Scene, numerics: Numerics | None = None) -> Float[Array, ""]:
    """Peak bending stress (Pa) of a drop: a scalar, differentiable with respect to every float field of scene.

    Equals `simulate(scene, numerics).peak.stress` but computes only that peak (no deflection search, no mode
    check), so gradients and optimisers pay for nothing else. The gradient is the exact gradient of the piece the
    scene is on (lowest corner, Routh mode), taken at the maximiser (envelope theorem). At `Drop.height` = 0 the
    derivative with respect to the height is infinite (the impact speed is sqrt(2 g h)); everywhere else in the
    valid domain gradients are finite. Forward mode (`jax.jvp`) gives the same derivative. Second derivatives
    (`jax.hessian`) leave out how the maximiser moves, so they are not the peak's curvature."""
    return _peak(scene, numerics, "stress")


def peak_strain(scene: Scene, numerics: Numerics | None = None) -> Float[Array, ""]:
    """Peak bending strain (-) of a drop; differentiable like `peak_stress`."""
    return _peak(scene, numerics, "strain")


def peak_deflection(scene: Scene, numerics: Numerics | None = None) -> Float[Array, ""]:
    """Peak deflection relative to the chord AB (m) of a drop; differentiable like `peak_stress`."""
    return _peak(scene, numerics, "deflection")


class Fields(eqx.Module):
    """Deflection (m), strain (-) and stress (Pa) on a grid: arrays of shape (len(x), len(t))."""

    x: Float[Array, " nx"]
    t: Float[Array, " nt"]
    deflection: Float[Array, "nx nt"]
    strain: Float[Array, "nx nt"]
    stress: Float[Array, "nx nt"]


def response_fields(scene: Scene, numerics: Numerics | None = None, nx: int = 101, nt: int = 801,
                    x=None) -> Fields:
    """Deflection, strain and stress over (x, t) for a scene, with the modes `simulate` reports. `x`: positions
    from end A (m; default `nx` points over the board), e.g. strain gauges. With several impacts, `nt` times follow
    each impact (the window after each, as in the peak search).

    Strain and stress are signed: those of the face on the board normal's side (-(h/2) u_xx; positive is tension),
    plus the membrane strain with `Numerics(stretching=True)`.
    """
    numerics = Numerics() if numerics is None else numerics
    if isinstance(scene.board, Plate):
        raise ValueError("response_fields reads a beam along x; for a plate use bd.plate_strain_map (a map at one "
                         "time) and simulate(..., gauges=((x, y), ...)) (histories at points)")
    as_int(nx, "nx", 2)
    as_int(nt, "nt", 2)
    response = simulate(scene, numerics)
    length = float(scene.board.length)
    if x is None:
        x = as_float(np.linspace(0.0, 1.0, nx) * length, "x")  # on the host: no program to compile
    else:
        x = as_float(x, "x", f"positions on the board, [0, {length:g}] m").reshape(-1)
        require(x, "x", 0.0, length, unit="m")
    return _fields(scene, response, numerics, x, nt)


@filter_jit
def _fields(scene, response, numerics, x, nt):
    board = scene.board
    M = numerics.computed_modes
    motion = drop_motion(scene, numerics)[0]
    k = jnp.arange(1, M + 1)
    used = response.n_modes
    window, t = _time_grid(board, motion, numerics, nt)
    modal, _ = _modal_solution(board, motion, numerics, window, (k <= used).astype(float_dtype()))
    Q = modal.grid_factors(t)
    mask = (k <= used).astype(float_dtype())
    u = field_on_grid(mask, Q, mode_shapes(board, x, M))
    curvature = field_on_grid(curvature_scale(board, M) * mask, Q, mode_shapes(board, x, M, True))
    strain = -board.thickness / 2 * curvature
    if numerics.stretching:
        scale, R = Q
        strain = strain + ((R * scale * mask) ** 2 @ wavenumbers(board, M) ** 2 / 4)[None, :]
    return Fields(x, t, u, strain, board.youngs_modulus * strain)


def response_notes(scene: Scene, response: Response) -> list[str]:
    """What a reader of a drop's numbers should know: where the model's assumptions stop holding or the answer is
    not converged (an empty list when nothing needs saying)."""
    notes = []
    board, peak = scene.board, response.peak
    if float(scene.contact.duration) == 0.0:
        notes.append(f"ideal impulse (contact duration 0): the peak grows with the mode count and never converges "
                     f"(stopped at {int(response.n_modes)} modes); give Contact.duration a physical value "
                     "(0.05-1 ms)")
    elif not bool(response.converged):
        notes.append(f"not converged: {int(response.check_modes)} modes change the peak by "
                     f"{float(response.error_estimate) * 100:.2g} % (Numerics.convergence_rtol = "
                     "0.1 %); " + (
                         # A check with fewer modes means the count hit its cap.
                         "raise Numerics.max_modes" if int(response.check_modes) < int(response.n_modes)
                         else "raise Numerics.pulse_modes (modes up to f_k x duration >= 2 by default)"))
    if float(board.youngs_modulus) < 1e6 or float(board.thickness) > 0.05:
        notes.append(f"the board is not an engineering board (E = {float(board.youngs_modulus):.4g} Pa, thickness "
                     f"{float(board.thickness):.4g} m): the thesis scene's nondimensional units, so stresses in MPa "
                     "and strains in microstrain mean nothing physical here")
    elif float(peak.strain) > 0.01:
        notes.append(f"peak strain {float(peak.strain) * 100:.3g} % is beyond the elastic range of board materials")
    if float(peak.deflection) > float(board.thickness):
        notes.append(f"peak deflection {float(peak.deflection) / float(board.thickness):.2g} x the thickness: "
                     "linear (small-deflection) theory overestimates it; mid-plane stretching matters "
                     + ("(not modelled for plates yet)" if isinstance(board, Plate)
                        else "(Numerics(method=\"diffrax\", stretching=True))"))
    return notes + (plate_notes(board, response) if isinstance(board, Plate) else [])


class StrainMap(eqx.Module):
    """Largest principal surface strain over a plate at one time: `x` (nx,), `y` (ny,) (m), `strain` (nx, ny)
    (NaN inside the mount discs), `t` (s)."""

    x: Float[Array, " nx"]
    y: Float[Array, " ny"]
    strain: Float[Array, "nx ny"]
    t: Float[Array, ""]


def plate_strain_map(scene: Scene, response: Response, numerics: Numerics | None = None, t=None, nx: int = 133,
                     ny: int = 78) -> StrainMap:
    """The largest principal surface strain over a plate scene's board at time `t` (s; default: the peak stress's
    time), with the modes `response` (from `simulate(scene, numerics)`) used."""
    numerics = Numerics() if numerics is None else numerics
    if not isinstance(scene.board, Plate):
        raise ValueError("plate_strain_map needs a scene whose board is a bd.Plate")
    as_int(nx, "nx", 2)
    as_int(ny, "ny", 2)
    t = response.peak.t if t is None else as_float(t, "t", Range(0.0, unit="s"))
    return _strain_map(scene, numerics, response.n_modes, t, nx, ny)


@filter_jit
def _strain_map(scene, numerics, used, t, nx, ny):
    plate = scene.board
    M = numerics.computed_modes
    motion = drop_motion(scene, numerics)[0]
    mask = (jnp.arange(1, M + 1) <= used).astype(float_dtype())
    modes = plate_modes(plate, M)
    modal, _ = _modal_solution(modes, motion, numerics, _span(modes, motion, numerics), mask)
    x = jnp.linspace(0.0, 1.0, nx) * plate.length
    y = jnp.linspace(-0.5, 0.5, ny) * plate.width
    X, Y = jnp.meshgrid(x, y, indexing="ij")
    _, kxx, kyy, kxy = (v @ (modal(t) * mask) for v in modes.shapes(X, Y))
    strain = surface_strain(plate, kxx, kyy, kxy)
    if plate.mounts is not None:
        inside = jnp.any(jnp.hypot(X[..., None] - plate.mounts[:, 0], Y[..., None] - plate.mounts[:, 1])
                         < plate.mount_radius, axis=-1)
        strain = jnp.where(inside, jnp.nan, strain)
    return StrainMap(x, y, strain, jnp.asarray(t))
