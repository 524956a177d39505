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
from ..tol import tol

__all__ = ["LIGHT_DIR", "AMBIENT", "DISPLAY_GAMMA", "HEIGHT_COLOURS", "GLSL_HEIGHT_COLOURS", "light_unit", "shade",
           "height_colour", "michelson", "contrast_of_range"]

#: Direction toward the light, scene frame (x east, y north, z up), not normalized: a sun from the
#: south-east, about 58° above the horizon.
LIGHT_DIR = (0.4, -0.3, 0.85)
#: Shade of a face turned away from the light, in [0, 1] (a face facing it gets 1).
AMBIENT = 0.25
#: The terrain's colour by height (RGB in [0, 1]): grey-green valleys, a middle, pale grey peaks; a height's
#: fraction t of the terrain's range is coloured low → middle over t in [0, 0.5], middle → high over [0.5, 1].
HEIGHT_COLOURS = ((0.30, 0.42, 0.26), (0.52, 0.56, 0.40), (0.80, 0.80, 0.76))
#: The same colours as GLSL constants ``LOW``, ``MID``, ``HIGH``, for every terrain shader.
GLSL_HEIGHT_COLOURS = "\n".join(f"const vec3 {name} = vec3({r:.2f}, {g:.2f}, {b:.2f});"
                                 for name, (r, g, b) in zip(("LOW", "MID", "HIGH"), HEIGHT_COLOURS))
#: The display's transfer: a code value v in [0, 1] is shown at relative luminance v ** DISPLAY_GAMMA (the
#: renderers write the shade as 8-bit code values to an sRGB display, without linear-to-sRGB encoding).
DISPLAY_GAMMA = 2.2


def light_unit(light_dir=LIGHT_DIR) -> np.ndarray:
    """(3,) float64 unit vector toward the light; a clear error for a zero or non-finite vector."""
    light = np.asarray(light_dir, dtype=np.float64).reshape(-1)
    if light.shape != (3,) or not np.isfinite(light).all() or np.linalg.norm(light) == 0:
        raise ValueError(f"light_dir must be a non-zero 3-vector, got {light_dir!r}")
    return light / np.linalg.norm(light)


def shade(normals, light_dir=LIGHT_DIR, ambient: float = AMBIENT) -> np.ndarray:
    """The drawn shade (code value in [0, 1]) of unit ``normals`` (..., 3), scene frame: the renderers' rule."""
    normals = np.asarray(normals)
    light = light_unit(light_dir).astype(normals.dtype if normals.dtype == np.float32 else np.float64)
    return ambient + (1 - ambient) * np.maximum(normals @ light, 0)


def michelson(shades, axis=-1) -> np.ndarray:
    """Michelson contrast (Lmax - Lmin) / (Lmax + Lmin) of the luminance the display shows for ``shades``
    (code values), over ``axis``; float64.

    The CSF is a function of luminance contrast, so the code values are taken through the display's
    transfer (:data:`DISPLAY_GAMMA`) first: a shade ratio of 2 is a luminance ratio of about 4.6.
    """
    shades = np.asarray(shades)
    return contrast_of_range(shades.max(axis=axis), shades.min(axis=axis))


def contrast_of_range(brightest, darkest) -> np.ndarray:
    """Michelson contrast of the displayed luminance between the shades ``brightest`` and ``darkest``
    (code values, arrays of one shape); float64 (:func:`michelson`)."""
    hi = np.asarray(brightest, dtype=np.float64) ** DISPLAY_GAMMA
    lo = np.asarray(darkest, dtype=np.float64) ** DISPLAY_GAMMA
    return (hi - lo) / np.maximum(hi + lo, tol.zero)


def height_colour(t) -> np.ndarray:
    """RGB (..., 3) of height fractions ``t`` (...) in [0, 1] (:data:`HEIGHT_COLOURS`), in t's float type."""
    t = np.asarray(t)
    f = t.dtype.type if np.issubdtype(t.dtype, np.floating) else np.float64
    low, mid, high = (np.array(c, f) for c in HEIGHT_COLOURS)
    t = t[..., None]
    return np.where(t < 0.5, low + (mid - low) * (f(2) * t), mid + (high - mid) * (f(2) * t - f(1)))

