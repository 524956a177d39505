"""Offscreen rendering of the terrain demo with head-coupled perspective.

See :mod:`headplod.render.gl` for frames, units and the matrix convention
(column vectors, ``p_clip = proj @ view @ model @ [p, 1]``, uploaded to GL as
``M.T.tobytes()``).
"""
from .gl import (
    PALETTE,
    VIEW_MODES,
    SceneTransform,
    TerrainRenderer,
    create_context,
    off_axis_projection,
    overlay_poi,
    scene_to_world,
    screen_frame,
)

__all__ = [
    "create_context",
    "screen_frame",
    "off_axis_projection",
    "SceneTransform",
    "scene_to_world",
    "TerrainRenderer",
    "overlay_poi",
    "PALETTE",
    "VIEW_MODES",
]
