"""How the board's response is computed: `Numerics`, static configuration of modes, grids, solver and search."""


import dataclasses

import equinox as eqx

from .._common.checks import Range, as_int, as_real
from .._impact.routh import LAWS
from .diffrax_path import SOLVERS


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
      an int means exactly modes 1..n_modes, checked against half as many. `max_modes` and `pulse_modes` left
      `None` take the board's own (`AbstractBoard.NUMERICS`; 16 and 2 for the beam and the plate). A plate under
      half-sine pulses (the closed form) keeps all `max_modes` modes (on its search grid they cost what fewer
      would) and is checked against every mode of its Ritz basis at the peak and the gauges; point mounts and
      narrow plates need modes well past the pulse's band: on the JESD22 board 48 (with `frequency_growth=1`,
      which keeps its time grid small).
    - `frequency_growth`: how the top computed mode's frequency grows with the mode count M, which sizes the time
      grid: 2 for M^2 (a beam; a bound for any board), 1 for about 1.5 M (a plate on mounts, by Weyl's law in two
      dimensions; the grid then allows 2 M + 8 periods, and a plate whose frequencies outgrow it is flagged,
      `Flag.WINDOW_RANGE`). `None` (the default): 2, except that `simulate` and `board_response` give a concrete
      plate 1 where its own top computed mode makes at most 2 M + 8 periods over the window (`plate_time_grid`).
    - `window`: time window (s); `None` is the pulse duration plus one fundamental period. With several impacts
      it is the window searched after each impact (the free vibration between impacts repeats with the
      fundamental period when the axial force is 0, so one period after each pulse holds the peak).
    - `points_per_period`: time-grid points per period of the highest computed mode (N = 0 estimate);
      `x_points_per_mode`: spatial grid points per computed mode.
    - `refine`: Newton refinement of the grid's best `candidates` peaks (`newton_steps` each; on a plate with
      mounts, half as many again, rounded up, from the points on the mounts' circles).
    - `convergence_rtol`: `converged` when the error estimate (`Response.convergence`) is below this.
    - `stretching`: nonlinear mid-plane stretching for axially immovable supports (diffrax only).
    - `law`: restitution law of the housing impact.
    - `max_impacts`: impacts followed (1: the first corner impact only, the thesis's model; more: the housing
      flies freely after each impact and clatters onto the next corner, closed form only). `rest_speed` (m/s):
      a next impact approaching slower than this ends the sequence.
    - `from_rest`: every drop starts from rest (no spin, no horizontal speed), so a box's vertex has no slip when it
      strikes, and the 3D rigid law takes its closed form (stick, or slide along the invariant direction: no
      diffrax solve; 15 times faster Monte-Carlo on a box). `montecarlo` sets it where its drops are from rest; a
      drop that is not gets NaN peaks and `Flag.SOLVER_FAILED`.
    - `landing_steps`: the step limit of the compliant landing's solve (near-flat drops; `Contact.model`). The
      solve keeps the state at each step in a buffer this long: near-flat drops of
      the embedded scenes took 1000 to 10,900 steps, a nearly plastic contact (restitution 0.02) 15,000.
      A landing that needs more is flagged `Flag.SOLVER_FAILED`; raise it then. `landing_tolerance`: its step
      controller's rtol and atol on the nondimensional state (tight: the gradients through the landing follow
      the solver's steps). `landing_kinks`: the step controller closes in on each contact's kinks (where it starts,
      turns from loading to unloading, or ends; derivatives through the landing need it); False steps across them:
      19 % fewer steps on the JESD22 plate's near-flat landings at a tolerance of 1e-6 (the orientation tables'),
      peaks within 2.1e-4 of the largest from `simulate`'s, and derivatives that are not the landing's.
    """

    method: str = eqx.field(static=True, default="closed_form")
    solver: str = eqx.field(static=True, default="Tsit5")
    n_modes: int | None = eqx.field(static=True, default=None)
    max_modes: int | None = eqx.field(static=True, default=None)
    min_modes: int = eqx.field(static=True, default=4)
    pulse_modes: float | None = eqx.field(static=True, default=None)
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
    frequency_growth: int | None = eqx.field(static=True, default=None)
    from_rest: bool = eqx.field(static=True, default=False)
    landing_steps: int = eqx.field(static=True, default=16384)
    landing_tolerance: float = eqx.field(static=True, default=1e-10)
    landing_kinks: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        def bad(field, value, valid):
            raise ValueError(f"Numerics.{field} = {value!r}; valid: {valid}")

        for name, choices in (("method", METHODS), ("solver", SOLVERS), ("law", LAWS)):
            if not (isinstance(getattr(self, name), str) and getattr(self, name) in choices):
                bad(name, getattr(self, name), ", ".join(choices))
        for name, flag in (("refine", self.refine), ("stretching", self.stretching),
                           ("landing_kinks", self.landing_kinks)):
            if not isinstance(flag, bool):
                bad(name, flag, "True or False")
        if self.n_modes is not None:
            as_int(self.n_modes, "Numerics.n_modes", 1, 512)
        if self.max_modes is not None:
            as_int(self.max_modes, "Numerics.max_modes", 2, 512)
        as_int(self.min_modes, "Numerics.min_modes", 1, 512)
        if self.max_modes is not None and self.max_modes < self.min_modes:
            bad("max_modes", self.max_modes, f"an int >= Numerics.min_modes = {self.min_modes} (to allow fewer "
                f"modes, lower min_modes with it: Numerics(max_modes={self.max_modes}, min_modes={self.max_modes}))")
        for name in ("points_per_period", "x_points_per_mode", "candidates", "max_steps", "max_impacts",
                     "landing_steps"):
            as_int(getattr(self, name), f"Numerics.{name}", 1)
        as_int(self.newton_steps, "Numerics.newton_steps", 0)
        if self.window is not None:
            as_real(self.window, "Numerics.window", Range(0.0, 10.0, lo_open=True, unit="s"))
        for name in ("rtol", "atol", "convergence_rtol", "landing_tolerance"):
            as_real(getattr(self, name), f"Numerics.{name}", Range(0.0, 1.0, lo_open=True))
        if self.pulse_modes is not None:
            as_real(self.pulse_modes, "Numerics.pulse_modes", Range(0.0, 100.0, lo_open=True))
        if self.frequency_growth not in (None, 1, 2):
            raise ValueError(f"Numerics.frequency_growth = {self.frequency_growth!r}; valid: None (the board's), 1, 2")
        as_real(self.rest_speed, "Numerics.rest_speed", Range(0.0, lo_open=True, unit="m/s"))
        if self.max_impacts > 1 and self.method != "closed_form":
            raise ValueError(
                f"Numerics.max_impacts = {self.max_impacts} needs Numerics.method = \"closed_form\": the flight "
                "between impacts spans thousands of board periods, which the closed form skips exactly"
            )
        if self.stretching and self.method != "diffrax":
            raise ValueError('Numerics.stretching = True needs Numerics.method = "diffrax" (it has no closed form)')

    def for_board(self, board) -> "Numerics":
        """These numerics with the fields left `None` set to the board's own (`AbstractBoard.NUMERICS`)."""
        own = {name: value for name, value in board.NUMERICS.items() if getattr(self, name) is None}
        return dataclasses.replace(self, **own) if own else self

    @property
    def computed_modes(self) -> int:
        return (16 if self.max_modes is None else self.max_modes) if self.n_modes is None else self.n_modes

    @property
    def pulse_band(self) -> float:
        """`pulse_modes`, or a beam's 2 when unset."""
        return 2.0 if self.pulse_modes is None else self.pulse_modes

    def grid_shape(self) -> tuple[int, int]:
        """(nx, nt): with N = 0 a beam's mode k makes k^2 oscillations per fundamental period, so the top mode
        needs about M^2 + a few periods over the default window; a plate's (`frequency_growth` 1) about 1.5 M,
        allowed 2 M + 8 (a grid too coarse for the plate's own frequencies is flagged, `Flag.WINDOW_RANGE`)."""
        M = self.computed_modes
        periods = 2 * M + 8 if self.frequency_growth == 1 else M * M + 8
        return self.x_points_per_mode * M + 1, self.points_per_period * periods + 1
