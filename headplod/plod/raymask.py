"""Murphy & Duchowski's CSF-derived ray mask (2009, §3.1), pure numpy.

The hybrid renderer (:mod:`headplod.render.raymask`) casts rays only through
the pixels of a *ray mask*: every pixel of a filled inset around the point of
regard (POI), and outside it concentric rings of samples whose radial spacing
follows the CSF's cutoff, connected into quad strips.

Construction (the paper's, with the project's CSF forms and uncertainty):

1. **Spacing against eccentricity.** Sampling every ``n`` pixels gives
   ``ppd / n`` samples per degree, which carries frequencies up to
   ``ppd / (2 n)`` cpd (Nyquist). The spacing at eccentricity ``e`` is the
   largest integer ``n`` in ``1..max_spacing_px`` with
   ``2 f_c(e) <= ppd / n``, i.e. ``n(e) = clip(floor(ppd / (2 f_c(e))), 1,
   max_spacing_px)``; ``f_c`` is Geisler & Perry's cutoff
   (:func:`headplod.plod.csf.gp_cutoff_cpd`, ``csf_model="gp"``) or the
   highest visible frequency of a Kelly form
   (:func:`headplod.plod.csf.max_visible_freq_cpd` at the speed floor). The
   thresholds ``T_n`` (where spacing ``n`` starts) are where
   ``f_c(T_n) = ppd / (2 n)``.
2. **The 1-D array** of radii, px from the POI: the filled inset out to
   ``r_fill = max(T_2, inset_deg / 2)`` (every pixel), then ring radii
   ``r_{k+1} = r_k + n(r_k)`` (every integer up to the first threshold, every
   second to the next, ..., as the paper builds it) until the farthest image
   corner is passed.
3. **Rotation.** Every ring gets the same ``M`` samples, as the paper
   rotates its array by one angular step. The paper's step is the
   separation of the two outermost entries; here it is the smallest
   ``n_k / r_k`` over the rings, ``M = ceil(2π max_k r_k / n_k)``, so that
   no ring is sparser along its circle than across (the outermost pair's
   step leaves the middle bands up to 1.4x too sparse, the spacing growing
   more slowly than the radius). Consecutive rings and angles form quads
   (quad strips around the POI).
4. **Uncertainty.** The radii are eccentricities *after* the shift of
   :func:`headplod.plod.perception.uncertainty_shift` (``form="ellipse"``),
   the one ``csf`` uses: a point at offset ``P`` from the POI is treated as
   if it were at ``P (1 - n_sigma / sqrt(Pᵀ Σ⁻¹ P))``. Mapping each ring
   sample back through the exact inverse pushes it out by the ellipse's
   radius in its direction, and the filled inset becomes every pixel whose
   shifted eccentricity is ``<= r_fill``: the ``n_sigma`` ellipse dilated by
   the inset. Eccentricities are angles seen from the eye
   (:func:`headplod.plod.perception.eccentricity_deg` of
   :func:`headplod.plod.perception.view_offsets_deg`), not pixel distances;
   the 1-D array is laid out in degrees at ``px_per_deg`` px/deg.

Frames and units: image pixels, x right, y down, (0, 0) the centre of the
top-left pixel (``docs/contract.md``); the image covers the screen's visible
area (image pixel column ``floor(x W_img / W_screen)`` holds screen pixel x).
World frame mm, angles deg.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import cv2
import numpy as np

from . import perception as pc
from .csf import CSF_MODELS, MIN_SPEED_DEG_S, gp_cutoff_cpd, max_visible_freq_cpd
from .view import head_axes
from ..tol import tol

__all__ = ["RAYMASK_CSF_MODELS", "RayMaskConfig", "RayMask", "spacing_thresholds_deg", "spacing_px",
           "radii_deg", "pixel_offsets_deg", "offsets_to_pixels", "build_ray_mask",
           "HeightGrid", "height_grid"]

#: CSF forms the mask can follow: Geisler–Perry (the paper's) and the Kelly forms of :mod:`headplod.plod.csf`.
RAYMASK_CSF_MODELS = ("gp",) + tuple(CSF_MODELS)


@dataclass(frozen=True)
class RayMaskConfig:
    """Settings of the ray mask and the hybrid renderer, each with its unit.

    Attributes
    ----------
    inset_deg : float
        Diameter of the filled full-resolution inset around the POI, deg
        (5.0; the paper's experiment: 2, 5, 10, 15, 20°), 0..30. The inset
        is filled out to the larger of its radius and where the CSF first
        allows a spacing of 2 px.
    csf_model : str
        ``"gp"`` (Geisler & Perry, the paper's; default) or a Kelly form of
        :data:`headplod.plod.csf.CSF_MODELS`.
    contrast : float
        Michelson contrast the spacing is chosen for, (0, 1] (1.0: the
        paper's "most conservative form").
    max_spacing_px : int
        Largest spacing between samples, px (17, the paper's ``n ∈ 1..17``), 1..64.
    n_sigma : float
        The POI's uncertainty ellipse that gets full density, standard
        deviations (2.0), >= 0.
    silhouettes : bool
        Cast every pixel of the quads that straddle a silhouette (True), as
        in the paper's "edges preserved" condition.
    depth_ratio : float
        A quad whose corners all hit but whose farthest hit is more than
        ``1 + depth_ratio`` times as far from the eye as its nearest straddles
        a nearer ridge in front of a farther slope: it is a silhouette quad
        too (0.05), > 0.
    """

    inset_deg: float = 5.0
    csf_model: str = "gp"
    contrast: float = 1.0
    max_spacing_px: int = 17
    n_sigma: float = 2.0
    silhouettes: bool = True
    depth_ratio: float = 0.05

    def __post_init__(self):
        def number(name, ok, text):
            v = getattr(self, name)
            if not (isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and ok(v)):
                raise ValueError(f"RayMaskConfig.{name} must be {text}, got {v!r}")
        number("inset_deg", lambda v: 0 <= v <= 30, "a number of degrees in 0..30")
        number("contrast", lambda v: 0 < v <= 1, "a Michelson contrast in (0, 1]")
        number("n_sigma", lambda v: v >= 0, "a number of standard deviations >= 0")
        number("depth_ratio", lambda v: v > 0, "a ratio > 0")
        if self.csf_model not in RAYMASK_CSF_MODELS:
            raise ValueError(f"RayMaskConfig.csf_model must be one of {RAYMASK_CSF_MODELS}, got {self.csf_model!r}")
        n = self.max_spacing_px
        if not (isinstance(n, numbers.Integral) and not isinstance(n, bool) and 1 <= n <= 64):
            raise ValueError(f"RayMaskConfig.max_spacing_px must be an integer 1..64 (px), got {n!r}")
        if not isinstance(self.silhouettes, (bool, np.bool_)):
            raise ValueError(f"RayMaskConfig.silhouettes must be True or False, got {self.silhouettes!r}")


def _cutoff_cpd(ecc_deg, config: RayMaskConfig) -> np.ndarray:
    """f_c(e), cpd, of the config's CSF at its contrast (the speed floor for the Kelly forms)."""
    if config.csf_model == "gp":
        return gp_cutoff_cpd(config.contrast, ecc_deg)
    return max_visible_freq_cpd(config.contrast, MIN_SPEED_DEG_S, ecc_deg, model=config.csf_model)


def spacing_thresholds_deg(px_per_deg: float, config: RayMaskConfig = RayMaskConfig()) -> np.ndarray:
    """Eccentricities where each spacing starts, deg, (max_spacing_px + 1,).

    Entry ``n`` (2..max_spacing_px) is ``T_n``, the smallest eccentricity
    with ``2 f_c(e) <= ppd / n`` (0 where already true at the fovea, inf
    where never true below 180°); entries 0 and 1 are 0 (one pixel is the
    finest spacing). ``f_c`` falls with ``e``
    for every form, so the thresholds are found by bisection (64 halvings).
    """
    ppd = float(px_per_deg)
    if not (math.isfinite(ppd) and ppd > 0):
        raise ValueError(f"spacing_thresholds_deg: px_per_deg must be > 0, got {px_per_deg!r}")
    n = np.arange(1, config.max_spacing_px + 1, dtype=np.float64)
    need = ppd / (2.0 * n)                                 # the highest frequency spacing n carries, cpd
    lo, hi = np.zeros_like(n), np.full_like(n, 180.0)
    ok_lo = 2.0 * _cutoff_cpd(lo, config) <= ppd / n
    ok_hi = 2.0 * _cutoff_cpd(hi, config) <= ppd / n
    for _ in range(64):                                    # bisection, all thresholds at once
        mid = 0.5 * (lo + hi)
        ok = _cutoff_cpd(mid, config) <= need
        hi = np.where(ok, mid, hi)
        lo = np.where(ok, lo, mid)
    t = np.where(ok_lo, 0.0, np.where(ok_hi, hi, np.inf))
    t[0] = 0.0                                             # one pixel is the finest spacing there is
    return np.concatenate([[0.0], t])


def spacing_px(ecc_deg, px_per_deg: float, config: RayMaskConfig = RayMaskConfig()) -> np.ndarray:
    """Sample spacing allowed at eccentricities, px (int64, same shape): ``clip(floor(ppd / (2 f_c(e))), 1, max)``.

    Computed from the thresholds (so it agrees with :func:`radii_deg` to the
    last bit): the largest ``n`` with ``T_n <= e``.
    """
    t = spacing_thresholds_deg(px_per_deg, config)[1:]
    e = np.asarray(ecc_deg, dtype=np.float64)
    return np.maximum(np.searchsorted(t, e, side="right"), 1).astype(np.int64)


def radii_deg(px_per_deg: float, max_ecc_deg: float, config: RayMaskConfig = RayMaskConfig()):
    """The paper's 1-D array: the fill radius and the ring radii, deg of (shifted) eccentricity.

    Returns
    -------
    r_fill_deg : float
        Every pixel whose shifted eccentricity is at most this is cast:
        ``max(T_2, inset_deg / 2)``.
    rings_deg : (R,) float64
        Ring radii: ``r_0 = r_fill``, ``r_{k+1} = r_k + n(r_k) / ppd``, up to
        the first radius ``>= max_ecc_deg`` (included, so the rings cover it).
    spacing : (R,) int64
        ``n(r_k)``, px: the radial step from ring k to ring k + 1.
    """
    ppd = float(px_per_deg)
    t = spacing_thresholds_deg(ppd, config)
    r_fill = max(float(t[2]) if len(t) > 2 else math.inf, 0.5 * config.inset_deg)
    if not math.isfinite(r_fill):               # spacing 1 everywhere: the fill covers everything asked
        r_fill = float(max_ecc_deg)
    # Segments [T_n, T_{n+1}) with step n px, built per spacing (<= 64 segments), in px then deg.
    thresholds_px = np.append(t[1:], np.inf) * ppd
    start = r_fill * ppd
    stop = max(float(max_ecc_deg), r_fill) * ppd
    radii, steps = [np.array([start])], []
    r = start
    for n in range(1, config.max_spacing_px + 1):              # loop over spacings, not samples
        end = thresholds_px[n] if n < config.max_spacing_px else np.inf   # where spacing n + 1 starts
        if r >= end:
            continue
        if r >= stop:
            break
        # Steps of n from r while the step starts before `end` and the radius has not yet passed `stop`.
        last = min(end, stop)
        k = int(np.ceil((last - r) / n - tol.zero))
        k = max(k, 1)
        seg = r + n * np.arange(1, k + 1, dtype=np.float64)
        radii.append(seg)
        steps.append(np.full(k, n, np.int64))
        r = float(seg[-1])
    rings = np.concatenate(radii) / ppd
    spacing = np.concatenate(steps + [np.array([steps[-1][-1] if steps else 1])])
    return r_fill, rings, spacing


def _image_to_screen(xy_img, size, screen):
    """Image px (centre-of-pixel origin) → screen px (corner origin), (..., 2)."""
    scale = np.array(screen.size_px, dtype=np.float64) / np.array(size, dtype=np.float64)
    return (np.asarray(xy_img, dtype=np.float64) + 0.5) * scale


def pixel_offsets_deg(xy_img, screen, eye_mm, axes, size) -> np.ndarray:
    """(φ, θ) of image pixels about the gaze, deg, (..., 2): :func:`perception.view_offsets_deg` of their screen points."""
    points = screen.pixel_to_world(_image_to_screen(xy_img, size, screen))
    return pc.view_offsets_deg(points, eye_mm, axes)


def offsets_to_pixels(offset_deg, screen, eye_mm, axes, size) -> np.ndarray:
    """Image px (..., 2) of gaze offsets (φ, θ), deg (..., 2): the inverse of :func:`pixel_offsets_deg`.

    The direction ``(tan θ, tan φ, 1)`` in the head frame meets the screen
    plane; its screen px go to image px.
    """
    p = np.radians(np.asarray(offset_deg, dtype=np.float64))
    d_head = np.stack([np.tan(p[..., 1]), np.tan(p[..., 0]), np.ones(p.shape[:-1])], axis=-1)
    d = d_head @ np.asarray(axes, dtype=np.float64)                     # rows Ξ, Ψ, V: head → world
    tl = np.asarray(screen.top_left, float)
    a = np.asarray(screen.top_right, float) - tl
    b = np.asarray(screen.bottom_left, float) - tl
    normal = np.cross(a, b)
    eye = np.asarray(eye_mm, dtype=np.float64)
    s = ((tl - eye) @ normal) / (d @ normal)
    q = eye + s[..., None] * d - tl
    # Solve q = x a + y b in the screen plane (a, b need not be orthogonal).
    g = np.array([[a @ a, a @ b], [a @ b, b @ b]])
    rhs = np.stack([q @ a, q @ b], axis=-1)
    xy01 = rhs @ np.linalg.inv(g).T
    xy_screen = xy01 * np.array(screen.size_px, dtype=np.float64)
    return xy_screen * np.array(size, dtype=np.float64) / np.array(screen.size_px, dtype=np.float64) - 0.5


def _ellipse_radius_deg(directions, cov_deg2, n_sigma) -> np.ndarray:
    """Radius of the n-σ ellipse of ``cov`` along unit (φ, θ) directions (..., 2), deg (0 without a covariance).

    The exact inverse of ``uncertainty_shift(form="ellipse")`` along a
    direction ``u``: ``P = P' + (n / sqrt(uᵀ Σ⁻¹ u)) u``. A direction with a
    component along a zero-variance axis gets 0 (as the shift's factor is 1 there).
    """
    u = np.asarray(directions, dtype=np.float64)
    if cov_deg2 is None or n_sigma == 0:
        return np.zeros(u.shape[:-1])
    S = np.asarray(cov_deg2, dtype=np.float64)
    S = 0.5 * (S + S.T)
    lam, U = np.linalg.eigh(S)
    if lam.max() <= 0:
        return np.zeros(u.shape[:-1])
    pos = lam > tol.zero * lam.max()
    proj = u @ U
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(pos, proj ** 2 / np.where(pos, lam, 1.0), np.where(np.abs(proj) < tol.zero, 0.0, np.inf))
        q = terms.sum(axis=-1)
        return np.where(np.isfinite(q) & (q > 0), n_sigma / np.sqrt(q), 0.0)


@dataclass(frozen=True)
class RayMask:
    """A ray mask for one view.

    Attributes
    ----------
    samples_px : (N, 2) float64
        Where rays are cast, image px (x right, y down, (0, 0) the centre
        of the top-left pixel): first the ``n_fill`` filled-inset pixel
        centres (integers), then the ring samples, ring by ring
        (``ring_of`` says which), only those of quads that touch the image.
    n_fill : int
        Samples of the filled inset.
    quads : (Q, 4) int64
        Quad strips between consecutive rings, as rows of ``samples_px``:
        (ring k, angle m), (ring k, angle m+1), (ring k+1, angle m+1),
        (ring k+1, angle m): counter-clockwise seen on the image (y down).
    ring_of : (N,) int64
        Ring of each sample, -1 for the fill.
    angle_of : (N,) int64
        Angle index (0..n_angles-1) of each sample, -1 for the fill.
    spacing_of : (N,) int64
        The CSF spacing at each sample, px (1 in the fill).
    r_fill_deg : float
        Shifted eccentricity out to which every pixel is cast, deg.
    rings_deg : (R,) float64
        Radii of the rings, shifted eccentricity, deg.
    ring_spacing_px : (R,) int64
        Radial step from each ring to the next, px.
    n_angles : int
        Samples per ring (before dropping those off the image).
    ellipse_deg : (M, 2) float64
        The n-σ ellipse's boundary at each ring angle, (φ, θ) deg about the
        gaze (zeros without a covariance).
    px_per_deg : float
    """

    samples_px: np.ndarray
    n_fill: int
    quads: np.ndarray
    ring_of: np.ndarray
    angle_of: np.ndarray
    spacing_of: np.ndarray
    r_fill_deg: float
    rings_deg: np.ndarray
    ring_spacing_px: np.ndarray
    n_angles: int
    ellipse_deg: np.ndarray
    px_per_deg: float

    @property
    def fill_px(self) -> np.ndarray:
        """(n_fill, 2) int64 pixel centres of the filled inset."""
        return self.samples_px[:self.n_fill].astype(np.int64)


def _shifted_ecc(offsets, cov_deg2, n_sigma):
    shifted = pc.uncertainty_shift(offsets, cov_deg2, "ellipse", n_sigma) if cov_deg2 is not None else offsets
    return pc.eccentricity_deg(shifted)


def build_ray_mask(screen, eye_mm, poi_px, size, px_per_deg: float, cov_deg2=None,
                   config: RayMaskConfig = RayMaskConfig()) -> RayMask:
    """The ray mask of one view (module notes).

    Parameters
    ----------
    screen : headplod.io.Screen
    eye_mm : (3,) array_like
        The eye, world frame, mm.
    poi_px : (2,) array_like
        The POI, screen px (corner origin, as the tracker reports it).
    size : (2,) int
        Image (width, height), px.
    px_per_deg : float
        Image px per degree at the POI (the 1-D array's scale), > 0.
    cov_deg2 : (2, 2) array_like or None
        Covariance of the gaze's (φ, θ), deg² (docs/contract.md); its
        ``n_sigma`` ellipse gets full density.
    config : RayMaskConfig

    Returns
    -------
    RayMask
    """
    w, h = (int(v) for v in size)
    if w <= 0 or h <= 0:
        raise ValueError(f"build_ray_mask: size must be positive (width, height), got {size!r}")
    if cov_deg2 is not None:
        cov_deg2 = np.asarray(cov_deg2, dtype=np.float64)
        if cov_deg2.shape != (2, 2) or not np.isfinite(cov_deg2).all():
            raise ValueError(f"build_ray_mask: cov_deg2 must be a finite (2, 2) matrix, got shape {cov_deg2.shape}")
    eye = np.asarray(eye_mm, dtype=np.float64)
    view = (screen, eye, head_axes(screen, eye, poi_px), (w, h))
    ppd = float(px_per_deg)
    r_fill, rings, steps = radii_deg(ppd, _ring_reach_deg(view, ppd, cov_deg2, config), config)
    ring_xy, r_ell, u0 = _ring_samples(view, rings, steps, ppd, cov_deg2, config)
    R, M = ring_xy.shape[:2]
    quads, keep = _quads_near_image(ring_xy, steps, (w, h))
    fill = _fill_pixels(view, ring_xy[0], r_fill, cov_deg2, config)
    n_fill = len(fill)
    remap = np.full(R * M, -1, np.int64)
    remap[keep] = n_fill + np.arange(len(keep))
    samples = np.concatenate([fill, ring_xy.reshape(-1, 2)[keep]])
    ring_of = np.concatenate([np.full(n_fill, -1, np.int64), keep // M])
    angle_of = np.concatenate([np.full(n_fill, -1, np.int64), keep % M])
    spacing_of = np.concatenate([np.ones(n_fill, np.int64), steps[keep // M]])
    return RayMask(samples_px=samples, n_fill=n_fill, quads=remap[quads], ring_of=ring_of, angle_of=angle_of,
                   spacing_of=spacing_of, r_fill_deg=float(r_fill), rings_deg=rings,
                   ring_spacing_px=steps, n_angles=M, ellipse_deg=r_ell[:, None] * u0, px_per_deg=ppd)


def _ring_reach_deg(view, ppd, cov_deg2, config) -> float:
    """How far the rings must reach, shifted eccentricity deg: the image corners' and edge midpoints', plus a step.

    ``view``: (screen, eye (3,) world mm, head axes (3, 3), image (w, h) px).
    """
    screen, eye, axes, (w, h) = view
    border = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5],
                       [w / 2, -0.5], [w / 2, h - 0.5], [-0.5, h / 2], [w - 0.5, h / 2]])
    corner_ecc = _shifted_ecc(pixel_offsets_deg(border, screen, eye, axes, (w, h)), cov_deg2, config.n_sigma)
    return float(corner_ecc.max()) + config.max_spacing_px / ppd


def _ring_samples(view, rings, steps, ppd, cov_deg2, config):
    """The ring samples, image px (R, M, 2); the ellipse's radius (M,) deg and the unit direction (M, 2) of each angle.

    One angular step for every ring, the smallest n / r over them (the paper takes the outermost pair's
    separation, which leaves the rings in between sparser along the ring than the CSF asks wherever the
    spacing grows more slowly than the radius).
    """
    screen, eye, axes, size = view
    ratio = rings * ppd / np.maximum(steps, 1)
    n_angles = max(8, int(math.ceil(2 * math.pi * float(ratio.max()))))
    psi = 2 * math.pi * np.arange(n_angles) / n_angles
    # Shifted offsets P' = (φ', θ') at eccentricity e exactly: tan θ' = tan e cos ψ, tan φ' = tan e sin ψ.
    te = np.tan(np.radians(rings))[:, None]
    shifted = np.degrees(np.stack([np.arctan(te * np.sin(psi)), np.arctan(te * np.cos(psi))], axis=-1))
    # Unshift: push each sample out by the ellipse's radius in its direction.
    norm = np.linalg.norm(shifted, axis=-1, keepdims=True)
    u = shifted / np.where(norm > 0, norm, 1.0)
    u0 = np.stack([np.sin(psi), np.cos(psi)], axis=-1)        # direction of each angle (φ, θ)
    r_ell = _ellipse_radius_deg(u0, cov_deg2, config.n_sigma)  # (M,)
    offsets = shifted + r_ell[None, :, None] * u
    return offsets_to_pixels(offsets, screen, eye, axes, size), r_ell, u0


def _quads_near_image(ring_xy, steps, size):
    """The quads (Q, 4) between consecutive rings, as flat (ring k * M + angle m) rows, and the samples (K,) kept.

    Quads (k, m), (k, m+1), (k+1, m+1), (k+1, m); kept when a corner lies within a quad's size of the
    image (so every quad over an image pixel is kept); ring 0's samples near the image are kept too (it
    borders the fill).
    """
    w, h = size
    R, M = ring_xy.shape[:2]
    flat = ring_xy.reshape(-1, 2)
    reach = np.repeat(np.maximum(steps, 1) * 2.0 + 2.0, M)          # px: a generous quad size
    near = ((flat[:, 0] >= -0.5 - reach) & (flat[:, 0] <= w - 0.5 + reach)
            & (flat[:, 1] >= -0.5 - reach) & (flat[:, 1] <= h - 0.5 + reach))
    k, m = np.meshgrid(np.arange(R - 1), np.arange(M), indexing="ij")
    m1 = (m + 1) % M
    quads = np.stack([k * M + m, k * M + m1, (k + 1) * M + m1, (k + 1) * M + m], axis=-1).reshape(-1, 4)
    quads = quads[near[quads].any(axis=1)]
    used = np.zeros(R * M, bool)
    used[quads.ravel()] = True
    used[:M] |= near[:M]                                                  # ring 0 borders the fill
    return quads, np.flatnonzero(used)


def _fill_pixels(view, ring0_xy, r_fill, cov_deg2, config) -> np.ndarray:
    """(n_fill, 2) float64 pixel centres of the filled inset, row by row: every pixel whose shifted eccentricity
    is <= ``r_fill``.

    Ring 0 (``ring0_xy`` (M, 2) image px, at r_fill, its chords within 0.01 px of the curve) is
    rasterised; the pixels within a pixel of its outline are decided exactly.
    """
    screen, eye, axes, (w, h) = view
    if not np.isfinite(ring0_xy).all():
        return np.zeros((0, 2))
    fill_mask = np.zeros((h, w), np.uint8)
    poly = np.round(ring0_xy * 256).astype(np.int32)         # cv2: pixel centres at integers; 8 bits of sub-pixel
    cv2.fillPoly(fill_mask, [poly], 1, lineType=cv2.LINE_8, shift=8)
    kernel = np.ones((3, 3), np.uint8)
    inner = cv2.erode(fill_mask, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    band = cv2.dilate(fill_mask, kernel).astype(bool) & ~inner
    by, bx = np.nonzero(band)
    pix = np.stack([bx, by], axis=-1).astype(np.float64)
    ecc = _shifted_ecc(pixel_offsets_deg(pix, screen, eye, axes, (w, h)), cov_deg2, config.n_sigma)
    fy, fx = np.nonzero(inner)
    fill = np.concatenate([np.stack([fx, fy], axis=-1), pix[ecc <= r_fill].astype(np.int64)]).astype(np.float64)
    return fill[np.lexsort((fill[:, 0], fill[:, 1]))]                # row by row


# ---------------------------------------------------------------------------
# The height field the rays are cast against: the triangles of ``full``
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class HeightGrid:
    """The finest-level mesh of a grid base mesh as a regular height field.

    Cell (i, j) (column i east, row j north) has corners (i, j) .. (i+1, j+1)
    and is split along its diagonal from (i, j) to (i+1, j+1), into the
    triangles (i,j)-(i+1,j)-(i+1,j+1) and (i,j)-(i+1,j+1)-(i,j+1): exactly
    the triangles ``full`` draws (the base grid's diagonal, kept by every
    midpoint subdivision).

    Attributes
    ----------
    heights : (ny + 1, nx + 1) float32
        Vertex heights, scene units, row j, column i: the float32 values
        of the mesh's vertex table.
    normals : (ny + 1, nx + 1, 3) float32
        The table's vertex normals (the finest level's: exact).
    origin : (2,) float64
        Scene (x, y) of vertex (0, 0).
    cell : (2,) float64
        Cell size (dx, dy), scene units.
    """

    heights: np.ndarray
    normals: np.ndarray
    origin: np.ndarray
    cell: np.ndarray

    @property
    def shape_cells(self) -> tuple[int, int]:
        """(nx, ny) cells."""
        return self.heights.shape[1] - 1, self.heights.shape[0] - 1

    def max_mip(self) -> list[np.ndarray]:
        """Per level k, the highest vertex height over each 2^k x 2^k block of cells, (ny >> k, nx >> k) float32.

        Level 0 is each cell's highest corner; the last level is one block.
        Needs nx = ny = a power of two.
        """
        nx, ny = self.shape_cells
        if nx != ny or nx & (nx - 1):
            raise ValueError(f"HeightGrid.max_mip needs a square power-of-two grid, got {nx}x{ny} cells")
        h = self.heights
        level = np.maximum(np.maximum(h[:-1, :-1], h[:-1, 1:]), np.maximum(h[1:, :-1], h[1:, 1:]))
        out = [level]
        while level.shape[0] > 1:
            level = level.reshape(level.shape[0] // 2, 2, level.shape[1] // 2, 2).max(axis=(1, 3))
            out.append(level)
        return out


def height_grid(mesh) -> HeightGrid:
    """The ``full`` mesh (every face at ``max_level``) of an :class:`AdaptiveMesh` over a grid base, as a height field.

    The vertices are read from the mesh's vertex table through the indices
    ``update_indices`` gives for ``full`` (on a :meth:`AdaptiveMesh.share`,
    so the mesh's own build state is untouched) and placed on the grid by
    their (x, y); every grid vertex must be found.
    """
    base = mesh.base
    verts = base.vertices
    xs, ys = np.unique(verts[:, 0]), np.unique(verts[:, 1])
    n = 2 ** mesh.max_level
    nx, ny = (len(xs) - 1) * n, (len(ys) - 1) * n
    origin = np.array([xs[0], ys[0]])
    cell = np.array([(xs[-1] - xs[0]) / nx, (ys[-1] - ys[0]) / ny])
    indices, _ = mesh.share().update_indices(np.full(mesh.n_faces, mesh.max_level))
    rows = np.unique(indices)
    pos = mesh.vertex_positions[rows].astype(np.float64)
    i = np.rint((pos[:, 0] - origin[0]) / cell[0]).astype(np.int64)
    j = np.rint((pos[:, 1] - origin[1]) / cell[1]).astype(np.int64)
    if i.min() < 0 or j.min() < 0 or i.max() > nx or j.max() > ny:
        raise ValueError("height_grid: the mesh's vertices do not lie on a regular grid over its base")
    heights = np.full((ny + 1, nx + 1), np.nan, np.float32)
    normals = np.zeros((ny + 1, nx + 1, 3), np.float32)
    heights[j, i] = mesh.vertex_positions[rows, 2]
    normals[j, i] = mesh.vertex_normals[rows]
    if np.isnan(heights).any():
        raise ValueError(f"height_grid: {int(np.isnan(heights).sum())} grid vertices missing from the full mesh")
    return HeightGrid(heights, normals, origin, cell)
