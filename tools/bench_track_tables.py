"""Write the tables of ``headplod bench track`` as Markdown, from its JSON, with the command and the date.

    headplod bench track --json out/bench_track.json --chart out/bench_track.png
    python tools/bench_track_tables.py out/bench_track.json docs/bench-track.md

The figures in ``docs/bench-track.md`` are only ever this script's output: no
measurement is copied by hand into prose. The page says which command made the
JSON, when (the JSON file's modification time, UTC), and whether it was a
``--quick`` run; each goal is listed with its worst set and whether it is met.
The output is written to a temporary name and renamed (whole or untouched).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import sys
import tempfile
from pathlib import Path


def _f(value, spec: str, scale: float = 1.0) -> str:
    if value is None:
        return "–"
    try:
        return format(float(value) * scale, spec)
    except (TypeError, ValueError):
        return "–"


def _goal_lines(goals: list) -> list[str]:
    lines = []
    for g in goals:
        worst = g.get("worst")
        if isinstance(worst, list):
            worst = " .. ".join(_f(w, ".3g") for w in worst)
        else:
            worst = _f(worst, ".3g")
        missed = g.get("missed") or []
        mark = "met" if g.get("met") else "**not met**"
        tail = f" (missed on: {', '.join(missed)})" if missed else ""
        lines.append(f"- {mark}: {g['goal']}: worst {worst}{tail}")
    return lines


def tables(data: dict, source: str, stamp: str) -> str:
    """The Markdown page for one ``bench track`` JSON (``data``), made from ``source`` at ``stamp``."""
    quick = bool(data.get("quick"))
    out = ["# `headplod bench track`: measured", "",
           f"Made by `python tools/bench_track_tables.py {source}` from the JSON of "
           f"`headplod bench track{' --quick' if quick else ''} --json {source}`, written {stamp} "
           "(UTC). Timing ratios depend on the machine and its load; the accuracy does not.", ""]
    estimator = data.get("default_estimator", "reproj")
    sets = data.get("sets") or {}
    if sets:
        out += ["## Perfect rigs, every estimator", "",
                "| set | estimator | pose | V median (°) | V p95 (°) | P1 median (mm) | wrong | mean pose × threshold |",
                "|---|---|---|---|---|---|---|---|"]
        for name, by_estimator in sets.items():
            for est, s in by_estimator.items():
                out.append(f"| {name} | {est}{' (default)' if est == estimator else ''} | "
                           f"{_f(s.get('tracked_fraction'), '.1%')} | {_f(s.get('v_err_deg_median'), '.3f')} | "
                           f"{_f(s.get('v_err_deg_p95'), '.3f')} | {_f(s.get('pos_err_mm_median'), '.3f')} | "
                           f"{s.get('wrong_identifications', '–')} | {_f(s.get('mean_pose_ratio_to_threshold'), '.1f')} |")
        out += ["", "Goals:", ""] + _goal_lines(data.get("goals") or []) + [""]
    rig = data.get("imperfect_rig") or {}
    if rig.get("sets"):
        settle = rig.get("settle_s", 3.0)
        out += ["## Imperfect rigs and ordinary webcams (default estimator, refined online)", "",
                f"| set | pose | wrong | V median (°) | P1 median (mm) | V / P1 after {settle:g} s | NEES | "
                "turn (°) / scale (%) / focal (%) / offset (ms) / readout (ms) error at the end | p99 / median frame |",
                "|---|---|---|---|---|---|---|---|---|"]
        for name, s in rig["sets"].items():
            f = s.get("final") or {}
            errors = " / ".join([_f(f.get("turn_err_deg"), ".3f"), _f(f.get("scale_err"), "+.2f", 100),
                                 _f(f.get("focal_err"), "+.2f", 100), _f(f.get("offset_err_ms"), "+.2f"),
                                 _f(f.get("readout_err_ms"), "+.2f")])
            out.append(f"| {name} | {_f(s.get('pose_fraction'), '.1%')} | {s.get('wrong_poses', '–')} | "
                       f"{_f(s.get('v_err_deg_median'), '.3f')} | {_f(s.get('pos_err_mm_median'), '.3f')} | "
                       f"{_f(s.get('v_err_deg_median_settled'), '.3f')} / {_f(s.get('pos_err_mm_median_settled'), '.3f')} | "
                       f"{_f(s.get('nees_mean'), '.2f')} | {errors} | {_f(s.get('frame_p99_to_median'), '.1f')} |")
        out += ["", "A wrong pose: V more than 5° or P1 more than 20 mm off. The readout is the rolling shutter's "
                "(first row to last); a global shutter's is 0.", "", "Goals:", ""] + _goal_lines(rig.get("goals") or [])
        timing = rig.get("timing")
        if timing:
            out += ["", f"The rig's refinement costs {_f(timing.get('refine_ms_mean'), '.2f')} ms per frame "
                        f"(median over the sets; slowest frame {_f(timing.get('refine_ms_max'), '.1f')} ms)."]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Markdown tables from `headplod bench track --json`.")
    parser.add_argument("json", help="the JSON that `headplod bench track --json FILE` wrote")
    parser.add_argument("out", help="the Markdown page to write (e.g. docs/bench-track.md)")
    args = parser.parse_args(argv)
    source = Path(args.json)
    try:
        data = json.loads(source.read_text())
    except (OSError, ValueError) as exc:
        print(f"bench_track_tables: cannot read {source}: {exc}", file=sys.stderr)
        return 2
    stamp = _dt.datetime.fromtimestamp(source.stat().st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M")
    text = tables(data, str(source), stamp)
    out = Path(args.out)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent or ".")
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, out)
    except OSError as exc:
        print(f"bench_track_tables: cannot write {out}: {exc}", file=sys.stderr)
        return 1
    print(f"tables: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
