"""The renderer's command line, one parser for ``python -m synthetic render`` and ``headplod synth``.

    python -m synthetic render PRESET --out DIR [--frames N] [--seed S] [-q] [--overwrite]
    python -m synthetic list
    headplod synth PRESET --out DIR [--frames N] [--seed S] [-q] [--overwrite]     (the same arguments and run)

:func:`add_render_arguments` adds the arguments of ``render`` to a parser and
:func:`run_render` runs it, so ``headplod synth`` (``headplod/cli.py``) is this
command under another name. Progress (frames, rate) goes to standard error
through tqdm, silent with ``-q``. The old spelling, a positional OUT_DIR after
PRESET, still works for one release and prints a note with the new one (the
line ``headplod``'s old spellings print: this package never imports headplod).

OUT_DIR is never mixed with what it held: a folder that is not empty is
refused unless ``--overwrite``, and then only the entries a dataset folder
owns (:data:`DATASET_ENTRIES`) are replaced; a folder that holds anything
else is refused even then (nothing that is not a dataset's is deleted), and
so are the current, home and root folders. The dataset is rendered into a
hidden folder beside OUT_DIR and moved in when complete, so a failed or
interrupted render leaves OUT_DIR as it was. Exit status: 0 on success, 1
when the dataset cannot be written, 2 on bad usage.
"""
from __future__ import annotations

import argparse
import os
import shutil
import stat
import sys
import tempfile
from pathlib import Path

from tqdm import tqdm

from .scenes import PRESETS, make_scene, preset_name

__all__ = ["add_render_arguments", "run_render", "build_parser", "main", "DATASET_ENTRIES"]

#: What a dataset folder owns: the contract's files and folders, and what the renderer and a recording add.
DATASET_ENTRIES = ("left", "right", "rig.yaml", "markers.yaml", "screen.yaml", "times.csv", "truth.csv",
                   "gaze_truth.csv", "rig_truth.json", "webcam_truth.json", "recording.log")


def _preset(text: str) -> str:
    try:
        preset_name(text)
    except KeyError as exc:
        raise argparse.ArgumentTypeError(exc.args[0]) from None
    return text


def _frames(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of frames, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def note_old_spelling(old: str, new: str) -> None:
    """The one-line note for an old spelling that still works, word for word ``headplod.argtypes``'s."""
    print(f"note: {old} is now {new}; the old spelling goes in the next release", file=sys.stderr)


def add_render_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``render``'s arguments to a (sub)parser; returns it."""
    parser.add_argument("preset", type=_preset, metavar="PRESET", help="one of: " + ", ".join(PRESETS))
    out = parser.add_mutually_exclusive_group(required=True)
    out.add_argument("--out", dest="out_dir", metavar="DIR",
                     help="dataset folder to write (created; an existing one must be empty, or hold only a "
                          "dataset, replaced with --overwrite)")
    out.add_argument("old_out_dir", nargs="?", metavar="OUT_DIR",
                     help="old spelling of --out OUT_DIR (goes in the next release)")
    parser.add_argument("--frames", type=_frames, default=None, help="number of frames (preset default)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene and of the noise")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on standard error")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the dataset already in OUT_DIR (only its own files: left/, right/, the "
                             "YAML and CSV files; a folder holding anything else is refused)")
    return parser


def _refuse_out_dir(out_dir: str, overwrite: bool) -> str | None:
    """Why OUT_DIR may not be written (one line), or None."""
    folder = Path(out_dir).expanduser()
    if folder.exists() and not folder.is_dir():
        return f"{out_dir}: is {_special(folder, follow=True) or 'a file'}; give a folder for the dataset"
    if not folder.exists():
        return None
    entries = sorted(e.name for e in folder.iterdir())
    if not entries:
        return None
    if not overwrite:
        return (f"{out_dir}: is not empty ({len(entries)} entries: {', '.join(entries[:4])}"
                f"{', ...' if len(entries) > 4 else ''}); choose an empty folder, or add --overwrite to replace "
                "the dataset in it")
    resolved = folder.resolve()
    special = [("the current folder", Path.cwd().resolve()), ("the home folder", Path.home().resolve()),
               ("the root folder", Path(resolved.anchor))]
    for name, path in special:
        if resolved == path:
            return f"{out_dir}: is {name}; --overwrite only replaces a dataset folder of its own"
    for name, path in special:
        if resolved in path.parents:
            return f"{out_dir}: holds {name}; --overwrite only replaces a dataset folder of its own"
    special = next((p for name in DATASET_ENTRIES for p in _tree(folder / name) if _special(p)), None)
    if special is not None:
        return (f"{out_dir}: its {special.relative_to(folder)} is {_special(special)}, which --overwrite would "
                "replace (a special file is never written over); move it, or choose another folder")
    foreign = [e for e in entries if e not in DATASET_ENTRIES]
    if foreign:
        return (f"{out_dir}: holds files that are not a dataset's ({', '.join(foreign[:4])}"
                f"{', ...' if len(foreign) > 4 else ''}); --overwrite deletes only a dataset's own files: "
                "move them, or choose another folder")
    return None


_SPECIAL = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
            (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


def _special(path: Path, follow: bool = False) -> str | None:
    """What ``path`` is when it is a device node, FIFO or socket (through a link when ``follow``), else None."""
    try:
        mode = (path.stat() if follow else path.lstat()).st_mode
    except OSError:
        return None
    return next((kind for test, kind in _SPECIAL if test(mode)), None)


def _tree(path: Path) -> list:
    """``path`` and, for a folder (not a link), everything in it; [] when there is nothing there."""
    if not (path.is_symlink() or path.exists()):
        return []
    return [path, *(path.rglob("*") if path.is_dir() and not path.is_symlink() else ())]


def _move_into(work: Path, folder: Path) -> None:
    """Put the dataset rendered in ``work`` in ``folder``'s place: its own entries replaced, then ``work`` gone."""
    if not folder.exists():
        os.replace(work, folder)
        return
    for name in DATASET_ENTRIES:
        old = folder / name
        if old.is_symlink() or old.is_file():
            old.unlink()
        elif old.is_dir():
            shutil.rmtree(old)
    for entry in work.iterdir():
        os.replace(entry, folder / entry.name)
    work.rmdir()


def run_render(args: argparse.Namespace) -> int:
    """Render ``args.preset`` into ``args.out_dir``; the exit status."""
    # Imported on use: the renderer's modules are not needed to parse (or to print --help).
    from .dataset import write_dataset

    if getattr(args, "old_out_dir", None):
        name = "headplod synth" if getattr(args, "command", None) == "synth" else "python -m synthetic render"
        note_old_spelling(f"'{name} {args.preset} {args.old_out_dir}'",
                          f"'{name} {args.preset} --out {args.old_out_dir}'")
        args.out_dir = args.old_out_dir
    problem = _refuse_out_dir(args.out_dir, args.overwrite)
    if problem:
        print(f"synth: {problem}", file=sys.stderr)
        return 2
    folder = Path(args.out_dir).expanduser()
    parent = folder.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f".{folder.name}.synth-", dir=parent))
    except OSError as exc:
        print(f"synth: {args.out_dir}: cannot write beside it ({exc.strerror or exc})", file=sys.stderr)
        return 1
    bar = None
    try:                                                  # whatever happens from here, the hidden folder goes
        scene = make_scene(args.preset, n_frames=args.frames, seed=args.seed)
        print(f"{scene.name}: {scene.description}; {scene.n_frames} frames "
              f"{scene.setup.image_size[0]}x{scene.setup.image_size[1]} -> {args.out_dir}")
        bar = tqdm(total=scene.n_frames, desc=f"render {scene.name}", unit="frame", file=sys.stderr,
                   disable=args.quiet, mininterval=0.5)

        def progress(done: int, total: int) -> None:
            bar.update(done - bar.n)

        write_dataset(work, scene, seed=args.seed, progress=progress)
        os.chmod(work, 0o777 & ~_umask())                 # mkdtemp's 0700 is for the hidden name only
        _move_into(work, folder)
    except OSError as exc:
        print(f"synth: {args.out_dir}: {exc}; left as it was", file=sys.stderr)
        return 1
    finally:
        if bar is not None:
            bar.close()
        shutil.rmtree(work, ignore_errors=True)
    if not args.quiet:
        print(f"wrote {scene.n_frames} stereo pairs to {args.out_dir}", file=sys.stderr)
    return 0


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def build_parser(prog: str = "python -m synthetic") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description="synthetic IR stereo datasets")
    sub = parser.add_subparsers(dest="cmd", required=True)
    add_render_arguments(sub.add_parser("render", help="render a preset into a dataset folder"))
    sub.add_parser("list", help="list the presets")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.cmd == "list":
        for name in PRESETS:
            print(f"{name:16s} {make_scene(name, n_frames=2).description}")
        return 0
    return run_render(args)
