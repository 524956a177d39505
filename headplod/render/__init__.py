"""Offscreen rendering of the terrain: the one PLOD frame step (condition, select, draw) and its back ends.

- :mod:`.context`: a headless OpenGL context (EGL).
- :mod:`.projection`: frames, units, the matrix convention (column vectors,
  ``p_clip = proj @ view @ model @ [p, 1]``, uploaded to GL as
  ``M.T.tobytes()``), the off-axis projection and the scene's placement.
- :mod:`.gl`: the terrain renderer (shaders, :class:`TerrainRenderer`).
- :mod:`.overlay`: the point of interest and its uncertainty ellipse.
- :mod:`.frame`: the one PLOD frame step (condition, select, draw) and its back ends' capability table.
- :mod:`.tessellate` (GLSL in :mod:`.tess_shaders`): the GPU tessellation back end; :mod:`.raymask`:
  Murphy & Duchowski's ray-mask renderer; :mod:`.foveate`: foveated resolution layers.
- :mod:`.still`: the terrain scene and ``headplod render``'s one frame; :mod:`.command`: ``headplod render``.
"""
from .context import EGL_PACKAGES, GLContextError, create_context
from .gl import PALETTE, VIEW_MODES, TerrainRenderer
from .overlay import overlay_poi
from .projection import SceneTransform, off_axis_projection, scene_to_world, screen_frame

__all__ = ["create_context", "GLContextError", "EGL_PACKAGES", "screen_frame", "off_axis_projection",
           "SceneTransform", "scene_to_world", "TerrainRenderer", "PALETTE", "VIEW_MODES", "overlay_poi"]
