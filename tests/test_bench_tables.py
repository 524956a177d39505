"""tools/bench_track_tables.py: the measured figures in docs come from the bench JSON, never by hand."""
from __future__ import annotations

import json

import pytest

from conftest import load_tool



def _tool():
    return load_tool("bench_track_tables")


@pytest.mark.slow
def test_tables_carry_every_set_and_goal_from_the_json(tmp_path):
    from headplod.bench.track import run_track_bench

    out = tmp_path / "bench.json"
    assert run_track_bench(json_path=out, quick=True, sets=["static 55 cm", "rolling shutter 30 ms"]) == 0
    data = json.loads(out.read_text())
    assert data["quick"] is True
    page = tmp_path / "bench-track.md"
    assert _tool().main([str(out), str(page)]) == 0
    text = page.read_text()
    assert "--quick" in text and str(out) in text
    assert "| static 55 cm | reproj (default) |" in text
    assert "| rolling shutter 30 ms |" in text
    s = data["imperfect_rig"]["sets"]["rolling shutter 30 ms"]
    assert f"{s['v_err_deg_median']:.3f}" in text                 # the figure, as measured
    for goal in data["goals"] + data["imperfect_rig"]["goals"]:
        assert goal["goal"] in text


def test_an_unreadable_json_is_refused_and_nothing_written(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    page = tmp_path / "page.md"
    assert _tool().main([str(bad), str(page)]) == 2
    assert "cannot read" in capsys.readouterr().err
    assert not page.exists()
