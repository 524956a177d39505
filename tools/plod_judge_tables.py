"""Write the judge's results at equal triangles as Markdown, from ``headplod bench plod --only judge``'s JSON.

    headplod bench plod --only judge --json out/judge.json --chart out/judge.png
    python tools/make_dem.py out/ridges24.npy --ridges 24
    headplod bench plod --only judge --terrain out/ridges24.npy --spacing-m 25 --json out/ridges/judge.json \
        --chart out/ridges/judge.png
    python tools/plod_judge_tables.py out/judge.json out/ridges/judge.json docs/plod-judge.md --charts

The figures in ``docs/plod-judge.md`` are only ever this script's output: no
measurement is copied by hand into prose. Each JSON (one terrain) is a section;
the page says which command made it and when (the file's modification time,
UTC). With ``--charts``, the per-view charts each JSON lists (``equal_triangles``
→ ``charts``) are copied beside the page (``docs/img/``, named by terrain and
view). Every output is written to a temporary name and renamed (whole or
untouched).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))    # the repository's headplod, as the other tools
from headplod.io import write_atomically     # noqa: E402


def _jod(value) -> str:
    return "–" if value is None else f"{value:.3f}"


def _signed(value, spec: str = "+.3f") -> str:
    return "–" if value is None else format(value, spec)


def _verdict(value) -> str:
    return {True: "met", False: "**not met**", None: "–"}[value]


def equal_triangles(report: dict) -> dict:
    """The equal-triangle part of a ``bench plod`` judge report (the whole report when it is that part)."""
    return report.get("equal_triangles", report) if isinstance(report, dict) else {}


def terrain_name(report: dict) -> str:
    """The terrain a report was measured on: ``built-in`` or its file's name."""
    terrain = report.get("terrain") or "built-in"
    return terrain if terrain == "built-in" else Path(terrain).name


def markdown(sections, images: dict) -> str:
    """The page: per terrain (``sections``: (report, source, when)), goals per view, then per view the curves, the
    comparison, the moved fixation, rings, pursuit. ``images``: {(terrain, view): relative path}."""
    out = ["# The judge at equal triangles", "",
           "Written by `tools/plod_judge_tables.py` from the JSON of `headplod bench plod --only judge` (the "
           "command is in the script's docstring). The judge is FovVideoVDP (foveated, fixation at the POI); JOD 10 "
           "is no visible difference from `full`. Every mode draws the same number of triangles at each budget "
           "(`--budget`, met within 3 %). How the default mode works and how its settings were fitted (on the "
           "built-in terrain's default view only; everything else is held out): [plod-criteria.md](plod-criteria.md)."]
    for report, source, when in sections:
        out += ["", *_section(report, source, when, images)]
    return "\n".join(out) + "\n"


def _section(report: dict, source: str, when: str, images: dict) -> list:
    eq = equal_triangles(report)
    if "views" not in eq:
        raise ValueError(f"{source}: no equal-triangle results (run: headplod bench plod --only judge --json ...)")
    default, terrain = eq["default"], terrain_name(report)
    out = [f"## Terrain: {terrain}", "", f"From `{source}` ({when}).", "",
           f"Margin: `{default}`'s JOD minus the best geometric mode's (sse, dpv, ipv), interpolated at the same "
           "triangles; the goal is ≥ +0.05 at every budget, or ≥ 25 % fewer triangles at equal JOD. Fixation moved: "
           f"with the fixation 20° from the POI, `{default}`'s JOD drops, and by more than `sse`'s (the drop of "
           "each is in the view's section).", "",
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
        out += ["", f"### {terrain}: {view}", "",
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
        if (terrain, view) in images:
            out += ["", f"![JOD against triangles and the error by ring, {terrain}, {view}]({images[terrain, view]})"]
    return out


def _write_atomic(path: Path, data: bytes) -> None:
    """``data`` to ``path``, whole or untouched (the project's own atomic write)."""
    write_atomically(path, lambda name: Path(name).write_bytes(data))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("json", nargs="+", help="headplod bench plod --only judge --json outputs, one per terrain")
    parser.add_argument("out", help="the Markdown page to write")
    parser.add_argument("--charts", action="store_true", help="copy the per-view charts each JSON lists into img/ "
                                                               "beside the page")
    args = parser.parse_args(argv)
    out = Path(args.out)
    sections, charts = [], {}
    try:
        for name in args.json:
            source = Path(name)
            report = json.loads(source.read_text())
            when = _dt.datetime.fromtimestamp(source.stat().st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
            sections.append((report, source.name, when))
            if args.charts:
                terrain = terrain_name(report)
                stem = "builtin" if terrain == "built-in" else Path(terrain).stem
                for chart in equal_triangles(report).get("charts", []):
                    view = Path(chart).stem.removeprefix("plod_jod_view_")
                    charts[terrain, view] = (Path(chart), f"judge_{stem}_{view}.png")
        missing = [str(p) for p, _ in charts.values() if not p.is_file()]
        if missing:
            raise OSError(f"no chart {missing[0]} (the JSON lists it; was the bench's folder moved?)")
        page = markdown(sections, {key: f"img/{name}" for key, (_, name) in charts.items()})
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"plod_judge_tables: {exc}", file=sys.stderr)
        return 2
    if charts:
        (out.parent / "img").mkdir(parents=True, exist_ok=True)
        for p, name in charts.values():
            _write_atomic(out.parent / "img" / name, p.read_bytes())
    _write_atomic(out, page.encode())
    print(f"wrote {out}" + (f" and {len(charts)} charts in {out.parent / 'img'}" if charts else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
