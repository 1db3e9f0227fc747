"""The `beamdrop` command: parse and check the arguments, load a scene, call the library, print, save files.

Every bad argument is one line on stderr and exit status 2 before any computation; Ctrl-C is one line naming the
files that are complete, and exit status 130. Files appear only complete (`_report.atomic_open`). `--json` prints
one JSON object on stdout (units in the keys) instead of the table; messages about written files then go to stderr.
Compiled programs are kept in a persistent cache (the user's cache folder: JAX's compilation cache, and the
package's own programs as executables under `programs/`, which later runs load without tracing them; `--no-cache`
or BEAMDROP_NO_CACHE=1 turn it off, BEAMDROP_CACHE_DIR moves it; a run that compiles removes the least recently
used programs beyond 1 GiB; the programs a command line used are listed under `runs/`, and its next run loads them
in the background while the package imports); a run that must compile says so on stderr.
"""

import argparse
import contextlib
import difflib
import functools
import hashlib
import json
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

# Clattering drops with restitution up to 0.8 come to rest or pivot within 50 impacts (the embedded scenes, every
# orientation). Each pair of impacts is a term of the compiled search (its size and compile time grow as K^2: on 2
# cores K = 3, 20, 50 compile in 6, 14, 54 s and take 0.3, 0.5, 1.3 GB).
MAX_IMPACTS = 50
# What a Monte-Carlo drop costs, measured on `montecarlo -n 2000000` (float64): 113 bytes of memory per drop
# without figures and 240 with them, over 0.5 GB for the process itself; 75 bytes of CSV per drop.
DROP_BYTES, DROP_BYTES_PLOTTED, PROCESS_BYTES, CSV_ROW_BYTES = 120, 250, 600 << 20, 76

STANDARDS = ("ista-1a", "ista-2a", "mil-std-810h-516-iv", "iec-60068-2-31", "jesd22-b111")
QUANTITIES = {"stress": ("MPa", 1e-6), "strain": ("microstrain", 1e6), "deflection": ("mm", 1e3)}


@functools.cache
def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("beamdrop-jax")
    except PackageNotFoundError:
        return "unknown"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        sys.stderr.write(f"{self.prog}: error: {message} (see '{self.prog} --help')\n")
        sys.exit(2)


# ---------------------------------------------------------------------------------------------------------------
# Argument types: each rejects a bad value with a message that names the valid range and unit.


def _int_at_least(lo):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (valid: >= {lo})") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"{value} is out of range (valid: a whole number >= {lo})")
        return value

    return parse


def _int_in(lo, hi):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (valid: [{lo}, {hi}])") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} is out of range (valid: a whole number in [{lo}, {hi}])")
        return value

    return parse


def _float_in(lo, hi, unit, lo_open=False):
    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number (valid: {unit})") from None
        low_ok = value > lo if lo_open else value >= lo
        if not (math.isfinite(value) and low_ok and value <= hi):
            bracket = "(" if lo_open else "["
            raise argparse.ArgumentTypeError(f"{text} is out of range (valid: {bracket}{lo:g}, {hi:g}] {unit})")
        return value

    return parse


def _microstrain(text):
    value = _float_in(0.0, 1e5, "microstrain", lo_open=True)(text)
    if value < 1.0:
        raise argparse.ArgumentTypeError(
            f"{text} microstrain is below 1: give the limit in microstrain (2000 means 0.2 %), not as a fraction"
        )
    return value


def _degrees_list(text):
    """'15:75:7' -> 7 angles from 15 to 75 degrees; '30,45' -> those angles (degrees)."""
    number = _float_in(-3600.0, 3600.0, "deg")
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise argparse.ArgumentTypeError(f"{text!r}: write 'low:high:count' (e.g. 15:75:7) or 'a,b,c' in degrees")
        import numpy as np

        return np.linspace(number(parts[0]), number(parts[1]), _int_at_least(1)(parts[2])).tolist()
    try:
        return [number(v) for v in text.split(",")]
    except argparse.ArgumentTypeError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {err} (write 'a,b,c' or 'low:high:count' in degrees)") from None


def _scene_arg(text):
    if not text.strip():  # not the default scene: an unset variable in a script (--scene "$SCENE") would be silent
        from ._scenefile import embedded_scenes

        raise argparse.ArgumentTypeError(f"{text!r} is empty (valid: a scene TOML file, or an embedded scene: "
                                         f"{', '.join(embedded_scenes())})")
    return text


def _heights(text):
    height = _float_in(0.0, 1e4, "m", lo_open=True)
    return [height(v) for v in text.split(",")]


# ---------------------------------------------------------------------------------------------------------------
# Output: tables for people, one JSON object for programs.


class _Output:
    def __init__(self, args):
        self.json = getattr(args, "json", False)
        self.report = {}

    def say(self, text=""):
        if not self.json:
            print(text)

    def wrote(self, path):
        print(f"wrote {path}", file=sys.stderr if self.json else sys.stdout)
        self.report.setdefault("files", []).append(str(path))
        _active["files"].append(path)

    def summary(self, summary: dict, title: str):
        from ._report import plain, summary_text

        self.report.update(plain(summary))
        self.say(summary_text(summary, title))


def _scene(args):
    import beamdrop_jax as bd

    return bd.load_scene(args.scene) if args.scene else bd.Scene.default()


def _scene_name(args) -> str:
    return f"scene {args.scene}" if args.scene else "the default scene"


def _writes_files(args) -> bool:
    return (not args.no_plots) or args.command in ("campaign", "sensitivity", "montecarlo", "optimize") or bool(
        getattr(args, "gauge", None)
    )


def _check_out(args):
    """Create `--out` and prove it writable before any computation."""
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".beamdrop-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise ValueError(f"--out {args.out}: cannot write there ({err.strerror or err})") from None


def _available_memory() -> int | None:
    """Bytes of memory a new allocation can still get: the kernel's estimate (MemAvailable: free memory and caches
    it can drop), within the cgroup's limit in a container; else free (or all) physical memory; None if unknown."""
    available = None
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/meminfo") as f:
            available = next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    for name in ("SC_AVPHYS_PAGES", "SC_PHYS_PAGES"):  # macOS has only the second
        if available is None:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                available = os.sysconf(name) * os.sysconf("SC_PAGE_SIZE")
    with contextlib.suppress(OSError, ValueError):
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            room = int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text())
            available = room if available is None else min(available, room)
    return available


def _size(n_bytes: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB", "TB", "PB"):
        if n_bytes < 1000 or unit == "PB":
            return f"{n_bytes:.0f} {unit}" if unit == "bytes" else f"{n_bytes:.3g} {unit}"
        n_bytes /= 1000


def _check_montecarlo_fits(args):
    """Refuse an `-n` whose results cannot fit in memory or whose CSV cannot fit on the disk of `--out`, before
    anything runs (an impossible -n otherwise fails inside XLA after a long wait, or fills the disk)."""
    import shutil

    per_drop = DROP_BYTES if args.no_plots else DROP_BYTES_PLOTTED
    memory, free = _available_memory(), shutil.disk_usage(args.out).free
    fits = [free // CSV_ROW_BYTES] + ([] if memory is None else [max(0, memory - PROCESS_BYTES) // per_drop])
    valid = f"valid here: -n in [1, {min(fits)}]" if min(fits) >= 1 else "too little is left for any -n"
    if memory is not None and PROCESS_BYTES + args.n * per_drop > memory:
        raise ValueError(f"-n {args.n} needs about {_size(PROCESS_BYTES + args.n * per_drop)} of memory ({per_drop} "
                         f"bytes per drop{'' if args.no_plots else ' with figures'}) but {_size(memory)} is "
                         f"available; {valid}" + ("" if args.no_plots else " (more with --no-plots)"))
    if args.n * CSV_ROW_BYTES > free:
        raise ValueError(f"-n {args.n}: the CSV of every drop needs about {_size(args.n * CSV_ROW_BYTES)} on disk "
                         f"({CSV_ROW_BYTES} bytes per drop) but {args.out} has {_size(free)} free; {valid}")


def _save(output, fig, name, args):
    import matplotlib.pyplot as plt

    from ._report import atomic_open

    path = Path(args.out) / name
    try:
        with atomic_open(path, "wb") as f:
            fig.savefig(f, format=path.suffix[1:], dpi=120)
    finally:
        plt.close(fig)
    output.wrote(path)


def _numerics(args, **overrides):
    import beamdrop_jax as bd

    kw = {k: getattr(args, k) for k in ("method", "solver", "n_modes", "max_impacts") if getattr(args, k, None)}
    kw.update(overrides)
    return bd.Numerics(**kw)


# ---------------------------------------------------------------------------------------------------------------
# Commands.


def cmd_impact(args, output):
    import numpy as np

    import beamdrop_jax as bd

    scene = _scene(args)
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
    output.summary(summary, f"Impact of {_scene_name(args)} ({args.law} restitution; S tangential, C normal)")
    if not args.no_plots:
        fig = bd.plot_impact(hit.B, hit.v0, scene.contact.friction, scene.contact.restitution, law=args.law)
        _save(output, fig, "impact.png", args)


def cmd_drop(args, output):
    import numpy as np

    import beamdrop_jax as bd

    scene = _scene(args)
    numerics = _numerics(args)
    if args.gauge is not None and not 0 <= args.gauge * 1e-3 <= float(scene.board.length):
        raise ValueError(f"--gauge {args.gauge:g} mm is off the board: valid [0, {float(scene.board.length) * 1e3:g}] "
                         "mm from end A")
    plate = isinstance(scene.board, bd.Plate)
    if plate:  # a gauge at the centre (where JESD22-B111 measures) and one at --gauge on the centre line
        gauges = [(float(scene.board.length) / 2, 0.0)] + ([(args.gauge * 1e-3, 0.0)] if args.gauge is not None else [])
        board_text = (f"; plate {float(scene.board.length) * 1e3:g} x {float(scene.board.width) * 1e3:g} mm, edges "
                      f"{scene.board.edges}" + ("" if scene.board.mounts is None
                                                else f", {scene.board.mounts.shape[0]} mounts"))
    else:
        gauges = None
        board_text = "" if scene.board.ends == "pinned" else f"; board ends {scene.board.ends}"
    res = bd.simulate(scene, numerics, gauges=gauges)
    tau = float(scene.contact.duration)
    output.report["scene"] = args.scene or "default"
    output.summary(res.summary(),
                   f"Drop of {_scene_name(args)}: {float(scene.drop.height):g} m onto a corner at "
                   f"{math.degrees(float(scene.drop.orientation)):.1f} deg, "
                   + (f"half-sine contact {tau * 1e3:g} ms" if tau > 0 else "ideal impulse (contact duration 0)")
                   + board_text)
    if numerics.max_impacts > 1:
        imp = res.impacts
        rows = [{"impact": i + 1, "t_ms": float(imp.t[i]) * 1e3, "corner_from_G_mm": np.asarray(imp.corner[i]) * 1e3,
                 "approach_speed_m_per_s": float(imp.approach_speed[i]), "impulse_Ns": np.asarray(imp.P[i]),
                 "support_jumps_m_per_s": np.asarray(imp.support_jumps[i])} for i in range(int(imp.count))]
        from ._report import plain

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
        output.say(f"  note: {note}")
        output.report.setdefault("notes", []).append(note)
    if plate:
        from ._report import summary_text, write_csv

        g = res.gauges
        rows = [{"t_ms": float(t) * 1e3, **{f"gauge{i + 1}_microstrain": float(g.strain[i, j]) * 1e6
                                             for i in range(len(gauges))}} for j, t in enumerate(np.asarray(g.t))]
        output.wrote(write_csv(rows, Path(args.out) / "gauges.csv"))
        readings = [{"x_mm": gx * 1e3, "y_mm": gy * 1e3, "peak_strain_microstrain": float(g.peak_strain[i]) * 1e6,
                     "peak_time_ms": float(g.peak_time[i]) * 1e3} for i, (gx, gy) in enumerate(gauges)]
        output.report["gauges"] = readings
        for i, reading in enumerate(readings):
            output.say(summary_text(reading, f"Gauge {i + 1} (largest principal surface strain)"))
        if not args.no_plots:
            strain_map = bd.plate_strain_map(scene, res, numerics)
            _save(output, bd.plot_scene(scene, res), "scene.png", args)
            _save(output, bd.plot_plate_strain(strain_map, res, scene.board), "strain_map.png", args)
            _save(output, bd.plot_impacts(scene, res), "impact.png", args)
        return
    if args.gauge is not None:
        fields = bd.response_fields(scene, numerics, x=[args.gauge * 1e-3], nt=2001)
        from ._report import write_csv

        rows = [{"t_ms": t * 1e3, "strain_microstrain": e * 1e6, "stress_MPa": s * 1e-6}
                for t, e, s in zip(np.asarray(fields.t), np.asarray(fields.strain[0]), np.asarray(fields.stress[0]))]
        output.wrote(write_csv(rows, Path(args.out) / f"gauge_{args.gauge:g}mm.csv"))
        peak = int(np.argmax(np.abs(np.asarray(fields.strain[0]))))
        output.summary({"gauge_x_mm": args.gauge, "gauge_peak_strain_microstrain": rows[peak]["strain_microstrain"],
                        "gauge_peak_time_ms": rows[peak]["t_ms"]}, "Gauge (signed strain of the normal-side face)")
    if not args.no_plots:
        fields = bd.response_fields(scene, numerics)
        _save(output, bd.plot_scene(scene, res), "scene.png", args)
        _save(output, bd.plot_stress_map(fields, res), "stress_map.png", args)
        _save(output, bd.plot_deflected_board(fields, res, thickness=scene.board.thickness), "deflection.png", args)
        _save(output, bd.plot_impacts(scene, res), "impact.png", args)


def cmd_campaign(args, output):
    import beamdrop_jax as bd

    scene = _scene(args)
    result = bd.campaign(scene, args.standard, _numerics(args), mass=args.mass, height=args.height)
    output.report |= {"standard": args.standard, "drops": result.rows()}
    output.say(f"{args.standard}: {bd.STANDARDS[args.standard]}")
    output.say(result.table())
    output.wrote(result.to_csv(Path(args.out) / f"campaign-{args.standard}.csv"))
    if not args.no_plots:
        _save(output, bd.plot_campaign(result, scene=args.scene or "default"), f"campaign-{args.standard}.png", args)


def cmd_sensitivity(args, output):
    import beamdrop_jax as bd
    from ._report import write_csv

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


def cmd_optimize(args, output):
    import numpy as np

    import beamdrop_jax as bd
    from ._report import write_csv

    scene = _scene(args)
    orientations = np.radians(args.orientations)
    numerics = _numerics(args, n_modes=args.n_modes or 8)
    res = bd.optimize_placement(scene, orientations, args.heights, objective=args.objective, alpha=args.alpha,
                                numerics=numerics, steps=args.steps, starts=args.starts, margin=args.margin * 1e-3,
                                progress=not args.json)
    output.summary(res.summary(scene), f"Board placement: {args.objective} peak stress over {res.n_drops} drops "
                                       f"({res.n_evaluations} evaluations with gradients)")
    history = [{"step": i, "objective_MPa": v / 1e6, "c1_mm": p[0] * 1e3, "c2_mm": p[1] * 1e3,
                "angle_deg": math.degrees(p[2])}
               for i, (v, p) in enumerate(zip(np.asarray(res.history).tolist(), np.asarray(res.path).tolist()))]
    output.wrote(write_csv(history, Path(args.out) / "optimize-history.csv"))
    if not args.no_plots:
        landscape = bd.placement_landscape(scene, res, orientations, args.heights, alpha=args.alpha,
                                           numerics=numerics, margin=args.margin * 1e-3)
        _save(output, bd.plot_placement(scene, res, landscape), "placement.png", args)


def cmd_montecarlo(args, output):
    import dataclasses

    import jax
    import numpy as np

    import beamdrop_jax as bd
    from ._report import write_csv_columns

    scene = _scene(args)
    numerics = bd.Numerics(n_modes=args.n_modes) if args.n_modes else None
    if args.max_impacts:
        numerics = (dataclasses.replace(numerics, max_impacts=args.max_impacts) if numerics
                    else bd.montecarlo_numerics(scene, max_impacts=args.max_impacts))
    # A chunk larger than -n would only be padding (the drops and results do not depend on the chunk size).
    batch_size = args.batch_size and min(args.batch_size, args.n)
    res = bd.montecarlo(scene, args.n, jax.random.PRNGKey(args.seed), numerics=numerics,
                        batch_size=batch_size, progress=not args.json)
    limit = args.allowable_microstrain * 1e-6
    output.summary(res.report(limit, "strain"),
                   f"{res.n} random drops (orientation uniform on [0, 360) deg); drops outside the model are left "
                   "out of every statistic")
    # In float64 whatever the run's precision, and in degrees as math.degrees rounds: the numbers the CSV held when
    # it was written a dict per drop.
    f64 = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    orientation = np.broadcast_to(f64(res.samples.drop.orientation), (res.n,))
    masks, which = np.unique(np.asarray(res.flags), return_inverse=True)
    names = np.array(["|".join(bd.Flag.describe(m)) for m in masks.tolist()], dtype=object)
    columns = {"orientation_deg": orientation * (180.0 / math.pi), "peak_stress_MPa": f64(res.peak_stress) / 1e6,
               "peak_strain_microstrain": f64(res.peak_strain) * 1e6,
               "peak_deflection_mm": f64(res.peak_deflection) * 1e3, "flags": names[which.reshape(-1)]}
    output.wrote(write_csv_columns(columns, Path(args.out) / "montecarlo-drops.csv", progress=not args.json))
    if not args.no_plots:
        _save(output, bd.plot_montecarlo(res, limit=limit, quantity="strain"), "montecarlo.png", args)


def cmd_bench(args, output):
    import beamdrop_jax as bd

    if args.latency:
        from ._bench import latency_bench

        output.summary(latency_bench(repeats=args.repeats), "beamdrop bench --latency: wall time against a bare "
                                                            "JAX process, median of the repeats")
        return
    from ._bench import CLATTER, PEERS, VARIED, ratio_at

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


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="beamdrop",
        description="Differentiable drop simulation of a board inside a device. Inputs in SI units (scene files: "
        "angles in degrees under *_deg keys); outputs in MPa, microstrain, mm and ms.",
        epilog="Start with 'beamdrop drop' (the embedded default scene). Each command's --help gives its options.",
    )
    parser.add_argument("--version", action="version", version=f"beamdrop {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    from ._scenefile import embedded_scenes

    scenes = ", ".join(embedded_scenes())

    def command(name, help_text, description=None):
        p = sub.add_parser(name, help=help_text, description=(description or help_text).replace("%%", "%"))
        p.add_argument("--scene", metavar="FILE_OR_NAME", type=_scene_arg,
                       help=f"scene TOML file, or an embedded scene: {scenes} (default: default)")
        p.add_argument("--out", default="beamdrop-out", metavar="DIR",
                       help="folder for figures and tables, created if needed (default: beamdrop-out)")
        p.add_argument("--float32", action="store_true", help="compute in float32 (default: float64)")
        p.add_argument("--no-plots", action="store_true", help="write no figures")
        p.add_argument("--json", action="store_true",
                       help="print one JSON object (units in the keys) instead of the table")
        p.add_argument("--no-cache", action="store_true",
                       help="do not keep compiled programs between runs (also: BEAMDROP_NO_CACHE=1)")
        return p

    def modes(p, default="chosen from the scene"):
        p.add_argument("--n-modes", type=_int_at_least(1), metavar="N",
                       help=f"use exactly modes 1..N (default: {default})")

    def impacts(p):
        p.add_argument("--max-impacts", type=_int_in(1, MAX_IMPACTS), metavar="K",
                       help=f"follow up to K impacts: the first and the clattering ones after it, K in [1, "
                            f"{MAX_IMPACTS}] (default 1: the first impact only)")

    p = command("impact", "the housing's corner impact alone: impulse (N s), contact mode, velocity jumps (m/s), "
                          "energy lost (J), impulse diagram")
    p.add_argument("--law", default="poisson", choices=["poisson", "newton", "stronge"],
                   help="restitution law (default poisson)")
    p.set_defaults(func=cmd_impact)

    p = command("drop", "the main job: one drop -> impulse (N s), support jumps (m/s), frequencies (Hz), peak "
                        "stress (MPa), strain (microstrain) and deflection (mm), where (mm from end A) and when (ms); "
                        "figures")
    p.add_argument("--method", choices=["closed_form", "diffrax"], help="board response method (default closed_form)")
    p.add_argument("--solver", help="diffrax solver (Tsit5, Dopri5, Dopri8, Kvaerno5, ImplicitEuler, ...)")
    modes(p)
    impacts(p)
    p.add_argument("--gauge", type=_float_in(0.0, 1e5, "mm"), metavar="X_MM",
                   help="also write the strain history at X_MM from end A (CSV: ms, microstrain, MPa)")
    p.set_defaults(func=cmd_drop)

    p = command("campaign", "a standard drop campaign (ISTA 1A/2A, MIL-STD-810H 516.8-IV, IEC 60068-2-31, "
                            "JESD22-B111): peak stress (MPa) of every drop, the worst drop, CSV table and bar chart")
    p.add_argument("--standard", required=True, choices=STANDARDS, help="the standard")
    p.add_argument("--mass", type=_float_in(0.0, 1e4, "kg", lo_open=True), metavar="KG",
                   help="packaged mass for mass-dependent heights, kg (default: the housing's)")
    p.add_argument("--height", type=_float_in(0.0, 1e3, "m", lo_open=True), metavar="M",
                   help="free-fall height where the standard leaves it open, m (IEC: default 1.0)")
    modes(p)
    impacts(p)
    p.set_defaults(func=cmd_campaign)

    p = command("sensitivity", "d(peak)/d(field) with units and the elasticity (%% per %%) of the peak for every "
                               "scene field, largest first; CSV table")
    p.add_argument("--quantity", default="stress", choices=list(QUANTITIES), help="which peak (default stress)")
    modes(p)
    p.set_defaults(func=cmd_sensitivity)

    p = command("optimize", "place the board (centre in mm, angle in deg) to minimise the peak stress (MPa) over a "
                            "set of drops; CSV history")
    p.add_argument("--orientations", type=_degrees_list, default=_degrees_list("15:75:7"), metavar="DEG",
                   help="drop angles in degrees: 'low:high:count' or 'a,b,c' (default 15:75:7)")
    p.add_argument("--heights", type=_heights, metavar="M", help="drop heights in m, 'h1,h2' (default: the scene's)")
    p.add_argument("--objective", default="mean", choices=["mean", "max", "cvar"],
                   help="risk over the drops (default mean)")
    p.add_argument("--alpha", type=_float_in(0.0, 0.999, "(CVaR level)"), default=0.9,
                   help="CVaR level in [0, 0.999] (default 0.9)")
    p.add_argument("--steps", type=_int_at_least(1), default=100, help="optimiser steps (default 100)")
    p.add_argument("--starts", type=_int_at_least(1), default=4, help="optimiser starts (default 4)")
    p.add_argument("--margin", type=_float_in(0.0, 1e4, "mm"), default=0.0, metavar="MM",
                   help="clearance between the board's ends and the housing's edges, mm (default 0)")
    modes(p, "8")
    p.set_defaults(func=cmd_optimize)

    p = command("montecarlo", "random drops: peak stress (MPa) and strain (microstrain) statistics, P(strain > "
                              "limit) with a 95 %% interval; CSV of every drop, polar and exceedance figures")
    p.add_argument("-n", type=_int_at_least(1), default=100_000, help="number of drops (default 100000)")
    p.add_argument("--allowable-microstrain", type=_microstrain, default=2000.0, metavar="UE",
                   help="strain limit in microstrain (default 2000, i.e. 0.2 %%)")
    p.add_argument("--seed", type=_int_at_least(0), default=0, help="random seed (default 0)")
    p.add_argument("--batch-size", type=_int_at_least(1), metavar="N", help="drops per compiled chunk")
    modes(p, "chosen from the scene")
    impacts(p)
    p.set_defaults(func=cmd_montecarlo)

    p = command("bench", "speed against accuracy (peak-stress error, seconds per drop) for every method against "
                         "NumPy and SciPy peers, or --latency: time to first answer; JSON table and chart")
    level = p.add_mutually_exclusive_group()
    level.add_argument("--quick", action="store_true", help="the quick set (about 5 minutes on 2 cores)")
    level.add_argument("--tiny", action="store_true", help="a smoke test of every part (seconds)")
    level.add_argument("--latency", action="store_true",
                       help="import, first drop and first gradient in fresh processes against a bare JAX process")
    p.add_argument("--repeats", type=_int_at_least(1), default=5, help="repeats for --latency (default 5)")
    p.set_defaults(func=cmd_bench)
    parser.commands = sub.choices
    return parser


def _parse(argv) -> argparse.Namespace:
    """The arguments; one a command does not know is reported by that command, with the nearest option."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        command = parser.commands[args.command]
        options = [o for action in command._actions for o in action.option_strings]
        near = difflib.get_close_matches(extra[0].split("=")[0], options, n=1)
        command.error(f"unrecognized arguments: {' '.join(extra)}" + (f"; did you mean {near[0]}?" if near else ""))
    if getattr(args, "solver", None) and args.method != "diffrax":
        parser.commands[args.command].error(
            f"--solver {args.solver} needs --method diffrax (--method {args.method or 'closed_form'}"
            f"{'' if args.method else ', the default,'} has no solver)")
    return args


# Commands whose programs run for milliseconds: compiled for latency (`_compile.quick_programs`).
QUICK_COMMANDS = ("drop", "sensitivity", "impact", "campaign")
CACHE_MAX_BYTES = 1 << 30  # the least recently used programs go beyond this (older package versions' first)


def _cache_dir() -> Path:
    if os.environ.get("BEAMDROP_CACHE_DIR"):
        return Path(os.environ["BEAMDROP_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "beamdrop_jax" / "xla"


def _setup_jax(args):
    """Precision, and the persistent compilation cache (the CLI's choices; the library never changes JAX's config).
    Returns the stamp file that marks these settings as compiled, or None without a cache."""
    import jax

    jax.config.update("jax_enable_x64", not args.float32)
    if getattr(args, "scene", None):
        _scene(args)  # a wrong scene file is reported before any word on compiling
    if args.no_cache or os.environ.get("BEAMDROP_NO_CACHE", "") not in ("", "0"):
        print("beamdrop: compiling (the compilation cache is off)", file=sys.stderr)
        return None
    cache = _cache_dir()
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError:
        print(f"beamdrop: compiling (cannot create the cache folder {cache})", file=sys.stderr)
        return None
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    settings = {k: v for k, v in sorted(vars(args).items()) if k not in ("out", "json", "func", "no_plots")}
    key = hashlib.sha1(repr((_version(), jax.__version__, settings)).encode()).hexdigest()[:16]
    stamp = cache / f"compiled-{key}"
    if not stamp.exists():
        print(f"beamdrop: compiling (first run with these settings; kept in {cache} for later runs)",
              file=sys.stderr)
    return stamp


def _run_record(argv) -> Path | None:
    """Where the kept programs that this command line (in this folder) used are listed, so that its next run
    starts loading them before the package has imported; None without a cache."""
    if "--no-cache" in argv or os.environ.get("BEAMDROP_NO_CACHE", "") not in ("", "0"):
        return None
    key = hashlib.sha1(repr((os.getcwd(), list(argv))).encode()).hexdigest()[:16]
    return _cache_dir() / "runs" / f"{key}.json"


def _preload(record: Path | None):
    """(names listed in `record`, the thread loading them) or ((), None)."""
    try:
        names = json.loads(record.read_text())
    except (AttributeError, OSError, ValueError):
        return (), None
    if not isinstance(names, list):
        return (), None
    from ._compile import preload_programs

    return names, preload_programs(_cache_dir() / "programs", names)


def _bound_cache(stamp: Path) -> None:
    """Mark the run's settings as compiled; after a run that compiled, remove the cache's least recently used
    programs beyond `CACHE_MAX_BYTES` (the settings' stamps stay)."""
    if not stamp.exists():
        from ._compile import prune_folder

        prune_folder(stamp.parent, CACHE_MAX_BYTES, keep=lambda path: path.name.startswith("compiled-"))
    stamp.touch()


@contextlib.contextmanager
def _figures_to_files():
    """Figures are drawn off-screen (Agg); matplotlib is imported only where a figure is drawn."""
    if "matplotlib" in sys.modules:
        sys.modules["matplotlib"].use("Agg")
        yield
        return
    before = os.environ.get("MPLBACKEND")
    os.environ["MPLBACKEND"] = "Agg"
    try:
        yield
    finally:  # the process's environment as it was (a caller's later subprocesses inherit it)
        if before is None:
            del os.environ["MPLBACKEND"]
        else:
            os.environ["MPLBACKEND"] = before


# 128 + SIGINT: the status shells give a command that Ctrl-C ended.
INTERRUPTED = 130
# The command running now and the files it has completed: what an interrupt's message names.
_active = {"command": None, "files": [], "claim": threading.Lock()}


def _interrupt_once(signum, frame):
    """SIGINT: a KeyboardInterrupt, once; later ones are ignored so that the cleanup it starts runs whole."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def _interrupted_line() -> str:
    files = _active["files"]
    kept = (f"kept the complete files {', '.join(map(str, files))}, nothing else written" if files
            else "no results written")
    return f"beamdrop{' ' + _active['command'] if _active['command'] else ''}: interrupted; {kept}"


def main(argv=None) -> int:
    """The command line `argv` (default: the process's); returns the exit status: 0, 2 for a bad input (one line
    on stderr), 130 for Ctrl-C (one line on stderr naming the files that are complete)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    _active.update(command=next((a for a in argv if not a.startswith("-")), None), files=[], claim=threading.Lock())
    previous = None
    # Python's own Ctrl-C handler only: a caller's handler, or SIGINT ignored (`nohup`), stays as it is.
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is \
            signal.default_int_handler:
        previous = signal.signal(signal.SIGINT, _interrupt_once)
    try:
        return _main(argv)
    except KeyboardInterrupt:
        if _active["claim"].acquire(blocking=False):  # else the watchdog (`run`) has said it and ends the process
            print(_interrupted_line(), file=sys.stderr)
        return INTERRUPTED
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _main(argv) -> int:
    record = _run_record(argv)
    # The programs this command line used last time load in the background while the package imports.
    listed, preloading = _preload(record)
    try:
        args = _parse(argv)
        _active["command"] = args.command
        output = _Output(args)
        try:
            if _writes_files(args):
                _check_out(args)
            if args.command == "montecarlo":
                _check_montecarlo_fits(args)
            stamp = _setup_jax(args)
            from ._compile import keep_programs, quick_programs

            keeping = keep_programs(_cache_dir() / "programs") if stamp is not None else contextlib.nullcontext([])
            with keeping as used, _figures_to_files(), quick_programs(args.command in QUICK_COMMANDS):
                args.func(args, output)
        except (ValueError, FileNotFoundError) as err:
            print(f"beamdrop {args.command}: error: {err}", file=sys.stderr)
            return 2
    finally:
        if preloading is not None:  # never exit while it runs in XLA
            preloading.join()
    if stamp is not None:
        _bound_cache(stamp)
        if used and used != listed:
            with contextlib.suppress(OSError):
                record.parent.mkdir(parents=True, exist_ok=True)
                record.write_text(json.dumps(used))
    if args.json:
        from ._report import plain

        print(json.dumps(plain(output.report), indent=1, allow_nan=False))  # NaN (a drop not modelled): null
    return 0


INTERRUPT_GRACE_S = 1.0


def _watch_interrupts() -> None:
    """Ctrl-C reaches Python's handler only when the main thread returns from compiled code (an XLA compile can
    take a minute): a thread woken by the signal itself (`signal.set_wakeup_fd`) ends the command when the main
    thread has not within `INTERRUPT_GRACE_S`, with the same line and status, after removing the files being
    written. Only for the `beamdrop` process (`run`): it ends the process."""
    try:
        wake, woken = os.pipe()
        os.set_blocking(woken, False)
        signal.set_wakeup_fd(woken)
    except (OSError, ValueError):  # not the main thread, or no pipes: Python's handler alone
        return

    def watch():
        while signal.SIGINT not in os.read(wake, 64):
            pass
        time.sleep(INTERRUPT_GRACE_S)
        if not _active["claim"].acquire(blocking=False):
            return  # the main thread has handled it
        if "beamdrop_jax._report" in sys.modules:  # else no file is being written
            sys.modules["beamdrop_jax._report"].abandon_writes()
        # Over a progress bar's line, as the bar redraws itself (and on a terminal, erasing it).
        with contextlib.suppress(OSError, ValueError):
            sys.stderr.write(("\r\033[K" if sys.stderr.isatty() else "\r") + _interrupted_line() + "\n")
            sys.stderr.flush()
        os._exit(INTERRUPTED)

    threading.Thread(target=watch, name="beamdrop-interrupt", daemon=True).start()


def run() -> None:
    """The `beamdrop` command: `main`, then the process ends without Python's teardown, which frees JAX's and XLA's
    objects one by one (0.1 s on the 2-core development machine, a sixth of a warm `beamdrop drop`). Everything
    the command writes is complete by then: files are closed as they are written, and the output is flushed here.
    A reader that stops early (`beamdrop drop | head`) ends the command quietly, as it does other Unix tools."""
    _watch_interrupts()
    try:
        code = main()
    except BrokenPipeError:
        code = 1
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # done: a late Ctrl-C changes nothing
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe or stream: nothing more to deliver
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    run()
