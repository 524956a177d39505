"""Martinez et al.'s Tables 1-4 under the paper's conditions: the four uncertainty scenarios per tracker.

The paper blamed the adaptive scenario's poorer satisfaction on the jitter of its covariance. Per tracker
condition (:data:`CONDITIONS`), viewpoint (the paper's three test cases) and scenario, hysteresis on and off,
on poses tracked once per condition and replayed for every run, this reports what stands in for
satisfaction (README: the paper's scenarios):

- ``changes``: base triangles whose level changed from the previous frame, per frame after the warm-up;
- ``flicker``: level reversals (A → B → A within :data:`FLICKER_FRAMES` frames) per frame;
- ``fps`` and its ratio to ``full`` run back to back;
- ``psnr_disc_db``: median PSNR within ``DISC_DEG`` of the POI against ``full`` from the same pose.

Conditions: ``today`` (the tracker as shipped), ``paper_estimator`` (the paper's covariance estimator),
``paper_noise`` (today's with its direction jittered by :data:`PAPER_NOISE_DEG` per angle, that variance added
to its covariance).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..demo import loop as lp
from ..demo.viewpoints import VIEWPOINTS
from ..plod.view import poi_direction
from ..progress import Progress
from ..render.context import create_context
from ..render.gl import TerrainRenderer
from ..render.still import TerrainScene, px_per_deg_at
from .harness import DISC_DEG, SIZE, poi_disc, pyplot, save_figure
from .image_metrics import psnr_db
from .outputs import write_json

__all__ = ["CONDITIONS", "PaperTablesConfig", "JitteredPoses", "track_poses",
           "level_statistics", "paper_tables", "format_tables", "plot_tables"]

#: Tracker conditions, in report order.
CONDITIONS = ("today", "paper_estimator", "paper_noise")
#: The paper's scenarios and ours (``smoothed``).
SCENARIOS = ("none", "fixed", "adaptive", "smoothed")
#: A reversal counts as flicker when a level returns within this many frames.
FLICKER_FRAMES = 3
#: σ per angle of the viewing-direction noise of ``paper_noise``, deg.
PAPER_NOISE_DEG = 0.5


@dataclass(frozen=True)
class PaperTablesConfig:
    """Settings of the paper-conditions run: ``frames`` per run, ``warmup`` frames left out of the level
    statistics, ``viewpoints`` (``demo.viewpoints.VIEWPOINTS``), ``conditions`` (:data:`CONDITIONS`),
    ``noise_deg`` (σ per angle of ``paper_noise``'s jitter, deg), image ``size`` px, ``seed`` of the jitter."""

    frames: int = 60
    warmup: int = 10
    viewpoints: tuple = tuple(VIEWPOINTS)
    conditions: tuple = CONDITIONS
    noise_deg: float = PAPER_NOISE_DEG
    size: tuple = SIZE
    seed: int = 0

    def __post_init__(self):
        if not (isinstance(self.frames, int) and self.frames >= 3):
            raise ValueError(f"PaperTablesConfig.frames must be an integer >= 3, got {self.frames!r}")
        if not (isinstance(self.warmup, int) and 0 <= self.warmup < self.frames - 2):
            raise ValueError(f"PaperTablesConfig.warmup must be 0..frames-3, got {self.warmup!r}")
        for name, allowed in (("viewpoints", tuple(VIEWPOINTS)), ("conditions", CONDITIONS)):
            bad = [v for v in getattr(self, name) if v not in allowed]
            if bad or not getattr(self, name):
                raise ValueError(f"PaperTablesConfig.{name}: {bad or 'none given'}; choose from {allowed}")
        if not (math.isfinite(self.noise_deg) and self.noise_deg >= 0):
            raise ValueError(f"PaperTablesConfig.noise_deg must be a finite number >= 0, got {self.noise_deg!r}")


class JitteredPoses(lp.PoseSource):
    """Another source's poses with the viewing direction jittered: a noisier tracker, honestly reported.

    Each good pose's direction from the eye to its POI turns by Gaussian angles of σ ``noise_deg`` (deg) about
    two axes perpendicular to it (the POI moves accordingly; kept where it would miss the screen), and
    ``noise_deg²`` is added to both variances of its (φ, θ) covariance.
    """

    def __init__(self, inner: lp.PoseSource, noise_deg: float, seed: int = 0):
        self.inner, self.screen, self.name = inner, inner.screen, f"{inner.name} + {noise_deg:g} deg jitter"
        self.noise_deg = float(noise_deg)
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
        cov = None if pose.cov_deg2 is None else pose.cov_deg2 + self.noise_deg ** 2 * np.eye(2)
        return replace(pose, poi_px=pose.poi_px if poi is None else np.asarray(poi, dtype=np.float64),
                       cov_deg2=cov)

    def close(self) -> None:
        self.inner.close()


def track_poses(condition: str, frames: int, noise_deg: float = PAPER_NOISE_DEG, seed: int = 0):
    """The poses of a tracker condition on the built-in synthetic sequence: (list of Pose, screen, name)."""
    from ..tracking.tracker import TrackerConfig

    if condition not in CONDITIONS:
        raise ValueError(f"unknown tracker condition {condition!r}; choose one of {CONDITIONS}")
    config = TrackerConfig(uncertainty="paper") if condition == "paper_estimator" else TrackerConfig()
    source = lp.TrackerPoses("synthetic", config=config, max_frames=frames)
    if condition == "paper_noise":
        source = JitteredPoses(source, noise_deg, seed)
    return lp.read_all_poses(source), source.screen, source.name


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


def _run_group(scene, poses, screen, viewpoint, renderers, config: PaperTablesConfig, progress) -> list:
    """One viewpoint of one condition: the scenarios (hysteresis on, off) and full, interleaved."""
    plan = [(sc, h) for h in (True, False) for sc in SCENARIOS] + [("full", False)]
    tee = lp.TeePoses(lp.ReplayPoses(poses, screen), len(plan))
    loops = []
    for k, (scenario, hysteresis) in enumerate(plan):
        mode, unc = ("full", "none") if scenario == "full" else ("csf", scenario)
        loops.append(lp.DemoLoop(scene, tee.consumer(k), renderers[k], mode=mode, uncertainty=unc,
                                 viewpoint=viewpoint, view_mode="shaded", hud=False,
                                 selector_options={"hysteresis": hysteresis}))
    levels = [[] for _ in plan]
    psnr = [[] for _ in plan]
    w, h = config.size
    scale = np.array([w, h], dtype=np.float64) / np.array(screen.size_px, dtype=np.float64)
    try:
        for _ in range(config.frames):
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
            radius = DISC_DEG * px_per_deg_at(screen, pose.eye_mm, config.size)
            disc = poi_disc(full.image.shape, pose.poi_px * scale, radius)
            for k, r in enumerate(results[:-1]):
                psnr[k].append(psnr_db(r.image, full.image, disc))
    finally:
        tee.close()
    rows = []
    full_fps = loops[-1].stats.summary()["fps"]
    for k, (scenario, hysteresis) in enumerate(plan):
        summary = loops[k].stats.summary()
        row = {"viewpoint": viewpoint, "scenario": scenario, "hysteresis": hysteresis,
               "fps": summary["fps"], "frame_ms": summary["frame_ms_median"],
               "triangles": summary["triangles_median"]}
        if scenario != "full":
            row.update(level_statistics(np.array(levels[k]), min(config.warmup, len(levels[k]) - 2)))
            finite = [p for p in psnr[k] if math.isfinite(p)]
            row["psnr_disc_db"] = float(np.median(finite)) if finite else float("inf")
            row["fps_ratio_to_full"] = summary["fps"] / full_fps
        rows.append(row)
    return rows


def paper_tables(config: PaperTablesConfig = PaperTablesConfig(), err=None) -> dict:
    """Run every condition x viewpoint x scenario; the report (JSON-ready dict)."""
    start = time.perf_counter()
    report = {"config": {"frames": config.frames, "warmup": config.warmup, "size": list(config.size),
                         "noise_deg": config.noise_deg, "disc_deg": DISC_DEG, "flicker_frames": FLICKER_FRAMES},
              "conditions": {}}
    renderer = TerrainRenderer(create_context(), size=tuple(config.size))
    renderers = [renderer] + [TerrainRenderer(renderer.ctx, size=tuple(config.size)) for _ in range(8)]
    scene = None
    try:
        for condition in config.conditions:
            poses, screen, name = track_poses(condition, config.frames, config.noise_deg, config.seed)
            if not poses:
                raise RuntimeError(f"{condition}: the tracker gave no poses")
            good = [p for p in poses if p.ok and p.cov_deg2 is not None]
            sigma = [math.sqrt(max(np.linalg.eigvalsh(p.cov_deg2))) for p in good]
            scene = scene or TerrainScene.build(screen)
            progress = Progress(len(config.viewpoints) * 9 * config.frames, f"paper tables: {condition}",
                                stream=err)
            rows = []
            for vp in config.viewpoints:
                rows += _run_group(scene, poses, screen, vp, renderers, config, progress)
            progress.close()
            report["conditions"][condition] = {
                "poses": name, "frames_with_pose": len(good), "frames": len(poses),
                "sigma_deg_median": float(np.median(sigma)) if sigma else None,
                "sigma_deg_change_median": (float(np.median(np.abs(np.diff(sigma)) / np.array(sigma[:-1])))
                                            if len(sigma) > 1 else None),
                "rows": rows, "table1": _table1(rows)}
    finally:
        for r in renderers:
            r.release()
    report["findings"] = _findings(report)
    report["wall_s"] = round(time.perf_counter() - start, 1)
    return report


def _table1(rows) -> list:
    """Table 1: each scenario's figures averaged over the viewpoints (test cases)."""
    out = []
    for hysteresis in (True, False):
        for scenario in SCENARIOS:
            mine = [r for r in rows if r["scenario"] == scenario and r["hysteresis"] == hysteresis]
            if mine:
                out.append({"scenario": scenario, "hysteresis": hysteresis,
                            **{k: float(np.mean([r[k] for r in mine]))
                               for k in ("changes", "flicker", "fps", "fps_ratio_to_full", "psnr_disc_db")}})
    return out


def _findings(report) -> list:
    """Whether 'adaptive is worse than fixed because of jitter' holds, per condition (no hysteresis: the paper's)."""
    lines = []
    for condition, c in report["conditions"].items():
        t = {(r["scenario"], r["hysteresis"]): r for r in c["table1"]}
        a, f, n = t[("adaptive", False)], t[("fixed", False)], t[("none", False)]
        worse = a["flicker"] > 1.2 * f["flicker"] + 0.5
        lines.append(
            f"{condition} (σ {c['sigma_deg_median']:.3g}°, frame-to-frame change of σ "
            f"{100 * (c['sigma_deg_change_median'] or 0):.0f}%), no hysteresis: flicker per frame "
            f"none {n['flicker']:.1f}, fixed {f['flicker']:.1f}, adaptive {a['flicker']:.1f}; "
            f"PSNR in the disc {n['psnr_disc_db']:.1f} / {f['psnr_disc_db']:.1f} / {a['psnr_disc_db']:.1f} dB: "
            + ("adaptive flickers more than fixed: the paper's finding holds here"
               if worse else "adaptive does not flicker more than fixed: the paper's finding does not hold here"))
    return lines


def format_tables(report: dict) -> str:
    """The tables as text: Table 1 (mean over viewpoints) per condition, then per viewpoint."""
    lines = []
    head = f"{'scenario':9} {'hyst':4} {'changes':>8} {'flicker':>8} {'fps':>6} {'x full':>7} {'PSNR 5°':>8}"
    for condition, c in report["conditions"].items():
        sigma = c["sigma_deg_median"]
        lines.append(f"\n{condition}: {c['poses']}; pose in {c['frames_with_pose']}/{c['frames']} frames, "
                     f"median σ of V {sigma:.3g}°" if sigma is not None else f"\n{condition}: no covariance")
        blocks = [("Table 1 (mean over viewpoints)", c["table1"])]
        for vp in dict.fromkeys(r["viewpoint"] for r in c["rows"]):
            blocks.append((vp, [r for r in c["rows"] if r["viewpoint"] == vp and r["scenario"] != "full"]))
        for title, rows in blocks:
            lines.append(f"  {title}")
            lines.append("  " + head)
            for r in rows:
                lines.append(f"  {r['scenario']:9} {'on' if r['hysteresis'] else 'off':4} {r['changes']:8.1f} "
                             f"{r['flicker']:8.1f} {r['fps']:6.1f} {r['fps_ratio_to_full']:6.1f}x "
                             f"{r['psnr_disc_db']:7.1f}")
    lines.append("")
    lines += report.get("findings", [])
    return "\n".join(lines)


def plot_tables(report: dict, path) -> None:
    """Bars of flicker per frame and PSNR in the disc per scenario, one column per condition."""
    plt = pyplot()
    conditions = list(report["conditions"])
    fig, axes = plt.subplots(2, len(conditions), figsize=(4.2 * len(conditions), 6.4), squeeze=False)
    x = np.arange(len(SCENARIOS))
    for j, condition in enumerate(conditions):
        c = report["conditions"][condition]
        for i, (key, label) in enumerate((("flicker", "level reversals per frame"),
                                          ("psnr_disc_db", f"PSNR within {DISC_DEG:g}° of the POI, dB"))):
            ax = axes[i, j]
            for off, hysteresis, colour in ((-0.2, False, "tab:red"), (0.2, True, "tab:blue")):
                t = {r["scenario"]: r for r in c["table1"] if r["hysteresis"] == hysteresis}
                ax.bar(x + off, [t[s][key] for s in SCENARIOS], 0.4, color=colour,
                       label=f"hysteresis {'on' if hysteresis else 'off'}")
            ax.set_xticks(x, SCENARIOS)
            ax.set_ylabel(label)
            if i == 0:
                sigma = c["sigma_deg_median"]
                ax.set_title(f"{condition}\nσ of V {sigma:.2g}°" if sigma is not None else condition)
            if key == "psnr_disc_db":
                finite = [r[key] for r in c["table1"] if math.isfinite(r[key])]
                if finite:
                    ax.set_ylim(min(finite) - 3, max(finite) + 3)
            ax.grid(alpha=0.3, axis="y")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Martinez et al.'s scenarios under the paper's conditions (mean over the three viewpoints)")
    save_figure(fig, path, dpi=110)


def run_paper_bench(json_path=None, chart_path=None, quick: bool = False, noise_deg: float = PAPER_NOISE_DEG,
                    out=None, err=None) -> int:
    """``headplod bench paper``: run, print the tables, write the JSON and chart; the exit status.

    The output paths are checked (their folders must exist or be creatable)
    before the run, and each is written whole or not at all.
    """
    import sys

    from ..io import write_atomically

    out = out or sys.stdout
    config = PaperTablesConfig(frames=30, warmup=10, viewpoints=("mountains",)) if quick else PaperTablesConfig()
    config = replace(config, noise_deg=noise_deg)
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
        print(f"chart: {chart_path}", file=out)
    return 0
