"""Offscreen rendering of the terrain demo with head-coupled perspective.

See :mod:`headplod.render.gl` for frames, units and the matrix convention
(column vectors, ``p_clip = proj @ view @ model @ [p, 1]``, uploaded to GL as
``M.T.tobytes()``).
"""
from .gl import __all__
from .gl import *
