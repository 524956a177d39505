"""Moved to :mod:`headplod.render.still` (it renders with GL; ``headplod.plod`` is pure numpy).

An alias until ``headplod/cli.py`` and the tests import from the new home;
nothing else in ``headplod`` may import it (``tests/test_layout.py``).
"""
from ..render.still import DEPTH_MM, PITCH_DEG, SCALE_MM_PER_M, TerrainScene, default_head, render_still

__all__ = ["TerrainScene", "default_head", "render_still", "SCALE_MM_PER_M", "DEPTH_MM", "PITCH_DEG"]
