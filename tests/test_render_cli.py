"""`headplod render`: one PLOD frame end to end (levels, mesh, head-coupled render)."""
import json

import pytest

from headplod.cli import main as cli_main

# The GL tests make their own contexts: ``gl_context`` only skips them on a machine without one.
needs_gl = pytest.mark.usefixtures("gl_context")


@pytest.mark.slow
@needs_gl
def test_render_writes_image_and_stats(tmp_path):
    out, stats = tmp_path / "csf.png", tmp_path / "csf.json"
    assert cli_main(["render", "--mode", "csf", "--view", "levels", "--size", "320,180", "--cov", "1,0,1",
                     "--out", str(out), "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    for key in ("triangles", "select_ms", "build_ms", "render_ms", "triangles_per_level"):
        assert key in s
    assert sum(s["triangles_per_level"]) == s["triangles"] > 2048
    assert out.stat().st_size > 1000


@pytest.mark.slow
@needs_gl
def test_csf_keeps_full_detail_at_the_poi_and_far_fewer_triangles(default_screen, terrain_scene):
    from headplod.plod.select import SelectorConfig
    from headplod.render.frame import FrameSettings
    from headplod.render.still import StillSettings, render_still

    def still(mode):
        return StillSettings(FrameSettings("mesh", SelectorConfig(mode=mode)), size=(320, 180))

    _, csf = render_still(still("csf"), default_screen, scene=terrain_scene)
    _, full = render_still(still("full"), default_screen, scene=terrain_scene)
    assert full["triangles"] >= 2_000_000
    assert csf["triangles"] < full["triangles"] / 5
    assert csf["triangles_per_level"][-1] > 0           # the finest level is used near the POI


def test_bad_cov_is_refused(tmp_path, capsys):
    assert cli_main(["render", "--cov", "1,2,1", "--out", str(tmp_path / "x.png")]) == 2
    assert "positive definite" in capsys.readouterr().err


@pytest.mark.slow
@needs_gl
def test_readback_contrast_variant_renders_and_reports_its_cost(tmp_path):
    out, stats = tmp_path / "rb.png", tmp_path / "rb.json"
    assert cli_main(["render", "--mode", "csf", "--size", "320,180", "--contrast", "readback",
                     "--out", str(out), "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    assert s["contrast"] == "readback" and s["readback_ms"] > 0
    assert 2048 < s["triangles"] < 2_000_000


@pytest.mark.parametrize("extra, expected", [
    (["--size", "0,0"], "--size"), (["--size", "64.5,48"], "--size"),
    (["--out", "{tmp}"], "is a folder"), (["--out", "{tmp}/x.bmpx"], "cannot write images"),
    (["--stats", "{tmp}"], "is a folder"),
])
def test_render_refuses_bad_outputs_before_rendering(tmp_path, capsys, extra, expected):
    args = ["render", "--size", "64,48", "--out", str(tmp_path / "x.png")]
    args += [a.replace("{tmp}", str(tmp_path)) for a in extra]
    assert cli_main(args) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and len(err.splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def test_render_that_cannot_write_is_refused_with_one_line(tmp_path, capsys):
    """The image's folder cannot be made (a file stands in its way): found before rendering (bad usage, exit 2),
    one line naming the path, nothing left."""
    blocker = tmp_path / "notes.txt"
    blocker.write_text("keep me\n")
    assert cli_main(["render", "--size", "64,48", "--out", str(blocker / "x.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--out {blocker / 'x.png'}: cannot be written" in err and len(err.splitlines()) == 1, err
    assert blocker.read_text() == "keep me\n" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


@pytest.mark.slow
@needs_gl
def test_render_warns_of_a_poi_off_the_screen(tmp_path, capsys):
    out = tmp_path / "x.png"
    assert cli_main(["render", "--size", "64,48", "--poi", "5000,-300", "--out", str(out)]) == 0
    assert "outside the screen" in capsys.readouterr().err and out.exists()
    assert cli_main(["render", "--size", "64,48", "--poi", "960,540", "--out", str(out)]) == 0
    assert "outside the screen" not in capsys.readouterr().err


@pytest.mark.slow
def test_a_full_disk_while_writing_the_image_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    """Writing the encoded image fails (a full disk): exit 1, one line naming the file, nothing left."""
    import errno
    import pathlib

    from headplod.cli import main as cli_main

    def full_disk(self, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(pathlib.Path, "write_bytes", full_disk)
    out = tmp_path / "r.png"
    assert cli_main(["render", "--size", "160,90", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "r.png" in err[0] and "No space left on device" in err[0], err
    assert ".r.png." not in err[0]                      # the user's name, not the temporary one
    assert list(tmp_path.iterdir()) == []
