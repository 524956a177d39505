"""Martinez et al.'s Tables 1-4 under tracker conditions: the four uncertainty scenarios judged where the viewer looks.

Per tracker condition (:data:`CONDITIONS`), viewpoint (the paper's three test cases) and scenario of the default
PLOD mode (``SelectorConfig().mode``), hysteresis on and off, on poses tracked once per condition and replayed
for every run, this reports what stands in for satisfaction (README: the paper's scenarios):

- ``changes``: base triangles whose level changed from the previous frame, per frame after the warm-up;
- ``flicker``: level reversals (A → B → A within :data:`FLICKER_FRAMES` frames) per frame;
- ``fps`` and its ratio to ``full`` run back to back; ``triangles`` (median per frame);
- ``psnr_tracked_disc_db``: median PSNR within ``DISC_DEG`` of the *tracked* POI against ``full`` drawn from the
  same (tracked) pose: the POI every scenario refines;
- ``psnr_true_disc_db``: the same within ``DISC_DEG`` of the *true* POI (:func:`true_pois`: the dataset's true V
  from the true head, on the screen), where the head points; with ``vdp``, ``jod_true`` (FovVideoVDP,
  fixated there);
- ``psnr_gaze_disc_db``: the same within ``DISC_DEG`` of the *true gaze* (head and eyes: the dataset's
  ``gaze_truth.csv``, docs/contract.md), where the viewer really looks; NaN without that file;
- ``tracker_cov_share``: the tracker's share of the POI's uncertainty, trace(the tracker's covariance after the
  scenario) / trace(that + the gaze prior's) (:func:`tracker_share`), median per frame; 1 with no prior,
  0 for ``none`` with one, NaN where there is no uncertainty at all;
- per frame (``per_frame``): those PSNRs, the share, the JOD and the triangles.

Each scenario runs with the mode's own gaze prior (``SelectorConfig.gaze_prior``, or
``PaperTablesConfig.gaze_prior_deg``), hysteresis on and off, and, when that prior is not zero, once more with
hysteresis on and the prior ``(0, 0)`` (head only: the paper's view): rows ``prior`` ``"default"`` and
``"head only"``, each with its ``gaze_prior_deg``. Table 1, the goals and the charts are the default rows';
``table1`` has the head-only rows after them.

Goals (:func:`true_poi_goals`, :func:`goal_verdicts`), per condition and viewpoint, over the frames after the
warm-up where ``none``'s true-POI PSNR is below :data:`GOAL_PSNR_DB`: the fraction where ``adaptive`` (and
``fixed``, ``smoothed``) is at or above it, and ``adaptive``'s triangles against ``fixed``'s.

Conditions: ``today`` (the tracker as shipped); ``honest`` (today's with V jittered by :data:`PAPER_NOISE_DEG`
per angle, that variance added to its covariance); ``overconfident`` (the same jitter, the reported covariance
shrunk so that a calibrated one's mean NEES of 2 becomes :data:`OVERCONFIDENT_NEES`); and, on request only,
``paper_estimator`` (the paper's covariance estimator; its wide σ of V makes every run several times slower).
Each condition's mean NEES of V against the truth is measured (:func:`pose_nees`).

This module runs the conditions and makes the rows; :mod:`headplod.bench.paper_report` makes the goals, Table 1,
the findings, the text and the charts from them.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..demo import loop as lp
from ..demo.viewpoints import VIEWPOINTS
from ..io import read_gaze_truth
from ..plod.select import MODES, SelectorConfig
from ..plod.view import default_head, head_axes, poi_direction
from ..progress import Progress
from ..render.context import create_context
from ..render.gl import TerrainRenderer
from ..render.still import TerrainScene, px_per_deg_at
from .harness import DISC_DEG, SIZE, poi_disc
from ..render.image_metrics import psnr_db
from .outputs import write_json
from .uncertainty import nees
from .paper_report import (GOAL_FRACTION, GOAL_PSNR_DB, PRIOR_DEFAULT, PRIOR_HEAD_ONLY, SCENARIOS, findings,
                           format_tables, goal_verdicts, plot_tables, plot_true_poi, table1, true_poi_chart_path,
                           true_poi_goals)

__all__ = ["CONDITIONS", "ALL_CONDITIONS", "PaperTablesConfig", "JitteredPoses", "TrackedRun", "track_poses",
           "true_pois", "true_gaze_pois", "tracker_share", "point_disc", "prior_variants", "pose_nees",
           "level_statistics", "paper_tables", "run_paper_bench"]

#: Tracker conditions run by default, in report order.
CONDITIONS = ("today", "honest", "overconfident")
#: Every condition: the default ones and ``paper_estimator`` (on request: its wide covariance is slow to draw).
ALL_CONDITIONS = CONDITIONS + ("paper_estimator",)
#: A reversal counts as flicker when a level returns within this many frames.
FLICKER_FRAMES = 3
#: σ per angle of the viewing-direction noise of ``honest`` and ``overconfident``, deg.
PAPER_NOISE_DEG = 0.5
#: The mean NEES ``overconfident``'s covariance is shrunk for (a calibrated 2-D covariance gives 2).
OVERCONFIDENT_NEES = 25.0
#: The gaze prior of the head-only runs, (horizontal, vertical) σ deg: the paper's view, V alone.
HEAD_ONLY_PRIOR_DEG = (0.0, 0.0)


@dataclass(frozen=True)
class PaperTablesConfig:
    """Settings of the paper-conditions run: ``frames`` per run, ``warmup`` frames left out of the level
    statistics and the goals, ``viewpoints`` (``demo.viewpoints.VIEWPOINTS``), ``conditions``
    (:data:`ALL_CONDITIONS`), ``noise_deg`` (σ per angle of the jitter of ``honest`` and ``overconfident``, deg),
    image ``size`` (w, h) px, ``seed`` of the jitter, ``source`` (the frame source tracked, a spec for
    :func:`headplod.capture.open_source` whose dataset has ``truth.csv``; its ``gaze_truth.csv``, when there is
    one, gives the true gaze), ``vdp`` (also FovVideoVDP's JOD at the true POI, hysteresis-on scenarios; needs
    the optional extra), ``mode`` (the PLOD mode; None: ``SelectorConfig().mode``), ``gaze_prior_deg`` (the
    default runs' gaze prior, (horizontal, vertical) σ deg; None: the mode's own), ``head_only`` (also run each
    scenario, hysteresis on, with the prior (0, 0) when the default runs' prior is not zero)."""

    frames: int = 60
    warmup: int = 10
    viewpoints: tuple = tuple(VIEWPOINTS)
    conditions: tuple = CONDITIONS
    noise_deg: float = PAPER_NOISE_DEG
    size: tuple = SIZE
    seed: int = 0
    source: str = "synthetic"
    vdp: bool = False
    mode: str | None = None
    gaze_prior_deg: tuple | None = None
    head_only: bool = True

    def __post_init__(self):
        if not (isinstance(self.frames, int) and self.frames >= 3):
            raise ValueError(f"PaperTablesConfig.frames must be an integer >= 3, got {self.frames!r}")
        if not (isinstance(self.warmup, int) and 0 <= self.warmup < self.frames - 2):
            raise ValueError(f"PaperTablesConfig.warmup must be 0..frames-3, got {self.warmup!r}")
        for name, allowed in (("viewpoints", tuple(VIEWPOINTS)), ("conditions", ALL_CONDITIONS)):
            bad = [v for v in getattr(self, name) if v not in allowed]
            if bad or not getattr(self, name):
                raise ValueError(f"PaperTablesConfig.{name}: {bad or 'none given'}; choose from {allowed}")
        if not (math.isfinite(self.noise_deg) and self.noise_deg >= 0):
            raise ValueError(f"PaperTablesConfig.noise_deg must be a finite number >= 0, got {self.noise_deg!r}")
        if len(self.size) != 2 or any(int(v) != v or v < 1 for v in self.size):
            raise ValueError(f"PaperTablesConfig.size must be two positive integers (w, h) px, got {self.size!r}")
        if self.mode is not None and (self.mode not in MODES or self.mode == "full"):
            raise ValueError(f"PaperTablesConfig.mode must be None or one of "
                             f"{tuple(m for m in MODES if m != 'full')}, got {self.mode!r}")
        try:
            self.selector_config()
        except ValueError as exc:
            raise ValueError(f"PaperTablesConfig.gaze_prior_deg: {exc}") from None

    def selector_config(self, gaze_prior_deg="default") -> SelectorConfig:
        """The selector settings of the default runs (their mode and prior), or of ``gaze_prior_deg``'s."""
        prior = self.gaze_prior_deg if isinstance(gaze_prior_deg, str) else gaze_prior_deg
        mode = SelectorConfig().mode if self.mode is None else self.mode
        return SelectorConfig(mode=mode, gaze_prior_deg=None if prior is None else tuple(prior))


def prior_variants(config: PaperTablesConfig) -> list:
    """The gaze priors a run compares: ``[(prior label, gaze_prior_deg for the selector, effective (h, v) σ
    deg)]``: the default (the configured prior or the mode's own) and, with ``config.head_only`` and a
    default that is not zero, :data:`HEAD_ONLY_PRIOR_DEG`."""
    default = config.selector_config().gaze_prior
    out = [(PRIOR_DEFAULT, config.gaze_prior_deg, default)]
    if config.head_only and tuple(default) != HEAD_ONLY_PRIOR_DEG:
        out.append((PRIOR_HEAD_ONLY, HEAD_ONLY_PRIOR_DEG, HEAD_ONLY_PRIOR_DEG))
    return out


class JitteredPoses(lp.PoseSource):
    """Another source's poses with the viewing direction jittered: a noisier tracker, honestly reported or not.

    Each good pose's direction from the eye to its POI turns by Gaussian angles of σ ``noise_deg`` (deg) about
    two axes perpendicular to it (the POI moves accordingly; kept where it would miss the screen), and its (φ, θ)
    covariance becomes ``cov_scale`` × (its covariance + ``noise_deg²`` I), deg²: ``cov_scale`` 1 is honest,
    below 1 overconfident.
    """

    def __init__(self, inner: lp.PoseSource, noise_deg: float, seed: int = 0, cov_scale: float = 1.0):
        if not (math.isfinite(cov_scale) and cov_scale > 0):
            raise ValueError(f"JitteredPoses: cov_scale must be a positive number, got {cov_scale!r}")
        self.inner, self.screen = inner, inner.screen
        self.name = f"{inner.name} + {noise_deg:g} deg jitter" + (
            f", covariance x {cov_scale:.3g}" if cov_scale != 1 else "")
        self.noise_deg, self.cov_scale = float(noise_deg), float(cov_scale)
        self._rng = np.random.default_rng(seed)

    def read(self):
        pose = self.inner.read()
        if pose is None or not pose.ok:
            return pose
        d = poi_direction(self.screen, pose.eye_mm, pose.poi_px)
        u = np.cross(d, [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        a, b = np.tan(np.radians(self._rng.normal(0.0, self.noise_deg, 2)))
        poi = self.screen.intersect_ray(pose.eye_mm, d + a * u + b * v)
        cov = (None if pose.cov_deg2 is None
               else self.cov_scale * (pose.cov_deg2 + self.noise_deg ** 2 * np.eye(2)))
        return replace(pose, poi_px=pose.poi_px if poi is None else np.asarray(poi, dtype=np.float64),
                       cov_deg2=cov)

    def close(self) -> None:
        self.inner.close()


@dataclass
class TrackedRun:
    """A tracker condition's poses and the truth of their frames.

    ``poses``: list of N :class:`headplod.demo.pose_sources.Pose`; ``screen``; ``name`` of the source;
    ``true_eye_mm`` (N, 3) and ``true_v`` (N, 3): the true head position P1 (world mm) and unit viewing
    direction V (world frame) of each pose's frame, NaN where ``truth.csv`` has no row; ``true_gaze_px`` (N, 2)
    screen px: where the viewer really looks (head and eyes, ``gaze_truth.csv``), NaN where that file has no row
    or its ray misses the screen plane (all NaN without the file).
    """

    poses: list
    screen: object
    name: str
    true_eye_mm: np.ndarray
    true_v: np.ndarray
    true_gaze_px: np.ndarray | None = None

    def __post_init__(self):
        if self.true_gaze_px is None:
            self.true_gaze_px = np.full((len(self.poses), 2), np.nan)


def track_poses(condition: str, frames: int, noise_deg: float = PAPER_NOISE_DEG, seed: int = 0,
                source: str = "synthetic") -> TrackedRun:
    """The poses of a tracker condition (:data:`ALL_CONDITIONS`) on ``source`` (default: the built-in synthetic
    sequence), tracked once, with the truth of each pose's frame (:class:`TrackedRun`)."""
    from ..tracking.tracker import TrackerConfig

    if condition not in ALL_CONDITIONS:
        raise ValueError(f"unknown tracker condition {condition!r}; choose one of {ALL_CONDITIONS}")
    config = TrackerConfig(uncertainty="paper") if condition == "paper_estimator" else TrackerConfig()
    tracker = lp.TrackerPoses(source, config=config, max_frames=frames)
    dataset = getattr(tracker.source, "dataset", None)
    if dataset is None or not dataset.truth:
        tracker.close()
        raise ValueError(f"bench paper: {tracker.source.name} has no truth.csv; the true POI needs it")
    poses_source = tracker
    if condition in ("honest", "overconfident"):
        scale = 2.0 / OVERCONFIDENT_NEES if condition == "overconfident" else 1.0
        poses_source = JitteredPoses(tracker, noise_deg, seed, cov_scale=scale)
    poses = lp.read_all_poses(poses_source)
    # One pose per frame read, in the dataset's order (track_frames yields every frame it reads).
    indices = list(dataset.indices)[:len(poses)]
    eyes = np.full((len(poses), 3), np.nan)
    vs = np.full((len(poses), 3), np.nan)
    for k, index in enumerate(indices):
        if index in dataset.truth:
            position, axes = dataset.truth[index]
            eyes[k], vs[k] = position, axes[2] / np.linalg.norm(axes[2])
    gaze_path = Path(dataset.folder) / "gaze_truth.csv"
    gaze = true_gaze_pois(read_gaze_truth(gaze_path) if gaze_path.is_file() else {}, indices, len(poses))
    return TrackedRun(poses, poses_source.screen, poses_source.name, eyes, vs, gaze)


def true_gaze_pois(gaze_truth: dict, indices, n: int) -> np.ndarray:
    """(n, 2) screen px: the true gaze point (``gaze_truth``, :func:`headplod.io.read_gaze_truth`) of the frame
    ``indices[k]`` of each pose k; NaN where there is none (no row, the ray missed the screen plane, no index)."""
    out = np.full((n, 2), np.nan)
    for k, index in enumerate(list(indices)[:n]):
        row = gaze_truth.get(index)
        if row is not None:
            out[k] = row.screen_px
    return out


def true_pois(screen, eye_mm, v) -> np.ndarray:
    """(N, 2) screen px: where each true viewing ray (eye ``eye_mm`` (N, 3) world mm along ``v`` (N, 3), world
    frame) meets the screen (:meth:`headplod.io.Screen.intersect_ray`, as the tracker's POI); NaN where a row
    is NaN or the ray misses the screen plane. The point may lie outside the screen."""
    eye_mm, v = np.atleast_2d(np.asarray(eye_mm, dtype=np.float64)), np.atleast_2d(np.asarray(v, dtype=np.float64))
    if eye_mm.shape != v.shape or eye_mm.shape[1:] != (3,):
        raise ValueError(f"true_pois: need eye_mm and v of one shape (N, 3), got {eye_mm.shape} and {v.shape}")
    out = np.full((len(eye_mm), 2), np.nan)
    for k in np.flatnonzero(np.isfinite(eye_mm).all(axis=1) & np.isfinite(v).all(axis=1)):
        if np.any(v[k]):
            poi = screen.intersect_ray(eye_mm[k], v[k])
            if poi is not None:
                out[k] = poi
    return out


def tracker_share(gaze_cov_deg2, prior_sigma_deg) -> float:
    """The tracker's share of the POI's uncertainty: trace(C) / trace(C + P), or NaN.

    ``gaze_cov_deg2`` (2, 2) deg² or None: the conditioned view's covariance of where the viewer looks, C + P
    (:func:`headplod.plod.view.gaze_covariance`: C the tracker's covariance of V after the scenario, P the gaze
    prior's); ``prior_sigma_deg`` (horizontal, vertical) σ deg of that prior. In [0, 1]: 1 with no prior, 0 for
    ``none`` (C = 0) with one; NaN when there is no uncertainty at all (None, or a zero trace).
    """
    if gaze_cov_deg2 is None:
        return float("nan")
    total = float(np.trace(np.asarray(gaze_cov_deg2, dtype=np.float64)))
    if not math.isfinite(total) or total <= 0:
        return float("nan")
    prior = float(prior_sigma_deg[0]) ** 2 + float(prior_sigma_deg[1]) ** 2
    return min(1.0, max(0.0, (total - prior) / total))


def point_disc(shape, screen, point_px, eye_mm, size):
    """The ``DISC_DEG`` disc (:func:`headplod.bench.harness.poi_disc`) of an image of ``shape`` drawn at ``size``
    (w, h) px about the screen point ``point_px`` (2,) screen px seen from ``eye_mm`` (3,) world mm, or None when
    either is missing (NaN)."""
    point_px, eye_mm = np.asarray(point_px, dtype=np.float64), np.asarray(eye_mm, dtype=np.float64)
    if not (np.isfinite(point_px).all() and np.isfinite(eye_mm).all()):
        return None
    scale = np.array(size, dtype=np.float64) / np.array(screen.size_px, dtype=np.float64)
    return poi_disc(shape, point_px * scale, DISC_DEG * px_per_deg_at(screen, eye_mm, size))


def pose_nees(screen, poses, true_v) -> np.ndarray:
    """(N,) NEES of each pose's (φ, θ) covariance against the true V ``true_v`` (N, 3) world frame
    (:func:`headplod.bench.uncertainty.nees`), in the head frame the PLOD reads the covariance in
    (:func:`headplod.plod.view.head_axes` of the pose's eye and POI); NaN without a pose, a covariance or a truth."""
    true_v = np.asarray(true_v, dtype=np.float64)
    if true_v.shape != (len(poses), 3):
        raise ValueError(f"pose_nees: need true_v of shape ({len(poses)}, 3), got {true_v.shape}")
    out = np.full(len(poses), np.nan)
    for k, p in enumerate(poses):
        if p is not None and p.ok and p.cov_deg2 is not None and np.isfinite(true_v[k]).all():
            out[k] = nees(p.cov_deg2, true_v[k], head_axes(screen, p.eye_mm, p.poi_px))
    return out


def level_statistics(levels: np.ndarray, warmup: int, window: int = FLICKER_FRAMES) -> dict:
    """Level changes and reversals per frame of ``levels`` (N, F) int over frames ``warmup+1 .. N-1``: ``changes``
    (mean per frame), ``changes_max``, ``flicker`` (mean reversals per frame: a level differing from the
    previous frame's and equal to the one ``2..window`` frames before)."""
    levels = np.asarray(levels)
    if levels.ndim != 2 or len(levels) < warmup + 2:
        raise ValueError(f"level_statistics: need (N, F) levels with N >= warmup + 2, got {levels.shape}")
    changed = levels[1:] != levels[:-1]                          # (N-1, F): frame k+1 differs from k
    flicker = np.zeros_like(changed)
    for lag in range(2, window + 1):                             # a handful of lags, vectorized over frames
        back = levels[lag:] == levels[:-lag]                     # frame k+lag equals frame k
        moved = changed[lag - 1:]                                # ... and changed into frame k+lag
        flicker[lag - 1:] |= back & moved
    counted = slice(warmup, None)
    per_frame = changed[counted].sum(axis=1)
    return {"changes": float(per_frame.mean()), "changes_max": int(per_frame.max()),
            "flicker": float(flicker[counted].sum(axis=1).mean())}


def _median(values) -> float:
    """Median of the non-NaN values (inf counts: an identical disc), NaN when there are none."""
    a = np.asarray(values, dtype=np.float64)
    a = a[~np.isnan(a)]
    return float(np.median(a)) if a.size else float("nan")


def _listed(values) -> list:
    """Per-frame values for the JSON: NaN as None."""
    return [None if isinstance(v, float) and math.isnan(v) else v for v in values]


def _run_group(scene, run: TrackedRun, pois_true, viewpoint, renderers, config: PaperTablesConfig, progress,
               judge=None) -> list:
    """One viewpoint of one condition: the scenarios (hysteresis on, off; head only, on) and full, interleaved;
    rows.

    ``pois_true`` (N, 2) screen px, the true POI of each pose (:func:`true_pois`); ``judge`` a
    :class:`headplod.bench.plod_judge.Judge` of ``config.size`` or None. Needs ``len(_plan(config))`` renderers.
    """
    from .plod_judge import fixation_px

    screen = run.screen
    mode = config.selector_config().mode
    plan = _plan(config)
    tee = lp.TeePoses(lp.ReplayPoses(run.poses, screen), len(plan))
    loops = []
    for k, (scenario, hysteresis, (_, prior, _)) in enumerate(plan):
        m, unc = ("full", "none") if scenario == "full" else (mode, scenario)
        loops.append(lp.DemoLoop(scene, tee.consumer(k), renderers[k], mode=m, uncertainty=unc,
                                 viewpoint=viewpoint, view_mode="shaded", hud=False,
                                 selector_options={"hysteresis": hysteresis, "gaze_prior_deg": prior}))
    levels = [[] for _ in plan]
    psnr_tracked = [[] for _ in plan]
    psnr_true = [[] for _ in plan]
    psnr_gaze = [[] for _ in plan]
    share = [[] for _ in plan]
    jod_true = [[] for _ in plan]
    try:
        for frame in range(config.frames):
            results = []
            for k, loop in enumerate(loops):
                r = loop.step()
                if r is None:
                    break
                results.append(r)
                levels[k].append(r.levels.copy())
                progress.step(f"{viewpoint} {plan[k][0]} {r.frame_ms:.0f} ms")
            if len(results) < len(loops):
                break
            full = results[-1]
            pose = full.pose
            shape = full.image.shape
            disc = point_disc(shape, screen, pose.poi_px, pose.eye_mm, config.size)
            true_poi, true_eye = pois_true[frame], run.true_eye_mm[frame]
            true_disc = point_disc(shape, screen, true_poi, true_eye, config.size)
            gaze_disc = point_disc(shape, screen, run.true_gaze_px[frame], true_eye, config.size)
            fixation = None
            if (judge is not None and true_disc is not None and frame >= config.warmup
                    and 0 <= true_poi[0] <= screen.size_px[0] and 0 <= true_poi[1] <= screen.size_px[1]):
                fixation = fixation_px(screen, true_poi, config.size)
            for k, r in enumerate(results[:-1]):
                psnr_tracked[k].append(float("nan") if disc is None else psnr_db(r.image, full.image, disc))
                psnr_true[k].append(float("nan") if true_disc is None else psnr_db(r.image, full.image, true_disc))
                psnr_gaze[k].append(float("nan") if gaze_disc is None else psnr_db(r.image, full.image, gaze_disc))
                share[k].append(tracker_share(r.view.cov_deg2, plan[k][2][2]))
                judged = fixation is not None and _judged(plan[k])
                jod_true[k].append(judge.jod(full.image, r.image, fixation) if judged else float("nan"))
    finally:
        tee.close()
    rows = []
    full_fps = loops[-1].stats.summary()["fps"]
    for k, (scenario, hysteresis, (label, _, effective)) in enumerate(plan):
        summary = loops[k].stats.summary()
        row = {"viewpoint": viewpoint, "scenario": scenario, "hysteresis": hysteresis,
               "fps": summary["fps"], "frame_ms": summary["frame_ms_median"],
               "triangles": summary["triangles_median"]}
        if scenario != "full":
            row["prior"], row["gaze_prior_deg"] = label, [float(v) for v in effective]
            row.update(level_statistics(np.array(levels[k]), min(config.warmup, len(levels[k]) - 2)))
            row["psnr_tracked_disc_db"] = _median(psnr_tracked[k][config.warmup:])
            row["psnr_true_disc_db"] = _median(psnr_true[k][config.warmup:])
            row["psnr_gaze_disc_db"] = _median(psnr_gaze[k][config.warmup:])
            row["tracker_cov_share"] = _median(share[k][config.warmup:])
            if judge is not None and _judged(plan[k]):
                row["jod_true"] = _median(jod_true[k])
            row["fps_ratio_to_full"] = summary["fps"] / full_fps
            row["per_frame"] = {"psnr_tracked_db": _listed(psnr_tracked[k]), "psnr_true_db": _listed(psnr_true[k]),
                                "psnr_gaze_db": _listed(psnr_gaze[k]), "tracker_cov_share": _listed(share[k]),
                                "triangles": [int(t) for t in loops[k].stats.triangles]}
            if judge is not None and _judged(plan[k]):
                row["per_frame"]["jod_true"] = _listed(jod_true[k])
        rows.append(row)
    return rows


def _plan(config: PaperTablesConfig) -> list:
    """The runs of one viewpoint, in order: ``(scenario, hysteresis, prior variant)`` (:func:`prior_variants`):
    every scenario with the default prior, hysteresis on and off; with the head-only prior, hysteresis on;
    ``full`` last."""
    variants = prior_variants(config)
    plan = [(sc, hyst, variants[0]) for hyst in (True, False) for sc in SCENARIOS]
    plan += [(sc, True, v) for v in variants[1:] for sc in SCENARIOS]
    return plan + [("full", False, variants[0])]


def _judged(run) -> bool:
    """Whether a run of :func:`_plan` gets the judge's JOD (slow): hysteresis on, the default prior."""
    scenario, hysteresis, (label, _, _) = run
    return hysteresis and label == PRIOR_DEFAULT

def paper_tables(config: PaperTablesConfig = PaperTablesConfig(), err=None, scene=None, ctx=None) -> dict:
    """Run every condition x viewpoint x scenario; the report (JSON-ready dict).

    ``scene``: the :class:`TerrainScene` (default: built for the source's screen); ``ctx``: the OpenGL context
    (default: a new one, released at the end).
    """
    start = time.perf_counter()
    report = {"config": {"frames": config.frames, "warmup": config.warmup, "size": list(config.size),
                         "noise_deg": config.noise_deg, "overconfident_nees": OVERCONFIDENT_NEES,
                         "disc_deg": DISC_DEG, "flicker_frames": FLICKER_FRAMES,
                         "mode": config.selector_config().mode,
                         "gaze_priors": {label: [float(v) for v in effective]
                                         for label, _, effective in prior_variants(config)},
                         "goal_psnr_db": GOAL_PSNR_DB, "goal_fraction": GOAL_FRACTION, "vdp": config.vdp,
                         "source": config.source},
              "conditions": {}}
    own_ctx = ctx is None
    ctx = create_context() if own_ctx else ctx
    runs = len(_plan(config))
    renderers = [TerrainRenderer(ctx, size=tuple(config.size)) for _ in range(runs)]
    judge = None
    try:
        for condition in config.conditions:
            run = track_poses(condition, config.frames, config.noise_deg, config.seed, config.source)
            if not run.poses:
                raise RuntimeError(f"{condition}: the tracker gave no poses")
            good = [p for p in run.poses if p.ok and p.cov_deg2 is not None]
            sigma = [math.sqrt(max(np.linalg.eigvalsh(p.cov_deg2))) for p in good]
            scene = scene or TerrainScene.build(run.screen)
            pois = true_pois(run.screen, run.true_eye_mm, run.true_v)
            errors = pose_nees(run.screen, run.poses, run.true_v)
            errors = errors[np.isfinite(errors)]
            if config.vdp and judge is None:
                judge = _make_judge(run, config.size)
            progress = Progress(len(config.viewpoints) * runs * config.frames, f"paper tables: {condition}",
                                stream=err)
            rows = []
            for vp in config.viewpoints:
                rows += _run_group(scene, run, pois, vp, renderers, config, progress, judge)
            progress.close()
            report["conditions"][condition] = {
                "poses": run.name, "frames_with_pose": len(good), "frames": len(run.poses),
                "sigma_deg_median": float(np.median(sigma)) if sigma else None,
                "sigma_deg_change_median": (float(np.median(np.abs(np.diff(sigma)) / np.array(sigma[:-1])))
                                            if len(sigma) > 1 else None),
                "nees_mean": float(np.mean(errors)) if errors.size else None,
                "nees_median": float(np.median(errors)) if errors.size else None,
                "nees_frames": int(errors.size),
                "true_poi_frames": int(np.isfinite(pois).all(axis=1).sum()),
                "true_gaze_frames": int(np.isfinite(run.true_gaze_px).all(axis=1).sum()),
                "rows": rows, "table1": table1(rows), "true_poi": true_poi_goals(rows, config.warmup)}
    finally:
        for r in renderers:
            r.release()
        if own_ctx:
            ctx.release()
    report["goals"] = goal_verdicts(report)
    report["findings"] = findings(report)
    report["wall_s"] = round(time.perf_counter() - start, 1)
    return report


def _make_judge(run: TrackedRun, size):
    """FovVideoVDP for the run's display: the screen seen from its centre's normal at the true head's median
    distance (the judge's flat-display model has no lateral eye offset)."""
    from .plod_judge import Judge, display_geometry

    eyes = run.true_eye_mm[np.isfinite(run.true_eye_mm).all(axis=1)]
    if not len(eyes):
        raise ValueError("bench paper --vdp: no frame has a true head position")
    screen = run.screen
    centre = screen.pixel_to_world(np.array(screen.size_px, dtype=np.float64) / 2.0)
    distance = float(np.median(np.abs((eyes - centre) @ screen.normal)))
    head = default_head(screen, distance)
    return Judge(display_geometry(screen, head, tuple(size)))


def run_paper_bench(json_path=None, chart_path=None, quick: bool = False, noise_deg: float = PAPER_NOISE_DEG,
                    out=None, err=None, vdp: bool = False, conditions=CONDITIONS, mode: str | None = None,
                    gaze_prior_deg=None, head_only: bool = True) -> int:
    """``headplod bench paper``: run, print the tables, write the JSON and the charts (``chart_path`` and
    :func:`true_poi_chart_path` beside it); the exit status.

    ``mode``, ``gaze_prior_deg`` and ``head_only`` are :class:`PaperTablesConfig`'s (None: the default mode,
    the mode's own prior).

    The output paths are checked (their folders must exist or be creatable)
    before the run, and each is written whole or not at all.
    """
    import sys

    from ..io import write_atomically

    out = out or sys.stdout
    config = PaperTablesConfig(frames=30, warmup=10, viewpoints=("mountains",)) if quick else PaperTablesConfig()
    config = replace(config, noise_deg=noise_deg, vdp=bool(vdp), conditions=tuple(conditions), mode=mode,
                     gaze_prior_deg=None if gaze_prior_deg is None else tuple(gaze_prior_deg),
                     head_only=bool(head_only))
    if vdp:
        from .plod_judge import vdp_available

        if not vdp_available("fvvdp"):
            print("bench paper: --vdp needs FovVideoVDP; pip install -e '.[vdp]'", file=err or sys.stderr)
            return 2
    targets = [Path(p) for p in (json_path, chart_path) if p]
    for path in targets:
        if path.is_dir():
            raise ValueError(f"bench paper: {path} is a folder; give a file name")
        path.parent.mkdir(parents=True, exist_ok=True)
    report = paper_tables(config, err=err)
    print(format_tables(report), file=out)
    if json_path:
        write_json(json_path, report, indent=1, default=float)
        print(f"json: {json_path}", file=out)
    if chart_path:
        write_atomically(chart_path, lambda name: plot_tables(report, name), suffix=".png")
        other = true_poi_chart_path(chart_path)
        write_atomically(other, lambda name: plot_true_poi(report, name), suffix=".png")
        print(f"charts: {chart_path}, {other}", file=out)
    return 0
