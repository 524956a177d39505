"""The renderer's command line, one parser for ``python -m synthetic render`` and ``headplod synth``.

    python -m synthetic render PRESET OUT_DIR [--frames N] [--seed S] [-q]
    python -m synthetic list
    headplod synth PRESET OUT_DIR [--frames N] [--seed S] [-q]      (the same arguments and run)

:func:`add_render_arguments` adds the arguments of ``render`` to a parser and
:func:`run_render` runs it, so ``headplod synth`` (``headplod/cli.py``) is this
command under another name. Progress (frames, rate) goes to standard error
through tqdm, silent with ``-q``.
"""
from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from .scenes import PRESETS, make_scene, preset_name

__all__ = ["add_render_arguments", "run_render", "build_parser", "main"]


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


def add_render_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``render``'s arguments to a (sub)parser; returns it."""
    parser.add_argument("preset", type=_preset, metavar="PRESET", help="one of: " + ", ".join(PRESETS))
    parser.add_argument("out_dir", metavar="OUT_DIR", help="dataset folder to write (created)")
    parser.add_argument("--frames", type=_frames, default=None, help="number of frames (preset default)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene and of the noise")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on standard error")
    return parser


def run_render(args: argparse.Namespace) -> int:
    """Render ``args.preset`` into ``args.out_dir``; the exit status."""
    # Imported on use: the renderer's modules are not needed to parse (or to print --help).
    from .dataset import write_dataset

    scene = make_scene(args.preset, n_frames=args.frames, seed=args.seed)
    print(f"{scene.name}: {scene.description}; {scene.n_frames} frames "
          f"{scene.setup.image_size[0]}x{scene.setup.image_size[1]} -> {args.out_dir}")
    bar = tqdm(total=scene.n_frames, desc=f"render {scene.name}", unit="frame", file=sys.stderr,
               disable=args.quiet, mininterval=0.5)

    def progress(done: int, total: int) -> None:
        bar.update(done - bar.n)

    try:
        write_dataset(args.out_dir, scene, seed=args.seed, progress=progress)
    finally:
        bar.close()
    if not args.quiet:
        print(f"wrote {scene.n_frames} stereo pairs to {args.out_dir}", file=sys.stderr)
    return 0


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
