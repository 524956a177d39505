"""Crack-free adaptive subdivision made lazily: geometry only for the cases a selection asks for.

:class:`headplod.plod.mesh.AdaptiveMesh` samples, when it is made, every
vertex any level of any base triangle can use (1.9 million rows at level 5
on the 32 x 32 base; about 68 million at level 8, gigabytes).
:class:`LazyAdaptiveMesh` draws the same triangulation (the same cases,
templates and canonical edge points: see :mod:`headplod.plod.mesh`) but
samples the terrain only for what a frame draws, and keeps what it sampled
in a least-recently-used cache bounded in bytes:

- an **edge piece** ``(edge, level)``: the points of one base edge at one
  edge level, in the edge's canonical direction (lower global vertex index
  to higher), ``2**level + 1`` of them, normals prefiltered for that level;
  level-0 edges are the base vertices and are not cached;
- a **face piece** ``(face, case)``: the interior points (level lattice and
  centroid-fan centres) of one base triangle for one case
  ``(L, e0, e1, e2)``, normals prefiltered for ``L``.

Each base face keeps a **block**: its case's points (the boundary points
read from its edges' pieces, then its face piece), made again only when
its case changes, as :class:`AdaptiveMesh` rebuilds only faces whose case
changed. A frame with new cases concatenates the blocks into a compact
per-frame table (grouped by case, then face: ``AdaptiveMesh``'s order for
a build from scratch) and offsets each case template's indices; a frame
with the same cases returns the same arrays. The table repeats a shared
edge's points once per face (bit-identical copies, a fifth more rows
than one shared copy), which the renderer draws alike. Keeping each face's
block until its case changes makes a changed frame cost a fraction of
assembling every face again (``headplod bench plod --only lazy``); what is
left is mostly the terrain evaluation of new pieces (its synthetic detail
waves) and the frame's concatenation.

Both faces of an edge read its points from the *same* edge piece: the
piece an edge's current blocks read at its level is kept (``_pinned``)
and read again when the other face is rebuilt, so neighbours of any
levels share bit-identical points on their common edge (no cracks, no
T-junctions) even if the cache evicted and remade the piece in between.
After each frame the cache is trimmed to its budget (the least recently
used pieces first): pieces not read to build a block for the longest are
freed first. The blocks and pinned edges are the current frame's geometry
(about the size of its compact table) and are not counted in the budget.

Per-face data for the selectors (``centroids``, ``corners``,
``edge_length``, ``geometric_error``, ``contrast``, ``z_range``,
``bounding_radius``) come from an :class:`AdaptiveMesh` at
``data_level = min(max_level, 5)`` made once and dropped (its arrays are
kept, its vertex table freed): for ``max_level <= 5`` they are exactly
``AdaptiveMesh``'s. Above it they are extended without sampling level
``max_level``: ``edge_length[:, L] = edge_length[:, K] / 2**(L - K)``
for ``L > K`` (a level halves every side; exact on planes, the xy part of
it everywhere); ``geometric_error`` of the levels ``< K`` is measured
against the level-K surface (not level M: an underestimate), that of the
levels ``K..M-1`` extrapolated from level K-1's by a quarter per level (a
smooth surface's linear-interpolation error), 0 at M; ``contrast`` is over
the level-K vertices; ``z_range`` and ``bounding_radius`` are widened by
the level-(K-1) error (an estimate, not a bound, for ``max_level > 5``).
Mode ``csf`` reads only ``edge_length`` (through the levels' angular
size) and ``contrast``; ``sse``-like modes read ``geometric_error``.

Scene units are the terrain's (metres for the built-in one): x east, y
north, z up; triangles counter-clockwise seen from +z; float32 output.
"""
from __future__ import annotations

import time
from collections import OrderedDict

import numpy as np

from .shading import AMBIENT, LIGHT_DIR
from .mesh import AdaptiveMesh
from .mesh_base import AdaptiveMeshBase, BaseMesh, _sample
from .mesh_cases import Template

#: Default byte budget of the piece cache (positions and normals of the cached pieces).
DEFAULT_CACHE_BYTES = 256 * 2 ** 20
#: Finest level whose per-face data are measured by sampling (above it they are extrapolated).
DATA_LEVEL = 5


class PieceCache:
    """The byte-bounded LRU cache of pieces, shareable by several meshes over the same base and terrain.

    Parameters
    ----------
    budget_bytes : int
        Bytes (positions + normals, float32) held at most after each trim.
    idle_frames : int or None
        Also evict pieces no frame has used in the last ``idle_frames``
        frames (frames counted over every mesh sharing the cache).

    Attributes
    ----------
    entries : OrderedDict
        key -> (positions (P, 3) float32, normals (P, 3) float32), least recently used first.
    used : dict
        key -> the frame number that last used it.
    nbytes : int
        Bytes held now.
    frame : int
        Frames built (with new cases) by the meshes sharing the cache.
    """

    def __init__(self, budget_bytes: int, idle_frames: int | None = None):
        if not int(budget_bytes) > 0:
            raise ValueError(f"cache_bytes must be > 0, got {budget_bytes!r}")
        if idle_frames is not None and not int(idle_frames) >= 1:
            raise ValueError(f"idle_frames must be >= 1 or None, got {idle_frames!r}")
        self.budget_bytes = int(budget_bytes)
        self.idle_frames = None if idle_frames is None else int(idle_frames)
        self.entries: OrderedDict = OrderedDict()
        self.used: dict = {}
        self.nbytes = 0
        self.frame = 0

    def get(self, key):
        item = self.entries.get(key)
        if item is not None:
            self.entries.move_to_end(key)
            self.used[key] = self.frame
        return item

    def put(self, key, positions, normals) -> None:
        old = self.entries.pop(key, None)
        if old is not None:
            self.nbytes -= old[0].nbytes + old[1].nbytes
        self.entries[key] = (positions, normals)
        self.used[key] = self.frame
        self.nbytes += positions.nbytes + normals.nbytes

    def trim(self) -> int:
        """Evict least recently used pieces until the cache fits its budget, and those idle for more than
        ``idle_frames`` frames; the number evicted."""
        n = 0
        oldest = -1 if self.idle_frames is None else self.frame - self.idle_frames
        while self.entries and (self.nbytes > self.budget_bytes
                                or self.used[next(iter(self.entries))] < oldest):
            key, (p, q) = self.entries.popitem(last=False)
            del self.used[key]
            self.nbytes -= p.nbytes + q.nbytes
            n += 1
        return n


class LazyAdaptiveMesh(AdaptiveMeshBase):
    """:class:`AdaptiveMesh`'s triangles for per-face levels, with geometry made only when asked for.

    Parameters
    ----------
    base : BaseMesh
        Its vertices should lie on the terrain (``BaseMesh.grid`` does that).
    terrain : object
        ``sample(x, y[, smooth_m]) -> (z (n,), normals (n, 3))`` or
        ``heights``/``normals``, vectorized, scene units.
    max_level : int
        Finest level M, 0..8 (4**M triangles per base face at full detail).
    cache_bytes : int
        Budget of the piece cache, bytes (positions + normals, float32);
        after every ``update`` the cache holds at most this much.
    idle_frames : int, optional
        Also free, after every frame, the pieces no frame has used in the
        last ``idle_frames`` frames (frames whose cases changed), within
        budget or not: memory then follows what is in view. ``None``: only
        the budget evicts.
    light_dir, ambient, normal_filter
        As :class:`AdaptiveMesh`'s.
    data_level : int
        Finest level sampled for the per-face data (module notes), default
        ``min(max_level, 5)``.

    Attributes
    ----------
    centroids : (F, 3) float64, corners : (F, 3, 3) float64, edge_length : (F, M+1) float64,
    geometric_error : (F, M+1) float64, contrast : (F,) float64, z_range : (F, 2) float64,
    bounding_radius : (F,) float64
        Per-face data as :class:`AdaptiveMesh`'s (module notes for M > data_level).
    vertex_positions : (V, 3) float32
        The last frame's compact vertex table, scene units (``update_indices`` indexes it;
        empty before the first update and after ``clear``).
    vertex_normals : (V, 3) float32
        Unit normals of its rows (prefiltered for the row's level).
    cache_bytes : int
        Bytes held by the cache now.
    stats : dict
        After each update: ``triangles``, ``vertices``, ``rebuilt_faces``,
        ``build_ms`` (pieces made and the frame assembled), ``assemble_ms``
        (for ``update``, the soup gather), ``generated_pieces``,
        ``reused_pieces``, ``evicted_pieces``, ``cache_bytes``,
        ``cache_pieces``.
    last_rebuilt_faces : (k,) int64
        Base faces whose block the last update made anew.

    Capabilities (:class:`headplod.plod.mesh_base.AdaptiveMeshBase`):
    ``kind == "lazy"``, ``has_full_table`` False (a frame's table holds
    only what it draws), ``full_fits`` up to
    :data:`headplod.plod.mesh_base.FULL_MAX_LEVEL`.
    """

    kind = "lazy"
    has_full_table = False

    def __init__(self, base: BaseMesh, terrain, max_level: int = 5, *, cache_bytes: int = DEFAULT_CACHE_BYTES,
                 idle_frames: int | None = None,
                 light_dir=LIGHT_DIR, ambient: float = AMBIENT, normal_filter: float = 0.25,
                 data_level: int | None = None):
        super().__init__(base, terrain, max_level, normal_filter)
        self._pieces_cache = PieceCache(cache_bytes, idle_frames)
        M = self.max_level
        K = min(M, DATA_LEVEL) if data_level is None else int(data_level)
        if not 0 <= K <= M:
            raise ValueError(f"data_level must be in 0..max_level={M}, got {data_level!r}")
        # The per-face data, from a mesh at the data level (its tables are dropped with it).
        data = AdaptiveMesh(base, terrain, max_level=K, light_dir=light_dir, ambient=ambient,
                            normal_filter=normal_filter)
        self._per_face_data(data, K)
        self.contrast = data.contrast
        self._shading_normals = data._shading_normals          # (F, P_K, 3) float32: shading_contrast
        del data
        _, vnrm = _sample(terrain, base.vertices[:, 0], base.vertices[:, 1])
        self._base_pos = base.vertices.astype(np.float32)
        self._base_nrm = vnrm.astype(np.float32)
        self.clear()

    # ------------------------------------------------------------------ per-face data
    def _per_face_data(self, data: AdaptiveMesh, K: int) -> None:
        M = self.max_level
        self.corners, self.centroids = data.corners, data.centroids
        self.edge_length = np.zeros((self.n_faces, M + 1))
        self.geometric_error = np.zeros((self.n_faces, M + 1))
        self.edge_length[:, :K + 1] = data.edge_length
        self.geometric_error[:, :K + 1] = data.geometric_error
        for L in range(K + 1, M + 1):                            # loop over the extrapolated levels
            self.edge_length[:, L] = data.edge_length[:, K] / 2 ** (L - K)
        slack = np.zeros(self.n_faces)
        if M > K and K > 0:
            tail = data.geometric_error[:, K - 1]
            for L in range(K, M):                                # loop over the extrapolated levels
                self.geometric_error[:, L] = tail / 4 ** (L - K + 1)
            slack = tail
        self.z_range = data.z_range + np.stack([-slack, slack], axis=1)
        self.bounding_radius = data.bounding_radius + slack
        # What a level removes from the shading: measured up to the data level; beyond it a normal's error,
        # hence the shading's, halves per level (first order in the spacing).
        self.change_contrast = np.zeros((self.n_faces, M + 1))
        self.change_contrast[:, :K + 1] = data.change_contrast
        if M > K and K > 0:
            for L in range(K, M):                                # loop over the extrapolated levels
                self.change_contrast[:, L] = data.change_contrast[:, K - 1] / 2 ** (L - K + 1)
        self.normal_axis, self.normal_cone_deg = data.normal_axis, data.normal_cone_deg

    # ------------------------------------------------------------------ cache
    @property
    def _cache(self) -> OrderedDict:
        """The cached pieces, key -> (positions, normals), least recently used first (shared by ``share()``s)."""
        return self._pieces_cache.entries

    @property
    def cache_bytes(self) -> int:
        """Bytes the (shared) piece cache holds now."""
        return self._pieces_cache.nbytes

    @property
    def budget_bytes(self) -> int:
        """The (shared) piece cache's budget, bytes."""
        return self._pieces_cache.budget_bytes

    @property
    def idle_frames(self) -> int | None:
        return self._pieces_cache.idle_frames

    def _get(self, key):
        return self._pieces_cache.get(key)

    def _put(self, key, positions, normals) -> None:
        self._pieces_cache.put(key, positions, normals)

    def _trim(self) -> int:
        return self._pieces_cache.trim()

    def clear(self) -> None:
        """Forget the last frame (output, table, face blocks; the cache stays): the next update builds every face.

        A :meth:`share` starts from here too: several selections (the
        demo's scenario loops) build side by side, each its own compact
        frame table, while the pieces any of them made are reused by all
        and the cache's byte budget bounds them together.
        """
        self._last_case = None
        self._output = self._soup = self._face_per_tri = None
        self._faces_of_groups = []
        self._face_case = np.full(self.n_faces, -1, dtype=np.int64)     # case of each face's block
        self._block_pos = [None] * self.n_faces                         # (P_f, 3) float32 per face
        self._block_nrm = [None] * self.n_faces
        self._block_len = np.zeros(self.n_faces, dtype=np.int64)
        self._pinned: dict = {}                                          # edge -> (level, pos, nrm)
        self.vertex_positions = np.zeros((0, 3), np.float32)
        self.vertex_normals = np.zeros((0, 3), np.float32)
        self.last_rebuilt_faces = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ pieces
    def _edge_block(self, level: int, edges: np.ndarray):
        """Points of ``edges`` (n,) at edge ``level``: positions, normals (n, 2**level + 1, 3) float32.

        An edge the current face blocks already read at this level (``_pinned``) gives the very points they
        read, so both faces of an edge share its points bit for bit even when one of them is rebuilt after
        the cache evicted and remade the piece.
        """
        M, N = self.max_level, 2 ** self.max_level
        base = self.base
        n_pts = 2 ** level + 1
        pos = np.empty((len(edges), n_pts, 3), np.float32)
        nrm = np.empty_like(pos)
        lo, hi = base.edges[edges, 0], base.edges[edges, 1]
        pos[:, 0], pos[:, -1] = self._base_pos[lo], self._base_pos[hi]
        nrm[:, 0], nrm[:, -1] = self._base_nrm[lo], self._base_nrm[hi]
        if level == 0 or not len(edges):
            return pos, nrm
        pinned = self._pinned
        held = [pinned.get(e) for e in edges.tolist()]                 # loop over edges: dict look-ups
        fresh = np.array([i for i, h in enumerate(held) if h is None or h[0] != level], dtype=np.int64)
        for i, h in enumerate(held):                                   # loop over edges: the pinned ones' rows
            if h is not None and h[0] == level:
                pos[i, 1:-1], nrm[i, 1:-1] = h[1], h[2]
        if not len(fresh):
            return pos, nrm
        sub = edges[fresh]
        t = np.arange(1, n_pts - 1) * 2 ** (M - level) / N             # canonical positions along the edge

        def make(miss):
            pa = base.vertices[base.edges[sub[miss], 0]][:, None, :2]
            pb = base.vertices[base.edges[sub[miss], 1]][:, None, :2]
            xy = pa + t[None, :, None] * (pb - pa)
            z, n = _sample(self.terrain, xy[..., 0].ravel(), xy[..., 1].ravel(),
                           self.normal_filter_m[level] if level < M else None)
            return (np.concatenate([xy, z.reshape(len(miss), -1, 1)], axis=2).astype(np.float32),
                    n.reshape(len(miss), -1, 3).astype(np.float32))

        p, q = self._pieces([("e", e, level) for e in sub.tolist()], make)
        pos[fresh, 1:-1], nrm[fresh, 1:-1] = p, q
        for j, e in enumerate(sub.tolist()):                           # loop over new edges: pin them
            pinned[e] = (level, p[j], q[j])
        return pos, nrm

    def _face_block(self, cid: int, level: int, tpl: Template, fids: np.ndarray):
        """Interior points of faces ``fids`` (m,) in case ``cid``: positions, normals (m, K, 3) float32."""
        Kp = len(tpl.interior_bary)
        if not Kp:
            z = np.zeros((len(fids), 0, 3), np.float32)
            return z, z

        def make(miss):
            corners = self.base.vertices[self.base.faces[fids[miss]]][..., :2]     # (m', 3, 2)
            xy = np.einsum("pk,mkd->mpd", tpl.interior_bary, corners)
            z, n = _sample(self.terrain, xy[..., 0].ravel(), xy[..., 1].ravel(),
                           self.normal_filter_m[level] if level < self.max_level else None)
            return (np.concatenate([xy, z.reshape(len(miss), Kp, 1)], axis=2).astype(np.float32),
                    n.reshape(len(miss), Kp, 3).astype(np.float32))

        return self._pieces([("f", f, cid) for f in fids.tolist()], make)

    def _pieces(self, keys, make):
        """The cached pieces under ``keys``: (positions, normals), each (len(keys), P, 3) float32.

        ``make(missing)`` gives the pieces not in the cache, for the indices
        ``missing`` (m,) into ``keys``, as two (m, P, 3) arrays; they are
        stored (as copies) before they are returned.
        """
        items = [self._get(key) for key in keys]                     # loop over pieces: cache look-ups only
        missing = [i for i, item in enumerate(items) if item is None]
        self._n_reused += len(keys) - len(missing)
        if missing:
            made_pos, made_nrm = make(np.array(missing))
            for j, i in enumerate(missing):                          # loop over new pieces: store copies
                items[i] = (made_pos[j].copy(), made_nrm[j].copy())
                self._put(keys[i], *items[i])
            self._n_generated += len(missing)
        return np.stack([item[0] for item in items]), np.stack([item[1] for item in items])

    # ------------------------------------------------------------------ frames
    def update_indices(self, levels):
        """Triangles for per-face levels as indices into this frame's ``vertex_positions``.

        As :meth:`AdaptiveMeshBase.update_indices`; the indices address the
        compact table of this frame, which every update with new cases
        replaces. Triangles are grouped by case (ascending), then by face
        (ascending): ``AdaptiveMesh``'s order for a build from scratch.
        """
        t0 = time.perf_counter()
        case = self.cases(levels)
        if self._last_case is not None and np.array_equal(case, self._last_case):
            self.last_rebuilt_faces = np.zeros(0, dtype=np.int64)
            self.stats.update(build_ms=1e3 * (time.perf_counter() - t0), assemble_ms=0.0, generated_pieces=0,
                              rebuilt_faces=0, evicted_pieces=0)
            return self._output
        self._n_generated = self._n_reused = 0
        self._pieces_cache.frame += 1
        # 1. Only the faces whose case changed get a new block (their boundary and interior points).
        rebuilt = np.flatnonzero(case != self._face_case)
        if len(rebuilt):
            self._rebuild_blocks(case, self.edge_levels(levels), rebuilt)
        # 2. The frame: the blocks grouped by case (ascending), then face; triangles = templates + offsets.
        total = self._assemble_frame(case)
        self._last_case = case
        self.last_rebuilt_faces = rebuilt
        evicted = self._trim()
        self.stats = {"triangles": int(len(self._output[1])), "vertices": total, "rebuilt_faces": int(len(rebuilt)),
                      "build_ms": 1e3 * (time.perf_counter() - t0), "assemble_ms": 0.0,
                      "generated_pieces": int(self._n_generated), "reused_pieces": int(self._n_reused),
                      "evicted_pieces": int(evicted), "cache_bytes": int(self.cache_bytes),
                      "cache_pieces": len(self._cache)}
        return self._output

    def _rebuild_blocks(self, case, el, rebuilt) -> None:
        """New blocks for the faces ``rebuilt`` (k,) entering ``case[rebuilt]``; edge levels ``el`` (E,).

        A block is the face's boundary points (read from its edges' pieces
        at their levels) then its face piece. Afterwards, edges no face
        reads at their pinned level any more are unpinned (their pieces
        stay cached).
        """
        edge_rows, edge_nrms, edge_off = self._edge_rows(np.unique(self.base.face_edges[rebuilt]), el)
        new_case = case[rebuilt]
        order = np.argsort(new_case, kind="stable")
        ids, starts = np.unique(new_case[order], return_index=True)
        for cid, fids in zip(ids.tolist(), np.split(rebuilt[order], starts[1:])):   # loop over cases
            self._case_blocks(cid, fids, el, edge_rows, edge_nrms, edge_off)
        self._face_case[rebuilt] = new_case
        stale = [e for e, (level, _, _) in self._pinned.items() if level != el[e]]
        for e in stale:                                                      # loop over stale pins
            del self._pinned[e]

    def _edge_rows(self, edges, el):
        """The points of ``edges`` (n,) at their levels ``el[edges]``, stacked edge after edge.

        Returns
        -------
        positions, normals : (R, 3) float32
            Each edge's ``2**level + 1`` points in its canonical direction.
        first_row : (E,) int64
            Row of each asked edge's first point (0 for the others).
        """
        rows, nrms = [], []
        first_row = np.zeros(len(self.base.edges), np.int64)
        row = 0
        for level in np.unique(el[edges]).tolist():                      # loop over edge levels
            sub = edges[el[edges] == level]
            p, n = self._edge_block(level, sub)
            first_row[sub] = row + np.arange(len(sub)) * p.shape[1]
            rows.append(p.reshape(-1, 3))
            nrms.append(n.reshape(-1, 3))
            row += p.shape[0] * p.shape[1]
        return np.concatenate(rows), np.concatenate(nrms), first_row

    def _case_blocks(self, cid, fids, el, edge_rows, edge_nrms, edge_first_row) -> None:
        """Make and keep the blocks of faces ``fids`` (m,) in case ``cid`` (rows from :meth:`_edge_rows`)."""
        M, N = self.max_level, 2 ** self.max_level
        base = self.base
        tpl = self.template(cid)
        eids = base.face_edges[fids][:, tpl.boundary_edge]                # (m, Pb)
        fwd = base.face_edge_forward[fids][:, tpl.boundary_edge]
        kk = np.where(fwd, tpl.boundary_k, N - tpl.boundary_k)           # canonical, 1/N of the edge
        rows = edge_first_row[eids] + (kk >> (M - el[eids]))
        p, n = self._face_block(cid, cid // (M + 1) ** 3, tpl, fids)
        block_pos = np.concatenate([edge_rows[rows], p], axis=1)         # (m, Pb + Kp, 3)
        block_nrm = np.concatenate([edge_nrms[rows], n], axis=1)
        for i, f in enumerate(fids.tolist()):                            # loop over rebuilt faces
            self._block_pos[f], self._block_nrm[f] = block_pos[i], block_nrm[i]
        self._block_len[fids] = block_pos.shape[1]

    def _assemble_frame(self, case) -> int:
        """This frame's table (the blocks by case, then face), its indices and triangle levels; the table's rows.

        Sets ``vertex_positions``, ``vertex_normals``, the output and what
        ``face_per_triangle`` reads.
        """
        M1 = self.max_level + 1
        order = np.argsort(case, kind="stable")
        ids, starts = np.unique(case[order], return_index=True)
        sizes = self._block_len[order]
        total = int(sizes.sum())
        if total >= 2 ** 32:
            raise ValueError(f"LazyAdaptiveMesh: {total} frame vertices do not fit 32-bit indices")
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.uint32)       # fits: checked above
        order_list = order.tolist()
        self.vertex_positions = np.concatenate([self._block_pos[f] for f in order_list])
        self.vertex_normals = np.concatenate([self._block_nrm[f] for f in order_list])
        idx_parts, lv_parts, face_parts = [], [], []
        bounds = np.append(starts, len(order))
        for j, cid in enumerate(ids.tolist()):                               # loop over cases
            a, b = int(bounds[j]), int(bounds[j + 1])
            tri = self.template(cid).triangles.reshape(-1)
            idx_parts.append((offsets[a:b, None] + tri.astype(np.uint32)[None, :]).reshape(-1))
            n_tri = len(tri) // 3
            lv_parts.append(np.full((b - a) * n_tri, cid // M1 ** 3, np.uint8))
            face_parts.append((order[a:b], n_tri))
        indices = np.concatenate(idx_parts) if idx_parts else np.zeros(0, np.uint32)
        tri_levels = np.concatenate(lv_parts) if lv_parts else np.zeros(0, np.uint8)
        self._output = (indices, tri_levels)
        self._faces_of_groups = face_parts
        self._soup = self._face_per_tri = None
        return total

    def face_per_triangle(self) -> np.ndarray:
        """Base face of each triangle of the last output, (T,) int64."""
        if self._output is None:
            return np.zeros(0, dtype=np.int64)
        if self._face_per_tri is None:
            parts = [np.repeat(f, n) for f, n in self._faces_of_groups]
            self._face_per_tri = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        return self._face_per_tri
