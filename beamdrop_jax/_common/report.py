"""Summaries of results as plain dicts whose keys carry their units (`peak_stress_MPa`), and their text form.

One summary serves three readers: `repr` in a REPL or notebook, the CLI's table, and the CLI's `--json`.
"""

import contextlib
import csv
import math
import os
import secrets
import threading
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


# Temporary files being written now: the CLI's interrupt watchdog removes them from another thread while the
# writer may be stuck in compiled code, so removing them and renaming one into place take turns.
_scratch_lock = threading.Lock()
_scratch: set = set()


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open `path` for writing such that it appears only complete: the file is written under a hidden temporary
    name in the same folder (`.NAME.PID-RANDOM.part`, same file system, so the final rename is atomic) and renamed
    to `path` when the block ends; a block that raises or is interrupted removes it. A run that stops half way
    (Ctrl-C, an error, a full disk) leaves no partial file under a finished-looking name."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scratch = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(3)}.part")
    created = False
    try:
        with _scratch_lock:
            # "x": create it new, with the permissions (umask) the final file would have had.
            f = open(scratch, mode.replace("w", "x"), **kwargs)
            created = True
            _scratch.add(scratch)
        with f:
            yield f
        with _scratch_lock:
            os.replace(scratch, path)
            _scratch.discard(scratch)
    except BaseException as err:
        if created or not isinstance(err, FileExistsError):  # another writer's file is not ours to remove
            with _scratch_lock:
                with contextlib.suppress(OSError):
                    scratch.unlink()
                _scratch.discard(scratch)
        raise


def abandon_writes() -> None:
    """Remove the temporary files being written now and keep them from being renamed into place: for a process
    about to end (the CLI's interrupt watchdog; the lock is never released)."""
    _scratch_lock.acquire()
    for scratch in list(_scratch):
        with contextlib.suppress(OSError):
            scratch.unlink()


def write_csv(rows: list[dict], path) -> Path:
    """Write dict rows (same keys) as CSV (creating its folder, atomically: `atomic_open`); returns the path."""
    path = Path(path)
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else [])
        writer.writeheader()
        writer.writerows([plain(r) for r in rows])
    return path


# A table with more rows than this shows a progress bar while it is written (a few seconds on 2 cores).
PROGRESS_ROWS = 500_000
_BLOCK_ROWS = 65_536


def _csv_text(values) -> list[str]:
    """One column's CSV fields, as `csv` writes `plain` values: floats by `repr` (the shortest text that reads back
    as the same float), NaN and inf empty (`plain`'s None), strings quoted where they hold `,`, `"` or a line break."""
    arr = np.asarray(values)
    if arr.dtype.kind == "f":
        text = list(map(repr, arr.tolist()))
        for i in np.flatnonzero(~np.isfinite(arr)).tolist():
            text[i] = ""
        return text
    if arr.dtype.kind in "biu":
        return list(map(str, arr.tolist()))
    text = ["" if v is None else str(v) for v in arr.tolist()]
    return [f'"{v.replace(chr(34), chr(34) * 2)}"' if any(c in v for c in ',"\r\n') else v for v in text]


def write_csv_columns(columns: dict, path, progress: bool = False, desc: str | None = None) -> Path:
    """Write equal-length columns (name -> array or list of str) as CSV, the same text as `write_csv` of the rows,
    formatted in blocks of rows (8x faster than a dict per row, and memory for one block's text at a time), with
    a progress bar on stderr for tables over `PROGRESS_ROWS` rows; atomically (`atomic_open`). Returns the path."""
    from tqdm import tqdm

    path = Path(path)
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 0
    if any(len(v) != n for v in columns.values()):
        raise ValueError(f"write_csv_columns: columns of different lengths {[len(v) for v in columns.values()]}")
    with atomic_open(path, "w", newline="") as f, tqdm(
        total=n, desc=desc or f"writing {path.name}", unit="rows", unit_scale=True, leave=False,
        disable=not progress or n <= PROGRESS_ROWS,
    ) as bar:
        f.write(",".join(_csv_text(names)) + "\r\n")  # csv's default (excel) dialect ends lines with \r\n
        for start in range(0, n, _BLOCK_ROWS):
            stop = min(start + _BLOCK_ROWS, n)
            fields = [_csv_text(v[start:stop]) for v in columns.values()]
            if len(fields) == 1:  # csv quotes a row's only field when empty (else the row is a blank line)
                fields = [[v or '""' for v in fields[0]]]
            f.write("\r\n".join(map(",".join, zip(*fields))) + "\r\n")
            bar.update(stop - start)
    return path
