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
import hashlib
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

from .._studies.standards import STANDARDS
from ._helpers import CSV_ROW_BYTES as CSV_ROW_BYTES  # named in the -n check's message
from ._helpers import (
    MAX_IMPACTS,
    MAX_MODES,
    QUANTITIES,
    _Output,
    _Parser,
    _active,
    _check_montecarlo_fits,
    _check_out,
    _degrees_list,
    _float_in,
    _gauge,
    _heights,
    _int_at_least,
    _int_in,
    _microstrain,
    _basis,
    _face_bias,
    _range,
    _region,
    _scene,
    _scene_arg,
    _version,
    _writes_files,
)

from ._commands import (cmd_bench, cmd_campaign, cmd_drop, cmd_impact, cmd_montecarlo, cmd_optimize, cmd_scenes,
                        cmd_sensitivity)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="beamdrop",
        description="Differentiable drop simulation of a board inside a device. Inputs in SI units (scene files: "
        "angles in degrees under *_deg keys); outputs in MPa, microstrain, mm and ms.",
        epilog="Start with 'beamdrop drop' (the embedded default scene). Each command's --help gives its options.",
    )
    parser.add_argument("--version", action="version", version=f"beamdrop {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    from .._scene.file import embedded_scenes

    scenes = ", ".join(embedded_scenes())

    def command(name, help_text, description=None):
        p = sub.add_parser(name, help=help_text, description=(description or help_text).replace("%%", "%"))
        p.add_argument("--scene", metavar="FILE_OR_NAME", type=_scene_arg,
                       help=f"scene TOML file, or an embedded scene: {scenes} (default: default; 'beamdrop "
                            "scenes' lists them)")
        p.add_argument("--out", default="beamdrop-out", metavar="DIR",
                       help="folder for figures and tables, created if needed (default: beamdrop-out)")
        p.add_argument("--float32", action="store_true", help="compute in float32 (default: float64)")
        p.add_argument("--no-plots", action="store_true", help="write no figures")
        p.add_argument("--json", action="store_true",
                       help="print one JSON object (units in the keys) instead of the table")
        p.add_argument("--no-cache", action="store_true",
                       help="do not keep compiled programs between runs (also: BEAMDROP_NO_CACHE=1)")
        return p

    def modes(p, default="chosen from the scene", cap=False):
        group = p.add_mutually_exclusive_group() if cap else p
        group.add_argument("--n-modes", type=_int_at_least(1), metavar="N",
                           help=f"use exactly modes 1..N (default: {default})")
        if cap:
            group.add_argument("--max-modes", type=_int_in(4, MAX_MODES), metavar="N",
                               help=f"at most N modes where the count is chosen from the scene, N in [4, "
                                    f"{MAX_MODES}] (default 16; Numerics.max_modes): raise it when a drop says "
                                    "it is not converged")
            p.add_argument("--window", type=_float_in(0.0, 1e3, "ms", lo_open=True), metavar="MS",
                           help="the peak window, ms (default: the contact plus the board's fundamental period; "
                                "Numerics.window): widen it when a plate drop says a gauge reads more after it")
            p.add_argument("--basis", type=_basis, metavar="NX,NY",
                           help="a plate's Ritz basis, NX x NY functions, each in [2, 40] (default: the scene's, "
                                "12,12 unless its [plate] gives basis; Plate.basis): raise it when a plate drop says "
                                "its basis is not converged")

    def landing(p):
        p.add_argument("--contact-model", choices=("auto", "rigid", "compliant"),
                       help="how the housing lands (default: the scene's [contact] model, auto): rigid = Routh's law "
                            "at one corner, the first strike; compliant = springs at every corner that touches, "
                            "integrated through the board's peak window; auto = rigid where a corner strikes alone, "
                            "compliant where strikes overlap (near-flat landings, about 0.03 s a drop on a beam, 0.2 s on a "
                            "plate)")

    def impacts(p):
        landing(p)
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
    modes(p, cap=True)
    impacts(p)
    p.add_argument("--landing-steps", type=_int_in(1024, 1 << 20), metavar="N",
                   help="step limit of a near-flat drop's compliant landing, N in [1024, 1048576] (default 16384; "
                        "Numerics.landing_steps): raise it when such a drop says its landing ran out of steps")
    p.add_argument("--gauge", type=_gauge, metavar="X_MM[,Y_MM]",
                   help="also read a strain gauge at X_MM from end A (on a plate: and Y_MM across it from its "
                        "centre line, default 0): a beam writes its history (CSV: ms, microstrain, MPa; and a figure, "
                        "gauge_X_MMmm.png), a plate adds it to its gauges (CSV gauges.csv)")
    p.set_defaults(func=cmd_drop)

    p = command("campaign", "a standard drop campaign (ISTA 1A/2A, MIL-STD-810H 516.8-IV, IEC 60068-2-31, "
                            "JESD22-B111): peak stress (MPa) of every drop, the worst drop, CSV table and bar chart")
    p.add_argument("--standard", required=True, choices=tuple(STANDARDS), help="the standard")
    p.add_argument("--mass", type=_float_in(0.0, 1e4, "kg", lo_open=True), metavar="KG",
                   help="packaged mass for mass-dependent heights, kg (default: the housing's)")
    p.add_argument("--height", type=_float_in(0.0, 1e3, "m", lo_open=True), metavar="M",
                   help="free-fall height where the standard leaves it open, m (IEC: default 1.0)")
    p.add_argument("--allowable-microstrain", type=_microstrain, metavar="UE",
                   help="the board's strain limit in microstrain (your part's or supplier's figure; no default): "
                        "each drop is marked ok or OVER, the chart shows peak strain against it")
    modes(p, cap=True)
    impacts(p)
    p.set_defaults(func=cmd_campaign)

    p = command("sensitivity", "d(peak)/d(field) with units and the elasticity (%% per %%) of the peak for every "
                               "scene field, largest first; CSV table and tornado chart")
    p.add_argument("--quantity", default="stress", choices=list(QUANTITIES), help="which peak (default stress)")
    modes(p, cap=True)
    p.set_defaults(func=cmd_sensitivity)

    p = command("optimize", "place the board (centre in mm, angle in deg) to minimise the peak stress (MPa) over a "
                            "set of drops; CSV history")
    p.add_argument("--orientations", type=_degrees_list, metavar="DEG",
                   help="drop angles in degrees: 'low:high:count' or 'a,b,c' (default 15:75:7; with --mounts the "
                        "scene's own drop)")
    p.add_argument("--heights", type=_heights, metavar="M", help="drop heights in m, 'h1,h2' (default: the scene's)")
    p.add_argument("--tilts", type=_degrees_list, metavar="DEG",
                   help="a box housing's tilt out of the plane of motion for each orientation, deg, one per "
                        "orientation: 'a,b,c' or 'low:high:count' (default: the scene's tilt)")
    p.add_argument("--objective", default="mean", choices=["mean", "max", "cvar"],
                   help="risk over the drops (default mean)")
    p.add_argument("--alpha", type=_float_in(0.0, 0.999, "(CVaR level)"), default=0.9,
                   help="CVaR level in [0, 0.999] (default 0.9)")
    p.add_argument("--steps", type=_int_at_least(1), default=100, help="optimiser steps (default 100)")
    p.add_argument("--starts", type=_int_at_least(1), default=4, help="optimiser starts (default 4)")
    p.add_argument("--margin", type=_float_in(0.0, 1e4, "mm"), default=0.0, metavar="MM",
                   help="clearance between the board's ends and the housing's edges, mm (default 0)")
    p.add_argument("--region", type=_region, metavar="C1LO,C2LO,C1HI,C2HI",
                   help="keep the board's centre in this box, mm along the housing's width (c1) and height (c2) "
                        "from its centre G, e.g. -10,-5,10,5 (default: anywhere the board fits)")
    p.add_argument("--max-angle", type=_float_in(0.0, 90.0, "deg"), metavar="DEG",
                   help="largest tilt of the board from the housing's width, deg in [0, 90] (0: level; default: "
                        "as far as it fits)")
    p.add_argument("--mounts", action="store_true",
                   help="move a plate's screws instead of the board (bd.optimize_mounts: each anywhere its disc fits "
                        "on the plate), minimising the peak strain (microstrain) or, with --gauge, that gauge's")
    p.add_argument("--min-spacing", type=_float_in(0.0, 1e4, "mm"), default=0.0, metavar="MM",
                   help="with --mounts: least distance between screws, mm (default 0)")
    p.add_argument("--gauge", type=_gauge, metavar="X_MM[,Y_MM]",
                   help="with --mounts: minimise the strain this gauge reads (mm from end A and across from the "
                        "centre line) instead of the peak over the plate")
    modes(p, "8")
    p.set_defaults(func=cmd_optimize)

    p = command("montecarlo", "random drops: peak stress (MPa) and strain (microstrain) statistics, P(strain > "
                              "limit) with a 95 %% interval; CSV of every drop, polar and exceedance figures",
                "random drops of the scene: the orientation, and with the options below the height and the contact "
                "duration, drawn uniformly over ranges (every other field as in the scene); peak stress (MPa) and "
                "strain (microstrain) statistics, P(strain > limit) with a 95 %% interval; CSV of every drop, polar "
                "and exceedance figures")
    p.add_argument("-n", type=_int_at_least(1), default=2000,
                   help="number of drops (default 2000). Near-flat drops (about 6 %% of uniform orientations) take "
                        "the compliant landing's path, about 0.005 s each on a beam and 0.05 s on a plate (2 cores, after "
                        "compiling; where only the orientation varies, a table over orientation serves them); with "
                        "--contact-model rigid every "
                        "drop takes the first strike's fast path (millions of drops/s), which misses their peaks")
    p.add_argument("--max-landings", type=_int_at_least(0), default=4000, metavar="K",
                   help="refuse a run with more than K near-flat drops (default 4000: about 20 s on a beam, 3 min on "
                        "a plate)")
    p.add_argument("--allowable-microstrain", type=_microstrain, metavar="UE",
                   help="the board's strain limit in microstrain, required: no one figure holds for every board "
                        "(limits depend on the board, its parts and joints, and the strain rate), so give your part's "
                        "or supplier's")
    p.add_argument("--orientations", type=_range("deg", -3600.0, 3600.0), metavar="LO:HI",
                   help="drop orientations drawn uniformly on [LO, HI] deg, or one value (default 0:360)")
    p.add_argument("--face-bias", type=_face_bias, metavar="SHARE:SPREAD",
                   help="flat devices land near a face more often than uniformly: SHARE in [0, 1] of the drops land "
                        "near one of the four faces (0, 90, 180, 270 deg plus a normal deviation of SPREAD deg), the "
                        "rest uniformly over 360 deg; e.g. 0.3:2 (instead of --orientations)")
    p.add_argument("--heights", type=_range("m", 0.0, 1e3, lo_open=True), metavar="LO:HI",
                   help="drop heights drawn uniformly on [LO, HI] m, or one value (default: the scene's)")
    p.add_argument("--durations", type=_range("ms", 0.0, 100.0, lo_open=True), metavar="LO:HI",
                   help="contact (half-sine) durations drawn uniformly on [LO, HI] ms, or one value (default: the "
                        "scene's)")
    p.add_argument("--tilts", type=_range("deg", -90.0, 90.0), metavar="LO:HI",
                   help="a box housing's tilt out of the plane of motion, drawn on [LO, HI] deg with its sine uniform, "
                        "or one value (default for a box -90:90: with --orientations 0:360, attitudes uniform on the "
                        "rotation group)")
    p.add_argument("--seed", type=_int_at_least(0), default=0, help="random seed (default 0)")
    p.add_argument("--batch-size", type=_int_at_least(1), metavar="N", help="drops per compiled chunk")
    modes(p, "chosen from the scene")
    impacts(p)
    p.set_defaults(func=cmd_montecarlo)

    p = sub.add_parser("scenes", help="the embedded scenes: name, board and what each models; or one as TOML text",
                       description="The scenes shipped in the package, for --scene NAME; 'beamdrop scenes NAME' "
                                   "prints one as TOML text, a start for a scene file of your own "
                                   "('beamdrop scenes phone > my-phone.toml').")
    p.add_argument("name", nargs="?", metavar="NAME", choices=embedded_scenes(),
                   help=f"print this scene's TOML text: {scenes}")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    # Reads files only: nothing is compiled or written.
    p.set_defaults(func=cmd_scenes, no_plots=True, no_cache=True, float32=False)

    p = command("bench", "speed against accuracy (peak-stress error, seconds per drop) for every method against "
                         "NumPy and SciPy peers, JSON table and chart; or --latency: time to first answer, printed "
                         "(no files)")
    level = p.add_mutually_exclusive_group()
    level.add_argument("--quick", action="store_true", help="the quick set (about 5 minutes on 2 cores)")
    level.add_argument("--tiny", action="store_true", help="a smoke test of every part (about a minute on 2 cores)")
    level.add_argument("--latency", action="store_true",
                       help="import, first drop and first gradient in fresh processes against a bare JAX process; "
                            "prints a table (with --json, an object) and writes no files")
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
    if args.command == "montecarlo" and args.allowable_microstrain is None:  # checked after a misspelt option
        parser.commands[args.command].error(
            "--allowable-microstrain UE is required: the board's strain limit in microstrain (your part's or "
            "supplier's; there is no default)")
    if getattr(args, "face_bias", None) and args.orientations is not None:
        parser.commands[args.command].error("--face-bias draws the orientation over the whole circle: give it or "
                                            "--orientations, not both")
    if args.command == "optimize" and not args.mounts and (args.gauge is not None or args.min_spacing):
        parser.commands[args.command].error("--gauge and --min-spacing go with --mounts (moving a plate's screws); "
                                            "placing the board takes --region and --max-angle")
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
    if hasattr(args, "scene"):
        _scene(args)  # a wrong scene file, or an option it cannot take, is reported before any word on compiling
    if args.no_cache or os.environ.get("BEAMDROP_NO_CACHE", "") not in ("", "0"):
        _say_when_compiling("beamdrop: compiling (the compilation cache is off)")
        return None
    cache = _cache_dir()
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError:
        _say_when_compiling(f"beamdrop: compiling (cannot create the cache folder {cache})")
        return None
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    settings = {k: v for k, v in sorted(vars(args).items()) if k not in ("out", "json", "func", "no_plots")}
    key = hashlib.sha1(repr((_version(), jax.__version__, settings)).encode()).hexdigest()[:16]
    stamp = cache / f"compiled-{key}"
    if not stamp.exists():
        _say_when_compiling(f"beamdrop: compiling (first run with these settings; kept in {cache} for later runs)")
    return stamp


_TRACED = "/jax/core/compile/jaxpr_trace_duration"


def _say_when_compiling(line: str) -> None:
    """Print `line` once, when the command's first program has been traced (before XLA compiles it): an input
    refused before then (most are checked eagerly) is reported without a word on compiling. The listener goes with
    the command (`_end_compiling_notice`)."""
    import jax

    def listener(event, duration, **kwargs):
        if event == _TRACED and _notice:
            print(_notice.pop(), file=sys.stderr, flush=True)

    _notice[:] = [line]
    jax.monitoring.register_event_duration_secs_listener(listener)
    _notice_listener[:] = [listener]


_notice: list[str] = []  # the line still to print
_notice_listener: list = []


def _end_compiling_notice() -> None:
    import jax

    _notice.clear()
    while _notice_listener:
        jax.monitoring.unregister_event_duration_listener(_notice_listener.pop())


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
    from .._common.compile import preload_programs

    return names, preload_programs(_cache_dir() / "programs", names)


def _bound_cache(stamp: Path) -> None:
    """Mark the run's settings as compiled; after a run that compiled, remove the cache's least recently used
    programs beyond `CACHE_MAX_BYTES` (the settings' stamps stay)."""
    if not stamp.exists():
        from .._common.compile import prune_folder

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

def _interrupt_once(signum, frame):
    """SIGINT: a KeyboardInterrupt, once; later ones are ignored so that the cleanup it starts runs whole."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def _redeliver_lost_interrupts(hook):
    """A `sys.unraisablehook`: a KeyboardInterrupt that Ctrl-C raised inside a callback whose exceptions Python only
    prints (JAX's garbage-collection hook) would be a traceback on stderr and a lost interrupt; it is delivered
    again instead, to the command's own code. Everything else goes to `hook`."""

    def handle(info):
        if info.exc_type is None or not issubclass(info.exc_type, KeyboardInterrupt):
            return hook(info)
        signal.signal(signal.SIGINT, _interrupt_once)
        threading.Timer(0.02, signal.raise_signal, (signal.SIGINT,)).start()

    return handle


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
        unraisable, sys.unraisablehook = sys.unraisablehook, _redeliver_lost_interrupts(sys.unraisablehook)
    try:
        return _main(argv)
    except KeyboardInterrupt:
        if _active["claim"].acquire(blocking=False):  # else the watchdog (`run`) has said it and ends the process
            print(_interrupted_line(), file=sys.stderr)
        return INTERRUPTED
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
            sys.unraisablehook = unraisable


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
            from .._common.compile import keep_programs, quick_programs

            keeping = keep_programs(_cache_dir() / "programs") if stamp is not None else contextlib.nullcontext([])
            with keeping as used, _figures_to_files(), quick_programs(args.command in QUICK_COMMANDS):
                args.func(args, output)
        except (ValueError, FileNotFoundError) as err:
            print(f"beamdrop {args.command}: error: {err}", file=sys.stderr)
            return 2
    finally:
        if preloading is not None:  # never exit while it runs in XLA
            preloading.join()
        if "jax" in sys.modules:
            _end_compiling_notice()
    if stamp is not None:
        _bound_cache(stamp)
        if used and used != listed:
            with contextlib.suppress(OSError):
                record.parent.mkdir(parents=True, exist_ok=True)
                record.write_text(json.dumps(used))
    if args.json:
        from .._common.report import plain

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
        if "beamdrop_jax._common.report" in sys.modules:  # else no file is being written
            sys.modules["beamdrop_jax._common.report"].abandon_writes()
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
