"""render --compare full compares like with like (issue 36, item 2): a levels or wire picture is not judged
against full's shaded one; the figures, and what was compared, go into --stats."""
import json

import pytest

from headplod import cli
from headplod.render import vdp

SMALL = ["render", "--size", "96,54", "--cov", "1,0,1", "--compare", "full"]


def _compare(tmp_path, capsys, view):
    stats = tmp_path / f"{view}.json"
    assert cli.main([*SMALL, "--view", view, "--out", str(tmp_path / f"{view}.png"), "--stats", str(stats)]) == 0
    line = next(t for t in capsys.readouterr().err.splitlines() if t.startswith("against full"))
    return json.loads(stats.read_text())["compare"], line


@pytest.mark.slow
def test_a_levels_picture_is_compared_as_the_shaded_frame_of_its_selection(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(vdp, "vdp_available", lambda name: False)      # JOD is FovVideoVDP's, slow; not judged here
    levels, line = _compare(tmp_path, capsys, "levels")
    shaded, _ = _compare(tmp_path, capsys, "shaded")
    # The level colours are not compared: the figures are those of the same selection drawn shaded.
    assert "drawn shaded" in line and "--view levels" in line, line
    assert levels["view"] == "levels" and "shaded" in levels["compared"]
    for key in ("psnr_db", "psnr_disc_5deg_db", "flip"):
        assert levels[key] == pytest.approx(shaded[key]), key
    assert 25 < levels["psnr_db"] < 80 and 0 < levels["flip"] < 0.3       # close to full, not a different picture
    assert f"PSNR {levels['psnr_db']:.2f} dB" in line and levels["jod"] is None and not levels["identical"]


@pytest.mark.slow
def test_full_against_itself_is_identical_in_the_stats(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(vdp, "vdp_available", lambda name: False)
    stats = tmp_path / "s.json"
    assert cli.main(["render", "--mode", "full", "--size", "96,54", "--compare", "full", "--out",
                     str(tmp_path / "f.png"), "--stats", str(stats)]) == 0
    entry = json.loads(stats.read_text())["compare"]          # strict JSON: no Infinity
    assert entry["identical"] and entry["psnr_db"] is None and entry["flip"] == 0.0


def test_the_frames_judged_are_drawn_alike(monkeypatch):
    # Fast: render_still stood in for; what matters is which frames are drawn and compared.
    import numpy as np

    from calib import DEFAULT_SCREEN
    from headplod import io
    from headplod.render import command
    from headplod.render.still import StillSettings

    drawn = []

    def fake_render_still(settings, screen, **kwargs):
        drawn.append(settings)
        shade = 100 if settings.frame.selection.mode == "full" else 90
        return np.full((54, 96, 3), shade, np.uint8), {}

    monkeypatch.setattr(command, "render_still", fake_render_still)
    monkeypatch.setattr(vdp, "vdp_available", lambda name: False)
    screen = io.read_screen(DEFAULT_SCREEN)
    levels_picture = np.zeros((54, 96, 3), np.uint8)            # level colours: never compared
    settings = StillSettings(view_mode="levels", cov_deg2=np.eye(2), size=(96, 54))
    entry, line = command.compare_with_full(settings, levels_picture, screen, scene=None, renderer=None)
    assert [(s.view_mode, s.overlay, s.frame.selection.mode) for s in drawn] == [
        ("shaded", False, settings.frame.selection.mode), ("shaded", False, "full")]
    assert entry["psnr_db"] == pytest.approx(10 * np.log10(255 ** 2 / 100))     # 90 against 100, not 0 against 100
    assert "drawn shaded" in line and entry["view"] == "levels"
    drawn.clear()
    plain = StillSettings(size=(96, 54))                         # shaded, no marker: the frame itself is judged
    entry, line = command.compare_with_full(plain, np.full((54, 96, 3), 90, np.uint8), screen, None, None)
    assert [s.frame.selection.mode for s in drawn] == ["full"] and line.startswith("against full: PSNR")
