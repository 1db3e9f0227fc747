"""The figures of studies over many drops: placement, Monte-Carlo, campaigns, benchmarks."""

import numpy as np

from .._common.checks import on_host
from .._scene.containers import board_ends
from .._studies.distribution import _FIELDS as SAMPLED_FIELDS, _SHOWN as SHOWN_FIELDS
from .._studies.standards import STANDARDS
from .common import _axes


def _draw_housing(ax, scene, placement, supports: bool = False, **style):
    """The housing's outline and the board (a line in the plane of motion, mm from G); with `supports`, where the
    board is held: its ends A and B (a beam), or its mounts seen edge-on and its supported edges (a plate)."""
    from matplotlib.patches import Rectangle

    W, H = float(scene.housing.width) * 1e3, float(scene.housing.height) * 1e3
    ax.add_patch(Rectangle((-W / 2, -H / 2), W, H, fill=False, lw=1.5, color="0.3"))
    ends = board_ends(on_host(placement), float(scene.board.length)) * 1e3
    ax.plot(ends[:, 0], ends[:, 1], **style)
    if not supports:
        return
    mounts = getattr(scene.board, "mounts", None)
    if mounts is None:  # a beam: held at its ends
        held = np.array([0.0, 1.0])
    else:
        ends_held = [f for f, letter in zip((0.0, 1.0), scene.board.edges[0::2]) if letter != "F"]  # x = 0, L
        held = np.r_[np.asarray(mounts)[:, 0] / float(scene.board.length), ends_held]
    points = ends[0] + held[:, None] * (ends[1] - ends[0])
    ax.plot(points[:, 0], points[:, 1], "^", color="k", ms=7, mfc="w", mew=1.5, zorder=4,
            label="supports (ends A, B)" if mounts is None else "mounts and supported edges, seen edge-on")


def plot_placement(scene, result, landscape, *, axes=None, orientations=None):
    """Left: the objective over board-centre positions (c1 along the housing's width, c2 along its height, mm from
    its centre of mass G) at the optimum's angle, with the optimiser's path; a curve over c1 where the centre has
    no room along the height at that angle. Right: the housing with the board before and after, its supports, and
    the drops' directions (`orientations`, rad: the downward direction at impact, in the housing's axes)."""
    import matplotlib.pyplot as plt

    if axes is None:
        fig, axes = plt.subplots(1, 2, figsize=(12, 5.4), layout="constrained")
    ax1, ax2 = axes
    fig = ax1.figure
    c1, c2, values = (np.asarray(v) for v in landscape)
    c1mm, c2mm, mpa = c1 * 1e3, c2 * 1e3, values / 1e6
    path = np.asarray(result.path)
    best = path[-1, :2] * 1e3
    label = f"{result.objective} peak stress over drops (MPa)"
    if 1 in mpa.shape:  # no room to move along one axis at this angle: a curve along the other
        free = 0 if mpa.shape[1] == 1 else 1
        grid, fixed = (c1mm, c2mm) if free == 0 else (c2mm, c1mm)
        names = ("c1 along the housing's width", "c2 along the housing's height")
        ax1.plot(grid, mpa.ravel(), color="tab:blue", lw=2,
                 label=f"objective, {names[1 - free].split()[0]} = {fixed[0]:.3g} mm")
        ax1.plot(best[free], float(result.value) / 1e6, "r*", ms=14, clip_on=False, label="optimum")
        ax1.set_xlabel(f"board centre {names[free]} (mm from G)")
        ax1.set_ylabel(label)
        ax1.grid(alpha=0.3)
        room = (f"at this angle the board fills the housing's {('height', 'width')[free]}, so its centre moves along "
                f"the {('width', 'height')[free]} only")
    else:
        mesh = ax1.pcolormesh(c1mm, c2mm, mpa.T, shading="gouraud", cmap="viridis")
        fig.colorbar(mesh, ax=ax1, label=label)
        lines = ax1.contour(c1mm, c2mm, mpa.T, levels=8, colors="w", linewidths=0.6, alpha=0.7)
        ax1.clabel(lines, fontsize=7, fmt="%.3g")
        ax1.plot(path[:, 0] * 1e3, path[:, 1] * 1e3, ".-", color="tab:orange", lw=1, ms=3,
                 label="optimiser path (best start)")
        ax1.set_xlim(c1mm.min(), c1mm.max())  # the path may start where only another angle had room
        ax1.set_ylim(c2mm.min(), c2mm.max())
        ax1.plot(path[0, 0] * 1e3, path[0, 1] * 1e3, "o", color="tab:orange", ms=7, mfc="none", label="its start")
        ax1.plot(*best, "r*", ms=14, clip_on=False, label="optimum")
        ax1.set_xlabel("board centre c1 along the housing's width (mm from G)")
        ax1.set_ylabel("board centre c2 along the housing's height (mm from G)")
        room = "the area is where the centre may go at this angle"
    span = np.array([np.ptp(c1mm), np.ptp(c2mm)])
    on_edge = [abs(best[i] - edge) <= 0.02 * span[i] + 1e-9 for i, axis in enumerate((c1mm, c2mm))
               for edge in (axis.min(), axis.max()) if span[i] > 0]
    if any(on_edge):
        room += ("; the optimum lies on its edge: the board touches the housing" +
                 (" or the region's edge" if getattr(result, "region", None) is not None else ""))
    ax1.set_title(f"Objective over the board's centre at the optimum's angle, "
                  f"{np.degrees(float(result.placement.angle)):.1f} deg\n(the path turns "
                  f"{np.degrees(path[0, 2]):.1f} -> {np.degrees(path[-1, 2]):.1f} deg; {room})", fontsize=9, wrap=True)
    ax1.legend(fontsize=8, loc="best")
    _draw_housing(ax2, scene, scene.placement, color="tab:gray", lw=4, ls="--",
                  label=f"before: {float(result.initial_value) / 1e6:.1f} MPa")
    _draw_housing(ax2, scene, result.placement, supports=True, color="tab:red", lw=4,
                  label=f"after: {float(result.value) / 1e6:.1f} MPa")
    ax2.plot(0, 0, "k+", ms=10, label="centre of mass G")
    W, H = float(scene.housing.width) * 1e3, float(scene.housing.height) * 1e3
    if orientations is not None:
        reach = 0.3 * max(W, H)
        for i, theta in enumerate(np.atleast_1d(np.asarray(orientations, float))):
            down = np.array([-np.sin(theta), -np.cos(theta)])
            ax2.annotate("", xy=down * reach, xytext=(0, 0), zorder=3,
                         arrowprops=dict(arrowstyle="-|>", color="tab:blue", lw=1.2, alpha=0.8))
        ax2.plot([], [], "-", color="tab:blue", label=f"drop directions (down at impact, {np.size(orientations)} "
                                                       "drops)")
    if getattr(result, "region", None) is not None:
        from matplotlib.patches import Rectangle

        (lo1, lo2), (hi1, hi2) = np.asarray(result.region) * 1e3
        ax2.add_patch(Rectangle((lo1, lo2), hi1 - lo1, hi2 - lo2, fill=False, ls=":", lw=1.5, color="tab:blue",
                                label="region kept for the centre"))
    if getattr(result, "max_angle", None) is not None:
        ax2.plot([], [], " ", label=f"tilt kept within {np.degrees(result.max_angle):g} deg")
    ax2.set_aspect("equal")
    ax2.set_xlabel("e1: along the housing's width from G (mm)")
    ax2.set_ylabel("e2: along its height from G (mm)")
    ax2.set_title(f"Board placement, {result.objective} objective (the plane of motion)", fontsize=10)
    from matplotlib.transforms import offset_copy

    # Below the axis label, however short the (equal-aspect) axes is.
    ax2.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=2, frameon=False,
               bbox_transform=offset_copy(ax2.transAxes, fig, y=-34, units="points"))
    reach = 0.3 * max(W, H) * 1.1 if orientations is not None else 0.0
    ax2.set_xlim(-max(0.6 * W, reach), max(0.6 * W, reach))
    ax2.set_ylim(-max(0.6 * H, reach), max(0.6 * H, reach))
    left_out = ("The objective counts the support jumps normal to the board (the box's motion in 3D): motion along "
                "the board is left out." if scene.housing.is_box else "The objective counts the support jumps normal "
                "to the board in the plane of the model: motion along the board and out of the plane are left out.")
    fig.text(0.01, 0.005, left_out, fontsize=8, color="0.2", va="bottom")
    if fig.get_layout_engine() is not None:
        fig.get_layout_engine().set(rect=(0, 0.04, 1, 0.96))
    return fig


def _quiet_radial_labels(ax, theta, r, rmax):
    """Radial tick labels on the ray where the points reach least (an empty sector first), and only those clear of
    the points within 12 deg of it: none collides with the curve."""
    bins = np.linspace(0.0, 2 * np.pi, 73)
    where = np.digitize(np.mod(theta, 2 * np.pi), bins) - 1
    reach = np.zeros(72)
    np.maximum.at(reach, np.clip(where, 0, 71), r)
    lo, hi = np.radians(ax.get_thetamin()), np.radians(ax.get_thetamax())
    centres = (bins[:-1] + bins[1:]) / 2
    inside = (centres >= lo - 1e-9) & (centres <= hi + 1e-9) if hi - lo < 2 * np.pi - 1e-9 else np.ones(72, bool)
    # Horizontal labels along a near-horizontal ray run into each other: prefer steeper rays where there are any.
    steep = inside & (np.abs(np.sin(centres)) > 0.5)
    inside = steep if steep.any() else inside
    angle = centres[np.flatnonzero(inside)[np.argmin(reach[inside])]]
    near = np.abs(np.angle(np.exp(1j * (theta - angle)))) < np.radians(12)
    band = (r[near].min() - 0.07 * rmax, r[near].max() + 0.07 * rmax) if np.any(near) else (np.inf, -np.inf)
    ticks = [t for t in ax.get_yticks() if 0 < t <= rmax]
    ax.set_yticks(ticks, ["" if band[0] <= t <= band[1] else f"{t:g}" for t in ticks])
    ax.set_rlabel_position(np.degrees(angle))
    ax.set_ylim(0, rmax)


def plot_montecarlo(result, *, limit=None, quantity: str = "stress", axes=None, distribution=None,
                    varied: str | None = None, flat: dict | None = None):
    """Left: peak against drop orientation (polar; the radius is the peak), coloured by the other field that varies
    (height or contact duration) where one does, with the limit's circle; against the varied field when the
    orientation is fixed. Right: exceedance curve P(peak > s) with the limit marked. The title says what varied:
    `varied` (text), or the `distribution` (`DropDistribution`) the drops came from; the polar axis spans the
    distribution's orientations (else the drops'). `flat` ({orientation rad: peak in SI}) marks drops exactly on a
    face, which random drops never draw under the rigid law (a hair off flat, one corner strikes first)."""
    import matplotlib.pyplot as plt

    names = {name: (what, unit.strip(), scale) for name, (what, unit, scale) in SHOWN_FIELDS.items()}
    names["height"] = ("drop height", "m", 1.0)  # an axis label alone: "height" of what
    paths = {name: path.split(".")[0] for name, path in SAMPLED_FIELDS.items()}
    valid = np.asarray(result.valid)
    n = valid.shape[0]

    def sampled(name):
        v = np.asarray(getattr(getattr(result.samples, paths[name]), name))
        return np.broadcast_to(v, (n,))[valid] if v.ndim else None  # None: fixed

    changing = [k for k in names if sampled(k) is not None and np.ptp(sampled(k)) > 0]
    polar = "orientation" in changing
    if axes is None:
        fig = plt.figure(figsize=(12, 5.2), layout="constrained")
        axes = (fig.add_subplot(1, 2, 1, projection="polar" if polar else None), fig.add_subplot(1, 2, 2))
    ax1, ax2 = axes
    fig = ax1.figure
    unit, scale = {"stress": ("MPa", 1e-6), "strain": ("microstrain", 1e6), "deflection": ("mm", 1e3)}[quantity]
    values = np.asarray(getattr(result, f"peak_{quantity}"))[valid] * scale
    others = [k for k in changing if k != "orientation"]
    x_name = "orientation" if polar else (others[0] if others else None)
    colour_name = next((k for k in others if k != x_name), None)
    colour = dict(c=sampled(colour_name) * names[colour_name][2], cmap="viridis") if colour_name else dict(
        color="tab:blue")
    x = sampled(x_name) if x_name else np.zeros(values.shape)
    shown = x if polar or x_name is None else x * names[x_name][2]  # a polar axis takes radians
    dots = ax1.scatter(shown, values, s=2, alpha=0.5, rasterized=True, **colour)
    if colour_name:
        what, cunit, _ = names[colour_name]
        fig.colorbar(dots, ax=ax1, pad=0.12 if polar else 0.02, shrink=0.8, label=f"{what} ({cunit})")
    flat = {} if flat is None else {float(k): float(v) * scale for k, v in flat.items()}
    top = max([float(values.max()) if values.size else 1.0, 0.0 if limit is None else limit * scale,
               *flat.values()]) * 1.08
    if polar:
        spec = None if distribution is None else distribution.orientation
        if spec is not None and spec[0] == "uniform":
            lo, hi = np.degrees(spec[1]), np.degrees(spec[2])
        elif spec is not None:
            lo, hi = 0.0, 360.0
        else:
            lo, hi = np.degrees(x.min()), np.degrees(x.max())
        if hi - lo < 359.0:
            ax1.set_thetamin(lo)
            ax1.set_thetamax(hi)
        if limit is not None:
            circle = np.linspace(np.radians(lo), np.radians(hi), 361) if hi - lo < 359.0 else np.linspace(
                0.0, 2 * np.pi, 361)
            ax1.plot(circle, np.full(circle.shape, limit * scale), "--", color="tab:red", lw=1.5,
                     label=f"limit {limit * scale:.4g} {unit}")
        if flat:
            ax1.plot(list(flat), list(flat.values()), "D", color="tab:orange", mec="k", ms=7, zorder=5,
                     label=f"exactly on a face: up to {max(flat.values()):.4g} {unit}\n(never drawn: a hair off "
                           "flat, one corner strikes first)")
        if limit is not None or flat:
            ax1.legend(loc="upper left", bbox_to_anchor=(-0.18, -0.04), fontsize=8)
        ax1.tick_params(axis="y", labelsize=7, labelcolor="0.3")
        _quiet_radial_labels(ax1, np.r_[x, list(flat)], np.r_[values, list(flat.values())], top)
        ax1.set_title(f"peak {quantity} ({unit}, the radius) against drop orientation (deg)", pad=18, fontsize=10)
    else:
        if limit is not None:
            ax1.axhline(limit * scale, color="tab:red", ls="--", lw=1.5, label=f"limit {limit * scale:.4g} {unit}")
            ax1.legend(fontsize=8)
        ax1.set_xlabel(f"{names[x_name][0]} ({names[x_name][1]})" if x_name else "")
        ax1.set_ylabel(f"peak {quantity} ({unit})")
        ax1.set_title(f"peak {quantity} against {names[x_name][0] if x_name else 'the drop'}", fontsize=10)
        ax1.grid(alpha=0.3)
    ordered = np.sort(values)
    ccdf = 1.0 - np.arange(1, ordered.size + 1) / ordered.size
    ax2.semilogy(ordered[:-1], ccdf[:-1], color="tab:blue", lw=2, label=f"{ordered.size} valid drops")
    if limit is not None:
        p, (lo, hi), k = result.exceedance(limit, quantity)
        ax2.axvline(limit * scale, color="tab:red", ls="--",
                    label=f"limit {limit * scale:.4g} {unit}: P = {p:.3g} (95 % CI {lo:.3g}-{hi:.3g})")
    ax2.set_xlabel(f"peak {quantity} ({unit})")
    ax2.set_ylabel("exceedance probability P(peak > value)")
    ax2.set_title("Exceedance curve (complementary CDF)")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=8)
    varied = varied if varied is not None or distribution is None else distribution.describe()
    if varied is not None:
        import textwrap

        fig.suptitle(textwrap.fill(f"{n} random drops: {varied}", 130), fontsize=10)
    return fig


def plot_campaign(result, *, ax=None, limit: float | None = None, scene: str | None = None,
                  quantity: str = "stress"):
    """Bar chart of a `CampaignResult`: the peak `quantity` ("stress" in MPa or "strain" in microstrain) of every
    drop, coloured by attitude, every drop tied for the worst outlined; a drop that does not bend the board in the
    plane model is labelled 0 with the reason, one the plane cannot represent n/a, both explained under the chart;
    `limit` (Pa, or a strain fraction) draws the allowable with the drops over it marked; `scene` names the scene
    in the title."""
    import textwrap

    import matplotlib.patches as mpatches

    n = len(result.drops)
    fig, ax = _axes(ax, figsize=(max(6.5, 0.42 * n + 2.5) + 1.6, 5.6))
    colours = {"face": "tab:blue", "edge": "tab:orange", "corner": "tab:green", "board": "tab:purple"}
    unit, scale = {"stress": ("MPa", 1e-6), "strain": ("microstrain", 1e6)}[quantity]
    values = np.asarray(getattr(result, quantity), float) * scale
    bars = ax.bar(range(n), np.nan_to_num(values), color=[colours[d.attitude] for d in result.drops], width=0.7)
    worst = result.worst_drops
    top = float(np.nanmax(values)) if worst else 1.0
    top = max(top if top > 0 else 1.0, 0.0 if limit is None else limit * scale)
    for i in worst:
        bars[i].set_edgecolor("black")
        bars[i].set_linewidth(2.0)
    unbent = set(result.unbent)
    for i in range(n):
        if not np.isfinite(values[i]):
            ax.text(i, 0.02 * top, "n/a: out of the plane", ha="center", va="bottom", rotation=90, fontsize=8.5,
                    color="0.15")
        elif i in unbent:
            ax.text(i, 0.02 * top, "0: no bending", ha="center", va="bottom", rotation=90, fontsize=8.5, color="0.15")
        elif values[i] < 0.01 * top:  # a bar too short to see: say its value
            ax.text(i, 0.02 * top, f"{values[i]:.2g}", ha="center", va="bottom", fontsize=8)
    if worst:
        tie = f" ({len(worst)} drops tie)" if len(worst) > 1 else ""
        ax.annotate(f"worst: {values[worst[0]]:.4g} {unit}{tie}", (worst[0], values[worst[0]]), xytext=(0, 6),
                    textcoords="offset points", ha="left", fontsize=9)
    handles = [mpatches.Patch(color=c, label=a) for a, c in colours.items()
               if any(d.attitude == a for d in result.drops)]
    if limit is not None:
        judged = [i for i in range(n) if np.isfinite(values[i]) and i not in unbent]
        over = [i for i in judged if values[i] > limit * scale]
        handles.append(ax.axhline(limit * scale, color="tab:red", ls="--", lw=1.5,
                                  label=f"limit {limit * scale:g} {unit}:\n{len(over)} of {len(judged)} drops "
                                        f"judged are over ({'FAIL' if over else 'PASS'})"))
        for i in over:
            bars[i].set_hatch("///")
            bars[i].set_edgecolor("tab:red")
        if over:
            handles.append(mpatches.Patch(facecolor="white", edgecolor="tab:red", hatch="///", label="over the limit"))
    # Labels whole, on two lines where long (JESD22's "board-level half-sine 1500 g 0.5 ms").
    ax.set_xticks(range(n), [textwrap.fill(d.label, 22) for d in result.drops], rotation=60 if n > 1 else 0,
                  ha="right" if n > 1 else "center", fontsize=8)
    ax.set_xlim(-0.6, n - 0.4)
    ax.set_ylabel(f"peak bending {quantity} ({unit})")
    ax.set_ylim(0, 1.2 * top)
    name = STANDARDS.get(result.standard, result.standard).split(":")[0].split(" (")[0]
    heights = sorted({round(d.height, 4) for d in result.drops if np.isfinite(d.height)})
    where = (f"from {', '.join(f'{h:g}' for h in heights)} m" if heights else "of a board-level half-sine at both "
             "supports")
    total = result.total_drops
    count = f"{total} drop{'s' if total != 1 else ''}" + (f" ({n} attitudes)" if total != n and n > 1 else "")
    # One line per part, each broken only at its commas: the standard's name, then the drops.
    width = int(14 * fig.get_figwidth())
    lines = []
    for part in (name, f"{count} {where}" + (f", scene {scene}" if scene else "")):
        line = ""
        for piece in part.split(", "):
            if line and len(line) + len(piece) + 2 > width:
                lines.append(line + ",")
                line = piece
            else:
                line = f"{line}, {piece}" if line else piece
        lines.append(line)
    ax.set_title("\n".join(lines), fontsize=10)
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the bars
    notes = []
    if unbent:
        notes.append("0: the velocity change runs along the board, which the plane model does not bend (a flat "
                     "landing on a face perpendicular to the board moves it along itself)")
    if not np.all(np.isfinite(values)):
        notes.append("n/a: the velocity change is perpendicular to the plane of the model (faces 5 and 6), not "
                     "represented in 2-D")
    if notes:
        text = "\n".join(textwrap.fill(t, int(15 * fig.get_figwidth())) for t in notes)
        fig.text(0.01, 0.01, text, fontsize=8, va="bottom", ha="left", color="0.2")
        room = (text.count("\n") + 1) * 0.14 / fig.get_figheight() + 0.02  # 0.14 in a line
        if fig.get_layout_engine() is not None:
            fig.get_layout_engine().set(rect=(0, room, 1, 1 - room))
    return fig


def plot_bench(rows, *, ax=None):
    """Log-log chart of max relative error of the peak stress against seconds per drop, the Pareto front of each
    workload marked (rows as `run_bench` returns them; open markers: drops whose contact duration varies; half-filled:
    clattering drops, up to 3 impacts each)."""
    fig, ax = _axes(ax, (8.0, 5.5))
    floor = 1e-16
    groups = {}
    for r in rows:
        groups.setdefault((r["method"], r.get("workload", "fixed duration")), []).append(r)
    styles = {}  # one marker and colour per method, filled for the fixed duration, open where it varies
    for (method, workload), rs in groups.items():
        marker, colour = styles.setdefault(method, ("osD^vP*Xh<>"[len(styles) % 11], f"C{len(styles) % 10}"))
        other = workload != "fixed duration"
        fill = dict(mfc="none") if workload.startswith("duration") else dict(fillstyle="left") if other else {}
        ax.loglog([r["seconds_per_drop"] for r in rs], [max(r["max_error"], floor) for r in rs], marker, ms=7,
                  color=colour, alpha=0.8, label=method + (f" ({workload})" if other else ""), **fill)
    for workload, style in (("fixed duration", "k-"), ("duration U[0.2, 1] ms", "k--"), ("up to 3 impacts", "k:")):
        front = sorted((r for r in rows if r.get("pareto") and r.get("workload", "fixed duration") == workload),
                       key=lambda r: r["seconds_per_drop"])
        if len(front) > 1:
            ax.loglog([r["seconds_per_drop"] for r in front], [max(r["max_error"], floor) for r in front], style,
                      lw=1, label=f"Pareto front ({workload})")
    ax.axhline(0.01, color="tab:red", ls=":", lw=1, label="1 % error")
    ax.set_xlabel("seconds per drop (median, batched where possible)")
    ax.set_ylabel("max relative error of peak stress vs converged reference")
    ax.set_title("Speed against accuracy on random drops of the default scene")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    return fig


def plot_stability(study: dict):
    """The stability map: four panels from `stability_study`."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 10), layout="constrained")
    ax = axes[0, 0]
    any_failed = False
    for solver in sorted({r["solver"] for r in study["stiffness"]}):
        rs = [r for r in study["stiffness"] if r["solver"] == solver]
        ax.loglog([r["top_frequency_hz"] for r in rs], [r["steps"] for r in rs], "o-",
                  label=f"{solver} (rtol {rs[0]['rtol']:g})")
        for r in rs:
            if r["failed"]:
                any_failed = True
                ax.plot(r["top_frequency_hz"], r["steps"], "rx", ms=12)
    ax.set_xlabel("frequency of the highest mode kept (Hz)")
    ax.set_ylabel("solver steps over the window")
    ax.set_title("Stiffness: steps grow with the top mode" + (" (x: max_steps hit)" if any_failed else ""),
                 fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[0, 1]
    for solver in sorted({r["solver"] for r in study["tolerance"]}):
        for f32, style in ((False, "o-"), (True, "s--")):
            rs = [r for r in study["tolerance"] if r["solver"] == solver and r["float32"] == f32]
            ok = [r for r in rs if np.isfinite(r["error"]) and not r["flags"]]
            failed = [r for r in rs if r not in ok]
            if ok:
                line, = ax.loglog([r["rtol"] for r in ok], [max(r["error"], 1e-16) for r in ok], style,
                                  label=f"{solver} {'f32' if f32 else 'f64'}")
                colour = line.get_color()
            if failed:
                ax.loglog([r["rtol"] for r in failed], [1.0] * len(failed), "x", ms=10, mew=2,
                          color=colour if ok else "tab:red",
                          label=f"{solver} {'f32' if f32 else 'f64'}: failed (flagged)")
    ax.set_xlabel("diffrax rtol")
    ax.set_ylabel("peak-stress error against the closed form (x at 1: failed)")
    ax.set_title("Tolerance: float32 floors near 1e-6; first-order damping", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[1, 0]
    for tau in sorted({r["duration"] for r in study["modes"]}):
        rs = [r for r in study["modes"] if r["duration"] == tau]
        label = "ideal impulse" if tau == 0 else f"half-sine {tau * 1e3:g} ms"
        ax.semilogx([r["n_modes"] for r in rs], [r["stress"] / 1e6 for r in rs], "o-", label=label)
    ax.set_xlabel("modes")
    ax.set_ylabel("peak stress (MPa)")
    ax.set_title("Ideal impulse never converges; 0.05-1 ms pulses do", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[1, 1]
    rs = study["buckling"]
    ax.plot([r["load_ratio"] for r in rs], [r["f1_hz"] for r in rs], "o-", color="tab:blue", label="f1 (Hz)")
    ax.set_xlabel("axial compression / Euler load")
    ax.set_ylabel("first frequency (Hz)", color="tab:blue")
    ax2 = ax.twinx()
    ax2.plot([r["load_ratio"] for r in rs], [r["stress"] / 1e6 for r in rs], "s--", color="tab:red")
    ax2.set_ylabel("peak stress (MPa)", color="tab:red")
    ax.set_title("Approaching buckling: f1 -> 0, the peak grows", fontsize=10)
    ax.grid(True, alpha=0.3)
    return fig
