"""Every figure the package draws. Functions take results, draw on an optional `ax`, and return the figure."""

import numpy as np

from ._impact import ImpactMode, routh_impulse


def _axes(ax, figsize=(6.0, 4.5)):
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax.figure, ax


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
    path = np.asarray(res.path)
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
    ax.axhline(float(res.P[1]), color="tab:red", lw=0.8, ls=":", label=f"termination ({law})")
    ax.plot(path[:, 0], path[:, 1], "-o", color="k", ms=4, lw=2, label="impulse path")
    ax.plot([float(res.P[0])], [float(res.P[1])], "*", color="tab:red", ms=12)
    pn_c = float(res.Pn_compression)
    ax.plot([np.interp(pn_c, path[:, 1], path[:, 0])], [pn_c], "D", color="tab:blue", ms=6, label="max compression")
    ax.set_xlim(-span, span)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("tangential impulse $P_t$ (N s)")
    ax.set_ylabel("normal impulse $P_n$ (N s)")
    mode = ImpactMode(int(res.mode)).label
    ax.set_title(title or f"Impact process: {mode}; P = ({float(res.P[0]):.4g}, {float(res.P[1]):.4g}) N s")
    ax.legend(loc="lower left", fontsize=8)
    return fig


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
    fig.colorbar(mesh, ax=list(axes), label="bending stress (MPa), normal-side face")
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


def plot_deflected_board(fields, response, *, ax=None):
    """Deflection relative to the chord AB at the time of peak stress, with the peak location marked."""
    fig, ax = _axes(ax, (6.5, 3.5))
    t_idx = int(np.abs(np.asarray(fields.t) - float(response.peak.t)).argmin())
    x_mm = np.asarray(fields.x) * 1e3
    u_mm = np.asarray(fields.deflection)[:, t_idx] * 1e3
    ax.plot(x_mm, u_mm, color="tab:blue", lw=2, label=f"t = {float(fields.t[t_idx]) * 1e3:.3f} ms")
    ax.plot([x_mm[0], x_mm[-1]], [0, 0], "k^", ms=10, label="pinned supports A, B")
    ax.axvline(float(response.peak.x) * 1e3, color="tab:red", ls="--", lw=1, label="peak stress location")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("position along the board from end A (mm)")
    ax.set_ylabel("deflection from chord AB (mm)")
    ax.set_title("Deflected board at the time of peak stress")
    ax.legend(fontsize=8)
    return fig


def _draw_housing(ax, scene, placement, **style):
    from ._scene import board_ends

    from matplotlib.patches import Rectangle

    W, H = float(scene.housing.width) * 1e3, float(scene.housing.height) * 1e3
    ax.add_patch(Rectangle((-W / 2, -H / 2), W, H, fill=False, lw=1.5, color="0.3"))
    ends = np.asarray(board_ends(placement, scene.board.length)) * 1e3
    ax.plot(ends[:, 0], ends[:, 1], **style)


def plot_placement(scene, result, landscape, *, axes=None):
    """Left: the objective over board-centre positions at the optimal angle, with the optimiser's path.
    Right: the housing (body axes, mm) with the board before and after."""
    import matplotlib.pyplot as plt

    if axes is None:
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), layout="constrained")
    ax1, ax2 = axes
    fig = ax1.figure
    c1, c2, values = landscape
    mesh = ax1.pcolormesh(np.asarray(c1) * 1e3, np.asarray(c2) * 1e3, np.asarray(values).T / 1e6,
                          shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax1, label=f"{result.objective} peak stress over drops (MPa)")
    path = np.asarray(result.path)
    ax1.plot(path[:, 0] * 1e3, path[:, 1] * 1e3, "w.-", lw=1, ms=3, label="optimiser path (best start)")
    ax1.plot(path[0, 0] * 1e3, path[0, 1] * 1e3, "wo", ms=7, mfc="none")
    ax1.plot(path[-1, 0] * 1e3, path[-1, 1] * 1e3, "r*", ms=14, label="optimum")
    ax1.set_xlabel("board centre c1 along the width (mm)")
    ax1.set_ylabel("board centre c2 along the height (mm)")
    ax1.set_title(f"Objective at the optimal angle {np.degrees(float(result.placement.angle)):.1f} deg")
    ax1.legend(fontsize=8, loc="lower right")
    _draw_housing(ax2, scene, scene.placement, color="tab:gray", lw=4, ls="--",
                  label=f"before: {float(result.initial_value) / 1e6:.1f} MPa")
    _draw_housing(ax2, scene, result.placement, color="tab:red", lw=4,
                  label=f"after: {float(result.value) / 1e6:.1f} MPa")
    ax2.plot(0, 0, "k+", ms=10, label="centre of mass G")
    ax2.set_aspect("equal")
    ax2.set_xlabel("e1 (mm)")
    ax2.set_ylabel("e2 (mm)")
    ax2.set_title(f"Board placement, {result.objective} objective")
    ax2.legend(fontsize=8, loc="upper right")
    W, H = float(scene.housing.width) * 1e3, float(scene.housing.height) * 1e3
    ax2.set_xlim(-0.6 * W, 0.6 * W)
    ax2.set_ylim(-0.6 * H - 0.3 * H, 0.6 * H + 0.3 * H)
    return fig


def plot_montecarlo(result, *, limit=None, quantity: str = "stress", axes=None):
    """Left: peak against drop orientation (polar). Right: exceedance curve P(peak > s) with the limit marked."""
    import matplotlib.pyplot as plt

    if axes is None:
        fig = plt.figure(figsize=(12, 4.8), layout="constrained")
        axes = (fig.add_subplot(1, 2, 1, projection="polar"), fig.add_subplot(1, 2, 2))
    ax1, ax2 = axes
    fig = ax1.figure
    unit, scale = {"stress": ("MPa", 1e-6), "strain": ("microstrain", 1e6), "deflection": ("mm", 1e3)}[quantity]
    valid = np.asarray(result.valid)
    values = np.asarray(getattr(result, f"peak_{quantity}"))[valid] * scale
    orient = np.broadcast_to(np.asarray(result.samples.drop.orientation), valid.shape)[valid]
    ax1.scatter(orient, values, s=2, alpha=0.4, c=values, cmap="viridis", rasterized=True)
    ax1.set_title(f"peak {quantity} ({unit}) against drop orientation", pad=14)
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
    return fig


def plot_campaign(result, *, ax=None, limit: float | None = None):
    """Bar chart of a `CampaignResult`: peak stress (MPa) of every drop, coloured by attitude, the worst drop
    outlined, drops the plane cannot represent marked n/a; `limit` (Pa) draws an allowable stress."""
    import matplotlib.patches as mpatches

    n = len(result.drops)
    fig, ax = _axes(ax, figsize=(max(6.0, 0.38 * n + 2.0), 4.5))
    colours = {"face": "tab:blue", "edge": "tab:orange", "corner": "tab:green", "board": "tab:purple"}
    stress = np.asarray(result.stress, float) / 1e6
    shown = np.nan_to_num(stress)
    bars = ax.bar(range(n), shown, color=[colours[d.attitude] for d in result.drops])
    worst = result.worst
    bars[worst].set_edgecolor("black")
    bars[worst].set_linewidth(2.0)
    top = float(np.nanmax(stress)) if np.any(np.isfinite(stress)) else 1.0
    for i, d in enumerate(result.drops):
        if not np.isfinite(stress[i]):
            ax.text(i, 0.02 * top, "n/a", ha="center", va="bottom", rotation=90, fontsize=8, color="0.4")
    ax.annotate(f"worst: {stress[worst]:.1f} MPa", (worst, stress[worst]), xytext=(0, 6),
                textcoords="offset points", ha="center", fontsize=9)
    if limit is not None:
        ax.axhline(limit / 1e6, color="tab:red", ls="--", lw=1.2, label=f"limit {limit / 1e6:g} MPa")
    ax.set_xticks(range(n), [d.label for d in result.drops], rotation=70, ha="right", fontsize=8)
    ax.set_ylabel("peak bending stress (MPa)")
    ax.set_ylim(0, 1.15 * top)
    ax.set_title(f"{result.standard}: {n} drops")
    handles = [mpatches.Patch(color=c, label=a) for a, c in colours.items()
               if any(d.attitude == a for d in result.drops)]
    ax.legend(handles=handles + ([ax.lines[-1]] if limit is not None else []), fontsize=8, loc="upper right")
    return fig


def plot_bench(rows, *, ax=None):
    """Log-log chart of max relative error of the peak stress against seconds per drop, Pareto front marked."""
    from ._bench import pareto_front

    fig, ax = _axes(ax, (8.0, 5.5))
    floor = 1e-16
    groups = {}
    for r in rows:
        groups.setdefault(r["method"], []).append(r)
    markers = iter("osD^vP*Xh<>")
    for method, rs in groups.items():
        ax.loglog([r["seconds_per_drop"] for r in rs], [max(r["max_error"], floor) for r in rs], next(markers, "o"),
                  ms=7, alpha=0.8, label=method)
    front = sorted((rows[i] for i in pareto_front(rows)), key=lambda r: r["seconds_per_drop"])
    ax.loglog([r["seconds_per_drop"] for r in front], [max(r["max_error"], floor) for r in front], "k-", lw=1,
              label="Pareto front")
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

    fig, axes = plt.subplots(2, 2, figsize=(12, 9), layout="constrained")
    ax = axes[0, 0]
    for solver in sorted({r["solver"] for r in study["stiffness"]}):
        rs = [r for r in study["stiffness"] if r["solver"] == solver]
        ax.loglog([r["top_frequency_hz"] for r in rs], [r["steps"] for r in rs], "o-",
                  label=f"{solver} (rtol {rs[0]['rtol']:g})")
        for r in rs:
            if r["failed"]:
                ax.plot(r["top_frequency_hz"], r["steps"], "rx", ms=12)
    ax.set_xlabel("frequency of the highest mode kept (Hz)")
    ax.set_ylabel("solver steps over the window")
    ax.set_title("Stiffness: explicit steps grow with the top mode (x = max_steps hit)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[0, 1]
    for solver in sorted({r["solver"] for r in study["tolerance"]}):
        for f32, style in ((False, "o-"), (True, "s--")):
            rs = [r for r in study["tolerance"] if r["solver"] == solver and r["float32"] == f32]
            if rs:
                ax.loglog([r["rtol"] for r in rs], [max(r["error"], 1e-16) if np.isfinite(r["error"]) else 1.0
                                                    for r in rs], style, label=f"{solver} {'f32' if f32 else 'f64'}")
    ax.set_xlabel("diffrax rtol")
    ax.set_ylabel("peak-stress error against the closed form (1 = failed, flagged)")
    ax.set_title("Tolerance: error floors (float32 near 1e-6) and first-order damping")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(True, which="both", alpha=0.3)

    ax = axes[1, 0]
    for tau in sorted({r["duration"] for r in study["modes"]}):
        rs = [r for r in study["modes"] if r["duration"] == tau]
        label = "ideal impulse" if tau == 0 else f"half-sine {tau * 1e3:g} ms"
        ax.semilogx([r["n_modes"] for r in rs], [r["stress"] / 1e6 for r in rs], "o-", label=label)
    ax.set_xlabel("modes")
    ax.set_ylabel("peak stress (MPa)")
    ax.set_title("Ideal impulse never converges; real pulses (0.05-1 ms) do")
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
    ax.set_title("Approaching buckling: f1 -> 0, window and peak grow")
    ax.grid(True, alpha=0.3)
    return fig
