"""headplod.bench.plod_judge: the display geometry, the fixation mapping and the comparison need only numpy;
the JOD tests need the optional extra ``.[vdp]`` and skip without it."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from headplod.bench import plod_judge as pj
from headplod.render.still import default_head, px_per_deg_at


def test_display_geometry_is_the_screens_size_at_the_heads_distance(default_screen):
    head = default_head(default_screen)
    d = pj.display_geometry(default_screen, head, (1280, 720))
    # calib/screen.yaml: a 24-inch 16:9 screen, 531.4 x 298.9 mm; the default head 600 mm from its centre.
    assert d.resolution_px == (1280, 720)
    assert d.width_m == pytest.approx(0.5314, abs=1e-4)
    assert d.height_m == pytest.approx(0.2989, abs=1e-4)
    assert d.distance_m == pytest.approx(0.600, abs=1e-9)
    assert math.hypot(d.width_m, d.height_m) / 0.0254 == pytest.approx(24.0, abs=0.01)
    assert d.horizontal_fov_deg == pytest.approx(2 * math.degrees(math.atan(0.2657 / 0.6)), abs=0.01)
    # The metrics' centre px/deg (one pixel's angle) against the project's (mm per degree): 0.01 % apart.
    assert d.px_per_deg == pytest.approx(px_per_deg_at(default_screen, head, (1280, 720)), rel=2e-4)
    # Twice as far: twice the pixels per degree, near enough at this size.
    far = pj.display_geometry(default_screen, default_head(default_screen, 1200.0), (1280, 720))
    assert far.distance_m == pytest.approx(1.2)
    assert far.px_per_deg == pytest.approx(2 * d.px_per_deg, rel=0.01)


def test_display_geometry_refuses_an_eye_off_the_centre_normal(default_screen):
    head = default_head(default_screen)
    right = np.asarray(default_screen.top_right) - default_screen.top_left
    right /= np.linalg.norm(right)
    pj.display_geometry(default_screen, head + 4.0 * right, (1280, 720))       # within 5 mm
    with pytest.raises(ValueError, match="off the screen centre's normal"):
        pj.display_geometry(default_screen, head + 50.0 * right, (1280, 720))
    with pytest.raises(ValueError, match="3-vector"):
        pj.display_geometry(default_screen, [1.0, 2.0], (1280, 720))
    with pytest.raises(ValueError, match="resolution_px"):
        pj.display_geometry(default_screen, head, (0, 720))


def test_fixation_is_the_poi_scaled_to_the_image_minus_half_a_pixel(default_screen):
    w, h = default_screen.size_px
    # The screen's centre is the image's centre: between pixels 639 and 640, 359 and 360.
    np.testing.assert_allclose(pj.fixation_px(default_screen, (w / 2, h / 2), (1280, 720)), [639.5, 359.5])
    # The top-left corner of the screen is the top-left corner of pixel (0, 0), half a pixel before its centre.
    np.testing.assert_allclose(pj.fixation_px(default_screen, (0, 0), (1280, 720)), [-0.5, -0.5])
    # Screen pixel (x, y) of 1920x1080 is image (x, y) * 2/3 at 1280x720.
    np.testing.assert_allclose(pj.fixation_px(default_screen, (300, 900), (1280, 720)), [199.5, 599.5])
    with pytest.raises(ValueError, match="poi_px"):
        pj.fixation_px(default_screen, (np.nan, 3), (1280, 720))


@pytest.mark.slow
def test_settings_refuse_bad_values():
    pj.JudgeSettings()
    for bad in ({"metric": "psnr"}, {"peak_luminance_cd_m2": 0}, {"contrast": -1}, {"ambient_lux": -5},
                {"reflectance": 1.0}, {"threads": 0}, {"threads": 1.5}):
        with pytest.raises(ValueError):
            pj.JudgeSettings(**bad)
    with pytest.raises(ValueError, match="unknown metric"):
        pj.vdp_available("ssim")
    assert isinstance(pj.vdp_available(), bool)


def test_judge_entries_are_every_mode_and_the_other_csf_forms():
    names = [n for n, _ in pj.judge_entries()]
    assert names[:9] == ["hybrid", "change", "csf", "gp", "acuity", "sse", "ipv", "dpv", "distance"]
    assert names[9:] == ["csf[paper]", "csf[kelly]", "csf[daly]", "csf[cortical]"]   # kelly_scaled is csf itself
    assert dict(pj.judge_entries(modes=[], forms=["daly"])) == {"csf[daly]": {"csf_model": "daly"}}
    with pytest.raises(ValueError, match="unknown mode"):
        pj.judge_entries(modes=["full"])
    with pytest.raises(ValueError, match="unknown CSF form"):
        pj.judge_entries(forms=["weber"])


def test_comparison_interpolates_the_best_geometric_curve_in_log_time():
    def curve(points):
        return [{"bias": b, "frame_ms": t, "jod_fvvdp": j} for b, t, j in points]

    curves = {"sse": curve([(-1, 10.0, 8.0), (0, 100.0, 9.0)]),
              "ipv": curve([(-1, 10.0, 7.0), (0, 40.0, 9.5)]),
              "csf": curve([(-1, 20.0, 9.6), (0, 200.0, 9.9)])}
    out = pj.compare_at_equal_time(curves)
    with pytest.raises(ValueError, match="x must be"):
        pj.compare_at_equal_time(curves, x="render_ms")
    assert list(out) == ["csf"]
    first, second = out["csf"]
    # At 20 ms: sse halfway (in log time, log 20 is 0.301 of the decade) 8.301; ipv half of its span 8.25.
    assert first["geometric_mode"] == "sse"
    assert first["geometric_jod"] == pytest.approx(8.0 + math.log10(2.0), abs=1e-9)
    assert first["margin"] == pytest.approx(9.6 - 8.0 - math.log10(2.0), abs=1e-9)
    assert second["margin"] is None and second["geometric_jod"] is None     # 200 ms: beyond every geometric curve


# --- with the optional extra -----------------------------------------------------------------------------------


def _scene(h=180, w=320):
    """A smooth sRGB test picture: gradients and a low-frequency grating, uint8 (h, w, 3)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = 0.5 + 0.25 * np.sin(2 * np.pi * xx / 40.0) * np.cos(2 * np.pi * yy / 50.0)
    img = np.stack([base, 0.8 * base + 0.1 * xx / w, 0.6 * base + 0.2 * yy / h], axis=-1)
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def small_display(default_screen):
    return pj.display_geometry(default_screen, default_head(default_screen), (320, 180))


@pytest.mark.slow
def test_fvvdp_is_foveated_on_the_fixation_point(small_display):
    if not pj.vdp_available("fvvdp"):
        pytest.skip("the optional extra .[vdp] (torch, pyfvvdp) is not installed")
    ref = _scene()
    test = ref.copy()
    rng = np.random.default_rng(3)
    patch = test[20:60, 30:70].astype(np.int16) + rng.integers(-40, 41, size=(40, 40, 3))
    test[20:60, 30:70] = np.clip(patch, 0, 255).astype(np.uint8)
    judge = pj.Judge(small_display)
    assert judge.foveated
    assert judge.jod(ref, ref, (159.5, 89.5)) == pytest.approx(10.0, abs=1e-3)
    on_patch = judge.jod(ref, test, (49.5, 39.5))
    far = judge.jod(ref, test, (300.0, 170.0))
    assert on_patch < 10.0 and far < 10.0
    # The same error is more visible where the viewer looks.
    assert on_patch < far - 0.05, (on_patch, far)
    assert judge.last_seconds > 0
    with pytest.raises(ValueError, match="uint8 sRGB of shape"):
        judge.jod(ref, ref[:, :-1], (0, 0))
    with pytest.raises(ValueError, match="heatmap=True"):
        judge.jod_map(ref, test, (49.5, 39.5))
    q, heatmap = pj.Judge(small_display, heatmap=True).jod_map(ref, test, (49.5, 39.5))
    assert q == pytest.approx(on_patch, abs=1e-4)
    assert heatmap.shape == (180, 320, 3) and heatmap.dtype == np.uint8
    # The threshold map is red where the error is visible (the patch) and blue where there is none.
    assert heatmap[30:50, 40:60, 0].mean() > heatmap[120:170, 200:300, 0].mean() + 50


@pytest.mark.slow
def test_cvvdp_scores_identical_images_10_and_ignores_fixation(small_display):
    if not pj.vdp_available("cvvdp"):
        pytest.skip("the optional extra .[vdp] (torch, cvvdp) is not installed")
    judge = pj.Judge(small_display, dataclasses.replace(pj.JudgeSettings(), metric="cvvdp"))
    assert not judge.foveated
    ref = _scene()
    test = ref.copy()
    test[20:60, 30:70] = 128
    assert judge.jod(ref, ref, (0, 0)) == pytest.approx(10.0, abs=1e-3)
    assert judge.jod(ref, test, (49.5, 39.5)) == pytest.approx(judge.jod(ref, test, (300.0, 170.0)), abs=1e-6)


def test_bench_plod_vdp_stops_before_the_run_without_the_extra(monkeypatch, capsys):
    from headplod.bench import plod
    from headplod.cli import main

    monkeypatch.setattr(pj, "vdp_available", lambda metric="fvvdp": False)
    monkeypatch.setattr(plod, "BenchScene", lambda *a, **k: pytest.fail("the bench ran"))
    assert main(["bench", "plod", "--vdp"]) == 2
    assert "pip install -e '.[vdp]'" in capsys.readouterr().err
    monkeypatch.setattr(pj, "vdp_available", lambda metric="fvvdp": True)
    assert main(["bench", "plod", "--vdp", "psnr"]) == 2


def test_the_judge_alone_refuses_a_missing_or_unknown_metric(monkeypatch, capsys):
    from headplod.bench import plod
    from headplod.cli import main

    monkeypatch.setattr(plod, "BenchScene", lambda *a, **k: pytest.fail("the bench ran"))
    monkeypatch.setattr(pj, "vdp_available", lambda metric="fvvdp": False)
    assert main(["bench", "plod", "--only", "judge"]) == 2
    assert "pip install -e '.[vdp]'" in capsys.readouterr().err
    monkeypatch.setattr(pj, "vdp_available", lambda metric="fvvdp": True)
    assert main(["bench", "plod", "--only", "judge", "--vdp", "psnr"]) == 2


@pytest.mark.slow
def test_ray_mask_points_have_no_triangles_and_are_compared_by_time_only(tmp_path):
    def pt(setting, tris, ms, jod, bias=0.0):
        return {"bias": bias, "setting": setting, "triangles": tris, "frame_ms": ms, "jod_fvvdp": jod}

    curves = {"sse": [pt("bias -1", 1e4, 10.0, 8.0, -1.0), pt("bias +0", 1e5, 100.0, 9.0)],
              "raymask": [pt("C=1", None, 20.0, 9.5, float("nan"))]}
    by_time = pj.compare_at_equal_time(curves, x="frame_ms")["raymask"][0]
    assert by_time["setting"] == "C=1" and by_time["margin"] == pytest.approx(9.5 - 8.0 - math.log10(2.0))
    assert pj.compare_at_equal_time(curves, x="triangles")["raymask"][0]["margin"] is None
    report = {"metrics": ["fvvdp"], "foveated": {"fvvdp": True}, "curves": curves, "px_per_deg": 25.2,
              "display": {"width_m": 0.53, "height_m": 0.3, "distance_m": 0.6}, "fixation_px": [639.5, 359.5],
              "full": {"frame_ms": 200.0, "triangles": 2e6}, "seconds": {"fvvdp": 1.0},
              "settings": {"peak_luminance_cd_m2": 200.0}, "off_fixation_deg": 10.0,
              "comparison": {"fvvdp": {x: pj.compare_at_equal_time(curves, x=x) for x in ("frame_ms", "triangles")}}}
    table = pj.jod_table(report)
    assert "raymask" in table and "rays" in table and "C=1: +" in table
    pj.jod_chart(report, tmp_path / "jod.png")
    assert (tmp_path / "jod.png").stat().st_size > 10000
