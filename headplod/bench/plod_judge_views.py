"""The judge at equal triangles on every viewpoint: does the default criterion beat the geometric ones (issue 24)?

For each view (the benches' default view and the demo's three viewpoints, :data:`VIEWS`), on the built-in
terrain or a DEM of one's own (``headplod bench plod --vdp --terrain FILE``):

1. **Equal-triangle curves** (:func:`budget_curves`): every mode rendered at triangle budgets
   (:data:`BUDGETS`; ``SelectorConfig.budget_triangles``, met per frame within its tolerance) through the demo's
   frame step, scored by FovVideoVDP against ``full``'s image of the same view, the fixation at the POI.
   :func:`compare_curves`: the default mode against the best geometric mode at equal triangles (the margin,
   JOD) and at equal JOD (the triangle saving), and whether the issue's goal is met.
2. **Fixation moved** (:func:`moved_fixation_px`): the same images judged with the fixation
   :data:`MOVED_FIXATION_DEG` from the POI; the drop of each mode's JOD (foveation's share of the gain).
3. **Error by eccentricity ring** (:func:`ring_reduce`): the metric's per-pixel visible difference, averaged
   over rings of eccentricity about the fixation (:data:`RINGS_DEG`).
4. **A moving POI** (:func:`pursuit_path_px`): a smooth pursuit with a saccade through the frame step, judged as
   one video with a fixation per frame (FovVideoVDP's ``fixation_point`` takes one (x, y) per frame).

:func:`judge_views` runs it all and returns the report; :func:`views_table` and :func:`views_charts` print
and draw it. The logic (interpolation, rings, geometry, paths) needs only numpy.

Units: triangles, JOD (10 = identical to ``full``), ms, deg; image px with a pixel's centre at index + 0.5 (the
metrics'), screen px as :class:`headplod.io.Screen`'s.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .plod_judge import GEOMETRIC, DisplayGeometry, Judge, JudgeSettings, display_geometry, fixation_px

__all__ = ["VIEWS", "BUDGETS", "QUICK_BUDGETS", "RINGS_DEG", "MOVED_FIXATION_DEG", "GOAL_MARGIN_JOD",
           "GOAL_SAVING", "GOAL_RANGE", "Pursuit", "default_modes", "foveation_goal", "eccentricity_deg", "moved_fixation_px",
           "ring_reduce", "interp_log", "first_crossing_log", "compare_curves", "pursuit_path_px",
           "budget_curves", "judge_views", "views_table", "views_charts"]

#: The views judged: the benches' default view (the scene's own framing), then the demo's viewpoints.
VIEWS = ("default", "overview", "mountains", "plains")
#: Triangle budgets of the curves (the issue's range, 100k-400k), and those of ``--quick``.
BUDGETS = (100_000, 150_000, 200_000, 300_000, 400_000)
QUICK_BUDGETS = (100_000, 200_000, 400_000)
#: Edges of the eccentricity rings about the fixation, deg (the metric's eccentricity, :func:`eccentricity_deg`).
RINGS_DEG = (0.0, 2.0, 5.0, 10.0, 20.0, 40.0)
#: How far the fixation is moved from the POI for part 2, deg.
MOVED_FIXATION_DEG = 20.0
#: The goal (issue 24): at equal triangles in :data:`GOAL_RANGE`, the default's JOD is at least the best
#: geometric mode's plus :data:`GOAL_MARGIN_JOD`; or it matches that JOD with :data:`GOAL_SAVING` fewer triangles.
GOAL_MARGIN_JOD = 0.05
GOAL_SAVING = 0.25
GOAL_RANGE = (100_000, 400_000)
#: How far outside a curve's measured triangles (a fraction of them) its end value is still used: a budget is
#: met within ``SelectorConfig.budget_tolerance`` (3 %), so a curve's ends miss the budgets by that much.
BUDGET_SLACK = 0.05
#: The modes judged beside the default (the geometric ones of the goal and the other CSF-based ones).
OTHER_MODES = ("sse", "dpv", "ipv", "change", "csf", "gp")


@dataclass(frozen=True)
class Pursuit:
    """The moving POI of part 4: ``frames`` at ``fps`` Hz; the POI pursued along the screen's middle row at
    ``speed_deg_s`` (deg/s of the metric's horizontal angle), jumping by ``saccade_deg`` at frame
    ``saccade_frame`` (None: no saccade); ``warmup`` frames at the first POI before the judged ones."""

    frames: int = 30
    fps: float = 60.0
    speed_deg_s: float = 10.0
    saccade_deg: float = 5.0
    saccade_frame: int | None = 20
    warmup: int = 3

    def __post_init__(self):
        if int(self.frames) != self.frames or self.frames < 2:
            raise ValueError(f"Pursuit.frames must be an integer ≥ 2, got {self.frames!r}")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Pursuit.fps must be a positive rate, Hz, got {self.fps!r}")
        if self.saccade_frame is not None and not 0 < self.saccade_frame < self.frames:
            raise ValueError(f"Pursuit.saccade_frame must lie in 1..frames-1 or be None, got {self.saccade_frame!r}")
        if int(self.warmup) != self.warmup or self.warmup < 1:
            raise ValueError(f"Pursuit.warmup must be an integer ≥ 1, got {self.warmup!r}")


#: ``--quick``'s pursuit: fewer frames, the saccade kept.
QUICK_PURSUIT = Pursuit(frames=10, saccade_frame=6)


def _mode(name: str) -> str:
    """The selector mode of a curve's name: ``"change[cortical]"`` → ``"change"``."""
    return name.split("[")[0]


def default_modes(default: str | None = None) -> list:
    """The default mode (``SelectorConfig().mode`` unless given) first, then :data:`OTHER_MODES`, once each."""
    from ..plod.select import SelectorConfig

    default = SelectorConfig().mode if default is None else default
    return list(dict.fromkeys([default, *OTHER_MODES]))


# --- Geometry: the metric's eccentricity ------------------------------------------------------------------------


def _view_angles_deg(display: DisplayGeometry, x_px, y_px) -> np.ndarray:
    """The metric's view direction of image points (x, y) px (continuous, a pixel's centre at index + 0.5):
    (..., 2) deg, the horizontal and vertical angle from the screen's normal (``atan(x_m / d)``, ``atan(y_m / d)``,
    y up), as FovVideoVDP's ``pix2view_direction``."""
    w, h = display.resolution_px
    x_m = (np.asarray(x_px, dtype=np.float64) - w / 2) * display.width_m / w
    y_m = -(np.asarray(y_px, dtype=np.float64) - h / 2) * display.height_m / h
    return np.degrees(np.stack([np.arctan(x_m / display.distance_m), np.arctan(y_m / display.distance_m)], -1))


def eccentricity_deg(display: DisplayGeometry, fixation, x_px=None, y_px=None) -> np.ndarray:
    """Eccentricity from ``fixation`` (x, y) image px (the metrics' convention, :func:`fixation_px`), deg, as
    FovVideoVDP computes it: the distance between the two view directions' (horizontal, vertical) angles.

    ``x_px``, ``y_px``: image px of the same shape (continuous; None: every pixel's centre, giving (H, W)).
    """
    if x_px is None:
        w, h = display.resolution_px
        y_px, x_px = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    fix = np.asarray(fixation, dtype=np.float64).reshape(2)
    gaze = _view_angles_deg(display, fix[0] + 0.5, fix[1] + 0.5)
    return np.linalg.norm(_view_angles_deg(display, x_px, y_px) - gaze, axis=-1)


def moved_fixation_px(display: DisplayGeometry, fixation, deg: float = MOVED_FIXATION_DEG) -> np.ndarray:
    """The fixation (x, y) image px moved ``deg`` along its image row (to the left, or to the right where the
    left would leave the image), so that :func:`eccentricity_deg` of the POI from it is ``deg``: (2,) float64.

    On the row the metric's horizontal angle is ``atan(x_m / d)``, so the moved point is at
    ``x_m = d tan(atan(x0_m / d) ∓ deg)``."""
    fix = np.asarray(fixation, dtype=np.float64).reshape(2)
    w = display.resolution_px[0]
    x0_m = (fix[0] + 0.5 - w / 2) * display.width_m / w
    a0 = math.atan(x0_m / display.distance_m)
    for sign in (-1.0, 1.0):
        a = a0 + sign * math.radians(deg)
        if abs(a) >= math.pi / 2:
            continue
        x = display.distance_m * math.tan(a) * w / display.width_m + w / 2 - 0.5
        if -0.5 <= x <= w - 0.5:
            return np.array([x, fix[1]])
    raise ValueError(f"no point on the image's row {fix[1]:.1f} lies {deg:g}° from the fixation")


def ring_reduce(error_map: np.ndarray, ecc_deg: np.ndarray, edges=RINGS_DEG) -> dict:
    """The error map averaged over eccentricity rings: ``error_map`` and ``ecc_deg`` (H, W) (the map's values,
    any unit; eccentricity deg), ``edges`` ascending deg (ring k: ``edges[k] ≤ e < edges[k+1]``).

    Returns ``edges_deg``; per ring ``mean`` (None for an empty ring), ``share`` (the ring's sum over the sum of
    every ring's, None when that is 0) and ``pixels``; ``outside_pixels``: beyond the last edge."""
    err, ecc = np.asarray(error_map, dtype=np.float64), np.asarray(ecc_deg, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.float64)
    if err.shape != ecc.shape:
        raise ValueError(f"error_map {err.shape} and ecc_deg {ecc.shape} must have the same shape")
    if edges.ndim != 1 or len(edges) < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"edges must be at least two ascending eccentricities, deg, got {edges.tolist()}")
    ring = np.digitize(ecc.ravel(), edges) - 1            # -1 below the first edge, len - 1 beyond the last
    inside = (ring >= 0) & (ring < len(edges) - 1)
    n = np.bincount(ring[inside], minlength=len(edges) - 1)
    total = np.bincount(ring[inside], weights=err.ravel()[inside], minlength=len(edges) - 1)
    whole = float(total.sum())
    return {"edges_deg": edges.tolist(),
            "mean": [float(s / k) if k else None for s, k in zip(total, n)],
            "share": [float(s / whole) if whole > 0 else None for s in total],
            "pixels": n.astype(int).tolist(), "outside_pixels": int((~inside).sum())}


def pursuit_path_px(screen, display: DisplayGeometry, pursuit: Pursuit = Pursuit()) -> np.ndarray:
    """The POI of each judged frame of ``pursuit``, (frames, 2) screen px: along the screen's middle row, its
    horizontal angle (``atan(x_m / d)``, the metric's) rising at ``speed_deg_s`` and jumping ``saccade_deg`` at
    the saccade, the whole path centred on the screen's centre."""
    k = np.arange(int(pursuit.frames), dtype=np.float64)
    angle = k * pursuit.speed_deg_s / pursuit.fps
    if pursuit.saccade_frame is not None:
        angle = angle + np.where(k >= pursuit.saccade_frame, pursuit.saccade_deg, 0.0)
    angle -= 0.5 * (angle[0] + angle[-1])
    x_m = display.distance_m * np.tan(np.radians(angle))
    sw, sh = screen.size_px
    return np.stack([sw / 2 + x_m / display.width_m * sw, np.full_like(x_m, sh / 2)], axis=-1)


# --- The comparison: interpolation in log triangles -------------------------------------------------------------


def interp_log(x: float, xs, ys, slack: float = BUDGET_SLACK) -> float | None:
    """``ys`` at ``x``, linear in log x between the points (``xs`` ascending, > 0); the end value within
    ``slack`` (a fraction) beyond the ends; None further out or for fewer than one point."""
    xs, ys = np.asarray(xs, dtype=np.float64), np.asarray(ys, dtype=np.float64)
    if len(xs) == 0 or not (xs[0] * (1 - slack) <= x <= xs[-1] * (1 + slack)):
        return None
    return float(np.interp(math.log(x), np.log(xs), ys))


def first_crossing_log(y: float, xs, ys) -> tuple[float | None, str]:
    """The smallest x at which the curve (``xs`` ascending, > 0; ``ys``; linear in log x) reaches ``y``:
    (x, ``"crossed"``); (None, ``"below"``) when its first point already reaches it (it would need fewer than
    ``xs[0]``); (None, ``"beyond"``) when no point does (it would need more than ``xs[-1]``)."""
    xs, ys = np.asarray(xs, dtype=np.float64), np.asarray(ys, dtype=np.float64)
    if len(xs) == 0:
        return None, "beyond"
    if ys[0] >= y:
        return (float(xs[0]), "crossed") if ys[0] == y else (None, "below")
    up = np.nonzero((ys[:-1] < y) & (ys[1:] >= y))[0]
    if len(up) == 0:
        return None, "beyond"
    i = int(up[0])
    lx = np.log(xs[i:i + 2])
    return float(np.exp(lx[0] + (y - ys[i]) / (ys[i + 1] - ys[i]) * (lx[1] - lx[0]))), "crossed"


def _curve_xy(points, key: str = "jod"):
    pts = sorted((p["triangles"], p[key]) for p in points if p.get("triangles") and p.get(key) is not None)
    return np.array([p[0] for p in pts], dtype=np.float64), np.array([p[1] for p in pts], dtype=np.float64)


def compare_curves(curves: dict, default: str, budgets=BUDGETS, geometric=GEOMETRIC, key: str = "jod",
                   goal_range=GOAL_RANGE, goal_margin: float = GOAL_MARGIN_JOD, goal_saving: float = GOAL_SAVING,
                   slack: float = BUDGET_SLACK) -> dict | None:
    """The ``default`` curve against the best of the ``geometric`` curves at equal triangles.

    ``curves``: {name: [{triangles, <key>, ...}]} (the triangles actually drawn); a curve is linear in log
    triangles between its points (:func:`interp_log`, ``slack`` past its ends). Returns None without the default
    or a geometric curve, else:

    - ``margins``: per budget, {budget, jod, geometric_jod, geometric_mode, margin}: the default's JOD minus the
      highest geometric JOD at that many triangles (None where a curve does not reach);
    - ``savings``: per default point, {triangles, jod, geometric_triangles, geometric_mode, saving, bound}: the
      fewest triangles a geometric curve needs to reach the point's JOD (:func:`first_crossing_log`) and
      ``saving = 1 − triangles / geometric_triangles``; when no geometric curve reaches it within its points,
      ``bound`` ``"at_least"`` (saving against the least of their largest counts), when every geometric curve
      already exceeds it at its first point ``"at_most"`` (against the least of their smallest counts);
    - ``min_margin`` and ``min_saving`` (over the goal range; None if any is missing), ``margin_met`` (every
      budget in ``goal_range`` ≥ ``goal_margin``), ``saving_met`` (every default point in it saves ≥
      ``goal_saving``, an ``"at_most"`` bound never counting), ``met`` (either).
    """
    geo = {g: _curve_xy(curves[g], key) for g in geometric if g in curves}
    geo = {g: xy for g, xy in geo.items() if len(xy[0]) >= 1}
    if default not in curves or not geo:
        return None
    dx, dy = _curve_xy(curves[default], key)
    lo, hi = goal_range[0] * (1 - slack), goal_range[1] * (1 + slack)
    margins = []
    for b in budgets:
        jod = interp_log(b, dx, dy, slack)
        at = {g: interp_log(b, gx, gy, slack) for g, (gx, gy) in geo.items()}
        at = {g: j for g, j in at.items() if j is not None}
        best = max(at, key=at.get) if at else None
        gj = at[best] if best else None
        margins.append({"budget": int(b), "jod": jod, "geometric_jod": gj, "geometric_mode": best,
                        "margin": None if jod is None or gj is None else jod - gj})
    savings = []
    for t, j in zip(dx, dy):
        found = {g: first_crossing_log(j, gx, gy) for g, (gx, gy) in geo.items()}
        crossed = {g: x for g, (x, s) in found.items() if s == "crossed"}
        if crossed:
            g = min(crossed, key=crossed.get)
            need, bound = crossed[g], None
        elif all(s == "beyond" for _, s in found.values()):
            g = min(geo, key=lambda m: geo[m][0][-1])
            need, bound = float(geo[g][0][-1]), "at_least"
        else:
            g = min(geo, key=lambda m: geo[m][0][0])
            need, bound = float(geo[g][0][0]), "at_most"
        savings.append({"triangles": int(t), "jod": float(j), "geometric_triangles": need, "geometric_mode": g,
                        "saving": 1.0 - t / need, "bound": bound})
    in_margins = [m for m in margins if goal_range[0] <= m["budget"] <= goal_range[1]]
    in_savings = [s for s in savings if lo <= s["triangles"] <= hi]
    margin_ok = bool(in_margins) and all(m["margin"] is not None and m["margin"] >= goal_margin for m in in_margins)
    saving_ok = bool(in_savings) and all(s["bound"] != "at_most" and s["saving"] >= goal_saving for s in in_savings)
    missing = any(m["margin"] is None for m in in_margins)
    return {"default": default, "geometric": list(geo), "margins": margins, "savings": savings,
            "min_margin": None if missing or not in_margins else min(m["margin"] for m in in_margins),
            "min_saving": min(s["saving"] for s in in_savings) if in_savings else None,
            "goal": {"margin_jod": goal_margin, "saving": goal_saving, "range": list(goal_range)},
            "margin_met": margin_ok, "saving_met": saving_ok, "met": margin_ok or saving_ok}


# --- Rendering and judging --------------------------------------------------------------------------------------


def _settings_for(name: str, mode_settings) -> dict:
    """The :class:`SelectorConfig` fields of curve ``name``: ``mode_settings[name]``, else those of its mode."""
    mode_settings = mode_settings or {}
    return dict(mode_settings.get(name, mode_settings.get(_mode(name), {})))


def _frame(bench, scene, name: str, mode_settings, **cost):
    """One steady frame of curve ``name`` at the default view of ``bench`` with ``scene`` placed: (image, stats)."""
    step = bench.mesh_step(_mode(name), scene=scene, **{**_settings_for(name, mode_settings), **cost})
    frame, stats = bench.steady(step, model=scene.model)
    info = step.backend.last_info or {}
    if "budget_bias" in info and cost.get("budget_triangles") is not None:
        stats["budget_bias"] = float(info["budget_bias"])
    return frame.image, stats


def budget_curves(bench, scene, modes, budgets, judge: Judge, fixation, reference=None, mode_settings=None,
                  progress=None, keep=()):
    """Each of ``modes`` at each of ``budgets`` (triangles) judged against ``full`` at one view.

    ``bench`` a :class:`.harness.BenchScene` (its renderer, head and POI); ``scene`` a :class:`TerrainScene`
    placed at the view (``bench.scene`` or :func:`headplod.demo.viewpoints.place`'s); ``modes`` curve names (a
    mode of ``headplod.plod.select.MODES``, or ``mode[tag]`` to judge one mode under several settings);
    ``judge`` a :class:`.plod_judge.Judge`; ``fixation`` (x, y) image px; ``reference`` full's image of the view
    (None: rendered); ``mode_settings`` {name or mode: {SelectorConfig field: value}} (e.g.
    ``{"change": {"csf_model": "cortical"}}``); ``keep``: budgets whose images are returned.

    Every frame is rendered (and timed) first, then judged. Returns (curves {name: [{budget, triangles, jod,
    frame_ms, render_ms, budget_bias, seconds}]}, images {(name, budget): (H, W, 3) uint8}, reference).
    """
    progress = progress or (lambda text: None)
    if reference is None:
        reference = _frame(bench, scene, "full", None)[0]
    images, curves = {}, {}
    for name in modes:
        curves[name] = []
        for b in budgets:
            image, stats = _frame(bench, scene, name, mode_settings, budget_triangles=int(b))
            images[name, int(b)] = image
            curves[name].append({"budget": int(b), "triangles": int(stats["triangles"]),
                                 "frame_ms": stats["frame_ms"], "render_ms": stats["render_ms"],
                                 "budget_bias": stats.get("budget_bias")})
    for name, pts in curves.items():
        for p in pts:
            p["jod"] = judge.jod(reference, images[name, p["budget"]], fixation)
            p["seconds"] = judge.last_seconds
        progress(f"{name}: " + ", ".join(f"{p['triangles'] / 1e3:.0f}k {p['jod']:.2f}" for p in pts))
    kept = {k: v for k, v in images.items() if k[1] in {int(b) for b in keep}}
    return curves, kept, reference


def _pursuit(bench, scene, names, budget: int, display, judge: Judge, pursuit: Pursuit, mode_settings) -> dict:
    """Part 4 at one view: {name: {jod, seconds, triangles [per frame]}} and the path, judged as a video."""
    from ..plod.view import View
    from .harness import TRACKER_COV_DEG2, run_views

    path = pursuit_path_px(bench.screen, display, pursuit)
    dt = 1.0 / pursuit.fps
    warm = [View(bench.head, path[0], TRACKER_COV_DEG2, k * dt) for k in range(pursuit.warmup)]
    views = warm + [View(bench.head, p, TRACKER_COV_DEG2, (pursuit.warmup + k) * dt) for k, p in enumerate(path)]
    fixations = np.stack([fixation_px(bench.screen, p, bench.size) for p in path])

    def frames(name, **cost):
        step = bench.mesh_step(_mode(name), scene=scene, **{**_settings_for(name, mode_settings), **cost})
        step.reset()
        out = run_views(step, views, scene.model)[pursuit.warmup:]
        return np.stack([f.image for f in out]), [int(f.triangles) for f in out]

    reference, _ = frames("full")
    out = {"poi_px": path.tolist(), "fixation_px": fixations.tolist(), "budget": int(budget),
           "settings": dataclasses.asdict(pursuit), "per_frame_fixation": judge.foveated, "modes": {}}
    for name in names:
        test, tris = frames(name, budget_triangles=int(budget))
        jod = judge.jod_video(reference, test, fixations, pursuit.fps)
        out["modes"][name] = {"jod": jod, "seconds": judge.last_seconds, "triangles": tris}
    return out


def _equal_budget(budgets) -> int:
    """The budget of parts 2-4: 200k if among ``budgets``, else their median one."""
    budgets = sorted(int(b) for b in budgets)
    return 200_000 if 200_000 in budgets else budgets[len(budgets) // 2]


def judge_views(bench=None, views=VIEWS, modes=None, budgets=BUDGETS, mode_settings=None, default: str | None = None,
                settings: JudgeSettings = JudgeSettings(), extras: bool = True, pursuit: Pursuit | None = Pursuit(),
                equal_budget: int | None = None, progress=None) -> dict:
    """The judge at equal triangles on each of ``views`` (module notes): the call for calibration.

    ``bench``: a :class:`.harness.BenchScene` (None: the built-in terrain's, made and released here; for a DEM,
    ``BenchScene(scene=TerrainScene.build(screen, terrain=...))``); ``views``: names of :data:`VIEWS`;
    ``modes``: curve names (None: :func:`default_modes`); ``budgets``: triangles; ``mode_settings``: {name or
    mode: {SelectorConfig field: value}} applied to that curve (e.g. ``{"change": {"csf_model": "cortical"}}``);
    ``default``: the curve compared with the geometric ones (None: ``SelectorConfig().mode``); ``settings``: the
    judge's display and photometry (its metric should be ``"fvvdp"``, the foveated one); ``extras``: also parts
    2-4 at ``equal_budget`` (None: :func:`_equal_budget`): the moved fixation, the rings (a second metric with
    the per-pixel map) and, unless ``pursuit`` is None, the moving POI.

    Returns {``display``, ``px_per_deg``, ``fixation_px``, ``budgets``, ``modes``, ``default``,
    ``mode_settings``, ``equal_budget``, ``views``: {view: {``full_triangles``, ``full_frame_ms``, ``curves``
    (:func:`budget_curves`), ``comparison`` (:func:`compare_curves`), and with ``extras``: ``moved_fixation``
    {deg, fixation_px, modes: {name: {jod, jod_moved, drop}}, goal_met}, ``rings`` {name: :func:`ring_reduce` +
    jod}, ``pursuit``}}, ``seconds_per_jod``}.
    """
    from ..demo.viewpoints import place
    from ..plod.select import SelectorConfig
    from .harness import BenchScene

    default = SelectorConfig().mode if default is None else default
    modes = default_modes(default) if modes is None else list(dict.fromkeys(modes))
    if default not in modes:
        modes = [default] + modes
    budgets = sorted(int(b) for b in budgets)
    for v in views:
        if v not in VIEWS:
            raise ValueError(f"unknown view {v!r}; expected some of {VIEWS}")
    for name in modes:
        SelectorConfig(mode=_mode(name), **_settings_for(name, mode_settings))     # ValueError now, not later
    equal = int(equal_budget) if equal_budget is not None else _equal_budget(budgets)
    progress = progress or (lambda text: None)
    own = bench is None
    bench = BenchScene() if own else bench
    try:
        size = tuple(bench.size)
        display = display_geometry(bench.screen, bench.head, size, settings.max_eye_offset_mm)
        fixation = fixation_px(bench.screen, bench.poi, size)
        judge = Judge(display, settings)
        mapper = Judge(display, settings, heatmap="raw") if extras else None
        ecc = eccentricity_deg(display, fixation) if extras else None
        report = {"display": dataclasses.asdict(display), "px_per_deg": display.px_per_deg,
                  "fixation_px": fixation.tolist(), "metric": settings.metric, "budgets": budgets, "modes": modes,
                  "default": default, "mode_settings": {k: dict(v) for k, v in (mode_settings or {}).items()},
                  "equal_budget": equal, "views": {}}
        seconds = []
        for v in views:
            scene = bench.scene if v == "default" else place(bench.scene, v)
            progress(f"view {v}: {len(modes)} modes x {len(budgets)} budgets")
            full_image, full_stats = _frame(bench, scene, "full", None)
            curves, images, _ = budget_curves(bench, scene, modes, budgets, judge, fixation, full_image,
                                              mode_settings, progress=lambda t, v=v: progress(f"{v} {t}"),
                                              keep=(equal,) if extras and equal in budgets else ())
            seconds += [p["seconds"] for pts in curves.values() for p in pts]
            res = {"full_triangles": int(full_stats["triangles"]), "full_frame_ms": full_stats["frame_ms"],
                   "curves": curves, "comparison": compare_curves(curves, default, budgets)}
            if extras:
                if equal not in budgets:
                    images = {(n, equal): _frame(bench, scene, n, mode_settings, budget_triangles=equal)[0]
                              for n in modes}
                res.update(_extras(bench, scene, v, modes, default, images, full_image, equal, display, fixation,
                                   judge, mapper, ecc, curves, pursuit, mode_settings, progress))
            report["views"][v] = res
        report["seconds_per_jod"] = float(np.median(seconds)) if seconds else None
        return report
    finally:
        if own:
            bench.release()


def foveation_goal(rows: dict, default: str, reference: str = "sse") -> bool | None:
    """Whether moving the fixation lowers the ``default``'s JOD, and by more than ``reference``'s: ``rows``
    {name: {drop}} (JOD at the POI minus JOD with the fixation moved); None without both or when they are one."""
    if default not in rows or reference not in rows or default == reference:
        return None
    return bool(rows[default]["drop"] > 0 and rows[default]["drop"] > rows[reference]["drop"])


def _extras(bench, scene, view, modes, default, images, reference, equal, display, fixation, judge, mapper, ecc,
            curves, pursuit, mode_settings, progress) -> dict:
    """Parts 2-4 at one view at budget ``equal``: moved fixation, rings, pursuit."""
    out = {}
    moved = moved_fixation_px(display, fixation, MOVED_FIXATION_DEG)
    rows = {}
    for name in [n for n in modes if n == default or n in GEOMETRIC]:
        at = judge.jod(reference, images[name, equal], fixation)
        off = judge.jod(reference, images[name, equal], moved)
        rows[name] = {"jod": at, "jod_moved": off, "drop": at - off}
    out["moved_fixation"] = {"deg": MOVED_FIXATION_DEG, "fixation_px": moved.tolist(), "budget": equal,
                             "modes": rows, "goal_met": foveation_goal(rows, default)}
    progress(f"{view} fixation moved {MOVED_FIXATION_DEG:g}°: " + ", ".join(
        f"{n} {r['jod']:.2f} → {r['jod_moved']:.2f}" for n, r in rows.items()))
    rings = {}
    for name in modes:
        q, err = mapper.jod_error_map(reference, images[name, equal], fixation)
        rings[name] = {"jod": q, **ring_reduce(err, ecc)}
    out["rings"] = {"budget": equal, "modes": rings}
    progress(f"{view} rings: " + "; ".join(
        f"{n} " + " ".join("-" if m is None else f"{m:.3g}" for m in r["mean"]) for n, r in rings.items()))
    if pursuit is not None:
        geo = {n: interp_log(equal, *_curve_xy(curves[n])) for n in modes if n in GEOMETRIC and n != default}
        geo = {n: j for n, j in geo.items() if j is not None}
        names = [default] + ([max(geo, key=geo.get)] if geo else [])
        out["pursuit"] = _pursuit(bench, scene, names, equal, display, judge, pursuit, mode_settings)
        progress(f"{view} pursuit: " + ", ".join(f"{n} {r['jod']:.2f}" for n, r in out["pursuit"]["modes"].items()))
    return out


# --- Output ------------------------------------------------------------------------------------------------------


def views_table(report: dict) -> str:
    """The report as text: per view, each curve's JOD at its triangles, the comparison and goals, parts 2-4."""
    lines = [f"judge at equal triangles ({report['metric']}, fixation at the POI; default {report['default']}; "
             f"{report['seconds_per_jod'] or float('nan'):.2f} s per JOD)"]
    for v, res in report["views"].items():
        lines.append(f"{v} (full: {res['full_triangles']:,} triangles, {res['full_frame_ms']:.0f} ms)")
        for name, pts in res["curves"].items():
            lines.append(f"  {name:14s} " + "  ".join(f"{p['triangles'] / 1e3:5.0f}k {p['jod']:.3f}" for p in pts))
        c = res["comparison"]
        if c is None:
            lines.append("  no geometric curve to compare with")
        else:
            lines.append(f"  {c['default']} − best geometric at equal triangles: " + "  ".join(
                f"{m['budget'] / 1e3:.0f}k " + ("outside" if m["margin"] is None
                                                else f"{m['margin']:+.3f} ({m['geometric_mode']})")
                for m in c["margins"]))
            lines.append(f"  {c['default']}'s triangle saving at equal JOD: " + "  ".join(
                f"{s['triangles'] / 1e3:.0f}k {'≥' if s['bound'] == 'at_least' else '≤' if s['bound'] else ''}"
                f"{s['saving']:+.0%} ({s['geometric_mode']})" for s in c["savings"]))
            lines.append(f"  [{'met' if c['met'] else 'NOT MET'}] margin ≥ +{c['goal']['margin_jod']:g} JOD at every "
                         f"budget ({'met' if c['margin_met'] else 'not met'}) or ≥ {c['goal']['saving']:.0%} fewer "
                         f"triangles at equal JOD ({'met' if c['saving_met'] else 'not met'})")
        if "moved_fixation" in res:
            mf = res["moved_fixation"]
            goal = {None: "no sse to compare", True: "met", False: "NOT MET"}[mf["goal_met"]]
            lines.append(f"  fixation {mf['deg']:g}° from the POI at {mf['budget'] / 1e3:.0f}k: " + ", ".join(
                f"{n} drops {r['drop']:+.3f} ({r['jod']:.3f} → {r['jod_moved']:.3f})" for n, r in mf["modes"].items())
                + f"  [{goal}] the default drops, and more than sse")
        if "rings" in res:
            edges = res["rings"]["modes"][next(iter(res["rings"]["modes"]))]["edges_deg"]
            lines.append("  mean visible difference by ring (" + ", ".join(
                f"{a:g}-{b:g}°" for a, b in zip(edges[:-1], edges[1:])) + "):")
            for n, r in res["rings"]["modes"].items():
                lines.append(f"    {n:12s} " + " ".join("      -" if m is None else f"{m:7.3g}" for m in r["mean"]))
        if "pursuit" in res:
            pu = res["pursuit"]
            s = pu["settings"]
            lines.append(f"  moving POI ({s['frames']} frames at {s['fps']:g} Hz, pursuit {s['speed_deg_s']:g}°/s"
                         + (f", saccade {s['saccade_deg']:g}° at frame {s['saccade_frame']}" if s["saccade_frame"]
                            else "") + f", {pu['budget'] / 1e3:.0f}k): " + ", ".join(
                f"{n} {r['jod']:.3f}" for n, r in pu["modes"].items()))
    return "\n".join(lines)


def views_charts(report: dict, folder, stem: str = "plod_jod_view") -> list:
    """Per view, ``<stem>_<view>.png`` in ``folder``: JOD against triangles per curve (log x; the goal's
    range shaded) and the mean visible difference per eccentricity ring per curve. Returns the paths."""
    from .harness import label_axes, pyplot, save_figure

    plt = pyplot()
    paths = []
    names = report["modes"]
    colours = {n: plt.cm.tab10(i % 10) for i, n in enumerate(names)}
    for v, res in report["views"].items():
        rings = res.get("rings")
        fig, axs = plt.subplots(1, 2 if rings else 1, figsize=(15 if rings else 8, 6), squeeze=False)
        ax = axs[0, 0]
        ax.axvspan(*GOAL_RANGE, color="0.92", zorder=0)
        for n, pts in res["curves"].items():
            x, y = _curve_xy(pts)
            base = _mode(n)
            ax.plot(x, y, "o-" if base not in GEOMETRIC else "s:", color=colours.get(n, "k"),
                    lw=2.2 if n == report["default"] else 1.2, ms=5, label=n + (" (default)" if n == report["default"]
                                                                               else ""))
        c = res["comparison"]
        title = f"{v}: JOD against full at equal triangles"
        if c is not None:
            least = "n/a (a curve short of a budget)" if c["min_margin"] is None else f"{c['min_margin']:+.3f} JOD"
            title += (f"\nleast margin over the best geometric {least}\ngoal (+{c['goal']['margin_jod']:g} JOD or "
                      f"{c['goal']['saving']:.0%} fewer triangles): {'met' if c['met'] else 'not met'}")
        label_axes(ax, "triangles (log; shaded: the goal's range)", "FovVideoVDP JOD (10 = full), fixation at the POI",
                   title, xscale="log", which="both")
        if rings:
            ax = axs[0, 1]
            modes = rings["modes"]
            edges = next(iter(modes.values()))["edges_deg"]
            k = len(edges) - 1
            width = 0.8 / max(len(modes), 1)
            for i, (n, r) in enumerate(modes.items()):
                vals = [np.nan if m is None else m for m in r["mean"]]
                ax.bar(np.arange(k) + (i - (len(modes) - 1) / 2) * width, vals, width, color=colours.get(n, "k"),
                       label=f"{n} ({r['jod']:.2f} JOD)")
            ax.set_xticks(np.arange(k), [f"{a:g}-{b:g}°" for a, b in zip(edges[:-1], edges[1:])])
            label_axes(ax, "eccentricity from the fixation (the POI)", "mean visible difference per pixel (metric's map)",
                       f"{v}: where the judge sees the error, at {rings['budget'] / 1e3:.0f}k triangles", yscale="log",
                       legend=None)
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
        d = report["display"]
        fig.suptitle(f"{d['width_m'] * 1000:.0f}x{d['height_m'] * 1000:.0f} mm screen from {d['distance_m'] * 1000:.0f}"
                     f" mm, {report['px_per_deg']:.1f} px/deg; each mode at triangle budgets "
                     + ", ".join(f"{b / 1e3:.0f}k" for b in report["budgets"]), fontsize=10)
        path = Path(folder) / f"{stem}_{v}.png"
        save_figure(fig, path, dpi=90)
        paths.append(path)
    return paths
