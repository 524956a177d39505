"""The *acquire* state: every blob of both images detected, and the five markers identified.

:class:`Identifier` is a part of :class:`~.tracker.Tracker` with no state
of its own (its settings and the marker model): blobs in, labelled markers
(a :class:`~.lock.Match`) or the reason for none out, with the count of
labelings it fitted (:meth:`Identifier.identify`, an
:class:`Identification`), on the rig in use and the tolerances it widens,
a :class:`~.tracker_rig.RigGeometry` given with each call. The blobs most
likely to be markers (:meth:`Identifier.candidates`); their stereo points
and the labelings of those by the model's distances (:mod:`.identify`, which
says why this bounds the cost); the best ``max_hypotheses`` labelings fitted
to the model (:meth:`Identifier._best_labeling`), or, when none fits, one
marker hidden in one view (:meth:`Identifier._hidden_marker`). The same
checks make a match of centres already labelled
(:meth:`Identifier.match_from_centers`, the *track* state's re-measure).
Centres in px, the model in mm.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import geometry as geo
from .detect import Blobs
from .identify import (DISTANCE_TOL_PER_FIT_TOL, collinear_in_image, find_labelings, model_distances,
                       point_graph, stereo_points)
from .lock import Match
from ..angles import angle_between_deg


def _scale_hint(points_mm: np.ndarray, model_mm: np.ndarray) -> str:
    """A hint on units when triangulated markers (5, 3) and the model (5, 3) differ in size, else "".

    Size: the RMS distance of the five points from their centroid. The
    markers seen 10, 25.4 or 1000 times the model's size mean a model in cm,
    inches or metres; any factor beyond 2 is worth saying.
    """
    def size(P):
        P = np.asarray(P, dtype=np.float64)
        return float(np.sqrt(np.mean(np.sum((P - P.mean(axis=0)) ** 2, axis=1))))

    seen, model = size(points_mm), size(model_mm)
    if not (model > 0 and np.isfinite(seen)) or 0.5 <= seen / model <= 2.0:
        return ""
    return (f"; the markers seen are {seen / model:.3g} times the size of the marker model: "
            "is markers.yaml in mm (docs/contract.md), and is it these glasses?")


# The sizes of the markers seen, relative to the model, that a model in other units gives (cm, inch, m).
_UNIT_FACTORS = (10.0, 25.4, 1000.0, 0.1, 1 / 25.4, 0.001)
# Cost of one glint-like blob in a labeling, in units of a full tolerance: a tie-breaker.
_GLINT_COST = 0.1


def _distinct(index: np.ndarray) -> np.ndarray:
    """Rows (H, n) of ``index`` whose entries are all different: (H,) bool."""
    s = np.sort(index, axis=1)
    return (s[:, 1:] != s[:, :-1]).all(axis=1)


# The markers shown when marker h (row) is hidden, in order.
_SHOWN = np.array([[m for m in range(5) if m != h] for h in range(5)])


class _Budget:
    """A frame's identification budget: each search (all five markers; one hidden) fits at most ``limit``
    labelings, the best first; how many were offered and fitted, and whether any search was cut."""

    def __init__(self, limit: int):
        self.limit, self.scored, self.offered, self.cut = limit, 0, 0, False

    def allow(self, offered: int) -> int:
        """How many of a search's ``offered`` labelings (best first) it may fit."""
        allowed = min(offered, self.limit)
        self.offered += offered
        self.cut |= allowed < offered
        return allowed


def _scan(error_mm: np.ndarray, allowed: int, markers: int, fit_tol_mm: float, fit) -> int:
    """Fit ranked labelings in growing chunks, ``fit(lo, hi)`` returning the best cost of labelings lo..hi-1
    (inf: none acceptable); stop when no later labeling can beat the best found or rival it, by their
    distance errors against the model at its true size (``error_mm`` (H,), in the ranking's order). The
    number fitted.

    The bound: a labeling whose points fit the model at an RMS ``r`` has its
    pairwise distances off by at most ``markers · (markers − 1) · r`` in total
    (each distance by two residuals; Cauchy-Schwarz over the markers), so its
    cost is at least ``error / (markers · (markers − 1) · fit_tol_mm)``; a rival
    costs at most twice the best plus 0.2 (:meth:`Identifier._ambiguous`).
    """
    least_after = np.minimum.accumulate(np.asarray(error_mm, dtype=np.float64)[::-1])[::-1]
    lo, chunk, best = 0, 16, np.inf
    while lo < allowed:
        hi = min(lo + chunk, allowed)
        best = min(best, fit(lo, hi))
        lo, chunk = hi, 2 * chunk
        if lo < allowed and least_after[lo] / (markers * (markers - 1) * fit_tol_mm) > 2 * best + 0.2:
            break
    return lo


class _Fits(NamedTuple):
    """Labelings (H, 5) fitted to the model: their blobs per view (candidate indices), points (H, 5, 3) mm,
    epipolar errors (H, 5) px, the fits (R (H, 3, 3), t (H, 3) mm, RMS (H,) mm), whether their blobs are
    distinct, and their costs (inf: not acceptable)."""

    left: np.ndarray
    right: np.ndarray
    points: np.ndarray
    epi: np.ndarray
    R: np.ndarray
    t: np.ndarray
    rms: np.ndarray
    distinct: np.ndarray
    cost: np.ndarray


class Identification(NamedTuple):
    """An identification's outcome: the labelled markers or the reason for none, and its cost.

    ``hypotheses``: the labelings (of five markers, or four with one hidden)
    fitted to the model, the identification's cost in units that do not
    depend on the machine.
    """

    match: Match | None
    reason: str | None
    hypotheses: int = 0


class Identifier:
    """The *acquire* state's identification of :class:`~.tracker.Tracker` (module docstring).

    Parameters
    ----------
    config : TrackerConfig
    model_mm : (5, 3) float
        The marker model, glasses frame, mm.
    axes_G : (3, 3) float
        The model's axes Ξ, Ψ, V (rows), glasses frame.
    """

    def __init__(self, config, model_mm: np.ndarray, axes_G: np.ndarray):
        self.ident_config = config
        self.ident_model_mm = model_mm
        self.ident_axes_G = axes_G
        self.model_d = model_distances(model_mm)

    def match_from_centers(self, centers, visible, index, g) -> Match | None:
        """Triangulate labeled centres (2, 5, 2) px and fit the model, on the rig ``g``
        (:class:`~.tracker_rig.RigGeometry`); None if they break the checks."""
        xn = [geo.undistort(centers[0], g.rig.K1, g.rig.D1), geo.undistort(centers[1], g.rig.K2, g.rig.D2)]
        epi = geo.epipolar_error_px(xn[0], xn[1], g.E, *g.focal)
        points, _ = geo.triangulate_midpoint(xn[0], xn[1], g.rig.R, g.rig.T)
        R, t, rms = geo.kabsch(self.ident_model_mm, points)
        if epi.max() > g.epipolar_tol_px or rms > g.fit_tol_mm:
            return None
        return Match(centers, visible, index, epi, points, R, t, float(rms))

    def candidates(self, b: Blobs) -> np.ndarray:
        """Indices of the blobs most likely to be markers, best first."""
        n = len(b)
        if n == 0:
            return np.zeros(0, np.int64)
        clean = np.flatnonzero(~b.glint)
        pool = clean if len(clean) else np.arange(n)
        # Typical marker size: the median of the five brightest clean blobs
        # (noise specks must not make the markers look oversized).
        brightest = pool[np.argsort(-b.flux_dn[pool])[:5]]
        typical = np.sort(b.area_px[brightest])[len(brightest) // 2]
        oversized = b.area_px > 6 * max(typical, 1)
        penalty = 2 * b.glint + 1 * oversized
        order = np.lexsort((-b.flux_dn, penalty))
        return order[: self.ident_config.max_candidates]

    def identify(self, blobs, g) -> Identification:
        """The five markers labelled in the (left, right) :class:`~.detect.Blobs`, on the rig ``g``
        (:class:`~.tracker_rig.RigGeometry`), or the reason for none.

        Stereo points first, then labelings by the model's distances
        (:mod:`.identify`), the best ``max_hypotheses`` of them fitted to the
        model; when no labeling of all five fits, one marker hidden in one
        view (:meth:`_hidden_marker`), with a budget of its own.
        """
        cand = [self.candidates(b) for b in blobs]
        counts = [len(c) for c in cand]
        names = ("left", "right")
        if min(counts) < 4 or (max(counts) < 5):
            cam = int(np.argmin(counts))
            return Identification(None, f"{names[cam]} image: {counts[cam]} marker blobs, 5 needed")
        xn = [geo.undistort(blobs[0].centers_px[cand[0]], g.rig.K1, g.rig.D1),
              geo.undistort(blobs[1].centers_px[cand[1]], g.rig.K2, g.rig.D2)]
        stereo = stereo_points(xn[0], xn[1], g, self.ident_config.working_range_mm)
        budget = _Budget(self.ident_config.max_hypotheses)
        tol_mm = DISTANCE_TOL_PER_FIT_TOL * g.fit_tol_mm
        graph = point_graph(stereo.points_mm, (stereo.left, stereo.right))
        labelings = find_labelings(graph, self.model_d, tuple(range(5)), tol_mm)
        match, reason = self._best_labeling(labelings, stereo, cand, blobs, g, budget)
        if match is None and self.ident_config.hidden_marker:
            alt, alt_reason = self._hidden_marker(stereo, graph, cand, blobs, g, tol_mm, budget)
            if alt is not None:
                return Identification(alt, None, budget.scored)
            reason = reason or alt_reason
        if match is None and not len(labelings):
            reason = self._other_units(graph, stereo, g, tol_mm) or reason
        if match is None and budget.cut:
            reason = (f"identification budget: {budget.scored} of {budget.offered} marker labelings fitted, "
                      f"the best first; {reason}")
        return Identification(match, reason, budget.scored)

    def _other_units(self, graph, stereo, g, tol_mm) -> str | None:
        """When no five points lie as the model's do: the reason, if they lie as the model would in other
        units (markers.yaml in cm, inches or m: the points 10, 25.4 or 1000 times its size, or a tenth...)."""
        for factor in _UNIT_FACTORS:
            found = find_labelings(graph, self.model_d * factor, tuple(range(5)), tol_mm * factor)
            if len(found):
                points = stereo.points_mm[found.index[0]]
                _, _, rms = geo.kabsch(self.ident_model_mm, points)
                return self._misfit_reason(float(rms), points, g)
        return None

    def _misfit_reason(self, rms_mm: float, points_mm: np.ndarray, g) -> str:
        """The reason for no pose when the best labeling's points (5, 3) mm fit the model at ``rms_mm``,
        beyond the rig ``g``'s tolerance; with a hint on units when their size says so."""
        return (f"no consistent stereo identification: the best labeling is {rms_mm:.1f} mm (RMS) "
                f"from the marker model, tolerance {g.fit_tol_mm:.1f} mm" + _scale_hint(points_mm, self.ident_model_mm))

    def _best_labeling(self, labelings, stereo, cand, blobs, g, budget) -> tuple[Match | None, str | None]:
        """The best of the five-marker labelings that fits the model and faces the cameras, or the reason."""
        if not len(labelings):
            return None, ("no consistent stereo identification: no five points pairing the two images within "
                          f"the epipolar tolerance ({g.epipolar_tol_px:.1f} px) lie as the marker model's do")
        fits = []

        def fit(lo, hi):
            fits.append(self._fit_labelings(labelings.index[lo:hi], stereo, cand, blobs, g))
            return float(fits[-1].cost.min())

        fitted = _scan(labelings.error_mm, budget.allow(len(labelings)), 5, self.ident_config.fit_tol_mm, fit)
        budget.scored += fitted
        f = _Fits(*(np.concatenate(column) for column in zip(*fits)))
        if not np.isfinite(f.cost).any():
            k = int(np.argmin(np.where(f.distinct, f.rms, np.inf)))
            return None, self._misfit_reason(f.rms[k], f.points[k], g)
        best = int(np.argmin(f.cost))
        if self._ambiguous(f.R, f.cost, best):
            return None, "ambiguous identification: two marker assignments fit equally well"
        index = np.stack([cand[0][f.left[best]], cand[1][f.right[best]]])
        return self._make_match(blobs, index, f.epi[best], f.points[best], f.R[best], f.t[best], f.rms[best]), None

    def _fit_labelings(self, labels, stereo, cand, blobs, g) -> "_Fits":
        """Five-marker labelings (H, 5) of stereo points fitted to the model; cost inf where not acceptable
        (a blob used twice, RMS beyond the tolerance, the glasses facing away)."""
        left, right = stereo.left[labels], stereo.right[labels]       # (H, 5)
        distinct = _distinct(left) & _distinct(right)
        points = stereo.points_mm[labels]
        epi = stereo.epipolar_px[labels]
        R, t, rms = geo.kabsch(self.ident_model_mm, points)
        valid = distinct & (rms <= g.fit_tol_mm) & self._facing_cameras(R, t, g) & self._trio_on_a_line(
            blobs[0].centers_px[cand[0][left]], blobs[1].centers_px[cand[1][right]])
        cost = np.where(valid, self._cost(rms, epi, blobs, cand, left, right), np.inf)
        return _Fits(left, right, points, epi, R, t, rms, distinct, cost)

    @staticmethod
    def _trio_on_a_line(*views_px) -> np.ndarray:
        """P0, P1, P2 collinear in each view's (H, n ≥ 3, 2) px, markers in order: (H,) bool."""
        return np.logical_and.reduce([collinear_in_image(v[:, 0], v[:, 1], v[:, 2]) for v in views_px])

    def _cost(self, rms, epi, blobs, cand, left, right) -> np.ndarray:
        """A labeling's cost: its errors in units of the image-noise tolerances (not of the rig-widened
        ones: widening must not make a clearly worse assignment a rival), plus a little per glint used."""
        glints = blobs[0].glint[cand[0]][left].sum(axis=1) + blobs[1].glint[cand[1]][right].sum(axis=1)
        return self._error_cost(rms, epi) + _GLINT_COST * glints

    def _error_cost(self, rms_mm, epipolar_px):
        """A fit's errors in units of the image-noise tolerances: RMS (...) mm, epipolar errors (..., 5) px
        (NaN: a marker not in both views)."""
        return (rms_mm / self.ident_config.fit_tol_mm
                + np.nanmax(epipolar_px, axis=-1) / self.ident_config.epipolar_tol_px)

    def _hidden_marker(self, stereo, graph, cand, blobs, g, tol_mm, budget) -> tuple[Match | None, str | None]:
        """One marker hidden in one view: four stereo points labelled by the model's distances (the best
        labelings over the five choices of the hidden marker, from the budget), the fifth marker the blob
        nearest its projection in one view (within ``hidden_search_px``)."""
        found = [find_labelings(graph, self.model_d, tuple(_SHOWN[hidden]), tol_mm) for hidden in range(5)]
        labels = np.concatenate([f.index for f in found])                           # (H, 4) stereo points
        hidden = np.concatenate([np.full(len(f), h) for h, f in enumerate(found)])
        order = np.argsort(np.concatenate([f.shape_mm for f in found]), kind="stable")
        error = np.concatenate([f.error_mm for f in found])[order]
        rows = []

        def fit(lo, hi):
            chosen = order[lo:hi]
            rows.extend(self._fit_hidden(labels[chosen], hidden[chosen], stereo, cand, blobs, g))
            return min((r[-1] for r in rows), default=np.inf)

        budget.scored += _scan(error, budget.allow(len(order)), 4, self.ident_config.fit_tol_mm, fit)
        if not rows:
            return None, "no consistent identification with a marker hidden in one view"
        cost = np.array([r[-1] for r in rows])
        best = int(np.argmin(cost))
        if self._ambiguous(np.array([r[3] for r in rows]), cost, best):
            return None, "ambiguous identification with a marker hidden in one view"
        return self._make_match(blobs, *rows[best][:-1]), None

    def _fit_hidden(self, labels, hidden, stereo, cand, blobs, g) -> list:
        """Four-marker labelings (H, 4) of stereo points, marker ``hidden`` (H,) not among them (the others
        in order), fitted to the model; each acceptable one with its fifth marker found in one view: a list
        of (index (2, 5), epipolar (5,), points (5, 3), R, t, rms, cost)."""
        n = len(labels)
        shown = _SHOWN[hidden]                                                      # (H, 4) marker numbers
        rows_ = np.arange(n)[:, None]
        left = np.full((n, 5), -1)
        right = np.full((n, 5), -1)
        left[rows_, shown], right[rows_, shown] = stereo.left[labels], stereo.right[labels]
        points = np.zeros((n, 5, 3))
        points[rows_, shown] = stereo.points_mm[labels]
        weights = np.ones((n, 5))
        weights[np.arange(n), hidden] = 0.0
        R, t, rms = geo.kabsch(self.ident_model_mm, points, weights)
        valid = (_distinct(stereo.left[labels]) & _distinct(stereo.right[labels]) & (rms <= g.fit_tol_mm)
                 & self._facing_cameras(R, t, g))
        # The trio P0-P1-P2 on a line in both views, where it is shown in both.
        trio = self._trio_on_a_line(blobs[0].centers_px[cand[0][np.maximum(left, 0)]],
                                    blobs[1].centers_px[cand[1][np.maximum(right, 0)]])
        valid &= trio | (hidden <= 2)
        valid = np.flatnonzero(valid)
        view, blob = self._find_hidden(hidden[valid], R[valid], t[valid], cand, blobs, g,
                                       stereo.left[labels[valid]], stereo.right[labels[valid]])
        out = []
        for h, v, b in zip(valid, view, blob):
            if v < 0:
                continue
            index = np.full((2, 5), -1)
            index[0, shown[h]], index[1, shown[h]] = cand[0][left[h, shown[h]]], cand[1][right[h, shown[h]]]
            index[v, hidden[h]] = cand[v][b]
            epi = np.full(5, np.nan)
            epi[shown[h]] = stereo.epipolar_px[labels[h]]
            pts = points[h].copy()
            pts[hidden[h]] = np.nan
            out.append((index, epi, pts, R[h], t[h], rms[h], self._error_cost(rms[h], epi)))
        return out

    def _find_hidden(self, hidden, R, t, cand, blobs, g, used_left, used_right) -> tuple[np.ndarray, np.ndarray]:
        """For poses (R (V, 3, 3), t (V, 3) mm) of four markers, the (view, candidate) of the blob nearest
        the projection of the hidden one (``hidden`` (V,)), within ``hidden_search_px``, among the blobs
        each pose's labeling did not use (``used_left``, ``used_right`` (V, 4)): two (V,) int arrays, −1
        where none."""
        points = np.einsum("vij,vj->vi", R, self.ident_model_mm[hidden]) + t                      # (V, 3)
        best_d = np.full(len(points), np.inf)
        best_view, best_blob = np.full(len(points), -1), np.full(len(points), -1)
        if not len(points):
            return best_view, best_blob
        rows = np.arange(len(points))[:, None]
        projected = g.cameras.project(points)                                                     # (2, V, 2)
        for view, used in ((0, used_left), (1, used_right)):
            px = projected[view]
            dist = np.linalg.norm(blobs[view].centers_px[cand[view]][None, :, :] - px[:, None, :], axis=2)
            dist[rows, used] = np.inf
            j = np.argmin(dist, axis=1)
            d = dist[rows[:, 0], j]
            better = (d <= self.ident_config.hidden_search_px) & (d < best_d)
            best_d = np.where(better, d, best_d)
            best_view, best_blob = np.where(better, view, best_view), np.where(better, j, best_blob)
        return best_view, best_blob

    def _make_match(self, blobs, index, epi, points, R, t, rms) -> Match:
        visible = index >= 0
        centers = np.full((2, 5, 2), np.nan)
        for cam in range(2):
            centers[cam, visible[cam]] = blobs[cam].centers_px[index[cam, visible[cam]]]
        epi = np.where(visible.all(axis=0), epi, np.nan)
        sigma, flux, shot = np.full((2, 5), np.nan), np.full((2, 5), np.nan), np.full((2, 5, 2), np.nan)
        for cam in range(2):
            sigma[cam, visible[cam]] = blobs[cam].sigma_px[index[cam, visible[cam]]]
            flux[cam, visible[cam]] = blobs[cam].flux_dn[index[cam, visible[cam]]]
            if blobs[cam].shot_var is not None:
                shot[cam, visible[cam]] = blobs[cam].shot_var[index[cam, visible[cam]]]
        return Match(centers, visible, index, epi, points, R, t, float(rms), sigma, flux, shot_var=shot)

    def _facing_cameras(self, R, t, g) -> np.ndarray:
        """The glasses' front (V) must face the cameras: retro-reflectors are seen only from the front."""
        v = np.einsum("...ij,j->...i", R, self.ident_axes_G[2])
        to_cams = g.cameras_mid_mm - t
        return np.einsum("...i,...i->...", v, to_cams) > 0

    def _ambiguous(self, R, cost, best) -> bool:
        """Another acceptable identification nearly as good as the best, with a different V.

        "Nearly as good": cost below twice the best's plus 0.2 (costs are
        errors in units of their tolerances). A hypothesis that merely passes
        the tolerances while the best fits at the noise level is not a rival.
        """
        v = np.einsum("...ij,j->...i", R, self.ident_axes_G[2])
        rivals = np.isfinite(cost) & (cost <= 2 * cost[best] + 0.2)
        return bool(np.any(angle_between_deg(v[rivals], v[best]) > self.ident_config.ambiguity_deg))
