"""tools/plod_judge_tables.py: docs/plod-judge.md comes from the judge's JSON, never by hand."""
from __future__ import annotations

import json

from conftest import load_tool



def _tool():
    return load_tool("plod_judge_tables")


def _report(terrain, chart, margin):
    """A judge report of one view with every key the page reads; ``margin`` the default's at both budgets."""
    points = [{"triangles": 100_000, "jod": 9.1234}, {"triangles": 200_000, "jod": 9.5678}]
    return {"terrain": terrain, "equal_triangles": {
        "default": "change", "budgets": [100_000, 200_000], "charts": [str(chart)],
        "views": {"plains": {
            "full_triangles": 2_097_152, "curves": {"change": points, "sse": points},
            "comparison": {"margins": [{"budget": 100_000, "margin": margin}, {"budget": 200_000, "margin": None}],
                           "min_saving": -0.125, "met": margin >= 0.05},
            "moved_fixation": {"deg": 20.0, "budget": 200_000, "goal_met": False,
                               "modes": {"change": {"jod": 9.5, "jod_moved": 9.6, "drop": -0.1}}},
            "rings": {"modes": {"change": {"edges_deg": [0, 2, 5], "mean": [0.01, None]}}},
            "pursuit": {"budget": 200_000, "settings": {"frames": 30, "fps": 60.0, "speed_deg_s": 10.0},
                        "modes": {"change": {"jod": 9.4321}}}}}}}


def test_the_page_carries_every_terrain_view_figure_and_chart(tmp_path):
    chart = tmp_path / "run" / "plod_jod_view_plains.png"
    chart.parent.mkdir()
    chart.write_bytes(b"png")
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(_report("built-in", chart, 0.0711)))
    b.write_text(json.dumps(_report("/data/ridges24.npy", chart, -0.0422)))
    page = tmp_path / "docs" / "judge.md"
    page.parent.mkdir()
    assert _tool().main([str(a), str(b), str(page), "--charts"]) == 0
    text = page.read_text()
    assert "## Terrain: built-in" in text and "## Terrain: ridges24.npy" in text
    assert "+0.071" in text and "-0.042" in text and "| met |" in text and "**not met**" in text
    assert "9.123 (100k)" in text and "9.568 (200k)" in text and "`change` 9.432" in text and "-12%" in text
    assert (page.parent / "img" / "judge_builtin_plains.png").read_bytes() == b"png"
    assert "img/judge_ridges24_plains.png" in text


def test_a_json_without_the_judge_leaves_the_page_alone(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"terrain": "built-in"}))
    page = tmp_path / "judge.md"
    page.write_text("before")
    assert _tool().main([str(bad), str(page)]) == 2
    assert page.read_text() == "before"
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no equal-triangle results" in err
