"""Foveated resolution layers (``--foveate``) measured: speed against ``full`` and plain ``csf``, seams, quality.

Parts of ``headplod bench plod`` (each returns JSON-ready dicts): :func:`foveate_speed` (the demo's loop,
interleaved on one tracked pose sequence), :func:`viewpoint_frames` (a still frame per viewpoint through the
frame step), :func:`seam_profiles` (luminance across each layer border against ``full``'s), :func:`quality`,
:func:`seam_chart`, :func:`layer_pictures`; :func:`run` does all of it into a folder.

Units: luminance relative linear (Rec. 709 weights on linearised sRGB, 0 … 1); distances in output px or
degrees at the screen centre (``px_per_deg``); times in ms.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import cv2
import numpy as np

from ..demo import loop as lp
from ..demo import viewpoints as vps
from ..render import TerrainRenderer, create_context
from ..render.foveate import FoveationConfig
from ..render.overlay import overlay_layers, overlay_poi
from ..render.still import TerrainScene
from .harness import SIZE, TRACKER_COV_DEG2, BenchScene, poi_disc, progress as progress_to, pyplot
from .harness import quality as image_quality, release_step, save_figure, write_png
from .outputs import write_json

__all__ = ["foveate_speed", "viewpoint_frames", "seam_profiles", "quality", "seam_chart", "layer_pictures",
           "luminance", "run", "summary_lines"]

#: Width of the windows either side of a border's blend band whose mean luminances make the step, deg.
STEP_WINDOW_DEG = 0.5
#: Angular sectors for the local steps (a seam on one side of the POI does not cancel one on the other).
SECTORS = 32


def luminance(image: np.ndarray) -> np.ndarray:
    """Relative linear luminance (H, W) float64 in 0 … 1 of an sRGB (H, W, 3) uint8 image (RGB order)."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"luminance: image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    c = img.astype(np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return lin @ np.array([0.2126, 0.7152, 0.0722])


def foveate_speed(scene=None, viewpoints=tuple(vps.VIEWPOINTS), frames: int = 20, size=SIZE, source="synthetic",
                  mode: str = "csf", uncertainty: str = "adaptive", config: FoveationConfig | None = None,
                  hud: bool = True, ctx=None, progress=None) -> dict:
    """Frame time of ``full``, ``mode`` and ``mode --foveate`` per viewpoint, interleaved on one pose sequence.

    ``source``: the pose source spec (:class:`headplod.demo.loop.TrackerPoses`), tracked once beforehand;
    ``frames`` ≥ 2 (the first is left out of the medians); ``hud``: draw the HUD as the headless demo does.
    Per viewpoint: ``full_ms``, ``plain_ms``, ``foveate_ms`` (median frame, ms), ``plain_ratio``,
    ``foveate_ratio`` (full's over theirs), ``frames``, ``stage_ms`` (median per stage, per run), ``triangles``,
    ``foveate_triangles_per_layer``, ``foveate_layers``.
    """
    if frames < 2:
        raise ValueError(f"foveate_speed: frames must be >= 2, got {frames}")
    ctx = ctx or create_context()
    scene = scene or TerrainScene.build(_source_screen(source))
    runs = (("plain", mode, False), ("foveate", mode, True), ("full", "full", False))
    poses = None
    renderers = [TerrainRenderer(ctx, size=tuple(size)) for _ in runs]
    out = {}
    try:
        for vp in viewpoints:
            if poses is None:              # tracked once, before the runs: the frames time no tracking
                poses = _tracked(source, scene.screen, frames)
            loops = [lp.DemoLoop(scene, lp.ReplayPoses(poses, scene.screen), renderers[k], mode=m,
                                 uncertainty=uncertainty if m != "full" else "none", viewpoint=vp, hud=hud,
                                 foveate=fov, foveation=config)
                     for k, (_, m, fov) in enumerate(runs)]
            per = {name: [] for name, _, _ in runs}
            stages = {name: [] for name, _, _ in runs}
            for i in range(len(poses)):
                order = list(range(len(runs)))
                order = order[i % len(order):] + order[:i % len(order)]     # each run leads in turn
                for k in order:
                    result = loops[k].step()
                    if i > 0:
                        per[runs[k][0]].append(result.frame_ms)
                        stages[runs[k][0]].append(result.stage_ms)
                if progress:
                    progress(f"speed {vp} frame {i + 1}/{len(poses)}")
            med = {name: float(np.median(v)) if v else float("nan") for name, v in per.items()}
            fov_loop = loops[1]
            out[vp] = {"full_ms": med["full"], "plain_ms": med["plain"], "foveate_ms": med["foveate"],
                       "plain_ratio": med["full"] / med["plain"], "foveate_ratio": med["full"] / med["foveate"],
                       "frames": len(per["full"]),
                       "stage_ms": {name: {s: float(np.median([st.get(s, 0.0) for st in v])) for s in lp.STAGES}
                                    for name, v in stages.items() if v},
                       "triangles": int(loops[0].last.triangles) if loops[0].last else None,
                       "foveate_triangles_per_layer": list(fov_loop.foveated.last_triangles_per_layer),
                       "foveate_layers": [_layer_dict(l) for l in fov_loop.foveated.last_layers]}
            for loop in loops:
                if loop.foveated is not None:
                    loop.foveated.release()
    finally:
        for r in renderers:
            r.release()
    return out


def _source_screen(source):
    """The screen of a pose source spec (its ``screen.yaml``, else the embedded one)."""
    first = lp.TrackerPoses(source, max_frames=1)
    first.close()
    return first.screen


def _tracked(source, screen, frames: int) -> list:
    """The first ``frames`` poses of a tracked source, as a list (images dropped)."""
    out = lp.read_all_poses(lp.TrackerPoses(source, screen=screen, max_frames=frames))
    if len(out) < 2:
        raise ValueError(f"foveate_speed: the source {source!r} gave {len(out)} poses, need at least 2")
    return out


def _layer_dict(layer) -> dict:
    return {"scale": layer.scale, "inner_deg": round(layer.inner_deg, 3),
            "outer_deg": None if math.isinf(layer.outer_deg) else round(layer.outer_deg, 3)}


def viewpoint_frames(scene=None, viewpoints=tuple(vps.VIEWPOINTS), size=SIZE, mode: str = "csf",
                     uncertainty: str = "adaptive", cov_deg2=TRACKER_COV_DEG2, config: FoveationConfig | None = None,
                     ctx=None) -> dict:
    """One still frame per viewpoint from the default view, each through the demo's frame step.

    Per viewpoint: ``full``, ``plain`` (``mode`` without hysteresis), ``foveate`` (as layers) and ``levels``
    (the plain step's next frame, levels view), (H, W, 3) uint8 RGB; ``poi_px`` (2,) output px,
    ``px_per_deg``, ``cov_deg2``, ``layers`` (as drawn), ``blend_deg``, ``triangles``, ``triangles_per_layer``.
    """
    config = config or FoveationConfig()
    b = BenchScene(size, scene=scene or TerrainScene.build(lp.default_screen()), ctx=ctx)
    view, cov = b.view(0.0, cov_deg2), np.asarray(cov_deg2, dtype=np.float64)
    out = {}
    try:
        for vp in viewpoints:
            placed = vps.place(b.scene, vp)
            full = b.mesh_step("full", "none", scene=placed)(view, placed.model)
            plain_step = b.mesh_step(mode, uncertainty, scene=placed, hysteresis=False)
            plain = plain_step(view, placed.model)
            levels = plain_step(b.view_at(cov_deg2)(1), placed.model, "levels")
            fov_step = b.mesh_step(mode, uncertainty, scene=placed, hysteresis=False, foveate=True,
                                   foveation=config)
            fov = fov_step(view, placed.model)
            layers = fov_step.backend.foveated
            out[vp] = {"full": full.image, "plain": plain.image, "foveate": fov.image, "levels": levels.image,
                       "poi_px": b.poi_image, "px_per_deg": b.px_per_deg, "cov_deg2": cov,
                       "layers": list(layers.last_layers), "blend_deg": config.blend_deg,
                       "triangles": plain.triangles, "triangles_per_layer": list(layers.last_triangles_per_layer)}
            release_step(fov_step)
    finally:
        b.release()
    return out


def _step(lum: np.ndarray, r: np.ndarray, inner_px: float, outer_px: float, window_px: float, mask=None) -> float:
    """Mean luminance in [outer, outer + window) minus that in [inner - window, inner) (px from the POI)."""
    out_sel = (r >= outer_px) & (r < outer_px + window_px)
    in_sel = (r >= inner_px - window_px) & (r < inner_px)
    if mask is not None:
        out_sel &= mask
        in_sel &= mask
    if not out_sel.any() or not in_sel.any():
        return float("nan")
    return float(lum[out_sel].mean() - lum[in_sel].mean())


def seam_profiles(frames: dict, half_width_deg: float = 2.0, window_deg: float = STEP_WINDOW_DEG,
                  sectors: int = SECTORS) -> dict:
    """Luminance across each layer border of :func:`viewpoint_frames`' frames, for ``full``, ``plain``, ``foveate``.

    For a border of radius R px about the POI with blend band [R - b, R]: the profile is the mean luminance at
    R + s px (1 px bins, s within ±``half_width_deg``); the step is the mean over [R, R + w) minus that over
    [R - b - w, R - b) (w = ``window_deg``), over the whole circle and per angular sector.

    Per viewpoint, per finite border: ``border_deg``, ``radius_px``, ``blend_px``, ``offset_px`` (S,),
    ``profile`` {image: (S,)}, ``step`` {image}, ``step_vs_full`` (plain's and foveate's minus full's),
    ``sector_step_vs_full_rms`` (RMS over the sectors of that difference), ``coverage`` (fraction of the
    circle in the image).
    """
    out = {}
    for vp, f in frames.items():
        ppd = float(f["px_per_deg"])
        h, w = f["full"].shape[:2]
        yy, xx = np.mgrid[0:h, 0:w]
        dx, dy = xx + 0.5 - f["poi_px"][0], yy + 0.5 - f["poi_px"][1]
        r = np.hypot(dx, dy)
        angle = np.mod(np.arctan2(dy, dx), 2 * np.pi)
        sector = np.minimum((angle / (2 * np.pi) * sectors).astype(int), sectors - 1)
        lum = {name: luminance(f[name]) for name in ("full", "plain", "foveate")}
        blend_px = float(f["blend_deg"]) * ppd
        half = int(math.ceil(half_width_deg * ppd))
        window = window_deg * ppd
        borders = []
        for layer in f["layers"][:-1]:
            if not math.isfinite(layer.outer_deg):
                continue
            R = layer.outer_deg * ppd
            offsets = np.arange(-half, half + 1)
            bins = np.floor(r - R).astype(np.int64)
            sel = (bins >= -half) & (bins <= half)
            counts = np.bincount(bins[sel] + half, minlength=2 * half + 1)
            profiles, steps, sector_rms = {}, {}, {}
            for name, L in lum.items():
                sums = np.bincount(bins[sel] + half, weights=L[sel], minlength=2 * half + 1)
                profiles[name] = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan).tolist()
                steps[name] = _step(L, r, R - blend_px, R, window)
            per_sector = {name: np.array([_step(L, r, R - blend_px, R, window, sector == s) for s in range(sectors)])
                          for name, L in lum.items()}
            for name in ("plain", "foveate"):
                d = per_sector[name] - per_sector["full"]
                d = d[np.isfinite(d)]
                sector_rms[name] = float(np.sqrt(np.mean(d ** 2))) if len(d) else float("nan")
            circle = np.linspace(0, 2 * np.pi, 720, endpoint=False)
            cx, cy = f["poi_px"][0] + R * np.cos(circle), f["poi_px"][1] + R * np.sin(circle)
            coverage = float(np.mean((cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)))
            borders.append({"border_deg": float(layer.outer_deg), "radius_px": float(R), "blend_px": blend_px,
                            "offset_px": offsets.tolist(), "profile": profiles, "step": steps,
                            "step_vs_full": {n: steps[n] - steps["full"] for n in ("plain", "foveate")},
                            "sector_step_vs_full_rms": sector_rms, "coverage": coverage})
        out[vp] = borders
    return out


def quality(frames: dict) -> dict:
    """Per viewpoint: ``psnr_5deg_db`` and ``flip`` {plain, foveate} against ``full``, and
    ``psnr_5deg_foveate_vs_plain_db`` (inf: the fovea is the plain frame's pixels)."""
    from .harness import DISC_DEG
    from ..render.image_metrics import psnr_db

    out = {}
    for vp, f in frames.items():
        disc = poi_disc(f["full"].shape, f["poi_px"], DISC_DEG * f["px_per_deg"])
        q = {n: image_quality(f[n], f["full"], disc, f["px_per_deg"]) for n in ("plain", "foveate")}
        out[vp] = {"psnr_5deg_db": {n: q[n]["psnr_disc_5deg_db"] for n in q}, "flip": {n: q[n]["flip"] for n in q},
                   "psnr_5deg_foveate_vs_plain_db": psnr_db(f["foveate"], f["plain"], disc)}
    return out


def seam_chart(profiles: dict, path) -> str:
    """The profiles of :func:`seam_profiles` as a chart (PNG at ``path``): one panel per viewpoint and border."""
    plt = pyplot()
    panels = [(vp, b) for vp, borders in profiles.items() for b in borders]
    if not panels:
        raise ValueError("seam_chart: no finite layer border in the profiles")
    fig, axes = plt.subplots(1, len(panels), figsize=(4.4 * len(panels), 3.6), squeeze=False)
    styles = {"full": {"color": "black", "lw": 1.6}, "plain": {"color": "tab:blue", "lw": 1.0, "ls": "--"},
              "foveate": {"color": "tab:red", "lw": 1.2}}
    for ax, (vp, b) in zip(axes[0], panels):
        x = np.asarray(b["offset_px"], dtype=np.float64)
        for name in ("full", "plain", "foveate"):
            label = {"full": "full", "plain": "csf", "foveate": "csf --foveate"}[name]
            ax.plot(x, np.asarray(b["profile"][name], dtype=np.float64) * 100, label=label, **styles[name])
        ax.axvspan(-b["blend_px"], 0, color="0.85", label="blend band")
        ax.axvline(0, color="0.5", lw=0.8)
        sv = b["step_vs_full"]
        ax.set_title(f"{vp}: border {b['border_deg']:.2f}° ({b['coverage']:.0%} in view)\n"
                     f"step - full's: foveate {sv['foveate'] * 100:+.2f}, csf {sv['plain'] * 100:+.2f} (% lum.)",
                     fontsize=8)
        ax.set_xlabel("distance from the border, px (+: outside, coarser layer)")
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("mean luminance along the border, % of white")
    axes[0, -1].legend(fontsize=7)
    fig.suptitle("foveation seams: luminance across each layer border (averaged along it)", fontsize=9)
    return str(save_figure(fig, path, dpi=110))


def layer_pictures(frames: dict, folder) -> dict:
    """A picture per viewpoint (PNG in ``folder``): the foveated frame's layers on the levels view, the POI and
    its 2σ ellipse; {viewpoint: path}."""
    out = {}
    for vp, f in frames.items():
        img = overlay_layers(f["levels"], f["poi_px"], f["layers"], f["px_per_deg"])
        img = overlay_poi(img, f["poi_px"], f["cov_deg2"], f["px_per_deg"], inplace=True)
        sigma = math.sqrt(float(np.linalg.eigvalsh(f["cov_deg2"]).max()))
        text = (f"{vp}: layers " + ", ".join(f"x{l.scale:g} to {l.outer_deg:.2f} deg" if math.isfinite(l.outer_deg)
                                             else f"x{l.scale:g} beyond" for l in f["layers"])
                + f"; POI 2-sigma ellipse (sigma {sigma:.2f} deg)")
        (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
        y = img.shape[0] - 10
        img[max(y - th - 6, 0):min(y + base + 2, img.shape[0]), 4:min(16 + tw, img.shape[1])] //= 3
        cv2.putText(img, text, (10, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        out[vp] = write_png(Path(folder) / f"foveate_layers_{vp}.png", img)
    return out


def run(folder, viewpoints=tuple(vps.VIEWPOINTS), frames: int = 20, speed: bool = True, progress=None) -> dict:
    """Speed, seams, quality, chart and pictures into ``folder``; the summary (also ``foveate.json``)."""
    folder = Path(folder)
    progress = progress or progress_to("plod_foveate")
    t0 = time.perf_counter()
    ctx = create_context()
    scene = TerrainScene.build(_source_screen("synthetic"))
    summary = {"size": list(SIZE), "config": FoveationConfig().__dict__}
    if speed:
        summary["speed"] = foveate_speed(scene, viewpoints, frames=frames, ctx=ctx, progress=progress)
    progress("still frames")
    still = viewpoint_frames(scene, viewpoints, ctx=ctx)
    summary["quality"] = quality(still)
    prof = seam_profiles(still)
    summary["seams"] = prof
    summary["seam_chart"] = seam_chart(prof, folder / "foveate_seams.png")
    summary["pictures"] = layer_pictures(still, folder)
    for vp, f in still.items():
        write_png(folder / f"foveate_frame_{vp}.png", f["foveate"])
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    write_json(folder / "foveate.json", summary, indent=1, default=_json_default)
    return summary


def summary_lines(s: dict) -> list:
    """A :func:`run` summary as text: per viewpoint its speed, quality and seams."""
    lines = []
    for vp, q in s["quality"].items():
        if vp in s.get("speed", {}):
            sp = s["speed"][vp]
            lines.append(f"foveate {vp}: full {sp['full_ms']:.0f} ms, csf {sp['plain_ms']:.1f} ms "
                         f"({sp['plain_ratio']:.1f}x), csf --foveate {sp['foveate_ms']:.1f} ms "
                         f"({sp['foveate_ratio']:.1f}x)")
        lines.append(f"   PSNR 5° csf {q['psnr_5deg_db']['plain']:.1f}, csf --foveate {q['psnr_5deg_db']['foveate']:.1f} "
                     f"dB; FLIP csf {q['flip']['plain']:.4f}, csf --foveate {q['flip']['foveate']:.4f}")
        lines += [f"   border {b['border_deg']:.2f}°: step full {b['step']['full'] * 100:+.2f}, foveate "
                  f"{b['step']['foveate'] * 100:+.2f}, csf {b['step']['plain'] * 100:+.2f} (% lum.); sector RMS "
                  f"vs full: foveate {b['sector_step_vs_full_rms']['foveate'] * 100:.2f}, csf "
                  f"{b['sector_step_vs_full_rms']['plain'] * 100:.2f}" for b in s["seams"][vp]]
    return lines


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")
