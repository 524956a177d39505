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
3. the labelings are ranked by their total distance error, and only the best
   ``budget`` of them are fitted to the model by the caller.

Costs: the epipolar matrix is blobs², the distance matrix stereo points²,
and the labelings are at most ``max_anchors`` × ``per_marker``³, fixed, so a
frame's cost grows with the square of the blobs in its vectorized parts and
not at all in its combinations. A labeling whose points fit the model rigidly
within an RMS of ``fit_tol`` mm has no pairwise distance off by more than
√10 · ``fit_tol`` (two residuals of at most that RMS over five points), so
that distance tolerance drops no labeling the final fit would accept.

The labeling itself needs no image rule: a labeling that mirrors the model
(P0↔P2 and P3↔P4 for a symmetric model) fits only with the glasses turned
away from the cameras, which the caller rejects (retro-reflectors are seen
only from the front).
"""
from __future__ import annotations

from itertools import product
from typing import NamedTuple

import numpy as np

from . import geometry as geo

# The fit-RMS tolerance times this bounds each pairwise distance's error (module docstring).
DISTANCE_TOL_PER_FIT_TOL = float(np.sqrt(10.0))


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
    """Labelings of some markers among stereo points, best (smallest distance error) first.

    ``markers`` the marker numbers labelled, in order; ``index`` (H, len(markers))
    the stereo point of each; ``error_mm`` (H,) the sum of the labelled
    pairwise distances' absolute errors against the model, mm; ``found``
    the labelings within the tolerances before any cap.
    """

    markers: tuple
    index: np.ndarray
    error_mm: np.ndarray
    found: int

    def __len__(self) -> int:
        return len(self.index)

    def best(self, count: int) -> "Labelings":
        """The first ``count`` labelings."""
        return Labelings(self.markers, self.index[:count], self.error_mm[:count], self.found)


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


def find_labelings(points_mm: np.ndarray, model_d: np.ndarray, markers: tuple, tol_mm: float, *,
                   max_anchors: int = 64, per_marker: int = 3) -> Labelings:
    """Labelings of ``markers`` (3 to 5 marker numbers) among stereo points by the model's distances.

    Parameters
    ----------
    points_mm : (K, 3)
        Stereo points, mm.
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
    P = np.asarray(points_mm, dtype=np.float64)
    k = len(P)
    markers = tuple(markers)
    empty = Labelings(markers, np.zeros((0, len(markers)), np.int64), np.zeros(0), 0)
    if k < len(markers):
        return empty
    D = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)
    # The anchor: the longest model edge among the markers labelled.
    pairs = [(a, b) for i, a in enumerate(markers) for b in markers[i + 1:]]
    a, b = max(pairs, key=lambda ab: model_d[ab])
    others = [c for c in markers if c not in (a, b)]
    anchor_err = np.abs(D - model_d[a, b])
    np.fill_diagonal(anchor_err, np.inf)
    ia, ib = np.nonzero(anchor_err <= tol_mm)           # both orders: (i, j) and (j, i)
    order = np.argsort(anchor_err[ia, ib], kind="stable")[:max_anchors]
    ia, ib = ia[order], ib[order]
    err = anchor_err[ia, ib]
    choices, choice_err = [], []
    for c in others:
        e_a, e_b = np.abs(D[ia] - model_d[a, c]), np.abs(D[ib] - model_d[b, c])   # (A, K)
        e = np.where((e_a <= tol_mm) & (e_b <= tol_mm), e_a + e_b, np.inf)
        e[np.arange(len(ia)), ia] = np.inf
        e[np.arange(len(ia)), ib] = np.inf
        q = min(per_marker, k)
        best = np.argsort(e, axis=1, kind="stable")[:, :q]                         # (A, q)
        choices.append(best)
        choice_err.append(np.take_along_axis(e, best, axis=1))
    # Every combination of the others' choices per anchor: (A, q^n, n).
    combos = np.array(list(product(range(choices[0].shape[1]), repeat=len(others))), np.int64)
    picked = np.stack([choices[j][:, combos[:, j]] for j in range(len(others))], axis=-1)
    total = err[:, None] + sum(choice_err[j][:, combos[:, j]] for j in range(len(others)))
    index = np.concatenate([np.broadcast_to(ia[:, None, None], picked.shape[:2] + (1,)),
                            np.broadcast_to(ib[:, None, None], picked.shape[:2] + (1,)), picked], axis=-1)
    index, total = index.reshape(-1, len(markers)), total.reshape(-1)
    ok = np.isfinite(total)
    for j1 in range(len(others)):
        for j2 in range(j1 + 1, len(others)):
            e = np.abs(D[index[:, 2 + j1], index[:, 2 + j2]] - model_d[others[j1], others[j2]])
            ok &= (e <= tol_mm) & (index[:, 2 + j1] != index[:, 2 + j2])
            total = total + e
    index, total = index[ok], total[ok]
    # Back to the order of ``markers``.
    labelled = (a, b, *others)
    index = index[:, [labelled.index(m) for m in markers]]
    order = np.argsort(total, kind="stable")
    return Labelings(markers, index[order], total[order], len(index))
