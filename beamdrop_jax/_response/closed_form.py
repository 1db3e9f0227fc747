"""The exact modal response to half-sine (or ideal impulse) pulses at the supports: `ClosedFormModes` and the pulse train's jets for the Newton search (`_TrainJet`)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .._common.checks import is_pulse as _is_pulse, pulse_duration
from .._common.trig import cexp, sincos
from .pulses import free_phasor, pulse_phasors, unit_response, unit_response_jet


class ClosedFormModes(eqx.Module):
    """q_k(t) = sum_i beta_ik R_k(t - t_i): exact modal response to half-sine (or ideal impulse) pulses at the
    supports starting at `times` t_i, pulse i leaving modal velocities `beta[i]`."""

    omega: Float[Array, " n"]
    zeta: Float[Array, ""]
    duration: Float[Array, ""]
    beta: Float[Array, "K n"]
    times: Float[Array, " K"]

    @property
    def windows(self) -> int:
        """Search windows: one per pulse (`_time_grid`)."""
        return self.times.shape[0]

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
        is_pulse = _is_pulse(m.duration)
        amp = jnp.where(is_pulse, math.pi / (2.0 * pulse_duration(m.duration)), 0.0)
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
