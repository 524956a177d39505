"""``headplod render``: its arguments (:func:`add_render_arguments`) and its run (:func:`run_render`).

    headplod render [--backend mesh|tessellation|raymask] [--mode MODE] [--uncertainty U]
                    [--gaze-prior SH,SV] [--head X,Y,Z] [--poi X,Y] [--cov PP,PT,TT] [--inset-deg D]
                    [--no-silhouettes]
                    [--size W,H] [--view shaded|wire|levels] --out IMAGE.png [--stats STATS.json]
                    [--export MESH.glb|.ply|.obj|.stl]
                    [--terrain DEM.tif|HEIGHTS.png|HEIGHTS.npy [--spacing-m D|DX,DY] [--height-scale S]]
                    [--max-level 1..8] [--lazy] [--cache-mb MB]

Exit status: 0 on success, 1 on a failed run (a broken input file, no OpenGL context, a write that failed), 2 on
bad usage (options that cannot work together, a view from on or behind the screen plane, an output that cannot be
written there), each with one line on standard error; bad usage is found before anything is drawn or written.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from calib import DEFAULT_SCREEN

from .. import io
from ..io import ViewError
from ..io.files import Inputs, OutputRefused, check_files
from ..plod.export import check_export_path
from ..argtypes import add_quiet_argument, floats, gaze_prior, level_bias, triangle_budget
from ..progress import note
from ..plod.csf import CSF_MODELS
from ..plod.raymask import RAYMASK_CSF_MODELS, RayMaskConfig
from .scene_command import (add_mesh_arguments, add_terrain_arguments, mesh_options, mesh_options_problem,
                            terrain_for_command)
from ..plod.select import (DEFAULT_CSF_MODEL, GAZE_DISTRIBUTION_MODES, GAZE_PRIOR_DEG, MAX_GAZE_PRIOR_DEG, MODES,
                           UNCERTAINTY_MODES, SelectorConfig)
from .frame import (BACKENDS, CAPABILITIES, FAR_MM, VIEW_MODES, FrameSettings, capability_table, default_mode,
                    options_problem)
from .still import (CONTRAST_SOURCES, MeshOptions, StillSettings, default_head, render_still, scene_model,
                    write_outputs)
from .context import create_context
from .gl import TerrainRenderer
from .outputs import OutputNotWritable, check_writable

__all__ = ["add_render_arguments", "run_render", "add_cost_arguments", "add_csf_argument", "add_gaze_prior_argument",
           "selection_options", "raymask_config"]


def add_render_arguments(render: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``render``'s options to a (sub)parser; returns it."""
    render.add_argument("--backend", choices=BACKENDS, default="mesh",
                        help="what draws the frame (default mesh); what each supports is in the table below")
    render.add_argument("--mode", choices=MODES, help="level-selection mode (default: the back end's; mesh: "
                                                       f"{default_mode('mesh')}, tessellation and raymask: csf)")
    render.add_argument("--uncertainty", default="adaptive", choices=UNCERTAINTY_MODES,
                        help="which covariance of the viewing direction the levels use (default adaptive)")
    add_cost_arguments(render)
    add_csf_argument(render)
    add_gaze_prior_argument(render)
    render.add_argument("--head", type=floats(3), help="eye position X,Y,Z in the world frame, mm "
                                                         "(default: 600 mm in front of the screen centre)")
    render.add_argument("--poi", type=floats(2), help="point of interest X,Y in screen pixels (default: centre)")
    render.add_argument("--cov", type=floats(3), help="covariance of (φ, θ) as PP,PT,TT in deg²")
    render.add_argument("--size", type=floats(2), default=(1280, 720), help="image size W,H (default 1280,720)")
    render.add_argument("--view", default="shaded", choices=tuple(VIEW_MODES),
                        help="shaded terrain, wireframe, or each triangle coloured by its level (default shaded)")
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
    render.add_argument("--grid-samples", type=int, default=1025,
                        help="tessellation: samples per side of the terrain's height grid (the built-in one or "
                             "--terrain's, resampled), 1 + a multiple of 64 (default 1025: 2M triangles at full "
                             "detail; 8193: 134M)")
    render.add_argument("--selection", choices=("flat", "tree"), default=None,
                        help="tessellation: flat = every patch's levels on the GPU; tree = a quadtree of "
                             "variable-size patches walked on the CPU (headplod.plod.patch_tree; needs "
                             "(grid samples - 1) / 64 a power of two). Default: TessellationConfig's")
    render.add_argument("--out", required=True, help="output image (PNG)")
    add_quiet_argument(render, help="no notes on standard error (the triangles and times line); errors, warnings "
                                    "and --compare's line still appear")
    render.add_argument("--stats", help="write triangles, select/build/render ms and per-level counts (JSON; - : "
                                         "to standard output)")
    render.add_argument("--compare", choices=("full",),
                        help="also render full from the same view and print the frame's PSNR (whole, and within 5° "
                             "of the POI) and FLIP against it, both drawn shaded without the POI marker (a levels "
                             "or wire view is judged by its shaded frame); also in --stats (default: no "
                             "comparison; mesh and raymask back ends)")
    render.add_argument("--export", metavar="MESH", help="also write the frame's PLOD mesh (.glb, .ply, .obj or .stl; "
                                                         "scene metres, faces coloured by level)")
    add_terrain_arguments(render)
    add_mesh_arguments(render.add_argument_group("mesh (backends mesh and raymask)"))
    render.formatter_class = argparse.RawDescriptionHelpFormatter
    render.epilog = "what each back end supports:\n" + capability_table()
    return render


def add_cost_arguments(parser) -> None:
    """Add ``--level-bias`` and ``--budget`` (what every mode is compared at) to a parser or group."""
    parser.add_argument("--level-bias", type=level_bias, default=0.0, metavar="B",
                        help="add B levels to every continuous level before rounding (default 0): trades "
                             "triangles for image error in every mode alike")
    parser.add_argument("--budget", type=triangle_budget, default=None, metavar="TRIANGLES",
                        help="meet this many triangles a frame within 3%%: the level bias is found per frame "
                             "(bisection), so modes can be compared at equal cost (mesh back end); a budget beyond "
                             "what the view allows is not met, and render's summary and --stats say so, with the "
                             "nearest count")


def add_csf_argument(parser) -> None:
    """Add ``--csf FORM`` (the contrast sensitivity function the levels follow) to a parser or group."""
    parser.add_argument("--csf", choices=RAYMASK_CSF_MODELS, default=None, metavar="FORM",
                        help="the CSF form of the CSF-based modes: " + ", ".join(RAYMASK_CSF_MODELS)
                             + " (gp, Geisler-Perry: raymask only). Default: the mode's own ("
                             + ", ".join(f"{m}: {f}" for m, f in DEFAULT_CSF_MODEL.items())
                             + f"; raymask: {RayMaskConfig.csf_model}); which back end takes which is in the table "
                               "below")


def add_gaze_prior_argument(parser) -> None:
    """Add ``--gaze-prior SH,SV`` (the σ of the eyes' offset in the head, :attr:`SelectorConfig.gaze_prior_deg`) to
    a parser or group. Every back end takes it: it widens the conditioned view's covariance."""
    own = ", ".join(f"{m}: {GAZE_PRIOR_DEG[0]:g},{GAZE_PRIOR_DEG[1]:g}" for m in GAZE_DISTRIBUTION_MODES)
    parser.add_argument("--gaze-prior", type=gaze_prior, default=None, metavar="SH,SV",
                        help="σ of the eyes' offset in the head, horizontal,vertical deg (0.."
                             f"{MAX_GAZE_PRIOR_DEG:g}): where the viewer may look besides along the head's direction, "
                             "added to the covariance of the viewing direction (every back end); 0,0: the head "
                             f"alone, the paper's view. Default: the mode's own ({own}; the others: 0,0)")


def selection_options(args) -> dict:
    """The :class:`SelectorConfig` fields of :func:`add_cost_arguments`' options, of ``--csf`` (the selector's
    CSF; raymask's own CSF is :func:`raymask_config`'s) and of ``--gaze-prior`` (absent: the mode's own)."""
    options = {"level_bias": float(getattr(args, "level_bias", 0.0)),
               "budget_triangles": getattr(args, "budget", None)}
    prior = getattr(args, "gaze_prior", None)
    if prior is not None:
        options["gaze_prior_deg"] = tuple(float(v) for v in prior)
    csf = getattr(args, "csf", None)
    if csf in CSF_MODELS:              # gp is raymask's alone (the mesh's Geisler-Perry is --mode gp)
        options["csf_model"] = csf
    return options


def raymask_config(args) -> RayMaskConfig:
    """The raymask back end's settings from ``--inset-deg``, ``--no-silhouettes`` and ``--csf`` (absent options:
    the defaults). Raises ValueError naming the setting that is out of range."""
    return RayMaskConfig(inset_deg=getattr(args, "inset_deg", RayMaskConfig.inset_deg),
                         silhouettes=not getattr(args, "no_silhouettes", False),
                         csf_model=getattr(args, "csf", None) or RayMaskConfig.csf_model)


def still_settings(args, mode: str, cov_deg2=None, size=(1280, 720), raymask: RayMaskConfig | None = None,
                   uncertainty: str | None = None) -> StillSettings:
    """The typed settings of ``headplod render``'s frame from its parsed (and checked) options; ``mode`` the
    mode in use (``--mode`` or the back end's own), ``cov_deg2`` (2, 2) deg² or None, ``size`` (w, h) px."""
    selection = SelectorConfig(mode=mode, uncertainty=args.uncertainty if uncertainty is None else uncertainty,
                               **selection_options(args))
    frame = FrameSettings(args.backend, selection, foveate=args.foveate, raymask=raymask)
    return StillSettings(frame, head_mm=args.head, poi_px=args.poi, cov_deg2=cov_deg2, size=size,
                         view_mode=args.view, contrast=args.contrast,
                         export=None if args.export is None else Path(args.export))


def _output_problem(option: str, path, image: bool = False) -> str | None:
    """Why ``path`` cannot be ``option``'s output file (a folder; an image ending OpenCV cannot write; a place no
    file can be written: :func:`headplod.render.outputs.check_writable`), or None."""
    p = Path(path)
    if p.is_dir():
        return f"{option} {path} is a folder; name a file"
    if image and not io.writes_images(p.suffix):      # the ending alone: OpenCV never sees the path
        return f"{path}: OpenCV cannot write images ending {p.suffix or '(no ending)'!r}; use .png or .jpg"
    try:
        check_writable(p)
    except OutputNotWritable as exc:
        return f"{option} {path}: {exc}"
    return None


def _usage_problem(args, screen) -> str | None:
    """Why ``headplod render``'s options cannot make a frame (one line, bad usage), found before any work: the
    covariance, the size, the outputs (``--out``, ``--stats``, ``--export``: ending, folder, a place that can be
    written) and the view (an eye on or behind the screen plane); or None."""
    if args.cov is not None:
        pp, pt, tt = args.cov
        if np.any(np.linalg.eigvalsh(np.array([[pp, pt], [pt, tt]])) <= 0):
            return f"--cov {args.cov} is not positive definite"
    if min(args.size) < 1 or max(args.size) > 16384 or any(v != int(v) for v in args.size):
        return f"--size must be two whole numbers of pixels in 1..16384, got {args.size}"
    problem = (_same_outputs_problem(args) or _output_problem("--out", args.out, image=True)
               or (args.stats not in (None, "-") and _output_problem("--stats", args.stats)))
    if problem:
        return problem
    if args.export is not None:
        try:
            check_export_path(args.export)
        except ValueError as exc:
            return f"--export {exc}"
        problem = _output_problem("--export", args.export)
        if problem:
            return problem
    return _view_problem(args.head, screen, args.screen)


def _same_outputs_problem(args) -> str | None:
    """Why ``--out``, ``--stats`` or ``--export`` may not be written (:mod:`headplod.io.files`: a special file,
    an input (``--terrain``, ``--screen``) however spelled, or one of them twice), or None."""
    inputs = Inputs()
    for option, what in (("screen", "the screen being read"), ("terrain", "the terrain being read")):
        if getattr(args, option, None):
            inputs = inputs.file(f"{what} (--{option})", getattr(args, option))
    try:
        check_files([("--out", args.out), ("--stats", args.stats), ("--export", getattr(args, "export", None))],
                    inputs)
    except OutputRefused as exc:
        return str(exc)
    return None


def _view_problem(head, screen, screen_path=None) -> str | None:
    """Why no frame can be drawn from ``head`` ((3,) world mm; None: :func:`default_head`) on ``screen`` (read
    from ``screen_path``; None: the embedded one): :meth:`headplod.io.Screen.check_eye`'s reason (on or behind the
    screen plane, or beyond the frame's far clip plane, :data:`~headplod.render.frame.FAR_MM`); or None."""
    try:
        screen.check_eye(default_head(screen) if head is None else head, far_mm=FAR_MM)
    except ViewError as exc:
        if head is not None:
            return f"--head {','.join(f'{v:g}' for v in head)}: {exc}"
        # The default eye stands on the cameras' side of the screen: the corners are given in the wrong order.
        return (f"--screen {screen_path}: the default eye, 600 mm in front of the screen's centre on the cameras' "
                f"side: {exc}; are top_left, top_right and bottom_left as the viewer sees them?")
    return None


def _stats_file(args):
    """``--stats``' file, or None when there is none or it is ``-`` (standard output: :func:`_print_stats`)."""
    return None if args.stats in (None, "-") else args.stats


def _write_failed(exc: Exception, args) -> int:
    """The one line of an output that could not be written after all (a full disk; OpenCV refusing to encode),
    naming its path as given; exit status 1."""
    where = getattr(exc, "filename", None)
    reason = getattr(exc, "strerror", None) or exc
    print(f"headplod: could not write the output: {reason}" + (f" ({where})" if where else ""), file=sys.stderr)
    return 1


def _print_stats(args, stats: dict) -> None:
    """``--stats -``: the stats (JSON) on standard output, as the file would hold them."""
    if args.stats == "-":
        print(json.dumps(stats, indent=2), flush=True)


def run_render(args) -> int:
    """Run ``headplod render`` from parsed arguments; the exit status.

    Every option, output and the view are checked before any work (one line, exit status 2); the OpenGL
    context is made next, before the terrain is read or its mesh built (a broken EGL ends the run at once,
    :class:`~headplod.render.context.GLContextError`, one line from the command line, exit status 1).
    """
    screen = io.read_screen(args.screen or DEFAULT_SCREEN)
    problem = _usage_problem(args, screen)
    if problem:
        print(f"headplod: {problem}", file=sys.stderr)
        return 2
    cov = None if args.cov is None else np.array([[args.cov[0], args.cov[1]], [args.cov[1], args.cov[2]]])
    size = tuple(int(v) for v in args.size)
    mode = args.mode or default_mode(args.backend)
    given = tuple(name for name, on in (("--max-level", args.max_level is not None), ("--lazy", args.lazy),
                                        ("--cache-mb", args.cache_mb is not None)) if on)
    problem = options_problem(args.backend, mode=mode, uncertainty=args.uncertainty, view_mode=args.view,
                              foveate=args.foveate, contrast=args.contrast, export=args.export is not None,
                              terrain=args.terrain is not None, level_bias=args.level_bias != 0.0,
                              budget=args.budget is not None, csf=args.csf, compare=args.compare is not None,
                              mesh_options=given)
    if CAPABILITIES[args.backend].mesh_options:
        problem = problem or mesh_options_problem(args, args.backend, mode)
    if problem:
        print(f"headplod: {problem}", file=sys.stderr)
        return 2
    if args.backend == "tessellation":
        return _run_tessellation(args, mode, screen, cov, size)
    raymask = None
    if args.backend == "raymask":
        try:
            raymask = raymask_config(args)
        except ValueError as exc:
            print(f"headplod: --inset-deg: {exc}", file=sys.stderr)
            return 2
    if args.poi is not None:
        w, h = screen.size_px
        x, y = args.poi
        if not (0 <= x <= w and 0 <= y <= h):
            print(f"headplod: warning: --poi {x:g},{y:g} lies outside the screen (0..{w}, 0..{h} px): the viewer "
                  "looks off the screen and the whole frame is periphery", file=sys.stderr)
    renderer = TerrainRenderer(create_context(), size=size)     # (the raymask back end's is made on its context)
    terrain, status = terrain_for_command(args, "headplod")     # read before anything is written
    if status is not None:
        return status
    options = mesh_options(args)
    scene = None
    if terrain is not None or options != MeshOptions() or args.compare:   # else render_still's default scene
        scene = options.build(screen, terrain)                   # (--compare: one scene for both frames)
    try:
        settings = still_settings(args, mode, cov, size, raymask)
        if args.compare != "full":
            image, stats = render_still(settings, screen, scene=scene, renderer=renderer, out=args.out,
                                        stats_path=_stats_file(args))
        else:                        # the figures go into the stats: both files written once they are known
            image, stats = render_still(settings, screen, scene=scene, renderer=renderer)
            stats["compare"], line = compare_with_full(settings, image, screen, scene, renderer)
            write_outputs(image, stats, args.out, _stats_file(args))
            print(line, file=sys.stderr)
    except OSError as exc:           # a write that failed all the same (a full disk): nothing half-written is left
        return _write_failed(exc, args)
    _print_stats(args, stats)
    if "raymask" in stats:
        r = stats["raymask"]
        note(f"{r['rays']} rays ({r['fill_rays']} inset, {r['ring_rays']} rings, {r['silhouette_rays']} in "
             f"{r['silhouette_quads']} silhouette quads), {stats['triangles']} triangles; mask "
             f"{stats['select_ms']:.1f} ms, render {stats['render_ms']:.1f} ms; image: {args.out}")
        return 0
    m = stats["mesh"]
    lazy = (f", lazy mesh: {m['vertices']:,} vertices, cache {m['cache_bytes'] / 2 ** 20:.0f} of "
            f"{m['cache_budget_bytes'] / 2 ** 20:.0f} MB" if m["kind"] == "lazy" else "")
    budget = f"; {budget_words(stats['budget'], m['max_level'])}" if "budget" in stats else ""
    note(f"{stats['triangles']} triangles (level {m['max_level']}{lazy}){budget}; select {stats['select_ms']:.1f} ms, "
         f"build {stats['build_ms']:.1f} ms, "
         f"render {stats['render_ms']:.1f} ms; image: {args.out}"
         + (f"; mesh: {args.export}" if args.export else ""))
    return 0


def budget_words(outcome: dict, max_level: int) -> str:
    """The summary's words on a budget (:func:`headplod.render.frame.budget_outcome`'s dict): met, or not met
    with the nearest count the view allows."""
    head = f"budget {outcome['triangles']:,}"
    if outcome["met"]:
        return f"{head} met with a level bias of {outcome['bias']:+.2f}"
    nearest = f"{outcome['nearest']:,} triangles"
    if outcome["limit"] == "coarsest":
        return f"{head} not met: {nearest}, the coarsest this view allows (every base triangle at level 0)"
    if outcome["limit"] == "finest":
        return f"{head} not met: {nearest}, the finest this view allows at --max-level {max_level}"
    return f"{head} not met: {nearest}, the nearest the levels allow (a base triangle refines as a whole)"


def compare_with_full(settings, image, screen, scene, renderer, judge=None) -> tuple[dict, str]:
    """``render --compare full``: the frame of ``settings`` (drawn as ``image``, (H, W, 3) uint8) judged against
    ``full`` from the same view, like with like; (the stats' ``compare`` entry, the line for stderr).

    Both are judged shaded and without the POI marker: a levels or wire picture colours levels or edges, which
    ``full`` (every triangle at the finest level) cannot share, and the marker is no part of the terrain. When
    ``image`` is not such a frame, the same selection is drawn again shaded for the comparison."""
    plain = settings.view_mode == "shaded" and settings.cov_deg2 is None     # no marker drawn (render_still)
    tested = image
    if not plain:
        tested, _ = render_still(replace(settings, view_mode="shaded", overlay=False, export=None), screen,
                                 scene=scene, renderer=renderer)
    full = FrameSettings("mesh", SelectorConfig(mode="full", uncertainty="none"))
    reference, _ = render_still(replace(settings, frame=full, cov_deg2=None, view_mode="shaded", contrast="shading",
                                        export=None, overlay=False), screen, scene=scene, renderer=renderer)
    figures = compare_figures(tested, reference, screen, settings.head_mm, settings.poi_px, settings.size, judge)
    if plain:
        compared, head = "the shaded frames", "against full"
    else:
        why = {"levels": "a --view levels picture colours levels", "wire": "a --view wire picture draws edges"}
        reason = why.get(settings.view_mode)
        compared = "the same selection and full, both drawn shaded without the POI marker"
        head = ("against full, both drawn shaded without the POI marker"
                + (f" ({reason}, not the detail full is judged on)" if reason else ""))
    entry = {"against": "full", "compared": compared, "view": settings.view_mode,
             **{k: (v if v is None or math.isfinite(v) else None) for k, v in figures.items()
                if k != "jod_note"}}
    entry["identical"] = figures["psnr_db"] == math.inf       # JSON has no infinity: PSNR null, said here
    return entry, format_compare(figures, head)


def compare_figures(image, reference, screen, head_mm, poi_px, size, judge=None) -> dict:
    """PSNR of ``image`` against ``reference`` (both (H, W, 3) uint8 of ``size`` (w, h) px) over the image
    (``psnr_db``) and within 5° of the POI (``psnr_disc_5deg_db``; screen px, None: the centre), FLIP (``flip``)
    at the screen's pixels per degree seen from ``head_mm`` (world mm; None: the default head), and FovVideoVDP's
    JOD (``jod``) fixated at the POI where the vdp extra is installed, else None and ``jod_note`` says why.

    ``judge``: a callable ``(display, reference, image, fixation) -> JOD`` standing in for FovVideoVDP (tests);
    None: :class:`headplod.render.vdp.Judge` when :func:`~headplod.render.vdp.vdp_available`."""
    from ..plod.view import default_head
    from .frame import px_per_deg_at
    from .image_metrics import poi_disc, quality
    from .projection import screen_to_image_px
    from .vdp import Judge, display_geometry, fixation_px, vdp_available

    head = default_head(screen) if head_mm is None else np.asarray(head_mm, dtype=np.float64)
    poi = np.array(screen.size_px, dtype=np.float64) / 2 if poi_px is None else np.asarray(poi_px, dtype=np.float64)
    ppd = px_per_deg_at(screen, head, size)
    centre = screen_to_image_px(poi, screen.size_px, size)
    q = quality(image, reference, poi_disc(image.shape[:2], centre, 5.0 * ppd), ppd)     # the benches' measures
    figures = {**q, "jod": None, "jod_note": None}
    if judge is None and not vdp_available("fvvdp"):
        return {**figures, "jod_note": "JOD needs the vdp extra (.venv/bin/pip install -e '.[vdp]')"}
    try:
        display = display_geometry(screen, head, size)
    except ValueError as exc:           # the metric's display model has the eye on the screen centre's normal
        return {**figures, "jod_note": f"no JOD: {exc}"}
    fixation = fixation_px(screen, poi, size)
    jod = Judge(display).jod(reference, image, fixation) if judge is None else judge(display, reference, image,
                                                                                      fixation)
    return {**figures, "jod": float(jod)}


def format_compare(figures: dict, head: str = "against full") -> str:
    """The one line of :func:`compare_figures`' figures, after ``head``."""
    line = (f"{head}: PSNR {figures['psnr_db']:.2f} dB, within 5° of the POI {figures['psnr_disc_5deg_db']:.2f} dB, "
            f"FLIP {figures['flip']:.4f}")
    if figures["jod"] is None:
        return line + f"; {figures['jod_note']}"
    return line + f", JOD {figures['jod']:.2f} (FovVideoVDP, fixated at the POI; 10 = no visible difference)"


def compare_line(image, reference, screen, head_mm, poi_px, size, judge=None) -> str:
    """``render --compare full``'s line for two frames already drawn alike: :func:`compare_figures`, formatted."""
    return format_compare(compare_figures(image, reference, screen, head_mm, poi_px, size, judge))


def _run_tessellation(args, mode, screen, cov, size) -> int:
    """``headplod render --backend tessellation``: one frame of :mod:`headplod.render.tessellate`."""
    from ..plod.patches import PatchGrid, height_grid, jacksboro_grid, patch_samples_for
    from .still import fit_scale
    from .tessellate import TessellationConfig, TessellationRenderer

    config = TessellationConfig()
    if getattr(args, "selection", None) is not None:
        config = replace(config, hierarchy=args.selection == "tree")
    n = args.grid_samples
    if n < config.patch_samples + 1 or (n - 1) % config.patch_samples:
        print(f"headplod: --grid-samples must be 1 + a multiple of {config.patch_samples}, got {n}", file=sys.stderr)
        return 2
    if not config.hierarchy:        # the flat grid: patches as large as the image can use (the tree's leaves stay 64)
        config = replace(config, patch_samples=patch_samples_for(n, max(size), config.max_tess_level,
                                                                 config.patch_samples))
    patches = (n - 1) // config.patch_samples
    if config.hierarchy and patches & (patches - 1):
        print(f"headplod: --selection tree needs a power-of-two number of patches per side: --grid-samples {n} "
              f"gives {patches} (1 + 64 x 2^k: 129, 257, 513, 1025, ...)", file=sys.stderr)
        return 2
    ctx = create_context(require=430)            # before the terrain and its grid: a broken EGL ends the run at once
    terrain, status = terrain_for_command(args, "headplod")     # --terrain FILE: a person's own terrain
    if status is not None:
        return status
    if terrain is None:
        z, dx, dy, origin = jacksboro_grid(n)
    else:
        z, dx, dy = height_grid(terrain, n)
        origin = (terrain.extent[0], terrain.extent[2])
    grid = PatchGrid.build(z, dx, dy, config.patch_samples, origin_m=origin)
    # Placed as the mesh back end places the same terrain (a --terrain file framed by its fit).
    if terrain is None:
        model = scene_model(grid.extent, float(np.median(z[::8, ::8])), screen)
    else:
        model = scene_model(grid.extent, float(np.median(terrain.dem_z_m)), screen, fit_scale(terrain))
    settings = still_settings(args, mode, cov, size)
    with TessellationRenderer(ctx, grid, size=size, config=config,
                              selection=settings.frame.selection) as renderer:
        try:                         # each file whole or not at all, as the mesh back end's
            _, stats = render_still(settings, screen, renderer=renderer, model=model, out=args.out,
                                    stats_path=_stats_file(args),
                                    details={"grid_samples": n, "patch_samples": config.patch_samples})
        except (OSError, ValueError) as exc:
            return _write_failed(exc, args)
    _print_stats(args, stats)
    note(f"{stats['triangles']} triangles ({grid.full_triangles} at full detail); select {stats['select_ms']:.1f} ms, "
         f"render {stats['render_ms']:.1f} ms; image: {args.out}")
    return 0
