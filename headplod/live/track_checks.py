"""The checks ``headplod track`` makes before its first frame: no output (``--out``, ``--record``,
``--save-rig``) may be a special file, nor overwrite what the run reads (the dataset folder with its
``left/``, ``right/``, frames and files, wherever their links lead; the videos; the rig, marker and screen
files) or another output. They read the file system and write nothing; a refusal is a :class:`Usage`
error (exit status 2) whose message says what to do. The rule itself is :mod:`headplod.io.files`'s: one
notion of the same file (resolved path, or device and inode), the same for every command.
"""
from __future__ import annotations

from pathlib import Path

from ..capture import RECORDING_ENTRIES, recording_held, source_inputs
from ..io.files import Inputs, OutputKind, OutputRefused, check_not_input, output_kind

__all__ = ["Usage", "check_outputs", "check_save_rig", "track_inputs"]


class Usage(Exception):
    """A command-line mistake: the message says what to do; exit status 2."""


def _inside(path: Path, folder: Path) -> bool:
    """Whether resolved ``path`` is ``folder`` or lies inside it (both resolved)."""
    return path == folder or folder in path.parents


def track_inputs(args, spec: str | None = None, source=None, rig=None) -> Inputs:
    """What the run reads: the source's inputs (:func:`~headplod.capture.source_inputs`: by ``spec`` before it
    is opened, by ``source`` after), the rig in use, and ``--calib``, ``--markers``, ``--screen``."""
    inputs = source_inputs(spec, source)
    for r in (rig, getattr(source, "rig", None)):
        if r is not None and getattr(r, "path", None):
            inputs = inputs.file("the rig being read", r.path)
    for option, what in (("calib", "the rig being read"), ("markers", "the markers being read"),
                         ("screen", "the screen being read")):
        value = getattr(args, option, None)
        if value:
            inputs = inputs.file(f"{what} (--{option})", value)
    return inputs


def check_outputs(args, spec: str | None = None, source=None, rig=None) -> None:
    """Refuse ``--out`` and ``--record`` that are special files, overwrite what is read, or each other
    (raises Usage).

    Without ``source``: what the command line tells (each output's kind; ``--out`` is not a folder and its
    folder exists; ``--record`` is not a file, holds no recording unless ``--overwrite``; neither is, holds
    or lies inside an input the command line names). With it: what the source read, resolved. Nothing is
    written.
    """
    try:
        _check_outputs(args, track_inputs(args, spec, source, rig), opened=source is not None)
    except OutputRefused as exc:
        raise Usage(str(exc)) from None


def _check_outputs(args, inputs: Inputs, opened: bool) -> None:
    if args.out and output_kind(args.out, option="--out", stream=True) is not OutputKind.STDOUT:
        out = Path(args.out).expanduser()
        resolved = out.resolve()
        if not opened and not resolved.parent.is_dir():
            raise Usage(f"--out {args.out}: the folder {out.parent} does not exist; create it first")
        check_not_input(args.out, inputs, option="--out", fix="write the records elsewhere")
        if args.record:
            record = Path(args.record).expanduser().resolve()
            for entry in RECORDING_ENTRIES:
                if _inside(resolved, record / entry):
                    raise Usage(f"--out {args.out}: is the recording's own {entry} in --record {args.record}; "
                                 "write the records elsewhere")
    if args.record:
        target = Path(args.record).expanduser()
        record = target.resolve()
        if not opened:
            output_kind(args.record, option="--record", folder=True, entries=RECORDING_ENTRIES)
        # Before the --overwrite advice below: that would be refused too.
        check_not_input(args.record, inputs, option="--record", folder=True, fix="record into another folder")
        if not opened:
            held = recording_held(target)
            if held and not args.overwrite:
                raise Usage(f"--record {args.record}: {held}; choose another folder, or add --overwrite to "
                             "replace it")
            if args.overwrite and record in (Path.cwd().resolve(), Path.home().resolve(), Path(record.anchor)):
                raise Usage(f"--record {args.record}: is the current, home or root folder; record into a "
                             "folder of its own")
    elif args.overwrite:
        raise Usage("--overwrite goes with --record DIR (it replaces the recording in DIR)")


def check_save_rig(args, source=None, rig=None, spec=None) -> None:
    """Refuse a ``--save-rig FILE`` that is a special file or would overwrite what is read or written
    (raises Usage); nothing is written.

    Without ``source``: what the command line alone tells (FILE's kind, its folder exists; FILE is not,
    nor lies inside, an input the command line names, --out, or --record's folder). With it: nor what the
    source read.
    """
    if not args.save_rig:
        return
    if source is None and args.refine_rig == "off":
        raise Usage("--save-rig needs the rig refinement (--refine-rig on): there is nothing to save")
    try:
        if source is None:
            output_kind(args.save_rig, option="--save-rig")
            target = Path(args.save_rig).expanduser()
            if not target.resolve().parent.is_dir():
                raise Usage(f"--save-rig {args.save_rig}: the folder {target.parent} does not exist")
        inputs = track_inputs(args, spec, source, rig)
        if args.out and args.out != "-":
            inputs = inputs.file("the pose records (--out)", args.out)
        if args.record:
            inputs = inputs.folder("the --record folder (a recording keeps the rig it was tracked with)",
                                   args.record)
        check_not_input(args.save_rig, inputs, option="--save-rig", fix="write the refined rig elsewhere")
    except OutputRefused as exc:
        raise Usage(str(exc)) from None
