"""One function per `beamdrop` command: call the library, print, save files. No physics here."""

import dataclasses
import json
import math
import textwrap
from pathlib import Path
from .._studies.standards import STANDARDS
from ._helpers import QUANTITIES, _cli_note, _degrees_list, _numerics, _save, _scene, _scene_name, _tidy_positions



# The faces as campaigns number them (ISTA): 1 top (+e2), 2 right (+e1), 3 bottom (-e2), 4 left (-e1); the face
# that lands flat at orientation k x 90 deg.
FACES = {1: "top, +e2", 2: "right, +e1", 3: "bottom, -e2", 4: "left, -e1"}
FLAT_FACE = {0: 3, 1: 4, 2: 1, 3: 2}


def _landing(scene, res) -> str:
    """'onto a corner', or 'flat onto face 3 (bottom, -e2)' when the housing lands flat (two corners at once)."""
    import numpy as np

    box = res if hasattr(res, "attitude") else getattr(res, "box", None)  # a BoxImpact, or a Response's
    if box is not None and float(scene.drop.tilt) != 0:  # a tilted box: its 3D impact says what struck
        level = int(np.sum(np.abs(np.asarray(box.attitude)[1]) < 64 * np.finfo(float).eps))
        what = ("onto a corner", "onto an edge (G above its midpoint)", "flat onto a face")[min(level, 2)]
        weight = getattr(res, "landing_weight", None)
        if level == 0 and weight is not None and float(weight) > 0:
            return "nearly on an edge or a face (vertices strike together)"
        return what
    hit = getattr(res, "housing", res)  # a Response or a HousingImpact
    weight = getattr(res, "landing_weight", None)
    if (hit is None or not bool(hit.flat)) and weight is not None and float(weight) > 0:
        return "nearly flat (corners strike together)"
    if hit is None or not bool(hit.flat):
        return "onto a corner"
    face = FLAT_FACE[round(float(scene.drop.orientation) / (math.pi / 2)) % 4]
    return f"flat onto face {face} ({FACES[face]})"


def _impact_figure(bd, scene, res):
    """(figure, name): the compliant landing's forces and support accelerations where the drop took it, else the
    rigid law's impulse diagram."""
    if float(res.landing_weight) > 0:
        return bd.plot_landing(scene), "landing.png"
    return bd.plot_impacts(scene, res), "impact.png"


def _impact_figures(bd, scene, res, output, args):
    """A box's 3D figure (box.png), and the impact figure: the compliant landing's where the drop took it, else the
    plane section's rigid impact unless the box is tilted (its 3D impulse is in box.png)."""
    if scene.housing.is_box:
        _save(output, bd.plot_box(scene, res), "box.png", args)
        if float(scene.drop.tilt) != 0 and float(res.landing_weight) == 0:
            return
    _save(output, *_impact_figure(bd, scene, res), args)


def cmd_impact(args, output):
    import numpy as np

    import beamdrop_jax as bd

    scene = _scene(args)
    if scene.housing.is_box and float(scene.drop.tilt) != 0:
        return _box_impact(bd, scene, args, output)
    hit = bd.housing_impact(scene, law=args.law)
    summary = {
        "striking_corner_from_G_mm": np.asarray(hit.corner) * 1e3,
        "approach_velocity_m_per_s": hit.v0,
        **hit.impact.summary(),
        "centre_of_mass_velocity_jump_m_per_s": hit.dv_G,
        "spin_jump_rad_per_s": hit.dw,
        "board_support_jumps_m_per_s": bd.support_jumps(scene, hit),
    }
    if bool(hit.flat):
        summary["contact_mode"] = "flat landing (translation)"
    output.summary(summary, f"Impact of {_scene_name(args)} {_landing(scene, hit)} ({args.law} restitution; S "
                            "tangential, C normal)")
    if not args.no_plots:
        _save(output, bd.plot_housing_impact(scene, hit, law=args.law), "impact.png", args)


def _box_impact(bd, scene, args, output):
    """`beamdrop impact` for a tilted box: the 3D law at its lowest vertex (contact frame (x, z, y): t1, t2, n)."""
    import numpy as np

    from .._impact.kinematics import box_housing_impact, box_support_jumps

    if args.law not in ("poisson", "stronge"):
        raise ValueError(f"--law {args.law}: a tilted box's 3D law takes poisson or stronge restitution")
    hit = box_housing_impact(scene, law=args.law)
    summary = {
        "struck_point_from_G_mm": np.asarray(hit.attitude).T @ np.asarray(hit.r) * 1e3,
        "approach_velocity_m_per_s": hit.u0,
        **hit.impact.summary(),
        "centre_of_mass_velocity_jump_m_per_s": hit.dV,
        "spin_jump_rad_per_s": hit.dOmega,
        "board_jumps_A_B_roll_m_per_s": box_support_jumps(scene, hit),
    }
    output.summary(summary, f"Impact of {_scene_name(args)} {_landing(scene, hit)} ({args.law} restitution; "
                            "contact frame (x, z, y): two tangential, then normal; jumps in the ground frame)")
    if not args.no_plots:
        _save(output, bd.plot_box(scene), "box.png", args)


def cmd_drop(args, output):
    import numpy as np

    import beamdrop_jax as bd

    scene = _scene(args)
    numerics = _numerics(args)
    gauge_x, gauge_y = args.gauge if args.gauge is not None else (None, None)
    plate = scene.board.SURFACE
    if plate:  # a gauge at the centre (where JESD22-B111 measures) and one at --gauge
        gauges = [(float(scene.board.length) / 2, 0.0)] + (
            [(gauge_x * 1e-3, (gauge_y or 0.0) * 1e-3)] if gauge_x is not None else [])
        board_text = (f"; plate {float(scene.board.length) * 1e3:g} x {float(scene.board.width) * 1e3:g} mm, edges "
                      f"{scene.board.edges}" + ("" if scene.board.mounts is None
                                                else f", {scene.board.mounts.shape[0]} mounts"))
    else:
        gauges = None
        board_text = "" if scene.board.ends == "pinned" else f"; board ends {scene.board.ends}"
    res = bd.simulate(scene, numerics, gauges=gauges)
    tau = float(scene.contact.duration)
    output.report["scene"] = args.scene or "default"
    size_mm = 1e3 * max(float(scene.board.length), float(getattr(scene.board, "width", 0.0)))
    output.summary(_tidy_positions(res.summary(), size_mm),
                   f"Drop of {_scene_name(args)}: {float(scene.drop.height):g} m {_landing(scene, res)} at "
                   f"{math.degrees(float(scene.drop.orientation)):.1f} deg"
                   + (f", tilted {math.degrees(float(scene.drop.tilt)):.1f} deg, " if float(scene.drop.tilt) else ", ")
                   + (("compliant contact, " if float(res.landing_weight) > 0 else "half-sine contact, ")
                      + f"{tau * 1e3:g} ms per corner strike" if tau > bd.IMPULSE_DURATION
                      else f"ideal impulse (contact duration {tau:g} s)")
                   + board_text)
    if numerics.max_impacts > 1:
        imp = res.impacts
        rows = [{"impact": i + 1, "t_ms": float(imp.t[i]) * 1e3, "corner_from_G_mm": np.asarray(imp.corner[i]) * 1e3,
                 "approach_speed_m_per_s": float(imp.approach_speed[i]), "impulse_Ns": np.asarray(imp.P[i]),
                 "support_jumps_m_per_s": np.asarray(imp.support_jumps[i])} for i in range(int(imp.count))]
        from .._common.report import plain

        output.report["impacts_table"] = plain(rows)
        output.say(f"Impacts ({int(imp.count)} of at most {numerics.max_impacts}; ended: "
                   f"{bd.Ending(int(imp.ending)).name.lower().replace('_', ' ')})")
        output.say(f"  {'#':>2} {'t (ms)':>9} {'corner (mm)':>16} {'approach (m/s)':>15} {'Pt, Pn (N s)':>20} "
                   f"{'dvA, dvB (m/s)':>17}")
        for r in plain(rows):
            output.say(f"  {r['impact']:>2} {r['t_ms']:>9.3f} {'({:.1f}, {:.1f})'.format(*r['corner_from_G_mm']):>16} "
                       f"{r['approach_speed_m_per_s']:>15.4f} {'{:.4f}, {:.4f}'.format(*r['impulse_Ns']):>20} "
                       f"{'{:.3f}, {:.3f}'.format(*r['support_jumps_m_per_s']):>17}")
    for note in bd.response_notes(scene, res):
        output.note(_cli_note(note, numerics))
    if plate:
        from .._common.report import summary_text, write_csv

        g = res.gauges
        strain = np.asarray(g.strain)  # indexing a JAX array element by element costs 0.3 ms a read
        rows = [{"t_ms": float(t) * 1e3, **{f"gauge{i + 1}_microstrain": float(strain[i, j]) * 1e6
                                             for i in range(len(gauges))}} for j, t in enumerate(np.asarray(g.t))]
        output.wrote(write_csv(rows, Path(args.out) / "gauges.csv"))
        peak_strain, peak_time = np.asarray(g.peak_strain), np.asarray(g.peak_time)  # an indexed JAX array compiles
        readings = [{"x_mm": gx * 1e3, "y_mm": gy * 1e3, "peak_strain_microstrain": float(peak_strain[i]) * 1e6,
                     "peak_time_ms": float(peak_time[i]) * 1e3} for i, (gx, gy) in enumerate(gauges)]
        output.report["gauges"] = readings
        for i, reading in enumerate(readings):
            output.say(summary_text(reading, f"Gauge {i + 1} (largest principal surface strain)"))
        if not args.no_plots:
            strain_map = bd.plate_strain_map(scene, res, numerics)
            _save(output, bd.plot_scene(scene, res), "scene.png", args)
            _save(output, bd.plot_plate_strain(strain_map, res, scene.board), "strain_map.png", args)
            _impact_figures(bd, scene, res, output, args)
        return
    if gauge_x is not None:
        fields = bd.response_fields(scene, numerics, x=[gauge_x * 1e-3], nt=2001)
        from .._common.report import write_csv

        rows = [{"t_ms": t * 1e3, "strain_microstrain": e * 1e6, "stress_MPa": s * 1e-6}
                for t, e, s in zip(np.asarray(fields.t), np.asarray(fields.strain[0]), np.asarray(fields.stress[0]))]
        output.wrote(write_csv(rows, Path(args.out) / f"gauge_{gauge_x:g}mm.csv"))
        peak = int(np.argmax(np.abs(np.asarray(fields.strain[0]))))
        output.summary({"gauge_x_mm": gauge_x, "gauge_peak_strain_microstrain": rows[peak]["strain_microstrain"],
                        "gauge_peak_time_ms": rows[peak]["t_ms"]}, "Gauge (signed strain of the normal-side face)")
        if not args.no_plots:
            fig = bd.plot_gauge_history(fields.t, fields.strain[0], gauge_x * 1e-3,
                                        modulus=scene.board.youngs_modulus)
            _save(output, fig, f"gauge_{gauge_x:g}mm.png", args)
    if not args.no_plots:
        fields = bd.response_fields(scene, numerics)
        _save(output, bd.plot_scene(scene, res), "scene.png", args)
        _save(output, bd.plot_stress_map(fields, res), "stress_map.png", args)
        _save(output, bd.plot_deflected_board(fields, res, thickness=scene.board.thickness), "deflection.png", args)
        _impact_figures(bd, scene, res, output, args)


def cmd_campaign(args, output):
    import beamdrop_jax as bd

    scene = _scene(args)
    result = bd.campaign(scene, args.standard, _numerics(args), mass=args.mass, height=args.height)
    limit = None if args.allowable_microstrain is None else args.allowable_microstrain * 1e-6
    rows = result.rows(limit)
    output.report |= {"standard": args.standard, "drops": rows}
    output.say(f"{args.standard}: {STANDARDS[args.standard]}")
    output.say(result.table(limit))
    if limit is not None:
        over = [r["label"] for r in rows if r["over_limit"]]
        judged = sum(r["over_limit"] is not None for r in rows)
        output.report["drops_over_limit"] = over
        output.say(f"{'FAIL' if over else 'PASS'}: {len(over)} of {judged} drops judged exceed "
                   f"{args.allowable_microstrain:g} microstrain" + (f" ({', '.join(over)})" if over else "")
                   + (f"; {len(rows) - judged} not judged (n/a: not represented or not bent in the plane model)"
                      if judged < len(rows) else ""))
    if result.unbent:
        output.note(f"{len(result.unbent)} drops show 0: {result.unbent_note}")
    output.wrote(result.to_csv(Path(args.out) / f"campaign-{args.standard}.csv"))
    if not args.no_plots:
        fig = bd.plot_campaign(result, scene=args.scene or "default", limit=limit,
                               quantity="stress" if limit is None else "strain")
        _save(output, fig, f"campaign-{args.standard}.png", args)


def cmd_sensitivity(args, output):
    import beamdrop_jax as bd
    from .._common.report import write_csv

    scene = _scene(args)
    numerics = _numerics(args)
    rows = bd.sensitivities(scene, numerics, quantity=args.quantity)
    unit, scale = QUANTITIES[args.quantity]
    peak = {"stress": bd.peak_stress, "strain": bd.peak_strain, "deflection": bd.peak_deflection}[args.quantity]
    value = float(peak(scene, numerics)) * scale
    table = [r.row(unit, scale) for r in rows]
    output.report |= {f"peak_{args.quantity}_{unit}": value, "fields": table}
    output.say(f"Sensitivity of the peak {args.quantity} ({value:.6g} {unit}) to every scene field, largest "
               "elasticity (% change of the peak per % change of the field) first; fields whose value is 0 have no "
               "elasticity and follow, largest derivative first")
    output.say(f"  {'field':<30} {'value':>12} {'unit':<7} {'d(peak)/d(field)':>17} {'per':<20} {'elasticity':>10}")
    for r in table:
        e = "n/a" if r["elasticity"] is None else f"{r['elasticity']:.4f}"
        output.say(f"  {r['field']:<30} {r['value']:>12.6g} {r['unit']:<7} {r['derivative']:>17.6g} "
                   f"{r['derivative_unit']:<20} {e:>10}")
    output.wrote(write_csv(table, Path(args.out) / f"sensitivity-{args.quantity}.csv"))
    if not args.no_plots:
        _save(output, bd.plot_sensitivity(rows, args.quantity), f"sensitivity-{args.quantity}.png", args)


def cmd_optimize(args, output):
    import numpy as np

    import beamdrop_jax as bd
    from .._common.report import write_csv

    scene = _scene(args)
    # Screws are placed for the scene's own drop (a board-level test's, say), as `bd.optimize_mounts` does; the
    # board's placement in a housing for a spread of drops.
    given = args.orientations if args.orientations is not None or args.mounts else _degrees_list("15:75:7")
    orientations = None if given is None else np.radians(given)
    tilts = None if args.tilts is None else np.radians(args.tilts)
    if tilts is not None and not scene.housing.is_box:
        raise ValueError("--tilts turns a box housing out of the plane of motion; this scene is a plane section (give "
                         "its [housing] a depth, or leave --tilts out)")
    if tilts is not None and orientations is None:
        raise ValueError("--tilts gives one tilt per orientation: give --orientations too")
    if tilts is not None and tilts.shape != orientations.shape:
        raise ValueError(f"--tilts gives one tilt per orientation: {tilts.size} tilts for {orientations.size} "
                         "orientations")
    numerics = _numerics(args, n_modes=args.n_modes or 8)
    if args.mounts:
        return _optimize_mounts(args, output, scene, orientations, numerics, tilts)
    max_angle = None if args.max_angle is None else math.radians(args.max_angle)
    res = bd.optimize_placement(scene, orientations, args.heights, objective=args.objective, alpha=args.alpha,
                                numerics=numerics, steps=args.steps, starts=args.starts, margin=args.margin * 1e-3,
                                progress=not args.json, region=args.region, max_angle=max_angle, tilts=tilts)
    summary = res.summary(scene)
    leaves_out = summary.pop("objective_leaves_out")
    output.summary(summary, f"Board placement: {args.objective} peak stress over {res.n_drops} drops "
                            f"({res.n_evaluations} evaluations with gradients)")
    output.report["objective_leaves_out"] = leaves_out
    output.note(f"the objective leaves out {leaves_out}")
    if args.region is None and args.max_angle is None:
        output.note("the board may go anywhere it fits in the housing; --region and --max-angle keep it where you "
                    "can put it")
    history = [{"step": i, "objective_MPa": v / 1e6, "c1_mm": p[0] * 1e3, "c2_mm": p[1] * 1e3,
                "angle_deg": math.degrees(p[2])}
               for i, (v, p) in enumerate(zip(np.asarray(res.history).tolist(), np.asarray(res.path).tolist()))]
    output.wrote(write_csv(history, Path(args.out) / "optimize-history.csv"))
    if not args.no_plots:
        landscape = bd.placement_landscape(scene, res, orientations, args.heights, alpha=args.alpha,
                                           numerics=numerics, margin=args.margin * 1e-3, region=args.region,
                                           tilts=tilts)
        _save(output, bd.plot_placement(scene, res, landscape, orientations=orientations), "placement.png", args)


def _optimize_mounts(args, output, scene, orientations, numerics, tilts=None):
    import numpy as np

    import beamdrop_jax as bd
    from .._common.report import write_csv

    if getattr(scene.board, "mounts", None) is None:
        raise ValueError(f"--mounts moves a plate's screws: {_scene_name(args)} has no plate with mounts (try "
                         "--scene jesd22-board)")
    if args.region is not None or args.max_angle is not None:
        raise ValueError("--region and --max-angle place the board; with --mounts each screw goes anywhere its disc "
                         "fits on the plate (bd.optimize_mounts(region=...) for boxes of your own)")
    gauges = None if args.gauge is None else ((args.gauge[0] * 1e-3, (args.gauge[1] or 0.0) * 1e-3),)
    res = bd.optimize_mounts(scene, min_spacing=args.min_spacing * 1e-3, gauges=gauges, orientations=orientations,
                             tilts=tilts,
                             heights=args.heights, objective=args.objective, alpha=args.alpha, numerics=numerics,
                             steps=args.steps, starts=args.starts, progress=not args.json)
    what = "the gauge's peak strain" if gauges else "the peak strain over the plate"
    output.summary(res.summary(), f"Screw placement: {args.objective} of {what} over {res.n_drops} drop"
                                  + ("" if res.n_drops == 1 else "s") + f" ({res.n_evaluations} evaluations)")
    if not res.converged:
        output.note(f"not converged: the objective still changed over the last steps; raise --steps (now {args.steps})")
    if args.min_spacing and not res.spacing_met:
        output.note(f"--min-spacing {args.min_spacing:g} mm not met: the closest screws are "
                    f"{float(res.spacing) * 1e3:.3g} mm apart")
    history = [{"step": i, "objective_microstrain": v * 1e6} for i, v in enumerate(np.asarray(res.history).tolist())]
    output.wrote(write_csv(history, Path(args.out) / "optimize-mounts-history.csv"))


def cmd_montecarlo(args, output):
    import jax
    import numpy as np

    import beamdrop_jax as bd
    from .._common.report import write_csv_columns

    scene = _scene(args)
    tilts = args.tilts
    if tilts is not None and not scene.housing.is_box:
        raise ValueError("--tilts turns a box housing out of the plane of motion; this scene is a plane section (give "
                         "its [housing] a depth, or leave --tilts out)")
    if tilts is None and scene.housing.is_box:
        tilts = (-90.0, 90.0)  # with orientations 0:360, attitudes uniform on the rotation group
    # Each range maps onto the distribution (uniform; the tilt's sine uniform); a single value fixes the field.
    spec, fixed, fixed_text = {}, {}, []
    orientations = None if args.face_bias else (args.orientations or (0.0, 360.0))
    for name, path, given, scale, unit in (("orientation", "drop.orientation", orientations, math.pi / 180, "deg"),
                                           ("height", "drop.height", args.heights, 1.0, "m"),
                                           ("duration", "contact.duration", args.durations, 1e-3, "ms"),
                                           ("tilt", "drop.tilt", tilts, math.pi / 180, "deg")):
        if given is None:
            spec[name] = None
        elif given[0] < given[1]:
            spec[name] = ("cosine" if name == "tilt" else "uniform", given[0] * scale, given[1] * scale)
        else:
            spec[name], fixed[path] = None, given[0] * scale
            fixed_text.append(f"{'contact ' * (name == 'duration')}{name} fixed at {given[0]:g} {unit}")
    if args.face_bias:
        spec["orientation"] = ("faces", args.face_bias[0], math.radians(args.face_bias[1]))
    if not any(spec.values()):
        raise ValueError("nothing varies: give a range LO:HI to --orientations, --heights or --durations (every drop "
                         "would be the same; 'beamdrop drop' computes one)")
    if fixed:
        scene = scene.replace(**fixed)
    distribution = bd.DropDistribution(**spec)
    numerics = bd.Numerics(n_modes=args.n_modes) if args.n_modes else None
    if args.max_impacts:
        numerics = (dataclasses.replace(numerics, max_impacts=args.max_impacts) if numerics
                    else bd.montecarlo_numerics(scene, distribution, max_impacts=args.max_impacts))
    # A chunk larger than -n would only be padding (the drops and results do not depend on the chunk size).
    batch_size = args.batch_size and min(args.batch_size, args.n)
    res = bd.montecarlo(scene, args.n, jax.random.PRNGKey(args.seed), distribution=distribution, numerics=numerics,
                        batch_size=batch_size, progress=not args.json, max_landings=args.max_landings)
    limit = args.allowable_microstrain * 1e-6
    varied = distribution.describe().replace("every other field", "; ".join(fixed_text + ["every other field"]))
    output.report["varied"] = varied
    output.summary(res.report(limit, "strain"),
                   f"{res.n} random drops ({varied}); drops outside the model are left out of every statistic")
    # In float64 whatever the run's precision, and in degrees as math.degrees rounds: the numbers the CSV held when
    # it was written a dict per drop.
    f64 = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    orientation = np.broadcast_to(f64(res.samples.drop.orientation), (res.n,))
    masks, which = np.unique(np.asarray(res.flags), return_inverse=True)
    names = np.array(["|".join(bd.Flag.describe(m)) for m in masks.tolist()], dtype=object)
    columns = {"orientation_deg": orientation * (180.0 / math.pi)}
    if spec["tilt"]:
        columns["tilt_deg"] = f64(res.samples.drop.tilt) * (180.0 / math.pi)
    if spec["height"]:
        columns["height_m"] = f64(res.samples.drop.height)
    if spec["duration"]:
        columns["contact_duration_ms"] = f64(res.samples.contact.duration) * 1e3
    columns |= {"peak_stress_MPa": f64(res.peak_stress) / 1e6, "peak_strain_microstrain": f64(res.peak_strain) * 1e6,
                "peak_deflection_mm": f64(res.peak_deflection) * 1e3, "flags": names[which.reshape(-1)]}
    output.wrote(write_csv_columns(columns, Path(args.out) / "montecarlo-drops.csv", progress=not args.json))
    flat = _flat_landings(scene, distribution)
    if flat:
        output.report["flat_landing_peak_strain_microstrain"] = max(flat.values()) * 1e6
        output.note(f"a drop exactly on a face gives up to {max(flat.values()) * 1e6:.4g} microstrain under the rigid "
                    "contact model, but random drops never draw one (a hair off flat, one corner strikes first and the "
                    "far corner's strike is not counted): --contact-model auto lands near-flat drops compliantly and "
                    "counts them")
    for note in bd.sample_notes(res.peak_strain, f64(res.samples.contact.duration) if args.durations else None):
        output.note(note)
    if not args.no_plots:
        fig = bd.plot_montecarlo(res, limit=limit, quantity="strain", varied=varied, distribution=distribution,
                                 flat=flat)
        _save(output, fig, "montecarlo.png", args)


def _flat_landings(scene, distribution) -> dict:
    """Under the rigid model, the peak strain of a drop exactly on each face the orientations reach ({orientation
    rad: strain}): random drops miss these (a set of measure zero), so the figure and the note show them. Empty for
    the other models (their near-flat band carries the flat landing) and for a tilted box."""
    import beamdrop_jax as bd

    spec = distribution.orientation
    if scene.contact.model != "rigid" or spec is None or distribution.tilt is not None:
        return {}
    lo, hi = (spec[1], spec[2]) if spec[0] == "uniform" else (0.0, 2 * math.pi)
    faces = [k * math.pi / 2 for k in range(math.ceil(lo / (math.pi / 2) - 1e-9), math.floor(hi / (math.pi / 2)
                                                                                             + 1e-9) + 1)]
    out = {}
    for face in dict.fromkeys(round(f % (2 * math.pi), 12) for f in faces):  # 0 and 360 deg are one face
        res = bd.simulate(scene.replace(**{"drop.orientation": face}))
        if int(res.flags) == 0:
            out[face] = float(res.peak.strain)
    return out


def cmd_bench(args, output):
    import beamdrop_jax as bd

    if args.latency:
        from .._bench import latency_bench

        output.summary(latency_bench(repeats=args.repeats), "beamdrop bench --latency: wall time against a bare "
                                                            "JAX process, median of the repeats")
        return
    from .._bench import CLATTER, PEERS, VARIED, ratio_at

    level = "tiny" if args.tiny else "quick" if args.quick else "full"
    output.say(f"beamdrop bench ({level}): peak-stress error against 32 modes refined (f64), seconds per drop")
    rows = bd.run_bench(_scene(args), level=level, out=Path(args.out))
    ratios = {f"speed_ratio_at_1pct_error_vs_{peer[6:].replace(' ', '_')}": ratio_at(rows, peer) for peer in PEERS}
    ratios["varying_duration_speed_ratio_at_1pct_error_vs_numpy_closed_form"] = ratio_at(
        rows, "peer: numpy closed form", workload=VARIED)
    ratios["clattering_speed_ratio_at_1pct_error_vs_numpy_closed_form"] = ratio_at(
        rows, "peer: numpy closed form", workload=CLATTER)
    output.summary(ratios, "Speed ratios at 1 % error (n/a: no row meets it)")
    output.wrote(Path(args.out) / "bench.json")
    if not args.no_plots:
        study = json.loads((Path(args.out) / "bench.json").read_text())["stability"]
        _save(output, bd.plot_bench(rows), "bench.png", args)
        _save(output, bd.plot_stability(study), "stability.png", args)


# ---------------------------------------------------------------------------------------------------------------


def cmd_scenes(args, output):
    from .._scene.file import embedded_scene_summary, embedded_scene_text, embedded_scenes

    if args.name:
        text = embedded_scene_text(args.name)
        output.report.update(name=args.name, toml=text)
        output.say(text.rstrip("\n"))
        return
    import beamdrop_jax as bd

    rows = {}
    for name in embedded_scenes():
        scene = bd.load_scene(name)
        b, mm = scene.board, lambda v: f"{1e3 * float(v):g}"
        if hasattr(b, "edges"):
            mounts = 0 if b.mounts is None else len(b.mounts)
            board = f"plate {mm(b.length)} x {mm(b.width)} x {mm(b.thickness)} mm, edges {b.edges}, {mounts} mounts"
        else:
            board = f"beam {mm(b.length)} x {mm(b.thickness)} mm, {b.ends} ends"
        h = scene.housing
        housing = (f"box {mm(h.width)} x {mm(h.height)} x {mm(h.depth)} mm" if h.is_box else
                   f"plane section {mm(h.width)} x {mm(h.height)} mm")
        rows[name] = dict(board=board, housing=housing, about=embedded_scene_summary(name))
    output.report["scenes"] = rows
    output.say("Embedded scenes (--scene NAME; 'beamdrop scenes NAME' prints one as TOML):")
    width = max(map(len, rows))
    for name, row in rows.items():
        output.say(f"  {name:<{width}}  {row['board']}; housing: {row['housing']}")
        for line in textwrap.wrap(row["about"], 110 - width):
            output.say(f"  {'':<{width}}  {line}")
