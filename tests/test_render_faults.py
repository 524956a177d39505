"""Faults of ``headplod render`` and ``headplod demo`` (issue 35): each is one line on standard error and an exit
status (2 bad usage, 1 a failed run), found before any rendering, and no earlier output loses a byte; the
summaries say what happened (a budget met or not, the frames actually run, the folders really written).

The commands run as a person runs them (``headplod.cli.main`` with argv; a subprocess where the fault is in the
process's environment, a broken EGL), on tiny images and coarse meshes.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from headplod.cli import main as cli_main

# The GL tests make their own contexts: ``gl_context`` only skips them on a machine without one.
needs_gl = pytest.mark.usefixtures("gl_context")
TINY = ["--size", "160,90"]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def no_rendering(monkeypatch):
    """Fail the test if a GL context is made or the terrain's mesh is built: the fault must be found first."""
    import headplod.render.context as context
    from headplod.render.still import TerrainScene

    def boom(*args, **kwargs):
        raise AssertionError("rendering started before the fault was found")

    if context.moderngl is not None:
        monkeypatch.setattr(context.moderngl, "create_standalone_context", boom)
    monkeypatch.setattr(TerrainScene, "build", classmethod(boom))


@pytest.fixture
def earlier_output(tmp_path):
    """An earlier image at ``tmp_path / 'x.png'`` that a refused run must leave as it is: (path, its digest)."""
    out = tmp_path / "x.png"
    out.write_bytes(b"\x89PNG an earlier image, not to be touched")
    return out, _digest(out)


# --------------------------------------------------------------------------
# a view that cannot be drawn
# --------------------------------------------------------------------------


def _on_the_screen_plane() -> str:
    from calib import DEFAULT_SCREEN
    from headplod import io

    screen = io.read_screen(DEFAULT_SCREEN)
    centre = screen.pixel_to_world(np.array(screen.size_px, dtype=np.float64) / 2)
    return ",".join(repr(float(v)) for v in centre)


@pytest.mark.parametrize("head, where", [("0,0,-600", "behind"), (_on_the_screen_plane(), "on")])
def test_a_head_behind_or_on_the_screen_plane_is_bad_usage_found_before_rendering(
        head, where, earlier_output, no_rendering, capsys):
    out, digest = earlier_output
    assert cli_main(["render", *TINY, f"--head={head}", "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("headplod: --head") and f"{where} the screen plane" in line, line
    assert _digest(out) == digest and sorted(p.name for p in out.parent.iterdir()) == ["x.png"]


def test_an_eye_beyond_the_far_plane_is_bad_usage_found_before_rendering(earlier_output, no_rendering, capsys):
    """Found by trying it: --head=0,0,1e300 overflowed into a traceback; 6 m away everything is clipped."""
    out, digest = earlier_output
    for head in ("0,0,1e300", "0,0,6000"):
        assert cli_main(["render", *TINY, f"--head={head}", "--out", str(out)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert line.startswith("headplod: --head") and "beyond the far clip plane" in line, line
    assert _digest(out) == digest


def test_a_screen_whose_corners_face_the_cameras_is_bad_usage_naming_it(tmp_path, earlier_output, no_rendering,
                                                                          default_screen, capsys):
    """Found by trying it: a screen.yaml with top_left and top_right swapped (seen from behind) put the default eye
    behind it: a traceback. Now one line naming --screen, before rendering."""
    from headplod import io

    flipped = tmp_path / "flipped.yaml"
    io.write_screen(flipped, io.Screen(default_screen.size_px, default_screen.top_right, default_screen.top_left,
                                       default_screen.top_right + default_screen.bottom_left
                                       - default_screen.top_left))
    out, digest = earlier_output
    assert cli_main(["render", *TINY, "--screen", str(flipped), "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"headplod: --screen {flipped}: ") and "behind the screen plane" in line, line
    assert _digest(out) == digest


@needs_gl
def test_demo_on_a_recording_whose_screen_faces_away_is_one_line_before_any_frame(tmp_path, sweep12_dir,
                                                                                default_screen, capsys):
    """Found by trying it: a recording's screen.yaml seen from behind failed the demo at its first frame with a
    line that named neither the screen nor what to check. Now found once the poses are opened, before the mesh."""
    import shutil

    from headplod import io

    source = tmp_path / "ds"
    shutil.copytree(sweep12_dir, source)
    io.write_screen(source / "screen.yaml", io.Screen(default_screen.size_px, default_screen.top_right,
                                                      default_screen.top_left, default_screen.top_right
                                                      + default_screen.bottom_left - default_screen.top_left))
    folder = tmp_path / "demo"
    assert cli_main(["demo", "--headless", "-q", "--source", str(source), "--frames", "3", "--viewpoints", "overview",
                     "--scenarios", "adaptive", "--no-full", "--max-level", "2", *TINY, "--out", str(folder)]) == 1
    line = _one_line(capsys.readouterr().err)
    assert "faces away from the cameras" in line and "top_left, top_right and bottom_left" in line, line
    assert not folder.exists()


@needs_gl
@pytest.mark.parametrize("mode", ["hybrid", "change", "csf"])
def test_a_view_that_sees_no_base_triangle_draws_them_all_at_level_0(tmp_path, mode, capsys):
    """Found by trying it: an eye far off to a side (in front, nearer than the far plane) whose view of the
    screen catches no base triangle crashed the hybrid mode's selection (a reshape of nothing)."""
    out, stats = tmp_path / "x.png", tmp_path / "s.json"
    assert cli_main(["render", *TINY, "--max-level", "2", "--mode", mode, "--head=3000,3000,3000",
                     "--out", str(out), "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    assert s["triangles"] == 32 * 32 * 2 and s["triangles_per_level"][0] == s["triangles"]
    assert out.stat().st_size > 0


def test_two_outputs_naming_one_file_are_refused(tmp_path, earlier_output, no_rendering, capsys):
    """Found by trying it: render --out x.png --stats x.png wrote the stats over the image, exit 0."""
    out, digest = earlier_output
    (tmp_path / "link.png").symlink_to(out.name)
    for stats in (out, tmp_path / "link.png", tmp_path / "sub" / ".." / "x.png"):
        assert cli_main(["render", *TINY, "--out", str(out), "--stats", str(stats)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert f"--stats {stats}: is the file --out writes" in line, line
    assert _digest(out) == digest


def test_an_output_naming_an_input_file_is_refused(tmp_path, no_rendering, capsys):
    """Found by trying it: render --terrain h.npy --stats h.npy replaced the height map with the stats, exit 0."""
    heights = tmp_path / "h.npy"
    np.save(heights, np.random.default_rng(0).random((65, 65)) * 100)
    digest = _digest(heights)
    (tmp_path / "hard.npy").hardlink_to(heights)
    for stats in (heights, tmp_path / "hard.npy"):
        assert cli_main(["render", *TINY, "--terrain", str(heights), "--spacing-m", "30", "--out",
                         str(tmp_path / "x.png"), "--stats", str(stats)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert f"--stats {stats}: is the terrain being read (--terrain)" in line, line
    assert _digest(heights) == digest and not (tmp_path / "x.png").exists()


def test_the_view_rule_is_the_screens_and_raises_a_typed_error(default_screen):
    """The rule lives with the screen: the eye's side of its plane; off_axis_projection raises the same error."""
    from headplod.io import ViewError
    from headplod.plod.view import default_head
    from headplod.render.projection import off_axis_projection

    front = default_head(default_screen)
    assert default_screen.eye_distance_mm(front) == pytest.approx(600.0)
    default_screen.check_eye(front)                                # in front: no error
    centre = default_screen.pixel_to_world(np.array(default_screen.size_px, float) / 2)
    for eye, where in ((centre, "on"), (2 * centre - front, "behind")):
        with pytest.raises(ViewError, match=f"{where} the screen plane"):
            default_screen.check_eye(eye)
        with pytest.raises(ViewError, match=f"{where} the screen plane"):
            off_axis_projection(eye, default_screen, 50.0, 5000.0)


# --------------------------------------------------------------------------
# --compare full where full does not fit
# --------------------------------------------------------------------------


def test_compare_full_above_the_finest_full_level_is_refused_before_anything_is_written(
        earlier_output, no_rendering, capsys):
    out, digest = earlier_output
    stats = out.parent / "s.json"
    assert cli_main(["render", *TINY, "--max-level", "8", "--compare", "full", "--out", str(out),
                     "--stats", str(stats)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "--compare full" in line and "--max-level 8" in line and "--max-level 7" in line, line
    assert _digest(out) == digest and not stats.exists()


# --------------------------------------------------------------------------
# a broken EGL
# --------------------------------------------------------------------------


def _run(argv, env_extra, cwd) -> subprocess.CompletedProcess:
    """The command in a child process that imports the headplod this test imports."""
    import headplod

    here = str(Path(headplod.__file__).resolve().parents[1])
    env = {**os.environ, **env_extra, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}
    code = "import sys; from headplod.cli import main; sys.exit(main())"
    return subprocess.run([sys.executable, "-c", code, *argv], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize("command", [
    ["render", *TINY, "--out", "x.png"],
    ["render", *TINY, "--backend", "tessellation", "--grid-samples", "129", "--out", "x.png"],
    ["demo", "--headless", "-q", "--mouse", "--frames", "2", "--viewpoints", "overview", "--scenarios", "adaptive",
     "--no-full", "--max-level", "2", *TINY, "--out", "demo"],
    pytest.param(["bench", "-q", "plod", "--quick", "--only", "lazy"], marks=pytest.mark.slow),
], ids=["render", "tessellation", "demo", "bench"])
def test_a_broken_egl_is_one_line_that_says_what_to_check(tmp_path, command):
    (tmp_path / "x.png").write_bytes(b"earlier")
    r = _run(command, {"__EGL_VENDOR_LIBRARY_FILENAMES": str(tmp_path / "nonexistent.json")}, tmp_path)
    assert r.returncode == 1, r.stderr
    line = _one_line(r.stderr)
    assert re.search(r"OpenGL [\d.]+ context could not be made", line) and "libegl1" in line and "setup.sh" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.png"]            # no demo folder, no new image
    assert (tmp_path / "x.png").read_bytes() == b"earlier"


# --------------------------------------------------------------------------
# a budget met or not
# --------------------------------------------------------------------------


def _render_budget(tmp_path, capsys, *extra) -> tuple[str, dict]:
    out, stats = tmp_path / "b.png", tmp_path / "b.json"
    assert cli_main(["render", *TINY, "--max-level", "3", *extra, "--out", str(out), "--stats", str(stats)]) == 0
    line = capsys.readouterr().err.strip().splitlines()[-1]
    return line, json.loads(stats.read_text())


@needs_gl
def test_a_budget_out_of_reach_is_said_not_met_with_the_nearest_count(tmp_path, capsys):
    _, most = _render_budget(tmp_path, capsys, "--level-bias", "8")       # every seen triangle as fine as it gets
    line, low = _render_budget(tmp_path, capsys, "--budget", "1")
    base = 32 * 32 * 2                                                       # every base triangle at level 0
    assert low["triangles"] == base
    assert low["budget"] == {"triangles": 1, "met": False, "nearest": base, "limit": "coarsest",
                             "reachable": [base, low["budget"]["reachable"][1]], "bias": low["budget_bias"]}
    assert "budget 1 not met" in line and f"{base:,} triangles, the coarsest" in line and " met " not in line, line

    line, high = _render_budget(tmp_path, capsys, "--budget", "1e12")
    finest = high["triangles"]
    assert finest >= most["triangles"] and high["budget"]["reachable"] == [base, finest]
    assert high["budget"]["met"] is False and high["budget"]["limit"] == "finest"
    assert high["budget"]["nearest"] == finest
    assert "not met" in line and f"{finest:,} triangles, the finest" in line, line

    line, mid = _render_budget(tmp_path, capsys, "--budget", "20000")
    assert abs(mid["triangles"] - 20000) <= 0.03 * 20000
    assert mid["budget"]["met"] is True and mid["budget"]["limit"] is None and mid["budget"]["nearest"] is None
    assert "budget 20,000 met" in line and "not met" not in line, line


@needs_gl
def test_the_demo_says_how_often_a_budget_was_met(tmp_path, capsys):
    """Found by trying it: demo --budget 1 said nothing of the budget; the table now says the frames that met it."""
    folder = tmp_path / "demo"
    assert cli_main(["demo", "--headless", "-q", "--mouse", "--frames", "3", "--viewpoints", "overview",
                     "--scenarios", "adaptive", "--no-full", "--max-level", "2", "--budget", "1", *TINY,
                     "--out", str(folder)]) == 0
    out = capsys.readouterr().out
    run = json.loads((folder / "summary.json").read_text())["runs"][0]
    assert run["budget"] == {"triangles": 1, "met_frames": 0, "missed_range": [2048, 2048],
                             "missed_limit": "coarsest"}
    assert "budget 1 met in 0 of 3 frames; missed: 2,048 triangles, the coarsest their views allow" in out, out


# --------------------------------------------------------------------------
# the demo's frames
# --------------------------------------------------------------------------


@needs_gl
def test_demo_with_more_frames_than_the_poses_says_the_frames_run_and_writes_what_it_names(
        tmp_path, sweep12_dir, capsys):
    folder = tmp_path / "demo"
    assert cli_main(["demo", "--headless", "-q", "--source", str(sweep12_dir), "--frames", "20",
                     "--viewpoints", "overview", "--scenarios", "adaptive", "--no-full", "--max-level", "2", *TINY,
                     "--out", str(folder)]) == 0
    captured = capsys.readouterr()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["frames_per_run"] == 12 and summary["frames_asked"] == 20          # sweep12 has 12 frames
    assert [r["frames"] for r in summary["runs"]] == [12]
    assert "12 frames per run" in captured.out and "20 frames per run" not in captured.out, captured.out
    assert "asked for 20" in captured.out, captured.out
    pngs = summary["runs"][0]["frames_png"]
    assert pngs and all(Path(p).is_file() for p in pngs)
    assert any(p.endswith("_011.png") for p in pngs)                                # the last frame run
    named = re.findall(r"(\S+)/\s", captured.out)                                       # "frames: DIR/ ..."
    for name in named:
        assert Path(name).is_dir() and any(Path(name).iterdir()), name


@needs_gl
def test_demo_names_no_frames_folder_it_did_not_write(tmp_path, capsys, monkeypatch):
    """A run whose frames were not kept (none at the frames chosen) names no frames/ folder, and makes none."""
    import headplod.demo.cli as demo_cli

    monkeypatch.setattr(demo_cli, "_PNG_AT", ())
    folder = tmp_path / "demo"
    assert cli_main(["demo", "--headless", "-q", "--mouse", "--frames", "2", "--viewpoints", "overview",
                     "--scenarios", "adaptive", "--no-full", "--max-level", "2", *TINY, "--out", str(folder)]) == 0
    out = capsys.readouterr().out
    assert not (folder / "frames").exists() and "frames/" not in out and "frames:" not in out, out
    assert (folder / "summary.json").is_file()


# --------------------------------------------------------------------------
# outputs that cannot be written
# --------------------------------------------------------------------------

needs_proc = pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="no /proc on this system")


@needs_proc
@pytest.mark.parametrize("option, name", [("--out", "/proc/x.png"), ("--stats", "/proc/s.json"),
                                          ("--export", "/proc/m.ply"), ("--out", "{blocker}/x.png"),
                                          ("--stats", "{blocker}/sub/s.json")])
def test_render_to_an_unwritable_place_is_one_line_naming_it_before_rendering(
        tmp_path, option, name, earlier_output, no_rendering, capsys):
    out, digest = earlier_output
    blocker = tmp_path / "notes.txt"                    # a file where a folder would have to be
    blocker.write_text("keep me\n")
    name = name.replace("{blocker}", str(blocker))
    argv = ["render", *TINY, "--out", str(out), option, name]
    if option == "--out":
        argv = ["render", *TINY, "--out", name]
    assert cli_main(argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"headplod: {option} {name}: ") and "cannot be written" in line, line
    assert not re.search(r"/\.[^/ ]+\.(png|json|ply)\.", line), line                  # no hidden temporary name
    assert _digest(out) == digest and blocker.read_text() == "keep me\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "x.png"]


@needs_proc
@pytest.mark.parametrize("name", ["/proc/demo", "{blocker}", "{blocker}/demo"])
def test_demo_to_an_unwritable_folder_is_one_line_naming_it_before_anything_runs(
        tmp_path, name, no_rendering, monkeypatch, capsys):
    import headplod.demo.cli as demo_cli

    def no_poses(*args, **kwargs):
        raise AssertionError("the poses were opened before the fault was found")

    monkeypatch.setattr(demo_cli, "make_poses", no_poses)
    blocker = tmp_path / "notes.txt"
    blocker.write_text("keep me\n")
    name = name.replace("{blocker}", str(blocker))
    assert cli_main(["demo", "--headless", "--mouse", "--frames", "2", *TINY, "--out", name]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"headplod demo: --out {name}: "), line
    assert blocker.read_text() == "keep me\n" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


@needs_gl
@pytest.mark.parametrize("option, name", [("--stats", "s.json"), ("--export", "m.ply")])
def test_a_write_that_fails_midway_names_the_users_path_not_a_temporary_one(tmp_path, option, name, capsys,
                                                                             monkeypatch):
    """The folder was writable when checked, and the write itself fails (a full disk, a folder made read-only
    meanwhile): exit 1, one line naming the option's path, no hidden name, nothing of it left."""
    import headplod.io
    import headplod.render.still as still

    def full_disk(path, write, suffix=""):
        def failing(tmp):
            raise OSError(28, "No space left on device", tmp)
        return real(path, failing if Path(path) == target else write, suffix)

    # the stats go through render.still's write_atomically, the mesh export through headplod.io's
    owner = still if option == "--stats" else headplod.io
    real = owner.write_atomically
    monkeypatch.setattr(owner, "write_atomically", full_disk)
    target = tmp_path / name
    assert cli_main(["render", *TINY, "--max-level", "2", "--out", str(tmp_path / "x.png"), option,
                     str(target)]) == 1
    line = _one_line(capsys.readouterr().err)
    assert str(target) in line and "No space left" in line and "/." not in line, line
    assert not target.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("in_the_way", ["summary.json/", "frames", "viewpoint_overview_levels.png/"])
def test_demo_entries_in_the_way_are_found_before_anything_runs(tmp_path, in_the_way, no_rendering, monkeypatch,
                                                               capsys):
    """Found by trying it: a folder named summary.json in --out failed the demo after the whole run, naming a
    hidden temporary file; a file named frames failed it at the first frame kept. Now one line before anything."""
    import headplod.demo.cli as demo_cli

    def no_poses(*args, **kwargs):
        raise AssertionError("the poses were opened before the fault was found")

    monkeypatch.setattr(demo_cli, "make_poses", no_poses)
    folder = tmp_path / "demo"
    folder.mkdir()
    blocker = folder / in_the_way.rstrip("/")
    blocker.mkdir() if in_the_way.endswith("/") else blocker.write_text("keep me\n")
    assert cli_main(["demo", "--headless", "--mouse", "--frames", "2", "--viewpoints", "overview", *TINY,
                     "--out", str(folder)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"headplod demo: --out {folder}: ") and str(blocker) in line and "/." not in line, line
    assert sorted(p.name for p in folder.iterdir()) == [blocker.name]


@needs_gl
def test_stats_dash_is_standard_output_not_a_file_named_dash(tmp_path, monkeypatch, capsys):
    """Found by trying it: render --stats - wrote a file named '-' in the current folder; '-' is standard output
    everywhere else (track --out -)."""
    monkeypatch.chdir(tmp_path)
    assert cli_main(["render", *TINY, "--max-level", "2", "--budget", "1", "-q", "--out", "x.png",
                     "--stats", "-"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["triangles"] == 2048 and stats["budget"]["met"] is False
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.png"]
