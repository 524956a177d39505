"""``python -m headplod.bench.plod_vdp``: the perceptual judge alone, on chosen modes, without the rest of ``bench plod``.

    python -m headplod.bench.plod_vdp [--modes csf,sse] [--forms paper,kelly,daly | --forms ''] [--biases -1,0,1]
                                      [--metrics fvvdp,cvvdp] [--no-image-side] [--json FILE] [--chart FILE.png]

Renders ``full``, each mode and CSF form over the level biases, ``raymask``
and ``csf+foveate`` at ``bench
plod``'s default view (:class:`headplod.bench.plod._Bench`), scores them with
:mod:`headplod.bench.plod_judge` and prints the JOD table; the chart's folder
also gets the heatmaps of ``csf`` and ``sse``. Needs the optional extra
``.[vdp]``. ``headplod bench plod --vdp`` runs the same judge after the full
benchmark.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .plod import _Bench
from .outputs import write_json
from .plod_judge import METRICS, jod_chart, jod_report, jod_table, vdp_available, write_heatmaps


def run_judge(json_path=None, chart_path=None, modes=None, forms=None, biases=(-1.0, 0.0, 1.0),
              metrics=("fvvdp",), frames: int = 3, timing_rounds: int = 3, image_side: bool = True) -> dict:
    """Render and judge ``modes`` and ``forms`` (None: all) over ``biases`` (levels); print the table, write
    JSON (``json_path``), the chart (``chart_path``) and beside it the heatmaps; ``image_side``: also
    ``raymask`` and ``csf+foveate`` (:data:`headplod.bench.plod_judge.IMAGE_SIDE`). Returns the report."""
    for m in metrics:
        if m not in METRICS or not vdp_available(m):
            raise ValueError(f"the metric {m!r} is not one of {METRICS} installed: pip install -e '.[vdp]'")
    bench = _Bench(frames=frames)
    report = jod_report(bench, modes=modes, forms=forms, biases=biases, metrics=metrics, timing_rounds=timing_rounds,
                        image_side=image_side,
                        progress=lambda text: print(f"plod_vdp: {text}", file=sys.stderr, flush=True))
    print(jod_table(report))
    if chart_path:
        jod_chart(report, chart_path)
        report["heatmap_jod"] = write_heatmaps(bench, Path(chart_path).parent)
    if json_path:
        write_json(json_path, report, default=float)
    return report


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m headplod.bench.plod_vdp",
                                 description="foveated JOD against frame time for the PLOD modes")
    ap.add_argument("--modes", help="comma-separated modes (default: every mode but full)")
    ap.add_argument("--forms", help="comma-separated CSF forms besides the default (default: all; '' for none)")
    ap.add_argument("--biases", default="-1,0,1", help="comma-separated level biases, levels (default -1,0,1)")
    ap.add_argument("--metrics", default="fvvdp", help="comma-separated, of " + ",".join(METRICS) + " (default fvvdp)")
    ap.add_argument("--no-image-side", action="store_true", help="leave out raymask and csf+foveate")
    ap.add_argument("--json", help="write the report as JSON")
    ap.add_argument("--chart", help="write the chart (PNG); the heatmaps go beside it")
    a = ap.parse_args(argv)
    try:
        biases = [float(b) for b in a.biases.split(",")]
        run_judge(a.json, a.chart, modes=a.modes.split(",") if a.modes else None,
                  forms=None if a.forms is None else [f for f in a.forms.split(",") if f],
                  biases=biases, metrics=[m for m in a.metrics.split(",") if m], image_side=not a.no_image_side)
    except ValueError as exc:
        print(f"plod_vdp: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
