"""Crack-free adaptive subdivision of a terrain's base mesh.

Scene units are those of the terrain (metres for ``Terrain.jacksboro``: x
east, y north, z up). The base mesh is a regular grid of ``nx x ny`` quads
over the terrain's extent, two triangles each (2048 triangles for 32 x 32),
counter-clockwise seen from +z.

Levels
------
Each base face ``f`` has a level ``L_f`` in ``0..max_level``; level ``L`` is
``L`` rounds of 1-to-4 midpoint subdivision (``4**L`` triangles), every
vertex lying on the terrain (heights sampled at its (x, y)). Each base edge
gets the level ``max(L)`` of its faces. A face whose edge has a higher level
than its own takes that edge's extra vertices: each of its level-``L``
sub-triangles with a side on that edge becomes a fan from its opposite vertex
to the edge's points or, if two of its sides are refined (a corner
sub-triangle, or the whole face at level 0), a fan from an inserted vertex at
its centroid. Every face's triangulation is therefore fixed by its *case*
``(L, e0, e1, e2)`` (its level and the levels of its edges 0: corner 0→1,
1: 1→2, 2: 2→0). One index template per case is built once (Python, cached)
and applied to all faces of that case at once with numpy gathers.

Watertightness: every vertex on a base edge is read from one array per edge
computed once in the edge's canonical direction (lower global vertex index to
higher), at the finest level, so both faces of an edge use bit-identical
floats, and the corners are the base vertices themselves. Two neighbours of
different levels meet with the same points on their shared edge, hence no
T-junctions at any mix of levels. Big level jumps between neighbours give
long thin fan triangles (still valid); a selector that keeps neighbours within
one level of each other gets well-shaped transitions.

Output
------
Every vertex any case can use is sampled once, when the mesh is made, into
one static **vertex table** (``vertex_positions``, ``vertex_normals``): the
canonical edge points once per edge level (an edge's normals are
prefiltered for its level) and every face's interior points per level. A
build is then only indices into that table:

- ``AdaptiveMesh.update_indices`` gives the triangles as indices into the
  table, ready for ``glDrawElements`` over a table uploaded once: a change
  of levels moves 12 bytes per triangle, not 72 (``TerrainRenderer.
  set_indices``);
- ``AdaptiveMesh.update`` gives the same triangles as a **non-indexed
  triangle soup** (the table gathered by those indices): three consecutive
  rows of ``positions`` (and ``normals``) per triangle, ready for
  ``glDrawArrays(GL_TRIANGLES)``.

Both are counter-clockwise seen from +z, float32. Normals are the terrain's
analytic normals at each vertex (smooth shading that is continuous across
faces and levels).

Where the parts are
-------------------
:class:`AdaptiveMesh` is the ``kind == "table"`` implementation of
:class:`headplod.plod.mesh_base.AdaptiveMeshBase` (the interface, and the
level checks, cases, counts, soup, sharing and contrast both kinds share);
the base mesh is :class:`headplod.plod.mesh_base.BaseMesh`, the case
templates are :mod:`headplod.plod.mesh_cases` (both importable from here
as before).
"""
from __future__ import annotations

import time

import numpy as np
from scipy import sparse

from .change import level_change_contrast, normal_cone
from .shading import AMBIENT, LIGHT_DIR
from .mesh_base import (LEVEL_PALETTE, AdaptiveMeshBase, BaseMesh, _face_areas_xy,  # noqa: F401 (re-exported)
                        _sample)
from .mesh_cases import Template, build_template, triangle_count_table  # noqa: F401 (re-exported)

#: Base faces per block of the per-level edge lengths (bounds the (faces, pairs, 3) temporaries).
_FACE_CHUNK = 128


class _Store:
    """The cached index blocks, (m, 3T) uint32 into the vertex table, of all faces currently in one case."""

    __slots__ = ("faces", "indices")

    def __init__(self, faces, indices):
        self.faces, self.indices = faces, indices


class AdaptiveMesh(AdaptiveMeshBase):
    """Per-face-level subdivision of a base mesh over a terrain, rebuilt incrementally.

    Parameters
    ----------
    base : BaseMesh
        Its vertices should lie on the terrain (``BaseMesh.grid`` does that).
    terrain : object
        ``heights(x, y)``, ``normals(x, y)`` (or ``sample(x, y) -> (z, normals)``),
        vectorized over arrays, scene units.
    max_level : int
        Finest level M (each base face then has up to 4**M triangles); 5 takes
        the default 2048-face base to 2,097,152 triangles.
    light_dir : (3,) float
        Direction *towards* the light, scene frame, used for ``contrast``
        (default: :data:`headplod.plod.shading.LIGHT_DIR`, the light every
        back end draws with, so the contrast is the one the viewer sees).
    ambient : float
        Ambient fraction of the shading used for ``contrast`` (default
        :data:`headplod.plod.shading.AMBIENT`).
    normal_filter : float
        Normals of a level-L vertex are those of the terrain prefiltered by
        a Gaussian of σ = ``normal_filter`` x the level's grid spacing (0 at
        the finest level, which stays exact): a coarse level then shades
        like the average of the detail it leaves out rather than like a
        point sample of it (normal mip-mapping), which brings a coarse
        level's image closer to ``full``'s (``headplod bench plod``). An edge's points take its level's normals (both
        faces share them: no seam); the base vertices keep exact ones.

    Attributes
    ----------
    centroids : (F, 3) float64
        Mean of each base face's corners, scene units.
    edge_length : (F, M+1) float64
        Longest 3-D edge of the face's pieces at each uniform level, scene units.
    geometric_error : (F, M+1) float64
        Largest vertical distance between the uniform level-L surface and the
        finest (level M) surface over the face, sampled at every finest-level
        vertex, scene units (0 at level M).
    z_range : (F, 2) float64
        Lowest and highest z of any vertex any case of the face can produce,
        scene units (the vertices lie above the base triangle's (x, y)
        within it: a prism bounding the face, see
        :func:`headplod.render.foveate.face_layer_span`).
    bounding_radius : (F,) float64
        Radius about ``centroids`` of a sphere holding every vertex any case of
        the face can produce (finest-level lattice and centroid-fan vertices,
        as rounded to float32 in the output), scene units.
    contrast : (F,) float64
        Michelson contrast ``(max - min) / (max + min)`` of the Lambertian
        shading ``ambient + (1 - ambient) max(n·l, 0)`` over the face's
        finest-level vertices.
    change_contrast : (F, M+1) float64
        Michelson contrast of what each uniform level removes from the drawn
        image over the face (:func:`headplod.plod.change.level_change_contrast`; 0 at level M).
    normal_axis : (F, 3) float64, normal_cone_deg : (F,) float64
        The cone holding the face's finest normals: its unit axis (scene
        frame) and half-angle, deg (:func:`headplod.plod.change.normal_cone`).
    vertex_positions : (V, 3) float32
        The vertex table, scene units: every vertex any build can use
        (``update_indices`` indexes it): the vertices of every level of
        every base face, those of a shared edge once.
    vertex_normals : (V, 3) float32
        Unit normal of each table row (prefiltered for the row's level).
    stats : dict
        After each ``update`` / ``update_indices``: ``rebuilt_faces``,
        ``rebuilt_triangles``, ``triangles``, ``build_ms`` (index gathers of
        the rebuilt faces), ``assemble_ms`` (concatenation, and for
        ``update`` the gather of the soup from the table).
    last_rebuilt_faces : (k,) int64
        Base faces rebuilt by the last ``update``.

    Capabilities (:class:`headplod.plod.mesh_base.AdaptiveMeshBase`):
    ``kind == "table"``, ``has_full_table`` True, ``full_fits`` up to
    :data:`headplod.plod.mesh_base.FULL_MAX_LEVEL`.
    """

    kind = "table"
    has_full_table = True

    def __init__(self, base: BaseMesh, terrain, max_level: int = 5, *,
                 light_dir=LIGHT_DIR, ambient: float = AMBIENT, normal_filter: float = 0.25):
        super().__init__(base, terrain, max_level, normal_filter)
        edge_pos = self._edge_points(terrain)
        self._level_points(terrain)
        self._vertex_table()
        self._face_data(light_dir, ambient, edge_pos)
        self.clear()

    def _edge_points(self, terrain) -> np.ndarray:
        """Sample the canonical edge points at the finest level, once per edge level for the normals.

        Sets ``_edge_pos`` (E, N+1, 3) and ``_edge_nrm`` (M+1, E, N+1, 3),
        float32, k = 0 and N being the base vertices (N = 2**M); heights
        are exact at every level, normals prefiltered for the edge's level.
        Returns the positions in float64 (the per-face data read them).
        """
        base, M = self.base, self.max_level
        N = 2 ** M
        lo, hi = base.edges[:, 0], base.edges[:, 1]
        t = np.arange(N + 1) / N
        pa, pb = base.vertices[lo][:, None, :2], base.vertices[hi][:, None, :2]
        xy = pa + t[None, :, None] * (pb - pa)
        edge_pos = np.empty((len(lo), N + 1, 3))
        edge_nrm = np.empty((M + 1, len(lo), N + 1, 3))          # per level of the edge
        edge_pos[..., :2] = xy
        if N > 1:
            inner_x, inner_y = xy[:, 1:-1, 0].ravel(), xy[:, 1:-1, 1].ravel()
            for L in range(M + 1):                                  # loop over levels
                z, nrm = _sample(terrain, inner_x, inner_y, self.normal_filter_m[L] if L < M else None)
                edge_nrm[L, :, 1:-1] = nrm.reshape(len(lo), N - 1, 3)
            edge_pos[:, 1:-1, 2] = z.reshape(len(lo), N - 1)       # heights are exact at every level
        _, vnrm = _sample(terrain, base.vertices[:, 0], base.vertices[:, 1])
        edge_pos[:, 0], edge_pos[:, N] = base.vertices[lo], base.vertices[hi]
        edge_nrm[:, :, 0], edge_nrm[:, :, N] = vnrm[lo], vnrm[hi]
        self._edge_pos = edge_pos.astype(np.float32)
        self._edge_nrm = edge_nrm.astype(np.float32)
        return edge_pos

    def _level_points(self, terrain) -> None:
        """Every interior point a face of each level can use, sampled once for every face.

        A level-L face's interior points are its level-L lattice points and
        the centres of its corner fans; the template with all three edges
        refined to the finest level has all of them. Heights are exact,
        normals prefiltered for the level (``normal_filter``), so building a
        face later is a gather, with no terrain evaluation.
        """
        M = self.max_level
        N3 = 3 * 2 ** M
        corners = self.base.vertices[self.base.faces][..., :2]                 # (F, 3, 2)
        self._points = []
        for L in range(M + 1):                                                 # loop over levels
            keys = build_template(M, L, (M, M, M)).interior_keys
            index = {(int(b), int(c)): i for i, (b, c) in enumerate(keys)}
            bary = np.column_stack([N3 - keys[:, 0] - keys[:, 1], keys[:, 0], keys[:, 1]]) / N3
            F, K = len(corners), len(keys)
            pos = np.zeros((F, K, 3), np.float32)
            nrm = np.zeros((F, K, 3), np.float32)
            if K:
                xy = np.einsum("pk,mkd->mpd", bary, corners)                   # (F, K, 2)
                z, n = _sample(terrain, xy[..., 0].ravel(), xy[..., 1].ravel(),
                               self.normal_filter_m[L] if L < M else None)
                pos[..., :2] = xy
                pos[..., 2] = z.reshape(F, K)
                nrm[:] = n.reshape(F, K, 3)
            self._points.append((index, pos, nrm))
        self._interior_index: dict[int, np.ndarray] = {}

    def _vertex_table(self) -> None:
        """Concatenate the edge points (once per edge level) and the level point tables into one table.

        Rows: ``edge_vertex(l, e, k) = (l * E + e) * (N + 1) + k`` for edge
        ``e`` at level ``l`` (position ``k`` in 1/N of the edge, canonical
        direction), then level ``L``'s interior points at
        ``_interior_offset[L] + f * K_L + i``. The level tables become views
        into the table (no second copy).
        """
        M, E = self.max_level, len(self.base.edges)
        n_edge = (M + 1) * E * (2 ** M + 1)
        sizes = [pos.shape[0] * pos.shape[1] for _, pos, _ in self._points]
        self._interior_offset = n_edge + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        total = n_edge + int(sum(sizes))
        if total >= 2 ** 32:
            raise ValueError(f"AdaptiveMesh: {total} table vertices do not fit 32-bit indices; "
                             f"use fewer base faces or a lower max_level")
        positions = np.empty((total, 3), np.float32)
        normals = np.empty((total, 3), np.float32)
        positions[:n_edge] = np.broadcast_to(self._edge_pos, (M + 1, *self._edge_pos.shape)).reshape(-1, 3)
        normals[:n_edge] = self._edge_nrm.reshape(-1, 3)
        for L, (index, pos, nrm) in enumerate(self._points):                   # loop over levels
            a, F, K = int(self._interior_offset[L]), pos.shape[0], pos.shape[1]
            positions[a:a + F * K] = pos.reshape(-1, 3)
            normals[a:a + F * K] = nrm.reshape(-1, 3)
            self._points[L] = (index, positions[a:a + F * K].reshape(F, K, 3),
                               normals[a:a + F * K].reshape(F, K, 3))
        self.vertex_positions, self.vertex_normals = positions, normals

    def _interior(self, case_id: int, tpl: "Template", level: int) -> np.ndarray:
        """Indices of a template's interior points in its level's point table, cached."""
        idx = self._interior_index.get(case_id)
        if idx is None:
            index = self._points[level][0]
            idx = np.array([index[(int(b), int(c))] for b, c in tpl.interior_keys], dtype=np.int64)
            self._interior_index[case_id] = idx
        return idx


    # ------------------------------------------------------------------ building
    def _build(self, groups):
        """Index blocks of rebuilt faces into the vertex table.

        Parameters
        ----------
        groups : list of (case_id, fids (m,) int64)
            Faces grouped by their (new) case.

        Returns
        -------
        list of (m, 3T) uint32, in the order of ``groups``.
        """
        base, N = self.base, 2 ** self.max_level
        M1, E = self.max_level + 1, len(base.edges)
        out = []
        for cid, fids in groups:                                                   # loop over cases
            tpl = self.template(cid)
            level, e0, e1, e2 = np.unravel_index(cid, (M1,) * 4)
            elev = np.array([e0, e1, e2])[tpl.boundary_edge]                       # each edge at its level
            eids = base.face_edges[fids][:, tpl.boundary_edge]                     # (m, Pb)
            fwd = base.face_edge_forward[fids][:, tpl.boundary_edge]
            kk = np.where(fwd, tpl.boundary_k, N - tpl.boundary_k)
            boundary = (elev[None, :] * E + eids) * (N + 1) + kk
            K = self._points[level][1].shape[1]
            interior = (self._interior_offset[level] + fids[:, None] * K
                        + self._interior(cid, tpl, level)[None, :])
            rows = np.concatenate([boundary, interior], axis=1)
            out.append(rows[:, tpl.triangles.reshape(-1)].astype(np.uint32))
        return out

    def update_indices(self, levels):
        """Triangles for per-face levels as indices into the vertex table, rebuilding only changed cases.

        As :meth:`AdaptiveMeshBase.update_indices`: ``indices`` (3T,) uint32
        rows of the static ``vertex_positions``, ``level_per_triangle`` (T,)
        uint8.

        Notes
        -----
        Triangles are grouped by case, then by the order in which faces
        entered that case; ``face_per_triangle()`` gives each one's base
        face. The returned arrays are reused (returned again) when no case
        changes; do not modify them.
        """
        t0 = time.perf_counter()
        case = self.cases(levels)
        changed = case != self._case
        rebuilt = np.flatnonzero(changed)
        self.last_rebuilt_faces = rebuilt
        n_rebuilt_tris = self._rebuild(case, changed, rebuilt) if len(rebuilt) else 0
        t1 = time.perf_counter()
        if self._output is None:
            self._output = self._assemble()
            self._soup = None
        t2 = time.perf_counter()
        self.stats = {"rebuilt_faces": int(len(rebuilt)), "rebuilt_triangles": int(n_rebuilt_tris),
                      "triangles": int(len(self._output[1])),
                      "build_ms": 1e3 * (t1 - t0), "assemble_ms": 1e3 * (t2 - t1)}
        return self._output

    def _rebuild(self, case, changed, rebuilt) -> int:
        """Move the faces ``rebuilt`` (``changed`` (F,) bool) from their old case's store to their new
        case's, with their index blocks built anew; the number of triangles built."""
        old_cases = np.unique(self._case[rebuilt])
        for key in old_cases[old_cases >= 0].tolist():  # loop over the cases that lose faces
            store = self._stores[key]
            keep = ~changed[store.faces]
            if not keep.all():
                if keep.any():
                    self._stores[key] = _Store(store.faces[keep], store.indices[keep])
                else:
                    del self._stores[key]
        new_case = case[rebuilt]
        order = np.argsort(new_case, kind="stable")
        ids, starts = np.unique(new_case[order], return_index=True)
        groups = list(zip(ids.tolist(), np.split(rebuilt[order], starts[1:])))
        n_tris = 0
        for (cid, fids), idx in zip(groups, self._build(groups)):              # loop over cases
            n_tris += idx.size // 3
            store = self._stores.get(cid)
            if store is None:
                self._stores[cid] = _Store(fids, idx)
            else:
                self._stores[cid] = _Store(np.concatenate([store.faces, fids]),
                                           np.concatenate([store.indices, idx]))
        self._case = case
        self._output = None
        return n_tris

    def _assemble(self):
        """(indices (3T,) uint32, level_per_triangle (T,) uint8) of the stores, by ascending case."""
        keys = sorted(self._stores)
        stores = [self._stores[k] for k in keys]
        if not stores:
            return np.zeros(0, np.uint32), np.zeros(0, np.uint8)
        M1 = self.max_level + 1
        indices = np.concatenate([s.indices.reshape(-1) for s in stores])
        lv = np.repeat(np.array([k // M1 ** 3 for k in keys], dtype=np.uint8), [s.indices.size // 3 for s in stores])
        return indices, lv

    def clear(self) -> None:
        """Forget the cached blocks: the next ``update`` builds every face from scratch."""
        self._case = np.full(self.n_faces, -1, dtype=np.int64)
        self._stores: dict[int, _Store] = {}
        self._output = None          # (indices, level_per_triangle) of the current cases
        self._soup = None            # (positions, normals, level_per_triangle) gathered from it
        self.last_rebuilt_faces = np.zeros(0, dtype=np.int64)

    def face_per_triangle(self) -> np.ndarray:
        """Base face of each triangle of the last ``update`` output, (T,) int64."""
        stores = [self._stores[k] for k in sorted(self._stores)]
        if not stores:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([np.repeat(s.faces, s.indices.shape[1] // 3) for s in stores])

    # ------------------------------------------------------------------ per-face data
    def _face_data(self, light_dir, ambient, edge_pos):
        """Centroids, corners, per-level edge lengths and geometric errors, bounds, shading normals, contrast."""
        fine, fine_n, B, C, index = self._fine_lattice(edge_pos)
        corners = self.base.vertices[self.base.faces]                            # (F, 3, 3)
        self.corners = corners.astype(np.float64)           # (F, 3, 3) scene units
        self.centroids = corners.mean(axis=1)
        interpolation, level_rows = self._level_sizes(fine, B, C, index)
        self._bounds(fine, corners)
        self._shading_normals = fine_n                      # (F, P, 3) float32: shading_contrast
        self.contrast = self.shading_contrast(light_dir, ambient)
        # What each level removes, coloured over the whole terrain's heights as the renderers colour it.
        height_range = (float(self.z_range[:, 0].min()), float(self.z_range[:, 1].max()))
        terrain, filters = self.terrain, self.normal_filter_m
        self.change_contrast = level_change_contrast(
            fine, fine_n, interpolation, level_rows, lambda L, x, y: _sample(terrain, x, y, filters[L])[1],
            height_range, light_dir, ambient)
        self.normal_axis, self.normal_cone_deg = normal_cone(fine_n)

    def _fine_lattice(self, edge_pos):
        """Every face's finest-lattice points (no centroids), boundary points from the canonical edges.

        Returns
        -------
        fine : (F, P, 3) float64
            Positions, scene units.
        fine_n : (F, P, 3) float32
            Their unit normals (exact: the finest level is not prefiltered).
        B, C : (P,) int64
            Lattice coordinates of each point: B along corner 0→1, C along 0→2, in 1/N (N = 2**M).
        index : (N + 2, N + 2) int64
            Point of each (B, C), -1 where none.
        """
        M = self.max_level
        N = 2 ** M
        base = self.base
        full = build_template(M, M, (M, M, M))               # the finest lattice, no centroids
        eids = base.face_edges[:, full.boundary_edge]
        kk = np.where(base.face_edge_forward[:, full.boundary_edge], full.boundary_k, N - full.boundary_k)
        parts, nparts = [edge_pos[eids, kk]], [self._edge_nrm[M, eids, kk]]
        if len(full.interior_bary):
            _, pos_table, nrm_table = self._points[M]                # sampled once, exact at level M
            inner = self._interior(int(np.ravel_multi_index((M,) * 4, (M + 1,) * 4)), full, M)
            parts.append(pos_table[:, inner].astype(np.float64))
            nparts.append(nrm_table[:, inner])
        fine = np.concatenate(parts, axis=1)                                     # (F, P, 3)
        fine_n = np.concatenate(nparts, axis=1)
        B = np.empty(fine.shape[1], dtype=np.int64)
        C = np.empty_like(B)
        nb = len(full.boundary_edge)
        e, k = full.boundary_edge, full.boundary_k
        B[:nb] = np.select([e == 0, e == 1, e == 2], [k, N - k, 0])
        C[:nb] = np.select([e == 0, e == 1, e == 2], [0, k, N - k])
        B[nb:] = np.rint(full.interior_bary[:, 1] * N).astype(np.int64)
        C[nb:] = np.rint(full.interior_bary[:, 2] * N).astype(np.int64)
        index = np.full((N + 2, N + 2), -1, dtype=np.int64)
        index[B, C] = np.arange(len(B))
        return fine, fine_n, B, C, index

    def _level_sizes(self, fine, B, C, index):
        """``edge_length`` and ``geometric_error`` (F, M+1) of every uniform level, from the finest lattice.

        Returns each level < M's interpolation matrix (sparse (P, P), :meth:`_interpolation_matrix`) and the
        lattice points that are its vertices ((P_L,) int), for :func:`level_change_contrast`.
        """
        M, F = self.max_level, self.n_faces
        N = 2 ** M
        self.edge_length = np.zeros((F, M + 1))
        self.geometric_error = np.zeros((F, M + 1))
        z_fine = fine[..., 2]
        interpolation, level_rows = [], []
        for L in range(M + 1):                              # loop over levels
            s = N // 2 ** L
            # Edges of the uniform level-L grid: along B, along C, and the diagonals.
            b, c = np.nonzero(np.add.outer(np.arange(2 ** L + 1), np.arange(2 ** L + 1)) <= 2 ** L)
            pairs = []
            for db, dc, ok in ((1, 0, b + c + 1 <= 2 ** L), (0, 1, b + c + 1 <= 2 ** L),
                               (-1, 1, (b >= 1))):
                pairs.append(np.column_stack([index[b[ok] * s, c[ok] * s],
                                              index[(b[ok] + db) * s, (c[ok] + dc) * s]]))
            pairs = np.concatenate(pairs)
            for a in range(0, F, _FACE_CHUNK):              # loop over blocks of faces: bounded temporaries
                d = fine[a:a + _FACE_CHUNK, pairs[:, 0]] - fine[a:a + _FACE_CHUNK, pairs[:, 1]]
                self.edge_length[a:a + _FACE_CHUNK, L] = np.sqrt((d ** 2).sum(-1)).max(axis=1)
            if L < M:
                W = self._interpolation_matrix(L, B, C, index, N)
                self.geometric_error[:, L] = np.abs(z_fine - (W @ z_fine.T).T).max(axis=1)
                interpolation.append(W)
                level_rows.append(np.flatnonzero((B % s == 0) & (C % s == 0)))
        return interpolation, level_rows

    def _bounds(self, fine, corners) -> None:
        """``z_range`` and ``bounding_radius``: the finest lattice and the centroid-fan vertices of every level."""
        M, F = self.max_level, self.n_faces
        # Vertices of the centroid fans: centroids of the corner up-triangles at every level < M.
        cbary = []
        for L in range(M):
            n = 2 ** L
            for b, c in {(0, 0), (n - 1, 0), (0, n - 1)}:
                cbary.append(((3 * n - 3 * b - 3 * c - 2) / (3 * n), (3 * b + 1) / (3 * n), (3 * c + 1) / (3 * n)))
        radius = np.sqrt(((fine - self.centroids[:, None]) ** 2).sum(-1)).max(axis=1)
        if cbary:
            xy = np.einsum("pk,mkd->mpd", np.array(cbary), corners[..., :2])
            z, _ = _sample(self.terrain, xy[..., 0].ravel(), xy[..., 1].ravel())
            extra = np.concatenate([xy, z.reshape(F, -1, 1)], axis=2)
            radius = np.maximum(radius, np.sqrt(((extra - self.centroids[:, None]) ** 2).sum(-1)).max(axis=1))
            z_lo = np.minimum(fine[..., 2].min(axis=1), extra[..., 2].min(axis=1))
            z_hi = np.maximum(fine[..., 2].max(axis=1), extra[..., 2].max(axis=1))
        else:
            z_lo, z_hi = fine[..., 2].min(axis=1), fine[..., 2].max(axis=1)
        # Every vertex of the face lies above its base triangle (x, y) within these heights (plus
        # the float32 rounding of the output: one ulp of the largest coordinate).
        ulp = 2 * np.finfo(np.float32).eps * np.abs(fine).max(axis=(1, 2))
        self.z_range = np.stack([z_lo - ulp, z_hi + ulp], axis=1)
        # Plus the float32 rounding of the output coordinates (half an ulp per component).
        self.bounding_radius = radius + np.sqrt(3) * np.finfo(np.float32).eps * np.abs(fine).max(axis=(1, 2))

    @staticmethod
    def _interpolation_matrix(L, B, C, index, N):
        """Sparse (P, P) matrix: level-L piecewise-linear surface at each finest lattice point."""
        s = N // 2 ** L
        u, v = B / s, C / s
        b, c = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - b, v - c
        up = fu + fv <= 1
        # Up triangle (b,c),(b+1,c),(b,c+1); down triangle (b+1,c),(b+1,c+1),(b,c+1).
        vb = np.where(up[:, None], [[0, 1, 0]], [[1, 1, 0]]) + b[:, None]
        vc = np.where(up[:, None], [[0, 0, 1]], [[0, 1, 1]]) + c[:, None]
        w = np.where(up[:, None], np.column_stack([1 - fu - fv, fu, fv]),
                     np.column_stack([1 - fv, fu + fv - 1, 1 - fu]))
        nz = w > 0
        rows = np.broadcast_to(np.arange(len(B))[:, None], w.shape)[nz]
        cols = index[np.minimum(vb[nz] * s, N + 1), np.minimum(vc[nz] * s, N + 1)]
        if np.any(cols < 0):
            raise RuntimeError("interpolation touched a point outside the lattice")   # programming error
        return sparse.csr_matrix((w[nz], (rows, cols)), shape=(len(B), len(B)))
