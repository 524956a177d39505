"""A judge that sees as a viewer does: foveated JOD of the PLOD modes against ``full`` (README: the judge).

The metrics (FovVideoVDP, foveated, the default; ColorVideoVDP, the second opinion), their display geometry and
photometry are :mod:`headplod.render.vdp`'s (``render --compare`` uses them too), re-exported here.

:func:`jod_report` judges every mode and CSF form over a level bias (and the image-side techniques), each
point's JOD against its frame time and triangles, then the CSF-based points against the best geometric
curve at the same cost (:func:`compare_at_equal_time`). The metrics are the optional extra ``.[vdp]``;
without it :func:`vdp_available` is False.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

# The metrics themselves live in render.vdp (render --compare scores with them too); the judge's API re-exports them.
from ..render.vdp import (METRICS, DisplayGeometry, Judge, JudgeSettings, display_geometry,  # noqa: F401
                          fixation_px, vdp_available)

#: The criteria whose levels come from a contrast-sensitivity function.
CSF_BASED = ("hybrid", "change", "csf", "gp", "acuity")
#: The criteria whose levels come from geometry alone (screen-space error, velocity, distance).
GEOMETRIC = ("sse", "ipv", "dpv", "distance")
#: The image-side CSF techniques judged beside the modes: Murphy & Duchowski's ray mask (its knob: the
#: Michelson contrast its ray spacing is chosen for) and ``csf`` drawn as foveated layers (``--foveate``).
IMAGE_SIDE = ("raymask", "csf+foveate")
RAYMASK_CONTRASTS = (1.0, 0.3, 0.1)


def judge_entries(modes=None, forms=None) -> list[tuple[str, dict]]:
    """The curves judged: (name, selector settings) per PLOD mode and per non-default CSF form of ``csf``.

    ``modes`` defaults to every mode but ``full``; ``forms`` to every CSF
    form but the default (``kelly_scaled``, which is ``csf`` itself).
    """
    from ..plod.csf import CSF_MODELS
    from ..plod.select import MODES, SelectorConfig

    default_form = SelectorConfig(mode="csf").csf          # csf's own form is the curve "csf" itself
    modes = [m for m in MODES if m != "full"] if modes is None else list(modes)
    forms = [f for f in CSF_MODELS if f != default_form] if forms is None else list(forms)
    for m in modes:
        if m not in MODES or m == "full":
            raise ValueError(f"unknown mode {m!r} to judge; expected one of {[x for x in MODES if x != 'full']}")
    for f in forms:
        if f not in CSF_MODELS:
            raise ValueError(f"unknown CSF form {f!r}; expected one of {CSF_MODELS}")
    return [(m, {}) for m in modes] + [(f"csf[{f}]", {"csf_model": f}) for f in forms if f != default_form]


def jod_report(bench, reference_rgb: np.ndarray | None = None, modes=None, forms=None, biases=(-1.0, 0.0, 1.0),
               metrics=("fvvdp",), settings: JudgeSettings = JudgeSettings(), off_fixation_deg: float = 10.0,
               timing_rounds: int = 3, image_side: bool = False, progress=None) -> dict:
    """JOD and frame time per mode and CSF form, each over a level bias, at ``bench``'s default view.

    ``bench``: a :class:`.harness.BenchScene`; ``reference_rgb``: its ``full`` image (None: rendered). Every
    point is a steady frame (:meth:`BenchScene.steady`) at level ``bias``; all are rendered and timed first (in
    ``timing_rounds`` rounds, a point's ``frame_ms`` its fastest), then scored with each of ``metrics``
    (PyTorch's threads would slow a render timed right after a JOD). ``image_side``: also the curves of
    :data:`IMAGE_SIDE` (``raymask`` over :data:`RAYMASK_CONTRASTS`, ``triangles`` None, ``bias`` NaN).
    Each curve's bias-0 point is also scored with the fixation ``off_fixation_deg`` left of the POI
    (``jod_<metric>_off``).

    Returns ``display``, ``px_per_deg``, ``fixation_px``, ``off_fixation_deg``, ``off_fixation_px``,
    ``settings``, ``metrics``, ``foveated``, ``full``, ``timing_rounds``, ``curves`` {name: [{bias, setting,
    triangles, frame_ms, render_ms, jod_<metric>, seconds_<metric>, ...}]}, ``seconds`` (median s per JOD) and
    ``comparison`` {metric: {"frame_ms"|"triangles": :func:`compare_at_equal_time`}}.
    """
    if int(timing_rounds) != timing_rounds or timing_rounds < 1:
        raise ValueError(f"timing_rounds must be a positive integer, got {timing_rounds!r}")
    progress = progress or (lambda text: None)
    full_frame, full_stats = bench.steady(bench.mesh_step("full"))
    reference_rgb = full_frame.image if reference_rgb is None else reference_rgb
    size, geometry, fixation = _bench_display(bench, settings)
    off_px = geometry.distance_m * math.tan(math.radians(off_fixation_deg)) / geometry.width_m * size[0]
    off_fixation = fixation - np.array([off_px, 0.0])
    points = [(name, float(b), f"bias {b:+g}", opts) for name, opts in judge_entries(modes, forms) for b in biases]
    if image_side:
        points += [("raymask", float("nan"), f"C={c:g}", {"contrast": float(c)}) for c in RAYMASK_CONTRASTS]
        points += [("csf+foveate", float(b), f"bias {b:+g}", {}) for b in biases]
    curves, images, full_ms = _time_points(bench, points, int(timing_rounds), full_stats, progress)
    seconds = {}
    for m in metrics:
        judge = Judge(geometry, dataclasses.replace(settings, metric=m))
        seconds[m] = []
        for name, pts in curves.items():
            for p in pts:
                p[f"jod_{m}"] = judge.jod(reference_rgb, images[name, p["setting"]], fixation)
                p[f"seconds_{m}"] = judge.last_seconds
                seconds[m].append(judge.last_seconds)
                if judge.foveated and p["setting"] in ("bias +0", "C=1"):
                    p[f"jod_{m}_off"] = judge.jod(reference_rgb, images[name, p["setting"]], off_fixation)
            progress(f"{m} {name}: " + ", ".join(f"{p['setting']}: {p[f'jod_{m}']:.2f}" for p in pts))
        seconds[m] = float(np.median(seconds[m])) if seconds[m] else float("nan")
    report = {"display": dataclasses.asdict(geometry), "px_per_deg": geometry.px_per_deg,
              "fixation_px": fixation.tolist(), "off_fixation_deg": float(off_fixation_deg),
              "off_fixation_px": off_fixation.tolist(), "settings": dataclasses.asdict(settings), "metrics": list(metrics),
              "foveated": {m: m == "fvvdp" for m in metrics},
              "full": {"frame_ms": min(full_ms), "frame_ms_rounds": full_ms, "triangles": full_stats["triangles"]},
              "timing_rounds": int(timing_rounds), "curves": curves, "seconds": seconds}
    report["comparison"] = {m: {x: compare_at_equal_time(curves, f"jod_{m}", x) for x in ("frame_ms", "triangles")}
                            for m in metrics}
    return report


def _bench_display(bench, settings: JudgeSettings):
    """``bench``'s image size, :func:`display_geometry` and :func:`fixation_px` at its default view."""
    size = tuple(bench.size)
    return (size, display_geometry(bench.screen, bench.head, size, settings.max_eye_offset_mm),
            fixation_px(bench.screen, bench.poi, size))


def _point_frame(bench, name: str, bias: float, opts: dict):
    """One curve point's steady frame through the demo's frame step: (image, stats).

    A mode or CSF form (``csf[...]``) at a level bias; ``raymask`` at a mask contrast (its mask reused for
    the still view; ``triangles`` None); ``csf+foveate``: ``csf`` at a level bias drawn as foveated layers.
    """
    from ..plod.raymask import RayMaskConfig
    from .harness import release_step

    if name == "raymask":
        step = bench.raymask_step(RayMaskConfig(contrast=opts["contrast"]))
    elif name == "csf+foveate":
        from ..render.foveate import FoveationConfig

        # The layers' settings given (harness.mesh_step passes foveation=None on to the renderer otherwise).
        step = bench.mesh_step("csf", level_bias=bias, foveate=True, foveation=FoveationConfig())
    else:
        step = bench.mesh_step(name.split("[")[0], level_bias=bias, **opts)
    try:
        frame, stats = bench.steady(step)
    finally:
        release_step(step)
    if name == "raymask":
        stats["triangles"] = None
    return frame.image, stats


def _time_points(bench, points, rounds: int, full_stats: dict, progress):
    """Every point's frame, in ``rounds`` rounds: (curves {name: [point]}, images {(name, setting): image},
    full's frame ms per round)."""
    curves = {name: [] for name, *_ in points}
    images = {}
    full_ms = [full_stats["frame_ms"]]
    for k in range(rounds):
        if k > 0:
            full_ms.append(bench.steady(bench.mesh_step("full"))[1]["frame_ms"])
        for name, bias, setting, opts in points:
            image, stats = _point_frame(bench, name, bias, opts)
            if k == 0:
                images[name, setting] = image
                curves[name].append({"bias": bias, "setting": setting, "triangles": stats["triangles"],
                                     "frame_ms_rounds": [], "render_ms_rounds": []})
            p = next(q for q in curves[name] if q["setting"] == setting)
            p["frame_ms_rounds"].append(stats["frame_ms"])
            p["render_ms_rounds"].append(stats["render_ms"])
            p["frame_ms"], p["render_ms"] = min(p["frame_ms_rounds"]), min(p["render_ms_rounds"])
        progress(f"timing round {k + 1}/{rounds}: " + ", ".join(
            f"{name} {min(q['frame_ms'] for q in c):.0f}-{max(q['frame_ms'] for q in c):.0f} ms"
            for name, c in curves.items()))
    return curves, images, full_ms


def compare_at_equal_time(curves: dict, key: str = "jod_fvvdp", x: str = "frame_ms") -> dict:
    """Each CSF-based point against the best geometric curve at the same cost ``x`` (``"frame_ms"`` or
    ``"triangles"``): the highest JOD of the :data:`GEOMETRIC` curves interpolated linearly in log cost at the
    point's (a curve counts only within its cost range). {curve: [{bias, setting, <x>, jod, geometric_jod,
    geometric_mode, margin}]} for the :data:`CSF_BASED` curves, the CSF forms and :data:`IMAGE_SIDE`; margin =
    jod − geometric_jod (None where no geometric curve spans the cost).
    """
    if x not in ("frame_ms", "triangles"):
        raise ValueError(f"x must be 'frame_ms' or 'triangles', got {x!r}")
    geometric = {n: sorted(((p[x], p[key]) for p in pts)) for n, pts in curves.items() if n in GEOMETRIC}
    out = {}
    for name, pts in curves.items():
        if name.split("[")[0] not in CSF_BASED + IMAGE_SIDE:
            continue
        rows = []
        for p in pts:
            best, best_mode = None, None
            for g, gp in geometric.items():
                if p[x] is None:
                    break
                t = np.log([q[0] for q in gp])
                c = math.log(p[x])
                if len(gp) < 2 or not (t[0] <= c <= t[-1]):
                    continue
                j = float(np.interp(c, t, [q[1] for q in gp]))
                if best is None or j > best:
                    best, best_mode = j, g
            rows.append({"bias": p["bias"], "setting": p.get("setting", f"bias {p['bias']:+g}"), x: p[x],
                         "jod": p[key], "geometric_jod": best,
                         "geometric_mode": best_mode, "margin": None if best is None else p[key] - best})
        out[name] = rows
    return out


def jod_table(report: dict) -> str:
    """The report as text: one line per curve point, then the comparisons at equal frame time and triangles."""
    metrics = report["metrics"]
    head = f"{'curve':16s} {'setting':>8s} {'triangles':>9s} {'frame ms':>9s} " + " ".join(
        f"{'JOD ' + m + (' (fov)' if report['foveated'][m] else ''):>15s}" for m in metrics)
    lines = [f"display {report['display']['width_m'] * 1000:.0f}x{report['display']['height_m'] * 1000:.0f} mm at "
             f"{report['display']['distance_m'] * 1000:.0f} mm, {report['px_per_deg']:.1f} px/deg, fixation "
             f"{report['fixation_px'][0]:.1f}, {report['fixation_px'][1]:.1f} px; full {report['full']['frame_ms']:.1f} ms; "
             + ", ".join(f"{m} {s:.2f} s per image" for m, s in report["seconds"].items()), head]
    for name, pts in report["curves"].items():
        for p in pts:
            off = [f"{p[f'jod_{m}_off']:.3f}" for m in metrics if f"jod_{m}_off" in p]
            tri = "rays" if p["triangles"] is None else f"{int(p['triangles']):d}"
            lines.append(f"{name:16s} {p['setting']:>8s} {tri:>9s} {p['frame_ms']:9.1f} "
                         + " ".join(f"{p[f'jod_{m}']:15.3f}" for m in metrics)
                         + (f"   (fixating {report['off_fixation_deg']:g}° left of the POI: {off[0]})" if off else ""))
    for m in metrics:
        for x, what in (("frame_ms", "frame time"), ("triangles", "triangle count")):
            lines.append(f"{m}: CSF-based point − best geometric curve at the same {what} (JOD):")
            for name, rows in report["comparison"][m][x].items():
                lines.append(f"  {name:14s} " + "  ".join(
                    f"{r['setting']}: " + ("outside" if r["margin"] is None
                                           else f"{r['margin']:+.3f} ({r['geometric_mode']})") for r in rows))
    return "\n".join(lines)


def jod_chart(report: dict, path) -> None:
    """JOD against frame time (top) and triangles (bottom), one column per metric; square: bias 0 (raymask: C=1)."""
    from .harness import label_axes, pyplot, save_figure

    plt = pyplot()
    metrics = report["metrics"]
    fig, axs = plt.subplots(2, len(metrics), figsize=(8 * len(metrics), 12), squeeze=False)
    names = list(report["curves"])
    palette = [plt.cm.tab10(i) for i in range(10)] + ["black", "darkgoldenrod", "magenta", "teal"]
    for col, m in enumerate(metrics):
        for row, (x, xlabel) in enumerate((("frame_ms", "frame time: select + build + render (ms, log)"),
                                           ("triangles", "triangles (log)"))):
            ax = axs[row, col]
            for i, name in enumerate(names):
                pts = sorted((p for p in report["curves"][name] if p[x] is not None), key=lambda p: p[x])
                if not pts:
                    continue
                base = name.split("[")[0]
                if base in IMAGE_SIDE:
                    base = "csf"           # drawn as the CSF-based curves
                style = "-" if base in CSF_BASED and "[" not in name else ("--" if "[" in name else ":")
                color = palette[i % len(palette)]
                marker = {"raymask": "D", "csf+foveate": "^"}.get(name, "o")
                ax.plot([p[x] for p in pts], [p[f"jod_{m}"] for p in pts], marker + style, color=color,
                        label=name + (" (CSF)" if base in CSF_BASED else ""), ms=4,
                        lw=2 if base in CSF_BASED and "[" not in name else 1.2)
                zero = [p for p in pts if p.get("setting") in ("bias +0", "C=1")]
                if zero:
                    ax.plot(zero[0][x], zero[0][f"jod_{m}"], "s", color=color, ms=9, mfc="none")
            ax.axvline(report["full"][x], color="k", lw=1, ls="--", label="full (JOD 10)")
            fov = "foveated on the POI" if report["foveated"][m] else "not foveated (the package has no such mode)"
            label_axes(ax, xlabel, f"JOD against full ({m}; 10 = identical)",
                       f"{'FovVideoVDP' if m == 'fvvdp' else 'ColorVideoVDP'}: {fov}", "log", which="both")
    d = report["display"]
    fig.suptitle(f"PLOD modes, level bias −1.5 … +1 (square: 0), judged at 1280x720 on a "
                 f"{d['width_m'] * 1000:.0f}x{d['height_m'] * 1000:.0f} mm screen from {d['distance_m'] * 1000:.0f} mm "
                 f"({report['px_per_deg']:.1f} px/deg), {report['settings']['peak_luminance_cd_m2']:g} cd/m²\n"
                 f"solid: CSF-based (raymask: diamonds over its mask contrast 1, 0.3, 0.1; csf+foveate: triangles), "
                 f"dotted: geometric modes, dashed: csf with other CSF forms", fontsize=10)
    save_figure(fig, path, dpi=90)


def write_heatmaps(bench, out_dir, modes=("csf", "sse"), settings: JudgeSettings = JudgeSettings()) -> dict:
    """The foveated metric's heatmap of each mode (bias 0) against ``full``, with the fixation marked.

    Writes ``plod_jod_heatmap_<mode>.png`` (1280x720) into ``out_dir``;
    returns {mode: JOD}.
    """
    import cv2

    from .outputs import write_png

    reference = bench.steady(bench.mesh_step("full"))[0].image
    _, geometry, fixation = _bench_display(bench, settings)
    judge = Judge(geometry, settings, heatmap=True)
    out = {}
    for mode in modes:
        out[mode], hm = judge.jod_map(reference, bench.steady(bench.mesh_step(mode))[0].image, fixation)
        hm = np.ascontiguousarray(hm)
        centre = tuple(int(round(c + 0.5)) for c in fixation)
        for deg in (2, 5, 10, 20):     # eccentricity rings around the fixation
            cv2.circle(hm, centre, int(round(deg * geometry.px_per_deg)), (255, 255, 255), 1, cv2.LINE_AA)
        cv2.putText(hm, f"{mode}: {out[mode]:.2f} JOD ({settings.metric}); rings 2, 5, 10, 20 deg", (10, 30),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
        write_png(Path(out_dir) / f"plod_jod_heatmap_{mode}.png", hm)
    return out

