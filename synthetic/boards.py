"""Synthetic stereo views of a planar calibration board (chessboard, ChArUco).

Independent of ``headplod`` (never imports it): the calibration tests compare
what ``headplod.calibration.calibrate`` recovers against the rig these images were made
with.

Board frame B
-------------
Origin at the top-left outer corner of the pattern (the top-left corner of
its first square, as in ``cv2.aruco.CharucoBoard.getChessboardCorners``), x
along the columns, y along the rows (down the printed page), z into the
board (away from a viewer who reads the print), mm.  Inner corner (row i,
column j) is at ``((j + 1) s, (i + 1) s, 0)`` for square size s.  The pattern
has ``cols + 1`` x ``rows + 1`` squares, the top-left one black, and a white
margin of ``margin_mm`` around it (the quiet zone detectors need).

Image formation
---------------
For every sub-pixel sample (``supersample`` x ``supersample`` per pixel) the
pixel is mapped back through the full OpenCV camera model (undistortion of a
2-px grid of points with ``cv2.undistortPoints``, tight criteria, then
bilinear interpolation in float64: error < 0.002 px for the default rig) to a
ray, the ray is intersected with the board plane, and the board texture is
sampled there with ``cv2.remap`` (bilinear; texture at ≥ 4 texels per mm).
The samples are averaged over each pixel (anti-aliasing), composited over a
smooth background, blurred with a Gaussian PSF, given Gaussian noise and
rounded to 8 bits.

Poses
-----
:func:`pick_board_poses` draws varied, plausible poses for a seed: each board
is fully visible (with its margin) in both cameras, faces both cameras
within ``max_view_angle_deg``, is tilted by up to ±35° about its own x and y
axes from the pose that faces the middle of the two cameras, fills 20-60 %
of the image (the larger of its bounding box's width and height fractions)
in both views, and the poses take turns at touching each ninth of each
camera's image (corners first).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from .conventions import rot_x, rot_y, rot_z, write_image, write_rig
from .render import CameraModel, project_points, rig_cameras

__all__ = [
    "Board",
    "BoardRenderOptions",
    "board_texture",
    "render_board_view",
    "render_board_pair",
    "pick_board_poses",
    "write_calibration_set",
    "CalibrationSet",
    "BAD_KINDS",
]

#: Kinds of deliberately bad pairs :func:`write_calibration_set` can add.
#: ``cut_off``: the board sticks out of the right image; ``blurred``: the
#: right image is heavily defocused; ``mismatched``: the right image is of
#: another board pose (an unsynchronised pair); ``wrong_size``: the right
#: image has half the resolution.
BAD_KINDS = ("cut_off", "blurred", "mismatched", "wrong_size")

_UNDIST_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-14)
#: Spacing (px) of the grid undistorted exactly; finer samples interpolate.
_RAY_GRID_PX = 2


# ----------------------------------------------------------------------------
# board and texture
# ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Board:
    """A printed calibration board.

    Attributes
    ----------
    kind : 'chessboard' or 'charuco'.
    cols, rows : inner corners per row and per column (the pattern has
        ``cols + 1`` x ``rows + 1`` squares).
    square_mm : side of a square, mm.
    marker_mm : ArUco marker side (ChArUco only; default 0.7 square).
    dictionary : cv2.aruco predefined dictionary name (ChArUco only).
    margin_mm : white quiet zone around the pattern (default one square).
    """

    kind: str = "chessboard"
    cols: int = 9
    rows: int = 6
    square_mm: float = 25.0
    marker_mm: Optional[float] = None
    dictionary: str = "DICT_5X5_100"
    margin_mm: Optional[float] = None

    def __post_init__(self):
        if self.kind not in ("chessboard", "charuco"):
            raise ValueError(f"Board.kind is {self.kind!r}, expected 'chessboard' or 'charuco'")
        if int(self.cols) < 2 or int(self.rows) < 2:
            raise ValueError(f"Board needs at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if not self.square_mm > 0:
            raise ValueError(f"Board.square_mm is {self.square_mm}, expected > 0")

    @property
    def margin(self) -> float:
        """White margin around the pattern, mm."""
        return float(self.square_mm if self.margin_mm is None else self.margin_mm)

    @property
    def marker(self) -> float:
        """ArUco marker side, mm."""
        return float(0.7 * self.square_mm if self.marker_mm is None else self.marker_mm)

    @property
    def pattern_size_mm(self) -> Tuple[float, float]:
        """(width, height) of the squares' area, mm."""
        return ((self.cols + 1) * self.square_mm, (self.rows + 1) * self.square_mm)

    def inner_corners_mm(self) -> np.ndarray:
        """(cols*rows, 3) inner corners in B, row by row, mm."""
        j, i = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        xy = np.stack([(j.ravel() + 1), (i.ravel() + 1)], axis=1) * self.square_mm
        return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float64)

    def outline_mm(self, with_margin: bool = True, per_side: int = 8) -> np.ndarray:
        """(4 * per_side, 3) points along the board's outline in B, mm."""
        m = self.margin if with_margin else 0.0
        w, h = self.pattern_size_mm
        x0, y0, x1, y1 = -m, -m, w + m, h + m
        t = np.linspace(0.0, 1.0, per_side, endpoint=False)
        sides = [
            np.column_stack([x0 + (x1 - x0) * t, np.full_like(t, y0)]),
            np.column_stack([np.full_like(t, x1), y0 + (y1 - y0) * t]),
            np.column_stack([x1 - (x1 - x0) * t, np.full_like(t, y1)]),
            np.column_stack([np.full_like(t, x0), y1 - (y1 - y0) * t]),
        ]
        xy = np.concatenate(sides)
        return np.column_stack([xy, np.zeros(len(xy))])

    def aruco_board(self):
        """The ``cv2.aruco.CharucoBoard`` of a ChArUco board (lengths in mm)."""
        if self.kind != "charuco":
            raise ValueError("aruco_board() is only for kind='charuco'")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols + 1, self.rows + 1), float(self.square_mm),
                                      float(self.marker), dictionary)


#: Gray levels (DN before the camera gain) of the print.
_BLACK_DN = 30.0
_WHITE_DN = 215.0


@functools.lru_cache(maxsize=8)
def board_texture(board: Board, texels_per_mm: float = 4.0) -> Tuple[np.ndarray, float]:
    """The board's print as a float32 image covering the pattern and margin.

    Texel (r, c) covers B's ``x in [c/ppm - margin, (c+1)/ppm - margin)`` and
    likewise for y, so B's point (x, y) is at texture coordinates
    ``((x + margin) ppm - 1/2, (y + margin) ppm - 1/2)``.

    Returns
    -------
    (texture (H, W) float32 DN, ppm) with ``ppm`` the texels per mm actually
    used (rounded so that a square is a whole number of texels).
    """
    sq_tex = max(8, int(round(board.square_mm * texels_per_mm)))
    ppm = sq_tex / board.square_mm
    m_tex = int(round(board.margin * ppm))
    pw, ph = (board.cols + 1) * sq_tex, (board.rows + 1) * sq_tex
    if board.kind == "chessboard":
        j = np.arange(pw) // sq_tex
        i = np.arange(ph) // sq_tex
        pattern = np.where(((i[:, None] + j[None, :]) % 2) == 0, 0.0, 1.0)
    else:
        img = board.aruco_board().generateImage((pw, ph), marginSize=0, borderBits=1)
        pattern = img.astype(np.float64) / 255.0
    tex = np.ones((ph + 2 * m_tex, pw + 2 * m_tex), np.float64)
    tex[m_tex:m_tex + ph, m_tex:m_tex + pw] = pattern
    tex = (_BLACK_DN + (_WHITE_DN - _BLACK_DN) * tex).astype(np.float32)
    tex.setflags(write=False)
    # the texture's origin is at -m_tex/ppm mm (the margin rounded to whole texels)
    return tex, ppm


def _texture_origin_mm(board: Board, ppm: float) -> float:
    """B coordinate (mm) of the texture's left/top edge (−margin, rounded to texels)."""
    return -round(board.margin * ppm) / ppm


# ----------------------------------------------------------------------------
# rays
# ----------------------------------------------------------------------------

@functools.lru_cache(maxsize=6)
def _ray_grid_cached(K: tuple, D: tuple, size: tuple, S: int) -> np.ndarray:
    w, h = size
    g = _RAY_GRID_PX
    nx = int(np.ceil(w / g)) + 1
    ny = int(np.ceil(h / g)) + 1
    gu = -0.5 + g * np.arange(nx)
    gv = -0.5 + g * np.arange(ny)
    uu, vv = np.meshgrid(gu, gv)
    pts = np.stack([uu, vv], axis=-1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, np.array(K).reshape(3, 3), np.array(D), R=np.eye(3), P=np.eye(3),
                              criteria=_UNDIST_CRITERIA).reshape(ny, nx, 2)
    # sub-pixel sample centres, px
    u = (np.arange(w * S) + 0.5) / S - 0.5
    v = (np.arange(h * S) + 0.5) / S - 0.5
    fu = (u + 0.5) / g
    fv = (v + 0.5) / g
    iu = np.minimum(np.floor(fu).astype(int), nx - 2)
    iv = np.minimum(np.floor(fv).astype(int), ny - 2)
    au = (fu - iu)[None, :, None]
    av = (fv - iv)[:, None, None]
    a00 = und[iv][:, iu]
    a01 = und[iv][:, iu + 1]
    a10 = und[iv + 1][:, iu]
    a11 = und[iv + 1][:, iu + 1]
    out = (1 - av) * ((1 - au) * a00 + au * a01) + av * ((1 - au) * a10 + au * a11)
    x = np.ascontiguousarray(out[..., 0], dtype=np.float32)
    y = np.ascontiguousarray(out[..., 1], dtype=np.float32)
    x.setflags(write=False)
    y.setflags(write=False)
    return x, y  # (h*S, w*S) each: normalized undistorted coordinates, z = 1


@functools.lru_cache(maxsize=8)
def _with_alpha(board: Board, texels_per_mm: float) -> np.ndarray:
    tex, _ = board_texture(board, texels_per_mm)
    return np.ascontiguousarray(np.dstack([tex, np.ones_like(tex)]))


def _ray_grid(cam: CameraModel, S: int) -> Tuple[np.ndarray, np.ndarray]:
    return _ray_grid_cached(tuple(np.asarray(cam.K, float).ravel()), tuple(np.asarray(cam.D, float).ravel()),
                            tuple(int(v) for v in cam.size), int(S))


# ----------------------------------------------------------------------------
# rendering
# ----------------------------------------------------------------------------

@dataclass(frozen=True)
class BoardRenderOptions:
    """Image formation options.

    Attributes
    ----------
    supersample : samples per pixel along each axis (anti-aliasing).
    texels_per_mm : resolution of the board texture.
    blur_sigma_px : Gaussian PSF sigma, px.
    noise_dn : Gaussian noise sigma, DN.
    gain : (min, max) random exposure gain per image.
    background_dn : (min, max) level of the smooth random background, DN.
    """

    supersample: int = 3
    texels_per_mm: float = 4.0
    blur_sigma_px: float = 0.7
    noise_dn: float = 1.5
    gain: Tuple[float, float] = (0.85, 1.1)
    background_dn: Tuple[float, float] = (50.0, 150.0)

    def replace(self, **kw) -> "BoardRenderOptions":
        from dataclasses import replace
        return replace(self, **kw)


def _background(size: Tuple[int, int], rng: np.random.Generator, lo: float, hi: float) -> np.ndarray:
    w, h = size
    coarse = rng.uniform(lo, hi, size=(4, 5)).astype(np.float32)
    return cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)


def render_board_view(cam: CameraModel, board: Board, R_world_board: np.ndarray, t_world_board_mm: np.ndarray,
                      options: Optional[BoardRenderOptions] = None,
                      rng: Optional[np.random.Generator] = None) -> np.ndarray:
    """One 8-bit gray image of the board seen by one camera.

    Parameters
    ----------
    cam : the camera (``X_cam = cam.R @ X_world + cam.t``).
    board : the board.
    R_world_board : (3, 3) rotation, B to world.
    t_world_board_mm : (3,) B's origin in the world, mm
        (``X_world = R_world_board @ X_B + t_world_board_mm``).
    options, rng : image formation options and random generator.

    Returns
    -------
    (h, w) uint8 image.
    """
    o = BoardRenderOptions() if options is None else options
    rng = np.random.default_rng(0) if rng is None else rng
    S = int(o.supersample)
    w, h = cam.size
    R_cb = cam.R @ np.asarray(R_world_board, float)
    t_cb = cam.R @ np.asarray(t_world_board_mm, float).reshape(3) + cam.t
    x, y = _ray_grid(cam, S)
    n = R_cb[:, 2]
    # the ray d = (x, y, 1) meets the plane n.(X - t) = 0 at s d, s = n.t / n.d;
    # board coordinates b_k = r_k . (s d - t) = s (r_k . d) - r_k . t
    nd = np.float32(n[0]) * x + np.float32(n[1]) * y + np.float32(n[2])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        s = np.float32(n @ t_cb) / nd
    bad = ~(s > 0.0)
    tex, ppm = board_texture(board, o.texels_per_mm)
    org = _texture_origin_mm(board, ppm)
    maps = []
    for r in (R_cb[:, 0], R_cb[:, 1]):
        # texture coordinate ((b - org) ppm - 1/2), folded into one affine expression
        a = r * ppm
        b = np.float32(-(r @ t_cb) * ppm - org * ppm - 0.5)
        m = s * (np.float32(a[0]) * x + np.float32(a[1]) * y + np.float32(a[2])) + b
        m[bad] = -1e5
        maps.append(m)
    # two channels: premultiplied value and coverage, 0 outside the texture
    samp = cv2.remap(_with_alpha(board, o.texels_per_mm), maps[0], maps[1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
    samp = cv2.resize(samp, (w, h), interpolation=cv2.INTER_AREA)  # mean over S x S samples
    bg = _background((w, h), rng, *o.background_dn)
    img = samp[..., 0] + (1.0 - samp[..., 1]) * bg
    img = img * rng.uniform(*o.gain)
    if o.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), float(o.blur_sigma_px))
    if o.noise_dn > 0:
        img = img + rng.normal(0.0, o.noise_dn, size=img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render_board_pair(setup_or_rig, board: Board, R_world_board: np.ndarray, t_world_board_mm: np.ndarray,
                      options: Optional[BoardRenderOptions] = None,
                      rng: Optional[np.random.Generator] = None) -> Tuple[np.ndarray, np.ndarray]:
    """(left, right) uint8 images of a board pose; see :func:`render_board_view`.

    ``setup_or_rig``: anything :func:`synthetic.render.rig_cameras` accepts
    (a Setup, a rig object or mapping, a path to rig.yaml).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    cams = rig_cameras(setup_or_rig)
    return tuple(render_board_view(c, board, R_world_board, t_world_board_mm, options, rng) for c in cams)


# ----------------------------------------------------------------------------
# poses
# ----------------------------------------------------------------------------

#: Order in which the ninths of an image are visited: corners first.
#: How far in from an image corner (fraction of the size) a pose aimed at a
#: corner ninth must reach.
PROBE = 0.15
_CELL_ORDER = (0, 8, 2, 6, 4, 1, 7, 3, 5)


def _view_geometry(cam: CameraModel, board: Board, R_wb: np.ndarray, t_wb: np.ndarray):
    """Projected outline (with margin) and checks for one camera.

    Returns (uv (N, 2), in_front, view_angle_deg, radius_ok)."""
    pts = board.outline_mm(with_margin=True) @ R_wb.T + t_wb
    pc = cam.to_cam(pts)
    in_front = bool(np.all(pc[:, 2] > 50.0))
    centre_w = R_wb @ np.array([board.pattern_size_mm[0] / 2, board.pattern_size_mm[1] / 2, 0.0]) + t_wb
    c = cam.to_cam(centre_w)
    normal_cam = cam.R @ (-R_wb[:, 2])  # toward the viewer
    cosang = float(-(normal_cam @ c) / np.linalg.norm(c))
    ang = float(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
    if not in_front:
        return None, False, ang, False
    rad = np.hypot(pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2])
    radius_ok = bool(np.all(rad < 0.95 * cam.r_max))
    uv = project_points(cam, pts)
    return uv, in_front, ang, radius_ok


def _fill(uv: np.ndarray, size) -> float:
    w, h = size
    span = uv.max(axis=0) - uv.min(axis=0)
    return float(max(span[0] / w, span[1] / h))


def _inside(uv: np.ndarray, size, margin_px: float) -> bool:
    w, h = size
    return bool(np.all(uv[:, 0] >= margin_px - 0.5) and np.all(uv[:, 0] <= w - 0.5 - margin_px)
                and np.all(uv[:, 1] >= margin_px - 0.5) and np.all(uv[:, 1] <= h - 0.5 - margin_px))


def _touches_cell(uv: np.ndarray, size, cell: int) -> bool:
    """True when the board's outline polygon covers most of the cell's outer corner region."""
    w, h = size
    gx, gy = cell % 3, cell // 3
    # a probe point well inside the cell, toward the image border for edge cells
    px = {0: PROBE, 1: 0.5, 2: 1-PROBE}[gx] * w
    py = {0: PROBE, 1: 0.5, 2: 1-PROBE}[gy] * h
    poly = uv.astype(np.float32).reshape(-1, 1, 2)
    return cv2.pointPolygonTest(poly, (float(px), float(py)), False) >= 0


def _base_rotation(board_centre_w: np.ndarray, look_from_w: np.ndarray) -> np.ndarray:
    """B to world rotation of a board facing ``look_from_w``, x roughly along world x."""
    z = board_centre_w - look_from_w  # into the board, away from the viewers
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def pick_board_poses(setup_or_rig, board: Board, n: int, seed: int = 0, max_tilt_deg: float = 35.0,
                     max_roll_deg: float = 15.0, fill_range: Tuple[float, float] = (0.2, 0.6),
                     max_view_angle_deg: float = 60.0, margin_px: float = 6.0,
                     tries_per_target: int = 800) -> List[Tuple[np.ndarray, np.ndarray]]:
    """``n`` varied board poses fully visible in both cameras.

    Pose k is aimed at a ninth of the image of camera ``k % 2`` (corners
    first, then the centre and the edge middles): its outline (with margin)
    must cover a probe point ``PROBE`` of the image size in from that
    ninth's outer corner.  The board faces the midpoint of the two camera
    centres, then is tilted by uniform angles in ±``max_tilt_deg`` about its
    x and y axes and rolled by ±``max_roll_deg``.  A ninth that no pose seen
    whole by both cameras can reach (on a toed-in rig, the corners of each
    image on the side of the other camera) is skipped for the next one after
    ``tries_per_target`` draws.

    Parameters
    ----------
    setup_or_rig : anything :func:`synthetic.render.rig_cameras` accepts.
    board : the board.
    n : number of poses.
    seed : random seed (same seed, same poses).
    fill_range : allowed max(bbox width / image width, bbox height / image
        height) of the board (with margin) in both views.
    max_view_angle_deg : the angle between the board normal and the line of
        sight of each camera stays below this.
    margin_px : the board with its margin stays this far inside both images.

    Returns
    -------
    list of (R_world_board (3, 3), t_world_board_mm (3,)).

    Raises
    ------
    RuntimeError when no pose at all can be found for a camera (the board
    is too big or too small for the rig).
    """
    cams = rig_cameras(setup_or_rig)
    rng = np.random.default_rng(seed)
    centres = [np.zeros(3), -cams[1].R.T @ cams[1].t]
    mid = 0.5 * (centres[0] + centres[1])
    pw, ph = board.pattern_size_mm
    m = board.margin
    aspect = (ph + 2 * m) / (pw + 2 * m)
    poses = []
    next_cell = [0, 0]
    for k in range(n):
        ci = k % 2
        cam = cams[ci]
        w, h = cam.size
        fx = float(cam.K[0, 0])
        found = None
        for attempt in range(len(_CELL_ORDER)):
            cell = _CELL_ORDER[next_cell[ci] % len(_CELL_ORDER)]
            next_cell[ci] += 1
            gx, gy = cell % 3, cell // 3
            for _ in range(tries_per_target):
                fill = rng.uniform(*fill_range)
                bw = fill * w
                bh = bw * aspect

                def centre_px(g, half, size):
                    if g == 1:
                        return size * (0.5 + rng.uniform(-0.1, 0.1))
                    p = PROBE * size + half * rng.uniform(0.3, 0.95)
                    return p if g == 0 else size - p

                u = centre_px(gx, bw / 2, w)
                v = centre_px(gy, bh / 2, h)
                depth = fx * (pw + 2 * m) / bw
                ray = cv2.undistortPoints(np.array([[[u, v]]], float), cam.K, cam.D).reshape(2)
                p_cam = depth * np.array([ray[0], ray[1], 1.0])
                centre_w = cam.R.T @ (p_cam - cam.t)
                R_wb = _base_rotation(centre_w, mid) @ rot_x(rng.uniform(-max_tilt_deg, max_tilt_deg)) \
                    @ rot_y(rng.uniform(-max_tilt_deg, max_tilt_deg)) \
                    @ rot_z(rng.uniform(-max_roll_deg, max_roll_deg))
                t_wb = centre_w - R_wb @ np.array([pw / 2, ph / 2, 0.0])
                if _pose_ok(cams, board, R_wb, t_wb, fill_range, max_view_angle_deg, margin_px,
                            (ci, cell)):
                    found = (R_wb, t_wb)
                    break
            if found is not None:
                break
        if found is None:
            raise RuntimeError(
                f"pick_board_poses: no pose for pose {k} (camera {ci}) in any ninth of the image; "
                f"the board ({pw:.0f} x {ph:.0f} mm) may not fit this rig")
        poses.append(found)
    return poses


def _pose_ok(cams, board, R_wb, t_wb, fill_range, max_view_angle_deg, margin_px, target) -> bool:
    """All the checks of :func:`pick_board_poses` for one pose; ``target``
    is (camera index, ninth) or None."""
    for cj, cm in enumerate(cams):
        uv, front, ang, rad_ok = _view_geometry(cm, board, R_wb, t_wb)
        if not (front and rad_ok and ang < max_view_angle_deg and _inside(uv, cm.size, margin_px)):
            return False
        if not (fill_range[0] <= _fill(uv, cm.size) <= fill_range[1]):
            return False
        if target is not None and cj == target[0] and not _touches_cell(uv, cm.size, target[1]):
            return False
    return True


def _cut_off_pose(setup_or_rig, board: Board, rng: np.random.Generator, max_tries: int = 20000):
    """A pose fully visible in the left image but cut off by the right image's border."""
    cams = rig_cameras(setup_or_rig)
    base = pick_board_poses(setup_or_rig, board, 1, seed=int(rng.integers(1 << 30)))[0]
    R_wb, t_wb = base
    # slide the board along the right camera's image x until it leaves the right image by a third
    right = cams[1]
    x_dir_w = right.R.T @ np.array([1.0, 0.0, 0.0])
    for step in np.arange(5.0, 1500.0, 5.0):
        for sign in (1.0, -1.0):
            t = t_wb + sign * step * x_dir_w
            uv_l, fl, _, okl = _view_geometry(cams[0], board, R_wb, t)
            uv_r, fr, _, okr = _view_geometry(right, board, R_wb, t)
            if not (fl and fr and okl and okr):
                continue
            if not _inside(uv_l, cams[0].size, 6.0):
                continue
            uv_in = project_points(right, board.inner_corners_mm() @ R_wb.T + t)
            w = right.size[0]
            out = np.mean((uv_in[:, 0] < 0) | (uv_in[:, 0] > w - 1))
            if 0.2 <= out <= 0.5:
                return R_wb, t
    raise RuntimeError("could not find a cut-off pose")


# ----------------------------------------------------------------------------
# calibration set writer
# ----------------------------------------------------------------------------

@dataclass
class CalibrationSet:
    """What :func:`write_calibration_set` wrote.

    Attributes
    ----------
    folder : the folder.
    names : pair names in order (e.g. '00'), good and bad.
    bad : {name: kind} of the deliberately bad pairs.
    poses : {name: (R_world_board, t_world_board_mm)} of each pair's left
        image (for 'mismatched' the right image shows another pose).
    truth_rig : path of ``truth_rig.yaml``.
    left_paths, right_paths : {name: Path}.
    """

    folder: Path
    names: List[str]
    bad: dict
    poses: dict
    truth_rig: Path
    left_paths: dict = field(default_factory=dict)
    right_paths: dict = field(default_factory=dict)

    @property
    def good(self) -> List[str]:
        return [n for n in self.names if n not in self.bad]




def write_calibration_set(folder: Union[str, Path], rig_or_setup, board: Board, n_pairs: int = 12,
                          seed: int = 0, layout: str = "subfolders", bad: Sequence[str] = (),
                          options: Optional[BoardRenderOptions] = None,
                          fill_range: Tuple[float, float] = (0.2, 0.6)) -> CalibrationSet:
    """Render a stereo calibration set into ``folder``.

    Layouts: ``'subfolders'`` writes ``left/NN.png`` and ``right/NN.png``;
    ``'side_by_side'`` writes ``leftNN.png`` and ``rightNN.png`` (as
    OpenCV's samples).  ``truth_rig.yaml`` (the contract's rig.yaml format)
    holds the rig the images were made with.

    Parameters
    ----------
    folder : output folder (created).
    rig_or_setup : a :class:`synthetic.setups.Setup`, a rig object or
        mapping (image_size, K1, D1, K2, D2, R, T) or a path to rig.yaml.
    board : the board.
    n_pairs : number of good pairs (poses from :func:`pick_board_poses`).
    seed : seeds the poses and the image noise.
    bad : kinds from :data:`BAD_KINDS`, one bad pair each, appended after
        the good pairs.
    options : image formation options.
    fill_range : size of the board in the images, see :func:`pick_board_poses`
        (a ChArUco board needs markers of 15 px or more: (0.3, 0.6) for a
        7 x 5 squares board).

    Returns
    -------
    :class:`CalibrationSet`.
    """
    if layout not in ("subfolders", "side_by_side"):
        raise ValueError(f"layout is {layout!r}, expected 'subfolders' or 'side_by_side'")
    for b in bad:
        if b not in BAD_KINDS:
            raise ValueError(f"bad pair kind {b!r}, expected one of {BAD_KINDS}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cams = rig_cameras(rig_or_setup)
    L, Rc = cams
    truth = write_rig(folder / "truth_rig.yaml", L.size, L.K, L.D, Rc.K, Rc.D, Rc.R, Rc.t)
    poses = pick_board_poses(rig_or_setup, board, n_pairs, seed, fill_range=fill_range)
    total = n_pairs + len(bad)
    digits = max(2, len(str(total - 1)))
    names = [f"{k:0{digits}d}" for k in range(total)]
    if layout == "subfolders":
        (folder / "left").mkdir(exist_ok=True)
        (folder / "right").mkdir(exist_ok=True)
        lp = {nm: folder / "left" / f"{nm}.png" for nm in names}
        rp = {nm: folder / "right" / f"{nm}.png" for nm in names}
    else:
        lp = {nm: folder / f"left{nm}.png" for nm in names}
        rp = {nm: folder / f"right{nm}.png" for nm in names}
    o = BoardRenderOptions() if options is None else options
    out_poses, bad_map = {}, {}
    for k, nm in enumerate(names):
        rng = np.random.default_rng([int(seed), k])
        if k < n_pairs:
            pose = poses[k]
            left = render_board_view(L, board, *pose, o, rng)
            right = render_board_view(Rc, board, *pose, o, rng)
        else:
            kind = bad[k - n_pairs]
            bad_map[nm] = kind
            if kind == "cut_off":
                pose = _cut_off_pose(rig_or_setup, board, rng)
                left = render_board_view(L, board, *pose, o, rng)
                right = render_board_view(Rc, board, *pose, o, rng)
            else:
                pose = poses[(k - n_pairs) % n_pairs]
                left = render_board_view(L, board, *pose, o, rng)
                if kind == "blurred":
                    right = render_board_view(Rc, board, *pose, o.replace(blur_sigma_px=9.0), rng)
                elif kind == "mismatched":
                    other = poses[(k - n_pairs + n_pairs // 2) % n_pairs]
                    right = render_board_view(Rc, board, *other, o, rng)
                else:  # wrong_size
                    right = render_board_view(Rc, board, *pose, o, rng)
                    right = cv2.resize(right, (right.shape[1] // 2, right.shape[0] // 2),
                                       interpolation=cv2.INTER_AREA)
        out_poses[nm] = pose
        write_image(lp[nm], left)
        write_image(rp[nm], right)
    return CalibrationSet(folder, names, bad_map, out_poses, truth, lp, rp)
