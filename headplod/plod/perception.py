"""Per-triangle perceptual criteria of the perceptual level of detail (PLOD).

Everything here is pure numpy/scipy and vectorized over triangles (arrays of
shape ``(n,)`` or broadcastable ones; no Python loop over triangles). The
equations, constants and the papers' slips are gathered in
docs/plod.md; the papers are Martinez et al. (2008, PLOD with
head-pose uncertainty), Ohshima et al. (1996, gaze-directed adaptive
rendering), Wakatsuki et al. (tolerance of micro-motion) and Murphy et al.
(2009, Geisler-Perry CSF).

Units
-----
- spatial frequency ``f``: cpd, cycles per degree of visual angle;
- retinal / angular speed ``v``: deg/s;
- eccentricity ``e`` and every other angle: degrees;
- lengths: mm;
- contrast: Michelson contrast (Lmax - Lmin) / (Lmax + Lmin), dimensionless;
- levels: number of 1-to-4 subdivisions of a base triangle (0 = coarsest).

Levels, continuous and discrete
-------------------------------
Every criterion computes a *continuous* level first and then rounds it. The
rounding differs with the criterion, and :class:`Hysteresis` must be told
which one was used:

- Martinez eq. 4, ``LOD = ceil(log2(f_max / f))``: ``"ceil"``
  (:func:`lod_continuous`, :func:`lod_from_frequency`);
- screen-space error, the coarsest level whose error is within tolerance:
  ``"ceil"`` (:func:`sse_level`);
- Ohshima, the finest level whose edges are all >= r_min: ``"floor"``
  (:func:`acuity_level`).
"""
from __future__ import annotations

import numpy as np

from .csf import (CSF_MODELS, ECC_SLOPE, MIN_SPEED_DEG_S, csf_coefficients, gp_cutoff_cpd,  # noqa: F401 (re-exported)
                  eccentricity_factor, max_visible_freq_cpd, sensitivity)
from ..tol import tol
from ..angles import angle_between_deg

__all__ = [
    "CSF_MODELS", "MIN_SPEED_DEG_S", "ECC_SLOPE",
    "sensitivity", "csf_coefficients", "max_visible_freq_cpd", "gp_cutoff_cpd", "eccentricity_factor",
    "lod_continuous", "lod_from_frequency",
    "triangle_frequency_cpd", "view_offsets_deg", "eccentricity_deg",
    "uncertainty_shift",
    "acuity_factors", "combine_acuity", "r_min_mm", "acuity_level", "display_acuity_a0",
    "vergence_deg",
    "sse_level", "velocity_baseline_level",
    "Hysteresis",
]


# ---------------------------------------------------------------------------
# Martinez eq. 4: level from frequency
# ---------------------------------------------------------------------------

def lod_continuous(triangle_freq_cpd, max_freq_cpd):
    """Continuous level ``log2(f_max / f)`` before Martinez eq. 4's ceiling.

    Parameters
    ----------
    triangle_freq_cpd : array_like
        The triangle's spatial frequency f = 1 / (angular diameter), cpd.
    max_freq_cpd : array_like
        The highest visible frequency f_max, cpd (:func:`max_visible_freq_cpd`).

    Returns
    -------
    ndarray of float
        Number of frequency doublings (1-to-4 subdivisions) from f to f_max;
        -inf where f_max = 0 (nothing visible), +inf where f = 0; NaN where
        both are 0 or an input is NaN.

    :func:`headplod.plod.criteria.frequency_level` is this with the pieces'
    floors (f_max and diameter) and the level bias: every back end's rule.
    """
    f = np.asarray(triangle_freq_cpd, dtype=float)
    fm = np.asarray(max_freq_cpd, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log2(fm / f)


def lod_from_frequency(triangle_freq_cpd, max_freq_cpd, max_level):
    """Martinez eq. 4: ``LOD = ceil(log2(f_max / f))`` clamped to [0, max_level].

    One 1-to-4 subdivision halves the triangle's diameter, so doubles its
    frequency: after LOD subdivisions the sub-triangles' frequency
    f 2^LOD first reaches f_max (details finer than the eye resolves).

    Parameters
    ----------
    triangle_freq_cpd : array_like
        f = 1 / (angular diameter of the triangle's projection), cpd.
    max_freq_cpd : array_like
        f_max, cpd. 0 (nothing visible) gives level 0.
    max_level : int
        Finest level available.

    Returns
    -------
    ndarray of int
        Levels in [0, max_level], broadcast shape; NaN inputs give 0.
    """
    x = lod_continuous(triangle_freq_cpd, max_freq_cpd)
    return round_level(x, "ceil", max_level)


def round_level(x, rounding, max_level):
    """Round a continuous level to int and clamp to [0, max_level] (NaN -> 0)."""
    x = np.asarray(x, dtype=float)
    x = np.nan_to_num(x, nan=-1.0, posinf=max_level + 1.0, neginf=-1.0)
    x = np.clip(x, -1.0, max_level + 1.0)
    r = {"ceil": np.ceil, "floor": np.floor, "round": np.round}[rounding](x)
    return np.clip(r, 0, max_level).astype(int)


# ---------------------------------------------------------------------------
# Geometry of the view
# ---------------------------------------------------------------------------

def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return v / n


def triangle_frequency_cpd(vertices_mm, eye_mm):
    """Spatial frequency of triangles: 1 / (angular diameter), cpd.

    The angular diameter is the largest angle, seen from the eye, between two
    of the triangle's vertices (the diameter of its projection, Martinez §5.2).

    Parameters
    ----------
    vertices_mm : (n, 3, 3) array_like
        Triangles' vertices, mm, any frame.
    eye_mm : (3,) array_like
        Eye (or head) position in the same frame, mm.

    Returns
    -------
    (n,) ndarray
        Frequency, cpd (one cycle per triangle diameter); inf for a
        degenerate (zero-size) projection.
    """
    d = np.asarray(vertices_mm, dtype=float) - np.asarray(eye_mm, dtype=float)
    a01 = angle_between_deg(d[:, 0], d[:, 1])
    a12 = angle_between_deg(d[:, 1], d[:, 2])
    a20 = angle_between_deg(d[:, 2], d[:, 0])
    diam = np.maximum(np.maximum(a01, a12), a20)
    with np.errstate(divide="ignore"):
        return 1.0 / diam


def view_offsets_deg(points_mm, head_position_mm, axes):
    """(φ, θ) of points about the viewing direction, deg (docs/contract.md).

    Parameters
    ----------
    points_mm : (..., 3) array_like
        Points (e.g. triangle centroids), world frame, mm.
    head_position_mm : (3,) array_like
        Head position (P1), world frame, mm.
    axes : (3, 3) array_like
        Rows Ξ, Ψ, V (unit vectors, world frame).

    Returns
    -------
    (..., 2) ndarray
        (φ, θ) in deg: θ = atan2(Ξ·d, V·d) (horizontal), φ = atan2(Ψ·d, V·d)
        (vertical), d = point − head position.
    """
    d = np.asarray(points_mm, dtype=float) - np.asarray(head_position_mm, dtype=float)
    loc = d @ np.asarray(axes, dtype=float).T
    th = np.degrees(np.arctan2(loc[..., 0], loc[..., 2]))
    ph = np.degrees(np.arctan2(loc[..., 1], loc[..., 2]))
    return np.stack([ph, th], axis=-1)


def eccentricity_deg(offset_deg):
    """Eccentricity of (φ, θ) offsets: the angle from V, deg.

    Parameters
    ----------
    offset_deg : (..., 2) array_like
        (φ, θ), deg, as in :func:`view_offsets_deg` (|φ|, |θ| < 90).

    Returns
    -------
    (...,) ndarray
        atan(sqrt(tan²φ + tan²θ)), deg; ≈ |(φ, θ)| for small angles.
    """
    p = np.radians(np.asarray(offset_deg, dtype=float))
    return np.degrees(np.arctan(np.hypot(np.tan(p[..., 0]), np.tan(p[..., 1]))))


# ---------------------------------------------------------------------------
# Martinez eq. 1: uncertainty shift
# ---------------------------------------------------------------------------

SHIFT_FORMS = ("eq1", "ellipse")


def uncertainty_shift(offset_deg, cov_deg2, form="eq1", n_sigma=2.0):
    """Shift offsets toward the POI by the chance that they are the POI.

    ``form="eq1"``: Martinez eq. 1 corrected: ``P' = (1 - exp(-½ Pᵀ Σ⁻¹ P)) P``.
    ``form="ellipse"``: ``P' = max(0, 1 - n/m) P`` with ``m² = Pᵀ Σ⁻¹ P``:
    the eccentricity from the nearest gaze direction inside the ``n``-σ
    ellipse (0 inside it; outside, the offset less ``n`` standard deviations
    along its direction). Eq. 1 keeps 86% of the offset at 2σ (and 39% at
    1σ), so with a large Σ the full-detail disc does not reach the 2σ
    ellipse; the ellipse form covers it by construction and, for the
    tracker's usual σ of a few hundredths of a degree, differs from eq. 1 by
    as much.
    As printed the exponent is ``+Pᵀ Σ⁻¹ P``: then exp(...) >= 1 and the
    factor 1 - exp(...) is <= 0 everywhere, which would flip every triangle
    through the POI (and push far ones to -inf). The intent (shift toward the
    POI by the Gaussian's un-normalized density at P) needs the minus sign;
    the ½ makes it the Gaussian of covariance Σ.

    Properties: P' = 0 at the POI (P = 0); P' → P far away (at 10 σ the
    relative change is e^-50); along a ray P = t u, |P'| = (1 - e^{-q t²/2}) t
    is strictly increasing in t, so the shift never reorders triangles along
    a ray.

    Parameters
    ----------
    offset_deg : (..., 2) array_like
        P = (φ, θ) of each triangle's projection about the reported viewing
        direction, deg.
    cov_deg2 : (2, 2) array_like or None
        Σ, covariance of (φ, θ) of the true viewing direction, deg². None or
        an all-zero matrix: no uncertainty, P returned unchanged. A singular
        Σ is handled through its eigenvectors: any component of P along a
        zero-variance direction makes the quadratic form infinite (factor 1).

    Returns
    -------
    (..., 2) ndarray
        P', deg.
    """
    P = np.asarray(offset_deg, dtype=float)
    if cov_deg2 is None:
        return P.copy()
    S = np.asarray(cov_deg2, dtype=float)
    if S.shape != (2, 2):
        raise ValueError(f"cov_deg2 must be (2, 2), got {S.shape}")
    if not np.all(np.isfinite(S)):
        raise ValueError("cov_deg2 must be finite")
    S = 0.5 * (S + S.T)
    lam, U = np.linalg.eigh(S)
    lmax = lam.max()
    if lmax <= 0.0:
        return P.copy()
    pos = lam > tol.zero * lmax
    proj = P @ U                                        # (..., 2) components along eigenvectors
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(pos, proj ** 2 / np.where(pos, lam, 1.0),
                         np.where(proj == 0.0, 0.0, np.inf))
    q = terms.sum(axis=-1)
    if form == "ellipse":
        with np.errstate(divide="ignore"):
            factor = np.maximum(1.0 - n_sigma / np.sqrt(q), 0.0)
    elif form == "eq1":
        factor = -np.expm1(-0.5 * q)                    # 1 - exp(-q/2), exact for small q
    else:
        raise ValueError(f"uncertainty_shift: form must be one of {SHIFT_FORMS}, got {form!r}")
    return factor[..., None] * P


# ---------------------------------------------------------------------------
# Ohshima et al. (1996): visual acuity
# ---------------------------------------------------------------------------

def acuity_factors(theta_deg, radius_deg, speed_deg_s, dpsi_deg,
                   c1=6.2, c2=180.0, c3=0.62, b=0.0):
    """Ohshima's three visual-acuity factors (eqs. 1-3), each in [0, 1].

    Parameters
    ----------
    theta_deg : array_like
        θ, angle between the visual axis and the direction to the object
        (triangle) centre, deg.
    radius_deg : array_like
        α, the object's angular radius, deg: inside it k1 = 1 (no switching
        while the gaze stays on the object).
    speed_deg_s : array_like
        Δφ, the object's angular speed, deg/s.
    dpsi_deg : array_like
        Δψ = |ψ - ψ0|, difference between the object's and the fixation
        point's convergence angles, deg (:func:`vergence_deg`); abs taken.
    c1 : float
        Peripheral decay, deg (6.2: k1 = exp(-10/6.2) ≈ 0.2 at 10° for α = 0).
    c2 : float
        Speed at which k2 reaches 0, deg/s (180).
    c3 : float
        Fusional decay, deg (0.62).
    b : float
        Half-width of the fusional area, deg (0).

    Returns
    -------
    k1, k2, k3 : ndarray
        k1 = 1 for θ <= α, exp(-(θ - α)/c1) beyond (central/peripheral);
        k2 = 1 - Δφ/c2 for Δφ <= c2, else 0 (kinetic vision);
        k3 = 1 for Δψ <= b, exp(-(Δψ - b)/c3) beyond (fusion).
        Each of the broadcast shape of all inputs.
    """
    th = np.asarray(theta_deg, dtype=float)
    r = np.asarray(radius_deg, dtype=float)
    sp = np.abs(np.asarray(speed_deg_s, dtype=float))
    dp = np.abs(np.asarray(dpsi_deg, dtype=float))
    shape = np.broadcast_shapes(th.shape, r.shape, sp.shape, dp.shape)
    k1 = np.exp(-np.maximum(th - r, 0.0) / c1)
    k2 = np.clip(1.0 - sp / c2, 0.0, 1.0)
    k3 = np.exp(-np.maximum(dp - b, 0.0) / c3)
    return (np.broadcast_to(k1, shape).copy(), np.broadcast_to(k2, shape).copy(),
            np.broadcast_to(k3, shape).copy())


def combine_acuity(k1, k2, k3, a0, combine="min"):
    """Visual acuity a from the factors: eq. 4 ``min(k1,k2,k3) a0`` or eq. 5 ``k1 k2 k3 a0``.

    Parameters
    ----------
    k1, k2, k3 : array_like
        Factors in [0, 1].
    a0 : float or array_like
        Base acuity, 1/deg (:func:`display_acuity_a0`).
    combine : {"min", "product"}
        Eq. 4 (which looked better in Ohshima's tests) or eq. 5.

    Returns
    -------
    ndarray
        a, 1/deg: 1/a is the smallest detail to render, in degrees.
    """
    k1, k2, k3 = (np.asarray(k, dtype=float) for k in (k1, k2, k3))
    if combine == "min":
        k = np.minimum(np.minimum(k1, k2), k3)
    elif combine == "product":
        k = k1 * k2 * k3
    else:
        raise ValueError(f"combine must be 'min' or 'product', got {combine!r}")
    return k * np.asarray(a0, dtype=float)


def r_min_mm(acuity_per_deg, distance_mm):
    """Ohshima eq. 6: ``r_min = 2 D tan(1 / (2a))``, the angle 1/(2a) in degrees.

    Parameters
    ----------
    acuity_per_deg : array_like
        a, 1/deg (see :func:`display_acuity_a0` for why degrees).
    distance_mm : array_like
        D, distance from the eye to the object, mm.

    Returns
    -------
    ndarray
        r_min, mm: the smallest polygon edge worth rendering; inf where
        a <= 0 or 1/(2a) >= 90° (nothing is resolved).
    """
    a = np.asarray(acuity_per_deg, dtype=float)
    D = np.asarray(distance_mm, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        half = np.where(a > 0, 0.5 / np.where(a > 0, a, 1.0), np.inf)
        return np.where(half < 90.0, 2.0 * D * np.tan(np.radians(np.minimum(half, 89.0))), np.inf)


def display_acuity_a0(pixel_pitch_mm, distance_mm, detail_px=5):
    """Ohshima eq. 7: base acuity ``a0 = 1 / (2 atan(l / 2D))``, l = detail_px · pitch.

    The angle 2 atan(l/2D) is in **degrees**, so a0 is in 1/deg and 1/a0 is
    the visual angle (deg) of the smallest detail to render. Only degrees
    reproduce the paper's numbers: l = 7.85 mm at D = 1500 mm subtends 0.30°,
    a0 = 1/0.30 ≈ 3.3 (in arcmin the same detail is 18', a0 = 0.056; in
    radians a0 = 191). The same convention makes eq. 6 invert eq. 7:
    r_min(a0, D) = l. So Ohshima's "visual acuity" is not the clinical
    decimal acuity (1.0 = resolves 1 arcmin, i.e. a = 60 /deg).

    Slip in the paper: it quotes a 1.1 mm pixel (right for a 70-inch,
    1280x1024 screen) but "5 pixels, 7.85 mm, 0.3°": 7.85 mm / 5 = 1.57 mm,
    which is 0.06° at 1.5 m. With 1.1 mm pixels 5 px is 5.5 mm and a0 ≈ 4.8.
    The example a0 = 3.3 needs ``pixel_pitch_mm = 1.57``.

    Parameters
    ----------
    pixel_pitch_mm : float or array_like
        Size of a display pixel, mm.
    distance_mm : float or array_like
        Viewer-to-display distance D, mm.
    detail_px : float
        Smallest detail to render, pixels (5).

    Returns
    -------
    float or ndarray
        a0, 1/deg.
    """
    l = detail_px * np.asarray(pixel_pitch_mm, dtype=float)
    D = np.asarray(distance_mm, dtype=float)
    out = 1.0 / (2.0 * np.degrees(np.arctan(l / (2.0 * D))))
    return float(out) if np.ndim(out) == 0 else out


def acuity_level(k1, k2, k3, a0, distance_mm, edge_len_at_level_mm, combine="min",
                 return_continuous=False):
    """Ohshima §3.2: the finest level whose longest edges are all >= r_min.

    a = min(k1, k2, k3) a0 (eq. 4) or k1 k2 k3 a0 (eq. 5), in 1/deg;
    r_min = 2 D tan(1/(2a)) (eq. 6); the chosen level is the largest l with
    ``edge_len_at_level_mm[i, l] >= r_min[i]`` (Ohshima's "biggest model in
    {H_l | ∀p ∈ H_l, r(p) >= r_min}"); level 0 when no level qualifies
    (a = 0, or even the base triangle is below r_min).

    Parameters
    ----------
    k1, k2, k3 : (n,) array_like
        Acuity factors (:func:`acuity_factors`).
    a0 : float
        Base acuity, 1/deg.
    distance_mm : (n,) array_like
        D, eye-to-triangle distance, mm.
    edge_len_at_level_mm : (n, L+1) array_like
        For each triangle and level l, the smallest over the level-l
        sub-triangles of their longest edge, mm (for 1-to-4 midpoint
        subdivision: the base triangle's longest edge / 2^l).
    combine : {"min", "product"}
        Eq. 4 or eq. 5.
    return_continuous : bool
        Also return the continuous level (log-interpolated crossing of
        r_min in the edge table, assumed decreasing with l), whose floor is
        the level: feed it to ``Hysteresis(rounding="floor")``.

    Returns
    -------
    levels : (n,) ndarray of int
        In [0, L]; non-increasing with distance.
    continuous : (n,) ndarray of float, only if ``return_continuous``
    """
    E = np.atleast_2d(np.asarray(edge_len_at_level_mm, dtype=float))
    L = E.shape[1] - 1
    a = combine_acuity(k1, k2, k3, a0, combine)
    r = np.broadcast_to(r_min_mm(a, distance_mm), E.shape[:1])
    ok = E >= r[:, None]
    any_ok = ok.any(axis=1)
    last = L - np.argmax(ok[:, ::-1], axis=1)
    levels = np.where(any_ok, last, 0).astype(int)
    if not return_continuous:
        return levels
    idx = np.arange(E.shape[0])
    nxt = np.minimum(levels + 1, L)
    e_l, e_n = E[idx, levels], E[idx, nxt]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.log(e_l / r) / np.log(e_l / e_n)
    t = np.clip(np.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0 - tol.small)
    cont = np.where(any_ok & (levels < L), levels + t, levels.astype(float))
    return levels, cont


def vergence_deg(points_mm, eye_mid_mm, ipd_mm, interocular_axis=(1.0, 0.0, 0.0)):
    """Convergence angle of each point: the angle at the point between the eyes.

    Points on one Vieth-Müller circle (through both eyes) share a vergence
    angle (inscribed-angle theorem), so Δψ = |ψ(point) - ψ(fixation)| is the
    angular distance from the geometric horopter used by Ohshima's k3.

    Parameters
    ----------
    points_mm : (n, 3) array_like
        Points, mm.
    eye_mid_mm : (3,) array_like
        Midpoint between the eyes, mm, same frame.
    ipd_mm : float
        Interpupillary distance, mm (typically ~63).
    interocular_axis : (3,) array_like
        Direction of the line through both eyes, either sign (the angle does
        not depend on it): the eyes are at eye_mid ± ipd/2 · axis. Default
        the frame's x axis; in the world frame of docs/contract.md pass Ξ.

    Returns
    -------
    (n,) ndarray
        ψ, deg: ~ipd/D rad for a distant point straight ahead; 180 between
        the eyes, 0 at infinity.
    """
    p = np.atleast_2d(np.asarray(points_mm, dtype=float))
    ax = np.asarray(interocular_axis, dtype=float)
    ax = ax / np.linalg.norm(ax)
    mid = np.asarray(eye_mid_mm, dtype=float)
    e_l = mid + 0.5 * ipd_mm * ax
    e_r = mid - 0.5 * ipd_mm * ax
    return angle_between_deg(e_l - p, e_r - p)


# ---------------------------------------------------------------------------
# Screen-space error with Wakatsuki's tolerance of micro-motion
# ---------------------------------------------------------------------------

def sse_level(geometric_error_mm, distance_mm, pixels_per_radian, tolerance_px=1.0,
              speed_deg_s=None, frame_s=1.0 / 60.0, return_continuous=False):
    """Coarsest level whose projected geometric error is within tolerance.

    The error of level l, E_l (mm) at distance d (mm), subtends
    tan φ_s = E_l / d (Wakatsuki eq. 5), i.e. ``err_px = ppr · E_l / d``
    on a flat screen whose focal length is ``ppr`` pixels per radian.

    With a speed (Wakatsuki's tolerance of micro-motion, TMM, eq. 3 and 6-7):
    the movement within one frame, φ_fc = v Δt (deg), is unrecognizable and
    is subtracted from the error: tan ψ_s = max(0, tan φ_s - tan φ_fc), i.e.
    ``effective = max(0, err_px - ppr · tan(v Δt))``. Wakatsuki uses the
    component of the motion along the node's normal n (n · v_f): pass the
    speed across the contour if known; the full speed is an upper bound on
    the tolerance. Wakatsuki keeps a node while tan ψ_s < threshold (strict);
    here ``<=`` (they differ only on the boundary, and ``<=`` lets a
    zero-tolerance still accept zero error).

    Parameters
    ----------
    geometric_error_mm : (n, L+1) array_like
        Geometric (shape) error of each level, mm; level 0 coarsest, errors
        decreasing with level (for the continuous value).
    distance_mm : (n,) array_like
        Eye-to-triangle distance, mm.
    pixels_per_radian : float
        Screen focal length, px/rad (e.g. screen_width_px / (2 tan(hfov/2))).
    tolerance_px : float
        Largest acceptable error, px (1).
    speed_deg_s : (n,) array_like or None
        Angular (retinal) speed of the triangle, deg/s; None: static.
    frame_s : float
        Frame interval Δt, s (1/60, Wakatsuki's standard).
    return_continuous : bool
        Also return the continuous level (log-interpolated crossing of the
        tolerance), whose ceiling is the level: ``Hysteresis(rounding="ceil")``.

    Returns
    -------
    levels : (n,) ndarray of int
        Smallest l with effective error <= tolerance; L when none is.
        Non-increasing with distance and with speed.
    continuous : (n,) ndarray of float, only if ``return_continuous``
    """
    E = np.atleast_2d(np.asarray(geometric_error_mm, dtype=float))
    n, L1 = E.shape
    L = L1 - 1
    d = np.broadcast_to(np.asarray(distance_mm, dtype=float), (n,))
    err_px = pixels_per_radian * E / d[:, None]
    if speed_deg_s is not None:
        sp = np.broadcast_to(np.abs(np.asarray(speed_deg_s, dtype=float)), (n,))
        ang = np.radians(np.minimum(sp * frame_s, 89.0))
        move_px = pixels_per_radian * np.tan(ang)
        err_px = np.maximum(0.0, err_px - move_px[:, None])
    ok = err_px <= tolerance_px
    any_ok = ok.any(axis=1)
    levels = np.where(any_ok, np.argmax(ok, axis=1), L).astype(int)
    if not return_continuous:
        return levels
    idx = np.arange(n)
    prv = np.maximum(levels - 1, 0)
    e_p, e_l = err_px[idx, prv], err_px[idx, levels]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.log(e_p / tolerance_px) / np.log(e_p / e_l)
    t = np.clip(np.nan_to_num(t, nan=1.0, posinf=1.0, neginf=1.0), tol.small, 1.0)
    cont = np.where(any_ok & (levels > 0), prv + t, levels.astype(float))
    return levels, cont


def velocity_baseline_level(base_levels, speed_deg_s, mode="ipv", v_ref=10.0,
                            max_level=None, return_continuous=False):
    """Wakatsuki's velocity-only baselines, IPV and DPV.

    Wakatsuki et al. compare their micro-motion tolerance with two older
    criteria that apply one speed to a whole object: "inverse proportional
    to velocity" (IPV; Clark 1976, Hitchner & McGreevy 1993) and "direct
    proportional to velocity" (DPV; Funkhouser & Séquin 1993, Ohshima 1996).
    The paper gives no formula; they were tuned to TMM's mean frame time.
    Our reading, with the linear resolution 2^level as the "detail":

    - IPV: resolution ∝ 1 / (1 + v/v_ref): the level drops by
      log2(1 + v/v_ref), rounded up (ceil), so nothing changes until
      v >= v_ref, then one level per doubling of 1 + v/v_ref: detail
      inversely proportional to v at high speed and never 0. This matches
      Fig. 8's IPV, flat at low speed and then falling.
    - DPV: the resolution *reduction* is directly proportional to v:
      resolution ∝ 1 - v/v_ref (Ohshima's k2 = 1 - Δφ/c2 scaling the
      acuity, i.e. 1/r_min); the level is base + log2(1 - v/v_ref), rounded
      up, and at v >= v_ref the resolution is 0: the triangle vanishes
      (level -1, "do not draw"), DPV's "fatal disadvantage" in Fig. 8. For
      Ohshima's constant pass v_ref = 180 deg/s.

    Parameters
    ----------
    base_levels : (n,) array_like of int
        Levels without the velocity criterion.
    speed_deg_s : (n,) array_like
        Angular speed, deg/s.
    mode : {"ipv", "dpv"}
    v_ref : float
        deg/s: IPV's knee speed; DPV's vanishing speed.
    max_level : int or None
        Upper clamp (None: no clamp above).
    return_continuous : bool
        Also return the continuous levels (before ceil; -inf where vanished).

    Returns
    -------
    levels : (n,) ndarray of int
        >= 0, except -1 for triangles DPV makes vanish.
    continuous : (n,) ndarray of float, only if ``return_continuous``
    """
    base = np.asarray(base_levels, dtype=float)
    v = np.abs(np.asarray(speed_deg_s, dtype=float))
    if mode == "ipv":
        cont = base - np.log2(1.0 + v / v_ref)
        vanished = np.zeros(np.broadcast(cont, v).shape, dtype=bool)
    elif mode == "dpv":
        vanished = v >= v_ref
        with np.errstate(divide="ignore", invalid="ignore"):
            cont = base + np.log2(np.clip(1.0 - v / v_ref, 0.0, 1.0))
        vanished = np.broadcast_to(vanished, cont.shape)
    else:
        raise ValueError(f"mode must be 'ipv' or 'dpv', got {mode!r}")
    top = np.inf if max_level is None else max_level
    lv = np.clip(np.ceil(np.clip(np.nan_to_num(cont, neginf=-1.0), -1.0, None)), 0, top)
    levels = np.where(vanished, -1, lv).astype(int)
    return (levels, cont) if return_continuous else levels


# ---------------------------------------------------------------------------
# Hysteresis
# ---------------------------------------------------------------------------

class Hysteresis:
    """Per-triangle level stability: a dead band of ``margin`` levels.

    A triangle at level L owns the continuous interval that rounds to L
    (``"ceil"``: (L-1, L]; ``"floor"``: [L, L+1); ``"round"``:
    [L-½, L+½); the extreme levels own everything beyond them). It keeps L
    while the continuous level stays within ``margin`` of that interval, and
    otherwise jumps straight to the rounded value, however far (so a real
    head movement changes levels in the same frame). Noise of amplitude
    < margin around a boundary therefore never switches a triangle after the
    first frame. This addresses Martinez's finding that jitter (of the
    covariance) made peripheral triangles oscillate between levels.

    Parameters
    ----------
    n : int
        Number of triangles.
    margin : float
        Dead band, levels (0.35). 0 reproduces plain rounding.
    rounding : {"ceil", "floor", "round"}
        How the criterion turns its continuous level into a level (see the
        module notes): "ceil" for eq. 4 and :func:`sse_level`, "floor" for
        :func:`acuity_level`.

    Attributes
    ----------
    levels : (n,) ndarray of int or None
        Current levels (None before the first update).
    """

    def __init__(self, n, margin=0.35, rounding="ceil"):
        if margin < 0:
            raise ValueError("margin must be >= 0")
        if rounding not in ("ceil", "floor", "round"):
            raise ValueError(f"rounding must be 'ceil', 'floor' or 'round', got {rounding!r}")
        self.n = int(n)
        self.margin = float(margin)
        self.rounding = rounding
        self.levels = None

    def reset(self):
        """Forget the state: the next update takes the rounded levels."""
        self.levels = None

    def update(self, continuous_level, max_level, eager=None):
        """Levels for this frame.

        Parameters
        ----------
        continuous_level : (n,) array_like of float
            The criterion's continuous level (±inf allowed; NaN keeps the
            current level, or gives 0 on the first frame).
        max_level : int
            Finest level available.
        eager : (n,) array_like of bool, optional
            Triangles that refine as soon as their continuous level asks
            (the dead band holds only their coarsening): the ones near the
            POI, where a level held too coarse is seen.

        Returns
        -------
        (n,) ndarray of int
            Levels in [0, max_level] (a copy; the state is kept inside).
        """
        x = np.asarray(continuous_level, dtype=float)
        if x.shape != (self.n,):
            raise ValueError(f"expected shape ({self.n},), got {x.shape}")
        nominal = round_level(x, self.rounding, max_level)
        if self.levels is None:
            self.levels = nominal
            return self.levels.copy()
        self.levels = self._rule(x, nominal, self.levels, max_level, eager)
        return self.levels.copy()

    def update_rows(self, rows, continuous_level, max_level, eager=None):
        """Update only the triangles ``rows``; the others keep their levels (0 on the first frame).

        The same rule as :meth:`update` applied to a subset, for a selector
        that evaluates the criterion on some triangles only
        (:mod:`headplod.bench.quadtree_selector`): it must know that the others'
        continuous levels would not have moved them.

        Parameters
        ----------
        rows : (k,) array_like of int
            Triangles to update (distinct).
        continuous_level : (k,) array_like of float
            Their continuous levels.
        max_level : int
        eager : (k,) array_like of bool, optional
            As in :meth:`update`, for the rows.

        Returns
        -------
        (k,) ndarray of int
            The rows' new levels; the state of all triangles stays in :attr:`levels`.
        """
        rows = np.asarray(rows, dtype=np.int64)
        x = np.asarray(continuous_level, dtype=float)
        if x.shape != rows.shape or rows.ndim != 1:
            raise ValueError(f"expected rows (k,) and continuous levels of the same shape, got {rows.shape} "
                             f"and {x.shape}")
        nominal = round_level(x, self.rounding, max_level)
        if self.levels is None:
            self.levels = np.zeros(self.n, dtype=nominal.dtype)
            self.levels[rows] = nominal
            return nominal
        new = self._rule(x, nominal, self.levels[rows], max_level, None if eager is None else np.asarray(eager))
        self.levels[rows] = new
        return new

    def _rule(self, x, nominal, current, max_level, eager):
        """New levels from continuous ``x``, their rounding ``nominal`` and the ``current`` levels."""
        cur = np.clip(current, 0, max_level)
        c = cur.astype(float)
        if self.rounding == "ceil":
            lo, hi = c - 1.0, c
        elif self.rounding == "floor":
            lo, hi = c, c + 1.0
        else:
            lo, hi = c - 0.5, c + 0.5
        lo = np.where(cur == 0, -np.inf, lo)
        hi = np.where(cur == max_level, np.inf, hi)
        m = self.margin
        # Where ``eager``, refine at once and coarsen only past the dead band: the level is never
        # held coarser than the criterion asks (the POI moving in gets its detail in the same
        # frame), and noise smaller than the band, having refined a triangle once, cannot
        # coarsen it again. Elsewhere the band is symmetric (fewer triangles kept fine).
        up = hi + m if eager is None else np.where(np.asarray(eager, dtype=bool), hi, hi + m)
        switch = (x < lo - m) | (x > up)              # False for NaN: keep
        return np.where(switch, nominal, cur).astype(int)
