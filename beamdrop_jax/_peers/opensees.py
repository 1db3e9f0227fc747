"""An independent finite-element peer for the board: OpenSees (`openseespy`, the optional extra `validation`).

The board is meshed with Euler-Bernoulli beam elements (`elasticBeamColumn`, consistent mass) and its two supports
are driven with the prescribed displacement, velocity and acceleration of the support motion (a `MultipleSupport`
pattern of imposed motions), integrated by Newmark's average-acceleration method. Nothing in it shares code with the
modal model: it is a second method for the same physics, to compare frequencies and peak stress, where and when.
"""

import importlib.util
import math
import os
from typing import NamedTuple

import numpy as np

from .._impact.motion import HalfSine
from .._board.beam import Board
from .._board.plate import Plate



def _opensees():
    """openseespy's module; its Linux wheel ships a BLAS its LAPACK cannot find, so load that first."""
    spec = importlib.util.find_spec("openseespylinux")
    if spec is not None and spec.origin is not None:
        import ctypes

        blas = os.path.join(os.path.dirname(spec.origin), "lib", "libblas.so.3")
        if os.path.exists(blas):
            ctypes.CDLL(blas, mode=ctypes.RTLD_GLOBAL)
    try:
        import openseespy.opensees as ops
    except (ImportError, RuntimeError) as err:
        raise ImportError('the OpenSees peer needs openseespy: pip install "beamdrop_jax[validation]"') from err
    return ops


class FEResponse(NamedTuple):
    """The OpenSees peer's answer for a board of `length` (m): `frequencies` (Hz, lowest first), peak bending
    `stress` (Pa) over the nodes and the time steps, where (`x` from end A, m) and when (`t`, s), both refined by
    parabolas through the neighbouring nodes and steps, the discretisation (`n_elements`, `dt`, s) and the whole `history`: |stress| (Pa) at the
    nodes x_i = i L / n_elements (columns) after each step t_j = (j + 1) dt (rows)."""

    length: float
    frequencies: np.ndarray
    stress: float
    x: float
    t: float
    n_elements: int
    dt: float
    history: np.ndarray

    def stress_at(self, x: float, t: float) -> float:
        """|stress| (Pa) at (x, t), bilinear between nodes and steps."""
        steps, nodes = self.history.shape
        fx = np.clip(x / self.length * (nodes - 1), 0, nodes - 1 - 1e-12)
        ft = np.clip(t / self.dt - 1, 0, steps - 1 - 1e-12)
        i, j = int(fx), int(ft)
        a, b = fx - i, ft - j
        h = self.history
        return float((1 - b) * ((1 - a) * h[j, i] + a * h[j, i + 1]) + b * ((1 - a) * h[j + 1, i] + a * h[j + 1, i + 1]))


def _support_history(dv: float, tau: float, t: np.ndarray):
    """Displacement, velocity and acceleration of a support whose velocity changes by `dv` as a half-sine of
    duration `tau` (the integrals of a(t) = dv pi/(2 tau) sin(pi t / tau) on [0, tau]) from rest at t = 0."""
    w = math.pi / tau
    on = t <= tau
    tt = np.minimum(t, tau)
    accel = np.where(on, dv * w / 2 * np.sin(w * tt), 0.0)
    vel = dv * (1 - np.cos(w * tt)) / 2
    disp = dv * (tt - np.sin(w * tt) / w) / 2 + np.where(on, 0.0, dv * (t - tau))
    return disp, vel, accel


def _build(ops, board: Board, n: int, stretching: bool = False):
    L, b, h = float(board.length), float(board.width), float(board.thickness)
    E, rho = float(board.youngs_modulus), float(board.density)
    ops.wipe()
    ops.model("basic", "-ndm", 2, "-ndf", 3)
    for i in range(n + 1):
        ops.node(i + 1, L * i / n, 0.0)
    ops.geomTransf("Corotational" if stretching else "Linear", 1)
    for i in range(n):
        ops.element("elasticBeamColumn", i + 1, i + 1, i + 2, b * h, E, b * h**3 / 12, 1, "-mass", rho * b * h,
                    "-cMass")
    ops.fix(1, 1, 0, 0)  # the board's axis: no axial rigid motion
    if stretching:
        ops.fix(n + 1, 1, 0, 0)  # axially immovable supports


def opensees_board_response(
    board: Board,
    motion: HalfSine,
    window: float,
    *,
    n_elements: int = 80,
    dt: float = 1e-6,
    n_frequencies: int = 4,
    stretching: bool = False,
) -> FEResponse:
    """Peak bending stress of a board (any `Board.ends`) whose supports move as `motion` (a `HalfSine` with
    duration > 0), computed by OpenSees over [0, `window`] s with `n_elements` beam elements and time step `dt`.
    A clamp turns with the chord AB (the housing's rotation); a free end follows nothing.

    `stretching=True`: axially immovable supports and corotational (large-displacement) elements solved by Newton's
    method; the stress is then that of the face in tension, N/A + |M| (h/2)/I, to compare with
    `Numerics(stretching=True)`.

    The peer models an undamped board without axial force (the cases it is there to check)."""
    if not isinstance(motion, HalfSine) or float(motion.duration) <= 0:
        raise ValueError("the OpenSees peer takes a HalfSine support motion with duration > 0")
    if stretching and board.ends != "pinned":
        raise ValueError("the OpenSees peer's stretching case has pinned ends")
    if float(board.axial_force) != 0.0 or float(board.damping_ratio) != 0.0:
        raise ValueError("the OpenSees peer models a board with axial_force = 0 and damping_ratio = 0")
    if n_elements < 2 or dt <= 0 or window <= 0:
        raise ValueError("n_elements >= 2, dt > 0 and window > 0 are needed")
    ops = _opensees()
    n = int(n_elements)

    end_a, end_b = {"pinned": ("P", "P"), "clamped": ("C", "C"), "clamped-pinned": ("C", "P"),
                    "pinned-clamped": ("P", "C"), "clamped-free": ("C", "F")}[board.ends]
    _build(ops, board, n)
    for node, end in ((1, end_a), (n + 1, end_b)):
        if end != "F":
            ops.fix(node, 0, 1, int(end == "C"))
    omega2 = np.asarray(ops.eigen(n_frequencies))
    frequencies = np.sqrt(omega2) / (2 * math.pi)

    _build(ops, board, n, stretching)
    steps = int(math.ceil(window / dt))
    # A Path series reads 0 past its last value, and round-off in the analysis time can step past it: pad.
    t = np.arange(steps + 11) * dt
    tau = float(motion.duration)
    ops.pattern("MultipleSupport", 1)
    dvA, dvB = float(motion.dvA), float(motion.dvB)
    # Ground motions: 1, 2 the supports' translations; 3 the chord's rotation (dB - dA) / L, which clamps follow.
    motions = (dvA, dvB, (dvB - dvA) / float(board.length))
    for k, dv in enumerate(motions):
        series = []
        for j, history in enumerate(_support_history(dv, tau, t)):
            tag = 10 * (k + 1) + j
            ops.timeSeries("Path", tag, "-dt", dt, "-values", *history.tolist())
            series.append(tag)
        ops.groundMotion(k + 1, "Plain", "-disp", series[0], "-vel", series[1], "-accel", series[2])
    for k, (node, end) in enumerate(((1, end_a), (n + 1, end_b))):
        if end != "F":
            ops.imposedMotion(node, 2, k + 1)
        if end == "C":
            ops.imposedMotion(node, 3, 3)
    ops.constraints("Transformation")
    ops.numberer("RCM")
    ops.system("BandGeneral")
    ops.test("NormDispIncr", 1e-12, 10)
    ops.algorithm("Newton" if stretching else "Linear")
    ops.integrator("Newmark", 0.5, 0.25)
    ops.analysis("Transient")

    area, inertia = float(board.width) * float(board.thickness), float(board.width) * float(board.thickness) ** 3 / 12
    c = float(board.thickness) / 2 / inertia
    # |stress| on the nodes, in units of c (a moment): |M| plus, with stretching, the membrane part N / (A c).
    moments = np.zeros((steps, n + 1))
    for step in range(steps):
        if ops.analyze(1, dt) != 0:
            raise RuntimeError(f"OpenSees failed at step {step + 1}")
        for e in range(n):
            axial, m_i, m_j = ops.eleResponse(e + 1, "basicForce")[:3]
            membrane = axial / (area * c) if stretching else 0.0
            moments[step, e] = abs(m_i) + membrane
        moments[step, n] = abs(m_j) + membrane
    # The largest over nodes and steps. An undamped board repeats its peak and mirror images tie; the mesh's
    # error differs between those instants, so this need not be the instant the package reports (its earliest).
    step = int(np.argmax(moments.max(axis=1)))
    i = int(np.argmax(moments[step]))
    peak, x, t_peak = moments[step, i], i * float(board.length) / n, (step + 1) * dt
    # Parabolas through the neighbouring nodes and steps place the peak between them.
    for axis, cell in ((0, float(board.length) / n), (1, dt)):
        j, m = (i, n + 1) if axis == 0 else (step, steps)
        if 0 < j < m - 1:
            lo, mid, hi = (moments[step, j - 1], moments[step, j], moments[step, j + 1]) if axis == 0 else (
                moments[j - 1, i], moments[j, i], moments[j + 1, i])
            curv = lo - 2 * mid + hi
            if curv < 0:
                offset = 0.5 * (lo - hi) / curv
                peak += -0.25 * (lo - hi) * offset
                if axis == 0:
                    x += offset * cell
                else:
                    t_peak += offset * cell
    ops.wipe()
    return FEResponse(float(board.length), frequencies, c * peak, x, t_peak, n, dt, c * moments)


class PlateFEResponse(NamedTuple):
    """The OpenSees shell peer's answer for a plate: `frequencies` (Hz, lowest first); at each gauge (x, y) (m),
    the largest principal surface strain over time (`strain`: (steps, gauges), after each step t_j = (j + 1) dt)
    from the nodal deflections by central differences, its peak (`peak_strain`) and when (`peak_time`, s), refined
    by a parabola through the neighbouring steps; the mesh (`element_size`, m, `element`) and `dt` (s)."""

    frequencies: np.ndarray
    gauges: np.ndarray
    strain: np.ndarray
    peak_strain: np.ndarray
    peak_time: np.ndarray
    element_size: float
    element: str
    dt: float


def _mesh_lines(lo: float, hi: float, points, size: float) -> np.ndarray:
    """Node coordinates from `lo` to `hi` through every one of `points`, each span between them cut into equal
    elements no longer than `size`."""
    breaks = np.unique(np.concatenate([[lo, hi], np.asarray(points, float)]))
    lines = [np.linspace(a, b, max(1, int(math.ceil((b - a) / size - 1e-9))) + 1)[:-1] for a, b in
             zip(breaks[:-1], breaks[1:])]
    return np.concatenate(lines + [[hi]])


def opensees_plate_response(plate, motion: HalfSine | None, window: float, *, gauges=None, element_size: float = 3e-3,
                            dt: float = 5e-6, n_frequencies: int = 4, element: str = "ShellDKGQ") -> PlateFEResponse:
    """A plate (`bd.Plate`, edges S or F, mounts) meshed with OpenSees shell elements (`element`: "ShellDKGQ",
    discrete Kirchhoff, or "ShellMITC4", Mindlin with mixed shear interpolation; `ElasticMembranePlateSection`),
    whose supports (S edges and mounts, nodes of the mesh) move with the housing as `motion` prescribes (a
    `HalfSine` with duration > 0; a point at x moves as (1 - x / L) end A + (x / L) end B), integrated by
    Newmark's average-acceleration method over [0, `window`] s. Strain at the `gauges` (default the plate's centre)
    from the nodal deflections: w_xx, w_yy and w_xy by central differences over the neighbouring nodes.

    `motion=None`: the frequencies alone (`strain` empty, peaks NaN).

    The peer models an undamped plate; in-plane motion is held (it is uncoupled from bending in a flat plate)."""

    if not isinstance(plate, Plate):  # input check: this peer meshes plates only
        raise ValueError("opensees_plate_response takes a bd.Plate")
    if motion is not None and (not isinstance(motion, HalfSine) or float(motion.duration) <= 0):
        raise ValueError("the OpenSees peer takes a HalfSine support motion with duration > 0")
    if set(plate.edges) - {"S", "F"} or float(plate.damping_ratio) != 0.0:
        raise ValueError("the OpenSees shell peer models undamped plates with edges S or F")
    if element not in ("ShellDKGQ", "ShellMITC4"):
        raise ValueError(f"element = {element!r}; valid: ShellDKGQ, ShellMITC4")
    L, W, h = float(plate.length), float(plate.width), float(plate.thickness)
    E, nu, rho = float(plate.youngs_modulus), float(plate.poisson_ratio), float(plate.density)
    gauges = np.asarray([(L / 2, 0.0)] if gauges is None else gauges, float).reshape(-1, 2)
    mounts = np.zeros((0, 2)) if plate.mounts is None else np.asarray(plate.mounts, float)
    xs = _mesh_lines(0.0, L, np.concatenate([mounts[:, 0], gauges[:, 0]]), element_size)
    ys = _mesh_lines(-W / 2, W / 2, np.concatenate([mounts[:, 1], gauges[:, 1]]), element_size)
    nx, ny = len(xs), len(ys)
    tag = lambda i, j: 1 + i * ny + j  # noqa: E731
    held = set()
    for (edge, on) in zip(plate.edges, (lambda i, j: i == 0, lambda i, j: j == 0, lambda i, j: i == nx - 1,
                                        lambda i, j: j == ny - 1)):
        if edge == "S":
            held |= {(i, j) for i in range(nx) for j in range(ny) if on(i, j)}
    for mx, my in mounts:
        held.add((int(np.argmin(np.abs(xs - mx))), int(np.argmin(np.abs(ys - my)))))
    ops = _opensees()

    def build():
        ops.wipe()
        ops.model("basic", "-ndm", 3, "-ndf", 6)
        for i, x in enumerate(xs):
            for j, y in enumerate(ys):
                ops.node(tag(i, j), float(x), float(y), 0.0)
                ops.fix(tag(i, j), 1, 1, 0, 0, 0, 1)  # in-plane motion and drilling held
        ops.section("ElasticMembranePlateSection", 1, E, nu, h, rho)
        for i in range(nx - 1):
            for j in range(ny - 1):
                ops.element(element, 1 + i * (ny - 1) + j, tag(i, j), tag(i + 1, j), tag(i + 1, j + 1), tag(i, j + 1), 1)

    build()
    for i, j in held:
        ops.fix(tag(i, j), 0, 0, 1, 0, 0, 0)
    frequencies = np.sqrt(np.asarray(ops.eigen(n_frequencies))) / (2 * math.pi)
    if motion is None:
        ops.wipe()
        nan = np.full(len(gauges), np.nan)
        return PlateFEResponse(frequencies, gauges, np.zeros((0, len(gauges))), nan, nan, float(element_size),
                               element, float(dt))

    build()
    steps = int(math.ceil(window / dt))
    t = np.arange(steps + 11) * dt
    tau, dvA, dvB = float(motion.duration), float(motion.dvA), float(motion.dvB)
    ops.pattern("MultipleSupport", 1)
    columns = sorted({i for i, _ in held})
    for k, i in enumerate(columns):  # one ground motion per column of held nodes: the housing's motion there
        s = xs[i] / L
        series = []
        for q, history in enumerate(_support_history((1 - s) * dvA + s * dvB, tau, t)):
            series.append(100 * (k + 1) + q)
            ops.timeSeries("Path", series[-1], "-dt", dt, "-values", *history.tolist())
        ops.groundMotion(k + 1, "Plain", "-disp", series[0], "-vel", series[1], "-accel", series[2])
    for i, j in held:
        ops.imposedMotion(tag(i, j), 3, columns.index(i) + 1)
    ops.constraints("Transformation")
    ops.numberer("RCM")
    ops.system("BandGeneral")
    ops.test("NormDispIncr", 1e-12, 10)
    ops.algorithm("Linear", "-factorOnce")  # linear, constant step: one factorisation (6x faster per step)
    ops.integrator("Newmark", 0.5, 0.25)
    ops.analysis("Transient")

    stencils = []
    for gx, gy in gauges:
        i, j = int(np.argmin(np.abs(xs - gx))), int(np.argmin(np.abs(ys - gy)))
        if not (0 < i < nx - 1 and 0 < j < ny - 1):
            raise ValueError(f"gauge ({gx}, {gy}) m: valid inside the plate, one element from its edges")
        stencils.append((i, j))
    strain = np.zeros((steps, len(gauges)))
    for step in range(steps):
        if ops.analyze(1, dt) != 0:
            raise RuntimeError(f"OpenSees failed at step {step + 1}")
        for g, (i, j) in enumerate(stencils):
            w = np.array([[ops.nodeDisp(tag(i + a, j + b), 3) for b in (-1, 0, 1)] for a in (-1, 0, 1)])
            hm, hp, km, kp = xs[i] - xs[i - 1], xs[i + 1] - xs[i], ys[j] - ys[j - 1], ys[j + 1] - ys[j]
            wxx = 2 * ((w[2, 1] - w[1, 1]) / hp - (w[1, 1] - w[0, 1]) / hm) / (hp + hm)
            wyy = 2 * ((w[1, 2] - w[1, 1]) / kp - (w[1, 1] - w[1, 0]) / km) / (kp + km)
            wxy = (w[2, 2] - w[2, 0] - w[0, 2] + w[0, 0]) / ((hp + hm) * (kp + km))
            centre, radius = (wxx + wyy) / 2, math.hypot((wxx - wyy) / 2, wxy)
            strain[step, g] = h / 2 * (abs(centre) + radius)
    ops.wipe()
    peak_strain, peak_time = strain.max(axis=0), (strain.argmax(axis=0) + 1) * dt
    for g in range(len(gauges)):
        j = int(strain[:, g].argmax())
        if 0 < j < steps - 1:
            lo, mid, hi = strain[j - 1:j + 2, g]
            curv = lo - 2 * mid + hi
            if curv < 0:
                offset = 0.5 * (lo - hi) / curv
                peak_strain[g] = mid - 0.25 * (lo - hi) * offset
                peak_time[g] += offset * dt
    return PlateFEResponse(frequencies, gauges, strain, peak_strain, peak_time, float(element_size), element, float(dt))
