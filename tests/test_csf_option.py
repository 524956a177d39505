"""The researcher's knobs on the command line (issue 25): ``--csf FORM`` for render and demo, and render
--compare's JOD where the vdp extra is installed."""
import json

import numpy as np
import pytest

from calib import DEFAULT_SCREEN
from headplod import cli, io
from headplod.plod.select import DEFAULT_CSF_MODEL, SelectorConfig
from headplod.render.command import compare_line
from headplod.render.frame import CAPABILITIES, options_problem
from headplod.render.vdp import vdp_available

SIZE = ["--size", "160,90"]


def _triangles(tmp_path, name, *extra):
    stats = tmp_path / f"{name}.json"
    assert cli.main(["render", *SIZE, "--mode", "csf", "--out", str(tmp_path / f"{name}.png"),
                     "--stats", str(stats), *extra]) == 0
    return json.loads(stats.read_text())["triangles"]


@pytest.mark.slow
def test_the_csf_form_changes_the_levels(tmp_path):
    """Daly's CSF sees less at the periphery than the scaled Kelly form the csf mode follows by default, so
    the same view needs fewer triangles; naming the default form gives the default's count exactly."""
    default = _triangles(tmp_path, "default")
    assert _triangles(tmp_path, "kelly_scaled", "--csf", DEFAULT_CSF_MODEL["csf"]) == default
    others = {form: _triangles(tmp_path, form, "--csf", form) for form in ("paper", "daly")}
    assert any(n != default for n in others.values()), (default, others)


def test_a_csf_form_only_where_it_means_something(tmp_path, capsys):
    out = tmp_path / "x.png"
    # a mode without a CSF
    assert cli.main(["render", *SIZE, "--mode", "sse", "--csf", "daly", "--out", str(out)]) == 2
    assert "--csf sets the CSF of the CSF-based modes" in capsys.readouterr().err
    # Geisler-Perry is the mesh's --mode gp, and the ray mask's form
    assert cli.main(["render", *SIZE, "--mode", "csf", "--csf", "gp", "--out", str(out)]) == 2
    assert "--mode gp" in capsys.readouterr().err
    # the GPU evaluates one form
    assert cli.main(["render", "--backend", "tessellation", "--csf", "daly", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--csf daly" in err and "kelly_scaled" in err
    assert not out.exists()
    assert options_problem("raymask", mode="csf", csf="gp") is None
    assert options_problem("raymask", mode="csf", csf="cortical") is None


def test_the_demo_takes_the_form_and_refuses_it_alike(tmp_path, capsys):
    assert cli.main(["demo", "--headless", "--mode", "sse", "--csf", "daly", "--frames", "1",
                     "--out", str(tmp_path / "d")]) == 2
    assert "--csf" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_a_mode_without_a_csf_ignores_the_form():
    """The demo switches modes live with one selector setting: a form set for csf must not change gp or sse."""
    for mode in ("gp", "sse", "full", "acuity"):
        assert SelectorConfig(mode=mode, csf_model="cortical").csf == SelectorConfig(mode=mode).csf
    assert SelectorConfig(mode="csf", csf_model="daly").csf == "daly"
    assert SelectorConfig(mode="change", csf_model="kelly").csf == "kelly"


def test_the_capability_table_lists_each_back_ends_forms():
    assert CAPABILITIES["tessellation"].csf_forms == ("kelly_scaled",)
    assert "gp" in CAPABILITIES["raymask"].csf_forms and "gp" not in CAPABILITIES["mesh"].csf_forms


def _images():
    rng = np.random.default_rng(0)
    reference = rng.integers(0, 256, (90, 160, 3), dtype=np.uint8)
    test = reference.copy()
    test[40:50, 70:90] = 0
    return reference, test


def test_compare_gives_the_jod_of_the_judge_fixated_at_the_poi():
    screen = io.read_screen(DEFAULT_SCREEN)
    reference, test = _images()
    seen = {}

    def judge(display, ref, img, fixation):
        seen.update(display=display, fixation=fixation)
        assert ref is reference and img is test
        return 8.75

    poi = (800.0, 300.0)
    line = compare_line(test, reference, screen, None, poi, (160, 90), judge=judge)
    assert "JOD 8.75" in line and "PSNR" in line and "FLIP" in line
    assert seen["display"].resolution_px == (160, 90)
    # the screen's poi in the 160 x 90 image, pixel centres at index + 0.5
    expected = np.array(poi) * np.array([160, 90]) / np.array(screen.size_px) - 0.5
    np.testing.assert_allclose(seen["fixation"], expected)


def test_compare_says_where_no_jod_can_be_had():
    screen = io.read_screen(DEFAULT_SCREEN)
    reference, test = _images()
    from headplod.plod.view import default_head

    off_axis = compare_line(test, reference, screen, default_head(screen) + np.array([200.0, 0.0, 0.0]), None,
                            (160, 90),
                            judge=lambda *a: pytest.fail("the judge must not run for an eye off the normal"))
    assert "no JOD" in off_axis and "off the screen centre's normal" in off_axis
    if not vdp_available("fvvdp"):
        assert "JOD needs the vdp extra" in compare_line(test, reference, screen, None, None, (160, 90))
