"""The one light of the terrain: what every image is drawn with and every contrast is computed for.

The CSF criteria need the contrast the viewer will see over a piece of
terrain; that contrast depends on the light. So the light the renderers draw
with (:mod:`headplod.render.gl`, :mod:`headplod.render.tessellate`,
:mod:`headplod.render.raymask`) and the light the contrast is computed for
(:mod:`headplod.plod.mesh`, :mod:`headplod.plod.patches`) are these two
values, defined here only.

Shading model (all back ends): shade = ambient + (1 - ambient) · max(n · l, 0),
times the height colour; ``n`` the unit surface normal and ``l`` the unit
vector toward the light, both in the scene frame (x east, y north, z up).
"""
from __future__ import annotations

import numpy as np

__all__ = ["LIGHT_DIR", "AMBIENT", "light_unit"]

#: Direction toward the light, scene frame (x east, y north, z up), not normalized: a sun from the
#: south-east, about 58° above the horizon.
LIGHT_DIR = (0.4, -0.3, 0.85)
#: Shade of a face turned away from the light, in [0, 1] (a face facing it gets 1).
AMBIENT = 0.25


def light_unit(light_dir=LIGHT_DIR) -> np.ndarray:
    """(3,) float64 unit vector toward the light; a clear error for a zero or non-finite vector."""
    light = np.asarray(light_dir, dtype=np.float64).reshape(-1)
    if light.shape != (3,) or not np.isfinite(light).all() or np.linalg.norm(light) == 0:
        raise ValueError(f"light_dir must be a non-zero 3-vector, got {light_dir!r}")
    return light / np.linalg.norm(light)
