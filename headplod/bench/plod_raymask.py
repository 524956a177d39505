"""``raymask`` against ``full`` and ``csf`` on the three viewpoints (issue 13), for ``headplod bench plod``.

:func:`raymask_report` measures, at 1280x720 with the default head and the
POI at the screen centre, on each viewpoint of :mod:`headplod.demo.viewpoints`:

- **Speed.** Frame time of ``full``, ``csf`` and ``raymask`` (silhouettes on
  and off, and at each mask contrast asked for), rendered in alternation
  round by round so a busy machine slows all alike; the median of the rounds
  after a warm-up round. ``full`` and ``csf``: select + build + render (as
  ``bench plod``: the upload is not timed; each mode keeps its own mesh
  build state, so a steady frame rebuilds nothing). ``raymask``: its ray
  mask (reused for the still view: 0 ms) + cast + classify + rasterise, GL
  finished. Where raymask's time goes: ``cast_ms`` (the ring samples cast
  and read back), ``classify_ms`` (numpy), ``raster_ms`` (the intermediate
  mesh, and every pixel of the inset and the silhouette quads cast).
- **Quality** against ``full``: PSNR over the image and in the 5° disc,
  FLIP (:func:`headplod.bench.plod.flip_error`).
- **Silhouettes.** Where the terrain meets the sky: the boundary pixels of
  the sky (background colour) in each image; the largest distance, px, from
  a boundary pixel of one image to the nearest of the other (both ways:
  the Hausdorff distance), over the whole frame, with silhouette
  preservation on and off. Ridge-in-front-of-slope silhouettes are found by
  the depth test of :func:`headplod.render.raymask.classify_quads` but not
  measured here (the images carry no depth): their quads are counted.
- **Inset sweep** (the paper's experiment): frame time and FLIP at inset
  diameters 2, 5, 10, 15°, at each contrast of ``sweep_contrasts`` (with the
  default contrast 1 the CSF already fills out to 12°, so the inset changes
  nothing below 24°; a lower contrast shows the inset's effect).
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from calib import DEFAULT_SCREEN

from .. import io
from ..plod.raymask import RayMaskConfig
from ..plod.select import View
from ..render import TerrainRenderer, create_context, off_axis_projection
from ..render.raymask import RayMaskRenderer
from ..render.still import TerrainScene, default_head, px_per_deg_at
from ..demo.viewpoints import place, viewpoint_names
from .image_metrics import disc_mask, flip_error, psnr_db

__all__ = ["raymask_report", "silhouette_displacement_px", "chart_raymask", "raymask_picture"]

SIZE = (1280, 720)
INSETS_DEG = (2.0, 5.0, 10.0, 15.0)


def _progress(text: str) -> None:
    print(f"bench raymask: {text}", file=sys.stderr, flush=True)


def _sky(image: np.ndarray, background) -> np.ndarray:
    """(H, W) bool: pixels of exactly the background colour."""
    return np.all(image == np.round(np.asarray(background) * 255).astype(np.uint8), axis=2)


def silhouette_displacement_px(image: np.ndarray, reference: np.ndarray, background) -> dict:
    """How far the sky/terrain boundary of ``image`` lies from ``reference``'s, px.

    The boundary is the set of terrain pixels with a sky pixel among their
    8 neighbours (sky: exactly the background colour). Returns ``max_px``
    (the Hausdorff distance of the two boundaries: the largest distance from
    a boundary pixel of either image to the other's nearest), ``p999_px``
    (99.9th percentile of those distances) and ``pixels`` (the reference's
    boundary pixels); ``max_px`` is 0 with no boundary in either.
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
    """The frame with its ray mask drawn on it, (H, W, 3) uint8 RGB.

    Every ring sample as a dark dot, the filled inset's outline (ring 0) in
    yellow, the silhouette quads outlined in magenta, the POI and its 2σ
    ellipse (:func:`headplod.render.overlay_poi`) in red.
    """
    from ..render import overlay_poi

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
                   size=SIZE, picture_dir=None, picture_cov_deg2=((1.0, 0.0), (0.0, 1.0))) -> dict:
    """Measure ``raymask`` against ``full`` and ``csf`` (module notes); returns a JSON-ready dict.

    Parameters
    ----------
    viewpoints : list of str, optional
        Names of :mod:`headplod.demo.viewpoints` (default: all three).
    rounds : int
        Timed rounds after one warm-up round (5); every mode is rendered once
        per round, in turn.
    contrasts : tuple of float
        Mask contrasts measured at the default inset (the first is the
        default config's, 1.0: the paper's; 0.3 is about the terrain's
        median shading contrast, what ``csf`` uses per triangle).
    insets_deg, sweep_contrasts, sweep_viewpoint
        The inset sweep: diameters, deg; contrasts; on which viewpoint.
    flip : bool
        Compute FLIP (about a second per image on one core).
    picture_dir : path, optional
        Write ``raymask_<viewpoint>.png`` there: the default raymask frame
        with its mask (:func:`raymask_picture`), drawn with the covariance
        ``picture_cov_deg2`` (deg²; σ = 1° by default, so the 2σ ellipse and
        the fill it widens are visible; the timed frames use the tracker's
        σ = 0.05°).

    Returns
    -------
    dict
        ``{"size", "px_per_deg", "viewpoints": {name: {mode: {frame_ms, ...,
        psnr_db, psnr_disc_5deg_db, flip, speedup_over_full, ...}}},
        "inset_sweep": {contrast: [{inset_deg, frame_ms, flip, rays}, ...]}}``.
    """
    screen = io.read_screen(DEFAULT_SCREEN)
    base = TerrainScene.build(screen)
    ctx = create_context()
    renderer = TerrainRenderer(ctx, size=size)
    rr = RayMaskRenderer(ctx, base.mesh, size=size, background=renderer.background)
    head = default_head(screen)
    poi = np.array(screen.size_px, dtype=np.float64) / 2
    cov = np.diag([0.05 ** 2, 0.05 ** 2])          # the tracker's σ of V at 60 cm, as bench plod uses
    view_m, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
    ppd = px_per_deg_at(screen, head, size)
    centre = poi * np.array(size) / np.array(screen.size_px)
    disc = disc_mask((size[1], size[0]), centre, 5 * ppd)

    configs = {}
    for c in contrasts:
        configs[f"raymask[C={c:g}]"] = RayMaskConfig(contrast=c)
        configs[f"raymask[C={c:g},no-silhouettes]"] = RayMaskConfig(contrast=c, silhouettes=False)

    def quality(image, reference):
        q = {"psnr_db": psnr_db(image, reference), "psnr_disc_5deg_db": psnr_db(image, reference, disc)}
        if flip:
            q["flip"] = flip_error(reference, image, ppd)
        q["silhouette"] = silhouette_displacement_px(image, reference, renderer.background)
        return q

    def raymask_frame(scene, cfg):
        mask = rr.mask(screen, head, poi, ppd, cov, cfg)
        image = rr.render(mask, view_m, proj, scene.model, cfg)
        st = dict(rr.last_stats)
        st["mask_ms"] = rr.last_mask_ms
        st["frame_ms"] = rr.last_mask_ms + st["render_ms"]
        return image, st

    report = {"size": list(size), "px_per_deg": ppd, "rounds": rounds, "viewpoints": {}}
    for name in viewpoints or viewpoint_names():
        scene = place(base, name)
        meshes = {m: base.mesh.share() for m in ("full", "csf")}
        selectors = {m: dataclasses.replace(scene, mesh=meshes[m]).selector(m, "adaptive", hysteresis=False)
                     for m in ("full", "csf")}
        times = {m: [] for m in ["full", "csf", *configs]}
        images, extra = {}, {}
        for k in range(rounds + 1):                       # round 0 warms up (builds meshes and masks)
            for m in ("full", "csf"):
                t0 = time.perf_counter()
                levels, _ = selectors[m].select(View(head, poi, cov, 0.0))
                t1 = time.perf_counter()
                positions, normals, tri_levels = meshes[m].update(levels)
                t2 = time.perf_counter()
                renderer.upload(positions, normals, tri_levels)
                images[m] = renderer.render(view_m, proj, scene.model)
                if k:
                    times[m].append(((t1 - t0) * 1e3, (t2 - t1) * 1e3, renderer.last_render_ms))
                extra[m] = {"triangles": int(len(tri_levels))}
            for m, cfg in configs.items():
                images[m], st = raymask_frame(scene, cfg)
                if k:
                    times[m].append((st["mask_ms"], st["classify_ms"], st["cast_ms"], st["raster_ms"],
                                     st["render_ms"]))
                extra[m] = {key: st[key] for key in ("rays", "ring_rays", "fill_rays", "silhouette_rays",
                                                     "silhouette_quads", "drawn_quads")}
        res = {}
        for m in ("full", "csf"):
            s, b, r = (float(np.median([t[i] for t in times[m]])) for i in range(3))
            res[m] = {"select_ms": s, "build_ms": b, "render_ms": r,
                      "frame_ms": float(np.median([sum(t) for t in times[m]])), **extra[m]}
        for m in configs:
            cols = ("mask_ms", "classify_ms", "cast_ms", "raster_ms", "render_ms")
            res[m] = {c: float(np.median([t[i] for t in times[m]])) for i, c in enumerate(cols)}
            res[m]["frame_ms"] = float(np.median([t[0] + t[4] for t in times[m]]))
            res[m].update(extra[m])
        # The speed-up per round (modes rendered back to back), its median.
        full_rounds = [sum(t) for t in times["full"]]
        for m in res:
            rounds_m = [sum(t) if m in ("full", "csf") else t[0] + t[4] for t in times[m]]
            res[m]["speedup_over_full"] = float(np.median([f / x for f, x in zip(full_rounds, rounds_m)]))
            if m != "full":
                res[m].update(quality(images[m], images["full"]))
        report["viewpoints"][name] = res
        if picture_dir is not None:
            cfg = RayMaskConfig(contrast=contrasts[0])
            pcov = np.asarray(picture_cov_deg2, dtype=np.float64)
            mask = rr.mask(screen, head, poi, ppd, pcov, cfg)
            image = rr.render(mask, view_m, proj, scene.model, cfg)
            pic = raymask_picture(image, mask, rr.last_silhouette_quads, centre, pcov, ppd)
            Path(picture_dir).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(Path(picture_dir) / f"raymask_{name}.png"), cv2.cvtColor(pic, cv2.COLOR_RGB2BGR))
        _progress(f"{name}: full {res['full']['frame_ms']:.0f} ms, csf {res['csf']['frame_ms']:.0f} ms, "
                  + ", ".join(f"{m} {res[m]['frame_ms']:.0f} ms" for m in configs))

    # The paper's experiment: inset size against frame time and FLIP.
    scene = place(base, sweep_viewpoint)
    meshes_full = base.mesh.share()
    meshes_full.clear()
    renderer.upload(*meshes_full.update(np.full(base.mesh.n_faces, base.mesh.max_level)))
    full = renderer.render(view_m, proj, scene.model)
    sweep = {}
    for c in sweep_contrasts:
        rows = []
        for inset in insets_deg:
            cfg = RayMaskConfig(contrast=c, inset_deg=inset)
            ms = []
            for k in range(rounds + 1):
                image, st = raymask_frame(scene, cfg)
                if k:
                    ms.append(st["frame_ms"])
            row = {"inset_deg": inset, "frame_ms": float(np.median(ms)), "rays": st["rays"],
                   "fill_radius_deg": round(rr._last_mask.r_fill_deg, 3),
                   "psnr_disc_5deg_db": psnr_db(image, full, disc)}
            if flip:
                row["flip"] = flip_error(full, image, ppd)
            rows.append(row)
        sweep[f"C={c:g}"] = rows
        _progress(f"inset sweep at C={c:g}: " + ", ".join(f"{r['inset_deg']:g}° {r['frame_ms']:.0f} ms"
                                                           for r in rows))
    report["inset_sweep"] = {"viewpoint": sweep_viewpoint, "rows": sweep}
    rr.release()
    renderer.release()
    return report


def chart_raymask(report: dict, path) -> None:
    """A 1x3 chart: frame time per viewpoint and mode; silhouette displacement on/off; the inset sweep."""
    import matplotlib  # imported only when a chart is drawn (slow to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
        x = [r["inset_deg"] for r in rows]
        ax.plot(x, [r["frame_ms"] for r in rows], "o-", label=f"frame ms, {label}")
    ax.set_xlabel("inset diameter (deg)")
    ax.set_ylabel("frame time (ms)")
    ax2 = ax.twinx()
    for label, rows in report["inset_sweep"]["rows"].items():
        if "flip" in rows[0]:
            ax2.plot([r["inset_deg"] for r in rows], [r["flip"] for r in rows], "s--", label=f"FLIP, {label}")
    ax2.set_ylabel("FLIP against full")
    ax.legend(loc="upper left", fontsize=7)
    ax2.legend(loc="upper right", fontsize=7)
    ax.set_title(f"inset size (the paper's experiment), {report['inset_sweep']['viewpoint']}")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


if __name__ == "__main__":  # pragma: no cover - a manual run: python -m headplod.bench.plod_raymask OUT.json
    from .outputs import write_json

    out = Path(sys.argv[1] if len(sys.argv) > 1 else "raymask_report.json")
    rep = raymask_report(picture_dir=out.parent)
    write_json(out, rep)
    chart_raymask(rep, out.with_suffix(".png"))
