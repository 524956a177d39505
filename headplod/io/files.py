"""One notion of "the same file", and what an output may be.

Every command that writes checks each output here, before any long work
(the rule lives here once; the commands call it):

- **What an output may be** (:func:`output_kind`): a missing path or a
  regular file (a folder where a folder is meant), or standard output:
  ``-`` where the command streams, and any path that *is* this process's
  standard output (``/dev/stdout``, ``/proc/self/fd/1``, a link to them, or
  any path whose ``(st_dev, st_ino)`` is fd 1's), which is written in place
  and never replaced. A device node, a FIFO or a socket, or a link to one,
  is refused: writing it atomically would delete it, opening a FIFO would
  wait for a reader. So is this process's standard input or error.
- **What an output may not touch** (:class:`Inputs`, :func:`check_not_input`):
  every input a run actually reads (the files, and the folders whose
  entries it lists) is held by its resolved path (``os.path.realpath``) and,
  when it exists, its ``(st_dev, st_ino)``. An output file that is an input
  (a symlink or a chain of them, ``..``, a hard link, a bind mount: the same
  device and inode), or lies inside an input folder, is refused; so is an
  output folder that holds an input or lies inside an input folder.

A refusal is an :class:`OutputRefused` with a one-line message that names
the option and the path as the user gave them, and says what to do.
Nothing here writes; it reads the file system (``stat``, ``realpath``) and
never opens a path, so a FIFO cannot block it.
"""
from __future__ import annotations

import enum
import errno
import fnmatch
import os
import stat
from dataclasses import dataclass
from typing import Iterable, Sequence

__all__ = ["OutputRefused", "OutputKind", "FileId", "Input", "Inputs", "file_id", "special_kind",
           "special_entry", "standard_stream", "refuse_special", "output_kind", "check_not_input", "check_output",
           "check_files"]

#: The kinds of file an output may never be, by ``stat`` test.
_SPECIAL = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
            (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))
_STREAMS = ((0, "standard input"), (1, "standard output"), (2, "standard error"))


class OutputRefused(ValueError):
    """An output path that is not written: a special file, an input, or inside one.

    ``str(exc)`` is one line naming the option and the path as given, and
    what to do; ``option`` and ``path`` are those two.
    """

    def __init__(self, message: str, option: str = "", path: str = ""):
        super().__init__(message)
        self.option, self.path = option, path


class OutputKind(enum.Enum):
    """What an accepted output path is now."""

    MISSING = "missing"          # made by the writer
    FILE = "file"                # a regular file (or a link to one): replaced whole
    FOLDER = "folder"            # a folder (or a link to one), where a folder output is meant
    STDOUT = "stdout"            # standard output: written in place, never replaced


@dataclass(frozen=True)
class FileId:
    """Where a path leads: ``real``, its ``os.path.realpath``; ``dev_ino``, ``(st_dev, st_ino)`` when it exists."""

    real: str
    dev_ino: tuple[int, int] | None

    def same(self, other: "FileId") -> bool:
        """The same file or folder: one resolved path, or one device and inode (a hard link, a bind mount)."""
        return self.real == other.real or (self.dev_ino is not None and self.dev_ino == other.dev_ino)


def _given(path) -> str:
    return os.path.expanduser(os.fspath(path))


def file_id(path) -> FileId:
    """The :class:`FileId` of ``path`` (str or path-like; ``~`` expanded). Never raises."""
    p = _given(path)
    real = os.path.realpath(p)
    try:
        st = os.stat(p)
    except (OSError, ValueError):
        return FileId(real, None)
    return FileId(real, (st.st_dev, st.st_ino))


def _ancestors(real: str) -> list[tuple[str, tuple[int, int] | None]]:
    """``real`` and each folder above it, with its (dev, ino) when it exists: nearest first."""
    chain, p = [], real
    while True:
        try:
            st = os.stat(p)
            chain.append((p, (st.st_dev, st.st_ino)))
        except (OSError, ValueError):
            chain.append((p, None))
        parent = os.path.dirname(p)
        if parent == p:
            return chain
        p = parent


def _under(real: str, folder: str) -> bool:
    """Whether resolved ``real`` is ``folder`` or lies inside it, by their resolved paths."""
    return real == folder or real.startswith(folder.rstrip(os.sep) + os.sep)


@dataclass(frozen=True)
class Input:
    """One input a run reads: ``what`` (a few words for messages), ``path`` as named, where it leads."""

    what: str
    path: str
    id: FileId
    folder: bool


@dataclass(frozen=True)
class Inputs:
    """Every input a run actually reads, files and folders, in the order they are named.

    Build it with :meth:`file`, :meth:`folder`, :meth:`files` and ``+``;
    each returns a new value. A file that has a single name (``st_nlink``
    1) and lies inside a folder already held adds nothing (any spelling of
    it leads inside that folder) and is left out, so that a dataset of many
    frames costs one ``stat`` per frame and a short list.
    """

    items: tuple[Input, ...] = ()

    def file(self, what: str, path) -> "Inputs":
        """With the file ``path`` (it need not exist yet)."""
        return Inputs(self.items + (Input(what, str(path), file_id(path), False),))

    def folder(self, what: str, path) -> "Inputs":
        """With the folder ``path``: nothing may be written inside it."""
        return Inputs(self.items + (Input(what, str(path), file_id(path), True),))

    def files(self, what: str, paths: Iterable) -> "Inputs":
        """With many files (``what`` says what each is, e.g. "a frame being read"); see the class docstring."""
        folders = [i.id.real for i in self.items if i.folder]
        heads: dict[str, str] = {}                      # each folder resolved once, not once per file in it
        added = []
        for path in paths:
            p = _given(path)
            head, name = os.path.split(p)
            if head not in heads:
                heads[head] = os.path.realpath(head or ".")
            try:
                st = os.lstat(p)
                real = os.path.join(heads[head], name)
                if stat.S_ISLNK(st.st_mode) or name in ("", ".", ".."):
                    real = os.path.realpath(p)
                    st = os.stat(p)
            except (OSError, ValueError):
                added.append(Input(what, str(path), FileId(os.path.realpath(p), None), False))
                continue
            if st.st_nlink == 1 and any(_under(real, f) for f in folders):
                continue
            added.append(Input(what, str(path), FileId(real, (st.st_dev, st.st_ino)), False))
        return Inputs(self.items + tuple(added))

    def __add__(self, other: "Inputs") -> "Inputs":
        return Inputs(self.items + other.items)

    def __iter__(self):
        return iter(self.items)

    def __len__(self) -> int:
        return len(self.items)


def _name(option: str, path: str) -> str:
    return f"{option} {path}" if option else str(path)


def special_kind(path) -> str | None:
    """What ``path`` is when it is not a regular file, folder or nothing: "a character device", "a FIFO (named
    pipe)", "a socket", "a block device" (through links: "a link to a FIFO ... (/real/path)"); else None."""
    p = _given(path)
    try:
        mode = os.stat(p).st_mode
    except (OSError, ValueError):
        return None
    for test, kind in _SPECIAL:
        if test(mode):
            return f"a link to {kind} ({os.path.realpath(p)})" if os.path.islink(p) else kind
    return None


def standard_stream(path) -> int | None:
    """The standard stream (0, 1 or 2) this process has open on ``path`` (same device and inode), or None.

    ``/dev/stdout``, ``/proc/self/fd/1`` and any link to them are fd 1 whatever fd 1 is (a terminal, a
    pipe, a file); so is the file fd 1 was redirected to, by its own name. ``-`` is not a path: None.
    """
    p = _given(path)
    if p == "-":
        return None
    try:
        st = os.stat(p)
    except (OSError, ValueError):
        return None
    for fd, _ in _STREAMS:
        try:
            own = os.fstat(fd)
        except (OSError, ValueError):
            continue
        if (own.st_dev, own.st_ino) == (st.st_dev, st.st_ino):
            return fd
    return None


def refuse_special(path, name: str | None = None, *, option: str = "", stream: bool = False,
                   folder: bool = False) -> bool:
    """Raise :class:`OutputRefused` when ``path`` may never be written: a device node, FIFO or socket (or a
    link to one), this process's standard input or error, or its standard output unless ``stream``; True
    when it is standard output (``-`` or a path that is fd 1: write it in place), else False.

    ``name`` begins the message (default ``option`` and the path); ``folder``: a folder output is meant.
    """
    given = os.fspath(path)
    name = name or _name(option, given)
    noun = "folder" if folder else "file"
    if given == "-":
        if stream and not folder:
            return True
        raise OutputRefused(f"{name}: this output cannot go to standard output ('-'); give a {noun} name",
                            option, given)
    fd = standard_stream(given)
    if fd == 1 and stream and not folder:
        return True
    kind = special_kind(given)
    if fd == 1 or (fd is not None and kind is None):      # (/dev/null as standard input: a device, said so)
        where = "cannot go there" if fd == 1 else "is never written there"
        raise OutputRefused(f"{name}: is this run's {dict(_STREAMS)[fd]}, and this output {where}; give a "
                            f"{noun} name", option, given)
    if kind is not None:
        discard = " (to keep nothing, leave the option out)" if os.path.realpath(given) == os.devnull else ""
        raise OutputRefused(f"{name}: is {kind}, not a {'folder' if folder else 'regular file'}, and a special "
                            f"file is never written over; give another {noun} name{discard}", option, given)
    closed = _closed_descriptor(given)
    if closed is not None:
        raise OutputRefused(f"{name}: is this run's {dict(_STREAMS).get(closed, f'file descriptor {closed}')}, "
                            f"which is closed; give a {noun} name", option, given)
    return False


def _closed_descriptor(path: str) -> int | None:
    """The descriptor a path such as ``/dev/stdout`` leads to (``/proc/<this pid>/fd/N``) when N is not open."""
    parent, fd = os.path.split(os.path.realpath(_given(path)))
    if fd.isdigit() and parent in (f"/proc/{os.getpid()}/fd", "/proc/self/fd") and not os.path.lexists(
            os.path.join(parent, fd)):
        return int(fd)
    return None


def output_kind(path, *, option: str = "", folder: bool = False, stream: bool = False,
                entries: Sequence[str] | None = None) -> OutputKind:
    """What output ``path`` is, or :class:`OutputRefused` when it may not be written.

    Parameters
    ----------
    path : str or path-like
        As the user gave it (``-`` is standard output).
    option : str
        The option that named it (``"--out"``), for the message.
    folder : bool
        A folder output (``--record DIR``): a missing path or a folder.
    stream : bool
        The command can write this output to standard output: ``-`` and a
        path that is standard output give :attr:`OutputKind.STDOUT`
        (refused otherwise).
    entries : sequence of str, optional
        With ``folder``: the names (``fnmatch`` patterns) of the entries
        the output writes or replaces in it; an existing one that is, or
        holds, a special file is refused (it would be moved and deleted).

    Returns
    -------
    OutputKind
    """
    given = os.fspath(path)
    name = _name(option, given)
    if refuse_special(given, name, option=option, stream=stream, folder=folder):
        return OutputKind.STDOUT
    p = _given(given)
    try:
        mode = os.stat(p).st_mode
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputRefused(f"{name}: is a loop of symbolic links; give another name", option, given) from None
        if not folder and given.endswith(("/", os.sep)):       # 'poses/' names a folder, not a file 'poses'
            raise OutputRefused(f"{name}: ends with '/', which names a folder; give the file to write (a "
                                "name without the '/')", option, given) from None
        return OutputKind.MISSING
    except ValueError:
        return OutputKind.MISSING
    if stat.S_ISDIR(mode):
        if folder:
            bad = special_entry(p, entries) if entries is not None else None
            if bad is not None:
                raise OutputRefused(f"{name}: its {bad[0]} is {bad[1]}, which would be replaced; move it, or "
                                    "choose another folder", option, given)
            return OutputKind.FOLDER
        raise OutputRefused(f"{name}: is a folder; give the file to write", option, given)
    if folder:
        raise OutputRefused(f"{name}: is a file; give a folder", option, given)
    return OutputKind.FILE


def special_entry(folder, patterns: Sequence[str] = ("*",)) -> tuple[str, str] | None:
    """The first entry of ``folder`` matching ``patterns`` (``fnmatch``) that is, or holds (not through
    links), a special file: (its path relative to ``folder``, its kind); None when there is none."""
    def problem(entry: os.DirEntry, rel: str) -> tuple[str, str] | None:
        if entry.is_symlink() or entry.is_file(follow_symlinks=False):
            return None                     # (from the folder listing: no stat per frame of a recording)
        if entry.is_dir(follow_symlinks=False):
            for child in _listing(entry.path):
                found = problem(child, os.path.join(rel, child.name))
                if found:
                    return found
            return None
        try:
            mode = entry.stat(follow_symlinks=False).st_mode
        except OSError:
            return None
        return next(((rel, kind) for test, kind in _SPECIAL if test(mode)), None)

    for entry in _listing(_given(folder)):
        if any(fnmatch.fnmatchcase(entry.name, pat) for pat in patterns):
            found = problem(entry, entry.name)
            if found:
                return found
    return None


def _listing(folder: str) -> list:
    try:
        with os.scandir(folder) as it:
            return list(it)
    except OSError:
        return []


def check_not_input(path, inputs: Inputs, *, option: str = "", folder: bool = False,
                    entries: Sequence[str] | None = None, fix: str | None = None) -> None:
    """Refuse an output that is, holds or lies inside an input (raises :class:`OutputRefused`).

    Parameters
    ----------
    path : str or path-like
        The output as the user gave it (a file; with ``folder``, a folder).
    inputs : Inputs
        What the run reads (and other outputs it must not overwrite).
    option : str
        The option that named it, for the message.
    folder : bool
        A folder output: it may not lie inside an input folder, nor hold an
        input (in one of its ``entries`` when given, anywhere in it when None).
    entries : sequence of str, optional
        With ``folder``: the names (``fnmatch`` patterns) of the entries the
        output writes or replaces; inputs elsewhere in the folder are safe.
    fix : str, optional
        What to do, ending the message (default: another name or folder).
    """
    given = os.fspath(path)
    if given == "-":
        return
    name = _name(option, given)
    out = file_id(given)
    chain = _ancestors(out.real)
    chain_ids = {ident for _, ident in chain if ident is not None}

    def spelled(item: Input) -> str:
        return "" if item.path == given else f" ({item.path})"

    if not folder:
        for item in inputs:
            if not item.folder and item.id.same(out):
                raise OutputRefused(f"{name}: is {item.what}{spelled(item)}; {fix or 'give another file name'}",
                                    option, given)
    for item in inputs:
        if item.folder and (_under(out.real, item.id.real) or item.id.dev_ino in chain_ids):
            raise OutputRefused(f"{name}: {'is' if item.id.same(out) else 'lies inside'} {item.what}{spelled(item)}, "
                                f"which is never written to; {fix or 'write it elsewhere'}", option, given)
    if not folder:
        return
    for item in inputs:
        entry = _entry_holding(item, out)
        if entry is not None and (entries is None or any(fnmatch.fnmatchcase(entry, pat) for pat in entries)):
            where = "" if entries is None else f" (in its {entry})"
            raise OutputRefused(f"{name}: holds {item.what}{spelled(item)}{where}; "
                                f"{fix or 'choose another folder'}", option, given)


def _entry_holding(item: Input, out: FileId) -> str | None:
    """The name of folder ``out``'s entry that is or holds ``item`` (``"."`` when ``item`` is ``out``), or None."""
    below = None
    for path, ident in _ancestors(item.id.real):
        if path == out.real or (ident is not None and ident == out.dev_ino):
            return "." if below is None else os.path.basename(below)
        below = path
    return None


def check_output(path, inputs: Inputs = Inputs(), *, option: str = "", folder: bool = False, stream: bool = False,
                 entries: Sequence[str] | None = None, fix: str | None = None) -> OutputKind:
    """:func:`output_kind`, then (unless standard output) :func:`check_not_input`: the whole check of one
    output; its kind, or :class:`OutputRefused`."""
    kind = output_kind(path, option=option, folder=folder, stream=stream, entries=entries)
    if kind is not OutputKind.STDOUT:
        check_not_input(path, inputs, option=option, folder=folder, entries=entries, fix=fix)
    return kind


def check_files(outputs: Iterable[tuple[str, object]], inputs: Inputs = Inputs(), *,
                stream: bool = True) -> Inputs:
    """:func:`check_output` for file outputs given as ``(option, path)`` (a None path is skipped), each against
    ``inputs`` and the outputs named before it (two options naming one file are refused).

    ``stream``: the outputs may be standard output (their writer is :func:`~headplod.io.write_atomically`,
    which writes such a path in place). Returns ``inputs`` with the outputs added, for later checks.
    """
    held = inputs
    for option, path in outputs:
        if path is None:
            continue
        if check_output(path, held, option=option, stream=stream) is not OutputKind.STDOUT:
            held = held.file(f"the file {option} writes", path)
    return held
