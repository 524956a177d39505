"""Per-triangle level selection: the perceptual criteria applied to a view.

A view is the viewer's eye position (world frame = left camera frame, mm), the
point of interest on the screen (POI, screen px) and the covariance of the
viewing direction (deg², docs/contract.md). The terrain lives in scene units
and is placed in the world by a 4x4 model matrix (scene → world mm).

Every criterion computes, for all base triangles at once, a *continuous*
level (for hysteresis) and returns integer levels in [0, max_level]:

- ``csf`` (Martinez et al.): eccentricity of the triangle from the POI seen
  from the eye, shifted toward the POI by the uncertainty (by default so
  that the 2σ ellipse around the POI gets full detail; or by eq. 1, with the
  sign the paper's print dropped), angular speed relative to the head
  (floored at 0.1 deg/s), contrast of the shaded terrain over the triangle;
  the CSF inverted for the highest visible frequency; LOD = ⌈log2(α_max/α)⌉.
- ``hybrid`` (the default): ``sse``'s level mixed with ``change``'s, whose
  visibility is expected over where the viewer may look: the gaze
  distribution, the tracker's covariance of V plus the eye-in-head prior,
  taken at Gauss–Hermite nodes (:func:`headplod.plod.criteria.hybrid_level`);
  ``change_share`` 0 is ``sse``.
- ``change``: whether what each level removes is visible: the shading it
  changes and the displacement of the surface, against the CSF scaled by
  cortical magnification (:func:`headplod.plod.criteria.change_level`).
- ``gp``: the same as ``csf`` with the Geisler–Perry cutoff.
- ``acuity``: Ohshima et al.'s k1·k2·k3 acuity and eq. 6.
- ``sse``: screen-space geometric error with Wakatsuki's micro-motion
  tolerance; ``ipv`` and ``dpv`` their velocity baselines on top of it.
- ``distance``: classic LOD by distance; ``full``: everything at max_level.

Every rule is written once in :mod:`headplod.plod.criteria` (the tessellation
back end's patches and the hierarchies' bounds use the same); the frustum
culling is :func:`headplod.plod.cull.outside_screen`.

Every setting of the selection is a field of :class:`SelectorConfig` (key,
unit, default, allowed range); :class:`LevelSelector` takes one.

:class:`LevelSelector` evaluates every base triangle on every frame; the
bench's :class:`headplod.bench.quadtree_selector.QuadtreeSelector` gives the
same levels walking a quadtree of the base grid, through the same
per-triangle criterion (``LevelSelector._criterion``) and hysteresis rule.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from . import criteria, cull
from .csf import CORTICAL_EXPONENT, display_nyquist_cpd
from . import perception as pc
from .view import UNCERTAINTY_MODES, ConditionedView, UncertaintyPolicy, View, require_conditioned  # noqa: F401
from ..tol import tol

MODES = ("hybrid", "change", "csf", "gp", "acuity", "sse", "ipv", "dpv", "distance", "full")
"""The level-selection criteria (:attr:`SelectorConfig.mode`), in the order the tools list them."""
#: Each CSF-based mode's own CSF model (:attr:`SelectorConfig.csf_model` None): the paper's for ``csf``, the
#: detection model for ``change``.
DEFAULT_CSF_MODEL = {"csf": "kelly_scaled", "change": "cortical", "hybrid": "cortical"}
#: Each mode's own k of the CSF model ``cortical`` (:attr:`SelectorConfig.cortical_exponent` None; the others
#: :data:`headplod.plod.csf.CORTICAL_EXPONENT`): ``hybrid``'s fitted at the true gaze (tools/fit_plod_gaze.py).
DEFAULT_CORTICAL_EXPONENT = {"hybrid": 1.2}
#: The modes that weigh every place the viewer may look (the gaze distribution), not the eccentricity shifted
#: by its σ: their default eye-in-head prior is :data:`GAZE_PRIOR_DEG`.
GAZE_DISTRIBUTION_MODES = criteria.GAZE_DISTRIBUTION_MODES
#: The σ of the eyes' offset in the head while a viewer looks about a desk screen, (horizontal, vertical) deg:
#: the viewer model's (``synthetic/gaze.py``; docs/viewer-model.md gives the sources).
GAZE_PRIOR_DEG = (10.7, 6.3)
#: The largest σ of the prior accepted, deg: beyond it the eyes would leave their orbit's range.
MAX_GAZE_PRIOR_DEG = 45.0


@dataclass(frozen=True)
class SelectorConfig:
    """Level-selection settings, each with its unit.

    Attributes
    ----------
    mode : one of MODES
        The criterion (module notes); default ``"hybrid"``, the one the
        judge prefers at the true gaze (``headplod bench plod --only gaze``,
        docs/plod-gaze.md; ``csf`` is the paper's).
    uncertainty : one of UNCERTAINTY_MODES
        Which covariance of the viewing direction the selection uses
        (:class:`UncertaintyPolicy`); default ``"adaptive"``.
    uncertainty_smoothing_frames : float
        Time constant of the ``"smoothed"`` covariance, frames (15): each
        frame's covariance enters with weight 1/15. At least 1.
    shift : one of perception.SHIFT_FORMS
        How the uncertainty moves eccentricities toward the POI: ``"ellipse"``
        (default: the ``ellipse_sigma`` ellipse is at zero eccentricity, so
        its triangles get full detail) or ``"eq1"`` (Martinez eq. 1,
        corrected; see :func:`perception.uncertainty_shift` for why it falls
        short of that).
    ellipse_sigma : float
        Size of that ellipse, standard deviations (2.0); ``"ellipse"`` only.
    csf_model : one of perception.CSF_MODELS, or None
        The CSF of modes ``"csf"``, ``"change"`` and ``"hybrid"`` (the other
        modes have no CSF form to choose and ignore it); None (the default)
        takes the mode's own: ``"kelly_scaled"`` for ``csf`` (the paper's
        reproduction), ``"cortical"`` for ``change`` and ``hybrid``.
    cortical_exponent : float or None
        k of the CSF model ``"cortical"``: frequencies scale with
        eccentricity as (1 + e / 3.67)^k (:mod:`headplod.plod.csf`); None
        (the default) takes the mode's own (:attr:`cortical`,
        :data:`DEFAULT_CORTICAL_EXPONENT`): 1.2 for ``hybrid`` (fitted with the
        judge at the true gaze, ``tools/fit_plod_gaze.py``), 0.9 for the
        others (``change``'s, fitted with the judge at the POI on the bench's
        default view).
    silhouette_contrast : float
        Mode ``change``: the Michelson contrast of a silhouette against
        what lies behind it, against which a level's displacement of a
        piece seen edge-on is judged (0.5; elsewhere the piece's own
        shading contrast).
    change_threshold : float
        Mode ``change``: how many times its detection threshold a change's
        contrast must be to count as visible (8.0, fitted with the judge on
        the bench's default view, ``headplod bench plod --vdp``: Kelly's CSF
        is that of a stabilized grating, far keener than the judge at a
        change in a textured image).
    gaze_prior_deg : (float, float) or None
        σ of the eyes' offset in the head, horizontal and vertical, deg: the
        uncertainty of where the viewer looks that the head's pose cannot
        tell, added to the tracker's covariance of V (:func:`view.gaze_covariance`).
        ``(0, 0)``: the paper's head-only view. None (the default) takes the
        mode's own (:attr:`gaze_prior`): :data:`GAZE_PRIOR_DEG` for the modes
        that weigh the whole gaze distribution (:data:`GAZE_DISTRIBUTION_MODES`),
        ``(0, 0)`` for the others, whose 2σ ellipse would take a disc of tens of
        degrees as the fovea.
    change_share : float
        Mode ``hybrid``: the share of ``change``'s level (what a level removes as
        the viewer would see it, expected over the gaze distribution) in its
        mix with ``sse``'s (the geometric error in pixels), 0..1 (0 is ``sse``;
        :func:`criteria.hybrid_level`); 0.45, fitted with the judge at the true
        gaze (``tools/fit_plod_gaze.py``, docs/plod-gaze.md).
    gaze_nodes_per_axis : int
        Mode ``hybrid``: Gauss–Hermite nodes per principal axis of the gaze
        distribution over which the change's visibility is averaged (3: 9 nodes).
    level_bias : float
        Added to every continuous level before rounding, levels (0.0): the one
        knob that trades triangles for image error in every mode alike, for
        the quality curves of ``headplod bench plod``.
    budget_triangles : int or None
        A triangle budget (None: none). Each frame, one more bias is added to
        the continuous levels of the triangles in view, found by bisection so
        that the frame's triangles meet the budget within
        ``budget_tolerance``: every mode is then compared at equal cost. Needs
        the selector's ``triangle_count`` (the mesh's).
    budget_tolerance : float
        How close the budget is met, a fraction of it (0.03); the bias stops
        changing once the count is within it.
    sse_tolerance_px : float
        Largest screen-space geometric error of modes ``sse``, ``ipv`` and
        ``dpv``, px (1.0; :func:`perception.sse_level`).
    frame_s : float
        Frame time Δt of Wakatsuki's micro-motion tolerance (mode ``sse``),
        s (1/60): the movement within one frame is unrecognizable.
    velocity_ref_deg_s : float
        v_ref of the velocity baselines ``ipv`` and ``dpv``, deg/s (10.0;
        :func:`perception.velocity_baseline_level`).
    distance_ref_mm : float
        Mode ``distance``: the eye distance that gets the finest level, mm
        (700.0); one level coarser per doubling beyond it.
    hysteresis : bool
        Keep a triangle's level while its continuous level stays within
        ``hysteresis_margin`` of the level's interval (True).
    hysteresis_margin : float
        That dead band, levels (0.35; :class:`perception.Hysteresis`).
    hysteresis_eager_deg : float
        While the POI moves (``hysteresis_eager_deg_s``), a triangle within
        this eccentricity (after the uncertainty shift) refines as soon as
        its continuous level asks and the band holds only its coarsening,
        deg (5.0, the disc the quality is measured in): a symmetric band
        held triangles coarse near a POI moving in (less PSNR in the disc
        during a pursuit: see ``headplod bench paper``).
    hysteresis_eager_deg_s : float
        Angular speed of the smoothed POI seen from the eye above which it
        moves, deg/s (3.0; a still head's filtered noise is about 0.2).
        A still head keeps the symmetric band everywhere: refining at once
        would let noise refine a triangle on the boundary at any frame.
    smoothing_s : float
        Time constant at rest of the One Euro filters on the eye and the POI,
        s (0.25): their minimum cutoff is 1 / (2π · smoothing_s).
    eye_beta : float
        Cutoff increase of the eye's filter per unit of its speed,
        Hz per mm/s (0.05; :class:`headplod.filters.OneEuroFilter`).
    poi_beta : float
        The same for the POI's filter, Hz per px/s (0.02).
    jump_eye_mm : float
        An eye movement from one frame to the next larger than this is a
        real movement, not noise: the filters and the hysteresis restart, mm
        (20.0).
    jump_poi_px : float
        The same for the POI, screen px (30.0); raised to ``jump_poi_sigma``
        of the tracker's σ of V on the screen when that is larger.
    jump_poi_sigma : float
        That multiple of the noise of the POI's prediction (√6 σ of V: see
        ``ViewConditioner._filter``), standard deviations (5.0).
    saccade_hold_deg_s : float
        Speed of the raw POI's direction seen from the eye above which the
        frame step keeps the last levels, deg/s (180: a saccade, during
        which vision is suppressed; :class:`headplod.plod.view.ConditionedView`).
    cull_margin_edges : float
        Frustum culling: a base triangle whose centroid projects farther
        outside the screen than this many of its level-0 edge lengths is
        culled (level 0, criterion not evaluated), level-0 edges (1.5).
    """

    mode: str = "hybrid"
    uncertainty: str = "adaptive"
    uncertainty_smoothing_frames: float = 15
    shift: str = "ellipse"
    ellipse_sigma: float = 2.0
    csf_model: str | None = None
    cortical_exponent: float | None = None
    silhouette_contrast: float = 0.5
    change_threshold: float = 8.0
    gaze_prior_deg: tuple[float, float] | None = None
    change_share: float = 0.45
    gaze_nodes_per_axis: int = criteria.GAZE_NODES_PER_AXIS
    level_bias: float = 0.0
    budget_triangles: int | None = None
    budget_tolerance: float = 0.03
    sse_tolerance_px: float = 1.0
    frame_s: float = 1 / 60
    velocity_ref_deg_s: float = 10.0
    distance_ref_mm: float = 700.0
    hysteresis: bool = True
    hysteresis_margin: float = 0.35
    hysteresis_eager_deg: float = 5.0
    hysteresis_eager_deg_s: float = 3.0
    smoothing_s: float = 0.25
    eye_beta: float = 0.05
    poi_beta: float = 0.02
    jump_eye_mm: float = 20.0
    jump_poi_px: float = 30.0
    jump_poi_sigma: float = 5.0
    saccade_hold_deg_s: float = 180.0
    cull_margin_edges: float = 1.5

    def __post_init__(self):
        for name, choices in (("mode", MODES), ("uncertainty", UNCERTAINTY_MODES), ("shift", pc.SHIFT_FORMS),
                              ("csf_model", pc.CSF_MODELS + (None,))):
            if getattr(self, name) not in choices:
                raise ValueError(f"SelectorConfig.{name} must be one of {choices}, got {getattr(self, name)!r}")
        budget = self.budget_triangles
        if budget is not None and not (isinstance(budget, numbers.Integral) and not isinstance(budget, bool)
                                       and budget >= 1):
            raise ValueError(f"SelectorConfig.budget_triangles must be a whole number of triangles >= 1 or None, "
                             f"got {budget!r}")
        prior = self.gaze_prior_deg
        if prior is not None:
            try:
                ok = (len(prior) == 2 and all(isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))
                                              and math.isfinite(v) and 0 <= v <= MAX_GAZE_PRIOR_DEG for v in prior))
            except TypeError:
                ok = False
            if not ok:
                raise ValueError(f"SelectorConfig.gaze_prior_deg must be two σ in 0..{MAX_GAZE_PRIOR_DEG:g} deg "
                                 f"(horizontal, vertical) or None, got {prior!r}")
        if not isinstance(self.hysteresis, (bool, np.bool_)):
            raise ValueError(f"SelectorConfig.hysteresis must be True or False, got {self.hysteresis!r}")
        # (field, lower bound, bound allowed, unit)
        for name, low, closed, unit in (
                ("uncertainty_smoothing_frames", 1.0, True, "frames"), ("ellipse_sigma", 0.0, True, "sigma"),
                ("silhouette_contrast", 0.0, False, "Michelson"),
                ("change_threshold", 0.0, False, "thresholds"), ("change_share", 0.0, True, "fraction"),
                ("level_bias", -math.inf, False, "levels"), ("sse_tolerance_px", 0.0, True, "px"),
                ("frame_s", 0.0, False, "s"), ("velocity_ref_deg_s", 0.0, False, "deg/s"),
                ("distance_ref_mm", 0.0, False, "mm"), ("hysteresis_margin", 0.0, True, "levels"),
                ("hysteresis_eager_deg", 0.0, True, "deg"), ("hysteresis_eager_deg_s", 0.0, True, "deg/s"),
                ("smoothing_s", 0.0, False, "s"), ("eye_beta", 0.0, True, "Hz per mm/s"),
                ("poi_beta", 0.0, True, "Hz per px/s"), ("jump_eye_mm", 0.0, False, "mm"),
                ("jump_poi_px", 0.0, False, "px"), ("jump_poi_sigma", 0.0, True, "sigma"),
                ("saccade_hold_deg_s", 0.0, False, "deg/s"), ("budget_tolerance", 0.0, False, "fraction"),
                ("cull_margin_edges", 0.0, True, "level-0 edges")):
            value = getattr(self, name)
            ok = (isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
                  and math.isfinite(value) and (value >= low if closed else value > low))
            if not ok:
                bound = ("any finite number" if low == -math.inf
                         else f"a finite number {'>=' if closed else '>'} {low:g}")
                raise ValueError(f"SelectorConfig.{name} must be {bound} ({unit}), got {value!r}")
        k = self.cortical_exponent
        if k is not None and not (isinstance(k, numbers.Real) and not isinstance(k, (bool, np.bool_))
                                  and math.isfinite(k) and k > 0):
            raise ValueError(f"SelectorConfig.cortical_exponent must be a finite number > 0 (dimensionless) or None, "
                             f"got {k!r}")
        if self.change_share > 1:
            raise ValueError(f"SelectorConfig.change_share must be in 0..1 (fraction), got {self.change_share!r}")
        nodes = self.gaze_nodes_per_axis
        if not (isinstance(nodes, numbers.Integral) and not isinstance(nodes, bool) and 1 <= nodes <= 9):
            raise ValueError(f"SelectorConfig.gaze_nodes_per_axis must be a whole number in 1..9, got {nodes!r}")
        if self.budget_tolerance >= 0.5:
            raise ValueError(f"SelectorConfig.budget_tolerance must be below 0.5 (fraction), "
                             f"got {self.budget_tolerance!r}")

    @property
    def gaze_prior(self) -> tuple[float, float]:
        """The eye-in-head prior in use, (horizontal, vertical) σ deg: ``gaze_prior_deg``, else the mode's own."""
        if self.gaze_prior_deg is not None:
            return (float(self.gaze_prior_deg[0]), float(self.gaze_prior_deg[1]))
        return GAZE_PRIOR_DEG if self.mode in GAZE_DISTRIBUTION_MODES else (0.0, 0.0)

    @property
    def cortical(self) -> float:
        """k of the CSF model ``"cortical"`` in use: ``cortical_exponent``, else the mode's own."""
        if self.cortical_exponent is not None:
            return float(self.cortical_exponent)
        return DEFAULT_CORTICAL_EXPONENT.get(self.mode, CORTICAL_EXPONENT)

    @property
    def csf(self) -> str:
        """The CSF model in use: ``csf_model`` for a CSF-based mode, else the mode's own (:data:`DEFAULT_CSF_MODEL`)."""
        if self.csf_model is not None and self.mode in DEFAULT_CSF_MODEL:
            return self.csf_model
        return DEFAULT_CSF_MODEL.get(self.mode, "kelly_scaled")


class LevelSelector:
    """Chooses a level per base triangle for a view.

    Parameters
    ----------
    centroids_scene : (F, 3)
        Base triangle centroids, scene units.
    edge_len_scene : (F, L+1)
        Longest edge of the triangle's pieces at each level, scene units.
    geometric_error_scene : (F, L+1)
        Largest distance of the level's surface from the finest, scene units.
    contrast : (F,)
        Michelson contrast of the shaded terrain over each triangle.
    model : (4, 4)
        Scene → world (mm) transform.
    screen : headplod.io.Screen
    config : SelectorConfig
        Every setting of the selection (the defaults: ``SelectorConfig()``).
    corners_scene : (F, 3, 3), optional
        The base triangles' corners, scene units. With them a triangle's
        angular size is the diameter of its projection seen from the eye
        (the largest angle between two corners: the paper's definition,
        foreshortening included); without, its longest edge seen face-on.
    triangle_count : callable (F,) int levels -> int, optional
        The mesh's triangle count of a selection (a budget needs it).
    change : (change_contrast (F, L+1), normal_axis (F, 3), normal_cone_deg (F,)), optional
        Mode ``change``'s features (the mesh's: :mod:`headplod.plod.change`): what each level removes from
        the shading, and the cone of each triangle's normals (scene frame; deg), which tells a silhouette.
    """

    def __init__(self, centroids_scene, edge_len_scene, geometric_error_scene, contrast, model, screen,
                 config: SelectorConfig = SelectorConfig(), *, corners_scene=None, triangle_count=None, change=None):
        if not isinstance(config, SelectorConfig):
            raise TypeError(f"LevelSelector: config must be a SelectorConfig, got {type(config).__name__}")
        if config.budget_triangles is not None and triangle_count is None:
            raise ValueError("LevelSelector: a triangle budget needs triangle_count (the mesh's)")
        if config.mode in criteria.CHANGE_MODES + criteria.GAZE_DISTRIBUTION_MODES and change is None:
            raise ValueError(f"LevelSelector: mode {config.mode!r} needs the mesh's change features (change=...)")
        self.config = config
        self.triangle_count = triangle_count
        self.max_level = edge_len_scene.shape[1] - 1
        model = np.asarray(model, dtype=np.float64)
        self.scale_mm = float(np.cbrt(abs(np.linalg.det(model[:3, :3]))))
        homog = np.concatenate([centroids_scene, np.ones((len(centroids_scene), 1))], axis=1)
        self.centroids_mm = (homog @ model.T)[:, :3]
        self.edge_len_mm = edge_len_scene * self.scale_mm
        self.error_mm = geometric_error_scene * self.scale_mm
        # Frustum culling's margin of each base triangle on the screen plane, mm: its level-0 size, generously.
        self.margin_mm = config.cull_margin_edges * self.edge_len_mm[:, 0]
        self.corners_mm = None
        if corners_scene is not None:
            corners = np.asarray(corners_scene, dtype=np.float64)
            homog = np.concatenate([corners, np.ones(corners.shape[:2] + (1,))], axis=2)
            self.corners_mm = (homog @ model.T)[..., :3]
            # A level's pieces are the level-0 triangle scaled by its edge ratio.
            self._level_scale = self.edge_len_mm / np.maximum(self.edge_len_mm[:, :1], tol.zero)
        self.contrast = np.asarray(contrast, dtype=np.float64)
        self.change_contrast = self.normal_axis_world = self.normal_cone_deg = None
        if change is not None:
            change_contrast, axis, cone = change
            self.change_contrast = np.asarray(change_contrast, dtype=np.float64)
            rotation = model[:3, :3] / self.scale_mm            # the model's rotation (its scale is uniform)
            self.normal_axis_world = criteria.unit(np.asarray(axis, dtype=np.float64) @ rotation.T)
            self.normal_cone_deg = np.asarray(cone, dtype=np.float64)
        self.screen = screen
        self.px_per_mm = screen.size_px[0] / float(np.linalg.norm(np.asarray(screen.top_right) - screen.top_left))
        # Eq. 4 and the screen-space error round up; Ohshima's eq. 6 takes the
        # finest level whose edges are long enough, which rounds down.
        self.rounding = "floor" if config.mode == "acuity" else "ceil"
        self.hysteresis = (pc.Hysteresis(len(centroids_scene), margin=config.hysteresis_margin,
                                         rounding=self.rounding) if config.hysteresis else None)
        self._previous = None          # (t, eye_mm, directions (F, 3))
        self._visibility = None        # mode change: the seen triangles' per-level visibility (S, L+1), last frame
        self._foveal_cache = None      # (contrast, seen, speed, foveal f_max) of the last frame

    def select(self, view: ConditionedView):
        """Levels (F,) int, and the continuous levels and per-triangle features used (dict).

        ``view``: the frame's :class:`ConditionedView`, from the frame step's
        :class:`headplod.plod.view.ViewConditioner` (the selector conditions
        nothing: a raw :class:`View` is refused with a TypeError).

        The features are NaN for base triangles outside the view (frustum-culled: level 0).
        ``full`` computes nothing: every base triangle at the finest level, features NaN.
        The dict also gives the view the levels were chosen for: ``poi_px``
        (2,) screen px, after the One Euro filter, and ``cov_deg2`` (2, 2)
        deg² or None, after the scenario's policy (not for ``full``).
        """
        require_conditioned(view, f"{type(self).__name__}.select")
        cfg = self.config
        if cfg.mode == "full":        # no criterion to evaluate (and no culling: the reference mesh)
            n = len(self.centroids_mm)
            nan = np.full(n, np.nan)
            return (np.full(n, self.max_level, dtype=np.int64),
                    {"eccentricity_deg": nan, "speed_deg_s": nan.copy(), "distance_mm": nan.copy(),
                     "continuous": np.full(n, float(self.max_level))})
        eye, cov = view.eye_mm, view.cov_deg2
        if view.restart and self.hysteresis is not None:
            self.hysteresis.reset()
        rel = self.centroids_mm - eye
        distance = np.linalg.norm(rel, axis=1)
        directions = rel / distance[:, None]
        # The modes that weigh the whole gaze distribution read it from its nodes, not from a shift.
        gaze = (criteria.gaze_nodes_deg(cov, cfg.gaze_nodes_per_axis) if cfg.mode in criteria.GAZE_DISTRIBUTION_MODES
                else None)
        shifted = criteria.shifted_offsets_deg(self.centroids_mm, eye, view.axes, cov if gaze is None else None,
                                               shift=cfg.shift, ellipse_sigma=cfg.ellipse_sigma)
        speed = self._angular_speed(view.t, eye, directions)
        # Frustum culling (the paper's renderer culled too): a base triangle
        # wholly outside the screen as seen from the eye gets the coarsest
        # level (GL clips it anyway), and the criterion is computed only for
        # the others.
        seen = np.flatnonzero(~self._outside_screen(eye))
        ecc = np.full(len(rel), np.nan)
        continuous = np.zeros(len(rel))
        if len(seen):
            ecc[seen], continuous[seen] = self._criterion(seen, eye, shifted[seen], distance[seen],
                                                          directions[seen], speed[seen], gaze)
        else:                                    # nothing in view (an eye far off to a side): all at level 0
            self._visibility = np.zeros((0, self.max_level + 1))
        budget_bias, budget_reach = 0.0, None
        if cfg.budget_triangles is not None:
            budget_bias, continuous[seen], budget_reach = self._budget_bias(continuous, seen, ecc[seen])
        if self.hysteresis is not None:
            levels = self.hysteresis.update(continuous, self.max_level, eager=self._eager(view, ecc))
        else:
            levels = pc.round_level(continuous, self.rounding, self.max_level)
        levels = np.clip(levels, 0, self.max_level).astype(np.int64)
        return levels, {"eccentricity_deg": ecc, "speed_deg_s": speed, "distance_mm": distance,
                        "continuous": continuous, "poi_px": view.poi_px, "cov_deg2": cov, "budget_bias": budget_bias,
                        "budget_reach": budget_reach}

    def _budget_bias(self, continuous, seen, ecc_seen):
        """The bias on the ``seen`` triangles that meets the triangle budget, their continuous levels
        (len(seen),) under it, and the counts a bias can reach at all: (coarsest, finest) triangles, every
        seen base triangle at level 0 or at the finest level (the others stay at 0).

        The bias is the level bias's own unit: levels, added to the continuous
        levels; for ``change``, doublings of the threshold (:func:`criteria.change_level`). The frame's
        triangles rise with it (every level rounds up or stays), so a
        bisection finds it, over the biases that take every seen triangle
        from level 0 to level L; it stops as soon as the count is within
        ``budget_tolerance`` of the budget, and otherwise keeps the closest
        count seen (a budget below the coarsest frame or above the finest
        cannot be met: the nearest end is taken).

        Where many triangles cross a level at the same bias (the geometric
        modes on even ground: equal errors at equal distances), no bias meets
        the budget; then, of the triangles between the two closest biases,
        those nearest the POI (``ecc_seen`` (len(seen),) deg) take the finer
        level, as many as meet it (a bisection over how many).
        """
        cfg, L = self.config, self.max_level
        budget = cfg.budget_triangles
        trial = np.zeros(len(continuous), dtype=np.int64)
        if cfg.mode in criteria.CHANGE_MODES:
            visibility = self._visibility + cfg.level_bias
            finite = visibility[:, :L][visibility[:, :L] > criteria.VISIBILITY_FLOOR]
            lo, hi = ((-float(finite.max()) - 1.0, 1.0 - float(finite.min())) if finite.size else (-1.0, 1.0))

            def levels_at(bias):
                return criteria.change_level(visibility, bias)
        else:
            base = continuous[seen]
            lo, hi = ((-(float(base.max()) + 1.0), L + 1.0 - float(base.min())) if len(seen) else (-1.0, 1.0))

            def levels_at(bias):
                return base + bias

        def count_levels(cont):
            trial[seen] = pc.round_level(cont, self.rounding, L)
            return self.triangle_count(np.clip(trial, 0, L))

        reach = (int(self.triangle_count(trial)), int(count_levels(np.full(len(seen), float(L)))))
        if len(seen) == 0:
            return 0.0, levels_at(0.0), reach
        best = (math.inf, 0.0)
        below = above = None                     # the closest biases under and over the budget
        for _ in range(40):                      # loop over bisection steps (each a vectorized count)
            mid = 0.5 * (lo + hi)
            n = count_levels(levels_at(mid))
            miss = abs(n - budget) / budget
            best = min(best, (miss, mid))
            if miss <= cfg.budget_tolerance:
                return mid, levels_at(mid), reach
            if n < budget:
                lo, below = mid, mid
            else:
                hi, above = mid, mid
        if below is None or above is None:
            return best[1], levels_at(best[1]), reach
        coarse, fine = levels_at(below), levels_at(above)
        rounded = pc.round_level(coarse, self.rounding, L) != pc.round_level(fine, self.rounding, L)
        ties = np.flatnonzero(rounded)[np.argsort(ecc_seen[rounded], kind="stable")]     # nearest the POI first
        k_lo, k_hi = 0, len(ties)
        chosen = (best[0], 0)
        while k_lo < k_hi:                       # loop over bisection steps on how many ties refine
            k = (k_lo + k_hi) // 2
            cont = coarse.copy()
            cont[ties[:k]] = fine[ties[:k]]
            n = count_levels(cont)
            chosen = min(chosen, (abs(n - budget) / budget, k))
            if n < budget:
                k_lo = k + 1
            else:
                k_hi = k
        cont = coarse.copy()
        cont[ties[:chosen[1]]] = fine[ties[:chosen[1]]]
        return below, cont, reach

    def _eager(self, view: ConditionedView, ecc):
        """(n,) bool for the hysteresis: triangles within ``hysteresis_eager_deg`` of a moving POI; None if still."""
        if not view.moving:
            return None
        with np.errstate(invalid="ignore"):      # NaN eccentricity: culled, not eager
            return ecc < self.config.hysteresis_eager_deg

    def _criterion(self, seen, eye, shifted, distance, directions, speed, gaze=None):
        """Eccentricities (S,) deg and continuous levels (S,) of the base triangles ``seen`` (S,) int.

        The per-triangle features and :func:`criteria.continuous_level`,
        shared by the flat selection and the hierarchical one
        (``headplod.bench.quadtree_selector``): ``shifted`` (S, 2) deg are
        their centroids' (φ, θ) after the uncertainty shift, ``distance``
        (S,) mm, ``directions`` (S, 3) unit vectors from the eye (3,) world
        mm to their centroids, ``speed`` (S,) deg/s, ``gaze`` the gaze distribution's nodes and weights
        (:func:`criteria.gaze_nodes_deg`; the modes of :data:`GAZE_DISTRIBUTION_MODES`, whose ``shifted``
        are then unshifted). The level bias is included.
        """
        if self.corners_mm is not None:
            angular_deg, reach_deg = criteria.triangle_sizes_deg(eye, directions, corners_mm=self.corners_mm[seen],
                                                                 level_scale=self._level_scale[seen])
        else:
            angular_deg, reach_deg = criteria.triangle_sizes_deg(eye, directions, edge_len_mm=self.edge_len_mm[seen],
                                                                 distance_mm=distance)
        # The triangle's nearest point to the POI, not its centroid, decides
        # what the eye can see of it: a large base triangle reaching into the
        # fovea must be refined there.
        ecc = criteria.piece_eccentricity_deg(shifted, reach_deg)
        change = {}
        cfg = self.config
        if cfg.mode in criteria.CHANGE_MODES + criteria.GAZE_DISTRIBUTION_MODES or cfg.csf == "cortical":
            change["nyquist_cpd"] = display_nyquist_cpd(self.px_per_mm, abs(float(
                np.dot(self.screen.normal, eye - np.asarray(self.screen.top_left, dtype=np.float64)))))
        if cfg.mode in criteria.CHANGE_MODES:
            # The per-level visibility is kept: a budget moves its threshold (_budget_bias).
            self._visibility = criteria.change_visibility_levels(
                self.change_contrast[seen], angular_deg, self.error_mm[seen], distance,
                self._displacement_contrast(seen, directions, reach_deg), speed, ecc, csf_model=cfg.csf,
                cortical_exponent=cfg.cortical, nyquist_cpd=change["nyquist_cpd"],
                threshold=cfg.change_threshold)
            return ecc, criteria.change_level(self._visibility, cfg.level_bias)
        if gaze is not None:
            sse = criteria.sse_continuous_level(self.error_mm[seen], distance, self.px_per_mm, speed, cfg)
            visibility = None
            if cfg.change_share > 0:
                visibility = criteria.expected_change_visibility(
                    self.change_contrast[seen], angular_deg, self.error_mm[seen], distance,
                    self._displacement_contrast(seen, directions, reach_deg), speed,
                    criteria.node_eccentricity_deg(shifted, reach_deg, gaze[0]), gaze[1], csf_model=cfg.csf,
                    cortical_exponent=cfg.cortical, nyquist_cpd=change["nyquist_cpd"],
                    threshold=cfg.change_threshold)
            return ecc, criteria.hybrid_level(sse, visibility, cfg.change_share) + cfg.level_bias
        continuous = criteria.continuous_level(
            self.config, self.max_level, ecc_deg=ecc, angular_deg=angular_deg, distance_mm=distance,
            speed_deg_s=speed, contrast=self.contrast[seen], edge_len_mm=self.edge_len_mm[seen],
            error_mm=self.error_mm[seen], px_per_mm=self.px_per_mm, foveal_cpd=self._foveal_fmax(seen, speed),
            **change)
        return ecc, continuous

    def _displacement_contrast(self, seen, directions, reach_deg):
        """(S,) the contrast a displacement of each triangle ``seen`` is seen against: at a silhouette (some
        normal in its cone is perpendicular to some ray from the eye to it) ``silhouette_contrast``, if
        larger; elsewhere its own shading contrast. ``directions`` (S, 3) unit, eye to centroid;
        ``reach_deg`` (S,) how far the rays to its corners stray from that."""
        to_eye = -directions
        angle = criteria.angle_between_deg(self.normal_axis_world[seen], to_eye)
        silhouette = np.abs(angle - 90.0) <= self.normal_cone_deg[seen] + reach_deg
        own = self.contrast[seen]
        return np.where(silhouette, np.maximum(own, self.config.silhouette_contrast), own)

    def _foveal_fmax(self, seen, speed):
        """``kelly_scaled``'s foveal f_max (S,) cpd of the triangles ``seen`` at ``speed``, or None for other modes.

        Eccentricity scales the frequency, f_max(C, v, e) = f_max(C, v, 0) / (1 + 0.29 e), and the
        foveal part (Lambert's W) changes only with the contrast and the speed: for a still head
        (speed at its floor) it is reused from the last frame.
        """
        cfg = self.config
        if cfg.mode != "csf" or cfg.csf != "kelly_scaled":
            return None
        cache = self._foveal_cache
        if (cache is None or cache[0] is not self.contrast or not np.array_equal(cache[1], seen)
                or not np.array_equal(cache[2], speed)):
            fmax0 = criteria.foveal_fmax_cpd(self.contrast[seen], speed, cfg.csf)
            self._foveal_cache = cache = (self.contrast, seen, speed, fmax0)
        return cache[3]

    def _outside_screen(self, eye, rows=None) -> np.ndarray:
        """(F,) bool (or (k,) for base triangles ``rows`` (k,) int): the centroid's ray from the eye misses the
        screen rectangle widened by the triangle's margin, or the centroid is behind the eye
        (:func:`cull.outside_screen`)."""
        rows = slice(None) if rows is None else rows
        return cull.outside_screen(self.centroids_mm[rows] - eye, self.margin_mm[rows],
                                   cull.screen_pyramid(self.screen, eye))

    def _angular_speed(self, t, eye, directions):
        """Angular speed (deg/s) of each triangle's direction from the eye since the last view, ≥ 0.1."""
        previous, self._previous = self._previous, (t, eye, directions)
        if previous is None or t is None or previous[0] is None or t <= previous[0]:
            return np.full(len(directions), pc.MIN_SPEED_DEG_S)
        return criteria.angular_speed_deg_s(directions, previous[2], t - previous[0])

    def reset(self):
        """Forget the last frame: the speeds and the hysteresis."""
        self._previous = None
        if self.hysteresis is not None:
            self.hysteresis.reset()
