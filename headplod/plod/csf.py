"""Contrast sensitivity of the eye against spatial frequency, retinal speed and eccentricity.

The CSF forms the perceptual criteria use (:mod:`headplod.plod.perception`):
Kelly's spatio-velocity CSF (the paper's form, Kelly's own, Daly's
correction, and Kelly scaled to the paper's peak), two fall-offs with
eccentricity, and Geisler & Perry's cutoff (Murphy & Duchowski).

How frequency scales with eccentricity decides how much the periphery loses:

- ``kelly_scaled``: Rovamo & Virsu's 1 + 0.29 e, a *resolution* (acuity)
  law: at 20° every frequency is scaled by 6.8;
- ``cortical``: Dougherty et al.'s cortical magnification
  M(e) = 29.2 / (e + 3.67) mm/deg, raised to an exponent k, so frequencies
  scale by (1 + e / 3.67)^k (k = 0.6: 3.1 at 20°; the default k, fitted
  with the judge, is :data:`CORTICAL_EXPONENT`). Detecting a *change*
  (what a level removes) falls off more slowly than resolution; FovVideoVDP
  scales its CSF the same way. Capped at the display's Nyquist frequency
  where it sets a level (:func:`display_nyquist_cpd`). Units: frequency cpd, speed deg/s, eccentricity deg, contrast
Michelson. The equations and the papers' slips: docs/plod.md.
"""
from __future__ import annotations

import numpy as np
from scipy.special import lambertw

__all__ = ["CSF_MODELS", "FREQUENCY_SCALED_MODELS", "MIN_SPEED_DEG_S", "ECC_SLOPE", "CORTICAL_E2_DEG",
           "CORTICAL_EXPONENT", "display_nyquist_cpd", "KELLY_K0", "KELLY_K1", "KELLY_SPEED_REF_DEG_S",
           "KELLY_SPEED_OFFSET_DEG_S", "KELLY_PEAK_CONSTANT",
           "sensitivity", "csf_coefficients", "max_visible_freq_cpd", "gp_cutoff_cpd", "eccentricity_factor"]

CSF_MODELS = ("paper", "kelly", "daly", "kelly_scaled", "cortical")
#: The models whose eccentricity scales the frequency, S(f · m(e), v), rather than dividing the sensitivity.
FREQUENCY_SCALED_MODELS = ("kelly_scaled", "cortical")

MIN_SPEED_DEG_S = 0.1
"""Speed floor (deg/s) of every CSF: Kelly's G is 0 at v = 0 (no stabilized image)."""

ECC_SLOPE = 0.29
"""Rovamo & Virsu's cortical-magnification slope, 1/deg: M(e) ∝ 1 / (1 + 0.29 e)."""
CORTICAL_E2_DEG = 3.67
"""Dougherty et al. (2003)'s V1 magnification M(e) = 29.2 / (e + 3.67) mm/deg: the eccentricity, deg, where it
has halved (the model ``cortical``: frequencies scale by (1 + e / 3.67)^k)."""
CORTICAL_EXPONENT = 0.9
"""Default k of the model ``cortical`` (dimensionless). Detection thresholds follow cortical magnification raised
to a power below 1 (about 0.6 in FovVideoVDP's fit to gratings; 1 would be a resolution law); 0.9 is the value
the judge preferred for the ``change`` criterion on the bench's default view (docs/plod-criteria.md)."""

# Kelly (1979)'s spatio-velocity CSF, G = (K0 + K1 |log10(v / V_REF)|^3) v α² exp(-2 α (v + V_OFFSET) / PEAK),
# α = 2π f: the constants every Kelly form here (and the tessellation shader's copy of kelly_scaled,
# headplod.render.tess_shaders) is built from.
KELLY_K0 = 6.1
"""Kelly's constant term of the amplitude (dimensionless)."""
KELLY_K1 = 7.3
"""Kelly's coefficient of |log10(v / 3)|³ in the amplitude (dimensionless)."""
KELLY_SPEED_REF_DEG_S = 3.0
"""The speed where Kelly's amplitude term is smallest, deg/s (the 3 of log10(v / 3))."""
KELLY_SPEED_OFFSET_DEG_S = 2.0
"""Added to the speed in the decay, deg/s (the 2 of (v + 2))."""
KELLY_PEAK_CONSTANT = 45.9
"""The peak's angular frequency times (v + 2): α_max = 45.9 / (v + 2), α = 2π f in rad per degree."""

# Daly (1998) constants of the spatio-velocity CSF.
_DALY_C0, _DALY_C1, _DALY_C2 = 1.14, 0.67, 1.7


# ---------------------------------------------------------------------------
# Contrast sensitivity
# ---------------------------------------------------------------------------

def _check_model(model):
    if model not in CSF_MODELS:
        raise ValueError(f"unknown CSF model {model!r}; expected one of {CSF_MODELS}")


def csf_coefficients(speed_deg_s, model="kelly_scaled"):
    """The foveal CSF written as ``S(f) = A f^2 exp(-b f)`` (f in cpd).

    Parameters
    ----------
    speed_deg_s : array_like
        Retinal speed, deg/s, any shape; its absolute value is floored at
        :data:`MIN_SPEED_DEG_S` (0.1 deg/s).
    model : {"paper", "kelly", "daly", "kelly_scaled", "cortical"}
        ``"kelly"``, ``"kelly_scaled"`` and ``"cortical"`` share these coefficients (they
        differ only in how eccentricity enters).

    Returns
    -------
    A : ndarray
        Amplitude, cpd^-2, shape of ``speed_deg_s``.
    b : ndarray
        Decay, 1/cpd (deg per cycle), same shape.

    Notes
    -----
    - ``"paper"``, Martinez eq. 3 as printed:
      A = (250.1 + 299.3 |log10(v/3)|^3) v, b = 5.5 ln(10) (v + 2) / 45.9.
    - ``"kelly"``, Kelly (1979): G = (6.1 + 7.3 |log10(v/3)|^3) v (2πf)^2
      exp(-2 (2πf)(v + 2)/45.9), so A = 4π^2 (6.1 + 7.3 |log10(v/3)|^3) v,
      b = 4π (v + 2)/45.9. The paper's 250.1, 299.3 are 41 x (6.1, 7.3), with
      41.0 for 4π^2 = 39.48, and its 5.5 stands for 4π/ln 10 = 5.4575.
    - ``"daly"``, Daly (1998), c0 = 1.14, c1 = 0.67, c2 = 1.7:
      A = (6.1 + 7.3 |log10(c2 v/3)|^3) c0 c2 v (2π c1)^2,
      b = 4π c1 (c2 v + 2)/45.9.
    """
    _check_model(model)
    v = np.maximum(np.abs(np.asarray(speed_deg_s, dtype=float)), MIN_SPEED_DEG_S)
    if model == "paper":
        k = 250.1 + 299.3 * np.abs(np.log10(v / 3.0)) ** 3
        return k * v, 5.5 * np.log(10.0) * (v + 2.0) / 45.9
    if model == "daly":
        c0, c1, c2 = _DALY_C0, _DALY_C1, _DALY_C2
        k = KELLY_K0 + KELLY_K1 * np.abs(np.log10(c2 * v / KELLY_SPEED_REF_DEG_S)) ** 3
        return (k * c0 * c2 * v * (2.0 * np.pi * c1) ** 2,
                4.0 * np.pi * c1 * (c2 * v + KELLY_SPEED_OFFSET_DEG_S) / KELLY_PEAK_CONSTANT)
    k = KELLY_K0 + KELLY_K1 * np.abs(np.log10(v / KELLY_SPEED_REF_DEG_S)) ** 3
    return k * v * (2.0 * np.pi) ** 2, 4.0 * np.pi * (v + KELLY_SPEED_OFFSET_DEG_S) / KELLY_PEAK_CONSTANT


def eccentricity_factor(ecc_deg, model="kelly_scaled", cortical_exponent=CORTICAL_EXPONENT):
    """Fall-off with eccentricity m(e) >= 1 (dimensionless; e in deg, its absolute value used).

    ``"cortical"``: (1 + |e| / 3.67)^k, k = ``cortical_exponent``; every
    other model: Rovamo & Virsu's 1 + 0.29 |e|. The frequency-scaled models
    (:data:`FREQUENCY_SCALED_MODELS`) scale frequency by it, the others divide
    the sensitivity by it.
    """
    e = np.abs(np.asarray(ecc_deg, dtype=float))
    if model == "cortical":
        return (1.0 + e / CORTICAL_E2_DEG) ** float(cortical_exponent)
    return 1.0 + ECC_SLOPE * e


def display_nyquist_cpd(px_per_mm, eye_distance_mm):
    """The highest frequency a display can show, cpd: half its pixels per degree seen from ``eye_distance_mm``.

    ``px_per_mm`` (scalar) the screen's pixels per mm; ``eye_distance_mm`` (...,) the eye's distance to the
    screen plane, mm. Detail finer than this cannot be drawn, whatever the eye could see.
    """
    return 0.5 * float(px_per_mm) * np.asarray(eye_distance_mm, dtype=float) * np.pi / 180.0


def sensitivity(freq_cpd, speed_deg_s, ecc_deg, model="kelly_scaled", cortical_exponent=CORTICAL_EXPONENT):
    """Contrast sensitivity S(f, v, e) (1 / threshold contrast).

    Parameters
    ----------
    freq_cpd : array_like
        Spatial frequency f, cpd (>= 0).
    speed_deg_s : array_like
        Retinal speed v, deg/s; floored at 0.1 deg/s.
    ecc_deg : array_like
        Eccentricity e, deg (its absolute value is used).
    model : {"paper", "kelly", "daly", "kelly_scaled", "cortical"}
        ``"paper"``, ``"kelly"``, ``"daly"``: the foveal CSF (see
        :func:`csf_coefficients`) divided by (1 + 0.29 e), as Martinez eq. 3
        does. ``"kelly_scaled"``: Kelly's CSF with the frequency scaled by the
        cortical magnification, S(f (1 + 0.29 e), v), no division; this is
        how Rovamo & Virsu's 0.29 is meant, and it cuts the periphery far
        more (f_max falls as 1 / (1 + 0.29 e) instead of logarithmically).
        ``"cortical"``: Kelly's CSF at S(f (1 + e/3.67)^k, v) (module notes).
    cortical_exponent : float
        k of ``"cortical"`` (:data:`CORTICAL_EXPONENT`).

    Returns
    -------
    ndarray
        Sensitivity, dimensionless, the broadcast shape of the inputs.
    """
    _check_model(model)
    f = np.asarray(freq_cpd, dtype=float)
    A, b = csf_coefficients(speed_deg_s, model)
    m = eccentricity_factor(ecc_deg, model, cortical_exponent)
    if model in FREQUENCY_SCALED_MODELS:
        fs = f * m
        return A * fs ** 2 * np.exp(-b * fs)
    return A * f ** 2 * np.exp(-b * f) / m


def max_visible_freq_cpd(contrast, speed_deg_s, ecc_deg, model="kelly_scaled", cortical_exponent=CORTICAL_EXPONENT):
    """Highest spatial frequency visible at a contrast: max f with C S(f) >= 1.

    With S = A f^2 exp(-b f) (eccentricity folded into A or f), C S(f) = 1 is
    solved in closed form by the lower branch of Lambert's W:
    ``f_max = -(2/b) W_{-1}(-(b/2) / sqrt(A C))``. When
    (b/2)/sqrt(A C) > 1/e the peak of C S(f) is below 1 and nothing is
    visible: 0 is returned (also for C <= 0).

    Parameters
    ----------
    contrast : array_like
        Michelson contrast C (dimensionless).
    speed_deg_s : array_like
        Retinal speed v, deg/s (floored at 0.1 deg/s).
    ecc_deg : array_like
        Eccentricity e, deg.
    model : {"paper", "kelly", "daly", "kelly_scaled", "cortical"}
        See :func:`sensitivity`. For ``"kelly_scaled"`` the foveal f_max is
        divided by (1 + 0.29 e), for ``"cortical"`` by (1 + e/3.67)^k.
    cortical_exponent : float
        k of ``"cortical"``.

    Returns
    -------
    ndarray
        f_max, cpd, the broadcast shape of the inputs; 0 where nothing is
        visible. For Kelly at C = 1: 18.1 cpd at 0.15 deg/s, 13.1 at 1,
        3.1 at 10 (Kelly's foveal cutoff is below real acuity, 40-60 cpd).
    """
    _check_model(model)
    C = np.asarray(contrast, dtype=float)
    A, b = csf_coefficients(speed_deg_s, model)
    m = eccentricity_factor(ecc_deg, model, cortical_exponent)
    C, A, b, m = np.broadcast_arrays(C, A, b, m)
    if model not in FREQUENCY_SCALED_MODELS:
        A = A / m
    AC = A * C
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(AC > 0, 0.5 * b / np.sqrt(np.where(AC > 0, AC, 1.0)), np.inf)
    visible = z <= np.exp(-1.0)
    zv = np.where(visible, z, 0.1)            # any point inside the domain
    w = lambertw(-zv, -1).real                # <= -1
    f = np.where(visible, -2.0 / b * w, 0.0)
    if model in FREQUENCY_SCALED_MODELS:
        f = f / m
    return f


def gp_cutoff_cpd(contrast, ecc_deg, ct0=1.0 / 64.0, alpha=0.106, e2=2.3):
    """Geisler-Perry cutoff frequency (Murphy et al. 2009, eq. 1-2).

    From CT(f, e) = CT0 exp(α f (e + e2)/e2) = C:
    ``f_c = e2 ln(C / CT0) / (α (e + e2))``.

    Parameters
    ----------
    contrast : array_like
        Contrast C (dimensionless); C = 1 gives the usual resolution map.
    ecc_deg : array_like
        Eccentricity e, deg (absolute value used).
    ct0 : float
        Minimum contrast threshold (1/64).
    alpha : float
        Spatial-frequency decay constant, deg per cycle (0.106).
    e2 : float
        Half-resolution eccentricity, deg (2.3).

    Returns
    -------
    ndarray
        f_c, cpd; 39.2 cpd at the fovea for C = 1; 0 where C <= CT0.
    """
    C = np.asarray(contrast, dtype=float)
    e = np.abs(np.asarray(ecc_deg, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        lr = np.log(np.where(C > ct0, C, ct0) / ct0)
    return np.where(C > ct0, e2 * lr / (alpha * (e + e2)), 0.0)
