"""``headplod render``: its arguments (:func:`add_render_arguments`) and its run (:func:`run_render`).

    headplod render --mode MODE|raymask [--inset-deg D] [--no-silhouettes] [--uncertainty U] [--head X,Y,Z] [--poi X,Y] [--cov PP,PT,TT]
                    [--size W,H] [--view shaded|wire|levels] --out IMAGE.png [--stats STATS.json]
                    [--export MESH.glb|.ply|.obj|.stl]
                    [--terrain DEM.tif|HEIGHTS.png|HEIGHTS.npy [--spacing-m D|DX,DY] [--height-scale S]]

Exit status: 0 on success, 1 on a broken input file, 2 on bad usage.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from calib import DEFAULT_SCREEN

from .. import io
from ..plod.export import check_export_path
from ..argtypes import floats
from ..plod.raymask import RayMaskConfig
from ..plod.terrain_file import TerrainUsageError, add_terrain_arguments, terrain_from_args
from ..plod.select import UNCERTAINTY_MODES
from .gl import VIEW_MODES
from .still import CONTRAST_SOURCES, RENDER_MODES, TerrainScene, render_still

__all__ = ["add_render_arguments", "run_render"]


def add_render_arguments(render: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``render``'s options to a (sub)parser; returns it."""
    render.add_argument("--mode", default="csf", choices=RENDER_MODES,
                        help="a level-selection mode, or raymask: Murphy & Duchowski's rays through a CSF ray mask")
    render.add_argument("--uncertainty", default="adaptive", choices=UNCERTAINTY_MODES)
    render.add_argument("--head", type=floats(3), help="eye position X,Y,Z in the world frame, mm "
                                                         "(default: 600 mm in front of the screen centre)")
    render.add_argument("--poi", type=floats(2), help="point of interest X,Y in screen pixels (default: centre)")
    render.add_argument("--cov", type=floats(3), help="covariance of (φ, θ) as PP,PT,TT in deg²")
    render.add_argument("--size", type=floats(2), default=(1280, 720), help="image size W,H (default 1280,720)")
    render.add_argument("--view", default="shaded", choices=tuple(VIEW_MODES))
    render.add_argument("--screen", help="screen.yaml (default: the embedded 24-inch screen)")
    render.add_argument("--contrast", choices=CONTRAST_SOURCES, default="shading",
                        help="triangle contrast: from the shading, no read-back (default), or the paper's "
                             "10x10 window read back from a first frame")
    render.add_argument("--foveate", action="store_true",
                        help="draw the frame as nested resolution layers around the POI, each as dense as the CSF "
                             "needs there (experimental: on llvmpipe the layers' extra geometry passes cost more "
                             "than the pixels they save)")
    render.add_argument("--inset-deg", type=float, default=RayMaskConfig.inset_deg,
                        help="raymask: diameter of the full-resolution inset around the POI, deg (default 5, 0..30)")
    render.add_argument("--no-silhouettes", action="store_true",
                        help="raymask: rasterise the quads that straddle a silhouette instead of casting "
                             "every pixel in them")
    render.add_argument("--out", required=True, help="output image (PNG)")
    render.add_argument("--stats", help="write triangles, select/build/render ms and per-level counts (JSON)")
    render.add_argument("--export", metavar="MESH", help="also write the frame's PLOD mesh (.glb, .ply, .obj or .stl; "
                                                         "scene metres, faces coloured by level)")
    add_terrain_arguments(render)
    return render


def run_render(args) -> int:
    """Run ``headplod render`` from parsed arguments; the exit status."""
    screen = io.read_screen(args.screen or DEFAULT_SCREEN)
    cov = None
    if args.cov is not None:
        pp, pt, tt = args.cov
        cov = np.array([[pp, pt], [pt, tt]])
        if np.any(np.linalg.eigvalsh(cov) <= 0):
            print(f"headplod: --cov {args.cov} is not positive definite", file=sys.stderr)
            return 2
    size = tuple(int(v) for v in args.size)
    if args.export is not None:
        try:
            check_export_path(args.export)
        except ValueError as exc:
            print(f"headplod: --export {exc}", file=sys.stderr)
            return 2
    raymask = None
    if args.mode == "raymask":
        bad = [name for name, on in (("--foveate", args.foveate), ("--export", args.export is not None),
                                     ("--contrast readback", args.contrast != "shading"),
                                     (f"--view {args.view}", args.view != "shaded")) if on]
        if bad:
            print(f"headplod: --mode raymask does not take {', '.join(bad)}", file=sys.stderr)
            return 2
        try:
            raymask = RayMaskConfig(inset_deg=args.inset_deg, silhouettes=not args.no_silhouettes)
        except ValueError as exc:
            print(f"headplod: --inset-deg: {exc}", file=sys.stderr)
            return 2
    try:        # the terrain file is read (and any problem reported) before anything is written
        terrain = terrain_from_args(args)
    except TerrainUsageError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"headplod: --terrain {exc}", file=sys.stderr)
        return 1
    scene = None if terrain is None else TerrainScene.build(screen, terrain=terrain)
    _, stats = render_still(screen, mode=args.mode, uncertainty=args.uncertainty, head_mm=args.head,
                            poi_px=args.poi, cov_deg2=cov, size=size, view_mode=args.view, out=args.out,
                            stats_path=args.stats, contrast=args.contrast, export=args.export,
                            foveate=args.foveate, raymask=raymask, scene=scene)
    if "raymask" in stats:
        r = stats["raymask"]
        print(f"{r['rays']} rays ({r['fill_rays']} inset, {r['ring_rays']} rings, {r['silhouette_rays']} in "
              f"{r['silhouette_quads']} silhouette quads), {stats['triangles']} triangles; mask "
              f"{stats['select_ms']:.1f} ms, render {stats['render_ms']:.1f} ms; image: {args.out}", file=sys.stderr)
        return 0
    print(f"{stats['triangles']} triangles; select {stats['select_ms']:.1f} ms, build {stats['build_ms']:.1f} ms, "
          f"render {stats['render_ms']:.1f} ms; image: {args.out}"
          + (f"; mesh: {args.export}" if args.export else ""), file=sys.stderr)
    return 0
