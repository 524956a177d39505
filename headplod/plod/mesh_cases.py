"""The crack-free cases of an adaptive mesh's base face: one index template per case, and the triangle counts.

A base face of level ``L`` whose edges carry the levels ``(e0, e1, e2)``
(each ``>= L``; edge 0: corner 0→1, 1: 1→2, 2: 2→0) is triangulated by its
case's :class:`Template` (see :mod:`headplod.plod.mesh` for the scheme: the
uniform level-``L`` lattice, fans to a refined edge's extra points from the
opposite vertex, or from an inserted centroid where two sides of a
sub-triangle are refined). Templates live in a face's local lattice and
know nothing of a terrain: the meshes (:mod:`headplod.plod.mesh_base`)
place their points.

Lattice units: a face is ``3 * 2**M`` units along each barycentric
direction (``M`` the finest level), so level-``L`` vertices and the
centroids of the level-``L`` sub-triangles are whole lattice keys ``(B,
C)`` (the weights of corners 1 and 2, times ``3 * 2**M``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Template:
    """Triangulation of one case, in a face's local lattice.

    Points are either on the face's boundary (local edge ``boundary_edge``,
    position ``boundary_k`` in units of 1/2**max_level of the edge from its
    start corner; corners are k = 0 of the edge they start) or interior
    (barycentric weights of the face's corners 0, 1, 2).

    Attributes
    ----------
    boundary_edge : (Pb,) int64
    boundary_k : (Pb,) int64
    interior_bary : (Pi, 3) float64
    interior_keys : (Pi, 2) int64
        The interior points' lattice keys (B, C) in units of 1/(3 * 2**M) of
        the face (``interior_bary`` = ((3N − B − C), B, C) / 3N).
    triangles : (T, 3) int32
        Indices into the concatenation [boundary points, interior points],
        counter-clockwise like the face.
    """

    boundary_edge: np.ndarray
    boundary_k: np.ndarray
    interior_bary: np.ndarray
    interior_keys: np.ndarray
    triangles: np.ndarray


def build_template(max_level: int, level: int, edge_levels) -> Template:
    """Triangulate a face of ``level`` whose edges carry ``edge_levels`` (each >= level).

    Parameters
    ----------
    max_level : int
        Finest level M; positions are kept in units of 1/(3 * 2**M) of the face.
    level : int
        The face's level L.
    edge_levels : (3,) int
        Levels of the face's edges 0 (corner 0→1), 1 (1→2), 2 (2→0).

    Returns
    -------
    Template
    """
    M, L = int(max_level), int(level)
    e = [int(v) for v in edge_levels]
    if not 0 <= L <= M or any(not L <= v <= M for v in e):
        raise ValueError(f"need 0 <= level <= edge levels <= max_level, got L={L}, e={e}, M={M}")
    keys, tris = _triangulate(M, L, e)
    return _template_of(keys, tris, 3 * 2 ** M)


def _edge_points(p, q, steps: int) -> list:
    """Lattice keys from ``p`` to ``q`` inclusive in ``steps`` equal steps (``steps + 1`` keys)."""
    return [(p[0] + (q[0] - p[0]) * t // steps, p[1] + (q[1] - p[1]) * t // steps) for t in range(steps + 1)]


def _triangulate(M: int, L: int, e: list) -> tuple[dict, list]:
    """The case's triangles over lattice keys.

    Returns
    -------
    keys : dict (B, C) -> int
        Every point used, numbered in order of first use.
    tris : list of (3,) int tuples
        Point numbers of each triangle, counter-clockwise: per level-L up
        triangle (b, c) its fan or itself, then the down triangle beside it.
    """
    N3 = 3 * 2 ** M
    n = 2 ** L
    s = N3 // n                     # one level-L step in lattice units
    keys: dict[tuple[int, int], int] = {}
    tris: list[tuple[int, int, int]] = []

    def pid(key):
        if key not in keys:
            keys[key] = len(keys)
        return keys[key]

    for b in range(n):
        for c in range(n - b):
            corners = [(b * s, c * s), ((b + 1) * s, c * s), (b * s, (c + 1) * s)]
            on_edge = [c == 0, b + c == n - 1, b == 0]      # sub-edge j lies on base edge j
            refined = [on_edge[j] and e[j] > L for j in range(3)]
            tris.extend(_up_triangle(corners, refined, e, L, pid))
            if b + c <= n - 2:      # the down triangle to the right of this up triangle
                tris.append((pid(((b + 1) * s, c * s)), pid(((b + 1) * s, (c + 1) * s)), pid((b * s, (c + 1) * s))))
    return keys, tris


def _up_triangle(corners, refined, e, L, pid) -> list:
    """Triangles of one level-L up triangle: itself, a fan from the vertex opposite its one refined side, or
    a fan from its centroid over its ring (two or three sides refined). ``pid`` numbers keys on first use."""
    r = sum(refined)
    if r == 0:
        return [(pid(corners[0]), pid(corners[1]), pid(corners[2]))]
    if r == 1:
        j = refined.index(True)
        pts = _edge_points(corners[j], corners[(j + 1) % 3], 2 ** (e[j] - L))
        apex = pid(corners[(j + 2) % 3])
        return [(pid(p), pid(q), apex) for p, q in zip(pts[:-1], pts[1:])]
    ring = []
    for j in range(3):
        steps = 2 ** (e[j] - L) if refined[j] else 1
        ring.extend(_edge_points(corners[j], corners[(j + 1) % 3], steps)[:-1])
    centre = (sum(k[0] for k in corners) // 3, sum(k[1] for k in corners) // 3)
    apex = pid(centre)
    return [(pid(p), pid(q), apex) for p, q in zip(ring, ring[1:] + ring[:1])]


def _template_of(keys: dict, tris: list, N3: int) -> Template:
    """The :class:`Template` of numbered lattice keys and triangles: boundary points first (by edge
    position), then interior ones, each kind in order of first use."""
    N = N3 // 3
    boundary, interior = [], []
    for key, i in keys.items():
        B3, C3 = key
        if C3 == 0 and B3 < N3:
            boundary.append((i, 0, B3 // 3))
        elif B3 + C3 == N3 and C3 < N3:
            boundary.append((i, 1, C3 // 3))
        elif B3 == 0:
            boundary.append((i, 2, N - C3 // 3))
        else:
            interior.append((i, (N3 - B3 - C3) / N3, B3 / N3, C3 / N3))
    remap = np.empty(len(keys), dtype=np.int64)
    remap[[t[0] for t in boundary]] = np.arange(len(boundary))
    remap[[t[0] for t in interior]] = len(boundary) + np.arange(len(interior))
    return Template(
        boundary_edge=np.array([t[1] for t in boundary], dtype=np.int64),
        boundary_k=np.array([t[2] for t in boundary], dtype=np.int64),
        interior_bary=np.array([t[1:] for t in interior], dtype=np.float64).reshape(-1, 3),
        interior_keys=np.array([[t[2] * N3, t[3] * N3] for t in interior], dtype=np.float64).round()
                        .astype(np.int64).reshape(-1, 2),
        triangles=remap[np.array(tris, dtype=np.int64)].astype(np.int32),
    )


def triangle_count_table(max_level: int) -> np.ndarray:
    """Triangles per case, (M+1, M+1, M+1, M+1) int64 indexed [L, e0, e1, e2] (0 where e < L).

    ``4**L`` + for each refined edge ``2**L * (2**(e-L) - 1)`` + 2 per
    sub-triangle with two or more refined edges (the centroid fans).
    """
    M = int(max_level)
    L, e0, e1, e2 = np.meshgrid(*[np.arange(M + 1)] * 4, indexing="ij")
    r = [e > L for e in (e0, e1, e2)]
    count = 4 ** L
    for e, ri in zip((e0, e1, e2), r):
        count = count + ri * 2 ** L * (2 ** np.maximum(e - L, 0) - 1)
    multi = np.where(L == 0, (r[0].astype(int) + r[1] + r[2]) >= 2,
                     (r[0] & r[2]).astype(int) + (r[0] & r[1]) + (r[1] & r[2]))
    count = count + 2 * multi
    valid = (e0 >= L) & (e1 >= L) & (e2 >= L)
    return np.where(valid, count, 0).astype(np.int64)
