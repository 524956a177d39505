"""The CSV tables of a dataset folder: ``times.csv``, ``truth.csv`` and ``gaze_truth.csv``.

:func:`read_times`, :func:`write_times` (``frame,t[,t_right]``, s),
:func:`read_truth`, :func:`write_truth` (the true position, mm, and axes rows
Ξ, Ψ, V per frame) and :func:`read_gaze_truth`, :func:`write_gaze_truth`
(where the viewer really looks: the eyes' offset in the head, deg, the gaze
direction and its point on the screen, px). The gaze truth is for benches:
the tracker never reads it.
"""

from __future__ import annotations

import csv
import math
import operator
import re
from pathlib import Path
from typing import Any, Iterable, Mapping, NamedTuple

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
#: Columns of gaze_truth.csv, in order.
GAZE_TRUTH_COLUMNS = (
    "frame", "eye_h_deg", "eye_v_deg",
    "gaze_x", "gaze_y", "gaze_z",
    "gaze_px_x", "gaze_px_y",
)
#: Tolerance on the unit length of a gaze direction read from gaze_truth.csv (6 decimals give ~1e-6), and of
#: one handed to :func:`write_gaze_truth` (full precision).
GAZE_UNIT_TOL_READ = 1e-4
GAZE_UNIT_TOL_WRITE = 1e-6


class GazeTruth(NamedTuple):
    """One frame of ``gaze_truth.csv``.

    eye_in_head_deg : (2,) float, deg: the eyes' rotation in the head, horizontal (positive to the wearer's
        right, -Ξ) and vertical (positive up, Ψ); the gaze's contract angles in the true head frame are
        θ = -horizontal, φ = vertical.
    direction : (3,) float, unit vector in the world frame: the gaze, from P1.
    screen_px : (2,) float, screen px: where the gaze ray meets the screen plane (possibly outside the screen);
        NaN where it meets it nowhere in front of the head.
    """

    eye_in_head_deg: np.ndarray
    direction: np.ndarray
    screen_px: np.ndarray


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


def read_gaze_truth(path: str | Path) -> dict[int, GazeTruth]:
    """Read ``gaze_truth.csv``: ``frame,eye_h_deg,eye_v_deg,gaze_x,gaze_y,gaze_z,gaze_px_x,gaze_px_y``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
        frame index -> :class:`GazeTruth` (the pixel NaN where both pixel cells are empty). Sorted by frame.

    Raises
    ------
    ContractError
        On a missing file, a wrong header or field count, a non-numeric or non-finite value, one pixel cell
        empty and the other not, a repeated frame, or a direction that is not a unit vector (tolerance
        ``GAZE_UNIT_TOL_READ``).
    """
    hint = ("gaze_truth.csv has the header " + ",".join(GAZE_TRUTH_COLUMNS)
            + " (deg, a unit gaze direction, screen px or two empty cells)")
    ctx, header, rows = _read_csv_rows(path, [GAZE_TRUTH_COLUMNS], hint)
    out: dict[int, GazeTruth] = {}
    for lineno, f in rows:
        if len(f) != len(GAZE_TRUTH_COLUMNS):
            raise ctx.error(f"line {lineno}: {len(f)} fields, expected {len(GAZE_TRUTH_COLUMNS)}", hint)
        frame = _csv_frame(ctx, lineno, f[0])
        if frame in out:
            raise ctx.error(f"line {lineno}: frame {frame} appears twice", "keep one row per frame")
        eye = np.array([_csv_float(ctx, lineno, c, x, "deg") for c, x in zip(GAZE_TRUTH_COLUMNS[1:3], f[1:3])])
        d = np.array([_csv_float(ctx, lineno, c, x, "unit vector") for c, x in zip(GAZE_TRUTH_COLUMNS[3:6], f[3:6])])
        if abs(float(np.linalg.norm(d)) - 1.0) > GAZE_UNIT_TOL_READ:
            raise ctx.error(f"line {lineno} (frame {frame}): the gaze direction has length {np.linalg.norm(d):.6g}, "
                            "expected 1", "write a unit vector with at least 6 decimals")
        cells = f[6:8]
        if cells == ["", ""]:
            px = np.full(2, np.nan)
        elif "" in cells:
            raise ctx.error(f"line {lineno}: one of gaze_px_x, gaze_px_y is empty and the other is not",
                            "leave both empty when the gaze misses the screen plane")
        else:
            px = np.array([_csv_float(ctx, lineno, c, x, "px") for c, x in zip(GAZE_TRUTH_COLUMNS[6:], cells)])
        out[frame] = GazeTruth(eye, d, px)
    return dict(sorted(out.items()))


def write_gaze_truth(path: str | Path, rows: Mapping[int, Any]) -> None:
    """Write ``gaze_truth.csv``.

    Parameters
    ----------
    path : str or Path
    rows : mapping
        frame -> :class:`GazeTruth` or ``(eye_in_head_deg (2,) deg, direction (3,) world, screen_px (2,) px)``;
        the direction a unit vector (within ``GAZE_UNIT_TOL_WRITE``: a wrong vector is refused, not
        normalized); a NaN pixel is written as two empty cells. Written sorted by frame with full
        (round-trip) precision.

    Raises
    ------
    ValueError
        On wrong shapes, non-finite angles or directions, a direction not of unit length, one pixel
        coordinate NaN and the other not, or a negative frame.
    """
    lines = [",".join(GAZE_TRUTH_COLUMNS)]
    for frame, row in sorted(rows.items(), key=lambda kv: kv[0]):
        frame = operator.index(frame)
        if frame < 0:
            raise ValueError(f"write_gaze_truth: frame {frame} is negative")
        eye, d, px = (np.asarray(v, dtype=np.float64).reshape(-1) for v in row)
        if eye.shape != (2,) or d.shape != (3,) or px.shape != (2,):
            raise ValueError(f"write_gaze_truth: frame {frame}: shapes {eye.shape}, {d.shape}, {px.shape}; "
                             "expected (2,), (3,) and (2,)")
        if not (np.isfinite(eye).all() and np.isfinite(d).all()):
            raise ValueError(f"write_gaze_truth: frame {frame}: non-finite angles or direction")
        if abs(float(np.linalg.norm(d)) - 1.0) > GAZE_UNIT_TOL_WRITE:
            raise ValueError(f"write_gaze_truth: frame {frame}: the direction has length {np.linalg.norm(d):.9g}, "
                             "expected 1")
        missing = np.isnan(px)
        if (missing.any() and not missing.all()) or np.isinf(px).any():
            raise ValueError(f"write_gaze_truth: frame {frame}: the pixel {px.tolist()} must be finite or all NaN")
        cells = [repr(float(x)) for x in np.concatenate([eye, d])]
        cells += ["", ""] if missing.all() else [repr(float(x)) for x in px]
        lines.append(",".join([str(frame)] + cells))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
