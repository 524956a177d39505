"""Built-in synthetic stereo sequences, rendered once and cached on disk.

The tracker never sees how these are made: :mod:`synthetic` renders a
dataset folder in the contract's format (docs/contract.md), and the tracker
reads it like any recording. Renders are cached under ``$HEADPLOD_CACHE``
(default ``~/.cache/headplod``), keyed by preset, frame count and seed.

A finished render holds ``.complete``, its manifest: every file's name,
size, modification time and hash. Each use checks the sizes and times (one
``stat`` per file, about a millisecond for a sequence) and hashes only the
files whose time changed; a file missing, truncated or changed makes the
sequence render again, with a one-line note. :func:`verify_dataset` reads
every image instead, for a sequence whose frame failed to read.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import uuid
from pathlib import Path

import synthetic

from ..cache import usable_cache_root
from ..io.images import read_image
from ..progress import Progress, is_quiet

#: The sequence ``headplod track`` runs without a dataset.
DEFAULT_SEQUENCE = "looking_around"


#: Modules of ``synthetic`` that do not take part in rendering the marker datasets.
_NOT_IN_DATASETS = {"boards.py", "__main__.py", "cli.py"}


def _renderer_version() -> str:
    """Hash of the synthetic package's source: a changed renderer never reuses stale renders."""
    digest = hashlib.sha256()
    for path in sorted(Path(synthetic.__file__).parent.glob("*.py")):
        if path.name not in _NOT_IN_DATASETS:
            digest.update(path.read_bytes())
    return digest.hexdigest()[:10]


def cache_root() -> Path:
    """The cache folder (:func:`headplod.cache.cache_root`), made and checked writable; raises
    :class:`~headplod.cache.CacheUnusable` (one line naming HEADPLOD_CACHE) when it cannot be used."""
    return usable_cache_root()


def ensure_dataset(preset: str = DEFAULT_SEQUENCE, frames: int | None = None, seed: int = 0,
                   root: Path | None = None, quiet: bool = False, **options) -> Path:
    """Path of a rendered dataset folder for a synthetic preset, rendering it if needed.

    Parameters
    ----------
    preset : str
        A name of ``synthetic.scenes.PRESETS``.
    frames : int, optional
        Number of frames (the preset's default when None).
    seed : int
        Random seed (noise, glints); the same seed gives the same images.
    root : Path, optional
        Cache folder (default :func:`cache_root`).
    quiet : bool
        No progress on standard error.
    **options
        Preset options (e.g. ``distance_mm`` for ``static``), part of the cache key.
    """
    # Imported on use: the renderer pulls in scipy.special, slow to import, which live tracking never needs.
    from synthetic import dataset as synth_dataset
    from synthetic import scenes

    quiet = quiet or is_quiet()                         # the command's -q
    if preset not in scenes.PRESETS:
        raise ValueError(f"unknown synthetic preset {preset!r}; choose one of {', '.join(sorted(scenes.PRESETS))}")
    root = Path(root) if root is not None else cache_root()
    tag = "".join(f"-{k}{v}" for k, v in sorted(options.items()))
    folder = root / f"{preset}{tag}-{frames or 'default'}-s{seed}-{_renderer_version()}"
    marker = folder / COMPLETE
    _remove_abandoned(folder)
    if marker.exists():
        problem = _check_manifest(folder)
        if problem is None:
            return folder
        print(f"note: the cached synthetic sequence {folder} is damaged ({problem}); rendering it again",
              file=sys.stderr)
    scene = scenes.make_scene(preset, n_frames=frames, seed=seed, **options)
    if not quiet:
        print(f"rendering synthetic sequence '{preset}' ({len(scene.times)} stereo pairs) into {folder}",
              file=sys.stderr)
    progress = None if quiet else _progress(len(scene.times), preset)
    # Rendered beside the cache entry and renamed into place when complete: two
    # processes rendering the same sequence (two benchmarks at once) never
    # write into, or delete, each other's folder.
    staging = folder.with_name(f"{_staging_prefix(folder)}{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        synth_dataset.write_dataset(staging, scene, seed=seed, progress=progress)
        _write_manifest(staging)
        if _intact(folder):
            return folder                      # another process finished it meanwhile
        if folder.exists():
            shutil.rmtree(folder)              # an interrupted or damaged render
        try:
            os.rename(staging, folder)
        except OSError:
            if not _intact(folder):
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return folder


#: The marker of a finished render, and its manifest (JSON: {"files": {name: [size, mtime_ns, blake2b]}}).
COMPLETE = ".complete"


def _file_hash(path: Path) -> str:
    return hashlib.blake2b(path.read_bytes(), digest_size=16).hexdigest()


def _dataset_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.name != COMPLETE)


def _write_manifest(folder: Path) -> None:
    """Write ``.complete`` with every file's size, modification time and hash (atomically)."""
    files = {}
    for path in _dataset_files(folder):
        st = path.stat()
        files[path.relative_to(folder).as_posix()] = [st.st_size, st.st_mtime_ns, _file_hash(path)]
    tmp = folder / (COMPLETE + ".tmp")
    tmp.write_text(json.dumps({"files": files}))
    os.replace(tmp, folder / COMPLETE)


def _staging_prefix(folder: Path) -> str:
    """The start of the names a cache entry is rendered under, before its renderer's process id."""
    return f".{folder.name}.rendering-"


def _remove_abandoned(folder: Path) -> None:
    """Delete the folders ``folder`` was being rendered in by processes that no longer run (killed
    mid-render: their own clean-up never ran)."""
    prefix = _staging_prefix(folder)
    for staging in folder.parent.glob(f"{prefix}*"):
        try:
            os.kill(int(staging.name[len(prefix):].split("-")[0]), 0)
        except ProcessLookupError:
            shutil.rmtree(staging, ignore_errors=True)
        except (ValueError, PermissionError):
            pass                                   # not ours to judge: another user's, or not a staging name


def _intact(folder: Path) -> bool:
    """A finished render whose files are as its manifest says."""
    return (folder / COMPLETE).exists() and _check_manifest(folder) is None


def _check_manifest(folder: Path) -> str | None:
    """What is wrong with a finished render, from its manifest (None: nothing). Cheap: one stat per file.

    A file whose modification time changed is hashed and compared; a marker
    of an older version (no manifest) has every image read once, then gets
    a manifest.
    """
    try:
        manifest = json.loads((folder / COMPLETE).read_text())
        files = manifest["files"]
    except (OSError, ValueError, KeyError, TypeError):
        problem = verify_dataset(folder)
        if problem is None:
            _write_manifest(folder)    # an older cache, read whole once: from now on, the cheap check
        return problem
    for name, (size, mtime_ns, digest) in files.items():
        path = folder / name
        try:
            st = path.stat()
        except OSError:
            return f"{name} is missing"
        if st.st_size != size:
            return f"{name} has {st.st_size} bytes, {size} when rendered"
        if st.st_mtime_ns != mtime_ns and _file_hash(path) != digest:
            return f"{name} changed since it was rendered"
    return None


def verify_dataset(folder: Path) -> str | None:
    """Read every image of a rendered sequence: the first one that fails, or None when all read."""
    folder = Path(folder)
    for side in ("left", "right"):
        if not (folder / side).is_dir():
            return f"{side}/ is missing"
    for path in _dataset_files(folder):
        if path.suffix == ".png" and read_image(path) is None:
            return f"{path.relative_to(folder).as_posix()} cannot be read"
    return None


def rerender(folder: Path, reason: str) -> None:
    """Mark a cached render as damaged (``reason``), so that the next :func:`ensure_dataset` renders it again."""
    print(f"note: the cached synthetic sequence {folder} is damaged ({reason}); it will be rendered again",
          file=sys.stderr)
    (Path(folder) / COMPLETE).unlink(missing_ok=True)


def _progress(total: int, label: str):
    bar = Progress(total, f"render {label}", unit="frame")
    return lambda *args, **kwargs: bar.step()
