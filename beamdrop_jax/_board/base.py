"""What the response needs from a board model, and nothing more.

Section 6 of the design: a board in modal form is its natural frequencies, the participation of the supports'
rigid motion in each mode, and its shapes (deflection and curvature) at points of its domain. `AbstractModal`
holds those; `AbstractBoard` adds what a scene's board is besides (its modes solved once per drop, its checks, its
scene-file section, how its peaks are found). Simulate, the superposition tables, Monte-Carlo, the optimisers,
sensitivities, campaigns, scene files and the CLI call these methods and never ask which board they hold.

Models: `Board` (Euler-Bernoulli beam, `beam.py`), `Plate` (Kirchhoff plate on edges and mounts, `plate.py`; its
solved modes are `PlateModes`). A new model is a new file implementing these classes and a scene-file section.
"""

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class AbstractModal(eqx.Module):
    """Modes of a board: frequencies, the supports' participation, curvature scaling, damping, checks."""

    @abc.abstractmethod
    def frequencies(self, n_modes: int) -> Float[Array, " n"]:
        """Undamped natural frequencies omega_k (rad/s) of the lowest `n_modes` modes."""

    @abc.abstractmethod
    def participation(self, n_modes: int) -> Float[Array, "n 2"]:
        """Modal forcing per unit support acceleration, columns (p_A, p_B): q_k'' + ... = p_kA a_A + p_kB a_B."""

    def curvature_scale(self, n_modes: int) -> Float[Array, " n"]:
        """Per mode, the factor that turns the model's shapes into curvature shapes (ones where the model
        evaluates curvature shapes itself)."""
        return jnp.ones(n_modes, dtype=self.frequencies(1).dtype)

    @abc.abstractmethod
    def flags(self):
        """Traceable checks (an int32 mask of `Flag`)."""


class AbstractBoard(AbstractModal):
    """A board in a scene: a modal model with a domain, a scene-file section and its own peak search.

    - `SECTION`: the scene-file section that holds it (`[board]`, `[plate]`).
    - `SURFACE`: whether its domain is a surface (x, y) with principal strains (a plate) or a line along x with
      bending strain (a beam): the peak search, gauges and superposition tables follow the domain, not the class.
    """

    SECTION: ClassVar[str]
    SURFACE: ClassVar[bool]

    @abc.abstractmethod
    def modes(self, n_modes: int) -> AbstractModal:
        """The board's lowest `n_modes` modes, solved once per drop and shared by everything after."""

    def describe(self) -> str:
        """A short description for reports, e.g. "beam 100 mm, pinned ends"."""
        return type(self).__name__


def natural_frequencies(board: AbstractModal, n_modes: int) -> Float[Array, " n"]:
    """Undamped natural frequencies omega_k (rad/s), k = 1..n, of a board or its solved modes (a beam includes its
    axial force; a buckled beam is flagged by `Board.flags()` and its frequencies clamped to a tiny positive
    value so nothing downstream is NaN)."""
    return board.frequencies(n_modes)


def support_participation(board: AbstractModal, n_modes: int) -> Float[Array, "n 2"]:
    """Modal forcing per unit support acceleration: F_k = p_kA a_A + p_kB a_B (columns p_A, p_B)."""
    return board.participation(n_modes)


def modal_velocity_jumps(board: AbstractModal, jumps: Float[Array, "2"], n_modes: int) -> Float[Array, " n"]:
    """The modal velocities an ideal impulse with support velocity jumps (dvA, dvB) leaves, m/s."""
    return board.participation(n_modes) @ jnp.asarray(jumps)


def curvature_scale(board: AbstractModal, n_modes: int) -> Float[Array, " n"]:
    """See `AbstractModal.curvature_scale`."""
    return board.curvature_scale(n_modes)
