"""Outputs written progressively under their final name: what they replace, and what a killed run left.

A run's growing outputs (the pose records of ``--out``, the recording of
``--record``) are written under the name the user gave from the first frame
on, flushed as they go, so that whatever ends the run (a crash, SIGKILL, a
closed terminal, a full disk) leaves everything up to it where the user
looks for it. Three things follow, and this module does them, the same way
for a file and for a recording folder:

- **What the output replaces is moved aside, to a visible name.** An
  existing ``poses.jsonl`` becomes ``poses.previous.jsonl`` (a recording's
  entries move into ``rec.previous/``) before the first frame. A run that
  ends as it should (its source ended, ``--frames``, a stop signal) deletes
  it: the user asked for it to be replaced, and it has been, by a whole
  run. A run that ends early keeps it, and says so.
- **A run in progress is marked.** A small marker (``.poses.jsonl.headplod-run``
  beside a file, ``rec/.headplod-run`` in a recording) names the process,
  its start and what it moved aside; a run that ends, early or not,
  removes it.
- **A marker whose process is gone is a killed run's.** The next run that
  writes to the same path moves the killed run's output to a visible
  ``poses.unfinished-20261202T021433.jsonl`` (``rec.unfinished-.../``), says
  so, and names what that run had moved aside. The hidden temporary files
  of earlier versions of headplod (``.poses.jsonl.XXXX.part``,
  ``.rec.recording-XXXX/``) are brought to light the same way.

The marker is a hidden file because it holds no data, only who is writing;
every name that holds data is visible.
"""
from __future__ import annotations

import datetime as _dt
import errno
import json
import os
import shutil
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from .files import OutputRefused, refuse_special, special_entry

__all__ = ["OutputClaim", "OutputBusy", "claim_output", "killed_run", "previous_name", "unfinished_name",
           "MARKER_SUFFIX"]

MARKER_SUFFIX = ".headplod-run"


class OutputBusy(ValueError):
    """Another live headplod process is writing the same output."""


def _split(path: Path) -> tuple[str, str]:
    """(stem, suffix) of a file name, or (name, "") of a folder's: ``poses.jsonl`` -> (poses, .jsonl)."""
    if path.suffix and not path.is_dir():
        return path.name[: -len(path.suffix)], path.suffix
    return path.name, ""


def _free(parent: Path, stem: str, tag: str, suffix: str) -> Path:
    """``parent/stem.tag suffix``, or with -2, -3, ... when taken."""
    candidate = parent / f"{stem}.{tag}{suffix}"
    n = 2
    while candidate.exists() or candidate.is_symlink():
        candidate = parent / f"{stem}.{tag}-{n}{suffix}"
        n += 1
    return candidate


def previous_name(path: str | Path) -> Path:
    """The visible, free name an existing output is moved to while a run replaces it.

    ``poses.jsonl`` -> ``poses.previous.jsonl`` (``poses.previous-2.jsonl``
    when that is taken); a folder ``rec`` -> ``rec.previous``.
    """
    path = Path(path)
    stem, suffix = _split(path)
    return _free(path.parent, stem, "previous", suffix)


def unfinished_name(path: str | Path, started: str | None = None, written: str | Path | None = None) -> Path:
    """The visible, free name a killed run's output is kept under: ``poses.unfinished-<start>.jsonl``.

    ``started`` is the run's start as ``YYYYmmddTHHMMSS`` (UTC); without it,
    the last modification of ``written`` (the leftover itself; default
    ``path``) stands for it.
    """
    path = Path(path)
    if not started:
        try:
            mtime = Path(written if written is not None else path).stat().st_mtime
            started = _dt.datetime.fromtimestamp(mtime, _dt.timezone.utc).strftime("%Y%m%dT%H%M%S")
        except OSError:
            started = "unknown"
    stem, suffix = _split(path)
    return _free(path.parent, stem, f"unfinished-{started}", suffix)


def _marker_path(path: Path, folder: bool) -> Path:
    return path / MARKER_SUFFIX if folder else path.parent / f".{path.name}{MARKER_SUFFIX}"


def _alive(pid: int, host: str) -> bool:
    """Whether ``pid`` on ``host`` is a running headplod process (a reused pid of another program is not)."""
    if host != socket.gethostname():
        return False                    # another machine's run on a shared folder: cannot tell; treat as gone
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass                            # exists, another user's
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return True
    return b"headplod" in cmdline


@dataclass
class KilledRun:
    """What a marker says of the run that left it."""

    pid: int
    host: str
    started: str                        # UTC, YYYYmmddTHHMMSS
    previous: str | None                # the name it had moved the replaced output to, if any
    alive: bool

    def describe(self) -> str:
        when = self.started
        try:
            when = _dt.datetime.strptime(self.started, "%Y%m%dT%H%M%S").strftime("%Y-%m-%d %H:%M:%S UTC")
        except ValueError:
            pass
        return f"a run that did not finish (pid {self.pid}, started {when})"


def killed_run(path: str | Path, folder: bool = False) -> KilledRun | None:
    """The run whose marker lies at ``path`` (alive or not), or None when there is no marker."""
    path = Path(path).expanduser()
    marker = _marker_path(path, folder)
    if not marker.is_file():
        return None
    try:
        data = json.loads(marker.read_text(encoding="utf-8"))
        pid, host = int(data["pid"]), str(data["host"])
        started, previous = str(data.get("started") or ""), data.get("previous")
    except (OSError, ValueError, KeyError, TypeError):
        return KilledRun(0, "", "", None, False)     # an unreadable marker: its run cannot be running
    return KilledRun(pid, host, started, previous, _alive(pid, host))


@dataclass
class OutputClaim:
    """A path claimed for a progressive output: what was moved aside and what was announced.

    Attributes
    ----------
    path : Path
        The output's final name (a file, or a recording folder).
    previous : Path or None
        Where the output it replaces was moved (None when there was none).
    notes : list of str
        One line each: leftovers of killed runs found and kept, under which
        names. The caller shows them.
    """

    path: Path
    folder: bool
    previous: Path | None = None
    notes: list = field(default_factory=list)
    _entries: tuple | None = None
    _done: bool = False

    @property
    def marker(self) -> Path:
        return _marker_path(self.path, self.folder)

    def finish(self, complete: bool) -> str | None:
        """End the claim: the marker goes; the replaced output goes too when ``complete``.

        Returns
        -------
        str or None
            When the replaced output is kept (``complete`` false), where it
            is, for the caller's one line; else None.
        """
        if self._done:
            return None
        self._done = True
        kept = None
        if self.previous is not None:
            if complete:
                _remove(self.previous)
            elif self.previous.exists():
                kept = str(self.previous)
        self.marker.unlink(missing_ok=True)
        return kept

    def restore(self, remove_new: Callable[[], None]) -> None:
        """Undo the claim before anything was made: ``remove_new()`` clears the new output, the replaced one
        comes back to its name, the marker goes."""
        if self._done:
            return
        self._done = True
        remove_new()
        if self.previous is not None and self.previous.exists():
            if self.folder:
                _move_entries(self.previous, self.path, self._entries)
                shutil.rmtree(self.previous, ignore_errors=True)
            else:
                os.replace(self.previous, self.path)
        self.marker.unlink(missing_ok=True)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _move_entries(src: Path, dst: Path, entries: Iterable[str] | None) -> list[str]:
    """Move ``entries`` (all of them when None) of folder ``src`` into folder ``dst``; the names moved."""
    moved = []
    dst.mkdir(parents=True, exist_ok=True)
    names = [p.name for p in src.iterdir()] if entries is None else list(entries)
    for name in names:
        if (src / name).exists() or (src / name).is_symlink():
            os.replace(src / name, dst / name)
            moved.append(name)
    return moved


def _stamp_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%S")


def folder_unwritable(folder: str | Path) -> str | None:
    """Why no file can be created in ``folder`` (the OS's words), or None when one can.

    Tried, not asked: ``os.access`` says yes to root everywhere, and to
    anyone on a read-only mount or in ``/proc``. The probe is a hidden empty
    file, removed at once.
    """
    try:
        fd, probe = tempfile.mkstemp(prefix=".headplod-probe-", dir=folder)
    except OSError as exc:
        if exc.errno == errno.ENOENT and os.path.isdir(folder):   # a file system that makes no files (/proc, /sys)
            return "it takes no new files"
        return exc.strerror or type(exc).__name__
    os.close(fd)
    os.unlink(probe)
    return None


def claim_output(path: str | Path, *, what: str, folder: bool = False, entries: tuple | None = None,
                 holds_output: Callable[[Path], bool] | None = None,
                 describe: Callable[[Path], str] | None = None,
                 tidy: Callable[[Path], None] | None = None) -> OutputClaim:
    """Claim ``path`` for an output written progressively during this run (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The output's final name: a file, or (``folder``) a recording folder.
    what : str
        How the user named it, for messages (``"--out poses.jsonl"``).
    folder : bool
        A folder whose ``entries`` are the output (other files in it are the
        user's and stay).
    entries : tuple of str, optional
        With ``folder``: the names that make up the output.
    holds_output : callable(Path) -> bool, optional
        Whether the path holds an output to move aside (default: it exists).
    describe : callable(Path) -> str, optional
        A few words on a killed run's output (``"42 records"``).
    tidy : callable(Path) -> None, optional
        Makes a killed run's recording consistent once set aside.

    Returns
    -------
    OutputClaim

    Raises
    ------
    OutputRefused
        When ``path`` is a device node, FIFO or socket (or a link to one), a
        standard stream, or (``folder``) holds one among ``entries``: a
        special file is never moved or deleted.
    OutputBusy
        When a live headplod process is writing ``path``.
    PermissionError
        When the folder cannot be written (checked first: nothing is moved then).
    OSError
        When a move or the marker fails (what was moved is put back).
    """
    path = Path(path).expanduser()
    refuse_special(path, what, folder=folder)      # never moved aside, never deleted: refused
    bad = special_entry(path, entries or ("*",)) if folder and path.is_dir() else None
    if bad is not None:
        raise OutputRefused(f"{what}: its {bad[0]} is {bad[1]}, which would be moved and deleted; move it, or "
                            "choose another folder", path=str(path))
    existing = path.resolve() if folder else path.resolve().parent
    while not existing.exists():                    # a folder output is made with its parents: the first that is
        existing = existing.parent
    unwritable = folder_unwritable(existing)
    if unwritable is not None:
        raise PermissionError(f"{what}: the folder {existing} cannot be written ({unwritable})")
    claim = OutputClaim(path, folder, _entries=entries)
    holds = holds_output or (lambda p: p.exists())
    run = killed_run(path, folder)
    if run is not None and run.alive and run.pid != os.getpid():
        raise OutputBusy(f"{what}: is being written by another headplod run (pid {run.pid}); "
                         "choose another name, or stop that run first")
    if run is not None:
        if holds(path):
            kept = unfinished_name(path, run.started or None)
            if folder:
                _move_entries(path, kept, entries)
                if tidy is not None:
                    tidy(kept)
            else:
                os.replace(path, kept)
            extra = f" ({describe(kept)})" if describe is not None else ""
            claim.notes.append(f"{what}: found the output of {run.describe()}{extra}; kept as {kept}")
        if run.previous and Path(run.previous).exists():
            claim.notes.append(f"{what}: the output that run was replacing is kept as {run.previous}")
        _marker_path(path, folder).unlink(missing_ok=True)
    for old in _hidden_leftovers(path, folder):
        kept = unfinished_name(path, written=old)
        os.replace(old, kept)
        if folder and tidy is not None:
            tidy(kept)
        extra = f" ({describe(kept)})" if describe is not None else ""
        claim.notes.append(f"{what}: found the hidden output of an earlier, interrupted run{extra}; kept as {kept}")
    if holds(path):
        claim.previous = previous_name(path)
        if folder:
            _move_entries(path, claim.previous, entries)
        else:
            os.replace(path, claim.previous)
    if folder:                                      # (through a link to nothing yet: where the link points)
        Path(os.path.realpath(path)).mkdir(parents=True, exist_ok=True)
    marker = {"pid": os.getpid(), "host": socket.gethostname(), "started": _stamp_now(),
              "previous": None if claim.previous is None else str(claim.previous)}
    try:
        claim.marker.write_text(json.dumps(marker) + "\n", encoding="utf-8")
    except OSError:
        if claim.previous is not None:              # put back what was moved: nothing is changed by a refusal
            if folder:
                _move_entries(claim.previous, path, entries)
                shutil.rmtree(claim.previous, ignore_errors=True)
            else:
                os.replace(claim.previous, path)
        raise
    return claim


def _hidden_leftovers(path: Path, folder: bool) -> list[Path]:
    """Temporary files of earlier headplod versions for this output: ``.NAME.XXXX.part`` beside a file,
    ``.NAME.recording-XXXX/`` beside a recording folder."""
    parent = path.parent
    if not parent.is_dir():
        return []
    pattern = f".{path.name}.recording-*" if folder else f".{path.name}.*.part"
    return sorted(parent.glob(pattern))
