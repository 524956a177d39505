"""Physically-motivated synthetic IR stereo image formation.

Scene model
-----------
- Five flat retro-reflective disks (diameter ``diameter_mm``) at the marker
  positions, all facing G's +z, lit by an IR ring light at each camera.
- Each disk is rendered only in a small region of interest (ROI) around its
  projection.  The ROI's pixel corners are back-projected through the full
  OpenCV camera model (``cv2.undistortPoints`` with tight iteration criteria)
  and bilinearly interpolated to ``supersample`` x ``supersample`` cells per
  pixel (the undistortion map is smooth: interpolation error < 1e-3 px).  The
  disk's image is the conic ``dᵀQd <= 0`` in undistorted coordinates
  (:func:`disk_conic`: exact ray / disk-plane intersection); in each cell
  its edge is replaced by the tangent line at the first-order signed distance
  and the exact area of the cell inside that line is the cell's coverage
  (analytic anti-aliasing; exact for straight edges).
- Accuracy (noise-free): blob centroids are within 0.01 px of the exact
  centroid of the disk's image; against ``cv2.projectPoints`` of the disk
  centre they are within ≈ 0.03 px without blur (the physical pixel-locking
  of a sharp disk integrated over square pixels, plus the perspective
  offset), ≈ 0.02 px with the default PSF, and ≈ 0.045 px near the corners
  of the strongly distorted wide rig (there the centroid of the disk's image
  really is that far from the image of its centre).
- Radiance of a disk, in DN for a fully covered pixel::

      L = peak_dn_at_ref * brightness_scale * cos(a) ** k_angle * (d_ref_mm / d) ** 2

  with ``a`` the angle between the disk normal and the direction to the
  camera (retro-reflective sheeting loses efficiency with entrance angle) and
  ``d`` the marker-camera distance (the ring light's irradiance falls with
  1/d²; the retro-reflected radiance follows it).  With the defaults a
  frontal marker at 800 mm gives 130 DN above the ambient level, a marker at
  40 cm saturates, one at 150 cm reaches ≈ 37 DN (less after blur, its image
  is only 2.4 px wide).
- Optical blur: Gaussian PSF (``blur_sigma_px``), applied to each ROI patch
  on the grid of sub-pixel cells, before the integration over the pixel
  area (so the blurred blob's centroid has no pixel-locking bias;
  without blur, a sharp-edged disk integrated over square pixels has a
  physical pixel-locking bias of up to ≈ 0.03 px).
- Background: smooth low-frequency ambient IR pattern (``ambient_dn`` ±
  ``ambient_variation_dn``), fixed for a scene (``ambient_seed``), different
  for the two cameras.
- Sensor: shot noise on electrons (``gain_e_per_dn`` e-/DN; Gaussian
  approximation by default, exact Poisson with ``shot_noise='poisson'``),
  Gaussian read noise (``read_noise_dn``), rounding to 8 bits with clipping
  to [0, 255].
- Options: motion blur (average of ``motion_samples`` sub-exposures spread
  over ``exposure_s`` around t), right image at ``t + right_time_offset_s``,
  specular glints near the glasses, lamps (bright extended blobs at a 3D
  position), reflectors (clutter: small shiny things at 3D points, in the room
  or on the glasses, :class:`Reflector`), occluded markers.
- Rolling shutter (``readout_s``, ``right_readout_s``; s): the rows of an
  image h rows high are exposed one after the other, row r at
  ``t_cam + (r - (h - 1) / 2) * readout_s / (h - 1)`` (``t_cam``: t for the
  left image, t + ``right_time_offset_s`` for the right one; the middle row
  is at ``t_cam``, which stays the mid-exposure time of the image).  Row by
  row: each pixel row of a marker's region of interest is covered by the
  disk in the pose of that row's time (the disk's conic and radiance per
  row; with motion blur the row's sub-exposures are centred on its time),
  so a moving blob is sheared and stretched as a real webcam's is.  The
  optical PSF then blurs the patch as a whole: it mixes rows ≈ 2 px apart,
  exposed ≈ 0.1 ms apart, which moves no centroid (the blur is symmetric).
  0 keeps the global-shutter path unchanged.
- MJPEG (``jpeg_quality``): after the 8-bit rounding each image goes through
  ``cv2.imencode('.jpg')`` / ``cv2.imdecode`` (grayscale), as a webcam's
  MJPEG mode does (webcams' quality ≈ 60-85 with libjpeg's tables).

Everything random comes from the ``numpy.random.Generator`` passed in, plus
``ambient_seed`` for the static background; rendering is deterministic.
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, FrozenSet, Iterable, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from .conventions import cross3, read_matrix_yaml

__all__ = [
    "Lamp",
    "Reflector",
    "RenderOptions",
    "CameraModel",
    "rig_cameras",
    "marker_radiance",
    "expected_peak_dn",
    "disk_conic",
    "render_pair",
    "render_pair_float",
    "render_signal",
    "project_points",
]

PoseFn = Callable[[float], Tuple[np.ndarray, np.ndarray]]

_UNDIST_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-13)


@dataclass(frozen=True)
class Lamp:
    """An IR lamp (incandescent bulb, halogen spot...) seen by the cameras.

    Attributes
    ----------
    position_mm : (3,) world position, mm.
    radius_mm : radius of the glowing part, mm.
    peak_dn : level of its core, DN (above 255 saturates).
    halo : relative level of a Gaussian halo of one core radius around it.
    """

    position_mm: Tuple[float, float, float]
    radius_mm: float = 25.0
    peak_dn: float = 400.0
    halo: float = 0.35


@dataclass(frozen=True)
class Reflector:
    """A small shiny thing in the room or on the glasses (a watch, a chrome lamp part, a patch of
    retro-reflective strip, a hinge screw of the spectacles) that the cameras' own IR lights make a blob.

    It is a 3D point (mm), so both cameras see its blob where the rig's epipolar geometry says: the
    highlight of a small convex object lit by a light beside the camera sits where its normal faces that
    camera, and for objects of a few mm the two cameras' highlights are a fraction of a mm apart.  Drawn
    as a disk of ``radius_mm`` facing the camera (image radius ``fx r / d`` px, anti-aliased over
    4 x 4 sub-pixel cells), blurred by the PSF, of radiance ``peak_dn_at_ref * gain * (d_ref_mm / d) ** 2``
    (DN for a fully covered pixel; 1/d²: lit by the ring light at the camera, as the markers are).  See
    :mod:`synthetic.clutter` for where they are put and why.

    Attributes
    ----------
    position_mm : (3,) position, mm: in the world (left camera) frame, or in G when ``on_head``.
    radius_mm : radius of its bright image, mm.
    peak_dn_at_ref : radiance at ``RenderOptions.d_ref_mm`` from the camera, DN (above 255 saturates).
    on_head : it moves with the glasses (``position_mm`` in G, through the pose).
    right_gain : the right camera sees it this many times as bright as the left one (a specular
        highlight's brightness depends on the surface's slopes toward each camera's light).
    kind : what it is, for people.
    """

    position_mm: Tuple[float, float, float]
    radius_mm: float
    peak_dn_at_ref: float
    on_head: bool = False
    right_gain: float = 1.0
    kind: str = ""

    def world_position(self, pose_fn: "PoseFn", t: float) -> np.ndarray:
        """Its world position (3,) mm at time t (through the head's pose when ``on_head``)."""
        p = np.asarray(self.position_mm, float)
        if not self.on_head:
            return p
        Rwg, p1 = pose_fn(t)
        return np.asarray(Rwg, float) @ p + np.asarray(p1, float).reshape(3)


@dataclass(frozen=True)
class RenderOptions:
    """Image formation options (units in the names: px, mm, DN, s, e-).

    Attributes
    ----------
    supersample : sub-pixel cells per pixel along each axis for the disk
        coverage and the PSF (4 is plenty: the coverage is analytic per cell).
    blur_sigma_px : Gaussian PSF sigma, px (0 disables).
    k_angle : exponent of the cos(entrance angle) fall-off.
    d_ref_mm, peak_dn_at_ref : a frontal marker at ``d_ref_mm`` from the
        camera has a radiance of ``peak_dn_at_ref`` DN (fully covered pixel,
        above the ambient level).
    brightness_scale : multiplies every marker radiance (dim IR: ≈ 0.3).
    ambient_dn, ambient_variation_dn : mean level and ± amplitude of the
        smooth ambient IR pattern, DN (0 disables the background).
    ambient_seed : seed of the static ambient pattern.
    noise : master switch for shot and read noise.
    gain_e_per_dn : conversion gain, electrons per DN (shot noise variance in
        DN² is signal/gain); None or 0 disables shot noise.
    read_noise_dn : Gaussian read noise sigma, DN.
    shot_noise : 'gaussian' (fast normal approximation of the Poisson law;
        the background holds ≈ 90 e-) or 'poisson' (exact, slower).
    exposure_s : exposure time, s (0 = instantaneous).
    motion_samples : number of sub-exposures averaged over ``exposure_s``.
    right_time_offset_s : the right image is taken at t + this offset, s.
    readout_s : rolling shutter: the time from the exposure of the first
        image row to that of the last, s (0 = global shutter; ordinary USB
        webcams 0.015-0.033 s).  Row r of an image h rows high is exposed at
        ``t_cam + (r - (h - 1) / 2) * readout_s / (h - 1)``: the middle row
        is at the camera's time (t, or t + ``right_time_offset_s``), so a
        frame's time stays mid-exposure of the image.
    right_readout_s : the right camera's readout time, s; None: ``readout_s``.
    jpeg_quality : None, or the MJPEG quality (1..100, libjpeg tables; webcams
        ≈ 60-85): after the 8-bit rounding each image is encoded with
        ``cv2.imencode('.jpg')`` and decoded, as a webcam's MJPEG mode does.
    glints : (min, max) number of specular glints per image.
    glint_peak_dn : (min, max) peak level of a glint, DN.
    glint_sigma_px : (min, max) Gaussian sigma of a glint, px.
    glint_spread : glints fall in the markers' image bounding box grown by
        this fraction of its size on each side.
    fused_glints : (min, max) number of glints per image fused with a
        marker's blob (a reflection off the lens rim beside a marker): each
        lands ``fused_glint_offset_px`` from a random marker's centre.
    fused_glint_offset_px : (min, max) distance of a fused glint from its
        marker's centre, px.
    lamps : lamps drawn in both views.
    reflectors : :class:`Reflector` s (clutter: 3D points, seen by both cameras) drawn in both views.
    occluded : (camera, marker) pairs not drawn; camera 0/'left' or
        1/'right', marker 0..4.
    """

    supersample: int = 4
    blur_sigma_px: float = 0.6
    k_angle: float = 1.5
    d_ref_mm: float = 800.0
    peak_dn_at_ref: float = 130.0
    brightness_scale: float = 1.0
    ambient_dn: float = 15.0
    ambient_variation_dn: float = 5.0
    ambient_seed: int = 0
    noise: bool = True
    gain_e_per_dn: Optional[float] = 6.0
    read_noise_dn: float = 1.5
    shot_noise: str = "gaussian"
    exposure_s: float = 0.0
    motion_samples: int = 1
    right_time_offset_s: float = 0.0
    readout_s: float = 0.0
    right_readout_s: Optional[float] = None
    jpeg_quality: Optional[int] = None
    glints: Tuple[int, int] = (0, 0)
    glint_peak_dn: Tuple[float, float] = (250.0, 700.0)
    glint_sigma_px: Tuple[float, float] = (0.3, 0.55)
    glint_spread: float = 0.3
    fused_glints: Tuple[int, int] = (0, 0)
    fused_glint_offset_px: Tuple[float, float] = (1.0, 3.0)
    lamps: Tuple[Lamp, ...] = ()
    reflectors: Tuple[Reflector, ...] = ()
    occluded: FrozenSet[Tuple[Union[int, str], int]] = frozenset()

    def replace(self, **kw) -> "RenderOptions":
        """A copy with some fields changed."""
        return replace(self, **kw)

    def readout_for(self, cam_index: int) -> float:
        """Readout time (s) of camera 0 (left) or 1 (right)."""
        if cam_index == 1 and self.right_readout_s is not None:
            return float(self.right_readout_s)
        return float(self.readout_s)

    def occluded_set(self) -> set:
        """``occluded`` normalized to {(camera_index, marker_index)}."""
        out = set()
        for cam, m in self.occluded:
            if isinstance(cam, str):
                cam = {"left": 0, "l": 0, "right": 1, "r": 1}[cam.lower()]
            out.add((int(cam), int(m)))
        return out


# ----------------------------------------------------------------------------
# cameras
# ----------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraModel:
    """One camera of the rig: ``X_cam = R @ X_world + t``, OpenCV intrinsics."""

    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: Tuple[int, int]
    r_max: float = field(default=np.inf)  # max undistorted radius still monotonic

    def to_cam(self, x_world: np.ndarray) -> np.ndarray:
        return np.asarray(x_world, float) @ self.R.T + self.t


def _max_monotonic_radius(D: np.ndarray) -> float:
    return _max_monotonic_radius_cached(tuple(float(v) for v in np.asarray(D, float).ravel()))


@functools.lru_cache(maxsize=64)
def _max_monotonic_radius_cached(D: tuple) -> float:
    d = np.zeros(max(14, len(D)))
    D = np.asarray(D, float)
    d[: D.size] = D
    k1, k2, k3, k4, k5, k6 = d[0], d[1], d[4], d[5], d[6], d[7]
    r = np.linspace(0.0, 8.0, 8001)
    r2 = r * r
    num = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    den = 1 + k4 * r2 + k5 * r2**2 + k6 * r2**3
    f = r * num / den
    bad = np.nonzero((np.diff(f) <= 0) | (den[1:] <= 0))[0]
    return float(8.0 if bad.size == 0 else r[bad[0]])


def rig_cameras(setup_or_rig) -> Tuple[CameraModel, CameraModel]:
    """The two cameras of a rig.

    Parameters
    ----------
    setup_or_rig : a :class:`synthetic.setups.Setup`, any object or mapping
        with ``image_size`` (or ``image_width``/``image_height``), K1, D1, K2,
        D2, R, T, or a path to a contract ``rig.yaml``.

    Returns
    -------
    (left, right) :class:`CameraModel`; left is the world frame.
    """
    obj = setup_or_rig
    if isinstance(obj, (str, Path)):
        obj = read_matrix_yaml(obj)
    get = (lambda k: obj[k]) if isinstance(obj, dict) else (lambda k: getattr(obj, k))
    try:
        size = tuple(int(v) for v in get("image_size"))
    except (KeyError, AttributeError):
        size = (int(get("image_width")), int(get("image_height")))
    K1, D1, K2, D2 = (np.asarray(get(k), float) for k in ("K1", "D1", "K2", "D2"))
    R = np.asarray(get("R"), float).reshape(3, 3)
    T = np.asarray(get("T"), float).reshape(3)
    left = CameraModel(K1.reshape(3, 3), D1.ravel(), np.eye(3), np.zeros(3), size, _max_monotonic_radius(D1))
    right = CameraModel(K2.reshape(3, 3), D2.ravel(), R, T, size, _max_monotonic_radius(D2))
    return left, right


def project_points(cam: CameraModel, x_world: np.ndarray) -> np.ndarray:
    """Project world points (N, 3) mm to pixels (N, 2) with ``cv2.projectPoints``."""
    x = np.asarray(x_world, float).reshape(-1, 3)
    rvec, _ = cv2.Rodrigues(cam.R)
    uv, _ = cv2.projectPoints(x, rvec, cam.t.reshape(3, 1), cam.K, cam.D)
    return uv.reshape(-1, 2)


def _project_cam(cam: CameraModel, x_cam: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.asarray(x_cam, float).reshape(-1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D)
    return uv.reshape(-1, 2)


def _undistort(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> normalized undistorted coordinates (N, 2)."""
    out = cv2.undistortPoints(
        np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 1, 2), cam.K, cam.D,
        R=np.eye(3), P=np.eye(3), criteria=_UNDIST_CRITERIA,
    )
    return out.reshape(-1, 2)


# ----------------------------------------------------------------------------
# brightness
# ----------------------------------------------------------------------------

def marker_radiance(centre_cam: np.ndarray, normal_cam: np.ndarray, options: RenderOptions) -> float:
    """Radiance (DN for a fully covered pixel) of a disk seen from a camera.

    Parameters
    ----------
    centre_cam : (3,) disk centre in the camera frame, mm.
    normal_cam : (3,) unit disk normal in the camera frame.

    Returns
    -------
    float, DN; 0 when the disk faces away from the camera.
    """
    c = np.asarray(centre_cam, float)
    d = float(np.linalg.norm(c))
    cos_a = float(-np.dot(normal_cam, c) / d)
    if cos_a <= 0.0:
        return 0.0
    o = options
    return o.peak_dn_at_ref * o.brightness_scale * cos_a ** o.k_angle * (o.d_ref_mm / d) ** 2


def expected_peak_dn(cam: "CameraModel", centre_w: np.ndarray, normal_w: np.ndarray, diameter_mm: float,
                     options: RenderOptions) -> float:
    """Rough peak (DN above the background) of a marker's blob.

    The radiance (:func:`marker_radiance`) times the fraction of a Gaussian
    (PSF plus pixel box, sigma² = blur² + 1/12 px²) that falls inside the
    ellipse of semi-axes ``a`` and ``a cos(angle)``, ``a = fx r / d``:
    ``1 - exp(-a b / (2 sigma²))``.  Good to ≈ 10 %, for choosing poses.
    """
    c = cam.to_cam(np.asarray(centre_w, float))
    n = cam.R @ np.asarray(normal_w, float)
    L = marker_radiance(c, n, options)
    if L <= 0.0:
        return 0.0
    d = float(np.linalg.norm(c))
    a = float(cam.K[0, 0]) * 0.5 * diameter_mm / d
    b = a * float(-np.dot(n, c) / d)
    s2 = float(options.blur_sigma_px) ** 2 + 1.0 / 12.0
    return L * (1.0 - np.exp(-a * b / (2.0 * s2)))


# ----------------------------------------------------------------------------
# marker rendering
# ----------------------------------------------------------------------------

_RIM = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)


def _disk_jobs(cam: CameraModel, centres_w: np.ndarray, normal_w: np.ndarray, radius: float,
               options: RenderOptions, skip: Iterable[int]):
    """Geometry and tight pixel box of each visible disk for one camera and
    one instant: a list of ``(marker, c_cam, n_cam, L, x0, y0, x1, y1)``
    (inclusive box, may extend outside the image)."""
    n_c = cam.R @ normal_w
    cs = cam.to_cam(centres_w)
    keep = []
    for i, c in enumerate(cs):
        if i in skip or c[2] <= radius + 1.0:
            continue
        L = marker_radiance(c, n_c, options)
        if L <= 0.0:
            continue
        # stay inside the region where the distortion map is one-to-one
        if np.hypot(c[0] / c[2], c[1] / c[2]) + radius / c[2] > 0.98 * cam.r_max:
            continue
        keep.append((i, c, L))
    if not keep:
        return []
    e1 = cross3(n_c, [1.0, 0.0, 0.0] if abs(n_c[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = cross3(n_c, e1)
    ring = radius * (np.cos(_RIM)[:, None] * e1 + np.sin(_RIM)[:, None] * e2)  # (24, 3)
    rims = np.concatenate([c + ring for (_, c, _) in keep])
    if np.any(rims[:, 2] <= 1.0):
        ok = [k for k, (_, c, _) in enumerate(keep) if np.all(c[2] + ring[:, 2] > 1.0)]
        keep = [keep[k] for k in ok]
        if not keep:
            return []
        rims = np.concatenate([c + ring for (_, c, _) in keep])
    uv = _project_cam(cam, rims).reshape(len(keep), len(_RIM), 2)
    lo = np.floor(uv.min(axis=1)).astype(int) - 1  # the inscribed 24-gon misses < 1 px
    hi = np.ceil(uv.max(axis=1)).astype(int) + 1
    jobs = []
    for (i, c, L), (x0, y0), (x1, y1) in zip(keep, lo, hi):
        if (x1 - x0) > 400 or (y1 - y0) > 400:  # absurdly close; not a use case
            continue
        jobs.append((i, c, n_c, L, int(x0), int(y0), int(x1), int(y1)))
    return jobs


def disk_conic(c: np.ndarray, n: np.ndarray, radius: float) -> np.ndarray:
    """Conic of the image of a disk in normalized (undistorted) coordinates.

    A ray ``d = (x, y, 1)`` (camera frame) meets the disk of centre ``c``
    (mm), unit normal ``n`` and radius ``radius`` (mm) iff
    ``d @ Q @ d <= 0``.  Derivation: the ray meets the disk plane at
    ``s d`` with ``s = (n.c)/(n.d)``, and ``|s d - c|² <= r²`` times
    ``(n.d)²`` gives ``|M d|² - r² (n.d)² <= 0`` with ``M = (n.c) I - c nᵀ``.

    Returns
    -------
    (3, 3) symmetric array, scaled to unit max-abs entry.
    """
    c = np.asarray(c, float)
    n = np.asarray(n, float)
    M = np.dot(n, c) * np.eye(3) - np.outer(c, n)
    Q = M.T @ M - radius * radius * np.outer(n, n)
    return Q / np.abs(Q).max()


def _disk_conics(c: np.ndarray, n: np.ndarray, radius: float) -> np.ndarray:
    """:func:`disk_conic` of many disks: c, n (N, 3) -> (N, 3, 3)."""
    c = np.asarray(c, float)
    n = np.asarray(n, float)
    nc = np.einsum("ij,ij->i", n, c)
    M = nc[:, None, None] * np.eye(3) - c[:, :, None] * n[:, None, :]
    Q = np.swapaxes(M, 1, 2) @ M - radius * radius * n[:, :, None] * n[:, None, :]
    return Q / np.abs(Q).max(axis=(1, 2), keepdims=True)


def _halfplane_square_area(nx: np.ndarray, ny: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Area of the unit square [-1/2, 1/2]² where ``nx x + ny y <= s``.

    ``(nx, ny)`` unit vectors, ``s`` the signed offset of the line from the
    square's centre (all arrays of the same shape).
    """
    a = np.minimum(np.abs(nx), np.abs(ny))
    b = np.maximum(np.abs(nx), np.abs(ny))
    u = np.clip(s + 0.5 * (a + b), 0.0, a + b)
    ab2 = 2.0 * np.maximum(a, 1e-9) * b
    out = np.where(u <= a, u * u / ab2,
                   np.where(u <= b, (u - 0.5 * a) / b, 1.0 - (a + b - u) ** 2 / ab2))
    return np.clip(out, 0.0, 1.0)


def _coverage(und_corners: np.ndarray, H: int, W: int, S: int, c: np.ndarray, n: np.ndarray,
              radius: float) -> np.ndarray:
    """Fraction of each sub-pixel cell covered by the image of a disk.

    The ROI is divided into ``S`` x ``S`` cells per pixel.  The cell centres
    are mapped to normalized undistorted coordinates by bilinear
    interpolation of the undistorted pixel corners (the undistortion map is
    smooth: the interpolation error is < 1e-3 px).  In each cell the disk's
    image edge is replaced by its tangent line at the signed distance
    ``q / |grad q|`` (q: the disk's conic, gradient taken in pixel units with
    the local Jacobian of the undistortion), and the exact area of the cell
    on the inner side of that line is the coverage.  This is exact for
    straight edges and second order in the cell size otherwise (centroid
    error < 0.005 px for blobs wider than 1 px at S = 4).

    Parameters
    ----------
    und_corners : ((H+1)*(W+1), 2) undistorted normalized coordinates of the
        pixel corners of the ROI, row major (corner (j, i) at pixel
        coordinates (i - 1/2, j - 1/2) relative to the ROI origin).
    H, W : ROI size, px.
    S : cells per pixel along each axis.
    c, n : disk centre (mm) and unit normal in the camera frame, (3,); or
        (H, 3), one per pixel row of the ROI (a rolling shutter exposes
        each row at its own time: the disk's pose per row).
    radius : disk radius, mm.

    Returns
    -------
    (H*S, W*S) float32 coverage in [0, 1].
    """
    C = und_corners.reshape(H + 1, W + 1, 2)
    o = C[(H + 1) // 2, (W + 1) // 2].copy()
    C = C - o
    # conic in local coordinates p = (xi, eta, 1): d = T p
    T = np.array([[1.0, 0.0, o[0]], [0.0, 1.0, o[1]], [0.0, 0.0, 1.0]])
    if np.ndim(c) == 1:
        Q = T.T @ disk_conic(c, n, radius) @ T
    else:   # a conic per pixel row, broadcast over (H, S, W, S)
        Q = (T.T @ _disk_conics(c, n, radius) @ T).reshape(H, 1, 1, 1, 3, 3)
        Q = np.moveaxis(Q, (-2, -1), (0, 1))
    a = (np.arange(S, dtype=np.float64) + 0.5) / S
    b = 1.0 - a
    Cx = C[:, :-1, None, :] * b[None, None, :, None] + C[:, 1:, None, :] * a[None, None, :, None]
    Cx = Cx.reshape(H + 1, W * S, 2)
    F = Cx[:-1, None] * b[None, :, None, None] + Cx[1:, None] * a[None, :, None, None]  # (H, S, W*S, 2)
    F = F.reshape(H, S, W, S, 2)
    x = F[..., 0]
    y = F[..., 1]
    gx = Q[0, 0] * x + Q[0, 1] * y + Q[0, 2]
    gy = Q[0, 1] * x + Q[1, 1] * y + Q[1, 2]
    q = gx * x + gy * y + (Q[0, 2] * x + Q[1, 2] * y + Q[2, 2])
    # Jacobian of the undistortion per pixel: d(xi, eta)/du and d(xi, eta)/dv
    Ju = 0.5 * (C[:-1, 1:] + C[1:, 1:] - C[:-1, :-1] - C[1:, :-1])  # (H, W, 2)
    Jv = 0.5 * (C[1:, :-1] + C[1:, 1:] - C[:-1, :-1] - C[:-1, 1:])
    Ju = Ju[:, None, :, None, :]
    Jv = Jv[:, None, :, None, :]
    gu = 2.0 * (gx * Ju[..., 0] + gy * Ju[..., 1])
    gv = 2.0 * (gx * Jv[..., 0] + gy * Jv[..., 1])
    g = np.hypot(gu, gv)
    tiny = g < 1e-300
    g = np.where(tiny, 1.0, g)
    nu = np.where(tiny, 1.0, gu / g)
    nv = np.where(tiny, 0.0, gv / g)
    d = (q / g) * S  # signed distance to the edge in cell units (inside < 0)
    cov = _halfplane_square_area(nu, nv, -d)
    return cov.reshape(H * S, W * S).astype(np.float32)


def _area_down(img: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return img
    h, w = img.shape
    return img.reshape(h // f, f, w // f, f).mean(axis=(1, 3), dtype=np.float32)


def _gauss_kernel_size(sigma: float) -> int:
    return 2 * int(np.ceil(4.0 * sigma)) + 1


def _marker_setup(layer: np.ndarray, cam_index: int, model_points_mm, diameter_mm: float, options: RenderOptions):
    """What drawing one camera's markers needs: the layer's (h, w) px, the sub-pixel cells per pixel S, the
    PSF's σ (px) and margin (px), the disks' radius (mm), the occluded markers of this camera, the model (5, 3)."""
    h, w = layer.shape
    sigma = float(options.blur_sigma_px)
    pad = int(np.ceil(4.0 * sigma)) + 1 if sigma > 0 else 0
    skip = {m for (ci, m) in options.occluded_set() if ci == cam_index}
    return (h, w, int(options.supersample), sigma, pad, 0.5 * float(diameter_mm), skip,
            np.asarray(model_points_mm, float).reshape(5, 3))


def _render_markers_into(layer: np.ndarray, cam: CameraModel, cam_index: int, model_points_mm: np.ndarray,
                         diameter_mm: float, pose_fn: PoseFn, times: Sequence[float],
                         options: RenderOptions, readout_s: float = 0.0) -> list:
    """Add the (blurred, motion-averaged) marker images of one camera into ``layer``.

    For each marker, the coverage of every sub-exposure is computed on its
    tight box (S x S cells per pixel), weighted by its radiance and summed in
    one buffer covering the union of the boxes plus the PSF margin; the
    buffer is blurred, integrated over the pixels and added to ``layer``.
    ``times`` are the sub-exposure times of the middle row; with
    ``readout_s`` > 0 (rolling shutter) each row is exposed at its own time
    (:func:`_render_markers_rolling`).

    Returns the list of world marker positions (5, 3) at each sub-time.
    """
    if readout_s > 0.0 and layer.shape[0] > 1:
        return _render_markers_rolling(layer, cam, cam_index, model_points_mm, diameter_mm, pose_fn, times,
                                       options, readout_s)
    h, w, S, sigma, pad, radius, skip, model = _marker_setup(layer, cam_index, model_points_mm, diameter_mm, options)
    weight = 1.0 / len(times)
    jobs = []
    positions = []
    for t in times:
        Rwg, p1 = pose_fn(t)
        Rwg = np.asarray(Rwg, float)
        pw = model @ Rwg.T + np.asarray(p1, float).reshape(3)
        positions.append(pw)
        for job in _disk_jobs(cam, pw, Rwg[:, 2], radius, options, skip):
            # clip the tight box to the image grown by the PSF margin
            i, c, n, L, x0, y0, x1, y1 = job
            x0, y0 = max(x0, -pad), max(y0, -pad)
            x1, y1 = min(x1, w - 1 + pad), min(y1, h - 1 + pad)
            if x1 >= x0 and y1 >= y0:
                jobs.append((i, c, n, L, x0, y0, x1, y1))
    _paste_disks(layer, cam, jobs, S, sigma, pad, radius, weight)
    return positions


def _paste_disks(layer: np.ndarray, cam: CameraModel, jobs: list, S: int, sigma: float, pad: int, radius: float,
                 weight: float) -> None:
    """Render ``jobs`` ``(marker, c, n, L, x0, y0, x1, y1)`` (one per marker and sub-exposure; c, n, L
    scalars of the instant, or per row of the box: (H, 3), (H, 3), (H,)) into ``layer``: each marker's
    coverages summed in one buffer, blurred by the PSF, integrated over the pixels and added."""
    if not jobs:
        return
    h, w = layer.shape
    # one undistortion call for the pixel corners of all boxes
    grids = []
    for (_, _, _, _, x0, y0, x1, y1) in jobs:
        u = np.arange(x0, x1 + 2, dtype=np.float64) - 0.5
        v = np.arange(y0, y1 + 2, dtype=np.float64) - 0.5
        uu, vv = np.meshgrid(u, v)
        grids.append(np.stack([uu.ravel(), vv.ravel()], axis=1))
    offs = np.concatenate([[0], np.cumsum([g.shape[0] for g in grids])])
    und = _undistort(cam, np.concatenate(grids))
    ks = _gauss_kernel_size(sigma * S) if sigma > 0 else 0
    for m in sorted({j[0] for j in jobs}):
        idx = [k for k, j in enumerate(jobs) if j[0] == m]
        bx0 = min(jobs[k][4] for k in idx) - pad
        by0 = min(jobs[k][5] for k in idx) - pad
        bx1 = max(jobs[k][6] for k in idx) + pad
        by1 = max(jobs[k][7] for k in idx) + pad
        buf = np.zeros(((by1 - by0 + 1) * S, (bx1 - bx0 + 1) * S), np.float32)
        for k in idx:
            _, c, n, L, x0, y0, x1, y1 = jobs[k]
            H, W = y1 - y0 + 1, x1 - x0 + 1
            cov = _coverage(und[offs[k]:offs[k + 1]], H, W, S, c, n, radius)
            oy, ox = (y0 - by0) * S, (x0 - bx0) * S
            if np.ndim(L) == 0:
                buf[oy:oy + H * S, ox:ox + W * S] += np.float32(L * weight) * cov
            else:   # a radiance per pixel row
                buf[oy:oy + H * S, ox:ox + W * S] += np.repeat((L * weight).astype(np.float32), S)[:, None] * cov
        if sigma > 0:
            buf = cv2.GaussianBlur(buf, (ks, ks), sigma * S, borderType=cv2.BORDER_CONSTANT)
        patch = _area_down(buf, S)
        # paste the part inside the image
        cx0, cy0 = max(bx0, 0), max(by0, 0)
        cx1, cy1 = min(bx1, w - 1), min(by1, h - 1)
        if cx1 >= cx0 and cy1 >= cy0:
            layer[cy0:cy1 + 1, cx0:cx1 + 1] += patch[cy0 - by0:cy1 - by0 + 1, cx0 - bx0:cx1 - bx0 + 1]


class _RowClock:
    """A rolling shutter's poses: the marker geometry of one camera when pixel row ``r`` is exposed at
    ``t + (r - (h - 1) / 2) * readout_s / (h - 1)`` for a sub-exposure time ``t`` of the middle row.

    Poses are evaluated exactly every :attr:`KNOT` rows (``KNOT * readout_s / (h - 1)``: 0.25 ms at
    30 ms over 480 rows) and the disk centres and normals interpolated linearly between (the error is
    the motion's curvature over 0.25 ms: < 1e-5 mm for a head); where a centre moves more than
    :attr:`JUMP_MM` between two knots (a pose function with jumps, such as independent random poses),
    every row between them is evaluated exactly.  Poses are cached per (t, row): markers on the same
    rows share them.
    """

    KNOT = 4
    JUMP_MM = 1.0
    #: pixels added around a box (0: the boxes hold the blobs whole; 3 changes no pixel of fast_motion)
    MARGIN = 0

    def __init__(self, cam: CameraModel, model: np.ndarray, pose_fn: PoseFn, h: int, readout_s: float,
                 radius: float, options: RenderOptions, skip):
        self.cam, self.model, self.pose_fn = cam, model, pose_fn
        self.row_s = float(readout_s) / (h - 1)
        self.mid = 0.5 * (h - 1)
        self.radius, self.options, self.skip = radius, options, skip
        self._states: dict = {}
        self._uv: dict = {}

    def state(self, t: float, row: int):
        """(world positions (5, 3), R_world_from_G, camera-frame centres (5, 3), camera-frame normal) at
        ``row``'s time."""
        key = (t, row)
        st = self._states.get(key)
        if st is None:
            Rwg, p1 = self.pose_fn(t + (row - self.mid) * self.row_s)
            Rwg = np.asarray(Rwg, float)
            pw = self.model @ Rwg.T + np.asarray(p1, float).reshape(3)
            st = self._states[key] = (pw, Rwg, self.cam.to_cam(pw), self.cam.R @ Rwg[:, 2])
        return st

    def centres_uv(self, t: float, row: int) -> np.ndarray:
        """Image points (5, 2) px of the disk centres at ``row``'s time (NaN behind the camera)."""
        key = (t, row)
        uv = self._uv.get(key)
        if uv is None:
            cs = self.state(t, row)[2]
            front = cs[:, 2] > 1.0
            uv = np.full((5, 2), np.nan)
            if front.any():
                uv[front] = _project_cam(self.cam, cs[front])
            self._uv[key] = uv
        return uv

    def knot(self, row: float, up: Optional[bool] = None) -> int:
        """The knot row nearest ``row`` (``up`` True / False: the next one at or above / below it)."""
        K = self.KNOT
        if up is None:
            return int(np.floor(row / K + 0.5)) * K
        return int(np.ceil(row / K)) * K if up else int(np.floor(row / K)) * K

    def centre_row(self, t: float, m: int, row: int, exact: bool = False) -> int:
        """The row marker m's image centre is on at that row's own time (fixed point from ``row``); to the
        nearest knot unless ``exact`` (a box needs no more: a knot is ≤ 2 rows, 0.13 ms at 30 ms, away)."""
        snap = (lambda v: int(np.floor(v + 0.5))) if exact else self.knot
        row = snap(row)
        for _ in range(8):
            v = self.centres_uv(t, row)[m, 1]
            if not np.isfinite(v):
                break
            nxt = snap(v)
            if nxt == row:
                break
            row = nxt
        return row

    def boxes(self, t: float) -> dict:
        """marker -> pixel box (x0, y0, x1, y1) holding the marker's sheared image: the disk's tight box
        at the middle row's time moved with its centre to the row that centre is on at its own time, and
        widened to the box's moves at the times of its first and last rows."""
        mid = self.knot(self.mid)
        pw, Rwg, _, _ = self.state(t, mid)
        uv0 = self.centres_uv(t, mid)
        out = {}
        for job in _disk_jobs(self.cam, pw, Rwg[:, 2], self.radius, self.options, self.skip):
            m = job[0]
            x0, y0, x1, y1 = job[4:]
            row = self.centre_row(t, m, int(np.floor(uv0[m, 1] + 0.5)))
            d = self.centres_uv(t, row)[m] - uv0[m]
            if not np.all(np.isfinite(d)):
                d = np.zeros(2)
            bx0, by0 = int(np.floor(x0 + d[0])), int(np.floor(y0 + d[1]))
            bx1, by1 = int(np.ceil(x1 + d[0])), int(np.ceil(y1 + d[1]))
            for r in (self.knot(by0, up=False), self.knot(by1, up=True)):
                e = self.centres_uv(t, r)[m] - uv0[m]
                if np.all(np.isfinite(e)):
                    bx0, by0 = min(bx0, int(np.floor(x0 + e[0]))), min(by0, int(np.floor(y0 + e[1])))
                    bx1, by1 = max(bx1, int(np.ceil(x1 + e[0]))), max(by1, int(np.ceil(y1 + e[1])))
            g = self.MARGIN
            out[m] = (bx0 - g, by0 - g, bx1 + g, by1 + g)
        return out

    def rows_geometry(self, t: float, m: int, y0: int, y1: int):
        """Marker m's centre and normal (camera frame) and radiance at the times of rows y0..y1:
        (H, 3), (H, 3), (H,); None when it is nowhere in front of the camera."""
        K = self.KNOT
        k0, k1 = (y0 // K) * K, -((-y1) // K) * K
        knots = list(range(k0, k1 + 1, K)) if k1 > k0 else [k0, k0 + K]
        Ck = np.array([self.state(t, r)[2][m] for r in knots])
        Nk = np.array([self.state(t, r)[3] for r in knots])
        rows = np.arange(y0, y1 + 1)
        seg = np.minimum((rows - knots[0]) // K, len(knots) - 2)
        f = ((rows - knots[0]) - seg * K)[:, None] / K
        C = (1.0 - f) * Ck[seg] + f * Ck[seg + 1]
        N = (1.0 - f) * Nk[seg] + f * Nk[seg + 1]
        jumps = np.linalg.norm(np.diff(Ck, axis=0), axis=1) > self.JUMP_MM
        if jumps.any():     # rows between knots a pose jumps between: each at its own pose
            for i in np.nonzero(jumps[seg])[0]:
                _, _, cs, n_c = self.state(t, int(rows[i]))
                C[i], N[i] = cs[m], n_c
        N /= np.linalg.norm(N, axis=1, keepdims=True)
        d = np.linalg.norm(C, axis=1)
        cos_a = -np.einsum("ij,ij->i", N, C) / d
        ok = (cos_a > 0.0) & (C[:, 2] > self.radius + 1.0)
        if not ok.any():
            return None
        o = self.options
        L = np.where(ok, o.peak_dn_at_ref * o.brightness_scale * np.maximum(cos_a, 0.0) ** o.k_angle
                     * (o.d_ref_mm / d) ** 2, 0.0)
        if not ok.all():    # rows where the disk is behind the camera: no light, and a harmless conic
            good = np.nonzero(ok)[0]
            near = good[np.abs(np.arange(len(rows))[:, None] - good[None, :]).argmin(axis=1)]
            C, N = C[near], N[near]
        return C, N, L

    def marker_positions(self, t: float) -> np.ndarray:
        """World positions (5, 3) of the markers, each at the time of the row its image centre is on."""
        mid = int(round(self.mid))
        out = np.empty((5, 3))
        for m in range(5):
            v = self.centres_uv(t, mid)[m, 1]
            row = self.centre_row(t, m, int(np.floor(v + 0.5)), exact=True) if np.isfinite(v) else mid
            out[m] = self.state(t, row)[0][m]
        return out


def _render_markers_rolling(layer: np.ndarray, cam: CameraModel, cam_index: int, model_points_mm: np.ndarray,
                            diameter_mm: float, pose_fn: PoseFn, times: Sequence[float], options: RenderOptions,
                            readout_s: float) -> list:
    """:func:`_render_markers_into` with a rolling shutter: every pixel row of a marker's box is
    covered by the disk as it is at that row's time (for each sub-exposure, centred on the row's time),
    so the blob is sheared and stretched by the motion; then blurred by the PSF as a whole.

    Returns the list of world marker positions (5, 3) at each sub-time of the middle row.
    """
    h, w, S, sigma, pad, radius, skip, model = _marker_setup(layer, cam_index, model_points_mm, diameter_mm, options)
    clock = _RowClock(cam, model, pose_fn, h, readout_s, radius, options, skip)
    jobs = []
    positions = []
    for t in times:
        t = float(t)
        Rwg, p1 = pose_fn(t)
        positions.append(model @ np.asarray(Rwg, float).T + np.asarray(p1, float).reshape(3))
        for m, (x0, y0, x1, y1) in sorted(clock.boxes(t).items()):
            x0, y0 = max(x0, -pad), max(y0, -pad)
            x1, y1 = min(x1, w - 1 + pad), min(y1, h - 1 + pad)
            if x1 < x0 or y1 < y0:
                continue
            geo = clock.rows_geometry(t, m, y0, y1)
            if geo is not None:
                jobs.append((m, geo[0], geo[1], geo[2], x0, y0, x1, y1))
    _paste_disks(layer, cam, jobs, S, sigma, pad, radius, 1.0 / len(times))
    return positions


# ----------------------------------------------------------------------------
# background, distractors, sensor
# ----------------------------------------------------------------------------

@functools.lru_cache(maxsize=16)
def _ambient(width: int, height: int, mean: float, variation: float, seed: int, cam_index: int) -> np.ndarray:
    """Smooth low-frequency ambient pattern (h, w) float32, read-only."""
    rng = np.random.default_rng([int(seed), int(cam_index), 7919])
    coarse = rng.uniform(-1.0, 1.0, size=(4, 5)).astype(np.float32)
    pat = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    # a gentle vertical gradient (window light, ceiling) and a soft bright region
    yy = np.linspace(-1.0, 1.0, height, dtype=np.float32)[:, None]
    xx = np.linspace(-1.0, 1.0, width, dtype=np.float32)[None, :]
    cx, cy = rng.uniform(-0.8, 0.8, size=2)
    pat = pat + 0.6 * rng.uniform(-1, 1) * yy + 0.8 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 0.3)
    pat = pat - pat.mean()
    pat = pat / max(float(np.abs(pat).max()), 1e-6)
    out = (mean + variation * pat).astype(np.float32)
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=1)
def _normal_table() -> np.ndarray:
    # 2^16 equiprobable normal quantiles: an exact sample of a normal law
    # quantized to 2^-16 in probability (tails at ±4.3 sigma).
    from scipy.special import ndtri   # on use: scipy.special costs 0.2 s to import, which parsing need not pay

    return ndtri((np.arange(65536, dtype=np.float64) + 0.5) / 65536.0).astype(np.float32)


_WS = threading.local()


def _workspace(name: str, shape, dtype=np.float32) -> np.ndarray:
    """A reusable per-thread scratch array (full-image temporaries would
    otherwise be freshly mapped, and page faults cost more than the maths)."""
    d = getattr(_WS, "arrays", None)
    if d is None:
        d = _WS.arrays = {}
    key = (name, tuple(shape), np.dtype(dtype).str)
    a = d.get(key)
    if a is None:
        a = d[key] = np.empty(shape, dtype)
    return a


def _std_normal(rng: np.random.Generator, shape, out: Optional[np.ndarray] = None) -> np.ndarray:
    """Standard normal deviates, float32: 16 random bits mapped through the
    table of 2^16 equiprobable normal quantiles."""
    idx = rng.integers(0, 65536, size=shape, dtype=np.uint16)
    if out is None:
        return _normal_table()[idx]
    return np.take(_normal_table(), idx, out=out)


def _add_spot(layer: np.ndarray, u: float, v: float, sigma: float, peak: float) -> None:
    """Pixel-integrated isotropic Gaussian spot of continuous peak ``peak`` at (u, v)."""
    from scipy.special import erf     # on use, as in _normal_table

    h, w = layer.shape
    r = int(np.ceil(4 * sigma)) + 1
    x0, x1 = max(int(np.floor(u)) - r, 0), min(int(np.ceil(u)) + r, w - 1)
    y0, y1 = max(int(np.floor(v)) - r, 0), min(int(np.ceil(v)) + r, h - 1)
    if x1 < x0 or y1 < y0:
        return
    s2 = np.sqrt(2.0) * sigma
    xs = np.arange(x0, x1 + 1, dtype=np.float64)
    ys = np.arange(y0, y1 + 1, dtype=np.float64)
    px = 0.5 * (erf((xs + 0.5 - u) / s2) - erf((xs - 0.5 - u) / s2))
    py = 0.5 * (erf((ys + 0.5 - v) / s2) - erf((ys - 0.5 - v) / s2))
    total = peak * 2.0 * np.pi * sigma * sigma
    layer[y0:y1 + 1, x0:x1 + 1] += (total * py[:, None] * px[None, :]).astype(np.float32)


def _glint_targets(cam: CameraModel, positions_w: np.ndarray, count: Tuple[int, int],
                   rng: np.random.Generator):
    """How many glints to draw (from ``count`` = (min, max)) and the markers' image points (5, 2) px,
    or (0, None) when there are none or a marker is behind the camera."""
    lo, hi = count
    n = int(rng.integers(lo, hi + 1)) if hi > 0 else 0
    if n == 0:
        return 0, None
    pc = cam.to_cam(positions_w)
    if np.any(pc[:, 2] <= 0):
        return 0, None
    return n, _project_cam(cam, pc)


def _add_glints(layer: np.ndarray, cam: CameraModel, positions_w: np.ndarray, options: RenderOptions,
                rng: np.random.Generator) -> None:
    n, uv = _glint_targets(cam, positions_w, options.glints, rng)
    if n == 0:
        return
    mn, mx = uv.min(axis=0), uv.max(axis=0)
    ext = np.maximum(mx - mn, 10.0)
    mn = mn - options.glint_spread * ext
    mx = mx + options.glint_spread * ext
    for _ in range(n):
        u, v = rng.uniform(mn, mx)
        peak = rng.uniform(*options.glint_peak_dn)
        sig = rng.uniform(*options.glint_sigma_px)
        _add_spot(layer, u, v, sig, peak)


def _add_fused_glints(layer: np.ndarray, cam: CameraModel, positions_w: np.ndarray, options: RenderOptions,
                      rng: np.random.Generator) -> None:
    """Glints on the rim of a marker's blob: they pull its centroid instead of making a blob of their own."""
    n, uv = _glint_targets(cam, positions_w, options.fused_glints, rng)
    if n == 0:
        return
    for _ in range(n):
        marker = int(rng.integers(0, len(uv)))
        angle = rng.uniform(0.0, 2.0 * np.pi)
        dist = rng.uniform(*options.fused_glint_offset_px)
        peak = rng.uniform(*options.glint_peak_dn)
        sig = rng.uniform(*options.glint_sigma_px)
        _add_spot(layer, uv[marker, 0] + dist * np.cos(angle), uv[marker, 1] + dist * np.sin(angle), sig, peak)


def _add_lamps(layer: np.ndarray, cam: CameraModel, options: RenderOptions) -> None:
    h, w = layer.shape
    for lamp in options.lamps:
        c = cam.to_cam(np.asarray(lamp.position_mm, float))
        if c[2] <= 0 or np.hypot(c[0] / c[2], c[1] / c[2]) > 0.98 * cam.r_max:
            continue
        u, v = _project_cam(cam, c)[0]
        rad = max(float(cam.K[0, 0] * lamp.radius_mm / np.linalg.norm(c)), 1.0)
        ext = int(np.ceil(3.5 * rad)) + 2
        x0, x1 = max(int(u) - ext, 0), min(int(u) + ext, w - 1)
        y0, y1 = max(int(v) - ext, 0), min(int(v) + ext, h - 1)
        if x1 < x0 or y1 < y0:
            continue
        xs = np.arange(x0, x1 + 1, dtype=np.float32) - np.float32(u)
        ys = np.arange(y0, y1 + 1, dtype=np.float32) - np.float32(v)
        r = np.sqrt(xs[None, :] ** 2 + ys[:, None] ** 2)
        core = np.clip(rad + 0.5 - r, 0.0, 1.0)
        halo = lamp.halo * np.exp(-0.5 * (r / rad) ** 2)
        layer[y0:y1 + 1, x0:x1 + 1] += np.float32(lamp.peak_dn) * (core + halo).astype(np.float32)


def _add_reflectors(layer: np.ndarray, cam: CameraModel, cam_index: int, pose_fn: PoseFn, t: float,
                    options: RenderOptions) -> None:
    """Draw ``options.reflectors`` (:class:`Reflector`) as seen by one camera at its time t into ``layer``."""
    h, w = layer.shape
    S = 4
    sigma = float(options.blur_sigma_px)
    pad = int(np.ceil(4.0 * sigma)) + 1 if sigma > 0 else 0
    for ref in options.reflectors:
        c = cam.to_cam(ref.world_position(pose_fn, t))
        d = float(np.linalg.norm(c))
        if c[2] <= 1.0 or np.hypot(c[0] / c[2], c[1] / c[2]) > 0.98 * cam.r_max:
            continue
        u, v = _project_cam(cam, c)[0]
        rad = float(cam.K[0, 0]) * float(ref.radius_mm) / d
        L = ref.peak_dn_at_ref * (ref.right_gain if cam_index == 1 else 1.0) * (options.d_ref_mm / d) ** 2
        ext = int(np.ceil(rad)) + pad + 1
        x0, y0 = int(np.floor(u)) - ext, int(np.floor(v)) - ext
        n = 2 * ext + 2
        if x0 + n <= 0 or y0 + n <= 0 or x0 >= w or y0 >= h:
            continue
        # sub-pixel cell centres of the patch, relative to the blob's centre
        g = (np.arange(n * S, dtype=np.float64) + 0.5) / S - 0.5
        xs, ys = x0 + g - u, y0 + g - v
        r = np.sqrt(xs[None, :] ** 2 + ys[:, None] ** 2)
        cov = np.clip((rad - r) * S + 0.5, 0.0, 1.0).astype(np.float32)   # anti-aliased edge, one cell wide
        if sigma > 0:
            ks = _gauss_kernel_size(sigma * S)
            cov = cv2.GaussianBlur(cov, (ks, ks), sigma * S, borderType=cv2.BORDER_CONSTANT)
        patch = np.float32(L) * _area_down(cov, S)
        cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x0 + n, w), min(y0 + n, h)
        layer[cy0:cy1, cx0:cx1] += patch[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]


@functools.lru_cache(maxsize=16)
def _std_table(gain: Optional[float], read_noise: float) -> np.ndarray:
    """Noise sigma (DN) as a function of the signal level 0..255 DN, (1, 256) float32."""
    lvl = np.arange(256, dtype=np.float64)
    var = np.full(256, float(read_noise) ** 2)
    if gain:
        var += lvl / float(gain)
    return np.sqrt(var).astype(np.float32).reshape(1, 256)


def _sensor(signal: np.ndarray, options: RenderOptions, rng: np.random.Generator) -> np.ndarray:
    """Add shot and read noise to the expected signal (DN, float32), in place.

    Gaussian mode: ``signal + sqrt(signal / gain + read²) * N(0, 1)``, the
    sigma looked up from the signal rounded to 0..255 DN (saturated pixels
    are clipped anyway).  Poisson mode: ``Poisson(signal * gain) / gain +
    read * N(0, 1)``.  Returns ``signal``.
    """
    if not options.noise:
        return signal
    g = options.gain_e_per_dn
    if options.shot_noise not in ("gaussian", "poisson"):
        raise ValueError(f"shot_noise must be 'gaussian' or 'poisson', not {options.shot_noise!r}")
    shape = signal.shape
    noise = _std_normal(rng, shape, out=_workspace("noise", shape))
    if options.shot_noise == "poisson" and g:
        e = rng.poisson(np.maximum(signal, 0.0).astype(np.float64) * g)
        signal[...] = e / g
        signal += np.float32(options.read_noise_dn) * noise
        return signal
    level = cv2.convertScaleAbs(cv2.max(signal, 0.0, dst=_workspace("tmp", shape)),
                                dst=_workspace("level", shape, np.uint8))
    std = cv2.LUT(level, _std_table(g, float(options.read_noise_dn)), dst=_workspace("std", shape))
    cv2.multiply(std, noise, dst=noise)
    cv2.add(signal, noise, dst=signal)
    return signal


def _to_u8(img: np.ndarray) -> np.ndarray:
    """Round to the nearest integer and clip to [0, 255], uint8 (a new array)."""
    return cv2.convertScaleAbs(cv2.max(img, 0.0, dst=_workspace("tmp", img.shape)))


# ----------------------------------------------------------------------------
# public entry points
# ----------------------------------------------------------------------------

def _sub_times(t: float, options: RenderOptions) -> list:
    n = max(int(options.motion_samples), 1)
    e = float(options.exposure_s)
    if e <= 0.0 or n == 1:
        return [float(t)]
    return [float(t) + ((k + 0.5) / n - 0.5) * e for k in range(n)]


def render_signal(cam: CameraModel, cam_index: int, model_points_mm: np.ndarray, diameter_mm: float,
                  pose_fn: PoseFn, t: float, options: RenderOptions,
                  rng: Optional[np.random.Generator] = None, out: Optional[np.ndarray] = None) -> np.ndarray:
    """Expected (noise-free) image of one camera at its time ``t``, float32 DN.

    Background, markers, lamps, reflectors and (when ``rng`` is given) glints; no noise,
    no rounding.  See :func:`render_pair` for the other parameters.

    Parameters
    ----------
    cam : the camera (:func:`rig_cameras`).
    cam_index : 0 (left) or 1 (right): selects the ambient pattern and the
        occlusions.
    out : optional (h, w) float32 array to render into.

    Returns
    -------
    (h, w) float32 array.
    """
    w, h = cam.size
    layer = np.empty((h, w), np.float32) if out is None else out
    if options.ambient_dn or options.ambient_variation_dn:
        np.copyto(layer, _ambient(w, h, float(options.ambient_dn), float(options.ambient_variation_dn),
                                  int(options.ambient_seed), cam_index))
    else:
        layer.fill(0.0)
    readout = options.readout_for(cam_index)
    _render_markers_into(layer, cam, cam_index, model_points_mm, diameter_mm, pose_fn,
                         _sub_times(t, options), options, readout)
    if options.lamps:
        _add_lamps(layer, cam, options)
    if options.reflectors:
        _add_reflectors(layer, cam, cam_index, pose_fn, float(t), options)
    if rng is not None and (options.glints[1] > 0 or options.fused_glints[1] > 0):
        if readout > 0.0 and h > 1:   # each marker where its (sheared) image is: at its own row's time
            pw = _RowClock(cam, np.asarray(model_points_mm, float).reshape(5, 3), pose_fn, h, readout,
                           0.5 * float(diameter_mm), options, set()).marker_positions(float(t))
        else:
            Rwg, p1 = pose_fn(t)
            pw = np.asarray(model_points_mm, float) @ np.asarray(Rwg, float).T + np.asarray(p1, float)
        _add_glints(layer, cam, pw, options, rng)
        _add_fused_glints(layer, cam, pw, options, rng)
    return layer


def _mjpeg(img: np.ndarray, quality: int) -> np.ndarray:
    """An 8-bit image through a JPEG encoder and decoder (grayscale, libjpeg quality ``quality``)."""
    ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"JPEG encoding failed (quality {quality})")
    return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)


def _render_views(setup_or_rig, model_points_mm, diameter_mm, pose_fn, t, options, rng, convert, jpeg=False):
    options = RenderOptions() if options is None else options
    rng = np.random.default_rng(0) if rng is None else rng
    cams = rig_cameras(setup_or_rig)
    out = []
    for ci, cam in enumerate(cams):
        tc = float(t) + (options.right_time_offset_s if ci == 1 else 0.0)
        w, h = cam.size
        sig = render_signal(cam, ci, model_points_mm, diameter_mm, pose_fn, tc, options, rng,
                            out=_workspace("signal", (h, w)))
        img = convert(_sensor(sig, options, rng))
        if jpeg and options.jpeg_quality is not None:
            img = _mjpeg(img, options.jpeg_quality)
        out.append(img)
    return out[0], out[1]


def render_pair_float(setup_or_rig, model_points_mm: np.ndarray, diameter_mm: float, pose_fn: PoseFn,
                      t: float, options: Optional[RenderOptions] = None,
                      rng: Optional[np.random.Generator] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Like :func:`render_pair` but returns the float32 images (DN) before
    rounding and clipping (with noise when ``options.noise``).  For the same
    ``rng`` state, ``render_pair`` output is these images rounded and clipped
    (and, with ``options.jpeg_quality``, through the JPEG codec)."""
    return _render_views(setup_or_rig, model_points_mm, diameter_mm, pose_fn, t, options, rng, np.copy)


def render_pair(setup_or_rig, model_points_mm: np.ndarray, diameter_mm: float, pose_fn: PoseFn,
                t: float, options: Optional[RenderOptions] = None,
                rng: Optional[np.random.Generator] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Render one synthetic IR stereo pair.

    Parameters
    ----------
    setup_or_rig : :class:`synthetic.setups.Setup`, rig mapping/object or
        path to a ``rig.yaml`` (see :func:`rig_cameras`).
    model_points_mm : (5, 3) marker model P0..P4 in G, mm.
    diameter_mm : marker disk diameter, mm.
    pose_fn : ``pose_fn(t) -> (R_world_from_G (3, 3), p1_world_mm (3,))``,
        t in seconds.  Called at the sub-exposure times (motion blur) and at
        ``t + right_time_offset_s`` for the right image; with a rolling
        shutter (``readout_s``) also at each image row's time.
    t : time of the left image (mid-exposure), s.
    options : :class:`RenderOptions` (defaults when None).
    rng : ``np.random.Generator`` for noise and glints (``default_rng(0)``
        when None).  Left is drawn before right, so a seeded generator gives
        identical images.

    Returns
    -------
    (left, right) : uint8 arrays of shape (h, w).
    """
    return _render_views(setup_or_rig, model_points_mm, diameter_mm, pose_fn, t, options, rng, _to_u8, jpeg=True)
