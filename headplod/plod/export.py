"""The selected PLOD mesh as a file any mesh viewer opens (``headplod render --export``), through trimesh.

Formats by the file's ending: ``.glb`` (binary glTF), ``.ply``, ``.obj``,
``.stl``. The mesh is the one the frame drew: the vertices its triangles
use (scene units: metres, x east, y north, z up, as
:class:`headplod.plod.terrain.Terrain`), one face per triangle, each face
coloured by its level (:data:`headplod.plod.mesh_base.LEVEL_PALETTE`, as the
renderer's "levels" view) where the format keeps face colours (PLY, glTF,
OBJ with its material; STL has none).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import io
from .mesh_base import LEVEL_PALETTE, AdaptiveMeshBase

#: File endings :func:`export_mesh` writes (trimesh's exporters).
EXPORT_FORMATS = (".glb", ".ply", ".obj", ".stl")


def check_export_path(path) -> Path:
    """``path`` as a Path, or ValueError with a one-line reason (ending, folder) before any work is done."""
    path = Path(path)
    if path.suffix.lower() not in EXPORT_FORMATS:
        raise ValueError(f"{path}: the mesh format comes from the ending, one of {', '.join(EXPORT_FORMATS)}")
    if path.is_dir():
        raise ValueError(f"{path} is a folder; give a file name ending in {', '.join(EXPORT_FORMATS)}")
    if not path.parent.is_dir():
        raise ValueError(f"{path}: folder {path.parent} does not exist")
    return path


def selected_mesh(mesh: AdaptiveMeshBase, levels):
    """The triangles of per-face ``levels`` (F,) as a ``trimesh.Trimesh`` (only the vertices they use), faces
    coloured by level.

    ``mesh`` is either kind (:class:`headplod.plod.mesh_base.AdaptiveMeshBase`):
    the indices address the table ``update_indices`` leaves in
    ``vertex_positions`` (scene units, float32, widened to float64 here).
    """
    import trimesh   # on use: it takes a third of a second to import, which every command would pay

    indices, tri_levels = mesh.update_indices(levels)
    used, faces = np.unique(np.asarray(indices, dtype=np.int64), return_inverse=True)
    colours = np.empty((len(tri_levels), 4), np.uint8)
    colours[:, :3] = LEVEL_PALETTE[np.asarray(tri_levels) % len(LEVEL_PALETTE)]
    colours[:, 3] = 255
    return trimesh.Trimesh(vertices=np.asarray(mesh.vertex_positions, np.float64)[used],
                           faces=faces.reshape(-1, 3), face_colors=colours, process=False)


def export_mesh(mesh: AdaptiveMeshBase, levels, path) -> Path:
    """Write the mesh of ``levels`` to ``path`` (format by its ending), whole or not at all.

    Written under a temporary name in the same folder and renamed, so an
    interrupted or failed export leaves no partial file.
    """
    path = check_export_path(path)
    tm = selected_mesh(mesh, levels)
    io.write_atomically(path, lambda name: tm.export(name, file_type=path.suffix.lower().lstrip(".")),
                        suffix=path.suffix)
    return path
