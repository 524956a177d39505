"""Write the judge's results at equal triangles as Markdown, from ``headplod bench plod --only judge``'s JSON.

    headplod bench plod --only judge --json out/judge.json --chart out/judge.png
    python tools/plod_judge_tables.py out/judge.json docs/plod-judge.md [--charts out]

The figures in ``docs/plod-judge.md`` are only ever this script's output: no
measurement is copied by hand into prose. The page says which command made the
JSON and when (the file's modification time, UTC). With ``--charts DIR``, the
per-view charts the bench wrote there (``plod_jod_view_<view>.png``) are copied
beside the page (``docs/img/``). Every output is written to a temporary name
and renamed (whole or untouched).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import sys
import tempfile
from pathlib import Path


def _jod(value) -> str:
    return "–" if value is None else f"{value:.3f}"


def _signed(value, spec: str = "+.3f") -> str:
    return "–" if value is None else format(value, spec)


def _verdict(value) -> str:
    return {True: "met", False: "**not met**", None: "–"}[value]


def equal_triangles(report: dict) -> dict:
    """The equal-triangle part of a ``bench plod`` judge report (the whole report when it is that part)."""
    return report.get("equal_triangles", report) if isinstance(report, dict) else {}


def markdown(report: dict, source: str, when: str, images: dict) -> str:
    """The page: goals per view, then per view the curves, the comparison, the moved fixation, rings, pursuit."""
    eq = equal_triangles(report)
    if "views" not in eq:
        raise ValueError("no equal-triangle results in this JSON (run: headplod bench plod --only judge --json ...)")
    default = eq["default"]
    out = ["# The judge at equal triangles", "",
           f"Written by `tools/plod_judge_tables.py` from `{source}` ({when}), the JSON of "
           "`headplod bench plod --only judge`. The judge is FovVideoVDP (foveated, fixation at the POI); JOD 10 is "
           "no visible difference from `full`. Every mode draws the same number of triangles at each budget "
           f"(`--budget`, met within 3 %). The default mode is `{default}`; how it works and how its settings were "
           "fitted (on the default view only): [plod-criteria.md](plod-criteria.md).", "",
           "## Goals", "",
           f"Margin: `{default}`'s JOD minus the best geometric mode's (sse, dpv, ipv), interpolated at the same "
           "triangles; the goal is ≥ +0.05 at every budget, or ≥ 25 % fewer triangles at equal JOD. Fixation moved: "
           f"with the fixation 20° from the POI, `{default}`'s JOD drops, and by more than `sse`'s.", "",
           "| view | margin at each budget | fewest triangles saved at equal JOD | goal | fixation moved |",
           "|---|---|---|---|---|"]
    for view, res in eq["views"].items():
        c = res.get("comparison") or {}
        margins = ", ".join(f"{m['budget'] / 1e3:.0f}k: {_signed(m['margin'])}" for m in c.get("margins", []))
        saving = c.get("min_saving")
        mf = res.get("moved_fixation", {})
        out.append(f"| {view} | {margins or '–'} | {_signed(saving, '+.0%')} | {_verdict(c.get('met'))} | "
                   f"{_verdict(mf.get('goal_met'))} |")
    for view, res in eq["views"].items():
        out += ["", f"## {view}", "",
                f"`full`: {res['full_triangles']:,} triangles. JOD (triangles) per mode at each budget:", ""]
        budgets = eq["budgets"]
        out.append("| mode | " + " | ".join(f"{b / 1e3:.0f}k" for b in budgets) + " |")
        out.append("|---|" + "---|" * len(budgets))
        for name, pts in res["curves"].items():
            out.append(f"| {name} | " + " | ".join(f"{_jod(p['jod'])} ({p['triangles'] / 1e3:.0f}k)" for p in pts)
                       + " |")
        mf = res.get("moved_fixation")
        if mf:
            out += ["", f"Fixation {mf['deg']:g}° from the POI at {mf['budget'] / 1e3:.0f}k: " + "; ".join(
                f"`{n}` {_jod(r['jod'])} → {_jod(r['jod_moved'])} ({_signed(r['drop'])})" for n, r in mf["modes"].items())
                + "."]
        rings = res.get("rings")
        if rings:
            modes = rings["modes"]
            edges = modes[next(iter(modes))]["edges_deg"]
            out += ["", "Mean visible difference (the metric's per-pixel map) by eccentricity ring from the POI:", "",
                    "| mode | " + " | ".join(f"{a:g}-{b:g}°" for a, b in zip(edges[:-1], edges[1:])) + " |",
                    "|---|" + "---|" * (len(edges) - 1)]
            for n, r in modes.items():
                out.append(f"| {n} | " + " | ".join("–" if m is None else f"{m:.3g}" for m in r["mean"]) + " |")
        pu = res.get("pursuit")
        if pu:
            s = pu["settings"]
            out += ["", f"Moving POI ({s['frames']} frames at {s['fps']:g} Hz, pursuit {s['speed_deg_s']:g}°/s, "
                    f"judged as one video with a fixation per frame, {pu['budget'] / 1e3:.0f}k): " + ", ".join(
                        f"`{n}` {_jod(r['jod'])}" for n, r in pu["modes"].items()) + "."]
        if view in images:
            out += ["", f"![JOD against triangles and the error by ring, {view}]({images[view]})"]
    return "\n".join(out) + "\n"


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("json", help="headplod bench plod --only judge --json output")
    parser.add_argument("out", help="the Markdown page to write")
    parser.add_argument("--charts", metavar="DIR", help="where the bench wrote plod_jod_view_<view>.png "
                                                       "(copied into img/ beside the page)")
    args = parser.parse_args(argv)
    source, out = Path(args.json), Path(args.out)
    try:
        report = json.loads(source.read_text())
        when = _dt.datetime.fromtimestamp(source.stat().st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        views = equal_triangles(report).get("views", {})
        charts = {v: Path(args.charts) / f"plod_jod_view_{v}.png" for v in views} if args.charts else {}
        missing = [str(p) for p in charts.values() if not p.is_file()]
        if missing:
            raise OSError(f"no chart {missing[0]} (--charts: the folder of the bench's --chart)")
        page = markdown(report, source.name, when, {v: f"img/{p.name}" for v, p in charts.items()})
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"plod_judge_tables: {exc}", file=sys.stderr)
        return 2
    if charts:
        (out.parent / "img").mkdir(parents=True, exist_ok=True)
        for p in charts.values():
            _write_atomic(out.parent / "img" / p.name, p.read_bytes())
    _write_atomic(out, page.encode())
    print(f"wrote {out}" + (f" and {len(charts)} charts in {out.parent / 'img'}" if charts else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
