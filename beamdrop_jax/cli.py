"""The `beamdrop` command: parse, load a scene, call the library, print a table, save figures."""

import argparse
import sys
from pathlib import Path


def _setup_jax(args):
    import jax

    # The CLI (not the library) picks the precision: float64 unless asked otherwise.
    jax.config.update("jax_enable_x64", not getattr(args, "float32", False))


def _scene(args):
    import beamdrop_jax as bd

    return bd.load_scene(args.scene) if args.scene else bd.Scene.default()


def _out(args) -> Path:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _save(fig, path: Path):
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def _table(rows):
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")


def cmd_impact(args):
    import beamdrop_jax as bd

    scene = _scene(args)
    hit = bd.housing_impact(scene, law=args.law)
    imp = hit.impact
    print(f"Impact of {'scene ' + args.scene if args.scene else 'the default scene'} ({args.law} restitution)")
    _table(
        [
            ("striking corner (q1, q2) from G", f"({float(hit.corner[0]) * 1e3:.1f}, {float(hit.corner[1]) * 1e3:.1f}) mm"),
            ("approach velocity (S0, C0)", f"({float(hit.v0[0]):.4f}, {float(hit.v0[1]):.4f}) m/s"),
            ("impulse (Pt, Pn)", f"({float(imp.P[0]):.5f}, {float(imp.P[1]):.5f}) N s"),
            ("contact mode", "flat landing (translation)" if bool(hit.flat) else bd.ImpactMode(int(imp.mode)).label),
            ("centre-of-mass velocity jump", f"({float(hit.dv_G[0]):.4f}, {float(hit.dv_G[1]):.4f}) m/s"),
            ("spin jump", f"{float(hit.dw):.4f} rad/s"),
            ("contact velocity after (S, C)", f"({float(imp.velocity[0]):.4f}, {float(imp.velocity[1]):.4f}) m/s"),
            ("kinetic energy lost", f"{-float(imp.energy_change):.5f} J"),
            ("board support jumps (dvA, dvB)", "({:.4f}, {:.4f}) m/s".format(*map(float, bd.support_jumps(scene, hit)))),
        ]
    )
    if not args.no_plots:
        out = _out(args)
        fig = bd.plot_impact(hit.B, hit.v0, scene.contact.friction, scene.contact.restitution, law=args.law)
        _save(fig, out / "impact.png")


def _numerics(args):
    import beamdrop_jax as bd

    kw = {}
    if getattr(args, "method", None):
        kw["method"] = args.method
    if getattr(args, "solver", None):
        kw["solver"] = args.solver
    if getattr(args, "n_modes", None):
        kw["n_modes"] = args.n_modes
    if getattr(args, "max_impacts", None):
        kw["max_impacts"] = args.max_impacts
    return bd.Numerics(**kw)


def cmd_drop(args):
    import beamdrop_jax as bd

    scene = _scene(args)
    numerics = _numerics(args)
    res = bd.simulate(scene, numerics)
    hit, peak = res.housing, res.peak
    freqs = ", ".join(f"{float(f):.0f}" for f in res.frequencies[:4])
    tau = float(scene.contact.duration)
    print(f"Drop of {'scene ' + args.scene if args.scene else 'the default scene'}: "
          f"{float(scene.drop.height):g} m onto a corner at {float(scene.drop.orientation) * 57.29577951308232:.1f} deg, "
          + (f"half-sine contact {tau * 1e3:g} ms" if tau > 0 else "ideal impulse"))
    _table(
        [
            ("impulse (Pt, Pn)", f"({float(res.impulse.P[0]):.4f}, {float(res.impulse.P[1]):.4f}) N s"),
            ("contact mode", "flat landing (translation)" if bool(hit.flat) else bd.ImpactMode(int(res.impulse.mode)).label),
            ("support jumps (dvA, dvB)", "({:.3f}, {:.3f}) m/s".format(*map(float, res.support_jumps))),
            ("first frequencies", f"{freqs} Hz"),
            ("modes used (checked against)", f"{int(res.n_modes)} ({int(res.check_modes)})"),
            ("peak stress", f"{float(peak.stress) / 1e6:.2f} MPa"),
            ("peak strain", f"{float(peak.strain) * 1e6:.1f} microstrain"),
            ("peak deflection", f"{float(peak.deflection) * 1e3:.3f} mm at x = {float(peak.deflection_x) * 1e3:.1f} mm, "
                                f"t = {float(peak.deflection_t) * 1e3:.3f} ms"),
            ("peak stress at", f"x = {float(peak.x) * 1e3:.1f} mm from end A, t = {float(peak.t) * 1e3:.3f} ms"),
            ("converged", ("yes" if bool(res.converged) else "NO")
                          + f" (mode check changes the peak by {float(res.error_estimate) * 100:.3f} %)"),
        ]
    )
    if numerics.max_impacts > 1:
        imp = res.impacts
        print(f"Impacts ({int(imp.count)} of at most {numerics.max_impacts}; ended: "
              f"{bd.Ending(int(imp.ending)).name.lower().replace('_', ' ')})")
        print(f"  {'#':>2} {'t (ms)':>9} {'corner (mm)':>16} {'approach (m/s)':>15} {'Pt, Pn (N s)':>20} "
              f"{'dvA, dvB (m/s)':>17}")
        for i in range(int(imp.count)):
            print(f"  {i + 1:>2} {float(imp.t[i]) * 1e3:>9.3f} "
                  f"{'({:.1f}, {:.1f})'.format(*(float(v) * 1e3 for v in imp.corner[i])):>16} "
                  f"{float(imp.approach_speed[i]):>15.4f} "
                  f"{'{:.4f}, {:.4f}'.format(*map(float, imp.P[i])):>20} "
                  f"{'{:.3f}, {:.3f}'.format(*map(float, imp.support_jumps[i])):>17}")
    if not bool(res.converged):
        print("  note: not converged. An ideal impulse (duration 0) never converges in the mode count; "
              "give Contact.duration a physical value (0.05-1 ms).")
    if not args.no_plots:
        out = _out(args)
        fields = bd.response_fields(scene, numerics)
        _save(bd.plot_stress_map(fields, res), out / "stress_map.png")
        _save(bd.plot_deflected_board(fields, res), out / "deflection.png")
        fig = bd.plot_impact(hit.B, hit.v0, scene.contact.friction, scene.contact.restitution, law=numerics.law)
        _save(fig, out / "impact.png")


def cmd_campaign(args):
    import beamdrop_jax as bd

    scene = _scene(args)
    numerics = _numerics(args)
    result = bd.campaign(scene, args.standard, numerics, mass=args.mass, height=args.height)
    print(f"{args.standard}: {bd.STANDARDS[args.standard]}")
    print(f"  {'#':>2}  {'drop':<36} {'height (m)':>10} {'angle (deg)':>11} {'reps':>4} {'stress (MPa)':>12} "
          f"{'strain (ue)':>11} {'defl. (mm)':>10}")
    for r in result.rows():
        mark = " <- worst" if r["worst"] else ("  " + r["note"] if r["note"] else "")
        print(f"  {r['drop']:>2}  {r['label']:<36} {r['height_m']:>10.3f} {r['orientation_deg']:>11.2f} "
              f"{r['repetitions']:>4} {r['peak_stress_MPa']:>12.2f} {r['peak_strain_microstrain']:>11.1f} "
              f"{r['peak_deflection_mm']:>10.3f}{mark}")
    out = _out(args)
    print(f"wrote {result.to_csv(out / f'campaign-{args.standard}.csv')}")
    if not args.no_plots:
        _save(bd.plot_campaign(result), out / f"campaign-{args.standard}.png")


def _angles(spec: str):
    """'15:75:7' -> 7 angles from 15 to 75 degrees (radians); '30,45' -> those angles."""
    import numpy as np

    if ":" in spec:
        lo, hi, n = spec.split(":")
        return np.radians(np.linspace(float(lo), float(hi), int(n)))
    return np.radians([float(v) for v in spec.split(",")])


def cmd_sensitivity(args):
    import beamdrop_jax as bd

    scene = _scene(args)
    rows = bd.sensitivities(scene, _numerics(args), quantity=args.quantity)
    unit = {"stress": "Pa", "strain": "-", "deflection": "m"}[args.quantity]
    peak = {"stress": bd.peak_stress, "strain": bd.peak_strain, "deflection": bd.peak_deflection}[args.quantity]
    print(f"Sensitivity of the peak {args.quantity} ({float(peak(scene, _numerics(args))):.6g} {unit}), "
          "largest elasticity first")
    print(f"  {'field':<32} {'value':>13} {'d(peak)/d(field)':>17} {'elasticity':>11}")
    for r in rows:
        print(f"  {r.field:<32} {r.value:>13.6g} {r.derivative:>17.6g} {r.elasticity:>11.4f}")


def cmd_optimize(args):
    import beamdrop_jax as bd

    scene = _scene(args)
    orientations = _angles(args.orientations)
    heights = [float(h) for h in args.heights.split(",")] if args.heights else None
    numerics = bd.Numerics(n_modes=args.n_modes or 8)
    res = bd.optimize_placement(scene, orientations, heights, objective=args.objective, alpha=args.alpha,
                                numerics=numerics, steps=args.steps, starts=args.starts, margin=args.margin)
    before, after = scene.placement, res.placement
    print(f"Board placement, {args.objective} peak stress over {res.n_drops} drops "
          f"({res.n_evaluations} evaluations with gradients)")
    _table(
        [
            ("before: centre, angle", f"({float(before.centre[0]) * 1e3:.2f}, {float(before.centre[1]) * 1e3:.2f}) mm, "
                                      f"{float(before.angle) * 57.29577951308232:.2f} deg"),
            ("before: objective", f"{float(res.initial_value) / 1e6:.2f} MPa"),
            ("after: centre, angle", f"({float(after.centre[0]) * 1e3:.2f}, {float(after.centre[1]) * 1e3:.2f}) mm, "
                                     f"{float(after.angle) * 57.29577951308232:.2f} deg"),
            ("after: objective", f"{float(res.value) / 1e6:.2f} MPa"),
        ]
    )
    if not args.no_plots:
        landscape = bd.placement_landscape(scene, res, orientations, heights, alpha=args.alpha, numerics=numerics,
                                           margin=args.margin)
        _save(bd.plot_placement(scene, res, landscape), _out(args) / "placement.png")


def cmd_montecarlo(args):
    import jax

    import beamdrop_jax as bd

    scene = _scene(args)
    numerics = bd.Numerics(n_modes=args.n_modes) if args.n_modes else None
    if args.max_impacts:
        import dataclasses

        numerics = dataclasses.replace(numerics or bd.montecarlo_numerics(scene), max_impacts=args.max_impacts)
    res = bd.montecarlo(scene, args.n, jax.random.PRNGKey(args.seed), numerics=numerics, batch_size=args.batch_size)
    stress, strain = res.summary("stress"), res.summary("strain")
    print(f"{res.n} random drops (orientation uniform on [0, 360) deg), {res.n_invalid} outside the model and "
          "left out")
    _table(
        [
            ("peak stress mean +- std", f"{stress['mean'] / 1e6:.2f} +- {stress['std'] / 1e6:.2f} MPa"),
            ("peak stress median / 99 % / max", f"{stress['q0.5'] / 1e6:.2f} / {stress['q0.99'] / 1e6:.2f} / "
                                                f"{stress['max'] / 1e6:.2f} MPa"),
            ("peak strain median / 99 % / max", f"{strain['q0.5'] * 1e6:.0f} / {strain['q0.99'] * 1e6:.0f} / "
                                                f"{strain['max'] * 1e6:.0f} microstrain"),
        ]
    )
    p, (lo, hi), k = res.exceedance(args.allowable_strain, "strain")
    print(f"  P(strain > {args.allowable_strain * 1e6:.0f} microstrain) = {p:.4g} ({k} drops; 95 % Wilson interval "
          f"{lo:.4g} to {hi:.4g})")
    if not args.no_plots:
        _save(bd.plot_montecarlo(res, limit=args.allowable_strain, quantity="strain"), _out(args) / "montecarlo.png")


def cmd_bench(args):
    import beamdrop_jax as bd
    from beamdrop_jax._bench import PEERS, ratio_at

    level = "tiny" if args.tiny else "quick" if args.quick else "full"
    print(f"beamdrop bench ({level}): peak-stress error against 32 modes refined (f64), seconds per drop")
    rows = bd.run_bench(_scene(args), level=level, out=_out(args))
    for peer in PEERS:
        ratio = ratio_at(rows, peer)
        print(f"  speed ratio at 1 % error against {peer[6:]}: " + (f"{ratio:.1f}x" if ratio else "n/a (no row meets it)"))
    print(f"wrote {Path(args.out) / 'bench.json'} and {Path(args.out) / 'bench.png'}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="beamdrop", description="Differentiable drop simulation of a board inside a device (SI units)."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p):
        p.add_argument("--scene", help="scene TOML file or embedded scene name (default: the embedded default scene)")
        p.add_argument("--out", default="beamdrop-out", help="folder for figures and tables (default: beamdrop-out)")
        p.add_argument("--float32", action="store_true", help="compute in float32 (default float64)")
        p.add_argument("--no-plots", action="store_true", help="print only, write no figures")

    p = sub.add_parser(
        "impact",
        help="Routh impact of the housing: impulse (N s), mode, velocity jumps (m/s), energy lost (J), diagram",
    )
    common(p)
    p.add_argument("--law", default="poisson", choices=["poisson", "newton", "stronge"], help="restitution law")
    p.set_defaults(func=cmd_impact)

    p = sub.add_parser(
        "drop",
        help="the main job: one drop -> impulse, support jumps (m/s), frequencies (Hz), peak stress (MPa), strain "
        "(microstrain), deflection (mm), where and when; figures",
    )
    common(p)
    p.add_argument("--method", choices=["closed_form", "diffrax"], help="board response method (default closed_form)")
    p.add_argument("--solver", help="diffrax solver name (Tsit5, Dopri5, Dopri8, Kvaerno5, ImplicitEuler, ...)")
    p.add_argument("--n-modes", type=int, help="exactly this many modes (default: chosen from the scene)")
    p.add_argument("--max-impacts", type=int, help="follow the clattering impacts after the first (default 1)")
    p.set_defaults(func=cmd_drop)

    p = sub.add_parser(
        "campaign",
        help="a standard drop campaign (ISTA 1A/2A, MIL-STD-810H 516.8-IV, IEC 60068-2-31, JESD22-B111): peak "
        "stress (MPa) of every drop, the worst drop, CSV table and bar chart",
    )
    common(p)
    p.add_argument("--standard", required=True, choices=["ista-1a", "ista-2a", "mil-std-810h-516-iv",
                                                          "iec-60068-2-31", "jesd22-b111"])
    p.add_argument("--mass", type=float, help="packaged mass for mass-dependent heights, kg (default: the housing's)")
    p.add_argument("--height", type=float, help="free-fall height where the standard leaves it open, m (IEC: 1.0)")
    p.add_argument("--n-modes", type=int, help="exactly this many modes (default: chosen from the scene)")
    p.add_argument("--max-impacts", type=int, help="follow clattering impacts after each drop's first (default 1)")
    p.set_defaults(func=cmd_campaign)

    p = sub.add_parser(
        "sensitivity",
        help="d(peak)/d(field) and elasticity (% per %) of the peak for every scene field, largest first",
    )
    common(p)
    p.add_argument("--quantity", default="stress", choices=["stress", "strain", "deflection"])
    p.add_argument("--n-modes", type=int, help="exactly this many modes (default: chosen from the scene)")
    p.set_defaults(func=cmd_sensitivity)

    p = sub.add_parser(
        "optimize",
        help="place the board (centre in mm, angle in deg) to minimise the peak stress (MPa) over a set of drops",
    )
    common(p)
    p.add_argument("--orientations", default="15:75:7", help="drop angles in degrees: 'lo:hi:n' or 'a,b,c'")
    p.add_argument("--heights", help="drop heights in m, 'h1,h2' (default: the scene's)")
    p.add_argument("--objective", default="mean", choices=["mean", "max", "cvar"])
    p.add_argument("--alpha", type=float, default=0.9, help="CVaR level (default 0.9)")
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--starts", type=int, default=4)
    p.add_argument("--margin", type=float, default=0.0, help="clearance from the housing's edges, m")
    p.add_argument("--n-modes", type=int, help="modes per drop (default 8)")
    p.set_defaults(func=cmd_optimize)

    p = sub.add_parser(
        "montecarlo",
        help="random drops: peak stress (MPa) and strain (microstrain) statistics, P(strain > limit) with a "
        "confidence interval, polar and exceedance figures",
    )
    common(p)
    p.add_argument("-n", type=int, default=100_000, help="number of drops (default 100000)")
    p.add_argument("--allowable-strain", type=float, default=2000e-6, help="strain limit (default 2000e-6)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, help="drops per compiled chunk")
    p.add_argument("--n-modes", type=int, help="modes per drop (default: chosen from the scene, f_k tau >= 1)")
    p.add_argument("--max-impacts", type=int, help="follow clattering impacts after each drop's first (default 1)")
    p.set_defaults(func=cmd_montecarlo)

    p = sub.add_parser(
        "bench",
        help="speed (seconds per drop) against accuracy (peak-stress error) for every method and two peers; "
        "JSON table and chart",
    )
    common(p)
    p.add_argument("--quick", action="store_true", help="the quick set (under 5 minutes on 2 cores)")
    p.add_argument("--tiny", action="store_true", help="a smoke test of every part (seconds)")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    _setup_jax(args)
    import matplotlib

    matplotlib.use("Agg")
    try:
        args.func(args)
    except (ValueError, FileNotFoundError) as err:
        print(f"beamdrop: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
