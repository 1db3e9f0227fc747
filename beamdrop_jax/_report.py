"""Summaries of results as plain dicts whose keys carry their units (`peak_stress_MPa`), and their text form.

One summary serves three readers: `repr` in a REPL or notebook, the CLI's table, and the CLI's `--json`.
"""

import contextlib
import csv
import math
import os
import secrets
from pathlib import Path

import numpy as np

# Longest first, so that "_m_per_s" wins over "_s".
_UNITS = {
    "_microstrain": "microstrain",
    "_m_per_s": "m/s",
    "_rad_per_s": "rad/s",
    "_MPa": "MPa",
    "_Pa": "Pa",
    "_Ns": "N s",
    "_Hz": "Hz",
    "_deg": "deg",
    "_mm": "mm",
    "_ms": "ms",
    "_kg": "kg",
    "_J": "J",
    "_m": "m",
    "_s": "s",
}


def label(key: str) -> str:
    """'peak_stress_MPa' -> 'peak stress (MPa)'."""
    for suffix, unit in sorted(_UNITS.items(), key=lambda kv: -len(kv[0])):
        if key.endswith(suffix):
            return f"{key[: -len(suffix)].replace('_', ' ')} ({unit})"
    return key.replace("_", " ")


def plain(value):
    """JSON-ready Python values: arrays to lists of floats, NaN and inf to None."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, str) or value is None:
        return value
    arr = np.asarray(value)
    if arr.ndim:
        return [plain(v) for v in arr.tolist()]
    if arr.dtype.kind == "b":
        return bool(arr)
    if arr.dtype.kind in "iu":
        return int(arr)
    x = float(arr)
    return x if math.isfinite(x) else None


def _fmt(value) -> str:
    if isinstance(value, bool):
        return "yes" if value else "NO"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list) and not value:
        return "none"
    if isinstance(value, list):
        return "(" + ", ".join(_fmt(v) for v in value) + ")"
    if value is None:
        return "n/a"
    return str(value)


def summary_text(summary: dict, title: str = "") -> str:
    """Aligned 'label  value' lines of a summary, under an optional title."""
    summary = plain(summary)
    labels = {k: label(k) for k in summary}
    width = max(map(len, labels.values()), default=0)
    lines = [title] if title else []
    lines += [f"  {labels[k]:<{width}}  {_fmt(v)}" for k, v in summary.items()]
    return "\n".join(lines)


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open `path` for writing such that it appears only complete: the file is written under a hidden temporary
    name in the same folder (`.NAME.PID-RANDOM.part`, same file system, so the final rename is atomic) and renamed
    to `path` when the block ends; a block that raises or is interrupted removes it. A run that stops half way
    (Ctrl-C, an error, a full disk) leaves no partial file under a finished-looking name."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scratch = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(3)}.part")
    # "x": create it new, with the permissions (umask) the final file would have had.
    f = open(scratch, mode.replace("w", "x"), **kwargs)
    try:
        with f:
            yield f
        os.replace(scratch, path)
    except BaseException:
        with contextlib.suppress(OSError):
            scratch.unlink()
        raise


def write_csv(rows: list[dict], path) -> Path:
    """Write dict rows (same keys) as CSV (creating its folder, atomically: `atomic_open`); returns the path."""
    path = Path(path)
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else [])
        writer.writeheader()
        writer.writerows([plain(r) for r in rows])
    return path
