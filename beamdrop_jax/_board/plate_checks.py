"""A plate's supports and where thin-plate theory holds: mechanisms (a rigid motion the edges and mounts leave
free), mount discs on the plate, strain gauges on it, the thickness and deflection limits of Kirchhoff theory.
Eager checks raise naming the mounts, gauges or fields; the traceable ones set `Flag` bits. Duck-typed on the
plate's fields (`plate.py` builds on these)."""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._common.checks import Flag, combine, flag_if, is_concrete, on_host


THIN_PLATE_RATIO = 0.1
"""Largest thickness over the plate's shorter side for Kirchhoff (thin-plate) theory (see the module notes)."""

DEFLECTION_RATIO = 0.25
"""Largest peak deflection over the plate's shorter side for small-rotation kinematics (see the module notes)."""

_EDGE_NAMES = ("x = 0", "y = -W/2", "x = L", "y = +W/2")


def _edge_distances(xp, plate):
    """Each mount's signed distance (m) to the edges x = 0, y = -W/2, x = L, y = +W/2 (in `edges` order), (..., m, 4);
    negative off the plate."""
    L, W = (xp.asarray(v)[..., None] for v in (plate.length, plate.width))
    x, y = plate.mounts[..., 0], plate.mounts[..., 1]
    return xp.stack(xp.broadcast_arrays(x, y + W / 2, L - x, W / 2 - y), axis=-1)


class _Supports(NamedTuple):
    """The support geometry of a plate (arrays with the plate's batch axes): per mount `off_plate` (not on the
    plate, or not finite) and `crossing` (its disc across an edge it does not sit on), per pair of mounts
    `coincide` (closer than `mount_radius`; pairs (i, j), i < j, in `np.triu_indices` order), and `hold`: over the
    rigid tilts its edges leave free, the least of the largest distance of a mount from the tilt's axis (m; inf
    where the edges hold every rigid motion, 0 for a mechanism)."""

    off_plate: Array
    crossing: Array
    coincide: Array
    hold: Array


def _held_by_edges(edges: str) -> bool:
    """A clamped edge, or two supported edges, leave the plate no rigid motion."""
    return "C" in edges or edges.count("S") >= 2


def _support_geometry(xp, plate) -> _Supports:
    """The plate's `_Supports` with `xp` (NumPy for eager checks and messages, jax.numpy under tracing; no gradient
    flows through a check, and none is built: the distances' square roots are singular where mounts coincide)."""
    if xp is jnp:
        plate = jax.tree_util.tree_map(jax.lax.stop_gradient, plate)
    L, W, r = (xp.asarray(v) for v in (plate.length, plate.width, plate.mount_radius))
    batch = xp.broadcast_shapes(xp.shape(L), xp.shape(W), xp.shape(r),
                                () if plate.mounts is None else xp.shape(plate.mounts)[:-2])
    inf = xp.full(batch, xp.inf, dtype=xp.result_type(L))
    if plate.mounts is None:
        none = xp.zeros(batch + (0,), dtype=bool)
        return _Supports(none, none, none, inf if _held_by_edges(plate.edges) else xp.zeros_like(inf))
    d = _edge_distances(xp, plate)
    m = plate.mounts.shape[-2]
    size = xp.maximum(L, W)[..., None, None]
    on_edge = xp.abs(d) <= 1e-9 * size  # a mount on an edge: a boundary point support (a corner: two edges)
    off_plate = ~xp.all((d >= 0) | on_edge, axis=-1)
    crossing = xp.any((d < r[..., None, None]) & ~on_edge, axis=-1) & ~off_plate
    i, j = np.triu_indices(m, 1)
    sep = plate.mounts[..., j, :] - plate.mounts[..., i, :]  # (..., pairs, 2)
    dist = xp.sqrt(xp.sum(sep * sep, axis=-1))
    coincide = ~(dist >= r[..., None])
    if _held_by_edges(plate.edges):
        hold = inf
    elif "S" in plate.edges:  # the turn about the one supported edge: held by the mount farthest from it
        hold = xp.max(xp.maximum(d[..., plate.edges.index("S")], 0.0), axis=-1)
    elif m < 3:  # free edges: every mount lies on one line
        hold = xp.zeros_like(inf)
    else:
        # Free edges: the mounts' smallest width (the narrowest strip holding them all), halved. It is attained
        # across one side of their convex hull, so the directions normal to the pairs' separations are enough.
        apart = dist > 0
        n = xp.stack([-sep[..., 1], sep[..., 0]], axis=-1) / xp.where(apart, dist, 1.0)[..., None]
        proj = xp.sum(plate.mounts[..., None, :, :] * n[..., :, None, :], axis=-1)  # (..., pairs, m)
        widths = xp.where(apart, xp.max(proj, axis=-1) - xp.min(proj, axis=-1), xp.inf)
        width = xp.min(widths, axis=-1)
        hold = xp.where(width < xp.inf, width / 2, 0.0)  # every pair coincides: a single point
    return _Supports(off_plate, crossing, coincide, xp.broadcast_to(hold, batch))


def _too_thick(xp, plate):
    return ~(xp.asarray(plate.thickness) <= THIN_PLATE_RATIO * xp.minimum(plate.length, plate.width))


def _static_mechanism(plate) -> str | None:
    """The message for a plate whose edges, without mounts, leave it a rigid motion (known from the edges alone,
    so raised under tracing too), or None."""
    if plate.mounts is not None or _held_by_edges(plate.edges):
        return None
    if "S" in plate.edges:
        edge = _EDGE_NAMES[plate.edges.index("S")]
        return (f"Plate.edges = {plate.edges!r} without mounts is a mechanism: the plate turns freely about its one "
                f"supported edge {edge}; valid: a mount at least mount_radius from that edge (Plate.mounts), a second "
                "supported edge or a clamped one")
    return (f"a plate with free edges (Plate.edges = {plate.edges!r}) and no mounts moves as a rigid body (a "
            "mechanism); valid: at least 3 mounts not on one line (Plate.mounts), or supported or clamped edges")


def _fmt_points(points) -> str:
    return "[" + ", ".join(f"({x:.6g}, {y:.6g})" for x, y in np.asarray(points).reshape(-1, 2)) + "]"


def _plate_problem(plate) -> str | None:
    """The first problem of a concrete plate (NumPy fields; in a batch, the first plate with one), as a message
    naming the field and its valid range, or None."""
    batch = np.broadcast_shapes(*(np.shape(v) for v in (plate.length, plate.width, plate.thickness,
                                                         plate.mount_radius)),
                                () if plate.mounts is None else np.shape(plate.mounts)[:-2])
    if batch:
        g = _support_geometry(np, plate)
        bad = np.broadcast_to(_too_thick(np, plate), batch)
        if plate.mounts is not None:
            bad = bad | np.broadcast_to(np.any(g.off_plate | g.crossing, axis=-1) | np.any(g.coincide, axis=-1)
                                        | ~(g.hold >= plate.mount_radius), batch)
        if not np.any(bad):
            return None
        k = np.unravel_index(int(np.argmax(bad)), batch)
        pick = lambda v, tail=0: np.broadcast_to(v, batch + np.shape(v)[np.ndim(v) - tail:])[k]  # noqa: E731
        fields = (pick(plate.length), pick(plate.width), pick(plate.thickness), pick(plate.mount_radius))
        single = eqx.tree_at(lambda p: (p.length, p.width, p.thickness, p.mount_radius), plate, fields)
        if plate.mounts is not None:
            single = eqx.tree_at(lambda p: p.mounts, single, pick(plate.mounts, 2))
        return _plate_problem(single)
    L, W, r, h = (float(v) for v in (plate.length, plate.width, plate.mount_radius, plate.thickness))
    if _too_thick(np, plate):
        return (f"Plate.thickness = {h:g} m is {h / min(L, W):.3g} of the plate's shorter side ({min(L, W):g} m): "
                "outside thin-plate (Kirchhoff) theory, which neglects transverse shear and rotary inertia "
                f"(Flag.OUTSIDE_THEORY); valid: thickness <= {THIN_PLATE_RATIO:g} x min(length, width) = "
                f"{THIN_PLATE_RATIO * min(L, W):g} m")
    if plate.mounts is None:
        return None
    g = _support_geometry(np, plate)
    mounts = np.asarray(plate.mounts)
    if np.any(g.off_plate):
        return (f"Plate.mounts = {mounts.tolist()} m; valid: 0 <= x <= length = {L:g} m and |y| <= width/2 = "
                f"{W / 2:g} m (mount {int(np.argmax(g.off_plate))} is off the plate; Flag.MOUNT_OUTSIDE_PLATE)")
    if np.any(g.crossing):
        k = int(np.argmax(g.crossing))
        d = _edge_distances(np, plate)[k]
        e = int(np.argmin(np.where((d < r) & (np.abs(d) > 1e-9 * max(L, W)), d, np.inf)))
        return (f"Plate.mounts[{k}] = ({mounts[k, 0]:g}, {mounts[k, 1]:g}) m: its disc of mount_radius = {r:g} m "
                f"crosses the edge {_EDGE_NAMES[e]} ({d[e]:.3g} m away), so the plate's peak would be sought off "
                "the plate (Flag.MOUNT_OUTSIDE_PLATE); valid: each mount's disc on the plate, "
                + (f"{r:g} <= x <= {L - r:g} m and |y| <= {W / 2 - r:g} m" if 2 * r <= min(L, W) else
                   f"which needs Plate.mount_radius <= min(length, width) / 2 = {min(L, W) / 2:g} m")
                + ", or the mount on the edge itself (a boundary point support)")
    if not g.hold >= r:
        return _mechanism_message(plate, float(g.hold), r)
    if np.any(g.coincide):
        p = int(np.argmax(g.coincide))
        i, j = (int(v[p]) for v in np.triu_indices(mounts.shape[0], 1))
        gap = float(np.hypot(*(mounts[j] - mounts[i])))
        return (f"Plate.mounts {i} and {j} are {gap:.3g} m apart, closer than mount_radius = {r:g} m: the model "
                "cannot tell them apart (one lies in the other's disc, where nothing is resolved; identical mounts "
                f"make the constraint singular) (Flag.MOUNTS_COINCIDE); valid: mounts at least {r:g} m apart")
    return None


def _mechanism_message(plate, hold: float, r: float) -> str:
    mounts = np.asarray(plate.mounts)
    what = "a mechanism" if hold <= 1e-12 * max(float(plate.length), float(plate.width)) else "a near-mechanism"
    if "S" in plate.edges:
        edge = _EDGE_NAMES[plate.edges.index("S")]
        return (f"Plate.mounts = {_fmt_points(mounts)} m with Plate.edges = {plate.edges!r} leave {what} "
                f"(Flag.MECHANISM): the plate turns about its one supported edge {edge}, and every mount "
                f"(0 to {mounts.shape[0] - 1}) lies within {hold:.3g} m of that edge, so the turn is held only inside "
                f"the mount discs the model leaves out; valid: a mount at least mount_radius = {r:g} m from the "
                "edge, or a second supported or a clamped edge")
    # Free edges: the axis is the centre line of the narrowest strip holding the mounts.
    m = mounts.shape[0]
    i, j = np.triu_indices(m, 1)
    sep = mounts[j] - mounts[i]
    dist = np.hypot(sep[:, 0], sep[:, 1])
    if m >= 3 and np.any(dist > 0):
        n = np.stack([-sep[:, 1], sep[:, 0]], -1) / np.where(dist > 0, dist, 1.0)[:, None]
        proj = n @ mounts.T
        p = int(np.argmin(np.where(dist > 0, proj.max(-1) - proj.min(-1), np.inf)))
        where = (f"mounts {', '.join(map(str, range(m)))} all lie within {hold:.3g} m of one line (along mounts "
                 f"{int(i[p])} and {int(j[p])}): " + ("collinear" if what == "a mechanism" else "nearly collinear"))
    elif m >= 2:
        where = f"mounts {', '.join(map(str, range(m)))} lie on one line (fewer than 3 mounts)"
    else:
        where = "one mount holds a single point"
    close = [(int(a), int(b)) for a, b, dd in zip(i, j, dist) if dd < r]
    if close:
        where += "; " + ", ".join(f"mounts {a} and {b} (nearly) coincident" for a, b in close) + (
            " (Flag.MOUNTS_COINCIDE: closer than mount_radius)")
    return (f"Plate.mounts = {_fmt_points(mounts)} m with free edges (Plate.edges = {plate.edges!r}) leave {what} "
            f"(Flag.MECHANISM): {where}, so the plate tilts about that line held only inside the mount discs the "
            f"model leaves out; valid: at least 3 mounts not on one line, spread at least 2 x mount_radius = "
            f"{2 * r:g} m across any line (no line within mount_radius of every mount), or supported or clamped "
            "edges")


def _gauges_off(xp, plate, points):
    """Per gauge point (g, 2): not finite, off the plate, or inside a mount's disc (on its circle is on the plate)."""
    if xp is jnp:
        plate, points = jax.tree_util.tree_map(jax.lax.stop_gradient, (plate, points))
    x, y = points[..., 0], points[..., 1]
    on = (xp.isfinite(x) & xp.isfinite(y) & (x >= 0) & (x <= plate.length) & (xp.abs(y) <= plate.width / 2))
    if plate.mounts is None:
        return ~on
    inside = xp.any(xp.hypot(x[..., None] - plate.mounts[:, 0], y[..., None] - plate.mounts[:, 1])
                    < plate.mount_radius * (1 - 1e-9), axis=-1)
    return ~on | inside


def check_gauges(board, points) -> None:
    """Eagerly, a `ValueError` naming the first strain gauge (of points (g, 2), m) that is not finite, off the plate
    or inside a mount's disc (where a point support's strain is singular), and the valid region; no-op when traced
    or for a beam (whose gauges are refused elsewhere)."""
    if points is None or not is_concrete(board, points):
        return
    plate, points = on_host(board), np.asarray(points)
    off = _gauges_off(np, plate, points)
    if not np.any(off):
        return
    k = int(np.argmax(off))
    L, W = float(plate.length), float(plate.width)
    why = ("is not finite" if not np.all(np.isfinite(points[k])) else
           "is off the plate" if not (0 <= points[k, 0] <= L and abs(points[k, 1]) <= W / 2) else
           f"is inside a mount's disc (mount_radius = {float(plate.mount_radius):g} m), where the point support's "
           "strain is singular")
    discs = "" if plate.mounts is None else (f", outside the discs of mount_radius = {float(plate.mount_radius):g} m"
                                             f" around the mounts {_fmt_points(plate.mounts)} m")
    raise ValueError(f"gauges[{k}] = ({points[k, 0]:g}, {points[k, 1]:g}) m {why} (Flag.GAUGE_OUTSIDE); valid: "
                     f"0 <= x <= length = {L:g} m and |y| <= width/2 = {W / 2:g} m{discs}")


def response_flags(plate, deflection, gauges=None):
    """Traceable checks of a plate's response: `Flag.OUTSIDE_THEORY` where the peak deflection (m) exceeds
    `DEFLECTION_RATIO` of the shorter side (beyond small rotations), `Flag.GAUGE_OUTSIDE` where a gauge point
    ((g, 2), m, or None) is not finite, off the plate or inside a mount's disc."""
    limit = DEFLECTION_RATIO * jnp.minimum(plate.length, plate.width)
    flags = flag_if(jax.lax.stop_gradient(deflection) > limit, Flag.OUTSIDE_THEORY)
    if gauges is not None:
        flags = combine(flags, flag_if(jnp.any(_gauges_off(jnp, plate, gauges)), Flag.GAUGE_OUTSIDE))
    return flags


def clip_to_plate(plate, x, y):
    """Points (x, y) (m) moved onto the plate's rectangle where they lie off it (inside, untouched, gradient
    included: a point on an edge keeps its own derivative)."""
    L, W = plate.length, plate.width
    x = jnp.where(x < 0, jnp.zeros_like(x), jnp.where(x > L, L, x))
    y = jnp.where(y < -W / 2, -W / 2, jnp.where(y > W / 2, W / 2, y))
    return x, y


def plate_grid_deflection(modes, Q, mask):
    """The largest |deflection| (m) on the plate's search grid (2 points per basis function each way, edges
    included), from the modal factors Q = (scale (n,), R (nt, n)) and the mode mask: a cheap stand-in for the
    deflection peak where only `response_flags` needs it (no gradient)."""
    plate = modes.plate
    xi, eta = (jnp.linspace(lo, lo + 1.0, 2 * b + 1) for lo, b in zip((0.0, -0.5), plate.basis))
    XI, ETA = (v.ravel() for v in jnp.meshgrid(xi, eta, indexing="ij"))
    phi = modes.shapes(XI * plate.length, ETA * plate.width, derivatives=False)
    scale, R = Q
    u = (phi * (mask * scale)) @ R.T
    return jax.lax.stop_gradient(jnp.max(jnp.abs(u)))


def blank_readings(gauges, bad):
    """Gauge readings (`Gauges`) NaN where the response is flagged (`bad`): never a silent number."""
    names = ("exx", "eyy", "gxy", "strain", "peak_strain", "peak_time")
    return eqx.tree_at(lambda g: [getattr(g, n) for n in names], gauges,
                       [jnp.where(bad, jnp.nan, getattr(gauges, n)) for n in names])


def raise_if_outside_theory(board, flags, what: str) -> None:
    """Eagerly, a plate response's `Flag.OUTSIDE_THEORY` (its deflection; a thick plate is refused when built) as a
    `ValueError` naming the fields and the valid range."""
    if not int(flags) & Flag.OUTSIDE_THEORY:
        return
    plate = on_host(board)
    short = float(np.min(np.minimum(plate.length, plate.width)))
    raise ValueError(
        f"{what}: the plate's peak deflection exceeds {DEFLECTION_RATIO:g} of its shorter side "
        f"({DEFLECTION_RATIO * short:.4g} m; Flag.OUTSIDE_THEORY): rotations too large for plate theory, whose "
        "kinematics assume small slopes (a half-wave's slope pi w / a reaches pi/4 there); the board is too flexible "
        f"for this drop (Plate.thickness = {float(np.max(plate.thickness)):g} m, Plate.youngs_modulus = "
        f"{float(np.max(plate.youngs_modulus)):g} Pa); valid: peak deflection <= {DEFLECTION_RATIO:g} x "
        "min(length, width): a thicker or stiffer plate, more support, or a gentler drop")


def plate_notes(plate, response) -> list[str]:
    """What a reader of a plate's numbers should know beyond a beam's notes (`response_notes`)."""
    notes = []
    h, short = float(plate.thickness), min(float(plate.length), float(plate.width))  # floats: no eager JAX op
    if h > short / 20:
        notes.append(f"the plate's thickness is {h / short:.2g} of its shorter side: thin-plate (Kirchhoff) theory "
                     "neglects transverse shear and rotary inertia, which lower the frequencies (by about 1 % at "
                     f"1/20, 3.5 % at 1/10, Mindlin); beyond {THIN_PLATE_RATIO:g} the plate is refused")
    return notes
