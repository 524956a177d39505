"""The visible-difference predictors that score a frame against a reference in JOD (``render --compare``, the
benchmarks' judge, :mod:`headplod.bench.plod_judge`).

Mantiuk's group's metrics score a test image against a reference in JOD (10 = identical, each unit below one
JOD of preference), knowing where the viewer looks and the screen's real size:

* ``"fvvdp"`` (default): FovVideoVDP (``pyfvvdp``) in foveated mode, the fixation point at the POI;
* ``"cvvdp"``: ColorVideoVDP (``pycvvdp`` 0.5.x), same geometry, no foveated mode (it judges every pixel as
  fixated): the second opinion. Its PyPI ``torchvision`` is a CUDA build; :func:`_import_metric` declares the
  two operator schemas torchvision's import registers so the import succeeds.

They are the optional extra ``.[vdp]``; without it :func:`vdp_available` is False. Geometry
(:func:`display_geometry`): the image fills the display of the screen's physical size, the eye on the normal
through its centre at the head's distance. Photometry (the metrics' ``standard_4k``): 200 cd/m² peak, 1000:1,
sRGB, 250 lux, 0.5 % reflectance (:class:`JudgeSettings`).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from .projection import screen_to_image_px

__all__ = ["METRICS", "JudgeSettings", "DisplayGeometry", "display_geometry", "fixation_px", "vdp_available",
           "Judge"]

#: The metrics this module can call, by the name of the PyPI package: "fvvdp" is the foveated one.
METRICS = ("fvvdp", "cvvdp")


@dataclass(frozen=True)
class JudgeSettings:
    """How the judge sees: ``metric`` (one of :data:`METRICS`), the display's white (cd/m²) and contrast ratio,
    the room's illuminance on the screen (lux) and the screen's reflectance (fraction), PyTorch's CPU threads,
    and the largest eye offset from the normal through the screen's centre the metrics' model is used for (mm).
    """

    metric: str = "fvvdp"
    peak_luminance_cd_m2: float = 200.0
    contrast: float = 1000.0
    ambient_lux: float = 250.0
    reflectance: float = 0.005
    threads: int = 2
    max_eye_offset_mm: float = 5.0

    def __post_init__(self) -> None:
        if self.metric not in METRICS:
            raise ValueError(f"unknown metric {self.metric!r}; expected one of {METRICS}")
        for name in ("peak_luminance_cd_m2", "contrast", "max_eye_offset_mm"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"JudgeSettings.{name} must be a positive number, got {value!r}")
        if not (np.isfinite(self.ambient_lux) and self.ambient_lux >= 0):
            raise ValueError(f"JudgeSettings.ambient_lux must be ≥ 0 lux, got {self.ambient_lux!r}")
        if not (0 <= self.reflectance < 1):
            raise ValueError(f"JudgeSettings.reflectance must be in [0, 1), got {self.reflectance!r}")
        if int(self.threads) != self.threads or self.threads < 1:
            raise ValueError(f"JudgeSettings.threads must be a positive integer, got {self.threads!r}")


@dataclass(frozen=True)
class DisplayGeometry:
    """The display as the judge sees it: the image's (width, height) px, the screen's size (m), the eye's
    distance to the screen plane along its normal (m)."""

    resolution_px: tuple[int, int]
    width_m: float
    height_m: float
    distance_m: float

    def __post_init__(self) -> None:
        w, h = self.resolution_px
        if int(w) != w or int(h) != h or w < 1 or h < 1:
            raise ValueError(f"resolution_px must be two positive integers (width, height), got {self.resolution_px!r}")
        for name in ("width_m", "height_m", "distance_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"DisplayGeometry.{name} must be a positive length in m, got {value!r}")

    @property
    def horizontal_fov_deg(self) -> float:
        """The screen's width as a visual angle, degrees."""
        return 2 * math.degrees(math.atan(self.width_m / (2 * self.distance_m)))

    @property
    def px_per_deg(self) -> float:
        """Pixels per degree at the screen's centre (one pixel's angle there), px/deg."""
        return 1 / (2 * math.degrees(math.atan(0.5 * self.width_m / self.resolution_px[0] / self.distance_m)))


def display_geometry(screen, head_mm, image_size, max_eye_offset_mm: float = 5.0) -> DisplayGeometry:
    """The judge's display: ``screen``'s physical size (its corners, mm), seen from ``head_mm`` (3,) world mm, as
    an image of ``image_size`` (w, h) px filling it; ValueError for an eye more than ``max_eye_offset_mm`` off
    the normal through the screen's centre."""
    head = np.asarray(head_mm, dtype=np.float64)
    if head.shape != (3,) or not np.all(np.isfinite(head)):
        raise ValueError(f"head_mm must be a finite 3-vector (mm), got shape {head.shape}")
    tl, tr, bl = (np.asarray(c, dtype=np.float64) for c in (screen.top_left, screen.top_right, screen.bottom_left))
    right, down = tr - tl, bl - tl
    width_mm, height_mm = float(np.linalg.norm(right)), float(np.linalg.norm(down))
    normal = np.cross(right, down)
    normal /= np.linalg.norm(normal)
    centre = screen.pixel_to_world(np.array(screen.size_px, dtype=np.float64) / 2.0)
    to_eye = head - centre
    distance_mm = abs(float(to_eye @ normal))
    offset_mm = float(np.linalg.norm(to_eye - (to_eye @ normal) * normal))
    if offset_mm > max_eye_offset_mm:
        raise ValueError(f"the eye is {offset_mm:.1f} mm off the screen centre's normal (the judge's model allows "
                         f"{max_eye_offset_mm:g} mm)")
    if distance_mm <= 0:
        raise ValueError("the eye lies in the screen plane")
    return DisplayGeometry(resolution_px=(int(image_size[0]), int(image_size[1])), width_m=width_mm / 1000,
                           height_m=height_mm / 1000, distance_m=distance_mm / 1000)


def fixation_px(screen, poi_px, image_size) -> np.ndarray:
    """The metrics' fixation point (x, y), float64 (2,), for ``poi_px`` in the screen's continuous px: scaled
    to the image of ``image_size`` (w, h) px, minus half a pixel (the metrics put a pixel's centre at index + 0.5).
    """
    poi = np.asarray(poi_px, dtype=np.float64).reshape(-1)
    if poi.shape != (2,) or not np.all(np.isfinite(poi)):
        raise ValueError(f"poi_px must be a finite (x, y) in screen px, got {poi_px!r}")
    return screen_to_image_px(poi, screen.size_px, image_size, pixel_index=True)


def vdp_available(metric: str = "fvvdp") -> bool:
    """True when the optional extra for ``metric`` (one of METRICS) imports."""
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; expected one of {METRICS}")
    try:
        _import_metric(metric)
    except ImportError:
        return False
    return True


def _import_metric(metric: str):
    """The metric's package (``pyfvvdp`` or ``pycvvdp``); ImportError when the extra is missing."""
    import torch  # noqa: F401  (ImportError without the extra)

    if metric == "fvvdp":
        return _import_isolated("pyfvvdp")
    if "torchvision" not in sys.modules:
        try:
            import torchvision  # noqa: F401
        except RuntimeError as e:
            # PyPI's torchvision is built for CUDA: with the CPU torch its C
            # operators do not load, and its import then fails registering fake
            # kernels for two of them. Declare their schemas (the metric never
            # calls them) and import again.
            if "torchvision::" not in str(e):
                raise
            for name in [m for m in sys.modules if m == "torchvision" or m.startswith("torchvision.")]:
                del sys.modules[name]
            _declare_torchvision_nms()
            import torchvision  # noqa: F401,F811
    return _import_isolated("pycvvdp")


def _import_isolated(package: str):
    """Import ``pyfvvdp`` or ``pycvvdp`` so that both can live in one process: each imports its helpers as
    top-level modules of the same names (``interp``, ``utils``, ...), so its folder goes first on the path while
    it is imported, and the other's helpers are set aside and put back afterwards.
    """
    import importlib.util
    import os

    if package not in ("pyfvvdp", "pycvvdp"):
        raise ValueError(f"no metric package {package!r}")

    if package in sys.modules:
        return sys.modules[package]
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        raise ImportError(f"{package} is not installed")
    folder = os.path.dirname(os.path.abspath(spec.origin))
    helpers = {os.path.splitext(n)[0] for n in os.listdir(folder)
               if n.endswith(".py") or os.path.isdir(os.path.join(folder, n))} - {"__init__", "__pycache__"}
    aside = {n: sys.modules.pop(n) for n in list(sys.modules) if n.split(".")[0] in helpers}
    sys.path.insert(0, folder)
    try:
        if package == "pyfvvdp":
            import pyfvvdp as module
        else:
            import pycvvdp as module
    finally:
        sys.path.remove(folder)
        for n in [n for n in list(sys.modules) if n.split(".")[0] in helpers]:
            if n in aside:
                sys.modules[n] = aside.pop(n)
        sys.modules.update(aside)
    return module


_DECLARED = []


def _declare_torchvision_nms() -> None:
    import torch

    if _DECLARED:
        return
    lib = torch.library.Library("torchvision", "FRAGMENT")
    for op in ("nms", "qnms"):
        if not hasattr(torch.ops.torchvision, op):
            lib.define(f"{op}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    _DECLARED.append(lib)     # the library object must live for the definitions to stay


class Judge:
    """One metric set up for one display; :meth:`jod` scores image pairs.

    Building it loads the metric's CSF tables (slow); reuse it.
    """

    def __init__(self, display: DisplayGeometry, settings: JudgeSettings = JudgeSettings(),
                 heatmap: bool | str = False):
        """``heatmap``: False (none), True (the metrics' threshold colour map, :meth:`jod_map`) or ``"raw"`` (the
        visible difference per pixel, :meth:`jod_error_map`)."""
        self.display, self.settings = display, settings
        if heatmap not in (False, True, "raw"):
            raise ValueError(f"heatmap must be False, True or 'raw', got {heatmap!r}")
        heatmap = "raw" if heatmap == "raw" else ("threshold" if heatmap else None)   # threshold: blue … red
        import torch

        torch.set_num_threads(int(settings.threads))
        vdp = _import_metric(settings.metric)
        s = settings
        if s.metric == "fvvdp":
            geometry = vdp.fvvdp_display_geometry(display.resolution_px, distance_m=display.distance_m,
                                                  fov_horizontal=display.horizontal_fov_deg)
            photometry = vdp.fvvdp_display_photo_eotf(s.peak_luminance_cd_m2, contrast=s.contrast, EOTF="sRGB",
                                                      E_ambient=s.ambient_lux, k_refl=s.reflectance)
            self._metric = vdp.fvvdp(display_photometry=photometry, display_geometry=geometry, foveated=True,
                                     heatmap=heatmap, device=torch.device("cpu"), quiet=True)
        else:
            geometry = vdp.vvdp_display_geometry(display.resolution_px, distance_m=display.distance_m,
                                                 fov_horizontal=display.horizontal_fov_deg)
            photometry = vdp.vvdp_display_photo_eotf(s.peak_luminance_cd_m2, contrast=s.contrast,
                                                     source_colorspace="sRGB", E_ambient=s.ambient_lux,
                                                     k_refl=s.reflectance)
            self._metric = vdp.cvvdp(display_photometry=photometry, display_geometry=geometry, heatmap=heatmap,
                                     device=torch.device("cpu"), quiet=True)
        self.last_seconds = float("nan")

    @property
    def foveated(self) -> bool:
        """Whether the metric uses the fixation point (only FovVideoVDP has a foveated mode)."""
        return self.settings.metric == "fvvdp"

    def jod_map(self, reference_rgb: np.ndarray, test_rgb: np.ndarray, fixation: np.ndarray):
        """(JOD, heatmap): the heatmap is sRGB uint8 (H, W, 3), the metric's threshold colour map over the
        reference's luminance (blue: invisible, green: at threshold, red: clearly visible). Needs ``heatmap=True``."""
        if self._metric.heatmap != "threshold":
            raise ValueError("this Judge was built without heatmap=True")
        q, stats = self._predict(reference_rgb, test_rgb, fixation)
        hm = stats["heatmap"].float().numpy()[0, :, 0]              # (3, H, W) in 0..1, display-encoded
        return q, np.clip(np.round(np.moveaxis(hm, 0, -1) * 255), 0, 255).astype(np.uint8)

    def jod_error_map(self, reference_rgb: np.ndarray, test_rgb: np.ndarray, fixation: np.ndarray):
        """(JOD, error map): the map is float32 (H, W), the metric's visible difference per pixel (0: none;
        larger: more visible; its unit the metric's pooled difference before the JOD mapping). Needs
        ``heatmap="raw"``."""
        if self._metric.heatmap != "raw":
            raise ValueError("this Judge was built without heatmap='raw'")
        q, stats = self._predict(reference_rgb, test_rgb, fixation)
        return q, stats["heatmap"].float().numpy()[0, 0, 0]

    def jod_video(self, reference_frames: np.ndarray, test_frames: np.ndarray, fixations: np.ndarray,
                  fps: float = 60.0) -> float:
        """JOD of a video ``test_frames`` against ``reference_frames``, both sRGB uint8 (F, H, W, 3) at ``fps``
        Hz, with frame f fixated at ``fixations[f]`` (F, 2) image px (FovVideoVDP takes one fixation point per
        frame; a non-foveated metric ignores them). ``last_seconds`` holds the wall time."""
        ref, test = np.asarray(reference_frames), np.asarray(test_frames)
        if ref.ndim != 4 or ref.shape != test.shape or ref.shape[0] < 2:
            raise ValueError(f"the frames must be two (F, H, W, 3) stacks of the same shape, F ≥ 2; got "
                             f"{ref.shape} and {test.shape}")
        for f in (0, len(ref) - 1):
            _check_image("reference_frames[f]", ref[f], self.display.resolution_px)
            _check_image("test_frames[f]", test[f], self.display.resolution_px)
        fix = np.asarray(fixations, dtype=np.float64)
        if fix.shape != (len(ref), 2) or not np.all(np.isfinite(fix)):
            raise ValueError(f"fixations must be finite (F, 2) = ({len(ref)}, 2) image px, got shape {fix.shape}")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive frame rate, Hz, got {fps!r}")
        import torch

        t0 = time.perf_counter()
        with torch.no_grad():
            if self.foveated:
                q, _ = self._metric.predict(test, ref, dim_order="FHWC", frames_per_second=float(fps),
                                            fixation_point=torch.tensor(fix, dtype=torch.float32))
            else:
                q, _ = self._metric.predict(test, ref, dim_order="FHWC", frames_per_second=float(fps))
        self.last_seconds = time.perf_counter() - t0
        return float(q)

    def jod(self, reference_rgb: np.ndarray, test_rgb: np.ndarray, fixation: np.ndarray) -> float:
        """JOD (10 = identical) of ``test_rgb`` against ``reference_rgb``, both sRGB uint8 (H, W, 3).

        ``fixation`` is the fixation point (x, y) in image pixel indices
        (:func:`fixation_px`); (H, W) must be the display's resolution.
        ``last_seconds`` holds the wall time of the call.
        """
        return self._predict(reference_rgb, test_rgb, fixation)[0]

    def _predict(self, reference_rgb, test_rgb, fixation):
        _check_image("reference_rgb", reference_rgb, self.display.resolution_px)
        _check_image("test_rgb", test_rgb, self.display.resolution_px)
        fix = np.asarray(fixation, dtype=np.float64).reshape(-1)
        if fix.shape != (2,) or not np.all(np.isfinite(fix)):
            raise ValueError(f"fixation must be a finite (x, y) in image px, got {fixation!r}")
        import torch

        t0 = time.perf_counter()
        with torch.no_grad():
            if self.foveated:
                q, stats = self._metric.predict(test_rgb, reference_rgb, dim_order="HWC",
                                                fixation_point=torch.tensor(fix, dtype=torch.float32))
            else:
                q, stats = self._metric.predict(test_rgb, reference_rgb, dim_order="HWC")
        self.last_seconds = time.perf_counter() - t0
        return float(q), stats


def _check_image(name, image, resolution_px) -> None:
    w, h = resolution_px
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.shape != (h, w, 3):
        shape = getattr(image, "shape", None)
        dtype = getattr(image, "dtype", type(image).__name__)
        raise ValueError(f"{name} must be uint8 sRGB of shape ({h}, {w}, 3), got {dtype} {shape}")


# --- The benchmark: JOD against frame time -------------------------------------------------------------------
