"""``headplod bench plod``: speed and image quality of each LOD mode against ``full`` (first part).

For the default view (embedded screen, head 60 cm in front of its centre, POI
at the centre) at 1280x720, every mode is run for a few frames of the same
view: the first builds the mesh from scratch, the later ones are the steady
state (only changed base triangles rebuilt). Reported per mode, measured in
the same run: triangles, select / build / render ms of a steady frame, the
frame time as a ratio to ``full``'s, select+build as a fraction of ``full``'s
render time, and the PSNR of the image against ``full``'s, over the whole
image and within 5° of the POI. (FLIP, the velocity sweep and the stability
through the tracker are not measured yet.)
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from .plod.select import MODES, View
from .plod.still import TerrainScene, _px_per_deg, default_head

SIZE = (1280, 720)


def psnr_db(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR (dB) of two 8-bit images, optionally over a boolean mask (H, W); inf when identical."""
    diff = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        diff = diff[mask]
    mse = float(np.mean(diff ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def run_plod_bench(json_path=None, chart_path=None, frames: int = 3) -> int:
    from calib import DEFAULT_SCREEN

    from . import io
    from .render import TerrainRenderer, create_context, off_axis_projection

    screen = io.read_screen(DEFAULT_SCREEN)
    scene = TerrainScene.build(screen)
    renderer = TerrainRenderer(create_context(), size=SIZE)
    head = default_head(screen)
    poi = np.array(screen.size_px, dtype=np.float64) / 2
    view_m, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
    results, images = {}, {}
    order = ["full"] + [m for m in MODES if m != "full"]
    for mode in order:
        selector = scene.selector(mode, "adaptive")
        scene.mesh.clear()
        steady = []
        for k in range(frames):
            t0 = time.perf_counter()
            levels, _ = selector.select(View(head, poi, np.diag([0.25, 0.25]), k / 60))
            t1 = time.perf_counter()
            positions, normals, tri_levels = scene.mesh.update(levels)
            t2 = time.perf_counter()
            renderer.upload(positions, normals, tri_levels)
            image = renderer.render(view_m, proj, scene.model, view_mode="shaded")
            if k > 0:
                steady.append(((t1 - t0) * 1e3, (t2 - t1) * 1e3, renderer.last_render_ms))
        select_ms, build_ms, render_ms = (float(np.median([s[i] for s in steady])) for i in range(3))
        results[mode] = {"triangles": int(len(tri_levels)), "select_ms": select_ms, "build_ms": build_ms,
                         "render_ms": render_ms, "frame_ms": select_ms + build_ms + render_ms,
                         "triangles_per_level": np.bincount(tri_levels, minlength=6).tolist()}
        images[mode] = image
        print(f"bench plod: {mode}", file=sys.stderr)
    # Quality against full, whole image and within 5° of the POI.
    px_per_deg = _px_per_deg(screen, head, SIZE)
    yy, xx = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    centre = poi * np.array(SIZE) / np.array(screen.size_px)
    disc = np.hypot(xx - centre[0], yy - centre[1]) <= 5 * px_per_deg
    full = results["full"]
    for mode, r in results.items():
        r["psnr_db"] = psnr_db(images[mode], images["full"])
        r["psnr_disc_5deg_db"] = psnr_db(images[mode], images["full"], disc)
        r["frame_ratio_full_over_mode"] = full["frame_ms"] / r["frame_ms"]
        r["select_build_over_full_render"] = (r["select_ms"] + r["build_ms"]) / full["render_ms"]
    lines = [f"{'mode':9s} {'triangles':>10s} {'select':>8s} {'build':>8s} {'render':>8s} {'full/x':>7s} "
             f"{'(s+b)/Rf':>9s} {'PSNR':>7s} {'PSNR 5°':>8s}"]
    for mode, r in results.items():
        lines.append(f"{mode:9s} {r['triangles']:10d} {r['select_ms']:8.1f} {r['build_ms']:8.1f} {r['render_ms']:8.1f} "
                     f"{r['frame_ratio_full_over_mode']:7.2f} {r['select_build_over_full_render']:9.1%} "
                     f"{r['psnr_db']:7.1f} {r['psnr_disc_5deg_db']:8.1f}")
    csf = results["csf"]
    goals = [
        {"goal": "csf frame ≥ 5x faster than full (POI at the centre, 1280x720)",
         "value": csf["frame_ratio_full_over_mode"], "met": bool(csf["frame_ratio_full_over_mode"] >= 5)},
        {"goal": "csf select + build ≤ 25% of full's render time", "value": csf["select_build_over_full_render"],
         "met": bool(csf["select_build_over_full_render"] <= 0.25)},
        {"goal": "csf within 5° of the POI identical or ≥ 45 dB PSNR against full",
         "value": csf["psnr_disc_5deg_db"], "met": bool(csf["psnr_disc_5deg_db"] >= 45)},
    ]
    lines.append("")
    for g in goals:
        lines.append(f"  [{'met' if g['met'] else 'NOT MET'}] {g['goal']}: {g['value']:.3g}")
    print("\n".join(lines))
    if json_path:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps({"size": SIZE, "modes": results, "goals": goals}, indent=2))
    if chart_path:
        _chart(results, chart_path)
    return 0


def _chart(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for mode, r in results.items():
        psnr = min(r["psnr_db"], 80.0)
        a1.plot(r["triangles"], psnr, "o")
        a1.annotate(mode, (r["triangles"], psnr), fontsize=8)
        a2.plot(r["frame_ms"], psnr, "o")
        a2.annotate(mode, (r["frame_ms"], psnr), fontsize=8)
    for ax, label in ((a1, "triangles"), (a2, "frame time: select + build + render (ms)")):
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("PSNR against full (dB; identical drawn at 80)")
        ax.grid(True, alpha=0.3)
    fig.suptitle("PLOD modes at 1280x720, POI at the screen centre")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
