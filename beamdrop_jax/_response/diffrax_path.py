"""The diffrax path: the modal equations integrated numerically, for any support motion and for mid-plane
stretching.

State (q, q') of every computed mode. Forcing F_k = p_kA a_A(t) + p_kB a_B(t); an ideal impulse enters as the
initial modal velocities instead. With `stretching=True` the axially immovable supports add the membrane force
N_s = (E b h / (2 L)) integral of u_x^2 dx = (E b h / 4) sum_j (j pi / L)^2 q_j^2 to the axial force, which couples
the modes (a Duffing-type hardening).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._board.beam import wavenumbers

from .._board.base import modal_velocity_jumps, natural_frequencies, support_participation
from .._board.beam import Board


# Names of diffrax solvers; diffrax itself is imported when a solve needs it (it takes a second to import).
SOLVERS = ("Tsit5", "Dopri5", "Dopri8", "Kvaerno3", "Kvaerno5", "ImplicitEuler", "Heun", "Bosh3")


class DiffraxModes(eqx.Module):
    """q(t) from a dense diffrax solution (callable; a pytree, so it can be differentiated and batched)."""

    solution: eqx.Module  # a diffrax.Solution
    n_modes: int = eqx.field(static=True)

    windows = 1  # one search window over the whole solve

    def __call__(self, t) -> Float[Array, " n"]:
        t = jnp.clip(t, self.solution.t0, self.solution.t1)
        return self.solution.evaluate(t)[: self.n_modes]

    def jet(self, t):
        """(q, q', q'') at time t from the dense interpolant (forward-mode derivatives in t)."""

        def q_and_rate(s):
            return jax.jvp(self, (s,), (jnp.ones_like(s),))

        (q, dq), (_, ddq) = jax.jvp(q_and_rate, (t,), (jnp.ones_like(t),))
        return q, dq, ddq

    def grid_factors(self, t):
        """(ones, q on the grid): the numerical solution has no separable form."""
        Q = jax.vmap(self)(t)
        return jnp.ones(Q.shape[-1], Q.dtype), Q


def solve_modes(
    board: Board,
    motion,
    n_modes: int,
    window,
    force_mask: Float[Array, " n"],
    *,
    solver: str = "Tsit5",
    rtol: float = 1e-8,
    atol: float = 1e-12,
    max_steps: int = 16384,
    stretching: bool = False,
) -> tuple[DiffraxModes, Array]:
    """Integrate the modal equations over [0, window]; returns (q(t) callable, whether the solve failed).

    `force_mask` (0/1 per mode) switches modes off: masked modes start at rest and feel no forcing.
    """
    omega = natural_frequencies(board, n_modes)
    zeta = board.damping_ratio
    if stretching:  # the membrane force of a pinned beam's immovable ends (section 3); no other board has one yet
        ends = getattr(board, "ends", None)
        if ends != "pinned":
            where = f'Board.ends = "{ends}"' if ends else f"a {type(board).__name__}"
            raise ValueError(f"Numerics.stretching = True models pinned ends only ({where})")
        kappa = wavenumbers(board, n_modes)
        membrane = board.youngs_modulus * board.width * board.thickness / 4.0
    part = support_participation(board, n_modes) * force_mask[:, None]

    v0, accel, jumps, dtmax = motion.forcing(lambda j: modal_velocity_jumps(board, j, n_modes) * force_mask, window)

    def rhs(t, y, args):
        q, v = y[:n_modes], y[n_modes:]
        if stretching:
            axial = board.axial_force + membrane * jnp.sum(kappa**2 * q**2)
            omega2 = (board.bending_stiffness * kappa**4 + axial * kappa**2) / board.mass_per_length
        else:
            omega2 = omega**2
        force = part @ accel(t)
        return jnp.concatenate([v, force - 2.0 * zeta * omega * v - omega2 * q])

    if solver not in SOLVERS:
        raise ValueError(f"Numerics.solver = {solver!r}; valid solvers: {', '.join(SOLVERS)}")
    y0 = jnp.concatenate([jnp.zeros(n_modes), v0])
    import diffrax

    # Where the steps fall (the largest step, the kinks stepped onto, the window's end) is numerics, not physics:
    # no derivative flows through it (diffrax's controller already stops it through the error estimate), or the
    # gradient would hold the discretisation's change with the step sizes (d peak / d contact duration 2e8 Pa/s
    # where the sampled landing's duration only sets the largest step).
    dtmax, jumps, t1 = jax.lax.stop_gradient((dtmax, jumps, window))
    pid = diffrax.PIDController(rtol=rtol, atol=atol, dtmax=dtmax)
    controller = diffrax.ClipStepSizeController(pid, jump_ts=jumps)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(rhs),
        getattr(diffrax, solver)(),
        t0=0.0,
        t1=t1,
        dt0=None,
        y0=y0,
        saveat=diffrax.SaveAt(dense=True),
        stepsize_controller=controller,
        max_steps=max_steps,
        throw=False,
    )
    return DiffraxModes(sol, n_modes), sol.result != diffrax.RESULTS.successful
