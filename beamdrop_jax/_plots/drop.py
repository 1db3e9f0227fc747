"""The figures of one drop: its impact, the scene, the board's stress, deflection and strain."""

import numpy as np

from .._impact.routh import ImpactMode, routh_impulse
from .._common.checks import on_host
from .._impact.kinematics import body_axes, housing_impact
from .._scene.containers import board_ends
from .common import _axes, _legend_below


def plot_impact(B, v0, friction, restitution, law: str = "poisson", *, ax=None, title: str | None = None):
    """Impact process diagram in the impulse plane (Pt horizontal, Pn vertical), as the thesis's figures 3.5 and 4.2.

    Draws the friction cone's edges, the stick line (S = 0), the line of maximum compression (C = 0), the
    termination level, and the impulse path with its vertices marked; the title names the contact mode.
    """
    res = routh_impulse(B, v0, friction, restitution, law=law)
    B = np.asarray(B, float)
    S0, C0 = np.asarray(v0, float)
    B1, B2, B3 = B[0, 0], B[1, 1], -B[0, 1]
    mu = float(friction)
    path, P = np.asarray(res.path), np.asarray(res.P)  # NumPy: indexing a JAX array compiles a program
    fig, ax = _axes(ax)
    top = 1.25 * max(float(path[:, 1].max()), 1e-12)
    pn = np.linspace(0.0, top, 2)
    span = max(np.abs(path[:, 0]).max(), mu * top, 1e-12) * 1.3
    ax.fill_betweenx(pn, -mu * pn, mu * pn, color="0.93", label="friction cone")
    ax.plot(mu * pn, pn, color="0.5", lw=1)
    ax.plot(-mu * pn, pn, color="0.5", lw=1)
    # S = S0 + B1 Pt - B3 Pn = 0 and C = C0 - B3 Pt + B2 Pn = 0.
    ax.plot((B3 * pn - S0) / B1, pn, "--", color="tab:green", label="stick line S = 0")
    pt = np.linspace(-span, span, 2)
    ax.plot(pt, (B3 * pt - C0) / B2, "--", color="tab:blue", label="max compression C = 0")
    ax.axhline(P[1], color="tab:red", lw=0.8, ls=":", label=f"termination ({law})")
    ax.plot(path[:, 0], path[:, 1], "-o", color="k", ms=4, lw=2, label="impulse path")
    pn_c = float(res.Pn_compression)
    ax.plot([np.interp(pn_c, path[:, 1], path[:, 0])], [pn_c], "D", color="tab:blue", ms=6, label="max compression")
    ax.plot([P[0]], [P[1]], "*", color="tab:red", ms=12, label="final impulse P")
    ax.set_xlim(-span, span)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("tangential impulse $P_t$ (N s)")
    ax.set_ylabel("normal impulse $P_n$ (N s)")
    mode = ImpactMode(int(res.mode)).label
    ax.set_title(title or f"Impact process: {mode}; P = ({P[0]:.4g}, {P[1]:.4g}) N s")
    _legend_below(ax, ncol=3)
    return fig


def _flat_face(orientation) -> int:
    """The face (ISTA numbering: 1 top +e2, 2 right +e1, 3 bottom -e2, 4 left -e1) that lands flat at
    orientation k x 90 deg."""
    return {0: 3, 1: 4, 2: 1, 3: 2}[round(float(orientation) / (np.pi / 2)) % 4]


def plot_flat_landing(hit, scene, *, ax=None, title: str | None = None):
    """A flat landing in the impulse plane: the housing lands on a face, both its corners at once, and translates;
    the impulse the drop uses (`hit.impact.P`, both corners' total) is normal, (1 + e) times the momentum, and
    friction plays no part (no tangential velocity)."""
    fig, ax = _axes(ax)
    P = np.asarray(hit.impact.P, float)
    e = float(scene.contact.restitution)
    pn = float(P[1])
    top = 1.25 * max(pn, 1e-12)
    ax.axhline(pn, color="tab:red", lw=0.8, ls=":", label="termination: (1 + e) m v")
    ax.plot([0.0, P[0]], [0.0, pn], "-", color="k", lw=2, label="impulse path (straight up)")
    ax.plot([P[0]], [pn], "*", color="tab:red", ms=12, label="final impulse P (both corners)")
    ax.plot([0.0], [pn / (1.0 + e)], "D", color="tab:blue", ms=6, label="max compression: m v")  # on P when e = 0
    ax.set_xlim(-0.5 * top, 0.5 * top)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("tangential impulse $P_t$ (N s)")
    ax.set_ylabel("normal impulse $P_n$ (N s)")
    ax.text(0.02, 0.97, f"e = {e:g}; no tangential velocity: friction plays no part", transform=ax.transAxes,
            fontsize=8, color="0.35", va="top")
    face = _flat_face(scene.drop.orientation)
    ax.set_title(title or f"Flat landing on face {face} (translation); P = ({P[0]:.4g}, {pn:.4g}) N s", fontsize=11)
    _legend_below(ax, ncol=2)
    return fig


def plot_housing_impact(scene, hit=None, law: str = "poisson", *, ax=None, title: str | None = None):
    """The housing's first impact as the drop uses it: the Routh diagram of a corner impact (`plot_impact`), or
    for a flat landing the translation answer (`plot_flat_landing`). `hit`: a `HousingImpact` (default computed
    with `law`)."""
    hit = housing_impact(scene, law=law) if hit is None else hit
    if bool(hit.flat):
        return plot_flat_landing(hit, scene, ax=ax, title=title)
    return plot_impact(hit.B, hit.v0, scene.contact.friction, scene.contact.restitution, law=law, ax=ax, title=title)


def plot_stress_map(fields, response, *, ax=None):
    """Bending stress over the board (x from end A) and time as a heat map, with the peak marked. A clattering
    drop (`Response.impacts` with several impacts) gets one panel per impact, time measured from that impact."""
    import matplotlib.pyplot as plt

    impacts = getattr(response, "impacts", None)
    K = 1 if impacts is None else int(np.shape(impacts.t)[0])
    count = 1 if impacts is None else int(impacts.count)
    t_all = np.asarray(fields.t).reshape(K, -1)
    stress_all = np.asarray(fields.stress).reshape(len(fields.x), K, -1) / 1e6
    if count > 1 and ax is None:
        fig, axes = plt.subplots(1, count, figsize=(3.2 * count + 1.5, 4.5), layout="constrained", sharey=True)
    else:
        fig, ax = _axes(ax, (7.0, 4.5))
        axes = [ax]
    x_mm = np.asarray(fields.x) * 1e3
    lim = np.abs(stress_all[:, : len(axes)]).max()
    peak = response.peak
    for i, ax in enumerate(axes):
        start = float(impacts.t[i]) if count > 1 else 0.0
        t_ms = (t_all[i] - start) * 1e3
        mesh = ax.pcolormesh(t_ms, x_mm, stress_all[:, i], cmap="RdBu_r", vmin=-lim, vmax=lim, shading="auto",
                             rasterized=True)
        ends = t_all[i][0], t_all[i][-1]
        if ends[0] <= float(peak.t) <= ends[1] and (count == 1 or i == _impact_of(impacts, float(peak.t))):
            ax.plot((float(peak.t) - start) * 1e3, float(peak.x) * 1e3, "k*", ms=14, mfc="yellow",
                    label=f"peak |stress| {float(peak.stress) / 1e6:.1f} MPa")
            ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel("time after impact (ms)" if count == 1 else f"ms after impact {i + 1} (t = {start * 1e3:.1f} ms)")
    axes[0].set_ylabel("position along the board from end A (mm)")
    fig.colorbar(mesh, ax=list(axes), label="bending stress (MPa), normal-side face; + tension")
    title = f"Stress over the board and time ({int(response.n_modes)} modes)"
    if count > 1:
        fig.suptitle(title + f", {count} impacts")
    else:
        axes[0].set_title(title)
    return fig


def _impact_of(impacts, t):
    """Index of the last applied impact at or before time t."""
    times = np.asarray(impacts.t)[: int(impacts.count)]
    return int(np.searchsorted(times, t, side="right") - 1)


def plot_deflected_board(fields, response, *, thickness=None, ax=None):
    """Deflection relative to the chord AB at the time of peak deflection and at the time of peak stress, with
    both peaks' positions marked (end A is x = 0). With the board's `thickness` (m) it says so when the deflection
    exceeds it, where small-deflection theory stops holding."""
    fig, ax = _axes(ax, (7.5, 4.6))
    x_mm = np.asarray(fields.x) * 1e3
    peak = response.peak
    shapes = {}
    for when, colour, what in ((float(peak.deflection_t), "tab:blue", "peak deflection"),
                               (float(peak.t), "tab:red", "peak stress")):
        j = int(np.abs(np.asarray(fields.t) - when).argmin())
        shapes[what] = np.asarray(fields.deflection)[:, j] * 1e3
        ax.plot(x_mm, shapes[what], color=colour, lw=2, label=f"shape at {what}, t = {np.asarray(fields.t)[j] * 1e3:.3f} ms")
    xd = float(peak.deflection_x) * 1e3
    ax.plot(xd, np.interp(xd, x_mm, shapes["peak deflection"]), "o", color="tab:blue",
            label=f"peak deflection {float(peak.deflection) * 1e3:.3g} mm at x = {xd:.1f} mm")
    ax.axvline(float(peak.x) * 1e3, color="tab:red", ls="--", lw=1,
               label=f"peak stress {float(peak.stress) / 1e6:.3g} MPa at x = {float(peak.x) * 1e3:.1f} mm")
    ax.plot([x_mm[0], x_mm[-1]], [0, 0], "k^", ms=10, label="supports: end A (x = 0) and end B")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("position along the board from end A (mm)")
    ax.set_ylabel("deflection from chord AB (mm)")
    title = "Deflected board, relative to its moving supports (+ along the board normal)"
    if thickness is not None and float(peak.deflection) > float(thickness):
        title += (f"\ndeflection {float(peak.deflection) / float(thickness):.2g} x the thickness: beyond "
                  "small-deflection theory (mid-plane stretching matters)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    return fig


def plot_scene(scene, response=None, *, ax=None):
    """The scene at the instant of impact, in the plane of the model: the housing (its width and height; the
    device's third dimension and the board's width point out of the page) with its lowest corner S on the ground
    (a flat landing: the whole face, both corners striking), the centre of mass G, the board from end A to end B
    with its supports, the velocity of G before impact and the ground's impulse (from `response`, or computed).
    Arrows give directions; their values are in their labels."""
    from matplotlib.patches import Polygon

    th = float(scene.drop.orientation)
    e1, e2 = body_axes(th)
    W, H = float(scene.housing.width), float(scene.housing.height)
    hit = response.housing if response is not None and response.housing is not None else housing_impact(scene)
    G = np.asarray(hit.r, float)  # ground frame with the striking corner S at the origin
    flat = bool(hit.flat)

    def ground(q):
        q = np.asarray(q, float)
        return (G + q[..., :1] * e1 + q[..., 1:] * e2) * 1e3

    box = ground(np.array([[W / 2, H / 2], [-W / 2, H / 2], [-W / 2, -H / 2], [W / 2, -H / 2]]))
    size = 1e3 * max(W, H)
    arrow_mm = 0.25 * size  # every arrow this long: directions, not magnitudes
    v = np.array([float(scene.drop.horizontal_speed), -float(np.sqrt(2 * 9.80665 * float(scene.drop.height)))])
    speed = np.linalg.norm(v)
    G_mm = G * 1e3
    tail = G_mm - v / speed * arrow_mm if speed > 0 else G_mm  # the velocity arrow ends at G
    lo_x = min(box[:, 0].min(), 0.0, tail[0]) - 0.08 * size
    hi_x = max(box[:, 0].max(), 0.0, tail[0]) + 0.08 * size
    lo_y, hi_y = -0.06 * size, max(box[:, 1].max(), tail[1], arrow_mm) + 0.08 * size
    if ax is None:  # the figure's shape follows the drawing's: no wide empty margins around a flat housing
        width = 8.0
        ax_height = (width - 1.0) * (hi_y - lo_y) / (hi_x - lo_x)
        fig, ax = _axes(None, (width, float(np.clip(ax_height + 1.7, 3.0, 9.0))))
    fig = ax.figure
    ax.add_patch(Polygon(box, closed=True, fc="0.93", ec="0.25", lw=1.5, label="housing (rigid)"))
    ends = ground(board_ends(on_host(scene.placement), float(scene.board.length)))
    ax.plot(ends[:, 0], ends[:, 1], color="tab:green", lw=4, solid_capstyle="butt", label="board")
    mounts = getattr(scene.board, "mounts", None)
    if mounts is None:  # a beam: held at its ends
        ax.plot(ends[:, 0], ends[:, 1], "^", color="tab:green", mec="k", ms=10,
                label=f"supports ({scene.board.ends})")
    else:  # a plate: its mounts along the board, seen edge-on
        along = np.asarray(mounts)[:, 0] / float(scene.board.length)
        held = ends[0] + along[:, None] * (ends[1] - ends[0])
        ax.plot(held[:, 0], held[:, 1], "^", color="tab:green", mec="k", ms=10, label="mounts (seen edge-on)")
    ax.annotate("A", ends[0], xytext=(-12, 6), textcoords="offset points", fontsize=11, weight="bold")
    ax.annotate("B", ends[1], xytext=(6, 6), textcoords="offset points", fontsize=11, weight="bold")
    ax.plot(*G_mm, "ko", ms=7, mfc="w", mew=2)
    ax.annotate("G", G_mm, xytext=(6, -12), textcoords="offset points", fontsize=11)
    ax.fill_between([lo_x, hi_x], [lo_y] * 2, [0, 0], color="0.55", hatch="///", alpha=0.5, lw=0)
    P = np.asarray(hit.impact.P, float)
    if flat:  # both lowest corners strike together: the face lands
        on_ground = box[np.argsort(box[:, 1])[:2]]
        on_ground = on_ground[np.argsort(on_ground[:, 0])]
        face = _flat_face(th)
        ax.plot(on_ground[:, 0], on_ground[:, 1], "-o", color="tab:red", lw=3, ms=8,
                label=f"face {face} strikes flat (both corners)")
        strikes = on_ground
    else:
        ax.plot(0, 0, "o", color="tab:red", ms=9, label="S: the corner that strikes")
        ax.annotate("S (strikes)", (0, 0), xytext=(-8, 6), textcoords="offset points", color="tab:red", fontsize=10,
                    ha="right")
        strikes = np.zeros((1, 2))
    if speed > 0:
        ax.annotate("", G_mm, tail, arrowprops=dict(arrowstyle="-|>", color="tab:blue", lw=2))
        ax.annotate(f"v_G = {speed:.3g} m/s", tail, xytext=(6, 0), textcoords="offset points", color="tab:blue",
                    fontsize=9, va="center")
    if np.linalg.norm(P) > 0:
        for i, at in enumerate(strikes):
            head = at + P / np.linalg.norm(P) * arrow_mm * (0.6 if flat else 1.0)
            ax.annotate("", head, at, arrowprops=dict(arrowstyle="-|>", color="tab:red", lw=2))
        what = "impulse of both corners" if flat else "impulse"
        inward = head[0] > (lo_x + hi_x) / 2  # the label on the side of the drawing's middle, inside the axes
        ax.annotate(f"{what} ({P[0]:.3g}, {P[1]:.3g}) N s", head, xytext=(-6 if inward else 6, 4),
                    textcoords="offset points", color="tab:red", fontsize=9, va="bottom",
                    ha="right" if inward else "left")
    ax.set_aspect("equal")
    ax.set_xlim(lo_x, hi_x)
    ax.set_ylim(lo_y, hi_y)
    ax.set_xlabel("ground x (mm)")
    ax.set_ylabel("height above ground (mm)")
    ax.set_title(
        f"Housing {W * 1e3:g} x {H * 1e3:g} mm, {float(scene.housing.mass) * 1e3:g} g, dropped "
        f"{float(scene.drop.height):.3g} m at {np.degrees(th):.1f} deg; board {float(scene.board.length) * 1e3:g} mm",
        fontsize=10,
    )
    _legend_below(ax, ncol=4, title="plane of the model: the housing's width and height; the board's width points "
                  "out of the page\narrows give directions, not to scale: their values are in their labels",
                  title_fontsize=7.5)
    return fig


def plot_impacts(scene, response):
    """The impact of a drop: the first impact's Routh diagram; with clattering, a second panel with every
    impact's time, approach speed and normal impulse."""
    import matplotlib.pyplot as plt


    hit = response.housing if response.housing is not None else housing_impact(scene)
    impacts = response.impacts
    count = 1 if impacts is None else int(impacts.count)
    if count == 1:
        return plot_housing_impact(scene, hit)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 4.8), layout="constrained")
    mode = "flat landing (translation)" if bool(hit.flat) else ImpactMode(int(hit.impact.mode)).label
    plot_housing_impact(scene, hit, ax=ax1, title=f"Impact 1 of {count}: {mode}")
    t = np.asarray(impacts.t)[:count] * 1e3
    Pn = np.asarray(impacts.P)[:count, 1]
    speed = np.asarray(impacts.approach_speed)[:count]
    ax2.stem(t, Pn, linefmt="tab:red", markerfmt="o", basefmt="0.6", label="normal impulse Pn (N s)")
    ax2.set_xlabel("time after the first impact (ms)")
    ax2.set_ylabel("normal impulse Pn (N s)", color="tab:red")
    twin = ax2.twinx()
    twin.plot(t, speed, "s", color="tab:blue", ms=7, label="approach speed (m/s)")
    twin.set_ylabel("corner approach speed (m/s)", color="tab:blue")
    twin.set_ylim(0, 1.15 * speed.max())
    ax2.set_ylim(0, 1.15 * Pn.max())
    for i in range(count):
        q = np.asarray(impacts.corner[i]) * 1e3
        ax2.annotate(f"#{i + 1}\ncorner ({q[0]:.0f}, {q[1]:.0f}) mm", (t[i], Pn[i]), xytext=(0, 8),
                     textcoords="offset points", ha="center", fontsize=8)
    ax2.set_title(f"Clattering: {count} impacts")
    return fig


def plot_plate_strain(strain_map, response, plate, *, axes=None):
    """Left: the largest principal surface strain over a plate at the peak time (microstrain), the mounts and
    their discs (where peaks are not searched), the peak and the gauges marked. Right: each gauge's principal
    strain history with its peak."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    if axes is None:
        fig, axes = plt.subplots(1, 2, figsize=(12.0, 4.2), layout="constrained", width_ratios=(1.5, 1.0))
    ax, hx = axes
    fig = ax.figure
    x, y = np.asarray(strain_map.x) * 1e3, np.asarray(strain_map.y) * 1e3
    strain = np.asarray(strain_map.strain) * 1e6
    holes = ~np.isfinite(strain)
    if np.any(holes) and not np.all(holes):
        # Inside the mount discs the map has no value; shaded as it is, the grid cells around each disc would show
        # as white square tabs beyond the drawn circle. Each hole takes its nearest value (the disc covers it).
        from scipy.ndimage import distance_transform_edt

        nearest = distance_transform_edt(holes, return_distances=False, return_indices=True)
        strain = strain[tuple(nearest)]
    mesh = ax.pcolormesh(x, y, strain.T, shading="gouraud", cmap="magma")
    fig.colorbar(mesh, ax=ax, label="largest principal surface strain (microstrain)")
    if plate.mounts is not None:
        r = float(plate.mount_radius) * 1e3
        for mx, my in np.asarray(plate.mounts) * 1e3:
            ax.add_patch(Circle((mx, my), r, facecolor="white", edgecolor="tab:cyan", lw=1.5))
            ax.plot(mx, my, "+", color="tab:cyan", ms=8)
        ax.plot([], [], "+", color="tab:cyan", label=f"mounts (discs r = {r:g} mm not searched)")
    peak = response.peak
    ax.plot(float(peak.strain_x) * 1e3, float(peak.strain_y) * 1e3, "*", ms=13, mfc="yellow", mec="k", zorder=4,
            label=f"peak {float(peak.strain) * 1e6:.0f} microstrain at t = {float(peak.strain_t) * 1e3:.3g} ms")
    gauges = response.gauges
    if gauges is not None:  # open squares around the star where a gauge sits on the peak, numbered
        gx, gy = np.asarray(gauges.x) * 1e3, np.asarray(gauges.y) * 1e3
        ax.plot(gx, gy, "s", ms=19, mfc="none", mec="lime", mew=2.5, zorder=5, label="gauges (numbered)")
        for i, (px, py) in enumerate(zip(gx, gy)):
            ax.annotate(f"{i + 1}", (px, py), xytext=(11, 7), textcoords="offset points", color="lime", fontsize=10,
                        weight="bold", zorder=5)
    ax.set_aspect("equal")
    ax.set_xlabel("x from end A (mm)")
    ax.set_ylabel("y across the width (mm)")
    ax.set_title(f"Surface strain at t = {float(strain_map.t) * 1e3:.3g} ms")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), fontsize=8, ncol=2, markerscale=0.7)
    if gauges is not None:
        t = np.asarray(gauges.t) * 1e3
        for i in range(len(np.asarray(gauges.x))):
            label = f"gauge {i + 1} ({float(gauges.x[i]) * 1e3:.1f}, {float(gauges.y[i]) * 1e3:.1f}) mm"
            line, = hx.plot(t, np.asarray(gauges.strain[i]) * 1e6, lw=1.2, label=label)
            hx.plot(float(gauges.peak_time[i]) * 1e3, float(gauges.peak_strain[i]) * 1e6, "o", color=line.get_color())
        hx.set_xlabel("t from the impact (ms)")
        hx.set_ylabel("largest principal strain (microstrain)")
        hx.set_title("Gauge histories")
        hx.grid(alpha=0.3)
        hx.legend(fontsize=8)
    else:
        hx.set_axis_off()
    return fig


def plot_gauge_history(t, strain, x, *, modulus=None, ax=None):
    """A strain gauge's reading over time: `strain` (-) at times `t` (s) at `x` (m from end A), on the board's
    normal-side face (+ tension), its largest magnitude marked; with the board's Young's `modulus` (Pa) a second
    axis gives the bending stress (MPa)."""
    fig, ax = _axes(ax, (7.5, 4.4))
    t_ms, micro = np.asarray(t) * 1e3, np.asarray(strain) * 1e6
    ax.plot(t_ms, micro, color="tab:blue", lw=1.5, label="strain")
    ax.axhline(0.0, color="0.6", lw=0.8)
    i = int(np.argmax(np.abs(micro)))
    ax.plot(t_ms[i], micro[i], "o", color="tab:red", ms=7,
            label=f"largest |strain| {abs(micro[i]):.4g} microstrain at t = {t_ms[i]:.3g} ms")
    ax.set_xlabel("time after impact (ms)")
    ax.set_ylabel("strain (microstrain), normal-side face; + tension")
    if modulus is not None:
        E = float(modulus) * 1e-12  # MPa per microstrain
        ax.secondary_yaxis("right", functions=(lambda e: e * E, lambda s: s / E)).set_ylabel("bending stress (MPa)")
    ax.set_title(f"Strain gauge at x = {float(x) * 1e3:.4g} mm from end A", fontsize=11)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return fig


def plot_sensitivity(rows, quantity: str = "stress", *, top: int = 15, ax=None):
    """A tornado chart of the elasticities (% change of the peak per % change of each scene field), largest
    magnitude on top, positive to the right; `rows` as `sensitivities` returns them (`Sensitivity` records or
    their `row()` dicts). Fields with no elasticity (value 0) are named under the chart."""
    get = (lambda r, k: r[k]) if rows and isinstance(rows[0], dict) else (lambda r, k: getattr(r, k))
    def effect(r):  # None: no elasticity (a field at 0); 0: none to round-off
        e = get(r, "elasticity")
        return None if e is None else (0.0 if abs(e) < 1e-9 else e)

    shown = sorted((r for r in rows if effect(r)), key=lambda r: -abs(effect(r)))
    shown, rest = shown[:top], shown[top:]
    fig, ax = _axes(ax, (7.5, 0.32 * max(len(shown), 4) + 2.2))
    names = [get(r, "field") for r in shown][::-1]
    values = np.array([get(r, "elasticity") for r in shown][::-1], float)
    colours = ["tab:red" if v > 0 else "tab:blue" for v in values]
    ax.barh(range(len(values)), values, color=colours, height=0.7)
    ax.set_yticks(range(len(values)), names, fontsize=8)
    ax.axvline(0.0, color="0.3", lw=0.8)
    span = max(float(np.abs(values).max()) if values.size else 1.0, 1e-12)
    for i, v in enumerate(values):
        ax.text(v + (0.01 if v >= 0 else -0.01) * span, i, f"{v:+.3g}", va="center", ha="left" if v >= 0 else "right",
                fontsize=7.5)
    ax.set_xlim(-1.25 * span if np.any(values < 0) else -0.05 * span, 1.25 * span if np.any(values > 0) else 0.05 * span)
    ax.set_xlabel(f"elasticity of the peak {quantity}: % change per % change of the field")
    ax.set_title(f"What the peak {quantity} is most sensitive to (red: raising the field raises it)", fontsize=10)
    zero = [get(r, "field") for r in rows if effect(r) is None]
    none = [get(r, "field") for r in rows if effect(r) == 0.0]
    notes = ([f"{len(rest)} smaller elasticities not drawn"] if rest else []) + (
        [f"no effect on the peak in this model (|elasticity| < 1e-9): {', '.join(none)}"] if none else []) + (
        [f"no elasticity (the field is 0; see its derivative in the table): {', '.join(zero)}"] if zero else [])
    if notes:
        import textwrap

        ax.annotate("\n".join(textwrap.fill(t, 110) for t in notes), (0, 0), xycoords="axes fraction",
                    xytext=(0, -34), textcoords="offset points", va="top", fontsize=7.5, color="0.3")
    ax.grid(axis="x", alpha=0.3)
    return fig


def plot_landing(scene, numerics=None):
    """A drop's compliant landing over the board's peak window: each corner's (a box's: vertex's) normal force (top)
    and the board supports' normal acceleration (bottom, in g), against the rigid law's half-sine at the first
    corner (a box's: vertex)."""
    import matplotlib.pyplot as plt

    from .._common.checks import GRAVITY
    from .._response.landing_path import landing_histories
    from .._response.numerics import Numerics

    h = landing_histories(scene, Numerics() if numerics is None else numerics)
    t = np.asarray(h.t) * 1e3
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 6.0), sharex=True, layout="constrained")
    forces = np.asarray(h.forces)
    if forces.shape[1] == 8:  # a box's vertices, in `box_vertices`' order
        names = [f"vertex ({'+-'[1 - (i >> 2 & 1)]}W/2, {'+-'[1 - (i >> 1 & 1)]}H/2, {'+-'[1 - (i & 1)]}D/2)"
                 for i in range(8)]
    else:
        names = [f"corner {c}" for c in ("(+W/2, +H/2)", "(-W/2, +H/2)", "(-W/2, -H/2)", "(+W/2, -H/2)")]
    for i, name in enumerate(names):
        if forces[:, i].max() > 0:
            top.plot(t, forces[:, i] / 1e3, label=name)
    top.set_ylabel("normal force (kN)")
    top.legend(fontsize=8)
    weight = float(h.weight)
    share = "the answer" if weight == 1.0 else f"{weight:.2g} of the answer, the rest the rigid law's"
    tilt = f", tilt {np.degrees(float(scene.drop.tilt)):.3g} deg" if scene.housing.is_box else ""
    top.set_title(f"Compliant landing at {np.degrees(float(scene.drop.orientation)):.3g} deg{tilt} "
                  f"(Contact.model {scene.contact.model!r}: {share})", fontsize=10)
    for j, (end, colour) in enumerate((("A", "tab:blue"), ("B", "tab:red"))):
        bottom.plot(t, np.asarray(h.support)[:, j] / GRAVITY, color=colour, label=f"support {end}: landing")
        bottom.plot(t, np.asarray(h.rigid)[:, j] / GRAVITY, color=colour, ls="--", lw=1,
                    label=f"support {end}: rigid law (first strike)")
    bottom.axhline(0.0, color="0.6", lw=0.8)
    touching = np.flatnonzero(forces.max(axis=1) > 0)
    end = t[touching[-1]] if touching.size else t[-1]
    bottom.set_xlim(0.0, min(t[-1], max(1.3 * end, 1.3 * float(scene.contact.duration) * 1e3)))
    bottom.set_xlabel(f"time from the first touch (ms; no strike after this plot's end in the {t[-1]:.3g} ms "
                      "peak window)")
    bottom.set_ylabel("support acceleration (g)")
    bottom.legend(fontsize=8, ncol=2)
    return fig
