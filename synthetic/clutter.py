"""Clutter: shiny things in a room lit by the cameras' IR lights, as 3D points both cameras see.

A user at a desk in front of two IR cameras with ring lights is not alone with the markers: a watch or a
ring on the hand at the keyboard, the chrome of a desk lamp or a headphone stand beside the screen, a
patch of retro-reflective strip on a jacket, bag or chair behind the user, the glass of a picture or a
door handle across the room, and on the glasses themselves the hinge screws, nose-pad arms and rim
highlights.  Each is a small convex or retro-reflective surface lit by a light beside the camera, so each
is a :class:`~synthetic.render.Reflector`: a 3D point, seen by both cameras where the rig's epipolar
geometry puts it.  That is what makes clutter hard for the identification: a clutter blob in one image
has a partner on the epipolar line in the other, and the pairs triangulate to real points in front of the
rig, unlike independent per-image specks (``RenderOptions.glints``), which the epipolar test removes.

:func:`place_reflectors` places ``count`` of them for a scene, seeded and deterministic; the first k
objects do not depend on ``count`` (the same stream, the same order), so a sweep over ``count`` only adds
objects.  Where and how bright (the numbers of :data:`KINDS` and :class:`ClutterSettings`):

- **Regions** (monitor frame M, mm; x_M toward the user's left, y_M down, z_M toward the user; the head
  is at z_M ≈ 550-750 mm, the cameras at z_M = 20 mm, toed in to the head, 600 mm apart, ±19° high: the
  volume both see is a wedge about the head, so a hand on the keyboard or a lamp beside the screen is out
  of one view or both): a hand raised to the face, a mug or the mouse is in front of the head (x_M ±250,
  y_M −250..80, z_M 300-560); a desk lamp, a microphone arm or a chair's chrome beside the user (|x_M|
  200-600, y_M −400..150, z_M 0.7-1.6 m); things behind the user are 1-2.6 m from the screen, across
  the room 1.8-3.5 m.
  The glasses' metal parts are in G within the frame's outline (x ±90 mm, y −45..+20 mm, up to 15 mm
  behind the markers' plane; the default markers span x ±65 mm and y −30..0 mm), at least
  ``head_gap_mm`` from every marker.
- **Image sizes and brightness** are drawn in the left image at the first frame and turned into a
  physical radius (``fx r / d``) and radiance at ``d_ref_mm`` (1/d², lit by the ring light): the image
  radius uniform in ``radius_px`` (0.9-6 px: the markers' disks are 2.4 px wide at 150 cm, ≈ 6.5 px at
  65 cm and ≈ 10 px at 40 cm, so some are smaller, some larger), the radiance log-uniform in
  ``peak_dn`` (40-600 DN for a fully covered pixel: the markers' are ≈ 37-255 DN over 40-150 cm, see
  :mod:`synthetic.render`; about a third of the draws saturate).  A specular highlight's brightness
  depends on the surface's slopes toward each camera's light: the right camera's ``right_gain`` is
  uniform in 0.8-1.25 (retro-reflective strip: 0.9-1.1, the sheeting's entrance-angle fall-off).
- **Separation** (every frame of the scene, both images): a blob's centre stays ``gap_px`` plus both
  radii away from every marker's and every other clutter blob's, inside the image by ``margin_px`` plus
  its radius, and a thing farther from the camera than the head stays outside the markers' image box
  grown by half its size plus ``head_margin_px`` (the head would hide it).  So each image shows exactly
  5 + ``count`` blobs: the tracker's detector should count them all.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence, Tuple

import numpy as np

from .render import CameraModel, Reflector, rig_cameras

__all__ = ["ClutterKind", "KINDS", "HEAD_KIND", "ClutterSettings", "place_reflectors", "reflector_image_points",
           "ClutterError"]

PoseFn = Callable[[float], Tuple[np.ndarray, np.ndarray]]


class ClutterError(ValueError):
    """The clutter asked for does not fit in the images with the separation required."""


@dataclass(frozen=True)
class ClutterKind:
    """A kind of shiny thing: where it is and how its highlight's brightness differs between the cameras.

    ``low_mm``, ``high_mm``: corners of its box in M (or in G for ``on_head``), mm; ``mirror_x``: the box
    is on either side of the screen (x_M's sign drawn); ``right_gain``: (min, max) of
    :attr:`~synthetic.render.Reflector.right_gain`; ``weight``: how often it is drawn among the room's.
    """

    name: str
    low_mm: Tuple[float, float, float]
    high_mm: Tuple[float, float, float]
    weight: float = 1.0
    mirror_x: bool = False
    right_gain: Tuple[float, float] = (0.8, 1.25)
    on_head: bool = False


#: The room's things (module docstring).
KINDS: Tuple[ClutterKind, ...] = (
    ClutterKind("watch or ring on a hand raised to the face, a mug or the mouse", (-250.0, -250.0, 300.0),
                (250.0, 80.0, 560.0), 0.25),
    ClutterKind("chrome of a desk lamp, a microphone arm or a chair beside the user", (200.0, -400.0, 700.0),
                (600.0, 150.0, 1600.0), 0.25, mirror_x=True),
    ClutterKind("retro-reflective strip on a jacket, bag or chair behind the user", (-700.0, -300.0, 1000.0),
                (700.0, 500.0, 2600.0), 0.3, right_gain=(0.9, 1.1)),
    ClutterKind("picture glass, door handle or window catch across the room", (-1200.0, -700.0, 1800.0),
                (1200.0, 300.0, 3500.0), 0.2),
)
#: The glasses' own metal: hinge screws, nose-pad arms, rim highlights (in G, mm).
HEAD_KIND = ClutterKind("spectacles' hinge screw, nose-pad arm or rim highlight", (-90.0, -45.0, -15.0),
                        (90.0, 20.0, 0.0), on_head=True)


@dataclass(frozen=True)
class ClutterSettings:
    """How clutter is drawn and kept apart (module docstring; units in the names).

    ``max_on_head``: most things on the glasses; ``head_every``: every this-many-th object is on the
    glasses (until ``max_on_head``); ``tries``: draws per object before :class:`ClutterError`.
    """

    radius_px: Tuple[float, float] = (0.9, 6.0)
    peak_dn: Tuple[float, float] = (40.0, 600.0)
    gap_px: float = 8.0
    margin_px: float = 10.0
    head_margin_px: float = 20.0
    head_gap_mm: float = 12.0
    max_on_head: int = 6
    head_every: int = 4
    tries: int = 4000


def _project_all(cam: CameraModel, x_world: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame points (..., 3), pixels (..., 2) (NaN where behind or past the one-to-one radius) and
    depths (...) of world points (..., 3) mm."""
    import cv2

    c = cam.to_cam(np.asarray(x_world, float).reshape(-1, 3))
    ok = (c[:, 2] > 150.0) & (np.hypot(c[:, 0] / np.maximum(c[:, 2], 1e-9), c[:, 1] / np.maximum(c[:, 2], 1e-9))
                              < 0.9 * cam.r_max)
    uv = np.full((len(c), 2), np.nan)
    if ok.any():
        p, _ = cv2.projectPoints(c[ok].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D)
        uv[ok] = p.reshape(-1, 2)
    shape = np.shape(x_world)[:-1]
    return c.reshape(shape + (3,)), uv.reshape(shape + (2,)), np.linalg.norm(c, axis=1).reshape(shape)


class _Views:
    """What the placement checks against: per camera and frame, the markers' image points, radii and box,
    and the clutter already placed (centres and radii)."""

    def __init__(self, setup, model_mm: np.ndarray, diameter_mm: float, pose_fn: PoseFn, times, settings):
        self.cams = rig_cameras(setup)
        self.size = np.array(setup.image_size, float)
        self.settings = settings
        self.poses = [pose_fn(float(t)) for t in times]
        self.R = np.array([np.asarray(R, float) for R, _ in self.poses])          # (F, 3, 3) world from G
        self.p = np.array([np.asarray(p, float).reshape(3) for _, p in self.poses])  # (F, 3) mm
        markers = np.einsum("fij,mj->fmi", self.R, np.asarray(model_mm, float)) + self.p[:, None, :]
        self.marker_uv, self.marker_rad, self.marker_depth, self.boxes = [], [], [], []
        for cam in self.cams:
            c, uv, d = _project_all(cam, markers)
            rad = float(cam.K[0, 0]) * 0.5 * diameter_mm / d
            self.marker_uv.append(uv)
            self.marker_rad.append(rad)
            self.marker_depth.append(c[..., 2].min(axis=1))
            lo, hi = np.nanmin(uv, axis=1), np.nanmax(uv, axis=1)
            grow = 0.5 * (hi - lo) + settings.head_margin_px
            self.boxes.append((lo - grow, hi + grow))
        self.placed_uv = [np.zeros((len(times), 0, 2)) for _ in self.cams]
        self.placed_rad = [np.zeros((len(times), 0)) for _ in self.cams]

    def world_track(self, ref: Reflector) -> np.ndarray:
        """The reflector's world position (F, 3) mm at every frame."""
        q = np.asarray(ref.position_mm, float)
        return np.einsum("fij,j->fi", self.R, q) + self.p if ref.on_head else np.tile(q, (len(self.R), 1))

    def fits(self, ref: Reflector) -> Tuple[bool, list]:
        """Whether ``ref`` keeps every separation in every frame and both images; its (uv, radius) per camera."""
        s, xw = self.settings, self.world_track(ref)
        views = []
        for ci, cam in enumerate(self.cams):
            c, uv, d = _project_all(cam, xw)
            if not np.all(np.isfinite(uv)):
                return False, []
            rad = float(cam.K[0, 0]) * ref.radius_mm / d
            if (np.any(uv < s.margin_px + rad[:, None]) or
                    np.any(uv > self.size - 1 - s.margin_px - rad[:, None])):
                return False, []
            for others, orad in ((self.marker_uv[ci], self.marker_rad[ci]), (self.placed_uv[ci], self.placed_rad[ci])):
                if others.shape[1]:
                    gap = np.linalg.norm(others - uv[:, None, :], axis=2)
                    if np.any(gap < orad + rad[:, None] + s.gap_px):
                        return False, []
            if not ref.on_head:
                behind = c[:, 2] > self.marker_depth[ci]
                lo, hi = self.boxes[ci]
                inside = np.all((uv > lo - rad[:, None]) & (uv < hi + rad[:, None]), axis=1)
                if np.any(behind & inside):
                    return False, []
            views.append((uv, rad))
        return True, views

    def add(self, views: list) -> None:
        for ci, (uv, rad) in enumerate(views):
            self.placed_uv[ci] = np.concatenate([self.placed_uv[ci], uv[:, None, :]], axis=1)
            self.placed_rad[ci] = np.concatenate([self.placed_rad[ci], rad[:, None]], axis=1)


def _draw(rng: np.random.Generator, kind: ClutterKind, views: _Views, model_mm: np.ndarray,
          settings: ClutterSettings, setup, d_ref_mm: float) -> Reflector | None:
    """One candidate of ``kind`` (None when it falls where it cannot be: too near a marker in G)."""
    q = rng.uniform(kind.low_mm, kind.high_mm)
    if kind.mirror_x and rng.random() < 0.5:
        q[0] = -q[0]
    if kind.on_head:
        if np.min(np.linalg.norm(np.asarray(model_mm, float) - q, axis=1)) < settings.head_gap_mm:
            return None
        world0 = views.R[0] @ q + views.p[0]
    else:
        q = np.asarray(setup.m_to_world(q), float)
        world0 = q
    d0 = float(np.linalg.norm(views.cams[0].to_cam(world0)))
    radius_px = rng.uniform(*settings.radius_px)
    lo, hi = np.log(settings.peak_dn)
    peak = float(np.exp(rng.uniform(lo, hi)))
    return Reflector(tuple(float(v) for v in q), radius_mm=radius_px * d0 / float(views.cams[0].K[0, 0]),
                     peak_dn_at_ref=peak * (d0 / d_ref_mm) ** 2, on_head=kind.on_head,
                     right_gain=float(rng.uniform(*kind.right_gain)), kind=kind.name)


def place_reflectors(setup, model_mm: np.ndarray, diameter_mm: float, pose_fn: PoseFn, times: Sequence[float],
                     count: int, seed: int = 0, settings: ClutterSettings = ClutterSettings(),
                     d_ref_mm: float = 800.0) -> Tuple[Reflector, ...]:
    """``count`` reflectors for a scene, each seen by both cameras as its own blob in every frame.

    Parameters
    ----------
    setup : the rig (:class:`synthetic.setups.Setup`).
    model_mm : (5, 3) marker model in G, mm; ``diameter_mm`` its disks' diameter, mm.
    pose_fn : the scene's ``pose_fn(t) -> (R_world_from_G (3, 3), p1_world_mm (3,))``.
    times : the scene's frame times, s: the separations hold at each.
    count : number of reflectors (≥ 0).
    seed : the placement's seed; the first k reflectors are the same for every ``count`` ≥ k.
    d_ref_mm : the render's ``RenderOptions.d_ref_mm`` (the reflectors' radiance is given there).

    Returns
    -------
    tuple of :class:`~synthetic.render.Reflector` (positions in the world, or in G on the glasses).

    Raises
    ------
    ClutterError
        When one of them finds no place after ``settings.tries`` draws.
    """
    if count < 0:
        raise ClutterError(f"clutter count must be ≥ 0, got {count}")
    rng = np.random.default_rng([int(seed), 0xC1A7])
    views = _Views(setup, model_mm, diameter_mm, pose_fn, times, settings)
    weights = np.array([k.weight for k in KINDS], float)
    weights /= weights.sum()
    out, on_head = [], 0
    for i in range(int(count)):
        head = i % settings.head_every == 0 and on_head < settings.max_on_head
        for _ in range(settings.tries):
            kind = HEAD_KIND if head else KINDS[int(rng.choice(len(KINDS), p=weights))]
            ref = _draw(rng, kind, views, model_mm, settings, setup, d_ref_mm)
            if ref is None:
                continue
            ok, seen = views.fits(ref)
            if ok:
                views.add(seen)
                out.append(ref)
                on_head += int(head)
                break
        else:
            raise ClutterError(f"no place for clutter object {i + 1} of {count} ({'on the glasses' if head else 'in the room'}) "
                               f"after {settings.tries} draws: fewer objects, or smaller gaps")
    return tuple(out)


def reflector_image_points(setup, reflectors: Sequence[Reflector], pose_fn: PoseFn, t: float) -> np.ndarray:
    """Where the reflectors' centres project at time t: (2, k, 2) px, left then right image (NaN: not seen)."""
    cams = rig_cameras(setup)
    xw = np.array([r.world_position(pose_fn, float(t)) for r in reflectors]).reshape(-1, 3)
    return np.stack([_project_all(cam, xw)[1] for cam in cams]) if len(xw) else np.zeros((2, 0, 2))
