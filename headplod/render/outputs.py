"""Whether the render and demo commands can write where they are told to, found before any long work
(:func:`check_writable`).

:func:`check_writable` tries what the write will do, in the place it will
do it: the nearest folder that exists on the way to the output must be a
folder that takes a new file (:func:`headplod.io.progressive.folder_unwritable`
makes a probe file there and removes it at once). Permission bits alone do not say it: root may write in a read-only
folder but not in ``/proc``, and a read-only mount refuses everyone. The
message names the path as the user gave it, never a temporary name.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..io.progressive import folder_unwritable

__all__ = ["OutputNotWritable", "check_writable"]


class OutputNotWritable(OSError):
    """An output that cannot be written where it is named (its folder cannot be made or takes no new file).

    The message says why, in words about the user's path; a command reports it as bad usage (exit status 2).
    """


def check_writable(path, *, folder: bool = False) -> None:
    """Raise :class:`OutputNotWritable` unless ``path`` can be written: as a file (made, with its missing
    folders, as the write will), or with ``folder`` as a folder (made, or filled when it exists).

    Nothing is left behind: the probe file is removed, no folder is made.
    """
    target = Path(path).expanduser()
    if folder and _exists(target) and not target.is_dir():
        raise OutputNotWritable("cannot be written: it is a file, not a folder")
    existing = target if folder else target.parent
    while not _exists(existing) and existing != existing.parent:     # the folders the write would make
        existing = existing.parent
    existing = existing if str(existing) else Path(".")
    if not existing.is_dir():
        raise OutputNotWritable(f"cannot be written: {existing} is not a folder")
    why = folder_unwritable(existing)
    if why is not None:
        raise OutputNotWritable(f"cannot be written: no file can be made in {existing} ({why})")


def _exists(path: Path) -> bool:
    """Whether ``path`` exists (a dangling symbolic link counts: the write would follow or replace it); a path
    that cannot be looked at (no permission on a folder on the way) counts as existing, so the probe fails
    there with the reason."""
    try:
        os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return False
    except OSError:
        return True
    return True
