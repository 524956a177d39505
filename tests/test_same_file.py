"""One notion of the same file, and outputs that are regular files or '-' (issue 35).

- ``track --record`` over the folder that a dataset's ``left/`` and ``right/`` (or its frames) link into is
  refused in one line, and not a byte of it changes (the issue's first case);
- ``--out`` a character device, a FIFO (without waiting for a reader), a link to ``/proc/self/fd/1``
  (the records reach standard output, the link stays); ``render --out/--stats`` device nodes; the other
  commands' outputs alike;
- a property test: any spelling of an input (symlink chains, ``..``, hard links, relative or absolute)
  given as an output is refused and no input changes;
- a fuzz over output kinds for ``track --out``, ``track --record`` and ``render --out``: no special file
  changes, no traceback, exit status 0 or 2 with one line;
- the library's rule (:mod:`headplod.io.files`) on its own, bind mounts included, and the writers'
  own refusal (``write_atomically``, ``claim_output``).
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from calib import DEFAULT_SCREEN

from headplod import io
from headplod.cli import main as cli_main
from headplod.io.files import (Inputs, OutputKind, OutputRefused, check_not_input, check_output, file_id,
                               output_kind)
from headplod.io.progressive import claim_output

ROOT = Path(__file__).resolve().parent.parent
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
needs_root = pytest.mark.skipif(not IS_ROOT, reason="making a device node (os.mknod) needs root")


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def _one_line(err: str, *words: str) -> str:
    """The one message line of a refusal: no traceback, one line naming each of ``words``."""
    assert "Traceback" not in err, err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1, err
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def _state(root: Path) -> dict:
    """Everything under ``root`` (and ``root``) as it is on disk: kind, device and inode, bytes of files,
    targets of links. Equal states: not a byte, not a name, not a node changed."""
    out = {}
    for path in [root, *sorted(root.rglob("*"))]:
        st_ = path.lstat()
        entry = (stat.S_IFMT(st_.st_mode), st_.st_dev, st_.st_ino, st_.st_rdev)
        if path.is_symlink():
            entry += (os.readlink(path),)
        elif stat.S_ISREG(st_.st_mode):
            entry += (path.read_bytes(),)
        out[str(path.relative_to(root))] = entry
    return out


def _node(path: Path) -> tuple:
    """What a special file (or a link) is: kind, device, inode, rdev (and a link's target)."""
    st_ = path.lstat()
    return (stat.S_IFMT(st_.st_mode), st_.st_dev, st_.st_ino, st_.st_rdev,
            os.readlink(path) if path.is_symlink() else None)


def _headplod(*argv, timeout=120, **kwargs) -> subprocess.CompletedProcess:
    """The real command in its own process (a FIFO or standard output must not be this one's)."""
    kwargs = {"stdout": subprocess.PIPE, **kwargs}
    return subprocess.run([sys.executable, "-c", "import sys; from headplod.cli import main; sys.exit(main())",
                           *map(str, argv)], stderr=subprocess.PIPE, text=True, timeout=timeout, **kwargs)


def _mknull(path: Path) -> Path:
    """A copy of /dev/null (character device 1, 3)."""
    os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    return path


def _socket(path: Path) -> Path:
    s = socket.socket(socket.AF_UNIX)
    try:
        s.bind(str(path))
    finally:
        s.close()                       # the socket file stays
    return path


@pytest.fixture
def linked(tmp_path, sweep12_dir):
    """The issue's layout: R/victim a recording; R/linked with its own rig.yaml and times.csv, whose left/ and
    right/ are (relative) links into R/victim."""
    r = tmp_path / "R"
    victim = r / "victim"
    shutil.copytree(sweep12_dir, victim)
    (r / "linked").mkdir()
    for side in ("left", "right"):
        (r / "linked" / side).symlink_to(Path("..") / "victim" / side)
    for name in ("rig.yaml", "times.csv"):
        shutil.copy(victim / name, r / "linked" / name)
    return r


# ---------------------------------------------------------------------------
# the cases
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("layout", ["folders", "frames", "absolute"])
def test_record_over_what_the_inputs_link_into_is_refused_and_keeps_every_byte(linked, layout, capsys,
                                                                               monkeypatch):
    """The issue's first case: `track --source R/linked --record R/victim --overwrite --frames 10` moved the
    recording aside, tracked 'missing' frames, exited 3 and deleted all 30 frames."""
    victim, source = linked / "victim", linked / "linked"
    if layout == "frames":                  # left/ and right/ real folders, each frame a link into the victim
        for side in ("left", "right"):
            (source / side).unlink()
            (source / side).mkdir()
            for frame in sorted((victim / side).iterdir()):
                (source / side / frame.name).symlink_to(Path("../../victim") / side / frame.name)
    elif layout == "absolute":
        for side in ("left", "right"):
            (source / side).unlink()
            (source / side).symlink_to(victim / side)
    monkeypatch.chdir(linked.parent)
    before = _state(linked)
    assert cli_main(["track", "--source", "R/linked", "--record", "R/victim", "--overwrite", "--frames", "10",
                     "-q"]) == 2
    line = _one_line(capsys.readouterr().err, "--record R/victim", "holds")
    assert "record into another folder" in line
    assert _state(linked) == before


@needs_root
def test_out_a_character_device_is_refused_and_the_node_kept(sample, tmp_path, capsys):
    """The issue: `--out NODE` (a copy of /dev/null) deleted the node and wrote a JSONL file there, exit 0."""
    node = _mknull(tmp_path / "node")
    link = tmp_path / "link.jsonl"
    link.symlink_to(node)
    nodes = {p: _node(p) for p in (node, link)}
    for out in (node, link):
        assert cli_main(["track", "--source", str(sample), "--out", str(out), "--frames", "2", "-q"]) == 2
        _one_line(capsys.readouterr().err, f"--out {out}", "character device")
    assert {p: _node(p) for p in nodes} == nodes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "link.jsonl", "node"]


def test_out_a_fifo_is_refused_at_once_and_the_fifo_kept(sample, tmp_path):
    """The issue: `--out FIFO` left its reader waiting for ever with 0 bytes. No reader here: a run that opened
    the FIFO would block, and the timeout fails the test."""
    fifo = tmp_path / "fifo.jsonl"
    os.mkfifo(fifo)
    before = _node(fifo)
    done = _headplod("track", "--source", sample, "--out", fifo, "--frames", "2", "-q", timeout=60)
    assert done.returncode == 2
    _one_line(done.stderr, f"--out {fifo}", "FIFO")
    assert _node(fifo) == before


# Never /dev/stdout itself here: the unfixed code, run as root, replaced the system's /dev/stdout link with a
# regular file. A link of the test's own to it (or to /proc/self/fd/1) shows the same, and risks nothing.
@pytest.mark.parametrize("aim", ["/proc/self/fd/1", "/dev/stdout", "chain"])
def test_out_through_a_link_to_standard_output_writes_the_records_there(sample, tmp_path, aim):
    """The issue: `--out` a link to /proc/self/fd/1 became a regular file and nothing reached standard output."""
    link = tmp_path / "stdout.jsonl"
    if aim == "chain":
        (tmp_path / "one").symlink_to("/proc/self/fd/1")
        aim = "one"
    link.symlink_to(aim)
    links = {p: os.readlink(p) for p in tmp_path.iterdir() if p.is_symlink()}
    done = _headplod("track", "--source", sample, "--out", link, "--frames", "3", "-q")
    assert done.returncode == 0, done.stderr
    records = [json.loads(line) for line in done.stdout.splitlines()]
    assert [r["frame"] for r in records] == [0, 1, 2] and all(r["ok"] for r in records)
    assert {p: os.readlink(p) for p in tmp_path.iterdir() if p.is_symlink()} == links
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["ds", *(p.name for p in links)])   # nothing aside


def test_out_through_a_link_to_a_closed_standard_output_is_refused(sample, tmp_path):
    """Found by trying it: with standard output closed, such a link leads nowhere, and the run named a hidden
    marker under /proc in its error (exit 1)."""
    link = tmp_path / "stdout.jsonl"
    link.symlink_to("/proc/self/fd/1")
    done = _headplod("track", "--source", sample, "--out", link, "--frames", "2", "-q", stdout=None,
                     preexec_fn=lambda: os.close(1))
    assert done.returncode == 2
    _one_line(done.stderr, f"--out {link}", "standard output is closed")
    assert link.is_symlink() and sorted(p.name for p in tmp_path.iterdir()) == ["ds", "stdout.jsonl"]


def _special_files(tmp_path: Path) -> list[Path]:
    """A device node (as root), a FIFO and a socket, each with a .png and a .json name."""
    made = []
    for ending in (".png", ".json"):
        if IS_ROOT:
            made.append(_mknull(tmp_path / f"node{ending}"))
        fifo = tmp_path / f"fifo{ending}"
        os.mkfifo(fifo)
        made.append(fifo)
        made.append(_socket(tmp_path / f"s{ending}"))
    return made


def test_render_out_and_stats_on_special_files_are_refused_before_rendering(tmp_path, capsys):
    """The issue: `render --out x.png --stats s.json` replaced device nodes (after rendering for seconds)."""
    made = _special_files(tmp_path)
    before = {p: _node(p) for p in made}
    for special in made:
        argv = (["--out", str(special)] if special.suffix == ".png"
                else ["--out", str(tmp_path / "x.png"), "--stats", str(special)])
        assert cli_main(["render", "--size", "64,48", *argv]) == 2
        option = "--out" if special.suffix == ".png" else "--stats"
        _one_line(capsys.readouterr().err, f"{option} {special}", "not a regular file")
    assert {p: _node(p) for p in made} == before
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("command", [
    ["board", "--cols", "9", "--rows", "6", "--square-mm", "25", "--out", "{fifo}.pdf"],
    ["glasses", "--out", "{tmp}/g.pdf", "--yaml", "{fifo}.yaml"],
    ["glasses", "--markers", "{ds}/markers.yaml", "--out", "{tmp}/g.pdf", "--yaml", "{ds}/left/../markers.yaml"],
    ["render", "--screen", "{tmp}/screen.yaml", "--out", "{tmp}/x.png", "--stats", "{link}/../screen.yaml"],
    ["render", "--out", "{tmp}/x.png", "--stats", "{tmp}/./x.png"],
    ["pivot", "--source", "{ds}", "--out", "{fifo}.yaml"],
    ["pivot", "--source", "{ds}", "--out", "{link}/times.csv"],
    ["preview", "--source", "{ds}", "--out", "{link}/left/pictures"],
    ["preview", "--source", "{ds}", "--out", "{fifo}"],
    ["demo", "--headless", "--source", "{ds}", "--out", "{link}"],
    ["demo", "--headless", "--source", "{ds}", "--out", "{fifo}"],
    ["bench", "track", "--json", "{fifo}.json"],
    ["bench", "live", "--source", "{ds}", "--json", "{link}/rig.yaml"],
    ["calibrate", "--source", "{tmp}", "--cols", "9", "--rows", "6", "--square-mm", "25", "--out", "{fifo}.yaml"],
    ["synth", "static", "--out", "{fifo}"],
    ["synth", "static", "--out", "{tmp}/made", "--overwrite"],
    ["track", "--source", "{ds}", "--save-rig", "{fifo}.yaml"],
    ["track", "--source", "{link}", "--record", "{ds}/..", "--overwrite"],
    ["track", "--source", "{ds}", "--calib", "{tmp}/calib.yaml", "--out", "{tmp}/../{tmpname}/calib.yaml"],
])
def test_every_command_refuses_special_files_and_its_inputs_as_outputs(sample, tmp_path, command, capsys):
    """Each command with a file output refuses a special file and a spelling of its own input, in one line,
    exit 2, before any long work, and changes nothing."""
    io.write_markers(sample / "markers.yaml", io.default_marker_model())
    shutil.copy(DEFAULT_SCREEN, tmp_path / "screen.yaml")
    shutil.copy(sample / "rig.yaml", tmp_path / "calib.yaml")
    link = tmp_path / "link"
    link.symlink_to(sample)
    fifo = tmp_path / "fifo"
    for name in ("fifo", "fifo.pdf", "fifo.yaml", "fifo.json"):
        os.mkfifo(tmp_path / name)
    (tmp_path / "made").mkdir()
    os.mkfifo(tmp_path / "made" / "times.csv")            # synth --overwrite would replace it
    before = _state(tmp_path)
    argv = [a.format(tmp=tmp_path, ds=sample, link=link, fifo=fifo, tmpname=tmp_path.name) for a in command]
    assert cli_main(argv) == 2, argv
    _one_line(capsys.readouterr().err)
    assert _state(tmp_path) == before


# ---------------------------------------------------------------------------
# the property: any spelling of an input is refused, and no input changes
# ---------------------------------------------------------------------------

#: What is read by `track --source in/ds --calib in/calib.yaml`: (path under the base, is a folder).
TARGETS = [("in/ds", True), ("in/ds/left", True), ("in/ds/right", True), ("in/ds/rig.yaml", False),
           ("in/ds/times.csv", False), ("in/ds/left/000003.png", False), ("in/ds/right/000007.png", False),
           ("in/calib.yaml", False), ("in", True)]


@pytest.fixture(scope="module")
def spelled_base(tmp_path_factory, sweep12_dir) -> Path:
    base = tmp_path_factory.mktemp("spelled")
    shutil.copytree(sweep12_dir, base / "in" / "ds")
    shutil.copy(sweep12_dir / "rig.yaml", base / "in" / "calib.yaml")
    return base


def _spell(base: Path, work: Path, target: str, steps: list, absolute: bool) -> str:
    """A spelling of ``base/target`` made by ``steps``: each a new link to the spelling so far (its target
    written relative or absolute), a detour through ``..``, or (files) a new hard link."""
    spelling = target                                   # relative to base, the current folder
    for k, (step, rel) in enumerate(steps):
        if step == "link":
            link = work / f"l{k}"
            aim = os.path.relpath(base / spelling, work) if rel else str(base / spelling)
            link.symlink_to(aim)
            spelling = os.path.relpath(link, base)
        elif step == "dotdot":
            (work / "a" / "b").mkdir(parents=True, exist_ok=True)
            spelling = os.path.join(os.path.relpath(work, base), "a", "b", "..", "..", "..", spelling)
        elif step == "hardlink" and (base / spelling).is_file():
            link = work / f"h{k}{Path(target).suffix}"
            os.link(os.path.realpath(base / spelling), link)
            spelling = os.path.relpath(link, base)
    return str(base / spelling) if absolute else spelling


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(target=st.sampled_from(TARGETS),
       steps=st.lists(st.tuples(st.sampled_from(["link", "dotdot", "hardlink"]), st.booleans()), max_size=4),
       absolute=st.booleans(), how=st.sampled_from(["as is", "inside"]),
       source=st.sampled_from(["plain", "absolute", "link"]))
def test_any_spelling_of_an_input_is_refused_and_no_input_changes(spelled_base, monkeypatch, capsys, target,
                                                                  steps, absolute, how, source):
    base = spelled_base
    monkeypatch.chdir(base)
    work = Path(tempfile.mkdtemp(prefix="w", dir=base))
    path, folder = target
    spelling = _spell(base, work, path, steps, absolute)
    ds = {"plain": "in/ds", "absolute": str(base / "in" / "ds")}.get(source)
    if ds is None:
        (work / "src").symlink_to(base / "in" / "ds")
        ds = str(work / "src")
    if folder:                  # a folder read, or (in/) one holding what is read: --record may not hold it
        inside = how == "inside" and path != "in"
        option, value = ("--out", os.path.join(spelling, "p.jsonl")) if inside else ("--record", spelling)
    else:
        option, value = ("--out", spelling) if how == "as is" else ("--save-rig", spelling)
    before = _state(base / "in")
    argv = ["track", "--source", ds, "--calib", "in/calib.yaml", option, value, "--frames", "1", "-q"]
    code = cli_main(argv + (["--overwrite"] if option == "--record" else []))
    err = capsys.readouterr().err
    assert code == 2, (argv, err)
    _one_line(err, f"{option} {value}")
    assert _state(base / "in") == before


# ---------------------------------------------------------------------------
# the fuzz over output kinds
# ---------------------------------------------------------------------------

KINDS = ["regular", "missing", "folder", "device", "fifo", "socket", "link-regular", "link-missing",
         "link-folder", "link-device", "link-fifo", "link-socket", "read-only file", "read-only folder",
         "in read-only folder"]


def _make(kind: str, where: Path, name: str) -> Path:
    """An output path ``where/name`` of ``kind``."""
    where.mkdir(parents=True, exist_ok=True)
    path = where / name
    if kind.startswith("link-"):
        path.symlink_to(_make(kind[5:], where / "targets", name))
    elif kind in ("regular", "read-only file"):
        path.write_text("old\n")
        if kind == "read-only file":
            path.chmod(0o444)
    elif kind in ("folder", "read-only folder"):
        path.mkdir()
        if kind == "read-only folder":
            path.chmod(0o555)
    elif kind == "device":
        _mknull(path)
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        _socket(path)
    elif kind == "in read-only folder":
        (where / "ro").mkdir()
        (where / "ro").chmod(0o555)
        path = where / "ro" / name
    return path


def _fake_render_still(settings, screen, *, out=None, stats_path=None, **_):
    """render_still without the GPU: a small picture and its stats, written as the real one writes them."""
    from headplod.render.still import write_outputs
    image = np.zeros((settings.size[1], settings.size[0], 3), np.uint8)
    stats = {"triangles": 2, "select_ms": 0.0, "build_ms": 0.0, "render_ms": 0.0,
             "mesh": {"max_level": 5, "kind": "table"}}
    write_outputs(image, stats, out, stats_path)
    return image, stats


@pytest.mark.parametrize("command", ["track --out", "track --record", "render --out"])
def test_fuzz_over_output_kinds_changes_no_special_file_and_says_one_line(sample, tmp_path, command, capsys,
                                                                         monkeypatch):
    """Every kind of output path, for each command: exit 0 or 2 (1 only where a folder cannot be written, as a
    user who is not root sees), no traceback, a special file (and a link to one) exactly as it was."""
    monkeypatch.setattr("headplod.render.command.render_still", _fake_render_still)
    for kind in KINDS:
        if "device" in kind and not IS_ROOT:
            continue
        where = tmp_path / kind.replace(" ", "_")
        name = {"render --out": "out.png", "track --out": "out.jsonl"}.get(command, "out")
        out = _make(kind, where, name)
        special = [p for p in [out, *where.rglob("*")] if p.is_symlink() or (os.path.lexists(p) and not
                                                                            (p.is_file() or p.is_dir()))]
        before = {p: _node(p) for p in special}
        if command == "render --out":
            argv = ["render", "--size", "64,48", "--out", str(out)]
        else:
            argv = ["track", "--source", str(sample), command.split()[1], str(out), "--frames", "1", "-q"]
        try:
            code = cli_main(argv)
        finally:
            for path in [where, *where.rglob("*")]:
                if path.is_dir() and not path.is_symlink():
                    path.chmod(0o755)
        err = capsys.readouterr().err
        assert "Traceback" not in err and "internal error" not in err, (kind, err)
        assert code in ((0, 1, 2) if "read-only" in kind and not IS_ROOT else (0, 2)), (kind, code, err)
        if code:
            _one_line(err)
        assert {p: _node(p) for p in before} == before, kind
        if code == 0 and command == "track --out":
            assert len(io.read_poses(out)) == 1
        if kind in ("device", "fifo", "socket") or kind.startswith("link-") and kind[5:] in ("device", "fifo",
                                                                                            "socket"):
            assert code == 2, (kind, err)


# ---------------------------------------------------------------------------
# the library's rule, alone
# ---------------------------------------------------------------------------


def test_output_kinds_and_standard_streams(tmp_path):
    (tmp_path / "f").write_text("x")
    (tmp_path / "d").mkdir()
    assert output_kind("-", stream=True) is OutputKind.STDOUT
    assert output_kind(tmp_path / "missing") is OutputKind.MISSING
    assert output_kind(tmp_path / "f") is OutputKind.FILE
    assert output_kind(tmp_path / "d", folder=True) is OutputKind.FOLDER
    with pytest.raises(OutputRefused, match="--x -: this output cannot go to standard output"):
        output_kind("-", option="--x")
    with pytest.raises(OutputRefused, match="is a folder"):
        output_kind(tmp_path / "d")
    with pytest.raises(OutputRefused, match="is a file; give a folder"):
        output_kind(tmp_path / "f", folder=True)
    (tmp_path / "loop").symlink_to("loop")
    with pytest.raises(OutputRefused, match="loop of symbolic links"):
        output_kind(tmp_path / "loop")
    with open(tmp_path / "fd1", "w") as fh:                 # the file fd 1 goes to, by its own name: stdout
        saved = os.dup(1)
        try:
            os.dup2(fh.fileno(), 1)
            assert output_kind(tmp_path / "fd1", stream=True) is OutputKind.STDOUT
            with pytest.raises(OutputRefused, match="standard output"):
                output_kind(tmp_path / "fd1")
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def test_inputs_hold_frames_only_where_a_folder_does_not(tmp_path):
    """A file with one name inside a folder held adds nothing; a hard-linked one is held by its inode."""
    (tmp_path / "ds").mkdir()
    for name in ("a.png", "b.png"):
        (tmp_path / "ds" / name).write_bytes(b"x")
    os.link(tmp_path / "ds" / "b.png", tmp_path / "b_again.png")
    inputs = Inputs().folder("the folder", tmp_path / "ds").files("a frame", sorted((tmp_path / "ds").iterdir()))
    assert [i.path for i in inputs] == [str(tmp_path / "ds"), str(tmp_path / "ds" / "b.png")]
    with pytest.raises(OutputRefused, match="is a frame"):
        check_output(tmp_path / "b_again.png", inputs, option="--out")
    check_output(tmp_path / "other.png", inputs, option="--out")
    assert file_id(tmp_path / "ds" / ".." / "ds").same(file_id(tmp_path / "ds"))


def test_folder_outputs_hold_inputs_only_in_their_own_entries(tmp_path):
    (tmp_path / "out" / "data").mkdir(parents=True)
    (tmp_path / "out" / "data" / "x.png").write_bytes(b"x")
    inputs = Inputs().file("a picture being read", tmp_path / "out" / "data" / "x.png")
    check_not_input(tmp_path / "out", inputs, folder=True, entries=("preview_*.png",))
    with pytest.raises(OutputRefused, match=r"holds a picture being read .*\(in its data\)"):
        check_not_input(tmp_path / "out", inputs, option="--out", folder=True, entries=("data",))
    with pytest.raises(OutputRefused, match="holds a picture being read"):
        check_not_input(tmp_path / "out", inputs, option="--out", folder=True)


@pytest.fixture
def bind_mount(tmp_path):
    """``(source, mount)``: the folder ``source`` bind-mounted at ``mount`` (skipped where mount is refused)."""
    source, mount = tmp_path / "source", tmp_path / "mount"
    source.mkdir()
    mount.mkdir()
    if not IS_ROOT or shutil.which("mount") is None:
        pytest.skip("a bind mount needs root and mount(8)")
    done = subprocess.run(["mount", "--bind", str(source), str(mount)], capture_output=True)
    if done.returncode:
        pytest.skip(f"mount --bind refused here: {done.stderr.decode(errors='replace').strip()}")
    try:
        yield source, mount
    finally:
        subprocess.run(["umount", str(mount)], check=True)


def test_a_bind_mount_is_the_same_folder_and_file(bind_mount):
    source, mount = bind_mount
    (source / "rig.yaml").write_text("x")
    inputs = Inputs().folder("the dataset folder being read", source).file("the rig being read",
                                                                           source / "rig.yaml")
    with pytest.raises(OutputRefused, match="is the rig being read"):
        check_output(mount / "rig.yaml", inputs, option="--out")
    with pytest.raises(OutputRefused, match="lies inside the dataset folder"):
        check_output(mount / "poses.jsonl", inputs, option="--out")
    with pytest.raises(OutputRefused, match="dataset folder"):
        check_output(mount, inputs, option="--record", folder=True)


@pytest.mark.parametrize("option", ["--record", "--out"])
def test_track_refuses_the_dataset_through_a_bind_mount(bind_mount, sweep12_dir, capsys, option):
    source, mount = bind_mount
    shutil.copytree(sweep12_dir, source / "ds")
    before = _state(source)
    value = mount / "ds" if option == "--record" else mount / "ds" / "times.csv"
    extra = ["--overwrite"] if option == "--record" else []
    assert cli_main(["track", "--source", str(source / "ds"), option, str(value), *extra, "--frames", "2", "-q"]) == 2
    _one_line(capsys.readouterr().err, f"{option} {value}")
    assert _state(source) == before


# ---------------------------------------------------------------------------
# the writers refuse on their own
# ---------------------------------------------------------------------------


def test_writers_never_replace_a_special_file(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock = _socket(tmp_path / "s")
    link = tmp_path / "link"
    link.symlink_to(fifo)
    called = []
    for path in (fifo, sock, link):
        before = _node(path)
        with pytest.raises(OutputRefused, match="never written over"):
            io.write_atomically(path, called.append)
        with pytest.raises(OutputRefused):
            claim_output(path, what=str(path))
        with pytest.raises(OutputRefused):
            io.PoseWriter(path)
        assert _node(path) == before
    assert not called                                       # refused before anything was written
    rec = tmp_path / "rec"
    (rec / "left").mkdir(parents=True)
    os.mkfifo(rec / "left" / "000000.png")
    with pytest.raises(OutputRefused, match=r"left/000000.png is a FIFO"):
        claim_output(rec, what="--record rec", folder=True, entries=("left", "right"))
    assert stat.S_ISFIFO((rec / "left" / "000000.png").lstat().st_mode)


def test_write_atomically_writes_through_a_link_and_in_place_to_standard_output(tmp_path, capfd):
    target = tmp_path / "real.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target.name)
    io.write_atomically(link, lambda name: Path(name).write_text("new"))
    assert link.is_symlink() and target.read_text() == "new"
    out = tmp_path / "stdout.txt"
    out.symlink_to("/proc/self/fd/1")
    capfd.readouterr()
    io.write_atomically(out, lambda name: Path(name).write_text("to stdout\n"))
    assert capfd.readouterr().out == "to stdout\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.txt", "real.txt", "stdout.txt"]
    assert out.is_symlink()
