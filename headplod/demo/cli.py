"""``headplod demo``: the head-coupled PLOD terrain viewer, in a window or headless.

    headplod demo [--source SPEC | --mouse] [--mode csf] [--uncertainty adaptive] [--viewpoint overview]
    headplod demo --headless [--frames N] [--out DIR] [--size W,H] [--source SPEC | --mouse] [--foveate]
    headplod demo ... --terrain FILE [--spacing-m D] [--height-scale S]     (your own DEM or height map)
    headplod demo ... --max-level N [--lazy] [--cache-mb MB]               (finer than level 5: the lazy mesh)

Headless, the same loop as the window runs offscreen: for each named
viewpoint, the PLOD criterion (``--mode``, default csf) under each
uncertainty scenario, then ``full`` (every triangle at the finest level), each
for N frames of the same poses; it writes a few frames per run, a level-colour
picture per viewpoint with the POI and its 2σ ellipse, ``summary.json`` and
``summary.png``, and prints a table with each run's frame rate against
``full``'s on the same viewpoint. A pose source shorter than ``--frames``
(the built-in sequence has 150 frames, a recording its own) is not replayed:
the runs end with it, the table and ``summary.json`` say how many frames ran
(``frames_per_run``, with ``frames_asked``), and each run writes its last
frame. ``--out`` is checked before anything runs: a place no folder can be
made or filled is refused (exit 2); the folder is made when its first file is
written, and the table names only the folders written. With ``--foveate`` the mode's runs are
repeated with foveated resolution layers (:mod:`headplod.render.foveate`),
interleaved with the others, and a picture per viewpoint shows the layers.

``--max-level N`` (1..8, default 5) sets the finest level; above 5 the
scene's mesh is :class:`headplod.plod.lazy_mesh.LazyAdaptiveMesh`, one
piece cache shared by every run (``--cache-mb`` bounds it together).
``--backend raymask`` is refused with the lazy mesh (exit 2); at level 8 the
``full`` runs (134 M triangles) are skipped with a warning, as with
``--no-full``, and ``--mode full`` is refused.

Also runnable as ``python -m headplod.demo.cli``.
"""
from __future__ import annotations

import argparse
import errno
import json
import resource
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from .. import io
from ..io import ViewError, write_atomically
from ..io.files import Inputs, OutputRefused, check_output
from ..argtypes import add_quiet_argument, frame_count
from ..render.scene_command import (add_mesh_arguments, add_terrain_arguments, mesh_options, mesh_options_problem,
                                    terrain_for_command)
from ..progress import Progress, note
from .hud import ellipse_words
from .sheet import SheetEntry, contact_sheet
from ..render import TerrainRenderer, create_context
from ..plod.select import MODES
from ..render.command import (add_cost_arguments, add_csf_argument, add_gaze_prior_argument, raymask_config,
                              selection_options)
from ..render.frame import DEMO_BACKENDS, capability_table, default_mode, options_problem
from ..render.outputs import OutputNotWritable, check_writable
from ..render.still import FULL_MAX_LEVEL, default_head, mesh_stats
from . import loop as lp
from .keys import key_help
from .poses import make_poses
from .viewpoints import VIEWPOINTS
from .window import run_window

#: Frames written per run (as fractions of the run: the middle and the last).
_PNG_AT = (0.5, 1.0)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(float(v)) for v in text.replace("x", ",").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be W,H in pixels, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"size must lie between 16 and 8192 px per side, got {w}x{h}")
    return w, h


def _names(allowed):
    def parse(text: str) -> list[str]:
        names = [t.strip() for t in text.split(",") if t.strip()]
        bad = [n for n in names if n not in allowed]
        if bad or not names:
            raise argparse.ArgumentTypeError(f"expected a comma-separated subset of {', '.join(allowed)}, "
                                             f"got {text!r}")
        return names
    return parse


def _span(text: str) -> range:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:END frame numbers, got {text!r}") from None
    if not 0 <= a < b:
        raise argparse.ArgumentTypeError(f"need 0 <= START < END, got {text!r}")
    return range(a, b)


def add_demo_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``demo`` options to a (sub)parser; returns it."""
    parser.description = (
        "Head-coupled perceptual level of detail on the Jacksboro terrain, driven by the tracker "
        "(live cameras, a recording, the built-in synthetic sequence) or the mouse. Window keys: "
        + key_help(values=("mode", "uncertainty", "view_mode"), sep="; ")
        + ". Without a tracker (--mouse) the mouse moves the point of interest.")
    src = parser.add_argument_group("poses")
    src.add_argument("--source", default="synthetic", metavar="SPEC",
                     help="frame source tracked live: 'synthetic' (default: the built-in sequence), a dataset "
                          "folder, 'v4l2:/dev/video0,/dev/video2' or 'v4l2:auto' (the cameras --calib names), "
                          "or LEFT.avi,RIGHT.avi")
    src.add_argument("--calib", metavar="RIG.YAML", help="rig.yaml of live cameras (with --source v4l2:...)")
    src.add_argument("--mouse", action="store_true",
                     help="no tracker: the POI follows the mouse (headless: a scripted path with one saccade), "
                          "the eye 60 cm in front of the screen centre")
    src.add_argument("--dropout", type=_span, metavar="START:END",
                     help="simulate a tracking failure on frames START..END-1 of every run")
    src.add_argument("--growth", type=float, default=lp.GROWTH_DEG2_PER_S, metavar="DEG2_PER_S",
                     help=f"covariance growth while tracking is lost, deg²/s (default {lp.GROWTH_DEG2_PER_S:g})")
    view = parser.add_argument_group("view")
    view.add_argument("--backend", default="mesh", choices=DEMO_BACKENDS,
                      help="what draws the frames (default mesh; raymask: Murphy & Duchowski's rays, no levels); "
                           "what each supports is in the table below")
    view.add_argument("--mode", choices=MODES,
                      help="LOD criterion (window: the initial one; headless: the one compared with full; "
                           f"default: the back end's, mesh: {default_mode('mesh')}, raymask: csf)")
    add_cost_arguments(view)
    add_csf_argument(view)
    add_gaze_prior_argument(view)
    view.add_argument("--uncertainty", default="adaptive", choices=lp.SCENARIOS,
                      help="uncertainty scenario (window: initial; default adaptive)")
    view.add_argument("--viewpoint", default="overview", choices=tuple(VIEWPOINTS),
                      help="initial viewpoint of the window (default overview): " + "; ".join(
                          f"{v.name}: {v.description}" for v in VIEWPOINTS.values()))
    view.add_argument("--foveate", action="store_true",
                      help="draw foveated resolution layers about the filtered POI (window: on; headless: "
                           "the mode's runs again with them, against full and the plain runs)")
    view.add_argument("--view", default="shaded", choices=lp.VIEW_MODES, help="initial view (window; default shaded)")
    view.add_argument("--size", type=_size, default=(1280, 720), metavar="W,H",
                      help="render size, px (default 1280,720)")
    view.add_argument("--saccade-deg-s", type=float, default=lp.SACCADE_DEG_S,
                      help=f"POI speed above which levels are kept (default {lp.SACCADE_DEG_S:g} deg/s, Ohshima)")
    add_terrain_arguments(parser.add_argument_group("terrain"))
    add_mesh_arguments(parser.add_argument_group("mesh"))
    head = parser.add_argument_group("headless run")
    head.add_argument("--headless", action="store_true", help="run offscreen and write frames and a summary")
    head.add_argument("--frames", type=frame_count, default=30,
                      help="frames per run (default 30); a shorter pose source (the built-in sequence has 150) "
                           "ends the runs with it, and the table says how many frames ran")
    head.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    head.add_argument("--viewpoints", type=_names(tuple(VIEWPOINTS)), default=list(VIEWPOINTS),
                      help="comma-separated viewpoints to run (default all three)")
    head.add_argument("--scenarios", type=_names(lp.SCENARIOS), default=list(lp.SCENARIOS),
                      help="comma-separated uncertainty scenarios to run with --mode (default all four)")
    head.add_argument("--no-full", action="store_true", help="skip the 'full' runs (no frame-rate ratio)")
    add_quiet_argument(parser, help="no progress and no notes on standard error (headless: the table and the files "
                                    "still appear; errors always)")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = "what each back end supports:\n" + capability_table()
    return parser


# --------------------------------------------------------------------------
# headless
# --------------------------------------------------------------------------


def _interleaved(demos, frames: int):
    """Step the loops one frame each in turn, up to ``frames`` each; yields (loop index, FrameResult).

    Each round starts one loop further: the loop that runs right after a new
    pose is taken shares the CPU with the tracking thread, and this spreads
    that over all of them.
    """
    active = list(range(len(demos)))
    turn = 0
    while active:
        start = turn % len(active)
        for k in active[start:] + active[:start]:
            result = demos[k].step() if demos[k].index < frames else None
            if result is None:
                active.remove(k)
            else:
                yield k, result
        turn += 1


def resolve_mode(args) -> str:
    """Give ``args.mode`` its default (the back end's own, :func:`headplod.render.frame.default_mode`) when it is
    None; the back end's name."""
    backend = getattr(args, "backend", "mesh")
    if getattr(args, "mode", None) is None:
        args.mode = default_mode(backend)
    return backend


def run_headless(args, out=None, err=None, scene=None, renderer=None) -> dict:
    """The headless benchmark run; returns the summary (also written to ``args.out``).

    ``scene`` (a TerrainScene for the poses' screen) and ``renderer`` (at
    ``args.size``) may be passed in to reuse them (tests); they are made here
    otherwise, the renderer's context first (a broken EGL ends the run before
    the poses are opened or the mesh built, and before anything is written).
    ``out``, ``err``: the table's and the notes' streams (default: standard output and error as they are now).
    """
    out, err = out or sys.stdout, err or sys.stderr
    resolve_mode(args)
    start = time.perf_counter()
    if renderer is None:
        renderer = TerrainRenderer(create_context(), size=tuple(args.size))
    elif tuple(renderer.size) != tuple(args.size):
        raise ValueError(f"run_headless: the renderer is {renderer.size}, --size is {tuple(args.size)}")
    folder = Path(args.out)
    first = make_poses(args, frames=1)          # opens (and on first use renders) the source; gives the screen
    screen = first.screen
    source_name = first.name
    first.close()
    _check_screen_faces_viewer(screen, source_name)
    if scene is None:
        note(f"demo: building the terrain mesh; poses from {source_name}", stream=err)
    if scene is None:
        scene = mesh_options(args).build(screen, getattr(args, "terrain_loaded", None))
    groups = _plan(args)
    # One renderer per run of a group: each keeps its mesh on the GPU between its frames.
    renderers = [renderer] + [TerrainRenderer(renderer.ctx, size=tuple(args.size))
                              for _ in range(max(len(g) for g in groups) - 1)]
    progress = Progress(sum(len(g) for g in groups) * args.frames, "demo", stream=err)
    runs, pictures = [], {}
    try:
        for plan in groups:
            runs += _run_group(args, plan, scene, screen, renderers, folder, progress, pictures, source_name)
    finally:
        for extra in renderers[1:]:
            extra.release()
    ratios = _ratios(runs, args)
    summary = {"size": list(args.size), "frames_per_run": min(r["frames"] for r in runs),
               "frames_asked": args.frames, "poses": source_name,
               "mode": args.mode, "cost": selection_options(args),
               "viewpoints": {vp: VIEWPOINTS[vp].description for vp in args.viewpoints},
               "fps_ratio_to_full": ratios, "pictures": pictures, "runs": runs, "mesh": mesh_stats(scene.mesh),
               "rss_mb": round(_rss_mb(), 1),
               "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
               "notes": "per viewpoint, the runs are interleaved (one frame of each in turn) on one tracked "
                        "sequence; medians over each run's frames after its first (the first uploads the "
                        "mesh's vertex table and builds the mesh); frame = pose (waiting for the tracking "
                        "thread) + select + build + upload (indices) + render + readback + hud; upload is "
                        "skipped when the mesh did not change; with the lazy mesh (mesh.kind 'lazy') a frame "
                        "whose cases changed uploads its compact vertex table and indices",
               "wall_s": None}
    chart = folder / "summary.png"
    folder.mkdir(parents=True, exist_ok=True)
    write_chart(runs, args.viewpoints, chart, title=f"{args.size[0]}x{args.size[1]}, {source_name}")
    summary["chart"] = str(chart)
    summary["index"] = _write_png(folder / "index.png", index_sheet(pictures, chart, args, source_name))
    summary["wall_s"] = round(time.perf_counter() - start, 1)
    write_atomically(folder / "summary.json", lambda name: Path(name).write_text(json.dumps(summary, indent=1)))
    print_table(summary, out)
    return summary


def _check_screen_faces_viewer(screen, source_name: str) -> None:
    """ViewError unless the eye the loop falls back on (:func:`default_head`: 600 mm in front of the screen's
    centre, on the cameras' side) is in front of ``screen``: else every frame would fail (a screen.yaml whose
    corners are given as seen from behind)."""
    try:
        screen.check_eye(default_head(screen))
    except ViewError as exc:
        raise ViewError(f"the screen of {source_name} faces away from the cameras: the default eye, 600 mm in "
                        f"front of its centre on the cameras' side: {exc}; are its top_left, top_right and "
                        "bottom_left as the viewer sees them?") from None


def _plan(args) -> list:
    """Per viewpoint, the runs (viewpoint, mode, scenario, foveate): the scenarios, again foveated, then full.

    The runs of a group are interleaved (one frame of each in turn) on one tracked sequence: the same
    poses for all, and the speed ratios measured back to back.
    """
    groups = []
    for vp in args.viewpoints:
        plan = [(vp, args.mode, sc, False) for sc in args.scenarios]
        if getattr(args, "foveate", False):
            plan += [(vp, args.mode, sc, True) for sc in args.scenarios]
        if not args.no_full and args.mode != "full":
            plan.append((vp, "full", "none", False))
        groups.append(plan)
    return groups


def _run_group(args, plan, scene, screen, renderers, folder, progress, pictures, source_name) -> list:
    """Run one viewpoint's runs interleaved; their records (and pictures added to ``pictures``)."""
    keep = {max(0, int(round(f * args.frames)) - 1) for f in _PNG_AT}
    tee = lp.TeePoses(make_poses(args, screen=screen, frames=args.frames), len(plan))
    demos, written = [], []
    for k, (vp, mode, scenario, foveate) in enumerate(plan):
        backend = getattr(args, "backend", "mesh") if mode == args.mode else "mesh"
        demos.append(lp.DemoLoop(scene, tee.consumer(k), renderers[k], mode=mode, uncertainty=scenario,
                                 viewpoint=vp, view_mode="shaded", hud=True, saccade_deg_s=args.saccade_deg_s,
                                 growth_deg2_per_s=args.growth, foveate=foveate, backend=backend,
                                 raymask=raymask_config(args),
                                 # full is the reference: no bias, no budget
                                 selector_options=selection_options(args) if mode == args.mode else None))
        written.append([])
    stems = ["_".join(p[:3]) + ("_foveate" if p[3] else "") for p in plan]
    try:
        for k, result in _interleaved(demos, args.frames):
            if result.index in keep:
                written[k].append(_write_png(folder / "frames" / f"{stems[k]}_{result.index:03d}.png", result.image))
            progress.step(f"{stems[k]} {result.frame_ms:.0f} ms")
    finally:
        tee.close()
    records = []
    for k, (vp, mode, scenario, foveate) in enumerate(plan):
        demo = demos[k]
        if demo.last is None:
            raise RuntimeError(f"the pose source gave no frame ({source_name})")
        if demo.index < args.frames and keep and demo.last.index not in keep:   # the poses ended early
            written[k].append(_write_png(folder / "frames" / f"{stems[k]}_{demo.last.index:03d}.png",
                                         demo.last.image))
        _pictures(args, demo, vp, mode, scenario, foveate, folder, pictures)
        s = demo.stats
        mesh = {**mesh_stats(demo.base_scene.mesh), "cache_bytes_max": max(s.cache_bytes, default=None)}
        mesh.pop("cache_bytes", None)
        records.append({"viewpoint": vp, "mode": mode, "uncertainty": scenario, "foveate": foveate,
                        **s.summary(), "mesh": mesh,
                        "per_frame": {"frame_ms": [round(v, 3) for v in s.frame_ms],
                                      "triangles": [int(v) for v in s.triangles],
                                      **({"lazy": s.lazy, "cache_bytes": s.cache_bytes} if s.lazy else {}),
                                      "stage_ms": {name: [round(x, 3) for x in v] for name, v in s.stage_ms.items()}},
                        "frames_png": written[k]})
    return records


def _pictures(args, demo, vp, mode, scenario, foveate, folder, pictures) -> None:
    """A viewpoint's level-colour picture (and its layers' with --foveate), from the adaptive run or the first."""
    if foveate and (scenario == "adaptive" or f"{vp} foveate" not in pictures):
        path = folder / f"viewpoint_{vp}_layers.png"
        caption = (f"{vp}: {mode} --foveate, {scenario}, level colours; layer borders (scale), "
                   "POI and 2-sigma ellipse")
        pictures[f"{vp} foveate"] = _write_png(path, demo.picture("levels", caption))
    if mode == args.mode and not foveate and (scenario == "adaptive" or vp not in pictures):
        info = demo.hud_info(demo.last)
        caption = (f"{vp}: {mode}, {scenario}, level colours; "
                   f"{ellipse_words(info.cov_deg2, info.px_per_deg, args.size[1])}")
        path = folder / f"viewpoint_{vp}_levels.png"
        pictures[vp] = _write_png(path, demo.picture("levels", caption))


def _write_png(path: Path, image: np.ndarray) -> str:
    """Write ``image`` ((H, W, 3) uint8 RGB) to ``path`` (PNG, through memory: :func:`headplod.io.write_image`),
    its folder made first; the path as a string. OSError naming ``path`` when it cannot be written."""
    path.parent.mkdir(parents=True, exist_ok=True)
    io.write_image(path, cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return str(path)


def _ratios(runs, args) -> dict:
    """Each run's frame rate over full's on its viewpoint (in the records), and per viewpoint the mode's."""
    ratios = {}
    for run in runs:
        full = next((r for r in runs if r["viewpoint"] == run["viewpoint"] and r["mode"] == "full"), None)
        run["fps_ratio_to_full"] = None if full is None or run is full else run["fps"] / full["fps"]
    for vp in args.viewpoints:
        full = next((r for r in runs if r["viewpoint"] == vp and r["mode"] == "full"), None)
        for foveate in (False, True):
            mine = [r for r in runs if r["viewpoint"] == vp and r["mode"] == args.mode and r["foveate"] == foveate]
            if mine and full is not None:
                ref = next((r for r in mine if r["uncertainty"] == "adaptive"), mine[0])
                ratios[vp + (" foveate" if foveate else "")] = {
                    "mode": args.mode + (" --foveate" if foveate else ""), "uncertainty": ref["uncertainty"],
                    "fps": ref["fps"], "full_fps": full["fps"], "ratio": ref["fps"] / full["fps"],
                    "ratio_range": [min(r["fps"] for r in mine) / full["fps"],
                                    max(r["fps"] for r in mine) / full["fps"]]}
    return ratios


def _rss_mb() -> float:
    """This process's resident set size now, MB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2 ** 20


def print_table(summary: dict, out=None) -> None:
    """The short table of the runs, the csf/full ratio per viewpoint and where the pictures are (to ``out``;
    default: standard output)."""
    out = out or sys.stdout
    w, h = summary["size"]
    ran, asked = summary["frames_per_run"], summary.get("frames_asked", summary["frames_per_run"])
    short = f" (asked for {asked}: the poses ended after {ran})" if ran < asked else ""
    print(f"\nheadless demo, {w}x{h}, {ran} frames per run{short}, poses: {summary['poses']}", file=out)
    print(f"{'viewpoint':<10} {'mode':<8} {'scenario':<9} {'fps':>6} {'frame ms':>9} {'select':>7} {'build':>6} "
          f"{'render':>7} {'triangles':>10} {'x full':>7} {'saccade':>7} {'lost':>5}", file=out)
    for r in summary["runs"]:
        st = r["stage_ms_median"]
        ratio = "" if r["fps_ratio_to_full"] is None else f"{r['fps_ratio_to_full']:.1f}x"
        mode = r["mode"] + ("+fov" if r.get("foveate") else "")
        print(f"{r['viewpoint']:<10} {mode:<8} {r['uncertainty']:<9} {r['fps']:6.1f} {r['frame_ms_median']:9.1f} "
              f"{st['select']:7.1f} {st['build']:6.1f} {st['render']:7.1f} {int(r['triangles_median']):>10,} "
              f"{ratio:>7} {r['saccade_skipped']:>7} {r['tracking_failures']:>5}", file=out)
    for r in (r for r in summary["runs"] if r.get("budget")):
        b = r["budget"]
        missed = ""
        if b["missed_range"] is not None:
            lo, hi = b["missed_range"]
            missed = f"; missed: {lo:,}" + ("" if lo == hi else f"..{hi:,}") + " triangles" + (
                f", the {b['missed_limit']} their views allow" if b["missed_limit"] else "")
        print(f"{r['viewpoint']} {r['mode']} {r['uncertainty']}: budget {b['triangles']:,} met in {b['met_frames']} of "
              f"{r['frames']} frames{missed}", file=out)
    for vp, q in summary["fps_ratio_to_full"].items():
        lo, hi = q["ratio_range"]
        print(f"{vp}: {q['mode']} ({q['uncertainty']}) {q['fps']:.1f} fps against full {q['full_fps']:.2f} fps: "
              f"{q['ratio']:.1f}x (all scenarios {lo:.1f}-{hi:.1f}x)", file=out)
    for vp, path in summary["pictures"].items():
        print(f"picture {vp}: {path}", file=out)
    m = summary.get("mesh")
    if m is not None:
        cache = ""
        if m["kind"] == "lazy":
            peak = max((r["mesh"]["cache_bytes_max"] or 0) for r in summary["runs"])
            cache = f", piece cache at most {peak / 2 ** 20:.0f} of {m['cache_budget_bytes'] / 2 ** 20:.0f} MB"
        print(f"mesh: {m['kind']}, level {m['max_level']} ({m['full_triangles']:,} triangles at full detail)"
              f"{cache}; RSS {summary['rss_mb']:.0f} MB (peak {summary['peak_rss_mb']:.0f} MB)", file=out)
    folder = Path(summary["chart"]).parent
    frames = f"frames: {folder / 'frames'}/   " if any(r["frames_png"] for r in summary["runs"]) else ""
    print(f"{frames}summary: {folder / 'summary.json'}, {summary['chart']}   ({summary['wall_s']} s)", file=out)
    if summary.get("index"):
        print(f"index of the pictures, each labelled: {summary['index']}", file=out)


def index_sheet(pictures: dict, chart: Path, args, source_name: str) -> np.ndarray:
    """The contact sheet of a headless run's pictures (``pictures``: {viewpoint or 'VP foveate': path}) and its
    chart, each labelled with what it shows; (H, W, 3) uint8 RGB."""
    legend = ("Each triangle is coloured by its level of detail (legend bottom left: L0 coarsest .. "
              f"L{mesh_options(args).max_level} finest). Red cross: the "
              "tracked point of interest; red ellipse: its 2-sigma uncertainty (drawn at least a visible size).")
    entries = []
    for key, path in pictures.items():
        vp, _, foveate = key.partition(" ")
        what = VIEWPOINTS[vp].description
        extra = " Circles: the foveation layers' borders." if foveate else ""
        entries.append(SheetEntry(Path(path).name, f"The {vp} view: {what}. {legend}{extra}",
                                  cv2.cvtColor(io.read_image(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)))
    entries.append(SheetEntry(chart.name, "Frame time and triangles per frame of every run, per viewpoint: the "
                              "criterion under each uncertainty scenario, against full detail.",
                              cv2.cvtColor(io.read_image(chart, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)))
    return contact_sheet(entries, heading=f"headplod demo --headless: {args.size[0]}x{args.size[1]}, "
                                          f"poses from {source_name.split(' (')[0]}")


def write_chart(runs, viewpoints, path, title="") -> None:
    """summary.png: frame time and triangles per frame, per viewpoint, one line per run."""
    import matplotlib  # imported only when a chart is drawn (slow to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(viewpoints), figsize=(4.2 * len(viewpoints), 6.4), squeeze=False,
                             sharex=True)
    styles = {"none": "-", "fixed": "--", "adaptive": "-", "smoothed": ":"}
    for j, vp in enumerate(viewpoints):
        for r in (r for r in runs if r["viewpoint"] == vp):
            full = r["mode"] == "full"
            label = "full" if full else f"{r['mode']}{' --foveate' if r.get('foveate') else ''} {r['uncertainty']}"
            kw = {"color": "black", "lw": 1.6} if full else {"ls": styles.get(r["uncertainty"], "-"), "lw": 1.2}
            x = np.arange(len(r["per_frame"]["frame_ms"]))
            axes[0, j].plot(x, r["per_frame"]["frame_ms"], label=label, **kw)
            axes[1, j].plot(x, r["per_frame"]["triangles"], label=label, **kw)
        axes[0, j].set_title(f"{vp}: {VIEWPOINTS[vp].description}", fontsize=8)
        axes[0, j].set_yscale("log")
        axes[1, j].set_yscale("log")
        axes[1, j].set_xlabel("frame")
        axes[0, j].grid(True, which="both", alpha=0.3)
        axes[1, j].grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel("frame time, ms")
    axes[1, 0].set_ylabel("triangles")
    axes[0, -1].legend(fontsize=7)
    fig.suptitle(f"headplod demo: frame time and triangles per frame ({title})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------
# entry points
# --------------------------------------------------------------------------


#: What a headless run writes in ``--out DIR`` (the other files there are left alone).
OUT_ENTRIES = ("frames", "summary.json", "summary.png", "index.png", "viewpoint_*.png")


def _out_problem(args) -> str | None:
    """Why the headless ``--out DIR`` may not be written (:mod:`headplod.io.files`: not a folder, a special
    file where it writes, inside a folder being read or holding a file read), or None."""
    from ..live.track_checks import track_inputs     # on use, as the tracker's other parts

    inputs = Inputs() if getattr(args, "mouse", False) else track_inputs(args, args.source)
    if getattr(args, "terrain", None):
        inputs = inputs.file("the terrain being read (--terrain)", args.terrain)
    try:
        check_output(args.out, inputs, option="--out", folder=True, entries=OUT_ENTRIES)
    except OutputRefused as exc:
        return str(exc)
    return None


def run_demo(args) -> int:
    """Run ``headplod demo`` from parsed arguments; the exit status."""
    if args.frames < 1:
        print("headplod demo: --frames must be at least 1", file=sys.stderr)
        return 2
    backend = resolve_mode(args)
    problem = options_problem(backend, mode=args.mode, uncertainty=args.uncertainty, view_mode=args.view,
                              foveate=args.foveate, level_bias=getattr(args, "level_bias", 0.0) != 0.0,
                              budget=getattr(args, "budget", None) is not None, csf=args.csf)
    problem = problem or mesh_options_problem(args, backend, args.mode)
    if problem:
        print(f"headplod demo: {problem}", file=sys.stderr)
        return 2
    max_level = mesh_options(args).max_level
    if args.headless and max_level > FULL_MAX_LEVEL and not args.no_full:
        print(f"headplod demo: warning: full at --max-level {max_level} would draw {2048 * 4 ** max_level:,} "
              f"triangles, which do not fit; the full runs are skipped (as --no-full: no ratio to full)",
              file=sys.stderr)
        args.no_full = True
    if args.headless:                   # where it writes, before anything runs
        try:
            check_writable(args.out, folder=True)
            _check_out_entries(Path(args.out), args.viewpoints)
        except OutputNotWritable as exc:
            print(f"headplod demo: --out {args.out}: {exc}", file=sys.stderr)
            return 2
    # The terrain file is read (and any problem reported) before anything is written; None: the built-in one.
    args.terrain_loaded, status = terrain_for_command(args, "headplod demo")
    if status is not None:
        return status
    problem = _out_problem(args) if args.headless else None
    if problem:
        print(f"headplod demo: {problem}", file=sys.stderr)
        return 2
    try:
        if args.headless:
            run_headless(args)
            return 0
        return run_window(args)
    except (io.ContractError, OSError, ValueError, RuntimeError) as exc:
        print(f"headplod demo: {exc}", file=sys.stderr)
        return 1


def _check_out_entries(folder: Path, viewpoints) -> None:
    """OutputNotWritable when what the headless run writes in ``folder`` is in the way: a folder where it writes a
    file (``summary.json``, ``summary.png``, a viewpoint's picture), or a file where it makes ``frames/``."""
    files = ["summary.json", "summary.png", "index.png"] + [f"viewpoint_{vp}_{kind}.png" for vp in viewpoints
                                               for kind in ("levels", "layers")]
    for name in files:
        if (folder / name).is_dir():
            raise OutputNotWritable(f"cannot be written: {folder / name} is a folder, where the demo writes a file")
    frames = folder / "frames"
    if (frames.exists() or frames.is_symlink()) and not frames.is_dir():
        raise OutputNotWritable(f"cannot be written: {frames} is a file, where the demo makes its frames' folder")


def main(argv=None) -> int:
    parser = add_demo_arguments(argparse.ArgumentParser(prog="headplod demo"))
    return run_demo(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
