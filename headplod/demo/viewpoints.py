"""The paper's three test views of the terrain, as named placements of the scene behind the screen.

Martinez et al. evaluated PLOD on three views of their terrain: a far
overview, a close view of the mountains from the left, and plains in front of
mountains. Here a viewpoint is only a model matrix ``T_world_scene`` (scene m
→ world mm): the head-coupled camera is the viewer's eye, so "where the
camera is" is where the terrain sits behind the screen window. The terrain
and its mesh are built once; a viewpoint is ``dataclasses.replace(scene,
model=...)``.

The Jacksboro DEM (scene x east, y north, z up, metres; extent 30.0 km x
31.7 km) has its ridges in the west and south-west (up to 1076 m) and
plains in the east (250-400 m), with the fault valley between them.
Another terrain (``--terrain FILE``) gets the same three placements, their
scales multiplied by the scene's ``fit`` (:func:`headplod.render.still.fit_scale`)
so that it is framed alike whatever its size; the names then only describe
the built-in one.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..render import scene_to_world
from ..render.projection import screen_fit


@dataclass(frozen=True)
class Viewpoint:
    """A placement of the terrain behind the screen.

    Attributes
    ----------
    name : str
    description : str
    centre_frac : (2,) float
        Terrain point (fraction of the extent, east and north, 0..1) that
        lands ``depth_mm`` behind the screen centre.
    scale_mm_per_m : float
        World mm per terrain metre (larger: closer).
    depth_mm : float
        How far behind the screen plane the centre point lies, mm.
    pitch_deg : float
        Tilt of the terrain (0: seen edge-on like a window onto the
        landscape, 90: a map on the screen).
    yaw_deg : float
        Rotation of the terrain about its up axis at the centre point before
        placing it, degrees counter-clockwise seen from above; 0 puts north
        into the screen, -90 west, +90 east.
    """

    name: str
    description: str
    centre_frac: tuple[float, float]
    scale_mm_per_m: float
    depth_mm: float
    pitch_deg: float
    yaw_deg: float = 0.0

    def model(self, terrain, screen, fit: float = 1.0) -> np.ndarray:
        """``T_world_scene``, (4, 4) float64: terrain metres → world mm, for ``screen``; ``fit`` scales
        ``scale_mm_per_m`` for a terrain of another size (``TerrainScene.fit``; 1 for the built-in), and
        :func:`headplod.render.projection.screen_fit` for a screen of another width."""
        x0, x1, y0, y1 = terrain.extent
        fx, fy = self.centre_frac
        cx, cy = x0 + fx * (x1 - x0), y0 + fy * (y1 - y0)
        centre = np.array([cx, cy, float(np.median(terrain.dem_z_m))])
        placed = np.asarray(scene_to_world(self.scale_mm_per_m * fit * screen_fit(screen), centre, screen, depth_mm=self.depth_mm,
                                           pitch_deg=self.pitch_deg).matrix, dtype=np.float64)
        # Yaw about the vertical through the centre point, in scene coordinates.
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        yaw = np.eye(4)
        yaw[:2, :2] = [[c, -s], [s, c]]
        yaw[:3, 3] = centre - yaw[:3, :3] @ centre
        return placed @ yaw


#: The three views, in the paper's order.
VIEWPOINTS: dict[str, Viewpoint] = {v.name: v for v in (
    # Large enough that the terrain fills the screen's middle, where the POI goes: a POI off the terrain has
    # nothing to refine, and its picture shows no fine level at all.
    Viewpoint("overview", "far overview of the terrain's middle, seen from above, filling the screen",
              centre_frac=(0.5, 0.5), scale_mm_per_m=0.03, depth_mm=320.0, pitch_deg=60.0),
    Viewpoint("mountains", "close view of the western ridges from the left (looking east)",
              centre_frac=(0.30, 0.30), scale_mm_per_m=0.055, depth_mm=350.0, pitch_deg=30.0, yaw_deg=90.0),
    Viewpoint("plains", "the eastern plains in front, the ridges behind (looking west)",
              centre_frac=(0.70, 0.40), scale_mm_per_m=0.05, depth_mm=450.0, pitch_deg=22.0, yaw_deg=-90.0),
)}


def viewpoint_names() -> list[str]:
    return list(VIEWPOINTS)


def get_viewpoint(name: str) -> Viewpoint:
    """The named viewpoint; ValueError listing the names for an unknown one."""
    try:
        return VIEWPOINTS[name]
    except KeyError:
        raise ValueError(f"unknown viewpoint {name!r}; choose one of {', '.join(VIEWPOINTS)}") from None


def place(scene, viewpoint: Viewpoint | str):
    """The TerrainScene with its model matrix set for ``viewpoint`` (the terrain and mesh are shared)."""
    vp = get_viewpoint(viewpoint) if isinstance(viewpoint, str) else viewpoint
    return dataclasses.replace(scene, model=vp.model(scene.terrain, scene.screen, getattr(scene, "fit", 1.0)))


def terrain_under(model: np.ndarray, terrain, screen, eye_mm, xy_px) -> np.ndarray | None:
    """Where the line of sight from ``eye_mm`` ((3,) world mm) through screen pixel ``xy_px`` ((2,) screen px)
    meets the terrain placed by ``model`` ((4, 4) scene m → world mm): (2,) scene metres (east, north) on the
    plane of the terrain's median height, or None when it misses the terrain's extent (sky, or off its edge).
    The relief is left out: a picture's POI is judged on the terrain's plane."""
    eye = np.asarray(eye_mm, dtype=np.float64)
    to_scene = np.linalg.inv(np.asarray(model, dtype=np.float64))
    a = to_scene @ np.append(eye, 1.0)
    b = to_scene @ np.append(screen.pixel_to_world(np.asarray(xy_px, dtype=np.float64)), 1.0)
    a, b = a[:3] / a[3], b[:3] / b[3]
    z = float(np.median(terrain.dem_z_m))
    if abs(b[2] - a[2]) < 1e-12:
        return None
    t = (z - a[2]) / (b[2] - a[2])
    if t <= 0:                                  # the plane lies behind the eye: sky
        return None
    hit = a + t * (b - a)
    x0, x1, y0, y1 = terrain.extent
    return hit[:2] if x0 <= hit[0] <= x1 and y0 <= hit[1] <= y1 else None
