"""Identification of the markers P0..P4 among the blobs of one image.

Martinez et al. (2008, §4.1, steps 4-7): the three collinear markers are P0,
P1, P2 with P1 in the middle; of the two others, the one nearer an end marker
Pa is Pa's partner, and the sign of (Pa − P1) × (Pa' − P1) tells whether Pa is
P0 or P2. The paper prints the rule for its own glasses and image axes; here
every part of it is derived from the marker model (docs/contract.md):

- the partner of P0 is whichever of P3, P4 is nearer to it in the model;
- a camera sees the glasses from their front (retro-reflectors face G's +z),
  and such a view maps G's (x, y) plane to the image (x right, y down) with a
  negative determinant (camera z = −G z gives det R[:2, :2] = R[2, 2] < 0), so
  the expected image sign of the cross product is minus its sign in G;
- where P1 sits between P0 and P2, and on which side of the P0-P2 line P3 and
  P4 lie, also come from the model.

Collinearity survives any projection (lines map to lines, also through lens
distortion to first order over the glasses' few tens of pixels), so the trio
test holds at any head angle. The nearest-partner step does not always (strong
yaw or perspective can reverse it), so besides the paper's labeling each trio
also yields the other labelings as second-rank hypotheses; the stereo stage
(epipolar error and rigid fit to the model) decides between them.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from ..tol import tol


@dataclass(frozen=True)
class ModelRule:
    """The paper's identification rule, derived from a marker model.

    Attributes
    ----------
    middle_ratio : float
        |P1 − P0| / |P2 − P0| in the model (0.5 for the default).
    partner_of_p0 : int
        3 or 4: the marker nearer to P0 in the model.
    image_sign : float
        Expected sign of cross(P0 − P1, partner − P1) in an image (x right,
        y down) of the glasses seen from the front.
    same_side : bool
        P3 and P4 lie on the same side of the P0-P2 line.
    """

    middle_ratio: float
    partner_of_p0: int
    image_sign: float
    same_side: bool

    @classmethod
    def from_model(cls, model_mm: np.ndarray) -> "ModelRule":
        p = np.asarray(model_mm, dtype=np.float64)
        ratio = np.linalg.norm(p[1] - p[0]) / np.linalg.norm(p[2] - p[0])
        partner = 3 if np.linalg.norm(p[3] - p[0]) <= np.linalg.norm(p[4] - p[0]) else 4
        a, b = p[0] - p[1], p[partner] - p[1]
        sign_g = np.sign(a[0] * b[1] - a[1] * b[0])
        if sign_g == 0:
            raise ValueError("marker model: P0's partner lies on the P0-P2 axis; the markers cannot be told apart")
        same_side = bool(np.sign(p[3, 1]) == np.sign(p[4, 1]) != 0)
        return cls(float(ratio), partner, float(-sign_g), same_side)


@dataclass
class Hypotheses:
    """Labeled candidate subsets of one image.

    Attributes
    ----------
    index : (k, 5) int
        Blob index of P0..P4 in each hypothesis.
    rank : (k,) int
        0 for the paper's labeling, 1 for the alternatives.
    collinearity_px : (k,)
        Distance of P1 from the P0-P2 line, px.
    """

    index: np.ndarray
    rank: np.ndarray
    collinearity_px: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


def find_hypotheses(centers_px: np.ndarray, rule: ModelRule, *, line_tol_px: float = 1.5,
                    line_tol_rel: float = 0.04, ratio_tol: float = 0.3,
                    alternatives: bool = True) -> Hypotheses:
    """All labelings P0..P4 of 5 of the given blob centres allowed by the rule.

    Parameters
    ----------
    centers_px : (m, 2)
        Blob centres in one image, px.
    rule : ModelRule
    line_tol_px, line_tol_rel : float
        A trio is collinear when the middle blob is within
        ``line_tol_px + line_tol_rel · |P0P2|`` of the line through the ends
        (relative part: centroid errors and lens curvature grow with size).
    ratio_tol : float
        Allowed deviation of |P1P0| / |P2P0| from the model (perspective and
        foreshortening change the ratio; 0.3 still excludes near-end blobs).
    alternatives : bool
        Also emit the three other labelings of each trio and pair (rank 1).
    """
    pts = np.asarray(centers_px, dtype=np.float64)
    m = len(pts)
    empty = Hypotheses(np.zeros((0, 5), np.int64), np.zeros(0, np.int64), np.zeros(0))
    if m < 5:
        return empty
    trios = np.array(list(combinations(range(m), 3)), dtype=np.int64)
    # Each trio with each of its members as the middle: (ends a, b; middle c).
    arrangements = np.concatenate([trios[:, [0, 2, 1]], trios[:, [0, 1, 2]], trios[:, [1, 2, 0]]])
    a, b, c = (pts[arrangements[:, i]] for i in range(3))
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    along = np.einsum("ij,ij->i", c - a, ab) / np.maximum(length, tol.small) ** 2
    off_line = np.abs(ab[:, 0] * (c - a)[:, 1] - ab[:, 1] * (c - a)[:, 0]) / np.maximum(length, tol.small)
    ratio_ok = (np.abs(along - rule.middle_ratio) <= ratio_tol) | (np.abs(1 - along - rule.middle_ratio) <= ratio_tol)
    ok = (off_line <= line_tol_px + line_tol_rel * length) & ratio_ok & (along > 0.05) & (along < 0.95)
    rows, ranks, lines = [], [], []
    for (ia, ib, ic), dev in zip(arrangements[ok], off_line[ok]):
        rest = [j for j in range(m) if j not in (ia, ib, ic)]
        for ip, iq in combinations(rest, 2):
            labelings = _labelings(pts, ia, ib, ic, ip, iq, rule)
            for rank, lab in labelings:
                if rank and not alternatives:
                    continue
                rows.append(lab)
                ranks.append(rank)
                lines.append(dev)
    if not rows:
        return empty
    return Hypotheses(np.array(rows, np.int64), np.array(ranks, np.int64), np.array(lines))


def _labelings(pts, ia, ib, ic, ip, iq, rule: ModelRule):
    """The paper's labeling (rank 0) and the other three (rank 1) of one trio + pair."""
    mid = pts[ic]
    if rule.same_side:
        # P3 and P4 on the same side of the P0-P2 line, as in the model.
        d = pts[ib] - pts[ia]
        side_p = np.sign(d[0] * (pts[ip] - pts[ia])[1] - d[1] * (pts[ip] - pts[ia])[0])
        side_q = np.sign(d[0] * (pts[iq] - pts[ia])[1] - d[1] * (pts[iq] - pts[ia])[0])
        if side_p != side_q:
            return []
    # Paper, steps 6-7: Pa = ia; its partner is the nearer of the two others.
    near, far = (ip, iq) if np.linalg.norm(pts[ip] - pts[ia]) <= np.linalg.norm(pts[iq] - pts[ia]) else (iq, ip)
    u, v = pts[ia] - mid, pts[near] - mid
    sign = np.sign(u[0] * v[1] - u[1] * v[0])
    if sign == rule.image_sign:
        p0, p2, partner0, partner2 = ia, ib, near, far
    else:
        p0, p2, partner0, partner2 = ib, ia, far, near
    def label(p0_, p2_, q0, q2):
        out = [0] * 5
        out[0], out[1], out[2] = p0_, ic, p2_
        other = 7 - rule.partner_of_p0       # 3 <-> 4
        out[rule.partner_of_p0], out[other] = q0, q2
        return out
    paper = label(p0, p2, partner0, partner2)
    result = [(0, paper)]
    for lab in (label(p0, p2, partner2, partner0), label(p2, p0, partner0, partner2),
                label(p2, p0, partner2, partner0)):
        result.append((1, lab))
    return result
