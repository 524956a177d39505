"""The base mesh, and the one interface of an adaptive mesh over it (:class:`AdaptiveMeshBase`).

Frame and units
---------------
Scene units are those of the terrain (metres for
:class:`headplod.plod.terrain.Terrain`): x east, y north, z up. A base
mesh's triangles, and every triangle an adaptive mesh draws, are
counter-clockwise seen from +z.

Two kinds of adaptive mesh draw the same triangles for the same per-face
levels (the crack-free cases of :mod:`headplod.plod.mesh_cases`):

- ``kind == "table"``: :class:`headplod.plod.mesh.AdaptiveMesh` samples,
  when it is made, every vertex any level of any face can use into one
  static vertex table (``has_full_table``); a build is indices into it.
- ``kind == "lazy"``: :class:`headplod.plod.lazy_mesh.LazyAdaptiveMesh`
  samples only what a frame draws, keeps it in a byte-bounded cache, and
  gives each frame its own compact vertex table.

Callers ask the mesh what it can do (``kind``, ``has_full_table``,
``full_fits``) instead of testing its class.
"""
from __future__ import annotations

import abc
import copy
import time

import numpy as np

from .shading import AMBIENT, LIGHT_DIR, michelson, shade
from .mesh_cases import Template, build_template, triangle_count_table

#: Colours of the levels, RGB uint8, (8, 3); level k uses ``LEVEL_PALETTE[k % 8]``
#: (the renderer's "levels" view and the exported meshes).
LEVEL_PALETTE = np.array([
    [230, 25, 75],    # red
    [60, 180, 75],    # green
    [0, 130, 200],    # blue
    [255, 225, 25],   # yellow
    [145, 30, 180],   # purple
    [70, 240, 240],   # cyan
    [245, 130, 48],   # orange
    [240, 50, 230],   # magenta
], dtype=np.uint8)

#: Finest level an adaptive mesh is made for (4**8 triangles per base face at full detail).
MAX_LEVEL = 8
#: Finest level at which every face drawn at the finest level (mode ``full``) is taken to fit in memory:
#: ``full_fits``. Level 8 on the default 32 x 32 base is 134 M triangles a frame.
FULL_MAX_LEVEL = 7


def _sample(terrain, x, y, smooth_m=None):
    """Heights (n,) and unit normals (n, 3) from any terrain-like object.

    ``smooth_m`` (metres, scalar or (n,)): normals of the terrain prefiltered
    at that scale, when the terrain offers it (``sample(x, y, smooth_m=...)``).
    """
    if smooth_m is not None and hasattr(terrain, "sample"):
        try:
            z, n = terrain.sample(x, y, smooth_m=smooth_m)
        except TypeError:                       # a terrain without prefiltering
            z, n = terrain.sample(x, y)
    elif hasattr(terrain, "sample"):
        z, n = terrain.sample(x, y)
    else:
        z, n = terrain.heights(x, y), terrain.normals(x, y)
    return np.asarray(z, dtype=np.float64).reshape(-1), np.asarray(n, dtype=np.float64).reshape(-1, 3)


def _face_areas_xy(base) -> np.ndarray:
    """Areas of the base faces projected on the xy plane, (F,), scene units²."""
    a, b, c = (base.vertices[base.faces[:, k], :2] for k in range(3))
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


class BaseMesh:
    """A triangle mesh with its edge topology.

    Parameters
    ----------
    vertices : (V, 3) float
        Vertex positions, scene units.
    faces : (F, 3) int
        Vertex indices, counter-clockwise seen from +z.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    edges : (E, 2) int64
        Unique edges as (lower, higher) vertex index: their canonical direction.
    face_edges : (F, 3) int64
        Edge of each face's local edge i (from corner i to corner (i + 1) % 3).
    face_edge_forward : (F, 3) bool
        True where local edge i runs in the edge's canonical direction.
    edge_faces : (E, 2) int64
        The faces of each edge, -1 for the missing one of a boundary edge.
    face_neighbors : (F, 3) int64
        Face across local edge i, -1 on the boundary.
    boundary_edges : (B,) int64
        Indices of the edges with one face.
    """

    def __init__(self, vertices, faces):
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ValueError(f"vertices must be (V, 3), got {vertices.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must be (F, 3), got {faces.shape}")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ValueError(f"faces index vertices 0..{len(vertices) - 1}, got {faces.min()}..{faces.max()}")
        self.vertices, self.faces = vertices, faces
        half = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)   # (3F, 2) i -> i+1
        canonical = np.sort(half, axis=1)
        self.edges, inverse = np.unique(canonical, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        self.face_edges = inverse.reshape(-1, 3)
        self.face_edge_forward = (half[:, 0] < half[:, 1]).reshape(-1, 3)
        order = np.argsort(inverse, kind="stable")
        counts = np.bincount(inverse, minlength=len(self.edges))
        if counts.max(initial=0) > 2:
            raise ValueError(f"non-manifold base mesh: an edge has {counts.max()} faces")
        if np.any(np.bincount(inverse[self.face_edge_forward.reshape(-1)], minlength=len(self.edges)) > 1):
            raise ValueError("inconsistently oriented base mesh: two faces traverse an edge the same way")
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        face_of_half = order // 3
        self.edge_faces = np.full((len(self.edges), 2), -1, dtype=np.int64)
        self.edge_faces[:, 0] = face_of_half[first]
        two = counts == 2
        self.edge_faces[two, 1] = face_of_half[first[two] + 1]
        self.boundary_edges = np.flatnonzero(counts == 1)
        ef = self.edge_faces[self.face_edges]                                 # (F, 3, 2)
        own = np.arange(len(faces))[:, None]
        self.face_neighbors = np.where(ef[..., 0] == own, ef[..., 1], ef[..., 0])

    @classmethod
    def grid(cls, terrain, nx: int = 32, ny: int = 32) -> "BaseMesh":
        """Regular grid over the terrain's extent, two triangles per quad, vertices on the terrain.

        Parameters
        ----------
        terrain : object with ``extent`` (xmin, xmax, ymin, ymax) and ``heights(x, y)``
        nx, ny : int
            Quads along x and y (F = 2 nx ny faces, (nx+1)(ny+1) vertices).

        Returns
        -------
        BaseMesh
            Vertex ``j * (nx + 1) + i`` at column i, row j; quad (i, j) is split
            along its diagonal from (i, j) to (i+1, j+1).
        """
        if nx < 1 or ny < 1:
            raise ValueError(f"nx and ny must be >= 1, got {nx}, {ny}")
        xmin, xmax, ymin, ymax = map(float, terrain.extent)
        xs, ys = np.linspace(xmin, xmax, nx + 1), np.linspace(ymin, ymax, ny + 1)
        gx, gy = np.meshgrid(xs, ys)
        z = np.asarray(terrain.heights(gx.ravel(), gy.ravel()), dtype=np.float64).reshape(-1)
        vertices = np.column_stack([gx.ravel(), gy.ravel(), z])
        j, i = np.mgrid[0:ny, 0:nx]
        v00 = (j * (nx + 1) + i).ravel()
        v10, v01 = v00 + 1, v00 + nx + 1
        v11 = v01 + 1
        faces = np.stack([np.column_stack([v00, v10, v11]), np.column_stack([v00, v11, v01])], axis=1)
        return cls(vertices, faces.reshape(-1, 3))


class AdaptiveMeshBase(abc.ABC):
    """Per-face-level crack-free subdivision of a :class:`BaseMesh` over a terrain: the common interface.

    A subclass makes the per-face data and the vertices (all at once, or
    per frame) and implements :meth:`update_indices`, :meth:`face_per_triangle`
    and :meth:`clear`; the level checks, edge levels, cases, triangle counts,
    soup, sharing and shading contrast live here once.

    Parameters (of every subclass)
    ------------------------------
    base : BaseMesh
        Its vertices should lie on the terrain (``BaseMesh.grid`` does that).
    terrain : object
        ``sample(x, y[, smooth_m]) -> (z (n,), normals (n, 3))`` or
        ``heights(x, y)`` / ``normals(x, y)``, vectorized, scene units.
    max_level : int
        Finest level M, 0..:data:`MAX_LEVEL` (up to ``4**M`` triangles per base face).
    normal_filter : float
        Normals of a level-L vertex are those of the terrain prefiltered by
        a Gaussian of σ = ``normal_filter`` x the level's grid spacing
        (``normal_filter_m``; 0 at the finest level, which stays exact).

    Capabilities (what callers test instead of the class)
    -----------------------------------------------------
    kind : str
        ``"table"`` (one static vertex table of every vertex any build can
        use) or ``"lazy"`` (vertices made per frame, from a piece cache).
    has_full_table : bool
        True when ``vertex_positions`` holds the whole finest-level mesh at
        all times, so the ``full`` mesh's vertices are readable on a
        :meth:`share` (``headplod.plod.raymask.height_grid`` needs this).
    full_fits : bool
        Whether drawing every face at the finest level (mode ``full``) fits
        in memory: ``max_level <= FULL_MAX_LEVEL``.

    Attributes
    ----------
    base : BaseMesh
    terrain : object
    max_level : int
        M.
    n_faces : int
        F, the base faces.
    centroids : (F, 3) float64
        Mean of each base face's corners, scene units.
    corners : (F, 3, 3) float64
        The base faces' corners, scene units.
    edge_length : (F, M+1) float64
        Longest 3-D edge of the face's pieces at each uniform level, scene units.
    geometric_error : (F, M+1) float64
        Largest vertical distance between the uniform level-L surface and the
        finest surface over the face, scene units (0 at level M).
    z_range : (F, 2) float64
        Lowest and highest z of any vertex any case of the face can produce,
        scene units (above the base triangle's (x, y): a bounding prism).
    bounding_radius : (F,) float64
        Radius about ``centroids`` of a sphere holding every vertex any case
        of the face can produce, scene units.
    contrast : (F,) float64
        Michelson contrast of the face's Lambertian shading
        (:meth:`shading_contrast` with the mesh's light).
    normal_filter_m : (M+1,) float64
        σ of each level's normal prefilter, scene units (0 at level M).
    vertex_positions : (V, 3) float32
        The vertex table the last :meth:`update_indices`' indices address,
        scene units (static for ``kind == "table"``; replaced by every frame
        with new cases for ``"lazy"``).
    vertex_normals : (V, 3) float32
        Unit normal of each row, scene frame (prefiltered for the row's level).
    stats : dict
        After each update: at least ``triangles``, ``rebuilt_faces``,
        ``build_ms`` and ``assemble_ms``; the subclasses add their own.
    last_rebuilt_faces : (k,) int64
        Base faces built anew by the last update with new cases.
    """

    #: ``"table"`` or ``"lazy"`` (class docstring: Capabilities).
    kind: str = ""
    #: Whether a whole finest-level vertex table exists at all times (class docstring: Capabilities).
    has_full_table: bool = False

    def __init__(self, base: BaseMesh, terrain, max_level: int, normal_filter: float):
        if not isinstance(max_level, (int, np.integer)) or not 0 <= max_level <= MAX_LEVEL:
            raise ValueError(f"max_level must be an integer in 0..{MAX_LEVEL}, got {max_level!r}")
        self.base, self.terrain, self.max_level = base, terrain, int(max_level)
        self.n_faces = len(base.faces)
        M = self.max_level
        self._count_table = triangle_count_table(M)
        self._templates: dict[int, Template] = {}
        # Grid spacing of each level (the base faces' legs halved per level), and the normals' filter.
        leg = float(np.sqrt(2 * np.median(_face_areas_xy(base))))
        self.normal_filter_m = np.array([normal_filter * leg / 2 ** L if L < M else 0.0 for L in range(M + 1)])
        self.stats: dict = {}
        self.last_rebuilt_faces = np.zeros(0, dtype=np.int64)

    @property
    def full_fits(self) -> bool:
        """Whether every face at the finest level (mode ``full``) fits: ``max_level <= FULL_MAX_LEVEL``."""
        return self.max_level <= FULL_MAX_LEVEL

    # ------------------------------------------------------------------ cases
    def template(self, case_id: int) -> Template:
        """The cached template of an encoded case (see ``cases``)."""
        tpl = self._templates.get(case_id)
        if tpl is None:
            M1 = self.max_level + 1
            L, e0, e1, e2 = np.unravel_index(case_id, (M1,) * 4)
            tpl = build_template(self.max_level, L, (e0, e1, e2))
            self._templates[case_id] = tpl
        return tpl

    def _check_levels(self, levels) -> np.ndarray:
        """``levels`` as (F,) int64 in 0..max_level, or ValueError."""
        lv = np.asarray(levels)
        if lv.shape != (self.n_faces,):
            raise ValueError(f"levels must have shape ({self.n_faces},), got {lv.shape}")
        if lv.dtype.kind not in "iu":
            if lv.dtype.kind == "f" and np.all(lv == np.round(lv)):
                lv = lv.astype(np.int64)
            else:
                raise ValueError(f"levels must be integers, got dtype {lv.dtype}")
        lv = lv.astype(np.int64)
        if lv.size and (lv.min() < 0 or lv.max() > self.max_level):
            raise ValueError(f"levels must be in 0..{self.max_level}, got {lv.min()}..{lv.max()}")
        return lv

    def edge_levels(self, levels) -> np.ndarray:
        """Level of each base edge, the max of its faces' levels, (E,) int64."""
        lv = self._check_levels(levels)
        ef = self.base.edge_faces
        return np.maximum(lv[ef[:, 0]], np.where(ef[:, 1] >= 0, lv[np.maximum(ef[:, 1], 0)], 0))

    def cases(self, levels) -> np.ndarray:
        """Case of each face, encoded ``((L*(M+1) + e0)*(M+1) + e1)*(M+1) + e2``, (F,) int64."""
        lv = self._check_levels(levels)
        el = self.edge_levels(lv)[self.base.face_edges]            # (F, 3)
        return np.ravel_multi_index((lv, el[:, 0], el[:, 1], el[:, 2]), (self.max_level + 1,) * 4)

    def triangle_count(self, levels) -> int:
        """Number of triangles ``update(levels)`` would produce, without building anything."""
        return int(self._count_table.reshape(-1)[self.cases(levels)].sum())

    # ------------------------------------------------------------------ building
    @abc.abstractmethod
    def update_indices(self, levels):
        """Triangles for per-face levels as indices into ``vertex_positions``.

        Parameters
        ----------
        levels : (F,) int
            Level of each base face, 0..max_level.

        Returns
        -------
        indices : (3T,) uint32
            Rows of ``vertex_positions`` / ``vertex_normals``; entries 3t,
            3t+1, 3t+2 are triangle t, counter-clockwise seen from +z.
        level_per_triangle : (T,) uint8
            Level of the base face each triangle belongs to (transition fans
            carry their face's level).

        Triangles are grouped by case (ascending); ``face_per_triangle()``
        gives each one's base face. The same arrays are returned again while
        no case changes; do not modify them.
        """

    @abc.abstractmethod
    def face_per_triangle(self) -> np.ndarray:
        """Base face of each triangle of the last update's output, (T,) int64."""

    @abc.abstractmethod
    def clear(self) -> None:
        """Forget the current frame (output and per-face build state): the next update builds every face."""

    def update(self, levels):
        """Mesh for per-face levels as a triangle soup (``update_indices``' triangles gathered from the table).

        ``levels``: (F,) int, as for :meth:`update_indices`.

        Returns
        -------
        positions : (3T, 3) float32
            Triangle soup, scene units: rows 3t, 3t+1, 3t+2 are triangle t,
            counter-clockwise seen from +z (``vertex_positions[indices]``,
            in ``update_indices``' triangle order).
        normals : (3T, 3) float32
            Terrain unit normal at each row's vertex, scene frame.
        level_per_triangle : (T,) uint8
            Level of the base face each triangle belongs to.

        The returned arrays are reused (returned again) when no case
        changes; do not modify them.
        """
        indices, lv = self.update_indices(levels)
        t0 = time.perf_counter()
        if self._soup is None:
            self._soup = (self.vertex_positions[indices], self.vertex_normals[indices], lv)
        self.stats["assemble_ms"] += 1e3 * (time.perf_counter() - t0)
        return self._soup

    def share(self) -> "AdaptiveMeshBase":
        """A mesh over the same read-only data (per-face data, templates, vertex table or piece cache) with
        its own build state.

        Several selections can then be built side by side, each rebuilding
        only what its own levels change, without a second copy of what the
        mesh made when it was built.
        """
        other = copy.copy(self)
        other.clear()
        other.stats = {}
        return other

    # ------------------------------------------------------------------ per-face data
    def shading_contrast(self, light_dir=LIGHT_DIR, ambient: float = AMBIENT) -> np.ndarray:
        """Michelson contrast of Lambertian shading over each face's sampled vertices.

        The vertices are the finest level's for ``kind == "table"``, the
        data level's for ``"lazy"`` (see :mod:`headplod.plod.lazy_mesh`).

        Parameters
        ----------
        light_dir : (3,) float
            Direction towards the light, scene frame (normalised here).
        ambient : float
            Ambient fraction in [0, 1).

        Returns
        -------
        contrast : (F,) float64
            ``(max - min) / (max + min)`` of the luminance the display shows for the shade
            ``ambient + (1 - ambient) max(n·l, 0)`` (:func:`headplod.plod.shading.michelson`).
        """
        return michelson(shade(self._shading_normals, light_dir, ambient), axis=1)
