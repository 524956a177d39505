"""``headplod bench plod --scale``: PLOD's cost against the terrain's size (issue 14).

One viewpoint (the embedded 24-inch screen, the head 60 cm in front of its
centre, the POI at the centre, the tracker's σ of 0.05°), 1280x720
offscreen, over terrains of 2, 8, 32 and 134 million triangles at full
detail: the built-in DEM (``Terrain.jacksboro()``) with its synthetic
detail, sampled on grids of 1025², 2049², 4097² and 8193² samples (the
detail's shortest wavelength 2.5 sample spacings, so every grid has detail
down to its own resolution; :func:`headplod.plod.patches.height_grid`).
Grids are cached (:func:`headplod.plod.patches.jacksboro_grid`).

Back ends:

- ``tessellation`` (:mod:`headplod.render.tessellate`), with each selection
  (:data:`SELECTIONS`): ``tree``, the quadtree of variable-size patches of
  :mod:`headplod.plod.patch_tree` walked on the CPU (leaves of 64 samples);
  ``flat``, the ``csf`` levels computed per patch on the GPU, with patches
  as large as the image can use (:func:`headplod.plod.patches.patch_samples_for`,
  as ``headplod render``: 64 samples up to 4097², 128 at 8193² for 1280 px).
  The goals are the default selection's (``TessellationConfig.hierarchy``).
  The flat one on the largest terrain also with the other patch sizes of
  64, 128, 256 and 512 samples (``patch_sweep``: fewer patches to select
  and draw, more triangles).
- ``full``: the whole grid as one indexed mesh (``TerrainRenderer``, 24 bytes
  per vertex and 12 per triangle), where it fits (by default up to 2049²:
  4097² needs about 1.6 GB of buffers before llvmpipe's copies).

Each (back end, terrain) runs in its own process, so its peak resident
memory (``ru_maxrss``) is its own: the cached grid loaded, the patch grid,
the GL objects, the frames. Per case: the median over ``frames`` steady
frames of the frame time (selection + draw, no read-back), the selection
time (the CPU's share before drawing: for ``tessellation`` the uniforms and
the split into draw calls, with the flat selection's levels pass and its
24-byte-per-patch read-back, or the tree's numpy walk and its 32-byte-per-node
upload), the triangles drawn (``GL_PRIMITIVES_GENERATED``) and the
PSNR within 5° of the POI against a full-detail render of that region (the
tessellation back end at its finest level, drawing only the patches that
reach the disc's bounding box: ``full`` of the whole 134M terrain need not
fit), with the case's own shading (the tessellation's default ``texture``;
``full``'s mesh shades per vertex, and so does its reference), at 1 and
4x4 samples per pixel.
"""
from __future__ import annotations

import json
import resource
from dataclasses import replace
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SIZE = (1280, 720)
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
#: draw (each drawn patch costs ~2.4 µs on llvmpipe beside its triangles; the levels pass ~0.3 µs a patch),
#: but coarser adaptation (a patch's inner level is its nearest point's), so more triangles. The finest level
#: of a patch of P samples has a vertex every P / 64 samples (8193²: 0.18 px per sample here).
SWEEP_PATCH_SAMPLES = (64, 128, 256, 512)
DISC_DEG = 5.0
COV_DEG2 = np.diag([0.05 ** 2, 0.05 ** 2])
#: The second reference: the same full-detail region drawn at 4x4 the pixels and averaged down.
SUPERSAMPLE = 4
GOAL_FPS = 15.0
GOAL_RSS_MB = 2048.0
GOAL_SELECT_GROWTH = 2.0
GOAL_PSNR_DB = 45.0


def _disc_region(screen, head, size):
    """(disc mask (H, W) bool, its bounding box in NDC (x0, y0, x1, y1), px per deg) around the centre POI."""
    from ..render.still import px_per_deg_at
    from .image_metrics import disc_mask

    w, h = size
    ppd = px_per_deg_at(screen, head, size)
    radius = DISC_DEG * ppd
    disc = disc_mask((h, w), (w / 2, h / 2), radius)
    # NDC y is up, the image's row 0 is the top: the box is symmetric about the centre either way.
    rx, ry = (radius + 4) / (w / 2), (radius + 4) / (h / 2)
    return disc, (-rx, -ry, rx, ry), ppd


def run_case(backend: str, n_samples: int, frames: int = 5, size=SIZE, cache_dir=None, level_bias: float = 0.0,
             patch_samples: int | None = None, hierarchy: bool | None = None, split_factor: int | None = None) -> dict:
    """One (back end, terrain) measured in this process; the result dict (see the module notes).

    The frames come first and the peak memory is read after them; the references (drawn by the
    tessellation back end, the supersampled one in a 4x4 larger framebuffer) come after.
    """
    from calib import DEFAULT_SCREEN

    from .. import io
    from ..plod.patches import PatchGrid, grid_normals, jacksboro_grid, patch_samples_for
    from ..plod.select import SelectorConfig
    from ..render import TerrainRenderer, create_context, off_axis_projection
    from ..render.still import default_head
    from ..plod.view import View
    from ..render.frame import FrameStep, TessellationBackend, one_frame
    from ..render.tessellate import TessellationConfig, TessellationRenderer, grid_model
    from .image_metrics import psnr_db

    if backend not in BACKENDS:
        raise ValueError(f"run_case: backend must be one of {BACKENDS}, got {backend!r}")
    t_start = time.perf_counter()
    z, dx, dy, origin = jacksboro_grid(n_samples, cache_dir)
    screen = io.read_screen(DEFAULT_SCREEN)
    head = default_head(screen)
    poi = np.array(screen.size_px, float) / 2
    view, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
    disc, region, _ = _disc_region(screen, head, size)
    ctx = create_context(require=430)
    tree = bool(TessellationConfig().hierarchy if hierarchy is None else hierarchy)
    # Default patches: the flat grid's as large as the image can use (the render command's rule); the tree's
    # leaves keep one vertex per sample at the finest level.
    p = (int(patch_samples) if patch_samples is not None else MIN_PATCH_SAMPLES if tree
         else patch_samples_for(n_samples, max(size), smallest=MIN_PATCH_SAMPLES))
    grid = PatchGrid.build(z, dx, dy, p, origin_m=origin)
    model = grid_model(grid, screen)
    config = TessellationConfig(patch_samples=p)
    if hierarchy is not None or split_factor is not None:
        config = replace(config, **({} if hierarchy is None else {"hierarchy": bool(hierarchy)}),
                         **({} if split_factor is None else {"split_factor": int(split_factor)}))
    steady, extra = [], {}
    if backend == "tessellation":
        tess = TessellationRenderer(ctx, grid, size=size, config=config,
                                    selection=SelectorConfig(level_bias=level_bias))
        extra["setup_s"] = time.perf_counter() - t_start
        step = FrameStep(TessellationBackend(tess), screen, tess.selection)
        for k in range(frames + 1):
            out = step(View(head, poi, COV_DEG2, k / 60), model)
            if k:
                steady.append((out.stage_ms["select"], out.stage_ms["render"], out.triangles,
                               out.details["draw_calls"]))
        image = out.image
        extra["drawn_patches"] = int(out.details["patches"])
        if tess.last_selection is not None and backend == "tessellation" and config.hierarchy:
            extra["nodes_evaluated"] = int(tess.last_selection.evaluated)
            extra["nodes_by_depth"] = np.bincount(tess.last_selection.depth, minlength=tess._tree.depth + 1).tolist()
            extra["capped"] = int(tess.last_selection.capped)
    else:
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
        del positions, normals, indices
        extra["setup_s"] = time.perf_counter() - t_start
        query = ctx.query(primitives=True)
        for k in range(frames + 1):
            with query:
                image = mesh.render(view, proj, model)
            if k:
                steady.append((0.0, mesh.last_render_ms, int(query.primitives), 1))
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if backend == "full":
        mesh.release()
    if backend == "full" or p != MIN_PATCH_SAMPLES:      # the reference needs patches of one vertex per sample
        if backend == "tessellation":
            tess.release()
        fine = PatchGrid.build(z, dx, dy, MIN_PATCH_SAMPLES, origin_m=origin)
        # ``full``'s mesh shades per vertex: its reference does too.
        tess = TessellationRenderer(ctx, fine, size=size, config=TessellationConfig(
            patch_samples=MIN_PATCH_SAMPLES, shading="vertex" if backend == "full" else config.shading))
    # The references: every patch reaching the disc's box at the finest level, at 1 and 4x4 samples per pixel.
    t0 = time.perf_counter()
    ref = one_frame(TessellationBackend(tess, "full", region_ndc=region), screen, model, head, poi, COV_DEG2)
    reference, ref_stats = ref.image, {"triangles": ref.triangles}
    extra["reference_s"] = time.perf_counter() - t0
    reference_ss = one_frame(TessellationBackend(tess, "full", region_ndc=region, supersample=SUPERSAMPLE), screen,
                             model, head, poi, COV_DEG2).image
    select_ms, render_ms = (float(np.median([s[j] for s in steady])) for j in range(2))
    return {"backend": backend, "samples": n_samples, "level_bias": level_bias, "full_triangles": grid.full_triangles,
            "shading": "vertex" if backend == "full" else config.shading,
            "hierarchy": bool(config.hierarchy) and backend == "tessellation", "split_factor": config.split_factor,
            "patch_samples": p, "patches": grid.n_patches ** 2, "frames": frames,
            "frame_ms": select_ms + render_ms, "select_ms": select_ms, "render_ms": render_ms,
            "fps": 1e3 / (select_ms + render_ms), "triangles": int(steady[-1][2]), "draw_calls": int(steady[-1][3]),
            "rss_mb": rss_mb, "psnr_disc_5deg_db": psnr_db(image, reference, disc),
            "psnr_disc_5deg_ssaa_db": psnr_db(image, reference_ss, disc),
            "reference_triangles": ref_stats["triangles"], **extra,
            "select_ms_all": [s[0] for s in steady], "render_ms_all": [s[1] for s in steady]}


def _run_in_subprocess(backend: str, n_samples: int, frames: int, cache_dir, patch_samples=None,
                       selection: str | None = None) -> dict:
    cmd = [sys.executable, "-m", "headplod.bench.plod_scale", backend, str(n_samples), str(frames),
           "-" if cache_dir is None else str(cache_dir), "0", str(patch_samples or "-"), selection or "-"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        return {"backend": backend, "samples": n_samples, "ok": False,
                "reason": (proc.stderr.strip().splitlines() or ["exit status %d" % proc.returncode])[-1]}
    return {**json.loads(proc.stdout.strip().splitlines()[-1]), "ok": True}


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
        subprocess.run([sys.executable, "-c", f"from headplod.plod.patches import jacksboro_grid; "
                        f"jacksboro_grid({n}, {repr(str(cache_dir)) if cache_dir else None})"], check=True)
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
                cases.append(_run_in_subprocess(backend, n, frames, cache_dir, selection=selection))
                say("  " + _row(cases[-1]))
    sweep = []
    if patch_sweep:
        from ..plod.patches import patch_samples_for
        default_p = patch_samples_for(max(samples), max(SIZE), smallest=MIN_PATCH_SAMPLES)
        for p in SWEEP_PATCH_SAMPLES:
            if p != default_p and (max(samples) - 1) % p == 0:
                say(f"tessellation on {max(samples)}x{max(samples)}, patches of {p} samples")
                sweep.append(_run_in_subprocess("tessellation", max(samples), frames, cache_dir, p, selection="flat"))
                say("  " + _row(sweep[-1]))
    return {"size": list(SIZE), "patch_samples": "flat: patches.patch_samples_for(samples, 1280); tree: leaves of 64",
            "cov_deg2": COV_DEG2.tolist(), "cases": cases,
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
        growth = tess[big]["select_ms"] / max(tess[small]["select_ms"], 1e-9)
        goals.append({"goal": f"selection grows <= {GOAL_SELECT_GROWTH:g}x from the smallest to the largest terrain",
                      "value": growth, "met": bool(growth <= GOAL_SELECT_GROWTH)})
    for hierarchy in (True, False):        # each selection's growth, for the comparison
        sel = {c["samples"]: c for c in cases if c["backend"] == "tessellation" and c.get("ok")
               and c.get("hierarchy", False) == hierarchy}
        if hierarchy != default and big in sel and small in sel:
            growth = sel[big]["select_ms"] / max(sel[small]["select_ms"], 1e-9)
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
    import matplotlib  # imported only when a chart is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
        ax.set_xscale("log")
        if key in ("frame_ms", "triangles", "rss_mb"):
            ax.set_yscale("log")
        ax.set_title(title)
        ax.set_xlabel("terrain triangles at full detail")
        ax.grid(True, which="both", alpha=0.3)
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
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_scale_bench(json_path=None, chart_path=None, quick: bool = False) -> int:
    """``headplod bench plod --scale``: measure, print the table and the goals, write JSON and the chart; 0."""
    def say(text):
        print(text, file=sys.stderr, flush=True)

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


if __name__ == "__main__":  # one case (scale_report's subprocesses): BACKEND SAMPLES FRAMES [CACHE_DIR [BIAS [PATCH [tree|flat [SPLIT]]]]]; "-" = default
    _backend, _n, _frames = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    _cache = sys.argv[4] if len(sys.argv) > 4 and sys.argv[4] != "-" else None
    _arg = (lambda k: sys.argv[k] if len(sys.argv) > k and sys.argv[k] != "-" else None)
    _result = run_case(_backend, _n, _frames, cache_dir=_cache, level_bias=float(_arg(5) or 0.0),
                       patch_samples=int(_arg(6)) if _arg(6) else None,
                       hierarchy={"tree": True, "flat": False, None: None}[_arg(7)],
                       split_factor=int(_arg(8)) if _arg(8) else None)
    print(json.dumps(_result))
