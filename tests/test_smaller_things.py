"""Issue 15, item 7, "smaller things": each case reproduced, and the fix checked.

- a colour PNG is tracked with a warning: the first in full, then a count
  at the end (not a line per frame), and in the records' ``flags``;
- absurd intrinsics in ``rig.yaml`` (``fx = 1e308``) are refused with a
  one-line reason; a ``t_right`` seconds away from ``t`` is named as a skew
  of the clocks, not left to a reprojection error;
- markers in metres get a hint about units;
- a corrupt frame in the synthetic sequence cache is found and re-rendered.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.capture import synthetic as cache
from headplod.cli import main as cli_main
from headplod.live.frame_notes import FrameNotes, split_frame_warning, warning_kind


def _one_line_error(err: str) -> str:
    lines = [l for l in err.strip().splitlines() if l.startswith("headplod:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    return lines[0]


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# ---------------------------------------------------------------------------
# 1. a colour PNG is tracked with a warning, shown once and counted
# ---------------------------------------------------------------------------


def _colour(folder: Path, side: str = "left") -> None:
    for path in sorted((folder / side).glob("*.png")):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        assert cv2.imwrite(str(path), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))


@pytest.mark.slow
@pytest.mark.parametrize("quiet", [False, True])
def test_colour_pngs_are_tracked_with_one_warning_and_a_count(sample, tmp_path, capsys, quiet):
    _colour(sample, "left")
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out)] + (["-q"] if quiet else [])) == 0
    err = capsys.readouterr().err
    lines = [l for l in err.splitlines() if "3-channel image converted to gray" in l]
    # The first occurrence in full (its file named), then one count at the end: two lines, not twelve.
    assert len(lines) == 2, err
    assert lines[0].startswith("warning: frame 0: left/000000.png: 3-channel image converted to gray")
    assert lines[1] == "warning: 12 of 12 frames: left/NNNNNN.png: 3-channel image converted to gray, " \
                       "expected 8-bit grayscale"
    records = _records(out)
    assert len(records) == 12 and all(r["ok"] for r in records)           # converted, and tracked
    for r in records:
        assert r["flags"] == [f"left/{r['frame']:06d}.png: 3-channel image converted to gray, "
                              "expected 8-bit grayscale"]


@pytest.mark.slow
def test_gray_pngs_give_no_warning(sample, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    assert "warning: frame" not in capsys.readouterr().err
    assert all(r["flags"] == [] for r in _records(out))


def test_frame_notes_split_and_count():
    both = ("left/000003.png: 4-channel image converted to gray, expected 8-bit grayscale; "
            "right/000003.png: 3-channel image converted to gray, expected 8-bit grayscale")
    assert len(split_frame_warning(both)) == 2
    # A note that holds "; " itself stays whole.
    interp = "times.csv has no row for this frame; t interpolated"
    assert split_frame_warning(interp + "; " + both) == [interp] + split_frame_warning(both)
    assert split_frame_warning(None) == [] and split_frame_warning("") == []
    assert warning_kind("left/000003.png: x") == warning_kind("left/000004.png: x") != warning_kind("right/000003.png: x")

    notes = FrameNotes(stream=None)
    for i in range(5):
        notes.add(i, both.replace("000003", f"{i:06d}") if i % 2 == 0 else None)
    assert notes.summary() == [
        "warning: 3 of 5 frames: left/NNNNNN.png: 4-channel image converted to gray, expected 8-bit grayscale",
        "warning: 3 of 5 frames: right/NNNNNN.png: 3-channel image converted to gray, expected 8-bit grayscale",
    ]


# ---------------------------------------------------------------------------
# 3. extreme values: absurd intrinsics refused; a t_right seconds off named as a skew
# ---------------------------------------------------------------------------


def _edit_rig(folder: Path, key: str, i: int, j: int, value: float) -> None:
    rig = io.read_rig(folder / "rig.yaml")
    K = dict(K1=rig.K1.copy(), K2=rig.K2.copy(), D1=rig.D1[None].copy(), D2=rig.D2[None].copy())
    K[key][i, j] = value
    fs = cv2.FileStorage(str(folder / "rig.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", rig.image_size[0])
    fs.write("image_height", rig.image_size[1])
    for name, m in (("K1", K["K1"]), ("D1", K["D1"]), ("K2", K["K2"]), ("D2", K["D2"]),
                    ("R", rig.R), ("T", rig.T[:, None])):
        fs.write(name, np.asarray(m, np.float64))
    fs.release()


@pytest.mark.parametrize("key, i, j, value, fragment", [
    ("K1", 0, 0, 1e308, "'K1' has fx = K1[0,0] = 1e+308 px"),
    ("K2", 1, 1, 1e6, "'K2' has fy = K2[1,1] = 1e+06 px"),
    ("K1", 0, 0, 5.0, "'K1' has fx = K1[0,0] = 5 px"),
    ("K2", 0, 2, 5000.0, "'K2' has cx = K2[0,2] = 5000 px, far outside the image"),
    ("K1", 1, 2, -1e300, "'K1' has cy = K1[1,2] = -1e+300 px"),
])
def test_absurd_intrinsics_are_refused_with_one_line(sample, tmp_path, capsys, key, i, j, value, fragment):
    _edit_rig(sample, key, i, j, value)
    with pytest.raises(io.ContractError, match="expected"):
        io.read_rig(sample / "rig.yaml")
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert fragment in line and "rig.yaml" in line, line
    assert not out.exists()


def test_plausible_intrinsics_still_read(sample):
    for k in range(5):                              # (a normal lens's distortion would fold a wide field)
        _edit_rig(sample, "D1", 0, k, 0.0)
    _edit_rig(sample, "K1", 0, 0, 0.2 * 640)        # a wide lens: 0.2 x the width
    _edit_rig(sample, "K2", 0, 2, -100.0)           # a principal point a little outside the image
    assert io.read_rig(sample / "rig.yaml").K1[0, 0] == 128.0


def _shift_right_times(folder: Path, offset_s: float) -> None:
    rows = (folder / "times.csv").read_text().split()[1:]
    text = "frame,t,t_right\n" + "".join(f"{f},{t},{float(t) + offset_s!r}\n"
                                         for f, t in (r.split(",")[:2] for r in rows))
    (folder / "times.csv").write_text(text)


def test_right_times_seconds_off_are_named_as_a_skew(sample, tmp_path, capsys):
    _shift_right_times(sample, 5.0)
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 3
    err = capsys.readouterr().err
    warned = [l for l in err.splitlines() if "times.csv: the right camera's times are 5.0 s after the left's" in l]
    assert len(warned) == 1 and "clocks" in warned[0], err              # once, naming the skew
    records = _records(out)
    assert len(records) == 12
    for r in records:                                                   # no pose, and the skew as the reason
        assert not r["ok"], r
        assert r["reason"].startswith("right image's time is 5.0 s after the left's"), r["reason"]
        assert "clocks" in r["reason"] and "reprojection" not in r["reason"]


@pytest.mark.slow
def test_right_times_a_little_off_are_tracked_without_a_skew_warning(sample, tmp_path, capsys):
    _shift_right_times(sample, 0.004)                                   # 4 ms: an exposure offset
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    assert "right camera's times" not in capsys.readouterr().err
    assert sum(r["ok"] for r in _records(out)) >= 11


# ---------------------------------------------------------------------------
# 2. units: markers in metres (or cm) get a hint about units
# ---------------------------------------------------------------------------


def _write_markers_raw(path: Path, points, diameter: float) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("markers", np.asarray(points, np.float64))
    fs.write("diameter", float(diameter))
    fs.release()
    return path


def test_markers_in_metres_are_refused_with_a_units_hint(sample, tmp_path, capsys):
    model = io.default_marker_model()
    path = _write_markers_raw(tmp_path / "markers.yaml", model.points_mm / 1000.0, 0.006)
    with pytest.raises(io.ContractError, match="looks like metres; markers.yaml is in mm"):
        io.read_markers(path)
    assert cli_main(["track", "--source", str(sample), "--markers", str(path), "-q"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "the markers span 0.13 mm" in line and "multiply every coordinate by 1000" in line, line
    # In a dataset's own markers.yaml too.
    _write_markers_raw(sample / "markers.yaml", model.points_mm / 1000.0, 0.006)
    with pytest.raises(io.ContractError, match="metres"):
        io.Dataset(sample)


@pytest.mark.slow
def test_markers_in_cm_get_a_units_hint_in_the_reason(sample, tmp_path, capsys):
    model = io.default_marker_model()
    path = _write_markers_raw(tmp_path / "markers.yaml", model.points_mm / 10.0, 0.6)   # plausible alone
    io.read_markers(path)
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--markers", str(path), "--out", str(out), "-q",
                     "--frames", "3"]) == 3
    for r in _records(out):
        assert "best labeling" in r["reason"], r["reason"]
        assert "the markers seen are 10 times the size of the marker model: is markers.yaml in mm" in r["reason"]


@pytest.mark.slow
def test_no_units_hint_for_the_right_model(sample, tmp_path):
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    assert not any("times the size" in (r["reason"] or "") for r in _records(out))


# ---------------------------------------------------------------------------
# 4. the synthetic sequence cache: a damaged frame is found and rendered again
# ---------------------------------------------------------------------------


@pytest.fixture
def cached(tmp_path):
    """A small rendered sequence in a cache of its own: (root, folder, original bytes of left/000002.png)."""
    root = tmp_path / "cache"
    folder = cache.ensure_dataset("yaw_sweep", frames=6, root=root, quiet=True)
    return root, folder, (folder / "left" / "000002.png").read_bytes()


def _again(root, capsys):
    folder = cache.ensure_dataset("yaw_sweep", frames=6, root=root, quiet=True)
    return folder, capsys.readouterr().err


@pytest.mark.slow
def test_an_intact_cache_is_used_as_it_is(cached, capsys):
    root, folder, _ = cached
    marker = (folder / cache.COMPLETE).read_text()
    again, err = _again(root, capsys)
    assert again == folder and err == ""
    assert (folder / cache.COMPLETE).read_text() == marker
    # Touched but unchanged (a copy, a backup tool): hashed, found the same, kept.
    path = folder / "right" / "000001.png"
    path.write_bytes(path.read_bytes())
    assert _again(root, capsys)[1] == ""


@pytest.mark.slow
@pytest.mark.parametrize("damage, words", [
    ("truncate", "left/000002.png has"),
    ("delete", "left/000002.png is missing"),
    ("flip", "left/000002.png changed since it was rendered"),
])
def test_a_damaged_cached_frame_is_rendered_again(cached, capsys, damage, words):
    root, folder, original = cached
    path = folder / "left" / "000002.png"
    if damage == "truncate":
        path.write_bytes(original[: len(original) // 2])
    elif damage == "delete":
        path.unlink()
    else:                                            # the same size, other bytes
        data = bytearray(original)
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))
    again, err = _again(root, capsys)
    notes = [l for l in err.splitlines() if l.startswith("note:")]
    assert len(notes) == 1 and "is damaged" in notes[0] and words in notes[0], err
    assert again == folder and path.read_bytes() == original           # rendered again, the same images
    assert _again(root, capsys)[1] == ""                                # and trusted from then on


@pytest.mark.slow
def test_an_older_cache_is_read_once_then_given_a_manifest(cached, capsys):
    root, folder, original = cached
    (folder / cache.COMPLETE).write_text("ok\n")                        # as earlier versions wrote it
    assert _again(root, capsys)[1] == ""
    assert '"files"' in (folder / cache.COMPLETE).read_text()
    (folder / cache.COMPLETE).write_text("ok\n")
    (folder / "left" / "000002.png").write_bytes(original[:100])        # and one with a broken frame
    err = _again(root, capsys)[1]
    assert "left/000002.png cannot be read" in err
    assert (folder / "left" / "000002.png").read_bytes() == original


@pytest.mark.slow
def test_ensure_dataset_stays_cheap_on_a_cached_sequence(cached, monkeypatch):
    """On an intact cache the check is one stat per file: no file is hashed or decoded, nothing rendered."""
    import synthetic.dataset

    root, folder, _ = cached
    work, real_hash = [], cache._file_hash

    def file_hash(path):
        work.append(("hash", path))
        return real_hash(path)

    monkeypatch.setattr(cache, "_file_hash", file_hash)
    monkeypatch.setattr(cache, "verify_dataset", lambda path: work.append(("decode", path)))
    monkeypatch.setattr(synthetic.dataset, "write_dataset", lambda *a, **k: work.append(("render", a)))
    for _ in range(3):
        assert cache.ensure_dataset("yaw_sweep", frames=6, root=root, quiet=True) == folder
    assert work == []
    # A file whose time changed is the one hashed (and, its bytes the same, the cache is still used).
    frame = folder / "left" / "000002.png"
    os.utime(frame, ns=(frame.stat().st_atime_ns, frame.stat().st_mtime_ns + 1000))
    assert cache.ensure_dataset("yaw_sweep", frames=6, root=root, quiet=True) == folder
    assert work == [("hash", frame)]


@pytest.mark.slow
def test_track_renders_a_damaged_default_sequence_again_and_tracks_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("HEADPLOD_CACHE", str(tmp_path / "cache"))
    first, second = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    assert cli_main(["track", "--source", "synthetic:yaw_sweep", "--frames", "8", "-q", "--out", str(first)]) == 0
    capsys.readouterr()
    folder = next((tmp_path / "cache").iterdir())
    path = folder / "left" / "000003.png"
    path.write_bytes(path.read_bytes()[:500])                           # truncated
    assert cli_main(["track", "--source", "synthetic:yaw_sweep", "--frames", "8", "-q", "--out", str(second)]) == 0
    err = capsys.readouterr().err
    assert "is damaged (left/000003.png has 500 bytes" in err and "rendering it again" in err
    a, b = _records(first), _records(second)
    assert [r["ok"] for r in b] == [r["ok"] for r in a] and b[3]["ok"]
    assert np.allclose(b[3]["position"], a[3]["position"])


@pytest.mark.slow
def test_a_cached_frame_that_fails_to_read_is_rendered_again_next_time(tmp_path, monkeypatch, capsys):
    import os
    monkeypatch.setenv("HEADPLOD_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", "synthetic:yaw_sweep", "--frames", "4", "-q"]) == 0
    folder = next((tmp_path / "cache").iterdir())
    path = folder / "left" / "000001.png"
    st = path.stat()
    data = bytearray(path.read_bytes())
    data[40:4000] = bytes(3960)                                         # the same size, the same time: not seen
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    capsys.readouterr()
    assert cli_main(["track", "--source", "synthetic:yaw_sweep", "--frames", "4", "-q", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert not _records(out)[1]["ok"]
    assert "it will be rendered again" in err and "left/000001.png" in err
    assert cli_main(["track", "--source", "synthetic:yaw_sweep", "--frames", "4", "-q", "--out", str(out)]) == 0
    assert all(r["ok"] for r in _records(out))


@pytest.mark.slow
def test_two_renders_of_one_sequence_at_once_neither_breaks_the_other(tmp_path, monkeypatch):
    """Another process finishes the same sequence while this one renders it (two benchmarks at once): each
    renders beside the cache entry and renames it into place, so this one keeps the finished entry, its own
    half never lands, and no staging folder is left."""
    import synthetic.dataset

    root = tmp_path / "cache"
    real_write = synthetic.dataset.write_dataset
    calls = []

    def write_while_another_finishes(folder, *args, **kwargs):
        calls.append(folder)
        if len(calls) == 1:               # the other process, start to end, during this one's render
            monkeypatch.setattr(synthetic.dataset, "write_dataset", real_write)
            other = cache.ensure_dataset("yaw_sweep", frames=4, root=root, quiet=True)
            calls.append(other)
        real_write(folder, *args, **kwargs)

    monkeypatch.setattr(synthetic.dataset, "write_dataset", write_while_another_finishes)
    folder = cache.ensure_dataset("yaw_sweep", frames=4, root=root, quiet=True)
    assert calls[1] == folder and calls[0] != folder and calls[0].parent == folder.parent
    assert cache._check_manifest(folder) is None
    assert sorted(p.name for p in root.iterdir()) == [folder.name]


@pytest.mark.slow
def test_a_render_killed_midway_leaves_nothing_behind_once_the_entry_is_asked_for_again(cached):
    """kill -9 during a render skips its own clean-up: its staging folder (named after its process) is
    deleted the next time the entry is asked for; one of a process still running is left alone."""
    import subprocess
    import sys

    root, folder, _ = cached
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True).stdout.strip()
    abandoned = root / f".{folder.name}.rendering-{dead}-0000abcd"
    running = root / f".{folder.name}.rendering-{os.getpid()}-0000abcd"
    for staging in (abandoned, running):
        (staging / "left").mkdir(parents=True)
    assert cache.ensure_dataset("yaw_sweep", frames=6, root=root, quiet=True) == folder
    assert not abandoned.exists() and running.exists()
