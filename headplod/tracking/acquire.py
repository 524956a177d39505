"""The *acquire* state: every blob of both images detected, and the five markers identified.

:class:`Identifier` is a part of :class:`~.tracker.Tracker` with no state
of its own (its settings and the marker model): blobs in, labelled markers
(a :class:`~.lock.Match`) or the reason for none out
(:meth:`Identifier.identify`), on the rig in use and the tolerances it
widens, a :class:`~.tracker_rig.RigGeometry` given with each call. The
blobs most likely to be markers (:meth:`Identifier.candidates`), their
labelings P0..P4 in each image (:mod:`.identify`), the left/right pair of
labelings that best fits the epipolar geometry and the model
(:meth:`Identifier._best_pair`), or, when none does, one marker hidden in
one view (:meth:`Identifier._hidden_marker`). The same checks make a match
of centres already labelled (:meth:`Identifier.match_from_centers`, the
*track* state's re-measure). Centres in px, the model in mm.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import geometry as geo
from .detect import Blobs
from .identify import ModelRule, find_hypotheses
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


class Identification(NamedTuple):
    """An identification's outcome: the labelled markers or the reason for none, and its cost.

    ``hypotheses``: the labelled five-marker hypotheses scored (triangulated
    and fitted to the model), the identification's cost in units that do
    not depend on the machine.
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
        self.rule = ModelRule.from_model(model_mm)

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
        (:class:`~.tracker_rig.RigGeometry`), or the reason for none."""
        cand = [self.candidates(b) for b in blobs]
        counts = [len(c) for c in cand]
        names = ("left", "right")
        if min(counts) < 4 or (max(counts) < 5):
            cam = int(np.argmin(counts))
            return Identification(None, f"{names[cam]} image: {counts[cam]} marker blobs, 5 needed")
        hyps = [find_hypotheses(blobs[i].centers_px[cand[i]], self.rule) if counts[i] >= 5 else None
                for i in range(2)]
        xn = [geo.undistort(blobs[0].centers_px[cand[0]], g.rig.K1, g.rig.D1),
              geo.undistort(blobs[1].centers_px[cand[1]], g.rig.K2, g.rig.D2)]
        match, reason, scored = None, None, [0]
        if hyps[0] is not None and hyps[1] is not None and len(hyps[0]) and len(hyps[1]):
            match, reason = self._best_pair(hyps, xn, cand, blobs, g, scored)
        if match is None and self.ident_config.hidden_marker:
            alt, alt_reason = self._hidden_marker(hyps, xn, cand, blobs, g, scored)
            if alt is not None:
                return Identification(alt, None, scored[0])
            reason = reason or alt_reason
        if match is None and reason is None:
            missing = [names[i] for i in range(2) if hyps[i] is None or not len(hyps[i])]
            reason = (f"{' and '.join(missing)} image: no five blobs in the markers' layout (three in a line "
                      "and two beside)" if missing else "no consistent stereo identification")
        return Identification(match, reason, scored[0])

    @staticmethod
    def _epipolar_matrix(xn, g) -> np.ndarray:
        """Epipolar error (px) of every left candidate against every right one: (m_left, m_right)."""
        return geo.epipolar_error_px(xn[0][:, None, :], xn[1][None, :, :], g.E, *g.focal)

    def _best_pair(self, hyps, xn, cand, blobs, g, scored) -> tuple[Match | None, str | None]:
        """The left/right pair of labelings that best fits the epipolar geometry and the model.

        Pairs are screened by a lookup in the candidates' epipolar-error
        matrix before anything is triangulated; the paper's labelings are
        tried first and the alternatives only when none of those fits.
        """
        hl, hr = hyps
        epi_matrix = self._epipolar_matrix(xn, g)
        tol = g.epipolar_tol_px
        best_reason = None
        for ranks in ((0,), (0, 1)):
            il_all = np.flatnonzero(hl.rank <= max(ranks))
            ir_all = np.flatnonzero(hr.rank <= max(ranks))
            il = np.repeat(il_all, len(ir_all))
            ir = np.tile(ir_all, len(il_all))
            epi = epi_matrix[hl.index[il], hr.index[ir]]           # (P, 5) by lookup
            keep = epi.max(axis=1) <= tol
            if not keep.any():
                best_reason = (f"no consistent stereo identification: no labeling of the left blobs matches "
                               f"one of the right blobs within the epipolar tolerance ({tol:.1f} px)")
                continue
            il, ir, epi = il[keep], ir[keep], epi[keep]
            scored[0] += len(il)
            xl = xn[0][hl.index[il]]            # (P, 5, 2)
            xr = xn[1][hr.index[ir]]
            points, _ = geo.triangulate_midpoint(xl, xr, g.rig.R, g.rig.T)
            R, t, rms = geo.kabsch(self.ident_model_mm, points)
            valid = (rms <= g.fit_tol_mm) & self._facing_cameras(R, t, g)
            if not valid.any():
                k = int(np.argmin(rms))
                best_reason = (f"no consistent stereo identification: the best labeling is {rms[k]:.1f} mm "
                               f"(RMS) from the marker model, tolerance {g.fit_tol_mm:.1f} mm"
                               + _scale_hint(points[k], self.ident_model_mm))
                continue
            # Ranked in units of the image-noise tolerances, not of the rig-widened
            # ones: widening must not make a clearly worse assignment a rival.
            cost = (rms / self.ident_config.fit_tol_mm + epi.max(axis=1) / self.ident_config.epipolar_tol_px
                    + 0.05 * (hl.rank[il] + hr.rank[ir]))
            cost = np.where(valid, cost, np.inf)
            best = int(np.argmin(cost))
            if self._ambiguous(R, cost, best):
                return None, "ambiguous identification: two marker assignments fit equally well"
            index = np.stack([cand[0][hl.index[il[best]]], cand[1][hr.index[ir[best]]]])
            return self._make_match(blobs, index, epi[best], points[best], R[best], t[best], rms[best]), None
        return None, best_reason

    def _hidden_marker(self, hyps, xn, cand, blobs, g, scored) -> tuple[Match | None, str | None]:
        """One marker hidden in one view: label the full view, match the other's blobs to it.

        For each labeled marker, the other view's blobs within the epipolar
        tolerance are its only possible partners; the assignments are the
        products of those short lists with exactly one marker hidden.
        """
        epi_matrix = self._epipolar_matrix(xn, g)
        tol = g.epipolar_tol_px
        best = None
        for full in (0, 1):
            other = 1 - full
            h = hyps[full]
            if h is None or not len(h) or len(cand[other]) < 4:
                continue
            rows, hyp_of_row = [], []
            for k, labels in enumerate(h.index[h.rank == 0] if (h.rank == 0).any() else h.index):
                errors = epi_matrix[labels, :] if full == 0 else epi_matrix[:, labels].T     # (5, m_other)
                options = [np.flatnonzero(errors[j] <= tol) for j in range(5)]
                for hidden in range(5):
                    lists = [options[j] if j != hidden else np.array([-1]) for j in range(5)]
                    if any(len(o) == 0 for o in lists):
                        continue
                    combos = np.array(np.meshgrid(*lists, indexing="ij")).reshape(5, -1).T
                    shown = combos[:, [j for j in range(5) if j != hidden]]
                    distinct = np.array([len(set(r)) == 4 for r in shown.tolist()])
                    rows.append(combos[distinct])
                    hyp_of_row.append(np.full(int(distinct.sum()), k))
            if not rows:
                continue
            assignments = np.concatenate(rows)
            labels_full = (h.index[h.rank == 0] if (h.rank == 0).any() else h.index)[np.concatenate(hyp_of_row)]
            if len(assignments) == 0:
                continue
            scored[0] += len(assignments)
            xf = xn[full][labels_full]                                   # (P, 5, 2)
            xo = xn[other][np.maximum(assignments, 0)]
            weights = (assignments >= 0).astype(np.float64)
            xl, xr = (xf, xo) if full == 0 else (xo, xf)
            epi = np.where(weights > 0, geo.epipolar_error_px(xl, xr, g.E, *g.focal), 0.0)
            points, _ = geo.triangulate_midpoint(xl, xr, g.rig.R, g.rig.T)
            R, t, rms = geo.kabsch(self.ident_model_mm, points, weights)
            valid = (rms <= g.fit_tol_mm) & self._facing_cameras(R, t, g)
            if not valid.any():
                continue
            cost = np.where(valid, rms / self.ident_config.fit_tol_mm + epi.max(axis=1) / self.ident_config.epipolar_tol_px, np.inf)
            k = int(np.argmin(cost))
            if self._ambiguous(R, cost, k):
                return None, "ambiguous identification with a marker hidden in one view"
            if best is None or cost[k] < best[0]:
                index = np.full((2, 5), -1)
                index[full] = cand[full][labels_full[k]]
                shown = assignments[k] >= 0
                index[other, shown] = cand[other][assignments[k][shown]]
                pts = np.where(weights[k][:, None] > 0, points[k], np.nan)
                best = (cost[k], index, epi[k], pts, R[k], t[k], rms[k])
        if best is None:
            return None, "no consistent identification with a marker hidden in one view"
        return self._make_match(blobs, *best[1:]), None

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
