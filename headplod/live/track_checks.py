"""The checks ``headplod track`` makes before its first frame: no output (``--out``, ``--record``,
``--save-rig``) may overwrite what the run reads (the dataset folder, the videos, the rig, the marker
and screen files) or another output. They read the file system and write nothing; a refusal is a
:class:`Usage` error (exit status 2) whose message says what to do. Paths are compared resolved.
"""
from __future__ import annotations

from pathlib import Path

from ..capture import RECORDING_ENTRIES, recording_held, source_kind, synthetic_preset

__all__ = ["Usage", "check_outputs", "check_save_rig"]


class Usage(Exception):
    """A command-line mistake: the message says what to do; exit status 2."""


def _inside(path: Path, folder: Path) -> bool:
    """Whether resolved ``path`` is ``folder`` or lies inside it (both resolved)."""
    return path == folder or folder in path.parents


def _source_inputs(spec: str | None = None, source=None, rig=None) -> tuple[list, list]:
    """What the source reads: ([(what, file)], [(what, folder)]), paths resolved."""
    files, folders = [], []
    if spec is not None and source_kind(spec) != "v4l2" and synthetic_preset(spec) is None:
        if Path(spec).expanduser().is_dir():
            folders.append(("the dataset folder being read", spec))
        elif "," in spec:
            files += [("a video being read", part) for part in spec.split(",")]
    if source is not None:
        dataset = getattr(source, "dataset", None)
        if dataset is not None:
            folders.append(("the dataset folder being read", dataset.folder))
        for r in (rig, getattr(source, "rig", None)):
            if r is not None and getattr(r, "path", None):
                files.append(("the rig being read", r.path))
    return _resolved(files), _resolved(folders)


def _resolved(items: list) -> list:
    return [(what, Path(path).expanduser().resolve()) for what, path in items]


def check_outputs(args, spec: str | None = None, source=None, rig=None) -> None:
    """Refuse ``--out`` and ``--record`` that would overwrite what is read, or each other (raises Usage).

    Without ``source``: what the command line tells (``--out`` is not a
    folder and its folder exists; ``--record`` is not a file, holds no
    recording unless ``--overwrite``; neither is an input named on the
    command line). With it: the dataset folder and the rig the source read.
    Nothing is written.
    """
    files, folders = _source_inputs(spec, source, rig)
    if source is None:
        files += [(f"the {name} being read", Path(value).expanduser().resolve())
                  for name, value in (("--calib", args.calib), ("--markers", args.markers),
                                      ("--screen", args.screen)) if value]
    if args.out and args.out != "-":
        out = Path(args.out).expanduser()
        resolved = out.resolve()
        if source is None:
            if out.is_dir():
                raise Usage(f"--out {args.out}: is a folder; give the file to write, e.g. {out / 'poses.jsonl'}")
            if not resolved.parent.is_dir():
                raise Usage(f"--out {args.out}: the folder {out.parent} does not exist; create it first")
        for what, path in files:
            if resolved == path:
                raise Usage(f"--out {args.out}: is {what}, which is never overwritten; give another file name")
        for what, folder in folders:
            if _inside(resolved, folder):
                raise Usage(f"--out {args.out}: lies inside {what} ({folder}), which is never written to; "
                             "write the records elsewhere")
        if args.record:
            record = Path(args.record).expanduser().resolve()
            for entry in RECORDING_ENTRIES:
                if _inside(resolved, record / entry):
                    raise Usage(f"--out {args.out}: is the recording's own {entry} in --record {args.record}; "
                                 "write the records elsewhere")
    if args.record:
        target = Path(args.record).expanduser()
        record = target.resolve()
        for what, folder in folders:                # before the --overwrite advice: that would be refused too
            if _inside(record, folder) or _inside(folder, record):
                relation = "is" if record == folder else "lies inside" if _inside(record, folder) else "holds"
                raise Usage(f"--record {args.record}: {relation} {what} ({folder}); record into another folder")
        if source is None:
            if target.exists() and not target.is_dir():
                raise Usage(f"--record {args.record}: is a file; give a folder for the recording")
            held = recording_held(target)
            if held and not args.overwrite:
                raise Usage(f"--record {args.record}: {held}; choose another folder, or add --overwrite to "
                             "replace it")
            if args.overwrite and record in (Path.cwd().resolve(), Path.home().resolve(), Path(record.anchor)):
                raise Usage(f"--record {args.record}: is the current, home or root folder; record into a "
                             "folder of its own")
        for what, path in files:
            if _inside(path, record):
                raise Usage(f"--record {args.record}: holds {what} ({path}); record into another folder")
    elif args.overwrite:
        raise Usage("--overwrite goes with --record DIR (it replaces the recording in DIR)")


def check_save_rig(args, source=None, rig=None, spec=None) -> None:
    """Refuse a ``--save-rig FILE`` that would overwrite what is read (raises Usage); nothing is written.

    Without ``source``: what the command line alone tells (the folder of FILE
    exists; FILE is not --calib, --out, a dataset folder given as the source
    ``spec`` or --record's folder, nor inside them). With it: not the rig.yaml
    the source read, nor inside its dataset folder.
    """
    if not args.save_rig:
        return
    target = Path(args.save_rig).expanduser()
    resolved = target.resolve()
    if source is None:
        if args.refine_rig == "off":
            raise Usage("--save-rig needs the rig refinement (--refine-rig on): there is nothing to save")
        if target.is_dir():
            raise Usage(f"--save-rig {args.save_rig}: is a folder; give the file to write, e.g. "
                         f"{target / 'rig_refined.yaml'}")
        if not resolved.parent.is_dir():
            raise Usage(f"--save-rig {args.save_rig}: the folder {target.parent} does not exist")
    files, folders = [], []
    if source is None:
        if args.calib:
            files.append(("the rig being read (--calib)", args.calib))
        if args.out and args.out != "-":
            files.append(("the pose records (--out)", args.out))
        if spec and Path(spec).is_dir():
            files.append(("the rig being read (the dataset's)", Path(spec) / "rig.yaml"))
            folders.append(("the dataset folder being read", spec))
        if args.record:
            folders.append(("the --record folder (a recording keeps the rig it was tracked with)", args.record))
    else:
        for r in (rig, getattr(source, "rig", None)):
            if r is not None and getattr(r, "path", None):
                files.append(("the rig being read", r.path))
        dataset = getattr(source, "dataset", None)
        if dataset is not None:
            folders.append(("the dataset folder being read", dataset.folder))
    for what, path in files:
        if _same_file(resolved, Path(path)):
            raise Usage(f"--save-rig {args.save_rig}: is {what}, which is never overwritten; "
                         "give another file name")
    for what, folder in folders:
        folder = Path(folder).expanduser().resolve()
        if resolved == folder or folder in resolved.parents:
            raise Usage(f"--save-rig {args.save_rig}: lies inside {what} ({folder}); "
                         "write the refined rig elsewhere")


def _same_file(a: Path, b: Path) -> bool:
    b = Path(b).expanduser()
    if a == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and a.samefile(b)
    except OSError:
        return False
