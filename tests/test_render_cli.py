"""`headplod render`: one PLOD frame end to end (levels, mesh, head-coupled render)."""
import json

import pytest

from calib import DEFAULT_SCREEN
from headplod.cli import main as cli_main
from headplod.io import read_screen

render = pytest.importorskip("headplod.render")


@pytest.fixture(scope="module")
def egl():
    try:
        render.create_context()
    except Exception as exc:           # no EGL / Mesa on this machine
        pytest.skip(f"offscreen OpenGL unavailable: {exc}")


def test_render_writes_image_and_stats(egl, tmp_path):
    out, stats = tmp_path / "csf.png", tmp_path / "csf.json"
    assert cli_main(["render", "--mode", "csf", "--view", "levels", "--size", "320,180", "--cov", "1,0,1",
                     "--out", str(out), "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    for key in ("triangles", "select_ms", "build_ms", "render_ms", "triangles_per_level"):
        assert key in s
    assert sum(s["triangles_per_level"]) == s["triangles"] > 2048
    assert out.stat().st_size > 1000


def test_csf_keeps_full_detail_at_the_poi_and_far_fewer_triangles(egl):
    from headplod.render.still import TerrainScene, render_still

    screen = read_screen(DEFAULT_SCREEN)
    scene = TerrainScene.build(screen)
    _, csf = render_still(screen, mode="csf", size=(320, 180), scene=scene)
    _, full = render_still(screen, mode="full", size=(320, 180), scene=scene)
    assert full["triangles"] >= 2_000_000
    assert csf["triangles"] < full["triangles"] / 5
    assert csf["triangles_per_level"][-1] > 0           # the finest level is used near the POI


def test_bad_cov_is_refused(tmp_path, capsys):
    assert cli_main(["render", "--cov", "1,2,1", "--out", str(tmp_path / "x.png")]) == 2
    assert "positive definite" in capsys.readouterr().err


def test_readback_contrast_variant_renders_and_reports_its_cost(egl, tmp_path):
    out, stats = tmp_path / "rb.png", tmp_path / "rb.json"
    assert cli_main(["render", "--mode", "csf", "--size", "320,180", "--contrast", "readback",
                     "--out", str(out), "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    assert s["contrast"] == "readback" and s["readback_ms"] > 0
    assert 2048 < s["triangles"] < 2_000_000
