"""``raymask`` against ``full`` and ``csf`` on the three viewpoints (issue 13), for ``headplod bench plod``.

:func:`raymask_report`, from the default view (:mod:`.harness`), on each viewpoint of
:mod:`headplod.demo.viewpoints`:

- **Speed**: ``full``, ``csf`` and ``raymask`` (silhouettes on and off, at each mask contrast), each through
  its frame step, in alternation round by round (:func:`.harness.alternate`), the median of the rounds after
  a warm-up. ``raymask``'s time: ``mask_ms`` (the select stage) + ``cast_ms`` + ``classify_ms`` +
  ``raster_ms``.
- **Quality** against ``full``: PSNR (whole, 5° disc), FLIP.
- **Silhouettes**: the largest distance between the sky/terrain boundaries of each image and ``full``'s
  (:func:`silhouette_displacement_px`), silhouette preservation on and off.
- **Inset sweep** (the paper's experiment): frame time and FLIP against the inset's diameter, per contrast.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..demo.viewpoints import place, viewpoint_names
from ..plod.raymask import RayMaskConfig
from ..render import TerrainRenderer, overlay_poi
from .harness import FRAME_STAGES, SIZE, BenchScene, alternate, progress, pyplot, save_figure, steady_frame, write_png

__all__ = ["raymask_report", "silhouette_displacement_px", "chart_raymask", "raymask_picture"]

INSETS_DEG = (2.0, 5.0, 10.0, 15.0)
#: The raymask back end's figures kept from a frame's details.
RAY_COUNTS = ("rays", "ring_rays", "fill_rays", "silhouette_rays", "silhouette_quads", "drawn_quads")


def _sky(image: np.ndarray, background) -> np.ndarray:
    """(H, W) bool: pixels of exactly the background colour."""
    return np.all(image == np.round(np.asarray(background) * 255).astype(np.uint8), axis=2)


def silhouette_displacement_px(image: np.ndarray, reference: np.ndarray, background) -> dict:
    """How far the sky/terrain boundary (terrain pixels with a sky pixel, exactly ``background``, among their 8
    neighbours) of ``image`` lies from ``reference``'s, px: ``max_px`` (the Hausdorff distance; 0 with no
    boundary in either), ``p999_px`` (99.9th percentile) and ``pixels`` (the reference's boundary pixels).
    """
    def boundary(img):
        sky = _sky(img, background).astype(np.uint8)
        near_sky = cv2.dilate(sky, np.ones((3, 3), np.uint8)).astype(bool)
        return near_sky & ~sky.astype(bool)

    a, b = boundary(image), boundary(reference)
    if not a.any() and not b.any():
        return {"max_px": 0.0, "p999_px": 0.0, "pixels": 0}
    if not a.any() or not b.any():
        return {"max_px": float("inf"), "p999_px": float("inf"), "pixels": int(b.sum())}
    da = cv2.distanceTransform((~a).astype(np.uint8), cv2.DIST_L2, 5)    # distance to a's boundary
    db = cv2.distanceTransform((~b).astype(np.uint8), cv2.DIST_L2, 5)
    d = np.concatenate([db[a], da[b]])
    return {"max_px": float(d.max()), "p999_px": float(np.percentile(d, 99.9)), "pixels": int(b.sum())}


def raymask_picture(image: np.ndarray, mask, silhouette_quads: np.ndarray, poi_image, cov_deg2,
                    px_per_deg: float) -> np.ndarray:
    """The frame with its ray mask drawn on it, (H, W, 3) uint8 RGB: the ring samples dark, the inset's outline
    yellow, the silhouette quads magenta, the POI and its 2σ ellipse red."""
    out = image.copy()
    h, w = out.shape[:2]
    ring = np.round(mask.samples_px[mask.n_fill:]).astype(int)
    ok = (ring[:, 0] >= 0) & (ring[:, 0] < w) & (ring[:, 1] >= 0) & (ring[:, 1] < h)
    out[ring[ok, 1], ring[ok, 0]] = (out[ring[ok, 1], ring[ok, 0]] * 0.35).astype(np.uint8)
    sil = mask.samples_px[mask.quads[silhouette_quads]]
    cv2.polylines(out, list(np.round(sil * 16).astype(np.int32)), True, (230, 40, 230), 1, cv2.LINE_AA, shift=4)
    ring0 = mask.samples_px[mask.n_fill:][mask.ring_of[mask.n_fill:] == 0]
    if len(ring0):
        order = np.argsort(np.arctan2(ring0[:, 1] - poi_image[1], ring0[:, 0] - poi_image[0]))
        cv2.polylines(out, [np.round(ring0[order] * 16).astype(np.int32)], True, (250, 220, 40), 1, cv2.LINE_AA,
                      shift=4)
    return overlay_poi(out, poi_image, cov_deg2, px_per_deg, n_sigma=2.0)


def raymask_report(viewpoints=None, rounds: int = 5, contrasts=(1.0, 0.3), insets_deg=INSETS_DEG,
                   sweep_contrasts=(1.0, 0.05), sweep_viewpoint: str = "mountains", flip: bool = True,
                   size=SIZE, picture_dir=None, picture_cov_deg2=((1.0, 0.0), (0.0, 1.0)), progress=None) -> dict:
    """Measure ``raymask`` against ``full`` and ``csf`` (module notes); a JSON-ready dict.

    ``viewpoints``: names (default all); ``rounds``: timed rounds after a warm-up; ``contrasts``: mask contrasts
    at the default inset (the first the default config's); ``insets_deg``, ``sweep_contrasts``,
    ``sweep_viewpoint``: the inset sweep (deg); ``flip``: compute FLIP (slow); ``picture_dir``: write
    ``raymask_<viewpoint>.png`` there (:func:`raymask_picture`, with covariance ``picture_cov_deg2``, deg²).

    Returns ``{"size", "px_per_deg", "rounds", "viewpoints": {name: {mode: {frame_ms, ..., psnr_db,
    psnr_disc_5deg_db, flip, speedup_over_full, silhouette}}}, "inset_sweep": {"viewpoint", "rows": {contrast:
    [{inset_deg, frame_ms, rays, fill_radius_deg, psnr_disc_5deg_db, flip}]}}}``.
    """
    progress = progress or (lambda text: None)
    b = BenchScene(size)
    configs = {}
    for c in contrasts:
        configs[f"raymask[C={c:g}]"] = RayMaskConfig(contrast=c)
        configs[f"raymask[C={c:g},no-silhouettes]"] = RayMaskConfig(contrast=c, silhouettes=False)
    report = {"size": list(size), "px_per_deg": b.px_per_deg, "rounds": rounds, "viewpoints": {}}
    renderers = {m: TerrainRenderer(b.ctx, size=b.size) for m in ("full", "csf")}   # steps in turn: one each
    try:
        for name in viewpoints or viewpoint_names():
            scene = place(b.scene, name)
            res = report["viewpoints"][name] = _viewpoint(b, scene, configs, renderers, rounds, flip)
            if picture_dir is not None:
                _picture(b, scene, RayMaskConfig(contrast=contrasts[0]), np.asarray(picture_cov_deg2, float),
                         Path(picture_dir) / f"raymask_{name}.png")
            progress(f"{name}: " + ", ".join(f"{m} {r['frame_ms']:.0f} ms" for m, r in res.items()))
        sweep = {f"C={c:g}": _inset_sweep(b, place(b.scene, sweep_viewpoint), c, insets_deg, rounds, flip)
                 for c in sweep_contrasts}
        for label, rows in sweep.items():
            progress(f"inset sweep at {label}: " + ", ".join(f"{r['inset_deg']:g}° {r['frame_ms']:.0f} ms"
                                                            for r in rows))
        report["inset_sweep"] = {"viewpoint": sweep_viewpoint, "rows": sweep}
    finally:
        for r in renderers.values():
            r.release()
        b.release()
    return report


def _frame_ms(frame) -> float:
    return sum(frame.stage_ms[s] for s in FRAME_STAGES)


def _viewpoint(b: BenchScene, scene, configs: dict, renderers: dict, rounds: int, flip: bool) -> dict:
    """One viewpoint: ``full``, ``csf`` and each ray-mask config in alternation; their figures by mode."""
    steps = {m: b.mesh_step(m, "adaptive", scene=scene, renderer=renderers[m], hysteresis=False)
             for m in ("full", "csf")}
    steps.update({m: b.raymask_step(cfg) for m, cfg in configs.items()})
    timed, last = alternate(steps, b.view_at(), scene.model, rounds)
    res = {}
    for m, per_round in timed.items():
        frames = [r[0] for r in per_round]

        def median(get):
            return float(np.median([get(f) for f in frames]))

        if m in configs:
            res[m] = {"mask_ms": median(lambda f: f.stage_ms["select"]),
                      **{k: median(lambda f: f.details["raymask"][k]) for k in ("classify_ms", "cast_ms", "raster_ms")},
                      "render_ms": median(lambda f: f.stage_ms["render"]), "frame_ms": median(_frame_ms),
                      **{k: last[m].details["raymask"][k] for k in RAY_COUNTS}}
        else:
            res[m] = {f"{s}_ms": median(lambda f: f.stage_ms[s]) for s in FRAME_STAGES}
            res[m].update(frame_ms=median(_frame_ms), triangles=last[m].triangles)
    full_rounds = [_frame_ms(r[0]) for r in timed["full"]]
    for m, per_round in timed.items():      # the speed-up per round (modes run back to back), its median
        res[m]["speedup_over_full"] = float(np.median([f / _frame_ms(r[0]) for f, r in zip(full_rounds, per_round)]))
        if m != "full":
            res[m].update(b.quality(last[m].image, last["full"].image, flip=flip))
            res[m]["silhouette"] = silhouette_displacement_px(last[m].image, last["full"].image, b.renderer.background)
    return res


def _picture(b: BenchScene, scene, config, cov, path) -> None:
    """The raymask frame of ``config`` with covariance ``cov`` (deg²) and its mask drawn on it, to ``path``."""
    frame = b.raymask_step(config)(b.view(0.0, cov), scene.model)
    rr = b.raymask_renderer
    mask = rr.mask(b.screen, b.head, b.poi, b.px_per_deg, cov, config)      # the frame's (cached)
    write_png(path, raymask_picture(frame.image, mask, rr.last_silhouette_quads, b.poi_image, cov, b.px_per_deg))


def _inset_sweep(b: BenchScene, scene, contrast: float, insets_deg, rounds: int, flip: bool) -> list:
    """The paper's experiment at one mask contrast: inset size against frame time, PSNR in the disc and FLIP."""
    full = b.mesh_step("full", "adaptive", scene=scene)(b.view(), scene.model).image
    rows = []
    for inset in insets_deg:
        frame, stats = steady_frame(b.raymask_step(RayMaskConfig(contrast=contrast, inset_deg=inset)), b.view_at(),
                                    scene.model, frames=rounds + 1)
        details = frame.details["raymask"]
        q = b.quality(frame.image, full, flip=flip)
        row = {"inset_deg": inset, "frame_ms": stats["frame_ms"], "rays": details["rays"],
               "fill_radius_deg": details["fill_radius_deg"], "psnr_disc_5deg_db": q["psnr_disc_5deg_db"]}
        if flip:
            row["flip"] = q["flip"]
        rows.append(row)
    return rows


def chart_raymask(report: dict, path) -> None:
    """A 1x3 chart: frame time per viewpoint and mode; silhouette displacement on/off; the inset sweep."""
    plt = pyplot()
    fig, axs = plt.subplots(1, 3, figsize=(18, 5))
    names = list(report["viewpoints"])
    modes = list(report["viewpoints"][names[0]])
    width = 0.8 / len(modes)
    for i, m in enumerate(modes):
        axs[0].bar(np.arange(len(names)) + i * width, [report["viewpoints"][n][m]["frame_ms"] for n in names],
                   width, label=m)
    axs[0].set_xticks(np.arange(len(names)) + 0.4 - width / 2, names)
    axs[0].set_ylabel("frame time (ms, median, modes in alternation)")
    axs[0].legend(fontsize=7)
    axs[0].set_title("frame time per viewpoint (1280x720, llvmpipe)")
    sil_modes = [m for m in modes if m.startswith("raymask")]
    for i, m in enumerate(sil_modes):
        axs[1].bar(np.arange(len(names)) + i * (0.8 / len(sil_modes)),
                   [report["viewpoints"][n][m]["silhouette"]["max_px"] for n in names], 0.8 / len(sil_modes),
                   label=m)
    axs[1].axhline(1.0, color="k", lw=0.8, ls="--")
    axs[1].set_xticks(np.arange(len(names)) + 0.4, names)
    axs[1].set_ylabel("largest sky-silhouette displacement against full (px)")
    axs[1].legend(fontsize=7)
    axs[1].set_title("silhouettes: preserved (per-pixel rays) vs not")
    ax = axs[2]
    for label, rows in report["inset_sweep"]["rows"].items():
        ax.plot([r["inset_deg"] for r in rows], [r["frame_ms"] for r in rows], "o-", label=f"frame ms, {label}")
    ax.set_xlabel("inset diameter (deg)")
    ax.set_ylabel("frame time (ms)")
    ax.legend(loc="upper left", fontsize=7)
    flips = {label: rows for label, rows in report["inset_sweep"]["rows"].items() if "flip" in rows[0]}
    if flips:
        ax2 = ax.twinx()
        for label, rows in flips.items():
            ax2.plot([r["inset_deg"] for r in rows], [r["flip"] for r in rows], "s--", label=f"FLIP, {label}")
        ax2.set_ylabel("FLIP against full")
        ax2.legend(loc="upper right", fontsize=7)
    ax.set_title(f"inset size (the paper's experiment), {report['inset_sweep']['viewpoint']}")
    save_figure(fig, path, dpi=90)
