"""Closed-form modal response to support motion: q_k'' + 2 zeta omega_k q_k' + omega_k^2 q_k = p_k . a(t) for an
ideal impulse or a half-sine pulse, whatever the board model that supplies omega_k and p_k (`_beam`)."""

import math

import jax
import jax.numpy as jnp

from .._board.base import natural_frequencies
from .._common.checks import float_dtype, is_pulse as _is_pulse, pulse_duration
from .._board.beam import Board

from .._common.trig import cexp, sincos


_SERIES_RADIUS = 0.1


def _phi(w):
    """(e^w - 1)/w for small complex w by its Taylor series (error < 1e-13 relative for |w| < 0.1)."""
    out = jnp.ones_like(w)
    for n in range(8, 0, -1):
        out = 1.0 + w * out / (n + 1)
    return out


def _cdiv(a, b):
    """a / b for complex b bounded away from 0 and overflow: one multiply by the conjugate (XLA's general complex
    division guards against both and compiles to many more operations)."""
    return a * jnp.conj(b) / (jnp.real(b) ** 2 + jnp.imag(b) ** 2)


def _response_phasor(t, omega, zeta, duration):
    """Z(t), lambda, omega_d and the pulse's switch, with the unit response q = Im(Z) / omega_d.

    For the half-sine, Z = (pi / (2 tau)) e^{lam (t - T)} I(T), T = min(t, tau), with
    I(T) = int_0^T e^{lam (T - s)} sin(Omega s) ds
         = (Omega T e^{i Omega T} phi(eps T) - sin(Omega T)) / (lam + i Omega), eps = lam - i Omega, phi(w) = (e^w - 1) / w: regular at resonance (eps = 0), where the textbook form
    (Omega e^{lam T} - lam sin - Omega cos) / (lam^2 + Omega^2) cancels; lam + i Omega never vanishes."""
    t = jnp.asarray(t, dtype=float_dtype())
    omega = jnp.asarray(omega)
    zeta = jnp.asarray(zeta)
    tau = jnp.asarray(duration)
    t_pos = jnp.maximum(t, 0.0)
    omega_d = omega * jnp.sqrt(1.0 - zeta**2)
    lam = jax.lax.complex(-zeta * omega, omega_d)

    is_pulse = _is_pulse(tau)
    tau_s = pulse_duration(tau)
    Omega = math.pi / tau_s
    T = jnp.where(is_pulse, jnp.minimum(t_pos, tau_s), 0.0)
    e_rest = cexp(lam * (t_pos - T))  # |.| <= 1: no overflow for heavy damping; e^{lam t} for the impulse
    sin, cos = sincos(Omega * T)
    w = (lam - 1j * Omega) * T
    small = jnp.abs(w) < _SERIES_RADIUS
    # Omega T e^{i Omega T} phi(w); directly Omega (e^{lam T} - e^{i Omega T}) / eps.
    e_omega = jax.lax.complex(cos, sin)
    direct = _cdiv(Omega * T * (cexp(lam * T) - e_omega), jnp.where(small, 1.0 + 0j, w))
    series = Omega * T * e_omega * _phi(jnp.where(small, w, 0j))
    integral = _cdiv(jnp.where(small, series, direct) - sin, lam + 1j * Omega)
    Z = jnp.where(is_pulse, math.pi / (2.0 * tau_s) * e_rest * integral, e_rest)
    return Z, lam, omega_d, (is_pulse, tau_s, Omega, t_pos), t


def unit_response(t, omega, zeta, duration):
    """Modal displacement at time t (s) for a unit modal velocity change delivered as a half-sine of `duration`
    (s) starting at t = 0, or as an ideal impulse when `duration` = 0 (or below `IMPULSE_DURATION`). Shapes broadcast over modes.

    Impulse: e^{-zeta w t} sin(w_d t) / w_d. Half-sine: its convolution with pi/(2 tau) sin(pi s / tau) on
    [0, tau], evaluated in complex exponentials with no division by (w^2 - (pi/tau)^2), so exact resonance
    (w = pi/tau) and tau -> 0 are regular. Zero for t < 0.
    """
    Z, _, omega_d, _, t = _response_phasor(t, omega, zeta, duration)
    return jnp.where(t >= 0, jnp.imag(Z) / omega_d, 0.0)


def pulse_phasors(s, omega, zeta, duration):
    """(Z_sin, Z_cos, lam, omega_d, Omega) at times s >= 0 from rest, Omega = pi / tau. Z_sin is the unit
    response's phasor (q = Im(Z) / omega_d), driven by (pi / (2 tau)) sin(Omega s); Z_cos, the response to
    (pi / (2 tau)) cos(Omega s), is Z_sin' / Omega, valid while the pulse runs (s <= tau). A pulse that has run
    for `lag` goes on as Z(lag + s) = Z(lag) e^{lam s} + cos(Omega lag) Z_sin(s) + sin(Omega lag) Z_cos(s) while
    lag + s <= tau (its forcing sin(Omega (lag + s)), expanded): with e^{lam s}, Z_sin and Z_cos on a grid shared
    by every drop, a running pulse costs a few multiply-adds per point."""
    Z, lam, omega_d, (is_pulse, tau_s, Omega, t_pos), _ = _response_phasor(s, omega, zeta, duration)
    force = jnp.where(is_pulse & (t_pos <= tau_s), math.pi / (2.0 * tau_s) * sincos(Omega * t_pos)[0], 0.0)
    return Z, (lam * Z + force) / Omega, lam, omega_d, Omega


def free_phasor(t, omega, zeta, duration):
    """(Z, lam, omega_d) with unit_response(t + s) = Im(Z e^{lam s}) / omega_d for every s >= 0 with
    t + s >= duration: the free vibration after the pulse, continued back to time t (exact for t >= duration)."""
    Z_end, lam, omega_d, _, _ = _response_phasor(duration, omega, zeta, duration)
    t = jnp.asarray(t, dtype=float_dtype())[..., None]
    return Z_end * cexp(lam * (t - duration)), lam, omega_d


def unit_response_jet(t, omega, zeta, duration):
    """(q, q', q'') of `unit_response` at t > 0, from Z' = lam Z + g(t), Z'' = lam Z' + g'(t) with g the pulse
    shape pi/(2 tau) sin(pi t / tau) on [0, tau] (zero for the impulse): no differentiation through exponentials."""
    Z, lam, omega_d, (is_pulse, tau_s, Omega, t_pos), t = _response_phasor(t, omega, zeta, duration)
    during = is_pulse & (t_pos <= tau_s)
    amp = math.pi / (2.0 * tau_s)
    sin, cos = sincos(Omega * t_pos)
    g = jnp.where(during, amp * sin, 0.0)
    dg = jnp.where(during, amp * Omega * cos, 0.0)
    dZ = lam * Z + g
    ddZ = lam * dZ + dg
    return jnp.imag(Z) / omega_d, jnp.imag(dZ) / omega_d, jnp.imag(ddZ) / omega_d


def fundamental_period(board: Board):
    """2 pi / omega_1, s."""
    return 2.0 * math.pi / natural_frequencies(board, 1)[0]
