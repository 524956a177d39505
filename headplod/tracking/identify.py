"""Identification of the markers P0..P4 among stereo points by the marker model's distances.

Martinez et al. (2008, §4.1, steps 4-7) label each image on its own: three
collinear blobs are P0, P1, P2, the nearer of the two others is an end's
partner, and a cross product's sign tells the ends apart; the stereo stage
then pairs the left and right labelings. Every trio of blobs, every pair of
the rest and every pairing of the two images' labelings is a hypothesis, so
the cost grows with the sixth power of the blobs an image holds, and a few
glints and a lamp already make a frame stall. The paper does not bound it.

This module bounds it by doing the stereo step first, as motion-capture
systems do:

1. a *stereo point* is a left blob and a right blob within the epipolar
   tolerance of each other (through the lenses' distortion: the centres are
   undistorted first), triangulated, in front of both cameras and within
   the working range; a blob far from every epipolar line of the other view
   makes none, so clutter that is not a 3D point is pruned before anything
   is combined;
2. the five markers are labelled among the stereo points by the model's
   pairwise distances, which no pose changes: an *anchor* (two points as far
   apart as the model's longest edge), then, for each other marker, the few
   points at its two distances from the anchor's ends, then the distances
   among those (the triangles' shapes);
3. the labelings are ranked by how well their shape matches the model's
   (the distances' errors after the best common scale: a rig whose baseline
   is off scales every triangulated shape), and only the best ``budget`` of
   them are fitted to the model, at its true size, by the caller.

Costs: the epipolar matrix is blobs², the distance matrix stereo points²,
and the labelings are at most ``max_anchors`` × ``per_marker``³, fixed, so a
frame's cost grows with the square of the blobs in its vectorized parts and
not at all in its combinations. A labeling whose points fit the model rigidly
within an RMS of ``fit_tol`` mm has no pairwise distance off by more than
√10 · ``fit_tol`` (two residuals of at most that RMS over five points), so
that distance tolerance drops no labeling the final fit would accept.

Of the paper's image rule one part stays, as a check no rig error affects
(:func:`collinear_in_image`): P1 lies between P0 and P2 on their image line
in both views. While the rig is uncertain (the first frames, a stale
rig.yaml) the 3D checks are wide, and a glint next to the markers can stand
in for one of them; the line cannot. A labeling that mirrors the model
(P0↔P2 and P3↔P4 for a symmetric model) fits only with the glasses turned
away from the cameras, which the caller rejects (retro-reflectors are seen
only from the front).
"""
from __future__ import annotations

from functools import lru_cache
from itertools import product
from typing import NamedTuple

import numpy as np

from . import geometry as geo
from ..tol import tol

# The partners a blob keeps in the other view, best epipolar error first (:func:`stereo_points`).
MAX_PARTNERS = 6
# The fit-RMS tolerance times this bounds each pairwise distance's error (module docstring).
DISTANCE_TOL_PER_FIT_TOL = float(np.sqrt(10.0))
# P1's largest distance from the image line through P0 and P2: centroid errors, plus lens curvature and
# foreshortening that grow with the trio's length (Martinez et al.'s collinearity, a tolerance of ours).
LINE_TOL_PX = 1.5
LINE_TOL_PER_LENGTH = 0.04


def collinear_in_image(p0_px: np.ndarray, p1_px: np.ndarray, p2_px: np.ndarray) -> np.ndarray:
    """Whether P1 (…, 2) px lies on the image line through P0 and P2 and between them, as the contract's
    markers (P0, P1, P2 on G's x axis) do in any view: (…) bool. A check no rig error affects."""
    ab, ac = p2_px - p0_px, p1_px - p0_px
    length = np.linalg.norm(ab, axis=-1)
    off_line = np.abs(ab[..., 0] * ac[..., 1] - ab[..., 1] * ac[..., 0]) / np.maximum(length, tol.small)
    along = np.einsum("...i,...i->...", ac, ab) / np.maximum(length, tol.small) ** 2
    return (off_line <= LINE_TOL_PX + LINE_TOL_PER_LENGTH * length) & (along > 0.05) & (along < 0.95)


class StereoPoints(NamedTuple):
    """Left-right blob pairs that satisfy the epipolar geometry, triangulated.

    ``left``, ``right`` (K,) indices into the two images' candidate lists;
    ``points_mm`` (K, 3) world (left camera) frame; ``epipolar_px`` (K,).
    """

    left: np.ndarray
    right: np.ndarray
    points_mm: np.ndarray
    epipolar_px: np.ndarray

    def __len__(self) -> int:
        return len(self.left)


class Labelings(NamedTuple):
    """Labelings of some markers among stereo points, best (smallest shape error) first.

    ``markers`` the marker numbers labelled, in order; ``index`` (H, len(markers))
    the stereo point of each; ``shape_mm`` (H,) the sum of the labelled
    pairwise distances' absolute errors against the model scaled to fit
    them best, mm (the ranking: a rig whose baseline is off scales every
    triangulated shape, and must not push the true labeling down);
    ``error_mm`` (H,) the same against the model at its true size, mm (the
    bound of :func:`headplod.tracking.acquire._scan`).
    """

    markers: tuple
    index: np.ndarray
    shape_mm: np.ndarray
    error_mm: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


def stereo_points(xn_left: np.ndarray, xn_right: np.ndarray, g, depth_range_mm: tuple,
                  max_partners: int = MAX_PARTNERS) -> StereoPoints:
    """The epipolar-consistent left-right pairs of undistorted centres, triangulated.

    ``xn_left`` (m, 2), ``xn_right`` (n, 2): normalized coordinates; ``g`` a
    :class:`~.tracker_rig.RigGeometry` (its ``epipolar_tol_px``, essential
    matrix, focal lengths and rig); ``depth_range_mm`` (near, far): the
    points' depth in both cameras, mm. A pair is kept when it is within the
    tolerance and among the ``max_partners`` best of its left or of its right
    blob: while the rig is uncertain the tolerance is wide, and a cluttered
    image would otherwise pair nearly every blob with every other.
    """
    epi = geo.epipolar_error_px(xn_left[:, None, :], xn_right[None, :, :], g.E, *g.focal)   # (m, n)
    near = np.zeros(epi.shape, bool)
    rows = np.arange(epi.shape[0])[:, None]
    near[rows, np.argsort(epi, axis=1, kind="stable")[:, :max_partners]] = True
    near[np.argsort(epi, axis=0, kind="stable")[:max_partners], np.arange(epi.shape[1])[None, :]] = True
    left, right = np.nonzero(near & (epi <= g.epipolar_tol_px))
    points, _ = geo.triangulate_midpoint(xn_left[left], xn_right[right], g.rig.R, g.rig.T)
    depth_right = points @ np.asarray(g.rig.R)[2] + np.reshape(g.rig.T, 3)[2]
    near, far = depth_range_mm
    keep = (points[:, 2] >= near) & (points[:, 2] <= far) & (depth_right >= near) & (depth_right <= far)
    return StereoPoints(left[keep], right[keep], points[keep], epi[left[keep], right[keep]])


def _pairwise_mm(points_mm: np.ndarray) -> np.ndarray:
    """Distances (n, n) mm between points (n, 3) mm."""
    P = np.asarray(points_mm, dtype=np.float64)
    return np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)


def model_distances(model_mm: np.ndarray) -> np.ndarray:
    """Pairwise distances (5, 5) of the marker model, mm."""
    return _pairwise_mm(model_mm)


class PointGraph(NamedTuple):
    """Stereo points' pairwise distances ``D`` (K, K) mm, and ``apart`` (K, K) bool: the two points use
    different blobs in both views (so they may be two markers)."""

    D: np.ndarray
    apart: np.ndarray

    def __len__(self) -> int:
        return len(self.D)


def point_graph(points_mm: np.ndarray, blobs: tuple | None = None) -> PointGraph:
    """The :class:`PointGraph` of stereo points (K, 3) mm; ``blobs`` (left (K,), right (K,)): each
    point's blob in each view (default: every point its own)."""
    D = _pairwise_mm(points_mm)
    if blobs is None:
        apart = ~np.eye(len(D), dtype=bool)
    else:
        left, right = (np.asarray(b) for b in blobs)
        apart = (left[:, None] != left[None, :]) & (right[:, None] != right[None, :])
    return PointGraph(D, apart)


@lru_cache(maxsize=None)
def _combinations(choices: int, others: int) -> np.ndarray:
    """Every choice (choices^others, others) of one of ``choices`` per other marker."""
    return np.array(list(product(range(choices), repeat=others)), np.int64).reshape(-1, others)


def find_labelings(graph: PointGraph, model_d: np.ndarray, markers: tuple, tol_mm: float, *,
                   max_anchors: int = 64, per_marker: int = 3) -> Labelings:
    """Labelings of ``markers`` (3 to 5 marker numbers) among stereo points by the model's distances.

    Parameters
    ----------
    graph : PointGraph
        The stereo points' distances, mm, and which may be two markers.
    model_d : (5, 5)
        The model's pairwise distances, mm (:func:`model_distances`).
    markers : tuple of int
        The markers to label (all five, or four with one hidden).
    tol_mm : float
        Largest error of any pairwise distance, mm.
    max_anchors, per_marker : int
        The anchors (ordered point pairs of the longest edge's length, best
        first) tried, and the points kept per other marker and anchor: the
        bound on the labelings formed (module docstring).
    """
    D, apart = graph
    k = len(D)
    markers = tuple(markers)
    empty = Labelings(markers, np.zeros((0, len(markers)), np.int64), np.zeros(0), np.zeros(0))
    if k < len(markers):
        return empty
    plan = _plan(markers, model_d.tobytes())
    anchor_err = np.where(apart, np.abs(D - plan.anchor_mm), np.inf)
    ia, ib = np.nonzero(anchor_err <= tol_mm)           # both orders: (i, j) and (j, i)
    order = np.argsort(anchor_err[ia, ib], kind="stable")[:max_anchors]
    ia, ib = ia[order], ib[order]
    # Each other marker's points at its two distances from the anchor's ends: (others, A, K).
    e_a = np.abs(D[ia][None] - plan.to_a_mm[:, None, None])
    e_b = np.abs(D[ib][None] - plan.to_b_mm[:, None, None])
    e = np.where((e_a <= tol_mm) & (e_b <= tol_mm) & (apart[ia] & apart[ib])[None], e_a + e_b, np.inf)
    q = min(per_marker, k)
    best = np.argsort(e, axis=2, kind="stable")[:, :, :q]                            # (O, A, q)
    finite = np.isfinite(np.take_along_axis(e, best, axis=2))
    # Every combination of the others' choices per anchor: (A, C, O).
    combos = _combinations(q, len(plan.others))
    o = np.arange(len(plan.others))[None, None, :]
    anchors = np.arange(len(ia))[:, None, None]
    picked = best[o, anchors, combos[None]]
    ok = finite[o, anchors, combos[None]].all(axis=2).reshape(-1)
    index = np.concatenate([np.broadcast_to(ia[:, None, None], picked.shape[:2] + (1,)),
                            np.broadcast_to(ib[:, None, None], picked.shape[:2] + (1,)), picked],
                           axis=-1).reshape(-1, len(markers))[ok][:, plan.to_markers]
    # Every labelled pair's distance: within the tolerance, and of points that may be two markers.
    seen = D[index[:, plan.pair_i], index[:, plan.pair_j]]                            # (H, P)
    errors = np.abs(seen - plan.pair_mm)
    keep = (errors <= tol_mm).all(axis=1) & apart[index[:, plan.pair_i], index[:, plan.pair_j]].all(axis=1)
    index, seen, total = index[keep], seen[keep], errors[keep].sum(axis=1)
    scale = seen @ plan.pair_mm / (plan.pair_mm @ plan.pair_mm)
    shape = np.abs(seen - scale[:, None] * plan.pair_mm).sum(axis=1)
    order = np.argsort(shape, kind="stable")
    return Labelings(markers, index[order], shape[order], total[order])


class _Plan(NamedTuple):
    """How :func:`find_labelings` labels a set of markers: the anchor's model length, the other markers'
    distances to its ends (O,), the column order back to ``markers``, and every labelled pair (columns
    ``pair_i``, ``pair_j`` (P,) of a labeling, model distance ``pair_mm`` (P,) mm)."""

    anchor_mm: float
    others: tuple
    to_a_mm: np.ndarray
    to_b_mm: np.ndarray
    to_markers: np.ndarray
    pair_i: np.ndarray
    pair_j: np.ndarray
    pair_mm: np.ndarray


@lru_cache(maxsize=64)
def _plan(markers: tuple, model_d_bytes: bytes) -> _Plan:
    """The :class:`_Plan` of ``markers`` for the model distances (5, 5) given as bytes (a cache key):
    the anchor is the longest model edge among them."""
    model_d = np.frombuffer(model_d_bytes, dtype=np.float64).reshape(5, 5)
    pairs = [(a, b) for i, a in enumerate(markers) for b in markers[i + 1:]]
    a, b = max(pairs, key=lambda ab: model_d[ab])
    others = tuple(c for c in markers if c not in (a, b))
    labelled = (a, b, *others)
    cols = [(i, j) for i in range(len(markers)) for j in range(i + 1, len(markers))]
    return _Plan(float(model_d[a, b]), others, model_d[a, list(others)], model_d[b, list(others)],
                 np.array([labelled.index(m) for m in markers]), np.array([i for i, _ in cols]),
                 np.array([j for _, j in cols]), np.array([model_d[markers[i], markers[j]] for i, j in cols]))


