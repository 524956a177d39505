"""Built-in synthetic stereo sequences, rendered once and cached on disk.

The tracker never sees how these are made: :mod:`synthetic` renders a
dataset folder in the contract's format (conventions.md), and the tracker
reads it like any recording. Renders are cached under ``$HEADPLOD_CACHE``
(default ``~/.cache/headplod``), keyed by preset, frame count and seed.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

import synthetic

from ..progress import Progress

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
    return Path(os.environ.get("HEADPLOD_CACHE", Path.home() / ".cache" / "headplod"))


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
    # Imported on use: the renderer pulls in scipy.special (~0.6 s), which live tracking never needs.
    from synthetic import dataset as synth_dataset
    from synthetic import scenes

    if preset not in scenes.PRESETS:
        raise ValueError(f"unknown synthetic preset {preset!r}; choose one of {', '.join(sorted(scenes.PRESETS))}")
    root = Path(root) if root is not None else cache_root()
    tag = "".join(f"-{k}{v}" for k, v in sorted(options.items()))
    folder = root / f"{preset}{tag}-{frames or 'default'}-s{seed}-{_renderer_version()}"
    if (folder / ".complete").exists():
        return folder
    if folder.exists():
        shutil.rmtree(folder)          # an interrupted render
    scene = scenes.make_scene(preset, n_frames=frames, seed=seed, **options)
    if not quiet:
        print(f"rendering synthetic sequence '{preset}' ({len(scene.times)} stereo pairs) into {folder}",
              file=sys.stderr)
    progress = None if quiet else _progress(len(scene.times), preset)
    synth_dataset.write_dataset(folder, scene, seed=seed, progress=progress)
    (folder / ".complete").write_text("ok\n")
    return folder


def _progress(total: int, label: str):
    bar = Progress(total, f"render {label}", unit="frame")
    return lambda *args, **kwargs: bar.step()
