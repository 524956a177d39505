"""The cache folder: rendered synthetic sequences, terrain grids and matplotlib's font cache.

``$HEADPLOD_CACHE`` when set (and not empty), else ``~/.cache/headplod``, where ``~`` is ``$HOME`` when it
is an absolute folder other than ``/``, else the user's home in the password database. An empty
``HOME`` (``HOME=""``, a service's environment) never puts the cache in ``/.cache``: without any home
:func:`cache_root` raises :class:`CacheUnusable`, whose one line says to set ``HEADPLOD_CACHE``.

:func:`usable_cache_root` also makes the folder and checks that files can be written in it, before any
long work that would fill it; what is wrong is one line naming ``HEADPLOD_CACHE`` and what to do.
The command line also keeps Mesa's shader cache here (``headplod.cli.LIBRARY_CACHES``).
"""
from __future__ import annotations

import errno
import os
import pwd
import tempfile
from pathlib import Path
from typing import Callable, Mapping, Optional

__all__ = ["CACHE_VARIABLE", "CacheUnusable", "cache_root", "usable_cache_root", "home_of_user"]

#: The environment variable that names the cache folder.
CACHE_VARIABLE = "HEADPLOD_CACHE"


class CacheUnusable(Exception):
    """The cache folder cannot be used; the message is one line naming ``HEADPLOD_CACHE`` and what to do."""


def home_of_user() -> Optional[str]:
    """The home folder of the user running the program in the password database, or None."""
    try:
        return pwd.getpwuid(os.getuid()).pw_dir
    except (KeyError, OSError):
        return None


def _a_home(text: Optional[str]) -> Optional[Path]:
    """``text`` as a home folder: absolute and not the root folder (else None)."""
    if not text or not os.path.isabs(text):
        return None
    path = Path(text)
    return None if path == Path(path.anchor) else path


def cache_root(environ: Mapping[str, str] | None = None,
               home_of_user: Callable[[], Optional[str]] = home_of_user) -> Path:
    """The cache folder (not made, not checked): ``$HEADPLOD_CACHE``, else ``HOME/.cache/headplod``.

    Raises :class:`CacheUnusable` when ``HEADPLOD_CACHE`` is unset and neither ``HOME`` nor the password
    database gives a home folder.
    """
    environ = os.environ if environ is None else environ
    given = environ.get(CACHE_VARIABLE, "")
    if given:
        return Path(given).expanduser()
    home = _a_home(environ.get("HOME")) or _a_home(home_of_user())
    if home is None:
        why = "HOME is empty" if environ.get("HOME") == "" else "HOME is unset or not an absolute folder"
        raise CacheUnusable(f"no folder for the cache: {CACHE_VARIABLE} is unset, {why}, and the user has no "
                            f"home in the password database; set {CACHE_VARIABLE} to a folder to keep the "
                            "cache in (e.g. HEADPLOD_CACHE=/var/tmp/headplod)")
    return home / ".cache" / "headplod"


def _named(root: Path, environ: Mapping[str, str]) -> str:
    """How the message names the cache: the variable and its value, or the default's folder."""
    if environ.get(CACHE_VARIABLE):
        return f"{CACHE_VARIABLE}={environ[CACHE_VARIABLE]}"
    return f"the cache folder {root} ({CACHE_VARIABLE} unset)"


def usable_cache_root(environ: Mapping[str, str] | None = None) -> Path:
    """:func:`cache_root`, made if missing and checked writable (a file is made and removed in it).

    Raises :class:`CacheUnusable` (one line naming ``HEADPLOD_CACHE`` and what to do) when it is a file,
    lies under one, or cannot be made or written, or (``HEADPLOD_CACHE`` unset) when the home folder does
    not exist: a home that is not there (``/nonexistent``, a service's) is not made.
    """
    environ = os.environ if environ is None else environ
    root = cache_root(environ)
    fix = f"point {CACHE_VARIABLE} at a folder you can write (or unset it for ~/.cache/headplod)"
    if root.exists() and not root.is_dir():
        raise CacheUnusable(f"{_named(root, environ)}: is a file, not a folder; {fix}")
    home = root.parent.parent
    if not environ.get(CACHE_VARIABLE) and not home.is_dir():     # a service's home (/nonexistent): not made
        raise CacheUnusable(f"{_named(root, environ)}: the home folder {home} does not exist; set "
                            f"{CACHE_VARIABLE} to a folder you can write")
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=root):
            pass
    except OSError as exc:
        what = "lies under a file, not a folder" if exc.errno == errno.ENOTDIR else "cannot be written"
        raise CacheUnusable(f"{_named(root, environ)}: {what} ({exc.strerror or exc}); {fix}") from None
    return root
