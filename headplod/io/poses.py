"""Pose records: JSON Lines, one object per frame, in frame order.

:func:`pose_record` builds and validates one record, :class:`PoseWriter`
writes them (a file or standard output), :func:`read_poses` reads and
validates a file of them.
"""

from __future__ import annotations

import json
import math
import operator
import os
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .files import refuse_special
from ._storage import AXES_TOL_READ, AXES_TOL_WRITE, ProgressiveOutput, _Ctx, _check_axes
from ..tol import tol

# --------------------------------------------------------------------------
# constants
# --------------------------------------------------------------------------

#: Keys of a pose record, in the contract's order.
POSE_KEYS = ("frame", "t", "ok", "position", "axes", "cov", "reason")


def _jsonable(value: Any, key: str) -> Any:
    """Convert numpy and containers to JSON-native values; NaN/inf -> None."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist(), key)
    if isinstance(value, (list, tuple)):
        return [_jsonable(v, key) for v in value]
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ValueError(f"pose record key {key!r}: mapping key {k!r} is not a str")
            out[k] = _jsonable(v, key)
        return out
    if isinstance(value, Path):
        return str(value)
    raise ValueError(f"pose record key {key!r}: {type(value).__name__} is not JSON-serializable")


def _as_float_array(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"pose record: {name} is not numeric: {value!r}") from None
    if a.shape != shape:
        if name == "position" and a.size == 3:
            a = a.reshape(3)
        else:
            raise ValueError(f"pose record: {name} has shape {a.shape}, expected {shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"pose record: {name} has NaN or inf: {a.tolist()}")
    return a


def _build_record(frame, t, ok, position, axes, cov, reason, extra, axes_tol) -> dict:
    if isinstance(frame, (bool, np.bool_)):
        raise ValueError(f"pose record: frame is {frame!r}, expected a non-negative int")
    try:
        frame = operator.index(frame)
    except TypeError:
        raise ValueError(f"pose record: frame is {frame!r}, expected a non-negative int") from None
    if frame < 0:
        raise ValueError(f"pose record: frame is {frame}, expected a non-negative int")
    if isinstance(t, (bool, np.bool_)):
        raise ValueError(f"pose record: t is {t!r}, expected a finite time in s")
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise ValueError(f"pose record: t is {t!r}, expected a finite time in s") from None
    if not math.isfinite(t):
        raise ValueError(f"pose record: t is {t}, expected a finite time in s")
    if not isinstance(ok, (bool, np.bool_)):
        raise ValueError(f"pose record: ok is {ok!r}, expected True or False")
    ok = bool(ok)
    if ok:
        if position is None or axes is None or cov is None:
            missing = [n for n, v in (("position", position), ("axes", axes), ("cov", cov)) if v is None]
            raise ValueError(f"pose record: ok=True needs position, axes and cov; missing {missing}")
        p = _as_float_array(position, "position", (3,))
        A = _as_float_array(axes, "axes", (3, 3))
        why = _check_axes(A, axes_tol)
        if why:
            raise ValueError(f"pose record: {why}")
        C = _as_float_array(cov, "cov", (2, 2))
        if abs(C[0, 1] - C[1, 0]) > tol.small * max(1.0, float(np.abs(C).max())):
            raise ValueError(f"pose record: cov is not symmetric: {C.tolist()}")
        if not (C[0, 0] > 0 and C[1, 1] > 0 and np.linalg.det(C) > 0):
            raise ValueError(f"pose record: cov is not positive definite: {C.tolist()} (deg²)")
        if reason is not None and not isinstance(reason, str):
            raise ValueError(f"pose record: reason is {reason!r}, expected None or a str")
        pos_out, axes_out, cov_out = p.tolist(), A.tolist(), C.tolist()
    else:
        given = [n for n, v in (("position", position), ("axes", axes), ("cov", cov)) if v is not None]
        if given:
            raise ValueError(
                f"pose record: ok=False must carry no pose, but {given} given; "
                "put diagnostic values in extra keys"
            )
        if not isinstance(reason, str) or not reason.strip():
            raise ValueError(
                f"pose record: ok=False needs a non-empty reason a person can act on, got {reason!r}"
            )
        pos_out = axes_out = cov_out = None
    rec = {
        "frame": frame,
        "t": t,
        "ok": ok,
        "position": pos_out,
        "axes": axes_out,
        "cov": cov_out,
        "reason": reason,
    }
    for k, v in extra.items():
        if k in rec:
            raise ValueError(f"pose record: extra key {k!r} clashes with a standard key")
        rec[k] = _jsonable(v, k)
    return rec


def pose_record(frame: int, t: float, ok: bool, position: Any = None, axes: Any = None,
                cov: Any = None, reason: str | None = None, **extra: Any) -> dict:
    """Build one pose record, JSON-ready, in the contract's key order.

    Parameters
    ----------
    frame : int
        Frame index (>= 0).
    t : float
        Frame time, s (finite).
    ok : bool
        Whether the record carries a pose.
    position : array_like, shape (3,), optional
        P1 in the world frame, mm. Required when ``ok``.
    axes : array_like, shape (3, 3), optional
        Rows Ξ, Ψ, V in the world frame; orthonormal and right-handed
        within ``AXES_TOL_WRITE``. Required when ``ok``.
    cov : array_like, shape (2, 2), optional
        Covariance of (φ, θ), deg², symmetric positive definite. Required
        when ``ok``.
    reason : str, optional
        Required and non-empty when not ``ok`` (something a person can act
        on); may be ``None`` or a note when ``ok``.
    **extra
        More keys (timings, POI, residuals), after the standard ones.
        numpy values become lists/ints/floats; NaN or inf inside extra
        values become ``None`` (JSON null).

    Returns
    -------
    dict
        Keys ``frame, t, ok, position, axes, cov, reason`` then ``extra``;
        arrays as lists of floats; ``None`` for position, axes and cov when
        not ``ok``.

    Raises
    ------
    ValueError
        On NaN/inf or a wrong shape in the pose, a non-rotation ``axes``, a
        non-SPD ``cov``, a missing pose when ``ok``, a pose or no reason
        when not ``ok`` (these are programming errors).
    """
    return _build_record(frame, t, ok, position, axes, cov, reason, extra, AXES_TOL_WRITE)


class PoseWriter(ProgressiveOutput):
    """Write pose records as JSON Lines under their final name, one object per line, flushed per record.

    Parameters
    ----------
    path : str or Path
        Output file, or ``'-'`` for standard output (which is not closed);
        a path that is standard output (``/dev/stdout``) is written in place
        as ``'-'``, a link to a file is written through (the link stays).
        A file is written under its own name from the first record on, so
        that whatever ends the run (a crash, SIGKILL, a full disk) leaves
        every record written before it in ``path``. An existing ``path`` is
        first moved to a visible name beside it (``poses.previous.jsonl``,
        :mod:`headplod.io.progressive`): :meth:`close` deletes it (the run
        replaced it whole), ``close(complete=False)`` keeps it, and
        :meth:`discard` puts it back. The output of a killed run found at
        ``path`` is kept as ``poses.unfinished-<start>.jsonl``; ``notes``
        says so.

    Attributes
    ----------
    count : int
        Records written.
    notes : list of str
        Leftovers of killed runs found and kept, one line each, for the
        caller to show.
    previous : Path or None
        Where the file this one replaces was moved, until :meth:`close`.

    Raises
    ------
    OSError
        When the file cannot be made (the folder is missing or not
        writable), or ``path`` is a folder; nothing is moved then.
    headplod.io.files.OutputRefused
        When ``path`` is a device node, FIFO or socket (or a link to one),
        or standard input or error; nothing is touched.
    headplod.io.progressive.OutputBusy
        When another running headplod process writes ``path``.

    Examples
    --------
    >>> with PoseWriter("poses.jsonl") as out:          # doctest: +SKIP
    ...     out.write(pose_record(0, 0.0, False, reason="left image: 4 marker blobs, 5 needed"))

    Notes
    -----
    Records must come in strictly increasing frame order (the contract's
    "one object per frame, in frame order"); :meth:`write` raises
    ``ValueError`` otherwise. Each record is one ``write`` of a whole line,
    written at once (unbuffered), and a write that fails midway is truncated
    back, so a file cut short by a fault or a kill ends with a whole record.
    """

    def __init__(self, path: str | Path):
        from .progressive import claim_output

        self.path = str(path)
        self._last_frame: int | None = None
        self._claim = None
        self.count = 0
        self.notes: list[str] = []
        target = Path(self.path).expanduser()
        if refuse_special(target, self.path, stream=True):      # '-', /dev/stdout, ...: written in place
            self._fh = sys.stdout
            self._owned = False
            return
        if target.is_dir():
            raise IsADirectoryError(f"{self.path}: is a folder; give the file to write, e.g. {target / 'poses.jsonl'}")
        if target.is_symlink():                                  # written through: the link stays a link
            target = Path(os.path.realpath(target))
        self._claim = claim_output(target, what=self.path, describe=_count_records)
        self.notes = list(self._claim.notes)
        try:
            self._fh = open(target, "xb", buffering=0)  # unbuffered: a record is on disk when write returns
        except BaseException:
            self._claim.restore(lambda: None)
            raise
        self._owned = True
        self._size = 0                                   # bytes of whole records in the file

    @property
    def previous(self) -> Path | None:
        return None if self._claim is None else self._claim.previous

    @property
    def to_stdout(self) -> bool:
        """True when the records go to standard output (``'-'``, or a path that is it), written in place."""
        return not self._owned

    def write(self, record: Mapping[str, Any] | None = None, **fields: Any) -> dict:
        """Validate and write one record.

        Parameters
        ----------
        record : mapping, optional
            A record as :func:`pose_record` returns (re-validated here).
        **fields
            Alternatively, the arguments of :func:`pose_record`.

        Returns
        -------
        dict
            The record written.
        """
        if self._fh is None:
            raise ValueError(f"{self.path}: PoseWriter is closed")
        if record is not None and fields:
            raise TypeError("PoseWriter.write takes a record or keyword fields, not both")
        rec = pose_record(**dict(record if record is not None else fields))
        if self._last_frame is not None and rec["frame"] <= self._last_frame:
            raise ValueError(
                f"{self.path}: frame {rec['frame']} written after frame {self._last_frame}; "
                "records must be in increasing frame order, one per frame"
            )
        line = json.dumps(rec, allow_nan=False) + "\n"
        if self._owned:
            self._write_whole(line.encode("utf-8"))
        else:
            self._fh.write(line)
            self._fh.flush()
        self._last_frame = rec["frame"]
        self.count += 1
        return rec

    def _write_whole(self, data: bytes) -> None:
        """Append one record's bytes, or none of them: a write the disk cuts short (full, over ``ulimit -f``)
        is truncated back, so the file always ends with a whole record."""
        view = memoryview(data)
        try:
            while view:
                view = view[self._fh.write(view):]
        except BaseException:
            try:
                os.ftruncate(self._fh.fileno(), self._size)
            except OSError:
                pass
            raise
        self._size += len(data)

    def close(self, complete: bool = True) -> str | None:
        """Close the file (standard output is only flushed); idempotent.

        Parameters
        ----------
        complete : bool
            True when the run ended as it should: the file this one replaced
            is deleted. False (the run ended early): it is kept.

        Returns
        -------
        str or None
            Where the replaced file is kept (``complete`` false), else None.

        Raises
        ------
        OSError
            When the last flush fails (a full disk, a closed pipe); the
            records written before stay in the file.
        """
        fh, self._fh = self._fh, None
        try:
            if fh is not None:
                if self._owned:
                    fh.close()
                else:
                    fh.flush()
        except OSError:
            complete = False
            raise
        finally:
            kept = self._claim.finish(complete) if self._claim is not None else None
        return kept

    def _undo(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None and self._owned:
            fh.close()
        if self._claim is not None:
            self._claim.restore(lambda: self._claim.path.unlink(missing_ok=True))

    def __repr__(self) -> str:
        return f"PoseWriter({self.path!r}, {self.count} records)"


def _count_records(path: Path) -> str:
    """``"42 records"``: the whole lines of a pose file (a killed run's last line may be cut)."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError:
        return "unreadable"
    lines = data.count(b"\n")
    return f"{lines} records"


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON (NaN/inf are not allowed)")


def read_poses(path: str | Path) -> list[dict]:
    """Read and validate a JSON Lines file of pose records.

    Parameters
    ----------
    path : str or Path
        The file, or ``'-'`` for standard input.

    Returns
    -------
    list of dict
        The records as parsed (JSON-native values, key order as in the
        file), blank lines skipped.

    Raises
    ------
    ContractError
        Naming the file and line: invalid JSON (including NaN/inf), a
        non-object line, a missing standard key, a record that
        :func:`pose_record` would refuse (axes checked with tolerance
        ``AXES_TOL_READ``), or frames not in strictly increasing order.
    """
    ctx = _Ctx.file(path)
    hint = "one JSON object per line with keys " + ", ".join(POSE_KEYS)
    if str(path) == "-":
        text = sys.stdin.read()
    else:
        p = Path(path)
        if not p.is_file():
            raise ctx.error("file not found" if not p.exists() else "is not a file", hint)
        text = p.read_text(encoding="utf-8")
    out: list[dict] = []
    last = None
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line, parse_constant=_reject_constant)
        except ValueError as exc:
            raise ctx.error(f"line {lineno}: invalid JSON ({exc})", hint) from None
        if not isinstance(rec, dict):
            raise ctx.error(f"line {lineno}: a JSON {type(rec).__name__}, expected an object", hint)
        missing = [k for k in POSE_KEYS if k not in rec]
        if missing:
            raise ctx.error(f"line {lineno}: keys {missing} missing", hint + " (null when no pose)")
        std = {k: rec[k] for k in POSE_KEYS}
        try:
            _build_record(std.pop("frame"), std.pop("t"), std.pop("ok"), std["position"],
                          std["axes"], std["cov"], std["reason"], {}, AXES_TOL_READ)
        except ValueError as exc:
            raise ctx.error(f"line {lineno}: {exc}", hint) from None
        if last is not None and rec["frame"] <= last:
            raise ctx.error(
                f"line {lineno}: frame {rec['frame']} after frame {last}, expected increasing frames",
                "records come one per frame, in frame order",
            )
        last = rec["frame"]
        out.append(rec)
    return out
