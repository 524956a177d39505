"""``headplod bench plod --only lazy``: the level-8 frame of the built-in terrain through the lazy mesh.

From the default view (:mod:`.harness`), every frame the demo's frame step over a ``MeshBackend`` whose
selector is ``csf`` over the quadtree (:func:`.quadtree_selector.scene_quadtree_selector`):

1. ``LazyAdaptiveMesh`` at :data:`LAZY_LEVEL` on the 32 x 32 base: a cold frame, then ``frames`` frames with
   the head moving 1 mm per frame along the screen (the POI fixed), each reusing the cached pieces it can;
2. ``AdaptiveMesh`` at :data:`ADAPTIVE_LEVEL`, the same frames.

Each mesh runs in its own process (:func:`.plod_scale.in_own_process`), so its resident memory is its own.
"""
from __future__ import annotations

import resource
import time

import numpy as np

from .harness import DEFAULT_SCREEN, FRAME_DT_S, SIZE, TRACKER_COV_DEG2, progress
from .quadtree_selector import scene_quadtree_selector

__all__ = ["LAZY_LEVEL", "ADAPTIVE_LEVEL", "CACHE_MB", "rss_mb", "run_frames", "measure_mesh", "lazy_report",
           "run_lazy_bench"]

#: Finest level of the lazy mesh (134M triangles at full detail on the 32 x 32 base).
LAZY_LEVEL = 8
#: Finest level of the whole-table mesh it is compared with.
ADAPTIVE_LEVEL = 5
#: The lazy mesh's piece cache budget, MB.
CACHE_MB = 256.0
#: The frames' statistics whose median over the warm frames is reported.
WARM_KEYS = ("select_ms", "build_ms", "upload_ms", "render_ms", "triangles", "nodes_visited", "triangles_evaluated")
#: The mesh's own statistics kept per frame.
MESH_KEYS = ("generated_pieces", "reused_pieces", "evicted_pieces", "cache_bytes", "rebuilt_faces")


def rss_mb() -> tuple[float, float]:
    """(current, peak) resident set size of this process, MB (peak: :func:`.plod_scale.peak_rss_mb`)."""
    from .plod_scale import peak_rss_mb

    with open("/proc/self/statm") as f:
        current = int(f.read().split()[1]) * resource.getpagesize()
    return current / 2 ** 20, peak_rss_mb()


def _frame_row(out, mesh, selector) -> dict:
    """One frame's figures: its stages (ms), triangles and their levels, the mesh's and the quadtree's stats."""
    st = out.stage_ms
    return {"select_ms": st["select"], "build_ms": st["build"], "upload_ms": st["upload"], "render_ms": st["render"],
            "triangles": int(out.triangles), "held": bool(out.held),
            "per_level": np.bincount(out.triangle_levels, minlength=mesh.max_level + 1).tolist(),
            **{k: selector.last_stats.get(k) for k in ("nodes_visited", "triangles_evaluated")},
            **{k: v for k, v in mesh.stats.items() if k in MESH_KEYS}}


def run_frames(scene, renderer, screen, frames: int, level_bias: float = 0.0) -> dict:
    """A cold frame then ``frames`` frames with the head moving 1 mm per frame, through the frame step: ``cold``
    (the first frame's figures), ``warm_median`` (medians of :data:`WARM_KEYS` over the rest), ``rss_mb``,
    ``peak_rss_mb`` (MB). ``scene``: a ``TerrainScene`` whose mesh is a ``BaseMesh.grid``'s."""
    from ..plod.view import View
    from ..render.frame import FrameSettings, make_frame_step
    from ..render.still import default_head

    selector = scene_quadtree_selector(scene, "csf", "adaptive", level_bias=level_bias)
    step = make_frame_step(FrameSettings("mesh", selector.config), screen, renderer=renderer, mesh=scene.mesh,
                           selector=selector)
    head0 = default_head(screen)
    poi = np.array(screen.size_px, dtype=np.float64) / 2
    rows = []
    for k in range(frames + 1):                     # loop over frames: the head 1 mm further each
        out = step(View(head0 + np.array([1.0 * k, 0.0, 0.0]), poi, TRACKER_COV_DEG2, k * FRAME_DT_S), scene.model)
        rows.append(_frame_row(out, scene.mesh, selector))
    warm = rows[1:]
    result = {"cold": rows[0]}
    if warm:
        result["warm_median"] = {k: float(np.median([r[k] for r in warm])) for k in WARM_KEYS}
    current, peak = rss_mb()
    result["rss_mb"], result["peak_rss_mb"] = round(current, 1), round(peak, 1)
    return result


def measure_mesh(kind: str, frames: int, level_bias: float = 0.0, cache_mb: float = CACHE_MB) -> dict:
    """One mesh (``lazy`` at :data:`LAZY_LEVEL`, ``adaptive`` at :data:`ADAPTIVE_LEVEL`) made and run in this
    process: ``init_s``, ``rss_start_mb``, ``rss_after_init_mb``, :func:`run_frames`' figures and, for
    ``lazy``, ``cache`` (budget and bytes held, triangles at full detail)."""
    from .. import io
    from ..plod.lazy_mesh import LazyAdaptiveMesh
    from ..plod.mesh import AdaptiveMesh, BaseMesh
    from ..render import TerrainRenderer, create_context
    from ..render.still import TerrainScene

    if kind not in ("lazy", "adaptive"):
        raise ValueError(f"measure_mesh: kind must be 'lazy' or 'adaptive', got {kind!r}")
    part = {"rss_start_mb": round(rss_mb()[0], 1)}
    screen = io.read_screen(DEFAULT_SCREEN)
    scene = TerrainScene.build(screen, max_level=0)          # the placement; its mesh is replaced
    base = BaseMesh.grid(scene.terrain)
    t0 = time.perf_counter()
    if kind == "lazy":
        scene.mesh = LazyAdaptiveMesh(base, scene.terrain, max_level=LAZY_LEVEL, cache_bytes=int(cache_mb * 2 ** 20))
    else:
        scene.mesh = AdaptiveMesh(base, scene.terrain, max_level=ADAPTIVE_LEVEL)
    part["init_s"] = time.perf_counter() - t0
    part["rss_after_init_mb"] = round(rss_mb()[0], 1)
    renderer = TerrainRenderer(create_context(), size=SIZE)
    part.update(run_frames(scene, renderer, screen, frames, level_bias))
    mesh = scene.mesh
    if kind == "lazy":
        part["cache"] = {"cache_budget_bytes": int(mesh.budget_bytes), "cache_bytes": int(mesh.cache_bytes),
                         "full_detail_triangles": int(mesh.triangle_count(np.full(mesh.n_faces, mesh.max_level)))}
    renderer.release()
    return part


def lazy_report(frames: int = 5, level_bias: float = 0.0, say=None) -> dict:
    """Both meshes, each measured in its own process (module notes); the report."""
    from .plod_scale import in_own_process

    say = say or (lambda text: None)
    report = {"size": list(SIZE), "level_bias": level_bias, "frames": frames, "cov_deg2": TRACKER_COV_DEG2.tolist(),
              "process": "each mesh in its own process"}
    for kind, level in (("lazy", LAZY_LEVEL), ("adaptive", ADAPTIVE_LEVEL)):
        say(f"{kind} mesh at level {level}")
        report[f"{kind}_level{level}"] = in_own_process(measure_mesh, kind, frames, level_bias)
    return report


def summary_lines(report) -> list:
    """A line per mesh: the warm frames' medians and the process's peak RSS."""
    lines = []
    for key in (f"lazy_level{LAZY_LEVEL}", f"adaptive_level{ADAPTIVE_LEVEL}"):
        part = report[key]
        w = part.get("warm_median") or part["cold"]
        lines.append(f"{key:16s} select {w['select_ms']:6.1f} ms, build {w['build_ms']:6.1f} ms, upload "
                     f"{w['upload_ms']:6.1f} ms, render {w['render_ms']:6.1f} ms, {int(w['triangles'])} triangles; "
                     f"cold build {part['cold']['build_ms']:.1f} ms; made in {part['init_s']:.1f} s; "
                     f"peak RSS {part['peak_rss_mb']:.0f} MB")
    return lines


def run_lazy_bench(json_path=None, quick: bool = False) -> int:
    """``headplod bench plod --only lazy``: measure, print a line per mesh, write ``json_path``; 0."""
    report = lazy_report(frames=2 if quick else 5, say=progress("bench plod --only lazy"))
    print("\n".join(summary_lines(report)))
    if json_path:
        from .outputs import write_json
        write_json(json_path, report)
    return 0
