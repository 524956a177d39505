"""``headplod bench plod --scale``: PLOD's cost against the terrain's size (issue 14; README: the tessellation).

The default view (:mod:`.harness`), 1280x720, over the built-in DEM with its synthetic detail sampled on
grids of 1025² … 8193² samples (2 … 134M triangles at full detail; :func:`headplod.plod.patches.jacksboro_grid`,
cached). Back ends: ``tessellation`` with each selection of :data:`SELECTIONS` (``tree``: the CPU quadtree of
:mod:`headplod.plod.patch_tree`; ``flat``: the levels per patch on the GPU, patches of
:func:`headplod.plod.patches.patch_samples_for`), on the largest terrain also with the patch sizes of
:data:`SWEEP_PATCH_SAMPLES` (``patch_sweep``); ``full``, the whole grid as one indexed mesh, up to
:data:`FULL_MAX_SAMPLES`.

Each (back end, terrain) runs in its own process (:func:`in_own_process`), so its peak memory
(:func:`peak_rss_mb`, MB) is its own. Per case, medians over the steady frames: frame ms (selection + draw,
no read-back), selection ms (the CPU's share), triangles drawn, and the PSNR within 5° of the POI against a
full-detail render of the disc's box by the tessellation back end at its finest level (the case's own
shading), at 1 and 4x4 samples per pixel.
"""
from __future__ import annotations

import resource
import time
from dataclasses import replace

import numpy as np

from ..progress import note
from .harness import (DEFAULT_SCREEN, DISC_DEG, FRAME_DT_S, SIZE, TRACKER_COV_DEG2, label_axes, pyplot,
                      save_figure)
from ..tol import tol

SCALE_SAMPLES = (1025, 2049, 4097, 8193)
QUICK_SAMPLES = (1025, 2049)
BACKENDS = ("tessellation", "full")
#: The tessellation's selections each terrain is measured with: the hierarchy (plod.patch_tree) and the flat grid.
SELECTIONS = ("tree", "flat")
#: Largest grid the ``full`` back end is run on by default (samples per side).
FULL_MAX_SAMPLES = 2049
#: Patch size of the scale runs, samples: the finest level has a vertex per sample.
MIN_PATCH_SAMPLES = 64
#: Patch sizes tried on the largest terrain: larger patches mean fewer patches for the levels pass and the
#: draw (each drawn patch has a cost of its own beside its triangles, and so has its levels pass),
#: but coarser adaptation (a patch's inner level is its nearest point's), so more triangles. The finest level
#: of a patch of P samples has a vertex every P / 64 samples (8193²: 0.18 px per sample here).
SWEEP_PATCH_SAMPLES = (64, 128, 256, 512)
#: The second reference: the same full-detail region drawn at 4x4 the pixels and averaged down.
SUPERSAMPLE = 4
GOAL_FPS = 15.0
GOAL_RSS_MB = 2048.0
GOAL_SELECT_GROWTH = 2.0
GOAL_PSNR_DB = 45.0


def _disc_region(screen, head, size):
    """(disc mask (H, W) bool, its bounding box in NDC (x0, y0, x1, y1), px per deg) around the centre POI."""
    from ..render.still import px_per_deg_at
    from ..render.image_metrics import disc_mask

    w, h = size
    ppd = px_per_deg_at(screen, head, size)
    radius = DISC_DEG * ppd
    disc = disc_mask((h, w), (w / 2, h / 2), radius)
    # NDC y is up, the image's row 0 is the top: the box is symmetric about the centre either way.
    rx, ry = (radius + 4) / (w / 2), (radius + 4) / (h / 2)
    return disc, (-rx, -ry, rx, ry), ppd


def peak_rss_mb() -> float:
    """This process's peak resident memory, MB: its address space's high-water mark (``VmHWM``).

    Not ``ru_maxrss``: Linux keeps that across ``execve``, so a process started from a large one would
    report its parent's peak. Falls back to ``ru_maxrss`` where ``/proc`` has no ``VmHWM``.
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def in_own_process(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a fresh process; its result.

    The process is multiprocessing's ``spawn`` (a new interpreter, not a fork of this one), so its
    peak resident memory (:func:`peak_rss_mb`) is its own. ``fn`` and its arguments and result are pickled.
    An exception in ``fn`` is raised here; a process that dies (e.g. killed for memory) raises
    :class:`RuntimeError`.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        try:
            return pool.submit(fn, *args, **kwargs).result()
        except BrokenProcessPool as exc:
            raise RuntimeError(f"the process of {getattr(fn, '__name__', fn)} died ({exc})") from exc


def _make_grid(n_samples: int, cache_dir) -> None:
    """Make (and cache) the terrain grid of ``n_samples`` per side (:func:`headplod.plod.patches.jacksboro_grid`)."""
    from ..plod.patches import jacksboro_grid

    jacksboro_grid(n_samples, cache_dir)


def _patch_grid(n_samples: int, size, cache_dir, patch_samples, hierarchy, split_factor):
    """The cached terrain grid and its patches: ((z, dx, dy, origin), PatchGrid, patch samples, TessellationConfig).

    Default patches: the flat grid's as large as the image can use (the render command's rule); the
    tree's leaves keep one vertex per sample at the finest level.
    """
    from ..plod.patches import PatchGrid, jacksboro_grid, patch_samples_for
    from ..render.tessellate import TessellationConfig

    z, dx, dy, origin = jacksboro_grid(n_samples, cache_dir)
    tree = bool(TessellationConfig().hierarchy if hierarchy is None else hierarchy)
    p = (int(patch_samples) if patch_samples is not None else MIN_PATCH_SAMPLES if tree
         else patch_samples_for(n_samples, max(size), smallest=MIN_PATCH_SAMPLES))
    grid = PatchGrid.build(z, dx, dy, p, origin_m=origin)
    config = TessellationConfig(patch_samples=p)
    if hierarchy is not None or split_factor is not None:
        config = replace(config, **({} if hierarchy is None else {"hierarchy": bool(hierarchy)}),
                         **({} if split_factor is None else {"split_factor": int(split_factor)}))
    return (z, dx, dy, origin), grid, p, config


def _tessellation_frames(tess, screen, model, frames, extra):
    """The frames of ``tess`` (a TessellationRenderer) through the frame step: (steady rows, last image).

    A steady row: (select ms, render ms, triangles, draw calls) of each frame after the first;
    ``extra`` gets the drawn patches and, for the tree, its nodes.
    """
    from ..plod.view import View
    from ..render.frame import FrameSettings, make_frame_step
    from ..render.still import default_head

    head, poi = default_head(screen), np.array(screen.size_px, float) / 2
    step = make_frame_step(FrameSettings("tessellation", tess.selection), screen, renderer=tess)
    steady = []
    for k in range(frames + 1):                     # loop over frames: the first is the warm-up
        out = step(View(head, poi, TRACKER_COV_DEG2, k * FRAME_DT_S), model)
        if k:
            steady.append((out.stage_ms["select"], out.stage_ms["render"], out.triangles,
                           out.details["draw_calls"]))
    extra["drawn_patches"] = int(out.details["patches"])
    if tess.last_selection is not None and tess.config.hierarchy:
        extra["nodes_evaluated"] = int(tess.last_selection.evaluated)
        extra["nodes_by_depth"] = np.bincount(tess.last_selection.depth, minlength=tess._tree.depth + 1).tolist()
        extra["capped"] = int(tess.last_selection.capped)
    return steady, out.image


def _full_mesh(ctx, grid, size):
    """The whole grid as one indexed mesh in a :class:`TerrainRenderer` (24 bytes a vertex, 12 a triangle)."""
    from ..plod.patches import grid_normals
    from ..render import TerrainRenderer

    n = grid.heights_m.shape[0]
    xs = grid.origin_m[0] + np.arange(n, dtype=np.float64) * grid.dx_m
    ys = grid.origin_m[1] + np.arange(n, dtype=np.float64) * grid.dy_m
    positions = np.empty((n, n, 3), np.float32)
    positions[..., 0], positions[..., 1], positions[..., 2] = xs[None, :], ys[:, None], grid.heights_m
    normals = grid_normals(grid.heights_m, grid.dx_m, grid.dy_m)
    i = (np.arange(n - 1, dtype=np.uint32)[:, None] * n + np.arange(n - 1, dtype=np.uint32)[None, :]).ravel()
    indices = np.empty((len(i), 6), np.uint32)
    for col, off in enumerate((0, 1, n + 1, 0, n + 1, n)):
        indices[:, col] = i + off
    del i
    mesh = TerrainRenderer(ctx, size=size)
    mesh.upload(positions.reshape(-1, 3), normals.reshape(-1, 3), indices=indices.reshape(-1, 3))
    mesh.height_range = (float(grid.heights_m.min()), float(grid.heights_m.max()))     # as the tessellation's
    return mesh


def _full_frames(mesh, ctx, screen, model, frames):
    """The full mesh's frames from the default head: (steady rows as the tessellation's, last image)."""
    from ..render import off_axis_projection
    from ..render.frame import FAR_MM, NEAR_MM
    from ..render.still import default_head

    view, proj = off_axis_projection(default_head(screen), screen, near_mm=NEAR_MM, far_mm=FAR_MM)
    query = ctx.query(primitives=True)
    steady = []
    for k in range(frames + 1):                     # loop over frames: the first is the warm-up
        with query:
            image = mesh.render(view, proj, model)
        if k:
            steady.append((0.0, mesh.last_render_ms, int(query.primitives), 1))
    return steady, image


def _references(ctx, terrain, tess, backend, config, p, screen, model, size, region, extra):
    """The full-detail references of the disc's box, at 1 and 4x4 samples per pixel: (image, image, triangles).

    Drawn by the tessellation back end at its finest level, every patch reaching the box; with patches of
    one vertex per sample (made anew unless the case's are those), shaded per vertex for ``full``.
    """
    from ..plod.patches import PatchGrid
    from ..plod.select import SelectorConfig
    from ..render.frame import FrameSettings, one_frame
    from ..render.still import default_head
    from ..render.tessellate import TessellationConfig, TessellationRenderer

    if backend == "full" or p != MIN_PATCH_SAMPLES:
        if tess is not None:
            tess.release()
        z, dx, dy, origin = terrain
        fine = PatchGrid.build(z, dx, dy, MIN_PATCH_SAMPLES, origin_m=origin)
        shading = "vertex" if backend == "full" else config.shading
        tess = TessellationRenderer(ctx, fine, size=size, config=TessellationConfig(
            patch_samples=MIN_PATCH_SAMPLES, shading=shading))
    head, poi = default_head(screen), np.array(screen.size_px, float) / 2
    t0 = time.perf_counter()
    full = FrameSettings("tessellation", SelectorConfig(mode="full"), region_ndc=region)
    ref = one_frame(full, screen, model, head, poi, TRACKER_COV_DEG2, renderer=tess)
    extra["reference_s"] = time.perf_counter() - t0
    ss = one_frame(replace(full, supersample=SUPERSAMPLE), screen, model, head, poi, TRACKER_COV_DEG2, renderer=tess)
    return ref.image, ss.image, ref.triangles


def run_case(backend: str, n_samples: int, frames: int = 5, size=SIZE, cache_dir=None, level_bias: float = 0.0,
             patch_samples: int | None = None, hierarchy: bool | None = None, split_factor: int | None = None) -> dict:
    """One (back end, terrain) measured in this process; the result dict (see the module notes).

    The frames come first and the peak memory is read after them; the references (drawn by the
    tessellation back end, the supersampled one in a 4x4 larger framebuffer) come after.
    """
    from .. import io
    from ..plod.select import SelectorConfig
    from ..render import create_context
    from ..render.still import default_head
    from ..render.tessellate import TessellationRenderer, grid_model
    from ..render.image_metrics import psnr_db

    if backend not in BACKENDS:
        raise ValueError(f"run_case: backend must be one of {BACKENDS}, got {backend!r}")
    t_start = time.perf_counter()
    terrain, grid, p, config = _patch_grid(n_samples, size, cache_dir, patch_samples, hierarchy, split_factor)
    screen = io.read_screen(DEFAULT_SCREEN)
    disc, region, _ = _disc_region(screen, default_head(screen), size)
    ctx = create_context(require=430)
    model = grid_model(grid, screen)
    extra, tess = {}, None
    if backend == "tessellation":
        tess = TessellationRenderer(ctx, grid, size=size, config=config,
                                    selection=SelectorConfig(mode="csf", level_bias=level_bias))
        extra["setup_s"] = time.perf_counter() - t_start
        steady, image = _tessellation_frames(tess, screen, model, frames, extra)
    else:
        mesh = _full_mesh(ctx, grid, size)
        extra["setup_s"] = time.perf_counter() - t_start
        steady, image = _full_frames(mesh, ctx, screen, model, frames)
    rss_mb = peak_rss_mb()
    if backend == "full":
        mesh.release()
    reference, reference_ss, ref_triangles = _references(ctx, terrain, tess, backend, config, p, screen, model, size,
                                                         region, extra)
    select_ms, render_ms = (float(np.median([s[j] for s in steady])) for j in range(2))
    return {"backend": backend, "samples": n_samples, "level_bias": level_bias, "full_triangles": grid.full_triangles,
            "shading": "vertex" if backend == "full" else config.shading,
            "hierarchy": bool(config.hierarchy) and backend == "tessellation", "split_factor": config.split_factor,
            "patch_samples": p, "patches": grid.n_patches ** 2, "frames": frames,
            "frame_ms": select_ms + render_ms, "select_ms": select_ms, "render_ms": render_ms,
            "fps": 1e3 / (select_ms + render_ms), "triangles": int(steady[-1][2]), "draw_calls": int(steady[-1][3]),
            "rss_mb": rss_mb, "psnr_disc_5deg_db": psnr_db(image, reference, disc),
            "psnr_disc_5deg_ssaa_db": psnr_db(image, reference_ss, disc),
            "reference_triangles": ref_triangles, **extra,
            "select_ms_all": [s[0] for s in steady], "render_ms_all": [s[1] for s in steady]}


def _run_isolated(backend: str, n_samples: int, frames: int, cache_dir, patch_samples=None,
                  selection: str | None = None) -> dict:
    """:func:`run_case` in its own process (:func:`in_own_process`); ``ok`` False with the reason if it failed."""
    hierarchy = {"tree": True, "flat": False, None: None}[selection]
    try:
        result = in_own_process(run_case, backend, n_samples, frames, cache_dir=cache_dir,
                                patch_samples=patch_samples, hierarchy=hierarchy)
    except Exception as exc:                      # the case's failure is its row, not the report's end
        return {"backend": backend, "samples": n_samples, "ok": False, "reason": f"{type(exc).__name__}: {exc}"}
    return {**result, "ok": True}


def scale_report(samples=SCALE_SAMPLES, frames: int = 9, full_max_samples: int = FULL_MAX_SAMPLES,
                 cache_dir=None, progress=None, patch_sweep: bool = True, selections=SELECTIONS) -> dict:
    """Measure every (back end, terrain) in its own process; the report (cases, patch sweep, goals).

    ``full`` runs on the grids up to ``full_max_samples`` per side; larger ones are listed as not run.
    ``selections``: the tessellation's selections measured on every terrain (``tree``: the hierarchy of
    :mod:`headplod.plod.patch_tree`; ``flat``: every patch's levels on the GPU); the goals are the
    default's (``TessellationConfig.hierarchy``), the selection growth of each is listed.
    ``patch_sweep``: also the tessellation on the largest terrain with the larger patches of
    :data:`SWEEP_PATCH_SAMPLES` (the trade between selection and draw).
    """
    say = progress or (lambda text: None)
    for n in samples:                         # make the grids first: their generation is not any case's memory
        say(f"terrain grid {n}x{n}")
        in_own_process(_make_grid, n, cache_dir)
    cases = []
    for n in samples:
        for backend in BACKENDS:
            if backend == "full" and n > full_max_samples:
                cases.append({"backend": backend, "samples": n, "ok": False,
                              "reason": f"not run: the mesh of {2 * (n - 1) ** 2 / 1e6:.0f}M triangles needs "
                                        f"{(24 * n * n + 12 * 2 * (n - 1) ** 2) / 2 ** 30:.1f} GB of buffers"})
                continue
            for selection in (selections if backend == "tessellation" else (None,)):
                say(f"{backend}{'' if selection is None else ' (' + selection + ')'} on {n}x{n}")
                cases.append(_run_isolated(backend, n, frames, cache_dir, selection=selection))
                say("  " + _row(cases[-1]))
    sweep = []
    if patch_sweep:
        from ..plod.patches import patch_samples_for
        default_p = patch_samples_for(max(samples), max(SIZE), smallest=MIN_PATCH_SAMPLES)
        for p in SWEEP_PATCH_SAMPLES:
            if p != default_p and (max(samples) - 1) % p == 0:
                say(f"tessellation on {max(samples)}x{max(samples)}, patches of {p} samples")
                sweep.append(_run_isolated("tessellation", max(samples), frames, cache_dir, p, selection="flat"))
                say("  " + _row(sweep[-1]))
    return {"size": list(SIZE), "patch_samples": "flat: patches.patch_samples_for(samples, 1280); tree: leaves of 64",
            "cov_deg2": TRACKER_COV_DEG2.tolist(), "cases": cases,
            "patch_sweep": sweep, "goals": _goals(cases, samples)}


def _goals(cases, samples) -> list:
    from ..render.tessellate import TessellationConfig

    default = TessellationConfig().hierarchy
    tess = {c["samples"]: c for c in cases if c["backend"] == "tessellation" and c.get("ok")
            and c.get("hierarchy", False) == default}
    goals = []
    big, small = max(samples), min(samples)
    if big in tess:
        c = tess[big]
        goals += [{"goal": f"csf on the largest terrain >= {GOAL_FPS:g} fps", "value": c["fps"],
                   "met": bool(c["fps"] >= GOAL_FPS)},
                  {"goal": f"process under {GOAL_RSS_MB:g} MB on the largest terrain", "value": c["rss_mb"],
                   "met": bool(c["rss_mb"] < GOAL_RSS_MB)},
                  {"goal": f"PSNR within 5 deg >= {GOAL_PSNR_DB:g} dB on the largest terrain (1-spp reference)",
                   "value": c["psnr_disc_5deg_db"], "met": bool(c["psnr_disc_5deg_db"] >= GOAL_PSNR_DB)},
                  {"goal": f"PSNR within 5 deg >= {GOAL_PSNR_DB:g} dB on the largest terrain (4x4-supersampled "
                           f"reference)", "value": c["psnr_disc_5deg_ssaa_db"],
                   "met": bool(c["psnr_disc_5deg_ssaa_db"] >= GOAL_PSNR_DB)}]
    if big in tess and small in tess:
        growth = tess[big]["select_ms"] / max(tess[small]["select_ms"], tol.small)
        goals.append({"goal": f"selection grows <= {GOAL_SELECT_GROWTH:g}x from the smallest to the largest terrain",
                      "value": growth, "met": bool(growth <= GOAL_SELECT_GROWTH)})
    for hierarchy in (True, False):        # each selection's growth, for the comparison
        sel = {c["samples"]: c for c in cases if c["backend"] == "tessellation" and c.get("ok")
               and c.get("hierarchy", False) == hierarchy}
        if hierarchy != default and big in sel and small in sel:
            growth = sel[big]["select_ms"] / max(sel[small]["select_ms"], tol.small)
            goals.append({"goal": f"({'tree' if hierarchy else 'flat'} selection, not the default) selection grows "
                                  f"<= {GOAL_SELECT_GROWTH:g}x", "value": growth,
                          "met": bool(growth <= GOAL_SELECT_GROWTH)})
    return goals


def _row(c) -> str:
    if not c.get("ok"):
        return f"{c['backend']:13s} {c['samples']:5d}  -- {c.get('reason')}"
    name = "full"
    if c["backend"] == "tessellation":
        name = f"{'tree' if c.get('hierarchy') else 'flat'} P={c['patch_samples']}"
    return (f"{name:13s} {c['samples']:5d} {c['full_triangles'] / 1e6:7.1f}M {c['frame_ms']:9.1f} "
            f"{c['select_ms']:8.2f} {c['rss_mb']:8.0f} {c['triangles']:10d} {c['psnr_disc_5deg_db']:7.1f} "
            f"{c['psnr_disc_5deg_ssaa_db']:7.1f}")


def _chart(report, path) -> None:
    plt = pyplot()
    fig, axs = plt.subplots(2, 3, figsize=(15, 8.5))
    panels = (("frame_ms", "frame time: selection + draw (ms)"), ("select_ms", "selection, CPU side (ms)"),
              ("rss_mb", "peak resident memory (MB)"), ("triangles", "triangles drawn"),
              ("psnr_disc_5deg_db", "PSNR within 5° of the POI (dB)"), ("fps", "frames per second"))
    for ax, (key, title) in zip(axs.ravel(), panels):
        for backend, hierarchy, style, label in (("tessellation", True, "o-", "tessellation, tree selection (csf)"),
                                                 ("tessellation", False, "^-", "tessellation, flat selection (csf)"),
                                                 ("full", False, "s--", "full (indexed mesh)")):
            cs = [c for c in report["cases"] if c["backend"] == backend and c.get("ok")
                  and c.get("hierarchy", False) == hierarchy]
            if cs:
                ax.plot([c["full_triangles"] for c in cs], [min(c[key], 99.0) if key.startswith("psnr") else c[key]
                                                            for c in cs], style, label=label)
        label_axes(ax, "terrain triangles at full detail", None, title, "log",
                   "log" if key in ("frame_ms", "triangles", "rss_mb") else None, "both", None)
    axs[0, 2].axhline(GOAL_RSS_MB, color="r", lw=0.8, ls=":")
    from ..render.tessellate import TessellationConfig

    cs = [c for c in report["cases"] if c["backend"] == "tessellation" and c.get("ok")
          and c.get("hierarchy", False) == TessellationConfig().hierarchy]
    if cs:
        axs[1, 1].plot([c["full_triangles"] for c in cs], [c["psnr_disc_5deg_ssaa_db"] for c in cs], "o:",
                       label="tessellation against the 4x4-supersampled reference")
        axs[1, 1].legend(fontsize=8)
    axs[1, 1].axhline(GOAL_PSNR_DB, color="r", lw=0.8, ls=":")
    axs[1, 2].axhline(GOAL_FPS, color="r", lw=0.8, ls=":")
    axs[0, 0].legend()
    fig.suptitle("PLOD against terrain size, 1280x720, llvmpipe (goals dotted)")
    save_figure(fig, path, dpi=110)


def run_scale_bench(json_path=None, chart_path=None, quick: bool = False) -> int:
    """``headplod bench plod --scale``: measure, print the table and the goals, write JSON and the chart; 0."""
    def say(text):
        note(text)                                  # nothing with -q

    report = scale_report(samples=QUICK_SAMPLES if quick else SCALE_SAMPLES, frames=2 if quick else 9, progress=say,
                          patch_sweep=not quick)
    print(f"{'back end':13s} {'grid':>5s} {'terrain':>8s} {'frame ms':>9s} {'sel ms':>8s} {'RSS MB':>8s} "
          f"{'triangles':>10s} {'PSNR 5°':>7s} {'4x4 ref':>7s}")
    for c in report["cases"] + report["patch_sweep"]:
        print(_row(c))
    for g in report["goals"]:
        print(f"{'met    ' if g['met'] else 'NOT met'} {g['goal']}: {g['value']:.2f}")
    if json_path:
        from .outputs import write_json
        write_json(json_path, report)
    if chart_path:
        _chart(report, chart_path)
    return 0
