"""Temporal stability of the PLOD level selection for a still head (``headplod bench stability``).

A still head rendered by the synthetic stereo renderer (preset ``static``: only image noise moves) is tracked
by the real tracker; each pose becomes a :class:`~headplod.plod.select.View` (eye = P1, POI = where the ray
along V meets the screen, cov = the tracker's (φ, θ) covariance, deg²) and goes through a fresh frame step
(:func:`.harness.mesh_step`, on a renderer of any size: the levels do not depend on it). After a warm-up,
every base triangle whose level differs from the previous frame's is a flicker the head did not cause. The
same head driven by the true pose (``truth.csv``, the tracker's cov) is the noise-free reference.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .. import io
from ..capture.synthetic import ensure_dataset
from ..live.loop import make_tracker, track_frames
from ..plod.select import MODES, UNCERTAINTY_MODES, View
from ..render.still import TerrainScene
from ..tracking.tracker import TrackerConfig
from .harness import DEFAULT_SCREEN, SIZE, mesh_step, pyplot, run_views, save_figure
from .outputs import write_json

__all__ = ["ViewList", "track_still_head", "still_head_views", "level_changes", "levels_sequence",
           "stability_report", "format_table", "plot_stability", "run_stability_bench"]


class ViewList(list):
    """A list of :class:`View`, one per frame; ``lost_frames``: the frames without a pose (they repeat the
    previous view; leading ones are dropped), ``lost`` their count, ``frames``: each view's frame index."""

    def __init__(self, views=(), lost_frames=(), frames=()):
        super().__init__(views)
        self.lost_frames = list(lost_frames)
        self.frames = list(frames)

    @property
    def lost(self) -> int:
        return len(self.lost_frames)


def _screen_of(dataset):
    if dataset.screen is not None:
        return dataset.screen
    return io.read_screen(DEFAULT_SCREEN)


def _dataset(frames: int, distance_mm: float, seed: int, root=None):
    return io.Dataset(ensure_dataset("static", frames=frames, seed=seed, root=root, quiet=True,
                                     distance_mm=float(distance_mm)))


def still_head_views(frames: int = 60, distance_mm: float = 600.0, seed: int = 0, config=None, root=None):
    """Tracked and truth-driven views of the still head: ``(tracked, truth, screen)``.

    ``tracked``: :func:`track_still_head`'s; ``truth``: per tracked view the true position and V of its frame,
    the same time and covariance (None without ``truth.csv``). ``config``: the TrackerConfig; ``root``: the
    render cache folder (default ``$HEADPLOD_CACHE``).
    """
    dataset = _dataset(frames, distance_mm, seed, root)
    screen = _screen_of(dataset)
    tracker = make_tracker(dataset, config or TrackerConfig())
    views, lost, indices = [], [], []
    for frame, result in track_frames(dataset, tracker):     # result None: an error frame
        view = None
        if result is not None and result.ok and result.cov_deg2 is not None:
            position = np.asarray(result.position_mm, dtype=np.float64)
            poi = screen.intersect_ray(position, np.asarray(result.axes, dtype=np.float64)[2])
            if poi is not None:
                view = View(position, np.asarray(poi, dtype=np.float64),
                            np.asarray(result.cov_deg2, dtype=np.float64), float(frame.t))
        if view is None:
            lost.append(frame.index)
            if not views:
                continue                       # nothing to repeat yet
            previous = views[-1]
            view = View(previous.eye_mm, previous.poi_px, previous.cov_deg2, float(frame.t))
        views.append(view)
        indices.append(frame.index)
    tracked = ViewList(views, lost, indices)

    truth = None
    if dataset.truth is not None:
        truth = ViewList(frames=indices)
        for index, view in zip(indices, tracked):
            position, axes = dataset.truth[index]
            poi = screen.intersect_ray(position, np.asarray(axes)[2])
            truth.append(View(np.asarray(position, dtype=np.float64), np.asarray(poi, dtype=np.float64),
                              view.cov_deg2, view.t))
    return tracked, truth, screen


def track_still_head(frames: int = 60, distance_mm: float = 600.0, seed: int = 0, root=None) -> ViewList:
    """Views of the synthetic still head (preset ``static``, ``frames`` at ``distance_mm``, image noise
    ``seed``) as the real tracker sees it: a :class:`ViewList` (eye = P1, world mm; POI screen px; cov deg²)."""
    return still_head_views(frames, distance_mm, seed, root=root)[0]


def levels_sequence(scene, views, mode="csf", uncertainty="adaptive", hysteresis=True, *, renderer,
                    **options) -> np.ndarray:
    """(N, F) levels of the views' frames, in order, through a fresh frame step drawing on ``renderer``."""
    step = mesh_step(scene, renderer, mode, uncertainty, hysteresis=hysteresis, **options)
    return np.stack([frame.levels for frame in run_views(step, views, scene.model, images=False)])


def _changes(levels: np.ndarray, warmup: int) -> tuple[list[int], list[int]]:
    start = max(int(warmup), 1)
    frames = list(range(start, len(levels)))
    return [int(np.count_nonzero(levels[i] != levels[i - 1])) for i in frames], frames


def level_changes(scene, views, mode="csf", uncertainty="adaptive", hysteresis=True, warmup=10,
                  levels: np.ndarray | None = None, renderer=None) -> dict:
    """Level changes per frame of a fresh frame step (``mode``, ``uncertainty``, ``hysteresis``, on ``renderer``)
    over ``views``, or of ``levels`` (N, F) already computed: frame i >= max(``warmup``, 1) counts the base
    triangles whose level differs from frame i-1's.

    Returns ``changes_per_frame``, ``frames`` (their indices), ``mean_changes``, ``max_changes``,
    ``frames_with_changes``, ``triangles`` (the mean triangle count over the counted frames), ``faces``.
    """
    if levels is None:
        levels = levels_sequence(scene, views, mode, uncertainty, hysteresis, renderer=renderer)
    changes, frames = _changes(levels, warmup)
    counted = levels[frames] if frames else levels[-1:]
    triangles = float(np.mean([scene.mesh.triangle_count(lv) for lv in counted]))
    return {"mode": mode, "uncertainty": uncertainty, "hysteresis": bool(hysteresis), "warmup": int(warmup),
            "changes_per_frame": changes, "frames": frames,
            "mean_changes": float(np.mean(changes)) if changes else 0.0,
            "max_changes": int(max(changes)) if changes else 0,
            "frames_with_changes": int(sum(c > 0 for c in changes)),
            "triangles": triangles, "faces": int(levels.shape[1])}


def _noise(views) -> dict:
    eye = np.array([v.eye_mm for v in views])
    poi = np.array([v.poi_px for v in views])
    covs = [np.asarray(v.cov_deg2) for v in views if v.cov_deg2 is not None]
    trace = np.array([np.trace(c) for c in covs]) if covs else np.array([np.nan])
    return {"eye_std_mm": eye.std(axis=0).round(4).tolist(), "poi_std_px": poi.std(axis=0).round(3).tolist(),
            "poi_range_px": np.ptp(poi, axis=0).round(3).tolist(),
            "cov_trace_deg2": {"mean": float(np.mean(trace)), "min": float(np.min(trace)),
                               "max": float(np.max(trace))},
            "sigma_deg": float(np.sqrt(np.mean(trace) / 2))}


def stability_report(scene=None, frames=60, modes=("csf",), uncertainties=UNCERTAINTY_MODES,
                     hysteresis=(True, False), warmup=10, distance_mm=600.0, seed=0, views=None,
                     root=None, renderer=None) -> dict:
    """Level changes per frame of the still head for every mode x uncertainty x hysteresis.

    ``scene``: built for the dataset's screen when None; ``views``: :func:`still_head_views`' output, else
    tracked here (``frames``, ``distance_mm``, ``seed``, ``root``); ``renderer``: default a quarter of the
    benches' size per side, made here.

    Returns ``runs`` (a :func:`level_changes` per combination, with ``truth``, the same counts for the
    truth-driven views, and ``differs_from_truth``[``_max``], triangles at another level than the truth-driven
    selection's on the last frame [at worst]), ``frames``, ``lost``, ``noise`` and ``truth_noise``, ...
    """
    start = time.perf_counter()
    if views is None:
        tracked, truth, screen = still_head_views(frames, distance_mm, seed, root=root)
    else:
        tracked, truth = views[:2]
        screen = views[2] if len(views) > 2 else None
    if scene is None:
        if screen is None:
            screen = _screen_of(_dataset(frames, distance_mm, seed, root))
        scene = TerrainScene.build(screen)
    own = renderer is None
    if own:
        from ..render import TerrainRenderer, create_context

        renderer = TerrainRenderer(create_context(), size=(SIZE[0] // 4, SIZE[1] // 4))
    try:
        runs = [_run(scene, tracked, truth, mode, unc, hyst, warmup, renderer)
                for mode in modes for hyst in hysteresis for unc in uncertainties]
    finally:
        if own:
            renderer.release()
    return {"preset": "static", "distance_mm": float(distance_mm), "seed": int(seed), "frames": len(tracked),
            "lost": tracked.lost, "lost_frames": tracked.lost_frames, "warmup": int(warmup),
            "faces": int(scene.mesh.n_faces), "max_level": int(scene.mesh.max_level),
            "noise": _noise(tracked), "truth_noise": _noise(truth) if truth is not None else None,
            "runs": runs, "seconds": time.perf_counter() - start}


def _run(scene, tracked, truth, mode, unc, hyst, warmup, renderer) -> dict:
    """One combination of :func:`stability_report`: its :func:`level_changes` and the comparison with the truth."""
    levels = levels_sequence(scene, tracked, mode, unc, hyst, renderer=renderer)
    run = level_changes(scene, tracked, mode, unc, hyst, warmup, levels=levels)
    if truth is not None:
        ref = levels_sequence(scene, truth, mode, unc, hyst, renderer=renderer)
        t = level_changes(scene, truth, mode, unc, hyst, warmup, levels=ref)
        run["truth"] = {k: t[k] for k in ("mean_changes", "max_changes", "frames_with_changes", "triangles")}
        run["differs_from_truth"] = int(np.count_nonzero(levels[-1] != ref[-1]))
        run["differs_from_truth_max"] = int(max(np.count_nonzero(a != b) for a, b in
                                                zip(levels[warmup:], ref[warmup:])))
    return run


def format_table(report: dict) -> str:
    """A plain-text table of a :func:`stability_report`."""
    lines = [f"still head at {report['distance_mm']:.0f} mm, {report['frames']} frames "
             f"({report['lost']} without pose), changes counted after frame {report['warmup']}, "
             f"{report['faces']} base triangles",
             f"tracked POI std {report['noise']['poi_std_px']} px, eye std {report['noise']['eye_std_mm']} mm, "
             f"tracker sigma(V) {report['noise']['sigma_deg']:.4f} deg",
             f"{'mode':8s} {'hyst':5s} {'uncertainty':11s} {'mean':>7s} {'max':>4s} {'frames':>6s} "
             f"{'tris':>8s} {'truth mean':>10s} {'truth max':>9s} {'!=truth':>7s}"]
    for r in report["runs"]:
        t = r.get("truth") or {}
        lines.append(f"{r['mode']:8s} {'yes' if r['hysteresis'] else 'no':5s} {r['uncertainty']:11s} "
                     f"{r['mean_changes']:7.3f} {r['max_changes']:4d} {r['frames_with_changes']:6d} "
                     f"{r['triangles']:8.0f} {t.get('mean_changes', float('nan')):10.3f} "
                     f"{t.get('max_changes', -1):9d} {r.get('differs_from_truth', -1):7d}")
    return "\n".join(lines)


def plot_stability(report: dict, path) -> Path:
    """Level changes per frame against frame index, a line per uncertainty mode (offset so coinciding ones stay
    visible), a column per hysteresis setting, a row per selection mode."""
    plt = pyplot()
    runs = report["runs"]
    modes = list(dict.fromkeys(r["mode"] for r in runs))
    hysts = list(dict.fromkeys(r["hysteresis"] for r in runs))
    uncs = list(dict.fromkeys(r["uncertainty"] for r in runs))
    fig, axes = plt.subplots(len(modes), len(hysts), figsize=(5.5 * len(hysts), 3.2 * len(modes)),
                             squeeze=False, sharey="row")
    for i, mode in enumerate(modes):
        for j, hyst in enumerate(hysts):
            ax = axes[i][j]
            for k, unc in enumerate(uncs):
                for r in runs:
                    if (r["mode"], r["hysteresis"], r["uncertainty"]) == (mode, hyst, unc):
                        # Coinciding lines stay visible: wider lines drawn first, distinct markers.
                        width = 1 + 2.5 * (len(uncs) - 1 - k) / max(len(uncs) - 1, 1)
                        label = f"{unc} (mean {r['mean_changes']:.2f}, max {r['max_changes']})"
                        ax.plot(r["frames"], r["changes_per_frame"], marker="os^.vD"[k % 6], ms=max(6 - k, 2),
                                lw=width, alpha=0.8, label=label)
            ax.set_title(f"{mode}, {'with' if hyst else 'without'} hysteresis", fontsize=10)
            ax.set_xlabel("frame")
            ax.set_ylabel("base triangles changing level")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"still head at {report['distance_mm']:.0f} mm through the tracker: level changes per frame "
                 f"after frame {report['warmup']}", fontsize=10)
    return save_figure(fig, path, dpi=110)


def run_stability_bench(json_path=None, chart_path=None, frames: int = 60, distance_mm: float = 600.0, seed: int = 0,
                        modes=("csf",)) -> int:
    """``headplod bench stability``: the report of :func:`stability_report` printed, as JSON and chart; the exit
    status. ``modes``: selection modes, or ``("all",)``."""
    modes = MODES if tuple(modes) == ("all",) else tuple(modes)
    bad = [m for m in modes if m not in MODES]
    if bad:
        raise ValueError(f"bench stability: unknown mode {bad[0]!r}; choose from {', '.join(MODES)} or all")
    warmup = 10          # stability_report's: the filters and the hysteresis settle first
    if frames <= warmup + 1:
        raise ValueError(f"bench stability: --frames {frames} leaves no frame to count: changes are counted after "
                         f"the first {warmup} (the filters settle); give at least {warmup + 2}")
    report = stability_report(frames=frames, modes=modes, distance_mm=distance_mm, seed=seed, warmup=warmup)
    print(format_table(report))
    if json_path:
        write_json(json_path, report, indent=1)
    if chart_path:
        plot_stability(report, chart_path)
    return 0
