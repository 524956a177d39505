"""Offscreen rendering of the terrain demo with head-coupled perspective.

See :mod:`headplod.render.gl` for frames, units and the matrix convention
(column vectors, ``p_clip = proj @ view @ model @ [p, 1]``, uploaded to GL as
``M.T.tobytes()``).
"""
from .gl import __all__  # noqa: F401  (one list of the public names, in gl.py)
from .gl import *  # noqa: F401,F403
