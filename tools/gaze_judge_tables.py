"""Write the judge at the true gaze as Markdown, from ``headplod bench plod --only gaze``'s JSON and the fit's.

    python tools/fit_plod_gaze.py out/fit_gaze.json
    headplod bench plod --only gaze --json out/gaze.json --chart out/gaze.png
    python tools/gaze_judge_tables.py out/gaze.json out/fit_gaze.json docs/plod-gaze.md --charts

The figures in ``docs/plod-gaze.md`` are only ever this script's output. The page says which commands made the
JSON and when (each file's modification time, UTC). With ``--charts`` the charts the gaze JSON lists are copied
into ``docs/img/`` beside the page. Every output is written under a temporary name and renamed.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))    # the repository's headplod, as the other tools
from headplod.bench.plod_gaze import GazeCase  # noqa: E402
from headplod.io import write_atomically  # noqa: E402


def _f(value, spec: str = ".3f") -> str:
    return "–" if value is None else format(value, spec)


def _when(path: Path) -> str:
    return _dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def verdict_lines(verdicts: dict) -> list:
    """The goals as a table: goal, measured (the worst or the mean it is judged on), the goal's bound, verdict."""
    what = {"margin_desk": "desk screen: default − best geometric mode, worst held-out case and budget",
            "margin_wide": "wide screen: default − best geometric mode, worst held-out case and budget",
            "oracle_every_view": "oracle − head-only, worst case (mean over its fixations and budgets)",
            "oracle_mean": "oracle − head-only, mean over every fixation",
            "prior_recovers": "the prior's gain over head-only / the oracle's, means over every fixation",
            "prior_never_worse": "default − head-only, worst case (mean over its fixations and budgets)"}
    rows = ["| goal | measured | bound | |", "|---|---|---|---|"]
    for key, v in verdicts.items():
        worst = _f(v.get("worst"), "+.3f" if key != "prior_recovers" else ".2f")
        where = f" ({v['worst_case']})" if v.get("worst_case") else ""
        rows.append(f"| {what.get(key, key)} | {worst}{where} | ≥ {v['goal']:+.2f} | "
                    f"{'met' if v['met'] else '**not met**'} |")
    return rows


def case_rows(report: dict) -> list:
    """Per case and budget: the mean JOD at the true gaze of each rule and the oracle, and the margin."""
    names = list(report["cases"][0]["curves"])
    oracle = "oracle" in report["cases"][0]
    head = "| case | budget | " + " | ".join(names) + (" | oracle" if oracle else "") + " | margin |"
    rows = [head, "|" + "---|" * (head.count("|") - 1)]
    for r, s in zip(report["cases"], report["summaries"]):
        name = GazeCase(**r["case"]).name
        for k, row in enumerate(s["budgets"]):
            cells = [_f(float(np.mean(r["curves"][n][k]["jod"]))) for n in names]
            if oracle:
                cells.append(_f(float(np.mean(r["oracle"][k]["jod"]))))
            margin = "–" if row["margin"] is None else f"{row['margin']:+.3f} ({row['geometric_mode']})"
            rows.append(f"| {name} | {row['budget'] // 1000}k | " + " | ".join(cells) + f" | {margin} |")
    return rows


def savings_rows(report: dict) -> list:
    """Per screen and rule: the triangles and frame-rate ratio against ``full`` at which the mean JOD at the true
    gaze reaches the target (median over the cases whose curve crosses it)."""
    rows = ["| screen | rule | cases crossing it | below the smallest budget | triangles (median) | of full | "
            "frame rate × full (median) |", "|---|---|---|---|---|---|---|"]
    for screen in sorted({s["case"]["screen"] for s in report["summaries"]}):
        targets = [s["target"] for s in report["summaries"] if s["case"]["screen"] == screen]
        for rule in (k for k in targets[0] if isinstance(targets[0][k], dict)):
            reached = [t[rule] for t in targets if t[rule]["triangles"] is not None]
            below = sum(t[rule]["state"] == "below" for t in targets)
            if reached:
                tri = float(np.median([t["triangles"] for t in reached]))
                ratio = float(np.median([t["frame_rate_ratio"] for t in reached]))
                rows.append(f"| {screen} | {rule} | {len(reached)} of {len(targets)} | {below} | {tri:,.0f} | "
                            f"{tri / targets[0]['full_triangles']:.1%} | {ratio:.1f} |")
            else:
                rows.append(f"| {screen} | {rule} | 0 of {len(targets)} | {below} | – | – | – |")
    return rows


def fit_rows(fit: dict) -> list:
    """The fit's scores, by mean margin (what the choice maximises), the chosen one marked."""
    keys = list(fit["grid"])
    rows = ["| " + " | ".join(keys) + " | mean margin | worst margin (case) |", "|" + "---|" * (len(keys) + 2)]
    for s in sorted(fit["scores"], key=lambda s: (-s["mean"], -s["worst"])):
        best = " **(chosen)**" if s["settings"] == fit["best"] else ""
        worst_case = min(s.get("cases", {}).items(), key=lambda kv: min(kv[1]) if kv[1] else math.inf,
                         default=(None, None))[0]
        rows.append("| " + " | ".join(f"{s['settings'][k]:g}" for k in keys) + f" | {s['mean']:+.3f}{best} | "
                    + f"{s['worst']:+.3f}" + (f" ({worst_case})" if worst_case else "") + " |")
    return rows


def markdown(report: dict, fit: dict | None, sources: dict, images: list) -> str:
    target = report["goals"]["target_jod"]
    out = ["# The judge at the true gaze", "",
           "Written by `tools/gaze_judge_tables.py` (the commands are in its docstring) from "
           f"`{sources['gaze'][0]}` ({sources['gaze'][1]})"
           + (f" and `{sources['fit'][0]}` ({sources['fit'][1]})" if fit else "") + ". "
           "FovVideoVDP judges each image with its fixation at a **true gaze**: the head's direction turned by an "
           "eye-in-head offset drawn from the viewer model ([viewer-model.md](viewer-model.md)). `default` is the "
           "default mode with its gaze prior, `head_only` the same with `--gaze-prior 0,0`, `oracle` the default "
           "mode drawn with its POI exactly at the true gaze (prior 0). Every rule draws the same triangles at each "
           "budget (`--budget`, within 3 %). JOD is the mean over the fixations of a case."
           + (" **A quick run** (one budget, three fixations)." if report.get("quick") else ""), "",
           f"Training (fitted): terrains {', '.join(report['training']['terrains'])}, views "
           f"{', '.join(report['training']['views'])}. Held out (reported here): every case with a terrain among "
           f"{', '.join(report['held_out']['terrains'])} or a view among {', '.join(report['held_out']['views'])}.",
           "", "## The goals", ""] + verdict_lines(report["verdicts"])
    out += ["", f"## What foveation saves: JOD {target:g} at the true gaze", ""] + savings_rows(report)
    out += ["", "## Every held-out case", ""] + case_rows(report)
    for path in images:
        out += ["", f"![JOD at the true gaze against triangles, and the error by eccentricity]({path})"]
    if fit is not None:
        out += ["", "## The fit", "",
                f"Mode `hybrid` on the training cases ({len(fit['cases'])}: {', '.join(fit['cases'])}), at "
                f"{', '.join(str(b // 1000) + 'k' for b in fit['config']['budgets'])} triangles with "
                f"{fit['config']['fixations']} fixations each; the margin is over the best geometric mode.", ""]
        out += fit_rows(fit)
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("gaze", help="the JSON of headplod bench plod --only gaze (or --only judge)")
    parser.add_argument("fit", nargs="?", help="the JSON of tools/fit_plod_gaze.py")
    parser.add_argument("out", help="the Markdown page to write")
    parser.add_argument("--charts", action="store_true", help="copy the charts into img/ beside the page")
    args = parser.parse_args(argv)
    paths = {"gaze": Path(args.gaze), "fit": Path(args.fit) if args.fit else None}
    try:
        report = json.loads(paths["gaze"].read_text())
        fit = json.loads(paths["fit"].read_text()) if paths["fit"] else None
    except (OSError, ValueError) as exc:
        print(f"gaze_judge_tables: {exc}", file=sys.stderr)
        return 2
    if isinstance(report, dict):
        report = report.get("gaze", (report.get("jod") or {}).get("gaze", report))
    if fit is not None and not (isinstance(fit, dict) and {"grid", "cases", "scores", "best", "config"} <= set(fit)):
        print(f"gaze_judge_tables: {args.fit} is not the JSON of tools/fit_plod_gaze.py", file=sys.stderr)
        return 2
    if not isinstance(report, dict) or "summaries" not in report:
        print(f"gaze_judge_tables: {args.gaze} has no judge-at-the-true-gaze report", file=sys.stderr)
        return 2
    out = Path(args.out)
    images = []
    if args.charts:
        for chart in report.get("charts", []):
            target = out.parent / "img" / Path(chart).name
            target.parent.mkdir(parents=True, exist_ok=True)
            data = Path(chart).read_bytes()
            write_atomically(target, lambda name, data=data: Path(name).write_bytes(data))
            images.append(f"img/{target.name}")
    sources = {k: (str(p), _when(p)) for k, p in paths.items() if p}
    page = markdown(report, fit, sources, images)
    write_atomically(out, lambda name: Path(name).write_text(page))
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
