"""The PLOD level rules, each written once: a piece of terrain's continuous level, and its bound over a node.

A *piece* is what gets one level: a base triangle of the mesh
(:class:`headplod.plod.select.LevelSelector`), a tessellation patch or one
of its edges (:mod:`headplod.plod.patches`, :class:`headplod.plod.patch_tree.PatchTree`;
the GLSL of :mod:`headplod.render.tess_shaders` evaluates the same rule in
float32, its constants generated from the ones used here). Every back end
describes its pieces by the same features and calls the functions below:

- ``ecc_deg``: the eccentricity of the piece's point nearest the POI,
  after the uncertainty shift: the eccentricity of its reference point's
  shifted offsets less the angle from that point to the piece's farthest
  corner, floored at 0 (:func:`piece_eccentricity_deg`);
- ``diameter_deg``: its angular diameter seen from the eye (the largest
  angle between two of its corners): its spatial frequency is
  ``1 / diameter`` cpd;
- ``speed_deg_s``: the angular speed of its direction from the eye,
  floored at :data:`headplod.plod.csf.MIN_SPEED_DEG_S`
  (:func:`angular_speed_deg_s`);
- ``contrast``: the Michelson contrast of the shaded terrain over it;
- for the other modes, its distance (mm), edge lengths and geometric
  error per level (mm).

Then ``csf``'s continuous level is ``log2(f_max(C, v, e) · diameter)``
(Martinez eq. 4 before its ceiling, :func:`csf_level`), ``gp``'s the same
with Geisler & Perry's cutoff, and :func:`continuous_level` gives every
mode's (``acuity``, ``sse``, ``ipv``, ``dpv``, ``distance`` too), the
level bias included.

``change`` asks, per piece and per level, whether what the level removes
is visible (Luebke & Hallen 2001; Williams et al. 2003), instead of
whether the level's triangles are (:func:`change_level`):

- the *shading change*: the Michelson contrast of the displayed difference
  between the level and the finest over the piece (``change_contrast``,
  :mod:`headplod.plod.change`), at the frequency of a change that spans a
  level-ℓ triangle, 1 / (2 · its diameter) (one half cycle), against the
  CSF at the shifted eccentricity;
- the *displacement*: the level's geometric error seen from the eye, deg,
  against half a period of the highest frequency visible at the contrast
  of what moves (the piece's own shading contrast; at a silhouette, the
  contrast of the terrain against what lies behind it,
  ``silhouette_contrast``). Shading cannot show a ridge's outline moving
  against the land behind it, nor a near piece's shape; this term does.

A level is visible when either term is: its visibility is the larger of
the two, log2(contrast × sensitivity) and log2(displacement / threshold),
and the continuous level is where the finest visible level's visibility
crosses 0 (:func:`crossing_level`).

Hierarchies (a quadtree over the mesh's base grid, the patch tree) need,
per node, an upper bound of the continuous level of every piece below it:
:func:`level_bound` is the same rule evaluated at the node's smallest
eccentricity (:func:`eccentricity_bound_deg`), its largest diameter and an
f_max that bounds every contrast and speed below it (:func:`fmax_bound_cpd`,
with :func:`sup_max_visible_freq_cpd` over every speed), plus a slack far
above float rounding and far below a level.

Units: angles deg, frequencies cpd, speeds deg/s, lengths mm, levels in
doublings of frequency (one 1-to-4 subdivision, or one halving of a patch's
vertex spacing). Frames: world (mm) for points and the eye; offsets
(φ, θ) about the head frame's V (:func:`headplod.plod.view.head_axes`).
Pure numpy, vectorised over pieces (any leading shape).
"""
from __future__ import annotations

import math

import numpy as np

from . import perception as pc
from .csf import (MIN_SPEED_DEG_S, CORTICAL_EXPONENT, FREQUENCY_SCALED_MODELS, csf_coefficients,
                  eccentricity_factor, gp_cutoff_cpd, max_visible_freq_cpd, sensitivity)
from ..tol import tol

__all__ = ["CSF_MODES", "DIAMETER_FLOOR_DEG", "FMAX_FLOOR_CPD", "ANGLE_SLACK_DEG", "LEVEL_SLACK",
           "unit", "chord_angle_deg", "angle_between_deg", "subtended_deg", "sphere_reach_deg",
           "triangle_sizes_deg", "patch_pieces", "patch_piece_contrast",
           "shifted_offsets_deg", "piece_eccentricity_deg", "angular_speed_deg_s", "point_speed_deg_s",
           "CHANGE_MODES", "GAZE_DISTRIBUTION_MODES", "GAZE_NODES_PER_AXIS", "gaze_nodes_deg",
           "node_eccentricity_deg", "expected_change_visibility", "sse_continuous_level", "hybrid_level",
           "VISIBILITY_FLOOR", "CROSSING_MIN_DROP", "crossing_level", "change_visibility",
           "displacement_visibility", "change_visibility_levels", "change_level",
           "foveal_fmax_cpd", "fmax_cpd", "frequency_level", "csf_level", "distance_level", "continuous_level",
           "patch_piece_levels",
           "shift_reach_deg", "angle_to_sphere_deg", "eccentricity_bound_deg", "sup_max_visible_freq_cpd",
           "sup_fmax_cpd", "fmax_bound_cpd", "level_bound"]

CSF_MODES = ("csf", "gp")
"""The modes whose level is ``log2(f_max · diameter)`` (:func:`csf_level`)."""
CHANGE_MODES = ("change",)
"""The modes whose level is where what a level removes stops being visible (:func:`change_level`)."""
GAZE_DISTRIBUTION_MODES = ("hybrid",)
"""The modes that weigh what a level removes over every place the viewer may look (:func:`gaze_nodes_deg`)."""
GAZE_NODES_PER_AXIS = 3
"""Gauss–Hermite nodes per principal axis of the gaze distribution (:func:`gaze_nodes_deg`;
:attr:`SelectorConfig.gaze_nodes_per_axis`'s default): exact for polynomials of degree 5 in each axis, so for
the distribution's mean, covariance and fourth moments."""
VISIBILITY_FLOOR = -60.0
"""Visibility (log2 of contrast x sensitivity) of a change of contrast 0: far below any level's (a flat piece)."""
CROSSING_MIN_DROP = 0.25
"""Smallest fall of visibility per level, log2 units, with which :func:`crossing_level` extrapolates the finest
level's (which removes nothing): the fall from the level before, at least this."""

DIAMETER_FLOOR_DEG = 1e-9
"""Smallest angular diameter the level rule divides by, deg (a piece seen edge-on or at a point)."""
FMAX_FLOOR_CPD = 1e-12
"""Smallest f_max the level rule takes the log of, cpd: where nothing is visible (f_max = 0) the level is
log2(1e-12 · diameter), about 40 levels below any real one, instead of -inf."""
ANGLE_SLACK_DEG = 1e-6
"""Slack of the bounds' angles against rounding, deg: far above the float64 error of their closed forms,
far below anything that changes a level."""
LEVEL_SLACK = 1e-6
"""Slack added to every level bound, levels (the same reason)."""


# ---------------------------------------------------------------------------
# Angles
# ---------------------------------------------------------------------------

def unit(v) -> np.ndarray:
    """``v`` (..., 3) divided by its norm along the last axis."""
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def chord_angle_deg(chord) -> np.ndarray:
    """The angle between two unit vectors whose difference has norm ``chord`` (...,), deg.

    ``2 asin(chord / 2)``: accurate for small angles, where ``acos`` of a
    dot product loses half the digits.
    """
    return np.degrees(2 * np.arcsin(np.minimum(np.asarray(chord, dtype=np.float64) / 2, 1.0)))


def angle_between_deg(u, v) -> np.ndarray:
    """Angle between unit vectors ``u``, ``v`` (..., 3), deg (:func:`chord_angle_deg` of their difference)."""
    return chord_angle_deg(np.linalg.norm(np.asarray(u) - np.asarray(v), axis=-1))


def subtended_deg(size_mm, distance_mm) -> np.ndarray:
    """Largest angle two points at most ``size_mm`` apart subtend from an eye at least ``distance_mm`` away, deg.

    ``2 asin(size / (2 distance))`` (two points at exactly that distance,
    symmetric about the eye's line of sight); 180 when ``distance <= size / 2``.
    """
    size, distance = np.asarray(size_mm, dtype=np.float64), np.asarray(distance_mm, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(distance > size / 2, np.degrees(2 * np.arcsin(np.minimum(size / (2 * distance), 1.0))),
                        180.0)


def sphere_reach_deg(radius_mm, distance_mm) -> np.ndarray:
    """Half-angle a sphere of ``radius_mm`` subtends from an eye ``distance_mm`` from its centre, deg; 180 inside."""
    radius, distance = np.asarray(radius_mm, dtype=np.float64), np.asarray(distance_mm, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(distance > radius, np.degrees(np.arcsin(np.minimum(radius / distance, 1.0))), 180.0)


# ---------------------------------------------------------------------------
# The pieces: base triangles, and patches with their edges
# ---------------------------------------------------------------------------

def triangle_sizes_deg(eye_mm, directions, *, corners_mm=None, level_scale=None, edge_len_mm=None,
                       distance_mm=None):
    """Angular sizes of base triangles' pieces at every level, and their reach, deg.

    With ``corners_mm`` (S, 3, 3) world mm: the diameter of the triangle's
    projection (the largest angle between two corners, foreshortening
    included: the paper's definition) times ``level_scale`` (S, L+1), the
    level's pieces' size over the level-0 triangle's; the reach is the angle
    from the centroid's direction ``directions`` (S, 3) (unit, from
    ``eye_mm`` (3,)) to the farthest corner. Without: the longest edge
    ``edge_len_mm`` (S, L+1) seen face-on at ``distance_mm`` (S,), and the
    reach an equilateral triangle's circumradius (the level-0 size / √3).

    Returns
    -------
    angular_deg : (S, L+1) float64
    reach_deg : (S,) float64
    """
    if corners_mm is not None:
        to_corners = np.asarray(corners_mm, dtype=np.float64) - eye_mm
        to_corners /= np.linalg.norm(to_corners, axis=2, keepdims=True)
        chord = np.linalg.norm(to_corners - to_corners[:, [2, 0, 1]], axis=2)           # (S, 3)
        angular_deg = chord_angle_deg(chord.max(axis=1))[:, None] * level_scale
        reach_deg = chord_angle_deg(np.linalg.norm(to_corners - directions[:, None, :], axis=2).max(axis=1))
        return angular_deg, reach_deg
    angular_deg = np.degrees(2 * np.arctan(edge_len_mm / (2 * distance_mm[:, None])))
    return angular_deg, angular_deg[:, 0] / math.sqrt(3)


#: A patch's edges (W, S, E, N, as ``gl_TessLevelOuter``) by their corners (SW 0, SE 1, NE 2, NW 3), ordered
#: west to east and south to north so that the two patches sharing an edge compute the same numbers.
EDGE_ENDS = ((3, 0), (0, 1), (1, 2), (3, 2))


def patch_pieces(corners_mm, eye_mm):
    """A patch's five pieces: its inside and its four edges, each with its reference point, reach and diameter.

    The inside's point is the mean of the corners, its diameter the
    largest angle between two corners, its reach the angle from the point
    to the farthest corner. An edge's point is its midpoint, its diameter
    the angle between its endpoints, its reach the angle from the midpoint
    to the farther endpoint: an edge's level depends on the edge alone, so
    both patches sharing it agree (no cracks).

    Parameters
    ----------
    corners_mm : (..., 4, 3)
        Corners SW, SE, NE, NW, world frame, mm.
    eye_mm : (3,)

    Returns
    -------
    points_mm : (..., 5, 3)
        The inside's point, then the W, S, E, N edges' midpoints, world mm.
    reach_deg, diameter_deg : (..., 5) float64
    """
    c_mm = np.asarray(corners_mm, dtype=np.float64)
    eye = np.asarray(eye_mm, dtype=np.float64)
    dirs = unit(c_mm - eye)
    centre = c_mm.mean(axis=-2)
    diameter = chord_angle_deg(np.linalg.norm(dirs[..., [0, 1, 2, 3, 0, 1], :] - dirs[..., [1, 2, 3, 0, 2, 3], :],
                                              axis=-1).max(axis=-1))
    reach = chord_angle_deg(np.linalg.norm(unit(centre - eye)[..., None, :] - dirs, axis=-1).max(axis=-1))
    a, b = [e[0] for e in EDGE_ENDS], [e[1] for e in EDGE_ENDS]
    mid = 0.5 * (c_mm[..., a, :] + c_mm[..., b, :])                                   # (..., 4, 3)
    mdir = unit(mid - eye)
    length = chord_angle_deg(np.linalg.norm(dirs[..., a, :] - dirs[..., b, :], axis=-1))
    reach_e = chord_angle_deg(np.maximum(np.linalg.norm(mdir - dirs[..., a, :], axis=-1),
                                         np.linalg.norm(mdir - dirs[..., b, :], axis=-1)))
    return (np.concatenate([centre[..., None, :], mid], axis=-2), np.concatenate([reach[..., None], reach_e], axis=-1),
            np.concatenate([diameter[..., None], length], axis=-1))


def patch_piece_contrast(contrast, neighbour_contrast) -> np.ndarray:
    """(..., 5) contrast of a patch's five pieces: its own inside, the larger of the two patches' on each edge.

    ``contrast`` (...,); ``neighbour_contrast`` (..., 4): the patch's across
    each edge W, S, E, N (its own at the grid's border). f_max rises with
    the contrast, so the edge's level is the finer of the two patches'.
    """
    c = np.asarray(contrast, dtype=np.float64)[..., None]
    return np.concatenate([c, np.maximum(c, np.asarray(neighbour_contrast, dtype=np.float64))], axis=-1)


# ---------------------------------------------------------------------------
# The view of a piece: eccentricity and speed
# ---------------------------------------------------------------------------

def shifted_offsets_deg(points_mm, eye_mm, axes, cov_deg2=None, *, shift: str = "ellipse",
                        ellipse_sigma: float = 2.0) -> np.ndarray:
    """(φ, θ) of points about the head frame's V, shifted toward the POI by the uncertainty, deg, (..., 2).

    :func:`perception.view_offsets_deg` of ``points_mm`` (..., 3) world mm
    seen from ``eye_mm`` (3,) in the head frame ``axes`` (3, 3) (rows Ξ, Ψ,
    V), then :func:`perception.uncertainty_shift` of form ``shift`` with
    ``ellipse_sigma`` for the covariance ``cov_deg2`` (2, 2) deg² (None: no shift).
    """
    offsets = pc.view_offsets_deg(points_mm, eye_mm, axes)
    return pc.uncertainty_shift(offsets, cov_deg2, shift, ellipse_sigma) if cov_deg2 is not None else offsets


def gaze_nodes_deg(cov_deg2, per_axis: int = GAZE_NODES_PER_AXIS) -> tuple[np.ndarray, np.ndarray]:
    """Where the viewer may look about V, as quadrature nodes of a normal distribution: ((K, 2) (φ, θ) deg,
    (K,) weights summing to 1).

    ``cov_deg2`` (2, 2) deg² over (φ, θ), or None: the gaze covariance
    (:func:`headplod.plod.view.gaze_covariance`). A product Gauss–Hermite rule
    of ``per_axis`` nodes along each principal axis; a single node at V, weight 1,
    for None or a zero covariance. The expectation of a smooth function of the
    gaze is the weighted sum over the nodes (Gaussian quadrature: no sampling
    noise, and the same nodes every frame for the same covariance).
    """
    if cov_deg2 is None or not np.any(np.asarray(cov_deg2) != 0):
        return np.zeros((1, 2)), np.ones(1)
    x, w = np.polynomial.hermite_e.hermegauss(int(per_axis))
    w = w / w.sum()
    values, vectors = np.linalg.eigh(np.asarray(cov_deg2, dtype=np.float64))
    grid = np.stack(np.meshgrid(x, x, indexing="ij"), -1).reshape(-1, 2)
    nodes = (grid * np.sqrt(np.maximum(values, 0.0))) @ vectors.T
    return nodes, np.outer(w, w).ravel()


def node_eccentricity_deg(offsets_deg, reach_deg, nodes_deg) -> np.ndarray:
    """(S, K) eccentricity of each piece's nearest point from each gaze node, deg.

    The angle from the node's direction (``nodes_deg`` (K, 2) (φ, θ) deg about V, :func:`gaze_nodes_deg`) to
    the piece's reference point's (``offsets_deg`` (S, 2) (φ, θ) deg about V, unshifted), less ``reach_deg``
    (S,) deg, floored at 0 (:func:`piece_eccentricity_deg` seen from another fixation).
    """
    # (φ, θ) are atan2 angles about V: the direction is (tan θ, tan φ, 1), normalised.
    def directions(offsets):
        t = np.tan(np.radians(np.asarray(offsets, dtype=np.float64)))
        d = np.stack([t[..., 1], t[..., 0], np.ones(t.shape[:-1])], -1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    cos = np.clip(directions(offsets_deg) @ directions(nodes_deg).T, -1.0, 1.0)
    return np.maximum(np.degrees(np.arccos(cos)) - np.asarray(reach_deg, dtype=np.float64)[:, None], 0.0)


def piece_eccentricity_deg(shifted_deg, reach_deg) -> np.ndarray:
    """Eccentricity of a piece's point nearest the POI, deg, (...,).

    The eccentricity of its reference point's shifted offsets
    ``shifted_deg`` (..., 2) less ``reach_deg`` (...,), the angle from that
    point to the piece's farthest corner, floored at 0: a large piece
    reaching into the fovea is refined there.
    """
    return np.maximum(pc.eccentricity_deg(shifted_deg) - reach_deg, 0.0)


def angular_speed_deg_s(directions, previous_directions, dt_s) -> np.ndarray:
    """Angular speed of directions (..., 3) (unit) that were ``previous_directions`` ``dt_s`` s ago, deg/s, (...,).

    The angle between them over ``dt_s``, floored at :data:`MIN_SPEED_DEG_S`.
    """
    return np.maximum(angle_between_deg(directions, previous_directions) / dt_s, MIN_SPEED_DEG_S)


def point_speed_deg_s(points_mm, eye_mm, eye_prev_mm=None, dt_s: float = 0.0) -> np.ndarray:
    """Angular speed of world points (..., 3) mm seen from an eye that moved, deg/s, (...,).

    :func:`angular_speed_deg_s` of the directions from ``eye_prev_mm`` and
    from ``eye_mm`` (3,) over ``dt_s``; the floor everywhere when
    ``dt_s <= 0`` or without a last eye.
    """
    pts = np.asarray(points_mm, np.float64)
    if eye_prev_mm is None or not dt_s > 0:
        return np.full(pts.shape[:-1], MIN_SPEED_DEG_S)
    return angular_speed_deg_s(unit(pts - np.asarray(eye_mm, np.float64)),
                               unit(pts - np.asarray(eye_prev_mm, np.float64)), dt_s)


# ---------------------------------------------------------------------------
# The levels
# ---------------------------------------------------------------------------

def foveal_fmax_cpd(contrast, speed_deg_s, csf_model: str = "kelly_scaled") -> np.ndarray:
    """f_max at eccentricity 0, cpd: :func:`fmax_cpd`'s ``foveal_cpd`` (``kelly_scaled``: f_max(e) = it / (1 + 0.29 e))."""
    return max_visible_freq_cpd(contrast, speed_deg_s, 0.0, model=csf_model)


def fmax_cpd(contrast, speed_deg_s, ecc_deg, *, mode: str = "csf", csf_model: str = "kelly_scaled",
             foveal_cpd=None, cortical_exponent: float = CORTICAL_EXPONENT, nyquist_cpd=None) -> np.ndarray:
    """Highest visible frequency of pieces, cpd, (...,).

    ``csf``: :func:`csf.max_visible_freq_cpd` of ``csf_model`` at the
    pieces' contrast, speed and eccentricity; with a frequency-scaled model
    (``kelly_scaled``, ``cortical``) and ``foveal_cpd`` (their f_max at
    eccentricity 0, :func:`foveal_fmax_cpd`, e.g. kept from the last frame,
    or shared by several eccentricities) it is ``foveal_cpd`` over the
    model's eccentricity factor, the same number without solving Lambert's
    W again. ``gp``: Geisler & Perry's
    cutoff (no speed). ``cortical_exponent``: k of ``csf_model="cortical"``.
    ``nyquist_cpd`` (scalar or (...,)): the display's Nyquist frequency
    (:func:`csf.display_nyquist_cpd`), the cap of ``"cortical"``'s f_max:
    no finer detail can be drawn.
    """
    if mode == "gp":
        return gp_cutoff_cpd(contrast, ecc_deg)
    if foveal_cpd is not None and csf_model == "kelly_scaled":
        return foveal_cpd / eccentricity_factor(ecc_deg)
    if foveal_cpd is not None and csf_model in FREQUENCY_SCALED_MODELS:
        fmax = foveal_cpd / eccentricity_factor(ecc_deg, csf_model, cortical_exponent)
    else:
        fmax = max_visible_freq_cpd(contrast, speed_deg_s, ecc_deg, model=csf_model,
                                    cortical_exponent=cortical_exponent)
    if nyquist_cpd is not None and csf_model == "cortical":
        fmax = np.minimum(fmax, nyquist_cpd)
    return fmax


def frequency_level(fmax, diameter_deg, level_bias: float = 0.0) -> np.ndarray:
    """Continuous level ``log2(f_max / f) + bias`` of pieces of frequency ``f = 1 / diameter``, (...,).

    Martinez eq. 4 before its ceiling (:func:`perception.lod_continuous`):
    the doublings of frequency from the piece's to the highest visible one. ``fmax`` (...,) cpd is floored at
    :data:`FMAX_FLOOR_CPD` and ``diameter_deg`` at :data:`DIAMETER_FLOOR_DEG`.
    """
    frequency = 1.0 / np.maximum(diameter_deg, DIAMETER_FLOOR_DEG)
    return pc.lod_continuous(frequency, np.maximum(fmax, FMAX_FLOOR_CPD)) + level_bias


def csf_level(contrast, speed_deg_s, ecc_deg, diameter_deg, *, mode: str = "csf", csf_model: str = "kelly_scaled",
              foveal_cpd=None, level_bias: float = 0.0, cortical_exponent: float = CORTICAL_EXPONENT,
              nyquist_cpd=None) -> np.ndarray:
    """Continuous level of ``csf`` (or ``gp``) pieces: :func:`frequency_level` of :func:`fmax_cpd`, (...,)."""
    fmax = fmax_cpd(contrast, speed_deg_s, ecc_deg, mode=mode, csf_model=csf_model, foveal_cpd=foveal_cpd,
                    cortical_exponent=cortical_exponent, nyquist_cpd=nyquist_cpd)
    return frequency_level(fmax, diameter_deg, level_bias)


def crossing_level(visibility) -> np.ndarray:
    """Continuous level (S,) from per-level visibilities (S, L+1): where the finest visible level's crosses 0.

    ``visibility[:, l]`` > 0 when what level ``l`` removes is visible (log2 of contrast x sensitivity over the
    threshold, or of displacement over threshold). Level L removes nothing; its visibility is extrapolated
    from the two before (their fall, at least :data:`CROSSING_MIN_DROP`), so that the continuous level moves
    smoothly with the threshold (a bias or a budget) instead of jumping to L. With k the finest level whose
    visibility is >= 0, the level is ``k + v_k / (v_k - v_{k+1})`` (linear between k and k + 1, so ``ceil``
    gives k + 1, the coarsest level with nothing visible removed at it or finer); when even the extrapolated
    finest is visible, the line continued past L (at most 2L: a level above L rounds to L, but a negative bias
    then coarsens such pieces one by one, not all at once); and, when no level's change is visible, ``v_0``
    clipped to [-(L + 1), 0]
    (a level below 0: the further below the threshold, the more bias it takes to refine it).
    """
    v = np.array(visibility, dtype=np.float64)
    L = v.shape[1] - 1
    if L >= 1:
        before = v[:, L - 2] if L >= 2 else v[:, L - 1] + CROSSING_MIN_DROP
        v[:, L] = v[:, L - 1] - np.maximum(before - v[:, L - 1], CROSSING_MIN_DROP)
    visible = v >= 0
    any_visible = visible.any(axis=1)
    k = L - np.argmax(visible[:, ::-1], axis=1)                     # finest visible level (0 where none)
    rows = np.arange(len(v))
    v_k = v[rows, k]
    v_next = v[rows, np.minimum(k + 1, L)]
    v_before = v[rows, np.maximum(k - 1, 0)]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(k < L, np.clip(v_k / np.maximum(v_k - v_next, tol.zero), 0.0, 1.0),
                        np.clip(v_k / np.maximum(v_before - v_k, CROSSING_MIN_DROP), 0.0, max(L, 1)))
    return np.where(any_visible, k + frac, np.clip(v[:, 0], -(L + 1.0), 0.0))


def change_visibility(change_contrast, angular_deg, speed_deg_s, ecc_deg, *, csf_model: str = "cortical",
                      cortical_exponent: float = CORTICAL_EXPONENT, nyquist_cpd=None) -> np.ndarray:
    """log2(contrast x sensitivity) (S, L+1) of what each level removes from the shading.

    ``change_contrast`` (S, L+1): Michelson contrast of the displayed change at each level (0 at L);
    ``angular_deg`` (S, L+1) the level's pieces' diameters, deg: the change spans one, half a cycle, so its
    frequency is ``1 / (2 diameter)`` cpd, taken no higher than ``nyquist_cpd`` (a change finer than a pixel
    shows as a pixel's) and no lower than the CSF's peak at the piece's speed and eccentricity: a local
    change is broadband, and the CSF's fall below its peak holds for gratings, not for it (Luebke & Hallen
    take the peak there too); ``speed_deg_s``, ``ecc_deg`` (S,).
    """
    freq = 0.5 / np.maximum(np.asarray(angular_deg, dtype=np.float64), DIAMETER_FLOOR_DEG)
    if nyquist_cpd is not None:
        freq = np.minimum(freq, np.asarray(nyquist_cpd, dtype=np.float64)[..., None])
    _, decay = csf_coefficients(speed_deg_s, csf_model)               # S = A f² exp(-b f) peaks at f = 2 / b
    peak = 2.0 / decay
    if csf_model in FREQUENCY_SCALED_MODELS:
        peak = peak / eccentricity_factor(ecc_deg, csf_model, cortical_exponent)
    freq = np.maximum(freq, np.asarray(peak)[:, None])
    s = sensitivity(freq, np.asarray(speed_deg_s)[:, None], np.asarray(ecc_deg)[:, None], model=csf_model,
                    cortical_exponent=cortical_exponent)
    product = np.asarray(change_contrast, dtype=np.float64) * s
    with np.errstate(divide="ignore"):
        return np.maximum(np.log2(np.maximum(product, 0.0)), VISIBILITY_FLOOR)


def displacement_visibility(error_mm, distance_mm, contrast, speed_deg_s, ecc_deg, *, csf_model: str = "cortical",
                            cortical_exponent: float = CORTICAL_EXPONENT, nyquist_cpd=None,
                            foveal_cpd=None) -> np.ndarray:
    """log2(displacement / threshold) (S, L+1) of each level's geometric error.

    ``error_mm`` (S, L+1) the level's largest distance from the finest surface, seen at ``distance_mm`` (S,):
    its angle is the displacement. The threshold is half a period of the highest frequency visible at the
    ``contrast`` (S,) of what moves, at the piece's speed and eccentricity (S,); f_max is capped at
    ``nyquist_cpd``, so nothing under half a pixel counts. ``foveal_cpd`` (S,): that f_max at eccentricity 0,
    if known (:func:`fmax_cpd`).
    """
    displacement = np.degrees(np.asarray(error_mm, dtype=np.float64) / np.asarray(distance_mm)[:, None])
    fmax = fmax_cpd(contrast, speed_deg_s, ecc_deg, csf_model=csf_model, cortical_exponent=cortical_exponent,
                    nyquist_cpd=nyquist_cpd, foveal_cpd=foveal_cpd)
    threshold = 0.5 / np.maximum(fmax, FMAX_FLOOR_CPD)
    with np.errstate(divide="ignore"):
        return np.maximum(np.log2(displacement / threshold[:, None]), VISIBILITY_FLOOR)


def change_level(visibility, level_bias: float = 0.0) -> np.ndarray:
    """Continuous level (S,) of ``change``: where neither the shading change nor the displacement is visible.

    ``visibility`` (S, L+1): :func:`change_visibility_levels`. :func:`crossing_level` of it plus ``level_bias``:
    for this mode a bias moves the *threshold*, not the level: bias B counts a change as visible once its
    contrast reaches 2^-B times the threshold. (Adding B to the level would move pieces whose visibility
    falls slowly with the level by the same levels as those whose falls fast: a budget would then coarsen
    some pieces far past their threshold while others keep detail nobody sees.) The visibility is an input,
    not computed here, because a budget (``LevelSelector``) evaluates this for many biases.
    """
    return crossing_level(np.asarray(visibility, dtype=np.float64) + level_bias)


def change_visibility_levels(change_contrast, angular_deg, error_mm, distance_mm, displacement_contrast,
                             speed_deg_s, ecc_deg, *, csf_model: str = "cortical",
                             cortical_exponent: float = CORTICAL_EXPONENT, nyquist_cpd=None,
                             threshold: float = 1.0, foveal_cpd=None) -> np.ndarray:
    """Visibility (S, L+1) of what each level removes, log2 units: the larger of :func:`change_visibility` and
    :func:`displacement_visibility`, both contrasts divided by ``threshold`` (how many times its detection
    threshold a change's contrast must be to count: 1, at threshold). Shapes as those functions';
    ``foveal_cpd`` (S,): the displacement's f_max at eccentricity 0, if known.
    """
    shading = change_visibility(np.asarray(change_contrast) / threshold, angular_deg, speed_deg_s, ecc_deg,
                                csf_model=csf_model, cortical_exponent=cortical_exponent, nyquist_cpd=nyquist_cpd)
    moving = displacement_visibility(error_mm, distance_mm, np.asarray(displacement_contrast) / threshold,
                                     speed_deg_s, ecc_deg, csf_model=csf_model, cortical_exponent=cortical_exponent,
                                     nyquist_cpd=nyquist_cpd, foveal_cpd=foveal_cpd)
    return np.maximum(shading, moving)


def distance_level(distance_mm, max_level: int, distance_ref_mm: float) -> np.ndarray:
    """Mode ``distance``: ``max_level`` at ``distance_ref_mm`` and nearer, one level coarser per doubling beyond."""
    return max_level - np.log2(np.maximum(np.asarray(distance_mm, dtype=np.float64) / distance_ref_mm, tol.small))


def continuous_level(config, max_level: int, *, ecc_deg, angular_deg, distance_mm, speed_deg_s, contrast,
                     edge_len_mm=None, error_mm=None, px_per_mm=None, foveal_cpd=None,
                     nyquist_cpd=None) -> np.ndarray:
    """Every mode's continuous level of base triangles but ``change``'s, the level bias included, (S,).

    ``change`` needs each level's visibility (:func:`change_visibility_levels`, then :func:`change_level`),
    which ``LevelSelector`` keeps for its budget; it is refused here.

    Parameters
    ----------
    config : SelectorConfig
        ``mode``, ``csf_model``, ``level_bias`` and the modes' settings
        (``distance_ref_mm``, ``sse_tolerance_px``, ``frame_s``, ``velocity_ref_deg_s``).
    max_level : int
    ecc_deg, distance_mm, speed_deg_s, contrast : (S,)
        As the module notes; ``distance_mm`` from the eye to the centroid.
    angular_deg : (S, L+1)
        Angular size of the pieces at each level (:func:`triangle_sizes_deg`).
    edge_len_mm, error_mm : (S, L+1)
        Longest edge and geometric error of each level, mm (``acuity``, ``sse``, ``ipv``, ``dpv``).
    px_per_mm : float
        The screen's pixels per mm (``acuity``, ``sse``, ``ipv``, ``dpv``: with
        the median distance of the triangles given, the display's resolution).
    foveal_cpd : (S,), optional
        ``kelly_scaled``'s foveal f_max (:func:`fmax_cpd`).
    nyquist_cpd : float, optional
        The display's Nyquist frequency at the eye (:func:`csf.display_nyquist_cpd`): the cap of
        ``csf_model="cortical"``.

    The rounding to integer levels is the caller's (``ceil``; ``floor`` for ``acuity``).
    """
    mode, bias = config.mode, float(config.level_bias)
    if mode in CSF_MODES:
        return csf_level(contrast, speed_deg_s, ecc_deg, angular_deg[:, 0], mode=mode, csf_model=config.csf,
                         foveal_cpd=foveal_cpd, level_bias=bias, cortical_exponent=config.cortical,
                         nyquist_cpd=nyquist_cpd)
    if mode in CHANGE_MODES + GAZE_DISTRIBUTION_MODES:
        raise ValueError(f"mode {mode!r} needs each level's visibility: change_level or hybrid_level")
    if mode == "distance":
        return distance_level(distance_mm, max_level, config.distance_ref_mm) + bias
    if mode == "acuity":
        k1, k2, k3 = pc.acuity_factors(ecc_deg, 0.5 * angular_deg[:, 0], speed_deg_s, np.zeros_like(ecc_deg))
        a0 = pc.display_acuity_a0(1.0 / px_per_mm, float(np.median(distance_mm)))
        return pc.acuity_level(k1, k2, k3, a0, distance_mm, edge_len_mm, return_continuous=True)[1] + bias
    pixels_per_radian = px_per_mm * float(np.median(distance_mm))
    if mode == "sse":
        return sse_continuous_level(error_mm, distance_mm, px_per_mm, speed_deg_s, config) + bias
    base = pc.sse_level(error_mm, distance_mm, pixels_per_radian, config.sse_tolerance_px, return_continuous=True)[1]
    return pc.velocity_baseline_level(base, speed_deg_s, mode=mode, v_ref=config.velocity_ref_deg_s,
                                      max_level=max_level, return_continuous=True)[1] + bias


def sse_continuous_level(error_mm, distance_mm, px_per_mm: float, speed_deg_s, config) -> np.ndarray:
    """Mode ``sse``'s continuous level (S,), no bias: :func:`perception.sse_level` with the screen's ``px_per_mm``
    at the median of ``distance_mm`` (S,) mm, ``error_mm`` (S, L+1) mm, ``speed_deg_s`` (S,) deg/s and
    ``config``'s ``sse_tolerance_px`` and ``frame_s``."""
    pixels_per_radian = px_per_mm * float(np.median(distance_mm))
    return pc.sse_level(error_mm, distance_mm, pixels_per_radian, config.sse_tolerance_px, speed_deg_s=speed_deg_s,
                        frame_s=config.frame_s, return_continuous=True)[1]


def expected_change_visibility(change_contrast, angular_deg, error_mm, distance_mm, displacement_contrast,
                               speed_deg_s, node_ecc_deg, node_weights, **options) -> np.ndarray:
    """(S, L+1) log2 of the expected visibility of what each level removes, over where the viewer may look.

    :func:`change_visibility_levels` (its inputs and keyword ``options``) at each gaze node's eccentricity
    (``node_ecc_deg`` (S, K) deg, :func:`node_eccentricity_deg`), weighed by ``node_weights`` (K,) in linear
    units (contrast over threshold): a change seen plainly from a few likely fixations counts, which the
    eccentricity of the most likely one alone would miss.
    """
    ecc = np.asarray(node_ecc_deg, dtype=np.float64)
    n, k = ecc.shape

    def tile(a):
        a = np.asarray(a, dtype=np.float64)
        return np.repeat(a, k, axis=0)

    model = options.get("csf_model", "cortical")
    if model in FREQUENCY_SCALED_MODELS:
        # The displacement's f_max at each node is its foveal one over the eccentricity factor: Lambert's W is
        # solved once per piece, not once per piece and node.
        contrast = np.asarray(displacement_contrast, dtype=np.float64) / options.get("threshold", 1.0)
        options = {**options, "foveal_cpd": tile(foveal_fmax_cpd(contrast, speed_deg_s, model))}
    vis = change_visibility_levels(tile(change_contrast), tile(angular_deg), tile(error_mm), tile(distance_mm),
                                   tile(displacement_contrast), tile(speed_deg_s), ecc.ravel(), **options)
    vis = vis.reshape(n, k, -1)
    top = vis.max(axis=1)                                   # log-sum-exp in base 2, against overflow
    weighted = np.einsum("skl,k->sl", np.exp2(vis - top[:, None, :]), np.asarray(node_weights, dtype=np.float64))
    with np.errstate(divide="ignore"):
        return np.maximum(top + np.log2(weighted), VISIBILITY_FLOOR)


def hybrid_level(sse_level, change_visibility, change_share: float) -> np.ndarray:
    """Mode ``hybrid``'s continuous level (S,), no bias: ``sse``'s (``sse_level`` (S,), the geometric error in
    pixels) and :func:`change_level` of ``change_visibility`` (S, L+1) (what the level removes as the viewer
    would see it), mixed ``1 − change_share`` : ``change_share``. ``change_share`` 0 is ``sse`` exactly."""
    if change_share == 0:
        return np.asarray(sse_level, dtype=np.float64)
    return (1.0 - change_share) * np.asarray(sse_level, dtype=np.float64) + change_share * change_level(
        change_visibility)


def patch_piece_levels(corners_mm, piece_contrast, eye_mm, axes, cov_deg2=None, *, shift: str = "ellipse",
                       ellipse_sigma: float = 2.0, level_bias: float = 0.0, speed_deg_s=MIN_SPEED_DEG_S,
                       eye_prev_mm=None, dt_s: float = 0.0, foveal_cpd=None) -> np.ndarray:
    """Continuous ``csf`` (``kelly_scaled``) levels of patches' five pieces (:func:`patch_pieces`), (..., 5).

    Parameters
    ----------
    corners_mm : (..., 4, 3)
        Corners SW, SE, NE, NW, world mm.
    piece_contrast : (..., 5)
        :func:`patch_piece_contrast`.
    eye_mm, axes, cov_deg2, shift, ellipse_sigma
        As :func:`shifted_offsets_deg`.
    level_bias : float
    speed_deg_s : float or (..., 5)
        The pieces' angular speed, deg/s (the floor for a still eye).
    eye_prev_mm : (3,) or None; dt_s : float
        The last frame's eye and the time since, s: when given (``dt_s > 0``)
        each piece's speed is :func:`point_speed_deg_s` of its point instead.
    foveal_cpd : (..., 5) or None
        The pieces' foveal f_max at ``speed_deg_s`` (:func:`foveal_fmax_cpd`),
        if known; ignored when the eye moves.
    """
    points, reach, diameter = patch_pieces(corners_mm, eye_mm)
    ecc = piece_eccentricity_deg(shifted_offsets_deg(points, eye_mm, axes, cov_deg2, shift=shift,
                                                     ellipse_sigma=ellipse_sigma), reach)
    moving = eye_prev_mm is not None and dt_s > 0
    speed = point_speed_deg_s(points, eye_mm, eye_prev_mm, dt_s) if moving else speed_deg_s
    return csf_level(piece_contrast, speed, ecc, diameter, foveal_cpd=None if moving else foveal_cpd,
                     level_bias=level_bias)


# ---------------------------------------------------------------------------
# Bounds over a node of a hierarchy
# ---------------------------------------------------------------------------

def shift_reach_deg(cov_deg2, shift: str = "ellipse", ellipse_sigma: float = 2.0) -> float:
    """Largest distance the uncertainty shift moves an offset (φ, θ), deg: 0 without a covariance.

    ``ellipse``: ``ellipse_sigma √λmax`` (the offset loses ``n / √q`` of
    itself, ``q >= |P|² / λmax``); ``eq1``: ``e^(-1/2) √λmax`` (it loses
    ``|P| exp(-q / 2)``, largest at ``|P| = √λmax``). The shift keeps an
    offset on its ray from the POI, and the eccentricity changes by at most
    the offset's change along such a ray, so a point at angle ``A`` from V
    has a shifted eccentricity of at least ``A -`` this.
    """
    if cov_deg2 is None:
        return 0.0
    cov = np.asarray(cov_deg2, dtype=np.float64)
    if not np.any(cov != 0):
        return 0.0
    lam = max(float(np.linalg.eigvalsh(0.5 * (cov + cov.T))[-1]), 0.0)
    return (ellipse_sigma if shift == "ellipse" else math.exp(-0.5)) * math.sqrt(lam)


def angle_to_sphere_deg(centre_rel_mm, radius_mm, gaze) -> np.ndarray:
    """Smallest angle from the direction ``gaze`` (3,) (unit) to spheres, deg (negative when the gaze ray meets one).

    ``centre_rel_mm`` (k, 3): centres less the eye, world mm; ``radius_mm`` (k,).
    The angle to the centre less :func:`sphere_reach_deg`.
    """
    rel = np.asarray(centre_rel_mm, dtype=np.float64)
    dist = np.sqrt(np.einsum("mi,mi->m", rel, rel))
    with np.errstate(divide="ignore", invalid="ignore"):
        to_centre = angle_between_deg(rel / dist[:, None], gaze)
    return to_centre - sphere_reach_deg(radius_mm, dist)


def eccentricity_bound_deg(angle_deg, shift_reach, reach_deg) -> np.ndarray:
    """Lower bound of the pieces' :func:`piece_eccentricity_deg` below a node, deg.

    ``angle_deg``: a lower bound of the angle from V to any reference point
    below the node (:func:`angle_to_sphere_deg`); ``shift_reach``:
    :func:`shift_reach_deg`; ``reach_deg``: an upper bound of the pieces'
    reach. Less :data:`ANGLE_SLACK_DEG`, floored at 0.
    """
    return np.maximum(angle_deg - shift_reach - reach_deg - ANGLE_SLACK_DEG, 0.0)


# Relative margin on the sup of f_max over the speed grid (the grid's own error is far smaller).
_FMAX_MARGIN = 1.001


def sup_max_visible_freq_cpd(contrast, model: str = "kelly_scaled", speeds_deg_s=None) -> np.ndarray:
    """Highest foveal f_max over all retinal speeds, per contrast, cpd, with a safety margin, (n,).

    ``max_visible_freq_cpd(C, v, 0)`` is not monotone in the speed ``v`` (it
    peaks near 0.2 deg/s for low contrasts), so a bound valid for any speed
    takes its maximum over a fine logarithmic speed grid ``speeds_deg_s``
    (default: from the floor, 0.1 deg/s, to 30 deg/s, beyond which f_max
    only falls), times 1.001. Non-decreasing in the contrast ``contrast`` (n,).
    """
    c = np.asarray(contrast, dtype=np.float64).reshape(-1)
    v = (np.logspace(math.log10(MIN_SPEED_DEG_S), math.log10(30.0), 600) if speeds_deg_s is None
         else np.asarray(speeds_deg_s, dtype=np.float64))
    f = max_visible_freq_cpd(c[:, None], v[None, :], 0.0, model=model)
    return f.max(axis=1) * _FMAX_MARGIN


_SUP_TABLES: dict = {}


def sup_fmax_cpd(contrast, csf_model: str = "kelly_scaled") -> np.ndarray:
    """:func:`sup_max_visible_freq_cpd` of contrasts (...,) from a table, rounded up in the contrast, cpd.

    The table (801 contrasts from 1e-4 to max(1, the largest asked), and 0)
    is made once per model and top; a contrast takes the value of the first
    grid point at or above it (f_max rises with the contrast).
    """
    c = np.asarray(contrast, dtype=np.float64)
    top = max(1.0, float(np.max(c, initial=0.0)))
    key = (csf_model, top)
    if key not in _SUP_TABLES:
        tops = [t for (m, t) in _SUP_TABLES if m == csf_model and t >= top]
        if tops:
            key = (csf_model, min(tops))
        else:
            grid = np.concatenate([[0.0], np.logspace(-4, math.log10(top), 801)])
            _SUP_TABLES[key] = (grid, sup_max_visible_freq_cpd(grid, csf_model))
    grid, table = _SUP_TABLES[key]
    k = np.searchsorted(grid, c, side="left")                   # grid[k] >= contrast
    return table[np.minimum(k, len(grid) - 1)]


def fmax_bound_cpd(contrast, ecc_deg, *, mode: str = "csf", csf_model: str = "kelly_scaled", speed_deg_s=None,
                   foveal_cpd=None) -> np.ndarray:
    """Upper bound of f_max over pieces of contrast at most ``contrast`` and eccentricity at least ``ecc_deg``, cpd.

    ``speed_deg_s`` None: over every speed (:func:`sup_fmax_cpd`); else at
    that speed. ``foveal_cpd``: the bound at eccentricity 0 if the caller
    has it (``kelly_scaled``: divided by ``1 + 0.29 e``). For the other Kelly
    forms ``f_max(C, v, e) = f_max(C / (1 + 0.29 e), v, 0)``. ``gp``: the cutoff.
    """
    if mode == "gp":
        return gp_cutoff_cpd(contrast, ecc_deg)
    m = eccentricity_factor(ecc_deg)
    if csf_model == "kelly_scaled":
        if foveal_cpd is not None:
            return foveal_cpd / m
        if speed_deg_s is None:
            return sup_fmax_cpd(contrast, csf_model) / m
        return max_visible_freq_cpd(contrast, speed_deg_s, ecc_deg, model=csf_model)
    if speed_deg_s is None:
        return sup_fmax_cpd(np.asarray(contrast, dtype=np.float64) / m, csf_model)
    return max_visible_freq_cpd(contrast, speed_deg_s, ecc_deg, model=csf_model)


def level_bound(contrast, ecc_deg, diameter_deg, *, mode: str = "csf", csf_model: str = "kelly_scaled",
                speed_deg_s=None, foveal_cpd=None, level_bias: float = 0.0) -> np.ndarray:
    """Upper bound of the continuous ``csf``/``gp`` level of every piece below nodes, (k,).

    :func:`frequency_level` at the nodes' largest contrast ``contrast``, smallest eccentricity ``ecc_deg``
    (:func:`eccentricity_bound_deg`) and largest diameter ``diameter_deg`` (plus :data:`ANGLE_SLACK_DEG`), with
    :func:`fmax_bound_cpd`'s f_max, plus :data:`LEVEL_SLACK`.
    """
    fmax = fmax_bound_cpd(contrast, ecc_deg, mode=mode, csf_model=csf_model, speed_deg_s=speed_deg_s,
                          foveal_cpd=foveal_cpd)
    return frequency_level(fmax, diameter_deg + ANGLE_SLACK_DEG, level_bias) + LEVEL_SLACK
