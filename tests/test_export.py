"""``headplod render --export``: the frame's PLOD mesh written through trimesh, and its conformity.

trimesh reads the files back; the checks are its own: one consistently
wound, crack-free disk (Euler number 1, boundary edges only on the
terrain's outer border) whose faces carry their level's colour.
"""
import json

import numpy as np
import pytest
import trimesh

from headplod.cli import main as cli_main
from headplod.plod.export import EXPORT_FORMATS, check_export_path, export_mesh, selected_mesh
from headplod.plod.mesh import LEVEL_PALETTE, AdaptiveMesh, BaseMesh
from headplod.plod.terrain import Terrain


@pytest.fixture(scope="module")
def small_mesh():
    terrain = Terrain.jacksboro()
    return AdaptiveMesh(BaseMesh.grid(terrain, 8, 6), terrain, max_level=3)


def _conforming_disk(tm: trimesh.Trimesh, border_xy):
    """Assert a welded mesh is one crack-free, consistently wound disk whose open edges lie on the border."""
    tm = tm.copy()
    tm.merge_vertices()
    assert tm.is_winding_consistent
    assert tm.euler_number == 1, f"Euler number {tm.euler_number}: holes or cracks"
    open_edges = tm.edges_sorted[trimesh.grouping.group_rows(tm.edges_sorted, require_count=1)]
    ends = tm.vertices[open_edges]                                           # (B, 2, 3)
    (xmin, ymin), (xmax, ymax) = border_xy
    tol = 1e-6 * max(xmax - xmin, ymax - ymin)
    on_border = ((np.abs(ends[..., 0] - xmin) < tol).all(1) | (np.abs(ends[..., 0] - xmax) < tol).all(1)
                 | (np.abs(ends[..., 1] - ymin) < tol).all(1) | (np.abs(ends[..., 1] - ymax) < tol).all(1))
    assert on_border.all(), f"{(~on_border).sum()} open edges inside the domain (cracks)"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_selected_mesh_is_a_crack_free_disk_coloured_by_level(small_mesh, seed):
    rng = np.random.default_rng(seed)
    levels = rng.integers(0, small_mesh.max_level + 1, small_mesh.n_faces)
    tm = selected_mesh(small_mesh, levels)
    assert len(tm.faces) == small_mesh.triangle_count(levels)
    _, tri_levels = small_mesh.update_indices(levels)
    assert np.array_equal(tm.visual.face_colors[:, :3], LEVEL_PALETTE[np.asarray(tri_levels) % len(LEVEL_PALETTE)])
    positions = np.asarray(small_mesh.vertex_positions, np.float64)
    _conforming_disk(tm, (positions[:, :2].min(axis=0), positions[:, :2].max(axis=0)))


@pytest.mark.parametrize("ending", EXPORT_FORMATS)
def test_export_round_trips_through_trimesh(small_mesh, tmp_path, ending):
    levels = np.full(small_mesh.n_faces, 2)
    levels[::3] = 0
    path = export_mesh(small_mesh, levels, tmp_path / f"frame{ending}")
    loaded = trimesh.load(path, force="mesh")
    expected = selected_mesh(small_mesh, levels)
    assert len(loaded.faces) == len(expected.faces)
    # Same surface: the area (formats may weld or split vertices, and glTF stores float32).
    assert loaded.area == pytest.approx(expected.area, rel=1e-5)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"frame{ending}"]        # no temporary left


@pytest.mark.parametrize("name, message", [("mesh.xyz", "ending"), ("missing/mesh.ply", "does not exist")])
def test_bad_export_paths_are_refused_before_any_work(tmp_path, name, message):
    with pytest.raises(ValueError, match=message):
        check_export_path(tmp_path / name)
    out = tmp_path / "frame.png"
    assert cli_main(["render", "--out", str(out), "--export", str(tmp_path / name), "--size", "64,36"]) == 2
    assert not out.exists()                                                     # nothing rendered


@pytest.mark.slow
@pytest.mark.usefixtures("gl_context")
def test_rendered_frame_exports_a_crack_free_mesh_with_the_stats_triangle_count(tmp_path, ending=".glb"):
    """``headplod render --export`` end to end on the built-in scene: trimesh reloads the file with as many
    faces as the stats report. The terrain is an open sheet, so trimesh's ``is_watertight`` (closed) is
    False by construction; watertight here means no cracks: after welding, every edge inside is shared by
    exactly two faces and the open edges lie only on the terrain's border (``_conforming_disk``). glTF here
    (float32 vertices); tests/test_terrain_files.py does the same with PLY for a ``--terrain`` file."""
    mesh, stats = tmp_path / f"frame{ending}", tmp_path / "frame.json"
    assert cli_main(["render", "--out", str(tmp_path / "frame.png"), "--stats", str(stats), "--export", str(mesh),
                     "--size", "160,90", "--cov", "1,0,1"]) == 0
    s = json.loads(stats.read_text())
    loaded = trimesh.load(mesh, force="mesh")
    assert len(loaded.faces) == s["triangles"] > 2048
    x0, x1, y0, y1 = Terrain.jacksboro(detail=False).extent
    _conforming_disk(loaded, ((x0, y0), (x1, y1)))
    welded = loaded.copy()
    welded.merge_vertices()
    _, counts = np.unique(welded.edges_sorted, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2}
