"""The command line's standard streams: a closed one is never a file's descriptor, a broken one costs nothing.

A program started with a standard stream closed (``2>&-``, ``>&-``, ``<&-``) has a free descriptor 0, 1
or 2: the next file it opens takes it, and then C libraries' messages (written to descriptor 2) land in
that file, or an output is read as standard input. :func:`reopen_closed` puts ``os.devnull`` on each
closed one before anything opens a file, and says which were closed, so that a command can refuse to
write its records to a standard output that nobody opened
(:meth:`StandardStreams.closed_stream_named`: ``-``, ``/dev/stdout``, ...).

Python itself leaves ``sys.stderr`` None when descriptor 2 was closed at its start, and ``print(...,
file=None)`` then writes to *standard output*: into the records of ``--out -``. :func:`reopen_closed`
gives each missing ``sys`` stream a real one on the reopened descriptor.

A name whose bytes are not UTF-8 prints on standard output as those bytes (:func:`print_names_as_they_are`)
rather than ending the command with UnicodeEncodeError.

Messages are not worth a run: :class:`DroppingStream` wraps standard error so that a write that fails
(EBADF, EPIPE: its reader left, ENOSPC: ``2>/dev/full``, EIO: a closed terminal) drops the message and
every later one, silently; the run's outputs and exit status are what they would have been.
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
from dataclasses import dataclass
from typing import Iterator, TextIO

__all__ = ["StandardStreams", "reopen_closed", "DroppingStream", "dropping_stderr", "print_names_as_they_are"]

#: The descriptors of standard input, output and error, and their names in ``sys``.
_STANDARD = ((0, "stdin"), (1, "stdout"), (2, "stderr"))


@dataclass(frozen=True)
class StandardStreams:
    """Which standard descriptors were closed when the command started (0 stdin, 1 stdout, 2 stderr)."""

    closed: frozenset = frozenset()

    def closed_stream_named(self, name: str, dash: int | None = None) -> str | None:
        """What ``name`` is (``"standard output"``, ...) when it names one of the standard streams that were
        closed (its data would go to, or come from, /dev/null), else None. ``dash``: the descriptor ``-``
        stands for in the option that gave ``name`` (1 for an output; None when ``-`` is no stream there)."""
        spellings = _link_chain(name)
        for fd, (what, names) in _STREAM_NAMES.items():
            if fd in self.closed and (any(s in names for s in spellings) or (dash == fd and name == "-")):
                return what
        return None


def _link_chain(name: str, most: int = 40) -> list:
    """``name`` and the paths its symbolic links lead through, as written (``out.jsonl`` -> ``/dev/stdout``
    -> ``/proc/self/fd/1``): with a stream closed, /proc/self/fd/N is /dev/null, so the names tell, not
    the file they lead to now."""
    chain = [name]
    while len(chain) <= most:
        try:
            target = os.readlink(chain[-1])
        except (OSError, ValueError):
            break
        chain.append(os.path.join(os.path.dirname(chain[-1]), target))
        if target.startswith("/proc/self/fd/") or target.startswith("/dev/fd/"):
            chain.append(target)
            break
    return [os.path.normpath(c) for c in chain]


#: The names of the standard streams as files, and what they are called.
_STREAM_NAMES = {0: ("standard input", ("/dev/stdin", "/dev/fd/0", "/proc/self/fd/0")),
                 1: ("standard output", ("/dev/stdout", "/dev/fd/1", "/proc/self/fd/1")),
                 2: ("standard error", ("/dev/stderr", "/dev/fd/2", "/proc/self/fd/2"))}


def _is_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


def reopen_closed() -> StandardStreams:
    """Open ``os.devnull`` on every closed standard descriptor, give ``sys`` a stream for each that Python left
    None, and return which were closed."""
    closed = frozenset(fd for fd, _ in _STANDARD if not _is_open(fd))
    for fd in sorted(closed):
        try:
            null = os.open(os.devnull, os.O_RDONLY if fd == 0 else os.O_WRONLY)
        except OSError:                                 # no /dev/null (a bare chroot): nothing to put there
            continue
        if null != fd:
            os.dup2(null, fd)
            os.close(null)
    for fd, name in _STANDARD:
        if getattr(sys, name) is None and _is_open(fd):
            mode = "r" if fd == 0 else "w"
            setattr(sys, name, open(fd, mode, encoding="utf-8", errors="backslashreplace", closefd=False,
                                    buffering=1 if fd else -1))
    return StandardStreams(closed)


def print_names_as_they_are() -> None:
    """Standard output writes a name's bytes that are not UTF-8 (``b'caf\\xe9'``, held as ``'caf\\udce9'``) as the
    bytes they are, as Python does under the C locale, instead of raising UnicodeEncodeError (a locale such
    as ``en_US.UTF-8`` makes it strict). Standard error already shows them as ``\\xe9`` escapes."""
    stream = sys.stdout
    if getattr(stream, "errors", None) == "strict" and hasattr(stream, "reconfigure"):
        with contextlib.suppress(Exception):
            stream.reconfigure(errors="surrogateescape")


class DroppingStream(io.TextIOBase):
    """A text stream over ``stream`` whose writes never raise: the first that fails (an OSError, or a stream
    closed under it) drops that message and every later one. ``dropped`` tells whether one did."""

    def __init__(self, stream: TextIO):
        super().__init__()
        self.stream = stream
        self.dropped = False

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        if not self.dropped:
            try:
                self.stream.write(text)
                if "\n" in text:
                    self.stream.flush()          # a message out as it is written, or dropped with it
            except (OSError, ValueError):
                self._drop()
        return len(text)

    def flush(self) -> None:
        if not self.dropped:
            try:
                self.stream.flush()
            except (OSError, ValueError):
                self._drop()

    def _drop(self) -> None:
        """Stop writing; discard what the stream still holds, so that its own flush at exit fails no more."""
        self.dropped = True
        with contextlib.suppress(Exception):
            fd = self.stream.buffer.raw.fileno()        # a stream over a descriptor (not a test's capture)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, fd)
            os.close(null)

    def isatty(self) -> bool:
        try:
            return not self.dropped and self.stream.isatty()
        except (OSError, ValueError, AttributeError):
            return False

    def fileno(self) -> int:
        return self.stream.fileno()

    @property
    def encoding(self) -> str | None:
        return getattr(self.stream, "encoding", None)

    @property
    def errors(self) -> str | None:
        return getattr(self.stream, "errors", None)

    def close(self) -> None:                     # the wrapped stream is not this one's to close
        pass


@contextlib.contextmanager
def dropping_stderr() -> Iterator[DroppingStream]:
    """``sys.stderr`` is a :class:`DroppingStream` over the current one while the block runs."""
    before = sys.stderr
    stream = before if isinstance(before, DroppingStream) else DroppingStream(before)
    sys.stderr = stream
    try:
        yield stream
    finally:
        sys.stderr = before
