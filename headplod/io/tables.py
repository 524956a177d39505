"""The CSV tables of a dataset folder: ``times.csv`` and ``truth.csv``.

:func:`read_times`, :func:`write_times` (``frame,t[,t_right]``, s) and
:func:`read_truth`, :func:`write_truth` (the true position, mm, and axes rows
Ξ, Ψ, V per frame).
"""

from __future__ import annotations

import csv
import math
import operator
import re
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ._storage import AXES_TOL_READ, AXES_TOL_WRITE, _Ctx, _check_axes

# --------------------------------------------------------------------------
# constants
# --------------------------------------------------------------------------

#: Columns of truth.csv, in order.
TRUTH_COLUMNS = (
    "frame", "x", "y", "z",
    "xi_x", "xi_y", "xi_z",
    "psi_x", "psi_y", "psi_z",
    "v_x", "v_y", "v_z",
)
_TIMES_COLUMNS = ("frame", "t", "t_right")


def _read_csv_rows(path: str | Path, headers: Iterable[tuple[str, ...]], hint: str):
    """Yield (line number, header, fields) of a small CSV file after checks."""
    ctx = _Ctx.file(path)
    p = Path(path)
    if not p.is_file():
        raise ctx.error("file not found" if not p.exists() else "is not a file", hint)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ctx.error(f"is not UTF-8 text ({exc.reason} at byte {exc.start})", hint) from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()]
    if not lines:
        raise ctx.error("file is empty, expected a header line", hint)
    header_line, header_text = lines[0]
    header = tuple(h.strip() for h in next(csv.reader([header_text])))
    allowed = list(headers)
    if header not in allowed:
        expected = " or ".join(repr(",".join(h)) for h in allowed)
        raise ctx.error(f"header is {','.join(header)!r}, expected {expected}", hint)
    rows = []
    for lineno, line in lines[1:]:
        fields = [f.strip() for f in next(csv.reader([line]))]
        rows.append((lineno, fields))
    return ctx, header, rows


def _csv_frame(ctx: _Ctx, lineno: int, text: str) -> int:
    if not re.fullmatch(r"[0-9]+", text):
        raise ctx.error(f"line {lineno}: frame is {text!r}, expected a non-negative integer")
    return int(text)


def _csv_float(ctx: _Ctx, lineno: int, column: str, text: str, unit: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ctx.error(f"line {lineno}: column '{column}' is {text!r}, expected a number ({unit})") from None
    if not math.isfinite(v):
        raise ctx.error(f"line {lineno}: column '{column}' is {text!r}, expected a finite number ({unit})")
    return v


def read_times(path: str | Path) -> dict[int, tuple[float, float | None]]:
    """Read ``times.csv``: ``frame,t[,t_right]``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
        frame index -> ``(t, t_right)``, s: the time of the left image and
        of the right one (``None`` when the column is absent or the cell
        empty, meaning the same as ``t``). Sorted by frame.

    Raises
    ------
    ContractError
        On a missing file, a wrong header, a wrong number of fields, a
        non-integer frame, a non-numeric or non-finite time, or a repeated
        frame.
    """
    hint = "times.csv has the header 'frame,t' or 'frame,t,t_right' and one row per frame, times in s"
    ctx, header, rows = _read_csv_rows(path, [_TIMES_COLUMNS[:2], _TIMES_COLUMNS], hint)
    out: dict[int, tuple[float, float | None]] = {}
    for lineno, f in rows:
        if not (len(f) == len(header) or (len(header) == 3 and len(f) == 2)):
            raise ctx.error(f"line {lineno}: {len(f)} fields, expected {len(header)} ({','.join(header)})", hint)
        frame = _csv_frame(ctx, lineno, f[0])
        if frame in out:
            raise ctx.error(f"line {lineno}: frame {frame} appears twice", "keep one row per frame")
        t = _csv_float(ctx, lineno, "t", f[1], "s")
        t_right = _csv_float(ctx, lineno, "t_right", f[2], "s") if len(f) == 3 and f[2] != "" else None
        out[frame] = (t, t_right)
    return dict(sorted(out.items()))


def write_times(path: str | Path, times: Mapping[int, Any]) -> None:
    """Write ``times.csv``.

    Parameters
    ----------
    path : str or Path
    times : mapping
        frame index -> ``t`` or ``(t, t_right)`` (s; ``t_right`` may be
        ``None``). The ``t_right`` column is written only when some frame has
        one. Floats are written with full (round-trip) precision.
    """
    rows = []
    for frame, v in sorted(times.items()):
        t, t_right = (v, None) if np.ndim(v) == 0 else (tuple(v) + (None,))[:2]
        t = float(t)
        t_right = None if t_right is None else float(t_right)
        if not math.isfinite(t) or (t_right is not None and not math.isfinite(t_right)):
            raise ValueError(f"write_times: frame {frame} has a non-finite time {v!r}")
        rows.append((operator.index(frame), t, t_right))
    with_right = any(r[2] is not None for r in rows)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(_TIMES_COLUMNS if with_right else _TIMES_COLUMNS[:2]) + "\n")
        for frame, t, t_right in rows:
            cells = [str(frame), repr(t)]
            if with_right:
                cells.append("" if t_right is None else repr(t_right))
            fh.write(",".join(cells) + "\n")


def read_truth(path: str | Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Read ``truth.csv``.

    Parameters
    ----------
    path : str or Path
        CSV with header ``frame,x,y,z,xi_x,xi_y,xi_z,psi_x,psi_y,psi_z,v_x,v_y,v_z``.

    Returns
    -------
    dict
        frame index -> ``(position, axes)``: position of P1 in the world
        frame, mm, shape (3,); axes with rows Ξ, Ψ, V in the world frame,
        shape (3, 3). Values as written (not re-orthonormalized). Sorted by
        frame.

    Raises
    ------
    ContractError
        On a missing file, a wrong header or field count, a non-numeric or
        non-finite value, a repeated frame, or axes that are not orthonormal
        (tolerance ``AXES_TOL_READ``) or left-handed.
    """
    hint = "truth.csv has the header " + ",".join(TRUTH_COLUMNS) + " (mm, unit axes rows Ξ, Ψ, V)"
    ctx, header, rows = _read_csv_rows(path, [TRUTH_COLUMNS], hint)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for lineno, f in rows:
        if len(f) != len(TRUTH_COLUMNS):
            raise ctx.error(f"line {lineno}: {len(f)} fields, expected {len(TRUTH_COLUMNS)}", hint)
        frame = _csv_frame(ctx, lineno, f[0])
        if frame in out:
            raise ctx.error(f"line {lineno}: frame {frame} appears twice", "keep one row per frame")
        vals = np.array([_csv_float(ctx, lineno, c, x, "mm" if c in "xyz" else "unit vector")
                         for c, x in zip(TRUTH_COLUMNS[1:], f[1:])])
        axes = vals[3:].reshape(3, 3)
        why = _check_axes(axes, AXES_TOL_READ)
        if why:
            raise ctx.error(f"line {lineno} (frame {frame}): {why}",
                            "write unit vectors Ξ, Ψ, V with at least 6 decimals")
        out[frame] = (vals[:3].copy(), axes.copy())
    return dict(sorted(out.items()))


def write_truth(path: str | Path, rows: Mapping[int, tuple[Any, Any]] | Iterable[tuple[int, Any, Any]]) -> None:
    """Write ``truth.csv``.

    Parameters
    ----------
    path : str or Path
    rows : mapping or iterable
        Either frame -> ``(position, axes)`` (as :func:`read_truth` returns)
        or an iterable of ``(frame, position, axes)``; position (3,) mm,
        axes (3, 3) rows Ξ, Ψ, V in the world frame. Written sorted by frame
        with full (round-trip) precision.

    Raises
    ------
    ValueError
        On wrong shapes, non-finite values, non-orthonormal or left-handed
        axes (tolerance ``AXES_TOL_WRITE``), or a repeated frame.
    """
    items = list(rows.items()) if isinstance(rows, Mapping) else [(r[0], (r[1], r[2])) for r in rows]
    seen = set()
    lines = [",".join(TRUTH_COLUMNS)]
    for frame, (pos, axes) in sorted(items, key=lambda kv: kv[0]):
        frame = operator.index(frame)
        if frame in seen:
            raise ValueError(f"write_truth: frame {frame} appears twice")
        seen.add(frame)
        p = np.asarray(pos, dtype=np.float64).reshape(-1)
        A = np.asarray(axes, dtype=np.float64)
        if p.shape != (3,) or A.shape != (3, 3):
            raise ValueError(f"write_truth: frame {frame}: position shape {p.shape}, axes shape {A.shape}; "
                             "expected (3,) and (3, 3)")
        if not (np.isfinite(p).all() and np.isfinite(A).all()):
            raise ValueError(f"write_truth: frame {frame}: non-finite values")
        why = _check_axes(A, AXES_TOL_WRITE)
        if why:
            raise ValueError(f"write_truth: frame {frame}: {why}")
        lines.append(",".join([str(frame)] + [repr(float(x)) for x in np.concatenate([p, A.reshape(-1)])]))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
