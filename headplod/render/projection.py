"""Head-coupled (off-axis) projection onto the physical screen, and the scene's placement behind it.

Frames and units
----------------
- world: the left camera frame (OpenCV: x right, y down, z forward), mm —
  the frame of ``screen.yaml`` and of the head position (docs/contract.md).
- screen-eye frame ("eye"): origin at the eye, x along
  ``top_left → top_right`` (right), y up (``bottom_left → top_left``, made
  orthogonal to x), z = x × y toward the viewer, mm. The screen plane is
  ``z = −d`` with d the eye's distance to the plane. This is the view space.
- scene: the virtual terrain, any unit (e.g. m), x east, y north, z up.
- clip / NDC: OpenGL's, NDC x right, y up, z ∈ [−1, 1] from near to far.
  Screen pixel (x, y) (``Screen.pixel_to_world`` convention: (0, 0) at the
  top-left corner of the visible area, (W, H) at the bottom-right one) is
  NDC ``(2x/W − 1, 1 − 2y/H)``.

Matrix convention
-----------------
Column vectors, ``p_clip = proj @ view @ model @ [p_scene, 1]``, so that
``model`` is ``T_world_scene`` (scene units → world mm), ``view`` is
``T_eye_world`` and ``proj`` is ``T_clip_eye``. All 4x4 matrices are numpy
arrays in row-major *memory* with the usual maths indexing ``M[row, col]``.
OpenGL (and moderngl's uniform ``write``) expects column-major bytes, so a
matrix is uploaded as ``prog['u_mvp'].write(M.T.astype('f4').tobytes())``.
:class:`TerrainRenderer` does this itself: it multiplies
``proj @ view @ model`` in float64 on the CPU and uploads one float32 MVP.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..io import Screen
from ..tol import tol

# --------------------------------------------------------------------------
# head-coupled (off-axis) projection
# --------------------------------------------------------------------------



def screen_to_image_px(points_px, screen_size_px, image_size_px, *, pixel_index: bool = False) -> np.ndarray:
    """Screen px → image px: the one mapping between the two (every back end, the demo, the benches).

    Convention: both are continuous pixel coordinates with (0, 0) at the top-left *corner* of the top-left
    pixel and (W, H) at the bottom-right corner (``Screen.pixel_to_world``'s), so the centre of pixel
    (column i, row j) is (i + 0.5, j + 0.5) and the mapping is a pure scale: x_image = x_screen * W_image /
    W_screen (the image shows the whole screen). ``pixel_index``: return pixel-index coordinates instead,
    the centre of pixel (i, j) at (i, j) (half a pixel less; what image metrics such as FovVideoVDP take).

    Parameters
    ----------
    points_px : (..., 2) float
        (x, y) screen px.
    screen_size_px, image_size_px : (2,)
        (width, height) of the screen and of the image, px.

    Returns
    -------
    (..., 2) float64 image px.
    """
    image = np.asarray(points_px, dtype=np.float64) * np.asarray(image_size_px, dtype=np.float64) \
        / np.asarray(screen_size_px, dtype=np.float64)
    return image - 0.5 if pixel_index else image


def screen_frame(screen: Screen) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal frame of the screen, world frame.

    Parameters
    ----------
    screen : Screen
        Corners in the world frame, mm.

    Returns
    -------
    right, up, toward_viewer : ndarray, shape (3,)
        Unit vectors (world frame): ``right`` along ``top_right − top_left``;
        ``up`` along ``top_left − bottom_left`` made orthogonal to ``right``
        (they are equal for a rectangular screen); ``toward_viewer`` =
        ``right × up`` = ``−screen.normal``, pointing from the screen to the
        side it is seen from.
    center_mm : ndarray, shape (3,)
        Centre of the visible area, world frame, mm.
    """
    a = screen.top_right - screen.top_left
    b = screen.bottom_left - screen.top_left
    right = a / np.linalg.norm(a)
    up = -b - np.dot(-b, right) * right
    up /= np.linalg.norm(up)
    toward = np.cross(right, up)
    center = screen.top_left + 0.5 * a + 0.5 * b
    return right, up, toward, center


def off_axis_projection(eye_mm: Any, screen: Screen, near_mm: float,
                        far_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """View and projection matrices of a head-coupled perspective.

    Kooima's generalized perspective projection: the screen's visible area is
    the image plane and the frustum's apex is the eye, so that a point on the
    screen is drawn where it is, whatever the eye position, and points behind
    (or in front of) the screen show the parallax of a real window.

    Parameters
    ----------
    eye_mm : array_like, shape (3,)
        Eye position (the centre of projection), world frame, mm. Must be on
        the viewer's side of the screen plane (``right × up`` side, i.e.
        opposite to ``screen.normal``).
    screen : Screen
        The display; its corners (world frame, mm) span the image.
    near_mm, far_mm : float
        Near and far clip planes, mm, as distances from the eye along the
        screen's normal (the planes are parallel to the screen);
        ``0 < near_mm < far_mm``. To see geometry popping out of the screen,
        take ``near_mm`` below the eye–screen distance.

    Returns
    -------
    view : ndarray, shape (4, 4), float32
        ``T_eye_world``: world (mm) → screen-eye frame (origin at the eye, x
        right along the screen's top edge, y up, z toward the viewer, mm).
        A rotation and a translation.
    proj : ndarray, shape (4, 4), float32
        ``T_clip_eye``: the asymmetric frustum through the screen's edges,
        OpenGL clip space (NDC z = −1 at ``near_mm``, +1 at ``far_mm``).
        A world point on the screen at pixel (x, y) lands on NDC
        ``(2x/W − 1, 1 − 2y/H)``. For a parallelogram (non-rectangular)
        screen the x row carries the shear that keeps this exact.

    Raises
    ------
    headplod.io.ViewError
        On an eye on or behind the screen plane
        (:meth:`headplod.io.Screen.check_eye`).
    ValueError
        On a non-finite or wrongly shaped eye, or bad clip distances.

    Notes
    -----
    Column vectors: ``p_clip = proj @ view @ [p_world, 1]``. Upload to GLSL
    as column-major bytes, ``M.T.tobytes()`` (see the module docstring).
    Matrices are computed in float64 and rounded to float32 on return.
    """
    eye = np.asarray(eye_mm, dtype=np.float64).reshape(-1)
    if eye.shape != (3,) or not np.isfinite(eye).all():
        raise ValueError(f"off_axis_projection: eye_mm must be 3 finite numbers (mm), got {eye_mm!r}")
    screen.check_eye(eye)                       # the screen's rule: ViewError on or behind its plane
    n, f = float(near_mm), float(far_mm)
    if not (math.isfinite(n) and math.isfinite(f) and 0.0 < n < f):
        raise ValueError(f"off_axis_projection: need 0 < near_mm < far_mm, got near={near_mm}, far={far_mm}")
    right, up, toward, _ = screen_frame(screen)
    R_eye_world = np.stack([right, up, toward])  # rows: the eye frame's axes in world
    tl = R_eye_world @ (screen.top_left - eye)          # (x0, y0, -d)
    a = R_eye_world @ (screen.top_right - screen.top_left)  # (ax, 0, 0)
    b = R_eye_world @ (screen.bottom_left - screen.top_left)  # (bx, by, 0)
    d = -tl[2]
    x0, y0 = tl[0], tl[1]
    ax, bx, by = a[0], b[0], b[1]
    # On the screen plane z = -d, a view-space point q projects to p = d q / (-q_z);
    # x_ndc = 2u/W - 1 and y_ndc = 1 - 2v/H are affine in p (solve p = tl + u/W a + v/H b).
    cx = -2.0 * x0 / ax + 2.0 * bx * y0 / (ax * by) - 1.0
    cy = 2.0 * y0 / by + 1.0
    proj = np.array([
        [2.0 * d / ax, -2.0 * d * bx / (ax * by), -cx, 0.0],
        [0.0, -2.0 * d / by, -cy, 0.0],
        [0.0, 0.0, -(f + n) / (f - n), -2.0 * f * n / (f - n)],
        [0.0, 0.0, -1.0, 0.0],
    ])
    view = np.eye(4)
    view[:3, :3] = R_eye_world
    view[:3, 3] = -R_eye_world @ eye
    return view.astype(np.float32), proj.astype(np.float32)


# --------------------------------------------------------------------------
# scene placement
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SceneTransform:
    """Placement of the virtual scene in the world: ``T_world_scene``.

    Parameters
    ----------
    matrix : array_like, shape (4, 4)
        Homogeneous affine map, column vectors: ``[p_world_mm, 1] = matrix @
        [p_scene, 1]``; last row ``[0, 0, 0, 1]``. Stored as float64.

    Notes
    -----
    ``np.asarray(transform)`` gives the matrix, so a SceneTransform can be
    passed wherever a (4, 4) ``model`` matrix is expected.
    """

    matrix: np.ndarray

    def __post_init__(self) -> None:
        m = np.array(self.matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"SceneTransform: matrix has shape {m.shape}, expected (4, 4)")
        if not np.isfinite(m).all():
            raise ValueError("SceneTransform: matrix has NaN or inf")
        if not np.allclose(m[3], [0, 0, 0, 1], atol=tol.zero):
            raise ValueError(f"SceneTransform: last row is {m[3].tolist()}, expected [0, 0, 0, 1] (affine)")
        if abs(np.linalg.det(m[:3, :3])) < 1e-300:
            raise ValueError("SceneTransform: the linear part is singular")
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)

    @classmethod
    def identity(cls) -> "SceneTransform":
        """Scene = world (scene units are mm in the world frame)."""
        return cls(np.eye(4))

    def apply(self, points_scene: Any) -> np.ndarray:
        """World positions (mm) of scene points.

        Parameters
        ----------
        points_scene : array_like, shape (..., 3)
            Scene frame, scene units.

        Returns
        -------
        ndarray, shape (..., 3)
            World frame, mm.
        """
        p = np.asarray(points_scene, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ValueError(f"SceneTransform.apply needs shape (..., 3), got {p.shape}")
        return p @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def inverse(self) -> "SceneTransform":
        """``T_scene_world``."""
        return SceneTransform(np.linalg.inv(self.matrix))

    def __matmul__(self, other: "SceneTransform") -> "SceneTransform":
        return SceneTransform(self.matrix @ np.asarray(other, dtype=np.float64))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self.matrix.astype(dtype) if dtype is not None else self.matrix.copy()


@functools.lru_cache(maxsize=1)
def _frame_width_mm() -> float:
    from calib import DEFAULT_SCREEN

    from ..io import read_screen

    return screen_width_mm(read_screen(DEFAULT_SCREEN))


def screen_width_mm(screen: Screen) -> float:
    """The visible area's width, mm (top-left to top-right corner)."""
    return float(np.linalg.norm(np.asarray(screen.top_right, dtype=np.float64) - np.asarray(screen.top_left)))


def screen_fit(screen: Screen) -> float:
    """Factor on a scene's scale that fills ``screen`` as the embedded screen (``calib/screen.yaml``, for which
    the scenes were framed) is filled: its width over the embedded screen's; 1 for that screen. A 32:9 screen
    then shows the terrain across its width, not on its middle third between sky."""
    return screen_width_mm(screen) / _frame_width_mm()


def scene_to_world(scale_mm_per_unit: float, center_scene: Any, screen: Screen,
                   depth_mm: float = 0.0, pitch_deg: float = 0.0) -> SceneTransform:
    """Place the terrain behind (or through) the screen.

    Parameters
    ----------
    scale_mm_per_unit : float
        World mm per scene unit (> 0), e.g. 0.1 shows 1 m of terrain as
        0.1 mm.
    center_scene : array_like, shape (3,)
        Scene point (scene units) that lands at the screen centre.
    screen : Screen
        The display (world frame, mm).
    depth_mm : float
        How far behind the screen plane ``center_scene`` lands, mm (away
        from the viewer; negative = in front of the screen). 0 puts it on the
        screen plane, the zero-parallax point that stays still as the head
        moves.
    pitch_deg : float
        Tilt about the screen's right axis, degrees. 0: the terrain's up (z)
        is the screen's up and north (y) points into the screen (a window
        onto the landscape). 90: up points at the viewer and north along
        the screen's up (a map on the screen). In between, the viewer looks
        down onto the terrain.

    Returns
    -------
    SceneTransform
        ``T_world_scene``: a rotation times ``scale_mm_per_unit`` plus a
        translation. Scene x (east) maps to the screen's right.
    """
    s = float(scale_mm_per_unit)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"scene_to_world: scale_mm_per_unit must be > 0, got {scale_mm_per_unit!r}")
    c = np.asarray(center_scene, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ValueError(f"scene_to_world: center_scene must be 3 finite numbers, got {center_scene!r}")
    if not (math.isfinite(depth_mm) and math.isfinite(pitch_deg)):
        raise ValueError("scene_to_world: depth_mm and pitch_deg must be finite")
    right, up, toward, center = screen_frame(screen)
    p = math.radians(pitch_deg)
    up_s = math.cos(p) * up + math.sin(p) * toward        # scene z
    north_s = -math.cos(p) * toward + math.sin(p) * up    # scene y
    R_world_scene = np.column_stack([right, north_s, up_s])
    origin = center - float(depth_mm) * toward
    m = np.eye(4)
    m[:3, :3] = s * R_world_scene
    m[:3, 3] = origin - s * R_world_scene @ c
    return SceneTransform(m)
