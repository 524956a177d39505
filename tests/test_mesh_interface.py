"""One adaptive-mesh interface (headplod.plod.mesh_base.AdaptiveMeshBase): both kinds alike through it.

The whole-table mesh and the lazy one are driven only through the base
class's methods and attributes here: for the same levels they must give
the same triangles (positions and normals, bit for bit) with the same
levels and base faces, and their capability attributes must say what each
can do, so callers need no ``isinstance``.
"""
import numpy as np
import pytest

from headplod.plod.export import selected_mesh
from headplod.plod.lazy_mesh import LazyAdaptiveMesh
from headplod.plod.mesh import AdaptiveMesh
from headplod.plod.mesh_base import FULL_MAX_LEVEL, AdaptiveMeshBase, BaseMesh
from headplod.plod.terrain import Terrain

M = 5


@pytest.fixture(scope="module")
def meshes():
    """{kind: mesh} over one 6 x 5 base of the built-in terrain at max_level 5."""
    terrain = Terrain.jacksboro()
    base = BaseMesh.grid(terrain, 6, 5)
    return {kind: cls(base, terrain, max_level=M) for kind, cls in (("table", AdaptiveMesh), ("lazy", LazyAdaptiveMesh))}


def _level_arrays(n_faces):
    """Uniform coarse and fine, two random mixes (neighbours up to 5 levels apart), a smooth ramp."""
    rng = np.random.default_rng(11)
    ramp = np.minimum(np.arange(n_faces) * (M + 1) // n_faces, M)
    return [np.zeros(n_faces, np.int64), np.full(n_faces, M, np.int64),
            rng.integers(0, M + 1, n_faces), rng.integers(0, M + 1, n_faces), ramp]


def _frame(mesh: AdaptiveMeshBase, levels):
    """What a frame gives through the interface: triangle corners and normals (T, 3, 3), levels (T,), faces (T,)."""
    mesh.clear()                                   # a build from scratch: both kinds order triangles alike
    indices, tri_levels = mesh.update_indices(levels)
    corners = mesh.vertex_positions[indices].reshape(-1, 3, 3)
    normals = mesh.vertex_normals[indices].reshape(-1, 3, 3)
    return corners, normals, np.asarray(tri_levels), mesh.face_per_triangle()


def test_both_kinds_are_the_interface(meshes):
    for mesh in meshes.values():
        assert isinstance(mesh, AdaptiveMeshBase)
    with pytest.raises(TypeError):
        AdaptiveMeshBase(meshes["table"].base, None, 1, 0.25)        # abstract: no update_indices, clear, ...


@pytest.mark.parametrize("which", range(5))
def test_same_triangles_and_levels_through_the_interface(meshes, which):
    table, lazy = meshes["table"], meshes["lazy"]
    levels = _level_arrays(table.n_faces)[which]
    a, b = _frame(table, levels), _frame(lazy, levels)
    expected = table.triangle_count(levels)
    assert expected == lazy.triangle_count(levels) and len(a[2]) == len(b[2]) == expected
    for x, y, name in zip(a, b, ("corners", "normals", "levels", "faces")):
        np.testing.assert_array_equal(x, y, err_msg=name)
    # Each triangle carries its base face's level, and lies over that face (x, y within its corners' box).
    corners, _, tri_levels, faces = a
    np.testing.assert_array_equal(tri_levels, levels[faces])
    box = table.corners[faces][..., :2]
    assert np.all(corners[..., :2] >= box.min(axis=1)[:, None] - 1e-3)
    assert np.all(corners[..., :2] <= box.max(axis=1)[:, None] + 1e-3)
    # The soup is the table gathered by the indices, for both kinds.
    for mesh, frame in ((table, a), (lazy, b)):
        positions, normals, soup_levels = mesh.update(levels)
        np.testing.assert_array_equal(positions.reshape(-1, 3, 3), frame[0])
        np.testing.assert_array_equal(soup_levels, frame[2])


def test_per_face_data_and_contrast_agree(meshes):
    table, lazy = meshes["table"], meshes["lazy"]
    for name in ("centroids", "corners", "edge_length", "geometric_error", "z_range", "bounding_radius", "contrast",
                 "normal_filter_m"):
        np.testing.assert_array_equal(getattr(table, name), getattr(lazy, name), err_msg=name)
    light = (0.3, -0.4, 0.8)
    np.testing.assert_array_equal(table.shading_contrast(light, 0.1), lazy.shading_contrast(light, 0.1))
    assert not np.array_equal(table.shading_contrast(light, 0.1), table.contrast)   # the light matters


def test_a_share_builds_on_its_own(meshes):
    levels = _level_arrays(meshes["table"].n_faces)
    for mesh in meshes.values():
        mesh.clear()
        mine = [x.copy() for x in mesh.update_indices(levels[2])]
        other = mesh.share()
        assert other.kind == mesh.kind and other.stats == {} and len(other.last_rebuilt_faces) == 0
        theirs = other.update_indices(levels[3])
        assert len(theirs[1]) == mesh.triangle_count(levels[3]) != len(mine[1])
        again = mesh.update_indices(levels[2])                      # the original's frame is untouched
        for x, y in zip(mine, again):
            np.testing.assert_array_equal(x, y)


def test_capabilities(meshes):
    terrain = meshes["table"].terrain
    base = BaseMesh.grid(terrain, 3, 2)
    table, lazy = AdaptiveMesh(base, terrain, max_level=2), LazyAdaptiveMesh(base, terrain, max_level=2)
    assert (table.kind, table.has_full_table, table.full_fits) == ("table", True, True)
    assert (lazy.kind, lazy.has_full_table, lazy.full_fits) == ("lazy", False, True)
    deepest = LazyAdaptiveMesh(base, terrain, max_level=FULL_MAX_LEVEL + 1)
    assert not deepest.full_fits and LazyAdaptiveMesh(base, terrain, max_level=FULL_MAX_LEVEL).full_fits
    # has_full_table: the table's rows hold every vertex of the full mesh before any update; the lazy
    # mesh's table is empty until a frame, and then holds only that frame's rows.
    full = np.full(table.n_faces, 2)
    n_full_rows = len(np.unique(table.share().update_indices(full)[0]))
    assert len(table.vertex_positions) >= n_full_rows
    assert len(lazy.vertex_positions) == 0
    lazy.update_indices(np.zeros(lazy.n_faces, np.int64))
    assert len(lazy.vertex_positions) < n_full_rows


def test_export_takes_either_kind(meshes):
    levels = _level_arrays(meshes["table"].n_faces)[2]
    shapes = []
    for mesh in meshes.values():
        mesh.clear()
        tm = selected_mesh(mesh, levels)
        shapes.append(np.asarray(tm.vertices)[np.asarray(tm.faces)])
    np.testing.assert_array_equal(shapes[0], shapes[1])
