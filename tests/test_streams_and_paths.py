"""Closed standard streams, undecodable paths, a deleted current folder and a broken cache (issue 35).

Every case runs the real command in a subprocess (``python -m headplod.cli``): a closed descriptor is the
process's own, and a crash inside OpenCV (a segfault) must fail the test, not end pytest. Each asserts
what the run made (records, images, folders), its exit status, and at most one ``headplod:`` line with no
traceback.

- **Streams**: standard error closed (``2>&-``), full (``/dev/full``) or a pipe nobody reads costs no
  record and no exit status; standard output closed while the records are to go there is one line and
  exit 2; a reader that leaves mid-run ends the run as a closed pipe does (exit 141, 128 + SIGPIPE).
- **Paths**: a folder whose name is not UTF-8 (``b'caf\\xe9'``), or ``café`` under ``LC_ALL=C`` without
  Python's UTF-8 mode, works for every file OpenCV reads or writes (images, rig.yaml), and a video that
  OpenCV could only open by its path is refused in one line.
- **The current folder deleted**: one line, exit 2.
- **The cache**: ``HOME`` empty or unset never puts it in ``/.cache``; ``HEADPLOD_CACHE`` a file or under
  a file is one line naming ``HEADPLOD_CACHE``, without matplotlib's advice about ``MPLCONFIGDIR``.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io

ROOT = Path(__file__).resolve().parent.parent
#: The code under test: the PYTHONPATH pytest runs with (a worktree, or the base checkout to see a test fail).
CODE = os.environ.get("PYTHONPATH") or str(ROOT)
HEADPLOD = [sys.executable, "-m", "headplod.cli"]
#: Where the commands run: ``python -m`` puts its current folder first on sys.path, and a checkout there
#: would win over CODE.
NEUTRAL = "/"
#: A folder name with a byte that is not UTF-8: 'caf\udce9' in Python under a UTF-8 locale.
UNDECODABLE = b"caf\xe9"
#: Python without its UTF-8 mode under the C locale: every non-ASCII byte of a name is a surrogate.
C_LOCALE = {"LC_ALL": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0"}


def _env(**changes) -> dict:
    env = {**os.environ, "PYTHONPATH": CODE}
    for key, value in changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    return env


def _run(args, shell_redirect: str = "", env=None, cwd=None, stdin=subprocess.DEVNULL, timeout=300):
    """``headplod ARGS`` in a subprocess (``shell_redirect``: e.g. ``2>&-``, applied by sh); its
    CompletedProcess with bytes stdout and stderr."""
    argv = HEADPLOD + [os.fsencode(a) if isinstance(a, (str, Path)) else a for a in args]
    if shell_redirect:
        argv = ["sh", "-c", f'exec "$@" {shell_redirect}', "sh"] + argv
    return subprocess.run(argv, stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          env=env or _env(), cwd=cwd or NEUTRAL, timeout=timeout)


def _one_line(err: bytes, among_others: bool = False) -> str:
    """The single line of ``err``, or with ``among_others`` its single ``headplod:`` line (the run's summary
    may come before it); no traceback, no crash."""
    text = err.decode("utf-8", "backslashreplace")
    assert "Traceback" not in text and "Fatal Python error" not in text, text
    lines = [line for line in text.splitlines() if line.strip() and (line.startswith("headplod:") or not among_others)]
    assert len(lines) == 1, text
    return lines[0]


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# ---------------------------------------------------------------------------
# standard streams
# ---------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("quiet", [[], ["-q"]], ids=["messages", "quiet"])
def test_a_closed_standard_error_costs_no_record(tmp_path, long_dataset, quiet):
    out = tmp_path / "f.jsonl"
    done = _run(["track", "--source", long_dataset, "--out", out, "--frames", "20", *quiet], "2>&-")
    assert done.returncode == 0, done
    records = _records(out)
    assert [r["frame"] for r in records] == list(range(20))
    assert all(r["ok"] for r in records)
    assert done.stdout == b""                           # no message fell back to standard output


def test_a_closed_standard_error_never_mixes_messages_into_records_on_standard_output(sweep12_dir):
    done = _run(["track", "--source", sweep12_dir, "--out", "-"], "2>&-")
    assert done.returncode == 0, done
    lines = done.stdout.decode().splitlines()
    assert [json.loads(line)["frame"] for line in lines] == list(range(12))


@pytest.mark.slow
@pytest.mark.parametrize("where", ["/dev/full", "a pipe nobody reads"])
def test_an_unwritable_standard_error_costs_no_record(tmp_path, long_dataset, where):
    out = tmp_path / "f.jsonl"
    if where == "/dev/full":
        if not os.path.exists("/dev/full"):
            pytest.skip("no /dev/full on this machine")
        done = _run(["track", "--source", long_dataset, "--out", out, "--frames", "20"], "2>/dev/full")
    else:
        read, write = os.pipe()
        os.close(read)                                  # every write to standard error: EPIPE
        try:
            argv = HEADPLOD + ["track", "--source", str(long_dataset), "--out", str(out), "--frames", "20"]
            done = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=write,
                                  env=_env(), cwd=NEUTRAL, timeout=300)
        finally:
            os.close(write)
    assert done.returncode == 0, done
    assert [r["frame"] for r in _records(out)] == list(range(20))


@pytest.mark.parametrize("redirect", ["2>&-", pytest.param("2>/dev/full", marks=pytest.mark.slow)])
def test_synth_with_a_closed_or_full_standard_error_makes_its_folder(tmp_path, redirect):
    if "/dev/full" in redirect and not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this machine")
    target = tmp_path / "D"
    done = _run(["synth", "static", "--out", target, "--frames", "3"], redirect)
    assert done.returncode == 0, done
    assert sorted(io.read_times(target / "times.csv")) == [0, 1, 2]
    assert sorted(p.name for p in (target / "left").iterdir()) == ["000000.png", "000001.png", "000002.png"]
    assert [p.name for p in tmp_path.iterdir()] == ["D"]          # no hidden .D.synth-* left beside it


@pytest.mark.parametrize("name", ["-", pytest.param("/dev/stdout", marks=pytest.mark.slow)])
def test_records_for_a_closed_standard_output_are_refused_in_one_line(tmp_path, sweep12_dir, name):
    if name != "-" and not os.path.exists("/dev/stdout"):
        pytest.skip("no /dev/stdout on this machine")
    done = _run(["track", "--source", sweep12_dir, "--out", name], ">&-")
    assert done.returncode == 2, done
    line = _one_line(done.stderr)
    assert line.startswith(f"headplod: --out {name}: standard output is closed"), line


@pytest.mark.slow
def test_a_reader_that_leaves_ends_the_run_as_a_closed_pipe_does(tmp_path, long_dataset):
    record = tmp_path / "rec"
    read, write = os.pipe()
    os.close(read)                                      # the reader has left before the first record
    try:
        argv = HEADPLOD + ["track", "--source", str(long_dataset), "--out", "-", "--record", str(record), "-q"]
        done = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=write, stderr=subprocess.PIPE,
                              env=_env(), cwd=NEUTRAL, timeout=300)
    finally:
        os.close(write)
    assert done.returncode == 128 + 13, done            # 141: what a writer killed by SIGPIPE reports
    line = _one_line(done.stderr, among_others=True)
    assert "--out -: the program reading it closed the pipe" in line, line
    assert f"in {record}" in line, line                 # and where what was made is kept
    frames = list(io.Dataset(record))                   # what was recorded is whole: every row, both images
    assert frames and all(f.error is None for f in frames)


# ---------------------------------------------------------------------------
# paths OpenCV's binding cannot take
# ---------------------------------------------------------------------------

FOLDERS = [pytest.param(UNDECODABLE, {}, id="not-utf8"),
           pytest.param("café".encode(), C_LOCALE, id="LC_ALL=C", marks=pytest.mark.slow)]


def _folder(tmp_path: Path, name: bytes) -> Path:
    folder = Path(os.fsdecode(os.path.join(os.fsencode(tmp_path), name)))
    folder.mkdir()
    return folder


@pytest.mark.parametrize("name, env", FOLDERS)
def test_track_reads_a_dataset_in_a_folder_opencv_cannot_name(tmp_path, sweep12_dir, name, env):
    source = _folder(tmp_path, name) / "D"
    shutil.copytree(sweep12_dir, source)
    out = tmp_path / "f.jsonl"
    done = _run(["track", "--source", source, "--out", out, "-q"], env=_env(**env))
    assert done.returncode == 0, done
    records = _records(out)
    assert len(records) == 12 and all(r["ok"] for r in records), records


@pytest.mark.slow
@pytest.mark.parametrize("name, env", FOLDERS)
def test_track_records_into_a_folder_opencv_cannot_name(tmp_path, sweep12_dir, name, env):
    record = _folder(tmp_path, name) / "rec"
    done = _run(["track", "--source", sweep12_dir, "--record", record, "--frames", "4", "-q"],
                env=_env(**env))
    assert done.returncode == 0, done
    assert io.read_rig(record / "rig.yaml").image_size == io.read_rig(sweep12_dir / "rig.yaml").image_size
    frames = list(io.Dataset(record))
    assert len(frames) == 4 and all(f.error is None for f in frames)
    for f in frames:                                    # the very pixels it read
        expected = cv2.imread(str(sweep12_dir / "left" / f"{f.index:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(f.left, expected)
    replay = _run(["track", "--source", record, "--out", tmp_path / "replay.jsonl", "-q"], env=_env(**env))
    assert replay.returncode == 0, replay
    assert len(_records(tmp_path / "replay.jsonl")) == 4


@pytest.mark.slow
@pytest.mark.parametrize("name, env", FOLDERS)
def test_render_writes_an_image_into_a_folder_opencv_cannot_name(tmp_path, gl_context, name, env):
    out = _folder(tmp_path, name) / "x.png"
    done = _run(["render", "--size", "64,48", "--out", out], env=_env(**env))
    assert done.returncode == 0, done
    image = cv2.imdecode(np.frombuffer(out.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.shape == (48, 64, 3)
    assert [p.name for p in out.parent.iterdir()] == ["x.png"]      # no temporary name left


@pytest.mark.parametrize("name, env", FOLDERS + [
    pytest.param(UNDECODABLE, {"PYTHONIOENCODING": "utf-8:strict"}, id="strict-stdout", marks=pytest.mark.slow)])
def test_synth_writes_a_dataset_into_a_folder_opencv_cannot_name(tmp_path, name, env):
    target = _folder(tmp_path, name) / "D"
    done = _run(["synth", "static", "--out", target, "--frames", "2", "-q"], env=_env(**env))
    assert done.returncode == 0, done
    assert os.fsencode(target) in done.stdout           # its summary names the folder by its own bytes
    assert [f.error for f in io.Dataset(target)] == [None, None]


def test_a_video_opencv_could_only_open_by_an_undecodable_name_is_refused_in_one_line(tmp_path, sweep12_dir):
    folder = _folder(tmp_path, UNDECODABLE)
    for side in ("left", "right"):
        writer = cv2.VideoWriter(str(tmp_path / f"{side}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 30, (640, 480),
                                 False)
        if not writer.isOpened():
            pytest.skip("OpenCV cannot write MJPG .avi here")
        writer.write(cv2.imread(str(sweep12_dir / side / "000000.png"), cv2.IMREAD_GRAYSCALE))
        writer.release()
        os.rename(tmp_path / f"{side}.avi", folder / f"{side}.avi")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    out = tmp_path / "f.jsonl"
    spec = os.fsencode(folder / "left.avi") + b"," + os.fsencode(folder / "right.avi")
    done = _run(["track", "--source", spec, "--calib", sweep12_dir / "rig.yaml", "--out", out])
    assert done.returncode == 2, done
    line = _one_line(done.stderr)
    assert "caf\\xe9" in line and "UTF-8" in line, line          # the path shown as it is, safely
    assert not out.exists()
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


# ---------------------------------------------------------------------------
# a deleted current folder
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("args", [pytest.param(["track", "--frames", "1"], id="track"),
                                  pytest.param(["synth", "static", "--out", "D"], id="synth", marks=pytest.mark.slow),
                                  pytest.param(["render", "--size", "64,48", "--out", "x.png"], id="render",
                                               marks=pytest.mark.slow)])
def test_a_deleted_current_folder_is_one_line(tmp_path, args):
    gone = tmp_path / "gone"
    gone.mkdir()
    argv = ["sh", "-c", 'cd "$1" && rmdir "$1" && shift && exec "$@"', "sh", str(gone)] + HEADPLOD + args
    done = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          env=_env(), timeout=300)
    assert done.returncode == 2, done
    line = _one_line(done.stderr)
    assert "current folder" in line, line
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------
# the cache folder
# ---------------------------------------------------------------------------


def test_the_cache_follows_home_then_the_password_database_and_refuses_without_either():
    from headplod.cache import CacheUnusable, cache_root

    assert cache_root({"HEADPLOD_CACHE": "/c"}, home_of_user=lambda: "/p") == Path("/c")
    assert cache_root({"HOME": "/h"}, home_of_user=lambda: "/p") == Path("/h/.cache/headplod")
    for environ in ({"HOME": ""}, {}, {"HOME": "relative"}, {"HOME": "/"}, {"HEADPLOD_CACHE": ""}):
        assert cache_root(environ, home_of_user=lambda: "/p") == Path("/p/.cache/headplod"), environ
        for home in (None, "", "/"):
            with pytest.raises(CacheUnusable, match="HEADPLOD_CACHE"):
                cache_root(environ, home_of_user=lambda: home)


def test_a_home_that_does_not_exist_is_not_made_for_the_cache(tmp_path):
    from headplod.cache import CacheUnusable, usable_cache_root

    with pytest.raises(CacheUnusable, match="home folder .* does not exist; set HEADPLOD_CACHE"):
        usable_cache_root({"HOME": str(tmp_path / "nonexistent")})
    assert list(tmp_path.iterdir()) == []
    assert usable_cache_root({"HOME": str(tmp_path)}) == tmp_path / ".cache" / "headplod"
    assert (tmp_path / ".cache" / "headplod").is_dir()


@pytest.mark.slow
@pytest.mark.parametrize("home", ["", None], ids=["HOME=''", "HOME unset"])
def test_an_empty_or_missing_home_never_puts_the_cache_in_the_root_folder(tmp_path, gl_context, home):
    if Path("/.cache").exists():
        pytest.skip("/.cache exists already on this machine")
    out = tmp_path / "x.png"
    done = _run(["render", "--size", "64,48", "--out", out], env=_env(HOME=home, HEADPLOD_CACHE=None,
                                                                      MPLCONFIGDIR=None))
    text = done.stderr.decode()
    assert done.returncode == 0, done
    assert "/.cache" not in text and "MPLCONFIGDIR" not in text, text
    assert not Path("/.cache").exists()                 # matplotlib's cache went to the user's home, or nowhere


@pytest.mark.parametrize("kind", ["a file", pytest.param("under a file", marks=pytest.mark.slow)])
def test_an_unusable_cache_is_one_line_naming_headplod_cache(tmp_path, kind):
    blocker = tmp_path / "blocker"
    blocker.write_text("mine\n")
    cache = blocker if kind == "a file" else blocker / "cache"
    out = tmp_path / "f.jsonl"
    done = _run(["track", "--frames", "2", "--out", out], env=_env(HEADPLOD_CACHE=str(cache), MPLCONFIGDIR=None))
    assert done.returncode == 2, done
    line = _one_line(done.stderr)
    assert "HEADPLOD_CACHE" in line and str(cache) in line and "MPLCONFIGDIR" not in line, line
    assert blocker.read_text() == "mine\n" and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]


@pytest.mark.slow
def test_an_unusable_cache_does_not_stop_a_command_that_does_not_need_it(tmp_path, gl_context):
    blocker = tmp_path / "blocker"
    blocker.write_text("mine\n")
    out = tmp_path / "x.png"
    done = _run(["render", "--size", "64,48", "--out", out], env=_env(HEADPLOD_CACHE=str(blocker),
                                                                      MPLCONFIGDIR=None))
    assert done.returncode == 0, done
    assert b"MPLCONFIGDIR" not in done.stderr and b"Matplotlib" not in done.stderr, done.stderr
    assert out.stat().st_size > 0 and blocker.read_text() == "mine\n"


# ---------------------------------------------------------------------------
# the parts, alone
# ---------------------------------------------------------------------------


def test_a_dropping_stream_drops_the_failed_message_and_every_later_one():
    from headplod.streams import DroppingStream

    class Broken:
        """A stream whose reader left after the first message."""
        def __init__(self):
            self.text = ""

        def write(self, text):
            if self.text.endswith("\n"):
                raise BrokenPipeError(32, "Broken pipe")
            self.text += text

        def flush(self):
            pass

    broken = Broken()
    stream = DroppingStream(broken)
    print("first", file=stream)
    assert broken.text == "first\n" and not stream.dropped
    print("second", file=stream)                        # raises inside; dropped here
    stream.flush()
    print("third", file=stream)
    assert broken.text == "first\n" and stream.dropped


def test_opencv_is_given_a_name_only_when_its_bytes_are_utf8():
    from headplod.io import UnnamablePath, opencv_name

    held = os.fsdecode(b"/v/caf\xc3\xa9/left.avi")      # 'café' as Python holds it under a UTF-8 locale
    assert opencv_name(held) == "/v/café/left.avi"
    assert opencv_name("/v/caf\udcc3\udca9/left.avi") == "/v/café/left.avi"   # held under LC_ALL=C
    with pytest.raises(UnnamablePath, match=r"^/v/caf\\xe9/left.avi: .*UTF-8"):
        opencv_name(os.fsdecode(b"/v/caf\xe9/left.avi"), "video file")


def test_yaml_through_memory_is_the_file_opencv_writes(tmp_path, sweep12_dir):
    rig = io.read_rig(sweep12_dir / "rig.yaml")
    io.write_rig(tmp_path / "ours.yaml", rig)
    fs = cv2.FileStorage(str(tmp_path / "opencv.yaml"), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    for key in ("image_width", "image_height"):
        fs.write(key, int(rig.image_size[key == "image_height"]))
    for key, value in (("K1", rig.K1), ("D1", rig.D1.reshape(1, -1)), ("K2", rig.K2), ("D2", rig.D2.reshape(1, -1)),
                       ("R", rig.R), ("T", rig.T.reshape(3, 1))):
        fs.write(key, np.ascontiguousarray(value, dtype=np.float64))
    fs.release()
    assert (tmp_path / "ours.yaml").read_bytes() == (tmp_path / "opencv.yaml").read_bytes()
    back = io.read_rig(tmp_path / "ours.yaml")
    assert np.array_equal(back.K1, rig.K1) and np.array_equal(back.T, rig.T)
