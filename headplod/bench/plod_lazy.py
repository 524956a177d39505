"""The level-8 frame of the built-in terrain through :class:`headplod.plod.lazy_mesh.LazyAdaptiveMesh`.

``python -m headplod.bench.plod_lazy [--frames N] [--cache-mb MB] [--max-level 8] [--out FILE]``

The default view (the embedded screen, the head 60 cm in front of its
centre, the POI at the centre, σ 0.05°, 1280x720 offscreen), selected by
``csf`` over the quadtree (:func:`headplod.bench.quadtree_selector.scene_quadtree_selector`),
the soup uploaded through ``TerrainRenderer.upload`` and drawn:

1. the lazy mesh at ``--max-level`` (default 8) on the 32 x 32 base: a
   cold frame (empty cache), then ``--frames`` frames with the head moving
   1 mm per frame along the screen (the POI fixed), each reusing the cached
   pieces it can;
2. :class:`headplod.plod.mesh.AdaptiveMesh` at level 5 in the same process,
   the same frames.

Per part: build ms (pieces made + frame assembled + soup gathered), select
ms, render ms, triangles, cache bytes and the process's RSS (current and
peak, MB) after it. Prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time

import numpy as np

from .. import io
from ..plod.lazy_mesh import LazyAdaptiveMesh
from ..plod.mesh import AdaptiveMesh, BaseMesh
from ..plod.select import View
from ..plod.terrain import Terrain
from ..render import TerrainRenderer, create_context, off_axis_projection
from ..render.still import TerrainScene, default_head
from .plod import DEFAULT_SCREEN, SIZE
from .quadtree_selector import scene_quadtree_selector


def rss_mb() -> tuple[float, float]:
    """(current, peak) resident set size of this process, MB."""
    with open("/proc/self/statm") as f:
        current = int(f.read().split()[1]) * resource.getpagesize()
    return current / 2 ** 20, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_frames(scene, renderer, screen, frames: int, level_bias: float = 0.0) -> dict:
    """A cold frame then ``frames`` frames with the head moving 1 mm per frame; stats of each kind."""
    selector = scene_quadtree_selector(scene, "csf", "adaptive", level_bias=level_bias)
    head0 = default_head(screen)
    poi = np.array(screen.size_px, dtype=np.float64) / 2
    cov = np.diag([0.05 ** 2, 0.05 ** 2])
    rows = []
    for k in range(frames + 1):
        head = head0 + np.array([1.0 * k, 0.0, 0.0])
        t0 = time.perf_counter()
        levels, _ = selector.select(View(head, poi, cov, k / 60))
        t1 = time.perf_counter()
        positions, normals, tri_levels = scene.mesh.update(levels)
        t2 = time.perf_counter()
        renderer.upload(positions, normals, tri_levels)
        view_m, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
        renderer.render(view_m, proj, scene.model, view_mode="shaded")
        rows.append({"select_ms": (t1 - t0) * 1e3, "build_ms": (t2 - t1) * 1e3,
                     "render_ms": renderer.last_render_ms, "triangles": int(len(tri_levels)),
                     "per_level": np.bincount(tri_levels, minlength=scene.mesh.max_level + 1).tolist(),
                     **{k: v for k, v in scene.mesh.stats.items() if k in
                        ("generated_pieces", "reused_pieces", "evicted_pieces", "cache_bytes")}})
    warm = rows[1:]
    out = {"cold": rows[0]}
    if warm:
        out["warm_median"] = {k: float(np.median([r[k] for r in warm])) for k in
                              ("select_ms", "build_ms", "render_ms", "triangles")}
    current, peak = rss_mb()
    out["rss_mb"], out["peak_rss_mb"] = round(current, 1), round(peak, 1)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m headplod.bench.plod_lazy", description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--cache-mb", type=float, default=256.0)
    parser.add_argument("--max-level", type=int, default=8)
    parser.add_argument("--level-bias", type=float, default=0.0,
                        help="csf's level bias (3: the default view asks for levels up to 8)")
    parser.add_argument("--only", choices=("lazy", "adaptive"), default=None,
                        help="run one mesh only (its RSS then is its own)")
    parser.add_argument("--out", default=None, help="also write the JSON here")
    args = parser.parse_args(argv)
    screen = io.read_screen(DEFAULT_SCREEN)
    result = {"size": list(SIZE), "level_bias": args.level_bias, "rss_start_mb": round(rss_mb()[0], 1)}
    terrain = Terrain.jacksboro()
    base = BaseMesh.grid(terrain)
    t0 = time.perf_counter()
    lazy = None if args.only == "adaptive" else LazyAdaptiveMesh(base, terrain, max_level=args.max_level,
                                                                 cache_bytes=int(args.cache_mb * 2 ** 20))
    result["lazy_init_s"] = time.perf_counter() - t0
    scene = TerrainScene.build(screen, max_level=0)          # the model matrix; its mesh is replaced
    scene.mesh = lazy
    renderer = TerrainRenderer(create_context(), size=SIZE)
    result["rss_after_lazy_init_mb"] = round(rss_mb()[0], 1)
    if args.only != "adaptive":
        result[f"lazy_level{args.max_level}"] = run_frames(scene, renderer, screen, args.frames, args.level_bias)
        result["lazy_level_stats"] = {"cache_budget_bytes": lazy.budget_bytes, "cache_bytes": lazy.cache_bytes,
                                      "full_detail_triangles": int(lazy.triangle_count(
                                          np.full(lazy.n_faces, lazy.max_level)))}
    if args.only != "lazy":
        scene.mesh = None
        del lazy
        t0 = time.perf_counter()
        scene.mesh = AdaptiveMesh(base, terrain, max_level=5)
        result["adaptive_init_s"] = time.perf_counter() - t0
        result["adaptive_level5"] = run_frames(scene, renderer, screen, args.frames, args.level_bias)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
