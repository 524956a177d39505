"""``headplod bench``: its subcommands' arguments (:func:`add_bench_arguments`) and dispatch (:func:`run_bench`).

Each benchmark is a module of this package; this one only parses and dispatches. ``bench live`` names its
recording with ``--source`` (the old positional RECORDING still works for one release, with a note).
"""
from __future__ import annotations

import argparse
import sys

from ..argtypes import add_quiet_argument, frame_count, non_negative, note_old_spelling
from ..capture import source_inputs, source_kind, synthetic_preset
from ..capture.synthetic import ensure_dataset
from ..io.files import Inputs, OutputRefused, check_files
from ..render.scene_command import add_terrain_arguments, terrain_for_command
from ..render.command import add_cost_arguments, add_gaze_prior_argument, selection_options

__all__ = ["add_bench_arguments", "run_bench", "BENCHMARKS"]


def add_bench_arguments(bench: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``bench`` subcommands and their options to a (sub)parser; returns it."""
    add_quiet_argument(bench, help="no progress and no notes on standard error (the results, the files and errors "
                                   "still appear); also after the benchmark's name")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    bt = bench_sub.add_parser("track", help="tracker accuracy and per-stage time on synthetic sets")
    bt.add_argument("--json", help="write the results as JSON")
    bt.add_argument("--chart", help="write the accuracy-against-time chart (PNG); the imperfect-rig sets' "
                                    "chart goes beside it as FILE_rig.png (in its place when only they run)")
    bt.add_argument("--quick", action="store_true", help="fewer frames (a smoke run)")
    bt.add_argument("--sets", help="comma-separated names of the sets to run (default: all); "
                                   "see headplod.bench.track.TRACK_SETS and headplod.bench.rig.RIG_SETS")

    bc = bench_sub.add_parser("clutter", help="per-frame time by stage and the identification's hypotheses against "
                                              "the blobs per image (5 to 60), tracking and acquiring every frame")
    bc.add_argument("--json", help="write the results as JSON")
    bc.add_argument("--chart", help="write the chart (PNG): time by stage and hypotheses against blobs per image")
    bc.add_argument("--quick", action="store_true", help="two frames per blob count (a smoke run)")
    bc.add_argument("--blobs", metavar="LIST", help="comma-separated blobs per image, each ≥ 5 (default "
                                                    "5,10,20,30,45,60; 5: the markers alone)")

    bu = bench_sub.add_parser("uncertainty", help="calibration (NEES), stability and cost of the covariance of V")
    bu.add_argument("--json", help="write the results as JSON")
    bu.add_argument("--chart", help="write the NEES/stability chart (PNG; a second chart *_paper.png "
                                    "reproduces the paper's Fig. 10 and 17)")
    bu.add_argument("--quick", action="store_true", help="fewer frames (a smoke run)")

    bl = bench_sub.add_parser("live", help="rate, latency and capture-layer cost of tracking a replayed recording")
    bl.add_argument("--source", metavar="SPEC",
                    help="the recording to replay: a dataset folder or 'synthetic[:PRESET]' (default: the "
                         "built-in sequence)")
    bl.add_argument("dataset", nargs="?", metavar="RECORDING",
                    help="old spelling of --source RECORDING (goes in the next release)")
    bl.add_argument("--json", help="write the results as JSON")
    bl.add_argument("--repeats", type=int, default=3, help="passes over the recording (default 3)")
    bl.add_argument("--camera-hz", type=float, default=120.0, metavar="HZ",
                    help="the camera case: the rate at which the cluttered recording (glints_lamp, 640x480) is "
                         "delivered to the capture thread's drop-oldest mailbox (default 120)")
    bl.add_argument("--camera-frames", type=frame_count, default=360, metavar="N",
                    help="the camera case: frames of its recording (default 360, 3 s at 120 Hz)")

    bp = bench_sub.add_parser("plod", help="speed and image quality of the LOD modes against full (1280x720)")
    bp.add_argument("--json", help="write the results as JSON")
    bp.add_argument("--chart", help="write the chart (PNG); the level-colour pictures go beside it")
    bp.add_argument("--quick", action="store_true", help="fewer points on the curves and sweeps (a smoke run)")
    part1 = bp.add_argument_group("every mode's cost and gaze prior (part 1: the modes at the default view)")
    add_cost_arguments(part1)
    add_gaze_prior_argument(part1)
    bp.add_argument("--vdp", nargs="?", const="fvvdp", metavar="METRICS",
                    help="also judge every mode and CSF form with a visible-difference predictor, JOD against frame "
                         "time: fvvdp (FovVideoVDP, foveated on the POI; the default) and/or cvvdp (ColorVideoVDP, "
                         "not foveated), comma-separated; needs the optional extra: pip install -e '.[vdp]'")
    add_terrain_arguments(bp.add_argument_group(
        "the judge's terrain (--vdp or --only judge): every view of it at equal triangles, framed as "
        "'headplod render --terrain' frames it"))
    bp.add_argument("--scale", action="store_true",
                    help="instead: cost against terrain size (2M-134M triangles), tessellation back end and full "
                         "(headplod.bench.plod_scale)")
    bp.add_argument("--only", choices=("foveate", "raymask", "judge", "gaze") + tuple(_PLOD_PARTS),
                    help="instead: only the foveated layers' part (headplod.bench.plod_foveate), the ray mask's "
                         "(headplod.bench.plod_raymask) or the perceptual judge's (--vdp's metrics, default "
                         "fvvdp; with the judge at the true gaze); gaze: only the judge at the true gaze, the "
                         "held-out terrains and views on the desk and the wide screen (headplod.bench.plod_gaze); "
                         "--json gets its report, its charts and pictures go into the folder of --chart. "
                         "Or: lazy, the level-8 lazy mesh against the level-5 one, each in its own process "
                         "(headplod.bench.plod_lazy); quadtree, the flat against the quadtree selection's time on "
                         "base grids of 32² to 512² quads (headplod.bench.plod_quadtree; --chart: its chart)")

    bs = bench_sub.add_parser("stability", help="level changes per frame of a still head through the real tracker, "
                                                "against the true pose")
    bs.add_argument("--frames", type=frame_count, default=60, help="frames of the still head (default 60)")
    bs.add_argument("--distance", type=float, default=600.0, metavar="MM", help="head distance, mm (default 600)")
    bs.add_argument("--seed", type=int, default=0, help="image noise seed (default 0)")
    bs.add_argument("--modes", default="csf", help="comma-separated selection modes, or 'all' (default csf)")
    bs.add_argument("--json", help="write the report as JSON")
    bs.add_argument("--chart", help="write the chart (PNG)")

    bpa = bench_sub.add_parser("paper", help="Martinez et al.'s Tables 1-4 (uncertainty scenarios) under the "
                                             "paper's tracker conditions")
    bpa.add_argument("--json", help="write the results as JSON")
    bpa.add_argument("--chart", help="write the chart (PNG); the true-POI chart goes beside it as FILE_truepoi.png")
    bpa.add_argument("--quick", action="store_true", help="one viewpoint, 30 frames (a smoke run)")
    bpa.add_argument("--noise-deg", type=non_negative, default=0.5, metavar="S",
                     help="sigma per angle of the 'honest' and 'overconfident' trackers' jitter of V, deg "
                          "(default 0.5)")
    bpa.add_argument("--conditions", metavar="LIST",
                     help="comma-separated tracker conditions (default today,honest,overconfident; also "
                          "paper_estimator, the paper's covariance estimator, slow)")
    bpa.add_argument("--vdp", action="store_true",
                     help="also judge each frame with FovVideoVDP fixated at the true POI (slow); needs the "
                          "optional extra: pip install -e '.[vdp]'")
    add_gaze_prior_argument(bpa)
    for parser in bench_sub.choices.values():
        add_quiet_argument(parser, below=True)
    return bench


# The benchmark modules are imported on use: they pull in the tracker (scipy.stats) and matplotlib,
# and `headplod --help` imports this module.

def _track(args) -> int:
    from . import track
    sets = [x.strip() for x in args.sets.split(",")] if args.sets else None
    return track.run_track_bench(json_path=args.json, chart_path=args.chart, quick=args.quick, sets=sets)


def _clutter(args) -> int:
    from . import clutter
    try:
        blobs = clutter.parse_blobs(args.blobs) if args.blobs else None
    except ValueError as exc:
        print(f"headplod: bench clutter {exc}", file=sys.stderr)
        return 2
    return clutter.run_clutter_bench(json_path=args.json, chart_path=args.chart, quick=args.quick, blobs=blobs)


def _uncertainty(args) -> int:
    from . import uncertainty
    return uncertainty.run_uncertainty_bench(json_path=args.json, chart_path=args.chart, quick=args.quick)


def _plod_lazy(args) -> int:
    from . import plod_lazy
    return plod_lazy.run_lazy_bench(json_path=args.json, quick=args.quick)


def _plod_quadtree(args) -> int:
    from . import plod_quadtree
    return plod_quadtree.run_quadtree_bench(json_path=args.json, chart_path=args.chart, quick=args.quick)


#: ``headplod bench plod --only NAME`` for the parts that are benchmarks of their own (not in ``bench.plod``).
_PLOD_PARTS = {"lazy": _plod_lazy, "quadtree": _plod_quadtree}


def _plod(args) -> int:
    vdp = tuple(m for m in args.vdp.split(",") if m) if getattr(args, "vdp", None) else ()
    only = getattr(args, "only", None)
    terrain, label = None, None
    if any(getattr(args, k, None) is not None for k in ("terrain", "spacing_m", "height_scale")):
        if args.scale or only not in (None, "judge") or not (vdp or only == "judge"):
            print("headplod: bench plod --terrain FILE is the judge's terrain: give it with --vdp or --only judge",
                  file=sys.stderr)
            return 2
        terrain, status = terrain_for_command(args, "headplod")     # read (and checked) before the long run
        if status is not None:
            return 2
        label = str(args.terrain)
    if args.scale:
        from . import plod_scale
        return plod_scale.run_scale_bench(json_path=args.json, chart_path=args.chart, quick=args.quick)
    if only in _PLOD_PARTS:
        return _PLOD_PARTS[only](args)
    from . import plod
    return plod.run_plod_bench(json_path=args.json, chart_path=args.chart, quick=args.quick, vdp=vdp,
                               only=only, cost=selection_options(args), terrain=terrain, terrain_label=label)


def _stability(args) -> int:
    from . import stability
    try:
        return stability.run_stability_bench(args.json, args.chart, frames=args.frames, distance_mm=args.distance,
                                             seed=args.seed, modes=[m for m in args.modes.split(",") if m])
    except ValueError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2


def _paper(args) -> int:
    from . import paper_tables
    conditions = (tuple(c.strip() for c in args.conditions.split(",") if c.strip()) if args.conditions
                  else paper_tables.CONDITIONS)
    unknown = [c for c in conditions if c not in paper_tables.ALL_CONDITIONS]
    if unknown or not conditions:
        print(f"headplod: bench paper --conditions: {', '.join(unknown) or 'none given'}; choose from "
              f"{', '.join(paper_tables.ALL_CONDITIONS)}", file=sys.stderr)
        return 2
    return paper_tables.run_paper_bench(json_path=args.json, chart_path=args.chart, quick=args.quick,
                                        noise_deg=args.noise_deg, vdp=args.vdp, conditions=conditions,
                                        gaze_prior_deg=args.gaze_prior)


def _live(args) -> int:
    from . import live
    if args.source and args.dataset:
        print("headplod: the recording is named twice (--source and RECORDING); give it once, as --source SPEC",
              file=sys.stderr)
        return 2
    spec = args.source
    if args.dataset:
        note_old_spelling(f"'headplod bench live {args.dataset}'", f"'headplod bench live --source {args.dataset}'")
        spec = args.dataset
    if spec is not None:
        preset = synthetic_preset(spec)
        if preset is not None:
            spec = str(ensure_dataset(preset, quiet=args.quiet))
        elif source_kind(spec) in ("v4l2", "video"):
            print(f"headplod: bench live replays a recording several times: --source must be a dataset folder or "
                  f"synthetic[:PRESET], got {spec!r}", file=sys.stderr)
            return 2
    if not args.camera_hz > 0:
        print(f"headplod: --camera-hz must be > 0, got {args.camera_hz:g}", file=sys.stderr)
        return 2
    return live.run_live_bench(spec, json_path=args.json, repeats=args.repeats, camera_hz=args.camera_hz,
                               camera_frames=args.camera_frames)


#: ``headplod bench NAME`` → its run(args) -> exit status.
BENCHMARKS = {"track": _track, "clutter": _clutter, "uncertainty": _uncertainty, "live": _live, "plod": _plod, "stability": _stability,
              "paper": _paper}


def run_bench(args) -> int:
    """Run ``headplod bench NAME`` from parsed arguments; the exit status. ``--json`` and ``--chart`` are checked
    first (:mod:`headplod.io.files`: no special file, no file the benchmark reads, not both the same file)."""
    inputs = Inputs()
    if getattr(args, "terrain", None):
        inputs = inputs.file("the terrain being read (--terrain)", args.terrain)
    spec = getattr(args, "source", None) or getattr(args, "dataset", None)
    if spec:
        inputs += source_inputs(spec)
    try:
        check_files([("--json", getattr(args, "json", None)), ("--chart", getattr(args, "chart", None))], inputs)
    except OutputRefused as exc:
        print(f"headplod: bench {args.bench} {exc}", file=sys.stderr)
        return 2
    return BENCHMARKS[args.bench](args)
