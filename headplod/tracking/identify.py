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
    off_line = np.abs(ab[..., 0] * ac[..., 1] - ab[..., 1] * ac[..., 0]) / np.maximum(length, 1e-9)
    along = np.einsum("...i,...i->...", ac, ab) / np.maximum(length, 1e-9) ** 2
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


def stereo_points(xn_left: np.ndarray, xn_right: np.ndarray, g, depth_range_mm: tuple) -> StereoPoints:
    """Every epipolar-consistent left-right pair of undistorted centres, triangulated.

    ``xn_left`` (m, 2), ``xn_right`` (n, 2): normalized coordinates; ``g`` a
    :class:`~.tracker_rig.RigGeometry` (its ``epipolar_tol_px``, essential
    matrix, focal lengths and rig); ``depth_range_mm`` (near, far): the
    points' depth in both cameras, mm.
    """
    epi = geo.epipolar_error_px(xn_left[:, None, :], xn_right[None, :, :], g.E, *g.focal)   # (m, n)
    left, right = np.nonzero(epi <= g.epipolar_tol_px)
    points, _ = geo.triangulate_midpoint(xn_left[left], xn_right[right], g.rig.R, g.rig.T)
    depth_right = points @ np.asarray(g.rig.R)[2] + np.reshape(g.rig.T, 3)[2]
    near, far = depth_range_mm
    keep = (points[:, 2] >= near) & (points[:, 2] <= far) & (depth_right >= near) & (depth_right <= far)
    return StereoPoints(left[keep], right[keep], points[keep], epi[left[keep], right[keep]])


def model_distances(model_mm: np.ndarray) -> np.ndarray:
    """Pairwise distances (5, 5) of the marker model, mm."""
    P = np.asarray(model_mm, dtype=np.float64)
    return np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)


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
    P = np.asarray(points_mm, dtype=np.float64)
    D = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)
    if blobs is None:
        apart = ~np.eye(len(P), dtype=bool)
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
    # The anchor: the longest model edge among the markers labelled.
    pairs = [(a, b) for i, a in enumerate(markers) for b in markers[i + 1:]]
    a, b = max(pairs, key=lambda ab: model_d[ab])
    others = [c for c in markers if c not in (a, b)]
    anchor_err = np.where(apart, np.abs(D - model_d[a, b]), np.inf)
    ia, ib = np.nonzero(anchor_err <= tol_mm)           # both orders: (i, j) and (j, i)
    order = np.argsort(anchor_err[ia, ib], kind="stable")[:max_anchors]
    ia, ib = ia[order], ib[order]
    err = anchor_err[ia, ib]
    choices, choice_err = [], []
    for c in others:
        e_a, e_b = np.abs(D[ia] - model_d[a, c]), np.abs(D[ib] - model_d[b, c])   # (A, K)
        e = np.where((e_a <= tol_mm) & (e_b <= tol_mm) & apart[ia] & apart[ib], e_a + e_b, np.inf)
        q = min(per_marker, k)
        best = np.argsort(e, axis=1, kind="stable")[:, :q]                         # (A, q)
        choices.append(best)
        choice_err.append(np.take_along_axis(e, best, axis=1))
    # Every combination of the others' choices per anchor: (A, q^n, n).
    combos = _combinations(choices[0].shape[1], len(others))
    picked = np.stack([choices[j][:, combos[:, j]] for j in range(len(others))], axis=-1)
    total = err[:, None] + sum(choice_err[j][:, combos[:, j]] for j in range(len(others)))
    index = np.concatenate([np.broadcast_to(ia[:, None, None], picked.shape[:2] + (1,)),
                            np.broadcast_to(ib[:, None, None], picked.shape[:2] + (1,)), picked], axis=-1)
    index, total = index.reshape(-1, len(markers)), total.reshape(-1)
    ok = np.isfinite(total)
    for j1 in range(len(others)):
        for j2 in range(j1 + 1, len(others)):
            e = np.abs(D[index[:, 2 + j1], index[:, 2 + j2]] - model_d[others[j1], others[j2]])
            ok &= (e <= tol_mm) & apart[index[:, 2 + j1], index[:, 2 + j2]]
            total = total + e
    index, total = index[ok], total[ok]
    # Back to the order of ``markers``.
    labelled = (a, b, *others)
    index = index[:, [labelled.index(m) for m in markers]]
    shape = _shape_error(D, index, model_d, markers)
    order = np.argsort(shape, kind="stable")
    return Labelings(markers, index[order], shape[order], total[order])


def _shape_error(D: np.ndarray, index: np.ndarray, model_d: np.ndarray, markers: tuple) -> np.ndarray:
    """Sum over the labelled pairs of |distance − s · model distance|, s the least-squares scale per
    labeling: (H,) mm for ``index`` (H, n) into the points' distance matrix ``D`` (K, K)."""
    pairs = [(i, j) for i in range(len(markers)) for j in range(i + 1, len(markers))]
    seen = np.stack([D[index[:, i], index[:, j]] for i, j in pairs], axis=1)        # (H, P)
    model = np.array([model_d[markers[i], markers[j]] for i, j in pairs])
    scale = seen @ model / (model @ model)
    return np.abs(seen - scale[:, None] * model).sum(axis=1)
