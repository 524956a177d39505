"""``headplod bench plod --only quadtree``: selection time against the terrain's size, flat against quadtree.

Issue 14's goal: selection cost grows at most 2x from the 2M-triangle terrain (32 x 32 base at level 5) to
the 128M one (256 x 256 at level 5). :func:`selection_scaling` times ``LevelSelector`` and
:class:`.quadtree_selector.QuadtreeSelector` on base grids of 32² to 512² quads over the built-in terrain,
from the default view, each frame the frame step's ``select`` stage over a :class:`headplod.render.frame.SelectionOnlyBackend`
(no mesh of these sizes fits in memory), and checks that both give the same levels. The selector's inputs
come from :func:`grid_inputs`, not ``AdaptiveMesh`` (approximations: there).
"""
from __future__ import annotations

import json
import time

import numpy as np

from .. import io
from ..plod.select import LevelSelector, SelectorConfig, View
from ..plod.shading import michelson, shade
from ..render.frame import FrameSettings, make_frame_step
from .harness import DEFAULT_SCREEN, label_axes, progress, pyplot, save_figure
from .outputs import write_json
from .quadtree_selector import QuadtreeSelector

SIZES = (32, 64, 128, 256, 512)
#: ``--quick``'s grids: up to the 128M terrain's base (the goal's), not beyond.
QUICK_SIZES = (32, 64, 128, 256)
#: The other way to the 128M terrain: the 32² base refined to level 8 (same base triangles, finer levels).
DEEP = ((32, 8),)
GOAL_GROWTH = 2.0


def grid_inputs(terrain, nx: int, ny: int, max_level: int = 5) -> dict:
    """The selector's inputs of ``BaseMesh.grid(terrain, nx, ny)`` without a mesh, scene units (m), F = 2 nx ny
    in its face order: ``corners`` (F, 3, 3), ``centroids`` (F, 3) (exact), ``edge_length`` (F, L+1) (the longest
    side over 2^L), ``geometric_error`` (F, L+1) (zeros: ``csf`` ignores it), ``contrast`` (F,) (the shading's
    Michelson contrast over 7 points per triangle: lower than ``AdaptiveMesh.contrast``), ``grid_shape`` (ny, nx).
    """
    xmin, xmax, ymin, ymax = map(float, terrain.extent)
    gx, gy = np.meshgrid(np.linspace(xmin, xmax, nx + 1), np.linspace(ymin, ymax, ny + 1))
    z, vertex_normals = terrain.sample(gx.ravel(), gy.ravel())
    vertices = np.column_stack([gx.ravel(), gy.ravel(), z])
    j, i = np.mgrid[0:ny, 0:nx]
    v00 = (j * (nx + 1) + i).ravel()
    v10, v01 = v00 + 1, v00 + nx + 1
    v11 = v01 + 1
    faces = np.stack([np.column_stack([v00, v10, v11]), np.column_stack([v00, v11, v01])], axis=1).reshape(-1, 3)
    corners = vertices[faces]
    centroids = corners.mean(axis=1)
    side = np.linalg.norm(corners - corners[:, [1, 2, 0]], axis=2).max(axis=1)
    edge_length = side[:, None] / 2.0 ** np.arange(max_level + 1)
    # Shading at the corners, the centroid and midway from it to each corner.
    inner = np.concatenate([centroids[:, None, :2], 0.5 * (corners[..., :2] + centroids[:, None, :2])], axis=1)
    _, inner_normals = terrain.sample(inner[..., 0].ravel(), inner[..., 1].ravel())
    normals = np.concatenate([vertex_normals[faces], inner_normals.reshape(len(faces), 4, 3)], axis=1)
    return {"corners": corners, "centroids": centroids, "edge_length": edge_length,
            "geometric_error": np.zeros_like(edge_length), "contrast": michelson(shade(normals), axis=1),
            "grid_shape": (ny, nx)}


def default_model(terrain, screen) -> np.ndarray:
    """The built-in scene's placement ``T_world_scene`` (4, 4) (``TerrainScene.build``), without its mesh."""
    from ..render.still import DEPTH_MM, PITCH_DEG, SCALE_MM_PER_M
    from ..render.projection import scene_to_world

    x0, x1, y0, y1 = terrain.extent
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, float(np.median(terrain.dem_z_m))])
    return np.asarray(scene_to_world(SCALE_MM_PER_M, centre, screen, depth_mm=DEPTH_MM,
                                     pitch_deg=PITCH_DEG).matrix, dtype=np.float64)


def default_views(screen, frames: int, seed: int = 0) -> list:
    """A still head 60 cm in front of the screen's centre looking at its centre, with a tracker's noise.

    ``frames`` views at 30 Hz; eye noise 0.3 mm, POI noise 2 px, covariance
    diag(0.05, 0.08) deg² (σ of 0.2-0.3°), from ``seed``.
    """
    from ..render.still import default_head

    rng = np.random.default_rng(seed)
    head = default_head(screen)
    poi = np.array(screen.size_px, dtype=np.float64) / 2
    cov = np.diag([0.05, 0.08])
    return [View(head + rng.normal(0, 0.3, 3), poi + rng.normal(0, 2.0, 2), cov, k / 30.0) for k in range(frames)]


def _measure_grid(terrain, n: int, level: int, model, screen, views) -> tuple[dict, np.ndarray]:
    """Both selections on the n x n grid at ``level``, each through its own frame step; (row, last levels)."""
    t0 = time.perf_counter()
    g = grid_inputs(terrain, n, n, level)
    args = (g["centroids"], g["edge_length"], g["geometric_error"], g["contrast"], model, screen, SelectorConfig(mode="csf"))
    tree = QuadtreeSelector(*args, corners_scene=g["corners"], grid_shape=g["grid_shape"])
    settings = FrameSettings("mesh", tree.config, draw=False)
    steps = {"flat": make_frame_step(settings, screen, selector=LevelSelector(*args, corners_scene=g["corners"])),
             "quadtree": make_frame_step(settings, screen, selector=tree)}
    build_s = time.perf_counter() - t0
    ms = {name: [] for name in steps}
    nodes, evaluated, mismatched = [], [], 0
    for k, view in enumerate(views):              # loop over frames: the first is the warm-up
        out = {name: step(view, model) for name, step in steps.items()}
        mismatched += int(np.count_nonzero(out["flat"].levels != out["quadtree"].levels))
        if k:
            for name in steps:
                ms[name].append(out[name].stage_ms["select"])
            nodes.append(tree.last_stats["nodes_visited"])
            evaluated.append(tree.last_stats["triangles_evaluated"])
    levels = out["quadtree"].levels
    F = len(g["centroids"])
    row = {"quads": n * n, "max_level": level, "base_triangles": F, "triangles_full": F * 4 ** level,
           "flat_ms": float(np.median(ms["flat"])), "quadtree_ms": float(np.median(ms["quadtree"])),
           "nodes_visited": int(np.median(nodes)), "triangles_evaluated": int(np.median(evaluated)),
           "tree_nodes": tree.tree.n_nodes, "mismatched_levels": mismatched,
           "levels_above_0": int(np.count_nonzero(levels)), "build_s": round(build_s, 2)}
    return row, levels


def selection_scaling(sizes=SIZES, frames: int = 12, max_level: int = 5, terrain=None, screen=None,
                      progress=None, deep=DEEP) -> dict:
    """Flat against quadtree selection time per n x n base grid of ``sizes`` at ``max_level``, plus the
    (n, level) rows of ``deep`` (default: the 32² base at level 8); ``frames`` views each, the first untimed.

    Returns ``rows`` (per grid: ``quads``, ``base_triangles``, ``triangles_full``, ``flat_ms``, ``quadtree_ms``
    (median select stage), ``nodes_visited``, ``triangles_evaluated``, ``tree_nodes``, ``mismatched_levels``
    (0: the same levels), ``build_s``, ``max_level``), ``growth_2M_to_128M``, ``goal`` and ``goal_met``.
    """
    from ..plod.terrain import Terrain

    terrain = Terrain.jacksboro() if terrain is None else terrain
    screen = io.read_screen(DEFAULT_SCREEN) if screen is None else screen
    model = default_model(terrain, screen)
    views = default_views(screen, frames)
    rows = []
    for n, level in [(n, max_level) for n in sizes] + list(deep):     # loop over grid sizes
        row, _ = _measure_grid(terrain, n, level, model, screen, views)
        rows.append(row)
        if progress:
            progress(f"{n}x{n} quads ({row['base_triangles']} base triangles) at level {level}: flat "
                     f"{row['flat_ms']:.2f} ms, quadtree {row['quadtree_ms']:.2f} ms, {row['nodes_visited']} nodes, "
                     f"{row['mismatched_levels']} mismatched levels")
    by_size = {(r["quads"], r["max_level"]): r for r in rows}
    small = by_size.get((32 * 32, 5))

    def growth(key):
        big = by_size.get(key)
        return None if big is None or small is None else min(big["quadtree_ms"], big["flat_ms"]) / small["flat_ms"]

    growths = {"256x256_level5": growth((256 * 256, 5)), "32x32_level8": growth((32 * 32, 8))}
    return {"rows": rows, "frames": frames, "max_level": max_level, "growth_2M_to_128M": growths,
            "goal": f"selection cost grows at most {GOAL_GROWTH:g}x from the 2M terrain (32² base at level 5, "
                    f"flat) to the 128M one (the faster selector on it)",
            "goal_met": {k: None if v is None else bool(v <= GOAL_GROWTH) for k, v in growths.items()}}


def chart(report: dict, path) -> None:
    """Selection ms and nodes visited against base triangles, flat and quadtree, log-log."""
    plt = pyplot()
    deep = [r for r in report["rows"] if r["max_level"] != report["max_level"]]
    rows = [r for r in report["rows"] if r["max_level"] == report["max_level"]]
    x = [r["triangles_full"] for r in rows]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.5))
    ax.plot(x, [r["flat_ms"] for r in rows], "o-", label="flat (LevelSelector)")
    ax.plot(x, [r["quadtree_ms"] for r in rows], "s-", label="quadtree (QuadtreeSelector)")
    for r in deep:
        ax.plot(r["triangles_full"], r["flat_ms"], "o", mfc="none", ms=10, color="tab:blue",
                label=f"{int(r['quads'] ** 0.5)}² base at level {r['max_level']}, flat")
        ax.plot(r["triangles_full"], r["quadtree_ms"], "s", mfc="none", ms=10, color="tab:orange",
                label=f"{int(r['quads'] ** 0.5)}² base at level {r['max_level']}, quadtree")
    if rows:
        base = rows[0]["flat_ms"]
        ax.axhline(GOAL_GROWTH * base, color="k", ls="--", lw=1, label=f"goal: {GOAL_GROWTH:g}x the 2M flat")
    label_axes(ax, f"triangles at full detail (lines: level {report['max_level']}, n² base quads)",
               "selection ms (median)", "csf selection, default view", "log", "log", "both", 8)
    bx.plot(x, [r["base_triangles"] for r in rows], "o-", label="base triangles (flat evaluates all)")
    bx.plot(x, [r["nodes_visited"] for r in rows], "s-", label="quadtree nodes visited")
    bx.plot(x, [r["triangles_evaluated"] for r in rows], "^-", label="base triangles evaluated (quadtree)")
    label_axes(bx, f"triangles at full detail (level {report['max_level']})", None, "work per frame", "log", "log",
               "both", 8)
    save_figure(fig, path, dpi=110)


def run_quadtree_bench(json_path=None, chart_path=None, quick: bool = False) -> int:
    """``headplod bench plod --only quadtree``: measure (``quick``: :data:`QUICK_SIZES`, 4 frames), print a line
    per grid and the goal, write ``json_path`` and ``chart_path``; 0."""
    report = selection_scaling(QUICK_SIZES if quick else SIZES, frames=4 if quick else 12,
                               progress=progress("bench plod --only quadtree"))
    print(json.dumps({k: v for k, v in report.items() if k != "rows"}, indent=2))
    if json_path:
        write_json(json_path, report)
    if chart_path:
        chart(report, chart_path)
    return 0
