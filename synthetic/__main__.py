"""Command line: ``python -m synthetic render PRESET OUT_DIR [--frames N] [--seed S]``.

Other commands: ``python -m synthetic list`` prints the presets.
"""
from __future__ import annotations

import argparse
import sys

from .dataset import _print_progress, write_dataset
from .scenes import PRESETS, make_scene


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m synthetic", description="synthetic IR stereo datasets")
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("render", help="render a preset into a dataset folder")
    r.add_argument("preset", help="one of: " + ", ".join(PRESETS))
    r.add_argument("out_dir")
    r.add_argument("--frames", type=int, default=None, help="number of frames (preset default)")
    r.add_argument("--seed", type=int, default=0, help="seed of the scene and of the noise")
    sub.add_parser("list", help="list the presets")
    a = ap.parse_args(argv)
    if a.cmd == "list":
        for name in PRESETS:
            sc = make_scene(name, n_frames=2)
            print(f"{name:16s} {sc.description}")
        return 0
    try:
        scene = make_scene(a.preset, n_frames=a.frames, seed=a.seed)
    except KeyError as e:
        print(e.args[0], file=sys.stderr)
        return 2
    print(f"{scene.name}: {scene.description}; {scene.n_frames} frames "
          f"{scene.setup.image_size[0]}x{scene.setup.image_size[1]} -> {a.out_dir}")
    write_dataset(a.out_dir, scene, seed=a.seed, progress=_print_progress("  "))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
