"""A terrain height field built from a real elevation model plus synthetic detail.

Scene frame and units
---------------------
Scene units are **metres**: x east, y north, z up. The default terrain is the
digital elevation model (DEM) that matplotlib ships as sample data,
``jacksboro_fault_dem.npz``: 344 x 403 samples of elevation (int16, metres
above sea level) on a 3 arc-second grid (``dx = dy = 1/1200`` degree) around
the Jacksboro fault and Pine Mountain, Tennessee/Kentucky
(84.41°W–84.08°W, 36.45°N–36.73°N). In the file row 0 is the *northern* edge
(its key ``ymin`` = 36.733 holds the latitude of row 0, ``ymax`` = 36.446 that
of the last row; the Pine Mountain ridge then strikes NE and the Jacksboro
fault NW, as mapped). Degrees become metres by a local equirectangular
projection at the centre latitude with the WGS84 lengths of a degree there:
one sample is ``dx_m`` = 74.6 m east by ``dy_m`` = 92.5 m north, the terrain
29.98 km x 31.72 km. The origin (0, 0) is the south-west sample; z is the
elevation in metres (236–1076 m) times an optional vertical exaggeration.

What is real and what is synthetic
----------------------------------
``heights = dem_heights + detail_heights``.

- ``dem_heights`` (real): the DEM samples, interpolated by a tensor-product
  cubic B-spline fitted through the samples (``scipy.ndimage.spline_filter``,
  mirror boundary), so it returns the DEM values exactly at the sample points
  and is C2 between them. Its gradient is analytic.
- ``detail_heights`` (synthetic, off with ``detail=False``): a sum of plane
  waves (random-phase spectral synthesis, fixed ``seed``) whose wave vectors
  all lie *outside* the DEM's Nyquist rectangle ``|fx| < 1/(2 dx)``,
  ``|fy| < 1/(2 dy)`` (with a 15 % margin), up to
  ``1 / detail_min_wavelength_m``. It therefore adds nothing the DEM could
  have represented. Its power spectrum continues the DEM's own radially
  averaged power spectrum, a power law ``P(f) ∝ f^-β`` fitted between 1/8 and
  1/2 of the DEM's Nyquist frequency (β ≈ 4.8 for this DEM, whose hillslopes
  are smooth below ~200 m), and it is modulated by an envelope proportional
  to the DEM's local roughness (RMS of the DEM minus its 2-sample Gaussian
  blur, averaged over 8 samples), normalised to unit mean square, so rough
  slopes get more detail than flat valley floors. For this DEM the detail's
  RMS is about a metre (``detail_rms_m``); ``detail_gain`` scales it.

Queries outside ``extent`` are clamped to it for the DEM part (the terrain
continues as its border values); the detail is defined everywhere.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy import ndimage as ndi

DEM_SAMPLE_NAME = "jacksboro_fault_dem.npz"

_CHUNK = 1 << 13      # points per evaluation chunk (temporaries stay in cache)
_trapezoid = getattr(np, "trapezoid", None) or np.trapz
_NYQUIST_MARGIN = 1.15  # detail wave vectors stay this factor outside the DEM's Nyquist rectangle


def metres_per_degree(lat_deg: float) -> tuple[float, float]:
    """WGS84 length of one degree of longitude and latitude at a latitude.

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude, degrees.

    Returns
    -------
    m_per_deg_lon, m_per_deg_lat : float
        Metres per degree east and north.
    """
    p = math.radians(lat_deg)
    lat = 111132.92 - 559.82 * math.cos(2 * p) + 1.175 * math.cos(4 * p) - 0.0023 * math.cos(6 * p)
    lon = 111412.84 * math.cos(p) - 93.5 * math.cos(3 * p) + 0.118 * math.cos(5 * p)
    return lon, lat


class DemGrid(NamedTuple):
    """An elevation grid in metres.

    Attributes
    ----------
    elevation_m : (ny, nx) float64
        Elevation, metres; row 0 is the southern edge, column 0 the western.
    dx_m, dy_m : float
        Sample spacing east and north, metres.
    lon_west_deg, lat_south_deg : float
        Longitude of column 0 and latitude of row 0, degrees (nan if unknown).
    dlon_deg, dlat_deg : float
        Spacing in degrees (nan if unknown).
    """

    elevation_m: np.ndarray
    dx_m: float
    dy_m: float
    lon_west_deg: float = float("nan")
    lat_south_deg: float = float("nan")
    dlon_deg: float = float("nan")
    dlat_deg: float = float("nan")


def load_jacksboro_dem() -> DemGrid:
    """Load matplotlib's ``jacksboro_fault_dem.npz`` as a metric grid, rows south to north.

    Returns
    -------
    DemGrid
        344 x 403 elevations (m); ``dx_m`` ≈ 74.6, ``dy_m`` ≈ 92.5.
    """
    from matplotlib import cbook  # only for its bundled sample file; importing matplotlib is slow

    dem = cbook.get_sample_data(DEM_SAMPLE_NAME)
    elevation = np.asarray(dem["elevation"], dtype=np.float64)[::-1]   # file row 0 = north
    dlon, dlat = float(dem["dx"]), float(dem["dy"])
    lat_north = float(dem["ymin"])          # latitude of the file's row 0 (the north edge)
    lat_south = lat_north - (elevation.shape[0] - 1) * dlat
    lon_west = float(dem["xmin"])
    m_lon, m_lat = metres_per_degree(0.5 * (lat_north + lat_south))
    return DemGrid(np.ascontiguousarray(elevation), dlon * m_lon, dlat * m_lat,
                   lon_west, lat_south, dlon, dlat)


def _padded_spline_coefficients(z) -> np.ndarray:
    """Cubic B-spline coefficients of a grid, padded by 2 samples on every side, flattened.

    The result is ``np.pad(ndi.spline_filter(z, order=3, mode="mirror"), 2,
    mode="reflect").ravel()`` bit for bit, made in one array: the filter
    runs in place on the padded array's interior (a 1-D pass at a time, line
    by line), and the border is filled by the reflect rule afterwards, so no
    unpadded coefficient grid or float64 temporary of the grid's size is made.
    Padding by 2 keeps every 4 x 4 stencil of a clamped query in range.

    Parameters
    ----------
    z : (ny, nx) float
        Grid values (metres for the DEM; any unit for the envelope).

    Returns
    -------
    (ny + 4) * (nx + 4) float64
        Row-major: padded row ``i + 2`` column ``j + 2`` holds sample (i, j)'s coefficient.
    """
    ny, nx = z.shape
    padded = np.empty((ny + 4, nx + 4))
    inner = padded[2:-2, 2:-2]
    inner[...] = z
    ndi.spline_filter(inner, order=3, output=inner, mode="mirror")
    # The reflect rule (the edge sample is the mirror, not repeated): pad[1] = z[1], pad[0] = z[2], both ends.
    for lo, hi in ((1, 3), (0, 4)):
        padded[2:-2, lo] = padded[2:-2, hi]
        padded[2:-2, -1 - lo] = padded[2:-2, -1 - hi]
    for lo, hi in ((1, 3), (0, 4)):
        padded[lo] = padded[hi]
        padded[-1 - lo] = padded[-1 - hi]
    return padded.ravel()


def _bspline_weights(t):
    """Cubic B-spline weights of the 4 taps (i-1, i, i+1, i+2) and their derivatives.

    Parameters
    ----------
    t : (n,) float64
        Fractional position in [0, 1] between taps i and i+1.

    Returns
    -------
    w, dw : (n, 4) float64
        Weights (summing to 1) and their derivatives with respect to t.
    """
    t2 = t * t
    t3 = t2 * t
    s = 1.0 - t
    w = np.empty((len(t), 4))
    dw = np.empty((len(t), 4))
    w[:, 0] = s * s * s / 6
    w[:, 1] = 0.5 * t3 - t2 + 2.0 / 3.0
    w[:, 3] = t3 / 6
    w[:, 2] = 1.0 - w[:, 0] - w[:, 1] - w[:, 3]
    dw[:, 0] = -0.5 * s * s
    dw[:, 1] = 1.5 * t2 - 2.0 * t
    dw[:, 3] = 0.5 * t2
    dw[:, 2] = -(dw[:, 0] + dw[:, 1] + dw[:, 3])
    return w, dw


class Terrain:
    """Height field: an interpolated DEM (real) plus band-limited procedural detail (synthetic).

    Parameters
    ----------
    elevation_m : (ny, nx) array_like
        Elevation samples, metres, row 0 south, column 0 west; ny, nx >= 4.
    dx_m, dy_m : float
        Sample spacing east and north, metres.
    vertical_exaggeration : float
        Factor applied to the elevation (and hence to the detail fitted on it).
    detail : bool
        Add the synthetic sub-DEM-resolution detail.
    seed : int
        Seed of the detail's wave vectors and phases (the terrain is a pure
        function of its arguments and the seed).
    detail_min_wavelength_m : float
        Shortest detail wavelength, metres. The default, 60 m, is about twice
        the vertex spacing of the finest level of the default adaptive mesh
        (32 x 32 base quads, level 5: ~29 m x 31 m); shorter waves would alias.
    detail_waves_per_octave : int
        Plane waves per octave of the detail band.
    detail_gain : float
        Multiplier of the detail amplitude (1 = the DEM spectrum's extrapolation).
    origin_m : (2,)
        Scene (x, y) of sample [0, 0], metres.
    copy : bool
        False: ``elevation_m``, when it is a C-contiguous float64 grid (or
        float32 with ``detail=False``) and ``vertical_exaggeration`` is 1,
        is kept as ``dem_z_m`` itself instead of a float64 copy (the caller
        hands it over and must not change it afterwards). True (default):
        ``dem_z_m`` is always the Terrain's own float64 array.

    Attributes
    ----------
    extent : tuple of float
        (xmin, xmax, ymin, ymax), metres.
    dem_x_m : (nx,) ; dem_y_m : (ny,)
        Scene coordinates of the DEM columns and rows.
    dem_z_m : (ny, nx) float64, or float32 (``copy=False`` with a float32 grid)
        DEM elevation times the exaggeration: what ``dem_heights`` returns there.
        A float32 grid is not widened (its values are exact as they are; the
        spline coefficients are float64 either way, the same as from the
        widened grid).
    nyquist_cpm : (2,)
        DEM Nyquist frequencies (1/(2 dx), 1/(2 dy)), cycles per metre.
    spectral_exponent : float
        β of the fitted DEM power spectrum ``P(f) ∝ f^-β`` (nan with ``detail=False``: not fitted).
    detail_band_cpm : (2,)
        Radial frequency range of the detail waves, cycles per metre.
    detail_wavevectors_cpm : (W, 2) ; detail_amplitudes_m : (W,) ; detail_phases_rad : (W,)
        The detail's plane waves (before the roughness envelope and gain).
    detail_rms_m : float
        RMS of the detail over the terrain (envelope has unit mean square).
    dem_info : DemGrid or None
        Where the DEM came from (``jacksboro``: its geographic corner and
        spacing, without the elevation array); None for a grid passed in.
    source : object or None
        The file a terrain was read from (set by
        :func:`headplod.plod.terrain_file.terrain_from_file`: a ``TerrainGrid``
        without its array); None otherwise.
    """

    def __init__(self, elevation_m, dx_m: float, dy_m: float, *, vertical_exaggeration: float = 1.0,
                 detail: bool = True, seed: int = 0, detail_min_wavelength_m: float = 60.0,
                 detail_waves_per_octave: int = 24, detail_gain: float = 1.0, origin_m=(0.0, 0.0),
                 copy: bool = True):
        z = np.asarray(elevation_m)
        # copy=False, no exaggeration: the caller's grid is kept as it is (no second grid; module notes).
        owned = (not copy and z.flags.c_contiguous and float(vertical_exaggeration) == 1.0
                 and (z.dtype == np.float64 or (z.dtype == np.float32 and not detail)))
        if not owned:
            z = np.asarray(z, dtype=np.float64)
        if z.ndim != 2 or min(z.shape) < 4:
            raise ValueError(f"elevation_m must be a 2-D grid of at least 4 x 4 samples, got shape {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("elevation_m must be finite everywhere (fill voids first)")
        if not (dx_m > 0 and dy_m > 0):
            raise ValueError(f"dx_m and dy_m must be positive, got {dx_m}, {dy_m}")
        if detail_min_wavelength_m <= 0:
            raise ValueError(f"detail_min_wavelength_m must be positive, got {detail_min_wavelength_m}")
        self.vertical_exaggeration = float(vertical_exaggeration)
        self.dem_info = None
        self.source = None
        self.dx_m, self.dy_m = float(dx_m), float(dy_m)
        ny, nx = z.shape
        self.shape = (ny, nx)
        x0, y0 = float(origin_m[0]), float(origin_m[1])
        self.dem_x_m = x0 + self.dx_m * np.arange(nx)
        self.dem_y_m = y0 + self.dy_m * np.arange(ny)
        self.dem_z_m = z if owned else z * self.vertical_exaggeration
        self.extent = (x0, float(self.dem_x_m[-1]), y0, float(self.dem_y_m[-1]))
        self.nyquist_cpm = np.array([0.5 / self.dx_m, 0.5 / self.dy_m])
        self.detail = bool(detail)
        self.seed = int(seed)
        self.detail_gain = float(detail_gain)
        self.detail_min_wavelength_m = float(detail_min_wavelength_m)

        self._row_stride = nx + 4
        # Offsets of the 16 taps from tap (i-1, j-1) in the padded, flattened coefficients.
        self._stencil = (np.arange(4)[:, None] * self._row_stride + np.arange(4)[None, :]).ravel().astype(np.int32)
        if not self.detail:
            # No detail: no roughness envelope, spectrum or waves (their cost grows with the grid, in
            # time and memory, for nothing that is drawn).
            self._coef = [_padded_spline_coefficients(self.dem_z_m)]
            self.spectral_exponent = float("nan")
            self._make_waves(-np.inf, int(detail_waves_per_octave))
        else:
            envelope = self._roughness_envelope(self.dem_z_m)
            self._coef = [_padded_spline_coefficients(self.dem_z_m), _padded_spline_coefficients(envelope)]
            del envelope
            self.spectral_exponent, log_p0 = self._fit_spectrum(self.dem_z_m)
            self._make_waves(log_p0, int(detail_waves_per_octave))
        self._centre = np.array([(self.extent[0] + self.extent[1]) / 2, (self.extent[2] + self.extent[3]) / 2])

    # ------------------------------------------------------------------ construction
    @classmethod
    def jacksboro(cls, **options) -> "Terrain":
        """The terrain of matplotlib's Jacksboro fault DEM (see the module docstring); options as ``Terrain``."""
        dem = load_jacksboro_dem()
        terrain = cls(dem.elevation_m, dem.dx_m, dem.dy_m, **options)
        terrain.dem_info = dem._replace(elevation_m=None)
        return terrain

    @staticmethod
    def _roughness_envelope(z):
        """Local roughness of the DEM normalised to unit mean square, (ny, nx)."""
        residual = z - ndi.gaussian_filter(z, 2.0, mode="mirror")
        rms = np.sqrt(ndi.gaussian_filter(residual ** 2, 8.0, mode="mirror"))
        ms = float(np.mean(rms ** 2))
        return rms / math.sqrt(ms) if ms > 0 else np.ones_like(z)

    def _fit_spectrum(self, z):
        """Fit ``log P = log_p0 - β log(f / f_ref)`` to the DEM's radially averaged PSD, m^4."""
        ny, nx = z.shape
        yy, xx = np.mgrid[0:ny, 0:nx]
        design = np.column_stack([np.ones(z.size), xx.ravel(), yy.ravel()])
        plane = design @ np.linalg.lstsq(design, z.ravel(), rcond=None)[0]
        window = np.outer(np.hanning(ny), np.hanning(nx))
        spectrum = np.fft.fft2((z - plane.reshape(z.shape)) * window)
        psd = np.abs(spectrum) ** 2 * self.dx_m * self.dy_m / (z.size * np.mean(window ** 2))
        fx, fy = np.meshgrid(np.fft.fftfreq(nx, self.dx_m), np.fft.fftfreq(ny, self.dy_m))
        f = np.hypot(fx, fy)
        f_n = float(self.nyquist_cpm.min())
        band = (f > f_n / 8) & (f < f_n / 2) & (psd > 0)
        if band.sum() < 8:
            return 3.0, -np.inf
        slope, intercept = np.polyfit(np.log(f[band] / f_n), np.log(psd[band]), 1)
        beta = float(np.clip(-slope, 1.0, 8.0))
        return beta, float(intercept)     # log P at f = f_n (the reference frequency)

    def _make_waves(self, log_p0, waves_per_octave):
        """Draw the detail's plane waves (deterministic in ``seed``) and scale them to the fitted spectrum."""
        f_n = float(self.nyquist_cpm.min())
        f_lo = _NYQUIST_MARGIN * f_n
        f_hi = 1.0 / self.detail_min_wavelength_m
        self.detail_band_cpm = np.array([f_lo, max(f_lo, f_hi)])
        empty = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        if f_hi <= 1.05 * f_lo or not np.isfinite(log_p0):
            self.detail_wavevectors_cpm, self.detail_amplitudes_m, self.detail_phases_rad = empty
            self.detail_rms_m = 0.0
            self._set_wave_tables()
            return
        rect = _NYQUIST_MARGIN * self.nyquist_cpm

        def outside(kx, ky):
            return (np.abs(kx) > rect[0]) | (np.abs(ky) > rect[1])

        n_waves = max(4, int(round(waves_per_octave * math.log2(f_hi / f_lo))))
        rng = np.random.default_rng(self.seed)
        k = np.zeros((0, 2))
        while len(k) < n_waves:      # rejection sampling: log-uniform |k|, uniform direction (half plane)
            f = f_lo * (f_hi / f_lo) ** rng.random(4 * n_waves)
            theta = np.pi * rng.random(4 * n_waves)
            cand = np.column_stack([f * np.cos(theta), f * np.sin(theta)])
            k = np.concatenate([k, cand[outside(cand[:, 0], cand[:, 1])]])
        k = k[:n_waves]
        phases = 2 * np.pi * rng.random(n_waves)
        beta = self.spectral_exponent
        f = np.hypot(k[:, 0], k[:, 1])
        # Sampling density ∝ 1/f² per unit area of the frequency plane, so a wave stands for
        # P(f) f² of spectrum: amplitude ∝ f^(1 - β/2); the total is set by the integral below.
        raw = f ** (1.0 - beta / 2.0)
        # Variance the fitted spectrum puts in the band: ∬ P dfx dfy over the (full-plane) region.
        fr = np.geomspace(f_lo, f_hi, 400)
        th = np.linspace(0, 2 * np.pi, 1440, endpoint=False)
        FR, TH = np.meshgrid(fr, th)
        inside = outside(FR * np.cos(TH), FR * np.sin(TH))
        integrand = np.exp(log_p0) * (FR / f_n) ** (-beta) * FR * FR * inside   # P f df dθ with df = f dlogf
        variance = float(_trapezoid(integrand.mean(axis=0) * 2 * np.pi, np.log(fr)))
        amplitudes = raw * math.sqrt(2.0 * variance / np.sum(raw ** 2))
        self.detail_wavevectors_cpm, self.detail_amplitudes_m, self.detail_phases_rad = k, amplitudes, phases
        self.detail_rms_m = math.sqrt(variance) * self.detail_gain
        self._set_wave_tables()

    def _set_wave_tables(self):
        self._w_k = (2 * np.pi * self.detail_wavevectors_cpm).astype(np.float32)       # rad/m
        self._w_a = (self.detail_amplitudes_m * self.detail_gain).astype(np.float32)
        self._w_phi = self.detail_phases_rad.astype(np.float32)

    # ------------------------------------------------------------------ evaluation
    def _spline(self, x, y):
        """DEM and envelope splines at clamped points.

        Returns
        -------
        value, d_dx, d_dy : list of two (n,) float64
            [DEM, envelope] values and their x and y derivatives (per metre); [DEM] only
            with ``detail=False``.
        """
        ny, nx = self.shape
        q = np.clip((x - self.extent[0]) / self.dx_m, 0.0, nx - 1.0)
        r = np.clip((y - self.extent[2]) / self.dy_m, 0.0, ny - 1.0)
        j0 = np.minimum(q.astype(np.int32), nx - 2)
        i0 = np.minimum(r.astype(np.int32), ny - 2)
        wq, dwq = _bspline_weights(q - j0)
        wr, dwr = _bspline_weights(r - i0)
        # Padded index of tap (i0 - 1, j0 - 1) is (i0 + 1, j0 + 1).
        idx = ((i0 + 1) * self._row_stride + (j0 + 1))[:, None] + self._stencil
        w = (wr[:, :, None] * wq[:, None, :]).reshape(-1, 16)
        w_x = (wr[:, :, None] * dwq[:, None, :]).reshape(-1, 16)
        w_y = (dwr[:, :, None] * wq[:, None, :]).reshape(-1, 16)
        keep_x = ((x >= self.extent[0]) & (x <= self.extent[1])) / self.dx_m   # clamped: flat outside
        keep_y = ((y >= self.extent[2]) & (y <= self.extent[3])) / self.dy_m
        value, d_dx, d_dy = [], [], []
        for coef in self._coef:                       # DEM, envelope
            taps = coef[idx]
            value.append(np.einsum("ij,ij->i", taps, w))
            d_dx.append(np.einsum("ij,ij->i", taps, w_x) * keep_x)
            d_dy.append(np.einsum("ij,ij->i", taps, w_y) * keep_y)
        return value, d_dx, d_dy

    def _waves(self, x, y, gradient, smooth_m=None):
        """Sum of the detail waves (float32 arithmetic; needs at least one wave) and optionally its
        gradient, each (n,) float64 (gradient entries None when not asked for).

        ``smooth_m`` (scalar or (n,), metres): the gradient of the waves as
        seen through a Gaussian of that standard deviation, i.e. each wave of
        wavenumber k scaled by exp(−½ k² σ²) (exact for plane waves); the
        sum itself (heights) stays exact."""
        n = len(x)
        sigma2 = None
        if smooth_m is not None:
            sigma2 = (np.broadcast_to(np.asarray(smooth_m, dtype=np.float32), (n,)) ** 2).astype(np.float32)
        s = np.zeros(n, np.float32)
        xr = (x - self._centre[0]).astype(np.float32)
        yr = (y - self._centre[1]).astype(np.float32)
        gx = np.zeros(n, np.float32) if gradient else None
        gy = np.zeros(n, np.float32) if gradient else None
        for (kx, ky), a, phi in zip(self._w_k, self._w_a, self._w_phi):   # a few dozen waves
            arg = kx * xr + ky * yr + phi
            s += a * np.cos(arg)
            if gradient:
                sn = a * np.sin(arg)
                if sigma2 is not None:
                    sn *= np.exp(np.float32(-0.5 * (kx * kx + ky * ky)) * sigma2)
                gx -= kx * sn
                gy -= ky * sn
        if not gradient:
            return s.astype(np.float64), None, None
        return s.astype(np.float64), gx.astype(np.float64), gy.astype(np.float64)

    def _evaluate(self, x, y, *, dem=True, detail=None, gradient=True, smooth_m=None):
        """Height and gradient over flattened arrays, chunked. Returns z, dz/dx, dz/dy (n,).

        ``smooth_m``: the synthetic detail's gradient prefiltered by a Gaussian of this σ (m; scalar or (n,))."""
        if smooth_m is not None:
            smooth_m = np.broadcast_to(np.asarray(smooth_m, dtype=np.float64), (len(x),))
        detail = self.detail if detail is None else detail
        n = len(x)
        z, gx, gy = np.zeros(n), np.zeros(n), np.zeros(n)
        for start in range(0, n, _CHUNK):       # chunks bound the temporaries; vectorized inside
            sl = slice(start, min(n, start + _CHUNK))
            xs, ys = x[sl], y[sl]
            value, d_dx, d_dy = self._spline(xs, ys)
            if dem:
                z[sl], gx[sl], gy[sl] = value[0], d_dx[0], d_dy[0]
            if detail and len(self._w_a):
                w, wx, wy = self._waves(xs, ys, gradient, None if smooth_m is None else smooth_m[sl])
                e = value[1]
                z[sl] += e * w
                if gradient:
                    gx[sl] += d_dx[1] * w + e * wx
                    gy[sl] += d_dy[1] * w + e * wy
        return z, gx, gy

    @staticmethod
    def _flat(x, y):
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return x.shape, x.ravel(), y.ravel()

    def heights(self, x, y) -> np.ndarray:
        """Terrain height.

        Parameters
        ----------
        x, y : array_like, broadcastable
            Scene coordinates, metres (east, north).

        Returns
        -------
        z : ndarray, broadcast shape, float64
            Height, metres (DEM elevation x exaggeration, plus detail if enabled).
        """
        shape, xf, yf = self._flat(x, y)
        return self._evaluate(xf, yf, gradient=False)[0].reshape(shape)

    def dem_heights(self, x, y) -> np.ndarray:
        """The real part only: the DEM's cubic B-spline interpolant, metres (shape as ``heights``)."""
        shape, xf, yf = self._flat(x, y)
        return self._evaluate(xf, yf, detail=False, gradient=False)[0].reshape(shape)

    def detail_heights(self, x, y) -> np.ndarray:
        """The synthetic part only (zero if ``detail`` is off), metres (shape as ``heights``)."""
        shape, xf, yf = self._flat(x, y)
        if not self.detail:
            return np.zeros(shape)
        return self._evaluate(xf, yf, dem=False, detail=True, gradient=False)[0].reshape(shape)

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Analytic slope (dz/dx, dz/dy), dimensionless, each of the broadcast shape of x, y."""
        shape, xf, yf = self._flat(x, y)
        _, gx, gy = self._evaluate(xf, yf)
        return gx.reshape(shape), gy.reshape(shape)

    def sample(self, x, y, smooth_m=None) -> tuple[np.ndarray, np.ndarray]:
        """Heights and unit normals in one pass.

        Parameters
        ----------
        x, y : array_like, broadcastable
            Scene coordinates, metres.
        smooth_m : float or array_like, optional
            σ (metres) of a Gaussian prefilter of the synthetic detail's
            slope, per point (broadcast with x, y): the normals of the
            surface a coarse mesh level can represent; heights stay exact
            (the DEM's spline is left as it is: its finest features are its
            75-92 m samples).

        Returns
        -------
        z : (...) float64
            Heights, metres.
        normals : (..., 3) float64
            Upward unit normals ``(-dz/dx, -dz/dy, 1) / norm``, scene frame.
        """
        shape, xf, yf = self._flat(x, y)
        sm = None if smooth_m is None else np.broadcast_to(np.asarray(smooth_m, dtype=np.float64), shape).ravel()
        z, gx, gy = self._evaluate(xf, yf, smooth_m=sm)
        n = np.column_stack([-gx, -gy, np.ones_like(gx)])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return z.reshape(shape), n.reshape(shape + (3,))

    def normals(self, x, y) -> np.ndarray:
        """Upward unit normals, (..., 3) float64, from the analytic gradient (see ``sample``)."""
        return self.sample(x, y)[1]
