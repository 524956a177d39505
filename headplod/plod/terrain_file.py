"""A person's own terrain from a file: a GeoTIFF DEM, a 16-bit PNG height map or a ``.npy`` grid.

``headplod render --terrain FILE`` and ``headplod demo --terrain FILE`` read
the file here into a :class:`TerrainGrid` (elevation in metres, row 0 south,
column 0 west, as :class:`headplod.plod.terrain.Terrain` wants it) and make
the :class:`Terrain` with :func:`terrain_from_file`. This module takes typed
values and raises typed errors; the options and their messages are the
commands' (:mod:`headplod.render.terrain_command`).

Formats, by the file's ending
-----------------------------
``.tif``, ``.tiff``: a GeoTIFF DEM, read with rasterio (GDAL), band 1. The
spacing comes from the georeferencing: a geographic CRS (degrees) becomes
metres at the grid's centre latitude (WGS84 lengths of a degree, as the
built-in DEM, :func:`headplod.plod.terrain.metres_per_degree`); a projected
CRS gives its linear unit (metres, feet, ...) converted to metres. A
north-up grid (negative y pixel size, the usual) has its rows flipped; a
rotated or sheared one is refused. Elevations are taken as metres (times
``height_scale``). A GeoTIFF without a CRS needs ``spacing_m``.

``.png``: a height map, read with OpenCV (``cv2.IMREAD_UNCHANGED``), row 0
north; 16-bit greyscale is the expected kind. 8-bit is read with a note
(256 levels: terraces), RGB whose three channels are equal is read as grey
with a note, true colour is refused; an alpha channel marks alpha = 0 as no
data. ``spacing_m`` is required and ``height_scale`` (metres per unit)
gives the heights.

``.npy``: a 2-D numeric array (no pickles), row 0 north as an image (as
``matplotlib``'s ``imshow`` shows it), with ``spacing_m`` and
``height_scale`` as for a PNG.

Bad files
---------
Every problem raises :class:`TerrainFileError` (a ``ValueError``) with one
line that starts with the file's name and says what to do. Repairs are
made and reported in :attr:`TerrainGrid.notes`: no-data samples (the
GeoTIFF's nodata value, NaN or infinite, -32768, any value beyond ±1e30, alpha
= 0) are filled from the nearest valid sample (``scipy.ndimage
.distance_transform_edt``'s indices), with the count; a grid with no valid
sample is refused. Limits: at least 4 x 4 samples, at most
:data:`MAX_SAMPLES` (8192 x 8192), spacing between 1 mm and 10 km, heights
within ±1000 km after scaling.

Memory
------
The heights are float32 where that is exact (float32 files, integers of
up to 16 bits, no ``height_scale``), float64 otherwise: the file's own
array lives only until the heights are made, the checks run without a
float temporary of the grid's size, and :func:`terrain_from_file` hands
the heights to the :class:`Terrain` as its ``dem_z_m`` (``copy=False``)
rather than widening or copying them. The built terrain then holds the
heights (4 or 8 bytes a sample) and the padded float64 spline
coefficients (8 bytes a sample), and its building adds no other grid.
Filling no-data samples takes the nearest-sample indices, two int32
grids, while it runs.
"""
from __future__ import annotations

import math
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .terrain import Terrain, metres_per_degree

#: File endings and the reader each one selects.
TERRAIN_FORMATS = {".tif": "geotiff", ".tiff": "geotiff", ".png": "png", ".npy": "npy"}
#: Largest grid read, samples (8192 x 8192): the built Terrain holds 16 bytes a sample (module notes: Memory).
MAX_SAMPLES = 8192 * 8192
#: Smallest grid side, samples (the Terrain's cubic spline needs 4).
MIN_SIDE = 4
#: Sample spacing range, metres: below a millimetre or above 10 km is taken as a wrong unit or a wrong tag.
MIN_SPACING_M, MAX_SPACING_M = 1e-3, 10_000.0
#: The void value of SRTM and many DEMs, treated as no data even without a nodata tag.
VOID_SENTINEL = -32768
#: Values beyond this magnitude are fill values (e.g. float32's -3.4e38), not heights.
SENTINEL_ABS = 1e30
#: Largest |height| accepted after scaling, metres.
MAX_ABS_HEIGHT_M = 1e6


class TerrainFileError(ValueError):
    """A terrain file that cannot be used as it is; the message is one line starting with the file."""


class TerrainUsageError(ValueError):
    """Terrain options that cannot work together (an unknown ending, a PNG without a spacing); one line."""


@dataclass(frozen=True)
class TerrainFileOptions:
    """How to read a terrain file (``--spacing-m``, ``--height-scale``).

    Attributes
    ----------
    spacing_m : (2,) float or None
        Sample spacing (east, north), metres; required for PNG and ``.npy``,
        overrides a GeoTIFF's georeferencing when given.
    height_scale : float
        Metres per stored unit of height (> 0).
    """

    spacing_m: tuple[float, float] | None = None
    height_scale: float = 1.0

    def __post_init__(self):
        if self.spacing_m is not None:
            spacing = tuple(float(v) for v in np.broadcast_to(np.asarray(self.spacing_m, dtype=np.float64), (2,)))
            object.__setattr__(self, "spacing_m", spacing)
            for v in spacing:
                check_spacing("spacing_m", v)
        scale = float(self.height_scale)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"height_scale must be a finite number > 0 (metres per stored unit), got {scale}")
        object.__setattr__(self, "height_scale", scale)


@dataclass(frozen=True)
class TerrainGrid:
    """A terrain file's heights in the Terrain's convention.

    Attributes
    ----------
    elevation_m : (ny, nx) float32 or float64
        Heights, metres; row 0 south, column 0 west; finite everywhere.
        float32 when the file's values are float32 (or narrower) or
        integers of up to 16 bits and ``height_scale`` is 1 (exact as they
        are), float64 otherwise.
    dx_m, dy_m : float
        Sample spacing east and north, metres.
    path : str
        The file.
    kind : str
        ``geotiff``, ``png`` or ``npy``.
    notes : tuple of str
        One line per repair or warning (filled samples, 8-bit levels, ...).
    crs : str or None
        The GeoTIFF's CRS (e.g. ``EPSG:4326``), None otherwise.
    filled : int
        Samples filled from their nearest valid neighbour.
    """

    elevation_m: np.ndarray
    dx_m: float
    dy_m: float
    path: str
    kind: str
    notes: tuple = field(default_factory=tuple)
    crs: str | None = None
    filled: int = 0

    def describe(self) -> str:
        """One line: name, size, spacing, extent and height range."""
        ny, nx = self.elevation_m.shape
        z = self.elevation_m
        return (f"{Path(self.path).name}: {nx} x {ny} samples, {self.dx_m:.4g} m x {self.dy_m:.4g} m apart, "
                f"{(nx - 1) * self.dx_m / 1e3:.3g} km x {(ny - 1) * self.dy_m / 1e3:.3g} km, "
                f"heights {float(z.min()):.5g}..{float(z.max()):.5g} m")


def check_spacing(name: str, value_m: float) -> None:
    """ValueError naming ``name`` unless ``value_m`` (metres) lies in MIN_SPACING_M..MAX_SPACING_M."""
    if not (math.isfinite(value_m) and MIN_SPACING_M <= value_m <= MAX_SPACING_M):
        raise ValueError(f"{name} must lie between {MIN_SPACING_M * 1e3:g} mm and {MAX_SPACING_M / 1e3:g} km, "
                         f"got {value_m:g} m")


def check_terrain_path(path, options: TerrainFileOptions = TerrainFileOptions()) -> tuple[Path, str]:
    """The file and its reader's name, or ValueError (one line) before anything is read.

    Checks that the file's ending names a format, that a PNG or ``.npy``
    comes with ``options.spacing_m`` (:class:`TerrainUsageError`), and that
    the file exists (:class:`TerrainFileError`).
    """
    path = Path(path)
    kind = TERRAIN_FORMATS.get(path.suffix.lower())
    if kind is None:
        raise TerrainUsageError(f"{path}: unknown terrain format {path.suffix or '(no ending)'!r}; "
                                f"use one of {', '.join(TERRAIN_FORMATS)}")
    if kind in ("png", "npy") and options.spacing_m is None:
        name = "PNG" if kind == "png" else ".npy"
        raise TerrainUsageError(f"{path}: a {name} height map has no georeferencing; give its sample spacing "
                                "with --spacing-m (metres, DX or DX,DY) and, unless the values are metres, "
                                "--height-scale")
    if not path.is_file():
        raise TerrainFileError(f"{path}: no such file" if not path.exists() else f"{path} is not a file")
    return path, kind


def read_terrain_file(path, options: TerrainFileOptions = TerrainFileOptions()) -> TerrainGrid:
    """Read a terrain file (format by ending; see the module docstring).

    Returns
    -------
    TerrainGrid
        Heights (m) row 0 south, spacing (m), and the notes of any repair.

    Raises
    ------
    TerrainFileError
        One line: what is wrong with the file and what to do.
    TerrainUsageError
        From :func:`check_terrain_path` (unknown ending, missing option).
    """
    path, kind = check_terrain_path(path, options)
    notes = []
    reader = {"geotiff": _read_geotiff, "png": _read_png, "npy": _read_npy}[kind]
    raw, invalid, found, dx_m, dy_m, crs = reader(path, options, notes)
    heights = _as_heights(path, raw, notes, options.height_scale)
    del raw
    filled = _fill_invalid(path, heights, invalid, found, notes)
    if options.height_scale != 1.0:
        heights *= options.height_scale         # float64 (_as_heights)
    peak = max(float(heights.max()), -float(heights.min()))      # max |height| without an |heights| grid
    if not peak <= MAX_ABS_HEIGHT_M:
        raise TerrainFileError(f"{path}: heights reach {peak:.3g} m (after --height-scale "
                               f"{options.height_scale:g}), beyond ±{MAX_ABS_HEIGHT_M:g} m; check --height-scale "
                               "or the file's nodata value")
    for name, v in (("x", dx_m), ("y", dy_m)):
        try:
            check_spacing(f"the {name} spacing", v)
        except ValueError as exc:
            raise TerrainFileError(f"{path}: {exc}; check the georeferencing or give --spacing-m") from None
    return TerrainGrid(np.ascontiguousarray(heights), float(dx_m), float(dy_m), str(path), kind, tuple(notes),
                       crs, filled)


def terrain_from_file(path, options: TerrainFileOptions = TerrainFileOptions(), **terrain_options):
    """Read ``path`` and make its :class:`Terrain`; returns (Terrain, TerrainGrid).

    The Terrain has no synthetic detail (``detail=False`` unless
    ``terrain_options`` say otherwise): the detail is fitted to the built-in
    DEM and the built-in mesh's finest spacing, and a person's own terrain
    should show their data, not invented relief. ``terrain.dem_info`` stays
    None; the grid (without its array) is ``terrain.source``.

    The heights are handed over, not copied (``Terrain(..., copy=False)``):
    without a vertical exaggeration the returned grid's ``elevation_m`` is
    the terrain's ``dem_z_m`` itself (one grid, not two, float32 where
    :class:`TerrainGrid` says so); neither may be modified.
    """
    grid = read_terrain_file(path, options)
    terrain = Terrain(grid.elevation_m, grid.dx_m, grid.dy_m, **{"detail": False, "copy": False, **terrain_options})
    terrain.source = grid.__class__(None, grid.dx_m, grid.dy_m, grid.path, grid.kind, grid.notes, grid.crs,
                                    grid.filled)
    return terrain, grid


# ---------------------------------------------------------------------------------------------- readers
def _check_shape(path, shape) -> None:
    if len(shape) != 2:
        raise TerrainFileError(f"{path}: expected a 2-D grid of heights, got shape {tuple(shape)}")
    ny, nx = shape
    if min(ny, nx) < MIN_SIDE:
        raise TerrainFileError(f"{path}: {nx} x {ny} samples is too small; a terrain needs at least "
                               f"{MIN_SIDE} x {MIN_SIDE}")
    if ny * nx > MAX_SAMPLES:
        raise TerrainFileError(f"{path}: {nx} x {ny} = {nx * ny:,} samples is over the limit of {MAX_SAMPLES:,} "
                               f"(8192 x 8192); crop or downsample it "
                               "(e.g. gdal_translate -outsize 50% 50%)")


def _check_dtype(path, dtype) -> None:
    dtype = np.dtype(dtype)
    if dtype == np.bool_:
        raise TerrainFileError(f"{path}: holds booleans (a mask?), not heights; give a numeric grid")
    if dtype.kind == "c":
        raise TerrainFileError(f"{path}: holds complex numbers, not heights; save the real part "
                               "(np.save(path, a.real))")
    if dtype.kind not in "iuf":
        raise TerrainFileError(f"{path}: holds {dtype} values, not numbers; give a numeric grid")


def _as_heights(path, raw, notes, height_scale: float = 1.0) -> np.ndarray:
    """``raw`` (checked dtype) as a new C-contiguous grid of heights; a note for 8-bit data.

    float32 when that holds every value exactly and they are not scaled
    (``height_scale`` 1; float16/float32 files, integers of up to 16 bits):
    the same numbers as float64 in half the bytes. float64 otherwise.
    """
    if raw.dtype.itemsize == 1:
        notes.append(f"{path.name}: 8-bit heights have only 256 levels (terraces on gentle slopes); "
                     "a 16-bit or float file keeps the detail")
    kind, size = raw.dtype.kind, raw.dtype.itemsize
    exact32 = height_scale == 1.0 and ((kind == "f" and size <= 4) or (kind in "iu" and size <= 2))
    return np.array(raw, dtype=np.float32 if exact32 else np.float64)


def _fill_invalid(path, heights, invalid, found, notes) -> int:
    """Fill ``invalid`` samples of ``heights`` in place from the nearest valid one (``found``: what marked
    them, for the note); the count."""
    n_bad = int(invalid.sum()) if invalid is not None else 0
    if n_bad == 0:
        return 0
    if n_bad == invalid.size:
        raise TerrainFileError(f"{path}: every sample is no data ({', '.join(found)}); nothing to show")
    from scipy import ndimage as ndi

    idx = ndi.distance_transform_edt(invalid, return_distances=False, return_indices=True)
    heights[invalid] = heights[idx[0][invalid], idx[1][invalid]]
    notes.append(f"{path.name}: filled {n_bad:,} of {invalid.size:,} samples ({100.0 * n_bad / invalid.size:.3g} %) "
                 f"that had no data ({', '.join(found)}) with the height of the nearest valid sample")
    return n_bad


def _invalid(raw, nodata=None) -> tuple[np.ndarray, list[str]]:
    """Mask of no-data samples of a numeric grid, and what was found (for the note)."""
    found = []
    invalid = np.zeros(raw.shape, dtype=bool)
    if raw.dtype.kind == "f":
        bad = ~np.isfinite(raw)
        if bad.any():
            invalid |= bad
            found.append("NaN/inf")
        big = raw > SENTINEL_ABS               # |raw| > SENTINEL_ABS, without an |raw| grid
        big |= raw < -SENTINEL_ABS
        big &= ~bad
        if big.any():
            invalid |= big
            found.append(f"values beyond ±{SENTINEL_ABS:g}")
    if nodata is not None and math.isfinite(nodata):
        hit = raw == nodata
        if hit.any():
            invalid |= hit
            found.append(f"nodata {nodata:g}")
    if (nodata is None or nodata != VOID_SENTINEL) and (raw.dtype.kind == "f" or np.dtype(raw.dtype).itemsize >= 2
                                                        and raw.dtype.kind == "i"):
        hit = raw == VOID_SENTINEL
        if hit.any():
            invalid |= hit
            found.append(f"{VOID_SENTINEL} (the usual void value)")
    return invalid, found


def _read_geotiff(path, options, notes):
    try:
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
    except ImportError:       # a dependency in pyproject; only a broken install lacks it
        raise TerrainFileError(f"{path}: reading a GeoTIFF needs rasterio ('pip install rasterio')") from None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            ds = rasterio.open(_utf8_name(path))
        except RasterioIOError as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise TerrainFileError(f"{path}: not a readable GeoTIFF ({first})") from None
        with ds:
            _check_shape(path, (ds.height, ds.width))
            _check_dtype(path, ds.dtypes[0])
            if ds.count > 1:
                notes.append(f"{path.name}: {ds.count} bands; band 1 used as the heights")
            t = ds.transform
            if abs(t.b) > 0 or abs(t.d) > 0:
                raise TerrainFileError(f"{path}: the grid is rotated or sheared (transform {tuple(t)[:6]}); "
                                       "warp it north-up first (gdalwarp)")
            georeferenced = ds.crs is not None
            crs = ds.crs.to_string() if georeferenced else None
            geographic = georeferenced and ds.crs.is_geographic
            projected = georeferenced and ds.crs.is_projected
            units = ds.crs.linear_units_factor if projected else None
            rows = ds.height
            raw = ds.read(1)
            nodata = ds.nodata
    if options.spacing_m is not None:
        dx_m, dy_m = options.spacing_m
        if georeferenced:
            notes.append(f"{path.name}: spacing {dx_m:g} m x {dy_m:g} m from --spacing-m; "
                         f"the file's georeferencing ({crs}) is not used")
    elif not georeferenced:
        raise TerrainFileError(f"{path}: no coordinate reference system, so the sample spacing is unknown; "
                               "give it with --spacing-m (metres)")
    elif geographic:
        lat_top = t.f
        lat_bottom = t.f + t.e * rows
        lat_c = 0.5 * (lat_top + lat_bottom)
        if not (abs(lat_top) <= 90.0001 and abs(lat_bottom) <= 90.0001):
            raise TerrainFileError(f"{path}: geographic CRS but latitudes {lat_bottom:g}..{lat_top:g} are not "
                                   "degrees; check the georeferencing or give --spacing-m")
        m_lon, m_lat = metres_per_degree(lat_c)
        dx_m, dy_m = abs(t.a) * m_lon, abs(t.e) * m_lat
        notes.append(f"{path.name}: geographic ({crs}), {abs(t.a):.6g}° x {abs(t.e):.6g}° = {dx_m:.4g} m x "
                     f"{dy_m:.4g} m at its centre latitude {lat_c:.4f}°")
    elif projected:
        unit, factor = units
        dx_m, dy_m = abs(t.a) * factor, abs(t.e) * factor
        if factor != 1.0:
            notes.append(f"{path.name}: projected ({crs}) in {unit}; spacing {dx_m:.4g} m x {dy_m:.4g} m "
                         "(heights are taken as metres: use --height-scale if they are not)")
    else:
        raise TerrainFileError(f"{path}: CRS {crs} is neither geographic nor projected; give --spacing-m")
    invalid, found = _invalid(raw, nodata)
    # Row 0 of a north-up GeoTIFF (y pixel size < 0, the usual) is the north edge; the Terrain's is south.
    if t.e < 0:
        raw, invalid = raw[::-1], invalid[::-1]
    if t.a < 0:
        raw, invalid = raw[:, ::-1], invalid[:, ::-1]
    return raw, invalid, found, dx_m, dy_m, crs


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _utf8_name(path) -> str:
    """The GeoTIFF's name as GDAL takes it (UTF-8 text), or a TerrainFileError when its bytes are not UTF-8."""
    from ..io.images import UnnamablePath, opencv_name      # on use, as rasterio: only a GeoTIFF needs it

    try:
        return opencv_name(path, "GeoTIFF", library="GDAL")
    except UnnamablePath as exc:
        raise TerrainFileError(str(exc)) from None


def _read_png(path, options, notes):
    from ..io.images import read_image             # on use, as OpenCV was: only a PNG height map needs it

    with open(path, "rb") as f:
        head = f.read(26)
    if len(head) < 26 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise TerrainFileError(f"{path}: not a PNG file (no PNG signature); save the height map as a 16-bit PNG")
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    _check_shape(path, (height, width))            # before decoding a huge image
    image = read_image(path)                       # through memory: OpenCV never sees the path
    if image is None:
        raise TerrainFileError(f"{path}: OpenCV could not decode this PNG (damaged or truncated?)")
    invalid = None
    if image.ndim == 3:
        channels = image.shape[2]
        if channels in (2, 4):
            alpha = image[..., -1]
            invalid = alpha == 0
            image = image[..., :-1]
        if image.shape[2] == 3:
            b, g, r = image[..., 0], image[..., 1], image[..., 2]
            if not (np.array_equal(b, g) and np.array_equal(g, r)):
                raise TerrainFileError(f"{path}: a colour PNG (its channels differ); a height map has one "
                                       "channel: save it as 16-bit greyscale")
            notes.append(f"{path.name}: stored as colour with three equal channels; read as greyscale")
        image = image[..., 0]
    _check_dtype(path, image.dtype)
    raw = image[::-1]                              # row 0 of an image is north
    return raw, None if invalid is None else invalid[::-1], ["alpha = 0"], *options.spacing_m, None


def _read_npy(path, options, notes):
    with open(path, "rb") as f:
        if f.read(6) != b"\x93NUMPY":
            raise TerrainFileError(f"{path}: cannot be read as .npy (no NumPy header); save it with numpy.save")
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except ValueError as exc:
        raise TerrainFileError(f"{path}: not a plain numeric .npy ({str(exc).splitlines()[0].split('. ')[0]}); "
                               "save a 2-D numeric array") from None
    except (OSError, EOFError) as exc:
        raise TerrainFileError(f"{path}: cannot be read as .npy ({str(exc).splitlines()[0] or type(exc).__name__})"
                               ) from None
    if not isinstance(arr, np.ndarray):
        raise TerrainFileError(f"{path}: holds {type(arr).__name__}, not one array; save one 2-D array")
    if arr.dtype.fields is not None:
        raise TerrainFileError(f"{path}: holds a structured array ({arr.dtype}); save one 2-D numeric array")
    _check_dtype(path, arr.dtype)
    _check_shape(path, arr.shape)
    raw = np.asarray(arr)[::-1]                    # row 0 north, as an image
    invalid, found = _invalid(raw)
    return raw, invalid, found, *options.spacing_m, None
