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
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
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
