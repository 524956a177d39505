"""``headplod bench plod``: speed against image error for every LOD mode, in one run (README: measurements).

The default view and every frame come from :mod:`.harness` (the demo's frame step); images are judged
against ``full``'s of the same view. Parts:

1. **Modes**: per mode, the CSF forms and the read-back contrast: triangles, stage ms of a steady frame,
   frame-time ratio to ``full`` (also in alternation), select + build over ``full``'s render, PSNR (whole,
   5° disc), FLIP.
2. **Quality curves**: each mode over a level bias (:data:`BIASES`).
3. **Velocity sweep** (Wakatsuki et al. Fig. 8): triangles against the terrain's on-screen angular speed.
4. **Uncertainty**: base triangles in the POI's 2σ ellipse at full detail, ``none`` against ``fixed``.
5. **Stability**: level changes per frame of a still head through the tracker (:mod:`.stability`).
6. **Foveated layers** (:mod:`.plod_foveate`), 7. **Ray mask** (:mod:`.plod_raymask`), 8. **Perceptual
   judge** (``--vdp``, :mod:`.plod_judge`): the curves over a level bias at the default view, then every mode at
   equal triangles on the default view and the three viewpoints (:mod:`.plod_judge_views`), on the built-in
   terrain or ``terrain`` (``--terrain FILE``).

Writes JSON, a 3x3 chart, the level-colour pictures and parts 6-8's charts and pictures beside the chart;
``only`` (``--only foveate|raymask|judge``) runs part 6, 7 or 8 alone.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from . import stability as still_head
from .harness import (DEFAULT_SCREEN, FRAME_DT_S, SIZE, BenchScene, alternate, label_axes, progress, pyplot,
                      run_views, save_figure, write_png)
from ..plod import perception as pc
from ..plod.contrast import project_to_screen_px, readback_contrast
from ..plod.csf import CSF_MODELS
from ..plod.select import MODES, UNCERTAINTY_MODES, SelectorConfig
from ..plod.view import head_axes
from ..progress import note
from ..render import TerrainRenderer, overlay_poi, screen_frame
from .outputs import write_json
from ..tol import tol

__all__ = ["SIZE", "DEFAULT_SCREEN", "CSF_FORMS", "measure_modes", "interleaved_speed", "quality_curves",
           "velocity_sweep", "ellipse_coverage", "stability", "run_plod_bench", "image_side_parts"]

#: The CSF forms compared: every model of :data:`headplod.plod.csf.CSF_MODELS`; the default is chosen from them.
CSF_FORMS = CSF_MODELS
BIASES = (-1.5, -1.0, -0.5, 0.0, 0.5, 1.0)
SWEEP_MODES = ("sse", "ipv", "dpv", "csf")
SWEEP_SPEEDS_DEG_S = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0)
ELLIPSE_SIGMA_DEG = (1.5, 3.0)      # (φ, θ)
#: The velocity sweep's saccade hold, deg/s: lifted (the sweep is the criteria's answer to speed; at its top
#: speeds the POI's direction moves faster than the demo's 180°/s hold, which would keep the first levels).
SWEEP_SACCADE_HOLD_DEG_S = 1e6
#: The mode the goals are measured on: the default criterion (the ellipse's goal is csf's: a triangle in the
#: 2σ ellipse at eccentricity 0 is at the finest level only under csf's rule, which refines by size alone).
DEFAULT_MODE = SelectorConfig().mode
#: The parts ``run_plod_bench(only=...)`` runs alone (``judge`` includes ``gaze``, the judge at the true gaze).
PARTS = ("foveate", "raymask", "judge", "gaze")

_progress = progress("bench plod")


def _mode_entries() -> list:
    """(name, selector settings, read-back contrast) of part 1: every mode, the other CSF forms, the read-back."""
    entries = [(m, {"mode": m}, False) for m in ["full"] + [m for m in MODES if m != "full"]]
    entries += [(f"csf[{form}]", {"mode": "csf", "csf_model": form}, False) for form in CSF_FORMS
                if form != "kelly_scaled"]
    # The read-back contrast replaces the shading contrast from the second
    # frame on; hysteresis off, so the levels follow it at once.
    return entries + [("csf[readback]", {"mode": "csf", "hysteresis": False}, True)]


def _readback_frame(b: BenchScene, step) -> tuple:
    """The steady frame of ``step`` with each frame's contrast read back from the frame before (eq. 2).

    ``readback_and_contrast_ms``: the image's read-back and the two filter passes, part of the frame.
    """
    selector = step.backend.selector
    centroids_px = project_to_screen_px(selector.centroids_mm, b.head, b.screen)
    spent = []

    def before(k, last):
        if last is not None:
            t0 = time.perf_counter()
            selector.contrast = readback_contrast(last.image, centroids_px, b.screen.size_px,
                                                  fallback=b.scene.mesh.contrast)
            spent.append(last.stage_ms["readback"] + (time.perf_counter() - t0) * 1e3)

    frame, stats = b.steady(step, before=before)
    stats["readback_and_contrast_ms"] = float(np.median(spent))
    stats["frame_ms"] += stats["readback_and_contrast_ms"]
    shading, contrast = b.scene.mesh.contrast, selector.contrast
    seen = np.isfinite(contrast) & (contrast != shading)
    stats["contrast_correlation"] = float(np.corrcoef(shading[seen], contrast[seen])[0, 1])
    stats["contrast_median_readback_over_shading"] = float(np.median(contrast[seen] / np.maximum(shading[seen], tol.floor)))
    return frame, stats


def measure_modes(b: BenchScene, cost=None) -> tuple[dict, dict]:
    """Part 1: every mode, the CSF forms and the read-back contrast at the default view.

    ``cost``: :class:`SelectorConfig` fields every mode but ``full`` (the reference) takes: a level bias
    or a triangle budget (``--level-bias``, ``--budget``), to compare them at equal cost."""
    results, images = {}, {}
    for name, opts, readback in _mode_entries():
        mode = opts.pop("mode")
        step = b.mesh_step(mode, "adaptive", **opts, **({} if mode == "full" else (cost or {})))
        frame, results[name] = _readback_frame(b, step) if readback else b.steady(step)
        images[name] = frame.image
        _progress(name)
    # The goal's ratio: render times measured in alternation (the other stages from the steady frames above).
    alternating = interleaved_speed(b)
    for name, ms in alternating["render_ms"].items():
        r = results[name]
        r["render_ms_alternating"] = ms
        r["frame_ms_alternating"] = r["frame_ms"] - r["render_ms"] + ms
    # One ratio per round (full and csf rendered back to back), and their spread.
    rest = {name: results[name]["frame_ms"] - results[name]["render_ms"] for name in ("full", DEFAULT_MODE)}
    per_round = [(f + rest["full"]) / (c + rest[DEFAULT_MODE]) for f, c in zip(
        alternating["rounds_ms"]["full"], alternating["rounds_ms"][DEFAULT_MODE])]
    results[DEFAULT_MODE]["frame_ratio_alternating"] = float(np.median(per_round))
    results[DEFAULT_MODE]["frame_ratio_alternating_quartiles"] = [float(np.percentile(per_round, 25)),
                                                           float(np.percentile(per_round, 75))]
    _progress("csf and full in alternation")
    full = results["full"]
    for name, r in results.items():
        r.update(b.quality(images[name], images["full"]))
        r["frame_ratio_full_over_mode"] = full["frame_ms"] / r["frame_ms"]
        r["select_build_over_full_render"] = (r["select_ms"] + r["build_ms"]) / full["render_ms"]
    return results, images


def interleaved_speed(b: BenchScene, modes=("full", DEFAULT_MODE), rounds: int = 9) -> dict:
    """Render ms of each mode in alternation (:func:`.harness.alternate`, twice a round, the faster kept):
    ``{"render_ms": {mode: median}, "rounds_ms": {mode: [per round]}}``."""
    renderers = {mode: TerrainRenderer(b.ctx, size=b.size) for mode in modes}
    try:
        steps = {mode: b.mesh_step(mode, renderer=renderers[mode]) for mode in modes}
        times, _ = alternate(steps, b.view_at(), b.scene.model, rounds, repeats=2)
    finally:
        for r in renderers.values():
            r.release()
    best = {mode: [min(f.stage_ms["render"] for f in per_round) for per_round in t] for mode, t in times.items()}
    return {"render_ms": {mode: float(np.median(t)) for mode, t in best.items()}, "rounds_ms": best}


def quality_curves(b: BenchScene, reference: np.ndarray, biases=BIASES) -> dict:
    """Part 2: triangles, frame time, PSNR and FLIP per mode over a level bias."""
    curves = {}
    for mode in [m for m in MODES if m != "full"]:
        points = []
        for bias in biases:
            frame, stats = b.steady(b.mesh_step(mode, "adaptive", level_bias=bias))
            stats.update(b.quality(frame.image, reference), bias=bias)
            points.append(stats)
        curves[mode] = points
        _progress(f"curve {mode}")
    return curves


def velocity_sweep(b: BenchScene, speeds=SWEEP_SPEEDS_DEG_S, frames: int = 60) -> dict:
    """Part 3: the eye moving along the screen's rows at each speed for ``frames`` frames at 60 Hz (the POI
    fixed): the last frame's triangles and the median angular speed of the base triangles (small renderer)."""
    right, _, _, _ = screen_frame(b.screen)
    centroids = b.mesh_step("full", "none").backend.selector.centroids_mm
    distance = float(np.median(np.linalg.norm(centroids - b.head, axis=1)))   # eye to the terrain, mm
    out = {}
    for mode in SWEEP_MODES:
        rows = []
        for speed in speeds:
            step = b.mesh_step(mode, "adaptive", renderer=b.small_renderer, hysteresis=False,
                               saccade_hold_deg_s=SWEEP_SACCADE_HOLD_DEG_S)
            speed_mm_s = np.radians(speed) * distance
            views = [b.view(k * FRAME_DT_S, eye_mm=b.head + right * speed_mm_s * (k - frames / 2) * FRAME_DT_S)
                     for k in range(frames)]
            last = run_views(step, views, b.scene.model, images=False)[-1]
            rows.append({"set_speed_deg_s": speed, "triangles": last.triangles,
                         "median_speed_deg_s": float(np.median(step.backend.last_info["speed_deg_s"]))})
        out[mode] = rows
        _progress(f"velocity sweep {mode}")
    return out


def ellipse_coverage(b: BenchScene, sigma_deg=ELLIPSE_SIGMA_DEG, out_dir: Path | None = None) -> dict:
    """Part 4: base triangles inside the POI's 2σ ellipse kept at full detail, none against fixed."""
    cov = np.diag(np.square(sigma_deg))
    res = {"sigma_deg": list(sigma_deg)}
    axes = head_axes(b.screen, b.head, b.poi)
    for name, unc, shift in (("none", "none", "ellipse"), ("fixed_eq1", "fixed", "eq1"),
                             ("fixed", "fixed", "ellipse")):
        step = b.mesh_step("csf", unc, hysteresis=False, shift=shift)
        frame = step(b.view(0.0, cov), b.scene.model, "levels")
        selector, info, levels = step.backend.selector, step.backend.last_info, frame.levels
        offsets = pc.view_offsets_deg(selector.centroids_mm, b.head, axes)
        # The triangle's nearest point to the POI: its centroid pulled in by half its angular size.
        half = 0.5 * np.degrees(2 * np.arctan(selector.edge_len_mm[:, 0] / (2 * info["distance_mm"])))
        norm = np.linalg.norm(offsets, axis=1)
        nearest = offsets * (np.maximum(norm - half, 0) / np.maximum(norm, tol.zero))[:, None]
        maha = np.sqrt(np.einsum("ij,jk,ik->i", nearest, np.linalg.inv(cov), nearest))
        inside = maha <= 2.0
        full_detail = levels == selector.max_level
        res[name] = {"triangles_inside": int(inside.sum()),
                     "fraction_inside_at_full_detail": float(full_detail[inside].mean()),
                     "full_detail_triangles": int(full_detail.sum())}
        if out_dir is not None:
            write_png(Path(out_dir) / f"plod_levels_csf_{name}.png",
                      overlay_poi(frame.image, b.poi_image, cov, b.px_per_deg))
    _progress("uncertainty ellipse")
    return res


def stability(b: BenchScene, frames: int) -> dict:
    """Part 5: level changes per frame for a still head through the real tracker (on the small renderer)."""
    views = still_head.track_still_head(frames=frames)
    out = {}
    for hysteresis in (True, False):
        for unc in UNCERTAINTY_MODES:
            key = unc if hysteresis else f"{unc}, no hysteresis"
            out[key] = still_head.level_changes(b.scene, views, mode=DEFAULT_MODE, uncertainty=unc,
                                                hysteresis=hysteresis,
                                                renderer=b.small_renderer)
    _progress("stability")
    return out


def _vdp_problem(vdp) -> str | None:
    """Why ``--vdp`` cannot run (checked before the long run), or None."""
    from . import plod_judge

    for metric in vdp:
        if metric not in plod_judge.METRICS or not plod_judge.vdp_available(metric):
            return f"the judge's metric {metric} (--vdp): not one of {plod_judge.METRICS} installed; " \
                   "pip install -e '.[vdp]'"
    return None


def run_plod_bench(json_path=None, chart_path=None, frames: int = 3, quick: bool = False, vdp=(),
                   only: str | None = None, cost=None, terrain=None, terrain_label: str | None = None) -> int:
    """``headplod bench plod``: every part (module notes), or the one part ``only`` (:data:`PARTS`); the exit
    status. Prints the table and the goals; writes ``json_path``, ``chart_path`` and the pictures beside it.
    ``terrain``: a :class:`headplod.plod.terrain.Terrain` the judge (part 8) runs on instead of the built-in
    (``terrain_label``: its name in the JSON, e.g. the file)."""
    vdp = tuple(vdp) or (("fvvdp",) if only in ("judge", "gaze") else ())
    problem = _vdp_problem(vdp) if vdp else None
    if only is not None and only not in PARTS:
        problem = f"--only {only}: choose one of {', '.join(PARTS)}"
    elif only == "gaze" and "fvvdp" not in vdp:
        problem = "--only gaze judges with FovVideoVDP: leave --vdp out or include fvvdp in it"
    elif terrain is not None and (not vdp or only not in (None, "judge")):
        problem = "--terrain FILE is the judge's terrain: give --vdp or --only judge with it"
    if problem:
        print(f"bench plod: {problem}", file=sys.stderr)
        return 2
    out_dir = Path(chart_path).parent if chart_path else None
    biases = (-1.0, 0.0, 1.0) if quick else BIASES
    if only is not None:
        report = _one_part(only, frames, quick, biases, vdp, chart_path, terrain)
        if only == "judge":
            report["terrain"] = "built-in" if terrain is None else (terrain_label or "given")
        if json_path:
            write_json(json_path, report, default=float)
        return 0
    b = BenchScene(frames=frames)
    results, images = measure_modes(b, cost)
    report = {"size": SIZE, "px_per_deg": b.px_per_deg, "cost": dict(cost or {}), "modes": results,
              "curves": quality_curves(b, images["full"], biases=biases),
              "velocity_sweep": velocity_sweep(b, speeds=(0.0, 5.0, 50.0) if quick else SWEEP_SPEEDS_DEG_S),
              "ellipse": ellipse_coverage(b, out_dir=out_dir), "stability": stability(b, frames=30 if quick else 60)}
    parts = image_side_parts(out_dir, quick)
    report["foveate"], report["raymask"] = parts["foveate"], parts["raymask"]
    report["goals"] = _goals(report)
    print("\n".join(_lines(report)))
    if vdp:   # --vdp: JOD against frame time per mode and CSF form (plod_judge), its table and chart
        if terrain is None:
            report["jod"] = _judge(b, images["full"], biases, vdp, chart_path, quick)
        else:
            jb = BenchScene(frames=frames, ctx=b.ctx, scene=_terrain_scene(b.screen, terrain))
            try:
                report["jod"] = _judge(jb, None, biases, vdp, chart_path, quick)
            finally:
                jb.release()
        report["jod"]["terrain"] = "built-in" if terrain is None else (terrain_label or "given")
    if json_path:
        write_json(json_path, report, default=float)
    if chart_path:
        _chart(report, chart_path)
        for mode in (DEFAULT_MODE, "full"):
            write_png(out_dir / f"plod_{mode}.png", images[mode])
        note(f"chart: {chart_path}; pictures: {out_dir}/plod_*.png")
    b.release()
    return 0


def _terrain_scene(screen, terrain):
    """The :class:`TerrainScene` of ``terrain`` behind ``screen``, framed as ``headplod render --terrain``'s."""
    from ..render.still import TerrainScene

    return TerrainScene.build(screen, terrain=terrain)


def _one_part(only: str, frames: int, quick: bool, biases, vdp, chart_path, terrain=None) -> dict:
    """The part ``only`` alone (``--only``): its report, its summary printed."""
    if only == "gaze":
        return _gaze(chart_path, quick)
    if only == "judge":
        if terrain is None:
            b = BenchScene(frames=frames)
        else:
            from .. import io

            screen = io.read_screen(DEFAULT_SCREEN)
            b = BenchScene(frames=frames, screen=screen, scene=_terrain_scene(screen, terrain))
        try:
            return _judge(b, None, biases, vdp, chart_path, quick)
        finally:
            b.release()
    report = image_side_parts(Path(chart_path).parent if chart_path else None, quick, parts=(only,))[only]
    print("\n".join(_image_side_lines(report if only == "foveate" else {}, report if only == "raymask" else {})))
    return report


def _judge(b: BenchScene, reference, biases, metrics, chart_path, quick: bool = False) -> dict:
    """Part 8 (``--vdp``): the judge's report (``reference``: full's image, None: rendered), its table
    printed, its chart and heatmaps beside ``chart_path``; then, with FovVideoVDP, every mode at equal
    triangles on each view (:func:`.plod_judge_views.judge_views`: key ``equal_triangles``, its table printed,
    its charts ``plod_jod_view_<view>.png`` beside ``chart_path``)."""
    from . import plod_judge, plod_judge_views as views

    jod = plod_judge.jod_report(b, reference, biases=biases, metrics=metrics, image_side=True,
                                timing_rounds=1 if quick else 3, progress=_progress)
    print(plod_judge.jod_table(jod))
    if chart_path:
        plod_judge.jod_chart(jod, Path(chart_path).parent / "plod_jod.png")
        jod["heatmap_jod"] = plod_judge.write_heatmaps(b, Path(chart_path).parent)
    if "fvvdp" in metrics:
        _progress("the judge at equal triangles on every view")
        eq = views.judge_views(b, budgets=views.QUICK_BUDGETS if quick else views.BUDGETS,
                               pursuit=views.QUICK_PURSUIT if quick else views.Pursuit(), progress=_progress)
        print(views.views_table(eq))
        if chart_path:
            eq["charts"] = [str(p) for p in views.views_charts(eq, Path(chart_path).parent)]
        jod["equal_triangles"] = eq
        jod["gaze"] = _gaze(chart_path, quick)
    return jod


def _gaze(chart_path, quick: bool = False) -> dict:
    """The judge at the true gaze (:mod:`.plod_gaze`) on the held-out cases of both screens: its report, its table
    printed, its charts ``gaze_judge_<screen>.png`` beside ``chart_path``."""
    from . import plod_gaze as pg

    _progress("the judge at the true gaze on the held-out cases")
    config = pg.GazeJudgeConfig(budgets=pg.QUICK_BUDGETS, fixations=3) if quick else pg.GazeJudgeConfig()
    report = pg.gaze_report(pg.cases_of(("held_out",)), config, progress=_progress)
    report["quick"] = bool(quick)
    print(pg.gaze_table(report))
    if chart_path:
        report["charts"] = [str(p) for p in pg.gaze_charts(report, Path(chart_path).parent)]
    return report


def _lines(report) -> list:
    """The printed summary: the modes' table, the read-back, the sweep, the ellipse, stability, parts 6-7, goals."""
    results, sweep, ellipse, stable = report["modes"], report["velocity_sweep"], report["ellipse"], report["stability"]
    lines = [f"{'mode':15s} {'triangles':>10s} {'select':>7s} {'build':>6s} {'render':>7s} {'full/x':>7s} "
             f"{'(s+b)/Rf':>9s} {'PSNR':>6s} {'PSNR 5°':>8s} {'FLIP':>7s}"]
    for name, r in results.items():
        lines.append(f"{name:15s} {r['triangles']:10d} {r['select_ms']:7.1f} {r['build_ms']:6.1f} "
                     f"{r['render_ms']:7.1f} {r['frame_ratio_full_over_mode']:7.2f} "
                     f"{r['select_build_over_full_render']:9.1%} {r['psnr_db']:6.1f} {r['psnr_disc_5deg_db']:8.1f} "
                     f"{r['flip']:7.4f}")
    rb = results["csf[readback]"]
    lines.append(f"read-back contrast: {rb['readback_and_contrast_ms']:.1f} ms per frame; correlation with the "
                 f"shading contrast {rb['contrast_correlation']:.2f}, median ratio "
                 f"{rb['contrast_median_readback_over_shading']:.2f}")
    lines.append("velocity sweep (triangles at median on-screen speed, deg/s):")
    for mode, rows in sweep.items():
        lines.append(f"  {mode:5s} " + "  ".join(f"{r['median_speed_deg_s']:.0f}:{r['triangles']}" for r in rows))
    lines.append(f"2σ ellipse (σ = {ellipse['sigma_deg']}°) base triangles at full detail: "
                 f"none {ellipse['none']['fraction_inside_at_full_detail']:.0%}, "
                 f"fixed with eq. 1 {ellipse['fixed_eq1']['fraction_inside_at_full_detail']:.0%}, "
                 f"fixed (default, ellipse shift) {ellipse['fixed']['fraction_inside_at_full_detail']:.0%}")
    lines.append("level changes per frame after frame 10, still head through the tracker (mean / max): "
                 + ", ".join(f"{u} {s['mean_changes']:.1f} / {s['max_changes']}" for u, s in stable.items()))
    lines += _image_side_lines(report["foveate"], report["raymask"]) + [""]
    return lines + [f"  [{'met' if g['met'] else 'NOT MET'}] {g['goal']}: {g['value']:.3g}" for g in report["goals"]]


def _image_side_lines(fov: dict, ray: dict) -> list:
    """Parts 6 and 7 in a few lines per viewpoint."""
    from .plod_foveate import summary_lines

    lines = summary_lines(fov) if fov else []
    for vp, modes in ray.get("viewpoints", {}).items():
        r, off = modes["raymask[C=1]"], modes["raymask[C=1,no-silhouettes]"]
        lines.append(f"raymask {vp}: {r['frame_ms']:.0f} ms ({r['speedup_over_full']:.2f}x full), "
                     f"PSNR 5° {r['psnr_disc_5deg_db']:.1f} dB, silhouette {r['silhouette']['max_px']:.1f} px "
                     f"({off['silhouette']['max_px']:.1f} px without preservation)")
    return lines


def _goals(report) -> list:
    """The issues' goals: value and whether met, from the report's figures."""
    default, ellipse, stable = report["modes"][DEFAULT_MODE], report["ellipse"], report["stability"]
    name = DEFAULT_MODE

    def goal(text, value, met):
        return {"goal": text, "value": value, "met": bool(met)}

    worst = max(stable["fixed"]["mean_changes"], stable["smoothed"]["mean_changes"])     # with hysteresis
    fov, ray = report["foveate"], report["raymask"]
    seam = max(abs(b["step_vs_full"]["foveate"]) for borders in fov["seams"].values() for b in borders)
    goals = [
        goal(f"{name} (the default) frame ≥ 5x faster than full (POI at the centre, 1280x720; median of 9 rounds "
             "rendering both back to back, quartiles {:.2f}-{:.2f})".format(
                 *default["frame_ratio_alternating_quartiles"]),
             default["frame_ratio_alternating"], default["frame_ratio_alternating"] >= 5),
        goal(f"{name} select + build ≤ 25% of full's render time", default["select_build_over_full_render"],
             default["select_build_over_full_render"] <= 0.25),
        goal(f"{name} within 5° of the POI identical or ≥ 45 dB PSNR against full", default["psnr_disc_5deg_db"],
             default["psnr_disc_5deg_db"] >= 45),
        goal("csf, fixed uncertainty: every base triangle in the POI's 2σ ellipse at full detail",
             ellipse["fixed"]["fraction_inside_at_full_detail"],
             ellipse["fixed"]["fraction_inside_at_full_detail"] >= 1.0),
        goal(f"{name}, still head through the tracker: fixed and smoothed reach zero level changes", worst,
             worst == 0)]
    goals += [goal(f"csf --foveate ≥ 5x faster than full on {vp} (demo loop, interleaved)", r["foveate_ratio"],
                   r["foveate_ratio"] >= 5) for vp, r in fov["speed"].items()]
    goals.append(goal("foveation seams: no luminance step at a layer border beyond full's there "
                      "(largest |step - full's step|, fraction of white; ≤ 0.5%)", seam, seam <= 0.005))
    for vp, modes in ray["viewpoints"].items():
        r = modes["raymask[C=1]"]
        goals += [goal(f"raymask ≥ 5x faster than full on {vp}", r["speedup_over_full"], r["speedup_over_full"] >= 5),
                  goal(f"raymask silhouette within 1 px of full's on {vp} (preservation on)",
                       r["silhouette"]["max_px"], r["silhouette"]["max_px"] <= 1.0)]
    return goals


def image_side_parts(out_dir, quick: bool = False, parts=PARTS) -> dict:
    """Parts 6 and 7 (or those of ``parts``): {part: its summary}; their charts and pictures in ``out_dir``
    (None: a temporary folder, dropped)."""
    import tempfile

    from . import plod_foveate, plod_raymask

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(out_dir) if out_dir else Path(tmp)
        if "foveate" in parts:
            _progress("foveated layers (demo loop, three viewpoints)")
            out["foveate"] = plod_foveate.run(folder, frames=8 if quick else 20, progress=_progress)
        if "raymask" in parts:
            _progress("ray mask (three viewpoints, inset sweep)")
            settings = dict(rounds=1, contrasts=(1.0,), insets_deg=(5.0,), sweep_contrasts=(1.0,), flip=False) \
                if quick else {}
            out["raymask"] = plod_raymask.raymask_report(picture_dir=folder, progress=_progress, **settings)
            plod_raymask.chart_raymask(out["raymask"], folder / "plod_raymask.png")
    return out


def _chart(report, path):
    """The 3x3 chart: quality against triangles and frame time, the velocity sweep, stability, the bars."""
    plt = pyplot()
    fig, axs = plt.subplots(3, 3, figsize=(18, 15))
    results, curves = report["modes"], report["curves"]
    colors = {m: plt.cm.tab10(i) for i, m in enumerate(MODES)}
    frame_label = "frame time: select + build + upload + render (ms)"
    psnr_label, flip_label = "PSNR against full (dB; identical at 80)", "FLIP against full (lower is better)"
    for ax, xkey, ykey, xlabel, ylabel in ((axs[0, 0], "triangles", "psnr_db", "triangles", psnr_label),
                                           (axs[0, 1], "triangles", "flip", "triangles", flip_label),
                                           (axs[1, 0], "frame_ms", "psnr_db", frame_label, psnr_label),
                                           (axs[1, 1], "frame_ms", "flip", frame_label, flip_label)):
        for mode, pts in curves.items():
            ax.plot([p[xkey] for p in pts], [min(p[ykey], 80.0) for p in pts], "o-", color=colors[mode],
                    label=mode, ms=4)
            zero = [p for p in pts if p["bias"] == 0.0]
            if zero:
                ax.plot(zero[0][xkey], min(zero[0][ykey], 80.0), "s", color=colors[mode], ms=8, mfc="none")
        ax.plot(results["full"][xkey], min(results["full"][ykey], 80.0), "k*", ms=12, label="full")
        label_axes(ax, xlabel, ylabel, xscale="log")
    axs[0, 0].set_title("each mode with its level shifted by −1.5 … +1 (square: no shift)")
    ax = axs[0, 2]
    for mode, rows in report["velocity_sweep"].items():
        ax.plot([max(r["median_speed_deg_s"], 0.1) for r in rows], [r["triangles"] for r in rows], "o-",
                color=colors[mode], label=mode)
    label_axes(ax, "on-screen angular speed of the terrain (deg/s, median; still drawn at 0.1)", "triangles",
          "velocity sweep (Wakatsuki et al. Fig. 8)", xscale="log", yscale="log")
    ax = axs[1, 2]
    for key, st in report["stability"].items():
        ax.plot(np.arange(len(st["changes_per_frame"])) + 10, st["changes_per_frame"], label=key,
                ls="-" if "no hysteresis" not in key else ":")
    label_axes(ax, "frame", "base triangles changing level", "still head through the tracker (csf)")
    names = list(results)
    for ax, key, colour, line, xlabel in (
            (axs[2, 0], "frame_ratio_full_over_mode", "tab:blue", 5,
             "frame time of full / frame time of the mode (goal for csf: ≥ 5)"),
            (axs[2, 1], "psnr_disc_5deg_db", "tab:green", 45,
             "PSNR within 5° of the POI (dB; identical at 80; goal ≥ 45)")):
        ax.barh(names, [min(results[n][key], 80.0) for n in names], color=colour)
        ax.axvline(line, color="k", ls="--", lw=1)
        ax.set_xlabel(xlabel)
        ax.invert_yaxis()
        ax.grid(True, axis="x", alpha=0.3)
    ax = axs[2, 2]
    ell = report["ellipse"]
    ax.bar(["none", "fixed, eq. 1", "fixed, 2σ ellipse\n(default)"],
           [100 * ell[k]["fraction_inside_at_full_detail"] for k in ("none", "fixed_eq1", "fixed")],
           color="tab:purple")
    ax.set_ylabel("% of the base triangles in the 2σ ellipse at full detail")
    ax.set_title(f"uncertainty σ = {ell['sigma_deg']}° (φ, θ)")
    ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle("PLOD at 1280x720, POI at the screen centre, head 60 cm (one run; llvmpipe)")
    save_figure(fig, path, dpi=90)

