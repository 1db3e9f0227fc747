"""The exact modal response to a sampled drive: the supports' acceleration linearly interpolated between samples
(as a `Record` reads it), zero after the last. Each mode q'' + 2 zeta omega q' + omega^2 q = f(t), f linear on each
sample interval, has the closed form

    q(s) = f_j / omega^2 - 2 zeta f'_j / omega^3 + f'_j s / omega^2 + exp(-zeta omega s) (E cos(w_d s) + D sin(w_d s))

at s = t - t_j on [t_j, t_j+1] (w_d = omega sqrt(1 - zeta^2); E, D from q and q' at t_j), so one pass over the
samples gives every mode's state at every sample time, and the state anywhere follows from the interval's own
formula: no step-size control, no tolerance, and derivatives of the formula itself.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._board.base import modal_velocity_jumps, natural_frequencies, support_participation


def _interval(q, v, f, slope, omega, zeta, s):
    """(q, q', q'') at s into an interval that starts at (q, v) under the forcing f + slope s, per mode."""
    w2 = omega**2
    wd = omega * jnp.sqrt(1.0 - zeta**2)
    base = f / w2 - 2.0 * zeta * slope / (w2 * omega)
    e0, de0 = q - base, v - slope / w2
    decay = jnp.exp(-zeta * omega * s)
    c, sn = jnp.cos(wd * s), jnp.sin(wd * s)
    b = (de0 + zeta * omega * e0) / wd
    e = decay * (e0 * c + b * sn)
    de = decay * ((b * wd - zeta * omega * e0) * c - (e0 * wd + zeta * omega * b) * sn)
    q_s = base + slope * s / w2 + e
    v_s = slope / w2 + de
    return q_s, v_s, f + slope * s - 2.0 * zeta * omega * v_s - w2 * q_s


class SampledModes(eqx.Module):
    """q(t) of every mode under modal forcing `force` (samples, n) at sample times `t` (samples,), linear between
    samples and zero after the last, from rest with modal velocities `v0` (n,) at t[0] (callable; a pytree, so it
    can be differentiated and batched). `states`: (q, q') of every mode at every sample time."""

    t: Float[Array, " m"]
    force: Float[Array, "m n"]
    omega: Float[Array, " n"]
    zeta: Float[Array, ""]
    states: Float[Array, "m 2 n"]

    windows = 1  # one search window over the whole drive

    def __init__(self, t, force, omega, zeta, v0):
        self.t, self.force, self.omega, self.zeta = t, force, omega, zeta
        slopes = (force[1:] - force[:-1]) / (t[1:] - t[:-1])[:, None]

        def step(state, interval):
            f, slope, h = interval
            q, v, _ = _interval(state[0], state[1], f, slope, omega, zeta, h)
            return jnp.stack([q, v]), state

        start = jnp.stack([jnp.zeros_like(v0), v0])
        last, before = jax.lax.scan(step, start, (force[:-1], slopes, t[1:] - t[:-1]))
        self.states = jnp.concatenate([before, last[None]])

    def jet(self, t):
        """(q, q', q'') at time t, each (n,)."""
        m = self.t.shape[0]
        j = jnp.clip(jnp.searchsorted(self.t, t, side="right") - 1, 0, m - 1)
        after = j == m - 1  # the drive is zero after its last sample
        nxt = jnp.minimum(j + 1, m - 1)
        h = jnp.where(after, 1.0, self.t[nxt] - self.t[j])
        f = jnp.where(after, 0.0, self.force[j])
        slope = jnp.where(after, 0.0, (self.force[nxt] - self.force[j]) / h)
        s = jnp.maximum(t - self.t[j], 0.0)
        return _interval(self.states[j, 0], self.states[j, 1], f, slope, self.omega, self.zeta, s)

    def __call__(self, t) -> Float[Array, " n"]:
        return self.jet(t)[0]

    def grid_factors(self, t):
        """(ones, q on the grid): a sampled drive has no separable form."""
        Q = jax.vmap(self)(t)
        return jnp.ones(Q.shape[-1], Q.dtype), Q


def sampled_modes(board, motion, n_modes: int, force_mask: Float[Array, " n"], window) -> SampledModes:
    """The exact response of the lowest `n_modes` of `board` to a sampled `motion` (a `Record`, such as a
    `LandingMotion`): `force_mask` (0/1 per mode) switches modes off, as `solve_modes`'s."""
    omega = natural_frequencies(board, n_modes)
    part = support_participation(board, n_modes) * force_mask[:, None]
    v0, _, _, _ = motion.forcing(lambda j: modal_velocity_jumps(board, j, n_modes) * force_mask, window)
    drive = jnp.stack([motion.aA, motion.aB, motion.aR], axis=-1)  # (samples, 3)
    return SampledModes(motion.t, drive @ part.T, omega, jnp.asarray(board.damping_ratio, omega.dtype), v0)
