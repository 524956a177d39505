"""Tests of the per-triangle perceptual criteria (headplod.plod.perception)."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from headplod.plod import perception as p

RNG = np.random.default_rng(1234)


# ---------------------------------------------------------------------------
# CSF
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("model", p.CSF_MODELS)
def test_csf_inversion_round_trip(model):
    n = 4000
    C = 10 ** RNG.uniform(-2.5, 0, n)
    v = 10 ** RNG.uniform(-1.5, 2, n)          # includes speeds below the 0.1 floor
    e = RNG.uniform(0, 40, n)
    f = p.max_visible_freq_cpd(C, v, e, model=model)
    vis = f > 0
    assert vis.sum() > n // 4
    s = p.sensitivity(f[vis], v[vis], e[vis], model=model)
    np.testing.assert_allclose(s * C[vis], 1.0, rtol=1e-9)
    # it is the *highest* visible frequency: just above it C S < 1, just below >= 1
    up = p.sensitivity(f[vis] * (1 + 1e-4), v[vis], e[vis], model=model) * C[vis]
    dn = p.sensitivity(f[vis] * (1 - 1e-4), v[vis], e[vis], model=model) * C[vis]
    assert np.all(up < 1.0)
    assert np.all(dn >= 1.0 - 1e-9)
    # where nothing is visible, the CSF's peak (f = 2/b, scaled) is below threshold
    if (~vis).any():
        A, b = p.csf_coefficients(v[~vis], model)
        fpk = 2.0 / b
        if model == "kelly_scaled":
            fpk = fpk / (1 + 0.29 * e[~vis])
        assert np.all(p.sensitivity(fpk, v[~vis], e[~vis], model=model) * C[~vis] < 1.0)


@pytest.mark.parametrize("model", p.CSF_MODELS)
def test_nothing_visible_is_zero(model):
    assert p.max_visible_freq_cpd(1e-5, 1.0, 0.0, model=model) == 0.0
    assert p.max_visible_freq_cpd(0.0, 1.0, 0.0, model=model) == 0.0
    assert p.max_visible_freq_cpd(-0.5, 1.0, 0.0, model=model) == 0.0
    f = np.linspace(0.01, 60, 20001)
    assert np.max(p.sensitivity(f, 1.0, 0.0, model=model)) * 1e-5 < 1.0


def test_kelly_numbers_of_methods_md():
    f = p.max_visible_freq_cpd(1.0, [0.15, 1.0, 10.0], 0.0, model="kelly")
    np.testing.assert_allclose(f, [18.1, 13.1, 3.1], atol=0.1)
    # kelly_scaled is Kelly at the fovea
    np.testing.assert_allclose(p.max_visible_freq_cpd(1.0, [0.15, 1.0, 10.0], 0.0), f, rtol=1e-12)


def test_speed_floor():
    # Kelly's G is 0 at v = 0; the floor keeps the CSF alive and equal to v = 0.1
    np.testing.assert_allclose(p.sensitivity(5.0, 0.0, 0.0, model="kelly"),
                               p.sensitivity(5.0, 0.1, 0.0, model="kelly"))
    assert p.sensitivity(5.0, 0.0, 0.0, model="kelly") > 0


def test_paper_form_is_kelly_rounded():
    C = 10 ** RNG.uniform(-1.5, 0, 2000)
    v = 10 ** RNG.uniform(-1, 1.5, 2000)
    e = RNG.uniform(0, 30, 2000)
    fp = p.max_visible_freq_cpd(C, v, e, model="paper")
    fk = p.max_visible_freq_cpd(C, v, e, model="kelly")
    # away from the visibility limit (peak of C·S at least 2; next to it f_max
    # has a square-root sensitivity to any change of amplitude)
    A, b = p.csf_coefficients(v, "kelly")
    peak = C * p.sensitivity(2.0 / b, v, e, model="kelly")
    ok = peak >= 2.0
    assert ok.sum() > 1000 and np.all(fp[ok] > 0)
    rel = np.abs(fp[ok] / fk[ok] - 1)
    assert rel.max() < 0.03          # the rounding of 4π² and 4π/ln10 only
    assert rel.max() > 1e-3          # ... but they are not the same function
    # exactly: S_paper / S_kelly = (41/4π²) exp(-(5.5 ln10 - 4π) f (v+2)/45.9)
    f = RNG.uniform(0.1, 20, 50)
    vv = RNG.uniform(0.2, 20, 50)
    ratio = p.sensitivity(f, vv, 3.0, model="paper") / p.sensitivity(f, vv, 3.0, model="kelly")
    np.testing.assert_allclose(ratio, 41 / (4 * np.pi ** 2)
                               * np.exp(-(5.5 * np.log(10) - 4 * np.pi) * f * (vv + 2) / 45.9),
                               rtol=1e-3)   # 250.1 = 41·6.1, 299.3 = 41·7.3 (to 4 digits)
    # the sensitivities themselves differ by 41/4π² at low frequency
    np.testing.assert_allclose(p.sensitivity(1e-3, 3.0, 0.0, model="paper")
                               / p.sensitivity(1e-3, 3.0, 0.0, model="kelly"),
                               41.0 / (4 * np.pi ** 2), rtol=1e-3)


def test_kelly_scaled_cuts_periphery_far_more():
    f0p, f20p = p.max_visible_freq_cpd(1.0, 1.0, [0.0, 20.0], model="paper")
    f0s, f20s = p.max_visible_freq_cpd(1.0, 1.0, [0.0, 20.0], model="kelly_scaled")
    assert f20p / f0p > 0.6                     # division of S: a mild fall
    assert f20s / f0s < 0.2                     # scaling of f: 1/(1 + 0.29·20) = 0.147
    np.testing.assert_allclose(f20s / f0s, 1 / (1 + 0.29 * 20), rtol=1e-12)
    assert f20s < 0.3 * f20p


@pytest.mark.parametrize("model", p.CSF_MODELS)
def test_fmax_decreases_with_eccentricity_and_increases_with_contrast(model):
    e = np.linspace(0, 40, 41)
    f = p.max_visible_freq_cpd(0.5, 2.0, e, model=model)
    assert np.all(np.diff(f) <= 0) and f[-1] < f[0]
    C = np.linspace(0.05, 1, 20)
    f = p.max_visible_freq_cpd(C, 2.0, 5.0, model=model)
    assert np.all(np.diff(f) >= 0)


def test_unknown_model():
    with pytest.raises(ValueError):
        p.sensitivity(1.0, 1.0, 0.0, model="nope")


# ---------------------------------------------------------------------------
# Geisler-Perry
# ---------------------------------------------------------------------------

def test_gp_cutoff():
    assert p.gp_cutoff_cpd(1.0, 0.0) == pytest.approx(39.2, abs=0.05)
    f = p.gp_cutoff_cpd(1.0, np.linspace(0, 60, 61))
    assert np.all(np.diff(f) < 0)
    np.testing.assert_array_equal(p.gp_cutoff_cpd([1 / 64, 0.01, 0.0], 0.0), 0.0)
    # it inverts CT(f, e) = C
    C, e = 0.3, 7.0
    fc = p.gp_cutoff_cpd(C, e)
    assert (1 / 64) * np.exp(0.106 * fc * (e + 2.3) / 2.3) == pytest.approx(C, rel=1e-12)


# ---------------------------------------------------------------------------
# Martinez eq. 4
# ---------------------------------------------------------------------------

def test_lod_from_frequency():
    fmax = np.array([8.0, 9.0, 0.5, 0.0, 1e6, 1.0, np.nan])
    lv = p.lod_from_frequency(1.0, fmax, max_level=6)
    np.testing.assert_array_equal(lv, [3, 4, 0, 0, 6, 0, 0])
    assert lv.dtype.kind == "i"
    np.testing.assert_allclose(p.lod_continuous(1.0, [8.0, 2.0]), [3.0, 1.0])
    # frequency 0 (infinitely large triangle): finest level
    assert p.lod_from_frequency(0.0, 10.0, 5) == 5
    # one subdivision doubles the frequency: halving f adds one level
    f = 10 ** RNG.uniform(-1, 1, 100)
    a = p.lod_from_frequency(f, 30.0, 20)
    b = p.lod_from_frequency(f / 2, 30.0, 20)
    np.testing.assert_array_equal(b, a + 1)


def test_triangle_frequency():
    # a triangle 1000 mm away whose diameter subtends 2 atan(5/1000)
    tri = np.array([[[-5.0, 0, 1000], [5.0, 0, 1000], [0.0, 3.0, 1000]]])
    ang = np.degrees(2 * np.arctan(5 / 1000))
    np.testing.assert_allclose(p.triangle_frequency_cpd(tri, [0, 0, 0]), 1 / ang, rtol=1e-9)


def test_view_offsets_and_eccentricity():
    axes = np.eye(3)                                 # Ξ = x, Ψ = y, V = z
    pts = np.array([[100.0, 0, 1000], [0, -100.0, 1000], [100.0, 100.0, 1000]])
    off = p.view_offsets_deg(pts, [0, 0, 0], axes)
    a = np.degrees(np.arctan(0.1))
    np.testing.assert_allclose(off, [[0, a], [-a, 0], [a, a]], atol=1e-12)
    np.testing.assert_allclose(p.eccentricity_deg(off),
                               [a, a, np.degrees(np.arctan(np.hypot(0.1, 0.1)))], rtol=1e-12)


# ---------------------------------------------------------------------------
# Martinez eq. 1 corrected
# ---------------------------------------------------------------------------

COV = np.array([[0.04, 0.01], [0.01, 0.09]])


def test_shift_zero_at_poi_and_identity_far():
    assert np.all(p.uncertainty_shift(np.zeros(2), COV) == 0)
    # at Mahalanobis distance 10 in any direction the shift is negligible
    ang = RNG.uniform(0, 2 * np.pi, 200)
    u = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    m = np.sqrt(np.einsum("ni,ij,nj->n", u, np.linalg.inv(COV), u))
    P = u * (10 / m)[:, None]
    Pp = p.uncertainty_shift(P, COV)
    rel = np.linalg.norm(Pp - P, axis=1) / np.linalg.norm(P, axis=1)
    assert rel.max() < 1e-6
    # at one sigma it is (1 - e^-1/2), shifted toward the POI along P
    P1 = u * (1 / m)[:, None]
    np.testing.assert_allclose(p.uncertainty_shift(P1, COV), (1 - np.exp(-0.5)) * P1, rtol=1e-12)


def test_shift_printed_sign_would_flip():
    # the printed exponent (+PᵀΣ⁻¹P) gives a factor <= 0; the corrected one is in [0, 1)
    P = np.array([[0.3, -0.2], [2.0, 1.0]])
    q = np.einsum("ni,ij,nj->n", P, np.linalg.inv(COV), P)
    assert np.all(1 - np.exp(q) <= 0)
    f = np.linalg.norm(p.uncertainty_shift(P, COV), axis=1) / np.linalg.norm(P, axis=1)
    assert np.all((f > 0) & (f <= 1))


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 2 * np.pi), st.floats(0.01, 1.0), st.floats(0.01, 1.0), st.floats(-0.9, 0.9))
def test_shift_monotone_along_a_ray(ang, s1, s2, rho):
    cov = np.array([[s1 ** 2, rho * s1 * s2], [rho * s1 * s2, s2 ** 2]])
    t = np.linspace(0, 12 * max(s1, s2), 400)
    P = t[:, None] * np.array([np.cos(ang), np.sin(ang)])
    r = np.linalg.norm(p.uncertainty_shift(P, cov), axis=1)
    assert np.all(np.diff(r) > 0)
    assert np.all(r <= t + 1e-12)


def test_shift_no_uncertainty_is_identity():
    P = RNG.normal(size=(10, 2))
    np.testing.assert_array_equal(p.uncertainty_shift(P, None), P)
    np.testing.assert_array_equal(p.uncertainty_shift(P, np.zeros((2, 2))), P)
    # singular: uncertainty along φ only; a point off that axis is not shifted
    sing = np.array([[0.04, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(p.uncertainty_shift([0.1, 0.5], sing), [0.1, 0.5])
    np.testing.assert_allclose(p.uncertainty_shift([0.2, 0.0], sing), [0.2 * (1 - np.exp(-0.5)), 0])


# ---------------------------------------------------------------------------
# Ohshima: acuity
# ---------------------------------------------------------------------------

def test_acuity_factors():
    k1, k2, k3 = p.acuity_factors([0.0, 10.0, 3.0, 13.0], [0.0, 0.0, 5.0, 3.0],
                                  [0.0, 90.0, 180.0, 400.0], [0.0, 0.62, -0.62, 0.0])
    assert k1[1] == pytest.approx(0.2, abs=0.01)             # "about 0.2 at 10°"
    assert k1[0] == 1 and k1[2] == 1                          # inside the object's radius
    assert k1[3] == pytest.approx(k1[1])                      # θ - α counts
    np.testing.assert_allclose(k2, [1.0, 0.5, 0.0, 0.0])
    np.testing.assert_allclose(k3, [1.0, np.exp(-1), np.exp(-1), 1.0])


def test_display_acuity_a0_example():
    pitch = 7.85 / 5                                          # the pixel that makes 5 px = 7.85 mm
    a0 = p.display_acuity_a0(pitch, 1500.0)
    assert a0 == pytest.approx(3.3, abs=0.05)
    # eq. 6 inverts eq. 7: the smallest rendered detail at a = a0 is l
    assert p.r_min_mm(a0, 1500.0) == pytest.approx(7.85, rel=1e-9)
    assert p.r_min_mm(0.0, 1500.0) == np.inf


def _edge_table(n, L, base_mm):
    return base_mm[:, None] / 2.0 ** np.arange(L + 1)[None, :]


def test_acuity_levels():
    L, n = 6, 50
    base = np.full(n, 200.0)
    E = _edge_table(n, L, base)
    D = np.linspace(300, 20000, n)
    k = np.ones(n)
    a0 = p.display_acuity_a0(1.57, 1500.0)
    lv, cont = p.acuity_level(k, k, k, a0, D, E, return_continuous=True)
    assert np.all(np.diff(lv) <= 0) and lv[0] > lv[-1]         # coarser farther away
    np.testing.assert_array_equal(np.floor(cont).astype(int), lv)
    # chosen level: longest edge >= r_min, next finer one below it
    r = p.r_min_mm(a0, D)
    idx = np.arange(n)
    assert np.all((E[idx, lv] >= r) | (lv == 0))
    assert np.all((E[idx, np.minimum(lv + 1, L)] < r) | (lv == L))
    # peripheral triangles get coarser levels; eq. 5 is never finer than eq. 4
    k1, k2, k3 = p.acuity_factors(np.linspace(0, 40, n), 0.0, 60.0, 0.3)
    lmin = p.acuity_level(k1, k2, k3, a0, 1500.0, E, combine="min")
    lprod = p.acuity_level(k1, k2, k3, a0, 1500.0, E, combine="product")
    assert np.all(np.diff(lmin) <= 0) and lmin[0] > lmin[-1]
    assert np.all(lprod <= lmin) and np.any(lprod < lmin)
    # invisible (k2 = 0): coarsest
    assert np.all(p.acuity_level(k, np.zeros(n), k, a0, D, E) == 0)


def test_vergence_horopter():
    ipd = 63.0
    fix = np.array([0.0, 0.0, 800.0])
    # points on the Vieth-Müller circle through both eyes and the fixation point
    # (in the x-z plane) share the fixation point's vergence
    ex = ipd / 2
    zc = (fix[2] ** 2 - ex ** 2) / (2 * fix[2])               # circle centre (0, 0, zc)
    R = fix[2] - zc
    ang = np.radians(np.linspace(-30, 30, 7))
    pts = np.stack([R * np.sin(ang), np.zeros_like(ang), zc + R * np.cos(ang)], axis=1)
    psi = p.vergence_deg(pts, [0, 0, 0], ipd)
    psi0 = p.vergence_deg(fix[None], [0, 0, 0], ipd)
    np.testing.assert_allclose(psi, np.full(7, psi0[0]), rtol=1e-9)
    assert psi0[0] == pytest.approx(np.degrees(2 * np.arctan(ex / 800)), rel=1e-12)
    # nearer than the horopter: larger vergence
    assert p.vergence_deg([[0, 0, 400.0]], [0, 0, 0], ipd)[0] > psi0[0]


# ---------------------------------------------------------------------------
# Screen-space error and Wakatsuki
# ---------------------------------------------------------------------------

def test_sse_coarser_with_distance():
    n, L = 40, 7
    err = _edge_table(n, L, np.full(n, 40.0))                 # errors halve per level
    D = np.geomspace(300, 30000, n)
    lv, cont = p.sse_level(err, D, pixels_per_radian=1500.0, return_continuous=True)
    assert np.all(np.diff(lv) <= 0) and lv[0] > lv[-1]
    np.testing.assert_array_equal(np.ceil(cont).astype(int), lv)
    px = 1500.0 * err / D[:, None]
    idx = np.arange(n)
    assert np.all((px[idx, lv] <= 1.0) | (lv == L))
    assert np.all((px[idx, np.maximum(lv - 1, 0)] > 1.0) | (lv == 0))


def test_sse_micro_motion_reduces_levels():
    n, L = 30, 7
    err = _edge_table(n, L, np.full(n, 40.0))
    v = np.linspace(0, 60, n)                                 # deg/s
    lv_static = p.sse_level(err, 1000.0, 1500.0)
    lv = p.sse_level(err, np.full(n, 1000.0), 1500.0, speed_deg_s=v)
    assert np.all(lv_static == lv_static[0])
    assert lv[0] == lv_static[0]
    assert np.all(np.diff(lv) <= 0) and lv[-1] < lv[0]
    # a shorter frame tolerates less
    lv120 = p.sse_level(err, np.full(n, 1000.0), 1500.0, speed_deg_s=v, frame_s=1 / 120)
    assert np.all(lv120 >= lv) and np.any(lv120 > lv)


def test_velocity_baselines():
    base = np.full(6, 5)
    v = np.array([0.0, 5.0, 10.0, 30.0, 70.0, 1000.0])
    ipv = p.velocity_baseline_level(base, v, "ipv", v_ref=10.0, max_level=6)
    np.testing.assert_array_equal(ipv, [5, 5, 4, 3, 2, 0])    # never vanishes
    dpv = p.velocity_baseline_level(base, v, "dpv", v_ref=100.0, max_level=6)
    assert np.all(np.diff(dpv) <= 0)
    np.testing.assert_array_equal(dpv[[0, -1]], [5, -1])      # gone past v_ref
    assert p.velocity_baseline_level([3], [100.0], "dpv", v_ref=100.0)[0] == -1
    with pytest.raises(ValueError):
        p.velocity_baseline_level(base, v, "nope")


# ---------------------------------------------------------------------------
# Hysteresis
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("rounding", ["ceil", "floor", "round"])
def test_hysteresis_noise_does_not_flip(rounding):
    n, frames = 500, 60
    boundary = {"ceil": 2.0, "floor": 2.0, "round": 2.5}[rounding]
    rng = np.random.default_rng(7)
    h = p.Hysteresis(n, margin=0.35, rounding=rounding)
    plain = p.Hysteresis(n, margin=0.0, rounding=rounding)
    first = None
    flips_plain = 0
    prev_plain = None
    for k in range(frames):
        x = boundary + rng.uniform(-0.3, 0.3, n)
        lv = h.update(x, max_level=6)
        lp = plain.update(x, max_level=6)
        if first is None:
            first = lv
        np.testing.assert_array_equal(lv, first)
        if prev_plain is not None:
            flips_plain += int(np.sum(lp != prev_plain))
        prev_plain = lp
    assert flips_plain > n                       # without hysteresis it would flicker
    assert h.levels is not None


def test_hysteresis_follows_real_changes_at_once():
    n = 100
    h = p.Hysteresis(n, margin=0.35)
    x = np.full(n, 2.0) + np.linspace(-0.3, 0.3, n)
    lv0 = h.update(x, max_level=6)
    lv1 = h.update(x + 2.0, max_level=6)         # a head movement: two levels at once
    np.testing.assert_array_equal(lv1, p.lod_from_frequency(1.0, 2.0 ** (x + 2.0), 6))
    assert np.all(lv1 - lv0 >= 1)
    lv2 = h.update(x - 2.0, max_level=6)
    np.testing.assert_array_equal(lv2, np.clip(np.ceil(x - 2.0), 0, 6).astype(int))
    # clamped extremes and non-finite inputs
    h.update(np.full(n, 50.0), max_level=6)
    assert np.all(h.levels == 6)
    lv = h.update(np.full(n, np.nan), max_level=6)
    assert np.all(lv == 6)                        # NaN keeps the level
    lv = h.update(np.full(n, -np.inf), max_level=6)
    assert np.all(lv == 0)
    with pytest.raises(ValueError):
        h.update(np.zeros(n + 1), max_level=6)


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 2 * np.pi), st.floats(0.05, 3.0), st.floats(0.05, 3.0), st.floats(-0.9, 0.9))
def test_ellipse_shift_zero_inside_2_sigma_then_offset_less_2_sigma(ang, s1, s2, rho):
    cov = np.array([[s1 ** 2, rho * s1 * s2], [rho * s1 * s2, s2 ** 2]])
    u = np.array([np.cos(ang), np.sin(ang)])
    sigma_u = 1.0 / np.sqrt(u @ np.linalg.inv(cov) @ u)     # σ along u: the 1σ ellipse's radius there
    t = np.linspace(0, 12 * max(s1, s2), 400)
    r = np.linalg.norm(p.uncertainty_shift(t[:, None] * u, cov, form="ellipse"), axis=1)
    inside = t <= 2 * sigma_u
    assert np.all(r[inside] == 0)
    np.testing.assert_allclose(r[~inside], t[~inside] - 2 * sigma_u, atol=1e-9)
    # Never farther than eq. 1 puts it: the ellipse form is the more conservative.
    r_eq1 = np.linalg.norm(p.uncertainty_shift(t[:, None] * u, cov, form="eq1"), axis=1)
    assert np.all(r <= r_eq1 + 1e-12)


def test_unknown_shift_form():
    with pytest.raises(ValueError, match="form must be one of"):
        p.uncertainty_shift(np.ones((3, 2)), np.eye(2), form="eq2")


def test_eager_hysteresis_refines_at_once_and_coarsens_past_the_band():
    from headplod.plod.perception import Hysteresis

    h = Hysteresis(2, margin=0.35, rounding="ceil")
    assert h.update([2.9, 2.9], 5).tolist() == [3, 3]
    # Just past the level's interval (2, 3]: only the eager triangle refines.
    assert h.update([3.1, 3.1], 5, eager=[True, False]).tolist() == [4, 3]
    # Back down within the band below its new interval (3, 4]: both keep their levels.
    assert h.update([2.8, 2.8], 5, eager=[True, False]).tolist() == [4, 3]
    # Past the band: the eager one coarsens too.
    assert h.update([2.6, 2.6], 5, eager=[True, False]).tolist() == [3, 3]
