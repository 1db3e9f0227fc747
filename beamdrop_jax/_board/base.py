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
import math
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
    def participation(self, n_modes: int) -> Float[Array, "n 3"]:
        """Modal forcing per unit support acceleration, columns (p_A, p_B, p_R): q_k'' + ... = p_kA a_A + p_kB a_B
        + p_kR a_R, for the three rigid-motion inputs of `bd.HalfSine` (end A, end B, roll across the width; a
        beam's roll column is zero)."""

    def curvature_scale(self, n_modes: int) -> Float[Array, " n"]:
        """Per mode, the factor that turns the model's shapes into curvature shapes (ones where the model
        evaluates curvature shapes itself)."""
        return jnp.ones(n_modes, dtype=self.frequencies(1).dtype)

    @abc.abstractmethod
    def flags(self):
        """Traceable checks (an int32 mask of `Flag`)."""

    def describe(self) -> str:
        """A short description for reports, e.g. "beam 100 mm, pinned ends"."""
        return type(self).__name__


class AbstractBoard(AbstractModal):
    """A board in a scene: a modal model with a domain, a scene-file section and its own peak search.

    - `SECTION`: the scene-file section that holds it (`[board]`, `[plate]`).
    - `SURFACE`: whether its domain is a surface (x, y) with principal strains (a plate) or a line along x with
      bending strain (a beam): the peak search, gauges and superposition tables follow the domain, not the class.
    """

    SECTION: ClassVar[str]
    SURFACE: ClassVar[bool]
    NUMERICS: ClassVar[dict] = {}  # the board's own `Numerics` where the user leaves a field `None`
    TABLE_DURATIONS: ClassVar[bool]  # whether its superposition table can span contact durations

    @abc.abstractmethod
    def mirror_symmetric(self) -> bool:
        """Whether the board maps onto itself under x -> L - x, so a drop's mirror image (A and B swapped) has the
        mirrored peak (superposition tables search half the jump directions)."""

    @abc.abstractmethod
    def modes(self, n_modes: int) -> AbstractModal:
        """The board's lowest `n_modes` modes, solved once per drop and shared by everything after."""

    def check_gauges(self, points) -> None:
        """Eagerly, a `ValueError` naming a gauge point ((g, 2), m) the board cannot read (none by default)."""

    def raise_if_outside_theory(self, flags, what: str) -> None:
        """Eagerly, a `ValueError` for a response flagged outside the board model's theory (none by default)."""

    def notes(self, response) -> list[str]:
        """What a reader of this board's numbers should know beyond `response_notes`'s general ones."""
        return []

    def file_extras(self) -> dict:
        """Scene-file keys of the board beyond its float fields and choices (plain Python values)."""
        return {}



def natural_frequencies(board: AbstractModal, n_modes: int) -> Float[Array, " n"]:
    """Undamped natural frequencies omega_k (rad/s), k = 1..n, of a board or its solved modes (a beam includes its
    axial force; a buckled beam is flagged by `Board.flags()` and its frequencies clamped to a tiny positive
    value so nothing downstream is NaN)."""
    return board.frequencies(n_modes)


def support_participation(board: AbstractModal, n_modes: int) -> Float[Array, "n 3"]:
    """Modal forcing per unit support acceleration: F_k = p_kA a_A + p_kB a_B + p_kR a_R (columns p_A, p_B, p_R)."""
    return board.participation(n_modes)


def modal_velocity_jumps(board: AbstractModal, jumps: Float[Array, "3"], n_modes: int) -> Float[Array, " n"]:
    """The modal velocities an ideal impulse with support velocity jumps (dvA, dvB, dvR) leaves, m/s ((dvA, dvB):
    no roll)."""
    jumps = jnp.asarray(jumps)
    return board.participation(n_modes)[:, :jumps.shape[-1]] @ jumps


def curvature_scale(board: AbstractModal, n_modes: int) -> Float[Array, " n"]:
    """See `AbstractModal.curvature_scale`."""
    return board.curvature_scale(n_modes)


class Peak(eqx.Module):
    """Peak bending response over the board and the window.

    `stress` (Pa), `strain` (-), where (`x` from end A, m) and when (`t`, s); `deflection` (m, relative to the
    chord AB) with its own `deflection_x`, `deflection_t`; `search_error`: relative error estimate of the stress
    peak search's refinement (on a plate: what a Newton step would still gain, or the last step's gain, whichever
    is larger; within a factor of 2 of the remaining gap in the tests). A maximum that the search grid does not
    resolve (two within one cell) is beyond it: `Numerics.points_per_period` and the plate's basis set the grid. With mid-plane stretching (`Numerics(stretching=True)`) `stress` and `strain` are those of the
    face in tension, bending plus membrane, and `membrane_stress` (Pa) is the membrane part at the peak (0
    without stretching). On a plate `stress` and `strain` are the largest principal surface values, `y` and
    `deflection_y` (m, from the centre line) say where across the width (0 for a beam), and the strain peak has
    its own place and time, `strain_x`, `strain_y`, `strain_t` (Poisson's ratio couples the two directions: the
    largest principal strain need not be where the largest principal stress is; on a beam they are the stress
    peak's)."""

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
    strain_x: Float[Array, ""]
    strain_y: Float[Array, ""]
    strain_t: Float[Array, ""]


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
