"""Shared machinery of the contract's files: errors and OpenCV FileStorage.

Everything the per-file modules of :mod:`headplod.io` have in common: the
:class:`ContractError` that a broken file raises and the context (``_Ctx``)
that names the file and key in its message, reading and writing OpenCV
FileStorage YAML (``rig.yaml``, ``markers.yaml``, ``screen.yaml``; through
memory, so that OpenCV's binding never sees a path: :func:`read_storage`,
:func:`writing_storage`), and the
checks used by more than one kind of file (3-vectors, orthonormal axes and
their tolerances). Of the package it imports only :mod:`headplod.io.files`
(what an output may be).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import cv2
import numpy as np

from .files import refuse_special

# --------------------------------------------------------------------------
# tolerances
# --------------------------------------------------------------------------

#: Tolerance on the orthonormality of pose axes handed to :func:`pose_record`.
AXES_TOL_WRITE = 1e-6
#: Tolerance on the orthonormality of axes read from text files (truth.csv,
#: pose records), which may have been rounded (6 decimals give ~1e-6).
AXES_TOL_READ = 1e-4


# --------------------------------------------------------------------------
# errors
# --------------------------------------------------------------------------


class ContractError(ValueError):
    """A file (or an object) breaks the contract of ``docs/contract.md``.

    The message names the file (or the object) first, then what is wrong,
    expected against actual, and usually a ``Hint:`` on how to fix it.

    Parameters
    ----------
    message : str
        The full, human-readable message.
    path : str or path-like, optional
        The offending file, ``None`` when the error is about an object built
        in code.

    Attributes
    ----------
    path : str or None
        The offending file as given by the caller, or ``None``.
    """

    def __init__(self, message: str, path: str | Path | None = None):
        super().__init__(message)
        self.path: str | None = None if path is None else str(path)


@dataclass(frozen=True)
class _Ctx:
    """Where a problem is: a file (item 'key') or an object (item 'field')."""

    where: str
    path: str | None
    item: str = "key"

    @classmethod
    def file(cls, path: str | Path) -> "_Ctx":
        return cls(str(path), str(path), "key")

    @classmethod
    def obj(cls, name: str) -> "_Ctx":
        return cls(name, None, "field")

    def name(self, key: str) -> str:
        return f"{self.item} '{key}'"

    def error(self, what: str, hint: str | None = None) -> ContractError:
        msg = f"{self.where}: {what}"
        if hint:
            msg += f". Hint: {hint}"
        return ContractError(msg, self.path)


def _shape_str(a: np.ndarray) -> str:
    if a.ndim == 0:
        return "a scalar"
    if a.ndim == 1:
        return f"a flat list of {a.shape[0]}"
    return "x".join(str(n) for n in a.shape)


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _check_finite(ctx: _Ctx, key: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ctx.error(
            f"{ctx.name(key)} has a non-finite value {a[where]} at index "
            f"{list(where)}, expected finite numbers",
            "recompute or re-export the value; NaN/inf usually means a failed "
            "calibration",
        )


# --------------------------------------------------------------------------
# OpenCV FileStorage helpers
# --------------------------------------------------------------------------


def _cv_message(exc: BaseException) -> str:
    """The useful part of a cv2.error (possibly wrapped in a SystemError)."""
    e: BaseException | None = exc
    while e is not None and not isinstance(e, cv2.error):
        e = e.__cause__ or e.__context__
    text = str(e if e is not None else exc).strip()
    m = re.search(r"in function '(.*)'\s*$", text, re.S)
    if m and ("(" in m.group(1) or ":" in m.group(1)):
        return m.group(1).strip()
    m = re.search(r"error: \(([^)]*)\)\s*(.*)$", text, re.S)
    if m:
        return f"{m.group(2).strip()} ({m.group(1)})"
    return text.splitlines()[-1] if text else type(exc).__name__


def _open_storage(path: str | Path, what: str) -> tuple[cv2.FileStorage, _Ctx]:
    """Open an OpenCV FileStorage file for reading, or raise ContractError."""
    ctx = _Ctx.file(path)
    p = Path(path)
    if not p.exists():
        raise ctx.error("file not found", f"expected {what} here; check the path")
    if p.is_dir():
        raise ctx.error("is a directory, expected a file", f"give the path of {what}")
    if p.stat().st_size == 0:
        raise ctx.error(
            "file is empty, expected OpenCV FileStorage YAML",
            f"write {what} with cv2.FileStorage or headplod.io",
        )
    try:
        fs = read_storage(p)
    except OSError as exc:
        raise ctx.error(f"cannot be opened for reading ({exc.strerror or exc})",
                        "check the file's permissions") from None
    except ValueError:
        raise ctx.error(f"is {p.stat().st_size / 2**20:.0f} MB, expected an OpenCV FileStorage YAML file "
                        f"of a few kB", f"give the path of {what}") from None
    except (cv2.error, SystemError) as exc:
        raise ctx.error(
            f"cannot be parsed as OpenCV FileStorage YAML: {_cv_message(exc)}",
            "check indentation and brackets near the reported line; the "
            "file should start with '%YAML:1.0' and hold 'key: value' lines "
            "and !!opencv-matrix blocks",
        ) from exc
    if not fs.isOpened():
        raise ctx.error("cannot be opened for reading", "check the file's permissions")
    if not fs.root().isMap():
        raise ctx.error(
            "top level is not a mapping of keys",
            "the file must hold 'key: value' entries at top level",
        )
    return fs, ctx


def _is_matrix_node(node: cv2.FileNode) -> bool:
    if not node.isMap():
        return False
    keys = set(node.keys())
    return {"dt", "data"} <= keys and ({"rows", "cols"} <= keys or "sizes" in keys)


def _node_to_python(node: cv2.FileNode, ctx: _Ctx, key: str) -> Any:
    """Convert a FileNode to int, float, str, ndarray, list or dict."""
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if _is_matrix_node(node):
        try:
            return np.array(node.mat())
        except (cv2.error, SystemError) as exc:
            raise ctx.error(
                f"{ctx.name(key)} is a malformed !!opencv-matrix: {_cv_message(exc)}",
                "rows x cols must equal the number of data values and dt must "
                "be a type code such as 'd'",
            ) from exc
    if node.isSeq():
        return [_node_to_python(node.at(i), ctx, key) for i in range(node.size())]
    if node.isMap():
        return {k: _node_to_python(node.getNode(k), ctx, f"{key}.{k}") for k in node.keys()}
    return None


def _missing_key(ctx: _Ctx, fs: cv2.FileStorage, key: str, hint: str) -> ContractError:
    present = ", ".join(fs.root().keys()) or "none"
    return ctx.error(f"key '{key}' is missing (keys present: {present})", hint)


def _read_numeric(fs: cv2.FileStorage, ctx: _Ctx, key: str, hint: str) -> np.ndarray:
    """A numeric node (matrix, sequence or scalar) as a float64 array."""
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        raise _missing_key(ctx, fs, key, hint)
    value = _node_to_python(node, ctx, key)
    if isinstance(value, str):
        raise ctx.error(f"{ctx.name(key)} is the string {value!r}, expected numbers", hint)
    if isinstance(value, dict):
        raise ctx.error(
            f"{ctx.name(key)} is a mapping with keys {list(value)}, expected a "
            "!!opencv-matrix or a list of numbers",
            hint,
        )
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ctx.error(
            f"{ctx.name(key)} is not a numeric matrix or list ({exc})", hint
        ) from exc
    return arr


def _read_positive_int(fs: cv2.FileStorage, ctx: _Ctx, key: str, hint: str) -> int:
    arr = _read_numeric(fs, ctx, key, hint)
    if arr.size != 1:
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(arr)}, expected one integer", hint)
    return _positive_int(ctx, key, float(arr.reshape(-1)[0]), hint)


def _positive_int(ctx: _Ctx, key: str, value: Any, hint: str | None = None) -> int:
    if isinstance(value, (bool, np.bool_)):
        raise ctx.error(f"{ctx.name(key)} is {value!r}, expected a positive integer", hint)
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name(key)} is {value!r}, expected a positive integer", hint) from None
    if not math.isfinite(f) or f != int(f) or f <= 0:
        raise ctx.error(f"{ctx.name(key)} is {value!r}, expected a positive integer", hint)
    return int(f)


#: The largest YAML file read, bytes: the contract's are a few kB; a bigger one is another file (a video
#: given as --calib), not read into memory.
MAX_YAML_BYTES = 64 * 2**20


def read_storage(path: str | Path) -> cv2.FileStorage:
    """An OpenCV FileStorage reading the file ``path``, whose text Python reads: OpenCV's binding never sees
    the path (it crashes on a name that is not UTF-8, :mod:`.images`). Bytes that are not UTF-8 in the text
    read as U+FFFD.

    Raises OSError when the file cannot be read, ValueError when it holds more than :data:`MAX_YAML_BYTES`,
    cv2.error or SystemError when it cannot be parsed.
    """
    with open(path, "rb") as f:
        data = f.read(MAX_YAML_BYTES + 1)
    if len(data) > MAX_YAML_BYTES:
        raise ValueError(f"{path}: larger than {MAX_YAML_BYTES // 2**20} MB, not an OpenCV YAML file")
    return cv2.FileStorage(data.decode("utf-8", errors="replace"), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)


@contextlib.contextmanager
def writing_storage(path: str | Path) -> Iterator[cv2.FileStorage]:
    """An OpenCV FileStorage writing YAML into memory, whose text is written to ``path`` when the block ends
    (the bytes OpenCV would write there; OpenCV's binding never sees the path). Nothing is written when the
    block raises.

    Raises OSError (naming ``path``) when the file cannot be written.
    """
    refuse_special(path)                # Python's open would wait on a FIFO, or write into a device
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    try:
        yield fs
    except BaseException:
        fs.release()
        raise
    text = fs.releaseAndGetString()
    try:
        with open(path, "w", encoding="utf-8", newline="") as f:
            f.write(text)
    except OSError as exc:
        raise OSError(f"{path}: cannot open for writing ({exc.strerror or exc})") from exc


def _fs_write(fs: cv2.FileStorage, name: str, value: Any) -> None:
    """Write a Python/numpy value to FileStorage (name '' inside sequences)."""
    if isinstance(value, (bool, np.bool_)):
        fs.write(name, int(value))
    elif isinstance(value, (int, np.integer)):
        fs.write(name, int(value))
    elif isinstance(value, (float, np.floating)):
        fs.write(name, float(value))
    elif isinstance(value, str):
        fs.write(name, value)
    elif isinstance(value, np.ndarray):
        a = value
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        elif a.dtype.kind in "iu" and a.dtype not in (np.uint8, np.int8, np.uint16, np.int16, np.int32):
            a = a.astype(np.int32) if (a.size == 0 or (a.min() >= -2**31 and a.max() < 2**31)) else a.astype(np.float64)
        elif a.dtype.kind == "f" and a.dtype not in (np.float32, np.float64):
            a = a.astype(np.float64)
        elif a.dtype.kind not in "iuf":
            raise ValueError(f"cannot write array {name!r} of dtype {a.dtype} to FileStorage")
        if a.ndim == 0:
            _fs_write(fs, name, a.item())
            return
        if a.ndim == 1:
            a = a.reshape(1, -1)
        fs.write(name, np.ascontiguousarray(a))
    elif isinstance(value, (list, tuple)):
        flow = all(isinstance(v, (int, float, str, np.number)) for v in value)
        flags = cv2.FileNode_SEQ | (cv2.FileNode_FLOW if flow else 0)
        fs.startWriteStruct(name, flags)
        for v in value:
            _fs_write(fs, "", v)
        fs.endWriteStruct()
    elif isinstance(value, Mapping):
        fs.startWriteStruct(name, cv2.FileNode_MAP)
        for k, v in value.items():
            if not isinstance(k, str):
                raise ValueError(f"cannot write mapping key {k!r} (keys must be str)")
            _fs_write(fs, k, v)
        fs.endWriteStruct()
    else:
        raise ValueError(f"cannot write {name!r} of type {type(value).__name__} to FileStorage")


def _values_equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        try:
            return np.array_equal(np.asarray(a), np.asarray(b))
        except Exception:  # pragma: no cover - odd types
            return False
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return a.keys() == b.keys() and all(_values_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_values_equal(x, y) for x, y in zip(a, b))
    return a == b


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------
# checks shared by several files
# --------------------------------------------------------------------------

def _check_vec3(ctx: _Ctx, key: str, v: np.ndarray, hint: str) -> np.ndarray:
    if v.shape not in ((3,), (3, 1), (1, 3)):
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(v)}, expected 3x1 or 1x3", hint)
    v = v.reshape(3)
    _check_finite(ctx, key, v)
    return v


def _check_axes(axes: np.ndarray, tol: float) -> str | None:
    """None if axes (rows Ξ, Ψ, V) are orthonormal and right-handed, else why not."""
    off = float(np.abs(axes @ axes.T - np.eye(3)).max())
    if off > tol:
        return f"axes rows are not orthonormal: max |A Aᵀ − I| = {off:.3g}, tolerance {tol:g}"
    det = float(np.linalg.det(axes))
    if det < 0:
        return f"axes are left-handed: det = {det:.6g}, expected +1 (Ψ must be V × Ξ)"
    return None


def write_atomically(path, write: Callable[[str], None], suffix: str = "") -> Path:
    """Call ``write(name)`` on a temporary name in ``path``'s folder, then rename it to ``path``.

    ``path`` is whole or untouched: an interrupted or failed write leaves no
    partial file (the temporary one is removed). ``suffix`` ends the
    temporary name (a writer that picks its format from the ending needs
    it). The file gets the permissions a plain write would give. A link is
    written through: its target is replaced and the link stays. An OSError
    names ``path`` as given, never the temporary name.

    A ``path`` that is this process's standard output (``/dev/stdout``,
    ``/proc/self/fd/1``, or the file fd 1 goes to) is written in place: the
    temporary file's bytes go to fd 1, and nothing is renamed. A device
    node, FIFO or socket (or a link to one), standard input or standard
    error is never replaced: :class:`~headplod.io.files.OutputRefused`,
    before ``write`` is called.
    """
    target = Path(path).expanduser()
    if refuse_special(target, stream=True):
        _write_to_stdout(write, suffix)
        return target
    final = os.path.realpath(target)
    with _naming(path):
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(final)}.", suffix=suffix,
                                   dir=os.path.dirname(final))
        os.close(fd)
        try:
            write(tmp)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)          # mkstemp's 0600 is for the temporary name only
            os.replace(tmp, final)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    return target


@contextlib.contextmanager
def _naming(path) -> Iterator[None]:
    """Re-raise an OSError of the block naming ``path`` as given: the temporary name a whole-or-nothing write
    uses first means nothing to the person who named ``path``."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None or str(exc.filename) == str(path):
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


def _write_to_stdout(write: Callable[[str], None], suffix: str) -> None:
    """``write`` to a temporary file, then its bytes to fd 1 (after what Python has buffered for it)."""
    with tempfile.TemporaryDirectory(prefix="headplod-") as folder:
        tmp = os.path.join(folder, f"output{suffix}")
        write(tmp)
        data = memoryview(Path(tmp).read_bytes())
    sys.stdout.flush()
    while data:
        data = data[os.write(1, data):]


class ProgressiveOutput:
    """The interface of an output written under its final name as a run goes (:mod:`headplod.io.progressive`).

    ``close(complete)`` ends it: a run that ended as it should (``True``)
    deletes what the output replaced; one that ended early keeps it.
    :meth:`discard`, before anything was written, puts back what it replaced.
    As a context manager: leaving the ``with`` block normally, or by Ctrl-C
    (KeyboardInterrupt: the run stopped), is ``close()``; leaving it by an
    error is ``close(complete=False)``.

    Subclasses set ``count`` (what was written) and define ``close`` and
    ``_undo`` (remove the new output, restore the replaced one).
    """

    count = 0

    def close(self, complete: bool = True):   # pragma: no cover - each output defines it
        raise NotImplementedError

    def _undo(self) -> None:                   # pragma: no cover - each output defines it
        raise NotImplementedError

    def discard(self) -> None:
        """Before anything was written: drop the new output and put back the one it replaced. Idempotent.

        Raises
        ------
        ValueError
            When something was written: it is never thrown away (use
            ``close(complete=False)``).
        """
        if self.count:
            raise ValueError(f"{self!r}: {self.count} written; they are kept (close(complete=False))")
        self._undo()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(complete=exc_type is None or not issubclass(exc_type, Exception))
