"""The judge at the true gaze: the PLOD modes judged where the viewer really looks, not where the head points.

The POI the tracker gives is where the head points; the viewer looks up to 15-20° away with the eyes alone
(docs/viewer-model.md). So every image here is judged by FovVideoVDP with its fixation at a **true gaze**: the
head's direction turned by an eye-in-head offset drawn from the viewer model (``synthetic/gaze.py``,
:func:`eye_offsets_deg`). Per case (a terrain, a view of it and a screen, :class:`GazeCase`):

- every rule at each triangle budget (``SelectorConfig.budget_triangles``, met within 3 %), drawn once from the
  head's POI and judged at each fixation: the default mode with its gaze prior (``default``), the same with
  ``gaze_prior_deg=(0, 0)`` (``head_only``: the paper's head-only view) and the geometric modes
  (:data:`GEOMETRIC`);
- the **oracle**: the default mode drawn with its POI exactly at each fixation (prior 0: the gaze is known),
  judged there;
- at one budget, the visible difference by eccentricity ring about the true gaze (:func:`ring_reduce`).

:func:`judge_case` measures one case; :func:`verdicts` checks the issue's goals on a report (:data:`GOALS`);
:func:`fit_settings` chooses the default mode's few settings on training cases; :func:`gaze_table` and
:func:`gaze_charts` print and draw. The training and held-out sets (:data:`TRAINING`, :data:`HELD_OUT`) share
no terrain and no view.

Units: triangles, JOD (10 = identical to ``full``), ms, deg; screen px as :class:`headplod.io.Screen`'s; image
px with a pixel's centre at index + 0.5 (the metrics').
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import numbers
from dataclasses import dataclass

import numpy as np

from calib import CALIB_DIR, DEFAULT_SCREEN

from .plod_judge_views import eccentricity_deg, first_crossing_log, interp_log, ring_reduce
from ..angles import angle_between_deg

__all__ = ["SCREENS", "GEOMETRIC", "BUDGETS", "QUICK_BUDGETS", "TRAINING", "HELD_OUT", "GOALS", "GazeCase",
           "GazeJudgeConfig", "eye_offsets_deg", "gaze_point_px", "case_bench", "judge_case", "case_summary",
           "verdicts", "fit_settings", "choose_settings", "gaze_report", "gaze_table", "gaze_charts"]

#: The screens judged: name → (screen file, image size judged (w, h) px, two thirds of the screen's pixels
#: on both, as the benches' 1280 x 720 on the 1920 x 1080 desk screen).
SCREENS = {"desk": (DEFAULT_SCREEN, (1280, 720)), "wide": (CALIB_DIR / "screen_wide.yaml", (2560, 720))}
#: The geometric modes the default must not lose to (issue 32).
GEOMETRIC = ("sse", "dpv", "ipv")
#: Triangle budgets (the issue's range, :data:`GOAL_RANGE`, and one below it, where the savings are read), and
#: those of ``--quick``.
BUDGETS = (50_000, 100_000, 150_000, 250_000, 400_000)
#: The budgets the margins are judged over (issue 32), triangles.
GOAL_RANGE = (100_000, 400_000)
QUICK_BUDGETS = (150_000,)
#: Terrains (``builtin`` or a :mod:`.landscapes` name) and views (:data:`.plod_judge_views.VIEWS`) of the fit and
#: of the report: no terrain and no view of one is in the other.
TRAINING = {"terrains": ("builtin", "ridges:24", "hills:3"), "views": ("default", "mountains")}
HELD_OUT = {"terrains": ("mesas:5", "ridges:7"), "views": ("overview", "plains")}
#: The goals (issue 32), JOD: the default against the best geometric mode at equal triangles, per screen; the
#: oracle against head-only on every view (tolerance) and on average (gain); the prior's share of the oracle's
#: gain it recovers on average, and how much it may lose to head-only on a view.
GOALS = {"margin": {"desk": -0.02, "wide": 0.05}, "oracle_tolerance": 0.02, "oracle_gain": 0.05,
         "prior_share": 0.5, "prior_tolerance": 0.02, "target_jod": 9.5}
#: How many offsets per fixation :func:`eye_offsets_deg` draws at most before it gives up (most land on a screen
#: seen from in front of it; none do from behind it).
MAX_OFFSET_DRAWS = 64
#: Budget at which the rings are measured (the middle of the range).
RINGS_BUDGET = 150_000


@dataclass(frozen=True)
class GazeCase:
    """One case: ``terrain`` (``"builtin"`` or ``KIND:SEED``), ``view`` (a name of
    :data:`.plod_judge_views.VIEWS`) and ``screen`` (a key of :data:`SCREENS`)."""

    terrain: str
    view: str
    screen: str

    @property
    def name(self) -> str:
        return f"{self.terrain}/{self.view}/{self.screen}"


@dataclass(frozen=True)
class GazeJudgeConfig:
    """How a case is judged: ``budgets`` (triangles), ``fixations`` per case (eye offsets from the viewer
    model), ``seed`` of those offsets, ``oracle`` (also the frames drawn at each true gaze), ``rings`` (the
    visible difference by ring at :data:`RINGS_BUDGET`, or the budget nearest it)."""

    budgets: tuple = BUDGETS
    fixations: int = 4
    seed: int = 0
    oracle: bool = True
    rings: bool = True

    def __post_init__(self):
        def whole(b):
            return isinstance(b, numbers.Real) and not isinstance(b, bool) and math.isfinite(b) and b == int(b)

        if not self.budgets or not all(whole(b) and b >= 1 for b in self.budgets):
            raise ValueError(f"GazeJudgeConfig.budgets must be whole numbers of triangles, got {self.budgets!r}")
        if not (whole(self.fixations) and self.fixations >= 1):
            raise ValueError(f"GazeJudgeConfig.fixations must be a positive integer, got {self.fixations!r}")
        object.__setattr__(self, "budgets", tuple(int(b) for b in self.budgets))
        object.__setattr__(self, "fixations", int(self.fixations))


# --- Where the viewer looks ---------------------------------------------------------------------------------------


def screen_half_extent_deg(screen, eye_mm) -> tuple[float, float]:
    """The screen's half extents seen from ``eye_mm`` (3,) world mm, (horizontal, vertical) deg: half the angle
    between its left and right edges' midpoints, and between its top and bottom ones."""
    w, h = screen.size_px
    eye = np.asarray(eye_mm, dtype=np.float64)

    def half_angle(a_px, b_px):
        a, b = screen.pixel_to_world(np.asarray(a_px, float)) - eye, screen.pixel_to_world(np.asarray(b_px, float)) - eye
        return 0.5 * float(angle_between_deg(a, b))

    return half_angle((0, h / 2), (w, h / 2)), half_angle((w / 2, 0), (w / 2, h))


def gaze_point_px(screen, eye_mm, poi_px, offset_deg) -> np.ndarray | None:
    """Where the true gaze meets the screen, (2,) screen px, or None off the screen plane.

    The gaze is the head's direction V (from ``eye_mm`` (3,) world mm to ``poi_px`` (2,) screen px) turned by
    the eye-in-head ``offset_deg`` (horizontal, vertical) deg: horizontal toward the screen's right (Ξ, the
    head frame's axis along the screen's rows), vertical up (−Ψ); each angle is the atan of its component over
    V's, as :func:`headplod.plod.perception.view_offsets_deg` measures them.
    """
    from ..plod.view import head_axes

    axes = head_axes(screen, eye_mm, poi_px)
    h, v = np.radians(np.asarray(offset_deg, dtype=np.float64))
    return screen.intersect_ray(eye_mm, axes[2] + math.tan(h) * axes[0] - math.tan(v) * axes[1])


def eye_offsets_deg(screen, eye_mm, n: int, seed: int = 0) -> np.ndarray:
    """(n, 2) eye-in-head offsets (horizontal, vertical) deg of a viewer looking about ``screen`` from ``eye_mm``:
    the viewer model's fixations (:func:`synthetic.gaze.eye_offset_distribution`, its default settings, the
    screen's half extents seen from the eye), keeping those whose gaze from the screen's centre lands on the
    screen, in the order drawn. Deterministic for a seed."""
    from synthetic import gaze

    half = screen_half_extent_deg(screen, eye_mm)
    centre = np.array(screen.size_px, dtype=np.float64) / 2
    w, h = screen.size_px
    kept, draw = [], 2 * int(n)
    while len(kept) < n:
        if draw > MAX_OFFSET_DRAWS * int(n):
            raise ValueError(f"fewer than {n} of {draw // 2} eye offsets land on the screen from its centre: is the "
                             f"eye {np.round(eye_mm, 1).tolist()} mm in front of it?")
        kept = []
        for off in gaze.eye_offset_distribution(gaze.EyeHeadSettings(), half, draw, seed=seed):
            p = gaze_point_px(screen, eye_mm, centre, off)
            if p is not None and 0 <= p[0] <= w and 0 <= p[1] <= h:
                kept.append(off)
        draw *= 2
    return np.array(kept[:n], dtype=np.float64)


# --- One case -----------------------------------------------------------------------------------------------------


def case_bench(case: GazeCase, ctx=None, scenes: dict | None = None):
    """(:class:`.harness.BenchScene` of the case's screen and terrain, the scene placed at its view).

    ``scenes``: a cache {(screen, terrain): BenchScene} shared between cases (a terrain's mesh is built once per
    screen)."""
    from .. import io
    from ..demo.viewpoints import place
    from ..render.still import TerrainScene
    from .harness import BenchScene
    from .landscapes import terrain as landscape

    key = (case.screen, case.terrain)
    if scenes is not None and key in scenes:
        bench = scenes[key]
    else:
        path, size = SCREENS[case.screen]
        screen = io.read_screen(path)
        scene = TerrainScene.build(screen, terrain=None if case.terrain == "builtin" else landscape(case.terrain))
        bench = BenchScene(size=size, scene=scene, ctx=ctx)
        if scenes is not None:
            scenes[key] = bench
    placed = bench.scene if case.view == "default" else place(bench.scene, case.view)
    return bench, placed


def _frame(bench, scene, mode: str, poi_px, settings: dict):
    """A steady frame of ``mode`` with ``settings`` seen from the bench's head, POI ``poi_px``: (image, stats)."""
    from ..plod.view import View
    from .harness import FRAME_DT_S, TRACKER_COV_DEG2, steady_frame

    step = bench.mesh_step(mode, scene=scene, **settings)
    poi = np.asarray(poi_px, dtype=np.float64)
    frame, stats = steady_frame(step, lambda k: View(bench.head, poi, TRACKER_COV_DEG2, k * FRAME_DT_S), scene.model,
                                bench.frames)
    return frame.image, stats


def rules(default_settings: dict | None = None) -> dict:
    """The rules drawn from the head's POI: name → (mode, settings): ``default`` (``SelectorConfig()``'s mode with
    ``default_settings``), ``head_only`` (the same, prior 0) and :data:`GEOMETRIC`."""
    from ..plod.select import SelectorConfig

    default = dict(default_settings or {})
    mode = default.pop("mode", SelectorConfig().mode)
    return {"default": (mode, default), "head_only": (mode, {**default, "gaze_prior_deg": (0.0, 0.0)}),
            **{g: (g, {}) for g in GEOMETRIC}}


def judge_case(case: GazeCase, config: GazeJudgeConfig = GazeJudgeConfig(), default_settings: dict | None = None,
               names=None, ctx=None, scenes=None, judge_settings=None, progress=None) -> dict:
    """One case judged at the true gaze (module notes).

    ``default_settings``: the default mode's :class:`SelectorConfig` fields (a ``mode`` among them replaces
    ``SelectorConfig().mode``); ``names``: which of :func:`rules` to draw (None: all); ``ctx``, ``scenes``:
    shared GL context and scene cache (:func:`case_bench`).

    Returns {``case``, ``display``, ``px_per_deg``, ``offsets_deg`` (F, 2), ``fixation_px`` (F, 2) image px,
    ``gaze_px`` (F, 2) screen px, ``full`` {triangles, frame_ms}, ``curves`` {rule: [{budget, triangles,
    frame_ms, jod: [F]}]}, ``oracle`` [{budget, jod: [F], triangles: [F]}] (with ``config.oracle``), ``rings``
    {rule: ring_reduce + jod} about the first fixation (with ``config.rings``)}.
    """
    from ..render.vdp import Judge, JudgeSettings, display_geometry, fixation_px

    progress = progress or (lambda text: None)
    judge_settings = judge_settings or JudgeSettings()
    bench, scene = case_bench(case, ctx, scenes)
    display = display_geometry(bench.screen, bench.head, bench.size, judge_settings.max_eye_offset_mm)
    offsets = eye_offsets_deg(bench.screen, bench.head, config.fixations, config.seed)
    gazes = np.stack([gaze_point_px(bench.screen, bench.head, bench.poi, o) for o in offsets])
    fixations = np.stack([fixation_px(bench.screen, g, bench.size) for g in gazes])
    judge = Judge(display, judge_settings)
    reference, full_stats = _frame(bench, scene, "full", bench.poi, {})
    all_rules = rules(default_settings)
    chosen = {k: v for k, v in all_rules.items() if names is None or k in names}
    rings_budget = min(config.budgets, key=lambda b: abs(b - RINGS_BUDGET))
    curves, ring_images = {}, {}
    for name, (mode, settings) in chosen.items():
        curves[name] = []
        for b in config.budgets:
            image, stats = _frame(bench, scene, mode, bench.poi, {**settings, "budget_triangles": int(b)})
            jods = [judge.jod(reference, image, f) for f in fixations]
            curves[name].append({"budget": int(b), "triangles": int(stats["triangles"]),
                                 "frame_ms": float(stats["frame_ms"]), "jod": jods})
            if b == rings_budget:
                ring_images[name] = image
        progress(f"{case.name} {name}: " + ", ".join(
            f"{p['triangles'] / 1e3:.0f}k {np.mean(p['jod']):.3f}" for p in curves[name]))
    report = {"case": dataclasses.asdict(case), "display": dataclasses.asdict(display),
              "px_per_deg": display.px_per_deg, "offsets_deg": offsets.tolist(), "fixation_px": fixations.tolist(),
              "gaze_px": gazes.tolist(), "default_settings": {k: list(v) if isinstance(v, tuple) else v
                                                              for k, v in (default_settings or {}).items()},
              "full": {"triangles": int(full_stats["triangles"]), "frame_ms": float(full_stats["frame_ms"])},
              "curves": curves}
    if config.oracle:
        mode, settings = all_rules["head_only"]
        report["oracle"] = []
        for b in config.budgets:
            jods, tris = [], []
            for g, f in zip(gazes, fixations):
                image, stats = _frame(bench, scene, mode, g, {**settings, "budget_triangles": int(b)})
                jods.append(judge.jod(reference, image, f))
                tris.append(int(stats["triangles"]))
            report["oracle"].append({"budget": int(b), "triangles": tris, "jod": jods})
        progress(f"{case.name} oracle: " + ", ".join(f"{p['budget'] / 1e3:.0f}k {np.mean(p['jod']):.3f}"
                                                     for p in report["oracle"]))
    if config.rings and ring_images:
        mapper = Judge(display, judge_settings, heatmap="raw")
        ecc = eccentricity_deg(display, fixations[0])
        report["rings"] = {"budget": int(rings_budget)}
        for name, image in ring_images.items():
            jod, error_map = mapper.jod_error_map(reference, image, fixations[0])
            report["rings"][name] = {**ring_reduce(np.asarray(error_map, dtype=np.float64), ecc), "jod": jod}
    return report


# --- What a case shows --------------------------------------------------------------------------------------------


def _mean_curve(points) -> tuple[np.ndarray, np.ndarray]:
    """(triangles ascending, mean JOD over the fixations) of a curve's points."""
    pts = sorted((p["triangles"], float(np.mean(p["jod"]))) for p in points)
    return np.array([p[0] for p in pts], dtype=np.float64), np.array([p[1] for p in pts], dtype=np.float64)


def case_summary(report: dict) -> dict:
    """What one case shows, per budget (JOD, mean over its fixations, at the budget's triangles):

    - ``margin``: default − the best geometric mode (interpolated in log triangles at the budget);
    - ``oracle_gain``: oracle − head-only, mean over fixations, and ``oracle_worst`` its lowest fixation;
    - ``prior_gain``: default − head-only, mean, and ``prior_worst`` its lowest fixation;
    - ``recovered``: prior_gain / oracle_gain (None where the oracle gains nothing).
    And ``target``: for the default and each geometric mode, the triangles at which its mean JOD reaches
    :data:`GOALS` ``target_jod`` and its frame-rate ratio against ``full`` there (None outside its curve:
    ``state`` ``"below"`` when its smallest budget already reaches it, ``"beyond"`` when its largest does not).
    """
    curves = report["curves"]
    out = {"case": report["case"], "budgets": []}
    geo = {g: _mean_curve(curves[g]) for g in GEOMETRIC if g in curves}
    for k, b in enumerate(p["budget"] for p in curves["default"]):
        row = {"budget": b}
        dx, dy = _mean_curve(curves["default"])
        jod = interp_log(b, dx, dy)
        at = {g: interp_log(b, *xy) for g, xy in geo.items()}
        at = {g: j for g, j in at.items() if j is not None}
        best = max(at, key=at.get) if at else None
        row.update(jod=jod, geometric_mode=best, geometric_jod=at.get(best),
                   margin=None if jod is None or best is None else jod - at[best])
        if "head_only" in curves:
            head = np.asarray(curves["head_only"][k]["jod"])
            prior = np.asarray(curves["default"][k]["jod"]) - head
            row.update(prior_gain=float(prior.mean()), prior_worst=float(prior.min()))
            if "oracle" in report:
                oracle = np.asarray(report["oracle"][k]["jod"]) - head
                row.update(oracle_gain=float(oracle.mean()), oracle_worst=float(oracle.min()),
                           recovered=float(prior.mean() / oracle.mean()) if oracle.mean() > 0 else None)
        out["budgets"].append(row)
    out["target"] = {"jod": GOALS["target_jod"], "full_triangles": report["full"]["triangles"]}
    for name in ("default",) + GEOMETRIC:
        if name not in curves:
            continue
        dx, dy = _mean_curve(curves[name])
        need, state = first_crossing_log(GOALS["target_jod"], dx, dy)
        ratio = None
        if need is not None:
            ms = [p["frame_ms"] for p in sorted(curves[name], key=lambda p: p["triangles"])]
            ratio = report["full"]["frame_ms"] / float(np.interp(math.log(need), np.log(dx), ms))
        out["target"][name] = {"triangles": need, "state": state, "frame_rate_ratio": ratio}
    return out


def verdicts(summaries, held_out_only: bool = True) -> dict:
    """The issue's goals over case summaries (:func:`case_summary`), each {met, worst, cases}:

    - ``margin_<screen>``: the default ≥ best geometric + :data:`GOALS` margin at every budget of every
      held-out case on that screen;
    - ``oracle_every_view``: oracle − head-only ≥ −tolerance at every fixation of every case (mean over the
      case's budgets), ``oracle_mean``: its mean over all ≥ the gain goal;
    - ``prior_recovers``: the default's gain over head-only ≥ the share of the oracle's, over all fixations;
      ``prior_never_worse``: ≥ −tolerance on every case.
    ``held_out_only``: the margins count held-out cases only (the others were fitted on).
    """
    held = [s for s in summaries if s["case"]["terrain"] in HELD_OUT["terrains"]
            or s["case"]["view"] in HELD_OUT["views"]] if held_out_only else list(summaries)
    out = {}
    for screen, goal in GOALS["margin"].items():
        rows = [(s["case"], r["budget"], r["margin"]) for s in held if s["case"]["screen"] == screen
                for r in s["budgets"] if r["margin"] is not None and GOAL_RANGE[0] <= r["budget"] <= GOAL_RANGE[1]]
        worst = min(rows, key=lambda r: r[2]) if rows else None
        out[f"margin_{screen}"] = {"goal": goal, "met": bool(rows) and worst[2] >= goal,
                                   "worst": None if worst is None else worst[2],
                                   "worst_case": None if worst is None else f"{GazeCase(**worst[0]).name} at "
                                                                            f"{worst[1] / 1e3:.0f}k",
                                   "cases": len({GazeCase(**r[0]) for r in rows})}
    with_oracle = [s for s in summaries if any("oracle_gain" in r for r in s["budgets"])]
    if with_oracle:
        per_case = [(s, float(np.mean([r["oracle_worst"] for r in s["budgets"]]))) for s in with_oracle]
        gains = [r["oracle_gain"] for s in with_oracle for r in s["budgets"]]
        priors = [r["prior_gain"] for s in with_oracle for r in s["budgets"]]
        worst_case = min(per_case, key=lambda x: x[1])
        out["oracle_every_view"] = {"goal": -GOALS["oracle_tolerance"], "worst": worst_case[1],
                                    "worst_case": GazeCase(**worst_case[0]["case"]).name,
                                    "met": worst_case[1] >= -GOALS["oracle_tolerance"]}
        out["oracle_mean"] = {"goal": GOALS["oracle_gain"], "worst": float(np.mean(gains)),
                              "met": float(np.mean(gains)) >= GOALS["oracle_gain"]}
        share = float(np.mean(priors)) / float(np.mean(gains)) if np.mean(gains) > 0 else None
        out["prior_recovers"] = {"goal": GOALS["prior_share"], "worst": share,
                                 "met": share is not None and share >= GOALS["prior_share"]}
        per_case_prior = [(s, float(np.mean([r["prior_gain"] for r in s["budgets"]]))) for s in with_oracle]
        worst_prior = min(per_case_prior, key=lambda x: x[1])
        out["prior_never_worse"] = {"goal": -GOALS["prior_tolerance"], "worst": worst_prior[1],
                                    "worst_case": GazeCase(**worst_prior[0]["case"]).name,
                                    "met": worst_prior[1] >= -GOALS["prior_tolerance"]}
    return out


# --- Fitting ------------------------------------------------------------------------------------------------------

#: The default mode's settings searched by :func:`fit_settings` (``change_share`` 0 is ``sse``).
FIT_GRID = {"change_share": (0.0, 0.3, 0.45, 0.6), "cortical_exponent": (0.9, 1.2)}


def fit_settings(cases, grid=None, config: GazeJudgeConfig = GazeJudgeConfig(oracle=False, rings=False),
                 ctx=None, progress=None) -> dict:
    """The default mode's settings that score best on the training ``cases`` at the true gaze.

    Every combination of ``grid`` ({field: values}; default :data:`FIT_GRID`) is drawn with the default mode on
    every case and budget and judged at the case's fixations; the geometric modes once. A combination's margins
    are its JOD over the best geometric mode's (mean over the fixations, per case and budget); the choice is
    :func:`choose_settings`': the highest mean margin (since ``change_share`` 0 is ``sse``, never below
    ``sse``'s on what it was fitted on). Returns
    {``grid``, ``cases``, ``scores`` [{settings, worst, mean, cases {case: margins}}], ``best`` settings}.
    """
    from .. import render

    grid = FIT_GRID if grid is None else grid
    progress = progress or (lambda text: None)
    ctx = ctx or render.create_context()
    scenes = {}
    geometric = {c: judge_case(c, config, names=GEOMETRIC, ctx=ctx, scenes=scenes) for c in cases}
    keys = list(grid)
    scores = []
    for values in itertools.product(*(grid[k] for k in keys)):
        settings = dict(zip(keys, values))
        if settings.get("change_share") == 0 and any(s["settings"].get("change_share") == 0 for s in scores):
            continue                                     # sse: the change's settings do not apply
        per_case = {}
        for c in cases:
            r = judge_case(c, config, settings, names=("default",), ctx=ctx, scenes=scenes)
            r["curves"].update(geometric[c]["curves"])
            per_case[c.name] = [row["margin"] for row in case_summary(r)["budgets"] if row["margin"] is not None]
        margins = [m for ms in per_case.values() for m in ms]
        scores.append({"settings": settings, "worst": float(min(margins)), "mean": float(np.mean(margins)),
                       "cases": per_case})
        progress(f"fit {settings}: worst margin {scores[-1]['worst']:+.3f}, mean {scores[-1]['mean']:+.3f}; "
                 + ", ".join(f"{n} {min(ms):+.3f}" for n, ms in per_case.items()))
    for b in scenes.values():
        b.release()
    return {"grid": {k: list(v) for k, v in grid.items()}, "cases": [c.name for c in cases], "scores": scores,
            "best": choose_settings(scores)}


def choose_settings(scores) -> dict:
    """The settings of :func:`fit_settings`' ``scores`` with the highest mean margin over the best geometric mode
    (ties: the higher worst margin). ``change_share`` 0 is ``sse``, so the chosen settings' mean margin on the
    cases fitted is never below ``sse``'s; their worst margin is reported beside it, not optimised: one
    outlying case would otherwise decide for every other."""
    return max(scores, key=lambda s: (round(s["mean"], 4), s["worst"]))["settings"]


# --- The report ---------------------------------------------------------------------------------------------------


def cases_of(sets=("held_out",), screens=tuple(SCREENS)) -> list:
    """The cases of ``sets`` (``"training"``: its terrains × views; ``"held_out"``: every case with a held-out
    terrain or a held-out view) on ``screens``."""
    from .plod_judge_views import VIEWS

    out = []
    for screen in screens:
        if "training" in sets:
            out += [GazeCase(t, v, screen) for t in TRAINING["terrains"] for v in TRAINING["views"]]
        if "held_out" in sets:
            out += [GazeCase(t, v, screen) for t in TRAINING["terrains"] + HELD_OUT["terrains"] for v in VIEWS
                    if t in HELD_OUT["terrains"] or v in HELD_OUT["views"]]
    return out


def gaze_report(cases, config: GazeJudgeConfig = GazeJudgeConfig(), default_settings=None, progress=None) -> dict:
    """Every case judged (:func:`judge_case`), summarized (:func:`case_summary`) and checked (:func:`verdicts`)."""
    from .. import render

    ctx = render.create_context()
    scenes = {}
    reports = [judge_case(c, config, default_settings, ctx=ctx, scenes=scenes, progress=progress) for c in cases]
    for b in scenes.values():
        b.release()
    summaries = [case_summary(r) for r in reports]
    return {"config": dataclasses.asdict(config), "goals": GOALS, "training": TRAINING, "held_out": HELD_OUT,
            "cases": reports, "summaries": summaries, "verdicts": verdicts(summaries)}


def gaze_table(report: dict) -> str:
    """The report as text: per case and budget the mean JOD at the true gaze per rule, then the verdicts."""
    lines = []
    for r, s in zip(report["cases"], report["summaries"]):
        name = GazeCase(**r["case"]).name
        for k, row in enumerate(s["budgets"]):
            jods = " ".join(f"{n} {np.mean(r['curves'][n][k]['jod']):.3f}" for n in r["curves"])
            oracle = f" oracle {np.mean(r['oracle'][k]['jod']):.3f}" if "oracle" in r else ""
            margin = "—" if row["margin"] is None else f"{row['margin']:+.3f} ({row['geometric_mode']})"
            lines.append(f"{name:34s} {row['budget'] / 1e3:4.0f}k  {jods}{oracle}  margin {margin}")
    for goal, v in report["verdicts"].items():
        worst = "—" if v.get("worst") is None else f"{v['worst']:+.3f}"
        lines.append(f"{'[met]' if v['met'] else '[NOT MET]':9s} {goal}: {worst} (goal {v['goal']:+.2f})"
                     + (f", worst {v['worst_case']}" if v.get("worst_case") else ""))
    return "\n".join(lines)


def gaze_charts(report: dict, out_dir) -> list:
    """Per screen: JOD at the true gaze against triangles per rule (mean over the held-out cases' fixations),
    and the visible difference by eccentricity ring about the true gaze. Returns the paths written."""
    from pathlib import Path

    from .harness import label_axes, pyplot, save_figure

    plt = pyplot()
    paths = []
    for screen in SCREENS:
        reports = [r for r in report["cases"] if r["case"]["screen"] == screen]
        if not reports:
            continue
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 5.5))
        names = list(reports[0]["curves"]) + (["oracle"] if "oracle" in reports[0] else [])
        for i, name in enumerate(names):
            series = [r["oracle"] if name == "oracle" else r["curves"][name] for r in reports]
            budgets = [p["budget"] for p in series[0]]
            tris = [np.mean([np.mean(np.atleast_1d(s[k]["triangles"])) for s in series]) for k in range(len(budgets))]
            jod = [np.mean([np.mean(s[k]["jod"]) for s in series]) for k in range(len(budgets))]
            ax.plot(tris, jod, "o-" if name in ("default", "oracle") else "s:", lw=2 if name == "default" else 1.2,
                    label=name)
        label_axes(ax, "triangles (log)", "JOD at the true gaze (mean over cases and fixations)",
                   f"{screen} screen: {len(reports)} cases", "log")
        rings = [r["rings"] for r in reports if "rings" in r]
        if rings:
            edges = rings[0][next(k for k in rings[0] if k != "budget")]["edges_deg"]
            mids = [0.5 * (a + b) for a, b in zip(edges[:-1], edges[1:])]
            for name in (n for n in rings[0] if n != "budget"):
                means = np.array([[np.nan if m is None else m for m in r[name]["mean"]] for r in rings])
                ax2.plot(mids, np.nanmean(means, axis=0), "o-" if name == "default" else "s:", label=name)
            label_axes(ax2, "eccentricity from the true gaze (deg)", "mean visible difference (FovVideoVDP map)",
                       f"error by eccentricity at {rings[0]['budget'] / 1e3:.0f}k triangles", yscale="log")
        path = Path(out_dir) / f"gaze_judge_{screen}.png"
        save_figure(fig, path, dpi=90)
        paths.append(path)
    return paths
