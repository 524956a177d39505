"""Camera rigs and screen geometry for synthetic data.

Monitor frame M
---------------
Origin at the centre of the visible screen area; x_M to the right *as seen
from the screen* (i.e. toward the user's left), y_M down, z_M toward the user
(right-handed: it is the frame of a virtual OpenCV camera at the screen centre
looking at the user).  Screen pixel (0, 0) is the user's top-left corner, so
for a W x H mm visible area::

    top_left    = (+W/2, -H/2, 0)
    top_right   = (-W/2, -H/2, 0)
    bottom_left = (+W/2, +H/2, 0)

Cameras
-------
Two cameras clipped to the monitor's sides at (∓300, 0, +20) mm in M.  The
contract puts the right camera at +x of the left one, and the world frame is
the left camera, so the LEFT camera is the one at x_M = −300 mm: on the
*user's right-hand side* (it is on the left as seen from the screen).  Each
camera is toed in and tilted so that its optical axis passes through the
nominal head position H0 = (0, −80, 650) mm in M, with its x axis horizontal
(perpendicular to y_M) and its y axis pointing down.

Run ``python -m synthetic.setups --write calib/`` to write the default
``rig.yaml``, ``screen.yaml`` and ``markers.yaml``.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from .conventions import (
    DEFAULT_DIAMETER_MM,
    DEFAULT_MARKERS_MM,
    write_markers,
    write_rig,
    write_screen,
)

__all__ = [
    "Setup",
    "SCREEN_24IN_MM",
    "SCREEN_24IN_PX",
    "NOMINAL_HEAD_M",
    "camera_pose_looking_at",
    "build_setup",
    "default_setup",
    "wide_hd_setup",
    "distortion_is_monotonic",
    "max_monotonic_radius",
    "write_setup",
    "SCREEN_49IN_MM",
    "SCREEN_49IN_PX",
    "wide_screen_setup",
]

#: Visible area of a 24-inch 16:9 monitor, (width, height) mm.
SCREEN_24IN_MM = (531.4, 298.9)
#: Its resolution, (width, height) px.
SCREEN_24IN_PX = (1920, 1080)
#: Visible area of a 49-inch 32:9 monitor (a flight-simulator user's wide screen), (width, height) mm: its
#: 1244.6 mm diagonal split 32:9. Drawn flat; such screens are often curved (1000-1800 mm radius).
SCREEN_49IN_MM = (1198.1, 337.0)
#: Its resolution, (width, height) px.
SCREEN_49IN_PX = (3840, 1080)
#: Nominal head (P1) position in the monitor frame M, mm.
NOMINAL_HEAD_M = np.array([0.0, -80.0, 650.0])
#: Camera centres in M, mm: left camera (user's right) and right camera.
CAMERA_CENTRES_M = (np.array([-300.0, 0.0, 20.0]), np.array([300.0, 0.0, 20.0]))


@dataclass
class Setup:
    """A stereo rig plus a screen, everything in the world (= left camera) frame.

    Attributes
    ----------
    image_size : (width, height) of both cameras, px.
    K1, K2 : (3, 3) camera matrices (px).
    D1, D2 : (N,) OpenCV distortion coefficients (k1, k2, p1, p2, k3, ...).
    R, T : right camera extrinsics: ``X_right = R @ X_left + T``; T (3,) mm.
    screen_size_px : (width, height) of the screen, px.
    top_left, top_right, bottom_left : (3,) screen corners in world, mm.
    nominal_head_mm : (3,) nominal head (P1) position in world, mm.
    R_world_from_M, t_world_from_M : pose of the monitor frame M in the world:
        ``X_world = R_world_from_M @ X_M + t_world_from_M`` (mm).
    name : a label.
    """

    image_size: Tuple[int, int]
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    screen_size_px: Tuple[int, int]
    top_left: np.ndarray
    top_right: np.ndarray
    bottom_left: np.ndarray
    nominal_head_mm: np.ndarray
    R_world_from_M: np.ndarray = field(default_factory=lambda: np.eye(3))
    t_world_from_M: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "custom"

    # convenience -----------------------------------------------------------
    @property
    def width(self) -> int:
        return int(self.image_size[0])

    @property
    def height(self) -> int:
        return int(self.image_size[1])

    def camera(self, index: int):
        """``(K, D, R_cam_from_world, t_cam_from_world)`` of camera 0 (left) or 1 (right)."""
        if index == 0:
            return self.K1, self.D1, np.eye(3), np.zeros(3)
        return self.K2, self.D2, np.asarray(self.R, float), np.asarray(self.T, float).reshape(3)

    def m_to_world(self, x_m: np.ndarray) -> np.ndarray:
        """Points (..., 3) from the monitor frame M to the world frame, mm."""
        return np.asarray(x_m, float) @ self.R_world_from_M.T + self.t_world_from_M

    def dir_m_to_world(self, d_m: np.ndarray) -> np.ndarray:
        """Directions (..., 3) from M to world."""
        return np.asarray(d_m, float) @ self.R_world_from_M.T

    def screen_point(self, x_px: float, y_px: float) -> np.ndarray:
        """World position (3,) mm of screen pixel (x, y), per docs/contract.md."""
        w, h = self.screen_size_px
        tl = np.asarray(self.top_left, float)
        return tl + (x_px / w) * (np.asarray(self.top_right) - tl) + (y_px / h) * (np.asarray(self.bottom_left) - tl)

    def right_camera_centre(self) -> np.ndarray:
        """Right camera centre in world, mm (3,)."""
        return -np.asarray(self.R, float).T @ np.asarray(self.T, float).reshape(3)


def camera_pose_looking_at(centre_m: np.ndarray, target_m: np.ndarray) -> np.ndarray:
    """Rotation M-from-camera of a camera at ``centre_m`` aimed at ``target_m``.

    The optical axis (camera z) points at the target, camera x is horizontal
    (perpendicular to y_M), camera y points down (positive y_M component).

    Returns
    -------
    (3, 3) array; columns are the camera axes expressed in M.
    """
    z = np.asarray(target_m, float) - np.asarray(centre_m, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def build_setup(
    image_size,
    K1,
    D1,
    K2,
    D2,
    screen_mm=SCREEN_24IN_MM,
    screen_px=SCREEN_24IN_PX,
    centres_m=CAMERA_CENTRES_M,
    aim_m=NOMINAL_HEAD_M,
    name: str = "custom",
) -> Setup:
    """Assemble a :class:`Setup` from intrinsics and the monitor geometry.

    Parameters
    ----------
    image_size : (w, h) px.
    K1, D1, K2, D2 : intrinsics of the left (at ``centres_m[0]``) and right
        cameras.
    screen_mm, screen_px : visible area (w, h) in mm and px.
    centres_m : camera centres in M, mm; the first is the left (world) camera
        and must be at smaller x_M (the right camera is at +x of the left).
    aim_m : point in M (mm) both optical axes pass through.
    """
    c_l, c_r = (np.asarray(c, float) for c in centres_m)
    R_M_l = camera_pose_looking_at(c_l, aim_m)  # M from left camera
    R_M_r = camera_pose_looking_at(c_r, aim_m)
    R = R_M_r.T @ R_M_l
    T = R_M_r.T @ (c_l - c_r)
    R_world_from_M = R_M_l.T
    t_world_from_M = -R_M_l.T @ c_l
    to_w = lambda p: R_world_from_M @ np.asarray(p, float) + t_world_from_M  # noqa: E731
    w, h = screen_mm
    return Setup(
        image_size=(int(image_size[0]), int(image_size[1])),
        K1=np.asarray(K1, float),
        D1=np.asarray(D1, float).ravel(),
        K2=np.asarray(K2, float),
        D2=np.asarray(D2, float).ravel(),
        R=R,
        T=T,
        screen_size_px=(int(screen_px[0]), int(screen_px[1])),
        top_left=to_w([w / 2, -h / 2, 0.0]),
        top_right=to_w([-w / 2, -h / 2, 0.0]),
        bottom_left=to_w([w / 2, h / 2, 0.0]),
        nominal_head_mm=to_w(NOMINAL_HEAD_M),
        R_world_from_M=R_world_from_M,
        t_world_from_M=t_world_from_M,
        name=name,
    )


def default_setup() -> Setup:
    """The embedded default rig: two 640x480 webcams beside a 24" monitor.

    - image 640 x 480 px, fx ≈ fy ≈ 700 px (49° horizontal field of view, a
      4 mm M12 lens on a 1/4-inch VGA sensor; see calib/README.md for why);
    - principal points a few px off the image centre (319.5, 239.5);
    - mild webcam barrel distortion, k1 ≈ −0.12, k2 ≈ 0.09, k3 ≈ −0.02, small
      tangential terms, slightly different for the two cameras;
    - cameras at (∓300, 0, +20) mm in M (baseline 600 mm), toed in and tilted
      toward H0 = (0, −80, 650) mm in M; the left (world) camera is on the
      user's right-hand side.
    """
    K1 = np.array([[702.3, 0.0, 322.1], [0.0, 701.2, 237.4], [0.0, 0.0, 1.0]])
    D1 = np.array([-0.118, 0.089, 0.0007, -0.0004, -0.021])
    K2 = np.array([[697.6, 0.0, 316.8], [0.0, 698.3, 242.0], [0.0, 0.0, 1.0]])
    D2 = np.array([-0.124, 0.094, -0.0005, 0.0006, -0.018])
    return build_setup((640, 480), K1, D1, K2, D2, name="default")


def wide_hd_setup() -> Setup:
    """A 1280x720 wide-angle rig with strong barrel distortion.

    fx ≈ 709 px with k1 ≈ −0.32, k2 ≈ 0.12, k3 ≈ −0.01, which gives a ≈100°
    horizontal field of view (the image edge is 50° off axis, the corners
    ≈54°).  The distortion map ``r -> r (1 + k1 r² + k2 r⁴ + k3 r⁶)`` is
    monotonic up to r ≈ 2.6 (69°), well beyond the image corners (r ≈ 1.37, 54°).
    Same monitor geometry and camera placement as :func:`default_setup`.
    """
    K1 = np.array([[709.4, 0.0, 642.7], [0.0, 709.9, 357.1], [0.0, 0.0, 1.0]])
    D1 = np.array([-0.320, 0.120, 0.0008, -0.0006, -0.010])
    K2 = np.array([[705.8, 0.0, 637.9], [0.0, 706.1, 362.6], [0.0, 0.0, 1.0]])
    D2 = np.array([-0.315, 0.117, -0.0004, 0.0007, -0.011])
    return build_setup((1280, 720), K1, D1, K2, D2, name="wide_hd")


def _radial_poly(D: np.ndarray) -> Tuple[float, float, float]:
    d = np.zeros(5)
    D = np.asarray(D, float).ravel()
    d[: min(5, D.size)] = D[:5]
    return d[0], d[1], d[4]


def max_monotonic_radius(D: np.ndarray, r_limit: float = 10.0) -> float:
    """Largest undistorted normalized radius where the radial distortion map
    ``r -> r (1 + k1 r² + k2 r⁴ + k3 r⁶)`` still increases (5-coefficient
    radial part; rational and prism terms are ignored)."""
    k1, k2, k3 = _radial_poly(D)
    r = np.linspace(0.0, r_limit, 20001)
    deriv = 1 + 3 * k1 * r**2 + 5 * k2 * r**4 + 7 * k3 * r**6
    bad = np.nonzero(deriv <= 0)[0]
    return float(r_limit if bad.size == 0 else r[bad[0]])


def distortion_is_monotonic(K: np.ndarray, D: np.ndarray, image_size, margin: float = 1.2) -> bool:
    """True when the radial distortion stays monotonic over the whole image
    (its corners), with ``margin`` times the corners' undistorted radius."""
    import cv2

    w, h = image_size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    und = cv2.undistortPoints(
        corners.reshape(-1, 1, 2), np.asarray(K, float), np.asarray(D, float),
        R=np.eye(3), P=np.eye(3),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14),
    ).reshape(-1, 2)
    r = np.linalg.norm(und, axis=1).max()
    return bool(margin * r < max_monotonic_radius(D))


def wide_screen_setup() -> Setup:
    """The embedded rig beside a 49-inch 32:9 monitor (``calib/screen_wide.yaml``) centred where the 24-inch one
    is: the same cameras and monitor frame M, a wider visible area. Only its screen is written
    (``--write-wide-screen``): the cameras would sit on the wide monitor's face, so a real rig moves them."""
    base = default_setup()
    return build_setup(base.image_size, base.K1, base.D1, base.K2, base.D2, screen_mm=SCREEN_49IN_MM,
                       screen_px=SCREEN_49IN_PX, name="wide_screen")


def write_setup(folder, setup: Optional[Setup] = None, markers_mm=DEFAULT_MARKERS_MM,
                diameter_mm: float = DEFAULT_DIAMETER_MM):
    """Write ``rig.yaml``, ``screen.yaml`` and ``markers.yaml`` into ``folder``.

    Returns the list of written paths.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    s = default_setup() if setup is None else setup
    return [
        write_rig(folder / "rig.yaml", s.image_size, s.K1, s.D1, s.K2, s.D2, s.R, s.T),
        write_screen(folder / "screen.yaml", s.screen_size_px, s.top_left, s.top_right, s.bottom_left),
        write_markers(folder / "markers.yaml", markers_mm, diameter_mm),
    ]


def _main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m synthetic.setups", description=__doc__.split("\n")[0])
    ap.add_argument("--write", metavar="DIR", help="write rig.yaml, screen.yaml, markers.yaml into DIR")
    ap.add_argument("--setup", default="default", choices=["default", "wide_hd"])
    ap.add_argument("--write-wide-screen", metavar="FILE",
                    help="write the 49-inch 32:9 screen beside the default rig (calib/screen_wide.yaml)")
    a = ap.parse_args(argv)
    s = default_setup() if a.setup == "default" else wide_hd_setup()
    if a.write_wide_screen:
        w = wide_screen_setup()
        print(write_screen(a.write_wide_screen, w.screen_size_px, w.top_left, w.top_right, w.bottom_left))
    if a.write:
        for p in write_setup(a.write, s):
            print(p)
    elif not a.write_wide_screen:
        np.set_printoptions(precision=4, suppress=True)
        print(s)
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
