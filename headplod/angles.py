"""The angle between two directions, one way for the whole package.

``atan2(|u × v|, u · v)`` is accurate at every angle: ``acos`` of a dot
product loses half the digits near 0° and 180°, where the eye's small
eccentricities and a head's small turns between frames live, and needs its
argument clipped; the atan2 form needs neither unit vectors nor a clip.
"""
from __future__ import annotations

import numpy as np

__all__ = ["angle_between_deg"]


def angle_between_deg(u, v):
    """Angle between vectors ``u`` and ``v`` along the last axis, deg in [0, 180].

    Parameters
    ----------
    u, v : (..., 3) array_like
        Directions in one frame, any length (not necessarily unit); broadcast against each other.

    Returns
    -------
    (...) ndarray of float64 (a 0-d array for two single vectors; ``float()`` it for a scalar).
    A zero vector gives 0.
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1)))
