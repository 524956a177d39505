"""tools/gaze_judge_tables.py: docs/plod-gaze.md comes from the judge's and the fit's JSON, never by hand.

The gaze report here is made the way ``gaze_report`` makes it (:func:`plod_gaze.case_summary` and
:func:`plod_gaze.verdicts` on hand-made case reports), so the page is checked against values computed by hand:
the margins, the triangles where the default reaches the target JOD, the verdicts.
"""
from __future__ import annotations

import json

import pytest

from conftest import load_tool
from headplod.bench import plod_gaze as pg

BUDGETS = (100_000, 200_000, 400_000)
FULL_TRIANGLES, FULL_MS = 2_000_000, 22.0


def _tool():
    return load_tool("gaze_judge_tables")


def _curve(means):
    """Two fixations at ±0.01 about each mean; frame_ms 4, 6, 10."""
    return [{"budget": b, "triangles": b, "frame_ms": ms, "jod": [m - 0.01, m + 0.01]}
            for b, ms, m in zip(BUDGETS, (4.0, 6.0, 10.0), means)]


def _case_report(terrain, view, screen, default_means):
    """A judge_case report: sse 9.1/9.55/9.7, dpv and ipv lower, head-only 0.05 below the default, the oracle
    0.1 above head-only."""
    t = pg.GOALS["target_jod"]
    return {"case": {"terrain": terrain, "view": view, "screen": screen},
            "full": {"triangles": FULL_TRIANGLES, "frame_ms": FULL_MS},
            "curves": {"default": _curve(default_means),
                       "head_only": _curve([m - 0.05 for m in default_means]),
                       "sse": _curve([t - 0.4, t + 0.05, t + 0.2]),
                       "dpv": _curve([t - 0.5, t - 0.1, t + 0.1]),
                       "ipv": _curve([t - 2.0, t - 1.5, t - 1.0])},
            "oracle": [{"budget": b, "triangles": [b, b], "jod": [m + 0.04, m + 0.06]}
                       for b, m in zip(BUDGETS, default_means)]}


def _gaze_report():
    t = pg.GOALS["target_jod"]
    # desk: the default crosses the target 3/4 of the way (in log) from 100k to 200k, so at 100k·2^0.75 =
    # 168,179 triangles (8.4 % of full), frame_ms 5.5 there: 4.0x full's frame rate. Its margins over the best
    # geometric mode are +0.1, +0.05 (sse's 9.55 at 200k) and +0.1; wide: the default trails sse by 0.25 at 200k.
    cases = [_case_report("mesas:5", "plains", "desk", [t - 0.3, t + 0.1, t + 0.3]),
             _case_report("ridges:7", "overview", "wide", [t - 0.5, t - 0.2, t + 0.1])]
    summaries = [pg.case_summary(c) for c in cases]
    return {"config": {"budgets": list(BUDGETS), "fixations": 2, "seed": 0, "oracle": True, "rings": False},
            "goals": pg.GOALS, "training": pg.TRAINING, "held_out": pg.HELD_OUT, "cases": cases,
            "summaries": summaries, "verdicts": pg.verdicts(summaries), "quick": False}


def _fit():
    scores = [{"settings": {"change_share": 0.0, "cortical_exponent": 0.9}, "worst": -0.04, "mean": 0.01,
               "cases": {"builtin/default/desk": [-0.04, 0.06]}},
              {"settings": {"change_share": 0.3, "cortical_exponent": 1.2}, "worst": -0.06, "mean": 0.034,
               "cases": {"builtin/default/desk": [-0.06, 0.128]}},
              {"settings": {"change_share": 0.45, "cortical_exponent": 0.9}, "worst": -0.09, "mean": 0.02,
               "cases": {"builtin/default/desk": [-0.09, 0.13]}}]
    return {"grid": {"change_share": [0.0, 0.3, 0.45], "cortical_exponent": [0.9, 1.2]},
            "cases": ["builtin/default/desk"], "scores": scores, "best": pg.choose_settings(scores),
            "config": {"budgets": [100_000, 250_000], "fixations": 4, "quick": False}}


def _section(text: str, title: str) -> list:
    """The table rows (lines starting with '|', header and rule left out) of the section ``## title``."""
    lines = text.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0].splitlines()
    rows = [line for line in lines if line.startswith("|")]
    return rows[2:]


def _write(tmp_path, report, fit=None):
    gaze = tmp_path / "gaze.json"
    gaze.write_text(json.dumps(report))
    paths = [gaze]
    if fit is not None:
        paths.append(tmp_path / "fit.json")
        paths[-1].write_text(json.dumps(fit))
    return paths


def test_the_page_carries_the_goals_savings_cases_and_fit(tmp_path):
    report, fit = _gaze_report(), _fit()
    assert fit["best"] == {"change_share": 0.3, "cortical_exponent": 1.2}       # the highest mean
    verdicts = report["verdicts"]
    assert verdicts["margin_desk"]["met"] and not verdicts["margin_wide"]["met"]   # both kinds on the page
    page = tmp_path / "docs" / "plod-gaze.md"
    page.parent.mkdir()
    assert _tool().main([*map(str, _write(tmp_path, report, fit)), str(page)]) == 0
    text = page.read_text()
    assert text.startswith("# The judge at the true gaze\n")
    assert "gaze.json" in text and "fit.json" in text and "A quick run" not in text

    goals = _section(text, "The goals")
    assert len(goals) == len(verdicts)
    for row, (key, v) in zip(goals, verdicts.items()):
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[-1] == ("met" if v["met"] else "**not met**"), key
        assert cells[-2] == f"≥ {v['goal']:+.2f}"
        if v.get("worst_case"):
            assert f"({v['worst_case']})" in cells[1]
    desk = goals[list(verdicts).index("margin_desk")]
    assert "+0.050 (mesas:5/plains/desk at 200k)" in desk          # 9.6 − sse's 9.55 at 200k

    savings = _section(text, f"What foveation saves: JOD {pg.GOALS['target_jod']:g} at the true gaze")
    desk_default = next(r for r in savings if r.startswith("| desk | default |"))
    assert desk_default == ("| desk | default | 1 of 1 | 0 | 168,179 | "
                            f"{100_000 * 2 ** 0.75 / FULL_TRIANGLES:.1%} | 4.0 |")
    wide_ipv = next(r for r in savings if r.startswith("| wide | ipv |"))
    assert wide_ipv == "| wide | ipv | 0 of 1 | 0 | – | – | – |"
    assert {r.split("|")[2].strip() for r in savings} == {"default", "sse", "dpv", "ipv"}

    cases = _section(text, "Every held-out case")
    assert len(cases) == len(BUDGETS) * len(report["cases"])
    for r, s in zip(report["cases"], report["summaries"]):
        name = pg.GazeCase(**r["case"]).name
        rows = [c for c in cases if c.startswith(f"| {name} |")]
        assert [c.split("|")[2].strip() for c in rows] == [f"{b // 1000}k" for b in BUDGETS]
        for row, summary_row in zip(rows, s["budgets"]):
            assert row.endswith(f"| {summary_row['margin']:+.3f} ({summary_row['geometric_mode']}) |")
    assert cases[1].startswith("| mesas:5/plains/desk | 200k | 9.600 | 9.550 | 9.550 | 9.400 |")
    assert cases[1].endswith("| 9.650 | +0.050 (sse) |")                      # the oracle, then the margin

    fit_rows = _section(text, "The fit")
    assert len(fit_rows) == len(fit["scores"])
    chosen = [r for r in fit_rows if "**(chosen)**" in r]
    assert chosen == ["| 0.3 | 1.2 | +0.034 **(chosen)** | -0.060 (builtin/default/desk) |"]
    assert fit_rows[0] == chosen[0]                          # by mean margin, what the choice maximises
    assert "100k, 250k triangles with 4 fixations" in text


def test_the_bench_json_wraps_the_report(tmp_path):
    """``bench plod --only judge`` puts the report under jod.gaze; the page is the same as from the report."""
    report = _gaze_report()
    plain, wrapped = tmp_path / "plain.md", tmp_path / "wrapped.md"
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = _write(tmp_path / "a", report)[0]
    b = _write(tmp_path / "b", {"jod": {"gaze": report}})[0]
    assert _tool().main([str(a), str(plain)]) == 0
    assert _tool().main([str(b), str(wrapped)]) == 0
    strip = lambda text: text.split("\n", 3)[3]                             # noqa: E731  (the sources' names differ)
    assert strip(plain.read_text()) == strip(wrapped.read_text())
    assert "## The fit" not in plain.read_text()


def test_a_quick_run_says_so(tmp_path):
    report = {**_gaze_report(), "quick": True}
    page = tmp_path / "p.md"
    assert _tool().main([str(_write(tmp_path, report)[0]), str(page)]) == 0
    assert "**A quick run**" in page.read_text()


@pytest.mark.parametrize("problem", ["missing gaze", "broken gaze", "no summaries", "missing fit", "broken fit"])
def test_a_missing_or_invalid_json_exits_2_and_writes_nothing(tmp_path, capsys, problem):
    gaze, fit = _write(tmp_path, _gaze_report(), _fit())
    if problem == "missing gaze":
        gaze.unlink()
    elif problem == "broken gaze":
        gaze.write_text('{"summaries": [')
    elif problem == "no summaries":
        gaze.write_text(json.dumps({"jod": {"equal_triangles": {}}}))
    elif problem == "missing fit":
        fit.unlink()
    else:
        fit.write_text("not json")
    page = tmp_path / "out" / "plod-gaze.md"
    page.parent.mkdir()
    page.write_text("before")
    assert _tool().main([str(gaze), str(fit), str(page)]) == 2
    assert page.read_text() == "before"
    assert sorted(p.name for p in page.parent.iterdir()) == ["plod-gaze.md"]
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and captured.err.startswith("gaze_judge_tables: ")
    assert captured.out == ""


def test_a_json_that_is_not_an_object_exits_2(tmp_path, capsys):
    gaze = tmp_path / "gaze.json"
    gaze.write_text("[]")
    assert _tool().main([str(gaze), str(tmp_path / "p.md")]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_the_page_is_written_atomically(tmp_path, monkeypatch):
    gaze = _write(tmp_path, _gaze_report())[0]
    out = tmp_path / "out"
    out.mkdir()
    page = out / "plod-gaze.md"
    tool = _tool()
    assert tool.main([str(gaze), str(page)]) == 0
    assert [p.name for p in out.iterdir()] == ["plod-gaze.md"]              # no temporary file left beside it
    first = page.read_text()
    # A write that fails half way leaves the page as it was and no temporary file.
    monkeypatch.setattr(tool, "markdown", lambda *args: 12345)               # write_text(int) raises TypeError
    with pytest.raises(TypeError):
        tool.main([str(gaze), str(page)])
    assert page.read_text() == first
    assert [p.name for p in out.iterdir()] == ["plod-gaze.md"]
