"""The command line's argument types, checks made before computing, output and saved files."""

import argparse
import contextlib
import difflib
import functools
import math
import os
import re
import sys
import threading
from pathlib import Path


# Clattering drops with restitution up to 0.8 come to rest or pivot within 50 impacts (the embedded scenes, every
# orientation). Each pair of impacts is a term of the compiled search (its size and compile time grow as K^2: on 2
# cores K = 3, 20, 50 compile in 6, 14, 54 s and take 0.3, 0.5, 1.3 GB).
MAX_IMPACTS = 50
# --max-modes: a plate's grid grows as modes^3 (its time grid as modes^2); 64 modes take seconds on 2 cores.
MAX_MODES = 64
# What a Monte-Carlo drop costs, measured on `montecarlo -n 2000000` (float64): 113 bytes of memory per drop
# without figures and 240 with them, over 0.5 GB for the process itself; 75 bytes of CSV per drop.
DROP_BYTES, DROP_BYTES_PLOTTED, PROCESS_BYTES, CSV_ROW_BYTES = 120, 250, 600 << 20, 76
QUANTITIES = {"stress": ("MPa", 1e-6), "strain": ("microstrain", 1e6), "deflection": ("mm", 1e3)}


@functools.cache
def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("beamdrop-jax")
    except PackageNotFoundError:
        return "unknown"


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Values that start with a minus and a digit are values, not options: --region -10,-5,10,5 and
        # --orientations -90:90 as well as -3 (no option of the command starts with a digit).
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message):
        # argparse names the choices of a misspelt value; say which one was meant, as misspelt options do.
        choice = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)$", message)
        if choice:
            near = difflib.get_close_matches(choice[1], re.findall(r"'([^']*)'", choice[2]), n=1)
            message += f"; did you mean {near[0]!r}?" if near else ""
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


def _range(unit, lo, hi, lo_open=False):
    """'low:high' -> (low, high), drawn uniformly; 'value' -> (value, value), fixed; in `unit`, within [lo, hi]."""
    number = _float_in(lo, hi, unit, lo_open=lo_open)

    def parse(text):
        parts = text.split(":")
        if len(parts) > 2:
            raise argparse.ArgumentTypeError(f"{text!r}: write 'low:high' (uniform) or one value (fixed), in {unit}")
        try:
            low, high = number(parts[0]), number(parts[-1])
        except argparse.ArgumentTypeError as err:
            raise argparse.ArgumentTypeError(f"{text!r}: {err} (write 'low:high' or one value)") from None
        if low > high:
            raise argparse.ArgumentTypeError(f"{text!r}: low {low:g} is above high {high:g} {unit}")
        return (low, high)

    return parse


def _basis(text):
    """'nx,ny' -> (nx, ny), each an int in `Plate.basis`'s range (`BASIS_LIMITS`)."""
    from .._board.plate import BASIS_LIMITS

    lo, hi = BASIS_LIMITS
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        nx, ny = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: write two whole numbers 'NX,NY', e.g. 20,20") from None
    if not (lo <= nx <= hi and lo <= ny <= hi):
        raise argparse.ArgumentTypeError(f"{text!r}: each of NX, NY must be in [{lo}, {hi}]")
    return nx, ny


def _face_bias(text):
    """'share:spread' -> (share in [0, 1], spread in [0, 45] deg)."""
    parts = text.split(":")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"{text!r}: write 'share:spread_deg', e.g. 0.3:2 (30 % of the drops within "
                                         "a normal spread of 2 deg of a face)")
    try:
        return _float_in(0.0, 1.0, "(share)")(parts[0]), _float_in(0.0, 45.0, "deg")(parts[1])
    except argparse.ArgumentTypeError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {err} (write 'share:spread_deg', e.g. 0.3:2)") from None


def _region(text):
    """'c1lo,c2lo,c1hi,c2hi' in mm -> ((c1lo, c2lo), (c1hi, c2hi)) in m."""
    number = _float_in(-1e4, 1e4, "mm")
    parts = text.split(",")
    if len(parts) != 4:
        raise argparse.ArgumentTypeError(f"{text!r}: write four numbers in mm, 'c1lo,c2lo,c1hi,c2hi' (e.g. "
                                         "-10,-5,10,5)")
    try:
        c1lo, c2lo, c1hi, c2hi = (number(v) for v in parts)
    except argparse.ArgumentTypeError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {err} (write 'c1lo,c2lo,c1hi,c2hi')") from None
    if c1lo > c1hi or c2lo > c2hi:
        raise argparse.ArgumentTypeError(f"{text!r}: each low must be <= its high (c1lo <= c1hi, c2lo <= c2hi)")
    return ((c1lo * 1e-3, c2lo * 1e-3), (c1hi * 1e-3, c2hi * 1e-3))


def _scene_arg(text):
    if not text.strip():  # not the default scene: an unset variable in a script (--scene "$SCENE") would be silent
        from .._scene.file import embedded_scenes

        raise argparse.ArgumentTypeError(f"{text!r} is empty (valid: a scene TOML file, or an embedded scene: "
                                         f"{', '.join(embedded_scenes())})")
    return text


def _heights(text):
    height = _float_in(0.0, 1e3, "m", lo_open=True)  # as montecarlo's and campaign's
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
        from .._common.report import plain, summary_text

        summary = plain(summary)
        self.report.update(summary)
        # For people, one value is a number, not a one-element tuple "(3424.92)".
        self.say(summary_text({k: v[0] if isinstance(v, list) and len(v) == 1 else v for k, v in summary.items()},
                              title))

    def note(self, text):
        self.say(f"  note: {text}")
        self.report.setdefault("notes", []).append(text)


# Positions closer to 0 than this fraction of the board's size are round-off of a symmetric answer, printed 0.
POSITION_RTOL = 1e-6


def _tidy_positions(summary: dict, size_mm: float) -> dict:
    """`summary` with every position in mm (keys ending _x_mm, _y_mm) within `POSITION_RTOL` x `size_mm` of 0
    set to 0: a peak on the centre line computed as -1.5e-08 mm is on the centre line."""
    from .._common.report import plain

    summary = plain(summary)
    tol = POSITION_RTOL * size_mm
    for key, value in summary.items():
        if key.endswith(("_x_mm", "_y_mm")) and isinstance(value, float) and abs(value) < tol:
            summary[key] = 0.0
    return summary


def _cli_note(note: str, numerics) -> str:
    """A library note (which names the Python API's fields) as the command line's user needs it: the option that
    does it, with the field in brackets."""
    n = numerics.max_modes or 16  # unset: the board's own (16 for the beam and the plate)
    if numerics.n_modes is not None:  # --n-modes fixes the count (the check takes half as many): it is the fix
        note = note.replace("raise Numerics.max_modes", f"raise --n-modes (now {numerics.n_modes}; the check "
                                                         f"compares it with half as many)")
    for api, cli in (
        ("`basis = [nx, ny]` in the scene file's [plate], at most 40", "--basis NX,NY, or `basis = [nx, ny]` in the "
                                                                         "scene file's [plate]; at most 40"),
        ("raise Numerics.max_modes", f"raise --max-modes (Numerics.max_modes, {n} here; at most {MAX_MODES})"),
        ("widen the window (Numerics.window, s;", "widen the window with --window MS (Numerics.window;"),
        ("raise Numerics.pulse_modes (modes up to f_k x duration >= 2 by default)",
         "give more modes with --n-modes N (or, from Python, raise Numerics.pulse_modes: modes up to f_k x "
         "duration >= 2 by default)"),
        ("give Contact.duration a physical value", "give the scene file's [contact] duration a physical value"),
        ("raise Numerics.landing_steps (16384 by default)", f"raise --landing-steps (Numerics.landing_steps, {numerics.landing_steps} "
                                         "here)"),
        ('(Numerics(method="diffrax", stretching=True))',
         '(from Python: Numerics(method="diffrax", stretching=True); no command-line option)'),
    ):
        note = note.replace(api, cli)
    return note


def _scene(args):
    import beamdrop_jax as bd

    scene = bd.load_scene(args.scene) if args.scene else bd.Scene.default()
    model = getattr(args, "contact_model", None)
    if model:
        scene = eqx_replace_contact(scene, scene.contact.with_model(model))
    if getattr(args, "basis", None):
        if getattr(scene.board, "basis", None) is None:
            raise ValueError(f"--basis {args.basis[0]},{args.basis[1]} sets a plate's Ritz basis; this scene's board "
                             "is a beam (its modes are exact): leave --basis out")
        import dataclasses

        import equinox as eqx

        scene = eqx.tree_at(lambda s: s.board, scene, dataclasses.replace(scene.board, basis=tuple(args.basis)))
    _check_gauge(getattr(args, "gauge", None), scene)
    return scene


def _check_gauge(gauge, scene) -> None:
    """--gauge X_MM[,Y_MM] against the scene's board: a clear error before anything compiles."""
    if gauge is None:
        return
    import numpy as np

    x, y = gauge
    if not 0 <= x * 1e-3 <= float(scene.board.length):
        raise ValueError(f"--gauge {x:g} mm is off the board: valid [0, {float(scene.board.length) * 1e3:g}] mm from "
                         "end A")
    if not scene.board.SURFACE:
        if y is not None:
            raise ValueError(f"--gauge {x:g},{y:g}: a beam's gauge is X_MM alone (it bends along x only); valid: "
                             "--gauge X_MM")
        return
    try:
        scene.board.check_gauges(np.array([[x, y or 0.0]]) * 1e-3)
    except ValueError as error:
        raise ValueError(f"--gauge {x:g},{y or 0.0:g} (mm): {error}") from None


def eqx_replace_contact(scene, contact):
    import equinox as eqx

    return eqx.tree_at(lambda s: s.contact, scene, contact)


def _gauge(text):
    """--gauge X_MM or X_MM,Y_MM: where a gauge reads, mm from end A (and across a plate from its centre line)."""
    parts = [part.strip() for part in str(text).split(",")]
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or not all(math.isfinite(v) and abs(v) <= 1e5 for v in values):
        raise argparse.ArgumentTypeError(f"{text!r} is not a number or a pair of numbers; valid: X_MM or X_MM,Y_MM "
                                         "(mm, finite), e.g. 66 or 30,20")
    return values[0], (values[1] if len(values) == 2 else None)


def _scene_name(args) -> str:
    return f"scene {args.scene}" if args.scene else "the default scene"


def _writes_files(args) -> bool:
    """Whether the command writes into --out (created only then: `bench --latency` prints its table only)."""
    if getattr(args, "latency", False):
        return False
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


# The command running now and the files it has completed: what an interrupt's message names.
_active = {"command": None, "files": [], "claim": threading.Lock()}


def _save(output, fig, name, args):
    import matplotlib.pyplot as plt

    from .._common.report import atomic_open

    path = Path(args.out) / name
    try:
        with atomic_open(path, "wb") as f:
            fig.savefig(f, format=path.suffix[1:], dpi=120)
    finally:
        plt.close(fig)
    output.wrote(path)


def _numerics(args, **overrides):
    import beamdrop_jax as bd

    kw = {k: getattr(args, k) for k in ("method", "solver", "n_modes", "max_modes", "max_impacts", "landing_steps")
          if getattr(args, k, None)}
    if getattr(args, "window", None):
        kw["window"] = args.window * 1e-3  # ms on the command line
    kw.update(overrides)
    return bd.Numerics(**kw)


# ---------------------------------------------------------------------------------------------------------------
# Commands.
