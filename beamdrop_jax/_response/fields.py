"""A drop's response as fields: deflection, strain and stress over (x, t) along a beam (`response_fields`), a plate's strain map at one time, and the notes a reader of the numbers should know."""


import jax.numpy as jnp
import numpy as np

from .._board.base import curvature_scale
from .._board.beam import mode_shapes, wavenumbers
from .._board.plate import surface_strain
from .._board.search import field_on_grid
from .._common.checks import Flag, Range, as_float, as_int, float_dtype, is_pulse, require
from .._common.compile import filter_jit
from .._scene.containers import Scene
from .numerics import Numerics
from .results import Fields, Response, StrainMap
from .setup import _modal_solution, _span, _time_grid
from .simulate import landing_drive, simulate


def response_fields(scene: Scene, numerics: Numerics | None = None, nx: int = 101, nt: int = 801,
                    x=None) -> Fields:
    """Deflection, strain and stress over (x, t) for a scene, with the modes `simulate` reports. `x`: positions
    from end A (m; default `nx` points over the board), e.g. strain gauges. With several impacts, `nt` times follow
    each impact (the window after each, as in the peak search).

    Strain and stress are signed: those of the face on the board normal's side (-(h/2) u_xx; positive is tension),
    plus the membrane strain with `Numerics(stretching=True)`.
    """
    numerics = Numerics() if numerics is None else numerics
    if scene.board.SURFACE:
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
    return _fields(scene, response, numerics, x, nt, landing=_landing_of(response))


def _landing_of(response: Response) -> str:
    """The landing path `simulate` took for `response` (`landing_drive`)."""
    weight = response.landing_weight
    return "compliant" if weight is not None and float(weight) > 0 else "rigid"


@filter_jit
def _fields(scene, response, numerics, x, nt, landing="rigid"):
    board = scene.board
    M = numerics.computed_modes
    motion, numerics = landing_drive(scene, numerics, landing)[:2]
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


def _not_converged(board, response: Response) -> str:
    """Which convergence estimates failed, by how much, and what to raise: every estimate over the tolerance (the
    modes' and the basis's errors add, so a user who raised one would otherwise meet the next), or the largest
    where only their sum is over it."""
    c = response.convergence
    rtol = Numerics().convergence_rtol
    values = {"modes": float(response.error_estimate)} if c is None else {
        "modes": float(c.modes), "gauges": float(c.gauges), "basis": float(c.basis), "window": float(c.window)}
    failed = {k: v for k, v in values.items() if v > rtol} or dict([max(values.items(), key=lambda kv: kv[1])])
    if "modes" in failed and "gauges" in failed:  # one fix for both: name the larger
        del failed["gauges" if failed["modes"] >= failed["gauges"] else "modes"]
    said, fixes = [], []
    # A check with fewer modes than the answer means the count hit its cap.
    capped = int(response.check_modes) < int(response.n_modes) or (c is not None and bool(c.check_cap))
    for name, value in sorted(failed.items(), key=lambda kv: -kv[1]):
        if name == "window":
            window = float(response.window)
            said.append(f"a gauge reads {value * 100:.2g} % more after the peak window ({window * 1e3:.4g} ms) than "
                        "within it")
            fixes.append(f"widen the window (Numerics.window, s; twice this one is {2 * window * 1e3:.4g} ms)")
        elif name == "basis":
            said.append(f"the Ritz basis's error at the peak or a gauge, from a basis 4 functions larger each way, is "
                        f"{value * 100:.2g} %")
            fixes.append(f"raise Plate.basis (now {board.basis}; `basis = [nx, ny]` in the scene file's [plate], at "
                         "most 40)")
        else:
            what = "the peak" if name == "modes" else "a gauge's peak strain"
            said.append(f"{int(response.check_modes)} modes change {what} by {value * 100:.2g} % (against "
                        f"{int(response.n_modes)})")
            fixes.append("raise Numerics.max_modes" if capped else "raise Numerics.pulse_modes (modes up to f_k x "
                         f"duration >= {Numerics().for_board(board).pulse_band:g} by default)")
    return (f"not converged: {', and '.join(said)} (Numerics.convergence_rtol = {rtol * 100:g} %); "
            + ", and ".join(fixes))


LONGEST_CONTACT = 0.1
"""A contact duration (s) beyond which `response_notes` asks whether it was meant in seconds."""
LIGHTEST_BOARD = 100.0
"""A board density (kg/m^3) below which `response_notes` asks whether it was meant in kg/m^3."""
SHORTEST_CONTACT = 1e-5
"""A contact duration (s) below which `sample_notes` asks whether it was meant in ms (a drop's contact lasts about
0.05 ms on metal to tens of ms on foam)."""
ELASTIC_STRAIN = 0.01
"""A peak strain beyond the elastic range of board materials (FR-4, ceramics, solder joints fail well below)."""


def sample_notes(peak_strain, durations=None) -> list[str]:
    """What a reader of many drops' numbers should know (`montecarlo`): the largest peak strain beyond the elastic
    range, contact durations (s, the drawn ones or their bounds) too short to be a drop's (a unit slip)."""
    notes = []
    strain = np.asarray(peak_strain, dtype=float)
    worst = float(np.max(strain[np.isfinite(strain)], initial=0.0))
    if worst > ELASTIC_STRAIN:
        notes.append(f"largest peak strain {worst * 100:.3g} % is beyond the elastic range of board materials")
    if durations is not None and float(np.min(durations)) < SHORTEST_CONTACT:
        notes.append(f"contact durations from {float(np.min(durations)) * 1e3:.3g} ms: shorter than a drop's contact "
                     "lasts (about 0.05 ms on metal to tens of ms on foam); durations are in seconds in Python and in "
                     "ms on the command line (0.5 ms is 0.0005 s, --durations 0.5)")
    return notes


def response_notes(scene: Scene, response: Response) -> list[str]:
    """What a reader of a drop's numbers should know: where the model's assumptions stop holding or the answer is
    not converged (an empty list when nothing needs saying)."""
    notes = []
    board, peak = scene.board, response.peak
    if not is_pulse(float(scene.contact.duration)):
        notes.append(f"ideal impulse (contact duration {float(scene.contact.duration):g} s): the peak grows with the mode count and never converges "
                     f"(stopped at {int(response.n_modes)} modes); give Contact.duration a physical value "
                     "(0.05-1 ms)")
    elif not bool(response.converged) and int(response.flags) == 0:
        notes.append(_not_converged(board, response))
    if float(scene.contact.duration) > LONGEST_CONTACT:
        notes.append(f"contact duration {float(scene.contact.duration):g} s: longer than a drop's contact lasts (about "
                     "0.05 ms on metal to tens of ms on foam); Contact.duration is in seconds (5 ms is 0.005)")
    if int(response.flags) & Flag.SOLVER_FAILED and response.landing_weight is not None and float(
            response.landing_weight) > 0:
        notes.append("the compliant landing's solve reached its step limit (a nearly plastic contact or a long "
                     "landing; near-flat drops take 1000 to 11,000 steps): raise Numerics.landing_steps (16384 by "
                     "default)")
    if float(board.youngs_modulus) < 1e6 or float(board.thickness) > 0.05:
        notes.append(f"the board is not an engineering board (E = {float(board.youngs_modulus):.4g} Pa, thickness "
                     f"{float(board.thickness):.4g} m): the thesis scene's nondimensional units, so stresses in MPa "
                     "and strains in microstrain mean nothing physical here")
    elif float(board.density) < LIGHTEST_BOARD:
        notes.append(f"board density {float(board.density):g} kg/m^3: lighter than any board material (about 1000 "
                     "to 9000 kg/m^3); the field is in kg/m^3 (1.85 g/cm^3 is 1850)")
    elif float(peak.strain) > ELASTIC_STRAIN:
        notes.append(f"peak strain {float(peak.strain) * 100:.3g} % is beyond the elastic range of board materials")
    if float(peak.deflection) > float(board.thickness):
        notes.append(f"peak deflection {float(peak.deflection) / float(board.thickness):.2g} x the thickness: "
                     "linear (small-deflection) theory overestimates it; mid-plane stretching matters "
                     + ("(not modelled for plates yet)" if board.SURFACE
                        else "(Numerics(method=\"diffrax\", stretching=True))"))
    return notes + board.notes(response)


def plate_strain_map(scene: Scene, response: Response, numerics: Numerics | None = None, t=None, nx: int = 133,
                     ny: int = 78) -> StrainMap:
    """The largest principal surface strain over a plate scene's board at time `t` (s; default: the peak strain's
    time, `response.peak.strain_t`), with the modes `response` (from `simulate(scene, numerics)`) used."""
    numerics = Numerics() if numerics is None else numerics
    if not scene.board.SURFACE:
        raise ValueError("plate_strain_map needs a scene whose board is a bd.Plate")
    as_int(nx, "nx", 2)
    as_int(ny, "ny", 2)
    t = response.peak.strain_t if t is None else as_float(t, "t", Range(0.0, unit="s"))
    return _strain_map(scene, numerics, response.n_modes, t, nx, ny, landing=_landing_of(response))


@filter_jit
def _strain_map(scene, numerics, used, t, nx, ny, landing="rigid"):
    plate = scene.board
    numerics = numerics.for_board(plate)
    M = numerics.computed_modes
    motion, numerics = landing_drive(scene, numerics, landing)[:2]
    mask = (jnp.arange(1, M + 1) <= used).astype(float_dtype())
    modes = plate.modes(M)
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
